/*
 * sort.c - introsort without allocation (sort.h): quicksort on the median
 * of three, insertion sort under INSERTION_N elements, and heapsort once
 * the partitions recurse past 2 log2 n (so O(n log n) whatever the input).
 */
#include "sort.h"

#include <string.h>

#define INSERTION_N 16

typedef int (*cmp_fn)(const void *, const void *);

static void swap_bytes(unsigned char *a, unsigned char *b, size_t size)
{
    unsigned char t[64];
    while (size) {
        size_t k = size < sizeof t ? size : sizeof t;
        memcpy(t, a, k);
        memcpy(a, b, k);
        memcpy(b, t, k);
        a += k;
        b += k;
        size -= k;
    }
}

/* Moves element i of the n-element heap at v down to its place (a
 * max-heap under cmp). */
static void sift_down(unsigned char *v, size_t i, size_t n, size_t size, cmp_fn cmp)
{
    for (;;) {
        size_t c = 2 * i + 1;
        if (c >= n)
            return;
        if (c + 1 < n && cmp(v + c * size, v + (c + 1) * size) < 0)
            c++;
        if (cmp(v + i * size, v + c * size) >= 0)
            return;
        swap_bytes(v + i * size, v + c * size, size);
        i = c;
    }
}

static void heap_sort(unsigned char *v, size_t n, size_t size, cmp_fn cmp)
{
    for (size_t i = n / 2; i-- > 0;)
        sift_down(v, i, n, size, cmp);
    for (size_t end = n - 1; end > 0; end--) {
        swap_bytes(v, v + end * size, size);
        sift_down(v, 0, end, size, cmp);
    }
}

static void insertion_sort(unsigned char *v, size_t n, size_t size, cmp_fn cmp)
{
    for (size_t i = 1; i < n; i++)
        for (size_t j = i; j > 0 && cmp(v + (j - 1) * size, v + j * size) > 0; j--)
            swap_bytes(v + (j - 1) * size, v + j * size, size);
}

/* Partitions v[0, n) (n > INSERTION_N) around the median of its first,
 * middle and last elements; returns p with v[0, p) <= pivot <= v[p, n),
 * 0 < p < n. */
static size_t partition(unsigned char *v, size_t n, size_t size, cmp_fn cmp)
{
    unsigned char *a = v, *m = v + (n / 2) * size, *z = v + (n - 1) * size;
    if (cmp(m, a) < 0)
        swap_bytes(m, a, size);
    if (cmp(z, m) < 0) {
        swap_bytes(z, m, size);
        if (cmp(m, a) < 0)
            swap_bytes(m, a, size);
    }
    /* the pivot goes to v[0]; a <= pivot <= z bound the scans below */
    swap_bytes(v, m, size);
    size_t i = 0, j = n;
    for (;;) {
        do
            i++;
        while (cmp(v + i * size, v) < 0);
        do
            j--;
        while (cmp(v, v + j * size) < 0);
        if (i >= j)
            break;
        swap_bytes(v + i * size, v + j * size, size);
    }
    swap_bytes(v, v + j * size, size);
    /* v[0, j) <= pivot = v[j] <= v[j + 1, n) */
    return j > 0 ? j : 1;
}

/* Sorts v[0, n); depth partitions left before heapsort takes over. */
static void intro_sort(unsigned char *v, size_t n, size_t size, cmp_fn cmp, int depth)
{
    /* recursion on the smaller part, the loop on the larger: at most
     * log2 n frames deep */
    while (n > INSERTION_N) {
        if (depth-- == 0) {
            heap_sort(v, n, size, cmp);
            return;
        }
        size_t p = partition(v, n, size, cmp);
        if (p < n - p) {
            intro_sort(v, p, size, cmp, depth);
            v += p * size;
            n -= p;
        } else {
            intro_sort(v + p * size, n - p, size, cmp, depth);
            n = p;
        }
    }
    insertion_sort(v, n, size, cmp);
}

void hlod_sort(void *base, size_t n, size_t size, int (*cmp)(const void *, const void *))
{
    if (!base || n < 2 || size == 0)
        return;
    int depth = 0;
    for (size_t k = n; k > 1; k >>= 1)
        depth += 2;
    intro_sort(base, n, size, cmp, depth);
}
