/*
 * lumigraph.c - the Grid-Lumigraph client's views: fetch thread, LRU cache
 * of fetched bytes, GPU slots (lumigraph.h; Okamoto et al. 5.1, 5.2).
 */
#include "lumigraph.h"

#include "hlod_clock.h"

#include <assert.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define SLOTS 48u       /* 8 points x 6 faces: every view a frame can blend */
#define READY_MAX 4u    /* decoded views waiting for an upload */
#define RETRY_MS 500.0  /* a failed fetch is asked again after this */
#define VIEW_MAX_BYTES (64u << 20)
#define NONE UINT32_MAX

typedef struct entry {  /* a fetched view's bytes (the fetch thread's cache) */
    uint32_t id;
    uint8_t *bytes;
    size_t n;
    uint64_t used;
} entry;

struct hlod_lumi {
    char *repo;
    hlod_lumi_index ix;
    hlod_logger lg;
    uint64_t cache_cap;
    int answers;        /* 1: ask the server's /answer (hlod-lumigraph-serve); 0: files */

    pthread_t thread;
    pthread_mutex_t mu;
    pthread_cond_t wake;
    int started;
    /* shared, under mu */
    int stop;
    atomic_int cancel;  /* set with stop: a transfer in flight is abandoned */
    atomic_uchar *gone; /* per view: a server declined it (answers mode, never baked) */
    uint32_t want[SLOTS], want_n;
    double eye[3], dir[3];  /* the camera the want list is for */
    hlod_lumi_view ready[READY_MAX];
    uint32_t ready_n;
    uint64_t bytes, answer_max;
    uint32_t failures;
    /* the fetch thread's own */
    entry *cache;
    size_t cache_n, cache_slots;
    uint64_t cache_bytes, tick;
    double *retry_at;   /* per view: not asked again before this (ms); NULL until needed */
    uint8_t *bad;       /* per view: its bytes are damaged; never asked again */
    int down;           /* the last fetch failed (logged once per outage) */
    /* the render thread's own */
    uint32_t slot_id[SLOTS];
    uint64_t slot_used[SLOTS];
    uint64_t frame;
    int gpu;            /* 1: slots made; -1: they cannot be */
};

const hlod_lumi_index *hlod_lumi_get_index(const hlod_lumi *l)
{
    return &l->ix;
}

/* ---- fetch thread ---- */

static int cancelled(void *user)
{
    hlod_lumi *l = user;
    return atomic_load_explicit(&l->cancel, memory_order_relaxed);
}

static entry *cache_find(hlod_lumi *l, uint32_t id)
{
    for (size_t k = 0; k < l->cache_n; k++)
        if (l->cache[k].id == id)
            return &l->cache[k];
    return NULL;
}

/* Keeps a view's bytes, dropping the least recently used past the cap
 * (the newest stays even when it alone is larger). */
static void cache_put(hlod_lumi *l, uint32_t id, uint8_t *bytes, size_t n)
{
    while (l->cache_n && l->cache_bytes + n > l->cache_cap) {
        size_t old = 0;
        for (size_t k = 1; k < l->cache_n; k++)
            if (l->cache[k].used < l->cache[old].used)
                old = k;
        l->cache_bytes -= l->cache[old].n;
        free(l->cache[old].bytes);
        l->cache[old] = l->cache[--l->cache_n];
    }
    if (l->cache_n == l->cache_slots) {
        size_t cap = l->cache_slots ? 2 * l->cache_slots : 64;
        entry *c = realloc(l->cache, cap * sizeof *c);
        if (!c) {
            free(bytes);
            return;
        }
        l->cache = c;
        l->cache_slots = cap;
    }
    l->cache[l->cache_n++] = (entry){id, bytes, n, ++l->tick};
    l->cache_bytes += n;
}

/* The first wanted view that is neither decoded nor waiting out a retry;
 * NONE when there is none.  Under mu. */
static uint32_t next_wanted(const hlod_lumi *l, double now)
{
    for (uint32_t k = 0; k < l->want_n; k++) {
        uint32_t id = l->want[k];
        int ready = 0;
        for (uint32_t q = 0; q < l->ready_n; q++)
            ready |= l->ready[q].id == id;
        if (!ready && !l->bad[id] && l->retry_at[id] <= now)
            return id;
    }
    return NONE;
}

/* Fetches (or finds in the cache) and decodes one view; 1 when *v holds it. */
static int get_view(hlod_lumi *l, uint32_t id, hlod_lumi_view *v)
{
    char rel[128], name[4200];
    hlod_lumi_view_path(&l->ix, id, rel, sizeof rel);
    snprintf(name, sizeof name, "%s/%s", l->repo, rel);
    entry *e = cache_find(l, id);
    if (!e) {
        uint8_t *buf;
        size_t n;
        /* an outage is logged once, when it starts */
        hlod_logger quiet = {0};
        hlod_result r = hlod_lumi_fetch_cancel(l->repo, rel, VIEW_MAX_BYTES, cancelled, l,
                                               l->down ? &quiet : &l->lg, &buf, &n);
        if (r == HLOD_ERR_CANCELLED)
            return 0; /* shutting down */
        pthread_mutex_lock(&l->mu);
        if (r != HLOD_OK) {
            l->failures++;
            l->retry_at[id] = hlod_now_ms() + RETRY_MS;
        } else {
            l->bytes += n;
            if (n > l->answer_max)
                l->answer_max = n;
        }
        pthread_mutex_unlock(&l->mu);
        if (r != HLOD_OK) {
            if (!l->down)
                hlod_logf(&l->lg, HLOD_LOG_WARN, "%s: the repository does not answer; views are "
                          "drawn from the cache until it does", l->repo);
            l->down = 1;
            return 0;
        }
        if (l->down)
            hlod_logf(&l->lg, HLOD_LOG_WARN, "%s: the repository answers again", l->repo);
        l->down = 0;
        cache_put(l, id, buf, n);
        e = cache_find(l, id);
        if (!e)
            return 0;
    }
    e->used = ++l->tick;
    if (hlod_lumi_view_decode(&l->ix, id, e->bytes, e->n, name, &l->lg, v) != HLOD_OK) {
        l->bad[id] = 1; /* logged; its slot stays empty, hole shading covers it */
        l->cache_bytes -= e->n;
        free(e->bytes);
        *e = l->cache[--l->cache_n];
        return 0;
    }
    return 1;
}

/* One request to the server's /answer for the camera of the want list
 * (copied under mu by the caller): its records go into the cache.  The
 * views it lacks that the answer did not bring wait out a retry. */
static void ask_server(hlod_lumi *l, const double eye[3], const double dir[3],
                       const uint32_t *want, uint32_t nw)
{
    hlod_lumi_request q = {{eye[0], eye[1], eye[2]}, {dir[0], dir[1], dir[2]}, 0};
    uint32_t ids[HLOD_LUMI_CANDIDATES], bits[HLOD_LUMI_CANDIDATES];
    uint32_t n = hlod_lumi_candidates(&l->ix, eye, dir, ids, bits);
    for (uint32_t k = 0; k < n; k++) {
        int wanted = 0;
        for (uint32_t w = 0; w < nw; w++)
            wanted |= want[w] == ids[k];
        if (!wanted || cache_find(l, ids[k]))
            q.have |= 1ull << bits[k];
    }
    char text[600], rel[1800] = "answer?";
    size_t tn = hlod_lumi_request_format(&q, text, sizeof text), rn = 7;
    for (size_t k = 0; k < tn; k++) { /* '+' (an exponent's) would reach the server as ' ' */
        if (text[k] == '+') {
            memcpy(rel + rn, "%2B", 3);
            rn += 3;
        } else {
            rel[rn++] = text[k];
        }
    }
    rel[rn] = 0;
    uint8_t *buf = NULL;
    size_t len = 0;
    hlod_logger quiet = {0};
    hlod_result r = tn ? hlod_lumi_fetch_cancel(l->repo, rel, VIEW_MAX_BYTES, cancelled, l,
                                                l->down ? &quiet : &l->lg, &buf, &len)
                       : HLOD_ERR_INVALID_ARG;
    size_t pos = 0;
    uint32_t last = 0; /* candidate order of the last record, + 1 */
    while (r == HLOD_OK && pos + 8 <= len) { /* records: id, length, a view's file */
        uint32_t head[2];
        memcpy(head, buf + pos, 8);
        int candidate = 0;
        for (uint32_t k = 0; k < n; k++)
            candidate |= ids[k] == head[0];
        if (!candidate || head[1] > len - pos - 8)
            break; /* not what was asked: the rest is not trusted */
        for (uint32_t k = 0; k < n; k++)
            if (ids[k] == head[0] && k + 1 > last)
                last = k + 1;
        uint8_t *v = malloc(head[1] ? head[1] : 1);
        if (v && !cache_find(l, head[0])) {
            memcpy(v, buf + pos + 8, head[1]);
            cache_put(l, head[0], v, head[1]);
        } else {
            free(v);
        }
        pos += 8 + (size_t)head[1];
    }
    if (r == HLOD_ERR_CANCELLED) {
        free(buf);
        return; /* shutting down */
    }
    if (r == HLOD_OK && pos != len)
        hlod_logf(&l->lg, HLOD_LOG_WARN, "%s: an answer that does not parse (%zu of %zu bytes "
                  "read); its rest dropped", l->repo, pos, len);
    free(buf);
    pthread_mutex_lock(&l->mu);
    double now = hlod_now_ms();
    if (r != HLOD_OK)
        l->failures++;
    l->bytes += len;
    if (len > l->answer_max)
        l->answer_max = len;
    /* a view the answer passed over (before its last record, or any when it
     * brought none) waits out a retry; one after its last record was only
     * cut by the answer's limit and is asked for again at once.  In
     * answers mode a never-baked view passed over is one the server cannot
     * render: not asked for again */
    for (uint32_t w = 0; w < nw; w++) {
        if (r == HLOD_OK && cache_find(l, want[w]))
            continue;
        uint32_t order = 0;
        for (uint32_t k = 0; k < n; k++)
            if (ids[k] == want[w])
                order = k + 1;
        if (r == HLOD_OK && last && order > last)
            continue;
        l->retry_at[want[w]] = now + RETRY_MS;
        if (r == HLOD_OK && l->ix.state[want[w]] == HLOD_LUMI_MISSING)
            atomic_store_explicit(&l->gone[want[w]], 1, memory_order_relaxed);
    }
    pthread_mutex_unlock(&l->mu);
    if (r != HLOD_OK) {
        if (!l->down)
            hlod_logf(&l->lg, HLOD_LOG_WARN, "%s: the server does not answer; views are drawn "
                      "from the cache until it does", l->repo);
        l->down = 1;
    } else {
        if (l->down)
            hlod_logf(&l->lg, HLOD_LOG_WARN, "%s: the server answers again", l->repo);
        l->down = 0;
    }
}

static void *fetch_main(void *arg)
{
    hlod_lumi *l = arg;
    pthread_mutex_lock(&l->mu);
    while (!l->stop) {
        double now = hlod_now_ms();
        uint32_t id = l->ready_n < READY_MAX ? next_wanted(l, now) : NONE;
        if (id == NONE) {
            /* nothing to do, or waiting out a retry: look again soon */
            struct timespec ts;
            clock_gettime(CLOCK_REALTIME, &ts);
            ts.tv_nsec += 100 * 1000000L;
            if (ts.tv_nsec >= 1000000000L) {
                ts.tv_sec++;
                ts.tv_nsec -= 1000000000L;
            }
            pthread_cond_timedwait(&l->wake, &l->mu, &ts);
            continue;
        }
        if (l->answers && !cache_find(l, id)) {
            uint32_t want[SLOTS], nw = l->want_n;
            double eye[3], dir[3];
            memcpy(want, l->want, nw * sizeof *want);
            memcpy(eye, l->eye, sizeof eye);
            memcpy(dir, l->dir, sizeof dir);
            pthread_mutex_unlock(&l->mu);
            ask_server(l, eye, dir, want, nw);
            pthread_mutex_lock(&l->mu);
            continue;
        }
        pthread_mutex_unlock(&l->mu);
        hlod_lumi_view v;
        int got = get_view(l, id, &v);
        pthread_mutex_lock(&l->mu);
        if (got)
            l->ready[l->ready_n++] = v;
    }
    pthread_mutex_unlock(&l->mu);
    return NULL;
}

/* ---- create / destroy ---- */

hlod_result hlod_lumi_create(const char *repo, int answers, uint64_t store_id,
                             uint64_t cache_bytes, const hlod_logger *lg,
                             hlod_lumi **out)
{
    *out = NULL;
    hlod_logger none = {0};
    if (!lg)
        lg = &none;
    hlod_lumi *l = calloc(1, sizeof *l);
    if (!l)
        return HLOD_ERR_NOMEM;
    l->lg = *lg;
    atomic_init(&l->cancel, 0);
    l->cache_cap = cache_bytes;
    l->answers = answers;
    if (answers && strncmp(repo, "http://", 7) && strncmp(repo, "https://", 8)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: answers come from a server (hlod-lumigraph-serve): "
                  "give its http(s) URL", repo);
        free(l);
        return HLOD_ERR_INVALID_ARG;
    }
    l->repo = strdup(repo);
    hlod_result r = l->repo ? hlod_lumi_index_load(repo, lg, &l->ix) : HLOD_ERR_NOMEM;
    if (r == HLOD_OK && l->ix.store_id != store_id) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: baked from another store (store id %016llx, this "
                  "store's %016llx); bake it again from this store", repo,
                  (unsigned long long)l->ix.store_id, (unsigned long long)store_id);
        r = HLOD_ERR_FORMAT;
    }
    if (r == HLOD_OK) {
        l->retry_at = calloc(l->ix.views, sizeof *l->retry_at);
        l->bad = calloc(l->ix.views, 1);
        l->gone = calloc(l->ix.views, sizeof *l->gone);
        if (!l->retry_at || !l->bad || !l->gone)
            r = HLOD_ERR_NOMEM;
    }
    for (uint32_t s = 0; s < SLOTS; s++)
        l->slot_id[s] = NONE;
    if (r == HLOD_OK) {
        pthread_mutex_init(&l->mu, NULL);
        pthread_cond_init(&l->wake, NULL);
        l->started = 1;
        if (pthread_create(&l->thread, NULL, fetch_main, l) != 0) {
            l->started = 0;
            pthread_mutex_destroy(&l->mu);
            pthread_cond_destroy(&l->wake);
            r = HLOD_ERR_NOMEM;
        }
    }
    if (r != HLOD_OK) {
        hlod_lumi_destroy(l, NULL);
        return r;
    }
    *out = l;
    return HLOD_OK;
}

void hlod_lumi_destroy(hlod_lumi *l, hlod_renderer *r)
{
    if (!l)
        return;
    if (l->started) {
        pthread_mutex_lock(&l->mu);
        l->stop = 1;
        atomic_store(&l->cancel, 1);
        pthread_cond_signal(&l->wake);
        pthread_mutex_unlock(&l->mu);
        pthread_join(l->thread, NULL);
        pthread_mutex_destroy(&l->mu);
        pthread_cond_destroy(&l->wake);
    }
    for (uint32_t k = 0; k < l->ready_n; k++)
        hlod_lumi_view_free(&l->ready[k]);
    for (size_t k = 0; k < l->cache_n; k++)
        free(l->cache[k].bytes);
    free(l->cache);
    free(l->retry_at);
    free(l->bad);
    free(l->gone);
    if (r && l->gpu > 0)
        hlod_gpu_lumi_release(r);
    hlod_lumi_index_free(&l->ix);
    free(l->repo);
    free(l);
}

/* ---- render thread ---- */

/* The views this camera blends, in request order (section 5.1, step 3;
 * hlod_lumi_candidates): views the bake found empty are left out, and
 * views it never baked unless a server may render them. */
static uint32_t needed_views(const hlod_lumi *l, const double eye[3], const double fwd[3],
                             uint32_t *out)
{
    uint32_t ids[HLOD_LUMI_CANDIDATES], bits[HLOD_LUMI_CANDIDATES], n = 0;
    uint32_t nc = hlod_lumi_candidates(&l->ix, eye, fwd, ids, bits);
    for (uint32_t k = 0; k < nc; k++) {
        uint8_t st = l->ix.state[ids[k]];
        if (st == HLOD_LUMI_BAKED ||
            (st == HLOD_LUMI_MISSING && l->answers &&
             !atomic_load_explicit(&l->gone[ids[k]], memory_order_relaxed)))
            out[n++] = ids[k];
    }
    return n;
}

static uint32_t slot_of(const hlod_lumi *l, uint32_t id)
{
    for (uint32_t s = 0; s < SLOTS; s++)
        if (l->slot_id[s] == id)
            return s;
    return NONE;
}

/* A slot for a new view: a free one, else the least recently used that
 * this frame does not need. */
static uint32_t free_slot(const hlod_lumi *l, const uint32_t *need, uint32_t nn)
{
    uint32_t best = NONE;
    for (uint32_t s = 0; s < SLOTS; s++) {
        if (l->slot_id[s] == NONE)
            return s;
        int needed = 0;
        for (uint32_t q = 0; q < nn; q++)
            needed |= need[q] == l->slot_id[s];
        if (!needed && (best == NONE || l->slot_used[s] < l->slot_used[best]))
            best = s;
    }
    return best;
}

/* Takes up to `max` decoded views and the fetch counters, without ever
 * waiting for the fetch thread: 0 views when it holds the lock. */
static uint32_t take_ready(hlod_lumi *l, uint32_t max, hlod_lumi_view *got, hlod_lumi_stats *st)
{
    if (pthread_mutex_trylock(&l->mu) != 0)
        return 0;
    uint32_t n = l->ready_n < max ? l->ready_n : max;
    memcpy(got, l->ready, n * sizeof *got);
    memmove(l->ready, l->ready + n, (l->ready_n - n) * sizeof *l->ready);
    l->ready_n -= n;
    st->bytes = l->bytes;
    st->answer_max = l->answer_max;
    st->fetch_failures = l->failures;
    l->bytes = l->answer_max = 0;
    l->failures = 0;
    pthread_mutex_unlock(&l->mu);
    return n;
}

hlod_result hlod_lumi_frame(hlod_lumi *l, hlod_renderer *r, const hlod_camera *cam,
                            uint32_t uploads, hlod_gpu_lumi_frame *f, hlod_lumi_stats *st)
{
    assert(l && cam && f && st);
    memset(st, 0, sizeof *st);
    memset(f, 0, sizeof *f);
    l->frame++;
    if (r && !l->gpu)
        l->gpu = hlod_gpu_lumi_init(r, SLOTS, l->ix.size, l->ix.depth_size) == HLOD_OK ? 1 : -1;
    if (r && l->gpu < 0)
        return HLOD_ERR_UNSUPPORTED; /* every frame: nothing to draw with (logged once) */
    uint32_t point[8], need[SLOTS];
    double w[8], fwd[3];
    hlod_lumi_corners(&l->ix, cam->position, point, w);
    hlod_camera_forward(cam, fwd);
    uint32_t nn = needed_views(l, cam->position, fwd, need);

    hlod_lumi_view got[READY_MAX];
    if (uploads > READY_MAX)
        uploads = READY_MAX;
    uint32_t ng = take_ready(l, uploads, got, st);
    double t0 = hlod_now_ms();
    for (uint32_t k = 0; k < ng; k++) {
        uint32_t s = slot_of(l, got[k].id);
        if (s == NONE)
            s = free_slot(l, need, nn);
        if (s != NONE && r && l->gpu > 0 &&
            hlod_gpu_lumi_upload(r, s, got[k].rgb, got[k].depth) == HLOD_OK) {
            l->slot_id[s] = got[k].id;
            l->slot_used[s] = l->frame;
            st->uploads++;
        }
        hlod_lumi_view_free(&got[k]);
    }
    st->upload_ms = ng ? hlod_now_ms() - t0 : 0;

    /* the frame's blend, and what it still lacks, asked for in order */
    uint32_t want[SLOTS], nw = 0;
    for (int c = 0; c < 8; c++) {
        double p[3];
        uint32_t g = l->ix.grid, pt = point[c];
        hlod_lumi_point(&l->ix, pt % g, pt / g % g, pt / g / g, p);
        for (int k = 0; k < 3; k++)
            f->point[c][k] = (float)(p[k] - cam->position[k]);
        f->weight[c] = (float)w[c];
        for (uint32_t d = 0; d < HLOD_LUMI_FACES; d++) {
            uint32_t id = pt * HLOD_LUMI_FACES + d;
            f->slot[c][d] = l->ix.state[id] == HLOD_LUMI_EMPTY ? -2 : -1;
        }
    }
    for (uint32_t q = 0; q < nn; q++) {
        uint32_t s = slot_of(l, need[q]);
        if (s != NONE) {
            l->slot_used[s] = l->frame;
            for (int c = 0; c < 8; c++)
                if (point[c] == need[q] / HLOD_LUMI_FACES)
                    f->slot[c][need[q] % HLOD_LUMI_FACES] = (int32_t)s;
        } else {
            want[nw++] = need[q];
        }
    }
    for (uint32_t q = 0; q < nw; q++) /* lacked where it would weigh in */
        for (int c = 0; c < 8; c++)
            st->missing += point[c] == want[q] / HLOD_LUMI_FACES && w[c] > 0;
    if (pthread_mutex_trylock(&l->mu) == 0) {
        memcpy(l->want, want, nw * sizeof *want);
        l->want_n = nw;
        memcpy(l->eye, cam->position, sizeof l->eye);
        memcpy(l->dir, fwd, sizeof l->dir);
        if (nw)
            pthread_cond_signal(&l->wake);
        pthread_mutex_unlock(&l->mu);
    }
    f->near_plane = (float)l->ix.near_plane;
    f->log_ratio = (float)log(l->ix.far_plane / l->ix.near_plane);
    return HLOD_OK;
}
