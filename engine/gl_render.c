/*
 * gl_render.c - the OpenGL 3.3 core renderer (gl_render.h, engine.h).
 *
 * Design:
 * - No GL library is linked: every entry point is loaded through the
 *   caller's hlod_gl_get_proc into a table inside the renderer (GL_FUNCS
 *   below lists them), so two renderers, in one context or two, share
 *   nothing and the library holds no global state.
 * - A node is one VAO, one VBO holding the payload's sections one after the
 *   other exactly as stored (positions, normals, UVs, colours; no CPU
 *   interleaving, so an upload is one glBufferData plus one glBufferSubData
 *   per section), one 32-bit IBO, and a mipmapped (bilinear in the nearest
 *   level), repeating RGBA8 texture.  Missing sections are constant attributes set in begin (light
 *   grey colour); without normals a shader variant lights the face normal
 *   from derivatives.
 * - Camera-relative rendering: positions are floats relative to the node's
 *   origin; the vertex shader adds `offset` = origin - eye (double, rounded
 *   once by the caller) and applies proj * view-rotation, so no float ever
 *   holds a world coordinate.
 * - UVs follow OBJ/OpenGL (v = 0 at the image's bottom row, see
 *   preprocess/build_common.c and gltf_write.c) while pixels are stored top
 *   row first, so the top row lands at t = 0: the shader samples (u, 1 - v).
 * - Shading: a headlight (light at the eye) plus a hemispheric sky term with
 *   +z up (the generated city's up; for other data it is only a soft
 *   gradient), applied to texture, vertex colour or depth colour alike.
 *   Back faces are lit like front faces (scanned meshes are not closed).
 */
#include <assert.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <GL/glcorearb.h>

#include "gl_render.h"
#include "texture.h"
#include "texture_codec.h"

#ifndef GL_COMPRESSED_RGB_S3TC_DXT1_EXT
#define GL_COMPRESSED_RGB_S3TC_DXT1_EXT 0x83F0   /* EXT_texture_compression_s3tc */
#endif

/* Every GL function the renderer calls: (typedef, name without "gl"). */
#define GL_FUNCS(X)                                                  \
    X(PFNGLGETSTRINGPROC, GetString)                                 \
    X(PFNGLGETINTEGERVPROC, GetIntegerv)                             \
    X(PFNGLGETERRORPROC, GetError)                                   \
    X(PFNGLCREATESHADERPROC, CreateShader)                           \
    X(PFNGLSHADERSOURCEPROC, ShaderSource)                           \
    X(PFNGLCOMPILESHADERPROC, CompileShader)                         \
    X(PFNGLGETSHADERIVPROC, GetShaderiv)                             \
    X(PFNGLGETSHADERINFOLOGPROC, GetShaderInfoLog)                   \
    X(PFNGLDELETESHADERPROC, DeleteShader)                           \
    X(PFNGLCREATEPROGRAMPROC, CreateProgram)                         \
    X(PFNGLATTACHSHADERPROC, AttachShader)                           \
    X(PFNGLLINKPROGRAMPROC, LinkProgram)                             \
    X(PFNGLGETPROGRAMIVPROC, GetProgramiv)                           \
    X(PFNGLGETPROGRAMINFOLOGPROC, GetProgramInfoLog)                 \
    X(PFNGLDELETEPROGRAMPROC, DeleteProgram)                         \
    X(PFNGLGETUNIFORMLOCATIONPROC, GetUniformLocation)               \
    X(PFNGLUSEPROGRAMPROC, UseProgram)                               \
    X(PFNGLUNIFORM1IPROC, Uniform1i)                                 \
    X(PFNGLUNIFORM1FPROC, Uniform1f)                                 \
    X(PFNGLUNIFORM3FPROC, Uniform3f)                                 \
    X(PFNGLUNIFORMMATRIX4FVPROC, UniformMatrix4fv)                   \
    X(PFNGLGENVERTEXARRAYSPROC, GenVertexArrays)                     \
    X(PFNGLBINDVERTEXARRAYPROC, BindVertexArray)                     \
    X(PFNGLDELETEVERTEXARRAYSPROC, DeleteVertexArrays)               \
    X(PFNGLGENBUFFERSPROC, GenBuffers)                               \
    X(PFNGLBINDBUFFERPROC, BindBuffer)                               \
    X(PFNGLBUFFERDATAPROC, BufferData)                               \
    X(PFNGLBUFFERSUBDATAPROC, BufferSubData)                         \
    X(PFNGLDELETEBUFFERSPROC, DeleteBuffers)                         \
    X(PFNGLVERTEXATTRIBPOINTERPROC, VertexAttribPointer)             \
    X(PFNGLENABLEVERTEXATTRIBARRAYPROC, EnableVertexAttribArray)     \
    X(PFNGLVERTEXATTRIB4FPROC, VertexAttrib4f)                       \
    X(PFNGLGENTEXTURESPROC, GenTextures)                             \
    X(PFNGLBINDTEXTUREPROC, BindTexture)                             \
    X(PFNGLACTIVETEXTUREPROC, ActiveTexture)                         \
    X(PFNGLTEXIMAGE2DPROC, TexImage2D)                               \
    X(PFNGLTEXSUBIMAGE2DPROC, TexSubImage2D)                         \
    X(PFNGLCOMPRESSEDTEXIMAGE2DPROC, CompressedTexImage2D)           \
    X(PFNGLGETSTRINGIPROC, GetStringi)                               \
    X(PFNGLTEXPARAMETERIPROC, TexParameteri)                         \
    X(PFNGLDELETETEXTURESPROC, DeleteTextures)                       \
    X(PFNGLPIXELSTOREIPROC, PixelStorei)                             \
    X(PFNGLVIEWPORTPROC, Viewport)                                   \
    X(PFNGLCLEARCOLORPROC, ClearColor)                               \
    X(PFNGLCLEARPROC, Clear)                                         \
    X(PFNGLENABLEPROC, Enable)                                       \
    X(PFNGLDISABLEPROC, Disable)                                     \
    X(PFNGLDEPTHFUNCPROC, DepthFunc)                                 \
    X(PFNGLDEPTHMASKPROC, DepthMask)                                 \
    X(PFNGLBLENDFUNCPROC, BlendFunc)                                 \
    X(PFNGLCULLFACEPROC, CullFace)                                   \
    X(PFNGLFRONTFACEPROC, FrontFace)                                 \
    X(PFNGLPOLYGONMODEPROC, PolygonMode)                             \
    X(PFNGLDRAWELEMENTSPROC, DrawElements)                           \
    X(PFNGLDRAWARRAYSPROC, DrawArrays)                               \
    X(PFNGLFLUSHPROC, Flush)                                         \
    X(PFNGLREADPIXELSPROC, ReadPixels)                               \
    X(PFNGLFINISHPROC, Finish)                                       \
    X(PFNGLGENFRAMEBUFFERSPROC, GenFramebuffers)                     \
    X(PFNGLDELETEFRAMEBUFFERSPROC, DeleteFramebuffers)               \
    X(PFNGLBINDFRAMEBUFFERPROC, BindFramebuffer)                     \
    X(PFNGLCHECKFRAMEBUFFERSTATUSPROC, CheckFramebufferStatus)       \
    X(PFNGLGENRENDERBUFFERSPROC, GenRenderbuffers)                   \
    X(PFNGLDELETERENDERBUFFERSPROC, DeleteRenderbuffers)             \
    X(PFNGLBINDRENDERBUFFERPROC, BindRenderbuffer)                   \
    X(PFNGLRENDERBUFFERSTORAGEPROC, RenderbufferStorage)             \
    X(PFNGLFRAMEBUFFERRENDERBUFFERPROC, FramebufferRenderbuffer)     \
    X(PFNGLBLITFRAMEBUFFERPROC, BlitFramebuffer)                     \
    X(PFNGLTEXIMAGE3DPROC, TexImage3D)                               \
    X(PFNGLTEXSUBIMAGE3DPROC, TexSubImage3D)                         \
    X(PFNGLUNIFORM1IVPROC, Uniform1iv)                               \
    X(PFNGLUNIFORM1FVPROC, Uniform1fv)                               \
    X(PFNGLUNIFORM3FVPROC, Uniform3fv)                               \
    X(PFNGLCOLORMASKPROC, ColorMask)

typedef struct gl_table {
#define GL_MEMBER(type, name) type name;
    GL_FUNCS(GL_MEMBER)
#undef GL_MEMBER
} gl_table;

/* Vertex attribute locations (the shader's layout qualifiers). */
enum { ATTR_POSITION = 0, ATTR_NORMAL = 1, ATTR_UV = 2, ATTR_COLOR = 3 };

/* Fragment colour source (u_mode). */
enum { MODE_TEXTURE = 0, MODE_VERTEX_COLOR = 1, MODE_FLAT = 2 };

/* Colour of untextured geometry without vertex colours: hlod_material's
 * default diffuse. */
#define DEFAULT_GREY 0.8f
#define DEFAULT_GREY_BYTE 204 /* 0.8 x 255, exactly */

/* A batched node's vertex, as its batch buffer holds it (stride 28). */
typedef struct batch_vertex {
    float pos[3], nrm[3];
    uint8_t rgba[4];
} batch_vertex;

/* Vertices a batch buffer holds before it is drawn (28 MiB). */
#define BATCH_MAX_VERTICES (1u << 20)

struct hlod_renderer {
    gl_table gl;
    hlod_logger lg;
    struct program {
        GLuint id;
        GLint u_viewproj, u_offset, u_flat;
    } prog[2][3];               /* [normals][MODE_*] */
    const struct program *cur;  /* in use, between begin and end */
    int culling;                /* GL_CULL_FACE on, between begin and end */
    int no_culling;             /* hlod_renderer_set_backface_culling(0) */
    float vp[16];               /* this frame's view-projection */
    GLint max_texture;          /* GL_MAX_TEXTURE_SIZE */
    int s3tc;                   /* EXT_texture_compression_s3tc: BC1 uploads */
    int software;               /* a software rasteriser (GL_RENDERER) */
    int depth_colors, wireframe;
    float clear[3];
    hlod_depth_view depth_view; /* reads depth in place; NULL: glReadPixels */
    void *depth_view_user;
    struct {                    /* frames drawn small (hlod_gpu_begin_scaled) */
        GLuint fbo, rb[2];      /* colour and depth renderbuffers */
        uint32_t w, h;          /* their size */
        GLint draw_prev, read_prev; /* bound at begin: the image */
        uint32_t out_w, out_h;  /* the image the frame is scaled up to */
        int on;                 /* between begin_scaled and end */
        int failed;             /* could not be made (logged once) */
    } low;
    struct {                    /* splats (hlod_gpu_splats): one program, one buffer */
        GLuint prog, vao, vbo;
        GLint u_viewproj, u_size;
        size_t cap;             /* splats the buffer holds */
    } splat;
    struct {                    /* a frame splatted on the CPU (hlod_gpu_composite) */
        GLuint prog, vao, tex[2]; /* colour (RGBA8), depth (R32F) */
        GLint u_color, u_depth;
        uint32_t w, h;          /* the textures' size */
    } comp;
    uint32_t batch_tris;        /* hlod_renderer_set_batch */
    uint32_t draw_calls;        /* since hlod_gpu_begin */
    struct batch {              /* small nodes drawn together: [normals][culled] */
        batch_vertex *v;
        uint32_t *i;
        size_t nv, ni, cap_v, cap_i;
        GLuint vao, vbo, ibo;
        int failed;             /* could not grow: logged once */
    } batch[2][2];
    struct {                    /* the Grid-Lumigraph client (hlod_gpu_lumi_*) */
        GLuint prog, bg_prog, bg_vao, tex[2]; /* colour (RGB8), depth codes (R16) arrays */
        GLuint depth_prog;      /* the depth pre-pass */
        GLint d_viewproj, d_offset;
        GLint u_viewproj, u_offset, u_pt, u_w, u_slot, u_depth_par, u_hole, u_parallax;
        GLint bg_inv, bg_pt, bg_w, bg_slot, bg_clear, bg_depth_par, bg_parallax;
        uint32_t slots, size, depth_size;
        int prepassed;          /* the depth pre-pass ran this frame */
    } lumi;
};

/* The shaders come in variants chosen per draw (compiled once): NORMALS
 * when the payload has vertex normals, and the colour source MODE.  A
 * software rasteriser runs both sides of a branch for every fragment, so
 * nothing per draw is left to a runtime branch, and with normals the
 * lighting is computed per vertex: the fragment shader is one texture
 * fetch and one multiply. */
static const char *vertex_src =
    "layout(location = 0) in vec3 a_position;\n"
    "layout(location = 1) in vec3 a_normal;\n"
    "layout(location = 2) in vec2 a_uv;\n"
    "layout(location = 3) in vec4 a_color;\n"
    "uniform mat4 u_viewproj;\n"
    "uniform vec3 u_offset;\n"
    "#if NORMALS\n"
    "out float v_light;\n"
    "#else\n"
    "out vec3 v_rel;\n"
    "#endif\n"
    "out vec2 v_uv;\n"
    "out vec4 v_color;\n"
    "void main() {\n"
    "    vec3 rel = a_position + u_offset;\n"
    "#if NORMALS\n"
    "    float d = length(rel);\n"
    "    vec3 to_eye = d > 0.0 ? -rel / d : vec3(0.0, 0.0, 1.0);\n"
    "    float len = length(a_normal);\n"
    "    vec3 n = len > 0.0 ? a_normal / len : to_eye;\n"
    /*   back faces are lit like front faces */
    "    if (dot(n, to_eye) < 0.0) n = -n;\n"
    "    v_light = 0.20 + 0.55 * abs(dot(n, to_eye)) + 0.25 * (0.5 + 0.5 * n.z);\n"
    "#else\n"
    "    v_rel = rel;\n"
    "#endif\n"
    "    v_uv = vec2(a_uv.x, 1.0 - a_uv.y);\n"  /* v = 0 is the bottom row */
    "    v_color = a_color;\n"
    "    gl_Position = u_viewproj * vec4(rel, 1.0);\n"
    "}\n";

static const char *fragment_src =
    "#if NORMALS\n"
    "in float v_light;\n"
    "#else\n"
    "in vec3 v_rel;\n"
    "#endif\n"
    "in vec2 v_uv;\n"
    "in vec4 v_color;\n"
    "uniform vec3 u_flat;\n"
    "uniform sampler2D u_tex;\n"
    "out vec4 o_color;\n"
    "void main() {\n"
    "#if NORMALS\n"
    "    float light = v_light;\n"
    "#else\n"
    /*   no normals in the payload: the face normal, towards the eye */
    "    vec3 to_eye = -v_rel;\n"
    "    float d = length(to_eye);\n"
    "    to_eye = d > 0.0 ? to_eye / d : vec3(0.0, 0.0, 1.0);\n"
    "    vec3 n = cross(dFdx(v_rel), dFdy(v_rel));\n"
    "    if (dot(n, to_eye) < 0.0) n = -n;\n"
    "    float len = length(n);\n"
    "    n = len > 0.0 ? n / len : to_eye;\n"
    /*   1.0 for a face seen head-on whose normal is straight up */
    "    float light = 0.20 + 0.55 * abs(dot(n, to_eye)) + 0.25 * (0.5 + 0.5 * n.z);\n"
    "#endif\n"
    "#if MODE == 0\n"
    "    vec3 base = texture(u_tex, v_uv).rgb;\n"
    "#elif MODE == 1\n"
    "    vec3 base = v_color.rgb;\n"
    "#else\n"
    "    vec3 base = u_flat;\n"
    "#endif\n"
    "    o_color = vec4(base * light, 1.0);\n"
    "}\n";

/* Splats: a point of u_size pixels, its colour as given (lit by the
 * caller), at its camera-relative position. */
static const char *splat_vertex_src =
    "layout(location = 0) in vec3 a_position;\n"
    "layout(location = 3) in vec4 a_color;\n"
    "uniform mat4 u_viewproj;\n"
    "uniform float u_size;\n"
    "out vec4 v_color;\n"
    "void main() {\n"
    "    v_color = a_color;\n"
    "    gl_PointSize = u_size;\n"
    "    gl_Position = u_viewproj * vec4(a_position, 1.0);\n"
    "}\n";

static const char *splat_fragment_src =
    "in vec4 v_color;\n"
    "out vec4 o_color;\n"
    "void main() {\n"
    "    o_color = v_color;\n"
    "}\n";

/* A frame splatted on the CPU: each pixel with a depth under 1 written
 * with its colour and depth, depth tested (one triangle over the
 * viewport). */
static const char *comp_vertex_src =
    "void main() {\n"
    "    vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);\n"
    "    gl_Position = vec4(p, 0.0, 1.0);\n"
    "}\n";

static const char *comp_fragment_src =
    "uniform sampler2D u_color;\n"
    "uniform sampler2D u_depth;\n"
    "out vec4 o_color;\n"
    "void main() {\n"
    "    ivec2 q = ivec2(gl_FragCoord.xy);\n"
    "    float d = texelFetch(u_depth, q, 0).r;\n"
    "    if (d >= 1.0) discard;\n"
    "    gl_FragDepth = d;\n"
    "    o_color = vec4(texelFetch(u_color, q, 0).rgb, 1.0);\n"
    "}\n";

/* Depth-colour mode: one colour per hierarchy level, cycling. */
static const float depth_palette[8][3] = {
    {0.90f, 0.30f, 0.25f}, {0.95f, 0.65f, 0.20f}, {0.90f, 0.90f, 0.30f},
    {0.40f, 0.80f, 0.35f}, {0.30f, 0.75f, 0.85f}, {0.35f, 0.45f, 0.90f},
    {0.70f, 0.40f, 0.85f}, {0.90f, 0.50f, 0.70f},
};

/* Converts a loader's object pointer to a function pointer without a cast
 * between the two kinds (not defined by ISO C, defined by POSIX). */
#define LOAD_PROC(dst, ptr) memcpy(&(dst), &(ptr), sizeof(dst))

static int load_table(gl_table *gl, hlod_gl_get_proc get_proc, const hlod_logger *lg)
{
    static_assert(sizeof(void *) == sizeof(PFNGLCLEARPROC), "function and object pointers differ");
#define GL_LOAD(type, name)                                                    \
    {                                                                          \
        void *p_ = get_proc("gl" #name);                                       \
        if (!p_) {                                                             \
            hlod_logf(lg, HLOD_LOG_ERROR, "renderer: no GL function gl%s", #name); \
            return 0;                                                          \
        }                                                                      \
        LOAD_PROC(gl->name, p_);                                               \
    }
    GL_FUNCS(GL_LOAD)
#undef GL_LOAD
    return 1;
}

/* Returns GL_NO_ERROR, GL_OUT_OF_MEMORY if any pending error is that, else
 * the first pending error; clears them all. */
static GLenum take_errors(const gl_table *gl)
{
    GLenum first = GL_NO_ERROR, e;
    for (int i = 0; i < 16 && (e = gl->GetError()) != GL_NO_ERROR; i++)
        if (first == GL_NO_ERROR || e == GL_OUT_OF_MEMORY)
            first = e;
    return first;
}

static GLuint compile(hlod_renderer *r, GLenum type, const char *defines, const char *src)
{
    const gl_table *gl = &r->gl;
    GLuint sh = gl->CreateShader(type);
    if (!sh)
        return 0;
    const char *parts[3] = {"#version 330 core\n", defines, src};
    gl->ShaderSource(sh, 3, parts, NULL);
    gl->CompileShader(sh);
    GLint ok = 0;
    gl->GetShaderiv(sh, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        char log[1024] = "";
        gl->GetShaderInfoLog(sh, sizeof log, NULL, log);
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: %s shader (%s): %s",
                  type == GL_VERTEX_SHADER ? "vertex" : "fragment", defines, log);
        gl->DeleteShader(sh);
        return 0;
    }
    return sh;
}

/* Compiles vs_src and fs_src with defines and links them; 0 (logged) on
 * failure. */
static GLuint link_program(hlod_renderer *r, const char *defines, const char *vs_src,
                           const char *fs_src)
{
    const gl_table *gl = &r->gl;
    GLuint vs = compile(r, GL_VERTEX_SHADER, defines, vs_src);
    GLuint fs = vs ? compile(r, GL_FRAGMENT_SHADER, defines, fs_src) : 0;
    GLuint prog = fs ? gl->CreateProgram() : 0;
    if (prog) {
        gl->AttachShader(prog, vs);
        gl->AttachShader(prog, fs);
        gl->LinkProgram(prog);
        GLint ok = 0;
        gl->GetProgramiv(prog, GL_LINK_STATUS, &ok);
        if (!ok) {
            char log[1024] = "";
            gl->GetProgramInfoLog(prog, sizeof log, NULL, log);
            hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: link: %s", log);
            gl->DeleteProgram(prog);
            prog = 0;
        }
    }
    /* flagged for deletion; they live on while attached to the program */
    if (vs)
        gl->DeleteShader(vs);
    if (fs)
        gl->DeleteShader(fs);
    return prog;
}

static int build_program(hlod_renderer *r, int normals, int mode, struct program *out)
{
    const gl_table *gl = &r->gl;
    char defines[64];
    snprintf(defines, sizeof defines, "#define NORMALS %d\n#define MODE %d\n", normals, mode);
    GLuint prog = link_program(r, defines, vertex_src, fragment_src);
    if (!prog)
        return 0;
    out->id = prog;
    out->u_viewproj = gl->GetUniformLocation(prog, "u_viewproj");
    out->u_offset = gl->GetUniformLocation(prog, "u_offset");
    out->u_flat = gl->GetUniformLocation(prog, "u_flat");
    gl->UseProgram(prog);
    gl->Uniform1i(gl->GetUniformLocation(prog, "u_tex"), 0);
    gl->UseProgram(0);
    return 1;
}

static void delete_programs(hlod_renderer *r)
{
    r->gl.UseProgram(0);
    for (int n = 0; n < 2; n++)
        for (int m = 0; m < 3; m++)
            if (r->prog[n][m].id)
                r->gl.DeleteProgram(r->prog[n][m].id);
    if (r->splat.prog)
        r->gl.DeleteProgram(r->splat.prog);
    if (r->splat.vbo)
        r->gl.DeleteBuffers(1, &r->splat.vbo);
    if (r->splat.vao)
        r->gl.DeleteVertexArrays(1, &r->splat.vao);
    memset(&r->splat, 0, sizeof r->splat);
    if (r->comp.prog)
        r->gl.DeleteProgram(r->comp.prog);
    if (r->comp.vao)
        r->gl.DeleteVertexArrays(1, &r->comp.vao);
    if (r->comp.tex[0])
        r->gl.DeleteTextures(2, r->comp.tex);
    memset(&r->comp, 0, sizeof r->comp);
}

static int build_splat_program(hlod_renderer *r)
{
    GLuint prog = link_program(r, "", splat_vertex_src, splat_fragment_src);
    if (!prog)
        return 0;
    r->splat.prog = prog;
    r->splat.u_viewproj = r->gl.GetUniformLocation(prog, "u_viewproj");
    r->splat.u_size = r->gl.GetUniformLocation(prog, "u_size");
    return 1;
}

static int build_programs(hlod_renderer *r)
{
    for (int n = 0; n < 2; n++)
        for (int m = 0; m < 3; m++)
            if (!build_program(r, n, m, &r->prog[n][m])) {
                delete_programs(r);
                return 0;
            }
    if (!build_splat_program(r)) {
        delete_programs(r);
        return 0;
    }
    return 1;
}

/* called from the render thread, context current */
hlod_result hlod_renderer_create(hlod_gl_get_proc get_proc, const hlod_logger *lg,
                                 hlod_renderer **out)
{
    if (out)
        *out = NULL;
    if (!get_proc || !out)
        return HLOD_ERR_INVALID_ARG;
    hlod_renderer *r = calloc(1, sizeof *r);
    if (!r)
        return HLOD_ERR_NOMEM;
    if (lg)
        r->lg = *lg;
    if (!load_table(&r->gl, get_proc, &r->lg)) {
        free(r);
        return HLOD_ERR_UNSUPPORTED;
    }
    const gl_table *gl = &r->gl;
    const GLubyte *version = gl->GetString(GL_VERSION);
    if (!version) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: no current GL context");
        free(r);
        return HLOD_ERR_UNSUPPORTED;
    }
    take_errors(gl);
    GLint major = 0, minor = 0;
    gl->GetIntegerv(GL_MAJOR_VERSION, &major);   /* an error (left 0) before 3.0 */
    gl->GetIntegerv(GL_MINOR_VERSION, &minor);
    take_errors(gl);
    if (major * 10 + minor < 33) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: needs OpenGL 3.3, context is %s",
                  (const char *)version);
        free(r);
        return HLOD_ERR_UNSUPPORTED;
    }
    gl->GetIntegerv(GL_MAX_TEXTURE_SIZE, &r->max_texture);
    if (r->max_texture < 1024)
        r->max_texture = 1024;   /* the 3.3 minimum, should the query fail */
    GLint next = 0;
    gl->GetIntegerv(GL_NUM_EXTENSIONS, &next);
    for (GLint i = 0; i < next; i++) {
        const char *e = (const char *)gl->GetStringi(GL_EXTENSIONS, (GLuint)i);
        r->s3tc |= e && !strcmp(e, "GL_EXT_texture_compression_s3tc");
    }
    const char *name = (const char *)gl->GetString(GL_RENDERER);
    r->software = name && (strstr(name, "llvmpipe") || strstr(name, "softpipe") ||
                           strstr(name, "swrast") || strstr(name, "Software"));
    take_errors(gl);
    if (!build_programs(r)) {
        free(r);
        return HLOD_ERR_UNSUPPORTED;
    }
    r->clear[0] = 0.62f;   /* a pale sky */
    r->clear[1] = 0.74f;
    r->clear[2] = 0.86f;
    *out = r;
    return HLOD_OK;
}

static void lumi_free(hlod_renderer *r);

/* called from the render thread, context current */
static void batches_free(hlod_renderer *r)
{
    for (int n = 0; n < 2; n++)
        for (int c = 0; c < 2; c++) {
            struct batch *b = &r->batch[n][c];
            if (b->vao)
                r->gl.DeleteVertexArrays(1, &b->vao);
            if (b->vbo)
                r->gl.DeleteBuffers(1, &b->vbo);
            if (b->ibo)
                r->gl.DeleteBuffers(1, &b->ibo);
            free(b->v);
            free(b->i);
            memset(b, 0, sizeof *b);
        }
}

void hlod_renderer_set_batch(hlod_renderer *r, uint32_t max_tris)
{
    if (r)
        r->batch_tris = max_tris;
}

uint32_t hlod_gpu_draw_calls(const hlod_renderer *r)
{
    return r ? r->draw_calls : 0;
}

/* called from the render thread, context current */
static void delete_low(hlod_renderer *r)
{
    if (r->low.fbo)
        r->gl.DeleteFramebuffers(1, &r->low.fbo);
    if (r->low.rb[0])
        r->gl.DeleteRenderbuffers(2, r->low.rb);
    r->low.fbo = r->low.rb[0] = r->low.rb[1] = 0;
    r->low.w = r->low.h = 0;
}

void hlod_renderer_destroy(hlod_renderer *r)
{
    if (!r)
        return;
    delete_low(r);
    lumi_free(r);
    batches_free(r);
    delete_programs(r);
    free(r);
}

void hlod_renderer_set_depth_colors(hlod_renderer *r, int on)
{
    if (r)
        r->depth_colors = on != 0;
}

void hlod_renderer_set_backface_culling(hlod_renderer *r, int on)
{
    if (r)
        r->no_culling = on == 0;
}

void hlod_renderer_set_wireframe(hlod_renderer *r, int on)
{
    if (r)
        r->wireframe = on != 0;
}

void hlod_renderer_set_clear_color(hlod_renderer *r, float red, float green, float blue)
{
    if (r) {
        r->clear[0] = red;
        r->clear[1] = green;
        r->clear[2] = blue;
    }
}

/* ---- nodes ---- */

/* called from the render thread */
void hlod_gpu_release(hlod_renderer *r, hlod_gpu_node *g)
{
    if (!g)
        return;
    assert(r || (!g->vao && !g->vbo && !g->ibo && !g->tex));
    if (r) {
        const gl_table *gl = &r->gl;
        if (g->vao)
            gl->DeleteVertexArrays(1, &g->vao);
        if (g->vbo)
            gl->DeleteBuffers(1, &g->vbo);
        if (g->ibo)
            gl->DeleteBuffers(1, &g->ibo);
        if (g->tex)
            gl->DeleteTextures(1, &g->tex);
    }
    free(g->cpu);
    memset(g, 0, sizeof *g);
}

/* Adds one payload section to the bound VBO at *offset and points attribute
 * `attr` at it. */
static void add_section(const gl_table *gl, GLuint attr, GLint size, GLenum type,
                        GLboolean normalized, const void *data, size_t bytes, size_t *offset)
{
    gl->BufferSubData(GL_ARRAY_BUFFER, (GLintptr)*offset, (GLsizeiptr)bytes, data);
    gl->VertexAttribPointer(attr, size, type, normalized, 0, (const void *)(uintptr_t)*offset);
    gl->EnableVertexAttribArray(attr);
    *offset += bytes;
}

/* Texels (RGBA from BC1, grey from BC4) of a payload holding blocks, for a
 * context that cannot take them: the chain in own->tex_memory. */
static int expand_blocks(hlod_store_payload *own)
{
    uint32_t oc = 0;
    uint8_t *t = hlod_bc_decode_chain(own->pixels, own->tex_width, own->tex_height,
                                      own->tex_channels, &oc);
    if (!t)
        return 0;
    own->pixels = t;
    own->tex_memory = t;
    own->tex_channels = oc;
    own->tex_format = HLOD_TEXFMT_TEXELS;
    return 1;
}

/* The stored blocks, level by level (BC1 through S3TC, BC4 as RGTC1). */
static uint64_t upload_blocks(const gl_table *gl, const hlod_store_payload *p)
{
    GLenum fmt = p->tex_channels == 3 ? GL_COMPRESSED_RGB_S3TC_DXT1_EXT : GL_COMPRESSED_RED_RGTC1;
    const uint8_t *level = p->pixels;
    uint64_t total = 0;
    for (uint32_t l = 0; l < p->tex_levels; l++) {
        uint32_t lw, lh;
        hlod_tex_level_size(p->tex_width, p->tex_height, l, &lw, &lh);
        size_t bytes = hlod_bc_level_bytes(lw, lh);
        gl->CompressedTexImage2D(GL_TEXTURE_2D, (GLint)l, fmt, (GLsizei)lw, (GLsizei)lh, 0,
                                 (GLsizei)bytes, level);
        level += bytes;
        total += bytes;
    }
    return total;
}

/* Texture of 1..4 channels: grey, grey + alpha, RGB, RGBA, with its mip
 * chain.  The loader thread builds the chain (texture.h); a payload that
 * comes without one (read on this thread) gets it here.  Each level is then
 * a plain copy: glGenerateMipmap and an RGB-to-RGBA conversion cost a
 * software GL 2-9x as much on this thread.  Block-coded textures
 * (tex_format HLOD_TEXFMT_BC) are uploaded as their blocks, level by
 * level, or expanded here on a GL without S3TC.  Returns the bytes the
 * driver holds, or 0 when the chain cannot be allocated. */
static uint64_t upload_texture(const hlod_renderer *r, const hlod_store_payload *p, GLuint tex)
{
    static const GLenum internal[4] = {GL_R8, GL_RG8, GL_RGBA8, GL_RGBA8};
    static const GLenum format[4] = {GL_RED, GL_RG, GL_RGB, GL_RGBA};
    const gl_table *gl = &r->gl;
    hlod_store_payload own = *p;
    own.tex_memory = NULL;
    int blocks = own.tex_format == HLOD_TEXFMT_BC;
    if (blocks && own.tex_channels == 3 && !r->s3tc) {
        if (!expand_blocks(&own))
            return 0;
        blocks = 0;
    }
    if (!blocks && !own.tex_levels &&
        (hlod_texture_prepare(&own) != HLOD_OK || !own.tex_levels))
        return 0;
    int c = (int)own.tex_channels - 1;
    gl->BindTexture(GL_TEXTURE_2D, tex);
    gl->PixelStorei(GL_UNPACK_ALIGNMENT, 1);   /* rows are w * channels bytes */
    uint64_t driver_bytes = 0;
    if (blocks) {
        driver_bytes = upload_blocks(gl, &own);
    } else {
        const uint8_t *level = own.pixels;
        uint32_t w = own.tex_width, h = own.tex_height;
        for (uint32_t l = 0; l < own.tex_levels; l++) {
            gl->TexImage2D(GL_TEXTURE_2D, (GLint)l, (GLint)internal[c], (GLsizei)w, (GLsizei)h,
                           0, format[c], GL_UNSIGNED_BYTE, level);
            level += (size_t)w * h * own.tex_channels;
            w = w > 1 ? w / 2 : 1;
            h = h > 1 ? h / 2 : 1;
        }
        /* drivers pad RGB8 texels to 4 bytes; the mip chain adds a third */
        uint64_t texel = c == 2 ? 4 : (uint64_t)c + 1;
        uint64_t base = (uint64_t)own.tex_width * own.tex_height * texel;
        driver_bytes = base + base / 3;
    }
    gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAX_LEVEL, (GLint)own.tex_levels - 1);
    free(own.tex_memory);
    if (c <= 1) {   /* grey in red (alpha in green): replicate, as luminance did */
        gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_SWIZZLE_G, GL_RED);
        gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_SWIZZLE_B, GL_RED);
        gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_SWIZZLE_A, c == 1 ? GL_GREEN : GL_ONE);
    }
    /* bilinear in the nearest mip level: trilinear cost a software
     * rasteriser 12-27% of a street-level frame for a barely visible gain */
    gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR_MIPMAP_NEAREST);
    gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
    gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_S, GL_REPEAT);
    gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_WRAP_T, GL_REPEAT);
    gl->BindTexture(GL_TEXTURE_2D, 0);
    return driver_bytes;
}

/* A small untextured node kept on the CPU for the batches: its vertices
 * (node-local, as the payload holds them; light grey without colours),
 * then its indices. */
static hlod_result upload_batched(const hlod_store_payload *p, hlod_gpu_node *out)
{
    size_t n = p->vertex_count, bytes = n * sizeof(batch_vertex) + (size_t)p->index_count * 4;
    batch_vertex *v = malloc(bytes);
    if (!v)
        return HLOD_ERR_NOMEM;
    for (size_t k = 0; k < n; k++) {
        memcpy(v[k].pos, p->positions + 3 * k, sizeof v[k].pos);
        if (p->normals)
            memcpy(v[k].nrm, p->normals + 3 * k, sizeof v[k].nrm);
        else
            v[k].nrm[0] = v[k].nrm[1] = v[k].nrm[2] = 0;
        if (p->colors)
            memcpy(v[k].rgba, p->colors + 4 * k, 4);
        else
            v[k].rgba[0] = v[k].rgba[1] = v[k].rgba[2] = DEFAULT_GREY_BYTE, v[k].rgba[3] = 255;
    }
    memcpy(v + n, p->indices, (size_t)p->index_count * 4);
    out->cpu = v;
    out->vertex_count = (uint32_t)n;
    out->index_count = p->index_count;
    out->tex_index_count = 0;
    out->bytes = bytes;
    out->flags = (p->normals ? HLOD_GPU_NORMALS : 0) | HLOD_GPU_BATCHED;
    return HLOD_OK;
}

/* called from the render thread, context current */
hlod_result hlod_gpu_upload(hlod_renderer *r, const hlod_store_payload *p, hlod_gpu_node *out)
{
    if (out)
        memset(out, 0, sizeof *out);
    if (!r || !p || !out || !p->vertex_count || !p->index_count || p->index_count % 3 ||
        !p->positions || !p->indices || (uint64_t)p->tex_tri_count * 3 > p->index_count)
        return HLOD_ERR_INVALID_ARG;
    if (p->pixels && (!p->tex_width || !p->tex_height || p->tex_channels < 1 ||
                      p->tex_channels > 4))
        return HLOD_ERR_INVALID_ARG;
    if (p->index_count > INT32_MAX) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: node %u: %u indices are too many to draw",
                  p->node, p->index_count);
        return HLOD_ERR_UNSUPPORTED;
    }
    /* textured triangles without a texture (or UVs) draw with their colour */
    int textured = p->pixels && p->uvs && p->tex_tri_count;
    if (textured && (p->tex_width > (uint32_t)r->max_texture ||
                     p->tex_height > (uint32_t)r->max_texture)) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: node %u: texture %ux%u over the GL limit %d",
                  p->node, p->tex_width, p->tex_height, r->max_texture);
        return HLOD_ERR_UNSUPPORTED;
    }
    if (!textured && r->batch_tris && p->index_count / 3 <= r->batch_tris)
        return upload_batched(p, out);
    const gl_table *gl = &r->gl;
    take_errors(gl);   /* errors from before are not this upload's */

    size_t n = p->vertex_count;
    size_t vbo_bytes = n * 12 + (p->normals ? n * 12 : 0) + (p->uvs ? n * 8 : 0) +
                       (p->colors ? n * 4 : 0);
    size_t ibo_bytes = (size_t)p->index_count * 4;
    gl->GenVertexArrays(1, &out->vao);
    gl->BindVertexArray(out->vao);
    gl->GenBuffers(1, &out->vbo);
    gl->BindBuffer(GL_ARRAY_BUFFER, out->vbo);
    gl->BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)vbo_bytes, NULL, GL_STATIC_DRAW);
    size_t off = 0;
    add_section(gl, ATTR_POSITION, 3, GL_FLOAT, GL_FALSE, p->positions, n * 12, &off);
    if (p->normals)
        add_section(gl, ATTR_NORMAL, 3, GL_FLOAT, GL_FALSE, p->normals, n * 12, &off);
    if (p->uvs)
        add_section(gl, ATTR_UV, 2, GL_FLOAT, GL_FALSE, p->uvs, n * 8, &off);
    if (p->colors)
        add_section(gl, ATTR_COLOR, 4, GL_UNSIGNED_BYTE, GL_TRUE, p->colors, n * 4, &off);
    gl->GenBuffers(1, &out->ibo);
    gl->BindBuffer(GL_ELEMENT_ARRAY_BUFFER, out->ibo);   /* VAO state */
    gl->BufferData(GL_ELEMENT_ARRAY_BUFFER, (GLsizeiptr)ibo_bytes, p->indices, GL_STATIC_DRAW);
    gl->BindVertexArray(0);
    gl->BindBuffer(GL_ARRAY_BUFFER, 0);
    out->bytes = vbo_bytes + ibo_bytes;
    if (textured) {
        gl->GenTextures(1, &out->tex);
        uint64_t tex_bytes = upload_texture(r, p, out->tex);
        if (!tex_bytes) {
            take_errors(gl);
            hlod_gpu_release(r, out);
            return HLOD_ERR_NOMEM;
        }
        out->bytes += tex_bytes;
    }
    out->index_count = p->index_count;
    out->tex_index_count = textured ? 3 * p->tex_tri_count : 0;
    out->flags = p->normals ? HLOD_GPU_NORMALS : 0;

    GLenum err = take_errors(gl);
    if (err == GL_NO_ERROR)
        return HLOD_OK;
    hlod_gpu_release(r, out);
    if (err == GL_OUT_OF_MEMORY) {
        hlod_logf(&r->lg, HLOD_LOG_WARN, "renderer: node %u: out of GPU memory", p->node);
        return HLOD_ERR_NOMEM;
    }
    hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: node %u: GL error 0x%04x on upload", p->node,
              (unsigned)err);
    return HLOD_ERR_UNSUPPORTED;
}

/* ---- frame ---- */

/* called from the render thread, context current */
void hlod_gpu_begin(hlod_renderer *r, const hlod_camera *cam)
{
    assert(r && cam);
    const gl_table *gl = &r->gl;
    /* camera-relative view-projection: proj * rotation, in double */
    double m[16];
    hlod_camera_view_proj(cam, m);
    float vp[16];
    for (int k = 0; k < 16; k++)
        vp[k] = (float)m[k];
    gl->Viewport(0, 0, (GLsizei)cam->width, (GLsizei)cam->height);
    gl->ClearColor(r->clear[0], r->clear[1], r->clear[2], 1.0f);
    gl->Enable(GL_DEPTH_TEST);
    gl->DepthFunc(GL_LESS);
    gl->CullFace(GL_BACK);
    gl->FrontFace(GL_CCW);
    gl->Disable(GL_CULL_FACE);
    r->culling = 0;
    gl->Disable(GL_BLEND);
    gl->PolygonMode(GL_FRONT_AND_BACK, r->wireframe ? GL_LINE : GL_FILL);
    gl->DepthMask(GL_TRUE); /* a clear writes depth only through the mask */
    gl->Clear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
    for (int n = 0; n < 2; n++)
        for (int m = 0; m < 3; m++) {
            gl->UseProgram(r->prog[n][m].id);
            gl->UniformMatrix4fv(r->prog[n][m].u_viewproj, 1, GL_FALSE, vp);
        }
    memcpy(r->vp, vp, sizeof vp);
    r->cur = NULL; /* the loop left prog[1][2] in use: the first draw binds its own */
    r->draw_calls = 0;
    for (int n = 0; n < 2; n++)
        for (int c = 0; c < 2; c++)
            r->batch[n][c].nv = r->batch[n][c].ni = 0;
    gl->ActiveTexture(GL_TEXTURE0);
    /* what nodes without these sections read (current attribute values) */
    gl->VertexAttrib4f(ATTR_NORMAL, 0, 0, 0, 0);
    gl->VertexAttrib4f(ATTR_UV, 0, 0, 0, 1);
    gl->VertexAttrib4f(ATTR_COLOR, DEFAULT_GREY, DEFAULT_GREY, DEFAULT_GREY, 1);
}

/* Makes program [normals][mode] current and places the node. */
static const struct program *use(hlod_renderer *r, int normals, int mode, const float off[3])
{
    const struct program *p = &r->prog[normals][mode];
    if (p != r->cur) {
        r->gl.UseProgram(p->id);
        r->cur = p;
    }
    r->gl.Uniform3f(p->u_offset, off[0], off[1], off[2]);
    return p;
}

/* Back faces culled (cull) or drawn, from here on in the frame. */
static void set_culling(hlod_renderer *r, int cull)
{
    if (cull == r->culling)
        return;
    if (cull)
        r->gl.Enable(GL_CULL_FACE);
    else
        r->gl.Disable(GL_CULL_FACE);
    r->culling = cull;
}

/* Draws batch [normals][cull] in one call and empties it. */
static void flush_batch(hlod_renderer *r, int normals, int cull)
{
    struct batch *b = &r->batch[normals][cull];
    if (!b->ni)
        return;
    const gl_table *gl = &r->gl;
    if (!b->vao) {
        gl->GenVertexArrays(1, &b->vao);
        gl->GenBuffers(1, &b->vbo);
        gl->GenBuffers(1, &b->ibo);
        gl->BindVertexArray(b->vao);
        gl->BindBuffer(GL_ARRAY_BUFFER, b->vbo);
        gl->VertexAttribPointer(ATTR_POSITION, 3, GL_FLOAT, GL_FALSE, sizeof(batch_vertex),
                                (const void *)offsetof(batch_vertex, pos));
        gl->EnableVertexAttribArray(ATTR_POSITION);
        if (normals) {
            gl->VertexAttribPointer(ATTR_NORMAL, 3, GL_FLOAT, GL_FALSE, sizeof(batch_vertex),
                                    (const void *)offsetof(batch_vertex, nrm));
            gl->EnableVertexAttribArray(ATTR_NORMAL);
        }
        gl->VertexAttribPointer(ATTR_COLOR, 4, GL_UNSIGNED_BYTE, GL_TRUE, sizeof(batch_vertex),
                                (const void *)offsetof(batch_vertex, rgba));
        gl->EnableVertexAttribArray(ATTR_COLOR);
        gl->BindBuffer(GL_ELEMENT_ARRAY_BUFFER, b->ibo);   /* VAO state */
    }
    gl->BindVertexArray(b->vao);
    gl->BindBuffer(GL_ARRAY_BUFFER, b->vbo);
    gl->BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)(b->nv * sizeof(batch_vertex)), b->v,
                   GL_STREAM_DRAW);
    gl->BufferData(GL_ELEMENT_ARRAY_BUFFER, (GLsizeiptr)(b->ni * 4), b->i, GL_STREAM_DRAW);
    set_culling(r, cull);
    static const float zero[3] = {0, 0, 0};   /* positions are camera-relative already */
    use(r, normals, MODE_VERTEX_COLOR, zero);
    gl->DrawElements(GL_TRIANGLES, (GLsizei)b->ni, GL_UNSIGNED_INT, NULL);
    r->draw_calls++;
    b->nv = b->ni = 0;
}

/* Draws every batch (before the frame is read, waited on or blended
 * over); 1 when one was drawn. */
static int flush_batches(hlod_renderer *r)
{
    int drew = 0;
    for (int n = 0; n < 2; n++)
        for (int c = 0; c < 2; c++) {
            drew |= r->batch[n][c].ni > 0;
            flush_batch(r, n, c);
        }
    return drew;
}

/* *p (of *cap elements of size elem) holds at least need; 0 when out of
 * memory (*p unchanged). */
static int grow(void **p, size_t *cap, size_t need, size_t elem, size_t first)
{
    if (need <= *cap)
        return 1;
    size_t c = *cap ? 2 * *cap : first;
    while (c < need)
        c *= 2;
    void *q = realloc(*p, c * elem);
    if (!q)
        return 0;
    *p = q;
    *cap = c;
    return 1;
}

/* Room in b for nv more vertices and ni more indices; 0 when out of memory. */
static int batch_room(struct batch *b, size_t nv, size_t ni)
{
    void *v = b->v, *i = b->i;
    int ok = grow(&v, &b->cap_v, b->nv + nv, sizeof *b->v, 4096) &&
             grow(&i, &b->cap_i, b->ni + ni, sizeof *b->i, 8192);
    b->v = v;
    b->i = i;
    return ok;
}

/* Appends count indices of batched node g from first, its vertices moved
 * by off (float adds, as the vertex shader's a_position + u_offset), in
 * colour flat when given (depth-colour mode). */
static void batch_append(hlod_renderer *r, const hlod_gpu_node *g, const float off[3],
                         uint32_t first, uint32_t count, int cull, const float *flat)
{
    int normals = (g->flags & HLOD_GPU_NORMALS) != 0;
    struct batch *b = &r->batch[normals][cull];
    size_t nv = g->vertex_count;
    if (b->nv && b->nv + nv > BATCH_MAX_VERTICES)
        flush_batch(r, normals, cull);
    if (!batch_room(b, nv, count)) {
        flush_batch(r, normals, cull);
        if (!batch_room(b, nv, count)) {
            if (!b->failed)
                hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: out of memory batching draws");
            b->failed = 1;
            return; /* this node is missing from the frame */
        }
    }
    const batch_vertex *src = g->cpu;
    batch_vertex *dst = b->v + b->nv;
    uint8_t rgba[4] = {0, 0, 0, 255};
    if (flat)
        for (int k = 0; k < 3; k++)
            rgba[k] = (uint8_t)(flat[k] * 255.0f + 0.5f);
    for (size_t k = 0; k < nv; k++) {
        dst[k] = src[k];
        dst[k].pos[0] = src[k].pos[0] + off[0];
        dst[k].pos[1] = src[k].pos[1] + off[1];
        dst[k].pos[2] = src[k].pos[2] + off[2];
        if (flat)
            memcpy(dst[k].rgba, rgba, 4);
    }
    const uint32_t *idx = (const uint32_t *)(src + nv) + first;
    uint32_t base = (uint32_t)b->nv, *out = b->i + b->ni;
    for (uint32_t k = 0; k < count; k++)
        out[k] = idx[k] + base;
    b->nv += nv;
    b->ni += count;
}

/* called from the render thread, between begin and end */
void hlod_gpu_draw(hlod_renderer *r, const hlod_gpu_node *g, const double offset[3],
                   uint32_t depth)
{
    assert(r && g && offset);
    const float off[3] = {(float)offset[0], (float)offset[1], (float)offset[2]};
    int cull = (g->flags & HLOD_GPU_CULL) && !r->wireframe && !r->no_culling;
    if (g->flags & HLOD_GPU_BATCHED) {
        batch_append(r, g, off, 0, g->index_count, cull,
                     r->depth_colors ? depth_palette[depth % 8] : NULL);
        return;
    }
    if (!g->vao || !g->index_count)
        return;
    const gl_table *gl = &r->gl;
    int normals = (g->flags & HLOD_GPU_NORMALS) != 0;
    set_culling(r, cull);
    gl->BindVertexArray(g->vao);
    if (r->depth_colors) {
        const float *c = depth_palette[depth % 8];
        const struct program *p = use(r, normals, MODE_FLAT, off);
        gl->Uniform3f(p->u_flat, c[0], c[1], c[2]);
        gl->DrawElements(GL_TRIANGLES, (GLsizei)g->index_count, GL_UNSIGNED_INT, NULL);
        r->draw_calls++;
        return;
    }
    if (g->tex_index_count) {
        gl->BindTexture(GL_TEXTURE_2D, g->tex);
        use(r, normals, MODE_TEXTURE, off);
        gl->DrawElements(GL_TRIANGLES, (GLsizei)g->tex_index_count, GL_UNSIGNED_INT, NULL);
        r->draw_calls++;
    }
    if (g->index_count > g->tex_index_count) {
        use(r, normals, MODE_VERTEX_COLOR, off);
        r->draw_calls++;
        gl->DrawElements(GL_TRIANGLES, (GLsizei)(g->index_count - g->tex_index_count),
                         GL_UNSIGNED_INT, (const void *)(uintptr_t)(4 * (size_t)g->tex_index_count));
    }
}

/* called from the render thread, between begin and end */
void hlod_gpu_draw_range(hlod_renderer *r, const hlod_gpu_node *g, const double offset[3],
                         uint32_t first, uint32_t count)
{
    assert(r && g && offset);
    if (!count || first > g->index_count || count > g->index_count - first)
        return;
    const float off[3] = {(float)offset[0], (float)offset[1], (float)offset[2]};
    if (g->flags & HLOD_GPU_BATCHED) {
        batch_append(r, g, off, first, count, 0, NULL);
        return;
    }
    if (!g->vao)
        return;
    const gl_table *gl = &r->gl;
    r->draw_calls++;
    if (r->culling) {
        gl->Disable(GL_CULL_FACE);
        r->culling = 0;
    }
    gl->BindVertexArray(g->vao);
    use(r, (g->flags & HLOD_GPU_NORMALS) != 0, MODE_VERTEX_COLOR, off);
    gl->DrawElements(GL_TRIANGLES, (GLsizei)count, GL_UNSIGNED_INT,
                     (const void *)(uintptr_t)(4 * (size_t)first));
}

/* The splats' vertex array bound, its buffer holding s[0..n). */
static void splat_buffer(hlod_renderer *r, const hlod_gpu_splat *s, uint32_t n)
{
    const gl_table *gl = &r->gl;
    if (!r->splat.vao) {
        gl->GenVertexArrays(1, &r->splat.vao);
        gl->GenBuffers(1, &r->splat.vbo);
        gl->BindVertexArray(r->splat.vao);
        gl->BindBuffer(GL_ARRAY_BUFFER, r->splat.vbo);
        gl->EnableVertexAttribArray(ATTR_POSITION);
        gl->VertexAttribPointer(ATTR_POSITION, 3, GL_FLOAT, GL_FALSE, sizeof *s, (const void *)0);
        gl->EnableVertexAttribArray(ATTR_COLOR);
        gl->VertexAttribPointer(ATTR_COLOR, 4, GL_UNSIGNED_BYTE, GL_TRUE, sizeof *s,
                                (const void *)offsetof(hlod_gpu_splat, rgba));
    }
    gl->BindVertexArray(r->splat.vao);
    gl->BindBuffer(GL_ARRAY_BUFFER, r->splat.vbo);
    if (n > r->splat.cap) {
        size_t cap = r->splat.cap ? r->splat.cap : 4096;
        while (cap < n)
            cap *= 2;
        gl->BufferData(GL_ARRAY_BUFFER, (GLsizeiptr)(cap * sizeof *s), NULL, GL_STREAM_DRAW);
        r->splat.cap = cap;
    }
    gl->BufferSubData(GL_ARRAY_BUFFER, 0, (GLsizeiptr)(n * sizeof *s), s);
    gl->UseProgram(r->splat.prog);
    r->cur = NULL;
    gl->UniformMatrix4fv(r->splat.u_viewproj, 1, GL_FALSE, r->vp);
}

/* called from the render thread, between begin and end */
hlod_result hlod_gpu_blended(hlod_renderer *r, const hlod_gpu_splat *v, uint32_t n)
{
    assert(r && (v || !n));
    flush_batches(r); /* blended over what is drawn */
    if (n < 3)
        return HLOD_OK;
    const gl_table *gl = &r->gl;
    splat_buffer(r, v, n);
    gl->Uniform1f(r->splat.u_size, 1);
    if (r->culling) { /* a solid node's culling, left on: the faces are two-sided */
        gl->Disable(GL_CULL_FACE);
        r->culling = 0;
    }
    gl->Enable(GL_BLEND);
    gl->BlendFunc(GL_ONE, GL_ONE_MINUS_SRC_ALPHA);
    gl->DepthMask(GL_FALSE);
    gl->DrawArrays(GL_TRIANGLES, 0, (GLsizei)(n - n % 3));
    r->draw_calls++;
    gl->DepthMask(GL_TRUE);
    gl->Disable(GL_BLEND);
    GLenum e = take_errors(gl);
    if (e != GL_NO_ERROR) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: %u blended corners: GL error %#x", n, e);
        return e == GL_OUT_OF_MEMORY ? HLOD_ERR_NOMEM : HLOD_ERR_UNSUPPORTED;
    }
    return HLOD_OK;
}

/* called from the render thread, between begin and end */
hlod_result hlod_gpu_splats(hlod_renderer *r, const hlod_gpu_splat *s, uint32_t n, float size_px)
{
    assert(r && (s || !n));
    flush_batches(r);
    if (!n)
        return HLOD_OK;
    const gl_table *gl = &r->gl;
    splat_buffer(r, s, n);
    gl->Uniform1f(r->splat.u_size, size_px);
    gl->Enable(GL_PROGRAM_POINT_SIZE);
    gl->DrawArrays(GL_POINTS, 0, (GLsizei)n);
    r->draw_calls++;
    gl->Disable(GL_PROGRAM_POINT_SIZE);
    GLenum e = take_errors(gl);
    if (e != GL_NO_ERROR) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: %u splats: GL error %#x", n, e);
        return e == GL_OUT_OF_MEMORY ? HLOD_ERR_NOMEM : HLOD_ERR_UNSUPPORTED;
    }
    return HLOD_OK;
}

/* The composite pass's program, vertex array and textures at w x h
 * (made again when the size changes); 0 when GL cannot make them. */
static int ensure_comp(hlod_renderer *r, uint32_t w, uint32_t h)
{
    const gl_table *gl = &r->gl;
    if (!r->comp.prog) {
        GLuint prog = link_program(r, "", comp_vertex_src, comp_fragment_src);
        if (!prog)
            return 0;
        r->comp.prog = prog;
        r->comp.u_color = gl->GetUniformLocation(prog, "u_color");
        r->comp.u_depth = gl->GetUniformLocation(prog, "u_depth");
        gl->GenVertexArrays(1, &r->comp.vao);
        gl->GenTextures(2, r->comp.tex);
    }
    if (r->comp.w == w && r->comp.h == h)
        return 1;
    const GLint fmt[2] = {GL_RGBA8, GL_R32F};
    const GLenum pix[2] = {GL_RGBA, GL_RED}, type[2] = {GL_UNSIGNED_BYTE, GL_FLOAT};
    for (int k = 0; k < 2; k++) {
        gl->BindTexture(GL_TEXTURE_2D, r->comp.tex[k]);
        gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
        gl->TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
        gl->TexImage2D(GL_TEXTURE_2D, 0, fmt[k], (GLsizei)w, (GLsizei)h, 0, pix[k], type[k], NULL);
    }
    r->comp.w = w;
    r->comp.h = h;
    return take_errors(gl) == GL_NO_ERROR;
}

/* called from the render thread, between begin and end */
hlod_result hlod_gpu_composite(hlod_renderer *r, const uint8_t *rgba, const float *depth,
                               uint32_t w, uint32_t h)
{
    assert(r && rgba && depth && w && h);
    flush_batches(r);
    const gl_table *gl = &r->gl;
    if (!ensure_comp(r, w, h)) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: cannot make the %ux%u composite pass", w, h);
        r->comp.w = r->comp.h = 0;
        return HLOD_ERR_UNSUPPORTED;
    }
    gl->PixelStorei(GL_UNPACK_ALIGNMENT, 4);
    const void *src[2] = {rgba, depth};
    const GLenum pix[2] = {GL_RGBA, GL_RED}, type[2] = {GL_UNSIGNED_BYTE, GL_FLOAT};
    for (int k = 0; k < 2; k++) {
        gl->ActiveTexture(GL_TEXTURE0 + (GLenum)k);
        gl->BindTexture(GL_TEXTURE_2D, r->comp.tex[k]);
        gl->TexSubImage2D(GL_TEXTURE_2D, 0, 0, 0, (GLsizei)w, (GLsizei)h, pix[k], type[k], src[k]);
    }
    gl->UseProgram(r->comp.prog);
    r->cur = NULL;
    gl->Uniform1i(r->comp.u_color, 0);
    gl->Uniform1i(r->comp.u_depth, 1);
    if (r->culling) {
        gl->Disable(GL_CULL_FACE);
        r->culling = 0;
    }
    gl->BindVertexArray(r->comp.vao);
    gl->DrawArrays(GL_TRIANGLES, 0, 3);
    gl->ActiveTexture(GL_TEXTURE0);
    GLenum e = take_errors(gl);
    if (e != GL_NO_ERROR) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: composite %ux%u: GL error %#x", w, h, e);
        return HLOD_ERR_UNSUPPORTED;
    }
    return HLOD_OK;
}

/* called from the render thread */
/* The offscreen framebuffer, w x h (made again when the size changes: a
 * larger one would be cleared whole each frame); 0 when GL cannot make
 * it. */
static int ensure_low(hlod_renderer *r, uint32_t w, uint32_t h)
{
    const gl_table *gl = &r->gl;
    if (r->low.fbo && r->low.w == w && r->low.h == h)
        return 1;
    delete_low(r);
    take_errors(gl);
    gl->GenFramebuffers(1, &r->low.fbo);
    gl->GenRenderbuffers(2, r->low.rb);
    gl->BindFramebuffer(GL_FRAMEBUFFER, r->low.fbo);
    gl->BindRenderbuffer(GL_RENDERBUFFER, r->low.rb[0]);
    gl->RenderbufferStorage(GL_RENDERBUFFER, GL_RGBA8, (GLsizei)w, (GLsizei)h);
    gl->FramebufferRenderbuffer(GL_FRAMEBUFFER, GL_COLOR_ATTACHMENT0, GL_RENDERBUFFER,
                                r->low.rb[0]);
    gl->BindRenderbuffer(GL_RENDERBUFFER, r->low.rb[1]);
    gl->RenderbufferStorage(GL_RENDERBUFFER, GL_DEPTH_COMPONENT24, (GLsizei)w, (GLsizei)h);
    gl->FramebufferRenderbuffer(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_RENDERBUFFER,
                                r->low.rb[1]);
    gl->BindRenderbuffer(GL_RENDERBUFFER, 0);
    GLenum status = gl->CheckFramebufferStatus(GL_FRAMEBUFFER);
    gl->BindFramebuffer(GL_DRAW_FRAMEBUFFER, (GLuint)r->low.draw_prev);
    gl->BindFramebuffer(GL_READ_FRAMEBUFFER, (GLuint)r->low.read_prev);
    GLenum err = take_errors(gl);
    if (status != GL_FRAMEBUFFER_COMPLETE || err != GL_NO_ERROR) {
        hlod_logf(&r->lg, HLOD_LOG_WARN,
                  "renderer: no %ux%u offscreen framebuffer for frames drawn small "
                  "(status 0x%x, GL error 0x%x); frames stay at full size",
                  (unsigned)w, (unsigned)h, (unsigned)status, (unsigned)err);
        delete_low(r);
        return 0;
    }
    r->low.w = w;
    r->low.h = h;
    return 1;
}

hlod_result hlod_gpu_begin_scaled(hlod_renderer *r, const hlod_camera *cam, uint32_t out_w,
                                  uint32_t out_h)
{
    assert(r && cam);
    if (r->low.failed)
        return HLOD_ERR_UNSUPPORTED;
    const gl_table *gl = &r->gl;
    gl->GetIntegerv(GL_DRAW_FRAMEBUFFER_BINDING, &r->low.draw_prev);
    gl->GetIntegerv(GL_READ_FRAMEBUFFER_BINDING, &r->low.read_prev);
    if (!ensure_low(r, cam->width, cam->height)) {
        r->low.failed = 1;
        return HLOD_ERR_UNSUPPORTED;
    }
    gl->BindFramebuffer(GL_FRAMEBUFFER, r->low.fbo);
    r->low.on = 1;
    r->low.out_w = out_w;
    r->low.out_h = out_h;
    hlod_gpu_begin(r, cam);
    return HLOD_OK;
}

void hlod_gpu_end(hlod_renderer *r, int finish)
{
    assert(r);
    flush_batches(r);
    r->gl.BindVertexArray(0);
    if (r->low.on) {
        const gl_table *gl = &r->gl;
        gl->BindFramebuffer(GL_READ_FRAMEBUFFER, r->low.fbo);
        gl->BindFramebuffer(GL_DRAW_FRAMEBUFFER, (GLuint)r->low.draw_prev);
        gl->BlitFramebuffer(0, 0, (GLint)r->low.w, (GLint)r->low.h, 0, 0,
                            (GLint)r->low.out_w, (GLint)r->low.out_h, GL_COLOR_BUFFER_BIT,
                            GL_LINEAR);
        gl->BindFramebuffer(GL_READ_FRAMEBUFFER, (GLuint)r->low.read_prev);
        r->low.on = 0;
    }
    if (finish)
        r->gl.Finish();
    else
        r->gl.Flush();
}

void hlod_renderer_set_depth_view(hlod_renderer *r, hlod_depth_view view, void *user)
{
    if (!r)
        return;
    r->depth_view = view;
    r->depth_view_user = user;
}

const uint32_t *hlod_gpu_depth_view(hlod_renderer *r, uint32_t *stride, uint32_t *mask)
{
    if (r && flush_batches(r))
        r->gl.Finish(); /* the view reads the depth as it stands */
    /* the in-place view is the image's depth, not a small frame's */
    return r && r->depth_view && !r->low.on ? r->depth_view(r->depth_view_user, stride, mask)
                                            : NULL;
}

/* called from the render thread between begin and end */
void hlod_gpu_wait(hlod_renderer *r)
{
    assert(r);
    flush_batches(r);
    r->gl.Finish();
}

/* called from the render thread between begin and end; waits for the
 * draws so far (glReadPixels does) */
hlod_result hlod_gpu_read_depth(hlod_renderer *r, uint32_t width, uint32_t height, uint32_t *out)
{
    if (!r || !out || !width || !height)
        return HLOD_ERR_INVALID_ARG;
    flush_batches(r);
    const gl_table *gl = &r->gl;
    take_errors(gl);
    gl->PixelStorei(GL_PACK_ALIGNMENT, 4);
    gl->ReadPixels(0, 0, (GLsizei)width, (GLsizei)height, GL_DEPTH_COMPONENT, GL_UNSIGNED_INT,
                   out);
    if (take_errors(gl) != GL_NO_ERROR) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: glReadPixels of depth %ux%u failed",
                  (unsigned)width, (unsigned)height);
        return HLOD_ERR_UNSUPPORTED;
    }
    return HLOD_OK;
}

/* called from the render thread, context current, after hlod_gpu_end and
 * before the buffer swap (a swap leaves the back buffer undefined) */
hlod_result hlod_renderer_read_rgb(hlod_renderer *r, uint32_t width, uint32_t height, uint8_t *rgb)
{
    if (!r || !rgb || !width || !height)
        return HLOD_ERR_INVALID_ARG;
    const gl_table *gl = &r->gl;
    take_errors(gl);   /* earlier errors are not this read's */
    gl->PixelStorei(GL_PACK_ALIGNMENT, 1);
    gl->ReadPixels(0, 0, (GLsizei)width, (GLsizei)height, GL_RGB, GL_UNSIGNED_BYTE, rgb);
    gl->PixelStorei(GL_PACK_ALIGNMENT, 4);
    if (take_errors(gl) != GL_NO_ERROR) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: glReadPixels %ux%u failed",
                  (unsigned)width, (unsigned)height);
        return HLOD_ERR_UNSUPPORTED;
    }
    hlod_rgb_flip_rows(rgb, width, height); /* GL rows are bottom first */
    return HLOD_OK;
}

void hlod_rgb_flip_rows(uint8_t *rgb, uint32_t width, uint32_t height)
{
    size_t row = (size_t)width * 3;
    for (uint32_t y = 0; y < height / 2; y++) {
        uint8_t *a = rgb + y * row, *b = rgb + (height - 1 - y) * row;
        for (size_t i = 0; i < row; i++) {
            uint8_t t = a[i];
            a[i] = b[i];
            b[i] = t;
        }
    }
}

/* any thread */
int hlod_renderer_texture_blocks(const hlod_renderer *r, uint32_t mode)
{
    if (!r || mode == 1)
        return 0;
    if (mode == 2 && !r->s3tc) {
        hlod_logf(&r->lg, HLOD_LOG_WARN, "renderer: texture_upload=2 asks for blocks, but the GL "
                  "has no EXT_texture_compression_s3tc; textures are expanded to texels");
        return 0;
    }
    return r->s3tc && (mode == 2 || !r->software);
}

/* ---- the Grid-Lumigraph client (Okamoto 3.2; docs/lumigraph.md) ----
 *
 * Each fragment of the sparse mesh looks itself up in the views of the 8
 * grid points around the eye: in each point's view whose face holds the
 * direction from the point to the fragment (the six views of a point are
 * a cube map), if that view's depth there is not nearer than the fragment
 * (a shadow-map test: hidden from that point, the view saw something
 * else), weighted by the point's trilinear weight; the sum is
 * normalised.  A fragment no view sees is shaded from its face normal
 * (section 5.2's hole filling).  Before the mesh, a pass at the far plane
 * fills the pixels the mesh leaves empty with each view's colour along the
 * pixel's ray, so a silhouette the sparse mesh lacks still shows. */

#define LUMI_GLSL_FACES                                                                   \
    "const vec3 FF[6] = vec3[6](vec3(1,0,0), vec3(-1,0,0), vec3(0,1,0), vec3(0,-1,0),\n"  \
    "                           vec3(0,0,1), vec3(0,0,-1));\n"                            \
    "const vec3 FU[6] = vec3[6](vec3(0,0,1), vec3(0,0,1), vec3(0,0,1), vec3(0,0,1),\n"    \
    "                           vec3(0,1,0), vec3(0,1,0));\n"                             \
    "uniform vec3 u_pt[8];\n"                                                             \
    "uniform float u_w[8];\n"                                                             \
    "uniform int u_slot[48];\n"                                                           \
    "uniform sampler2DArray u_color;\n"                                                   \
    "int face_of(vec3 v) {\n"                                                             \
    "    vec3 a = abs(v);\n"                                                              \
    "    if (a.x >= a.y && a.x >= a.z) return v.x >= 0.0 ? 0 : 1;\n"                      \
    "    if (a.y >= a.z) return v.y >= 0.0 ? 2 : 3;\n"                                    \
    "    return v.z >= 0.0 ? 4 : 5;\n"                                                    \
    "}\n"                                                                                 \
    /* texture coordinates of v in face f (rows top first), and its axial distance */     \
    "vec3 face_uvz(vec3 v, int f) {\n"                                                    \
    "    vec3 r = cross(FF[f], FU[f]);\n"                                                 \
    "    float z = dot(v, FF[f]);\n"                                                      \
    "    vec2 n = vec2(dot(v, r), dot(v, FU[f])) / z;\n"                                  \
    "    return vec3(0.5 + 0.5 * n.x, 0.5 - 0.5 * n.y, z);\n"                             \
    "}\n"

static const char *lumi_vertex_src =
    "layout(location = 0) in vec3 a_position;\n"
    "uniform mat4 u_viewproj;\n"
    "uniform vec3 u_offset;\n"
    "out vec3 v_rel;\n"
    "void main() {\n"
    "    v_rel = a_position + u_offset;\n"
    "    gl_Position = u_viewproj * vec4(v_rel, 1.0);\n"
    "}\n";

static const char *lumi_fragment_src =
    LUMI_GLSL_FACES
    "uniform sampler2DArray u_depth;\n"
    "uniform vec3 u_depth_par;\n" /* near, ln(far / near), 1 + tolerance */
    "uniform vec3 u_hole;\n"
    "uniform float u_parallax;\n" /* radians a pixel spans */
    "in vec3 v_rel;\n"
    "out vec4 o_color;\n"
    "void main() {\n"
    /*   the face's normal, towards the eye */
    "    vec3 n = cross(dFdx(v_rel), dFdy(v_rel));\n"
    "    if (dot(n, v_rel) > 0.0) n = -n;\n"
    "    vec3 acc = vec3(0.0);\n"
    "    float wsum = 0.0;\n"
    "    for (int i = 0; i < 8; i++) {\n"
    "        if (u_w[i] <= 0.0) continue;\n"
    "        vec3 v = v_rel - u_pt[i];\n"
    /*       a point behind the face saw its back, or through it (the
     *       shadow map's back-face case, section 3.2) */
    "        if (dot(n, v) > 0.0) continue;\n"
    "        int f = face_of(v);\n"
    "        int s = u_slot[i * 6 + f];\n"
    "        if (s < 0) continue;\n"
    "        vec3 t = face_uvz(v, f);\n"
    "        float q = texture(u_depth, vec3(t.xy, float(s))).r * 65535.0;\n"
    /*       a point within two pixels' parallax of the eye saw along this
     *       ray what the eye sees: no depth test (at a grid point the
     *       image is that point's view, whatever the sparse mesh) */
    "        if (length(u_pt[i]) > 2.0 * u_parallax * t.z) {\n"
    "            if (q > 65534.5) continue;\n" /* the view saw nothing there */
    "            float zs = u_depth_par.x * exp(q / 65534.0 * u_depth_par.y);\n"
    "            if (t.z > zs * u_depth_par.z) continue;\n" /* hidden from point i */
    "        }\n"
    "        acc += u_w[i] * texture(u_color, vec3(t.xy, float(s))).rgb;\n"
    "        wsum += u_w[i];\n"
    "    }\n"
    "    if (wsum > 0.0) {\n"
    "        o_color = vec4(acc / wsum, 1.0);\n"
    "        return;\n"
    "    }\n"
    "    vec3 to_eye = -v_rel;\n"
    "    float d = length(to_eye);\n"
    "    to_eye = d > 0.0 ? to_eye / d : vec3(0.0, 0.0, 1.0);\n"
    "    float len = length(n);\n"
    "    n = len > 0.0 ? n / len : to_eye;\n"
    "    o_color = vec4(u_hole * (0.20 + 0.55 * abs(dot(n, to_eye)) + 0.25 * (0.5 + 0.5 * n.z)), 1.0);\n"
    "}\n";

static const char *lumi_bg_vertex_src =
    "uniform mat4 u_inv;\n" /* clip space -> camera-relative position */
    /* the far plane's point, homogeneous: linear across the screen, so it
     * interpolates exactly; divided per fragment (the eye is at 0) */
    "out vec4 v_far;\n"
    "void main() {\n"
    "    vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);\n"
    "    v_far = u_inv * vec4(p, 1.0, 1.0);\n"
    "    gl_Position = vec4(p, 1.0, 1.0);\n"
    "}\n";

static const char *lumi_bg_fragment_src =
    LUMI_GLSL_FACES
    "uniform sampler2DArray u_depth;\n"
    "uniform vec3 u_depth_par;\n"
    "uniform vec3 u_clear;\n"
    "uniform float u_parallax;\n" /* radians a pixel spans */
    "in vec4 v_far;\n"
    "out vec4 o_color;\n"
    "void main() {\n"
    "    vec3 v_dir = v_far.xyz / v_far.w;\n"
    "    vec3 acc = vec3(0.0);\n"
    "    float wsum = 0.0;\n"
    "    int f = face_of(v_dir);\n"
    "    vec3 t = face_uvz(v_dir, f);\n"
    "    for (int i = 0; i < 8; i++) {\n"
    "        if (u_w[i] <= 0.0) continue;\n"
    "        int s = u_slot[i * 6 + f];\n"
    "        if (s == -1) continue;\n"
    "        vec3 c = u_clear;\n"
    "        if (s >= 0) {\n"
    /*           what point i saw along this direction is seen along it from
     *           the eye too only when it is far enough for the offset to
     *           the point to move it under two pixels (nothing, at any
     *           offset: the view's own colour there, its sky as coded);
     *           else, unknown */
    "            float q = texture(u_depth, vec3(t.xy, float(s))).r * 65535.0;\n"
    "            if (q <= 65534.5) {\n"
    "                float zs = u_depth_par.x * exp(q / 65534.0 * u_depth_par.y);\n"
    "                if (length(u_pt[i]) > 2.0 * u_parallax * zs) continue;\n"
    "            }\n"
    "            c = texture(u_color, vec3(t.xy, float(s))).rgb;\n"
    "        }\n"
    "        acc += u_w[i] * c;\n"
    "        wsum += u_w[i];\n"
    "    }\n"
    "    o_color = vec4(wsum > 0.0 ? acc / wsum : u_clear, 1.0);\n"
    "}\n";

static const char *lumi_depth_fragment_src = "void main() {}\n";

static void lumi_free(hlod_renderer *r)
{
    const gl_table *gl = &r->gl;
    if (r->lumi.depth_prog)
        gl->DeleteProgram(r->lumi.depth_prog);
    if (r->lumi.prog)
        gl->DeleteProgram(r->lumi.prog);
    if (r->lumi.bg_prog)
        gl->DeleteProgram(r->lumi.bg_prog);
    if (r->lumi.bg_vao)
        gl->DeleteVertexArrays(1, &r->lumi.bg_vao);
    if (r->lumi.tex[0])
        gl->DeleteTextures(2, r->lumi.tex);
    memset(&r->lumi, 0, sizeof r->lumi);
}

void hlod_gpu_lumi_release(hlod_renderer *r)
{
    if (r) {
        r->gl.UseProgram(0);
        r->cur = NULL;
        lumi_free(r);
    }
}

static int lumi_programs(hlod_renderer *r)
{
    const gl_table *gl = &r->gl;
    r->lumi.prog = link_program(r, "", lumi_vertex_src, lumi_fragment_src);
    r->lumi.bg_prog = r->lumi.prog ? link_program(r, "", lumi_bg_vertex_src, lumi_bg_fragment_src) : 0;
    r->lumi.depth_prog =
        r->lumi.bg_prog ? link_program(r, "", lumi_vertex_src, lumi_depth_fragment_src) : 0;
    if (!r->lumi.depth_prog)
        return 0;
    r->lumi.d_viewproj = gl->GetUniformLocation(r->lumi.depth_prog, "u_viewproj");
    r->lumi.d_offset = gl->GetUniformLocation(r->lumi.depth_prog, "u_offset");
    GLuint p = r->lumi.prog, b = r->lumi.bg_prog;
    r->lumi.u_viewproj = gl->GetUniformLocation(p, "u_viewproj");
    r->lumi.u_offset = gl->GetUniformLocation(p, "u_offset");
    r->lumi.u_pt = gl->GetUniformLocation(p, "u_pt");
    r->lumi.u_w = gl->GetUniformLocation(p, "u_w");
    r->lumi.u_slot = gl->GetUniformLocation(p, "u_slot");
    r->lumi.u_depth_par = gl->GetUniformLocation(p, "u_depth_par");
    r->lumi.u_hole = gl->GetUniformLocation(p, "u_hole");
    r->lumi.u_parallax = gl->GetUniformLocation(p, "u_parallax");
    r->lumi.bg_inv = gl->GetUniformLocation(b, "u_inv");
    r->lumi.bg_pt = gl->GetUniformLocation(b, "u_pt");
    r->lumi.bg_w = gl->GetUniformLocation(b, "u_w");
    r->lumi.bg_slot = gl->GetUniformLocation(b, "u_slot");
    r->lumi.bg_clear = gl->GetUniformLocation(b, "u_clear");
    r->lumi.bg_depth_par = gl->GetUniformLocation(b, "u_depth_par");
    r->lumi.bg_parallax = gl->GetUniformLocation(b, "u_parallax");
    gl->UseProgram(p);
    gl->Uniform1i(gl->GetUniformLocation(p, "u_color"), 1);
    gl->Uniform1i(gl->GetUniformLocation(p, "u_depth"), 2);
    gl->UseProgram(b);
    gl->Uniform1i(gl->GetUniformLocation(b, "u_color"), 1);
    gl->Uniform1i(gl->GetUniformLocation(b, "u_depth"), 2);
    gl->UseProgram(0);
    r->cur = NULL;
    gl->GenVertexArrays(1, &r->lumi.bg_vao);
    return 1;
}

/* called from the render thread, context current */
hlod_result hlod_gpu_lumi_init(hlod_renderer *r, uint32_t slots, uint32_t size,
                               uint32_t depth_size)
{
    assert(r && slots && size && depth_size);
    const gl_table *gl = &r->gl;
    if (r->lumi.prog && r->lumi.slots == slots && r->lumi.size == size &&
        r->lumi.depth_size == depth_size)
        return HLOD_OK;
    hlod_gpu_lumi_release(r);
    take_errors(gl);
    if (!lumi_programs(r)) {
        lumi_free(r);
        return HLOD_ERR_UNSUPPORTED;
    }
    gl->GenTextures(2, r->lumi.tex);
    const GLint fmt[2] = {GL_RGB8, GL_R16};
    const GLenum pix[2] = {GL_RGB, GL_RED}, type[2] = {GL_UNSIGNED_BYTE, GL_UNSIGNED_SHORT};
    const uint32_t side[2] = {size, depth_size};
    for (int k = 0; k < 2; k++) {
        gl->ActiveTexture(GL_TEXTURE1 + (GLenum)k);
        gl->BindTexture(GL_TEXTURE_2D_ARRAY, r->lumi.tex[k]);
        /* colour filtered, depth codes never blended across an edge */
        GLint filter = k ? GL_NEAREST : GL_LINEAR;
        gl->TexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MIN_FILTER, filter);
        gl->TexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MAG_FILTER, filter);
        gl->TexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_WRAP_S, GL_CLAMP_TO_EDGE);
        gl->TexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_WRAP_T, GL_CLAMP_TO_EDGE);
        gl->TexImage3D(GL_TEXTURE_2D_ARRAY, 0, fmt[k], (GLsizei)side[k], (GLsizei)side[k],
                       (GLsizei)slots, 0, pix[k], type[k], NULL);
    }
    gl->ActiveTexture(GL_TEXTURE0);
    GLenum e = take_errors(gl);
    if (e != GL_NO_ERROR) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: cannot make %u Grid-Lumigraph slots of "
                  "%ux%u: GL error %#x", slots, size, size, e);
        lumi_free(r);
        return e == GL_OUT_OF_MEMORY ? HLOD_ERR_NOMEM : HLOD_ERR_UNSUPPORTED;
    }
    r->lumi.slots = slots;
    r->lumi.size = size;
    r->lumi.depth_size = depth_size;
    return HLOD_OK;
}

/* called from the render thread, context current, outside begin and end
 * or between them */
hlod_result hlod_gpu_lumi_upload(hlod_renderer *r, uint32_t slot, const uint8_t *rgb,
                                 const uint16_t *depth)
{
    assert(r && rgb && depth);
    if (!r->lumi.prog || slot >= r->lumi.slots)
        return HLOD_ERR_INVALID_ARG;
    const gl_table *gl = &r->gl;
    take_errors(gl);
    gl->PixelStorei(GL_UNPACK_ALIGNMENT, 1);
    const void *src[2] = {rgb, depth};
    const GLenum pix[2] = {GL_RGB, GL_RED}, type[2] = {GL_UNSIGNED_BYTE, GL_UNSIGNED_SHORT};
    const uint32_t side[2] = {r->lumi.size, r->lumi.depth_size};
    for (int k = 0; k < 2; k++) {
        gl->ActiveTexture(GL_TEXTURE1 + (GLenum)k);
        gl->BindTexture(GL_TEXTURE_2D_ARRAY, r->lumi.tex[k]);
        gl->TexSubImage3D(GL_TEXTURE_2D_ARRAY, 0, 0, 0, (GLint)slot, (GLsizei)side[k],
                          (GLsizei)side[k], 1, pix[k], type[k], src[k]);
    }
    gl->ActiveTexture(GL_TEXTURE0);
    gl->PixelStorei(GL_UNPACK_ALIGNMENT, 4);
    GLenum e = take_errors(gl);
    if (e != GL_NO_ERROR) {
        hlod_logf(&r->lg, HLOD_LOG_ERROR, "renderer: Grid-Lumigraph upload: GL error %#x", e);
        return HLOD_ERR_UNSUPPORTED;
    }
    return HLOD_OK;
}

/* Inverts a 4x4 column-major matrix (Cramer's rule through cofactors);
 * 0 when it is singular. */
static int invert4(const double m[16], double out[16])
{
    double inv[16];
    inv[0] = m[5] * m[10] * m[15] - m[5] * m[11] * m[14] - m[9] * m[6] * m[15] + m[9] * m[7] * m[14] + m[13] * m[6] * m[11] - m[13] * m[7] * m[10];
    inv[4] = -m[4] * m[10] * m[15] + m[4] * m[11] * m[14] + m[8] * m[6] * m[15] - m[8] * m[7] * m[14] - m[12] * m[6] * m[11] + m[12] * m[7] * m[10];
    inv[8] = m[4] * m[9] * m[15] - m[4] * m[11] * m[13] - m[8] * m[5] * m[15] + m[8] * m[7] * m[13] + m[12] * m[5] * m[11] - m[12] * m[7] * m[9];
    inv[12] = -m[4] * m[9] * m[14] + m[4] * m[10] * m[13] + m[8] * m[5] * m[14] - m[8] * m[6] * m[13] - m[12] * m[5] * m[10] + m[12] * m[6] * m[9];
    inv[1] = -m[1] * m[10] * m[15] + m[1] * m[11] * m[14] + m[9] * m[2] * m[15] - m[9] * m[3] * m[14] - m[13] * m[2] * m[11] + m[13] * m[3] * m[10];
    inv[5] = m[0] * m[10] * m[15] - m[0] * m[11] * m[14] - m[8] * m[2] * m[15] + m[8] * m[3] * m[14] + m[12] * m[2] * m[11] - m[12] * m[3] * m[10];
    inv[9] = -m[0] * m[9] * m[15] + m[0] * m[11] * m[13] + m[8] * m[1] * m[15] - m[8] * m[3] * m[13] - m[12] * m[1] * m[11] + m[12] * m[3] * m[9];
    inv[13] = m[0] * m[9] * m[14] - m[0] * m[10] * m[13] - m[8] * m[1] * m[14] + m[8] * m[2] * m[13] + m[12] * m[1] * m[10] - m[12] * m[2] * m[9];
    inv[2] = m[1] * m[6] * m[15] - m[1] * m[7] * m[14] - m[5] * m[2] * m[15] + m[5] * m[3] * m[14] + m[13] * m[2] * m[7] - m[13] * m[3] * m[6];
    inv[6] = -m[0] * m[6] * m[15] + m[0] * m[7] * m[14] + m[4] * m[2] * m[15] - m[4] * m[3] * m[14] - m[12] * m[2] * m[7] + m[12] * m[3] * m[6];
    inv[10] = m[0] * m[5] * m[15] - m[0] * m[7] * m[13] - m[4] * m[1] * m[15] + m[4] * m[3] * m[13] + m[12] * m[1] * m[7] - m[12] * m[3] * m[5];
    inv[14] = -m[0] * m[5] * m[14] + m[0] * m[6] * m[13] + m[4] * m[1] * m[14] - m[4] * m[2] * m[13] - m[12] * m[1] * m[6] + m[12] * m[2] * m[5];
    inv[3] = -m[1] * m[6] * m[11] + m[1] * m[7] * m[10] + m[5] * m[2] * m[11] - m[5] * m[3] * m[10] - m[9] * m[2] * m[7] + m[9] * m[3] * m[6];
    inv[7] = m[0] * m[6] * m[11] - m[0] * m[7] * m[10] - m[4] * m[2] * m[11] + m[4] * m[3] * m[10] + m[8] * m[2] * m[7] - m[8] * m[3] * m[6];
    inv[11] = -m[0] * m[5] * m[11] + m[0] * m[7] * m[9] + m[4] * m[1] * m[11] - m[4] * m[3] * m[9] - m[8] * m[1] * m[7] + m[8] * m[3] * m[5];
    inv[15] = m[0] * m[5] * m[10] - m[0] * m[6] * m[9] - m[4] * m[1] * m[10] + m[4] * m[2] * m[9] + m[8] * m[1] * m[6] - m[8] * m[2] * m[5];
    double det = m[0] * inv[0] + m[1] * inv[4] + m[2] * inv[8] + m[3] * inv[12];
    if (!(fabs(det) > 0))
        return 0;
    for (int k = 0; k < 16; k++)
        out[k] = inv[k] / det;
    return 1;
}

/* called from the render thread, after hlod_gpu_begin */
void hlod_gpu_lumi_depth_begin(hlod_renderer *r)
{
    assert(r && r->lumi.prog);
    flush_batches(r);
    const gl_table *gl = &r->gl;
    if (r->culling) {
        gl->Disable(GL_CULL_FACE);
        r->culling = 0;
    }
    gl->UseProgram(r->lumi.depth_prog);
    gl->UniformMatrix4fv(r->lumi.d_viewproj, 1, GL_FALSE, r->vp);
    gl->ColorMask(GL_FALSE, GL_FALSE, GL_FALSE, GL_FALSE);
    r->cur = NULL;
    r->lumi.prepassed = 1;
}

/* called from the render thread, after hlod_gpu_lumi_depth_begin */
void hlod_gpu_lumi_depth(hlod_renderer *r, const hlod_gpu_node *g, const double offset[3])
{
    assert(r && g && offset);
    if (!g->vao || !g->index_count)
        return;
    const gl_table *gl = &r->gl;
    gl->Uniform3f(r->lumi.d_offset, (float)offset[0], (float)offset[1], (float)offset[2]);
    gl->BindVertexArray(g->vao);
    gl->DrawElements(GL_TRIANGLES, (GLsizei)g->index_count, GL_UNSIGNED_INT, NULL);
}

/* called from the render thread, after hlod_gpu_begin (and the pre-pass) */
void hlod_gpu_lumi_begin(hlod_renderer *r, const hlod_camera *cam, const hlod_gpu_lumi_frame *f)
{
    assert(r && cam && f && r->lumi.prog);
    flush_batches(r);
    const gl_table *gl = &r->gl;
    double vp[16], inv[16];
    hlod_camera_view_proj(cam, vp);
    float finv[16];
    if (!invert4(vp, inv))
        memset(inv, 0, sizeof inv);
    for (int k = 0; k < 16; k++)
        finv[k] = (float)inv[k];
    for (int k = 0; k < 2; k++) {
        gl->ActiveTexture(GL_TEXTURE1 + (GLenum)k);
        gl->BindTexture(GL_TEXTURE_2D_ARRAY, r->lumi.tex[k]);
    }
    gl->ActiveTexture(GL_TEXTURE0);
    if (r->culling) {
        gl->Disable(GL_CULL_FACE);
        r->culling = 0;
    }
    /* the far-plane pass: at depth 1 under GL_LEQUAL, what the mesh draws
     * later covers it */
    gl->UseProgram(r->lumi.bg_prog);
    gl->UniformMatrix4fv(r->lumi.bg_inv, 1, GL_FALSE, finv);
    gl->Uniform3fv(r->lumi.bg_pt, 8, &f->point[0][0]);
    gl->Uniform1fv(r->lumi.bg_w, 8, f->weight);
    gl->Uniform1iv(r->lumi.bg_slot, 48, &f->slot[0][0]);
    gl->Uniform3f(r->lumi.bg_clear, r->clear[0], r->clear[1], r->clear[2]);
    gl->Uniform3f(r->lumi.bg_depth_par, f->near_plane, f->log_ratio, 1.0f + f->tolerance);
    const float parallax =
        (float)(2.0 * tan(0.5 * cam->fov_y_deg * 3.14159265358979 / 180.0) / cam->height);
    gl->Uniform1f(r->lumi.bg_parallax, parallax);
    gl->ColorMask(GL_TRUE, GL_TRUE, GL_TRUE, GL_TRUE);
    gl->DepthFunc(GL_LEQUAL);
    gl->DepthMask(GL_FALSE);
    gl->BindVertexArray(r->lumi.bg_vao);
    gl->DrawArrays(GL_TRIANGLES, 0, 3);
    if (r->lumi.prepassed) {
        /* each pixel shaded once: the nearest surface's fragment, whose
         * depth the pre-pass wrote */
        gl->DepthFunc(GL_LEQUAL);
        r->lumi.prepassed = 0;
    } else {
        gl->DepthMask(GL_TRUE);
        gl->DepthFunc(GL_LESS);
    }
    gl->UseProgram(r->lumi.prog);
    gl->UniformMatrix4fv(r->lumi.u_viewproj, 1, GL_FALSE, r->vp);
    gl->Uniform3fv(r->lumi.u_pt, 8, &f->point[0][0]);
    gl->Uniform1fv(r->lumi.u_w, 8, f->weight);
    gl->Uniform1iv(r->lumi.u_slot, 48, &f->slot[0][0]);
    gl->Uniform3f(r->lumi.u_depth_par, f->near_plane, f->log_ratio, 1.0f + f->tolerance);
    gl->Uniform3f(r->lumi.u_hole, DEFAULT_GREY, DEFAULT_GREY, DEFAULT_GREY);
    gl->Uniform1f(r->lumi.u_parallax, parallax);
    r->cur = NULL;
}

/* called from the render thread, after hlod_gpu_lumi_begin */
void hlod_gpu_lumi_draw(hlod_renderer *r, const hlod_gpu_node *g, const double offset[3])
{
    assert(r && g && offset);
    if (!g->vao || !g->index_count)
        return;
    const gl_table *gl = &r->gl;
    gl->Uniform3f(r->lumi.u_offset, (float)offset[0], (float)offset[1], (float)offset[2]);
    gl->BindVertexArray(g->vao);
    gl->DrawElements(GL_TRIANGLES, (GLsizei)g->index_count, GL_UNSIGNED_INT, NULL);
}
