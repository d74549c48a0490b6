/*
 * cost_model.c - the frame cost model and the gains fitted to it
 * (cost_model.h; README, "The runtime").
 *
 * A frame costs a fixed part (clear, fill, swap, traversal) plus a part
 * proportional to the drawn cost; feeding back only v_time would make it
 * swallow the fixed part and misprice every node.  We fit
 *   measured_ms = fixed_ms + v_time * drawn_cost
 * by exponentially weighted least squares (forgetting factor 0.93: about
 * 14 frames of memory, so it follows a change within a few frames without
 * chasing one noisy frame), with a small ridge holding v_time when the
 * drawn cost does not vary.  Both outputs are clamped to sane ranges.
 */
#include "cost_model.h"

#include <math.h>

#define FORGET 0.93
#define RIDGE 0.05

void hlod_cost_model_init(hlod_cost_model *m, const hlod_engine_desc *d)
{
    *m = (hlod_cost_model){0};
    m->v_time = m->fit_v = d->deterministic ? d->fixed_v_time : 1e-4;
    m->fixed_ms = m->fit_fixed = d->deterministic ? d->fixed_frame_ms : 0.2 * d->target_ms;
    m->sse_pixels = d->sse_pixels;
    m->share_gain = 1;
}

void hlod_cost_model_set(hlod_cost_model *m, const hlod_engine_desc *old,
                         const hlod_engine_desc *d)
{
    if (d->sse_pixels != old->sse_pixels)
        m->sse_pixels = d->sse_pixels;
    if (d->deterministic) {
        m->v_time = d->fixed_v_time;
        m->fixed_ms = d->fixed_frame_ms;
    }
}

void hlod_cost_model_fit(hlod_cost_model *m, double target, double x, double y)
{
    if (!(isfinite(x) && isfinite(y)) || x < 0 || y < 0)
        return;
    m->s0 = FORGET * m->s0 + 1;
    m->sx = FORGET * m->sx + x;
    m->sy = FORGET * m->sy + y;
    m->sxx = FORGET * m->sxx + x * x;
    m->sxy = FORGET * m->sxy + x * y;
    /* Weighted least squares with a ridge pulling v_time toward its last
     * value, scaled by mean(x)^2 so it is unit-free:
     *   [s0, sx; sx, sxx + k] [a; b] = [sy; sxy + k * b_prev],
     *   k = RIDGE * s0 * mean(x)^2.
     * With no spread in x the data fix only a + b * mean(x): the ridge then
     * keeps v_time and lets the fixed part take the change.  A wrong v_time
     * moves the budget, which moves x, which gives the spread that corrects
     * it: the fit explores by itself. */
    double mean_x = m->sx / m->s0;
    double b_prev = m->fit_v;
    double k = RIDGE * m->s0 * mean_x * mean_x;
    double m00 = m->s0, m01 = m->sx, m11 = m->sxx + k;
    double r0 = m->sy, r1 = m->sxy + k * b_prev;
    double det = m00 * m11 - m01 * m01;
    double a = m->fit_fixed, b = b_prev;
    if (det > 1e-12 * m00 * m11 && m11 > 0) {
        a = (r0 * m11 - m01 * r1) / det;
        b = (m00 * r1 - m01 * r0) / det;
    } else if (m->s0 > 0) {
        a = m->sy / m->s0; /* nothing drawn yet: all of it is fixed */
    }
    if (!(b > 1e-9) || !isfinite(b))
        b = 1e-9;
    if (!(b < 1e6))
        b = 1e6;
    /* keep a inside [0, 0.8 target] and re-fit b to the mean if clamped */
    double hi_a = 0.8 * target;
    if (!(a >= 0) || !(a <= hi_a)) {
        a = !(a >= 0) ? 0 : hi_a;
        double mean_y = m->sy / m->s0;
        if (mean_x > 0 && mean_y > a)
            b = (mean_y - a) / mean_x;
    }
    m->fit_fixed = a;
    m->fit_v = b;
    /* Publish only changes the noise of one frame cannot explain (3% of
     * v_time, 3% of the target for the fixed part): with a still camera the
     * selection then sees constant inputs and its hysteresis settles, while
     * a real change still passes within a frame or two. */
    if (fabs(b - m->v_time) > 0.03 * m->v_time || fabs(a - m->fixed_ms) > 0.03 * target) {
        m->v_time = b;
        m->fixed_ms = a;
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
 * The budget still bounds the estimate (selection), so the gain moves
 * detail between nodes and never pushes the frame over the target. */
void hlod_cost_model_adapt_share(hlod_cost_model *m, hlod_policy policy, double est,
                                 double budget, int moved, uint32_t cap_hits,
                                 uint32_t slice_denied)
{
    if (policy != HLOD_POLICY_LAKHIA && policy != HLOD_POLICY_NOHYST)
        return;
    double ratio = budget > 0 ? est / budget : 1;
    double g = m->share_gain;
    if (cap_hits && moved) {
        g *= 0.97;
    } else if (ratio < 0.85 && slice_denied) {
        double up = ratio > 0 ? sqrt(0.92 / ratio) : 1.1;
        g *= up < 1.1 ? up : 1.1;
    }
    m->share_gain = g < 1 ? 1 : g > 64 ? 64 : g;
}

/* The SSE policy's pixel threshold follows the frame time: coarser when
 * over target, finer when under; the square root damps the response. */
void hlod_cost_model_adapt_sse(hlod_cost_model *m, double ratio)
{
    if (!(isfinite(ratio) && ratio > 0))
        return;
    double f = sqrt(ratio);
    f = f < 0.8 ? 0.8 : f > 1.25 ? 1.25 : f;
    m->sse_pixels *= f;
    if (m->sse_pixels < 0.05)
        m->sse_pixels = 0.05;
    if (m->sse_pixels > 1e4)
        m->sse_pixels = 1e4;
}
