/*
 * texture_codec.h - textures stored GPU-ready (docs/store-format.md,
 * "Block-coded textures"; docs/runtime.md, "Texture upload").
 *
 * A texture of 3 channels is stored as BC1 blocks (S3TC DXT1, opaque), one
 * of 1 channel as BC4 blocks (RGTC1, unsigned): 8 bytes a 4x4 block either
 * way, so 4 bits a texel.  The whole mip chain is stored, level 0 first:
 * level l + 1 is the 2x2 box average of level l's texels (the filter of
 * engine/texture.h), sizes halving and rounding down to 1x1, each level
 * block-coded on its own (a level not a multiple of 4 pads its last blocks
 * with its edge texels).  The chain is then one zstd frame.
 *
 * Blocks are encoded with stb_dxt (Debian libstb, high-quality mode).
 * Decoding follows the format as GL samples it (OpenGL's
 * EXT_texture_compression_s3tc and ARB_texture_compression_rgtc): a BC1
 * block whose first colour is not greater than its second is in
 * three-colour mode, index 3 black.  The loader decodes with the few lines
 * here rather than libsquish (Debian libsquish-dev): libsquish decodes a
 * block at a time into a 16-texel scratch, 4.9 ms a megapixel of RGBA
 * against 2.4 ms here (one run side by side, 1024^2 level 0, this 2-core
 * machine under load).  libsquish stays as the reference the tests hold
 * this decoder to, byte for byte (hlod_bc_decode_block).
 *
 * Reentrant; no global state.
 */
#ifndef HLOD_TEXTURE_CODEC_H
#define HLOD_TEXTURE_CODEC_H

#include "hlod/hlod.h"

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HLOD_BC_BLOCK_BYTES 8u

/* Levels of a full mip chain of w x h (w, h >= 1): 1 + floor(log2(max)). */
uint32_t hlod_tex_level_count(uint32_t w, uint32_t h);

/* Size of level l of a w x h chain: max(1, w >> l) x max(1, h >> l). */
void hlod_tex_level_size(uint32_t w, uint32_t h, uint32_t l, uint32_t *lw, uint32_t *lh);

/* Bytes of one level's blocks: ceil(lw / 4) * ceil(lh / 4) * 8. */
size_t hlod_bc_level_bytes(uint32_t lw, uint32_t lh);

/* Bytes of a w x h chain's blocks, all levels; 0 when it would not fit a
 * size_t or w, h is 0. */
size_t hlod_bc_chain_bytes(uint32_t w, uint32_t h);

/* dst (half of sw x sh, rounding down, at least 1) from src: each texel the
 * rounded mean of its 2x2 source block, an odd edge clamped.  c channels. */
void hlod_tex_downsample(const uint8_t *src, uint32_t sw, uint32_t sh, uint8_t *dst,
                         uint32_t c);

/* Encodes the mip chain of pixels (w x h, c = 1 or 3 channels, top row
 * first) into *blocks (malloc'ed, *bytes = hlod_bc_chain_bytes(w, h)):
 * BC4 for c = 1, BC1 for c = 3.  HLOD_ERR_INVALID_ARG for another c or a
 * zero size, HLOD_ERR_NOMEM. */
hlod_result hlod_bc_encode_chain(const uint8_t *pixels, uint32_t w, uint32_t h, uint32_t c,
                                 uint8_t **blocks, size_t *bytes);

/* hlod_bc_encode_chain in two steps, for a caller that may stop after
 * level 0: the top level's blocks into the start of chain (a buffer of
 * hlod_bc_chain_bytes(w, h)), then the levels below it (HLOD_ERR_NOMEM).
 * c is 1 or 3, w and h at least 1; the bytes equal the one-step call's. */
void hlod_bc_encode_top(const uint8_t *pixels, uint32_t w, uint32_t h, uint32_t c, uint8_t *chain);
hlod_result hlod_bc_encode_below(const uint8_t *pixels, uint32_t w, uint32_t h, uint32_t c,
                                 uint8_t *chain);

/* Decodes one level's blocks (lw x lh texels, ceil(lw/4) * ceil(lh/4)
 * blocks) into out: out_c bytes a texel (BC1: 3 RGB or 4 RGBA with alpha
 * 255; BC4: 1).  c is the texture's stored channels (1: BC4, 3: BC1). */
void hlod_bc_decode_level(const uint8_t *blocks, uint32_t lw, uint32_t lh, uint32_t c,
                          uint8_t *out, uint32_t out_c);

/* The whole chain of a w x h texture's blocks (c = 1: BC4, 3: BC1)
 * decoded to texels, level after level, in a new malloc'ed buffer: RGBA
 * (alpha 255) from BC1, grey from BC4; *out_c says which.  NULL when out
 * of memory. */
uint8_t *hlod_bc_decode_chain(const uint8_t *blocks, uint32_t w, uint32_t h, uint32_t c,
                              uint32_t *out_c);

/* PSNR in dB of n bytes against n bytes, 10 log10(255^2 / MSE), at most
 * 99 (identical bytes give 99). */
double hlod_tex_psnr(const uint8_t *a, const uint8_t *b, size_t n);

/* One block through libsquish (texture_squish.cpp), the reference the
 * decoder above is tested against: 16 RGBA texels, row by row; bc4
 * selects BC4 (red in texel byte 0) over BC1. */
void hlod_bc_decode_block(const uint8_t *block, int bc4, uint8_t rgba[64]);

#ifdef __cplusplus
}
#endif

#endif
