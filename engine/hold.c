/*
 * hold.c - the still-camera hold (hold.h; docs/runtime.md, "The
 * still-camera hold").
 *
 * Why inputs are held: the fit, the margin and the share gain go on
 * learning from every frame, and on a noisy machine they move with it;
 * where a held front sat at its bound, each move coarsened it and the
 * next refined it again.  Why a held front still refines what the bound
 * coarsened in this hold: else a moment's slowdown leaves a still view
 * coarse until the camera moves.  Why late data still refines it
 * (still_refine_late): held whatever arrives, a still viewer over a slow
 * disk never sees the city sharpen (test_faults slow_reads).
 */
#include "hold.h"

#include <assert.h>

static void take(hlod_hold *h, const hlod_select_in *in, uint32_t frame, double target_ms,
                 int slowed)
{
    h->since = in->hold_since;
    h->taken = frame;
    h->target_ms = target_ms;
    h->budget_ms = in->budget_ms;
    h->share_ms = in->share_ms;
    h->v_time = in->v_time;
    h->draw_ms = in->draw_ms;
    h->pixel_ms = in->pixel_ms;
    h->misses = 0;
    h->slowed = slowed;
}

/* The budget the front leaves over under these inputs. */
static double room(double budget_ms, double draw_ms, double v_time, double pixel_ms,
                   const hlod_front_load *f)
{
    return budget_ms - (draw_ms * f->draws + v_time * f->cost + pixel_ms * f->pixels);
}

void hlod_hold_inputs(hlod_hold *h, int holds, uint32_t frame, double target_ms,
                      const hlod_front_load *front, hlod_select_in *in)
{
    assert(h && in && front);
    if (!in->hold_since || !holds) {
        h->since = 0;
        return;
    }
    if (h->since != in->hold_since || h->target_ms != target_ms) {
        take(h, in, frame, target_ms, 0);
        return;
    }
    if (__builtin_popcount(h->misses & 0xffffu) >= HOLD_SLOW_MISSES) {
        take(h, in, frame, target_ms, 1);
        return;
    }
    if (h->slowed && frame - h->taken >= HOLD_RECOVER && h->misses == 0 &&
        room(in->budget_ms, in->draw_ms, in->v_time, in->pixel_ms, front) >
            room(h->budget_ms, h->draw_ms, h->v_time, h->pixel_ms, front)) {
        take(h, in, frame, target_ms, 1); /* still after a slowdown: may come back further */
        return;
    }
    in->budget_ms = h->budget_ms;
    in->share_ms = h->share_ms;
    in->v_time = h->v_time;
    in->draw_ms = h->draw_ms;
    in->pixel_ms = h->pixel_ms;
}

void hlod_hold_measured(hlod_hold *h, double measured_ms, double target_ms)
{
    assert(h);
    if (h->since)
        h->misses = h->misses << 1 | (measured_ms > target_ms);
}

int hlod_hold_front(const hlod_node_frame *pf, uint32_t frame, uint32_t hold_since,
                    int still_refine_late, int refine)
{
    assert(pf && hold_since);
    if (pf->refined && pf->refined + 1 == frame)
        return 1;
    if (pf->drawn && pf->drawn + 1 == frame)
        return refine && (pf->capped >= hold_since ||
                          (still_refine_late && pf->waiting && pf->waiting + 1 == frame));
    return refine;
}
