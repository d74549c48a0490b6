/*
 * inspect.h - a window on an engine for its tests (inspect.c): what the
 * selection, residency and the cost model hold between frames, and one
 * frame selected by hand.  Tests read through these functions, not the
 * parts' structs, so a part may change its state without touching them.
 * Render thread only, between frames.  Not installed.
 */
#ifndef HLOD_ENGINE_INSPECT_H
#define HLOD_ENGINE_INSPECT_H

#include "hlod/engine.h"

/* What the selection remembers of one node. */
typedef struct hlod_node_look {
    double hyst;        /* Lakhia's urgency counter */
    double slice;       /* its last time slice, ms (eq. 4) */
    double needed;      /* its last timeNeeded, ms */
    double priority;    /* its last priority */
    uint32_t priced;    /* the frame it was last priced (0: never) */
    uint32_t drawn;     /* ... last drawn */
    uint32_t refined;   /* ... last refined (its children drawn in its place) */
} hlod_node_look;

/* The cost model's published state. */
typedef struct hlod_model_look {
    double theta[4];    /* fixed ms, ms per draw, ms per unit of cost (v_time), ms per pixel */
    double margin;      /* the deadline margin */
    uint32_t scale_updates, shape_updates, margin_updates;
} hlod_model_look;

/* The store the engine draws. */
const hlod_store *hlod_inspect_store(const hlod_engine *e);
/* The number of the last frame (1-based; 0 before any). */
uint32_t hlod_inspect_frame(const hlod_engine *e);
hlod_node_look hlod_inspect_node(const hlod_engine *e, uint32_t node);
/* The last frame's selection in selection order (*n nodes). */
const uint32_t *hlod_inspect_selected(const hlod_engine *e, size_t *n);
/* Refinements the budget bound refused in the last frame. */
uint32_t hlod_inspect_cap_hits(const hlod_engine *e);
hlod_model_look hlod_inspect_model(const hlod_engine *e);
/* Bytes of reads in flight that residency holds room for. */
uint64_t hlod_inspect_reserved_bytes(const hlod_engine *e);
/* Whether residency may evict node now, and its key (lower goes first). */
int hlod_inspect_evictable(const hlod_engine *e, uint32_t node, double *key);
/* Whether the loader has done all it was last given (inspect.c). */
int hlod_inspect_loader_idle(const hlod_engine *e);
/* Nodes [0, n) stay resident from the start. */
uint32_t hlod_inspect_pinned_count(const hlod_engine *e);

/* One frame selected by hand: no drawing, no fit, no residency schedule.
 * The selection gets budget_ms and share_ms, the cost model's current
 * terms, and, with occlusion, the verdicts set by hlod_inspect_hide.
 * Fills *st with the frame's selection stats; returns the selection's
 * result. */
typedef struct hlod_hand_frame {
    const hlod_camera *cam;
    double budget_ms, share_ms;
    int occlusion, still;
} hlod_hand_frame;
hlod_result hlod_inspect_select(hlod_engine *e, const hlod_hand_frame *in, hlod_frame_stats *st);

/* Sets occlusion's verdict on node: hidden at frame. */
void hlod_inspect_hide(hlod_engine *e, uint32_t node, uint32_t frame);

#endif
