/*
 * renderer.h - the OpenGL 3.3 renderer the engine draws with
 * (engine/gl_*.c), and headless OSMesa and EGL contexts for it.  Render thread
 * only, with the renderer's context current.
 */
#ifndef HLOD_RENDERER_H
#define HLOD_RENDERER_H

#include "hlod/hlod.h"

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hlod_renderer hlod_renderer;   /* also in hlod/engine.h */

/* A GL function loader: OSMesaGetProcAddress, glfwGetProcAddress. */
typedef void *(*hlod_gl_get_proc)(const char *name);

/* Creates a renderer in the current GL context (3.3 core or later): loads
 * the entry points through get_proc, compiles the shaders.  HLOD_ERR_UNSUPPORTED
 * when the context is too old or a function is missing.  Render thread. */
hlod_result hlod_renderer_create(hlod_gl_get_proc get_proc, const hlod_logger *lg,
                                 hlod_renderer **out);
void hlod_renderer_destroy(hlod_renderer *r);   /* context current; r may be NULL */

/* Colour nodes by depth instead of texture/material (viewer toggle). */
void hlod_renderer_set_depth_colors(hlod_renderer *r, int on);
void hlod_renderer_set_wireframe(hlod_renderer *r, int on);
/* Cull back faces of nodes whose block is solid (HLOD_RENDER_SOLID); on by
 * default.  Off draws every face (for checking that culling hides nothing). */
void hlod_renderer_set_backface_culling(hlod_renderer *r, int on);
void hlod_renderer_set_clear_color(hlod_renderer *r, float red, float green, float blue);

/* How block-coded textures (BC1/BC4, docs/store-format.md) reach this GL,
 * for the engine's texture_upload setting `mode`: 1 when they are uploaded
 * as blocks (glCompressedTexImage2D), 0 when the loader expands them to
 * texels first.  mode 2 asks for blocks, 1 for texels; 0 picks blocks where
 * the context has EXT_texture_compression_s3tc and is not a software
 * rasteriser (on llvmpipe a frame drawn from blocks took 1.2x the time of
 * one drawn from texels, docs/runtime.md "Texture upload").  Blocks asked for on a
 * context without the extension give 0, with a warning through r's
 * logger.  Any thread; the answer is fixed at hlod_renderer_create. */
int hlod_renderer_texture_blocks(const hlod_renderer *r, uint32_t mode);

/* A way for the renderer to read the depth buffer in place instead of
 * copying it (occlusion culling reads it every frame): returns the depth
 * values of the current framebuffer, bottom row first, rows *stride values
 * apart, the depth in the bits of *mask; NULL when it cannot.  Called
 * between draws, after the GPU has finished them. */
typedef const uint32_t *(*hlod_depth_view)(void *user, uint32_t *stride, uint32_t *mask);
void hlod_renderer_set_depth_view(hlod_renderer *r, hlod_depth_view view, void *user);

/* A headless OSMesa context with its own colour and depth buffer. */
typedef struct hlod_osmesa hlod_osmesa;
hlod_result hlod_osmesa_create(uint32_t width, uint32_t height, const hlod_logger *lg,
                               hlod_osmesa **out);   /* and makes it current */
void hlod_osmesa_destroy(hlod_osmesa *o);
hlod_gl_get_proc hlod_osmesa_get_proc(void);
/* Lets r read o's depth buffer in place (hlod_renderer_set_depth_view);
 * o's context current.  Without it the renderer copies the depth with
 * glReadPixels. */
void hlod_osmesa_share_depth(hlod_osmesa *o, hlod_renderer *r);
/* Copies the current image as 8-bit RGB, top row first, width*height*3
 * bytes (glReadPixels after glFinish). */
hlod_result hlod_osmesa_read_rgb(hlod_osmesa *o, uint8_t *rgb);
/* Makes o's context current again (a process with several contexts, e.g.
 * hlod-bench's measured and reference ones, calls it before each engine
 * call).  A no-op when it already is. */
hlod_result hlod_osmesa_make_current(hlod_osmesa *o);
/* GL_RENDERER of o's context, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)". */
const char *hlod_osmesa_renderer_name(const hlod_osmesa *o);

/* A headless EGL context (engine/gl_egl.c, library hlod_egl) of the same
 * shape: desktop GL 3.3 core, current with no surface, drawing into an FBO
 * it owns (RGBA8 colour, 24-bit depth, width x height) that stays bound.
 * The display is a hardware EGL device when the driver lists one, else
 * Mesa's surfaceless platform (llvmpipe without a GPU), else
 * EGL_DEFAULT_DISPLAY; HLOD_EGL_PLATFORM=device|surfaceless|default forces
 * one.  Contexts of a process share one display.  Render thread only. */
typedef struct hlod_egl hlod_egl;
hlod_result hlod_egl_create(uint32_t width, uint32_t height, const hlod_logger *lg,
                            hlod_egl **out);   /* and makes it current */
/* Leaves no context current (make another one current before using it). */
void hlod_egl_destroy(hlod_egl *g);
hlod_gl_get_proc hlod_egl_get_proc(void);
hlod_result hlod_egl_make_current(hlod_egl *g);   /* no-op when it already is */
/* As hlod_osmesa_read_rgb, from the FBO; g's context current. */
hlod_result hlod_egl_read_rgb(hlod_egl *g, uint8_t *rgb);
/* GL_RENDERER and the EGL platform, e.g. "llvmpipe (...) (EGL surfaceless)". */
const char *hlod_egl_renderer_name(const hlod_egl *g);

/* Copies the framebuffer bound for reading (the back buffer of a window)
 * as 8-bit RGB, top row first, width*height*3 bytes (glReadPixels, which
 * waits for the GPU).  Call after the frame is drawn and before the swap.
 * HLOD_ERR_UNSUPPORTED (logged) on a GL error, e.g. a size past the
 * framebuffer.  For screenshots. */
hlod_result hlod_renderer_read_rgb(hlod_renderer *r, uint32_t width, uint32_t height,
                                   uint8_t *rgb);

/* Turns an 8-bit RGB image bottom row first (as GL reads it) into top row
 * first, in place. */
void hlod_rgb_flip_rows(uint8_t *rgb, uint32_t width, uint32_t height);

#ifdef __cplusplus
}
#endif
#endif
