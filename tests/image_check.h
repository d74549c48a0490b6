/*
 * image_check.h - coverage masks for the image tests: PSNR averages a hole
 * away (27 dB accepts about 0.8% of pixels completely wrong), a mask
 * comparison does not.
 *
 * A pixel is covered when it differs from the background colour.  Two
 * renders of the same scene may disagree on covered pixels along a
 * silhouette (rasterisation, a simplified edge); a hole, or geometry where
 * there should be none, makes them disagree inside a region.  mask_holes
 * counts the pixels where the masks disagree although each mask is
 * uniform over the pixel's 3 x 3 neighbourhood: not on an edge of either.
 */
#ifndef HLOD_IMAGE_CHECK_H
#define HLOD_IMAGE_CHECK_H

#include <stddef.h>
#include <stdint.h>

static inline int mask_covered(const uint8_t *rgb, int w, int x, int y, const uint8_t bg[3])
{
    const uint8_t *p = rgb + 3 * ((size_t)y * (size_t)w + (size_t)x);
    return p[0] != bg[0] || p[1] != bg[1] || p[2] != bg[2];
}

/* Is the mask the same over the 3 x 3 pixels around (x, y)? */
static inline int mask_uniform(const uint8_t *rgb, int w, int x, int y, const uint8_t bg[3])
{
    int c = mask_covered(rgb, w, x, y, bg);
    for (int dy = -1; dy <= 1; dy++)
        for (int dx = -1; dx <= 1; dx++)
            if (mask_covered(rgb, w, x + dx, y + dy, bg) != c)
                return 0;
    return 1;
}

/* Pixels inside a region of either mask that the other mask disagrees
 * on (the border row and column are not judged).  *differ, when not NULL,
 * gets every pixel whose coverage differs, edges included. */
static inline size_t mask_holes(const uint8_t *a, const uint8_t bg_a[3], const uint8_t *b,
                                const uint8_t bg_b[3], int w, int h, size_t *differ)
{
    size_t holes = 0, all = 0;
    for (int y = 1; y + 1 < h; y++)
        for (int x = 1; x + 1 < w; x++) {
            if (mask_covered(a, w, x, y, bg_a) == mask_covered(b, w, x, y, bg_b))
                continue;
            all++;
            holes += mask_uniform(a, w, x, y, bg_a) && mask_uniform(b, w, x, y, bg_b);
        }
    if (differ)
        *differ = all;
    return holes;
}

#endif
