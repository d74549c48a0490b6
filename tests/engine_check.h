/*
 * engine_check.h - helpers shared by the engine's tests (test_engine,
 * test_faults, test_soak, test_degenerate): wall clock, sleeping, the
 * excuse for wall-clock bounds (cpu_span.h), the finiteness of a frame's
 * stats, and a synthetic machine for the engine's time_model.  Define
 * _GNU_SOURCE before the first include.
 */
#ifndef HLOD_ENGINE_CHECK_H
#define HLOD_ENGINE_CHECK_H

#include "cpu_span.h"
#include "hlod/engine.h"

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <sys/resource.h>
#include <time.h>

static inline double now_ms(void)
{
    return span_clock_ms(CLOCK_MONOTONIC);
}

static inline void sleep_us(long us)
{
    struct timespec ts = {us / 1000000, (us % 1000000) * 1000};
    while (nanosleep(&ts, &ts) != 0)
        ;
}

/* A synthetic machine without noise: a frame takes fixed + per_cost * cost
 * ms.  Pass fixed_machine_time as time_model and the machine as its user. */
typedef struct fixed_machine {
    double fixed, per_cost;
} fixed_machine;

static inline double fixed_machine_time(void *user, const hlod_frame_stats *frame)
{
    double cost = frame->cost_drawn;
    const fixed_machine *m = user;
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
