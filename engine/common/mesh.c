/* hlod_mesh container: allocation, copies and measures (see mesh.h).
 * Validation and cleanup live in mesh_check.c. */
#include "hlod/mesh.h"
#include "hlod/vec3.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static char *dup_str(const char *s)
{
    if (!s)
        return NULL;
    size_t n = strlen(s) + 1;
    char *d = malloc(n);
    if (d)
        memcpy(d, s, n);
    return d;
}

void hlod_mesh_free(hlod_mesh *m)
{
    if (!m)
        return;
    free(m->positions);
    free(m->normals);
    free(m->uvs);
    free(m->indices);
    free(m->tri_material);
    for (size_t i = 0; i < m->material_count; i++) {
        free(m->materials[i].name);
        free(m->materials[i].texture_path);
    }
    free(m->materials);
    for (size_t i = 0; i < m->object_count; i++)
        free(m->objects[i].name);
    free(m->objects);
    memset(m, 0, sizeof *m);
}

hlod_result hlod_mesh_alloc(hlod_mesh *m, size_t vertex_count, size_t tri_count, unsigned flags)
{
    hlod_mesh_free(m);
    size_t vc = vertex_count ? vertex_count : 1, tc = tri_count ? tri_count : 1;
    m->positions = malloc(vc * 3 * sizeof(double));
    m->indices = malloc(tc * 3 * sizeof(uint32_t));
    if (flags & HLOD_MESH_NORMALS)
        m->normals = malloc(vc * 3 * sizeof(float));
    if (flags & HLOD_MESH_UVS)
        m->uvs = malloc(vc * 2 * sizeof(float));
    if (flags & HLOD_MESH_MATERIALS)
        m->tri_material = malloc(tc * sizeof(uint32_t));
    if (!m->positions || !m->indices || ((flags & HLOD_MESH_NORMALS) && !m->normals) ||
        ((flags & HLOD_MESH_UVS) && !m->uvs) || ((flags & HLOD_MESH_MATERIALS) && !m->tri_material)) {
        hlod_mesh_free(m);
        return HLOD_ERR_NOMEM;
    }
    m->vertex_count = vertex_count;
    m->tri_count = tri_count;
    return HLOD_OK;
}

static void *dup_mem(const void *p, size_t n)
{
    if (!p)
        return NULL;
    void *d = malloc(n ? n : 1);
    if (d)
        memcpy(d, p, n);
    return d;
}

hlod_result hlod_mesh_copy(hlod_mesh *dst, const hlod_mesh *src)
{
    hlod_mesh_free(dst);
    hlod_mesh m = {0};
    m.vertex_count = src->vertex_count;
    m.tri_count = src->tri_count;
    m.positions = dup_mem(src->positions, src->vertex_count * 3 * sizeof(double));
    m.normals = dup_mem(src->normals, src->vertex_count * 3 * sizeof(float));
    m.uvs = dup_mem(src->uvs, src->vertex_count * 2 * sizeof(float));
    m.indices = dup_mem(src->indices, src->tri_count * 3 * sizeof(uint32_t));
    m.tri_material = dup_mem(src->tri_material, src->tri_count * sizeof(uint32_t));
    int bad = (src->positions && !m.positions) || (src->normals && !m.normals) ||
              (src->uvs && !m.uvs) || (src->indices && !m.indices) ||
              (src->tri_material && !m.tri_material);
    bad |= hlod_mesh_copy_tables(&m, src, NULL) != HLOD_OK;
    if (bad) {
        hlod_mesh_free(&m);
        return HLOD_ERR_NOMEM;
    }
    *dst = m;
    return HLOD_OK;
}

hlod_result hlod_mesh_copy_tables(hlod_mesh *dst, const hlod_mesh *src, const uint8_t *kept)
{
    int bad = 0;
    if (src->material_count) {
        dst->materials = calloc(src->material_count, sizeof *dst->materials);
        if (!dst->materials)
            return HLOD_ERR_NOMEM;
        dst->material_count = src->material_count;
        for (size_t i = 0; i < src->material_count; i++) {
            dst->materials[i] = src->materials[i];
            dst->materials[i].name = dup_str(src->materials[i].name);
            dst->materials[i].texture_path = dup_str(src->materials[i].texture_path);
            bad |= (src->materials[i].name && !dst->materials[i].name) ||
                   (src->materials[i].texture_path && !dst->materials[i].texture_path);
        }
    }
    if (src->object_count) {
        dst->objects = calloc(src->object_count, sizeof *dst->objects);
        if (!dst->objects)
            return HLOD_ERR_NOMEM;
        dst->object_count = src->object_count;
        size_t at = 0;
        for (size_t i = 0; i < src->object_count; i++) {
            const hlod_object *o = &src->objects[i];
            dst->objects[i] = *o;
            dst->objects[i].name = dup_str(o->name);
            bad |= o->name && !dst->objects[i].name;
            if (!kept)
                continue;
            dst->objects[i].first_tri = at;
            for (size_t t = o->first_tri; t < o->first_tri + o->tri_count && t < src->tri_count; t++)
                at += kept[t] != 0;
            dst->objects[i].tri_count = at - dst->objects[i].first_tri;
        }
    }
    return bad ? HLOD_ERR_NOMEM : HLOD_OK;
}

int hlod_mesh_bounds(const hlod_mesh *m, double lo[3], double hi[3])
{
    if (!m->vertex_count) {
        for (int k = 0; k < 3; k++)
            lo[k] = hi[k] = 0;
        return 0;
    }
    for (int k = 0; k < 3; k++)
        lo[k] = hi[k] = m->positions[k];
    for (size_t i = 1; i < m->vertex_count; i++)
        for (int k = 0; k < 3; k++) {
            double v = m->positions[3 * i + k];
            if (v < lo[k])
                lo[k] = v;
            if (v > hi[k])
                hi[k] = v;
        }
    return 1;
}

double hlod_mesh_bbox_diag(const hlod_mesh *m)
{
    double lo[3], hi[3];
    if (!hlod_mesh_bounds(m, lo, hi))
        return 0;
    return sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                (hi[2] - lo[2]) * (hi[2] - lo[2]));
}

double hlod_mesh_area(const hlod_mesh *m)
{
    double sum = 0;
    for (size_t t = 0; t < m->tri_count; t++) {
        const double *a = m->positions + 3 * m->indices[3 * t];
        const double *b = m->positions + 3 * m->indices[3 * t + 1];
        const double *c = m->positions + 3 * m->indices[3 * t + 2];
        double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double n[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
        sum += 0.5 * sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    }
    return sum;
}

hlod_result hlod_mesh_vertex_normals(const hlod_mesh *m, float *out)
{
    double *acc = calloc(m->vertex_count * 3 + 1, sizeof *acc);
    if (!acc)
        return HLOD_ERR_NOMEM;
    for (size_t t = 0; t < m->tri_count; t++) {
        const uint32_t *ix = m->indices + 3 * t;
        const double *p0 = m->positions + 3 * (size_t)ix[0];
        double e0[3], e1[3], n[3];
        hlod_sub3(e0, m->positions + 3 * (size_t)ix[1], p0);
        hlod_sub3(e1, m->positions + 3 * (size_t)ix[2], p0);
        hlod_cross3(n, e0, e1);
        for (int c = 0; c < 3; c++)
            for (int j = 0; j < 3; j++)
                acc[3 * (size_t)ix[c] + j] += n[j];
    }
    for (size_t v = 0; v < m->vertex_count; v++) {
        const double *a = acc + 3 * v;
        double l = sqrt(hlod_dot3(a, a));
        for (int j = 0; j < 3; j++)
            out[3 * v + j] = l > 0 ? (float)(a[j] / l) : 0.0f;
    }
    free(acc);
    return HLOD_OK;
}
