/*
 * texture_squish.cpp - block decoding through libsquish (texture_codec.h).
 *
 * libsquish 1.15's Decompress decodes BC1 (kDxt1) directly; its kBc4 flag
 * is honoured by the image functions only, so a BC4 block is decoded as
 * the alpha half of a BC3 (kDxt5) block, which has BC4's exact layout
 * (Microsoft's BC4 format documentation; ARB_texture_compression_rgtc).
 * It throws nothing.
 */
#include "texture_codec.h"

#include <cstring>
#include <squish.h>

extern "C" void hlod_bc_decode_block(const uint8_t *block, int bc4, uint8_t rgba[64])
{
    if (!bc4) {
        squish::Decompress(rgba, block, squish::kDxt1);
        return;
    }
    uint8_t bc3[16] = {0};
    std::memcpy(bc3, block, 8);
    squish::Decompress(rgba, bc3, squish::kDxt5);
    for (int i = 0; i < 16; i++)
        rgba[4 * i] = rgba[4 * i + 3];
}
