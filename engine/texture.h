/*
 * texture.h - a payload's texture made ready for the GPU on the loader thread.
 *
 * A software GL converts RGB texels to its 4-byte layout and builds the mip
 * chain (glGenerateMipmap: one blit per level) on the render thread, where
 * the frame's deadline pays for it.  Done here instead, the upload is a copy
 * per level: on llvmpipe 116x116 went from 0.47 to 0.05 ms, 290x290 from
 * 1.06 to 0.32 ms and 850x850 from 5.0-6.0 to 2.6-2.9 ms of render-thread
 * time (docs/runtime.md, Loading).
 */
#ifndef HLOD_TEXTURE_H
#define HLOD_TEXTURE_H

#include "hlod/store.h"

/* Replaces p's texture (if any) by its mip chain: RGB becomes RGBA (alpha
 * 255), grey, grey + alpha and RGBA keep their channels; level l + 1 is the
 * 2x2 box average of level l (sizes halve, rounding down, to 1x1; an odd
 * last row or column is averaged with its neighbour's clamp).  The levels
 * lie one after another in p->tex_memory (freed by hlod_store_payload_free),
 * p->pixels points at level 0 and p->tex_levels counts them.  A payload
 * without a texture, or one already prepared, is left alone.  Returns
 * HLOD_ERR_NOMEM (p unchanged) when the chain cannot be allocated. */
hlod_result hlod_texture_prepare(hlod_store_payload *p);

/* Bytes of a mip chain of w x h texels of c channels, all levels. */
size_t hlod_texture_chain_bytes(uint32_t w, uint32_t h, uint32_t c);

#endif
