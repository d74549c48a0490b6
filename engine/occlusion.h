/*
 * occlusion.h - a depth pyramid for occlusion culling (README, "Occlusion
 * culling").  Render thread only.
 *
 * Built from a frame's depth buffer (window depth scaled to 32-bit
 * integers, as glReadPixels(GL_DEPTH_COMPONENT, GL_UNSIGNED_INT) gives
 * it): level 0 holds the farthest depth of each TILE x TILE block of
 * pixels, each further level the farthest of 2 x 2 texels below.  A box
 * whose nearest point lies behind the farthest depth over every pixel its
 * projection may touch is hidden: each of its fragments would fail the
 * depth test.  The test is conservative (a hidden box may pass), never
 * the other way.
 */
#ifndef HLOD_ENGINE_OCCLUSION_H
#define HLOD_ENGINE_OCCLUSION_H

#include "alloc.h"

#include <stdint.h>

#define HLOD_OCC_TILE 8
#define HLOD_OCC_LEVELS 16

typedef struct hlod_occlusion {
    uint32_t *depth;                /* the read-back buffer, width * height */
    size_t depth_cap;
    uint32_t *level[HLOD_OCC_LEVELS];
    uint32_t lw[HLOD_OCC_LEVELS], lh[HLOD_OCC_LEVELS];
    uint32_t levels;
    uint32_t width, height;         /* of the depth buffer */
    size_t cap;                     /* texels allocated for all levels */
    uint32_t *texels;
} hlod_occlusion;

/* The buffer to read width x height depth values into (bottom row
 * first), grown as needed; NULL when out of memory. */
uint32_t *hlod_occlusion_buffer(hlod_occlusion *o, const hlod_allocator *a, uint32_t width,
                                uint32_t height);

/* Builds the pyramid from the buffer.  0 when out of memory. */
int hlod_occlusion_build(hlod_occlusion *o, const hlod_allocator *a);

/* 1 when a box whose projection covers rect (pixels, x0 y0 x1 y1 with y
 * up, clipped to the viewport) with nearest window depth zmin in [0, 1]
 * may show; 0 when it is hidden. */
int hlod_occlusion_visible(const hlod_occlusion *o, const double rect[4], double zmin);

void hlod_occlusion_free(hlod_occlusion *o, const hlod_allocator *a);

#endif
