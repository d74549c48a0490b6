/*
 * metrics.h - image error and summary statistics for the benchmarks
 * (docs/hlod-bench.md): PSNR and SSIM of a frame against its full-detail reference,
 * the mean absolute luminance change between consecutive frames (the
 * image-space temporal flicker of issue 5), and percentiles, means and a
 * moving average for summary.json and the plots.
 *
 * Images are 8-bit RGB, width * height * 3 bytes, rows packed with no
 * padding (what hlod_osmesa_read_rgb returns); the row order does not
 * matter as long as both images use the same one.  The caller owns every
 * buffer; nothing here keeps a pointer after returning.
 *
 * Luminance is Rec. 601 luma, Y = 0.299 R + 0.587 G + 0.114 B on the 0..255
 * codes (MATLAB's rgb2gray, which Wang et al.'s reference SSIM code uses).
 *
 * Thread safety: every function is reentrant (no global state).
 */
#ifndef HLOD_METRICS_H
#define HLOD_METRICS_H

#include <stddef.h>
#include <stdint.h>

#include "hlod/hlod.h"

#ifdef __cplusplus
extern "C" {
#endif

/* PSNR of identical images, and the ceiling of every PSNR: a finite value
 * keeps means and plots usable.  A single code differing by 1 in a 1280x720
 * image would read 112.6 dB, so anything above 99 dB is reported as 99:
 * "indistinguishable". */
#define HLOD_PSNR_MAX 99.0

/* SSIM constants (Wang, Bovik, Sheikh, Simoncelli 2004, section III-C). */
#define HLOD_SSIM_WINDOW 11         /* Gaussian window side, pixels */
#define HLOD_SSIM_SIGMA 1.5         /* its standard deviation */
#define HLOD_SSIM_K1 0.01
#define HLOD_SSIM_K2 0.03

/* PSNR in dB over all three channels: 10 log10(255^2 / MSE), MSE the mean
 * of the squared code differences over width * height * 3 samples,
 * clamped to at most HLOD_PSNR_MAX.  HLOD_ERR_INVALID_ARG for a NULL
 * pointer or a zero size.  O(pixels), no allocation. */
hlod_result hlod_psnr_rgb8(const uint8_t *a, const uint8_t *b, uint32_t width, uint32_t height,
                           double *out);

/* Mean SSIM on luminance (Wang et al. 2004, eq. 13 with C1 = (K1 L)^2,
 * C2 = (K2 L)^2, L = 255): local statistics weighted by an 11x11 Gaussian
 * (sigma 1.5, normalised), averaged over every window position that fits
 * inside the image (no padding), without the automatic downsampling of
 * the later ssim.m.  1 for identical images, symmetric in a and b, in
 * [-1, 1].  Both sides must be at least 11 pixels: else
 * HLOD_ERR_INVALID_ARG.  HLOD_ERR_NOMEM.  Cost: about 2 * 5 * 11 multiply-adds
 * per pixel (a separable filter) and about 57 * width doubles of scratch;
 * about 0.1 s at 1280x720. */
hlod_result hlod_ssim_rgb8(const uint8_t *a, const uint8_t *b, uint32_t width, uint32_t height,
                           double *out);

/* Mean over pixels of |Y_a - Y_b| (luma codes, 0..255): the image-space
 * flicker between consecutive frames a and b.  O(pixels). */
hlod_result hlod_luma_change_rgb8(const uint8_t *a, const uint8_t *b, uint32_t width,
                                  uint32_t height, double *out);

/* ---- summary statistics ----
 *
 * NaN entries mean "no value" (e.g. a frame without a reference) and are
 * skipped by every function below; a result over no values is NaN. */

/* Arithmetic mean. */
double hlod_stats_mean(const double *v, size_t n);
double hlod_stats_min(const double *v, size_t n);
double hlod_stats_max(const double *v, size_t n);

/* Sorts ascending, NaNs last; returns the number of non-NaN values (the
 * sorted prefix). */
size_t hlod_stats_sort(double *v, size_t n);

/* Percentile p in [0, 100] of n sorted values (no NaN), interpolated
 * linearly between the closest ranks: x = p / 100 * (n - 1), result
 * v[floor x] + (x - floor x) * (v[floor x + 1] - v[floor x]).  This is
 * Hyndman and Fan's type 7, numpy's and R's default, so scripts
 * recomputing a percentile from frames.csv get the same number.  NaN for
 * n == 0 or p outside [0, 100]. */
double hlod_stats_percentile_sorted(const double *sorted, size_t n, double p);

/* Percentiles p[0..np-1] of unsorted values (copied and sorted once). */
hlod_result hlod_stats_percentiles(const double *v, size_t n, const double *p, size_t np,
                                   double *out);

/* Trailing moving average over `window` values: out[i] is the mean of the
 * non-NaN values among v[max(0, i - window + 1) .. i] (fewer at the start;
 * NaN when there are none).  The 35-frame toggle curve of Lakhia Fig. 8
 * is window = 35.  out must not overlap v.  O(n). */
hlod_result hlod_stats_moving_average(const double *v, size_t n, size_t window, double *out);

#ifdef __cplusplus
}
#endif
#endif
