/*
 * texture.c - mip chains built on the loader thread (texture.h).
 */
#include "texture.h"

#include <stdlib.h>
#include <string.h>

static uint32_t half(uint32_t n)
{
    return n > 1 ? n / 2 : 1;
}

size_t hlod_texture_chain_bytes(uint32_t w, uint32_t h, uint32_t c)
{
    size_t total = 0;
    for (;;) {
        total += (size_t)w * h * c;
        if (w == 1 && h == 1)
            return total;
        w = half(w);
        h = half(h);
    }
}

/* dst (dw x dh) from src (sw x sh), c channels: each texel the rounded mean
 * of its 2x2 source block, clamped at an odd edge. */
static void downsample(const uint8_t *src, uint32_t sw, uint32_t sh, uint8_t *dst, uint32_t dw,
                       uint32_t dh, uint32_t c)
{
    for (uint32_t y = 0; y < dh; y++) {
        const uint8_t *r0 = src + (size_t)(2 * y < sh ? 2 * y : sh - 1) * sw * c;
        const uint8_t *r1 = src + (size_t)(2 * y + 1 < sh ? 2 * y + 1 : sh - 1) * sw * c;
        uint8_t *out = dst + (size_t)y * dw * c;
        for (uint32_t x = 0; x < dw; x++) {
            size_t x0 = (size_t)(2 * x < sw ? 2 * x : sw - 1) * c;
            size_t x1 = (size_t)(2 * x + 1 < sw ? 2 * x + 1 : sw - 1) * c;
            for (uint32_t k = 0; k < c; k++)
                out[(size_t)x * c + k] =
                    (uint8_t)((r0[x0 + k] + r0[x1 + k] + r1[x0 + k] + r1[x1 + k] + 2) / 4);
        }
    }
}

hlod_result hlod_texture_prepare(hlod_store_payload *p)
{
    if (!p || !p->pixels || p->tex_levels || !p->tex_width || !p->tex_height ||
        p->tex_channels < 1 || p->tex_channels > 4)
        return HLOD_OK;
    const uint32_t w = p->tex_width, h = p->tex_height, c = p->tex_channels == 3 ? 4 : p->tex_channels;
    uint8_t *chain = malloc(hlod_texture_chain_bytes(w, h, c));
    if (!chain)
        return HLOD_ERR_NOMEM;
    const size_t n = (size_t)w * h;
    if (p->tex_channels == 3) {
        const uint8_t *s = p->pixels;
        for (size_t i = 0; i < n; i++) {
            chain[4 * i] = s[3 * i];
            chain[4 * i + 1] = s[3 * i + 1];
            chain[4 * i + 2] = s[3 * i + 2];
            chain[4 * i + 3] = 255;
        }
    } else {
        memcpy(chain, p->pixels, n * c);
    }
    uint32_t lw = w, lh = h, levels = 1;
    uint8_t *level = chain;
    while (lw > 1 || lh > 1) {
        uint32_t nw = half(lw), nh = half(lh);
        uint8_t *next = level + (size_t)lw * lh * c;
        downsample(level, lw, lh, next, nw, nh, c);
        level = next;
        lw = nw;
        lh = nh;
        levels++;
    }
    free(p->tex_memory);
    p->tex_memory = chain;
    p->pixels = chain;
    p->tex_channels = c;
    p->tex_levels = levels;
    return HLOD_OK;
}
