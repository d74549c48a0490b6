/*
 * test_cutplane.c - the Lakhia III-A builder's hierarchy invariants on a
 * synthetic textured block: leaves hold the original surface, cuts keep
 * area, siblings share bit-identical boundaries, triangle counts follow
 * the factors, errors bound their subtrees and grow towards the root.
 */
#include "btree_check.h"
#include "check.h"
#include "build.h"
#include "hlod/distance.h"
#include "hlod/mesh_io.h"

#include <math.h>
#include <stdint.h>
#include <string.h>
#include <unistd.h>

/* A bumpy, irregular height field, n x n quads over w x h m, with UVs. */
static void field_mesh(hlod_mesh *m, int n, double w, double h, int textured)
{
    hlod_mesh_alloc(m, (size_t)(n + 1) * (n + 1), (size_t)2 * n * n, textured ? HLOD_MESH_UVS : 0);
    for (int j = 0; j <= n; j++)
        for (int i = 0; i <= n; i++) {
            size_t v = (size_t)j * (n + 1) + i;
            double x = w * i / n, y = h * j / n;
            m->positions[3 * v] = x + 5e5;
            m->positions[3 * v + 1] = y + 4.1e6;
            m->positions[3 * v + 2] = 0.3 * sin(0.7 * x) * cos(1.3 * y) + 0.05 * sin(5.1 * x + 2.3 * y);
            if (m->uvs) {
                m->uvs[2 * v] = (float)i / n;
                m->uvs[2 * v + 1] = (float)j / n;
            }
        }
    size_t t = 0;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            uint32_t a = (uint32_t)(j * (n + 1) + i), b = a + 1, c = a + (uint32_t)n + 1, d = c + 1;
            uint32_t *x = m->indices + 3 * t;
            x[0] = a, x[1] = b, x[2] = d, x[3] = a, x[4] = d, x[5] = c;
            t += 2;
        }
}

/* The block of most tests: 40 x 10 m, so every cut is along x. */
static void block_mesh(hlod_mesh *m, int n, int textured)
{
    field_mesh(m, n, 40, 10, textured);
}

static void texture(hlod_image *img, int w, int h)
{
    img->width = w;
    img->height = h;
    img->channels = 3;
    img->pixels = malloc((size_t)w * h * 3);
    for (size_t i = 0; i < (size_t)w * h * 3; i++)
        img->pixels[i] = (uint8_t)(i * 7 % 251);
}

static hlod_build_params params(void)
{
    hlod_build_params p = {0};
    p.desired_tris = 1000;
    p.level_factor = 3;
    p.seed = 1;
    return p;
}

static int is_leaf(const hlod_btree *t, uint32_t i)
{
    for (size_t k = 0; k < t->count; k++)
        if (t->nodes[k].parent == i)
            return 0;
    return 1;
}

/* Union of the leaves under node i (the original triangles it stands for). */
static void leaves_under(const hlod_btree *t, uint32_t i, hlod_mesh *out)
{
    size_t nv = 0, nt = 0;
    for (size_t k = 0; k < t->count; k++) {
        uint32_t a = (uint32_t)k;
        while (a != HLOD_BNODE_NONE && a != i)
            a = t->nodes[a].parent;
        if (a == i && is_leaf(t, (uint32_t)k)) {
            nv += t->nodes[k].mesh.vertex_count;
            nt += t->nodes[k].mesh.tri_count;
        }
    }
    hlod_mesh_alloc(out, nv, nt, 0);
    nv = nt = 0;
    for (size_t k = 0; k < t->count; k++) {
        uint32_t a = (uint32_t)k;
        while (a != HLOD_BNODE_NONE && a != i)
            a = t->nodes[a].parent;
        if (a != i || !is_leaf(t, (uint32_t)k))
            continue;
        const hlod_mesh *m = &t->nodes[k].mesh;
        memcpy(out->positions + 3 * nv, m->positions, m->vertex_count * 3 * sizeof(double));
        for (size_t x = 0; x < m->tri_count * 3; x++)
            out->indices[3 * nt + x] = m->indices[x] + (uint32_t)nv;
        nv += m->vertex_count;
        nt += m->tri_count;
    }
}

static void leaves_keep_area_and_cover_the_block(void)
{
    hlod_mesh m = {0};
    block_mesh(&m, 60, 1);
    hlod_image img = {0};
    texture(&img, 64, 32);
    hlod_build_params p = params();
    hlod_btree t;
    CHECK(hlod_build_cutplane(&m, &img, &p, &t) == HLOD_OK);
    /* s0 = 7200 / 1000 = 7.2 -> 2.4 -> 0.8: three levels, 1 + 3 + 9 nodes */
    CHECKF(t.count == 13, "nodes %zu", t.count);
    double area = 0;
    size_t leaf_tris = 0;
    for (size_t k = 0; k < t.count; k++)
        if (is_leaf(&t, (uint32_t)k)) {
            area += hlod_mesh_area(&t.nodes[k].mesh);
            leaf_tris += t.nodes[k].mesh.tri_count;
            CHECK(t.nodes[k].depth == 2);
            CHECK(t.nodes[k].error == 0);
        }
    double a0 = hlod_mesh_area(&m);
    CHECKF(fabs(area - a0) < 1e-9 * a0, "leaf area %.17g vs %.17g", area, a0);
    /* Two-sided: the leaves hold the block's triangles, none lost and none
     * added (a cut moves each triangle whole to one side) */
    CHECKF(leaf_tris == m.tri_count, "leaves hold %zu triangles of %zu", leaf_tris, m.tri_count);
    fprintf(stderr, "  leaves hold %zu triangles of %zu\n", leaf_tris, m.tri_count);
    /* hlod_0 covers the block */
    double lo[3], hi[3], rlo[3], rhi[3];
    hlod_mesh_bounds(&m, lo, hi);
    hlod_mesh_bounds(&t.nodes[0].mesh, rlo, rhi);
    for (int k = 0; k < 2; k++)
        CHECKF(fabs(lo[k] - rlo[k]) <= t.nodes[0].error && fabs(hi[k] - rhi[k]) <= t.nodes[0].error,
               "axis %d: block [%.17g, %.17g], hlod_0 [%.17g, %.17g], error %g", k, lo[k], hi[k], rlo[k], rhi[k],
               t.nodes[0].error);
    hlod_btree_free(&t);
    hlod_image_free(&img);
    hlod_mesh_free(&m);
}

static int cmp_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return x < y ? -1 : x > y;
}

/* The end of the run of keys equal to v[i] in a sorted array. */
static size_t run_end(const uint64_t *v, size_t n, size_t i)
{
    size_t j = i;
    while (j < n && v[j] == v[i])
        j++;
    return j;
}

static uint64_t hash_pos(const double *p)
{
    uint64_t h = 1469598103934665603ull;
    const unsigned char *c = (const unsigned char *)p;
    for (size_t i = 0; i < 3 * sizeof(double); i++)
        h = (h ^ c[i]) * 1099511628211ull;
    return h;
}

/* The block's outline is simplified too (its vertices may move a little
 * off it, within the node's error), so "on the outline" is within 2 cm;
 * the cuts lie 13 m from the ends. */
static int on_outline(const double *p)
{
    double x = p[0] - 5e5, y = p[1] - 4.1e6;
    return fabs(x) < 0.02 || fabs(x - 40) < 0.02 || fabs(y) < 0.02 || fabs(y - 10) < 0.02;
}

/* On the outline of a square block of side w at (5e5, 4.1e6): within 2 cm,
 * as on_outline. */
static int on_square_outline(const double *p, double w)
{
    double x = p[0] - 5e5, y = p[1] - 4.1e6;
    return fabs(x) < 0.02 || fabs(x - w) < 0.02 || fabs(y) < 0.02 || fabs(y - w) < 0.02;
}

/* Border edges (one face) of every node at a depth, keyed by the bits of
 * their two positions: a border edge inside the block must appear in
 * exactly two nodes (one on each side of a cut), or it is a crack.  Only
 * the block's own outline may stay unmatched. */
static void siblings_share_boundaries(void)
{
    hlod_mesh m = {0};
    block_mesh(&m, 60, 0);
    hlod_build_params p = params();
    hlod_btree t;
    CHECK(hlod_build_cutplane(&m, NULL, &p, &t) == HLOD_OK);
    for (uint32_t depth = 1; depth <= 2; depth++) {
        size_t cap = 0;
        for (size_t k = 0; k < t.count; k++)
            if (t.nodes[k].depth == depth)
                cap += t.nodes[k].mesh.tri_count * 3;
        uint64_t *all = malloc(cap * sizeof *all);
        uint8_t *outline = malloc(cap);
        size_t n_all = 0, inner = 0;
        for (size_t k = 0; k < t.count; k++) {
            if (t.nodes[k].depth != depth)
                continue;
            const hlod_mesh *nm = &t.nodes[k].mesh;
            size_t ne = nm->tri_count * 3;
            uint64_t *e = malloc(ne * sizeof *e);
            uint8_t *ol = malloc(ne);
            for (size_t x = 0; x < nm->tri_count; x++)
                for (int c = 0; c < 3; c++) {
                    const double *pa = nm->positions + 3 * nm->indices[3 * x + c];
                    const double *pb = nm->positions + 3 * nm->indices[3 * x + (c + 1) % 3];
                    uint64_t a = hash_pos(pa), b = hash_pos(pb);
                    /* the low bit says "on the outline" */
                    e[3 * x + c] = ((a < b ? a * 31 + b : b * 31 + a) & ~1ull) | (uint64_t)(on_outline(pa) && on_outline(pb));
                }
            qsort(e, ne, sizeof *e, cmp_u64);
            for (size_t i = 0; i < ne;) {
                size_t j = run_end(e, ne, i);
                if (j - i == 1) {
                    all[n_all] = e[i];
                    outline[n_all++] = (uint8_t)(e[i] & 1);
                    inner += !(e[i] & 1);
                }
                i = j;
            }
            free(e);
            free(ol);
        }
        qsort(all, n_all, sizeof *all, cmp_u64);
        size_t cracks = 0;
        for (size_t i = 0; i < n_all;) {
            size_t j = run_end(all, n_all, i);
            if (!(all[i] & 1))
                cracks += j - i != 2;
            i = j;
        }
        CHECKF(cracks == 0, "depth %u: %zu inner border edges without a twin", depth, cracks);
        CHECKF(inner > 0, "depth %u: no cut edges at all", depth);
        free(all);
        free(outline);
    }
    hlod_btree_free(&t);
    hlod_mesh_free(&m);
}

static void counts_follow_factors_and_errors_bound(void)
{
    hlod_mesh m = {0};
    block_mesh(&m, 60, 1);
    hlod_image img = {0};
    texture(&img, 64, 32);
    hlod_build_params p = params();
    hlod_btree t;
    CHECK(hlod_build_cutplane(&m, &img, &p, &t) == HLOD_OK);
    double s[3] = {7.2, 2.4, 0.8};
    for (size_t k = 0; k < t.count; k++) {
        const hlod_bnode *n = &t.nodes[k];
        if (n->depth < 2) {
            double want = (double)n->source_tris / s[n->depth];
            CHECKF(n->mesh.tri_count <= want + 1 && n->mesh.tri_count >= 0.8 * want,
                   "node %zu depth %u: %zu tris, want %.0f", k, n->depth, n->mesh.tri_count, want);
            /* texture shrinks by sqrt(s) per side, cropped to the node */
            CHECK(n->tex.width > 0 && n->tex.width <= 64 && n->tex.height <= 32);
        }
        if (n->parent != HLOD_BNODE_NONE)
            CHECKF(t.nodes[n->parent].error >= n->error, "node %zu error above its parent's", k);
        hlod_mesh orig = {0};
        leaves_under(&t, (uint32_t)k, &orig);
        hlod_distance d;
        CHECK(hlod_mesh_distance(&n->mesh, &orig, 20000, 3, &d) == HLOD_OK);
        CHECKF(d.max <= n->error * (1 + 1e-9) + 1e-12, "node %zu: sampled %g > error %g", k, d.max, n->error);
        double lower, cap = node_error_cap(&t, (uint32_t)k, &orig, &lower);
        CHECKF(n->error >= lower && n->error <= cap, "node %zu: error %g outside the "
               "documented [%g, %g]", k, n->error, lower, cap);
        hlod_mesh_free(&orig);
    }
    CHECK(t.nodes[0].error > 0);
    hlod_btree_free(&t);
    hlod_image_free(&img);
    hlod_mesh_free(&m);
}

/* Vertices of a mesh on a border edge (an edge of one face only). */
static uint8_t *border_vertices(const hlod_mesh *m)
{
    size_t ne = m->tri_count * 3;
    uint64_t *e = malloc((ne + 1) * sizeof *e);
    uint8_t *on = calloc(m->vertex_count + 1, 1);
    for (size_t x = 0; x < m->tri_count; x++)
        for (int c = 0; c < 3; c++) {
            uint64_t a = m->indices[3 * x + c], b = m->indices[3 * x + (c + 1) % 3];
            e[3 * x + c] = a < b ? a << 32 | b : b << 32 | a;
        }
    qsort(e, ne, sizeof *e, cmp_u64);
    for (size_t i = 0; i < ne;) {
        size_t j = run_end(e, ne, i);
        if (j - i == 1) {
            on[e[i] >> 32] = 1;
            on[e[i] & 0xffffffffu] = 1;
        }
        i = j;
    }
    free(e);
    return on;
}

static int has_position(const hlod_mesh *m, const double *p)
{
    for (size_t v = 0; v < m->vertex_count; v++)
        if (!memcmp(m->positions + 3 * v, p, 3 * sizeof(double)))
            return 1;
    return 0;
}

/* A square block, so the cut axis alternates (level 1 cuts one axis, level
 * 2 the other): drawn at mixed depths, a depth-1 node beside the depth-2
 * children of its sibling, the seam holds no crack.  Every border vertex
 * of a child that lies on its coarser neighbour's box is bit-identical to
 * a vertex of that neighbour. */
static void mixed_depths_share_boundaries(void)
{
    hlod_mesh m = {0};
    field_mesh(&m, 60, 30, 30, 0);
    hlod_build_params p = params();
    hlod_btree t;
    CHECK(hlod_build_cutplane(&m, NULL, &p, &t) == HLOD_OK);
    size_t seams = 0, seam_vertices = 0, missing = 0;
    double axis_seen[2] = {0, 0};
    for (size_t c = 0; c < t.count; c++) {
        if (t.nodes[c].depth != 1)
            continue;
        double clo[3], chi[3];
        hlod_mesh_bounds(&t.nodes[c].mesh, clo, chi);
        for (size_t f = 0; f < t.count; f++) {
            const hlod_bnode *fn = &t.nodes[f];
            if (fn->depth != 2 || fn->parent == c)
                continue;
            const hlod_mesh *fm = &fn->mesh;
            double flo[3], fhi[3];
            hlod_mesh_bounds(fm, flo, fhi);
            /* the child's cut axis: its long side is its parent's short one */
            axis_seen[fhi[0] - flo[0] < fhi[1] - flo[1]] += 1;
            uint8_t *on = border_vertices(fm);
            size_t here = 0;
            for (size_t v = 0; v < fm->vertex_count; v++) {
                const double *q = fm->positions + 3 * v;
                if (!on[v] || on_square_outline(q, 30))
                    continue;
                int inside = 1;
                for (int k = 0; k < 2; k++)
                    inside &= q[k] >= clo[k] - 1e-9 && q[k] <= chi[k] + 1e-9;
                if (!inside)
                    continue;
                here++;
                if (!has_position(&t.nodes[c].mesh, q)) {
                    if (missing < 5)
                        fprintf(stderr, "  node %zu (depth 2) vertex (%.17g, %.17g, %.17g) is not "
                                "in its depth-1 neighbour %zu\n", f, q[0], q[1], q[2], c);
                    missing++;
                }
            }
            seams += here > 0;
            seam_vertices += here;
            free(on);
        }
    }
    fprintf(stderr, "  %zu seams between depths 1 and 2, %zu seam vertices, %zu not in the coarser "
            "node\n", seams, seam_vertices, missing);
    CHECKF(seams >= 2 && seam_vertices > 0, "%zu seams, %zu vertices", seams, seam_vertices);
    CHECKF(missing == 0, "%zu of %zu seam vertices not in the coarser neighbour", missing,
           seam_vertices);
    hlod_btree_free(&t);
    hlod_mesh_free(&m);
}

/* Border edges of m (one face) as keys of their two positions' bits,
 * appended to *keys (grown as needed); not those with both ends on the
 * source's outline (outline NULL: a closed source). */
static void border_edge_keys(const hlod_mesh *m, int (*outline)(const double *), uint64_t **keys,
                             size_t *n, size_t *cap)
{
    uint8_t *on = border_vertices(m);
    size_t ne = m->tri_count * 3;
    uint64_t *e = malloc((ne + 1) * sizeof *e);
    uint64_t *pk = malloc((ne + 1) * sizeof *pk);
    for (size_t x = 0; x < m->tri_count; x++)
        for (int c = 0; c < 3; c++) {
            uint64_t a = m->indices[3 * x + c], b = m->indices[3 * x + (c + 1) % 3];
            e[3 * x + c] = a < b ? a << 32 | b : b << 32 | a;
            uint64_t ha = hash_pos(m->positions + 3 * a), hb = hash_pos(m->positions + 3 * b);
            pk[3 * x + c] = ha < hb ? ha * 31 + hb : hb * 31 + ha;
        }
    /* an edge is a border edge when its index pair occurs once */
    uint64_t *sorted = malloc((ne + 1) * sizeof *sorted);
    memcpy(sorted, e, ne * sizeof *e);
    qsort(sorted, ne, sizeof *sorted, cmp_u64);
    for (size_t i = 0; i < ne; i++) {
        if (!on[e[i] >> 32] || !on[e[i] & 0xffffffffu])
            continue;
        uint64_t *lo = sorted, *hi = sorted + ne;
        while (lo < hi) { /* lower bound of e[i] */
            uint64_t *mid = lo + (hi - lo) / 2;
            if (*mid < e[i])
                lo = mid + 1;
            else
                hi = mid;
        }
        if (run_end(sorted, ne, (size_t)(lo - sorted)) - (size_t)(lo - sorted) != 1)
            continue;
        const double *pa = m->positions + 3 * (e[i] >> 32);
        const double *pb = m->positions + 3 * (e[i] & 0xffffffffu);
        if (outline && outline(pa) && outline(pb))
            continue; /* the outline is simplified too: only seams must match */
        if (*n == *cap) {
            *cap = *cap ? 2 * *cap : 1024;
            *keys = realloc(*keys, *cap * sizeof **keys);
        }
        (*keys)[(*n)++] = pk[i];
    }
    free(sorted);
    free(pk);
    free(e);
    free(on);
}

/* Drawn at mixed depths (every depth-1 node, but one replaced by its
 * children), the selection is watertight: every border edge off the
 * source's outline appears in exactly two nodes, with the same bits.
 * Returns the edges without a twin over all such selections. */
static size_t mixed_selection_cracks(const hlod_btree *t, int (*on_outline)(const double *),
                                     size_t *tried)
{
    size_t cracks = 0;
    *tried = 0;
    for (size_t b = 0; b < t->count; b++) {
        if (t->nodes[b].depth != 1 || is_leaf(t, (uint32_t)b))
            continue;
        uint64_t *keys = NULL;
        size_t n = 0, cap = 0;
        for (size_t k = 0; k < t->count; k++) {
            const hlod_bnode *nd = &t->nodes[k];
            if ((nd->depth == 1 && k != b) || nd->parent == b)
                border_edge_keys(&nd->mesh, on_outline, &keys, &n, &cap);
        }
        qsort(keys, n, sizeof *keys, cmp_u64);
        for (size_t i = 0; i < n;) {
            size_t j = run_end(keys, n, i);
            cracks += j - i != 2;
            i = j;
        }
        free(keys);
        ++*tried;
    }
    return cracks;
}

static int on_square30(const double *p)
{
    return on_square_outline(p, 30);
}

/* The same on a real model nobody here made (CGAL's fandisk, fetched into
 * data/meshes/ by data/fetch-meshes.sh) and on the square block. */
static void mixed_selections_are_watertight(void)
{
    char path[1024];
    check_src_path("data/meshes/fandisk.off", path, sizeof path);
    hlod_mesh real = {0}, square = {0};
    hlod_result r = hlod_mesh_import(path, NULL, &real, NULL);
    CHECKF(r == HLOD_OK, "%s: %s (run data/fetch-meshes.sh)", path, hlod_result_str(r));
    field_mesh(&square, 60, 30, 30, 0);
    const hlod_mesh *meshes[2] = {&square, &real};
    const char *names[2] = {"square block", "fandisk"};
    for (int k = 0; k < 4; k++) {
        if (!meshes[k % 2]->tri_count)
            continue;
        hlod_build_params p = params();
        p.cone_split = k >= 2; /* orientation classes as leaves: the same rule */
        hlod_btree t;
        CHECK(hlod_build_cutplane(meshes[k % 2], NULL, &p, &t) == HLOD_OK);
        size_t tried = 0, cracks = mixed_selection_cracks(&t, k % 2 ? NULL : on_square30, &tried);
        size_t leaf_tris = 0;
        for (size_t i = 0; i < t.count; i++)
            leaf_tris += is_leaf(&t, (uint32_t)i) ? t.nodes[i].mesh.tri_count : 0;
        const char *nm = names[k % 2], *how = k >= 2 ? " (cone split)" : "";
        fprintf(stderr, "  %s%s: %zu triangles, %zu nodes, %zu mixed selections, %zu border edges "
                "without a twin, leaves hold %zu triangles\n", nm, how, meshes[k % 2]->tri_count,
                t.count, tried, cracks, leaf_tris);
        CHECKF(tried >= 2 && cracks == 0, "%s%s: %zu twinless edges in %zu selections", nm, how,
               cracks, tried);
        CHECKF(leaf_tris == meshes[k % 2]->tri_count, "%s%s: leaves hold %zu of %zu triangles",
               nm, how, leaf_tris, meshes[k % 2]->tri_count);
        hlod_btree_free(&t);
    }
    hlod_mesh_free(&real);
    hlod_mesh_free(&square);
}

static void small_block_is_one_node(void)
{
    hlod_mesh m = {0};
    block_mesh(&m, 10, 0); /* 200 triangles < 1000 */
    hlod_build_params p = params();
    hlod_btree t;
    CHECK(hlod_build_cutplane(&m, NULL, &p, &t) == HLOD_OK);
    CHECK(t.count == 1 && t.nodes[0].mesh.tri_count == m.tri_count && t.nodes[0].error == 0);
    hlod_btree_free(&t);
    hlod_mesh_free(&m);
}

static void reproducible(void)
{
    hlod_mesh m = {0};
    block_mesh(&m, 40, 1);
    hlod_image img = {0};
    texture(&img, 32, 32);
    hlod_build_params p = params();
    hlod_btree a, b;
    CHECK(hlod_build_cutplane(&m, &img, &p, &a) == HLOD_OK);
    CHECK(hlod_build_cutplane(&m, &img, &p, &b) == HLOD_OK);
    CHECK(a.count == b.count);
    for (size_t k = 0; k < a.count && a.count == b.count; k++) {
        const hlod_mesh *x = &a.nodes[k].mesh, *y = &b.nodes[k].mesh;
        CHECK(x->vertex_count == y->vertex_count && x->tri_count == y->tri_count);
        if (x->vertex_count == y->vertex_count && x->tri_count == y->tri_count) {
            CHECK(!memcmp(x->positions, y->positions, x->vertex_count * 3 * sizeof(double)));
            CHECK(!memcmp(x->indices, y->indices, x->tri_count * 3 * sizeof(uint32_t)));
            CHECK(!memcmp(x->uvs, y->uvs, x->vertex_count * 2 * sizeof(float)));
        }
        CHECK(a.nodes[k].error == b.nodes[k].error);
    }
    hlod_btree_free(&a);
    hlod_btree_free(&b);
    hlod_image_free(&img);
    hlod_mesh_free(&m);
}

/* Regression: every triangle of a comb of long slivers crosses every
 * cutting plane, so the planes cross about two edges per triangle; the
 * split-vertex map once had room for a quarter per triangle and probed
 * forever when full (hlod-build hung on the default city at
 * --desired-tris 400).  SIGALRM turns a hang into a failure. */
static void plane_crossing_every_triangle(void)
{
    const int n = 4000;
    hlod_mesh m = {0};
    hlod_mesh_alloc(&m, (size_t)3 * n, (size_t)n, 0);
    for (int i = 0; i < n; i++) {
        double y = 0.02 * i, z = 0.3 * sin(0.1 * i);
        double v[3][3] = {{0, y, z}, {40, y + 0.005, z}, {40, y + 0.01, z + 0.01}};
        for (int k = 0; k < 3; k++) {
            memcpy(m.positions + 3 * (3 * (size_t)i + k), v[k], sizeof v[k]);
            m.indices[3 * (size_t)i + k] = (uint32_t)(3 * i + k);
        }
    }
    hlod_build_params p = params();
    hlod_btree t;
    alarm(120);
    CHECK(hlod_build_cutplane(&m, NULL, &p, &t) == HLOD_OK);
    alarm(0);
    CHECK(t.count > 1);
    hlod_btree_free(&t);
    hlod_mesh_free(&m);
}

/* The cosine of the widest unit face normal of m from its area-weighted
 * mean normal (the cone the store would start from). */
static double leaf_cone_cos(const hlod_mesh *m)
{
    double sum[3] = {0, 0, 0}, lo = 2;
    for (int pass = 0; pass < 2; pass++) {
        double len = sqrt(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]);
        for (size_t t = 0; t < m->tri_count; t++) {
            const double *a = m->positions + 3 * (size_t)m->indices[3 * t],
                         *b = m->positions + 3 * (size_t)m->indices[3 * t + 1],
                         *c = m->positions + 3 * (size_t)m->indices[3 * t + 2];
            double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]},
                   v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
            double x[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                           u[0] * v[1] - u[1] * v[0]};
            double l = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
            if (!(l > 0))
                continue;
            if (pass == 0) {
                for (int k = 0; k < 3; k++)
                    sum[k] += x[k];
            } else if (len > 0) {
                double d = (x[0] * sum[0] + x[1] * sum[1] + x[2] * sum[2]) / (l * len);
                lo = d < lo ? d : lo;
            }
        }
    }
    return lo;
}

static int cmp_dbl(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* --cone-split on a model nobody here made (the Stanford bunny, closed,
 * data/meshes/): the leaves become orientation classes of their parent's
 * piece.  They still hold exactly the source's triangles, their normals
 * spread much less (median leaf half-angle), and every inner node is the
 * same as without the split, bit for bit: only the leaves change. */
static void cone_split_narrows_only_the_leaves(void)
{
    char path[1024];
    check_src_path("data/meshes/bunny00.off", path, sizeof path);
    hlod_mesh m = {0};
    hlod_result r = hlod_mesh_import(path, NULL, &m, NULL);
    if (r != HLOD_OK) {
        CHECK_SKIP("%s: %s (run data/fetch-meshes.sh)", path, hlod_result_str(r));
        return;
    }
    hlod_btree t[2];
    double median[2] = {0, 0};
    size_t leaves[2] = {0, 0};
    for (int k = 0; k < 2; k++) {
        hlod_build_params p = params();
        p.desired_tris = 450;
        p.cone_split = k;
        CHECK(hlod_build_cutplane(&m, NULL, &p, &t[k]) == HLOD_OK);
        double *cs = malloc(t[k].count * sizeof *cs);
        size_t leaf_tris = 0;
        for (size_t i = 0; i < t[k].count; i++) {
            if (!is_leaf(&t[k], (uint32_t)i))
                continue;
            cs[leaves[k]++] = leaf_cone_cos(&t[k].nodes[i].mesh);
            leaf_tris += t[k].nodes[i].mesh.tri_count;
        }
        qsort(cs, leaves[k], sizeof *cs, cmp_dbl);
        median[k] = leaves[k] ? acos(fmin(1, fmax(-1, cs[leaves[k] / 2]))) * 180 / M_PI : 0;
        free(cs);
        CHECKF(leaf_tris == m.tri_count, "cone split %d: leaves hold %zu of %zu triangles", k,
               leaf_tris, m.tri_count);
    }
    fprintf(stderr, "  bunny: %zu and %zu leaves, median leaf half-angle %.1f degrees by space, "
            "%.1f with --cone-split\n", leaves[0], leaves[1], median[0], median[1]);
    CHECKF(median[1] < 0.8 * median[0], "median leaf half-angle %.1f with the split, %.1f without",
           median[1], median[0]);
    size_t a = 0, b = 0, same = 0, inner = 0;
    for (;; a++, b++) {
        while (a < t[0].count && is_leaf(&t[0], (uint32_t)a))
            a++;
        while (b < t[1].count && is_leaf(&t[1], (uint32_t)b))
            b++;
        if (a >= t[0].count || b >= t[1].count)
            break;
        const hlod_mesh *x = &t[0].nodes[a].mesh, *y = &t[1].nodes[b].mesh;
        inner++;
        same += x->vertex_count == y->vertex_count && x->tri_count == y->tri_count &&
                !memcmp(x->positions, y->positions, x->vertex_count * 3 * sizeof(double)) &&
                !memcmp(x->indices, y->indices, x->tri_count * 3 * sizeof(uint32_t)) &&
                t[0].nodes[a].error == t[1].nodes[b].error;
    }
    CHECKF(inner > 10 && same == inner && a >= t[0].count && b >= t[1].count,
           "%zu of %zu inner nodes the same with and without the split", same, inner);
    hlod_btree_free(&t[0]);
    hlod_btree_free(&t[1]);
    hlod_mesh_free(&m);
}

int main(void)
{
    RUN(plane_crossing_every_triangle);
    RUN(leaves_keep_area_and_cover_the_block);
    RUN(siblings_share_boundaries);
    RUN(counts_follow_factors_and_errors_bound);
    RUN(mixed_depths_share_boundaries);
    RUN(mixed_selections_are_watertight);
    RUN(small_block_is_one_node);
    RUN(reproducible);
    RUN(cone_split_narrows_only_the_leaves);
    return check_done();
}
