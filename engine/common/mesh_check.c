/*
 * Mesh validation and cleanup (see mesh.h).
 *
 * Positions are first reduced to integer ids (one hash pass over vertices:
 * vertices at the same position share an id), so a triangle's key is its
 * three ids sorted, the same for every rotation and both windings, and
 * comparing keys never touches doubles again.  The triangle table stores
 * only a 32-bit triangle index and a 32-bit hash fragment (8 bytes a slot,
 * load <= 2/3); keys are recomputed on a fragment match.  Scratch is about
 * 4-12 bytes per vertex and 13-25 bytes per triangle, all O(n).
 */
#include "hlod/mesh.h"

#include <assert.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

hlod_result hlod_mesh_validate(const hlod_mesh *m, const char *name, const hlod_logger *lg)
{
    if (!name)
        name = "mesh";
    if (!m)
        return HLOD_ERR_INVALID_ARG;
    if (m->tri_count == 0 || m->vertex_count == 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: no triangles", name);
        return HLOD_ERR_EMPTY;
    }
    if (!m->positions || !m->indices) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: mesh has no position or index array", name);
        return HLOD_ERR_FORMAT;
    }
    for (size_t v = 0; v < m->vertex_count; v++) {
        const double *p = m->positions + 3 * v;
        for (int k = 0; k < 3; k++)
            if (!isfinite(p[k])) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: vertex %zu: coordinate is %s", name, v,
                          isnan(p[k]) ? "NaN" : "infinite");
                return HLOD_ERR_NAN;
            }
        for (int k = 0; m->normals && k < 3; k++)
            if (!isfinite(m->normals[3 * v + k])) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: vertex %zu: normal is not finite", name, v);
                return HLOD_ERR_NAN;
            }
        for (int k = 0; m->uvs && k < 2; k++)
            if (!isfinite(m->uvs[2 * v + k])) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: vertex %zu: texture coordinate is not finite",
                          name, v);
                return HLOD_ERR_NAN;
            }
    }
    for (size_t t = 0; t < m->tri_count; t++)
        for (int k = 0; k < 3; k++)
            if (m->indices[3 * t + k] >= m->vertex_count) {
                hlod_logf(lg, HLOD_LOG_ERROR,
                          "%s: triangle %zu: vertex index %u out of range (%zu vertices)", name, t,
                          m->indices[3 * t + k], m->vertex_count);
                return HLOD_ERR_INDEX_RANGE;
            }
    if (m->material_count && !m->materials) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %zu materials but no material array", name,
                  m->material_count);
        return HLOD_ERR_FORMAT;
    }
    if (m->tri_material)
        for (size_t t = 0; t < m->tri_count; t++)
            if (m->tri_material[t] >= m->material_count) {
                hlod_logf(lg, HLOD_LOG_ERROR,
                          "%s: triangle %zu: material %u out of range (%zu materials)", name, t,
                          m->tri_material[t], m->material_count);
                return HLOD_ERR_INDEX_RANGE;
            }
    if (m->object_count) {
        if (!m->objects) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: %zu objects but no object array", name,
                      m->object_count);
            return HLOD_ERR_FORMAT;
        }
        size_t next = 0;
        for (size_t o = 0; o < m->object_count; o++) {
            const hlod_object *ob = m->objects + o;
            if (ob->first_tri != next || ob->tri_count > m->tri_count - next) {
                hlod_logf(lg, HLOD_LOG_ERROR,
                          "%s: object %zu (%s): triangles [%zu, +%zu) do not follow the previous "
                          "object's end %zu within %zu triangles",
                          name, o, ob->name ? ob->name : "unnamed", ob->first_tri, ob->tri_count,
                          next, m->tri_count);
                return HLOD_ERR_FORMAT;
            }
            next += ob->tri_count;
        }
        if (next != m->tri_count) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: objects cover %zu of %zu triangles", name, next,
                      m->tri_count);
            return HLOD_ERR_FORMAT;
        }
    }
    return HLOD_OK;
}

static int pos_equal(const double *a, const double *b)
{
    return a[0] == b[0] && a[1] == b[1] && a[2] == b[2];
}

static uint64_t fmix64(uint64_t h)
{
    h ^= h >> 33;
    h *= 0xff51afd7ed558ccdull;
    h ^= h >> 33;
    h *= 0xc4ceb9fe1a85ec53ull;
    return h ^ (h >> 33);
}

static uint64_t pos_hash(const double *p)
{
    uint64_t b[3];
    for (int k = 0; k < 3; k++) {
        double d = p[k] + 0.0; /* -0.0 and 0.0 compare equal, so must hash equal */
        memcpy(&b[k], &d, sizeof b[k]);
    }
    return fmix64(b[0] * 0x9e3779b97f4a7c15ull ^ b[1] * 0xbf58476d1ce4e5b9ull ^
                  b[2] * 0x94d049bb133111ebull ^ (b[0] >> 29) ^ (b[1] >> 31) ^ (b[2] >> 27));
}

/* pid[v] = the first vertex at v's position, so equal positions compare as
 * equal integers from here on. */
static uint32_t *position_ids(const hlod_mesh *m)
{
    size_t cap = 16;
    while (cap < 2 * m->vertex_count)
        cap *= 2;
    uint32_t *table = calloc(cap, sizeof *table); /* vertex + 1, 0 = empty */
    uint32_t *pid = malloc((m->vertex_count ? m->vertex_count : 1) * sizeof *pid);
    if (!table || !pid) {
        free(table);
        free(pid);
        return NULL;
    }
    for (size_t v = 0; v < m->vertex_count; v++) {
        const double *p = m->positions + 3 * v;
        size_t i = (size_t)pos_hash(p) & (cap - 1);
        while (table[i] && !pos_equal(m->positions + 3 * (size_t)(table[i] - 1), p))
            i = (i + 1) & (cap - 1);
        if (!table[i])
            table[i] = (uint32_t)v + 1;
        pid[v] = table[i] - 1;
    }
    free(table);
    return pid;
}

/* The triangle's position ids in ascending order: the duplicate key, the
 * same for every rotation and both windings. */
static void tri_key(const hlod_mesh *m, const uint32_t *pid, size_t t, uint32_t k[3])
{
    uint32_t a = pid[m->indices[3 * t]], b = pid[m->indices[3 * t + 1]];
    uint32_t c = pid[m->indices[3 * t + 2]];
    uint32_t lo = a < b ? a : b, hi = a < b ? b : a;
    k[0] = lo < c ? lo : c;
    k[2] = hi > c ? hi : c;
    k[1] = a ^ b ^ c ^ k[0] ^ k[2];
}

static int zero_area(const hlod_mesh *m, size_t t)
{
    const uint32_t *i = m->indices + 3 * t;
    const double *a = m->positions + 3 * (size_t)i[0];
    const double *b = m->positions + 3 * (size_t)i[1];
    const double *c = m->positions + 3 * (size_t)i[2];
    double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double n0 = u[1] * v[2] - u[2] * v[1];
    double n1 = u[2] * v[0] - u[0] * v[2];
    double n2 = u[0] * v[1] - u[1] * v[0];
    return n0 == 0 && n1 == 0 && n2 == 0;
}

typedef struct slot {
    uint32_t tri_plus1; /* 0 = empty */
    uint32_t hash_hi;
} slot;

/* keep[t] = 1 for each triangle that is neither degenerate nor a
 * duplicate of an earlier one in its object.  Duplicates count within an
 * object only: a triangle two objects share belongs to both blocks, and an
 * object alone cleans as it does in its file (the sharded build reads one
 * object at a time: docs/sharded-builds.md). */
static void mark_kept(const hlod_mesh *m, const uint32_t *pid, slot *table, size_t cap,
                      uint8_t *keep, size_t *ndeg, size_t *ndup)
{
    size_t obj_at = 0, obj_first = 0, at_end = m->object_count ? m->objects[0].tri_count : m->tri_count;
    for (size_t t = 0; t < m->tri_count; t++) {
        keep[t] = 0;
        while (m->object_count && t >= at_end && obj_at + 1 < m->object_count) {
            obj_first = at_end;
            at_end += m->objects[++obj_at].tri_count;
        }
        uint32_t k[3];
        tri_key(m, pid, t, k);
        /* equal ids cover both a repeated index and a repeated position */
        if (k[0] == k[1] || k[1] == k[2] || zero_area(m, t)) {
            (*ndeg)++;
            continue;
        }
        uint64_t h = fmix64(((uint64_t)k[0] << 32 | k[1]) ^ (uint64_t)k[2] * 0x9e3779b97f4a7c15ull ^
                            (uint64_t)obj_at * 0xc2b2ae3d27d4eb4full);
        uint32_t hi = (uint32_t)(h >> 32);
        size_t i = (size_t)h & (cap - 1);
        int dup = 0;
        for (; table[i].tri_plus1; i = (i + 1) & (cap - 1)) {
            if (table[i].hash_hi != hi || table[i].tri_plus1 - 1 < obj_first)
                continue;
            uint32_t o[3];
            tri_key(m, pid, table[i].tri_plus1 - 1, o);
            if (o[0] == k[0] && o[1] == k[1] && o[2] == k[2]) {
                dup = 1;
                break;
            }
        }
        if (dup) {
            (*ndup)++;
            continue;
        }
        table[i].tri_plus1 = (uint32_t)t + 1;
        table[i].hash_hi = hi;
        keep[t] = 1;
    }
}

hlod_result hlod_mesh_clean(hlod_mesh *m, size_t *degenerate, size_t *duplicate)
{
    size_t ndeg = 0, ndup = 0;
    if (degenerate)
        *degenerate = 0;
    if (duplicate)
        *duplicate = 0;
    if (!m)
        return HLOD_ERR_INVALID_ARG;
    if (m->tri_count == 0)
        return HLOD_OK;
    /* Slots store triangle indices in 32 bits, as the index buffer does. */
    assert(m->tri_count < UINT32_MAX);
    for (size_t t = 0; t < 3 * m->tri_count; t++)
        if (m->indices[t] >= m->vertex_count)
            return HLOD_ERR_INDEX_RANGE;

    uint32_t *pid = position_ids(m);
    /* Load <= 2/3: linear probes stay in one or two cache lines, and a
     * smaller table misses the cache less than a sparser one. */
    size_t cap = 16;
    while (cap < m->tri_count + m->tri_count / 2)
        cap *= 2;
    slot *table = calloc(cap, sizeof *table);
    uint8_t *keep = malloc(m->tri_count);
    if (!pid || !table || !keep) {
        free(pid);
        free(table);
        free(keep);
        return HLOD_ERR_NOMEM;
    }
    mark_kept(m, pid, table, cap, keep, &ndeg, &ndup);
    free(pid);
    free(table);

    /* Compact triangles, then recount each object's range. */
    size_t w = 0;
    size_t obj = 0, obj_end = m->object_count ? m->objects[0].tri_count : m->tri_count;
    size_t *new_count = NULL;
    if (m->object_count) {
        new_count = calloc(m->object_count, sizeof *new_count);
        if (!new_count) {
            free(keep);
            return HLOD_ERR_NOMEM;
        }
    }
    for (size_t t = 0; t < m->tri_count; t++) {
        while (m->object_count && t >= obj_end && obj + 1 < m->object_count) {
            obj++;
            obj_end += m->objects[obj].tri_count;
        }
        if (!keep[t])
            continue;
        if (w != t) {
            memcpy(m->indices + 3 * w, m->indices + 3 * t, 3 * sizeof *m->indices);
            if (m->tri_material)
                m->tri_material[w] = m->tri_material[t];
        }
        if (new_count)
            new_count[obj]++;
        w++;
    }
    free(keep);
    m->tri_count = w;
    if (m->object_count) {
        /* Objects that lost every triangle go: a block with nothing to
         * draw only costs the hierarchy builders a special case. */
        size_t ow = 0, first = 0;
        for (size_t o = 0; o < m->object_count; o++) {
            if (!new_count[o]) {
                free(m->objects[o].name);
                continue;
            }
            m->objects[ow] = m->objects[o];
            m->objects[ow].first_tri = first;
            m->objects[ow].tri_count = new_count[o];
            first += new_count[o];
            ow++;
        }
        m->object_count = ow;
        free(new_count);
        if (!ow) {
            free(m->objects);
            m->objects = NULL;
        }
    }

    /* Drop vertices no triangle uses, keeping the survivors' order. */
    uint32_t *remap = malloc((m->vertex_count ? m->vertex_count : 1) * sizeof *remap);
    if (!remap)
        return HLOD_ERR_NOMEM;
    for (size_t v = 0; v < m->vertex_count; v++)
        remap[v] = UINT32_MAX;
    for (size_t i = 0; i < 3 * m->tri_count; i++)
        remap[m->indices[i]] = 0;
    size_t vw = 0;
    for (size_t v = 0; v < m->vertex_count; v++) {
        if (remap[v] == UINT32_MAX)
            continue;
        remap[v] = (uint32_t)vw;
        if (vw != v) {
            memcpy(m->positions + 3 * vw, m->positions + 3 * v, 3 * sizeof(double));
            if (m->normals)
                memcpy(m->normals + 3 * vw, m->normals + 3 * v, 3 * sizeof(float));
            if (m->uvs)
                memcpy(m->uvs + 2 * vw, m->uvs + 2 * v, 2 * sizeof(float));
        }
        vw++;
    }
    for (size_t i = 0; i < 3 * m->tri_count; i++)
        m->indices[i] = remap[m->indices[i]];
    free(remap);
    m->vertex_count = vw;

    if (degenerate)
        *degenerate = ndeg;
    if (duplicate)
        *duplicate = ndup;
    return HLOD_OK;
}
