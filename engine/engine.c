/*
 * engine.c - the engine object and its frame (docs/runtime.md).
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
 * The cost model is cost_model.c; the frame ties the three parts together.
 */
#include "engine_internal.h"

#include "hlod_clock.h"
#include "hold.h"
#include "sort.h"
#include "policy.h"
#include "sleeps.h"

#include <assert.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* ---- descriptor ---- */

/* ---- settings (the table HLOD_ENGINE_SETTINGS in engine.h) ---- */

void hlod_engine_desc_defaults(hlod_engine_desc *d)
{
#define DEF_D(def) (def)
#define DEF_U32(def) (def)
#define DEF_U64(def) (def)
#define DEF_B(def) ((def) ? 1 : -1)
#define DEF(key, field, kind, def, lo, lo_open, hi, live, help) \
    if (d->field == 0)                                          \
        d->field = (HLOD_SETTING_KIND_##kind)DEF_##kind(def);
    HLOD_ENGINE_SETTINGS(DEF)
#undef DEF
}

static const hlod_engine_setting settings[] = {
#define ROW(key, field, kind, def, lo, lo_open, hi, live, help) \
    {#key, help, #kind, (double)(def), lo, hi, lo_open, live},
    HLOD_ENGINE_SETTINGS(ROW)
#undef ROW
};

const hlod_engine_setting *hlod_engine_settings(size_t *count)
{
    if (count)
        *count = sizeof settings / sizeof *settings;
    return settings;
}

static int store_D(double *field, double v)
{
    *field = v;
    return 1;
}

static int store_U32(uint32_t *field, double v)
{
    if (!(v >= 0 && v <= (double)UINT32_MAX) || v != floor(v))
        return 0;
    *field = (uint32_t)v;
    return 1;
}

static int store_U64(uint64_t *field, double v)
{
    if (!(v >= 0 && v < 18446744073709551616.0) || v != floor(v))
        return 0;
    *field = (uint64_t)v;
    return 1;
}

static int store_B(int *field, double v)
{
    if (v != 0 && v != 1)
        return 0;
    *field = v == 1 ? 1 : -1;
    return 1;
}

hlod_result hlod_engine_desc_set(hlod_engine_desc *d, const char *key, double v)
{
    if (!d || !key || !isfinite(v))
        return HLOD_ERR_INVALID_ARG;
#define SET(k, field, kind, def, lo, lo_open, hi, live, help) \
    if (strcmp(key, #k) == 0)                                 \
        return store_##kind(&d->field, v) ? HLOD_OK : HLOD_ERR_INVALID_ARG;
    HLOD_ENGINE_SETTINGS(SET)
#undef SET
    return HLOD_ERR_INVALID_ARG;
}

/* A setting's range as text: [lo, hi] or (lo, hi], "inf" for no limit. */
static hlod_result out_of_range(const hlod_logger *lg, const char *key, double v, double lo,
                                int lo_open, double hi)
{
    char l[32], h[32];
    snprintf(l, sizeof l, isinf(lo) ? "-inf" : "%g", lo);
    snprintf(h, sizeof h, isinf(hi) ? "inf" : "%g", hi);
    hlod_logf(lg, HLOD_LOG_ERROR, "engine: %s %g is not in %c%s, %s]", key, v, lo_open ? '(' : '[',
              l, h);
    return HLOD_ERR_INVALID_ARG;
}

#define VALUE_D(f) (f)
#define VALUE_U32(f) ((double)(f))
#define VALUE_U64(f) ((double)(f))
#define VALUE_B(f) ((f) > 0 ? 1.0 : (f) < 0 ? 0.0 : NAN)

static hlod_result check_desc(const hlod_engine_desc *d, const hlod_logger *lg)
{
#define RANGE(key, field, kind, def, lo, lo_open, hi, live, help)                      \
    {                                                                                 \
        double v_ = VALUE_##kind(d->field);                                           \
        if (!isfinite(v_) || v_ < (lo) || ((lo_open) && v_ == (lo)) || v_ > (hi))    \
            return out_of_range(lg, #key, v_, lo, lo_open, hi);                       \
    }
    HLOD_ENGINE_SETTINGS(RANGE)
#undef RANGE
#define REQUIRE(cond, ...)                                \
    if (!(cond)) {                                        \
        hlod_logf(lg, HLOD_LOG_ERROR, __VA_ARGS__);       \
        return HLOD_ERR_INVALID_ARG;                      \
    }
    REQUIRE(d->c_hyst_switch <= d->c_hyst_limit,
            "engine: c_hyst_switch %g is not in [1, c_hyst_limit = %g]", d->c_hyst_switch,
            d->c_hyst_limit);
    REQUIRE(d->fixed_frame_ms < d->target_ms,
            "engine: fixed_frame_ms %g is not in [0, target_ms)", d->fixed_frame_ms);
    REQUIRE((unsigned)d->policy < HLOD_POLICY_COUNT, "engine: unknown policy %d", (int)d->policy);
    REQUIRE(!!d->allocator.alloc == !!d->allocator.free &&
                !!d->allocator.alloc == !!d->allocator.realloc,
            "engine: an allocator needs alloc, realloc and free");
#undef REQUIRE
    return HLOD_OK;
}

/* A store that refines additively (a sample tree) is drawn by a policy
 * with HLOD_PT_ADDITIVE, or full (its reference: every node); one that
 * refines by replacement by any other. */
static hlod_result check_refine(const hlod_store *store, const hlod_engine_desc *d)
{
    int add = (hlod_store_get_header(store)->flags & HLOD_STORE_ADDITIVE) != 0;
    int pol = hlod_policy_has(d->policy, HLOD_PT_ADDITIVE);
    if (add && !pol && d->policy != HLOD_POLICY_FULL) {
        hlod_logf(&d->logger, HLOD_LOG_ERROR, "engine: the store refines additively (a sample "
                  "tree): policy %s draws replacement hierarchies; use klein or full",
                  hlod_policy_name(d->policy));
        return HLOD_ERR_INVALID_ARG;
    }
    if (add && hlod_policy_has(d->policy, HLOD_PT_RZB)) {
        hlod_logf(&d->logger, HLOD_LOG_ERROR, "engine: the store refines additively (a sample "
                  "tree): policy rzb samples the leaves of a replacement hierarchy, and a sample "
                  "tree keeps faces in its inner nodes too");
        return HLOD_ERR_INVALID_ARG;
    }
    const hlod_store_extra *x = hlod_store_extras(store);
    if (add && hlod_policy_has(d->policy, HLOD_PT_CUBES) &&
        (!x || !hlod_store_get_header(store)->node_count || !(x[0].flags & HLOD_EXTRA_CUBE))) {
        hlod_logf(&d->logger, HLOD_LOG_ERROR, "engine: policy cubes draws colour cubes; this "
                  "store's nodes carry none (build one with hlod-build --method cubes)");
        return HLOD_ERR_INVALID_ARG;
    }
    if (d->far_cubes > 0 && (add || hlod_policy_has(d->policy, HLOD_PT_RZB) ||
                              hlod_policy_has(d->policy, HLOD_PT_LUMI))) {
        hlod_logf(&d->logger, HLOD_LOG_ERROR, "engine: far_cubes draws a replacement "
                  "hierarchy's front; policy %s on this store has none (klein's small nodes "
                  "are splats, cubes' are cubes already)", hlod_policy_name(d->policy));
        return HLOD_ERR_INVALID_ARG;
    }
    if (d->far_cubes > 0 &&
        (!x || !hlod_store_get_header(store)->node_count || !(x[0].flags & HLOD_EXTRA_CUBE))) {
        hlod_logf(&d->logger, HLOD_LOG_ERROR, "engine: far_cubes draws the nodes' colour "
                  "cubes; this store's nodes carry none (build it with hlod-build --far-cubes on)");
        return HLOD_ERR_INVALID_ARG;
    }
    if (d->cube_copies > 0 && hlod_policy_has(d->policy, HLOD_PT_CUBES) &&
        hlod_store_root_count(store) != 1) {
        hlod_logf(&d->logger, HLOD_LOG_ERROR, "engine: cube_copies draws copies of a store of "
                  "one root; this one has %u", hlod_store_root_count(store));
        return HLOD_ERR_INVALID_ARG;
    }
    if (!add && pol) {
        hlod_logf(&d->logger, HLOD_LOG_ERROR, "engine: policy %s draws a sample tree; this "
                  "store refines by replacement (build one with hlod-build --method sampletree)",
                  hlod_policy_name(d->policy));
        return HLOD_ERR_INVALID_ARG;
    }
    return HLOD_OK;
}

/* ---- create / destroy ---- */

/* Policy rzb: every leaf read into the randomized z-buffer's structure
 * (rzb.h), its faces uploaded for the ranges it rasterises.  A leaf that
 * cannot be read is left out (logged); only running out of memory fails.
 * The leaves are not made resident: the structure holds what it draws. */
static hlod_result rzb_build(hlod_engine *e)
{
    e->rzb = hlod_rzb_create(&e->d.allocator);
    if (!e->rzb)
        return HLOD_ERR_NOMEM;
    hlod_result r = HLOD_OK;
    for (uint32_t i = 0; i < e->node_count && r == HLOD_OK; i++) {
        if (hlod_store_first_child(e->nodes, i) != hlod_store_child_end(e->nodes, i))
            continue;
        hlod_store_payload p;
        hlod_result lr = hlod_store_read_node(e->store, i, e->d.read_chunk_bytes, &p);
        if (lr == HLOD_OK) {
            r = hlod_rzb_add(e->rzb, &e->nodes[i], i, &p);
            hlod_store_payload_free(&p);
        } else if (lr == HLOD_ERR_NOMEM) {
            r = lr;
        } else {
            hlod_logf(&e->d.logger, HLOD_LOG_WARN, "%s: leaf %u: %s; rzb leaves it out",
                      hlod_store_path(e->store), i, hlod_result_str(lr));
        }
    }
    if (r == HLOD_OK)
        r = hlod_rzb_finish(e->rzb);
    if (r == HLOD_OK && e->d.renderer)
        r = hlod_rzb_upload(e->rzb, e->d.renderer);
    return r;
}

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
    if (r == HLOD_OK)
        r = check_refine(store, &d);
    if (r != HLOD_OK)
        return r;

    if (d.steady_heap > 0)
        hlod_steady_heap();
    hlod_engine *e = hlod_mem_alloc(&d.allocator, sizeof *e);
    if (!e)
        return HLOD_ERR_NOMEM;
    *e = (hlod_engine){0};
    e->d = d;
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
        e->d.c_memory = total > 0 ? (double)hlod_store_memory_bytes(store) / total : 1.0;
    }
    hlod_cost_model_init(&e->cost, &e->d);
    r = hlod_selection_init(&e->sel, store, &e->d, &e->st);
    if (r == HLOD_OK && !hlod_occlusion_init(&e->occ, &e->d.allocator, e->node_count))
        r = HLOD_ERR_NOMEM;
    /* before any upload: the lumigraph's passes draw every node's own arrays */
    if (e->d.renderer)
        hlod_renderer_set_batch(e->d.renderer,
                                hlod_policy_has(e->d.policy, HLOD_PT_LUMI) || e->d.batch < 0
                                    ? 0
                                    : e->d.batch_tris);
    if (r == HLOD_OK)
        r = hlod_residency_init(&e->res, store, &e->d, &e->st);
    if (r == HLOD_OK && hlod_policy_has(e->d.policy, HLOD_PT_RZB))
        r = rzb_build(e);
    if (r == HLOD_OK && hlod_policy_has(e->d.policy, HLOD_PT_LUMI)) {
        if (!e->d.lumigraph_repo) {
            hlod_logf(&e->d.logger, HLOD_LOG_ERROR, "engine: policy lumigraph needs a sampling "
                      "repository (lumigraph_repo; hlod-bench --repo)");
            r = HLOD_ERR_INVALID_ARG;
        } else {
            r = hlod_lumi_create(e->d.lumigraph_repo, e->d.lumigraph_answers,
                                 hlod_store_get_header(store)->node_table_hash,
                                 (uint64_t)e->d.lumi_cache_mb << 20,
                                 &e->d.logger, &e->lumi);
        }
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
    hlod_residency_destroy(&e->res); /* joins the loader thread first */
    hlod_selection_free(&e->sel);
    hlod_mem_free(&e->d.allocator, e->draw_keys);
    hlod_occlusion_free(&e->occ, &e->d.allocator);
    hlod_mem_free(&e->d.allocator, e->drawn.v);
    hlod_mem_free(&e->d.allocator, e->later.v);
    hlod_mem_free(&e->d.allocator, e->order.v);
    hlod_mem_free(&e->d.allocator, e->splat_buf);
    if (e->d.renderer)
        hlod_rzb_release(e->rzb, e->d.renderer);
    hlod_rzb_destroy(e->rzb);
    hlod_rzb_out_free(&e->d.allocator, &e->rzb_out);
    hlod_lumi_destroy(e->lumi, e->d.renderer);
    hlod_allocator a = e->d.allocator;
    hlod_mem_free(&a, e);
}

hlod_result hlod_engine_set(hlod_engine *e, const hlod_engine_desc *desc)
{
    if (!e || !desc)
        return HLOD_ERR_INVALID_ARG;
    hlod_engine_desc d = *desc;
    hlod_engine_desc_defaults(&d);
    /* fields that need a restart keep their values */
#define KEEP(key, field, kind, def, lo, lo_open, hi, live, help) \
    if (!(live))                                                \
        d.field = e->d.field;
    HLOD_ENGINE_SETTINGS(KEEP)
#undef KEEP
    d.renderer = e->d.renderer;
    d.deterministic = e->d.deterministic;
    d.read_hook = e->d.read_hook;
    d.read_hook_user = e->d.read_hook_user;
    d.allocator = e->d.allocator;
    if (d.c_memory == 0)
        d.c_memory = e->d.c_memory;
    hlod_result r = check_desc(&d, &e->d.logger);
    if (r == HLOD_OK && (d.policy == HLOD_POLICY_LUMIGRAPH) != (e->lumi != NULL)) {
        /* the client and its repository are made at create */
        hlod_logf(&e->d.logger, HLOD_LOG_ERROR, "engine: policy lumigraph is chosen at create, "
                  "not switched to or from (%s asked)", hlod_policy_name(d.policy));
        r = HLOD_ERR_INVALID_ARG;
    }
    if (r == HLOD_OK)
        r = check_refine(e->store, &d);
    if (r != HLOD_OK)
        return r;
    hlod_cost_model_set(&e->cost, &e->d, &d);
    e->d = d;
    return HLOD_OK;
}

const hlod_engine_desc *hlod_engine_get_desc(const hlod_engine *e)
{
    return e ? &e->d : NULL;
}

void hlod_engine_scene_box(const hlod_engine *e, double lo[3], double hi[3])
{
    assert(e && lo && hi);
    const hlod_selection *s = &e->sel;
    uint32_t levels = hlod_policy_has(e->d.policy, HLOD_PT_RZB)     ? e->d.rzb_copies
                      : hlod_policy_has(e->d.policy, HLOD_PT_CUBES) ? e->d.cube_copies
                                                                    : 0;
    for (int k = 0; k < 3; k++) {
        lo[k] = s->scene_lo[k];
        hi[k] = s->scene_hi[k];
        if (k < 2)
            hi[k] = lo[k] + ldexp(hi[k] - lo[k], (int)levels);
    }
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

/* The engine's sort keys for n entries (draw order, far_cubes' cubes);
 * NULL without memory (the caller keeps its order). */
static draw_key *draw_keys(hlod_engine *e, size_t n)
{
    if (e->draw_keys_cap < n) {
        draw_key *k = hlod_mem_realloc(&e->d.allocator, e->draw_keys, n * sizeof *k);
        if (!k)
            return NULL;
        e->draw_keys = k;
        e->draw_keys_cap = n;
    }
    return e->draw_keys;
}

/* The engine's draw order (e->order): the selection's nodes near to far
 * from the camera, those the eye stands in or above (flat, below it)
 * first.  Without memory for it, the selection's own order (still
 * correct, only slower to draw). */
static void order_draws(hlod_engine *e, const hlod_camera *cam)
{
    const hlod_u32_vec *sel = &e->sel.draw;
    size_t n = sel->n;
    if (e->sel.copy_levels) {
        /* cube_copies: the walk's order, each entry beside its copy */
        e->draw_list = sel;
        return;
    }
    e->order.n = 0;
    if (e->order.cap < n) {
        uint32_t *v = hlod_mem_realloc(&e->d.allocator, e->order.v, n * sizeof *v);
        if (!v) {
            e->order.cap = 0;
            hlod_mem_free(&e->d.allocator, e->order.v);
            e->order.v = NULL;
            e->draw_list = sel;
            return;
        }
        e->order.v = v;
        e->order.cap = n;
    }
    if (n) /* rzb draws no node (its faces are its own) */
        memcpy(e->order.v, sel->v, n * sizeof *sel->v);
    e->order.n = n;
    e->draw_list = &e->order;
    draw_key *keys = n < 2 ? NULL : draw_keys(e, n);
    if (!keys)
        return; /* unsorted is still correct */
    for (size_t k = 0; k < n; k++) {
        const hlod_store_node *nd = &e->nodes[e->order.v[k]];
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
        keys[k].node = e->order.v[k];
    }
    hlod_sort(keys, n, sizeof *keys, cmp_draw_key);
    for (size_t k = 0; k < n; k++)
        e->order.v[k] = keys[k].node;
}

/* Node i drawn where copy `copy` of the scene puts it (cube_copies; 0:
 * where it is). */
static void gpu_draw_copy(hlod_engine *e, const hlod_camera *cam, uint32_t i, uint32_t copy)
{
    const hlod_store_node *n = &e->nodes[i];
    double off[3] = {n->origin[0] - cam->position[0], n->origin[1] - cam->position[1],
                     n->origin[2] - cam->position[2]}, c[3];
    if (copy) {
        hlod_sel_copy_offset(&e->sel, copy, c);
        for (int a = 0; a < 3; a++)
            off[a] += c[a];
    }
    if (e->lumi)
        hlod_gpu_lumi_draw(e->d.renderer, hlod_residency_gpu(&e->res, i), off);
    else
        hlod_gpu_draw(e->d.renderer, hlod_residency_gpu(&e->res, i), off, n->depth);
}

static void gpu_draw_node(hlod_engine *e, const hlod_camera *cam, uint32_t i)
{
    gpu_draw_copy(e, cam, i, 0);
}

/* Entry k of a draw list: with cube_copies the selection's list carries
 * each entry's copy. */
static void gpu_draw_listed(hlod_engine *e, const hlod_camera *cam, const hlod_u32_vec *list,
                            size_t k)
{
    const hlod_selection *s = &e->sel;
    uint32_t copy = s->copy_levels && list == &s->draw && k < s->draw_copy.n ? s->draw_copy.v[k] : 0;
    gpu_draw_copy(e, cam, list->v[k], copy);
}

/* Policy lumigraph's draw (docs/lumigraph.md): the nodes' depth first,
 * then the background and the blend, each pixel shaded once. */
static void lumi_draw(hlod_engine *e, const hlod_camera *cam, const hlod_u32_vec *list)
{
    hlod_renderer *r = e->d.renderer;
    hlod_gpu_lumi_depth_begin(r);
    for (size_t k = 0; k < list->n; k++) {
        const hlod_store_node *n = &e->nodes[list->v[k]];
        double off[3] = {n->origin[0] - cam->position[0], n->origin[1] - cam->position[1],
                         n->origin[2] - cam->position[2]};
        hlod_gpu_lumi_depth(r, hlod_residency_gpu(&e->res, list->v[k]), off);
    }
    hlod_gpu_lumi_begin(r, cam, &e->lumi_frame);
    for (size_t k = 0; k < list->n; k++)
        gpu_draw_node(e, cam, list->v[k]);
}

/* A node the occlusion test hid: it is not drawn, so it leaves the drawn
 * totals (the cost fit and the time model see what was drawn). */
static void uncount(hlod_engine *e, uint32_t i)
{
    const hlod_store_node *n = &e->nodes[i];
    e->st.nodes_drawn--;
    e->st.nodes_per_depth[n->depth < HLOD_STATS_MAX_DEPTH ? n->depth : HLOD_STATS_MAX_DEPTH - 1]--;
    e->st.tris_drawn -= n->tri_count;
    e->st.cost_drawn -= n->cost;
    e->st.pixels_drawn -= e->sel.fr[i].pix;
    e->st.occlusion_culled++;
}

/* A node drawn in place of children the last frame saw (it coarsened):
 * it stands where they stood, so it occludes as they did.  Left to pass 3,
 * what they hid was tested against a depth without them and drawn, was
 * charged the next frame, and the front coarsened elsewhere to pay: on
 * walk-drive 44-98 seen nodes gone to their parents in one frame flipped
 * 73-138 hidden nodes to visible, every few frames. */
static int child_seen(const hlod_engine *e, uint32_t i, uint32_t f)
{
    uint32_t c1 = hlod_store_child_end(e->nodes, i);
    for (uint32_t c = hlod_store_first_child(e->nodes, i); c < c1; c++)
        if (hlod_occlusion_seen(&e->occ, c) + 1 == f)
            return 1;
    return 0;
}

/* Occlusion culling in two passes (docs/runtime.md, "Occlusion"):
 *   1. draw the nodes that were visible in the last frame (or whose parent
 *      was, and that were not themselves hidden, or one of whose children
 *      was: child_seen): they are the occluders;
 *   2. read the depth, build the pyramid, and test every node of the
 *      selection against it; the result is what the next frame's selection
 *      calls hidden;
 *   3. draw the nodes not drawn in 1 that the test did not hide.
 * Pass 1's depth is real geometry seen from this camera, so a node hidden
 * behind it is hidden in the final image too: culling never makes a hole.
 * The price is a GPU wait between the passes. */
static void draw_occluded(hlod_engine *e, const hlod_camera *cam, const hlod_view *view)
{
    const uint32_t f = e->frame;
    hlod_occlusion *o = &e->occ;
    e->later.n = 0;
    const hlod_u32_vec *list = e->draw_list;
    for (size_t k = 0; k < list->n; k++) {
        uint32_t i = list->v[k], par = e->nodes[i].parent;
        int was_seen = hlod_occlusion_seen(o, i) + 1 == f ||
                       (hlod_occlusion_hidden(o, i) + 1 != f && par != HLOD_STORE_NO_PARENT &&
                        hlod_occlusion_seen(o, par) + 1 == f) ||
                       child_seen(e, i, f);
        if (was_seen) {
            gpu_draw_node(e, cam, i);
            (void)hlod_u32_push(&e->d.allocator, &e->drawn, i); /* only replay reads it */
        } else if (!hlod_u32_push(&e->d.allocator, &e->later, i)) {
            gpu_draw_node(e, cam, i); /* no memory to defer: draw it */
        }
    }
    /* pass 1's drawing is the GPU's work, not occlusion's: wait for it
     * first, so occlusion_ms is the read-back, the pyramid and the tests */
    hlod_gpu_wait(e->d.renderer);
    double t0 = hlod_now_ms();
    uint32_t w = cam->width, h = cam->height, stride = 0, mask = 0;
    const uint32_t *view_depth = hlod_gpu_depth_view(e->d.renderer, &stride, &mask);
    int ok;
    if (view_depth) {
        ok = hlod_occlusion_build_from(&e->occ, &e->d.allocator, view_depth, w, h, stride, mask);
    } else {
        uint32_t *depth = hlod_occlusion_buffer(&e->occ, &e->d.allocator, w, h);
        ok = depth && hlod_gpu_read_depth(e->d.renderer, w, h, depth) == HLOD_OK &&
             hlod_occlusion_build(&e->occ, &e->d.allocator);
    }
    if (ok)
        for (size_t k = 0; k < list->n; k++) {
            uint32_t i = list->v[k];
            double rect[4], z;
            const hlod_store_node *n = &e->nodes[i];
            int vis = !hlod_view_project(view, n->bbox_min, n->bbox_max, rect, &z) ||
                      hlod_occlusion_visible(o, rect, z);
            e->st.occlusion_tested++;
            hlod_occlusion_mark(o, i, vis, f);
        }
    double t2 = hlod_now_ms();
    for (size_t k = 0; k < e->later.n; k++) {
        uint32_t i = e->later.v[k];
        if (ok && hlod_occlusion_hidden(o, i) == f) {
            uncount(e, i);
            continue;
        }
        gpu_draw_node(e, cam, i);
        (void)hlod_u32_push(&e->d.allocator, &e->drawn, i);
    }
    e->st.occlusion_ms = t2 - t0;
}

/* The selection's colour cubes (policy cubes, Chamberlain 3, with its
 * copies' block cubes; or a front's far_cubes, ordered by order_cubes), in
 * the walk's back-to-front order: each cube's faces that face the eye, two
 * triangles each, lit as the geometry is, blended over what is drawn
 * (docs/cubes.md). */
static void draw_cubes(hlod_engine *e, const hlod_camera *cam)
{
    const hlod_u32_vec *sp = &e->sel.splats;
    const hlod_store_extra *x = e->sel.extras;
    if (!sp->n || !x)
        return;
    size_t need = 18 * sp->n; /* three faces of six corners at most */
    if (e->splat_cap < need) {
        hlod_gpu_splat *b = hlod_mem_realloc(&e->d.allocator, e->splat_buf, need * sizeof *b);
        if (!b)
            return; /* the frame goes without its cubes */
        e->splat_buf = b;
        e->splat_cap = need;
    }
    size_t nv = 0;
    const hlod_selection *s = &e->sel;
    for (size_t k = 0; k < sp->n; k++) {
        uint32_t i = sp->v[k];
        uint32_t copy = s->copy_levels && k < s->splat_copy.n ? s->splat_copy.v[k] : 0;
        double lo[3], hi[3], off[3];
        hlod_sel_copy_offset(s, copy, off);
        uint32_t level = HLOD_SEL_IS_BLOCK(i) ? UINT32_MAX - i : 0;
        for (int a = 0; a < 3; a++) {
            /* a block of 2^level x 2^level copies (cube_copies), or a node */
            double b0 = level ? s->scene_lo[a] : e->nodes[i].bbox_min[a],
                   b1 = level ? s->scene_hi[a] : e->nodes[i].bbox_max[a];
            if (level && a < 2)
                b1 += ((1u << level) - 1) * s->copy_side[a];
            lo[a] = b0 + off[a] - cam->position[a];
            hi[a] = b1 + off[a] - cam->position[a];
        }
        for (int f = 0; f < 6; f++) {
            const uint8_t *c = level ? s->block_cube[level][f] : x[i].cube[f];
            const int a = f / 2, plus = !(f & 1), u = (a + 1) % 3, w = (a + 2) % 3;
            double plane = plus ? hi[a] : lo[a];
            /* seen only from its own side: the eye (0) beyond its plane */
            if (!c[3] || (plus ? plane >= 0 : plane <= 0))
                continue;
            double nrm[3] = {0, 0, 0}, mid[3];
            nrm[a] = plus ? 1 : -1;
            mid[a] = plane;
            mid[u] = 0.5 * (lo[u] + hi[u]);
            mid[w] = 0.5 * (lo[w] + hi[w]);
            double d = sqrt(mid[0] * mid[0] + mid[1] * mid[1] + mid[2] * mid[2]);
            /* the face is seen from its own side: its normal faces the eye */
            double light = d > 0 ? hlod_gpu_light(-mid[a] * nrm[a] / d, nrm[2]) : 1;
            uint8_t rgba[4];
            for (int q = 0; q < 3; q++) {
                double val = c[q] * light;
                rgba[q] = (uint8_t)(val > c[3] ? c[3] : val + 0.5); /* premultiplied */
            }
            rgba[3] = c[3];
            static const int corner[6][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 0}, {1, 1}, {0, 1}};
            for (int q = 0; q < 6; q++) {
                hlod_gpu_splat *s = &e->splat_buf[nv++];
                s->pos[a] = (float)plane;
                s->pos[u] = (float)(corner[q][0] ? hi[u] : lo[u]);
                s->pos[w] = (float)(corner[q][1] ? hi[w] : lo[w]);
                memcpy(s->rgba, rgba, 4);
            }
        }
    }
    (void)hlod_gpu_blended(e->d.renderer, e->splat_buf, (uint32_t)nv);
}

/* far_cubes: the front's cubes far to near (their box centres' distance
 * from the eye), so that each blends over those behind it.  Unsorted
 * without memory for the keys. */
static void order_cubes(hlod_engine *e, const hlod_camera *cam)
{
    hlod_u32_vec *sp = &e->sel.splats;
    size_t n = sp->n;
    draw_key *keys = n < 2 ? NULL : draw_keys(e, n);
    if (!keys)
        return;
    for (size_t k = 0; k < n; k++) {
        const hlod_store_node *nd = &e->nodes[sp->v[k]];
        double d2 = 0;
        for (int a = 0; a < 3; a++) {
            double c = 0.5 * (nd->bbox_min[a] + nd->bbox_max[a]) - cam->position[a];
            d2 += c * c;
        }
        keys[k] = (draw_key){0, d2, sp->v[k]};
    }
    hlod_sort(keys, n, sizeof *keys, cmp_draw_key);
    for (size_t k = 0; k < n; k++)
        sp->v[k] = keys[n - 1 - k].node;
}

/* The selection's splats (a sample tree's small nodes, Klein 4.5): each
 * at its box's centre, its colour lit as a face with the node's average
 * normal would be (gl_render.c's headlight and sky), as wide as the walk's
 * splat size. */
static void draw_splats(hlod_engine *e, const hlod_camera *cam)
{
    if (e->rzb) {
        /* rzb's rasterised faces, then its points, d x d each (Wand 4.2) */
        hlod_rzb_draw(e->rzb, e->d.renderer, cam->position, &e->rzb_out, e->d.splat_px);
        return;
    }
    if (hlod_policy_has(e->d.policy, HLOD_PT_CUBES)) {
        draw_cubes(e, cam);
        return;
    }
    if (e->d.far_cubes > 0) { /* the front's nodes within cube_px (docs/cubes.md) */
        order_cubes(e, cam);
        draw_cubes(e, cam);
        return;
    }
    const hlod_u32_vec *sp = &e->sel.splats;
    const hlod_store_extra *x = e->sel.extras;
    if (!sp->n || !x)
        return;
    if (e->splat_cap < sp->n) {
        hlod_gpu_splat *b = hlod_mem_realloc(&e->d.allocator, e->splat_buf, sp->n * sizeof *b);
        if (!b)
            return; /* the frame goes without its splats */
        e->splat_buf = b;
        e->splat_cap = sp->n;
    }
    for (size_t k = 0; k < sp->n; k++) {
        const hlod_store_node *n = &e->nodes[sp->v[k]];
        const uint8_t *c = x[sp->v[k]].color;
        double rel[3], d2 = 0, nl = 0, dot = 0;
        for (int a = 0; a < 3; a++) {
            rel[a] = 0.5 * (n->bbox_min[a] + n->bbox_max[a]) - cam->position[a];
            d2 += rel[a] * rel[a];
            nl += (double)n->avg_normal[a] * n->avg_normal[a];
        }
        double d = sqrt(d2), nz = 1;
        if (nl > 0 && d > 0) {
            for (int a = 0; a < 3; a++)
                dot -= n->avg_normal[a] * rel[a] / (d * sqrt(nl));
            nz = n->avg_normal[2] / sqrt(nl);
            if (dot < 0)
                nz = -nz; /* back faces are lit like front faces */
        } else {
            dot = 1;
            nz = d > 0 ? -rel[2] / d : 1;
        }
        double light = hlod_gpu_light(dot, nz);
        hlod_gpu_splat *s = &e->splat_buf[k];
        for (int a = 0; a < 3; a++) {
            s->pos[a] = (float)rel[a];
            double v = c[a] * light;
            s->rgba[a] = (uint8_t)(v > 255 ? 255 : v + 0.5);
        }
        s->rgba[3] = 255;
    }
    /* the size the walk stopped at (klein-auto's is fractional: rounded up,
     * so a splat covers its node's box) */
    (void)hlod_gpu_splats(e->d.renderer, e->splat_buf, (uint32_t)sp->n, (float)ceil(e->sel.splat_px));
}

/* cam is the frame's camera; at a reduced resolution (dyn_res) the image
 * is scaled up to out's width and height. */
static void draw_frame(hlod_engine *e, const hlod_camera *cam, const hlod_camera *out,
                       const hlod_view *view)
{
    hlod_renderer *r = e->d.renderer;
    order_draws(e, cam);
    int in_place = 0;
    if (cam->width == out->width && cam->height == out->height) {
        hlod_gpu_begin(r, cam);
    } else if (hlod_gpu_begin_scaled(r, cam, out->width, out->height) != HLOD_OK) {
        /* no framebuffer for it (logged): drawn at full size, without
         * occlusion (the view is the small one), and full size from now */
        hlod_gpu_begin(r, out);
        e->dynres_failed = 1;
        e->st.res_scale = 1;
        in_place = 1;
    }
    e->drawn.n = 0;
    if (e->lumi) { /* the sparse mesh coloured from the repository's views */
        lumi_draw(e, cam, e->draw_list);
        e->drawn_valid = 0;
        hlod_gpu_end(r, 1);
        return;
    }
    if (!in_place && e->d.occlusion > 0 && hlod_policy_has(e->d.policy, HLOD_PT_OCCLUDE)) {
        draw_occluded(e, cam, view);
        draw_splats(e, cam); /* far_cubes' cubes, over what occlusion left */
    } else {
        for (size_t k = 0; k < e->draw_list->n; k++)
            gpu_draw_listed(e, cam, e->draw_list, k);
        draw_splats(e, cam);
        e->drawn_valid = 0; /* replay draws the selection */
        hlod_gpu_end(r, 1);
        return;
    }
    e->drawn_valid = 1;
    hlod_gpu_end(r, 1);
}

/* Residency evicts what the selection values least: nodes priced this
 * frame by priority, the others before them, oldest first; never one
 * drawn this frame, nor one refined this frame (the front below it stands
 * on it: evicted for a nearer prefetch, it drew its parent in its place
 * the next frame, its whole subtree toggled down, and was read again). */
int hlod_engine_evict_key(void *user, uint32_t node, double *key)
{
    assert(user && key);
    const hlod_engine *e = user;
    const hlod_node_frame *f = &e->sel.fr[node];
    if (f->drawn == e->frame || f->refined == e->frame)
        return 0;
    *key = f->priced == e->frame ? f->priority : -(double)(e->frame - f->priced);
    return 1;
}

/* Camera velocity (model units per second) for the distance look-ahead;
 * returns whether the camera moved since the last frame. */
static int camera_motion(hlod_engine *e, const hlod_camera *cam, double dt, double vel[3])
{
    int moved = !e->have_prev;
    vel[0] = vel[1] = vel[2] = 0;
    if (e->have_prev && dt > 0)
        for (int k = 0; k < 3; k++)
            vel[k] = (cam->position[k] - e->prev_cam.position[k]) / dt;
    for (int k = 0; k < 3 && e->have_prev; k++)
        moved |= cam->position[k] != e->prev_cam.position[k];
    /* the whole camera (a turn on the spot is not still) */
    int same = e->have_prev && memcmp(e->prev_cam.position, cam->position, sizeof cam->position) == 0 &&
               memcmp(e->prev_cam.view, cam->view, sizeof cam->view) == 0 &&
               memcmp(e->prev_cam.proj, cam->proj, sizeof cam->proj) == 0 &&
               e->prev_cam.width == cam->width && e->prev_cam.height == cam->height &&
               e->prev_cam.fov_y_deg == cam->fov_y_deg;
    e->still_run = same ? e->still_run + 1 : 0;
    /* the view axis's turn (the view matrix's third row), radians per second */
    e->turn_rad_s = 0;
    if (e->have_prev && dt > 0) {
        double dot = 0;
        for (int k = 0; k < 3; k++)
            dot += cam->view[4 * k + 2] * e->prev_cam.view[4 * k + 2];
        dot = dot > 1 ? 1 : dot < -1 ? -1 : dot;
        e->turn_rad_s = acos(dot) / dt;
    }
    e->prev_cam = *cam;
    e->have_prev = 1;
    return moved;
}

/* What the budget keeps for uploads: their cap (upload_budget_ms; uploads
 * predicted to run a quarter past it wait, see residency.c).  Reserved
 * whether this frame uploads less or more, so that the budget a still
 * camera's selection sees does not move with the loader; an overrun is
 * left to the deadline margin. */
static double upload_reserve(const hlod_engine *e)
{
    return e->d.upload_budget_ms > 0 ? e->d.upload_budget_ms : 0.1 * e->d.target_ms;
}

/* After the frame is drawn and measured: the cost model learns from it. */
static void learn(hlod_engine *e, double measured, double upload, double budget, int moved)
{
    hlod_cost_model *m = &e->cost;
    const hlod_frame_stats *st = &e->st;
    double front = hlod_cost_model_predict(m, st->nodes_drawn, st->cost_drawn, st->pixels_drawn) -
                   m->theta[0];
    if (!e->d.deterministic)
        hlod_cost_model_fit(m, &e->d, st->nodes_drawn, st->cost_drawn, st->pixels_drawn,
                            measured - upload);
    if (hlod_policy_has(e->d.policy, HLOD_PT_SHARE))
        hlod_cost_model_adapt_share(m, front, budget, moved, e->sel.cap_hits,
                                    e->sel.slice_denied);
    if (hlod_policy_has(e->d.policy, HLOD_PT_SSE))
        hlod_cost_model_adapt_sse(
            m, (e->d.deterministic ? e->st.estimated_ms : measured) / e->d.target_ms);
    if (hlod_policy_has(e->d.policy, HLOD_PT_AUTOSPLAT))
        hlod_cost_model_adapt_splat(
            m, (e->d.deterministic ? e->st.estimated_ms : measured) / e->d.target_ms);
}

/* Inputs: a new frame's stamp and stats, and the camera's motion (its
 * velocity into vel).  Returns whether the camera moved. */
static int frame_inputs(hlod_engine *e, const hlod_camera *cam, double dt, double vel[3])
{
    e->frame++;
    memset(&e->st, 0, sizeof e->st);
    e->st.frame = e->frame - 1;
    hlod_residency_begin_frame(&e->res, e->frame);
    return camera_motion(e, cam, dt, vel);
}

/* Load: finished reads are uploaded within the upload reserve.  A big
 * upload that has waited may use the room the last front's estimate, with
 * the deadline margin, left of the target. */
static void frame_uploads(hlod_engine *e)
{
    double t0 = hlod_now_ms();
    double room = e->have_front ? 0.8 * (e->d.target_ms - e->cost.margin * e->last_front_ms) : 0;
    hlod_residency_collect(&e->res, upload_reserve(e), room);
    e->st.upload_ms = hlod_now_ms() - t0;
}

/* The uploads this frame's fit leaves out: none when deterministic or
 * under a time model (its frame time is the whole frame, and a
 * wall-clock upload would bias a synthetic machine's budget and fit). */
static double frame_upload_ms(const hlod_engine *e)
{
    return e->d.deterministic || e->d.time_model ? 0 : e->st.upload_ms;
}

/* The budget that bounds the front's estimate: with the margin the
 * measured spread needs, deadline_quantile of frames finish within the
 * target (margin 1 when aiming at the mean, as the paper does).  The
 * uploads' share is their cap (upload_budget_ms), not this frame's: with a
 * still camera whose loader keeps prefetching, the frames that upload and
 * those that do not would otherwise hand the selection two budgets in
 * turn, and marginal nodes would toggle with them.  At least a tenth of
 * the target. */
static double frame_budget(const hlod_engine *e, int *at_floor)
{
    const hlod_cost_model *m = &e->cost;
    const double target = e->d.target_ms;
    const double reserve = e->d.deterministic || e->d.time_model ? 0 : upload_reserve(e);
    double budget = (target - reserve) / m->margin - m->theta[0];
    /* below full resolution detail waits at the floor (dynres.h) */
    *at_floor = budget <= 0.1 * target || e->dynres.step > 0;
    return *at_floor ? 0.1 * target : budget;
}

/* The camera this frame is selected and drawn with: cam, or at dyn_res
 * its width and height scaled (dynres.h). */
static hlod_camera frame_camera(hlod_engine *e, const hlod_camera *cam)
{
    hlod_camera c = *cam;
    if (e->d.dyn_res <= 0 || e->dynres_failed) {
        if (e->dynres.step)
            hlod_dynres_reset(&e->dynres);
        return c;
    }
    double s = hlod_dynres_scale(&e->dynres);
    long w = lround(cam->width * s), h = lround(cam->height * s);
    c.width = w > 1 ? (uint32_t)w : 1;
    c.height = h > 1 ? (uint32_t)h : 1;
    return c;
}

/* What the selection is given: the cost model's terms, the budget and
 * the roots' share, occlusion's verdicts, and the hold's inputs when the
 * camera has stood still. */
static hlod_select_in select_inputs(hlod_engine *e, double budget, int moved)
{
    const hlod_cost_model *m = &e->cost;
    hlod_select_in in = {.frame = e->frame,
                         .v_time = m->theta[2],
                         .draw_ms = m->theta[1],
                         .pixel_ms = m->theta[3],
                         .occlusion = e->d.occlusion > 0 && e->d.renderer != NULL,
                         .occ = &e->occ,
                         .still = !moved,
                         .hold_since = hlod_hold_since(e->still_run, e->frame),
                         .sse_pixels = m->sse_pixels,
                         .splat_px = hlod_policy_has(e->d.policy, HLOD_PT_AUTOSPLAT)
                                         ? m->splat_px
                                         : hlod_policy_has(e->d.policy, HLOD_PT_CUBES)
                                         ? e->d.cube_px
                                         : e->d.splat_px,
                         .budget_ms = budget,
                         .share_ms = budget * m->share_gain};
    hlod_hold_inputs(&e->hold, hlod_policy_has(e->d.policy, HLOD_PT_HOLD), e->frame,
                     e->d.target_ms, &e->last_load, &in);
    return in;
}

/* Publish: the frame's measured time and the model's view of it go into
 * the stats; the hold learns whether it met the target. */
static void publish(hlod_engine *e, const hlod_select_in *in, double measured, double upload)
{
    const hlod_cost_model *m = &e->cost;
    e->st.measured_ms = measured;
    e->st.v_time = m->theta[2];
    e->st.fixed_ms = m->theta[0];
    e->st.margin = m->margin;
    e->st.budget_ms = in->budget_ms;
    hlod_hold_measured(&e->hold, measured, e->d.target_ms);
    e->last_load = (hlod_front_load){e->st.nodes_drawn, e->st.cost_drawn, e->st.pixels_drawn};
    e->st.share_gain = m->share_gain;
    e->st.estimated_ms =
        hlod_cost_model_predict(m, e->st.nodes_drawn, e->st.cost_drawn, e->st.pixels_drawn) +
        upload;
    e->st.sse_pixels = m->sse_pixels;
    e->st.splat_px = hlod_policy_has(e->d.policy, HLOD_PT_ADDITIVE) ? in->splat_px : 0;
    e->last_front_ms = e->st.estimated_ms - upload;
    e->have_front = 1;
}

/* After the frame: residency admits and evicts for what the selection
 * wanted (policies that stream), and closes the frame. */
static void frame_residency(hlod_engine *e)
{
    if (hlod_policy_has(e->d.policy, HLOD_PT_STREAM)) {
        hlod_evict_order order = {hlod_engine_evict_key, e};
        hlod_residency_schedule(&e->res, &order);
    }
    hlod_residency_end_frame(&e->res);
}

/* Policy rzb's selection: no front; its ranges of faces (one draw each)
 * and its points, which the stats count. */
static hlod_result rzb_select(hlod_engine *e, const hlod_view *view)
{
    hlod_selection *s = &e->sel;
    s->draw.n = s->splats.n = s->coned.n = 0;
    hlod_rzb_set_cache(e->rzb, (size_t)e->d.rzb_cache_mb << 20);
    hlod_result r = hlod_rzb_set_copies(e->rzb, e->d.rzb_copies);
    if (r != HLOD_OK)
        return r;
    e->rzb_view = *view;
    hlod_rzb_params p = {.eps = e->d.rzb_eps,
                         .d = e->d.splat_px,
                         .seed = 0x9E3779B97F4A7C15ull * e->frame,
                         .frame = e->frame,
                         .splat_c = e->d.rzb_splat_c > 0 && e->d.renderer,
                         .no_raster = !(e->d.rzb_raster > 0)};
    r = hlod_rzb_frame(e->rzb, view, &p, &e->rzb_out);
    e->st.nodes_drawn = (uint32_t)e->rzb_out.range_count;
    e->st.tris_drawn = e->rzb_out.range_tris;
    e->st.cost_drawn = (double)e->rzb_out.range_tris;
    e->st.splats = (uint32_t)e->rzb_out.splat_count;
    return r;
}

/* Policy lumigraph: the views decoded since the last frame uploaded, this
 * camera's blend made and its missing views asked for (lumigraph.h). */
static hlod_result lumi_frame(hlod_engine *e, const hlod_camera *cam)
{
    hlod_lumi_stats ls;
    long x = hlod_excuse_begin(); /* uploads: GL may wait for the driver's threads */
    hlod_result r = hlod_lumi_frame(e->lumi, e->d.renderer, cam, e->d.lumi_uploads,
                                    &e->lumi_frame, &ls);
    hlod_excuse_end(x);
    e->st.lumi_bytes = ls.bytes;
    e->st.lumi_answer_max = ls.answer_max;
    e->st.lumi_uploads = ls.uploads;
    e->st.lumi_missing = ls.missing;
    e->st.upload_ms += ls.upload_ms;
    e->lumi_frame.tolerance = (float)e->d.lumi_tol; /* a live setting */
    return r;
}

/* The frame in its steps: inputs, load, select, draw, measure and
 * publish, learn, and residency for the next. */
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
    double t_start = hlod_now_ms(), vel[3];
    const long slept0 = hlod_sleeps_now(), excused0 = hlod_sleeps_excused(),
               paged0 = hlod_sleeps_paged();
    int moved = frame_inputs(e, cam, dt, vel), at_floor;
    frame_uploads(e);
    const hlod_camera fcam = frame_camera(e, cam);
    const double upload = frame_upload_ms(e), budget = frame_budget(e, &at_floor);
    e->st.res_scale = (double)fcam.width / cam->width;
    hlod_view view;
    hlod_view_init(&view, &fcam, vel, e->d.velocity_lookahead_s);
    view.turn_rad_s = e->turn_rad_s;
    hlod_select_in in = select_inputs(e, budget, moved);
    double t0 = hlod_now_ms();
    hlod_result r = e->rzb ? rzb_select(e, &view) : hlod_select(&e->sel, &e->res, &view, &in);
    e->st.traversal_ms = hlod_now_ms() - t0;
    if (r != HLOD_OK)
        return r;
    if (e->lumi && (r = lumi_frame(e, &fcam)) != HLOD_OK)
        return r;
    if (e->d.renderer) {
        long x = hlod_excuse_begin(); /* GL may wait for the driver's threads */
        draw_frame(e, &fcam, cam, &view);
        hlod_excuse_end(x);
        e->st.gl_draws = hlod_gpu_draw_calls(e->d.renderer);
    }
    double measured = e->d.time_model ? e->d.time_model(e->d.time_model_user, &e->st)
                                      : hlod_now_ms() - t_start;
    publish(e, &in, measured, upload);
    /* a step changes every pixel count: a still view's hold starts over
     * with inputs taken at the new size (held, the floor's budget would
     * outlast the step back to full size) */
    if (e->d.dyn_res > 0) {
        /* the frame would miss with no detail at all: the budget at its
         * floor, or its time less what detail costs in the model (its
         * draws and triangles; the pixels stay, the fixed part too) still
         * over the target */
        const hlod_frame_stats *st = &e->st;
        double detail = hlod_cost_model_predict(&e->cost, st->nodes_drawn, st->cost_drawn, 0) -
                        e->cost.theta[0];
        int coarsest = at_floor || measured - fmax(detail, 0) > e->d.target_ms;
        if (hlod_dynres_update(&e->dynres, measured, e->d.target_ms, coarsest))
            e->still_run = 0;
    }
    learn(e, measured, upload, budget, moved);
    frame_residency(e);
    /* the render thread slept outside GL, synchronous reads and the
     * logger: it waited (sleeps.h), unless the system was reading a page
     * of the process back in (a major fault: counted apart) */
    long slept = hlod_sleeps_now() - slept0 - (hlod_sleeps_excused() - excused0);
    long paged = hlod_sleeps_paged() - paged0;
    if (paged > slept)
        paged = slept > 0 ? slept : 0;
    slept -= paged;
    e->st.render_waits = slept > 0 ? (uint32_t)slept : 0;
    e->st.render_paged = paged > 0 ? (uint32_t)paged : 0;
    if (stats)
        *stats = e->st;
    return HLOD_OK;
}

/* ---- replay ---- */

hlod_result hlod_engine_replay(hlod_engine *e, const hlod_camera *cam, int occlusion, double *ms)
{
    if (ms)
        *ms = 0;
    if (!e || !cam || !camera_ok(cam) || e->frame == 0)
        return HLOD_ERR_INVALID_ARG;
    double t0 = hlod_now_ms();
    hlod_renderer *r = e->d.renderer;
    if (e->rzb) {
        /* rzb's selection is its sampling, most of its frame: done again
         * for the view and seed of the last frame, it gives the same
         * points (a replay of the draw alone timed 4 ms of a 215 ms
         * frame) */
        hlod_view v = e->rzb_view;
        hlod_result sr = rzb_select(e, &v);
        if (sr != HLOD_OK)
            return sr;
    }
    if (r) {
        /* the last frame's nodes, in its draw order: with occlusion, the
         * ones it drew; without, the whole selection.  A frame that culled
         * drew its two passes in turn; without culling, its culled nodes
         * are drawn last, after the same nodes in the same order, so that
         * only what culling removed can change a pixel, not where a depth
         * tie between two nodes fell in the order */
        const hlod_u32_vec *list = e->drawn_valid ? &e->drawn
                                   : e->draw_list  ? e->draw_list
                                                   : &e->sel.draw;
        hlod_gpu_begin(r, cam);
        if (e->lumi)
            lumi_draw(e, cam, list);
        else
            for (size_t k = 0; k < list->n; k++)
                gpu_draw_listed(e, cam, list, k);
        if (!occlusion && e->drawn_valid)
            for (size_t k = 0; k < e->later.n; k++)
                if (hlod_occlusion_hidden(&e->occ, e->later.v[k]) == e->frame)
                    gpu_draw_node(e, cam, e->later.v[k]);
        draw_splats(e, cam);
        hlod_gpu_end(r, 1);
    }
    double t = e->d.time_model ? e->d.time_model(e->d.time_model_user, &e->st)
                               : hlod_now_ms() - t0;
    if (ms)
        *ms = t;
    return HLOD_OK;
}

hlod_result hlod_engine_replay_coned(hlod_engine *e, const hlod_camera *cam, uint32_t *drawn,
                                     uint32_t *unchecked)
{
    if (drawn)
        *drawn = 0;
    if (unchecked)
        *unchecked = 0;
    if (!e || !cam || !camera_ok(cam) || e->frame == 0)
        return HLOD_ERR_INVALID_ARG;
    if (!e->d.renderer)
        return HLOD_OK;
    /* the frame's nodes as it drew them, then the culled ones: their faces
     * all face away, so with back faces culled (HLOD_RENDER_SOLID) no
     * pixel changes */
    const hlod_u32_vec *list = e->drawn_valid ? &e->drawn
                               : e->draw_list  ? e->draw_list
                                               : &e->sel.draw;
    uint32_t missed = 0, done = 0;
    hlod_gpu_begin(e->d.renderer, cam);
    if (e->lumi)
        hlod_gpu_lumi_begin(e->d.renderer, cam, &e->lumi_frame);
    for (size_t k = 0; k < list->n; k++)
        gpu_draw_listed(e, cam, list, k);
    for (size_t k = 0; k < e->sel.coned.n; k++) {
        uint32_t i = e->sel.coned.v[k];
        if (hlod_residency_state(&e->res, i) == HLOD_NODE_RESIDENT &&
            hlod_residency_gpu(&e->res, i)) {
            gpu_draw_node(e, cam, i);
            done++;
        } else {
            missed++;
        }
    }
    hlod_gpu_end(e->d.renderer, 1);
    if (drawn)
        *drawn = done;
    if (unchecked)
        *unchecked = missed;
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
        if (!hlod_u32_push(&e->d.allocator, &stack, i))
            r = HLOD_ERR_NOMEM;
    while (r == HLOD_OK && stack.n) {
        uint32_t i = stack.v[--stack.n];
        if (hlod_view_outside(&view, e->nodes[i].bbox_min, e->nodes[i].bbox_max) > 0)
            continue;
        uint32_t c0 = hlod_store_first_child(e->nodes, i), c1 = hlod_store_child_end(e->nodes, i);
        hlod_node_state ns = hlod_residency_state(&e->res, i);
        if (ns != HLOD_NODE_RESIDENT && ns != HLOD_NODE_BAD) {
            hlod_result lr = hlod_residency_load_now(&e->res, i);
            if (lr != HLOD_OK)
                hlod_logf(&e->d.logger, HLOD_LOG_WARN, "%s: node %u: %s; its parent stands in",
                          hlod_store_path(e->store), i, hlod_result_str(lr));
            if (lr == HLOD_ERR_NOMEM)
                r = lr;
        }
        for (uint32_t c = c0; c < c1 && r == HLOD_OK; c++)
            if (!hlod_u32_push(&e->d.allocator, &stack, c))
                r = HLOD_ERR_NOMEM;
    }
    hlod_mem_free(&e->d.allocator, stack.v);
    return r;
}

/* ---- inspection ---- */

hlod_node_state hlod_engine_node_state(const hlod_engine *e, uint32_t node)
{
    if (!e || node >= e->node_count)
        return HLOD_NODE_ABSENT;
    return hlod_residency_state(&e->res, node);
}

int hlod_engine_node_drawn(const hlod_engine *e, uint32_t node)
{
    if (!e || node >= e->node_count || e->frame == 0)
        return 0;
    return e->sel.fr[node].drawn == e->frame;
}

void hlod_engine_node_debug(const hlod_engine *e, uint32_t node, double *hyst,
                            double *time_slice, double *time_needed, double *priority)
{
    const hlod_node_frame *f = e && node < e->node_count ? &e->sel.fr[node] : NULL;
    if (hyst)
        *hyst = f ? f->hyst : 0;
    if (time_slice)
        *time_slice = f ? f->slice : 0;
    if (time_needed)
        *time_needed = f ? f->needed : 0;
    if (priority)
        *priority = f ? f->priority : 0;
}
