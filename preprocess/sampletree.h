/*
 * sampletree.h - Klein's randomized sample tree (Klein et al., "The
 * Randomized Sample Tree", sections 4-5; docs/sampletree.md) built into an
 * HLOD store that refines additively.  Private to preprocess/.
 *
 * An octree over every input triangle: a triangle sits in the deepest
 * cell whose bounding sphere holds it; a cell of more than leaf_tris
 * triangles splits.  Then bottom-up, each inner node u draws
 * m_u = q_u ln q_u + c q_u times, with probability proportional to area,
 * from the triangles its own list and its children's lists hold (section
 * 5.2), q_u = ceil(A(P(u)) / e_u^2) (e_u its cell's edge, A(P(u)) the
 * area of every triangle in its subtree); the distinct triangles drawn
 * move up into u.  Every input triangle is stored exactly once.  Each
 * node's representative colour is the per-channel area-weighted median
 * of its subtree's triangle colours (section 4.4; a textured triangle's
 * colour is its texture's at the triangle's UV centroid).
 */
#ifndef HLOD_SAMPLETREE_H
#define HLOD_SAMPLETREE_H

#include "hlod/mesh.h"
#include "hlod/store_write.h"

#include <stddef.h>
#include <stdint.h>

/* One input block: its triangles, its texture (a path read once per
 * distinct path; NULL: untextured, or a mesh without UVs) and the colour
 * of its untextured triangles. */
typedef struct hlod_st_block {
    const hlod_mesh *mesh;
    const char *texture;
    uint8_t rgba[4];
} hlod_st_block;

typedef struct hlod_st_params {
    double c;               /* the sample constant (Theorem 1), > 0 */
    size_t leaf_tris;       /* a cell of more triangles splits, >= 1 */
    uint64_t seed;          /* the draws' seed: the same seed, the same store */
    const hlod_logger *lg;
} hlod_st_params;

typedef struct hlod_st_report {
    size_t nodes, levels;
    size_t tris;            /* triangles stored (= the input's) */
    size_t tris_inner;      /* ... of them in inner nodes (moved up by the draws) */
    size_t tris_leaf;       /* ... of them in leaves */
} hlod_st_report;

/* Builds the tree over blocks b[0..nb), adds every node's payload to w
 * and finishes w (which is freed whatever the result; on failure nothing
 * appears at its path).  Deterministic: a function of the blocks, the
 * textures and p.  HLOD_ERR_EMPTY without triangles, HLOD_ERR_NOMEM,
 * the writer's errors; a texture that cannot be read is logged and its
 * block built untextured. */
hlod_result hlod_build_sampletree(const hlod_st_block *b, size_t nb, const hlod_st_params *p,
                                  hlod_store_writer *w, hlod_st_report *rep);

/* The sample size of Theorem 1: m = q ln q + c q for q = ceil(area /
 * face), at least 1; face > 0. */
size_t hlod_st_sample_size(double area, double face, double c);

/* Draws m indices in [0, n) with replacement, index j with probability
 * w[j] / sum(w), into out[0..m) (deterministic for a given *state,
 * which it advances).  cum: n doubles of scratch.  Weights >= 0 with a
 * positive sum. */
void hlod_st_draw(const double *w, size_t n, size_t m, uint64_t *state, double *cum,
                  uint32_t *out);

#endif
