/*
 * PLY reader (ascii, binary_little_endian, binary_big_endian), positions in
 * double whatever the file's property type.
 *
 * The header is parsed into elements and properties; the body is walked
 * element by element in file order, decoding only the properties we keep
 * (x y z, nx ny nz, s t / u v / texture_u texture_v, and the face index list)
 * and stepping over everything else, lists included.  Header counts are
 * checked against the bytes left in the file before anything is allocated,
 * so a hostile header cannot ask for gigabytes; every read is bounds-checked
 * so a truncated body is an error, never an overrun.
 */
#include "io_internal.h"

#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

typedef enum ptype { T_NONE, T_I8, T_U8, T_I16, T_U16, T_I32, T_U32, T_F32, T_F64 } ptype;

static const struct {
    const char *name;
    ptype t;
} type_names[] = {
    {"char", T_I8},    {"int8", T_I8},     {"uchar", T_U8},   {"uint8", T_U8},
    {"short", T_I16},  {"int16", T_I16},   {"ushort", T_U16}, {"uint16", T_U16},
    {"int", T_I32},    {"int32", T_I32},   {"uint", T_U32},   {"uint32", T_U32},
    {"float", T_F32},  {"float32", T_F32}, {"double", T_F64}, {"float64", T_F64},
};
static const int type_size[] = {0, 1, 1, 2, 2, 4, 4, 4, 8};

enum role { R_NONE, R_X, R_Y, R_Z, R_NX, R_NY, R_NZ, R_U, R_V, R_INDICES };

typedef struct prop {
    ptype type;       /* item type for lists */
    ptype count_type; /* T_NONE for scalars */
    enum role role;
} prop;

typedef struct element {
    char *name;
    unsigned long long count;
    io_vec props; /* prop */
    size_t header_line;
} element;

enum fmt { F_ASCII, F_LE, F_BE };

typedef struct ply_reader {
    const char *path;
    const hlod_logger *lg;
    io_stream s;
    enum fmt fmt;
    io_vec elems; /* element */
    char *tok_line; /* ascii: rest of the current line */
    io_vec indices; /* uint32_t, 3 per triangle */
    unsigned long long faces_seen;
} ply_reader;

static hlod_result fail(ply_reader *r, hlod_result res, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static hlod_result fail(ply_reader *r, hlod_result res, const char *fmt, ...)
{
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    hlod_logf(r->lg, HLOD_LOG_ERROR, "%s: %s", r->path, msg);
    return res;
}

static ptype parse_type(const char *s)
{
    for (size_t i = 0; i < sizeof type_names / sizeof type_names[0]; i++)
        if (strcmp(s, type_names[i].name) == 0)
            return type_names[i].t;
    return T_NONE;
}

static enum role vertex_role(const char *n)
{
    static const struct {
        const char *name;
        enum role role;
    } roles[] = {{"x", R_X},          {"y", R_Y},          {"z", R_Z},         {"nx", R_NX},
                 {"ny", R_NY},        {"nz", R_NZ},        {"s", R_U},         {"t", R_V},
                 {"u", R_U},          {"v", R_V},          {"texture_u", R_U}, {"texture_v", R_V},
                 {"texture_s", R_U},  {"texture_t", R_V}};
    for (size_t i = 0; i < sizeof roles / sizeof roles[0]; i++)
        if (strcmp(n, roles[i].name) == 0)
            return roles[i].role;
    return R_NONE;
}

/* Splits the next blank-separated word off *p (NUL-terminating it). */
static char *word(char **p)
{
    char *s = *p;
    while (*s == ' ' || *s == '\t')
        s++;
    if (!*s)
        return NULL;
    char *e = s;
    while (*e && *e != ' ' && *e != '\t')
        e++;
    if (*e)
        *e++ = '\0';
    *p = e;
    return s;
}

static hlod_result parse_header(ply_reader *r)
{
    char *line;
    if (!io_line(&r->s, &line, NULL) || strcmp(line, "ply") != 0)
        return r->s.error ? HLOD_ERR_IO : fail(r, HLOD_ERR_FORMAT, "line 1: not a PLY file");
    int have_format = 0;
    while (io_line(&r->s, &line, NULL)) {
        char *p = line;
        char *kw = word(&p);
        size_t ln = r->s.line;
        if (!kw || strcmp(kw, "comment") == 0 || strcmp(kw, "obj_info") == 0)
            continue;
        if (strcmp(kw, "end_header") == 0) {
            if (!have_format)
                return fail(r, HLOD_ERR_FORMAT, "line %zu: end_header before format", ln);
            return HLOD_OK;
        }
        if (strcmp(kw, "format") == 0) {
            char *f = word(&p);
            if (!f)
                return fail(r, HLOD_ERR_FORMAT, "line %zu: format without a name", ln);
            if (strcmp(f, "ascii") == 0)
                r->fmt = F_ASCII;
            else if (strcmp(f, "binary_little_endian") == 0)
                r->fmt = F_LE;
            else if (strcmp(f, "binary_big_endian") == 0)
                r->fmt = F_BE;
            else
                return fail(r, HLOD_ERR_FORMAT, "line %zu: unknown format '%s'", ln, f);
            have_format = 1;
        } else if (strcmp(kw, "element") == 0) {
            char *name = word(&p), *cnt = word(&p);
            const char *q = cnt;
            long long c;
            if (!name || !cnt || !io_parse_long(&q, &c) || c < 0 || *q)
                return fail(r, HLOD_ERR_FORMAT, "line %zu: element needs a name and a count", ln);
            element *e = io_vec_push(&r->elems, sizeof(element), 1);
            if (!e)
                return HLOD_ERR_NOMEM;
            memset(e, 0, sizeof *e);
            e->count = (unsigned long long)c;
            e->header_line = ln;
            if (!(e->name = io_strdup(name)))
                return HLOD_ERR_NOMEM;
        } else if (strcmp(kw, "property") == 0) {
            if (!r->elems.count)
                return fail(r, HLOD_ERR_FORMAT, "line %zu: property before any element", ln);
            element *e = (element *)r->elems.data + r->elems.count - 1;
            prop pr = {T_NONE, T_NONE, R_NONE};
            char *t = word(&p);
            if (t && strcmp(t, "list") == 0) {
                char *ct = word(&p);
                pr.count_type = ct ? parse_type(ct) : T_NONE;
                if (pr.count_type == T_NONE || pr.count_type == T_F32 || pr.count_type == T_F64)
                    return fail(r, HLOD_ERR_FORMAT, "line %zu: bad list count type '%s'", ln,
                                ct ? ct : "");
                t = word(&p);
            }
            pr.type = t ? parse_type(t) : T_NONE;
            char *name = word(&p);
            if (pr.type == T_NONE || !name)
                return fail(r, HLOD_ERR_FORMAT, "line %zu: bad property (type '%s')", ln,
                            t ? t : "");
            if (strcmp(e->name, "vertex") == 0) {
                pr.role = vertex_role(name);
                if (pr.role != R_NONE && pr.count_type != T_NONE)
                    return fail(r, HLOD_ERR_FORMAT, "line %zu: vertex property %s is a list", ln,
                                name);
            } else if (strcmp(e->name, "face") == 0 &&
                       (strcmp(name, "vertex_indices") == 0 || strcmp(name, "vertex_index") == 0)) {
                if (pr.count_type == T_NONE)
                    return fail(r, HLOD_ERR_FORMAT, "line %zu: %s is not a list", ln, name);
                if (pr.type == T_F32 || pr.type == T_F64)
                    return fail(r, HLOD_ERR_FORMAT, "line %zu: %s holds floats", ln, name);
                pr.role = R_INDICES;
            }
            prop *d = io_vec_push(&e->props, sizeof(prop), 1);
            if (!d)
                return HLOD_ERR_NOMEM;
            *d = pr;
        } else {
            /* Blender 2.4x wrote a bare text line here (assimp's Wuson.ply);
             * nothing in it changes how the body reads. */
            hlod_logf(r->lg, HLOD_LOG_WARN, "%s: line %zu: unknown header line '%s' ignored",
                      r->path, ln, kw);
        }
    }
    return r->s.error ? HLOD_ERR_IO : fail(r, HLOD_ERR_FORMAT, "header has no end_header");
}

static double decode(const uint8_t *p, ptype t, int big)
{
    int n = type_size[t];
    uint64_t v = 0;
    if (big)
        for (int i = 0; i < n; i++)
            v = v << 8 | p[i];
    else
        for (int i = n - 1; i >= 0; i--)
            v = v << 8 | p[i];
    switch (t) {
    case T_I8: return (int8_t)(uint8_t)v;
    case T_U8: return (uint8_t)v;
    case T_I16: return (int16_t)(uint16_t)v;
    case T_U16: return (uint16_t)v;
    case T_I32: return (int32_t)(uint32_t)v;
    case T_U32: return (uint32_t)v;
    case T_F32: {
        uint32_t b = (uint32_t)v;
        float f;
        memcpy(&f, &b, sizeof f);
        return f;
    }
    case T_F64: {
        double d;
        memcpy(&d, &v, sizeof d);
        return d;
    }
    default: return 0;
    }
}

/* ascii: next value, crossing line ends.  Returns 0 at end of file or when
 * the word is not a number (then *bad is set). */
static int next_value(ply_reader *r, double *out, int *bad)
{
    for (;;) {
        if (r->tok_line) {
            const char *q = r->tok_line;
            char c = io_skip_blanks(&q);
            if (c && c != '#') {
                if (!io_parse_double(&q, out)) {
                    *bad = 1;
                    return 0;
                }
                r->tok_line = (char *)q;
                return 1;
            }
        }
        if (!io_line(&r->s, &r->tok_line, NULL)) {
            r->tok_line = NULL;
            return 0;
        }
    }
}

/* Reads one value of property-type t; on failure logs and returns non-OK. */
static hlod_result get_value(ply_reader *r, ptype t, double *out, const element *e,
                             unsigned long long k)
{
    if (r->fmt == F_ASCII) {
        int bad = 0;
        if (next_value(r, out, &bad))
            return HLOD_OK;
        if (r->s.error)
            return HLOD_ERR_IO;
        if (bad)
            return fail(r, HLOD_ERR_FORMAT, "line %zu: %s %llu: bad number", r->s.line, e->name,
                        k);
        return fail(r, HLOD_ERR_FORMAT, "unexpected end of file in %s %llu of %llu", e->name, k,
                    e->count);
    }
    const uint8_t *p = io_bytes(&r->s, (size_t)type_size[t]);
    if (!p)
        return r->s.error ? HLOD_ERR_IO
                          : fail(r, HLOD_ERR_FORMAT, "file truncated in %s %llu of %llu", e->name,
                                 k, e->count);
    *out = decode(p, t, r->fmt == F_BE);
    return HLOD_OK;
}

static hlod_result get_count(ply_reader *r, ptype t, unsigned long long *n, const element *e,
                             unsigned long long k)
{
    double d;
    hlod_result res = get_value(r, t, &d, e, k);
    if (res)
        return res;
    if (!(d >= 0 && d <= 1e9) || d != floor(d))
        return fail(r, HLOD_ERR_FORMAT, "%s %llu: bad list length %g", e->name, k, d);
    *n = (unsigned long long)d;
    return HLOD_OK;
}

/* Smallest number of bytes one instance of e can take: the size check that
 * keeps a lying header from allocating more than the file could hold. */
static unsigned long long min_size(const ply_reader *r, const element *e)
{
    unsigned long long n = 0;
    const prop *ps = e->props.data;
    for (size_t i = 0; i < e->props.count; i++)
        n += r->fmt == F_ASCII ? 2
                               : (unsigned long long)type_size[ps[i].count_type != T_NONE
                                                                   ? ps[i].count_type
                                                                   : ps[i].type];
    return n;
}

static hlod_result read_vertices(ply_reader *r, const element *e, hlod_mesh *m, int has_n,
                                 int has_uv)
{
    const prop *ps = e->props.data;
    for (unsigned long long k = 0; k < e->count; k++) {
        double vals[R_INDICES] = {0};
        for (size_t i = 0; i < e->props.count; i++) {
            hlod_result res;
            if (ps[i].count_type != T_NONE) {
                unsigned long long n;
                double dummy;
                if ((res = get_count(r, ps[i].count_type, &n, e, k)))
                    return res;
                for (unsigned long long j = 0; j < n; j++)
                    if ((res = get_value(r, ps[i].type, &dummy, e, k)))
                        return res;
                continue;
            }
            double v;
            if ((res = get_value(r, ps[i].type, &v, e, k)))
                return res;
            vals[ps[i].role] = v;
        }
        for (int c = 0; c < 3; c++)
            if (!isfinite(vals[R_X + c]))
                return fail(r, HLOD_ERR_NAN, "vertex %llu: coordinate is %s", k,
                            isnan(vals[R_X + c]) ? "NaN" : "infinite");
        memcpy(m->positions + 3 * k, &vals[R_X], 3 * sizeof(double));
        if (has_n)
            for (int c = 0; c < 3; c++)
                m->normals[3 * k + c] = (float)vals[R_NX + c];
        if (has_uv) {
            m->uvs[2 * k] = (float)vals[R_U];
            m->uvs[2 * k + 1] = (float)vals[R_V];
        }
    }
    return HLOD_OK;
}

static hlod_result read_faces(ply_reader *r, const element *e, size_t nverts)
{
    const prop *ps = e->props.data;
    io_vec poly = {0};
    hlod_result res = HLOD_OK;
    for (unsigned long long k = 0; k < e->count && res == HLOD_OK; k++) {
        for (size_t i = 0; i < e->props.count && res == HLOD_OK; i++) {
            double v;
            if (ps[i].count_type == T_NONE) {
                res = get_value(r, ps[i].type, &v, e, k);
                continue;
            }
            unsigned long long n;
            if ((res = get_count(r, ps[i].count_type, &n, e, k)))
                break;
            if (ps[i].role != R_INDICES) {
                for (unsigned long long j = 0; j < n && res == HLOD_OK; j++)
                    res = get_value(r, ps[i].type, &v, e, k);
                continue;
            }
            if (n < 3) {
                res = fail(r, HLOD_ERR_FORMAT, "face %llu has %llu vertices, needs at least 3", k,
                           n);
                break;
            }
            poly.count = 0;
            uint32_t *pi = io_vec_push(&poly, sizeof(uint32_t), (size_t)n);
            if (!pi) {
                res = HLOD_ERR_NOMEM;
                break;
            }
            for (unsigned long long j = 0; j < n && res == HLOD_OK; j++) {
                if ((res = get_value(r, ps[i].type, &v, e, k)))
                    break;
                if (!(v >= 0 && v < (double)nverts) || v != floor(v))
                    res = fail(r, HLOD_ERR_INDEX_RANGE,
                               "face %llu: vertex index %.0f out of range (%zu vertices)", k, v,
                               nverts);
                else
                    pi[j] = (uint32_t)v;
            }
            if (res)
                break;
            uint32_t *t = io_vec_push(&r->indices, sizeof(uint32_t), 3 * (size_t)(n - 2));
            if (!t) {
                res = HLOD_ERR_NOMEM;
                break;
            }
            for (size_t j = 1; j + 1 < n; j++) {
                *t++ = pi[0];
                *t++ = pi[j];
                *t++ = pi[j + 1];
            }
        }
    }
    io_vec_free(&poly);
    return res;
}

static hlod_result skip_element(ply_reader *r, const element *e)
{
    const prop *ps = e->props.data;
    int fixed = r->fmt != F_ASCII;
    for (size_t i = 0; i < e->props.count; i++)
        fixed &= ps[i].count_type == T_NONE;
    if (fixed) {
        /* Step over the whole element in bounded strides. */
        unsigned long long bytes = min_size(r, e) * e->count;
        while (bytes) {
            size_t step = bytes > (1u << 20) ? (1u << 20) : (size_t)bytes;
            if (!io_bytes(&r->s, step))
                return r->s.error ? HLOD_ERR_IO
                                  : fail(r, HLOD_ERR_FORMAT, "file truncated in element %s",
                                         e->name);
            bytes -= step;
        }
        return HLOD_OK;
    }
    for (unsigned long long k = 0; k < e->count; k++)
        for (size_t i = 0; i < e->props.count; i++) {
            double v;
            hlod_result res;
            if (ps[i].count_type == T_NONE) {
                if ((res = get_value(r, ps[i].type, &v, e, k)))
                    return res;
                continue;
            }
            unsigned long long n;
            if ((res = get_count(r, ps[i].count_type, &n, e, k)))
                return res;
            for (unsigned long long j = 0; j < n; j++)
                if ((res = get_value(r, ps[i].type, &v, e, k)))
                    return res;
        }
    return HLOD_OK;
}

static hlod_result read_body(ply_reader *r, hlod_mesh *m)
{
    element *es = r->elems.data;
    element *ve = NULL, *fe = NULL;
    for (size_t i = 0; i < r->elems.count; i++) {
        if (!ve && strcmp(es[i].name, "vertex") == 0)
            ve = &es[i];
        else if (!fe && strcmp(es[i].name, "face") == 0)
            fe = &es[i];
    }
    if (!ve)
        return fail(r, HLOD_ERR_FORMAT, "no vertex element");
    int has[R_INDICES + 1] = {0};
    const prop *vp = ve->props.data;
    for (size_t i = 0; i < ve->props.count; i++)
        has[vp[i].role] = 1;
    if (!has[R_X] || !has[R_Y] || !has[R_Z])
        return fail(r, HLOD_ERR_FORMAT, "line %zu: vertex element lacks x, y or z",
                    ve->header_line);
    int has_idx = 0;
    if (fe) {
        const prop *fp = fe->props.data;
        for (size_t i = 0; i < fe->props.count; i++)
            has_idx |= fp[i].role == R_INDICES;
    }
    if (!fe || !fe->count || !has_idx || !ve->count)
        return fail(r, HLOD_ERR_EMPTY, "no faces (%llu vertices)", ve->count);
    if (ve->count >= UINT32_MAX)
        return fail(r, HLOD_ERR_UNSUPPORTED, "%llu vertices exceed 32-bit indices", ve->count);
    uint64_t left = io_remaining(&r->s);
    for (size_t i = 0; i < r->elems.count; i++) {
        unsigned long long ms = min_size(r, &es[i]);
        if (r->s.file_size && ms && es[i].count > left / ms)
            return fail(r, HLOD_ERR_FORMAT,
                        "line %zu: header promises %llu %s elements but only %llu bytes follow",
                        es[i].header_line, es[i].count, es[i].name, (unsigned long long)left);
    }

    int has_n = has[R_NX] && has[R_NY] && has[R_NZ], has_uv = has[R_U] && has[R_V];
    hlod_result res = hlod_mesh_alloc(m, (size_t)ve->count, 0,
                                      (has_n ? HLOD_MESH_NORMALS : 0u) |
                                          (has_uv ? HLOD_MESH_UVS : 0u));
    if (res)
        return res;
    for (size_t i = 0; i < r->elems.count && res == HLOD_OK; i++) {
        if (&es[i] == ve)
            res = read_vertices(r, ve, m, has_n, has_uv);
        else if (&es[i] == fe)
            res = read_faces(r, fe, (size_t)ve->count);
        else
            res = skip_element(r, &es[i]);
    }
    if (res)
        return res;
    if (r->fmt != F_ASCII && io_remaining(&r->s))
        hlod_logf(r->lg, HLOD_LOG_WARN, "%s: %llu bytes after the last element ignored", r->path,
                  (unsigned long long)io_remaining(&r->s));
    if (r->indices.count == 0)
        return fail(r, HLOD_ERR_EMPTY, "no faces");
    free(m->indices);
    m->tri_count = r->indices.count / 3;
    m->indices = io_vec_take(&r->indices, sizeof(uint32_t));
    return m->indices ? HLOD_OK : HLOD_ERR_NOMEM;
}

hlod_result io_read_ply(const char *path, const hlod_logger *lg, hlod_mesh *out,
                        hlod_import_stats *st)
{
    ply_reader r;
    memset(&r, 0, sizeof r);
    r.path = path;
    r.lg = lg;
    hlod_mesh_free(out);
    hlod_result res = io_open(&r.s, path, lg);
    if (res)
        return res;
    res = parse_header(&r);
    if (res == HLOD_OK)
        res = read_body(&r, out);
    res = io_finish_file_mesh(path, lg, res, out, st);
    io_close(&r.s);
    element *es = r.elems.data;
    for (size_t i = 0; i < r.elems.count; i++) {
        free(es[i].name);
        io_vec_free(&es[i].props);
    }
    io_vec_free(&r.elems);
    io_vec_free(&r.indices);
    return res;
}
