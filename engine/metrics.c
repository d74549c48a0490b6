/*
 * Image metrics and summary statistics (see hlod/metrics.h).
 *
 * SSIM design: the five local moments (mean of x, of y, of x^2, y^2, xy)
 * under the separable 11x11 Gaussian are computed in one pass over the
 * rows.  Each input row is converted to luma and filtered horizontally
 * into a ring of 11 rows; once 11 rows are in, the vertical filter gives
 * one output row of SSIM values, which are summed at once.  Scratch is
 * O(width), not O(pixels), and every input pixel is converted once.
 *
 * The formula is evaluated so that swapping a and b swaps only operands of
 * commutative operations: SSIM(a, b) == SSIM(b, a) bit for bit, and
 * identical images give exactly 1.
 */
#include "hlod/metrics.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define W HLOD_SSIM_WINDOW

static double luma(const uint8_t *p)
{
    return 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2];
}

static int bad_images(const uint8_t *a, const uint8_t *b, uint32_t width, uint32_t height,
                      const double *out)
{
    return !a || !b || !out || width == 0 || height == 0 ||
           (uint64_t)width * height > SIZE_MAX / 3;
}

hlod_result hlod_psnr_rgb8(const uint8_t *a, const uint8_t *b, uint32_t width, uint32_t height,
                           double *out)
{
    if (bad_images(a, b, width, height, out))
        return HLOD_ERR_INVALID_ARG;
    size_t n = (size_t)width * height * 3;
    uint64_t sse = 0;
    for (size_t i = 0; i < n; i++) {
        int d = (int)a[i] - (int)b[i];
        sse += (uint64_t)(d * d);
    }
    if (sse == 0) {
        *out = HLOD_PSNR_MAX;
        return HLOD_OK;
    }
    double mse = (double)sse / (double)n;
    double psnr = 10.0 * log10(255.0 * 255.0 / mse);
    *out = psnr < HLOD_PSNR_MAX ? psnr : HLOD_PSNR_MAX;
    return HLOD_OK;
}

hlod_result hlod_luma_change_rgb8(const uint8_t *a, const uint8_t *b, uint32_t width,
                                  uint32_t height, double *out)
{
    if (bad_images(a, b, width, height, out))
        return HLOD_ERR_INVALID_ARG;
    size_t n = (size_t)width * height;
    double sum = 0;
    for (size_t i = 0; i < n; i++)
        sum += fabs(luma(a + 3 * i) - luma(b + 3 * i));
    *out = sum / (double)n;
    return HLOD_OK;
}

enum { MX, MY, XX, YY, XY, MOMENTS };

hlod_result hlod_ssim_rgb8(const uint8_t *a, const uint8_t *b, uint32_t width, uint32_t height,
                           double *out)
{
    if (bad_images(a, b, width, height, out) || width < W || height < W)
        return HLOD_ERR_INVALID_ARG;
    const double L = 255.0;
    const double c1 = (HLOD_SSIM_K1 * L) * (HLOD_SSIM_K1 * L);
    const double c2 = (HLOD_SSIM_K2 * L) * (HLOD_SSIM_K2 * L);
    double g[W], gsum = 0;
    for (int k = 0; k < W; k++) {
        double d = k - (W - 1) / 2;
        g[k] = exp(-d * d / (2 * HLOD_SSIM_SIGMA * HLOD_SSIM_SIGMA));
        gsum += g[k];
    }
    for (int k = 0; k < W; k++)
        g[k] /= gsum;

    size_t w = width, ow = w - (W - 1);
    /* ring[slot][moment][x]: horizontally filtered rows */
    double *ring = malloc((size_t)W * MOMENTS * ow * sizeof *ring);
    double *ya = malloc(2 * w * sizeof *ya);
    if (!ring || !ya) {
        free(ring);
        free(ya);
        return HLOD_ERR_NOMEM;
    }
    double *yb = ya + w;
    double total = 0;
    for (size_t y = 0; y < height; y++) {
        const uint8_t *ra = a + y * w * 3, *rb = b + y * w * 3;
        for (size_t x = 0; x < w; x++) {
            ya[x] = luma(ra + 3 * x);
            yb[x] = luma(rb + 3 * x);
        }
        double *slot = ring + (y % W) * MOMENTS * ow;
        for (size_t x = 0; x < ow; x++) {
            double m[MOMENTS] = {0};
            for (int k = 0; k < W; k++) {
                double p = ya[x + k], q = yb[x + k];
                m[MX] += g[k] * p;
                m[MY] += g[k] * q;
                m[XX] += g[k] * (p * p);
                m[YY] += g[k] * (q * q);
                m[XY] += g[k] * (p * q);
            }
            for (int j = 0; j < MOMENTS; j++)
                slot[j * ow + x] = m[j];
        }
        if (y + 1 < W)
            continue;
        /* Output row y - (W - 1): input rows y - W + 1 .. y, weight g[k]
         * for row y - W + 1 + k. */
        double row = 0;
        for (size_t x = 0; x < ow; x++) {
            double m[MOMENTS] = {0};
            for (int k = 0; k < W; k++) {
                const double *s = ring + ((y + 1 + (size_t)k) % W) * MOMENTS * ow;
                for (int j = 0; j < MOMENTS; j++)
                    m[j] += g[k] * s[j * ow + x];
            }
            double vx = m[XX] - m[MX] * m[MX], vy = m[YY] - m[MY] * m[MY];
            double cov = m[XY] - m[MX] * m[MY];
            double num = (2 * (m[MX] * m[MY]) + c1) * (2 * cov + c2);
            double den = (m[MX] * m[MX] + m[MY] * m[MY] + c1) * (vx + vy + c2);
            row += num / den;
        }
        total += row;
    }
    free(ring);
    free(ya);
    *out = total / ((double)ow * (double)(height - (W - 1)));
    return HLOD_OK;
}

/* ---- summary statistics ---- */

double hlod_stats_mean(const double *v, size_t n)
{
    double sum = 0;
    size_t k = 0;
    for (size_t i = 0; v && i < n; i++)
        if (!isnan(v[i])) {
            sum += v[i];
            k++;
        }
    return k ? sum / (double)k : NAN;
}

double hlod_stats_min(const double *v, size_t n)
{
    double m = NAN;
    for (size_t i = 0; v && i < n; i++)
        if (!isnan(v[i]) && (isnan(m) || v[i] < m))
            m = v[i];
    return m;
}

double hlod_stats_max(const double *v, size_t n)
{
    double m = NAN;
    for (size_t i = 0; v && i < n; i++)
        if (!isnan(v[i]) && (isnan(m) || v[i] > m))
            m = v[i];
    return m;
}

static int cmp_nan_last(const void *pa, const void *pb)
{
    double a = *(const double *)pa, b = *(const double *)pb;
    if (isnan(a) || isnan(b))
        return isnan(a) - isnan(b);
    return (a > b) - (a < b);
}

size_t hlod_stats_sort(double *v, size_t n)
{
    if (!v || n == 0)
        return 0;
    qsort(v, n, sizeof *v, cmp_nan_last);
    size_t k = n;
    while (k > 0 && isnan(v[k - 1]))
        k--;
    return k;
}

double hlod_stats_percentile_sorted(const double *sorted, size_t n, double p)
{
    if (!sorted || n == 0 || !(p >= 0 && p <= 100))
        return NAN;
    double x = p / 100.0 * (double)(n - 1);
    size_t i = (size_t)floor(x);
    if (i >= n - 1)
        return sorted[n - 1];
    double f = x - (double)i;
    if (f == 0 || sorted[i] == sorted[i + 1])
        return sorted[i];
    return sorted[i] + f * (sorted[i + 1] - sorted[i]);
}

hlod_result hlod_stats_percentiles(const double *v, size_t n, const double *p, size_t np,
                                   double *out)
{
    if ((!v && n) || (!p && np) || (!out && np))
        return HLOD_ERR_INVALID_ARG;
    double *s = NULL;
    if (n) {
        if (n > SIZE_MAX / sizeof *s || !(s = malloc(n * sizeof *s)))
            return HLOD_ERR_NOMEM;
        memcpy(s, v, n * sizeof *s);
    }
    size_t k = hlod_stats_sort(s, n);
    for (size_t i = 0; i < np; i++)
        out[i] = hlod_stats_percentile_sorted(s, k, p[i]);
    free(s);
    return HLOD_OK;
}

hlod_result hlod_stats_moving_average(const double *v, size_t n, size_t window, double *out)
{
    if (window == 0 || (n && (!v || !out)))
        return HLOD_ERR_INVALID_ARG;
    double sum = 0;
    size_t count = 0;
    for (size_t i = 0; i < n; i++) {
        size_t first = i + 1 >= window ? i + 1 - window : 0;
        if (i % window == 0) {
            /* Re-sum exactly once per window length: rounding errors of
             * the running sum cannot build up, and an infinity leaves it. */
            sum = 0;
            count = 0;
            for (size_t j = first; j <= i; j++)
                if (!isnan(v[j])) {
                    sum += v[j];
                    count++;
                }
        } else {
            if (!isnan(v[i])) {
                sum += v[i];
                count++;
            }
            if (first > 0 && !isnan(v[first - 1])) {
                sum -= v[first - 1];
                count--;
            }
        }
        out[i] = count ? sum / (double)count : NAN;
    }
    return HLOD_OK;
}
