/*
 * texture_codec.c - block-coded mip chains (texture_codec.h).
 */
#include "texture_codec.h"

#include <math.h>
#include <stb_dxt.h>
#include <stdlib.h>
#include <string.h>

static uint32_t half(uint32_t n)
{
    return n > 1 ? n / 2 : 1;
}

uint32_t hlod_tex_level_count(uint32_t w, uint32_t h)
{
    uint32_t m = w > h ? w : h, levels = 1;
    while (m > 1) {
        m /= 2;
        levels++;
    }
    return levels;
}

void hlod_tex_level_size(uint32_t w, uint32_t h, uint32_t l, uint32_t *lw, uint32_t *lh)
{
    *lw = l >= 32 ? 1 : (w >> l ? w >> l : 1);
    *lh = l >= 32 ? 1 : (h >> l ? h >> l : 1);
}

static size_t level_blocks(uint32_t lw, uint32_t lh)
{
    return (size_t)((lw + 3) / 4) * ((lh + 3) / 4);
}

size_t hlod_bc_chain_bytes(uint32_t w, uint32_t h)
{
    if (!w || !h)
        return 0;
    size_t total = 0;
    uint32_t levels = hlod_tex_level_count(w, h);
    for (uint32_t l = 0; l < levels; l++) {
        uint32_t lw, lh;
        hlod_tex_level_size(w, h, l, &lw, &lh);
        total += level_blocks(lw, lh) * HLOD_BC_BLOCK_BYTES;
    }
    return total;
}

void hlod_tex_downsample(const uint8_t *src, uint32_t sw, uint32_t sh, uint8_t *dst, uint32_t c)
{
    const uint32_t dw = half(sw), dh = half(sh);
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

/* One level's blocks from its texels (c = 1: BC4, 3: BC1); the last row
 * and column of blocks repeat the edge texels. */
static void encode_level(const uint8_t *px, uint32_t lw, uint32_t lh, uint32_t c, uint8_t *out)
{
    uint8_t tile[64];
    for (uint32_t by = 0; by < lh; by += 4)
        for (uint32_t bx = 0; bx < lw; bx += 4) {
            for (uint32_t j = 0; j < 16; j++) {
                uint32_t x = bx + j % 4, y = by + j / 4;
                x = x < lw ? x : lw - 1;
                y = y < lh ? y : lh - 1;
                const uint8_t *s = px + ((size_t)y * lw + x) * c;
                if (c == 1) {
                    tile[j] = s[0];
                } else {
                    tile[4 * j] = s[0];
                    tile[4 * j + 1] = s[1];
                    tile[4 * j + 2] = s[2];
                    tile[4 * j + 3] = 255;
                }
            }
            if (c == 1)
                stb_compress_bc4_block(out, tile);
            else
                stb_compress_dxt_block(out, tile, 0, STB_DXT_HIGHQUAL);
            out += HLOD_BC_BLOCK_BYTES;
        }
}

hlod_result hlod_bc_encode_chain(const uint8_t *pixels, uint32_t w, uint32_t h, uint32_t c,
                                 uint8_t **blocks, size_t *bytes)
{
    *blocks = NULL;
    *bytes = 0;
    if (!pixels || (c != 1 && c != 3) || !w || !h)
        return HLOD_ERR_INVALID_ARG;
    size_t total = hlod_bc_chain_bytes(w, h);
    uint8_t *out = total ? malloc(total) : NULL;
    /* two scratch levels: level l + 1 is made from level l */
    size_t scratch = (size_t)half(w) * half(h) * c;
    uint8_t *a = malloc(scratch), *b = malloc(scratch);
    if (!out || !a || !b) {
        free(out);
        free(a);
        free(b);
        return HLOD_ERR_NOMEM;
    }
    uint32_t levels = hlod_tex_level_count(w, h), lw = w, lh = h;
    const uint8_t *level = pixels;
    uint8_t *at = out;
    for (uint32_t l = 0; l < levels; l++) {
        encode_level(level, lw, lh, c, at);
        at += level_blocks(lw, lh) * HLOD_BC_BLOCK_BYTES;
        if (l + 1 < levels) {
            uint8_t *next = level == a ? b : a;
            hlod_tex_downsample(level, lw, lh, next, c);
            level = next;
            lw = half(lw);
            lh = half(lh);
        }
    }
    free(a);
    free(b);
    *blocks = out;
    *bytes = total;
    return HLOD_OK;
}

void hlod_bc_decode_level(const uint8_t *blocks, uint32_t lw, uint32_t lh, uint32_t c,
                          uint8_t *out, uint32_t out_c)
{
    uint8_t rgba[64];
    const int bc4 = c == 1;
    for (uint32_t by = 0; by < lh; by += 4)
        for (uint32_t bx = 0; bx < lw; bx += 4) {
            hlod_bc_decode_block(blocks, bc4, rgba);
            blocks += HLOD_BC_BLOCK_BYTES;
            for (uint32_t j = 0; j < 16; j++) {
                uint32_t x = bx + j % 4, y = by + j / 4;
                if (x >= lw || y >= lh)
                    continue;
                uint8_t *d = out + ((size_t)y * lw + x) * out_c;
                for (uint32_t k = 0; k < out_c; k++)
                    d[k] = k < 3 ? rgba[4 * j + k] : 255;
            }
        }
}

double hlod_tex_psnr(const uint8_t *a, const uint8_t *b, size_t n)
{
    double se = 0;
    for (size_t i = 0; i < n; i++) {
        double d = (double)a[i] - b[i];
        se += d * d;
    }
    if (!n || se == 0)
        return 99.0;
    double db = 10.0 * log10(255.0 * 255.0 * (double)n / se);
    return db < 99.0 ? db : 99.0;
}
