/* Pieces every hierarchy builder shares: the tree container, node textures
 * and node errors (see build.h). */
#include "build.h"
#include "union_find.h"

#include "hlod/distance.h"

#include <assert.h>
#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

void hlod_btree_free(hlod_btree *t)
{
    if (!t)
        return;
    for (size_t i = 0; i < t->count; i++) {
        hlod_mesh_free(&t->nodes[i].mesh);
        hlod_image_free(&t->nodes[i].tex);
    }
    free(t->nodes);
    memset(t, 0, sizeof *t);
}

uint32_t hlod_btree_add(hlod_btree *t)
{
    if (t->count == t->cap) {
        size_t nc = t->cap ? t->cap * 2 : 16;
        hlod_bnode *n = realloc(t->nodes, nc * sizeof *n);
        if (!n)
            return HLOD_BNODE_NONE;
        t->nodes = n;
        t->cap = nc;
    }
    memset(&t->nodes[t->count], 0, sizeof t->nodes[t->count]);
    t->nodes[t->count].parent = HLOD_BNODE_NONE;
    return (uint32_t)t->count++;
}

/* ---- node textures ----
 *
 * A block's atlas holds many charts scattered over the image (the city
 * shelf-packs every wall and roof of a block into one atlas), so the UV box
 * of a small node -- a leaf cut out of the block by planes -- covers nearly
 * the whole atlas although its triangles sample a few percent of it.  Each
 * node therefore gets its own atlas, repacked from the source:
 *
 * 1. Charts: connected components of the node's triangles through shared
 *    vertex indices (union-find).  A UV seam already duplicates a vertex,
 *    so a component never joins two source charts, and each triangle's UV
 *    triangle lies inside its component's UV box (a box is convex).
 * 2. Rectangles: each component's UV box in source texels (rows counted
 *    from the top: v = 0 is the image's bottom row), padded by a gutter of
 *    G texels.  The first COPY_GUTTER of them come from the source (the
 *    atlas's own gutter, clamped inside the image); the rest repeat the
 *    outermost copied texels.  G grows with the shrink that follows (about
 *    2 * sqrt(factor) source texels, so that two texels of gutter survive
 *    it, up to MAX_GUTTER).  Two padded rectangles that touch merge when
 *    their union costs no more texels than the two apart (pieces of one
 *    chart split by cuts, charts that share UVs like the ground tiles),
 *    until no such pair is left.
 * 3. Packing: skyline bottom-left (each rectangle where its top lands
 *    lowest) in order of decreasing height, then width, then component
 *    order, at widths from 0.6 to 2.5 times the square root of the total
 *    area; the smallest atlas wins.  It is kept only when it is no larger
 *    than the crop to the node's UV box (G = COPY_GUTTER is tried before
 *    giving up), so no node's texture grows; otherwise, and for a node with
 *    more than MAX_CHARTS components (a triangle soup: merging is
 *    quadratic) the crop is used, and a node whose UVs wrap (outside
 *    [0, 1]) keeps the whole image, as before.
 * 4. The atlas then shrinks by sqrt(factor) per side (Lakhia III-A).
 *
 * Everything before the shrink is integer arithmetic under total orders,
 * so a node's texture is a function of its mesh and the source image alone
 * (byte-identical stores), and nothing is shared between calls (blocks
 * build in parallel).  Cost: O(vertices + triangles + texels copied), plus
 * O(r^2) per merging pass and per packing width for r components. */

#define COPY_GUTTER 2 /* source texels around a chart taken from the source */
#define MAX_GUTTER 32 /* cap of the gutter scaled with the shrink */
#define MAX_CHARTS 2048 /* more components than this: crop instead */

typedef struct tex_rect {
    int x0, y0, x1, y1; /* content box in source texels, [x0, x1) x [y0, y1),
                           rows from the top */
    int ax, ay;         /* the padded rectangle's corner in the atlas */
    uint32_t merged;    /* its own index, or the rectangle it merged into */
} tex_rect;

typedef struct rect_key {
    int h, w;           /* content size */
    uint32_t i;         /* rectangle index */
} rect_key;

static int64_t padded_area(const tex_rect *r, int g)
{
    return (int64_t)(r->x1 - r->x0 + 2 * g) * (r->y1 - r->y0 + 2 * g);
}

/* Merges rectangles whose padded boxes touch when the union costs no more
 * texels than both apart; a merged rectangle points at the survivor. */
static void merge_rects(tex_rect *r, size_t n, int g)
{
    for (int changed = 1; changed;) {
        changed = 0;
        for (size_t i = 0; i < n; i++) {
            if (r[i].merged != i)
                continue;
            for (size_t j = i + 1; j < n; j++) {
                tex_rect *a = &r[i], *b = &r[j];
                if (b->merged != j || a->x0 - g > b->x1 + g || b->x0 - g > a->x1 + g ||
                    a->y0 - g > b->y1 + g || b->y0 - g > a->y1 + g)
                    continue;
                tex_rect u = *a;
                u.x0 = a->x0 < b->x0 ? a->x0 : b->x0;
                u.y0 = a->y0 < b->y0 ? a->y0 : b->y0;
                u.x1 = a->x1 > b->x1 ? a->x1 : b->x1;
                u.y1 = a->y1 > b->y1 ? a->y1 : b->y1;
                if (padded_area(&u, g) > padded_area(a, g) + padded_area(b, g))
                    continue;
                *a = u;
                b->merged = (uint32_t)i;
                changed = 1;
            }
        }
    }
}

static int key_cmp(const void *pa, const void *pb)
{
    const rect_key *a = pa, *b = pb;
    if (a->h != b->h)
        return a->h > b->h ? -1 : 1;
    if (a->w != b->w)
        return a->w > b->w ? -1 : 1;
    return a->i < b->i ? -1 : a->i > b->i;
}

/* Skyline bottom-left packing of keys (sorted by key_cmp) into `width`:
 * each rectangle goes where its top lands lowest, leftmost on ties.  Sets
 * each rectangle's ax, ay and returns the height used.  scratch: 6 * n + 3
 * ints (the skyline has at most 2 * n + 1 segments). */
static int skyline_pack(tex_rect *r, const rect_key *keys, size_t n, int g, int width, int *scratch)
{
    size_t cap = 2 * n + 1, ns = 1;
    int *sx = scratch, *sy = scratch + cap, *sw = scratch + 2 * cap;
    sx[0] = 0;
    sy[0] = 0;
    sw[0] = width;
    int top = 0;
    for (size_t k = 0; k < n; k++) {
        int w = keys[k].w + 2 * g, h = keys[k].h + 2 * g;
        size_t bi = 0;
        int by = 0, btop = INT_MAX;
        for (size_t i = 0; i < ns && sx[i] + w <= width; i++) {
            int y = 0;
            for (size_t j = i; j < ns && sx[j] < sx[i] + w; j++)
                y = sy[j] > y ? sy[j] : y;
            if (y + h < btop) {
                btop = y + h;
                by = y;
                bi = i;
            }
        }
        assert(btop != INT_MAX); /* width >= the widest rectangle */
        int x = sx[bi], xe = x + w;
        r[keys[k].i].ax = x;
        r[keys[k].i].ay = by;
        top = btop > top ? btop : top;
        /* the new segment [x, xe) replaces the ones it covers */
        size_t j = bi;
        while (j < ns && sx[j] + sw[j] <= xe)
            j++;
        if (j < ns && sx[j] < xe) {
            sw[j] -= xe - sx[j];
            sx[j] = xe;
        }
        size_t tail = ns - j;
        memmove(sx + bi + 1, sx + j, tail * sizeof *sx);
        memmove(sy + bi + 1, sy + j, tail * sizeof *sy);
        memmove(sw + bi + 1, sw + j, tail * sizeof *sw);
        ns = bi + 1 + tail;
        sx[bi] = x;
        sy[bi] = btop;
        sw[bi] = w;
        if (bi + 1 < ns && sy[bi + 1] == sy[bi]) { /* merge level neighbours */
            sw[bi] += sw[bi + 1];
            ns--;
            memmove(sx + bi + 1, sx + bi + 2, (ns - bi - 1) * sizeof *sx);
            memmove(sy + bi + 1, sy + bi + 2, (ns - bi - 1) * sizeof *sy);
            memmove(sw + bi + 1, sw + bi + 2, (ns - bi - 1) * sizeof *sw);
        }
        if (bi > 0 && sy[bi - 1] == sy[bi]) {
            sw[bi - 1] += sw[bi];
            ns--;
            memmove(sx + bi, sx + bi + 1, (ns - bi) * sizeof *sx);
            memmove(sy + bi, sy + bi + 1, (ns - bi) * sizeof *sy);
            memmove(sw + bi, sw + bi + 1, (ns - bi) * sizeof *sw);
        }
        assert(ns <= cap);
    }
    return top;
}

/* Copies rectangle q (gutter g) from tex into atlas at (q->ax, q->ay). */
static void copy_rect(const hlod_image *tex, const tex_rect *q, int g, hlod_image *atlas)
{
    int c = tex->channels;
    int sx0 = q->x0 - COPY_GUTTER, sx1 = q->x1 + COPY_GUTTER;
    int sy0 = q->y0 - COPY_GUTTER, sy1 = q->y1 + COPY_GUTTER;
    sx0 = sx0 < 0 ? 0 : sx0;
    sy0 = sy0 < 0 ? 0 : sy0;
    sx1 = sx1 > tex->width ? tex->width : sx1;
    sy1 = sy1 > tex->height ? tex->height : sy1;
    int pw = q->x1 - q->x0 + 2 * g, ph = q->y1 - q->y0 + 2 * g;
    /* destination columns [l, rr) copy source columns [sx0, sx1); the
     * others repeat the nearest copied column */
    int l = sx0 - (q->x0 - g), rr = sx1 - (q->x0 - g);
    for (int y = 0; y < ph; y++) {
        int sy = q->y0 - g + y;
        sy = sy < sy0 ? sy0 : sy >= sy1 ? sy1 - 1 : sy;
        const uint8_t *src = tex->pixels + (size_t)sy * tex->width * c;
        uint8_t *dst = atlas->pixels + ((size_t)(q->ay + y) * atlas->width + q->ax) * c;
        for (int x = 0; x < l; x++)
            memcpy(dst + (size_t)x * c, src + (size_t)sx0 * c, (size_t)c);
        memcpy(dst + (size_t)l * c, src + (size_t)sx0 * c, (size_t)(sx1 - sx0) * c);
        for (int x = rr; x < pw; x++)
            memcpy(dst + (size_t)x * c, src + (size_t)(sx1 - 1) * c, (size_t)c);
    }
}

/* Steps 2-3 of the design at gutter g, from the components' boxes `base`;
 * builds the atlas and rewrites m's UVs when it is no larger than `limit`
 * texels, else leaves atlas->width 0 and m untouched. */
static hlod_result pack_atlas(const hlod_image *tex, hlod_mesh *m, const tex_rect *base, size_t n,
                              const uint32_t *vert_rect, int g, int64_t limit, hlod_image *atlas)
{
    hlod_result res = HLOD_ERR_NOMEM;
    tex_rect *r = malloc(n * sizeof *r);
    rect_key *keys = malloc(n * sizeof *keys);
    int *scratch = malloc((6 * n + 3) * sizeof *scratch);
    if (!r || !keys || !scratch)
        goto done;
    memcpy(r, base, n * sizeof *r);
    merge_rects(r, n, g);
    size_t live = 0;
    int64_t area = 0;
    int wmax = 0;
    for (size_t i = 0; i < n; i++)
        if (r[i].merged == i) {
            keys[live++] = (rect_key){r[i].y1 - r[i].y0, r[i].x1 - r[i].x0, (uint32_t)i};
            area += padded_area(&r[i], g);
            wmax = keys[live - 1].w + 2 * g > wmax ? keys[live - 1].w + 2 * g : wmax;
        }
    res = HLOD_OK;
    if (area > limit)
        goto done;
    qsort(keys, live, sizeof *keys, key_cmp);
    /* widths from 0.6 to 2.5 times the square root of the area, no wider
     * than the source plus a gutter (nor taller: an atlas is never larger
     * than the source could be in either dimension) */
    int best_w = 0, prev_w = 0;
    int64_t best = INT64_MAX;
    for (int k = 0; k <= 38; k++) {
        int w = (int)ceil(sqrt((double)area) * (0.6 + 0.05 * k));
        w = w < wmax ? wmax : w;
        if (w == prev_w || w > tex->width + 2 * g)
            continue;
        prev_w = w;
        int h = skyline_pack(r, keys, live, g, w, scratch);
        if (h <= tex->height + 2 * g && (int64_t)w * h < best) {
            best = (int64_t)w * h;
            best_w = w;
        }
    }
    if (!best_w || best > limit)
        goto done;
    int aw = best_w, ah = skyline_pack(r, keys, live, g, best_w, scratch), c = tex->channels;
    atlas->pixels = calloc((size_t)aw * ah, (size_t)c);
    if (!atlas->pixels) {
        res = HLOD_ERR_NOMEM;
        goto done;
    }
    atlas->width = aw;
    atlas->height = ah;
    atlas->channels = c;
    for (size_t k = 0; k < live; k++)
        copy_rect(tex, &r[keys[k].i], g, atlas);
    for (size_t v = 0; v < m->vertex_count; v++) {
        float *uv = m->uvs + 2 * v;
        if (vert_rect[v] == UINT32_MAX) { /* used by no triangle */
            uv[0] = uv[1] = 0;
            continue;
        }
        uint32_t k = vert_rect[v];
        while (r[k].merged != k)
            k = r[k].merged;
        const tex_rect *q = &r[k];
        double x = q->ax + g + ((double)uv[0] * tex->width - q->x0);
        double y = q->ay + g + ((1 - (double)uv[1]) * tex->height - q->y0);
        uv[0] = (float)(x / aw);
        uv[1] = (float)(1 - y / ah);
    }
done:
    free(r);
    free(keys);
    free(scratch);
    return res;
}

/* Steps 1-3 of the design: the node's own atlas in *atlas, or width 0 when
 * it would exceed `limit` texels (m untouched then).  All UVs in [0, 1]. */
static hlod_result repack(const hlod_image *tex, hlod_mesh *m, double factor, int64_t limit, hlod_image *atlas)
{
    size_t nv = m->vertex_count;
    if (nv >= UINT32_MAX)
        return HLOD_OK;
    uint32_t *parent = malloc(nv * sizeof *parent), *vert_rect = malloc(nv * sizeof *vert_rect);
    tex_rect *base = NULL;
    hlod_result res = HLOD_ERR_NOMEM;
    if (!parent || !vert_rect)
        goto done;
    for (size_t v = 0; v < nv; v++) {
        parent[v] = (uint32_t)v;
        vert_rect[v] = UINT32_MAX;
    }
    for (size_t t = 0; t < m->tri_count; t++) {
        const uint32_t *x = m->indices + 3 * t;
        assert(x[0] < nv && x[1] < nv && x[2] < nv);
        uf_union(parent, x[0], x[1]);
        uf_union(parent, x[1], x[2]);
    }
    /* component boxes in texels, numbered in order of first use */
    size_t n = 0;
    for (size_t t = 0; t < 3 * m->tri_count; t++) {
        uint32_t v = m->indices[t], root = uf_find(parent, v);
        if (vert_rect[root] == UINT32_MAX)
            vert_rect[root] = (uint32_t)n++;
        vert_rect[v] = vert_rect[root];
    }
    res = HLOD_OK;
    if (!n || n > MAX_CHARTS)
        goto done;
    res = HLOD_ERR_NOMEM;
    base = malloc(n * sizeof *base);
    if (!base)
        goto done;
    for (size_t i = 0; i < n; i++)
        base[i] = (tex_rect){INT_MAX, INT_MAX, INT_MIN, INT_MIN, 0, 0, (uint32_t)i};
    for (size_t v = 0; v < nv; v++) {
        if (vert_rect[v] == UINT32_MAX)
            continue;
        tex_rect *q = &base[vert_rect[v]];
        double x = (double)m->uvs[2 * v] * tex->width, y = (1 - (double)m->uvs[2 * v + 1]) * tex->height;
        int fx = (int)floor(x), cx = (int)ceil(x), fy = (int)floor(y), cy = (int)ceil(y);
        q->x0 = fx < q->x0 ? fx : q->x0;
        q->x1 = cx > q->x1 ? cx : q->x1;
        q->y0 = fy < q->y0 ? fy : q->y0;
        q->y1 = cy > q->y1 ? cy : q->y1;
    }
    for (size_t i = 0; i < n; i++) {
        /* at least one texel, inside the image */
        tex_rect *q = &base[i];
        q->x0 = q->x0 > tex->width - 1 ? tex->width - 1 : q->x0;
        q->y0 = q->y0 > tex->height - 1 ? tex->height - 1 : q->y0;
        q->x1 = q->x1 <= q->x0 ? q->x0 + 1 : q->x1;
        q->y1 = q->y1 <= q->y0 ? q->y0 + 1 : q->y1;
    }
    double gf = ceil(2 * sqrt(factor)); /* factor >= 1, maybe infinite */
    int g = gf > MAX_GUTTER ? MAX_GUTTER : gf < COPY_GUTTER ? COPY_GUTTER : (int)gf;
    res = pack_atlas(tex, m, base, n, vert_rect, g, limit, atlas);
    if (res == HLOD_OK && !atlas->width && g > COPY_GUTTER)
        res = pack_atlas(tex, m, base, n, vert_rect, COPY_GUTTER, limit, atlas);
done:
    free(parent);
    free(vert_rect);
    free(base);
    return res;
}

static int imod(long a, int n)
{
    long r = a % n;
    return (int)(r < 0 ? r + n : r);
}

/* A node whose UVs leave [0, 1] (a repeating texture, like the ground's):
 * per axis, when its UVs span less than one period, shift them by whole
 * periods to start in [0, 1) and crop the texels they cover, reading the
 * image modulo its size (the crop may straddle the image's edge), with
 * one texel of margin; an axis spanning a period or more keeps the whole
 * image and its UVs.  Leaves *crop empty (and m untouched) when neither
 * axis can be cropped or a UV is not finite. */
static hlod_result wrapped_crop(const hlod_image *tex, hlod_mesh *m, const float lo[2],
                                const float hi[2], hlod_image *crop)
{
    memset(crop, 0, sizeof *crop);
    int size[2] = {tex->width, tex->height}, p0[2], n[2], cut[2];
    double shift[2];
    for (int k = 0; k < 2; k++) {
        if (!isfinite(lo[k]) || !isfinite(hi[k]))
            return HLOD_OK;
        shift[k] = floor(lo[k]);
        double a = lo[k] - shift[k], b = hi[k] - shift[k];
        /* texels covered, in image space (x right; rows from the bottom
         * here, flipped on copy), plus a margin */
        long t0 = (long)floor(a * size[k]) - 1, t1 = (long)ceil(b * size[k]) + 1;
        cut[k] = t1 - t0 < size[k];
        p0[k] = cut[k] ? (int)t0 : 0;
        n[k] = cut[k] ? (int)(t1 - t0) : size[k];
        if (!cut[k])
            shift[k] = 0;
    }
    if (!cut[0] && !cut[1])
        return HLOD_OK;
    int c = tex->channels;
    uint8_t *px = malloc((size_t)n[0] * n[1] * c);
    if (!px)
        return HLOD_ERR_NOMEM;
    /* crop row r (top first) holds image-space row p0[1] + n[1] - 1 - r
     * counted from the bottom, i.e. stored row H - 1 - that */
    for (int r = 0; r < n[1]; r++) {
        int up = imod((long)p0[1] + n[1] - 1 - r, size[1]);
        const uint8_t *src_row = tex->pixels + (size_t)(size[1] - 1 - up) * size[0] * c;
        for (int x = 0; x < n[0]; x++)
            memcpy(px + ((size_t)r * n[0] + x) * c, src_row + (size_t)imod((long)p0[0] + x, size[0]) * c,
                   (size_t)c);
    }
    for (size_t v = 0; v < m->vertex_count; v++)
        for (int k = 0; k < 2; k++)
            if (cut[k]) {
                float *uv = m->uvs + 2 * v + k;
                *uv = (float)(((*uv - shift[k]) * size[k] - p0[k]) / n[k]);
            }
    *crop = (hlod_image){n[0], n[1], c, px};
    return HLOD_OK;
}

hlod_result hlod_node_texture(const hlod_image *tex, hlod_mesh *m, double factor, hlod_image *out)
{
    memset(out, 0, sizeof *out);
    if (!tex || !tex->width || !tex->pixels || !m->uvs || !m->vertex_count)
        return HLOD_OK;
    if (!(factor >= 1))
        factor = 1;
    /* UV box of the node; a node whose UVs wrap keeps the whole image. */
    float lo[2] = {m->uvs[0], m->uvs[1]}, hi[2] = {m->uvs[0], m->uvs[1]};
    int inside = 1;
    for (size_t v = 0; v < m->vertex_count; v++)
        for (int k = 0; k < 2; k++) {
            float u = m->uvs[2 * v + k];
            lo[k] = u < lo[k] ? u : lo[k];
            hi[k] = u > hi[k] ? u : hi[k];
            inside &= u >= 0 && u <= 1; /* also false for NaN */
        }
    int x0 = 0, y0 = 0, x1 = tex->width, y1 = tex->height;
    if (inside) {
        /* v = 0 is the image's bottom row (OpenGL convention), rows are
         * stored top first; one texel of margin for bilinear filtering */
        x0 = (int)floor(lo[0] * tex->width) - 1;
        x1 = (int)ceil(hi[0] * tex->width) + 1;
        y0 = (int)floor((1 - hi[1]) * tex->height) - 1;
        y1 = (int)ceil((1 - lo[1]) * tex->height) + 1;
        x0 = x0 < 0 ? 0 : x0;
        y0 = y0 < 0 ? 0 : y0;
        x1 = x1 > tex->width ? tex->width : x1;
        y1 = y1 > tex->height ? tex->height : y1;
        if (x1 <= x0 || y1 <= y0) {
            x0 = y0 = 0;
            x1 = tex->width;
            y1 = tex->height;
        }
    }
    int cw = x1 - x0, ch = y1 - y0, c = tex->channels;
    hlod_image crop = {0};
    if (!inside) {
        hlod_result r = wrapped_crop(tex, m, lo, hi, &crop);
        if (r != HLOD_OK)
            return r;
    }
    if (inside) {
        hlod_result r = repack(tex, m, factor, (int64_t)cw * ch, &crop);
        if (r != HLOD_OK)
            return r;
    }
    if (crop.width) {
        cw = crop.width;
        ch = crop.height;
    } else {
        crop = (hlod_image){cw, ch, c, malloc((size_t)cw * ch * c)};
        if (!crop.pixels)
            return HLOD_ERR_NOMEM;
        for (int y = 0; y < ch; y++)
            memcpy(crop.pixels + (size_t)y * cw * c, tex->pixels + ((size_t)(y0 + y) * tex->width + x0) * c,
                   (size_t)cw * c);
        /* UVs into the crop */
        if (cw != tex->width || ch != tex->height) {
            for (size_t v = 0; v < m->vertex_count; v++) {
                float *uv = m->uvs + 2 * v;
                uv[0] = (float)((uv[0] * tex->width - x0) / cw);
                uv[1] = (float)((uv[1] * tex->height - (tex->height - y1)) / ch);
            }
        }
    }
    /* Lakhia III-A: texture shrinks with the triangle count (per side, the
     * square root of the simplification factor). */
    double s = 1 / sqrt(factor);
    int w = (int)lround(cw * s), h = (int)lround(ch * s);
    w = w < 4 ? (cw < 4 ? cw : 4) : w;
    h = h < 4 ? (ch < 4 ? ch : 4) : h;
    if (w == cw && h == ch) {
        *out = crop;
        return HLOD_OK;
    }
    hlod_result r = hlod_image_resize(&crop, w, h, out);
    hlod_image_free(&crop);
    return r;
}

hlod_result hlod_node_error(const hlod_mesh *node, const hlod_mesh *original, double *error)
{
    *error = 0;
    if (!node->tri_count || !original->tri_count)
        return HLOD_OK;
    double lower, upper;
    /* 25% and 1e-3 of the size: node errors steer refinement, where a
     * looser bound costs a little detail and a tight one costs build time
     * (coincident flat walls cost the most to resolve) */
    hlod_result r = hlod_mesh_hausdorff_bound(node, original, 0.25, 1e-3 * hlod_mesh_bbox_diag(original), &lower,
                                              &upper);
    if (r == HLOD_OK)
        *error = upper;
    return r;
}

/* ---- solidity (back-face culling) ---- */

typedef struct pos_key {
    double p[3];
    uint32_t v;
} pos_key;

static int cmp_pos_key(const void *pa, const void *pb)
{
    const pos_key *a = pa, *b = pb;
    for (int k = 0; k < 3; k++)
        if (a->p[k] != b->p[k])
            return a->p[k] < b->p[k] ? -1 : 1;
    return (a->v > b->v) - (a->v < b->v);
}

static int cmp_u64(const void *pa, const void *pb)
{
    uint64_t a = *(const uint64_t *)pa, b = *(const uint64_t *)pb;
    return (a > b) - (a < b);
}

static int has_u64(const uint64_t *v, size_t n, uint64_t key)
{
    size_t lo = 0, hi = n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (v[mid] < key)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < n && v[lo] == key;
}

int hlod_mesh_is_solid(const hlod_mesh *m)
{
    if (!m || !m->tri_count || !m->vertex_count || m->vertex_count > UINT32_MAX)
        return 0;
    size_t nv = m->vertex_count, ne = 3 * m->tri_count;
    pos_key *keys = malloc(nv * sizeof *keys);
    uint32_t *weld = malloc(nv * sizeof *weld);
    uint64_t *edges = malloc(ne * sizeof *edges);
    int solid = 0;
    if (!keys || !weld || !edges)
        goto done;
    for (size_t v = 0; v < nv; v++) {
        memcpy(keys[v].p, m->positions + 3 * v, sizeof keys[v].p);
        keys[v].v = (uint32_t)v;
    }
    qsort(keys, nv, sizeof *keys, cmp_pos_key);
    for (size_t i = 0, id = 0; i < nv; i++) {
        if (i && memcmp(keys[i].p, keys[i - 1].p, sizeof keys[i].p) != 0)
            id++;
        weld[keys[i].v] = (uint32_t)id;
    }
    double lo[3], hi[3], c[3], vol = 0;
    hlod_mesh_bounds(m, lo, hi);
    for (int k = 0; k < 3; k++)
        c[k] = 0.5 * (lo[k] + hi[k]);
    size_t n = 0;
    for (size_t t = 0; t < m->tri_count; t++) {
        const uint32_t *ix = m->indices + 3 * t;
        double p[3][3];
        for (int j = 0; j < 3; j++)
            for (int k = 0; k < 3; k++)
                p[j][k] = m->positions[3 * (size_t)ix[j] + k] - c[k];
        vol += (p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1]) -
                p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0]) +
                p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0])) / 6;
        for (int j = 0; j < 3; j++) {
            uint64_t a = weld[ix[j]], b = weld[ix[(j + 1) % 3]];
            if (a != b) /* a collapsed edge says nothing */
                edges[n++] = a << 32 | b;
        }
    }
    qsort(edges, n, sizeof *edges, cmp_u64);
    size_t paired = 0;
    for (size_t i = 0; i < n; i++) {
        if (i && edges[i] == edges[i - 1])
            goto done; /* the same directed edge twice */
        paired += has_u64(edges, n, edges[i] << 32 | edges[i] >> 32);
    }
    double box = (hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]);
    solid = n > 0 && (double)paired >= 0.99 * (double)n && vol > 0 && vol >= 0.05 * box;
done:
    free(keys);
    free(weld);
    free(edges);
    return solid;
}
