/* Tests for hlod_mesh_distance() and the closest-point grid behind it. */
#include "check.h"
#include "distance_grid.h"
#include "hlod/distance.h"

#include <math.h>

#define SEED 12345u

static uint64_t rng_next(uint64_t *s)
{
    uint64_t z = (*s += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

static double rng_unit(uint64_t *s)
{
    return (double)(rng_next(s) >> 11) * (1.0 / 9007199254740992.0);
}

/* Builds a mesh from literal arrays. */
static void make_mesh(hlod_mesh *m, const double *pos, size_t nv, const uint32_t *idx, size_t nt)
{
    *m = (hlod_mesh){0};
    CHECK(hlod_mesh_alloc(m, nv, nt, 0) == HLOD_OK);
    memcpy(m->positions, pos, nv * 3 * sizeof(double));
    memcpy(m->indices, idx, nt * 3 * sizeof(uint32_t));
}

/* The unit square in z = `z`, split along its diagonal (0,0)-(1,1). */
static void make_square(hlod_mesh *m, double z)
{
    const double pos[] = {0, 0, z, 1, 0, z, 1, 1, z, 0, 1, z};
    const uint32_t idx[] = {0, 1, 2, 0, 2, 3};
    make_mesh(m, pos, 4, idx, 2);
}

/* A bumpy height field of n x n quads, `size` across: a stand-in for a
 * terrain tile or a roof.  `bump` scales the relief. */
static void make_terrain(hlod_mesh *m, int n, double size, double bump)
{
    *m = (hlod_mesh){0};
    size_t nv = (size_t)(n + 1) * (n + 1), nt = (size_t)2 * n * n;
    CHECK(hlod_mesh_alloc(m, nv, nt, 0) == HLOD_OK);
    for (int y = 0; y <= n; y++)
        for (int x = 0; x <= n; x++) {
            double *p = m->positions + 3 * ((size_t)y * (n + 1) + x);
            p[0] = size * x / n;
            p[1] = size * y / n;
            p[2] = bump * size * (0.1 * sin(7.0 * x / n) * cos(5.0 * y / n) + 0.02 * sin(31.0 * x * y / (n * n)));
        }
    uint32_t *t = m->indices;
    for (int y = 0; y < n; y++)
        for (int x = 0; x < n; x++) {
            uint32_t v = (uint32_t)(y * (n + 1) + x);
            *t++ = v, *t++ = v + 1, *t++ = v + (uint32_t)n + 2;
            *t++ = v, *t++ = v + (uint32_t)n + 2, *t++ = v + (uint32_t)n + 1;
        }
}

static void translate(hlod_mesh *m, double dx, double dy, double dz)
{
    for (size_t i = 0; i < m->vertex_count; i++) {
        m->positions[3 * i] += dx;
        m->positions[3 * i + 1] += dy;
        m->positions[3 * i + 2] += dz;
    }
}

static void identical_meshes_are_zero(void)
{
    hlod_mesh a, b;
    make_terrain(&a, 40, 100.0, 1.0);
    make_terrain(&b, 40, 100.0, 1.0);
    hlod_distance d;
    CHECK(hlod_mesh_distance(&a, &b, 20000, SEED, &d) == HLOD_OK);
    /* Rounding in the closest-point projection only: far below 1e-12 of
     * the mesh size. */
    CHECKF(d.max < 1e-12 * 100.0, "max %g", d.max);
    CHECKF(d.mean < 1e-12 * 100.0, "mean %g", d.mean);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

static void offset_square_is_half(void)
{
    hlod_mesh a, b;
    make_square(&a, 0.0);
    make_square(&b, 0.5);
    hlod_distance d;
    CHECK(hlod_mesh_distance(&a, &b, 5000, SEED, &d) == HLOD_OK);
    CHECKF(fabs(d.max - 0.5) < 1e-12, "max %.17g", d.max);
    CHECKF(fabs(d.mean - 0.5) < 1e-12, "mean %.17g", d.mean);
    CHECKF(fabs(d.max_ab - 0.5) < 1e-12 && fabs(d.max_ba - 0.5) < 1e-12, "%.17g %.17g", d.max_ab,
           d.max_ba);
    CHECKF(fabs(d.mean_ab - 0.5) < 1e-12 && fabs(d.mean_ba - 0.5) < 1e-12, "%.17g %.17g",
           d.mean_ab, d.mean_ba);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

static void make_half_square(hlod_mesh *m)
{
    const double pos[] = {0, 0, 0, 1, 0, 0, 1, 1, 0};
    const uint32_t idx[] = {0, 1, 2};
    make_mesh(m, pos, 3, idx, 1);
}

/* The square's corner (0,1) is 1/sqrt(2) from the half-square's diagonal;
 * every point of the half-square lies on the square. */
static void half_square_max_is_asymmetric(void)
{
    hlod_mesh a, b;
    make_square(&a, 0.0);
    make_half_square(&b);
    hlod_distance d;
    CHECK(hlod_mesh_distance(&a, &b, 5000, SEED, &d) == HLOD_OK);
    CHECKF(fabs(d.max_ab - sqrt(0.5)) < 1e-12, "max_ab %.17g", d.max_ab);
    CHECKF(d.max_ba < 1e-12, "max_ba %.17g", d.max_ba);
    CHECKF(fabs(d.max - sqrt(0.5)) < 1e-12, "max %.17g", d.max);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

/* The missing half is the triangle (0,0),(1,1),(0,1); a point there is
 * (y - x)/sqrt(2) from the diagonal, whose mean over it is 1/(3 sqrt 2)
 * (the centroid has y - x = 1/3).  Over the whole square: 1/(6 sqrt 2).
 * The combined mean weights the sides by area, 1 and 1/2. */
static void half_square_mean_matches_integral(void)
{
    hlod_mesh a, b;
    make_square(&a, 0.0);
    make_half_square(&b);
    hlod_distance d;
    CHECK(hlod_mesh_distance(&a, &b, 100000, SEED, &d) == HLOD_OK);
    double want = 1.0 / (6.0 * sqrt(2.0));
    CHECKF(fabs(d.mean_ab - want) < 2e-3 * want, "mean_ab %.9g want %.9g", d.mean_ab, want);
    CHECKF(d.mean_ba < 1e-12, "mean_ba %g", d.mean_ba);
    CHECKF(fabs(d.mean - d.mean_ab / 1.5) < 1e-12, "mean %.17g", d.mean);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

static void translation_invariant(void)
{
    hlod_mesh a, b;
    make_terrain(&a, 30, 200.0, 1.0);
    make_terrain(&b, 11, 200.0, 0.7);
    hlod_distance d0, d1;
    CHECK(hlod_mesh_distance(&a, &b, 30000, SEED, &d0) == HLOD_OK);
    translate(&a, 5e5, 4.1e6, 30);
    translate(&b, 5e5, 4.1e6, 30);
    CHECK(hlod_mesh_distance(&a, &b, 30000, SEED, &d1) == HLOD_OK);
    CHECK(d0.max > 0.1 && d0.mean > 0.01);
    const double *v0 = &d0.max_ab, *v1 = &d1.max_ab;
    for (int i = 0; i < 6; i++)
        CHECKF(fabs(v0[i] - v1[i]) <= 1e-6 * fabs(v0[i]), "field %d: %.17g vs %.17g", i, v0[i], v1[i]);
    CHECK(d0.samples == d1.samples);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

/* A random triangle soup: mostly small triangles, some large, some
 * slivers (Ericson's path), some collinear, with a repeated corner or all
 * corners at one point (the edge path); optionally flat (one grid layer). */
static void make_soup(hlod_mesh *m, size_t nt, uint64_t *rng, int flat, double offset)
{
    *m = (hlod_mesh){0};
    CHECK(hlod_mesh_alloc(m, 3 * nt, nt, 0) == HLOD_OK);
    for (size_t t = 0; t < nt; t++) {
        double c[3] = {rng_unit(rng), rng_unit(rng), flat ? 0.25 : rng_unit(rng)};
        double s = rng_unit(rng) < 0.1 ? 0.8 : 0.08;
        double *p = m->positions + 9 * t;
        for (int j = 0; j < 3; j++)
            for (int k = 0; k < 3; k++)
                p[3 * j + k] = (flat && k == 2) ? c[k] : c[k] + s * (rng_unit(rng) - 0.5);
        int kind = (int)(rng_next(rng) % 16);
        if (kind == 0)
            for (int k = 0; k < 3; k++)
                p[6 + k] = 0.5 * (p[k] + p[3 + k]);     /* collinear */
        else if (kind == 1)
            memcpy(p + 3, p, 3 * sizeof(double));   /* repeated corner */
        else if (kind == 2)
            for (int k = 0; k < 3; k++)
                p[3 + k] = p[6 + k] = p[k];         /* a point */
        else if (kind == 3)
            for (int k = 0; k < 3; k++)             /* a sliver */
                p[6 + k] = 0.5 * (p[k] + p[3 + k]) + (flat && k == 2 ? 0 : 1e-5 * rng_unit(rng));
        for (int k = 0; k < 9; k++)
            p[k] += offset;
        for (int j = 0; j < 3; j++)
            m->indices[3 * t + j] = (uint32_t)(3 * t + j);
    }
}

static double brute_closest2(const hlod_dgrid *g, const double p[3])
{
    double best = INFINITY;
    for (size_t i = 0; i < g->tri_count; i++) {
        double d = hlod_dgrid_tri_dist2(p, &g->tris[i]);
        if (d < best)
            best = d;
    }
    return best;
}

static void grid_matches_brute_force(void)
{
    uint64_t rng = 99;
    int mismatches = 0, queries = 0;
    for (int trial = 0; trial < 12; trial++) {
        hlod_mesh m;
        int flat = trial % 3 == 2;
        double offset = trial % 4 == 3 ? 4.1e6 : 0.0;
        make_soup(&m, 50 + (size_t)trial * 40, &rng, flat, offset);
        double origin[3] = {offset + 0.5, offset + 0.5, offset + 0.5};
        hlod_dgrid g;
        CHECK(hlod_dgrid_build(&g, m.positions, m.indices, m.tri_count, origin) == HLOD_OK);
        for (int q = 0; q < 3000; q++) {
            double p[3];
            int where = q % 4;
            if (where == 3) {
                /* On the surface: a corner or an edge midpoint, like the
                 * samples hlod_mesh_distance sends. */
                size_t t = rng_next(&rng) % m.tri_count;
                const hlod_dgrid_tri *tr = &g.tris[t];
                for (int k = 0; k < 3; k++)
                    p[k] = q % 8 == 3 ? tr->a[k] : 0.5 * (tr->b[k] + tr->c[k]);
            } else {
                double spread = where == 0 ? 1.0 : where == 1 ? 3.0 : 400.0;
                for (int k = 0; k < 3; k++)
                    p[k] = spread * (rng_unit(&rng) - 0.5);
            }
            uint32_t tri;
            double got = hlod_dgrid_closest2(&g, p, &tri);
            double want = brute_closest2(&g, p);
            queries++;
            if (got != want || hlod_dgrid_tri_dist2(p, &g.tris[tri]) != got) {
                if (mismatches++ < 5)
                    fprintf(stderr, "trial %d query %d: grid %.17g brute %.17g\n", trial, q, got, want);
            }
        }
        hlod_dgrid_free(&g);
        hlod_mesh_free(&m);
    }
    CHECKF(mismatches == 0, "%d of %d queries differ", mismatches, queries);
}

static double ref_seg2(const double p[3], const double a[3], const double b[3])
{
    double ab[3], ap[3], len2 = 0, t = 0, d2 = 0;
    for (int k = 0; k < 3; k++) {
        ab[k] = b[k] - a[k];
        ap[k] = p[k] - a[k];
        len2 += ab[k] * ab[k];
        t += ap[k] * ab[k];
    }
    t = len2 > 0 ? fmin(1.0, fmax(0.0, t / len2)) : 0;
    for (int k = 0; k < 3; k++)
        d2 += (ap[k] - t * ab[k]) * (ap[k] - t * ab[k]);
    return d2;
}

/* An independent point-triangle distance: project onto the plane, keep the
 * projection if the three edge functions agree it is inside, else take the
 * nearest edge. */
static double ref_tri2(const double p[3], const double *v)
{
    const double *a = v, *b = v + 3, *c = v + 6;
    double e1[3], e2[3], n[3];
    for (int k = 0; k < 3; k++) {
        e1[k] = b[k] - a[k];
        e2[k] = c[k] - a[k];
    }
    n[0] = e1[1] * e2[2] - e1[2] * e2[1];
    n[1] = e1[2] * e2[0] - e1[0] * e2[2];
    n[2] = e1[0] * e2[1] - e1[1] * e2[0];
    double n2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
    if (n2 > 0) {
        double s = 0, q[3];
        for (int k = 0; k < 3; k++)
            s += n[k] * (p[k] - a[k]);
        for (int k = 0; k < 3; k++)
            q[k] = p[k] - s / n2 * n[k];
        int inside = 1;
        const double *corner[4] = {a, b, c, a};
        for (int e = 0; e < 3; e++) {
            const double *u = corner[e], *w = corner[e + 1];
            double uw[3] = {w[0] - u[0], w[1] - u[1], w[2] - u[2]};
            double uq[3] = {q[0] - u[0], q[1] - u[1], q[2] - u[2]};
            double x[3] = {uw[1] * uq[2] - uw[2] * uq[1], uw[2] * uq[0] - uw[0] * uq[2],
                           uw[0] * uq[1] - uw[1] * uq[0]};
            if (x[0] * n[0] + x[1] * n[1] + x[2] * n[2] < 0)
                inside = 0;
        }
        if (inside)
            return s * s / n2;
    }
    return fmin(ref_seg2(p, a, b), fmin(ref_seg2(p, b, c), ref_seg2(p, c, a)));
}

/* hlod_dgrid_tri_dist2 on every path (barycentric, Ericson for slivers,
 * edges for degenerate triangles) agrees with the reference above. */
static void point_triangle_matches_reference(void)
{
    uint64_t rng = 7;
    hlod_mesh m;
    make_soup(&m, 400, &rng, 0, 0.0);
    double origin[3] = {0, 0, 0};
    hlod_dgrid g;
    CHECK(hlod_dgrid_build(&g, m.positions, m.indices, m.tri_count, origin) == HLOD_OK);
    int bad = 0, slivers = 0, degenerate = 0;
    for (size_t t = 0; t < g.tri_count; t++) {
        const hlod_dgrid_tri *tr = &g.tris[t];
        double v[9];
        memcpy(v, tr->a, sizeof tr->a);
        memcpy(v + 3, tr->b, sizeof tr->b);
        memcpy(v + 6, tr->c, sizeof tr->c);
        int is_degenerate = tr->n[0] == 0 && tr->n[1] == 0 && tr->n[2] == 0;
        degenerate += is_degenerate;
        slivers += !is_degenerate && tr->inv_det == 0;
        for (int q = 0; q < 50; q++) {
            double p[3];
            for (int k = 0; k < 3; k++)
                p[k] = tr->a[k] + 0.3 * (rng_unit(&rng) - 0.5);
            double got = hlod_dgrid_tri_dist2(p, tr), want = ref_tri2(p, v);
            if (!(fabs(got - want) <= 1e-9 * (want + 1e-6))) {
                if (bad++ < 5)
                    fprintf(stderr, "tri %zu: got %.17g want %.17g\n", t, got, want);
            }
        }
    }
    CHECKF(bad == 0, "%d distances differ", bad);
    CHECKF(slivers > 0 && degenerate > 0, "soup lacks slivers (%d) or degenerates (%d)", slivers,
           degenerate);
    hlod_dgrid_free(&g);
    hlod_mesh_free(&m);
}

static void degenerate_triangle_is_its_edges(void)
{
    hlod_dgrid_tri t = {.a = {0, 0, 0}, .b = {1, 0, 0}, .c = {2, 0, 0}};
    double p[3] = {1.5, 1, 0}, q[3] = {3, 0, 0}, r[3] = {-1, 0, 2};
    CHECK(hlod_dgrid_tri_dist2(p, &t) == 1.0);
    CHECK(hlod_dgrid_tri_dist2(q, &t) == 1.0);
    CHECK(hlod_dgrid_tri_dist2(r, &t) == 5.0);
    hlod_dgrid_tri pt = {.a = {1, 1, 1}, .b = {1, 1, 1}, .c = {1, 1, 1}};
    CHECK(hlod_dgrid_tri_dist2(p, &pt) == 0.25 + 0 + 1);
}

/* A collinear triangle sticking out of a square is sampled at its corners
 * and edges (its far corner sets max_ab) but has no area to sample. */
static void degenerate_triangle_in_mesh(void)
{
    const double pos[] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 2, 0, 0, 3, 0, 0, 4, 0, 0};
    const uint32_t idx[] = {0, 1, 2, 0, 2, 3, 4, 5, 6};
    hlod_mesh a, b;
    make_mesh(&a, pos, 7, idx, 3);
    make_square(&b, 0.0);
    hlod_distance d;
    CHECK(hlod_mesh_distance(&a, &b, 4000, SEED, &d) == HLOD_OK);
    CHECKF(d.max_ab == 3.0, "max_ab %.17g", d.max_ab);
    CHECKF(d.mean_ab < 1e-12, "mean_ab %g", d.mean_ab);
    CHECKF(d.max_ba < 1e-12, "max_ba %g", d.max_ba);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

/* Each unit square has 4 vertices and 5 distinct edges (the diagonal is
 * shared by both triangles and counted once). */
static void sample_count(void)
{
    hlod_mesh a, b;
    make_square(&a, 0.0);
    make_square(&b, 1.0);
    hlod_distance d;
    CHECK(hlod_mesh_distance(&a, &b, 1000, SEED, &d) == HLOD_OK);
    CHECKF(d.samples == 2 * (4 + 5 + 1000), "samples %zu", d.samples);
    CHECK(hlod_mesh_distance(&a, &b, 0, SEED, &d) == HLOD_OK);
    CHECKF(d.samples == 2 * (4 + 5 + 200000), "default samples %zu", d.samples);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

static void seed_reproducible(void)
{
    hlod_mesh a, b;
    make_terrain(&a, 20, 10.0, 1.0);
    make_terrain(&b, 7, 10.0, 0.5);
    hlod_distance d0, d1, d2;
    CHECK(hlod_mesh_distance(&a, &b, 5000, 7, &d0) == HLOD_OK);
    CHECK(hlod_mesh_distance(&a, &b, 5000, 7, &d1) == HLOD_OK);
    CHECK(hlod_mesh_distance(&a, &b, 5000, 8, &d2) == HLOD_OK);
    CHECK(memcmp(&d0, &d1, sizeof d0) == 0);
    CHECK(d0.mean_ab != d2.mean_ab);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

static void empty_and_bad_input(void)
{
    hlod_mesh a, empty = {0};
    make_square(&a, 0.0);
    hlod_distance d;
    CHECK(hlod_mesh_distance(&a, &empty, 100, SEED, &d) == HLOD_ERR_EMPTY);
    CHECK(hlod_mesh_distance(&empty, &a, 100, SEED, &d) == HLOD_ERR_EMPTY);
    CHECK(hlod_mesh_distance(&a, &a, 100, SEED, NULL) == HLOD_ERR_INVALID_ARG);
    CHECK(hlod_mesh_distance(NULL, &a, 100, SEED, &d) == HLOD_ERR_INVALID_ARG);
    hlod_mesh bad;
    make_square(&bad, 0.0);
    bad.indices[4] = 9;
    CHECK(hlod_mesh_distance(&a, &bad, 100, SEED, &d) == HLOD_ERR_INDEX_RANGE);
    bad.indices[4] = 2;
    bad.positions[1] = NAN;
    CHECK(hlod_mesh_distance(&a, &bad, 100, SEED, &d) == HLOD_ERR_NAN);
    hlod_mesh_free(&bad);
    hlod_mesh_free(&a);
}

/* The certified bound brackets the exact answer: a square 0.5 above. */
static void bound_offset_square(void)
{
    hlod_mesh a, b;
    make_square(&a, 0.0);
    make_square(&b, 0.5);
    double lo, up;
    CHECK(hlod_mesh_hausdorff_bound(&a, &b, 0.01, 0, &lo, &up) == HLOD_OK);
    CHECKF(lo <= 0.5 + 1e-12 && up >= 0.5 - 1e-12 && up <= 0.5 * 1.01 + 1e-8, "[%.17g, %.17g]", lo, up);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

/* A flat square A (with an off-centre middle vertex) over a downward
 * pyramid B of depth h sharing A's corners.  B -> A peaks at the apex, h;
 * A -> B peaks at the square's centre, inside a face of A, at
 * 0.5 h / sqrt(h^2 + 1/4).  The bound must find the first exactly and the
 * sampler must agree with the second. */
static void bound_finds_interior_peak(void)
{
    const double h = 0.2;
    const double pa[] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0.3, 0.7, 0};
    const double pb[] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0, 0.5, 0.5, -h};
    const uint32_t idx[] = {0, 1, 4, 1, 2, 4, 2, 3, 4, 3, 0, 4};
    hlod_mesh a, b;
    make_mesh(&a, pa, 5, idx, 4);
    make_mesh(&b, pb, 5, idx, 4);
    double lo, up;
    CHECK(hlod_mesh_hausdorff_bound(&a, &b, 0.001, 0, &lo, &up) == HLOD_OK);
    CHECKF(fabs(lo - h) < 1e-12 && up <= h * 1.001 + 1e-8, "[%.17g, %.17g]", lo, up);
    double exact = 0.5 * h / sqrt(h * h + 0.25);
    hlod_distance d;
    CHECK(hlod_mesh_distance(&a, &b, 400000, SEED, &d) == HLOD_OK);
    CHECKF(d.max_ab <= exact + 1e-12 && d.max_ab > exact - 2e-3, "sampled A->B %.17g, exact %.17g", d.max_ab,
           exact);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

/* On random height fields the bound is never below a dense sampling and
 * stays within its tolerance of its own lower bound: at the simplifier's
 * tolerance (1%), and at the builder's (25% and 1e-3 of the size), where
 * most midpoints keep a corner triangle's distance instead of a query. */
static void bound_dominates_sampling(void)
{
    uint64_t rng = 12345;
    for (int it = 0; it < 40; it++) {
        double rel = it < 20 ? 0.01 : 0.25, abs_tol = it < 20 ? 0 : 1e-3 * 10;
        hlod_mesh a, b;
        make_terrain(&a, 6 + it % 5, 10.0, 0.5 + rng_unit(&rng));
        make_terrain(&b, 3 + it % 4, 10.0, 0.5 + rng_unit(&rng));
        translate(&b, 0, 0, (rng_unit(&rng) - 0.5) * 0.3);
        double lo, up;
        CHECK(hlod_mesh_hausdorff_bound(&a, &b, rel, abs_tol, &lo, &up) == HLOD_OK);
        hlod_distance d;
        CHECK(hlod_mesh_distance(&a, &b, 100000, SEED + (uint64_t)it, &d) == HLOD_OK);
        CHECKF(d.max <= up * (1 + 1e-12), "it %d: sampled %.17g above bound %.17g", it, d.max, up);
        CHECKF(lo <= up && up <= lo * (1 + rel) + abs_tol + 1e-7, "it %d: [%.17g, %.17g]", it, lo, up);
        hlod_mesh_free(&a);
        hlod_mesh_free(&b);
    }
}

/* Two triangulations of the same flat square (a fine grid and its two
 * halves): the bound reaches its absolute floor quickly instead of
 * splitting every piece that straddles a grid edge. */
static void bound_coincident_surfaces(void)
{
    const int n = 24;
    hlod_mesh a = {0}, b;
    CHECK(hlod_mesh_alloc(&a, (size_t)(n + 1) * (n + 1), (size_t)2 * n * n, 0) == HLOD_OK);
    for (int j = 0; j <= n; j++)
        for (int i = 0; i <= n; i++) {
            double *p = a.positions + 3 * ((size_t)j * (n + 1) + i);
            p[0] = (double)i / n;
            p[1] = (double)j / n;
            p[2] = 0;
        }
    uint32_t *x = a.indices;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            uint32_t v = (uint32_t)(j * (n + 1) + i);
            *x++ = v, *x++ = v + 1, *x++ = v + (uint32_t)n + 2;
            *x++ = v, *x++ = v + (uint32_t)n + 2, *x++ = v + (uint32_t)n + 1;
        }
    make_square(&b, 0.0);
    double lo, up;
    CHECK(hlod_mesh_hausdorff_bound(&a, &b, 0.01, 1e-9, &lo, &up) == HLOD_OK);
    CHECKF(lo <= 1e-15 && up <= 2e-9, "[%.17g, %.17g]", lo, up);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

int main(void)
{
    RUN(identical_meshes_are_zero);
    RUN(offset_square_is_half);
    RUN(half_square_max_is_asymmetric);
    RUN(half_square_mean_matches_integral);
    RUN(translation_invariant);
    RUN(grid_matches_brute_force);
    RUN(point_triangle_matches_reference);
    RUN(degenerate_triangle_is_its_edges);
    RUN(degenerate_triangle_in_mesh);
    RUN(sample_count);
    RUN(seed_reproducible);
    RUN(empty_and_bad_input);
    RUN(bound_offset_square);
    RUN(bound_finds_interior_peak);
    RUN(bound_dominates_sampling);
    RUN(bound_coincident_surfaces);
    return check_done();
}
