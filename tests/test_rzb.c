/*
 * test_rzb.c - Wand's randomized z-buffer (engine/rzb.h, docs/rzb.md):
 * - the sampler: 10 faces of unequal area (one class), 10^5 picks, as a
 *   frame makes them and one by one, pass a chi-square test against area
 *   (p >= 0.01); picks uniform over the faces fail it;
 * - a point is uniform over its face (chi-square over the four halved
 *   sub-triangles) and lies on it;
 * - every face with an area is held once; classes keep areas within 4x;
 * - a flat board of 819k faces filling a 160x120 view, rzb at d = 1 and 2
 *   leaves at most 3 pixels uncovered (the paper: about 1), every face
 *   sampled, none rasterised; the same seed gives the same points;
 * - with every face large, rzb rasterises them all and draws the image
 *   policy full draws (PSNR >= 40 dB);
 * - faces seen from behind, one-sided, give no point;
 * - a replay (the machine's jitter) samples the frame's view again: the
 *   same points and image;
 * - copies (Wand 7.3): a block of 2 x 2 copies draws the image of the
 *   store twice as wide (faces rasterised, 40 dB); a 2 x 2 block seen from
 *   above is sampled as one box, its points spread over the copies
 *   uniformly (chi-square) and covering the view but for about a pixel a
 *   frame (at most 10 in 4 frames), and from the block's cache in the
 *   next frame with a third of the points or fewer; 4^20
 *   and 4^24 copies seen over the horizon (the eye scaled with them) take
 *   no more boxes than 4^10: the walk grows with the picture, not with
 *   the copies.
 */
#include "check.h"
#include "engine_internal.h"
#include "rzb.h"
#include "store_fixture.h"

#include "hlod/engine.h"
#include "hlod/metrics.h"
#include "hlod/renderer.h"
#include "hlod/store.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define W 160
#define H 120

static char g_dir[256];
static hlod_osmesa *g_gl;
static hlod_renderer *g_r;
static const hlod_allocator g_alloc; /* malloc */

/* Ten faces in the plane z = 0 with areas 1.0, 1.2, ... 2.8 (one class),
 * added as one one-sided leaf. */
static hlod_rzb *ten_faces(double *area)
{
    float pos[30 * 3];
    uint32_t idx[30];
    for (int t = 0; t < 10; t++) {
        area[t] = 1.0 + 0.2 * t;
        double x0 = 10.0 * t, w = 2 * area[t]; /* base w, height 1 */
        float v[3][3] = {{(float)x0, 0, 0}, {(float)(x0 + w), 0, 0}, {(float)x0, 1, 0}};
        memcpy(pos + 9 * t, v, sizeof v);
        for (int k = 0; k < 3; k++)
            idx[3 * t + k] = (uint32_t)(3 * t + k);
    }
    hlod_store_node n = {0};
    n.render_flags = HLOD_RENDER_SOLID;
    hlod_store_payload p = {0};
    p.vertex_count = 30;
    p.index_count = 30;
    p.positions = pos;
    p.indices = idx;
    hlod_rzb *z = hlod_rzb_create(&g_alloc);
    CHECK(z && hlod_rzb_add(z, &n, 0, &p) == HLOD_OK && hlod_rzb_finish(z) == HLOD_OK);
    return z;
}

static double chi2_of(const uint32_t *count, const double *want, int k)
{
    double c = 0;
    for (int j = 0; j < k; j++)
        c += (count[j] - want[j]) * (count[j] - want[j]) / want[j];
    return c;
}

static void picks_follow_area(void)
{
    double area[10];
    hlod_rzb *z = ten_faces(area);
    if (!z)
        return;
    CHECK(hlod_rzb_class_count(z) == 1 && hlod_rzb_class_size(z, 0) == 10);
    /* the class array is in octree order: map its faces back by area */
    double total = 0, want[10];
    for (uint32_t t = 0; t < 10; t++)
        total += hlod_rzb_area(z, 0, t);
    const uint32_t n = 100000;
    for (uint32_t t = 0; t < 10; t++)
        want[t] = n * hlod_rzb_area(z, 0, t) / total;
    uint32_t *pick = malloc(n * sizeof *pick), strat[10] = {0}, indep[10] = {0}, unif[10] = {0};
    CHECK(pick != NULL);
    if (!pick)
        return;
    hlod_rzb_picks(z, 0, 0, 10, 7, n, pick);
    uint64_t s = 12345;
    for (uint32_t i = 0; i < n; i++) {
        strat[pick[i]]++;
        s = s * 6364136223846793005ull + 1442695040888963407ull;
        double u = (double)(s >> 11) / 9007199254740992.0;
        indep[hlod_rzb_pick(z, 0, 0, 10, u)]++;
        unif[(uint32_t)(u * 10)]++;
    }
    double c_strat = chi2_of(strat, want, 10), c_indep = chi2_of(indep, want, 10),
           c_unif = chi2_of(unif, want, 10);
    printf("REPORT sampler: chi2 %.3f (a frame's picks), %.2f (independent picks), %.0f "
           "(uniform over faces); p >= 0.01 below 21.67 at 9 dof\n", c_strat, c_indep, c_unif);
    /* 9 degrees of freedom: p >= 0.01 is chi2 <= 21.666 */
    CHECKF(c_strat <= 21.666, "a frame's picks: chi2 %.3f", c_strat);
    CHECKF(c_indep <= 21.666, "independent picks: chi2 %.3f", c_indep);
    CHECKF(c_unif > 1000, "uniform picks pass as area-weighted: chi2 %.1f", c_unif);
    free(pick);
    hlod_rzb_destroy(z);
}

/* Points of one face: on it, and as many in each of its four halved
 * sub-triangles (equal areas). */
static void points_are_uniform_on_the_face(void)
{
    double area[10];
    hlod_rzb *z = ten_faces(area);
    if (!z)
        return;
    /* face 0 of the class, whichever it is: its corners from three points */
    double a[3], b[3], c[3];
    hlod_rzb_point(z, 0, 0, 0, 0, a); /* u1 = 0: corner 0 */
    hlod_rzb_point(z, 0, 0, 1, 0, b); /* u1 = 1, u2 = 0: corner 1 */
    hlod_rzb_point(z, 0, 0, 1, 1, c); /* corner 2 */
    uint32_t count[4] = {0};
    int off = 0;
    uint64_t s = 99;
    const uint32_t n = 40000;
    for (uint32_t i = 0; i < n; i++) {
        double u[2], p[3];
        for (int k = 0; k < 2; k++) {
            s = s * 6364136223846793005ull + 1442695040888963407ull;
            u[k] = (double)(s >> 11) / 9007199254740992.0;
        }
        hlod_rzb_point(z, 0, 0, u[0], u[1], p);
        /* barycentric coordinates in the plane z = 0 */
        double d = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
        double l1 = ((p[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (p[1] - a[1])) / d;
        double l2 = ((b[0] - a[0]) * (p[1] - a[1]) - (p[0] - a[0]) * (b[1] - a[1])) / d;
        double l0 = 1 - l1 - l2;
        off += l0 < -1e-9 || l1 < -1e-9 || l2 < -1e-9 || fabs(p[2]) > 1e-9;
        /* the corner triangles of the midpoint split, else the middle one */
        count[l0 > 0.5 ? 0 : l1 > 0.5 ? 1 : l2 > 0.5 ? 2 : 3]++;
    }
    double want[4] = {n / 4.0, n / 4.0, n / 4.0, n / 4.0};
    double chi2 = chi2_of(count, want, 4);
    printf("REPORT points: chi2 %.3f over the four sub-triangles (p >= 0.01 below 11.34), %d "
           "off the face\n", chi2, off);
    CHECKF(off == 0, "%d points off their face", off);
    CHECKF(chi2 <= 11.345, "points not uniform on the face: chi2 %.3f", chi2);
    hlod_rzb_destroy(z);
}

/* A camera looking straight down at (cx, cy) from height h. */
static void down_camera(hlod_camera *cam, double cx, double cy, double h)
{
    const double eye[3] = {cx, cy, h}, at[3] = {cx, cy, 0}, up[3] = {0, 1, 0};
    CHECK(hlod_camera_look_at(cam, eye, at, up, 60, 0.1, 1e4, W, H) == HLOD_OK);
}

/* One frame of store `path` under policy pol, splat size d (rzb: points
 * splatted in C, or GL points), into rgb. */
static uint32_t g_copies; /* rzb_copies of the next render_as */

static int render_as(const char *path, hlod_policy pol, uint32_t d, int splat_c,
                     const hlod_camera *cam, uint8_t *rgb, hlod_frame_stats *st)
{
    hlod_store *s = NULL;
    if (hlod_store_open(path, NULL, &s) != HLOD_OK)
        return 0;
    hlod_engine_desc desc = {0};
    desc.policy = pol;
    desc.renderer = g_r;
    desc.deterministic = 1;
    desc.splat_px = d;
    desc.rzb_splat_c = splat_c ? 1 : -1; /* a flag: 0 would be the default */
    desc.rzb_copies = g_copies;
    desc.memory_budget_bytes = 1ull << 32;
    hlod_engine *e = NULL;
    int ok = hlod_engine_create(s, &desc, &e) == HLOD_OK &&
             (pol != HLOD_POLICY_FULL || hlod_engine_load_all_leaves(e, cam) == HLOD_OK) &&
             hlod_engine_frame(e, cam, 1.0 / 30, st) == HLOD_OK &&
             hlod_osmesa_read_rgb(g_gl, rgb) == HLOD_OK;
    hlod_engine_destroy(e);
    hlod_store_close(s);
    return ok;
}

static int render(const char *path, hlod_policy pol, uint32_t d, const hlod_camera *cam,
                  uint8_t *rgb, hlod_frame_stats *st)
{
    return render_as(path, pol, d, 1, cam, rgb, st);
}

static int is_bg(const uint8_t *p)
{
    return p[0] == 255 && p[1] == 0 && p[2] == 255;
}

/* The background pixels of a frame read back. */
static size_t count_bg(const uint8_t *img)
{
    size_t n = 0;
    for (size_t p = 0; p < W * H; p++)
        n += is_bg(img + 3 * p);
    return n;
}

/* fine_board_is_covered's store, opened (NULL on failure, checked). */
static hlod_store *open_fine(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/fine.hlod", g_dir);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    return s;
}

/* The fine board and the view from above that it fills (*cam); NULL,
 * counted as a failure, when the store cannot be opened. */
static hlod_store *open_fine_view(hlod_camera *cam)
{
    down_camera(cam, 5e6 + 50, 50, 50);
    return open_fine();
}

/* An rzb engine's description over the test renderer, deterministic. */
static hlod_engine_desc rzb_desc(void)
{
    hlod_engine_desc desc = {0};
    desc.policy = HLOD_POLICY_RZB;
    desc.renderer = g_r;
    desc.deterministic = 1;
    return desc;
}

/* The board (4 roots of 100 m side by side along x) seen from above fills
 * the view: 64 leaves a root of 80 x 80 quads, 0.05 px^2 a face. */
static void fine_board_is_covered(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/fine.hlod", g_dir);
    fixture_opts o = {.roots = 1, .depth = 3, .grid = 80, .size = 100};
    o.origin[0] = 5e6; /* far from the world origin, as a city may be */
    CHECK(fixture_write(path, &o, NULL) == HLOD_OK);
    hlod_camera cam;
    down_camera(&cam, 5e6 + 50, 50, 50);
    uint8_t *img = malloc(W * H * 3), *again = malloc(W * H * 3), *gl = malloc(W * H * 3);
    CHECK(img && again && gl);
    const uint32_t sizes[2] = {1, 2};
    for (int k = 0; k < 2 && img && again && gl; k++) {
        for (int c = 0; c < 2; c++) {
            hlod_frame_stats st, st2;
            uint8_t *out = c ? img : gl;
            CHECK(render_as(path, HLOD_POLICY_RZB, sizes[k], c, &cam, out, &st));
            size_t holes = count_bg(out);
            printf("REPORT d = %u, %s: %u points, %llu faces rasterised, %zu of %d pixels "
                   "uncovered\n", sizes[k], c ? "C splatter" : "GL points", st.splats,
                   (unsigned long long)st.tris_drawn, holes, W * H);
            CHECKF(holes <= 3, "d = %u, splat_c %d: %zu pixels uncovered", sizes[k], c, holes);
            CHECKF(st.splats > 1000 && st.tris_drawn == 0,
                   "d = %u: %u points, %llu faces rasterised", sizes[k], st.splats,
                   (unsigned long long)st.tris_drawn);
            CHECK(render_as(path, HLOD_POLICY_RZB, sizes[k], c, &cam, again, &st2));
            CHECKF(st2.splats == st.splats && memcmp(out, again, W * H * 3) == 0,
                   "d = %u, splat_c %d: the same frame drew another image", sizes[k], c);
        }
        /* the same points: the C splatter's pixels are GL's */
        double psnr = 0;
        CHECK(hlod_psnr_rgb8(img, gl, W, H, &psnr) == HLOD_OK);
        printf("REPORT d = %u: the C splatter's image %.1f dB from GL points'\n", sizes[k], psnr);
        CHECKF(psnr >= 40, "d = %u: C splatter %.1f dB from GL points", sizes[k], psnr);
    }
    free(img);
    free(again);
    free(gl);
}

/* The points one frame of desc draws from cam without sample caches
 * (checked; 0 on failure). */
static uint64_t fresh_points(const hlod_store *s, hlod_engine_desc desc, const hlod_camera *cam)
{
    desc.rzb_cache_mb = 0;
    hlod_engine *e = NULL;
    hlod_frame_stats st;
    CHECK(hlod_engine_create(s, &desc, &e) == HLOD_OK);
    CHECK(e && hlod_engine_frame(e, cam, 1.0 / 30, &st) == HLOD_OK);
    uint64_t n = e ? e->rzb_out.samples : 0;
    hlod_engine_destroy(e);
    return n;
}

/* A replay (hlod_engine_replay: the machine's jitter) samples the last
 * frame's view again with its seed: the same points, the same image, and
 * the frame's counts unchanged. */
static void replay_draws_the_same_points(void)
{
    hlod_camera cam;
    hlod_store *s = open_fine_view(&cam);
    if (!s)
        return;
    hlod_engine_desc desc = rzb_desc();
    hlod_engine *e = NULL;
    hlod_frame_stats st;
    uint8_t *a = malloc(W * H * 3), *b = malloc(W * H * 3);
    CHECK(a && b && hlod_engine_create(s, &desc, &e) == HLOD_OK);
    if (e && a && b) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        CHECK(hlod_osmesa_read_rgb(g_gl, a) == HLOD_OK);
        uint64_t samples = e->rzb_out.samples;
        double ms = 0;
        CHECK(hlod_engine_replay(e, &cam, 1, &ms) == HLOD_OK);
        CHECK(hlod_osmesa_read_rgb(g_gl, b) == HLOD_OK);
        printf("REPORT replay: %llu points again (frame: %llu), images %s, %.1f ms\n",
               (unsigned long long)e->rzb_out.samples, (unsigned long long)samples,
               memcmp(a, b, W * H * 3) ? "differ" : "equal", ms);
        CHECKF(e->rzb_out.samples == samples && memcmp(a, b, W * H * 3) == 0,
               "replay: %llu points against %llu, images %s", (unsigned long long)e->rzb_out.samples,
               (unsigned long long)samples, memcmp(a, b, W * H * 3) ? "differ" : "equal");
    }
    hlod_engine_destroy(e);
    hlod_store_close(s);
    free(a);
    free(b);
}

/* With sample caches, a second frame from the same view draws every point
 * from them, far fewer than fresh (one a cell instead of ln v a pixel),
 * and still covers the board but for a few pixels (a point sits at its
 * cell's centre, up to half a cell off the surface). */
static void caches_serve_the_next_frame(void)
{
    hlod_camera cam;
    hlod_store *s = open_fine_view(&cam);
    if (!s)
        return;
    hlod_engine_desc desc = rzb_desc();
    hlod_engine *e = NULL;
    hlod_frame_stats st;
    uint64_t fresh = fresh_points(s, desc, &cam);
    desc.rzb_cache_mb = 64;
    uint8_t *img = malloc(W * H * 3);
    CHECK(img && hlod_engine_create(s, &desc, &e) == HLOD_OK);
    for (int k = 0; k < 2 && e && img; k++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        const hlod_rzb_out *o = &e->rzb_out;
        if (k == 0) {
            CHECKF(o->cache_fills > 0, "frame 1 made %u caches", o->cache_fills);
            continue;
        }
        CHECK(hlod_osmesa_read_rgb(g_gl, img) == HLOD_OK);
        size_t holes = count_bg(img);
        printf("REPORT caches: frame 2 drew %llu points from %zu bytes of caches (%u made "
               "again), fresh points %llu; %zu of %d pixels uncovered\n",
               (unsigned long long)o->samples, o->cache_bytes, o->cache_fills,
               (unsigned long long)fresh, holes, W * H);
        CHECKF(o->cache_fills == 0 && o->cache_points == o->samples && o->samples > 1000,
               "frame 2: %u caches made, %llu of %llu points from caches", o->cache_fills,
               (unsigned long long)o->cache_points, (unsigned long long)o->samples);
        CHECKF(3 * o->samples < fresh, "cached points %llu, fresh %llu",
               (unsigned long long)o->samples, (unsigned long long)fresh);
        CHECKF(holes <= W * H / 200, "from caches: %zu pixels uncovered", holes);
    }
    /* a smaller limit drops the least recently drawn */
    if (e) {
        hlod_rzb_set_cache(e->rzb, 1 << 10);
        CHECKF(hlod_rzb_cache_bytes(e->rzb) <= (1 << 10), "caches at %zu bytes over a 1 KiB limit",
               hlod_rzb_cache_bytes(e->rzb));
    }
    hlod_engine_destroy(e);
    hlod_store_close(s);
    free(img);
}

/* Large faces (a 4 x 4 grid a leaf) are rasterised, all of them: the
 * image is full's. */
static void large_faces_draw_as_full(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/coarse.hlod", g_dir);
    fixture_opts o = {.roots = 1, .depth = 1, .grid = 4, .size = 100};
    CHECK(fixture_write(path, &o, NULL) == HLOD_OK);
    hlod_camera cam;
    down_camera(&cam, 50, 50, 40);
    uint8_t *a = malloc(W * H * 3), *b = malloc(W * H * 3);
    hlod_frame_stats sa, sb;
    CHECK(a && b && render(path, HLOD_POLICY_FULL, 1, &cam, a, &sa) &&
          render(path, HLOD_POLICY_RZB, 1, &cam, b, &sb));
    double psnr = 0;
    if (a && b)
        CHECK(hlod_psnr_rgb8(a, b, W, H, &psnr) == HLOD_OK);
    printf("REPORT large faces: rzb rasterised %llu faces in %u draws, %u points; %.1f dB "
           "against full (%llu faces)\n", (unsigned long long)sb.tris_drawn, sb.nodes_drawn,
           sb.splats, psnr, (unsigned long long)sa.tris_drawn);
    CHECKF(sb.splats == 0 && sb.tris_drawn >= 2 * 4 * 4, "rzb: %u points, %llu faces", sb.splats,
           (unsigned long long)sb.tris_drawn);
    CHECKF(psnr >= 40, "rzb's image %.1f dB from full's", psnr);
    free(a);
    free(b);
}

/* One-sided faces seen from behind give no point; two-sided ones do. */
static void back_faces_give_no_point(void)
{
    for (int solid = 0; solid < 2; solid++) {
        enum { G = 200 };
        float *pos = malloc(sizeof(float) * 3 * (G + 1) * (G + 1));
        uint32_t *idx = malloc(sizeof(uint32_t) * 6 * G * G);
        CHECK(pos && idx);
        if (!pos || !idx)
            return;
        for (int j = 0; j <= G; j++)
            for (int i = 0; i <= G; i++) {
                float *v = pos + 3 * (j * (G + 1) + i);
                v[0] = (float)i / 2;
                v[1] = (float)j / 2;
                v[2] = 0;
            }
        grid_quads(idx, G, G);
        hlod_store_node n = {0};
        n.render_flags = solid ? HLOD_RENDER_SOLID : 0;
        hlod_store_payload p = {0};
        p.vertex_count = (G + 1) * (G + 1);
        p.index_count = 6 * G * G;
        p.positions = pos;
        p.indices = idx;
        hlod_rzb *z = hlod_rzb_create(&g_alloc);
        CHECK(z && hlod_rzb_add(z, &n, 0, &p) == HLOD_OK && hlod_rzb_finish(z) == HLOD_OK);
        CHECK(hlod_rzb_tri_count(z) == 2 * G * G);
        /* from below the plane (it faces +z), far: every face small */
        hlod_camera cam;
        const double eye[3] = {50, 50, -2000}, at[3] = {50, 50, 0}, up[3] = {0, 1, 0};
        CHECK(hlod_camera_look_at(&cam, eye, at, up, 60, 0.1, 1e5, W, H) == HLOD_OK);
        double still[3] = {0, 0, 0};
        hlod_view v;
        hlod_view_init(&v, &cam, still, 0);
        hlod_rzb_out out = {0};
        hlod_rzb_params prm = {.eps = 1.4, .d = 1, .seed = 1, .frame = 1};
        CHECK(hlod_rzb_frame(z, &v, &prm, &out) == HLOD_OK);
        printf("REPORT from behind, %s: %llu points drawn, %zu kept\n",
               solid ? "one-sided" : "two-sided", (unsigned long long)out.samples,
               out.splat_count);
        CHECK(out.samples > 100 && out.range_count == 0);
        if (solid)
            CHECKF(out.splat_count == 0, "one-sided: %zu points kept from behind", out.splat_count);
        else
            CHECKF(out.splat_count == out.samples, "two-sided: %zu of %llu kept", out.splat_count,
                   (unsigned long long)out.samples);
        hlod_rzb_out_free(&g_alloc, &out);
        hlod_rzb_destroy(z);
        free(pos);
        free(idx);
    }
}

/* 2 x 2 copies of a textured block of 100 m (leaves of 50 m, 4 x 4 quads)
 * against one block of 200 m built with the same leaves: seen from 60 m,
 * every face rasterised, the same image. */
static void copies_draw_the_wider_store(void)
{
    char one[512], wide[512];
    snprintf(one, sizeof one, "%s/copy1.hlod", g_dir);
    snprintf(wide, sizeof wide, "%s/copy2.hlod", g_dir);
    fixture_opts o1 = {.roots = 1, .depth = 1, .grid = 4, .size = 100, .textured = 1};
    fixture_opts o2 = {.roots = 1, .depth = 2, .grid = 4, .size = 200, .textured = 1};
    CHECK(fixture_write(one, &o1, NULL) == HLOD_OK && fixture_write(wide, &o2, NULL) == HLOD_OK);
    hlod_camera cam;
    const double eye[3] = {130, 60, 60}, at[3] = {100, 110, 0}, up[3] = {0, 0, 1};
    CHECK(hlod_camera_look_at(&cam, eye, at, up, 60, 0.1, 1e4, W, H) == HLOD_OK);
    uint8_t *a = malloc(W * H * 3), *b = malloc(W * H * 3);
    hlod_frame_stats sa, sb;
    g_copies = 1;
    CHECK(a && b && render(one, HLOD_POLICY_RZB, 1, &cam, a, &sa));
    g_copies = 0;
    CHECK(a && b && render(wide, HLOD_POLICY_RZB, 1, &cam, b, &sb));
    double psnr = 0;
    if (a && b)
        CHECK(hlod_psnr_rgb8(a, b, W, H, &psnr) == HLOD_OK);
    size_t bg = a ? count_bg(a) : W * H;
    printf("REPORT 2 x 2 copies: %llu faces rasterised in %u draws, %u points; %.1f dB against "
           "the store twice as wide (%llu faces); %zu background pixels\n",
           (unsigned long long)sa.tris_drawn, sa.nodes_drawn, sa.splats, psnr,
           (unsigned long long)sb.tris_drawn, bg);
    CHECKF(sa.splats == 0 && sa.tris_drawn > 128, "copies: %u points, %llu faces", sa.splats,
           (unsigned long long)sa.tris_drawn);
    CHECKF(bg < W * H / 2, "copies: %zu background pixels", bg);
    CHECKF(psnr >= 40, "copies' image %.1f dB from the wide store's", psnr);
    free(a);
    free(b);
}

/* The fine board (100 m, at x = 5e6) as 2 x 2 copies seen from 125 m
 * above their middle (the view within them): one block, sampled as one
 * box; its points are spread over the 4 copies as their areas say
 * (chi-square, 3 degrees of freedom) and cover the view. */
static void copies_sample_as_one_box(void)
{
    hlod_store *s = open_fine();
    if (!s)
        return;
    hlod_camera cam;
    down_camera(&cam, 5e6 + 100, 100, 125);
    uint8_t *img = malloc(W * H * 3);
    for (int splat_c = 0; splat_c < 2 && img; splat_c++) {
        hlod_engine_desc desc = rzb_desc();
        desc.rzb_copies = 1;
        desc.rzb_splat_c = splat_c ? 1 : -1;
        hlod_engine *e = NULL;
        hlod_frame_stats st;
        CHECK(hlod_engine_create(s, &desc, &e) == HLOD_OK);
        CHECK(e && hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        if (!e)
            break;
        const hlod_rzb_out *o = &e->rzb_out;
        CHECKF(o->boxes_sampled == 1 && o->boxes_drawn == 0 && o->range_count == 0,
               "%u boxes sampled, %u rasterised", o->boxes_sampled, o->boxes_drawn);
        if (!splat_c) {
            /* GL points: each point's copy from its position */
            uint32_t count[4] = {0};
            size_t outside = 0;
            for (size_t k = 0; k < o->splat_count; k++) {
                double x = cam.position[0] + o->splats[k].pos[0] - 5e6,
                       y = cam.position[1] + o->splats[k].pos[1];
                /* (a point's position is a float relative to the eye:
                 * within a centimetre of the edge is on it) */
                long i = (long)floor(x / 100), j = (long)floor(y / 100);
                if (x < -0.01 || x > 200.01 || y < -0.01 || y > 200.01)
                    outside++;
                else
                    count[2 * (j < 0 ? 0 : j > 1 ? 1 : j) + (i < 0 ? 0 : i > 1 ? 1 : i)]++;
            }
            double want[4];
            for (int q = 0; q < 4; q++)
                want[q] = (double)(o->splat_count - outside) / 4;
            double c2 = chi2_of(count, want, 4);
            printf("REPORT 2 x 2 copies, one box: %zu points, chi2 over the copies %.2f (p >= "
                   "0.01 below 11.34 at 3 dof), %zu outside them\n", o->splat_count, c2,
                   outside);
            CHECKF(outside == 0 && o->splat_count > 10000, "%zu points, %zu outside the copies",
                   o->splat_count, outside);
            CHECKF(c2 <= 11.345, "points over the copies: chi2 %.2f", c2);
        } else {
            /* each copy drawn independently: a pixel is missed with
             * probability e^-(ln v), about 1 a frame (Poisson); over 4
             * frames at most 10 (P(more) = 0.3 %) */
            size_t holes = 0, worst = 0;
            for (int fr = 0; fr < 4; fr++) {
                if (fr)
                    CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
                CHECK(hlod_osmesa_read_rgb(g_gl, img) == HLOD_OK);
                size_t h = count_bg(img);
                holes += h;
                worst = h > worst ? h : worst;
            }
            printf("REPORT 2 x 2 copies, C splatter: %u points a frame, %zu of %d pixels "
                   "uncovered in 4 frames (at most %zu in one)\n", st.splats, holes, W * H, worst);
            CHECKF(holes <= 10, "copies: %zu pixels uncovered in 4 frames", holes);
        }
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
    free(img);
}

/* A block of copies keeps its points too: the 2 x 2 copies' frame 2 draws
 * them all from the block's cache, far fewer than fresh, and covers the
 * view as a range's cache does. */
static void copies_serve_from_caches(void)
{
    hlod_store *s = open_fine();
    if (!s)
        return;
    hlod_camera cam;
    down_camera(&cam, 5e6 + 100, 100, 125);
    hlod_engine_desc desc = rzb_desc();
    desc.rzb_copies = 1;
    hlod_engine *e = NULL;
    hlod_frame_stats st;
    uint64_t fresh = fresh_points(s, desc, &cam);
    desc.rzb_cache_mb = 64;
    uint8_t *img = malloc(W * H * 3);
    CHECK(img && hlod_engine_create(s, &desc, &e) == HLOD_OK);
    uint64_t first = 0;
    for (int k = 0; k < 2 && e && img; k++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        const hlod_rzb_out *o = &e->rzb_out;
        if (k == 0) {
            CHECKF(o->cache_fills == 1 && o->boxes_sampled == 1, "frame 1: %u caches made, %u boxes",
                   o->cache_fills, o->boxes_sampled);
            first = o->cache_bytes;
            continue;
        }
        CHECK(hlod_osmesa_read_rgb(g_gl, img) == HLOD_OK);
        size_t holes = count_bg(img);
        printf("REPORT 2 x 2 copies from the block's cache: frame 2 drew %llu points from %zu "
               "bytes (fresh: %llu); %zu of %d pixels uncovered\n",
               (unsigned long long)o->samples, o->cache_bytes, (unsigned long long)fresh, holes,
               W * H);
        CHECKF(o->cache_fills == 0 && o->cache_points == o->samples && o->cache_bytes == first,
               "frame 2: %u caches made, %llu of %llu points from caches", o->cache_fills,
               (unsigned long long)o->cache_points, (unsigned long long)o->samples);
        CHECKF(o->samples > 1000 && 3 * o->samples < fresh, "cached points %llu, fresh %llu",
               (unsigned long long)o->samples, (unsigned long long)fresh);
        CHECKF(holes <= W * H / 200, "from the block's cache: %zu pixels uncovered", holes);
    }
    hlod_engine_destroy(e);
    hlod_store_close(s);
    free(img);
}

/* 2^levels x 2^levels copies of the fine board seen from a low eye over
 * the horizon, the eye's height and distances scaled with the copies (the
 * same picture, as in Wand Fig. 6): the boxes walked follow the picture,
 * not the copies (a walk over copies would take 4^10 times more at 20). */
static uint32_t horizon_boxes(hlod_rzb *z, uint32_t levels, uint64_t *points)
{
    double k = ldexp(1.0, (int)levels - 4);
    hlod_camera cam;
    const double eye[3] = {5e6 + 40 * k, 40 * k, 10 * k}, at[3] = {5e6 + 400 * k, 400 * k, 0},
                 up[3] = {0, 0, 1};
    CHECK(hlod_camera_look_at(&cam, eye, at, up, 60, 0.1 * k, 1e4 * k, W, H) == HLOD_OK);
    double still[3] = {0, 0, 0};
    hlod_view v;
    hlod_view_init(&v, &cam, still, 0);
    hlod_rzb_out out = {0};
    hlod_rzb_params prm = {.eps = 1.4, .d = 2, .seed = 1, .frame = 1, .splat_c = 0};
    CHECK(hlod_rzb_set_copies(z, levels) == HLOD_OK);
    CHECK(hlod_rzb_frame(z, &v, &prm, &out) == HLOD_OK);
    *points = out.samples;
    uint32_t boxes = out.boxes_sampled + out.boxes_drawn;
    hlod_rzb_out_free(&g_alloc, &out);
    return boxes;
}

static void copies_walk_grows_with_levels(void)
{
    hlod_store *s = open_fine();
    if (!s)
        return;
    hlod_engine_desc desc = {0};
    desc.policy = HLOD_POLICY_RZB;
    desc.deterministic = 1;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &desc, &e) == HLOD_OK);
    if (e) {
        uint64_t p10, p20, p40;
        uint32_t b10 = horizon_boxes(e->rzb, 10, &p10), b20 = horizon_boxes(e->rzb, 20, &p20),
                 b40 = horizon_boxes(e->rzb, 24, &p40);
        printf("REPORT copies over the horizon: 4^10 copies %u boxes (%llu points), 4^20 %u "
               "(%llu), 4^24 %u (%llu)\n", b10, (unsigned long long)p10, b20,
               (unsigned long long)p20, b40, (unsigned long long)p40);
        CHECKF(b10 > 10 && b20 < 3 * b10 && b40 < 4 * b10,
               "boxes %u, %u, %u at 10, 20, 24 levels", b10, b20, b40);
        CHECKF(p20 < 4 * p10 && p10 < 4 * p20, "points %llu at 10 levels, %llu at 20",
               (unsigned long long)p10, (unsigned long long)p20);
        CHECK(hlod_rzb_set_copies(e->rzb, HLOD_RZB_MAX_COPY_LEVELS + 1) == HLOD_ERR_INVALID_ARG);
    }
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod_test_rzb_XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(picks_follow_area);
    RUN(points_are_uniform_on_the_face);
    RUN(back_faces_give_no_point);
    if (hlod_osmesa_create(W, H, NULL, &g_gl) == HLOD_OK &&
        hlod_renderer_create(hlod_osmesa_get_proc(), NULL, &g_r) == HLOD_OK) {
        hlod_renderer_set_clear_color(g_r, 1, 0, 1);
        RUN(fine_board_is_covered);
        RUN(caches_serve_the_next_frame);
        RUN(replay_draws_the_same_points);
        RUN(large_faces_draw_as_full);
        RUN(copies_draw_the_wider_store);
        RUN(copies_sample_as_one_box);
        RUN(copies_serve_from_caches);
        RUN(copies_walk_grows_with_levels);
    } else {
        CHECK(0); /* OSMesa is installed by the test command */
    }
    hlod_renderer_destroy(g_r);
    hlod_osmesa_destroy(g_gl);
    if (check_failures_ == 0)
        check_sh("rm -rf '%s'", g_dir);
    return check_done();
}
