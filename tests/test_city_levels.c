/*
 * test_city_levels.c - group nodes above the blocks (docs/store-format.md): the store's
 * shape, each group's content (triangles, texture or
 * colours, error, extent) and the runtime's use of them (the top stays
 * resident, the coarsest frame is the root alone).  Generated cities:
 * textured (scan style) and multi-part untextured (parts style), built with
 * C_levelFactor 2 so groups have at most 4 children and there are two
 * group levels.
 */
#include "check.h"
#include "inspect.h"
#include "hlod/build_store.h"
#include "hlod/engine.h"
#include "hlod/mesh_io.h"
#include "hlod/simplify.h"
#include "hlod/store.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define DESIRED 500
#define BLOCKS 12 /* + the ground: 13 blocks, 4 groups, 1 root */

static char bin[1024], tmp[1024];

static hlod_store *build(const char *style, int levels, const char *out)
{
    char obj[2048], path[2048];
    snprintf(obj, sizeof obj, "%s/%s.obj", tmp, style);
    snprintf(path, sizeof path, "%s/%s", tmp, out);
    if (access(obj, R_OK) != 0)
        CHECK(check_sh("'%s/hlod-gen-city' --preset tiny --blocks %d --style %s --quiet -o '%s'", bin,
                       BLOCKS, style, obj) == 0);
    hlod_build_desc d;
    hlod_build_desc_defaults(&d);
    d.desired_tris = DESIRED;
    d.level_factor = 2;
    d.city_levels = levels;
    d.threads = 2;
    const char *in[] = {obj};
    hlod_build_report rep;
    CHECK(hlod_build_store(&d, in, 1, path, NULL, &rep) == HLOD_OK);
    CHECKF(rep.tris_leaf == rep.tris_in, "%s: %zu leaf triangles of %zu", out, rep.tris_leaf, rep.tris_in);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    return s;
}

/* Every group: non-leaf, at most C_levelFactor^2 children, at most 1.1 x
 * C_desiredTri triangles and at least half of it (or all its children's
 * where they hold fewer), an error at least each child's, and a box that
 * covers its children's within its error (simplification may not lose
 * whole children at the edge of the group).  Returns the groups. */
static uint32_t check_groups(hlod_store *s, const char *name, int textured)
{
    const hlod_store_header *h = hlod_store_get_header(s);
    const hlod_store_node *n = hlod_store_nodes(s);
    CHECKF(h->root_count == 1 && h->block_count == BLOCKS + 1 && h->block_depth == 2,
           "%s: %u roots, %u blocks at depth %u", name, h->root_count, h->block_count, h->block_depth);
    uint32_t groups = hlod_store_first_block(s);
    for (uint32_t g = 0; g < groups; g++) {
        uint32_t c0 = hlod_store_first_child(n, g), c1 = hlod_store_child_end(n, g);
        CHECKF(c1 > c0 && c1 - c0 <= 4, "%s: group %u has %u children", name, g, c1 - c0);
        uint64_t kids = 0; /* what the group simplifies */
        for (uint32_t c = c0; c < c1; c++)
            kids += n[c].tri_count;
        uint64_t lo = kids < DESIRED / 2 ? kids : DESIRED / 2;
        CHECKF(n[g].tri_count <= DESIRED * 11 / 10 && n[g].tri_count >= lo,
               "%s: group %u holds %u triangles (%llu to %u; its children %llu)", name, g,
               n[g].tri_count, (unsigned long long)lo, DESIRED * 11 / 10,
               (unsigned long long)kids);
        CHECKF(n[g].block == HLOD_STORE_NO_BLOCK && n[g].error > 0, "%s: group %u: block %u, error %g",
               name, g, n[g].block, n[g].error);
        CHECKF(textured ? n[g].tex_tri_count == n[g].tri_count && (n[g].flags & HLOD_NODE_TEXTURE)
                        : n[g].tex_tri_count == 0 && !(n[g].flags & HLOD_NODE_TEXTURE) &&
                              (n[g].flags & HLOD_NODE_COLORS),
               "%s: group %u: %u of %u triangles textured, flags %#x", name, g, n[g].tex_tri_count,
               n[g].tri_count, n[g].flags);
        for (int a = 0; a < 3; a++) {
            double lo = INFINITY, hi = -INFINITY;
            for (uint32_t c = c0; c < c1; c++) {
                lo = fmin(lo, n[c].bbox_min[a]);
                hi = fmax(hi, n[c].bbox_max[a]);
            }
            double tol = n[g].error + 1e-6 * (hi - lo);
            CHECKF(n[g].bbox_min[a] >= lo - tol && n[g].bbox_max[a] <= hi + tol,
                   "%s: group %u sticks out of its children on axis %d", name, g, a);
            if (textured) /* the scan-style city's groups keep their children's extent */
                CHECKF(n[g].bbox_min[a] <= lo + tol && n[g].bbox_max[a] >= hi - tol,
                       "%s: group %u lost part of its children on axis %d: [%g, %g] of [%g, %g], "
                       "error %g", name, g, a, n[g].bbox_min[a], n[g].bbox_max[a], lo, hi, n[g].error);
        }
    }
    return groups;
}

/* An untextured group's colours are colours of the blocks under it. */
static void check_group_colors(hlod_store *s)
{
    uint32_t first = hlod_store_first_block(s), top = hlod_store_top_count(s);
    uint8_t block_rgba[BLOCKS + 1][4];
    for (uint32_t b = first; b < top; b++) {
        hlod_store_payload p;
        CHECK(hlod_store_read_node(s, b, 1 << 20, &p) == HLOD_OK);
        CHECK(p.colors != NULL);
        if (p.colors)
            memcpy(block_rgba[b - first], p.colors, 4);
        hlod_store_payload_free(&p);
    }
    size_t distinct = 0;
    for (uint32_t g = 0; g < first; g++) {
        hlod_store_payload p;
        CHECK(hlod_store_read_node(s, g, 1 << 20, &p) == HLOD_OK);
        if (!p.colors)
            continue;
        uint32_t bad = 0;
        for (uint32_t v = 0; v < p.vertex_count; v++) {
            int found = 0;
            for (uint32_t b = 0; b < top - first && !found; b++)
                found = memcmp(p.colors + 4 * v, block_rgba[b], 4) == 0;
            bad += !found;
            if (v && memcmp(p.colors + 4 * v, p.colors, 4) != 0)
                distinct++;
        }
        CHECKF(bad == 0, "group %u: %u vertices with a colour no block has", g, bad);
        hlod_store_payload_free(&p);
    }
    CHECKF(distinct > 0, "the groups carry one colour only: the blocks' colours were lost");
}

static void textured_city(void)
{
    hlod_store *s = build("scan", 1, "scan.hlod");
    if (!s)
        return;
    CHECK(check_groups(s, "scan", 1) == 5);
    hlod_store_close(s);
}

static void parts_city(void)
{
    hlod_store *s = build("parts", 1, "parts.hlod");
    if (!s)
        return;
    CHECK(check_groups(s, "parts", 0) == 5);
    check_group_colors(s);
    hlod_store_close(s);
}

/* One BIM-like block (parts style, 35,000 triangles of separate boxes)
 * simplified to 4000: part pruning alone took whole buildings (31 m of an
 * 83 m diagonal, and 3296 triangles for 4000); the clustering fallback
 * welds the boxes into walls (1.1 m). */
static void parts_block_aggregates(void)
{
    char obj[2048];
    snprintf(obj, sizeof obj, "%s/block.obj", tmp);
    CHECK(check_sh("'%s/hlod-gen-city' --preset tiny --blocks 1 --tris-per-block 35000 --style parts "
                   "--quiet -o '%s'", bin, obj) == 0);
    hlod_mesh m = {0}, o = {0};
    hlod_import_desc id = {0};
    CHECK(hlod_mesh_import(obj, &id, &m, NULL) == HLOD_OK);
    /* the block alone (the ground is the last object) */
    if (m.object_count >= 2 && m.objects[0].first_tri == 0) {
        hlod_mesh b = {0};
        size_t nt = m.objects[0].tri_count;
        CHECK(hlod_mesh_alloc(&b, m.vertex_count, nt, 0) == HLOD_OK);
        memcpy(b.positions, m.positions, 3 * m.vertex_count * sizeof *b.positions);
        memcpy(b.indices, m.indices, 3 * nt * sizeof *b.indices);
        hlod_simplify_desc d = {0};
        d.target_tris = 4000;
        d.measure_error = 1;
        hlod_simplify_stats st;
        CHECK(hlod_simplify(&b, &d, &o, &st) == HLOD_OK);
        double diag = hlod_mesh_bbox_diag(&b);
        fprintf(stderr, "  block: %zu -> %zu triangles, error %.3g of diagonal %.3g, clustered %d\n",
                b.tri_count, o.tri_count, st.error, diag, st.clustered);
        CHECKF(o.tri_count <= 4000 && o.tri_count >= 3600, "%zu triangles for 4000", o.tri_count);
        CHECKF(st.clustered && st.error < 0.03 * diag, "error %g of diagonal %g (clustered %d)",
               st.error, diag, st.clustered);
        hlod_mesh_free(&b);
    } else {
        CHECKF(0, "%s: %zu objects, the block not first", obj, m.object_count);
    }
    hlod_mesh_free(&m);
    hlod_mesh_free(&o);
}

static void look_down(hlod_camera *cam, const hlod_store_header *h)
{
    double c[3], r = 0;
    for (int a = 0; a < 3; a++) {
        c[a] = 0.5 * (h->bbox_min[a] + h->bbox_max[a]);
        r = fmax(r, h->bbox_max[a] - h->bbox_min[a]);
    }
    double eye[3] = {c[0], c[1] - 0.8 * r, c[2] + 1.2 * r}, up[3] = {0, 0, 1};
    CHECK(hlod_camera_look_at(cam, eye, c, up, 60, 0.5, 1e5, 1280, 720) == HLOD_OK);
}

/* The runtime: with a memory budget of one byte only the roots are pinned
 * (resident from the start, never evicted) and the coarsest frame is the
 * root alone; with --city-levels off the roots are the blocks, and it is
 * every block in view. */
static void runtime_uses_the_root(void)
{
    const char *names[2] = {"scan-flat.hlod", "scan.hlod"};
    for (int levels = 0; levels < 2; levels++) {
        hlod_store *s = levels ? NULL : build("scan", 0, names[0]);
        if (levels) {
            char p[2048];
            snprintf(p, sizeof p, "%s/%s", tmp, names[1]);
            CHECK(hlod_store_open(p, NULL, &s) == HLOD_OK);
        }
        if (!s)
            continue;
        const hlod_store_header *h = hlod_store_get_header(s);
        hlod_engine_desc d = {0};
        d.deterministic = 1;
        d.fixed_v_time = 1e-3;
        d.target_ms = 1e-3; /* nothing can refine */
        d.memory_budget_bytes = 1;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        if (!e) {
            hlod_store_close(s);
            continue;
        }
        hlod_camera cam;
        look_down(&cam, h);
        hlod_frame_stats st;
        for (int f = 0; f < 10; f++)
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        uint32_t resident = 0;
        for (uint32_t i = 0; i < h->node_count; i++)
            resident += hlod_engine_node_state(e, i) == HLOD_NODE_RESIDENT;
        CHECKF(resident == h->root_count, "%s: %u nodes resident, %u roots", names[levels], resident,
               h->root_count);
        if (levels)
            CHECKF(st.nodes_drawn == 1 && st.tris_drawn == hlod_store_nodes(s)[0].tri_count,
                   "%s: the coarsest frame draws %u nodes, %llu triangles", names[levels],
                   st.nodes_drawn, (unsigned long long)st.tris_drawn);
        else
            CHECKF(st.nodes_drawn > 1 && st.nodes_drawn <= h->block_count,
                   "%s: the coarsest frame draws %u nodes", names[levels], st.nodes_drawn);
        hlod_engine_destroy(e);
        /* a generous target refines below the blocks */
        d.target_ms = 1e3;
        d.memory_budget_bytes = 1ull << 30;
        d.deterministic_load_bytes = 1u << 30;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        for (int f = 0; e && f < 30; f++)
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
        uint32_t below = 0;
        for (uint32_t k = h->block_depth + 1; k < HLOD_STATS_MAX_DEPTH; k++)
            below += st.nodes_per_depth[k];
        CHECKF(e && below > 0 && below == st.nodes_drawn, "%s: %u of %u nodes drawn below the blocks",
               names[levels], below, st.nodes_drawn);
        hlod_engine_destroy(e);
        hlod_store_close(s);
    }
}

/* Resident nodes of e among [first, end). */
static uint32_t resident_in(hlod_engine *e, uint32_t first, uint32_t end)
{
    uint32_t n = 0;
    for (uint32_t i = first; i < end; i++)
        n += hlod_engine_node_state(e, i) == HLOD_NODE_RESIDENT;
    return n;
}

/* The pinned set follows the budget (docs/store-format.md): every group
 * and hlod_0 node when they take at most half of it; else whole depths
 * from the root while they fit that half, and the hlod_0 nodes come and
 * go by priority under the budget like any other node. */
static void runtime_pins_what_fits(void)
{
    char p[2048];
    snprintf(p, sizeof p, "%s/scan.hlod", tmp);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(p, NULL, &s) == HLOD_OK);
    if (!s)
        return;
    const hlod_store_header *h = hlod_store_get_header(s);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    uint64_t top_bytes = 0, depth_end_bytes[64] = {0};
    uint32_t depth_end[64] = {0};
    for (uint32_t i = 0; i < h->top_count; i++) {
        top_bytes += hlod_store_node_memory(&nodes[i]);
        depth_end[nodes[i].depth] = i + 1;
        depth_end_bytes[nodes[i].depth] = top_bytes;
    }
    CHECKF(h->block_depth >= 1 && h->block_depth < 64, "block depth %u", h->block_depth);
    hlod_camera cam;
    look_down(&cam, h);
    const uint64_t budgets[3] = {2 * top_bytes, top_bytes, top_bytes + top_bytes / 2};
    for (int k = 0; k < 3 && h->block_depth >= 1 && h->block_depth < 64; k++) {
        hlod_engine_desc d = {0};
        d.deterministic = 1;
        d.fixed_v_time = 1e-3;
        d.target_ms = 1e3;
        d.memory_budget_bytes = budgets[k];
        d.deterministic_load_bytes = 1u << 30;
        /* the expected pinned prefix, from the node table */
        uint32_t pinned = h->root_count;
        for (uint32_t dd = 0; dd <= h->block_depth; dd++)
            if (depth_end_bytes[dd] <= budgets[k] / 2)
                pinned = depth_end[dd] > pinned ? depth_end[dd] : pinned;
        hlod_engine *e = NULL;
        CHECK(hlod_engine_create(s, &d, &e) == HLOD_OK);
        if (!e)
            continue;
        uint32_t at_start = resident_in(e, 0, h->node_count);
        CHECKF(at_start == pinned && resident_in(e, 0, pinned) == pinned,
               "budget %llu (top %llu): %u resident at start, %u pinned expected",
               (unsigned long long)budgets[k], (unsigned long long)top_bytes, at_start, pinned);
        CHECKF(k == 0 ? pinned == h->top_count : pinned < h->top_count,
               "budget %llu: %u pinned of %u top nodes", (unsigned long long)budgets[k], pinned,
               h->top_count);
        hlod_frame_stats st;
        uint64_t peak = 0;
        uint32_t below = 0;
        for (int f = 0; f < 40; f++) {
            CHECK(hlod_engine_frame(e, &cam, 1.0 / 30, &st) == HLOD_OK);
            peak = st.resident_bytes > peak ? st.resident_bytes : peak;
            if (resident_in(e, 0, pinned) != pinned) {
                CHECKF(0, "budget %llu: frame %d: a pinned node is not resident",
                       (unsigned long long)budgets[k], f);
                break;
            }
        }
        for (uint32_t dd = h->block_depth; dd < HLOD_STATS_MAX_DEPTH; dd++)
            below += st.nodes_per_depth[dd];
        CHECKF(peak <= budgets[k], "budget %llu: peak resident %llu", (unsigned long long)budgets[k],
               (unsigned long long)peak);
        /* room for more than the top: the frame reaches the blocks and below */
        CHECKF(below > 0, "budget %llu: %u of %u drawn nodes at or below the blocks",
               (unsigned long long)budgets[k], below, st.nodes_drawn);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
}

int main(void)
{
    const char *b = getenv("HLOD_BIN_DIR");
    snprintf(bin, sizeof bin, "%s", b ? b : "build/bin");
    snprintf(tmp, sizeof tmp, "/tmp/hlod-test-levels-%ld", (long)getpid());
    check_sh("rm -rf '%s' && mkdir -p '%s'", tmp, tmp);
    RUN(textured_city);
    RUN(parts_city);
    RUN(parts_block_aggregates);
    RUN(runtime_uses_the_root);
    RUN(runtime_pins_what_fits);
    check_sh("rm -rf '%s'", tmp);
    return check_done();
}
