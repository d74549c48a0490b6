/*
 * cubes.h - Chamberlain's colour cubes: the six RGBA faces of a box, from
 * its triangles seen orthographically and its children's cubes
 * composited (docs/cubes.md).
 *
 * Chamberlain, DeRose, Lischinski, Salesin, Snyder, "Fast rendering of
 * complex environments using a spatial hierarchy", section 4: a
 * leaf's face is its primitives drawn orthographically through the face
 * at about 4 x 4 pixels and averaged; an inner cell's is its children's
 * faces composited front to back ("over") and averaged.
 */
#ifndef HLOD_CUBES_H
#define HLOD_CUBES_H

#include <stddef.h>
#include <stdint.h>

#include "hlod/hlod.h"
#include "hlod/store_write.h"

/* Samples along a face side: 4 x 4 pixels of 4 x 4 samples each. */
#define HLOD_CUBE_SAMPLES 16

/* The six faces, in the order +x, -x, +y, -y, +z, -z: face f is what a
 * viewer outside the box on the f side, looking in along the axis, sees.
 * RGB premultiplied by alpha, all in [0, 1]; alpha is the share of the
 * face that geometry covers. */
typedef struct hlod_cube {
    float rgba[6][4];
} hlod_cube;

/* What one box's faces are made from. */
typedef struct hlod_cube_in {
    double lo[3], hi[3];        /* the box: geometry outside it is clipped */
    const void *tris;           /* n triangles, each beginning with double p[9] */
    size_t stride, n;           /* bytes from one triangle to the next */
    /* the opaque colour of triangle i at barycentric weights w (RGB in
     * [0, 1]); NULL: white */
    void (*color)(void *user, size_t i, const double w[3], float rgb[3]);
    void *user;
    const hlod_cube *kids;      /* children's cubes, composited with the triangles */
    const double (*kid_lo)[3], (*kid_hi)[3];
    size_t nkids;
} hlod_cube_in;

/* The six faces of in->lo..hi from its triangles and children: per face,
 * HLOD_CUBE_SAMPLES^2 orthographic samples, each the nearest triangle
 * (opaque) and the children's faces that cover it at their depth,
 * composited front to back, then averaged. */
void hlod_cube_faces(const hlod_cube_in *in, hlod_cube *out);

/* A face as stored (hlod_store_extra.cube): RGBA8, premultiplied. */
void hlod_cube_pack(const hlod_cube *c, uint8_t out[6][4]);
void hlod_cube_unpack(const uint8_t in[6][4], hlod_cube *c);

/* A pixel of `channels` (1..4) channels as RGBA. */
void hlod_pixel_rgba(const uint8_t *p, int channels, uint8_t out[4]);

/* The texel of a w x h image of `channels` (1-4) bytes a pixel, top row
 * first, at (u, v), wrapped (v = 0 the bottom row), as RGBA. */
void hlod_cube_texel(const uint8_t *pixels, int w, int h, int channels, double u, double v,
                     uint8_t out[4]);

/* The packed cube of one node's own mesh, as hlod_store_writer_add takes
 * it, over the box of its positions: what `far_cubes` draws in place of
 * the mesh (docs/cubes.md, "Cubes as stand-ins").  A triangle's colour is
 * its texture's texel (the first tex_tri_count triangles), else its
 * vertex colours blended, else the renderer's grey.  HLOD_ERR_NOMEM. */
hlod_result hlod_cube_of_payload(const hlod_store_payload_desc *p, uint8_t out[6][4]);

#endif
