/*
 * knapsack.c - Funkhouser and Séquin's greedy knapsack on a cut of a tree
 * (knapsack.h).
 */
#include "knapsack.h"

#include <math.h>
#include <string.h>

/* An indexed binary heap of item numbers keyed by ratio: the highest first
 * (max) or the lowest.  An item is in it at most once. */
typedef struct heap {
    uint32_t *v, *pos; /* pos[i]: index in v + 1, or 0 when absent */
    uint32_t n;
    int max;
    const double *key;
} heap;

static int above(const heap *h, uint32_t a, uint32_t b)
{
    double ka = h->key[a], kb = h->key[b];
    if (ka != kb)
        return h->max ? ka > kb : ka < kb;
    return a < b; /* ties: the item first in the front, so the result is stable */
}

static void heap_set(heap *h, uint32_t at, uint32_t item)
{
    h->v[at] = item;
    h->pos[item] = at + 1;
}

static void heap_push(heap *h, uint32_t item)
{
    if (h->pos[item])
        return;
    uint32_t at = h->n++;
    while (at > 0) {
        uint32_t up = (at - 1) / 2;
        if (!above(h, item, h->v[up]))
            break;
        heap_set(h, at, h->v[up]);
        at = up;
    }
    heap_set(h, at, item);
}

static uint32_t heap_pop(heap *h)
{
    uint32_t top = h->v[0], last = h->v[--h->n], at = 0;
    h->pos[top] = 0;
    if (h->n == 0)
        return top;
    for (;;) {
        uint32_t c = 2 * at + 1;
        if (c >= h->n)
            break;
        if (c + 1 < h->n && above(h, h->v[c + 1], h->v[c]))
            c++;
        if (!above(h, h->v[c], last))
            break;
        heap_set(h, at, h->v[c]);
        at = c;
    }
    heap_set(h, at, last);
    return top;
}

/* One solve's view of the items. */
typedef struct solve {
    hlod_knapsack_item *it;
    uint32_t n;
    double *ratio;
    uint32_t *kids;           /* taken children */
    uint32_t *child0, *child; /* children of item i: child[child0[i] .. child0[i + 1]) */
    uint32_t *out;            /* leaves set aside while giving back */
    uint8_t *done;            /* given back in step 2: not taken again this solve */
    uint32_t exchanges;       /* items given back for better ones */
    heap leaves;              /* taken, no taken child: what may be given back, lowest first */
    heap cand;                /* may be taken, best first */
    double total, budget;
    double fresh;             /* the bound for an item not taken last frame */
} solve;

static int is_leaf(const solve *s, uint32_t i)
{
    return s->it[i].taken && s->kids[i] == 0;
}

static int can_take(const solve *s, uint32_t i)
{
    const hlod_knapsack_item *t = &s->it[i];
    return !t->taken && !(s->done[i] & 1) && t->allowed && t->gain > 0 &&
           (t->parent == HLOD_KNAPSACK_NONE || s->it[t->parent].taken);
}

static void take(solve *s, uint32_t i)
{
    hlod_knapsack_item *t = &s->it[i];
    t->taken = 1;
    s->total += t->cost;
    if (t->parent != HLOD_KNAPSACK_NONE)
        s->kids[t->parent]++;
    heap_push(&s->leaves, i);
    for (uint32_t k = s->child0[i]; k < s->child0[i + 1]; k++)
        if (can_take(s, s->child[k]))
            heap_push(&s->cand, s->child[k]);
}

static void give_back(solve *s, uint32_t i)
{
    hlod_knapsack_item *t = &s->it[i];
    t->taken = 0;
    s->total -= t->cost;
    if (t->parent != HLOD_KNAPSACK_NONE && --s->kids[t->parent] == 0)
        heap_push(&s->leaves, t->parent);
    if (can_take(s, i))
        heap_push(&s->cand, i);
}

/* Step 1: over the budget, or holding an item worth nothing, gives back
 * the taken leaves of the lowest gain per cost (never one that saves time
 * and gains: giving it back would only cost). */
static void shed(solve *s)
{
    uint32_t kept = 0;
    while (s->leaves.n) {
        uint32_t i = heap_pop(&s->leaves);
        const hlod_knapsack_item *t = &s->it[i];
        if (!is_leaf(s, i))
            continue;
        int over = s->total > s->budget;
        if (!over && t->gain > 0) {
            s->out[kept++] = i;
            break; /* it and the rest are worth their time */
        }
        if (over ? t->cost <= 0 : s->total - t->cost > s->budget) {
            s->out[kept++] = i; /* giving it back would not free time, or would not fit */
            continue;
        }
        give_back(s, i);
    }
    for (uint32_t k = 0; k < kept; k++)
        heap_push(&s->leaves, s->out[k]);
}

/* The bound item i is taken under: the budget for one taken last frame,
 * the fresh bound for a new one. */
static double bound_for(const solve *s, uint32_t i)
{
    return (s->done[i] & 2) ? s->budget : s->fresh;
}

/* Step 2 for item i, taken over its bound: the taken leaves of the lowest
 * gain per cost are given back until the front fits it again, i itself
 * when its turn comes (then the solve moves on to the next item).  Each
 * item given back here is done with for this solve. */
static void make_room(solve *s, uint32_t i)
{
    uint32_t kept = 0;
    const double bound = bound_for(s, i);
    while (s->total > bound && s->leaves.n) {
        uint32_t j = heap_pop(&s->leaves);
        if (!is_leaf(s, j))
            continue;
        if (s->it[j].cost <= 0) {
            s->out[kept++] = j; /* frees no time */
            continue;
        }
        s->done[j] |= 1;
        give_back(s, j);
        if (j == i)
            break;
        s->exchanges++;
    }
    for (uint32_t k = 0; k < kept; k++)
        heap_push(&s->leaves, s->out[k]);
}

/* Step 3: the single best item that fits alone, if worth more. */
static void best_single(solve *s, double base)
{
    double sum = 0, best = 0;
    uint32_t b = HLOD_KNAPSACK_NONE;
    for (uint32_t i = 0; i < s->n; i++) {
        const hlod_knapsack_item *t = &s->it[i];
        if (t->taken)
            sum += t->gain;
        if (t->parent == HLOD_KNAPSACK_NONE && t->allowed && t->gain > best &&
            base + t->cost <= bound_for(s, i)) {
            best = t->gain;
            b = i;
        }
    }
    if (b == HLOD_KNAPSACK_NONE || !(best > sum))
        return;
    for (uint32_t i = 0; i < s->n; i++)
        s->it[i].taken = 0;
    s->it[b].taken = 1;
    s->total = base + s->it[b].cost;
}

static void *knap_realloc(const hlod_knapsack *k, void *p, size_t size)
{
    static const hlod_allocator plain = {0};
    return hlod_mem_realloc(k->a ? k->a : &plain, p, size);
}

static int grow(hlod_knapsack *k, size_t n)
{
    if (n <= k->cap)
        return 1;
    size_t cap = n > 2 * k->cap ? n : 2 * k->cap;
    /* heap (v, pos) x 2, kids, child0 (n + 1), child, out; ratio as doubles */
    uint32_t *u = knap_realloc(k, k->u, (8 * cap + 1) * sizeof *u);
    if (!u)
        return 0;
    k->u = u;
    double *r = knap_realloc(k, k->ratio, cap * sizeof *r);
    if (!r)
        return 0;
    k->ratio = r;
    uint8_t *d = knap_realloc(k, k->done, cap);
    if (!d)
        return 0;
    k->done = d;
    k->cap = cap;
    return 1;
}

double hlod_knapsack_solve(hlod_knapsack *k, hlod_knapsack_item *it, uint32_t n, double base,
                           double budget, double fresh)
{
    if (!grow(k, n ? n : 1))
        return -1;
    uint32_t *u = k->u;
    solve s = {.it = it, .n = n, .ratio = k->ratio, .done = k->done, .budget = budget,
               .fresh = fresh < budget ? fresh : budget};
    s.leaves = (heap){u, u + n, 0, 0, s.ratio};
    s.cand = (heap){u + 2 * n, u + 3 * n, 0, 1, s.ratio};
    s.kids = u + 4 * n;
    s.child0 = u + 5 * n;
    s.child = u + 6 * n + 1;
    s.out = u + 7 * n + 1;
    memset(u, 0, (8 * (size_t)n + 1) * sizeof *u);
    memset(s.done, 0, n);

    /* what last frame took stands only under a taken parent, and allowed */
    for (uint32_t i = 0; i < n; i++) {
        hlod_knapsack_item *t = &it[i];
        if (t->taken && (!t->allowed || (t->parent != HLOD_KNAPSACK_NONE && !it[t->parent].taken)))
            t->taken = 0;
        if (t->taken)
            s.done[i] = 2; /* kept from last frame: its bound is the budget */
        s.ratio[i] = t->cost > 0 ? t->gain / t->cost : t->gain > 0 ? INFINITY : -INFINITY;
        if (t->parent != HLOD_KNAPSACK_NONE)
            s.child0[t->parent + 1]++;
    }
    for (uint32_t i = 0; i < n; i++)
        s.child0[i + 1] += s.child0[i];
    for (uint32_t i = 0; i < n; i++)
        if (it[i].parent != HLOD_KNAPSACK_NONE)
            s.child[s.out[it[i].parent]++ + s.child0[it[i].parent]] = i;
    memset(s.out, 0, n * sizeof *s.out);

    if (base > budget) {
        /* even the coarsest choice is over: it alone, as every policy draws
         * only the roots then */
        for (uint32_t i = 0; i < n; i++)
            it[i].taken = 0;
        return base;
    }
    s.total = base;
    for (uint32_t i = 0; i < n; i++)
        if (it[i].taken) {
            s.total += it[i].cost;
            if (it[i].parent != HLOD_KNAPSACK_NONE)
                s.kids[it[i].parent]++;
        }
    for (uint32_t i = 0; i < n; i++) {
        if (is_leaf(&s, i))
            heap_push(&s.leaves, i);
        if (can_take(&s, i))
            heap_push(&s.cand, i);
    }
    shed(&s);
    while (s.cand.n) {
        uint32_t i = heap_pop(&s.cand);
        if (!can_take(&s, i))
            continue;
        int fits = s.total + it[i].cost <= bound_for(&s, i) || it[i].cost <= 0;
        take(&s, i);
        if (!fits)
            make_room(&s, i);
    }
    k->exchanges = s.exchanges;
    best_single(&s, base);
    return s.total;
}

void hlod_knapsack_free(hlod_knapsack *k)
{
    static const hlod_allocator plain = {0};
    const hlod_allocator *a = k->a ? k->a : &plain;
    hlod_mem_free(a, k->u);
    hlod_mem_free(a, k->ratio);
    hlod_mem_free(a, k->done);
    k->u = NULL;
    k->ratio = NULL;
    k->done = NULL;
    k->cap = 0;
}
