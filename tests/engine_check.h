/*
 * engine_check.h - helpers shared by the engine's tests (test_engine,
 * test_faults, test_soak, test_degenerate): wall clock, sleeping, the
 * calling thread's context switches, and the finiteness of a frame's
 * stats, and a synthetic machine for the engine's time_model.
 */
#ifndef HLOD_ENGINE_CHECK_H
#define HLOD_ENGINE_CHECK_H

#include "hlod/engine.h"

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/resource.h>
#include <time.h>

static inline double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

static inline void sleep_us(long us)
{
    struct timespec ts = {us / 1000000, (us % 1000000) * 1000};
    nanosleep(&ts, NULL);
}

#ifdef RUSAGE_THREAD /* _GNU_SOURCE before the first include */
/* Context switches of the calling thread: voluntary (it blocked) and
 * involuntary (the scheduler preempted it). */
static inline void thread_switches(long *vol, long *invol)
{
    struct rusage ru;
    getrusage(RUSAGE_THREAD, &ru);
    *vol = ru.ru_nvcsw;
    *invol = ru.ru_nivcsw;
}
#endif

/* CPU time of the calling thread, in ms. */
static inline double thread_cpu_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

/* Did the thread run for most of a wall-clock interval?  On a virtual
 * machine the host can take the CPU away (steal time) without any context
 * switch in the guest: such a frame is long on the wall clock but short in
 * CPU time, and the runtime did not make it slow. */
static inline int ran_most_of(double wall_ms, double cpu_ms)
{
    return cpu_ms >= 0.5 * wall_ms;
}

/* A synthetic machine without noise: a frame takes fixed + per_cost * cost
 * ms.  Pass fixed_machine_time as time_model and the machine as its user. */
typedef struct fixed_machine {
    double fixed, per_cost;
} fixed_machine;

static inline double fixed_machine_time(void *user, double cost, uint64_t tris)
{
    const fixed_machine *m = user;
    (void)tris;
    return m->fixed + m->per_cost * cost;
}

/* Every floating-point field of a frame's stats is finite. */
static inline int stats_finite(const hlod_frame_stats *s)
{
    const double v[] = {s->measured_ms,  s->estimated_ms, s->v_time,       s->fixed_ms,
                        s->budget_ms,    s->share_gain,   s->traversal_ms, s->upload_ms,
                        s->sse_pixels,   s->cost_drawn,   s->resident_cost};
    for (size_t k = 0; k < sizeof v / sizeof *v; k++)
        if (!isfinite(v[k]))
            return 0;
    return 1;
}

#endif
