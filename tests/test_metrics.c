/*
 * Image metrics and summary statistics (hlod/metrics.h): PSNR against
 * hand-computed values and its cap, SSIM against a hand-computed value and
 * a direct (non-separable, per-window) evaluation of Wang et al.'s
 * formula, its symmetry and the orderings the paper is known for (a
 * constant shift costs far less than noise of the same MSE), the
 * luminance change, and percentiles, means and the moving average against
 * hand-computed numbers.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "hlod/metrics.h"

static uint8_t *image(uint32_t w, uint32_t h, uint8_t v)
{
    uint8_t *p = malloc((size_t)w * h * 3);
    memset(p, v, (size_t)w * h * 3);
    return p;
}

static uint64_t lcg(uint64_t *s)
{
    *s = *s * 6364136223846793005ULL + 1442695040888963407ULL;
    return *s >> 33;
}

/* A grey test card with structure at several scales, values in 40..215
 * so that +-30 never clips. */
static uint8_t *test_card(uint32_t w, uint32_t h)
{
    uint8_t *p = malloc((size_t)w * h * 3);
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++) {
            double v = 128 + 40 * sin(x * 0.31) * cos(y * 0.17) + 30 * ((x / 7 + y / 5) % 2 ? 1 : -1) +
                       15 * sin((x + 2.0 * y) * 0.05);
            uint8_t c = (uint8_t)lround(fmin(215, fmax(40, v)));
            for (int k = 0; k < 3; k++)
                p[3 * ((size_t)y * w + x) + k] = c;
        }
    return p;
}

/* ---------- PSNR ---------- */

static void psnr_hand_values(void)
{
    double v = 0;
    uint8_t *a = image(2, 1, 0), *b = image(2, 1, 0);
    CHECK(hlod_psnr_rgb8(a, b, 2, 1, &v) == HLOD_OK && v == HLOD_PSNR_MAX && v == 99.0);
    b[4] = 10;                                      /* SSE 100 over 6 samples */
    CHECK(hlod_psnr_rgb8(a, b, 2, 1, &v) == HLOD_OK);
    CHECKF(fabs(v - 35.91231611251554) < 1e-12, "%.17g", v);
    memset(b, 1, 6);                                /* MSE 1: 20 log10 255 */
    CHECK(hlod_psnr_rgb8(a, b, 2, 1, &v) == HLOD_OK && fabs(v - 48.1308036086791) < 1e-12);
    memset(b, 255, 6);                              /* MSE 255^2: 0 dB */
    CHECK(hlod_psnr_rgb8(a, b, 2, 1, &v) == HLOD_OK && fabs(v) < 1e-12);
    CHECK(hlod_psnr_rgb8(b, a, 2, 1, &v) == HLOD_OK && fabs(v) < 1e-12);
    free(a);
    free(b);

    /* One code off by one in 1280x720 would be 112.5 dB: capped. */
    a = image(1280, 720, 77);
    b = image(1280, 720, 77);
    b[12345] = 78;
    CHECK(hlod_psnr_rgb8(a, b, 1280, 720, &v) == HLOD_OK && v == HLOD_PSNR_MAX);
    free(a);
    free(b);

    CHECK(hlod_psnr_rgb8(NULL, NULL, 2, 1, &v) == HLOD_ERR_INVALID_ARG);
    uint8_t px[3] = {0};
    CHECK(hlod_psnr_rgb8(px, px, 0, 1, &v) == HLOD_ERR_INVALID_ARG);
    CHECK(hlod_psnr_rgb8(px, px, 1, 1, NULL) == HLOD_ERR_INVALID_ARG);
}

/* ---------- SSIM ---------- */

/* Wang et al. eq. 13, mean over all valid 11x11 windows, each window's
 * statistics summed directly with the 2-D Gaussian: the oracle. */
static double ssim_direct(const uint8_t *a, const uint8_t *b, int w, int h)
{
    double g[11], gs = 0;
    for (int k = 0; k < 11; k++) {
        g[k] = exp(-(k - 5) * (k - 5) / (2 * 1.5 * 1.5));
        gs += g[k];
    }
    const double c1 = pow(0.01 * 255, 2), c2 = pow(0.03 * 255, 2);
    double total = 0;
    for (int y0 = 0; y0 + 11 <= h; y0++)
        for (int x0 = 0; x0 + 11 <= w; x0++) {
            double mx = 0, my = 0, sxx = 0, syy = 0, sxy = 0;
            for (int j = 0; j < 11; j++)
                for (int i = 0; i < 11; i++) {
                    double wgt = g[i] * g[j] / (gs * gs);
                    const uint8_t *p = a + 3 * ((size_t)(y0 + j) * w + x0 + i);
                    const uint8_t *q = b + 3 * ((size_t)(y0 + j) * w + x0 + i);
                    double x = 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2];
                    double y = 0.299 * q[0] + 0.587 * q[1] + 0.114 * q[2];
                    mx += wgt * x;
                    my += wgt * y;
                    sxx += wgt * x * x;
                    syy += wgt * y * y;
                    sxy += wgt * x * y;
                }
            double vx = sxx - mx * mx, vy = syy - my * my, cv = sxy - mx * my;
            total += (2 * mx * my + c1) * (2 * cv + c2) /
                     ((mx * mx + my * my + c1) * (vx + vy + c2));
        }
    return total / ((double)(w - 10) * (h - 10));
}

static void ssim_identical_is_one(void)
{
    uint8_t *a = test_card(64, 48);
    double v = 0;
    CHECK(hlod_ssim_rgb8(a, a, 64, 48, &v) == HLOD_OK && v == 1.0);
    uint8_t *c = image(11, 11, 200);
    CHECK(hlod_ssim_rgb8(c, c, 11, 11, &v) == HLOD_OK && v == 1.0);
    free(a);
    free(c);
}

static void ssim_constant_images_hand_value(void)
{
    /* No variance: SSIM = (2 * 100 * 110 + C1) / (100^2 + 110^2 + C1),
     * C1 = (0.01 * 255)^2 = 6.5025. */
    uint8_t *a = image(16, 12, 100), *b = image(16, 12, 110);
    double v = 0;
    CHECK(hlod_ssim_rgb8(a, b, 16, 12, &v) == HLOD_OK);
    CHECKF(fabs(v - 22006.5025 / 22106.5025) < 1e-12, "%.17g", v);
    free(a);
    free(b);
}

static void ssim_matches_direct_windows(void)
{
    const uint32_t w = 37, h = 23;
    uint8_t *a = malloc(w * h * 3), *b = malloc(w * h * 3);
    uint64_t s = 99;
    for (size_t i = 0; i < (size_t)w * h * 3; i++) {
        a[i] = (uint8_t)lcg(&s);
        b[i] = (uint8_t)(a[i] / 2 + lcg(&s) % 100);
    }
    double v = 0, ref = ssim_direct(a, b, (int)w, (int)h);
    CHECK(hlod_ssim_rgb8(a, b, w, h, &v) == HLOD_OK);
    CHECKF(fabs(v - ref) < 1e-12, "%.17g vs %.17g", v, ref);
    CHECK(v > 0 && v < 1);
    free(a);
    free(b);
}

static void ssim_symmetric_and_ordered(void)
{
    const uint32_t w = 96, h = 64;
    size_t n = (size_t)w * h * 3;
    uint8_t *ref = test_card(w, h), *shift = malloc(n), *noise = malloc(n), *inv = malloc(n);
    uint64_t s = 7;
    for (size_t px = 0; px < (size_t)w * h; px++) {
        int d = lcg(&s) & 1 ? 10 : -10;              /* noise with the shift's MSE */
        for (int k = 0; k < 3; k++) {
            size_t i = 3 * px + (size_t)k;
            shift[i] = (uint8_t)(ref[i] + 10);
            noise[i] = (uint8_t)(ref[i] + d);
            inv[i] = (uint8_t)(255 - ref[i]);
        }
    }
    double p_shift, p_noise, s_shift, s_noise, s_rev, s_inv;
    CHECK(hlod_psnr_rgb8(ref, shift, w, h, &p_shift) == HLOD_OK);
    CHECK(hlod_psnr_rgb8(ref, noise, w, h, &p_noise) == HLOD_OK);
    CHECK(p_shift == p_noise);                      /* same MSE: PSNR cannot tell */
    CHECK(hlod_ssim_rgb8(ref, shift, w, h, &s_shift) == HLOD_OK);
    CHECK(hlod_ssim_rgb8(ref, noise, w, h, &s_noise) == HLOD_OK);
    CHECK(hlod_ssim_rgb8(noise, ref, w, h, &s_rev) == HLOD_OK);
    CHECK(hlod_ssim_rgb8(ref, inv, w, h, &s_inv) == HLOD_OK);
    CHECKF(s_shift > 0.99, "%g", s_shift);          /* Wang Fig. 2: a shift is mild */
    CHECKF(1 - s_noise > 10 * (1 - s_shift), "%g vs %g", s_noise, s_shift);  /* noise: 10x worse */
    CHECK(s_rev == s_noise);                        /* symmetric, bit for bit */
    CHECKF(s_inv < 0 && s_inv >= -1, "%g", s_inv);  /* inverted structure */

    /* More noise, lower SSIM. */
    double s_more;
    for (size_t i = 0; i < n; i++)
        noise[i] = (uint8_t)(ref[i] + (int)(lcg(&s) % 61) - 30);
    CHECK(hlod_ssim_rgb8(ref, noise, w, h, &s_more) == HLOD_OK && s_more < s_noise);

    CHECK(hlod_ssim_rgb8(ref, ref, 10, h, &s_more) == HLOD_ERR_INVALID_ARG);
    CHECK(hlod_ssim_rgb8(ref, ref, w, 10, &s_more) == HLOD_ERR_INVALID_ARG);
    CHECK(hlod_ssim_rgb8(ref, NULL, w, h, &s_more) == HLOD_ERR_INVALID_ARG);
    free(ref);
    free(shift);
    free(noise);
    free(inv);
}

/* ---------- luminance change ---------- */

static void luma_change(void)
{
    uint8_t a[6] = {0, 0, 0, 50, 50, 50}, b[6] = {10, 20, 30, 50, 50, 50};
    double v = -1;
    /* pixel 0: 0.299 * 10 + 0.587 * 20 + 0.114 * 30 = 18.15; pixel 1: 0 */
    CHECK(hlod_luma_change_rgb8(a, b, 2, 1, &v) == HLOD_OK && fabs(v - 18.15 / 2) < 1e-12);
    CHECK(hlod_luma_change_rgb8(b, a, 1, 2, &v) == HLOD_OK && fabs(v - 18.15 / 2) < 1e-12);
    CHECK(hlod_luma_change_rgb8(a, a, 2, 1, &v) == HLOD_OK && v == 0);
    uint8_t w[3] = {255, 255, 255}, k[3] = {0, 0, 0};
    CHECK(hlod_luma_change_rgb8(w, k, 1, 1, &v) == HLOD_OK && fabs(v - 255) < 1e-9);
    CHECK(hlod_luma_change_rgb8(w, k, 1, 0, &v) == HLOD_ERR_INVALID_ARG);
}

/* ---------- statistics ---------- */

static void percentiles_hand_values(void)
{
    /* Sorted: 15 20 35 40 50; rank x = p / 100 * 4. */
    const double v[] = {40, NAN, 15, 50, 35, 20};
    const double p[] = {0, 25, 40, 50, 95, 99, 100, -1, 101};
    const double want[] = {15, 20, 29, 35, 48, 49.6, 50};
    double out[9];
    CHECK(hlod_stats_percentiles(v, 6, p, 9, out) == HLOD_OK);
    for (int i = 0; i < 7; i++)
        CHECKF(fabs(out[i] - want[i]) < 1e-12, "p%g = %.17g", p[i], out[i]);
    CHECK(isnan(out[7]) && isnan(out[8]));

    double one = 7, r;
    CHECK(hlod_stats_percentiles(&one, 1, p + 4, 1, &r) == HLOD_OK && r == 7);
    const double nans[2] = {NAN, NAN};
    CHECK(hlod_stats_percentiles(nans, 2, p + 4, 1, &r) == HLOD_OK && isnan(r));
    CHECK(hlod_stats_percentiles(NULL, 0, p + 4, 1, &r) == HLOD_OK && isnan(r));
    CHECK(hlod_stats_percentiles(NULL, 3, p, 1, &r) == HLOD_ERR_INVALID_ARG);

    /* p95 of 1..100 (type 7): rank 94.05 -> 95.05 */
    double h[100];
    for (int i = 0; i < 100; i++)
        h[99 - i] = i + 1;
    double s[100];
    memcpy(s, h, sizeof s);
    CHECK(hlod_stats_sort(s, 100) == 100 && s[0] == 1 && s[99] == 100);
    CHECK(fabs(hlod_stats_percentile_sorted(s, 100, 95) - 95.05) < 1e-12);
    CHECK(fabs(hlod_stats_percentile_sorted(s, 100, 50) - 50.5) < 1e-12);
    CHECK(hlod_stats_percentile_sorted(s, 0, 50) != hlod_stats_percentile_sorted(s, 0, 50));
}

static void mean_min_max(void)
{
    const double v[] = {3, NAN, -1, 10};
    CHECK(hlod_stats_mean(v, 4) == 4);
    CHECK(hlod_stats_min(v, 4) == -1 && hlod_stats_max(v, 4) == 10);
    CHECK(isnan(hlod_stats_mean(v + 1, 1)) && isnan(hlod_stats_min(NULL, 0)));
    CHECK(isnan(hlod_stats_max(v, 0)));
}

static void moving_average(void)
{
    const double v[] = {1, 2, 3, 4, 5, 6};
    const double want[] = {1, 1.5, 2, 3, 4, 5};
    double out[6];
    CHECK(hlod_stats_moving_average(v, 6, 3, out) == HLOD_OK);
    for (int i = 0; i < 6; i++)
        CHECKF(fabs(out[i] - want[i]) < 1e-15, "%d: %g", i, out[i]);
    const double g[] = {1, NAN, 3, 4, NAN, NAN};
    CHECK(hlod_stats_moving_average(g, 6, 2, out) == HLOD_OK);
    CHECK(out[0] == 1 && out[1] == 1 && out[2] == 3 && out[3] == 3.5 && out[4] == 4);
    CHECK(isnan(out[5]));
    CHECK(hlod_stats_moving_average(v, 6, 1, out) == HLOD_OK && !memcmp(out, v, sizeof v));
    CHECK(hlod_stats_moving_average(v, 6, 0, out) == HLOD_ERR_INVALID_ARG);

    /* A long sequence with a 35-frame window against direct sums. */
    enum { N = 2000, WIN = 35 };
    double *x = malloc(N * sizeof *x), *y = malloc(N * sizeof *y);
    uint64_t s = 3;
    for (int i = 0; i < N; i++)
        x[i] = (double)(lcg(&s) % 1000) / 7.0 - 50;
    CHECK(hlod_stats_moving_average(x, N, WIN, y) == HLOD_OK);
    double worst = 0;
    for (int i = 0; i < N; i++) {
        double sum = 0;
        int k = 0;
        for (int j = i - WIN + 1 < 0 ? 0 : i - WIN + 1; j <= i; j++, k++)
            sum += x[j];
        worst = fmax(worst, fabs(y[i] - sum / k));
    }
    CHECKF(worst < 1e-12, "%g", worst);
    free(x);
    free(y);
}

int main(void)
{
    RUN(psnr_hand_values);
    RUN(ssim_identical_is_one);
    RUN(ssim_constant_images_hand_value);
    RUN(ssim_matches_direct_windows);
    RUN(ssim_symmetric_and_ordered);
    RUN(luma_change);
    RUN(percentiles_hand_values);
    RUN(mean_min_max);
    RUN(moving_average);
    return check_done();
}
