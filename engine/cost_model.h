/*
 * cost_model.h - what a frame costs, and the two gains fitted to it
 * (README, "The runtime": cost model, share gain, SSE threshold).
 *
 *   measured_ms = fixed_ms + v_time * drawn_cost
 *
 * fitted by exponentially weighted least squares with a ridge on v_time.
 * The selection reads only the published values (v_time, fixed_ms,
 * share_gain, sse_pixels); the fit keeps its own and publishes a change
 * only when one frame's noise cannot explain it.  Render thread only.
 */
#ifndef HLOD_ENGINE_COST_MODEL_H
#define HLOD_ENGINE_COST_MODEL_H

#include "hlod/engine.h"

typedef struct hlod_cost_model {
    /* published: what the selection uses */
    double v_time;          /* ms per unit of cost (eq. 1) */
    double fixed_ms;        /* the frame's fixed part */
    double share_gain;      /* roots' shareTime = gain * budget, in [1, 64] */
    double sse_pixels;      /* the SSE policy's adaptive threshold */
    /* the fit's own state */
    double fit_v, fit_fixed;
    double s0, sx, sy, sxx, sxy; /* exponentially weighted sums */
} hlod_cost_model;

/* Starts from the descriptor: fixed values when deterministic, else
 * v_time 1e-4 and a fixed part of 20% of the target. */
void hlod_cost_model_init(hlod_cost_model *m, const hlod_engine_desc *d);

/* Settings changed between frames (hlod_engine_set): old is the engine's
 * descriptor before, d the one after. */
void hlod_cost_model_set(hlod_cost_model *m, const hlod_engine_desc *old,
                         const hlod_engine_desc *d);

/* One measured frame: x the drawn cost, y its time (ms) without uploads.
 * Non-finite or negative samples are ignored. */
void hlod_cost_model_fit(hlod_cost_model *m, double target_ms, double x, double y);

/* The roots' share gain after a frame whose estimate was est against
 * budget (both ms); cap_hits and slice_denied are the selection's counts
 * of refinements the budget bound and the time slices refused. */
void hlod_cost_model_adapt_share(hlod_cost_model *m, hlod_policy policy, double est,
                                 double budget, int moved, uint32_t cap_hits,
                                 uint32_t slice_denied);

/* The SSE threshold after a frame that took ratio times the target. */
void hlod_cost_model_adapt_sse(hlod_cost_model *m, double ratio);

#endif
