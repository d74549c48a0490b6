/*
 * loader.h - the loader thread (Lakhia III-D), internal to the engine.
 *
 * The render thread owns residency: it decides what may be loaded (admission
 * against the memory budget, evicting lower-priority resident nodes first)
 * and hands the loader an ordered list of requests each frame.  The loader
 * only reads: it takes the most urgent request, reads its payload in small
 * increments (hlod_store_read_step), re-checks the list between increments
 * and switches to a more urgent node when one appears.  A suspended read
 * keeps its bytes and resumes where it stopped, as long as its node stays in
 * the list; a node dropped from the list has its partial read freed.
 * Finished payloads (checksum verified by hlod_store_read_finish) and
 * failures go to a result queue that the render thread drains.
 *
 * Never blocking the render thread: post and collect take the loader's
 * mutex with trylock only; the mutex is never held across I/O, hashing or
 * parsing (only to swap short arrays).  When trylock fails the call does
 * nothing and returns 0 (the render thread tries again next frame).
 *
 * Synchronous mode (threaded = 0): no thread; hlod_loader_pump() does the
 * same work on the caller's thread, reproducibly.
 */
#ifndef HLOD_ENGINE_LOADER_H
#define HLOD_ENGINE_LOADER_H

#include "hlod/engine.h"

typedef struct hlod_loader hlod_loader;

typedef struct hlod_load_request {
    uint32_t node;
    float priority;         /* larger = more urgent; the list is sorted by it */
} hlod_load_request;

typedef struct hlod_load_result {
    uint32_t node;
    hlod_result result;     /* HLOD_OK: payload valid; else payload zeroed */
    hlod_store_payload payload;
} hlod_load_result;

typedef struct hlod_loader_desc {
    int threaded;               /* 1: own thread; 0: work only in hlod_loader_pump */
    uint32_t chunk_bytes;       /* increment, e.g. 65536 */
    hlod_read_hook hook;        /* may be NULL */
    void *hook_user;
    hlod_logger logger;
    int prepare_textures;       /* 1: build each texture's mip chain (texture.h) here,
                                   off the render thread that uploads it */
    int idle;                   /* 1: the thread runs under SCHED_IDLE (falling back to
                                   nice 19 where that is refused); 0: at nice 10 */
    int texture_out;            /* HLOD_TEXOUT_*: what a block-coded texture becomes
                                   here (store.h, hlod_store_read_finish_as) */
} hlod_loader_desc;

typedef struct hlod_loader_counters {
    uint64_t bytes_read;        /* total so far */
    uint64_t reads_done;        /* payloads finished OK */
    uint64_t reads_failed;
    uint64_t switches;          /* times a read was suspended for a more urgent one */
    uint64_t finish_ns;         /* thread CPU time in hlod_store_read_finish: checksum,
                                   decoding (packed stores) and validation, and in
                                   the mip chain when prepare_textures */
    uint64_t busy_ns;           /* thread CPU time of all the loader's work */
    uint64_t cache_hits;        /* payloads taken from the local cache (HLOD_CACHE_DIR):
                                   not in bytes_read */
} hlod_loader_counters;

hlod_result hlod_loader_create(const hlod_store *s, const hlod_loader_desc *d,
                               hlod_loader **out);
/* Stops and joins the thread, cancels reads, frees queued results. */
void hlod_loader_destroy(hlod_loader *l);

/* Replaces the request list (n entries, sorted by priority descending, no
 * duplicates).  Returns 1 when posted, 0 when the loader was busy swapping
 * (trylock failed; nothing changed).  Render thread. */
int hlod_loader_post(hlod_loader *l, const hlod_load_request *reqs, size_t n);

/* Moves up to max finished results into out; returns how many.  0 when none
 * or when the loader was busy (trylock failed).  The caller owns the
 * payloads.  Render thread. */
size_t hlod_loader_collect(hlod_loader *l, hlod_load_result *out, size_t max);

/* 1 when the loader has done all it was last given and waits for a new
 * list (a synchronous loader: always).  For tests that step the loader
 * with their frames.  Any thread. */
int hlod_loader_idle(const hlod_loader *l);

/* Hands back a payload the caller is done with (zeroed): the loader
 * thread frees it, so the render thread never takes the loader's malloc
 * arena lock; synchronous loaders free it at once.  Render thread. */
void hlod_loader_discard(hlod_loader *l, hlod_store_payload *p);

/* Synchronous mode: reads up to max_bytes in priority order (finishing
 * reads into the result queue).  Returns the bytes read.  In threaded mode
 * it does nothing and returns 0. */
uint64_t hlod_loader_pump(hlod_loader *l, uint64_t max_bytes);

/* Counters, read atomically; any thread. */
void hlod_loader_get_counters(const hlod_loader *l, hlod_loader_counters *out);

#endif
