/*
 * store_write.c - the store writer (API: hlod/store_write.h, format:
 * hlod/store.h).
 *
 * Design: the file is a temporary file from hlod_atomic_open, written only
 * with pwrite on its descriptor (its FILE* never buffers anything), so
 * threads write disjoint ranges without sharing a file position.  add()
 * serialises the payload into one buffer outside any lock, then takes the
 * mutex just long enough to reserve the next aligned offset and append a
 * record, and writes outside the lock.  Offsets are reserved in increasing
 * order, so the record array is sorted by offset and finish() finds a
 * node's payload by binary search.  finish() orders the caller's nodes
 * breadth-first (the reader's tree rule), writes the table after the last
 * payload and the header at offset 0, validates with the reader's own
 * hlod_store_validate, and only then commits (fsync + rename).
 *
 * Packed stores (desc.quant_step > 0; docs/store-format.md): add snaps the
 * node's origin to the store's position grid, puts every vertex on the grid,
 * orders each triangle range for the vertex cache and the vertices by first
 * use (meshoptimizer; what its codecs expect), derives the node's fields from
 * the quantized positions (so boxes hold what is drawn) and packs the
 * payload (payload_codec.c).  finish adds the grid's half cell diagonal to
 * every node's error: the stored surface lies that far from the exact one.
 */
#include "hlod/store_write.h"

#include "atomic_file.h"
#include "cubes.h"
#include "payload_codec.h"

#include <assert.h>
#include <errno.h>
#include <math.h>
#include <meshoptimizer.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* What finish needs to know about a written payload (the node's copy of
 * these must still agree). */
typedef struct payload_record {
    uint64_t offset, size, hash;
    double origin[3];
    uint32_t flags, vertex_count, tri_count, tex_tri_count;
    uint32_t tex_width, tex_height, tex_channels;
    uint8_t written;    /* pwrite completed */
    uint8_t used;       /* claimed by a node in finish */
    float cone_axis[3]; /* the normal cone of the payload's own faces (unit), as stored */
    float cone_cos;     /* its half-angle's cosine; -1: no bound; 2: no face */
    uint8_t has_cube;   /* cube holds the payload's colour cube (desc.cubes) */
    uint8_t cube[6][4];
} payload_record;

struct hlod_store_writer {
    hlod_atomic_file file;
    int fd;
    hlod_store_writer_desc desc;
    const hlod_logger *lg;
    pthread_mutex_t lock;       /* guards next, records, failed */
    uint64_t next;              /* next free aligned offset */
    payload_record *records;
    size_t record_count, record_cap;
    int failed;
    double quant_error;         /* half a grid cell's diagonal; 0 when raw */
    uint8_t (*colors)[4];       /* per node given to finish: its representative
                                   colour (hlod_store_writer_set_colors), or NULL */
    uint8_t (*cubes)[6][4];     /* ... its colour cube (hlod_store_writer_set_cubes) */
    uint32_t cube_count;
    uint32_t color_count;
    hlod_store_texture_stats tex;   /* guarded by lock */
};

static uint64_t align_up(uint64_t v, uint64_t a)
{
    return (v + a - 1) & ~(a - 1);
}

static int pwrite_all(int fd, const void *buf, size_t n, uint64_t off)
{
    const uint8_t *p = buf;
    while (n) {
        ssize_t k = pwrite(fd, p, n, (off_t)off);
        if (k < 0) {
            if (errno == EINTR)
                continue;
            return errno;
        }
        p += k;
        n -= (size_t)k;
        off += (uint64_t)k;
    }
    return 0;
}

hlod_result hlod_store_writer_open(const char *path, const hlod_store_writer_desc *desc,
                                   hlod_store_writer **out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    *out = NULL;
    if (!path || !desc)
        return HLOD_ERR_INVALID_ARG;
    const hlod_logger *lg = desc->logger;
    uint32_t align = desc->payload_align ? desc->payload_align : HLOD_STORE_DEFAULT_ALIGN;
    if (align < HLOD_STORE_MIN_ALIGN || align > HLOD_STORE_MAX_ALIGN || (align & (align - 1))) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: payload alignment %u is not a power of two in "
                  "[%u, %u]", path, align, HLOD_STORE_MIN_ALIGN, HLOD_STORE_MAX_ALIGN);
        return HLOD_ERR_INVALID_ARG;
    }
    const hlod_store_build_info *b = &desc->build;
    if (!(b->c_tex >= 0 && b->c_tex <= 1) || !isfinite(b->level_factor) ||
        b->level_factor < 0 || b->method > HLOD_STORE_METHOD_LAST || (b->flags & ~HLOD_BUILD_KNOWN_FLAGS) ||
        (b->flags && b->method != HLOD_STORE_METHOD_CUTPLANE)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: bad build parameters (method %u, c_tex %g, level "
                  "factor %g)", path, b->method, b->c_tex, b->level_factor);
        return HLOD_ERR_INVALID_ARG;
    }
    if (desc->cubes > 1) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cubes is %u, not 0 or 1", path, desc->cubes);
        return HLOD_ERR_INVALID_ARG;
    }
    if (desc->quant_step != 0) {
        int ex = 0;
        if (!(desc->quant_step > 0) || !isfinite(desc->quant_step) ||
            frexp(desc->quant_step, &ex) != 0.5 || !isfinite(desc->quant_origin[0]) ||
            !isfinite(desc->quant_origin[1]) || !isfinite(desc->quant_origin[2]) ||
            desc->jpeg_quality > 100 || desc->texture_blocks > 1 ||
            !(desc->texture_min_db >= 0 && desc->texture_min_db <= 99)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: position grid step %g is not a positive power of "
                      "two, its origin is not finite, JPEG quality %u is over 100 or the texture "
                      "floor %g dB is outside [0, 99]", path,
                      desc->quant_step, desc->jpeg_quality, desc->texture_min_db);
            return HLOD_ERR_INVALID_ARG;
        }
    }
    /* The codec versions every reader since meshoptimizer 0.14 decodes,
     * whatever a newer library would pick by default. */
    meshopt_encodeVertexVersion(0);
    meshopt_encodeIndexVersion(1);
    hlod_store_writer *w = calloc(1, sizeof *w);
    if (!w)
        return HLOD_ERR_NOMEM;
    if (pthread_mutex_init(&w->lock, NULL) != 0) {
        free(w);
        return HLOD_ERR_NOMEM;
    }
    hlod_result r = hlod_atomic_open(&w->file, path, lg);
    if (r != HLOD_OK) {
        pthread_mutex_destroy(&w->lock);
        free(w);
        return r;
    }
    w->fd = fileno(w->file.fp);
    w->desc = *desc;
    w->desc.payload_align = align;
    w->lg = lg;
    w->next = align_up(sizeof(hlod_store_header), align);
    w->quant_error = 0.5 * sqrt(3.0) * desc->quant_step;
    *out = w;
    return HLOD_OK;
}

void hlod_store_writer_abort(hlod_store_writer *w)
{
    if (!w)
        return;
    hlod_atomic_abort(&w->file);
    pthread_mutex_destroy(&w->lock);
    free(w->records);
    free(w->colors);
    free(w->cubes);
    free(w);
}

/* ---- add ---- */

static int finite_f(const float *v, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

/* Checks p; logs the first problem. */
static hlod_result check_desc(const hlod_store_payload_desc *p, const char *name,
                              const hlod_logger *lg)
{
    if (!p->vertex_count || !p->positions || !p->tri_count || !p->indices ||
        p->tri_count > UINT32_MAX / 3) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: payload with %u vertices, %u triangles", name,
                  p->vertex_count, p->tri_count);
        return HLOD_ERR_INVALID_ARG;
    }
    int textured = p->pixels != NULL;
    if (textured ? (!p->uvs || !p->tex_width || !p->tex_height || p->tex_channels < 1 ||
                    p->tex_channels > 4 || p->tex_width > HLOD_STORE_MAX_TEXTURE ||
                    p->tex_height > HLOD_STORE_MAX_TEXTURE || p->tex_tri_count > p->tri_count)
                 : (p->tex_width || p->tex_height || p->tex_channels || p->tex_tri_count)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: payload texture %ux%ux%u (%s pixels, %s UVs, %u of "
                  "%u triangles textured) is inconsistent", name, p->tex_width, p->tex_height,
                  p->tex_channels, textured ? "with" : "no", p->uvs ? "with" : "no",
                  p->tex_tri_count, p->tri_count);
        return HLOD_ERR_INVALID_ARG;
    }
    size_t v = p->vertex_count;
    int finite = isfinite(p->origin[0]) && isfinite(p->origin[1]) && isfinite(p->origin[2]);
    for (size_t i = 0; finite && i < 3 * v; i++)
        finite = isfinite(p->positions[i]) &&
                 isfinite((float)(p->positions[i] - p->origin[i % 3]));
    if (!finite || (p->normals && !finite_f(p->normals, 3 * v)) ||
        (p->uvs && !finite_f(p->uvs, 2 * v))) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: payload has non-finite vertex data", name);
        return HLOD_ERR_NAN;
    }
    for (size_t i = 0; i < 3 * (size_t)p->tri_count; i++)
        if (p->indices[i] >= p->vertex_count) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: payload index %zu is %u, vertex count %u", name, i,
                      p->indices[i], p->vertex_count);
            return HLOD_ERR_INDEX_RANGE;
        }
    return HLOD_OK;
}

/* Triangle t's edge cross product (b - a) x (c - a), in double: its
 * normal times twice its area. */
static void face_cross(const hlod_store_payload_desc *p, size_t t, double x[3])
{
    const double *a = p->positions + 3 * (size_t)p->indices[3 * t];
    const double *b = p->positions + 3 * (size_t)p->indices[3 * t + 1];
    const double *c = p->positions + 3 * (size_t)p->indices[3 * t + 2];
    double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    x[0] = u[1] * v[2] - u[2] * v[1];
    x[1] = u[2] * v[0] - u[0] * v[2];
    x[2] = u[0] * v[1] - u[1] * v[0];
}

/* A cone in floats, as the extras table holds it: the axis rounded, the
 * cosine rounded down by a margin that covers the axis's rounding (2 and
 * -1, no face and no bound, kept). */
static void cone_store(const double axis[3], double c, float out_axis[3], float *out_cos)
{
    for (int k = 0; k < 3; k++)
        out_axis[k] = (float)axis[k];
    if (c >= 2 || c <= -1) {
        *out_cos = c >= 2 ? 2.0f : -1.0f;
        return;
    }
    float f = (float)(c - 1e-6);
    while ((double)f > c - 1e-6)
        f = nextafterf(f, -2.0f);
    *out_cos = f < -1 ? -1.0f : f;
}

/* A face with an area: its edge cross product and that product's length. */
typedef struct cone_face {
    double x[3], len;
} cone_face;

/* The cosine of the widest of the n faces from the unit axis (2: none);
 * *far_out, that face's unit normal (the first such face on a tie). */
static double widest_face(const cone_face *f, size_t n, const double axis[3], double far_out[3])
{
    double lo = 2;
    size_t at = 0;
    for (size_t t = 0; t < n; t++) {
        double d = (f[t].x[0] * axis[0] + f[t].x[1] * axis[1] + f[t].x[2] * axis[2]) / f[t].len;
        if (d < lo) {
            lo = d;
            at = t;
        }
    }
    if (lo < 2)
        for (int k = 0; k < 3; k++)
            far_out[k] = f[at].x[k] / f[at].len;
    return lo;
}

/* Rounds of the axis's walk towards the widest face (face_cone). */
#define CONE_AXIS_ROUNDS 24

/* The cone of the faces' unit normals: an axis and the widest face from
 * it; cos 2 when no face has an area (nothing to bound), -1 when the
 * normals cancel out.  The axis starts at the area-weighted mean normal
 * and walks towards the widest face by 1/(i + 2) of the way in round i,
 * the minimal enclosing ball's iteration (Badoiu and Clarkson), kept
 * where the widest face is narrowest: the half-angle is never wider than
 * the mean's, and is often much narrower where the faces lean one way.  In
 * double, relative to each face's first corner; each face's cross product
 * is formed once, not once a round. */
static hlod_result face_cone(const hlod_store_payload_desc *p, double axis[3], double *cos_out)
{
    cone_face *f = malloc(((size_t)p->tri_count + 1) * sizeof *f);
    if (!f)
        return HLOD_ERR_NOMEM;
    double sum[3] = {0, 0, 0};
    size_t n = 0;
    for (size_t t = 0; t < p->tri_count; t++) {
        double *x = f[n].x;
        face_cross(p, t, x);
        double len = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        if (!(len > 0))
            continue; /* no area: draws nothing */
        for (int k = 0; k < 3; k++)
            sum[k] += x[k];
        f[n++].len = len;
    }
    double len = sqrt(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]);
    if (!n || !(len > 0)) {
        axis[0] = axis[1] = 0;
        axis[2] = 1;
        *cos_out = n ? -1 : 2;
        free(f);
        return HLOD_OK;
    }
    for (int k = 0; k < 3; k++)
        axis[k] = sum[k] / len;
    double far[3], best = widest_face(f, n, axis, far), cur[3];
    memcpy(cur, axis, sizeof cur);
    double c = best;
    for (int round = 0; round < CONE_AXIS_ROUNDS && c < 1; round++) {
        double step = 1.0 / (round + 2), n2 = 0;
        for (int k = 0; k < 3; k++) {
            cur[k] += (far[k] - cur[k]) * step;
            n2 += cur[k] * cur[k];
        }
        if (!(n2 > 1e-24))
            break;
        for (int k = 0; k < 3; k++)
            cur[k] /= sqrt(n2);
        c = widest_face(f, n, cur, far);
        if (c > best) {
            best = c;
            memcpy(axis, cur, sizeof cur);
        }
    }
    *cos_out = best < -1 ? -1 : best;
    free(f);
    return HLOD_OK;
}

/* face_cone of the faces a raw payload stores: float offsets from the
 * origin, so that a sliver whose orientation the rounding flips is bounded
 * as it is drawn. */
static hlod_result raw_face_cone(const hlod_store_payload_desc *p, double axis[3],
                                 double *cone_cos)
{
    double *pos = malloc(3 * sizeof *pos * (size_t)p->vertex_count);
    if (!pos)
        return HLOD_ERR_NOMEM;
    for (size_t i = 0; i < 3 * (size_t)p->vertex_count; i++)
        pos[i] = (double)(float)(p->positions[i] - p->origin[i % 3]);
    hlod_store_payload_desc d = *p;
    d.positions = pos;
    hlod_result r = face_cone(&d, axis, cone_cos);
    free(pos);
    return r;
}

/* Fills the fields of n that p determines (Lakhia eqs. 1-3). */
static void derive_node(const hlod_store_payload_desc *p, double c_tex, hlod_store_node *n)
{
    n->vertex_count = p->vertex_count;
    n->tri_count = p->tri_count;
    n->tex_tri_count = p->tex_tri_count;
    n->untex_tri_count = p->tri_count - p->tex_tri_count;
    n->tex_width = p->tex_width;
    n->tex_height = p->tex_height;
    n->tex_channels = p->tex_channels;
    memcpy(n->origin, p->origin, sizeof n->origin);
    for (int k = 0; k < 3; k++) {
        n->bbox_min[k] = INFINITY;
        n->bbox_max[k] = -INFINITY;
    }
    for (size_t i = 0; i < p->vertex_count; i++)
        for (int k = 0; k < 3; k++) {
            double x = p->positions[3 * i + k];
            n->bbox_min[k] = fmin(n->bbox_min[k], x);
            n->bbox_max[k] = fmax(n->bbox_max[k], x);
        }
    /* Areas and normals in double, relative to the origin (differences are
     * what matter; this keeps city-scale coordinates exact). */
    double area = 0, sum[3] = {0, 0, 0};
    for (size_t t = 0; t < p->tri_count; t++) {
        double x[3];
        face_cross(p, t, x);
        /* |x| / 2 is the area; x / 2 is the unit normal times the area */
        area += 0.5 * sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        for (int k = 0; k < 3; k++)
            sum[k] += 0.5 * x[k];
    }
    n->cost = hlod_store_cost(n->tex_tri_count, n->untex_tri_count, c_tex);   /* eq. 1 */
    n->static_benefit = sqrt((double)p->tri_count * area);                    /* eq. 2 */
    /* eq. 3; a closed surface's normals cancel out: store 0 (no
     * foreshortening preference) rather than a noise direction */
    double len = sqrt(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]);
    for (int k = 0; k < 3; k++)
        n->avg_normal[k] = len > 1e-9 * area && len > 0 ? (float)(sum[k] / len) : 0.0f;
}

static void write_section(uint8_t **dst, const void *src, size_t bytes)
{
    memcpy(*dst, src, bytes);
    *dst += bytes;
}

/* The raw layout of p (node->flags set) into a new buffer. */
static hlod_result serialize_raw(const hlod_store_payload_desc *p, const hlod_store_node *node,
                                 uint8_t **out, uint64_t *out_size)
{
    uint64_t size = hlod_store_payload_size(node->flags, p->vertex_count, 3 * p->tri_count,
                                            p->tex_width, p->tex_height, p->tex_channels);
    assert(size > 0);
    if (size > SIZE_MAX)
        return HLOD_ERR_NOMEM;
    uint8_t *buf = malloc((size_t)size);
    if (!buf)
        return HLOD_ERR_NOMEM;

    size_t v = p->vertex_count;
    hlod_store_payload_header ph;
    memset(&ph, 0, sizeof ph);
    memcpy(ph.magic, HLOD_PAYLOAD_MAGIC, 4);
    ph.flags = node->flags;
    ph.vertex_count = p->vertex_count;
    ph.index_count = 3 * p->tri_count;
    ph.tex_tri_count = p->tex_tri_count;
    ph.tex_width = p->tex_width;
    ph.tex_height = p->tex_height;
    ph.tex_channels = p->tex_channels;
    uint8_t *dst = buf;
    write_section(&dst, &ph, sizeof ph);
    for (size_t i = 0; i < 3 * v; i++) {
        float f = (float)(p->positions[i] - p->origin[i % 3]);
        write_section(&dst, &f, sizeof f);
    }
    if (p->normals)
        write_section(&dst, p->normals, 12 * v);
    if (p->uvs)
        write_section(&dst, p->uvs, 8 * v);
    if (p->colors)
        write_section(&dst, p->colors, 4 * v);
    write_section(&dst, p->indices, 12 * (size_t)p->tri_count);
    if (p->pixels)
        write_section(&dst, p->pixels,
                      (size_t)p->tex_width * p->tex_height * p->tex_channels);
    assert((uint64_t)(dst - buf) == size);
    *out = buf;
    *out_size = size;
    return HLOD_OK;
}

/* Vertex i of p moves to remap[i]: each triangle range in vertex-cache
 * order (meshopt_optimizeVertexCache), vertices in first-use order
 * (meshopt_optimizeVertexFetchRemap), unused vertices last in their order.
 * idx receives the triangles in the new vertex numbering. */
static void cache_order(const hlod_store_payload_desc *p, uint32_t *idx, uint32_t *remap)
{
    size_t v = p->vertex_count, ic = 3 * (size_t)p->tri_count, tc = 3 * (size_t)p->tex_tri_count;
    if (tc)
        meshopt_optimizeVertexCache(idx, p->indices, tc, v);
    if (ic > tc)
        meshopt_optimizeVertexCache(idx + tc, p->indices + tc, ic - tc, v);
    size_t used = meshopt_optimizeVertexFetchRemap(remap, idx, ic, v);
    for (size_t i = 0; i < v; i++)
        if (remap[i] == ~0u)
            remap[i] = (uint32_t)used++;
    meshopt_remapIndexBuffer(idx, idx, ic, remap);
}

/* The packed layout of p into a new buffer; fills node's derived fields from
 * the quantized positions and the snapped origin (node->flags set). */
static hlod_result serialize_packed(const hlod_store_writer *w, const hlod_store_payload_desc *p,
                                    hlod_store_node *node, uint8_t **out, uint64_t *out_size,
                                    double axis[3], double *cone_cos, hlod_packed_info *info)
{
    const char *name = w->file.final_path;
    const double q = w->desc.quant_step, *g0 = w->desc.quant_origin;
    const size_t v = p->vertex_count, ic = 3 * (size_t)p->tri_count;
    hlod_result r = HLOD_ERR_NOMEM;
    uint32_t *idx = malloc(ic * sizeof *idx), *remap = malloc(v * sizeof *remap);
    int64_t *grid = malloc(3 * v * sizeof *grid);
    double *pos = malloc(3 * v * sizeof *pos);
    float *nrm = p->normals ? malloc(12 * v) : NULL, *uvs = p->uvs ? malloc(8 * v) : NULL;
    uint8_t *col = p->colors ? malloc(4 * v) : NULL;
    if (!idx || !remap || !grid || !pos || (p->normals && !nrm) || (p->uvs && !uvs) ||
        (p->colors && !col))
        goto done;
    hlod_store_payload_desc d = *p;
    for (int k = 0; k < 3; k++) {
        double t = rint((p->origin[k] - g0[k]) / q);
        d.origin[k] = g0[k] + t * q;
    }
    cache_order(p, idx, remap);
    r = HLOD_ERR_INVALID_ARG;
    for (size_t i = 0; i < v; i++) {
        size_t j = remap[i];
        for (int k = 0; k < 3; k++) {
            double t = rint((p->positions[3 * i + k] - d.origin[k]) / q);
            if (!(fabs(t) < 2147483647.0)) {
                hlod_logf(w->lg, HLOD_LOG_ERROR, "%s: a vertex lies %g from its node's origin "
                          "on axis %d, past the 2^31 steps of %g that the store's grid holds",
                          name, p->positions[3 * i + k] - d.origin[k], k, q);
                goto done;
            }
            grid[3 * j + k] = (int64_t)t;
            pos[3 * j + k] = d.origin[k] + t * q;
        }
        if (nrm)
            memcpy(nrm + 3 * j, p->normals + 3 * i, 12);
        if (uvs)
            memcpy(uvs + 2 * j, p->uvs + 2 * i, 8);
        if (col)
            memcpy(col + 4 * j, p->colors + 4 * i, 4);
    }
    d.positions = pos;
    d.indices = idx;
    d.normals = nrm;
    d.uvs = uvs;
    d.colors = col;
    derive_node(&d, w->desc.build.c_tex, node);
    r = face_cone(&d, axis, cone_cos); /* of the faces as stored, on the grid */
    if (r != HLOD_OK)
        goto done;
    hlod_packed_input in = {
        .flags = node->flags, .vertex_count = p->vertex_count, .tri_count = p->tri_count,
        .tex_tri_count = p->tex_tri_count, .grid = grid, .normals = nrm, .uvs = uvs,
        .colors = col, .indices = idx, .tex_width = p->tex_width, .tex_height = p->tex_height,
        .tex_channels = p->tex_channels, .pixels = p->pixels,
        .jpeg_quality = (int)w->desc.jpeg_quality,
        .texture_blocks = (int)w->desc.texture_blocks,
        .texture_min_db = w->desc.texture_min_db,
    };
    size_t size = 0;
    r = hlod_payload_pack(&in, out, &size, info, name, w->lg);
    *out_size = size;
done:
    free(idx);
    free(remap);
    free(grid);
    free(pos);
    free(nrm);
    free(uvs);
    free(col);
    return r;
}

/* called from any thread */
static hlod_result store_payload(hlod_store_writer *w, uint8_t *buf, uint64_t size,
                                 hlod_store_node *node, const double axis[3], double cone_cos,
                                 int stored, const uint8_t (*cube)[4]);

/* called from any thread: one stored texture of codec HLOD_TEX_* */
static void count_texture(hlod_store_writer *w, uint32_t codec, double db)
{
    pthread_mutex_lock(&w->lock);
    hlod_store_texture_stats *t = &w->tex;
    if (codec == HLOD_TEX_BC)
        t->bc++;
    else if (codec == HLOD_TEX_JPEG)
        t->jpeg++;
    else
        t->raw++;
    if (db > 0 && (t->db_min == 0 || db < t->db_min))
        t->db_min = db;
    pthread_mutex_unlock(&w->lock);
}

void hlod_store_writer_texture_stats(const hlod_store_writer *w, hlod_store_texture_stats *out)
{
    memset(out, 0, sizeof *out);
    if (w)
        *out = w->tex;
}

hlod_result hlod_store_writer_add(hlod_store_writer *w, const hlod_store_payload_desc *p,
                                  hlod_store_node *node)
{
    if (!w || !p || !node)
        return HLOD_ERR_INVALID_ARG;
    const char *name = w->file.final_path;
    hlod_result r = check_desc(p, name, w->lg);
    if (r != HLOD_OK)
        return r;
    memset(node, 0, sizeof *node);
    node->flags = (p->normals ? HLOD_NODE_NORMALS : 0) | (p->uvs ? HLOD_NODE_UVS : 0) |
                  (p->colors ? HLOD_NODE_COLORS : 0) | (p->pixels ? HLOD_NODE_TEXTURE : 0);
    uint8_t *buf = NULL;
    uint64_t size = 0;
    double axis[3], cone_cos = -1;
    if (w->desc.quant_step > 0) {
        hlod_packed_info info;
        r = serialize_packed(w, p, node, &buf, &size, axis, &cone_cos, &info);
        if (r == HLOD_OK && p->pixels)
            count_texture(w, info.tex_codec, info.tex_db);
    } else {
        r = serialize_raw(p, node, &buf, &size);
        if (r == HLOD_OK) {
            derive_node(p, w->desc.build.c_tex, node);
            r = raw_face_cone(p, axis, &cone_cos);
            if (r != HLOD_OK)
                free(buf);
        }
    }
    uint8_t cube[6][4];
    if (r == HLOD_OK && w->desc.cubes && (r = hlod_cube_of_payload(p, cube)) != HLOD_OK)
        free(buf);
    if (r != HLOD_OK)
        return r;
    return store_payload(w, buf, size, node, axis, cone_cos, 0,
                         w->desc.cubes ? (const uint8_t (*)[4])cube : NULL);
}

/* Writes the serialized payload buf (size bytes, freed here) at the next
 * aligned offset and completes *node's payload fields. */
static hlod_result store_payload(hlod_store_writer *w, uint8_t *buf, uint64_t size,
                                 hlod_store_node *node, const double axis[3], double cone_cos,
                                 int stored, const uint8_t (*cube)[4])
{
    const char *name = w->file.final_path;
    uint64_t hash = hlod_store_hash(buf, (size_t)size);

    /* Reserve the offset and the record; write outside the lock. */
    pthread_mutex_lock(&w->lock);
    if (w->failed) {
        pthread_mutex_unlock(&w->lock);
        free(buf);
        hlod_logf(w->lg, HLOD_LOG_ERROR, "%s: store writer already failed", name);
        return HLOD_ERR_IO;
    }
    if (w->record_count == w->record_cap) {
        size_t cap = w->record_cap ? 2 * w->record_cap : 256;
        payload_record *nr = realloc(w->records, cap * sizeof *nr);
        if (!nr) {
            w->failed = 1;
            pthread_mutex_unlock(&w->lock);
            free(buf);
            return HLOD_ERR_NOMEM;
        }
        w->records = nr;
        w->record_cap = cap;
    }
    size_t idx = w->record_count++;
    uint64_t offset = w->next;
    w->next = align_up(offset + size, w->desc.payload_align);
    payload_record *rec = &w->records[idx];
    memset(rec, 0, sizeof *rec);
    rec->offset = offset;
    rec->size = size;
    rec->hash = hash;
    memcpy(rec->origin, node->origin, sizeof rec->origin);
    rec->flags = node->flags;
    rec->vertex_count = node->vertex_count;
    rec->tri_count = node->tri_count;
    rec->tex_tri_count = node->tex_tri_count;
    rec->tex_width = node->tex_width;
    rec->tex_height = node->tex_height;
    rec->tex_channels = node->tex_channels;
    if (stored) { /* a cone as a store holds it: kept exactly */
        for (int k = 0; k < 3; k++)
            rec->cone_axis[k] = (float)axis[k];
        rec->cone_cos = (float)cone_cos;
    } else {
        cone_store(axis, cone_cos, rec->cone_axis, &rec->cone_cos);
    }
    if (cube) {
        memcpy(rec->cube, cube, sizeof rec->cube);
        rec->has_cube = 1;
    }
    pthread_mutex_unlock(&w->lock);

    int e = pwrite_all(w->fd, buf, (size_t)size, offset);
    free(buf);
    pthread_mutex_lock(&w->lock);
    if (e)
        w->failed = 1;
    else
        w->records[idx].written = 1;    /* records may have moved: index again */
    pthread_mutex_unlock(&w->lock);
    if (e) {
        hlod_logf(w->lg, HLOD_LOG_ERROR, "%s: cannot write payload: %s", name, strerror(e));
        return HLOD_ERR_IO;
    }
    node->payload_offset = offset;
    node->payload_size = size;
    node->payload_hash = hash;
    return HLOD_OK;
}

hlod_result hlod_store_writer_add_copy(hlod_store_writer *w, const hlod_store_node *src,
                                       const void *bytes, const hlod_store_extra *src_extra,
                                       hlod_store_node *node)
{
    if (!w || !src || !bytes || !node || !src->payload_size || src->payload_size > SIZE_MAX)
        return HLOD_ERR_INVALID_ARG;
    if (hlod_store_hash(bytes, (size_t)src->payload_size) != src->payload_hash) {
        hlod_logf(w->lg, HLOD_LOG_ERROR, "%s: a copied payload does not match its checksum",
                  w->file.final_path);
        return HLOD_ERR_CHECKSUM;
    }
    uint8_t *buf = malloc((size_t)src->payload_size);
    if (!buf)
        return HLOD_ERR_NOMEM;
    memcpy(buf, bytes, (size_t)src->payload_size);
    if ((src->flags & HLOD_NODE_TEXTURE) && w->desc.quant_step > 0 &&
        src->payload_size >= sizeof(hlod_store_packed_header)) {
        hlod_store_packed_header ph;
        memcpy(&ph, buf, sizeof ph);
        count_texture(w, ph.tex_codec, ph.tex_db);
    }
    *node = *src;
    node->parent = 0;
    node->first_child = 0;
    node->depth = 0;
    node->block = 0;
    node->error = 0;
    /* the source's cone bounds its subtree, so its own faces too (a record
     * without one: no face under it) */
    double axis[3] = {0, 0, 1}, cone_cos = src_extra ? 2 : -1;
    if (src_extra && (src_extra->flags & HLOD_EXTRA_CONE)) {
        for (int k = 0; k < 3; k++)
            axis[k] = src_extra->cone_axis[k];
        cone_cos = src_extra->cone_cos;
    }
    return store_payload(w, buf, src->payload_size, node, axis, cone_cos, src_extra != NULL,
                         src_extra && (src_extra->flags & HLOD_EXTRA_CUBE)
                             ? (const uint8_t (*)[4])src_extra->cube
                             : NULL);
}

/* ---- finish ---- */

static payload_record *find_record(hlod_store_writer *w, uint64_t offset)
{
    size_t lo = 0, hi = w->record_count;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (w->records[mid].offset < offset)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < w->record_count && w->records[lo].offset == offset ? &w->records[lo] : NULL;
}

/* Does node n (in store order, index i) still describe record rec? */
static int node_matches(const hlod_store_node *n, const payload_record *rec)
{
    return rec->written && n->payload_size == rec->size && n->payload_hash == rec->hash &&
           n->flags == rec->flags && n->vertex_count == rec->vertex_count &&
           n->tri_count == rec->tri_count && n->tex_tri_count == rec->tex_tri_count &&
           n->untex_tri_count == rec->tri_count - rec->tex_tri_count &&
           n->tex_width == rec->tex_width && n->tex_height == rec->tex_height &&
           n->tex_channels == rec->tex_channels &&
           memcmp(n->origin, rec->origin, sizeof n->origin) == 0;
}

/* Breadth-first order of the caller's nodes: order[pos] = caller index,
 * child_count[k] = children of caller node k.  Roots by block. */
static hlod_result bfs_order(const hlod_store_node *nodes, uint32_t count, uint32_t *order,
                             uint32_t *child_count, uint32_t *root_count, const char *name,
                             const hlod_logger *lg)
{
    hlod_result r = HLOD_ERR_NOMEM;
    uint32_t *start = calloc((size_t)count + 1, sizeof *start);  /* CSR of children */
    uint32_t *kids = malloc((size_t)count * sizeof *kids);
    uint32_t *fill = malloc((size_t)count * sizeof *fill);
    if (!start || !kids || !fill)
        goto done;
    r = HLOD_ERR_INVALID_ARG;
    uint32_t roots = 0;
    memset(child_count, 0, (size_t)count * sizeof *child_count);
    for (uint32_t k = 0; k < count; k++) {
        uint32_t p = nodes[k].parent;
        if (p == HLOD_STORE_NO_PARENT) {
            roots++;
        } else if (p >= count || p == k) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u: parent %u is not another of the %u "
                      "nodes", name, k, p, count);
            goto done;
        } else {
            child_count[p]++;
        }
    }
    if (roots == 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: no root node (parent = HLOD_STORE_NO_PARENT)", name);
        goto done;
    }
    /* block roots go to order[block]; group roots (HLOD_STORE_NO_BLOCK)
     * keep the caller's order */
    uint32_t group_roots = 0;
    for (uint32_t k = 0; k < count; k++)
        group_roots += nodes[k].parent == HLOD_STORE_NO_PARENT && nodes[k].block == HLOD_STORE_NO_BLOCK;
    if (group_roots && group_roots != roots) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %u of the %u roots are group nodes: roots must be "
                  "all blocks or all groups", name, group_roots, roots);
        goto done;
    }
    for (uint32_t i = 0; i < roots; i++)
        order[i] = UINT32_MAX;
    for (uint32_t k = 0, g = 0; k < count; k++) {
        if (nodes[k].parent != HLOD_STORE_NO_PARENT)
            continue;
        uint32_t b = group_roots ? g++ : nodes[k].block;
        if (b >= roots || order[b] != UINT32_MAX) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: root node %u has block %u; the %u roots need "
                      "blocks 0..%u, one each", name, k, b, roots, roots - 1);
            goto done;
        }
        order[b] = k;
    }
    for (uint32_t k = 0; k < count; k++)
        start[k + 1] = start[k] + child_count[k];
    memcpy(fill, start, (size_t)count * sizeof *fill);
    for (uint32_t k = 0; k < count; k++)   /* stable: children keep caller order */
        if (nodes[k].parent != HLOD_STORE_NO_PARENT)
            kids[fill[nodes[k].parent]++] = k;
    uint32_t len = roots;
    for (uint32_t pos = 0; pos < len; pos++) {
        uint32_t k = order[pos];
        for (uint32_t c = start[k]; c < start[k + 1]; c++)
            order[len++] = kids[c];
    }
    if (len != count) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %u of %u nodes are not reachable from a root "
                  "(a parent cycle)", name, count - len, count);
        goto done;
    }
    *root_count = roots;
    r = HLOD_OK;
done:
    free(start);
    free(kids);
    free(fill);
    return r;
}

/* The node table in store order (finish's first half): first_child,
 * parent, depth and block of every node, checked against the payloads
 * added.  Sets the block count, their depth and the top node count. */
static hlod_result fill_table(hlod_store_writer *w, const hlod_store_node *nodes, uint32_t count,
                              const uint32_t *order, const uint32_t *child_count,
                              const uint32_t *index, uint32_t roots, hlod_store_node *table,
                              uint32_t *blocks_out, uint32_t *depth_out, uint32_t *top_out)
{
    const hlod_logger *lg = w->lg;
    const char *name = w->file.final_path;
    /* The table in store order; children of pos are [first_child, next's).
     * A node the caller marked HLOD_STORE_NO_BLOCK is a group; a node under
     * a group or at the top that is not one is a block's hlod_0 node, and
     * blocks are numbered in store order. */
    uint32_t next_child = roots, blocks = 0, block_depth = 0, top = 0;
    hlod_result r = HLOD_ERR_INVALID_ARG;
    for (uint32_t pos = 0; pos < count; pos++) {
        uint32_t k = order[pos];
        hlod_store_node *t = &table[pos];
        *t = nodes[k];
        t->error += w->quant_error;
        t->first_child = next_child;
        next_child += child_count[k];
        int group = nodes[k].block == HLOD_STORE_NO_BLOCK;
        uint32_t up = HLOD_STORE_NO_BLOCK;
        if (nodes[k].parent == HLOD_STORE_NO_PARENT) {
            t->parent = HLOD_STORE_NO_PARENT;
            t->depth = 0;
        } else {
            t->parent = index[nodes[k].parent];
            t->depth = table[t->parent].depth + 1;  /* parent comes first in BFS */
            up = table[t->parent].block;
        }
        if (group && up != HLOD_STORE_NO_BLOCK) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u: a group node under block %u", name, k, up);
            return r;
        }
        if (group && !child_count[k]) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u: a group node without children", name, k);
            return r;
        }
        if (group) {
            t->block = HLOD_STORE_NO_BLOCK;
            top = pos + 1;
        } else if (up == HLOD_STORE_NO_BLOCK) {
            if (blocks && t->depth != block_depth) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u: a block at depth %u, another at %u: "
                          "every block's hlod_0 node needs the same depth", name, k, t->depth,
                          block_depth);
                return r;
            }
            block_depth = t->depth;
            t->block = blocks++;
            top = pos + 1;
        } else {
            t->block = up;
        }
        payload_record *rec = find_record(w, t->payload_offset);
        if (!rec || !node_matches(t, rec)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u (store node %u): its payload fields do "
                      "not match a payload added to this writer", name, k, pos);
            return r;
        }
        if (rec->used) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u: payload at %llu is used by two nodes",
                      name, k, (unsigned long long)rec->offset);
            return r;
        }
        rec->used = 1;
    }
    *blocks_out = blocks;
    *depth_out = block_depth;
    *top_out = top;
    return HLOD_OK;
}

/* cos(angle between unit a and b + the half-angle whose cosine is c): the
 * cosine of the widest normal of a cone (b, c) seen from a; -1 past 180. */
static double widest_from(const float a[3], const float b[3], double c)
{
    double d = (double)a[0] * b[0] + (double)a[1] * b[1] + (double)a[2] * b[2];
    double alpha = acos(d > 1 ? 1 : d < -1 ? -1 : d), theta = acos(c > 1 ? 1 : c < -1 ? -1 : c);
    return alpha + theta >= M_PI ? -1 : cos(alpha + theta);
}

/* The extras of the table in store order: each node's normal cone bounds
 * its own faces and every descendant's.  Its axis is its own faces' (the
 * first child's when it has none), and the cosine the least of its own and
 * each child's cone's widest normal seen from that axis, in floats as
 * stored, so that a merge, which hands each copied node its subtree's cone
 * as its own, gets the same bytes (the cone of a node taken with its
 * children's again is itself).  A node drawn two-sided (not
 * HLOD_RENDER_SOLID) or under which one is, never culls (cos -1). */
static void subtree_cones(hlod_store_writer *w, const hlod_store_node *table, uint32_t count,
                          hlod_store_extra *x)
{
    for (uint32_t pos = count; pos-- > 0;) {
        const hlod_store_node *t = &table[pos];
        const payload_record *rec = find_record(w, t->payload_offset);
        float axis[3] = {rec->cone_axis[0], rec->cone_axis[1], rec->cone_axis[2]};
        double c = rec->cone_cos;
        uint32_t c0 = t->first_child, c1 = table[pos + 1].first_child;
        if (c >= 2)
            for (uint32_t k = c0; k < c1; k++)
                if (x[k].cone_cos < 2) {
                    memcpy(axis, x[k].cone_axis, sizeof axis);
                    break;
                }
        int two_sided = !(t->render_flags & HLOD_RENDER_SOLID) || c <= -1;
        for (uint32_t k = c0; k < c1 && !two_sided; k++) {
            if (x[k].cone_cos >= 2)
                continue; /* nothing drawn under it */
            if (x[k].cone_cos <= -1) {
                two_sided = 1;
                break;
            }
            double wide = widest_from(axis, x[k].cone_axis, x[k].cone_cos);
            c = wide < c ? wide : c;
        }
        x[pos].flags = HLOD_EXTRA_CONE;
        memcpy(x[pos].cone_axis, axis, sizeof axis);
        if (two_sided || c <= -1) {
            x[pos].cone_cos = -1;
        } else if (c >= 2) {
            x[pos].cone_cos = 2; /* no face: replaced below once the children are done */
        } else {
            /* rounded down, no margin: the terms are exact in the floats
             * stored, and a cosine already stored comes back unchanged */
            float f = (float)c;
            x[pos].cone_cos = (double)f > c ? nextafterf(f, -2.0f) : f;
        }
    }
    /* a subtree without a face bounds nothing: no cone (and no culling) */
    for (uint32_t pos = 0; pos < count; pos++)
        if (x[pos].cone_cos >= 2)
            memset(&x[pos], 0, sizeof x[pos]);
    /* the payloads' own cubes (desc.cubes, or a copy's) */
    for (uint32_t pos = 0; pos < count; pos++) {
        const payload_record *rec = find_record(w, table[pos].payload_offset);
        if (rec->has_cube) {
            memcpy(x[pos].cube, rec->cube, sizeof x[pos].cube);
            x[pos].flags |= HLOD_EXTRA_CUBE;
        }
    }
}

/* The per-node colours and colour cubes given before finish, into the
 * extras records (index: the given order's node in the table);
 * HLOD_ERR_INVALID_ARG (logged) when a count is not the table's. */
static hlod_result given_extras(const hlod_store_writer *w, const char *name, uint32_t count,
                                const uint32_t *index, hlod_store_extra *extras)
{
    const hlod_logger *lg = w->desc.logger;
    if (w->colors && w->color_count != count) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %u node colours for %u nodes", name, w->color_count,
                  count);
        return HLOD_ERR_INVALID_ARG;
    }
    if (w->cubes && w->cube_count != count) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %u colour cubes for %u nodes", name, w->cube_count,
                  count);
        return HLOD_ERR_INVALID_ARG;
    }
    for (uint32_t k = 0; w->colors && k < count; k++) {
        memcpy(extras[index[k]].color, w->colors[k], 4);
        extras[index[k]].flags |= HLOD_EXTRA_COLOR;
    }
    for (uint32_t k = 0; w->cubes && k < count; k++) {
        memcpy(extras[index[k]].cube, w->cubes[k], sizeof w->cubes[k]);
        extras[index[k]].flags |= HLOD_EXTRA_CUBE;
    }
    return HLOD_OK;
}

/* called from the owner thread */
hlod_result hlod_store_writer_finish(hlod_store_writer *w, const hlod_store_node *nodes,
                                     uint32_t count, uint32_t *store_index)
{
    if (!w)
        return HLOD_ERR_INVALID_ARG;
    const hlod_logger *lg = w->lg;
    const char *name = w->file.final_path;
    hlod_result r = HLOD_ERR_INVALID_ARG;
    uint32_t *order = NULL, *child_count = NULL, *index = NULL;
    hlod_store_node *table = NULL;
    hlod_store_extra *extras = NULL;
    if (!nodes || count == 0 || count >= UINT32_MAX) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %u nodes given to finish", name, count);
        goto fail;
    }
    if (w->failed) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: a payload write failed; not finishing", name);
        r = HLOD_ERR_IO;
        goto fail;
    }
    r = HLOD_ERR_NOMEM;
    order = malloc((size_t)count * sizeof *order);
    child_count = malloc((size_t)count * sizeof *child_count);
    index = malloc((size_t)count * sizeof *index);
    table = calloc((size_t)count + 1, sizeof *table);
    if (!order || !child_count || !index || !table)
        goto fail;
    uint32_t roots = 0;
    r = bfs_order(nodes, count, order, child_count, &roots, name, lg);
    if (r != HLOD_OK)
        goto fail;
    for (uint32_t pos = 0; pos < count; pos++)
        index[order[pos]] = pos;

    uint32_t blocks = 0, block_depth = 0, top = 0;
    r = fill_table(w, nodes, count, order, child_count, index, roots, table, &blocks, &block_depth, &top);
    if (r != HLOD_OK)
        goto fail;
    table[count].first_child = count;   /* the sentinel */
    for (size_t i = 0; i < w->record_count; i++)
        if (!w->records[i].used) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: payload at offset %llu belongs to no node", name,
                      (unsigned long long)w->records[i].offset);
            r = HLOD_ERR_INVALID_ARG;
            goto fail;
        }

    hlod_store_header h;
    memset(&h, 0, sizeof h);
    memcpy(h.magic, HLOD_STORE_MAGIC, 8);
    h.version = HLOD_STORE_VERSION;
    h.endian = HLOD_STORE_ENDIAN;
    h.header_size = sizeof(hlod_store_header);
    h.node_size = sizeof(hlod_store_node);
    h.node_count = count;
    h.root_count = roots;
    h.block_count = blocks;
    h.block_depth = block_depth;
    h.top_count = top;
    h.payload_align = w->desc.payload_align;
    h.build = w->desc.build;
    if (w->desc.quant_step > 0) {
        h.payload_codec = HLOD_STORE_CODEC_PACKED;
        h.quant_step = w->desc.quant_step;
        memcpy(h.quant_origin, w->desc.quant_origin, sizeof h.quant_origin);
    }
    for (int k = 0; k < 3; k++) {
        h.bbox_min[k] = INFINITY;
        h.bbox_max[k] = -INFINITY;
    }
    for (uint32_t i = 0; i < count; i++) {
        const hlod_store_node *t = &table[i];
        if (t->depth + 1 > h.depth_count)
            h.depth_count = t->depth + 1;
        if (t->flags & HLOD_NODE_TEXTURE)
            h.flags |= HLOD_STORE_TEXTURED;
        if (h.build.method == HLOD_STORE_METHOD_SAMPLETREE ||
            h.build.method == HLOD_STORE_METHOD_CUBES)
            h.flags |= HLOD_STORE_ADDITIVE;
        h.payload_bytes += t->payload_size;
        for (int k = 0; k < 3; k++) {
            h.bbox_min[k] = fmin(h.bbox_min[k], t->bbox_min[k]);
            h.bbox_max[k] = fmax(h.bbox_max[k], t->bbox_max[k]);
        }
    }
    h.node_table_offset = w->next;      /* aligned, after the last payload */
    h.node_table_size = ((uint64_t)count + 1) * sizeof(hlod_store_node);
    extras = calloc(count, sizeof *extras);
    if (!extras) {
        r = HLOD_ERR_NOMEM;
        goto fail;
    }
    subtree_cones(w, table, count, extras);
    if ((r = given_extras(w, name, count, index, extras)) != HLOD_OK)
        goto fail;
    hlod_store_extras_header xh;
    memset(&xh, 0, sizeof xh);
    memcpy(xh.magic, HLOD_EXTRAS_MAGIC, 8);
    xh.count = count;
    xh.record_size = sizeof(hlod_store_extra);
    xh.hash = hlod_store_hash(extras, (size_t)count * sizeof *extras);
    h.extras_size = sizeof(hlod_store_extra);
    h.extras_offset = h.node_table_offset + h.node_table_size;
    h.file_size = h.extras_offset + sizeof xh + (uint64_t)count * sizeof *extras;
    h.node_table_hash = hlod_store_hash(table, (size_t)h.node_table_size);
    h.header_hash = hlod_store_hash(&h, HLOD_STORE_HEADER_HASHED);

    /* Never commit what the reader would refuse. */
    r = hlod_store_validate(&h, table, h.file_size, name, lg);
    if (r != HLOD_OK)
        goto fail;
    r = hlod_store_check_extras(&h, &xh, extras, name, lg);
    if (r != HLOD_OK)
        goto fail;
    int e = pwrite_all(w->fd, table, (size_t)h.node_table_size, h.node_table_offset);
    if (!e)
        e = pwrite_all(w->fd, &xh, sizeof xh, h.extras_offset);
    if (!e)
        e = pwrite_all(w->fd, extras, (size_t)count * sizeof *extras, h.extras_offset + sizeof xh);
    if (!e)
        e = pwrite_all(w->fd, &h, sizeof h, 0);
    if (e) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write the node table: %s", name, strerror(e));
        r = HLOD_ERR_IO;
        goto fail;
    }
    r = hlod_atomic_commit(&w->file, lg);   /* fsync + rename; aborts itself on error */
    if (r != HLOD_OK)
        goto fail;
    if (store_index)
        memcpy(store_index, index, (size_t)count * sizeof *index);
fail:
    free(extras);
    free(order);
    free(child_count);
    free(index);
    free(table);
    hlod_store_writer_abort(w);     /* after a commit: only frees */
    return r;
}

/* A per-node table given before finish: *dst becomes a copy of
 * src[0..count) of elem bytes each (count 0: none), *n its count. */
static hlod_result set_table(void *dst, uint32_t *n, const void *src, uint32_t count, size_t elem)
{
    void *old, *copy = NULL;
    memcpy(&old, dst, sizeof old);
    if (count && !(copy = malloc((size_t)count * elem)))
        return HLOD_ERR_NOMEM;
    if (count)
        memcpy(copy, src, (size_t)count * elem);
    free(old);
    memcpy(dst, &copy, sizeof copy);
    *n = count;
    return HLOD_OK;
}

hlod_result hlod_store_writer_set_colors(hlod_store_writer *w, const uint8_t (*colors)[4],
                                         uint32_t count)
{
    if (!w || (!colors && count))
        return HLOD_ERR_INVALID_ARG;
    return set_table(&w->colors, &w->color_count, colors, count, sizeof *w->colors);
}

hlod_result hlod_store_writer_set_cubes(hlod_store_writer *w, const uint8_t (*cubes)[6][4],
                                        uint32_t count)
{
    if (!w || (!cubes && count))
        return HLOD_ERR_INVALID_ARG;
    return set_table(&w->cubes, &w->cube_count, cubes, count, sizeof *w->cubes);
}
