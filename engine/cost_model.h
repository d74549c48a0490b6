/*
 * cost_model.h - what a frame costs, how sure the engine is of it, and the
 * gains fitted to it (docs/runtime.md, "The cost model and deadline margin").
 *
 *   measured_ms = fixed_ms + draw_ms * draws + v_time * cost + pixel_ms * pixels
 *
 * draws: nodes drawn; cost: the sum of eq. 1 over them (the paper's
 * triangle term); pixels: the screen pixels their projected boxes cover,
 * clipped to the screen (the fill term of Funkhouser and Sequin's
 * max(per-primitive, per-pixel) model, summed instead of maxed so one
 * linear fit holds both).  The frame time is taken without uploads.
 *
 * The selection reads only the published values.  The fit keeps its own
 * and publishes a change only when the data call for it (see the .c file):
 * with a still camera the inputs of the selection then stay constant
 * whatever the machine's noise does, and its hysteresis settles.
 *
 * The deadline margin: the engine aims at a quantile of the frame time
 * (deadline_quantile, 99 % by default) by dividing what the front may take
 * by margin = exp(median + z * sigma) of the model's log residuals over the
 * last HLOD_COST_WINDOW frames.  aim_mean (the paper) holds margin at 1.
 * Render thread only.
 */
#ifndef HLOD_ENGINE_COST_MODEL_H
#define HLOD_ENGINE_COST_MODEL_H

#include "hlod/engine.h"

#define HLOD_COST_TERMS 4    /* fixed, per draw, per unit of cost, per pixel */
#define HLOD_COST_WINDOW 512 /* frames of residuals for the margin (17 s at 30 Hz) */
#define HLOD_COST_EMPTY 9    /* frames that drew nothing whose median floors the fixed part */

typedef struct hlod_cost_sample {
    double x[HLOD_COST_TERMS]; /* 1, draws, cost, pixels */
    double y;                  /* measured ms without uploads */
} hlod_cost_sample;

typedef struct hlod_cost_model {
    /* published: what the selection uses */
    double theta[HLOD_COST_TERMS]; /* fixed_ms, draw_ms, v_time, pixel_ms */
    double margin;                 /* >= 1; 1 when aiming at the mean */
    double share_gain;             /* roots' shareTime = gain * budget, in [1, 64] */
    double sse_pixels;             /* the SSE policy's adaptive threshold */
    double splat_px;               /* klein-auto's adaptive splat size, pixels */
    /* the fit's own state */
    double a[HLOD_COST_TERMS][HLOD_COST_TERMS]; /* exponentially weighted x x^T */
    double b[HLOD_COST_TERMS];                  /* exponentially weighted x y */
    double s0;                                  /* weight of the sums */
    hlod_cost_sample ring[HLOD_COST_WINDOW];
    uint32_t ring_n, ring_head;
    uint32_t scale_updates, shape_updates, margin_updates; /* counts, for tests */
    uint32_t settled_run;          /* frames in a row with the same front */
    uint64_t frames;               /* samples fitted */
    uint64_t shape_at;             /* frames when the shape last changed */
    uint64_t scale_at;             /* frames when the scale last changed */
    int scale_dir;                 /* and which way: +1 up, -1 down */
    double sigma;                  /* robust spread of the log residuals (last update) */
    double empty[HLOD_COST_EMPTY]; /* measured ms of the last frames that drew nothing */
    uint32_t empty_n, empty_head;
    double fixed_floor;            /* their median: the fixed part is never below it */
} hlod_cost_model;

/* Starts from the descriptor: the fixed values when deterministic (no
 * draw or pixel terms, margin 1), else v_time 1e-4, a fixed part of 20 %
 * of the target, and the margin a 15 % spread would need. */
void hlod_cost_model_init(hlod_cost_model *m, const hlod_engine_desc *d);

/* Settings changed between frames (hlod_engine_set): old is the engine's
 * descriptor before, d the one after. */
void hlod_cost_model_set(hlod_cost_model *m, const hlod_engine_desc *old,
                         const hlod_engine_desc *d);

/* The model's prediction (ms, no uploads) for a front of these totals. */
double hlod_cost_model_predict(const hlod_cost_model *m, double draws, double cost,
                               double pixels);

/* One measured frame: the drawn totals and its time without uploads (ms).
 * Non-finite or negative samples are ignored. */
void hlod_cost_model_fit(hlod_cost_model *m, const hlod_engine_desc *d, double draws,
                         double cost, double pixels, double y);

/* The roots' share gain after a frame whose estimate was est against
 * budget (both ms); cap_hits and slice_denied are the selection's counts
 * of refinements the budget bound and the time slices refused.  For the
 * policies that share time (policy.h, HLOD_PT_SHARE). */
void hlod_cost_model_adapt_share(hlod_cost_model *m, double est, double budget, int moved,
                                 uint32_t cap_hits, uint32_t slice_denied);

/* The SSE threshold after a frame that took ratio times the target. */
void hlod_cost_model_adapt_sse(hlod_cost_model *m, double ratio);

/* klein-auto (Klein 4.5's splat size, chosen each frame; ours): the splat
 * size times sqrt(ratio), ratio the frame's time over the target (the
 * estimate's when deterministic), each step within [0.8, 1.25], the size
 * within [1, 64] pixels.  A frame's triangles fall about as the square of
 * the splat size where splats stand in for them. */
void hlod_cost_model_adapt_splat(hlod_cost_model *m, double ratio);

#endif
