/*
 * city_levels.c - group nodes above the blocks (docs/store-format.md).
 *
 * Grouping (the plan, made before any block is built): the blocks are
 * split by the centres of their input boxes, recursively at the median of
 * the axis of largest spread, into ceil(n / group_size) parts of nearly
 * equal size; a part of at most group_size items is a group.  Each level's
 * groups, with the union of their children's boxes, become the next
 * level's items until one is left: the root.  The plan depends on the
 * input alone, not on what simplification makes of it, so a shard of a
 * sharded build (docs/sharded-builds.md) knows the whole tree after
 * reading the blocks' boxes, and builds whole subtrees of it.
 *
 * A group node:
 * 1. Atlas: the textured children's textures are shelf-packed, with a
 *    gutter of repeated edge texels, into one image; a child whose UVs
 *    repeat the texture (outside [0, 1]) gets the periods its UVs span
 *    tiled, up to MAX_PERIODS, and beyond that its texture's average
 *    colour (a group is seen from afar).
 * 2. Union: the children's triangles in one mesh, UVs moved into the
 *    atlas; untextured triangles carry a material per colour (a triangle
 *    takes its first vertex's colour), the textured ones material 0, so the
 *    simplifier keeps colour and texture regions apart (material borders
 *    are seams to it).
 * 3. Simplified to target_tris (the simplifier's part pruning and
 *    relaxation are the aggregation: small separate parts go first, then
 *    the rest coarsens as a whole).
 * 4. Error: the certified Hausdorff bound between the node and the union,
 *    plus the largest child error (each child is within its error of the
 *    original triangles it stands for, so the node is within the sum).
 * 5. Output: textured triangles first, their texture repacked from the
 *    atlas and shrunk by the simplification factor (hlod_node_texture), then
 *    the untextured ones with per-vertex colours.
 */
#include "city_levels.h"

#include "hlod/simplify.h"
#include "hlod/store.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#define MAX_PERIODS 16  /* repeats of a wrapping texture tiled into an atlas */
#define GUTTER 2        /* texels of repeated edge around each atlas entry */
#define UV_SLACK 1e-3f  /* UVs this far outside [0, 1] still count as inside */

void hlod_city_item_free(hlod_city_item *it)
{
    hlod_mesh_free(&it->mesh);
    hlod_image_free(&it->tex);
    free(it->colors);
    memset(it, 0, sizeof *it);
}

/* ---- 1. the atlas ---- */

/* One textured child's entry: its (tiled) image at (x, y) of the atlas. */
typedef struct entry {
    hlod_image img;         /* the child's texture, tiled px x py times */
    int x, y;               /* top-left texel of the image in the atlas */
    float u0, v0;           /* whole periods subtracted from the UVs */
    int px, py;
    int textured;           /* 0: its textured triangles became a colour */
    uint8_t avg[4];         /* that colour */
} entry;

static void texel_rgba(const hlod_image *im, int x, int y, uint8_t out[4])
{
    const uint8_t *p = im->pixels + ((size_t)y * im->width + x) * im->channels;
    switch (im->channels) {
    case 1: out[0] = out[1] = out[2] = p[0]; out[3] = 255; break;
    case 2: out[0] = out[1] = out[2] = p[0]; out[3] = p[1]; break;
    case 3: memcpy(out, p, 3); out[3] = 255; break;
    default: memcpy(out, p, 4); break;
    }
}

static void average_rgba(const hlod_image *im, uint8_t out[4])
{
    double sum[4] = {0};
    for (int y = 0; y < im->height; y++)
        for (int x = 0; x < im->width; x++) {
            uint8_t t[4];
            texel_rgba(im, x, y, t);
            for (int k = 0; k < 4; k++)
                sum[k] += t[k];
        }
    double n = (double)im->width * im->height;
    for (int k = 0; k < 4; k++)
        out[k] = (uint8_t)lrint(n > 0 ? sum[k] / n : 255);
}

/* UV box of the child's textured vertices. */
static void textured_uv_box(const hlod_city_item *c, float lo[2], float hi[2])
{
    lo[0] = lo[1] = INFINITY;
    hi[0] = hi[1] = -INFINITY;
    for (size_t t = 0; t < c->tex_tris; t++)
        for (int j = 0; j < 3; j++) {
            const float *uv = c->mesh.uvs + 2 * c->mesh.indices[3 * t + j];
            for (int k = 0; k < 2; k++) {
                lo[k] = uv[k] < lo[k] ? uv[k] : lo[k];
                hi[k] = uv[k] > hi[k] ? uv[k] : hi[k];
            }
        }
}

/* The entry of a textured child: its texture, tiled when its UVs repeat. */
static hlod_result make_entry(const hlod_city_item *c, entry *e)
{
    memset(e, 0, sizeof *e);
    float lo[2], hi[2];
    textured_uv_box(c, lo, hi);
    e->px = e->py = 1;
    if (lo[0] < -UV_SLACK || lo[1] < -UV_SLACK || hi[0] > 1 + UV_SLACK || hi[1] > 1 + UV_SLACK) {
        e->u0 = floorf(lo[0]);
        e->v0 = floorf(lo[1]);
        double px = ceil((double)hi[0]) - e->u0, py = ceil((double)hi[1]) - e->v0;
        e->px = px < 1 ? 1 : (int)px;
        e->py = py < 1 ? 1 : (int)py;
        if (!(px * py <= MAX_PERIODS) || (double)c->tex.width * e->px > 16384 ||
            (double)c->tex.height * e->py > 16384) {
            average_rgba(&c->tex, e->avg);
            return HLOD_OK; /* textured = 0: a colour */
        }
    }
    const hlod_image *s = &c->tex;
    int w = s->width * e->px, h = s->height * e->py;
    e->img = (hlod_image){w, h, s->channels, malloc((size_t)w * h * s->channels)};
    if (!e->img.pixels)
        return HLOD_ERR_NOMEM;
    size_t row = (size_t)s->width * s->channels;
    for (int y = 0; y < h; y++)
        for (int i = 0; i < e->px; i++)
            memcpy(e->img.pixels + (size_t)y * w * s->channels + i * row,
                   s->pixels + (size_t)(y % s->height) * row, row);
    e->textured = 1;
    return HLOD_OK;
}

typedef struct shelf_key {
    int h, w;
    size_t i;
} shelf_key;

static int cmp_shelf(const void *pa, const void *pb)
{
    const shelf_key *a = pa, *b = pb;
    if (a->h != b->h)
        return a->h > b->h ? -1 : 1;
    if (a->w != b->w)
        return a->w > b->w ? -1 : 1;
    return a->i < b->i ? -1 : a->i > b->i;
}

/* Shelf-packs the textured entries (tallest first) and copies them into
 * *atlas with their gutters.  Leaves atlas->width 0 when none is textured. */
static hlod_result pack_entries(entry *e, size_t n, hlod_image *atlas)
{
    memset(atlas, 0, sizeof *atlas);
    shelf_key *keys = malloc((n + 1) * sizeof *keys);
    if (!keys)
        return HLOD_ERR_NOMEM;
    size_t m = 0;
    double area = 0;
    int widest = 0, channels = 0, has2 = 0;
    for (size_t i = 0; i < n; i++) {
        if (!e[i].textured)
            continue;
        int w = e[i].img.width + 2 * GUTTER, h = e[i].img.height + 2 * GUTTER;
        keys[m++] = (shelf_key){h, w, i};
        area += (double)w * h;
        widest = w > widest ? w : widest;
        channels = e[i].img.channels > channels ? e[i].img.channels : channels;
        has2 |= e[i].img.channels == 2;
    }
    if (!m) {
        free(keys);
        return HLOD_OK;
    }
    /* mixed grey-alpha and colour (or grey-alpha alone): RGBA */
    if (channels == 2 || (has2 && channels == 3))
        channels = 4;
    qsort(keys, m, sizeof *keys, cmp_shelf);
    int width = (int)ceil(sqrt(area) * 1.15);
    width = width < widest ? widest : width;
    int x = 0, y = 0, shelf = 0;
    for (size_t k = 0; k < m; k++) {
        if (x + keys[k].w > width) {
            y += shelf;
            x = shelf = 0;
        }
        e[keys[k].i].x = x + GUTTER;
        e[keys[k].i].y = y + GUTTER;
        x += keys[k].w;
        shelf = keys[k].h > shelf ? keys[k].h : shelf;
    }
    int height = y + shelf;
    free(keys);
    *atlas = (hlod_image){width, height, channels, calloc((size_t)width * height, (size_t)channels)};
    if (!atlas->pixels)
        return HLOD_ERR_NOMEM;
    for (size_t i = 0; i < n; i++) {
        if (!e[i].textured)
            continue;
        const hlod_image *s = &e[i].img;
        for (int dy = -GUTTER; dy < s->height + GUTTER; dy++)
            for (int dx = -GUTTER; dx < s->width + GUTTER; dx++) {
                int sx = dx < 0 ? 0 : dx >= s->width ? s->width - 1 : dx;
                int sy = dy < 0 ? 0 : dy >= s->height ? s->height - 1 : dy;
                uint8_t t[4];
                texel_rgba(s, sx, sy, t);
                uint8_t *d = atlas->pixels +
                             ((size_t)(e[i].y + dy) * width + (e[i].x + dx)) * channels;
                if (channels == 1)
                    d[0] = t[0];
                else
                    memcpy(d, t, (size_t)channels);
            }
    }
    return HLOD_OK;
}

/* ---- 2. the union ---- */

typedef struct palette {
    uint8_t (*rgba)[4];
    size_t n, cap;
    size_t last;
} palette;

/* Index of colour c, added when new; SIZE_MAX when out of memory. */
static size_t palette_index(palette *p, const uint8_t c[4])
{
    if (p->n && memcmp(p->rgba[p->last], c, 4) == 0)
        return p->last;
    for (size_t i = 0; i < p->n; i++)
        if (memcmp(p->rgba[i], c, 4) == 0)
            return p->last = i;
    if (p->n == p->cap) {
        size_t nc = p->cap ? 2 * p->cap : 16;
        void *nr = realloc(p->rgba, nc * sizeof *p->rgba);
        if (!nr)
            return SIZE_MAX;
        p->rgba = nr;
        p->cap = nc;
    }
    memcpy(p->rgba[p->n], c, 4);
    return p->last = p->n++;
}

static const uint8_t *vertex_color(const hlod_city_item *c, uint32_t v)
{
    return c->colors ? c->colors + 4 * (size_t)v : c->color;
}

/* Maps the atlas position of a child's UV. */
static void atlas_uv(const entry *e, const hlod_image *atlas, const float uv[2], float out[2])
{
    double u = ((double)uv[0] - e->u0) / e->px, v = ((double)uv[1] - e->v0) / e->py;
    double col = e->x + u * e->img.width, row = e->y + (1 - v) * e->img.height;
    out[0] = (float)(col / atlas->width);
    out[1] = (float)(1 - row / atlas->height);
}

/* The union of the children (step 2).  vmap: scratch of the largest
 * child's vertex count.  *tex_tris_in: its textured triangles. */
static hlod_result make_union(const hlod_city_item *const *kids, size_t n, const entry *e,
                              const hlod_image *atlas, palette *pal, hlod_mesh *u,
                              size_t *tex_tris_in)
{
    size_t nv = 0, nt = 0, maxv = 0;
    for (size_t i = 0; i < n; i++) {
        nv += 2 * kids[i]->mesh.vertex_count; /* at most twice: textured and not */
        nt += kids[i]->mesh.tri_count;
        maxv = kids[i]->mesh.vertex_count > maxv ? kids[i]->mesh.vertex_count : maxv;
    }
    unsigned flags = HLOD_MESH_MATERIALS | (atlas->width ? HLOD_MESH_UVS : 0);
    hlod_result r = hlod_mesh_alloc(u, nv, nt, flags);
    uint32_t *vmap = malloc(2 * (maxv + 1) * sizeof *vmap);
    if (r != HLOD_OK || !vmap) {
        free(vmap);
        return HLOD_ERR_NOMEM;
    }
    size_t v_out = 0, t_out = 0;
    *tex_tris_in = 0;
    for (size_t i = 0; i < n && r == HLOD_OK; i++) {
        const hlod_city_item *c = kids[i];
        int textured = e[i].textured && atlas->width;
        for (size_t k = 0; k < 2 * c->mesh.vertex_count; k++)
            vmap[k] = UINT32_MAX;
        for (size_t t = 0; t < c->mesh.tri_count; t++) {
            const uint32_t *tri = c->mesh.indices + 3 * t;
            int tx = textured && t < c->tex_tris;
            uint32_t mat = 0;
            if (!tx) {
                const uint8_t *col = t < c->tex_tris ? e[i].avg : vertex_color(c, tri[0]);
                size_t pi = palette_index(pal, col);
                if (pi == SIZE_MAX) {
                    r = HLOD_ERR_NOMEM;
                    break;
                }
                mat = (uint32_t)(pi + 1);
            } else {
                (*tex_tris_in)++;
            }
            for (int j = 0; j < 3; j++) {
                uint32_t *slot = &vmap[2 * (size_t)tri[j] + (tx ? 0 : 1)];
                if (*slot == UINT32_MAX) {
                    *slot = (uint32_t)v_out;
                    memcpy(u->positions + 3 * v_out, c->mesh.positions + 3 * (size_t)tri[j],
                           3 * sizeof(double));
                    if (u->uvs) {
                        float *dst = u->uvs + 2 * v_out;
                        if (tx)
                            atlas_uv(&e[i], atlas, c->mesh.uvs + 2 * (size_t)tri[j], dst);
                        else
                            dst[0] = dst[1] = 0;
                    }
                    v_out++;
                }
                u->indices[3 * t_out + j] = *slot;
            }
            u->tri_material[t_out++] = mat;
        }
    }
    free(vmap);
    if (r != HLOD_OK)
        return r;
    u->vertex_count = v_out;
    u->tri_count = t_out;
    u->material_count = 1 + pal->n;
    u->materials = calloc(u->material_count, sizeof *u->materials);
    if (!u->materials)
        return HLOD_ERR_NOMEM;
    for (size_t k = 0; k < u->material_count; k++) {
        float d[4] = {1, 1, 1, 1};
        if (k)
            for (int j = 0; j < 4; j++)
                d[j] = pal->rgba[k - 1][j] / 255.0f;
        memcpy(u->materials[k].diffuse, d, sizeof d);
    }
    return HLOD_OK;
}

/* ---- 5. the node ---- */

/* Reorders s (the simplified union) into out: material-0 (textured)
 * triangles first, a vertex once per material it is used with. */
static hlod_result split_by_material(const hlod_mesh *s, const palette *pal, hlod_city_item *out)
{
    size_t nt = s->tri_count, nv = s->vertex_count;
    uint32_t *order = malloc((nt + 1) * sizeof *order);
    uint32_t *stamp = malloc((nv + 1) * sizeof *stamp), *remap = malloc((nv + 1) * sizeof *remap);
    size_t *count = calloc(s->material_count + 1, sizeof *count);
    hlod_result r = HLOD_ERR_NOMEM;
    if (!order || !stamp || !remap || !count)
        goto done;
    /* counting sort by material: stable, so triangle order follows the input */
    for (size_t t = 0; t < nt; t++)
        count[s->tri_material[t] + 1]++;
    for (size_t m = 1; m <= s->material_count; m++)
        count[m] += count[m - 1];
    for (size_t t = 0; t < nt; t++)
        order[count[s->tri_material[t]]++] = (uint32_t)t;
    /* vertices: each (vertex, material) once, in triangle order */
    size_t cap = 3 * nt;
    r = hlod_mesh_alloc(&out->mesh, cap, nt, s->uvs ? HLOD_MESH_UVS : 0);
    if (r != HLOD_OK)
        goto done;
    int untextured = 0;
    for (size_t t = 0; t < nt; t++)
        untextured |= s->tri_material[t] != 0;
    if (untextured && !(out->colors = malloc(4 * cap))) {
        r = HLOD_ERR_NOMEM;
        goto done;
    }
    for (size_t v = 0; v < nv; v++)
        stamp[v] = UINT32_MAX;
    size_t v_out = 0;
    out->tex_tris = 0;
    for (size_t k = 0; k < nt; k++) {
        uint32_t t = order[k], mat = s->tri_material[t];
        out->tex_tris += mat == 0;
        for (int j = 0; j < 3; j++) {
            uint32_t v = s->indices[3 * (size_t)t + j];
            if (stamp[v] != mat) {
                stamp[v] = mat;
                remap[v] = (uint32_t)v_out;
                memcpy(out->mesh.positions + 3 * v_out, s->positions + 3 * (size_t)v, 3 * sizeof(double));
                if (s->uvs)
                    memcpy(out->mesh.uvs + 2 * v_out, s->uvs + 2 * (size_t)v, 2 * sizeof(float));
                if (out->colors) {
                    static const uint8_t white[4] = {255, 255, 255, 255};
                    memcpy(out->colors + 4 * v_out, mat ? pal->rgba[mat - 1] : white, 4);
                }
                v_out++;
            }
            out->mesh.indices[3 * k + j] = remap[v];
        }
    }
    out->mesh.vertex_count = v_out;
    /* one colour for every vertex: no per-vertex array */
    if (out->colors && !out->tex_tris) {
        int same = 1;
        for (size_t v = 1; v < v_out && same; v++)
            same = memcmp(out->colors + 4 * v, out->colors, 4) == 0;
        if (same) {
            memcpy(out->color, out->colors, 4);
            free(out->colors);
            out->colors = NULL;
        }
    }
    r = HLOD_OK;
done:
    free(order);
    free(stamp);
    free(remap);
    free(count);
    return r;
}

/* Step 5's texture: the textured part's own atlas, repacked from the
 * union's and shrunk by factor. */
static hlod_result node_texture(const hlod_image *atlas, hlod_city_item *out, double factor)
{
    if (!out->tex_tris || !atlas->width)
        return HLOD_OK;
    /* the textured vertices come first: a view of them */
    size_t nv = 0;
    for (size_t i = 0; i < 3 * out->tex_tris; i++)
        nv = out->mesh.indices[i] + 1 > nv ? out->mesh.indices[i] + 1 : nv;
    hlod_mesh view = {0};
    view.vertex_count = nv;
    view.positions = out->mesh.positions;
    view.uvs = out->mesh.uvs;
    view.tri_count = out->tex_tris;
    view.indices = out->mesh.indices;
    return hlod_node_texture(atlas, &view, factor, &out->tex);
}

/* One group node from its children (steps 1-5 above). */
static hlod_result city_group(const hlod_city_item *const *kids, size_t n, size_t target_tris,
                              const hlod_logger *lg, hlod_city_item *out)
{
    memset(out, 0, sizeof *out);
    if (!kids || !n || !target_tris)
        return HLOD_ERR_INVALID_ARG;
    entry *e = calloc(n, sizeof *e);
    if (!e)
        return HLOD_ERR_NOMEM;
    hlod_result r = HLOD_OK;
    double child_error = 0;
    int solid = 1;
    for (size_t i = 0; i < n && r == HLOD_OK; i++) {
        const hlod_city_item *c = kids[i];
        if (c->tex_tris && c->tex.width && c->mesh.uvs)
            r = make_entry(c, &e[i]);
        else
            memcpy(e[i].avg, c->color, 4); /* textured triangles without a texture */
        child_error = c->error > child_error ? c->error : child_error;
        solid &= c->solid;
        out->source_tris += c->source_tris;
    }
    hlod_image atlas = {0};
    hlod_mesh u = {0}, s = {0};
    palette pal = {0};
    size_t tex_in = 0;
    if (r == HLOD_OK)
        r = pack_entries(e, n, &atlas);
    if (r == HLOD_OK)
        r = make_union(kids, n, e, &atlas, &pal, &u, &tex_in);
    if (r == HLOD_OK) {
        hlod_simplify_desc d = {0};
        d.strict_texture = 1; /* HLOD nodes: no smeared texture (docs/hlod-build.md) */
        d.target_tris = target_tris;
        d.logger = lg;
        r = u.tri_count > target_tris ? hlod_simplify(&u, &d, &s, NULL) : hlod_mesh_copy(&s, &u);
    }
    double err = 0;
    if (r == HLOD_OK && s.tri_count < u.tri_count)
        r = hlod_node_error(&s, &u, &err);
    if (r == HLOD_OK)
        r = split_by_material(&s, &pal, out);
    if (r == HLOD_OK && out->tex_tris)
        r = node_texture(&atlas, out, (double)tex_in / (double)out->tex_tris);
    if (r == HLOD_OK) {
        out->error = err + child_error;
        out->solid = solid && hlod_mesh_is_solid(&out->mesh);
    }
    for (size_t i = 0; i < n; i++)
        hlod_image_free(&e[i].img);
    free(e);
    hlod_image_free(&atlas);
    hlod_mesh_free(&u);
    hlod_mesh_free(&s);
    free(pal.rgba);
    if (r != HLOD_OK)
        hlod_city_item_free(out);
    return r;
}

/* ---- grouping ---- */

typedef struct sort_key {
    double key;
    uint32_t i;
} sort_key;

static int cmp_key(const void *pa, const void *pb)
{
    const sort_key *a = pa, *b = pb;
    if (a->key != b->key)
        return a->key < b->key ? -1 : 1;
    return a->i < b->i ? -1 : a->i > b->i;
}

/* Splits ix[0..n) (item indices, centres c) into groups of at most g:
 * appends each group's end (an offset into ix, from base) to ends. */
static void partition(uint32_t *ix, size_t n, const double (*c)[3], size_t g, sort_key *scratch,
                      size_t base, size_t *ends, size_t *nends)
{
    if (n <= g) {
        ends[(*nends)++] = base + n;
        return;
    }
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t k = 0; k < n; k++)
        for (int a = 0; a < 3; a++) {
            lo[a] = fmin(lo[a], c[ix[k]][a]);
            hi[a] = fmax(hi[a], c[ix[k]][a]);
        }
    int axis = 0;
    for (int a = 1; a < 3; a++)
        if (hi[a] - lo[a] > hi[axis] - lo[axis])
            axis = a;
    for (size_t k = 0; k < n; k++)
        scratch[k] = (sort_key){c[ix[k]][axis], ix[k]};
    qsort(scratch, n, sizeof *scratch, cmp_key);
    for (size_t k = 0; k < n; k++)
        ix[k] = scratch[k].i;
    size_t parts = (n + g - 1) / g, left = parts / 2;
    size_t nl = (n * left + parts / 2) / parts;
    nl = nl < 1 ? 1 : nl >= n ? n - 1 : nl;
    partition(ix, nl, c, g, scratch, base, ends, nends);
    partition(ix + nl, n - nl, c, g, scratch, base + nl, ends, nends);
}

/* One level's groups, built by `threads` workers. */
typedef struct level_job {
    const hlod_city_item *const *items; /* in group order */
    const size_t *ends;                 /* group k: items [ends[k-1], ends[k]) */
    size_t groups;
    size_t target;
    const hlod_logger *lg;
    hlod_city_item *out;
    hlod_result *res;
    atomic_size_t next;
} level_job;

/* called from a worker thread */
static void *level_worker(void *arg)
{
    level_job *J = arg;
    for (;;) {
        size_t k = atomic_fetch_add(&J->next, 1);
        if (k >= J->groups)
            return NULL;
        size_t b = k ? J->ends[k - 1] : 0;
        J->res[k] = city_group(J->items + b, J->ends[k] - b, J->target, J->lg, &J->out[k]);
    }
}

static hlod_result build_level(level_job *J, size_t threads)
{
    atomic_init(&J->next, 0);
    size_t nth = threads < J->groups ? threads : J->groups;
    pthread_t th[64];
    nth = nth > 64 ? 64 : nth;
    size_t started = 0;
    for (; started + 1 < nth; started++)
        if (pthread_create(&th[started], NULL, level_worker, J) != 0)
            break;
    level_worker(J); /* the calling thread works too */
    for (size_t i = 0; i < started; i++)
        pthread_join(th[i], NULL);
    for (size_t k = 0; k < J->groups; k++)
        if (J->res[k] != HLOD_OK)
            return J->res[k];
    return HLOD_OK;
}

void hlod_city_plan_free(hlod_city_plan *p)
{
    for (uint32_t l = 1; p->first && p->kids && l <= p->levels; l++) {
        free(p->first[l]);
        free(p->kids[l]);
    }
    free(p->first);
    free(p->kids);
    free(p->count);
    memset(p, 0, sizeof *p);
}

hlod_result hlod_city_plan_make(const double (*lo)[3], const double (*hi)[3], size_t n,
                                size_t group_size, hlod_city_plan *p)
{
    memset(p, 0, sizeof *p);
    if (!n || group_size < 2 || n > UINT32_MAX)
        return HLOD_ERR_INVALID_ARG;
    /* levels: at most log2(n) + 1 (each level at least halves) */
    size_t maxl = 2;
    for (size_t k = n; k > 1; k = (k + 1) / 2)
        maxl++;
    p->count = calloc(maxl, sizeof *p->count);
    p->first = calloc(maxl, sizeof *p->first);
    p->kids = calloc(maxl, sizeof *p->kids);
    double (*blo)[3] = malloc(n * sizeof *blo), (*bhi)[3] = malloc(n * sizeof *bhi);
    double (*c)[3] = malloc(n * sizeof *c);
    uint32_t *ix = malloc(n * sizeof *ix);
    size_t *ends = malloc(n * sizeof *ends);
    sort_key *scratch = malloc(n * sizeof *scratch);
    hlod_result r = p->count && p->first && p->kids && blo && bhi && c && ix && ends && scratch
                        ? HLOD_OK : HLOD_ERR_NOMEM;
    if (r == HLOD_OK) {
        memcpy(blo, lo, n * sizeof *blo);
        memcpy(bhi, hi, n * sizeof *bhi);
        p->count[0] = n;
    }
    size_t ncur = n;
    while (r == HLOD_OK && ncur > 1) {
        for (size_t i = 0; i < ncur; i++) {
            ix[i] = (uint32_t)i;
            for (int a = 0; a < 3; a++)
                c[i][a] = 0.5 * (blo[i][a] + bhi[i][a]);
        }
        size_t groups = 0;
        partition(ix, ncur, (const double (*)[3])c, group_size, scratch, 0, ends, &groups);
        uint32_t l = ++p->levels;
        p->count[l] = groups;
        p->first[l] = malloc((groups + 1) * sizeof **p->first);
        p->kids[l] = malloc(ncur * sizeof **p->kids);
        if (!p->first[l] || !p->kids[l]) {
            r = HLOD_ERR_NOMEM;
            break;
        }
        memcpy(p->kids[l], ix, ncur * sizeof *ix);
        p->first[l][0] = 0;
        for (size_t g = 0; g < groups; g++)
            p->first[l][g + 1] = ends[g];
        /* the groups' boxes: their children's, joined (in place: group g
         * reads children only, written as g < each child's old slot or
         * after all of them are read) */
        double (*glo)[3] = malloc(groups * sizeof *glo), (*ghi)[3] = malloc(groups * sizeof *ghi);
        if (!glo || !ghi) {
            free(glo);
            free(ghi);
            r = HLOD_ERR_NOMEM;
            break;
        }
        for (size_t g = 0; g < groups; g++) {
            for (int a = 0; a < 3; a++) {
                glo[g][a] = INFINITY;
                ghi[g][a] = -INFINITY;
            }
            for (size_t k = p->first[l][g]; k < p->first[l][g + 1]; k++)
                for (int a = 0; a < 3; a++) {
                    glo[g][a] = fmin(glo[g][a], blo[ix[k]][a]);
                    ghi[g][a] = fmax(ghi[g][a], bhi[ix[k]][a]);
                }
        }
        memcpy(blo, glo, groups * sizeof *glo);
        memcpy(bhi, ghi, groups * sizeof *ghi);
        free(glo);
        free(ghi);
        ncur = groups;
    }
    free(blo);
    free(bhi);
    free(c);
    free(ix);
    free(ends);
    free(scratch);
    if (r != HLOD_OK)
        hlod_city_plan_free(p);
    return r;
}

uint64_t hlod_city_plan_hash(const hlod_city_plan *p)
{
    uint64_t h = hlod_store_hash(&p->levels, sizeof p->levels);
    for (uint32_t l = 0; l <= p->levels; l++) {
        uint64_t c = p->count[l];
        h ^= hlod_store_hash(&c, sizeof c) + 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
        if (l)
            h ^= hlod_store_hash(p->kids[l], p->count[l - 1] * sizeof *p->kids[l]) +
                 0x9e3779b97f4a7c15ull + (h << 6) + (h >> 2);
    }
    return h;
}

/* Frees items[0..n) and the array (NULL is fine). */
static void free_items(hlod_city_item *items, size_t n)
{
    for (size_t i = 0; items && i < n; i++)
        hlod_city_item_free(&items[i]);
    free(items);
}

hlod_result hlod_city_levels(const hlod_city_plan *p, uint32_t from, hlod_city_item *const *items,
                             uint32_t to, const hlod_city_levels_desc *d, hlod_city_item **tops)
{
    if (tops)
        *tops = NULL;
    if (!p || !d || from > to || to > p->levels || !d->target_tris || !d->emit)
        return HLOD_ERR_INVALID_ARG;
    /* cur[i]: level l's item i, or NULL where it is not built here */
    hlod_city_item *const *cur = items;
    hlod_city_item *made = NULL;    /* level l's items, when l > from */
    hlod_city_item **made_ptr = NULL;
    hlod_result r = HLOD_OK;
    for (uint32_t l = from + 1; l <= to && r == HLOD_OK; l++) {
        size_t groups = p->count[l], nkids = p->count[l - 1];
        const hlod_city_item **ordered = malloc((nkids ? nkids : 1) * sizeof *ordered);
        size_t *ends = malloc((groups ? groups : 1) * sizeof *ends);
        size_t *which = malloc((groups ? groups : 1) * sizeof *which);
        hlod_city_item *out = calloc(groups ? groups : 1, sizeof *out);
        hlod_city_item **out_ptr = calloc(groups ? groups : 1, sizeof *out_ptr);
        level_job J = {0};
        size_t built = 0, at = 0;
        if (!ordered || !ends || !which || !out || !out_ptr)
            r = HLOD_ERR_NOMEM;
        /* the groups whose children are all here, their children in order */
        for (size_t g = 0; g < groups && r == HLOD_OK; g++) {
            size_t b = p->first[l][g], e = p->first[l][g + 1], k = b;
            while (k < e && cur[p->kids[l][k]])
                k++;
            if (k < e)
                continue;
            for (k = b; k < e; k++)
                ordered[at++] = cur[p->kids[l][k]];
            ends[built] = at;
            which[built++] = g;
        }
        hlod_city_item *res_items = NULL;
        if (r == HLOD_OK && built) {
            res_items = calloc(built, sizeof *res_items);
            J.res = calloc(built, sizeof *J.res);
            if (!res_items || !J.res)
                r = HLOD_ERR_NOMEM;
        }
        if (r == HLOD_OK && built) {
            J.items = ordered;
            J.ends = ends;
            J.groups = built;
            J.target = d->target_tris;
            J.lg = d->logger;
            J.out = res_items;
            r = build_level(&J, d->threads ? d->threads : 1);
        }
        for (size_t k = 0; k < built && r == HLOD_OK; k++) {
            size_t b = k ? ends[k - 1] : 0;
            r = d->emit(d->user, l, (uint32_t)which[k], &res_items[k], ordered + b, ends[k] - b);
        }
        for (size_t k = 0; k < built; k++) {
            if (r == HLOD_OK) {
                out[which[k]] = res_items[k];
                out_ptr[which[k]] = &out[which[k]];
            } else {
                hlod_city_item_free(&res_items[k]);
            }
        }
        free(res_items);
        free(J.res);
        free(ordered);
        free(ends);
        free(which);
        free_items(made, nkids); /* the level before: no longer needed */
        free(made_ptr);
        made = out;
        made_ptr = out_ptr;
        cur = out_ptr;
        if (r != HLOD_OK) {
            free_items(made, groups);
            free(made_ptr);
            made = NULL;
            made_ptr = NULL;
        }
    }
    if (r == HLOD_OK && tops && made) {
        *tops = made;
        made = NULL;
    }
    free_items(made, p->count[to]);
    free(made_ptr);
    return r;
}
