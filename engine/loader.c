/*
 * loader.c - the loader thread (Lakhia III-D): incremental, preemptive
 * payload reads in the order the render thread asks for.
 *
 * Who owns what:
 *   - shared, under mu: the inbox (the last posted list, until the loader
 *     takes it), a spare list buffer handed back to post for reuse, and the
 *     result queue.  mu is held only to swap pointers and copy short arrays:
 *     never across I/O, hashing, parsing or the hook, never while
 *     allocating.  post and collect only trylock it.
 *   - atomics: the post version (the cheap "anything new?" check the loader
 *     makes between increments), the stop flag and the counters.
 *   - the loader's own (the loader thread; in synchronous mode whoever calls
 *     hlod_loader_pump): the current list, the open reads and per-node
 *     stamps.
 *
 * A list's order is its priority order (the priority values are not read).
 * Each list the loader takes gets a new generation `gen`.  A node whose read
 * finished or failed under the current list has done_gen == gen and is not
 * read again until a later list asks for it (the render thread decides about
 * retries).  The work is always the first request of the list that is not
 * done: the loader reads it one chunk at a time and re-checks the version
 * between chunks.  When a new list puts another node first, the current read
 * is left open (its bytes and hash state stay in its hlod_store_read) and
 * resumes where it stopped if its node comes first again; a read whose node
 * is not in the new list is cancelled, and at most LOADER_MAX_SUSPENDED reads
 * wait suspended (the least urgent is cancelled to open another).
 *
 * A result the render thread had not collected when it posted a list was
 * unknown to it when it built that list, so its node counts as done under
 * that list too: otherwise a read finishing between the render thread's
 * collect and its post would be read twice.  The loader keeps the sequence
 * numbers of the results it queued (`sent`) and post records how many had
 * been collected (`inbox_seen`).
 *
 * Every list of n requests yields at most n results, so when the loader
 * takes a list it reserves queue room for the results still queued plus n:
 * queueing a result never allocates and never fails.
 *
 * Payloads the render thread is done with come back to be freed here
 * (hlod_loader_discard): freed on the render thread, a block the loader
 * allocated takes the loader's malloc arena lock, and the render thread
 * slept on it while the loader allocated.  The render thread gathers them
 * in its own list (trash); post hands that list over (garbage, under mu)
 * once the loader has taken the last one, and the loader frees them
 * outside the lock (freeing).
 */
#define _GNU_SOURCE /* syscall(SYS_gettid): the loader thread's own nice value */
#include "loader.h"
#include "texture.h"

#include <assert.h>
#include <errno.h>
#include <pthread.h>
#include <sched.h>
#include <sys/eventfd.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define LOADER_MAX_SUSPENDED 8
#define LOADER_SLOTS (LOADER_MAX_SUSPENDED + 1) /* the current read and the suspended */
#define LOADER_DEFAULT_CHUNK 65536u
/* A store read over HTTP: parallel transfers, each a range request of at
 * most LOADER_HTTP_RANGE bytes (each request costs a round trip). */
/* 12 by default: each request waits a round trip, and 6 (a browser's
 * HTTP/1.1 count) cap a 40 ms link at 150 requests a second, 5 a frame at
 * 30 Hz, fewer than a moving camera's refinements ask for: on the small
 * city's fly at 40 ms and 100 Mbit/s, 6 transfers missed 54 and 86 frames
 * against the file's 16 and 17, 12 missed 25 and 34 against 18 and 24. */
#define LOADER_HTTP_TRANSFERS 12u   /* env HLOD_HTTP_TRANSFERS overrides, 1..16 */
#define LOADER_HTTP_MAX_TRANSFERS 16u
#define LOADER_HTTP_RANGE (1u << 20)
#define LOADER_SLOTS_MAX (LOADER_HTTP_MAX_TRANSFERS + LOADER_SLOTS)
#define LOADER_HTTP_POLL_MS 100     /* the longest a poll waits (a post wakes it) */

/* Loader's per-node stamps. */
typedef struct loader_node {
    uint32_t list_gen;      /* == gen: in the current list, at index rank */
    uint32_t rank;
    uint32_t done_gen;      /* == gen: finished or failed under the current list */
    uint32_t logged;        /* a failure of this node was logged */
} loader_node;

/* A result the loader queued: its sequence number and node. */
typedef struct loader_sent {
    uint64_t seq;
    uint32_t node;
} loader_sent;

struct hlod_loader {
    const hlod_store *store;
    uint32_t node_count;
    hlod_loader_desc d;

    pthread_mutex_t mu;
    pthread_cond_t wake;        /* signalled by post and destroy */
    pthread_t thread;
    int has_thread;

    /* shared, under mu */
    hlod_load_request *inbox;   /* the last posted list; NULL once taken */
    size_t inbox_n, inbox_cap;
    uint64_t inbox_seen;        /* results collected when the inbox was posted */
    hlod_load_request *spare;   /* a list buffer handed back to post */
    size_t spare_cap;
    hlod_load_result *res;      /* the queue: [res_head, res_n) */
    size_t res_head, res_n, res_cap; /* res_cap is written by the loader only */
    uint64_t collected;         /* results collected so far */

    /* render thread only */
    hlod_load_request *post_buf;
    size_t post_cap;
    void **trash;               /* payload blocks to free, not yet handed over */
    size_t trash_n, trash_cap;

    /* shared, under mu: handed over by post, taken by the loader */
    void **garbage;
    size_t garbage_n, garbage_cap;
    atomic_int garbage_ready;   /* garbage_n > 0: the loader's cheap check */
    /* the loader's: what it frees now */
    void **freeing;
    size_t freeing_n, freeing_cap;

    /* the loader's own */
    hlod_load_request *list;
    size_t list_n, list_cap;
    size_t cursor;              /* the requests before it are done */
    uint64_t list_version;      /* version of the list taken */
    uint32_t gen;
    loader_node *nodes;         /* node_count */
    hlod_store_read reads[LOADER_SLOTS_MAX]; /* open when .store != NULL */
    int nslots;                 /* reads used: LOADER_SLOTS, + transfers over HTTP */
    hlod_store_fetch *fetch;    /* a store read over HTTP: its transfers; else NULL */
    unsigned transfers;
    int wake_fd;                /* eventfd post writes to wake a poll (HTTP, threaded); -1 */
    struct http_plan *plan;     /* HTTP pump: the ranges of one pump, in list order */
    size_t plan_cap;
    hlod_store_read *cur;       /* the read stepped last, if still open */
    loader_sent *sent;          /* queued results the render thread may not have seen */
    size_t sent_n, sent_cap;
    uint64_t pushed;            /* results queued so far */

    atomic_uint_fast64_t version; /* lists posted so far */
    atomic_uint_fast64_t idle_at; /* + 1: the version the loader last went idle at (0: never) */
    atomic_int stop;
    atomic_uint_fast64_t bytes_read, reads_done, reads_failed, switches;
    atomic_uint_fast64_t finish_ns, busy_ns, cache_hits;
};

/* ---- the loader's side (loader thread, or the pump caller) ---- */

static size_t grow_cap(size_t cap, size_t need)
{
    if (cap < 16)
        cap = 16;
    while (cap < need)
        cap *= 2;
    return cap;
}

/* loader thread: room for every result the current list can produce (see
 * the top of the file).  pending: results queued when the list was taken.
 * On allocation failure the list is cut to what fits; the render thread
 * posts the rest again next frame. */
static void reserve_results(hlod_loader *l, size_t pending)
{
    size_t need = pending + l->list_n;
    if (need > l->res_cap) {
        size_t cap = grow_cap(l->res_cap, need);
        hlod_load_result *a = malloc(cap * sizeof *a);
        if (a) {
            /* collect may have taken some meanwhile: copy what is left */
            pthread_mutex_lock(&l->mu);
            hlod_load_result *old = l->res;
            size_t k = l->res_n - l->res_head;
            if (k)
                memcpy(a, old + l->res_head, k * sizeof *a);
            l->res = a;
            l->res_head = 0;
            l->res_n = k;
            l->res_cap = cap;
            pthread_mutex_unlock(&l->mu);
            free(old);
        }
    }
    need = l->sent_n + l->list_n;
    if (need > l->sent_cap) {
        size_t cap = grow_cap(l->sent_cap, need);
        loader_sent *a = realloc(l->sent, cap * sizeof *a);
        if (a) {
            l->sent = a;
            l->sent_cap = cap;
        }
    }
    size_t fit = l->res_cap - pending;
    if (l->sent_cap - l->sent_n < fit)
        fit = l->sent_cap - l->sent_n;
    if (fit < l->list_n) {
        hlod_logf(&l->d.logger, HLOD_LOG_ERROR,
                  "loader: out of memory: reading only %zu of %zu requests", fit, l->list_n);
        l->list_n = fit;
    }
}

/* loader thread */
static void close_read(hlod_loader *l, hlod_store_read *rd)
{
    if (l->cur == rd)
        l->cur = NULL;
    hlod_store_fetch_stop(l->fetch, rd);    /* no-op without a transfer */
    hlod_store_read_cancel(rd);
}

/* loader thread: swaps the posted list in and re-stamps the nodes. */
static void take_list(hlod_loader *l)
{
    hlod_load_request *old = l->list;
    size_t old_cap = l->list_cap;

    pthread_mutex_lock(&l->mu);
    l->list_version = atomic_load(&l->version);
    l->list = l->inbox;
    l->list_n = l->inbox_n;
    l->list_cap = l->inbox_cap;
    uint64_t seen = l->inbox_seen;
    size_t pending = l->res_n - l->res_head;
    l->inbox = NULL;
    l->inbox_n = l->inbox_cap = 0;
    if (!l->spare) {
        l->spare = old;
        l->spare_cap = old_cap;
        old = NULL;
    }
    pthread_mutex_unlock(&l->mu);
    free(old);

    l->cursor = 0;
    if (++l->gen == 0) {
        /* wrapped after 2^32 lists: old stamps could alias the new ones */
        for (uint32_t i = 0; i < l->node_count; i++)
            l->nodes[i].list_gen = l->nodes[i].done_gen = 0;
        l->gen = 1;
    }

    /* forget the results the render thread had seen when it posted */
    size_t k = 0;
    while (k < l->sent_n && l->sent[k].seq < seen)
        k++;
    if (k) {
        l->sent_n -= k;
        memmove(l->sent, l->sent + k, l->sent_n * sizeof *l->sent);
    }

    reserve_results(l, pending);

    for (size_t i = 0; i < l->list_n; i++) {
        uint32_t node = l->list[i].node;
        if (node < l->node_count && l->nodes[node].list_gen != l->gen) {
            l->nodes[node].list_gen = l->gen;
            l->nodes[node].rank = (uint32_t)i;
        }
    }
    for (size_t i = 0; i < l->sent_n; i++)
        if (l->sent[i].node < l->node_count)
            l->nodes[l->sent[i].node].done_gen = l->gen;

    for (int i = 0; i < l->nslots; i++) {
        hlod_store_read *rd = &l->reads[i];
        if (rd->store && (l->nodes[rd->node].list_gen != l->gen ||
                          l->nodes[rd->node].done_gen == l->gen))
            close_read(l, rd);      /* dropped from the list */
    }
}

/* loader thread: queues a result; room was reserved by take_list. */
static void push_result(hlod_loader *l, uint32_t node, hlod_result r,
                        const hlod_store_payload *p)
{
    hlod_load_result res;
    memset(&res, 0, sizeof res);
    res.node = node;
    res.result = r;
    if (p)
        res.payload = *p;

    pthread_mutex_lock(&l->mu);
    if (l->res_n == l->res_cap && l->res_head > 0) {
        l->res_n -= l->res_head;
        memmove(l->res, l->res + l->res_head, l->res_n * sizeof *l->res);
        l->res_head = 0;
    }
    assert(l->res_n < l->res_cap);
    l->res[l->res_n++] = res;
    pthread_mutex_unlock(&l->mu);

    assert(l->sent_n < l->sent_cap);
    l->sent[l->sent_n].seq = l->pushed++;
    l->sent[l->sent_n].node = node;
    l->sent_n++;
    if (node < l->node_count)
        l->nodes[node].done_gen = l->gen;
}

/* loader thread: reports a failed read (logged once per node). */
static void fail_node(hlod_loader *l, uint32_t node, hlod_result r)
{
    atomic_fetch_add_explicit(&l->reads_failed, 1, memory_order_relaxed);
    int valid = node < l->node_count;
    if (!valid || !l->nodes[node].logged) {
        if (valid)
            l->nodes[node].logged = 1;
        hlod_logf(&l->d.logger, r == HLOD_ERR_IO ? HLOD_LOG_WARN : HLOD_LOG_ERROR,
                  "loader: %s: node %u: read failed: %s", hlod_store_path(l->store), node,
                  hlod_result_str(r));
    }
    push_result(l, node, r, NULL);
}

/* loader thread: a free slot for a new read; when all are taken, cancels the
 * least urgent open read (every open read's node is in the list). */
static hlod_store_read *free_slot(hlod_loader *l)
{
    hlod_store_read *worst = NULL;
    for (int i = 0; i < l->nslots; i++) {
        hlod_store_read *rd = &l->reads[i];
        if (!rd->store)
            return rd;
        assert(l->nodes[rd->node].list_gen == l->gen);
        if (!worst || l->nodes[rd->node].rank > l->nodes[worst->node].rank)
            worst = rd;
    }
    close_read(l, worst);
    return worst;
}

/* loader thread: the open read of node, or NULL */
static hlod_store_read *find_read(hlod_loader *l, uint32_t node)
{
    for (int i = 0; i < l->nslots; i++)
        if (l->reads[i].store && l->reads[i].node == node)
            return &l->reads[i];
    return NULL;
}

/* CPU time of the calling thread, ns (what the loader spends, whatever the
 * scheduler does to its wall time at nice 10) */
static uint64_t thread_cpu_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* loader thread: checksum, decoding and validation of a complete read,
 * then its result (rd ends zeroed). */
static hlod_result finish_payload(hlod_loader *l, hlod_store_read *rd, hlod_store_payload *p)
{
    if (l->cur == rd)
        l->cur = NULL;
    uint64_t t0 = thread_cpu_ns();
    /* verifies the checksum, decodes; zeroes rd */
    hlod_result r = hlod_store_read_finish_as(rd, l->d.texture_out, p);
    if (r == HLOD_OK && l->d.prepare_textures)
        (void)hlod_texture_prepare(p); /* out of memory: the upload makes the chain */
    atomic_fetch_add_explicit(&l->finish_ns, thread_cpu_ns() - t0, memory_order_relaxed);
    return r;
}

static void finish_read(hlod_loader *l, hlod_store_read *rd)
{
    uint32_t node = rd->node;
    hlod_store_payload p;
    hlod_result r = finish_payload(l, rd, &p);
    if (r != HLOD_OK) {
        fail_node(l, node, r);
    } else {
        atomic_fetch_add_explicit(&l->reads_done, 1, memory_order_relaxed);
        push_result(l, node, HLOD_OK, &p);
    }
}

/* loader thread (or the pump caller): one increment of the most urgent
 * request not done (hook, one hlod_store_read_step of at most chunk_bytes
 * and budget bytes, and the finish when that completes it), or one failure.
 * Adds the bytes read to *bytes.  Returns 0 when the list is done. */
static int work(hlod_loader *l, uint64_t budget, uint64_t *bytes)
{
    assert(budget > 0);
    if (atomic_load(&l->version) != l->list_version)
        take_list(l);

    uint32_t node;
    for (;; l->cursor++) {
        if (l->cursor == l->list_n)
            return 0;
        node = l->list[l->cursor].node;
        if (node >= l->node_count) {
            l->cursor++;
            fail_node(l, node, HLOD_ERR_INVALID_ARG);
            return 1;
        }
        if (l->nodes[node].done_gen != l->gen)
            break;
    }

    hlod_store_read *rd = find_read(l, node);
    if (!rd) {
        rd = free_slot(l);
        hlod_result r = hlod_store_read_begin(l->store, node, rd);
        if (r != HLOD_OK) {
            fail_node(l, node, r);
            return 1;
        }
    }
    if (l->cur && l->cur != rd)
        atomic_fetch_add_explicit(&l->switches, 1, memory_order_relaxed);
    l->cur = rd;

    uint64_t left = rd->size - rd->done;
    uint64_t want = l->d.chunk_bytes;
    if (left < want)
        want = left;
    if (budget < want)
        want = budget;
    if (want == 0)
        want = 1;       /* an empty remainder: the step just reports completion */

    hlod_result r = HLOD_OK;
    if (l->d.hook)
        r = l->d.hook(l->d.hook_user, node, rd->done, (size_t)want);
    int complete = 0;
    if (r == HLOD_OK) {
        uint64_t before = rd->done;
        r = hlod_store_read_step(rd, (size_t)want, &complete);
        atomic_fetch_add_explicit(&l->bytes_read, rd->done - before, memory_order_relaxed);
        *bytes += rd->done - before;
    }
    if (r != HLOD_OK) {
        close_read(l, rd);
        fail_node(l, node, r);
        return 1;
    }
    if (complete)
        finish_read(l, rd);
    return 1;
}

/* ---- a store read over HTTP: parallel transfers ---- */

/* loader thread: the index of the first request from *i on that is not
 * done (an invalid node is failed on the way), or list_n. */
static size_t next_undone(hlod_loader *l, size_t i)
{
    for (; i < l->list_n; i++) {
        uint32_t node = l->list[i].node;
        if (node >= l->node_count) {
            if (i == l->cursor) {
                l->cursor++;
                fail_node(l, node, HLOD_ERR_INVALID_ARG);
            }
            continue;
        }
        if (l->nodes[node].done_gen != l->gen)
            return i;
        if (i == l->cursor)
            l->cursor++;
    }
    return i;
}

/* loader thread: the open read of node, opened when there is none (NULL
 * after failing the node). */
static hlod_store_read *open_read(hlod_loader *l, uint32_t node)
{
    hlod_store_read *rd = find_read(l, node);
    if (rd)
        return rd;
    rd = free_slot(l);
    hlod_result r = hlod_store_read_begin(l->store, node, rd);
    if (r != HLOD_OK) {
        fail_node(l, node, r);
        return NULL;
    }
    return rd;
}

/* loader thread: a transfer of at most max bytes for rd (the hook first);
 * the node failed when 0 is returned. */
static int start_range(hlod_loader *l, hlod_store_read *rd, uint64_t max)
{
    uint64_t left = rd->size - rd->done;
    uint64_t want = left < max ? left : max;
    hlod_result r = HLOD_OK;
    if (l->d.hook)
        r = l->d.hook(l->d.hook_user, rd->node, rd->done, (size_t)want);
    if (r == HLOD_OK)
        r = hlod_store_fetch_start(l->fetch, rd, want);
    if (r != HLOD_OK) {
        uint32_t node = rd->node;
        close_read(l, rd);
        fail_node(l, node, r);
        return 0;
    }
    return 1;
}

/* loader thread: the first `transfers` requests not done get a transfer
 * each, most urgent first; a transfer of any other read stops (preempted:
 * its bytes stay in the read, which resumes from there with a new range
 * when its node comes up again).  A read not begun is first looked up in
 * the local cache (HLOD_CACHE_DIR): an entry whose checksum matches is
 * finished at once, without a transfer.  Returns the cache hits. */
static unsigned http_assign(hlod_loader *l)
{
    unsigned hits = 0;
    uint32_t want[LOADER_HTTP_MAX_TRANSFERS];
    unsigned nw = 0;
    for (size_t i = next_undone(l, l->cursor); i < l->list_n && nw < l->transfers;
         i = next_undone(l, i + 1))
        want[nw++] = l->list[i].node;
    for (int s = 0; s < l->nslots; s++) {
        hlod_store_read *rd = &l->reads[s];
        if (!rd->store || !hlod_store_fetch_has(l->fetch, rd))
            continue;
        unsigned k = 0;
        while (k < nw && want[k] != rd->node)
            k++;
        if (k == nw) {
            hlod_store_fetch_stop(l->fetch, rd);
            atomic_fetch_add_explicit(&l->switches, 1, memory_order_relaxed);
        }
    }
    for (unsigned k = 0; k < nw; k++) {
        hlod_store_read *rd = open_read(l, want[k]);
        if (!rd || hlod_store_fetch_has(l->fetch, rd))
            continue;
        if (rd->done == 0 && hlod_store_cache_get(rd)) {
            atomic_fetch_add_explicit(&l->cache_hits, 1, memory_order_relaxed);
            hits++;
            finish_read(l, rd);
            continue;
        }
        if (rd->done == rd->size)
            finish_read(l, rd); /* not reached: a complete read is finished at once */
        else
            start_range(l, rd, LOADER_HTTP_RANGE);
    }
    return hits;
}

/* loader thread: runs the transfers up to timeout_ms; finishes the reads
 * whose last byte came, fails those whose transfer failed (after the HTTP
 * layer's retries: residency retries a transient failure later). */
static void http_collect(hlod_loader *l, int timeout_ms)
{
    hlod_store_fetch_end ends[LOADER_HTTP_MAX_TRANSFERS];
    uint64_t bytes = 0;
    size_t n = hlod_store_fetch_poll(l->fetch, timeout_ms, l->wake_fd, ends, l->transfers, &bytes);
    if (l->wake_fd >= 0) {
        uint64_t v;
        while (read(l->wake_fd, &v, sizeof v) < 0 && errno == EINTR)
            ;
    }
    atomic_fetch_add_explicit(&l->bytes_read, bytes, memory_order_relaxed);
    for (size_t i = 0; i < n; i++) {
        hlod_store_read *rd = ends[i].rd;
        uint32_t node = rd->node;
        if (ends[i].result != HLOD_OK) {
            close_read(l, rd);
            fail_node(l, node, ends[i].result);
        } else if (rd->done == rd->size) {
            hlod_store_cache_put(rd);   /* checksum matched: kept for the next run */
            finish_read(l, rd);
        }
    }
}

/* The HTTP pump's ranges, in list order: each node's result is queued in
 * that order once every transfer of the pump has ended, as the file's
 * pump, reading one node after the other, would queue them. */
typedef struct http_plan {
    uint32_t node;
    hlod_store_read *rd;        /* while its transfer runs */
    hlod_result result;
    int has_result;             /* else the read stays open (budget reached) */
    hlod_store_payload payload;
} http_plan;

/* pump caller: the next range of the plan (from request *i on, within
 * *budget), or 0 when none.  *i only grows: no node is planned twice. */
static int plan_next(hlod_loader *l, size_t *i, uint64_t *budget, size_t *np)
{
    for (; *i < l->list_n && *budget > 0; (*i)++) {
        uint32_t node = l->list[*i].node;
        if (node >= l->node_count || l->nodes[node].done_gen == l->gen)
            continue;   /* an invalid node fails when the cursor reaches it */
        hlod_store_read *rd = open_read(l, node);
        if (!rd || !start_range(l, rd, *budget))
            continue;   /* failed and queued */
        *budget -= rd->size - rd->done < *budget ? rd->size - rd->done : *budget;
        http_plan *e = &l->plan[(*np)++];
        memset(e, 0, sizeof *e);
        e->node = node;
        e->rd = rd;
        (*i)++;
        return 1;
    }
    return 0;
}

/* pump caller: an ended transfer of the plan. */
static void plan_end(hlod_loader *l, size_t np, const hlod_store_fetch_end *end)
{
    http_plan *e = NULL;
    for (size_t k = 0; k < np && !e; k++)
        if (l->plan[k].rd == end->rd)
            e = &l->plan[k];
    if (!e)
        return;
    hlod_store_read *rd = end->rd;
    e->rd = NULL;
    if (end->result != HLOD_OK) {
        close_read(l, rd);
        e->result = end->result;
        e->has_result = 1;
    } else if (rd->done == rd->size) {
        e->result = finish_payload(l, rd, &e->payload);
        e->has_result = 1;
    }
}

/* Synchronous mode over HTTP: the budget's bytes in list order, as the
 * file's pump reads them, fetched in parallel; returns the bytes read. */
static uint64_t http_pump(hlod_loader *l, uint64_t max_bytes)
{
    if (atomic_load(&l->version) != l->list_version)
        take_list(l);
    if (l->plan_cap < l->list_n) {
        http_plan *a = realloc(l->plan, l->list_n * sizeof *a);
        if (!a)
            return 0;
        l->plan = a;
        l->plan_cap = l->list_n;
    }
    uint64_t budget = max_bytes, bytes = 0;
    size_t i = next_undone(l, l->cursor), np = 0;
    int more = 1;
    for (;;) {
        while (more && hlod_store_fetch_active(l->fetch) < l->transfers)
            more = plan_next(l, &i, &budget, &np);
        if (!hlod_store_fetch_active(l->fetch))
            break;
        hlod_store_fetch_end ends[LOADER_HTTP_MAX_TRANSFERS];
        uint64_t got = 0;
        size_t n = hlod_store_fetch_poll(l->fetch, LOADER_HTTP_POLL_MS, -1, ends, l->transfers,
                                         &got);
        bytes += got;
        atomic_fetch_add_explicit(&l->bytes_read, got, memory_order_relaxed);
        for (size_t k = 0; k < n; k++)
            plan_end(l, np, &ends[k]);
    }
    for (size_t k = 0; k < np; k++) {
        http_plan *e = &l->plan[k];
        if (!e->has_result)
            continue;
        if (e->result != HLOD_OK) {
            fail_node(l, e->node, e->result);
        } else {
            atomic_fetch_add_explicit(&l->reads_done, 1, memory_order_relaxed);
            push_result(l, e->node, HLOD_OK, &e->payload);
        }
    }
    return bytes;
}

/* loader thread: frees the payload blocks the render thread handed over */
static void free_garbage(hlod_loader *l)
{
    pthread_mutex_lock(&l->mu);
    void **g = l->garbage;
    size_t g_cap = l->garbage_cap;
    l->freeing_n = l->garbage_n;
    l->garbage = l->freeing;
    l->garbage_cap = l->freeing_cap;
    l->garbage_n = 0;
    atomic_store_explicit(&l->garbage_ready, 0, memory_order_relaxed);
    l->freeing = g;
    l->freeing_cap = g_cap;
    pthread_mutex_unlock(&l->mu);
    for (size_t i = 0; i < l->freeing_n; i++)
        free(l->freeing[i]);
    l->freeing_n = 0;
}

/* loader thread over HTTP: assign transfers, run them; waits for a post
 * when the list is done. */
static void http_main(hlod_loader *l)
{
    while (!atomic_load(&l->stop)) {
        uint64_t t0 = thread_cpu_ns();
        if (atomic_load(&l->version) != l->list_version)
            take_list(l);
        unsigned hits = http_assign(l);
        int active = hlod_store_fetch_active(l->fetch) > 0;
        if (active) /* no wait after cache hits: the next requests may be hits too */
            http_collect(l, hits ? 0 : LOADER_HTTP_POLL_MS);
        atomic_fetch_add_explicit(&l->busy_ns, thread_cpu_ns() - t0, memory_order_relaxed);
        if (atomic_load_explicit(&l->garbage_ready, memory_order_relaxed))
            free_garbage(l);
        if (active || hits)
            continue;
        pthread_mutex_lock(&l->mu);
        while (!atomic_load(&l->stop) && atomic_load(&l->version) == l->list_version) {
            atomic_store(&l->idle_at, l->list_version + 1);
            pthread_cond_wait(&l->wake, &l->mu);
        }
        pthread_mutex_unlock(&l->mu);
    }
}

/* loader thread */
#define LOADER_NICE 10 /* the loader thread's nice value, relative to the process */

static void *loader_main(void *arg)
{
    hlod_loader *l = arg;
    /* Below the render thread: on a machine with few cores the loader's
     * reads, hashing and parsing would otherwise take a core from the
     * rasteriser mid-frame, and frame times would follow the loader. */
    if (l->d.idle) {
        /* SCHED_IDLE: CPU time only where no other thread of the machine
         * wants it (sched(7)); no privilege needed to lower a policy */
        struct sched_param sp = {0};
        if (pthread_setschedparam(pthread_self(), SCHED_IDLE, &sp) != 0) {
            hlod_logf(&l->d.logger, HLOD_LOG_WARN, "%s: the loader cannot run under SCHED_IDLE; "
                      "it runs at nice 19", hlod_store_path(l->store));
            (void)setpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid), 19);
        }
    } else {
        (void)setpriority(PRIO_PROCESS, (id_t)syscall(SYS_gettid), LOADER_NICE);
    }
    if (l->fetch) {
        http_main(l);
        return NULL;
    }
    while (!atomic_load(&l->stop)) {
        uint64_t bytes = 0;
        uint64_t t0 = thread_cpu_ns();
        int worked = work(l, UINT64_MAX, &bytes);
        atomic_fetch_add_explicit(&l->busy_ns, thread_cpu_ns() - t0, memory_order_relaxed);
        if (atomic_load_explicit(&l->garbage_ready, memory_order_relaxed))
            free_garbage(l);
        if (worked)
            continue;
        /* post bumps the version under mu, so a post between the work and
         * this check is seen here, and one after it signals the wait */
        pthread_mutex_lock(&l->mu);
        while (!atomic_load(&l->stop) && atomic_load(&l->version) == l->list_version) {
            atomic_store(&l->idle_at, l->list_version + 1);
            pthread_cond_wait(&l->wake, &l->mu);
        }
        pthread_mutex_unlock(&l->mu);
    }
    return NULL;
}

/* ---- public ---- */

/* called from the render thread */
hlod_result hlod_loader_create(const hlod_store *s, const hlod_loader_desc *d,
                               hlod_loader **out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    *out = NULL;
    if (!s || !d)
        return HLOD_ERR_INVALID_ARG;
    hlod_loader *l = calloc(1, sizeof *l);
    if (!l)
        return HLOD_ERR_NOMEM;
    l->store = s;
    l->node_count = hlod_store_node_count(s);
    l->d = *d;
    if (!l->d.chunk_bytes)
        l->d.chunk_bytes = LOADER_DEFAULT_CHUNK;
    l->nodes = calloc(l->node_count ? l->node_count : 1, sizeof *l->nodes);
    l->nslots = LOADER_SLOTS;
    l->wake_fd = -1;
    atomic_init(&l->version, 0);
    atomic_init(&l->stop, 0);
    atomic_init(&l->bytes_read, 0);
    atomic_init(&l->reads_done, 0);
    atomic_init(&l->reads_failed, 0);
    atomic_init(&l->switches, 0);
    atomic_init(&l->finish_ns, 0);
    atomic_init(&l->busy_ns, 0);
    atomic_init(&l->cache_hits, 0);
    if (!l->nodes) {
        free(l);
        return HLOD_ERR_NOMEM;
    }
    if (pthread_mutex_init(&l->mu, NULL) != 0) {
        free(l->nodes);
        free(l);
        return HLOD_ERR_NOMEM;
    }
    if (pthread_cond_init(&l->wake, NULL) != 0) {
        pthread_mutex_destroy(&l->mu);
        free(l->nodes);
        free(l);
        return HLOD_ERR_NOMEM;
    }
    if (hlod_store_is_remote(s)) {
        const char *env = getenv("HLOD_HTTP_TRANSFERS");
        long t = env ? strtol(env, NULL, 10) : LOADER_HTTP_TRANSFERS;
        l->transfers = t >= 1 && t <= (long)LOADER_HTTP_MAX_TRANSFERS ? (unsigned)t
                                                                      : LOADER_HTTP_TRANSFERS;
        l->nslots = LOADER_SLOTS + (int)l->transfers;
        hlod_result r = hlod_store_fetch_create(s, l->transfers, &l->fetch);
        if (r == HLOD_OK && d->threaded &&
            (l->wake_fd = eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC)) < 0)
            r = HLOD_ERR_NOMEM;
        if (r != HLOD_OK) {
            hlod_loader_destroy(l);
            return r;
        }
    }
    if (d->threaded) {
        if (pthread_create(&l->thread, NULL, loader_main, l) != 0) {
            hlod_logf(&l->d.logger, HLOD_LOG_ERROR, "loader: cannot start the loader thread");
            hlod_loader_destroy(l);
            return HLOD_ERR_NOMEM;
        }
        l->has_thread = 1;
    }
    *out = l;
    return HLOD_OK;
}

/* called from the render thread */
void hlod_loader_destroy(hlod_loader *l)
{
    if (!l)
        return;
    if (l->has_thread) {
        atomic_store(&l->stop, 1);
        /* a loader between its stop check and its wait holds mu: once we got
         * mu it is waiting (and the broadcast wakes it) or will see stop */
        pthread_mutex_lock(&l->mu);
        pthread_mutex_unlock(&l->mu);
        pthread_cond_broadcast(&l->wake);
        pthread_join(l->thread, NULL);
    }
    hlod_store_fetch_destroy(l->fetch); /* stops the transfers into the reads */
    l->fetch = NULL;
    if (l->wake_fd >= 0)
        close(l->wake_fd);
    for (size_t i = 0; i < LOADER_SLOTS_MAX; i++)
        hlod_store_read_cancel(&l->reads[i]);
    free(l->plan);
    for (size_t i = l->res_head; i < l->res_n; i++)
        hlod_store_payload_free(&l->res[i].payload);
    free(l->res);
    free(l->inbox);
    free(l->spare);
    free(l->post_buf);
    for (size_t i = 0; i < l->trash_n; i++)
        free(l->trash[i]);
    for (size_t i = 0; i < l->garbage_n; i++)
        free(l->garbage[i]);
    free(l->trash);
    free(l->garbage);
    free(l->freeing);
    free(l->list);
    free(l->sent);
    free(l->nodes);
    pthread_cond_destroy(&l->wake);
    pthread_mutex_destroy(&l->mu);
    free(l);
}

/* called from the render thread: copies reqs outside the lock, then swaps
 * buffers under a trylock */
int hlod_loader_post(hlod_loader *l, const hlod_load_request *reqs, size_t n)
{
    if (!l || (n && !reqs))
        return 0;
    if (n > l->post_cap) {
        size_t cap = grow_cap(l->post_cap, n);
        hlod_load_request *a = malloc(cap * sizeof *a);
        if (!a)
            return 0;
        free(l->post_buf);
        l->post_buf = a;
        l->post_cap = cap;
    }
    if (n)
        memcpy(l->post_buf, reqs, n * sizeof *reqs);

    if (pthread_mutex_trylock(&l->mu) != 0)
        return 0;
    hlod_load_request *give = l->post_buf;
    size_t give_cap = l->post_cap;
    if (l->inbox) {                 /* superseded before the loader took it */
        l->post_buf = l->inbox;
        l->post_cap = l->inbox_cap;
    } else {
        l->post_buf = l->spare;
        l->post_cap = l->spare_cap;
        l->spare = NULL;
        l->spare_cap = 0;
    }
    l->inbox = give;
    l->inbox_n = n;
    l->inbox_cap = give_cap;
    l->inbox_seen = l->collected;
    if (l->trash_n && !l->garbage_n) { /* the loader took the last: hand this over */
        void **g = l->garbage;
        size_t g_cap = l->garbage_cap;
        l->garbage = l->trash;
        l->garbage_cap = l->trash_cap;
        l->garbage_n = l->trash_n;
        l->trash = g;
        l->trash_cap = g_cap;
        l->trash_n = 0;
        atomic_store_explicit(&l->garbage_ready, 1, memory_order_relaxed);
    }
    atomic_fetch_add(&l->version, 1);
    pthread_mutex_unlock(&l->mu);
    pthread_cond_signal(&l->wake);
    if (l->wake_fd >= 0) {
        /* an HTTP loader may be in a poll: an eventfd write never blocks */
        uint64_t one = 1;
        ssize_t w = write(l->wake_fd, &one, sizeof one);
        (void)w;
    }
    return 1;
}

/* called from the render thread */
size_t hlod_loader_collect(hlod_loader *l, hlod_load_result *out, size_t max)
{
    if (!l || !out || !max)
        return 0;
    if (pthread_mutex_trylock(&l->mu) != 0)
        return 0;
    size_t k = l->res_n - l->res_head;
    if (k > max)
        k = max;
    if (k)
        memcpy(out, l->res + l->res_head, k * sizeof *out);
    l->res_head += k;
    l->collected += k;
    if (l->res_head == l->res_n)
        l->res_head = l->res_n = 0;
    pthread_mutex_unlock(&l->mu);
    return k;
}

/* called from the render thread */
void hlod_loader_discard(hlod_loader *l, hlod_store_payload *p)
{
    if (!p)
        return;
    if (!l || !l->has_thread) {
        hlod_store_payload_free(p); /* synchronous: this thread allocated it */
        return;
    }
    if (l->trash_cap < l->trash_n + 2) {
        size_t cap = grow_cap(l->trash_cap, l->trash_n + 2);
        void **a = realloc(l->trash, cap * sizeof *a);
        if (!a) {
            hlod_store_payload_free(p); /* no room to defer: free it here */
            return;
        }
        l->trash = a;
        l->trash_cap = cap;
    }
    if (p->memory)
        l->trash[l->trash_n++] = p->memory;
    if (p->tex_memory)
        l->trash[l->trash_n++] = p->tex_memory;
    memset(p, 0, sizeof *p);
}

/* called from the render thread (synchronous mode) */
uint64_t hlod_loader_pump(hlod_loader *l, uint64_t max_bytes)
{
    if (!l || l->has_thread)
        return 0;
    uint64_t bytes = 0;
    uint64_t t0 = thread_cpu_ns();
    if (l->fetch)
        bytes = http_pump(l, max_bytes);
    while (!l->fetch && bytes < max_bytes && work(l, max_bytes - bytes, &bytes))
        ;
    atomic_fetch_add_explicit(&l->busy_ns, thread_cpu_ns() - t0, memory_order_relaxed);
    return bytes;
}

/* any thread */
int hlod_loader_idle(const hlod_loader *l)
{
    if (!l || !l->has_thread)
        return 1;
    return atomic_load((atomic_uint_fast64_t *)&l->idle_at) ==
           atomic_load((atomic_uint_fast64_t *)&l->version) + 1;
}

/* any thread */
void hlod_loader_get_counters(const hlod_loader *l, hlod_loader_counters *out)
{
    if (!out)
        return;
    memset(out, 0, sizeof *out);
    if (!l)
        return;
    out->bytes_read = atomic_load_explicit(&l->bytes_read, memory_order_relaxed);
    out->reads_done = atomic_load_explicit(&l->reads_done, memory_order_relaxed);
    out->reads_failed = atomic_load_explicit(&l->reads_failed, memory_order_relaxed);
    out->switches = atomic_load_explicit(&l->switches, memory_order_relaxed);
    out->finish_ns = atomic_load_explicit(&l->finish_ns, memory_order_relaxed);
    out->busy_ns = atomic_load_explicit(&l->busy_ns, memory_order_relaxed);
    out->cache_hits = atomic_load_explicit(&l->cache_hits, memory_order_relaxed);
}
