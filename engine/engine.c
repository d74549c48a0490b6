/*
 * engine.c - the engine object and its frame (README, "The runtime").
 *
 * A frame, on the render thread:
 *   1. collect finished loads and upload them (residency.c);
 *   2. select the nodes to draw (traverse.c) with the budget
 *      c_targetTime - fixed_ms;
 *   3. draw them at (origin - camera), computed in double (gl_render.c), and
 *      wait for the GPU so the measured time covers the whole frame;
 *   4. fit the cost model to the measured time;
 *   5. admit wanted nodes against the memory budget and hand the loader its
 *      new queue (residency.c).
 *
 * Cost model.  A frame costs a fixed part (clear, fill, swap,
 * traversal) plus a part proportional to the drawn cost; feeding back only
 * v_time would make it swallow the fixed part and misprice every node.  We
 * fit  measured_ms = fixed_ms + v_time * drawn_cost  by exponentially
 * weighted least squares (forgetting factor 0.93: about 14 frames of memory,
 * so it follows a change within a few frames without chasing one noisy
 * frame), with a small ridge holding v_time when the drawn cost does not
 * vary (see fit_cost_model).  Both outputs are clamped to sane ranges.
 */
#include "engine_internal.h"

#include <assert.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define FORGET 0.93
#define RIDGE 0.05

/* ---- allocation ---- */

void *hlod_engine_alloc(hlod_engine *e, size_t size)
{
    const hlod_allocator *a = &e->d.allocator;
    return a->alloc ? a->alloc(a->user_data, size) : malloc(size);
}

void *hlod_engine_realloc(hlod_engine *e, void *p, size_t size)
{
    const hlod_allocator *a = &e->d.allocator;
    return a->realloc ? a->realloc(a->user_data, p, size) : realloc(p, size);
}

void hlod_engine_free(hlod_engine *e, void *p)
{
    const hlod_allocator *a = &e->d.allocator;
    if (!p)
        return;
    if (a->free)
        a->free(a->user_data, p);
    else
        free(p);
}

static int grow(hlod_engine *e, void **v, size_t *cap, size_t need, size_t elem)
{
    if (need <= *cap)
        return 1;
    size_t c = *cap ? *cap : 64;
    while (c < need)
        c *= 2;
    void *p = hlod_engine_realloc(e, *v, c * elem);
    if (!p)
        return 0;
    *v = p;
    *cap = c;
    return 1;
}

int hlod_u32_push(hlod_engine *e, hlod_u32_vec *a, uint32_t x)
{
    if (!grow(e, (void **)&a->v, &a->cap, a->n + 1, sizeof *a->v))
        return 0;
    a->v[a->n++] = x;
    return 1;
}

int hlod_req_push(hlod_engine *e, hlod_req_vec *a, uint32_t node, double priority)
{
    if (!grow(e, (void **)&a->v, &a->cap, a->n + 1, sizeof *a->v))
        return 0;
    a->v[a->n].node = node;
    a->v[a->n].priority = (float)(priority < 3e38 ? priority : 3e38);
    a->n++;
    return 1;
}

/* ---- descriptor ---- */

static const char *const policy_names[HLOD_POLICY_COUNT] = {"lakhia", "nohyst", "sse", "full"};

const char *hlod_policy_name(hlod_policy p)
{
    return (unsigned)p < HLOD_POLICY_COUNT ? policy_names[p] : "unknown";
}

int hlod_policy_parse(const char *name, hlod_policy *out)
{
    for (int i = 0; name && i < HLOD_POLICY_COUNT; i++)
        if (strcmp(name, policy_names[i]) == 0) {
            *out = (hlod_policy)i;
            return 1;
        }
    return 0;
}

#define DEF(field, value) \
    if (d->field == 0)    \
    d->field = (value)

void hlod_engine_desc_defaults(hlod_engine_desc *d)
{
    DEF(target_ms, 33.3);
    DEF(memory_budget_bytes, 512ull << 20);
    DEF(c_vis, 4.0);
    DEF(c_vis_falloff, 1.0);
    DEF(c_fore, 0.25);
    DEF(c_hyst_limit, 8.0);
    DEF(c_hyst_switch, 2.0);
    DEF(c_safety_slack, 0.10);
    DEF(c_hyst_deadband, 0.10);
    DEF(velocity_lookahead_s, 0.5);
    DEF(sse_pixels, 2.0);
    DEF(read_chunk_bytes, 64u << 10);
    DEF(upload_budget_bytes, 16ull << 20);
    DEF(max_inflight, 32);
    DEF(fixed_v_time, 1e-4);
    DEF(deterministic_load_bytes, 4ull << 20);
    /* c_memory: 0 means "from the store", resolved at create */
}
#undef DEF

static hlod_result check_desc(const hlod_engine_desc *d, const hlod_logger *lg)
{
#define REQUIRE(cond, ...)                                \
    if (!(cond)) {                                        \
        hlod_logf(lg, HLOD_LOG_ERROR, __VA_ARGS__);       \
        return HLOD_ERR_INVALID_ARG;                      \
    }
    REQUIRE(isfinite(d->target_ms) && d->target_ms > 0 && d->target_ms <= 1e6,
            "engine: target_ms %g is not a positive time", d->target_ms);
    REQUIRE(isfinite(d->c_vis) && d->c_vis >= 0, "engine: c_vis %g < 0", d->c_vis);
    REQUIRE(isfinite(d->c_vis_falloff) && d->c_vis_falloff > 0,
            "engine: c_vis_falloff %g <= 0", d->c_vis_falloff);
    REQUIRE(isfinite(d->c_fore) && d->c_fore >= 0 && d->c_fore <= 1,
            "engine: c_fore %g is not in [0, 1]", d->c_fore);
    REQUIRE(isfinite(d->c_hyst_limit) && d->c_hyst_limit >= 1 && d->c_hyst_limit <= 1e6,
            "engine: c_hyst_limit %g is not in [1, 1e6]", d->c_hyst_limit);
    REQUIRE(isfinite(d->c_hyst_switch) && d->c_hyst_switch >= 1 &&
                d->c_hyst_switch <= d->c_hyst_limit,
            "engine: c_hyst_switch %g is not in [1, c_hyst_limit = %g]", d->c_hyst_switch,
            d->c_hyst_limit);
    REQUIRE(isfinite(d->c_memory) && d->c_memory >= 0, "engine: c_memory %g < 0", d->c_memory);
    REQUIRE(isfinite(d->c_safety_slack) && d->c_safety_slack >= 0 && d->c_safety_slack <= 10,
            "engine: c_safety_slack %g is not in [0, 10]", d->c_safety_slack);
    REQUIRE(isfinite(d->c_hyst_deadband) && d->c_hyst_deadband <= 1,
            "engine: c_hyst_deadband %g is above 1", d->c_hyst_deadband);
    REQUIRE(isfinite(d->velocity_lookahead_s) && d->velocity_lookahead_s >= 0,
            "engine: velocity_lookahead_s %g < 0", d->velocity_lookahead_s);
    REQUIRE(isfinite(d->upload_budget_ms) && d->upload_budget_ms >= 0,
            "engine: upload_budget_ms %g < 0", d->upload_budget_ms);
    REQUIRE(isfinite(d->sse_pixels) && d->sse_pixels > 0, "engine: sse_pixels %g <= 0",
            d->sse_pixels);
    REQUIRE((unsigned)d->policy < HLOD_POLICY_COUNT, "engine: unknown policy %d", (int)d->policy);
    REQUIRE(isfinite(d->fixed_v_time) && d->fixed_v_time > 0, "engine: fixed_v_time %g <= 0",
            d->fixed_v_time);
    REQUIRE(isfinite(d->fixed_frame_ms) && d->fixed_frame_ms >= 0 &&
                d->fixed_frame_ms < d->target_ms,
            "engine: fixed_frame_ms %g is not in [0, target_ms)", d->fixed_frame_ms);
    REQUIRE(!!d->allocator.alloc == !!d->allocator.free &&
                !!d->allocator.alloc == !!d->allocator.realloc,
            "engine: an allocator needs alloc, realloc and free");
#undef REQUIRE
    return HLOD_OK;
}

/* ---- create / destroy ---- */

hlod_result hlod_engine_create(const hlod_store *store, const hlod_engine_desc *desc,
                               hlod_engine **out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    *out = NULL;
    if (!store || !desc)
        return HLOD_ERR_INVALID_ARG;
    hlod_engine_desc d = *desc;
    hlod_engine_desc_defaults(&d);
    hlod_result r = check_desc(&d, &d.logger);
    if (r != HLOD_OK)
        return r;

    hlod_engine tmp = {0};
    tmp.d = d;
    hlod_engine *e = hlod_engine_alloc(&tmp, sizeof *e);
    if (!e)
        return HLOD_ERR_NOMEM;
    *e = tmp;
    e->store = store;
    e->nodes = hlod_store_nodes(store);
    e->node_count = hlod_store_node_count(store);
    e->root_count = hlod_store_root_count(store);
    if (e->d.c_memory == 0) {
        /* Lakhia: memory proportional to cost; by default the store's own
         * bytes per unit of cost, so both limits agree on average. */
        double total = 0;
        for (uint32_t i = 0; i < e->node_count; i++)
            total += e->nodes[i].cost;
        const hlod_store_header *h = hlod_store_get_header(store);
        e->d.c_memory = total > 0 ? (double)h->payload_bytes / total : 1.0;
    }
    e->v_time = e->fit_v = e->d.deterministic ? e->d.fixed_v_time : 1e-4;
    e->fixed_ms = e->fit_fixed = e->d.deterministic ? e->d.fixed_frame_ms : 0.2 * e->d.target_ms;
    e->sse_pixels = e->d.sse_pixels;
    e->share_gain = 1;

    e->fr = hlod_engine_alloc(e, (size_t)e->node_count * sizeof *e->fr);
    e->res = hlod_engine_alloc(e, (size_t)e->node_count * sizeof *e->res);
    if (!e->fr || !e->res) {
        hlod_engine_destroy(e);
        return HLOD_ERR_NOMEM;
    }
    memset(e->fr, 0, (size_t)e->node_count * sizeof *e->fr);
    memset(e->res, 0, (size_t)e->node_count * sizeof *e->res);

    r = hlod_residency_load_roots(e);
    if (r == HLOD_OK) {
        hlod_loader_desc ld = {0};
        ld.threaded = !e->d.deterministic;
        ld.chunk_bytes = e->d.read_chunk_bytes;
        ld.hook = e->d.read_hook;
        ld.hook_user = e->d.read_hook_user;
        ld.logger = e->d.logger;
        r = hlod_loader_create(store, &ld, &e->loader);
    }
    if (r != HLOD_OK) {
        hlod_engine_destroy(e);
        return r;
    }
    *out = e;
    return HLOD_OK;
}

void hlod_engine_destroy(hlod_engine *e)
{
    if (!e)
        return;
    hlod_loader_destroy(e->loader); /* joins the thread first */
    hlod_residency_release_all(e);
    hlod_engine_free(e, e->fr);
    hlod_engine_free(e, e->res);
    hlod_engine_free(e, e->resident.v);
    hlod_engine_free(e, e->pending);
    hlod_engine_free(e, e->draw.v);
    hlod_engine_free(e, e->draw_keys);
    hlod_engine_free(e, e->level.v);
    hlod_engine_free(e, e->next.v);
    hlod_engine_free(e, e->want.v);
    hlod_engine_free(e, e->post.v);
    hlod_engine_free(e, e);
}

hlod_result hlod_engine_set(hlod_engine *e, const hlod_engine_desc *desc)
{
    if (!e || !desc)
        return HLOD_ERR_INVALID_ARG;
    hlod_engine_desc d = *desc;
    hlod_engine_desc_defaults(&d);
    /* fields that need a restart keep their values */
    d.memory_budget_bytes = e->d.memory_budget_bytes;
    d.renderer = e->d.renderer;
    d.deterministic = e->d.deterministic;
    d.read_hook = e->d.read_hook;
    d.read_hook_user = e->d.read_hook_user;
    d.allocator = e->d.allocator;
    d.read_chunk_bytes = e->d.read_chunk_bytes;
    if (d.c_memory == 0)
        d.c_memory = e->d.c_memory;
    hlod_result r = check_desc(&d, &e->d.logger);
    if (r != HLOD_OK)
        return r;
    if (d.sse_pixels != e->d.sse_pixels)
        e->sse_pixels = d.sse_pixels;
    e->d = d;
    if (e->d.deterministic) {
        e->v_time = e->d.fixed_v_time;
        e->fixed_ms = e->d.fixed_frame_ms;
    }
    return HLOD_OK;
}

const hlod_engine_desc *hlod_engine_get_desc(const hlod_engine *e)
{
    return e ? &e->d : NULL;
}

/* ---- cost model ---- */

static void fit_cost_model(hlod_engine *e, double x, double y)
{
    const double target = e->d.target_ms;
    if (!(isfinite(x) && isfinite(y)) || x < 0 || y < 0)
        return;
    e->s0 = FORGET * e->s0 + 1;
    e->sx = FORGET * e->sx + x;
    e->sy = FORGET * e->sy + y;
    e->sxx = FORGET * e->sxx + x * x;
    e->sxy = FORGET * e->sxy + x * y;
    /* Weighted least squares with a ridge pulling v_time toward its last
     * value, scaled by mean(x)^2 so it is unit-free:
     *   [s0, sx; sx, sxx + k] [a; b] = [sy; sxy + k * b_prev],
     *   k = RIDGE * s0 * mean(x)^2.
     * With no spread in x the data fix only a + b * mean(x): the ridge then
     * keeps v_time and lets the fixed part take the change.  A wrong v_time
     * moves the budget, which moves x, which gives the spread that corrects
     * it: the fit explores by itself. */
    double mean_x = e->sx / e->s0;
    double b_prev = e->fit_v;
    double k = RIDGE * e->s0 * mean_x * mean_x;
    double m00 = e->s0, m01 = e->sx, m11 = e->sxx + k;
    double r0 = e->sy, r1 = e->sxy + k * b_prev;
    double det = m00 * m11 - m01 * m01;
    double a = e->fit_fixed, b = b_prev;
    if (det > 1e-12 * m00 * m11 && m11 > 0) {
        a = (r0 * m11 - m01 * r1) / det;
        b = (m00 * r1 - m01 * r0) / det;
    } else if (e->s0 > 0) {
        a = e->sy / e->s0; /* nothing drawn yet: all of it is fixed */
    }
    if (!(b > 1e-9) || !isfinite(b))
        b = 1e-9;
    if (!(b < 1e6))
        b = 1e6;
    /* keep a inside [0, 0.8 target] and re-fit b to the mean if clamped */
    double hi_a = 0.8 * target;
    if (!(a >= 0) || !(a <= hi_a)) {
        a = !(a >= 0) ? 0 : hi_a;
        double mean_y = e->sy / e->s0;
        if (mean_x > 0 && mean_y > a)
            b = (mean_y - a) / mean_x;
    }
    e->fit_fixed = a;
    e->fit_v = b;
    /* Publish only changes the noise of one frame cannot explain (3% of
     * v_time, 3% of the target for the fixed part): with a still camera the
     * traversal then sees constant inputs and its hysteresis settles, while
     * a real change still passes within a frame or two. */
    if (fabs(b - e->v_time) > 0.03 * e->v_time || fabs(a - e->fixed_ms) > 0.03 * target) {
        e->v_time = b;
        e->fixed_ms = a;
    }
}

/* Eq. 4 hands each node a fixed share of its parent's slice, and time a
 * node cannot use (its children need more than its slice, or it is a leaf)
 * is lost to the frame: left alone the front settles well under the target
 * (about 65% of it on the tests' synthetic city).  The paper is silent;
 * we scale the roots' shareTime by a gain:
 *   - it grows, at most 10% a frame, while the estimate is under 85% of
 *     the budget and time slices refused a refinement that was near;
 *   - it shrinks 3% a frame while the budget bound refused refinements the
 *     slices granted (the slices then promise more than the frame holds,
 *     and the bound, not priority, would choose), but only while the
 *     camera moves: with a still camera a refused node simply stays
 *     refused, whereas shrinking would lower every slice until some other
 *     node gave way, then grow again: a slow cycle of toggles.
 * The budget still bounds the estimate (traverse.c), so the gain moves
 * detail between nodes and never pushes the frame over the target. */
static void adapt_share_gain(hlod_engine *e, double est, double budget, int moved)
{
    if (e->d.policy != HLOD_POLICY_LAKHIA && e->d.policy != HLOD_POLICY_NOHYST)
        return;
    double ratio = budget > 0 ? est / budget : 1;
    double g = e->share_gain;
    if (e->cap_hits && moved) {
        g *= 0.97;
    } else if (ratio < 0.85 && e->slice_denied) {
        double up = ratio > 0 ? sqrt(0.92 / ratio) : 1.1;
        g *= up < 1.1 ? up : 1.1;
    }
    e->share_gain = g < 1 ? 1 : g > 64 ? 64 : g;
}

/* ---- frame ---- */

static int camera_ok(const hlod_camera *c)
{
    for (int k = 0; k < 3; k++)
        if (!isfinite(c->position[k]))
            return 0;
    for (int k = 0; k < 16; k++)
        if (!isfinite(c->view[k]) || !isfinite(c->proj[k]))
            return 0;
    return c->width > 0 && c->height > 0 && isfinite(c->fov_y_deg) && c->fov_y_deg > 0 &&
           c->fov_y_deg < 180;
}

/* Draw order: nearest first by the distance from the eye to the node's
 * box, so a software rasteriser's early depth test rejects hidden
 * fragments before they are shaded (street level: 88 -> 38 ms with back
 * faces culled too).  A node whose box holds the eye (the ground under a
 * street-level camera) would come first and be shaded everywhere the
 * buildings cover it, so those come last, by their centres. */
typedef struct draw_key {
    int inside;
    double d2;
    uint32_t node;
} draw_key;

static int cmp_draw_key(const void *pa, const void *pb)
{
    const draw_key *a = pa, *b = pb;
    if (a->inside != b->inside)
        return a->inside - b->inside;
    return a->d2 < b->d2 ? -1 : a->d2 > b->d2 ? 1 : (a->node > b->node) - (a->node < b->node);
}

static void sort_draws(hlod_engine *e, const hlod_camera *cam)
{
    size_t n = e->draw.n;
    if (n < 2)
        return;
    if (e->draw_keys_cap < n) {
        draw_key *k = hlod_engine_realloc(e, e->draw_keys, n * sizeof *k);
        if (!k)
            return; /* unsorted is still correct */
        e->draw_keys = k;
        e->draw_keys_cap = n;
    }
    draw_key *keys = e->draw_keys;
    for (size_t k = 0; k < n; k++) {
        const hlod_store_node *nd = &e->nodes[e->draw.v[k]];
        double box = 0, centre = 0;
        for (int a = 0; a < 3; a++) {
            double p = cam->position[a], lo = nd->bbox_min[a], hi = nd->bbox_max[a];
            double o = p < lo ? lo - p : p > hi ? p - hi : 0;
            double c = 0.5 * (lo + hi) - p;
            box += o * o;
            centre += c * c;
        }
        /* a flat node below the eye (z up: the ground, streets) is covered
         * by whatever stands on it, from any height */
        double h = nd->bbox_max[2] - nd->bbox_min[2];
        double w = fmax(nd->bbox_max[0] - nd->bbox_min[0], nd->bbox_max[1] - nd->bbox_min[1]);
        int under = h <= 0.02 * w && nd->bbox_max[2] <= cam->position[2];
        keys[k].inside = !(box > 0) || under;
        keys[k].d2 = box > 0 ? box : centre;
        keys[k].node = e->draw.v[k];
    }
    qsort(keys, n, sizeof *keys, cmp_draw_key);
    for (size_t k = 0; k < n; k++)
        e->draw.v[k] = keys[k].node;
}

static void draw_frame(hlod_engine *e, const hlod_camera *cam)
{
    hlod_renderer *r = e->d.renderer;
    sort_draws(e, cam);
    hlod_gpu_begin(r, cam);
    for (size_t k = 0; k < e->draw.n; k++) {
        uint32_t i = e->draw.v[k];
        const hlod_store_node *n = &e->nodes[i];
        double off[3] = {n->origin[0] - cam->position[0], n->origin[1] - cam->position[1],
                         n->origin[2] - cam->position[2]};
        hlod_gpu_draw(r, &e->res[i].gpu, off, n->depth);
    }
    hlod_gpu_end(r, 1);
}

hlod_result hlod_engine_frame(hlod_engine *e, const hlod_camera *cam, double dt,
                              hlod_frame_stats *stats)
{
    if (stats)
        memset(stats, 0, sizeof *stats);
    if (!e || !cam)
        return HLOD_ERR_INVALID_ARG;
    if (!camera_ok(cam) || !isfinite(dt) || dt < 0) {
        hlod_logf(&e->d.logger, HLOD_LOG_ERROR,
                  "engine: frame %u: camera or dt is not finite or out of range; not drawn",
                  e->frame + 1);
        return HLOD_ERR_INVALID_ARG;
    }
    double t_start = hlod_now_ms();
    e->frame++;
    memset(&e->st, 0, sizeof e->st);
    e->st.frame = e->frame - 1;

    /* camera velocity, for the distance look-ahead */
    double vel[3] = {0, 0, 0};
    int moved = !e->have_prev;
    if (e->have_prev && dt > 0)
        for (int k = 0; k < 3; k++)
            vel[k] = (cam->position[k] - e->prev_eye[k]) / dt;
    for (int k = 0; k < 3 && e->have_prev; k++)
        moved |= cam->position[k] != e->prev_eye[k];
    memcpy(e->prev_eye, cam->position, sizeof e->prev_eye);
    e->have_prev = 1;

    double t0 = hlod_now_ms();
    hlod_residency_collect(e);
    e->st.upload_ms = hlod_now_ms() - t0;

    /* This frame's uploads are done and timed: the traversal gets what is
     * left, and the fit sees the frame without them.  Not when
     * deterministic (a measured time would make the selection vary), nor
     * under a time model: its frame time is the whole frame, uploads
     * included, and a wall-clock upload (a preempted collect) would bias
     * the budget and the fit of a synthetic machine. */
    const double target = e->d.target_ms;
    const double upload = e->d.deterministic || e->d.time_model ? 0 : e->st.upload_ms;
    double budget = target - e->fixed_ms - upload;
    if (budget < 0.1 * target)
        budget = 0.1 * target;
    hlod_view view;
    hlod_view_init(&view, cam, vel, e->d.velocity_lookahead_s);
    t0 = hlod_now_ms();
    hlod_result r = hlod_traverse(e, &view, budget, budget * e->share_gain);
    e->st.traversal_ms = hlod_now_ms() - t0;
    if (r != HLOD_OK)
        return r;

    if (e->d.renderer)
        draw_frame(e, cam);

    double measured;
    if (e->d.time_model)
        measured = e->d.time_model(e->d.time_model_user, e->st.cost_drawn, e->st.tris_drawn);
    else
        measured = hlod_now_ms() - t_start;
    e->st.measured_ms = measured;
    e->st.v_time = e->v_time;
    e->st.fixed_ms = e->fixed_ms;
    e->st.budget_ms = budget;
    e->st.share_gain = e->share_gain;
    e->st.estimated_ms = e->fixed_ms + e->v_time * e->st.cost_drawn + upload;
    e->st.sse_pixels = e->sse_pixels;

    if (!e->d.deterministic)
        fit_cost_model(e, e->st.cost_drawn, measured - upload);
    adapt_share_gain(e, e->v_time * e->st.cost_drawn, budget, moved);
    if (e->d.policy == HLOD_POLICY_SSE) {
        /* Adapt the pixel threshold to the frame time: coarser when over
         * target, finer when under; square root damps the response. */
        double ratio = (e->d.deterministic ? e->st.estimated_ms : measured) / target;
        if (isfinite(ratio) && ratio > 0) {
            double f = sqrt(ratio);
            f = f < 0.8 ? 0.8 : f > 1.25 ? 1.25 : f;
            e->sse_pixels *= f;
            if (e->sse_pixels < 0.05)
                e->sse_pixels = 0.05;
            if (e->sse_pixels > 1e4)
                e->sse_pixels = 1e4;
        }
    }

    if (e->d.policy != HLOD_POLICY_FULL)
        hlod_residency_schedule(e);

    hlod_loader_counters lc;
    hlod_loader_get_counters(e->loader, &lc);
    e->st.bytes_read += lc.bytes_read - e->bytes_read_prev;
    e->bytes_read_prev = lc.bytes_read;
    e->st.resident_nodes = (uint32_t)e->resident.n;
    e->st.resident_bytes = e->resident_bytes;
    e->st.resident_cost = e->d.c_memory * e->resident_cost;
    e->st.memory_budget_bytes = e->d.memory_budget_bytes;
    e->st.bad_nodes = e->bad_total;
    if (stats)
        *stats = e->st;
    return HLOD_OK;
}

/* ---- reference renders ---- */

hlod_result hlod_engine_load_all_leaves(hlod_engine *e, const hlod_camera *cam)
{
    if (!e || !cam || !camera_ok(cam))
        return HLOD_ERR_INVALID_ARG;
    hlod_view view;
    double still[3] = {0, 0, 0};
    hlod_view_init(&view, cam, still, 0);
    /* Every node whose box meets the frustum, top down: load the visible
     * leaves (and the inner nodes on the way, which cost little and give
     * the full policy its fallback). */
    hlod_u32_vec stack = {0};
    hlod_result r = HLOD_OK;
    for (uint32_t i = 0; i < e->root_count && r == HLOD_OK; i++)
        if (!hlod_u32_push(e, &stack, i))
            r = HLOD_ERR_NOMEM;
    while (r == HLOD_OK && stack.n) {
        uint32_t i = stack.v[--stack.n];
        const hlod_store_node *n = &e->nodes[i];
        double lo[3], hi[3], worst = -INFINITY;
        for (int k = 0; k < 3; k++) {
            lo[k] = n->bbox_min[k] - view.eye[k];
            hi[k] = n->bbox_max[k] - view.eye[k];
        }
        for (int p = 0; p < 6; p++) {
            const double *pl = view.planes[p];
            double s = pl[3];
            for (int k = 0; k < 3; k++)
                s += pl[k] * (pl[k] >= 0 ? hi[k] : lo[k]);
            if (-s > worst)
                worst = -s;
        }
        if (worst > 0)
            continue;
        uint32_t c0 = hlod_store_first_child(e->nodes, i), c1 = hlod_store_child_end(e->nodes, i);
        if (e->res[i].state != HLOD_NODE_RESIDENT && e->res[i].state != HLOD_NODE_BAD) {
            hlod_result lr = hlod_residency_load_now(e, i);
            if (lr != HLOD_OK)
                hlod_logf(&e->d.logger, HLOD_LOG_WARN, "%s: node %u: %s; its parent stands in",
                          hlod_store_path(e->store), i, hlod_result_str(lr));
            if (lr == HLOD_ERR_NOMEM)
                r = lr;
        }
        for (uint32_t c = c0; c < c1 && r == HLOD_OK; c++)
            if (!hlod_u32_push(e, &stack, c))
                r = HLOD_ERR_NOMEM;
    }
    hlod_engine_free(e, stack.v);
    return r;
}

/* ---- inspection ---- */

hlod_node_state hlod_engine_node_state(const hlod_engine *e, uint32_t node)
{
    if (!e || node >= e->node_count)
        return HLOD_NODE_ABSENT;
    return (hlod_node_state)e->res[node].state;
}

int hlod_engine_node_drawn(const hlod_engine *e, uint32_t node)
{
    if (!e || node >= e->node_count || e->frame == 0)
        return 0;
    return e->fr[node].drawn == e->frame;
}

void hlod_engine_node_debug(const hlod_engine *e, uint32_t node, double *hyst,
                            double *time_slice, double *time_needed, double *priority)
{
    const hlod_node_frame *f = e && node < e->node_count ? &e->fr[node] : NULL;
    if (hyst)
        *hyst = f ? f->hyst : 0;
    if (time_slice)
        *time_slice = f ? f->slice : 0;
    if (time_needed)
        *time_needed = f ? f->needed : 0;
    if (priority)
        *priority = f ? f->priority : 0;
}
