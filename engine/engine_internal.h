/*
 * engine_internal.h - the engine's parts and the data they share.
 * Render thread only, except where loader.h says otherwise.
 *
 * Three kinds of per-node data, kept apart (no single struct holds all):
 *   - the store's node table (immutable: box, cost, benefit, tree links);
 *   - hlod_node_frame: what the traversal remembers between frames
 *     (hysteresis counter, last priority, draw/refine stamps for toggles);
 *   - hlod_node_res: residency (state, GPU handles, retry backoff).
 * Frame stamps replace per-frame clearing, so a frame touches only the
 * nodes it visits: cost grows with what is visible, not with the store.
 * Stamps are frame numbers starting at 1; 0 means "never".
 */
#ifndef HLOD_ENGINE_INTERNAL_H
#define HLOD_ENGINE_INTERNAL_H

#include "gl_render.h"
#include "hlod/engine.h"
#include "loader.h"

#include <time.h>

/* Traversal memory of one node. */
typedef struct hlod_node_frame {
    double hyst;            /* Lakhia hyst_n, in [-c_hystLimit, c_hystLimit] */
    double slice;           /* last timeSlice_n (ms) */
    double needed;          /* last timeNeeded_n (ms) */
    double priority;        /* last priority_n */
    uint32_t priced;        /* frame of the last pricing */
    uint32_t hyst_frame;    /* frame hyst was last updated; older = re-entering */
    uint32_t drawn;         /* frame the node was last drawn */
    uint32_t refined;       /* frame its children were last drawn in its place */
    uint32_t toggled;       /* frame of the last toggle */
    int8_t toggle_dir;      /* +1 up, -1 down */
} hlod_node_frame;

/* Residency of one node. */
typedef struct hlod_node_res {
    uint8_t state;          /* hlod_node_state */
    uint8_t failures;       /* transient read failures so far */
    uint32_t retry_frame;   /* absent until this frame after a transient failure */
    uint32_t wanted;        /* frame the traversal last asked for it */
    uint32_t posted;        /* frame it was last put in the loader's list */
    uint32_t slot;          /* index in the resident list while resident */
    hlod_gpu_node gpu;      /* when a renderer is attached */
} hlod_node_res;

/* Growable arrays (render thread). */
typedef struct hlod_u32_vec {
    uint32_t *v;
    size_t n, cap;
} hlod_u32_vec;

typedef struct hlod_req_vec {
    hlod_load_request *v;
    size_t n, cap;
} hlod_req_vec;

/* The camera as the traversal sees it, in camera-relative doubles. */
typedef struct hlod_view {
    double eye[3];          /* camera position (model units) */
    double probe[3];        /* eye advanced by velocity * look-ahead: distances use it */
    double planes[6][4];    /* frustum planes, camera-relative, unit normals pointing in */
    double toward[3];       /* unit vector toward the viewer (image plane normal) */
    double pixels_per_radian; /* height / (2 tan(fovy/2)), for screen-space error */
} hlod_view;

struct hlod_engine {
    const hlod_store *store;
    const hlod_store_node *nodes;
    uint32_t node_count, root_count;
    hlod_engine_desc d;
    hlod_loader *loader;

    hlod_node_frame *fr;    /* node_count */
    hlod_node_res *res;     /* node_count */

    /* residency */
    hlod_u32_vec resident;  /* nodes resident (roots included) */
    uint64_t resident_bytes, reserved_bytes;
    double resident_cost, reserved_cost; /* sum of eq. 1 (not yet times c_memory) */
    hlod_load_result *pending; /* collected, not yet uploaded (upload budget) */
    size_t pending_n, pending_cap;

    /* frame scratch */
    hlod_u32_vec draw;      /* nodes drawn this frame */
    struct draw_key *draw_keys; /* sort scratch (engine.c) */
    size_t draw_keys_cap;
    hlod_u32_vec level, next; /* breadth-first levels */
    hlod_req_vec want;      /* non-resident nodes priced this frame */
    hlod_req_vec post;      /* what was handed to the loader */

    /* cost model: frame ms = fixed + v_time * drawn cost (engine.c) */
    double v_time, fixed_ms;     /* published: what the traversal uses */
    double fit_v, fit_fixed;     /* the fit's own current values */
    double s0, sx, sy, sxx, sxy; /* exponentially weighted sums */
    double sse_pixels;
    double share_gain;      /* roots' shareTime = gain * budget (engine.c) */
    uint32_t cap_hits;      /* refinements the budget bound refused this frame */
    uint32_t slice_denied;  /* refinements near but refused by time slices */

    /* camera motion */
    double prev_eye[3];
    int have_prev;

    uint32_t frame;         /* current frame stamp (1-based) */
    hlod_frame_stats st;    /* being filled */
    uint64_t bytes_read_prev;
    uint32_t bad_total;
};

/* ---- growable arrays ---- */
int hlod_u32_push(hlod_engine *e, hlod_u32_vec *a, uint32_t x);
int hlod_req_push(hlod_engine *e, hlod_req_vec *a, uint32_t node, double priority);
void *hlod_engine_alloc(hlod_engine *e, size_t size);
void *hlod_engine_realloc(hlod_engine *e, void *p, size_t size);
void hlod_engine_free(hlod_engine *e, void *p);

/* ---- traverse.c: selection ---- */

/* Builds the view (frustum planes, look-ahead probe) from a camera and the
 * camera velocity (model units per second). */
void hlod_view_init(hlod_view *v, const hlod_camera *cam, const double velocity[3],
                    double lookahead_s);

/* Selects this frame's nodes with e->d.policy: fills e->draw and e->want
 * and the selection fields of e->st (drawn, per depth, toggles, visited,
 * wanted_missing, estimated_ms).  budget_ms is what the traversal shares
 * out (target minus the fixed part): the estimate of the front never
 * exceeds it.  share_ms is the roots' shareTime (eq. 4).  Counts cap_hits
 * and slice_denied.  O(nodes visited). */
hlod_result hlod_traverse(hlod_engine *e, const hlod_view *v, double budget_ms,
                          double share_ms);

/* ---- residency.c: loads, uploads, admission, eviction ---- */

/* Reads and uploads every hlod_0 node (create). */
hlod_result hlod_residency_load_roots(hlod_engine *e);
/* Collects finished loads and uploads them within the upload budget. */
void hlod_residency_collect(hlod_engine *e);
/* Admits wanted nodes against the budget (evicting lower-priority resident
 * nodes not drawn this frame), hands the loader its list. */
void hlod_residency_schedule(hlod_engine *e);
/* Reads one node synchronously and makes it resident, ignoring the budget. */
hlod_result hlod_residency_load_now(hlod_engine *e, uint32_t node);
/* Frees every resident node and pending load (destroy). */
void hlod_residency_release_all(hlod_engine *e);

static inline double hlod_node_cost(const hlod_store_node *n)
{
    /* eq. 1 can be 0 (c_tex = 1 on untextured triangles): keep every
     * ratio finite with a floor of a thousandth of a triangle. */
    return n->cost > 1e-3 ? n->cost : 1e-3;
}

/* The monotonic clock in ms, for the engine's wall-clock measures (never
 * read for a decision under a time model). */
static inline double hlod_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

#endif
