/*
 * image.h - texture images, read, resized and written through OpenImageIO.
 *
 * A small C++ file (engine/common/image_oiio.cpp) wraps OpenImageIO; this
 * header is plain C so nothing else sees C++ types.  Pixels are 8-bit,
 * row-major, top row first, `channels` interleaved (1..4).
 *
 * Ownership: hlod_image owns its pixels (malloc'ed); free with
 * hlod_image_free().  Thread safety: reentrant on distinct images.
 */
#ifndef HLOD_IMAGE_H
#define HLOD_IMAGE_H

#include "hlod/hlod.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hlod_image {
    int width, height, channels;
    uint8_t *pixels;            /* width * height * channels bytes */
} hlod_image;

void hlod_image_free(hlod_image *img);

/* Reads any format OpenImageIO knows (PNG, JPEG, TGA, ...), converted to
 * 8 bits per channel.  Errors name the file through lg. */
hlod_result hlod_image_read(const char *path, hlod_image *out, const hlod_logger *lg);

/* Header only: size and channels without decoding pixels. */
hlod_result hlod_image_probe(const char *path, int *width, int *height, int *channels,
                             const hlod_logger *lg);

/* Writes by extension (.png, .jpg, ...), through a temporary file renamed
 * into place. */
hlod_result hlod_image_write(const char *path, const hlod_image *img, const hlod_logger *lg);

/* Resamples src to width x height.  Shrinking on both axes (what the
 * hierarchy builders do) averages the source area each output texel
 * covers, partial texels by their overlap (an exact box filter); anything
 * else goes through OpenImageIO's ImageBufAlgo::resize with a box filter. */
hlod_result hlod_image_resize(const hlod_image *src, int width, int height, hlod_image *out);

#ifdef __cplusplus
}
#endif
#endif
