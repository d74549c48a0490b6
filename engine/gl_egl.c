/*
 * gl_egl.c - headless OpenGL through EGL (renderer.h), for benchmarks on a
 * machine with a GPU; its own library (hlod_egl) so hlod_engine links no
 * EGL.  The same shape as gl_osmesa.c: create (and make current), make
 * current, read back, destroy.
 *
 * The display, in this order:
 * 1. a hardware EGL device (EGL_EXT_platform_device), when the driver lists
 *    one: the GPU's own driver (first, because on a GPU without a Mesa
 *    driver, e.g. NVIDIA's, Mesa's surfaceless platform can answer with
 *    llvmpipe);
 * 2. Mesa's surfaceless platform (EGL_PLATFORM_SURFACELESS_MESA): a render
 *    node's Mesa driver, or llvmpipe on a machine without a GPU;
 * 3. EGL_DEFAULT_DISPLAY.
 * HLOD_EGL_PLATFORM=device|surfaceless|default forces one.
 *
 * A context is desktop GL 3.3 core (eglBindAPI(EGL_OPENGL_API)), current
 * with EGL_NO_SURFACE (EGL_KHR_surfaceless_context), drawing into an FBO
 * the hlod_egl owns: an RGBA8 colour and a 24-bit depth renderbuffer of the
 * viewport's size.  The FBO is bound in create and stays bound (the
 * renderer draws into whatever framebuffer is bound, and the binding is
 * the context's, so it survives make_current).  GL functions come from
 * eglGetProcAddress, like the renderer's.
 *
 * Render thread only.  The EGL display is initialised once per process
 * and shared by its contexts; it is never terminated (see
 * release_display).
 */
#include <assert.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <GL/gl.h>
#include <GL/glext.h>

#include "hlod/renderer.h"

#ifndef EGL_PLATFORM_SURFACELESS_MESA
#define EGL_PLATFORM_SURFACELESS_MESA 0x31DD
#endif
#ifndef EGL_PLATFORM_DEVICE_EXT
#define EGL_PLATFORM_DEVICE_EXT 0x313F
#endif

typedef void (*gl_finish_fn)(void);
typedef void (*gl_pixel_store_fn)(GLenum pname, GLint param);
typedef void (*gl_read_pixels_fn)(GLint x, GLint y, GLsizei w, GLsizei h, GLenum format,
                                  GLenum type, void *pixels);
typedef GLenum (*gl_get_error_fn)(void);
typedef const GLubyte *(*gl_get_string_fn)(GLenum name);
typedef void (*gl_gen_fn)(GLsizei n, GLuint *ids);
typedef void (*gl_delete_fn)(GLsizei n, const GLuint *ids);
typedef void (*gl_bind_fn)(GLenum target, GLuint id);
typedef void (*gl_rb_storage_fn)(GLenum target, GLenum format, GLsizei w, GLsizei h);
typedef void (*gl_fb_rb_fn)(GLenum target, GLenum attachment, GLenum rb_target, GLuint rb);
typedef GLenum (*gl_fb_status_fn)(GLenum target);

struct hlod_egl {
    EGLContext ctx;
    GLuint fbo, color, depth;
    uint32_t width, height;
    hlod_logger lg;
    char renderer_name[256];
    gl_finish_fn finish;
    gl_pixel_store_fn pixel_store;
    gl_read_pixels_fn read_pixels;
    gl_get_error_fn get_error;
    gl_delete_fn delete_framebuffers, delete_renderbuffers;
};

/* The process's display, shared by every hlod_egl (render thread). */
static EGLDisplay g_display = EGL_NO_DISPLAY;
static const char *g_platform = "";
static int g_users;

/* The hlod_gl_get_proc of EGL (function and object pointers have the same
 * size on every platform EGL runs on; POSIX requires it). */
static void *egl_get_proc(const char *name)
{
    __eglMustCastToProperFunctionPointerType f = eglGetProcAddress(name);
    void *p;
    _Static_assert(sizeof p == sizeof f, "function and object pointers differ");
    memcpy(&p, &f, sizeof p);
    return p;
}

hlod_gl_get_proc hlod_egl_get_proc(void)
{
    return egl_get_proc;
}

#define LOAD(dst, name)                             \
    do {                                            \
        void *p_ = egl_get_proc(name);              \
        memcpy(&(dst), &p_, sizeof(dst));           \
    } while (0)

/* Is word a whole word of the space-separated list? */
static int has_word(const char *list, const char *word)
{
    size_t n = strlen(word);
    for (const char *p = list; p && (p = strstr(p, word)); p += n)
        if ((p == list || p[-1] == ' ') && (p[n] == ' ' || p[n] == 0))
            return 1;
    return 0;
}

/* A hardware device's display (EGL_EXT_platform_device), else
 * EGL_NO_DISPLAY.  Mesa marks its software device EGL_MESA_device_software. */
static EGLDisplay device_display(PFNEGLGETPLATFORMDISPLAYEXTPROC get_platform_display)
{
    PFNEGLQUERYDEVICESEXTPROC query_devices;
    PFNEGLQUERYDEVICESTRINGEXTPROC query_string;
    LOAD(query_devices, "eglQueryDevicesEXT");
    LOAD(query_string, "eglQueryDeviceStringEXT");
    if (!query_devices || !query_string)
        return EGL_NO_DISPLAY;
    EGLDeviceEXT dev[16];
    EGLint n = 0;
    if (!query_devices(16, dev, &n))
        return EGL_NO_DISPLAY;
    for (EGLint i = 0; i < n; i++) {
        const char *ext = query_string(dev[i], EGL_EXTENSIONS);
        if (ext && has_word(ext, "EGL_MESA_device_software"))
            continue;
        EGLDisplay d = get_platform_display(EGL_PLATFORM_DEVICE_EXT, dev[i], NULL);
        if (d != EGL_NO_DISPLAY && eglInitialize(d, NULL, NULL))
            return d;
    }
    return EGL_NO_DISPLAY;
}

/* Opens and initialises the shared display (see the top of the file). */
static EGLDisplay open_display(const hlod_logger *lg)
{
    if (g_display != EGL_NO_DISPLAY)
        return g_display;
    const char *force = getenv("HLOD_EGL_PLATFORM");
    if (force && *force && strcmp(force, "device") && strcmp(force, "surfaceless") &&
        strcmp(force, "default")) {
        hlod_logf(lg, HLOD_LOG_ERROR, "egl: HLOD_EGL_PLATFORM=%s: not device, surfaceless or "
                  "default", force);
        return EGL_NO_DISPLAY;
    }
    const char *client = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    PFNEGLGETPLATFORMDISPLAYEXTPROC get_platform_display;
    LOAD(get_platform_display, "eglGetPlatformDisplay"); /* EGL 1.5; same signature */
    if (!get_platform_display)
        LOAD(get_platform_display, "eglGetPlatformDisplayEXT");
    int any = !force || !*force;
    EGLDisplay d = EGL_NO_DISPLAY;
    if ((any || !strcmp(force, "device")) && get_platform_display && client &&
        has_word(client, "EGL_EXT_platform_device")) {
        d = device_display(get_platform_display);
        g_platform = "device";
    }
    if (d == EGL_NO_DISPLAY && (any || !strcmp(force, "surfaceless")) && get_platform_display &&
        client && has_word(client, "EGL_MESA_platform_surfaceless")) {
        d = get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, NULL);
        if (d != EGL_NO_DISPLAY && !eglInitialize(d, NULL, NULL))
            d = EGL_NO_DISPLAY;
        g_platform = "surfaceless";
    }
    if (d == EGL_NO_DISPLAY && (any || !strcmp(force, "default"))) {
        d = eglGetDisplay(EGL_DEFAULT_DISPLAY);
        if (d != EGL_NO_DISPLAY && !eglInitialize(d, NULL, NULL))
            d = EGL_NO_DISPLAY;
        g_platform = "default";
    }
    if (d == EGL_NO_DISPLAY) {
        hlod_logf(lg, HLOD_LOG_ERROR, "egl: no display (%s%s; EGL error 0x%x)",
                  force && *force ? "HLOD_EGL_PLATFORM=" : "tried device, surfaceless, default",
                  force && *force ? force : "", (unsigned)eglGetError());
        return EGL_NO_DISPLAY;
    }
    g_display = d;
    return d;
}

/* The last hlod_egl gone: no context current.  The display stays
 * initialised for the process's life (a later create reuses it): Mesa's
 * eglTerminate unloads the driver with a few blocks it never frees, which
 * LeakSanitizer then reports from an unknown module that no suppression
 * can name. */
static void release_display(void)
{
    if (g_users == 0 && g_display != EGL_NO_DISPLAY) {
        eglMakeCurrent(g_display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        eglReleaseThread();
    }
}

/* Makes the 3.3 core context: *ctx, or a logged error. */
static hlod_result make_context(EGLDisplay d, const hlod_logger *lg, EGLContext *ctx)
{
    const char *ext = eglQueryString(d, EGL_EXTENSIONS);
    if (!ext || !has_word(ext, "EGL_KHR_surfaceless_context")) {
        hlod_logf(lg, HLOD_LOG_ERROR, "egl: the display has no EGL_KHR_surfaceless_context");
        return HLOD_ERR_UNSUPPORTED;
    }
    if (!eglBindAPI(EGL_OPENGL_API)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "egl: no desktop OpenGL (eglBindAPI failed, 0x%x)",
                  (unsigned)eglGetError());
        return HLOD_ERR_UNSUPPORTED;
    }
    const EGLint cfg_attribs[] = {EGL_SURFACE_TYPE, 0, /* no surface: any config */
                                  EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT, EGL_NONE};
    EGLConfig cfg;
    EGLint ncfg = 0;
    if (!eglChooseConfig(d, cfg_attribs, &cfg, 1, &ncfg) || ncfg < 1) {
        hlod_logf(lg, HLOD_LOG_ERROR, "egl: no config for desktop OpenGL (0x%x)",
                  (unsigned)eglGetError());
        return HLOD_ERR_UNSUPPORTED;
    }
    const EGLint ctx_attribs[] = {EGL_CONTEXT_MAJOR_VERSION, 3,
                                  EGL_CONTEXT_MINOR_VERSION, 3,
                                  EGL_CONTEXT_OPENGL_PROFILE_MASK,
                                  EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
                                  EGL_NONE};
    *ctx = eglCreateContext(d, cfg, EGL_NO_CONTEXT, ctx_attribs);
    if (*ctx == EGL_NO_CONTEXT) {
        hlod_logf(lg, HLOD_LOG_ERROR, "egl: cannot create a 3.3 core context (0x%x)",
                  (unsigned)eglGetError());
        return HLOD_ERR_UNSUPPORTED;
    }
    if (!eglMakeCurrent(d, EGL_NO_SURFACE, EGL_NO_SURFACE, *ctx)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "egl: cannot make the context current without a surface "
                  "(0x%x)", (unsigned)eglGetError());
        eglDestroyContext(d, *ctx);
        *ctx = EGL_NO_CONTEXT;
        return HLOD_ERR_UNSUPPORTED;
    }
    return HLOD_OK;
}

/* The FBO of g's size, bound; g's context current. */
static hlod_result make_fbo(hlod_egl *g)
{
    gl_gen_fn gen_fb, gen_rb;
    gl_bind_fn bind_fb, bind_rb;
    gl_rb_storage_fn storage;
    gl_fb_rb_fn attach;
    gl_fb_status_fn status;
    LOAD(gen_fb, "glGenFramebuffers");
    LOAD(gen_rb, "glGenRenderbuffers");
    LOAD(bind_fb, "glBindFramebuffer");
    LOAD(bind_rb, "glBindRenderbuffer");
    LOAD(storage, "glRenderbufferStorage");
    LOAD(attach, "glFramebufferRenderbuffer");
    LOAD(status, "glCheckFramebufferStatus");
    LOAD(g->delete_framebuffers, "glDeleteFramebuffers");
    LOAD(g->delete_renderbuffers, "glDeleteRenderbuffers");
    if (!gen_fb || !gen_rb || !bind_fb || !bind_rb || !storage || !attach || !status ||
        !g->delete_framebuffers || !g->delete_renderbuffers) {
        hlod_logf(&g->lg, HLOD_LOG_ERROR, "egl: missing framebuffer functions");
        return HLOD_ERR_UNSUPPORTED;
    }
    gen_rb(1, &g->color);
    bind_rb(GL_RENDERBUFFER, g->color);
    storage(GL_RENDERBUFFER, GL_RGBA8, (GLsizei)g->width, (GLsizei)g->height);
    gen_rb(1, &g->depth);
    bind_rb(GL_RENDERBUFFER, g->depth);
    storage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, (GLsizei)g->width, (GLsizei)g->height);
    bind_rb(GL_RENDERBUFFER, 0);
    gen_fb(1, &g->fbo);
    bind_fb(GL_FRAMEBUFFER, g->fbo);
    attach(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER, g->color);
    attach(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER, g->depth);
    GLenum s = status(GL_FRAMEBUFFER);
    if (s != GL_FRAMEBUFFER_COMPLETE || g->get_error() != GL_NO_ERROR) {
        hlod_logf(&g->lg, HLOD_LOG_ERROR, "egl: a %ux%u RGBA8 + depth24 framebuffer is not "
                  "complete (status 0x%x)", g->width, g->height, (unsigned)s);
        return HLOD_ERR_UNSUPPORTED;
    }
    return HLOD_OK;
}

/* called from the thread that will render */
hlod_result hlod_egl_create(uint32_t width, uint32_t height, const hlod_logger *lg,
                            hlod_egl **out)
{
    if (out)
        *out = NULL;
    if (!out || width == 0 || height == 0 || width > 16384 || height > 16384)
        return HLOD_ERR_INVALID_ARG;
    hlod_egl *g = calloc(1, sizeof *g);
    if (!g)
        return HLOD_ERR_NOMEM;
    if (lg)
        g->lg = *lg;
    g->width = width;
    g->height = height;
    g->ctx = EGL_NO_CONTEXT;
    EGLDisplay d = open_display(&g->lg);
    if (d == EGL_NO_DISPLAY) {
        free(g);
        return HLOD_ERR_UNSUPPORTED;
    }
    g_users++;
    hlod_result r = make_context(d, &g->lg, &g->ctx);
    if (r != HLOD_OK) {
        hlod_egl_destroy(g);
        return r;
    }
    gl_get_string_fn get_string;
    LOAD(g->finish, "glFinish");
    LOAD(g->pixel_store, "glPixelStorei");
    LOAD(g->read_pixels, "glReadPixels");
    LOAD(g->get_error, "glGetError");
    LOAD(get_string, "glGetString");
    if (!g->finish || !g->pixel_store || !g->read_pixels || !g->get_error || !get_string) {
        hlod_logf(&g->lg, HLOD_LOG_ERROR, "egl: missing GL functions");
        hlod_egl_destroy(g);
        return HLOD_ERR_UNSUPPORTED;
    }
    const char *name = (const char *)get_string(GL_RENDERER);
    snprintf(g->renderer_name, sizeof g->renderer_name, "%s (EGL %s)", name ? name : "?",
             g_platform);
    r = make_fbo(g);
    if (r != HLOD_OK) {
        hlod_egl_destroy(g);
        return r;
    }
    *out = g;
    return HLOD_OK;
}

/* called from the thread that rendered */
void hlod_egl_destroy(hlod_egl *g)
{
    if (!g)
        return;
    if (g->ctx != EGL_NO_CONTEXT) {
        if (eglGetCurrentContext() != g->ctx)
            eglMakeCurrent(g_display, EGL_NO_SURFACE, EGL_NO_SURFACE, g->ctx);
        if (g->fbo)
            g->delete_framebuffers(1, &g->fbo);
        if (g->color)
            g->delete_renderbuffers(1, &g->color);
        if (g->depth)
            g->delete_renderbuffers(1, &g->depth);
        eglMakeCurrent(g_display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
        eglDestroyContext(g_display, g->ctx);
    }
    g_users--;
    release_display();
    free(g);
}

/* called from the render thread */
hlod_result hlod_egl_make_current(hlod_egl *g)
{
    if (!g)
        return HLOD_ERR_INVALID_ARG;
    if (eglGetCurrentContext() == g->ctx)
        return HLOD_OK;
    if (!eglMakeCurrent(g_display, EGL_NO_SURFACE, EGL_NO_SURFACE, g->ctx)) {
        hlod_logf(&g->lg, HLOD_LOG_ERROR, "egl: make_current failed (0x%x)",
                  (unsigned)eglGetError());
        return HLOD_ERR_UNSUPPORTED;
    }
    return HLOD_OK;
}

const char *hlod_egl_renderer_name(const hlod_egl *g)
{
    return g ? g->renderer_name : "";
}

/* called from the thread that rendered, g's context current */
hlod_result hlod_egl_read_rgb(hlod_egl *g, uint8_t *rgb)
{
    if (!g || !rgb)
        return HLOD_ERR_INVALID_ARG;
    if (eglGetCurrentContext() != g->ctx) {
        hlod_logf(&g->lg, HLOD_LOG_ERROR, "egl: read_rgb: context not current");
        return HLOD_ERR_INVALID_ARG;
    }
    for (int i = 0; i < 16 && g->get_error() != GL_NO_ERROR; i++)
        ;   /* earlier errors are not this read's */
    g->finish();
    g->pixel_store(GL_PACK_ALIGNMENT, 1);
    g->read_pixels(0, 0, (GLsizei)g->width, (GLsizei)g->height, GL_RGB, GL_UNSIGNED_BYTE, rgb);
    g->pixel_store(GL_PACK_ALIGNMENT, 4);
    if (g->get_error() != GL_NO_ERROR) {
        hlod_logf(&g->lg, HLOD_LOG_ERROR, "egl: glReadPixels failed");
        return HLOD_ERR_UNSUPPORTED;
    }
    hlod_rgb_flip_rows(rgb, g->width, g->height); /* GL rows are bottom first */
    return HLOD_OK;
}
