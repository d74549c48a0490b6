/*
 * test_lumigraph.c - Okamoto's Grid-Lumigraph (docs/lumigraph.md): the
 * repository's codecs refuse damaged bytes; at a grid point looking along
 * an axis the client's image is the baked view; a view whose point was
 * occluded contributes nothing; a second look from the same place fetches
 * nothing; a vanished repository leaves the client drawing from its cache
 * without waiting, and it recovers when the repository returns.
 */
#include "check.h"
#include "hlod/engine.h"
#include "hlod/image.h"
#include "hlod/lumigraph.h"
#include "hlod/metrics.h"
#include "hlod/renderer.h"
#include "hlod/store.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#define S 128 /* the views' and the client's side */

static char bin[1024], tmp[1024], city_repo[1200], boxes_repo[1200];
static hlod_osmesa *g_gl;
static hlod_renderer *g_r;
static hlod_store *g_city, *g_boxes;

static void save(const char *name, const uint8_t *rgb)
{
    char p[2048];
    snprintf(p, sizeof p, "%s/%s.png", tmp, name);
    hlod_image img = {S, S, 3, (uint8_t *)rgb};
    if (hlod_image_write(p, &img, NULL) == HLOD_OK)
        fprintf(stderr, "  wrote %s\n", p);
}

/* ---- codecs ---- */

static void codecs_refuse_damage(void)
{
    hlod_lumi_index ix;
    const double lo[3] = {-1, -2, -3}, hi[3] = {1, 2, 3};
    CHECK(hlod_lumi_index_init(&ix, 3, 16, 8, 80, lo, hi, 0.01, 10, 42) == HLOD_OK);
    ix.state[5] = HLOD_LUMI_BAKED;
    ix.state[7] = HLOD_LUMI_EMPTY;
    uint8_t *b;
    size_t n;
    CHECK(hlod_lumi_index_encode(&ix, &b, &n) == HLOD_OK);
    hlod_lumi_index back;
    CHECK(hlod_lumi_index_decode(b, n, "ix", NULL, &back) == HLOD_OK);
    CHECK(back.grid == 3 && back.views == ix.views && back.state[5] == HLOD_LUMI_BAKED &&
          back.state[7] == HLOD_LUMI_EMPTY && back.store_id == 42 && back.box_max[2] == 3);
    hlod_lumi_index_free(&back);
    CHECK(hlod_lumi_index_decode(b, n - 1, "ix", NULL, &back) == HLOD_ERR_FORMAT);
    b[HLOD_LUMI_INDEX_HEAD + 9] ^= 1;
    CHECK(hlod_lumi_index_decode(b, n, "ix", NULL, &back) == HLOD_ERR_CHECKSUM);
    b[HLOD_LUMI_INDEX_HEAD + 9] ^= 1;
    b[4] = 9;
    CHECK(hlod_lumi_index_decode(b, n, "ix", NULL, &back) == HLOD_ERR_VERSION);
    free(b);

    /* a view: round trip, then a flipped byte, a short file, another id */
    uint8_t rgb[16 * 16 * 3];
    uint16_t depth[8 * 8];
    for (int i = 0; i < 16 * 16 * 3; i++)
        rgb[i] = (uint8_t)(i * 7);
    for (int i = 0; i < 64; i++)
        depth[i] = (uint16_t)(i * 1000);
    CHECK(hlod_lumi_view_encode(&ix, 5, rgb, depth, &b, &n) == HLOD_OK);
    hlod_lumi_view v;
    CHECK(hlod_lumi_view_decode(&ix, 5, b, n, "v", NULL, &v) == HLOD_OK);
    CHECK(v.depth && !memcmp(v.depth, depth, sizeof depth));
    hlod_lumi_view_free(&v);
    CHECK(hlod_lumi_view_decode(&ix, 6, b, n, "v", NULL, &v) == HLOD_ERR_FORMAT);
    CHECK(hlod_lumi_view_decode(&ix, 5, b, n - 3, "v", NULL, &v) == HLOD_ERR_FORMAT);
    b[n - 2] ^= 0x40;
    CHECK(hlod_lumi_view_decode(&ix, 5, b, n, "v", NULL, &v) == HLOD_ERR_CHECKSUM);
    CHECK(!v.rgb && !v.depth);
    free(b);

    /* depth codes keep their order and round trip within a step */
    double prev = 0;
    for (double z = 0.02; z < 10; z *= 1.37) {
        uint16_t q = hlod_lumi_depth_quant(z, 0.01, 10);
        double back_z = hlod_lumi_depth_value(q, 0.01, 10);
        CHECK(fabs(back_z - z) <= 2e-4 * z && back_z > prev);
        prev = back_z;
    }
    hlod_lumi_index_free(&ix);
}

/* ---- the client ---- */

static hlod_engine *client(hlod_store *s, const char *repo, double tol)
{
    hlod_engine_desc d = {0};
    d.policy = HLOD_POLICY_LUMIGRAPH;
    d.lumigraph_repo = repo;
    d.renderer = g_r;
    d.lumi_mesh_px = 0.5; /* the leaves: the tests judge the views, not the mesh */
    d.lumi_tol = tol;
    d.lumi_uploads = 4;
    d.memory_budget_bytes = 1ull << 30;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    return e;
}

/* Frames at cam until nothing is missing (views and nodes), 10 s at most;
 * the last frame's stats in *st, its image in rgb. */
static int settle(hlod_engine *e, const hlod_camera *cam, hlod_frame_stats *st, uint8_t *rgb,
                  uint32_t *waits)
{
    for (int k = 0; k < 1000; k++) {
        if (hlod_engine_frame(e, cam, 1.0 / 30, st) != HLOD_OK)
            return 0;
        *waits += st->render_waits;
        if (k > 2 && !st->lumi_missing && !st->wanted_missing && !st->lumi_uploads)
            return hlod_osmesa_read_rgb(g_gl, rgb) == HLOD_OK;
        nanosleep(&(struct timespec){0, 10000000}, NULL);
    }
    return 0;
}

static void axis_camera(const hlod_lumi_index *ix, uint32_t id, hlod_camera *cam)
{
    uint32_t x, y, z, d;
    double eye[3], f[3], u[3], r[3], at[3];
    hlod_lumi_view_key(ix, id, &x, &y, &z, &d);
    hlod_lumi_point(ix, x, y, z, eye);
    hlod_lumi_face(d, f, u, r);
    for (int k = 0; k < 3; k++)
        at[k] = eye[k] + f[k];
    CHECK(hlod_camera_look_at(cam, eye, at, u, 90, 0.05, 5000, S, S) == HLOD_OK);
}

/* At every baked view of a middle grid point, looking along its axis, the
 * client draws the view itself (issue: PSNR >= 38 dB). */
static void grid_point_is_its_view(void)
{
    hlod_lumi_index ix;
    CHECK(hlod_lumi_index_load(city_repo, NULL, &ix) == HLOD_OK);
    hlod_engine *e = client(g_city, city_repo, 0.05);
    if (!e || !ix.state) {
        hlod_lumi_index_free(&ix);
        return;
    }
    uint8_t *img = malloc(S * S * 3);
    int tested = 0;
    uint32_t waits = 0, mid = ix.grid / 2;
    for (uint32_t d = 0; d < HLOD_LUMI_FACES; d++) {
        uint32_t id = hlod_lumi_view_id(&ix, mid, mid, mid, d);
        if (ix.state[id] != HLOD_LUMI_BAKED)
            continue;
        hlod_camera cam;
        axis_camera(&ix, id, &cam);
        hlod_frame_stats st;
        CHECK(settle(e, &cam, &st, img, &waits));
        char rel[128];
        uint8_t *buf = NULL;
        size_t n;
        hlod_lumi_view v = {0};
        hlod_lumi_view_path(&ix, id, rel, sizeof rel);
        CHECK(hlod_lumi_fetch(city_repo, rel, 1 << 24, NULL, &buf, &n) == HLOD_OK);
        CHECK(buf && hlod_lumi_view_decode(&ix, id, buf, n, rel, NULL, &v) == HLOD_OK);
        double db = 0;
        CHECK(v.rgb && hlod_psnr_rgb8(img, v.rgb, S, S, &db) == HLOD_OK);
        CHECKF(db >= 38, "view %u: client %.2f dB against the baked view", id, db);
        if (db < 38) {
            save("grid_point_client", img);
            save("grid_point_view", v.rgb);
        }
        tested++;
        hlod_lumi_view_free(&v);
        free(buf);
    }
    CHECKF(tested >= 3, "only %d baked views at the middle point", tested);
    CHECK(waits == 0);
    free(img);
    hlod_engine_destroy(e);
    hlod_lumi_index_free(&ix);
}

/* The two-box fixture: a green wall at x = 20 and a red post at x in
 * [10, 12], y in [-3.5, -1.5].  Its grid (G = 3) has points at x = 5, 15,
 * 25, y = -20, 0, 20, z = -5, 5, 15.  From the eye at (5, 10, 5) the wall
 * point W = (20, -6, 5) is in sight; from the grid point (5, 0, 5), one of
 * the eye's two weighted points, the post hides it.  Returns W's pixel's
 * colour. */
static int wall_pixel(double tol, uint8_t out[3])
{
    hlod_engine *e = client(g_boxes, boxes_repo, tol);
    if (!e)
        return 0;
    double eye[3] = {5, 10, 5}, at[3] = {20, -6, 5}, up[3] = {0, 0, 1};
    hlod_camera cam;
    CHECK(hlod_camera_look_at(&cam, eye, at, up, 60, 0.05, 500, S, S) == HLOD_OK);
    uint8_t *img = malloc(S * S * 3);
    hlod_frame_stats st;
    uint32_t waits = 0;
    int ok = settle(e, &cam, &st, img, &waits);
    CHECK(ok);
    if (ok) { /* W is the centre of the image; a 3x3 mean */
        double c[3] = {0, 0, 0};
        for (int y = S / 2 - 1; y <= S / 2 + 1; y++)
            for (int x = S / 2 - 1; x <= S / 2 + 1; x++)
                for (int k = 0; k < 3; k++)
                    c[k] += img[(y * S + x) * 3 + k] / 9.0;
        for (int k = 0; k < 3; k++)
            out[k] = (uint8_t)c[k];
        save(tol < 1 ? "occluded_view" : "occluded_view_blind", img);
    }
    free(img);
    hlod_engine_destroy(e);
    return ok;
}

static void occluded_view_contributes_nothing(void)
{
    uint8_t tested[3], blind[3];
    if (!wall_pixel(0.05, tested) || !wall_pixel(10, blind))
        return;
    fprintf(stderr, "  wall pixel %u %u %u with the depth test, %u %u %u without\n", tested[0],
            tested[1], tested[2], blind[0], blind[1], blind[2]);
    /* the occluded point's view holds the post's red there */
    CHECKF(tested[0] < 40 && tested[1] > 100, "the wall is not green: %u %u %u", tested[0],
           tested[1], tested[2]);
    CHECKF(blind[0] > tested[0] + 40, "without the test the post's red should show: %u %u %u", blind[0],
           blind[1], blind[2]);
}

/* Settled at one place, a second look fetches nothing; with the
 * repository gone the client draws from what it holds without waiting,
 * and a place it lacks views for fills in once the repository is back. */
static void cache_and_outage(void)
{
    char copy[1400], gone[1400];
    snprintf(copy, sizeof copy, "%s/city_copy", tmp);
    snprintf(gone, sizeof gone, "%s/city_gone", tmp);
    CHECK(check_sh("cp -r '%s' '%s'", city_repo, copy) == 0);
    hlod_lumi_index ix;
    CHECK(hlod_lumi_index_load(copy, NULL, &ix) == HLOD_OK);
    hlod_engine *e = client(g_city, copy, 0.05);
    if (!e || !ix.state) {
        hlod_lumi_index_free(&ix);
        return;
    }
    uint8_t *img = malloc(S * S * 3);
    hlod_frame_stats st;
    uint32_t waits = 0, mid = ix.grid / 2;
    hlod_camera a, b;
    axis_camera(&ix, hlod_lumi_view_id(&ix, mid, mid, mid, 0), &a);
    axis_camera(&ix, hlod_lumi_view_id(&ix, 0, 0, ix.grid - 1, 5), &b);
    CHECK(settle(e, &a, &st, img, &waits));
    uint64_t again = 0;
    for (int k = 0; k < 20; k++) {
        CHECK(hlod_engine_frame(e, &a, 1.0 / 30, &st) == HLOD_OK);
        again += st.lumi_bytes;
        waits += st.render_waits;
    }
    CHECKF(again == 0, "%llu bytes fetched again at the same place", (unsigned long long)again);
    /* the repository vanishes: b's views cannot come */
    CHECK(rename(copy, gone) == 0);
    uint32_t missing = 0;
    for (int k = 0; k < 40; k++) {
        CHECK(hlod_engine_frame(e, &b, 1.0 / 30, &st) == HLOD_OK);
        missing = st.lumi_missing;
        waits += st.render_waits;
        nanosleep(&(struct timespec){0, 5000000}, NULL);
    }
    CHECKF(missing > 0, "views at the new place came from nowhere");
    CHECK(rename(gone, copy) == 0);
    CHECK(settle(e, &b, &st, img, &waits));
    CHECK(st.lumi_missing == 0);
    CHECKF(waits == 0, "%u render waits", waits);
    free(img);
    hlod_engine_destroy(e);
    hlod_lumi_index_free(&ix);
}

/* A repository of another store, or a damaged index: the engine refuses
 * it at create, naming the file. */
static void bad_repositories_refused(void)
{
    hlod_engine_desc d = {0};
    d.policy = HLOD_POLICY_LUMIGRAPH;
    d.lumigraph_repo = boxes_repo; /* baked from the boxes */
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(g_city, &d, &e) == HLOD_ERR_FORMAT && !e);
    char bad[1400];
    snprintf(bad, sizeof bad, "%s/bad_repo", tmp);
    CHECK(check_sh("mkdir -p '%s' && head -c 100 '%s/repo.hlg' > '%s/repo.hlg'", bad, city_repo,
                   bad) == 0);
    d.lumigraph_repo = bad;
    CHECK(hlod_engine_create(g_city, &d, &e) == HLOD_ERR_FORMAT && !e);
    d.lumigraph_repo = NULL;
    CHECK(hlod_engine_create(g_city, &d, &e) == HLOD_ERR_INVALID_ARG && !e);
}

/* The bake: an interrupted one goes on to the same bytes; shards merge
 * into the same repository. */
static void bake_resumes_and_merges(void)
{
    char one[1400];
    snprintf(one, sizeof one, "%s/again", tmp);
    /* a bake cut off: the views of x = 0 and 1 neither in the index nor on disk */
    CHECK(check_sh("rm -rf '%s' && cp -r '%s' '%s' && rm -rf '%s/views/0' '%s/views/1'", one,
                   city_repo, one, one, one) == 0);
    hlod_lumi_index ix;
    CHECK(hlod_lumi_index_load(one, NULL, &ix) == HLOD_OK);
    uint32_t cut = 0;
    for (uint32_t id = 0; ix.state && id < ix.views; id++) {
        uint32_t x, y, z, d;
        hlod_lumi_view_key(&ix, id, &x, &y, &z, &d);
        if (x < 2 && ix.state[id] != HLOD_LUMI_MISSING) {
            ix.state[id] = HLOD_LUMI_MISSING;
            cut++;
        }
    }
    CHECK(cut > 10 && hlod_lumi_index_save(one, &ix, NULL) == HLOD_OK);
    hlod_lumi_index_free(&ix);
    CHECK(check_sh("'%s/hlod-lumigraph-bake' '%s/city.hlod' -o '%s' --grid 3 --size %d --quiet && "
                   "diff -r '%s' '%s'", bin, tmp, one, S, city_repo, one) == 0);
    /* two shards merged: the same repository */
    CHECK(check_sh("rm -rf '%s' && '%s/hlod-lumigraph-bake' '%s/city.hlod' -o '%s/s1' --grid 3 "
                   "--size %d --shard 1/2 --quiet && '%s/hlod-lumigraph-bake' '%s/city.hlod' -o "
                   "'%s/s2' --grid 3 --size %d --shard 2/2 --quiet && '%s/hlod-lumigraph-bake' "
                   "--merge -o '%s' '%s/s1' '%s/s2' && diff -r '%s' '%s'", one, bin, tmp, tmp, S,
                   bin, tmp, tmp, S, bin, one, tmp, tmp, city_repo, one) == 0);
    /* other parameters into the same folder: refused, nothing changed */
    CHECK(check_sh("'%s/hlod-lumigraph-bake' '%s/city.hlod' -o '%s' --grid 4 --size %d --quiet "
                   "2>/dev/null", bin, tmp, one, S) != 0);
    CHECK(check_sh("diff -r '%s' '%s'", city_repo, one) == 0);
}

static int write_boxes(const char *dir)
{
    char p[1400];
    snprintf(p, sizeof p, "%s/boxes.mtl", dir);
    FILE *fp = fopen(p, "w");
    if (!fp)
        return 0;
    fprintf(fp, "newmtl wall\nKd 0.1 0.9 0.1\nnewmtl post\nKd 0.9 0.1 0.1\n");
    fclose(fp);
    snprintf(p, sizeof p, "%s/boxes.obj", dir);
    fp = fopen(p, "w");
    if (!fp)
        return 0;
    fprintf(fp, "mtllib boxes.mtl\n");
    /* boxes as 8 corners and 12 triangles, outward */
    const double box[2][6] = {{20, -10, 0, 21, 10, 10}, {10, -3.5, 0, 12, -1.5, 10}};
    const char *mtl[2] = {"wall", "post"};
    for (int b = 0; b < 2; b++) {
        const double *q = box[b];
        for (int c = 0; c < 8; c++)
            fprintf(fp, "v %g %g %g\n", q[(c & 1) ? 3 : 0], q[(c & 2) ? 4 : 1], q[(c & 4) ? 5 : 2]);
        /* an object each: two blocks */
        fprintf(fp, "o %s\nusemtl %s\n", mtl[b], mtl[b]);
        const int f[12][3] = {{1, 3, 2}, {1, 2, 0}, {4, 6, 7}, {4, 7, 5}, {0, 4, 5}, {0, 5, 1},
                              {2, 3, 7}, {2, 7, 6}, {0, 2, 6}, {0, 6, 4}, {1, 5, 7}, {1, 7, 3}};
        for (int t = 0; t < 12; t++)
            fprintf(fp, "f %d %d %d\n", 8 * b + f[t][0] + 1, 8 * b + f[t][1] + 1,
                    8 * b + f[t][2] + 1);
    }
    fclose(fp);
    return 1;
}

int main(void)
{
    const char *b = getenv("HLOD_BIN_DIR");
    snprintf(bin, sizeof bin, "%s", b ? b : "build/bin");
    snprintf(tmp, sizeof tmp, "/tmp/hlod-test-lumigraph-%ld", (long)getpid());
    snprintf(city_repo, sizeof city_repo, "%s/city_repo", tmp);
    snprintf(boxes_repo, sizeof boxes_repo, "%s/boxes_repo", tmp);
    check_sh("rm -rf '%s' && mkdir -p '%s'", tmp, tmp);
    RUN_UNTHREADED(codecs_refuse_damage);
    int ok = write_boxes(tmp) &&
             check_sh("'%s/hlod-gen-city' --preset tiny -o '%s/city.obj' --quiet", bin, tmp) == 0 &&
             check_sh("'%s/hlod-build' '%s/city.obj' -o '%s/city.hlod' --desired-tris 300 --quiet",
                      bin, tmp, tmp) == 0 &&
             check_sh("'%s/hlod-build' '%s/boxes.obj' -o '%s/boxes.hlod' --quiet", bin, tmp, tmp) == 0 &&
             check_sh("'%s/hlod-lumigraph-bake' '%s/city.hlod' -o '%s' --grid 3 --size %d --quiet",
                      bin, tmp, city_repo, S) == 0 &&
             check_sh("'%s/hlod-lumigraph-bake' '%s/boxes.hlod' -o '%s' --grid 3 --size %d --quiet",
                      bin, tmp, boxes_repo, S) == 0;
    CHECK(ok);
    char p[2048];
    snprintf(p, sizeof p, "%s/city.hlod", tmp);
    CHECK(ok && hlod_store_open(p, NULL, &g_city) == HLOD_OK);
    snprintf(p, sizeof p, "%s/boxes.hlod", tmp);
    CHECK(ok && hlod_store_open(p, NULL, &g_boxes) == HLOD_OK);
    CHECK(hlod_osmesa_create(S, S, NULL, &g_gl) == HLOD_OK);
    CHECK(g_gl && hlod_renderer_create(hlod_osmesa_get_proc(), NULL, &g_r) == HLOD_OK);
    if (g_city && g_boxes && g_r) {
        RUN(grid_point_is_its_view);
        RUN(occluded_view_contributes_nothing);
        RUN(cache_and_outage);
        RUN(bad_repositories_refused);
        RUN_UNTHREADED(bake_resumes_and_merges);
    }
    hlod_renderer_destroy(g_r);
    hlod_osmesa_destroy(g_gl);
    hlod_store_close(g_city);
    hlod_store_close(g_boxes);
    if (check_failures_ == 0)
        check_sh("rm -rf '%s'", tmp);
    return check_done();
}
