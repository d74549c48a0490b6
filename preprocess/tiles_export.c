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
    const uint8_t *data;        /* plain bytes (owned) */
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
    double *box_lo, *box_hi;    /* 3 per node, world: its glb's content as
                                   written (quantized), then, bottom-up, its
                                   descendants' boxes too (3D Tiles: a
                                   child's content lies in its parent's box) */
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

/* One node's glb while it is made. */
typedef struct gb {
    job *J;
    uint32_t i;
    const hlod_store_payload *p;
    size_t nv, ni;
    /* positions */
    int quantize;
    double lo[3], step, pmin[3], pmax[3];
    /* streams: positions, then normals, UVs, colours, indices as present */
    view views[5];
    int nviews;
    int has_n, has_uv, has_c, uv_quant, idx16, meshopt;
    size_t isz;
    /* texture */
    int textured;
    const uint8_t *img;         /* image bytes (the store's JPEG or img_own) */
    size_t img_len;
    uint8_t *img_own;
    const char *mime;
} gb;

static void gb_free(gb *b)
{
    for (int k = 0; k < b->nviews; k++) {
        free((void *)b->views[k].data);
        free(b->views[k].coded);
    }
    free(b->img_own);
}

/* Adds a stream of count elements of stride bytes; NULL when out of memory. */
static uint8_t *gb_stream(gb *b, size_t count, size_t stride, int is_index)
{
    uint8_t *d = malloc(count * stride + 1);
    if (d)
        b->views[b->nviews++] = (view){d, count, stride, is_index, NULL, 0};
    return d;
}

/* Positions in glTF's frame, (x, z, -y): 16-bit steps of a power-of-two
 * multiple of the store's grid when the step keeps every vertex within the
 * tolerance, else floats.  Records the content's box (our frame, world). */
static hlod_result gb_positions(gb *b)
{
    const hlod_store_payload *p = b->p;
    const hlod_store_node *n = &b->J->nodes[b->i];
    double hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int k = 0; k < 3; k++)
        b->lo[k] = INFINITY;
    for (size_t v = 0; v < b->nv; v++) {
        const float *q = p->positions + 3 * v;
        double g[3] = {q[0], q[2], -(double)q[1]};
        for (int k = 0; k < 3; k++) {
            b->lo[k] = fmin(b->lo[k], g[k]);
            hi[k] = fmax(hi[k], g[k]);
        }
    }
    double extent = fmax(fmax(hi[0] - b->lo[0], hi[1] - b->lo[1]), hi[2] - b->lo[2]);
    double step = extent > 0 ? extent / 65535.0 : 1.0;
    if (b->J->h->quant_step > 0 && extent > 0) {   /* a power-of-two multiple of the grid */
        double s = b->J->h->quant_step;
        while (s < step)
            s *= 2;
        step = s;
    }
    b->step = step;
    double tol = fmax(b->J->tol_floor, 0.1 * n->error);
    b->quantize = 0.5 * step <= tol && extent / step <= 65535.0;
    uint8_t *pos = gb_stream(b, b->nv, b->quantize ? 8 : 12, 0);
    if (!pos)
        return HLOD_ERR_NOMEM;
    for (int k = 0; k < 3; k++) {
        b->pmin[k] = INFINITY;
        b->pmax[k] = -INFINITY;
    }
    for (size_t v = 0; v < b->nv; v++) {
        const float *q = p->positions + 3 * v;
        double g[3] = {q[0], q[2], -(double)q[1]};
        double o[3];
        if (b->quantize) {
            uint16_t u[4] = {0, 0, 0, 0};
            for (int k = 0; k < 3; k++) {
                double t = nearbyint((g[k] - b->lo[k]) / step);
                u[k] = (uint16_t)(t < 0 ? 0 : t > 65535 ? 65535 : t);
                o[k] = u[k];
            }
            memcpy(pos + 8 * v, u, 8);
        } else {
            float f[3] = {(float)g[0], (float)g[1], (float)g[2]};
            for (int k = 0; k < 3; k++)
                o[k] = f[k];
            memcpy(pos + 12 * v, f, 12);
        }
        for (int k = 0; k < 3; k++) {
            b->pmin[k] = fmin(b->pmin[k], o[k]);
            b->pmax[k] = fmax(b->pmax[k], o[k]);
        }
    }
    /* the content's box as written, back in our frame: (gx, -gz, gy) */
    double a[3], c[3];
    for (int k = 0; k < 3; k++) {
        a[k] = b->quantize ? b->lo[k] + b->pmin[k] * step : b->pmin[k];
        c[k] = b->quantize ? b->lo[k] + b->pmax[k] * step : b->pmax[k];
    }
    double *L = b->J->box_lo + 3 * (size_t)b->i, *H = b->J->box_hi + 3 * (size_t)b->i;
    const double *o = n->origin;
    L[0] = o[0] + a[0], H[0] = o[0] + c[0];
    L[1] = o[1] - c[2], H[1] = o[1] - a[2];
    L[2] = o[2] + a[1], H[2] = o[2] + c[1];
    return HLOD_OK;
}

/* Normals (normalized 16-bit), UVs (normalized 16-bit in [0, 1], else
 * float; v flipped to glTF's), colours (linear, normalized 16-bit) and the
 * indices (16-bit below 65535 vertices). */
static hlod_result gb_attributes(gb *b)
{
    const hlod_store_payload *p = b->p;
    size_t nv = b->nv;
    b->has_n = p->normals != NULL;
    b->has_uv = p->uvs != NULL;
    b->has_c = p->colors != NULL;
    uint8_t *d;
    if (b->has_n) {
        if (!(d = gb_stream(b, nv, 8, 0)))
            return HLOD_ERR_NOMEM;
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
            memcpy(d + 8 * v, o, 8);
        }
    }
    if (b->has_uv) {
        b->uv_quant = 1;
        for (size_t v = 0; v < 2 * nv && b->uv_quant; v++)
            b->uv_quant = p->uvs[v] >= 0.0f && p->uvs[v] <= 1.0f;
        size_t stride = b->uv_quant ? 4 : 8;
        if (!(d = gb_stream(b, nv, stride, 0)))
            return HLOD_ERR_NOMEM;
        for (size_t v = 0; v < nv; v++) {
            float t[2] = {p->uvs[2 * v], 1.0f - p->uvs[2 * v + 1]};
            if (b->uv_quant) {
                uint16_t o[2] = {(uint16_t)lrint(fmin(fmax(t[0], 0), 1) * 65535.0),
                                 (uint16_t)lrint(fmin(fmax(t[1], 0), 1) * 65535.0)};
                memcpy(d + 4 * v, o, 4);
            } else {
                memcpy(d + 8 * v, t, 8);
            }
        }
    }
    if (b->has_c) {
        if (!(d = gb_stream(b, nv, 8, 0)))
            return HLOD_ERR_NOMEM;
        for (size_t v = 0; v < nv; v++) {
            uint16_t o[4];
            for (int k = 0; k < 3; k++)
                o[k] = (uint16_t)lrint(srgb_to_linear(p->colors[4 * v + k] / 255.0) * 65535.0);
            o[3] = (uint16_t)(p->colors[4 * v + 3] * 257u);
            memcpy(d + 8 * v, o, 8);
        }
    }
    b->idx16 = nv <= 65535;
    b->isz = b->idx16 ? 2 : 4;
    if (!(d = gb_stream(b, b->ni, b->isz, 1)))
        return HLOD_ERR_NOMEM;
    for (size_t t = 0; t < b->ni; t++) {
        if (b->idx16) {
            uint16_t o = (uint16_t)p->indices[t];
            memcpy(d + 2 * t, &o, 2);
        } else {
            memcpy(d + 4 * t, &p->indices[t], 4);
        }
    }
    return HLOD_OK;
}

/* EXT_meshopt_compression: codes every stream; b->meshopt when it pays
 * (or is asked for). */
static hlod_result gb_meshopt(gb *b)
{
    const hlod_tiles_export_desc *desc = b->J->desc;
    if (desc->meshopt == HLOD_MESHOPT_NEVER)
        return HLOD_OK;
    size_t plain = 0, coded = 0;
    for (int k = 0; k < b->nviews; k++) {
        view *w = &b->views[k];
        size_t bound = w->is_index ? meshopt_encodeIndexBufferBound(w->count, b->nv)
                                   : meshopt_encodeVertexBufferBound(w->count, w->stride);
        w->coded = malloc(bound + 1);
        if (!w->coded)
            return HLOD_ERR_NOMEM;
        w->coded_len = w->is_index
            ? meshopt_encodeIndexBuffer(w->coded, bound, b->p->indices, w->count)
            : meshopt_encodeVertexBuffer(w->coded, bound, w->data, w->count, w->stride);
        if (w->coded_len == 0) {
            hlod_logf(desc->logger, HLOD_LOG_ERROR, "%s: node %u: meshoptimizer could not code "
                      "a stream", hlod_store_path(b->J->s), b->i);
            return HLOD_ERR_FORMAT;
        }
        plain += w->count * w->stride;
        coded += w->coded_len;
    }
    b->meshopt = desc->meshopt == HLOD_MESHOPT_ALWAYS || coded < 0.9 * (double)plain;
    return HLOD_OK;
}

/* The texture's bytes: the store's JPEG as it is, else encoded here. */
static hlod_result gb_texture(gb *b, const uint8_t *raw, size_t raw_len, glb_out *go)
{
    const hlod_store_payload *p = b->p;
    b->textured = (p->flags & HLOD_NODE_TEXTURE) && p->pixels && p->tex_tri_count > 0;
    if (!b->textured)
        return HLOD_OK;
    b->img = packed_jpeg(b->J->h, raw, raw_len, &b->img_len);
    if (b->img) {
        b->mime = "image/jpeg";
        go->jpeg_copied = 1;
        return HLOD_OK;
    }
    hlod_result r = encode_texture(b->J, b->i, p, &b->img_own, &b->img_len, &b->mime);
    b->img = b->img_own;
    return r;
}

/* bufferViews and buffers into root, their bytes into bin; returns the
 * image's view or -1. */
static int gb_views_json(gb *b, cJSON *root, bytes *bin)
{
    cJSON *bviews = cJSON_AddArrayToObject(root, "bufferViews");
    size_t fallback_len = 0;
    for (int k = 0; k < b->nviews; k++) {
        view *w = &b->views[k];
        size_t plain_len = w->count * w->stride;
        cJSON *bv = cJSON_CreateObject();
        if (b->meshopt) {   /* data in buffer 0, coded; buffer 1 holds no bytes */
            size_t at = bytes_put(bin, w->coded, w->coded_len, 0);
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
            size_t at = bytes_put(bin, w->data, plain_len, 0);
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
    if (b->textured) {
        size_t at = bytes_put(bin, b->img, b->img_len, 0);
        cJSON *bv = cJSON_CreateObject();
        cJSON_AddNumberToObject(bv, "buffer", 0);
        if (at)
            cJSON_AddNumberToObject(bv, "byteOffset", (double)at);
        cJSON_AddNumberToObject(bv, "byteLength", (double)b->img_len);
        img_view = cJSON_GetArraySize(bviews);
        cJSON_AddItemToArray(bviews, bv);
    }
    bytes_put(bin, NULL, 0, 0);     /* pad the chunk to 4 */
    cJSON *buffers = cJSON_AddArrayToObject(root, "buffers");
    cJSON *b0 = cJSON_CreateObject();
    cJSON_AddNumberToObject(b0, "byteLength", (double)bin->len);
    cJSON_AddItemToArray(buffers, b0);
    if (b->meshopt) {
        cJSON *b1 = cJSON_CreateObject();
        cJSON_AddNumberToObject(b1, "byteLength", (double)fallback_len);
        cJSON_AddTrueToObject(cJSON_AddObjectToObject(cJSON_AddObjectToObject(b1, "extensions"),
                                                      "EXT_meshopt_compression"),
                              "fallback");
        cJSON_AddItemToArray(buffers, b1);
    }
    return img_view;
}

/* Accessors (positions, normals, UVs, colours, then the textured and the
 * untextured triangles' indices), materials, the mesh, the texture. */
static void gb_mesh_json(gb *b, cJSON *root, int img_view)
{
    cJSON *accs = cJSON_AddArrayToObject(root, "accessors");
    int vi = 0, a_n = -1, a_uv = -1, a_c = -1, a_i[2] = {-1, -1};
    add_accessor(accs, vi++, 0, b->quantize ? GL_USHORT_ : GL_FLOAT_, b->nv, "VEC3", 0, b->pmin,
                 b->pmax, 3);
    if (b->has_n) {
        a_n = cJSON_GetArraySize(accs);
        add_accessor(accs, vi++, 0, GL_SHORT_, b->nv, "VEC3", 1, NULL, NULL, 0);
    }
    if (b->has_uv) {
        a_uv = cJSON_GetArraySize(accs);
        add_accessor(accs, vi++, 0, b->uv_quant ? GL_USHORT_ : GL_FLOAT_, b->nv, "VEC2",
                     b->uv_quant, NULL, NULL, 0);
    }
    if (b->has_c) {
        a_c = cJSON_GetArraySize(accs);
        add_accessor(accs, vi++, 0, GL_USHORT_, b->nv, "VEC4", 1, NULL, NULL, 0);
    }
    int ct = b->idx16 ? GL_USHORT_ : GL_UINT_;
    size_t tex_idx = b->textured ? 3 * (size_t)b->p->tex_tri_count : 0;
    if (tex_idx > 0) {
        a_i[0] = cJSON_GetArraySize(accs);
        add_accessor(accs, vi, 0, ct, tex_idx, "SCALAR", 0, NULL, NULL, 0);
    }
    if (b->ni > tex_idx) {
        a_i[1] = cJSON_GetArraySize(accs);
        add_accessor(accs, vi, tex_idx * b->isz, ct, b->ni - tex_idx, "SCALAR", 0, NULL, NULL, 0);
    }
    int double_sided = !(b->J->nodes[b->i].render_flags & HLOD_RENDER_SOLID);
    cJSON *mats = cJSON_AddArrayToObject(root, "materials");
    cJSON *prims = cJSON_CreateArray();
    for (int part = 0; part < 2; part++) {
        if (a_i[part] < 0)
            continue;
        cJSON *m = cJSON_CreateObject();
        cJSON *pbr = cJSON_AddObjectToObject(m, "pbrMetallicRoughness");
        if (part == 0) {
            cJSON_AddNumberToObject(cJSON_AddObjectToObject(pbr, "baseColorTexture"), "index", 0);
        } else if (!b->has_c) {
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
        cJSON_AddNumberToObject(at, "POSITION", 0);
        if (a_n >= 0)
            cJSON_AddNumberToObject(at, "NORMAL", a_n);
        if (part == 0 && a_uv >= 0)
            cJSON_AddNumberToObject(at, "TEXCOORD_0", a_uv);
        if (part == 1 && a_c >= 0)
            cJSON_AddNumberToObject(at, "COLOR_0", a_c);
        cJSON_AddNumberToObject(pr, "indices", a_i[part]);
        cJSON_AddNumberToObject(pr, "material", mi);
        cJSON_AddNumberToObject(pr, "mode", 4);
        cJSON_AddItemToArray(prims, pr);
    }
    cJSON *mesh = cJSON_CreateObject();
    cJSON_AddItemToObject(mesh, "primitives", prims);
    cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "meshes"), mesh);
    if (b->textured) {
        cJSON *smp = cJSON_CreateObject();
        cJSON_AddNumberToObject(smp, "magFilter", 9729);    /* LINEAR */
        cJSON_AddNumberToObject(smp, "minFilter", 9987);    /* LINEAR_MIPMAP_LINEAR */
        cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "samplers"), smp);
        cJSON *im = cJSON_CreateObject();
        cJSON_AddNumberToObject(im, "bufferView", img_view);
        cJSON_AddStringToObject(im, "mimeType", b->mime);
        cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "images"), im);
        cJSON *tx = cJSON_CreateObject();
        cJSON_AddNumberToObject(tx, "sampler", 0);
        cJSON_AddNumberToObject(tx, "source", 0);
        cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "textures"), tx);
    }
}

/* asset, extensions, the scene and its one node (the quantization's
 * translation and scale). */
static cJSON *gb_head_json(gb *b)
{
    cJSON *root = cJSON_CreateObject();
    cJSON *asset = cJSON_AddObjectToObject(root, "asset");
    cJSON_AddStringToObject(asset, "version", "2.0");
    cJSON_AddStringToObject(asset, "generator", "hlod-export-3dtiles");
    const char *ext[2];
    int next = 0;
    if (b->quantize || b->has_n || (b->has_uv && b->uv_quant) || b->has_c)
        ext[next++] = "KHR_mesh_quantization";
    if (b->meshopt)
        ext[next++] = "EXT_meshopt_compression";
    if (next) {
        cJSON *used = cJSON_AddArrayToObject(root, "extensionsUsed");
        cJSON *required = cJSON_AddArrayToObject(root, "extensionsRequired");
        for (int k = 0; k < next; k++) {
            cJSON_AddItemToArray(used, cJSON_CreateString(ext[k]));
            cJSON_AddItemToArray(required, cJSON_CreateString(ext[k]));
        }
    }
    cJSON_AddNumberToObject(root, "scene", 0);
    cJSON *scene = cJSON_CreateObject();
    cJSON_AddItemToArray(cJSON_AddArrayToObject(scene, "nodes"), cJSON_CreateNumber(0));
    cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "scenes"), scene);
    cJSON *gnode = cJSON_CreateObject();
    char name[32];
    snprintf(name, sizeof name, "node %u", b->i);
    cJSON_AddStringToObject(gnode, "name", name);
    cJSON_AddNumberToObject(gnode, "mesh", 0);
    if (b->quantize) {
        double sc[3] = {b->step, b->step, b->step};
        cJSON_AddItemToObject(gnode, "translation", num_array(b->lo, 3));
        cJSON_AddItemToObject(gnode, "scale", num_array(sc, 3));
    }
    cJSON_AddItemToArray(cJSON_AddArrayToObject(root, "nodes"), gnode);
    return root;
}

/* The glb container: header, JSON chunk (space-padded), BIN chunk. */
static int glb_assemble(bytes *glb, const char *json, const bytes *bin)
{
    size_t jlen = strlen(json), jpad = (4 - jlen % 4) % 4;
    uint32_t hdr[3] = {0x46546C67u, 2u, (uint32_t)(12 + 8 + jlen + jpad + 8 + bin->len)};
    uint32_t jch[2] = {(uint32_t)(jlen + jpad), 0x4E4F534Au};   /* "JSON" */
    uint32_t bch[2] = {(uint32_t)bin->len, 0x004E4942u};        /* "BIN\0" */
    glb->len = 0;
    bytes_put(glb, hdr, 12, 0);
    bytes_put(glb, jch, 8, 0);
    bytes_put(glb, json, jlen, 0);
    if (bytes_reserve(glb, jpad)) {
        memset(glb->p + glb->len, ' ', jpad);
        glb->len += jpad;
    }
    bytes_put(glb, bch, 8, 0);
    bytes_put(glb, bin->p, bin->len, 0);
    return !glb->oom;
}

/* Builds node i's glb from payload p (raw: its read bytes before decoding,
 * for the JPEG texture). */
static hlod_result node_glb(job *J, uint32_t i, const hlod_store_payload *p,
                            const uint8_t *raw, size_t raw_len, bytes *glb, glb_out *go)
{
    gb b;
    memset(&b, 0, sizeof b);
    b.J = J;
    b.i = i;
    b.p = p;
    b.nv = p->vertex_count;
    b.ni = p->index_count;
    memset(go, 0, sizeof *go);
    hlod_result r = gb_positions(&b);
    if (r == HLOD_OK)
        r = gb_attributes(&b);
    if (r == HLOD_OK)
        r = gb_meshopt(&b);
    if (r == HLOD_OK)
        r = gb_texture(&b, raw, raw_len, go);
    if (r == HLOD_OK) {
        bytes bin = {0};
        cJSON *root = gb_head_json(&b);
        int img_view = gb_views_json(&b, root, &bin);
        gb_mesh_json(&b, root, img_view);
        char *json = cJSON_PrintUnformatted(root);
        if (!json || bin.oom || !glb_assemble(glb, json, &bin))
            r = HLOD_ERR_NOMEM;
        cJSON_free(json);
        cJSON_Delete(root);
        free(bin.p);
        go->meshopt = b.meshopt;
        go->float_positions = !b.quantize;
        go->texture_bytes = b.textured ? b.img_len : 0;
    }
    gb_free(&b);
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
    const double *lo = J->box_lo + 3 * (size_t)i, *hi = J->box_hi + 3 * (size_t)i;
    for (int k = 0; k < 3; k++) {
        box[k] = 0.5 * (lo[k] + hi[k]) - n->origin[k];
        box[3 + 4 * k] = 0.5 * (hi[k] - lo[k]) + pad;
    }
    cJSON_AddItemToObject(cJSON_AddObjectToObject(t, "boundingVolume"), "box", num_array(box, 12));
    add_num(t, "geometricError", n->error);
    /* a sample tree's nodes add to their ancestors (docs/sampletree.md) */
    cJSON_AddStringToObject(t, "refine", (J->h->flags & HLOD_STORE_ADDITIVE) ? "ADD" : "REPLACE");
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
            double lo = INFINITY, hi = -INFINITY;
            for (uint32_t r = 0; r < roots; r++) {
                lo = fmin(lo, J->box_lo[3 * r + k]);
                hi = fmax(hi, J->box_hi[3 * r + k]);
            }
            box[k] = 0.5 * (lo + hi);
            box[3 + 4 * k] = 0.5 * (hi - lo) + pad;
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

/* Renames the finished folder tmp to dir (dl: dir's length without
 * trailing slashes); an existing dir is moved aside first and removed
 * after, or put back if the rename fails. */
static hlod_result into_place(const char *tmp, const char *dir, size_t dl, int exists,
                              const hlod_logger *lg)
{
    hlod_result r = HLOD_OK;
    char old[PATH_MAX + 16];
    old[0] = 0;
    if (exists) {
        snprintf(old, sizeof old, "%.*s.old-XXXXXX", (int)dl, dir);
        if (!mkdtemp(old) || rename(dir, old) != 0) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot move the old folder aside: %s", dir,
                      strerror(errno));
            return HLOD_ERR_IO;
        }
    }
    if (rename(tmp, dir) != 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot rename %s into place: %s", dir, tmp,
                  strerror(errno));
        if (old[0])
            rename(old, dir);
        r = HLOD_ERR_IO;
    }
    if (r == HLOD_OK && old[0])
        hlod_rm_tree(old);
    return r;
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
    uint32_t nn = hlod_store_node_count(s);
    J.box_lo = malloc(3 * (size_t)nn * sizeof *J.box_lo);
    J.box_hi = malloc(3 * (size_t)nn * sizeof *J.box_hi);
    if (!J.box_lo || !J.box_hi) {
        free(J.box_lo);
        free(J.box_hi);
        hlod_rm_tree(tmp);
        return HLOD_ERR_NOMEM;
    }
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
        /* children's boxes into their parents' (breadth-first: children
         * come after their parent) */
        for (uint32_t i = count; i-- > 0;) {
            uint32_t p = J.nodes[i].parent;
            if (p == HLOD_STORE_NO_PARENT)
                continue;
            for (int k = 0; k < 3; k++) {
                J.box_lo[3 * p + k] = fmin(J.box_lo[3 * p + k], J.box_lo[3 * i + k]);
                J.box_hi[3 * p + k] = fmax(J.box_hi[3 * p + k], J.box_hi[3 * i + k]);
            }
        }
        /* a margin for the viewer's rounding: 1e-7 of the diagonal */
        char *ts = tileset_json(&J, 1e-7 * sqrt(diag2) + 1e-12, &J.st.tiles);
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
    if (r == HLOD_OK)
        r = into_place(tmp, dir, dl, exists, lg);
    free(J.box_lo);
    free(J.box_hi);
    if (r != HLOD_OK) {
        hlod_rm_tree(tmp);
        return r;
    }
    J.st.bytes = J.st.glb_bytes + J.st.tileset_bytes;
    if (stats)
        *stats = J.st;
    return HLOD_OK;
}
