/*
 * simplify.c - Garland-Heckbert quadric edge collapse (see simplify.h).
 *
 * Design:
 * - Topology lives on *position vertices* (pv): input vertices with the
 *   same double position are welded.  Each input vertex is a *wedge* (one
 *   attribute set of a pv); a triangle corner names a pv and a wedge.  A UV
 *   seam is thus an edge whose two faces use different wedges, and both
 *   sides of a seam always share one position: seams cannot open.
 * - Positions are re-centred on the bounding-box centre and divided by the
 *   largest extent, so the arithmetic is the same for a mesh at x = 5e6 m
 *   or at the origin, and for a mesh in millimetres or kilometres.
 * - Error: area-weighted plane quadrics (Garland-Heckbert 1997) plus, per
 *   wedge, Hoppe's (1999) attribute quadric for UVs, reduced in closed form
 *   to a quadric over position (the best UV for a point is a weighted mean
 *   of the faces' linear UV functions).  Borders, seams and material
 *   boundaries get perpendicular constraint planes so they keep their shape.
 * - Feature rules (as meshoptimizer's vertex kinds, but with free
 *   placement): a vertex on a feature line (border/seam) may only move along
 *   that line, i.e. collapse along a feature edge; an interior vertex may
 *   collapse onto a feature vertex, which then stays put; vertices with 1 or
 *   more than 2 feature edges, non-manifold ones and user-locked ones never
 *   move.
 * - Placement: quadric optimum when the 3x3 system is well conditioned
 *   (scale-free test) and the point stays near the edge; else the best
 *   point on the edge; else an endpoint.  When a collapse is made, the
 *   candidates are tried cheapest first against the link condition, face
 *   flips/folds and slivers.
 * - Priority order in passes (as meshoptimizer schedules its collapses):
 *   each pass prices every edge (later passes: those whose prices
 *   changed), radix-sorts the prices under its bound and collapses in
 *   that order, skipping edges whose endpoints this pass already changed,
 *   and stops at that bound, 1.5x the price of the collapse that would
 *   reach the target.  Both endpoint quadrics of a queued edge are untouched until
 *   it is taken, so its price is exact, as with a heap; a pass just avoids
 *   the heap's cache misses (a 4-ary heap with lazy deletion spent 40% of
 *   the time in sift-down on bunny00.off, and this is 3x faster).
 * - Vertices and triangles are numbered internally along a Morton curve.
 */
#include "hlod_clock.h"
#include "union_find.h"
#include "hlod/simplify.h"

#include "cluster.h"
#include "hlod/distance.h"
#include "hlod/vec3.h"
#include "prefetch.h"

#include <assert.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* Tunables: scale-free, explained where used.  (#ifndef so experiments
 * can override them from the compiler command line.) */
#ifndef BORDER_WEIGHT
#define BORDER_WEIGHT 10.0    /* constraint plane weight per unit edge length^2 */
#endif
#ifndef COND_MIN
#define COND_MIN 1e-5         /* det / (trace/3)^3 below this: ill-conditioned */
#endif
#ifndef SPIKE_FACTOR
#define SPIKE_FACTOR 1.0      /* optimum farther than this * |ab| from the edge */
#endif
#ifndef FLIP_COS
#define FLIP_COS 0.2          /* face normal may turn by at most ~78 degrees */
#endif
#ifndef PASS_SLACK
#define PASS_SLACK 1.5f       /* a pass stops at this x the goal collapse's price */
#endif
#ifndef SLIVER_Q
#define SLIVER_Q 0.01         /* triangle quality 4*sqrt(3)*A / sum(l^2) floor */
#endif
#ifndef UV_STRETCH_MAX
#define UV_STRETCH_MAX 4.0    /* texture stretch: sigma_max / sigma_min of the
                                 UV-to-surface map of a face, in UV units */
#endif

typedef struct quadric {
    double a00, a01, a02, a11, a12, a22; /* symmetric 3x3 */
    double b0, b1, b2;                   /* linear term (x^T A x + 2 b.x + c) */
    double c;
} quadric;

/* Hoppe attribute quadric of one wedge (or a merged group), for u and v. */
typedef struct attrq {
    double w;          /* sum of weights */
    double g[2][3];    /* sum w * gradient */
    double d[2];       /* sum w * offset */
    quadric q;         /* sum over u,v of w * (g.x + d)^2 */
} attrq;

/* A priced collapse candidate of the current pass. */
typedef struct cand {
    float cost;
    uint32_t a, b;     /* position vertices, a < b */
} cand;

/* A small binary min-heap of re-priced candidates (see the pass loop). */
typedef struct rheap {
    cand *e;
    size_t n, cap;
} rheap;

static int rheap_push(rheap *h, cand c)
{
    if (h->n == h->cap) {
        size_t nc = h->cap ? h->cap * 2 : 256;
        cand *ne = realloc(h->e, nc * sizeof *ne);
        if (!ne)
            return 0;
        h->e = ne;
        h->cap = nc;
    }
    size_t i = h->n++;
    while (i && c.cost < h->e[(i - 1) / 2].cost) {
        h->e[i] = h->e[(i - 1) / 2];
        i = (i - 1) / 2;
    }
    h->e[i] = c;
    return 1;
}

static cand rheap_pop(rheap *h)
{
    cand top = h->e[0], last = h->e[--h->n];
    size_t i = 0;
    for (;;) {
        size_t l = 2 * i + 1;
        if (l >= h->n)
            break;
        if (l + 1 < h->n && h->e[l + 1].cost < h->e[l].cost)
            l++;
        if (!(h->e[l].cost < last.cost))
            break;
        h->e[i] = h->e[l];
        i = l;
    }
    if (h->n)
        h->e[i] = last;
    return top;
}

/* What pricing and collapsing read about a position vertex, in one place
 * (two cache lines instead of nine scattered arrays); the position itself
 * is in state.px. */
typedef struct pvert {
    quadric q;         /* geometric quadric (faces + feature constraints) */
    double w;          /* area weight sum, for error estimates */
    uint8_t alive;
    uint8_t locked;    /* never moves (user, border lock, corner, complex) */
    uint8_t ulock;     /* sticky user lock (vertex_lock, lock_border) */
    uint8_t xlock;     /* sticky complex lock: on a non-manifold edge */
    uint8_t moved;     /* position differs from its input */
    uint8_t fdeg;      /* feature edges here (capped at 255) */
    uint8_t plain;     /* plain_interior() at the last classification */
} pvert;

/* A position vertex's triangle list: pool[start .. start + count), room
 * for cap.  (One record, so a lookup reads one cache line, not three.) */
typedef struct adjrec {
    uint32_t start, count, cap;
} adjrec;

/* Constraints the passes relax, in this order, only when no collapse is
 * left (state.relax): the target is then reached wherever the caller's
 * locks allow, and the quadrics' feature planes still price what moves.
 *   RELAX_NONE     feature lines keep their topology: an edge between two
 *                  feature vertices that is no feature edge is refused,
 *                  and corners (1 or 3+ feature edges) never move;
 *   RELAX_ACROSS   such an edge may collapse (two feature lines meet);
 *   RELAX_CORNERS  corners may move too; only the caller's locks
 *                  (vertex_lock, lock_border) and non-manifold vertices
 *                  hold;
 *   RELAX_COMPLEX  vertices on non-manifold edges may move too (separate
 *                  parts that touch, welded by position, make such edges
 *                  everywhere in BIM-like models); the non-manifold edges
 *                  themselves never collapse;
 *   RELAX_TEXTURE  a face's texture may stretch past UV_STRETCH_MAX or
 *                  flip (uv_ok). */
enum { RELAX_NONE, RELAX_ACROSS, RELAX_CORNERS, RELAX_COMPLEX, RELAX_TEXTURE, RELAX_LAST = RELAX_TEXTURE };
/* Past RELAX_LAST, whole parts that cannot shrink go (prune_parts). */

/* Per-vertex flags of a pass (state.vflag). */
enum {
    VF_LOCK = 1,    /* changed by this pass: its queued prices are stale */
    VF_STALE = 2,   /* its edges must be priced again next pass */
    VF_TOUCHED = 4, /* its star changed: its parked edges may be valid */
};

/* An adjacency entry (state.pool, state.sa/sb): a face and the corner of
 * the list's own vertex in it, so walking a vertex's faces never searches
 * for that corner. */
#define ENT(t, c) ((uint32_t)(t) << 2 | (uint32_t)(c))
#define ENT_T(e) ((e) >> 2)
#define ENT_C(e) ((int)((e) & 3))
#define NEXT3(c) ((c) == 2 ? 0 : (c) + 1)

typedef struct state {
    size_t n_pos;              /* position vertices (welded input positions) */
    size_t n_wedges;           /* wedges (= input vertices) */
    size_t n_tris;             /* triangles (= input triangles) */
    int oom;                   /* an allocation failed: every phase stops
                                  and hlod_simplify returns HLOD_ERR_NOMEM */
    int relax;                 /* constraints relaxed so far (RELAX_*) */
    uint32_t *part;            /* position vertex -> its part (find_parts) */
    size_t n_parts;
    /* position vertices (phase "vertices": one allocation) */
    pvert *verts;
    double (*pos)[3];          /* their positions, normalized frame: apart
                                  from verts, so the flip tests that read a
                                  whole ring stay in cache */
    adjrec *adj;               /* their triangle lists in pool */
    uint8_t *pos_flag;         /* flags of this pass, VF_* (one byte, so
                                  the walk reads one line for all three) */
    uint32_t *pos_mark;        /* scratch stamps (link_ok, plain_interior) */
    uint32_t *pos_slot;        /* scratch: a face or record index, under a stamp */
    uint32_t pos_clock;
    /* adjacency: position vertex -> its triangles (dead ones are dropped
     * lazily); grows, so allocated apart */
    uint32_t *pool;
    size_t pool_n, pool_cap;
    /* input tables (phase "weld": one allocation) */
    uint32_t *wedge_pos;       /* wedge -> its position vertex */
    uint32_t *pos_rep;         /* position vertex -> an input vertex carrying
                                  its position */
    uint32_t *tri_pos;         /* 3 per triangle: position vertices */
    uint32_t *tri_wedge;       /* 3 per triangle: wedges */
    uint8_t *tri_alive;
    uint32_t *tri_slot;        /* input triangle -> internal slot */
    uint32_t *tri_mat;         /* material per internal triangle, or NULL */
    /* attributes (phase "attributes": one allocation) */
    uint32_t *pos_wedge;       /* untextured: position vertex -> its one wedge */
    float (*wedge_uv)[2];      /* NULL when untextured */
    attrq *wedge_aq;           /* attribute quadrics; NULL when untextured */
    uint8_t *wedge_touched;    /* uv must be recomputed from wedge_aq */
    float *wedge_sref;         /* the source's worst stretch (squared) around
                                  the wedge, merged as wedges merge (uv_ok) */
    uint32_t *wedge_mark;      /* scratch stamps (edge_groups) */
    uint32_t wedge_clock;
    double uv_weight;
    int strict_texture;        /* desc->strict_texture: RELAX_TEXTURE never comes */
    /* passes (grow, so allocated apart) */
    cand *cand;                /* this pass's candidates */
    size_t n_cand, cand_cap;
    cand *cand_tmp;            /* radix sort buffer */
    size_t cand_tmp_cap;
    rheap requeue;             /* re-priced candidates of this pass */
    cand *parked;              /* refused edges (see refresh_candidates) */
    size_t n_parked, parked_cap;
    uint32_t *star_a, *star_b; /* star faces of the edge's ends a, b */
    uint32_t *off_a, *off_b;   /* of those, the ones off the edge (a, b) */
    size_t star_cap;
    /* phase allocations, freed by state_free */
    void *weld_block, *vert_block, *attr_block;
} state;

/* ---------- small linear algebra ---------- */

static void q_add(quadric *r, const quadric *q)
{
    r->a00 += q->a00; r->a01 += q->a01; r->a02 += q->a02;
    r->a11 += q->a11; r->a12 += q->a12; r->a22 += q->a22;
    r->b0 += q->b0; r->b1 += q->b1; r->b2 += q->b2;
    r->c += q->c;
}

/* w * (n.x + d)^2 */
static void q_plane(quadric *q, const double n[3], double d, double w)
{
    q->a00 += w * n[0] * n[0]; q->a01 += w * n[0] * n[1]; q->a02 += w * n[0] * n[2];
    q->a11 += w * n[1] * n[1]; q->a12 += w * n[1] * n[2]; q->a22 += w * n[2] * n[2];
    q->b0 += w * d * n[0]; q->b1 += w * d * n[1]; q->b2 += w * d * n[2];
    q->c += w * d * d;
}

static double q_eval(const quadric *q, const double x[3])
{
    double ax = q->a00 * x[0] + q->a01 * x[1] + q->a02 * x[2];
    double ay = q->a01 * x[0] + q->a11 * x[1] + q->a12 * x[2];
    double az = q->a02 * x[0] + q->a12 * x[1] + q->a22 * x[2];
    double r = x[0] * ax + x[1] * ay + x[2] * az + 2 * (q->b0 * x[0] + q->b1 * x[1] + q->b2 * x[2]) + q->c;
    return r > 0 ? r : 0;
}

/* Solves A x = -b when A is well conditioned relative to its own scale. */
static int q_optimum(const quadric *q, double x[3])
{
    double c00 = q->a11 * q->a22 - q->a12 * q->a12;
    double c01 = q->a02 * q->a12 - q->a01 * q->a22;
    double c02 = q->a01 * q->a12 - q->a02 * q->a11;
    double det = q->a00 * c00 + q->a01 * c01 + q->a02 * c02;
    double tr = (q->a00 + q->a11 + q->a22) / 3;
    /* det = product of eigenvalues, tr = their mean: the ratio is scale
     * free and small when one eigenvalue is tiny against the others. */
    if (!(tr > 0) || !(det > COND_MIN * tr * tr * tr))
        return 0;
    double c11 = q->a00 * q->a22 - q->a02 * q->a02;
    double c12 = q->a01 * q->a02 - q->a00 * q->a12;
    double c22 = q->a00 * q->a11 - q->a01 * q->a01;
    double inv = -1.0 / det;
    x[0] = inv * (c00 * q->b0 + c01 * q->b1 + c02 * q->b2);
    x[1] = inv * (c01 * q->b0 + c11 * q->b1 + c12 * q->b2);
    x[2] = inv * (c02 * q->b0 + c12 * q->b1 + c22 * q->b2);
    return isfinite(x[0]) && isfinite(x[1]) && isfinite(x[2]);
}

/* ---------- attribute quadrics ---------- */

static void aq_add(attrq *r, const attrq *a)
{
    r->w += a->w;
    for (int j = 0; j < 2; j++) {
        for (int k = 0; k < 3; k++)
            r->g[j][k] += a->g[j][k];
        r->d[j] += a->d[j];
    }
    q_add(&r->q, &a->q);
}

/* Adds to qr the reduced quadric: min over uv of the attribute error. */
static void aq_reduce(quadric *qr, const attrq *a)
{
    if (!(a->w > 0))
        return;
    q_add(qr, &a->q);
    double s = -1.0 / a->w;
    for (int j = 0; j < 2; j++) {
        const double *g = a->g[j];
        double d = a->d[j];
        qr->a00 += s * g[0] * g[0]; qr->a01 += s * g[0] * g[1]; qr->a02 += s * g[0] * g[2];
        qr->a11 += s * g[1] * g[1]; qr->a12 += s * g[1] * g[2]; qr->a22 += s * g[2] * g[2];
        qr->b0 += s * g[0] * d; qr->b1 += s * g[1] * d; qr->b2 += s * g[2] * d;
        qr->c += s * d * d;
    }
}

static void aq_uv(const attrq *a, const double x[3], float uv[2])
{
    for (int j = 0; j < 2; j++)
        uv[j] = (float)((hlod_dot3(a->g[j], x) + a->d[j]) / a->w);
}

/* ---------- heap ---------- */

/* Appends c to a growable candidate array (*v, *n, *cap). */
static int cands_push(cand **v, size_t *n, size_t *cap, cand c)
{
    if (*n == *cap) {
        size_t nc = *cap ? *cap * 2 : 1024;
        cand *nv = realloc(*v, nc * sizeof *nv);
        if (!nv)
            return 0;
        *v = nv;
        *cap = nc;
    }
    (*v)[(*n)++] = c;
    return 1;
}

/* (the allocating helpers below set s->oom on failure and return as if
 * there were nothing to do; each phase checks s->oom) */
static void cand_push(state *s, cand c)
{
    if (!cands_push(&s->cand, &s->n_cand, &s->cand_cap, c))
        s->oom = 1;
}

static void park(state *s, cand c)
{
    if (!cands_push(&s->parked, &s->n_parked, &s->parked_cap, c))
        s->oom = 1;
}

static void requeue(state *s, cand c)
{
    if (!rheap_push(&s->requeue, c))
        s->oom = 1;
}

/* The order of a pass: by price, then edge (prices are never NaN). */
static int cand_less(const cand *x, const cand *y)
{
    if (x->cost != y->cost)
        return x->cost < y->cost;
    return x->a != y->a ? x->a < y->a : x->b < y->b;
}

/* Sorts v[0..n) by cand_less: insertion sort of blocks of 16, then
 * bottom-up merges through tmp (n places).  (Runs of equal radix keys can
 * be long: planar regions price at 0.) */
static void run_sort(cand *v, size_t n, cand *tmp)
{
    enum { BLOCK = 16 };
    for (size_t lo = 0; lo < n; lo += BLOCK) {
        size_t hi = lo + BLOCK < n ? lo + BLOCK : n;
        for (size_t a = lo + 1; a < hi; a++) {
            cand c = v[a];
            size_t b = a;
            for (; b > lo && cand_less(&c, &v[b - 1]); b--)
                v[b] = v[b - 1];
            v[b] = c;
        }
    }
    cand *src = v, *dst = tmp;
    for (size_t w = BLOCK; w < n; w *= 2) {
        for (size_t lo = 0; lo < n; lo += 2 * w) {
            size_t mid = lo + w < n ? lo + w : n, hi = lo + 2 * w < n ? lo + 2 * w : n;
            size_t x = lo, y = mid, k = lo;
            while (x < mid && y < hi)
                dst[k++] = cand_less(&src[y], &src[x]) ? src[y++] : src[x++];
            while (x < mid)
                dst[k++] = src[x++];
            while (y < hi)
                dst[k++] = src[y++];
        }
        cand *t = src;
        src = dst;
        dst = t;
    }
    if (src != v)
        memcpy(v, src, n * sizeof *v);
}

/* Sorts s->cand[0..n) by (price, a, b): an LSD radix sort of the
 * candidates themselves on the price's top 22 bits (non-negative floats
 * order like their bit patterns), 2 passes of 11 bits (3 of 8 bits, on 24,
 * for fewer than 8192), then each run with equal top bits (prices within
 * 2^-13 of each other, or tied) sorted in full.  The pass then reads them
 * in order, sequentially.  Equal prices thus go in edge order, so the order
 * does not depend on which prices were kept from the last pass (planar
 * regions tie at 0). */
static void cand_sort(state *s, size_t n)
{
    if (n > s->cand_tmp_cap) {
        free(s->cand_tmp);
        s->cand_tmp = malloc(n * sizeof *s->cand_tmp);
        s->cand_tmp_cap = s->cand_tmp ? n : 0;
        if (!s->cand_tmp) {
            s->oom = 1;
            return;
        }
    }
    /* Digits of 11 bits, or of 8 when there are few candidates (then the
     * histograms would cost more than the candidates: small meshes' late
     * passes).  Either way the runs below make the order total. */
    int bits = n < 8192 ? 8 : 11, passes = n < 8192 ? 3 : 2;
    int low = 32 - bits * passes;
    size_t nb = (size_t)1 << bits, mask = nb - 1;
    cand *src = s->cand, *dst = s->cand_tmp;
    for (int pass = 0; pass < passes; pass++) {
        size_t hist[2048];
        memset(hist, 0, nb * sizeof *hist);
        int shift = low + pass * bits;
        for (size_t i = 0; i < n; i++) {
            uint32_t k;
            memcpy(&k, &src[i].cost, 4);
            hist[(k >> shift) & mask]++;
        }
        size_t sum = 0;
        for (size_t k = 0; k < nb; k++) {
            size_t h = hist[k];
            hist[k] = sum;
            sum += h;
        }
        for (size_t i = 0; i < n; i++) {
            uint32_t k;
            memcpy(&k, &src[i].cost, 4);
            dst[hist[(k >> shift) & mask]++] = src[i];
        }
        cand *t = src;
        src = dst;
        dst = t;
    }
    if (src != s->cand)
        memcpy(s->cand, src, n * sizeof *src);
    for (size_t i = 0; i < n;) {
        uint32_t ki;
        memcpy(&ki, &s->cand[i].cost, 4);
        size_t j = i + 1;
        for (; j < n; j++) {
            uint32_t kj;
            memcpy(&kj, &s->cand[j].cost, 4);
            if (kj >> low != ki >> low)
                break;
        }
        run_sort(s->cand + i, j - i, s->cand_tmp);
        i = j;
    }
}

/* The k-th smallest price of c[0..n), k < n: a radix select on the
 * price's bits, 8 at a time (non-negative floats order like their bit
 * patterns). */
static float cost_rank(const cand *c, size_t n, size_t k)
{
    uint32_t prefix = 0;
    for (int level = 0; level < 4; level++) {
        int shift = 24 - 8 * level; /* the bits above it are known */
        uint32_t known = level ? ~0u << (shift + 8) : 0;
        size_t hist[256] = {0};
        for (size_t i = 0; i < n; i++) { /* (counted without a branch) */
            uint32_t key;
            memcpy(&key, &c[i].cost, 4);
            hist[key >> shift & 255] += (key & known) == (prefix & known);
        }
        uint32_t bucket = 0;
        while (k >= hist[bucket])
            k -= hist[bucket++];
        prefix |= bucket << shift;
    }
    float r;
    memcpy(&r, &prefix, 4);
    return r;
}

/* Moves the candidates priced at most bound to the front of c[0..n)
 * (without a branch: which side a price falls is a coin toss); returns
 * their count. */
static size_t cands_under(cand *c, size_t n, float bound)
{
    size_t j = 0;
    for (size_t i = 0; i < n; i++) {
        cand t = c[i];
        c[i] = c[j];
        c[j] = t;
        j += t.cost <= bound;
    }
    return j;
}

/* A fresh stamp for a scratch array of n marks: a mark equal to it was set
 * after this call.  (When the clock wraps, the marks are cleared.) */
static uint32_t new_stamp(uint32_t *marks, uint32_t *clock, size_t n)
{
    if (++*clock == 0) {
        memset(marks, 0, n * sizeof *marks);
        *clock = 1;
    }
    return *clock;
}

/* ---------- adjacency ---------- */

static int adj_reserve(state *s, uint32_t v, uint32_t need)
{
    if (s->adj[v].cap >= need)
        return 1;
    uint32_t cap = need * 2;
    if (s->pool_n + cap > s->pool_cap) {
        size_t nc = (s->pool_n + cap) * 3 / 2;
        uint32_t *np = realloc(s->pool, nc * sizeof *np);
        if (!np) {
            s->oom = 1;
            return 0;
        }
        s->pool = np;
        s->pool_cap = nc;
    }
    memcpy(s->pool + s->pool_n, s->pool + s->adj[v].start, s->adj[v].count * sizeof(uint32_t));
    s->adj[v].start = (uint32_t)s->pool_n;
    s->adj[v].cap = cap;
    s->pool_n += cap;
    return 1;
}

/* Copies the live face entries around v (see ENT) into s->star_a (which = 0)
 * or s->star_b (1), both grown together as needed; returns the count
 * (0 and s->oom set when out of memory). */
static size_t star(state *s, uint32_t v, int which)
{
    uint32_t n = s->adj[v].count;
    if (n > s->star_cap) {
        size_t nc = (size_t)n * 2;
        uint32_t **bufs[4] = {&s->star_a, &s->star_b, &s->off_a, &s->off_b};
        for (int i = 0; i < 4; i++) {
            uint32_t *nb = realloc(*bufs[i], nc * sizeof *nb);
            if (!nb) {
                s->oom = 1;
                return 0;
            }
            *bufs[i] = nb;
        }
        s->star_cap = nc;
    }
    uint32_t *buf = which ? s->star_b : s->star_a;
    const uint32_t *list = s->pool + s->adj[v].start;
    size_t k = 0;
    for (uint32_t i = 0; i < n; i++) {
        buf[k] = list[i];
        k += s->tri_alive[ENT_T(list[i])];
    }
    return k;
}

/* The corner of v in face t, -1 when v is not on it.  (Without branches:
 * which corner it is, is a coin toss for the predictor.  A live face has
 * three distinct corners, so at most one bit is set.) */
static int corner_of(const state *s, uint32_t t, uint32_t v)
{
    static const signed char corner[8] = {-1, 0, 1, -1, 2, -1, -1, -1};
    const uint32_t *tv = s->tri_pos + 3 * (size_t)t;
    return corner[(tv[0] == v) | (tv[1] == v) << 1 | (tv[2] == v) << 2];
}

/* ---------- vertex classification ---------- */

typedef struct nrec {
    uint32_t n;        /* neighbour pv */
    uint32_t wv, wn;   /* wedges at v and n in the first face seen */
    uint32_t mat;
    uint16_t faces;
    uint8_t feature;
} nrec;

/* Fills recs with one record per neighbour of v; returns the count (0 and
 * s->oom set on allocation failure).  *recs is a caller-owned growable
 * buffer. */
static long neighbours(state *s, uint32_t v, nrec **recs, size_t *rcap)
{
    uint32_t *faces = s->pool + s->adj[v].start;
    uint32_t nf = s->adj[v].count;
    if ((size_t)nf * 2 > *rcap) {
        size_t nc = (size_t)nf * 4 + 16;
        nrec *nr = realloc(*recs, nc * sizeof *nr);
        if (!nr) {
            s->oom = 1;
            return 0;
        }
        *recs = nr;
        *rcap = nc;
    }
    nrec *r = *recs;
    long cnt = 0;
    uint32_t stamp = new_stamp(s->pos_mark, &s->pos_clock, s->n_pos); /* a stamped neighbour's record is slot[n] */
    for (uint32_t i = 0; i < nf; i++) {
        uint32_t t = ENT_T(faces[i]);
        if (!s->tri_alive[t])
            continue;
        int c = ENT_C(faces[i]);
        assert(s->tri_pos[3 * (size_t)t + c] == v);
        uint32_t mat = s->tri_mat ? s->tri_mat[t] : 0;
        /* (untextured, a vertex has one wedge: only faces and materials
         * can make a feature edge, and the wedges need no reading) */
        uint32_t wv = s->wedge_uv ? s->tri_wedge[3 * t + c] : 0;
        for (int k = 1; k <= 2; k++) {
            int cn = (c + k) % 3;
            uint32_t n = s->tri_pos[3 * t + cn], wn = s->wedge_uv ? s->tri_wedge[3 * t + cn] : 0;
            long j = s->pos_mark[n] == stamp ? (long)s->pos_slot[n] : cnt;
            if (j == cnt) {
                s->pos_mark[n] = stamp;
                s->pos_slot[n] = (uint32_t)cnt;
                r[cnt].n = n;
                r[cnt].wv = wv;
                r[cnt].wn = wn;
                r[cnt].mat = mat;
                r[cnt].faces = 1;
                r[cnt].feature = 0;
                cnt++;
            } else {
                if (r[j].faces < 0xffff)
                    r[j].faces++;
                if (r[j].wv != wv || r[j].wn != wn || r[j].mat != mat)
                    r[j].feature = 1;
            }
        }
    }
    for (long j = 0; j < cnt; j++)
        if (r[j].faces != 2)
            r[j].feature = 1;
    return cnt;
}

/* neighbours() for pricing: a plain interior vertex has a closed manifold
 * fan, where every neighbour follows v in exactly one face, so the
 * O(deg^2) matching is not needed.  (Not every vertex without feature
 * edges: where the winding flips, two faces can both follow v with the
 * same neighbour, and the fast path would list one twice and miss one.) */
static long edges_of(state *s, uint32_t v, nrec **recs, size_t *rcap)
{
    if (!s->verts[v].plain)
        return neighbours(s, v, recs, rcap);
    uint32_t *faces = s->pool + s->adj[v].start;
    uint32_t nf = s->adj[v].count;
    if ((size_t)nf > *rcap) {
        size_t nc = (size_t)nf * 4 + 16;
        nrec *nr = realloc(*recs, nc * sizeof *nr);
        if (!nr) {
            s->oom = 1;
            return 0;
        }
        *recs = nr;
        *rcap = nc;
    }
    long cnt = 0;
    for (uint32_t i = 0; i < nf; i++) {
        uint32_t t = ENT_T(faces[i]);
        if (!s->tri_alive[t])
            continue;
        uint32_t n = s->tri_pos[3 * (size_t)t + NEXT3(ENT_C(faces[i]))];
        nrec *r = &(*recs)[cnt++];
        r->n = n;
        r->faces = 2;
        r->feature = 0;
    }
    return cnt;
}

/* Is v an interior vertex of one UV chart and one material: every edge
 * shared by exactly two faces that agree on the wedges at both ends?
 * (In O(faces): the neighbours that follow v are stamped with their face.) */
static int plain_interior(state *s, uint32_t v)
{
    const uint32_t *faces = s->pool + s->adj[v].start;
    uint32_t nf = s->adj[v].count;
    uint32_t pv[32], wv[32], wn[32], wp[32], mt[32];
    uint32_t k = 0;
    uint32_t stamp = new_stamp(s->pos_mark, &s->pos_clock, s->n_pos);
    for (uint32_t i = 0; i < nf; i++) {
        uint32_t t = ENT_T(faces[i]);
        if (!s->tri_alive[t])
            continue;
        if (k == 32)
            return 0;
        int c = ENT_C(faces[i]);
        int c1 = NEXT3(c), c2 = NEXT3(c1);
        uint32_t nx = s->tri_pos[3 * t + c1];
        /* each neighbour follows v in one face only (consistent winding) */
        if (s->pos_mark[nx] == stamp)
            return 0;
        s->pos_mark[nx] = stamp;
        s->pos_slot[nx] = k;
        pv[k] = s->tri_pos[3 * t + c2];
        if (s->wedge_uv) {
            wv[k] = s->tri_wedge[3 * t + c];
            wn[k] = s->tri_wedge[3 * t + c1];
            wp[k] = s->tri_wedge[3 * t + c2];
        } else { /* one wedge per vertex: they always agree */
            wv[k] = wn[k] = wp[k] = 0;
        }
        mt[k] = s->tri_mat ? s->tri_mat[t] : 0;
        k++;
    }
    if (k < 3)
        return 0;
    /* and precedes it in exactly one other face, with the same wedges */
    uint32_t matched = 0;
    for (uint32_t j = 0; j < k; j++) {
        uint32_t p = pv[j];
        if (s->pos_mark[p] != stamp)
            return 0;
        uint32_t i = s->pos_slot[p];
        if (matched >> i & 1u || wv[j] != wv[i] || wp[j] != wn[i] || mt[j] != mt[i])
            return 0;
        matched |= 1u << i;
    }
    return 1;
}

/* Recomputes fdeg/locked of v from its current star. */
static void classify(state *s, uint32_t v, nrec **recs, size_t *rcap)
{
    s->verts[v].plain = (uint8_t)plain_interior(s, v);
    if (s->verts[v].plain) {
        s->verts[v].fdeg = 0;
        s->verts[v].locked = s->verts[v].ulock | s->verts[v].xlock;
        return;
    }
    long cnt = neighbours(s, v, recs, rcap);
    if (s->oom)
        return;
    unsigned f = 0;
    int complex_ = 0;
    for (long j = 0; j < cnt; j++) {
        f += (*recs)[j].feature;
        if ((*recs)[j].faces > 2)
            complex_ = 1;
    }
    if (complex_)
        s->verts[v].xlock = 1;
    s->verts[v].fdeg = (uint8_t)(f > 255 ? 255 : f);
    s->verts[v].locked = s->verts[v].ulock || s->verts[v].xlock || f == 1 || f > 2;
}

/* ---------- collapse evaluation ---------- */

typedef struct plan {
    double x[3];
    double cost;      /* total quadric error at x */
} plan;

/* Wedge groups for an edge collapse: pairs joined through the edge faces. */
typedef struct wgroup {
    uint32_t w[2];
    int n;
} wgroup;

#define MAX_GROUPS 64

typedef struct eval {
    int allowed;
    int forced;        /* 0 free, 1 at a, 2 at b */
    quadric qsum;      /* geometric + reduced attribute quadric */
    quadric qgeo;
    double w;          /* area weight for estimates */
    plan cand[4];
    int ncand;
    wgroup g[MAX_GROUPS]; /* the edge's wedge groups (textured meshes) */
    int ng;
} eval;


static int edge_groups(state *s, uint32_t b, const uint32_t *fa, size_t na,
                       const uint32_t *fb, size_t nb, wgroup *g)
{
    /* A wedge already in a group is stamped (a's and b's wedges are
     * distinct: a wedge belongs to one position vertex). */
    uint32_t stamp = new_stamp(s->wedge_mark, &s->wedge_clock, s->n_wedges);
    int ng = 0;
    /* Pairs through the faces containing both a and b. */
    for (size_t i = 0; i < na; i++) {
        uint32_t t = ENT_T(fa[i]);
        int cb = corner_of(s, ENT_T(fa[i]), b);
        if (cb < 0)
            continue;
        uint32_t wa = s->tri_wedge[3 * t + ENT_C(fa[i])], wb = s->tri_wedge[3 * t + cb];
        if (s->wedge_mark[wa] != stamp && s->wedge_mark[wb] != stamp && ng < MAX_GROUPS) {
            s->wedge_mark[wa] = s->wedge_mark[wb] = stamp;
            g[ng].w[0] = wa;
            g[ng].w[1] = wb;
            g[ng].n = 2;
            ng++;
        }
    }
    /* Remaining wedges of a and b stand alone. */
    for (int side = 0; side < 2; side++) {
        const uint32_t *f = side ? fb : fa;
        size_t nf = side ? nb : na;
        for (size_t i = 0; i < nf; i++) {
            uint32_t w = s->tri_wedge[3 * ENT_T(f[i]) + ENT_C(f[i])];
            if (s->wedge_mark[w] != stamp && ng < MAX_GROUPS) {
                s->wedge_mark[w] = stamp;
                g[ng].w[0] = w;
                g[ng].n = 1;
                ng++;
            }
        }
    }
    return ng;
}

/* The wedge of v in any live face (v's only wedge when fdeg is 0). */
static uint32_t any_wedge(const state *s, uint32_t v)
{
    const uint32_t *f = s->pool + s->adj[v].start;
    for (uint32_t i = 0; i < s->adj[v].count; i++)
        if (s->tri_alive[ENT_T(f[i])])
            return s->tri_wedge[3 * (size_t)ENT_T(f[i]) + ENT_C(f[i])];
    assert(!"vertex without a live face");
    return 0;
}

static void add_candidate(eval *e, const double x[3])
{
    plan *p = &e->cand[e->ncand++];
    memcpy(p->x, x, sizeof p->x);
    p->cost = q_eval(&e->qsum, x);
#ifdef RANK_RMS
    p->cost /= e->w > 0 ? e->w : 1;
#endif
}

/* Prices the collapse of edge (a, b): which placements are allowed and what
 * each costs.  fa/fb are the live stars of a and b (used for UV wedges
 * only).  With all == 0 only the cheapest candidate is guaranteed: an
 * accepted optimum or an interior edge minimum makes the others moot. */
static void evaluate(state *s, uint32_t a, uint32_t b, int edge_feature,
                     const uint32_t *fa, size_t na, const uint32_t *fb, size_t nb, int all, eval *e)
{
    e->allowed = 0;
    e->ncand = 0;
    int la = s->verts[a].locked, lb = s->verts[b].locked;
    if (s->relax >= RELAX_CORNERS) { /* only the caller's and non-manifold locks hold */
        la = s->verts[a].ulock | (s->relax < RELAX_COMPLEX ? s->verts[a].xlock : 0);
        lb = s->verts[b].ulock | (s->relax < RELAX_COMPLEX ? s->verts[b].xlock : 0);
    }
    int fta = la || s->verts[a].fdeg > 0, ftb = lb || s->verts[b].fdeg > 0;
    if (la && lb)
        return;
    if (edge_feature || (fta && ftb && s->relax >= RELAX_ACROSS))
        e->forced = la ? 1 : lb ? 2 : 0;
    else if (fta && ftb)
        return;
    else
        e->forced = fta ? 1 : ftb ? 2 : 0;
    e->allowed = 1;

    e->qgeo = s->verts[a].q;
    q_add(&e->qgeo, &s->verts[b].q);
    e->qsum = e->qgeo;
    e->w = s->verts[a].w + s->verts[b].w;
    e->ng = 0;
    if (s->wedge_aq) {
        wgroup *g = e->g;
        int ng;
        if (!s->verts[a].fdeg && !s->verts[b].fdeg) {
            /* no seam at either end: one wedge each, merged */
            g[0].w[0] = any_wedge(s, a);
            g[0].w[1] = any_wedge(s, b);
            g[0].n = 2;
            ng = 1;
        } else {
            ng = edge_groups(s, b, fa, na, fb, nb, g);
        }
        e->ng = ng;
        for (int i = 0; i < ng; i++) {
            attrq t = s->wedge_aq[g[i].w[0]];
            if (g[i].n == 2)
                aq_add(&t, &s->wedge_aq[g[i].w[1]]);
            aq_reduce(&e->qsum, &t);
        }
    }

    const double *pa = s->pos[a], *pb = s->pos[b];
    if (e->forced) {
        add_candidate(e, e->forced == 1 ? pa : pb);
        return;
    }
    double opt[3];
    if (q_optimum(&e->qsum, opt)) {
        /* Reject far-away optima: the "spike" of optimal placement on
         * nearly flat or nearly cylindrical areas. */
        double ab[3], ao[3];
        hlod_sub3(ab, pb, pa);
        hlod_sub3(ao, opt, pa);
        double l2 = hlod_dot3(ab, ab);
        double t = l2 > 0 ? hlod_dot3(ao, ab) / l2 : 0;
        t = t < 0 ? 0 : t > 1 ? 1 : t;
        double d[3] = {ao[0] - t * ab[0], ao[1] - t * ab[1], ao[2] - t * ab[2]};
        if (hlod_dot3(d, d) <= SPIKE_FACTOR * SPIKE_FACTOR * l2) {
            add_candidate(e, opt);
            if (!all)
                return;
        }
    }
    /* Best point on the edge: minimise the quadric along a + t (b - a). */
    {
        double ab[3];
        hlod_sub3(ab, pb, pa);
        const quadric *q = &e->qsum;
        double Ad[3] = {q->a00 * ab[0] + q->a01 * ab[1] + q->a02 * ab[2],
                        q->a01 * ab[0] + q->a11 * ab[1] + q->a12 * ab[2],
                        q->a02 * ab[0] + q->a12 * ab[1] + q->a22 * ab[2]};
        double Aa[3] = {q->a00 * pa[0] + q->a01 * pa[1] + q->a02 * pa[2],
                        q->a01 * pa[0] + q->a11 * pa[1] + q->a12 * pa[2],
                        q->a02 * pa[0] + q->a12 * pa[1] + q->a22 * pa[2]};
        double den = hlod_dot3(ab, Ad);
        double bd = q->b0 * ab[0] + q->b1 * ab[1] + q->b2 * ab[2];
        double num = -(hlod_dot3(ab, Aa) + bd);
        if (den > 0) {
            double t = num / den;
            if (t > 1e-3 && t < 1 - 1e-3) {
                double x[3] = {pa[0] + t * ab[0], pa[1] + t * ab[1], pa[2] + t * ab[2]};
                add_candidate(e, x);
                if (!all)
                    return;
            }
        }
    }
    add_candidate(e, pa);
    add_candidate(e, pb);
}

/* evaluate(all = 0) for the common case, kept lean because every pass
 * prices every edge: no UVs, no features, no locks, so the placement is
 * free and only the cheapest candidate's cost is needed. */
static double price_plain(const state *s, uint32_t a, uint32_t b)
{
    const quadric *qa = &s->verts[a].q, *qb = &s->verts[b].q;
    quadric q = {qa->a00 + qb->a00, qa->a01 + qb->a01, qa->a02 + qb->a02, qa->a11 + qb->a11,
                 qa->a12 + qb->a12, qa->a22 + qb->a22, qa->b0 + qb->b0,   qa->b1 + qb->b1,
                 qa->b2 + qb->b2,   qa->c + qb->c};
    const double *pa = s->pos[a], *pb = s->pos[b];
    double ab[3] = {pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]};
    double l2 = hlod_dot3(ab, ab);
    double opt[3];
    if (q_optimum(&q, opt)) {
        double ao[3] = {opt[0] - pa[0], opt[1] - pa[1], opt[2] - pa[2]};
        double t = l2 > 0 ? hlod_dot3(ao, ab) / l2 : 0;
        t = t < 0 ? 0 : t > 1 ? 1 : t;
        double d[3] = {ao[0] - t * ab[0], ao[1] - t * ab[1], ao[2] - t * ab[2]};
        if (hlod_dot3(d, d) <= SPIKE_FACTOR * SPIKE_FACTOR * l2) {
            return q_eval(&q, opt);
        }
    }
    double Ad[3] = {q.a00 * ab[0] + q.a01 * ab[1] + q.a02 * ab[2], q.a01 * ab[0] + q.a11 * ab[1] + q.a12 * ab[2],
                    q.a02 * ab[0] + q.a12 * ab[1] + q.a22 * ab[2]};
    double den = hlod_dot3(ab, Ad);
    if (den > 0) {
        double Aa[3] = {q.a00 * pa[0] + q.a01 * pa[1] + q.a02 * pa[2],
                        q.a01 * pa[0] + q.a11 * pa[1] + q.a12 * pa[2],
                        q.a02 * pa[0] + q.a12 * pa[1] + q.a22 * pa[2]};
        double t = -(hlod_dot3(ab, Aa) + q.b0 * ab[0] + q.b1 * ab[1] + q.b2 * ab[2]) / den;
        if (t > 1e-3 && t < 1 - 1e-3) {
            double x[3] = {pa[0] + t * ab[0], pa[1] + t * ab[1], pa[2] + t * ab[2]};
            return q_eval(&q, x);
        }
    }
    double ca = q_eval(&q, pa), cb = q_eval(&q, pb);
    return ca < cb ? ca : cb;
}

static double best_cost(const eval *e)
{
    double c = DBL_MAX;
    for (int i = 0; i < e->ncand; i++)
        if (e->cand[i].cost < c)
            c = e->cand[i].cost;
    return c;
}

/* The price of collapsing edge (a, b), a < b, as a pass ranks it: 1 with
 * *price set, 0 when no placement is allowed (or out of memory: s->oom). */
static int price_edge(state *s, uint32_t a, uint32_t b, int feature, double *price)
{
    if (!s->wedge_aq && !feature && !s->verts[a].fdeg && !s->verts[b].fdeg && !s->verts[a].locked && !s->verts[b].locked) {
        *price = price_plain(s, a, b);
        return 1;
    }
    /* stars feed the wedge groups of seam vertices only */
    int need = s->wedge_aq && (s->verts[a].fdeg || s->verts[b].fdeg);
    size_t na = need ? star(s, a, 0) : 0, nb = need ? star(s, b, 1) : 0;
    if (s->oom)
        return 0;
    eval e;
    evaluate(s, a, b, feature, s->star_a, na, s->star_b, nb, 0, &e);
    if (!e.allowed)
        return 0;
    *price = best_cost(&e);
    return 1;
}

#ifdef HLOD_SELFCHECK
static int try_edge(state *s, uint32_t a, uint32_t b, eval *e, size_t *na_, size_t *nb_);

static int cand_edge_order(const void *pa, const void *pb)
{
    const cand *x = pa, *y = pb;
    if (x->a != y->a)
        return x->a < y->a ? -1 : 1;
    return (x->b > y->b) - (x->b < y->b);
}

/* The candidates of a pass must be exactly what pricing every edge anew
 * would give: the same edges, each once, at the same prices; every kept
 * vertex class must be what its faces say, and every parked edge must
 * still be refused.  Aborts otherwise (the incremental pricing in the pass
 * loop relies on it). */

static void selfcheck_prices(state *s, nrec **recs, size_t *rcap)
{
    size_t n = s->n_cand + s->n_parked, found = 0;
    cand *sorted = malloc((n ? n : 1) * sizeof *sorted);
    if (!sorted)
        return;
    if (s->n_cand) /* (cand is NULL until the first candidate) */
        memcpy(sorted, s->cand, s->n_cand * sizeof *sorted);
    if (s->n_parked)
        memcpy(sorted + s->n_cand, s->parked, s->n_parked * sizeof *sorted);
    /* every vertex's class is what its star says now */
    for (size_t v = 0; v < s->n_pos; v++) {
        if (!s->verts[v].alive || !s->adj[v].count)
            continue;
        pvert kept = s->verts[v];
        classify(s, (uint32_t)v, recs, rcap);
        if (s->oom)
            goto out_of_memory;
        /* (plain may lag behind: a vertex over 32 faces is not plain, and
         * one that loses faces in plain collapses around it is not looked
         * at again; that only costs the slower neighbour listing) */
        if (kept.fdeg != s->verts[v].fdeg || kept.locked != s->verts[v].locked || (kept.plain && !s->verts[v].plain)) {
            fprintf(stderr, "simplify selfcheck: vertex %zu classified as fdeg %d locked %d plain %d, "
                    "its star says %d %d %d\n", v, kept.fdeg, kept.locked, kept.plain, s->verts[v].fdeg,
                    s->verts[v].locked, s->verts[v].plain);
            abort();
        }
        s->verts[v] = kept;
    }
    /* a parked edge must still be refused */
    for (size_t i = 0; i < s->n_parked; i++) {
        eval e;
        size_t na, nb;
        int k = try_edge(s, s->parked[i].a, s->parked[i].b, &e, &na, &nb);
        if (s->oom)
            goto out_of_memory;
        if (k >= 0) {
            fprintf(stderr, "simplify selfcheck: parked edge %u-%u is valid\n", s->parked[i].a,
                    s->parked[i].b);
            abort();
        }
    }
    qsort(sorted, n, sizeof *sorted, cand_edge_order);
    for (size_t i = 1; i < n; i++)
        if (sorted[i].a == sorted[i - 1].a && sorted[i].b == sorted[i - 1].b) {
            fprintf(stderr, "simplify selfcheck: edge %u-%u listed twice\n", sorted[i].a, sorted[i].b);
            abort();
        }
    for (size_t v = 0; v < s->n_pos; v++) {
        if (!s->verts[v].alive || !s->adj[v].count)
            continue;
        long cnt = neighbours(s, (uint32_t)v, recs, rcap);
        if (s->oom)
            goto out_of_memory;
        for (long j = 0; j < cnt; j++) {
            nrec r = (*recs)[j];
            if (r.n < v || r.faces > 2)
                continue;
            uint32_t a = (uint32_t)v, b = r.n;
            double price;
            int k = price_edge(s, a, b, r.feature, &price);
            if (s->oom)
                goto out_of_memory;
            if (k == 0)
                continue;
            cand key = {0, a, b};
            const cand *c = bsearch(&key, sorted, n, sizeof *sorted, cand_edge_order);
            if (!c || c->cost != (float)price) {
                fprintf(stderr, "simplify selfcheck: edge %u-%u %s (%g, fresh %g)\n", a, b,
                        c ? "mispriced" : "missing", c ? c->cost : 0.0, price);
                abort();
            }
            found++;
        }
    }
    if (found != n) {
        fprintf(stderr, "simplify selfcheck: %zu candidates, %zu edges\n", n, found);
        abort();
    }
out_of_memory: /* no verdict */
    free(sorted);
}
#endif

/* ---------- validity checks ---------- */

/* Do the faces f of v (those off the collapsing edge) keep their
 * orientation and shape when v moves to x?  With d = p2 - p1 the edge
 * opposite v, a face's (doubled) normal is d x (v - p1) before and
 * d x (x - p1) after: one cross product each, squared forms, no sqrt.
 * This runs for every face of every collapse. */
static int star_ok(const state *s, uint32_t v, const uint32_t *f, size_t nf, const double x[3])
{
    const double *pv = s->pos[v];
    for (size_t i = 0; i < nf; i++) {
        const uint32_t *tv = s->tri_pos + 3 * (size_t)ENT_T(f[i]);
        int c1 = NEXT3(ENT_C(f[i])), c2 = NEXT3(c1);
        const double *p1 = s->pos[tv[c1]], *p2 = s->pos[tv[c2]];
        double d[3], a0[3], a1[3], n0[3], n1[3];
        hlod_sub3(d, p2, p1);
        hlod_sub3(a0, pv, p1);
        hlod_sub3(a1, x, p1);
        hlod_cross3(n0, d, a0);
        hlod_cross3(n1, d, a1);
        double s0 = hlod_dot3(n0, n0), s1 = hlod_dot3(n1, n1), dn = hlod_dot3(n0, n1);
        if (!(s1 > 0))
            return 0;
        if (s0 > 0 && (dn < 0 || dn * dn < FLIP_COS * FLIP_COS * s0 * s1))
            return 0;
        /* quality^2 = 12 |n|^2 / l^2 with l the sum of squared edges: a
         * new sliver is refused unless the face was already that bad, or
         * it was a sliver and only grows longer, not thinner (its height
         * over its longest edge, |n| / e_max, does not shrink): a strip
         * that is all needles can only be simplified by longer needles */
        double dd = hlod_dot3(d, d), e1a = hlod_dot3(a1, a1), e1b = e1a - 2 * hlod_dot3(a1, d) + dd;
        double l1 = dd + e1a + e1b;
        if (12 * s1 < SLIVER_Q * SLIVER_Q * l1 * l1) {
            double e0a = hlod_dot3(a0, a0), e0b = e0a - 2 * hlod_dot3(a0, d) + dd;
            double l0 = dd + e0a + e0b;
            if (s1 * l0 * l0 < s0 * l1 * l1) {
                double m0 = fmax(dd, fmax(e0a, e0b)), m1 = fmax(dd, fmax(e1a, e1b));
                if (!(12 * s0 < SLIVER_Q * SLIVER_Q * l0 * l0) || s1 * m0 < s0 * m1)
                    return 0;
            }
        }
    }
    return 1;
}

/* Texture stretch of a face (positions p, UVs t): (sigma_max /
 * sigma_min)^2 of the map from UV to the surface (the Jacobian's singular
 * values, Sander et al.'s stretch), INFINITY when the UV triangle is
 * degenerate; *orient gets the UV triangle's winding (+1, -1, 0). */
static double uv_stretch2(const double *p0, const double *p1, const double *p2, const float *t0,
                          const float *t1, const float *t2, int *orient)
{
    double e1[3], e2[3];
    hlod_sub3(e1, p1, p0);
    hlod_sub3(e2, p2, p0);
    double s1 = (double)t1[0] - t0[0], s2 = (double)t2[0] - t0[0];
    double u1 = (double)t1[1] - t0[1], u2 = (double)t2[1] - t0[1];
    double det = s1 * u2 - s2 * u1;
    *orient = (det > 0) - (det < 0);
    if (det == 0)
        return INFINITY;
    double js[3], jt[3];
    for (int k = 0; k < 3; k++) {
        js[k] = (e1[k] * u2 - e2[k] * u1) / det;
        jt[k] = (e2[k] * s1 - e1[k] * s2) / det;
    }
    double a = hlod_dot3(js, js), b = hlod_dot3(js, jt), c = hlod_dot3(jt, jt);
    double tr = a + c, d = sqrt(fmax(0, (a - c) * (a - c) + 4 * b * b));
    double lo = 0.5 * (tr - d), hi = 0.5 * (tr + d);
    return lo > 1e-300 * hi && hi > 0 ? hi / lo : INFINITY;
}

/* The UVs the wedges of a and b get when (a, b) collapses to x (as
 * collapse() will set them), one per wedge group: paired wedges share the
 * merged attribute quadric's optimum, an unpaired one is refitted when its
 * vertex moves. */
static void predicted_uvs(const state *s, uint32_t a, uint32_t b, const double x[3], const wgroup *g,
                          int ng, float (*uv)[2])
{
    int moved = x[0] != s->pos[b][0] || x[1] != s->pos[b][1] || x[2] != s->pos[b][2];
    int a_stays = x[0] == s->pos[a][0] && x[1] == s->pos[a][1] && x[2] == s->pos[a][2];
    for (int i = 0; i < ng; i++) {
        uint32_t w = g[i].w[0];
        memcpy(uv[i], s->wedge_uv[w], sizeof uv[i]);
        if (g[i].n == 2 && g[i].w[0] != g[i].w[1]) {
            if (a_stays) {
                continue; /* wb takes wa's UV */
            } else if (moved) {
                attrq m = s->wedge_aq[w];
                aq_add(&m, &s->wedge_aq[g[i].w[1]]);
                aq_uv(&m, x, uv[i]);
            } else {
                memcpy(uv[i], s->wedge_uv[g[i].w[1]], sizeof uv[i]);
            }
        } else {
            uint32_t owner = s->wedge_pos[w];
            if ((owner == b && moved) || (owner == a && !a_stays))
                aq_uv(&s->wedge_aq[w], x, uv[i]);
        }
    }
}

/* Does the collapse of (a, b) to x keep the texture on the faces off the
 * edge (fa of a, fb of b) unfolded and unstretched?  A face may not flip
 * its UV winding, and its stretch may not pass UV_STRETCH_MAX, or
 * SOURCE_SLACK x the source's worst stretch around its corners where the
 * source itself is stretched (an atlas packed anisotropically in UV units
 * has every face past 4:1), unless it was already past that and grows no
 * worse (within rounding): a long thin face whose UVs do not follow
 * smears the texture along it (slivers at street level). */
#define STRETCH_SLACK2 1.02
#define SOURCE_SLACK 1.25
static int uv_ok(const state *s, uint32_t a, uint32_t b, const double x[3], const eval *e,
                 const uint32_t *fa, size_t na, const uint32_t *fb, size_t nb)
{
    if (!s->wedge_uv || !s->wedge_aq || s->relax >= RELAX_TEXTURE)
        return 1;
    /* the wedge groups evaluate() found for the edge */
    const wgroup *g = e->g;
    int ng = e->ng;
    float puv[MAX_GROUPS][2];
    predicted_uvs(s, a, b, x, g, ng, puv);
    const double lim2 = UV_STRETCH_MAX * UV_STRETCH_MAX;
    for (int side = 0; side < 2; side++) {
        const uint32_t *f = side ? fb : fa;
        size_t nf = side ? nb : na;
        for (size_t i = 0; i < nf; i++) {
            uint32_t t = ENT_T(f[i]);
            int c = ENT_C(f[i]);
            const uint32_t *tv = s->tri_pos + 3 * (size_t)t, *tw = s->tri_wedge + 3 * (size_t)t;
            const double *p[3] = {s->pos[tv[0]], s->pos[tv[1]], s->pos[tv[2]]};
            const float *uv[3] = {s->wedge_uv[tw[0]], s->wedge_uv[tw[1]], s->wedge_uv[tw[2]]};
            const float *moved_uv = uv[c];
            for (int k = 0; k < ng; k++)
                if (g[k].w[0] == tw[c] || (g[k].n == 2 && g[k].w[1] == tw[c])) {
                    moved_uv = puv[k];
                    break;
                }
            const double *pc = p[c];
            const float *uc = uv[c];
            /* the moved corner takes its group's merged reference */
            float ref = fmaxf(s->wedge_sref[tw[(c + 1) % 3]], s->wedge_sref[tw[(c + 2) % 3]]);
            for (int k = 0; k < ng; k++)
                if (g[k].w[0] == tw[c] || (g[k].n == 2 && g[k].w[1] == tw[c]))
                    ref = fmaxf(ref, fmaxf(s->wedge_sref[g[k].w[0]], s->wedge_sref[g[k].w[g[k].n - 1]]));
            double bound2 = fmax(lim2, SOURCE_SLACK * SOURCE_SLACK * (double)ref);
            p[c] = x;
            uv[c] = moved_uv;
            int o0, o1;
            double after = uv_stretch2(p[0], p[1], p[2], uv[0], uv[1], uv[2], &o1);
            /* the UV winding before: only c's UV changes it */
            double det0 = ((double)uv[(c + 1) % 3][0] - uc[0]) * ((double)uv[(c + 2) % 3][1] - uc[1]) -
                          ((double)uv[(c + 2) % 3][0] - uc[0]) * ((double)uv[(c + 1) % 3][1] - uc[1]);
            o0 = (det0 > 0) - (det0 < 0);
            if (o0 && o1 != o0)
                return 0;
            if (after <= bound2)
                continue;
            /* the stretch before, only when it matters */
            p[c] = pc;
            uv[c] = uc;
            double before = uv_stretch2(p[0], p[1], p[2], uv[0], uv[1], uv[2], &o0);
            if (after > STRETCH_SLACK2 * before)
                return 0;
        }
    }
    return 1;
}

/* Link condition: the common neighbours of a and b are exactly the apexes
 * of the edge's faces, and no face of a and face of b share an opposite
 * edge (which would fold the mesh onto itself, e.g. a tetrahedron). */
static int link_ok(state *s, uint32_t b, const uint32_t *fa, size_t na, const uint32_t *fb, size_t nb)
{
    /* the apexes of the faces on edge (a, b): one or two (a slot past the
     * last found one takes the misses' throwaway reads) */
    uint32_t apex[4];
    size_t napex = 0;
    for (size_t i = 0; i < na; i++) {
        const uint32_t *tv = s->tri_pos + 3 * (size_t)ENT_T(fa[i]);
        int cb = corner_of(s, ENT_T(fa[i]), b);
        apex[napex & 3] = tv[cb >= 0 ? 3 - ENT_C(fa[i]) - cb : 0];
        napex += cb >= 0;
    }
    if (!napex || napex > 2)
        return 0;
    /* Stamp b's link vertices, and note whether b has a face on the two
     * apexes (then a face of a on them too would close a tetrahedron).
     * (Without branches, edge faces included: their links hold a and an
     * apex, which the test below never counts, and the corners of a face
     * are a coin toss for the predictor.) */
    uint32_t stamp = new_stamp(s->pos_mark, &s->pos_clock, s->n_pos);
    uint32_t ap0 = apex[0], ap1 = napex == 2 ? apex[1] : apex[0];
    int b_apex_face = 0;
    for (size_t j = 0; j < nb; j++) {
        const uint32_t *tb = s->tri_pos + 3 * (size_t)ENT_T(fb[j]);
        int c1 = NEXT3(ENT_C(fb[j]));
        uint32_t v0 = tb[c1], v1 = tb[NEXT3(c1)];
        s->pos_mark[v0] = s->pos_mark[v1] = stamp;
        b_apex_face |= ((v0 == ap0) & (v1 == ap1)) | ((v0 == ap1) & (v1 == ap0));
    }
    b_apex_face &= napex == 2;
    /* A link vertex of a (off the edge faces, whose links hold b and an
     * apex: b is never stamped, an apex never counts) shared with b must
     * be an apex, and no face of a may close the tetrahedron. */
    int bad = 0;
    for (size_t i = 0; i < na; i++) {
        const uint32_t *ta = s->tri_pos + 3 * (size_t)ENT_T(fa[i]);
        int c1 = NEXT3(ENT_C(fa[i]));
        uint32_t u0 = ta[c1], u1 = ta[NEXT3(c1)];
        bad |= (s->pos_mark[u0] == stamp) & (u0 != ap0) & (u0 != ap1);
        bad |= (s->pos_mark[u1] == stamp) & (u1 != ap0) & (u1 != ap1);
        bad |= b_apex_face & (((u0 == ap0) & (u1 == ap1)) | ((u0 == ap1) & (u1 == ap0)));
    }
    return !bad;
}

/* Everything a collapse of (a, b) must pass, for every placement: returns
 * the index of the cheapest valid plan in *e, -1 if none (or out of
 * memory: s->oom).  Leaves the stars of a and b in s->star_a / s->star_b (*na / *nb). */
static int try_edge(state *s, uint32_t a, uint32_t b, eval *e, size_t *na_, size_t *nb_)
{
    size_t na = star(s, a, 0), nb = star(s, b, 1);
    if (s->oom)
        return -1;
    *na_ = na;
    *nb_ = nb;
    /* Is the edge still there, and is it a feature edge? */
    int nfaces = 0, feature = 0;
    uint32_t wa0 = 0, wb0 = 0, m0 = 0;
    /* (the faces off the edge go to ra and rb for star_ok, without
     * branches: which faces hold the edge is a coin toss) */
    size_t nra = 0, nrb = 0;
    for (size_t k = 0; k < nb; k++) {
        s->off_b[nrb] = s->star_b[k];
        nrb += corner_of(s, ENT_T(s->star_b[k]), a) < 0;
    }
    for (size_t k = 0; k < na; k++) {
        uint32_t t = ENT_T(s->star_a[k]);
        int cb = corner_of(s, ENT_T(s->star_a[k]), b);
        s->off_a[nra] = s->star_a[k];
        nra += cb < 0;
        if (cb < 0)
            continue;
        uint32_t wa = s->wedge_uv ? s->tri_wedge[3 * t + ENT_C(s->star_a[k])] : 0, wb = s->wedge_uv ? s->tri_wedge[3 * t + cb] : 0;
        uint32_t m = s->tri_mat ? s->tri_mat[t] : 0;
        if (nfaces == 0) {
            wa0 = wa;
            wb0 = wb;
            m0 = m;
        } else if (wa != wa0 || wb != wb0 || m != m0) {
            feature = 1;
        }
        nfaces++;
    }
    if (nfaces == 0 || nfaces > 2)
        return -1;
    if (nfaces == 1)
        feature = 1;
    /* The cheapest placement first: it is nearly always valid, and the
     * others are priced only when it is not. */
    evaluate(s, a, b, feature, s->star_a, na, s->star_b, nb, 0, e);
    if (!e->allowed || !link_ok(s, b, s->star_a, na, s->star_b, nb))
        return -1;
    int first = 0;
    for (int k = 1; k < e->ncand; k++)
        if (e->cand[k].cost < e->cand[first].cost)
            first = k;
    if (star_ok(s, a, s->off_a, nra, e->cand[first].x) && star_ok(s, b, s->off_b, nrb, e->cand[first].x) &&
        uv_ok(s, a, b, e->cand[first].x, e, s->off_a, nra, s->off_b, nrb))
        return first;
    evaluate(s, a, b, feature, s->star_a, na, s->star_b, nb, 1, e);
    /* Cheapest valid placement. */
    int order[4] = {0, 1, 2, 3};
    for (int k = 1; k < e->ncand; k++)
        for (int j = k; j > 0 && e->cand[order[j]].cost < e->cand[order[j - 1]].cost; j--) {
            int tmp = order[j];
            order[j] = order[j - 1];
            order[j - 1] = tmp;
        }
    for (int k = 0; k < e->ncand; k++) {
        const plan *pl = &e->cand[order[k]];
        if (star_ok(s, a, s->off_a, nra, pl->x) && star_ok(s, b, s->off_b, nrb, pl->x) &&
            uv_ok(s, a, b, pl->x, e, s->off_a, nra, s->off_b, nrb))
            return order[k];
    }
    return -1;
}

/* ---------- the collapse itself ---------- */

/* Collapses edge (a, b) to position x; b survives. */
static void collapse(state *s, uint32_t a, uint32_t b, const double x[3], const uint32_t *fa, size_t na,
                    const uint32_t *fb, size_t nb, size_t *live_tris, nrec **recs, size_t *rcap)
{
    int moved = x[0] != s->pos[b][0] || x[1] != s->pos[b][1] || x[2] != s->pos[b][2];
    int had_features = !s->verts[a].plain || !s->verts[b].plain;
    /* distinct pvs never share a position, so a_stays implies moved */
    int a_stays = x[0] == s->pos[a][0] && x[1] == s->pos[a][1] && x[2] == s->pos[a][2];
    /* Wedge merges through the edge faces: wa -> wb.  (Untextured, a
     * vertex has one wedge and nothing reads the corners' wedges until
     * the output: untextured_wedges() sets them then.) */
    wgroup g[MAX_GROUPS];
    int ng = s->wedge_uv ? edge_groups(s, b, fa, na, fb, nb, g) : 0;
    uint32_t apex[2];
    int napex = 0;
    for (size_t i = 0; i < na; i++) {
        uint32_t t = ENT_T(fa[i]);
        int cb = corner_of(s, ENT_T(fa[i]), b);
        if (cb >= 0) {
            s->tri_alive[t] = 0;
            (*live_tris)--;
            /* the apex lost a face: its seams may have changed */
            if (had_features) {
                uint32_t x = s->tri_pos[3 * (size_t)t + 3 - ENT_C(fa[i]) - cb];
                s->pos_flag[x] |= VF_STALE;
                if (napex < 2)
                    apex[napex++] = x;
            }
        }
    }
    for (int i = 0; i < ng; i++) {
        if (g[i].n == 2 && g[i].w[0] != g[i].w[1]) {
            uint32_t wa = g[i].w[0], wb = g[i].w[1];
            if (s->wedge_aq) {
                aq_add(&s->wedge_aq[wb], &s->wedge_aq[wa]);
                s->wedge_sref[wb] = fmaxf(s->wedge_sref[wb], s->wedge_sref[wa]);
            }
            /* An endpoint that stays put keeps its exact UV (locked cut
             * boundaries and seams must not drift); a moved one is refit. */
            if (s->wedge_uv && a_stays)
                memcpy(s->wedge_uv[wb], s->wedge_uv[wa], sizeof s->wedge_uv[wb]);
            else if (moved)
                s->wedge_touched[wb] = 1;
            s->wedge_pos[wa] = UINT32_MAX;
            /* (a wedge belongs to one position vertex: only a's corner
             * of a face can hold wa) */
            for (size_t k = 0; k < na; k++) {
                uint32_t t = ENT_T(fa[k]);
                if (!s->tri_alive[t])
                    continue;
                uint32_t *w = &s->tri_wedge[3 * (size_t)t + ENT_C(fa[k])];
                if (*w == wa)
                    *w = wb;
            }
        } else {
            /* An unpaired wedge keeps its UV unless its position moves. */
            uint32_t w = g[i].w[0];
            uint32_t owner = s->wedge_pos[w];
            if ((owner == b && moved) || (owner == a && !a_stays))
                s->wedge_touched[w] = 1;
        }
    }
    /* Move a's corners to b and merge adjacency. */
    uint32_t need = 0;
    for (size_t i = 0; i < na; i++)
        if (s->tri_alive[ENT_T(fa[i])])
            need++;
    for (size_t i = 0; i < nb; i++)
        if (s->tri_alive[ENT_T(fb[i])])
            need++;
    if (!adj_reserve(s, b, need))
        return;
    uint32_t *list = s->pool + s->adj[b].start;
    uint32_t k = 0;
    for (size_t i = 0; i < nb; i++)
        if (s->tri_alive[ENT_T(fb[i])])
            list[k++] = fb[i];
    for (size_t i = 0; i < na; i++) {
        uint32_t t = ENT_T(fa[i]);
        if (!s->tri_alive[t])
            continue;
        int c = ENT_C(fa[i]); /* b takes a's corner: the entry stays */
        s->tri_pos[3 * t + c] = b;
        if (s->wedge_uv)
            s->wedge_pos[s->tri_wedge[3 * t + c]] = b;
        list[k++] = fa[i];
    }
    s->adj[b].count = k;
    s->adj[a].count = 0;
    /* every vertex whose star changed is on a face of b now; after a
     * feature collapse the pass also leaves them alone (see the walk) */
    uint8_t flags = VF_TOUCHED | (had_features ? VF_LOCK : 0);
    for (uint32_t i = 0; i < k; i++) {
        const uint32_t *tv = s->tri_pos + 3 * (size_t)ENT_T(list[i]);
        s->pos_flag[tv[0]] |= flags;
        s->pos_flag[tv[1]] |= flags;
        s->pos_flag[tv[2]] |= flags;
    }
    s->verts[a].alive = 0;
    q_add(&s->verts[b].q, &s->verts[a].q);
    s->verts[b].w += s->verts[a].w;
    if (a_stays) {
        s->verts[b].moved = s->verts[a].moved;
        s->pos_rep[b] = s->pos_rep[a];
    } else if (moved) {
        s->verts[b].moved = 1;
    }
    memcpy(s->pos[b], x, sizeof s->pos[b]);
    s->verts[b].ulock |= s->verts[a].ulock;
    s->verts[b].xlock |= s->verts[a].xlock;
    /* UVs of wedges whose data or position changed. */
    if (s->wedge_aq) {
        for (uint32_t i = 0; i < k; i++) {
            uint32_t w = s->tri_wedge[3 * (size_t)ENT_T(list[i]) + ENT_C(list[i])];
            if (s->wedge_touched[w]) {
                aq_uv(&s->wedge_aq[w], s->pos[b], s->wedge_uv[w]);
                s->wedge_touched[w] = 0;
            }
        }
    }
    /* Feature status of b and the apexes may have changed, unless both
     * endpoints were plain interior vertices: then every merged edge is
     * interior too and nothing around them changes. */
    if (!had_features) {
        s->verts[b].locked = s->verts[b].ulock | s->verts[b].xlock;
        /* (past 32 faces plain_interior() no longer looks: b is classed
         * as a feature-free vertex that is not plain) */
        if (k > 32)
            classify(s, b, recs, rcap);
        return;
    }
    classify(s, b, recs, rcap);
    if (s->oom)
        return;
    /* The rest of the ring keeps its class: a neighbour v of a that is no
     * apex is no neighbour of b (the link test), so its faces from a now
     * name b where they named a, with a's wedge there mapped to one of
     * b's; each of v's edges keeps its faces, wedges and materials, so
     * its feature degree, lock and plainness stay (the self-check
     * verifies every vertex's class each pass).  Only the apexes lose
     * faces. */
    /* An apex lost a face, and with it maybe a seam or two border edges:
     * classify it (it is stale already).  Left alone, spider.obj kept a
     * vertex on a feature line that no longer existed, and it could not
     * move. */
    for (int i = 0; i < napex && !s->oom; i++)
        classify(s, apex[i], recs, rcap);
}

/* ---------- the walk ---------- */

/* The walk takes candidates in price order, all over the mesh, and each
 * first reads its endpoints' records and then their face lists: fetch those
 * for the candidates PREFETCH_FAR and PREFETCH_NEAR ahead (bunny00.off:
 * about 5% faster; the result does not change). */
#define PREFETCH_FAR 16
#define PREFETCH_NEAR 8

static void prefetch_ahead(const state *s, size_t i)
{
    if (i + PREFETCH_FAR < s->n_cand) {
        const cand *c = &s->cand[i + PREFETCH_FAR];
        for (int k = 0; k < 2; k++) {
            uint32_t v = k ? c->b : c->a;
            HLOD_PREFETCH(&s->verts[v]);
            HLOD_PREFETCH((const char *)&s->verts[v] + 64);
            HLOD_PREFETCH(&s->pos[v]);
            HLOD_PREFETCH(&s->adj[v]);
            HLOD_PREFETCH(&s->pos_flag[v]);
        }
    }
    if (i + PREFETCH_NEAR < s->n_cand) {
        const cand *c = &s->cand[i + PREFETCH_NEAR];
        if (!((s->pos_flag[c->a] | s->pos_flag[c->b]) & VF_LOCK)) {
            HLOD_PREFETCH(&s->pool[s->adj[c->a].start]);
            HLOD_PREFETCH(&s->pool[s->adj[c->b].start]);
        }
    }
}

/* ---------- setup ---------- */

typedef struct hentry {
    uint64_t key;
    uint32_t v;
} hentry;

static uint64_t hash_pos(const double *p)
{
    uint64_t h = 0x9E3779B97F4A7C15ull;
    for (int k = 0; k < 3; k++) {
        double d = p[k] == 0 ? 0 : p[k]; /* -0 == +0 */
        uint64_t u;
        memcpy(&u, &d, 8);
        h ^= u + 0x9E3779B97F4A7C15ull + (h << 6) + (h >> 2);
        h *= 0xff51afd7ed558ccdull;
    }
    return h ^ (h >> 33);
}

static uint64_t spread3(uint64_t x)
{
    x &= 0x1fffff;
    x = (x | x << 32) & 0x1f00000000ffffull;
    x = (x | x << 16) & 0x1f0000ff0000ffull;
    x = (x | x << 8) & 0x100f00f00f00f00full;
    x = (x | x << 4) & 0x10c30c30c30c30c3ull;
    x = (x | x << 2) & 0x1249249249249249ull;
    return x;
}

/* Renumbers position vertices along a Morton curve (s->pos_rep, s->wedge_pos):
 * 11 bits per axis, a stable 3-pass radix sort. */
static void spatial_order(state *s, const hlod_mesh *in, const double centre[3], double inv_scale)
{
    size_t nv = s->n_pos;
    uint32_t *code = malloc(nv * sizeof *code * 2), *ord = malloc(nv * sizeof *ord * 2);
    uint32_t *rep = malloc(nv * sizeof *rep);
    if (!code || !ord || !rep) {
        free(code);
        free(ord);
        free(rep);
        s->oom = 1;
        return;
    }
    for (size_t v = 0; v < nv; v++) {
        const double *p = in->positions + 3 * (size_t)s->pos_rep[v];
        uint64_t c = 0;
        for (int a = 0; a < 3; a++) {
            double u = ((p[a] - centre[a]) * inv_scale + 0.5) * 2047.0;
            uint64_t q = u < 0 ? 0 : u > 2047.0 ? 2047 : (uint64_t)u;
            c |= spread3(q) << a;
        }
        code[v] = (uint32_t)(c >> 1); /* 33 bits; the lowest x bit can go */
        ord[v] = (uint32_t)v;
    }
    uint32_t *src = ord, *dst = ord + nv;
    for (int pass = 0; pass < 3; pass++) {
        size_t hist[2048] = {0};
        int shift = pass * 11;
        for (size_t i = 0; i < nv; i++)
            hist[(code[src[i]] >> shift) & 2047]++;
        size_t sum = 0;
        for (int k = 0; k < 2048; k++) {
            size_t h = hist[k];
            hist[k] = sum;
            sum += h;
        }
        for (size_t i = 0; i < nv; i++)
            dst[hist[(code[src[i]] >> shift) & 2047]++] = src[i];
        uint32_t *t = src;
        src = dst;
        dst = t;
    }
    uint32_t *newid = code; /* reuse */
    for (size_t i = 0; i < nv; i++) {
        newid[src[i]] = (uint32_t)i;
        rep[i] = s->pos_rep[src[i]];
    }
    memcpy(s->pos_rep, rep, nv * sizeof *rep);
    for (size_t w = 0; w < s->n_wedges; w++)
        s->wedge_pos[w] = newid[s->wedge_pos[w]];
    free(code);
    free(ord);
    free(rep);
}

/* canon[w] = the first input vertex with w's position and UV. */
static void canonical_wedges(state *s, const hlod_mesh *in, uint32_t *canon)
{
    size_t nw = s->n_wedges, cap = 16;
    while (cap < nw * 2)
        cap *= 2;
    uint32_t *table = malloc(cap * sizeof *table);
    if (!table) {
        s->oom = 1;
        return;
    }
    for (size_t i = 0; i < cap; i++)
        table[i] = UINT32_MAX;
    for (size_t w = 0; w < nw; w++) {
        uint32_t uvb[2] = {0, 0};
        if (in->uvs)
            memcpy(uvb, in->uvs + 2 * w, sizeof uvb);
        uint64_t h = (uint64_t)s->wedge_pos[w] * 0x9E3779B97F4A7C15ull ^ ((uint64_t)uvb[0] << 32 | uvb[1]);
        h ^= h >> 29;
        h *= 0xbf58476d1ce4e5b9ull;
        h ^= h >> 32;
        size_t i = h & (cap - 1);
        for (;;) {
            uint32_t o = table[i];
            if (o == UINT32_MAX) {
                table[i] = (uint32_t)w;
                canon[w] = (uint32_t)w;
                break;
            }
            if (s->wedge_pos[o] == s->wedge_pos[w] &&
                (!in->uvs || !memcmp(in->uvs + 2 * (size_t)o, in->uvs + 2 * w, 2 * sizeof(float)))) {
                canon[w] = o;
                break;
            }
            i = (i + 1) & (cap - 1);
        }
    }
    free(table);
}

static void state_free(state *s)
{
    free(s->part);
    free(s->weld_block);
    free(s->vert_block);
    free(s->attr_block);
    free(s->pool);
    free(s->cand);
    free(s->cand_tmp);
    free(s->requeue.e);
    free(s->parked);
    free(s->star_a);
    free(s->star_b);
    free(s->off_a);
    free(s->off_b);
}

/* Untextured, the walk leaves the corners' wedges alone (collapse()):
 * each live vertex keeps the one wedge it started with, s->pos_wedge. */
static void untextured_wedges(state *s)
{
    for (size_t t = 0; t < s->n_tris; t++)
        if (s->tri_alive[t])
            for (int c = 0; c < 3; c++)
                s->tri_wedge[3 * t + c] = s->pos_wedge[s->tri_pos[3 * t + c]];
}

/* Builds the output mesh from the surviving faces. */
static hlod_result emit(const state *s, const hlod_mesh *in, const double centre[3], double scale,
                        hlod_mesh *out)
{
    size_t nt = 0;
    for (size_t t = 0; t < s->n_tris; t++)
        nt += s->tri_alive[t];
    uint32_t *remap = malloc((s->n_wedges ? s->n_wedges : 1) * sizeof *remap);
    if (!remap)
        return HLOD_ERR_NOMEM;
    for (size_t w = 0; w < s->n_wedges; w++)
        remap[w] = UINT32_MAX;
    for (size_t t = 0; t < s->n_tris; t++)
        if (s->tri_alive[t])
            for (int c = 0; c < 3; c++)
                remap[s->tri_wedge[3 * t + c]] = 0;
    size_t nv = 0;
    for (size_t w = 0; w < s->n_wedges; w++)
        if (remap[w] == 0)
            remap[w] = (uint32_t)nv++;
    unsigned flags = (in->normals ? HLOD_MESH_NORMALS : 0) | (in->uvs ? HLOD_MESH_UVS : 0) |
                     (in->tri_material ? HLOD_MESH_MATERIALS : 0);
    hlod_mesh m = {0};
    hlod_result r = hlod_mesh_alloc(&m, nv, nt, flags);
    if (r != HLOD_OK) {
        free(remap);
        return r;
    }
    for (size_t w = 0; w < s->n_wedges; w++) {
        if (remap[w] == UINT32_MAX)
            continue;
        uint32_t o = remap[w], v = s->wedge_pos[w];
        if (!s->verts[v].moved) {
            memcpy(m.positions + 3 * (size_t)o, in->positions + 3 * (size_t)s->pos_rep[v], 3 * sizeof(double));
        } else {
            for (int k = 0; k < 3; k++)
                m.positions[3 * (size_t)o + k] = s->pos[v][k] * scale + centre[k];
        }
        if (m.uvs) {
            m.uvs[2 * (size_t)o] = s->wedge_uv[w][0];
            m.uvs[2 * (size_t)o + 1] = s->wedge_uv[w][1];
        }
        if (m.normals)
            memset(m.normals + 3 * (size_t)o, 0, 3 * sizeof(float));
    }
    size_t k = 0;
    for (size_t t0 = 0; t0 < s->n_tris; t0++) {
        size_t t = s->tri_slot[t0];
        if (!s->tri_alive[t])
            continue;
        for (int c = 0; c < 3; c++)
            m.indices[3 * k + c] = remap[s->tri_wedge[3 * t + c]];
        if (m.tri_material)
            m.tri_material[k] = in->tri_material[t0];
        k++;
    }
    /* Normals: area-weighted face normals per wedge, so hard edges (split
     * normals) stay hard. */
    if (m.normals && hlod_mesh_vertex_normals(&m, m.normals) != HLOD_OK) {
        free(remap);
        hlod_mesh_free(&m);
        return HLOD_ERR_NOMEM;
    }
    free(remap);
    /* Materials and objects (triangle order is kept, so ranges shrink). */
    uint8_t *kept = in->object_count ? malloc(s->n_tris + 1) : NULL;
    if (kept)
        for (size_t t = 0; t < s->n_tris; t++)
            kept[t] = s->tri_alive[s->tri_slot[t]];
    if ((in->object_count && !kept) || hlod_mesh_copy_tables(&m, in, kept) != HLOD_OK) {
        free(kept);
        hlod_mesh_free(&m);
        return HLOD_ERR_NOMEM;
    }
    free(kept);
    *out = m;
    return HLOD_OK;
}

/* ---------- the phases of hlod_simplify ---------- */

/* One allocation per phase for its fixed-size arrays: a layout function
 * carves 16-byte aligned pieces, once to measure (base NULL) and once for
 * real into one zeroed block. */
typedef struct carver {
    char *base;
    size_t used;
} carver;

static void *carve(carver *c, size_t bytes)
{
    size_t at = (c->used + 15) & ~(size_t)15;
    c->used = at + bytes;
    return c->base ? c->base + at : NULL;
}

static void *phase_block(state *s, void (*layout)(state *, carver *, const hlod_mesh *),
                         const hlod_mesh *in)
{
    carver c = {0};
    layout(s, &c, in);
    void *block = calloc(1, c.used ? c.used : 1);
    if (!block) {
        s->oom = 1;
        return NULL;
    }
    c = (carver){block, 0};
    layout(s, &c, in);
    return block;
}

static void layout_weld(state *s, carver *c, const hlod_mesh *in)
{
    size_t nw = s->n_wedges, nt = s->n_tris;
    s->wedge_pos = carve(c, nw * sizeof *s->wedge_pos);
    s->pos_rep = carve(c, nw * sizeof *s->pos_rep); /* n_pos <= n_wedges */
    s->tri_pos = carve(c, nt * 3 * sizeof *s->tri_pos);
    s->tri_wedge = carve(c, nt * 3 * sizeof *s->tri_wedge);
    s->tri_alive = carve(c, nt);
    s->tri_slot = carve(c, nt * sizeof *s->tri_slot);
    s->tri_mat = in->tri_material ? carve(c, nt * sizeof *s->tri_mat) : NULL;
}

static void layout_verts(state *s, carver *c, const hlod_mesh *in)
{
    (void)in;
    size_t nv = s->n_pos;
    s->verts = carve(c, nv * sizeof *s->verts);
    s->pos = carve(c, nv * sizeof *s->pos);
    s->adj = carve(c, nv * sizeof *s->adj);
    s->pos_flag = carve(c, nv);
    s->pos_mark = carve(c, nv * sizeof *s->pos_mark);
    s->pos_slot = carve(c, nv * sizeof *s->pos_slot);
}

static void layout_attrs(state *s, carver *c, const hlod_mesh *in)
{
    size_t nw = s->n_wedges;
    if (in->uvs) {
        s->wedge_uv = carve(c, nw * sizeof *s->wedge_uv);
        s->wedge_aq = carve(c, nw * sizeof *s->wedge_aq);
        s->wedge_touched = carve(c, nw);
        s->wedge_sref = carve(c, nw * sizeof *s->wedge_sref);
        s->wedge_mark = carve(c, nw * sizeof *s->wedge_mark);
    } else {
        s->pos_wedge = carve(c, s->n_pos * sizeof *s->pos_wedge);
    }
}

static hlod_result check_input(const hlod_mesh *in)
{
    if (!in->tri_count || !in->vertex_count)
        return HLOD_ERR_EMPTY;
    /* (adjacency entries keep a face index in 30 bits, see ENT) */
    if (in->vertex_count >= UINT32_MAX || in->tri_count >= (size_t)1 << 30)
        return HLOD_ERR_INVALID_ARG;
    for (size_t i = 0; i < in->tri_count * 3; i++)
        if (in->indices[i] >= in->vertex_count)
            return HLOD_ERR_INDEX_RANGE;
    for (size_t i = 0; i < in->vertex_count * 3; i++)
        if (!isfinite(in->positions[i]))
            return HLOD_ERR_NAN;
    return HLOD_OK;
}

/* Normalized frame: centre on the bounding box, unit extent.  Dividing by
 * the extent itself (not a power of two near it) makes the normalized
 * coordinates, hence every cost and its queue bucket, the same for a
 * scaled copy of the mesh up to rounding.  Returns the scale. */
static double normalized_frame(const hlod_mesh *in, double centre[3])
{
    double lo[3], hi[3], ext = 0;
    hlod_mesh_bounds(in, lo, hi);
    for (int k = 0; k < 3; k++) {
        centre[k] = 0.5 * (lo[k] + hi[k]);
        if (hi[k] - lo[k] > ext)
            ext = hi[k] - lo[k];
    }
    return ext > 0 ? ext : 1;
}

/* Phase "weld": the input tables, and input vertices at one position
 * become one position vertex (an open-addressing hash). */
static void weld(state *s, const hlod_mesh *in)
{
    s->weld_block = phase_block(s, layout_weld, in);
    if (s->oom)
        return;
    size_t nw = s->n_wedges, tcap = 16;
    while (tcap < nw * 2)
        tcap *= 2;
    hentry *table = malloc(tcap * sizeof *table);
    if (!table) {
        s->oom = 1;
        return;
    }
    for (size_t i = 0; i < tcap; i++)
        table[i].v = UINT32_MAX;
    size_t nv = 0;
    for (size_t w = 0; w < nw; w++) {
        const double *p = in->positions + 3 * w;
        uint64_t h = hash_pos(p);
        size_t i = h & (tcap - 1);
        for (;;) {
            if (table[i].v == UINT32_MAX) {
                table[i].key = h;
                table[i].v = (uint32_t)nv;
                s->pos_rep[nv] = (uint32_t)w;
                s->wedge_pos[w] = (uint32_t)nv++;
                break;
            }
            const double *q = in->positions + 3 * (size_t)s->pos_rep[table[i].v];
            if (table[i].key == h && q[0] == p[0] && q[1] == p[1] && q[2] == p[2]) {
                s->wedge_pos[w] = table[i].v;
                break;
            }
            i = (i + 1) & (tcap - 1);
        }
    }
    free(table);
    s->n_pos = nv;
}

/* Phase "vertices": position vertices numbered in Morton order (inputs
 * often list vertices at random, bunny00.off: neighbours ~9000 indices
 * apart, and every collapse reads its neighbourhood), their records and
 * normalized positions, and the caller's locks. */
static void vertices(state *s, const hlod_mesh *in, const double centre[3], double inv_scale,
                     const hlod_simplify_desc *desc)
{
    spatial_order(s, in, centre, inv_scale);
    if (!s->oom)
        s->vert_block = phase_block(s, layout_verts, in);
    if (s->oom)
        return;
    for (size_t v = 0; v < s->n_pos; v++)
        s->verts[v].alive = 1;
#ifdef HLOD_SELFCHECK
    /* the stamp clocks wrap within the first thousand stamps */
    s->pos_clock = s->wedge_clock = UINT32_MAX - 1000;
#endif
    for (size_t v = 0; v < s->n_pos; v++)
        for (int k = 0; k < 3; k++)
            s->pos[v][k] = (in->positions[3 * (size_t)s->pos_rep[v] + k] - centre[k]) * inv_scale;
    if (desc->vertex_lock)
        for (size_t w = 0; w < s->n_wedges; w++)
            if (desc->vertex_lock[w])
                s->verts[s->wedge_pos[w]].ulock = 1;
}

/* Phase "triangles": corners as wedges (input vertices that share a
 * position and a UV are one wedge, whatever their normals say: normals are
 * recomputed on output, so a flat-shaded mesh does not turn every edge
 * into a seam) and position vertices, triangles in the order of their
 * first corner's vertex; those whose corners weld together die.  Returns
 * the live count and counts each vertex's faces. */
static size_t triangles(state *s, const hlod_mesh *in)
{
    size_t nw = s->n_wedges, nt = s->n_tris, nv = s->n_pos;
    uint32_t *wcanon = malloc(nw * sizeof *wcanon);
    uint32_t *bucket = calloc(nv + 1, sizeof *bucket);
    if (!wcanon || !bucket)
        s->oom = 1;
    else
        canonical_wedges(s, in, wcanon);
    if (s->oom) {
        free(wcanon);
        free(bucket);
        return 0;
    }
    for (size_t t = 0; t < nt; t++)
        bucket[s->wedge_pos[in->indices[3 * t]] + 1]++;
    for (size_t v = 0; v < nv; v++)
        bucket[v + 1] += bucket[v];
    for (size_t t = 0; t < nt; t++)
        s->tri_slot[t] = bucket[s->wedge_pos[in->indices[3 * t]]]++;
    free(bucket);
    for (size_t t0 = 0; t0 < nt; t0++) {
        size_t t = s->tri_slot[t0];
        for (int c = 0; c < 3; c++) {
            s->tri_wedge[3 * t + c] = wcanon[in->indices[3 * t0 + c]];
            s->tri_pos[3 * t + c] = s->wedge_pos[in->indices[3 * t0 + c]];
        }
        if (s->tri_mat)
            s->tri_mat[t] = in->tri_material[t0];
    }
    free(wcanon);
    size_t live = 0;
    for (size_t t = 0; t < nt; t++) {
        const uint32_t *tv = s->tri_pos + 3 * t;
        s->tri_alive[t] = tv[0] != tv[1] && tv[1] != tv[2] && tv[0] != tv[2];
        if (s->tri_alive[t]) {
            live++;
            for (int c = 0; c < 3; c++)
                s->adj[tv[c]].count++;
        }
    }
    return live;
}

/* Phase "adjacency": each position vertex's live faces in the pool. */
static void adjacency(state *s, size_t live)
{
    s->pool_cap = live * 3 + 16;
    s->pool = malloc(s->pool_cap * sizeof *s->pool);
    if (!s->pool) {
        s->oom = 1;
        return;
    }
    for (size_t v = 0; v < s->n_pos; v++) {
        s->adj[v].start = (uint32_t)s->pool_n;
        s->adj[v].cap = s->adj[v].count;
        s->pool_n += s->adj[v].count;
        s->adj[v].count = 0;
    }
    for (size_t t = 0; t < s->n_tris; t++)
        if (s->tri_alive[t])
            for (int c = 0; c < 3; c++) {
                uint32_t v = s->tri_pos[3 * t + c];
                s->pool[s->adj[v].start + s->adj[v].count++] = ENT(t, c);
            }
}

/* Phase "attributes": UVs and their quadrics when textured (wedge groups
 * are formed only then); untextured, each position vertex's one wedge
 * (canonical_wedges() merges by position alone), for untextured_wedges(). */
static void attributes(state *s, const hlod_mesh *in, const hlod_simplify_desc *desc)
{
    s->attr_block = phase_block(s, layout_attrs, in);
    if (s->oom)
        return;
    if (in->uvs) {
        memcpy(s->wedge_uv, in->uvs, s->n_wedges * sizeof *s->wedge_uv);
        s->uv_weight = desc->uv_weight > 0 ? desc->uv_weight : 1.0;
        s->strict_texture = desc->strict_texture != 0;
    } else {
        for (size_t t = 0; t < s->n_tris; t++)
            if (s->tri_alive[t])
                for (int c = 0; c < 3; c++)
                    s->pos_wedge[s->tri_pos[3 * t + c]] = s->tri_wedge[3 * t + c];
    }
}

/* Phase "face quadrics": each face's plane (Garland-Heckbert) into its
 * corners, weighted by area, and when textured the UV as a linear function
 * over the face (Hoppe) into its wedges. */
static void face_quadrics(state *s)
{
    for (size_t t = 0; t < s->n_tris; t++) {
        if (!s->tri_alive[t])
            continue;
        const uint32_t *tv = s->tri_pos + 3 * t;
        const double *p0 = s->pos[tv[0]], *p1 = s->pos[tv[1]], *p2 = s->pos[tv[2]];
        double e1[3], e2[3], n[3];
        hlod_sub3(e1, p1, p0);
        hlod_sub3(e2, p2, p0);
        hlod_cross3(n, e1, e2);
        double l = sqrt(hlod_dot3(n, n));
        if (!(l > 0))
            continue;
        double area = 0.5 * l;
        double un[3] = {n[0] / l, n[1] / l, n[2] / l};
        quadric q = {0};
        q_plane(&q, un, -hlod_dot3(un, p0), area);
        for (int c = 0; c < 3; c++) {
            q_add(&s->verts[tv[c]].q, &q);
            s->verts[tv[c]].w += area;
        }
        if (!s->wedge_aq)
            continue;
        const uint32_t *tw = s->tri_wedge + 3 * t;
        double w = area * s->uv_weight * s->uv_weight;
        double l2 = l * l;
        double e2n[3], ne1[3];
        hlod_cross3(e2n, e2, n);
        hlod_cross3(ne1, n, e1);
        attrq a = {0};
        a.w = w;
        for (int j = 0; j < 2; j++) {
            double s0 = s->wedge_uv[tw[0]][j], s1 = s->wedge_uv[tw[1]][j], s2 = s->wedge_uv[tw[2]][j];
            double g[3];
            for (int k = 0; k < 3; k++)
                g[k] = ((s1 - s0) * e2n[k] + (s2 - s0) * ne1[k]) / l2;
            double d = s0 - hlod_dot3(g, p0);
            for (int k = 0; k < 3; k++)
                a.g[j][k] = w * g[k];
            a.d[j] = w * d;
            q_plane(&a.q, g, d, w);
        }
        for (int c = 0; c < 3; c++)
            aq_add(&s->wedge_aq[tw[c]], &a);
        /* the source's own texture stretch around each corner (uv_ok) */
        int o;
        double st = uv_stretch2(p0, p1, p2, s->wedge_uv[tw[0]], s->wedge_uv[tw[1]], s->wedge_uv[tw[2]], &o);
        if (isfinite(st))
            for (int c = 0; c < 3; c++)
                s->wedge_sref[tw[c]] = fmaxf(s->wedge_sref[tw[c]], (float)st);
    }
}

/* Phase "feature classification": every vertex's feature degree and lock,
 * border locks when asked.  VF_LOCK, cleared before each pass's walk,
 * first flags the feature vertices in a byte each, so feature_planes()
 * reads a small array instead of every corner's pvert.  Returns how many
 * vertices are on features. */
static size_t classify_vertices(state *s, const hlod_simplify_desc *desc, nrec **recs,
                                size_t *rcap)
{
    size_t nfeat = 0;
    memset(s->pos_flag, 0, s->n_pos);
    for (size_t v = 0; v < s->n_pos; v++) {
        if (!s->adj[v].count)
            continue;
        classify(s, (uint32_t)v, recs, rcap);
        if (s->oom)
            return 0;
        if (desc->lock_border) {
            long cnt = neighbours(s, (uint32_t)v, recs, rcap);
            if (s->oom)
                return 0;
            for (long j = 0; j < cnt; j++)
                if ((*recs)[j].faces == 1)
                    s->verts[v].ulock = s->verts[v].locked = 1;
        }
        if (s->verts[v].fdeg) {
            s->pos_flag[v] = VF_LOCK;
            nfeat++;
        }
    }
    return nfeat;
}

/* Is (a, b), corner c of face t, a feature edge (a border, a seam, a
 * material change or a non-manifold edge)?  Looks for the other face. */
static int is_feature_edge(const state *s, size_t t, int c, uint32_t a, uint32_t b)
{
    int feature = 1, found = 0;
    const uint32_t *fl = s->pool + s->adj[a].start;
    for (uint32_t i = 0; i < s->adj[a].count; i++) {
        uint32_t u = ENT_T(fl[i]);
        if (u == t || !s->tri_alive[u])
            continue;
        int ca = ENT_C(fl[i]), cb = corner_of(s, ENT_T(fl[i]), b);
        if (cb < 0)
            continue;
        found++;
        uint32_t wa = s->tri_wedge[3 * t + c], wb = s->tri_wedge[3 * t + (c + 1) % 3];
        int same = s->tri_wedge[3 * u + ca] == wa && s->tri_wedge[3 * u + cb] == wb &&
                   (!s->tri_mat || s->tri_mat[u] == s->tri_mat[t]);
        feature = !same;
    }
    return found > 1 ? 1 : feature;
}

/* Phase "feature planes": a constraint plane through each feature edge,
 * perpendicular to its face, into both ends. */
static void feature_planes(state *s, size_t nfeat)
{
    for (size_t t = 0; t < s->n_tris && nfeat; t++) {
        if (!s->tri_alive[t])
            continue;
        const uint32_t *tv = s->tri_pos + 3 * t;
        /* a feature edge has feature vertices at both ends */
        if ((s->pos_flag[tv[0]] & VF_LOCK) + (s->pos_flag[tv[1]] & VF_LOCK) +
                (s->pos_flag[tv[2]] & VF_LOCK) < 2)
            continue;
        double e1[3], e2[3], n[3];
        hlod_sub3(e1, s->pos[tv[1]], s->pos[tv[0]]);
        hlod_sub3(e2, s->pos[tv[2]], s->pos[tv[0]]);
        hlod_cross3(n, e1, e2);
        double ln = sqrt(hlod_dot3(n, n));
        if (!(ln > 0))
            continue;
        for (int c = 0; c < 3; c++) {
            uint32_t a = tv[c], b = tv[(c + 1) % 3];
            if (!s->verts[a].fdeg || !s->verts[b].fdeg || !is_feature_edge(s, t, c, a, b))
                continue;
            double ed[3], m[3];
            hlod_sub3(ed, s->pos[b], s->pos[a]);
            hlod_cross3(m, ed, n);
            double lm = sqrt(hlod_dot3(m, m));
            if (!(lm > 0))
                continue;
            for (int k = 0; k < 3; k++)
                m[k] /= lm;
            /* Weighted by the edge's length squared, or by twice its
             * face's area when that is larger: a short border edge of a
             * long face must still hold its corner in place (a flat grid
             * graded from 1e-3 to 1e7 otherwise slid a corner along the
             * other border for free and lost half its area). */
            quadric q = {0};
            q_plane(&q, m, -hlod_dot3(m, s->pos[a]), BORDER_WEIGHT * fmax(hlod_dot3(ed, ed), ln));
            q_add(&s->verts[a].q, &q);
            q_add(&s->verts[b].q, &q);
        }
    }
}

/* What the passes carry from one to the next. */
typedef struct run {
    size_t live, target;       /* live triangles, and the goal */
    double err_limit2;         /* squared, normalized units; 0 = none */
    double max_est;            /* the largest squared estimate collapsed */
    size_t collapses;
    int stop;                  /* the error limit was reached */
    int stalled;               /* no valid collapse was left */
    size_t pruned;             /* parts pruned */
    size_t pruned_tris;        /* their triangles */
    double pruned_at;          /* max_est at the last pass's pruning */
} run;

/* Before a pass (not the first): keep last pass's candidates whose ends
 * are not stale, and bring back parked edges with a touched end.
 *
 * A price depends only on its two endpoints (quadrics, positions, locks,
 * feature degrees, wedges) and on the faces of its edge, and a collapse
 * changes those only at the vertices it marks stale (both endpoints;
 * after a feature collapse, the apexes).  So after the first pass only
 * edges with a stale endpoint are re-priced; the others keep last pass's
 * candidate, whose price is still exact (checked by re-pricing every kept
 * one on the benchmark meshes and a city block).  On a city block's late
 * passes, where a pass makes a few hundred collapses among thousands of
 * edges, pricing was most of the time.
 *
 * A refused edge is parked: try_edge reads only the stars of its
 * endpoints (their faces, wedges, positions, quadrics and locks), and
 * every vertex whose star a collapse changes is marked touched.  So it
 * stays refused, and out of the walk, until an endpoint is touched; then
 * it comes back at its kept price, or is re-priced when an endpoint is
 * stale.  (On spider.obj three of four tries were the same refusals, pass
 * after pass.) */
static void refresh_candidates(state *s)
{
    /* (a negative price marks an edge this pass parked) */
    size_t keep = 0;
    for (size_t i = 0; i < s->n_cand; i++)
        if (s->cand[i].cost >= 0 &&
            !((s->pos_flag[s->cand[i].a] | s->pos_flag[s->cand[i].b]) & VF_STALE))
            s->cand[keep++] = s->cand[i];
    s->n_cand = keep;
    size_t still = 0;
    for (size_t i = 0; i < s->n_parked; i++) {
        cand c = s->parked[i];
        if ((s->pos_flag[c.a] | s->pos_flag[c.b]) & VF_STALE)
            continue;
        if ((s->pos_flag[c.a] | s->pos_flag[c.b]) & VF_TOUCHED) {
            cand_push(s, c);
            if (s->oom)
                return;
        } else {
            s->parked[still++] = c;
        }
    }
    s->n_parked = still;
}

/* Prices every edge (first pass) or every edge with a stale end. */
static void price_edges(state *s, int first_pass, nrec **recs, size_t *rcap)
{
    for (size_t v = 0; v < s->n_pos; v++) {
        /* (the stale byte first: later passes then skip most vertices
         * without reading their records) */
        if ((!first_pass && !(s->pos_flag[v] & VF_STALE)) || !s->verts[v].alive || !s->adj[v].count)
            continue;
        long cnt = edges_of(s, (uint32_t)v, recs, rcap);
        for (long j = 0; j < cnt && !s->oom; j++) {
            nrec r = (*recs)[j];
            /* each edge once: from its lower end when both are to be
             * priced, else from the marked one */
            int other_priced = first_pass || (s->pos_flag[r.n] & VF_STALE);
            if ((other_priced && r.n < v) || r.faces > 2)
                continue;
            uint32_t a = (uint32_t)v < r.n ? (uint32_t)v : r.n, b = (uint32_t)v < r.n ? r.n : (uint32_t)v;
            double price;
            if (!price_edge(s, a, b, r.feature, &price))
                continue;
            cand c = {(float)price, a, b};
            cand_push(s, c);
        }
        if (s->oom)
            return;
    }
}

/* Walks the sorted prices up to cost_goal, collapsing the cheapest edges
 * whose endpoints this pass has not touched yet.  A candidate whose
 * cheapest placement is refused (flip, sliver) but has a valid dearer one
 * is re-queued at its true price in a small heap merged into the walk, so
 * a refusal never lets a dearer edge jump the queue.  Returns the pass's
 * collapses. */
static size_t walk_pass(state *s, run *r, float cost_goal, nrec **recs, size_t *rcap)
{
    size_t pass_collapses = 0, i = 0;
    s->requeue.n = 0;
    while (r->live > r->target) {
        cand c;
        int from_heap = s->requeue.n && (i >= s->n_cand || s->requeue.e[0].cost < s->cand[i].cost);
        if (from_heap) {
            c = rheap_pop(&s->requeue);
        } else if (i < s->n_cand) {
            prefetch_ahead(s, i);
            c = s->cand[i++];
        } else {
            break;
        }
        if (c.cost > cost_goal)
            break;
        uint32_t a = c.a, b = c.b;
        /* an endpoint changed in this pass: its price is stale */
        if ((s->pos_flag[a] | s->pos_flag[b]) & VF_LOCK)
            continue;
        size_t na, nb;
        eval e;
        int k = try_edge(s, a, b, &e, &na, &nb);
        if (s->oom)
            break;
        if (k < 0) {
            /* park it (a re-queued one keeps its place in the list: its
             * price there is the pass's, not the re-queued one) */
            if (!from_heap) {
                park(s, c);
                s->cand[i - 1].cost = -1;
            }
            if (s->oom)
                break;
            continue;
        }
        const plan *chosen = &e.cand[k];
        if ((float)chosen->cost > c.cost) {
            cand dearer = {(float)chosen->cost, a, b};
            requeue(s, dearer);
            if (s->oom)
                break;
            continue;
        }
        double est2 = e.w > 0 ? q_eval(&e.qgeo, chosen->x) / e.w : 0;
        if (r->err_limit2 > 0 && est2 > r->err_limit2) {
            r->stop = 1;
            break;
        }
        if (est2 > r->max_est)
            r->max_est = est2;
        double x[3] = {chosen->x[0], chosen->x[1], chosen->x[2]};
        collapse(s, a, b, x, s->star_a, na, s->star_b, nb, &r->live, recs, rcap);
        if (s->oom)
            break;
        r->collapses++;
        /* A pass that found nothing under its bound takes the cheapest
         * valid collapse, then bounds itself by that. */
        if (!pass_collapses++ && cost_goal == FLT_MAX)
            cost_goal = c.cost * PASS_SLACK;
        s->pos_flag[a] |= VF_LOCK | VF_STALE;
        s->pos_flag[b] |= VF_LOCK | VF_STALE;
        /* A feature collapse may reclassify the apexes: collapse() then
         * locked b's whole ring for the rest of the pass.  (Only the apexes
         * are stale: collapse() marked them.  Locking just those let passes
         * run further from the priority order, and fandisk at 1% lost its
         * max-error lead over meshoptimizer.) */
    }
    return pass_collapses;
}

/* ---------- the last resort: parts that cannot shrink further ---------- */

/* A uniform grid over the live vertices, about two a cell (counting sort
 * into cells): built once per prune_parts round, queried by both of its
 * phases. */
typedef struct vgrid {
    double lo[3], h;
    int g;
    uint32_t *start, *list;   /* cell c holds list[start[c] .. start[c + 1]) */
    uint32_t *part;           /* per cell: the one part of its vertices, or UINT32_MAX */
} vgrid;

static void vgrid_free(vgrid *vg)
{
    free(vg->start);
    free(vg->list);
    free(vg->part);
}

/* 0 when out of memory. */
static int vgrid_build(const state *s, const uint32_t *live_v, size_t n, vgrid *vg)
{
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t i = 0; i < n; i++)
        for (int k = 0; k < 3; k++) {
            lo[k] = fmin(lo[k], s->pos[live_v[i]][k]);
            hi[k] = fmax(hi[k], s->pos[live_v[i]][k]);
        }
    double ext = fmax(hi[0] - lo[0], fmax(hi[1] - lo[1], hi[2] - lo[2]));
    int g = (int)ceil(cbrt((double)n / 2));
    g = g < 1 ? 1 : g > 128 ? 128 : g;
    double h = ext > 0 ? ext / g : 1;
    size_t cells = (size_t)g * g * g;
    uint32_t *start = calloc(cells + 1, sizeof *start), *list = malloc((n + 1) * sizeof *list),
             *cell = malloc((n + 1) * sizeof *cell), *part = malloc(cells * sizeof *part);
    if (!start || !list || !cell || !part) {
        free(start);
        free(list);
        free(cell);
        free(part);
        return 0;
    }
    int c3[3];
    for (size_t i = 0; i < n; i++) {
        for (int k = 0; k < 3; k++) {
            int c = (int)((s->pos[live_v[i]][k] - lo[k]) / h);
            c3[k] = c < 0 ? 0 : c >= g ? g - 1 : c;
        }
        cell[i] = (uint32_t)(c3[0] + g * (c3[1] + g * c3[2]));
        start[cell[i] + 1]++;
    }
    for (size_t c = 0; c < cells; c++)
        start[c + 1] += start[c];
    for (size_t i = 0; i < n; i++)
        list[start[cell[i]]++] = (uint32_t)i;
    for (size_t c = cells; c > 0; c--)
        start[c] = start[c - 1];
    start[0] = 0;
    for (size_t c = 0; c < cells; c++) {
        uint32_t p = start[c] < start[c + 1] ? s->part[live_v[list[start[c]]]] : UINT32_MAX;
        for (uint32_t j = start[c] + 1; j < start[c + 1] && p != UINT32_MAX; j++)
            if (s->part[live_v[list[j]]] != p)
                p = UINT32_MAX;
        part[c] = p;
    }
    free(cell);
    memcpy(vg->lo, lo, sizeof lo);
    vg->h = h;
    vg->g = g;
    vg->part = part;
    vg->start = start;
    vg->list = list;
    return 1;
}

/* For every query point q[i] of part qpart[i], the distance to the
 * nearest live vertex (of the grid vg over live_v) of another part
 * (INFINITY when there is none), searched ring by ring until the ring lies
 * farther than the best found, or past limit (farther counts as INFINITY).
 * Queries go in `order`; a part found to cost more than limit is skipped
 * from then on. */
static void other_part_distances(const state *s, const vgrid *vg, const uint32_t *part,
                                 const uint32_t *live_v, const double (*q)[3],
                                 const uint32_t *qpart, size_t nq, double limit, double *dist,
                                 uint32_t *near_part, const uint32_t *order, uint8_t *skip)
{
    const int g = vg->g;
    const double h = vg->h, *lo = vg->lo;
    const uint32_t *start = vg->start, *list = vg->list;
    for (size_t oi = 0; oi < nq; oi++) {
        size_t i = order[oi];
        if (skip[qpart[i]]) { /* not wanted, or a point of it is too far */
            dist[i] = INFINITY;
            near_part[i] = UINT32_MAX;
            continue;
        }
        const double *p = q[i];
        int ci[3];
        for (int k = 0; k < 3; k++) {
            int c = (int)((p[k] - lo[k]) / h);
            ci[k] = c < 0 ? 0 : c >= g ? g - 1 : c;
        }
        double best2 = INFINITY;
        uint32_t best_part = UINT32_MAX;
        for (int ring = 0; ring < g; ring++) {
            /* a ring past the best found cannot hold a nearer vertex */
            double near = (ring - 1) * h;
            if (ring > 0 && near > 0 && (near * near > best2 || near > limit))
                break; /* nothing nearer, or nothing within the limit */
            for (int z = ci[2] - ring; z <= ci[2] + ring; z++)
                for (int y = ci[1] - ring; y <= ci[1] + ring; y++)
                    for (int x = ci[0] - ring; x <= ci[0] + ring; x++) {
                        if (x < 0 || y < 0 || z < 0 || x >= g || y >= g || z >= g)
                            continue;
                        if (abs(x - ci[0]) != ring && abs(y - ci[1]) != ring && abs(z - ci[2]) != ring)
                            continue; /* inside: an earlier ring */
                        size_t c = (size_t)x + (size_t)g * ((size_t)y + (size_t)g * (size_t)z);
                        /* a cell of its own part's vertices alone, or one
                         * no nearer than the best found (its box grown
                         * by a millionth of a cell against rounding),
                         * cannot change the answer */
                        if (start[c] == start[c + 1] || vg->part[c] == qpart[i])
                            continue;
                        const int cc[3] = {x, y, z};
                        double cd2 = 0;
                        for (int k = 0; k < 3; k++) {
                            double a = lo[k] + (cc[k] - 1e-6) * h, b = lo[k] + (cc[k] + 1 + 1e-6) * h;
                            double e = p[k] < a ? a - p[k] : p[k] > b ? p[k] - b : 0;
                            cd2 += e * e;
                        }
                        if (cd2 >= best2)
                            continue;
                        for (uint32_t j = start[c]; j < start[c + 1]; j++) {
                            uint32_t o = list[j];
                            if (part[live_v[o]] == qpart[i])
                                continue;
                            double d[3];
                            hlod_sub3(d, s->pos[live_v[o]], p);
                            double d2 = hlod_dot3(d, d);
                            if (d2 < best2) {
                                best2 = d2;
                                best_part = part[live_v[o]];
                            }
                        }
                    }
        }
        dist[i] = best2 <= limit * limit ? sqrt(best2) : INFINITY;
        near_part[i] = best_part;
        if (!(dist[i] < INFINITY))
            skip[qpart[i]] = 1; /* the part costs more than limit */
    }
}

typedef struct part_cost {
    double cost;       /* normalized units: how far its vertices lie from the rest */
    uint32_t part, tris;
    uint8_t locked;
} part_cost;

static int cmp_part_cost(const void *a, const void *b)
{
    const part_cost *x = a, *y = b;
    if (x->cost != y->cost)
        return x->cost < y->cost ? -1 : 1;
    return (x->part > y->part) - (x->part < y->part);
}

#define UNDERSHOOT 0.98 /* a part may take the count this far under the target */
#define CENTROID_FRAC 0.1 /* centroids nearer a corner than this x the vertex cost are skipped */

/* prune_parts' measurement: each part's cost (pc[].cost) over its
 * vertices (queries [0, n) of q), then over the centroids that could
 * matter (appended to q, *nq grows); parts over limit2 or gone are
 * skipped.  first, by_part: scratch; dist, near: per query.  0 when out of
 * memory. */
static int part_costs(state *s, const uint32_t *live_v, size_t n, double (*q)[3], uint32_t *qpart,
                      size_t *nq, uint32_t *first, uint32_t *by_part, double *dist, uint32_t *near,
                      uint8_t *gone, part_cost *pc, double limit2)
{
    size_t np = s->n_parts;
    vgrid vg;
    if (!vgrid_build(s, live_v, n, &vg))
        return 0;
    for (int phase = 0; phase < 2; phase++) {
        size_t q0 = phase ? n : 0;
        if (phase) {
            for (size_t t = 0; t < s->n_tris; t++) {
                if (!s->tri_alive[t])
                    continue;
                const uint32_t *tv = s->tri_pos + 3 * t;
                uint32_t pt = s->part[tv[0]];
                if (gone[pt])
                    continue;
                double c[3], r2 = INFINITY;
                for (int k = 0; k < 3; k++)
                    c[k] = (s->pos[tv[0]][k] + s->pos[tv[1]][k] + s->pos[tv[2]][k]) / 3;
                for (int j = 0; j < 3; j++) {
                    double d[3];
                    hlod_sub3(d, c, s->pos[tv[j]]);
                    r2 = fmin(r2, hlod_dot3(d, d));
                }
                if (r2 <= CENTROID_FRAC * CENTROID_FRAC * pc[pt].cost * pc[pt].cost)
                    continue;
                memcpy(q[*nq], c, sizeof q[*nq]);
                qpart[(*nq)++] = pt;
            }
        }
        /* this phase's query points, in part order */
        memset(first, 0, (np + 1) * sizeof *first);
        for (size_t i = q0; i < *nq; i++)
            first[qpart[i] + 1]++;
        for (size_t i = 0; i < np; i++)
            first[i + 1] += first[i];
        for (size_t i = q0; i < *nq; i++)
            by_part[first[qpart[i]]++] = (uint32_t)i;
        other_part_distances(s, &vg, s->part, live_v, (const double(*)[3])q, qpart, *nq - q0,
                             sqrt(limit2), dist, near, by_part, gone);
        for (size_t i = q0; i < *nq; i++) {
            part_cost *c = &pc[qpart[i]];
            c->cost = fmax(c->cost, dist[i]);
        }
    }
    vgrid_free(&vg);
    return 1;
}

/* When no collapse is left: whole parts (connected pieces of the surface)
 * go, cheapest first, until the target is met, those costing more than
 * limit2 (squared, normalized) excepted.  Each stall first takes the parts
 * that cost no more than the error already made, before any constraint
 * relaxes; the last stall takes what it must.  A part's cost is the
 * largest distance from one of its vertices or triangle centroids to the
 * nearest vertex of another part (part_costs): what the surface loses when
 * it goes, the limit of Garland-Heckbert's aggregation of a small part into
 * its neighbour.  Parts with a locked vertex stay, as does the last part;
 * the error limit holds. */
/* What prune_parts measured, kept between the calls of one prune_all, where
 * only parts go: a part's cost changes only when a part nearest to one of
 * its query points went (removing vertices never brings one nearer, and a
 * part over the limit stays over it), so only those are measured again.
 * The costs are those a full measurement gives, bit for bit. */
typedef struct part_cache {
    double *cost;           /* per part: its cost when `have` */
    uint8_t *have;          /* measured (not filtered out) in an earlier call */
    uint8_t *removed;       /* taken by an earlier call */
    uint32_t *near_first;   /* per part: its query points' nearest parts ... */
    uint32_t *near;         /* ... near[near_first[p] .. near_first[p + 1]), distinct */
    size_t near_n;
    int valid;              /* a call has filled it */
} part_cache;

static void part_cache_free(part_cache *c)
{
    free(c->cost);
    free(c->have);
    free(c->removed);
    free(c->near_first);
    free(c->near);
    memset(c, 0, sizeof *c);
}

/* Is part p's cached cost still what a measurement would give? */
static int part_clean(const part_cache *c, uint32_t p)
{
    if (!c->valid || !c->have[p])
        return 0;
    for (uint32_t j = c->near_first[p]; j < c->near_first[p + 1]; j++)
        if (c->removed[c->near[j]])
            return 0;
    return 1;
}

/* The cache after a call: measured parts' costs and nearest parts from
 * this call's queries (first, by_part: the queries by part; near: each
 * query's nearest part), clean ones as they were; 0 when out of memory. */
static int part_cache_update(part_cache *c, size_t np, const part_cost *pc, const uint8_t *clean,
                             const uint8_t *filtered, const uint32_t *first,
                             const uint32_t *by_part, const uint32_t *near)
{
    size_t cap = c->near_n + first[np];
    uint32_t *nf = malloc((np + 1) * sizeof *nf), *nl = malloc((cap + 1) * sizeof *nl);
    uint32_t *mark = malloc((np + 1) * sizeof *mark);
    if (!nf || !nl || !mark) {
        free(nf);
        free(nl);
        free(mark);
        return 0;
    }
    size_t n = 0;
    for (size_t p = 0; p < np; p++) {
        nf[p] = (uint32_t)n;
        mark[p] = UINT32_MAX;
        if (clean[p]) {
            for (uint32_t j = c->near_first[p]; j < c->near_first[p + 1]; j++)
                nl[n++] = c->near[j];
            continue;
        }
        c->have[p] = !filtered[p];
        c->cost[p] = pc[p].cost;
        if (filtered[p])
            continue;
        for (uint32_t j = first[p]; j < first[p + 1]; j++) {
            uint32_t q = near[by_part[j]];
            if (q != UINT32_MAX && mark[q] != (uint32_t)p) {
                mark[q] = (uint32_t)p;
                nl[n++] = q;
            }
        }
    }
    nf[np] = (uint32_t)n;
    free(mark);
    free(c->near_first);
    free(c->near);
    c->near_first = nf;
    c->near = nl;
    c->near_n = n;
    c->valid = 1;
    return 1;
}

static size_t prune_parts(state *s, run *r, double limit2, int may_undershoot, part_cache *cache)
{
    if (s->n_parts < 2 || (!r->target && !(r->err_limit2 > 0)))
        return 0; /* one part, or no goal to prune for */
    size_t removed = 0;
    size_t nv = s->n_pos, np = s->n_parts, n = 0, nq = 0, mq = nv + s->n_tris;
    uint32_t *live_v = malloc(nv * sizeof *live_v), *near = malloc(mq * sizeof *near);
    uint32_t *first = calloc(np + 1, sizeof *first), *by_part = malloc(mq * sizeof *by_part);
    uint32_t *qpart = malloc(mq * sizeof *qpart);
    double(*q)[3] = malloc(mq * sizeof *q);
    double *dist = malloc(mq * sizeof *dist);
    part_cost *pc = calloc(np, sizeof *pc);
    uint8_t *gone = calloc(np, 1), *filtered = calloc(np, 1), *clean = calloc(np, 1);
    if (!cache->cost) {
        cache->cost = calloc(np, sizeof *cache->cost);
        cache->have = calloc(np, 1);
        cache->removed = calloc(np, 1);
    }
    if (!live_v || !near || !first || !by_part || !qpart || !q || !dist || !pc || !gone ||
        !filtered || !clean || !cache->cost || !cache->have || !cache->removed) {
        s->oom = 1;
        goto out;
    }
    for (size_t v = 0; v < nv; v++)
        if (s->verts[v].alive && s->adj[v].count)
            live_v[n++] = (uint32_t)v;
    for (size_t i = 0; i < np; i++)
        pc[i].part = (uint32_t)i;
    /* What a part's loss is measured at: its vertices, then the centroids
     * of its triangles that could matter (a big face far from everything
     * else, like a ground plane among buildings, costs what its middle
     * lies from the rest).  A centroid lies within the distance d of a
     * corner's to the rest plus its distance r to that corner, so one whose
     * nearest corner is under CENTROID_FRAC of the part's vertex cost can
     * add little and is not measured. */
    for (size_t i = 0; i < n; i++) {
        memcpy(q[nq], s->pos[live_v[i]], sizeof q[nq]);
        qpart[nq++] = s->part[live_v[i]];
        pc[s->part[live_v[i]]].locked |= s->verts[live_v[i]].ulock;
    }
    for (size_t t = 0; t < s->n_tris; t++)
        if (s->tri_alive[t])
            pc[s->part[s->tri_pos[3 * t]]].tris++;
    /* measure only parts that could go: unlocked, and not so large that
     * they would take the count too far under the target */
    for (size_t i = 0; i < np; i++) {
        filtered[i] = !pc[i].tris || pc[i].locked ||
                      (!may_undershoot &&
                       (double)(r->live - pc[i].tris) < UNDERSHOOT * (double)r->target);
        /* ... and those whose cost the last call's measurement still gives */
        clean[i] = !filtered[i] && part_clean(cache, (uint32_t)i);
        gone[i] = filtered[i] || clean[i];
    }
    if (!part_costs(s, live_v, n, q, qpart, &nq, first, by_part, dist, near, gone, pc, limit2)) {
        s->oom = 1;
        goto out;
    }
    for (size_t i = 0; i < np; i++)
        if (clean[i])
            pc[i].cost = cache->cost[i];
    /* every part's query points, in part order (the stale check below) */
    memset(first, 0, (np + 1) * sizeof *first);
    for (size_t i = 0; i < nq; i++)
        first[qpart[i] + 1]++;
    for (size_t i = 0; i < np; i++)
        first[i + 1] += first[i];
    for (size_t i = 0; i < nq; i++)
        by_part[first[qpart[i]]++] = (uint32_t)i;
    for (size_t i = np; i > 0; i--)
        first[i] = first[i - 1];
    first[0] = 0;
    if (!part_cache_update(cache, np, pc, clean, filtered, first, by_part, near)) {
        s->oom = 1;
        goto out;
    }
    memset(gone, 0, np);
    size_t live_parts = 0;
    for (size_t i = 0; i < np; i++)
        live_parts += pc[i].tris > 0;
    qsort(pc, np, sizeof *pc, cmp_part_cost);
    size_t last = 0;
    for (size_t i = 0; i < np && r->live > r->target && live_parts > 1; i++) {
        double c2 = pc[i].cost * pc[i].cost;
        if (!pc[i].tris || pc[i].locked || !isfinite(c2))
            continue;
        if (c2 > limit2)
            break;
        if (!may_undershoot && (double)(r->live - pc[i].tris) < UNDERSHOOT * (double)r->target)
            continue; /* collapses can still get there more finely (not measured) */
        if (r->err_limit2 > 0 && c2 > r->err_limit2) {
            r->stop = 1;
            break;
        }
        /* its cost was measured to parts that are still there */
        int stale = 0;
        for (uint32_t j = cache->near_first[pc[i].part];
             j < cache->near_first[pc[i].part + 1] && !stale; j++)
            stale = gone[cache->near[j]];
        if (stale)
            break; /* measured again on the next call, before any dearer part */
        gone[pc[i].part] = 1;
        r->live -= pc[i].tris;
        live_parts--;
        last = i + 1;
    }
    /* The last part taken may overshoot the target by far: parts taken
     * before it come back, dearest first, while the target still holds. */
    for (size_t i = last; i-- > 0;)
        if (gone[pc[i].part] && i + 1 < last && r->live + pc[i].tris <= r->target) {
            gone[pc[i].part] = 0;
            r->live += pc[i].tris;
        }
    for (size_t i = 0; i < last; i++)
        if (gone[pc[i].part]) {
            cache->removed[pc[i].part] = 1;
            r->pruned_tris += pc[i].tris;
            r->max_est = fmax(r->max_est, pc[i].cost * pc[i].cost);
            removed++;
        }
    for (size_t t = 0; t < s->n_tris; t++)
        if (s->tri_alive[t] && gone[s->part[s->tri_pos[3 * t]]])
            s->tri_alive[t] = 0;
    for (size_t i = 0; i < n; i++)
        if (gone[s->part[live_v[i]]]) {
            s->verts[live_v[i]].alive = 0;
            s->adj[live_v[i]].count = 0;
            s->pos_flag[live_v[i]] |= VF_STALE; /* their candidates go */
        }
out:
    free(live_v);
    free(near);
    free(first);
    free(by_part);
    free(qpart);
    free(q);
    free(dist);
    free(pc);
    free(gone);
    free(filtered);
    free(clean);
    return removed;
}

/* prune_parts until it takes nothing more (a part measured against one
 * that went is measured again first). */
static void prune_all(state *s, run *r, double limit2, int may_undershoot)
{
    size_t k;
    part_cache cache = {0};
    while (r->live > r->target && !r->stop && !s->oom &&
           (k = prune_parts(s, r, limit2, may_undershoot, &cache)))
        r->pruned += k;
    part_cache_free(&cache);
}

/* Phase "parts": the connected pieces of the surface, numbered 0..n_parts
 * (collapses stay inside a part, so the numbers hold to the end). */
static void find_parts(state *s)
{
    size_t nv = s->n_pos;
    uint32_t *parent = malloc(nv * sizeof *parent);
    s->part = malloc(nv * sizeof *s->part);
    if (!parent || !s->part) {
        free(parent);
        s->oom = 1;
        return;
    }
    for (size_t v = 0; v < nv; v++)
        parent[v] = (uint32_t)v;
    for (size_t t = 0; t < s->n_tris; t++)
        if (s->tri_alive[t]) {
            const uint32_t *tv = s->tri_pos + 3 * t;
            parent[uf_find(parent, tv[0])] = uf_find(parent, tv[1]);
            parent[uf_find(parent, tv[1])] = uf_find(parent, tv[2]);
        }
    for (size_t v = 0; v < nv; v++)
        s->part[v] = UINT32_MAX;
    s->n_parts = 0;
    for (size_t v = 0; v < nv; v++) {
        uint32_t root = uf_find(parent, (uint32_t)v);
        if (!s->adj[root].count && root == v)
            continue; /* an unused vertex */
        if (s->part[root] == UINT32_MAX)
            s->part[root] = (uint32_t)s->n_parts++;
        s->part[v] = s->part[root];
    }
    free(parent);
}

/* No collapse is left: parts that cost no more than the error made so far
 * go first; if the target still is not met, the next constraint relaxes
 * (and every edge is priced anew); past the last, parts go at any cost.
 * Returns 1 when the passes are over. */
static int stall(state *s, run *r)
{
    prune_all(s, r, r->max_est, 0);
    if (s->oom || r->live <= r->target || r->stop)
        return 1;
    if (s->relax == (s->strict_texture ? RELAX_TEXTURE - 1 : RELAX_LAST)) {
        r->stalled = 1;
        prune_all(s, r, INFINITY, 1);
        return 1;
    }
    s->relax++;
    s->n_parked = 0;
    return 0;
}

/* Phase "passes": price, sort, walk, until the target, the error limit,
 * or no valid collapse is left. */
static hlod_result run_passes(state *s, const hlod_simplify_desc *desc, run *r, nrec **recs,
                              size_t *rcap)
{
    const size_t tris_start = r->live;
    int first_pass = 1, unlimited = 0;
    while (r->live > r->target && !r->stop) {
        /* Parts whose loss costs no more than the error already made go
         * as soon as it has been made (Garland-Heckbert's aggregation in
         * cost order): the quadrics would otherwise pay far more to
         * shrink the large parts than the small ones cost whole. */
        if (!first_pass && r->max_est > 2 * r->pruned_at) { /* (each doubling) */
            prune_all(s, r, r->max_est, 0);
            r->pruned_at = r->max_est;
        }
        if (s->oom)
            return HLOD_ERR_NOMEM;
        if (r->live <= r->target)
            break;
        if (first_pass)
            s->n_cand = 0;
        else
            refresh_candidates(s);
        if (!s->oom)
            price_edges(s, first_pass, recs, rcap);
        if (s->oom)
            return HLOD_ERR_NOMEM;
#ifdef HLOD_SELFCHECK
        selfcheck_prices(s, recs, rcap);
#endif
        first_pass = 0;
        if (!s->n_cand) {
            if (stall(s, r))
                break;
            first_pass = 1;
            unlimited = 0;
            continue;
        }
        /* Each interior collapse removes two triangles.  Stop the pass at
         * 1.5x the cost of the collapse that would reach the goal, so a
         * pass never runs far ahead of a strict priority order.  Only the
         * candidates under that bound are sorted (about half): the walk
         * stops at the first one over it, whichever it is, and the next
         * pass sorts afresh. */
        size_t goal = (r->live - r->target) / 2;
        float cost_goal = goal < s->n_cand && !unlimited
                              ? cost_rank(s->cand, s->n_cand, goal) * PASS_SLACK
                              : FLT_MAX;
        size_t nsorted = s->n_cand;
        if (cost_goal < FLT_MAX)
            nsorted = cands_under(s->cand, s->n_cand, cost_goal);
        cand_sort(s, nsorted);
        if (s->oom)
            return HLOD_ERR_NOMEM;
        memset(s->pos_flag, 0, s->n_pos);
        size_t pass_collapses = walk_pass(s, r, cost_goal, recs, rcap);
        if (s->oom)
            return HLOD_ERR_NOMEM;
        /* When every candidate under the bound was refused, retry once
         * without the bound; when that finds nothing either, relax the
         * next constraint and price every edge anew (prices and refusals
         * depend on it); past the last, give up. */
        if (!pass_collapses) {
            if (!unlimited) {
                unlimited = 1;
                continue;
            }
            if (stall(s, r))
                break;
            first_pass = 1;
            unlimited = 0;
            continue;
        }
        unlimited = 0;
        if (desc->progress) {
            size_t target = r->target;
            double total = (double)(tris_start - (target < tris_start ? target : 0));
            if (desc->progress(desc->progress_user, (double)(tris_start - r->live), total))
                return HLOD_ERR_CANCELLED;
        }
    }
    return HLOD_OK;
}

/* Phase "output": the mesh, and the error (certified, not sampled: a
 * sampled maximum misses peaks, by 10% on fandisk at 200k samples). */
static hlod_result output(state *s, const hlod_mesh *in, const hlod_simplify_desc *desc,
                          const double centre[3], double scale, const run *r, double t0,
                          hlod_mesh *out, hlod_simplify_stats *st)
{
    if (!s->wedge_uv)
        untextured_wedges(s);
    hlod_result res = emit(s, in, centre, scale, out);
    st->seconds = hlod_now_s() - t0;
    if (res != HLOD_OK)
        return res;
    st->tris_out = out->tri_count;
    st->vertices_out = out->vertex_count;
    for (size_t v = 0; v < s->n_pos; v++)
        st->locked_vertices += s->verts[v].alive && s->adj[v].count && s->verts[v].ulock;
    if (r->stop)
        st->stop_reason = "error_limit";
    else if (r->stalled && r->live > r->target)
        st->stop_reason = st->locked_vertices ? "locked" : "no_valid_collapse";
    else
        st->stop_reason = "target";
    st->error_estimate = sqrt(r->max_est) * scale;
    st->error = st->error_estimate;
    if (desc->measure_error && out->tri_count) {
        double lower, upper;
        hlod_result hr = hlod_mesh_hausdorff_bound(in, out, 0.01, 1e-9 * hlod_mesh_bbox_diag(in),
                                                   &lower, &upper);
        if (hr == HLOD_OK)
            st->error = upper;
    }
    if (!out->tri_count)
        st->error = hlod_mesh_bbox_diag(in);
    return HLOD_OK;
}

/* One run of the phases; *pruned gets the triangles of the parts pruning
 * took. */
static hlod_result simplify_once(const hlod_mesh *in, const hlod_simplify_desc *desc, hlod_mesh *out,
                                 hlod_simplify_stats *stats, size_t *pruned)
{
    hlod_mesh_free(out);
    hlod_result res = check_input(in);
    if (res != HLOD_OK)
        return res;
    hlod_simplify_stats st = {0};
    st.tris_in = in->tri_count;
    st.vertices_in = in->vertex_count;
    double t0 = hlod_now_s();
    double centre[3];
    double scale = normalized_frame(in, centre), inv_scale = 1 / scale;

    state s = {0};
    s.n_wedges = in->vertex_count;
    s.n_tris = in->tri_count;
    nrec *recs = NULL;
    size_t rcap = 0;
    run r = {0};
    r.target = desc->target_tris;
    if (desc->target_error > 0)
        r.err_limit2 = (desc->target_error * inv_scale) * (desc->target_error * inv_scale);
    weld(&s, in);
    if (!s.oom)
        vertices(&s, in, centre, inv_scale, desc);
    if (!s.oom)
        r.live = triangles(&s, in);
    if (!s.oom)
        adjacency(&s, r.live);
    if (!s.oom)
        attributes(&s, in, desc);
    if (!s.oom)
        find_parts(&s);
    if (!s.oom) {
        face_quadrics(&s);
        size_t nfeat = classify_vertices(&s, desc, &recs, &rcap);
        if (!s.oom)
            feature_planes(&s, nfeat);
    }
    res = s.oom ? HLOD_ERR_NOMEM : run_passes(&s, desc, &r, &recs, &rcap);
    st.collapses = r.collapses;
    *pruned = r.pruned_tris;
    if (res == HLOD_OK)
        res = output(&s, in, desc, centre, scale, &r, t0, out, &st);
    free(recs);
    state_free(&s);
    if (stats)
        *stats = st;
    if (res != HLOD_OK)
        hlod_mesh_free(out);
    return res;
}

/* ---------- the last resort for many parts: vertex clustering ---------- */

#define CLUSTER_GAIN 0.8 /* clustering is kept only this much nearer the input */
#define CLUSTER_WHEN 0.5 /* tried when pruned triangles reach this x the target */
#define CLUSTER_TOL 0.5  /* the bounds compared are within this (relative) */

/* Clusters m to at most `want` triangles, within 10% under it when it can:
 * a surface of area A in cubes of side h makes about 2 A / h^2 triangles
 * to start with, then bisection on h between a side over the count (lo)
 * and one under it (hi), steered by the count measured (it falls about as
 * 1 / h^2). */
static hlod_result cluster_to(const hlod_mesh *m, size_t want, const uint8_t *lock, hlod_mesh *out)
{
    double h = sqrt(2 * hlod_mesh_area(m) / (double)want), lo = 0, hi = INFINITY;
    hlod_result r = HLOD_ERR_INVALID_ARG;
    for (int it = 0; it < 16; it++) {
        r = hlod_cluster_vertices(m, h, lock, out);
        if (r != HLOD_OK)
            return r;
        double ratio = (double)out->tri_count / (double)want;
        if (ratio <= 1 && ratio >= 0.9)
            break;
        if (ratio > 1)
            lo = h;
        else
            hi = h;
        double guess = h * sqrt(ratio > 0.01 ? ratio : 0.01);
        h = isfinite(hi) && lo > 0 ? (guess > lo && guess < hi ? guess : 0.5 * (lo + hi)) : guess;
    }
    if (out->tri_count > want && isfinite(hi))
        r = hlod_cluster_vertices(m, hi, lock, out); /* the last side under the count */
    return r;
}

/* Simplifies in; when part pruning took parts holding at least
 * CLUSTER_WHEN x the target's triangles (the parts, not collapses, made
 * the count: a multi-part model) and nothing forbids it (no UVs:
 * clustering keeps none; no border locks: clustering does not find
 * borders; locked vertices are never welded), the
 * input clustered to the target is made too and kept when it is nearer
 * the input by CLUSTER_GAIN (certified Hausdorff bounds, within 25%; it
 * may hold non-manifold edges where parts welded).  Garland-Heckbert
 * aggregation without virtual pairs: a facade of separate piers becomes
 * one wall, where pruning could only take piers away until whole
 * buildings went (a BIM-like city block of 35,000 triangles to 4000:
 * 17.5 m pruned, 1.0 m clustered).  Clustering to twice the target and
 * then collapsing did worse on every mesh measured (the collapses prune
 * again: 17.5 m on that block). */
hlod_result hlod_simplify(const hlod_mesh *in, const hlod_simplify_desc *desc,
                          hlod_mesh *out, hlod_simplify_stats *stats)
{
    if (!in || !desc || !out || in == out)
        return HLOD_ERR_INVALID_ARG;
    hlod_simplify_stats st = {0};
    size_t pruned = 0;
    hlod_result res = simplify_once(in, desc, out, &st, &pruned);
    if (res != HLOD_OK || !desc->target_tris ||
        (double)pruned < CLUSTER_WHEN * (double)desc->target_tris || in->uvs || desc->lock_border) {
        if (stats)
            *stats = st;
        return res;
    }
    double t0 = hlod_now_s();
    double tol = 1e-3 * hlod_mesh_bbox_diag(in), lower, now = INFINITY, e = INFINITY;
    hlod_mesh alt = {0};
    int keep = 0;
    res = cluster_to(in, desc->target_tris, desc->vertex_lock, &alt);
    if (res == HLOD_OK && alt.tri_count && alt.tri_count <= desc->target_tris)
        res = hlod_mesh_hausdorff_bound(&alt, in, CLUSTER_TOL, tol, &lower, &e);
    if (res == HLOD_OK && e < INFINITY) {
        /* the collapses' bound only as far as the choice needs it: once a
         * point lies farther than e / CLUSTER_GAIN, clustering is kept */
        res = hlod_mesh_hausdorff_bound_above(out, in, CLUSTER_TOL, tol, e / CLUSTER_GAIN,
                                              &lower, &now);
        if (res == HLOD_OK && now == INFINITY && !(e < CLUSTER_GAIN * lower))
            res = hlod_mesh_hausdorff_bound(out, in, CLUSTER_TOL, tol, &lower, &now);
        keep = res == HLOD_OK && (now == INFINITY || e < CLUSTER_GAIN * now);
    }
    if (keep) {
        hlod_mesh_free(out);
        *out = alt;
        memset(&alt, 0, sizeof alt);
        st.tris_out = out->tri_count;
        st.vertices_out = out->vertex_count;
        st.error_estimate = fmax(st.error_estimate, e);
        st.error = e;
        st.stop_reason = "target";
        st.clustered = 1;
        if (desc->measure_error)
            res = hlod_mesh_hausdorff_bound(in, out, 0.01, 1e-9 * hlod_mesh_bbox_diag(in), &lower,
                                            &st.error);
    }
    hlod_mesh_free(&alt);
    st.seconds += hlod_now_s() - t0;
    if (res != HLOD_OK)
        hlod_mesh_free(out);
    if (stats)
        *stats = st;
    return res;
}
