/*
 * test_node_texture.c - per-node atlas repacking (hlod_node_texture): a node
 * whose charts are scattered over its block's atlas gets a texture no
 * larger than its charts, and every point of its triangles still samples
 * the texel it sampled in the source.
 *
 * The source atlas encodes each texel's position in its colour (R = x,
 * G = row from the top), so a fetch tells which source texel it came from.
 */
#include "check.h"
#include "build.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

#define SRC 256     /* source atlas side */
#define CHART 48    /* chart side in texels */
#define NCHART 16   /* charts: 4 x 4 cells of 64 texels */
#define GRID 6      /* quads per wall side */

/* R = x, G = row from the top, B = a hash of both: every texel distinct. */
static void coded_atlas(hlod_image *img)
{
    img->width = img->height = SRC;
    img->channels = 3;
    img->pixels = malloc((size_t)SRC * SRC * 3);
    for (int y = 0; y < SRC; y++)
        for (int x = 0; x < SRC; x++) {
            uint8_t *p = img->pixels + ((size_t)y * SRC + x) * 3;
            p[0] = (uint8_t)x;
            p[1] = (uint8_t)y;
            p[2] = (uint8_t)(x * 7 + y * 13);
        }
}

/* Chart of wall i: a scrambled cell, so that walls side by side in space
 * sit far apart in the atlas (as the city's shelf-packed charts do).
 * Returns the chart's lower-left corner in texels, y up. */
static void chart_origin(int i, int *cx, int *cy)
{
    int cell = (i * 7 + 3) % NCHART;
    *cx = (cell % 4) * 64 + 8;
    *cy = (cell / 4) * 64 + 8;
}

/* UV of a point on wall i at local (s, t) in [0, 1]^2. */
static void wall_uv(int i, double s, double t, float uv[2])
{
    int cx, cy;
    chart_origin(i, &cx, &cy);
    uv[0] = (float)((cx + s * CHART) / SRC);
    uv[1] = (float)((cy + t * CHART) / SRC);
}

/* Walls first..first+count-1 of a row: wall i is a bumpy GRID x GRID quad
 * grid over x in [1.5 i, 1.5 i + 1], z in [0, 1], at y ~ 0, with its own
 * vertices (a chart per wall). */
static void walls(hlod_mesh *m, int first, int count)
{
    size_t per_v = (GRID + 1) * (GRID + 1), per_t = 2 * GRID * GRID;
    hlod_mesh_alloc(m, per_v * count, per_t * count, HLOD_MESH_UVS);
    for (int w = 0; w < count; w++) {
        int i = first + w;
        for (int b = 0; b <= GRID; b++)
            for (int a = 0; a <= GRID; a++) {
                size_t v = per_v * w + (size_t)b * (GRID + 1) + a;
                double s = (double)a / GRID, t = (double)b / GRID;
                m->positions[3 * v] = 1.5 * i + s;
                m->positions[3 * v + 1] = 0.05 * sin(3.1 * s + 1.7 * i) * cos(2.3 * t);
                m->positions[3 * v + 2] = t;
                wall_uv(i, s, t, m->uvs + 2 * v);
            }
        for (int b = 0; b < GRID; b++)
            for (int a = 0; a < GRID; a++) {
                uint32_t p = (uint32_t)(per_v * w) + (uint32_t)(b * (GRID + 1) + a), q = p + 1,
                         r = p + GRID + 1, s = r + 1;
                uint32_t *x = m->indices + 3 * (per_t * w + 2 * ((size_t)b * GRID + a));
                x[0] = p, x[1] = q, x[2] = s, x[3] = p, x[4] = s, x[5] = r;
            }
    }
}

/* Nearest-texel fetch at (u, v), v = 0 the bottom row: the source texel
 * coded in the colour, (x, row from the top). */
static void fetch(const hlod_image *img, double u, double v, int *sx, int *sy)
{
    int x = (int)floor(u * img->width), y = (int)floor((1 - v) * img->height);
    x = x < 0 ? 0 : x >= img->width ? img->width - 1 : x;
    y = y < 0 ? 0 : y >= img->height ? img->height - 1 : y;
    const uint8_t *p = img->pixels + ((size_t)y * img->width + x) * img->channels;
    *sx = p[0];
    *sy = p[1];
}

/* Samples each triangle at a lattice of interior barycentric points and
 * compares the node texture at the rewritten UVs with the source texture
 * at the original ones; original UVs come from `orig_uv` (per vertex) or,
 * when NULL, from the position (wall index and local coordinates). */
static void check_samples(const hlod_mesh *m, const float *orig_uv, const hlod_image *node,
                          const hlod_image *src, size_t *exact, size_t *total, int *worst)
{
    for (size_t t = 0; t < m->tri_count; t++) {
        const uint32_t *x = m->indices + 3 * t;
        for (int a = 0; a < 8; a++)
            for (int b = 0; a + b < 8; b++) {
                /* off the texel grid (the walls' vertices sit on it) */
                double w[3] = {(a + 0.31) / 8.7, (b + 0.17) / 8.7, 0};
                w[2] = 1 - w[0] - w[1];
                double nu = 0, nv = 0, ou = 0, ov = 0, px = 0, pz = 0;
                for (int k = 0; k < 3; k++) {
                    nu += w[k] * m->uvs[2 * x[k]];
                    nv += w[k] * m->uvs[2 * x[k] + 1];
                    px += w[k] * m->positions[3 * x[k]];
                    pz += w[k] * m->positions[3 * x[k] + 2];
                    if (orig_uv) {
                        ou += w[k] * orig_uv[2 * x[k]];
                        ov += w[k] * orig_uv[2 * x[k] + 1];
                    }
                }
                if (!orig_uv) {
                    int i = (int)floor(px / 1.5);
                    float uv[2];
                    wall_uv(i, px - 1.5 * i, pz, uv);
                    ou = uv[0];
                    ov = uv[1];
                }
                int ax, ay, bx, by;
                fetch(node, nu, nv, &ax, &ay);
                fetch(src, ou, ov, &bx, &by);
                int d = abs(ax - bx) > abs(ay - by) ? abs(ax - bx) : abs(ay - by);
                *worst = d > *worst ? d : *worst;
                *exact += d == 0;
                (*total)++;
            }
    }
}

/* A node holding 4 of the 16 scattered charts (a leaf, factor 1): its
 * texture is the four charts with their gutters, not the atlas's UV box,
 * and samples the same texels. */
static void quarter_of_the_charts_is_a_small_texture(void)
{
    hlod_image src = {0};
    coded_atlas(&src);
    hlod_mesh m = {0};
    walls(&m, 6, 4);
    float *orig = malloc(m.vertex_count * 2 * sizeof *orig);
    memcpy(orig, m.uvs, m.vertex_count * 2 * sizeof *orig);
    /* the four charts' UV box spans most of the atlas */
    float lo[2] = {1, 1}, hi[2] = {0, 0};
    for (size_t v = 0; v < m.vertex_count; v++)
        for (int k = 0; k < 2; k++) {
            lo[k] = fminf(lo[k], orig[2 * v + k]);
            hi[k] = fmaxf(hi[k], orig[2 * v + k]);
        }
    CHECK((hi[0] - lo[0]) * (hi[1] - lo[1]) > 0.5f);

    hlod_image t = {0};
    CHECK(hlod_node_texture(&src, &m, 1, &t) == HLOD_OK);
    CHECK(t.channels == 3 && t.pixels);
    /* 4 charts of (48 + 2 * 2 gutter)^2 texels, packed */
    double area = (double)t.width * t.height, charts = 4.0 * 52 * 52;
    CHECKF(area >= charts && area < 1.25 * charts, "%dx%d for %.0f texels of charts", t.width, t.height,
           charts);
    CHECKF(area < 0.25 * SRC * SRC, "%dx%d", t.width, t.height);
    for (size_t v = 0; v < 2 * m.vertex_count; v++)
        CHECK(m.uvs[v] >= 0 && m.uvs[v] <= 1);

    size_t exact = 0, total = 0;
    int worst = 0;
    check_samples(&m, orig, &t, &src, &exact, &total, &worst);
    CHECKF(exact == total && worst == 0, "%zu of %zu samples exact, worst %d texels", exact, total, worst);

    free(orig);
    hlod_image_free(&t);
    hlod_image_free(&src);
    hlod_mesh_free(&m);
}

/* Two charts far apart: each is copied with two texels of gutter taken
 * from around it in the source. */
static void gutter_copies_the_source(void)
{
    hlod_image src = {0};
    coded_atlas(&src);
    hlod_mesh m = {0};
    walls(&m, 0, 2);
    hlod_image t = {0};
    CHECK(hlod_node_texture(&src, &m, 1, &t) == HLOD_OK);
    /* two charts of 48 x 48 texels (their UVs fall on texel edges) plus two
     * texels of gutter a side */
    CHECKF(t.width * t.height >= 2 * 52 * 52 && t.width * t.height <= 3 * 52 * 52, "%dx%d", t.width,
           t.height);
    size_t per_v = (GRID + 1) * (GRID + 1);
    for (int i = 0; i < 2; i++) {
        /* the chart's lower-left vertex (s = t = 0) lands on the corner of
         * its content: the gutter starts two texels left of it and 48 + 2
         * rows above it */
        const float *uv = m.uvs + 2 * per_v * (size_t)i;
        int X = (int)lround(uv[0] * t.width) - 2, Y = (int)lround((1 - uv[1]) * t.height) - CHART - 2;
        CHECK(X >= 0 && Y >= 0 && X + 52 <= t.width && Y + 52 <= t.height);
        if (X < 0 || Y < 0 || X + 52 > t.width || Y + 52 > t.height)
            continue;
        int cx, cy;
        chart_origin(i, &cx, &cy);
        int x0 = cx - 2, y0 = SRC - cy - CHART - 2; /* rows from the top */
        int bad = 0;
        for (int y = 0; y < 52; y++)
            for (int x = 0; x < 52; x++) {
                const uint8_t *p = t.pixels + ((size_t)(Y + y) * t.width + X + x) * 3;
                bad += p[0] != (uint8_t)(x0 + x) || p[1] != (uint8_t)(y0 + y);
            }
        CHECKF(bad == 0, "chart %d: %d texels differ from the source", i, bad);
    }
    hlod_image_free(&t);
    hlod_image_free(&src);
    hlod_mesh_free(&m);
}

/* Charts that share UVs (tiles of one texture) are copied once: two charts
 * three times each make an atlas of two. */
static void charts_on_the_same_texels_share_them(void)
{
    hlod_image src = {0};
    coded_atlas(&src);
    hlod_mesh a = {0}, m = {0};
    walls(&a, 0, 2);
    /* three copies of both walls, each with its own vertices */
    hlod_mesh_alloc(&m, 3 * a.vertex_count, 3 * a.tri_count, HLOD_MESH_UVS);
    for (size_t c = 0; c < 3; c++) {
        memcpy(m.positions + 3 * c * a.vertex_count, a.positions, 3 * a.vertex_count * sizeof(double));
        for (size_t v = 0; v < a.vertex_count; v++)
            m.positions[3 * (c * a.vertex_count + v) + 1] += 2.0 * c;
        memcpy(m.uvs + 2 * c * a.vertex_count, a.uvs, 2 * a.vertex_count * sizeof(float));
        for (size_t i = 0; i < 3 * a.tri_count; i++)
            m.indices[3 * c * a.tri_count + i] = a.indices[i] + (uint32_t)(c * a.vertex_count);
    }
    hlod_image t = {0};
    CHECK(hlod_node_texture(&src, &m, 1, &t) == HLOD_OK);
    CHECKF(t.width * t.height >= 2 * 52 * 52 && t.width * t.height <= 3 * 52 * 52, "%dx%d", t.width,
           t.height);
    hlod_image_free(&t);
    hlod_image_free(&src);
    hlod_mesh_free(&a);
    hlod_mesh_free(&m);
}

/* UVs outside [0, 1] spanning a period or more on both axes (a repeating
 * texture) keep the whole image and their UVs, shrunk by sqrt(factor) per
 * side. */
static void wrapping_uvs_keep_the_whole_image(void)
{
    hlod_image src = {0};
    coded_atlas(&src);
    hlod_mesh m = {0};
    walls(&m, 0, 2);
    m.uvs[0] = 2.0f; /* u spans 0.53 .. 2, v 0.03 .. 2 */
    m.uvs[1] = 2.0f;
    float *orig = malloc(m.vertex_count * 2 * sizeof *orig);
    memcpy(orig, m.uvs, m.vertex_count * 2 * sizeof *orig);
    hlod_image t = {0};
    CHECK(hlod_node_texture(&src, &m, 1, &t) == HLOD_OK);
    CHECK(t.width == SRC && t.height == SRC && !memcmp(t.pixels, src.pixels, (size_t)SRC * SRC * 3));
    CHECK(!memcmp(orig, m.uvs, m.vertex_count * 2 * sizeof *orig));
    hlod_image_free(&t);
    CHECK(hlod_node_texture(&src, &m, 4, &t) == HLOD_OK);
    CHECK(t.width == SRC / 2 && t.height == SRC / 2);
    free(orig);
    hlod_image_free(&t);
    hlod_image_free(&src);
    hlod_mesh_free(&m);
}

/* The texel of img under (u, v), v up, repeating. */
static const uint8_t *texel_at(const hlod_image *img, double u, double v)
{
    long x = (long)floor(u * img->width), yb = (long)floor(v * img->height);
    x %= img->width;
    yb %= img->height;
    x += x < 0 ? img->width : 0;
    yb += yb < 0 ? img->height : 0;
    return img->pixels + ((size_t)(img->height - 1 - yb) * img->width + (size_t)x) * img->channels;
}

/* A node of a repeating texture whose UVs lie within one period, placed
 * whole periods away and straddling the image's edge on both axes (the
 * ground's leaves): it gets a small crop read across the edge, and every
 * triangle's centre samples the texel it sampled in the source. */
static void wrapping_uvs_within_a_period_are_cropped_across_the_edge(void)
{
    hlod_image src = {0};
    coded_atlas(&src);
    hlod_mesh m = {0};
    walls(&m, 0, 1);
    int cx, cy;
    chart_origin(0, &cx, &cy);
    /* the chart's corner to (3 + 0.9, -2 + 0.95): past both edges */
    double du = 3.9 - (double)cx / SRC, dv = -2 + 0.95 - (double)cy / SRC;
    for (size_t v = 0; v < m.vertex_count; v++) {
        m.uvs[2 * v] = (float)(m.uvs[2 * v] + du);
        m.uvs[2 * v + 1] = (float)(m.uvs[2 * v + 1] + dv);
    }
    float *orig = malloc(m.vertex_count * 2 * sizeof *orig);
    memcpy(orig, m.uvs, m.vertex_count * 2 * sizeof *orig);
    hlod_image t = {0};
    CHECK(hlod_node_texture(&src, &m, 1, &t) == HLOD_OK);
    CHECKF(t.width <= CHART + 4 && t.height <= CHART + 4, "crop %dx%d for a %d-texel chart",
           t.width, t.height, CHART);
    int bad = 0;
    for (size_t f = 0; f < m.tri_count && t.pixels; f++) {
        double u0 = 0, v0 = 0, u1 = 0, v1 = 0;
        for (int k = 0; k < 3; k++) {
            uint32_t i = m.indices[3 * f + k];
            u0 += orig[2 * i] / 3.0;
            v0 += orig[2 * i + 1] / 3.0;
            u1 += m.uvs[2 * i] / 3.0;
            v1 += m.uvs[2 * i + 1] / 3.0;
        }
        CHECK(u1 >= 0 && u1 <= 1 && v1 >= 0 && v1 <= 1);
        bad += memcmp(texel_at(&src, u0, v0), texel_at(&t, u1, v1), 3) != 0;
    }
    CHECKF(bad == 0, "%d of %zu triangle centres sample another texel", bad, m.tri_count);
    free(orig);
    hlod_image_free(&t);
    hlod_image_free(&src);
    hlod_mesh_free(&m);
}

/* A coarse node (factor 9) shrinks its packed atlas by 3 per side and
 * keeps each sample within the shrink's footprint of its source texel. */
static void coarse_node_shrinks_the_packed_atlas(void)
{
    hlod_image src = {0};
    coded_atlas(&src);
    hlod_mesh m = {0};
    walls(&m, 0, 4);
    float *orig = malloc(m.vertex_count * 2 * sizeof *orig);
    memcpy(orig, m.uvs, m.vertex_count * 2 * sizeof *orig);
    hlod_image full = {0}, t = {0};
    hlod_mesh m1 = {0};
    hlod_mesh_copy(&m1, &m);
    CHECK(hlod_node_texture(&src, &m1, 1, &full) == HLOD_OK);
    CHECK(hlod_node_texture(&src, &m, 9, &t) == HLOD_OK);
    /* gutters grow to 2 * sqrt(9) = 6 source texels before the shrink, so
     * the shrunk atlas is about (4 charts of 60^2) / 9 */
    double area = (double)t.width * t.height;
    CHECKF(area >= 4.0 * 60 * 60 / 9 * 0.95 && area < 1.25 * 4 * 60 * 60 / 9, "%dx%d", t.width, t.height);
    CHECK(t.width < full.width && t.height < full.height);
    /* box-filtered: each sample is an average of nearby source texels; the
     * coded colours are linear in x and y inside a chart, so it decodes to
     * about the original texel */
    size_t exact = 0, total = 0;
    int worst = 0;
    check_samples(&m, orig, &t, &src, &exact, &total, &worst);
    CHECKF(worst <= 3, "worst %d texels (of %zu samples)", worst, total);
    free(orig);
    hlod_image_free(&full);
    hlod_image_free(&t);
    hlod_image_free(&src);
    hlod_mesh_free(&m);
    hlod_mesh_free(&m1);
}

/* Cut-plane build of 16 walls whose charts are scattered: the four leaves
 * (a quarter of the charts each) have textures well under the source's,
 * and their triangles -- split by the cuts -- sample the source's texels. */
static void cutplane_leaves_get_small_correct_textures(void)
{
    hlod_image src = {0};
    coded_atlas(&src);
    hlod_mesh m = {0};
    walls(&m, 0, NCHART);
    hlod_build_params p = {0};
    p.desired_tris = m.tri_count / 4; /* s0 = 4: root, then leaves */
    p.level_factor = 4;
    p.seed = 1;
    hlod_btree t;
    CHECK(hlod_build_cutplane(&m, &src, &p, &t) == HLOD_OK);
    size_t leaves = 0;
    for (size_t k = 1; k < t.count; k++) {
        const hlod_bnode *n = &t.nodes[k];
        CHECK(n->depth == 1);
        leaves++;
        double area = (double)n->tex.width * n->tex.height;
        CHECKF(area < 0.5 * SRC * SRC, "leaf %zu: %dx%d", k, n->tex.width, n->tex.height);
        size_t exact = 0, total = 0;
        int worst = 0;
        check_samples(&n->mesh, NULL, &n->tex, &src, &exact, &total, &worst);
        /* cut vertices carry interpolated float UVs: a sample on a texel
         * edge may round to its neighbour */
        CHECKF(worst <= 1 && exact >= total - total / 100, "leaf %zu: %zu of %zu exact, worst %d", k, exact,
               total, worst);
    }
    CHECKF(leaves == 4, "%zu leaves", leaves);
    /* the root (factor 4) is no larger than the whole atlas shrunk by 2 */
    CHECK(t.nodes[0].tex.width * t.nodes[0].tex.height <= SRC * SRC / 4);
    hlod_btree_free(&t);
    hlod_image_free(&src);
    hlod_mesh_free(&m);
}

/* Same input, same texture and UVs, byte for byte. */
static void repacking_is_deterministic(void)
{
    hlod_image src = {0};
    coded_atlas(&src);
    hlod_mesh a = {0}, b = {0};
    walls(&a, 3, 9);
    hlod_mesh_copy(&b, &a);
    hlod_image ta = {0}, tb = {0};
    CHECK(hlod_node_texture(&src, &a, 2.5, &ta) == HLOD_OK);
    CHECK(hlod_node_texture(&src, &b, 2.5, &tb) == HLOD_OK);
    CHECK(ta.width == tb.width && ta.height == tb.height);
    CHECK(ta.width == tb.width && ta.height == tb.height &&
          !memcmp(ta.pixels, tb.pixels, (size_t)ta.width * ta.height * 3));
    CHECK(!memcmp(a.uvs, b.uvs, a.vertex_count * 2 * sizeof(float)));
    hlod_image_free(&ta);
    hlod_image_free(&tb);
    hlod_image_free(&src);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

int main(void)
{
    RUN(quarter_of_the_charts_is_a_small_texture);
    RUN(gutter_copies_the_source);
    RUN(charts_on_the_same_texels_share_them);
    RUN(wrapping_uvs_keep_the_whole_image);
    RUN(wrapping_uvs_within_a_period_are_cropped_across_the_edge);
    RUN(coarse_node_shrinks_the_packed_atlas);
    RUN(cutplane_leaves_get_small_correct_textures);
    RUN(repacking_is_deterministic);
    return check_done();
}
