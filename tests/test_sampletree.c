/*
 * test_sampletree.c - Klein's randomized sample tree (preprocess/sampletree.c,
 * docs/sampletree.md) and its additive drawing (traverse.c walk_additive).
 *
 * - The sampler: 10^5 area-weighted draws over polygons of unequal area
 *   pass a chi-square test (p >= 0.01); m_u follows Theorem 1.
 * - A two-colour board built into a store: every input triangle in exactly
 *   one node, inner nodes holding the draws, payload bytes (raw layout)
 *   within 1.3x a store holding the same triangles in one node, the
 *   median colours, the
 *   additive flag, and the same bytes for the same seed (another seed,
 *   other bytes).
 * - Drawn with klein from a far oblique camera at 640x480: where full
 *   (every node, no splats) shows the board, klein leaves at most 1 pixel
 *   uncovered with splat_px 1 and 0.1 % with splat_px 4, splats drawn.
 * - klein-auto raises the splat size until a synthetic machine's frames
 *   meet a tight target, and leaves it at 1 under a generous one.
 * - Policies and stores that do not match are refused.
 */
#include "check.h"
#include "grid_quads.h"

#include "../preprocess/build_node.h"
#include "../preprocess/sampletree.h"
#include "hlod/engine.h"
#include "hlod/renderer.h"
#include "hlod/store.h"
#include "hlod/store_write.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static char g_dir[256];

static const uint8_t LIGHT[4] = {230, 222, 200, 255}, DARK[4] = {40, 46, 60, 255};

/* ---- the sampler ---- */

static void sampler_matches_areas(void)
{
    enum { N = 10, M = 100000 };
    double w[N], cum[N], sum = 0;
    for (int j = 0; j < N; j++)
        sum += w[j] = (j + 1) * (j % 3 == 0 ? 3.0 : 1.0);   /* unequal areas */
    uint32_t *out = malloc(M * sizeof *out);
    CHECK(out != NULL);
    if (!out)
        return;
    uint64_t state = 12345;
    hlod_st_draw(w, N, M, &state, cum, out);
    long count[N] = {0};
    for (int i = 0; i < M; i++) {
        CHECK(out[i] < N);
        if (out[i] < N)
            count[out[i]]++;
    }
    double chi2 = 0;
    for (int j = 0; j < N; j++) {
        double e = M * w[j] / sum;
        chi2 += (count[j] - e) * (count[j] - e) / e;
    }
    /* 9 degrees of freedom: p >= 0.01 is chi2 <= 21.666 */
    CHECKF(chi2 <= 21.666, "chi2 %.3f over 9 dof", chi2);
    /* and uniform draws would fail it */
    double u[N];
    for (int j = 0; j < N; j++)
        u[j] = 1;
    state = 12345;
    hlod_st_draw(u, N, M, &state, cum, out);
    double chi2u = 0;
    long cu[N] = {0};
    for (int i = 0; i < M; i++)
        cu[out[i]]++;
    for (int j = 0; j < N; j++) {
        double e = M * w[j] / sum;
        chi2u += (cu[j] - e) * (cu[j] - e) / e;
    }
    CHECKF(chi2u > 1000, "uniform draws pass as area-weighted: chi2 %.1f", chi2u);
    printf("REPORT sampler: chi2 %.2f over 9 dof (p >= 0.01 below 21.67); uniform draws %.0f\n",
           chi2, chi2u);
    free(out);
    /* Theorem 1: q = ceil(A / face), m = q ln q + c q */
    CHECK(hlod_st_sample_size(1.0, 1.0, 13.8) == 14);
    CHECK(hlod_st_sample_size(2.5, 1.0, 13.8) == (size_t)ceil(3 * log(3.0) + 13.8 * 3));
    CHECK(hlod_st_sample_size(1e-9, 1.0, 13.8) == 14);
    CHECK(hlod_st_sample_size(100.0, 1.0, 1.0) == (size_t)ceil(100 * log(100.0) + 100));
}

/* ---- the board ---- */

/* An n x n board of side `side` in z = 0, its 8 x 8 squares in two
 * meshes (light, dark), each holding every grid vertex. */
static int make_board(uint32_t n, double side, hlod_mesh m[2])
{
    memset(m, 0, 2 * sizeof *m);
    size_t nv = (size_t)(n + 1) * (n + 1);
    uint32_t *all = malloc((size_t)6 * n * n * sizeof *all);
    if (!all)
        return 0;
    grid_quads(all, n, n);
    size_t cnt[2] = {0, 0};
    uint32_t sq = n / 8 ? n / 8 : 1;
    for (int k = 0; k < 2; k++)
        if (hlod_mesh_alloc(&m[k], nv, (size_t)n * n, 0) != HLOD_OK) {
            free(all);
            return 0;
        }
    for (uint32_t j = 0; j <= n; j++)
        for (uint32_t i = 0; i <= n; i++)
            for (int k = 0; k < 2; k++) {
                double *p = &m[k].positions[3 * ((size_t)j * (n + 1) + i)];
                p[0] = side * i / n;
                p[1] = side * j / n;
                p[2] = 0;
            }
    for (uint32_t q = 0; q < n * n; q++) {
        uint32_t i = q % n, j = q / n;
        int k = ((i / sq) + (j / sq)) % 2 ? 0 : 1;
        memcpy(&m[k].indices[3 * cnt[k]], &all[6 * (size_t)q], 6 * sizeof *all);
        cnt[k] += 2;
    }
    for (int k = 0; k < 2; k++)
        m[k].tri_count = cnt[k];
    free(all);
    return 1;
}

/* Raw payloads (the bytes of the triangles themselves: a packed store's
 * codecs would compare how well a regular grid compresses whole against
 * in pieces), 64-byte alignment. */
static void layout(hlod_store_writer_desc *wd)
{
    wd->payload_align = HLOD_STORE_MIN_ALIGN;
}

static hlod_result build_board(const hlod_mesh m[2], const char *path, size_t leaf,
                               uint64_t seed)
{
    hlod_store_writer_desc wd = {0};
    wd.build.method = HLOD_STORE_METHOD_SAMPLETREE;
    wd.build.level_factor = 13.8;
    wd.build.leaf_tris = leaf;
    wd.build.c_tex = 0.5;
    layout(&wd);
    hlod_store_writer *w = NULL;
    hlod_result r = hlod_store_writer_open(path, &wd, &w);
    if (r != HLOD_OK)
        return r;
    hlod_st_block b[2] = {{&m[0], NULL, {0}}, {&m[1], NULL, {0}}};
    memcpy(b[0].rgba, LIGHT, 4);
    memcpy(b[1].rgba, DARK, 4);
    hlod_st_params p = {13.8, leaf, seed, 0, NULL, 0};
    hlod_st_report rep;
    return hlod_build_sampletree(b, 2, &p, w, &rep);
}

typedef struct tri_key {
    double c[3];
} tri_key;

static int cmp_key(const void *a, const void *b)
{
    const tri_key *x = a, *y = b;
    for (int k = 0; k < 3; k++)
        if (x->c[k] != y->c[k])
            return x->c[k] < y->c[k] ? -1 : 1;
    return 0;
}

static char *slurp(const char *path, size_t *n)
{
    FILE *fp = fopen(path, "rb");
    if (!fp)
        return NULL;
    fseek(fp, 0, SEEK_END);
    long len = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    char *buf = malloc(len > 0 ? (size_t)len : 1);
    if (buf && fread(buf, 1, (size_t)len, fp) != (size_t)len) {
        free(buf);
        buf = NULL;
    }
    fclose(fp);
    *n = (size_t)len;
    return buf;
}

static void every_triangle_once(void)
{
    const uint32_t n = 64;
    hlod_mesh m[2];
    CHECK(make_board(n, 100.0, m));
    char path[512], path2[512], path3[512], one[512];
    snprintf(path, sizeof path, "%s/board.hlod", g_dir);
    snprintf(path2, sizeof path2, "%s/board2.hlod", g_dir);
    snprintf(path3, sizeof path3, "%s/board3.hlod", g_dir);
    snprintf(one, sizeof one, "%s/one.hlod", g_dir);
    CHECK(build_board(m, path, 256, 1) == HLOD_OK);
    CHECK(build_board(m, path2, 256, 1) == HLOD_OK);
    CHECK(build_board(m, path3, 256, 2) == HLOD_OK);
    size_t n1 = 0, n2 = 0, n3 = 0;
    char *b1 = slurp(path, &n1), *b2 = slurp(path2, &n2), *b3 = slurp(path3, &n3);
    CHECK(b1 && b2 && b3);
    CHECKF(b1 && b2 && n1 == n2 && memcmp(b1, b2, n1) == 0, "the same seed gave other bytes");
    CHECKF(b1 && b3 && (n1 != n3 || memcmp(b1, b3, n1) != 0), "another seed gave the same bytes");
    free(b1);
    free(b2);
    free(b3);

    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (!s) {
        hlod_mesh_free(&m[0]);
        hlod_mesh_free(&m[1]);
        return;
    }
    const hlod_store_header *h = hlod_store_get_header(s);
    CHECK(h->flags & HLOD_STORE_ADDITIVE);
    CHECK(h->build.method == HLOD_STORE_METHOD_SAMPLETREE);
    CHECK(h->root_count == 1 && h->depth_count >= 3);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    const hlod_store_extra *x = hlod_store_extras(s);
    CHECK(x != NULL);
    size_t total = (size_t)2 * n * n, got = 0, inner = 0;
    tri_key *want = malloc(total * sizeof *want), *have = malloc((total + 1) * sizeof *have);
    CHECK(want && have);
    size_t wi = 0;
    for (int k = 0; k < 2 && want; k++)
        for (size_t t = 0; t < m[k].tri_count; t++, wi++)
            for (int a = 0; a < 3; a++) {
                double c = 0;
                for (int v = 0; v < 3; v++)
                    c += m[k].positions[3 * (size_t)m[k].indices[3 * t + v] + a];
                want[wi].c[a] = round(c / 3 * 1e3) / 1e3;
            }
    for (uint32_t i = 0; i < h->node_count && have; i++) {
        const hlod_store_node *nd = &nodes[i];
        int leaf = hlod_store_first_child(nodes, i) == hlod_store_child_end(nodes, i);
        if (!leaf)
            inner += nd->tri_count;
        CHECK(x && (x[i].flags & HLOD_EXTRA_COLOR));
        hlod_store_payload p = {0};
        if (hlod_store_read_node(s, i, 1 << 20, &p) != HLOD_OK) {
            CHECKF(0, "node %u unreadable", i);
            continue;
        }
        for (uint32_t t = 0; t < p.index_count / 3; t++, got++) {
            if (got >= total)
                break;
            for (int a = 0; a < 3; a++) {
                double c = 0;
                for (int v = 0; v < 3; v++)
                    c += nd->origin[a] + p.positions[3 * (size_t)p.indices[3 * t + v] + a];
                have[got].c[a] = round(c / 3 * 1e3) / 1e3;
            }
        }
        hlod_store_payload_free(&p);
    }
    CHECKF(got == total, "%zu triangles stored, %zu in the input", got, total);
    CHECKF(inner > 0 && inner < total / 2, "%zu triangles in inner nodes of %zu", inner, total);
    if (want && have && got == total) {
        qsort(want, total, sizeof *want, cmp_key);
        qsort(have, total, sizeof *have, cmp_key);
        size_t diff = 0;
        for (size_t i = 0; i < total; i++)
            diff += cmp_key(&want[i], &have[i]) != 0;
        CHECKF(diff == 0, "%zu triangles differ from the input's (each once)", diff);
    }
    /* the root's colour: the area-weighted median of a board half light,
     * half dark, channel by channel: one of the two */
    if (x)
        for (int k = 0; k < 3; k++)
            CHECK(x[0].color[k] == LIGHT[k] || x[0].color[k] == DARK[k]);
    /* the same triangles as one node of a store: its payload bytes */
    uint64_t st_bytes = h->payload_bytes;
    hlod_store_close(s);
    hlod_store_writer_desc wd = {0};
    wd.build.method = HLOD_STORE_METHOD_CUTPLANE;
    wd.build.c_tex = 0.5;
    layout(&wd);
    hlod_store_writer *w = NULL;
    CHECK(hlod_store_writer_open(one, &wd, &w) == HLOD_OK);
    hlod_mesh all = {0};
    CHECK(hlod_mesh_alloc(&all, m[0].vertex_count, total, 0) == HLOD_OK);
    uint8_t *col = malloc(4 * m[0].vertex_count);
    if (w && all.positions && col) {
        memcpy(all.positions, m[0].positions, 3 * m[0].vertex_count * sizeof(double));
        memcpy(all.indices, m[0].indices, 3 * m[0].tri_count * sizeof(uint32_t));
        memcpy(all.indices + 3 * m[0].tri_count, m[1].indices, 3 * m[1].tri_count * sizeof(uint32_t));
        for (size_t v = 0; v < m[0].vertex_count; v++)
            memcpy(col + 4 * v, LIGHT, 4);
        hlod_store_node nd;
        CHECK(hlod_build_add_payload(w, &all, NULL, 0, col, LIGHT, &nd) == HLOD_OK);
        nd.parent = HLOD_STORE_NO_PARENT;
        nd.block = 0;
        CHECK(hlod_store_writer_finish(w, &nd, 1, NULL) == HLOD_OK);
        w = NULL;
        hlod_store *o = NULL;
        CHECK(hlod_store_open(one, NULL, &o) == HLOD_OK);
        if (o) {
            uint64_t one_bytes = hlod_store_get_header(o)->payload_bytes;
            printf("REPORT payload bytes: sample tree %llu, the same triangles in one node %llu "
                   "(%.2fx)\n", (unsigned long long)st_bytes, (unsigned long long)one_bytes,
                   (double)st_bytes / (double)one_bytes);
            CHECKF(st_bytes <= 1.3 * one_bytes, "sample tree payloads %llu bytes, the input's %llu",
                   (unsigned long long)st_bytes, (unsigned long long)one_bytes);
            hlod_store_close(o);
        }
    }
    hlod_store_writer_abort(w);
    free(col);
    hlod_mesh_free(&all);
    free(want);
    free(have);
    hlod_mesh_free(&m[0]);
    hlod_mesh_free(&m[1]);
}

/* ---- drawing ---- */

#define W 640
#define H 480

static hlod_osmesa *g_gl;
static hlod_renderer *g_r;
static const uint8_t BG[3] = {255, 0, 255};

/* One frame of s from cam under policy pol (every node loaded first). */
static int render(hlod_store *s, hlod_policy pol, uint32_t splat_px, const hlod_camera *cam,
                  uint8_t *rgb, hlod_frame_stats *st)
{
    hlod_engine_desc d = {0};
    d.policy = pol;
    d.renderer = g_r;
    d.deterministic = 1;
    d.splat_px = splat_px;
    d.memory_budget_bytes = 1ull << 32;
    hlod_engine *e = NULL;
    if (hlod_engine_create(s, &d, &e) != HLOD_OK)
        return 0;
    int ok = hlod_engine_load_all_leaves(e, cam) == HLOD_OK &&
             hlod_engine_frame(e, cam, 1.0 / 30, st) == HLOD_OK &&
             hlod_osmesa_read_rgb(g_gl, rgb) == HLOD_OK;
    hlod_engine_destroy(e);
    return ok;
}

/* A synthetic machine: 2e-5 ms a triangle, 1e-4 ms a splat. */
static double tri_time(void *user, const hlod_frame_stats *st)
{
    (void)user;
    return 2e-5 * (double)st->tris_drawn + 1e-4 * st->splats;
}

static int is_bg(const uint8_t *p)
{
    return p[0] == BG[0] && p[1] == BG[1] && p[2] == BG[2];
}

static void splats_leave_no_hole(void)
{
    /* 2 x 512^2 triangles on a 100 m board, leaves of 16: leaf cells of
     * about 1.1 m, a pixel or less at the far edge */
    hlod_mesh m[2];
    CHECK(make_board(512, 100.0, m));
    char path[512];
    snprintf(path, sizeof path, "%s/big.hlod", g_dir);
    CHECK(build_board(m, path, 16, 7) == HLOD_OK);
    hlod_mesh_free(&m[0]);
    hlod_mesh_free(&m[1]);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (!s)
        return;
    hlod_camera cam;
    const double eye[3] = {50, -50, 30}, at[3] = {50, 40, 0}, up[3] = {0, 0, 1};
    CHECK(hlod_camera_look_at(&cam, eye, at, up, 60, 0.5, 1e4, W, H) == HLOD_OK);
    uint8_t *ref = malloc(W * H * 3), *img = malloc(W * H * 3);
    hlod_frame_stats st;
    CHECK(ref && img && render(s, HLOD_POLICY_FULL, 1, &cam, ref, &st));
    CHECK(st.splats == 0);
    size_t board = 0;
    for (size_t p = 0; ref && p < W * H; p++)
        board += !is_bg(ref + 3 * p);
    CHECKF(board > W * H / 10, "the board covers %zu pixels", board);
    const uint32_t sizes[2] = {1, 4};
    for (int k = 0; k < 2 && ref && img; k++) {
        CHECK(render(s, HLOD_POLICY_KLEIN, sizes[k], &cam, img, &st));
        size_t holes = 0;
        for (size_t p = 0; p < W * H; p++)
            holes += is_bg(img + 3 * p) && !is_bg(ref + 3 * p);
        printf("REPORT splat_px %u: %u splats, %llu triangles drawn, %zu of %zu board pixels "
               "uncovered\n", sizes[k], st.splats, (unsigned long long)st.tris_drawn, holes, board);
        CHECKF(st.splats > 1000, "splat_px %u: %u splats", sizes[k], st.splats);
        if (sizes[k] == 1)
            CHECKF(holes <= 1, "splat_px 1: %zu pixels uncovered", holes);
        else
            CHECKF(holes <= board / 1000, "splat_px 4: %zu of %zu pixels uncovered", holes, board);
    }
    /* klein-auto: on a synthetic machine of 2e-5 ms a triangle, a target
     * of 6 ms (klein at splat_px 1 draws ~10 ms) raises the splat size
     * until the frames fit; a target of 100 ms leaves it at 1 */
    const double targets[2] = {6, 100};
    for (int k = 0; k < 2; k++) {
        hlod_engine_desc ad = {0};
        ad.policy = HLOD_POLICY_KLEIN_AUTO;
        ad.target_ms = targets[k];
        ad.memory_budget_bytes = 1ull << 32;
        ad.time_model = tri_time;
        hlod_engine *ae = NULL;
        CHECK(hlod_engine_create(s, &ad, &ae) == HLOD_OK);
        if (!ae)
            continue;
        CHECK(hlod_engine_load_all_leaves(ae, &cam) == HLOD_OK);
        double late = 0, px = 0;
        for (int f = 0; f < 60; f++) {
            CHECK(hlod_engine_frame(ae, &cam, 1.0 / 30, &st) == HLOD_OK);
            if (f >= 50) {
                late += st.measured_ms / 10;
                px += st.splat_px / 10;
            }
        }
        printf("REPORT klein-auto target %.0f ms: frames %.2f ms, splat_px %.2f\n", targets[k],
               late, px);
        if (k == 0)
            CHECKF(px > 1.5 && late <= 1.15 * targets[k], "target %.0f: %.2f ms at splat_px %.2f",
                   targets[k], late, px);
        else
            CHECKF(fabs(px - 1) < 1e-9, "target %.0f: splat_px %.2f", targets[k], px);
        hlod_engine_destroy(ae);
    }
    /* klein-auto drawn: the splats take the adapted size, so the board
     * stays covered as it grows past 1 (20 frames of the 6 ms target) */
    if (ref && img) {
        hlod_engine_desc ad = {0};
        ad.policy = HLOD_POLICY_KLEIN_AUTO;
        ad.target_ms = 6;
        ad.memory_budget_bytes = 1ull << 32;
        ad.time_model = tri_time;
        ad.renderer = g_r;
        hlod_engine *ae = NULL;
        CHECK(hlod_engine_create(s, &ad, &ae) == HLOD_OK);
        if (ae) {
            CHECK(hlod_engine_load_all_leaves(ae, &cam) == HLOD_OK);
            for (int f = 0; f < 20; f++)
                CHECK(hlod_engine_frame(ae, &cam, 1.0 / 30, &st) == HLOD_OK);
            CHECK(hlod_osmesa_read_rgb(g_gl, img) == HLOD_OK);
            size_t holes = 0;
            for (size_t q = 0; q < W * H; q++)
                holes += is_bg(img + 3 * q) && !is_bg(ref + 3 * q);
            printf("REPORT klein-auto drawn: splat_px %.2f, %u splats, %zu of %zu board pixels "
                   "uncovered\n", st.splat_px, st.splats, holes, board);
            CHECKF(st.splat_px > 1.5 && holes <= board / 1000,
                   "klein-auto: splat_px %.2f, %zu of %zu pixels uncovered", st.splat_px, holes,
                   board);
            hlod_engine_destroy(ae);
        }
    }
    /* klein draws no replacement store, and no other policy a sample tree */
    hlod_engine_desc d = {0};
    d.policy = HLOD_POLICY_LAKHIA;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_ERR_INVALID_ARG && !e);
    free(ref);
    free(img);
    hlod_store_close(s);
}

static void klein_refuses_replacement_stores(void)
{
    char one[512];
    snprintf(one, sizeof one, "%s/one.hlod", g_dir);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(one, NULL, &s) == HLOD_OK);
    if (!s)
        return;
    hlod_engine_desc d = {0};
    d.policy = HLOD_POLICY_KLEIN;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_ERR_INVALID_ARG && !e);
    d.policy = HLOD_POLICY_LAKHIA;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK && e);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod_test_sampletree_XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(sampler_matches_areas);
    RUN(every_triangle_once);
    RUN(klein_refuses_replacement_stores);
    if (hlod_osmesa_create(W, H, NULL, &g_gl) == HLOD_OK &&
        hlod_renderer_create(hlod_osmesa_get_proc(), NULL, &g_r) == HLOD_OK) {
        hlod_renderer_set_clear_color(g_r, 1, 0, 1);
        RUN(splats_leave_no_hole);
    } else {
        CHECK(0); /* OSMesa is installed by the test command */
    }
    hlod_renderer_destroy(g_r);
    hlod_osmesa_destroy(g_gl);
    if (check_failures_ == 0)
        check_sh("rm -rf '%s'", g_dir);
    return check_done();
}
