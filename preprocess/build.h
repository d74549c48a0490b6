/*
 * build.h - the hierarchy builders' common shape (private to preprocess/).
 *
 * A builder turns one block (an input object or a grid cell) into a tree of
 * nodes: node 0 is the block's hlod_0 (its coarsest version), children
 * refine their parent over a part of it, leaves hold the original
 * triangles.  hlod-build runs builders on many blocks in parallel and
 * writes their nodes into one store (store_write.h).
 *
 * Ownership: an hlod_btree owns its nodes and their meshes and textures;
 * hlod_btree_free() releases everything.  Builders are reentrant: distinct
 * blocks may be built on distinct threads at once.
 */
#ifndef HLOD_BUILD_H
#define HLOD_BUILD_H

#include "hlod/image.h"
#include "hlod/mesh.h"

#include <stdatomic.h>
#include <stdint.h>
#include <time.h>

#define HLOD_BNODE_NONE UINT32_MAX

typedef struct hlod_bnode {
    hlod_mesh mesh;        /* world coordinates (double); no objects; UVs when
                              textured, addressing `tex` */
    hlod_image tex;        /* this node's texture (width 0 when none): the
                              block texture's texels the node's UVs cover,
                              repacked (hlod_node_texture), downsampled by
                              the node's simplification factor (sqrt of
                              the triangle ratio per side) */
    uint32_t parent;       /* index in the tree, HLOD_BNODE_NONE for node 0 */
    uint32_t depth;        /* 0 for node 0 */
    size_t source_tris;    /* original triangles this node stands for */
    double error;          /* certified two-sided Hausdorff distance to the
                              original triangles it stands for (model units),
                              raised to at least each child's error */
} hlod_bnode;

typedef struct hlod_btree {
    hlod_bnode *nodes;     /* node 0 is the root; a parent precedes its children */
    size_t count, cap;
} hlod_btree;

void hlod_btree_free(hlod_btree *t);
/* Appends a zeroed node (parent/depth set by the caller); returns its
 * index, or HLOD_BNODE_NONE when out of memory.  Invalidates pointers
 * into t->nodes. */
uint32_t hlod_btree_add(hlod_btree *t);

/* CPU time the block builders spent in their parts, summed over threads
 * (hlod-build --json stage_cpu_seconds), in nanoseconds. */
typedef struct hlod_build_timing {
    _Atomic uint64_t simplify_ns;       /* hlod_simplify */
    _Atomic uint64_t error_ns;          /* hlod_node_error: the certified errors */
    _Atomic uint64_t node_texture_ns;   /* hlod_node_texture: the nodes' atlases */
} hlod_build_timing;

/* This thread's CPU time, ns. */
static inline uint64_t hlod_thread_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (uint64_t)ts.tv_sec * 1000000000u + (uint64_t)ts.tv_nsec;
}

/* Adds the thread's CPU time since t0 to *c (c NULL: nothing). */
static inline void hlod_timing_add(_Atomic uint64_t *c, uint64_t t0)
{
    if (c)
        atomic_fetch_add(c, hlod_thread_ns() - t0);
}

typedef struct hlod_build_params {
    size_t desired_tris;   /* C_desiredTri: triangles of hlod_0 (cutplane) */
    double level_factor;   /* C_levelFactor: pieces per split and triangle
                              ratio between levels (cutplane), >= 2 */
    size_t voxel_tris;     /* N_v: triangles per voxel at most (metis) */
    size_t leaf_tris;      /* N_l: a part under this is a leaf (metis) */
    size_t node_tris;      /* N_n: triangles of an inner node (metis) */
    int cone_split;        /* cutplane: within three levels of the leaves, a
                              piece whose normals spread over 45 degrees is
                              cut into orientation classes (docs/hlod-build.md) */
    uint64_t seed;         /* METIS seed and any other choice: fixed, so a
                              build is reproducible byte for byte */
    const hlod_logger *logger;
    hlod_build_timing *timing;  /* NULL: not timed */
} hlod_build_params;

/* Lakhia III-A.  block: one block's triangles (materials/objects ignored
 * except for the texture test), tex: its texture or NULL (untextured: no
 * UVs needed, the texture path is never touched).  A block already at or
 * under desired_tris is a single leaf node. */
hlod_result hlod_build_cutplane(const hlod_mesh *block, const hlod_image *tex,
                                const hlod_build_params *p, hlod_btree *out);

/* Okamoto 4.1: voxels of < N_v triangles, METIS bisection of the voxel
 * graph until parts have < N_l triangles, inner nodes = children's union
 * simplified to N_n triangles with the union's outer boundary locked. */
hlod_result hlod_build_metis(const hlod_mesh *block, const hlod_image *tex,
                             const hlod_build_params *p, hlod_btree *out);

/* The texture of a node: the node's own atlas, made of the texel
 * rectangles its UV charts (triangles connected through shared vertices)
 * cover in tex, each with a gutter, packed together -- or the crop of tex
 * to m's UV box when that is no larger -- then shrunk by sqrt(factor) per
 * side (factor = source triangles / node triangles, >= 1), at least 4x4
 * pixels.  Rewrites m->uvs into the result (v = 0 stays the bottom row);
 * a vertex no triangle uses gets UV (0, 0).  Wrapping UVs (outside
 * [0, 1], a repeating texture) are cropped per axis when they span less
 * than one period (shifted by whole periods, the crop read across the
 * image's edge); an axis spanning a period or more keeps the whole image
 * and its UVs.  Leaves out->width 0 and
 * touches nothing when tex is NULL or m has no UVs.  Deterministic (a
 * function of m, tex and factor), reentrant; out is malloc'ed, free with
 * hlod_image_free().  Cost: O(vertices + triangles + output texels), plus
 * a resize when factor > 1.  Design: build_common.c. */
hlod_result hlod_node_texture(const hlod_image *tex, hlod_mesh *m, double factor, hlod_image *out);

/* Certified error of a node against the original triangles it stands for
 * (hlod_mesh_hausdorff_bound, within 25% plus 1e-3 of the original's
 * size), in model units. */
hlod_result hlod_node_error(const hlod_mesh *node, const hlod_mesh *original, double *error);

/* Is m a closed, consistently outward-wound surface, so that a renderer
 * may cull its back faces?  Positions are welded exactly (UV seams split
 * vertices); then no directed edge may occur twice (an inconsistent
 * winding or a non-manifold edge), at least 99% of directed edges must
 * have their reverse (a few open edges, such as a building's bottom on
 * the ground, are allowed) and the enclosed volume must be positive and
 * at least 5% of the bounding box's (outward, and a solid rather than a
 * folded sheet).  O(n log n) in the triangles. */
int hlod_mesh_is_solid(const hlod_mesh *m);

#endif
