/*
 * gl_render.h - the engine's side of the renderer (engine/gl_*.c hold every
 * GL call).  Render thread only, with the renderer's context current.
 *
 * A node on the GPU is one VAO with one VBO (positions, normals, UVs and
 * colours as present in the payload) and one IBO, plus a mipmapped texture
 * when the payload has one.  A small untextured node may instead stay on
 * the CPU and be drawn in a batch (hlod_renderer_set_batch).  Positions stay relative to the node's origin;
 * hlod_gpu_draw gets the origin minus the camera position, computed in
 * double by the caller and rounded to float once, so vertex data never
 * sees large coordinates.
 *
 * Shading: textured triangles sample the texture; untextured ones use the
 * vertex colour (the material's diffuse colour), or light grey when the
 * payload has none; both with a simple headlight-plus-sky diffuse term from
 * the normals so untextured geometry shows its shape.
 */
#ifndef HLOD_ENGINE_GL_RENDER_H
#define HLOD_ENGINE_GL_RENDER_H

#include "hlod/camera.h"
#include "hlod/renderer.h"
#include "hlod/store.h"

#include <math.h>

typedef struct hlod_gpu_node {
    uint32_t vao, vbo, ibo, tex;    /* GL names; 0 = none */
    uint32_t index_count;
    uint32_t tex_index_count;       /* the first tex_index_count indices are textured */
    uint64_t bytes;                 /* GPU bytes (buffers + texture with mipmaps), or a
                                       batched node's CPU bytes */
    uint32_t flags;                 /* HLOD_GPU_* */
    uint32_t vertex_count;          /* a batched node's */
    void *cpu;                      /* a batched node's vertices, then its indices */
} hlod_gpu_node;

#define HLOD_GPU_NORMALS 1u         /* vertex normals: lit per vertex */
#define HLOD_GPU_CULL 2u            /* closed and outward: cull back faces
                                       (the caller sets it) */
#define HLOD_GPU_BATCHED 4u         /* kept on the CPU and drawn with others (below) */

/* Small nodes drawn together (docs/runtime.md, "Batched draws"): an
 * untextured payload of at most max_tris triangles uploaded after this
 * call keeps its vertices on the CPU, no GL objects; each draw of it (or
 * of a range of it) appends its vertices, moved by the draw's offset in
 * float as the vertex shader would, to one of four buffers (normals or
 * not, culled or not), and a buffer is drawn in one call when it fills
 * and before anything reads or blends over the frame.  The image is the
 * one the node's own draws make, but for pixels where two nodes' faces
 * lie at exactly the same depth.  0 (the default): no batching. */
void hlod_renderer_set_batch(hlod_renderer *r, uint32_t max_tris);
/* Draw calls issued since hlod_gpu_begin. */
uint32_t hlod_gpu_draw_calls(const hlod_renderer *r);

/* Uploads a payload.  HLOD_ERR_NOMEM when GL runs out of memory (the node
 * stays absent), HLOD_ERR_INVALID_ARG for an empty payload,
 * HLOD_ERR_UNSUPPORTED (logged) for a texture over GL_MAX_TEXTURE_SIZE or
 * any other GL error.  Indices must be < vertex_count (the store reader
 * checks them).  *out zeroed on failure. */
hlod_result hlod_gpu_upload(hlod_renderer *r, const hlod_store_payload *p, hlod_gpu_node *out);
void hlod_gpu_release(hlod_renderer *r, hlod_gpu_node *g);   /* zeroes g; g may be zeroed */

/* Frame: begin clears and sets the viewport and camera-relative
 * view-projection; draw draws one node at `offset` = origin - camera;
 * end flushes and, when finish is set, waits for the GPU (glFinish) so the
 * caller's timer measures the whole frame.  depth picks the level colour in
 * depth-colour mode. */
void hlod_gpu_begin(hlod_renderer *r, const hlod_camera *cam);
void hlod_gpu_draw(hlod_renderer *r, const hlod_gpu_node *g, const double offset[3],
                   uint32_t depth);
void hlod_gpu_end(hlod_renderer *r, int finish);
/* Writes a frame splatted on the CPU over what is drawn: each pixel whose
 * depth (window depth, rows bottom up, w x h: the viewport) is under 1,
 * with its RGBA8 colour, depth tested against the frame (policy rzb's C
 * splatter, rzb.h).  HLOD_ERR_UNSUPPORTED (logged) when GL cannot. */
hlod_result hlod_gpu_composite(hlod_renderer *r, const uint8_t *rgba, const float *depth,
                               uint32_t w, uint32_t h);
/* Draws count indices of g from index first, with their vertex colours
 * (g's texture, if any, unused), back faces kept: policy rzb's ranges of
 * faces (rzb.h). */
void hlod_gpu_draw_range(hlod_renderer *r, const hlod_gpu_node *g, const double offset[3],
                         uint32_t first, uint32_t count);
/* As hlod_gpu_begin, for a frame drawn smaller than the image (dyn_res,
 * engine/dynres.h): the draws go to an offscreen framebuffer of cam's
 * width x height (RGBA8, 24-bit depth; depth reads read it), and
 * hlod_gpu_end scales it up, bilinear, to out_w x out_h of the framebuffer
 * bound at this call, which it binds again.  That framebuffer's depth is
 * not written.  HLOD_ERR_UNSUPPORTED (logged once) when the offscreen
 * framebuffer cannot be made: nothing is begun. */
hlod_result hlod_gpu_begin_scaled(hlod_renderer *r, const hlod_camera *cam, uint32_t out_w,
                                  uint32_t out_h);

/* One splat: a position relative to the camera and a colour, lit. */
/* The light gl_render.c's shaders give a face: a headlight and a sky
 * term.  dot: the cosine between its normal and the direction to the
 * eye; nz: its normal's z, both taken from the eye's side (a back face's
 * normal flipped).  For what the CPU lights as the shaders would (splats,
 * colour cubes, rzb's points). */
static inline double hlod_gpu_light(double dot, double nz)
{
    return 0.20 + 0.55 * fabs(dot) + 0.25 * (0.5 + 0.5 * nz);
}

typedef struct hlod_gpu_splat {
    float pos[3];
    uint8_t rgba[4];
} hlod_gpu_splat;   /* 16 bytes */

/* Draws n splats as points of size_px x size_px pixels, depth tested
 * (Klein 4.5; docs/sampletree.md).  Between begin and end.
 * HLOD_ERR_NOMEM, HLOD_ERR_UNSUPPORTED (logged) on a GL error. */
hlod_result hlod_gpu_splats(hlod_renderer *r, const hlod_gpu_splat *s, uint32_t n, float size_px);

/* Draws n / 3 triangles of the given corners (camera-relative) and
 * premultiplied colours, unlit, blended over the frame (one, one minus
 * source alpha), depth tested without writing depth, in the order given
 * (colour cubes, docs/cubes.md).  Between begin and end.
 * HLOD_ERR_NOMEM, HLOD_ERR_UNSUPPORTED (logged) on a GL error. */
hlod_result hlod_gpu_blended(hlod_renderer *r, const hlod_gpu_splat *v, uint32_t n);

/* Waits for the draws so far (glFinish), between begin and end: what
 * follows is timed without the GPU's work. */
void hlod_gpu_wait(hlod_renderer *r);

/* The depth buffer read in place, when the context lends it
 * (hlod_renderer_set_depth_view); NULL otherwise.  After hlod_gpu_wait. */
const uint32_t *hlod_gpu_depth_view(hlod_renderer *r, uint32_t *stride, uint32_t *mask);

/* Reads the depth buffer drawn so far (between begin and end; it waits for
 * the GPU) as window depth scaled to 32-bit integers, bottom row first,
 * width * height values.  HLOD_ERR_UNSUPPORTED (logged) on a GL error.
 * For occlusion culling (engine/occlusion.h). */
hlod_result hlod_gpu_read_depth(hlod_renderer *r, uint32_t width, uint32_t height, uint32_t *out);

/* The Grid-Lumigraph client's images on the GPU (engine/lumigraph.h,
 * docs/lumigraph.md): `slots` layers of size^2 RGB8 colour and
 * depth_size^2 16-bit depth codes.  Made once (again when the shape
 * changes); HLOD_ERR_UNSUPPORTED (logged) when GL cannot. */
hlod_result hlod_gpu_lumi_init(hlod_renderer *r, uint32_t slots, uint32_t size,
                               uint32_t depth_size);
void hlod_gpu_lumi_release(hlod_renderer *r);
/* Fills a slot: colour rows top first, depth codes rows top first. */
hlod_result hlod_gpu_lumi_upload(hlod_renderer *r, uint32_t slot, const uint8_t *rgb,
                                 const uint16_t *depth);

/* A frame's images: the 8 grid points around the eye (camera-relative),
 * their weights, and per point and face the slot holding that view, -1
 * when none does (not fetched yet), -2 when the view is empty (it saw
 * nothing: the clear colour). */
typedef struct hlod_gpu_lumi_frame {
    float point[8][3];
    float weight[8];
    int32_t slot[8][6];
    float near_plane, log_ratio;   /* depth codes: near * exp(q / 65534 * log_ratio) */
    float tolerance;               /* a fragment farther than (1 + tolerance) x the view's
                                      depth is hidden from that view */
} hlod_gpu_lumi_frame;

/* An optional depth pre-pass, after hlod_gpu_begin: the nodes' depth
 * alone (hlod_gpu_lumi_depth each), so that hlod_gpu_lumi_draw then
 * shades each pixel once, whatever the overdraw. */
void hlod_gpu_lumi_depth_begin(hlod_renderer *r);
void hlod_gpu_lumi_depth(hlod_renderer *r, const hlod_gpu_node *g, const double offset[3]);
/* After hlod_gpu_begin (and the pre-pass): fills the background from the
 * views along each pixel's ray where nothing is drawn, then readies
 * hlod_gpu_lumi_draw (depth tested LEQUAL without writing after a
 * pre-pass; LESS with writes without one). */
void hlod_gpu_lumi_begin(hlod_renderer *r, const hlod_camera *cam, const hlod_gpu_lumi_frame *f);
/* Draws a node's triangles coloured from the views (its own texture and
 * colours unused). */
void hlod_gpu_lumi_draw(hlod_renderer *r, const hlod_gpu_node *g, const double offset[3]);

#endif
