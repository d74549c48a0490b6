/*
 * simplify.h - quadric error metric (Garland-Heckbert) mesh simplification.
 *
 * Edge collapses ordered by quadric error (in passes that each price every
 * edge, sort the prices and collapse in that order), in double precision on
 * positions re-centred on the mesh's own bounding-box centre and scaled to
 * unit size, so a mesh at x = 5e6 m, or in millimetres, simplifies like the
 * same mesh at the origin in metres.
 * Vertices are placed at the quadric optimum when the system is well
 * conditioned (a scale-invariant test), else at the best point on the edge,
 * else at an endpoint; collapses that flip or fold a face, create slivers,
 * or move a vertex far outside its neighbourhood are rejected, and so are
 * those that would stretch a face's texture past 4:1 or flip it (relaxed
 * last, when nothing else is left, unless strict_texture).  Texture
 * coordinates enter the error (Hoppe-style attribute quadrics) and UV seams
 * stay closed: the copies of a seam vertex move and collapse together.
 * Open borders and seams keep their shape through boundary quadrics; locked
 * vertices never move and are never removed.  Input vertices that share a
 * position and a UV are one vertex to the simplifier whatever their normals;
 * output normals are recomputed per vertex from the faces around it.
 * Collapses keep the mesh manifold (link condition), so a closed part stops
 * at a tetrahedron and the result may hold more than target_tris triangles
 * when nothing valid is left to collapse.  Where whole parts had to go to
 * meet a count target and the mesh has no UVs and no locks, vertex
 * clustering of the input is tried as well (docs/hlod-simplify.md) and
 * kept when clearly nearer the input; stats->clustered says so.
 *
 * Cost: O(n) per pass, about 10 passes; ~400 bytes per input vertex.
 * Thread safety: reentrant; distinct calls may run on distinct threads.
 */
#ifndef HLOD_SIMPLIFY_H
#define HLOD_SIMPLIFY_H

#include "hlod/mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hlod_simplify_desc {
    /* Stop when at most target_tris triangles remain (0: no count target). */
    size_t target_tris;
    /* Stop before a collapse whose estimated error (quadric RMS distance,
     * model units) would exceed target_error (<= 0: no error target). */
    double target_error;
    /* Non-zero: vertices on open borders never move. */
    int lock_border;
    /* Per-vertex locks (vertex_count bytes, non-zero = locked) or NULL.  A
     * locked vertex keeps its exact position and attributes. */
    const uint8_t *vertex_lock;
    /* Weight of UV error against geometric error; 0 selects the default
     * (1.0: a UV shift of 0.01 costs like moving 1% of the mesh size). */
    double uv_weight;
    /* Non-zero: a face's texture never stretches past the bound (4:1,
     * sigma_max / sigma_min of its UV-to-surface map) nor flips, even
     * where the target then cannot be met (HLOD nodes: a few more
     * triangles rather than smeared texture).  Zero (default): that
     * constraint is the last to relax when the target needs it. */
    int strict_texture;
    /* Non-zero: after simplifying, bound the two-sided Hausdorff distance
     * to the input (hlod_mesh_hausdorff_bound, within 1%) and report the
     * upper bound in stats->error. */
    int measure_error;
    hlod_progress_fn progress;  /* may be NULL */
    void *progress_user;
    const hlod_logger *logger;  /* may be NULL */
} hlod_simplify_desc;

typedef struct hlod_simplify_stats {
    size_t tris_in, tris_out;
    size_t vertices_in, vertices_out;
    size_t collapses;
    /* Largest quadric error estimate of any collapse made (model units). */
    double error_estimate;
    /* Reported error (model units): a certified upper bound of the
     * two-sided Hausdorff distance when desc->measure_error, else
     * error_estimate. */
    double error;
    double seconds;             /* time spent simplifying (not measuring) */
    /* Why the collapses stopped: "target" (target_tris reached, or no
     * count target and nothing left to do within target_error),
     * "error_limit" (the next collapse would exceed target_error),
     * "locked" (no valid collapse is left and vertices the caller locked,
     * border locks or non-manifold vertices remain), "no_valid_collapse"
     * (none is left: every remaining edge would fold a face or break the
     * surface's topology).  A static string. */
    const char *stop_reason;
    size_t locked_vertices;     /* live vertices under a lock that never relaxes */
    /* Non-zero: the result came from the last resort for meshes of many
     * parts (vertex clustering, then collapses): it may hold non-manifold
     * edges where parts were welded. */
    int clustered;
} hlod_simplify_stats;

/* Simplifies in into *out (freed first; may not alias in).  Materials,
 * objects, normals and UVs are carried over; vertex and triangle order
 * follow the input.  stats may be NULL.  HLOD_ERR_INVALID_ARG for 2^30
 * triangles or 2^32 - 1 vertices and more. */
hlod_result hlod_simplify(const hlod_mesh *in, const hlod_simplify_desc *desc,
                          hlod_mesh *out, hlod_simplify_stats *stats);

#ifdef __cplusplus
}
#endif
#endif
