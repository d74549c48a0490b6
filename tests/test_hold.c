/*
 * test_hold.c - the still-camera hold's inputs (engine/hold.c,
 * docs/runtime.md "The still-camera hold"): held while the view stays
 * still, taken anew on a target change and after a slowdown, and after a
 * slowdown given back to the model only where its inputs leave the held
 * front more room, so recovery never coarsens the front.
 */
#include "check.h"
#include "hold.h"

static hlod_select_in inputs(double budget, double v_time)
{
    hlod_select_in in = {0};
    in.hold_since = 61;
    in.budget_ms = budget;
    in.share_ms = budget;
    in.v_time = v_time;
    in.draw_ms = 0.01;
    in.pixel_ms = 1e-6;
    return in;
}

/* A hold slowed down at frame 80 to budget 5 ms, v_time 2e-3; then
 * HOLD_RECOVER clean frames. */
static void slowed_hold(hlod_hold *h, const hlod_front_load *f, uint32_t *frame)
{
    memset(h, 0, sizeof *h);
    hlod_select_in in = inputs(10, 1e-3);
    for (*frame = 61; *frame < 80; (*frame)++) {
        hlod_hold_inputs(h, 1, *frame, 33, f, &in);
        hlod_hold_measured(h, *frame < 80 - HOLD_SLOW_MISSES ? 20 : 40, 33);
    }
    in = inputs(5, 2e-3);
    hlod_hold_inputs(h, 1, *frame, 33, f, &in);   /* 8 misses: taken, slowed */
    CHECK(h->slowed && h->budget_ms == 5 && h->v_time == 2e-3);
    for (uint32_t k = 0; k < HOLD_RECOVER; k++) {
        hlod_hold_measured(h, 20, 33);
        (*frame)++;
        in = inputs(5, 2e-3);
        hlod_hold_inputs(h, 1, *frame, 33, f, &in);
    }
    hlod_hold_measured(h, 20, 33);
    (*frame)++;
}

static void recovery_never_coarsens(void)
{
    /* the held front: 100 draws, cost 1500, 2e5 pixels.  Under the held
     * inputs it takes 1 + 3 + 0.2 = 4.2 ms of the 5: room 0.8 */
    const hlod_front_load f = {100, 1500, 2e5};
    hlod_hold h;
    uint32_t frame;
    slowed_hold(&h, &f, &frame);
    /* a larger budget whose grown v_time leaves the front less room
     * (6 - 1 - 4.5 - 0.2 = 0.3): stays held */
    hlod_select_in in = inputs(6, 3e-3);
    hlod_hold_inputs(&h, 1, frame, 33, &f, &in);
    CHECKF(in.budget_ms == 5 && in.v_time == 2e-3, "taken: budget %g v_time %g", in.budget_ms,
           in.v_time);
    /* more room (8 - 1 - 3 - 0.2 = 3.8): taken */
    in = inputs(8, 2e-3);
    hlod_hold_inputs(&h, 1, frame + 1, 33, &f, &in);
    CHECK(in.budget_ms == 8 && h.budget_ms == 8);
    /* held from then on: the model's next inputs do not reach the selection */
    in = inputs(9, 1e-3);
    hlod_hold_inputs(&h, 1, frame + 2, 33, &f, &in);
    CHECK(in.budget_ms == 8 && in.v_time == 2e-3);
}

static void held_and_given_way(void)
{
    const hlod_front_load f = {10, 100, 1e4};
    hlod_hold h;
    memset(&h, 0, sizeof h);
    hlod_select_in in = inputs(10, 1e-3);
    hlod_hold_inputs(&h, 1, 61, 33, &f, &in);
    CHECK(h.since == 61 && h.budget_ms == 10 && !h.slowed);
    /* the model moves; the hold does not */
    in = inputs(12, 5e-4);
    hlod_hold_inputs(&h, 1, 62, 33, &f, &in);
    CHECK(in.budget_ms == 10 && in.v_time == 1e-3 && in.share_ms == 10);
    /* a new target takes the model's inputs */
    in = inputs(12, 5e-4);
    hlod_hold_inputs(&h, 1, 63, 20, &f, &in);
    CHECK(in.budget_ms == 12 && h.budget_ms == 12 && h.target_ms == 20);
    /* no hold (the camera moved), or a policy that does not hold: untouched */
    in = inputs(7, 1e-3);
    in.hold_since = 0;
    hlod_hold_inputs(&h, 1, 64, 20, &f, &in);
    CHECK(in.budget_ms == 7 && h.since == 0);
    in = inputs(7, 1e-3);
    hlod_hold_inputs(&h, 0, 65, 20, &f, &in);
    CHECK(in.budget_ms == 7 && h.since == 0);
}

int main(void)
{
    RUN(held_and_given_way);
    RUN(recovery_never_coarsens);
    return check_done();
}
