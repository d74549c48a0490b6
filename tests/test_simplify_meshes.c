/*
 * test_simplify_meshes.c - the simplifier on the real test meshes that
 * data/fetch-meshes.sh extracts from Debian packages (the test command
 * fetches them first; a missing mesh is a failure, not a skip).
 *
 * For each mesh at 10% and 1%: the target is reached, a closed mesh stays
 * closed, a manifold one stays manifold, locked borders stay bit-exact,
 * and an independent, denser Hausdorff measurement stays within the error
 * the simplifier reported.
 */
#include "check.h"
#include "hlod/distance.h"
#include "hlod/mesh_io.h"
#include "hlod/simplify.h"

#include <math.h>
#include <stdint.h>

typedef struct edge_stats {
    size_t border;      /* position edges with one face */
    size_t nonmanifold; /* position edges with more than two faces */
} edge_stats;

static int cmp_u64(const void *p, const void *q)
{
    uint64_t a = *(const uint64_t *)p, b = *(const uint64_t *)q;
    return a < b ? -1 : a > b;
}

typedef struct pkey {
    double p[3];
    uint32_t v;
} pkey;

static int cmp_pkey(const void *p, const void *q)
{
    const pkey *a = p, *b = q;
    for (int k = 0; k < 3; k++)
        if (a->p[k] != b->p[k])
            return a->p[k] < b->p[k] ? -1 : 1;
    return 0;
}

/* Welds equal positions, then counts undirected edge uses. */
static edge_stats edges(const hlod_mesh *m)
{
    edge_stats es = {0, 0};
    pkey *k = malloc(m->vertex_count * sizeof *k);
    uint32_t *id = malloc(m->vertex_count * sizeof *id);
    for (size_t i = 0; i < m->vertex_count; i++) {
        memcpy(k[i].p, m->positions + 3 * i, sizeof k[i].p);
        k[i].v = (uint32_t)i;
    }
    qsort(k, m->vertex_count, sizeof *k, cmp_pkey);
    uint32_t cur = 0;
    for (size_t i = 0; i < m->vertex_count; i++) {
        if (i && cmp_pkey(&k[i], &k[i - 1]))
            cur++;
        id[k[i].v] = cur;
    }
    size_t ne = m->tri_count * 3;
    uint64_t *e = malloc(ne * sizeof *e);
    for (size_t t = 0; t < m->tri_count; t++)
        for (int c = 0; c < 3; c++) {
            uint64_t a = id[m->indices[3 * t + c]], b = id[m->indices[3 * t + (c + 1) % 3]];
            e[3 * t + c] = a < b ? (a << 32 | b) : (b << 32 | a);
        }
    qsort(e, ne, sizeof *e, cmp_u64);
    for (size_t i = 0; i < ne;) {
        size_t j = i;
        while (j < ne && e[j] == e[i])
            j++;
        es.border += j - i == 1;
        es.nonmanifold += j - i > 2;
        i = j;
    }
    free(k);
    free(id);
    free(e);
    return es;
}

static int load(const char *rel, hlod_mesh *m)
{
    char path[1024];
    check_src_path(rel, path, sizeof path);
    hlod_result r = hlod_mesh_import(path, NULL, m, NULL);
    CHECKF(r == HLOD_OK, "%s: %s (run data/fetch-meshes.sh)", path, hlod_result_str(r));
    return r == HLOD_OK;
}

static void check_mesh(const char *rel, int closed, int multipart)
{
    hlod_mesh m = {0};
    if (!load(rel, &m))
        return;
    edge_stats in = edges(&m);
    CHECKF(!closed || in.border == 0, "%s: expected a closed mesh, %zu border edges", rel, in.border);
    double diag = hlod_mesh_bbox_diag(&m);
    const double ratios[2] = {0.1, 0.01};
    for (int r = 0; r < 2; r++) {
        hlod_mesh o = {0};
        hlod_simplify_desc d = {0};
        d.target_tris = (size_t)(m.tri_count * ratios[r]);
        d.measure_error = 1;
        hlod_simplify_stats st;
        CHECK(hlod_simplify(&m, &d, &o, &st) == HLOD_OK);
        /* The target is reached within 2% (or one collapse, two
         * triangles), either side (RELAX stages, then whole parts that
         * cannot shrink go), unless the caller's locks forbid: none here;
         * the clustering last resort may land 5 % under. */
        fprintf(stderr, "  %s %.2f: %zu triangles for a target of %zu%s\n", rel, ratios[r],
                o.tri_count, d.target_tris, st.clustered ? " (clustered)" : "");
        double under = st.clustered ? 0.95 : 0.98, lo = under * (double)d.target_tris;
        if (lo > (double)d.target_tris - 2)
            lo = (double)d.target_tris - 2; /* one collapse takes two */
        CHECKF((double)o.tri_count <= 1.02 * (double)d.target_tris &&
                   (double)o.tri_count >= lo && !strcmp(st.stop_reason, "target"),
               "%s %.2f: stopped at %zu triangles for a target of %zu: %s", rel, ratios[r],
               o.tri_count, d.target_tris, st.stop_reason);
        edge_stats out = edges(&o);
        CHECKF(!closed || out.border == 0, "%s %.2f: closed mesh opened (%zu border edges)", rel,
               ratios[r], out.border);
        /* (the last resort for many parts, clustering, welds parts) */
        CHECKF(in.nonmanifold || out.nonmanifold == 0 || st.clustered, "%s %.2f: %zu non-manifold edges",
               rel, ratios[r], out.nonmanifold);
        /* An independent, denser measurement with another seed. */
        hlod_distance hd;
        CHECK(hlod_mesh_distance(&m, &o, 400000, 99, &hd) == HLOD_OK);
        CHECKF(hd.max <= st.error * (1 + 1e-9), "%s %.2f: measured %g > reported %g", rel, ratios[r], hd.max,
               st.error);
        /* and the bound is tight: within 10% of what dense sampling finds
         * (sampling itself misses peaks by up to ~10% here) */
        CHECKF(st.error <= hd.max * 1.10, "%s %.2f: reported %g, measured only %g", rel, ratios[r], st.error,
               hd.max);
        /* 1% of a many-part mesh keeps fewer triangles than it has parts
         * (spider.obj: 13 for 18 parts): some parts go whole */
        double worst = r == 0 || !multipart ? 0.2 : 0.5;
        CHECKF(st.error > 0 && st.error < worst * diag, "%s %.2f: reported error %g of diagonal %g",
               rel, ratios[r], st.error, diag);
        fprintf(stderr, "     %s %.2f: %zu -> %zu tris, error %.4f%% of diagonal\n", rel, ratios[r], m.tri_count,
                o.tri_count, 100 * st.error / diag);
        hlod_mesh_free(&o);
    }
    hlod_mesh_free(&m);
}

static void bunny(void) { check_mesh("data/meshes/bunny00.off", 0, 0); }
static void fandisk(void) { check_mesh("data/meshes/fandisk.off", 1, 0); }
static void shark_open_borders(void) { check_mesh("data/meshes/mech-holes-shark.off", 0, 0); }
static void spider_textured(void) { check_mesh("data/meshes/spider.obj", 0, 1); }
/* 86 parts, most vertices on open borders and material changes */
static void engine_many_parts(void) { check_mesh("data/meshes/2CylinderEngine.glb", 0, 1); }
/* textured, 51 parts, UV seams everywhere */
static void wuson_seams(void) { check_mesh("data/meshes/Wuson.ply", 0, 1); }

static void shark_locked_border_stays(void)
{
    hlod_mesh m = {0}, o = {0};
    if (!load("data/meshes/mech-holes-shark.off", &m))
        return;
    edge_stats in = edges(&m);
    CHECK(in.border > 0);
    hlod_simplify_desc d = {0};
    d.target_tris = m.tri_count / 20;
    d.lock_border = 1;
    CHECK(hlod_simplify(&m, &d, &o, NULL) == HLOD_OK);
    /* every input border edge is still an output border edge, exactly */
    edge_stats out = edges(&o);
    CHECKF(out.border == in.border, "border edges %zu -> %zu", in.border, out.border);
    hlod_mesh_free(&m);
    hlod_mesh_free(&o);
}

static void target_error_is_respected(void)
{
    hlod_mesh m = {0}, o = {0};
    if (!load("data/meshes/bunny00.off", &m))
        return;
    double diag = hlod_mesh_bbox_diag(&m);
    hlod_simplify_desc d = {0};
    d.target_error = 1e-3 * diag;
    d.measure_error = 1;
    hlod_simplify_stats st;
    CHECK(hlod_simplify(&m, &d, &o, &st) == HLOD_OK);
    /* it stopped on the error, well above zero triangles */
    CHECKF(o.tri_count > 100 && o.tri_count < m.tri_count / 2, "tris %zu", o.tri_count);
    CHECKF(st.error_estimate <= d.target_error, "estimate %g > target %g", st.error_estimate, d.target_error);
    hlod_mesh_free(&m);
    hlod_mesh_free(&o);
}

int main(void)
{
    RUN(bunny);
    RUN(fandisk);
    RUN(shark_open_borders);
    RUN(spider_textured);
    RUN(engine_many_parts);
    RUN(wuson_seams);
    RUN(shark_locked_border_stays);
    RUN(target_error_is_respected);
    return check_done();
}
