/*
 * traverse.c - node selection (Lakhia III-C; docs/runtime.md).
 *
 * Top-down and breadth-first from the roots (the city's group root, or
 * each block's hlod_0 node without city levels).  Each visible node is
 * priced (priority = benefit / cost); a node's time slice is its parent's
 * slice shared among the visible siblings by priority (eq. 4), and its
 * timeNeeded is v_time * cost.  For each node p on the current front the
 * policy decides between drawing p and drawing its visible children
 * (policy.c: one function a policy, asked through its row).
 *
 * Whatever the policy: a visible child that is not resident forces the
 * parent (Lakhia III-C), and for the time-based policies the frame estimate
 * never exceeds the budget: a refinement that would push the running
 * estimate of the whole front over it draws the parent instead.  A top
 * node (group or hlod_0) that is bad, or a pinned one not read yet, is the
 * exception: its readable children stand in for it (stand_in).
 *
 * Visibility: a node whose box meets the frustum is visible (frustumVis = 1).
 * Outside, frustumVis falls linearly to 0 over c_vis_falloff node radii;
 * those nodes are priced only for the loader (prefetch) and share no time.
 * Farther nodes are not priced at all, so the work per frame is bounded by
 * the visible front and its children, not by the store.
 *
 * Everything is computed in doubles relative to the camera, so a city at
 * x = 5e6 m selects exactly as at the origin.
 */
#include "selection.h"

#include "hold.h"
#include "knapsack.h"
#include "policy.h"
#include "residency.h"

#include <assert.h>
#include <math.h>
#include <string.h>

/* One frame's walk: the selection, what it asks, and the frame's inputs. */
typedef struct walk {
    hlod_selection *s;
    hlod_residency *res;
    const hlod_engine_desc *d;
    hlod_frame_stats *st;
    const hlod_store_node *nodes;
    hlod_node_frame *fr;
    uint32_t frame;
    double v_time, sse_pixels, draw_ms, pixel_ms;
    int occlusion, still, hold;
    uint32_t hold_since; /* when hold: the frame the front began to hold */
    const hlod_policy_row *policy;
    const hlod_occlusion *occ; /* when occlusion: last frame's verdicts */
    int cones;           /* normal cones cull (the setting, or the policy's trait) */
    int nomem;           /* an allocation failed where no result could say so */
    double splat_px;     /* the additive walk's splat size (select_in) */
    int far_cubes;       /* a front node within cube_px is its cube (docs/cubes.md) */
} walk;

/* ---- life ---- */

hlod_result hlod_selection_init(hlod_selection *s, const hlod_store *store,
                                const hlod_engine_desc *d, hlod_frame_stats *st)
{
    assert(s && store && d && st);
    *s = (hlod_selection){0};
    s->nodes = hlod_store_nodes(store);
    s->extras = hlod_store_extras(store);
    s->additive = (hlod_store_get_header(store)->flags & HLOD_STORE_ADDITIVE) != 0;
    s->node_count = hlod_store_node_count(store);
    s->root_count = hlod_store_root_count(store);
    s->d = d;
    s->st = st;
    const hlod_store_header *h = hlod_store_get_header(store);
    for (int a = 0; a < 3; a++) {
        s->scene_lo[a] = h->bbox_min[a];
        s->scene_hi[a] = h->bbox_max[a];
    }
    s->copy_side[0] = h->bbox_max[0] - h->bbox_min[0];
    s->copy_side[1] = h->bbox_max[1] - h->bbox_min[1];
    s->fr = hlod_mem_alloc(&d->allocator, (size_t)s->node_count * sizeof *s->fr);
    if (!s->fr)
        return HLOD_ERR_NOMEM;
    memset(s->fr, 0, (size_t)s->node_count * sizeof *s->fr);
    return HLOD_OK;
}

void hlod_selection_free(hlod_selection *s)
{
    if (!s->d)
        return; /* never initialised */
    const hlod_allocator *a = &s->d->allocator;
    hlod_mem_free(a, s->fr);
    hlod_mem_free(a, s->draw.v);
    hlod_mem_free(a, s->level.v);
    hlod_mem_free(a, s->next.v);
    hlod_mem_free(a, s->refined.v);
    hlod_mem_free(a, s->coned.v);
    hlod_mem_free(a, s->splats.v);
    hlod_mem_free(a, s->draw_copy.v);
    hlod_mem_free(a, s->splat_copy.v);
    hlod_mem_free(a, s->fs93_items);
    hlod_mem_free(a, s->fs93_nodes);
    hlod_mem_free(a, s->fs93_wish);
    hlod_knapsack_free(&s->ks);
    *s = (hlod_selection){0};
}

/* ---- view ---- */

void hlod_view_init(hlod_view *v, const hlod_camera *cam, const double velocity[3],
                    double lookahead_s)
{
    assert(v && cam && velocity);
    memset(v, 0, sizeof *v);
    for (int k = 0; k < 3; k++) {
        v->eye[k] = cam->position[k];
        double ahead = velocity[k] * lookahead_s;
        v->probe[k] = cam->position[k] + (isfinite(ahead) ? ahead : 0);
        v->velocity[k] = isfinite(velocity[k]) ? velocity[k] : 0;
    }
    /* the rows of proj * view give the planes (Gribb-Hartmann), in
     * camera-relative coordinates */
    double m[16];
    hlod_camera_view_proj(cam, m);
    double row[4][4];
    for (int r = 0; r < 4; r++)
        for (int c = 0; c < 4; c++)
            row[r][c] = m[c * 4 + r];
    for (int i = 0; i < 6; i++) {
        int axis = i / 2;
        double sign = (i % 2) ? -1.0 : 1.0;
        double len2 = 0;
        for (int c = 0; c < 4; c++) {
            v->planes[i][c] = row[3][c] + sign * row[axis][c];
            if (c < 3)
                len2 += v->planes[i][c] * v->planes[i][c];
        }
        double inv = len2 > 0 ? 1 / sqrt(len2) : 0;
        for (int c = 0; c < 4; c++)
            v->planes[i][c] *= inv;
    }
    /* The view matrix's third row is the eye's +z axis in world space: the
     * direction toward the viewer, i.e. the image plane's normal. */
    v->toward[0] = cam->view[2];
    v->toward[1] = cam->view[6];
    v->toward[2] = cam->view[10];
    double t = tan(0.5 * cam->fov_y_deg * M_PI / 180.0);
    v->pixels_per_radian = t > 0 ? 0.5 * (double)cam->height / t : 1.0;
    memcpy(v->vp, m, sizeof v->vp);
    v->width = cam->width;
    v->height = cam->height;
}

/* The box's screen rectangle, not clipped (x0, y0, x1, y1, pixels), and
 * the window depth of its nearest corner; 0 when part of it lies at or
 * behind the eye plane or before the near plane. */
static int project_raw(const hlod_view *v, const double bmin[3], const double bmax[3],
                       double rect[4], double *zmin)
{
    const double *m = v->vp;
    double x0 = INFINITY, y0 = INFINITY, x1 = -INFINITY, y1 = -INFINITY, z0 = INFINITY;
    for (int c = 0; c < 8; c++) {
        double p[3] = {((c & 1) ? bmax[0] : bmin[0]) - v->eye[0],
                       ((c & 2) ? bmax[1] : bmin[1]) - v->eye[1],
                       ((c & 4) ? bmax[2] : bmin[2]) - v->eye[2]};
        double cx = m[0] * p[0] + m[4] * p[1] + m[8] * p[2] + m[12];
        double cy = m[1] * p[0] + m[5] * p[1] + m[9] * p[2] + m[13];
        double cz = m[2] * p[0] + m[6] * p[1] + m[10] * p[2] + m[14];
        double cw = m[3] * p[0] + m[7] * p[1] + m[11] * p[2] + m[15];
        if (!(cw > 1e-9) || !(cz > -cw))
            return 0; /* behind the eye or before the near plane */
        double sx = (cx / cw * 0.5 + 0.5) * v->width, sy = (cy / cw * 0.5 + 0.5) * v->height;
        double sz = cz / cw * 0.5 + 0.5;
        x0 = sx < x0 ? sx : x0;
        x1 = sx > x1 ? sx : x1;
        y0 = sy < y0 ? sy : y0;
        y1 = sy > y1 ? sy : y1;
        z0 = sz < z0 ? sz : z0;
    }
    rect[0] = x0;
    rect[1] = y0;
    rect[2] = x1;
    rect[3] = y1;
    *zmin = z0;
    return 1;
}

int hlod_view_project(const hlod_view *v, const double bmin[3], const double bmax[3],
                      double rect[4], double *zmin)
{
    assert(v && bmin && bmax && rect && zmin);
    if (!project_raw(v, bmin, bmax, rect, zmin))
        return 0;
    rect[0] = rect[0] > 0 ? rect[0] : 0;
    rect[1] = rect[1] > 0 ? rect[1] : 0;
    rect[2] = rect[2] < v->width ? rect[2] : v->width;
    rect[3] = rect[3] < v->height ? rect[3] : v->height;
    return 1;
}

double hlod_view_pixels(const hlod_view *v, const double lo[3], const double hi[3])
{
    assert(v && lo && hi);
    double r[4], z;
    if (!hlod_view_project(v, lo, hi, r, &z))
        return v->width * v->height;
    double w = r[2] - r[0], h = r[3] - r[1];
    return w > 0 && h > 0 ? w * h : 0;
}

double hlod_view_outside(const hlod_view *v, const double bmin[3], const double bmax[3])
{
    assert(v && bmin && bmax);
    double lo[3], hi[3];
    for (int k = 0; k < 3; k++) {
        lo[k] = bmin[k] - v->eye[k];
        hi[k] = bmax[k] - v->eye[k];
    }
    double worst = -INFINITY;
    for (int i = 0; i < 6; i++) {
        const double *p = v->planes[i];
        double s = p[3];
        for (int k = 0; k < 3; k++)
            s += p[k] * (p[k] >= 0 ? hi[k] : lo[k]);
        if (-s > worst)
            worst = -s;
    }
    return worst;
}

static double node_radius(const hlod_store_node *n)
{
    double dx = n->bbox_max[0] - n->bbox_min[0], dy = n->bbox_max[1] - n->bbox_min[1],
           dz = n->bbox_max[2] - n->bbox_min[2];
    return 0.5 * sqrt(dx * dx + dy * dy + dz * dz);
}

/* Distance from the look-ahead probe to the box, clamped below by a tenth
 * of the node's radius (and never zero): a camera inside a node gets a large
 * but finite benefit, where benefit over distance would have none. */
static double node_distance(const hlod_view *v, const hlod_store_node *n)
{
    double d2 = 0;
    for (int k = 0; k < 3; k++) {
        double lo = n->bbox_min[k] - v->probe[k], hi = v->probe[k] - n->bbox_max[k];
        double g = lo > hi ? lo : hi;
        if (g > 0)
            d2 += g * g;
    }
    double d = sqrt(d2), floor = 0.1 * node_radius(n);
    if (!(floor > 1e-6))
        floor = 1e-6;
    return d > floor ? d : floor;
}

/* Lakhia: priority = benefit / cost, benefit = staticBenefit * vis *
 * foreshorten / distance^2.  Kept inside (0, 1e300): no zero, NaN or Inf
 * reaches a slice. */
static double node_priority(const walk *w, const hlod_view *v, uint32_t i,
                            double frustum_vis)
{
    const hlod_store_node *n = &w->nodes[i];
    double vis = 1 + w->d->c_vis * frustum_vis;
    double dot = v->toward[0] * n->avg_normal[0] + v->toward[1] * n->avg_normal[1] +
                 v->toward[2] * n->avg_normal[2];
    double fore = 1 + w->d->c_fore * dot;
    if (!(fore > 0.05))
        fore = 0.05; /* c_fore near 1 would zero a back-facing node */
    double d = node_distance(v, n);
    double sb = n->static_benefit > 0 ? n->static_benefit : 1e-9;
    double pr = sb * vis * fore / (d * d) / hlod_node_cost(n);
    if (!(pr > 1e-300))
        pr = 1e-300;
    if (!(pr < 1e300))
        pr = 1e300;
    return pr;
}

/* Whether node i's faces and all its descendants' face away from the eye:
 * its normal cone (axis a, half-angle t < 90 degrees) and the node's box,
 * which holds every descendant's faces too.  Every face is back-facing
 * when every view ray to a point p of the box makes at most 90 - t
 * degrees with a: dot(a, p - eye) >= sin(t) |p - eye| (Shirman and
 * Abi-Ezzi's cone test).  The points that meet it form a convex cone with
 * its apex at the eye, so the box lies in it exactly when its eight
 * corners do: tighter than the test on the sphere around the box, and
 * still exact.  Camera-relative doubles.  A node without a cone
 * (two-sided, or its normals spread too wide) never culls. */
static int cone_hides(const walk *w, const hlod_view *v, uint32_t i)
{
    const hlod_store_extra *x = &w->s->extras[i];
    if (!(x->flags & HLOD_EXTRA_CONE) || !(x->cone_cos > 0))
        return 0;
    const hlod_store_node *n = &w->nodes[i];
    double sine = sqrt(1 - (double)x->cone_cos * x->cone_cos);
    double lo[3], hi[3];
    for (int k = 0; k < 3; k++) {
        lo[k] = n->bbox_min[k] - v->eye[k];
        hi[k] = n->bbox_max[k] - v->eye[k];
    }
    for (int corner = 0; corner < 8; corner++) {
        double along = 0, d2 = 0;
        for (int k = 0; k < 3; k++) {
            double c = corner >> k & 1 ? hi[k] : lo[k];
            along += x->cone_axis[k] * c;
            d2 += c * c;
        }
        double d = sqrt(d2);
        if (!(along > sine * d + 1e-7 * d))
            return 0;
    }
    return 1;
}

/* Notes node i culled by its cone this frame (once), and asks for it when
 * the engine keeps culled nodes (hlod-bench --cone-check).  0 on
 * allocation failure. */
static int note_coned(walk *w, const hlod_view *v, uint32_t i)
{
    hlod_node_frame *f = &w->fr[i];
    if (f->coned == w->frame)
        return 1;
    f->coned = w->frame;
    w->st->cone_culled++;
    w->st->cone_culled_tris += w->nodes[i].tri_count;
    if (!hlod_u32_push(&w->d->allocator, &w->s->coned, i))
        return 0;
    if (!w->d->keep_coned || hlod_residency_state(w->res, i) == HLOD_NODE_RESIDENT)
        return 1;
    f->priority = node_priority(w, v, i, 0);
    f->priced = w->frame;
    return hlod_residency_want(w->res, i, f->priority);
}

/* frustumVis in [0, 1], or -1 when the node is beyond the falloff or its
 * normal cone faces away (not priced). */
static double frustum_vis(walk *w, const hlod_view *v, uint32_t i)
{
    if (w->cones && cone_hides(w, v, i)) {
        if (!note_coned(w, v, i))
            w->nomem = 1;
        return -1;
    }
    double out = hlod_view_outside(v, w->nodes[i].bbox_min, w->nodes[i].bbox_max);
    if (!(out > 0))
        return 1;
    double fall = w->d->c_vis_falloff * node_radius(&w->nodes[i]);
    if (!(fall > 0) || out >= fall)
        return -1;
    return 1 - out / fall;
}

/* Refinements already made keep their place against bounds that a new one
 * must meet with this much to spare (see visit).  With the fitted cost
 * model the budget moves a little with every frame of a moving camera;
 * walk-drive (default city, 33 ms, two runs each) oscillated 255 and 249
 * times at 0.05, 163 and 91 at 0.15, 56 and 39 at 0.25; but at 0.25 a new
 * refinement fits only 75 % of the budget, and the mean frame fell to
 * 0.81 of the target when aiming at the mean (test_engine cost_model_fit). */
#define KEEP_MARGIN HLOD_KEEP_MARGIN

/* A hidden node whose children are still prefetched: one the occlusion
 * test found visible within this many frames ("just out of sight"). */
#define PREFETCH_HIDDEN_FRAMES 30

/* Prices node i (priority, and the pixels of its box when visible). */
static void price(walk *w, const hlod_view *v, uint32_t i, double fv)
{
    hlod_node_frame *f = &w->fr[i];
    f->priority = node_priority(w, v, i, fv);
    f->priced = w->frame;
    if (fv >= 1) {
        const hlod_store_node *n = &w->nodes[i];
        f->pix = hlod_view_pixels(v, n->bbox_min, n->bbox_max);
        double raw[4], z;
        if (w->far_cubes && (w->s->extras[i].flags & HLOD_EXTRA_CUBE) &&
            project_raw(v, n->bbox_min, n->bbox_max, raw, &z) &&
            raw[2] - raw[0] <= w->d->cube_px && raw[3] - raw[1] <= w->d->cube_px)
            f->cube = w->frame;
    }
    w->st->nodes_visited++;
}

/* Whether node i stands as its colour cube this frame (far_cubes): priced
 * visible within cube_px x cube_px pixels.  Its mesh is neither read nor
 * drawn, nor its subtree walked. */
static int is_cube(const walk *w, uint32_t i)
{
    return w->fr[i].cube == w->frame;
}

/* timeNeeded of a visible node: the cost model's terms for drawing it (a
 * cube: its pixels only; its faces go with the frame's other cubes). */
static double node_needed(const walk *w, uint32_t i)
{
    if (is_cube(w, i))
        return w->pixel_ms * w->fr[i].pix;
    return w->draw_ms + w->v_time * hlod_node_cost(&w->nodes[i]) + w->pixel_ms * w->fr[i].pix;
}

/* Hidden: the last frame's occlusion test found it behind nearer geometry.
 * A hidden node is drawn as it is (the renderer tests it again against
 * this frame's depth and draws it if it shows), neither charged nor
 * refined. */
static int is_hidden(const walk *w, uint32_t i)
{
    if (!w->occlusion)
        return 0;
    uint32_t hidden = hlod_occlusion_hidden(w->occ, i);
    return hidden && hidden + 1 == w->frame;
}

/* The children of a hidden node that was visible a moment ago are still
 * wanted, at the priority of nodes just outside the frustum, so turning a
 * corner does not stall; a node long hidden costs nothing.  Returns 0 on
 * allocation failure. */
static int prefetch_hidden(walk *w, const hlod_view *v, uint32_t p)
{
    uint32_t seen = hlod_occlusion_seen(w->occ, p);
    if (!seen || w->frame - seen > PREFETCH_HIDDEN_FRAMES)
        return 1;
    uint32_t c0 = hlod_store_first_child(w->nodes, p), c1 = hlod_store_child_end(w->nodes, p);
    for (uint32_t c = c0; c < c1; c++) {
        if (frustum_vis(w, v, c) < 0 || hlod_residency_state(w->res, c) == HLOD_NODE_RESIDENT)
            continue;
        price(w, v, c, 0);
        if (!hlod_residency_want(w->res, c, w->fr[c].priority))
            return 0;
    }
    return 1;
}

/* ---- bookkeeping ---- */

static void note_toggle(walk *w, uint32_t i, int dir)
{
    hlod_node_frame *f = &w->fr[i];
    if (dir > 0)
        w->st->toggles_up++;
    else
        w->st->toggles_down++;
    /* An oscillation: this toggle undoes one made within the last 10 frames. */
    if (f->toggled && f->toggle_dir == -dir && w->frame - f->toggled <= 10)
        w->st->oscillations++;
    f->toggled = w->frame;
    f->toggle_dir = (int8_t)dir;
}

static int draw_node(walk *w, uint32_t i)
{
    const hlod_store_node *n = &w->nodes[i];
    hlod_node_frame *f = &w->fr[i];
    if (!hlod_u32_push(&w->d->allocator, &w->s->draw, i))
        return 0;
    if (f->refined && f->refined + 1 == w->frame)
        note_toggle(w, i, -1);
    f->drawn = w->frame;
    w->st->nodes_drawn++;
    w->st->nodes_per_depth[n->depth < HLOD_STATS_MAX_DEPTH ? n->depth : HLOD_STATS_MAX_DEPTH - 1]++;
    w->st->tris_drawn += n->tri_count;
    w->st->cost_drawn += n->cost;
    w->st->pixels_drawn += f->pix;
    if (is_hidden(w, i))
        w->st->occlusion_hidden++;
    return 1;
}

/* Node i drawn as its colour cube (far_cubes): listed with the frame's
 * cubes, counted as a splat; for toggles and the hold it is drawn. */
static int draw_cube(walk *w, uint32_t i)
{
    hlod_node_frame *f = &w->fr[i];
    if (!hlod_u32_push(&w->d->allocator, &w->s->splats, i))
        return 0;
    if (f->refined && f->refined + 1 == w->frame)
        note_toggle(w, i, -1);
    f->drawn = w->frame;
    w->st->splats++;
    return 1;
}

/* While the camera stands still, a counter outside the dead band moves
 * by at least this much a frame: a node just past the band would
 * otherwise creep to its switch over a hundred frames, and a still view
 * would keep refining long after it stopped (one toggle at frame 130 of a
 * still camera).  With c_hyst_switch 2 a switch still takes 4 frames of
 * the same sign.  While it moves, the paper's sum filters the urgencies
 * (with the floor, walk-drive's oscillations doubled: 124 -> 262). */
#define HYST_MIN_STEP 0.5

static void update_hyst(walk *w, hlod_node_frame *f)
{
    /* New or re-entering nodes start at 0 (Lakhia III-C). */
    if (f->hyst_frame + 1 != w->frame)
        f->hyst = 0;
    /* Lakhia: hyst += (timeSlice - timeNeeded) / timeNeeded, clamped.
     * Within the dead band the two are "almost the same" and the counter
     * stays where it is: a nearly balanced node would otherwise creep to a
     * switch hundreds of frames later, or random-walk across one with the
     * noise of the measured frame time, and a still camera would never
     * settle. */
    double urgency = (f->slice - f->needed) / f->needed;
    if (fabs(urgency) > w->d->c_hyst_deadband)
        f->hyst += !w->still || fabs(urgency) >= HYST_MIN_STEP ? urgency
                                                               : copysign(HYST_MIN_STEP, urgency);
    double lim = w->d->c_hyst_limit;
    if (f->hyst > lim)
        f->hyst = lim;
    if (f->hyst < -lim)
        f->hyst = -lim;
    f->hyst_frame = w->frame;
}

/* ---- the traversal ---- */

typedef struct front {
    double est;     /* estimated ms of the front so far (sum of timeNeeded) */
    double budget;
    double reserved; /* extra of the last frame's refinements not yet visited (signed) */
} front;

/* Node f was refined last frame: what it added to the estimate then is
 * reserved for it (fr->reserved) until the walk reaches it. */
static int refined_last(const walk *w, const hlod_node_frame *f)
{
    return f->refined && f->refined + 1 == w->frame;
}

/* The walk has reached node f: a reservation of its own is claimed (it
 * decides again, against the bound).  Returns whether it was refined last
 * frame. */
static int claim(const walk *w, front *fr, const hlod_node_frame *f)
{
    if (!refined_last(w, f))
        return 0;
    fr->reserved -= f->extra;
    return 1;
}

/* Reservations that this walk will not claim: last frame's refinements at
 * and under child c, which is culled, or whose parent is drawn.  Held to
 * the end of the walk, they refused new refinements room the front never
 * used: on walk (33 ms) a quarter of the budget at the median refusal, and
 * the front filled 73 % of its budget. */
static void release(const walk *w, front *fr, uint32_t c)
{
    const hlod_node_frame *cf = &w->fr[c];
    if (!refined_last(w, cf))
        return;
    fr->reserved -= cf->sub_extra;
}

/* The children of p from w->s->next.v[mark] on will not be visited. */
static void release_pushed(walk *w, front *fr, size_t mark)
{
    for (size_t k = mark; k < w->s->next.n; k++)
        release(w, fr, w->s->next.v[k]);
    w->s->next.n = mark;
}

/* Node p is refined this frame, its children adding extra to the
 * estimate.  The extra keeps its sign: children hidden by occlusion (not
 * charged) make it negative, and the reservations then net to what the
 * walk will add.  (Each clamped at 0, they summed to 0.87 of the budget at
 * the start of a walk that ended at 0.75.)  Returns 0 on allocation
 * failure. */
static int mark_refined(walk *w, hlod_node_frame *pf, uint32_t p, double extra)
{
    pf->extra = extra;
    w->s->reserving += extra;
    pf->refined = w->frame;
    return hlod_u32_push(&w->d->allocator, &w->s->refined, p);
}

/* A node that cannot be drawn, its children standing in for it: one marked
 * bad, or a pinned node (residency.h) not read yet after a transient
 * failure.  Any other node the walk reaches is resident (a parent is drawn
 * while a visible child is not). */
static int stands_down(const walk *w, uint32_t i)
{
    hlod_node_state st = hlod_residency_state(w->res, i);
    return st == HLOD_NODE_BAD || (hlod_residency_is_pinned(w->res, i) && st != HLOD_NODE_RESIDENT);
}

/* Node p stands down: its visible children take its place, whatever the
 * policy or the budget (there is nothing else to draw there).  Those that
 * stand down too are visited in turn (their children stand in, and so on);
 * those being read are asked for and leave nothing drawn in their place
 * this frame.  p is neither drawn nor charged: the estimate trades its
 * timeNeeded for the children's.  Returns 0 on allocation failure. */
static int stand_in(walk *w, const hlod_view *v, front *fr, uint32_t p)
{
    hlod_node_frame *pf = &w->fr[p];
    uint32_t c0 = hlod_store_first_child(w->nodes, p), c1 = hlod_store_child_end(w->nodes, p);
    size_t mark = w->s->next.n;
    double sum_pr = 0, sum_needed = 0;
    (void)claim(w, fr, pf);
    for (uint32_t c = c0; c < c1; c++) {
        double fv = frustum_vis(w, v, c);
        if (fv < 0) {
            release(w, fr, c);
            continue;
        }
        price(w, v, c, fv);
        if (fv < 1 || (!stands_down(w, c) && !is_cube(w, c) &&
                       hlod_residency_state(w->res, c) != HLOD_NODE_RESIDENT)) {
            release(w, fr, c);
            /* a visible one being read leaves a hole until it arrives */
            if (!(fv >= 1 ? hlod_residency_need : hlod_residency_want)(w->res, c, w->fr[c].priority))
                return 0;
            w->st->wanted_missing += fv >= 1;
            continue;
        }
        if (!hlod_u32_push(&w->d->allocator, &w->s->next, c))
            return 0;
        if (!is_hidden(w, c))
            sum_pr += w->fr[c].priority;
    }
    for (size_t k = mark; k < w->s->next.n; k++) {
        hlod_node_frame *cf = &w->fr[w->s->next.v[k]];
        if (is_hidden(w, w->s->next.v[k])) {
            cf->slice = cf->needed = 0;
            continue;
        }
        cf->slice = pf->slice * (cf->priority / sum_pr);
        cf->needed = node_needed(w, w->s->next.v[k]);
        sum_needed += cf->needed;
        if ((w->policy->traits & HLOD_PT_HYST) && cf->needed > 0) /* (a cube's may be 0) */
            update_hyst(w, cf);
    }
    fr->est += sum_needed - pf->needed;
    return mark_refined(w, pf, p, 0); /* no choice: nothing to reserve for */
}

/* The policy's own decision for node p of the front, its children
 * needing sum_needed of share (ms) and their counters voting cum; *near:
 * refining is close, so the children are asked for. */
static int policy_refines(const walk *w, const hlod_view *v, uint32_t p, double share,
                          double sum_needed, double cum, int *near)
{
    hlod_node_frame *pf = &w->fr[p];
    hlod_policy_in in = {.d = w->d,
                         .node = &w->nodes[p],
                         /* (a square root a node: only for the policy that reads it) */
                         .distance = w->policy->traits & HLOD_PT_SSE
                                         ? node_distance(v, &w->nodes[p])
                                         : 0,
                         .pixels_per_radian = v->pixels_per_radian,
                         .share = share,
                         .sum_needed = sum_needed,
                         .cum = cum,
                         .refined_last = pf->refined && pf->refined + 1 == w->frame,
                         .sse_pixels = w->sse_pixels,
                         .eye = v->eye,
                         .frame = w->frame,
                         .mem = &pf->mem};
    return w->policy->refines(&in, near);
}

/* Child c of a node whose slice is share, among visible siblings of total
 * priority sum_pr not hidden: its slice and timeNeeded (eq. 4), its
 * counter, and its vote trunc(hyst / c_hyst_switch) (lakhia; 0 without
 * one).  A hidden child gets no slice and no need (it is not drawn), but
 * its counter holds and it votes with it: it is still on the front.
 * (Left out, the others decided alone: on walk-drive a parent refined for
 * a child at +8, that child was hidden the next frame, the parent
 * coarsened on a sibling at -8, the child, no longer drawn, was no longer
 * hidden, and its counter had restarted: refined and coarsened every 3-4
 * frames.) */
static double child_vote(walk *w, uint32_t c, double share, double sum_pr)
{
    hlod_node_frame *cf = &w->fr[c];
    const int lakhia = (w->policy->traits & HLOD_PT_HYST) != 0;
    if (is_hidden(w, c)) {
        cf->slice = cf->needed = 0;
        if (!lakhia)
            return 0;
        if (cf->hyst_frame + 1 != w->frame)
            cf->hyst = 0;
        cf->hyst_frame = w->frame;
    } else {
        cf->slice = share * (cf->priority / sum_pr);
        cf->needed = node_needed(w, c);
        if (!lakhia || !(cf->needed > 0))
            return 0;
        update_hyst(w, cf);
    }
    return trunc(cf->hyst / w->d->c_hyst_switch);
}

/* Whether the eye stands inside node n's box. */
static int eye_inside(const hlod_view *v, const hlod_store_node *n)
{
    for (int k = 0; k < 3; k++)
        if (!(v->eye[k] >= n->bbox_min[k] && v->eye[k] <= n->bbox_max[k]))
            return 0;
    return 1;
}

/* The shareTime of node p when the eye stands inside its box: at least
 * what its visible children not hidden need (those pushed from mark).
 * Its coarse geometry is then seen from within (a city group simplified
 * from separate blocks and the ground roofs the street), an error no
 * distance bounds, and priority by distance cannot price it: the box's
 * distance is its floor, a tenth of a radius that may span the city, so
 * its siblings took the parent's time.  Parts city, walk-drive at 33 ms:
 * a group of 9 children needing 4.44 ms got a slice of 4.04 of its
 * parent's 27, with 14 ms of the budget unused, and was drawn over the
 * street camera (6.4 dB) for hundreds of frames.  The frame's budget
 * still bounds the refinement. */
static double surround_share(const walk *w, size_t mark, double share)
{
    double need = 0;
    for (size_t k = mark; k < w->s->next.n; k++) {
        uint32_t c = w->s->next.v[k];
        if (!is_hidden(w, c))
            need += node_needed(w, c);
    }
    need *= 1 + KEEP_MARGIN; /* nohyst refines only past the need */
    return need > share ? need : share;
}

/* Moves the nodes of this level that the eye stands inside to its front
 * (each part keeps its order): the budget bound is met in walk order, and
 * a coarse node drawn around the eye is the worst error a frame can show.
 * Parts city, walk-drive, nohyst at a 7.1 ms budget: the street camera's
 * group, reached after the blocks elsewhere had refined, was coarsened by
 * the bound (6.6 dB). */
static void eye_first(walk *w, const hlod_view *v)
{
    hlod_u32_vec *l = &w->s->level;
    size_t first = 0;
    for (size_t k = 0; k < l->n; k++)
        if (eye_inside(v, &w->nodes[l->v[k]])) {
            uint32_t t = l->v[k];
            memmove(l->v + first + 1, l->v + first, (k - first) * sizeof *l->v);
            l->v[first++] = t;
        }
}

/* Pushes the visible children of p onto w->s->next, priced, and sums
 * the priorities of those not hidden (sum_pr) and of all (sum_vote, with
 * voters their count: a hidden child votes).  Those outside but near are
 * prefetched.  Returns 0 on allocation failure. */
static int gather(walk *w, const hlod_view *v, front *fr, uint32_t p, double *sum_pr,
                  double *sum_vote, uint32_t *voters)
{
    uint32_t c0 = hlod_store_first_child(w->nodes, p), c1 = hlod_store_child_end(w->nodes, p);
    for (uint32_t c = c0; c < c1; c++) {
        double fv = frustum_vis(w, v, c);
        if (fv < 1)
            release(w, fr, c);
        if (fv < 0)
            continue;
        hlod_node_frame *cf = &w->fr[c];
        price(w, v, c, fv);
        if (fv < 1) {
            /* outside but near: prefetch only */
            if (!hlod_residency_want(w->res, c, cf->priority))
                return 0;
            continue;
        }
        if (!hlod_u32_push(&w->d->allocator, &w->s->next, c))
            return 0;
        if (!is_hidden(w, c))
            *sum_pr += cf->priority;
        *sum_vote += cf->priority;
        (*voters)++;
    }
    return 1;
}

/* Node p's children as the walk weighs them: pushed onto w->s->next from
 * mark, their priorities, needs and votes, and the decision so far. */
typedef struct family {
    size_t mark;
    double sum_pr;      /* priorities of the children not hidden */
    double sum_vote;    /* priorities of the voters */
    uint32_t voters;    /* visible children, hidden or not: they vote */
    double share;       /* p's shareTime for them (eq. 4) */
    double sum_needed;  /* their summed timeNeeded */
    double cum;         /* cumHyst: their weighted votes */
    int around;         /* the eye stands inside p's box */
    int all_resident;   /* every child that must be resident is */
    uint32_t missing;   /* those that are not */
    int refine, near;   /* the decision; refining is close */
} family;

/* Whether child c, not resident, holds its parent back.  A top child
 * (group or hlod_0) that stands down (bad, or pinned and not read yet)
 * with children of its own does not: they stand in for it when the walk
 * reaches it.  Else one bad hlod_0 under a readable group would hold the
 * whole group at its coarse level.  Below the top, a bad child still
 * draws its parent (the coarser node is whole); so does an unpinned
 * hlod_0 not read yet (it is on its way). */
static int holds_back(const walk *w, uint32_t c)
{
    return !is_cube(w, c) && hlod_residency_state(w->res, c) != HLOD_NODE_RESIDENT &&
           !(hlod_residency_is_top(w->res, c) && stands_down(w, c) &&
             hlod_store_first_child(w->nodes, c) < hlod_store_child_end(w->nodes, c));
}

/* eq. 4 among the visible siblings: each child's slice, timeNeeded and
 * vote, summed into f.  Lakhia sums the siblings' votes unweighted:
 * siblings of like priority, as cutting planes make them.  A city group's
 * children are not alike (the ground, its box the whole city, beside
 * blocks a two-hundredth of its priority), and there the far siblings'
 * slices voted down a parent whose slice was 7 times its children's whole
 * need.  Each vote counts by the slice it was given. */
static void weigh_children(walk *w, const hlod_view *v, uint32_t p, family *f)
{
    f->share = w->fr[p].slice;
    f->around = eye_inside(v, &w->nodes[p]);
    if (f->around)
        f->share = surround_share(w, f->mark, f->share);
    f->all_resident = 1;
    for (size_t k = f->mark; k < w->s->next.n; k++) {
        uint32_t c = w->s->next.v[k];
        const hlod_node_frame *cf = &w->fr[c];
        double vote = child_vote(w, c, f->share, f->sum_pr);
        f->sum_needed += cf->needed;
        if (vote != 0)
            f->cum += f->voters * (cf->priority / f->sum_vote) * vote;
        if (holds_back(w, c)) {
            f->all_resident = 0;
            f->missing++;
        }
    }
}

/* The frame estimate never exceeds the budget (HLOD_PT_BUDGET).  A new
 * refinement must fit in KEEP_MARGIN less than the budget, one already
 * made may use all of it: the bound itself has hysteresis, so frame-time
 * noise moving the budget by a few percent does not flip a marginal node
 * every frame.  A new refinement also leaves room for the ones the last
 * frame made that this walk has not reached yet: else a node whose
 * counter crossed its switch takes the budget of one refined further on,
 * which then toggles down.  Around the eye a refinement may use the whole
 * budget, as one already made: it comes first in its level (eye_first),
 * so the reservations of all the others would stand against it. */
static void apply_bound(walk *w, const front *fr, hlod_node_frame *pf, int was_refined,
                        family *f)
{
    double held = fr->reserved > 0 ? fr->reserved : 0;
    double bound =
        was_refined || f->around ? fr->budget : fr->budget * (1 - KEEP_MARGIN) - held;
    if (f->refine && fr->est - pf->needed + f->sum_needed > bound) {
        f->refine = 0;
        w->s->cap_hits++;
        if (was_refined && w->hold)
            hlod_hold_capped(pf, w->frame);
    } else if (!f->refine && f->near) {
        w->s->slice_denied++;
    }
}

/* The policy decides p (around the eye the children's counters do not
 * hold it back: their slices split its time by priority, and the far
 * ones' voted down a group the street camera stood in), then the hold and
 * the budget bound may overrule it. */
static void decide(walk *w, const hlod_view *v, const front *fr, uint32_t p, int was_refined,
                   family *f)
{
    hlod_node_frame *pf = &w->fr[p];
    f->refine = policy_refines(w, v, p, f->share, f->sum_needed,
                               f->around && f->cum < 0 ? 0 : f->cum, &f->near);
    if (w->hold)
        f->refine = hlod_hold_front(pf, w->frame, w->hold_since, w->d->still_refine_late > 0,
                                    f->refine);
    if (w->policy->traits & HLOD_PT_BUDGET)
        apply_bound(w, fr, pf, was_refined, f);
}

/* Asks for the children that are not resident when refining is near: a
 * refinement held back only by their read is waited for (read and
 * uploaded before the prefetch).  0 on allocation failure. */
static int ask_children(walk *w, const family *f)
{
    if (!f->near || f->all_resident)
        return 1;
    for (size_t k = f->mark; k < w->s->next.n; k++) {
        uint32_t c = w->s->next.v[k];
        if (!is_cube(w, c) &&
            !(f->refine ? hlod_residency_need : hlod_residency_want)(w->res, c, w->fr[c].priority))
            return 0;
    }
    return 1;
}

/* Carries out the decision: a visible child that is not resident forces
 * the parent; else the children replace p on the front.  0 on allocation
 * failure. */
static int commit(walk *w, front *fr, uint32_t p, family *f)
{
    hlod_node_frame *pf = &w->fr[p];
    if (f->refine && !f->all_resident) {
        w->st->wanted_missing += f->missing;
        pf->waiting = w->frame;
        f->refine = 0;
    }
    if (!f->refine) {
        release_pushed(w, fr, f->mark);
        return draw_node(w, p);
    }
    fr->est += f->sum_needed - pf->needed;
    hlod_hold_uncap(pf);
    if (pf->drawn && pf->drawn + 1 == w->frame)
        note_toggle(w, p, +1);
    return mark_refined(w, pf, p, f->sum_needed - pf->needed);
}

/* Decides node p of the front: draw it, or append its visible children to
 * w->s->next.  Returns 0 on allocation failure. */
static int visit(walk *w, const hlod_view *v, front *fr, uint32_t p)
{
    hlod_node_frame *pf = &w->fr[p];
    uint32_t c0 = hlod_store_first_child(w->nodes, p), c1 = hlod_store_child_end(w->nodes, p);
    if (is_cube(w, p)) {
        /* its cube needs no read, and its children would be smaller still */
        (void)claim(w, fr, pf);
        for (uint32_t c = c0; c < c1; c++)
            release(w, fr, c);
        return draw_cube(w, p);
    }
    if (stands_down(w, p))
        return stand_in(w, v, fr, p);
    const int was_refined = claim(w, fr, pf);
    if (c0 == c1)
        return draw_node(w, p);
    if (is_hidden(w, p)) {
        for (uint32_t c = c0; c < c1; c++)
            release(w, fr, c);
        return prefetch_hidden(w, v, p) && draw_node(w, p);
    }
    family f = {.mark = w->s->next.n};
    if (!gather(w, v, fr, p, &f.sum_pr, &f.sum_vote, &f.voters))
        return 0;
    if (w->s->next.n == f.mark) {
        /* The box meets the frustum but no child's does: nothing of the
         * children would show; drawing p is the safe choice. */
        return draw_node(w, p);
    }
    weigh_children(w, v, p, &f);
    decide(w, v, fr, p, was_refined, &f);
    return ask_children(w, &f) && commit(w, fr, p, &f);
}

/* ---- fs93: the knapsack, planned before the walk ---- */

/* Funkhouser and Séquin's benefit of showing node p's region (its box's
 * pixels) with tris triangles at a projected error of err_px pixels:
 * size x accuracy x importance (1) x focus x motion, with accuracy
 * 1 - err_px / tris^fs93_m, focus 0.5 + 0.5 cos(the angle off the view
 * axis, 0 behind), and motion 1 / (1 + the region's angular speed across
 * the view, rad/s: the camera's turn plus its travel seen from p). */
static double fs93_benefit(const walk *w, const hlod_view *v, uint32_t p, double err_px,
                           double tris)
{
    const hlod_store_node *n = &w->nodes[p];
    double c[3], r2 = 0, ahead = 0;
    for (int k = 0; k < 3; k++) {
        c[k] = 0.5 * (n->bbox_min[k] + n->bbox_max[k]) - v->eye[k];
        r2 += c[k] * c[k];
        ahead -= v->toward[k] * c[k];
    }
    double r = sqrt(r2);
    double cosine = r > 1e-9 ? ahead / r : 1;
    double focus = 0.5 + 0.5 * (cosine > 0 ? cosine : 0);
    double cross[3] = {v->velocity[1] * c[2] - v->velocity[2] * c[1],
                       v->velocity[2] * c[0] - v->velocity[0] * c[2],
                       v->velocity[0] * c[1] - v->velocity[1] * c[0]};
    double sweep = r2 > 1e-18 ? sqrt(cross[0] * cross[0] + cross[1] * cross[1] +
                                     cross[2] * cross[2]) / r2
                              : 0;
    double motion = 1 / (1 + v->turn_rad_s + sweep);
    double accuracy = 1 - err_px / pow(tris > 1 ? tris : 1, w->d->fs93_m);
    return w->fr[p].pix * accuracy * focus * motion;
}

/* A choice other than last frame's loses 1 - fs93_hyst of its benefit's
 * size (FS93's hysteresis term). */
static double fs93_hysteresis(const walk *w, double b)
{
    return b - (1 - w->d->fs93_hyst) * fabs(b);
}

/* What fs93 prices node i at: the cost model's timeNeeded (the sum of its
 * terms), or with fs93_cost the paper's max(per-primitive, per-pixel)
 * form of the same fitted terms (Funkhouser and Séquin's cost heuristic:
 * the pipeline's slower stage sets a node's time). */
static double fs93_node_cost(const walk *w, uint32_t i)
{
    if (!(w->d->fs93_cost > 0))
        return node_needed(w, i);
    double prim = w->draw_ms + w->v_time * hlod_node_cost(&w->nodes[i]),
           fill = w->pixel_ms * w->fr[i].pix;
    return prim > fill ? prim : fill;
}

static double projected_error(const walk *w, const hlod_view *v, uint32_t i)
{
    return w->nodes[i].error * v->pixels_per_radian / node_distance(v, &w->nodes[i]);
}

/* The knapsack's items, one a node whose children may replace it. */
typedef struct fs93_plan {
    hlod_knapsack_item *it;
    uint32_t *node;
    uint32_t n;
    size_t cap;
} fs93_plan;

/* Adds node p's item under item `parent`, priced, and then its children's
 * (those under last frame's front, and one level past it).  Returns 0 on
 * allocation failure. */
static int fs93_add(walk *w, const hlod_view *v, fs93_plan *pl, uint32_t p, uint32_t parent,
                    int past)
{
    uint32_t c0 = hlod_store_first_child(w->nodes, p), c1 = hlod_store_child_end(w->nodes, p);
    if (c0 == c1 || is_hidden(w, p) || stands_down(w, p))
        return 1;
    double cost = -fs93_node_cost(w, p), tris = 0, err = 0;
    uint32_t shown = 0;
    int allowed = 1;
    for (uint32_t c = c0; c < c1; c++) {
        if (frustum_vis(w, v, c) < 1)
            continue;
        price(w, v, c, 1);
        shown++;
        allowed &= !holds_back(w, c);
        if (is_hidden(w, c))
            continue;
        cost += fs93_node_cost(w, c);
        tris += w->nodes[c].tri_count;
        double e = projected_error(w, v, c);
        err = e > err ? e : err;
    }
    if (!shown)
        return 1;
    if (pl->n == pl->cap) {
        size_t cap = pl->cap ? 2 * pl->cap : 256;
        hlod_knapsack_item *it = hlod_mem_realloc(&w->d->allocator, pl->it, cap * sizeof *it);
        if (!it)
            return 0;
        pl->it = it;
        uint32_t *node = hlod_mem_realloc(&w->d->allocator, pl->node, cap * sizeof *node);
        if (!node)
            return 0;
        pl->node = node;
        pl->cap = cap;
    }
    const hlod_node_frame *pf = &w->fr[p];
    int was = pf->refined && pf->refined + 1 == w->frame;
    double mine = fs93_benefit(w, v, p, projected_error(w, v, p), w->nodes[p].tri_count),
           theirs = fs93_benefit(w, v, p, err, tris);
    uint32_t me = pl->n++;
    pl->node[me] = p;
    pl->it[me] = (hlod_knapsack_item){
        .gain = was ? theirs - fs93_hysteresis(w, mine) : fs93_hysteresis(w, theirs) - mine,
        .cost = cost,
        .parent = parent,
        .allowed = (uint8_t)allowed,
        .taken = (uint8_t)was};
    if (!was && past)
        return 1;
    for (uint32_t c = c0; c < c1; c++)
        /* priced above as visible (a node cones culled may be priced too,
         * with keep_coned, but is stamped coned) */
        if (w->fr[c].priced == w->frame && w->fr[c].coned != w->frame &&
            !fs93_add(w, v, pl, c, me, past || !was))
            return 0;
    return 1;
}

/* Plans this frame's front for fs93: the items from the visible roots,
 * the knapsack solved within the budget, and each node's decision left in
 * its policy memory (plan: refine; ask: its children are worth reading).
 * Returns 0 on allocation failure. */
static int fs93_plan_front(walk *w, const hlod_view *v, double budget)
{
    hlod_selection *s = w->s;
    fs93_plan pl = {s->fs93_items, s->fs93_nodes, 0, s->fs93_cap};
    double base = 0;
    int ok = 1;
    for (uint32_t r = 0; r < s->root_count && ok; r++) {
        if (frustum_vis(w, v, r) < 1)
            continue;
        price(w, v, r, 1);
        if (!is_hidden(w, r))
            base += fs93_node_cost(w, r);
        ok = fs93_add(w, v, &pl, r, HLOD_KNAPSACK_NONE, 0);
    }
    s->fs93_items = pl.it;
    s->fs93_nodes = pl.node;
    s->fs93_cap = pl.cap;
    if (!ok)
        return 0;
    s->ks.a = &w->d->allocator;
    const double fresh = budget * (1 - KEEP_MARGIN);
    /* the children worth reading: the refinements the knapsack would take
     * were every child resident (the same solve, every item allowed) */
    if (s->fs93_wish_cap < pl.n) {
        hlod_knapsack_item *x = hlod_mem_realloc(&w->d->allocator, s->fs93_wish,
                                                 pl.cap * sizeof *x);
        if (!x)
            return 0;
        s->fs93_wish = x;
        s->fs93_wish_cap = pl.cap;
    }
    for (uint32_t i = 0; i < pl.n; i++) {
        s->fs93_wish[i] = pl.it[i];
        s->fs93_wish[i].allowed = 1;
    }
    if (hlod_knapsack_solve(&s->ks, s->fs93_wish, pl.n, base, budget, fresh) < 0)
        return 0;
    /* the plan, within the budget bound and its own hysteresis, as for the
     * other policies: a new refinement must leave KEEP_MARGIN of it free */
    if (hlod_knapsack_solve(&s->ks, pl.it, pl.n, base, budget, fresh) < 0)
        return 0;
    for (uint32_t i = 0; i < pl.n; i++) {
        hlod_policy_mem *m = &w->fr[pl.node[i]].mem;
        m->plan = pl.it[i].taken ? w->frame : 0;
        m->ask = s->fs93_wish[i].taken ? w->frame : 0;
    }
    return 1;
}

/* Each node refined this frame: sub_extra, the extra of the refinements
 * at and under it, which next frame's walk releases at once when it
 * coarsens the node or culls it.  Walk order puts a parent before its
 * children, so the reverse order sums bottom up. */
/* ---- additive stores (a sample tree; docs/sampletree.md) ---- */

/* Pushes children [c0, c1) on the walk's stack so that they pop back to
 * front: the farthest box centre from the eye first (an octree's cells
 * do not overlap, so this orders them; Chamberlain 3).  More than 64
 * children (never in an octree) go in index order. */
static int push_back_to_front(walk *w, const hlod_view *v, uint32_t c0, uint32_t c1)
{
    uint32_t id[64];
    double d2[64];
    uint32_t n = c1 - c0 <= 64 ? c1 - c0 : 0;
    for (uint32_t k = 0; k < n; k++) {
        const hlod_store_node *c = &w->nodes[c0 + k];
        double s = 0;
        for (int a = 0; a < 3; a++) {
            double x = 0.5 * (c->bbox_min[a] + c->bbox_max[a]) - v->eye[a];
            s += x * x;
        }
        uint32_t at = k;
        while (at > 0 && d2[at - 1] > s) { /* nearest first: pushed first, popped last */
            d2[at] = d2[at - 1];
            id[at] = id[at - 1];
            at--;
        }
        d2[at] = s;
        id[at] = c0 + k;
    }
    for (uint32_t k = 0; k < n; k++)
        if (!hlod_u32_push(&w->d->allocator, &w->s->level, id[k]))
            return 0;
    if (!n)
        for (uint32_t c = c1; c-- > c0;)
            if (!hlod_u32_push(&w->d->allocator, &w->s->level, c))
                return 0;
    return 1;
}

/* Klein 4.2 and 4.5: depth-first from the roots, every node whose box
 * meets the frustum (and that normal cones do not cull) is drawn, its
 * ancestors with it; where a node's box projects within splat_px x
 * splat_px pixels the walk stops there and the node is one splat of its
 * colour instead of its triangles.  A node not resident is asked for
 * (bigger on screen first: an ancestor before its descendants) and the
 * walk goes on below it: a missing node thins the picture, it leaves no
 * hole where its ancestors or descendants are in.  Policy full draws
 * every node (no splats): the sample tree's reference; so does klein
 * with splats off, streaming as klein does.  Policy cubes (Chamberlain
 * 3) walks the same way over colour cubes: children back to front, and
 * a node within cube_px is its cube, listed in that order. */
static int walk_nodes(walk *w, const hlod_view *v)
{
    hlod_selection *s = w->s;
    const int full = w->d->policy == HLOD_POLICY_FULL || w->d->splats < 0;
    const int cubes = (w->policy->traits & HLOD_PT_CUBES) != 0;
    const uint32_t stand_in = cubes ? HLOD_EXTRA_CUBE : HLOD_EXTRA_COLOR;
    const double px = w->splat_px;
    hlod_u32_vec *stack = &s->level;
    stack->n = 0;
    for (uint32_t r = s->root_count; r-- > 0;)
        if (!hlod_u32_push(&w->d->allocator, stack, r))
            return 0;
    while (stack->n) {
        uint32_t i = stack->v[--stack->n];
        const hlod_store_node *n = &w->nodes[i];
        if (hlod_view_outside(v, n->bbox_min, n->bbox_max) > 0)
            continue;
        if (w->cones && cone_hides(w, v, i)) {
            if (!note_coned(w, v, i))
                return 0;
            continue;
        }
        hlod_node_frame *f = &w->fr[i];
        double raw[4], z;
        int front = project_raw(v, n->bbox_min, n->bbox_max, raw, &z);
        double cw = fmin(raw[2], v->width) - fmax(raw[0], 0),
               ch = fmin(raw[3], v->height) - fmax(raw[1], 0);
        w->st->nodes_visited++;
        f->pix = !front ? v->width * v->height : cw > 0 && ch > 0 ? cw * ch : 0;
        f->priority = 1 + f->pix;
        f->priced = w->frame;
        if (!full && front && raw[2] - raw[0] <= px && raw[3] - raw[1] <= px && s->extras &&
            (s->extras[i].flags & stand_in)) {
            if (!hlod_u32_push(&w->d->allocator, &s->splats, i))
                return 0;
            w->st->splats++;
            continue;
        }
        hlod_node_state state = hlod_residency_state(w->res, i);
        if (state == HLOD_NODE_RESIDENT) {
            if (!draw_node(w, i))
                return 0;
        } else if (state != HLOD_NODE_BAD) {
            w->st->wanted_missing++;
            if (!hlod_residency_need(w->res, i, f->priority))
                return 0;
        }
        uint32_t c0 = hlod_store_first_child(w->nodes, i), c1 = hlod_store_child_end(w->nodes, i);
        if (cubes && c1 - c0 > 1) {
            if (!push_back_to_front(w, v, c0, c1))
                return 0;
            continue;
        }
        for (uint32_t c = c1; c-- > c0;)
            if (!hlod_u32_push(&w->d->allocator, stack, c))
                return 0;
    }
    return 1;
}

/* The cube of a block of 2^L x 2^L copies, L = 0..16, from the root's
 * (Chamberlain 4 over copies that tile the block): seen along z the four
 * sub-blocks lie side by side, so the face is theirs; seen along x or y
 * each column is a sub-block over the one behind it, so the face is
 * theirs composited front over back ("over", premultiplied). */
static void make_block_cubes(hlod_selection *s)
{
    float c[6][4];
    for (int f = 0; f < 6; f++)
        for (int k = 0; k < 4; k++)
            c[f][k] = s->extras[0].cube[f][k] / 255.0f;
    for (int L = 0; L <= 16; L++) {
        for (int f = 0; f < 6; f++)
            for (int k = 0; k < 4; k++)
                s->block_cube[L][f][k] = (uint8_t)lrintf(255 * (c[f][k] < 1 ? c[f][k] : 1));
        for (int f = 0; f < 4; f++) { /* +-x, +-y */
            float a = c[f][3];
            for (int k = 0; k < 4; k++)
                c[f][k] += (1 - a) * c[f][k];
        }
    }
    s->block_cubes_made = 1;
}

/* The box of the block of 2^L x 2^L copies from copy (i, j). */
static void block_box(const hlod_selection *s, uint32_t L, uint32_t i, uint32_t j, double lo[3],
                      double hi[3])
{
    for (int a = 0; a < 3; a++) {
        lo[a] = s->scene_lo[a];
        hi[a] = s->scene_hi[a];
    }
    lo[0] += i * s->copy_side[0];
    lo[1] += j * s->copy_side[1];
    hi[0] += (i + (1u << L) - 1) * s->copy_side[0];
    hi[1] += (j + (1u << L) - 1) * s->copy_side[1];
}

/* Chamberlain Fig. 5, copies instanced at the top (cube_copies): a
 * quadtree of blocks of copies, walked depth first from the whole grid,
 * sub-blocks far to near.  A block outside the frustum is skipped; one
 * whose box projects within cube_px is its block cube; a single copy is
 * walked as the scene is, with the eye moved by minus its offset (every
 * test is relative to the eye), its entries marked with the copy; any
 * other block splits in four. */
static int walk_copies(walk *w, const hlod_view *v)
{
    hlod_selection *s = w->s;
    const hlod_allocator *al = &w->d->allocator;
    const uint32_t N = s->copy_levels, side = 1u << N;
    if (!s->block_cubes_made)
        make_block_cubes(s);
    hlod_u32_vec *stack = &s->next; /* level, i, j triples */
    stack->n = 0;
    if (!hlod_u32_push(al, stack, N) || !hlod_u32_push(al, stack, 0) || !hlod_u32_push(al, stack, 0))
        return 0;
    while (stack->n) {
        uint32_t j = stack->v[--stack->n], i = stack->v[--stack->n], L = stack->v[--stack->n];
        double lo[3], hi[3];
        block_box(s, L, i, j, lo, hi);
        if (hlod_view_outside(v, lo, hi) > 0)
            continue;
        double raw[4], z;
        w->st->nodes_visited++;
        if (L > 0 && project_raw(v, lo, hi, raw, &z) && raw[2] - raw[0] <= w->splat_px &&
            raw[3] - raw[1] <= w->splat_px) {
            if (!hlod_u32_push(al, &s->splats, HLOD_SEL_BLOCK(L)) ||
                !hlod_u32_push(al, &s->splat_copy, i + j * side))
                return 0;
            w->st->splats++;
            continue;
        }
        if (L == 0) {
            hlod_view cv = *v;
            double off[3];
            hlod_sel_copy_offset(s, i + j * side, off);
            for (int a = 0; a < 3; a++) {
                cv.eye[a] -= off[a];
                cv.probe[a] -= off[a];
            }
            size_t d0 = s->draw.n, s0 = s->splats.n;
            size_t keep = stack->n; /* walk_nodes uses s->level, not this stack */
            if (!walk_nodes(w, &cv))
                return 0;
            stack->n = keep;
            for (size_t k = d0; k < s->draw.n; k++)
                if (!hlod_u32_push(al, &s->draw_copy, i + j * side))
                    return 0;
            for (size_t k = s0; k < s->splats.n; k++)
                if (!hlod_u32_push(al, &s->splat_copy, i + j * side))
                    return 0;
            continue;
        }
        /* the four sub-blocks, nearest pushed first (popped last) */
        uint32_t h = 1u << (L - 1), sub[4][2] = {{i, j}, {i + h, j}, {i, j + h}, {i + h, j + h}};
        double d2[4];
        int order[4] = {0, 1, 2, 3};
        for (int k = 0; k < 4; k++) {
            double sl[3], sh[3];
            block_box(s, L - 1, sub[k][0], sub[k][1], sl, sh);
            d2[k] = 0;
            for (int a = 0; a < 3; a++) {
                double c = 0.5 * (sl[a] + sh[a]) - v->eye[a];
                d2[k] += c * c;
            }
        }
        for (int k = 1; k < 4; k++)
            for (int q = k; q > 0 && d2[order[q]] < d2[order[q - 1]]; q--) {
                int t = order[q];
                order[q] = order[q - 1];
                order[q - 1] = t;
            }
        for (int k = 0; k < 4; k++)
            if (!hlod_u32_push(al, stack, L - 1) || !hlod_u32_push(al, stack, sub[order[k]][0]) ||
                !hlod_u32_push(al, stack, sub[order[k]][1]))
                return 0;
    }
    return 1;
}

static int walk_additive(walk *w, const hlod_view *v)
{
    hlod_selection *s = w->s;
    s->draw_copy.n = s->splat_copy.n = 0;
    s->copy_levels = (w->policy->traits & HLOD_PT_CUBES) && s->extras ? w->d->cube_copies : 0;
    return s->copy_levels ? walk_copies(w, v) : walk_nodes(w, v);
}

static void sum_subtrees(walk *w)
{
    const hlod_u32_vec *r = &w->s->refined;
    for (size_t k = 0; k < r->n; k++)
        w->fr[r->v[k]].sub_extra = w->fr[r->v[k]].extra;
    for (size_t k = r->n; k-- > 0;) {
        uint32_t parent = w->nodes[r->v[k]].parent;
        if (parent != HLOD_STORE_NO_PARENT && w->fr[parent].refined == w->frame)
            w->fr[parent].sub_extra += w->fr[r->v[k]].sub_extra;
    }
}

hlod_result hlod_select(hlod_selection *s, struct hlod_residency *res, const hlod_view *v,
                        const hlod_select_in *in)
{
    assert(s && res && v && in);
    const hlod_policy_row *pol = hlod_policy_row_of(s->d->policy);
    walk ctx = {s,           res,           s->d,        s->st,
                s->nodes,    s->fr,         in->frame,   in->v_time,
                in->sse_pixels, in->draw_ms, in->pixel_ms,
                in->occlusion && in->occ && (pol->traits & HLOD_PT_OCCLUDE), in->still,
                in->hold_since && (pol->traits & HLOD_PT_HOLD), in->hold_since, pol, in->occ,
                s->extras && (s->d->cone_cull > 0 || (pol->traits & HLOD_PT_CONES)), 0,
                in->splat_px >= 1 ? in->splat_px : 1,
                s->extras && !s->additive && s->d->far_cubes > 0};
    walk *w = &ctx;
    const double share_ms = in->share_ms;
    s->draw.n = s->level.n = s->next.n = s->refined.n = s->coned.n = s->splats.n = 0;
    s->cap_hits = s->slice_denied = 0;
    s->splat_px = w->splat_px;
    if (s->additive)
        return walk_additive(w, v) && !w->nomem ? HLOD_OK : HLOD_ERR_NOMEM;
    front fr = {0, in->budget_ms, s->reserving};
    s->reserving = 0;
    if ((pol->traits & HLOD_PT_KNAPSACK) && !fs93_plan_front(w, v, in->budget_ms))
        return HLOD_ERR_NOMEM;

    /* the visible roots share share_ms (shareTime: c_targetTime less
     * the fixed frame part, times the engine's share gain); they are always
     * resident and drawn. */
    double sum_pr = 0;
    for (uint32_t r = 0; r < w->s->root_count; r++) {
        double fv = frustum_vis(w, v, r);
        if (fv < 1) {
            release(w, &fr, r);
            continue; /* roots are resident, or asked for by residency */
        }
        price(w, v, r, fv);
        if (!hlod_u32_push(&w->d->allocator, &w->s->level, r))
            return HLOD_ERR_NOMEM;
        if (!is_hidden(w, r))
            sum_pr += w->fr[r].priority;
    }
    for (size_t k = 0; k < w->s->level.n; k++) {
        uint32_t r = w->s->level.v[k];
        hlod_node_frame *f = &w->fr[r];
        if (is_hidden(w, r)) {
            f->slice = f->needed = 0;
            continue;
        }
        f->slice = share_ms * (f->priority / sum_pr);
        f->needed = node_needed(w, r);
        fr.est += f->needed;
    }

    while (w->s->level.n) {
        w->s->next.n = 0;
        eye_first(w, v);
        for (size_t k = 0; k < w->s->level.n; k++)
            if (!visit(w, v, &fr, w->s->level.v[k]))
                return HLOD_ERR_NOMEM;
        hlod_u32_vec t = w->s->level;
        w->s->level = w->s->next;
        w->s->next = t;
    }
    sum_subtrees(w);
    return w->nomem ? HLOD_ERR_NOMEM : HLOD_OK;
}
