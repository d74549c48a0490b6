/*
 * test_engine.c - the runtime's selection and residency, without GL.
 *
 * Synthetic stores (tests/store_fixture.h) and an engine with no renderer:
 * the traversal, hysteresis, cost model and loader run for real; frame time
 * comes from a synthetic machine (hlod_time_model) or from the
 * deterministic mode's fixed v_time.  Each test checks one behaviour of
 * the runtime (docs/runtime.md): time slices, the estimate bound, the missing-sibling
 * rule, hysteresis clamps and settling, pricing only what is near the view,
 * the memory budget under random jumps, load-once when the scene fits,
 * corrupt and failing nodes, a slow disk that must not stall the render
 * thread, and a city far from the origin selecting exactly as at it.
 */
#define _GNU_SOURCE /* RUSAGE_THREAD (cpu_span.h) */
#include "check.h"
#include "inspect.h"
#include "selection.h" /* hlod_node_cost */
#include "engine_check.h"
#include "hlod/metrics.h"
#include "store_fixture.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <time.h>
#include <unistd.h>
#include <sys/wait.h>
#if defined(__GLIBC__)
#include <malloc.h>

/* The engine as inspect.h shows it. */
static hlod_node_look node_look(const hlod_engine *e, uint32_t node)
{
    return hlod_inspect_node(e, node);
}

static uint32_t last_frame(const hlod_engine *e)
{
    return hlod_inspect_frame(e);
}
#endif

static char g_dir[256];

static const char *tmp_path(const char *name, char *buf, size_t n)
{
    snprintf(buf, n, "%s/%s", g_dir, name);
    return buf;
}

static hlod_store *make_store(const char *name, const fixture_opts *o, uint32_t *count)
{
    char path[512];
    tmp_path(name, path, sizeof path);
    hlod_result r = fixture_write(path, o, count);
    CHECKF(r == HLOD_OK, "fixture_write: %s", hlod_result_str(r));
    hlod_store *s = NULL;
    r = hlod_store_open(path, NULL, &s);
    CHECKF(r == HLOD_OK, "open: %s", hlod_result_str(r));
    return s;
}

/* n frames of camera cam, 1/30 s each; *st (unless NULL) gets the last
 * one's stats. */
static void run_frames(hlod_engine *e, const hlod_camera *cam, int n, hlod_frame_stats *st)
{
    for (int f = 0; f < n; f++)
        CHECK(hlod_engine_frame(e, cam, 1.0 / 30, st) == HLOD_OK);
}

/* A store of `roots` blocks (x in [0, 100], [110, 210], ...), each a root
 * over its four quadrants. */
static hlod_store *shallow_store(const char *name, uint32_t roots)
{
    fixture_opts o = {0};
    o.roots = roots;
    o.depth = 1;
    return make_store(name, &o, NULL);
}

static void look(hlod_camera *cam, double ex, double ey, double ez, double tx, double ty,
                 double tz)
{
    double eye[3] = {ex, ey, ez}, at[3] = {tx, ty, tz}, up[3] = {0, 0, 1};
    hlod_result r = hlod_camera_look_at(cam, eye, at, up, 60, 0.5, 1e5, 1280, 720);
    CHECK(r == HLOD_OK);
}

/* xorshift64: each test seeds its own (RNG_SEED), so a test's cameras do
 * not depend on which tests ran before it. */
#define RNG_SEED 88172645463325252ull
static double frand(uint64_t *rng)
{
    *rng ^= *rng << 13;
    *rng ^= *rng >> 7;
    *rng ^= *rng << 17;
    return (double)(*rng >> 11) / 9007199254740992.0;
}

/* A random camera over and around the fixture's blocks (x in [0, 440]). */
static void random_camera(hlod_camera *cam, double ox, double oy, uint64_t *rng)
{
    double ex = ox - 200 + 840 * frand(rng), ey = oy - 200 + 500 * frand(rng);
    double ez = 1 + 300 * frand(rng);
    double tx = ox + 440 * frand(rng), ty = oy + 100 * frand(rng);
    look(cam, ex, ey, ez, tx, ty, 0);
}

/* A synthetic machine: fixed + per-cost time, with optional noise, all of
 * it times `slow` where that is set. */
typedef struct machine {
    double fixed, per_cost, noise;
    uint64_t rng;   /* own noise stream: engines in two threads share nothing */
    double slow;    /* 0: 1 */
} machine;

static double machine_time(void *user, const hlod_frame_stats *frame)
{
    double cost = frame->cost_drawn;
    machine *m = user;
    double t = m->fixed + m->per_cost * cost;
    if (m->noise > 0) {
        if (!m->rng)
            m->rng = 0x9e3779b97f4a7c15ull;
        m->rng ^= m->rng << 13;
        m->rng ^= m->rng >> 7;
        m->rng ^= m->rng << 17;
        double u = (double)(m->rng >> 11) / 9007199254740992.0;
        t *= 1 + m->noise * (2 * u - 1);
    }
    return m->slow > 0 ? t * m->slow : t;
}

/* ---------- selection ---------- */

/* Lakhia eq. 4: the visible roots share the budget, and the children of a
 * refined node share its slice exactly. */
static void time_slices_sum(void)
{
    fixture_opts o = {0};
    uint32_t count = 0;
    hlod_store *s = make_store("slices.hlod", &o, &count);
    hlod_engine_desc d = {0};
    d.deterministic = 1;
    d.fixed_v_time = 1e-3;
    d.target_ms = 33;
    d.deterministic_load_bytes = 1u << 30;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    hlod_camera cam;
    look(&cam, 200, -60, 40, 200, 50, 0);
    hlod_frame_stats st;
    for (int f = 0; f < 60; f++)
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    int refined_seen = 0;
    double root_sum = 0;
    for (uint32_t r = 0; r < hlod_store_root_count(s); r++) {
        double slice;
        hlod_engine_node_debug(e, r, NULL, &slice, NULL, NULL);
        if (node_look(e, r).priced == last_frame(e))
            root_sum += slice;
    }
    double share = st.budget_ms * st.share_gain;
    CHECKF(fabs(root_sum - share) <= 1e-9 * share, "roots %g share %g", root_sum, share);
    for (uint32_t p = 0; p < count; p++) {
        if (node_look(e, p).refined != last_frame(e))
            continue;
        double sum = 0;
        int n = 0;
        for (uint32_t c = nodes[p].first_child; c < nodes[p + 1].first_child; c++)
            if (node_look(e, c).drawn == last_frame(e) ||
                node_look(e, c).refined == last_frame(e)) {
                sum += node_look(e, c).slice;
                n++;
            }
        CHECKF(fabs(sum - node_look(e, p).slice) <= 1e-9 * node_look(e, p).slice,
               "node %u: %g vs %g", p, sum, node_look(e, p).slice);
        refined_seen += n > 0;
    }
    CHECK(refined_seen > 0);
    CHECK(st.nodes_per_depth[1] + st.nodes_per_depth[2] + st.nodes_per_depth[3] > 0);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* The estimate of what is drawn never exceeds the target, for the
 * time-based policies, over random views (v_time such that full detail
 * would need several times the target). */
static void estimate_within_target(void)
{
    uint64_t rng = RNG_SEED;
    fixture_opts o = {0};
    hlod_store *s = make_store("estimate.hlod", &o, NULL);
    for (int pol = HLOD_POLICY_LAKHIA; pol <= HLOD_POLICY_NOHYST; pol++) {
        hlod_engine_desc d = {0};
        d.deterministic = 1;
        d.fixed_v_time = 0.05; /* 32-tri nodes cost 16: 0.8 ms each */
        d.fixed_frame_ms = 3;
        d.target_ms = 20;
        d.deterministic_load_bytes = 1u << 30;
        d.policy = (hlod_policy)pol;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        hlod_camera cam;
        hlod_frame_stats st;
        int over = 0, deep = 0;
        for (int f = 0; f < 400; f++) {
            if (f % 20 == 0)
                random_camera(&cam, 0, 0, &rng);
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
            over += st.estimated_ms > d.target_ms * (1 + 1e-12);
            deep += st.nodes_per_depth[2] + st.nodes_per_depth[3];
            CHECK(stats_finite(&st));
        }
        CHECKF(over == 0, "%s: %d frames over target", hlod_policy_name((hlod_policy)pol), over);
        CHECKF(deep > 0, "%s: never refined", hlod_policy_name((hlod_policy)pol));
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

/* A visible sibling that cannot be loaded forces its parent, for good. */
static uint32_t g_bad_node;
static hlod_result fail_one(void *user, uint32_t node, uint64_t offset, size_t bytes)
{
    (void)user;
    (void)offset;
    (void)bytes;
    return node == g_bad_node ? HLOD_ERR_CHECKSUM : HLOD_OK;
}

static void missing_sibling_forces_parent(void)
{
    hlod_store *s = shallow_store("missing.hlod", 1);
    /* node 0 = root, 1..4 its quadrants: make quadrant 2 unreadable */
    g_bad_node = 2;
    hlod_engine_desc d = {0};
    d.deterministic = 1;
    d.fixed_v_time = 1e-6; /* everything affordable */
    d.deterministic_load_bytes = 1u << 30;
    d.read_hook = fail_one;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    hlod_camera cam;
    look(&cam, 50, -100, 80, 50, 50, 0);
    hlod_frame_stats st;
    for (int f = 0; f < 30; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        CHECK(hlod_engine_node_drawn(e, 0));
        for (uint32_t c = 1; c <= 4; c++)
            CHECK(!hlod_engine_node_drawn(e, c));
    }
    CHECK(hlod_engine_node_state(e, 2) == HLOD_NODE_BAD);
    CHECK(hlod_engine_node_state(e, 1) == HLOD_NODE_RESIDENT);
    CHECK(st.bad_nodes == 1);
    CHECK(st.wanted_missing == 1);
    hlod_engine_destroy(e);

    /* Control: without the fault the children replace the root. */
    g_bad_node = 999;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    for (int f = 0; f < 10; f++)
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
    CHECK(!hlod_engine_node_drawn(e, 0));
    CHECK(hlod_engine_node_drawn(e, 2));
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A deterministic descriptor at 33 ms, 1 ms of frame overhead, nodes like
 * nodes[child] costing child_ms each, everything loadable at once. */
static hlod_engine_desc timed_desc(const hlod_store_node *nodes, uint32_t child, double child_ms)
{
    hlod_engine_desc d;
    memset(&d, 0, sizeof d);
    d.deterministic = 1;
    d.target_ms = 33;
    d.fixed_frame_ms = 1;
    d.fixed_v_time = child_ms / hlod_node_cost(&nodes[child]);
    d.deterministic_load_bytes = 1u << 30;
    return d;
}

/* The quadrants of unequal_siblings_refine: one root over four
 * children, deterministic at 0.5 ms a child and 33 ms, the camera 1.5 m
 * over one quadrant (*d is the engine's descriptor). */
static hlod_engine *quadrants(const char *name, hlod_store **s, hlod_engine_desc *d,
                              hlod_camera *cam)
{
    *s = shallow_store(name, 1);
    const hlod_store_node *nodes = hlod_store_nodes(*s);
    *d = timed_desc(nodes, 1, 0.5);
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(*s, d, &e) == HLOD_OK);
    look(cam, 10, 10, 1.5, 100, 100, 0);
    return e;
}

/* Siblings of very unequal priority (the cumulative hysteresis, each vote
 * weighted by its slice).  A camera low over one quadrant, the other three
 * 40-57 m away, and time for all four children sixteen times over: the far
 * quadrants' slices (eq. 4, by priority) are half their need, so their
 * counters fall to -c_hyst_limit.  Summed unweighted as in the paper,
 * their three votes beat the near one's and the root, 50 m of coarse
 * ground, is drawn under the camera (as a 430-triangle city group was
 * drawn over a street camera of the parts city).  Weighted by the slice
 * each was given, the near quadrant decides and the children stay. */
static void unequal_siblings_refine(void)
{
    hlod_store *s;
    hlod_engine_desc d;
    hlod_camera cam;
    hlod_engine *e = quadrants("unequal.hlod", &s, &d, &cam);
    hlod_frame_stats st;
    uint32_t root_frames = 0, far_low = 0;
    for (int f = 0; f < 60; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        if (f < 20)
            continue;
        root_frames += hlod_engine_node_drawn(e, 0);
        for (uint32_t c = 2; c <= 4; c++)
            far_low += node_look(e, c).hyst <= -0.5 * d.c_hyst_limit;
    }
    const hlod_engine_desc *dd = hlod_engine_get_desc(e);
    fprintf(stderr, "  root drawn in %u of frames 20-59; far counters at or under %g: %u of 120\n",
            root_frames, -0.5 * dd->c_hyst_limit, far_low);
    /* the premise: the far siblings do vote against */
    CHECKF(far_low >= 60, "far quadrants' counters under -limit/2 in only %u of 120", far_low);
    CHECKF(root_frames == 0, "the root was drawn in %u of frames 20-59", root_frames);
    for (uint32_t c = 1; c <= 4; c++)
        CHECK(hlod_engine_node_drawn(e, c));
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A child hidden by occlusion keeps its counter and its vote.  The
 * siblings of unequal_siblings_refine (the near quadrant at +limit,
 * the three far ones at -limit), then frames selected with occlusion on
 * in which the near quadrant, whenever it was drawn, is found hidden
 * behind nearer geometry (as the occlusion test finds a drawn node), and
 * a tight slice: 1.5 ms for children that need 0.5 ms each, so that the
 * far quadrants, given the hidden one's share, climb from -limit a fifth
 * of a step a frame.  Without its vote the far quadrants decided and
 * the root was drawn: here in all 40 frames (the near quadrant's counter
 * restarted from 0 each time it was left out); on walk-drive, where the
 * hidden child was tested again once drawn, refined and coarsened every
 * 3-4 frames.  With it the root stays refined. */
static void hidden_child_keeps_vote(void)
{
    hlod_store *s;
    hlod_engine_desc d;
    hlod_camera cam;
    hlod_engine *e = quadrants("hidden_vote.hlod", &s, &d, &cam);
    hlod_frame_stats st;
    run_frames(e, &cam, 40, &st);
    CHECK(!hlod_engine_node_drawn(e, 0) && hlod_engine_node_drawn(e, 1));
    const double lim = hlod_engine_get_desc(e)->c_hyst_limit;
    CHECKF(node_look(e, 1).hyst >= 0.5 * lim && node_look(e, 2).hyst <= -0.5 * lim,
           "premise: near counter %g, far %g", node_look(e, 1).hyst, node_look(e, 2).hyst);
    uint32_t root_frames = 0, toggles = 0;
    for (int k = 0; k < 40; k++) {
        uint32_t f = last_frame(e) + 1;
        if (node_look(e, 1).drawn + 1 == f)
            hlod_inspect_hide(e, 1, f - 1); /* drawn last frame, and found hidden */
        hlod_hand_frame hf = {.cam = &cam,
                              .budget_ms = d.target_ms - hlod_inspect_model(e).theta[0],
                              .share_ms = 1.5,
                              .occlusion = 1,
                              .still = 1};
        CHECK(hlod_inspect_select(e, &hf, &st) == HLOD_OK);
        root_frames += node_look(e, 0).drawn == f;
        toggles += st.toggles_up + st.toggles_down;
    }
    fprintf(stderr, "  near quadrant hidden whenever drawn: root drawn in %u of 40 frames, "
            "%u toggles\n", root_frames, toggles);
    CHECKF(root_frames == 0 && toggles == 0, "root drawn in %u of 40 frames, %u toggles",
           root_frames, toggles);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* One frame selected by hand (no drawing, no fit): budget and share in ms,
 * the deterministic v_time.  Returns the frame's number. */
static uint32_t select_by_hand(hlod_engine *e, const hlod_camera *cam, double budget,
                               double share)
{
    hlod_hand_frame hf = {.cam = cam, .budget_ms = budget, .share_ms = share};
    CHECK(hlod_inspect_select(e, &hf, NULL) == HLOD_OK);
    return last_frame(e);
}

/* A refinement the walk will not reach frees what was reserved for it.
 * Two blocks 110 m apart, each a root over four children, 1 ms a node:
 * refining a root adds 3 ms.  With a budget of 6 ms a new refinement must
 * fit 0.85 x 6 = 5.1 ms less what last frame's refinements still hold.
 * The camera looks at block 0 (refined), then turns to block 1: block 0,
 * behind the camera, is not visited, and block 1's refinement (4 ms) must
 * be made in the first frame.  Held for block 0, the 3 ms left 2.1 ms and
 * block 1 waited a frame, at every turn; on walk (33 ms) such reservations
 * held a quarter of the budget at the median refusal. */
static void culled_refinement_frees_its_reservation(void)
{
    hlod_store *s = shallow_store("reserve.hlod", 2);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    hlod_engine_desc d = timed_desc(nodes, hlod_store_first_child(nodes, 0), 1);
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    uint32_t b0 = 0, b1 = 1;
    CHECK(hlod_store_root_count(s) == 2 && nodes[b0].bbox_max[0] < nodes[b1].bbox_min[0]);
    hlod_camera both, at0, at1;
    look(&both, 105, -150, 150, 105, 50, 0);
    look(&at0, 105, 50, 20, 0, 50, 0);
    look(&at1, 105, 50, 20, 210, 50, 0);
    CHECK(hlod_engine_load_all_leaves(e, &both) == HLOD_OK);
    for (int k = 0; k < 3; k++)
        select_by_hand(e, &both, 100, 100);
    CHECKF(node_look(e, b0).refined == last_frame(e) && node_look(e, b1).refined == last_frame(e),
           "premise: both blocks refined with time to spare");
    for (int k = 0; k < 3; k++)
        select_by_hand(e, &at0, 6, 6);
    CHECKF(node_look(e, b0).refined == last_frame(e) &&
               node_look(e, b1).refined + 3 <= last_frame(e),
           "premise: block 0 alone refined");
    uint32_t f = select_by_hand(e, &at1, 6, 6);
    fprintf(stderr, "  first frame at block 1: refined %d, %u refusals by the budget\n",
            node_look(e, b1).refined == f, hlod_inspect_cap_hits(e));
    CHECKF(node_look(e, b1).refined == f && !hlod_engine_node_drawn(e, b1),
           "block 1 drawn coarse on the first frame (%u refusals by the budget)",
           hlod_inspect_cap_hits(e));
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A node the eye stands inside is refined whenever the budget allows.
 * Its coarse geometry is then seen from within (the parts city's group
 * of nine blocks and the ground, drawn around a street camera at 6-7 dB),
 * and its priority, by the distance to its box, cannot say so.  Two
 * blocks 110 m apart, each a root over four children, boxes 10 m high,
 * 1 ms a node; the eye 1.5 m up inside block 1, looking at both.
 * (a) The slice: a share of 2 ms for a root whose children need 4.  Eye
 * outside the box (20 m up): the root is drawn, as eq. 4 says, and
 * (lakhia) the children's counters fall.  Inside: refined at once (before,
 * never; with the slice alone, after their vote let go: drawn 1 frame).  (b) The bound: a budget of
 * 6 ms with block 0 refined first. Before, block 1 (needing 5 - 1 + 4 = 8 > 6 ms with block 0
 * refined) waited behind block 0's refinement for good; now it is decided first in its level and
 * block 0, elsewhere, is drawn coarse instead. */
static void eye_inside_refines(void)
{
    fixture_opts o = {0};
    o.roots = 2;
    o.depth = 1;
    o.height = 10;
    hlod_store *s = make_store("eye_inside.hlod", &o, NULL);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    for (int pol = HLOD_POLICY_LAKHIA; pol <= HLOD_POLICY_NOHYST; pol++) {
        const char *name = hlod_policy_name((hlod_policy)pol);
        hlod_engine_desc d = timed_desc(nodes, hlod_store_first_child(nodes, 1), 1);
        d.policy = (hlod_policy)pol;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        const uint32_t b0 = 0, b1 = 1;
        CHECK(nodes[b1].bbox_min[2] < 1.5 && nodes[b1].bbox_max[2] > 1.5);
        hlod_camera in, above, both;
        look(&in, 200, 50, 1.5, 160, 50, 0);
        look(&above, 200, 50, 20, 160, 50, 0);
        look(&both, 200, 50, 1.5, 0, 50, 0);
        CHECK(hlod_engine_load_all_leaves(e, &both) == HLOD_OK);
        uint32_t coarse_above = 0, coarse_in = 0;
        for (int k = 0; k < 20; k++) {
            select_by_hand(e, k < 10 ? &above : &in, 100, 2);
            *(k < 10 ? &coarse_above : &coarse_in) += hlod_engine_node_drawn(e, b1);
        }
        fprintf(stderr, "  %s: root drawn at a 2 ms share in %u of 10 frames from above, "
                "%u of 10 from inside\n", name, coarse_above, coarse_in);
        CHECKF(coarse_above == 10, "%s: premise: the share binds from above (%u of 10)", name,
               coarse_above);
        CHECKF(coarse_in == 0, "%s: root drawn around the eye in %u of 10 frames", name,
               coarse_in);

        /* (b): both refined, then at 6 ms block 0 alone (first in the
         * walk), shares ample throughout */
        look(&above, 105, -60, 60, 105, 50, 0);
        for (int k = 0; k < 3; k++)
            select_by_hand(e, &above, 100, 1e4);
        CHECKF(node_look(e, b0).refined == last_frame(e) &&
                   node_look(e, b1).refined == last_frame(e),
               "%s: premise: both blocks refined with time to spare", name);
        for (int k = 0; k < 3; k++)
            select_by_hand(e, &above, 6, 1e4);
        int premise =
            node_look(e, b0).refined == last_frame(e) && node_look(e, b1).refined != last_frame(e);
        uint32_t in_refined = 0, far_refined = 0;
        for (int k = 0; k < 5; k++) {
            uint32_t f = select_by_hand(e, &both, 6, 1e4);
            in_refined += node_look(e, b1).refined == f;
            far_refined += node_look(e, b0).refined == f;
        }
        fprintf(stderr, "  %s: at 6 ms, eye in block 1: block 1 refined in %u of 5 frames, "
                "block 0 in %u\n", name, in_refined, far_refined);
        CHECKF(premise, "%s: premise: block 0 alone refined at 6 ms", name);
        CHECKF(in_refined == 5 && far_refined == 0, "%s: block 1 refined %u, block 0 %u of 5",
               name, in_refined, far_refined);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

/* One still-camera run for hysteresis_settles.  Everything in view is
 * made resident first (hlod_engine_load_all_leaves), so no frame waits for
 * the loader thread and the run is the same whatever the scheduler does:
 * 200 frames with a machine without noise, then a window of 200 frames
 * with `noise` from `seed`.  Returns the toggles in the window. */
static uint32_t still_window_toggles(hlod_store *s, hlod_policy policy, double noise,
                                     uint64_t seed)
{
    machine m = {4, 0.02, 0, 0, 1};
    hlod_engine_desc d = {0};
    d.target_ms = 20;
    d.time_model = machine_time;
    d.time_model_user = &m;
    d.policy = policy;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    if (!e)
        return 0;
    hlod_camera cam;
    look(&cam, 150, -80, 60, 200, 50, 0);
    /* with what lies just outside the view, which is priced to prefetch */
    hlod_camera wide;
    double eye[3] = {150, -80, 60}, at[3] = {200, 50, 0}, up[3] = {0, 0, 1};
    CHECK(hlod_camera_look_at(&wide, eye, at, up, 170, 0.5, 1e5, 1280, 720) == HLOD_OK);
    CHECK(hlod_engine_load_all_leaves(e, &wide) == HLOD_OK);
    hlod_frame_stats st;
    double lim = hlod_engine_get_desc(e)->c_hyst_limit;
    uint32_t toggles = 0, out_of_range = 0, loads = 0;
    m.noise = noise;
    m.rng = seed;
    double lo = INFINITY, hi = 0;
    for (int f = 0; f < 400; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        loads += st.loads;
        if (f >= 60) {
            toggles += st.toggles_up + st.toggles_down;
            lo = st.measured_ms < lo ? st.measured_ms : lo;
            hi = st.measured_ms > hi ? st.measured_ms : hi;
        }
        if (getenv("HLOD_TEST_VERBOSE") &&
            (st.toggles_up + st.toggles_down || getenv("HLOD_TEST_ALL")))
            fprintf(stderr,
                    "  %s f %d: up %u down %u gain %.3f est %.3f budget %.3f fixed %.3f "
                    "v %.5f meas %.2f draw %.4f pix %.3g m %.3f n %u c %.0f p %.0f u %u/%u/%u\n",
                    hlod_policy_name(policy), f, st.toggles_up, st.toggles_down, st.share_gain,
                    st.estimated_ms, st.budget_ms, st.fixed_ms, st.v_time, st.measured_ms,
                    hlod_inspect_model(e).theta[1], hlod_inspect_model(e).theta[3], st.margin,
                    st.nodes_drawn, st.cost_drawn, st.pixels_drawn,
                    hlod_inspect_model(e).scale_updates, hlod_inspect_model(e).shape_updates,
                    hlod_inspect_model(e).margin_updates);
        for (uint32_t i = 0; i < hlod_store_node_count(s); i++)
            out_of_range += node_look(e, i).hyst < -lim || node_look(e, i).hyst > lim;
    }
    CHECKF(loads == 0, "%s: %u loads after everything in view was resident",
           hlod_policy_name(policy), loads);
    CHECKF(out_of_range == 0, "%s: %u node-frames with hyst outside +-%g",
           hlod_policy_name(policy), out_of_range, lim);
    /* the measured time is held under the target, and the noise is there */
    CHECKF(st.measured_ms < 1.25 * d.target_ms, "%s: %g ms", hlod_policy_name(policy),
           st.measured_ms);
    CHECKF(hi > (1 + 0.5 * noise) * lo, "%s: frame times %g..%g ms: no noise",
           hlod_policy_name(policy), lo, hi);
    hlod_engine_destroy(e);
    return toggles;
}

/* Hysteresis counters stay within +-c_hyst_limit, and a still camera
 * settles: with 10 % noise on the machine's frame times from the first
 * frame, nothing toggles after frame 60, in 8 seeds, with either policy.
 * Before the guarded cost model (docs/runtime.md, "The cost model and deadline margin") the
 * fit followed the noise and the counters followed the budget: nohyst
 * toggled in every seed and lakhia at 20 % noise in 3 of 8. */
static void hysteresis_settles(void)
{
    fixture_opts o = {0};
    hlod_store *s = make_store("hyst.hlod", &o, NULL);
    static const uint64_t seeds[] = {1, 2, 3, 7, 99, 12345, 77777, 0xabcdef};
    const int n = (int)(sizeof seeds / sizeof seeds[0]);
    uint32_t lakhia = 0, nohyst = 0;
    double noise = getenv("HLOD_TEST_NOISE") ? atof(getenv("HLOD_TEST_NOISE")) : 0.1;
    for (int k = 0; k < n; k++) {
        uint32_t tl = still_window_toggles(s, HLOD_POLICY_LAKHIA, noise, seeds[k]);
        uint32_t tn = still_window_toggles(s, HLOD_POLICY_NOHYST, noise, seeds[k]);
        if (getenv("HLOD_TEST_VERBOSE"))
            fprintf(stderr, "  seed %llu: lakhia %u, nohyst %u\n", (unsigned long long)seeds[k],
                    tl, tn);
        CHECKF(tl == 0, "seed %llu: lakhia toggled %u times in 340 still frames",
               (unsigned long long)seeds[k], tl);
        CHECKF(tn == 0, "seed %llu: nohyst toggled %u times in 340 still frames",
               (unsigned long long)seeds[k], tn);
        lakhia += tl;
        nohyst += tn;
    }
    fprintf(stderr, "  still camera, %.0f%% noise, %d seeds x 340 frames: lakhia %u toggles, "
            "nohyst %u\n", 100 * noise, n, lakhia, nohyst);
    hlod_store_close(s);
}

/* The still-camera tests' engine: the default fixture, a deterministic
 * machine (v_time 0.02, target 20 ms) and a camera over its first blocks. */
static hlod_engine *still_engine(const char *name, hlod_store **s, hlod_engine_desc *d,
                                 hlod_camera *cam)
{
    fixture_opts o = {0};
    *s = make_store(name, &o, NULL);
    *d = (hlod_engine_desc){0};
    d->deterministic = 1;
    d->fixed_v_time = 0.02;
    d->target_ms = 20;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(*s, d, &e) == HLOD_OK);
    look(cam, 100, -50, 30, 220, 50, 0);
    return e;
}

/* With the deterministic machine a still camera reaches a fixed selection
 * within a bounded number of frames. */
static void still_camera_fixed_point(void)
{
    hlod_store *s;
    hlod_engine_desc d;
    hlod_camera cam;
    hlod_engine *e = still_engine("still.hlod", &s, &d, &cam);
    hlod_frame_stats st;
    int last_toggle = -1;
    for (int f = 0; f < 300; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        if (st.toggles_up + st.toggles_down) {
            last_toggle = f;
            if (getenv("HLOD_TEST_VERBOSE"))
                fprintf(stderr, "  frame %d: up %u down %u gain %.3f est %.3f drawn %u\n", f,
                        st.toggles_up, st.toggles_down, st.share_gain, st.estimated_ms,
                        st.nodes_drawn);
        }
    }
    CHECKF(last_toggle < 100, "last toggle at frame %d", last_toggle);
    CHECK(st.oscillations == 0);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* Only what the bound coarsened during this hold may refine again while
 * the camera stays still: the front held, coarsened by a budget 5 times
 * smaller, then a small move, 80 still frames (a new hold) on the small
 * budget, and the budget back.  The new hold keeps its front (no toggle);
 * remembered from the first hold, the coarsened nodes refined. */
static void capped_in_an_earlier_hold_holds(void)
{
    hlod_store *s;
    hlod_engine_desc d;
    hlod_camera cam, moved;
    hlod_engine *e = still_engine("capped.hlod", &s, &d, &cam);
    hlod_frame_stats st;
    run_frames(e, &cam, 120, &st);
    d.target_ms = 4;
    CHECK(hlod_engine_set(e, &d) == HLOD_OK);
    uint32_t down = 0;
    for (int f = 0; f < 10; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        down += st.toggles_down;
    }
    CHECKF(down > 0, "premise: the small budget coarsened the held front (%u down)", down);
    look(&moved, 100, -49.99, 30, 220, 50, 0);
    run_frames(e, &moved, 80, &st);
    d.target_ms = 20;
    CHECK(hlod_engine_set(e, &d) == HLOD_OK);
    uint32_t toggles = 0;
    for (int f = 0; f < 20; f++) {
        CHECK(hlod_engine_frame(e, &moved, 1.0 / 30, &st) == HLOD_OK);
        toggles += st.toggles_up + st.toggles_down;
    }
    fprintf(stderr, "  a new hold, budget back: %u toggles\n", toggles);
    CHECKF(toggles == 0, "a new hold, budget back: %u toggles", toggles);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A still camera on a machine with bursts of slow frames (4 in a row,
 * 1.8 x, every 97 frames, over 10 % noise: what issue 17's machines do)
 * keeps its front: no toggle after frame 60 in 4 seeds.  (The margin grew
 * with each burst and the bound coarsened the held front; the capped
 * recovery refined it again.)  Slower for good (2 x), the held frames miss
 * and the front coarsens until they meet the target again; the machine
 * back, it refines again. */
static void still_hold_rides_out_bursts(void)
{
    fixture_opts o = {0};
    hlod_store *s = make_store("bursts.hlod", &o, NULL);
    static const uint64_t seeds[] = {7, 99, 12345, 0xabcdef};
    for (int k = 0; k < 4; k++) {
        machine m = {4, 0.02, 0.1, seeds[k], 1};
        hlod_engine_desc d = {0};
        d.target_ms = 20;
        d.time_model = machine_time;
        d.time_model_user = &m;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        if (!e)
            break;
        hlod_camera cam;
        look(&cam, 150, -80, 60, 200, 50, 0);
        CHECK(hlod_engine_load_all_leaves(e, &cam) == HLOD_OK);
        hlod_frame_stats st;
        uint32_t toggles = 0, down = 0, up = 0;
        int met = 0;
        for (int f = 0; f < 1000; f++) {
            m.slow = f >= 600 && f < 800 ? 2 : f >= 100 && f < 600 && f % 97 < 4 ? 1.8 : 1;
            run_frames(e, &cam, 1, &st);
            toggles += f >= 60 && f < 600 ? st.toggles_up + st.toggles_down : 0;
            down += f >= 600 && f < 800 ? st.toggles_down : 0;
            met += f >= 700 && f < 800 && st.measured_ms <= d.target_ms;
            up += f >= 800 ? st.toggles_up : 0;
            if (getenv("HLOD_TEST_VERBOSE") && st.toggles_up + st.toggles_down)
                fprintf(stderr, "  f %d: up %u down %u, measured %.2f, estimate %.2f, budget %.3f, "
                        "margin %.3f\n", f, st.toggles_up, st.toggles_down, st.measured_ms,
                        st.estimated_ms, st.budget_ms, st.margin);
        }
        fprintf(stderr, "  seed %llu: %u toggles in bursts; slower: %u down, %d of 100 met; "
                "back: %u up\n", (unsigned long long)seeds[k], toggles, down, met, up);
        CHECKF(toggles == 0, "seed %llu: %u toggles after frame 60 with bursts",
               (unsigned long long)seeds[k], toggles);
        CHECKF(down > 0 && met >= 90, "seed %llu: 2 x slower: %u down, %d of 100 frames met",
               (unsigned long long)seeds[k], down, met);
        CHECKF(up > 0, "seed %llu: the machine back, nothing refined",
               (unsigned long long)seeds[k]);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

/* Residency never evicts a node refined this frame: the front below it
 * stands on it.  (Evicted for a nearer prefetch with memory full, it drew
 * its parent in its place the next frame: on orbit, deterministic, 1,211
 * toggles and 345 oscillations in 400 frames, 763 and 89 without.) */
static void refined_not_evicted(void)
{
    hlod_store *s;
    hlod_engine_desc d;
    hlod_camera cam;
    hlod_engine *e = still_engine("refined.hlod", &s, &d, &cam);
    run_frames(e, &cam, 40, NULL);
    uint32_t refined = 0, drawn = 0, other = 0;
    for (uint32_t i = hlod_inspect_pinned_count(e); i < hlod_store_node_count(s); i++) {
        if (hlod_engine_node_state(e, i) != HLOD_NODE_RESIDENT)
            continue;
        double key = 0;
        int evictable = hlod_inspect_evictable(e, i, &key);
        if (node_look(e, i).refined == last_frame(e)) {
            refined++;
            CHECKF(!evictable, "node %u, refined this frame, may be evicted (key %g)", i, key);
        } else if (node_look(e, i).drawn == last_frame(e)) {
            drawn++;
            CHECKF(!evictable, "node %u, drawn this frame, may be evicted", i);
        } else {
            other += evictable;
        }
    }
    fprintf(stderr,
            "  resident below the pinned nodes: %u refined, %u drawn, %u others evictable\n",
            refined, drawn, other);
    CHECKF(refined > 0 && drawn > 0, "premise: %u refined, %u drawn below the pinned nodes",
           refined, drawn);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A camera that has stood still 60 frames holds its front (docs/runtime.md, Selection): a
 * budget three times larger refines nothing while it
 * stays still, one that no longer fits coarsens it, the budget back
 * refines what it coarsened, and the first move refines; data arriving
 * after frame 60 refines (and changes nothing with still_refine_late
 * off). */
static void still_front_holds(void)
{
    hlod_store *s;
    hlod_engine_desc d;
    hlod_camera cam;
    hlod_engine *e = still_engine("hold.hlod", &s, &d, &cam);
    hlod_frame_stats st;
    for (int f = 0; f < 120; f++)
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
    uint32_t held = st.nodes_drawn;
    d.target_ms = 60;
    CHECK(hlod_engine_set(e, &d) == HLOD_OK);
    uint32_t up = 0, down = 0;
    for (int f = 0; f < 40; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        up += st.toggles_up;
        down += st.toggles_down;
    }
    CHECKF(up == 0 && down == 0 && st.nodes_drawn == held,
           "still, budget x3: %u up, %u down, %u nodes drawn (held %u)", up, down, st.nodes_drawn,
           held);
    d.target_ms = 4;
    CHECK(hlod_engine_set(e, &d) == HLOD_OK);
    down = 0;
    for (int f = 0; f < 10; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        down += st.toggles_down;
    }
    CHECKF(down > 0 && st.estimated_ms <= st.budget_ms + st.fixed_ms + 1e-9,
           "still, budget below the front: %u down, estimate %.3f, budget %.3f + %.3f", down,
           st.estimated_ms, st.budget_ms, st.fixed_ms);
    /* the machine recovers, the camera still still: what the bound
     * coarsened refines again */
    d.target_ms = 20;
    CHECK(hlod_engine_set(e, &d) == HLOD_OK);
    up = 0;
    for (int f = 0; f < 20; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        up += st.toggles_up;
    }
    fprintf(stderr, "  still, budget back: %u up, %u nodes drawn (held %u)\n", up, st.nodes_drawn,
            held);
    CHECKF(up > 0 && st.nodes_drawn > held / 2,
           "still, budget back: %u up, %u nodes drawn (held %u)", up, st.nodes_drawn, held);
    d.target_ms = 60;
    CHECK(hlod_engine_set(e, &d) == HLOD_OK);
    up = 0;
    for (int f = 0; f < 20; f++) {
        hlod_camera moved;
        look(&moved, 100, -50 + 0.01 * (f + 1), 30, 220, 50, 0);
        CHECK(hlod_engine_frame(e, &moved, 1.0 / 30, &st) == HLOD_OK);
        up += st.toggles_up;
    }
    CHECKF(up > 0, "moving, budget x3: %u up", up);
    hlod_engine_destroy(e);

    /* data late: a slow deterministic disk, the camera still from frame 0.
     * The front refines as the data arrives (the default), and with
     * still_refine_late off (-1 in C) the held front does not change. */
    d.target_ms = 60;
    d.deterministic_load_bytes = 2 << 10;
    for (int late = 0; late < 2; late++) {
        d.still_refine_late = late ? 1 : -1;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        uint32_t late_up = 0, late_down = 0, at60 = 0, missing = 0;
        for (int f = 0; f < 600; f++) {
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
            if (f == 60)
                at60 = st.nodes_drawn;
            if (f > 60) {
                late_up += st.toggles_up;
                late_down += st.toggles_down;
            }
            missing = st.wanted_missing;
        }
        fprintf(stderr, "  late data, still_refine_late %d: %u up, %u down after frame 60, "
                "%u nodes drawn at 60, %u at 600\n", late, late_up, late_down, at60,
                st.nodes_drawn);
        if (late)
            CHECKF(late_up > 0 && st.nodes_drawn > at60 && missing == 0,
                   "late data refines: %u up after frame 60, %u nodes at 60, %u at 600, "
                   "%u wanted missing", late_up, at60, st.nodes_drawn, missing);
        else
            CHECKF(late_up == 0 && late_down == 0 && st.nodes_drawn == at60,
                   "held: %u up, %u down after frame 60, %u nodes at 60, %u at 600", late_up,
                   late_down, at60, st.nodes_drawn);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

/* Nodes outside the view are neither priced nor loaded. */
static void outside_not_priced(void)
{
    fixture_opts o = {0};
    o.roots = 8;
    uint32_t count = 0;
    hlod_store *s = make_store("outside.hlod", &o, &count);
    hlod_engine_desc d = {0};
    d.deterministic = 1;
    d.fixed_v_time = 1e-6;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    hlod_camera cam;
    hlod_frame_stats st;
    /* looking up into the sky */
    look(&cam, 400, 50, 10, 400, 51, 1000);
    for (int f = 0; f < 5; f++)
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
    CHECK(st.nodes_visited == 0 && st.nodes_drawn == 0 && st.queued == 0);
    /* looking at one block from close by: far fewer nodes than the store */
    look(&cam, 50, -20, 30, 50, 50, 0);
    uint32_t visited_max = 0;
    for (int f = 0; f < 20; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        if (st.nodes_visited > visited_max)
            visited_max = st.nodes_visited;
    }
    CHECKF(visited_max * 4 < count, "visited %u of %u", visited_max, count);
    for (uint32_t i = hlod_store_root_count(s); i < count; i++) {
        const hlod_store_node *n = &hlod_store_nodes(s)[i];
        if (n->bbox_min[0] > 300) /* blocks 3.. are well outside the view */
            CHECK(hlod_engine_node_state(e, i) == HLOD_NODE_ABSENT);
    }
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* Prefetch: with the camera moving, the block it moves toward loads first
 * (distance is measured from the eye advanced by the velocity). */
static void prefetch_follows_motion(void)
{
    fixture_opts o = {0};
    o.roots = 2; /* blocks x in [0, 100] and [110, 210] */
    o.depth = 2;
    hlod_store *s = make_store("prefetch.hlod", &o, NULL);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    for (int dir = -1; dir <= 1; dir += 2) {
        hlod_engine_desc d = {0};
        d.deterministic = 1;
        d.fixed_v_time = 1e-6;
        d.deterministic_load_bytes = nodes[2].payload_size; /* one node per frame */
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        hlod_camera cam;
        hlod_frame_stats st;
        /* Load order; the read pumped in frame 0 (no velocity yet) is
         * collected in frame 1 and skipped. */
        int toward = 0, away = 0, seen = 0;
        uint8_t was[64] = {0};
        for (int f = 0; f < 6; f++) {
            double x = 105 + dir * 2.0 * f; /* 60 m/s along x */
            look(&cam, x, 50, 150, x, 50.5, 0);
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
            for (uint32_t i = hlod_store_root_count(s); i < hlod_store_node_count(s) && i < 64;
                 i++) {
                int now = hlod_engine_node_state(e, i) == HLOD_NODE_RESIDENT;
                if (now && !was[i] && f >= 2 && seen < 3) {
                    seen++;
                    if ((int)nodes[i].block == (dir > 0 ? 1 : 0))
                        toward++;
                    else
                        away++;
                }
                was[i] = (uint8_t)now;
            }
        }
        CHECKF(toward == 3 && away == 0, "moving %+d: %d nodes toward, %d away", dir, toward, away);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

/* ---------- residency ---------- */

/* The budget holds at every frame under random jumps (threaded loader). */
static void budget_random_jumps(void)
{
    uint64_t rng = RNG_SEED;
    fixture_opts o = {0};
    o.depth = 4;
    hlod_store *s = make_store("budget.hlod", &o, NULL);
    const hlod_store_header *h = hlod_store_get_header(s);
    machine m = {2, 0.002, 0.05, 0, 1};
    hlod_engine_desc d = {0};
    d.target_ms = 20;
    d.time_model = machine_time;
    d.time_model_user = &m;
    d.memory_budget_bytes = h->payload_bytes / 8;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    const int frames = getenv("HLOD_SOAK_FRAMES") ? atoi(getenv("HLOD_SOAK_FRAMES")) : 10000;
    hlod_camera cam;
    hlod_frame_stats st;
    uint64_t loads = 0, evictions = 0, over = 0, peak = 0;
    uint64_t drawn_absent = 0, roots_absent = 0, drawn_total = 0;
    for (int f = 0; f < frames; f++) {
        if (f % 7 == 0)
            random_camera(&cam, 0, 0, &rng);
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        loads += st.loads;
        evictions += st.evictions;
        if (st.resident_bytes + hlod_inspect_reserved_bytes(e) > d.memory_budget_bytes ||
            st.resident_cost > (double)d.memory_budget_bytes * (1 + 1e-9))
            over++;
        if (st.resident_bytes > peak)
            peak = st.resident_bytes;
        /* what was drawn is resident, and no root was evicted */
        uint32_t drawn = 0;
        for (uint32_t i = 0; i < hlod_store_node_count(s); i++) {
            int res = hlod_engine_node_state(e, i) == HLOD_NODE_RESIDENT;
            if (hlod_engine_node_drawn(e, i)) {
                drawn++;
                drawn_absent += !res;
            }
            roots_absent += i < hlod_store_root_count(s) && !res;
        }
        drawn_total += drawn;
        CHECKF(drawn == st.nodes_drawn, "frame %d: %u nodes drawn, stats say %u", f, drawn,
               st.nodes_drawn);
        if (f % 97 == 0)
            sleep_us(200); /* let the loader run */
    }
    CHECKF(over == 0, "%llu frames over budget", (unsigned long long)over);
    CHECKF(drawn_absent == 0 && roots_absent == 0, "%llu drawn node-frames and %llu root-frames "
           "not resident", (unsigned long long)drawn_absent, (unsigned long long)roots_absent);
    CHECK(drawn_total > 0);
    CHECK(loads > 50 && evictions > 10); /* it did stream */
    fprintf(stderr, "  %d frames: %llu loads, %llu evictions, peak %llu of %llu bytes\n", frames,
            (unsigned long long)loads, (unsigned long long)evictions, (unsigned long long)peak,
            (unsigned long long)d.memory_budget_bytes);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A scene that fits the budget is loaded once and never evicted. */
static void fits_loaded_once(void)
{
    uint64_t rng = RNG_SEED;
    fixture_opts o = {0};
    uint32_t count = 0;
    hlod_store *s = make_store("fits.hlod", &o, &count);
    hlod_engine_desc d = {0};
    d.deterministic = 1;
    d.fixed_v_time = 1e-3;
    d.deterministic_load_bytes = 256u << 10;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    hlod_camera cam;
    hlod_frame_stats st;
    uint64_t loads = 0, evictions = 0;
    for (int f = 0; f < 1500; f++) {
        if (f % 5 == 0)
            random_camera(&cam, 0, 0, &rng);
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        loads += st.loads;
        evictions += st.evictions;
    }
    CHECK(evictions == 0);
    CHECKF(loads <= count - hlod_store_root_count(s), "%llu loads for %u nodes",
           (unsigned long long)loads, count);
    CHECK(loads > 0);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A payload corrupted on disk is marked bad and never drawn. */
static void corrupt_never_drawn(void)
{
    fixture_opts o = {0};
    o.roots = 1;
    o.depth = 1;
    char path[512];
    hlod_store *s = make_store("corrupt.hlod", &o, NULL);
    const hlod_store_node n3 = hlod_store_nodes(s)[3];
    hlod_store_close(s);
    FILE *fp = fopen(tmp_path("corrupt.hlod", path, sizeof path), "r+b");
    CHECK(fp != NULL);
    fseek(fp, (long)(n3.payload_offset + n3.payload_size - 5), SEEK_SET);
    fputc(0x5a, fp);
    fclose(fp);
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    hlod_engine_desc d = {0};
    d.deterministic = 1;
    d.fixed_v_time = 1e-6;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    hlod_camera cam;
    look(&cam, 50, -100, 80, 50, 50, 0);
    hlod_frame_stats st;
    for (int f = 0; f < 20; f++) {
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        CHECK(!hlod_engine_node_drawn(e, 3));
        CHECK(hlod_engine_node_drawn(e, 0)); /* the parent stands in */
    }
    CHECK(hlod_engine_node_state(e, 3) == HLOD_NODE_BAD);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* Transient read errors are retried with backoff, not in a tight loop. */
static int g_io_calls;
static hlod_result fail_io(void *user, uint32_t node, uint64_t offset, size_t bytes)
{
    (void)user;
    (void)offset;
    (void)bytes;
    if (node == 2) {
        g_io_calls++;
        return HLOD_ERR_IO;
    }
    return HLOD_OK;
}

static void transient_backoff(void)
{
    hlod_store *s = shallow_store("transient.hlod", 1);
    hlod_engine_desc d = {0};
    d.deterministic = 1;
    d.fixed_v_time = 1e-6;
    d.read_hook = fail_io;
    g_io_calls = 0;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    hlod_camera cam;
    look(&cam, 50, -100, 80, 50, 50, 0);
    hlod_frame_stats st;
    for (int f = 0; f < 400; f++)
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
    /* 4 tries (backoffs of 16, 32, 64 frames), then bad */
    CHECKF(g_io_calls == 4, "%d read attempts", g_io_calls);
    CHECK(hlod_engine_node_state(e, 2) == HLOD_NODE_BAD);
    CHECK(hlod_engine_node_drawn(e, 0));
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A slow disk never stalls the render thread. */
/*
 * A slow disk that proves the render thread never waits for it.  Each read
 * is held until the render thread has finished SLOW_FRAMES more frames (or
 * SLOW_TIMEOUT_MS pass).  A frame() that waited for a read could never
 * finish those frames, so the read times out: the verdict counts frames,
 * not milliseconds, and a loaded machine cannot fake or hide a stall.
 */
enum { SLOW_FRAMES = 3, SLOW_TIMEOUT_MS = 10000 };

typedef struct slow_disk_state {
    atomic_uint frames_done; /* frames the render thread has finished */
    atomic_uint reads, timeouts;
} slow_disk_state;

static hlod_result slow_disk(void *user, uint32_t node, uint64_t offset, size_t bytes)
{
    slow_disk_state *sd = user;
    (void)node;
    (void)offset;
    (void)bytes;
    unsigned start = atomic_load(&sd->frames_done);
    double t_end = now_ms() + SLOW_TIMEOUT_MS;
    while (atomic_load(&sd->frames_done) < start + SLOW_FRAMES) {
        if (now_ms() > t_end) {
            atomic_fetch_add(&sd->timeouts, 1);
            break;
        }
        sleep_us(500);
    }
    atomic_fetch_add(&sd->reads, 1);
    return HLOD_OK;
}

static void slow_disk_no_stall(void)
{
    uint64_t rng = RNG_SEED;
    fixture_opts o = {0};
    hlod_store *s = make_store("slow.hlod", &o, NULL);
    machine m = {2, 0.001, 0, 0, 1};
    slow_disk_state sd;
    atomic_init(&sd.frames_done, 0);
    atomic_init(&sd.reads, 0);
    atomic_init(&sd.timeouts, 0);
    hlod_engine_desc d = {0};
    d.time_model = machine_time;
    d.time_model_user = &m;
    d.read_hook = slow_disk;
    d.read_hook_user = &sd;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    hlod_camera cam;
    hlod_frame_stats st;
    uint32_t loads = 0, waits = 0;
    int f;
    for (f = 0; f < 400; f++) {
        if (f % 10 == 0)
            random_camera(&cam, 0, 0, &rng);
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        atomic_fetch_add(&sd.frames_done, 1);
        loads += st.loads;
        waits += st.render_waits; /* the engine's count of the thread's sleeps */
        sleep_us(1000);
    }
    /* let a read still held finish before the engine goes */
    atomic_fetch_add(&sd.frames_done, 1u << 20);
    hlod_engine_destroy(e);
    unsigned reads = atomic_load(&sd.reads), timeouts = atomic_load(&sd.timeouts);
    fprintf(stderr, "  %d frames, each read held for %d frames: %u reads, %u timed out, %u loads\n",
            f, SLOW_FRAMES, reads, timeouts, loads);
    CHECKF(timeouts == 0, "%u reads waited on a frame() that never finished", timeouts);
    if (span_judges_waits())
        CHECKF(waits == 0, "the render thread slept %u times", waits);
    CHECK(loads > 3); /* the loader got through some */
    hlod_store_close(s);
}

/* A disk whose every read step takes one of the test's frames, in lock
 * step: the hook waits until the test has run the next frame, and the
 * test, after a frame, waits until the loader has taken its step and
 * waits at the hook again (or, idle, never comes: then 2 s).  The
 * loader's progress is counted in frames whatever the scheduler does. */
#define GATED_MAXN 64
typedef struct gated_disk {
    atomic_uint frame;              /* frames the test has run */
    atomic_uint waiting_for;        /* the frame the hook waits for */
    atomic_int released;            /* set before destroy */
    atomic_int steps[GATED_MAXN];   /* read steps per node */
} gated_disk;

static hlod_result gated_read(void *user, uint32_t node, uint64_t offset, size_t bytes)
{
    gated_disk *g = user;
    (void)offset;
    (void)bytes;
    if (node < GATED_MAXN)
        atomic_fetch_add(&g->steps[node], 1);
    unsigned until = atomic_load(&g->frame) + 1;
    atomic_store(&g->waiting_for, until);
    while (atomic_load(&g->frame) < until && !atomic_load(&g->released))
        sleep_us(100);
    return HLOD_OK;
}

/* One frame, then the gate lets the loader take one step. */
static void gated_frame(hlod_engine *e, const hlod_camera *cam, gated_disk *g,
                        hlod_frame_stats *st)
{
    CHECK(hlod_engine_frame(e, cam, 1.0 / 30, st) == HLOD_OK);
    unsigned f = atomic_fetch_add(&g->frame, 1) + 1;
    double t_end = now_ms() + 2000;
    while (atomic_load(&g->waiting_for) <= f && now_ms() < t_end)
        sleep_us(50);
}

/* Preemption through the engine: while a big read of a distant block's
 * node is in flight (a few steps in), the camera comes close to another
 * block.  Its nodes are now the most urgent, and one of them becomes
 * resident before the read in flight completes, though that read had
 * fewer steps left than a whole node takes.  Counted in frames. */
static void urgent_preempts_prefetch(void)
{
    fixture_opts o = {0};
    o.roots = 2;  /* blocks x in [0, 100] and [110, 210] */
    o.depth = 1;
    o.grid = 32;  /* ~60 KiB a node: many 4 KiB steps */
    hlod_store *s = make_store("preempt.hlod", &o, NULL);
    uint32_t count = hlod_store_node_count(s), roots = hlod_store_root_count(s);
    CHECK(count <= GATED_MAXN);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    gated_disk g;
    memset(&g, 0, sizeof g);
    hlod_engine_desc d = {0};
    machine m = {1, 1e-6, 0, 0, 1}; /* everything fits: all in view is wanted */
    d.time_model = machine_time;
    d.time_model_user = &m;
    d.read_chunk_bytes = 4096;
    d.read_hook = gated_read;
    d.read_hook_user = &g;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    if (!e) {
        hlod_store_close(s);
        return;
    }
    uint32_t steps_per_node = (uint32_t)((nodes[roots].payload_size + 4095) / 4096);
    hlod_camera cam;
    hlod_frame_stats st;
    /* 1: above block 1, block 0 out of view: a block-1 node starts reading */
    look(&cam, 160, 50, 90, 160, 50.1, 0);
    uint32_t inflight = UINT32_MAX;
    int f = 0;
    for (; f < 200 && inflight == UINT32_MAX; f++) {
        gated_frame(e, &cam, &g, &st);
        for (uint32_t i = roots; i < count; i++)
            if (nodes[i].block == 1 && atomic_load(&g.steps[i]) >= 3 &&
                hlod_engine_node_state(e, i) != HLOD_NODE_RESIDENT)
                inflight = i;
    }
    CHECKF(inflight != UINT32_MAX, "no block-1 read in flight after %d frames", f);
    int left = (int)steps_per_node - atomic_load(&g.steps[inflight < count ? inflight : 0]);
    /* 2: close over block 0, block 1 still in view further off */
    look(&cam, 50, -40, 35, 110, 50, 0);
    int turn = f, first_urgent = -1, inflight_done = -1;
    for (; f < turn + 8 * (int)steps_per_node && inflight_done < 0 && inflight < count; f++) {
        gated_frame(e, &cam, &g, &st);
        for (uint32_t i = roots; i < count && first_urgent < 0; i++)
            if (nodes[i].block == 0 && hlod_engine_node_state(e, i) == HLOD_NODE_RESIDENT)
                first_urgent = f - turn;
        if (hlod_engine_node_state(e, inflight) == HLOD_NODE_RESIDENT)
            inflight_done = f - turn;
        if (getenv("HLOD_TEST_VERBOSE")) {
            fprintf(stderr, "  f %d: queued %u missing %u drawn %u states", f - turn, st.queued,
                    st.wanted_missing, st.nodes_drawn);
            for (uint32_t i = 0; i < count; i++)
                fprintf(stderr, " %d/%d", (int)hlod_engine_node_state(e, i),
                        atomic_load(&g.steps[i]));
            fputc('\n', stderr);
        }
    }
    fprintf(stderr, "  %u steps a node; the read in flight had %d left at the turn: a block-0 node "
            "resident after %d frames, the read in flight after %d\n", steps_per_node, left,
            first_urgent, inflight_done);
    CHECKF(left > 0 && left < (int)steps_per_node, "%d steps left of %u", left, steps_per_node);
    CHECKF(first_urgent >= 0 && (inflight_done < 0 || first_urgent < inflight_done),
           "urgent node resident after %d frames, the read in flight after %d", first_urgent,
           inflight_done);
    /* it was read, not found, and read at once: a whole node's steps, one
     * a frame, and the frame that collects it */
    CHECKF(first_urgent >= (int)steps_per_node && first_urgent <= (int)steps_per_node + 2,
           "urgent node resident after %d frames for its %u steps", first_urgent, steps_per_node);
    atomic_store(&g.released, 1);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A city at x = 5e6 m selects exactly as the same city at the origin. */
static void far_origin_same_selection(void)
{
    fixture_opts a = {0}, b = {0};
    b.origin[0] = 5e6;
    b.origin[1] = 4.1e6;
    b.origin[2] = 30;
    hlod_store *sa = make_store("near.hlod", &a, NULL), *sb = make_store("far.hlod", &b, NULL);
    hlod_engine_desc d = {0};
    d.deterministic = 1;
    d.fixed_v_time = 0.01;
    d.target_ms = 20;
    hlod_engine *ea = NULL, *eb = NULL;
    CHECK(hlod_engine_create(sa, &d, &ea) == HLOD_OK);
    CHECK(hlod_engine_create(sb, &d, &eb) == HLOD_OK);
    uint32_t count = hlod_store_node_count(sa);
    int differ = 0, refined = 0;
    for (int f = 0; f < 300; f++) {
        hlod_camera ca, cb;
        double t = f / 300.0;
        look(&ca, 40 + 300 * t, -60 + 50 * t, 5 + 60 * t, 200, 50, 0);
        look(&cb, 5e6 + 40 + 300 * t, 4.1e6 - 60 + 50 * t, 30 + 5 + 60 * t, 5e6 + 200,
             4.1e6 + 50, 30);
        hlod_frame_stats s1, s2;
        CHECK(hlod_engine_frame(ea, &ca, 1.0 / 30, &s1) == HLOD_OK);
        CHECK(hlod_engine_frame(eb, &cb, 1.0 / 30, &s2) == HLOD_OK);
        for (uint32_t i = 0; i < count; i++)
            differ += hlod_engine_node_drawn(ea, i) != hlod_engine_node_drawn(eb, i);
        refined += s1.nodes_drawn > s1.nodes_per_depth[0];
    }
    CHECKF(differ == 0, "%d node-frames differ", differ);
    CHECK(refined > 0);
    hlod_engine_destroy(ea);
    hlod_engine_destroy(eb);
    hlod_store_close(sa);
    hlod_store_close(sb);
}

/* Bad input and degenerate views: errors, not NaN. */
static void degenerate_views(void)
{
    fixture_opts o = {0};
    hlod_store *s = make_store("degenerate.hlod", &o, NULL);
    hlod_engine_desc d = {0};
    d.c_hyst_switch = 0.5; /* below 1: rejected */
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_ERR_INVALID_ARG && e == NULL);
    d.c_hyst_switch = 0;
    d.target_ms = NAN;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_ERR_INVALID_ARG);
    double targets[2] = {1, 10000};
    double switches[2] = {1, 8};
    for (int k = 0; k < 4; k++) {
        machine m = {0.5, 0.01, 0.1, 0, 1};
        memset(&d, 0, sizeof d);
        d.target_ms = targets[k % 2];
        d.c_hyst_switch = switches[k / 2];
        d.time_model = machine_time;
        d.time_model_user = &m;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        hlod_camera cam;
        hlod_frame_stats st;
        /* inside a node's box (on the ground plane, z = 0), then right at a
         * vertex, then all siblings behind the camera */
        double eyes[3][6] = {{50, 50, 0, 60, 50, 0},
                             {0, 0, 0, 10, 10, 0},
                             {200, 200, 5, 200, 300, 5}};
        for (int f = 0; f < 90; f++) {
            const double *q = eyes[f / 30];
            look(&cam, q[0], q[1], q[2], q[3], q[4], q[5]);
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
            CHECK(stats_finite(&st));
        }
        for (uint32_t i = 0; i < hlod_store_node_count(s); i++)
            CHECK(isfinite(node_look(e, i).hyst) && isfinite(node_look(e, i).slice) &&
                  isfinite(node_look(e, i).priority));
        /* a NaN camera is rejected, not drawn */
        cam.position[0] = NAN;
        CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_ERR_INVALID_ARG);
        CHECK(st.nodes_drawn == 0);
        look(&cam, 50, -50, 20, 50, 50, 0);
        CHECK(hlod_engine_frame(e, &cam, INFINITY, &st) == HLOD_ERR_INVALID_ARG);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

/* The cost model through the engine, on a synthetic machine with a
 * synchronous loader (every node in view is loaded before its frame, so
 * the run does not depend on when the loader thread finishes): a moving
 * camera, 5 % noise.  The model predicts each frame within 5 % (median)
 * and 20 % (95th percentile); aiming at the deadline, at least 98 % of
 * frames meet the target; aiming at the mean (the paper), the mean sits
 * within 15 % of it (this small fixture's front moves in steps of 4 % of
 * the target). */
static void cost_model_fit(void)
{
    fixture_opts o = {0};
    o.depth = 4;
    hlod_store *s = make_store("fit.hlod", &o, NULL);
    for (int aim_mean = 0; aim_mean < 2; aim_mean++) {
        machine m = {8, 0.004, 0.05, 0x1234567ull, 1};
        hlod_engine_desc d = {0};
        d.target_ms = 30;
        d.time_model = machine_time;
        d.time_model_user = &m;
        d.memory_budget_bytes = 1ull << 30;
        d.aim_mean = aim_mean ? 1 : -1;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        if (!e)
            break;
        hlod_camera cam;
        hlod_frame_stats st;
        double err[500], sum_ratio = 0;
        int n = 0, met = 0;
        for (int f = 0; f < 600; f++) {
            double t = f / 600.0;
            look(&cam, 20 + 400 * t, -40 - 100 * t, 10 + 150 * t, 220, 50, 0);
            CHECK(hlod_engine_load_all_leaves(e, &cam) == HLOD_OK);
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
            if (f >= 100) {
                err[n] = fabs(st.estimated_ms - st.measured_ms) / st.measured_ms;
                sum_ratio += st.measured_ms / d.target_ms;
                met += st.measured_ms <= d.target_ms;
                n++;
            }
        }
        hlod_stats_sort(err, (size_t)n);
        double p50 = hlod_stats_percentile_sorted(err, (size_t)n, 50);
        double p95 = hlod_stats_percentile_sorted(err, (size_t)n, 95);
        fprintf(stderr, "  %s: estimate error p50 %.3f p95 %.3f; mean %.3f x target, %d/%d "
                "within; fixed %.2f v_time %.5f margin %.3f\n", aim_mean ? "aim_mean" : "deadline",
                p50, p95, sum_ratio / n, met, n, st.fixed_ms, st.v_time, st.margin);
        CHECKF(p50 <= 0.05 && p95 <= 0.20, "estimate error p50 %.3f, p95 %.3f", p50, p95);
        if (aim_mean)
            CHECKF(fabs(sum_ratio / n - 1) <= 0.15, "mean %.3f x target", sum_ratio / n);
        else
            CHECKF(met >= 0.98 * n, "%d of %d frames within the target", met, n);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

/* Two engines, each in its own thread, over one store. */
typedef struct twin {
    hlod_store *s;
    int ok;
    uint64_t loads;
} twin;

static void *twin_main(void *arg)
{
    twin *t = arg;
    machine m = {2, 0.002, 0.05, 0, 1};
    hlod_engine_desc d = {0};
    d.time_model = machine_time;
    d.time_model_user = &m;
    d.memory_budget_bytes = hlod_store_get_header(t->s)->payload_bytes / 4;
    hlod_engine *e = NULL;
    if (hlod_engine_create(t->s, &d, &e) != HLOD_OK)
        return NULL;
    t->ok = 1;
    for (int f = 0; f < 1500; f++) {
        hlod_camera cam;
        double eye[3] = {40 + (f % 300), -50, 20 + (f % 50)}, at[3] = {200, 50, 0},
               up[3] = {0, 0, 1};
        hlod_camera_look_at(&cam, eye, at, up, 60, 0.5, 1e5, 640, 480);
        hlod_frame_stats st;
        if (hlod_engine_frame(e, &cam, 1.0 / 30, &st) != HLOD_OK ||
            st.resident_bytes > d.memory_budget_bytes) {
            if (t->ok)
                fprintf(stderr, "  twin frame %d: resident %llu of %llu\n", f,
                        (unsigned long long)st.resident_bytes,
                        (unsigned long long)d.memory_budget_bytes);
            t->ok = 0;
        }
        t->loads += st.loads;
        if (f % 50 == 0)
            sleep_us(500);
    }
    hlod_engine_destroy(e);
    return NULL;
}

static void two_engines_two_threads(void)
{
    fixture_opts o = {0};
    hlod_store *s = make_store("twins.hlod", &o, NULL);
    twin a = {s, 0, 0}, b = {s, 0, 0};
    pthread_t ta, tb;
    pthread_create(&ta, NULL, twin_main, &a);
    pthread_create(&tb, NULL, twin_main, &b);
    pthread_join(ta, NULL);
    pthread_join(tb, NULL);
    CHECK(a.ok && b.ok);
    CHECK(a.loads > 0 && b.loads > 0);
    hlod_store_close(s);
}

/* steady_heap (docs/runtime.md, "The cost model and deadline margin"): an engine makes glibc
 * keep an 8 MiB block in its heap and keep it there once freed; with the
 * setting off the block is mapped and unmapped, as glibc does by default
 * (that, per draw of a software rasteriser, doubled a still view's frames).
 * Each case runs in a child of its own, before this process creates any
 * engine: the setting is made once per process. */
static int heap_case(int steady, const hlod_store *s)
{
#if defined(__GLIBC__) && !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
    pid_t pid = fork();
    if (pid < 0)
        return -1;
    if (pid == 0) {
        hlod_engine_desc d = {0};
        d.deterministic = 1;
        d.steady_heap = steady ? 1 : -1;
        hlod_engine *e = NULL;
        if (hlod_engine_create(s, &d, &e) != HLOD_OK)
            _exit(3);
        size_t big = 8u << 20;
        char *p = malloc(big);
        if (!p)
            _exit(3);
        memset(p, 1, big);
        struct mallinfo2 in = mallinfo2();
        free(p);
        struct mallinfo2 out = mallinfo2();
        hlod_engine_destroy(e);
        int mapped = in.hblkhd >= big;
        int kept = out.arena >= big && out.fordblks >= big;
        _exit(mapped ? 1 : kept ? 0 : 2);
    }
    int status = 0;
    if (waitpid(pid, &status, 0) != pid || !WIFEXITED(status))
        return -1;
    return WEXITSTATUS(status);
#else
    (void)steady;
    (void)s;
    return -2;
#endif
}

static void steady_heap_keeps_blocks(void)
{
    if (getenv("GLIBC_TUNABLES") || getenv("MALLOC_TRIM_THRESHOLD_") ||
        getenv("MALLOC_MMAP_THRESHOLD_")) {
        CHECK_SKIP("malloc tunables are set in the environment");
        return;
    }
    fixture_opts o = {0};
    uint32_t count = 0;
    hlod_store *s = make_store("heap.hlod", &o, &count);
    int on = heap_case(1, s), off = heap_case(0, s);
    if (on == -2) {
        CHECK_SKIP("not glibc's malloc, or under a sanitizer");
    } else {
        CHECKF(on == 0, "steady_heap on: child said %d (1: mapped, 2: given back)", on);
        CHECKF(off == 1, "steady_heap off: child said %d (0: kept, 2: given back)", off);
    }
    hlod_store_close(s);
}

int main(int argc, char **argv)
{
    (void)argc;
    (void)argv;
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod-test-engine-XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    /* first: no engine may exist in this process yet.  A sanitizer
     * brings its own malloc, which has no glibc tunables for steady_heap
     * to set: the setting does nothing there and is not tested. */
#if defined(__GLIBC__) && !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
    RUN(steady_heap_keeps_blocks);
#endif
    RUN(time_slices_sum);
    RUN(estimate_within_target);
    RUN(missing_sibling_forces_parent);
    RUN(unequal_siblings_refine);
    RUN(culled_refinement_frees_its_reservation);
    RUN(eye_inside_refines);
    RUN(hidden_child_keeps_vote);
    RUN(hysteresis_settles);
    RUN(still_camera_fixed_point);
    RUN(still_front_holds);
    RUN(still_hold_rides_out_bursts);
    RUN(capped_in_an_earlier_hold_holds);
    RUN(refined_not_evicted);
    RUN(outside_not_priced);
    RUN(prefetch_follows_motion);
    RUN(budget_random_jumps);
    RUN(fits_loaded_once);
    RUN(corrupt_never_drawn);
    RUN(transient_backoff);
    RUN(slow_disk_no_stall);
    RUN(urgent_preempts_prefetch);
    RUN(far_origin_same_selection);
    RUN(degenerate_views);
    RUN(cost_model_fit);
    RUN(two_engines_two_threads);
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", g_dir);
    return check_done();
}
