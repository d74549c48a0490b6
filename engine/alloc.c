/*
 * alloc.c - the engine's allocator and its growable arrays (alloc.h).
 */
#include "alloc.h"

#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

static void steady_heap_once(void)
{
#if defined(__GLIBC__)
    const char *tun = getenv("GLIBC_TUNABLES");
    if ((tun && strstr(tun, "glibc.malloc.")) || getenv("MALLOC_TRIM_THRESHOLD_") ||
        getenv("MALLOC_MMAP_THRESHOLD_") || getenv("MALLOC_TOP_PAD_"))
        return; /* the user chose */
    mallopt(M_MMAP_THRESHOLD, 32 << 20);
    mallopt(M_TRIM_THRESHOLD, 128 << 20);
#endif
}

void hlod_steady_heap(void)
{
    static pthread_once_t once = PTHREAD_ONCE_INIT;
    pthread_once(&once, steady_heap_once);
}

void *hlod_mem_alloc(const hlod_allocator *a, size_t size)
{
    return a->alloc ? a->alloc(a->user_data, size) : malloc(size);
}

void *hlod_mem_realloc(const hlod_allocator *a, void *p, size_t size)
{
    return a->realloc ? a->realloc(a->user_data, p, size) : realloc(p, size);
}

void hlod_mem_free(const hlod_allocator *a, void *p)
{
    if (!p)
        return;
    if (a->free)
        a->free(a->user_data, p);
    else
        free(p);
}

static int grow(const hlod_allocator *a, void **v, size_t *cap, size_t need, size_t elem)
{
    if (need <= *cap)
        return 1;
    size_t c = *cap ? *cap : 64;
    while (c < need)
        c *= 2;
    void *p = hlod_mem_realloc(a, *v, c * elem);
    if (!p)
        return 0;
    *v = p;
    *cap = c;
    return 1;
}

int hlod_u32_push(const hlod_allocator *a, hlod_u32_vec *v, uint32_t x)
{
    if (!grow(a, (void **)&v->v, &v->cap, v->n + 1, sizeof *v->v))
        return 0;
    v->v[v->n++] = x;
    return 1;
}

int hlod_req_push(const hlod_allocator *a, hlod_req_vec *v, uint32_t node, double priority)
{
    if (!grow(a, (void **)&v->v, &v->cap, v->n + 1, sizeof *v->v))
        return 0;
    v->v[v->n].node = node;
    v->v[v->n].priority = (float)(priority < 3e38 ? priority : 3e38);
    v->n++;
    return 1;
}
