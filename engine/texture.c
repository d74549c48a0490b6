/*
 * texture.c - mip chains built on the loader thread (texture.h).
 */
#include "texture.h"
#include "texture_codec.h"

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
        hlod_tex_downsample(level, lw, lh, next, c);
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
