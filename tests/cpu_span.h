/*
 * cpu_span.h - the one excuse a wall-clock bound in a test may take: the
 * scheduler preempted the thread.
 *
 * Whether the render thread waited is not a wall-clock question: the
 * engine counts the times it slept outside GL, synchronous reads and the
 * logger (hlod_frame_stats.render_waits, engine/common/sleeps.h), and a
 * test asserts that count is 0 in every frame, with no excuse.  Only under
 * ThreadSanitizer is it not judged (span_judges_waits): the runtime wraps
 * every sync operation, trylocks included, in internal mutexes that sleep.
 *
 * Tests that bound a frame's time on the wall clock run while ctest runs
 * other tests on the machine's two cores.  Such a bound judges only spans
 * the scheduler did not preempt (no involuntary context switch; under
 * ThreadSanitizer, no voluntary one either), and requires that a quarter
 * of the spans at least were judged (span_judged_enough).  A host that takes the vCPU away shows
 * no switch here (these VMs report no steal time): span_host_spikes allows
 * for it.  Include after defining _GNU_SOURCE (RUSAGE_THREAD).
 */
#ifndef HLOD_CPU_SPAN_H
#define HLOD_CPU_SPAN_H

#include <sys/resource.h>
#include <time.h>

#ifndef RUSAGE_THREAD
#error "cpu_span.h needs _GNU_SOURCE defined before the first include"
#endif

#if defined(__SANITIZE_THREAD__)
#define HLOD_TEST_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define HLOD_TEST_TSAN 1
#endif
#endif
#ifndef HLOD_TEST_TSAN
#define HLOD_TEST_TSAN 0
#endif

typedef struct cpu_span {
    double wall0, cpu0;
    long vol0, inv0, maj0;
    double wall_ms, cpu_ms; /* set by span_stop */
    long vol, inv;          /* voluntary and involuntary switches in the span */
    long maj;               /* major page faults in the span (a page read back in) */
} cpu_span;

static inline double span_clock_ms(clockid_t id)
{
    struct timespec ts;
    clock_gettime(id, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

static inline void span_start(cpu_span *s)
{
    struct rusage ru;
    getrusage(RUSAGE_THREAD, &ru);
    s->vol0 = ru.ru_nvcsw;
    s->inv0 = ru.ru_nivcsw;
    s->maj0 = ru.ru_majflt;
    s->cpu0 = span_clock_ms(CLOCK_THREAD_CPUTIME_ID);
    s->wall0 = span_clock_ms(CLOCK_MONOTONIC);
}

static inline void span_stop(cpu_span *s)
{
    s->wall_ms = span_clock_ms(CLOCK_MONOTONIC) - s->wall0;
    s->cpu_ms = span_clock_ms(CLOCK_THREAD_CPUTIME_ID) - s->cpu0;
    struct rusage ru;
    getrusage(RUSAGE_THREAD, &ru);
    s->vol = ru.ru_nvcsw - s->vol0;
    s->inv = ru.ru_nivcsw - s->inv0;
    s->maj = ru.ru_majflt - s->maj0;
}

/* How many spans that kept the CPU may still be slow for no cause in the
 * code.  These virtual machines report no steal time (the steal column of
 * /proc/stat stays 0), so while the host runs something else the guest's
 * clocks go on and the span shows neither a switch nor a gap between its
 * CPU and wall time.  Measured in test_soak's 60,000 frames of about
 * 0.2 ms each, alone on the machine: worst frames 2.0, 2.8 and 14.7 ms in
 * three runs, and 22.0 ms of CPU time once in a CI run.  A fault of the
 * code (a stall behind the loader, a scan of every node) repeats with its
 * cause in many frames; one such spike in tens of thousands of spans is
 * the host's. */
static inline int span_host_spikes(int spans)
{
    return 1 + spans / 30000;
}

/* The shared predicate: a wall-clock bound judges this span. */
static inline int span_kept_cpu(const cpu_span *s)
{
    return s->inv == 0 && !(HLOD_TEST_TSAN && s->vol);
}

/* Whether render_waits is judged in this build (not under TSan). */
static inline int span_judges_waits(void)
{
    return !HLOD_TEST_TSAN;
}

/* Whether enough of n spans were judged (judged of them kept the CPU) for
 * a bound on them to mean something: a quarter.  Beside a make -j4 on two
 * cores, test_faults' frames (a few ms each, drawn by llvmpipe) kept the
 * CPU in 101 and 103 of 320; test_soak's (0.2 ms) in 54,895 of 58,194. */
static inline int span_judged_enough(int judged, int n)
{
    return n > 0 && 4 * judged >= n;
}

#endif
