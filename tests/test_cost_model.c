/*
 * test_cost_model.c - the frame cost model and its deadline margin
 * (engine/cost_model.c), driven directly by synthetic machines with
 * seeded noise: no threads, no clock, so every run gives the same result.
 *
 * A synthetic machine takes
 *   ms = (fixed + a * draws + b * cost + c * pixels) * exp(noise)
 * with noise drawn from a seeded generator: Gaussian in log space, and
 * stalls (a heavier tail): the machine measured in issue 17 (p99/p50 of
 * one fixed frame 1.39) and a harsher one.
 */
#include "check.h"
#include "cost_model.h"

#include <math.h>
#include <stdint.h>

typedef struct rng {
    uint64_t s;
} rng;

static double uniform(rng *r)
{
    r->s ^= r->s << 13;
    r->s ^= r->s >> 7;
    r->s ^= r->s << 17;
    return ((double)(r->s >> 11) + 0.5) / 9007199254740992.0;
}

static double gauss(rng *r)
{
    double u = uniform(r), v = uniform(r);
    return sqrt(-2 * log(u)) * cos(2 * M_PI * v);
}

typedef struct machine {
    double t[4];    /* fixed, per draw, per cost, per pixel */
    double sigma;   /* log-normal spread */
    int stalls;     /* 1: 0.5 % of frames 1.2-1.5x slower; 2: 2 % of frames 1.3-1.8x */
    rng r;
} machine;

static double machine_ms(machine *m, double draws, double cost, double pixels)
{
    double ms = m->t[0] + m->t[1] * draws + m->t[2] * cost + m->t[3] * pixels;
    ms *= exp(m->sigma * gauss(&m->r));
    if (m->stalls == 2 && uniform(&m->r) < 0.02)
        ms *= 1.3 + 0.5 * uniform(&m->r);
    if (m->stalls == 1 && uniform(&m->r) < 0.005)
        ms *= 1.2 + 0.3 * uniform(&m->r);
    return ms;
}

static hlod_engine_desc desc(double target)
{
    hlod_engine_desc d = {0};
    d.target_ms = target;
    hlod_engine_desc_defaults(&d);
    return d;
}

/* A front that varies as a moving camera's does: draws, cost and pixels
 * with spread, not proportional to each other. */
static void moving_front(rng *r, double *draws, double *cost, double *pixels)
{
    *draws = 50 + 400 * uniform(r);
    *cost = 2e4 + 2e5 * uniform(r);
    *pixels = 2e5 + 1.5e6 * uniform(r);
}

static double rel_err(const hlod_cost_model *cm, const machine *m, double draws, double cost,
                      double pixels)
{
    double truth = m->t[0] + m->t[1] * draws + m->t[2] * cost + m->t[3] * pixels;
    return fabs(hlod_cost_model_predict(cm, draws, cost, pixels) - truth) / truth;
}

/* With spread in the regressors the fit recovers the machine: its
 * predictions of new fronts are within 5 % (median) of the truth, from a
 * start 5x off. */
static void fit_recovers_machine(void)
{
    for (uint64_t seed = 1; seed <= 4; seed++) {
        machine m = {{6, 0.01, 5e-5, 2e-6}, 0.05, 0, {seed * 0x9e3779b97f4a7c15ull}};
        hlod_engine_desc d = desc(40);
        hlod_cost_model cm;
        hlod_cost_model_init(&cm, &d);
        rng r = {seed};
        for (int f = 0; f < 400; f++) {
            double dr, c, p;
            moving_front(&r, &dr, &c, &p);
            hlod_cost_model_fit(&cm, &d, dr, c, p, machine_ms(&m, dr, c, p));
        }
        double errs[200];
        for (int k = 0; k < 200; k++) {
            double dr, c, p;
            moving_front(&r, &dr, &c, &p);
            errs[k] = rel_err(&cm, &m, dr, c, p);
        }
        int below = 0;
        for (int k = 0; k < 200; k++)
            below += errs[k] <= 0.05;
        fprintf(stderr, "  seed %llu: fixed %.2f draw %.4f cost %.3g pixel %.3g; %d/200 within 5%%\n",
                (unsigned long long)seed, cm.theta[0], cm.theta[1], cm.theta[2], cm.theta[3],
                below);
        CHECKF(below >= 100, "seed %llu: %d of 200 predictions within 5%%",
               (unsigned long long)seed, below);
        for (int k = 0; k < 4; k++)
            CHECK(cm.theta[k] >= 0 && isfinite(cm.theta[k]));
    }
}

/* A still camera: the same front every frame.  After a warm-up of 60
 * frames nothing the selection reads changes with the noise of the
 * machine measured in issue 17 (p99/p50 1.39: log-normal 12 % and a
 * stall of 1.2-1.5x in 0.5 % of frames): neither the model nor the
 * margin, over 2000 frames, in 8 seeds.  On a harsher machine (10 % and
 * stalls of 1.3-1.8x in 2 % of frames, p99/p50 about 1.6) the margin of
 * the warm-up can be too small, and then it may grow, once, when frames
 * miss it significantly more often than 1 %; it never shrinks and the
 * model never moves.  The control: 16-frame means of the same machine
 * wander by more than 5 %, which an unguarded fit would publish. */
static int still_run(uint64_t seed, int harsh, int *grew)
{
    machine m = {{8, 0.02, 1e-4, 3e-6}, harsh ? 0.10 : 0.12, harsh ? 2 : 1,
                 {seed * 0x2545f4914f6cdd1dull}};
    hlod_engine_desc d = desc(33.3);
    hlod_cost_model cm;
    hlod_cost_model_init(&cm, &d);
    const double dr = 140, c = 64e3, p = 6e5;
    double theta[4] = {0}, margin = 0;
    int changes = 0;
    double lo = INFINITY, hi = -INFINITY;
    *grew = 0;
    for (int f = 0; f < 2060; f++) {
        if (f == 60) {
            memcpy(theta, cm.theta, sizeof theta);
            margin = cm.margin;
        }
        hlod_cost_model_fit(&cm, &d, dr, c, p, machine_ms(&m, dr, c, p));
        if (f >= 60) {
            int model = memcmp(theta, cm.theta, sizeof theta) != 0;
            if ((model || margin != cm.margin) && getenv("HLOD_TEST_VERBOSE"))
                fprintf(stderr, "    frame %d: margin %.3f -> %.3f, model %s\n", f, margin,
                        cm.margin, model ? "changed" : "kept");
            changes += model || margin != cm.margin;
            *grew += !model && cm.margin > margin;
            memcpy(theta, cm.theta, sizeof theta);
            margin = cm.margin;
        }
        if (f >= 60 && f % 16 == 0) {
            double s = 0;
            for (int k = 0; k < 16; k++)
                s += machine_ms(&m, dr, c, p);
            lo = s / 16 < lo ? s / 16 : lo;
            hi = s / 16 > hi ? s / 16 : hi;
        }
    }
    fprintf(stderr, "  %s seed %llu: %d changes after frame 60; margin %.3f; 16-frame means "
            "wander %.1f%%\n", harsh ? "harsh" : "measured", (unsigned long long)seed, changes,
            cm.margin, 100 * (hi - lo) / lo);
    CHECK(hi - lo > 0.05 * lo); /* the noise is there to be ignored */
    return changes;
}

static void still_front_publishes_nothing(void)
{
    for (uint64_t seed = 1; seed <= 8; seed++) {
        int grew;
        int changes = still_run(seed, 0, &grew);
        CHECKF(changes == 0, "seed %llu: the published model changed %d times with a still front",
               (unsigned long long)seed, changes);
        changes = still_run(seed, 1, &grew);
        CHECKF(changes <= 1 && grew == changes,
               "harsh machine, seed %llu: %d changes, %d of them the margin growing",
               (unsigned long long)seed, changes, grew);
    }
}

/* Two stalls of 3 x, 7 frames apart, on a still front whose margin needs
 * to grow: the margin grows to what the machine's tail needs, not to the
 * stalls.  On the machine of issue 17, from frame 300 one frame in 16 is
 * 1.45 x slower (8 misses in 128 frames: the margin must grow).  Grown to
 * the quantile of the last MISS_W frames alone, it took the stalls (1 %
 * of 128 frames is 1.3 of them), as the still view at 33 ms did: margin
 * 3.03, 16 nodes coarsened, and the held front kept them.  Over 8 seeds
 * the largest margin with the stalls stays within 15 % of the same run's
 * without them. */
static double burst_run(uint64_t seed, int stalls)
{
    machine m = {{8, 0.02, 1e-4, 3e-6}, 0.12, 1, {seed * 0x2545f4914f6cdd1dull}};
    hlod_engine_desc d = desc(33.3);
    hlod_cost_model cm;
    hlod_cost_model_init(&cm, &d);
    const double dr = 140, c = 64e3, p = 6e5;
    double top = 0;
    for (int f = 0; f < 700; f++) {
        double ms = machine_ms(&m, dr, c, p);
        if (f >= 300 && f % 16 == 0)
            ms *= 1.45;
        if (stalls && (f == 303 || f == 310))
            ms *= f == 303 ? 3.0 : 3.1;
        hlod_cost_model_fit(&cm, &d, dr, c, p, ms);
        if (f >= 200 && cm.margin > top)
            top = cm.margin;
    }
    return top;
}

static void stall_burst_grows_margin_little(void)
{
    for (uint64_t seed = 1; seed <= 8; seed++) {
        double plain = burst_run(seed, 0), burst = burst_run(seed, 1);
        fprintf(stderr, "  seed %llu: largest margin %.3f with the stalls, %.3f without\n",
                (unsigned long long)seed, burst, plain);
        /* the margin grows to the tail (1.45 x one frame in 16), and the
         * stalls add little to it */
        CHECKF(plain >= 1.3 && burst >= plain && burst <= 1.15 * plain,
               "seed %llu: largest margin %.3f with the stalls, %.3f without",
               (unsigned long long)seed, burst, plain);
    }
}

/* A persistent change is followed within a few frames: the machine gets
 * 40 % slower, and within 8 frames the prediction is within 10 % again;
 * then 40 % faster than that. */
static void persistent_change_followed(void)
{
    machine m = {{8, 0.02, 1e-4, 3e-6}, 0.05, 0, {42}};
    hlod_engine_desc d = desc(33.3);
    hlod_cost_model cm;
    hlod_cost_model_init(&cm, &d);
    rng r = {7};
    for (int f = 0; f < 300; f++) {
        double dr, c, p;
        moving_front(&r, &dr, &c, &p);
        hlod_cost_model_fit(&cm, &d, dr, c, p, machine_ms(&m, dr, c, p));
    }
    double factors[2] = {1.4, 1 / 1.4};
    for (int step = 0; step < 2; step++) {
        for (int k = 0; k < 4; k++)
            m.t[k] *= factors[step];
        int followed = -1;
        for (int f = 0; f < 40; f++) {
            double dr, c, p;
            moving_front(&r, &dr, &c, &p);
            hlod_cost_model_fit(&cm, &d, dr, c, p, machine_ms(&m, dr, c, p));
            if (followed < 0 && rel_err(&cm, &m, 200, 1e5, 8e5) < 0.10)
                followed = f + 1;
        }
        fprintf(stderr, "  x%.2f: followed after %d frames\n", factors[step], followed);
        CHECKF(followed >= 4 && followed <= 6, "x%.2f: followed after %d frames (4-6 promised)",
               factors[step], followed);
    }
}

/* A settled front (draws dr, cost c, pixels p, 300 frames on issue 17's
 * machine) whose machine then changes by each of factors in turn: for
 * each change, the frames until the prediction is within 10 % again
 * (-1: not in 200 frames) and the model changes in those 200 frames. */
static void settled_follow(uint64_t seed, const double *front, const double *factors, int steps,
                           int *followed, uint32_t *moves)
{
    machine m = {{8, 0.02, 1e-4, 3e-6}, 0.12, 1, {seed * 0x2545f4914f6cdd1dull}};
    hlod_engine_desc d = desc(33.3);
    hlod_cost_model cm;
    hlod_cost_model_init(&cm, &d);
    const double dr = front[0], c = front[1], p = front[2];
    for (int f = 0; f < 300; f++)
        hlod_cost_model_fit(&cm, &d, dr, c, p, machine_ms(&m, dr, c, p));
    for (int step = 0; step < steps; step++) {
        for (int k = 0; k < 4; k++)
            m.t[k] *= factors[step];
        uint32_t before = cm.scale_updates + cm.shape_updates;
        followed[step] = -1;
        for (int f = 0; f < 200; f++) {
            hlod_cost_model_fit(&cm, &d, dr, c, p, machine_ms(&m, dr, c, p));
            if (followed[step] < 0 && rel_err(&cm, &m, dr, c, p) < 0.10)
                followed[step] = f + 1;
        }
        moves[step] = cm.scale_updates + cm.shape_updates - before;
        fprintf(stderr, "  seed %llu x%.2f: followed after %d frames, %u model changes\n",
                (unsigned long long)seed, factors[step], followed[step], moves[step]);
    }
}

/* A settled front follows a persistent error too, once: the still front
 * of still_run on the measured machine, which then gets 40 % faster (the
 * loads that competed for the CPU stopped), then 40 % slower again.  Each
 * time the prediction is within 10 % again within SETTLED_K + 8 frames
 * (cost_model.c: a settled front is checked over 32 frames), and the
 * model moves once per change, not with the noise. */
static void settled_error_followed(void)
{
    const double front[3] = {140, 64e3, 6e5}, factors[2] = {1 / 1.4, 1.4};
    for (uint64_t seed = 1; seed <= 4; seed++) {
        int followed[2];
        uint32_t moves[2];
        settled_follow(seed, front, factors, 2, followed, moves);
        for (int step = 0; step < 2; step++)
            CHECKF(followed[step] >= 14 && followed[step] <= 29 && moves[step] == 1,
                   "seed %llu x%.2f: followed after %d frames, %u model changes",
                   (unsigned long long)seed, factors[step], followed[step], moves[step]);
    }
}

/* A settled front that runs far faster than its estimate is followed
 * within SCALE_K frames, not after SETTLED_K: the machine of issue 17
 * with a front of 6 nodes the model puts at 3 x its time (parts city,
 * walk-drive, nohyst: 19.3 ms estimated, 5.3-6.9 ms measured, the budget
 * at its floor and reference frames at 6 dB).  Within 12 frames the
 * prediction is within 10 %, with one model change in 200 frames.  The
 * old gate took 23-24 frames.  still_front_publishes_nothing is the
 * other side: noise never passes this rule. */
static void settled_fast_front_followed(void)
{
    const double front[3] = {6, 2552, 5.5e6}, factor = 1.0 / 3;
    for (uint64_t seed = 1; seed <= 8; seed++) {
        int followed;
        uint32_t moves;
        settled_follow(seed, front, &factor, 1, &followed, &moves);
        CHECKF(followed == 7 && moves == 1,
               "seed %llu: a settled front 3 x faster followed after %d frames, %u model changes",
               (unsigned long long)seed, followed, moves);
    }
}

/* The margin keeps 99 % of frames within the target: a front sized so
 * that prediction x margin = target, on the heavy-tailed machine, meets
 * the target in at least 98 % of frames, and the mean stays at or above
 * 65 % of the target (the margin is not wasteful).  aim_mean keeps the
 * margin at 1, so the mean sits on the target, as in the paper. */
static void margin_meets_the_deadline(void)
{
    for (int mean_mode = 0; mean_mode < 2; mean_mode++) {
        machine m = {{8, 0.02, 1e-4, 3e-6}, 0.10, 2, {99}};
        hlod_engine_desc d = desc(33.3);
        d.aim_mean = mean_mode ? 1 : -1;
        hlod_cost_model cm;
        hlod_cost_model_init(&cm, &d);
        rng r = {5};
        int met = 0, n = 0;
        double sum = 0;
        for (int f = 0; f < 3000; f++) {
            /* a front with spread, scaled to fill the budget */
            double dr, c, p;
            moving_front(&r, &dr, &c, &p);
            double budget = d.target_ms / cm.margin - cm.theta[0];
            double per = hlod_cost_model_predict(&cm, dr, c, p) - cm.theta[0];
            double s = per > 0 ? budget / per : 1;
            dr *= s;
            c *= s;
            p *= s;
            double ms = machine_ms(&m, dr, c, p);
            hlod_cost_model_fit(&cm, &d, dr, c, p, ms);
            if (f >= 200) {
                met += ms <= d.target_ms;
                sum += ms;
                n++;
            }
        }
        double frac = (double)met / n, mean = sum / n / d.target_ms;
        fprintf(stderr, "  %s: %.3f of frames within target, mean %.3f x target, margin %.3f\n",
                mean_mode ? "aim_mean" : "deadline", frac, mean, cm.margin);
        if (mean_mode) {
            CHECK(cm.margin == 1);
            CHECKF(mean > 0.93 && mean < 1.07, "mean %.3f x target", mean);
        } else {
            CHECKF(frac >= 0.98, "%.3f of frames within target", frac);
            CHECKF(mean >= 0.65, "mean %.3f x target", mean);
        }
    }
}

/* The first frames of a run (shaders compiled on first use, cold pages)
 * leave no margin behind: frames 0-3 take 2.5-3.6 x the machine's time,
 * 40 loading frames vary (five of them 1.3 x slower: loads competing for
 * the CPU, as in frames 39-41 of that run), then the front settles for
 * 400 frames, as the still view at 33 ms did.  The margin ends under 1.6
 * in every seed (1.13-1.45; the same runs without the slow start end at
 * 1.15-1.59).  With the warm-up in the margin's tail and miss count, 4 of
 * the 10 seeds ended at 1.65-3.28; in the engine, 2.59: the front fell to
 * 28 % of the target and stayed. */
static double cold_start_margin(int cold, uint64_t seed)
{
    static const double slow[4] = {3.6, 2.5, 2.2, 3.3};
    machine m = {{4, 0.02, 1e-4, 1e-6}, 0.06, 1, {seed * 0x9e3779b97f4a7c15ull}};
    hlod_engine_desc d = desc(33);
    hlod_cost_model cm;
    hlod_cost_model_init(&cm, &d);
    rng r = {seed + 11};
    for (int f = 0; f < 445; f++) {
        double dr = 41, c = 18e3, p = 2.8e6;
        if (f < 45)
            moving_front(&r, &dr, &c, &p);
        double ms = machine_ms(&m, dr, c, p);
        if (cold && f < 4)
            ms *= slow[f];
        if (f >= 38 && f < 43)
            ms *= 1.3; /* loads compete for the CPU, as frames 39-41 of that run */
        hlod_cost_model_fit(&cm, &d, dr, c, p, ms);
    }
    return cm.margin;
}

static void cold_start_leaves_no_margin(void)
{
    for (uint64_t seed = 1; seed <= 10; seed++) {
        double warm = cold_start_margin(0, seed), cold = cold_start_margin(1, seed);
        fprintf(stderr, "  seed %llu: margin %.3f after a cold start, %.3f without\n",
                (unsigned long long)seed, cold, warm);
        CHECKF(cold < 1.6,
               "seed %llu: margin %.3f after a cold start, %.3f without",
               (unsigned long long)seed, cold, warm);
    }
}

/* A camera that turns to the sky: 70 frames draw nothing (the machine's
 * fixed part alone, 1.7 ms), between two stretches of moving fronts whose
 * pixels hardly vary (the fit may then put the fixed part in the pixel
 * term, as on fly).  From the second, the empty frames are predicted
 * within 25 %, no
 * coefficient grows past 3 x its value before the turn, and the margin
 * stays under 2.  Without the floor from empty frames: v_time 170 x twice
 * and the margin at 4 on fly. */
static void sky_frames_keep_the_model(void)
{
    for (uint64_t seed = 1; seed <= 4; seed++) {
        machine m = {{1.7, 0.02, 1.5e-4, 3e-6}, 0.06, 1, {seed * 0x9e3779b97f4a7c15ull}};
        hlod_engine_desc d = desc(33);
        hlod_cost_model cm;
        hlod_cost_model_init(&cm, &d);
        rng r = {seed + 3};
        double before[4] = {0}, worst = 0, top_margin = 0, empty_err = 0;
        for (int f = 0; f < 700; f++) {
            double dr = 0, c = 0, p = 0;
            int sky = f >= 400 && f < 470;
            if (!sky) {
                dr = 80 + 120 * uniform(&r);
                c = 3e4 + 6e4 * uniform(&r);
                p = 2.5e6 * (0.95 + 0.1 * uniform(&r));
            }
            if (f == 399)
                memcpy(before, cm.theta, sizeof before);
            if (sky && f > 400)
                empty_err = fmax(empty_err, fabs(hlod_cost_model_predict(&cm, 0, 0, 0) - 1.7) / 1.7);
            hlod_cost_model_fit(&cm, &d, dr, c, p, machine_ms(&m, dr, c, p));
            if (f >= 400) {
                for (int k = 1; k < 4; k++)
                    if (before[k] > 0)
                        worst = fmax(worst, cm.theta[k] / before[k]);
                top_margin = fmax(top_margin, cm.margin);
            }
        }
        fprintf(stderr, "  seed %llu: empty frames predicted within %.0f %% (after the first), "
                "a term grew %.2f x at most, margin %.2f at most\n", (unsigned long long)seed,
                100 * empty_err, worst, top_margin);
        CHECKF(worst <= 3 && top_margin < 2 && empty_err <= 0.25,
               "seed %llu: a term grew %.2f x, margin %.2f, empty frames %.0f %% off",
               (unsigned long long)seed, worst, top_margin, 100 * empty_err);
    }
}

/* Fronts the model misses one way and the other in turn: after 300 quiet
 * frames (3 % noise), 40 frames alternately 1.25 x and 0.8 x the model's
 * machine (walk-drive: 250 and 280 nodes every other frame, -20 % and
 * +20 %).  The scale is not undone within SCALE_K frames of a change:
 * without that guard the median of the last 7 swung with each frame and
 * the scale went up and down on consecutive frames (x1.21, x0.81, x1.24,
 * x0.84), the budget and the front with it. */
static void alternating_error_no_flip_flop(void)
{
    for (uint64_t seed = 1; seed <= 4; seed++) {
        machine m = {{6, 0.01, 5e-5, 2e-6}, 0.03, 0, {seed * 0x9e3779b97f4a7c15ull}};
        hlod_engine_desc d = desc(33);
        hlod_cost_model cm;
        hlod_cost_model_init(&cm, &d);
        rng r = {seed + 21};
        uint32_t before = 0, reversals = 0, last_dir = 0;
        int last_at = -100;
        for (int f = 0; f < 340; f++) {
            double dr, c, p;
            moving_front(&r, &dr, &c, &p);
            double ms = machine_ms(&m, dr, c, p);
            if (f >= 300)
                ms *= f % 2 ? 1.25 : 0.8;
            double fixed = cm.theta[0];
            uint32_t n = cm.scale_updates;
            hlod_cost_model_fit(&cm, &d, dr, c, p, ms);
            if (f == 299)
                before = cm.scale_updates;
            if (f >= 300 && cm.scale_updates != n) {
                uint32_t dir = cm.theta[0] > fixed ? 1 : 2;
                reversals += last_dir && dir != last_dir && f - last_at < 7;
                last_dir = dir;
                last_at = f;
            }
        }
        uint32_t during = cm.scale_updates - before;
        fprintf(stderr, "  seed %llu: %u scale changes in the 40 alternating frames, %u undone "
                "within 7 frames\n", (unsigned long long)seed, during, reversals);
        CHECKF(reversals == 0 && during >= 2,
               "seed %llu: %u scale changes undone within 7 frames (%u in all)",
               (unsigned long long)seed, reversals, during);
    }
}

/* The shape (the terms' split) changes at most once per 64 frames once
 * the window is full: a machine whose split swings every 20 frames
 * between two (per-draw time 4 x, per-cost time / 4, at equal total on
 * the mean front) gets shape changes, and never two within 64 frames. */
static void shape_changes_at_most_once_per_64_frames(void)
{
    for (uint64_t seed = 1; seed <= 4; seed++) {
        machine m = {{6, 0.01, 5e-5, 2e-6}, 0.02, 0, {seed * 0x9e3779b97f4a7c15ull}};
        const machine a = m;
        hlod_engine_desc d = desc(33);
        hlod_cost_model cm;
        hlod_cost_model_init(&cm, &d);
        rng r = {seed + 5};
        uint32_t n = 0, closest = UINT32_MAX;
        int last = -1;
        for (int f = 0; f < 1000; f++) {
            if (f >= 100 && f % 20 == 0) {
                int swung = (f / 20) % 2;
                m.t[1] = swung ? 4 * a.t[1] : a.t[1];
                m.t[2] = swung ? a.t[2] / 4 : a.t[2];
            }
            double dr, c, p;
            moving_front(&r, &dr, &c, &p);
            uint32_t before = cm.shape_updates;
            hlod_cost_model_fit(&cm, &d, dr, c, p, machine_ms(&m, dr, c, p));
            if (f >= 45 && cm.shape_updates != before) {
                if (last >= 0 && (uint32_t)(f - last) < closest)
                    closest = (uint32_t)(f - last);
                last = f;
                n++;
            }
        }
        fprintf(stderr, "  seed %llu: %u shape changes after frame 45, the closest %u frames "
                "apart\n", (unsigned long long)seed, n, closest);
        CHECKF(n >= 2 && closest >= 64, "seed %llu: %u shape changes, two %u frames apart",
               (unsigned long long)seed, n, closest);
    }
}

/* The margin shrinks only when the margin wanted is more than 0.1 below
 * it in log (9.5 %), so each step down is at least that: a machine with
 * 20 % noise for 400 frames, then 3 %, on a moving front. */
static void margin_shrinks_in_log_steps_over_0_1(void)
{
    for (uint64_t seed = 1; seed <= 4; seed++) {
        machine m = {{6, 0.01, 5e-5, 2e-6}, 0.20, 0, {seed * 0x2545f4914f6cdd1dull}};
        hlod_engine_desc d = desc(33);
        hlod_cost_model cm;
        hlod_cost_model_init(&cm, &d);
        rng r = {seed + 9};
        uint32_t downs = 0;
        double smallest = INFINITY, high = 0;
        for (int f = 0; f < 1400; f++) {
            if (f == 400)
                m.sigma = 0.03;
            double dr, c, p;
            moving_front(&r, &dr, &c, &p);
            double before = cm.margin;
            hlod_cost_model_fit(&cm, &d, dr, c, p, machine_ms(&m, dr, c, p));
            if (f == 399)
                high = cm.margin;
            if (f >= 45 && cm.margin < before) {
                downs++;
                smallest = fmin(smallest, 1 - cm.margin / before);
            }
        }
        fprintf(stderr, "  seed %llu: margin %.3f at frame 400, %.3f at the end, %u steps down, "
                "the smallest %.1f %%\n", (unsigned long long)seed, high, cm.margin, downs,
                100 * smallest);
        CHECKF(downs >= 1 && smallest > 1 - exp(-0.1) && cm.margin < 0.85 * high,
               "seed %llu: %u steps down, the smallest %.1f %%, margin %.3f from %.3f",
               (unsigned long long)seed, downs, 100 * smallest, cm.margin, high);
    }
}

/* Garbage in: non-finite and negative samples are ignored, and nothing
 * published becomes non-finite or negative. */
static void bad_samples_ignored(void)
{
    hlod_engine_desc d = desc(20);
    hlod_cost_model cm;
    hlod_cost_model_init(&cm, &d);
    hlod_cost_model before = cm;
    hlod_cost_model_fit(&cm, &d, NAN, 1, 1, 5);
    hlod_cost_model_fit(&cm, &d, 1, INFINITY, 1, 5);
    hlod_cost_model_fit(&cm, &d, 1, 1, -1, 5);
    hlod_cost_model_fit(&cm, &d, 1, 1, 1, NAN);
    CHECK(memcmp(&before, &cm, sizeof cm) == 0);
    rng r = {3};
    for (int f = 0; f < 500; f++) {
        double y = f % 50 == 0 ? 1e9 : f % 7 == 0 ? 0 : 5 + uniform(&r);
        hlod_cost_model_fit(&cm, &d, f % 3, 1e3 * (f % 5), 0, y);
        for (int k = 0; k < 4; k++)
            CHECK(isfinite(cm.theta[k]) && cm.theta[k] >= 0);
        CHECK(isfinite(cm.margin) && cm.margin >= 0.5 && cm.margin <= 4);
        CHECK(cm.theta[0] <= 0.8 * d.target_ms);
    }
}

int main(void)
{
    RUN(fit_recovers_machine);
    RUN(still_front_publishes_nothing);
    RUN(persistent_change_followed);
    RUN(stall_burst_grows_margin_little);
    RUN(settled_error_followed);
    RUN(settled_fast_front_followed);
    RUN(margin_meets_the_deadline);
    RUN(cold_start_leaves_no_margin);
    RUN(sky_frames_keep_the_model);
    RUN(alternating_error_no_flip_flop);
    RUN(shape_changes_at_most_once_per_64_frames);
    RUN(margin_shrinks_in_log_steps_over_0_1);
    RUN(bad_samples_ignored);
    return check_done();
}
