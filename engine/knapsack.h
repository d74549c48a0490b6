/*
 * knapsack.h - the greedy multiple-choice knapsack of Funkhouser and
 * Séquin's adaptive display (SIGGRAPH 1993, section 4.2), on a cut of a
 * tree (knapsack.c; the fs93 policy, docs/runtime.md "Policies").
 *
 * Each item is one refinement: replacing a node of the front by its
 * visible children, worth `gain` more benefit for `cost` more time.  An
 * item may be taken only when its parent item is (the node is on the front
 * only then); an item is given back only when none of its children are.
 * The front's coarsest choice (every item given back) is always drawn: no
 * visible node is dropped, Lakhia's one change to the algorithm.
 *
 * hlod_knapsack_solve starts from the items taken last frame and moves
 * incrementally, as the paper does from one frame to the next:
 *   1. while the front's time is over the budget, the taken item of the
 *      lowest gain per cost with no taken child is given back;
 *   2. each item that may be taken (its parent taken), best gain per cost
 *      first, is taken; over its bound (the budget for an item taken last
 *      frame, `fresh` for a new one), the taken items of the lowest
 *      gain per cost with no taken child are given back until it fits,
 *      the new item itself when its turn comes (the paper's "increment the
 *      best, decrement the worst"); an item given back is not taken again
 *      in the same solve, and one that frees no time is never given back;
 *   3. the single best item that fits alone, when it is worth more than
 *      everything step 2 took (the classic guarantee: at least half the
 *      optimum's gain when items are independent).
 * Render thread only; O(n log n) for n items but for exchanges.
 */
#ifndef HLOD_ENGINE_KNAPSACK_H
#define HLOD_ENGINE_KNAPSACK_H

#include "alloc.h"

#include <stddef.h>
#include <stdint.h>

#define HLOD_KNAPSACK_NONE UINT32_MAX

typedef struct hlod_knapsack_item {
    double gain;        /* benefit added by taking it */
    double cost;        /* time added by taking it, ms (may be <= 0) */
    uint32_t parent;    /* the item that must be taken first, or HLOD_KNAPSACK_NONE;
                           parents come before their children in the array */
    uint8_t allowed;    /* 0: may not be taken this frame (data not resident) */
    uint8_t taken;      /* in: taken last frame; out: the decision */
} hlod_knapsack_item;

/* Scratch kept between frames (grown as needed; zero-initialise, then
 * set a: the engine's allocator, or NULL for malloc). */
typedef struct hlod_knapsack {
    const hlod_allocator *a;
    uint32_t *u;        /* 8 words an item: two heaps, children, counts */
    double *ratio;      /* gain per cost, an item */
    uint8_t *done;      /* an item: 1 given back in step 2, 2 taken last frame */
    size_t cap;         /* items the scratch holds */
    uint32_t exchanges; /* items the last solve gave back for better ones (step 2) */
} hlod_knapsack;

/* Decides items[0, n): `taken` on return.  base is the time of the
 * coarsest choice (no item taken), budget the bound on base plus the
 * taken items' cost.  An item not taken last frame is taken only while the
 * front then stays within fresh (<= budget; the engine's budget bound
 * keeps KEEP_MARGIN of room for new refinements): the bound's own
 * hysteresis.  Returns the front's time, or a negative value on
 * allocation failure (items unchanged).  When even the coarsest choice
 * exceeds the budget, nothing is taken. */
double hlod_knapsack_solve(hlod_knapsack *k, hlod_knapsack_item *items, uint32_t n, double base,
                           double budget, double fresh);

void hlod_knapsack_free(hlod_knapsack *k);

#endif
