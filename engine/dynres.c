/*
 * dynres.c - resolution steps with their own hysteresis (dynres.h).
 */
#include "dynres.h"
#include "sort.h"

#include <string.h>

static const double step_scale[DYNRES_STEPS] = {1.0, 0.85, 0.72, 0.6, 0.5};

double hlod_dynres_step_scale(int s)
{
    if (s < 0)
        s = 0;
    if (s >= DYNRES_STEPS)
        s = DYNRES_STEPS - 1;
    return step_scale[s];
}

void hlod_dynres_reset(hlod_dynres *d)
{
    memset(d, 0, sizeof *d);
}

static int cmp_double(const void *pa, const void *pb)
{
    double a = *(const double *)pa, b = *(const double *)pb;
    return (a > b) - (a < b);
}

/* The median of the window (full). */
static double window_median(const hlod_dynres *d)
{
    double v[DYNRES_WINDOW];
    memcpy(v, d->ms, sizeof v);
    hlod_sort(v, DYNRES_WINDOW, sizeof *v, cmp_double);
    return 0.5 * (v[DYNRES_WINDOW / 2 - 1] + v[DYNRES_WINDOW / 2]);
}

static int take_step(hlod_dynres *d, int by)
{
    d->judging = by > 0;
    if (by > 0)
        d->before_ms = window_median(d);
    d->step += by;
    d->hold = DYNRES_HOLD;
    d->n = 0;
    return by;
}

/* A step down whose frames are in: kept if it saved what it should. */
static int judge(hlod_dynres *d)
{
    d->judging = 0;
    if (window_median(d) < DYNRES_GAIN * d->before_ms) {
        d->backoff_len = 0;
        return 0;
    }
    d->backoff_len = d->backoff_len ? 2 * d->backoff_len : DYNRES_BACKOFF;
    if (d->backoff_len > DYNRES_BACKOFF_MAX)
        d->backoff_len = DYNRES_BACKOFF_MAX;
    d->backoff = d->backoff_len;
    d->reverted++;
    return take_step(d, -1);
}

int hlod_dynres_update(hlod_dynres *d, double measured_ms, double target_ms, int coarsest)
{
    d->frames++;
    d->ms[d->head] = measured_ms;
    d->floor_miss[d->head] = coarsest && measured_ms > target_ms;
    d->head = (d->head + 1) % DYNRES_WINDOW;
    if (d->n < DYNRES_WINDOW)
        d->n++;
    if (d->backoff)
        d->backoff--;
    if (d->n == DYNRES_WINDOW && d->judging)
        return judge(d);
    if (d->hold) {
        d->hold--;
        return 0;
    }
    if (d->n < DYNRES_WINDOW)
        return 0;
    int misses = 0, fit_up = d->step > 0;
    if (fit_up) {
        double s = step_scale[d->step], up = step_scale[d->step - 1];
        double grow = (up * up) / (s * s);
        for (int k = 0; k < DYNRES_WINDOW; k++)
            fit_up &= d->ms[k] * grow <= DYNRES_UP_FRAC * target_ms;
    }
    for (int k = 0; k < DYNRES_WINDOW; k++)
        misses += d->floor_miss[k];
    if (fit_up)
        return take_step(d, -1);
    if (misses >= DYNRES_DOWN_OF && d->step + 1 < DYNRES_STEPS && d->frames > DYNRES_SETTLE &&
        !d->backoff)
        return take_step(d, +1);
    return 0;
}
