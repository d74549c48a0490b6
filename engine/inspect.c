/*
 * inspect.c - the tests' window on an engine (inspect.h).
 */
#include "inspect.h"

#include "engine_internal.h"

#include <assert.h>
#include <string.h>

const hlod_store *hlod_inspect_store(const hlod_engine *e)
{
    assert(e);
    return e->store;
}

uint32_t hlod_inspect_frame(const hlod_engine *e)
{
    assert(e);
    return e->frame;
}

hlod_node_look hlod_inspect_node(const hlod_engine *e, uint32_t node)
{
    assert(e && node < e->node_count);
    const hlod_node_frame *f = &e->sel.fr[node];
    return (hlod_node_look){f->hyst,   f->slice, f->needed,  f->priority,
                            f->priced, f->drawn, f->refined};
}

const uint32_t *hlod_inspect_selected(const hlod_engine *e, size_t *n)
{
    assert(e && n);
    *n = e->sel.draw.n;
    return e->sel.draw.v;
}

uint32_t hlod_inspect_cap_hits(const hlod_engine *e)
{
    assert(e);
    return e->sel.cap_hits;
}

hlod_model_look hlod_inspect_model(const hlod_engine *e)
{
    assert(e);
    hlod_model_look m = {{0}, e->cost.margin, e->cost.scale_updates, e->cost.shape_updates,
                         e->cost.margin_updates};
    memcpy(m.theta, e->cost.theta, sizeof m.theta);
    return m;
}

uint64_t hlod_inspect_reserved_bytes(const hlod_engine *e)
{
    assert(e);
    return e->res.reserved_bytes;
}

int hlod_inspect_evictable(const hlod_engine *e, uint32_t node, double *key)
{
    assert(e && key && node < e->node_count);
    return hlod_engine_evict_key((void *)e, node, key);
}

int hlod_inspect_loader_idle(const hlod_engine *e)
{
    assert(e);
    return hlod_loader_idle(e->res.loader);
}

uint32_t hlod_inspect_pinned_count(const hlod_engine *e)
{
    assert(e);
    return e->res.pinned_count;
}

hlod_result hlod_inspect_select(hlod_engine *e, const hlod_hand_frame *in, hlod_frame_stats *st)
{
    assert(e && in && in->cam);
    hlod_view view;
    const double still[3] = {0, 0, 0};
    hlod_view_init(&view, in->cam, still, 0);
    uint32_t f = e->frame + 1;
    memset(&e->st, 0, sizeof e->st);
    hlod_residency_begin_frame(&e->res, f);
    hlod_select_in sin = {.frame = f,
                          .v_time = e->cost.theta[2],
                          .occlusion = in->occlusion,
                          .occ = in->occlusion ? &e->occ : NULL,
                          .still = in->still,
                          .budget_ms = in->budget_ms,
                          .share_ms = in->share_ms};
    hlod_result r = hlod_select(&e->sel, &e->res, &view, &sin);
    hlod_residency_end_frame(&e->res);
    e->frame = f;
    if (st)
        *st = e->st;
    return r;
}

void hlod_inspect_hide(hlod_engine *e, uint32_t node, uint32_t frame)
{
    assert(e && node < e->node_count);
    hlod_occlusion_mark(&e->occ, node, 0, frame);
}
