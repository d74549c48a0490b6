/*
 * alloc.h - the engine's allocator and its growable arrays (render thread).
 *
 * Every table the engine owns comes from the descriptor's hlod_allocator,
 * or malloc/realloc/free when it has none.  The arrays double their
 * capacity (64 first) and report an allocation failure with 0, leaving the
 * array as it was.
 */
#ifndef HLOD_ENGINE_ALLOC_H
#define HLOD_ENGINE_ALLOC_H

#include "hlod/engine.h"
#include "loader.h"

#include <stddef.h>
#include <stdint.h>

void *hlod_mem_alloc(const hlod_allocator *a, size_t size);
void *hlod_mem_realloc(const hlod_allocator *a, void *p, size_t size);
void hlod_mem_free(const hlod_allocator *a, void *p);   /* p may be NULL */

/* Once per process: glibc's malloc keeps freed memory up to 128 MiB
 * (M_TRIM_THRESHOLD) and serves blocks up to 32 MiB from its heap
 * (M_MMAP_THRESHOLD), unless GLIBC_TUNABLES or MALLOC_*_ set them.  See
 * docs/runtime.md, "The cost model and deadline margin": with glibc's sliding defaults, a
 * software rasteriser's per-draw buffers were given back and faulted in
 * again every frame once the loader went quiet, and a still view's frames
 * took twice their time. */
void hlod_steady_heap(void);

typedef struct hlod_u32_vec {
    uint32_t *v;
    size_t n, cap;
} hlod_u32_vec;

typedef struct hlod_req_vec {
    hlod_load_request *v;
    size_t n, cap;
} hlod_req_vec;

/* Appends; 0 on allocation failure. */
int hlod_u32_push(const hlod_allocator *a, hlod_u32_vec *v, uint32_t x);
/* Appends a request, its priority clamped to a finite float. */
int hlod_req_push(const hlod_allocator *a, hlod_req_vec *v, uint32_t node, double priority);

#endif
