/*
 * city_levels.h - group nodes above the blocks (README, "City levels").
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

/* Called from the calling thread once per group node, children before
 * parents: stores g (its mesh, texture, colours, error) as a node whose
 * children are the items kids[0..n) (their `node` fields), and sets
 * g->node. */
typedef hlod_result (*hlod_city_emit_fn)(void *user, hlod_city_item *g,
                                         const hlod_city_item *const *kids, size_t n);

typedef struct hlod_city_levels_desc {
    size_t target_tris;     /* triangles of a group node (C_desiredTri) */
    size_t group_size;      /* children per group at most, >= 2 */
    size_t threads;         /* >= 1: groups of a level build in parallel */
    const hlod_logger *logger;
    hlod_city_emit_fn emit;
    void *user;
} hlod_city_levels_desc;

/* Builds the levels over items[0..n) (n >= 2; the blocks' hlod_0 nodes,
 * each with its `node` set), emitting every group; *levels receives the
 * number of group levels.  The items are left as they are.  Deterministic:
 * the same items give the same groups on any number of threads.
 * HLOD_ERR_NOMEM, or a simplifier's or emit's error. */
hlod_result hlod_city_levels(hlod_city_item *items, size_t n, const hlod_city_levels_desc *d,
                             uint32_t *levels);

#endif
