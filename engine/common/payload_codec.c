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
#include "texture_codec.h"

#include <math.h>
#include <meshoptimizer.h>
#include <stdlib.h>
#include <string.h>
#include <turbojpeg.h>
#include <zstd.h>

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
/* zstd's ceiling: a frame spends at least 3 bytes per 128 KiB block */
#define MAX_BC_BYTES_PER_BYTE 65536u

/* zstd level of block-coded textures: on the default city's facades 19
 * saves a few per cent over 9 at 5x the build time */
#define BC_ZSTD_LEVEL 9

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

/* PSNR of a JPEG against the pixels it was made from (0 when it cannot be
 * decoded, which the caller then treats as unmeasured). */
static double jpeg_db(const hlod_packed_input *in, const uint8_t *jpeg, unsigned long bytes)
{
    size_t n = (size_t)in->tex_width * in->tex_height * in->tex_channels;
    uint8_t *dec = malloc(n);
    tjhandle tj = tjInitDecompress();
    double db = 0;
    if (dec && tj &&
        tjDecompress2(tj, jpeg, bytes, dec, (int)in->tex_width, 0, (int)in->tex_height,
                      in->tex_channels == 1 ? TJPF_GRAY : TJPF_RGB, 0) == 0)
        db = hlod_tex_psnr(in->pixels, dec, n);
    if (tj)
        tjDestroy(tj);
    free(dec);
    return db;
}

/* Level 0 of in's texture as blocks, at the start of a new chain buffer
 * (*chain, malloc'ed, the whole chain's size), and its PSNR: enough to
 * choose a codec; blocks_finish completes the chain when blocks win. */
static hlod_result blocks_top(const hlod_packed_input *in, uint8_t **chain, double *db,
                              const char *name, const hlod_logger *lg)
{
    *chain = NULL;
    *db = 0;
    const uint32_t w = in->tex_width, h = in->tex_height, c = in->tex_channels;
    hlod_result r = HLOD_OK;
    size_t total = hlod_bc_chain_bytes(w, h), n = (size_t)w * h * c;
    uint8_t *blocks = total ? malloc(total) : NULL, *dec = malloc(n);
    if (!blocks || !dec)
        BAD(HLOD_ERR_NOMEM, "%s: out of memory coding a %ux%u texture as blocks", name, w, h);
    hlod_bc_encode_top(in->pixels, w, h, c, blocks);
    hlod_bc_decode_level(blocks, w, h, c, dec, c);
    *db = hlod_tex_psnr(in->pixels, dec, n);
    *chain = blocks;
    blocks = NULL;
done:
    free(blocks);
    free(dec);
    return r;
}

/* The levels below level 0 into chain, then the chain zstd-coded into *out
 * (malloc'ed). */
static hlod_result blocks_finish(const hlod_packed_input *in, uint8_t *chain, uint8_t **out,
                                 size_t *bytes, const char *name, const hlod_logger *lg)
{
    *out = NULL;
    *bytes = 0;
    const uint32_t w = in->tex_width, h = in->tex_height, c = in->tex_channels;
    hlod_result r = hlod_bc_encode_below(in->pixels, w, h, c, chain);
    uint8_t *z = NULL;
    if (r != HLOD_OK)
        BAD(r, "%s: out of memory coding a %ux%u texture as blocks", name, w, h);
    size_t size = hlod_bc_chain_bytes(w, h), room = ZSTD_compressBound(size);
    z = malloc(room);
    if (!z)
        BAD(HLOD_ERR_NOMEM, "%s: out of memory coding a %ux%u texture as blocks", name, w, h);
    size_t zn = ZSTD_compress(z, room, chain, size, BC_ZSTD_LEVEL);
    if (ZSTD_isError(zn))
        BAD(HLOD_ERR_NOMEM, "%s: zstd cannot code a %ux%u texture: %s", name, w, h,
            ZSTD_getErrorName(zn));
    *out = z;
    *bytes = zn;
    z = NULL;
done:
    free(z);
    return r;
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

/* How a texture is stored: its codec and bytes (bc: malloc'ed, jpeg:
 * libturbojpeg's; raw: none, the input's pixels). */
typedef struct packed_texture {
    uint32_t codec, levels;
    double db;
    uint8_t *bc, *jpeg;
    size_t bc_bytes;
    unsigned long jpeg_bytes;
} packed_texture;

/* Blocks where they reach the floor; under it JPEG where that comes closer
 * to the source, raw (exact) without JPEG, else the blocks after all. */
static hlod_result choose_texture(const hlod_packed_input *in, packed_texture *t,
                                  const char *name, const hlod_logger *lg)
{
    hlod_result r = HLOD_OK;
    uint8_t *chain = NULL; /* level 0's blocks, the rest only once blocks win */
    size_t raw_tex = (size_t)in->tex_width * in->tex_height * in->tex_channels;
    int jpeg_ok = in->tex_width <= JPEG_MAX_SIDE && in->tex_height <= JPEG_MAX_SIDE;
    if (!(in->jpeg_quality > 0 && jpeg_ok) && raw_tex > UINT32_MAX)
        BAD(HLOD_ERR_INVALID_ARG, "%s: a %ux%ux%u texture is %zu bytes, over the 4 GiB a "
            "payload section holds", name, in->tex_width, in->tex_height, in->tex_channels,
            raw_tex);
    int grey_or_rgb = in->tex_channels == 1 || in->tex_channels == 3;
    double bc_db = 0;
    if (in->texture_blocks && grey_or_rgb &&
        (r = blocks_top(in, &chain, &bc_db, name, lg)) != HLOD_OK)
        goto done;
    t->db = bc_db;
    if ((!chain || bc_db < in->texture_min_db) && in->jpeg_quality > 0 && jpeg_ok &&
        grey_or_rgb) {
        if ((r = pack_texture(in, &t->jpeg, &t->jpeg_bytes, name, lg)) != HLOD_OK)
            goto done;
        t->db = in->texture_blocks ? jpeg_db(in, t->jpeg, t->jpeg_bytes) : 0;
        if (chain && t->db <= bc_db) {
            tjFree(t->jpeg);
            t->jpeg = NULL;
            t->db = bc_db;
        }
    }
    if (chain && !t->jpeg && (bc_db >= in->texture_min_db || in->jpeg_quality > 0)) {
        if ((r = blocks_finish(in, chain, &t->bc, &t->bc_bytes, name, lg)) != HLOD_OK)
            goto done;
        t->codec = HLOD_TEX_BC;
        t->levels = hlod_tex_level_count(in->tex_width, in->tex_height);
    } else if (t->jpeg) {
        t->codec = HLOD_TEX_JPEG;
    } else {
        t->codec = HLOD_TEX_RAW;
        t->db = 0;
    }
done:
    free(chain);
    return r;
}

hlod_result hlod_payload_pack(const hlod_packed_input *in, uint8_t **out, size_t *out_size,
                              hlod_packed_info *info, const char *name, const hlod_logger *lg)
{
    *out = NULL;
    *out_size = 0;
    if (info)
        memset(info, 0, sizeof *info);
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
    packed_texture tx = {0};
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
    if (textured && (r = choose_texture(in, &tx, name, lg)) != HLOD_OK)
        goto done;
    ph.tex_codec = tx.codec;
    ph.tex_levels = tx.levels;
    ph.tex_db = (float)tx.db;
    size_t tex_raw = textured ? (size_t)in->tex_width * in->tex_height * in->tex_channels : 0;
    size_t tex_bytes = ph.tex_codec == HLOD_TEX_JPEG ? (size_t)tx.jpeg_bytes
                       : ph.tex_codec == HLOD_TEX_BC ? tx.bc_bytes : tex_raw;
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
        memcpy(buf + at, ph.tex_codec == HLOD_TEX_JPEG ? tx.jpeg
                         : ph.tex_codec == HLOD_TEX_BC ? tx.bc : in->pixels, tex_bytes);
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
    if (info) {
        info->tex_codec = textured ? ph.tex_codec : 0;
        info->tex_db = ph.tex_db;
    }
done:
    free(buf);
    free(pos);
    free(attr);
    free(tx.bc);
    tjFree(tx.jpeg);
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

/* The block-coded texture section src (bytes) of ph: zstd undone into a new
 * chain, then made what texout asks into *u (apart) or into dst (level 0
 * texels inside the raw layout). */
static hlod_result unpack_blocks(const uint8_t *src, size_t bytes, const hlod_store_packed_header *ph,
                                 int texout, uint8_t *dst, hlod_unpacked *u, const char *name,
                                 uint32_t node, const hlod_logger *lg)
{
    hlod_result r = HLOD_OK;
    const uint32_t w = ph->tex_width, h = ph->tex_height, c = ph->tex_channels;
    const size_t chain = hlod_bc_chain_bytes(w, h);
    uint8_t *blocks = NULL, *texels = NULL;
    unsigned long long fs = ZSTD_getFrameContentSize(src, bytes);
    if (fs != chain)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: block texture frame holds %llu bytes, a %ux%u chain "
            "%zu", name, node, fs, w, h, chain);
    blocks = malloc(chain);
    if (!blocks)
        BAD(HLOD_ERR_NOMEM, "%s: node %u: out of memory decoding its texture", name, node);
    size_t got = ZSTD_decompress(blocks, chain, src, bytes);
    if (ZSTD_isError(got) || got != chain)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: bad block texture stream: %s", name, node,
            ZSTD_isError(got) ? ZSTD_getErrorName(got) : "short");
    if (texout == HLOD_TEXOUT_BLOCKS) {
        u->tex = blocks;
        u->tex_levels = ph->tex_levels;
        u->tex_format = HLOD_TEXFMT_BC;
        u->tex_channels = c;
        return HLOD_OK;
    }
    if (texout == HLOD_TEXOUT_PIXELS) {
        hlod_bc_decode_level(blocks, w, h, c, dst, c);
        goto done;
    }
    uint32_t oc = 0;
    texels = hlod_bc_decode_chain(blocks, w, h, c, &oc);
    if (!texels)
        BAD(HLOD_ERR_NOMEM, "%s: node %u: out of memory decoding its texture", name, node);
    u->tex = texels;
    u->tex_levels = ph->tex_levels;
    u->tex_format = HLOD_TEXFMT_TEXELS;
    u->tex_channels = oc;
    texels = NULL;
done:
    free(blocks);
    free(texels);
    return r;
}

/* The packed header's texture fields against its version and counts. */
static hlod_result check_texture_fields(const hlod_store_packed_header *ph,
                                        const hlod_store_header *h, const char *name,
                                        uint32_t node, const hlod_logger *lg)
{
    hlod_result r = HLOD_OK;
    const int textured = (ph->flags & HLOD_NODE_TEXTURE) != 0;
    const int bc = textured && ph->tex_codec == HLOD_TEX_BC;
    const uint32_t max_codec = h->version >= 5 ? HLOD_TEX_BC : HLOD_TEX_JPEG;
    if (textured ? ph->tex_codec > max_codec : ph->tex_codec != 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: unknown texture codec %u", name, node, ph->tex_codec);
    if (bc ? ph->tex_levels != hlod_tex_level_count(ph->tex_width, ph->tex_height) ||
                 (ph->tex_channels != 1 && ph->tex_channels != 3)
           : ph->tex_levels != 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: %u texture levels for a %ux%ux%u texture of codec %u",
            name, node, ph->tex_levels, ph->tex_width, ph->tex_height, ph->tex_channels,
            ph->tex_codec);
    if (!isfinite(ph->tex_db) || ph->tex_db < 0 || (h->version < 5 && ph->tex_db != 0))
        BAD(HLOD_ERR_FORMAT, "%s: node %u: bad texture PSNR field", name, node);
    if (textured && ph->tex_codec == HLOD_TEX_JPEG && ph->tex_channels != 1 && ph->tex_channels != 3)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: a JPEG texture with %u channels", name, node,
            ph->tex_channels);
    if (textured && ph->tex_codec == HLOD_TEX_RAW &&
        ph->section_bytes[HLOD_SEC_TEXTURE] !=
            (uint64_t)ph->tex_width * ph->tex_height * ph->tex_channels)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: raw texture of %u bytes for %ux%ux%u", name, node,
            ph->section_bytes[HLOD_SEC_TEXTURE], ph->tex_width, ph->tex_height, ph->tex_channels);
done:
    return r;
}

hlod_result hlod_payload_unpack(const uint8_t *buf, size_t size, const hlod_store_node *n,
                                uint32_t node, const hlod_store_header *h, int texout,
                                hlod_unpacked *out, const char *name, const hlod_logger *lg)
{
    memset(out, 0, sizeof *out);
    hlod_result r = HLOD_OK;
    uint8_t *raw = NULL;
    uint32_t *tmp = NULL;
    const double quant_step = h->quant_step;
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
    if ((r = check_texture_fields(&ph, h, name, node, lg)) != HLOD_OK)
        goto done;
    const int bc = textured && ph.tex_codec == HLOD_TEX_BC;
    for (int k = 0; k < 2; k++)
        if (!isfinite(ph.uv_min[k]) || !isfinite(ph.uv_scale[k]) || ph.uv_scale[k] < 0)
            BAD(HLOD_ERR_NAN, "%s: node %u: non-finite UV range", name, node);

    const size_t v = ph.vertex_count, ic = ph.index_count;
    if ((uint64_t)v * 12 > (uint64_t)sb_min(ph.section_bytes[HLOD_SEC_POSITIONS]) * MAX_VERTEX_BYTES_PER_BYTE ||
        (uint64_t)ic / 3 > (uint64_t)sb_min(ph.section_bytes[HLOD_SEC_INDICES]) * MAX_TRIS_PER_BYTE ||
        (textured && ph.tex_codec == HLOD_TEX_JPEG &&
         (uint64_t)ph.tex_width * ph.tex_height >
             (uint64_t)sb_min(ph.section_bytes[HLOD_SEC_TEXTURE]) * MAX_PIXELS_PER_BYTE) ||
        (bc && (uint64_t)hlod_bc_chain_bytes(ph.tex_width, ph.tex_height) >
                   (uint64_t)sb_min(ph.section_bytes[HLOD_SEC_TEXTURE]) * MAX_BC_BYTES_PER_BYTE))
        BAD(HLOD_ERR_FORMAT, "%s: node %u: %zu vertices, %zu triangles or a %ux%u texture cannot "
            "come from streams this short", name, node, v, ic / 3, ph.tex_width, ph.tex_height);
    /* a chain kept apart leaves the raw layout without level 0 */
    const int apart = bc && texout != HLOD_TEXOUT_PIXELS;
    uint64_t raw_size = hlod_store_node_memory(n) -
                        (apart ? (uint64_t)ph.tex_width * ph.tex_height * ph.tex_channels : 0);
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
        else if (bc)
            r = unpack_blocks(src, sb[HLOD_SEC_TEXTURE], &ph, texout, dst, out, name, node, lg);
        else
            r = unpack_texture(src, sb[HLOD_SEC_TEXTURE], &ph, dst, name, node, lg);
        if (r != HLOD_OK)
            goto done;
    }
    out->raw = raw;
    out->raw_size = raw_size;
    raw = NULL;
done:
    free(raw);
    free(tmp);
    if (r != HLOD_OK) {
        free(out->tex);
        memset(out, 0, sizeof *out);
    }
    return r;
}
