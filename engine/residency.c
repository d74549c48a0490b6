/*
 * residency.c - which nodes are in memory (Lakhia III-D; README, "The runtime").
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
 *             room: never an hlod_0 node, never one drawn this frame.  The
 *             admitted list goes to the loader.
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
 */
#include "engine_internal.h"

#include <assert.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define MAX_TRANSIENT_FAILURES 4
#define KEEP_UNWANTED_FRAMES 8  /* a queued node not wanted for this long is dropped */
#define WAIT_MS 5.0             /* a post/collect call this slow counts as a wait */

static double mem_cost(const hlod_engine *e, double cost)
{
    return e->d.c_memory * cost;
}

/* ---- resident set ---- */

/* Takes ownership of p (freed here). */
static hlod_result make_resident(hlod_engine *e, uint32_t node, hlod_store_payload *p)
{
    hlod_node_res *r = &e->res[node];
    assert(r->state != HLOD_NODE_RESIDENT);
    hlod_result res = HLOD_OK;
    if (e->d.renderer)
        res = hlod_gpu_upload(e->d.renderer, p, &r->gpu);
    hlod_store_payload_free(p);
    if (res != HLOD_OK)
        return res;
    if (e->nodes[node].render_flags & HLOD_RENDER_SOLID)
        r->gpu.flags |= HLOD_GPU_CULL;
    if (!hlod_u32_push(e, &e->resident, node)) {
        if (e->d.renderer)
            hlod_gpu_release(e->d.renderer, &r->gpu);
        return HLOD_ERR_NOMEM;
    }
    r->state = HLOD_NODE_RESIDENT;
    r->slot = (uint32_t)(e->resident.n - 1);
    r->failures = 0;
    e->resident_bytes += e->nodes[node].payload_size;
    e->resident_cost += e->nodes[node].cost;
    return HLOD_OK;
}

static void evict(hlod_engine *e, uint32_t node)
{
    hlod_node_res *r = &e->res[node];
    assert(r->state == HLOD_NODE_RESIDENT && node >= e->root_count);
    if (e->d.renderer)
        hlod_gpu_release(e->d.renderer, &r->gpu);
    uint32_t last = e->resident.v[e->resident.n - 1];
    e->resident.v[r->slot] = last;
    e->res[last].slot = r->slot;
    e->resident.n--;
    r->state = HLOD_NODE_ABSENT;
    e->resident_bytes -= e->nodes[node].payload_size;
    e->resident_cost -= e->nodes[node].cost;
    if (e->resident_cost < 0)
        e->resident_cost = 0;
    e->st.evictions++;
}

static void reserve(hlod_engine *e, uint32_t node, int sign)
{
    if (sign > 0) {
        e->reserved_bytes += e->nodes[node].payload_size;
        e->reserved_cost += e->nodes[node].cost;
    } else {
        e->reserved_bytes -= e->nodes[node].payload_size;
        e->reserved_cost -= e->nodes[node].cost;
        if (e->reserved_cost < 0 || e->reserved_bytes == 0)
            e->reserved_cost = 0;
    }
}

/* Leaves QUEUED without becoming resident. */
static void unqueue(hlod_engine *e, uint32_t node)
{
    hlod_node_res *r = &e->res[node];
    assert(r->state == HLOD_NODE_QUEUED);
    reserve(e, node, -1);
    r->state = HLOD_NODE_ABSENT;
}

hlod_result hlod_residency_load_now(hlod_engine *e, uint32_t node)
{
    assert(e && node < e->node_count);
    hlod_node_res *r = &e->res[node];
    if (r->state == HLOD_NODE_RESIDENT)
        return HLOD_OK;
    if (r->state == HLOD_NODE_BAD)
        return HLOD_ERR_CHECKSUM;
    hlod_store_payload p;
    hlod_result res = hlod_store_read_node(e->store, node, e->d.read_chunk_bytes, &p);
    if (res != HLOD_OK)
        return res;
    if (r->state == HLOD_NODE_QUEUED)
        unqueue(e, node);
    res = make_resident(e, node, &p);
    if (res == HLOD_OK) {
        e->st.loads++;
        e->st.bytes_read += e->nodes[node].payload_size;
    }
    return res;
}

hlod_result hlod_residency_load_roots(hlod_engine *e)
{
    for (uint32_t i = 0; i < e->root_count; i++) {
        hlod_result r = hlod_residency_load_now(e, i);
        if (r != HLOD_OK) {
            hlod_logf(&e->d.logger, HLOD_LOG_ERROR, "%s: hlod_0 node %u cannot be loaded: %s",
                      hlod_store_path(e->store), i, hlod_result_str(r));
            return r;
        }
    }
    if (e->resident_bytes > e->d.memory_budget_bytes)
        hlod_logf(&e->d.logger, HLOD_LOG_WARN,
                  "%s: the hlod_0 nodes alone take %llu bytes, over the %llu-byte budget",
                  hlod_store_path(e->store), (unsigned long long)e->resident_bytes,
                  (unsigned long long)e->d.memory_budget_bytes);
    return HLOD_OK;
}

/* ---- collect ---- */

static void load_failed(hlod_engine *e, uint32_t node, hlod_result why)
{
    hlod_node_res *r = &e->res[node];
    e->st.load_failures++;
    if (why == HLOD_ERR_IO && ++r->failures < MAX_TRANSIENT_FAILURES) {
        r->state = HLOD_NODE_ABSENT;
        r->retry_frame = e->frame + (8u << r->failures);
        return;
    }
    r->state = HLOD_NODE_BAD;
    e->bad_total++;
    hlod_logf(&e->d.logger, HLOD_LOG_WARN, "%s: node %u is unreadable (%s); its parent is "
              "drawn instead", hlod_store_path(e->store), node, hlod_result_str(why));
}

void hlod_residency_collect(hlod_engine *e)
{
    /* Drain the loader into our pending list (bounded by max_inflight per
     * call, so a frame never takes an unbounded batch). */
    size_t room = e->d.max_inflight;
    if (e->pending_cap < e->pending_n + room) {
        size_t cap = e->pending_n + room;
        hlod_load_result *p = hlod_engine_realloc(e, e->pending, cap * sizeof *p);
        if (!p)
            return;
        e->pending = p;
        e->pending_cap = cap;
    }
    double t0 = hlod_now_ms();
    size_t got = hlod_loader_collect(e->loader, e->pending + e->pending_n, room);
    if (hlod_now_ms() - t0 > WAIT_MS)
        e->st.render_waits++;
    e->pending_n += got;

    /* Uploads stop at the byte budget or, measured, at the time budget: a
     * software GL copies and mipmaps every texture on this thread. */
    double up_ms = e->d.upload_budget_ms > 0 ? e->d.upload_budget_ms : 0.1 * e->d.target_ms;
    if (e->d.deterministic || e->d.time_model)
        up_ms = INFINITY; /* reproducible, or a synthetic machine: bytes alone decide */
    double t_up = hlod_now_ms();
    uint64_t uploaded = 0;
    size_t keep = 0;
    for (size_t k = 0; k < e->pending_n; k++) {
        hlod_load_result *lr = &e->pending[k];
        hlod_node_res *r = &e->res[lr->node];
        if (r->state != HLOD_NODE_QUEUED) {
            /* dropped while in flight: nothing was reserved any more */
            hlod_store_payload_free(&lr->payload);
            continue;
        }
        if (lr->result != HLOD_OK) {
            unqueue(e, lr->node);
            load_failed(e, lr->node, lr->result);
            continue;
        }
        if (uploaded && (uploaded + lr->payload.bytes > e->d.upload_budget_bytes ||
                         hlod_now_ms() - t_up >= up_ms)) {
            e->pending[keep++] = *lr; /* next frame */
            continue;
        }
        uploaded += lr->payload.bytes;
        uint32_t node = lr->node;
        unqueue(e, node);
        hlod_result res = make_resident(e, node, &lr->payload);
        if (res == HLOD_OK)
            e->st.loads++;
        else
            load_failed(e, node, res == HLOD_ERR_NOMEM ? HLOD_ERR_IO : res);
    }
    e->pending_n = keep;
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

/* Resident nodes that may be evicted, least valuable first: those priced
 * this frame by priority, the others before them, oldest first. */
static victim *victims(hlod_engine *e, size_t *count)
{
    victim *v = hlod_engine_alloc(e, (e->resident.n + 1) * sizeof *v);
    size_t n = 0;
    if (!v)
        return NULL;
    for (size_t k = 0; k < e->resident.n; k++) {
        uint32_t i = e->resident.v[k];
        const hlod_node_frame *f = &e->fr[i];
        if (i < e->root_count || f->drawn == e->frame)
            continue;
        v[n].node = i;
        v[n].key = f->priced == e->frame ? f->priority : -(double)(e->frame - f->priced);
        n++;
    }
    qsort(v, n, sizeof *v, cmp_victim);
    *count = n;
    return v;
}

static int in_pending(const hlod_engine *e, uint32_t node)
{
    for (size_t k = 0; k < e->pending_n; k++)
        if (e->pending[k].node == node)
            return 1;
    return 0;
}

void hlod_residency_schedule(hlod_engine *e)
{
    const uint64_t budget = e->d.memory_budget_bytes;
    hlod_req_vec *want = &e->want;
    if (want->n > 1) /* want->v is NULL until something was wanted: qsort(NULL) is UB */
        qsort(want->v, want->n, sizeof *want->v, cmp_request);

    /* The previous list: queued nodes the traversal stopped asking for stay
     * queued for a few frames (a partial read survives a brief dip), then
     * are dropped and their reservation returned. */
    hlod_req_vec old = e->post;
    e->post = (hlod_req_vec){0};
    hlod_req_vec *post = &e->post;

    victim *vic = NULL;
    size_t nvic = 0, vi = 0;
    int vic_built = 0;
    for (size_t k = 0; k < want->n && post->n < e->d.max_inflight; k++) {
        uint32_t node = want->v[k].node;
        hlod_node_res *r = &e->res[node];
        double pr = want->v[k].priority;
        if (r->state == HLOD_NODE_QUEUED) {
            if (!in_pending(e, node) && hlod_req_push(e, post, node, pr))
                r->posted = e->frame;
            continue;
        }
        if (r->state != HLOD_NODE_ABSENT)
            continue;
        const hlod_store_node *n = &e->nodes[node];
        for (;;) {
            uint64_t used = e->resident_bytes + e->reserved_bytes;
            double used_c = mem_cost(e, e->resident_cost + e->reserved_cost);
            if (used + n->payload_size <= budget && used_c + mem_cost(e, n->cost) <= (double)budget)
                break;
            if (!vic_built) {
                vic = victims(e, &nvic);
                vic_built = 1;
            }
            while (vi < nvic && e->res[vic[vi].node].state != HLOD_NODE_RESIDENT)
                vi++;
            if (vi >= nvic || !(vic[vi].key < pr))
                break;
            evict(e, vic[vi++].node);
        }
        uint64_t used = e->resident_bytes + e->reserved_bytes;
        double used_c = mem_cost(e, e->resident_cost + e->reserved_cost);
        if (used + n->payload_size > budget || used_c + mem_cost(e, n->cost) > (double)budget)
            continue; /* does not fit; a smaller one further down may */
        if (!hlod_req_push(e, post, node, pr))
            break;
        r->state = HLOD_NODE_QUEUED;
        r->posted = e->frame;
        reserve(e, node, +1);
    }
    hlod_engine_free(e, vic);

    int resort = 0;
    for (size_t k = 0; k < old.n; k++) {
        uint32_t node = old.v[k].node;
        hlod_node_res *r = &e->res[node];
        if (r->state != HLOD_NODE_QUEUED || r->posted == e->frame || in_pending(e, node))
            continue;
        if (r->wanted + KEEP_UNWANTED_FRAMES >= e->frame && post->n < e->d.max_inflight &&
            hlod_req_push(e, post, node, 0.5f * old.v[k].priority)) {
            r->posted = e->frame;
            resort = 1;
            continue;
        }
        unqueue(e, node);
    }
    hlod_engine_free(e, old.v);
    if (resort)
        qsort(post->v, post->n, sizeof *post->v, cmp_request);

    double t0 = hlod_now_ms();
    hlod_loader_post(e->loader, post->v, post->n); /* busy: the same list goes next frame */
    if (hlod_now_ms() - t0 > WAIT_MS)
        e->st.render_waits++;
    e->st.queued = (uint32_t)post->n;
    if (e->d.deterministic)
        hlod_loader_pump(e->loader, e->d.deterministic_load_bytes);
}

void hlod_residency_release_all(hlod_engine *e)
{
    for (size_t k = 0; k < e->pending_n; k++)
        hlod_store_payload_free(&e->pending[k].payload);
    e->pending_n = 0;
    if (e->d.renderer && e->res)
        for (size_t k = 0; k < e->resident.n; k++)
            hlod_gpu_release(e->d.renderer, &e->res[e->resident.v[k]].gpu);
    e->resident.n = 0;
}
