/*
 * rzb.h - Wand's randomized z-buffer (Wand, Fischer, Peter, Meyer auf der
 * Heide, Strasser, "The Randomized z-Buffer Algorithm", SIGGRAPH 2001;
 * docs/rzb.md): the policy rzb draws a store's leaves in core as random
 * surface points, chosen with probability proportional to area, into the
 * frame's depth buffer, so that its time grows with the logarithm of the
 * scene, not with its triangles.
 *
 * Built once from every leaf's payload (hlod_rzb_add, hlod_rzb_finish):
 * the triangles in area classes (each within a factor RZB_CLASS_FACTOR),
 * one loose octree per class whose nodes own a range of one prefix-sum
 * array of areas in depth-first order (section 5.3).  Each frame
 * (hlod_rzb_frame) selects the boxes in the frustum whose depth range is
 * narrow, (z_max / z_min)^2 <= eps, and for each either draws samples,
 * A f^2 / z_min^2 ln v / d^2 of them (section 4.1; f the focal length in
 * pixels, v the viewport's pixels, d the splat size), or, where one of its
 * triangles may project over d^2 / ln v pixels, draws its faces with the
 * rasteriser (section 7.1), so the method is never much slower than the
 * rasteriser: in depth-first order a box's faces are one range of its
 * class's buffer, one draw.  Render thread only.
 */
#ifndef HLOD_ENGINE_RZB_H
#define HLOD_ENGINE_RZB_H

#include "gl_render.h"
#include "alloc.h"
#include "hlod/store.h"
#include "selection.h"

#include <stddef.h>
#include <stdint.h>

typedef struct hlod_rzb hlod_rzb;

/* An empty structure; NULL on allocation failure. */
hlod_rzb *hlod_rzb_create(const hlod_allocator *a);
void hlod_rzb_destroy(hlod_rzb *z);

/* Adds the faces of leaf `node` (its store record n, its payload p, read
 * with level-0 texels): corners in world doubles, colours from the
 * payload's vertex colours, else its texture at the corner (nearest
 * texel), else the renderer's grey.  Faces without area draw nothing and
 * are left out.  HLOD_ERR_NOMEM on allocation failure. */
hlod_result hlod_rzb_add(hlod_rzb *z, const hlod_store_node *n, uint32_t node,
                         const hlod_store_payload *p);

/* Builds the classes, octrees and prefix sums; no add after it. */
hlod_result hlod_rzb_finish(hlod_rzb *z);

/* Uploads each class's faces as one buffer for the ranges drawn by the
 * rasteriser (corners lit with the face normal, the corners' colours:
 * textures are not drawn); hlod_rzb_release gives them back (before the
 * renderer goes).  HLOD_ERR_NOMEM when memory or GL memory runs out. */
hlod_result hlod_rzb_upload(hlod_rzb *z, hlod_renderer *r);
void hlod_rzb_release(hlod_rzb *z, hlod_renderer *r);

/* Triangles held (after hlod_rzb_finish), and area classes. */
size_t hlod_rzb_tri_count(const hlod_rzb *z);
uint32_t hlod_rzb_class_count(const hlod_rzb *z);

/* A range of one class's faces, drawn by the rasteriser. */
typedef struct hlod_rzb_range {
    uint32_t cls, first, count;
    uint64_t copy;  /* the copy (hlod_rzb_set_copies): column << 32 | row */
    double off[3];  /* and its offset from the scene */
} hlod_rzb_range;

/* One frame's output, kept between frames (its arrays grow). */
typedef struct hlod_rzb_out {
    hlod_gpu_splat *splats;    /* camera-relative points, lit */
    size_t splat_count, splat_cap;
    hlod_rzb_range *ranges;    /* faces to rasterise (adjacent ones merged) */
    size_t range_count, range_cap;
    uint64_t range_tris;       /* their faces */
    uint64_t samples;          /* points drawn, back faces rejected included */
    uint64_t cache_points;     /* ... of them from caches */
    uint32_t cache_fills;      /* caches made this frame */
    size_t cache_bytes;        /* the caches' points after the frame */
    /* the C splatter's frame (splat_c): colour and window depth per pixel,
     * rows bottom up, depth 1 where no point landed; splat_count then
     * counts the points kept, and splats is unused */
    uint8_t *rgba;
    float *depth;
    uint32_t w, h;
    size_t pix_cap;
    int splatted;
    uint32_t boxes_sampled, boxes_drawn; /* selected boxes, by how */
} hlod_rzb_out;

void hlod_rzb_out_free(const hlod_allocator *a, hlod_rzb_out *o);

/* Sample caches (Wand 7.2): a selected box's points are kept, snapped to
 * a grid whose cells project within d pixels at the box's nearest depth,
 * one a cell, and drawn again while the cells fit (made again when they
 * would project over d pixels, or four times finer than needed); the
 * least recently drawn are dropped past `bytes` (0: no caches, every
 * point fresh; the default). */
void hlod_rzb_set_cache(hlod_rzb *z, size_t bytes);
size_t hlod_rzb_cache_bytes(const hlod_rzb *z);

/* Instancing (Wand 7.3): the scene is drawn as 2^levels x 2^levels
 * copies of itself side by side along x and y, each offset by a whole
 * number of the scene box's x and y sides from the first (which stays
 * where it is), held once.  Each frame walks a quadtree of blocks of
 * copies: a block whose depth range is narrow (rzb_eps) and whose faces
 * project within d^2 / ln v pixels is sampled as one box, its points
 * spread over its copies uniformly (no sample caches: those are made
 * only within one copy); a single copy is walked as the scene is.
 * levels <= HLOD_RZB_MAX_COPY_LEVELS; 0 (the default): the scene once.
 * HLOD_ERR_NOMEM, HLOD_ERR_INVALID_ARG past the limit. */
#define HLOD_RZB_MAX_COPY_LEVELS 24
hlod_result hlod_rzb_set_copies(hlod_rzb *z, uint32_t levels);
uint32_t hlod_rzb_copy_levels(const hlod_rzb *z);

typedef struct hlod_rzb_params {
    double eps;      /* a box is selected when (z_max / z_min)^2 <= eps; > 1 */
    double d;        /* the points' size, pixels; >= 1 */
    uint64_t seed;   /* the frame's points (the same seed, view and
                        structure give the same points) */
    uint32_t frame;  /* stamp: the caches' recency */
    int splat_c;     /* the points are splatted here, d x d pixels each, into
                        out's colour and depth (the C splatter), else listed
                        for GL points */
    int no_raster;   /* every selected box is sampled, whatever its faces
                        project to (Wand Fig. 6: points only); a box
                        reaching the eye's plane is still rasterised */
} hlod_rzb_params;

/* Selects and samples for view v.  HLOD_ERR_NOMEM on allocation failure
 * (the output is then partial). */
hlod_result hlod_rzb_frame(hlod_rzb *z, const hlod_view *v, const hlod_rzb_params *p,
                           hlod_rzb_out *out);

/* Draws out's ranges (uploaded) and then its points, d x d pixels (as GL
 * points, or the C splatter's frame composited), for the eye at `eye`,
 * between hlod_gpu_begin and hlod_gpu_end. */
void hlod_rzb_draw(const hlod_rzb *z, hlod_renderer *r, const double eye[3],
                   const hlod_rzb_out *out, double d);

/* Test seams (tests/test_rzb.c): the index, within class c's array, of
 * the triangle a uniform u in [0, 1) picks from the range [b, e) by
 * area; n picks from it as hlod_rzb_frame makes them for one box (in
 * area order, one per stratum, from the seed); and a point of triangle t
 * of class c from two uniforms, as hlod_rzb_frame draws them (world
 * doubles). */
uint32_t hlod_rzb_pick(const hlod_rzb *z, uint32_t c, uint32_t b, uint32_t e, double u);
void hlod_rzb_picks(const hlod_rzb *z, uint32_t c, uint32_t b, uint32_t e, uint64_t seed,
                    uint32_t n, uint32_t *out);
void hlod_rzb_point(const hlod_rzb *z, uint32_t c, uint32_t t, double u1, double u2,
                    double out[3]);
/* Class c's triangle count and the area of its triangle t. */
uint32_t hlod_rzb_class_size(const hlod_rzb *z, uint32_t c);
double hlod_rzb_area(const hlod_rzb *z, uint32_t c, uint32_t t);

#endif
