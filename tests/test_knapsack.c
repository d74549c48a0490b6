/*
 * test_knapsack.c - the fs93 policy's greedy knapsack (engine/knapsack.h)
 * against exact optima: dynamic programming over integer costs for
 * independent items (each a node of the front or its children), and every
 * cut of small random trees.
 */
#include "check.h"
#include "knapsack.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static uint64_t g_rng = 0x2545f4914f6cdd1dull;

static double uniform(void)
{
    g_rng = g_rng * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(g_rng >> 11) / 9007199254740992.0;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* The best gain of independent items within cap (integer costs >= 1). */
static double dp_optimum(const hlod_knapsack_item *it, uint32_t n, int cap)
{
    double best[1024] = {0};
    for (uint32_t i = 0; i < n; i++) {
        int c = (int)it[i].cost;
        if (!it[i].allowed || !(it[i].gain > 0))
            continue;
        for (int w = cap; w >= c; w--)
            if (best[w - c] + it[i].gain > best[w])
                best[w] = best[w - c] + it[i].gain;
    }
    return best[cap];
}

/* Gain and cost of the taken items; 0 when a taken item breaks a rule
 * (not allowed, or its parent not taken). */
static int sums(const hlod_knapsack_item *it, uint32_t n, double *gain, double *cost)
{
    *gain = *cost = 0;
    for (uint32_t i = 0; i < n; i++) {
        if (!it[i].taken)
            continue;
        if (!it[i].allowed || (it[i].parent != HLOD_KNAPSACK_NONE && !it[it[i].parent].taken))
            return 0;
        *gain += it[i].gain;
        *cost += it[i].cost;
    }
    return 1;
}

/* 2,000 fronts of at most 12 independent candidates, integer costs, a
 * random budget and a random last frame: the greedy within the budget,
 * at least half the optimum every time, 0.9 of it at the median. */
static void greedy_half_the_optimum(void)
{
    enum { FRONTS = 2000 };
    static double ratio[FRONTS];
    hlod_knapsack k = {0};
    double worst = INFINITY;
    uint32_t exchanges = 0;
    for (int f = 0; f < FRONTS; f++) {
        hlod_knapsack_item it[12];
        uint32_t n = 1 + (uint32_t)(uniform() * 12);
        int sum = 0;
        for (uint32_t i = 0; i < n; i++) {
            it[i] = (hlod_knapsack_item){.gain = 100 * uniform(),
                                         .cost = 1 + (int)(50 * uniform()),
                                         .parent = HLOD_KNAPSACK_NONE,
                                         .allowed = uniform() < 0.9,
                                         .taken = uniform() < 0.4};
            sum += (int)it[i].cost;
        }
        /* a few fronts where one big item is worth more than the best
         * ratios together (the case the single-item check is for) */
        if (f % 10 == 0 && n >= 2) {
            it[0] = (hlod_knapsack_item){99, 40, HLOD_KNAPSACK_NONE, 1, 0};
            it[1] = (hlod_knapsack_item){3, 1, HLOD_KNAPSACK_NONE, 1, 0};
        }
        int base = (int)(20 * uniform()), cap = (int)(uniform() * sum);
        double total = hlod_knapsack_solve(&k, it, n, base, base + cap, base + cap);
        exchanges += k.exchanges;
        double gain, cost, opt = dp_optimum(it, n, cap);
        CHECKF(sums(it, n, &gain, &cost), "front %d: a taken item not allowed", f);
        CHECKF(fabs(total - (base + cost)) < 1e-9 && cost <= cap + 1e-9,
               "front %d: time %g for base %d + %g, cap %d", f, total, base, cost, cap);
        ratio[f] = opt > 0 ? gain / opt : 1;
        CHECKF(ratio[f] >= 0.5 - 1e-12, "front %d: %g of the optimum %g (%u items, cap %d)", f,
               gain, opt, n, cap);
        if (ratio[f] < worst)
            worst = ratio[f];
    }
    qsort(ratio, FRONTS, sizeof *ratio, cmp_double);
    printf("     greedy / optimum over %d fronts: worst %.3f, 10th percentile %.3f, median %.3f; "
           "%u exchanges\n", FRONTS, worst, ratio[FRONTS / 10], ratio[FRONTS / 2], exchanges);
    CHECKF(ratio[FRONTS / 2] >= 0.9, "median %g of the optimum", ratio[FRONTS / 2]);
    hlod_knapsack_free(&k);
}

/* The best gain over every valid cut of a tree of n <= 12 items. */
static double tree_optimum(const hlod_knapsack_item *it, uint32_t n, double room)
{
    double best = 0;
    for (uint32_t m = 0; m < 1u << n; m++) {
        double g = 0, c = 0;
        int ok = 1;
        for (uint32_t i = 0; i < n && ok; i++) {
            if (!(m >> i & 1))
                continue;
            ok = it[i].allowed && (it[i].parent == HLOD_KNAPSACK_NONE || (m >> it[i].parent & 1));
            g += it[i].gain;
            c += it[i].cost;
        }
        if (ok && c <= room && g > best)
            best = g;
    }
    return best;
}

/* Random trees (a refinement's children may refine in turn): every cut
 * the greedy leaves is whole (a taken item's parent taken) and within the
 * budget, and what it reaches of the exhaustive optimum is reported. */
static void tree_cuts_stay_whole(void)
{
    enum { TREES = 1000 };
    static double ratio[TREES];
    hlod_knapsack k = {0};
    for (int f = 0; f < TREES; f++) {
        hlod_knapsack_item it[12];
        uint32_t n = 1 + (uint32_t)(uniform() * 12);
        double sum = 0;
        for (uint32_t i = 0; i < n; i++) {
            uint32_t parent = i > 0 && uniform() < 0.6 ? (uint32_t)(uniform() * i)
                                                       : HLOD_KNAPSACK_NONE;
            it[i] = (hlod_knapsack_item){.gain = 100 * uniform(),
                                         .cost = 1 + 50 * uniform(),
                                         .parent = parent,
                                         .allowed = uniform() < 0.9,
                                         .taken = uniform() < 0.5};
            sum += it[i].cost;
        }
        double base = 10, room = uniform() * sum;
        double total = hlod_knapsack_solve(&k, it, n, base, base + room, base + room);
        double gain, cost, opt = tree_optimum(it, n, room);
        CHECKF(sums(it, n, &gain, &cost), "tree %d: a cut with a taken item under one not taken",
               f);
        CHECKF(cost <= room + 1e-9 && fabs(total - base - cost) < 1e-9,
               "tree %d: cost %g over room %g", f, cost, room);
        ratio[f] = opt > 0 ? gain / opt : 1;
    }
    qsort(ratio, TREES, sizeof *ratio, cmp_double);
    printf("     trees: greedy / optimum worst %.3f, 10th percentile %.3f, median %.3f\n",
           ratio[0], ratio[TREES / 10], ratio[TREES / 2]);
    CHECKF(ratio[TREES / 2] >= 0.9, "trees: median %g of the optimum", ratio[TREES / 2]);
    hlod_knapsack_free(&k);
}

/* The edges: a front whose coarsest choice is already over the budget
 * takes nothing; else a refinement that saves time and gains is taken,
 * one taken last frame and worth nothing is given back, and one that
 * still fits stays; what last frame took and still fits stays, one no
 * longer allowed is given back; a new item must fit the fresh bound, a
 * kept one the budget. */
static void edges(void)
{
    hlod_knapsack k = {0};
    hlod_knapsack_item it[3] = {{5, 1, HLOD_KNAPSACK_NONE, 1, 1},
                                {5, -2, HLOD_KNAPSACK_NONE, 1, 0},
                                {-1, 1, HLOD_KNAPSACK_NONE, 1, 1}};
    double t = hlod_knapsack_solve(&k, it, 3, 20, 10, 10);
    CHECKF(!it[0].taken && !it[1].taken && !it[2].taken && fabs(t - 20) < 1e-9,
           "over the budget: taken %d %d %d, time %g", it[0].taken, it[1].taken, it[2].taken, t);
    it[0].taken = it[2].taken = 1;
    t = hlod_knapsack_solve(&k, it, 3, 5, 10, 10);
    CHECKF(it[0].taken && it[1].taken && !it[2].taken && fabs(t - 4) < 1e-9,
           "5 ms of a 10 ms budget: taken %d %d %d, time %g", it[0].taken, it[1].taken,
           it[2].taken, t);
    hlod_knapsack_item keep[3] = {{5, 3, HLOD_KNAPSACK_NONE, 1, 1},
                                  {1, 3, 0, 1, 1},
                                  {4, 3, HLOD_KNAPSACK_NONE, 0, 1}};
    t = hlod_knapsack_solve(&k, keep, 3, 0, 6, 6);
    CHECKF(keep[0].taken && keep[1].taken && !keep[2].taken && fabs(t - 6) < 1e-9,
           "kept: taken %d %d %d (the third not allowed), time %g", keep[0].taken, keep[1].taken,
           keep[2].taken, t);
    /* the fresh bound: a new item must fit it, a kept one only the budget */
    hlod_knapsack_item two[2] = {{5, 5, HLOD_KNAPSACK_NONE, 1, 1}, {4, 3, HLOD_KNAPSACK_NONE, 1, 0}};
    t = hlod_knapsack_solve(&k, two, 2, 0, 9, 7);
    CHECKF(two[0].taken && !two[1].taken && fabs(t - 5) < 1e-9,
           "budget 9, fresh 7: taken %d %d, time %g", two[0].taken, two[1].taken, t);
    two[0].taken = 1;
    two[1].taken = 0;
    t = hlod_knapsack_solve(&k, two, 2, 0, 9, 9);
    CHECKF(two[0].taken && two[1].taken && fabs(t - 8) < 1e-9,
           "budget and fresh 9: taken %d %d, time %g", two[0].taken, two[1].taken, t);
    hlod_knapsack_item late[1] = {{5, 8, HLOD_KNAPSACK_NONE, 1, 1}};
    t = hlod_knapsack_solve(&k, late, 1, 0, 9, 7);
    CHECKF(late[0].taken, "a kept item over the fresh bound but within the budget given back");
    hlod_knapsack_free(&k);
}

int main(void)
{
    RUN(greedy_half_the_optimum);
    RUN(tree_cuts_stay_whole);
    RUN(edges);
    return check_done();
}
