/*
 * sort.h - an in-place sort that never allocates, for the render thread.
 *
 * glibc's qsort() takes a heap buffer for any array over 1 KiB.  The
 * render thread sorts every frame (the cost model's residuals, the load
 * requests, the eviction victims, the draw order), and a malloc there
 * can sleep on the allocator's locks while the loader thread holds them
 * (the sanitizers' allocators lock their free lists and quarantine;
 * test_soak counts such sleeps).  hlod_sort() is an introsort: as fast
 * as qsort on these arrays, O(n log n) in the worst case, no memory but
 * a stack of at most log2 n frames.
 *
 * It is not stable.  Every caller's comparison is a total order (ties are
 * broken by node index), so the result is the one any sort gives.
 */
#ifndef HLOD_SORT_H
#define HLOD_SORT_H

#include <stddef.h>

void hlod_sort(void *base, size_t n, size_t size, int (*cmp)(const void *, const void *));

#endif
