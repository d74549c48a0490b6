/*
 * OBJ (+ MTL), PLY and OFF writers.
 *
 * Positions are printed with %.17g (or stored as binary doubles in PLY), so
 * that every double reads back bit for bit; normals and texture coordinates
 * are floats and %.9g is enough for them.  Every file goes through
 * atomic_file.h.  An OBJ and its MTL are both written to temporary files and
 * flushed to disk before either is renamed, so a failure leaves neither; the
 * one window left is a rename of the OBJ failing after the MTL's succeeded,
 * and then the new MTL is removed again.
 */
#include "io_internal.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "atomic_file.h"

/* A name safe for one OBJ/MTL line: blanks and line breaks become '_'. */
static char *line_safe(const char *name, const char *fallback, size_t k)
{
    char buf[64];
    if (!name || !*name) {
        snprintf(buf, sizeof buf, "%s%zu", fallback, k);
        name = buf;
    }
    char *s = io_strdup(name);
    for (char *p = s; p && *p; p++)
        if (*p == ' ' || *p == '\t' || *p == '\n' || *p == '\r')
            *p = '_';
    return s;
}

static void free_names(char **names, size_t n)
{
    for (size_t i = 0; names && i < n; i++)
        free(names[i]);
    free(names);
}

/* Material names as written: line-safe and unique, so usemtl finds the
 * newmtl it means. */
static char **material_names(const hlod_mesh *m)
{
    char **names = calloc(m->material_count ? m->material_count : 1, sizeof *names);
    if (!names)
        return NULL;
    io_strmap seen = {0};
    for (size_t i = 0; i < m->material_count; i++) {
        char *n = line_safe(m->materials[i].name, "material", i);
        if (n && io_strmap_get(&seen, n) >= 0) {
            char *u = malloc(strlen(n) + 24);
            if (u)
                sprintf(u, "%s_%zu", n, i);
            free(n);
            n = u;
        }
        if (!n || !io_strmap_put(&seen, n, (uint32_t)i)) {
            free(n);
            io_strmap_free(&seen);
            free_names(names, m->material_count);
            return NULL;
        }
        names[i] = n;
    }
    io_strmap_free(&seen);
    return names;
}

/* "dir/x.obj" -> "dir/x.mtl" */
static char *mtl_path_for(const char *obj)
{
    size_t n = strlen(obj);
    const char *slash = strrchr(obj, '/');
    const char *dot = strrchr(obj, '.');
    if (!dot || (slash && dot < slash))
        dot = obj + n;
    size_t stem = (size_t)(dot - obj);
    char *p = malloc(stem + 5);
    if (p) {
        memcpy(p, obj, stem);
        memcpy(p + stem, ".mtl", 5);
    }
    return p;
}

static int write_mtl(FILE *fp, const hlod_mesh *m, char **names, const char *dir)
{
    fprintf(fp, "# hlod material library\n");
    for (size_t i = 0; i < m->material_count; i++) {
        const hlod_material *mt = &m->materials[i];
        fprintf(fp, "\nnewmtl %s\nKd %.9g %.9g %.9g\n", names[i], mt->diffuse[0], mt->diffuse[1],
                mt->diffuse[2]);
        if (mt->diffuse[3] != 1.0f)
            fprintf(fp, "d %.9g\n", mt->diffuse[3]);
        if (mt->texture_path) {
            char *rel = io_relative_path(dir, mt->texture_path);
            if (!rel)
                return 0;
            fprintf(fp, "map_Kd %s\n", rel);
            free(rel);
        }
    }
    return 1;
}

static void write_obj_body(FILE *fp, const hlod_mesh *m, char **mat_names, const char *mtl_name)
{
    fprintf(fp, "# hlod mesh: %zu vertices, %zu triangles\n", m->vertex_count, m->tri_count);
    if (mtl_name)
        fprintf(fp, "mtllib %s\n", mtl_name);
    for (size_t v = 0; v < m->vertex_count; v++) {
        const double *p = m->positions + 3 * v;
        fprintf(fp, "v %.17g %.17g %.17g\n", p[0], p[1], p[2]);
    }
    for (size_t v = 0; m->uvs && v < m->vertex_count; v++)
        fprintf(fp, "vt %.9g %.9g\n", m->uvs[2 * v], m->uvs[2 * v + 1]);
    for (size_t v = 0; m->normals && v < m->vertex_count; v++) {
        const float *n = m->normals + 3 * v;
        fprintf(fp, "vn %.9g %.9g %.9g\n", n[0], n[1], n[2]);
    }
    hlod_object whole = {NULL, 0, m->tri_count};
    const hlod_object *objs = m->object_count ? m->objects : &whole;
    size_t nobj = m->object_count ? m->object_count : 1;
    for (size_t o = 0; o < nobj; o++) {
        if (m->object_count) {
            char *name = line_safe(objs[o].name, "object", o);
            fprintf(fp, "o %s\n", name ? name : "object");
            free(name);
        }
        uint32_t cur = UINT32_MAX;
        for (size_t t = objs[o].first_tri; t < objs[o].first_tri + objs[o].tri_count; t++) {
            uint32_t mat = m->tri_material ? m->tri_material[t] : 0;
            if (mat_names && mat != cur) {
                fprintf(fp, "usemtl %s\n", mat_names[mat]);
                cur = mat;
            }
            const uint32_t *i = m->indices + 3 * t;
            unsigned long a = i[0] + 1ul, b = i[1] + 1ul, c = i[2] + 1ul;
            if (m->uvs && m->normals)
                fprintf(fp, "f %lu/%lu/%lu %lu/%lu/%lu %lu/%lu/%lu\n", a, a, a, b, b, b, c, c, c);
            else if (m->uvs)
                fprintf(fp, "f %lu/%lu %lu/%lu %lu/%lu\n", a, a, b, b, c, c);
            else if (m->normals)
                fprintf(fp, "f %lu//%lu %lu//%lu %lu//%lu\n", a, a, b, b, c, c);
            else
                fprintf(fp, "f %lu %lu %lu\n", a, b, c);
        }
    }
}

hlod_result io_write_obj(const char *path, const hlod_mesh *m, const hlod_logger *lg)
{
    hlod_atomic_file obj, mtl;
    memset(&mtl, 0, sizeof mtl);
    hlod_result res = hlod_atomic_open(&obj, path, lg);
    if (res)
        return res;
    char **names = NULL, *mtl_path = NULL, *dir = NULL;
    if (m->material_count) {
        names = material_names(m);
        mtl_path = mtl_path_for(path);
        dir = io_dirname(path);
        if (!names || !mtl_path || !dir) {
            res = HLOD_ERR_NOMEM;
            goto fail;
        }
        if ((res = hlod_atomic_open(&mtl, mtl_path, lg)))
            goto fail;
        if (!write_mtl(mtl.fp, m, names, dir)) {
            res = HLOD_ERR_NOMEM;
            goto fail;
        }
    }
    {
        const char *mtl_base = mtl_path ? strrchr(mtl_path, '/') : NULL;
        mtl_base = mtl_base ? mtl_base + 1 : mtl_path;
        write_obj_body(obj.fp, m, names, mtl_base);
    }
    if (!hlod_flush_sync(obj.fp) || (mtl.fp && !hlod_flush_sync(mtl.fp))) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: write failed: %s", path, strerror(errno));
        res = HLOD_ERR_IO;
        goto fail;
    }
    if (mtl.fp && (res = hlod_atomic_commit(&mtl, lg)))
        goto fail;
    if ((res = hlod_atomic_commit(&obj, lg))) {
        if (mtl_path)
            unlink(mtl_path);
        goto fail;
    }
    free_names(names, m->material_count);
    free(mtl_path);
    free(dir);
    return HLOD_OK;
fail:
    if (res == HLOD_ERR_NOMEM)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory", path);
    hlod_atomic_abort(&obj);
    hlod_atomic_abort(&mtl);
    free_names(names, m->material_count);
    free(mtl_path);
    free(dir);
    return res;
}

static void put32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static void put64(uint8_t *p, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static void putf(uint8_t *p, float f)
{
    uint32_t b;
    memcpy(&b, &f, sizeof b);
    put32(p, b);
}

static void putd(uint8_t *p, double d)
{
    uint64_t b;
    memcpy(&b, &d, sizeof b);
    put64(p, b);
}

hlod_result io_write_ply(const char *path, const hlod_mesh *m, const hlod_logger *lg)
{
    hlod_atomic_file f;
    hlod_result res = hlod_atomic_open(&f, path, lg);
    if (res)
        return res;
    fprintf(f.fp, "ply\nformat binary_little_endian 1.0\ncomment written by hlod\n");
    fprintf(f.fp, "element vertex %zu\nproperty double x\nproperty double y\nproperty double z\n",
            m->vertex_count);
    if (m->normals)
        fprintf(f.fp, "property float nx\nproperty float ny\nproperty float nz\n");
    if (m->uvs)
        fprintf(f.fp, "property float s\nproperty float t\n");
    fprintf(f.fp, "element face %zu\nproperty list uchar uint vertex_indices\nend_header\n",
            m->tri_count);
    size_t vsize = 24 + (m->normals ? 12 : 0) + (m->uvs ? 8 : 0);
    enum { BATCH = 4096 };
    uint8_t *buf = malloc(BATCH * vsize);
    if (!buf) {
        hlod_atomic_abort(&f);
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory", path);
        return HLOD_ERR_NOMEM;
    }
    for (size_t v0 = 0; v0 < m->vertex_count; v0 += BATCH) {
        size_t n = m->vertex_count - v0 < BATCH ? m->vertex_count - v0 : BATCH;
        uint8_t *p = buf;
        for (size_t v = v0; v < v0 + n; v++) {
            for (int k = 0; k < 3; k++, p += 8)
                putd(p, m->positions[3 * v + k]);
            for (int k = 0; m->normals && k < 3; k++, p += 4)
                putf(p, m->normals[3 * v + k]);
            for (int k = 0; m->uvs && k < 2; k++, p += 4)
                putf(p, m->uvs[2 * v + k]);
        }
        fwrite(buf, 1, (size_t)(p - buf), f.fp);
    }
    for (size_t t0 = 0; t0 < m->tri_count; t0 += BATCH) {
        size_t n = m->tri_count - t0 < BATCH ? m->tri_count - t0 : BATCH;
        uint8_t *p = buf; /* 13 bytes a face fit in vsize >= 24 */
        for (size_t t = t0; t < t0 + n; t++) {
            *p++ = 3;
            for (int k = 0; k < 3; k++, p += 4)
                put32(p, m->indices[3 * t + k]);
        }
        fwrite(buf, 1, (size_t)(p - buf), f.fp);
    }
    free(buf);
    return hlod_atomic_commit(&f, lg);
}

hlod_result io_write_off(const char *path, const hlod_mesh *m, const hlod_logger *lg)
{
    hlod_atomic_file f;
    hlod_result res = hlod_atomic_open(&f, path, lg);
    if (res)
        return res;
    fprintf(f.fp, "OFF\n%zu %zu 0\n", m->vertex_count, m->tri_count);
    for (size_t v = 0; v < m->vertex_count; v++) {
        const double *p = m->positions + 3 * v;
        fprintf(f.fp, "%.17g %.17g %.17g\n", p[0], p[1], p[2]);
    }
    for (size_t t = 0; t < m->tri_count; t++) {
        const uint32_t *i = m->indices + 3 * t;
        fprintf(f.fp, "3 %u %u %u\n", i[0], i[1], i[2]);
    }
    return hlod_atomic_commit(&f, lg);
}
