/*
 * test_cubes.c - Chamberlain's colour cubes (preprocess/cubes.c,
 * hlod-build --method cubes, policy cubes; docs/cubes.md).
 *
 * - Faces: a face that geometry covers whole has alpha >= 15/16, an empty
 *   cell alpha 0, an edge-on quad no alpha on the faces it is seen edge
 *   on from; a box whose faces come from its eight children's cubes
 *   composited front to back is within 0.1 of its triangles seen
 *   directly, on a cloud of small triangles of random colours.
 * - A cloud of 20k small triangles (Chamberlain's "suspension") built
 *   into a store: every input triangle stored once, every node with a
 *   cube, the additive flag and method.
 * - Drawn by policy cubes from far at 320 x 240: it draws a small share
 *   of full's triangles, covers about as many pixels as full, and its
 *   image is close to full's; without its cubes (cube_px 1 with the
 *   cubes' alpha taken away) the far cloud would vanish.
 * - Policies and stores that do not match are refused.
 * - Cubes as stand-ins (far_cubes): a replacement store written with
 *   cubes has one on every node, made from the node's own mesh (its
 *   vertex colours, or its texture's texels), and the same payload bytes
 *   as without; drawn from far by lakhia with far_cubes, the nodes within
 *   cube_px are cubes, no node under them is read, and the picture
 *   covers what the meshes cover in about their colour.  Engines refuse
 *   far_cubes on a store without cubes and on an additive one.
 * - Copies (cube_copies, Chamberlain Fig. 5): 2 x 2 copies of the cloud
 *   seen whole draw 4 x its triangles with every node drawn; 8 x 8 copies
 *   far off are one block cube; a copies image of one copy in view is
 *   the plain image of the same view moved by the copy's offset.
 */
#include "check.h"
#include "store_fixture.h"

#include "../preprocess/cubes.h"
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

#define W 320
#define H 240

static char g_dir[256];

typedef struct tri {
    double p[9];
    float rgb[3];
} tri;

static void tri_color(void *user, size_t i, const double w[3], float rgb[3])
{
    (void)w;
    memcpy(rgb, ((const tri *)user)[i].rgb, 3 * sizeof(float));
}

static uint64_t g_rng = 88172645463325252ull;

static double rnd(void)
{
    g_rng ^= g_rng << 13;
    g_rng ^= g_rng >> 7;
    g_rng ^= g_rng << 17;
    return (double)(g_rng >> 11) / 9007199254740992.0;
}

/* n small triangles (edge about `size`) with centres uniform in the unit
 * cube [0, 1]^3, colours random. */
static tri *cloud(size_t n, double size)
{
    tri *t = malloc(n * sizeof *t);
    for (size_t i = 0; t && i < n; i++) {
        double c[3] = {rnd(), rnd(), rnd()};
        for (int k = 0; k < 3; k++)
            for (int a = 0; a < 3; a++)
                t[i].p[3 * k + a] = c[a] + size * (rnd() - 0.5);
        for (int a = 0; a < 3; a++)
            t[i].rgb[a] = (float)(0.2 + 0.8 * rnd());
    }
    return t;
}

static void box_of(const tri *t, size_t n, double lo[3], double hi[3])
{
    for (int a = 0; a < 3; a++) {
        lo[a] = INFINITY;
        hi[a] = -INFINITY;
    }
    for (size_t i = 0; i < n; i++)
        for (int k = 0; k < 9; k++) {
            lo[k % 3] = fmin(lo[k % 3], t[i].p[k]);
            hi[k % 3] = fmax(hi[k % 3], t[i].p[k]);
        }
}

static void faces_of(const tri *t, size_t n, const double lo[3], const double hi[3],
                     const hlod_cube *kids, const double (*klo)[3], const double (*khi)[3],
                     size_t nk, hlod_cube *out)
{
    hlod_cube_in in = {.tris = t, .stride = sizeof *t, .n = n, .color = tri_color,
                       .user = (void *)t, .kids = kids, .kid_lo = klo, .kid_hi = khi,
                       .nkids = nk};
    memcpy(in.lo, lo, sizeof in.lo);
    memcpy(in.hi, hi, sizeof in.hi);
    hlod_cube_faces(&in, out);
}

/* ---- faces ---- */

static void covered_and_empty_faces(void)
{
    /* a unit square at z = 0 in a box 2 deep: seen whole from +z and -z,
     * edge on from the sides */
    tri q[2] = {{{0, 0, 0, 1, 0, 0, 1, 1, 0}, {1, 0.5f, 0.25f}},
                {{0, 0, 0, 1, 1, 0, 0, 1, 0}, {1, 0.5f, 0.25f}}};
    double lo[3] = {0, 0, -1}, hi[3] = {1, 1, 1};
    hlod_cube c;
    faces_of(q, 2, lo, hi, NULL, NULL, NULL, 0, &c);
    for (int f = 4; f < 6; f++) {
        CHECKF(c.rgba[f][3] >= 15.0f / 16, "face %d: alpha %.3f", f, c.rgba[f][3]);
        CHECKF(fabsf(c.rgba[f][0] - c.rgba[f][3]) < 1e-3 &&
                   fabsf(c.rgba[f][1] - 0.5f * c.rgba[f][3]) < 1e-3,
               "face %d: premultiplied colour %.3f %.3f", f, c.rgba[f][0], c.rgba[f][1]);
    }
    for (int f = 0; f < 4; f++)
        CHECKF(c.rgba[f][3] == 0, "face %d sees the square edge on: alpha %.3f", f, c.rgba[f][3]);
    /* half the square: alpha about a half from +z */
    faces_of(q, 1, lo, hi, NULL, NULL, NULL, 0, &c);
    CHECKF(fabsf(c.rgba[4][3] - 0.5f) < 0.07f, "half covered: alpha %.3f", c.rgba[4][3]);
    /* empty: nothing at all */
    faces_of(NULL, 0, lo, hi, NULL, NULL, NULL, 0, &c);
    for (int f = 0; f < 6; f++)
        for (int k = 0; k < 4; k++)
            CHECK(c.rgba[f][k] == 0);
    /* geometry outside the box is clipped: the square above it */
    tri up[2] = {q[0], q[1]};
    for (int k = 0; k < 3; k++)
        up[0].p[3 * k + 2] = up[1].p[3 * k + 2] = 2;
    faces_of(up, 2, lo, hi, NULL, NULL, NULL, 0, &c);
    CHECKF(c.rgba[4][3] == 0, "a square outside the box shows: alpha %.3f", c.rgba[4][3]);
}

static void composite_matches_direct(void)
{
    enum { N = 3000 };
    tri *t = cloud(N, 0.08);
    CHECK(t != NULL);
    if (!t)
        return;
    /* the eight octants by centroid, each child's box its triangles' */
    tri *sorted = malloc(N * sizeof *sorted);
    size_t start[9] = {0}, cnt[8] = {0};
    for (size_t i = 0; i < N; i++) {
        int o = 0;
        for (int a = 0; a < 3; a++)
            o |= ((t[i].p[a] + t[i].p[3 + a] + t[i].p[6 + a]) / 3 > 0.5) << a;
        cnt[o]++;
    }
    for (int o = 0; o < 8; o++)
        start[o + 1] = start[o] + cnt[o];
    size_t cur[8];
    memcpy(cur, start, sizeof cur);
    for (size_t i = 0; sorted && i < N; i++) {
        int o = 0;
        for (int a = 0; a < 3; a++)
            o |= ((t[i].p[a] + t[i].p[3 + a] + t[i].p[6 + a]) / 3 > 0.5) << a;
        sorted[cur[o]++] = t[i];
    }
    hlod_cube kids[8], direct, comp, sum;
    double klo[8][3], khi[8][3], lo[3], hi[3];
    for (int o = 0; sorted && o < 8; o++) {
        box_of(sorted + start[o], cnt[o], klo[o], khi[o]);
        faces_of(sorted + start[o], cnt[o], klo[o], khi[o], NULL, NULL, NULL, 0, &kids[o]);
    }
    box_of(t, N, lo, hi);
    faces_of(t, N, lo, hi, NULL, NULL, NULL, 0, &direct);
    faces_of(NULL, 0, lo, hi, kids, (const double (*)[3])klo, (const double (*)[3])khi, 8, &comp);
    /* the children summed instead of composited: what the test tells apart */
    memset(&sum, 0, sizeof sum);
    for (int o = 0; o < 8; o++)
        for (int f = 0; f < 6; f++)
            for (int k = 0; k < 4; k++)
                sum.rgba[f][k] += kids[o].rgba[f][k] / 4;
    double worst = 0, worst_sum = 0;
    for (int f = 0; f < 6; f++)
        for (int k = 0; k < 4; k++) {
            worst = fmax(worst, fabs(comp.rgba[f][k] - direct.rgba[f][k]));
            worst_sum = fmax(worst_sum, fabs(sum.rgba[f][k] - direct.rgba[f][k]));
        }
    printf("REPORT composite vs direct over 6 faces x RGBA: worst %.3f (children summed: %.3f); "
           "+x direct alpha %.3f\n", worst, worst_sum, direct.rgba[0][3]);
    CHECKF(worst <= 0.1, "composited faces differ from direct by %.3f", worst);
    CHECKF(worst_sum > 0.1, "summing would pass too (%.3f): the test cannot tell", worst_sum);
    CHECKF(direct.rgba[0][3] > 0.5 && direct.rgba[0][3] < 1, "+x alpha %.3f", direct.rgba[0][3]);
    free(sorted);
    free(t);
}

/* ---- a store ---- */

static void log_stderr(void *user, hlod_log_level level, const char *msg)
{
    (void)user;
    if (level <= HLOD_LOG_WARN)
        fprintf(stderr, "log: %s\n", msg);
}

static const hlod_logger g_log = {log_stderr, NULL};

static hlod_result build_cloud(const char *path, size_t n, int cubes, hlod_st_report *rep)
{
    tri *t = cloud(n, 0.04);
    hlod_mesh m = {0};
    hlod_result r = t ? hlod_mesh_alloc(&m, 3 * n, n, 0) : HLOD_ERR_NOMEM;
    for (size_t i = 0; r == HLOD_OK && i < n; i++) {
        memcpy(&m.positions[9 * i], t[i].p, sizeof t[i].p);
        for (int k = 0; k < 3; k++)
            m.indices[3 * i + k] = (uint32_t)(3 * i + k);
    }
    free(t);
    hlod_store_writer_desc wd = {0};
    wd.build.method = cubes ? HLOD_STORE_METHOD_CUBES : HLOD_STORE_METHOD_SAMPLETREE;
    wd.build.level_factor = cubes ? 0 : 13.8;
    wd.build.leaf_tris = 16;
    wd.build.c_tex = 0.5;
    wd.payload_align = HLOD_STORE_MIN_ALIGN;
    wd.logger = &g_log;
    hlod_store_writer *w = NULL;
    if (r == HLOD_OK)
        r = hlod_store_writer_open(path, &wd, &w);
    /* green leaves: the block colour */
    hlod_st_block b = {&m, NULL, {60, 150, 70, 255}};
    hlod_st_params p = {13.8, 16, 1, 0, &g_log, cubes};
    if (r == HLOD_OK)
        r = hlod_build_sampletree(&b, 1, &p, w, rep);
    else if (w)
        hlod_store_writer_abort(w);
    hlod_mesh_free(&m);
    return r;
}

static void cloud_store(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/cloud.hlod", g_dir);
    hlod_st_report rep;
    hlod_result br = build_cloud(path, 20000, 1, &rep);
    CHECKF(br == HLOD_OK, "build: %s", hlod_result_str(br));
    CHECKF(rep.tris == 20000, "stored %zu triangles of 20000", rep.tris);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (!s)
        return;
    const hlod_store_header *h = hlod_store_get_header(s);
    CHECK(h->build.method == HLOD_STORE_METHOD_CUBES && (h->flags & HLOD_STORE_ADDITIVE));
    const hlod_store_extra *x = hlod_store_extras(s);
    uint32_t n = hlod_store_node_count(s), with = 0;
    uint64_t tris = 0;
    for (uint32_t i = 0; x && i < n; i++) {
        with += (x[i].flags & HLOD_EXTRA_CUBE) != 0;
        tris += hlod_store_nodes(s)[i].tri_count;
    }
    CHECKF(with == n, "%u of %u nodes carry a cube", with, n);
    CHECKF(tris == 20000, "the nodes hold %llu triangles", (unsigned long long)tris);
    CHECKF(x && x[0].cube[0][3] > 64, "the root's +x alpha %u", x ? x[0].cube[0][3] : 0);
    printf("REPORT cloud of 20000: %u nodes, %zu levels, %zu triangles in inner nodes; root "
           "+x RGBA %u %u %u %u\n", n, rep.levels, rep.tris_inner, x ? x[0].cube[0][0] : 0,
           x ? x[0].cube[0][1] : 0, x ? x[0].cube[0][2] : 0, x ? x[0].cube[0][3] : 0);
    hlod_store_close(s);
}

/* ---- drawing ---- */

static hlod_osmesa *g_gl;
static hlod_renderer *g_r;
static const uint8_t BG[3] = {255, 0, 255};

static uint32_t g_copies; /* cube_copies of the next render */
static int g_no_splats;   /* splats = 0 (every node) */

static int render(hlod_store *s, hlod_policy pol, uint32_t cube_px, const hlod_camera *cam,
                  uint8_t *rgb, hlod_frame_stats *st)
{
    hlod_engine_desc d = {0};
    d.policy = pol;
    d.cube_px = cube_px;
    d.cube_copies = g_copies;
    d.splats = g_no_splats ? -1 : 0;
    d.renderer = g_r;
    d.deterministic = 1;
    d.memory_budget_bytes = 1ull << 32;
    d.max_inflight = 1u << 16;
    hlod_engine *e = NULL;
    if (hlod_engine_create(s, &d, &e) != HLOD_OK)
        return 0;
    int ok = hlod_engine_load_all_leaves(e, cam) == HLOD_OK &&
             hlod_engine_frame(e, cam, 1.0 / 30, st) == HLOD_OK;
    /* copies elsewhere than the store: what load_all_leaves saw from the
     * camera is not what they need; the deterministic loader reads it */
    for (int f = 0; ok && st->wanted_missing && f < 20; f++)
        ok = hlod_engine_frame(e, cam, 1.0 / 30, st) == HLOD_OK;
    ok = ok && hlod_osmesa_read_rgb(g_gl, rgb) == HLOD_OK;
    hlod_engine_destroy(e);
    return ok;
}

static int is_bg(const uint8_t *p)
{
    return p[0] == BG[0] && p[1] == BG[1] && p[2] == BG[2];
}

/* The mean absolute difference of two frames over RGB (0..255), on the
 * pixels either covers. */
static double mean_diff(const uint8_t *a, const uint8_t *b)
{
    double s = 0;
    size_t n = 0;
    for (size_t p = 0; p < (size_t)W * H; p++) {
        if (is_bg(a + 3 * p) && is_bg(b + 3 * p))
            continue;
        n++;
        for (int c = 0; c < 3; c++)
            s += abs((int)a[3 * p + c] - (int)b[3 * p + c]);
    }
    return n ? s / (3.0 * n) : 0;
}

/* The frame's colour away from the background, summed per channel: what
 * the cloud adds to the picture, partly covered pixels in proportion. */
static void ink(const uint8_t *img, double out[3])
{
    out[0] = out[1] = out[2] = 0;
    for (size_t p = 0; p < (size_t)W * H; p++)
        for (int c = 0; c < 3; c++)
            out[c] += abs((int)img[3 * p + c] - (int)BG[c]);
}

static size_t covered(const uint8_t *img)
{
    size_t n = 0;
    for (size_t p = 0; p < (size_t)W * H; p++)
        n += !is_bg(img + 3 * p);
    return n;
}

/* The cloud store cloud_store wrote (NULL, counted as a failure, when
 * it cannot be opened). */
static hlod_store *open_cloud(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/cloud.hlod", g_dir);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    return s;
}

static void far_cloud_is_cubes(void)
{
    hlod_store *s = open_cloud();
    if (!s)
        return;
    uint8_t *ref = malloc(W * H * 3), *img = malloc(W * H * 3);
    /* near: cells of many pixels; far: the leaves' cells within 2 pixels */
    const double dist[2] = {1.75, 40};
    const uint32_t px[2] = {1, 2};
    for (int k = 0; k < 2 && ref && img; k++) {
        /* dist in radii of the cloud (sqrt(3) / 2 about its centre) */
        double r = dist[k] * sqrt(3.0) / 2;
        const double at[3] = {0.5, 0.5, 0.5}, eye[3] = {0.5 + r * 0.8, 0.5 - r * 0.5, 0.5 + r * 0.33},
                     up[3] = {0, 0, 1};
        hlod_camera cam;
        CHECK(hlod_camera_look_at(&cam, eye, at, up, 60, 0.01, 100, W, H) == HLOD_OK);
        hlod_frame_stats sf, sc;
        CHECK(render(s, HLOD_POLICY_FULL, 1, &cam, ref, &sf));
        CHECK(render(s, HLOD_POLICY_CUBES, px[k], &cam, img, &sc));
        size_t cf = covered(ref), cc = covered(img);
        double md = mean_diff(ref, img), inf[3], inc[3], worst = 1;
        ink(ref, inf);
        ink(img, inc);
        for (int c = 0; c < 3; c++) {
            double q = inf[c] > 0 ? inc[c] / inf[c] : 1;
            worst = fabs(log(q)) > fabs(log(worst)) ? q : worst;
        }
        printf("REPORT %.2f radii, cube_px %u: full %llu triangles, %zu pixels; cubes %llu "
               "triangles, %u cubes, %zu pixels; colour added, cubes / full, worst channel "
               "%.3f; mean difference on the covered pixels %.1f of 255\n", dist[k], px[k],
               (unsigned long long)sf.tris_drawn, cf, (unsigned long long)sc.tris_drawn,
               sc.splats, cc, worst, md);
        if (k == 1) {
            CHECKF(sc.splats > 10, "%u cubes drawn", sc.splats);
            CHECKF(sc.tris_drawn * 10 <= sf.tris_drawn, "cubes drew %llu of full's %llu "
                   "triangles", (unsigned long long)sc.tris_drawn,
                   (unsigned long long)sf.tris_drawn);
            /* the cubes blend partly covered pixels where full covers a
             * pixel or not: the colour they add is what compares */
            CHECKF(worst > 0.75 && worst < 1.33, "cubes add %.3f of full's colour", worst);
        } else {
            CHECKF(sc.tris_drawn * 2 >= sf.tris_drawn, "near: cubes drew %llu of %llu triangles",
                   (unsigned long long)sc.tris_drawn, (unsigned long long)sf.tris_drawn);
        }
    }
    free(ref);
    free(img);
    hlod_store_close(s);
}

/* The camera from e to a, z up (y up when looking straight down), fov degrees. */
static hlod_camera look(double ex, double ey, double ez, double ax, double ay, double az,
                        double fov)
{
    const double eye[3] = {ex, ey, ez}, at[3] = {ax, ay, az};
    const double up[3] = {0, ex == ax && ey == ay ? 1 : 0, ex == ax && ey == ay ? 0 : 1};
    hlod_camera cam;
    CHECK(hlod_camera_look_at(&cam, eye, at, up, fov, 0.01, 1e4, W, H) == HLOD_OK);
    return cam;
}

static void cloud_copies(void)
{
    hlod_store *s = open_cloud();
    uint8_t *a = malloc(W * H * 3), *b = malloc(W * H * 3);
    if (!s || !a || !b) {
        free(a);
        free(b);
        hlod_store_close(s);
        return;
    }
    const hlod_store_header *h = hlod_store_get_header(s);
    double sx = h->bbox_max[0] - h->bbox_min[0], sy = h->bbox_max[1] - h->bbox_min[1];
    /* every node of 1 and of 2 x 2 copies, all in view */
    hlod_camera cam = look(1, -6, 5, 1, 1, 0.5, 60);
    hlod_frame_stats s0, s1;
    g_no_splats = 1;
    g_copies = 0;
    CHECK(render(s, HLOD_POLICY_CUBES, 1, &cam, a, &s0));
    g_copies = 1;
    CHECK(render(s, HLOD_POLICY_CUBES, 1, &cam, b, &s1));
    CHECKF(s1.tris_drawn == 4 * s0.tris_drawn && s0.tris_drawn > 0,
           "2 x 2 copies drew %llu triangles, one %llu", (unsigned long long)s1.tris_drawn,
           (unsigned long long)s0.tris_drawn);
    /* one copy in view, straight down on copy (1, 1) through a narrow
     * field: the plain image of the eye moved back by its offset */
    double cx = 0.5 * (h->bbox_min[0] + h->bbox_max[0]), cy = 0.5 * (h->bbox_min[1] + h->bbox_max[1]);
    cam = look(cx + sx, cy + sy, 3, cx + sx, cy + sy, 0, 14);
    g_copies = 1;
    CHECK(render(s, HLOD_POLICY_CUBES, 1, &cam, a, &s1));
    cam = look(cx, cy, 3, cx, cy, 0, 14);
    g_copies = 0;
    CHECK(render(s, HLOD_POLICY_CUBES, 1, &cam, b, &s0));
    double md = mean_diff(a, b);
    printf("REPORT copy (1, 1) seen alone (%llu and %llu triangles): %zu and %zu pixels covered, mean difference %.2f "
           "of 255\n", (unsigned long long)s1.tris_drawn, (unsigned long long)s0.tris_drawn, covered(a), covered(b), md);
    CHECKF(covered(a) > 1000 && md < 1, "copy (1, 1): %zu pixels, mean difference %.2f",
           covered(a), md);
    /* 8 x 8 copies far off, within 8 pixels: one block cube */
    g_no_splats = 0;
    g_copies = 3;
    cam = look(-300, -300, 300, 4 * sx, 4 * sy, 0, 60);
    CHECK(render(s, HLOD_POLICY_CUBES, 8, &cam, a, &s1));
    CHECKF(s1.splats == 1 && s1.tris_drawn == 0 && covered(a) > 0,
           "8 x 8 copies far off: %u cubes, %llu triangles, %zu pixels", s1.splats,
           (unsigned long long)s1.tris_drawn, covered(a));
    g_copies = 0;
    /* the box a viewer's far plane must reach: the copies', under cubes */
    for (int pol = 0; pol < 2; pol++) {
        hlod_engine_desc d = {0};
        d.policy = pol ? HLOD_POLICY_KLEIN : HLOD_POLICY_CUBES;
        d.cube_copies = 3;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        double lo[3], hi[3], want = pol ? 1 : 8;
        if (e) {
            hlod_engine_scene_box(e, lo, hi);
            CHECKF(fabs((hi[0] - lo[0]) - want * sx) < 1e-9 && fabs((hi[1] - lo[1]) - want * sy) < 1e-9 &&
                       lo[0] == h->bbox_min[0] && hi[2] == h->bbox_max[2],
                   "%s: scene box %g x %g, want %g x %g", pol ? "klein" : "cubes", hi[0] - lo[0],
                   hi[1] - lo[1], want * sx, want * sy);
        }
        hlod_engine_destroy(e);
    }
    free(a);
    free(b);
    hlod_store_close(s);
}

/* A budget of exactly the store's size holds all of it: every node
 * drawn from a view that sees all, loaded, none left out. */
static void exact_budget_holds_all(void)
{
    hlod_store *s = open_cloud();
    if (!s)
        return;
    hlod_engine_desc d = {0};
    d.policy = HLOD_POLICY_CUBES;
    d.splats = -1;
    d.deterministic = 1;
    d.max_inflight = 1u << 16;
    d.memory_budget_bytes = hlod_store_memory_bytes(s);
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    hlod_camera cam = look(0.5, -3, 2, 0.5, 0.5, 0.5, 60);
    hlod_frame_stats st = {0};
    for (int f = 0; e && f < 10; f++)
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
    uint32_t n = hlod_store_node_count(s), resident = 0;
    for (uint32_t i = 0; e && i < n; i++)
        resident += hlod_engine_node_state(e, i) == HLOD_NODE_RESIDENT;
    CHECKF(resident == n && st.wanted_missing == 0, "%u of %u nodes resident, %u wanted missing",
           resident, n, st.wanted_missing);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

static void policies_refuse_other_stores(void)
{
    char cubes[512], st[512];
    snprintf(cubes, sizeof cubes, "%s/cloud.hlod", g_dir);
    snprintf(st, sizeof st, "%s/st.hlod", g_dir);
    hlod_st_report rep;
    CHECK(build_cloud(st, 2000, 0, &rep) == HLOD_OK);
    hlod_store *a = NULL, *b = NULL;
    CHECK(hlod_store_open(cubes, NULL, &a) == HLOD_OK);
    CHECK(hlod_store_open(st, NULL, &b) == HLOD_OK);
    if (!a || !b) {
        hlod_store_close(a);
        hlod_store_close(b);
        return;
    }
    hlod_engine_desc d = {0};
    hlod_engine *e = NULL;
    /* a sample tree carries no cubes */
    d.policy = HLOD_POLICY_CUBES;
    CHECK(hlod_engine_create(b, &d, &e) == HLOD_ERR_INVALID_ARG && !e);
    /* colour cubes carry colours too: klein draws them as splats */
    d.policy = HLOD_POLICY_KLEIN;
    CHECK(hlod_engine_create(a, &d, &e) == HLOD_OK && e);
    hlod_engine_destroy(e);
    e = NULL;
    d.policy = HLOD_POLICY_LAKHIA;
    CHECK(hlod_engine_create(a, &d, &e) == HLOD_ERR_INVALID_ARG && !e);
    hlod_store_close(a);
    hlod_store_close(b);
}

/* ---- cubes as stand-ins (far_cubes) ---- */

static hlod_store *fixture_store(const char *name, int cubes, int textured)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", g_dir, name);
    fixture_opts o = {.roots = 4, .depth = 3, .grid = 4, .size = 100, .cubes = cubes,
                      .textured = textured};
    hlod_store *s = NULL;
    if (fixture_write(path, &o, NULL) != HLOD_OK || hlod_store_open(path, NULL, &s) != HLOD_OK)
        return NULL;
    return s;
}

static void payload_cubes(void)
{
    hlod_store *a = fixture_store("plain.hlod", 0, 0), *b = fixture_store("fc.hlod", 1, 0),
               *t = fixture_store("fct.hlod", 1, 1);
    CHECK(a && b && t);
    if (a && b && t) {
        uint32_t n = hlod_store_node_count(b);
        const hlod_store_node *na = hlod_store_nodes(a), *nb = hlod_store_nodes(b);
        const hlod_store_extra *xa = hlod_store_extras(a), *xb = hlod_store_extras(b),
                               *xt = hlod_store_extras(t);
        CHECK(n == hlod_store_node_count(a) && xb && xt);
        uint32_t with_a = 0, with_b = 0, same_payload = 0;
        for (uint32_t i = 0; i < n && xb; i++) {
            with_a += xa && (xa[i].flags & HLOD_EXTRA_CUBE) != 0;
            with_b += (xb[i].flags & HLOD_EXTRA_CUBE) != 0;
            same_payload += na[i].payload_hash == nb[i].payload_hash;
        }
        CHECKF(with_b == n && with_a == 0, "cubes on %u and %u of %u nodes", with_b, with_a, n);
        CHECKF(same_payload == n, "%u of %u payloads the same bytes", same_payload, n);
        /* the fixture's node: a flat square facing +z, vertex colour
         * (60 + 40 level, 120, 200) */
        int ok_col = 1;
        for (uint32_t i = 0; i < n && xb; i++) {
            const uint8_t *up = xb[i].cube[4], *down = xb[i].cube[5], *side = xb[i].cube[0];
            int want[3] = {60 + 40 * (int)nb[i].depth, 120, 200};
            for (int c = 0; c < 3; c++)
                ok_col &= abs(up[c] - want[c]) <= 1 && abs(down[c] - want[c]) <= 1;
            ok_col &= up[3] == 255 && down[3] == 255 && side[3] == 0;
            if (!ok_col) {
                CHECKF(0, "node %u (depth %u): +z %u %u %u %u, -z alpha %u, +x alpha %u", i,
                       nb[i].depth, up[0], up[1], up[2], up[3], down[3], side[3]);
                break;
            }
        }
        /* textured: the 4 x 4 checker's mean, (135, 120, 128) */
        const uint8_t *up = xt ? xt[0].cube[4] : NULL;
        CHECKF(up && abs(up[0] - 135) <= 4 && abs(up[1] - 120) <= 4 && abs(up[2] - 128) <= 4 &&
               up[3] == 255, "textured +z face %u %u %u %u", up ? up[0] : 0, up ? up[1] : 0,
               up ? up[2] : 0, up ? up[3] : 0);
    }
    hlod_store_close(a);
    hlod_store_close(b);
    hlod_store_close(t);
}

/* Policy lakhia from above at distance `dist`: frame `frames` of a still
 * camera, deterministic; *deep gets the nodes at depth >= 2 that were
 * ever resident. */
static int far_frames(hlod_store *s, int far_cubes, uint32_t cube_px, double dist, int frames,
                      uint8_t *rgb, hlod_frame_stats *st, uint32_t *deep)
{
    hlod_engine_desc d = {0};
    d.policy = HLOD_POLICY_LAKHIA;
    d.far_cubes = far_cubes ? 1 : -1;
    d.cube_px = cube_px;
    d.renderer = g_r;
    d.deterministic = 1;
    d.target_ms = 1000;
    d.memory_budget_bytes = 1ull << 32;
    hlod_engine *e = NULL;
    if (hlod_engine_create(s, &d, &e) != HLOD_OK)
        return 0;
    const double at[3] = {200, 50, 0}, eye[3] = {200, 50 - 0.2 * dist, dist}, up[3] = {0, 0, 1};
    hlod_camera cam;
    int ok = hlod_camera_look_at(&cam, eye, at, up, 60, 1, 10 * dist, W, H) == HLOD_OK;
    const hlod_store_node *n = hlod_store_nodes(s);
    *deep = 0;
    uint8_t *seen = calloc(hlod_store_node_count(s), 1);
    for (int f = 0; ok && seen && f < frames; f++) {
        ok = hlod_engine_frame(e, &cam, 1.0 / 30, st) == HLOD_OK;
        for (uint32_t i = 0; i < hlod_store_node_count(s); i++)
            if (n[i].depth >= 2 && hlod_engine_node_state(e, i) == HLOD_NODE_RESIDENT && !seen[i]) {
                seen[i] = 1;
                (*deep)++;
            }
    }
    ok = ok && seen && hlod_osmesa_read_rgb(g_gl, rgb) == HLOD_OK;
    free(seen);
    hlod_engine_destroy(e);
    return ok;
}

static void far_cubes_stand_in(void)
{
    hlod_store *a = fixture_store("plain.hlod", 0, 0), *b = fixture_store("fc.hlod", 1, 0);
    uint8_t *ref = malloc(W * H * 3), *img = malloc(W * H * 3);
    CHECK(a && b && ref && img);
    if (a && b && ref && img) {
        /* at 600 m a root (100 m) is about 35 px wide, a depth-2 node 9:
         * within cube_px 12 the nodes from depth 2 down are cubes */
        hlod_frame_stats sm, sc;
        uint32_t deep_m = 0, deep_c = 0;
        CHECK(far_frames(a, 0, 12, 600, 20, ref, &sm, &deep_m));
        CHECK(far_frames(b, 1, 12, 600, 20, img, &sc, &deep_c));
        size_t cm = covered(ref), cc = covered(img);
        double md = mean_diff(ref, img);
        printf("REPORT far_cubes at 600 m, cube_px 12: meshes %llu triangles, %u nodes, %zu "
               "pixels, %u nodes of depth >= 2 read; cubes %llu triangles, %u nodes, %u cubes, "
               "%zu pixels, %u read; mean difference on the covered pixels %.1f of 255\n",
               (unsigned long long)sm.tris_drawn, sm.nodes_drawn, cm, deep_m,
               (unsigned long long)sc.tris_drawn, sc.nodes_drawn, sc.splats, cc, deep_c, md);
        CHECKF(sm.splats == 0 && deep_m > 0, "without far_cubes: %u cubes, %u deep nodes read",
               sm.splats, deep_m);
        CHECKF(sc.splats >= 16 && deep_c == 0, "far_cubes: %u cubes, %u deep nodes read",
               sc.splats, deep_c);
        CHECKF(cc * 10 >= cm * 9 && cc * 10 <= cm * 11, "covered %zu pixels against %zu", cc, cm);
        CHECKF(md < 16, "mean difference %.1f of 255", md);
        if (check_failures_) {
            char p1[600], p2[600];
            snprintf(p1, sizeof p1, "%s/far_meshes.ppm", g_dir);
            snprintf(p2, sizeof p2, "%s/far_cubes.ppm", g_dir);
            for (int k = 0; k < 2; k++) {
                FILE *fp = fopen(k ? p2 : p1, "wb");
                if (fp) {
                    fprintf(fp, "P6\n%d %d\n255\n", W, H);
                    fwrite(k ? img : ref, 1, (size_t)W * H * 3, fp);
                    fclose(fp);
                }
            }
        }
    }
    free(ref);
    free(img);
    hlod_store_close(a);
    hlod_store_close(b);
}

static void far_cubes_refused(void)
{
    char st[512];
    snprintf(st, sizeof st, "%s/cloud.hlod", g_dir);
    hlod_store *a = fixture_store("plain.hlod", 0, 0), *c = NULL;
    CHECK(a && hlod_store_open(st, NULL, &c) == HLOD_OK);
    hlod_engine_desc d = {0};
    hlod_engine *e = NULL;
    d.far_cubes = 1;
    d.policy = HLOD_POLICY_LAKHIA;
    if (a)
        CHECK(hlod_engine_create(a, &d, &e) == HLOD_ERR_INVALID_ARG && !e);
    d.policy = HLOD_POLICY_CUBES; /* additive: its cubes are its own */
    if (c)
        CHECK(hlod_engine_create(c, &d, &e) == HLOD_ERR_INVALID_ARG && !e);
    hlod_store_close(a);
    hlod_store_close(c);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod_test_cubes_XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(covered_and_empty_faces);
    RUN(composite_matches_direct);
    RUN(cloud_store);
    RUN(policies_refuse_other_stores);
    RUN(payload_cubes);
    RUN(far_cubes_refused);
    if (hlod_osmesa_create(W, H, NULL, &g_gl) == HLOD_OK &&
        hlod_renderer_create(hlod_osmesa_get_proc(), NULL, &g_r) == HLOD_OK) {
        hlod_renderer_set_clear_color(g_r, 1, 0, 1);
        RUN(far_cloud_is_cubes);
        RUN(far_cubes_stand_in);
        RUN(cloud_copies);
        RUN(exact_budget_holds_all);
    } else {
        CHECK(0); /* OSMesa is installed by the test command */
    }
    hlod_renderer_destroy(g_r);
    hlod_osmesa_destroy(g_gl);
    if (check_failures_ == 0)
        check_sh("rm -rf '%s'", g_dir);
    return check_done();
}
