/*
 * cost_model.c - the frame cost model, its deadline margin and the gains
 * fitted to it (cost_model.h; docs/runtime.md, "The cost model and deadline margin").
 *
 * Why it is built this way.  A two-term fit updated every frame wandered
 * with the machine's noise: a still camera gives the regressors no spread,
 * so noise alone moved the fixed part and v_time, the budget followed, and
 * the hysteresis counters followed the budget (2.4 toggles a frame on a
 * still view).  Here the published model changes for three reasons only,
 * each gated by what the noise can explain:
 *
 *   scale  the median log residual of the last SCALE_K frames is beyond
 *          both 5 % and three standard errors of a median of the measured
 *          noise: every term is multiplied by its exponential (the machine
 *          got faster or slower).  A persistent error passes within
 *          SCALE_K / 2 + 1 frames; a burst of slow frames shorter than that
 *          cannot move a median.
 *   shape  a ridge-regularised least-squares fit over about 33 frames
 *          (forgetting 0.97; the ridge pulls toward the published values,
 *          so a regressor without spread keeps its coefficient) predicts
 *          the last SHAPE_W frames clearly better (30 % less robust loss)
 *          than the published model.  Without spread in the regressors it
 *          cannot do clearly better, so it never publishes then.
 *   margin the deadline margin exp(median + z * sigma) of the last
 *          HLOD_COST_WINDOW residuals moved by more than 5 % (see below:
 *          once the window is full it grows only on actual misses).
 *
 * A settled front (the same totals frame after frame) publishes none of
 * these, with one exception: when the median log residuals of both halves
 * of its last SETTLED_K frames are beyond 15 % and SCALE_SE standard
 * errors, the same way, the model is scaled once (the machine's speed changed, or the model learned
 * it while loads competed for the CPU and they have stopped: seen as a
 * still view held at 3 nodes, estimated 12.5 ms, measuring 9 ms against a
 * 33 ms target).  Noise cannot pass that gate over so many frames; a
 * persistent error passes it SETTLED_K frames after the front settled.
 * A settled front that runs faster than its estimate by more than FAST_ERR
 * in each of its last SCALE_K frames passes at once: noise slows frames
 * down and never makes seven in a row 26 % faster (parts city,
 * walk-drive, nohyst: a front of 6 nodes estimated at 19.3 ms measured
 * 5.3-6.9 ms; the budget at its floor held it there for 30 frames).
 *
 * sigma is 1.4826 x the median absolute deviation: a few outliers do not
 * move it.  All coefficients are kept non-negative, the fixed part under
 * 80 % of the target.
 */
#include "cost_model.h"
#include "sort.h"

#include <assert.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define FORGET 0.97
#define RIDGE 0.05
#define SCALE_K 7
#define SHAPE_W 32
#define SHAPE_HOLD 64 /* frames between two shape changes once the window is full */
#define PRIOR_SIGMA 0.15 /* assumed spread until MARGIN_MIN frames are seen */
#define MARGIN_MIN 20
#define MARGIN_STEP 0.05 /* published margin moves by more than this (log) */
#define MARGIN_SETTLE 45 /* frames after which the margin moves only on evidence */
#define MISS_W 128       /* recent frames whose misses can grow the margin */
#define SCALE_SE 4       /* standard errors of the median that a scale change must pass */
#define SETTLED_K 32     /* frames of a settled front whose median error may rescale it */
#define SETTLED_ERR 0.15 /* and the log error each half of them must pass */
#define FAST_ERR 0.3     /* a settled front faster than this (log) in each of SCALE_K frames */

/* z with P(N(0,1) <= z) = q, by bisection on erfc (q in (0.5, 1)). */
static double normal_quantile(double q)
{
    double lo = 0, hi = 10;
    for (int i = 0; i < 80; i++) {
        double mid = 0.5 * (lo + hi);
        if (1 - 0.5 * erfc(mid / sqrt(2.0)) < q)
            lo = mid;
        else
            hi = mid;
    }
    return 0.5 * (lo + hi);
}

/* The margin for a quantile: the larger of the Gaussian one from the
 * median and sigma of n residuals and, given nt residuals of the frames
 * past the warm-up sorted ascending, their empirical quantile (the
 * machine's tail is heavier than a Gaussian's) once nt holds at least one
 * frame past it. */
static double aim_margin(const hlod_engine_desc *d, double median, double sigma,
                         const double *sorted, uint32_t nt, uint32_t n)
{
    if (d->deterministic || d->aim_mean > 0)
        return 1;
    /* until the window holds MARGIN_SETTLE frames the tail is barely
     * seen: aim at a quantile ten times as far out, so that a settled
     * view rarely needs to grow its margin later */
    double q = d->deadline_quantile;
    double qz = n < MARGIN_SETTLE ? 1 - 0.1 * (1 - q) : q;
    double l = median + normal_quantile(qz) * sigma;
    /* (a quantile of fewer frames is their maximum: the one slowest
     * frame, not the machine's tail) */
    if (n >= MARGIN_SETTLE && nt * (1 - q) >= 1) {
        uint32_t k = (uint32_t)ceil(q * nt);
        double emp = sorted[k ? (k <= nt ? k - 1 : nt - 1) : 0];
        l = emp > l ? emp : l;
    }
    double m = exp(l);
    return m < 0.5 ? 0.5 : m > HLOD_MARGIN_MAX ? HLOD_MARGIN_MAX : m;
}

void hlod_cost_model_init(hlod_cost_model *m, const hlod_engine_desc *d)
{
    assert(m && d);
    memset(m, 0, sizeof *m);
    if (d->deterministic) {
        m->theta[0] = d->fixed_frame_ms;
        m->theta[2] = d->fixed_v_time;
    } else {
        m->theta[0] = 0.2 * d->target_ms;
        m->theta[2] = 1e-4;
    }
    m->sigma = PRIOR_SIGMA;
    m->margin = aim_margin(d, 0, PRIOR_SIGMA, NULL, 0, 0);
    m->sse_pixels = d->sse_pixels;
    m->splat_px = d->splat_px;
    m->share_gain = 1;
}

void hlod_cost_model_set(hlod_cost_model *m, const hlod_engine_desc *old,
                         const hlod_engine_desc *d)
{
    assert(m && old && d);
    if (d->sse_pixels != old->sse_pixels)
        m->sse_pixels = d->sse_pixels;
    if (d->splat_px != old->splat_px)
        m->splat_px = d->splat_px;
    if (d->deterministic) {
        m->theta[0] = d->fixed_frame_ms;
        m->theta[2] = d->fixed_v_time;
    }
    if (d->aim_mean != old->aim_mean || d->deadline_quantile != old->deadline_quantile)
        m->margin = aim_margin(d, 0, m->sigma, NULL, 0, 0);
}

static double dot(const double *t, const double *x)
{
    double s = 0;
    for (int k = 0; k < HLOD_COST_TERMS; k++)
        s += t[k] * x[k];
    return s;
}

/* The model's ms for regressors x under theta: a frame that draws nothing
 * is the fixed part alone, measured (the median of the last such frames)
 * once one was seen; a front is theta . x. */
static double model_ms(const hlod_cost_model *m, const double *theta, const double *x)
{
    return m->empty_n && x[1] == 0 ? m->fixed_floor : dot(theta, x);
}

double hlod_cost_model_predict(const hlod_cost_model *m, double draws, double cost,
                               double pixels)
{
    assert(m);
    const double x[HLOD_COST_TERMS] = {1, draws, cost, pixels};
    return model_ms(m, m->theta, x);
}

/* ln(measured / predicted), both floored at 10 us. */
static double log_residual(const hlod_cost_model *m, const double *theta,
                           const hlod_cost_sample *s)
{
    double p = model_ms(m, theta, s->x);
    return log((s->y > 0.01 ? s->y : 0.01) / (p > 0.01 ? p : 0.01));
}

static int cmp_double(const void *pa, const void *pb)
{
    double a = *(const double *)pa, b = *(const double *)pb;
    return (a > b) - (a < b);
}

static double median(double *v, uint32_t n)
{
    hlod_sort(v, n, sizeof *v, cmp_double);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/* The residuals of the newest n samples (newest first) under theta. */
static uint32_t residuals(const hlod_cost_model *m, const double *theta, uint32_t n, double *out)
{
    if (n > m->ring_n)
        n = m->ring_n;
    for (uint32_t k = 0; k < n; k++) {
        uint32_t i = (m->ring_head + HLOD_COST_WINDOW - 1 - k) % HLOD_COST_WINDOW;
        out[k] = log_residual(m, theta, &m->ring[i]);
    }
    return n;
}

/* median and 1.4826 x MAD of the n values e; e comes back sorted
 * ascending */
static void robust(double *e, uint32_t n, double *med, double *sigma)
{
    double dev[HLOD_COST_WINDOW];
    *med = median(e, n);
    for (uint32_t k = 0; k < n; k++)
        dev[k] = fabs(e[k] - *med);
    *sigma = 1.4826 * median(dev, n);
}

/* median and 1.4826 x MAD of the newest n residuals under the published
 * model */
static uint32_t spread(const hlod_cost_model *m, uint32_t n, double *med, double *sigma)
{
    double e[HLOD_COST_WINDOW];
    n = residuals(m, m->theta, n, e);
    robust(e, n, med, sigma);
    return n;
}

/* Of the newest n samples, those past the warm-up (the first MARGIN_SETTLE
 * samples the model saw).  The margin's tail and its miss count read only
 * these: the first frames compile shaders on first use and fault in cold
 * pages, and the model is still unfit.  One such frame was the whole
 * empirical tail of the 45-200 frames that followed: on the still view at
 * 33 ms, frame 0 at 3.6 x its estimate set the margin to 2.59 at frame 45,
 * the front fell from 123 nodes to 41, and, the front then being settled,
 * the margin never shrank again (frames of 9 ms for the rest of the run). */
static uint32_t past_warmup(const hlod_cost_model *m, uint32_t n)
{
    uint64_t after = m->frames > MARGIN_SETTLE ? m->frames - MARGIN_SETTLE : 0;
    return after < n ? (uint32_t)after : n;
}

/* Robust loss of theta over the newest SHAPE_W samples: squared log
 * residuals, each capped at 0.25 (a 65 % miss), so one stalled frame
 * cannot decide. */
static double shape_loss(const hlod_cost_model *m, const double *theta)
{
    double e[SHAPE_W], l = 0;
    uint32_t n = residuals(m, theta, SHAPE_W, e);
    for (uint32_t k = 0; k < n; k++)
        l += e[k] * e[k] < 0.25 ? e[k] * e[k] : 0.25;
    return l;
}

/* Solves the ridge system (A + L) t = b + L prior with t >= lo (lo: the
 * fixed part's floor, 0 for the other terms; terms that come out below
 * their bound are held at it and the rest solved again).  Returns 0 when
 * the system is singular. */
static int ridge_solve(const hlod_cost_model *m, const double *prior, double ridge, double *t)
{
    const double lo[HLOD_COST_TERMS] = {m->fixed_floor, 0, 0, 0};
    double lam[HLOD_COST_TERMS];
    for (int j = 0; j < HLOD_COST_TERMS; j++) {
        double mean = m->a[0][j] / m->s0; /* a[0][j] = sum of x_j (x_0 = 1) */
        lam[j] = ridge * m->s0 * (j == 0 ? 1 : mean * mean);
        if (!(lam[j] > 0))
            lam[j] = 1e-12;
    }
    int active[HLOD_COST_TERMS] = {1, 1, 1, 1};
    for (int round = 0; round <= HLOD_COST_TERMS; round++) {
        double g[HLOD_COST_TERMS][HLOD_COST_TERMS + 1];
        int idx[HLOD_COST_TERMS], n = 0;
        for (int j = 0; j < HLOD_COST_TERMS; j++)
            if (active[j])
                idx[n++] = j;
        for (int r = 0; r < n; r++) {
            int i = idx[r];
            for (int c = 0; c < n; c++)
                g[r][c] = m->a[i][idx[c]] + (r == c ? lam[i] : 0);
            g[r][n] = m->b[i] + lam[i] * prior[i];
            for (int j = 0; j < HLOD_COST_TERMS; j++)
                if (!active[j])
                    g[r][n] -= m->a[i][j] * lo[j];
        }
        /* Gaussian elimination with partial pivoting */
        for (int c = 0; c < n; c++) {
            int piv = c;
            for (int r = c + 1; r < n; r++)
                if (fabs(g[r][c]) > fabs(g[piv][c]))
                    piv = r;
            if (!(fabs(g[piv][c]) > 1e-300))
                return 0;
            for (int k = 0; k <= n; k++) {
                double tmp = g[c][k];
                g[c][k] = g[piv][k];
                g[piv][k] = tmp;
            }
            for (int r = 0; r < n; r++) {
                if (r == c)
                    continue;
                double f = g[r][c] / g[c][c];
                for (int k = c; k <= n; k++)
                    g[r][k] -= f * g[c][k];
            }
        }
        int below = 0;
        for (int j = 0; j < HLOD_COST_TERMS; j++)
            t[j] = lo[j];
        for (int r = 0; r < n; r++) {
            t[idx[r]] = g[r][n] / g[r][r];
            if (!isfinite(t[idx[r]]))
                return 0;
            if (t[idx[r]] < lo[idx[r]]) {
                active[idx[r]] = 0;
                below = 1;
            }
        }
        if (below) /* the held terms at their bounds, the rest solved again */
            continue;
        return 1;
    }
    return 0;
}

static void scale_theta(hlod_cost_model *m, double f)
{
    for (int k = 0; k < HLOD_COST_TERMS; k++)
        m->theta[k] *= f;
}

/* The standard error of the median of n residuals of spread sigma. */
static double median_se(double sigma, double n)
{
    return 1.2533 * sigma / sqrt(n);
}

/* A settled front measured faster than its estimate by more than FAST_ERR
 * in each of its last SCALE_K frames, their median past SCALE_SE standard
 * errors of the measured noise (see the header: noise never does that). */
static int settled_faster(const hlod_cost_model *m, double sigma)
{
    double e[SCALE_K];
    uint32_t n = residuals(m, m->theta, SCALE_K, e);
    if (n < SCALE_K)
        return 0;
    for (uint32_t k = 0; k < n; k++)
        if (e[k] > -FAST_ERR)
            return 0;
    return fabs(median(e, n)) > SCALE_SE * median_se(sigma, n);
}

/* The deadline margin, from the residuals under the model now
 * published.  While the window fills it follows the measured spread.
 * Then it grows only when frames actually miss it more often than the
 * quantile allows (over the last MISS_W frames past the warm-up, each a
 * frame's time over prediction x margin), and shrinks only when the
 * spread has fallen by twice the step and the front is not settled: an
 * estimate that
 * wanders with the noise must not move the budget of a still camera. */
static void update_margin(hlod_cost_model *m, const hlod_engine_desc *d, int settled)
{
    double med, sigma;
    /* the residuals once, newest first; the margin's tail and the
     * recent frames are their first past_warmup() (copied before
     * robust() sorts them) */
    double e[HLOD_COST_WINDOW], tail[HLOD_COST_WINDOW], recent[MISS_W];
    uint32_t n = residuals(m, m->theta, m->ring_n, e);
    uint32_t nt = past_warmup(m, n), nr = past_warmup(m, n < MISS_W ? n : MISS_W);
    memcpy(tail, e, nt * sizeof *e);
    memcpy(recent, e, nr * sizeof *e);
    hlod_sort(tail, nt, sizeof *tail, cmp_double);
    robust(e, n, &med, &sigma);
    m->sigma = sigma;
    double want = aim_margin(d, med, sigma, tail, nt, n);
    double step = log(want / m->margin);
    int change;
    if (m->ring_n < MARGIN_SETTLE) {
        change = fabs(step) > 0.02;
    } else {
        /* misses over the last MISS_W frames past the warm-up: the
         * regime now, not the loading start that the long window
         * still holds */
        double rmed, rsig;
        uint32_t misses = 0;
        for (uint32_t k = 0; k < nr; k++)
            misses += recent[k] > log(m->margin);
        double allowed = (1 - d->deadline_quantile) * nr;
        /* four standard deviations of a binomial count over what the
         * quantile allows: an adequate margin almost never passes it */
        int too_many = nr && misses >= ceil(allowed + 4 * sqrt(allowed) + 2);
        if (too_many) {
            /* grow to what the recent frames need, no further: their
             * median and spread, and the window's empirical quantile.
             * Not the recent frames' own: 1 % of MISS_W frames is 1.3
             * frames, so two stalls of a few frames decided it.  On the
             * still view at 33 ms, stalls of 3.0 and 3.1 x, 7 frames
             * apart, among 6 misses of 1.25-1.36 x, set the margin to
             * 3.03: 16 nodes coarsened, and the held front kept them. */
            robust(recent, nr, &rmed, &rsig);
            double grow = aim_margin(d, rmed, rsig, tail, nt, n);
            want = grow > m->margin ? grow : m->margin;
            step = log(want / m->margin);
        }
        change = (step > MARGIN_STEP && too_many) || (step < -2 * MARGIN_STEP && !settled);
    }
    if (change || d->aim_mean > 0) {
        if (want != m->margin)
            m->margin_updates++;
        m->margin = want;
    }
}

/* A frame that drew nothing measures the fixed part alone: the median of
 * the last HLOD_COST_EMPTY such frames predicts such frames, and floors
 * the fixed part of a front.  Without the floor the
 * fit may put the fixed part in the pixel term (every moving frame covers
 * 2-3 M pixels, nearly a constant): on fly it was 0.0000 when the camera
 * turned to the sky, the empty frames (1.7 ms against an estimate of
 * 0.003 ms) scaled every term by 170 x twice (v_time 0.001 -> 28.9), the
 * margin went to 4 and the front's estimate to 49 s; the margin took 600
 * frames to come back to 1.33.  The floor is raised only past 10 % of
 * it, so a view of the sky does not publish its noise. */
static void empty_frame(hlod_cost_model *m, double y, double target)
{
    double v[HLOD_COST_EMPTY];
    m->empty[m->empty_head] = y;
    m->empty_head = (m->empty_head + 1) % HLOD_COST_EMPTY;
    if (m->empty_n < HLOD_COST_EMPTY)
        m->empty_n++;
    memcpy(v, m->empty, m->empty_n * sizeof *v);
    double floor_ms = median(v, m->empty_n);
    if (floor_ms > 0.8 * target)
        floor_ms = 0.8 * target;
    if (floor_ms > m->fixed_floor * 1.1 || floor_ms < m->fixed_floor / 1.1)
        m->fixed_floor = floor_ms;
    if (m->theta[0] < m->fixed_floor)
        m->theta[0] = m->fixed_floor;
}

/* Record: the frame goes into the window, and into the fit's sums
 * when it drew something (an empty frame stays out of the fit: it is
 * predicted by the floor, and a front's fixed part may be more than an
 * empty frame's).  Returns whether the front is settled: the same as the
 * last frame's (a still camera whose selection has settled), when only
 * missed deadlines move anything. */
static int record(hlod_cost_model *m, const hlod_cost_sample *s)
{
    const hlod_cost_sample *last =
        m->ring_n ? &m->ring[(m->ring_head + HLOD_COST_WINDOW - 1) % HLOD_COST_WINDOW] : NULL;
    int settled =
        m->ring_n >= MARGIN_SETTLE && last && memcmp(last->x, s->x, sizeof s->x) == 0;
    m->settled_run = settled ? m->settled_run + 1 : 0;
    m->frames++;
    m->ring[m->ring_head] = *s;
    m->ring_head = (m->ring_head + 1) % HLOD_COST_WINDOW;
    if (m->ring_n < HLOD_COST_WINDOW)
        m->ring_n++;
    if (s->x[1] > 0) {
        m->s0 = FORGET * m->s0 + 1;
        for (int i = 0; i < HLOD_COST_TERMS; i++) {
            m->b[i] = FORGET * m->b[i] + s->x[i] * s->y;
            for (int j = 0; j < HLOD_COST_TERMS; j++)
                m->a[i][j] = FORGET * m->a[i][j] + s->x[i] * s->x[j];
        }
    }
    return settled;
}

/* Whether the median residual mk of the last k_scale frames (n of
 * them) shows a persistent error of the whole model: of a settled front,
 * both halves of its last SETTLED_K frames (medians h) past SETTLED_ERR
 * the same way (so that the error is there all along and not a step
 * half-way that a second change would have to finish); or, faster than
 * its estimate, its last SCALE_K frames (settled_faster); else past 5 %
 * and the noise. */
static int scale_passes(const double h[2], uint32_t n, double mk, double sigma, int settled,
                        int fast)
{
    if (fast)
        return 1;
    if (!settled)
        return fabs(mk) > 0.05 && fabs(mk) > SCALE_SE * median_se(sigma, n);
    double lo = fmin(fabs(h[0]), fabs(h[1]));
    return h[0] * h[1] > 0 && lo > SETTLED_ERR &&
           lo > SCALE_SE * median_se(sigma, SETTLED_K / 2.0);
}

/* The machine changed: the model scales by f.  The frames seen before the
 * last k_scale are rescaled with it, so the fit and the margin do not see
 * two machines (nor pull the model back to the old one); the last k_scale
 * are left as measured, so the next median sees the new machine at
 * residual 0, not the same change again.  While the window fills it is
 * the model that was wrong, not the machine: the frames stay as measured. */
static void rescale(hlod_cost_model *m, double mk, uint32_t k_scale)
{
    double f = exp(mk);
    scale_theta(m, f);
    if (m->ring_n >= MARGIN_SETTLE) {
        for (uint32_t k = k_scale; k < m->ring_n; k++)
            m->ring[(m->ring_head + HLOD_COST_WINDOW - 1 - k) % HLOD_COST_WINDOW].y *= f;
        for (int i = 0; i < HLOD_COST_TERMS; i++)
            m->b[i] *= f;
    }
    m->scale_updates++;
    m->scale_at = m->frames;
    m->scale_dir = mk > 0 ? 1 : -1;
    m->settled_run = 0; /* a settled front is checked again SETTLED_K frames on */
}

/* Scale: a persistent error of the whole model rescales it.  A scale is
 * not undone before SCALE_K frames measured after it can say so: with
 * fronts that the model misses one way and the other in turn (errors of
 * -20 % and +20 % every other frame), the median of the last SCALE_K
 * swung with each new frame, and the scale with it. */
static void update_scale(hlod_cost_model *m, int settled, double sigma)
{
    const int fast = settled && m->settled_run >= SCALE_K && settled_faster(m, sigma);
    const uint32_t k_scale = settled && !fast ? SETTLED_K : SCALE_K;
    if (!(m->ring_n >= SCALE_K / 2 + 1 && (!settled || fast || m->settled_run >= SETTLED_K)))
        return;
    double e[SETTLED_K > SCALE_K ? SETTLED_K : SCALE_K], h[2] = {0, 0};
    uint32_t n = residuals(m, m->theta, k_scale, e);
    if (settled && !fast) /* the halves' medians, before median() reorders e */
        for (int half = 0; half < 2; half++) {
            double part[SETTLED_K / 2];
            memcpy(part, e + half * (SETTLED_K / 2), sizeof part);
            h[half] = median(part, SETTLED_K / 2);
        }
    double mk = median(e, n);
    int passes = scale_passes(h, n, mk, sigma, settled, fast);
    if (passes && (mk > 0 ? 1 : -1) == -m->scale_dir && m->frames - m->scale_at < SCALE_K)
        passes = 0;
    if (passes)
        rescale(m, mk, k_scale);
}

/* Shape: the terms' split changes when the fit explains recent frames
 * clearly better (30 %).  While the window fills the prior is only the
 * start guess: it is held weakly, so the first frames' spread (a cold
 * start loads and refines) fixes the terms, and any improvement is taken.
 * After the window has filled, one shape change per SHAPE_HOLD frames:
 * two shapes that each fit the last frames a little better in turn would
 * otherwise swap back and forth, and the front with them. */
static void update_shape(hlod_cost_model *m, double target, int settled)
{
    double t[HLOD_COST_TERMS];
    int warm = m->ring_n < MARGIN_SETTLE;
    if (!(m->ring_n >= 6 && !settled && ridge_solve(m, m->theta, warm ? 0.1 * RIDGE : RIDGE, t)))
        return;
    if (t[0] > 0.8 * target)
        t[0] = 0.8 * target;
    if (t[2] < 1e-9)
        t[2] = 1e-9; /* v_time stays positive: the traversal divides by needs */
    double lp = shape_loss(m, m->theta), lf = shape_loss(m, t);
    double need = warm ? 1.0 : 0.7;
    int held = !warm && m->frames - m->shape_at < SHAPE_HOLD && m->shape_updates;
    if (lf < need * lp && lp > SHAPE_W * 0.02 * 0.02 && !held) {
        memcpy(m->theta, t, sizeof t);
        m->shape_updates++;
        m->shape_at = m->frames;
    }
}

void hlod_cost_model_fit(hlod_cost_model *m, const hlod_engine_desc *d, double draws,
                         double cost, double pixels, double y)
{
    assert(m && d);
    if (!(isfinite(draws) && isfinite(cost) && isfinite(pixels) && isfinite(y)) || draws < 0 ||
        cost < 0 || pixels < 0 || y < 0)
        return;
    const double target = d->target_ms;
    hlod_cost_sample s = {{1, draws, cost, pixels}, y};
    if (draws == 0)
        empty_frame(m, y, target);
    int settled = record(m, &s);
    double med, sigma = PRIOR_SIGMA; /* the noise as measured so far */
    if (m->ring_n >= 8)
        spread(m, m->ring_n, &med, &sigma);
    update_scale(m, settled, sigma);
    update_shape(m, target, settled);
    if (m->ring_n >= MARGIN_MIN)
        update_margin(m, d, settled);
    if (m->theta[0] > 0.8 * target)
        m->theta[0] = 0.8 * target;
    if (m->theta[0] < m->fixed_floor)
        m->theta[0] = m->fixed_floor;
}

/* Eq. 4 hands each node a fixed share of its parent's slice, and time a
 * node cannot use (its children need more than its slice, or it is a leaf)
 * is lost to the frame: left alone the front settles well under the target
 * (about 65% of it on the tests' synthetic city).  The paper is silent;
 * we scale the roots' shareTime by a gain:
 *   - it grows, at most 10% a frame, while the estimate is under 85% of
 *     the budget and time slices refused a refinement that was near;
 *   - it shrinks 3% a frame while the budget bound refused refinements the
 *     slices granted (the slices then promise more than the frame holds,
 *     and the bound, not priority, would choose), but only while the
 *     camera moves: with a still camera a refused node simply stays
 *     refused, whereas shrinking would lower every slice until some other
 *     node gave way, then grow again: a slow cycle of toggles.
 * The budget still bounds the estimate (selection), so the gain moves
 * detail between nodes and never pushes the frame over the target. */
void hlod_cost_model_adapt_share(hlod_cost_model *m, double est, double budget, int moved,
                                 uint32_t cap_hits, uint32_t slice_denied)
{
    assert(m);
    double ratio = budget > 0 ? est / budget : 1;
    double g = m->share_gain;
    if (cap_hits && moved) {
        g *= 0.97;
    } else if (ratio < 0.85 && slice_denied) {
        double up = ratio > 0 ? sqrt(0.92 / ratio) : 1.1;
        g *= up < 1.1 ? up : 1.1;
    }
    m->share_gain = g < 1 ? 1 : g > 64 ? 64 : g;
}

/* The SSE policy's pixel threshold follows the frame time: coarser when
 * over target, finer when under; the square root damps the response. */
/* *v times sqrt(ratio), each step within [0.8, 1.25], *v within [lo, hi]. */
static void adapt_scale(double *v, double ratio, double lo, double hi)
{
    if (!(isfinite(ratio) && ratio > 0))
        return;
    double f = sqrt(ratio);
    f = f < 0.8 ? 0.8 : f > 1.25 ? 1.25 : f;
    *v *= f;
    *v = *v < lo ? lo : *v > hi ? hi : *v;
}

void hlod_cost_model_adapt_sse(hlod_cost_model *m, double ratio)
{
    assert(m);
    adapt_scale(&m->sse_pixels, ratio, 0.05, 1e4);
}

void hlod_cost_model_adapt_splat(hlod_cost_model *m, double ratio)
{
    assert(m);
    adapt_scale(&m->splat_px, ratio, 1, 64);
}
