/*
 * dynres.h - resolution as the last knob (setting dyn_res; docs/runtime.md
 * "Dynamic resolution").
 *
 * Detail is the first knob: the selection fits its front to the frame's
 * budget.  When even the budget's floor (a tenth of the target: the
 * coarsest front the engine draws) misses target_ms, which a fill-bound
 * frame does (a software rasteriser, a 4K window on a weak GPU), the frame
 * renders at a smaller width and height and is scaled up to the window.
 *
 * Scales come in steps.  Down one when DYNRES_DOWN_OF of the last
 * DYNRES_WINDOW frames missed where no detail could help: the budget at
 * its floor, or the frame's time less the front's estimated variable part
 * still over the target (not in the first DYNRES_SETTLE frames: loading
 * and first uses, not fill).  Up one when every one of
 * the last DYNRES_WINDOW frames, grown to the next step's pixels (as if
 * the whole frame were fill), fits DYNRES_UP_FRAC of the target.  A step
 * down is judged once DYNRES_WINDOW frames of the new size are in: unless
 * their median is under DYNRES_GAIN of the median before it, the frame was
 * not fill-bound (or the scaling up costs what the smaller frame saved),
 * and it is taken back, and no step down is tried again for a back-off
 * that doubles at each such failure (DYNRES_BACKOFF to DYNRES_BACKOFF_MAX
 * frames).  After a step the next waits DYNRES_HOLD frames.  While below
 * full resolution the budget stays at its floor: resolution comes back to
 * full before any detail is added again.  Render thread only.
 */
#ifndef HLOD_ENGINE_DYNRES_H
#define HLOD_ENGINE_DYNRES_H

#include <stdint.h>

#define DYNRES_STEPS 5     /* scales of width and height: 1, 0.85, 0.72, 0.6, 0.5 */
#define DYNRES_WINDOW 8    /* frames each decision reads */
#define DYNRES_DOWN_OF 5   /* misses at the floor among them that step down */
#define DYNRES_UP_FRAC 0.8 /* a step up when the grown frames fit this of the target */
#define DYNRES_HOLD 12     /* frames between steps */
#define DYNRES_SETTLE 45   /* frames before the first step down (the cost model's warm-up) */
#define DYNRES_GAIN 0.9    /* a step down must bring the median frame under this of before */
#define DYNRES_BACKOFF 300 /* frames without a step down after one that did not help, */
#define DYNRES_BACKOFF_MAX 4800 /* doubling up to this */

typedef struct hlod_dynres {
    int step;                       /* 0: full resolution */
    uint32_t frames;                /* frames seen */
    uint32_t hold;                  /* frames before the next step may be taken */
    uint32_t n;                     /* frames in the window since the last step */
    uint32_t head;
    double ms[DYNRES_WINDOW];       /* measured frame times, newest at head - 1 */
    uint8_t floor_miss[DYNRES_WINDOW]; /* missed the target where no detail could help */
    int judging;                    /* the last step was down and is not judged yet */
    double before_ms;               /* the median frame before it */
    uint32_t backoff;               /* frames left without a step down */
    uint32_t backoff_len;           /* the next back-off's length */
    uint32_t reverted;              /* steps down taken back, in all */
} hlod_dynres;

/* The scale of width and height at step s (0 <= s < DYNRES_STEPS). */
double hlod_dynres_step_scale(int s);

/* This frame's scale. */
static inline double hlod_dynres_scale(const hlod_dynres *d)
{
    return hlod_dynres_step_scale(d->step);
}

/* After a frame measured at the current scale: measured_ms against
 * target_ms; coarsest when no detail could have helped it (see above; the
 * engine's budget is at its floor below full resolution).  Returns the
 * step change taken: -1 up, +1 down, 0. */
int hlod_dynres_update(hlod_dynres *d, double measured_ms, double target_ms, int coarsest);

/* Back to full resolution, everything forgotten (dyn_res switched off). */
void hlod_dynres_reset(hlod_dynres *d);

#endif
