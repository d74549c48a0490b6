/*
 * city_levels.h - group nodes above the blocks (docs/store-format.md).
 * Private to preprocess/.
 *
 * Lakhia's hierarchy has one tree per block, so the coarsest frame draws
 * every block in view.  City levels put a tree of group nodes on top: the
 * blocks' hlod_0 nodes are grouped by position, about group_size
 * (C_levelFactor^2) neighbours to a group, each group node is the union of
 * its children simplified (with aggregation: separate parts merge or go
 * as the error allows) to target_tris triangles with one texture atlas,
 * and groups are grouped again up to one root.
 */
#ifndef HLOD_CITY_LEVELS_H
#define HLOD_CITY_LEVELS_H

#include "build.h"

/* One node the levels are built from or produce. */
typedef struct hlod_city_item {
    hlod_mesh mesh;         /* world coordinates; triangles [0, tex_tris) use
                               tex (and the mesh's UVs), the rest do not */
    size_t tex_tris;
    hlod_image tex;         /* width 0 when no triangle is textured */
    uint8_t *colors;        /* RGBA per vertex, or NULL: every vertex `color` */
    uint8_t color[4];
    double error;           /* certified, model units, >= each child's */
    size_t source_tris;     /* original triangles below it */
    int solid;              /* a closed, outward-wound surface */
    uint32_t node;          /* its index in the caller's node list */
} hlod_city_item;

void hlod_city_item_free(hlod_city_item *it);

/* The group tree, from the blocks' input boxes alone.  Level 0 are the
 * blocks (count[0] of them), level l >= 1 has count[l] groups; group g of
 * level l has the level l-1 items kids[l][first[l][g] .. first[l][g+1]),
 * in that order.  count[levels] is 1 (the root) when levels > 0. */
typedef struct hlod_city_plan {
    uint32_t levels;
    size_t *count;          /* levels + 1 */
    size_t **first;         /* [l][count[l] + 1], l >= 1 */
    uint32_t **kids;        /* [l][count[l - 1]], l >= 1 */
} hlod_city_plan;

/* Groups n blocks with boxes lo[b]..hi[b] into groups of at most
 * group_size (>= 2) per level, up to one root (no levels for n = 1).
 * HLOD_ERR_INVALID_ARG, HLOD_ERR_NOMEM.  Deterministic. */
hlod_result hlod_city_plan_make(const double (*lo)[3], const double (*hi)[3], size_t n,
                                size_t group_size, hlod_city_plan *p);
void hlod_city_plan_free(hlod_city_plan *p);
/* A checksum of the plan's shape (counts and children), for parts that
 * must share one plan. */
uint64_t hlod_city_plan_hash(const hlod_city_plan *p);

/* Called from the calling thread once per group node, level by level and
 * in plan order within a level, children before parents: stores g (its
 * mesh, texture, colours, error), group `index` of `level`, as a node
 * whose children are the items kids[0..n) (their `node` fields), and sets
 * g->node. */
typedef hlod_result (*hlod_city_emit_fn)(void *user, uint32_t level, uint32_t index,
                                         hlod_city_item *g, const hlod_city_item *const *kids,
                                         size_t n);

typedef struct hlod_city_levels_desc {
    size_t target_tris;     /* triangles of a group node (C_desiredTri) */
    size_t threads;         /* >= 1: groups of a level build in parallel */
    const hlod_logger *logger;
    hlod_city_emit_fn emit;
    void *user;
} hlod_city_levels_desc;

/* Builds the groups of levels from+1 .. to of plan p over items[0 ..
 * count[from]) (level `from`'s items, each with its `node` set; NULL for
 * an item built elsewhere), emitting each group whose children are all
 * here (so a shard owning whole subtrees builds exactly them).  The items
 * are left as they are.  When tops is not NULL and to > from, *tops
 * receives level `to`'s items (count[to], zeroed where not built; the
 * caller frees each and the array).  Deterministic: the same items give
 * the same groups on any number of threads.  HLOD_ERR_INVALID_ARG,
 * HLOD_ERR_NOMEM, or a simplifier's or emit's error. */
hlod_result hlod_city_levels(const hlod_city_plan *p, uint32_t from, hlod_city_item *const *items,
                             uint32_t to, const hlod_city_levels_desc *d, hlod_city_item **tops);

#endif
