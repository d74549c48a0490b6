/*
 * policy.h - the selection policies (docs/runtime.md, "Policies"): one row
 * each of a table, a name, the traits the rest of the engine asks about,
 * and one function that decides a node of the front.  Render thread only.
 *
 * Adding a policy is an enum value in hlod/engine.h, a row and a function
 * here (policy.c), a section in docs/runtime.md and a test
 * (docs/extending.md).  Nothing else in the engine names a policy: the
 * selection, the frame and the cost model ask for traits.
 */
#ifndef HLOD_ENGINE_POLICY_H
#define HLOD_ENGINE_POLICY_H

#include "hlod/engine.h"
#include "hlod/store.h"

/* What the rest of the engine does around a policy's decisions. */
enum {
    HLOD_PT_HYST = 1u << 0,    /* children keep urgency counters and vote (Lakhia) */
    HLOD_PT_BUDGET = 1u << 1,  /* the budget bound caps the front's estimate */
    HLOD_PT_HOLD = 1u << 2,    /* a still camera's front holds (hold.h) */
    HLOD_PT_OCCLUDE = 1u << 3, /* occlusion culling runs when the engine has it on */
    HLOD_PT_SHARE = 1u << 4,   /* the cost model adapts the share gain */
    HLOD_PT_SSE = 1u << 5,     /* screen-space error: the cost model adapts the SSE
                                  threshold, and the decision reads the distance */
    HLOD_PT_STREAM = 1u << 6,  /* residency admits and evicts by priority each frame */
    HLOD_PT_CONES = 1u << 8,   /* normal cones cull whatever the cone_cull setting */
    HLOD_PT_KNAPSACK = 1u << 7, /* the front is planned before the walk by FS93's knapsack
                                   (traverse.c): the decision reads mem->plan and mem->ask */
    HLOD_PT_ADDITIVE = 1u << 9, /* draws a store that refines additively (a sample tree):
                                   every visited node, ancestors too, and splats where a
                                   node's box is small (traverse.c, walk_additive) */
    HLOD_PT_AUTOSPLAT = 1u << 10, /* the cost model adapts the splat size to the target */
    HLOD_PT_RZB = 1u << 11,     /* no front: every leaf in core, drawn as random points or
                                   rasterised where its faces are large (rzb.h) */
    HLOD_PT_LUMI = 1u << 13,    /* the Grid-Lumigraph client draws the front (lumigraph.h) */
    HLOD_PT_CUBES = 1u << 12,   /* additive, small nodes drawn as their colour cubes
                                   (docs/cubes.md), children back to front */
};

/* What a policy remembers of a node between frames (its own use). */
typedef struct hlod_policy_mem {
    uint32_t frame;        /* counter: the last frame that wanted a switch */
    uint32_t count;        /* ... how many in a row, up to that frame */
    int8_t dir;            /* ... +1 refine, -1 coarsen */
    uint32_t plan;         /* fs93: the frame the knapsack refined the node */
    uint32_t ask;          /* fs93: the frame its children were worth reading */
} hlod_policy_mem;

/* What a policy decides node p of the front from (traverse.c, visit). */
typedef struct hlod_policy_in {
    const hlod_engine_desc *d;
    const hlod_store_node *node; /* p */
    double distance;       /* from the look-ahead probe to p's box; filled for
                              HLOD_PT_SSE policies only (0 otherwise) */
    double pixels_per_radian; /* the view's, for screen-space error */
    double share;          /* p's shareTime for its visible children, ms (eq. 4) */
    double sum_needed;     /* their summed timeNeeded, ms */
    double cum;            /* their counters' weighted vote, cumHyst (HLOD_PT_HYST) */
    int refined_last;      /* p was refined last frame */
    double sse_pixels;     /* the SSE threshold */
    const double *eye;     /* the camera's position (world) */
    uint32_t frame;        /* this frame's stamp */
    hlod_policy_mem *mem;  /* p's memory */
} hlod_policy_in;

/* 1: draw p's visible children in its place; 0: draw p.  *near: refining
 * is close, so the children not resident are asked for. */
typedef int (*hlod_policy_fn)(const hlod_policy_in *in, int *near);

typedef struct hlod_policy_row {
    const char *name;      /* hlod_policy_name, hlod-bench --policy */
    unsigned traits;       /* HLOD_PT_* */
    hlod_policy_fn refines;
} hlod_policy_row;

/* The row of p (a valid policy). */
const hlod_policy_row *hlod_policy_row_of(hlod_policy p);

/* Whether policy p has all of the traits t. */
static inline int hlod_policy_has(hlod_policy p, unsigned t)
{
    return (hlod_policy_row_of(p)->traits & t) == t;
}

/* A refinement made last frame may exceed the shared time by this much
 * more (lakhia) or must leave this much of the budget free when new
 * (traverse.c): the bound's own hysteresis. */
#define HLOD_KEEP_MARGIN 0.15

#endif
