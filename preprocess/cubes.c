/*
 * cubes.c - the six faces of a colour cube (cubes.h, docs/cubes.md).
 *
 * Chamberlain et al., section 4.  Each face is sampled on a
 * HLOD_CUBE_SAMPLES^2 grid; a sample holds the nearest triangle hit
 * inside the box (opaque) and the children's faces over it, each at the
 * depth of its own face plane, composited front to back.  For children
 * that tile the box (an octree's) this is the paper's figure 3: the front
 * four faces over the back four, then averaged; children that do not
 * tile it (loose cells) are composited where they lie.
 */
#include "cubes.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define S HLOD_CUBE_SAMPLES
#define MAX_LAYERS 16

typedef struct layer {
    float d;                    /* depth from the face plane, inwards */
    float rgba[4];              /* premultiplied */
} layer;

/* The nearest triangle under each sample of face f: best[] its index
 * (SIZE_MAX none), w[] its barycentric weights, depth[] its depth. */
static void nearest(const hlod_cube_in *in, int f, float *depth, size_t *best, double (*w)[3])
{
    const int a = f / 2, plus = !(f & 1), u = (a + 1) % 3, v = (a + 2) % 3;
    const double eu = in->hi[u] - in->lo[u], ev = in->hi[v] - in->lo[v],
                 ea = in->hi[a] - in->lo[a], tol = 1e-9 * (fabs(eu) + fabs(ev) + fabs(ea));
    for (int s = 0; s < S * S; s++) {
        depth[s] = INFINITY;
        best[s] = SIZE_MAX;
    }
    if (!(eu > 0) || !(ev > 0))
        return; /* a face of no area */
    const char *base = in->tris;
    for (size_t t = 0; t < in->n; t++) {
        const double *p = (const double *)(const void *)(base + t * in->stride);
        double U[3], V[3], D[3];
        for (int k = 0; k < 3; k++) {
            U[k] = (p[3 * k + u] - in->lo[u]) / eu * S - 0.5;   /* in sample units */
            V[k] = (p[3 * k + v] - in->lo[v]) / ev * S - 0.5;
            D[k] = plus ? in->hi[a] - p[3 * k + a] : p[3 * k + a] - in->lo[a];
        }
        double area2 = (U[1] - U[0]) * (V[2] - V[0]) - (U[2] - U[0]) * (V[1] - V[0]);
        if (!(fabs(area2) > 1e-12))
            continue; /* edge-on: covers no area of this face */
        double umin = fmin(U[0], fmin(U[1], U[2])), umax = fmax(U[0], fmax(U[1], U[2])),
               vmin = fmin(V[0], fmin(V[1], V[2])), vmax = fmax(V[0], fmax(V[1], V[2]));
        int i0 = (int)fmax(0, ceil(umin)), i1 = (int)fmin(S - 1, floor(umax)),
            j0 = (int)fmax(0, ceil(vmin)), j1 = (int)fmin(S - 1, floor(vmax));
        for (int j = j0; j <= j1; j++)
            for (int i = i0; i <= i1; i++) {
                double w1 = ((i - U[0]) * (V[2] - V[0]) - (U[2] - U[0]) * (j - V[0])) / area2,
                       w2 = ((U[1] - U[0]) * (j - V[0]) - (i - U[0]) * (V[1] - V[0])) / area2,
                       w0 = 1 - w1 - w2;
                if (w0 < -1e-9 || w1 < -1e-9 || w2 < -1e-9)
                    continue;
                double d = w0 * D[0] + w1 * D[1] + w2 * D[2];
                int s = j * S + i;
                if (d < -tol || d > ea + tol || !(d < depth[s]))
                    continue;
                depth[s] = (float)fmax(d, 0);
                best[s] = t;
                w[s][0] = w0;
                w[s][1] = w1;
                w[s][2] = w2;
            }
    }
}

/* Does the child's face cover sample (i, j) of face f? */
static int covers(const hlod_cube_in *in, size_t k, int f, int i, int j)
{
    const int a = f / 2, u = (a + 1) % 3, v = (a + 2) % 3;
    double su = in->lo[u] + (i + 0.5) / S * (in->hi[u] - in->lo[u]),
           sv = in->lo[v] + (j + 0.5) / S * (in->hi[v] - in->lo[v]);
    return su >= in->kid_lo[k][u] && su <= in->kid_hi[k][u] && sv >= in->kid_lo[k][v] &&
           sv <= in->kid_hi[k][v];
}

void hlod_cube_faces(const hlod_cube_in *in, hlod_cube *out)
{
    static const float white[3] = {1, 1, 1};
    float depth[S * S];
    size_t best[S * S];
    double w[S * S][3];
    memset(out, 0, sizeof *out);
    for (int f = 0; f < 6; f++) {
        const int a = f / 2, plus = !(f & 1);
        nearest(in, f, depth, best, w);
        double sum[4] = {0, 0, 0, 0};
        for (int j = 0; j < S; j++)
            for (int i = 0; i < S; i++) {
                int s = j * S + i;
                layer L[MAX_LAYERS];
                int nl = 0;
                if (best[s] != SIZE_MAX) {
                    float rgb[3];
                    if (in->color)
                        in->color(in->user, best[s], w[s], rgb);
                    else
                        memcpy(rgb, white, sizeof rgb);
                    L[nl++] = (layer){depth[s], {rgb[0], rgb[1], rgb[2], 1}};
                }
                for (size_t k = 0; k < in->nkids && nl < MAX_LAYERS; k++) {
                    const float *c = in->kids[k].rgba[f];
                    if (!(c[3] > 0) || !covers(in, k, f, i, j))
                        continue;
                    double d = plus ? in->hi[a] - in->kid_hi[k][a] : in->kid_lo[k][a] - in->lo[a];
                    /* kept sorted by depth (the own hit too): a tie keeps the
                     * earlier layer in front */
                    int at = nl;
                    while (at > 0 && L[at - 1].d > (float)d) {
                        L[at] = L[at - 1];
                        at--;
                    }
                    L[at] = (layer){(float)d, {c[0], c[1], c[2], c[3]}};
                    nl++;
                }
                double acc[4] = {0, 0, 0, 0};
                for (int q = 0; q < nl && acc[3] < 1; q++) {
                    double t = 1 - acc[3];
                    for (int c = 0; c < 4; c++)
                        acc[c] += t * L[q].rgba[c];
                }
                for (int c = 0; c < 4; c++)
                    sum[c] += acc[c];
            }
        for (int c = 0; c < 4; c++) {
            double x = sum[c] / (S * S);
            out->rgba[f][c] = (float)(x < 0 ? 0 : x > 1 ? 1 : x);
        }
    }
}

void hlod_cube_pack(const hlod_cube *c, uint8_t out[6][4])
{
    for (int f = 0; f < 6; f++)
        for (int k = 0; k < 4; k++) {
            float x = c->rgba[f][k];
            out[f][k] = (uint8_t)lrintf((x < 0 ? 0 : x > 1 ? 1 : x) * 255);
        }
}

void hlod_cube_unpack(const uint8_t in[6][4], hlod_cube *c)
{
    for (int f = 0; f < 6; f++)
        for (int k = 0; k < 4; k++)
            c->rgba[f][k] = in[f][k] / 255.0f;
}

void hlod_pixel_rgba(const uint8_t *p, int channels, uint8_t out[4])
{
    switch (channels) {
    case 1: out[0] = out[1] = out[2] = p[0]; out[3] = 255; break;
    case 2: out[0] = out[1] = out[2] = p[0]; out[3] = p[1]; break;
    case 3: out[0] = p[0]; out[1] = p[1]; out[2] = p[2]; out[3] = 255; break;
    default: memcpy(out, p, 4); break;
    }
}

void hlod_cube_texel(const uint8_t *pixels, int w, int h, int channels, double u, double v,
                     uint8_t out[4])
{
    u -= floor(u);
    v -= floor(v);
    int x = (int)(u * w), y = (int)((1 - v) * h);
    x = x < 0 ? 0 : x >= w ? w - 1 : x;
    y = y < 0 ? 0 : y >= h ? h - 1 : y;
    hlod_pixel_rgba(pixels + ((size_t)y * w + x) * channels, channels, out);
}

/* The renderer's colour of a node without texture or vertex colours
 * (gl_render.c's DEFAULT_GREY). */
#define PAYLOAD_GREY 0.8f

static void payload_color(void *user, size_t t, const double w[3], float rgb[3])
{
    const hlod_store_payload_desc *p = user;
    const uint32_t *ix = p->indices + 3 * t;
    if (t < p->tex_tri_count && p->pixels && p->uvs) {
        double u = 0, v = 0;
        for (int k = 0; k < 3; k++) {
            u += w[k] * p->uvs[2 * ix[k]];
            v += w[k] * p->uvs[2 * ix[k] + 1];
        }
        uint8_t px[4];
        hlod_cube_texel(p->pixels, (int)p->tex_width, (int)p->tex_height, (int)p->tex_channels, u,
                        v, px);
        for (int c = 0; c < 3; c++)
            rgb[c] = px[c] / 255.0f;
    } else if (p->colors) {
        for (int c = 0; c < 3; c++) {
            double x = 0;
            for (int k = 0; k < 3; k++)
                x += w[k] * p->colors[4 * ix[k] + c];
            rgb[c] = (float)(x / 255);
        }
    } else {
        rgb[0] = rgb[1] = rgb[2] = PAYLOAD_GREY;
    }
}

hlod_result hlod_cube_of_payload(const hlod_store_payload_desc *p, uint8_t out[6][4])
{
    double (*P)[9] = malloc((size_t)p->tri_count * sizeof *P);
    if (!P)
        return HLOD_ERR_NOMEM;
    hlod_cube_in in = {.lo = {INFINITY, INFINITY, INFINITY},
                       .hi = {-INFINITY, -INFINITY, -INFINITY},
                       .tris = P, .stride = sizeof *P, .n = p->tri_count,
                       .color = payload_color, .user = (void *)p};
    for (uint32_t i = 0; i < p->vertex_count; i++)
        for (int a = 0; a < 3; a++) {
            in.lo[a] = fmin(in.lo[a], p->positions[3 * i + a]);
            in.hi[a] = fmax(in.hi[a], p->positions[3 * i + a]);
        }
    for (uint32_t t = 0; t < p->tri_count; t++)
        for (int k = 0; k < 3; k++)
            memcpy(&P[t][3 * k], p->positions + 3 * (size_t)p->indices[3 * t + k], 3 * sizeof(double));
    hlod_cube c;
    hlod_cube_faces(&in, &c);
    hlod_cube_pack(&c, out);
    free(P);
    return HLOD_OK;
}
