/*
 * test_dynres.c - resolution as the last knob (engine/dynres.h, setting
 * dyn_res): the steps' hysteresis on made-up frame times, and an engine
 * on a synthetic fill-bound machine (no GL) whose coarsest frame misses
 * the target at full size.
 */
#include "check.h"
#include "dynres.h"
#include "hlod/engine.h"
#include "store_fixture.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A frame's time at d's scale: fill_ms of fill times the area, plus
 * fixed_ms. */
static double frame_ms(const hlod_dynres *d, double fill_ms, double fixed_ms)
{
    double s = hlod_dynres_scale(d);
    return fill_ms * s * s + fixed_ms;
}

/* Frames until the next step against a 10 ms target (*dir its way); -1
 * when none in `limit`. */
static int frames_to_step(hlod_dynres *d, double fill_ms, double fixed_ms, int coarsest,
                          int limit, int *dir)
{
    for (int f = 1; f <= limit; f++) {
        int s = hlod_dynres_update(d, frame_ms(d, fill_ms, fixed_ms), 10, coarsest);
        if (s) {
            *dir = s;
            return f;
        }
    }
    return -1;
}

static void steps_and_hysteresis(void)
{
    hlod_dynres d;
    int dir = 0, f;
    /* fill-bound misses: no step while the engine settles, then a step
     * down once the window is full, kept (it saved), and one per hold +
     * window at most, down to the last step and no further */
    hlod_dynres_reset(&d);
    CHECK(hlod_dynres_scale(&d) == 1.0);
    f = frames_to_step(&d, 40, 0, 1, 200, &dir);
    CHECKF(f == DYNRES_SETTLE + 1 && dir == 1, "first step after %d frames (dir %d), want %d down",
           f, dir, DYNRES_SETTLE + 1);
    for (int k = 2; k < DYNRES_STEPS; k++) {
        f = frames_to_step(&d, 40, 0, 1, 200, &dir);
        CHECKF(f > DYNRES_HOLD && f <= DYNRES_HOLD + DYNRES_WINDOW && dir == 1,
               "step %d after %d frames (dir %d)", k, f, dir);
    }
    CHECKF(d.step == DYNRES_STEPS - 1 && hlod_dynres_scale(&d) == 0.5 && d.reverted == 0,
           "at step %d, scale %g, %u taken back", d.step, hlod_dynres_scale(&d), d.reverted);
    CHECKF(frames_to_step(&d, 40, 0, 1, 200, &dir) == -1, "stepped past the last scale");
    /* misses that detail can still fix are detail's */
    hlod_dynres_reset(&d);
    CHECKF(frames_to_step(&d, 40, 0, 0, 400, &dir) == -1, "stepped down with detail to drop");
    /* fewer than DYNRES_DOWN_OF misses in a window: no step */
    hlod_dynres_reset(&d);
    int stepped = 0;
    for (int k = 0; k < 400; k++)
        stepped |= hlod_dynres_update(&d, k % 2 ? 11 : 9, 10, 1) != 0;
    CHECKF(!stepped, "every other frame missing (4 of 8) stepped");
    /* a step that does not save (the frame is not fill) is taken back once
     * judged, and the next try waits DYNRES_BACKOFF frames, then twice that */
    hlod_dynres_reset(&d);
    f = frames_to_step(&d, 0, 20, 1, 200, &dir);
    CHECK(f == DYNRES_SETTLE + 1 && dir == 1);
    f = frames_to_step(&d, 0, 20, 1, 200, &dir);
    CHECKF(f == DYNRES_WINDOW && dir == -1 && d.step == 0 && d.reverted == 1,
           "a step that saved nothing: back after %d frames (dir %d, step %d)", f, dir, d.step);
    f = frames_to_step(&d, 0, 20, 1, 2000, &dir);
    CHECKF(dir == 1 && f >= DYNRES_BACKOFF && f <= DYNRES_BACKOFF + DYNRES_WINDOW,
           "the next try after %d frames (want the back-off, %d)", f, DYNRES_BACKOFF);
    (void)frames_to_step(&d, 0, 20, 1, 200, &dir);
    f = frames_to_step(&d, 0, 20, 1, 4000, &dir);
    CHECKF(dir == 1 && f >= 2 * DYNRES_BACKOFF && f <= 2 * DYNRES_BACKOFF + DYNRES_WINDOW,
           "the third try after %d frames (want twice the back-off)", f);
    /* up: only when every frame of the window, grown to the next step's
     * pixels, fits DYNRES_UP_FRAC of the target */
    hlod_dynres_reset(&d);
    (void)frames_to_step(&d, 40, 0, 1, 200, &dir);
    (void)frames_to_step(&d, 40, 0, 1, 200, &dir);
    CHECK(d.step == 2);
    double up = hlod_dynres_step_scale(1);
    double edge = DYNRES_UP_FRAC * 10 / (up * up); /* the fill at which the step up just fits */
    CHECKF(frames_to_step(&d, edge * 1.01, 0, 1, 200, &dir) == -1, "stepped up at 1.01 x the edge");
    f = frames_to_step(&d, edge * 0.99, 0, 1, 200, &dir);
    CHECKF(f > 0 && f <= DYNRES_WINDOW && dir == -1 && d.step == 1,
           "0.99 x the edge: step %d after %d frames (dir %d)", d.step, f, dir);
    /* one slow frame in the window holds the step */
    stepped = 0;
    for (int k = 0; k < 60; k++)
        stepped |= hlod_dynres_update(&d, k % DYNRES_WINDOW ? 1 : 9.9, 10, 1) == -1;
    CHECKF(!stepped, "stepped up with a frame at 0.99 x the target in every window");
}

/* A fill-bound machine: the frame's pixels cost fill_ms at full size
 * (scaled by the area drawn), each unit of cost per_cost. */
typedef struct fill_machine {
    double fill_ms, per_cost;
} fill_machine;

static double fill_time(void *user, const hlod_frame_stats *st)
{
    const fill_machine *m = user;
    double s = st->res_scale > 0 ? st->res_scale : 1;
    return m->fill_ms * s * s + m->per_cost * st->cost_drawn;
}

static char g_dir[256];

typedef struct run_out {
    int met, frames, scaled, detail_while_scaled, min_step_frame;
    double min_scale, last_scale, tris_before, tris_after;
} run_out;

/* frames [f0, f1) of an engine on machine m, 16 ms target */
static void run(hlod_engine *e, const hlod_camera *cam, int f0, int f1, run_out *o)
{
    hlod_frame_stats st;
    for (int f = f0; f < f1; f++) {
        CHECK(hlod_engine_frame(e, cam, 1.0 / 30, &st) == HLOD_OK);
        o->frames++;
        o->met += st.measured_ms <= 16;
        o->scaled += st.res_scale < 1;
        if (st.res_scale < o->min_scale)
            o->min_scale = st.res_scale;
        /* below full size the budget stays at its floor */
        o->detail_while_scaled += st.res_scale < 1 && st.budget_ms > 0.1 * 16 + 1e-9;
        o->last_scale = st.res_scale;
        o->tris_after = (double)st.tris_drawn;
    }
}

static void engine_fill_bound(void)
{
    char path[512];
    snprintf(path, sizeof path, "%s/dynres.hlod", g_dir);
    fixture_opts fo = {0};
    fo.roots = 4;
    fo.depth = 3;
    CHECK(fixture_write(path, &fo, NULL) == HLOD_OK);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (!s)
        return;
    hlod_camera cam;
    double eye[3] = {150, -80, 60}, at[3] = {200, 50, 0}, up[3] = {0, 0, 1};
    CHECK(hlod_camera_look_at(&cam, eye, at, up, 60, 0.5, 1e5, 1280, 720) == HLOD_OK);
    for (int on = 0; on < 2; on++) {
        fill_machine m = {24, 1e-4}; /* 1.5 x the 16 ms target before any geometry */
        hlod_engine_desc d = {0};
        d.target_ms = 16;
        d.time_model = fill_time;
        d.time_model_user = &m;
        d.dyn_res = on ? 1 : -1;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        if (!e)
            break;
        CHECK(hlod_engine_load_all_leaves(e, &cam) == HLOD_OK);
        run_out a = {.min_scale = 1}, b = {.min_scale = 1};
        run(e, &cam, 0, 100, &a);      /* settles */
        run_out c = {.min_scale = 1};
        run(e, &cam, 100, 400, &c);    /* judged */
        printf("REPORT dynres on=%d fill_ms=24 deadline_met=%.3f scaled_frames=%d min_scale=%.2f\n",
               on, (double)c.met / c.frames, c.scaled, c.min_scale);
        if (!on) {
            CHECKF(c.met == 0 && c.scaled == 0, "premise: without dyn_res %d of %d frames met, "
                   "%d scaled", c.met, c.frames, c.scaled);
        } else {
            CHECKF(c.met >= 0.98 * c.frames, "dyn_res: %d of %d frames met 16 ms", c.met,
                   c.frames);
            CHECKF(c.min_scale < 1 && c.min_scale >= 0.5, "dyn_res: min scale %g", c.min_scale);
            CHECKF(a.detail_while_scaled + c.detail_while_scaled == 0,
                   "%d frames below full size had a budget over its floor",
                   a.detail_while_scaled + c.detail_while_scaled);
            /* the scene gets cheap: full size comes back first, then
             * detail */
            b.tris_before = c.tris_after;
            m.fill_ms = 2;
            run(e, &cam, 400, 700, &b);
            CHECKF(b.last_scale == 1 && b.detail_while_scaled == 0,
                   "cheap again: scale %g at the end, %d frames scaled with detail added",
                   b.last_scale, b.detail_while_scaled);
            CHECKF(b.tris_after > b.tris_before, "cheap again: %.0f triangles, %.0f before",
                   b.tris_after, b.tris_before);
            printf("REPORT dynres recovery scale=%.2f tris %.0f -> %.0f\n", b.last_scale,
                   b.tris_before, b.tris_after);
        }
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod-test-dynres-XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(steps_and_hysteresis);
    RUN(engine_fill_bound);
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", g_dir);
    return check_done();
}
