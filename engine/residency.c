/*
 * residency.c - which nodes are in memory (Lakhia III-D; docs/runtime.md).
 *
 * The render thread owns residency; the loader thread only reads bytes
 * (loader.h).  Each frame:
 *
 *   collect   drain the loader's finished reads (trylock: never blocks) and
 *             upload them, at most upload_budget_bytes per frame (Nexus-style
 *             bounded work; the rest waits for the next frame);
 *   schedule  sort the nodes the traversal wants by priority and admit them
 *             in that order while c_memory * sum(cost) and the real bytes
 *             (resident + reserved for reads in flight) stay under
 *             maxMemory, evicting resident nodes of lower priority to make
 *             room: never a pinned node (the top of the tree, or its
 *             first levels: pinned_count), never one drawn this frame.
 *             The admitted list goes to the loader.
 *
 * Admission reserves a node's bytes before it is read, so the budget holds
 * at every instant, reads in flight included.  A scene that fits the budget
 * is therefore loaded once and never evicted: eviction happens only to make
 * room.
 *
 * Failures: a checksum, format or other permanent error marks the node bad
 * (logged once by the loader, never retried; its parent keeps being drawn).
 * A transient error (HLOD_ERR_IO) is retried after a backoff that doubles
 * with each failure (16, 32, 64 frames), and the node turns bad after 4.
 * Pinned nodes too: one that cannot be read at start does not stop the engine
 * (load_top); a missing one is asked for every frame once its backoff has
 * passed, admitted whatever the budget, and meanwhile, or for good when it
 * is bad, the traversal draws its children in its place (traverse.c).
 */
#include "residency.h"

#include "hlod_clock.h"
#include "sleeps.h"
#include "sort.h"

#include <assert.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define MAX_TRANSIENT_FAILURES 4
#define KEEP_UNWANTED_FRAMES 8  /* a queued node not wanted for this long is dropped */
static double mem_cost(const hlod_residency *rs, double cost)
{
    return rs->d->c_memory * cost;
}

/* ---- resident set ---- */

/* Takes ownership of p (freed here). */
/* GL's release of a node's buffers (excused: sleeps.h). */
static void gpu_release(hlod_residency *rs, hlod_gpu_node *g)
{
    long x = hlod_excuse_begin();
    hlod_gpu_release(rs->d->renderer, g);
    hlod_excuse_end(x);
}

static hlod_result make_resident(hlod_residency *rs, uint32_t node, hlod_store_payload *p)
{
    hlod_node_res *nr = &rs->res[node];
    assert(nr->state != HLOD_NODE_RESIDENT);
    hlod_result res = HLOD_OK;
    if (rs->d->renderer) {
        long x = hlod_excuse_begin(); /* GL may wait for the driver's threads */
        res = hlod_gpu_upload(rs->d->renderer, p, &nr->gpu);
        hlod_excuse_end(x);
    }
    hlod_loader_discard(rs->loader, p); /* freed on the loader thread */
    if (res != HLOD_OK)
        return res;
    if (rs->nodes[node].render_flags & HLOD_RENDER_SOLID)
        nr->gpu.flags |= HLOD_GPU_CULL;
    if (!hlod_u32_push(&rs->d->allocator, &rs->resident, node)) {
        if (rs->d->renderer)
            gpu_release(rs, &nr->gpu);
        return HLOD_ERR_NOMEM;
    }
    nr->state = HLOD_NODE_RESIDENT;
    nr->slot = (uint32_t)(rs->resident.n - 1);
    nr->failures = 0;
    if (node < rs->pinned_count)
        rs->pinned_missing--; /* pinned nodes are never evicted */
    rs->resident_bytes += hlod_store_node_memory(&rs->nodes[node]);
    rs->resident_cost += rs->nodes[node].cost;
    return HLOD_OK;
}

static void evict(hlod_residency *rs, uint32_t node)
{
    hlod_node_res *nr = &rs->res[node];
    assert(nr->state == HLOD_NODE_RESIDENT && node >= rs->pinned_count);
    if (rs->d->renderer)
        gpu_release(rs, &nr->gpu);
    uint32_t last = rs->resident.v[rs->resident.n - 1];
    rs->resident.v[nr->slot] = last;
    rs->res[last].slot = nr->slot;
    rs->resident.n--;
    nr->state = HLOD_NODE_ABSENT;
    rs->resident_bytes -= hlod_store_node_memory(&rs->nodes[node]);
    rs->resident_cost -= rs->nodes[node].cost;
    if (rs->resident_cost < 0)
        rs->resident_cost = 0;
    rs->st->evictions++;
}

static void reserve(hlod_residency *rs, uint32_t node, int sign)
{
    if (sign > 0) {
        rs->reserved_bytes += hlod_store_node_memory(&rs->nodes[node]);
        rs->reserved_cost += rs->nodes[node].cost;
    } else {
        rs->reserved_bytes -= hlod_store_node_memory(&rs->nodes[node]);
        rs->reserved_cost -= rs->nodes[node].cost;
        if (rs->reserved_cost < 0 || rs->reserved_bytes == 0)
            rs->reserved_cost = 0;
    }
}

/* Leaves QUEUED without becoming resident. */
static void unqueue(hlod_residency *rs, uint32_t node)
{
    hlod_node_res *nr = &rs->res[node];
    assert(nr->state == HLOD_NODE_QUEUED);
    reserve(rs, node, -1);
    nr->state = HLOD_NODE_ABSENT;
}

hlod_result hlod_residency_load_now(hlod_residency *rs, uint32_t node)
{
    assert(rs && node < rs->node_count);
    hlod_node_res *nr = &rs->res[node];
    if (nr->state == HLOD_NODE_RESIDENT)
        return HLOD_OK;
    if (nr->state == HLOD_NODE_BAD)
        return HLOD_ERR_CHECKSUM;
    hlod_store_payload p;
    hlod_result res = hlod_store_read_node_as(rs->store, node, rs->d->read_chunk_bytes,
                                              rs->texture_out, &p);
    if (res != HLOD_OK)
        return res;
    if (nr->state == HLOD_NODE_QUEUED)
        unqueue(rs, node);
    res = make_resident(rs, node, &p);
    if (res == HLOD_OK) {
        rs->st->loads++;
        rs->st->bytes_read += rs->nodes[node].payload_size;
    }
    return res;
}

/* A pinned node that cannot be read at start does not stop
 * the engine: a permanent failure (checksum, format) marks it bad, a
 * transient one (I/O) leaves it absent, retried through the loader after
 * the usual backoff (hlod_residency_schedule asks for it).  Either way the
 * traversal draws its readable children in its place.  Only running out
 * of memory fails. */
static void top_failed(hlod_residency *rs, uint32_t node, hlod_result why)
{
    hlod_node_res *nr = &rs->res[node];
    rs->start_failures++;
    if (why == HLOD_ERR_IO) {
        nr->failures = 1;
        nr->state = HLOD_NODE_ABSENT;
        nr->retry_frame = 8u << nr->failures;
        hlod_logf(&rs->d->logger, HLOD_LOG_WARN,
                  "%s: pinned node %u cannot be loaded yet (%s); retried later, "
                  "its readable children are drawn in its place",
                  hlod_store_path(rs->store), node, hlod_result_str(why));
        return;
    }
    nr->state = HLOD_NODE_BAD;
    rs->bad_total++;
    rs->pinned_missing--;
    hlod_logf(&rs->d->logger, HLOD_LOG_ERROR,
              "%s: pinned node %u is unreadable (%s); its readable children are "
              "drawn in its place", hlod_store_path(rs->store), node, hlod_result_str(why));
}

/* The pinned nodes [first, first + n) of a store read over HTTP, read with
 * parallel requests (hlod_store_read_nodes), made resident. */
#define TOP_BATCH 32u
static hlod_result load_top_batch(hlod_residency *rs, uint32_t first, uint32_t n)
{
    hlod_store_payload p[TOP_BATCH];
    hlod_result res[TOP_BATCH];
    hlod_result r = hlod_store_read_nodes_as(rs->store, first, n, rs->d->read_chunk_bytes,
                                             rs->texture_out, p, res);
    for (uint32_t k = 0; k < n && r == HLOD_OK; k++) {
        uint32_t node = first + k;
        if (res[k] == HLOD_OK && (res[k] = make_resident(rs, node, &p[k])) == HLOD_OK) {
            rs->st->loads++;
            rs->st->bytes_read += rs->nodes[node].payload_size;
        }
        if (res[k] == HLOD_ERR_NOMEM)
            r = HLOD_ERR_NOMEM;
        else if (res[k] != HLOD_OK)
            top_failed(rs, node, res[k]);
    }
    for (uint32_t k = 0; k < n; k++)
        hlod_store_payload_free(&p[k]); /* those not made resident */
    return r;
}

static hlod_result load_top(hlod_residency *rs)
{
    for (uint32_t i = 0; hlod_store_is_remote(rs->store) && i < rs->pinned_count; i += TOP_BATCH) {
        uint32_t n = rs->pinned_count - i < TOP_BATCH ? rs->pinned_count - i : TOP_BATCH;
        hlod_result r = load_top_batch(rs, i, n);
        if (r != HLOD_OK)
            return r;
    }
    for (uint32_t i = 0; !hlod_store_is_remote(rs->store) && i < rs->pinned_count; i++) {
        hlod_result r = hlod_residency_load_now(rs, i);
        if (r == HLOD_ERR_NOMEM)
            return r;
        if (r != HLOD_OK)
            top_failed(rs, i, r);
    }
    if (rs->resident_bytes > rs->d->memory_budget_bytes)
        hlod_logf(&rs->d->logger, HLOD_LOG_WARN,
                  "%s: the roots alone take %llu bytes, over the %llu-byte budget",
                  hlod_store_path(rs->store), (unsigned long long)rs->resident_bytes,
                  (unsigned long long)rs->d->memory_budget_bytes);
    return HLOD_OK;
}

/* ---- collect ---- */

static void load_failed(hlod_residency *rs, uint32_t node, hlod_result why)
{
    hlod_node_res *nr = &rs->res[node];
    rs->st->load_failures++;
    if (why == HLOD_ERR_IO && ++nr->failures < MAX_TRANSIENT_FAILURES) {
        nr->state = HLOD_NODE_ABSENT;
        nr->retry_frame = rs->frame + (8u << nr->failures);
        return;
    }
    nr->state = HLOD_NODE_BAD;
    rs->bad_total++;
    if (node < rs->pinned_count) {
        rs->pinned_missing--;
        hlod_logf(&rs->d->logger, HLOD_LOG_WARN, "%s: pinned node %u is "
                  "unreadable (%s); its readable children are drawn in its place",
                  hlod_store_path(rs->store), node, hlod_result_str(why));
        return;
    }
    hlod_logf(&rs->d->logger, HLOD_LOG_WARN, "%s: node %u is unreadable (%s); its parent is "
              "drawn instead", hlod_store_path(rs->store), node, hlod_result_str(why));
}

/* The measured cost of an upload per byte, in two size classes (a small
 * upload's fixed part made a big texture look cheap: it then went inline
 * and missed the deadline) and biased up: it rises half way to a slower
 * upload and falls a tenth of the way to a faster one, so that it predicts
 * near the slow end of a software GL's spread (the same 871x871 texture
 * took 3-20 ms, as its memory was fresh or not). */
#define UPLOAD_BIG_BYTES (512u << 10)

static double predict_upload(const hlod_residency *rs, size_t bytes)
{
    double per = rs->upload_ms_per_byte[bytes >= UPLOAD_BIG_BYTES];
    if (per == 0) /* the other class until this one is measured */
        per = rs->upload_ms_per_byte[bytes < UPLOAD_BIG_BYTES];
    return per * (double)bytes;
}

static void measured_upload(hlod_residency *rs, size_t bytes, double ms)
{
    double *c = &rs->upload_ms_per_byte[bytes >= UPLOAD_BIG_BYTES];
    double per = ms / (double)bytes;
    *c = *c == 0 ? per : *c + (per > *c ? 0.5 : 0.1) * (per - *c);
}

/* Frames an upload predicted to overrun the time budget may wait before
 * it is made anyway (it may be the one node the view needs). */
#define UPLOAD_STARVE 8
#define UPLOAD_STARVE_MAX 64
#define UPLOAD_FORCED_GAP 256 /* frames between two uploads past the room */

/* An upload too big for up_ms waits, but each one only so long: the first
 * of the pending list (in its order) that has waited UPLOAD_STARVE frames
 * and fits the room the last front left under the target, or has waited
 * UPLOAD_STARVE_MAX frames, is moved to its head; returns 1 when one was.
 * (A count of frames that uploaded nothing, as before, let a trickle of
 * small prefetches starve a big texture a refinement waited for: 5-9 nodes
 * of a still view stayed missing for 500 frames.)  Those past the room go
 * at most once every UPLOAD_FORCED_GAP frames: each misses the deadline (on
 * fly, one every 8 frames took deadline_met from 0.997 to 0.983; on orbit,
 * one every 64 from 0.997 to 0.979-0.990, 14-28 ms uploads on 20 ms
 * fronts). */
static int waited_first(hlod_residency *rs, double up_ms, double room_ms)
{
    for (size_t k = 0; k < rs->pending_n; k++) {
        const hlod_load_result *lr = &rs->pending[k];
        uint32_t age = rs->frame - rs->res[lr->node].arrived;
        double predicted = predict_upload(rs, lr->payload.bytes);
        if (rs->res[lr->node].state != HLOD_NODE_QUEUED || lr->result != HLOD_OK ||
            predicted <= 1.25 * up_ms)
            continue;
        int fits = age >= UPLOAD_STARVE && predicted <= room_ms;
        int forced = age >= UPLOAD_STARVE_MAX && rs->frame - rs->forced_frame >= UPLOAD_FORCED_GAP;
        if (fits || forced) {
            hlod_load_result t = *lr;
            memmove(rs->pending + 1, rs->pending, k * sizeof t);
            rs->pending[0] = t;
            if (!fits)
                rs->forced_frame = rs->frame;
            return 1;
        }
    }
    return 0;
}

void hlod_residency_collect(hlod_residency *rs, double up_ms, double room_ms)
{
    assert(rs && rs->d);
    /* Drain the loader into our pending list (bounded by max_inflight per
     * call, so a frame never takes an unbounded batch). */
    size_t room = rs->d->max_inflight;
    if (rs->pending_cap < rs->pending_n + room) {
        size_t cap = rs->pending_n + room;
        hlod_load_result *p = hlod_mem_realloc(&rs->d->allocator, rs->pending, cap * sizeof *p);
        if (!p)
            return;
        rs->pending = p;
        rs->pending_cap = cap;
    }
    size_t got = hlod_loader_collect(rs->loader, rs->pending + rs->pending_n, room);
    for (size_t k = rs->pending_n; k < rs->pending_n + got; k++)
        rs->res[rs->pending[k].node].arrived = rs->frame;
    rs->pending_n += got;

    /* Uploads stop at the byte budget or, measured, at the time budget: a
     * software GL copies and mipmaps every texture on this thread. */
    if (rs->d->deterministic || rs->d->time_model)
        up_ms = INFINITY; /* reproducible, or a synthetic machine: bytes alone decide */
    /* The nodes a refinement waits for go first (a stable partition: each
     * part keeps its arrival order, which is the loader's priority order):
     * behind a still camera's prefetch they would wait many frames, and
     * then refine late, after the view has settled. */
    const uint32_t recent = rs->frame > 1 ? rs->frame - 1 : 0;
    size_t first = 0;
    for (size_t k = 0; k < rs->pending_n; k++)
        if (rs->res[rs->pending[k].node].needed >= recent) {
            hlod_load_result t = rs->pending[k];
            memmove(rs->pending + first + 1, rs->pending + first, (k - first) * sizeof t);
            rs->pending[first++] = t;
        }
    const int waited = waited_first(rs, up_ms, room_ms); /* pending[0] goes, whatever its size */
    double t_up = hlod_now_ms();
    uint64_t uploaded = 0;
    size_t keep = 0;
    for (size_t k = 0; k < rs->pending_n; k++) {
        hlod_load_result *lr = &rs->pending[k];
        hlod_node_res *nr = &rs->res[lr->node];
        if (nr->state != HLOD_NODE_QUEUED) {
            /* dropped while in flight: nothing was reserved any more */
            hlod_loader_discard(rs->loader, &lr->payload);
            continue;
        }
        if (lr->result != HLOD_OK) {
            unqueue(rs, lr->node);
            load_failed(rs, lr->node, lr->result);
            continue;
        }
        /* An upload that the measured cost per byte says would run a
         * quarter past the time budget waits too (a big texture takes tens
         * of ms on a software GL, and the frame's deadline counts them),
         * unless it is first: the one that waited too long (above). */
        double elapsed = hlod_now_ms() - t_up;
        double predicted = elapsed + predict_upload(rs, lr->payload.bytes);
        if ((uploaded && (uploaded + lr->payload.bytes > rs->d->upload_budget_bytes ||
                          elapsed >= up_ms || predicted > 1.25 * up_ms)) ||
            (!uploaded && !(waited && k == 0) && predicted > 1.25 * up_ms)) {
            rs->pending[keep++] = *lr; /* next frame */
            continue;
        }
        uploaded += lr->payload.bytes;
        uint32_t node = lr->node;
        unqueue(rs, node);
        double t_one = hlod_now_ms();
        size_t bytes = lr->payload.bytes;
        hlod_result res = make_resident(rs, node, &lr->payload);
        if (res == HLOD_OK && bytes > 0 && isfinite(up_ms))
            measured_upload(rs, bytes, hlod_now_ms() - t_one);
        if (res == HLOD_OK)
            rs->st->loads++;
        else
            load_failed(rs, node, res == HLOD_ERR_NOMEM ? HLOD_ERR_IO : res);
    }
    rs->pending_n = keep;
}

/* ---- schedule ---- */

typedef struct victim {
    double key;
    uint32_t node;
} victim;

static int cmp_victim(const void *a, const void *b)
{
    const victim *x = a, *y = b;
    if (x->key != y->key)
        return x->key < y->key ? -1 : 1;
    return x->node < y->node ? -1 : x->node > y->node;
}

static int cmp_request(const void *a, const void *b)
{
    const hlod_load_request *x = a, *y = b;
    if (x->priority != y->priority)
        return x->priority > y->priority ? -1 : 1;
    return x->node < y->node ? -1 : x->node > y->node;
}

/* Resident nodes that may be evicted, least valuable first (the order's
 * keys); pinned nodes never. */
static victim *victims(hlod_residency *rs, const hlod_evict_order *order, size_t *count)
{
    if (rs->victims_cap < rs->resident.n + 1) {
        size_t cap = rs->resident.n + 1 + rs->resident.n / 2;
        victim *g = hlod_mem_realloc(&rs->d->allocator, rs->victims, cap * sizeof *g);
        if (!g)
            return NULL;
        rs->victims = g;
        rs->victims_cap = cap;
    }
    victim *v = rs->victims;
    size_t n = 0;
    for (size_t k = 0; k < rs->resident.n; k++) {
        uint32_t i = rs->resident.v[k];
        if (i < rs->pinned_count || !order->key(order->user, i, &v[n].key))
            continue;
        v[n].node = i;
        n++;
    }
    hlod_sort(v, n, sizeof *v, cmp_victim);
    *count = n;
    return v;
}

static int in_pending(const hlod_residency *rs, uint32_t node)
{
    for (size_t k = 0; k < rs->pending_n; k++)
        if (rs->pending[k].node == node)
            return 1;
    return 0;
}

/* Whether node n fits the memory budget beside the reservations, were
 * the resident set to hold `bytes` and `cost`. */
static int fits(const hlod_residency *rs, uint64_t bytes, double cost, const hlod_store_node *n)
{
    const uint64_t budget = rs->d->memory_budget_bytes;
    /* the cost term is a sum of doubles: with the budget the store's exact
     * size (c_memory 0), its rounding refused the last node of a colour-
     * cube tree (2,480 of 2,481 resident for good) */
    return bytes + rs->reserved_bytes + hlod_store_node_memory(n) <= budget &&
           mem_cost(rs, cost + rs->reserved_cost) + mem_cost(rs, n->cost) <=
               (double)budget * (1 + 1e-9);
}

/* The victims, from vic[vi] on, to evict so that node n of priority pr
 * fits: evicting vic[vi, returned index) (those still resident) makes the
 * room, each of key under pr.  SIZE_MAX when those cannot: then nothing
 * is evicted.  (Evicting first and finding the node still did not fit
 * freed room that the next frame read again: on the still view at 66 ms
 * with memory full, two prefetched nodes evicted each other, one load a
 * frame from frame 80 to the end, for a need that never fit.) */
static size_t room_by_evicting(const hlod_residency *rs, const victim *vic, size_t nvic,
                               size_t vi, double pr, const hlod_store_node *n)
{
    uint64_t bytes = rs->resident_bytes;
    double cost = rs->resident_cost;
    for (;; vi++) {
        if (fits(rs, bytes, cost, n))
            return vi;
        while (vi < nvic && rs->res[vic[vi].node].state != HLOD_NODE_RESIDENT)
            vi++;
        if (vi >= nvic || !(vic[vi].key < pr))
            return SIZE_MAX;
        const hlod_store_node *v = &rs->nodes[vic[vi].node];
        bytes -= hlod_store_node_memory(v);
        cost -= v->cost;
    }
}

void hlod_residency_schedule(hlod_residency *rs, const hlod_evict_order *order)
{
    assert(rs && rs->d && order && order->key);
    hlod_req_vec *want = &rs->want;
    hlod_sort(want->v, want->n, sizeof *want->v, cmp_request);

    /* The previous list: queued nodes the traversal stopped asking for stay
     * queued for a few frames (a partial read survives a brief dip), then
     * are dropped and their reservation returned. */
    hlod_req_vec old = rs->post;
    rs->post = rs->post_spare;
    rs->post.n = 0;
    hlod_req_vec *post = &rs->post;

    /* Admitted in two passes, each in priority order: first the nodes a
     * refinement waits for, then the prefetch.  In one pass a prefetch of
     * higher priority (a hidden or coming child near the eye) took the
     * max_inflight slots from the refinements: on the still view at 66 ms,
     * 300-410 wanted nodes stayed missing from frame 40 to 150 while 1,308
     * prefetched nodes took half the upload time.  Each admission still
     * evicts only nodes of lower priority than its own. */
    victim *vic = NULL;
    size_t nvic = 0, vi = 0;
    int vic_built = 0;
    for (size_t k = 0; k < 2 * want->n && post->n < rs->d->max_inflight; k++) {
        uint32_t node = want->v[k % want->n].node;
        hlod_node_res *nr = &rs->res[node];
        double pr = want->v[k % want->n].priority;
        if ((nr->needed == rs->frame) != (k < want->n))
            continue;
        if (nr->state == HLOD_NODE_QUEUED) {
            if (!in_pending(rs, node) && hlod_req_push(&rs->d->allocator, post, node, pr))
                nr->posted = rs->frame;
            continue;
        }
        if (nr->state != HLOD_NODE_ABSENT)
            continue;
        const hlod_store_node *n = &rs->nodes[node];
        const int top = node < rs->pinned_count; /* admitted whatever the budget, as at start */
        if (!top && !fits(rs, rs->resident_bytes, rs->resident_cost, n)) {
            if (!vic_built) {
                vic = victims(rs, order, &nvic);
                vic_built = 1;
            }
            size_t upto = room_by_evicting(rs, vic, nvic, vi, pr, n);
            if (upto == SIZE_MAX)
                continue; /* does not fit; a smaller one further down may */
            for (; vi < upto; vi++)
                if (rs->res[vic[vi].node].state == HLOD_NODE_RESIDENT)
                    evict(rs, vic[vi].node);
        }
        if (!hlod_req_push(&rs->d->allocator, post, node, pr))
            break;
        nr->state = HLOD_NODE_QUEUED;
        nr->posted = rs->frame;
        reserve(rs, node, +1);
    }

    int resort = 0;
    for (size_t k = 0; k < old.n; k++) {
        uint32_t node = old.v[k].node;
        hlod_node_res *nr = &rs->res[node];
        if (nr->state != HLOD_NODE_QUEUED || nr->posted == rs->frame || in_pending(rs, node))
            continue;
        if (nr->wanted + KEEP_UNWANTED_FRAMES >= rs->frame && post->n < rs->d->max_inflight &&
            hlod_req_push(&rs->d->allocator, post, node, 0.5f * old.v[k].priority)) {
            nr->posted = rs->frame;
            resort = 1;
            continue;
        }
        unqueue(rs, node);
    }
    rs->post_spare = old; /* its storage, for the next frame's list */
    if (resort)
        hlod_sort(post->v, post->n, sizeof *post->v, cmp_request);
    /* The loader reads in list order: the nodes a refinement waits for
     * first, each part in priority order (as admitted above; the queued
     * nodes of the old list were appended after them). */
    size_t first = 0;
    for (size_t k = 0; k < post->n; k++)
        if (rs->res[post->v[k].node].needed == rs->frame) {
            hlod_load_request t = post->v[k];
            memmove(post->v + first + 1, post->v + first, (k - first) * sizeof t);
            post->v[first++] = t;
        }

    hlod_loader_post(rs->loader, post->v, post->n); /* busy: the same list goes next frame */
    rs->st->queued = (uint32_t)post->n;
    if (rs->d->deterministic) { /* the synchronous read is this thread's by design */
        long x = hlod_excuse_begin();
        hlod_loader_pump(rs->loader, rs->d->deterministic_load_bytes);
        hlod_excuse_end(x);
    }
}

/* ---- life and frame ---- */

/* The nodes kept resident: the top of the tree (groups and the blocks'
 * hlod_0 nodes), or, when those take more than PINNED_SHARE of the budget
 * (a large city: 2,816 blocks' hlod_0 nodes take 1.4 GB), its first levels
 * only: the depths [0, d] for the deepest d whose nodes fit that share,
 * the roots at least.  Nodes are stored breadth-first, so that is a prefix
 * [0, n).  Below it every node is loaded, drawn and evicted by priority:
 * an hlod_0 node not read yet leaves its group drawn. */
#define PINNED_SHARE 0.5
static uint32_t pinned_count(const hlod_store *s, uint64_t budget)
{
    const hlod_store_node *nodes = hlod_store_nodes(s);
    const uint32_t top = hlod_store_top_count(s), roots = nodes[0].first_child;
    uint64_t bytes = 0;
    uint32_t pinned = roots;
    for (uint32_t i = 0; i < top; i++) {
        bytes += hlod_store_node_memory(&nodes[i]);
        if (bytes > PINNED_SHARE * (double)budget)
            break;
        if (i + 1 == top || nodes[i + 1].depth != nodes[i].depth)
            pinned = i + 1; /* depth nodes[i].depth fits whole */
    }
    return pinned;
}

hlod_result hlod_residency_init(hlod_residency *rs, const hlod_store *store,
                                const hlod_engine_desc *d, hlod_frame_stats *st)
{
    assert(rs && store && d && st);
    *rs = (hlod_residency){0};
    rs->store = store;
    rs->nodes = hlod_store_nodes(store);
    rs->node_count = hlod_store_node_count(store);
    rs->top_count = hlod_store_top_count(store);
    rs->pinned_count = pinned_count(store, d->memory_budget_bytes);
    rs->d = d;
    rs->st = st;
    rs->res = hlod_mem_alloc(&d->allocator, (size_t)rs->node_count * sizeof *rs->res);
    if (!rs->res)
        return HLOD_ERR_NOMEM;
    memset(rs->res, 0, (size_t)rs->node_count * sizeof *rs->res);
    rs->pinned_missing = rs->pinned_count;
    rs->texture_out = !d->renderer ? HLOD_TEXOUT_PIXELS
                      : hlod_renderer_texture_blocks(d->renderer, d->texture_upload)
                          ? HLOD_TEXOUT_BLOCKS
                          : HLOD_TEXOUT_CHAIN;
    hlod_result r = load_top(rs);
    if (r == HLOD_OK) {
        hlod_loader_desc ld = {0};
        ld.threaded = !d->deterministic;
        ld.chunk_bytes = d->read_chunk_bytes;
        ld.hook = d->read_hook;
        ld.hook_user = d->read_hook_user;
        ld.logger = d->logger;
        ld.idle = d->loader_idle > 0;
        ld.prepare_textures = d->renderer != NULL;
        ld.texture_out = rs->texture_out;
        r = hlod_loader_create(store, &ld, &rs->loader);
    }
    if (r != HLOD_OK)
        hlod_residency_destroy(rs);
    return r;
}

void hlod_residency_destroy(hlod_residency *rs)
{
    if (!rs->d)
        return; /* never initialised */
    const hlod_allocator *a = &rs->d->allocator;
    hlod_loader_destroy(rs->loader); /* joins the thread first */
    rs->loader = NULL;
    for (size_t k = 0; k < rs->pending_n; k++)
        hlod_store_payload_free(&rs->pending[k].payload);
    rs->pending_n = 0;
    if (rs->d->renderer && rs->res)
        for (size_t k = 0; k < rs->resident.n; k++)
            hlod_gpu_release(rs->d->renderer, &rs->res[rs->resident.v[k]].gpu);
    rs->resident.n = 0;
    hlod_mem_free(a, rs->res);
    hlod_mem_free(a, rs->resident.v);
    hlod_mem_free(a, rs->pending);
    hlod_mem_free(a, rs->want.v);
    hlod_mem_free(a, rs->post.v);
    hlod_mem_free(a, rs->post_spare.v);
    hlod_mem_free(a, rs->victims);
    rs->post_spare.v = NULL;
    rs->victims = NULL;
    rs->victims_cap = 0;
    rs->res = NULL;
    rs->resident.v = NULL;
    rs->pending = NULL;
    rs->want.v = rs->post.v = NULL;
}

/* Above any priority the traversal gives (those are doubles below 1e300,
 * stored as floats: at most FLT_MAX). */
#define TOP_PRIORITY INFINITY

void hlod_residency_begin_frame(hlod_residency *rs, uint32_t frame)
{
    assert(rs && rs->d && frame > rs->frame);
    rs->frame = frame;
    rs->want.n = 0;
    /* Top nodes that could not be read yet (a transient failure) are asked
     * for first, visible or not, once their backoff has passed; while
     * missing, the traversal draws their children in their place. */
    for (uint32_t i = 0; rs->pinned_missing && i < rs->pinned_count; i++)
        if (rs->res[i].state == HLOD_NODE_ABSENT || rs->res[i].state == HLOD_NODE_QUEUED)
            (void)hlod_residency_want(rs, i, TOP_PRIORITY);
}

void hlod_residency_end_frame(hlod_residency *rs)
{
    assert(rs && rs->d);
    hlod_loader_counters lc;
    hlod_loader_get_counters(rs->loader, &lc);
    rs->st->bytes_read += lc.bytes_read - rs->bytes_read_prev;
    rs->bytes_read_prev = lc.bytes_read;
    rs->st->cache_hits += (uint32_t)(lc.cache_hits - rs->cache_hits_prev);
    rs->cache_hits_prev = lc.cache_hits;
    rs->st->loader_finish_ms = (double)(lc.finish_ns - rs->finish_ns_prev) * 1e-6;
    rs->st->loader_busy_ms = (double)(lc.busy_ns - rs->busy_ns_prev) * 1e-6;
    rs->finish_ns_prev = lc.finish_ns;
    rs->busy_ns_prev = lc.busy_ns;
    rs->st->resident_nodes = (uint32_t)rs->resident.n;
    rs->st->resident_bytes = rs->resident_bytes;
    rs->st->resident_cost = rs->d->c_memory * rs->resident_cost;
    rs->st->memory_budget_bytes = rs->d->memory_budget_bytes;
    rs->st->bad_nodes = rs->bad_total;
    rs->st->load_failures += rs->start_failures; /* the first frame reports those at start */
    rs->start_failures = 0;
}
