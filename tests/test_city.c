/*
 * The synthetic city (preprocess/city.h) and its tool hlod-gen-city:
 * determinism, the triangle budget, objects and textures, exact origin
 * offsets through OBJ and glTF, the untextured variant, closed and
 * non-trivial facade geometry, and the tool's command line and cleanup.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "check.h"
#include "city.h"
#include "hlod/image.h"
#include "hlod/mesh_io.h"
#include "hlod/simplify.h"

static char root[256];  /* a fresh folder under /tmp for this run */

static const char *path_in(char *buf, size_t n, const char *rel)
{
    snprintf(buf, n, "%s/%s", root, rel);
    return buf;
}

static int exists(const char *p)
{
    struct stat st;
    return stat(p, &st) == 0;
}

/* 1 when both files exist and hold the same bytes. */
static int same_bytes(const char *a, const char *b)
{
    size_t na = 0, nb = 0;
    char *x = check_slurp(a, &na), *y = check_slurp(b, &nb);
    int same = x && y && na == nb && memcmp(x, y, na) == 0;
    free(x);
    free(y);
    return same;
}

/* Generates a preset city (textures into DIR/tex unless untextured). */
static hlod_result make_city(const char *preset, const char *dir, const double origin[3],
                             int untextured, hlod_mesh *m, hlod_city_stats *st)
{
    char tex[512];
    hlod_city_desc d = {0};
    CHECK(hlod_city_preset(preset, &d));
    d.seed = 7;
    if (origin)
        memcpy(d.origin, origin, sizeof d.origin);
    d.untextured = untextured;
    mkdir(dir, 0777);
    snprintf(tex, sizeof tex, "%s/tex", dir);
    d.texture_dir = tex;
    return hlod_city_generate(&d, m, st);
}

static int run(const char *cmd)
{
    int rc = system(cmd);
    return rc == -1 || !WIFEXITED(rc) ? -1 : WEXITSTATUS(rc);
}

static const char *tool(void)
{
    static char buf[512];
    const char *bin = getenv("HLOD_BIN_DIR");
    if (!bin)
        return NULL;
    snprintf(buf, sizeof buf, "%s/hlod-gen-city", bin);
    return access(buf, X_OK) == 0 ? buf : NULL;
}

/* ---- determinism ---- */

static void library_is_deterministic(void)
{
    char a[512], b[512], fa[600], fb[600];
    hlod_mesh ma = {0}, mb = {0};
    path_in(a, sizeof a, "det_a");
    path_in(b, sizeof b, "det_b");
    CHECK(make_city("tiny", a, NULL, 0, &ma, NULL) == HLOD_OK);
    CHECK(make_city("tiny", b, NULL, 0, &mb, NULL) == HLOD_OK);
    snprintf(fa, sizeof fa, "%s/city.obj", a);
    snprintf(fb, sizeof fb, "%s/city.obj", b);
    CHECK(hlod_mesh_export(fa, &ma, NULL) == HLOD_OK);
    CHECK(hlod_mesh_export(fb, &mb, NULL) == HLOD_OK);
    CHECK(same_bytes(fa, fb));
    const char *files[] = {"city.mtl", "tex/block_0000.png", "tex/block_0001.png", "tex/ground.png"};
    for (size_t i = 0; i < sizeof files / sizeof files[0]; i++) {
        snprintf(fa, sizeof fa, "%s/%s", a, files[i]);
        snprintf(fb, sizeof fb, "%s/%s", b, files[i]);
        CHECKF(same_bytes(fa, fb), "%s differs", files[i]);
    }
    hlod_mesh_free(&ma);
    hlod_mesh_free(&mb);
}

static void tool_is_deterministic(void)
{
    const char *t = tool();
    if (!t) {
        fprintf(stderr, "  (HLOD_BIN_DIR/hlod-gen-city not found: run through ctest)\n");
        CHECK(getenv("HLOD_BIN_DIR") == NULL);
        return;
    }
    char cmd[2048], a[600], b[600];
    snprintf(cmd, sizeof cmd,
             "mkdir -p %s/tool_a %s/tool_b %s/tool_c && "
             "%s --preset small -o %s/tool_a/c.obj --quiet && "
             "%s --preset small -o %s/tool_b/c.obj --quiet && "
             "%s --preset small --seed 2 -o %s/tool_c/c.obj --quiet",
             root, root, root, t, root, t, root, t, root);
    CHECK(run(cmd) == 0);
    snprintf(a, sizeof a, "%s/tool_a/c.obj", root);
    snprintf(b, sizeof b, "%s/tool_b/c.obj", root);
    CHECK(same_bytes(a, b));
    snprintf(a, sizeof a, "%s/tool_a/c_tex/block_0005.png", root);
    snprintf(b, sizeof b, "%s/tool_b/c_tex/block_0005.png", root);
    CHECK(same_bytes(a, b));
    snprintf(b, sizeof b, "%s/tool_c/c.obj", root);
    snprintf(a, sizeof a, "%s/tool_a/c.obj", root);
    CHECK(!same_bytes(a, b));       /* the seed matters */
}

/* ---- budget, objects, textures ---- */

static void budget_and_objects(void)
{
    char dir[512];
    hlod_mesh m = {0};
    hlod_city_stats st;
    hlod_city_desc d = {0};
    hlod_city_preset("small", &d);
    CHECK(make_city("small", path_in(dir, sizeof dir, "budget"), NULL, 1, &m, &st) == HLOD_OK);
    CHECK(m.object_count == d.blocks + 1);
    CHECK(m.material_count == d.blocks + 1);
    CHECK(hlod_mesh_validate(&m, "city", NULL) == HLOD_OK);
    size_t block_tris = 0;
    for (size_t b = 0; b < d.blocks && b < m.object_count; b++) {
        char name[32];
        snprintf(name, sizeof name, "block_%04zu", b);
        CHECKF(m.objects[b].name && !strcmp(m.objects[b].name, name), "object %zu", b);
        double n = (double)m.objects[b].tri_count, want = (double)d.tris_per_block;
        CHECKF(fabs(n - want) <= 0.10 * want, "block %zu has %g triangles, budget %g", b, n, want);
        block_tris += m.objects[b].tri_count;
        for (size_t t = m.objects[b].first_tri; t < m.objects[b].first_tri + m.objects[b].tri_count; t++)
            if (m.tri_material[t] != b) {
                CHECKF(0, "triangle %zu of block %zu uses material %u", t, b, m.tri_material[t]);
                break;
            }
    }
    CHECK(fabs((double)block_tris - (double)(d.blocks * d.tris_per_block)) <=
          0.10 * (double)(d.blocks * d.tris_per_block));
    CHECK(st.block_tris == block_tris && st.tris == m.tri_count && st.vertices == m.vertex_count);
    CHECK(m.object_count > 0 && !strcmp(m.objects[m.object_count - 1].name, "ground"));
    CHECK(st.ground_tris > 0 && st.tris == st.block_tris + st.ground_tris);
    hlod_mesh_free(&m);

    /* The default's per-block budget, on two blocks. */
    d.blocks = 2;
    d.tris_per_block = 35000;
    d.untextured = 1;
    CHECK(hlod_city_generate(&d, &m, &st) == HLOD_OK);
    for (size_t b = 0; b < 2 && b < m.object_count; b++)
        CHECKF(fabs((double)m.objects[b].tri_count - 35000.0) <= 3500.0, "block %zu: %zu", b,
               m.objects[b].tri_count);
    hlod_mesh_free(&m);
}

static void textures_written(void)
{
    char dir[512];
    hlod_mesh m = {0};
    hlod_city_stats st;
    CHECK(make_city("tiny", path_in(dir, sizeof dir, "tex"), NULL, 0, &m, &st) == HLOD_OK);
    CHECK(m.uvs != NULL);
    CHECK(st.textures == m.material_count);
    CHECK(st.texture_pixels == (uint64_t)st.textures * 64 * 64);
    for (size_t i = 0; m.uvs && i < 2 * m.vertex_count; i++)
        if (!(m.uvs[i] >= 0.0f && m.uvs[i] <= 1.0f)) {
            CHECKF(0, "uv %zu = %g is outside [0, 1]", i, m.uvs[i]);
            break;
        }
    for (size_t k = 0; k < m.object_count; k++) {
        uint32_t mat = m.tri_material[m.objects[k].first_tri];
        const char *tp = m.materials[mat].texture_path;
        CHECKF(tp && exists(tp), "object %zu has no texture on disk", k);
        int w = 0, h = 0, c = 0;
        CHECK(tp && hlod_image_probe(tp, &w, &h, &c, NULL) == HLOD_OK && w == 64 && h == 64 &&
              c == 3);
    }
    /* The atlas is painted: walls, windows and roofs are not one colour. */
    hlod_image img = {0};
    CHECK(m.material_count && hlod_image_read(m.materials[0].texture_path, &img, NULL) == HLOD_OK);
    int lo = 255, hi = 0;
    for (size_t i = 0; img.pixels && i < (size_t)img.width * (size_t)img.height * 3; i++) {
        lo = img.pixels[i] < lo ? img.pixels[i] : lo;
        hi = img.pixels[i] > hi ? img.pixels[i] : hi;
    }
    CHECK(hi - lo > 100);
    hlod_image_free(&img);
    hlod_mesh_free(&m);
}

static void untextured_variant(void)
{
    char dir[512], tex[600];
    hlod_mesh m = {0};
    hlod_city_stats st;
    CHECK(make_city("tiny", path_in(dir, sizeof dir, "untex"), NULL, 1, &m, &st) == HLOD_OK);
    CHECK(m.uvs == NULL);
    CHECK(st.textures == 0 && st.texture_pixels == 0);
    for (size_t i = 0; i < m.material_count; i++) {
        CHECK(m.materials[i].texture_path == NULL);
        CHECK(m.materials[i].diffuse[3] == 1.0f);
    }
    CHECK(m.material_count >= 2 && memcmp(m.materials[0].diffuse, m.materials[1].diffuse,
                                          sizeof m.materials[0].diffuse) != 0);
    snprintf(tex, sizeof tex, "%s/tex", dir);
    CHECK(!exists(tex));
    /* And through a file: no vt, no map_Kd. */
    char obj[600], mtl[600];
    snprintf(obj, sizeof obj, "%s/u.obj", dir);
    snprintf(mtl, sizeof mtl, "%s/u.mtl", dir);
    CHECK(hlod_mesh_export(obj, &m, NULL) == HLOD_OK);
    hlod_mesh back = {0};
    CHECK(hlod_mesh_import(obj, NULL, &back, NULL) == HLOD_OK);
    CHECK(back.uvs == NULL && back.tri_count == m.tri_count);
    for (size_t i = 0; i < back.material_count; i++)
        CHECK(back.materials[i].texture_path == NULL);
    size_t n = 0;
    char *text = check_slurp(mtl, &n);
    CHECK(text && !strstr(text, "map_Kd"));
    free(text);
    hlod_mesh_free(&back);
    hlod_mesh_free(&m);
}

/* ---- exact origin ---- */

static void origin_round_trip(void)
{
    const double off[3] = {5e5, 4.1e6, 0};
    char d0[512], d1[512], f0[600], f1[600], g1[600];
    hlod_mesh m0 = {0}, m1 = {0}, r0 = {0}, r1 = {0}, gl = {0};
    CHECK(make_city("tiny", path_in(d0, sizeof d0, "origin0"), NULL, 0, &m0, NULL) == HLOD_OK);
    CHECK(make_city("tiny", path_in(d1, sizeof d1, "origin1"), off, 0, &m1, NULL) == HLOD_OK);
    snprintf(f0, sizeof f0, "%s/c.obj", d0);
    snprintf(f1, sizeof f1, "%s/c.obj", d1);
    snprintf(g1, sizeof g1, "%s/c.glb", d1);
    CHECK(hlod_mesh_export(f0, &m0, NULL) == HLOD_OK);
    CHECK(hlod_mesh_export(f1, &m1, NULL) == HLOD_OK);
    CHECK(hlod_mesh_export(g1, &m1, NULL) == HLOD_OK);
    hlod_import_stats s0 = {0}, s1 = {0};
    CHECK(hlod_mesh_import(f0, NULL, &r0, &s0) == HLOD_OK);
    CHECK(hlod_mesh_import(f1, NULL, &r1, &s1) == HLOD_OK);
    CHECK(s0.degenerate_dropped == 0 && s0.duplicate_dropped == 0 && s1.missing_textures == 0);
    CHECK(r0.vertex_count == r1.vertex_count && r0.tri_count == r1.tri_count);
    CHECK(r1.vertex_count == m1.vertex_count && r1.object_count == m1.object_count);
    double worst = 0, worst_file = 0;
    for (size_t v = 0; v < r0.vertex_count && v < r1.vertex_count; v++)
        for (int k = 0; k < 3; k++) {
            double d = fabs(r1.positions[3 * v + k] - r0.positions[3 * v + k] - off[k]);
            worst = d > worst ? d : worst;
            /* the OBJ keeps every bit */
            if (v < m1.vertex_count && r1.positions[3 * v + k] != m1.positions[3 * v + k])
                worst_file = 1;
        }
    CHECKF(worst <= 1e-6, "positions differ from the offset by up to %g m", worst);
    CHECK(worst_file == 0);
    /* glTF stores float offsets from a double node translation per object. */
    CHECK(hlod_mesh_import(g1, NULL, &gl, NULL) == HLOD_OK);
    CHECK(gl.tri_count == m1.tri_count);
    double lo[3], hi[3], glo[3], ghi[3];
    CHECK(hlod_mesh_bounds(&m1, lo, hi) && hlod_mesh_bounds(&gl, glo, ghi));
    for (int k = 0; k < 3; k++)
        CHECKF(fabs(lo[k] - glo[k]) < 1e-3 && fabs(hi[k] - ghi[k]) < 1e-3, "axis %d: %.9g vs %.9g",
               k, lo[k], glo[k]);
    CHECK(lo[0] > 4.9e5 && hi[1] < 4.2e6 && lo[1] > 4.0e6);
    hlod_mesh_free(&m0);
    hlod_mesh_free(&m1);
    hlod_mesh_free(&r0);
    hlod_mesh_free(&r1);
    hlod_mesh_free(&gl);
}

/* ---- geometry ---- */

typedef struct wkey {
    double p[3];
    uint32_t v;
} wkey;

static int wkey_cmp(const void *a, const void *b)
{
    const wkey *x = a, *y = b;
    for (int k = 0; k < 3; k++)
        if (x->p[k] != y->p[k])
            return x->p[k] < y->p[k] ? -1 : 1;
    return 0;
}

static int edge_cmp(const void *a, const void *b)
{
    const uint64_t *x = a, *y = b;
    return *x < *y ? -1 : *x > *y;
}

/* Welds the block triangles of m by exact position and checks that every
 * edge has exactly two triangles, except the open bottom rims at ground
 * level: no cracks at corners, mitres, recesses or the roof. */
/* Edges of triangles [first, first + count) after welding positions:
 * open (one triangle), open above the ground, and over two triangles. */
static void edge_counts(const hlod_mesh *m, size_t first, size_t count, size_t *open,
                        size_t *open_high, size_t *over)
{
    *open = *open_high = *over = 0;
    wkey *keys = malloc(m->vertex_count * sizeof *keys);
    uint32_t *id = malloc(m->vertex_count * sizeof *id);
    double *zid = malloc(m->vertex_count * sizeof *zid);
    uint64_t *edges = malloc(3 * count * sizeof *edges);
    CHECK(keys && id && zid && edges);
    if (!keys || !id || !zid || !edges)
        goto done;
    for (size_t v = 0; v < m->vertex_count; v++) {
        memcpy(keys[v].p, m->positions + 3 * v, sizeof keys[v].p);
        keys[v].v = (uint32_t)v;
    }
    qsort(keys, m->vertex_count, sizeof *keys, wkey_cmp);
    uint32_t next = 0;
    for (size_t i = 0; i < m->vertex_count; i++) {
        if (i && wkey_cmp(&keys[i], &keys[i - 1]))
            next++;
        id[keys[i].v] = next;
        zid[next] = keys[i].p[2];
    }
    size_t ne = 0;
    for (size_t t = first; t < first + count; t++)
        for (int k = 0; k < 3; k++) {
            uint64_t a = id[m->indices[3 * t + k]], b = id[m->indices[3 * t + (k + 1) % 3]];
            CHECK(a != b);
            edges[ne++] = a < b ? a << 32 | b : b << 32 | a;
        }
    qsort(edges, ne, sizeof *edges, edge_cmp);
    for (size_t i = 0; i < ne;) {
        size_t j = i;
        while (j < ne && edges[j] == edges[i])
            j++;
        if (j - i > 2)
            (*over)++;
        if (j - i == 1) {
            (*open)++;
            double za = zid[edges[i] >> 32], zb = zid[(uint32_t)edges[i]];
            if (fabs(za) > 0.05 || fabs(zb) > 0.05)
                (*open_high)++;
        }
        i = j;
    }
done:
    free(keys);
    free(id);
    free(zid);
    free(edges);
}

/* Closed but for the bottom: an open edge must be a wall's bottom, on the
 * ground; no edge in more than two triangles. */
static void check_closed(const hlod_mesh *m, size_t first, size_t count)
{
    size_t open, open_high, over;
    edge_counts(m, first, count, &open, &open_high, &over);
    CHECKF(open_high == 0, "%zu open edges above the ground (of %zu open)", open_high, open);
    CHECKF(over == 0, "%zu edges with more than two triangles", over);
    CHECK(open > 0);
}

/* Copies object k into its own mesh (used vertices only). */
static void extract(const hlod_mesh *m, size_t k, hlod_mesh *out)
{
    const hlod_object *o = &m->objects[k];
    uint32_t *map = malloc(m->vertex_count * sizeof *map);
    CHECK(map != NULL);
    if (!map)
        return;
    for (size_t v = 0; v < m->vertex_count; v++)
        map[v] = UINT32_MAX;
    size_t nv = 0;
    for (size_t i = 3 * o->first_tri; i < 3 * (o->first_tri + o->tri_count); i++)
        if (map[m->indices[i]] == UINT32_MAX)
            map[m->indices[i]] = (uint32_t)nv++;
    CHECK(hlod_mesh_alloc(out, nv, o->tri_count, 0) == HLOD_OK);
    for (size_t v = 0; v < m->vertex_count; v++)
        if (map[v] != UINT32_MAX)
            memcpy(out->positions + 3 * map[v], m->positions + 3 * v, 3 * sizeof(double));
    for (size_t i = 0; i < 3 * o->tri_count; i++)
        out->indices[i] = map[m->indices[3 * o->first_tri + i]];
    free(map);
}

static void facades_are_closed_and_detailed(void)
{
    char dir[512];
    hlod_mesh m = {0}, blk = {0}, simp = {0};
    CHECK(make_city("small", path_in(dir, sizeof dir, "detail"), NULL, 1, &m, NULL) == HLOD_OK);
    if (m.object_count < 2)
        return;
    check_closed(&m, 0, m.objects[m.object_count - 1].first_tri);

    /* Not boxes: many faces look down (ledge and cornice soffits, window
     * heads), and faces spread over many distinct planes. */
    extract(&m, 0, &blk);
    size_t down = 0;
    for (size_t t = 0; t < blk.tri_count; t++) {
        const double *a = blk.positions + 3 * blk.indices[3 * t];
        const double *b = blk.positions + 3 * blk.indices[3 * t + 1];
        const double *c = blk.positions + 3 * blk.indices[3 * t + 2];
        double u[3], v[3];
        for (int k = 0; k < 3; k++) {
            u[k] = b[k] - a[k];
            v[k] = c[k] - a[k];
        }
        double nz = u[0] * v[1] - u[1] * v[0];
        double nx = u[1] * v[2] - u[2] * v[1], ny = u[2] * v[0] - u[0] * v[2];
        if (nz < -0.9 * sqrt(nx * nx + ny * ny + nz * nz))
            down++;
    }
    CHECKF(down > blk.tri_count / 50, "%zu of %zu triangles face down", down, blk.tri_count);

    /* Simplifying to 10% must cost more than the noise: recesses and
     * ledges are 10-50 cm deep. */
    hlod_simplify_desc sd = {0};
    sd.target_tris = blk.tri_count / 10;
    sd.measure_error = 1;
    hlod_simplify_stats ss = {0};
    CHECK(hlod_simplify(&blk, &sd, &simp, &ss) == HLOD_OK);
    CHECKF(ss.error > 0.05, "error %g m at 10%%", ss.error);
    hlod_mesh_free(&simp);
    hlod_mesh_free(&blk);
    hlod_mesh_free(&m);

    /* The dense variant is closed too (subdivided grids and recesses). */
    hlod_city_desc d = {0};
    d.blocks = 1;
    d.tris_per_block = 60000;
    d.untextured = 1;
    CHECK(hlod_city_generate(&d, &m, NULL) == HLOD_OK);
    if (m.object_count == 2)
        check_closed(&m, 0, m.objects[1].first_tri);
    hlod_mesh_free(&m);
}

/* ---- errors ---- */

/* ---- the parts style ---- */

static uint32_t find_root(uint32_t *par, uint32_t x)
{
    while (par[x] != x)
        x = par[x] = par[par[x]];
    return x;
}

/* Connected parts of triangles [first, first + count) of m, by shared
 * vertex index (the generator gives every face of a box its own vertices:
 * this counts faces, a lower bound that the budget check uses). */
static size_t parts_of(const hlod_mesh *m, size_t first, size_t count)
{
    uint32_t *par = malloc(m->vertex_count * sizeof *par);
    if (!par)
        return 0;
    for (size_t v = 0; v < m->vertex_count; v++)
        par[v] = (uint32_t)v;
    for (size_t t = first; t < first + count; t++) {
        const uint32_t *ix = m->indices + 3 * t;
        par[find_root(par, ix[0])] = find_root(par, ix[1]);
        par[find_root(par, ix[1])] = find_root(par, ix[2]);
    }
    size_t n = 0;
    uint8_t *seen = calloc(m->vertex_count, 1);
    for (size_t t = first; t < first + count && seen; t++) {
        uint32_t r = find_root(par, m->indices[3 * t]);
        n += !seen[r];
        seen[r] = 1;
    }
    free(seen);
    free(par);
    return n;
}

/* Buildings of separate boxes, untextured, within the budget; the
 * simplifier takes a block to its target, the parts merging as they go. */
static void parts_style(void)
{
    hlod_city_desc d = {0};
    CHECK(hlod_city_preset("tiny", &d));
    d.blocks = 2;
    d.tris_per_block = 6000;
    d.style = HLOD_CITY_STYLE_PARTS;
    hlod_mesh m = {0}, again = {0};
    hlod_city_stats st;
    char dir[512];
    d.texture_dir = path_in(dir, sizeof dir, "parts_tex");
    CHECK(hlod_city_generate(&d, &m, NULL) == HLOD_ERR_INVALID_ARG); /* textured parts: refused */
    d.untextured = 1;
    CHECK(hlod_city_generate(&d, &m, &st) == HLOD_OK);
    CHECK(hlod_city_generate(&d, &again, NULL) == HLOD_OK);
    CHECK(m.tri_count == again.tri_count && m.vertex_count == again.vertex_count &&
          !memcmp(m.positions, again.positions, 3 * m.vertex_count * sizeof *m.positions));
    CHECK(m.uvs == NULL && st.textures == 0);
    CHECK(m.object_count == 3);
    for (size_t b = 0; b < 2 && m.object_count == 3; b++) {
        size_t n = m.objects[b].tri_count, parts = parts_of(&m, m.objects[b].first_tri, n);
        CHECKF(fabs((double)n - 6000) <= 0.15 * 6000, "block %zu: %zu triangles", b, n);
        /* boxes: 12 triangles or more each, every face its own vertices */
        CHECKF(parts >= n / 24, "block %zu: %zu parts in %zu triangles", b, parts, n);
        /* and every box closed once positions are welded (faces meet
         * exactly: no crack), touching boxes sharing edges */
        size_t open, open_high, over;
        edge_counts(&m, m.objects[b].first_tri, n, &open, &open_high, &over);
        CHECKF(open == 0 && over > 0, "block %zu: %zu open edges, %zu shared by boxes", b, open, over);
        if (b == 0) {
            hlod_mesh blk = {0}, out = {0};
            extract(&m, 0, &blk);
            hlod_simplify_desc sd = {0};
            sd.target_tris = 600;
            hlod_simplify_stats ss;
            CHECK(hlod_simplify(&blk, &sd, &out, &ss) == HLOD_OK);
            CHECKF(out.tri_count <= 612 && !strcmp(ss.stop_reason, "target"), "%zu triangles: %s",
                   out.tri_count, ss.stop_reason);
            hlod_mesh_free(&blk);
            hlod_mesh_free(&out);
        }
    }
    hlod_mesh_free(&m);
    hlod_mesh_free(&again);
}

static void bad_descriptions(void)
{
    hlod_mesh m = {0};
    hlod_city_desc d = {0};
    CHECK(hlod_city_preset("tiny", &d));
    CHECK(!hlod_city_preset("huge", &d));
    CHECK(hlod_city_generate(&d, &m, NULL) == HLOD_ERR_INVALID_ARG);   /* no texture folder */
    char dir[512];
    d.texture_dir = path_in(dir, sizeof dir, "bad_tex");
    d.texture_size = 8;
    CHECK(hlod_city_generate(&d, &m, NULL) == HLOD_ERR_INVALID_ARG);
    d.texture_size = 64;
    d.origin[0] = NAN;
    CHECK(hlod_city_generate(&d, &m, NULL) == HLOD_ERR_INVALID_ARG);
    d.origin[0] = 0;
    d.texture_dir = "/nonexistent-folder/tex";
    CHECK(hlod_city_generate(&d, &m, NULL) == HLOD_ERR_IO);
    CHECK(m.tri_count == 0 && m.positions == NULL);
}

static void tool_command_line(void)
{
    const char *t = tool();
    if (!t)
        return;
    char cmd[2048], p[600];
    struct {
        const char *args;
        int status;
    } cases[] = {
        {"", 2},
        {"--preset tiny -o %s/cli/c.ply", 2},
        {"--preset huge -o %s/cli/c.obj", 2},
        {"--blocks 0 -o %s/cli/c.obj", 2},
        {"--blocks 2x -o %s/cli/c.obj", 2},
        {"--origin 1 2 -o %s/cli/c.obj", 2},
        {"--texture-size 8 -o %s/cli/c.obj", 2},
        {"--preset tiny -o %s/cli/missing/c.obj", 1},
    };
    snprintf(cmd, sizeof cmd, "mkdir -p %s/cli", root);
    CHECK(run(cmd) == 0);
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        char args[600];
        snprintf(args, sizeof args, cases[i].args, root);
        snprintf(cmd, sizeof cmd, "%s %s 2>/dev/null >/dev/null", t, args);
        int rc = run(cmd);
        CHECKF(rc == cases[i].status, "'%s' exited %d, expected %d", cases[i].args, rc,
               cases[i].status);
    }
    snprintf(p, sizeof p, "%s/cli/c.obj", root);
    CHECK(!exists(p));

    /* --json on stdout, with the documented keys. */
    snprintf(cmd, sizeof cmd,
             "%s --preset tiny --origin 5e5 4.1e6 0 -o %s/cli/j.glb --json > %s/cli/j.json", t,
             root, root);
    CHECK(run(cmd) == 0);
    snprintf(p, sizeof p, "%s/cli/j.json", root);
    size_t n = 0;
    char *js = check_slurp(p, &n);
    CHECK(js != NULL);
    const char *keys[] = {"\"blocks\": 2,", "\"tris\": ", "\"vertices\": ", "\"textures\": 3,",
                          "\"texture_pixels\": 12288,", "\"bytes_written\": ", "\"seconds\": ",
                          "\"origin\": [500000, 4100000, 0]}"};
    for (size_t i = 0; js && i < sizeof keys / sizeof keys[0]; i++)
        CHECKF(strstr(js, keys[i]) != NULL, "missing %s in %s", keys[i], js);
    free(js);

    /* A mesh that cannot be written (its .mtl name is a folder) leaves
     * neither the mesh nor the texture folder this run created. */
    snprintf(cmd, sizeof cmd, "mkdir -p %s/cli/fail/c.mtl && %s --preset tiny -o %s/cli/fail/c.obj "
             "2>/dev/null", root, t, root);
    CHECK(run(cmd) == 1);
    snprintf(p, sizeof p, "%s/cli/fail/c.obj", root);
    CHECK(!exists(p));
    snprintf(p, sizeof p, "%s/cli/fail/c_tex", root);
    CHECK(!exists(p));
}

int main(void)
{
    snprintf(root, sizeof root, "/tmp/hlod_test_city_XXXXXX");
    if (!mkdtemp(root)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(library_is_deterministic);
    RUN(tool_is_deterministic);
    RUN(budget_and_objects);
    RUN(textures_written);
    RUN(untextured_variant);
    RUN(origin_round_trip);
    RUN(facades_are_closed_and_detailed);
    RUN(parts_style);
    RUN(bad_descriptions);
    RUN(tool_command_line);
    int rc = check_done();
    if (rc == 0) {
        char cmd[512];
        snprintf(cmd, sizeof cmd, "rm -rf %s", root);
        if (system(cmd) != 0)
            fprintf(stderr, "could not remove %s\n", root);
    } else {
        fprintf(stderr, "outputs kept in %s\n", root);
    }
    return rc;
}
