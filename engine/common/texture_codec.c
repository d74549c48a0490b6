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

size_t hlod_bc_level_bytes(uint32_t lw, uint32_t lh)
{
    return level_blocks(lw, lh) * HLOD_BC_BLOCK_BYTES;
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

void hlod_bc_encode_top(const uint8_t *pixels, uint32_t w, uint32_t h, uint32_t c, uint8_t *chain)
{
    encode_level(pixels, w, h, c, chain);
}

hlod_result hlod_bc_encode_below(const uint8_t *pixels, uint32_t w, uint32_t h, uint32_t c,
                                 uint8_t *chain)
{
    uint32_t levels = hlod_tex_level_count(w, h), lw = w, lh = h;
    if (levels < 2)
        return HLOD_OK;
    /* two scratch levels: level l + 1 is made from level l */
    size_t scratch = (size_t)half(w) * half(h) * c;
    uint8_t *a = malloc(scratch), *b = malloc(scratch);
    if (!a || !b) {
        free(a);
        free(b);
        return HLOD_ERR_NOMEM;
    }
    const uint8_t *level = pixels;
    uint8_t *at = chain + level_blocks(lw, lh) * HLOD_BC_BLOCK_BYTES;
    for (uint32_t l = 1; l < levels; l++) {
        uint8_t *next = level == a ? b : a;
        hlod_tex_downsample(level, lw, lh, next, c);
        level = next;
        lw = half(lw);
        lh = half(lh);
        encode_level(level, lw, lh, c, at);
        at += level_blocks(lw, lh) * HLOD_BC_BLOCK_BYTES;
    }
    free(a);
    free(b);
    return HLOD_OK;
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
    if (!out)
        return HLOD_ERR_NOMEM;
    hlod_bc_encode_top(pixels, w, h, c, out);
    hlod_result r = hlod_bc_encode_below(pixels, w, h, c, out);
    if (r != HLOD_OK) {
        free(out);
        return r;
    }
    *blocks = out;
    *bytes = total;
    return HLOD_OK;
}

/* A 565 colour widened to 8 bits a channel by bit replication. */
static void rgb565(uint32_t c, uint8_t out[3])
{
    uint32_t r = (c >> 11) & 31, g = (c >> 5) & 63, b = c & 31;
    out[0] = (uint8_t)((r << 3) | (r >> 2));
    out[1] = (uint8_t)((g << 2) | (g >> 4));
    out[2] = (uint8_t)((b << 3) | (b >> 2));
}

/* A BC1 block's palette, RGBA with alpha 255 (what the texel chain holds;
 * three-colour mode's index 3 is black): as the S3TC extension defines it,
 * rounded down as libsquish does (texture_squish.cpp decodes the same
 * bytes; test_texture_codec compares them). */
static void bc1_palette(const uint8_t *b, uint8_t pal[4][4])
{
    uint32_t c0 = b[0] | (uint32_t)b[1] << 8, c1 = b[2] | (uint32_t)b[3] << 8;
    rgb565(c0, pal[0]);
    rgb565(c1, pal[1]);
    for (int k = 0; k < 3; k++) {
        if (c0 > c1) {
            pal[2][k] = (uint8_t)((2 * pal[0][k] + pal[1][k]) / 3);
            pal[3][k] = (uint8_t)((pal[0][k] + 2 * pal[1][k]) / 3);
        } else {
            pal[2][k] = (uint8_t)((pal[0][k] + pal[1][k]) / 2);
            pal[3][k] = 0;
        }
    }
    pal[0][3] = pal[1][3] = pal[2][3] = pal[3][3] = 255;
}

/* One BC1 block's texels into out (rows of lw texels, out_c = 3 or 4
 * bytes each), nx x ny of them (an edge block's may be fewer than 4). */
static void bc1_block(const uint8_t *b, uint8_t *out, uint32_t lw, uint32_t out_c, uint32_t nx,
                      uint32_t ny)
{
    uint8_t pal[4][4];
    bc1_palette(b, pal);
    for (uint32_t y = 0; y < ny; y++) {
        uint32_t row = b[4 + y];
        uint8_t *d = out + (size_t)y * lw * out_c;
        if (out_c == 4)
            for (uint32_t x = 0; x < nx; x++)
                memcpy(d + 4 * x, pal[(row >> (2 * x)) & 3], 4);
        else
            for (uint32_t x = 0; x < nx; x++)
                memcpy(d + 3 * x, pal[(row >> (2 * x)) & 3], 3);
    }
}

/* One BC4 block's values into out (rows of lw bytes), nx x ny of them
 * (the BC3 alpha block's layout and rounding). */
static void bc4_block(const uint8_t *b, uint8_t *out, uint32_t lw, uint32_t nx, uint32_t ny)
{
    uint8_t pal[8];
    uint32_t a0 = b[0], a1 = b[1];
    pal[0] = (uint8_t)a0;
    pal[1] = (uint8_t)a1;
    if (a0 > a1) {
        for (uint32_t i = 1; i < 7; i++)
            pal[1 + i] = (uint8_t)(((7 - i) * a0 + i * a1) / 7);
    } else {
        for (uint32_t i = 1; i < 5; i++)
            pal[1 + i] = (uint8_t)(((5 - i) * a0 + i * a1) / 5);
        pal[6] = 0;
        pal[7] = 255;
    }
    uint64_t idx = 0;
    for (int k = 0; k < 6; k++)
        idx |= (uint64_t)b[2 + k] << (8 * k);
    for (uint32_t y = 0; y < ny; y++)
        for (uint32_t x = 0; x < nx; x++)
            out[(size_t)y * lw + x] = pal[(idx >> (3 * (4 * y + x))) & 7];
}

void hlod_bc_decode_level(const uint8_t *blocks, uint32_t lw, uint32_t lh, uint32_t c,
                          uint8_t *out, uint32_t out_c)
{
    for (uint32_t by = 0; by < lh; by += 4)
        for (uint32_t bx = 0; bx < lw; bx += 4) {
            uint32_t nx = lw - bx < 4 ? lw - bx : 4, ny = lh - by < 4 ? lh - by : 4;
            uint8_t *d = out + ((size_t)by * lw + bx) * out_c;
            if (c == 1)
                bc4_block(blocks, d, lw, nx, ny);
            else
                bc1_block(blocks, d, lw, out_c, nx, ny);
            blocks += HLOD_BC_BLOCK_BYTES;
        }
}

uint8_t *hlod_bc_decode_chain(const uint8_t *blocks, uint32_t w, uint32_t h, uint32_t c,
                              uint32_t *out_c)
{
    const uint32_t oc = c == 3 ? 4 : 1, levels = hlod_tex_level_count(w, h);
    size_t total = 0;
    for (uint32_t l = 0; l < levels; l++) {
        uint32_t lw, lh;
        hlod_tex_level_size(w, h, l, &lw, &lh);
        total += (size_t)lw * lh * oc;
    }
    uint8_t *texels = malloc(total), *t = texels;
    if (!texels)
        return NULL;
    for (uint32_t l = 0; l < levels; l++) {
        uint32_t lw, lh;
        hlod_tex_level_size(w, h, l, &lw, &lh);
        hlod_bc_decode_level(blocks, lw, lh, c, t, oc);
        blocks += hlod_bc_level_bytes(lw, lh);
        t += (size_t)lw * lh * oc;
    }
    *out_c = oc;
    return texels;
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
