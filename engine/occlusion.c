/*
 * occlusion.c - the depth pyramid and its test (occlusion.h).
 */
#include "occlusion.h"

#include <assert.h>
#include <math.h>
#include <string.h>

uint32_t *hlod_occlusion_buffer(hlod_occlusion *o, const hlod_allocator *a, uint32_t width,
                                uint32_t height)
{
    assert(o && a);
    size_t n = (size_t)width * height;
    if (o->depth_cap < n) {
        uint32_t *p = hlod_mem_realloc(a, o->depth, n * sizeof *p);
        if (!p)
            return NULL;
        o->depth = p;
        o->depth_cap = n;
    }
    o->width = width;
    o->height = height;
    return o->depth;
}

static uint32_t max4(uint32_t a, uint32_t b, uint32_t c, uint32_t d)
{
    uint32_t x = a > b ? a : b, y = c > d ? c : d;
    return x > y ? x : y;
}

int hlod_occlusion_build(hlod_occlusion *o, const hlod_allocator *a)
{
    return hlod_occlusion_build_from(o, a, o->depth, o->width, o->height, o->width, 0xffffffffu);
}

int hlod_occlusion_build_from(hlod_occlusion *o, const hlod_allocator *a, const uint32_t *depth,
                              uint32_t width, uint32_t height, uint32_t stride, uint32_t mask)
{
    assert(o && a && depth && stride >= width);
    o->src = depth;
    o->width = width;
    o->height = height;
    o->stride = stride;
    o->mask = mask;
    const uint32_t T = HLOD_OCC_TILE;
    uint32_t w = (o->width + T - 1) / T, h = (o->height + T - 1) / T;
    size_t need = 0;
    uint32_t levels = 0;
    for (uint32_t lw = w, lh = h; levels < HLOD_OCC_LEVELS; levels++) {
        need += (size_t)lw * lh;
        if (lw == 1 && lh == 1) {
            levels++;
            break;
        }
        lw = (lw + 1) / 2;
        lh = (lh + 1) / 2;
    }
    if (o->cap < need) {
        uint32_t *p = hlod_mem_realloc(a, o->texels, need * sizeof *p);
        if (!p)
            return 0;
        o->texels = p;
        o->cap = need;
    }
    if (o->band_cap < o->width) {
        uint32_t *p = hlod_mem_realloc(a, o->band, o->width * sizeof *p);
        if (!p)
            return 0;
        o->band = p;
        o->band_cap = o->width;
    }
    o->levels = levels;
    size_t at = 0;
    for (uint32_t l = 0, lw = w, lh = h; l < levels; l++) {
        o->level[l] = o->texels + at;
        o->lw[l] = lw;
        o->lh[l] = lh;
        at += (size_t)lw * lh;
        lw = (lw + 1) / 2;
        lh = (lh + 1) / 2;
    }
    /* level 0: the farthest depth per tile.  The TILE rows of a band are
     * first folded into one row, element by element (a loop compilers
     * vectorise), then each tile's TILE values of that row are folded. */
    uint32_t *l0 = o->level[0], *acc = o->band;
    for (uint32_t ty = 0; ty < h; ty++) {
        uint32_t y0 = ty * T, y1 = y0 + T < o->height ? y0 + T : o->height;
        const uint32_t *first = o->src + (size_t)y0 * o->stride;
        for (uint32_t x = 0; x < o->width; x++)
            acc[x] = first[x] & mask;
        for (uint32_t y = y0 + 1; y < y1; y++) {
            const uint32_t *row = o->src + (size_t)y * o->stride;
            for (uint32_t x = 0; x < o->width; x++) {
                uint32_t v = row[x] & mask;
                acc[x] = v > acc[x] ? v : acc[x];
            }
        }
        for (uint32_t tx = 0; tx < w; tx++) {
            uint32_t x0 = tx * T, x1 = x0 + T < o->width ? x0 + T : o->width, m = 0;
            for (uint32_t x = x0; x < x1; x++)
                m = acc[x] > m ? acc[x] : m;
            l0[(size_t)ty * w + tx] = m;
        }
    }
    for (uint32_t l = 1; l < levels; l++) {
        const uint32_t *src = o->level[l - 1];
        uint32_t sw = o->lw[l - 1], sh = o->lh[l - 1];
        for (uint32_t y = 0; y < o->lh[l]; y++)
            for (uint32_t x = 0; x < o->lw[l]; x++) {
                uint32_t x0 = 2 * x, y0 = 2 * y;
                uint32_t x1 = x0 + 1 < sw ? x0 + 1 : x0, y1 = y0 + 1 < sh ? y0 + 1 : y0;
                o->level[l][(size_t)y * o->lw[l] + x] =
                    max4(src[(size_t)y0 * sw + x0], src[(size_t)y0 * sw + x1],
                         src[(size_t)y1 * sw + x0], src[(size_t)y1 * sw + x1]);
            }
    }
    return 1;
}

int hlod_occlusion_visible(const hlod_occlusion *o, const double rect[4], double zmin)
{
    assert(o && rect);
    if (!o->levels || !(zmin >= 0) || !(zmin <= 1))
        return 1;
    if (!(rect[2] >= rect[0] && rect[3] >= rect[1]))
        return 1; /* an empty rectangle: keep it, the frustum test said it meets the view */
    /* every pixel whose centre the rectangle may cover, one more each side */
    long px0 = (long)floor(rect[0]) - 1, py0 = (long)floor(rect[1]) - 1;
    long px1 = (long)floor(rect[2]) + 1, py1 = (long)floor(rect[3]) + 1;
    px0 = px0 < 0 ? 0 : px0;
    py0 = py0 < 0 ? 0 : py0;
    px1 = px1 >= (long)o->width ? (long)o->width - 1 : px1;
    py1 = py1 >= (long)o->height ? (long)o->height - 1 : py1;
    if (px1 < px0 || py1 < py0)
        return 1;
    uint32_t tx0 = (uint32_t)px0 / HLOD_OCC_TILE, tx1 = (uint32_t)px1 / HLOD_OCC_TILE;
    uint32_t ty0 = (uint32_t)py0 / HLOD_OCC_TILE, ty1 = (uint32_t)py1 / HLOD_OCC_TILE;
    uint32_t l = 0;
    while (l + 1 < o->levels && ((tx1 >> l) - (tx0 >> l) > 1 || (ty1 >> l) - (ty0 >> l) > 1))
        l++;
    uint32_t far = 0;
    for (uint32_t y = ty0 >> l; y <= ty1 >> l && y < o->lh[l]; y++)
        for (uint32_t x = tx0 >> l; x <= tx1 >> l && x < o->lw[l]; x++) {
            uint32_t d = o->level[l][(size_t)y * o->lw[l] + x];
            far = d > far ? d : far;
        }
    /* allow a few steps of a 24-bit buffer (2^-20 of the range) */
    double zq = zmin * (double)o->mask;
    return !(zq > (double)far + (double)o->mask * (1.0 / 1048576.0));
}

int hlod_occlusion_init(hlod_occlusion *o, const hlod_allocator *a, uint32_t node_count)
{
    assert(o && a && !o->stamp);
    o->stamp = hlod_mem_alloc(a, ((size_t)node_count + 1) * sizeof *o->stamp);
    if (!o->stamp)
        return 0;
    memset(o->stamp, 0, ((size_t)node_count + 1) * sizeof *o->stamp);
    o->node_count = node_count;
    return 1;
}

void hlod_occlusion_free(hlod_occlusion *o, const hlod_allocator *a)
{
    hlod_mem_free(a, o->stamp);
    hlod_mem_free(a, o->depth);
    hlod_mem_free(a, o->texels);
    hlod_mem_free(a, o->band);
    memset(o, 0, sizeof *o);
}
