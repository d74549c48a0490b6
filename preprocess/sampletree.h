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
 *
 * Out of core (section 5): a first pass over the input counts triangles
 * per cell of a 64^3 grid over the root cube; the cells become buckets,
 * each an octree cell of at most the triangles memory allows (or a grid
 * cell); a second pass writes every triangle to its bucket (buffered,
 * spilled to a file beside the output when the buffers outgrow memory);
 * then each bucket's subtree is built and written on its own, keeping
 * only its root's triangles, and the levels above the buckets are built
 * last from those.  Memory: the largest bucket, the buffers and the upper
 * levels, not the scene.
 */
#ifndef HLOD_SAMPLETREE_H
#define HLOD_SAMPLETREE_H

#include "hlod/build_store.h"
#include "hlod/mesh.h"
#include "hlod/store_write.h"

#include <stddef.h>
#include <stdint.h>

/* One input block (tests): its triangles, its texture (a path read once
 * per distinct path; NULL: untextured, or a mesh without UVs) and the
 * colour of its untextured triangles. */
typedef struct hlod_st_block {
    const hlod_mesh *mesh;
    const char *texture;
    uint8_t rgba[4];
} hlod_st_block;

typedef struct hlod_st_params {
    double c;               /* the sample constant (Theorem 1), > 0 */
    size_t leaf_tris;       /* a cell of more triangles splits, >= 1 */
    uint64_t seed;          /* the draws' seed: the same seed, the same store */
    size_t memory_bytes;    /* what the build may hold (buckets, buffers); 0: no limit */
    const hlod_logger *lg;
    int cubes;              /* Chamberlain's colour cubes instead: no draws, each
                               triangle where it sits, every node's six faces */
} hlod_st_params;

typedef struct hlod_st_report {
    size_t nodes, levels;
    size_t tris;            /* triangles stored (= the input's) */
    size_t tris_inner;      /* ... of them in inner nodes (moved up by the draws) */
    size_t tris_leaf;       /* ... of them in leaves */
    size_t buckets;         /* subtrees built one at a time */
    size_t bucket_tris_max; /* triangles of the largest */
    uint64_t spill_bytes;   /* written to the spill file (0: all in memory) */
    hlod_store_texture_stats tex;   /* how the writer stored the textures */
} hlod_st_report;

/* Builds the tree over blocks b[0..nb) (held in memory), adds every
 * node's payload to w and finishes w (freed whatever the result; on
 * failure nothing appears at its path).  Deterministic.  HLOD_ERR_EMPTY
 * without triangles, HLOD_ERR_NOMEM, the writer's errors; a texture that
 * cannot be read is logged and its triangles built untextured. */
hlod_result hlod_build_sampletree(const hlod_st_block *b, size_t nb, const hlod_st_params *p,
                                  hlod_store_writer *w, hlod_st_report *rep);

/* The first pass over inputs[0..n) (hlod-build's inputs): the box of
 * every triangle and the counts the buckets are planned from. */
typedef struct hlod_st_scan hlod_st_scan;
hlod_result hlod_st_scan_inputs(const char *const *inputs, size_t n, const char *scratch,
                                const hlod_logger *lg, hlod_st_scan **out);
void hlod_st_scan_box(const hlod_st_scan *s, double lo[3], double hi[3]);
size_t hlod_st_scan_tris(const hlod_st_scan *s);
void hlod_st_scan_free(hlod_st_scan *s);

/* The second pass and the build, out of core: the triangles of the inputs
 * scanned by s into buckets (a spill file at spill_path when they outgrow
 * p->memory_bytes), each bucket's subtree, the levels above; finishes w as
 * hlod_build_sampletree does.  The inputs must be what s scanned (a
 * changed input is an error). */
hlod_result hlod_build_sampletree_inputs(const hlod_st_scan *s, const char *const *inputs,
                                         size_t n, const char *scratch, const char *spill_path,
                                         const hlod_st_params *p, hlod_store_writer *w,
                                         hlod_st_report *rep);

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
