/*
 * test_soak.c - soak and load (issue 6, "Soak and load").
 *
 * A threaded engine over a synthetic city of 8 blocks (2728 nodes) with a
 * tiny memory budget (5% of the store's payload bytes, at least the roots'
 * bytes), a time_model machine instead of GL, and a camera teleported at
 * random across the city and far outside it (up to 1e7 units away), with
 * invalid input mixed in: NaN and infinite positions, a NaN in the view or
 * projection matrix, an empty viewport, NaN, infinite and negative dt.
 *
 * Asserted: invalid input returns HLOD_ERR_INVALID_ARG with zeroed stats
 * (nothing drawn) and is logged; resident bytes (and resident plus the
 * bytes reserved for reads in flight) never exceed the budget; the render
 * thread never waits and frame() stays fast; RSS is flat after warm-up
 * (compared at 25% and 100% of the run; not asserted under a sanitizer,
 * whose allocator quarantines freed memory, but LSan checks leaks there);
 * and it streams (loads and evictions all along).  A second test runs two
 * such engines over one store, each in its own thread.
 *
 * Quick by default (60000 frames, about 10 s); HLOD_SOAK_FRAMES=100000 is the long
 * variant.  Under a sanitizer (ASan or TSan) the default is a quarter of the frames.
 * Prints "REPORT soak ..." for tests/reliability_report.sh.
 */
#define _GNU_SOURCE /* RUSAGE_THREAD */
#include "check.h"
#include "inspect.h"
#include "engine_check.h"
#include "store_fixture.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define SANITIZED 1
#endif
#endif
#ifndef SANITIZED
#define SANITIZED 0
#endif
#define TSAN HLOD_TEST_TSAN

#define DEFAULT_FRAMES 60000
#define FRAME_MS 20.0
/* The CPU time a frame that kept the CPU may take.  Under the sanitizers
 * their allocator has its own spikes (quarantine recycling, shadow pages
 * faulted in): single frames of 60,000 took 28.8 ms and, with a build
 * running beside the test, 45.4 ms of CPU time under ASan, never blocked
 * nor preempted, where the one-engine run's worst is about 10 ms.  The
 * bound there catches a frame that does a stall's or a scan's work; the
 * frame time itself is judged in the plain build (20 ms) and by
 * hlod-bench. */
#define FRAME_CPU_MS (SANITIZED ? 5 * FRAME_MS : FRAME_MS)
#define RSS_TOLERANCE_KB 2048   /* allocator noise allowed after warm-up */

static char g_dir[256];

/* Resident set size in KiB (/proc/self/statm, second field, in pages). */
static long rss_kb(void)
{
    FILE *fp = fopen("/proc/self/statm", "r");
    long size = 0, resident = 0;
    if (!fp)
        return -1;
    if (fscanf(fp, "%ld %ld", &size, &resident) != 2)
        resident = -1;
    fclose(fp);
    return resident < 0 ? -1 : resident * (sysconf(_SC_PAGESIZE) / 1024);
}

static int soak_frames(void)
{
    const char *s = getenv("HLOD_SOAK_FRAMES");
    /* under a sanitizer a quarter: its checks are per access, not per
     * hour, and the plain build runs the long soak */
    int n = s ? atoi(s) : (SANITIZED ? DEFAULT_FRAMES / 4 : DEFAULT_FRAMES);
    return n > 100 ? n : 100;
}

/* ---- the run ---- */

typedef struct counting_log {
    atomic_long errors, warnings, other;
} counting_log;

/* called from the render and the loader thread */
static void log_count(void *user, hlod_log_level level, const char *msg)
{
    counting_log *c = user;
    (void)msg;
    if (level == HLOD_LOG_ERROR)
        atomic_fetch_add(&c->errors, 1);
    else if (level == HLOD_LOG_WARN)
        atomic_fetch_add(&c->warnings, 1);
    else
        atomic_fetch_add(&c->other, 1);
}

typedef struct soak {
    /* in */
    const hlod_store *store;
    int frames;
    uint64_t seed;
    int measure_rss;
    /* out */
    int ok;                         /* engine created */
    int frames_ok, invalid, invalid_ok;
    uint64_t loads, evictions, over_budget, budget, peak_resident, peak_used;
    uint32_t render_waits, bad_nodes;
    uint64_t load_failures;
    int slow_frames;                /* over FRAME_MS, of the frames that kept the CPU */
    int nonfinite, drew_outside;
    int blocked_frames;             /* frame() blocked (voluntary switch) */
    int paged_frames;               /* ... in a major page fault (render_paged) */
    uint32_t render_paged;
    double worst_blocked_ms;        /* the longest of those frames */
    int judged;                     /* frames that kept the CPU (cpu_span.h) */
    int unexplained_slow;           /* frames that kept the CPU, never blocked and took
                                       over FRAME_MS of CPU time */
    double worst_ms;                /* of the frames that kept the CPU */
    long rss_warm_kb, rss_end_kb;
    long logged_errors;
} soak;

static double frand(uint64_t *s)
{
    *s ^= *s << 13;
    *s ^= *s >> 7;
    *s ^= *s << 17;
    return (double)(*s >> 11) / 9007199254740992.0;
}

static int stats_zero(const hlod_frame_stats *s)
{
    static const hlod_frame_stats zero;
    return memcmp(s, &zero, sizeof zero) == 0;
}

/* frame() refuses the input: HLOD_ERR_INVALID_ARG, stats zeroed (nothing
 * drawn). */
static int stats_zero_after(hlod_engine *e, const hlod_camera *cam, double dt,
                            hlod_frame_stats *st)
{
    return hlod_engine_frame(e, cam, dt, st) == HLOD_ERR_INVALID_ARG && stats_zero(st);
}

/* A teleport: mostly over and around the city (x in [0, 870], y in [0,
 * 100]), sometimes far outside it looking anywhere.  Returns 1 when the
 * city cannot be in view (far away and looking away from it). */
static int teleport(hlod_camera *cam, uint64_t *rng, const double lo[3], const double hi[3])
{
    double eye[3], at[3], up[3] = {0, 0, 1};
    double cx = 0.5 * (lo[0] + hi[0]), cy = 0.5 * (lo[1] + hi[1]);
    double u = frand(rng);
    int away = 0;
    if (u < 0.8) {
        eye[0] = lo[0] - 200 + (hi[0] - lo[0] + 400) * frand(rng);
        eye[1] = lo[1] - 300 + (hi[1] - lo[1] + 600) * frand(rng);
        eye[2] = 0.5 + 400 * frand(rng) * frand(rng);
        at[0] = lo[0] + (hi[0] - lo[0]) * frand(rng);
        at[1] = lo[1] + (hi[1] - lo[1]) * frand(rng);
        at[2] = 0;
    } else {
        /* 1e3 .. 1e7 units away, toward the city or away from it */
        double dist = pow(10, 3 + 4 * frand(rng)), ang = 2 * M_PI * frand(rng);
        eye[0] = cx + dist * cos(ang);
        eye[1] = cy + dist * sin(ang);
        eye[2] = dist * 0.3 * frand(rng);
        away = frand(rng) < 0.5;
        double sgn = away ? 2 : 0; /* look-at beyond the eye, away from the city */
        at[0] = cx + (eye[0] - cx) * sgn;
        at[1] = cy + (eye[1] - cy) * sgn;
        at[2] = away ? eye[2] + 1 : 0;
        away = away && dist > 1e4;
    }
    if (hlod_camera_look_at(cam, eye, at, up, 60, 0.5, 1e5, 1280, 720) != HLOD_OK) {
        double e2[3] = {cx, cy - 100, 50}, a2[3] = {cx, cy, 0};
        hlod_camera_look_at(cam, e2, a2, up, 60, 0.5, 1e5, 1280, 720);
        away = 0;
    }
    return away;
}

/* One of the invalid inputs: a copy of cam with a bad field, a bad dt, or
 * what hlod_camera_look_at makes of a non-finite eye.  Returns 0 when
 * look_at accepted that eye. */
static int invalid_input(const hlod_camera *cam, uint64_t *rng, hlod_camera *bad, double *dt)
{
    *bad = *cam;
    *dt = 1.0 / 30;
    switch ((int)(frand(rng) * 9)) {
    case 0: bad->position[(int)(frand(rng) * 3)] = NAN; break;
    case 1: bad->position[(int)(frand(rng) * 3)] = frand(rng) < 0.5 ? INFINITY : -INFINITY; break;
    case 2: bad->view[(int)(frand(rng) * 16)] = NAN; break;
    case 3: bad->proj[(int)(frand(rng) * 16)] = INFINITY; break;
    case 4: bad->width = 0; break;
    case 5: *dt = NAN; break;
    case 6: *dt = INFINITY; break;
    case 7: *dt = -1.0 / 30; break;
    default: {
        /* through the API: look_at refuses a NaN or infinite eye and zeroes
         * the camera, which frame() refuses in turn */
        double eye[3] = {cam->position[0], NAN, INFINITY}, at[3] = {0, 0, 0}, up[3] = {0, 0, 1};
        return hlod_camera_look_at(bad, eye, at, up, 60, 0.5, 1e5, 1280, 720) ==
               HLOD_ERR_INVALID_ARG;
    }
    }
    return 1;
}

/* called from the test thread or a twin thread: one engine's soak */
static void *soak_main(void *arg)
{
    soak *k = arg;
    const hlod_store *s = k->store;
    const hlod_store_header *h = hlod_store_get_header(s);
    uint64_t roots = 0;
    for (uint32_t i = 0; i < hlod_store_root_count(s); i++)
        roots += hlod_store_nodes(s)[i].payload_size;
    k->budget = h->payload_bytes / 20 > roots ? h->payload_bytes / 20 : roots;

    counting_log lg;
    atomic_init(&lg.errors, 0);
    atomic_init(&lg.warnings, 0);
    atomic_init(&lg.other, 0);
    fixed_machine m = {3, 0.002};
    hlod_engine_desc d = {0};
    d.target_ms = 20;
    d.time_model = fixed_machine_time;
    d.time_model_user = &m;
    d.memory_budget_bytes = k->budget;
    d.logger.func = log_count;
    d.logger.user_data = &lg;
    hlod_engine *e = NULL;
    if (hlod_engine_create(s, &d, &e) != HLOD_OK)
        return NULL;
    k->ok = 1;

    uint64_t rng = k->seed;
    hlod_camera cam;
    int away = teleport(&cam, &rng, h->bbox_min, h->bbox_max);
    for (int f = 0; f < k->frames; f++) {
        if (k->measure_rss && f == k->frames / 4)
            k->rss_warm_kb = rss_kb();
        double u = frand(&rng);
        if (u < 0.03) {
            hlod_camera bad;
            double dt;
            int look_at_ok = invalid_input(&cam, &rng, &bad, &dt);
            hlod_frame_stats st;
            memset(&st, 0xab, sizeof st);
            k->invalid++;
            k->invalid_ok += look_at_ok && stats_zero_after(e, &bad, dt, &st);
            continue;
        }
        if (u < 0.25)
            away = teleport(&cam, &rng, h->bbox_min, h->bbox_max);
        hlod_frame_stats st;
        cpu_span sp;
        span_start(&sp);
        hlod_result r = hlod_engine_frame(e, &cam, 1.0 / 30, &st);
        span_stop(&sp);
        double dt = sp.wall_ms;
        if (r != HLOD_OK)
            continue;
        /* the engine counts the render thread's sleeps itself
         * (render_waits); the frame's time is judged only where the
         * scheduler did not preempt it (cpu_span.h) */
        if (span_kept_cpu(&sp)) {
            k->judged++;
            /* the frame's own work: its CPU time (a frame that ran for
             * only part of its wall time lost the rest to the host, which
             * no switch count shows; seen once under ASan: over 20 ms of
             * wall time, no switch) */
            k->unexplained_slow += sp.cpu_ms > FRAME_CPU_MS && sp.vol == 0;
            k->slow_frames += dt > FRAME_MS;
            if (dt > k->worst_ms)
                k->worst_ms = dt;
        }
        /* a sleep in a major page fault is the system paging the process
         * back in (render_paged), bounded apart */
        if (sp.vol && sp.maj) {
            k->paged_frames++;
            fprintf(stderr, "  frame %ld slept %ld times in %ld major faults (%.2f ms)\n",
                    (long)k->frames_ok, sp.vol, sp.maj, dt);
        } else if (sp.vol) {
            k->blocked_frames++;
            if (dt > k->worst_blocked_ms)
                k->worst_blocked_ms = dt;
        }
        k->frames_ok++;
        k->loads += st.loads;
        k->evictions += st.evictions;
        k->render_waits += st.render_waits;
        k->render_paged += st.render_paged;
        k->load_failures += st.load_failures;
        k->bad_nodes = st.bad_nodes;
        k->nonfinite += !stats_finite(&st);
        k->drew_outside += away && st.nodes_drawn > 0;
        /* reserved_bytes is the engine's own (this thread's) field */
        uint64_t used = st.resident_bytes + hlod_inspect_reserved_bytes(e);
        k->over_budget += st.resident_bytes > k->budget || used > k->budget ||
                          st.resident_cost > (double)k->budget * (1 + 1e-9);
        if (st.resident_bytes > k->peak_resident)
            k->peak_resident = st.resident_bytes;
        if (used > k->peak_used)
            k->peak_used = used;
        if (f % 8 == 0)
            sleep_us(100); /* frames take time: the loader gets the CPU */
    }
    if (k->measure_rss)
        k->rss_end_kb = rss_kb();
    hlod_engine_destroy(e);
    k->logged_errors = atomic_load(&lg.errors);
    return NULL;
}

static void check_soak(const soak *k, const char *what)
{
    int allowed = k->frames_ok / 200 > 3 ? k->frames_ok / 200 : 3;
    CHECKF(k->ok, "%s: engine not created", what);
    CHECKF(k->invalid_ok == k->invalid && k->invalid > 0, "%s: %d of %d invalid inputs "
           "rejected with zeroed stats", what, k->invalid_ok, k->invalid);
    CHECKF(k->logged_errors >= k->invalid, "%s: %ld errors logged for %d invalid inputs", what,
           k->logged_errors, k->invalid);
    CHECKF(k->over_budget == 0, "%s: %llu frames over the budget", what,
           (unsigned long long)k->over_budget);
    /* the render thread never slept: counted by the engine, and seen
     * here as a voluntary switch in frame() (no GL here; the logger only
     * counts) */
    if (span_judges_waits() && !SANITIZED)
        CHECKF(k->render_waits == 0 && k->blocked_frames == 0,
               "%s: the render thread slept %u times; %d frames blocked, the longest %.2f ms",
               what, k->render_waits, k->blocked_frames, k->worst_blocked_ms);
    /* sleeps in major page faults: the host paging the process back in
     * (these machines run DAMON's pageout of cold pages), not the engine;
     * as rare as the host's other spikes (cpu_span.h) */
    CHECKF(k->paged_frames <= 1 + k->frames_ok / 30000 &&
               k->render_paged <= (uint32_t)(2 * (1 + k->frames_ok / 30000)),
           "%s: %d frames slept in major page faults (%u sleeps)", what, k->paged_frames,
           k->render_paged);
    /* ASan's allocator locks its central free lists and its quarantine;
     * a thread that finds them taken yields or sleeps, as long as the
     * holder takes (30 ms once, beside another build).  The render thread
     * allocates nothing in steady state (engine/sort.h: glibc's qsort
     * took a buffer each frame, and twin engines then blocked in a median
     * 7-10 of 3,750 frames each, up to 24); measured since: 0-1 of 3,750
     * frames per twin (40 twins), the plain build in none.  What is left
     * is the loader's allocations beside a first use on this thread.
     * The bound (tests/lib.sh's too): 1 + one frame in 200 (a 10 ms sleep
     * every 100th frame fails it). */
    if (span_judges_waits() && SANITIZED)
        CHECKF(k->blocked_frames <= 1 + k->frames_ok / 200 &&
                   k->render_waits <= (uint32_t)(1 + k->frames_ok / 100),
               "%s: the render thread slept %u times; %d frames blocked, the longest %.2f ms "
               "(the sanitizer's allocator is allowed 1 + one frame in 200)",
               what, k->render_waits, k->blocked_frames, k->worst_blocked_ms);
    CHECKF(span_judged_enough(k->judged, k->frames_ok),
           "%s: only %d of %d frames kept the CPU: too few to judge", what, k->judged,
           k->frames_ok);
    CHECKF(k->unexplained_slow <= span_host_spikes(k->frames_ok),
           "%s: %d frames over %.0f ms of CPU time, neither preempted nor blocked (%d allowed: "
           "cpu_span.h)", what, k->unexplained_slow, FRAME_CPU_MS,
           span_host_spikes(k->frames_ok));
    CHECKF(k->slow_frames <= allowed && k->worst_ms < 500, "%s: %d frames over %.0f ms, worst "
           "%.1f ms", what, k->slow_frames, FRAME_MS, k->worst_ms);
    CHECKF(k->nonfinite == 0, "%s: %d frames with non-finite stats", what, k->nonfinite);
    CHECKF(k->drew_outside == 0, "%s: %d frames looking away from the city drew something",
           what, k->drew_outside);
    CHECKF(k->load_failures == 0 && k->bad_nodes == 0, "%s: %llu load failures", what,
           (unsigned long long)k->load_failures);
    /* it streamed all along: the tiny budget forces evictions */
    CHECKF(k->loads > (uint64_t)k->frames / 50 && k->evictions > (uint64_t)k->frames / 100,
           "%s: %llu loads, %llu evictions in %d frames", what, (unsigned long long)k->loads,
           (unsigned long long)k->evictions, k->frames);
}

static hlod_store *g_store;

static void soak_one_engine(void)
{
    soak k = {0};
    k.store = g_store;
    k.frames = soak_frames();
    k.seed = 0x9e3779b97f4a7c15ull;
    k.measure_rss = 1;
    double t0 = now_ms();
    soak_main(&k);
    double secs = (now_ms() - t0) / 1e3;
    check_soak(&k, "soak");
    long drift = k.rss_end_kb - k.rss_warm_kb;
    fprintf(stderr, "  %d frames in %.1f s (%d invalid inputs rejected): %llu loads, %llu "
            "evictions, peak resident %llu of %llu bytes (with reads in flight %llu), worst "
            "frame() %.2f ms, RSS %ld KiB at 25%%, %ld KiB at the end (%+ld KiB)\n", k.frames,
            secs, k.invalid, (unsigned long long)k.loads, (unsigned long long)k.evictions,
            (unsigned long long)k.peak_resident, (unsigned long long)k.budget,
            (unsigned long long)k.peak_used, k.worst_ms, k.rss_warm_kb, k.rss_end_kb, drift);
    if (!SANITIZED)
        CHECKF(k.rss_warm_kb > 0 && drift <= RSS_TOLERANCE_KB, "RSS grew by %ld KiB after "
               "warm-up", drift);
    printf("REPORT soak engines=1 frames=%d invalid_rejected=%d loads=%llu evictions=%llu "
           "peak_resident=%llu peak_with_reads=%llu budget=%llu over_budget=%llu "
           "rss_warm_kb=%ld rss_end_kb=%ld rss_drift_kb=%ld rss_checked=%d "
           "worst_frame_ms=%.2f slow_frames=%d render_waits=%u preempted_frames=%u "
           "blocked_frames=%d worst_blocked_ms=%.2f paged_frames=%d seconds=%.1f\n", k.frames,
           k.invalid_ok, (unsigned long long)k.loads, (unsigned long long)k.evictions,
           (unsigned long long)k.peak_resident, (unsigned long long)k.peak_used,
           (unsigned long long)k.budget, (unsigned long long)k.over_budget, k.rss_warm_kb,
           k.rss_end_kb, drift, !SANITIZED, k.worst_ms, k.slow_frames, k.render_waits,
           (uint32_t)(k.frames_ok - k.judged), k.blocked_frames, k.worst_blocked_ms,
           k.paged_frames, secs);
    fprintf(stderr, "  render thread: slept %u times; blocked in %d frames (longest %.2f ms); "
            "%d of %d frames judged (not preempted)\n", k.render_waits, k.blocked_frames,
            k.worst_blocked_ms, k.judged, k.frames_ok);
}

/* Two engines over one store, each in its own thread, each with its own
 * camera: both stay within their budgets and correct. */
static void soak_two_engines(void)
{
    soak a = {0}, b = {0};
    a.store = b.store = g_store;
    a.frames = b.frames = soak_frames() / 4;
    a.seed = 0x2545f4914f6cdd1dull;
    b.seed = 0xd1b54a32d192ed03ull;
    pthread_t ta, tb;
    CHECK(pthread_create(&ta, NULL, soak_main, &a) == 0);
    CHECK(pthread_create(&tb, NULL, soak_main, &b) == 0);
    pthread_join(ta, NULL);
    pthread_join(tb, NULL);
    check_soak(&a, "twin a");
    check_soak(&b, "twin b");
    printf("REPORT soak engines=2 frames=%d invalid_rejected=%d loads=%llu "
           "peak_resident=%llu budget=%llu over_budget=%llu worst_frame_ms=%.2f\n",
           a.frames + b.frames, a.invalid_ok + b.invalid_ok,
           (unsigned long long)(a.loads + b.loads),
           (unsigned long long)(a.peak_resident > b.peak_resident ? a.peak_resident
                                                                  : b.peak_resident),
           (unsigned long long)a.budget, (unsigned long long)(a.over_budget + b.over_budget),
           a.worst_ms > b.worst_ms ? a.worst_ms : b.worst_ms);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod-test-soak-XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    char path[512];
    snprintf(path, sizeof path, "%s/soak.hlod", g_dir);
    fixture_opts o = {0};
    o.roots = 8;
    o.depth = 4;
    o.textured = 1;
    CHECK(fixture_write(path, &o, NULL) == HLOD_OK);
    CHECK(hlod_store_open(path, NULL, &g_store) == HLOD_OK);
    if (g_store) {
        RUN(soak_one_engine);
        RUN(soak_two_engines);
    }
    hlod_store_close(g_store);
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", g_dir);
    return check_done();
}
