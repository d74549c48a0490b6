/*
 * grid_quads.h - the triangles of a regular grid, shared by the tests'
 * synthetic meshes (store_fixture.h, loader_store.h, test_store.c).
 */
#ifndef HLOD_TESTS_GRID_QUADS_H
#define HLOD_TESTS_GRID_QUADS_H

#include <stdint.h>
#include <string.h>

/* Writes the 2 * nx * ny triangles (6 * nx * ny indices) of an nx x ny
 * grid of quads whose (nx + 1) x (ny + 1) vertices are numbered row by row,
 * x fastest; every quad is split along the same diagonal. */
static inline void grid_quads(uint32_t *idx, uint32_t nx, uint32_t ny)
{
    uint32_t n = 0;
    for (uint32_t j = 0; j < ny; j++)
        for (uint32_t i = 0; i < nx; i++) {
            uint32_t a = j * (nx + 1) + i, b = a + 1, c = a + nx + 1, d = c + 1;
            uint32_t q[6] = {a, b, d, a, d, c};
            memcpy(idx + n, q, sizeof q);
            n += 6;
        }
}

#endif
