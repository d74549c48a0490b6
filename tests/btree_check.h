/*
 * btree_check.h - the documented bound on a built node's error, shared by
 * the builders' tests (test_cutplane, test_metis).
 *
 * docs/hlod-build.md: a node's error is a certified upper bound of the
 * two-sided Hausdorff distance to the original triangles it stands for,
 * within 25% plus 1e-3 of the node's size, raised to at least each child's.
 * The true distance H lies between a tight certified bound's ends, so the
 * error lies in [lower, max(1.25 x upper + 1e-3 x size, largest child
 * error)]: an error of 1e9, or 0 over a node that moved its surface, fails.
 */
#ifndef HLOD_BTREE_CHECK_H
#define HLOD_BTREE_CHECK_H

#include "build.h"
#include "hlod/distance.h"
#include "hlod/mesh.h"

#include <math.h>

/* The largest error node k may report over the original triangles under
 * it (orig): 1.25 x H + 1e-3 x size, with H bounded from above by a tight
 * certified bound (1%, and 1e-4 of the size), or the largest child error
 * if that is more.  *lower gets that bound's lower end (H >= *lower: the
 * node's error may not be under it). */
static inline double node_error_cap(const hlod_btree *t, uint32_t k, const hlod_mesh *orig,
                                    double *lower)
{
    double size = hlod_mesh_bbox_diag(orig), lo = 0, hi = INFINITY;
    *lower = 0;
    if (hlod_mesh_hausdorff_bound(&t->nodes[k].mesh, orig, 0.01, 1e-4 * size, &lo, &hi) != HLOD_OK)
        return -1; /* fails the caller's check */
    *lower = lo * (1 - 1e-9) - 1e-12 * size; /* rounding: a leaf's 0 against 1e-17 */
    double cap = 1.25 * hi + 1e-3 * size;
    for (size_t c = 0; c < t->count; c++)
        if (t->nodes[c].parent == k && t->nodes[c].error > cap)
            cap = t->nodes[c].error;
    return cap;
}

#endif
