/*
 * Wavefront OBJ (+ MTL) reader, positions in double.
 *
 * One pass over the lines collects v/vt/vn arrays and, per triangle corner,
 * the (v, vt, vn) tuple; polygons are fan-triangulated.  Afterwards each
 * distinct tuple becomes one vertex, numbered in (v, vt, vn) order so that a
 * file written by io_write_obj (where every tuple is (i, i, i)) reads back
 * with its vertex order intact.  A file whose faces use positions only skips
 * the tuple table altogether.
 *
 * Materials are collected by name as usemtl lines name them and filled in
 * from the mtllib files at the end, because some exporters write mtllib
 * after the first usemtl.  Only materials that faces use enter the mesh.
 */
#include "io_internal.h"
#include "prefetch.h"

#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

typedef struct corner {
    uint32_t v, vt, vn; /* vt/vn: index + 1, 0 when absent */
} corner;

typedef struct obj_reader {
    const char *path;
    const hlod_logger *lg;
    io_stream s;
    io_vec pos;      /* double[3] */
    io_vec uv;       /* float[2] */
    io_vec nrm;      /* float[3] */
    io_vec corners;  /* corner, 3 per triangle */
    io_vec tri_mat;  /* uint32_t per triangle; UINT32_MAX = no usemtl yet */
    io_vec objects;  /* hlod_object: name, first_tri (tri_count filled at the end) */
    io_vec mat_names; /* char *, in first-use order */
    io_strmap mat_index;
    io_vec mtllibs;  /* char *, resolved paths */
    io_vec poly;     /* corner scratch for one face */
    uint32_t cur_mat;
    int any_untagged, has_vt, has_vn;
    size_t faces;
    size_t lines[3];  /* v, vt and vn lines read so far (the indices' range) */
    /* hlod_obj_stream: which lines are kept (n == 0: all; none: keep_none)
     * and, for the object being read, whether its faces are kept and the
     * lines they use */
    int stream;
    struct window {
        const hlod_obj_range *r;
        size_t n, at;
        size_t *start; /* stored index of r[i].lo */
        int keep_none;
    } win[3];
    int want_cur;
    hlod_obj_range used[3];
    const hlod_obj_stream_desc *sd;
    hlod_mesh *table;     /* the material table every object points into */
    char *cur_name;       /* the object being read (NULL: named after the file) */
    size_t ordinal;       /* objects with faces so far */
    size_t object_faces;  /* faces before the object being read */
} obj_reader;

/* Is line `line` of kind k kept?  (Lines come in order: the cursor only
 * moves forward.) */
static int window_keeps(struct window *w, size_t line)
{
    if (w->keep_none)
        return 0;
    if (!w->n)
        return 1;
    while (w->at < w->n && w->r[w->at].hi <= line)
        w->at++;
    return w->at < w->n && w->r[w->at].lo <= line;
}

/* Where kept line `line` of a kind is stored; 0 when it was not kept. */
static int window_index(const struct window *w, uint32_t line, uint32_t *stored)
{
    if (!w->n) {
        *stored = line;
        return !w->keep_none;
    }
    size_t a = 0, b = w->n;
    while (a < b) {
        size_t m = a + (b - a) / 2;
        if (w->r[m].hi <= line)
            a = m + 1;
        else
            b = m;
    }
    if (a == w->n || w->r[a].lo > line)
        return 0;
    *stored = (uint32_t)(w->start[a] + (line - w->r[a].lo));
    return 1;
}

static hlod_result fail(obj_reader *r, hlod_result res, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static hlod_result fail(obj_reader *r, hlod_result res, const char *fmt, ...)
{
    char msg[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    hlod_logf(r->lg, HLOD_LOG_ERROR, "%s: line %zu: %s", r->path, r->s.line, msg);
    return res;
}

static int is_blank(char c)
{
    return c == ' ' || c == '\t';
}

/* The rest of the line with blanks trimmed on both ends (modifies line). */
static char *rest_of_line(char *p)
{
    while (is_blank(*p))
        p++;
    size_t n = strlen(p);
    while (n && is_blank(p[n - 1]))
        p[--n] = '\0';
    return p;
}

static hlod_result parse_floats(obj_reader *r, const char *p, double *out, int need, int max,
                                const char *what)
{
    int n = 0;
    while (n < max) {
        char c = io_skip_blanks(&p);
        if (!c || c == '#')
            break;
        if (!io_parse_double(&p, &out[n]))
            return fail(r, HLOD_ERR_FORMAT, "%s: bad number", what);
        n++;
    }
    if (n < need)
        return fail(r, HLOD_ERR_FORMAT, "%s needs %d numbers, found %d", what, need, n);
    return HLOD_OK;
}

static hlod_result read_v(obj_reader *r, const char *p)
{
    double xyz[3];
    hlod_result res = parse_floats(r, p, xyz, 3, 3, "v");
    if (res)
        return res;
    for (int k = 0; k < 3; k++)
        if (!(xyz[k] - xyz[k] == 0))
            return fail(r, HLOD_ERR_NAN, "vertex %zu: coordinate is %s", r->lines[0] + 1,
                        xyz[k] != xyz[k] ? "NaN" : "infinite");
    if (!window_keeps(&r->win[0], r->lines[0]++))
        return HLOD_OK;
    double *d = io_vec_push(&r->pos, sizeof(double[3]), 1);
    if (!d)
        return HLOD_ERR_NOMEM;
    memcpy(d, xyz, sizeof xyz);
    return HLOD_OK;
}

static hlod_result read_vt(obj_reader *r, const char *p)
{
    double uv[2] = {0, 0};
    hlod_result res = parse_floats(r, p, uv, 1, 2, "vt");
    if (res)
        return res;
    if (!(uv[0] - uv[0] == 0) || !(uv[1] - uv[1] == 0))
        return fail(r, HLOD_ERR_NAN, "texture coordinate %zu is not finite", r->lines[1] + 1);
    if (!window_keeps(&r->win[1], r->lines[1]++))
        return HLOD_OK;
    float *d = io_vec_push(&r->uv, sizeof(float[2]), 1);
    if (!d)
        return HLOD_ERR_NOMEM;
    d[0] = (float)uv[0];
    d[1] = (float)uv[1];
    return HLOD_OK;
}

static hlod_result read_vn(obj_reader *r, const char *p)
{
    double n[3];
    hlod_result res = parse_floats(r, p, n, 3, 3, "vn");
    if (res)
        return res;
    for (int k = 0; k < 3; k++)
        if (!(n[k] - n[k] == 0))
            return fail(r, HLOD_ERR_NAN, "normal %zu is not finite", r->lines[2] + 1);
    if (!window_keeps(&r->win[2], r->lines[2]++))
        return HLOD_OK;
    float *d = io_vec_push(&r->nrm, sizeof(float[3]), 1);
    if (!d)
        return HLOD_ERR_NOMEM;
    for (int k = 0; k < 3; k++)
        d[k] = (float)n[k];
    return HLOD_OK;
}

/* OBJ indices are 1-based; negative ones count back from the last element
 * defined so far. */
static hlod_result resolve(obj_reader *r, long long idx, int kind, uint32_t *out)
{
    static const char *const what[3] = {"vertex", "texture coordinate", "normal"};
    const size_t count = r->lines[kind];
    long long abs_idx = idx > 0 ? idx - 1 : (long long)count + idx;
    if (idx == 0)
        return fail(r, HLOD_ERR_FORMAT, "face %zu: %s index 0 (OBJ indices start at 1)",
                    r->faces + 1, what[kind]);
    if (abs_idx < 0 || (unsigned long long)abs_idx >= count)
        return fail(r, HLOD_ERR_INDEX_RANGE, "face %zu: %s index %lld out of range (%zu defined)",
                    r->faces + 1, what[kind], idx, count);
    uint32_t line = (uint32_t)abs_idx;
    if (!r->stream) {
        *out = line;
        return HLOD_OK;
    }
    hlod_obj_range *u = &r->used[kind];
    if (u->lo == u->hi) {
        u->lo = line;
        u->hi = line + 1;
    } else {
        u->lo = line < u->lo ? line : u->lo;
        u->hi = line + 1 > u->hi ? line + 1 : u->hi;
    }
    *out = 0;
    if (r->want_cur && !r->win[kind].keep_none && !window_index(&r->win[kind], line, out))
        return fail(r, HLOD_ERR_IO, "face %zu: %s %u was not kept: the file changed while it "
                    "was read", r->faces + 1, what[kind], line + 1);
    return HLOD_OK;
}

static hlod_result read_f(obj_reader *r, const char *p)
{
    r->poly.count = 0;
    for (;;) {
        char c = io_skip_blanks(&p);
        if (!c || c == '#')
            break;
        long long iv, it, in;
        corner cn = {0, 0, 0};
        hlod_result res;
        if (!io_parse_long(&p, &iv))
            return fail(r, HLOD_ERR_FORMAT, "face %zu: bad vertex reference", r->faces + 1);
        if ((res = resolve(r, iv, 0, &cn.v)))
            return res;
        if (*p == '/') {
            p++;
            if (*p != '/') {
                if (!io_parse_long(&p, &it))
                    return fail(r, HLOD_ERR_FORMAT, "face %zu: bad texture coordinate reference",
                                r->faces + 1);
                if ((res = resolve(r, it, 1, &cn.vt)))
                    return res;
                cn.vt = r->win[1].keep_none ? 0 : cn.vt + 1;
                r->has_vt = 1;
            }
            if (*p == '/') {
                p++;
                if (!io_parse_long(&p, &in))
                    return fail(r, HLOD_ERR_FORMAT, "face %zu: bad normal reference",
                                r->faces + 1);
                if ((res = resolve(r, in, 2, &cn.vn)))
                    return res;
                cn.vn = r->win[2].keep_none ? 0 : cn.vn + 1;
                r->has_vn = 1;
            }
        }
        if (*p && !is_blank(*p))
            return fail(r, HLOD_ERR_FORMAT, "face %zu: bad vertex reference", r->faces + 1);
        corner *d = io_vec_push(&r->poly, sizeof(corner), 1);
        if (!d)
            return HLOD_ERR_NOMEM;
        *d = cn;
    }
    size_t n = r->poly.count;
    if (n < 3)
        return fail(r, HLOD_ERR_FORMAT, "face %zu has %zu vertices, needs at least 3",
                    r->faces + 1, n);
    if (r->stream && !r->want_cur) {
        r->faces++; /* checked, not kept */
        return HLOD_OK;
    }
    const corner *pc = r->poly.data;
    corner *out = io_vec_push(&r->corners, sizeof(corner), 3 * (n - 2));
    uint32_t *tm = io_vec_push(&r->tri_mat, sizeof(uint32_t), n - 2);
    if (!out || !tm)
        return HLOD_ERR_NOMEM;
    for (size_t i = 1; i + 1 < n; i++) {
        *out++ = pc[0];
        *out++ = pc[i];
        *out++ = pc[i + 1];
        *tm++ = r->cur_mat;
    }
    if (r->cur_mat == UINT32_MAX)
        r->any_untagged = 1;
    r->faces++;
    return HLOD_OK;
}

static hlod_result start_object(obj_reader *r, char *name)
{
    hlod_object *o = io_vec_push(&r->objects, sizeof(hlod_object), 1);
    if (!o)
        return HLOD_ERR_NOMEM;
    o->name = name[0] ? io_strdup(name) : NULL;
    o->first_tri = r->tri_mat.count;
    o->tri_count = 0;
    return HLOD_OK;
}

static hlod_result use_material(obj_reader *r, const char *name)
{
    long idx = io_strmap_get(&r->mat_index, name);
    if (idx < 0) {
        char **slot = io_vec_push(&r->mat_names, sizeof(char *), 1);
        if (!slot)
            return HLOD_ERR_NOMEM;
        *slot = io_strdup(name);
        idx = (long)r->mat_names.count - 1;
        if (!*slot || !io_strmap_put(&r->mat_index, name, (uint32_t)idx))
            return HLOD_ERR_NOMEM;
    }
    r->cur_mat = (uint32_t)idx;
    return HLOD_OK;
}

static hlod_result add_mtllib(obj_reader *r, char *names, const char *dir)
{
    /* File names may hold spaces; several files may share one line.  Take
     * the whole rest as one name when such a file exists. */
    char *whole = io_join(dir, names);
    if (!whole)
        return HLOD_ERR_NOMEM;
    if (io_file_exists(whole) || !strpbrk(names, " \t")) {
        char **d = io_vec_push(&r->mtllibs, sizeof(char *), 1);
        if (!d) {
            free(whole);
            return HLOD_ERR_NOMEM;
        }
        *d = whole;
        return HLOD_OK;
    }
    free(whole);
    for (char *tok = strtok(names, " \t"); tok; tok = strtok(NULL, " \t")) {
        char **d = io_vec_push(&r->mtllibs, sizeof(char *), 1);
        if (!d || !(*d = io_join(dir, tok))) {
            if (d)
                r->mtllibs.count--;
            return HLOD_ERR_NOMEM;
        }
    }
    return HLOD_OK;
}

static char *skip_token(char *p)
{
    while (is_blank(*p))
        p++;
    while (*p && !is_blank(*p))
        p++;
    return p;
}

/* "map_Kd [-options args] file name.png" -> "file name.png", with DOS
 * separators turned into '/' (spider.mtl says ".\SpiderTex.jpg"). */
static char *texture_name(char *p)
{
    while (io_skip_blanks((const char **)&p) == '-') {
        char *opt = p;
        p = skip_token(p);
        size_t len = (size_t)(p - opt);
        if (len == 2 && strchr("ost", opt[1])) {
            /* -o/-s/-t take one to three numbers */
            for (int a = 0; a < 3; a++) {
                const char *q = p;
                double d;
                if (!io_parse_double(&q, &d))
                    break;
                p = (char *)q;
            }
        } else if (len == 3 && strncmp(opt, "-mm", 3) == 0) {
            p = skip_token(skip_token(p));
        } else {
            p = skip_token(p);
        }
    }
    p = rest_of_line(p);
    for (char *c = p; *c; c++)
        if (*c == '\\')
            *c = '/';
    while (p[0] == '.' && p[1] == '/')
        p += 2;
    return p;
}

static hlod_result read_mtllib(obj_reader *r, const char *lib, hlod_material *mats,
                               uint8_t *defined, const char *obj_dir)
{
    io_stream s;
    hlod_logger quiet = {0};
    /* Regular files only: "mtllib /dev/stdin" (or a FIFO) would block. */
    if (!io_file_exists(lib) || io_open(&s, lib, &quiet) != HLOD_OK) {
        hlod_logf(r->lg, HLOD_LOG_WARN, "%s: material library %s cannot be read; its materials "
                  "stay grey and untextured", r->path, lib);
        return HLOD_OK;
    }
    char *mtl_dir = io_dirname(lib);
    if (!mtl_dir) {
        io_close(&s);
        return HLOD_ERR_NOMEM;
    }
    hlod_result res = HLOD_OK;
    hlod_material *cur = NULL;
    char *line;
    while (res == HLOD_OK && io_line(&s, &line, NULL)) {
        char *p = line;
        io_skip_blanks((const char **)&p);
        char *kw = p;
        while (*p && !is_blank(*p))
            p++;
        size_t kl = (size_t)(p - kw);
        if (kl == 6 && strncmp(kw, "newmtl", 6) == 0) {
            long idx = io_strmap_get(&r->mat_index, rest_of_line(p));
            cur = idx >= 0 && !defined[idx] ? &mats[idx] : NULL;
            if (cur)
                defined[idx] = 1;
        } else if (!cur) {
            continue;
        } else if (kl == 2 && strncmp(kw, "Kd", 2) == 0) {
            const char *q = p;
            double c[3];
            int k = 0;
            for (; k < 3 && io_parse_double(&q, &c[k]); k++)
                ;
            if (k == 3)
                for (int j = 0; j < 3; j++)
                    cur->diffuse[j] = (float)c[j];
            else
                hlod_logf(r->lg, HLOD_LOG_WARN, "%s: line %zu: Kd needs 3 numbers; ignored", lib,
                          s.line);
        } else if ((kl == 1 && kw[0] == 'd') || (kl == 2 && strncmp(kw, "Tr", 2) == 0)) {
            const char *q = p;
            double a;
            if (io_parse_double(&q, &a))
                cur->diffuse[3] = (float)(kw[0] == 'd' ? a : 1.0 - a);
        } else if (kl == 6 && strncmp(kw, "map_Kd", 6) == 0) {
            char *name = texture_name(p);
            if (!name[0])
                continue;
            char *a = io_join(mtl_dir, name);
            char *b = a && !io_file_exists(a) ? io_join(obj_dir, name) : NULL;
            if (!a) {
                res = HLOD_ERR_NOMEM;
                break;
            }
            free(cur->texture_path);
            if (b && io_file_exists(b)) {
                cur->texture_path = b;
                free(a);
            } else {
                cur->texture_path = a;
                free(b);
            }
        }
    }
    if (s.error)
        hlod_logf(r->lg, HLOD_LOG_WARN, "%s: material library %s could not be read to the end",
                  r->path, lib);
    io_close(&s);
    free(mtl_dir);
    return res;
}

/* The materials the usemtl lines name, in first-use order (plus "default"
 * when some face comes before any usemtl), filled from the libraries. */
static hlod_result build_material_table(obj_reader *r, hlod_mesh *m, const char *obj_dir)
{
    size_t n = r->mat_names.count;
    if (n == 0)
        return HLOD_OK;
    size_t total = n + (r->any_untagged ? 1 : 0);
    m->materials = calloc(total, sizeof *m->materials);
    uint8_t *defined = calloc(n, 1);
    if (!m->materials || !defined) {
        free(defined);
        return HLOD_ERR_NOMEM;
    }
    m->material_count = total;
    char **names = r->mat_names.data;
    for (size_t i = 0; i < total; i++) {
        hlod_material *mt = &m->materials[i];
        mt->diffuse[0] = mt->diffuse[1] = mt->diffuse[2] = 0.8f;
        mt->diffuse[3] = 1.0f;
        if (i < n) {
            mt->name = names[i];
            names[i] = NULL;
        } else if (!(mt->name = io_strdup("default"))) {
            free(defined);
            return HLOD_ERR_NOMEM;
        }
    }
    hlod_result res = HLOD_OK;
    char **libs = r->mtllibs.data;
    for (size_t i = 0; i < r->mtllibs.count && res == HLOD_OK; i++)
        res = read_mtllib(r, libs[i], m->materials, defined, obj_dir);
    for (size_t i = 0; i < n && res == HLOD_OK; i++)
        if (!defined[i])
            hlod_logf(r->lg, HLOD_LOG_WARN,
                      "%s: material '%s' is not defined in any material library; using grey",
                      r->path, m->materials[i].name);
    free(defined);
    return res;
}

/* Each triangle's material: "default" (the last) for those before any
 * usemtl; none at all without usemtl lines. */
static hlod_result take_tri_materials(obj_reader *r, hlod_mesh *m)
{
    size_t n = r->mat_names.count;
    if (n == 0)
        return HLOD_OK;
    uint32_t *tm = r->tri_mat.data;
    for (size_t t = 0; t < r->tri_mat.count; t++)
        if (tm[t] == UINT32_MAX)
            tm[t] = (uint32_t)n;
    m->tri_material = io_vec_take(&r->tri_mat, sizeof(uint32_t));
    return m->tri_material ? HLOD_OK : HLOD_ERR_NOMEM;
}

typedef struct tuple {
    corner c;
    uint32_t id; /* first-occurrence number, before sorting */
} tuple;

static int tuple_cmp(const void *pa, const void *pb)
{
    const corner *a = &((const tuple *)pa)->c, *b = &((const tuple *)pb)->c;
    if (a->v != b->v)
        return a->v < b->v ? -1 : 1;
    if (a->vt != b->vt)
        return a->vt < b->vt ? -1 : 1;
    return a->vn < b->vn ? -1 : a->vn > b->vn;
}

static uint64_t corner_hash(const corner *c)
{
    uint64_t h = (uint64_t)c->v * 0x9e3779b97f4a7c15ull;
    h ^= ((uint64_t)c->vt + 0x632be59bd9b4e019ull) * 0xbf58476d1ce4e5b9ull;
    h ^= ((uint64_t)c->vn + 0x85ebca6b) * 0x94d049bb133111ebull;
    return h ^ (h >> 31);
}

static int corner_eq(const corner *a, const corner *b)
{
    return a->v == b->v && a->vt == b->vt && a->vn == b->vn;
}

/* One vertex per distinct (v, vt, vn) tuple, numbered in tuple order.  The
 * corner list is freed as soon as the tuples are known, so the peak is the
 * corners plus the hash table, not that plus the final arrays. */
static hlod_result build_vertices(obj_reader *r, hlod_mesh *m)
{
    size_t nc = r->corners.count;
    m->tri_count = nc / 3;
    m->indices = malloc((nc ? nc : 1) * sizeof(uint32_t));
    if (!m->indices)
        return HLOD_ERR_NOMEM;
    const corner *cs = r->corners.data;
    if (!r->has_vt && !r->has_vn && !r->stream) {
        for (size_t i = 0; i < nc; i++)
            m->indices[i] = cs[i].v;
        io_vec_free(&r->corners);
        m->vertex_count = r->pos.count;
        m->positions = io_vec_take(&r->pos, sizeof(double[3]));
        return m->positions || !m->vertex_count ? HLOD_OK : HLOD_ERR_NOMEM;
    }
    size_t cap = 16;
    while (cap < nc + nc / 2)
        cap *= 2;
    uint32_t *table = calloc(cap, sizeof *table); /* tuple number + 1, 0 = empty */
    if (!table)
        return HLOD_ERR_NOMEM;
    io_vec uniq = {0};
    /* The table is far larger than the caches: each probe misses twice
     * (the slot, then the tuple it names).  Corners go in batches whose
     * slots, then tuples, are prefetched first, so the misses overlap
     * instead of queueing (hints only: the probe below is unchanged). */
    enum { BATCH = 16 };
    size_t hs[BATCH];
    for (size_t i = 0; i < nc; i++) {
        if (i % BATCH == 0) {
            size_t nb = nc - i < BATCH ? nc - i : BATCH;
            for (size_t j = 0; j < nb; j++) {
                hs[j] = (size_t)corner_hash(&cs[i + j]) & (cap - 1);
                HLOD_PREFETCH(&table[hs[j]]);
            }
            const tuple *u = uniq.data;
            for (size_t j = 0; j < nb; j++)
                if (table[hs[j]])
                    HLOD_PREFETCH(&u[table[hs[j]] - 1]);
        }
        size_t h = hs[i % BATCH];
        const tuple *u = uniq.data;
        while (table[h] && !corner_eq(&u[table[h] - 1].c, &cs[i]))
            h = (h + 1) & (cap - 1);
        if (!table[h]) {
            tuple *t = io_vec_push(&uniq, sizeof(tuple), 1);
            if (!t) {
                free(table);
                io_vec_free(&uniq);
                return HLOD_ERR_NOMEM;
            }
            t->c = cs[i];
            t->id = (uint32_t)(uniq.count - 1);
            table[h] = (uint32_t)uniq.count;
        }
        m->indices[i] = table[h] - 1;
    }
    free(table);
    io_vec_free(&r->corners);

    size_t nu = uniq.count;
    tuple *u = uniq.data;
    qsort(u, nu, sizeof *u, tuple_cmp);
    uint32_t *rank = malloc((nu ? nu : 1) * sizeof *rank);
    m->vertex_count = nu;
    m->positions = malloc((nu ? nu : 1) * 3 * sizeof(double));
    m->uvs = r->has_vt ? malloc((nu ? nu : 1) * 2 * sizeof(float)) : NULL;
    m->normals = r->has_vn ? malloc((nu ? nu : 1) * 3 * sizeof(float)) : NULL;
    if (!rank || !m->positions || (r->has_vt && !m->uvs) || (r->has_vn && !m->normals)) {
        free(rank);
        io_vec_free(&uniq);
        return HLOD_ERR_NOMEM;
    }
    for (size_t k = 0; k < nu; k++)
        rank[u[k].id] = (uint32_t)k;
    for (size_t i = 0; i < nc; i++)
        m->indices[i] = rank[m->indices[i]];
    free(rank);
    const double *P = r->pos.data;
    const float *T = r->uv.data, *N = r->nrm.data;
    for (size_t k = 0; k < nu; k++) {
        const corner *c = &u[k].c;
        memcpy(m->positions + 3 * k, P + 3 * (size_t)c->v, 3 * sizeof(double));
        if (m->uvs) {
            if (c->vt)
                memcpy(m->uvs + 2 * k, T + 2 * (size_t)(c->vt - 1), 2 * sizeof(float));
            else
                m->uvs[2 * k] = m->uvs[2 * k + 1] = 0;
        }
        if (m->normals) {
            if (c->vn)
                memcpy(m->normals + 3 * k, N + 3 * (size_t)(c->vn - 1), 3 * sizeof(float));
            else
                m->normals[3 * k] = m->normals[3 * k + 1] = m->normals[3 * k + 2] = 0;
        }
    }
    io_vec_free(&uniq);
    return HLOD_OK;
}

/* Object ranges from the o/g starts: triangles before the first o/g form an
 * object named after the file; objects without triangles are dropped. */
static hlod_result build_objects(obj_reader *r, hlod_mesh *m)
{
    size_t n = r->objects.count;
    hlod_object *src = r->objects.data;
    m->objects = calloc(n + 1, sizeof *m->objects);
    if (!m->objects)
        return HLOD_ERR_NOMEM;
    size_t w = 0, ntri = r->tri_mat.count;
    size_t first_start = n ? src[0].first_tri : ntri;
    if (first_start > 0) {
        m->objects[w].name = io_file_stem(r->path);
        m->objects[w].first_tri = 0;
        m->objects[w].tri_count = first_start;
        w++;
    }
    for (size_t i = 0; i < n; i++) {
        size_t end = i + 1 < n ? src[i + 1].first_tri : ntri;
        if (end == src[i].first_tri) {
            free(src[i].name);
            continue;
        }
        m->objects[w] = src[i];
        if (!m->objects[w].name)
            m->objects[w].name = io_file_stem(r->path);
        m->objects[w].tri_count = end - src[i].first_tri;
        w++;
    }
    r->objects.count = 0;
    m->object_count = w;
    return HLOD_OK;
}

/* What every reader's end frees. */
static void reader_free(obj_reader *r)
{
    io_vec_free(&r->pos);
    io_vec_free(&r->uv);
    io_vec_free(&r->nrm);
    io_vec_free(&r->corners);
    io_vec_free(&r->tri_mat);
    io_vec_free(&r->poly);
    hlod_object *objs = r->objects.data;
    for (size_t i = 0; i < r->objects.count; i++)
        free(objs[i].name);
    io_vec_free(&r->objects);
    char **names = r->mat_names.data;
    for (size_t i = 0; i < r->mat_names.count; i++)
        free(names[i]);
    io_vec_free(&r->mat_names);
    char **libs = r->mtllibs.data;
    for (size_t i = 0; i < r->mtllibs.count; i++)
        free(libs[i]);
    io_vec_free(&r->mtllibs);
    io_strmap_free(&r->mat_index);
    for (int k = 0; k < 3; k++)
        free(r->win[k].start);
    free(r->cur_name);
}

static hlod_result stream_next_object(obj_reader *r, char *name);

/* Every line of the file, each to its reader. */
static hlod_result read_lines(obj_reader *r, const char *dir)
{
    hlod_result res = HLOD_OK;
    char *line;
    while (res == HLOD_OK && io_line(&r->s, &line, NULL)) {
        char *p = line;
        char c = io_skip_blanks((const char **)&p);
        if (!c || c == '#')
            continue;
        if (p[0] == 'v' && is_blank(p[1])) {
            res = read_v(r, p + 2);
        } else if (p[0] == 'f' && is_blank(p[1])) {
            res = read_f(r, p + 2);
        } else if (p[0] == 'v' && p[1] == 't' && is_blank(p[2])) {
            res = read_vt(r, p + 3);
        } else if (p[0] == 'v' && p[1] == 'n' && is_blank(p[2])) {
            res = read_vn(r, p + 3);
        } else if ((p[0] == 'o' || p[0] == 'g') && (is_blank(p[1]) || !p[1])) {
            res = r->stream ? stream_next_object(r, rest_of_line(p + 1))
                            : start_object(r, rest_of_line(p + 1));
        } else if (strncmp(p, "usemtl", 6) == 0 && (is_blank(p[6]) || !p[6])) {
            res = use_material(r, rest_of_line(p + 6));
        } else if (strncmp(p, "mtllib", 6) == 0 && is_blank(p[6]) && !r->stream) {
            res = add_mtllib(r, rest_of_line(p + 6), dir);
        }
        /* Everything else (s, l, p, vp, curves, ...) carries nothing we keep. */
    }
    if (res == HLOD_OK && r->s.error)
        res = HLOD_ERR_IO;
    return res;
}

hlod_result io_read_obj(const char *path, const hlod_logger *lg, hlod_mesh *out,
                        hlod_import_stats *st)
{
    obj_reader r;
    memset(&r, 0, sizeof r);
    r.path = path;
    r.lg = lg;
    r.cur_mat = UINT32_MAX;
    hlod_result res = io_open(&r.s, path, lg);
    if (res)
        return res;
    char *dir = io_dirname(path);
    if (!dir) {
        io_close(&r.s);
        return HLOD_ERR_NOMEM;
    }
    res = read_lines(&r, dir);
    if (res == HLOD_OK && r.corners.count == 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: no faces (%zu vertices)", path, r.pos.count);
        res = HLOD_ERR_EMPTY;
    }
    hlod_mesh_free(out);
    if (res == HLOD_OK)
        res = build_vertices(&r, out);
    if (res == HLOD_OK)
        res = build_objects(&r, out);
    if (res == HLOD_OK)
        res = build_material_table(&r, out, dir);
    if (res == HLOD_OK)
        res = take_tri_materials(&r, out);
    if (res == HLOD_OK && st)
        st->tris_read = out->tri_count;
    if (res)
        hlod_mesh_free(out);
    if (res == HLOD_ERR_NOMEM)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory", path);

    io_close(&r.s);
    free(dir);
    reader_free(&r);
    return res;
}

/* ---- hlod_obj_stream (mesh_io.h) ---- */

/* The first pass: materials (usemtl in first-use order, mtllib), faces
 * before any usemtl, and whether faces carry texture coordinates or
 * normals, which decide every object's mesh as they decide the file's. */
static hlod_result prescan(obj_reader *r, const char *dir)
{
    hlod_result res = HLOD_OK;
    char *line;
    while (res == HLOD_OK && io_line(&r->s, &line, NULL)) {
        char *p = line;
        char c = io_skip_blanks((const char **)&p);
        if (c == 'f' && is_blank(p[1])) {
            r->faces++;
            r->any_untagged |= r->cur_mat == UINT32_MAX;
            /* "v/vt", "v/vt/vn", "v//vn": what follows each slash */
            for (const char *q = p + 2; *q && *q != '#'; q++) {
                if (*q != '/')
                    continue;
                if (q[1] && q[1] != '/' && !is_blank(q[1]))
                    r->has_vt = 1;
                const char *e = q + 1;
                while (*e && *e != '/' && !is_blank(*e))
                    e++;
                if (*e == '/')
                    r->has_vn = 1;
                while (*e && !is_blank(*e))
                    e++;
                q = e - 1;
            }
        } else if (strncmp(p, "usemtl", 6) == 0 && (is_blank(p[6]) || !p[6])) {
            res = use_material(r, rest_of_line(p + 6));
        } else if (strncmp(p, "mtllib", 6) == 0 && is_blank(p[6])) {
            res = add_mtllib(r, rest_of_line(p + 6), dir);
        }
    }
    if (res == HLOD_OK && r->s.error)
        res = HLOD_ERR_IO;
    return res;
}

/* The object just read as a mesh of its own (its faces' corners and
 * materials are taken from r). */
static hlod_result object_mesh(obj_reader *r, hlod_mesh *m)
{
    size_t ntri = r->tri_mat.count;
    hlod_result res = build_vertices(r, m);
    if (res == HLOD_OK)
        res = take_tri_materials(r, m);
    r->tri_mat.count = 0;
    if (res != HLOD_OK)
        return res;
    m->materials = r->table->materials;
    m->material_count = r->table->material_count;
    m->objects = calloc(1, sizeof *m->objects);
    if (!m->objects)
        return HLOD_ERR_NOMEM;
    m->object_count = 1;
    m->objects[0].name = r->cur_name ? io_strdup(r->cur_name) : io_file_stem(r->path);
    m->objects[0].tri_count = ntri;
    if (!m->objects[0].name)
        return HLOD_ERR_NOMEM;
    res = hlod_mesh_validate(m, r->path, r->lg);
    return res == HLOD_OK ? hlod_mesh_clean(m, NULL, NULL) : res;
}

/* The object being read ends: one with faces goes to the callback. */
static hlod_result stream_flush(obj_reader *r)
{
    if (r->faces == r->object_faces)
        return HLOD_OK; /* none: dropped, as build_objects does */
    hlod_obj_info info = {.index = r->ordinal++};
    memcpy(&info.v, &r->used[0], sizeof info.v);
    memcpy(&info.vt, &r->used[1], sizeof info.vt);
    memcpy(&info.vn, &r->used[2], sizeof info.vn);
    const hlod_obj_stream_desc *d = r->sd;
    if (!r->want_cur)
        return d->object(d->user, &info, NULL);
    hlod_mesh m = {0};
    hlod_result res = object_mesh(r, &m);
    info.tris = m.tri_count;
    if (res == HLOD_OK)
        res = d->object(d->user, &info, &m);
    m.materials = NULL; /* the table's */
    m.material_count = 0;
    hlod_mesh_free(&m);
    return res;
}

static hlod_result stream_next_object(obj_reader *r, char *name)
{
    hlod_result res = stream_flush(r);
    if (res != HLOD_OK)
        return res;
    free(r->cur_name);
    r->cur_name = NULL;
    if (name[0] && !(r->cur_name = io_strdup(name)))
        return HLOD_ERR_NOMEM;
    r->want_cur = !r->sd->want || r->sd->want(r->sd->user, r->ordinal);
    memset(r->used, 0, sizeof r->used);
    r->object_faces = r->faces;
    return HLOD_OK;
}

/* The kept lines of each kind and where each range starts once stored. */
static hlod_result set_windows(obj_reader *r, const hlod_obj_stream_desc *d)
{
    for (int k = 0; k < 3; k++) {
        struct window *w = &r->win[k];
        w->keep_none = k > 0 && d->positions_only;
        w->r = d->keep[k];
        w->n = d->keep[k] ? d->keep_n[k] : 0;
        if (d->keep[k] && !w->n)
            w->keep_none = 1;
        if (!w->n)
            continue;
        if (!(w->start = malloc(w->n * sizeof *w->start)))
            return HLOD_ERR_NOMEM;
        size_t at = 0;
        for (size_t i = 0; i < w->n; i++) {
            if (w->r[i].hi < w->r[i].lo || (i && w->r[i].lo < w->r[i - 1].hi))
                return HLOD_ERR_INVALID_ARG; /* not sorted and disjoint */
            w->start[i] = at;
            at += w->r[i].hi - w->r[i].lo;
        }
    }
    return HLOD_OK;
}

hlod_result hlod_obj_stream(const char *path, hlod_obj_stream_desc *d, hlod_mesh *materials)
{
    if (!path || !d || !d->object || !materials)
        return HLOD_ERR_INVALID_ARG;
    hlod_mesh_free(materials);
    obj_reader r;
    memset(&r, 0, sizeof r);
    r.path = path;
    r.lg = d->logger;
    r.cur_mat = UINT32_MAX;
    r.sd = d;
    r.table = materials;
    char *dir = io_dirname(path);
    if (!dir)
        return HLOD_ERR_NOMEM;
    hlod_result res = io_open(&r.s, path, r.lg);
    if (res == HLOD_OK)
        res = prescan(&r, dir);
    if (res == HLOD_OK && !r.faces) {
        hlod_logf(r.lg, HLOD_LOG_ERROR, "%s: no faces", path);
        res = HLOD_ERR_EMPTY;
    }
    if (res == HLOD_OK && (res = build_material_table(&r, materials, dir)) == HLOD_OK) {
        hlod_import_stats st = {0};
        io_check_textures(path, materials, r.lg, &st);
    }
    if (res == HLOD_OK)
        res = set_windows(&r, d);
    if (r.s.fp)
        io_close(&r.s);
    if (res == HLOD_OK && (res = io_open(&r.s, path, r.lg)) == HLOD_OK) {
        r.stream = 1;
        r.faces = 0;
        r.cur_mat = UINT32_MAX;
        r.want_cur = !d->want || d->want(d->user, 0);
        res = read_lines(&r, dir);
        if (res == HLOD_OK)
            res = stream_flush(&r);
        io_close(&r.s);
        d->lines_kept[0] = r.pos.count;
        d->lines_kept[1] = r.uv.count;
        d->lines_kept[2] = r.nrm.count;
    }
    if (res == HLOD_ERR_NOMEM)
        hlod_logf(r.lg, HLOD_LOG_ERROR, "%s: out of memory", path);
    if (res != HLOD_OK)
        hlod_mesh_free(materials);
    free(dir);
    reader_free(&r);
    return res;
}
