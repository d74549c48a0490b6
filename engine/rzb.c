/*
 * rzb.c - Wand's randomized z-buffer over a store's leaves (rzb.h,
 * docs/rzb.md).
 *
 * Layout: the triangles of each area class in one array, in the depth-
 * first order of the class's octree (a node's children's triangles, then
 * its own), with the prefix sums of their areas beside it, so that every
 * node owns one range and its area is cum[end] - cum[begin] (section
 * 5.3).  A triangle sits in the deepest octree cell whose loose box (the
 * cell grown by half its side on every side) holds it; a class's
 * triangles are within RZB_CLASS_FACTOR in area, so most sit near the
 * depth where a cell is about their size.  Corners are floats relative to
 * the class's origin (the centre of its box): a model far from the world
 * origin is drawn as it is near it.
 */
#include "rzb.h"

#include "sort.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define RZB_CLASS_FACTOR 4.0 /* areas within a class (Wand 7.1: 2 to 64 alike) */
#define RZB_MAX_CLASSES 64
#define RZB_LEAF_TRIS 32     /* an octree cell of more triangles splits */
#define RZB_MAX_DEPTH 32
#define RZB_MAX_SAMPLES (8u << 20) /* points a frame at most (the rest are dropped) */
#define RZB_GREY 204               /* the renderer's colour for faces without one */

typedef struct rzb_tri {
    float p[3][3];        /* corners relative to the class origin */
    float n[3];           /* unit face normal */
    uint8_t rgba[3][4];   /* corner colours */
    uint32_t leaf;        /* the store node */
    uint32_t two_sided;   /* drawn both ways: no back-face rejection */
} rzb_tri;

typedef struct rzb_in {   /* a face as added, before the classes */
    double p[3][3];
    double area;
    float n[3];
    uint8_t rgba[3][4];
    uint32_t leaf, two_sided;
} rzb_in;

typedef struct rzb_node {
    double lo[3], hi[3];     /* the box of the subtree's faces, world */
    uint32_t begin, own, end; /* the subtree's range; its own faces [own, end) */
    uint32_t kid[8];
    uint32_t kids;
} rzb_node;

typedef struct rzb_class {
    hlod_gpu_node gpu;       /* its faces for the rasteriser (hlod_rzb_upload) */
    double origin[3];
    double max_area;
    rzb_tri *tri;
    double *cum;             /* count + 1 prefix sums, cum[0] = 0 */
    uint32_t count;
    rzb_node *node;
    uint32_t nodes, node_cap;
} rzb_class;

/* A cached point: snapped to its cell's centre (relative to the class
 * origin), its face's normal and two-sidedness, its unlit colour. */
typedef struct cache_pt {
    float p[3];
    int16_t n[3];
    uint8_t rgb[3];
    uint8_t two_sided;
} cache_pt; /* 24 bytes */

typedef struct rzb_cache rzb_cache;
struct rzb_cache {
    uint64_t key;        /* class, node and own-faces flag, + 1; 0: a free slot */
    uint64_t copy;       /* the copy drawn (hlod_rzb_set_copies): its column << 32 | row */
    int level;           /* cells of 2^level model units */
    uint32_t used;       /* the frame it was last drawn */
    uint32_t count;
    cache_pt *pt;
};

struct hlod_rzb {
    const hlod_allocator *a;
    rzb_in *in;
    size_t in_count, in_cap;
    rzb_class cls[RZB_MAX_CLASSES];
    uint32_t class_count;
    size_t tri_count;
    int finished;
    uint32_t *stack;
    size_t stack_cap;
    struct rzb_cache *cache;   /* sample caches by box (section 7.2), open addressing */
    size_t cache_slots, cache_used, cache_bytes, cache_limit;
    /* instancing (section 7.3; hlod_rzb_set_copies) */
    uint32_t copy_levels;      /* 2^levels x 2^levels copies; 0: the scene once */
    double box_lo[3], box_hi[3]; /* the scene's box (its classes' roots) */
    double class_cum[RZB_MAX_CLASSES + 1]; /* prefix sums of the classes' areas */
    double max_area;           /* the largest face's */
    struct copy_block *blocks; /* the copies' walk */
    size_t block_cap;
};

/* A square block of copies: 2^level on a side, the first at column i, row j. */
typedef struct copy_block {
    uint32_t level, i, j;
} copy_block;

hlod_rzb *hlod_rzb_create(const hlod_allocator *a)
{
    hlod_rzb *z = hlod_mem_alloc(a, sizeof *z);
    if (z) {
        memset(z, 0, sizeof *z);
        z->a = a;
    }
    return z;
}

void hlod_rzb_destroy(hlod_rzb *z)
{
    if (!z)
        return;
    for (uint32_t c = 0; c < z->class_count; c++) {
        hlod_mem_free(z->a, z->cls[c].tri);
        hlod_mem_free(z->a, z->cls[c].cum);
        hlod_mem_free(z->a, z->cls[c].node);
    }
    hlod_mem_free(z->a, z->in);
    hlod_mem_free(z->a, z->stack);
    hlod_mem_free(z->a, z->blocks);
    for (size_t i = 0; i < z->cache_slots; i++)
        hlod_mem_free(z->a, z->cache[i].pt);
    hlod_mem_free(z->a, z->cache);
    hlod_mem_free(z->a, z);
}

void hlod_rzb_out_free(const hlod_allocator *a, hlod_rzb_out *o)
{
    if (!o)
        return;
    hlod_mem_free(a, o->splats);
    hlod_mem_free(a, o->ranges);
    hlod_mem_free(a, o->rgba);
    hlod_mem_free(a, o->depth);
    memset(o, 0, sizeof *o);
}

size_t hlod_rzb_tri_count(const hlod_rzb *z)
{
    return z ? z->tri_count : 0;
}

uint32_t hlod_rzb_class_count(const hlod_rzb *z)
{
    return z ? z->class_count : 0;
}

/* ---- adding faces ---- */

static uint8_t clamp_byte(double v)
{
    return (uint8_t)(v <= 0 ? 0 : v >= 255 ? 255 : v + 0.5);
}

/* The colour of corner v: the vertex colour, else the texel under its UV
 * (nearest; v = 0 is the bottom row, repeating), else grey. */
static void corner_color(const hlod_store_payload *p, uint32_t v, int textured, uint8_t out[4])
{
    out[3] = 255;
    if (p->colors) {
        memcpy(out, p->colors + 4 * (size_t)v, 3);
        return;
    }
    if (textured && p->uvs && p->pixels && p->tex_width && p->tex_height &&
        p->tex_format == HLOD_TEXFMT_TEXELS && p->tex_channels >= 1) {
        double u = p->uvs[2 * (size_t)v], t = 1.0 - p->uvs[2 * (size_t)v + 1];
        u -= floor(u);
        t -= floor(t);
        uint32_t x = (uint32_t)(u * p->tex_width), y = (uint32_t)(t * p->tex_height);
        x = x >= p->tex_width ? p->tex_width - 1 : x;
        y = y >= p->tex_height ? p->tex_height - 1 : y;
        const uint8_t *px = p->pixels + ((size_t)y * p->tex_width + x) * p->tex_channels;
        for (int k = 0; k < 3; k++)
            out[k] = px[p->tex_channels >= 3 ? k : 0];
        return;
    }
    out[0] = out[1] = out[2] = RZB_GREY;
}

hlod_result hlod_rzb_add(hlod_rzb *z, const hlod_store_node *n, uint32_t node,
                         const hlod_store_payload *p)
{
    if (!z || !n || !p || z->finished)
        return HLOD_ERR_INVALID_ARG;
    uint32_t tris = p->index_count / 3;
    if (z->in_count + tris > z->in_cap) {
        size_t cap = z->in_cap ? z->in_cap : 4096;
        while (cap < z->in_count + tris)
            cap *= 2;
        rzb_in *in = hlod_mem_realloc(z->a, z->in, cap * sizeof *in);
        if (!in)
            return HLOD_ERR_NOMEM;
        z->in = in;
        z->in_cap = cap;
    }
    uint32_t two_sided = !(n->render_flags & HLOD_RENDER_SOLID);
    for (uint32_t t = 0; t < tris; t++) {
        rzb_in *f = &z->in[z->in_count];
        for (int k = 0; k < 3; k++) {
            uint32_t v = p->indices[3 * t + k];
            for (int a = 0; a < 3; a++)
                f->p[k][a] = n->origin[a] + (double)p->positions[3 * (size_t)v + a];
            corner_color(p, v, t < p->tex_tri_count, f->rgba[k]);
        }
        double u[3], w[3], x[3];
        for (int a = 0; a < 3; a++) {
            u[a] = f->p[1][a] - f->p[0][a];
            w[a] = f->p[2][a] - f->p[0][a];
        }
        x[0] = u[1] * w[2] - u[2] * w[1];
        x[1] = u[2] * w[0] - u[0] * w[2];
        x[2] = u[0] * w[1] - u[1] * w[0];
        double len = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        if (!(len > 0) || !isfinite(len))
            continue; /* no area: draws nothing */
        for (int a = 0; a < 3; a++)
            f->n[a] = (float)(x[a] / len);
        f->area = len / 2;
        f->leaf = node;
        f->two_sided = two_sided;
        z->in_count++;
    }
    return HLOD_OK;
}

/* ---- the classes and their octrees ---- */

typedef struct build_ctx {
    hlod_rzb *z;
    rzb_class *c;
    const rzb_in *in;
    uint32_t out;            /* faces placed so far */
} build_ctx;

static int place(build_ctx *b, uint32_t i)
{
    const rzb_in *f = &b->in[i];
    rzb_tri *t = &b->c->tri[b->out++];
    for (int k = 0; k < 3; k++)
        for (int a = 0; a < 3; a++)
            t->p[k][a] = (float)(f->p[k][a] - b->c->origin[a]);
    memcpy(t->n, f->n, sizeof t->n);
    memcpy(t->rgba, f->rgba, sizeof t->rgba);
    t->leaf = f->leaf;
    t->two_sided = f->two_sided;
    return 1;
}

static uint32_t new_node(build_ctx *b)
{
    rzb_class *c = b->c;
    if (c->nodes == c->node_cap) {
        uint32_t cap = c->node_cap ? 2 * c->node_cap : 64;
        rzb_node *n = hlod_mem_realloc(b->z->a, c->node, cap * sizeof *n);
        if (!n)
            return UINT32_MAX;
        c->node = n;
        c->node_cap = cap;
    }
    memset(&c->node[c->nodes], 0, sizeof c->node[0]);
    return c->nodes++;
}

/* Whether face i lies within the cube [lo, lo + side] grown by side / 2. */
static int fits(const rzb_in *f, const double lo[3], double side)
{
    for (int k = 0; k < 3; k++)
        for (int a = 0; a < 3; a++)
            if (f->p[k][a] < lo[a] - side / 2 || f->p[k][a] > lo[a] + 1.5 * side)
                return 0;
    return 1;
}

/* The subtree over faces idx[0, n) in the cell [lo, lo + side]: children
 * first (their faces placed), then the node's own. */
static hlod_result build_cell(build_ctx *b, uint32_t *idx, uint32_t n, const double lo[3],
                              double side, int depth, uint32_t *id_out)
{
    uint32_t id = new_node(b);
    if (id == UINT32_MAX)
        return HLOD_ERR_NOMEM;
    *id_out = id;
    uint32_t begin = b->out, own_n = n;
    hlod_result r = HLOD_OK;
    if (n > RZB_LEAF_TRIS && depth < RZB_MAX_DEPTH) {
        /* partition idx: each octant's faces that fit its loose cell,
         * then the rest (the node's own) at the end */
        uint32_t counts[8] = {0}, start[9];
        uint8_t *oct = hlod_mem_alloc(b->z->a, n);
        if (!oct)
            return HLOD_ERR_NOMEM;
        double half = side / 2;
        for (uint32_t k = 0; k < n; k++) {
            const rzb_in *f = &b->in[idx[k]];
            int o = 0;
            double clo[3];
            for (int a = 0; a < 3; a++) {
                double cen = (f->p[0][a] + f->p[1][a] + f->p[2][a]) / 3;
                int hi = cen >= lo[a] + half;
                o |= hi << a;
                clo[a] = lo[a] + (hi ? half : 0);
            }
            oct[k] = (uint8_t)(fits(f, clo, half) ? o : 8);
            if (oct[k] < 8)
                counts[o]++;
        }
        start[0] = 0;
        for (int o = 0; o < 8; o++)
            start[o + 1] = start[o] + counts[o];
        own_n = n - start[8];
        uint32_t *tmp = hlod_mem_alloc(b->z->a, (size_t)n * sizeof *tmp);
        if (!tmp) {
            hlod_mem_free(b->z->a, oct);
            return HLOD_ERR_NOMEM;
        }
        uint32_t pos[9];
        memcpy(pos, start, sizeof pos);
        for (uint32_t k = 0; k < n; k++)
            tmp[oct[k] < 8 ? pos[oct[k]]++ : pos[8]++] = idx[k];
        memcpy(idx, tmp, (size_t)n * sizeof *idx);
        hlod_mem_free(b->z->a, tmp);
        hlod_mem_free(b->z->a, oct);
        /* a cell whose faces all stay or all fit one octant with nothing
         * gained keeps splitting only while the depth allows */
        for (int o = 0; o < 8 && r == HLOD_OK; o++) {
            if (!counts[o])
                continue;
            double clo[3];
            for (int a = 0; a < 3; a++)
                clo[a] = lo[a] + ((o >> a) & 1 ? half : 0);
            uint32_t kid;
            r = build_cell(b, idx + start[o], counts[o], clo, half, depth + 1, &kid);
            if (r == HLOD_OK) {
                rzb_node *nd = &b->c->node[id];
                nd->kid[nd->kids++] = kid;
            }
        }
    }
    if (r != HLOD_OK)
        return r;
    rzb_node *nd = &b->c->node[id];
    nd->begin = begin;
    nd->own = b->out;
    for (uint32_t k = n - own_n; k < n; k++)
        place(b, idx[k]);
    nd->end = b->out;
    /* the box of the faces placed under it */
    for (int a = 0; a < 3; a++) {
        nd->lo[a] = INFINITY;
        nd->hi[a] = -INFINITY;
    }
    for (uint32_t k = nd->begin; k < nd->end; k++)
        for (int v = 0; v < 3; v++)
            for (int a = 0; a < 3; a++) {
                double x = b->c->origin[a] + (double)b->c->tri[k].p[v][a];
                nd->lo[a] = x < nd->lo[a] ? x : nd->lo[a];
                nd->hi[a] = x > nd->hi[a] ? x : nd->hi[a];
            }
    return HLOD_OK;
}

static hlod_result build_class(hlod_rzb *z, rzb_class *c, uint32_t *idx, uint32_t n)
{
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t k = 0; k < n; k++)
        for (int v = 0; v < 3; v++)
            for (int a = 0; a < 3; a++) {
                double x = z->in[idx[k]].p[v][a];
                lo[a] = x < lo[a] ? x : lo[a];
                hi[a] = x > hi[a] ? x : hi[a];
            }
    double side = 0;
    for (int a = 0; a < 3; a++) {
        c->origin[a] = 0.5 * (lo[a] + hi[a]);
        side = hi[a] - lo[a] > side ? hi[a] - lo[a] : side;
    }
    side = side > 0 ? side * (1 + 1e-9) : 1;
    double cube[3];
    for (int a = 0; a < 3; a++)
        cube[a] = c->origin[a] - side / 2;
    c->count = n;
    c->tri = hlod_mem_alloc(z->a, (size_t)n * sizeof *c->tri);
    c->cum = hlod_mem_alloc(z->a, ((size_t)n + 1) * sizeof *c->cum);
    if (!c->tri || !c->cum)
        return HLOD_ERR_NOMEM;
    build_ctx b = {z, c, z->in, 0};
    uint32_t root;
    hlod_result r = build_cell(&b, idx, n, cube, side, 0, &root);
    if (r != HLOD_OK)
        return r;
    /* the prefix sums, in the placed order, from the corners as stored */
    c->cum[0] = 0;
    c->max_area = 0;
    for (uint32_t k = 0; k < n; k++) {
        double area = hlod_rzb_area(z, (uint32_t)(c - z->cls), k);
        c->cum[k + 1] = c->cum[k] + area;
        c->max_area = area > c->max_area ? area : c->max_area;
    }
    return HLOD_OK;
}

typedef struct by_area {
    double area;
    uint32_t i;
} by_area;

static int cmp_area(const void *x, const void *y)
{
    const by_area *a = x, *b = y;
    if (a->area != b->area)
        return a->area < b->area ? -1 : 1;
    return a->i < b->i ? -1 : a->i > b->i;
}

hlod_result hlod_rzb_finish(hlod_rzb *z)
{
    if (!z || z->finished)
        return HLOD_ERR_INVALID_ARG;
    z->finished = 1;
    size_t n = z->in_count;
    if (n > UINT32_MAX / 2)
        return HLOD_ERR_NOMEM;
    uint32_t *idx = hlod_mem_alloc(z->a, (n ? n : 1) * sizeof *idx);
    by_area *order = hlod_mem_alloc(z->a, (n ? n : 1) * sizeof *order);
    if (!idx || !order) {
        hlod_mem_free(z->a, idx);
        hlod_mem_free(z->a, order);
        return HLOD_ERR_NOMEM;
    }
    for (size_t i = 0; i < n; i++)
        order[i] = (by_area){z->in[i].area, (uint32_t)i};
    hlod_sort(order, n, sizeof *order, cmp_area);
    for (size_t i = 0; i < n; i++)
        idx[i] = order[i].i;
    hlod_mem_free(z->a, order);
    /* classes from the smallest area up, each within RZB_CLASS_FACTOR (the
     * last one takes whatever is left past RZB_MAX_CLASSES) */
    hlod_result r = HLOD_OK;
    size_t b = 0;
    while (b < n && r == HLOD_OK) {
        double top = z->in[idx[b]].area * RZB_CLASS_FACTOR;
        size_t e = b;
        while (e < n && (z->in[idx[e]].area < top || z->class_count == RZB_MAX_CLASSES - 1))
            e++;
        r = build_class(z, &z->cls[z->class_count++], idx + b, (uint32_t)(e - b));
        b = e;
    }
    z->tri_count = n;
    for (int a = 0; a < 3; a++) {
        z->box_lo[a] = INFINITY;
        z->box_hi[a] = -INFINITY;
    }
    z->class_cum[0] = 0;
    for (uint32_t c = 0; c < z->class_count; c++) {
        const rzb_class *k = &z->cls[c];
        z->class_cum[c + 1] = z->class_cum[c] + (k->count ? k->cum[k->count] : 0);
        z->max_area = k->max_area > z->max_area ? k->max_area : z->max_area;
        for (int a = 0; k->nodes && a < 3; a++) {
            z->box_lo[a] = k->node[0].lo[a] < z->box_lo[a] ? k->node[0].lo[a] : z->box_lo[a];
            z->box_hi[a] = k->node[0].hi[a] > z->box_hi[a] ? k->node[0].hi[a] : z->box_hi[a];
        }
    }
    hlod_mem_free(z->a, idx);
    hlod_mem_free(z->a, z->in);
    z->in = NULL;
    z->in_count = z->in_cap = 0;
    return r;
}

/* ---- test seams ---- */

uint32_t hlod_rzb_class_size(const hlod_rzb *z, uint32_t c)
{
    return c < z->class_count ? z->cls[c].count : 0;
}

double hlod_rzb_area(const hlod_rzb *z, uint32_t c, uint32_t t)
{
    const rzb_tri *f = &z->cls[c].tri[t];
    double u[3], w[3];
    for (int a = 0; a < 3; a++) {
        u[a] = (double)f->p[1][a] - f->p[0][a];
        w[a] = (double)f->p[2][a] - f->p[0][a];
    }
    double x = u[1] * w[2] - u[2] * w[1], y = u[2] * w[0] - u[0] * w[2],
           q = u[0] * w[1] - u[1] * w[0];
    return 0.5 * sqrt(x * x + y * y + q * q);
}

static uint32_t pick_next(const rzb_class *c, uint32_t b, uint32_t e, uint64_t i, uint64_t n,
                          double u, uint32_t *t);

void hlod_rzb_picks(const hlod_rzb *z, uint32_t c, uint32_t b, uint32_t e, uint64_t seed,
                    uint32_t n, uint32_t *out)
{
    uint64_t rng = seed;
    uint32_t at = b;
    for (uint32_t i = 0; i < n; i++) {
        uint64_t x = (rng += 0x9E3779B97F4A7C15ull);
        x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
        x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
        x ^= x >> 31;
        out[i] = pick_next(&z->cls[c], b, e, i, n, (double)(x >> 11) * (1.0 / 9007199254740992.0),
                           &at);
    }
}

uint32_t hlod_rzb_pick(const hlod_rzb *z, uint32_t c, uint32_t b, uint32_t e, double u)
{
    const double *cum = z->cls[c].cum;
    double x = cum[b] + u * (cum[e] - cum[b]);
    /* the first t in [b, e) with cum[t + 1] > x */
    uint32_t lo = b, hi = e - 1;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (cum[mid + 1] > x)
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

/* Barycentric weights of a uniform point of a triangle from two uniforms
 * (the square-root method). */
static void bary(double u1, double u2, double w[3])
{
    double s = sqrt(u1);
    w[0] = 1 - s;
    w[1] = s * (1 - u2);
    w[2] = s * u2;
}

void hlod_rzb_point(const hlod_rzb *z, uint32_t c, uint32_t t, double u1, double u2,
                    double out[3])
{
    const rzb_class *k = &z->cls[c];
    double w[3];
    bary(u1, u2, w);
    for (int a = 0; a < 3; a++)
        out[a] = k->origin[a] + w[0] * k->tri[t].p[0][a] + w[1] * k->tri[t].p[1][a] +
                 w[2] * k->tri[t].p[2][a];
}

/* ---- the frame ---- */

typedef struct frame_ctx {
    hlod_rzb *z;
    const hlod_view *v;
    double eps, d2, lnv, f2;  /* d^2, ln v, focal length^2 (pixels) */
    uint64_t rng;
    hlod_rzb_out *out;
    int splat_c;               /* points splatted here (out->rgba, out->depth) */
    uint32_t frame;            /* stamp for the caches' LRU */
    double d;                  /* their size, pixels */
    int raster;                /* faces over d^2 / ln v pixels are rasterised */
    double off[3];             /* the copy drawn: its offset from the scene */
    uint64_t copy;             /* and its column << 32 | row */
    int nomem;
} frame_ctx;

static double uniform(frame_ctx *f)
{
    /* splitmix64: 53 random bits */
    uint64_t x = (f->rng += 0x9E3779B97F4A7C15ull);
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    x ^= x >> 31;
    return (double)(x >> 11) * (1.0 / 9007199254740992.0);
}

static void add_range(frame_ctx *f, uint32_t ci, uint32_t b, uint32_t e)
{
    hlod_rzb_out *o = f->out;
    o->range_tris += e - b;
    if (o->range_count) {
        hlod_rzb_range *last = &o->ranges[o->range_count - 1];
        if (last->cls == ci && last->first + last->count == b && last->copy == f->copy) {
            last->count += e - b;
            return;
        }
    }
    if (o->range_count == o->range_cap) {
        size_t cap = o->range_cap ? 2 * o->range_cap : 256;
        hlod_rzb_range *g = hlod_mem_realloc(f->z->a, o->ranges, cap * sizeof *g);
        if (!g) {
            f->nomem = 1;
            return;
        }
        o->ranges = g;
        o->range_cap = cap;
    }
    o->ranges[o->range_count++] = (hlod_rzb_range){ci, b, e - b, f->copy,
                                                   {f->off[0], f->off[1], f->off[2]}};
}

static int grow_splats(frame_ctx *f, size_t more)
{
    hlod_rzb_out *o = f->out;
    if (o->splat_count + more <= o->splat_cap)
        return 1;
    size_t cap = o->splat_cap ? o->splat_cap : 4096;
    while (cap < o->splat_count + more)
        cap *= 2;
    hlod_gpu_splat *s = hlod_mem_realloc(f->z->a, o->splats, cap * sizeof *s);
    if (!s) {
        f->nomem = 1;
        return 0;
    }
    o->splats = s;
    o->splat_cap = cap;
    return 1;
}

/* The first t in [t, e) with cum[t + 1] > x (x below cum[e]), searched
 * forward from t by doubling steps, then halving: the picks of a range
 * come in order, so its prefix sums are read front to back. */
static uint32_t gallop(const double *cum, uint32_t t, uint32_t e, double x)
{
    if (cum[t + 1] > x || t + 1 >= e)
        return t;
    uint32_t lo = t, hi = t, step = 1;
    for (;;) {
        hi = lo + step < e - 1 ? lo + step : e - 1;
        if (cum[hi + 1] > x || hi == e - 1)
            break;
        lo = hi;
        step *= 2;
    }
    while (lo + 1 < hi) { /* cum[lo + 1] <= x < cum[hi + 1] */
        uint32_t mid = lo + (hi - lo) / 2;
        if (cum[mid + 1] > x)
            hi = mid;
        else
            lo = mid;
    }
    return hi;
}

/* The i-th of n picks from [b, e) by area: one uniform point in each of
 * n equal strata of the range's area, so the picks come in order (each
 * face is picked with probability n x area / total, as independent picks
 * are, with fewer gaps between them).  *t: the last pick (b at first). */
static uint32_t pick_next(const rzb_class *c, uint32_t b, uint32_t e, uint64_t i, uint64_t n,
                          double u, uint32_t *t)
{
    double x = c->cum[b] + ((double)i + u) / (double)n * (c->cum[e] - c->cum[b]);
    if (!(x < c->cum[e]))
        x = nextafter(c->cum[e], 0);
    *t = gallop(c->cum, *t, e, x);
    return *t;
}

/* The C splatter: the point at camera-relative rel, projected as GL does
 * (the view's camera-relative view-projection, the viewport, depth range
 * [0, 1]), written d x d pixels wide where it is nearer than what is
 * there: the pixels whose centres lie in the d x d square around it, as
 * GL rasterises a point. */
static void splat(frame_ctx *f, const double rel[3], const uint8_t col[4])
{
    const double *m = f->v->vp;
    double x = m[0] * rel[0] + m[4] * rel[1] + m[8] * rel[2] + m[12],
           y = m[1] * rel[0] + m[5] * rel[1] + m[9] * rel[2] + m[13],
           zc = m[2] * rel[0] + m[6] * rel[1] + m[10] * rel[2] + m[14],
           wc = m[3] * rel[0] + m[7] * rel[1] + m[11] * rel[2] + m[15];
    if (!(wc > 0) || zc < -wc || zc > wc)
        return; /* behind the eye, or past the near or far plane */
    hlod_rzb_out *o = f->out;
    double xw = (x / wc * 0.5 + 0.5) * o->w, yw = (y / wc * 0.5 + 0.5) * o->h, half = 0.5 * f->d;
    if (!(xw > -f->d && xw < o->w + f->d && yw > -f->d && yw < o->h + f->d))
        return;
    float z = (float)(zc / wc * 0.5 + 0.5);
    long x0 = (long)ceil(xw - half - 0.5), y0 = (long)ceil(yw - half - 0.5), n = (long)f->d;
    long x1 = x0 + n < (long)o->w ? x0 + n : (long)o->w, y1 = y0 + n < (long)o->h ? y0 + n : (long)o->h;
    x0 = x0 > 0 ? x0 : 0;
    y0 = y0 > 0 ? y0 : 0;
    for (long py = y0; py < y1; py++)
        for (long px = x0; px < x1; px++) {
            size_t p = (size_t)py * o->w + (size_t)px;
            if (z < o->depth[p]) {
                o->depth[p] = z;
                memcpy(o->rgba + 4 * p, col, 4);
            }
        }
}

/* The C splatter's frame at the view's size, cleared (depth 1). */
static int clear_frame(frame_ctx *f)
{
    hlod_rzb_out *o = f->out;
    uint32_t w = (uint32_t)f->v->width, h = (uint32_t)f->v->height;
    size_t n = (size_t)w * h;
    if (n > o->pix_cap) {
        uint8_t *c = hlod_mem_realloc(f->z->a, o->rgba, 4 * n);
        if (c)
            o->rgba = c;
        float *d = c ? hlod_mem_realloc(f->z->a, o->depth, n * sizeof *d) : NULL;
        if (d)
            o->depth = d;
        if (!c || !d)
            return 0;
        o->pix_cap = n;
    }
    o->w = w;
    o->h = h;
    memset(o->rgba, 0, 4 * n);
    for (size_t p = 0; p < n; p++)
        o->depth[p] = 1.0f;
    return 1;
}

/* N points of the range [b, e) of class c, back faces rejected, lit as
 * the renderer lights a face (gl_render.c: headlight and sky). */
/* One point at camera-relative rel of a face with unit normal n and base
 * colour base: dropped when it faces away and is one-sided (section
 * 5.3.3), else lit as the renderer lights a face and drawn. */
static void emit(frame_ctx *f, const double rel[3], const float n[3], const double base[3],
                 int two_sided)
{
    hlod_rzb_out *o = f->out;
    double d2 = 0, facing = 0;
    for (int a = 0; a < 3; a++) {
        d2 += rel[a] * rel[a];
        facing -= n[a] * rel[a];
    }
    o->samples++;
    if (facing <= 0 && !two_sided)
        return;
    double dist = sqrt(d2), dot = dist > 0 ? fabs(facing) / dist : 1;
    double nz = facing < 0 ? -n[2] : n[2];
    double light = hlod_gpu_light(dot, nz);
    uint8_t col[4] = {clamp_byte(base[0] * light), clamp_byte(base[1] * light),
                      clamp_byte(base[2] * light), 255};
    if (f->splat_c) {
        splat(f, rel, col);
        o->splat_count++; /* counted, landed or not, as a GL point is */
        return;
    }
    hlod_gpu_splat *s = &o->splats[o->splat_count++];
    for (int a = 0; a < 3; a++)
        s->pos[a] = (float)rel[a];
    memcpy(s->rgba, col, 4);
}

/* Makes room for n more points (fewer past RZB_MAX_SAMPLES); the count. */
static uint64_t room(frame_ctx *f, uint64_t n)
{
    hlod_rzb_out *o = f->out;
    if (o->samples + n > RZB_MAX_SAMPLES)
        n = o->samples < RZB_MAX_SAMPLES ? RZB_MAX_SAMPLES - o->samples : 0;
    if (!n || (!f->splat_c && !grow_splats(f, n)))
        return 0;
    return n;
}

/* The i-th of n points of range [b, e) of class c: its face t, its
 * position relative to the class origin and its colour. */
static uint32_t draw_point(frame_ctx *f, const rzb_class *c, uint32_t b, uint32_t e, uint64_t i,
                           uint64_t n, uint32_t *at, double p[3], double col[3])
{
    uint32_t t = pick_next(c, b, e, i, n, uniform(f), at);
    double w[3];
    bary(uniform(f), uniform(f), w);
    const rzb_tri *tr = &c->tri[t];
    for (int a = 0; a < 3; a++) {
        p[a] = w[0] * tr->p[0][a] + w[1] * tr->p[1][a] + w[2] * tr->p[2][a];
        col[a] = w[0] * tr->rgba[0][a] + w[1] * tr->rgba[1][a] + w[2] * tr->rgba[2][a];
    }
    return t;
}

/* Where points come from: a range [b, e) of one class, or (k set) a
 * block of copies.  Positions are relative to `origin` (world): the
 * class's origin (offset to the copy drawn) for a range, the block's box
 * corner for a block, so that a cache's floats stay small. */
typedef struct point_src {
    const rzb_class *c;  /* a range's class */
    uint32_t b, e, at;   /* ... its faces, the last pick */
    const copy_block *k; /* a block; NULL for a range */
    double pitch[2];     /* ... its copies' spacing */
    uint32_t ci, t;      /* ... the last class and face picked */
    double origin[3];
} point_src;

static point_src range_src(const frame_ctx *f, uint32_t ci, uint32_t b, uint32_t e)
{
    point_src s = {.c = &f->z->cls[ci], .b = b, .e = e, .at = b};
    for (int a = 0; a < 3; a++)
        s.origin[a] = s.c->origin[a] + f->off[a];
    return s;
}

static point_src block_src(const frame_ctx *f, const copy_block *k, const double pitch[2])
{
    const hlod_rzb *z = f->z;
    point_src s = {.k = k, .pitch = {pitch[0], pitch[1]}};
    for (int a = 0; a < 3; a++)
        s.origin[a] = z->box_lo[a];
    s.origin[0] += k->i * pitch[0];
    s.origin[1] += k->j * pitch[1];
    return s;
}

/* The i-th of n points of source s: its face (NULL: none, an empty
 * class), its position relative to s's origin and its colour.
 *   A range: one uniform position in each of n equal strata of its area
 * (pick_next).
 *   A block: the faces picked as a range's are, over the scene's classes
 * in order; each point's copy drawn uniformly (the copies' areas are
 * equal): each face of each copy is picked with probability n x its area
 * / the block's.  (Strata over the copies instead, copy by copy, restart
 * the search at every copy: with more copies than points each point
 * searched its class afresh, 1.6x the time a frame.) */
static const rzb_tri *src_point(frame_ctx *f, point_src *s, uint64_t i, uint64_t n, double p[3],
                                double col[3])
{
    const hlod_rzb *z = f->z;
    if (!s->k) {
        uint32_t t = draw_point(f, s->c, s->b, s->e, i, n, &s->at, p, col);
        return &s->c->tri[t];
    }
    double total = z->class_cum[z->class_count];
    double r = ((double)i + uniform(f)) / (double)n * total;
    while (s->ci + 1 < z->class_count && !(z->class_cum[s->ci + 1] > r)) {
        s->ci++;
        s->t = 0;
    }
    const rzb_class *c = &z->cls[s->ci];
    if (!c->count)
        return NULL;
    double y = r - z->class_cum[s->ci];
    if (!(y < c->cum[c->count]))
        y = nextafter(c->cum[c->count], 0);
    s->t = gallop(c->cum, s->t, c->count, y);
    double side = ldexp(1.0, (int)s->k->level);
    double col_i = floor(uniform(f) * side), row_j = floor(uniform(f) * side), w[3];
    bary(uniform(f), uniform(f), w);
    const rzb_tri *tr = &c->tri[s->t];
    for (int a = 0; a < 3; a++) {
        p[a] = c->origin[a] - z->box_lo[a] + w[0] * tr->p[0][a] + w[1] * tr->p[1][a] +
               w[2] * tr->p[2][a];
        col[a] = w[0] * tr->rgba[0][a] + w[1] * tr->rgba[1][a] + w[2] * tr->rgba[2][a];
    }
    p[0] += col_i * s->pitch[0];
    p[1] += row_j * s->pitch[1];
    return tr;
}

/* N fresh points of source s. */
static void fresh(frame_ctx *f, point_src *s, uint64_t n)
{
    n = room(f, n);
    double base[3];
    for (int a = 0; a < 3; a++)
        base[a] = s->origin[a] - f->v->eye[a];
    for (uint64_t i = 0; i < n; i++) {
        double p[3], col[3], rel[3];
        const rzb_tri *tr = src_point(f, s, i, n, p, col);
        if (!tr)
            continue;
        for (int a = 0; a < 3; a++)
            rel[a] = base[a] + p[a];
        emit(f, rel, tr->n, col, (int)tr->two_sided);
    }
}

/* ---- sample caches (section 7.2) ---- */

static uint64_t mix64(uint64_t x)
{
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
}

static size_t cache_home(const hlod_rzb *z, uint64_t key, uint64_t copy)
{
    return mix64(key ^ mix64(copy + 0x9E3779B97F4A7C15ull)) & (z->cache_slots - 1);
}

/* The slot of (key, copy) in the table (linear probing): its entry, or
 * the free slot where it would go. */
static rzb_cache *cache_slot(hlod_rzb *z, uint64_t key, uint64_t copy)
{
    size_t mask = z->cache_slots - 1, i = cache_home(z, key, copy);
    while (z->cache[i].key && (z->cache[i].key != key || z->cache[i].copy != copy))
        i = (i + 1) & mask;
    return &z->cache[i];
}

/* Frees slot i and closes the gap behind it (backward shift), so every
 * key stays reachable from its home slot. */
static void cache_remove(hlod_rzb *z, size_t i)
{
    size_t mask = z->cache_slots - 1;
    z->cache_bytes -= (size_t)z->cache[i].count * sizeof(cache_pt);
    hlod_mem_free(z->a, z->cache[i].pt);
    z->cache[i] = (rzb_cache){0};
    z->cache_used--;
    for (size_t j = (i + 1) & mask; z->cache[j].key; j = (j + 1) & mask) {
        size_t home = cache_home(z, z->cache[j].key, z->cache[j].copy);
        /* j's entry may move into the hole at i if its home is not in (i, j] */
        if ((j > i && (home <= i || home > j)) || (j < i && home <= i && home > j)) {
            z->cache[i] = z->cache[j];
            z->cache[j] = (rzb_cache){0};
            i = j;
        }
    }
}

/* Evicts the least recently drawn caches, never this frame's, until the
 * caches fit the limit. */
static void cache_trim(hlod_rzb *z, uint32_t frame)
{
    while (z->cache_bytes > z->cache_limit) {
        size_t worst = SIZE_MAX;
        for (size_t i = 0; i < z->cache_slots; i++)
            if (z->cache[i].key && z->cache[i].used != frame &&
                (worst == SIZE_MAX || z->cache[i].used < z->cache[worst].used))
                worst = i;
        if (worst == SIZE_MAX)
            return;
        cache_remove(z, worst);
    }
}

/* A table with room for one more entry (at most half full). */
static int cache_grow(hlod_rzb *z)
{
    if (2 * (z->cache_used + 1) <= z->cache_slots)
        return 1;
    size_t slots = z->cache_slots ? 2 * z->cache_slots : 1024;
    rzb_cache *old = z->cache, *t = hlod_mem_alloc(z->a, slots * sizeof *t);
    if (!t)
        return 0;
    memset(t, 0, slots * sizeof *t);
    size_t old_slots = z->cache_slots;
    z->cache = t;
    z->cache_slots = slots;
    for (size_t i = 0; i < old_slots; i++)
        if (old[i].key)
            *cache_slot(z, old[i].key, old[i].copy) = old[i];
    hlod_mem_free(z->a, old);
    return 1;
}

/* The points of a new cache at `level`: n fresh points of the range,
 * without back-face rejection (a cache serves every side), each snapped
 * to the centre of its cell, one a cell (a scratch hash set of cells). */
static int cache_fill(frame_ctx *f, point_src *src, uint64_t n, int level, rzb_cache *out)
{
    hlod_rzb *z = f->z;
    double side = ldexp(1.0, level);
    size_t slots = 64;
    while (slots < 2 * n)
        slots *= 2;
    uint64_t *seen = hlod_mem_alloc(z->a, slots * sizeof *seen);
    cache_pt *pt = hlod_mem_alloc(z->a, (n ? n : 1) * sizeof *pt);
    if (!seen || !pt) {
        hlod_mem_free(z->a, seen);
        hlod_mem_free(z->a, pt);
        return 0;
    }
    memset(seen, 0, slots * sizeof *seen);
    uint32_t count = 0;
    for (uint64_t i = 0; i < n; i++) {
        double p[3], col[3];
        const rzb_tri *tr = src_point(f, src, i, n, p, col);
        if (!tr)
            continue;
        int64_t cell[3];
        for (int a = 0; a < 3; a++)
            cell[a] = (int64_t)floor(p[a] / side);
        uint64_t key = mix64((uint64_t)cell[0] * 0x9E3779B97F4A7C15ull ^
                             (uint64_t)cell[1] * 0xC2B2AE3D27D4EB4Full ^ (uint64_t)cell[2]) | 1;
        size_t s = key & (slots - 1);
        while (seen[s] && seen[s] != key)
            s = (s + 1) & (slots - 1);
        if (seen[s])
            continue; /* the cell has its point (a rare hash clash drops one more) */
        seen[s] = key;
        cache_pt *q = &pt[count++];
        for (int a = 0; a < 3; a++) {
            q->p[a] = (float)((cell[a] + 0.5) * side);
            q->n[a] = (int16_t)lrint(tr->n[a] * 32767.0);
            q->rgb[a] = clamp_byte(col[a]);
        }
        q->two_sided = (uint8_t)tr->two_sided;
    }
    hlod_mem_free(z->a, seen);
    cache_pt *fit = hlod_mem_realloc(z->a, pt, (count ? count : 1) * sizeof *pt);
    out->pt = fit ? fit : pt;
    out->count = count;
    out->level = level;
    return 1;
}

/* Source s drawn from its cache, the one of (key, copy): made, or made
 * again when its cells no longer fit the view (over d pixels at the
 * box's nearest depth zmin, or four times smaller than needed). */
static void cached(frame_ctx *f, point_src *s, uint64_t key, uint64_t copy, double zmin,
                   uint64_t n)
{
    hlod_rzb *z = f->z;
    /* a cell whose side projects within d pixels at zmin: its diagonal
     * within sqrt(3) d (Wand 7.2) */
    int level = (int)floor(log2(zmin * f->d / sqrt(f->f2)));
    if (!cache_grow(z)) {
        fresh(f, s, n);
        return;
    }
    rzb_cache *slot = cache_slot(z, key, copy);
    if (slot->key && (slot->level > level || slot->level < level - 2)) {
        cache_remove(z, (size_t)(slot - z->cache));
        slot = cache_slot(z, key, copy);
    }
    if (!slot->key) {
        /* four times the points a fresh frame draws: its cells project
         * within d / 2 to d pixels, so each gets about ln v of them, and
         * few stay empty */
        uint64_t fill = 4 * n < RZB_MAX_SAMPLES ? 4 * n : RZB_MAX_SAMPLES;
        rzb_cache made = {0};
        if (!cache_fill(f, s, fill, level, &made)) {
            f->nomem = 1;
            return;
        }
        made.key = key;
        made.copy = copy;
        slot = cache_slot(z, key, copy); /* unchanged: nothing was added since */
        *slot = made;
        z->cache_used++;
        z->cache_bytes += (size_t)made.count * sizeof(cache_pt);
        f->out->cache_fills++;
    }
    slot->used = f->frame;
    uint64_t m = room(f, slot->count);
    double base[3];
    for (int a = 0; a < 3; a++)
        base[a] = s->origin[a] - f->v->eye[a];
    for (uint64_t i = 0; i < m; i++) {
        const cache_pt *q = &slot->pt[i];
        double rel[3], col[3];
        float nrm[3];
        for (int a = 0; a < 3; a++) {
            rel[a] = base[a] + q->p[a];
            nrm[a] = (float)(q->n[a] / 32767.0);
            col[a] = q->rgb[a];
        }
        emit(f, rel, nrm, col, q->two_sided);
    }
    f->out->cache_points += m;
}

/* A selected range of class c, nearest depth zmin: points, or its faces
 * for the rasteriser where a face may project over d^2 / ln v pixels
 * (section 7.1) or the box reaches the eye's plane. */
static void select_range(frame_ctx *f, uint32_t ci, uint32_t node, int own, uint32_t b,
                         uint32_t e, double zmin)
{
    const rzb_class *c = &f->z->cls[ci];
    if (b >= e)
        return;
    double proj = zmin > 0 ? f->f2 / (zmin * zmin) : INFINITY;
    if (!(proj < INFINITY) || (f->raster && !(c->max_area * proj <= f->d2 / f->lnv))) {
        add_range(f, ci, b, e);
        f->out->boxes_drawn++;
        return;
    }
    double want = ceil((c->cum[e] - c->cum[b]) * proj * f->lnv / f->d2);
    uint64_t n = want < (double)RZB_MAX_SAMPLES ? (uint64_t)want : RZB_MAX_SAMPLES;
    point_src src = range_src(f, ci, b, e);
    if (f->z->cache_limit)
        cached(f, &src, (((uint64_t)ci << 40) | ((uint64_t)node << 1) | (uint64_t)own) + 1,
               f->copy, zmin, n);
    else
        fresh(f, &src, n);
    f->out->boxes_sampled++;
}

/* Depths (along the view axis) of box [lo, hi]'s nearest and farthest
 * corners. */
static void depth_range(const hlod_view *v, const double lo[3], const double hi[3], double *zmin,
                        double *zmax)
{
    *zmin = INFINITY;
    *zmax = -INFINITY;
    for (int corner = 0; corner < 8; corner++) {
        double z = 0;
        for (int a = 0; a < 3; a++)
            z -= ((corner >> a & 1 ? hi[a] : lo[a]) - v->eye[a]) * v->toward[a];
        *zmin = z < *zmin ? z : *zmin;
        *zmax = z > *zmax ? z : *zmax;
    }
}

static void walk_class(frame_ctx *f, uint32_t ci)
{
    hlod_rzb *z = f->z;
    const rzb_class *c = &z->cls[ci];
    if (!c->nodes)
        return;
    size_t sp = 0;
    z->stack[sp++] = 0;
    while (sp && !f->nomem) {
        uint32_t id = z->stack[--sp];
        const rzb_node *nd = &c->node[id];
        double lo[3], hi[3];
        for (int a = 0; a < 3; a++) {
            lo[a] = nd->lo[a] + f->off[a];
            hi[a] = nd->hi[a] + f->off[a];
        }
        if (hlod_view_outside(f->v, lo, hi) > 0)
            continue;
        double zmin, zmax;
        depth_range(f->v, lo, hi, &zmin, &zmax);
        if (!(zmax > 0))
            continue; /* behind the eye */
        int narrow = zmin > 0 && zmax * zmax <= f->eps * zmin * zmin;
        if (narrow || !nd->kids) {
            select_range(f, ci, id, 0, nd->begin, nd->end, zmin);
            continue;
        }
        select_range(f, ci, id, 1, nd->own, nd->end, zmin);
        for (uint32_t k = 0; k < nd->kids; k++)
            z->stack[sp++] = nd->kid[k];
    }
}

/* ---- instancing (section 7.3) ---- */

/* The copies' walk: a quadtree of square blocks of copies from the whole
 * grid down.  A block outside the frustum or behind the eye is skipped;
 * a block whose depth range is narrow, and whose faces all project within
 * d^2 / ln v pixels (or rasterising is off), is sampled as one box; a
 * single copy is walked as the scene is, offset; any other block is split
 * in four. */
static void walk_copies(frame_ctx *f)
{
    hlod_rzb *z = f->z;
    double pitch[2] = {z->box_hi[0] - z->box_lo[0], z->box_hi[1] - z->box_lo[1]};
    size_t sp = 0;
    z->blocks[sp++] = (copy_block){z->copy_levels, 0, 0};
    while (sp && !f->nomem) {
        copy_block k = z->blocks[--sp];
        uint32_t n = 1u << k.level;
        double lo[3], hi[3];
        for (int a = 0; a < 3; a++) {
            lo[a] = z->box_lo[a];
            hi[a] = z->box_hi[a];
        }
        lo[0] += k.i * pitch[0];
        lo[1] += k.j * pitch[1];
        hi[0] += (k.i + n - 1.0) * pitch[0];
        hi[1] += (k.j + n - 1.0) * pitch[1];
        if (hlod_view_outside(f->v, lo, hi) > 0)
            continue;
        double zmin, zmax;
        depth_range(f->v, lo, hi, &zmin, &zmax);
        if (!(zmax > 0))
            continue;
        if (!k.level) {
            f->off[0] = k.i * pitch[0];
            f->off[1] = k.j * pitch[1];
            f->off[2] = 0;
            f->copy = (uint64_t)k.i << 32 | k.j;
            for (uint32_t c = 0; c < z->class_count && !f->nomem; c++)
                walk_class(f, c);
            continue;
        }
        double proj = zmin > 0 ? f->f2 / (zmin * zmin) : INFINITY;
        if (zmin > 0 && zmax * zmax <= f->eps * zmin * zmin &&
            (!f->raster || z->max_area * proj <= f->d2 / f->lnv)) {
            double want = ceil(z->class_cum[z->class_count] * (double)n * n * proj * f->lnv / f->d2);
            uint64_t m = want < (double)RZB_MAX_SAMPLES ? (uint64_t)want : RZB_MAX_SAMPLES;
            point_src src = block_src(f, &k, pitch);
            if (z->cache_limit) /* a block's key: its level, past every range's */
                cached(f, &src, (1ull << 63) | k.level, (uint64_t)k.i << 32 | k.j, zmin, m);
            else
                fresh(f, &src, m);
            f->out->boxes_sampled++;
            continue;
        }
        uint32_t h = n / 2;
        for (uint32_t q = 0; q < 4; q++)
            z->blocks[sp++] = (copy_block){k.level - 1, k.i + (q & 1) * h, k.j + (q >> 1) * h};
    }
    f->off[0] = f->off[1] = f->off[2] = 0;
    f->copy = 0;
}

hlod_result hlod_rzb_set_copies(hlod_rzb *z, uint32_t levels)
{
    if (!z || levels > HLOD_RZB_MAX_COPY_LEVELS)
        return HLOD_ERR_INVALID_ARG;
    size_t need = 3 * (size_t)levels + 4;
    if (levels && z->block_cap < need) {
        copy_block *b = hlod_mem_realloc(z->a, z->blocks, need * sizeof *b);
        if (!b)
            return HLOD_ERR_NOMEM;
        z->blocks = b;
        z->block_cap = need;
    }
    z->copy_levels = levels;
    return HLOD_OK;
}

uint32_t hlod_rzb_copy_levels(const hlod_rzb *z)
{
    return z ? z->copy_levels : 0;
}

void hlod_rzb_set_cache(hlod_rzb *z, size_t bytes)
{
    if (!z)
        return;
    z->cache_limit = bytes;
    cache_trim(z, UINT32_MAX);
}

size_t hlod_rzb_cache_bytes(const hlod_rzb *z)
{
    return z ? z->cache_bytes : 0;
}

hlod_result hlod_rzb_frame(hlod_rzb *z, const hlod_view *v, const hlod_rzb_params *p,
                           hlod_rzb_out *out)
{
    if (!z || !v || !p || !out || !z->finished || !(p->eps > 1) || !(p->d >= 1))
        return HLOD_ERR_INVALID_ARG;
    out->splat_count = out->range_count = 0;
    out->range_tris = 0;
    out->samples = out->cache_points = 0;
    out->boxes_sampled = out->boxes_drawn = out->cache_fills = 0;
    /* the walk's stack: at most 7 more per level below the root */
    size_t need = 8 * (RZB_MAX_DEPTH + 2);
    if (z->stack_cap < need) {
        uint32_t *s = hlod_mem_realloc(z->a, z->stack, need * sizeof *s);
        if (!s)
            return HLOD_ERR_NOMEM;
        z->stack = s;
        z->stack_cap = need;
    }
    double pixels = v->width * v->height;
    frame_ctx f = {.z = z,
                   .v = v,
                   .eps = p->eps,
                   .d2 = p->d * p->d,
                   .lnv = log(pixels > 2 ? pixels : 2),
                   .f2 = v->pixels_per_radian * v->pixels_per_radian,
                   .rng = p->seed,
                   .out = out,
                   .splat_c = p->splat_c,
                   .frame = p->frame,
                   .d = p->d,
                   .raster = !p->no_raster};
    out->splatted = p->splat_c;
    if (p->splat_c && !clear_frame(&f))
        return HLOD_ERR_NOMEM;
    if (z->copy_levels && z->class_count)
        walk_copies(&f);
    else
        for (uint32_t c = 0; c < z->class_count && !f.nomem; c++)
            walk_class(&f, c);
    cache_trim(z, p->frame);
    out->cache_bytes = z->cache_bytes;
    return f.nomem ? HLOD_ERR_NOMEM : HLOD_OK;
}

/* ---- the rasteriser's part ---- */

/* Class c's faces as a payload: three corners each (relative to the
 * origin), the face normal at each, the corners' colours. */
static hlod_result upload_class(hlod_rzb *z, rzb_class *c, hlod_renderer *r)
{
    size_t nv = 3 * (size_t)c->count;
    if (!nv || nv > INT32_MAX)
        return nv ? HLOD_ERR_NOMEM : HLOD_OK;
    float *pos = hlod_mem_alloc(z->a, nv * 3 * sizeof *pos);
    float *nrm = hlod_mem_alloc(z->a, nv * 3 * sizeof *nrm);
    uint8_t *rgba = hlod_mem_alloc(z->a, nv * 4);
    uint32_t *idx = hlod_mem_alloc(z->a, nv * sizeof *idx);
    hlod_result res = HLOD_ERR_NOMEM;
    if (pos && nrm && rgba && idx) {
        for (uint32_t t = 0; t < c->count; t++)
            for (int k = 0; k < 3; k++) {
                size_t v = 3 * (size_t)t + (size_t)k;
                memcpy(pos + 3 * v, c->tri[t].p[k], 3 * sizeof *pos);
                memcpy(nrm + 3 * v, c->tri[t].n, 3 * sizeof *nrm);
                memcpy(rgba + 4 * v, c->tri[t].rgba[k], 4);
                idx[v] = (uint32_t)v;
            }
        hlod_store_payload p = {.vertex_count = (uint32_t)nv,
                                .index_count = (uint32_t)nv,
                                .positions = pos,
                                .normals = nrm,
                                .colors = rgba,
                                .indices = idx};
        res = hlod_gpu_upload(r, &p, &c->gpu);
    }
    hlod_mem_free(z->a, pos);
    hlod_mem_free(z->a, nrm);
    hlod_mem_free(z->a, rgba);
    hlod_mem_free(z->a, idx);
    return res;
}

hlod_result hlod_rzb_upload(hlod_rzb *z, hlod_renderer *r)
{
    if (!z || !r || !z->finished)
        return HLOD_ERR_INVALID_ARG;
    hlod_result res = HLOD_OK;
    for (uint32_t c = 0; c < z->class_count && res == HLOD_OK; c++)
        res = upload_class(z, &z->cls[c], r);
    return res;
}

void hlod_rzb_release(hlod_rzb *z, hlod_renderer *r)
{
    for (uint32_t c = 0; z && r && c < z->class_count; c++)
        hlod_gpu_release(r, &z->cls[c].gpu);
}

void hlod_rzb_draw(const hlod_rzb *z, hlod_renderer *r, const double eye[3],
                   const hlod_rzb_out *out, double d)
{
    for (size_t k = 0; k < out->range_count; k++) {
        const hlod_rzb_range *g = &out->ranges[k];
        const rzb_class *c = &z->cls[g->cls];
        double off[3] = {c->origin[0] + g->off[0] - eye[0], c->origin[1] + g->off[1] - eye[1],
                         c->origin[2] + g->off[2] - eye[2]};
        hlod_gpu_draw_range(r, &c->gpu, off, 3 * g->first, 3 * g->count);
    }
    if (out->splatted && out->w && out->h)
        (void)hlod_gpu_composite(r, out->rgba, out->depth, out->w, out->h);
    else if (!out->splatted)
        (void)hlod_gpu_splats(r, out->splats, (uint32_t)out->splat_count, (float)d);
}
