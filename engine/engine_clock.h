/*
 * engine_clock.h - the monotonic clock in ms, for the engine's wall-clock
 * measures (never read for a decision under a time model).
 */
#ifndef HLOD_ENGINE_CLOCK_H
#define HLOD_ENGINE_CLOCK_H

#include <time.h>

static inline double hlod_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

#endif
