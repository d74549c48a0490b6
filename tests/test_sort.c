/*
 * test_sort.c - hlod_sort (engine/sort.h) against qsort: the same order
 * for total orders over random, sorted, reversed, constant and
 * few-valued arrays of several element sizes; the cases that drive a
 * quicksort to its worst case end sorted too (the heapsort fallback).
 */
#include "check.h"
#include "sort.h"

#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static uint64_t g_rng = 0x9e3779b97f4a7c15ull;

static uint32_t next(void)
{
    g_rng = g_rng * 6364136223846793005ull + 1442695040888963407ull;
    return (uint32_t)(g_rng >> 33);
}

/* A record as the engine sorts them: a key, then a unique index, and
 * padding to an odd size. */
typedef struct rec {
    float key;
    uint32_t id;
    unsigned char pad[5];
} rec;

static int cmp_rec(const void *a, const void *b)
{
    const rec *x = a, *y = b;
    if (x->key != y->key)
        return x->key < y->key ? -1 : 1;
    return (x->id > y->id) - (x->id < y->id);
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

enum { RANDOM, SORTED, REVERSED, CONSTANT, FEW, ORGAN, SHAPES };

static double value(int shape, size_t i, size_t n)
{
    switch (shape) {
    case RANDOM: return next() / 4294967296.0;
    case SORTED: return (double)i;
    case REVERSED: return (double)(n - i);
    case CONSTANT: return 1.0;
    case FEW: return next() % 3;
    default: return (double)(i < n / 2 ? i : n - i); /* organ pipe */
    }
}

static void same_as_qsort(void)
{
    const size_t sizes[] = {0, 1, 2, 3, 15, 16, 17, 31, 100, 511, 512, 4000, 20000};
    int bad = 0, cases = 0;
    for (size_t s = 0; s < sizeof sizes / sizeof *sizes; s++) {
        size_t n = sizes[s];
        for (int shape = 0; shape < SHAPES; shape++) {
            rec *a = malloc((n + 1) * sizeof *a), *b = malloc((n + 1) * sizeof *b);
            double *x = malloc((n + 1) * sizeof *x), *y = malloc((n + 1) * sizeof *y);
            CHECK(a && b && x && y);
            if (!a || !b || !x || !y)
                return;
            for (size_t i = 0; i < n; i++) {
                memset(&a[i], 0, sizeof a[i]);
                a[i].key = (float)value(shape, i, n);
                a[i].id = next();
                x[i] = value(shape, i, n);
            }
            memcpy(b, a, n * sizeof *a);
            memcpy(y, x, n * sizeof *x);
            hlod_sort(a, n, sizeof *a, cmp_rec);
            qsort(b, n, sizeof *b, cmp_rec);
            hlod_sort(x, n, sizeof *x, cmp_double);
            qsort(y, n, sizeof *y, cmp_double);
            int differ = (n && memcmp(a, b, n * sizeof *a)) || (n && memcmp(x, y, n * sizeof *x));
            CHECKF(!differ, "n=%zu shape %d: hlod_sort's order differs from qsort's", n, shape);
            bad += differ;
            cases++;
            free(a);
            free(b);
            free(x);
            free(y);
        }
    }
    printf("REPORT sort cases=%d differing=%d\n", cases, bad);
}

/* An element bigger than the swap buffer moves whole. */
typedef struct big {
    uint32_t key;
    unsigned char body[200];
} big;

static int cmp_big(const void *a, const void *b)
{
    const big *x = a, *y = b;
    return (x->key > y->key) - (x->key < y->key);
}

static void edges(void)
{
    big v[40];
    for (int i = 0; i < 40; i++) {
        v[i].key = (uint32_t)(40 - i);
        memset(v[i].body, 40 - i, sizeof v[i].body);
    }
    hlod_sort(NULL, 0, sizeof *v, cmp_big); /* nothing to sort */
    hlod_sort(v, 40, sizeof *v, cmp_big);
    int ok = 1;
    for (int i = 0; i < 40; i++)
        ok &= v[i].key == (uint32_t)(i + 1) && v[i].body[0] == i + 1 && v[i].body[199] == i + 1;
    CHECKF(ok, "200-byte records: sorted with their bodies");
}

int main(void)
{
    RUN(same_as_qsort);
    RUN(edges);
    return check_done();
}
