/* Chunked file reading, exact number parsing, growable arrays, a string map
 * and path helpers shared by the readers and writers (see io_internal.h). */
#include "io_internal.h"

#include <assert.h>
#include <errno.h>
#include <limits.h>
#include <locale.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* Large enough that fread's per-call cost vanishes, small enough to stay in
 * L2/L3 while the parser walks it. */
#define IO_CHUNK ((size_t)1 << 20)

hlod_result io_open(io_stream *s, const char *path, const hlod_logger *lg)
{
    memset(s, 0, sizeof *s);
    s->path = path;
    s->lg = lg;
    s->fp = fopen(path, "rb");
    if (!s->fp) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot open: %s", path, strerror(errno));
        return HLOD_ERR_IO;
    }
    struct stat st;
    if (fstat(fileno(s->fp), &st) == 0) {
        if (S_ISDIR(st.st_mode)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read: %s", path, strerror(EISDIR));
            io_close(s);
            return HLOD_ERR_IO;
        }
        if (S_ISREG(st.st_mode))
            s->file_size = (uint64_t)st.st_size;
    }
    s->cap = IO_CHUNK;
    s->buf = malloc(s->cap + 1);
    if (!s->buf) {
        io_close(s);
        return HLOD_ERR_NOMEM;
    }
    return HLOD_OK;
}

void io_close(io_stream *s)
{
    if (s->fp)
        fclose(s->fp);
    free(s->buf);
    s->fp = NULL;
    s->buf = NULL;
}

/* Makes at least `need` unconsumed bytes available unless the file ends
 * first; returns the number available. */
static size_t fill(io_stream *s, size_t need)
{
    if (s->pos > 0) {
        memmove(s->buf, s->buf + s->pos, s->end - s->pos);
        s->end -= s->pos;
        s->pos = 0;
    }
    if (need > s->cap) {
        size_t ncap = s->cap * 2 > need ? s->cap * 2 : need;
        char *nb = realloc(s->buf, ncap + 1);
        if (!nb) {
            s->error = 1;
            hlod_logf(s->lg, HLOD_LOG_ERROR, "%s: out of memory for a %zu-byte record", s->path,
                      need);
            return s->end;
        }
        s->buf = nb;
        s->cap = ncap;
    }
    while (s->end < need && !s->eof) {
        size_t n = fread(s->buf + s->end, 1, s->cap - s->end, s->fp);
        s->end += n;
        s->consumed += n;
        if (n == 0) {
            if (ferror(s->fp)) {
                s->error = 1;
                hlod_logf(s->lg, HLOD_LOG_ERROR, "%s: read error: %s", s->path, strerror(errno));
            }
            s->eof = 1;
        }
    }
    return s->end;
}

/* s->consumed counts bytes read from the file; the unconsumed tail of the
 * buffer is subtracted to get the logical position. */
static uint64_t total_read_(const io_stream *s)
{
    return s->consumed - (s->end - s->pos);
}

uint64_t io_remaining(const io_stream *s)
{
    uint64_t at = total_read_(s);
    return s->file_size > at ? s->file_size - at : 0;
}

int io_line(io_stream *s, char **line, size_t *len)
{
    for (;;) {
        char *start = s->buf + s->pos;
        size_t avail = s->end - s->pos;
        char *nl = avail ? memchr(start, '\n', avail) : NULL;
        if (nl || (s->eof && avail)) {
            size_t n = nl ? (size_t)(nl - start) : avail;
            s->pos += nl ? n + 1 : n;
            start[n] = '\0'; /* the buffer has one spare byte past cap */
            if (n && start[n - 1] == '\r')
                start[--n] = '\0';
            s->line++;
            *line = start;
            if (len)
                *len = n;
            return 1;
        }
        if (s->eof || s->error)
            return 0;
        fill(s, avail + 1);
        if (s->error)
            return 0;
    }
}

const uint8_t *io_bytes(io_stream *s, size_t n)
{
    if (s->end - s->pos < n) {
        if (s->error || fill(s, n) < n)
            return NULL;
    }
    const uint8_t *p = (const uint8_t *)s->buf + s->pos;
    s->pos += n;
    return p;
}

/* ---- numbers ---- */

static int is_end(char c)
{
    return c == '\0' || c == ' ' || c == '\t' || c == '\r' || c == '\n';
}

/* fast_float's from_chars (parse_double.cpp) on [start, end): rounds
 * correctly, reads nan/inf, never looks at the locale.  What it refuses
 * (a leading '+' it does not take, hex floats) goes to strtod on a copy,
 * with '.' swapped for the locale's decimal point, so a program that
 * called setlocale() still reads "1.5" as 1.5. */
static int parse_double_slow(const char *start, const char **pp, double *out)
{
    const char *end = start;
    while (!is_end(*end))
        end++;
    size_t n = (size_t)(end - start);
    if (n == 0)
        return 0;
    const char *first = start + (start[0] == '+' && n > 1 && start[1] != '-' && start[1] != '+');
    if (io_from_chars(first, end, out)) {
        *pp = end;
        return 1;
    }
    char tmp[512];
    if (n >= sizeof tmp)
        return 0;
    const char *dp = localeconv()->decimal_point;
    char point = (dp && dp[0] && !dp[1]) ? dp[0] : '.';
    for (size_t i = 0; i < n; i++)
        tmp[i] = start[i] == '.' ? point : start[i];
    tmp[n] = '\0';
    char *e;
    errno = 0;
    double v = strtod(tmp, &e);
    if (e != tmp + n)
        return 0;
    /* ERANGE underflow gives a correctly rounded denormal or zero, and
     * overflow gives inf, which the reader reports as a non-finite value. */
    *out = v;
    *pp = end;
    return 1;
}

int io_parse_double(const char **pp, double *out)
{
    static const double pow10[] = {1e0,  1e1,  1e2,  1e3,  1e4,  1e5,  1e6,  1e7,
                                   1e8,  1e9,  1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
                                   1e16, 1e17, 1e18, 1e19, 1e20, 1e21, 1e22};
    const char *p = *pp;
    io_skip_blanks(&p);
    const char *start = p;
    int neg = 0;
    if (*p == '-' || *p == '+')
        neg = *p++ == '-';
    uint64_t w = 0;
    int nd = 0, inexact = 0, any = 0;
    long exp10 = 0;
    while (*p == '0') {
        p++;
        any = 1;
    }
    for (; *p >= '0' && *p <= '9'; p++, any = 1) {
        if (nd < 19) {
            w = w * 10 + (uint64_t)(*p - '0');
            nd++;
        } else {
            exp10++;
            inexact = 1;
        }
    }
    if (*p == '.') {
        p++;
        if (nd == 0)
            for (; *p == '0'; p++, any = 1)
                exp10--;
        for (; *p >= '0' && *p <= '9'; p++, any = 1) {
            if (nd < 19) {
                w = w * 10 + (uint64_t)(*p - '0');
                nd++;
                exp10--;
            } else {
                inexact = 1;
            }
        }
    }
    if (!any)
        return parse_double_slow(start, pp, out);
    if (*p == 'e' || *p == 'E') {
        const char *q = p + 1;
        int eneg = 0;
        if (*q == '-' || *q == '+')
            eneg = *q++ == '-';
        if (*q < '0' || *q > '9')
            return 0;
        long e = 0;
        for (; *q >= '0' && *q <= '9'; q++)
            if (e < 100000)
                e = e * 10 + (*q - '0');
        exp10 += eneg ? -e : e;
        p = q;
    }
    if (!is_end(*p))
        return parse_double_slow(start, pp, out);
    /* Clinger's fast path: w and 10^|e| are both exact doubles, so one
     * correctly rounded multiply or divide gives the correctly rounded
     * result. */
    if (!inexact && w <= ((uint64_t)1 << 53) && exp10 >= -22 && exp10 <= 22) {
        double d = (double)w;
        d = exp10 < 0 ? d / pow10[-exp10] : d * pow10[exp10];
        *out = neg ? -d : d;
        *pp = p;
        return 1;
    }
    return parse_double_slow(start, pp, out);
}

int io_parse_long(const char **pp, long long *out)
{
    const char *p = *pp;
    io_skip_blanks(&p);
    int neg = 0;
    if (*p == '-' || *p == '+')
        neg = *p++ == '-';
    if (*p < '0' || *p > '9')
        return 0;
    unsigned long long v = 0;
    for (; *p >= '0' && *p <= '9'; p++) {
        if (v > (unsigned long long)LLONG_MAX / 10)
            return 0;
        v = v * 10 + (unsigned)(*p - '0');
    }
    if (v > (unsigned long long)LLONG_MAX)
        return 0;
    if (!is_end(*p) && *p != '/')
        return 0;
    *out = neg ? -(long long)v : (long long)v;
    *pp = p;
    return 1;
}

/* ---- growable arrays ---- */

int io_vec_reserve(io_vec *v, size_t elem_size, size_t total)
{
    if (total <= v->cap)
        return 1;
    size_t ncap = v->cap ? v->cap : 64;
    while (ncap < total) {
        if (ncap > SIZE_MAX / 2 / elem_size)
            return 0;
        ncap *= 2;
    }
    void *nd = realloc(v->data, ncap * elem_size);
    if (!nd)
        return 0;
    v->data = nd;
    v->cap = ncap;
    return 1;
}

void *io_vec_push(io_vec *v, size_t elem_size, size_t n)
{
    if (n > SIZE_MAX - v->count || !io_vec_reserve(v, elem_size, v->count + n))
        return NULL;
    void *p = (char *)v->data + v->count * elem_size;
    v->count += n;
    return p;
}

void *io_vec_take(io_vec *v, size_t elem_size)
{
    void *d = v->data;
    if (d && v->count < v->cap) {
        void *s = realloc(d, (v->count ? v->count : 1) * elem_size);
        if (s)
            d = s;
    }
    v->data = NULL;
    v->count = v->cap = 0;
    return d;
}

void io_vec_free(io_vec *v)
{
    free(v->data);
    v->data = NULL;
    v->count = v->cap = 0;
}

/* ---- string map ---- */

static uint64_t str_hash(const char *s)
{
    uint64_t h = 1469598103934665603ull; /* FNV-1a */
    for (; *s; s++)
        h = (h ^ (unsigned char)*s) * 1099511628211ull;
    return h;
}

long io_strmap_get(const io_strmap *m, const char *key)
{
    if (!m->cap)
        return -1;
    size_t mask = m->cap - 1;
    for (size_t i = str_hash(key) & mask;; i = (i + 1) & mask) {
        if (!m->keys[i])
            return -1;
        if (strcmp(m->keys[i], key) == 0)
            return (long)m->vals[i];
    }
}

static int strmap_insert(io_strmap *m, char *key, uint32_t val)
{
    size_t mask = m->cap - 1;
    size_t i = str_hash(key) & mask;
    while (m->keys[i] && strcmp(m->keys[i], key) != 0)
        i = (i + 1) & mask;
    if (m->keys[i]) {
        free(key);
    } else {
        m->keys[i] = key;
        m->count++;
    }
    m->vals[i] = val;
    return 1;
}

int io_strmap_put(io_strmap *m, const char *key, uint32_t val)
{
    if ((m->count + 1) * 2 > m->cap) {
        size_t ncap = m->cap ? m->cap * 2 : 16;
        io_strmap n = {calloc(ncap, sizeof(char *)), calloc(ncap, sizeof(uint32_t)), 0, ncap};
        if (!n.keys || !n.vals) {
            free(n.keys);
            free(n.vals);
            return 0;
        }
        for (size_t i = 0; i < m->cap; i++)
            if (m->keys[i])
                strmap_insert(&n, m->keys[i], m->vals[i]);
        free(m->keys);
        free(m->vals);
        *m = n;
    }
    char *k = io_strdup(key);
    return k ? strmap_insert(m, k, val) : 0;
}

void io_strmap_free(io_strmap *m)
{
    for (size_t i = 0; i < m->cap; i++)
        free(m->keys[i]);
    free(m->keys);
    free(m->vals);
    memset(m, 0, sizeof *m);
}

/* ---- strings and paths ---- */

char *io_strndup(const char *s, size_t n)
{
    char *d = malloc(n + 1);
    if (d) {
        memcpy(d, s, n);
        d[n] = '\0';
    }
    return d;
}

char *io_strdup(const char *s)
{
    return s ? io_strndup(s, strlen(s)) : NULL;
}

char *io_file_stem(const char *path)
{
    const char *b = strrchr(path, '/');
    b = b ? b + 1 : path;
    const char *dot = strrchr(b, '.');
    return io_strndup(b, dot && dot != b ? (size_t)(dot - b) : strlen(b));
}

char *io_dirname(const char *path)
{
    const char *b = strrchr(path, '/');
    return io_strndup(path, b ? (size_t)(b - path + 1) : 0);
}

char *io_join(const char *dir, const char *rel)
{
    if (rel[0] == '/' || !dir[0])
        return io_strdup(rel);
    size_t a = strlen(dir), b = strlen(rel);
    int slash = dir[a - 1] != '/';
    char *d = malloc(a + slash + b + 1);
    if (!d)
        return NULL;
    memcpy(d, dir, a);
    if (slash)
        d[a] = '/';
    memcpy(d + a + slash, rel, b + 1);
    return d;
}

const char *io_ext(const char *path, char *buf, size_t n)
{
    assert(n > 0);
    const char *b = strrchr(path, '/');
    b = b ? b + 1 : path;
    const char *dot = strrchr(b, '.');
    size_t i = 0;
    if (dot)
        for (dot++; *dot && i + 1 < n; dot++)
            buf[i++] = (char)((*dot >= 'A' && *dot <= 'Z') ? *dot - 'A' + 'a' : *dot);
    buf[i] = '\0';
    return buf;
}

int io_file_exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode) && access(path, R_OK) == 0;
}

/* Absolute form of path even when it does not exist yet. */
static char *absolute(const char *path)
{
    char *r = realpath(path, NULL);
    if (r)
        return r;
    if (path[0] == '/')
        return io_strdup(path);
    char cwd[4096];
    if (!getcwd(cwd, sizeof cwd))
        return io_strdup(path);
    return io_join(cwd, path);
}

char *io_relative_path(const char *dir, const char *target)
{
    char *d = absolute(dir[0] ? dir : ".");
    char *t = absolute(target);
    if (!d || !t) {
        free(d);
        free(t);
        return NULL;
    }
    /* Longest common prefix that ends on a folder boundary. */
    size_t dl = strlen(d), common = 0;
    for (size_t i = 0;; i++) {
        int dend = i == dl || d[i] == '/';
        if (dend && (t[i] == '/' || t[i] == '\0'))
            common = i;
        if (i == dl || t[i] == '\0' || d[i] != t[i])
            break;
    }
    size_t ups = 0;
    for (size_t i = common; i < dl; i++)
        if (d[i] == '/' && i + 1 < dl)
            ups++;
    const char *rest = t + common + (t[common] == '/');
    char *r = malloc(ups * 3 + strlen(rest) + 1);
    if (r) {
        char *w = r;
        for (size_t i = 0; i < ups; i++, w += 3)
            memcpy(w, "../", 3);
        strcpy(w, rest);
    }
    free(d);
    free(t);
    return r;
}

hlod_result io_finish_file_mesh(const char *path, const hlod_logger *lg, hlod_result res, hlod_mesh *out,
                                hlod_import_stats *st)
{
    if (res == HLOD_OK) {
        out->objects = calloc(1, sizeof *out->objects);
        if (!out->objects || !(out->objects[0].name = io_file_stem(path))) {
            res = HLOD_ERR_NOMEM;
        } else {
            out->object_count = 1;
            out->objects[0].tri_count = out->tri_count;
        }
    }
    if (res == HLOD_ERR_NOMEM)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory", path);
    if (res)
        hlod_mesh_free(out);
    else if (st)
        st->tris_read = out->tri_count;
    return res;
}

/* A texture that cannot be read makes its material untextured: the mesh
 * is still worth building, and the warning says what went missing. */
void io_check_textures(const char *path, hlod_mesh *m, const hlod_logger *lg,
                       hlod_import_stats *st)
{
    for (size_t i = 0; i < m->material_count; i++) {
        hlod_material *mt = &m->materials[i];
        if (!mt->texture_path || io_file_exists(mt->texture_path))
            continue;
        hlod_logf(lg, HLOD_LOG_WARN, "%s: material %zu (%s): texture %s not found; untextured",
                  path, i, mt->name ? mt->name : "unnamed", mt->texture_path);
        free(mt->texture_path);
        mt->texture_path = NULL;
        st->missing_textures++;
    }
}
