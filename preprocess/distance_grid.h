/*
 * distance_grid.h - exact closest-point queries against a triangle set
 * (private to preprocess/; hlod_mesh_distance() is the public face).
 *
 * A uniform grid of cubic cells over the triangles' bounding box; each cell
 * lists the triangles whose plane crosses it within their bounding box.  An
 * occupancy pyramid over the cells lets a query skip empty space a block at
 * a time.  A query opens blocks nearest first and drops one only when it is
 * empty or farther than the best triangle found, so the answer equals a
 * brute-force loop over every triangle with hlod_dgrid_tri_dist2() (the
 * tests check this bit for bit).
 *
 * Coordinates: the grid stores triangles relative to `origin` (pass the
 * meshes' common bounding-box centre so a city tile at x = 5e6 m keeps its
 * millimetres); query points are given in that same relative frame.
 *
 * Ownership: the grid owns its arrays; hlod_dgrid_free() releases them.
 * Thread safety: a query writes the grid's visit stamps, so one grid serves
 * one thread at a time; distinct grids are independent.
 */
#ifndef HLOD_DISTANCE_GRID_H
#define HLOD_DISTANCE_GRID_H

#include "hlod/hlod.h"

typedef struct hlod_dgrid_tri {
    /* a and n first: the plane test that rejects most triangles then
     * reads one 64-byte line (the array is 64-byte aligned). */
    double a[3];
    double n[3];            /* unit normal; zero when degenerate (collinear
                               or repeated corners): then the three edges
                               stand for the triangle */
    double b[3], c[3];
    double g00, g01, g11;   /* Gram matrix of ab, ac */
    double inv_det;         /* 1 / det(Gram), or 0 for a sliver */
} hlod_dgrid_tri;

#define HLOD_DGRID_MAX_LEVELS 32

typedef struct hlod_dgrid {
    double lo[3];           /* grid corner, relative to origin */
    double h, inv_h;        /* cell edge length and its inverse */
    int n[3];               /* cells per axis, each >= 1 */
    uint32_t *cell_start;   /* n0*n1*n2 + 1 offsets into cell_tris */
    uint32_t *cell_tris;
    hlod_dgrid_tri *tris;   /* in cell order, not input order */
    float (*box)[6];        /* per triangle: its bounding box (lo xyz, hi xyz),
                               rounded outwards to floats */
    size_t tri_count;
    /* Occupancy pyramid: level l has level_n[l] blocks of 2^l cells a side
     * (level 0 is the grid); occupied[level_first[l] + block] is non-zero
     * when a cell below holds a triangle. */
    int levels;
    int level_n[HLOD_DGRID_MAX_LEVELS][3];
    size_t level_first[HLOD_DGRID_MAX_LEVELS];
    uint8_t *occupied;
    uint32_t *stamp;        /* per triangle: last query that tested it */
    uint32_t query;
    uint32_t hint;          /* previous answer: a cheap first upper bound */
} hlod_dgrid;

/* Builds g over tri_count triangles (indices into positions, 3 doubles per
 * vertex), stored relative to origin.  Indices must be valid.  Costs
 * O(tri_count) time and about 150 bytes per triangle. */
hlod_result hlod_dgrid_build(hlod_dgrid *g, const double *positions, const uint32_t *indices,
                             size_t tri_count, const double origin[3]);

/* Squared distance from p (relative to origin) to the closest point of any
 * triangle; *tri (may be NULL) receives that triangle's index in g->tris. */
double hlod_dgrid_closest2(hlod_dgrid *g, const double p[3], uint32_t *tri);

void hlod_dgrid_free(hlod_dgrid *g);

/* Squared distance from p to triangle t: barycentric projection, Ericson's
 * ClosestPtPointTriangle (Real-Time Collision Detection 5.1.5) for slivers,
 * the three edges for degenerate triangles.  t comes from a built grid. */
double hlod_dgrid_tri_dist2(const double p[3], const hlod_dgrid_tri *t);

#endif
