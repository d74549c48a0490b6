/*
 * lumigraph_repo.c - the Grid-Lumigraph's sampling repository (lumigraph.h):
 * the index, the view codec (JPEG through libturbojpeg, depth as 16-bit
 * logarithmic codes in a zstd frame), the grid's geometry, and reading a
 * file from a folder or over HTTP (libcurl).  Okamoto et al., section 4.3.
 */
#include "hlod/lumigraph.h"

#include "atomic_file.h"

#include <curl/curl.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <turbojpeg.h>
#include <zstd.h>
#define XXH_INLINE_ALL
#include <xxhash.h>

#define BAD(code, ...)                                   \
    do {                                                 \
        hlod_logf(lg, HLOD_LOG_ERROR, __VA_ARGS__);      \
        return code;                                     \
    } while (0)

static void put32(uint8_t *p, uint32_t v) { memcpy(p, &v, 4); }
static void put64(uint8_t *p, uint64_t v) { memcpy(p, &v, 8); }
static void putd(uint8_t *p, double v) { memcpy(p, &v, 8); }
static uint32_t get32(const uint8_t *p) { uint32_t v; memcpy(&v, p, 4); return v; }
static uint64_t get64(const uint8_t *p) { uint64_t v; memcpy(&v, p, 8); return v; }
static double getd(const uint8_t *p) { double v; memcpy(&v, p, 8); return v; }

/* ---- geometry ---- */

void hlod_lumi_face(uint32_t d, double forward[3], double up[3], double right[3])
{
    /* +x -x +y -y look with z up; +z -z with y up */
    static const double f[6][3] = {{1, 0, 0}, {-1, 0, 0}, {0, 1, 0}, {0, -1, 0}, {0, 0, 1}, {0, 0, -1}};
    static const double u[6][3] = {{0, 0, 1}, {0, 0, 1}, {0, 0, 1}, {0, 0, 1}, {0, 1, 0}, {0, 1, 0}};
    d %= HLOD_LUMI_FACES;
    for (int k = 0; k < 3; k++) {
        forward[k] = f[d][k];
        up[k] = u[d][k];
    }
    right[0] = f[d][1] * u[d][2] - f[d][2] * u[d][1];
    right[1] = f[d][2] * u[d][0] - f[d][0] * u[d][2];
    right[2] = f[d][0] * u[d][1] - f[d][1] * u[d][0];
}

void hlod_lumi_point(const hlod_lumi_index *ix, uint32_t x, uint32_t y, uint32_t z, double out[3])
{
    const uint32_t c[3] = {x, y, z};
    double g = (double)(ix->grid - 1);
    for (int k = 0; k < 3; k++)
        out[k] = ix->box_min[k] + (ix->box_max[k] - ix->box_min[k]) * (double)c[k] / g;
}

void hlod_lumi_view_key(const hlod_lumi_index *ix, uint32_t id, uint32_t *x, uint32_t *y,
                        uint32_t *z, uint32_t *d)
{
    uint32_t g = ix->grid, p = id / HLOD_LUMI_FACES;
    *d = id % HLOD_LUMI_FACES;
    *x = p % g;
    *y = p / g % g;
    *z = p / g / g;
}

void hlod_lumi_corners(const hlod_lumi_index *ix, const double p[3], uint32_t point[8],
                       double weight[8])
{
    uint32_t lo[3];
    double t[3];
    for (int k = 0; k < 3; k++) {
        double ext = ix->box_max[k] - ix->box_min[k];
        double u = ext > 0 ? (p[k] - ix->box_min[k]) / ext * (double)(ix->grid - 1) : 0;
        if (!(u > 0))
            u = 0; /* NaN too */
        if (u > (double)(ix->grid - 1))
            u = (double)(ix->grid - 1);
        uint32_t i = (uint32_t)u;
        if (i >= ix->grid - 1)
            i = ix->grid - 2;
        lo[k] = i;
        t[k] = u - (double)i;
    }
    for (int c = 0; c < 8; c++) {
        uint32_t q[3];
        double w = 1;
        for (int k = 0; k < 3; k++) {
            int hi = c >> k & 1;
            q[k] = lo[k] + (uint32_t)hi;
            w *= hi ? t[k] : 1 - t[k];
        }
        point[c] = (q[2] * ix->grid + q[1]) * ix->grid + q[0];
        weight[c] = w;
    }
}

uint16_t hlod_lumi_depth_quant(double z, double near_plane, double far_plane)
{
    if (!(z > near_plane))
        return 0;
    if (!(z < far_plane))
        return HLOD_LUMI_DEPTH_NONE - 1;
    double u = log(z / near_plane) / log(far_plane / near_plane);
    return (uint16_t)lround(u * (HLOD_LUMI_DEPTH_NONE - 1));
}

double hlod_lumi_depth_value(uint16_t q, double near_plane, double far_plane)
{
    if (q == HLOD_LUMI_DEPTH_NONE)
        return INFINITY;
    return near_plane * exp((double)q / (HLOD_LUMI_DEPTH_NONE - 1) * log(far_plane / near_plane));
}

/* ---- index ---- */

static int shape_ok(uint32_t grid, uint32_t size, uint32_t depth_size, uint32_t quality,
                    const double *bmin, const double *bmax, double near_plane, double far_plane)
{
    if (grid < 2 || grid > HLOD_LUMI_GRID_MAX || size < 8 || size > HLOD_LUMI_SIZE_MAX ||
        depth_size < 1 || depth_size > size || size % depth_size || quality < 1 || quality > 100)
        return 0;
    for (int k = 0; k < 3; k++)
        if (!isfinite(bmin[k]) || !isfinite(bmax[k]) || !(bmax[k] >= bmin[k]))
            return 0;
    return near_plane > 0 && isfinite(far_plane) && far_plane > near_plane &&
           far_plane / near_plane < 1e9;
}

hlod_result hlod_lumi_index_init(hlod_lumi_index *ix, uint32_t grid, uint32_t size,
                                 uint32_t depth_size, uint32_t quality, const double box_min[3],
                                 const double box_max[3], double near_plane, double far_plane,
                                 uint64_t store_id)
{
    memset(ix, 0, sizeof *ix);
    if (!shape_ok(grid, size, depth_size, quality, box_min, box_max, near_plane, far_plane))
        return HLOD_ERR_INVALID_ARG;
    ix->grid = grid;
    ix->size = size;
    ix->depth_size = depth_size;
    ix->quality = quality;
    memcpy(ix->box_min, box_min, sizeof ix->box_min);
    memcpy(ix->box_max, box_max, sizeof ix->box_max);
    ix->near_plane = near_plane;
    ix->far_plane = far_plane;
    ix->store_id = store_id;
    ix->views = grid * grid * grid * HLOD_LUMI_FACES;
    ix->state = calloc(ix->views, 1);
    return ix->state ? HLOD_OK : HLOD_ERR_NOMEM;
}

void hlod_lumi_index_free(hlod_lumi_index *ix)
{
    if (ix) {
        free(ix->state);
        ix->state = NULL;
    }
}

/* Layout (little-endian):
 *   0 "HLGR"   4 version   8 grid  12 size  16 depth_size  20 quality
 *  24 box_min[3]  48 box_max[3]  72 near  80 far  88 store_id
 *  96 views  100 0  104 XXH3-64 of [0, 104) and the states  112 states */
hlod_result hlod_lumi_index_encode(const hlod_lumi_index *ix, uint8_t **out, size_t *n)
{
    size_t total = HLOD_LUMI_INDEX_HEAD + ix->views;
    uint8_t *b = calloc(total, 1);
    if (!b)
        return HLOD_ERR_NOMEM;
    memcpy(b, "HLGR", 4);
    put32(b + 4, HLOD_LUMI_VERSION);
    put32(b + 8, ix->grid);
    put32(b + 12, ix->size);
    put32(b + 16, ix->depth_size);
    put32(b + 20, ix->quality);
    for (int k = 0; k < 3; k++) {
        putd(b + 24 + 8 * k, ix->box_min[k]);
        putd(b + 48 + 8 * k, ix->box_max[k]);
    }
    putd(b + 72, ix->near_plane);
    putd(b + 80, ix->far_plane);
    put64(b + 88, ix->store_id);
    put32(b + 96, ix->views);
    memcpy(b + HLOD_LUMI_INDEX_HEAD, ix->state, ix->views);
    XXH3_state_t st;
    XXH3_64bits_reset(&st);
    XXH3_64bits_update(&st, b, 104);
    XXH3_64bits_update(&st, b + HLOD_LUMI_INDEX_HEAD, ix->views);
    put64(b + 104, XXH3_64bits_digest(&st));
    *out = b;
    *n = total;
    return HLOD_OK;
}

hlod_result hlod_lumi_index_decode(const uint8_t *b, size_t n, const char *name,
                                   const hlod_logger *lg, hlod_lumi_index *out)
{
    memset(out, 0, sizeof *out);
    if (n < HLOD_LUMI_INDEX_HEAD || memcmp(b, "HLGR", 4))
        BAD(HLOD_ERR_FORMAT, "%s: not a Grid-Lumigraph index (%zu bytes, no HLGR header)", name, n);
    if (get32(b + 4) != HLOD_LUMI_VERSION)
        BAD(HLOD_ERR_VERSION, "%s: index version %u, this build reads %u", name, get32(b + 4),
            HLOD_LUMI_VERSION);
    double bmin[3], bmax[3];
    for (int k = 0; k < 3; k++) {
        bmin[k] = getd(b + 24 + 8 * k);
        bmax[k] = getd(b + 48 + 8 * k);
    }
    uint32_t grid = get32(b + 8);
    if (!shape_ok(grid, get32(b + 12), get32(b + 16), get32(b + 20), bmin, bmax, getd(b + 72),
                  getd(b + 80)))
        BAD(HLOD_ERR_FORMAT, "%s: impossible shape (grid %u, size %u, depth size %u, quality %u, "
            "or a bad box or clip planes)", name, grid, get32(b + 12), get32(b + 16), get32(b + 20));
    uint32_t views = grid * grid * grid * HLOD_LUMI_FACES;
    if (get32(b + 100) != 0)
        BAD(HLOD_ERR_FORMAT, "%s: reserved field is %u, not 0", name, get32(b + 100));
    if (get32(b + 96) != views || n != HLOD_LUMI_INDEX_HEAD + (size_t)views)
        BAD(HLOD_ERR_FORMAT, "%s: %zu bytes for %u views; a grid of %u needs %u views, %zu bytes",
            name, n, get32(b + 96), grid, views, HLOD_LUMI_INDEX_HEAD + (size_t)views);
    XXH3_state_t st;
    XXH3_64bits_reset(&st);
    XXH3_64bits_update(&st, b, 104);
    XXH3_64bits_update(&st, b + HLOD_LUMI_INDEX_HEAD, views);
    if (XXH3_64bits_digest(&st) != get64(b + 104))
        BAD(HLOD_ERR_CHECKSUM, "%s: index checksum mismatch (damaged or truncated)", name);
    for (uint32_t i = 0; i < views; i++)
        if (b[HLOD_LUMI_INDEX_HEAD + i] > HLOD_LUMI_BAKED)
            BAD(HLOD_ERR_FORMAT, "%s: view %u has unknown state %u", name, i,
                b[HLOD_LUMI_INDEX_HEAD + i]);
    hlod_result r = hlod_lumi_index_init(out, grid, get32(b + 12), get32(b + 16), get32(b + 20),
                                         bmin, bmax, getd(b + 72), getd(b + 80), get64(b + 88));
    if (r != HLOD_OK)
        BAD(r, "%s: out of memory for the index", name);
    memcpy(out->state, b + HLOD_LUMI_INDEX_HEAD, views);
    return HLOD_OK;
}

hlod_result hlod_lumi_index_load(const char *repo, const hlod_logger *lg, hlod_lumi_index *out)
{
    uint8_t *buf;
    size_t n;
    memset(out, 0, sizeof *out);
    size_t max = HLOD_LUMI_INDEX_HEAD + (size_t)HLOD_LUMI_GRID_MAX * HLOD_LUMI_GRID_MAX *
                                            HLOD_LUMI_GRID_MAX * HLOD_LUMI_FACES;
    hlod_result r = hlod_lumi_fetch(repo, HLOD_LUMI_INDEX_NAME, max, lg, &buf, &n);
    if (r != HLOD_OK)
        return r;
    char name[4096];
    snprintf(name, sizeof name, "%s/%s", repo, HLOD_LUMI_INDEX_NAME);
    r = hlod_lumi_index_decode(buf, n, name, lg, out);
    free(buf);
    return r;
}

hlod_result hlod_lumi_index_save(const char *repo, const hlod_lumi_index *ix,
                                 const hlod_logger *lg)
{
    uint8_t *buf;
    size_t n;
    hlod_result r = hlod_lumi_index_encode(ix, &buf, &n);
    if (r != HLOD_OK)
        return r;
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", repo, HLOD_LUMI_INDEX_NAME);
    hlod_atomic_file af;
    r = hlod_atomic_open(&af, path, lg);
    if (r == HLOD_OK) {
        if (fwrite(buf, 1, n, af.fp) != n) {
            hlod_atomic_abort(&af);
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: write failed: %s", path, strerror(errno));
            r = HLOD_ERR_IO;
        } else {
            r = hlod_atomic_commit(&af, lg);
        }
    }
    free(buf);
    return r;
}

/* ---- views ---- */

void hlod_lumi_view_path(const hlod_lumi_index *ix, uint32_t id, char *out, size_t cap)
{
    uint32_t x, y, z, d;
    hlod_lumi_view_key(ix, id, &x, &y, &z, &d);
    snprintf(out, cap, "views/%u/%u_%u_%u.hlv", x, y, z, d);
}

/* Layout: 0 "HLGV"  4 version  8 x  12 y  16 z  20 d  24 size  28 depth_size
 *        32 jpeg_bytes  36 depth_bytes  40 XXH3-64 of [48, end)
 *        48 the JPEG, then a zstd frame of depth_size^2 little-endian u16. */
hlod_result hlod_lumi_view_encode(const hlod_lumi_index *ix, uint32_t id, const uint8_t *rgb,
                                  const uint16_t *depth, uint8_t **out, size_t *n)
{
    *out = NULL;
    *n = 0;
    tjhandle tj = tjInitCompress();
    if (!tj)
        return HLOD_ERR_NOMEM;
    unsigned char *jpeg = NULL;
    unsigned long jbytes = 0;
    int bad = tjCompress2(tj, rgb, (int)ix->size, 0, (int)ix->size, TJPF_RGB, &jpeg, &jbytes,
                          TJSAMP_420, (int)ix->quality, TJFLAG_ACCURATEDCT);
    tjDestroy(tj);
    if (bad) {
        tjFree(jpeg);
        return HLOD_ERR_FORMAT;
    }
    size_t draw = (size_t)ix->depth_size * ix->depth_size * 2;
    size_t dcap = ZSTD_compressBound(draw);
    uint8_t *b = malloc(HLOD_LUMI_VIEW_HEAD + jbytes + dcap);
    if (!b) {
        tjFree(jpeg);
        return HLOD_ERR_NOMEM;
    }
    memcpy(b + HLOD_LUMI_VIEW_HEAD, jpeg, jbytes);
    tjFree(jpeg);
    size_t dbytes = ZSTD_compress(b + HLOD_LUMI_VIEW_HEAD + jbytes, dcap, depth, draw, 9);
    if (ZSTD_isError(dbytes)) {
        free(b);
        return HLOD_ERR_NOMEM;
    }
    uint32_t x, y, z, d;
    hlod_lumi_view_key(ix, id, &x, &y, &z, &d);
    memcpy(b, "HLGV", 4);
    put32(b + 4, HLOD_LUMI_VERSION);
    put32(b + 8, x);
    put32(b + 12, y);
    put32(b + 16, z);
    put32(b + 20, d);
    put32(b + 24, ix->size);
    put32(b + 28, ix->depth_size);
    put32(b + 32, (uint32_t)jbytes);
    put32(b + 36, (uint32_t)dbytes);
    size_t total = HLOD_LUMI_VIEW_HEAD + jbytes + dbytes;
    put64(b + 40, XXH3_64bits(b + HLOD_LUMI_VIEW_HEAD, total - HLOD_LUMI_VIEW_HEAD));
    *out = b;
    *n = total;
    return HLOD_OK;
}

void hlod_lumi_view_free(hlod_lumi_view *v)
{
    if (v) {
        free(v->rgb);
        free(v->depth);
        v->rgb = NULL;
        v->depth = NULL;
    }
}

static hlod_result decode_jpeg(const uint8_t *jpeg, size_t n, uint32_t size, uint8_t *rgb)
{
    tjhandle tj = tjInitDecompress();
    if (!tj)
        return HLOD_ERR_NOMEM;
    int w = 0, h = 0, sub = 0, cs = 0;
    int bad = tjDecompressHeader3(tj, jpeg, (unsigned long)n, &w, &h, &sub, &cs) != 0 ||
              w != (int)size || h != (int)size ||
              tjDecompress2(tj, jpeg, (unsigned long)n, rgb, (int)size, 0, (int)size, TJPF_RGB,
                            TJFLAG_ACCURATEDCT) != 0;
    tjDestroy(tj);
    return bad ? HLOD_ERR_FORMAT : HLOD_OK;
}

hlod_result hlod_lumi_view_decode(const hlod_lumi_index *ix, uint32_t id, const uint8_t *b,
                                  size_t n, const char *name, const hlod_logger *lg,
                                  hlod_lumi_view *out)
{
    memset(out, 0, sizeof *out);
    if (n < HLOD_LUMI_VIEW_HEAD || memcmp(b, "HLGV", 4))
        BAD(HLOD_ERR_FORMAT, "%s: not a Grid-Lumigraph view (%zu bytes, no HLGV header)", name, n);
    if (get32(b + 4) != HLOD_LUMI_VERSION)
        BAD(HLOD_ERR_VERSION, "%s: view version %u, this build reads %u", name, get32(b + 4),
            HLOD_LUMI_VERSION);
    uint32_t x, y, z, d;
    hlod_lumi_view_key(ix, id, &x, &y, &z, &d);
    if (get32(b + 8) != x || get32(b + 12) != y || get32(b + 16) != z || get32(b + 20) != d)
        BAD(HLOD_ERR_FORMAT, "%s: holds view (%u, %u, %u, %u), not the (%u, %u, %u, %u) asked for",
            name, get32(b + 8), get32(b + 12), get32(b + 16), get32(b + 20), x, y, z, d);
    if (get32(b + 24) != ix->size || get32(b + 28) != ix->depth_size)
        BAD(HLOD_ERR_FORMAT, "%s: images of %u and %u pixels, the index says %u and %u", name,
            get32(b + 24), get32(b + 28), ix->size, ix->depth_size);
    uint64_t jb = get32(b + 32), db = get32(b + 36);
    if (HLOD_LUMI_VIEW_HEAD + jb + db != n)
        BAD(HLOD_ERR_FORMAT, "%s: %zu bytes, its header says %llu", name, n,
            (unsigned long long)(HLOD_LUMI_VIEW_HEAD + jb + db));
    if (XXH3_64bits(b + HLOD_LUMI_VIEW_HEAD, n - HLOD_LUMI_VIEW_HEAD) != get64(b + 40))
        BAD(HLOD_ERR_CHECKSUM, "%s: view checksum mismatch (damaged)", name);
    size_t npix = (size_t)ix->size * ix->size;
    size_t dn = (size_t)ix->depth_size * ix->depth_size;
    out->rgb = malloc(npix * 3);
    out->depth = malloc(dn * 2);
    if (!out->rgb || !out->depth) {
        hlod_lumi_view_free(out);
        BAD(HLOD_ERR_NOMEM, "%s: out of memory", name);
    }
    if (decode_jpeg(b + HLOD_LUMI_VIEW_HEAD, jb, ix->size, out->rgb) != HLOD_OK) {
        hlod_lumi_view_free(out);
        BAD(HLOD_ERR_FORMAT, "%s: its JPEG does not decode to %ux%u RGB", name, ix->size, ix->size);
    }
    const uint8_t *zf = b + HLOD_LUMI_VIEW_HEAD + jb;
    unsigned long long content = ZSTD_getFrameContentSize(zf, db);
    size_t got = content == dn * 2 ? ZSTD_decompress(out->depth, dn * 2, zf, db) : 0;
    if (content != dn * 2 || ZSTD_isError(got) || got != dn * 2) {
        hlod_lumi_view_free(out);
        BAD(HLOD_ERR_FORMAT, "%s: its depth is not one zstd frame of %zu bytes", name, dn * 2);
    }
    out->id = id;
    out->size = ix->size;
    out->depth_size = ix->depth_size;
    return HLOD_OK;
}

/* ---- fetching ---- */

typedef struct sink {
    uint8_t *buf;
    size_t n, cap, max;
    int over;
} sink;

static size_t on_body(char *data, size_t size, size_t nmemb, void *user)
{
    sink *s = user;
    size_t add = size * nmemb;
    if (s->n + add > s->max) {
        s->over = 1;
        return 0;
    }
    if (s->n + add > s->cap) {
        size_t cap = s->cap ? s->cap : 65536;
        while (cap < s->n + add)
            cap *= 2;
        uint8_t *nb = realloc(s->buf, cap);
        if (!nb)
            return 0;
        s->buf = nb;
        s->cap = cap;
    }
    memcpy(s->buf + s->n, data, add);
    s->n += add;
    return add;
}

typedef struct cancel_cb {
    int (*fn)(void *);
    void *user;
} cancel_cb;

static int on_progress(void *user, curl_off_t dt, curl_off_t dn, curl_off_t ut, curl_off_t un)
{
    (void)dt, (void)dn, (void)ut, (void)un;
    const cancel_cb *c = user;
    return c->fn && c->fn(c->user); /* non-zero aborts the transfer */
}

static hlod_result fetch_url(const char *url, size_t max_bytes, const hlod_logger *lg,
                             const cancel_cb *cancel, uint8_t **out, size_t *n)
{
    /* the HTTP reader's test hook (store_http.h): a latency before each
     * request */
    const char *lat = getenv("HLOD_HTTP_LATENCY_MS");
    double ms = lat ? atof(lat) : 0;
    if (ms > 0 && ms < 1e5) {
        struct timespec ts = {(time_t)(ms / 1000), (long)(fmod(ms, 1000) * 1e6)};
        nanosleep(&ts, NULL);
    }
    CURL *e = curl_easy_init();
    if (!e)
        BAD(HLOD_ERR_NOMEM, "%s: cannot start libcurl", url);
    sink s = {.max = max_bytes};
    char err[CURL_ERROR_SIZE] = "";
    curl_easy_setopt(e, CURLOPT_URL, url);
    curl_easy_setopt(e, CURLOPT_NOSIGNAL, 1L);
    curl_easy_setopt(e, CURLOPT_WRITEFUNCTION, on_body);
    curl_easy_setopt(e, CURLOPT_WRITEDATA, &s);
    curl_easy_setopt(e, CURLOPT_ERRORBUFFER, err);
    curl_easy_setopt(e, CURLOPT_CONNECTTIMEOUT_MS, 5000L);
    curl_easy_setopt(e, CURLOPT_TIMEOUT_MS, 30000L);
    if (cancel->fn) {
        curl_easy_setopt(e, CURLOPT_XFERINFOFUNCTION, on_progress);
        curl_easy_setopt(e, CURLOPT_XFERINFODATA, (void *)cancel);
        curl_easy_setopt(e, CURLOPT_NOPROGRESS, 0L);
    }
    const char *ca = getenv("CURL_CA_BUNDLE"); /* as the store reader */
    if (!ca || !*ca)
        ca = getenv("SSL_CERT_FILE");
    if (ca && *ca)
        curl_easy_setopt(e, CURLOPT_CAINFO, ca);
    CURLcode c = curl_easy_perform(e);
    long code = 0;
    curl_easy_getinfo(e, CURLINFO_RESPONSE_CODE, &code);
    curl_easy_cleanup(e);
    if (s.over) {
        free(s.buf);
        BAD(HLOD_ERR_FORMAT, "%s: longer than %zu bytes", url, max_bytes);
    }
    if (c == CURLE_ABORTED_BY_CALLBACK) { /* the caller cancelled it: nothing to say */
        free(s.buf);
        return HLOD_ERR_CANCELLED;
    }
    if (c != CURLE_OK || code != 200) {
        free(s.buf);
        if (c != CURLE_OK)
            BAD(HLOD_ERR_IO, "%s: %s", url, err[0] ? err : curl_easy_strerror(c));
        BAD(HLOD_ERR_IO, "%s: HTTP status %ld", url, code);
    }
    *out = s.buf ? s.buf : malloc(1);
    *n = s.n;
    return *out ? HLOD_OK : HLOD_ERR_NOMEM;
}

static hlod_result fetch_file(const char *path, size_t max_bytes, const hlod_logger *lg,
                              uint8_t **out, size_t *n)
{
    FILE *fp = fopen(path, "rb");
    if (!fp)
        BAD(HLOD_ERR_IO, "%s: %s", path, strerror(errno));
    sink s = {.max = max_bytes};
    char chunk[65536];
    size_t got;
    while ((got = fread(chunk, 1, sizeof chunk, fp)) > 0)
        if (on_body(chunk, 1, got, &s) != got)
            break;
    int err = ferror(fp);
    fclose(fp);
    if (s.over) {
        free(s.buf);
        BAD(HLOD_ERR_FORMAT, "%s: longer than %zu bytes", path, max_bytes);
    }
    if (err || got) {
        free(s.buf);
        BAD(HLOD_ERR_IO, "%s: read failed", path);
    }
    *out = s.buf ? s.buf : malloc(1);
    *n = s.n;
    return *out ? HLOD_OK : HLOD_ERR_NOMEM;
}

hlod_result hlod_lumi_fetch(const char *repo, const char *rel, size_t max_bytes,
                            const hlod_logger *lg, uint8_t **out, size_t *n)
{
    return hlod_lumi_fetch_cancel(repo, rel, max_bytes, NULL, NULL, lg, out, n);
}

hlod_result hlod_lumi_fetch_cancel(const char *repo, const char *rel, size_t max_bytes,
                                   int (*cancel)(void *), void *user, const hlod_logger *lg,
                                   uint8_t **out, size_t *n)
{
    const cancel_cb cb = {cancel, user};
    char name[4096];
    size_t len = strlen(repo);
    int slash = len && repo[len - 1] == '/';
    if (snprintf(name, sizeof name, "%s%s%s", repo, slash ? "" : "/", rel) >= (int)sizeof name)
        BAD(HLOD_ERR_INVALID_ARG, "%s: name too long", repo);
    *out = NULL;
    *n = 0;
    if (!strncmp(repo, "http://", 7) || !strncmp(repo, "https://", 8))
        return fetch_url(name, max_bytes, lg, &cb, out, n);
    return fetch_file(name, max_bytes, lg, out, n);
}

/* ---- the answer protocol ---- */

uint32_t hlod_lumi_candidates(const hlod_lumi_index *ix, const double eye[3], const double dir[3],
                              uint32_t out[HLOD_LUMI_CANDIDATES],
                              uint32_t slot[HLOD_LUMI_CANDIDATES])
{
    uint32_t point[8];
    double w[8];
    hlod_lumi_corners(ix, eye, point, w);
    int order[8];
    for (int c = 0; c < 8; c++)
        order[c] = c;
    for (int a = 1; a < 8; a++) /* insertion sort, weight down (stable) */
        for (int b = a; b > 0 && w[order[b]] > w[order[b - 1]]; b--) {
            int t = order[b];
            order[b] = order[b - 1];
            order[b - 1] = t;
        }
    uint32_t n = 0;
    for (int pass = 0; pass < 2; pass++)
        for (int k = 0; k < 8; k++) {
            int c = order[k], first = 1;
            for (int q = 0; q < k; q++)
                first &= point[order[q]] != point[c];
            if (!first)
                continue; /* a corner repeated where the eye is clamped to the box */
            for (uint32_t d = 0; d < HLOD_LUMI_FACES; d++) {
                double f[3], u[3], r[3];
                hlod_lumi_face(d, f, u, r);
                int ahead = f[0] * dir[0] + f[1] * dir[1] + f[2] * dir[2] > -0.5;
                if (ahead != (pass == 0))
                    continue;
                out[n] = point[c] * HLOD_LUMI_FACES + d;
                slot[n] = (uint32_t)c * HLOD_LUMI_FACES + d;
                n++;
            }
        }
    return n;
}

/* "a,b,c": three finite numbers, nothing after them */
static int three(const char *s, size_t len, double out[3])
{
    char buf[200];
    if (len >= sizeof buf)
        return 0;
    memcpy(buf, s, len);
    buf[len] = 0;
    char *p = buf;
    for (int k = 0; k < 3; k++) {
        if (*p == ' ' || *p == '+' || !*p)
            return 0;
        char *end;
        out[k] = strtod(p, &end);
        if (end == p || !isfinite(out[k]))
            return 0;
        p = end;
        if (k < 2 && *p++ != ',')
            return 0;
    }
    return *p == 0;
}

int hlod_lumi_request_parse(const char *q, size_t len, hlod_lumi_request *out)
{
    memset(out, 0, sizeof *out);
    if (!q || len > 512)
        return 0;
    int seen = 0; /* 1 p, 2 d, 4 have */
    size_t i = 0;
    while (i < len) {
        size_t j = i;
        while (j < len && q[j] != '&')
            j++;
        const char *kv = q + i, *eq = memchr(kv, '=', j - i);
        if (!eq)
            return 0;
        size_t kl = (size_t)(eq - kv), vl = j - i - kl - 1;
        const char *v = eq + 1;
        if (kl == 1 && kv[0] == 'p' && !(seen & 1)) {
            if (!three(v, vl, out->eye))
                return 0;
            seen |= 1;
        } else if (kl == 1 && kv[0] == 'd' && !(seen & 2)) {
            if (!three(v, vl, out->dir))
                return 0;
            double l = sqrt(out->dir[0] * out->dir[0] + out->dir[1] * out->dir[1] +
                            out->dir[2] * out->dir[2]);
            if (!(l > 0) || !isfinite(l))
                return 0;
            seen |= 2;
        } else if (kl == 4 && !memcmp(kv, "have", 4) && !(seen & 4)) {
            if (vl < 1 || vl > 12)
                return 0;
            uint64_t h = 0;
            for (size_t k = 0; k < vl; k++) {
                char c = v[k];
                int d = c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : -1;
                if (d < 0)
                    return 0;
                h = h << 4 | (uint64_t)d;
            }
            out->have = h;
            seen |= 4;
        } else {
            return 0;
        }
        i = j + 1;
        if (j + 1 == len)
            return 0; /* a trailing '&' */
    }
    return seen == 7;
}

size_t hlod_lumi_request_format(const hlod_lumi_request *q, char *out, size_t cap)
{
    int n = snprintf(out, cap, "p=%.17g,%.17g,%.17g&d=%.17g,%.17g,%.17g&have=%llx", q->eye[0],
                     q->eye[1], q->eye[2], q->dir[0], q->dir[1], q->dir[2],
                     (unsigned long long)(q->have & ((1ull << HLOD_LUMI_CANDIDATES) - 1)));
    return n > 0 && (size_t)n < cap ? (size_t)n : 0;
}
