/*
 * engine_internal.h - the engine object: its three parts and what ties
 * them together (engine.c; tests look inside).  Render thread only.
 *
 *   selection  (selection.h, traverse.c): what a frame draws;
 *   residency  (residency.h, residency.c with loader.c): what is in memory;
 *   cost model (cost_model.h, cost_model.c): what a frame costs.
 *
 * Per-node data stays with its part: the store's node table (immutable:
 * box, cost, benefit, tree links), the selection's hlod_node_frame and
 * residency's hlod_node_res.  The parts share the engine's settings and
 * the frame's stats by const pointer and pointer.
 */
#ifndef HLOD_ENGINE_INTERNAL_H
#define HLOD_ENGINE_INTERNAL_H

#include "cost_model.h"
#include "dynres.h"
#include "hold.h"
#include "hlod/engine.h"
#include "occlusion.h"
#include "residency.h"
#include "lumigraph.h"
#include "rzb.h"
#include "selection.h"

struct hlod_engine {
    const hlod_store *store;
    const hlod_store_node *nodes;
    uint32_t node_count, root_count;
    hlod_engine_desc d;
    hlod_selection sel;
    hlod_residency res;
    hlod_cost_model cost;

    hlod_u32_vec order;         /* the selection's nodes in draw order (engine.c) */
    const hlod_u32_vec *draw_list; /* order, or the selection's list without memory for it */
    struct draw_key *draw_keys; /* draw-order sort scratch (engine.c) */
    size_t draw_keys_cap;
    hlod_occlusion occ;         /* the depth pyramid and each node's last verdicts
                                   (occlusion.h) */
    hlod_u32_vec drawn;         /* nodes the last frame drew, in draw order */
    int drawn_valid;            /* drawn holds them (occlusion was on) */
    hlod_u32_vec later;         /* scratch: nodes tested before they are drawn */
    struct hlod_gpu_splat *splat_buf; /* the frame's splats for the renderer (engine.c) */
    size_t splat_cap;
    hlod_rzb *rzb;              /* policy rzb: every leaf in core (rzb.h); else NULL */
    hlod_rzb_out rzb_out;       /* ... the frame's points and faces to rasterise */
    hlod_view rzb_view;         /* ... and the view it sampled (a replay samples it again) */
    hlod_lumi *lumi;            /* policy lumigraph: the repository's views; else NULL */
    hlod_gpu_lumi_frame lumi_frame; /* ... this frame's blend */

    /* camera motion */
    int have_prev;
    hlod_camera prev_cam;   /* the last frame's camera (when have_prev) */
    double turn_rad_s;      /* how fast the view axis turned into this frame, rad/s */
    uint32_t still_run;     /* frames in a row with the same camera as the last */
    hlod_hold hold;         /* the still camera's hold (hold.h) */
    int have_front;         /* last_front_ms is set (a frame was selected) */
    double last_front_ms;   /* the last front's estimate, fixed part included */
    hlod_front_load last_load; /* what the last front drew (the hold's recovery) */
    hlod_dynres dynres;     /* the resolution's steps (dyn_res; dynres.h) */
    int dynres_failed;      /* the renderer could not draw small: full size */

    uint32_t frame;         /* current frame stamp (1-based) */
    hlod_frame_stats st;    /* being filled */
};

/* The order residency evicts in (hlod_evict_order's key; engine.c). */
int hlod_engine_evict_key(void *user, uint32_t node, double *key);

#endif
