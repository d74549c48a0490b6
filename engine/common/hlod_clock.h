/*
 * hlod_clock.h - the one monotonic clock every part and tool reads, in
 * seconds and in milliseconds (never read for a decision under the
 * engine's time model).
 */
#ifndef HLOD_CLOCK_H
#define HLOD_CLOCK_H

#include <time.h>

static inline double hlod_now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + (double)ts.tv_nsec * 1e-9;
}

static inline double hlod_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

#endif
