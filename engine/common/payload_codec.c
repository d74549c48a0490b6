/*
 * payload_codec.c - pack and unpack a node's payload (API: payload_codec.h,
 * layout: hlod/store.h, docs/store-format.md).
 *
 * The choices were measured on the default city (docs/store-format.md):
 * geometry goes through meshoptimizer's codecs (Debian libmeshoptimizer),
 * which delta-code each byte column of fixed-size vertices and code
 * triangles against a small FIFO of recent edges and vertices; so the writer
 * orders triangles for the vertex cache first and vertices in first-use
 * order (store_write.c), which is what both codecs assume.  Textures are
 * JPEG through libturbojpeg, whose SIMD decoder keeps the loader thread's
 * decode time small.
 */
#include "payload_codec.h"
#include "store_node.h"

#include <math.h>
#include <meshoptimizer.h>
#include <stdlib.h>
#include <string.h>
#include <turbojpeg.h>

_Static_assert(sizeof(hlod_store_packed_header) == 128, "packed header layout");

/* JPEG's limit on a side (libjpeg-turbo's JPEG_MAX_DIMENSION); wider
 * textures are stored raw. */
#define JPEG_MAX_SIDE 65500u

/* The most a codec stream can expand into, per byte (a forged payload must
 * not make the reader allocate far beyond its own size): meshoptimizer's
 * vertex codec spends at least 2 bits per 16 bytes of vertex data and its
 * index codec at least 4 bits per triangle; a JPEG at least 2 bits per 8x8
 * block and channel.  Bounds with a wide margin. */
#define MAX_VERTEX_BYTES_PER_BYTE 256u
#define MAX_TRIS_PER_BYTE 64u
#define MAX_PIXELS_PER_BYTE 4096u

#define BAD(code, ...)                                  \
    do {                                                \
        hlod_logf(lg, HLOD_LOG_ERROR, __VA_ARGS__);     \
        r = (code);                                     \
        goto done;                                      \
    } while (0)

/* ---- octahedral normals (Meyer et al., "On floating-point normal vectors") ---- */

static float sign_not_zero(float v) { return v < 0 ? -1.0f : 1.0f; }

void hlod_oct_encode(const float n[3], int16_t out[2])
{
    float l1 = fabsf(n[0]) + fabsf(n[1]) + fabsf(n[2]);
    float x = 0, y = 0;
    if (l1 > 0 && isfinite(l1)) {
        x = n[0] / l1;
        y = n[1] / l1;
        if (n[2] < 0) {
            float ox = (1 - fabsf(y)) * sign_not_zero(x);
            float oy = (1 - fabsf(x)) * sign_not_zero(y);
            x = ox;
            y = oy;
        }
    }
    out[0] = (int16_t)lrintf(fminf(fmaxf(x, -1), 1) * 32767.0f);
    out[1] = (int16_t)lrintf(fminf(fmaxf(y, -1), 1) * 32767.0f);
}

void hlod_oct_decode(const int16_t in[2], float n[3])
{
    float x = fmaxf((float)in[0] / 32767.0f, -1.0f);
    float y = fmaxf((float)in[1] / 32767.0f, -1.0f);
    float z = 1 - fabsf(x) - fabsf(y);
    if (z < 0) {
        float ox = (1 - fabsf(y)) * sign_not_zero(x);
        float oy = (1 - fabsf(x)) * sign_not_zero(y);
        x = ox;
        y = oy;
    }
    float len = sqrtf(x * x + y * y + z * z);   /* >= 1/sqrt(3): never 0 */
    n[0] = x / len;
    n[1] = y / len;
    n[2] = z / len;
}

/* ---- pack ---- */

/* Appends a meshopt-coded vertex stream to *dst; returns its bytes, 0 on
 * failure (the bound is exact, so only a bug fails). */
static size_t put_vertices(uint8_t *dst, size_t room, const void *v, size_t count, size_t size)
{
    return meshopt_encodeVertexBuffer(dst, room, v, count, size);
}

static hlod_result pack_texture(const hlod_packed_input *in, uint8_t **jpeg, unsigned long *bytes,
                                const char *name, const hlod_logger *lg)
{
    hlod_result r = HLOD_OK;
    *jpeg = NULL;
    *bytes = 0;
    tjhandle tj = tjInitCompress();
    if (!tj)
        return HLOD_ERR_NOMEM;
    int gray = in->tex_channels == 1;
    if (tjCompress2(tj, in->pixels, (int)in->tex_width, 0, (int)in->tex_height,
                    gray ? TJPF_GRAY : TJPF_RGB, jpeg, bytes, gray ? TJSAMP_GRAY : TJSAMP_444,
                    in->jpeg_quality, TJFLAG_ACCURATEDCT) != 0)
        BAD(HLOD_ERR_FORMAT, "%s: cannot encode a %ux%u texture as JPEG: %s", name,
            in->tex_width, in->tex_height, tjGetErrorStr2(tj));
done:
    tjDestroy(tj);
    if (r != HLOD_OK) {
        tjFree(*jpeg);
        *jpeg = NULL;
    }
    return r;
}

hlod_result hlod_payload_pack(const hlod_packed_input *in, uint8_t **out, size_t *out_size,
                              const char *name, const hlod_logger *lg)
{
    *out = NULL;
    *out_size = 0;
    hlod_result r = HLOD_OK;
    const size_t v = in->vertex_count, ic = 3 * (size_t)in->tri_count;
    hlod_store_packed_header ph;
    memset(&ph, 0, sizeof ph);
    memcpy(ph.magic, HLOD_PACKED_MAGIC, 4);
    ph.flags = in->flags;
    ph.vertex_count = in->vertex_count;
    ph.index_count = (uint32_t)ic;
    ph.tex_tri_count = in->tex_tri_count;
    ph.tex_width = in->tex_width;
    ph.tex_height = in->tex_height;
    ph.tex_channels = in->tex_channels;

    uint32_t *pos = malloc(12 * v);
    uint32_t *attr = malloc(4 * v);     /* normals, then UVs */
    uint8_t *jpeg = NULL;
    unsigned long jpeg_bytes = 0;
    uint8_t *buf = NULL;
    if (!pos || !attr)
        BAD(HLOD_ERR_NOMEM, "%s: out of memory packing a payload", name);

    /* positions: offsets from the per-axis minimum, which must span < 2^32 */
    for (int k = 0; k < 3; k++) {
        int64_t lo = INT64_MAX, hi = INT64_MIN;
        for (size_t i = 0; i < v; i++) {
            int64_t g = in->grid[3 * i + k];
            lo = g < lo ? g : lo;
            hi = g > hi ? g : hi;
        }
        if (lo < INT32_MIN || lo > INT32_MAX || hi - lo > (int64_t)UINT32_MAX)
            BAD(HLOD_ERR_INVALID_ARG, "%s: a node spans grid steps [%lld, %lld] on axis %d, "
                "more than the store's 32-bit grid holds", name, (long long)lo, (long long)hi, k);
        ph.pos_shift[k] = (int32_t)lo;
        for (size_t i = 0; i < v; i++)
            pos[3 * i + k] = (uint32_t)(in->grid[3 * i + k] - lo);
    }

    int textured = in->pixels != NULL;
    if (textured) {
        size_t raw_tex = (size_t)in->tex_width * in->tex_height * in->tex_channels;
        int jpeg_ok = in->tex_width <= JPEG_MAX_SIDE && in->tex_height <= JPEG_MAX_SIDE;
        if (!(in->jpeg_quality > 0 && jpeg_ok) && raw_tex > UINT32_MAX)
            BAD(HLOD_ERR_INVALID_ARG, "%s: a %ux%ux%u texture is %zu bytes, over the 4 GiB a "
                "payload section holds", name, in->tex_width, in->tex_height, in->tex_channels,
                raw_tex);
        if (in->jpeg_quality > 0 && jpeg_ok && (in->tex_channels == 1 || in->tex_channels == 3)) {
            r = pack_texture(in, &jpeg, &jpeg_bytes, name, lg);
            if (r != HLOD_OK)
                goto done;
            ph.tex_codec = HLOD_TEX_JPEG;
        } else {
            ph.tex_codec = HLOD_TEX_RAW;
        }
    }
    size_t tex_raw = textured ? (size_t)in->tex_width * in->tex_height * in->tex_channels : 0;
    size_t tex_bytes = ph.tex_codec == HLOD_TEX_JPEG ? (size_t)jpeg_bytes : tex_raw;
    size_t room = sizeof ph + meshopt_encodeVertexBufferBound(v, 12) +
                  (in->normals ? meshopt_encodeVertexBufferBound(v, 4) : 0) +
                  (in->uvs ? meshopt_encodeVertexBufferBound(v, 4) : 0) +
                  (in->colors ? meshopt_encodeVertexBufferBound(v, 4) : 0) +
                  meshopt_encodeIndexBufferBound(ic, v) + tex_bytes;
    buf = malloc(room);
    if (!buf)
        BAD(HLOD_ERR_NOMEM, "%s: out of memory packing a payload", name);
    size_t at = sizeof ph, n;
    size_t sec[HLOD_SEC_COUNT] = {0};

    sec[HLOD_SEC_POSITIONS] = n = put_vertices(buf + at, room - at, pos, v, 12);
    at += n;
    if (in->normals) {
        int16_t *o = (int16_t *)attr;
        for (size_t i = 0; i < v; i++)
            hlod_oct_encode(in->normals + 3 * i, o + 2 * i);
        sec[HLOD_SEC_NORMALS] = n = put_vertices(buf + at, room - at, attr, v, 4);
        at += n;
    }
    if (in->uvs) {
        for (int k = 0; k < 2; k++) {
            float lo = INFINITY, hi = -INFINITY;
            for (size_t i = 0; i < v; i++) {
                lo = fminf(lo, in->uvs[2 * i + k]);
                hi = fmaxf(hi, in->uvs[2 * i + k]);
            }
            float scale = (hi - lo) / 65535.0f;
            if (!(scale > 0) || !isfinite(scale))
                scale = 0;
            ph.uv_min[k] = lo;
            ph.uv_scale[k] = scale;
            uint16_t *q = (uint16_t *)attr;
            for (size_t i = 0; i < v; i++) {
                float t = scale > 0 ? rintf((in->uvs[2 * i + k] - lo) / scale) : 0;
                q[2 * i + k] = (uint16_t)fminf(fmaxf(t, 0), 65535);
            }
        }
        sec[HLOD_SEC_UVS] = n = put_vertices(buf + at, room - at, attr, v, 4);
        at += n;
    }
    if (in->colors) {
        sec[HLOD_SEC_COLORS] = n = put_vertices(buf + at, room - at, in->colors, v, 4);
        at += n;
    }
    sec[HLOD_SEC_INDICES] = n = meshopt_encodeIndexBuffer(buf + at, room - at, in->indices, ic);
    at += n;
    if (textured) {
        memcpy(buf + at, ph.tex_codec == HLOD_TEX_JPEG ? jpeg : in->pixels, tex_bytes);
        sec[HLOD_SEC_TEXTURE] = tex_bytes;
        at += tex_bytes;
    }
    for (int k = 0; k < HLOD_SEC_COUNT; k++) {
        int present = k == HLOD_SEC_POSITIONS || k == HLOD_SEC_INDICES ||
                      (k == HLOD_SEC_NORMALS && in->normals) || (k == HLOD_SEC_UVS && in->uvs) ||
                      (k == HLOD_SEC_COLORS && in->colors) || (k == HLOD_SEC_TEXTURE && textured);
        if ((present && sec[k] == 0) || sec[k] > UINT32_MAX)
            BAD(HLOD_ERR_NOMEM, "%s: payload section %d cannot be encoded", name, k);
        ph.section_bytes[k] = (uint32_t)sec[k];
    }
    memcpy(buf, &ph, sizeof ph);
    *out = buf;
    *out_size = at;
    buf = NULL;
done:
    free(buf);
    free(pos);
    free(attr);
    tjFree(jpeg);
    return r;
}

/* ---- unpack ---- */

/* A stream's bytes, with a floor that covers codec headers. */
static uint64_t sb_min(uint32_t bytes) { return (uint64_t)bytes + 64; }

static hlod_result unpack_texture(const uint8_t *src, size_t bytes, const hlod_store_packed_header *ph,
                                  uint8_t *dst, const char *name, uint32_t node,
                                  const hlod_logger *lg)
{
    hlod_result r = HLOD_OK;
    tjhandle tj = tjInitDecompress();
    if (!tj)
        return HLOD_ERR_NOMEM;
    int w = 0, h = 0, sub = 0, cs = 0;
    int gray = ph->tex_channels == 1;
    if (tjDecompressHeader3(tj, src, (unsigned long)bytes, &w, &h, &sub, &cs) != 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: texture is not a JPEG: %s", name, node,
            tjGetErrorStr2(tj));
    if ((uint32_t)w != ph->tex_width || (uint32_t)h != ph->tex_height ||
        (gray != (cs == TJCS_GRAY)))
        BAD(HLOD_ERR_FORMAT, "%s: node %u: JPEG is %dx%d (%s), the node says %ux%ux%u", name,
            node, w, h, cs == TJCS_GRAY ? "gray" : "colour", ph->tex_width, ph->tex_height,
            ph->tex_channels);
    if (tjDecompress2(tj, src, (unsigned long)bytes, dst, w, 0, h, gray ? TJPF_GRAY : TJPF_RGB,
                      TJFLAG_STOPONWARNING | TJFLAG_LIMITSCANS) != 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: cannot decode its JPEG texture: %s", name, node,
            tjGetErrorStr2(tj));
done:
    tjDestroy(tj);
    return r;
}

hlod_result hlod_payload_unpack(const uint8_t *buf, size_t size, const hlod_store_node *n,
                                uint32_t node, double quant_step, uint8_t **out,
                                const char *name, const hlod_logger *lg)
{
    *out = NULL;
    hlod_result r = HLOD_OK;
    uint8_t *raw = NULL;
    uint32_t *tmp = NULL;
    hlod_store_packed_header ph;
    if (size < sizeof ph)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: payload shorter than its header", name, node);
    memcpy(&ph, buf, sizeof ph);
    int reserved_zero = 1;
    for (size_t k = 0; k < sizeof ph.reserved / sizeof ph.reserved[0]; k++)
        reserved_zero &= ph.reserved[k] == 0;
    if (memcmp(ph.magic, HLOD_PACKED_MAGIC, 4) != 0 || !reserved_zero)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: bad packed payload header", name, node);
    if (!hlod_store_counts_agree(n, ph.flags, ph.vertex_count, ph.index_count, ph.tex_tri_count,
                                 ph.tex_width, ph.tex_height, ph.tex_channels))
        BAD(HLOD_ERR_FORMAT, "%s: node %u: payload counts disagree with the node table", name,
            node);
    const uint32_t f = ph.flags;
    const int textured = (f & HLOD_NODE_TEXTURE) != 0;
    uint64_t total = sizeof ph;
    for (int k = 0; k < HLOD_SEC_COUNT; k++) {
        int present = k == HLOD_SEC_POSITIONS || k == HLOD_SEC_INDICES ||
                      (k == HLOD_SEC_NORMALS && (f & HLOD_NODE_NORMALS)) ||
                      (k == HLOD_SEC_UVS && (f & HLOD_NODE_UVS)) ||
                      (k == HLOD_SEC_COLORS && (f & HLOD_NODE_COLORS)) ||
                      (k == HLOD_SEC_TEXTURE && textured);
        if (present != (ph.section_bytes[k] != 0))
            BAD(HLOD_ERR_FORMAT, "%s: node %u: section %d is %u bytes, flags %#x", name, node,
                k, ph.section_bytes[k], f);
        total += ph.section_bytes[k];
    }
    if (total != size)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: sections hold %llu bytes, the payload %zu", name,
            node, (unsigned long long)total, size);
    if (textured ? ph.tex_codec > HLOD_TEX_JPEG : ph.tex_codec != 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: unknown texture codec %u", name, node, ph.tex_codec);
    if (textured && ph.tex_codec == HLOD_TEX_JPEG && ph.tex_channels != 1 && ph.tex_channels != 3)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: a JPEG texture with %u channels", name, node,
            ph.tex_channels);
    if (textured && ph.tex_codec == HLOD_TEX_RAW &&
        ph.section_bytes[HLOD_SEC_TEXTURE] !=
            (uint64_t)ph.tex_width * ph.tex_height * ph.tex_channels)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: raw texture of %u bytes for %ux%ux%u", name, node,
            ph.section_bytes[HLOD_SEC_TEXTURE], ph.tex_width, ph.tex_height, ph.tex_channels);
    for (int k = 0; k < 2; k++)
        if (!isfinite(ph.uv_min[k]) || !isfinite(ph.uv_scale[k]) || ph.uv_scale[k] < 0)
            BAD(HLOD_ERR_NAN, "%s: node %u: non-finite UV range", name, node);

    const size_t v = ph.vertex_count, ic = ph.index_count;
    if ((uint64_t)v * 12 > (uint64_t)sb_min(ph.section_bytes[HLOD_SEC_POSITIONS]) * MAX_VERTEX_BYTES_PER_BYTE ||
        (uint64_t)ic / 3 > (uint64_t)sb_min(ph.section_bytes[HLOD_SEC_INDICES]) * MAX_TRIS_PER_BYTE ||
        (textured && ph.tex_codec == HLOD_TEX_JPEG &&
         (uint64_t)ph.tex_width * ph.tex_height >
             (uint64_t)sb_min(ph.section_bytes[HLOD_SEC_TEXTURE]) * MAX_PIXELS_PER_BYTE))
        BAD(HLOD_ERR_FORMAT, "%s: node %u: %zu vertices, %zu triangles or a %ux%u texture cannot "
            "come from streams this short", name, node, v, ic / 3, ph.tex_width, ph.tex_height);
    uint64_t raw_size = hlod_store_node_memory(n);
    raw = malloc((size_t)raw_size);
    tmp = malloc(12 * v);
    if (!raw || !tmp)
        BAD(HLOD_ERR_NOMEM, "%s: node %u: out of memory decoding its payload", name, node);

    hlod_store_payload_header rh;
    memset(&rh, 0, sizeof rh);
    memcpy(rh.magic, HLOD_PAYLOAD_MAGIC, 4);
    rh.flags = f;
    rh.vertex_count = ph.vertex_count;
    rh.index_count = ph.index_count;
    rh.tex_tri_count = ph.tex_tri_count;
    rh.tex_width = ph.tex_width;
    rh.tex_height = ph.tex_height;
    rh.tex_channels = ph.tex_channels;
    memcpy(raw, &rh, sizeof rh);

    const uint8_t *src = buf + sizeof ph;
    uint8_t *dst = raw + sizeof rh;
    const uint32_t *sb = ph.section_bytes;
    if (meshopt_decodeVertexBuffer(tmp, v, 12, src, sb[HLOD_SEC_POSITIONS]) != 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: bad position stream", name, node);
    src += sb[HLOD_SEC_POSITIONS];
    for (size_t i = 0; i < 3 * v; i++) {
        float p = (float)(((double)tmp[i] + ph.pos_shift[i % 3]) * quant_step);
        memcpy(dst + 4 * i, &p, 4);
    }
    dst += 12 * v;
    if (f & HLOD_NODE_NORMALS) {
        if (meshopt_decodeVertexBuffer(tmp, v, 4, src, sb[HLOD_SEC_NORMALS]) != 0)
            BAD(HLOD_ERR_FORMAT, "%s: node %u: bad normal stream", name, node);
        src += sb[HLOD_SEC_NORMALS];
        const int16_t *o = (const int16_t *)tmp;
        for (size_t i = 0; i < v; i++) {
            float nv[3];
            hlod_oct_decode(o + 2 * i, nv);
            memcpy(dst + 12 * i, nv, 12);
        }
        dst += 12 * v;
    }
    if (f & HLOD_NODE_UVS) {
        if (meshopt_decodeVertexBuffer(tmp, v, 4, src, sb[HLOD_SEC_UVS]) != 0)
            BAD(HLOD_ERR_FORMAT, "%s: node %u: bad UV stream", name, node);
        src += sb[HLOD_SEC_UVS];
        const uint16_t *q = (const uint16_t *)tmp;
        for (size_t i = 0; i < 2 * v; i++) {
            float t = ph.uv_min[i & 1] + (float)q[i] * ph.uv_scale[i & 1];
            memcpy(dst + 4 * i, &t, 4);
        }
        dst += 8 * v;
    }
    if (f & HLOD_NODE_COLORS) {
        if (meshopt_decodeVertexBuffer(dst, v, 4, src, sb[HLOD_SEC_COLORS]) != 0)
            BAD(HLOD_ERR_FORMAT, "%s: node %u: bad colour stream", name, node);
        src += sb[HLOD_SEC_COLORS];
        dst += 4 * v;
    }
    if (meshopt_decodeIndexBuffer(dst, ic, 4, src, sb[HLOD_SEC_INDICES]) != 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: bad index stream", name, node);
    src += sb[HLOD_SEC_INDICES];
    dst += 4 * ic;
    if (textured) {
        if (ph.tex_codec == HLOD_TEX_RAW)
            memcpy(dst, src, sb[HLOD_SEC_TEXTURE]);
        else if ((r = unpack_texture(src, sb[HLOD_SEC_TEXTURE], &ph, dst, name, node, lg)) !=
                 HLOD_OK)
            goto done;
    }
    *out = raw;
    raw = NULL;
done:
    free(raw);
    free(tmp);
    return r;
}
