/*
 * test_degenerate.c - degenerate views and settings (issue 6, "Numerical
 * stress"), beyond test_engine.c's degenerate_views.
 *
 * Cases: the camera (or its velocity look-ahead probe) exactly on a box
 * corner, so the distance to several nodes is 0; back-facing nodes with
 * c_fore = 1 (foreshortening 0 or below); nodes with zero area (benefit 0,
 * average normal 0), zero cost (c_tex = 1 on untextured triangles) and a
 * zero-size box; a visible parent none of whose children is in the
 * frustum; dt of 0 and of the smallest denormal (infinite velocity); a
 * target time of 1 ms and of 10 s; c_hyst_switch at 1 and at c_hyst_limit
 * (with limits of 1, 8 and 1e6).
 *
 * After every frame check_frame asserts that frame() returned valid output:
 * no NaN or Inf in any stats field or per-node slice, need, priority or
 * hysteresis counter; priorities > 0; counters within +-c_hyst_limit; the
 * drawn nodes resident, counted right and forming a cut (no drawn node
 * below another); the visible roots' slices summing to the shared time and
 * each refined node's children's slices to its own (eq. 4, as in
 * test_engine.c's time_slices_sum); and for the time-based policies
 * the estimate within the budget whenever more than the roots is drawn.
 */
#define _GNU_SOURCE /* RUSAGE_THREAD (cpu_span.h) */
#include "check.h"
#include "inspect.h"
#include "engine_check.h"
#include "store_fixture.h"

#include <math.h>
#include <time.h>
#include <unistd.h>

static char g_dir[256];
static long g_frames_checked, g_sums_checked;

static const char *tmp_path(const char *name, char *buf, size_t n)
{
    snprintf(buf, n, "%s/%s", g_dir, name);
    return buf;
}

static hlod_store *open_store(const char *name)
{
    char path[512];
    hlod_store *s = NULL;
    hlod_result r = hlod_store_open(tmp_path(name, path, sizeof path), NULL, &s);
    CHECKF(r == HLOD_OK, "open %s: %s", name, hlod_result_str(r));
    return s;
}

static hlod_store *make_fixture(const char *name, const fixture_opts *o)
{
    char path[512];
    hlod_result r = fixture_write(tmp_path(name, path, sizeof path), o, NULL);
    CHECKF(r == HLOD_OK, "fixture_write: %s", hlod_result_str(r));
    return open_store(name);
}

/* ---- a store of degenerate nodes ---- */

typedef struct quad_spec {
    double x0, y0, x1, y1;  /* a rectangle at z = 0 ... */
    int down;               /* ... facing -z instead of +z */
    int line;               /* a zero-area triangle along y = y0 instead */
    int point;              /* three copies of (x0, y0, 0) instead */
    int textured;
} quad_spec;

static hlod_result add_node(hlod_store_writer *w, const quad_spec *q, hlod_store_node *out)
{
    double pos[12];
    float nrm[12], uv[8];
    uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    uint32_t nv = 4, nt = 2;
    const double xs[4] = {q->x0, q->x1, q->x1, q->x0}, ys[4] = {q->y0, q->y0, q->y1, q->y1};
    for (int v = 0; v < 4; v++) {
        pos[3 * v] = xs[v];
        pos[3 * v + 1] = ys[v];
        pos[3 * v + 2] = 0;
        nrm[3 * v] = nrm[3 * v + 1] = 0;
        nrm[3 * v + 2] = q->down ? -1.0f : 1.0f;
        uv[2 * v] = v == 1 || v == 2;
        uv[2 * v + 1] = v >= 2;
    }
    if (q->down) {
        idx[1] = 2, idx[2] = 1;
        idx[4] = 3, idx[5] = 2;
    }
    if (q->line || q->point) {
        nv = 3;
        nt = 1;
        for (int v = 0; v < 3; v++) {
            pos[3 * v] = q->point ? q->x0 : q->x0 + (q->x1 - q->x0) * v / 2;
            pos[3 * v + 1] = q->y0;
            pos[3 * v + 2] = 0;
        }
    }
    uint8_t tex[2 * 2 * 3] = {200, 30, 30, 30, 200, 30, 30, 30, 200, 200, 200, 30};
    hlod_store_payload_desc d = {0};
    d.vertex_count = nv;
    d.positions = pos;
    d.origin[0] = 0.5 * (q->x0 + q->x1);
    d.origin[1] = 0.5 * (q->y0 + q->y1);
    d.normals = nrm;
    d.tri_count = nt;
    d.indices = idx;
    if (q->textured) {
        d.uvs = uv;
        d.tex_tri_count = nt;
        d.tex_width = d.tex_height = 2;
        d.tex_channels = 3;
        d.pixels = tex;
    }
    return hlod_store_writer_add(w, &d, out);
}

/* Node ids in the store (breadth-first): roots A, B, C = 0, 1, 2; then A's
 * four children (small squares in one corner of A: most of A has no child
 * below it), B's two point children, C's four quadrants; then the
 * grandchild under B's first point. */
enum { DA = 0, DB = 1, DC = 2, DA_KIDS = 3, DB_KIDS = 7, DC_KIDS = 9, DB_GRAND = 13, DN = 14 };

static hlod_store *make_degenerate(void)
{
    char path[512];
    tmp_path("degenerate.hlod", path, sizeof path);
    hlod_store_writer_desc wd = {0};
    wd.build.c_tex = 1.0; /* untextured triangles cost 0 (eq. 1) */
    hlod_store_writer *w = NULL;
    CHECK(hlod_store_writer_open(path, &wd, &w) == HLOD_OK);
    hlod_store_node n[DN];
    quad_spec spec[DN];
    uint32_t parent[DN];
    double error[DN];
    memset(spec, 0, sizeof spec);
    /* A: textured, facing up; children in its corner [0, 20]^2 */
    spec[DA] = (quad_spec){0, 0, 100, 100, 0, 0, 0, 1};
    parent[DA] = HLOD_STORE_NO_PARENT, error[DA] = 2;
    for (int k = 0; k < 4; k++) {
        double x = 10.0 * (k % 2), y = 10.0 * (k / 2);
        spec[DA_KIDS + k] = (quad_spec){x, y, x + 10, y + 10, 0, 0, 0, 1};
        parent[DA_KIDS + k] = DA, error[DA_KIDS + k] = 1;
    }
    /* B: a zero-area line (benefit 0, normal 0, cost 0), then points */
    spec[DB] = (quad_spec){110, 50, 210, 50, 0, 1, 0, 0};
    parent[DB] = HLOD_STORE_NO_PARENT, error[DB] = 1;
    spec[DB_KIDS] = (quad_spec){160, 50, 160, 50, 0, 0, 1, 0};
    spec[DB_KIDS + 1] = (quad_spec){200, 50, 200, 50, 0, 0, 1, 0};
    parent[DB_KIDS] = parent[DB_KIDS + 1] = DB, error[DB_KIDS] = error[DB_KIDS + 1] = 0;
    spec[DB_GRAND] = (quad_spec){160, 50, 160, 50, 0, 0, 1, 0};
    parent[DB_GRAND] = DB_KIDS, error[DB_GRAND] = 0;
    /* C: textured, facing down (back-facing from above) */
    spec[DC] = (quad_spec){220, 0, 320, 100, 1, 0, 0, 1};
    parent[DC] = HLOD_STORE_NO_PARENT, error[DC] = 2;
    for (int k = 0; k < 4; k++) {
        double x = 220 + 50.0 * (k % 2), y = 50.0 * (k / 2);
        spec[DC_KIDS + k] = (quad_spec){x, y, x + 50, y + 50, 1, 0, 0, 1};
        parent[DC_KIDS + k] = DC, error[DC_KIDS + k] = 1;
    }
    for (int i = 0; i < DN; i++) {
        CHECK(add_node(w, &spec[i], &n[i]) == HLOD_OK);
        n[i].parent = parent[i];
        n[i].error = error[i];
    }
    n[DA].block = 0, n[DB].block = 1, n[DC].block = 2;
    uint32_t index[DN];
    hlod_result r = hlod_store_writer_finish(w, n, DN, index);
    CHECKF(r == HLOD_OK, "finish: %s", hlod_result_str(r));
    for (int i = 0; i < DN; i++)
        CHECKF(index[i] == (uint32_t)i, "node %d is %u in the store", i, index[i]);
    hlod_store *s = open_store("degenerate.hlod");
    if (s) {
        const hlod_store_node *sn = hlod_store_nodes(s);
        CHECK(sn[DB].static_benefit == 0 && sn[DB].cost == 0 && sn[DB].avg_normal[2] == 0);
        CHECK(sn[DB_KIDS].bbox_min[0] == sn[DB_KIDS].bbox_max[0]);
        CHECK(sn[DC].avg_normal[2] == -1.0f && sn[DA].avg_normal[2] == 1.0f);
    }
    return s;
}

/* ---- frame validity ---- */

static int close_to(double a, double b)
{
    return fabs(a - b) <= 1e-9 * fmax(fabs(a), fabs(b)) + 1e-300;
}

/* Whether eye lies in node n's box. */
static int holds_eye(const hlod_store_node *n, const double eye[3])
{
    for (int k = 0; k < 3; k++)
        if (!(eye[k] >= n->bbox_min[k] && eye[k] <= n->bbox_max[k]))
            return 0;
    return 1;
}

/* Everything the header promises about one frame's output, the camera at
 * eye; returns the number of problems (each reported once per call with
 * `what`). */
static int check_frame(const hlod_engine *e, const hlod_store *s, const hlod_frame_stats *st,
                       const double eye[3], const char *what)
{
    int bad = 0;
    const hlod_store_node *n = hlod_store_nodes(s);
    const uint32_t count = hlod_store_node_count(s);
    const hlod_engine_desc *d = hlod_engine_get_desc(e);
    const double lim = d->c_hyst_limit;
    const uint32_t fr = hlod_inspect_frame(e);
    g_frames_checked++;
#define EXPECT(cond, ...)                                                        \
    do {                                                                         \
        if (!(cond)) {                                                           \
            if (!bad++) {                                                        \
                fprintf(stderr, "%s: frame %llu: ", what,                        \
                        (unsigned long long)st->frame);                          \
                fprintf(stderr, __VA_ARGS__);                                    \
                fputc('\n', stderr);                                             \
            }                                                                    \
        }                                                                        \
    } while (0)
    EXPECT(stats_finite(st), "non-finite stats: est %g v %g fixed %g budget %g gain %g",
           st->estimated_ms, st->v_time, st->fixed_ms, st->budget_ms, st->share_gain);
    uint32_t drawn = 0, per_depth = 0;
    for (int k = 0; k < HLOD_STATS_MAX_DEPTH; k++)
        per_depth += st->nodes_per_depth[k];
    double root_sum = 0;
    for (uint32_t i = 0; i < count; i++) {
        const hlod_node_look look = hlod_inspect_node(e, i), *f = &look;
        EXPECT(isfinite(f->hyst) && isfinite(f->slice) && isfinite(f->needed) &&
                   isfinite(f->priority), "node %u: hyst %g slice %g need %g priority %g", i,
               f->hyst, f->slice, f->needed, f->priority);
        EXPECT(f->hyst >= -lim && f->hyst <= lim, "node %u: hyst %g outside +-%g", i, f->hyst,
               lim);
        if (f->priced == fr) /* visible, or near enough to prefetch */
            EXPECT(f->priority > 0, "node %u: priority %g", i, f->priority);
        if (f->drawn == fr || f->refined == fr) /* visible: shares time */
            EXPECT(f->slice >= 0 && f->needed > 0, "node %u: slice %g need %g", i, f->slice,
                   f->needed);
        if (hlod_engine_node_drawn(e, i)) {
            drawn++;
            EXPECT(hlod_engine_node_state(e, i) == HLOD_NODE_RESIDENT, "drawn node %u absent",
                   i);
            for (uint32_t a = n[i].parent; a != HLOD_STORE_NO_PARENT; a = n[a].parent)
                EXPECT(!hlod_engine_node_drawn(e, a), "node %u drawn with its ancestor %u", i,
                       a);
        }
        if (i < hlod_store_root_count(s) && f->priced == fr)
            root_sum += f->slice;
        if (f->refined == fr) {
            double sum = 0, need = 0;
            int kids = 0;
            for (uint32_t c = n[i].first_child; c < n[i + 1].first_child; c++)
                if (hlod_inspect_node(e, c).drawn == fr || hlod_inspect_node(e, c).refined == fr) {
                    sum += hlod_inspect_node(e, c).slice;
                    need += hlod_inspect_node(e, c).needed;
                    kids++;
                }
            /* around the eye the children share at least 1.15 x their
             * need (traverse.c surround_share, docs/runtime.md) */
            double shared = holds_eye(&n[i], eye) ? fmax(f->slice, 1.15 * need) : f->slice;
            g_sums_checked++;
            EXPECT(kids > 0 && close_to(sum, shared),
                   "node %u: children's slices sum to %.17g, its share is %.17g (slice %.17g)",
                   i, sum, shared, f->slice);
        }
    }
    EXPECT(drawn == st->nodes_drawn && per_depth == drawn, "drawn %u, stats %u, per depth %u",
           drawn, st->nodes_drawn, per_depth);
    if (root_sum > 0)
        EXPECT(close_to(root_sum, st->budget_ms * st->share_gain),
               "roots' slices %.17g, shared time %.17g", root_sum,
               st->budget_ms * st->share_gain);
    hlod_policy pol = d->policy;
    if ((pol == HLOD_POLICY_LAKHIA || pol == HLOD_POLICY_NOHYST || pol == HLOD_POLICY_COUNTER ||
         pol == HLOD_POLICY_FS93) &&
        st->nodes_per_depth[0] != st->nodes_drawn)
        EXPECT(st->estimated_ms - st->fixed_ms - (d->deterministic ? 0 : st->upload_ms) <=
                   st->budget_ms * (1 + 1e-9),
               "estimate %g - fixed %g - uploads %g over the budget %g", st->estimated_ms,
               st->fixed_ms, st->upload_ms, st->budget_ms);
#undef EXPECT
    return bad;
}

/* ---- runs ---- */

typedef struct view {
    double eye[3], at[3];
    double dt;
} view;

static int set_camera(hlod_camera *cam, const view *v)
{
    double up[3] = {0, 0, 1};
    return hlod_camera_look_at(cam, v->eye, v->at, up, 60, 0.5, 1e5, 640, 360) == HLOD_OK;
}

/* Policies these tests leave to their own: full (references only, it
 * loads every leaf); klein, klein-auto and cubes (additive stores only:
 * test_sampletree, test_cubes); rzb (no front, faces: test_rzb);
 * lumigraph (a sampling repository: test_lumigraph). */
static int not_here(int pol)
{
    return pol == HLOD_POLICY_FULL || pol == HLOD_POLICY_KLEIN || pol == HLOD_POLICY_KLEIN_AUTO ||
           pol == HLOD_POLICY_RZB || pol == HLOD_POLICY_CUBES || pol == HLOD_POLICY_LUMIGRAPH;
}

/* Each view for `each` frames under every policy but full, in
 * deterministic mode; returns the problems found. */
static int run_views(const hlod_store *s, const hlod_engine_desc *base, const view *views,
                     int nviews, int each, const char *what)
{
    int bad = 0;
    for (int pol = 0; pol < HLOD_POLICY_COUNT; pol++) {
        if (not_here(pol))
            continue;
        hlod_engine_desc d = *base;
        d.policy = (hlod_policy)pol;
        hlod_engine *e = NULL;
        hlod_result r = hlod_engine_create(s, &d, &e);
        CHECKF(r == HLOD_OK, "%s: create: %s", what, hlod_result_str(r));
        if (!e)
            return 1;
        char label[160];
        snprintf(label, sizeof label, "%s/%s", what, hlod_policy_name(d.policy));
        for (int v = 0; v < nviews; v++) {
            hlod_camera cam;
            CHECKF(set_camera(&cam, &views[v]), "%s: view %d", label, v);
            for (int f = 0; f < each; f++) {
                hlod_frame_stats st;
                double dt = views[v].dt >= 0 ? views[v].dt : 1.0 / 30;
                r = hlod_engine_frame(e, &cam, dt, &st);
                CHECKF(r == HLOD_OK, "%s: view %d: %s", label, v, hlod_result_str(r));
                bad += check_frame(e, s, &st, cam.position, label);
            }
        }
        hlod_engine_destroy(e);
    }
    return bad;
}

static hlod_engine_desc det_desc(double v_time, double target)
{
    hlod_engine_desc d = {0};
    d.deterministic = 1;
    d.fixed_v_time = v_time;
    d.target_ms = target;
    d.deterministic_load_bytes = 1u << 30;
    return d;
}

/* ---------- tests ---------- */

/* The camera, then the look-ahead probe, exactly on box corners: distance
 * 0 to every node meeting there (clamped to a fraction of the node's
 * size, never 0).  dt = 0 (no velocity) and dt = the smallest denormal
 * (an infinite velocity, whose look-ahead is dropped). */
static void distance_zero(void)
{
    fixture_opts o = {0};
    hlod_store *s = make_fixture("corners.hlod", &o);
    const view views[] = {
        {{0, 0, 0}, {50, 50, 0}, -1},           /* block 0's outer corner */
        {{50, 50, 0}, {100, 100, 0}, -1},       /* 4 depth-1 boxes meet here */
        {{25, 25, 0}, {60, 40, 0}, -1},         /* depth 2 */
        {{12.5, 12.5, 0}, {0, 60, 0}, -1},      /* depth 3 (leaves) */
        {{110, 0, 0}, {110, 100, 0}, -1},       /* block 1's corner */
        {{105, 50, 0}, {0, 50, 0}, -1},         /* between two blocks */
        {{-2, 0, 1}, {50, 50, 0}, -1},          /* then the probe: */
        {{-1, 0, 0.5}, {50, 50, 0}, 0.5},       /* -1 + 2 * 0.5 = 0: the corner */
        {{-1, 0, 0.5}, {50, 50, 0}, 0},         /* dt 0 */
        {{0, 0, 0.5}, {50, 50, 0}, 4.9e-324},   /* velocity 1 / denormal = inf */
    };
    int n = (int)(sizeof views / sizeof *views);
    hlod_engine_desc d = det_desc(1e-3, 20);
    CHECK(run_views(s, &d, views, n, 8, "corners") == 0);
    d = det_desc(1e-6, 20); /* everything affordable: the deepest nodes too */
    CHECK(run_views(s, &d, views, n, 8, "corners, fine") == 0);
    hlod_store_close(s);
}

/* Priorities that would be 0 or negative: c_fore = 1 on back-facing nodes
 * (foreshortening 1 + (view . normal) reaches 0), zero-area nodes (benefit
 * 0), zero-cost nodes, zero-size boxes with the camera on them. */
static void zero_priorities(void)
{
    hlod_store *s = make_degenerate();
    if (!s)
        return;
    const view views[] = {
        {{270, 50, 80}, {270, 51, 0}, -1},      /* C from above: back-facing */
        {{270, 50, 20}, {270, 90, 0}, -1},
        {{50, 50, -30}, {50, 51, 0}, -1},       /* A from below: back-facing */
        {{160, 50, 0}, {200, 50, 0}, -1},       /* on B's point child (box of size 0) */
        {{200, 50, 0}, {160, 50, 0}, -1},
        {{160, 40, 10}, {160, 50, 0}, -1},      /* B's line from above */
        {{160, -150, 150}, {160, 50, 0}, -1},   /* everything */
    };
    int n = (int)(sizeof views / sizeof *views);
    for (int fore = 0; fore < 2; fore++) {
        hlod_engine_desc d = det_desc(1e-3, 20);
        d.c_fore = fore ? 1.0 : 0.25;
        CHECK(run_views(s, &d, views, n, 10, fore ? "zero priority c_fore=1" : "zero priority") ==
              0);
        d.fixed_v_time = 1e-7;
        CHECK(run_views(s, &d, views, n, 10, fore ? "zero priority fine c_fore=1"
                                                  : "zero priority fine") == 0);
    }
    /* Every node was priced at some point, with a positive priority: the
     * back-facing, zero-benefit and zero-cost ones included. */
    hlod_engine_desc d = det_desc(1e-7, 20);
    d.c_fore = 1;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
    int priced[DN] = {0};
    for (int v = 0; v < n && e; v++) {
        hlod_camera cam;
        CHECK(set_camera(&cam, &views[v]));
        for (int f = 0; f < 10; f++) {
            hlod_frame_stats st;
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
            for (int i = 0; i < DN; i++)
                priced[i] |= hlod_inspect_node(e, (uint32_t)i).priced == hlod_inspect_frame(e) &&
                             hlod_inspect_node(e, (uint32_t)i).priority > 0;
        }
    }
    for (int i = 0; i < DN; i++)
        CHECKF(priced[i], "node %d never priced", i);
    hlod_engine_destroy(e);
    hlod_store_close(s);
}

/* A parent in view, none of its children: the parent is drawn, its
 * children are neither drawn nor asked for. */
static void all_siblings_outside(void)
{
    hlod_store *s = make_degenerate();
    if (!s)
        return;
    const view views[] = {
        {{80, 80, 5}, {95, 95, 0}, -1},          /* over A's child-free corner */
        {{60, 90, 30}, {90, 60, 0}, -1},
        {{95, 5, 2}, {99, 60, 0}, -1},
    };
    int n = (int)(sizeof views / sizeof *views);
    hlod_engine_desc d = det_desc(1e-7, 20);
    CHECK(run_views(s, &d, views, n, 10, "siblings outside") == 0);
    for (int pol = 0; pol < HLOD_POLICY_COUNT; pol++) {
        if (not_here(pol))
            continue;
        d.policy = (hlod_policy)pol;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        for (int v = 0; v < n && e; v++) {
            hlod_camera cam;
            CHECK(set_camera(&cam, &views[v]));
            hlod_frame_stats st;
            for (int f = 0; f < 10; f++)
                CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
            CHECKF(hlod_engine_node_drawn(e, DA), "%s view %d: A not drawn",
                   hlod_policy_name(d.policy), v);
            for (int k = 0; k < 4; k++)
                CHECK(!hlod_engine_node_drawn(e, DA_KIDS + k) &&
                      hlod_engine_node_state(e, DA_KIDS + k) == HLOD_NODE_ABSENT);
        }
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

/* Random views over and around the fixture (a few exactly on corners). */
static uint64_t g_rng = 0x853c49e6748fea9bull;
static double frand(void)
{
    g_rng ^= g_rng << 13;
    g_rng ^= g_rng >> 7;
    g_rng ^= g_rng << 17;
    return (double)(g_rng >> 11) / 9007199254740992.0;
}

static void random_views(view *v, int n)
{
    for (int i = 0; i < n; i++) {
        if (i % 5 == 4) { /* on a leaf corner of block 0 or 1 */
            v[i] = (view){{12.5 * (int)(frand() * 9), 12.5 * (int)(frand() * 9), 0},
                          {220, 50, 0}, -1};
            continue;
        }
        v[i] = (view){{-200 + 840 * frand(), -200 + 500 * frand(), 1 + 300 * frand()},
                      {440 * frand(), 100 * frand(), 0}, -1};
    }
}

/* Threaded engine with a machine, random views, every policy. */
static int run_machine(const hlod_store *s, hlod_engine_desc d, fixed_machine *m, int frames,
                       const char *what)
{
    int bad = 0;
    view v[40];
    random_views(v, 40);
    d.time_model = fixed_machine_time;
    d.time_model_user = m;
    for (int pol = 0; pol < HLOD_POLICY_COUNT; pol++) {
        if (not_here(pol))
            continue;
        d.policy = (hlod_policy)pol;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        char label[160];
        snprintf(label, sizeof label, "%s/%s", what, hlod_policy_name(d.policy));
        hlod_camera cam;
        for (int f = 0; f < frames && e; f++) {
            if (f % 10 == 0)
                CHECK(set_camera(&cam, &v[(f / 10) % 40]));
            hlod_frame_stats st;
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
            bad += check_frame(e, s, &st, cam.position, label);
            if (f % 16 == 0)
                nanosleep(&(struct timespec){0, 200000}, NULL); /* let the loader run */
        }
        hlod_engine_destroy(e);
    }
    return bad;
}

/* A target of 1 ms and of 10 s, deterministic and with a machine whose
 * fixed part alone exceeds the 1 ms target. */
static void target_extremes(void)
{
    fixture_opts o = {0};
    hlod_store *s = make_fixture("targets.hlod", &o);
    view v[40];
    random_views(v, 40);
    const double targets[2] = {1, 10000};
    for (int k = 0; k < 2; k++) {
        char what[64];
        snprintf(what, sizeof what, "target %g ms", targets[k]);
        hlod_engine_desc d = det_desc(1e-2, targets[k]);
        CHECK(run_views(s, &d, v, 40, 5, what) == 0);
        hlod_engine_desc t = {0};
        t.target_ms = targets[k];
        fixed_machine m = {2, 0.01};
        CHECK(run_machine(s, t, &m, 300, what) == 0);
    }
    hlod_store_close(s);
}

/* c_hyst_switch at 1 and at c_hyst_limit, for limits 1, 8 and 1e6 (the
 * largest check_desc accepts). */
static void hyst_switch_limits(void)
{
    fixture_opts o = {0};
    hlod_store *s = make_fixture("hyst.hlod", &o);
    view v[40];
    random_views(v, 40);
    const double limits[3] = {1, 8, 1e6};
    for (int k = 0; k < 3; k++)
        for (int end = 0; end < 2; end++) {
            char what[96];
            hlod_engine_desc d = det_desc(2e-3, 20);
            d.c_hyst_limit = limits[k];
            d.c_hyst_switch = end ? limits[k] : 1;
            snprintf(what, sizeof what, "c_hyst_limit %g switch %g", d.c_hyst_limit,
                     d.c_hyst_switch);
            CHECK(run_views(s, &d, v, 40, 6, what) == 0);
            hlod_engine_desc t = {0};
            t.c_hyst_limit = d.c_hyst_limit;
            t.c_hyst_switch = d.c_hyst_switch;
            t.target_ms = 20;
            fixed_machine m = {3, 0.02};
            CHECK(run_machine(s, t, &m, 200, what) == 0);
        }
    hlod_store_close(s);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod-test-degenerate-XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(distance_zero);
    RUN(zero_priorities);
    RUN(all_siblings_outside);
    RUN(target_extremes);
    RUN(hyst_switch_limits);
    printf("REPORT degenerate frames=%ld slice_sums=%ld failed_tests=%d\n", g_frames_checked,
           g_sums_checked, check_failed_);
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", g_dir);
    return check_done();
}
