/*
 * OFF reader (Geomview Object File Format and its [ST][C][N]OFF variants),
 * positions in double.
 *
 * Line-oriented on purpose: a colour after a vertex or a face has three or
 * four components, so only the line end tells where a record stops.  '#'
 * starts a comment anywhere.  Polygons are fan-triangulated.  The 4OFF/nOFF
 * (higher-dimensional) and binary variants are reported as unsupported.
 */
#include "io_internal.h"

#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

typedef struct off_reader {
    const char *path;
    const hlod_logger *lg;
    io_stream s;
} off_reader;

static hlod_result fail(off_reader *r, hlod_result res, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static hlod_result fail(off_reader *r, hlod_result res, const char *fmt, ...)
{
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    hlod_logf(r->lg, HLOD_LOG_ERROR, "%s: line %zu: %s", r->path, r->s.line, msg);
    return res;
}

/* Next line holding data, comments cut off; NULL at end of file. */
static char *data_line(off_reader *r)
{
    char *line;
    size_t len;
    while (io_line(&r->s, &line, &len)) {
        char *hash = memchr(line, '#', len);
        if (hash)
            *hash = '\0';
        const char *p = line;
        if (io_skip_blanks(&p))
            return line;
    }
    return NULL;
}

enum { HAS_ST = 1, HAS_C = 2, HAS_N = 4 };

/* Returns the variant flags, -1 when kw is not an OFF keyword, -2 for a
 * variant we do not read. */
static int header_flags(const char *kw, size_t len)
{
    int f = 0;
    if (len >= 2 && kw[0] == 'S' && kw[1] == 'T')
        f |= HAS_ST, kw += 2, len -= 2;
    if (len && *kw == 'C')
        f |= HAS_C, kw++, len--;
    if (len && *kw == 'N')
        f |= HAS_N, kw++, len--;
    int exotic = 0;
    if (len && *kw == '4')
        exotic = 1, kw++, len--;
    if (len && *kw == 'n')
        exotic = 1, kw++, len--;
    if (len != 3 || strncmp(kw, "OFF", 3) != 0)
        return -1;
    return exotic ? -2 : f;
}

static hlod_result read_counts(off_reader *r, const char *p, long long c[3])
{
    int n = 0;
    while (n < 3 && io_skip_blanks(&p)) {
        if (!io_parse_long(&p, &c[n]) || c[n] < 0)
            return fail(r, HLOD_ERR_FORMAT, "bad vertex/face/edge counts");
        n++;
    }
    if (n < 2)
        return fail(r, HLOD_ERR_FORMAT, "expected vertex and face counts");
    return HLOD_OK;
}

static hlod_result read_off(off_reader *r, hlod_mesh *m)
{
    char *line = data_line(r);
    if (!line)
        return r->s.error ? HLOD_ERR_IO : fail(r, HLOD_ERR_FORMAT, "empty file, no OFF header");
    const char *p = line;
    io_skip_blanks(&p);
    const char *kw = p;
    while (*p && *p != ' ' && *p != '\t')
        p++;
    int flags = header_flags(kw, (size_t)(p - kw));
    if (flags == -1)
        return fail(r, HLOD_ERR_FORMAT, "no OFF header");
    if (flags == -2)
        return fail(r, HLOD_ERR_UNSUPPORTED, "4OFF/nOFF (not 3-D) is not supported");
    long long c[3] = {0, 0, 0};
    const char *q = p;
    io_skip_blanks(&q);
    if (strncmp(q, "BINARY", 6) == 0)
        return fail(r, HLOD_ERR_UNSUPPORTED, "binary OFF is not supported");
    hlod_result res;
    if (*q) {
        res = read_counts(r, q, c);
    } else {
        if (!(line = data_line(r)))
            return r->s.error ? HLOD_ERR_IO : fail(r, HLOD_ERR_FORMAT, "no vertex/face counts");
        res = read_counts(r, line, c);
    }
    if (res)
        return res;
    long long nv = c[0], nf = c[1];
    if (nf == 0 || nv == 0)
        return fail(r, HLOD_ERR_EMPTY, "no faces (%lld vertices, %lld faces)", nv, nf);
    if (nv >= (long long)UINT32_MAX)
        return fail(r, HLOD_ERR_UNSUPPORTED, "%lld vertices exceed 32-bit indices", nv);
    /* "0 0 0\n" and "3 0 1 2\n" are the shortest records: a header that
     * promises more than the file can hold is caught before allocating. */
    uint64_t left = io_remaining(&r->s);
    if (r->s.file_size && ((uint64_t)nv > left / 6 || (uint64_t)nf > left / 8 ||
                           (uint64_t)nv * 6 + (uint64_t)nf * 8 > left))
        return fail(r, HLOD_ERR_FORMAT,
                    "header promises %lld vertices and %lld faces but only %llu bytes follow", nv,
                    nf, (unsigned long long)left);

    int has_n = flags & HAS_N, has_uv = flags & HAS_ST;
    res = hlod_mesh_alloc(m, (size_t)nv, 0,
                          (has_n ? HLOD_MESH_NORMALS : 0u) | (has_uv ? HLOD_MESH_UVS : 0u));
    if (res)
        return res;
    int need = 3 + (has_n ? 3 : 0) + (has_uv ? 2 : 0);
    for (long long v = 0; v < nv; v++) {
        if (!(line = data_line(r)))
            return r->s.error ? HLOD_ERR_IO
                              : fail(r, HLOD_ERR_FORMAT,
                                     "unexpected end of file after %lld of %lld vertices", v, nv);
        double vals[16];
        int n = 0;
        p = line;
        while (n < 16 && io_skip_blanks(&p)) {
            if (!io_parse_double(&p, &vals[n]))
                return fail(r, HLOD_ERR_FORMAT, "vertex %lld: bad number", v);
            n++;
        }
        if (n < need)
            return fail(r, HLOD_ERR_FORMAT, "vertex %lld: expected %d numbers, found %d", v, need,
                        n);
        for (int k = 0; k < 3; k++)
            if (!(vals[k] - vals[k] == 0))
                return fail(r, HLOD_ERR_NAN, "vertex %lld: coordinate is %s", v,
                            vals[k] != vals[k] ? "NaN" : "infinite");
        memcpy(m->positions + 3 * v, vals, 3 * sizeof(double));
        if (has_n)
            for (int k = 0; k < 3; k++)
                m->normals[3 * v + k] = (float)vals[3 + k];
        if (has_uv) {
            /* ST comes last, after any colour. */
            m->uvs[2 * v] = (float)vals[n - 2];
            m->uvs[2 * v + 1] = (float)vals[n - 1];
        }
    }

    io_vec idx = {0};
    if (!io_vec_reserve(&idx, sizeof(uint32_t), 3 * (size_t)nf))
        return HLOD_ERR_NOMEM;
    res = HLOD_OK;
    for (long long f = 0; f < nf && res == HLOD_OK; f++) {
        if (!(line = data_line(r))) {
            res = r->s.error ? HLOD_ERR_IO
                             : fail(r, HLOD_ERR_FORMAT,
                                    "unexpected end of file after %lld of %lld faces", f, nf);
            break;
        }
        p = line;
        long long n;
        if (!io_parse_long(&p, &n) || n < 0) {
            res = fail(r, HLOD_ERR_FORMAT, "face %lld: bad vertex count", f);
            break;
        }
        if (n < 3) {
            res = fail(r, HLOD_ERR_FORMAT, "face %lld has %lld vertices, needs at least 3", f, n);
            break;
        }
        long long first = 0, prev = 0;
        for (long long k = 0; k < n; k++) {
            long long vi;
            if (!io_parse_long(&p, &vi) || *p == '/') {
                res = fail(r, HLOD_ERR_FORMAT, "face %lld: expected %lld vertex indices", f, n);
                break;
            }
            if (vi < 0 || vi >= nv) {
                res = fail(r, HLOD_ERR_INDEX_RANGE,
                           "face %lld: vertex index %lld out of range (%lld vertices)", f, vi, nv);
                break;
            }
            if (k >= 2) {
                uint32_t *t = io_vec_push(&idx, sizeof(uint32_t), 3);
                if (!t) {
                    res = HLOD_ERR_NOMEM;
                    break;
                }
                t[0] = (uint32_t)first;
                t[1] = (uint32_t)prev;
                t[2] = (uint32_t)vi;
            }
            if (k == 0)
                first = vi;
            prev = vi;
        }
    }
    if (res == HLOD_OK && r->s.error)
        res = HLOD_ERR_IO;
    if (res) {
        io_vec_free(&idx);
        return res;
    }
    free(m->indices);
    m->tri_count = idx.count / 3;
    m->indices = io_vec_take(&idx, sizeof(uint32_t));
    return m->indices ? HLOD_OK : HLOD_ERR_NOMEM;
}

hlod_result io_read_off(const char *path, const hlod_logger *lg, hlod_mesh *out,
                        hlod_import_stats *st)
{
    off_reader r;
    memset(&r, 0, sizeof r);
    r.path = path;
    r.lg = lg;
    hlod_mesh_free(out);
    hlod_result res = io_open(&r.s, path, lg);
    if (res)
        return res;
    res = read_off(&r, out);
    res = io_finish_file_mesh(path, lg, res, out, st);
    io_close(&r.s);
    return res;
}
