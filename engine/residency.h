/*
 * residency.h - which nodes are in memory (Lakhia III-D; docs/runtime.md: residency). 
 * Render thread only; the loader thread it owns
 * only reads bytes (loader.h).
 *
 * The selection asks through hlod_residency_want and reads states through
 * hlod_residency_state, hlod_residency_is_pinned and hlod_residency_is_top;
 * it reads and writes no field here.  Once a frame the engine
 * collects finished reads (uploads within the upload budget) and schedules
 * the wanted nodes against the memory budget, evicting in the order the
 * caller's hlod_evict_order gives.
 */
#ifndef HLOD_ENGINE_RESIDENCY_H
#define HLOD_ENGINE_RESIDENCY_H

#include "alloc.h"
#include "gl_render.h"
#include "hlod/engine.h"
#include "loader.h"

/* Residency of one node. */
typedef struct hlod_node_res {
    uint8_t state;          /* hlod_node_state */
    uint8_t failures;       /* transient read failures so far */
    uint32_t retry_frame;   /* absent until this frame after a transient failure */
    uint32_t wanted;        /* frame the selection last asked for it */
    uint32_t posted;        /* frame it was last put in the loader's list */
    uint32_t needed;        /* frame a refinement last waited for it (it is
                               visible, and its parent would refine into it) */
    uint32_t slot;          /* index in the resident list while resident */
    uint32_t arrived;       /* frame its read came back (waiting for upload) */
    hlod_gpu_node gpu;      /* when a renderer is attached */
} hlod_node_res;

typedef struct hlod_residency {
    const hlod_store *store;
    const hlod_store_node *nodes;
    uint32_t node_count;
    uint32_t top_count;         /* groups and the blocks' hlod_0 nodes */
    uint32_t pinned_count;      /* [0, pinned_count) stay resident: the top of
                                   the tree, or its first levels when the top
                                   takes over half the budget (residency.c) */
    const hlod_engine_desc *d;  /* the engine's settings, read only */
    int texture_out;            /* HLOD_TEXOUT_*: block-coded textures as the
                                   renderer takes them (the loader's too) */
    hlod_frame_stats *st;       /* the engine's stats of the current frame */
    uint32_t frame;             /* current frame stamp (1-based; 0 = before any) */
    hlod_loader *loader;

    hlod_node_res *res;         /* node_count */
    hlod_u32_vec resident;      /* nodes resident (roots included) */
    uint64_t resident_bytes, reserved_bytes;
    double resident_cost, reserved_cost; /* sum of eq. 1 (not yet times c_memory) */
    hlod_load_result *pending;  /* collected, not yet uploaded (upload budget) */
    size_t pending_n, pending_cap;
    hlod_req_vec want;          /* asked for this frame (hlod_residency_want) */
    hlod_req_vec post;          /* what was handed to the loader */
    hlod_req_vec post_spare;    /* the list before it: its storage is the next
                                   frame's (no allocation in steady state) */
    struct victim *victims;     /* eviction candidates' buffer, kept between frames */
    size_t victims_cap;
    uint64_t bytes_read_prev;   /* the loader's counter at the last frame's end */
    uint64_t cache_hits_prev;   /* the loader's cache hits then */
    uint64_t finish_ns_prev, busy_ns_prev;  /* the loader's CPU-time counters then */
    uint32_t bad_total;
    uint32_t pinned_missing;    /* pinned nodes neither resident nor bad (a transient
                                   failure, being retried) */
    uint32_t start_failures;    /* failed reads of pinned nodes at start, not yet in a
                                   frame's stats */
    double upload_ms_per_byte[2]; /* measured cost of an upload, small and big
                                     (residency.c; 0: none measured yet) */
    uint32_t forced_frame;      /* frame of the last upload past every budget */
} hlod_residency;

/* Which resident nodes may go, and in what order: key() returns 0 for a
 * node that must stay this frame, else 1 with *key (lower goes first; a
 * node goes only for a wanted node of higher priority). */
typedef struct hlod_evict_order {
    int (*key)(void *user, uint32_t node, double *key);
    void *user;
} hlod_evict_order;

/* Reads and uploads the pinned nodes (residency.c: the groups and hlod_0
 * nodes, or the first levels of a large city), then starts the loader (threaded
 * unless deterministic).  A pinned node that cannot be read does not fail it:
 * it turns bad (checksum, format) or stays absent and is retried (I/O), and
 * the traversal draws its children in its place.  d and st must outlive r.
 * On failure (memory, the loader) everything is released. */
hlod_result hlod_residency_init(hlod_residency *r, const hlod_store *store,
                                const hlod_engine_desc *d, hlod_frame_stats *st);
/* Stops the loader, frees every resident node and pending load. */
void hlod_residency_destroy(hlod_residency *r);

/* A new frame: stamps it and empties the wanted list, then asks for the
 * pinned nodes still missing after a transient failure (first of all). */
void hlod_residency_begin_frame(hlod_residency *r, uint32_t frame);

/* The selection would like node resident: queues it for admission unless
 * it is resident, bad, already asked for this frame, or backing off after
 * a failure.  0 on allocation failure.  (Inline: the selection asks once
 * for every node it prices.) */
static inline int hlod_residency_want(hlod_residency *r, uint32_t node, double priority)
{
    hlod_node_res *nr = &r->res[node];
    if (nr->state == HLOD_NODE_RESIDENT || nr->state == HLOD_NODE_BAD)
        return 1;
    if (nr->wanted == r->frame)
        return 1;
    if (nr->state == HLOD_NODE_ABSENT && nr->retry_frame > r->frame)
        return 1;
    nr->wanted = r->frame;
    return hlod_req_push(&r->d->allocator, &r->want, node, priority);
}

/* As hlod_residency_want, for a node a refinement the selection would make
 * now is waiting for (not a prefetch): the loader reads, and collect
 * uploads, such nodes before the others. */
static inline int hlod_residency_need(hlod_residency *r, uint32_t node, double priority)
{
    r->res[node].needed = r->frame;
    return hlod_residency_want(r, node, priority);
}

static inline hlod_node_state hlod_residency_state(const hlod_residency *r, uint32_t node)
{
    return (hlod_node_state)r->res[node].state;
}

/* Whether node is one of the pinned nodes, kept resident from the start
 * (residency.c: the top of the tree, or its first levels). */
static inline int hlod_residency_is_pinned(const hlod_residency *r, uint32_t node)
{
    return node < r->pinned_count;
}

/* Whether node is a top node: a group, or a block's hlod_0. */
static inline int hlod_residency_is_top(const hlod_residency *r, uint32_t node)
{
    return node < r->top_count;
}

static inline const hlod_gpu_node *hlod_residency_gpu(const hlod_residency *r, uint32_t node)
{
    return &r->res[node].gpu;
}

/* Collects finished loads and uploads them within the upload budget:
 * up_ms of uploads this frame (the engine's reserve), the nodes a
 * refinement waits for first.  An upload too big for up_ms goes first once
 * it has itself waited 8 frames and fits in room_ms (what the last front
 * left of the target), or waited 64 frames whatever the room (one such every
 * 256 frames at most).  up_ms is ignored when
 * deterministic or timed by a model (bytes alone decide). */
void hlod_residency_collect(hlod_residency *r, double up_ms, double room_ms);
/* Admits wanted nodes against the budget (evicting in order's order),
 * hands the loader its list. */
void hlod_residency_schedule(hlod_residency *r, const hlod_evict_order *order);
/* Reads one node synchronously and makes it resident, ignoring the budget. */
hlod_result hlod_residency_load_now(hlod_residency *r, uint32_t node);
/* Fills the frame's residency stats (resident set, bytes read, bad nodes). */
void hlod_residency_end_frame(hlod_residency *r);

#endif
