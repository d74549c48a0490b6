/*
 * test_metis.c - the Okamoto 4.1 builder (hlod_build_metis): leaves hold
 * exactly the original triangles, inner nodes meet N_n, errors bound their
 * subtrees and grow towards the root, a node keeps every edge it shares
 * with the rest of the block (no cracks), the METIS wrapper's edge cases
 * (one part, a disconnected block, a tiny block, coincident triangles),
 * and reproducibility.
 */
#include "hlod_clock.h"
#include "build.h"
#include "btree_check.h"
#include "check.h"
#include "hlod/distance.h"

#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <time.h>

/* ---------- synthetic blocks ---------- */

static uint64_t hash64(uint64_t z)
{
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    return z ^ (z >> 31);
}

/* A bumpy height field of n x n quads over 60 x 40 m with small noise, UVs
 * over [0, 1]^2 and normals when asked; offset by (ox, oy). */
static void height_field(hlod_mesh *m, int n, unsigned flags, double ox, double oy)
{
    *m = (hlod_mesh){0};
    CHECK(hlod_mesh_alloc(m, (size_t)(n + 1) * (n + 1), (size_t)2 * n * n, flags) == HLOD_OK);
    for (int j = 0; j <= n; j++)
        for (int i = 0; i <= n; i++) {
            size_t v = (size_t)j * (n + 1) + i;
            double x = 60.0 * i / n, y = 40.0 * j / n;
            double noise = (double)(hash64(v * 2654435761u + 1) >> 11) / 9007199254740992.0 - 0.5;
            m->positions[3 * v] = x + ox;
            m->positions[3 * v + 1] = y + oy;
            m->positions[3 * v + 2] = 2.0 * sin(0.3 * x) * cos(0.4 * y) + 0.5 * sin(1.7 * x + 0.9 * y) + 0.02 * noise;
            if (m->uvs) {
                m->uvs[2 * v] = (float)i / n;
                m->uvs[2 * v + 1] = (float)j / n;
            }
            if (m->normals) {
                m->normals[3 * v] = 0;
                m->normals[3 * v + 1] = 0;
                m->normals[3 * v + 2] = 1;
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

/* A closed box of size s at (ox, 0, 0), each face an n x n grid (faces do
 * not share vertex indices: the seams are only welded by position), every
 * vertex moved by up to 1% of s as a function of its position, so copies
 * stay together.  (Exactly planar faces are avoided on purpose: see the
 * note on hlod_mesh_hausdorff_bound in the builder's report.) */
static void box(hlod_mesh *m, int n, double s, double ox)
{
    *m = (hlod_mesh){0};
    size_t fv = (size_t)(n + 1) * (n + 1), ft = (size_t)2 * n * n;
    CHECK(hlod_mesh_alloc(m, 6 * fv, 6 * ft, 0) == HLOD_OK);
    for (int f = 0; f < 6; f++) {
        int ax = f / 2, hi = f % 2;
        int u = (ax + 1) % 3, w = (ax + 2) % 3;
        for (int j = 0; j <= n; j++)
            for (int i = 0; i <= n; i++) {
                double *p = m->positions + 3 * (f * fv + (size_t)j * (n + 1) + i);
                p[ax] = hi ? s : 0;
                p[u] = s * i / n;
                p[w] = s * j / n;
                double h = sin(12.9898 * p[0] + 78.233 * p[1] + 37.719 * p[2]) * 43758.5453;
                h -= floor(h);
                for (int k = 0; k < 3; k++)
                    p[k] += 0.01 * s * (h - 0.5) * (k == ax ? 1 : 0.3);
                p[0] += ox;
            }
        for (int j = 0; j < n; j++)
            for (int i = 0; i < n; i++) {
                uint32_t a = (uint32_t)(f * fv + (size_t)j * (n + 1) + i), b = a + 1, c = a + (uint32_t)n + 1,
                         d = c + 1;
                uint32_t *x = m->indices + 3 * (f * ft + 2 * ((size_t)j * n + i));
                if (hi)
                    x[0] = a, x[1] = b, x[2] = d, x[3] = a, x[4] = d, x[5] = c;
                else
                    x[0] = a, x[1] = d, x[2] = b, x[3] = a, x[4] = c, x[5] = d;
            }
    }
}

/* Concatenates b onto a. */
static void append(hlod_mesh *a, const hlod_mesh *b)
{
    hlod_mesh c = {0};
    CHECK(hlod_mesh_alloc(&c, a->vertex_count + b->vertex_count, a->tri_count + b->tri_count, 0) == HLOD_OK);
    if (a->vertex_count) /* an empty mesh has NULL arrays */
        memcpy(c.positions, a->positions, a->vertex_count * 3 * sizeof(double));
    if (a->tri_count)
        memcpy(c.indices, a->indices, a->tri_count * 3 * sizeof(uint32_t));
    memcpy(c.positions + 3 * a->vertex_count, b->positions, b->vertex_count * 3 * sizeof(double));
    for (size_t i = 0; i < 3 * b->tri_count; i++)
        c.indices[3 * a->tri_count + i] = b->indices[i] + (uint32_t)a->vertex_count;
    hlod_mesh_free(a);
    *a = c;
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

typedef struct logbook {
    int warn, error;
} logbook;

static void record(void *user, hlod_log_level level, const char *msg)
{
    (void)msg;
    logbook *b = user;
    b->warn += level == HLOD_LOG_WARN;
    b->error += level == HLOD_LOG_ERROR;
}

static hlod_build_params params(size_t nv, size_t nl, size_t nn)
{
    hlod_build_params p = {0};
    p.voxel_tris = nv;
    p.leaf_tris = nl;
    p.node_tris = nn;
    p.seed = 7;
    return p;
}

/* ---------- tree helpers ---------- */

static int is_leaf(const hlod_btree *t, uint32_t i)
{
    for (size_t k = i + 1; k < t->count; k++)
        if (t->nodes[k].parent == i)
            return 0;
    return 1;
}

static int under(const hlod_btree *t, uint32_t k, uint32_t i)
{
    while (k != HLOD_BNODE_NONE && k != i)
        k = t->nodes[k].parent;
    return k == i;
}

/* Triangles as sorted position triples: a triangle's corners rotated so
 * the smallest comes first (winding kept), then all triangles sorted. */
typedef struct tkey {
    double p[9];
} tkey;

static int cmp_d3(const double *a, const double *b)
{
    for (int k = 0; k < 3; k++)
        if (a[k] != b[k])
            return a[k] < b[k] ? -1 : 1;
    return 0;
}

static int cmp_tkey(const void *pa, const void *pb)
{
    const tkey *a = pa, *b = pb;
    for (int k = 0; k < 9; k++)
        if (a->p[k] != b->p[k])
            return a->p[k] < b->p[k] ? -1 : 1;
    return 0;
}

static size_t add_keys(const hlod_mesh *m, tkey *k)
{
    for (size_t t = 0; t < m->tri_count; t++) {
        const double *c[3];
        for (int j = 0; j < 3; j++)
            c[j] = m->positions + 3 * (size_t)m->indices[3 * t + j];
        int r = 0;
        for (int j = 1; j < 3; j++)
            if (cmp_d3(c[j], c[r]) < 0)
                r = j;
        for (int j = 0; j < 3; j++)
            memcpy(k[t].p + 3 * j, c[(r + j) % 3], 3 * sizeof(double));
    }
    return m->tri_count;
}

/* The leaves under node i, concatenated (the original triangles). */
static void leaves_under(const hlod_btree *t, uint32_t i, hlod_mesh *out)
{
    *out = (hlod_mesh){0};
    for (size_t k = 0; k < t->count; k++)
        if (under(t, (uint32_t)k, i) && is_leaf(t, (uint32_t)k))
            append(out, &t->nodes[k].mesh);
}

static int leaves_are_block(const hlod_btree *t, const hlod_mesh *block)
{
    size_t n = 0;
    for (size_t k = 0; k < t->count; k++)
        if (is_leaf(t, (uint32_t)k))
            n += t->nodes[k].mesh.tri_count;
    if (n != block->tri_count)
        return 0;
    tkey *a = malloc(n * sizeof *a), *b = malloc(n * sizeof *b);
    size_t f = 0;
    for (size_t k = 0; k < t->count; k++)
        if (is_leaf(t, (uint32_t)k))
            f += add_keys(&t->nodes[k].mesh, a + f);
    add_keys(block, b);
    qsort(a, n, sizeof *a, cmp_tkey);
    qsort(b, n, sizeof *b, cmp_tkey);
    int same = !memcmp(a, b, n * sizeof *a);
    free(a);
    free(b);
    return same;
}

/* ---------- invariants on a 35k-triangle block ---------- */

static hlod_mesh block35;
static hlod_image tex35;
static hlod_btree tree35;
static const size_t NV = 500, NL = 4000, NN = 2000;

static void build_block35(void)
{
    height_field(&block35, 132, HLOD_MESH_UVS | HLOD_MESH_NORMALS, 0, 0); /* 34848 triangles */
    texture(&tex35, 256, 256);
    hlod_build_params p = params(NV, NL, NN);
    logbook lb = {0};
    hlod_logger lg = {record, &lb};
    p.logger = &lg;
    double t0 = hlod_now_s();
    CHECK(hlod_build_metis(&block35, &tex35, &p, &tree35) == HLOD_OK);
    fprintf(stderr, "     %zu triangles, N_v %zu, N_l %zu, N_n %zu: %zu nodes in %.2f s\n", block35.tri_count, NV,
            NL, NN, tree35.count, hlod_now_s() - t0);
    CHECK(lb.warn == 0 && lb.error == 0);
}

static void leaves_hold_exactly_the_original_triangles(void)
{
    CHECK(tree35.count > 1);
    CHECK(leaves_are_block(&tree35, &block35));
    for (size_t k = 0; k < tree35.count; k++)
        if (is_leaf(&tree35, (uint32_t)k)) {
            CHECKF(tree35.nodes[k].mesh.tri_count < NL, "leaf %zu: %zu", k, tree35.nodes[k].mesh.tri_count);
            CHECK(tree35.nodes[k].error == 0);
            CHECK(tree35.nodes[k].source_tris == tree35.nodes[k].mesh.tri_count);
        }
}

static void tree_shape_and_triangle_counts(void)
{
    const hlod_btree *t = &tree35;
    CHECK(t->nodes[0].parent == HLOD_BNODE_NONE && t->nodes[0].depth == 0);
    CHECK(t->nodes[0].source_tris == block35.tri_count);
    size_t leaves = 0;
    for (size_t k = 0; k < t->count; k++) {
        const hlod_bnode *n = &t->nodes[k];
        if (k) {
            CHECKF(n->parent < k, "node %zu parent %u", k, n->parent);
            CHECK(n->depth == t->nodes[n->parent].depth + 1);
        }
        /* Okamoto: a binary tree; inner nodes at N_n triangles */
        size_t kids = 0, kid_tris = 0, kid_src = 0;
        for (size_t c = k + 1; c < t->count; c++)
            if (t->nodes[c].parent == k) {
                kids++;
                kid_tris += t->nodes[c].mesh.tri_count;
                kid_src += t->nodes[c].source_tris;
            }
        CHECK(kids == 0 || kids == 2);
        leaves += kids == 0;
        if (kids) {
            CHECK(n->source_tris == kid_src);
            CHECK(n->source_tris >= NL);
            size_t cap = kid_tris < NN ? kid_tris : NN;
            CHECKF(n->mesh.tri_count <= cap, "node %zu: %zu triangles", k, n->mesh.tri_count);
            CHECKF(n->mesh.tri_count > NN * 9 / 10, "node %zu: %zu triangles", k, n->mesh.tri_count);
        }
        /* textured: each node has its own, smaller for coarser nodes */
        CHECK(n->tex.width > 0 && n->tex.pixels);
        CHECK(n->mesh.uvs && !n->mesh.tri_material);
    }
    /* balanced: 34848 / 4000 needs at least 9 leaves; METIS halves evenly */
    CHECKF(leaves >= 9 && leaves <= 32, "leaves %zu", leaves);
    CHECK(t->nodes[0].tex.width < tex35.width);
}

static void errors_bound_subtrees_and_grow_upwards(void)
{
    const hlod_btree *t = &tree35;
    for (size_t k = 1; k < t->count; k++)
        CHECKF(t->nodes[t->nodes[k].parent].error >= t->nodes[k].error, "node %zu", k);
    for (size_t k = 0; k < t->count; k++) {
        if (is_leaf(t, (uint32_t)k))
            continue;
        hlod_mesh orig;
        leaves_under(t, (uint32_t)k, &orig);
        hlod_distance d;
        CHECK(hlod_mesh_distance(&t->nodes[k].mesh, &orig, 20000, 3, &d) == HLOD_OK);
        CHECKF(d.max <= t->nodes[k].error * (1 + 1e-9), "node %zu: sampled %g > error %g", k, d.max,
               t->nodes[k].error);
        double lower, cap = node_error_cap(t, (uint32_t)k, &orig, &lower);
        double err = t->nodes[k].error;
        CHECKF(err >= lower && err <= cap, "node %zu: error %g outside the documented [%g, %g]", k,
               err, lower, cap);
        CHECK(t->nodes[k].error > 0);
        hlod_mesh_free(&orig);
    }
}

/* Exact positions to ids, by sorting. */
typedef struct pk {
    double p[3];
    uint32_t i;
} pk;

static int cmp_pk(const void *a, const void *b)
{
    int c = cmp_d3(((const pk *)a)->p, ((const pk *)b)->p);
    return c ? c : (((const pk *)a)->i > ((const pk *)b)->i) - (((const pk *)a)->i < ((const pk *)b)->i);
}

typedef struct edge {
    uint32_t a, b, in, out;
} edge;

static int cmp_edge(const void *x, const void *y)
{
    const edge *a = x, *b = y;
    if (a->a != b->a)
        return a->a < b->a ? -1 : 1;
    return (a->b > b->b) - (a->b < b->b);
}

/* Welds the positions of all leaf vertices; pos[id] is a sorted table. */
static uint32_t find_id(const pk *tab, size_t n, const double *p)
{
    size_t lo = 0, hi = n;
    while (lo < hi) {
        size_t mid = (lo + hi) / 2;
        int c = cmp_d3(tab[mid].p, p);
        if (!c)
            return tab[mid].i;
        if (c < 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    return UINT32_MAX;
}

/* No cracks: every original edge between a triangle under node k and one
 * outside it is an edge of node k's mesh, with bit-identical ends. */
static size_t check_no_cracks(const hlod_btree *t)
{
    /* unique original positions */
    size_t nv = 0;
    for (size_t k = 0; k < t->count; k++)
        if (is_leaf(t, (uint32_t)k))
            nv += t->nodes[k].mesh.vertex_count;
    pk *all = malloc(nv * sizeof *all);
    size_t f = 0;
    for (size_t k = 0; k < t->count; k++)
        if (is_leaf(t, (uint32_t)k))
            for (size_t v = 0; v < t->nodes[k].mesh.vertex_count; v++, f++) {
                memcpy(all[f].p, t->nodes[k].mesh.positions + 3 * v, 3 * sizeof(double));
                all[f].i = 0;
            }
    qsort(all, nv, sizeof *all, cmp_pk);
    size_t np = 0;
    for (size_t i = 0; i < nv; i++)
        if (!np || cmp_d3(all[np - 1].p, all[i].p)) {
            all[np] = all[i];
            all[np].i = (uint32_t)np;
            np++;
        }
    size_t checked = 0;
    for (size_t k = 1; k < t->count; k++) {
        /* original edges with in/out triangle counts */
        size_t ne = 0;
        for (size_t l = 0; l < t->count; l++)
            if (is_leaf(t, (uint32_t)l))
                ne += 3 * t->nodes[l].mesh.tri_count;
        edge *e = malloc(ne * sizeof *e);
        ne = 0;
        for (size_t l = 0; l < t->count; l++) {
            if (!is_leaf(t, (uint32_t)l))
                continue;
            const hlod_mesh *m = &t->nodes[l].mesh;
            int in = under(t, (uint32_t)l, (uint32_t)k);
            for (size_t tr = 0; tr < m->tri_count; tr++)
                for (int c = 0; c < 3; c++) {
                    uint32_t a = find_id(all, np, m->positions + 3 * (size_t)m->indices[3 * tr + c]);
                    uint32_t b = find_id(all, np, m->positions + 3 * (size_t)m->indices[3 * tr + (c + 1) % 3]);
                    e[ne++] = (edge){a < b ? a : b, a < b ? b : a, (uint32_t)in, (uint32_t)!in};
                }
        }
        qsort(e, ne, sizeof *e, cmp_edge);
        /* node k's edges */
        const hlod_mesh *m = &t->nodes[k].mesh;
        edge *me = malloc(3 * m->tri_count * sizeof *me + 1);
        size_t nme = 0;
        for (size_t tr = 0; tr < m->tri_count; tr++)
            for (int c = 0; c < 3; c++) {
                uint32_t a = find_id(all, np, m->positions + 3 * (size_t)m->indices[3 * tr + c]);
                uint32_t b = find_id(all, np, m->positions + 3 * (size_t)m->indices[3 * tr + (c + 1) % 3]);
                if (a != UINT32_MAX && b != UINT32_MAX)
                    me[nme++] = (edge){a < b ? a : b, a < b ? b : a, 0, 0};
            }
        qsort(me, nme, sizeof *me, cmp_edge);
        size_t missing = 0;
        for (size_t i = 0; i < ne;) {
            size_t j = i;
            uint32_t in = 0, out = 0;
            while (j < ne && e[j].a == e[i].a && e[j].b == e[i].b) {
                in += e[j].in;
                out += e[j].out;
                j++;
            }
            if (in && out) {
                checked++;
                if (!bsearch(&e[i], me, nme, sizeof *me, cmp_edge))
                    missing++;
            }
            i = j;
        }
        CHECKF(missing == 0, "node %zu lost %zu boundary edges", k, missing);
        free(e);
        free(me);
    }
    free(all);
    return checked;
}

static void boundaries_never_crack(void)
{
    CHECK(check_no_cracks(&tree35) > 0);
}

/* ---------- METIS edge cases ---------- */

static void a_tiny_block_is_one_leaf(void)
{
    hlod_mesh m;
    height_field(&m, 20, HLOD_MESH_UVS, 0, 0); /* 800 triangles < N_l */
    hlod_image img;
    texture(&img, 32, 32);
    hlod_build_params p = params(NV, NL, NN);
    hlod_btree t;
    CHECK(hlod_build_metis(&m, &img, &p, &t) == HLOD_OK);
    CHECK(t.count == 1);
    CHECK(t.nodes[0].parent == HLOD_BNODE_NONE && t.nodes[0].error == 0);
    CHECK(t.nodes[0].source_tris == m.tri_count && t.nodes[0].mesh.tri_count == m.tri_count);
    CHECK(leaves_are_block(&t, &m));
    CHECK(t.nodes[0].tex.width == 32); /* factor 1: full resolution */
    hlod_btree_free(&t);
    /* exactly N_l triangles is not under N_l: one split */
    p.leaf_tris = m.tri_count;
    p.node_tris = 300;
    CHECK(hlod_build_metis(&m, NULL, &p, &t) == HLOD_OK);
    CHECK(t.count == 3);
    CHECK(leaves_are_block(&t, &m));
    CHECK(t.nodes[0].tex.width == 0);
    hlod_btree_free(&t);
    hlod_image_free(&img);
    hlod_mesh_free(&m);
}

/* A block whose voxel graph is one vertex (5000 coincident triangles
 * cannot be voxelised): METIS would be asked for one part; the block
 * stays one over-full leaf and says so. */
static void one_part_stays_one_leaf(void)
{
    hlod_mesh m = {0};
    CHECK(hlod_mesh_alloc(&m, 3, 5000, 0) == HLOD_OK);
    const double pos[9] = {1, 2, 3, 1.5, 2, 3, 1, 2.5, 3.25};
    memcpy(m.positions, pos, sizeof pos);
    for (size_t t = 0; t < m.tri_count; t++)
        for (int c = 0; c < 3; c++)
            m.indices[3 * t + c] = (uint32_t)c;
    hlod_build_params p = params(NV, NL, NN);
    logbook lb = {0};
    hlod_logger lg = {record, &lb};
    p.logger = &lg;
    hlod_btree t;
    CHECK(hlod_build_metis(&m, NULL, &p, &t) == HLOD_OK);
    CHECK(t.count == 1);
    CHECK(t.nodes[0].mesh.tri_count == 5000);
    CHECK(lb.warn == 1 && lb.error == 0);
    hlod_btree_free(&t);
    hlod_mesh_free(&m);
}

/* Two boxes 10 m apart: the root's children are the two boxes (the
 * components), not a METIS cut through both. */
static void a_disconnected_block_splits_by_components(void)
{
    hlod_mesh m, b2;
    box(&m, 24, 4.0, 0);   /* 6912 triangles */
    box(&b2, 20, 3.0, 14); /* 4800 triangles */
    append(&m, &b2);
    hlod_build_params p = params(NV, NL, 1500);
    hlod_btree t;
    CHECK(hlod_build_metis(&m, NULL, &p, &t) == HLOD_OK);
    CHECK(leaves_are_block(&t, &m));
    size_t kids = 0;
    for (size_t k = 1; k < t.count; k++) {
        if (t.nodes[k].parent != 0)
            continue;
        kids++;
        const hlod_mesh *c = &t.nodes[k].mesh;
        double lo[3], hi[3];
        hlod_mesh_bounds(c, lo, hi);
        CHECKF(hi[0] <= 4.1 || lo[0] >= 13.9, "child %zu spans x %g..%g", k, lo[0], hi[0]);
        CHECK(t.nodes[k].source_tris == 6912 || t.nodes[k].source_tris == 4800);
    }
    CHECK(kids == 2);
    CHECK(check_no_cracks(&t) > 0);
    /* closed boxes stay closed: the root simplifies both to N_n together */
    CHECK(t.nodes[0].mesh.tri_count <= 1500);
    hlod_btree_free(&t);

    /* many small components: bin packing, still a valid tree */
    hlod_mesh many;
    box(&many, 8, 1.0, 0); /* 768 triangles each */
    for (int i = 1; i < 12; i++) {
        hlod_mesh b;
        box(&b, 8, 1.0, 3.0 * i);
        append(&many, &b);
        hlod_mesh_free(&b);
    }
    p = params(200, 2000, 600);
    CHECK(hlod_build_metis(&many, NULL, &p, &t) == HLOD_OK);
    CHECK(leaves_are_block(&t, &many));
    for (size_t k = 0; k < t.count; k++)
        if (!is_leaf(&t, (uint32_t)k))
            CHECK(t.nodes[k].mesh.tri_count <= 600);
    /* boxes of 768 < N_l triangles are packed whole, never cut */
    CHECK(check_no_cracks(&t) == 0);
    hlod_btree_free(&t);
    hlod_mesh_free(&many);
    hlod_mesh_free(&b2);
    hlod_mesh_free(&m);
}

static void bad_blocks_are_rejected(void)
{
    hlod_build_params p = params(NV, NL, NN);
    hlod_btree t;
    hlod_mesh empty = {0};
    CHECK(hlod_build_metis(&empty, NULL, &p, &t) == HLOD_ERR_EMPTY);
    CHECK(t.count == 0);
    hlod_mesh m;
    height_field(&m, 4, 0, 0, 0);
    m.indices[5] = 1000;
    CHECK(hlod_build_metis(&m, NULL, &p, &t) == HLOD_ERR_INDEX_RANGE);
    m.indices[5] = 0;
    m.positions[4] = NAN;
    CHECK(hlod_build_metis(&m, NULL, &p, &t) == HLOD_ERR_NAN);
    CHECK(hlod_build_metis(NULL, NULL, &p, &t) == HLOD_ERR_INVALID_ARG);
    hlod_mesh_free(&m);
}

/* ---------- reproducibility ---------- */

static int same_mesh(const hlod_mesh *a, const hlod_mesh *b)
{
    if (a->vertex_count != b->vertex_count || a->tri_count != b->tri_count)
        return 0;
    if (memcmp(a->positions, b->positions, a->vertex_count * 3 * sizeof(double)) ||
        memcmp(a->indices, b->indices, a->tri_count * 3 * sizeof(uint32_t)))
        return 0;
    if (!a->uvs != !b->uvs || (a->uvs && memcmp(a->uvs, b->uvs, a->vertex_count * 2 * sizeof(float))))
        return 0;
    if (!a->normals != !b->normals ||
        (a->normals && memcmp(a->normals, b->normals, a->vertex_count * 3 * sizeof(float))))
        return 0;
    return 1;
}

static void same_seed_same_tree(void)
{
    hlod_build_params p = params(NV, NL, NN);
    hlod_btree t;
    CHECK(hlod_build_metis(&block35, &tex35, &p, &t) == HLOD_OK);
    CHECK(t.count == tree35.count);
    for (size_t k = 0; k < t.count && k < tree35.count; k++) {
        const hlod_bnode *a = &t.nodes[k], *b = &tree35.nodes[k];
        CHECKF(same_mesh(&a->mesh, &b->mesh), "node %zu", k);
        CHECK(a->parent == b->parent && a->depth == b->depth && a->source_tris == b->source_tris);
        CHECK(a->error == b->error);
        CHECK(a->tex.width == b->tex.width && a->tex.height == b->tex.height);
        CHECK(!memcmp(a->tex.pixels, b->tex.pixels, (size_t)a->tex.width * a->tex.height * a->tex.channels));
    }
    hlod_btree_free(&t);
}

typedef struct job {
    hlod_btree t;
    hlod_result r;
} job;

/* called from a test thread */
static void *build_job(void *arg)
{
    job *j = arg;
    hlod_build_params p = params(NV, NL, NN);
    j->r = hlod_build_metis(&block35, &tex35, &p, &j->t);
    return NULL;
}

/* hlod-build runs blocks on several threads: concurrent builds (and their
 * METIS calls) give the single-threaded tree. */
static void threads_build_the_same_tree(void)
{
    job jobs[2] = {0};
    pthread_t th[2];
    for (int i = 0; i < 2; i++)
        CHECK(pthread_create(&th[i], NULL, build_job, &jobs[i]) == 0);
    for (int i = 0; i < 2; i++) {
        pthread_join(th[i], NULL);
        CHECK(jobs[i].r == HLOD_OK && jobs[i].t.count == tree35.count);
        for (size_t k = 0; k < jobs[i].t.count && k < tree35.count; k++)
            CHECKF(same_mesh(&jobs[i].t.nodes[k].mesh, &tree35.nodes[k].mesh), "thread %d node %zu", i, k);
        hlod_btree_free(&jobs[i].t);
    }
}

/* Untextured: no texture path, normals carried, same invariants. */
static void untextured_block(void)
{
    hlod_mesh m;
    height_field(&m, 100, HLOD_MESH_NORMALS, 0, 0); /* 20000 triangles */
    hlod_build_params p = params(1000, 3000, 1500);
    hlod_btree t;
    CHECK(hlod_build_metis(&m, NULL, &p, &t) == HLOD_OK);
    CHECK(t.count > 3);
    CHECK(leaves_are_block(&t, &m));
    for (size_t k = 0; k < t.count; k++) {
        CHECK(t.nodes[k].tex.width == 0 && !t.nodes[k].mesh.uvs && t.nodes[k].mesh.normals);
        if (!is_leaf(&t, (uint32_t)k))
            CHECK(t.nodes[k].mesh.tri_count <= 1500);
    }
    CHECK(check_no_cracks(&t) > 0);
    hlod_btree_free(&t);
    hlod_mesh_free(&m);
}

/* At projected coordinates the tree has the same shape. */
static void large_coordinates_same_shape(void)
{
    hlod_mesh m;
    height_field(&m, 100, 0, 5e5, 4.1e6);
    hlod_build_params p = params(1000, 3000, 1500);
    hlod_btree t;
    CHECK(hlod_build_metis(&m, NULL, &p, &t) == HLOD_OK);
    CHECK(leaves_are_block(&t, &m));
    CHECK(check_no_cracks(&t) > 0);
    CHECK(t.count > 3);
    for (size_t k = 0; k < t.count; k++)
        if (!is_leaf(&t, (uint32_t)k))
            CHECK(t.nodes[k].mesh.tri_count <= 1500 && t.nodes[k].error < 1.0);
    hlod_btree_free(&t);
    hlod_mesh_free(&m);
}

int main(void)
{
    build_block35();
    RUN_UNTHREADED(leaves_hold_exactly_the_original_triangles);
    RUN_UNTHREADED(tree_shape_and_triangle_counts);
    RUN_UNTHREADED(errors_bound_subtrees_and_grow_upwards);
    RUN_UNTHREADED(boundaries_never_crack);
    RUN_UNTHREADED(same_seed_same_tree);
    RUN(threads_build_the_same_tree);
    RUN_UNTHREADED(a_tiny_block_is_one_leaf);
    RUN_UNTHREADED(one_part_stays_one_leaf);
    RUN_UNTHREADED(a_disconnected_block_splits_by_components);
    RUN_UNTHREADED(bad_blocks_are_rejected);
    RUN_UNTHREADED(untextured_block);
    RUN_UNTHREADED(large_coordinates_same_shape);
    hlod_btree_free(&tree35);
    hlod_image_free(&tex35);
    hlod_mesh_free(&block35);
    return check_done();
}
