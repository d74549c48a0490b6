/*
 * test_render.c - the GL renderer, cameras and OSMesa contexts, headless.
 *
 * Payloads are built in memory (no store): hand-made quads and cubes with
 * known colours and textures, the real meshes of data/meshes/ and the
 * small synthetic city.  Images are rendered with llvmpipe through OSMesa
 * at 256 x 256, read back and checked by pixel values and by PSNR against
 * a second render that must match (origins 4 000 km away, a node split in
 * two payloads, a second context).  A failing comparison keeps both images
 * as PNG files in $TMPDIR (or /tmp) and prints their names; HLOD_TEST_KEEP=1
 * keeps every compared image.
 */
#include "check.h"
#include "rec_log.h"
#include "city.h"
#include "gl_render.h"
#include "texture.h"
#include "hlod/engine.h"
#include "hlod/renderer.h"
#include "hlod/image.h"
#include "hlod/mesh_io.h"

#include <dirent.h>
#include <math.h>
#include <stdint.h>
#include <unistd.h>

#define W 256
#define H 256
#define NPIX ((size_t)W * H)

/* ---------- helpers ---------- */

static double psnr(const uint8_t *a, const uint8_t *b, size_t bytes)
{
    double se = 0;
    for (size_t i = 0; i < bytes; i++) {
        double d = (double)a[i] - (double)b[i];
        se += d * d;
    }
    if (se == 0)
        return INFINITY;
    return 10 * log10(255.0 * 255.0 / (se / (double)bytes));
}

/* Keeps an image for a human to look at; returns its path in buf. */
static const char *keep_image(const char *name, const uint8_t *rgb, char *buf, size_t n)
{
    const char *tmp = getenv("TMPDIR");
    snprintf(buf, n, "%s/hlod-test-render-%s.png", tmp && *tmp ? tmp : "/tmp", name);
    hlod_image img = {W, H, 3, (uint8_t *)rgb};
    if (hlod_image_write(buf, &img, NULL) != HLOD_OK)
        snprintf(buf, n, "(could not write %s)", name);
    return buf;
}

/* PSNR of two renders; below `min_db` (or always, with HLOD_TEST_KEEP set
 * in the environment) both images are kept. */
static double compare(const char *name, const uint8_t *a, const uint8_t *b, double min_db)
{
    double db = psnr(a, b, NPIX * 3);
    fprintf(stderr, "     %s: PSNR %.2f dB\n", name, db);
    if (!(db > min_db) || getenv("HLOD_TEST_KEEP")) {
        char pa[600], pb[600], na[300];
        snprintf(na, sizeof na, "%s-a", name);
        keep_image(na, a, pa, sizeof pa);
        snprintf(na, sizeof na, "%s-b", name);
        keep_image(na, b, pb, sizeof pb);
        fprintf(stderr, "     kept %s and %s\n", pa, pb);
    }
    return db;
}

static const uint8_t *pixel(const uint8_t *rgb, int x, int y)
{
    return rgb + ((size_t)y * W + (size_t)x) * 3;
}

/* Pixels that differ from `bg` by more than 2 in some channel. */
static size_t covered(const uint8_t *rgb, const uint8_t bg[3])
{
    size_t n = 0;
    for (size_t i = 0; i < NPIX; i++)
        for (int k = 0; k < 3; k++)
            if (abs((int)rgb[3 * i + k] - (int)bg[k]) > 2) {
                n++;
                break;
            }
    return n;
}

/* A context and a renderer clearing to black. */
typedef struct gl_ctx {
    hlod_osmesa *o;
    hlod_renderer *r;
} gl_ctx;

static int ctx_open(gl_ctx *c)
{
    memset(c, 0, sizeof *c);
    hlod_result res = hlod_osmesa_create(W, H, NULL, &c->o);
    CHECKF(res == HLOD_OK, "%s", hlod_result_str(res));
    if (res != HLOD_OK)
        return 0;
    res = hlod_renderer_create(hlod_osmesa_get_proc(), NULL, &c->r);
    CHECKF(res == HLOD_OK, "%s", hlod_result_str(res));
    if (res != HLOD_OK) {
        hlod_osmesa_destroy(c->o);
        return 0;
    }
    hlod_renderer_set_clear_color(c->r, 0, 0, 0);
    return 1;
}

static void ctx_close(gl_ctx *c)
{
    hlod_renderer_destroy(c->r);
    hlod_osmesa_destroy(c->o);
    memset(c, 0, sizeof *c);
}

/* A payload built in memory, with the arrays it owns and its origin. */
typedef struct tpay {
    hlod_store_payload p;
    double origin[3];
    uint32_t depth;
    float *pos, *nrm, *uv;
    uint8_t *col, *pix;
    uint32_t *idx;
} tpay;

static void tpay_free(tpay *t)
{
    free(t->pos);
    free(t->nrm);
    free(t->uv);
    free(t->col);
    free(t->pix);
    free(t->idx);
    memset(t, 0, sizeof *t);
}

typedef struct tpay_opts {
    const float *normals;       /* per mesh vertex, or NULL: mesh normals or none */
    const uint32_t *tris;       /* mesh triangles to take, or NULL: all */
    size_t ntri;
    const hlod_image *tex;      /* texture (needs mesh UVs), or NULL */
    size_t tex_tris;            /* leading textured triangles; 0: all when tex */
    const uint8_t *rgba;        /* one colour for every vertex, or NULL */
} tpay_opts;

/* Payload of some triangles of m, positions relative to the centre of their
 * bounding box (the payload's origin). */
static int tpay_from_mesh(tpay *t, const hlod_mesh *m, const tpay_opts *o)
{
    memset(t, 0, sizeof *t);
    size_t ntri = o->tris ? o->ntri : m->tri_count;
    uint32_t *map = malloc(m->vertex_count * sizeof *map);
    t->idx = malloc(3 * ntri * sizeof *t->idx);
    t->pos = malloc(3 * m->vertex_count * sizeof *t->pos);
    if (!map || !t->idx || !t->pos) {
        free(map);
        tpay_free(t);
        return 0;
    }
    memset(map, 0xff, m->vertex_count * sizeof *map);
    uint32_t nv = 0;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    uint32_t *order = malloc(m->vertex_count * sizeof *order);
    for (size_t i = 0; i < ntri; i++) {
        size_t tri = o->tris ? o->tris[i] : i;
        for (int k = 0; k < 3; k++) {
            uint32_t v = m->indices[3 * tri + k];
            if (map[v] == UINT32_MAX) {
                map[v] = nv;
                order[nv++] = v;
                for (int a = 0; a < 3; a++) {
                    lo[a] = fmin(lo[a], m->positions[3 * v + a]);
                    hi[a] = fmax(hi[a], m->positions[3 * v + a]);
                }
            }
            t->idx[3 * i + k] = map[v];
        }
    }
    for (int a = 0; a < 3; a++)
        t->origin[a] = 0.5 * (lo[a] + hi[a]);
    const float *nsrc = o->normals ? o->normals : m->normals;
    t->nrm = nsrc ? malloc(3 * (size_t)nv * sizeof *t->nrm) : NULL;
    t->uv = o->tex ? malloc(2 * (size_t)nv * sizeof *t->uv) : NULL;
    t->col = o->rgba ? malloc(4 * (size_t)nv) : NULL;
    for (uint32_t i = 0; i < nv; i++) {
        uint32_t v = order[i];
        for (int a = 0; a < 3; a++)
            t->pos[3 * i + a] = (float)(m->positions[3 * v + a] - t->origin[a]);
        if (t->nrm)
            memcpy(t->nrm + 3 * i, nsrc + 3 * v, 3 * sizeof(float));
        if (t->uv)
            memcpy(t->uv + 2 * i, m->uvs + 2 * v, 2 * sizeof(float));
        if (t->col)
            memcpy(t->col + 4 * i, o->rgba, 4);
    }
    free(order);
    free(map);
    hlod_store_payload *p = &t->p;
    p->vertex_count = nv;
    p->index_count = (uint32_t)(3 * ntri);
    p->positions = t->pos;
    p->normals = t->nrm;
    p->uvs = t->uv;
    p->colors = t->col;
    p->indices = t->idx;
    p->flags = (t->nrm ? HLOD_NODE_NORMALS : 0) | (t->uv ? HLOD_NODE_UVS : 0) |
               (t->col ? HLOD_NODE_COLORS : 0);
    if (o->tex) {
        size_t bytes = (size_t)o->tex->width * o->tex->height * o->tex->channels;
        t->pix = malloc(bytes);
        memcpy(t->pix, o->tex->pixels, bytes);
        p->pixels = t->pix;
        p->tex_width = (uint32_t)o->tex->width;
        p->tex_height = (uint32_t)o->tex->height;
        p->tex_channels = (uint32_t)o->tex->channels;
        p->tex_tri_count = (uint32_t)(o->tex_tris ? o->tex_tris : ntri);
        p->flags |= HLOD_NODE_TEXTURE;
    }
    return 1;
}

/* Uploads the payloads, draws them from cam, reads the image, releases. */
static void render(gl_ctx *c, tpay *ps, size_t n, const hlod_camera *cam, uint8_t *rgb)
{
    hlod_gpu_node *g = calloc(n, sizeof *g);
    for (size_t i = 0; i < n; i++) {
        hlod_result res = hlod_gpu_upload(c->r, &ps[i].p, &g[i]);
        CHECKF(res == HLOD_OK, "payload %zu: %s", i, hlod_result_str(res));
    }
    hlod_gpu_begin(c->r, cam);
    for (size_t i = 0; i < n; i++) {
        double off[3];
        for (int a = 0; a < 3; a++)
            off[a] = ps[i].origin[a] - cam->position[a];
        hlod_gpu_draw(c->r, &g[i], off, ps[i].depth);
    }
    hlod_gpu_end(c->r, 1);
    CHECK(hlod_osmesa_read_rgb(c->o, rgb) == HLOD_OK);
    for (size_t i = 0; i < n; i++)
        hlod_gpu_release(c->r, &g[i]);
    free(g);
}

/* A quad [x0, x1] x [y0, y1] at z, facing +z, UVs 0..1 over it. */
static void add_quad(hlod_mesh *m, size_t *v, size_t *t, double x0, double y0, double x1,
                     double y1, double z)
{
    const double xs[4] = {x0, x1, x1, x0}, ys[4] = {y0, y0, y1, y1};
    const float us[4] = {0, 1, 1, 0}, vs[4] = {0, 0, 1, 1};
    for (int k = 0; k < 4; k++) {
        size_t i = *v + (size_t)k;
        m->positions[3 * i] = xs[k];
        m->positions[3 * i + 1] = ys[k];
        m->positions[3 * i + 2] = z;
        m->normals[3 * i] = 0;
        m->normals[3 * i + 1] = 0;
        m->normals[3 * i + 2] = 1;
        m->uvs[2 * i] = us[k];
        m->uvs[2 * i + 1] = vs[k];
    }
    const uint32_t q[6] = {0, 1, 2, 0, 2, 3};
    for (int k = 0; k < 6; k++)
        m->indices[3 * *t + (size_t)k] = (uint32_t)*v + q[k];
    *v += 4;
    *t += 2;
}

/* One or two quads in one mesh. */
static void quad_mesh(hlod_mesh *m, int quads, const double (*rects)[4])
{
    memset(m, 0, sizeof *m);
    hlod_mesh_alloc(m, 4 * (size_t)quads, 2 * (size_t)quads, HLOD_MESH_NORMALS | HLOD_MESH_UVS);
    size_t v = 0, t = 0;
    for (int q = 0; q < quads; q++)
        add_quad(m, &v, &t, rects[q][0], rects[q][1], rects[q][2], rects[q][3], 0);
}

/* Looking straight down -z at the z = 0 plane from far away with a narrow
 * field of view, so [-1, 1]^2 fills the viewport exactly and every pixel
 * sees its face almost head-on (lighting factor 1 for up-facing faces). */
static void top_camera(hlod_camera *cam)
{
    const double eye[3] = {0, 0, 100}, at[3] = {0, 0, 0}, up[3] = {0, 1, 0};
    double fov = 2 * atan(1.0 / 100) * 180 / M_PI;
    CHECK(hlod_camera_look_at(cam, eye, at, up, fov, 1, 1000, W, H) == HLOD_OK);
}

/* Camera that fits a bounding sphere in the view, from direction dir. */
static void fit_camera(hlod_camera *cam, const double lo[3], const double hi[3], const double dir[3],
                       const double up[3], const double shift[3])
{
    double c[3], r = 0, len = 0;
    for (int a = 0; a < 3; a++) {
        c[a] = 0.5 * (lo[a] + hi[a]);
        r += (hi[a] - lo[a]) * (hi[a] - lo[a]);
        len += dir[a] * dir[a];
    }
    r = 0.5 * sqrt(r);
    len = sqrt(len);
    double fov = 50, d = r / sin(fov * M_PI / 360);
    double eye[3], at[3];
    for (int a = 0; a < 3; a++) {
        eye[a] = c[a] + d * dir[a] / len + shift[a];
        at[a] = c[a] + shift[a];
    }
    CHECK(hlod_camera_look_at(cam, eye, at, up, fov, 0.01 * r, 4 * d, W, H) == HLOD_OK);
}

/* Area-weighted vertex normals. */
static float *mesh_normals(const hlod_mesh *m)
{
    double *acc = calloc(3 * m->vertex_count, sizeof *acc);
    float *n = malloc(3 * m->vertex_count * sizeof *n);
    for (size_t t = 0; t < m->tri_count; t++) {
        const uint32_t *i = m->indices + 3 * t;
        const double *a = m->positions + 3 * i[0], *b = m->positions + 3 * i[1],
                     *c = m->positions + 3 * i[2];
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double x[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
        for (int k = 0; k < 3; k++)
            for (int a2 = 0; a2 < 3; a2++)
                acc[3 * i[k] + a2] += x[a2];
    }
    for (size_t v = 0; v < m->vertex_count; v++) {
        double *x = acc + 3 * v, l = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        for (int a = 0; a < 3; a++)
            n[3 * v + a] = l > 0 ? (float)(x[a] / l) : 0.0f;
    }
    free(acc);
    return n;
}

static int load_mesh(const char *rel, hlod_mesh *m)
{
    char path[512];
    memset(m, 0, sizeof *m);
    hlod_result r = hlod_mesh_import(check_src_path(rel, path, sizeof path), NULL, m, NULL);
    CHECKF(r == HLOD_OK, "%s: %s (run data/fetch-meshes.sh)", path, hlod_result_str(r));
    return r == HLOD_OK;
}

/* ---------- camera ---------- */

static void mul4(const double *m, const double v[4], double out[4])
{
    for (int r = 0; r < 4; r++)
        out[r] = m[r] * v[0] + m[4 + r] * v[1] + m[8 + r] * v[2] + m[12 + r] * v[3];
}

/* NDC of a world point p. */
static void project(const hlod_camera *cam, const double p[3], double ndc[3], double *w)
{
    double rel[4] = {p[0] - cam->position[0], p[1] - cam->position[1], p[2] - cam->position[2], 1};
    double e[4], c[4];
    mul4(cam->view, rel, e);
    mul4(cam->proj, e, c);
    for (int a = 0; a < 3; a++)
        ndc[a] = c[a] / c[3];
    *w = c[3];
}

static int all_zero(const void *p, size_t n)
{
    const uint8_t *b = p;
    for (size_t i = 0; i < n; i++)
        if (b[i])
            return 0;
    return 1;
}

/* The look-at point lands at the screen centre, up is up, right is right,
 * near and far map to -1 and 1, the rotation is orthonormal; every invalid
 * input is rejected with a zeroed camera. */
static void camera_look_at(void)
{
    const double shifts[2][3] = {{0, 0, 0}, {5e5, 4.1e6, 0}};
    for (int s = 0; s < 2; s++) {
        const double *sh = shifts[s];
        double eye[3] = {1 + sh[0], 2 + sh[1], 3 + sh[2]};
        double at[3] = {4 + sh[0], -1 + sh[1], 5 + sh[2]}, up[3] = {0, 0, 1};
        hlod_camera cam;
        CHECK(hlod_camera_look_at(&cam, eye, at, up, 60, 0.1, 100, 320, 200) == HLOD_OK);
        CHECK(cam.width == 320 && cam.height == 200 && cam.fov_y_deg == 60);
        CHECK(cam.position[0] == eye[0] && cam.position[1] == eye[1] && cam.position[2] == eye[2]);
        double ndc[3], w;
        project(&cam, at, ndc, &w);
        CHECKF(fabs(ndc[0]) < 1e-9 && fabs(ndc[1]) < 1e-9, "%g %g", ndc[0], ndc[1]);
        CHECK(w > 0 && ndc[2] > -1 && ndc[2] < 1);
        double above[3] = {at[0], at[1], at[2] + 0.5};
        project(&cam, above, ndc, &w);
        CHECK(ndc[1] > 0.01 && w > 0);
        /* f x up points right */
        double f[3] = {at[0] - eye[0], at[1] - eye[1], at[2] - eye[2]};
        double fl = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
        double right[3] = {at[0] + f[1] * up[2] - f[2] * up[1], at[1] + f[2] * up[0] - f[0] * up[2],
                           at[2] + f[0] * up[1] - f[1] * up[0]};
        project(&cam, right, ndc, &w);
        CHECK(ndc[0] > 0.01);
        double fw[3];
        hlod_camera_forward(&cam, fw);
        for (int a = 0; a < 3; a++)
            CHECK(fabs(fw[a] - f[a] / fl) < 1e-12);
        double pn[3], pf[3];
        for (int a = 0; a < 3; a++) {
            pn[a] = eye[a] + 0.1 * f[a] / fl;
            pf[a] = eye[a] + 100 * f[a] / fl;
        }
        project(&cam, pn, ndc, &w);
        CHECKF(fabs(ndc[2] + 1) < 1e-6, "near %g", ndc[2]);
        project(&cam, pf, ndc, &w);
        CHECKF(fabs(ndc[2] - 1) < 1e-6, "far %g", ndc[2]);
        /* rotation only: orthonormal 3x3, no translation, w row 0 0 0 1 */
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) {
                double d = 0;
                for (int k = 0; k < 3; k++)
                    d += cam.view[k * 4 + i] * cam.view[k * 4 + j];
                CHECK(fabs(d - (i == j)) < 1e-12);
            }
        CHECK(cam.view[12] == 0 && cam.view[13] == 0 && cam.view[14] == 0 && cam.view[15] == 1);
        CHECK(cam.view[3] == 0 && cam.view[7] == 0 && cam.view[11] == 0);
        /* aspect: a point at the top edge of the frustum maps to ndc y = 1 */
        CHECK(fabs(cam.proj[5] - 1 / tan(M_PI / 6)) < 1e-12);
        CHECK(fabs(cam.proj[0] * 320 / 200 - cam.proj[5]) < 1e-12);
    }

    const double e[3] = {0, 0, 0}, t[3] = {1, 0, 0}, up[3] = {0, 0, 1};
    const double nan3[3] = {NAN, 0, 0}, inf3[3] = {0, INFINITY, 0}, zero3[3] = {0, 0, 0};
    const double par[3] = {-2, 0, 0};
    struct {
        const double *eye, *at, *up;
        double fov, n, f;
        uint32_t w, h;
    } bad[] = {
        {NULL, t, up, 60, 1, 10, 8, 8},   {e, NULL, up, 60, 1, 10, 8, 8},
        {e, t, NULL, 60, 1, 10, 8, 8},    {nan3, t, up, 60, 1, 10, 8, 8},
        {e, inf3, up, 60, 1, 10, 8, 8},   {e, t, nan3, 60, 1, 10, 8, 8},
        {e, e, up, 60, 1, 10, 8, 8},      {e, t, par, 60, 1, 10, 8, 8},
        {e, t, zero3, 60, 1, 10, 8, 8},   {e, t, up, 0, 1, 10, 8, 8},
        {e, t, up, 180, 1, 10, 8, 8},     {e, t, up, -30, 1, 10, 8, 8},
        {e, t, up, NAN, 1, 10, 8, 8},     {e, t, up, 60, 0, 10, 8, 8},
        {e, t, up, 60, -1, 10, 8, 8},     {e, t, up, 60, NAN, 10, 8, 8},
        {e, t, up, 60, 1, 1, 8, 8},       {e, t, up, 60, 1, 0.5, 8, 8},
        {e, t, up, 60, 1, INFINITY, 8, 8}, {e, t, up, 60, 1, 10, 0, 8},
        {e, t, up, 60, 1, 10, 8, 0},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        hlod_camera cam;
        memset(&cam, 0x5a, sizeof cam);
        hlod_result r = hlod_camera_look_at(&cam, bad[i].eye, bad[i].at, bad[i].up, bad[i].fov,
                                            bad[i].n, bad[i].f, bad[i].w, bad[i].h);
        CHECKF(r == HLOD_ERR_INVALID_ARG, "case %zu: %s", i, hlod_result_str(r));
        CHECKF(all_zero(&cam, sizeof cam), "case %zu: camera not zeroed", i);
    }
    CHECK(hlod_camera_look_at(NULL, e, t, up, 60, 1, 10, 8, 8) == HLOD_ERR_INVALID_ARG);
}

/* ---------- rendering ---------- */

/* Nothing drawn: every pixel is the clear colour. */
static void clear_color(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    hlod_renderer_set_clear_color(c.r, 0.25f, 0.5f, 0.75f);
    hlod_camera cam;
    top_camera(&cam);
    uint8_t *rgb = malloc(NPIX * 3);
    render(&c, NULL, 0, &cam, rgb);
    const uint8_t bg[3] = {64, 128, 191};
    size_t off = 0;
    for (size_t i = 0; i < NPIX; i++)
        for (int k = 0; k < 3; k++)
            off += abs((int)rgb[3 * i + k] - (int)bg[k]) > 1;
    CHECKF(off == 0, "%zu channels differ from the clear colour", off);
    free(rgb);
    ctx_close(&c);
}

/* A red quad over the top half of the view shows in the top rows of the
 * image read back (read_rgb flips GL's bottom-up rows). */
static void read_orientation(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    const double rect[1][4] = {{-1, 0, 1, 1}};
    hlod_mesh m;
    quad_mesh(&m, 1, rect);
    const uint8_t red[4] = {255, 0, 0, 255};
    tpay t;
    tpay_opts o = {.rgba = red};
    tpay_from_mesh(&t, &m, &o);
    hlod_camera cam;
    top_camera(&cam);
    uint8_t *rgb = malloc(NPIX * 3);
    render(&c, &t, 1, &cam, rgb);
    const uint8_t *top = pixel(rgb, W / 2, H / 4), *bottom = pixel(rgb, W / 2, 3 * H / 4);
    CHECKF(top[0] > 240 && top[1] < 10 && top[2] < 10, "top %d %d %d", top[0], top[1], top[2]);
    CHECKF(bottom[0] == 0 && bottom[1] == 0 && bottom[2] == 0, "bottom %d %d %d", bottom[0],
           bottom[1], bottom[2]);
    free(rgb);
    tpay_free(&t);
    hlod_mesh_free(&m);
    ctx_close(&c);
}

/* A 2x2 texture (rows top first) on a quad with OBJ-convention UVs (v = 0
 * at the bottom) appears upright and unmirrored, for 1 to 4 channels. */
static void texture_checker(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    const double rect[1][4] = {{-1, -1, 1, 1}};
    hlod_mesh m;
    quad_mesh(&m, 1, rect);
    hlod_camera cam;
    top_camera(&cam);
    uint8_t *rgb = malloc(NPIX * 3);
    /* texels: top-left, top-right, bottom-left, bottom-right */
    const uint8_t rgba[4][4] = {{255, 0, 0, 255}, {0, 255, 0, 128}, {0, 0, 255, 255},
                                {255, 255, 255, 0}};
    const uint8_t grey[4] = {255, 40, 160, 90};
    /* screen positions of the texel centres */
    const int at[4][2] = {{W / 4, H / 4}, {3 * W / 4, H / 4}, {W / 4, 3 * H / 4},
                          {3 * W / 4, 3 * H / 4}};
    for (int ch = 1; ch <= 4; ch++) {
        uint8_t pix[16];
        for (int i = 0; i < 4; i++)
            for (int k = 0; k < ch; k++)
                pix[i * ch + k] = ch <= 2 ? (k == 0 ? grey[i] : rgba[i][3]) : rgba[i][k];
        hlod_image tex = {2, 2, ch, pix};
        tpay t;
        tpay_opts o = {.tex = &tex};
        tpay_from_mesh(&t, &m, &o);
        render(&c, &t, 1, &cam, rgb);
        for (int i = 0; i < 4; i++) {
            const uint8_t *p = pixel(rgb, at[i][0], at[i][1]);
            for (int k = 0; k < 3; k++) {
                int want = ch <= 2 ? grey[i] : rgba[i][k];
                CHECKF(abs((int)p[k] - want) <= 3, "%d channels, texel %d: got %d %d %d", ch, i,
                       p[0], p[1], p[2]);
            }
        }
        tpay_free(&t);
    }
    free(rgb);
    hlod_mesh_free(&m);
    ctx_close(&c);
}

/* The loader's mip chain (texture.h): level sizes, RGB to RGBA, the 2x2
 * mean, grey kept grey, idempotent, nothing done without a texture. */
static void texture_chain(void)
{
    static const uint32_t dims[][3] = {{116, 116, 7}, {871, 871, 10}, {1, 1, 1}, {5, 1, 3},
                                       {1, 6, 3}, {655, 1024, 11}};
    for (size_t d = 0; d < sizeof dims / sizeof dims[0]; d++) {
        uint32_t w = dims[d][0], h = dims[d][1];
        uint8_t *pix = malloc((size_t)w * h * 3);
        for (size_t i = 0; i < (size_t)w * h * 3; i++)
            pix[i] = (uint8_t)(i * 37 + i / 7);
        hlod_store_payload p = {.tex_width = w, .tex_height = h, .tex_channels = 3, .pixels = pix};
        CHECK(hlod_texture_prepare(&p) == HLOD_OK);
        CHECKF(p.tex_levels == dims[d][2] && p.tex_channels == 4 && p.pixels == p.tex_memory,
               "%ux%u: %u levels, %u channels", w, h, p.tex_levels, p.tex_channels);
        if (w == 116) /* 116, 58, 29, 14, 7, 3, 1 squared, by hand: 17,916 texels */
            CHECK(hlod_texture_chain_bytes(w, h, 4) == 4 * 17916);
        /* level 0: the texels with alpha 255 */
        int same = 1;
        for (size_t i = 0; i < (size_t)w * h && same; i++)
            same = !memcmp(p.pixels + 4 * i, pix + 3 * i, 3) && p.pixels[4 * i + 3] == 255;
        CHECKF(same, "%ux%u: level 0 is not the texture", w, h);
        /* level 1's first texel: the rounded mean of level 0's 2x2 block */
        if (w > 1 && h > 1) {
            const uint8_t *l1 = p.pixels + (size_t)w * h * 4;
            for (int k = 0; k < 4; k++) {
                int sum = p.pixels[k] + p.pixels[4 + k] + p.pixels[(size_t)w * 4 + k] +
                          p.pixels[(size_t)w * 4 + 4 + k];
                CHECKF(l1[k] == (sum + 2) / 4, "%ux%u: level 1 channel %d: %d, want %d", w, h,
                       k, l1[k], (sum + 2) / 4);
            }
        }
        const uint8_t *before = p.pixels;
        CHECK(hlod_texture_prepare(&p) == HLOD_OK && p.pixels == before); /* once */
        hlod_store_payload_free(&p); /* frees the chain (ASan: no leak) */
        free(pix);
    }
    /* grey and grey + alpha keep their channels; a flat texture stays flat */
    for (uint32_t ch = 1; ch <= 2; ch++) {
        uint8_t pix[12 * 10 * 2];
        memset(pix, 77, sizeof pix);
        hlod_store_payload p = {.tex_width = 12, .tex_height = 10, .tex_channels = ch,
                                .pixels = pix};
        CHECK(hlod_texture_prepare(&p) == HLOD_OK && p.tex_channels == ch && p.tex_levels == 4);
        size_t n = hlod_texture_chain_bytes(12, 10, ch), flat = 1;
        for (size_t i = 0; i < n; i++)
            flat &= p.pixels[i] == 77;
        CHECKF(flat, "%u channels: the chain of a flat texture is not flat", ch);
        hlod_store_payload_free(&p);
    }
    hlod_store_payload none = {.vertex_count = 3};
    CHECK(hlod_texture_prepare(&none) == HLOD_OK && !none.tex_levels && !none.tex_memory);
}

/* Minified, a texture samples its mip chain: a 64x64 black-and-white
 * checker of 1-texel squares drawn 8 pixels wide is mid grey, whether the
 * loader made the chain or the upload did (the same image), and not the
 * aliased black or white of level 0 alone. */
static void minified_texture(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    const double rect[1][4] = {{-0.05, -0.05, 0.05, 0.05}};
    hlod_mesh m;
    quad_mesh(&m, 1, rect);
    hlod_camera cam;
    top_camera(&cam);
    uint8_t pix[64 * 64 * 3];
    for (int y = 0; y < 64; y++)
        for (int x = 0; x < 64; x++)
            memset(pix + 3 * (y * 64 + x), (x + y) % 2 ? 255 : 0, 3);
    hlod_image tex = {64, 64, 3, pix};
    uint8_t *rgb[2] = {malloc(NPIX * 3), malloc(NPIX * 3)};
    for (int prepared = 0; prepared < 2; prepared++) {
        tpay t;
        tpay_opts o = {.tex = &tex};
        tpay_from_mesh(&t, &m, &o);
        if (prepared)
            CHECK(hlod_texture_prepare(&t.p) == HLOD_OK && t.p.tex_levels == 7);
        render(&c, &t, 1, &cam, rgb[prepared]);
        const uint8_t *mid = pixel(rgb[prepared], W / 2, H / 2);
        CHECKF(abs((int)mid[0] - 128) <= 12 && mid[0] == mid[1] && mid[1] == mid[2],
               "%s chain: centre %d %d %d, want grey 128", prepared ? "loader's" : "upload's",
               mid[0], mid[1], mid[2]);
        free(t.p.tex_memory);
        t.p.tex_memory = NULL;
        tpay_free(&t);
    }
    CHECK(compare("texture_minified", rgb[0], rgb[1], 99) >= 99);
    free(rgb[0]);
    free(rgb[1]);
    hlod_mesh_free(&m);
    ctx_close(&c);
}

/* Untextured triangles use their vertex colour, grey without one; in one
 * payload the first tex_tri_count triangles are textured and the rest are
 * not. */
static void vertex_colors(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    const double rects[2][4] = {{-1, -1, 0, 1}, {0, -1, 1, 1}};
    hlod_mesh m;
    quad_mesh(&m, 2, rects);
    hlod_camera cam;
    top_camera(&cam);
    uint8_t *rgb = malloc(NPIX * 3);
    const uint8_t red[4] = {220, 30, 30, 255};
    uint8_t blue_px[3] = {0, 0, 255};
    hlod_image blue = {1, 1, 3, blue_px};

    tpay t;
    tpay_opts o = {.rgba = red};
    tpay_from_mesh(&t, &m, &o);
    render(&c, &t, 1, &cam, rgb);
    double sum[3] = {0, 0, 0};
    for (size_t i = 0; i < NPIX; i++)
        for (int k = 0; k < 3; k++)
            sum[k] += rgb[3 * i + k];
    CHECKF(sum[0] > 3 * sum[1] && sum[0] > 3 * sum[2] && sum[0] > 150.0 * NPIX,
           "mean %.0f %.0f %.0f", sum[0] / NPIX, sum[1] / NPIX, sum[2] / NPIX);
    tpay_free(&t);

    tpay_opts none = {0};
    tpay_from_mesh(&t, &m, &none);
    render(&c, &t, 1, &cam, rgb);
    const uint8_t *p = pixel(rgb, W / 2 + 10, H / 2 + 10);
    CHECKF(p[0] > 150 && p[0] == p[1] && p[1] == p[2], "no colours: %d %d %d", p[0], p[1], p[2]);
    tpay_free(&t);

    tpay_opts mixed = {.rgba = red, .tex = &blue, .tex_tris = 2};
    tpay_from_mesh(&t, &m, &mixed);
    render(&c, &t, 1, &cam, rgb);
    const uint8_t *l = pixel(rgb, W / 4, H / 2), *r = pixel(rgb, 3 * W / 4, H / 2);
    CHECKF(l[2] > 240 && l[0] < 10 && l[1] < 10, "textured half %d %d %d", l[0], l[1], l[2]);
    CHECKF(r[0] > 200 && r[1] < 40 && r[2] < 40, "coloured half %d %d %d", r[0], r[1], r[2]);
    tpay_free(&t);

    free(rgb);
    hlod_mesh_free(&m);
    ctx_close(&c);
}

/* A unit cube without colours seen from a corner: its three visible faces
 * get three clearly different grey levels (lighting from normals), with
 * payload normals and with face normals from derivatives. */
static void lighting_from_normals(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    hlod_mesh m;
    memset(&m, 0, sizeof m);
    hlod_mesh_alloc(&m, 24, 12, HLOD_MESH_NORMALS | HLOD_MESH_UVS);
    for (int f = 0; f < 6; f++) {
        int axis = f / 2;
        double sgn = f % 2 ? 1 : -1;
        int u = (axis + 1) % 3, v = (axis + 2) % 3;
        const double cu[4] = {-1, 1, 1, -1}, cv[4] = {-1, -1, 1, 1};
        for (int k = 0; k < 4; k++) {
            size_t i = (size_t)f * 4 + (size_t)k;
            double p[3];
            p[axis] = sgn;
            p[u] = cu[k];
            p[v] = sgn > 0 ? cv[k] : -cv[k];   /* counter-clockwise seen from outside */
            for (int a = 0; a < 3; a++) {
                m.positions[3 * i + a] = p[a];
                m.normals[3 * i + a] = a == axis ? (float)sgn : 0.0f;
            }
            m.uvs[2 * i] = m.uvs[2 * i + 1] = 0;
        }
        const uint32_t q[6] = {0, 1, 2, 0, 2, 3};
        for (int k = 0; k < 6; k++)
            m.indices[f * 6 + k] = (uint32_t)(f * 4) + q[k];
    }
    const double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1}, dir[3] = {0.7, -0.4, 0.6},
                 up[3] = {0, 0, 1}, zero[3] = {0, 0, 0};
    hlod_camera cam;
    fit_camera(&cam, lo, hi, dir, up, zero);
    uint8_t *rgb = malloc(NPIX * 3);
    float *no_normals = NULL;
    for (int pass = 0; pass < 2; pass++) {
        if (pass == 1) {
            free(m.normals);
            m.normals = no_normals;
        }
        tpay t;
        tpay_opts o = {0};
        tpay_from_mesh(&t, &m, &o);
        CHECK(pass == 0 ? t.p.normals != NULL : t.p.normals == NULL);
        render(&c, &t, 1, &cam, rgb);
        /* grey at the centres of the three visible faces: all different */
        const double centres[3][3] = {{1, 0, 0}, {0, -1, 0}, {0, 0, 1}};
        int g[3];
        for (int f = 0; f < 3; f++) {
            double ndc[3], w;
            project(&cam, centres[f], ndc, &w);
            int x = (int)((ndc[0] + 1) * 0.5 * W), y = (int)((1 - ndc[1]) * 0.5 * H);
            const uint8_t *p = pixel(rgb, x, y);
            CHECK(p[0] == p[1] && p[1] == p[2]);
            g[f] = p[0];
        }
        fprintf(stderr, "     %s normals: faces +x %d, -y %d, +z %d\n",
                pass ? "derived" : "payload", g[0], g[1], g[2]);
        CHECKF(abs(g[0] - g[1]) >= 8 && abs(g[1] - g[2]) >= 8 && abs(g[0] - g[2]) >= 8,
               "pass %d: face shades %d %d %d", pass, g[0], g[1], g[2]);
        tpay_free(&t);
    }
    free(rgb);
    hlod_mesh_free(&m);
    ctx_close(&c);
}

/* Depth-colour mode colours levels differently; wireframe draws edges only. */
static void modes(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    const double rect[1][4] = {{-0.5, -0.5, 0.5, 0.5}};
    hlod_mesh m;
    quad_mesh(&m, 1, rect);
    const uint8_t red[4] = {220, 30, 30, 255}, black[3] = {0, 0, 0};
    tpay t;
    tpay_opts o = {.rgba = red};
    tpay_from_mesh(&t, &m, &o);
    hlod_camera cam;
    top_camera(&cam);
    uint8_t *a = malloc(NPIX * 3), *b = malloc(NPIX * 3);
    render(&c, &t, 1, &cam, a);
    size_t fill = covered(a, black);
    CHECKF(fill > NPIX / 5 && fill < NPIX / 3, "fill %zu", fill);

    hlod_renderer_set_depth_colors(c.r, 1);
    t.depth = 0;
    render(&c, &t, 1, &cam, a);
    t.depth = 1;
    render(&c, &t, 1, &cam, b);
    const uint8_t *pa = pixel(a, W / 2, H / 2), *pb = pixel(b, W / 2, H / 2);
    CHECKF(abs(pa[0] - pb[0]) + abs(pa[1] - pb[1]) + abs(pa[2] - pb[2]) > 60,
           "depth 0 %d %d %d, depth 1 %d %d %d", pa[0], pa[1], pa[2], pb[0], pb[1], pb[2]);
    CHECK(covered(a, black) == fill);
    hlod_renderer_set_depth_colors(c.r, 0);

    hlod_renderer_set_wireframe(c.r, 1);
    render(&c, &t, 1, &cam, a);
    size_t wire = covered(a, black);
    CHECKF(wire > 0 && wire < fill / 10, "wireframe %zu of %zu", wire, fill);
    const uint8_t *centre = pixel(a, W / 2 + 20, H / 2 + 40);
    CHECK(centre[0] == 0 && centre[1] == 0 && centre[2] == 0);
    hlod_renderer_set_wireframe(c.r, 0);
    render(&c, &t, 1, &cam, b);
    CHECK(covered(b, black) == fill);

    free(a);
    free(b);
    tpay_free(&t);
    hlod_mesh_free(&m);
    ctx_close(&c);
}

/* Real meshes render: not blank, a plausible share of the view, shaded. */
static void real_meshes(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    const char *files[] = {"data/meshes/bunny00.off", "data/meshes/fandisk.off"};
    uint8_t *rgb = malloc(NPIX * 3);
    for (size_t f = 0; f < sizeof files / sizeof files[0]; f++) {
        hlod_mesh m;
        if (!load_mesh(files[f], &m))
            continue;
        float *n = mesh_normals(&m);
        tpay t;
        tpay_opts o = {.normals = n};
        tpay_from_mesh(&t, &m, &o);
        double lo[3], hi[3];
        hlod_mesh_bounds(&m, lo, hi);
        const double dir[3] = {0.3, 0.4, 1}, up[3] = {0, 1, 0}, zero[3] = {0, 0, 0};
        hlod_camera cam;
        fit_camera(&cam, lo, hi, dir, up, zero);
        render(&c, &t, 1, &cam, rgb);
        const uint8_t black[3] = {0, 0, 0};
        double frac = (double)covered(rgb, black) / (double)NPIX;
        size_t hist[256] = {0}, levels = 0;
        for (size_t i = 0; i < NPIX; i++)
            hist[rgb[3 * i]]++;
        for (int g = 1; g < 256; g++)
            levels += hist[g] > 0;
        fprintf(stderr, "     %s: %zu triangles, %.1f%% covered, %zu grey levels\n", files[f],
                m.tri_count, 100 * frac, levels);
        CHECKF(frac > 0.08 && frac < 0.75, "%s: %.3f covered", files[f], frac);
        CHECKF(levels > 40, "%s: %zu grey levels", files[f], levels);
        tpay_free(&t);
        free(n);
        hlod_mesh_free(&m);
    }
    free(rgb);
    ctx_close(&c);
}

/* ---------- the city ---------- */

static char g_dir[512];

typedef struct city {
    hlod_mesh mesh;
    tpay *pay;          /* one textured payload per object */
    size_t count;
    double lo[3], hi[3];
} city;

static void city_free(city *ct)
{
    for (size_t i = 0; i < ct->count; i++)
        tpay_free(&ct->pay[i]);
    free(ct->pay);
    hlod_mesh_free(&ct->mesh);
    memset(ct, 0, sizeof *ct);
}

/* The small city, one payload per block and one for the ground, each with
 * its texture. */
static int city_make(city *ct)
{
    memset(ct, 0, sizeof *ct);
    hlod_city_desc d = {0};
    hlod_city_preset("small", &d);
    d.seed = 7;
    d.texture_dir = g_dir;
    hlod_result r = hlod_city_generate(&d, &ct->mesh, NULL);
    CHECKF(r == HLOD_OK, "%s", hlod_result_str(r));
    if (r != HLOD_OK)
        return 0;
    const hlod_mesh *m = &ct->mesh;
    hlod_mesh_bounds(m, ct->lo, ct->hi);
    float *n = m->normals ? NULL : mesh_normals(m);
    ct->pay = calloc(m->object_count, sizeof *ct->pay);
    uint32_t *tris = malloc(m->tri_count * sizeof *tris);
    for (size_t k = 0; k < m->object_count; k++) {
        const hlod_object *ob = &m->objects[k];
        for (size_t i = 0; i < ob->tri_count; i++)
            tris[i] = (uint32_t)(ob->first_tri + i);
        uint32_t mat = m->tri_material ? m->tri_material[ob->first_tri] : 0;
        hlod_image tex = {0};
        const char *tp = mat < m->material_count ? m->materials[mat].texture_path : NULL;
        CHECKF(tp && hlod_image_read(tp, &tex, NULL) == HLOD_OK, "object %zu texture", k);
        tpay_opts o = {.normals = n, .tris = tris, .ntri = ob->tri_count,
                       .tex = tex.pixels ? &tex : NULL};
        tpay_from_mesh(&ct->pay[ct->count], m, &o);
        ct->pay[ct->count].depth = (uint32_t)k;
        ct->count++;
        hlod_image_free(&tex);
    }
    free(tris);
    free(n);
    return ct->count > 0;
}

static void city_camera(const city *ct, hlod_camera *cam, const double shift[3])
{
    const double dir[3] = {0.35, -0.8, 0.55}, up[3] = {0, 0, 1};
    fit_camera(cam, ct->lo, ct->hi, dir, up, shift);
}

/* The city with every origin and the camera moved to (5e5, 4.1e6, 0)
 * renders the same image: offsets are taken in double. */
static void far_origin(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    city ct;
    if (!city_make(&ct)) {
        ctx_close(&c);
        return;
    }
    const double zero[3] = {0, 0, 0}, far[3] = {5e5, 4.1e6, 0};
    uint8_t *a = malloc(NPIX * 3), *b = malloc(NPIX * 3);
    hlod_camera cam;
    city_camera(&ct, &cam, zero);
    render(&c, ct.pay, ct.count, &cam, a);
    const uint8_t black[3] = {0, 0, 0};
    double frac = (double)covered(a, black) / (double)NPIX;
    fprintf(stderr, "     city: %zu payloads, %zu triangles, %.1f%% covered\n", ct.count,
            ct.mesh.tri_count, 100 * frac);
    CHECKF(frac > 0.2, "city covers %.3f", frac);
    /* textured: many distinct colours, not shades of one */
    size_t chroma = 0;
    for (size_t i = 0; i < NPIX; i++) {
        const uint8_t *p = a + 3 * i;
        int mx = p[0] > p[1] ? (p[0] > p[2] ? p[0] : p[2]) : (p[1] > p[2] ? p[1] : p[2]);
        int mn = p[0] < p[1] ? (p[0] < p[2] ? p[0] : p[2]) : (p[1] < p[2] ? p[1] : p[2]);
        chroma += mx - mn > 12;
    }
    CHECKF(chroma > NPIX / 20, "only %zu coloured pixels", chroma);

    for (size_t i = 0; i < ct.count; i++)
        for (int k = 0; k < 3; k++)
            ct.pay[i].origin[k] += far[k];
    city_camera(&ct, &cam, far);
    render(&c, ct.pay, ct.count, &cam, b);
    CHECK(compare("far-origin", a, b, 50) > 50);

    /* depth colours: same coverage, different image */
    hlod_renderer_set_depth_colors(c.r, 1);
    render(&c, ct.pay, ct.count, &cam, b);
    CHECK(covered(b, black) == covered(a, black));
    CHECK(psnr(a, b, NPIX * 3) < 30);
    hlod_renderer_set_depth_colors(c.r, 0);

    free(a);
    free(b);
    city_free(&ct);
    ctx_close(&c);
}

/* A mesh split into two payloads with their own origins renders like the
 * mesh in one payload. */
static void split_node(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    hlod_mesh m;
    if (!load_mesh("data/meshes/bunny00.off", &m)) {
        ctx_close(&c);
        return;
    }
    float *n = mesh_normals(&m);
    double lo[3], hi[3];
    hlod_mesh_bounds(&m, lo, hi);
    /* halves by centroid x, about the middle of the box */
    double mid = 0.5 * (lo[0] + hi[0]);
    uint32_t *left = malloc(m.tri_count * sizeof *left), *right = malloc(m.tri_count * sizeof *right);
    size_t nl = 0, nr = 0;
    for (size_t t = 0; t < m.tri_count; t++) {
        double cx = 0;
        for (int k = 0; k < 3; k++)
            cx += m.positions[3 * m.indices[3 * t + k]];
        if (cx / 3 < mid)
            left[nl++] = (uint32_t)t;
        else
            right[nr++] = (uint32_t)t;
    }
    const uint8_t col[4] = {200, 170, 120, 255};
    tpay whole, parts[2];
    tpay_opts ow = {.normals = n, .rgba = col};
    tpay_opts ol = {.normals = n, .rgba = col, .tris = left, .ntri = nl};
    tpay_opts orr = {.normals = n, .rgba = col, .tris = right, .ntri = nr};
    tpay_from_mesh(&whole, &m, &ow);
    tpay_from_mesh(&parts[0], &m, &ol);
    tpay_from_mesh(&parts[1], &m, &orr);
    CHECK(nl > 1000 && nr > 1000);
    CHECK(parts[0].origin[0] != parts[1].origin[0] && parts[0].origin[0] != whole.origin[0]);

    const double dir[3] = {0.3, 0.4, 1}, up[3] = {0, 1, 0}, zero[3] = {0, 0, 0};
    hlod_camera cam;
    fit_camera(&cam, lo, hi, dir, up, zero);
    uint8_t *a = malloc(NPIX * 3), *b = malloc(NPIX * 3);
    render(&c, &whole, 1, &cam, a);
    render(&c, parts, 2, &cam, b);
    CHECK(compare("split-node", a, b, 50) > 50);

    free(a);
    free(b);
    tpay_free(&whole);
    tpay_free(&parts[0]);
    tpay_free(&parts[1]);
    free(left);
    free(right);
    free(n);
    hlod_mesh_free(&m);
    ctx_close(&c);
}

/* ---------- contexts, renderers, resources ---------- */

/* Two contexts one after the other, and two renderers in one context,
 * render the same image; a renderer outlives its sibling's destruction. */
static void two_renderers(void)
{
    hlod_mesh m;
    if (!load_mesh("data/meshes/fandisk.off", &m))
        return;
    float *n = mesh_normals(&m);
    tpay t;
    tpay_opts o = {.normals = n};
    tpay_from_mesh(&t, &m, &o);
    double lo[3], hi[3];
    hlod_mesh_bounds(&m, lo, hi);
    const double dir[3] = {1, 0.5, 0.8}, up[3] = {0, 0, 1}, zero[3] = {0, 0, 0};
    hlod_camera cam;
    fit_camera(&cam, lo, hi, dir, up, zero);
    uint8_t *img[4];
    for (int i = 0; i < 4; i++)
        img[i] = malloc(NPIX * 3);

    for (int round = 0; round < 2; round++) {
        gl_ctx c;
        if (!ctx_open(&c))
            break;
        render(&c, &t, 1, &cam, img[round]);
        ctx_close(&c);
    }
    const uint8_t black[3] = {0, 0, 0};
    CHECK(covered(img[0], black) > NPIX / 20);
    CHECK(compare("second-context", img[0], img[1], 50) > 50);

    gl_ctx c;
    if (ctx_open(&c)) {
        hlod_renderer *r2 = NULL;
        CHECK(hlod_renderer_create(hlod_osmesa_get_proc(), NULL, &r2) == HLOD_OK);
        hlod_renderer_set_clear_color(r2, 0, 0, 0);
        hlod_renderer_set_wireframe(c.r, 1);   /* state is per renderer */
        hlod_gpu_node g2;
        CHECK(hlod_gpu_upload(r2, &t.p, &g2) == HLOD_OK);
        gl_ctx c2 = {c.o, r2};
        render(&c2, &t, 1, &cam, img[2]);
        CHECK(compare("second-renderer", img[0], img[2], 50) > 50);
        hlod_renderer_destroy(c.r);
        c.r = NULL;
        double off[3];
        for (int a = 0; a < 3; a++)
            off[a] = t.origin[a] - cam.position[a];
        hlod_gpu_begin(r2, &cam);
        hlod_gpu_draw(r2, &g2, off, 0);
        hlod_gpu_end(r2, 1);
        CHECK(hlod_osmesa_read_rgb(c.o, img[3]) == HLOD_OK);
        CHECK(compare("after-sibling-destroyed", img[0], img[3], 50) > 50);
        hlod_gpu_release(r2, &g2);
        hlod_renderer_destroy(r2);
        hlod_osmesa_destroy(c.o);
    }
    for (int i = 0; i < 4; i++)
        free(img[i]);
    tpay_free(&t);
    free(n);
    hlod_mesh_free(&m);
}

/* GL queries for the leak check, loaded like the renderer loads its
 * functions (the test includes no GL header: GLboolean is unsigned char,
 * GLuint unsigned int). */
typedef unsigned char (*gl_is_fn)(unsigned int name);

static gl_is_fn gl_is(const char *name)
{
    void *p = hlod_osmesa_get_proc()(name);
    gl_is_fn f;
    memcpy(&f, &p, sizeof f);
    return f;
}

static void *no_teximage_proc(const char *name)
{
    if (!strcmp(name, "glTexImage2D"))
        return NULL;
    return hlod_osmesa_get_proc()(name);
}

/* Uploads report their bytes and release everything (ASan/LSan watch the
 * loop); bad payloads are refused with a zeroed node; a missing GL
 * function or an oversized texture is reported, not crashed on. */
static void upload_release(void)
{
    gl_ctx c;
    if (!ctx_open(&c))
        return;
    const double rect[1][4] = {{-1, -1, 1, 1}};
    hlod_mesh m;
    quad_mesh(&m, 1, rect);
    uint8_t px[64 * 32 * 3];
    for (size_t i = 0; i < sizeof px; i++)
        px[i] = (uint8_t)(i * 7);
    hlod_image tex = {64, 32, 3, px};
    const uint8_t red[4] = {255, 0, 0, 255};
    tpay t;
    tpay_opts o = {.tex = &tex, .rgba = red};
    tpay_from_mesh(&t, &m, &o);
    /* 4 vertices x (12 + 12 + 8 + 4) + 6 indices x 4 + 64 x 32 x 4 x 4/3 */
    const uint64_t want = 4 * 36 + 24 + 64 * 32 * 4 + 64 * 32 * 4 / 3;
    gl_is_fn is_vao = gl_is("glIsVertexArray"), is_buf = gl_is("glIsBuffer"),
             is_tex = gl_is("glIsTexture");
    CHECK(is_vao && is_buf && is_tex);
    for (int i = 0; i < 200; i++) {
        hlod_gpu_node g;
        CHECK(hlod_gpu_upload(c.r, &t.p, &g) == HLOD_OK);
        CHECK(g.vao && g.vbo && g.ibo && g.tex && g.index_count == 6 && g.tex_index_count == 6);
        CHECKF(g.bytes == want, "%llu bytes, want %llu", (unsigned long long)g.bytes,
               (unsigned long long)want);
        hlod_gpu_node copy = g;
        CHECK(is_vao(copy.vao) && is_buf(copy.vbo) && is_buf(copy.ibo) && is_tex(copy.tex));
        hlod_gpu_release(c.r, &g);
        CHECK(all_zero(&g, sizeof g));
        /* the GL objects are gone, not just forgotten */
        CHECK(!is_vao(copy.vao) && !is_buf(copy.vbo) && !is_buf(copy.ibo) && !is_tex(copy.tex));
        hlod_gpu_release(c.r, &g);   /* zeroed: no-op */
    }
    hlod_gpu_release(c.r, NULL);

    hlod_store_payload bad;
    hlod_gpu_node g;
    const hlod_store_payload *good = &t.p;
    for (int k = 0; k < 6; k++) {
        bad = *good;
        switch (k) {
        case 0: bad.vertex_count = 0; break;
        case 1: bad.index_count = 0; break;
        case 2: bad.index_count = 5; break;
        case 3: bad.positions = NULL; break;
        case 4: bad.tex_tri_count = 3; break;
        case 5: bad.tex_channels = 5; break;
        }
        memset(&g, 0x5a, sizeof g);
        CHECKF(hlod_gpu_upload(c.r, &bad, &g) == HLOD_ERR_INVALID_ARG, "case %d", k);
        CHECK(all_zero(&g, sizeof g));
    }
    CHECK(hlod_gpu_upload(NULL, good, &g) == HLOD_ERR_INVALID_ARG);
    CHECK(hlod_gpu_upload(c.r, NULL, &g) == HLOD_ERR_INVALID_ARG);
    CHECK(hlod_gpu_upload(c.r, good, NULL) == HLOD_ERR_INVALID_ARG);

    /* over GL_MAX_TEXTURE_SIZE (pixels are never read then) */
    rec_log rl = {{0}, 0};
    hlod_logger lg = {rec_fn, &rl};
    hlod_renderer *r2 = NULL;
    CHECK(hlod_renderer_create(hlod_osmesa_get_proc(), &lg, &r2) == HLOD_OK);
    bad = *good;
    bad.tex_width = 1u << 20;
    CHECK(hlod_gpu_upload(r2, &bad, &g) == HLOD_ERR_UNSUPPORTED);
    CHECK(all_zero(&g, sizeof g) && rl.count == 1 && strstr(rl.last, "texture"));
    hlod_renderer_destroy(r2);

    /* a payload without texture but with textured triangles draws them coloured */
    bad = *good;
    bad.pixels = NULL;
    CHECK(hlod_gpu_upload(c.r, &bad, &g) == HLOD_OK);
    CHECK(g.tex == 0 && g.tex_index_count == 0 && g.index_count == 6);
    hlod_gpu_release(c.r, &g);

    rl.count = 0;
    r2 = (hlod_renderer *)&rl;
    CHECK(hlod_renderer_create(no_teximage_proc, &lg, &r2) == HLOD_ERR_UNSUPPORTED);
    CHECK(r2 == NULL && rl.count == 1 && strstr(rl.last, "glTexImage2D"));
    CHECK(hlod_renderer_create(NULL, &lg, &r2) == HLOD_ERR_INVALID_ARG);
    CHECK(hlod_osmesa_read_rgb(c.o, NULL) == HLOD_ERR_INVALID_ARG);
    hlod_osmesa *o2 = NULL;
    CHECK(hlod_osmesa_create(0, 16, NULL, &o2) == HLOD_ERR_INVALID_ARG && !o2);

    tpay_free(&t);
    hlod_mesh_free(&m);
    ctx_close(&c);
    hlod_renderer_destroy(NULL);
    hlod_osmesa_destroy(NULL);
}

static void clear_dir(void)
{
    DIR *d = opendir(g_dir);
    struct dirent *e;
    char p[1024];
    while (d && (e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, "..")) {
            snprintf(p, sizeof p, "%s/%s", g_dir, e->d_name);
            unlink(p);
        }
    if (d)
        closedir(d);
}

int main(void)
{
    const char *tmp = getenv("TMPDIR");
    snprintf(g_dir, sizeof g_dir, "%s/hlod-test-render.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(camera_look_at);
    RUN(clear_color);
    RUN(read_orientation);
    RUN(texture_checker);
    RUN(texture_chain);
    RUN(minified_texture);
    RUN(vertex_colors);
    RUN(lighting_from_normals);
    RUN(modes);
    RUN(real_meshes);
    RUN(far_origin);
    RUN(split_node);
    RUN(two_renderers);
    RUN(upload_release);
    clear_dir();
    rmdir(g_dir);
    return check_done();
}
