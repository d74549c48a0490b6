/*
 * gl_osmesa.c - headless OpenGL through OSMesa (engine.h), for tests and
 * benchmarks; its own library (hlod_osmesa) so hlod_engine links no GL.
 *
 * A context is a 3.3 core profile context (Mesa gives the newest core
 * version it has, e.g. 4.5 on llvmpipe) rendering into a buffer the
 * hlod_osmesa owns: RGBA, 24-bit depth, no stencil.  GL functions used here
 * are loaded through OSMesaGetProcAddress like the renderer's, so nothing
 * depends on which GL symbols libOSMesa happens to export.
 */
#include <assert.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <GL/osmesa.h>

#include "hlod/renderer.h"

typedef void (GLAPIENTRY *gl_finish_fn)(void);
typedef void (GLAPIENTRY *gl_pixel_store_fn)(GLenum pname, GLint param);
typedef void (GLAPIENTRY *gl_read_pixels_fn)(GLint x, GLint y, GLsizei w, GLsizei h, GLenum format,
                                  GLenum type, void *pixels);
typedef GLenum (GLAPIENTRY *gl_get_error_fn)(void);
typedef void (GLAPIENTRY *gl_clear_depth_fn)(GLdouble depth);
typedef void (GLAPIENTRY *gl_clear_fn)(GLbitfield mask);
typedef const GLubyte *(GLAPIENTRY *gl_get_string_fn)(GLenum name);

struct hlod_osmesa {
    OSMesaContext ctx;
    uint8_t *buffer;            /* width * height * 4, bottom row first */
    uint32_t width, height;
    hlod_logger lg;
    gl_finish_fn finish;
    gl_pixel_store_fn pixel_store;
    gl_read_pixels_fn read_pixels;
    gl_get_error_fn get_error;
    gl_clear_depth_fn clear_depth;
    gl_clear_fn clear;
    uint32_t depth_mask;        /* the depth's bits in the buffer; 0: not lent */
    char renderer_name[256];    /* GL_RENDERER */
};

/* The hlod_gl_get_proc of OSMesa.  Function and object pointers have the
 * same size on every platform OSMesa runs on (POSIX requires it). */
static void *osmesa_get_proc(const char *name)
{
    OSMESAproc f = OSMesaGetProcAddress(name);
    void *p;
    _Static_assert(sizeof p == sizeof f, "function and object pointers differ");
    memcpy(&p, &f, sizeof p);
    return p;
}

hlod_gl_get_proc hlod_osmesa_get_proc(void)
{
    return osmesa_get_proc;
}

#define LOAD(dst, name)                             \
    do {                                            \
        void *p_ = osmesa_get_proc(name);           \
        memcpy(&(dst), &p_, sizeof(dst));           \
    } while (0)

/* called from the thread that will render */
hlod_result hlod_osmesa_create(uint32_t width, uint32_t height, const hlod_logger *lg,
                               hlod_osmesa **out)
{
    if (out)
        *out = NULL;
    if (!out || width == 0 || height == 0 || width > 16384 || height > 16384)
        return HLOD_ERR_INVALID_ARG;
    hlod_osmesa *o = calloc(1, sizeof *o);
    if (!o)
        return HLOD_ERR_NOMEM;
    if (lg)
        o->lg = *lg;
    o->width = width;
    o->height = height;
    o->buffer = malloc((size_t)width * height * 4);
    if (!o->buffer) {
        free(o);
        return HLOD_ERR_NOMEM;
    }
    const int attribs[] = {OSMESA_FORMAT, OSMESA_RGBA,
                           OSMESA_DEPTH_BITS, 24,
                           OSMESA_STENCIL_BITS, 0,
                           OSMESA_ACCUM_BITS, 0,
                           OSMESA_PROFILE, OSMESA_CORE_PROFILE,
                           OSMESA_CONTEXT_MAJOR_VERSION, 3,
                           OSMESA_CONTEXT_MINOR_VERSION, 3,
                           0};
    o->ctx = OSMesaCreateContextAttribs(attribs, NULL);
    if (!o->ctx) {
        hlod_logf(&o->lg, HLOD_LOG_ERROR, "osmesa: cannot create a 3.3 core context");
        free(o->buffer);
        free(o);
        return HLOD_ERR_UNSUPPORTED;
    }
    if (!OSMesaMakeCurrent(o->ctx, o->buffer, GL_UNSIGNED_BYTE, (GLsizei)width,
                           (GLsizei)height)) {
        hlod_logf(&o->lg, HLOD_LOG_ERROR, "osmesa: cannot make a %ux%u context current", width,
                  height);
        OSMesaDestroyContext(o->ctx);
        free(o->buffer);
        free(o);
        return HLOD_ERR_UNSUPPORTED;
    }
    LOAD(o->finish, "glFinish");
    LOAD(o->pixel_store, "glPixelStorei");
    LOAD(o->read_pixels, "glReadPixels");
    LOAD(o->get_error, "glGetError");
    LOAD(o->clear_depth, "glClearDepth");
    LOAD(o->clear, "glClear");
    gl_get_string_fn get_string;
    LOAD(get_string, "glGetString");
    if (!o->finish || !o->pixel_store || !o->read_pixels || !o->get_error || !get_string ||
        !o->clear_depth || !o->clear) {
        hlod_logf(&o->lg, HLOD_LOG_ERROR, "osmesa: missing GL functions");
        hlod_osmesa_destroy(o);
        return HLOD_ERR_UNSUPPORTED;
    }
    const char *name = (const char *)get_string(GL_RENDERER);
    snprintf(o->renderer_name, sizeof o->renderer_name, "%s (OSMesa)", name ? name : "?");
    *out = o;
    return HLOD_OK;
}

/* called from the thread that rendered */
void hlod_osmesa_destroy(hlod_osmesa *o)
{
    if (!o)
        return;
    if (OSMesaGetCurrentContext() == o->ctx)
        OSMesaMakeCurrent(NULL, NULL, GL_UNSIGNED_BYTE, 0, 0);
    OSMesaDestroyContext(o->ctx);
    free(o->buffer);
    free(o);
}

/* called from the render thread */
hlod_result hlod_osmesa_make_current(hlod_osmesa *o)
{
    if (!o)
        return HLOD_ERR_INVALID_ARG;
    if (OSMesaGetCurrentContext() == o->ctx)
        return HLOD_OK;
    if (!OSMesaMakeCurrent(o->ctx, o->buffer, GL_UNSIGNED_BYTE, (GLsizei)o->width,
                           (GLsizei)o->height)) {
        hlod_logf(&o->lg, HLOD_LOG_ERROR, "osmesa: cannot make the %ux%u context current",
                  o->width, o->height);
        return HLOD_ERR_UNSUPPORTED;
    }
    return HLOD_OK;
}

const char *hlod_osmesa_renderer_name(const hlod_osmesa *o)
{
    return o ? o->renderer_name : "";
}

/* The depth buffer in place (hlod_depth_view): OSMesa lends it.  Its
 * layout is the driver's (24 depth bits in the low or the high bits of
 * each 32-bit value); share_depth found which by clearing. */
static const uint32_t *osmesa_depth(void *user, uint32_t *stride, uint32_t *mask)
{
    hlod_osmesa *o = user;
    GLint w = 0, h = 0, bytes = 0;
    void *buf = NULL;
    if (!o->depth_mask || OSMesaGetCurrentContext() != o->ctx ||
        !OSMesaGetDepthBuffer(o->ctx, &w, &h, &bytes, &buf) || bytes != 4 || !buf ||
        (uint32_t)w != o->width || (uint32_t)h != o->height)
        return NULL;
    *stride = (uint32_t)w;
    *mask = o->depth_mask;
    return buf;
}

/* called from the thread that renders, o's context current */
void hlod_osmesa_share_depth(hlod_osmesa *o, hlod_renderer *r)
{
    if (!o || !r || OSMesaGetCurrentContext() != o->ctx)
        return;
    /* which bits hold the depth: those that differ between a clear to 0
     * and a clear to 1; window depth 1 must fill them exactly */
    uint32_t v[2] = {0, 0};
    for (int k = 0; k < 2; k++) {
        o->clear_depth(k ? 1.0 : 0.0);
        o->clear(GL_DEPTH_BUFFER_BIT);
        o->finish();
        GLint w = 0, h = 0, bytes = 0;
        void *buf = NULL;
        if (!OSMesaGetDepthBuffer(o->ctx, &w, &h, &bytes, &buf) || bytes != 4 || !buf)
            return; /* the renderer copies with glReadPixels */
        v[k] = ((const uint32_t *)buf)[0];
    }
    o->clear_depth(1.0);
    uint32_t mask = v[0] ^ v[1];
    if ((v[1] & mask) != mask || !(mask == 0xffffffu || mask == 0xffffff00u || mask == ~0u))
        return;
    o->depth_mask = mask;
    hlod_renderer_set_depth_view(r, osmesa_depth, o);
}

/* called from the thread that rendered, o's context current */
hlod_result hlod_osmesa_read_rgb(hlod_osmesa *o, uint8_t *rgb)
{
    if (!o || !rgb)
        return HLOD_ERR_INVALID_ARG;
    if (OSMesaGetCurrentContext() != o->ctx) {
        hlod_logf(&o->lg, HLOD_LOG_ERROR, "osmesa: read_rgb: context not current");
        return HLOD_ERR_INVALID_ARG;
    }
    for (int i = 0; i < 16 && o->get_error() != GL_NO_ERROR; i++)
        ;   /* earlier errors are not this read's */
    o->finish();
    o->pixel_store(GL_PACK_ALIGNMENT, 1);
    o->read_pixels(0, 0, (GLsizei)o->width, (GLsizei)o->height, GL_RGB, GL_UNSIGNED_BYTE, rgb);
    o->pixel_store(GL_PACK_ALIGNMENT, 4);
    if (o->get_error() != GL_NO_ERROR) {
        hlod_logf(&o->lg, HLOD_LOG_ERROR, "osmesa: glReadPixels failed");
        return HLOD_ERR_UNSUPPORTED;
    }
    hlod_rgb_flip_rows(rgb, o->width, o->height); /* GL rows are bottom first */
    return HLOD_OK;
}
