/*
 * cluster.h - vertex clustering (Rossignac-Borrel), the simplifier's last
 * resort for meshes of many separate parts (simplify.c).  Private to
 * preprocess/.
 */
#ifndef HLOD_CLUSTER_H
#define HLOD_CLUSTER_H

#include "hlod/mesh.h"

/* Welds every vertex of in that falls into one cube of a grid of side
 * `cell` (anchored at in's bounding-box minimum) into one of them (the one
 * nearest, in the quadric sense, the planes of the faces around them), and
 * drops the triangles that become degenerate and the exact
 * duplicates (same three vertices in the same cyclic order; a pair of
 * opposite faces, a thin wall's two sides, stays).  Separate parts closer
 * than a cell merge into one surface; every point moves by at most the
 * cell's diagonal.  Untextured meshes only (UVs are not carried: out has
 * none); normals are dropped; materials and object ranges are kept.  A
 * vertex with a non-zero lock (lock may be NULL) is never welded: it keeps
 * its position, and triangles to it stay (a locked seam stays crack-free).
 * HLOD_ERR_INVALID_ARG for a cell that is not positive and finite,
 * HLOD_ERR_NOMEM.  O(n log n). */
hlod_result hlod_cluster_vertices(const hlod_mesh *in, double cell, const uint8_t *lock,
                                  hlod_mesh *out);

#endif
