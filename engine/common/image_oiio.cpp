/*
 * image.h through OpenImageIO 2.4 (with preprocess/io/parse_double.cpp,
 * one of the two C++ files).
 *
 * Every entry point catches all exceptions, so no C++ exception ever
 * crosses into C.  Writes go to "<stem>.tmp-<pid>-<n>.<ext>" in the target's
 * folder (OpenImageIO picks the format from the extension, so the
 * temporary name keeps it), are fsync'ed and then renamed over the target,
 * as atomic_file.h does for our own files.
 */
#include "hlod/image.h"

#include <OpenImageIO/imagebuf.h>
#include <OpenImageIO/imagebufalgo.h>
#include <OpenImageIO/imageio.h>

#include <atomic>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fcntl.h>
#include <string>
#include <unistd.h>
#include <vector>

using namespace OIIO;

namespace {

std::atomic<unsigned> tmp_counter{0};

/* Distinguishes "no such file" (an I/O error with errno's text) from a file
 * OpenImageIO cannot decode (a format error). */
hlod_result open_error(const char *path, const std::string &why, const hlod_logger *lg)
{
    FILE *f = std::fopen(path, "rb");
    if (!f) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot open image: %s", path, std::strerror(errno));
        return HLOD_ERR_IO;
    }
    std::fclose(f);
    hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read image: %s", path,
              why.empty() ? "unknown format" : why.c_str());
    return HLOD_ERR_FORMAT;
}

bool size_ok(int w, int h, int c)
{
    return w > 0 && h > 0 && c >= 1 && c <= 4 && (size_t)w <= SIZE_MAX / (size_t)h / (size_t)c;
}

/* Per output column (or row) of a minification from n source texels to m
 * <= n: the first source texel and the normalised weights of the ones its
 * footprint [i n/m, (i+1) n/m) covers, by the length of the overlap. */
struct box_axis {
    std::vector<int> first, count;
    std::vector<float> weight;   /* `taps` per output texel, zero-padded */
    int taps = 0;
};

void box_weights(int n, int m, box_axis &ax)
{
    double step = (double)n / m;
    ax.taps = (int)std::ceil(step) + 1;
    ax.first.assign(m, 0);
    ax.count.assign(m, 0);
    ax.weight.assign((size_t)m * ax.taps, 0.0f);
    for (int i = 0; i < m; i++) {
        double a = i * step, b = (i + 1) * step;
        int j0 = (int)std::floor(a), j1 = (int)std::ceil(b);
        j1 = j1 > n ? n : j1;
        ax.first[i] = j0;
        ax.count[i] = j1 - j0;
        for (int j = j0; j < j1; j++) {
            double lo = j > a ? j : a, hi = j + 1 < b ? j + 1 : b;
            ax.weight[(size_t)i * ax.taps + (j - j0)] = (float)((hi - lo) / step);
        }
    }
}

/* Area-averaging minification (an exact box filter: each output texel is
 * the mean of the source area it covers, partial texels weighted by their
 * overlap), separable: each source row is filtered across once and added
 * into the one or two output rows it overlaps.  OpenImageIO's box resize
 * point-samples its filter per tap through generic iterators: 20-60 ns per
 * source texel on 8-bit RGB here, about 15% of a METIS build of the
 * default city, and off by up to 47 levels from the area mean at ratios
 * like 97 -> 40. */
template <int C> void box_minify_c(const hlod_image *src, int w, int h, uint8_t *dst)
{
    const int W = src->width, H = src->height;
    box_axis ax;
    box_weights(W, w, ax);
    const double step_y = (double)H / h;
    /* a source row overlaps at most two output rows (step_y >= 1): two
     * accumulating rows, each written out once no later source row can
     * reach it */
    std::vector<float> row((size_t)w * C), acc(2 * (size_t)w * C, 0.0f);
    int flushed = 0;
    auto flush_below = [&](int end) {
        for (; flushed < end && flushed < h; flushed++) {
            float *a = &acc[(size_t)(flushed & 1) * w * C];
            uint8_t *o = dst + (size_t)flushed * w * C;
            for (size_t i = 0; i < (size_t)w * C; i++) {
                float v = a[i] + 0.5f;
                o[i] = (uint8_t)(v < 0 ? 0 : v > 255 ? 255 : v);
                a[i] = 0;
            }
        }
    };
    for (int sy = 0; sy < H; sy++) {
        const uint8_t *in = src->pixels + (size_t)sy * W * C;
        for (int x = 0; x < w; x++) {
            const float *wx = &ax.weight[(size_t)x * ax.taps];
            const uint8_t *p = in + (size_t)ax.first[x] * C;
            /* channels in registers (a summed array went through memory) */
            float s0 = 0, s1 = 0, s2 = 0, s3 = 0;
            for (int k = 0; k < ax.count[x]; k++, p += C) {
                float wk = wx[k];
                s0 += wk * p[0];
                if constexpr (C > 1)
                    s1 += wk * p[1];
                if constexpr (C > 2)
                    s2 += wk * p[2];
                if constexpr (C > 3)
                    s3 += wk * p[3];
            }
            float *r = &row[(size_t)x * C];
            r[0] = s0;
            if constexpr (C > 1)
                r[1] = s1;
            if constexpr (C > 2)
                r[2] = s2;
            if constexpr (C > 3)
                r[3] = s3;
        }
        for (int y = (int)(sy / step_y); y < h && y * step_y < sy + 1; y++) {
            double lo = y * step_y > sy ? y * step_y : sy;
            double hi = (y + 1) * step_y < sy + 1 ? (y + 1) * step_y : sy + 1;
            float wy = (float)((hi - lo) / step_y);
            if (!(wy > 0))
                continue;
            float *out = &acc[(size_t)(y & 1) * w * C];
            for (size_t i = 0; i < (size_t)w * C; i++)
                out[i] += wy * row[i];
        }
        /* the next source row starts at output row (sy + 1) / step_y */
        flush_below(sy + 1 < H ? (int)((sy + 1) / step_y) : h);
    }
}

void box_minify(const hlod_image *src, int w, int h, uint8_t *dst)
{
    switch (src->channels) {
    case 1: box_minify_c<1>(src, w, h, dst); break;
    case 2: box_minify_c<2>(src, w, h, dst); break;
    case 3: box_minify_c<3>(src, w, h, dst); break;
    default: box_minify_c<4>(src, w, h, dst); break;
    }
}

} // namespace

extern "C" void hlod_image_free(hlod_image *img)
{
    if (!img)
        return;
    std::free(img->pixels);
    std::memset(img, 0, sizeof *img);
}

extern "C" hlod_result hlod_image_read(const char *path, hlod_image *out, const hlod_logger *lg)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    std::memset(out, 0, sizeof *out);
    if (!path)
        return HLOD_ERR_INVALID_ARG;
    try {
        /* Textures keep straight alpha as stored: by default OIIO would
         * premultiply PNG/TGA alpha on read, and rounding that in 8 bits
         * loses colour wherever alpha is low. */
        ImageSpec config;
        config.attribute("oiio:UnassociatedAlpha", 1);
        auto in = ImageInput::open(path, &config);
        if (!in)
            return open_error(path, OIIO::geterror(), lg);
        const ImageSpec &spec = in->spec();
        int w = spec.width, h = spec.height, c = spec.nchannels < 4 ? spec.nchannels : 4;
        if (!size_ok(w, h, c)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: unsupported image size %dx%d with %d channels", path,
                      w, h, spec.nchannels);
            return HLOD_ERR_UNSUPPORTED;
        }
        uint8_t *px = static_cast<uint8_t *>(std::malloc((size_t)w * h * c));
        if (!px) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory for %dx%d pixels", path, w, h);
            return HLOD_ERR_NOMEM;
        }
        if (!in->read_image(0, 0, 0, c, TypeDesc::UINT8, px)) {
            std::string why = in->geterror();
            std::free(px);
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot decode image: %s", path, why.c_str());
            return HLOD_ERR_FORMAT;
        }
        in->close();
        out->width = w;
        out->height = h;
        out->channels = c;
        out->pixels = px;
        return HLOD_OK;
    } catch (const std::exception &e) {
        hlod_image_free(out);
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read image: %s", path, e.what());
        return HLOD_ERR_FORMAT;
    } catch (...) {
        hlod_image_free(out);
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read image: unknown exception", path);
        return HLOD_ERR_FORMAT;
    }
}

extern "C" hlod_result hlod_image_probe(const char *path, int *width, int *height, int *channels,
                                        const hlod_logger *lg)
{
    if (!path)
        return HLOD_ERR_INVALID_ARG;
    try {
        auto in = ImageInput::open(path);
        if (!in)
            return open_error(path, OIIO::geterror(), lg);
        const ImageSpec &spec = in->spec();
        if (width)
            *width = spec.width;
        if (height)
            *height = spec.height;
        if (channels)
            *channels = spec.nchannels < 4 ? spec.nchannels : 4;
        in->close();
        return HLOD_OK;
    } catch (const std::exception &e) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read image header: %s", path, e.what());
        return HLOD_ERR_FORMAT;
    } catch (...) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read image header: unknown exception", path);
        return HLOD_ERR_FORMAT;
    }
}

extern "C" hlod_result hlod_image_write(const char *path, const hlod_image *img,
                                        const hlod_logger *lg)
{
    if (!path || !img || !img->pixels || !size_ok(img->width, img->height, img->channels))
        return HLOD_ERR_INVALID_ARG;
    std::string tmp;
    try {
        std::string p(path);
        size_t slash = p.rfind('/');
        size_t dot = p.rfind('.');
        if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: no extension to choose an image format by", path);
            return HLOD_ERR_UNSUPPORTED;
        }
        tmp = p.substr(0, dot) + ".tmp-" + std::to_string((long)getpid()) + "-" +
              std::to_string(tmp_counter++) + p.substr(dot);
        auto out = ImageOutput::create(tmp);
        if (!out) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: no image writer for this extension: %s", path,
                      OIIO::geterror().c_str());
            return HLOD_ERR_UNSUPPORTED;
        }
        ImageSpec spec(img->width, img->height, img->channels, TypeDesc::UINT8);
        spec.attribute("oiio:UnassociatedAlpha", 1); /* pixels hold straight alpha */
        /* zlib's fastest level: PNG encoding was 40% of generating the
         * default city at the default level 6, for files about 10% smaller */
        spec.attribute("png:compressionLevel", 1);
        if (!out->open(tmp, spec)) {
            std::string why = out->geterror();
            unlink(tmp.c_str());
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create image: %s", path, why.c_str());
            return HLOD_ERR_IO;
        }
        bool ok = out->write_image(TypeDesc::UINT8, img->pixels);
        std::string why = ok ? std::string() : out->geterror();
        ok = out->close() && ok;
        if (ok) {
            int fd = open(tmp.c_str(), O_RDONLY);
            ok = fd >= 0 && fsync(fd) == 0;
            if (fd >= 0)
                close(fd);
            if (!ok)
                why = std::strerror(errno);
        }
        if (ok && rename(tmp.c_str(), path) != 0) {
            ok = false;
            why = std::strerror(errno);
        }
        if (!ok) {
            unlink(tmp.c_str());
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write image: %s", path,
                      why.empty() ? "write failed" : why.c_str());
            return HLOD_ERR_IO;
        }
        return HLOD_OK;
    } catch (const std::exception &e) {
        if (!tmp.empty())
            unlink(tmp.c_str());
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write image: %s", path, e.what());
        return HLOD_ERR_IO;
    } catch (...) {
        if (!tmp.empty())
            unlink(tmp.c_str());
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write image: unknown exception", path);
        return HLOD_ERR_IO;
    }
}

extern "C" hlod_result hlod_image_resize(const hlod_image *src, int width, int height,
                                         hlod_image *out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    std::memset(out, 0, sizeof *out);
    if (!src || !src->pixels || !size_ok(src->width, src->height, src->channels) ||
        !size_ok(width, height, src->channels))
        return HLOD_ERR_INVALID_ARG;
    try {
        if (width <= src->width && height <= src->height) {
            size_t n = (size_t)width * height * src->channels;
            uint8_t *px = static_cast<uint8_t *>(std::malloc(n));
            if (!px)
                return HLOD_ERR_NOMEM;
            try {
                box_minify(src, width, height, px);
            } catch (...) {
                std::free(px);
                throw;
            }
            *out = hlod_image{width, height, src->channels, px};
            return HLOD_OK;
        }
        ImageSpec sspec(src->width, src->height, src->channels, TypeDesc::UINT8);
        /* ImageBuf wraps the caller's pixels without copying; it only reads. */
        ImageBuf in(sspec, const_cast<uint8_t *>(src->pixels));
        ImageSpec dspec(width, height, src->channels, TypeDesc::UINT8);
        ImageBuf dst(dspec);
        /* One thread: the callers (hierarchy builders) choose their own
         * parallelism and should not be oversubscribed by OIIO's pool. */
        /* a box filter: the builders shrink textures by large factors, where
         * it is several times faster than the default lanczos and just as
         * good for minification */
        if (!ImageBufAlgo::resize(dst, in, "box", 0.0f, ROI(), 1))
            return HLOD_ERR_INVALID_ARG;
        size_t n = (size_t)width * height * src->channels;
        uint8_t *px = static_cast<uint8_t *>(std::malloc(n));
        if (!px)
            return HLOD_ERR_NOMEM;
        if (!dst.get_pixels(ROI(0, width, 0, height, 0, 1, 0, src->channels), TypeDesc::UINT8,
                            px)) {
            std::free(px);
            return HLOD_ERR_INVALID_ARG;
        }
        out->width = width;
        out->height = height;
        out->channels = src->channels;
        out->pixels = px;
        return HLOD_OK;
    } catch (const std::bad_alloc &) {
        hlod_image_free(out);
        return HLOD_ERR_NOMEM;
    } catch (...) {
        hlod_image_free(out);
        return HLOD_ERR_INVALID_ARG;
    }
}
