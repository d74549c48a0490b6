/*
 * lumi_bake.c - one Grid-Lumigraph view rendered into a repository
 * (lumi_bake.h).
 */
#include "lumi_bake.h"

#include "atomic_file.h"
#include "cli.h"
#include "gl_render.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The grid's box: `box` (lo[3], hi[3]) when given, else the model's box
 * about its centre, twice as large in each axis (an axis under a tenth of
 * the widest counts as a tenth).  The clip planes: 0.001 and 1.01 x the
 * diagonal of the box and the model's together, so every view reaches
 * the whole model. */
static void grid_box(const hlod_store_header *h, const double *box, double lo[3], double hi[3],
                     double *near_plane, double *far_plane)
{
    double half[3], widest = 0, diag = 0;
    for (int k = 0; k < 3; k++) {
        half[k] = 0.5 * (h->bbox_max[k] - h->bbox_min[k]);
        widest = fmax(widest, half[k]);
    }
    if (!(widest > 0))
        widest = 1;
    for (int k = 0; k < 3; k++) {
        double c = 0.5 * (h->bbox_max[k] + h->bbox_min[k]);
        double e = 2 * fmax(half[k], 0.1 * widest);
        lo[k] = box ? box[k] : c - e;
        hi[k] = box ? box[3 + k] : c + e;
        double u = fmax(hi[k], h->bbox_max[k]) - fmin(lo[k], h->bbox_min[k]);
        diag += u * u;
    }
    diag = sqrt(diag);
    *near_plane = 1e-3 * diag;
    *far_plane = 1.01 * diag;
}

/* Window depth (24 bits scaled to 32) to 16-bit codes, rows flipped to
 * top first, each depth_size block keeping its nearest; 1 when anything
 * was drawn. */
static int depth_codes(lumi_baker *b)
{
    const hlod_lumi_index *ix = &b->ix;
    uint32_t s = ix->size, ds = ix->depth_size, k = s / ds;
    double n = ix->near_plane, f = ix->far_plane;
    int any = 0;
    for (size_t i = 0; i < (size_t)ds * ds; i++)
        b->depth[i] = HLOD_LUMI_DEPTH_NONE;
    for (uint32_t y = 0; y < s; y++)
        for (uint32_t x = 0; x < s; x++) {
            uint32_t w = b->window_depth[(size_t)(s - 1 - y) * s + x];
            if (w >= 0xFFFFFF00u)
                continue; /* the far plane: nothing drawn */
            double zn = 2.0 * ((double)w / 4294967295.0) - 1.0;
            double z = 2.0 * n * f / ((f + n) - zn * (f - n));
            uint16_t q = hlod_lumi_depth_quant(z, n, f);
            uint16_t *d = &b->depth[(size_t)(y / k) * ds + x / k];
            if (q < *d)
                *d = q;
            any = 1;
        }
    return any;
}

/* Renders, encodes and writes view id; its state into the index. */
int lumi_baker_view(lumi_baker *b, uint32_t id, const char *repo)
{
    uint32_t x, y, z, d;
    hlod_lumi_view_key(&b->ix, id, &x, &y, &z, &d);
    double eye[3], fwd[3], up[3], right[3], at[3];
    hlod_lumi_point(&b->ix, x, y, z, eye);
    hlod_lumi_face(d, fwd, up, right);
    for (int k = 0; k < 3; k++)
        at[k] = eye[k] + fwd[k];
    hlod_camera cam;
    hlod_frame_stats st;
    uint32_t s = b->ix.size;
    if (hlod_camera_look_at(&cam, eye, at, up, 90, b->ix.near_plane, b->ix.far_plane, s, s) != HLOD_OK ||
        hlod_engine_load_all_leaves(b->engine, &cam) != HLOD_OK ||
        hlod_engine_frame(b->engine, &cam, 0, &st) != HLOD_OK ||
        hlod_gpu_read_depth(b->renderer, s, s, b->window_depth) != HLOD_OK ||
        hlod_osmesa_read_rgb(b->gl, b->rgb) != HLOD_OK) {
        hlod_cli_error(b->prog, "%s: cannot render view (%u, %u, %u, %u)", b->store_path, x, y, z, d);
        return 0;
    }
    if (st.load_failures || st.bad_nodes) {
        hlod_cli_error(b->prog, "%s: nodes could not be read for view (%u, %u, %u, %u)", b->store_path,
                       x, y, z, d);
        return 0;
    }
    if (!depth_codes(b)) {
        b->ix.state[id] = HLOD_LUMI_EMPTY;
        return 1;
    }
    uint8_t *buf;
    size_t n;
    if (hlod_lumi_view_encode(&b->ix, id, b->rgb, b->depth, &buf, &n) != HLOD_OK) {
        hlod_cli_error(b->prog, "%s: cannot encode view (%u, %u, %u, %u)", repo, x, y, z, d);
        return 0;
    }
    char rel[128], path[4200], dir[4200];
    hlod_lumi_view_path(&b->ix, id, rel, sizeof rel);
    snprintf(path, sizeof path, "%s/%s", repo, rel);
    snprintf(dir, sizeof dir, "%s/views/%u", repo, x);
    int ok = hlod_mkdir_p(dir, 0777) == 0;
    hlod_atomic_file af;
    if (ok && hlod_atomic_open(&af, path, &b->lg) == HLOD_OK) {
        ok = fwrite(buf, 1, n, af.fp) == n;
        if (!ok)
            hlod_atomic_abort(&af);
        ok = ok && hlod_atomic_commit(&af, &b->lg) == HLOD_OK;
    } else {
        ok = 0;
    }
    free(buf);
    if (!ok) {
        hlod_cli_error(b->prog, "%s: cannot write the view: %s", path, strerror(errno));
        return 0;
    }
    b->ix.state[id] = HLOD_LUMI_BAKED;
    return 1;
}

int lumi_baker_open(lumi_baker *b, const char *prog, const char *store, hlod_logger lg,
                    uint32_t grid, uint32_t size, uint32_t depth_size, uint32_t quality,
                    const double *box)
{
    memset(b, 0, sizeof *b);
    b->prog = prog;
    b->store_path = store;
    b->lg = lg;
    if (hlod_store_open(store, &b->lg, &b->store) != HLOD_OK)
        return 0;
    const hlod_store_header *h = hlod_store_get_header(b->store);
    double lo[3], hi[3], n, f;
    grid_box(h, box, lo, hi, &n, &f);
    if (hlod_lumi_index_init(&b->ix, grid, size, depth_size, quality, lo, hi, n, f,
                             h->node_table_hash) != HLOD_OK) {
        hlod_cli_error(prog, "%s: cannot lay a grid over its box", store);
        return 0;
    }
    b->rgb = malloc((size_t)size * size * 3);
    b->window_depth = malloc((size_t)size * size * 4);
    b->depth = malloc((size_t)depth_size * depth_size * 2);
    if (!b->rgb || !b->window_depth || !b->depth) {
        hlod_cli_error(prog, "out of memory for %ux%u views", size, size);
        return 0;
    }
    if (hlod_osmesa_create(size, size, &b->lg, &b->gl) != HLOD_OK ||
        hlod_renderer_create(hlod_osmesa_get_proc(), &b->lg, &b->renderer) != HLOD_OK) {
        hlod_cli_error(prog, "cannot set up headless OpenGL (OSMesa, GL 3.3) at %ux%u", size, size);
        return 0;
    }
    hlod_engine_desc d = {0};
    d.policy = HLOD_POLICY_FULL;
    d.renderer = b->renderer;
    d.logger = b->lg;
    d.deterministic = 1; /* no loader thread: load_all_leaves reads */
    d.memory_budget_bytes = UINT64_MAX / 4;
    if (hlod_engine_create(b->store, &d, &b->engine) != HLOD_OK) {
        hlod_cli_error(prog, "%s: cannot start the engine", store);
        return 0;
    }
    return 1;
}

int lumi_same_shape(const hlod_lumi_index *a, const hlod_lumi_index *b)
{
    return a->grid == b->grid && a->size == b->size && a->depth_size == b->depth_size &&
           a->quality == b->quality && a->store_id == b->store_id &&
           !memcmp(a->box_min, b->box_min, sizeof a->box_min) &&
           !memcmp(a->box_max, b->box_max, sizeof a->box_max) &&
           a->near_plane == b->near_plane && a->far_plane == b->far_plane;
}

void lumi_baker_close(lumi_baker *b)
{
    if (b->gl) /* current on this thread (a server made it on another) */
        hlod_osmesa_make_current(b->gl);
    hlod_engine_destroy(b->engine);
    hlod_renderer_destroy(b->renderer);
    hlod_osmesa_destroy(b->gl);
    hlod_store_close(b->store);
    hlod_lumi_index_free(&b->ix);
    free(b->rgb);
    free(b->window_depth);
    free(b->depth);
}

/* Bytes of the baked views in repo (and the largest). */
