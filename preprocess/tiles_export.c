/*
 * tiles_export.c - an hlod store as a 3D Tiles 1.1 tileset (tiles3d.h).
 *
 * Workers take nodes in index order from an atomic counter; each reads its
 * node's payload (decoded; for a packed store its JPEG texture bytes are
 * taken from the payload as they are, before decoding, so a texture is not
 * coded twice), builds the node's .glb in memory and writes it into the
 * temporary folder.  The calling thread draws the progress and then writes
 * tileset.json from the node table alone.
 */
#define _GNU_SOURCE 1
#include "tiles3d.h"

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <cjson/cJSON.h>
#include <meshoptimizer.h>
#include <turbojpeg.h>

#include "atomic_file.h"
#include "hlod/image.h"

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "tiles_export.c writes glb buffers from host integers: little-endian only"
#endif

/* glTF constants */
#define GL_BYTE_ 5120
#define GL_UBYTE_ 5121
#define GL_SHORT_ 5122
#define GL_USHORT_ 5123
#define GL_UINT_ 5125
#define GL_FLOAT_ 5126
#define GL_ARRAY_BUFFER_ 34962
#define GL_ELEMENT_ARRAY_BUFFER_ 34963

#define RENDER_GREY 0.8     /* engine/gl_render.c DEFAULT_GREY: an sRGB value */

static double srgb_to_linear(double c)
{
    return c <= 0.04045 ? c / 12.92 : pow((c + 0.055) / 1.055, 2.4);
}

/* ---- a growing byte buffer, sections 4-byte aligned ---- */

typedef struct bytes {
    uint8_t *p;
    size_t len, cap;
    int oom;
} bytes;

static int bytes_reserve(bytes *b, size_t more)
{
    if (b->oom)
        return 0;
    if (b->len + more <= b->cap)
        return 1;
    size_t cap = b->cap ? b->cap : 4096;
    while (cap < b->len + more)
        cap *= 2;
    uint8_t *p = realloc(b->p, cap);
    if (!p) {
        b->oom = 1;
        return 0;
    }
    b->p = p;
    b->cap = cap;
    return 1;
}

/* Pads to 4 bytes with `pad`, then appends n bytes (data NULL: zeros);
 * returns the offset they start at. */
static size_t bytes_put(bytes *b, const void *data, size_t n, uint8_t pad)
{
    size_t fill = (4 - b->len % 4) % 4;
    if (!bytes_reserve(b, fill + n))
        return 0;
    memset(b->p + b->len, pad, fill);
    b->len += fill;
    size_t at = b->len;
    if (data)
        memcpy(b->p + at, data, n);
    else
        memset(b->p + at, 0, n);
    b->len += n;
    return at;
}

/* ---- JSON helpers ---- */

/* A number that reads back as exactly v: cJSON prints 15 digits when they
 * come within an epsilon of v, which may be an ulp off (a geometricError
 * that is not the node's error, a transform a nanometre off), so a finite
 * double goes in as the shortest of %.15g, %.16g, %.17g that round-trips. */
static cJSON *json_num(double v)
{
    if (!isfinite(v))
        return cJSON_CreateNull();
    char b[40];
    for (int digits = 15; digits <= 17; digits++) {
        snprintf(b, sizeof b, "%.*g", digits, v);
        if (strtod(b, NULL) == v)
            break;
    }
    return cJSON_CreateRaw(b);
}

static void add_num(cJSON *o, const char *key, double v)
{
    cJSON_AddItemToObject(o, key, json_num(v));
}

static cJSON *num_array(const double *v, int n)
{
    cJSON *a = cJSON_CreateArray();
    for (int i = 0; a && i < n; i++)
        cJSON_AddItemToArray(a, json_num(v[i]));
    return a;
}

/* ---- one node's glb ---- */

typedef struct view {           /* one vertex or index stream */
    const uint8_t *data;        /* plain bytes */
    size_t count, stride;       /* elements and bytes each (indices: count = indices) */
    int is_index;
    uint8_t *coded;             /* meshopt-coded, or NULL */
    size_t coded_len;
} view;

typedef struct glb_out {
    int meshopt, float_positions, jpeg_copied;
    size_t texture_bytes;
} glb_out;

typedef struct job {
    const hlod_store *s;
    const hlod_store_header *h;
    const hlod_store_node *nodes;
    const char *tmp_dir;
    const hlod_tiles_export_desc *desc;
    double tol_floor;           /* max(grid step, 1e-6 x diagonal) */
    atomic_uint next;
    atomic_uint done;
    atomic_int failed;
    pthread_mutex_t lock;       /* the totals below */
    hlod_result result;
    hlod_tiles_export_stats st;
} job;

/* The texture as an encoded image: the store's JPEG when it holds one,
 * else JPEG (1 or 3 channels) or PNG (2 or 4, through OpenImageIO and a
 * file in the temporary folder). */
static hlod_result encode_texture(const job *J, uint32_t node, const hlod_store_payload *p,
                                  uint8_t **img, size_t *img_len, const char **mime)
{
    const hlod_logger *lg = J->desc->logger;
    const char *name = hlod_store_path(J->s);
    *img = NULL;
    *img_len = 0;
    if (p->tex_channels == 1 || p->tex_channels == 3) {
        tjhandle tj = tjInitCompress();
        if (!tj)
            return HLOD_ERR_NOMEM;
        unsigned char *jpeg = NULL;
        unsigned long len = 0;
        int gray = p->tex_channels == 1;
        int q = J->desc->jpeg_quality > 0 ? J->desc->jpeg_quality : 90;
        int rc = tjCompress2(tj, p->pixels, (int)p->tex_width, 0, (int)p->tex_height,
                             gray ? TJPF_GRAY : TJPF_RGB, &jpeg, &len,
                             gray ? TJSAMP_GRAY : TJSAMP_444, q, TJFLAG_ACCURATEDCT);
        if (rc != 0) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u: cannot encode its %ux%u texture as JPEG: %s",
                     name, node, p->tex_width, p->tex_height, tjGetErrorStr2(tj));
            tjDestroy(tj);
            return HLOD_ERR_FORMAT;
        }
        tjDestroy(tj);
        *img = malloc(len ? len : 1);
        if (!*img) {
            tjFree(jpeg);
            return HLOD_ERR_NOMEM;
        }
        memcpy(*img, jpeg, len);
        tjFree(jpeg);
        *img_len = len;
        *mime = "image/jpeg";
        return HLOD_OK;
    }
    /* 2 or 4 channels: PNG keeps the alpha */
    char path[PATH_MAX];
    snprintf(path, sizeof path, "%s/.texture-%u.png", J->tmp_dir, node);
    hlod_image im = {(int)p->tex_width, (int)p->tex_height, (int)p->tex_channels,
                     (uint8_t *)p->pixels};
    hlod_result r = hlod_image_write(path, &im, lg);
    if (r != HLOD_OK)
        return r;
    FILE *fp = fopen(path, "rb");
    if (!fp) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %s", path, strerror(errno));
        return HLOD_ERR_IO;
    }
    fseek(fp, 0, SEEK_END);
    long len = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    *img = len > 0 ? malloc((size_t)len) : NULL;
    if (!*img || fread(*img, 1, (size_t)len, fp) != (size_t)len) {
        fclose(fp);
        unlink(path);
        free(*img);
        *img = NULL;
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read back the PNG", path);
        return HLOD_ERR_IO;
    }
    fclose(fp);
    unlink(path);
    *img_len = (size_t)len;
    *mime = "image/png";
    return HLOD_OK;
}

/* The JPEG bytes of a packed payload's texture section, or NULL. */
static const uint8_t *packed_jpeg(const hlod_store_header *h, const uint8_t *buf, size_t size,
                                  size_t *len)
{
    *len = 0;
    if (h->payload_codec != HLOD_STORE_CODEC_PACKED || size < sizeof(hlod_store_packed_header))
        return NULL;
    hlod_store_packed_header ph;
    memcpy(&ph, buf, sizeof ph);
    if (memcmp(ph.magic, HLOD_PACKED_MAGIC, 4) != 0 || ph.tex_codec != HLOD_TEX_JPEG)
        return NULL;
    size_t at = sizeof ph;
    for (int k = 0; k < HLOD_SEC_TEXTURE; k++)
        at += ph.section_bytes[k];
    if (at + ph.section_bytes[HLOD_SEC_TEXTURE] > size || ph.section_bytes[HLOD_SEC_TEXTURE] == 0)
        return NULL;
    *len = ph.section_bytes[HLOD_SEC_TEXTURE];
    return buf + at;
}

static void add_accessor(cJSON *accs, int view_index, size_t offset, int comp, size_t count,
                         const char *type, int normalized, const double *mn, const double *mx,
                         int nmm)
{
    cJSON *a = cJSON_CreateObject();
    cJSON_AddNumberToObject(a, "bufferView", view_index);
    if (offset)
        cJSON_AddNumberToObject(a, "byteOffset", (double)offset);
    cJSON_AddNumberToObject(a, "componentType", comp);
    if (normalized)
        cJSON_AddTrueToObject(a, "normalized");
    cJSON_AddNumberToObject(a, "count", (double)count);
    cJSON_AddStringToObject(a, "type", type);
    if (mn) {
        cJSON_AddItemToObject(a, "min", num_array(mn, nmm));
        cJSON_AddItemToObject(a, "max", num_array(mx, nmm));
    }
    cJSON_AddItemToArray(accs, a);
}

/* Builds node i's glb from payload p (raw: its read bytes before decoding,
 * for the JPEG texture). */
static hlod_result node_glb(job *J, uint32_t i, const hlod_store_payload *p,
                            const uint8_t *raw, size_t raw_len, bytes *glb, glb_out *go)
{
    const hlod_store_node *n = &J->nodes[i];
    const hlod_logger *lg = J->desc->logger;
    hlod_result r = HLOD_OK;
    size_t nv = p->vertex_count, ni = p->index_count;
    memset(go, 0, sizeof *go);

    /* positions in glTF's frame: (x, z, -y) */
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t v = 0; v < nv; v++) {
        const float *q = p->positions + 3 * v;
        double g[3] = {q[0], q[2], -(double)q[1]};
        for (int k = 0; k < 3; k++) {
            lo[k] = fmin(lo[k], g[k]);
            hi[k] = fmax(hi[k], g[k]);
        }
    }
    double extent = fmax(fmax(hi[0] - lo[0], hi[1] - lo[1]), hi[2] - lo[2]);
    double step = extent > 0 ? extent / 65535.0 : 1.0;
    if (J->h->quant_step > 0 && extent > 0) {  /* a power-of-two multiple of the grid */
        double s = J->h->quant_step;
        while (s < step)
            s *= 2;
        step = s;
    }
    double tol = fmax(J->tol_floor, 0.1 * n->error);
    int quantize = 0.5 * step <= tol && extent / step <= 65535.0;

    uint8_t *pos = NULL, *nrm = NULL, *uv = NULL, *col = NULL, *idx = NULL, *img = NULL;
    size_t pos_stride = quantize ? 8 : 12, uv_stride = 4;
    double pmin[3], pmax[3];
    int uv_quant = 1;
    size_t img_len = 0;
    const char *mime = NULL;
    cJSON *root = NULL;
    view views[5];
    int nviews = 0;

    pos = malloc(nv * pos_stride + 1);
    if (!pos)
        return HLOD_ERR_NOMEM;
    for (int k = 0; k < 3; k++) {
        pmin[k] = INFINITY;
        pmax[k] = -INFINITY;
    }
    for (size_t v = 0; v < nv; v++) {
        const float *q = p->positions + 3 * v;
        double g[3] = {q[0], q[2], -(double)q[1]};
        if (quantize) {
            uint16_t o[4] = {0, 0, 0, 0};
            for (int k = 0; k < 3; k++) {
                double t = nearbyint((g[k] - lo[k]) / step);
                o[k] = (uint16_t)(t < 0 ? 0 : t > 65535 ? 65535 : t);
                pmin[k] = fmin(pmin[k], o[k]);
                pmax[k] = fmax(pmax[k], o[k]);
            }
            memcpy(pos + 8 * v, o, 8);
        } else {
            float o[3] = {(float)g[0], (float)g[1], (float)g[2]};
            for (int k = 0; k < 3; k++) {
                pmin[k] = fmin(pmin[k], o[k]);
                pmax[k] = fmax(pmax[k], o[k]);
            }
            memcpy(pos + 12 * v, o, 12);
        }
    }
    go->float_positions = !quantize;
    views[nviews++] = (view){pos, nv, pos_stride, 0, NULL, 0};

    int has_n = p->normals != NULL, has_uv = p->uvs != NULL, has_c = p->colors != NULL;
    if (has_n) {
        nrm = malloc(nv * 8 + 1);
        if (!nrm)
            goto nomem;
        for (size_t v = 0; v < nv; v++) {
            const float *q = p->normals + 3 * v;
            double g[3] = {q[0], q[2], -(double)q[1]};
            double len = sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
            if (!(len > 1e-12)) {   /* no direction: up */
                g[0] = 0, g[1] = 1, g[2] = 0;
                len = 1;
            }
            int16_t o[4] = {0, 0, 0, 0};
            for (int k = 0; k < 3; k++)
                o[k] = (int16_t)lrint(g[k] / len * 32767.0);
            memcpy(nrm + 8 * v, o, 8);
        }
        views[nviews++] = (view){nrm, nv, 8, 0, NULL, 0};
    }
    if (has_uv) {
        for (size_t v = 0; v < 2 * nv && uv_quant; v++)
            uv_quant = p->uvs[v] >= 0.0f && p->uvs[v] <= 1.0f;
        uv_stride = uv_quant ? 4 : 8;
        uv = malloc(nv * uv_stride + 1);
        if (!uv)
            goto nomem;
        for (size_t v = 0; v < nv; v++) {
            float t[2] = {p->uvs[2 * v], 1.0f - p->uvs[2 * v + 1]};  /* glTF: v down */
            if (uv_quant) {
                uint16_t o[2] = {(uint16_t)lrint(fmin(fmax(t[0], 0), 1) * 65535.0),
                                 (uint16_t)lrint(fmin(fmax(t[1], 0), 1) * 65535.0)};
                memcpy(uv + 4 * v, o, 4);
            } else {
                memcpy(uv + 8 * v, t, 8);
            }
        }
        views[nviews++] = (view){uv, nv, uv_stride, 0, NULL, 0};
    }
    if (has_c) {
        col = malloc(nv * 8 + 1);
        if (!col)
            goto nomem;
        for (size_t v = 0; v < nv; v++) {
            uint16_t o[4];
            for (int k = 0; k < 3; k++)
                o[k] = (uint16_t)lrint(srgb_to_linear(p->colors[4 * v + k] / 255.0) * 65535.0);
            o[3] = (uint16_t)(p->colors[4 * v + 3] * 257u);
            memcpy(col + 8 * v, o, 8);
        }
        views[nviews++] = (view){col, nv, 8, 0, NULL, 0};
    }
    int idx16 = nv <= 65535;
    size_t isz = idx16 ? 2 : 4;
    idx = malloc(ni * isz + 1);
    if (!idx)
        goto nomem;
    for (size_t t = 0; t < ni; t++) {
        if (idx16) {
            uint16_t o = (uint16_t)p->indices[t];
            memcpy(idx + 2 * t, &o, 2);
        } else {
            memcpy(idx + 4 * t, &p->indices[t], 4);
        }
    }
    views[nviews++] = (view){idx, ni, isz, 1, NULL, 0};

    /* EXT_meshopt_compression: code every view, keep it when it pays */
    int meshopt = 0;
    if (J->desc->meshopt != HLOD_MESHOPT_NEVER) {
        size_t plain = 0, coded = 0;
        for (int k = 0; k < nviews; k++) {
            view *w = &views[k];
            size_t bound = w->is_index ? meshopt_encodeIndexBufferBound(w->count, nv)
                                       : meshopt_encodeVertexBufferBound(w->count, w->stride);
            w->coded = malloc(bound + 1);
            if (!w->coded)
                goto nomem;
            w->coded_len = w->is_index
                ? meshopt_encodeIndexBuffer(w->coded, bound, p->indices, w->count)
                : meshopt_encodeVertexBuffer(w->coded, bound, w->data, w->count, w->stride);
            if (w->coded_len == 0) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u: meshoptimizer could not code a stream",
                         hlod_store_path(J->s), i);
                r = HLOD_ERR_FORMAT;
                goto done;
            }
            plain += w->count * w->stride;
            coded += w->coded_len;
        }
        meshopt = J->desc->meshopt == HLOD_MESHOPT_ALWAYS || coded < 0.9 * (double)plain;
    }
    go->meshopt = meshopt;

    /* the texture */
    int textured = (p->flags & HLOD_NODE_TEXTURE) && p->pixels && p->tex_tri_count > 0;
    const uint8_t *store_jpeg = NULL;
    size_t store_jpeg_len = 0;
    if (textured) {
        store_jpeg = packed_jpeg(J->h, raw, raw_len, &store_jpeg_len);
        if (store_jpeg) {
            mime = "image/jpeg";
            go->jpeg_copied = 1;
        } else if ((r = encode_texture(J, i, p, &img, &img_len, &mime)) != HLOD_OK) {
            goto done;
        }
    }

    /* the binary chunk and the JSON */
    bytes bin = {0};
    root = cJSON_CreateObject();
    cJSON *asset = cJSON_AddObjectToObject(root, "asset");
    cJSON_AddStringToObject(asset, "version", "2.0");
    cJSON_AddStringToObject(asset, "generator", "hlod-export-3dtiles");
    cJSON *used = cJSON_AddArrayToObject(root, "extensionsUsed");
    cJSON *required = cJSON_AddArrayToObject(root, "extensionsRequired");
    if (quantize || has_n || (has_uv && uv_quant) || has_c) {
        cJSON_AddItemToArray(used, cJSON_CreateString("KHR_mesh_quantization"));
        cJSON_AddItemToArray(required, cJSON_CreateString("KHR_mesh_quantization"));
    }
    if (meshopt) {
        cJSON_AddItemToArray(used, cJSON_CreateString("EXT_meshopt_compression"));
        cJSON_AddItemToArray(required, cJSON_CreateString("EXT_meshopt_compression"));
    }
    if (cJSON_GetArraySize(used) == 0) {
        cJSON_DeleteItemFromObject(root, "extensionsUsed");
        cJSON_DeleteItemFromObject(root, "extensionsRequired");
    }
    cJSON_AddNumberToObject(root, "scene", 0);
    cJSON *scene = cJSON_CreateObject();
    cJSON *scene_nodes = cJSON_AddArrayToObject(scene, "nodes");
    cJSON_AddItemToArray(scene_nodes, cJSON_CreateNumber(0));
    cJSON *scenes = cJSON_AddArrayToObject(root, "scenes");
    cJSON_AddItemToArray(scenes, scene);
    cJSON *gnode = cJSON_CreateObject();
    char nname[32];
    snprintf(nname, sizeof nname, "node %u", i);
    cJSON_AddStringToObject(gnode, "name", nname);
    cJSON_AddNumberToObject(gnode, "mesh", 0);
    if (quantize) {
        double sc[3] = {step, step, step};
        cJSON_AddItemToObject(gnode, "translation", num_array(lo, 3));
        cJSON_AddItemToObject(gnode, "scale", num_array(sc, 3));
    }
    cJSON *gnodes = cJSON_AddArrayToObject(root, "nodes");
    cJSON_AddItemToArray(gnodes, gnode);

    /* buffer 0: the glb's BIN chunk; with meshopt, buffer 1 is the
     * decoded views' fallback, which holds no bytes */
    cJSON *bviews = cJSON_AddArrayToObject(root, "bufferViews");
    size_t fallback_len = 0;
    for (int k = 0; k < nviews; k++) {
        view *w = &views[k];
        size_t plain_len = w->count * w->stride;
        cJSON *bv = cJSON_CreateObject();
        if (meshopt) {
            size_t at = bytes_put(&bin, w->coded, w->coded_len, 0);
            fallback_len = (fallback_len + 3) / 4 * 4;
            cJSON_AddNumberToObject(bv, "buffer", 1);
            cJSON_AddNumberToObject(bv, "byteOffset", (double)fallback_len);
            cJSON_AddNumberToObject(bv, "byteLength", (double)plain_len);
            fallback_len += plain_len;
            cJSON *ext = cJSON_AddObjectToObject(cJSON_AddObjectToObject(bv, "extensions"),
                                                 "EXT_meshopt_compression");
            cJSON_AddNumberToObject(ext, "buffer", 0);
            cJSON_AddNumberToObject(ext, "byteOffset", (double)at);
            cJSON_AddNumberToObject(ext, "byteLength", (double)w->coded_len);
            cJSON_AddNumberToObject(ext, "byteStride", (double)w->stride);
            cJSON_AddNumberToObject(ext, "count", (double)w->count);
            cJSON_AddStringToObject(ext, "mode", w->is_index ? "TRIANGLES" : "ATTRIBUTES");
        } else {
            size_t at = bytes_put(&bin, w->data, plain_len, 0);
            cJSON_AddNumberToObject(bv, "buffer", 0);
            if (at)
                cJSON_AddNumberToObject(bv, "byteOffset", (double)at);
            cJSON_AddNumberToObject(bv, "byteLength", (double)plain_len);
        }
        if (!w->is_index)
            cJSON_AddNumberToObject(bv, "byteStride", (double)w->stride);
        cJSON_AddNumberToObject(bv, "target",
                                w->is_index ? GL_ELEMENT_ARRAY_BUFFER_ : GL_ARRAY_BUFFER_);
        cJSON_AddItemToArray(bviews, bv);
    }
    int img_view = -1;
    if (textured) {
        const uint8_t *src = store_jpeg ? store_jpeg : img;
        size_t len = store_jpeg ? store_jpeg_len : img_len;
        size_t at = bytes_put(&bin, src, len, 0);
        cJSON *bv = cJSON_CreateObject();
        cJSON_AddNumberToObject(bv, "buffer", 0);
        if (at)
            cJSON_AddNumberToObject(bv, "byteOffset", (double)at);
        cJSON_AddNumberToObject(bv, "byteLength", (double)len);
        img_view = cJSON_GetArraySize(bviews);
        cJSON_AddItemToArray(bviews, bv);
        go->texture_bytes = len;
    }
    bytes_put(&bin, NULL, 0, 0);    /* pad the chunk to 4 */
    cJSON *buffers = cJSON_AddArrayToObject(root, "buffers");
    cJSON *b0 = cJSON_CreateObject();
    cJSON_AddNumberToObject(b0, "byteLength", (double)bin.len);
    cJSON_AddItemToArray(buffers, b0);
    if (meshopt) {
        cJSON *b1 = cJSON_CreateObject();
        cJSON_AddNumberToObject(b1, "byteLength", (double)fallback_len);
        cJSON_AddTrueToObject(cJSON_AddObjectToObject(cJSON_AddObjectToObject(b1, "extensions"),
                                                      "EXT_meshopt_compression"),
                              "fallback");
        cJSON_AddItemToArray(buffers, b1);
    }

    /* accessors: 0 positions, then normals, UVs, colours, then the two
     * primitives' indices */
    cJSON *accs = cJSON_AddArrayToObject(root, "accessors");
    int vi = 0, a_pos, a_n = -1, a_uv = -1, a_c = -1;
    a_pos = cJSON_GetArraySize(accs);
    add_accessor(accs, vi++, 0, quantize ? GL_USHORT_ : GL_FLOAT_, nv, "VEC3", 0, pmin, pmax, 3);
    if (has_n) {
        a_n = cJSON_GetArraySize(accs);
        add_accessor(accs, vi++, 0, GL_SHORT_, nv, "VEC3", 1, NULL, NULL, 0);
    }
    if (has_uv) {
        a_uv = cJSON_GetArraySize(accs);
        add_accessor(accs, vi++, 0, uv_quant ? GL_USHORT_ : GL_FLOAT_, nv, "VEC2", uv_quant, NULL,
                     NULL, 0);
    }
    if (has_c) {
        a_c = cJSON_GetArraySize(accs);
        add_accessor(accs, vi++, 0, GL_USHORT_, nv, "VEC4", 1, NULL, NULL, 0);
    }
    size_t tex_idx = textured ? 3 * (size_t)p->tex_tri_count : 0;
    int a_i0 = -1, a_i1 = -1;
    if (tex_idx > 0) {
        a_i0 = cJSON_GetArraySize(accs);
        add_accessor(accs, vi, 0, idx16 ? GL_USHORT_ : GL_UINT_, tex_idx, "SCALAR", 0, NULL, NULL, 0);
    }
    if (ni > tex_idx) {
        a_i1 = cJSON_GetArraySize(accs);
        add_accessor(accs, vi, tex_idx * isz, idx16 ? GL_USHORT_ : GL_UINT_, ni - tex_idx, "SCALAR",
                     0, NULL, NULL, 0);
    }

    /* materials, textures, the mesh */
    int double_sided = !(n->render_flags & HLOD_RENDER_SOLID);
    cJSON *mats = cJSON_AddArrayToObject(root, "materials");
    cJSON *prims = cJSON_CreateArray();
    for (int part = 0; part < 2; part++) {
        int acc = part == 0 ? a_i0 : a_i1;
        if (acc < 0)
            continue;
        cJSON *m = cJSON_CreateObject();
        cJSON *pbr = cJSON_AddObjectToObject(m, "pbrMetallicRoughness");
        if (part == 0) {
            cJSON_AddNumberToObject(cJSON_AddObjectToObject(pbr, "baseColorTexture"), "index", 0);
        } else if (!has_c) {
            double g = srgb_to_linear(RENDER_GREY), c[4] = {g, g, g, 1.0};
            cJSON_AddItemToObject(pbr, "baseColorFactor", num_array(c, 4));
        }
        cJSON_AddNumberToObject(pbr, "metallicFactor", 0);
        cJSON_AddNumberToObject(pbr, "roughnessFactor", 1);
        if (double_sided)
            cJSON_AddTrueToObject(m, "doubleSided");
        int mi = cJSON_GetArraySize(mats);
        cJSON_AddItemToArray(mats, m);
        cJSON *pr = cJSON_CreateObject();
        cJSON *at = cJSON_AddObjectToObject(pr, "attributes");
        cJSON_AddNumberToObject(at, "POSITION", a_pos);
        if (a_n >= 0)
            cJSON_AddNumberToObject(at, "NORMAL", a_n);
        if (part == 0 && a_uv >= 0)
            cJSON_AddNumberToObject(at, "TEXCOORD_0", a_uv);
        if (part == 1 && a_c >= 0)
            cJSON_AddNumberToObject(at, "COLOR_0", a_c);
        cJSON_AddNumberToObject(pr, "indices", acc);
        cJSON_AddNumberToObject(pr, "material", mi);
        cJSON_AddNumberToObject(pr, "mode", 4);
        cJSON_AddItemToArray(prims, pr);
    }
    cJSON *meshes = cJSON_AddArrayToObject(root, "meshes");
    cJSON *mesh = cJSON_CreateObject();
    cJSON_AddItemToObject(mesh, "primitives", prims);
    cJSON_AddItemToArray(meshes, mesh);
    if (textured) {
        cJSON *smp = cJSON_CreateObject();
        cJSON_AddNumberToObject(smp, "magFilter", 9729);    /* LINEAR */
        cJSON_AddNumberToObject(smp, "minFilter", 9987);    /* LINEAR_MIPMAP_LINEAR */
        cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "samplers"), smp);
        cJSON *im = cJSON_CreateObject();
        cJSON_AddNumberToObject(im, "bufferView", img_view);
        cJSON_AddStringToObject(im, "mimeType", mime);
        cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "images"), im);
        cJSON *tx = cJSON_CreateObject();
        cJSON_AddNumberToObject(tx, "sampler", 0);
        cJSON_AddNumberToObject(tx, "source", 0);
        cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "textures"), tx);
    }

    char *json = cJSON_PrintUnformatted(root);
    if (!json || bin.oom) {
        free(json);
        free(bin.p);
        goto nomem;
    }
    size_t jlen = strlen(json), jpad = (4 - jlen % 4) % 4;
    uint32_t total = (uint32_t)(12 + 8 + jlen + jpad + 8 + bin.len);
    glb->len = 0;
    uint32_t hdr[3] = {0x46546C67u, 2u, total};  /* "glTF" */
    uint32_t jch[2] = {(uint32_t)(jlen + jpad), 0x4E4F534Au};   /* "JSON" */
    uint32_t bch[2] = {(uint32_t)bin.len, 0x004E4942u};         /* "BIN\0" */
    bytes_put(glb, hdr, 12, 0);
    bytes_put(glb, jch, 8, 0);
    bytes_put(glb, json, jlen, 0);
    if (bytes_reserve(glb, jpad)) {
        memset(glb->p + glb->len, ' ', jpad);
        glb->len += jpad;
    }
    bytes_put(glb, bch, 8, 0);
    bytes_put(glb, bin.p, bin.len, 0);
    free(json);
    free(bin.p);
    if (glb->oom)
        goto nomem;
    goto done;
nomem:
    r = HLOD_ERR_NOMEM;
done:
    cJSON_Delete(root);
    for (int k = 0; k < nviews; k++)
        free(views[k].coded);
    free(pos);
    free(nrm);
    free(uv);
    free(col);
    free(idx);
    free(img);
    return r;
}

/* ---- workers ---- */

static void fail(job *J, hlod_result r)
{
    pthread_mutex_lock(&J->lock);
    if (J->result == HLOD_OK)
        J->result = r;
    pthread_mutex_unlock(&J->lock);
    atomic_store(&J->failed, 1);
}

static hlod_result write_file(const char *path, const void *data, size_t len,
                              const hlod_logger *lg)
{
    FILE *fp = fopen(path, "wb");
    if (!fp) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create: %s", path, strerror(errno));
        return HLOD_ERR_IO;
    }
    int bad = fwrite(data, 1, len, fp) != len;
    bad |= fflush(fp) != 0;
    int err = errno;
    bad |= fclose(fp) != 0;
    if (bad) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write: %s", path, strerror(err ? err : errno));
        return HLOD_ERR_IO;
    }
    return HLOD_OK;
}

static void *worker(void *arg)
{
    job *J = arg;
    uint32_t count = hlod_store_node_count(J->s);
    bytes glb = {0};
    for (;;) {
        if (atomic_load(&J->failed))
            break;
        uint32_t i = atomic_fetch_add(&J->next, 1u);
        if (i >= count)
            break;
        hlod_store_read rd;
        hlod_result r = hlod_store_read_begin(J->s, i, &rd);
        int complete = 0;
        if (r == HLOD_OK && !hlod_store_cache_get(&rd))
            while (r == HLOD_OK && !complete)
                r = hlod_store_read_step(&rd, 1u << 20, &complete);
        uint8_t *raw = NULL;
        size_t raw_len = 0;
        if (r == HLOD_OK) {
            hlod_store_cache_put(&rd);
            /* keep the packed bytes for the JPEG copy: finish frees them */
            size_t jl = 0;
            const uint8_t *j = packed_jpeg(J->h, rd.buf, rd.size, &jl);
            if (j) {
                raw = malloc(rd.size);
                if (!raw)
                    r = HLOD_ERR_NOMEM;
                else {
                    memcpy(raw, rd.buf, rd.size);
                    raw_len = rd.size;
                }
            }
        }
        hlod_store_payload p = {0};
        if (r == HLOD_OK)
            r = hlod_store_read_finish(&rd, &p);
        else
            hlod_store_read_cancel(&rd);
        if (r != HLOD_OK) {
            hlod_logf(J->desc->logger, HLOD_LOG_ERROR, "%s: node %u: cannot read its payload (%s)",
                     hlod_store_path(J->s), i, hlod_result_str(r));
            free(raw);
            fail(J, r);
            break;
        }
        glb_out go;
        r = node_glb(J, i, &p, raw, raw_len, &glb, &go);
        free(raw);
        uint64_t tris = p.index_count / 3;
        hlod_store_payload_free(&p);
        if (r == HLOD_OK) {
            char path[PATH_MAX];
            snprintf(path, sizeof path, "%s/tiles/%u.glb", J->tmp_dir, i);
            r = write_file(path, glb.p, glb.len, J->desc->logger);
        }
        if (r != HLOD_OK) {
            fail(J, r);
            break;
        }
        pthread_mutex_lock(&J->lock);
        J->st.glbs++;
        J->st.glb_bytes += glb.len;
        J->st.texture_bytes += go.texture_bytes;
        J->st.jpeg_copied += (uint64_t)go.jpeg_copied;
        J->st.meshopt_glbs += (uint64_t)go.meshopt;
        J->st.float_position_glbs += (uint64_t)go.float_positions;
        J->st.triangles += tris;
        pthread_mutex_unlock(&J->lock);
        atomic_fetch_add(&J->done, 1u);
    }
    free(glb.p);
    return NULL;
}

/* ---- tileset.json ---- */

static cJSON *tile_json(const job *J, uint32_t i, const double parent_origin[3], double pad)
{
    const hlod_store_node *n = &J->nodes[i];
    cJSON *t = cJSON_CreateObject();
    double box[12] = {0};
    for (int k = 0; k < 3; k++) {
        box[k] = 0.5 * (n->bbox_min[k] + n->bbox_max[k]) - n->origin[k];
        box[3 + 4 * k] = 0.5 * (n->bbox_max[k] - n->bbox_min[k]) + pad;
    }
    cJSON_AddItemToObject(cJSON_AddObjectToObject(t, "boundingVolume"), "box", num_array(box, 12));
    add_num(t, "geometricError", n->error);
    cJSON_AddStringToObject(t, "refine", "REPLACE");
    double m[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    for (int k = 0; k < 3; k++)
        m[12 + k] = n->origin[k] - parent_origin[k];
    cJSON_AddItemToObject(t, "transform", num_array(m, 16));
    char uri[48];
    snprintf(uri, sizeof uri, "tiles/%u.glb", i);
    cJSON_AddStringToObject(cJSON_AddObjectToObject(t, "content"), "uri", uri);
    uint32_t c0 = hlod_store_first_child(J->nodes, i), c1 = hlod_store_child_end(J->nodes, i);
    if (c1 > c0) {
        cJSON *ch = cJSON_AddArrayToObject(t, "children");
        for (uint32_t c = c0; c < c1; c++)
            cJSON_AddItemToArray(ch, tile_json(J, c, n->origin, pad));
    }
    return t;
}

static char *tileset_json(const job *J, double pad, uint64_t *tiles)
{
    const hlod_store_header *h = J->h;
    cJSON *root = cJSON_CreateObject();
    cJSON *asset = cJSON_AddObjectToObject(root, "asset");
    cJSON_AddStringToObject(asset, "version", "1.1");
    cJSON_AddStringToObject(asset, "generator", "hlod-export-3dtiles");
    double zero[3] = {0, 0, 0};
    uint32_t roots = h->root_count;
    cJSON *top;
    double err;
    if (roots == 1) {
        top = tile_json(J, 0, zero, pad);
        err = J->nodes[0].error;
        *tiles = h->node_count;
    } else {    /* a content-less tile over the roots */
        top = cJSON_CreateObject();
        double box[12] = {0}, diag2 = 0;
        for (int k = 0; k < 3; k++) {
            box[k] = 0.5 * (h->bbox_min[k] + h->bbox_max[k]);
            box[3 + 4 * k] = 0.5 * (h->bbox_max[k] - h->bbox_min[k]) + pad;
            diag2 += (h->bbox_max[k] - h->bbox_min[k]) * (h->bbox_max[k] - h->bbox_min[k]);
        }
        err = 0;
        for (uint32_t r = 0; r < roots; r++)
            err = fmax(err, J->nodes[r].error);
        err = fmax(2 * err, sqrt(diag2));   /* always refined */
        cJSON_AddItemToObject(cJSON_AddObjectToObject(top, "boundingVolume"), "box",
                              num_array(box, 12));
        add_num(top, "geometricError", err);
        cJSON_AddStringToObject(top, "refine", "REPLACE");
        cJSON *ch = cJSON_AddArrayToObject(top, "children");
        for (uint32_t r = 0; r < roots; r++)
            cJSON_AddItemToArray(ch, tile_json(J, r, zero, pad));
        *tiles = (uint64_t)h->node_count + 1;
    }
    add_num(root, "geometricError", err);
    cJSON_AddItemToObject(root, "root", top);
    char *s = cJSON_PrintUnformatted(root);
    cJSON_Delete(root);
    return s;
}

/* ---- the folder ---- */

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

hlod_result hlod_tiles_export(const hlod_store *s, const char *dir,
                              const hlod_tiles_export_desc *desc,
                              hlod_tiles_export_stats *stats)
{
    const hlod_logger *lg = desc->logger;
    if (stats)
        memset(stats, 0, sizeof *stats);
    struct stat sb;
    int exists = stat(dir, &sb) == 0;
    if (exists && !S_ISDIR(sb.st_mode)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: exists and is not a folder", dir);
        return HLOD_ERR_IO;
    }
    if (exists && !desc->force) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: exists (--force replaces it)", dir);
        return HLOD_ERR_IO;
    }
    char tmp[PATH_MAX], sub[PATH_MAX + 16];
    size_t dl = strlen(dir);
    while (dl > 1 && dir[dl - 1] == '/')
        dl--;
    if (dl + 32 >= sizeof tmp) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: path too long", dir);
        return HLOD_ERR_INVALID_ARG;
    }
    snprintf(tmp, sizeof tmp, "%.*s.tmp-XXXXXX", (int)dl, dir);
    if (!mkdtemp(tmp)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create a folder beside it: %s", dir,
                 strerror(errno));
        return HLOD_ERR_IO;
    }
    snprintf(sub, sizeof sub, "%s/tiles", tmp);
    if (mkdir(sub, 0777) != 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %s", sub, strerror(errno));
        hlod_rm_tree(tmp);
        return HLOD_ERR_IO;
    }

    job J;
    memset(&J, 0, sizeof J);
    J.s = s;
    J.h = hlod_store_get_header(s);
    J.nodes = hlod_store_nodes(s);
    J.tmp_dir = tmp;
    J.desc = desc;
    double diag2 = 0;
    for (int k = 0; k < 3; k++)
        diag2 += (J.h->bbox_max[k] - J.h->bbox_min[k]) * (J.h->bbox_max[k] - J.h->bbox_min[k]);
    J.tol_floor = fmax(J.h->quant_step, 1e-6 * sqrt(diag2));
    atomic_init(&J.next, 0u);
    atomic_init(&J.done, 0u);
    atomic_init(&J.failed, 0);
    pthread_mutex_init(&J.lock, NULL);

    unsigned nt = desc->threads ? desc->threads : 2;
    if (nt > 64)
        nt = 64;
    pthread_t th[64];
    unsigned started = 0;
    for (; started < nt; started++)
        if (pthread_create(&th[started], NULL, worker, &J) != 0)
            break;
    if (started == 0)
        worker(&J);
    uint32_t count = hlod_store_node_count(s);
    double last = 0;
    while (started && atomic_load(&J.done) < count && !atomic_load(&J.failed)) {
        struct timespec ts = {0, 20 * 1000 * 1000};
        nanosleep(&ts, NULL);
        double t = now_s();
        if (desc->progress && t - last > 0.1) {
            desc->progress(desc->progress_user, atomic_load(&J.done), count);
            last = t;
        }
        /* every worker may have stopped on the same error */
    }
    for (unsigned k = 0; k < started; k++)
        pthread_join(th[k], NULL);
    pthread_mutex_destroy(&J.lock);
    hlod_result r = J.result;
    if (r == HLOD_OK && J.st.glbs != count) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %llu of %u tiles written", dir,
                 (unsigned long long)J.st.glbs, count);
        r = HLOD_ERR_IO;
    }
    if (r == HLOD_OK && desc->progress)
        desc->progress(desc->progress_user, count, count);

    if (r == HLOD_OK) {
        char *ts = tileset_json(&J, J.tol_floor, &J.st.tiles);
        if (!ts) {
            r = HLOD_ERR_NOMEM;
        } else {
            char path[PATH_MAX + 16];
            snprintf(path, sizeof path, "%s/tileset.json", tmp);
            J.st.tileset_bytes = strlen(ts);
            r = write_file(path, ts, J.st.tileset_bytes, lg);
            cJSON_free(ts);
        }
    }
    if (r == HLOD_OK) {     /* into place */
        char old[PATH_MAX + 16];
        old[0] = 0;
        if (exists) {
            snprintf(old, sizeof old, "%.*s.old-XXXXXX", (int)dl, dir);
            if (!mkdtemp(old) || rename(dir, old) != 0) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot move the old folder aside: %s", dir,
                         strerror(errno));
                r = HLOD_ERR_IO;
            }
        }
        if (r == HLOD_OK && rename(tmp, dir) != 0) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot rename %s into place: %s", dir, tmp,
                     strerror(errno));
            if (old[0])
                rename(old, dir);
            r = HLOD_ERR_IO;
        }
        if (r == HLOD_OK && old[0])
            hlod_rm_tree(old);
    }
    if (r != HLOD_OK) {
        hlod_rm_tree(tmp);
        return r;
    }
    J.st.bytes = J.st.glb_bytes + J.st.tileset_bytes;
    if (stats)
        *stats = J.st;
    return HLOD_OK;
}
