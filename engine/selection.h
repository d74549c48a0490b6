/*
 * selection.h - which nodes a frame draws (Lakhia III-C; docs/runtime.md: selection). 
 * Render thread only.
 *
 * The selection reads the store's node table and the cost model's
 * published values, remembers per node what it needs between frames
 * (hysteresis counter, last priority, draw/refine stamps for toggles), and
 * fills the draw list.  It asks residency for nodes through
 * hlod_residency_want and reads their states; it writes nothing there.
 *
 * Frame stamps replace per-frame clearing, so a frame touches only the
 * nodes it visits: cost grows with what is visible, not with the store.
 * Stamps are frame numbers starting at 1; 0 means "never".
 */
#ifndef HLOD_ENGINE_SELECTION_H
#define HLOD_ENGINE_SELECTION_H

#include "alloc.h"
#include "knapsack.h"
#include "occlusion.h"
#include "policy.h"
#include "hlod/camera.h"
#include "hlod/engine.h"

struct hlod_residency;

/* Selection memory of one node. */
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
    double pix;             /* screen pixels of its projected box (when priced visible) */
    double extra;           /* what refining it added to the estimate when last refined (signed) */
    double sub_extra;       /* extra summed over its subtree's refinements, last frame */
    uint32_t waiting;       /* frame a refinement of it last waited for its children's data */
    uint32_t capped;        /* frame the budget bound coarsened it while the front was held;
                             * 0 once refined again */
    hlod_policy_mem mem;    /* the policy's own (policy.h) */
    uint32_t coned;         /* frame normal cones last culled it */
    uint32_t cube;          /* frame it was priced visible within cube_px, its colour cube
                             * standing in for it (far_cubes) */
} hlod_node_frame;

/* The camera as the selection sees it, in camera-relative doubles. */
typedef struct hlod_view {
    double eye[3];          /* camera position (model units) */
    double probe[3];        /* eye advanced by velocity * look-ahead: distances use it */
    double planes[6][4];    /* frustum planes, camera-relative, unit normals pointing in */
    double toward[3];       /* unit vector toward the viewer (image plane normal) */
    double pixels_per_radian; /* height / (2 tan(fovy/2)), for screen-space error */
    double vp[16];          /* camera-relative view-projection, column-major */
    double width, height;   /* viewport, pixels */
    double velocity[3];     /* the camera's, model units per second */
    double turn_rad_s;      /* how fast the view axis turns, radians per second (the
                             * engine sets it after hlod_view_init; 0 there) */
} hlod_view;

/* What one frame's selection is given. */
typedef struct hlod_select_in {
    uint32_t frame;         /* stamp (1-based) */
    double v_time;          /* the cost model's published ms per unit of cost */
    double draw_ms;         /* ... per node drawn */
    double pixel_ms;        /* ... per pixel of a node's projected box */
    int occlusion;          /* nodes hidden in the last frame are not charged or refined */
    const hlod_occlusion *occ; /* the test's verdicts (occlusion.h); NULL: occlusion off */
    int still;              /* the camera has not moved since the last frame */
    uint32_t hold_since;    /* frame from which a lakhia front holds, the whole camera still a
                             * while (hold_front); 0: not held */
    double sse_pixels;      /* the SSE policy's threshold */
    double splat_px;        /* the additive walk's splat size, pixels (klein, klein-auto) */
    double budget_ms;       /* the bound on the front's estimate */
    double share_ms;        /* the roots' shareTime (eq. 4) */
} hlod_select_in;

typedef struct hlod_selection {
    const hlod_store_node *nodes;
    const hlod_store_extra *extras; /* the store's, or NULL: no normal cones */
    uint32_t node_count, root_count;
    const hlod_engine_desc *d;  /* the engine's settings, read only */
    hlod_frame_stats *st;       /* the engine's stats of the current frame */
    hlod_node_frame *fr;        /* node_count */
    hlod_u32_vec draw;          /* nodes drawn this frame */
    hlod_u32_vec level, next;   /* breadth-first levels */
    hlod_u32_vec refined;       /* nodes refined this frame, in walk order */
    hlod_u32_vec coned;         /* nodes normal cones culled this frame */
    int additive;               /* the store refines additively (walk_additive) */
    hlod_u32_vec splats;        /* additive: nodes drawn as one splat (or cube) this frame;
                                   a front with far_cubes: the nodes drawn as their cubes */
    double splat_px;            /* ... the splat size they stopped at (klein-auto's varies) */
    /* cube_copies (policy cubes, Chamberlain Fig. 5): the scene drawn as
     * 2^copy_levels x 2^copy_levels copies side by side, copy c = i + j
     * 2^copy_levels offset by (i, j) x copy_side.  draw_copy and
     * splat_copy give each entry of draw and splats its copy; a splats
     * entry HLOD_SEL_BLOCK(L) is the cube of the block of 2^L x 2^L copies
     * whose first copy its splat_copy gives (block_cube[L]). */
    uint32_t copy_levels;
    hlod_u32_vec draw_copy, splat_copy;
    double scene_lo[3], scene_hi[3], copy_side[2];
    uint8_t block_cube[17][6][4];
    int block_cubes_made;       /* block_cube holds the root's cube per level */
    double reserved, reserving; /* extra of the last frame's refinements; of this frame's */
    uint32_t cap_hits;          /* refinements the budget bound refused this frame */
    uint32_t slice_denied;      /* refinements near but refused by time slices */
    hlod_knapsack ks;           /* fs93's solver and its items (traverse.c) */
    hlod_knapsack_item *fs93_items;
    uint32_t *fs93_nodes;
    size_t fs93_cap;
    hlod_knapsack_item *fs93_wish; /* the items again, all allowed: what to read */
    size_t fs93_wish_cap;
} hlod_selection;

/* A splats entry that is a block of copies' cube (cube_copies). */
#define HLOD_SEL_BLOCK(level) (UINT32_MAX - (uint32_t)(level))
#define HLOD_SEL_IS_BLOCK(entry) ((entry) >= UINT32_MAX - 16u)

/* The offset of copy c (cube_copies): (i, j, 0) x copy_side. */
static inline void hlod_sel_copy_offset(const struct hlod_selection *s, uint32_t c, double off[3])
{
    uint32_t side = 1u << s->copy_levels;
    off[0] = (double)(c % side) * s->copy_side[0];
    off[1] = (double)(c / side) * s->copy_side[1];
    off[2] = 0;
}

/* d and st must outlive s.  HLOD_ERR_NOMEM. */
hlod_result hlod_selection_init(hlod_selection *s, const hlod_store *store,
                                const hlod_engine_desc *d, hlod_frame_stats *st);
void hlod_selection_free(hlod_selection *s);

/* Builds the view (frustum planes, look-ahead probe) from a camera and the
 * camera velocity (model units per second). */
void hlod_view_init(hlod_view *v, const hlod_camera *cam, const double velocity[3],
                    double lookahead_s);

/* How far (model units) the box [lo, hi] lies outside the view's frustum:
 * <= 0 when it meets it.  Conservative (a box near a frustum corner may be
 * reported as meeting it), as usual. */
double hlod_view_outside(const hlod_view *v, const double lo[3], const double hi[3]);

/* The box [lo, hi] (world) projected: its screen rectangle in pixels
 * (x0, y0, x1, y1; y up, clipped to the viewport, possibly empty) and the
 * window depth in [0, 1] of its nearest point.  Returns 0 when part of the
 * box lies at or behind the eye plane (then it may cover the whole screen
 * and nothing is filled in). */
int hlod_view_project(const hlod_view *v, const double lo[3], const double hi[3], double rect[4],
                      double *zmin);

/* Screen pixels of the box's projected rectangle, clipped to the viewport
 * (the whole viewport when the box reaches behind the eye). */
double hlod_view_pixels(const hlod_view *v, const double lo[3], const double hi[3]);

/* Selects this frame's nodes with d->policy: fills s->draw, asks res for
 * the nodes it wants, and fills the selection fields of the stats (drawn,
 * per depth, toggles, visited, wanted_missing, cost and triangles drawn).
 * The estimate of the front never exceeds in->budget_ms.  Counts
 * cap_hits and slice_denied.  O(nodes visited). */
hlod_result hlod_select(hlod_selection *s, struct hlod_residency *res, const hlod_view *v,
                        const hlod_select_in *in);

static inline double hlod_node_cost(const hlod_store_node *n)
{
    /* eq. 1 can be 0 (c_tex = 1 on untextured triangles): keep every
     * ratio finite with a floor of a thousandth of a triangle. */
    return n->cost > 1e-3 ? n->cost : 1e-3;
}

#endif
