/*
 * hold.h - the still-camera hold (docs/runtime.md, "The still-camera
 * hold"): once the whole camera has stayed the same STILL_HOLD frames, a
 * policy with HLOD_PT_HOLD keeps its front, and the selection keeps the
 * inputs (budget, share, cost terms) it saw when the hold began.  All of
 * the hold's rules live in hold.c; the engine (engine.c) and the
 * selection (traverse.c) ask through these functions.  Render thread only.
 *
 * A held front: a node refined last frame stays refined, one drawn last
 * frame stays drawn, and a node new to the front is decided as usual;
 * the budget bound still coarsens a front that no longer fits.  Two
 * exceptions refine a held drawn node: the bound coarsened it during this
 * hold (hlod_hold_capped: the machine slowed, and has recovered), or, with
 * still_refine_late, its refinement waited for its children's data last
 * frame (data arriving late sharpens a still view).
 *
 * Held inputs give way when the target changes, when HOLD_SLOW_MISSES of
 * the last 16 held frames missed the target (the held front no longer fits
 * the machine), and, after such a slowdown, once HOLD_RECOVER frames in a
 * row met it and the model's inputs leave the held front more room than
 * the held ones (budget less the front's predicted variable time): a
 * larger budget with a grown v_time can hold less, and recovery must not
 * coarsen.
 */
#ifndef HLOD_ENGINE_HOLD_H
#define HLOD_ENGINE_HOLD_H

#include "selection.h"

/* Frames the whole camera must stay the same before the front holds: 2 s
 * at 30 Hz, past the cost model's 45-frame warm-up and time for a still
 * view's wanted nodes to arrive. */
#define STILL_HOLD 60
/* Held frames over the target, of the last 16, that show the held front
 * itself no longer fits the machine (a burst of slow frames on a noisy
 * machine misses 1-5 in a row). */
#define HOLD_SLOW_MISSES 8
/* Clean frames in a row (the width of misses) after which inputs taken in
 * a slowdown give way to the model's again, where those give more. */
#define HOLD_RECOVER 32

/* The selection inputs a hold keeps, and how its frames went. */
typedef struct hlod_hold {
    uint32_t since;     /* the hold they belong to (hold_since; 0: none) */
    uint32_t taken;     /* the frame they were taken */
    double target_ms;   /* the target they were taken at */
    double budget_ms, share_ms, v_time, draw_ms, pixel_ms;
    uint32_t misses;    /* a bit a held frame, newest lowest: over the target */
    int slowed;         /* taken because the held frames missed */
} hlod_hold;

/* What the front drew last frame, in the cost model's terms. */
typedef struct hlod_front_load {
    double draws, cost, pixels;
} hlod_front_load;

/* The frame from which the front holds at frame `frame`, the camera having
 * stayed the same still_run frames; 0: it does not hold. */
static inline uint32_t hlod_hold_since(uint32_t still_run, uint32_t frame)
{
    return still_run >= STILL_HOLD ? frame - (still_run - STILL_HOLD) : 0;
}

/* Before the selection of frame `frame` at target_ms: replaces in's
 * budget, share and cost terms with the held ones, or takes them anew
 * (see above).  holds: the policy has HLOD_PT_HOLD; front: what the
 * held front drew last frame. */
void hlod_hold_inputs(hlod_hold *h, int holds, uint32_t frame, double target_ms,
                      const hlod_front_load *front, hlod_select_in *in);

/* After a frame measured at measured_ms against target_ms. */
void hlod_hold_measured(hlod_hold *h, double measured_ms, double target_ms);

/* The selection's decision for node pf of a held front (hold_since > 0 at
 * frame `frame`), the policy having decided refine. */
int hlod_hold_front(const hlod_node_frame *pf, uint32_t frame, uint32_t hold_since,
                    int still_refine_late, int refine);

/* The budget bound coarsened pf, refined last frame, during a hold at
 * frame; a refinement clears the mark. */
static inline void hlod_hold_capped(hlod_node_frame *pf, uint32_t frame)
{
    pf->capped = frame;
}

static inline void hlod_hold_uncap(hlod_node_frame *pf)
{
    pf->capped = 0;
}

#endif
