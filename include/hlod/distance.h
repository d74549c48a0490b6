/*
 * distance.h - sampled surface distances between two meshes.
 *
 * hlod_mesh_distance() measures the two-sided Hausdorff distance the way
 * Metro/MeshLab do: points sampled on each surface (every vertex, plus
 * area-proportional stratified samples on every triangle, plus edge
 * midpoints), each sent to the closest point of the other surface through a
 * uniform grid of triangles.  It is our own measuring stick: benchmarks and
 * tests judge every simplifier with it, and the HLOD builder records a
 * node's error with it.
 *
 * Cost: O((n_a + n_b + samples) * k) with k the triangles per grid query.
 * Thread safety: reentrant.
 */
#ifndef HLOD_DISTANCE_H
#define HLOD_DISTANCE_H

#include "hlod/mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hlod_distance {
    double max_ab, mean_ab;   /* from points on a to the surface of b */
    double max_ba, mean_ba;   /* from points on b to the surface of a */
    double max, mean;         /* max of both; area-weighted mean of both */
    size_t samples;           /* points measured in total */
} hlod_distance;

/* samples_per_mesh: area-proportional samples on each mesh in addition to
 * its vertices and edge midpoints (0 selects 200000).  seed makes the
 * sampling reproducible. */
hlod_result hlod_mesh_distance(const hlod_mesh *a, const hlod_mesh *b,
                               size_t samples_per_mesh, uint64_t seed,
                               hlod_distance *out);

/* A certified two-sided Hausdorff distance: *lower <= H(a, b) <= *upper,
 * with *upper <= *lower * (1 + rel_tol) + max(abs_tol, 1e-9 * diagonal)
 * unless a region needed more than 30 levels of splitting, or more than
 * 5e4 + 512 (n_a + n_b) splits per side (surfaces apart by about the
 * tolerance but not coplanar: folds, layers or noise that fine): then
 * *upper is the bound of the deepest refinement within that budget, still
 * certified but looser.  Branch and bound over each surface: the
 * distance is 1-Lipschitz, so a triangle whose corners are all at most f
 * from the other surface lies within f + (longest edge)/sqrt(3) of it;
 * triangles that cannot beat the best value found are dropped, the others
 * split in four.  Where the surfaces coincide, two coplanar neighbours of
 * the other surface bound a piece that straddles their shared edge (through
 * their union when it is convex, else through a convex triangle of it
 * along that edge), so a flat or creased region resolves to the floor
 * cheaply.  Unlike sampling, it cannot miss a peak: the simplifier
 * reports this upper bound.  Cost: a few closest-point queries per vertex
 * plus the refinement near the worst regions. */
hlod_result hlod_mesh_hausdorff_bound(const hlod_mesh *a, const hlod_mesh *b, double rel_tol,
                                      double abs_tol, double *lower, double *upper);

/* As hlod_mesh_hausdorff_bound, for a caller that only needs to know
 * whether the distance exceeds stop_above: as soon as a point is found
 * farther than stop_above from the other surface, it returns with *lower
 * that point's distance (> stop_above) and *upper INFINITY.  Otherwise
 * *lower and *upper are exactly hlod_mesh_hausdorff_bound's. */
hlod_result hlod_mesh_hausdorff_bound_above(const hlod_mesh *a, const hlod_mesh *b, double rel_tol,
                                            double abs_tol, double stop_above, double *lower,
                                            double *upper);

#ifdef __cplusplus
}
#endif
#endif
