/*
 * test_faults.c - I/O faults injected behind the store's read interface
 * while the engine streams (issue 6, "Fault injection in the loader").
 *
 * Two injection points, both test hooks:
 *   - hlod_engine_desc.read_hook, called by the loader thread before every
 *     incremental read step: fails steps with HLOD_ERR_IO (always, or for a
 *     node's first k tries), or sleeps (a disk 10x slower than the base
 *     simulated one);
 *   - hlod_store_set_pread, which replaces pread(2) under
 *     hlod_store_read_step: short reads, EINTR, EIO from the "disk", a read
 *     returning more than asked;
 * plus two done to the file itself: bits flipped in payloads after the
 * store was opened (its table checksum says one thing, the bytes another),
 * and the file truncated while the engine runs.
 *
 * Each test runs a threaded engine with no renderer (a time_model machine),
 * a camera that sees the whole synthetic city and time enough to draw all of
 * it, and asserts what the issue expects: no crash or hang (an alarm kills a
 * hung run), no render wait and no frame() call taking long (render_waits
 * and frame times are wall-clock measures, so frames in which the scheduler
 * preempted the render thread, per getrusage, are excused), the affected
 * nodes ending bad with their parents drawn instead, each fault counted in
 * the stats and logged once (a thread-safe logger counts messages per node),
 * the other blocks streaming to full detail, and transient failures retried
 * after 16, 32 and 64 frames rather than in a tight loop (the hook records
 * the frame of every attempt).
 *
 * Prints "REPORT faults kind=K injected=N frames=F ..." lines for
 * tests/reliability_report.sh.
 */
#define _GNU_SOURCE /* RUSAGE_THREAD */
#include "check.h"
#include "inspect.h"
#include "engine_check.h"
#include "store_fixture.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#define MAXN 1024           /* nodes a fixture here may have */
#define MAX_TRIES 8         /* failing attempts recorded per node */
#define FRAME_MS 20.0       /* a frame() call longer than this is a stall */

static char g_dir[256];

static const char *tmp_path(const char *name, char *buf, size_t n)
{
    snprintf(buf, n, "%s/%s", g_dir, name);
    return buf;
}

/* ---- thread-safe logger: messages per node (the loader thread logs) ---- */

typedef struct logrec {
    pthread_mutex_t mu;
    int read_failed[MAXN];  /* loader: "node N: read failed" */
    int unreadable[MAXN];   /* engine: "node N is unreadable" (turned bad) */
    int store_errors;       /* the store reader's own messages */
    int other;
} logrec;

static int msg_node(const char *msg, unsigned *node)
{
    const char *q = strstr(msg, ": node ");
    return q && sscanf(q, ": node %u", node) == 1 && *node < MAXN;
}

static void log_engine(void *user, hlod_log_level level, const char *msg)
{
    logrec *l = user;
    unsigned node;
    (void)level;
    pthread_mutex_lock(&l->mu);
    if (strstr(msg, "read failed") && msg_node(msg, &node))
        l->read_failed[node]++;
    else if (strstr(msg, "is unreadable") && msg_node(msg, &node))
        l->unreadable[node]++;
    else
        l->other++;
    if (getenv("HLOD_TEST_VERBOSE"))
        fprintf(stderr, "  log: %s\n", msg);
    pthread_mutex_unlock(&l->mu);
}

static void log_store(void *user, hlod_log_level level, const char *msg)
{
    logrec *l = user;
    (void)level;
    (void)msg;
    pthread_mutex_lock(&l->mu);
    l->store_errors++;
    pthread_mutex_unlock(&l->mu);
}

/* A counter, read under the logger's lock (the loader thread may log). */
static int logged(logrec *l, const int *counter)
{
    pthread_mutex_lock(&l->mu);
    int v = *counter;
    pthread_mutex_unlock(&l->mu);
    return v;
}

/* Node i's failure was logged once by the loader, and once more when it
 * turned bad (bad = 1) or not at all (bad = 0). */
static void check_logged_once(logrec *l, uint32_t i, int bad, const char *what)
{
    int failed = logged(l, &l->read_failed[i]), unreadable = logged(l, &l->unreadable[i]);
    CHECKF(failed == 1 && unreadable == bad, "%s: node %u: %d read failures and %d "
           "\"unreadable\" logged (want 1 and %d)", what, i, failed, unreadable, bad);
}

static logrec *logrec_new(void)
{
    logrec *l = calloc(1, sizeof *l);
    pthread_mutex_init(&l->mu, NULL);
    return l;
}

static void logrec_free(logrec *l)
{
    pthread_mutex_destroy(&l->mu);
    free(l);
}

/* ---- the read hook (loader thread) ---- */

enum { PLAN_NONE = 0, PLAN_EIO_ALWAYS, PLAN_EIO_FIRST_K };

typedef struct faults {
    uint8_t plan[MAXN];             /* set before the engine starts */
    int first_k;                    /* PLAN_EIO_FIRST_K: fail this many tries */
    atomic_int step_frames;         /* every step waits this many test frames (slow disk) */
    atomic_int released;            /* set before destroy: no step waits any more */
    atomic_int frame;               /* the test's frame number, for records */
    atomic_int attempts[MAXN];      /* steps at offset 0: read attempts */
    atomic_int failed[MAXN];        /* steps the hook failed */
    atomic_int fail_frame[MAXN][MAX_TRIES];
    atomic_long steps;              /* all hook calls */
    atomic_long injected;           /* failed or slowed steps */
} faults;

static faults *faults_new(void)
{
    faults *fx = calloc(1, sizeof *fx); /* zero is a valid initial atomic value */
    return fx;
}

/* called from the loader thread */
static hlod_result fault_hook(void *user, uint32_t node, uint64_t offset, size_t bytes)
{
    faults *fx = user;
    (void)bytes;
    atomic_fetch_add(&fx->steps, 1);
    if (node >= MAXN)
        return HLOD_OK;
    int try_no = offset == 0 ? atomic_fetch_add(&fx->attempts[node], 1) : -1;
    int wait = atomic_load(&fx->step_frames);
    if (wait > 0) {
        /* counted in the test's frames, not in ms: the disk's speed is
         * the same whatever the scheduler does to either thread */
        atomic_fetch_add(&fx->injected, 1);
        int until = atomic_load(&fx->frame) + wait;
        while (atomic_load(&fx->frame) < until && !atomic_load(&fx->released))
            sleep_us(100);
    }
    int fail = fx->plan[node] == PLAN_EIO_ALWAYS ||
               (fx->plan[node] == PLAN_EIO_FIRST_K && try_no >= 0 && try_no < fx->first_k);
    if (!fail)
        return HLOD_OK;
    int k = atomic_fetch_add(&fx->failed[node], 1);
    if (k < MAX_TRIES)
        atomic_store(&fx->fail_frame[node][k], atomic_load(&fx->frame));
    atomic_fetch_add(&fx->injected, 1);
    return HLOD_ERR_IO;
}

/* ---- engine runs ---- */

static fixed_machine g_machine = {2, 1e-5}; /* the whole fixture fits in a frame */

static hlod_store *open_fixture(const char *name, const fixture_opts *o, const hlod_logger *lg)
{
    char path[512];
    tmp_path(name, path, sizeof path);
    hlod_result r = fixture_write(path, o, NULL);
    CHECKF(r == HLOD_OK, "fixture_write: %s", hlod_result_str(r));
    hlod_store *s = NULL;
    r = hlod_store_open(path, lg, &s);
    CHECKF(r == HLOD_OK, "open: %s", hlod_result_str(r));
    CHECK(hlod_store_node_count(s) <= MAXN);
    return s;
}

/* The default fixture here: 4 blocks side by side along x (each 100 wide,
 * 10 apart), 2 levels below each root: 4 + 16 + 64 = 84 nodes. */
static fixture_opts city_opts(void)
{
    fixture_opts o = {0};
    o.roots = 4;
    o.depth = 2;
    return o;
}

static hlod_engine *start_engine(hlod_store *s, faults *fx, logrec *lg)
{
    hlod_engine_desc d = {0};
    d.target_ms = 33;
    d.time_model = fixed_machine_time;
    d.time_model_user = &g_machine;
    d.read_hook = fault_hook;
    d.read_hook_user = fx;
    d.logger.func = log_engine;
    d.logger.user_data = lg;
    hlod_engine *e = NULL;
    hlod_result r = hlod_engine_create(s, &d, &e);
    CHECKF(r == HLOD_OK, "engine: %s", hlod_result_str(r));
    return e;
}

static void look(hlod_camera *cam, double ex, double ey, double ez, double tx, double ty,
                 double tz)
{
    double eye[3] = {ex, ey, ez}, at[3] = {tx, ty, tz}, up[3] = {0, 0, 1};
    CHECK(hlod_camera_look_at(cam, eye, at, up, 60, 0.5, 1e5, 1280, 720) == HLOD_OK);
}

/* Above the city's south side, every block in view. */
static void whole_city(hlod_camera *cam)
{
    look(cam, 215, -180, 260, 215, 50, 0);
}

typedef struct tally {
    int frames;
    uint64_t loads, load_failures;
    uint32_t bad_nodes, render_waits;
    double worst_ms;    /* of the frames that kept the CPU (cpu_span.h) */
    int slow_frames;    /* frame() calls over FRAME_MS that kept the CPU */
    int nonfinite;      /* frames with a NaN or Inf in the stats */
    int judged;         /* frames that kept the CPU (cpu_span.h) */
    int unexplained_slow;
} tally;

/* n frames from cam; frame() is timed on the wall clock; 1 ms between frames
 * lets the loader thread run (as a real frame would). */
static void run_frames(hlod_engine *e, const hlod_camera *cam, int n, faults *fx, tally *t,
                       hlod_frame_stats *last)
{
    for (int f = 0; f < n; f++) {
        atomic_store(&fx->frame, t->frames);
        hlod_frame_stats st;
        cpu_span sp;
        span_start(&sp);
        hlod_result r = hlod_engine_frame(e, cam, 1.0 / 30, &st);
        span_stop(&sp);
        double dt = sp.wall_ms;
        CHECK(r == HLOD_OK);
        if (span_kept_cpu(&sp)) { /* the time bounds judge only frames not preempted */
            t->judged++;
            t->unexplained_slow += dt > FRAME_MS && sp.vol == 0;
            t->slow_frames += dt > FRAME_MS;
            if (dt > t->worst_ms)
                t->worst_ms = dt;
        }
        t->frames++;
        t->loads += st.loads;
        t->load_failures += st.load_failures;
        t->bad_nodes = st.bad_nodes;
        t->render_waits += st.render_waits;
        t->nonfinite += !stats_finite(&st);
        if (last)
            *last = st;
        sleep_us(1000);
    }
}

/* No stall: the render thread never waited on the loader, and frame() was
 * fast.  A stall behind the loader would show in nearly every frame while
 * reads are slow, without the scheduler preempting the thread; a frame or
 * two descheduled on a loaded machine is noise. */
static void check_no_stall(const char *what, const tally *t)
{
    int allowed = t->frames / 100 > 2 ? t->frames / 100 : 2;
    if (span_judges_waits()) /* counted by the engine: no excuse */
        CHECKF(t->render_waits == 0, "%s: the render thread slept %u times", what,
               t->render_waits);
    CHECKF(span_judged_enough(t->judged, t->frames), "%s: only %d of %d frames kept the CPU",
           what, t->judged, t->frames);
    CHECKF(t->unexplained_slow <= span_host_spikes(t->frames),
           "%s: %d of %d frames over %.0f ms, neither preempted nor blocked", what,
           t->unexplained_slow, t->frames, FRAME_MS);
    CHECKF(t->slow_frames <= allowed && t->worst_ms < 1000, "%s: %d of %d frames over %.0f ms, "
           "worst %.1f ms", what, t->slow_frames, t->frames, FRAME_MS, t->worst_ms);
    CHECKF(t->nonfinite == 0, "%s: %d frames with non-finite stats", what, t->nonfinite);
}

static uint32_t child(const hlod_store *s, uint32_t p, uint32_t k)
{
    const hlod_store_node *n = hlod_store_nodes(s);
    CHECK(n[p].first_child + k < n[p + 1].first_child);
    return n[p].first_child + k;
}

static int is_leaf(const hlod_store *s, uint32_t i)
{
    const hlod_store_node *n = hlod_store_nodes(s);
    return n[i].first_child == n[i + 1].first_child;
}

/* Each bad node is not drawn and neither is anything below it; its parent
 * (or, when that is bad too, the nearest good ancestor) is drawn. */
static void check_bad_covered(const hlod_engine *e, const hlod_store *s, const char *what)
{
    const hlod_store_node *n = hlod_store_nodes(s);
    for (uint32_t i = 0; i < hlod_store_node_count(s); i++) {
        if (hlod_engine_node_state(e, i) != HLOD_NODE_BAD)
            continue;
        CHECKF(!hlod_engine_node_drawn(e, i), "%s: bad node %u drawn", what, i);
        uint32_t a = n[i].parent;
        while (a != HLOD_STORE_NO_PARENT && hlod_engine_node_state(e, a) == HLOD_NODE_BAD)
            a = n[a].parent;
        CHECKF(a != HLOD_STORE_NO_PARENT && hlod_engine_node_drawn(e, a),
               "%s: bad node %u: ancestor %u not drawn", what, i, a);
    }
}

/* Every leaf of block b is drawn and every node of it resident. */
static int block_full_detail(const hlod_engine *e, const hlod_store *s, uint32_t b)
{
    const hlod_store_node *n = hlod_store_nodes(s);
    for (uint32_t i = 0; i < hlod_store_node_count(s); i++) {
        if (n[i].block != b)
            continue;
        if (hlod_engine_node_state(e, i) != HLOD_NODE_RESIDENT)
            return 0;
        if (is_leaf(s, i) && !hlod_engine_node_drawn(e, i))
            return 0;
    }
    return 1;
}

/* A transiently failing node: exactly 4 attempts, at least 16, 32 and 64
 * frames apart (residency.c's backoff), then bad. */
static void check_backoff(const faults *fx, uint32_t node, const char *what)
{
    int tries = atomic_load(&fx->failed[node]);
    CHECKF(tries == 4, "%s: node %u failed %d times (want 4: 1 + 3 retries)", what, node, tries);
    for (int k = 1; k < tries && k < MAX_TRIES; k++) {
        int gap = atomic_load(&fx->fail_frame[node][k]) - atomic_load(&fx->fail_frame[node][k - 1]);
        CHECKF(gap >= (8 << k), "%s: node %u: retry %d came %d frames after the last, want "
               ">= %d", what, node, k, gap, 8 << k);
    }
}

/* ---------- EIO ---------- */

/* HLOD_ERR_IO on every read of two nodes: a depth-1 node of block 1 and a
 * leaf of block 2.  Both are retried with backoff and end bad; their
 * parents stand in; blocks 0 and 3 stream to full detail. */
static void eio_always(void)
{
    logrec *lg = logrec_new();
    faults *fx = faults_new();
    fixture_opts o = city_opts();
    hlod_store *s = open_fixture("eio.hlod", &o, NULL);
    uint32_t a = child(s, 1, 2), b = child(s, child(s, 2, 1), 3);
    fx->plan[a] = fx->plan[b] = PLAN_EIO_ALWAYS;
    hlod_engine *e = start_engine(s, fx, lg);
    hlod_camera cam;
    whole_city(&cam);
    tally t = {0};
    hlod_frame_stats st;
    run_frames(e, &cam, 320, fx, &t, &st);

    check_no_stall("eio", &t);
    const uint32_t bad[2] = {a, b};
    for (int k = 0; k < 2; k++) {
        uint32_t i = bad[k];
        CHECKF(hlod_engine_node_state(e, i) == HLOD_NODE_BAD, "node %u state %d", i,
               hlod_engine_node_state(e, i));
        check_backoff(fx, i, "eio");
        check_logged_once(lg, i, 1, "eio");
    }
    CHECK(hlod_engine_node_drawn(e, 1));               /* a's parent */
    CHECK(hlod_engine_node_drawn(e, child(s, 2, 1)));  /* b's parent */
    check_bad_covered(e, s, "eio");
    long injected = atomic_load(&fx->injected);
    CHECKF(t.load_failures == (uint64_t)injected, "%llu failures counted, %ld injected",
           (unsigned long long)t.load_failures, injected);
    CHECK(t.bad_nodes == 2);
    CHECK(block_full_detail(e, s, 0) && block_full_detail(e, s, 3));
    /* b's siblings loaded: only b is missing below its parent */
    for (uint32_t k = 0; k < 3; k++)
        CHECK(hlod_engine_node_state(e, child(s, child(s, 2, 1), k)) == HLOD_NODE_RESIDENT);
    printf("REPORT faults kind=eio injected=%ld frames=%d bad=%u worst_frame_ms=%.2f\n",
           injected, t.frames, t.bad_nodes, t.worst_ms);
    hlod_engine_destroy(e);
    hlod_store_close(s);
    free(fx);
    logrec_free(lg);
}

/* HLOD_ERR_IO on the first 2 tries of three nodes: each loads on its third
 * try after backoffs of 16 and 32 frames, is counted twice in
 * load_failures, logged once, and the scene ends at full detail. */
static void eio_first_tries(void)
{
    logrec *lg = logrec_new();
    faults *fx = faults_new();
    fixture_opts o = city_opts();
    hlod_store *s = open_fixture("eio2.hlod", &o, NULL);
    uint32_t nodes[3] = {child(s, 0, 0), child(s, 3, 3), child(s, child(s, 1, 1), 2)};
    fx->first_k = 2;
    for (int k = 0; k < 3; k++)
        fx->plan[nodes[k]] = PLAN_EIO_FIRST_K;
    hlod_engine *e = start_engine(s, fx, lg);
    hlod_camera cam;
    whole_city(&cam);
    tally t = {0};
    run_frames(e, &cam, 200, fx, &t, NULL);

    check_no_stall("eio first tries", &t);
    for (int k = 0; k < 3; k++) {
        uint32_t i = nodes[k];
        CHECKF(atomic_load(&fx->failed[i]) == 2 && atomic_load(&fx->attempts[i]) == 3,
               "node %u: %d failures in %d attempts", i, atomic_load(&fx->failed[i]),
               atomic_load(&fx->attempts[i]));
        int gap = atomic_load(&fx->fail_frame[i][1]) - atomic_load(&fx->fail_frame[i][0]);
        CHECKF(gap >= 16, "node %u retried after %d frames", i, gap);
        CHECK(hlod_engine_node_state(e, i) == HLOD_NODE_RESIDENT);
        check_logged_once(lg, i, 0, "eio first tries");
    }
    CHECK(t.load_failures == 6 && t.bad_nodes == 0);
    for (uint32_t b = 0; b < 4; b++)
        CHECKF(block_full_detail(e, s, b), "block %u not at full detail", b);
    printf("REPORT faults kind=eio_transient injected=%ld frames=%d bad=%u recovered=3\n",
           atomic_load(&fx->injected), t.frames, t.bad_nodes);
    hlod_engine_destroy(e);
    hlod_store_close(s);
    free(fx);
    logrec_free(lg);
}

/* ---------- pread interposition: short reads, EINTR, EIO ---------- */

typedef struct disk {
    uint64_t rng;               /* loader thread only (or the test thread when
                                   no engine runs) */
    int shorten;                /* return a random prefix of what was asked */
    int eintr_every;            /* every n-th call fails with EINTR (0: never) */
    uint64_t eio_lo, eio_hi;    /* reads touching [lo, hi) fail with EIO */
    int overlong;               /* claim one byte more than asked */
    atomic_long calls, short_reads, eintrs, eios;
} disk;

static uint64_t disk_rand(disk *d)
{
    d->rng ^= d->rng << 13;
    d->rng ^= d->rng >> 7;
    d->rng ^= d->rng << 17;
    return d->rng;
}

/* called from the reading thread, in place of pread */
static ssize_t disk_pread(void *user, int fd, void *buf, size_t n, off_t off)
{
    disk *d = user;
    long call = atomic_fetch_add(&d->calls, 1) + 1;
    if (d->eintr_every && call % d->eintr_every == 0) {
        atomic_fetch_add(&d->eintrs, 1);
        errno = EINTR;
        return -1;
    }
    if ((uint64_t)off < d->eio_hi && (uint64_t)off + n > d->eio_lo) {
        atomic_fetch_add(&d->eios, 1);
        errno = EIO;
        return -1;
    }
    size_t want = n;
    if (d->shorten && n > 1) {
        want = 1 + (size_t)(disk_rand(d) % n);
        if (want < n)
            atomic_fetch_add(&d->short_reads, 1);
    }
    ssize_t k = pread(fd, buf, want, off);
    if (d->overlong && k > 0)
        k++;
    return k;
}

/* The reader alone: every payload read through a disk that returns random
 * short counts and EINTR equals the plain read; EIO, a read past the end and
 * an over-long count are HLOD_ERR_IO. */
static void reader_short_reads(void)
{
    fixture_opts o = city_opts();
    o.textured = 1;
    hlod_store *s = open_fixture("short.hlod", &o, NULL);
    uint32_t n = hlod_store_node_count(s);
    disk *d = calloc(1, sizeof *d);
    d->rng = 0x2545f4914f6cdd1dull;
    d->shorten = 1;
    d->eintr_every = 5;
    const size_t chunks[3] = {7, 256, 1 << 20};
    int same = 0;
    for (uint32_t i = 0; i < n; i++) {
        hlod_store_payload ref, got;
        hlod_store_set_pread(s, NULL, NULL);
        CHECK(hlod_store_read_node(s, i, 0, &ref) == HLOD_OK);
        hlod_store_set_pread(s, disk_pread, d);
        /* a step reads all it may: short reads are continued inside it */
        hlod_store_read rd;
        int complete = 0;
        CHECK(hlod_store_read_begin(s, i, &rd) == HLOD_OK);
        CHECK(hlod_store_read_step(&rd, 100, &complete) == HLOD_OK);
        CHECK(rd.done == (rd.size < 100 ? rd.size : 100));
        hlod_store_read_cancel(&rd);
        CHECK(hlod_store_read_node(s, i, chunks[i % 3], &got) == HLOD_OK);
        same += ref.bytes == got.bytes && memcmp(ref.memory, got.memory, ref.bytes) == 0;
        hlod_store_payload_free(&ref);
        hlod_store_payload_free(&got);
    }
    CHECKF(same == (int)n, "%d of %u payloads identical", same, n);
    CHECK(atomic_load(&d->short_reads) > n && atomic_load(&d->eintrs) > 0);

    /* EIO from the disk */
    const hlod_store_node *nd = hlod_store_nodes(s);
    hlod_store_payload p;
    d->shorten = 0;
    d->eintr_every = 0;
    d->eio_lo = nd[5].payload_offset + 10;
    d->eio_hi = d->eio_lo + 1;
    CHECK(hlod_store_read_node(s, 5, 0, &p) == HLOD_ERR_IO && p.memory == NULL);
    CHECK(hlod_store_read_node(s, 6, 0, &p) == HLOD_OK);
    hlod_store_payload_free(&p);
    /* a disk that claims more than it was asked for */
    d->eio_lo = d->eio_hi = 0;
    d->overlong = 1;
    CHECK(hlod_store_read_node(s, 5, 0, &p) == HLOD_ERR_IO);
    d->overlong = 0;
    hlod_store_set_pread(s, NULL, NULL);
    CHECK(hlod_store_read_node(s, 5, 0, &p) == HLOD_OK);
    hlod_store_payload_free(&p);
    printf("REPORT faults kind=short_read_unit injected=%ld eintr=%ld payloads=%u\n",
           atomic_load(&d->short_reads), atomic_load(&d->eintrs), n);
    free(d);
    hlod_store_close(s);
}

/* The engine over a disk that returns short counts and EINTR everywhere,
 * and EIO for one node: every other node loads (short reads are not
 * failures), the EIO node is retried with backoff and ends bad. */
static void engine_short_reads_and_eio(void)
{
    logrec *lg = logrec_new();
    faults *fx = faults_new();
    fixture_opts o = city_opts();
    o.textured = 1;
    hlod_store *s = open_fixture("short-engine.hlod", &o, NULL);
    uint32_t bad = child(s, 2, 2);
    disk *d = calloc(1, sizeof *d);
    d->rng = 0x9e3779b97f4a7c15ull;
    d->shorten = 1;
    d->eintr_every = 7;
    d->eio_lo = hlod_store_nodes(s)[bad].payload_offset;
    d->eio_hi = d->eio_lo + hlod_store_nodes(s)[bad].payload_size;
    hlod_store_set_pread(s, disk_pread, d);  /* before the engine starts reading */
    hlod_engine *e = start_engine(s, fx, lg);
    hlod_camera cam;
    whole_city(&cam);
    tally t = {0};
    run_frames(e, &cam, 320, fx, &t, NULL);

    check_no_stall("short reads", &t);
    CHECK(hlod_engine_node_state(e, bad) == HLOD_NODE_BAD);
    CHECKF(atomic_load(&fx->attempts[bad]) == 4, "node %u: %d attempts", bad,
           atomic_load(&fx->attempts[bad]));
    CHECK(atomic_load(&d->eios) == 4);
    CHECK(t.load_failures == 4 && t.bad_nodes == 1);
    check_logged_once(lg, bad, 1, "pread eio");
    check_bad_covered(e, s, "short reads");
    CHECK(hlod_engine_node_drawn(e, 2));
    for (uint32_t b = 0; b < 4; b++)
        if (b != 2)
            CHECKF(block_full_detail(e, s, b), "block %u not at full detail", b);
    CHECK(atomic_load(&d->short_reads) > 50);
    printf("REPORT faults kind=short_read injected=%ld eintr=%ld frames=%d failures=0\n",
           atomic_load(&d->short_reads), atomic_load(&d->eintrs), t.frames);
    printf("REPORT faults kind=pread_eio injected=%ld frames=%d bad=%u\n",
           atomic_load(&d->eios), t.frames, t.bad_nodes);
    hlod_engine_destroy(e);
    hlod_store_close(s);
    free(d);
    free(fx);
    logrec_free(lg);
}

/* ---------- slow disk ---------- */

/* Reads 10x slower than the base simulated disk: every read step takes 1
 * frame on the base disk and 10 on the slow one.  Both engines stream the
 * city from a cold start side by side in one run, a frame of each in turn,
 * and the disks' speeds are counted in frames: the slow city takes longer
 * to stream in, every frame stays fast, nothing fails. */
static void slow_reads(void)
{
    fixture_opts o = city_opts();
    hlod_store *s = open_fixture("slow.hlod", &o, NULL);
    const int step_frames[2] = {1, 10};
    logrec *lg[2];
    faults *fx[2];
    hlod_engine *e[2];
    tally t[2] = {{0}, {0}};
    int done[2] = {-1, -1};
    for (int k = 0; k < 2; k++) {
        lg[k] = logrec_new();
        fx[k] = faults_new();
        atomic_store(&fx[k]->step_frames, step_frames[k]);
        e[k] = start_engine(s, fx[k], lg[k]);
    }
    hlod_camera cam;
    whole_city(&cam);
    for (int f = 0; f < 20000 && done[1] < 0 && e[0] && e[1]; f++)
        for (int k = 0; k < 2; k++) {
            if (done[k] >= 0)
                continue;
            hlod_frame_stats st;
            run_frames(e[k], &cam, 1, fx[k], &t[k], &st);
            if (st.resident_nodes == hlod_store_node_count(s))
                done[k] = f + 1;
        }
    for (int k = 0; k < 2; k++) {
        CHECK(t[k].load_failures == 0 && t[k].bad_nodes == 0);
        for (uint32_t b = 0; b < 4; b++)
            CHECK(done[k] < 0 || block_full_detail(e[k], s, b));
        atomic_store(&fx[k]->released, 1);
        hlod_engine_destroy(e[k]);
    }
    check_no_stall("base disk", &t[0]);
    check_no_stall("slow disk", &t[1]);
    CHECKF(done[0] > 0 && done[1] > 0, "full detail after %d / %d frames", done[0], done[1]);
    CHECKF(done[1] > 2 * done[0], "10x slower disk: %d frames vs %d", done[1], done[0]);
    long n_slow = atomic_load(&fx[1]->injected);
    fprintf(stderr, "  full detail after %d frames (1 frame/step) and %d frames (10 frames/step); "
            "worst frame() %.2f ms\n", done[0], done[1], t[1].worst_ms);
    printf("REPORT faults kind=slow_read injected=%ld frames=%d base_frames=%d "
           "worst_frame_ms=%.2f\n", n_slow, t[1].frames, done[0], t[1].worst_ms);
    for (int k = 0; k < 2; k++) {
        free(fx[k]);
        logrec_free(lg[k]);
    }
    hlod_store_close(s);
}

/* ---------- bit flips ---------- */

static void flip_bit(const char *path, uint64_t offset, int bit)
{
    int fd = open(path, O_RDWR);
    CHECK(fd >= 0);
    uint8_t c = 0;
    CHECK(pread(fd, &c, 1, (off_t)offset) == 1);
    c ^= (uint8_t)(1u << bit);
    CHECK(pwrite(fd, &c, 1, (off_t)offset) == 1);
    close(fd);
}

/* Bits flipped in the file after the store was opened (its node table and
 * checksums were read and verified): the payload checksum catches them at
 * once, no retry; a node resident before the flip keeps drawing; a flip in
 * the padding between payloads changes nothing. */
static void bit_flips(void)
{
    logrec *lg = logrec_new();
    faults *fx = faults_new();
    fixture_opts o = city_opts();
    char path[512];
    tmp_path("flips.hlod", path, sizeof path);
    hlod_store *s = open_fixture("flips.hlod", &o, NULL);
    const hlod_store_node *n = hlod_store_nodes(s);
    hlod_engine *e = start_engine(s, fx, lg); /* roots are read now */
    uint32_t flipped[3] = {child(s, 1, 0), child(s, child(s, 2, 3), 1), child(s, 3, 2)};
    flip_bit(path, n[flipped[0]].payload_offset + 70, 3);                  /* positions */
    flip_bit(path, n[flipped[1]].payload_offset + n[flipped[1]].payload_size - 1, 7);
    flip_bit(path, n[flipped[2]].payload_offset + 5, 0);                   /* header flags */
    flip_bit(path, n[0].payload_offset + 100, 1);                          /* resident root */
    uint32_t pad = child(s, 0, 1);
    flip_bit(path, n[pad].payload_offset + n[pad].payload_size + 3, 4);    /* padding */
    hlod_camera cam;
    whole_city(&cam);
    tally t = {0};
    run_frames(e, &cam, 150, fx, &t, NULL);

    check_no_stall("bit flips", &t);
    for (int k = 0; k < 3; k++) {
        uint32_t i = flipped[k];
        CHECKF(hlod_engine_node_state(e, i) == HLOD_NODE_BAD, "node %u state %d", i,
               hlod_engine_node_state(e, i));
        CHECKF(atomic_load(&fx->attempts[i]) == 1, "node %u read %d times", i,
               atomic_load(&fx->attempts[i]));
        check_logged_once(lg, i, 1, "bit flips");
    }
    check_bad_covered(e, s, "bit flips");
    CHECK(t.load_failures == 3 && t.bad_nodes == 3);
    CHECK(hlod_engine_node_state(e, 0) == HLOD_NODE_RESIDENT);
    CHECK(hlod_engine_node_state(e, pad) == HLOD_NODE_RESIDENT);
    CHECK(block_full_detail(e, s, 0));
    printf("REPORT faults kind=bit_flip injected=3 frames=%d bad=%u\n", t.frames, t.bad_nodes);
    hlod_engine_destroy(e);
    hlod_store_close(s);
    free(fx);
    logrec_free(lg);
}

/* ---------- truncation ---------- */

/* The store file is cut short while the engine runs: a city of 6 blocks,
 * blocks 0 and 1 resident (seen up close first) keep drawing at full
 * detail; the nodes whose payloads now lie past the end (blocks 3-5 and
 * some of 2; payloads are in build order, block after block) fail with
 * transient I/O errors when asked for, are retried with backoff and end
 * bad, their parents drawn instead. */
static void truncated_while_running(void)
{
    logrec *lg = logrec_new();
    faults *fx = faults_new();
    fixture_opts o = city_opts();
    o.roots = 6;
    char path[512];
    tmp_path("truncate.hlod", path, sizeof path);
    hlod_logger store_lg = {log_store, lg};
    hlod_store *s = open_fixture("truncate.hlod", &o, &store_lg);
    const hlod_store_node *n = hlod_store_nodes(s);
    uint32_t count = hlod_store_node_count(s);
    hlod_engine *e = start_engine(s, fx, lg);

    /* phase 1: blocks 0 and 1 up close, until they are at full detail */
    hlod_camera cam;
    look(&cam, 105, -90, 120, 105, 50, 0);
    tally t1 = {0};
    for (int k = 0; k < 40 && !(block_full_detail(e, s, 0) && block_full_detail(e, s, 1)); k++)
        run_frames(e, &cam, 10, fx, &t1, NULL);
    CHECK(block_full_detail(e, s, 0) && block_full_detail(e, s, 1));
    /* no read in flight when the file is cut: one that failed after the
     * cut was counted in phase 2 without an attempt there (37 failures
     * for 9 nodes once, under TSan beside a build) */
    double t_idle = now_ms();
    while (!hlod_inspect_loader_idle(e) && now_ms() - t_idle < 10000)
        sleep_us(500);
    CHECK(hlod_inspect_loader_idle(e));

    /* cut the file where the first payload not resident starts */
    uint64_t cut = UINT64_MAX;
    for (uint32_t i = 0; i < count; i++)
        if (hlod_engine_node_state(e, i) != HLOD_NODE_RESIDENT && n[i].payload_offset < cut)
            cut = n[i].payload_offset;
    CHECK(cut != UINT64_MAX);
    uint8_t cut_off[MAXN] = {0};
    int lost = 0;
    for (uint32_t i = 0; i < count; i++)
        if (n[i].payload_offset + n[i].payload_size > cut) {
            CHECKF(n[i].block >= 2, "node %u of block %u lies past the cut", i, n[i].block);
            cut_off[i] = hlod_engine_node_state(e, i) != HLOD_NODE_RESIDENT;
            lost += cut_off[i];
        }
    int fd = open(path, O_RDWR);
    CHECK(fd >= 0 && ftruncate(fd, (off_t)cut) == 0);
    close(fd);

    /* phase 2: the whole city; attempts are counted from here */
    for (uint32_t i = 0; i < count; i++)
        atomic_store(&fx->attempts[i], 0);
    look(&cam, 325, -250, 380, 325, 50, 0);
    tally t2 = {0};
    int full01 = 0;
    for (int k = 0; k < 35; k++) {
        run_frames(e, &cam, 10, fx, &t2, NULL);
        full01 += block_full_detail(e, s, 0) && block_full_detail(e, s, 1);
    }
    check_no_stall("truncated", &t2);
    CHECKF(full01 == 35, "blocks 0-1 at full detail in %d of 35 samples", full01);
    int bad = 0, wanted = 0;
    for (uint32_t i = 0; i < count; i++) {
        if (!cut_off[i] || atomic_load(&fx->attempts[i]) == 0)
            continue; /* never asked for: below a node that is drawn in its place */
        wanted++;
        bad += hlod_engine_node_state(e, i) == HLOD_NODE_BAD;
        CHECKF(atomic_load(&fx->attempts[i]) == 4, "node %u: %d attempts", i,
               atomic_load(&fx->attempts[i]));
        check_logged_once(lg, i, 1, "truncated");
    }
    if (getenv("HLOD_TEST_VERBOSE"))
        for (uint32_t i = 0; i < count; i++)
            fprintf(stderr, "  node %u block %u depth %u off %llu: state %d drawn %d cut %d "
                    "attempts %d\n", i, n[i].block, n[i].depth,
                    (unsigned long long)n[i].payload_offset, hlod_engine_node_state(e, i),
                    hlod_engine_node_drawn(e, i), cut_off[i], atomic_load(&fx->attempts[i]));
    CHECKF(bad == wanted && wanted >= 8, "%d of %d nodes past the cut ended bad", bad, wanted);
    CHECKF(t2.load_failures == 4u * (uint64_t)wanted, "%llu failures for %d nodes",
           (unsigned long long)t2.load_failures, wanted);
    CHECK(t2.bad_nodes == (uint32_t)bad);
    for (uint32_t r = 3; r < 6; r++)
        CHECKF(hlod_engine_node_drawn(e, r), "root %u not drawn", r);
    check_bad_covered(e, s, "truncated");
    fprintf(stderr, "  cut at %llu bytes: %d payloads lost, %d wanted and bad; the store "
            "reader logged %d read errors\n", (unsigned long long)cut, lost, wanted,
            logged(lg, &lg->store_errors));
    printf("REPORT faults kind=truncate injected=%d frames=%d bad=%u store_log_lines=%d\n",
           wanted, t2.frames, t2.bad_nodes, logged(lg, &lg->store_errors));
    hlod_engine_destroy(e);
    hlod_store_close(s);
    free(fx);
    logrec_free(lg);
}

/* Control: the same runs without faults reach full detail with no failure
 * and nothing logged. */
static void control_no_faults(void)
{
    logrec *lg = logrec_new();
    faults *fx = faults_new();
    fixture_opts o = city_opts();
    hlod_store *s = open_fixture("control.hlod", &o, NULL);
    hlod_engine *e = start_engine(s, fx, lg);
    hlod_camera cam;
    whole_city(&cam);
    tally t = {0};
    run_frames(e, &cam, 120, fx, &t, NULL);
    check_no_stall("control", &t);
    for (uint32_t b = 0; b < 4; b++)
        CHECKF(block_full_detail(e, s, b), "block %u not at full detail", b);
    CHECK(t.load_failures == 0 && t.bad_nodes == 0 && logged(lg, &lg->other) == 0);
    hlod_engine_destroy(e);
    hlod_store_close(s);
    free(fx);
    logrec_free(lg);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod-test-faults-XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    alarm(540); /* a hang fails the test (SIGALRM) before ctest's timeout */
    RUN(control_no_faults);
    RUN(eio_always);
    RUN(eio_first_tries);
    RUN(reader_short_reads);
    RUN(engine_short_reads_and_eio);
    RUN(slow_reads);
    RUN(bit_flips);
    RUN(truncated_while_running);
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", g_dir);
    return check_done();
}
