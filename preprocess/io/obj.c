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
} obj_reader;

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
            return fail(r, HLOD_ERR_NAN, "vertex %zu: coordinate is %s", r->pos.count + 1,
                        xyz[k] != xyz[k] ? "NaN" : "infinite");
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
        return fail(r, HLOD_ERR_NAN, "texture coordinate %zu is not finite", r->uv.count + 1);
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
            return fail(r, HLOD_ERR_NAN, "normal %zu is not finite", r->nrm.count + 1);
    float *d = io_vec_push(&r->nrm, sizeof(float[3]), 1);
    if (!d)
        return HLOD_ERR_NOMEM;
    for (int k = 0; k < 3; k++)
        d[k] = (float)n[k];
    return HLOD_OK;
}

/* OBJ indices are 1-based; negative ones count back from the last element
 * defined so far. */
static hlod_result resolve(obj_reader *r, long long idx, size_t count, const char *what,
                           uint32_t *out)
{
    long long abs_idx = idx > 0 ? idx - 1 : (long long)count + idx;
    if (idx == 0)
        return fail(r, HLOD_ERR_FORMAT, "face %zu: %s index 0 (OBJ indices start at 1)",
                    r->faces + 1, what);
    if (abs_idx < 0 || (unsigned long long)abs_idx >= count)
        return fail(r, HLOD_ERR_INDEX_RANGE, "face %zu: %s index %lld out of range (%zu defined)",
                    r->faces + 1, what, idx, count);
    *out = (uint32_t)abs_idx;
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
        if ((res = resolve(r, iv, r->pos.count, "vertex", &cn.v)))
            return res;
        if (*p == '/') {
            p++;
            if (*p != '/') {
                if (!io_parse_long(&p, &it))
                    return fail(r, HLOD_ERR_FORMAT, "face %zu: bad texture coordinate reference",
                                r->faces + 1);
                if ((res = resolve(r, it, r->uv.count, "texture coordinate", &cn.vt)))
                    return res;
                cn.vt++;
                r->has_vt = 1;
            }
            if (*p == '/') {
                p++;
                if (!io_parse_long(&p, &in))
                    return fail(r, HLOD_ERR_FORMAT, "face %zu: bad normal reference",
                                r->faces + 1);
                if ((res = resolve(r, in, r->nrm.count, "normal", &cn.vn)))
                    return res;
                cn.vn++;
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

static hlod_result build_materials(obj_reader *r, hlod_mesh *m, const char *obj_dir)
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
    if (res)
        return res;
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
    if (!r->has_vt && !r->has_vn) {
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
    char *line;
    while (res == HLOD_OK && io_line(&r.s, &line, NULL)) {
        char *p = line;
        char c = io_skip_blanks((const char **)&p);
        if (!c || c == '#')
            continue;
        if (p[0] == 'v' && is_blank(p[1])) {
            res = read_v(&r, p + 2);
        } else if (p[0] == 'f' && is_blank(p[1])) {
            res = read_f(&r, p + 2);
        } else if (p[0] == 'v' && p[1] == 't' && is_blank(p[2])) {
            res = read_vt(&r, p + 3);
        } else if (p[0] == 'v' && p[1] == 'n' && is_blank(p[2])) {
            res = read_vn(&r, p + 3);
        } else if ((p[0] == 'o' || p[0] == 'g') && (is_blank(p[1]) || !p[1])) {
            res = start_object(&r, rest_of_line(p + 1));
        } else if (strncmp(p, "usemtl", 6) == 0 && (is_blank(p[6]) || !p[6])) {
            res = use_material(&r, rest_of_line(p + 6));
        } else if (strncmp(p, "mtllib", 6) == 0 && is_blank(p[6])) {
            res = add_mtllib(&r, rest_of_line(p + 6), dir);
        }
        /* Everything else (s, l, p, vp, curves, ...) carries nothing we keep. */
    }
    if (res == HLOD_OK && r.s.error)
        res = HLOD_ERR_IO;
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
        res = build_materials(&r, out, dir);
    if (res == HLOD_OK && st)
        st->tris_read = out->tri_count;
    if (res)
        hlod_mesh_free(out);
    if (res == HLOD_ERR_NOMEM)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory", path);

    io_close(&r.s);
    free(dir);
    io_vec_free(&r.pos);
    io_vec_free(&r.uv);
    io_vec_free(&r.nrm);
    io_vec_free(&r.corners);
    io_vec_free(&r.tri_mat);
    io_vec_free(&r.poly);
    hlod_object *objs = r.objects.data;
    for (size_t i = 0; i < r.objects.count; i++)
        free(objs[i].name);
    io_vec_free(&r.objects);
    char **names = r.mat_names.data;
    for (size_t i = 0; i < r.mat_names.count; i++)
        free(names[i]);
    io_vec_free(&r.mat_names);
    char **libs = r.mtllibs.data;
    for (size_t i = 0; i < r.mtllibs.count; i++)
        free(libs[i]);
    io_vec_free(&r.mtllibs);
    io_strmap_free(&r.mat_index);
    return res;
}
