/*
 * policy.c - the selection policies' table and their decisions
 * (policy.h; docs/runtime.md, "Policies").
 *
 *   lakhia  refine if cumHyst >= 0 (Lakhia, "Hysteresis": the children's
 *           urgency counters vote), unless the children's summed
 *           timeNeeded exceeds the shared time by more than
 *           c_safety_slack (the safety clamp);
 *   nohyst  refine if shareTime > sum timeNeeded (eq. 4 recursion rule);
 *   sse     refine while p's projected geometric error exceeds the pixel
 *           threshold (the threshold is adapted by the cost model);
 *   full    refine whenever the children are resident (reference renders);
 *   counter nohyst's rule, but a node switches (refines or coarsens) only
 *           after switch_frames consecutive frames that want the switch
 *           (Maciel and Shirley, I3D 1995, as Lakhia's "Hysteresis"
 *           describes it: a fixed counter, blind to urgency);
 *   fs93    refine where Funkhouser and Séquin's greedy knapsack, planned
 *           before the walk (traverse.c, fs93_plan_front), took the
 *           refinement (SIGGRAPH 1993; every visible node still drawn);
 *   okamoto refine while the node's projected error eps * f / r exceeds
 *           the pixel threshold, r the eye's distance to the centre of
 *           the node's box (Okamoto et al., section 4.2; the threshold
 *           adapted as sse's); back-facing subtrees (normal cones) are
 *           always skipped, as the paper's walk does;
 *   klein   a sample tree's walk (traverse.c, walk_additive): no front to
 *           decide, so its function is never asked;
 *   klein-auto  klein, the splat size adapted each frame to the target
 *           (cost_model.c, hlod_cost_model_adapt_splat);
 *   rzb     Wand's randomized z-buffer (rzb.h): every leaf in core, points
 *           where faces are small; no front, so its function is never
 *           asked;
 *   cubes   Chamberlain's colour cubes: klein's walk over a store whose
 *           nodes carry cubes, children back to front, a node within
 *           cube_px drawn as its blended cube (docs/cubes.md);
 *   lumigraph  okamoto's rule at the fixed lumi_mesh_px: the sparse mesh
 *           that Okamoto's Grid-Lumigraph client colours from the views of
 *           its repository (lumigraph.h, docs/lumigraph.md).
 */
#include "policy.h"

#include <assert.h>
#include <math.h>
#include <string.h>

/* cumHyst < 0 draws the parent (the tolerance: weights of equal siblings
 * that sum to n only to rounding); the safety clamp draws it too when the
 * children clearly do not fit the shared time (c_safety_slack), with
 * room to keep a refinement made last frame. */
static int lakhia_refines(const hlod_policy_in *in, int *near)
{
    *near = in->sum_needed <= 2 * in->share;
    return in->cum >= -1e-9 &&
           in->sum_needed <= in->share * (1 + in->d->c_safety_slack) *
                                 (in->refined_last ? 1 + HLOD_KEEP_MARGIN : 1);
}

static int nohyst_refines(const hlod_policy_in *in, int *near)
{
    *near = in->sum_needed <= 2 * in->share;
    return in->share > in->sum_needed;
}

static int sse_refines(const hlod_policy_in *in, int *near)
{
    double sse = in->node->error * in->pixels_per_radian / in->distance;
    *near = sse > 0.5 * in->sse_pixels;
    return sse > in->sse_pixels;
}

static int full_refines(const hlod_policy_in *in, int *near)
{
    (void)in;
    *near = 1;
    return 1;
}

/* A switch wanted in a row: each frame that wants one counts, any frame
 * that does not (or that skips the node) starts the count again.  The
 * count is not reset by the switch itself: a refinement that must wait for
 * its children's data happens the frame they arrive. */
static int counter_refines(const hlod_policy_in *in, int *near)
{
    int want = nohyst_refines(in, near);
    hlod_policy_mem *m = in->mem;
    if (want == in->refined_last) {
        m->count = 0;
        return want;
    }
    int8_t dir = want ? 1 : -1;
    m->count = m->frame + 1 == in->frame && m->dir == dir ? m->count + 1 : 1;
    m->frame = in->frame;
    m->dir = dir;
    return m->count >= in->d->switch_frames ? want : in->refined_last;
}

static int okamoto_refines(const hlod_policy_in *in, int *near)
{
    const hlod_store_node *n = in->node;
    double r2 = 0;
    for (int k = 0; k < 3; k++) {
        double c = 0.5 * (n->bbox_min[k] + n->bbox_max[k]) - in->eye[k];
        r2 += c * c;
    }
    double r = sqrt(r2) > 1e-6 ? sqrt(r2) : 1e-6;
    double px = n->error * in->pixels_per_radian / r;
    *near = px > 0.5 * in->sse_pixels;
    return px > in->sse_pixels;
}

/* lumigraph: okamoto's rule at the fixed lumi_mesh_px (the sparse mesh's
 * patches are asked for finer as their projected error grows, 5.1 step 4) */
static int lumigraph_refines(const hlod_policy_in *in, int *near)
{
    hlod_policy_in at = *in;
    at.sse_pixels = in->d->lumi_mesh_px;
    return okamoto_refines(&at, near);
}

static int fs93_refines(const hlod_policy_in *in, int *near)
{
    *near = in->mem->ask == in->frame;
    return in->mem->plan == in->frame;
}

static int klein_refines(const hlod_policy_in *in, int *near)
{
    (void)in;
    *near = 1;
    return 1;
}

static const hlod_policy_row rows[HLOD_POLICY_COUNT] = {
    [HLOD_POLICY_LAKHIA] = {"lakhia",
                            HLOD_PT_HYST | HLOD_PT_BUDGET | HLOD_PT_HOLD | HLOD_PT_OCCLUDE |
                                HLOD_PT_SHARE | HLOD_PT_STREAM,
                            lakhia_refines},
    [HLOD_POLICY_NOHYST] = {"nohyst",
                            HLOD_PT_BUDGET | HLOD_PT_OCCLUDE | HLOD_PT_SHARE | HLOD_PT_STREAM,
                            nohyst_refines},
    [HLOD_POLICY_SSE] = {"sse", HLOD_PT_OCCLUDE | HLOD_PT_SSE | HLOD_PT_STREAM, sse_refines},
    [HLOD_POLICY_FULL] = {"full", 0, full_refines},
    [HLOD_POLICY_COUNTER] = {"counter",
                             HLOD_PT_BUDGET | HLOD_PT_OCCLUDE | HLOD_PT_SHARE | HLOD_PT_STREAM,
                             counter_refines},
    [HLOD_POLICY_OKAMOTO] = {"okamoto", HLOD_PT_SSE | HLOD_PT_STREAM | HLOD_PT_CONES,
                             okamoto_refines},
    [HLOD_POLICY_FS93] = {"fs93", HLOD_PT_KNAPSACK | HLOD_PT_OCCLUDE | HLOD_PT_STREAM,
                          fs93_refines},
    [HLOD_POLICY_KLEIN] = {"klein", HLOD_PT_ADDITIVE | HLOD_PT_STREAM, klein_refines},
    [HLOD_POLICY_KLEIN_AUTO] = {"klein-auto", HLOD_PT_ADDITIVE | HLOD_PT_STREAM | HLOD_PT_AUTOSPLAT,
                                klein_refines},
    [HLOD_POLICY_RZB] = {"rzb", HLOD_PT_RZB, klein_refines},
    [HLOD_POLICY_CUBES] = {"cubes", HLOD_PT_ADDITIVE | HLOD_PT_STREAM | HLOD_PT_CUBES, klein_refines},
    [HLOD_POLICY_LUMIGRAPH] = {"lumigraph", HLOD_PT_STREAM | HLOD_PT_CONES | HLOD_PT_LUMI,
                               lumigraph_refines},
};

const hlod_policy_row *hlod_policy_row_of(hlod_policy p)
{
    assert((unsigned)p < HLOD_POLICY_COUNT);
    return &rows[p];
}

const char *hlod_policy_name(hlod_policy p)
{
    return (unsigned)p < HLOD_POLICY_COUNT ? rows[p].name : "unknown";
}

int hlod_policy_parse(const char *name, hlod_policy *out)
{
    for (int i = 0; name && i < HLOD_POLICY_COUNT; i++)
        if (strcmp(name, rows[i].name) == 0) {
            *out = (hlod_policy)i;
            return 1;
        }
    return 0;
}
