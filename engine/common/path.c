/*
 * Camera paths: the text format, its validating parser, the Catmull-Rom
 * evaluator and the writer (see hlod/path.h).
 *
 * Design:
 * - The parser takes a length-delimited buffer and never reads past it: each
 *   line is copied into a bounded, NUL-terminated buffer first, so strtod
 *   sees a C string, and every byte the fuzzer can invent (NUL, 0xff, a
 *   missing last newline) is either a token character or a reported error.
 * - Numbers are checked against a plain decimal grammar before strtod, so
 *   hex floats, "nan", "inf" and locale tricks are refused; a token strtod
 *   reads as non-finite ("nan", "1e999") gets its own message.
 * - The evaluator forms each Hermite tangent already scaled by the segment
 *   length, h * m_i = (p[i+1] - p[i-1]) * (h / (t[i+1] - t[i-1])), where the
 *   ratio is in (0, 1]: with the format's range limits nothing can overflow,
 *   however close two keyframe times are, so no NaN ever leaves it.
 * - It evaluates p0 + h01 * (p1 - p0) + h10 * T0 + h11 * T1 (h00 = 1 - h01),
 *   which keeps full precision for a city far from the origin (x = 5e6).
 */
#include "hlod/path.h"

#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "atomic_file.h"

#define FILE_MAX ((size_t)256 << 20)

/* ---- numbers ---- */

void hlod_path_format_double(char buf[32], double v)
{
    for (int prec = 15; prec <= 17; prec++) {
        snprintf(buf, 32, "%.*g", prec, v);
        double back = strtod(buf, NULL);
        if (memcmp(&back, &v, sizeof v) == 0)
            return;
    }
}

static int is_digit(char c)
{
    return c >= '0' && c <= '9';
}

/* [+-] digits [. digits] [e [+-] digits], at least one mantissa digit. */
static int is_decimal(const char *s)
{
    int digits = 0;
    if (*s == '+' || *s == '-')
        s++;
    for (; is_digit(*s); s++)
        digits++;
    if (*s == '.')
        for (s++; is_digit(*s); s++)
            digits++;
    if (!digits)
        return 0;
    if (*s == 'e' || *s == 'E') {
        s++;
        if (*s == '+' || *s == '-')
            s++;
        if (!is_digit(*s))
            return 0;
        while (is_digit(*s))
            s++;
    }
    return *s == 0;
}

/* A token made printable and short for a message. */
static void quote_token(char out[48], const char *tok)
{
    size_t n = 0;
    for (; tok[n] && n < 32; n++) {
        unsigned char c = (unsigned char)tok[n];
        out[n] = c >= 0x20 && c < 0x7f ? (char)c : '?';
    }
    if (tok[n]) {
        memcpy(out + n, "...", 3);
        n += 3;
    }
    out[n] = 0;
}

/* ---- shared key checks ---- */

static int same_point(const double a[3], const double b[3])
{
    return a[0] == b[0] && a[1] == b[1] && a[2] == b[2];
}

/* HLOD_OK, or an error with `why` filled (no location prefix). */
static hlod_result check_key(const hlod_path_key *k, const hlod_path_key *prev, char *why,
                             size_t n)
{
    const double *v = &k->t;
    for (int i = 0; i < 7; i++) {
        char num[32];
        if (!isfinite(v[i])) {
            snprintf(why, n, "%s is not a finite number", i == 0 ? "time" : "a coordinate");
            return HLOD_ERR_NAN;
        }
        double lim = i == 0 ? HLOD_PATH_T_MAX : HLOD_PATH_COORD_MAX;
        if (fabs(v[i]) > lim) {
            hlod_path_format_double(num, v[i]);
            snprintf(why, n, "%s %s is out of range (at most %g in magnitude)",
                     i == 0 ? "time" : "coordinate", num, lim);
            return HLOD_ERR_FORMAT;
        }
    }
    if (prev && !(k->t > prev->t)) {
        char a[32], b[32];
        hlod_path_format_double(a, k->t);
        hlod_path_format_double(b, prev->t);
        snprintf(why, n, "time %s is not after the previous keyframe's time %s", a, b);
        return HLOD_ERR_FORMAT;
    }
    if (same_point(k->eye, k->at)) {
        snprintf(why, n, "eye and look-at are the same point");
        return HLOD_ERR_FORMAT;
    }
    return HLOD_OK;
}

static hlod_result reserve(hlod_path *p, size_t need)
{
    if (need <= p->capacity)
        return HLOD_OK;
    size_t cap = p->capacity ? p->capacity : 16;
    while (cap < need) {
        if (cap > SIZE_MAX / 2 / sizeof *p->keys)
            return HLOD_ERR_NOMEM;
        cap *= 2;
    }
    hlod_path_key *k = realloc(p->keys, cap * sizeof *k);
    if (!k)
        return HLOD_ERR_NOMEM;
    p->keys = k;
    p->capacity = cap;
    return HLOD_OK;
}

void hlod_path_free(hlod_path *p)
{
    if (!p)
        return;
    free(p->keys);
    memset(p, 0, sizeof *p);
}

/* ---- parsing ---- */

typedef struct parser {
    const char *name;
    const hlod_logger *lg;
} parser;

static hlod_result fail(const parser *ps, size_t line, hlod_result r, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;

static hlod_result fail(const parser *ps, size_t line, hlod_result r, const char *fmt, ...)
{
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    if (line)
        hlod_logf(ps->lg, HLOD_LOG_ERROR, "%s:%zu: %s", ps->name, line, msg);
    else
        hlod_logf(ps->lg, HLOD_LOG_ERROR, "%s: %s", ps->name, msg);
    return r;
}

static int is_space(char c)
{
    return c == ' ' || c == '\t' || c == '\r';
}

/* One line (NUL-terminated, comment not yet removed).  *got is 1 when it
 * held a keyframe, stored in *k. */
static hlod_result parse_line(const parser *ps, size_t line, char *buf, hlod_path_key *k,
                              int *got)
{
    char *hash = strchr(buf, '#');
    if (hash)
        *hash = 0;
    double *v = &k->t;
    size_t fields = 0;
    char *s = buf;
    *got = 0;
    for (;;) {
        while (is_space(*s))
            s++;
        if (!*s)
            break;
        char *tok = s;
        while (*s && !is_space(*s))
            s++;
        int more = *s != 0;
        *s = 0;
        char q[48];
        quote_token(q, tok);
        if (fields == 7)
            return fail(ps, line, HLOD_ERR_FORMAT,
                        "unexpected '%s' after the 7 numbers of a keyframe", q);
        char *end = NULL;
        double x = strtod(tok, &end);
        if (!is_decimal(tok)) {
            if (end && end != tok && *end == 0 && !isfinite(x))
                return fail(ps, line, HLOD_ERR_NAN, "'%s' is not a finite number", q);
            return fail(ps, line, HLOD_ERR_FORMAT, "'%s' is not a number", q);
        }
        if (!end || *end != 0)    /* a decimal strtod cannot read: a non-C locale */
            return fail(ps, line, HLOD_ERR_FORMAT, "'%s' is not a number", q);
        if (!isfinite(x))
            return fail(ps, line, HLOD_ERR_NAN, "'%s' is not a finite number", q);
        double lim = fields == 0 ? HLOD_PATH_T_MAX : HLOD_PATH_COORD_MAX;
        if (fabs(x) > lim)
            return fail(ps, line, HLOD_ERR_FORMAT, "%s %s is out of range (at most %g in magnitude)",
                        fields == 0 ? "time" : "coordinate", q, lim);
        v[fields++] = x;
        if (!more)
            break;
        s++;
    }
    if (fields == 0)
        return HLOD_OK;
    if (fields != 7)
        return fail(ps, line, HLOD_ERR_FORMAT,
                    "expected 7 numbers (t px py pz lx ly lz), found %zu", fields);
    *got = 1;
    return HLOD_OK;
}

hlod_result hlod_path_parse(const char *text, size_t len, const char *name,
                            const hlod_logger *lg, hlod_path *out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    hlod_path_free(out);
    if (!text && len)
        return HLOD_ERR_INVALID_ARG;
    parser ps = {name ? name : "<buffer>", lg};
    char buf[HLOD_PATH_LINE_MAX + 1];
    size_t line = 0, prev_line = 0, pos = 0;
    hlod_result r = HLOD_OK;
    while (pos < len) {
        line++;
        const char *start = text + pos;
        const char *nl = memchr(start, '\n', len - pos);
        size_t n = nl ? (size_t)(nl - start) : len - pos;
        pos += n + (nl ? 1 : 0);
        if (n > HLOD_PATH_LINE_MAX) {
            r = fail(&ps, line, HLOD_ERR_FORMAT, "line longer than %d bytes",
                     HLOD_PATH_LINE_MAX);
            goto fail;
        }
        if (memchr(start, 0, n)) {
            r = fail(&ps, line, HLOD_ERR_FORMAT, "NUL byte in the line");
            goto fail;
        }
        memcpy(buf, start, n);
        buf[n] = 0;
        hlod_path_key k;
        int got;
        if ((r = parse_line(&ps, line, buf, &k, &got)) != HLOD_OK)
            goto fail;
        if (!got)
            continue;
        char why[256];
        const hlod_path_key *prev = out->count ? &out->keys[out->count - 1] : NULL;
        if ((r = check_key(&k, prev, why, sizeof why)) != HLOD_OK) {
            if (prev && !(k.t > prev->t))
                r = fail(&ps, line, r, "%s (line %zu)", why, prev_line);
            else
                r = fail(&ps, line, r, "%s", why);
            goto fail;
        }
        if ((r = reserve(out, out->count + 1)) != HLOD_OK) {
            fail(&ps, line, r, "out of memory");
            goto fail;
        }
        out->keys[out->count++] = k;
        prev_line = line;
    }
    if (out->count == 0) {
        r = fail(&ps, 0, HLOD_ERR_FORMAT, "no keyframes (expected lines of 't px py pz lx ly lz')");
        goto fail;
    }
    return HLOD_OK;
fail:
    hlod_path_free(out);
    return r;
}

hlod_result hlod_path_load(const char *file, const hlod_logger *lg, hlod_path *out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    hlod_path_free(out);
    if (!file)
        return HLOD_ERR_INVALID_ARG;
    FILE *fp = fopen(file, "rb");
    if (!fp) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot open: %s", file, strerror(errno));
        return HLOD_ERR_IO;
    }
    char *buf = NULL;
    size_t len = 0, cap = 0;
    hlod_result r = HLOD_OK;
    for (;;) {
        if (len == cap) {
            if (cap >= FILE_MAX) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: larger than %zu MiB", file, FILE_MAX >> 20);
                r = HLOD_ERR_IO;
                break;
            }
            size_t nc = cap ? 2 * cap : 65536;
            char *nb = realloc(buf, nc);
            if (!nb) {
                r = HLOD_ERR_NOMEM;
                break;
            }
            buf = nb;
            cap = nc;
        }
        size_t got = fread(buf + len, 1, cap - len, fp);
        len += got;
        if (got == 0) {
            if (ferror(fp)) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: read failed", file);
                r = HLOD_ERR_IO;
            }
            break;
        }
    }
    fclose(fp);
    if (r == HLOD_OK)
        r = hlod_path_parse(buf, len, file, lg, out);
    free(buf);
    return r;
}

hlod_result hlod_path_validate(const hlod_path *p, const char *name, const hlod_logger *lg)
{
    if (!p)
        return HLOD_ERR_INVALID_ARG;
    name = name ? name : "<path>";
    if (p->count == 0 || !p->keys) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: no keyframes", name);
        return HLOD_ERR_FORMAT;
    }
    for (size_t i = 0; i < p->count; i++) {
        char why[256];
        hlod_result r = check_key(&p->keys[i], i ? &p->keys[i - 1] : NULL, why, sizeof why);
        if (r != HLOD_OK) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: keyframe %zu: %s", name, i, why);
            return r;
        }
    }
    return HLOD_OK;
}

hlod_result hlod_path_append(hlod_path *p, double t, const double eye[3], const double at[3])
{
    if (!p || !eye || !at)
        return HLOD_ERR_INVALID_ARG;
    hlod_path_key k = {t, {eye[0], eye[1], eye[2]}, {at[0], at[1], at[2]}};
    char why[256];
    hlod_result r = check_key(&k, p->count ? &p->keys[p->count - 1] : NULL, why, sizeof why);
    if (r != HLOD_OK)
        return r == HLOD_ERR_NAN ? r : HLOD_ERR_INVALID_ARG;
    if ((r = reserve(p, p->count + 1)) != HLOD_OK)
        return r;
    p->keys[p->count++] = k;
    return HLOD_OK;
}

/* ---- evaluation ---- */

double hlod_path_start(const hlod_path *p)
{
    assert(p && p->count > 0);
    return p->keys[0].t;
}

double hlod_path_end(const hlod_path *p)
{
    assert(p && p->count > 0);
    return p->keys[p->count - 1].t;
}

double hlod_path_duration(const hlod_path *p)
{
    return hlod_path_end(p) - hlod_path_start(p);
}

uint64_t hlod_path_frame_count(const hlod_path *p, double dt)
{
    if (!p || p->count == 0 || !isfinite(dt) || !(dt > 0))
        return 0;
    double q = hlod_path_duration(p) / dt + 1e-6;
    if (!(q < 9007199254740992.0))
        return 0;
    return (uint64_t)floor(q) + 1;
}

double hlod_path_frame_time(const hlod_path *p, double dt, uint64_t frame)
{
    return hlod_path_start(p) + (double)frame * dt;
}

/* Coordinate c (0-2 eye, 3-5 look-at) of keyframe i. */
static double coord(const hlod_path_key *k, size_t i, int c)
{
    return c < 3 ? k[i].eye[c] : k[i].at[c - 3];
}

void hlod_path_eval(const hlod_path *p, double t, double eye[3], double at[3])
{
    assert(p && p->count > 0 && eye && at);
    const hlod_path_key *k = p->keys;
    size_t n = p->count, i = 0;
    int clamped = 1;
    if (n == 1 || !(t > k[0].t)) {
        i = 0;
    } else if (t >= k[n - 1].t) {
        i = n - 1;
    } else {
        clamped = 0;
        /* Largest i with k[i].t <= t; then k[0].t < t < k[n-1].t puts it
         * in [0, n-2]. */
        size_t lo = 0, hi = n - 1;
        while (hi - lo > 1) {
            size_t mid = lo + (hi - lo) / 2;
            if (k[mid].t <= t)
                lo = mid;
            else
                hi = mid;
        }
        i = lo;
    }
    if (clamped || t == k[i].t) {
        memcpy(eye, k[i].eye, sizeof k[i].eye);
        memcpy(at, k[i].at, sizeof k[i].at);
        return;
    }
    double h = k[i + 1].t - k[i].t;
    double s = (t - k[i].t) / h;
    double s2 = s * s, s3 = s2 * s;
    double h01 = 3 * s2 - 2 * s3, h10 = s3 - 2 * s2 + s, h11 = s3 - s2;
    /* Catmull-Rom tangents over time, pre-multiplied by h (see the top). */
    double w0 = i > 0 ? h / (k[i + 1].t - k[i - 1].t) : 1.0;
    double w1 = i + 2 < n ? h / (k[i + 2].t - k[i].t) : 1.0;
    for (int c = 0; c < 6; c++) {
        double p0 = coord(k, i, c), p1 = coord(k, i + 1, c);
        double t0 = i > 0 ? (p1 - coord(k, i - 1, c)) * w0 : p1 - p0;
        double t1 = i + 2 < n ? (coord(k, i + 2, c) - p0) * w1 : p1 - p0;
        double v = p0 + h01 * (p1 - p0) + h10 * t0 + h11 * t1;
        if (c < 3)
            eye[c] = v;
        else
            at[c - 3] = v;
    }
}

/* ---- writing ---- */

typedef struct sbuf {
    char *p;
    size_t len, cap;
    int oom;
} sbuf;

static void put(sbuf *b, const char *s, size_t n)
{
    if (b->oom)
        return;
    if (b->len + n + 1 > b->cap) {
        size_t nc = b->cap ? b->cap : 4096;
        while (nc < b->len + n + 1)
            nc *= 2;
        char *np = realloc(b->p, nc);
        if (!np) {
            b->oom = 1;
            return;
        }
        b->p = np;
        b->cap = nc;
    }
    memcpy(b->p + b->len, s, n);
    b->len += n;
    b->p[b->len] = 0;
}

static void puts_(sbuf *b, const char *s)
{
    put(b, s, strlen(s));
}

hlod_result hlod_path_to_text(const hlod_path *p, const char *comment, char **text, size_t *len)
{
    if (!text)
        return HLOD_ERR_INVALID_ARG;
    *text = NULL;
    if (len)
        *len = 0;
    if (!p || p->count == 0 || !p->keys)
        return HLOD_ERR_INVALID_ARG;
    sbuf b = {0};
    for (const char *c = comment; c && *c;) {
        const char *nl = strchr(c, '\n');
        size_t n = nl ? (size_t)(nl - c) : strlen(c);
        if (n) {
            puts_(&b, "# ");
            put(&b, c, n);
            puts_(&b, "\n");
        } else {
            puts_(&b, "#\n");
        }
        c += n + (nl ? 1 : 0);
    }
    puts_(&b, "# t px py pz lx ly lz\n");
    for (size_t i = 0; i < p->count; i++) {
        const double *v = &p->keys[i].t;
        for (int j = 0; j < 7; j++) {
            char num[32];
            hlod_path_format_double(num, v[j]);
            if (j)
                puts_(&b, " ");
            puts_(&b, num);
        }
        puts_(&b, "\n");
    }
    if (b.oom) {
        free(b.p);
        return HLOD_ERR_NOMEM;
    }
    *text = b.p;
    if (len)
        *len = b.len;
    return HLOD_OK;
}

hlod_result hlod_path_write(const hlod_path *p, const char *file, const char *comment,
                            const hlod_logger *lg)
{
    if (!p || !file)
        return HLOD_ERR_INVALID_ARG;
    hlod_result r = hlod_path_validate(p, file, lg);
    if (r != HLOD_OK)
        return r;
    char *text = NULL;
    size_t len = 0;
    if ((r = hlod_path_to_text(p, comment, &text, &len)) != HLOD_OK)
        return r;
    hlod_atomic_file f;
    if ((r = hlod_atomic_open(&f, file, lg)) == HLOD_OK) {
        fwrite(text, 1, len, f.fp);   /* errors surface in commit (ferror) */
        r = hlod_atomic_commit(&f, lg);
    }
    free(text);
    return r;
}
