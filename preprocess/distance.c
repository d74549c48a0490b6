/*
 * distance.c - sampled two-sided Hausdorff distance (see distance.h).
 *
 * Design, after Metro (Cignoni, Rocchini, Scopigno, "Metro: measuring error
 * on simplified surfaces", CGF 1998) and MeshLab's Hausdorff filter:
 *
 * - Both meshes are moved into one frame, relative to the centre of their
 *   common bounding box, in double.  A city tile at x = 5e6 m then measures
 *   like the same tile at the origin.
 * - Samples on mesh A: every vertex some triangle uses, the midpoint of every
 *   distinct edge, and N area-proportional stratified points: the cumulative
 *   area is cut into N equal strata and each stratum gets one jittered point,
 *   placed uniformly inside the triangle it falls in (Osada et al. 2002,
 *   eq. 1).  So a triangle receives floor or ceil of N * area / total area
 *   points, never a random clump.  A splitmix64 stream seeded from `seed`
 *   makes the samples reproducible on every platform.
 * - Each sample goes to the exact closest point of B through the grid in
 *   distance_grid.h.  The query is exact, not approximate: it drops a block
 *   of cells only when it is empty or farther than the best triangle found.
 *   Samples are queried in grid-cell order, so each query starts from its
 *   neighbour's answer and reads memory its neighbour just read.
 * - max_ab is over all samples (vertices and edge midpoints are where a
 *   simplifier's error peaks); mean_ab is over the area samples only, so it
 *   is a true surface mean that dense regions do not outweigh.  When A has
 *   no area (every triangle degenerate) the mean falls back to all samples.
 *   The combined mean weights each side by its surface area.
 */
#include "hlod/distance.h"
#include "hlod/vec3.h"
#include "distance_grid.h"

#include <assert.h>
#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Samples per mesh when the caller passes 0 (the header's default). */
#define DEFAULT_SAMPLES 200000

/* Grid sizing (see hlod_dgrid_build): triangles per occupied cell, and a
 * bound on the cells per triangle that keeps the grid O(n) in memory. */
#define TRIS_PER_CELL 2.0
#define MAX_CELLS_PER_TRI 16.0
#define MAX_CELLS (1u << 24)

/* A query starts on the finest pyramid level where the ball around p
 * spans at most MAX_SPAN blocks (3 x 3 x 3; a limit of 8 climbs to coarse
 * levels too soon and measured slower).  The stack then holds the starting
 * blocks plus at most 7 waiting siblings per level. */
#define MAX_SPAN 27
#define SEARCH_STACK (MAX_SPAN + 8 * HLOD_DGRID_MAX_LEVELS)

/* Slack, in cell units, that keeps every floating-point cell decision
 * conservative: a triangle lands in every cell it might touch, and a cell
 * is never judged farther than it is. */
#define CELL_EPS 1e-7

/* aligned_alloc needs a size that is a multiple of the alignment. */
_Static_assert(sizeof(hlod_dgrid_tri) % 64 == 0, "hlod_dgrid_tri must fill whole cache lines");

/* ---- small vector helpers ---------------------------------------------- */

/* min/max without fmin's NaN rules: libm calls otherwise, in the
 * innermost loops (inputs here are finite, checked at the entry points). */
static inline double dmin(double a, double b) { return a < b ? a : b; }
static inline double dmax(double a, double b) { return a > b ? a : b; }

/* ---- splitmix64 (Steele, Lea, Flood, OOPSLA 2014) ----------------------- */

static inline uint64_t splitmix64(uint64_t *s)
{
    uint64_t z = (*s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* Uniform in [0, 1) with 53 random bits. */
static inline double rand01(uint64_t *s)
{
    return (double)(splitmix64(s) >> 11) * (1.0 / 9007199254740992.0);
}

/* ---- point-triangle distance ------------------------------------------- */

static double seg_dist2(const double p[3], const double a[3], const double b[3])
{
    double ab[3], ap[3];
    hlod_sub3(ab, b, a);
    hlod_sub3(ap, p, a);
    double len2 = hlod_dot3(ab, ab), t = 0;
    if (len2 > 0) {
        t = hlod_dot3(ap, ab) / len2;
        t = t < 0 ? 0 : t > 1 ? 1 : t;
    }
    double d[3] = {ap[0] - t * ab[0], ap[1] - t * ab[1], ap[2] - t * ab[2]};
    return hlod_dot3(d, d);
}

/* Ericson, Real-Time Collision Detection, ClosestPtPointTriangle: find the
 * Voronoi region of p by sign tests on dot products, then project.  Used
 * for slivers, where it stays accurate. */
static double ericson_dist2(const double p[3], const hlod_dgrid_tri *t)
{
    const double *a = t->a, *b = t->b, *c = t->c;
    double ab[3], ac[3], ap[3], bp[3], cp[3], q[3];
    hlod_sub3(ab, b, a);
    hlod_sub3(ac, c, a);
    hlod_sub3(ap, p, a);
    double d1 = hlod_dot3(ab, ap), d2 = hlod_dot3(ac, ap);
    if (d1 <= 0 && d2 <= 0) {
        memcpy(q, a, sizeof q);
        goto done;
    }
    hlod_sub3(bp, p, b);
    double d3 = hlod_dot3(ab, bp), d4 = hlod_dot3(ac, bp);
    if (d3 >= 0 && d4 <= d3) {
        memcpy(q, b, sizeof q);
        goto done;
    }
    double vc = d1 * d4 - d3 * d2;
    if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        double v = d1 / (d1 - d3);
        for (int k = 0; k < 3; k++)
            q[k] = a[k] + v * ab[k];
        goto done;
    }
    hlod_sub3(cp, p, c);
    double d5 = hlod_dot3(ab, cp), d6 = hlod_dot3(ac, cp);
    if (d6 >= 0 && d5 <= d6) {
        memcpy(q, c, sizeof q);
        goto done;
    }
    double vb = d5 * d2 - d1 * d6;
    if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        double w = d2 / (d2 - d6);
        for (int k = 0; k < 3; k++)
            q[k] = a[k] + w * ac[k];
        goto done;
    }
    double va = d3 * d6 - d5 * d4;
    if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        for (int k = 0; k < 3; k++)
            q[k] = b[k] + w * (c[k] - b[k]);
        goto done;
    }
    {
        /* va + vb + vc = |ab x ac|^2 > 0: the triangle is not degenerate. */
        double denom = 1.0 / (va + vb + vc);
        double v = vb * denom, w = vc * denom;
        for (int k = 0; k < 3; k++)
            q[k] = a[k] + ab[k] * v + ac[k] * w;
    }
done:;
    double d[3];
    hlod_sub3(d, p, q);
    return hlod_dot3(d, d);
}

double hlod_dgrid_tri_dist2(const double p[3], const hlod_dgrid_tri *t)
{
    if (t->n[0] == 0 && t->n[1] == 0 && t->n[2] == 0) {
        double d0 = seg_dist2(p, t->a, t->b);
        double d1 = seg_dist2(p, t->b, t->c);
        double d2 = seg_dist2(p, t->c, t->a);
        return dmin(d0, dmin(d1, d2));
    }
    if (t->inv_det == 0)
        return ericson_dist2(p, t);
    /* Barycentric coordinates of p's projection from the precomputed
     * inverse Gram matrix.  Inside: the distance is the plane distance.
     * Outside: the closest point lies on an edge whose line has the
     * projection on its far side (a point in a vertex's Voronoi region is
     * beyond one of that vertex's edges, by Cauchy-Schwarz), so only the
     * edges with a negative coordinate need measuring. */
    double e1[3], e2[3], ap[3];
    hlod_sub3(e1, t->b, t->a);
    hlod_sub3(e2, t->c, t->a);
    hlod_sub3(ap, p, t->a);
    double d1 = hlod_dot3(e1, ap), d2 = hlod_dot3(e2, ap);
    double v = (t->g11 * d1 - t->g01 * d2) * t->inv_det;
    double w = (t->g00 * d2 - t->g01 * d1) * t->inv_det;
    if (v >= 0 && w >= 0 && v + w <= 1) {
        double s = hlod_dot3(t->n, ap);
        return s * s;
    }
    double best = DBL_MAX;
    if (w < 0)
        best = seg_dist2(p, t->a, t->b);
    if (v < 0)
        best = dmin(best, seg_dist2(p, t->a, t->c));
    if (v + w > 1)
        best = dmin(best, seg_dist2(p, t->b, t->c));
    return best;
}

/* ---- grid ------------------------------------------------------------- */

static double cells_for(const double ext[3], double h)
{
    double n = 1;
    for (int k = 0; k < 3; k++)
        n *= dmax(1.0, ceil(ext[k] / h));
    return n;
}

/* floor(x) clamped to [0, top].  Clamping first lets a cast do the floor
 * (x >= 0), which is much cheaper than libm's floor() without SSE4.1. */
static inline int clamp_cell(double x, int top)
{
    if (!(x > 0))
        return 0;
    if (x >= top)
        return top;
    return (int)x;
}

/* Cell range [*i0, *i1] along axis k covering [vmin, vmax], widened by
 * CELL_EPS so rounding never drops a cell the interval touches. */
static inline void cell_range(const hlod_dgrid *g, int k, double vmin, double vmax, int *i0,
                              int *i1)
{
    *i0 = clamp_cell((vmin - g->lo[k]) * g->inv_h - CELL_EPS, g->n[k] - 1);
    *i1 = clamp_cell((vmax - g->lo[k]) * g->inv_h + CELL_EPS, g->n[k] - 1);
}

/* Linear index of the cell holding p, clamped into the grid. */
static inline size_t cell_of(const hlod_dgrid *g, const double p[3])
{
    size_t c[3];
    for (int k = 0; k < 3; k++)
        c[k] = (size_t)clamp_cell((p[k] - g->lo[k]) * g->inv_h, g->n[k] - 1);
    return c[0] + (size_t)g->n[0] * (c[1] + (size_t)g->n[1] * c[2]);
}

/* Does triangle t's plane cross cell (x, y, z)?  The plane-box test of
 * Akenine-Moller's triangle-box overlap, with slack so it never says no
 * to a cell the triangle touches.  Degenerate triangles (zero normal)
 * always pass. */
static int plane_hits_cell(const hlod_dgrid *g, const hlod_dgrid_tri *t, int x, int y, int z)
{
    double half = 0.5 * g->h;
    double c[3] = {g->lo[0] + (x + 0.5) * g->h - t->a[0], g->lo[1] + (y + 0.5) * g->h - t->a[1],
                   g->lo[2] + (z + 0.5) * g->h - t->a[2]};
    double r = half * (fabs(t->n[0]) + fabs(t->n[1]) + fabs(t->n[2]));
    return fabs(hlod_dot3(t->n, c)) <= r + CELL_EPS * g->h * 4;
}

/* Visits the cells triangle t may touch: counts them (fill == NULL) or
 * appends t's index to each (fill = per-cell cursors). */
static size_t insert_tri(hlod_dgrid *g, uint32_t ti, uint32_t *fill)
{
    const hlod_dgrid_tri *t = &g->tris[ti];
    int r0[3], r1[3];
    for (int k = 0; k < 3; k++) {
        double vmin = dmin(t->a[k], dmin(t->b[k], t->c[k]));
        double vmax = dmax(t->a[k], dmax(t->b[k], t->c[k]));
        cell_range(g, k, vmin, vmax, &r0[k], &r1[k]);
    }
    int single = r0[0] == r1[0] && r0[1] == r1[1] && r0[2] == r1[2];
    size_t count = 0;
    for (int z = r0[2]; z <= r1[2]; z++)
        for (int y = r0[1]; y <= r1[1]; y++)
            for (int x = r0[0]; x <= r1[0]; x++) {
                if (!single && !plane_hits_cell(g, t, x, y, z))
                    continue;
                size_t cell = (size_t)x + (size_t)g->n[0] * ((size_t)y + (size_t)g->n[1] * z);
                if (fill)
                    g->cell_tris[fill[cell]++] = ti;
                else
                    g->cell_start[cell + 1]++;
                count++;
            }
    return count;
}

void hlod_dgrid_free(hlod_dgrid *g)
{
    if (!g)
        return;
    free(g->cell_start);
    free(g->cell_tris);
    free(g->tris);
    free(g->box);
    free(g->stamp);
    free(g->occupied);
    memset(g, 0, sizeof *g);
}

/* The triangles relative to origin, with their normals and Gram
 * matrices; lo/hi get their bounds. */
/* t's bounding box in floats, rounded outwards: never nearer to a point
 * than the box in doubles, so a test against it rejects no triangle the
 * exact box would keep. */
static void tri_box(const hlod_dgrid_tri *t, float out[6])
{
    for (int k = 0; k < 3; k++) {
        double lo = dmin(t->a[k], dmin(t->b[k], t->c[k])), hi = dmax(t->a[k], dmax(t->b[k], t->c[k]));
        float fl = (float)lo, fh = (float)hi;
        if ((double)fl > lo)
            fl = nextafterf(fl, -INFINITY);
        if ((double)fh < hi)
            fh = nextafterf(fh, INFINITY);
        out[k] = fl;
        out[3 + k] = fh;
    }
}

static void prepare_tris(hlod_dgrid_tri *raw, const double *positions, const uint32_t *indices,
                         size_t tri_count, const double origin[3], double lo[3], double hi[3])
{
    for (int k = 0; k < 3; k++) {
        lo[k] = DBL_MAX;
        hi[k] = -DBL_MAX;
    }
    for (size_t i = 0; i < tri_count; i++) {
        hlod_dgrid_tri *t = &raw[i];
        double *dst[3] = {t->a, t->b, t->c};
        for (int j = 0; j < 3; j++) {
            const double *v = positions + 3 * (size_t)indices[3 * i + j];
            for (int k = 0; k < 3; k++) {
                dst[j][k] = v[k] - origin[k];
                lo[k] = dmin(lo[k], dst[j][k]);
                hi[k] = dmax(hi[k], dst[j][k]);
            }
        }
        double ab[3], ac[3], n[3];
        hlod_sub3(ab, t->b, t->a);
        hlod_sub3(ac, t->c, t->a);
        hlod_cross3(n, ab, ac);
        double n2 = hlod_dot3(n, n);
        /* sin^2 of the corner angle below 1e-20: the triangle is a segment
         * for all purposes, and Ericson's face-region division would
         * divide by (almost) zero.  A zero normal marks it. */
        double g00 = hlod_dot3(ab, ab), g01 = hlod_dot3(ab, ac), g11 = hlod_dot3(ac, ac);
        int degenerate = !(n2 > 1e-20 * g00 * g11);
        double inv = degenerate ? 0 : 1.0 / sqrt(n2);
        for (int k = 0; k < 3; k++)
            t->n[k] = n[k] * inv;
        /* Barycentric coordinates lose about eps / sin^2(angle) to
         * rounding: below an angle of 0.01 rad, leave slivers to Ericson's
         * sign tests (inv_det = 0). */
        double det = g00 * g11 - g01 * g01;
        t->g00 = g00;
        t->g01 = g01;
        t->g11 = g11;
        t->inv_det = n2 > 1e-4 * g00 * g11 && det > 0 ? 1.0 / det : 0;
    }
}

/* The cell size, and the grid's corner and cell counts. */
static void choose_cells(hlod_dgrid *g, const hlod_dgrid_tri *raw, size_t tri_count,
                         const double lo[3], const double hi[3])
{
    /* Cubic cells sized to the surface, not the box: a plane of area A
     * crosses about 1.5 A / h^2 cells (the mean of |nx| + |ny| + |nz|), so
     * this h gives about one occupied cell per TRIS_PER_CELL triangles.  A
     * triangle then overlaps ~4 cells, so an occupied cell lists ~8.  On
     * the CGAL meshes, 1 to 4 measured within noise of each other; 2 keeps
     * the grid small.  A surface spread thinly through its box would need
     * too many empty cells: MAX_CELLS_PER_TRI bounds the grid, found by
     * bisection (the count is monotone in h; flat meshes make a closed
     * form awkward). */
    double ext[3], diag2 = 0, area = 0;
    for (int k = 0; k < 3; k++) {
        ext[k] = hi[k] - lo[k];
        diag2 += ext[k] * ext[k];
    }
    for (size_t i = 0; i < tri_count; i++) {
        double ab[3], ac[3], n[3];
        hlod_sub3(ab, raw[i].b, raw[i].a);
        hlod_sub3(ac, raw[i].c, raw[i].a);
        hlod_cross3(n, ab, ac);
        area += 0.5 * sqrt(hlod_dot3(n, n));
    }
    double h = sqrt(1.5 * TRIS_PER_CELL * area / (double)tri_count);
    double target = dmin(MAX_CELLS_PER_TRI * (double)tri_count + 1.0, (double)MAX_CELLS);
    double h_hi = sqrt(diag2);
    if (!(h_hi > 0)) {
        h = 1.0;    /* every corner at one point: one cell */
    } else if (!(h > 0) || cells_for(ext, h) > target) {
        double h_lo = h > 0 ? h : 0;
        for (int it = 0; it < 64; it++) {
            double mid = 0.5 * (h_lo + h_hi);
            if (cells_for(ext, mid) <= target)
                h_hi = mid;
            else
                h_lo = mid;
        }
        h = h_hi;
    }
    g->h = h;
    g->inv_h = 1.0 / h;
    for (int k = 0; k < 3; k++) {
        g->lo[k] = lo[k];
        g->n[k] = (int)dmax(1.0, ceil(ext[k] / h));
    }
}

/* The occupancy pyramid over the filled cells; 0 when out of memory. */
static int build_pyramid(hlod_dgrid *g, size_t cells)
{
    /* Occupancy pyramid: level l has blocks of 2^l cells a side, the top
     * level a single block; a byte says whether any cell below holds a
     * triangle.  About 1/7 byte per cell on top of level 0. */
    size_t bytes = 0;
    int l = 0;
    for (;; l++) {
        assert(l < HLOD_DGRID_MAX_LEVELS);
        size_t count = 1;
        for (int k = 0; k < 3; k++) {
            g->level_n[l][k] = (int)(((size_t)g->n[k] + ((size_t)1 << l) - 1) >> l);
            count *= (size_t)g->level_n[l][k];
        }
        g->level_first[l] = bytes;
        bytes += count;
        if (count == 1)
            break;
    }
    g->levels = l + 1;
    g->occupied = calloc(bytes, 1);
    if (!g->occupied)
        return 0;
    for (size_t c = 0; c < cells; c++)
        g->occupied[c] = g->cell_start[c + 1] > g->cell_start[c];
    for (l = 1; l < g->levels; l++) {
        const int *cn = g->level_n[l - 1], *pn = g->level_n[l];
        const uint8_t *child = g->occupied + g->level_first[l - 1];
        uint8_t *parent = g->occupied + g->level_first[l];
        for (int z = 0; z < cn[2]; z++)
            for (int y = 0; y < cn[1]; y++)
                for (int x = 0; x < cn[0]; x++)
                    if (child[(size_t)x + (size_t)cn[0] * ((size_t)y + (size_t)cn[1] * z)])
                        parent[(size_t)(x >> 1) + (size_t)pn[0] * ((size_t)(y >> 1) + (size_t)pn[1] * (z >> 1))] = 1;
    }
    return 1;
}

hlod_result hlod_dgrid_build(hlod_dgrid *g, const double *positions, const uint32_t *indices,
                             size_t tri_count, const double origin[3])
{
    assert(g && positions && indices && origin);
    memset(g, 0, sizeof *g);
    if (!tri_count)
        return HLOD_ERR_EMPTY;
    if (tri_count >= UINT32_MAX)
        return HLOD_ERR_INVALID_ARG;
    g->tri_count = tri_count;
    hlod_dgrid_tri *raw = malloc(tri_count * sizeof *raw);
    uint32_t *key = malloc(tri_count * sizeof *key);
    g->tris = aligned_alloc(64, tri_count * sizeof *g->tris);
    g->stamp = calloc(tri_count, sizeof *g->stamp);
    if (!raw || !key || !g->tris || !g->stamp)
        goto nomem;

    double lo[3], hi[3];
    prepare_tris(raw, positions, indices, tri_count, origin, lo, hi);

    choose_cells(g, raw, tri_count, lo, hi);

    size_t cells = (size_t)g->n[0] * (size_t)g->n[1] * (size_t)g->n[2];
    g->cell_start = calloc(cells + 1, sizeof *g->cell_start);
    uint32_t *fill = malloc(cells * sizeof *fill);
    if (!g->cell_start || !fill)
        goto nomem_fill;

    /* Store triangles in cell order of their centroids (a counting sort):
     * a query then reads neighbouring triangles from neighbouring memory,
     * whatever order the file had them in. */
    for (size_t i = 0; i < tri_count; i++) {
        double c[3];
        for (int k = 0; k < 3; k++)
            c[k] = (raw[i].a[k] + raw[i].b[k] + raw[i].c[k]) * (1.0 / 3.0);
        key[i] = (uint32_t)cell_of(g, c);
        g->cell_start[key[i] + 1]++;
    }
    for (size_t c = 0; c < cells; c++)
        g->cell_start[c + 1] += g->cell_start[c];
    for (size_t i = 0; i < tri_count; i++)
        g->tris[g->cell_start[key[i]]++] = raw[i];
    free(raw);
    free(key);
    raw = NULL;
    key = NULL;
    memset(g->cell_start, 0, (cells + 1) * sizeof *g->cell_start);
    if (!(g->box = malloc(tri_count * sizeof *g->box)))
        goto nomem_fill;
    for (size_t i = 0; i < tri_count; i++)
        tri_box(&g->tris[i], g->box[i]);

    /* Two passes, count then fill: a CSR layout with no per-cell allocation. */
    size_t total = 0;
    for (size_t i = 0; i < tri_count; i++)
        total += insert_tri(g, (uint32_t)i, NULL);
    if (total >= UINT32_MAX)
        goto nomem_fill;
    for (size_t c = 0; c < cells; c++)
        g->cell_start[c + 1] += g->cell_start[c];
    memcpy(fill, g->cell_start, cells * sizeof *fill);
    g->cell_tris = malloc((total ? total : 1) * sizeof *g->cell_tris);
    if (!g->cell_tris)
        goto nomem_fill;
    for (size_t i = 0; i < tri_count; i++)
        insert_tri(g, (uint32_t)i, fill);
    free(fill);
    fill = NULL;

    if (!build_pyramid(g, cells))
        goto nomem_fill;
    return HLOD_OK;

nomem_fill:
    free(fill);
nomem:
    free(raw);
    free(key);
    hlod_dgrid_free(g);
    return HLOD_ERR_NOMEM;
}

/* Squared distance from p to block (x, y, z) of pyramid level l (2^l cells
 * on a side), the block grown by CELL_EPS cells so the value never exceeds
 * the true distance. */
static inline double block_dist2(const hlod_dgrid *g, const double p[3], int l, const int c[3])
{
    double side = (double)(1u << l), d2 = 0;
    for (int k = 0; k < 3; k++) {
        double lo = g->lo[k] + (c[k] * side - CELL_EPS) * g->h;
        double hi = g->lo[k] + ((c[k] + 1) * side + CELL_EPS) * g->h;
        double d = p[k] < lo ? lo - p[k] : p[k] > hi ? p[k] - hi : 0;
        d2 += d * d;
    }
    return d2;
}

static inline int block_occupied(const hlod_dgrid *g, int l, const int c[3])
{
    const int *n = g->level_n[l];
    return g->occupied[g->level_first[l] + (size_t)c[0] + (size_t)n[0] * ((size_t)c[1] + (size_t)n[1] * c[2])];
}

static inline void test_cell(hlod_dgrid *g, const double p[3], size_t cell, double *best2,
                             uint32_t *best)
{
    for (uint32_t i = g->cell_start[cell], e = g->cell_start[cell + 1]; i < e; i++) {
        uint32_t ti = g->cell_tris[i];
        if (g->stamp[ti] == g->query)
            continue;
        g->stamp[ti] = g->query;
        const hlod_dgrid_tri *t = &g->tris[ti];
        /* The distance to the plane bounds the distance to the triangle.
         * The 1e-12 margin covers rounding, so a triangle is skipped only
         * when its computed distance could not win either. */
        double ap[3];
        hlod_sub3(ap, p, t->a);
        double s = hlod_dot3(t->n, ap);
        if (s * s > *best2 * (1 + 1e-12))
            continue;
        /* So does the distance to its bounding box: it rejects the
         * coplanar neighbours on a facade, where the plane test cannot. */
        const float *bx = g->box[ti];
        double box2 = 0;
        for (int k = 0; k < 3; k++) {
            double lo = bx[k], hi = bx[3 + k];
            double e = p[k] < lo ? lo - p[k] : p[k] > hi ? p[k] - hi : 0;
            box2 += e * e;
        }
        if (box2 > *best2 * (1 + 1e-12))
            continue;
        double d2 = hlod_dgrid_tri_dist2(p, t);
        if (d2 < *best2) {
            *best2 = d2;
            *best = ti;
        }
    }
}

/* A block waiting on the search stack. */
typedef struct pending {
    double d2;
    int l, c[3];
} pending;

/* Pushes list[0..n) onto stack so that the nearest is popped first. */
static int push_sorted(pending *stack, int top, pending *list, int n)
{
    for (int i = 1; i < n; i++) {
        pending e = list[i];
        int j = i;
        for (; j > 0 && list[j - 1].d2 < e.d2; j--)
            list[j] = list[j - 1];
        list[j] = e;
    }
    assert(top + n <= SEARCH_STACK);
    for (int i = 0; i < n; i++)
        stack[top++] = list[i];
    return top;
}

double hlod_dgrid_closest2(hlod_dgrid *g, const double p[3], uint32_t *tri)
{
    assert(g && g->tri_count && p);
    if (++g->query == 0) {
        memset(g->stamp, 0, g->tri_count * sizeof *g->stamp);
        g->query = 1;
    }
    /* The previous query's answer is usually near this one (samples come
     * in cell order): its distance is a tight first bound, and only blocks
     * nearer than the bound are ever opened. */
    uint32_t best = g->hint < g->tri_count ? g->hint : 0;
    double best2 = hlod_dgrid_tri_dist2(p, &g->tris[best]);
    g->stamp[best] = g->query;

    /* The cell holding p first: it usually holds the answer, and the
     * tighter bound shrinks the search below to a few blocks. */
    size_t home = cell_of(g, p);
    test_cell(g, p, home, &best2, &best);

    /* Branch and bound over the occupancy pyramid: start on the finest
     * level where at most MAX_SPAN blocks cover the ball around p, open
     * occupied blocks nearest first, and drop every block farther than the
     * best triangle so far.  A block is skipped only when empty or provably
     * too far, so the result is exact; near queries stay on level 0 and
     * read a handful of cells, far ones skip empty space a block at a time. */
    double d = sqrt(best2);
    int l = 0, r0[3], r1[3], span;
    for (;;) {
        span = 1;
        for (int k = 0; k < 3; k++) {
            int a0, a1;
            cell_range(g, k, p[k] - d, p[k] + d, &a0, &a1);
            r0[k] = a0 >> l;
            r1[k] = a1 >> l;
            span *= r1[k] - r0[k] + 1;
        }
        if (span <= MAX_SPAN || l + 1 >= g->levels)
            break;
        l++;
    }
    pending stack[SEARCH_STACK], list[MAX_SPAN];
    int top = 0, n = 0, c[3];
    for (c[2] = r0[2]; c[2] <= r1[2]; c[2]++)
        for (c[1] = r0[1]; c[1] <= r1[1]; c[1]++)
            for (c[0] = r0[0]; c[0] <= r1[0]; c[0]++) {
                if (!block_occupied(g, l, c))
                    continue;
                double d2 = block_dist2(g, p, l, c);
                if (d2 < best2) {
                    assert(n < MAX_SPAN);
                    list[n++] = (pending){d2, l, {c[0], c[1], c[2]}};
                }
            }
    top = push_sorted(stack, top, list, n);
    while (top > 0) {
        pending e = stack[--top];
        if (e.d2 >= best2)
            continue;
        if (e.l == 0) {
            const int *gn = g->level_n[0];
            size_t cell = (size_t)e.c[0] + (size_t)gn[0] * ((size_t)e.c[1] + (size_t)gn[1] * e.c[2]);
            if (cell != home)
                test_cell(g, p, cell, &best2, &best);
            continue;
        }
        int cl = e.l - 1;
        const int *cn = g->level_n[cl];
        n = 0;
        for (int i = 0; i < 8; i++) {
            c[0] = 2 * e.c[0] + (i & 1);
            c[1] = 2 * e.c[1] + ((i >> 1) & 1);
            c[2] = 2 * e.c[2] + (i >> 2);
            if (c[0] >= cn[0] || c[1] >= cn[1] || c[2] >= cn[2] || !block_occupied(g, cl, c))
                continue;
            double d2 = block_dist2(g, p, cl, c);
            if (d2 < best2)
                list[n++] = (pending){d2, cl, {c[0], c[1], c[2]}};
        }
        top = push_sorted(stack, top, list, n);
    }
    g->hint = best;
    if (tri)
        *tri = best;
    return best2;
}

/* ---- sampling --------------------------------------------------------- */

typedef struct side {
    double max, sum_area, sum_all;
    size_t n_area, n_all;
} side;

/* A growable list of sample points (relative coordinates). */
typedef struct points {
    double *p;
    size_t n, cap;
} points;

static int push_point(points *l, double x, double y, double z)
{
    if (l->n == l->cap) {
        size_t cap = l->cap ? 2 * l->cap : 4096;
        double *p = realloc(l->p, cap * 3 * sizeof *p);
        if (!p)
            return 0;
        l->p = p;
        l->cap = cap;
    }
    double *d = l->p + 3 * l->n++;
    d[0] = x;
    d[1] = y;
    d[2] = z;
    return 1;
}

/* Every vertex some triangle uses (a stray vertex is not on the surface)
 * and the midpoint of each distinct edge: edges are bucketed by their lower
 * vertex (a counting sort), and repeats dropped inside each small bucket. */
static hlod_result vertex_edge_samples(const hlod_mesh *m, const double origin[3], points *out)
{
    size_t nv = m->vertex_count, nt = m->tri_count;
    const uint32_t *idx = m->indices;
    const double *pos = m->positions;
    uint32_t *start = calloc(nv + 1, sizeof *start);
    uint32_t *cursor = malloc((nv ? nv : 1) * sizeof *cursor);
    uint32_t *other = malloc(3 * nt * sizeof *other);
    uint8_t *used = calloc(nv ? nv : 1, 1);
    hlod_result r = HLOD_ERR_NOMEM;
    if (!start || !cursor || !other || !used)
        goto done;
    for (size_t i = 0; i < 3 * nt; i++) {
        uint32_t a = idx[i], b = idx[i - i % 3 + (i % 3 + 1) % 3];
        if (a != b)
            start[(a < b ? a : b) + 1]++;
    }
    for (size_t v = 0; v < nv; v++)
        start[v + 1] += start[v];
    memcpy(cursor, start, nv * sizeof *cursor);
    for (size_t i = 0; i < 3 * nt; i++) {
        uint32_t a = idx[i], b = idx[i - i % 3 + (i % 3 + 1) % 3];
        used[a] = 1;
        if (a == b)
            continue;
        uint32_t lo = a < b ? a : b, hi = a < b ? b : a;
        const uint32_t *bucket = other + start[lo];
        uint32_t n = cursor[lo] - start[lo], j = 0;
        while (j < n && bucket[j] != hi)
            j++;
        if (j == n)
            other[cursor[lo]++] = hi;
    }
    for (size_t v = 0; v < nv; v++)
        if (used[v] && !push_point(out, pos[3 * v] - origin[0], pos[3 * v + 1] - origin[1],
                                   pos[3 * v + 2] - origin[2]))
            goto done;
    for (size_t v = 0; v < nv; v++)
        for (uint32_t j = start[v]; j < cursor[v]; j++) {
            const double *a = pos + 3 * v, *b = pos + 3 * (size_t)other[j];
            double p[3];
            for (int k = 0; k < 3; k++)
                p[k] = 0.5 * ((a[k] - origin[k]) + (b[k] - origin[k]));
            if (!push_point(out, p[0], p[1], p[2]))
                goto done;
        }
    r = HLOD_OK;
done:
    free(start);
    free(cursor);
    free(other);
    free(used);
    return r;
}

/* n_samples area strata on m; *area receives m's area.  Areas come from
 * re-centred corners: at x = 5e6 the raw differences would already have
 * lost their low bits. */
static hlod_result area_samples(const hlod_mesh *m, const double origin[3], size_t n_samples,
                                uint64_t rng, points *out, double *area)
{
    size_t nt = m->tri_count;
    const uint32_t *idx = m->indices;
    const double *pos = m->positions;
    double *cum = malloc(nt * sizeof *cum);
    if (!cum)
        return HLOD_ERR_NOMEM;
    double total = 0;
    for (size_t t = 0; t < nt; t++) {
        double v[3][3], e1[3], e2[3], n[3];
        for (int j = 0; j < 3; j++)
            for (int k = 0; k < 3; k++)
                v[j][k] = pos[3 * (size_t)idx[3 * t + j] + k] - origin[k];
        hlod_sub3(e1, v[1], v[0]);
        hlod_sub3(e2, v[2], v[0]);
        hlod_cross3(n, e1, e2);
        total += 0.5 * sqrt(hlod_dot3(n, n));
        cum[t] = total;
    }
    *area = total;
    if (total > 0) {
        double step = total / (double)n_samples;
        size_t t = 0;
        for (size_t i = 0; i < n_samples; i++) {
            double u = ((double)i + rand01(&rng)) * step;
            while (t + 1 < nt && cum[t] <= u)
                t++;
            double r1 = rand01(&rng), r2 = rand01(&rng);
            /* Osada et al. eq. 1: uniform density over the triangle. */
            double sq = sqrt(r1), wa = 1 - sq, wb = sq * (1 - r2), wc = sq * r2;
            double p[3];
            for (int k = 0; k < 3; k++) {
                double a = pos[3 * (size_t)idx[3 * t] + k] - origin[k];
                double b = pos[3 * (size_t)idx[3 * t + 1] + k] - origin[k];
                double c = pos[3 * (size_t)idx[3 * t + 2] + k] - origin[k];
                p[k] = wa * a + wb * b + wc * c;
            }
            if (!push_point(out, p[0], p[1], p[2])) {
                free(cum);
                return HLOD_ERR_NOMEM;
            }
        }
    }
    free(cum);
    return HLOD_OK;
}

/* Samples mesh m against grid g (coordinates relative to origin) into s;
 * *area receives m's area. */
static hlod_result sample_side(const hlod_mesh *m, hlod_dgrid *g, const double origin[3],
                               size_t n_samples, uint64_t rng, side *s, double *area)
{
    memset(s, 0, sizeof *s);
    points pts = {0};
    hlod_result r = vertex_edge_samples(m, origin, &pts);
    size_t n_fixed = pts.n;
    if (r == HLOD_OK)
        r = area_samples(m, origin, n_samples, rng, &pts, area);
    if (r != HLOD_OK) {
        free(pts.p);
        return r;
    }

    /* Query in the grid's cell order (a counting sort on each sample's
     * cell): consecutive queries then touch the same cells and triangles,
     * and the previous answer is a tight first bound.  Files often list
     * triangles in no spatial order, which costs several times more. */
    size_t cells = (size_t)g->n[0] * (size_t)g->n[1] * (size_t)g->n[2];
    uint32_t *start = calloc(cells + 1, sizeof *start);
    uint32_t *key = malloc((pts.n ? pts.n : 1) * sizeof *key);
    uint32_t *order = malloc((pts.n ? pts.n : 1) * sizeof *order);
    if (!start || !key || !order || pts.n >= UINT32_MAX) {
        free(start);
        free(key);
        free(order);
        free(pts.p);
        return HLOD_ERR_NOMEM;
    }
    for (size_t i = 0; i < pts.n; i++) {
        key[i] = (uint32_t)cell_of(g, pts.p + 3 * i);
        start[key[i] + 1]++;
    }
    for (size_t c = 0; c < cells; c++)
        start[c + 1] += start[c];
    for (size_t i = 0; i < pts.n; i++)
        order[start[key[i]]++] = (uint32_t)i;
    free(start);
    free(key);

    for (size_t j = 0; j < pts.n; j++) {
        uint32_t i = order[j];
        double d = sqrt(hlod_dgrid_closest2(g, pts.p + 3 * (size_t)i, NULL));
        if (d > s->max)
            s->max = d;
        s->sum_all += d;
        if (i >= n_fixed)
            s->sum_area += d;
    }
    s->n_all = pts.n;
    s->n_area = pts.n - n_fixed;
    free(order);
    free(pts.p);
    return HLOD_OK;
}

/* ---- public entry -------------------------------------------------------- */

static hlod_result check_mesh(const hlod_mesh *m)
{
    if (!m->tri_count)
        return HLOD_ERR_EMPTY;
    if (!m->positions || !m->indices || m->vertex_count >= UINT32_MAX ||
        m->tri_count >= UINT32_MAX / 3)
        return HLOD_ERR_INVALID_ARG;
    for (size_t i = 0; i < 3 * m->tri_count; i++)
        if (m->indices[i] >= m->vertex_count)
            return HLOD_ERR_INDEX_RANGE;
    for (size_t i = 0; i < 3 * m->vertex_count; i++)
        if (!isfinite(m->positions[i]))
            return HLOD_ERR_NAN;
    return HLOD_OK;
}

hlod_result hlod_mesh_distance(const hlod_mesh *a, const hlod_mesh *b, size_t samples_per_mesh,
                               uint64_t seed, hlod_distance *out)
{
    if (!a || !b || !out)
        return HLOD_ERR_INVALID_ARG;
    memset(out, 0, sizeof *out);
    hlod_result r = check_mesh(a);
    if (r == HLOD_OK)
        r = check_mesh(b);
    if (r != HLOD_OK)
        return r;
    if (!samples_per_mesh)
        samples_per_mesh = DEFAULT_SAMPLES;

    double lo[3], hi[3], lo_b[3], hi_b[3], origin[3];
    hlod_mesh_bounds(a, lo, hi);
    hlod_mesh_bounds(b, lo_b, hi_b);
    for (int k = 0; k < 3; k++)
        origin[k] = 0.5 * (dmin(lo[k], lo_b[k]) + dmax(hi[k], hi_b[k]));

    /* One grid at a time keeps the peak memory to the larger mesh's grid.
     * Each side draws from its own stream, so sampling a does not shift
     * the samples on b. */
    hlod_dgrid g;
    side sab, sba;
    double area_a = 0, area_b = 0;
    uint64_t s = seed;
    uint64_t rng_a = splitmix64(&s);
    uint64_t rng_b = splitmix64(&s);
    r = hlod_dgrid_build(&g, b->positions, b->indices, b->tri_count, origin);
    if (r != HLOD_OK)
        return r;
    r = sample_side(a, &g, origin, samples_per_mesh, rng_a, &sab, &area_a);
    hlod_dgrid_free(&g);
    if (r != HLOD_OK)
        return r;
    r = hlod_dgrid_build(&g, a->positions, a->indices, a->tri_count, origin);
    if (r != HLOD_OK)
        return r;
    r = sample_side(b, &g, origin, samples_per_mesh, rng_b, &sba, &area_b);
    hlod_dgrid_free(&g);
    if (r != HLOD_OK)
        return r;

    out->max_ab = sab.max;
    out->max_ba = sba.max;
    out->mean_ab = sab.n_area ? sab.sum_area / (double)sab.n_area : sab.sum_all / (double)sab.n_all;
    out->mean_ba = sba.n_area ? sba.sum_area / (double)sba.n_area : sba.sum_all / (double)sba.n_all;
    out->max = dmax(out->max_ab, out->max_ba);
    if (area_a + area_b > 0)
        out->mean = (out->mean_ab * area_a + out->mean_ba * area_b) / (area_a + area_b);
    else
        out->mean = (sab.sum_all + sba.sum_all) / (double)(sab.n_all + sba.n_all);
    out->samples = sab.n_all + sba.n_all;
    return HLOD_OK;
}

/* ---- certified bound ------------------------------------------------------ */

/* Corner triangles are tried in the order near[i], near[i+1], near[i+2]
 * (indices mod 3): is the one at offset o the same as one tried before it? */
static int tried_before(const uint32_t near[3], int i, int o)
{
    for (int k = 0; k < o; k++)
        if (near[(i + o) % 3] == near[(i + k) % 3])
            return 1;
    return 0;
}

/* A sub-triangle of the measured surface with the distances at its corners. */
typedef struct subtri {
    double p[3][3];
    double f[3];        /* distance from corner c to triangle near[c]: the
                           exact distance to the other surface, or an upper
                           bound of it (see the midpoints in bound_side) */
    uint32_t near[3];   /* the closest triangle of the other surface at each
                           corner, or one near it */
    int depth;
} subtri;

typedef struct subtri_stack {
    subtri *e;
    size_t n, cap;
} subtri_stack;

static int subtri_push(subtri_stack *s, const subtri *t)
{
    if (s->n == s->cap) {
        size_t nc = s->cap ? s->cap * 2 : 1024;
        subtri *ne = realloc(s->e, nc * sizeof *ne);
        if (!ne)
            return 0;
        s->e = ne;
        s->cap = nc;
    }
    s->e[s->n++] = *t;
    return 1;
}

/* A safety cap on splitting.  Pieces straddling an edge between two
 * coplanar triangles of the other surface are settled by the convex-pair
 * bound, so where the surfaces coincide only the pieces at the other
 * surface's vertices keep splitting, a constant number per level. */
#define BOUND_MAX_DEPTH 30

/* See the midpoint queries in bound_side (0.25 to 0.4 measured within noise
 * of each other on the default city's blocks). */
#define LAZY_FRACTION 0.32

/* A work budget.  Where the surfaces differ by about the tolerance but are
 * not coplanar (a fold 1e-9 of the size high, two layers 1e-9 apart,
 * noise), pieces along every edge of the other surface split down to the
 * tolerance: 2^25 pieces per edge, hours.  So each side may split at most
 * BOUND_BUDGET_BASE + BOUND_BUDGET_PER_TRI * (triangles of both) times.  Past
 * that the search restarts in rounds of growing depth caps (BOUND_DEPTHS;
 * a capped piece counts with its whole bound), and the last round that
 * fits the budget gives the answer: still certified, only looser.
 * Ordinary meshes stay inside the budget (the most, of the test meshes:
 * fandisk to 50% at the simplifier's tolerances, 3.0M splits of 10M
 * allowed) and get exactly the bound they got without one. */
#define BOUND_BUDGET_BASE 5e4
#define BOUND_BUDGET_PER_TRI 512.0
static const int BOUND_DEPTHS[] = {BOUND_MAX_DEPTH, 0, 8, 12, 16, 20, 24};

static int same_point(const double *a, const double *b)
{
    return a[0] == b[0] && a[1] == b[1] && a[2] == b[2];
}

/* Twice the signed area of (a, b, p) about the unit normal n. */
static double side2(const double n[3], const double *a, const double *b, const double *p)
{
    double e[3], f[3], c[3];
    hlod_sub3(e, b, a);
    hlod_sub3(f, p, a);
    hlod_cross3(c, e, f);
    return hlod_dot3(n, c);
}

/* Are u and v coplanar, sharing an edge, on opposite sides of it?  Returns
 * 1 when their union is convex (a convex quad), 2 when it is not but holds
 * a convex triangle covering the shared edge, stored in *part, else 0.
 * Exact comparisons with a tight relative slack for coplanarity: a false
 * "no" only costs a split. */
static int convex_pair(const hlod_dgrid_tri *u, const hlod_dgrid_tri *v, hlod_dgrid_tri *part)
{
    if (hlod_dot3(u->n, u->n) == 0 || hlod_dot3(v->n, v->n) == 0 || hlod_dot3(u->n, v->n) < 1 - 1e-12)
        return 0;
    const double *pu[3] = {u->a, u->b, u->c}, *pv[3] = {v->a, v->b, v->c};
    int su[2], sv[2], ns = 0;
    for (int i = 0; i < 3 && ns < 3; i++)
        for (int j = 0; j < 3; j++)
            if (same_point(pu[i], pv[j])) {
                if (ns < 2) {
                    su[ns] = i;
                    sv[ns] = j;
                }
                ns++;
            }
    if (ns != 2)
        return 0;
    const double *s0 = pu[su[0]], *s1 = pu[su[1]];
    const double *ou = pu[3 - su[0] - su[1]], *ov = pv[3 - sv[0] - sv[1]];
    /* ov in u's plane */
    double d[3];
    hlod_sub3(d, ov, u->a);
    double e[3];
    hlod_sub3(e, s1, s0);
    double scale = hlod_dot3(e, e);
    if (fabs(hlod_dot3(u->n, d)) > 1e-9 * sqrt(scale))
        return 0;
    /* opposite sides of the shared edge, and the shared edge's ends on
     * opposite sides of the other diagonal: a convex quad */
    double a1 = side2(u->n, s0, s1, ou), a2 = side2(u->n, s0, s1, ov);
    if (!((a1 > 0 && a2 < 0) || (a1 < 0 && a2 > 0)))
        return 0;
    double b1 = side2(u->n, ou, ov, s0), b2 = side2(u->n, ou, ov, s1);
    if ((b1 > 0 && b2 < 0) || (b1 < 0 && b2 > 0))
        return 1;
    /* Not convex: the end r of the shared edge nearer the line ou-ov has
     * a reflex (or straight) angle, as a simplifier leaves behind on any
     * crease: without this rule pieces straddling such an edge split down
     * to the tolerance all along it (minutes for a 128-triangle roof).
     * The ray from ou through r leaves v through its edge q-ov at some x;
     * the triangle (q, ou, x) = u + (q, r, x) is convex, lies inside the
     * union and still covers the shared edge. */
    const double *q = fabs(b1) >= fabs(b2) ? s0 : s1, *r = q == s0 ? s1 : s0;
    double sq = side2(u->n, q, ov, ou), sr = side2(u->n, q, ov, r);
    double t = sq / (sq - sr);          /* x = ou + t (r - ou) */
    if (!(t >= 1 && isfinite(t)))
        return 0;
    double x[3], qo[3], qx[3];
    for (int k = 0; k < 3; k++)
        x[k] = ou[k] + t * (r[k] - ou[k]);
    hlod_sub3(qo, ov, q);
    hlod_sub3(qx, x, q);
    double along = hlod_dot3(qx, qo) / hlod_dot3(qo, qo);   /* x = q + along (ov - q) */
    if (along > 1 && along <= 1 + 1e-12)
        memcpy(x, ov, sizeof x);                  /* a straight angle at r */
    else if (!(along >= 0 && along <= 1))
        return 0;
    memcpy(part->a, q, sizeof part->a);
    memcpy(part->b, ou, sizeof part->b);
    memcpy(part->c, x, sizeof part->c);
    /* ericson_dist2 needs a proper triangle */
    double e1[3], e2[3], nn[3];
    hlod_sub3(e1, ou, q);
    hlod_sub3(e2, x, q);
    hlod_cross3(nn, e1, e2);
    return hlod_dot3(nn, nn) > 1e-20 * hlod_dot3(e1, e1) * hlod_dot3(e2, e2) ? 2 : 0;
}

/* An upper bound of the distance over the whole sub-triangle, the smaller
 * of two:
 * - every point lies within (longest edge)/sqrt(3) of a corner (the
 *   circumradius bound of an acute triangle; obtuse ones do better), and
 *   the distance to a surface is 1-Lipschitz;
 * - the distance to one fixed triangle of the other surface is convex, so
 *   over the sub-triangle it peaks at a corner; try the corners' nearest
 *   triangles.  This one is tight where both surfaces are flat;
 * - the convex-pair variant below, where the surfaces coincide.
 * Returns as soon as a bound is at most `enough`: the caller only needs to
 * know whether the piece is settled. */
static double subtri_upper(const hlod_dgrid *g, const subtri *t, double enough)
{
    double l2 = 0;
    for (int i = 0; i < 3; i++) {
        double e[3];
        hlod_sub3(e, t->p[(i + 1) % 3], t->p[i]);
        double d = hlod_dot3(e, e);
        if (d > l2)
            l2 = d;
    }
    double fmax3 = dmax(t->f[0], dmax(t->f[1], t->f[2]));
    double best = fmax3 + sqrt(l2 / 3);
    /* the cheaper bounds first; stop as soon as one settles the piece */
    if (best <= enough)
        return best;
    for (int j = 0; j < 3; j++) {
        if (j && (t->near[j] == t->near[0] || (j == 2 && t->near[2] == t->near[1])))
            continue;
        const hlod_dgrid_tri *tr = &g->tris[t->near[j]];
        double worst2 = 0;
        for (int i = 0; i < 3; i++) {
            double d2 = i == j ? t->f[i] * t->f[i] : hlod_dgrid_tri_dist2(t->p[i], tr);
            if (d2 > worst2)
                worst2 = d2;
        }
        double w = sqrt(worst2);
        if (w < best)
            best = w;
    }
    /* A pair can only settle the piece when every corner already does. */
    if (best <= enough || fmax3 > enough)
        return best;
    /* Corner regions: the medians cut the piece into three convex quads
     * (corner i, the midpoints of its two edges, the centroid).  On the
     * quad at corner i the distance to any one triangle is convex, so it
     * peaks at the quad's corners; take, per quad, the best of the three
     * corners' nearest triangles.  Where the other surface is flat but
     * finely triangulated, each corner's triangle covers its own third
     * long before one covers the whole piece: a level of splitting less. */
    {
        double mid[3][3], cen[3];
        for (int e = 0; e < 3; e++)
            for (int k = 0; k < 3; k++)
                mid[e][k] = 0.5 * (t->p[e][k] + t->p[(e + 1) % 3][k]);
        for (int k = 0; k < 3; k++)
            cen[k] = (t->p[0][k] + t->p[1][k] + t->p[2][k]) * (1.0 / 3.0);
        /* Only settling matters here: a quad no triangle settles ends the
         * test, and each triangle is tried at its own corner's quad first. */
        double worst2 = 0, enough2 = enough * enough;
        int settled = 1;
        for (int i = 0; i < 3 && settled; i++) {
            /* quad of corner i: p[i], mid[i] (edge i, i+1), cen, mid[i-1] */
            const double *q[3] = {mid[i], cen, mid[(i + 2) % 3]};
            double region2 = INFINITY;
            for (int o = 0; o < 3 && region2 > enough2; o++) {
                int j = (i + o) % 3;
                if (tried_before(t->near, i, o))
                    continue;
                const hlod_dgrid_tri *tr = &g->tris[t->near[j]];
                double w2 = o == 0 ? t->f[i] * t->f[i] : hlod_dgrid_tri_dist2(t->p[i], tr);
                for (int c = 0; c < 3 && w2 <= enough2; c++)
                    w2 = dmax(w2, hlod_dgrid_tri_dist2(q[c], tr));
                region2 = dmin(region2, w2);
            }
            settled = region2 <= enough2;
            worst2 = dmax(worst2, region2);
        }
        if (settled)
            return dmin(best, sqrt(worst2));
    }
    /* Where the two surfaces coincide the corners often sit on two
     * neighbouring triangles, and neither alone is near all three corners.
     * Two coplanar triangles sharing an edge and forming a convex quad
     * have a convex union, so the distance to the union also peaks at a
     * corner: without this a flat region would split to the depth cap.
     * When the quad is not convex, a convex triangle inside it along the
     * shared edge does the same (an upper bound: it is part of the union). */
    for (int j = 0; j < 3; j++)
        for (int k = j + 1; k < 3; k++) {
            if (t->near[j] == t->near[k])
                continue;
            const hlod_dgrid_tri *u = &g->tris[t->near[j]], *v = &g->tris[t->near[k]];
            hlod_dgrid_tri part;
            int kind = convex_pair(u, v, &part);
            if (!kind)
                continue;
            double worst2 = 0;
            for (int i = 0; i < 3; i++) {
                double d2 = kind == 1 ? dmin(hlod_dgrid_tri_dist2(t->p[i], u),
                                             hlod_dgrid_tri_dist2(t->p[i], v))
                                      : ericson_dist2(t->p[i], &part);
                if (d2 > worst2)
                    worst2 = d2;
            }
            double w = sqrt(worst2);
            if (w < best)
                best = w;
        }
    return best;
}

typedef struct ftri {
    double fmax;
    uint32_t t;
} ftri;

static int ftri_desc(const void *p, const void *q)
{
    const ftri *a = p, *b = q;
    if (a->fmax != b->fmax)
        return a->fmax > b->fmax ? -1 : 1;
    return a->t < b->t ? -1 : a->t > b->t;
}

/* Branch and bound over the triangles of m: the distance is evaluated at
 * the corners, a triangle whose bound cannot beat the best value found (by
 * more than the tolerance) is dropped, the others are split in four.
 * known: a lower bound of the two-sided answer from the other side, so
 * regions that cannot exceed it are dropped at once.  Pieces at max_depth
 * are not split but count with their whole bound (*capped is set); after
 * `budget` splits the search stops with *upper = INFINITY (*lower is still
 * a valid lower bound). */
static hlod_result bound_side(const hlod_mesh *m, hlod_dgrid *g, const double origin[3], double rel_tol,
                              double abs_tol, double known, int max_depth, double budget,
                              double stop, double *lower, double *upper, int *capped)
{
    size_t nv = m->vertex_count, nt = m->tri_count;
    double *fv = malloc((nv ? nv : 1) * sizeof *fv);
    uint32_t *nearv = malloc((nv ? nv : 1) * sizeof *nearv);
    ftri *order = malloc((nt ? nt : 1) * sizeof *order);
    subtri_stack st = {0};
    hlod_result r = HLOD_ERR_NOMEM;
    if (!fv || !nearv || !order)
        goto done;
    double lb = known, ub_left = 0;
    for (size_t v = 0; v < nv; v++) {
        double p[3];
        for (int k = 0; k < 3; k++)
            p[k] = m->positions[3 * v + k] - origin[k];
        fv[v] = sqrt(hlod_dgrid_closest2(g, p, &nearv[v]));
        if (fv[v] > stop) { /* the caller's question is answered */
            lb = dmax(lb, fv[v]);
            ub_left = INFINITY;
            goto out;
        }
    }
    for (size_t t = 0; t < nt; t++) {
        const uint32_t *ix = m->indices + 3 * t;
        order[t].fmax = dmax(fv[ix[0]], dmax(fv[ix[1]], fv[ix[2]]));
        order[t].t = (uint32_t)t;
        if (order[t].fmax > lb)
            lb = order[t].fmax;
    }
    /* the worst triangles first: they raise the lower bound early */
    qsort(order, nt, sizeof *order, ftri_desc);
    for (size_t i = 0; i < nt; i++) {
        const uint32_t *ix = m->indices + 3 * (size_t)order[i].t;
        subtri t0;
        for (int c = 0; c < 3; c++) {
            for (int k = 0; k < 3; k++)
                t0.p[c][k] = m->positions[3 * (size_t)ix[c] + k] - origin[k];
            t0.f[c] = fv[ix[c]];
            t0.near[c] = nearv[ix[c]];
        }
        t0.depth = 0;
        if (subtri_upper(g, &t0, lb * (1 + rel_tol) + abs_tol) <= lb * (1 + rel_tol) + abs_tol)
            continue;
        st.n = 0;
        if (!subtri_push(&st, &t0))
            goto done;
        while (st.n) {
            subtri t = st.e[--st.n];
            double ub = subtri_upper(g, &t, lb * (1 + rel_tol) + abs_tol);
            if (ub <= lb * (1 + rel_tol) + abs_tol)
                continue;
            if (t.depth >= max_depth) {
                ub_left = dmax(ub_left, ub);
                *capped = 1;
                continue;
            }
            if (--budget < 0) {
                ub_left = INFINITY;
                goto out;
            }
            double mid[3][3], fm[3];
            uint32_t nm[3];
            double enough = lb * (1 + rel_tol) + abs_tol;
            for (int e = 0; e < 3; e++) {
                for (int k = 0; k < 3; k++)
                    mid[e][k] = 0.5 * (t.p[e][k] + t.p[(e + 1) % 3][k]);
                /* A corner value only has to bound the distance from above,
                 * so a midpoint well inside the tolerance keeps the distance
                 * to the best of its piece's corner triangles instead of an
                 * exact query (a third of the queries, on a city block).
                 * Nearer than LAZY_FRACTION of the tolerance it could not
                 * have raised the lower bound much; farther, splitting on
                 * a loose value costs more than the query saves. */
                double u2 = INFINITY;
                uint32_t un = t.near[0];
                for (int j = 0; j < 3; j++) {
                    if (tried_before(t.near, 0, j))
                        continue;
                    double d2 = hlod_dgrid_tri_dist2(mid[e], &g->tris[t.near[j]]);
                    if (d2 < u2) {
                        u2 = d2;
                        un = t.near[j];
                    }
                }
                if (u2 <= LAZY_FRACTION * LAZY_FRACTION * enough * enough) {
                    fm[e] = sqrt(u2);
                    nm[e] = un;
                    continue;
                }
                /* the best corner triangle is a tighter first bound than
                 * the previous query's answer */
                g->hint = un;
                fm[e] = sqrt(hlod_dgrid_closest2(g, mid[e], &nm[e]));
                if (fm[e] > lb)
                    lb = fm[e];
                if (lb > stop) {
                    ub_left = INFINITY;
                    goto out;
                }
            }
            /* corners 0,1,2; midpoints m0 = (0,1), m1 = (1,2), m2 = (2,0) */
            const double *cp[4][3] = {{t.p[0], mid[0], mid[2]},
                                      {mid[0], t.p[1], mid[1]},
                                      {mid[2], mid[1], t.p[2]},
                                      {mid[0], mid[1], mid[2]}};
            const double cf[4][3] = {{t.f[0], fm[0], fm[2]},
                                     {fm[0], t.f[1], fm[1]},
                                     {fm[2], fm[1], t.f[2]},
                                     {fm[0], fm[1], fm[2]}};
            const uint32_t cn[4][3] = {{t.near[0], nm[0], nm[2]},
                                       {nm[0], t.near[1], nm[1]},
                                       {nm[2], nm[1], t.near[2]},
                                       {nm[0], nm[1], nm[2]}};
            for (int c = 0; c < 4; c++) {
                subtri s;
                for (int j = 0; j < 3; j++) {
                    memcpy(s.p[j], cp[c][j], sizeof s.p[j]);
                    s.f[j] = cf[c][j];
                    s.near[j] = cn[c][j];
                }
                s.depth = t.depth + 1;
                if (!subtri_push(&st, &s))
                    goto done;
            }
        }
    }
out:
    *lower = lb;
    *upper = dmax(lb * (1 + rel_tol) + abs_tol, ub_left);
    r = HLOD_OK;
done:
    free(fv);
    free(nearv);
    free(order);
    free(st.e);
    return r;
}

hlod_result hlod_mesh_hausdorff_bound(const hlod_mesh *a, const hlod_mesh *b, double rel_tol,
                                      double abs_tol, double *lower, double *upper)
{
    return hlod_mesh_hausdorff_bound_above(a, b, rel_tol, abs_tol, INFINITY, lower, upper);
}

hlod_result hlod_mesh_hausdorff_bound_above(const hlod_mesh *a, const hlod_mesh *b, double rel_tol,
                                            double abs_tol, double stop_above, double *lower,
                                            double *upper)
{
    if (!a || !b || !lower || !upper || !(rel_tol >= 0) || !(abs_tol >= 0))
        return HLOD_ERR_INVALID_ARG;
    *lower = *upper = 0;
    hlod_result r = check_mesh(a);
    if (r == HLOD_OK)
        r = check_mesh(b);
    if (r != HLOD_OK)
        return r;
    double lo[3], hi[3], lo_b[3], hi_b[3], origin[3];
    hlod_mesh_bounds(a, lo, hi);
    hlod_mesh_bounds(b, lo_b, hi_b);
    for (int k = 0; k < 3; k++)
        origin[k] = 0.5 * (dmin(lo[k], lo_b[k]) + dmax(hi[k], hi_b[k]));
    /* An absolute floor, at least 1e-9 of the size: when the surfaces
     * coincide (a flat wall simplified losslessly) no relative tolerance of
     * a zero lower bound can be met, and pieces straddling the other
     * surface's edges would split down to the depth cap. */
    double diag = 0;
    for (int k = 0; k < 3; k++) {
        double e = dmax(hi[k], hi_b[k]) - dmin(lo[k], lo_b[k]);
        diag += e * e;
    }
    abs_tol = dmax(abs_tol, 1e-9 * sqrt(diag));
    /* The finer mesh first: its small triangles rarely need splitting, so
     * it yields a good lower bound cheaply, and that bound prunes most of
     * the coarse mesh's large triangles on the way back. */
    const hlod_mesh *first = a->tri_count >= b->tri_count ? a : b, *second = first == a ? b : a;
    hlod_dgrid g1, g2;
    r = hlod_dgrid_build(&g2, second->positions, second->indices, second->tri_count, origin);
    if (r != HLOD_OK)
        return r;
    r = hlod_dgrid_build(&g1, first->positions, first->indices, first->tri_count, origin);
    if (r != HLOD_OK) {
        hlod_dgrid_free(&g2);
        return r;
    }
    /* The full search, then, if it ran out of budget, rounds of deepening
     * caps from 0 (see BOUND_DEPTHS), each starting from the best lower
     * bound found so far.  Depth 0 splits nothing, so it always finishes. */
    double lb = 0, ub = INFINITY;
    double budget = BOUND_BUDGET_BASE + BOUND_BUDGET_PER_TRI * (double)(a->tri_count + b->tri_count);
    size_t rounds = sizeof BOUND_DEPTHS / sizeof BOUND_DEPTHS[0];
    for (size_t k = 0; k < rounds; k++) {
        int depth = BOUND_DEPTHS[k], capped = 0;
        double l1, u1, l2 = 0, u2 = INFINITY;
        r = bound_side(first, &g2, origin, rel_tol, abs_tol, lb, depth, budget, stop_above, &l1,
                       &u1, &capped);
        if (r == HLOD_OK && u1 < INFINITY)
            r = bound_side(second, &g1, origin, rel_tol, abs_tol, dmax(lb, l1), depth, budget,
                           stop_above, &l2, &u2, &capped);
        if (r != HLOD_OK)
            break;
        lb = dmax(lb, dmax(l1, l2));
        if (lb > stop_above) {
            ub = INFINITY; /* answered: farther than stop_above */
            break;
        }
        if (u1 == INFINITY || u2 == INFINITY) {
            if (k == 0)
                continue;       /* over budget: start the rounds */
            break;              /* keep the last finished round */
        }
        ub = dmax(u1, u2);
        if (!capped || k == 0)
            break;              /* nothing deeper to gain */
    }
    hlod_dgrid_free(&g1);
    hlod_dgrid_free(&g2);
    if (r != HLOD_OK)
        return r;
    *lower = lb;
    *upper = dmax(ub, lb);
    return HLOD_OK;
}
