/*
 * occlusion.h - a depth pyramid for occlusion culling (docs/runtime.md).  Render thread only.
 *
 * Built from a frame's depth buffer (window depth scaled to integers:
 * 32-bit ones as glReadPixels(GL_DEPTH_COMPONENT, GL_UNSIGNED_INT) gives
 * them, or a context's own buffer read in place, e.g. 24 bits of 32): level 0 holds the farthest depth of each TILE x TILE block of
 * pixels, each further level the farthest of 2 x 2 texels below.  A box
 * whose nearest point lies behind the farthest depth over every pixel its
 * projection may touch is hidden: each of its fragments would fail the
 * depth test.  The test is conservative (a hidden box may pass), never
 * the other way.
 *
 * It also keeps, per node, the frames the test last found it visible and
 * hidden: the next frame's selection (hidden nodes are not charged or
 * refined) and drawing order (last frame's visible nodes draw first, as
 * occluders) read them through hlod_occlusion_seen and
 * hlod_occlusion_hidden.  Stamps are frame numbers from 1; 0 is never.
 */
#ifndef HLOD_ENGINE_OCCLUSION_H
#define HLOD_ENGINE_OCCLUSION_H

#include "alloc.h"

#include <stdint.h>

#define HLOD_OCC_TILE 8
#define HLOD_OCC_LEVELS 16

/* What the test last found of one node. */
typedef struct hlod_occ_stamp {
    uint32_t seen;                  /* frame the test last found it visible */
    uint32_t hidden;                /* frame the test last found it hidden */
} hlod_occ_stamp;

typedef struct hlod_occlusion {
    hlod_occ_stamp *stamp;          /* per node (hlod_occlusion_init) */
    uint32_t node_count;
    uint32_t *depth;                /* the read-back buffer, width * height */
    size_t depth_cap;
    uint32_t *level[HLOD_OCC_LEVELS];
    uint32_t lw[HLOD_OCC_LEVELS], lh[HLOD_OCC_LEVELS];
    uint32_t levels;
    uint32_t width, height;         /* of the depth buffer */
    size_t cap;                     /* texels allocated for all levels */
    uint32_t *texels;
    uint32_t *band;                 /* scratch: one row, the fold of a band of TILE rows */
    const uint32_t *src;            /* the values the pyramid is built from */
    uint32_t stride, mask;          /* their row stride and depth bits */
    size_t band_cap;
} hlod_occlusion;

/* Makes room for the stamps of node_count nodes, all "never".  0 when
 * out of memory. */
int hlod_occlusion_init(hlod_occlusion *o, const hlod_allocator *a, uint32_t node_count);

/* Records the test's verdict on node at frame. */
static inline void hlod_occlusion_mark(hlod_occlusion *o, uint32_t node, int visible,
                                       uint32_t frame)
{
    if (visible)
        o->stamp[node].seen = frame;
    else
        o->stamp[node].hidden = frame;
}

/* The frame the test last found node visible; hidden (0: never). */
static inline uint32_t hlod_occlusion_seen(const hlod_occlusion *o, uint32_t node)
{
    return o->stamp[node].seen;
}

static inline uint32_t hlod_occlusion_hidden(const hlod_occlusion *o, uint32_t node)
{
    return o->stamp[node].hidden;
}

/* The buffer to read width x height depth values into (bottom row
 * first), grown as needed; NULL when out of memory. */
uint32_t *hlod_occlusion_buffer(hlod_occlusion *o, const hlod_allocator *a, uint32_t width,
                                uint32_t height);

/* Builds the pyramid from the buffer.  0 when out of memory. */
int hlod_occlusion_build(hlod_occlusion *o, const hlod_allocator *a);

/* Builds it from someone else's depth values (a context's own depth
 * buffer, read in place): width x height values, bottom row first, rows
 * stride values apart, the depth in the bits of mask (window depth 1 is
 * all of mask).  0 when out of memory. */
int hlod_occlusion_build_from(hlod_occlusion *o, const hlod_allocator *a, const uint32_t *depth,
                              uint32_t width, uint32_t height, uint32_t stride, uint32_t mask);

/* 1 when a box whose projection covers rect (pixels, x0 y0 x1 y1 with y
 * up, clipped to the viewport) with nearest window depth zmin in [0, 1]
 * may show; 0 when it is hidden. */
int hlod_occlusion_visible(const hlod_occlusion *o, const double rect[4], double zmin);

void hlod_occlusion_free(hlod_occlusion *o, const hlod_allocator *a);

#endif
