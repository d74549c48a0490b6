/*
 * cluster.c - vertex clustering (Rossignac-Borrel; cluster.h).
 *
 * Vertices are keyed by their grid cell, sorted by key (ties by index, so
 * the result is deterministic), and each run of one key becomes one
 * vertex: the run's vertex nearest, in the quadric sense, to the planes of
 * every face around the run (Garland-Heckbert's error, area-weighted), so
 * a building's base corner stays on the ground and a wall's vertices in
 * the wall, where the mean would float or sink them by up to a cell.
 * Triangles are rewritten through that map; the
 * degenerate ones go, and of triangles with the same vertices in the same
 * cyclic order the first stays.
 */
#include "cluster.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct vkey {
    uint64_t key;
    uint32_t v;
} vkey;

/* Sorts k[0..n), given in increasing v, by key then v: a stable LSD radix
 * sort on the key, a byte a pass, passes where every key has the same byte
 * skipped (the order qsort by (key, v) gives, in linear time).  0 when out
 * of memory. */
static int sort_vkeys(vkey *k, size_t n)
{
    vkey *tmp = malloc((n + 1) * sizeof *tmp);
    if (!tmp)
        return 0;
    vkey *src = k, *dst = tmp;
    for (int shift = 0; shift < 64; shift += 8) {
        size_t count[257] = {0};
        for (size_t i = 0; i < n; i++)
            count[((src[i].key >> shift) & 255) + 1]++;
        int one = 0;
        for (int b = 1; b <= 256; b++)
            one |= count[b] == n;
        if (one)
            continue; /* every key has this byte: the order stands */
        for (int b = 0; b < 256; b++)
            count[b + 1] += count[b];
        for (size_t i = 0; i < n; i++)
            dst[count[(src[i].key >> shift) & 255]++] = src[i];
        vkey *t = src;
        src = dst;
        dst = t;
    }
    if (src != k)
        memcpy(k, src, n * sizeof *k);
    free(tmp);
    return 1;
}

typedef struct tkey {
    uint32_t v[3];      /* rotated so the smallest index is first */
    uint32_t t;
} tkey;

static int cmp_tkey(const void *pa, const void *pb)
{
    const tkey *a = pa, *b = pb;
    for (int k = 0; k < 3; k++)
        if (a->v[k] != b->v[k])
            return a->v[k] < b->v[k] ? -1 : 1;
    return (a->t > b->t) - (a->t < b->t);
}

/* Plane quadric x^T A x + 2 b.x + c, summed per cluster. */
typedef struct cquad {
    double a[6], b[3], c;
} cquad;

static double cquad_eval(const cquad *q, const double *p)
{
    double x = p[0], y = p[1], z = p[2];
    return q->a[0] * x * x + 2 * q->a[1] * x * y + 2 * q->a[2] * x * z + q->a[3] * y * y +
           2 * q->a[4] * y * z + q->a[5] * z * z + 2 * (q->b[0] * x + q->b[1] * y + q->b[2] * z) + q->c;
}

/* Moves each cluster's position to its member vertex of least quadric
 * error (k: the members in key order, ties to the first). */
static hlod_result pick_representatives(const hlod_mesh *in, const uint32_t *map, size_t n,
                                        const vkey *k, double *p)
{
    cquad *q = calloc(n + 1, sizeof *q);
    double *best = malloc((n + 1) * sizeof *best);
    if (!q || !best) {
        free(q);
        free(best);
        return HLOD_ERR_NOMEM;
    }
    for (size_t t = 0; t < in->tri_count; t++) {
        const uint32_t *ix = in->indices + 3 * t;
        const double *p0 = in->positions + 3 * (size_t)ix[0], *p1 = in->positions + 3 * (size_t)ix[1],
                     *p2 = in->positions + 3 * (size_t)ix[2];
        double e1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
        double e2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        double nx = e1[1] * e2[2] - e1[2] * e2[1], ny = e1[2] * e2[0] - e1[0] * e2[2],
               nz = e1[0] * e2[1] - e1[1] * e2[0];
        double l = sqrt(nx * nx + ny * ny + nz * nz);
        if (!(l > 0))
            continue;
        double w = 0.5 * l; /* area */
        nx /= l, ny /= l, nz /= l;
        double d = -(nx * p0[0] + ny * p0[1] + nz * p0[2]);
        for (int c = 0; c < 3; c++) {
            cquad *r = &q[map[ix[c]]];
            r->a[0] += w * nx * nx, r->a[1] += w * nx * ny, r->a[2] += w * nx * nz;
            r->a[3] += w * ny * ny, r->a[4] += w * ny * nz, r->a[5] += w * nz * nz;
            r->b[0] += w * nx * d, r->b[1] += w * ny * d, r->b[2] += w * nz * d;
            r->c += w * d * d;
        }
    }
    for (size_t i = 0; i < n; i++)
        best[i] = INFINITY;
    for (size_t i = 0; i < in->vertex_count; i++) {
        uint32_t v = k[i].v, cl = map[v];
        double e = cquad_eval(&q[cl], in->positions + 3 * (size_t)v);
        if (e < best[cl]) {
            best[cl] = e;
            memcpy(p + 3 * (size_t)cl, in->positions + 3 * (size_t)v, 3 * sizeof *p);
        }
    }
    free(best);
    free(q);
    return HLOD_OK;
}

/* Cluster of every vertex (*n_out clusters, positions in pos). */
static hlod_result cluster_map(const hlod_mesh *in, double cell, const uint8_t *lock, uint32_t *map,
                               double **pos, size_t *n_out)
{
    size_t nv = in->vertex_count;
    double lo[3], hi[3];
    hlod_mesh_bounds(in, lo, hi);
    vkey *k = malloc((nv + 1) * sizeof *k);
    if (!k)
        return HLOD_ERR_NOMEM;
    /* 21 bits per axis: coarser cells when the box spans more */
    double span = fmax(hi[0] - lo[0], fmax(hi[1] - lo[1], hi[2] - lo[2]));
    if (span / cell > (double)((1u << 21) - 2))
        cell = span / (double)((1u << 21) - 2);
    for (size_t v = 0; v < nv; v++) {
        uint64_t key = 0;
        for (int a = 0; a < 3; a++) {
            double c = floor((in->positions[3 * v + a] - lo[a]) / cell);
            key = (key << 21) | (uint64_t)(c < 0 ? 0 : c);
        }
        /* a locked vertex is a cluster of its own (keys past every cell's) */
        k[v] = (vkey){lock && lock[v] ? (1ull << 63) | v : key, (uint32_t)v};
    }
    if (!sort_vkeys(k, nv)) {
        free(k);
        return HLOD_ERR_NOMEM;
    }
    double *p = malloc((nv + 1) * 3 * sizeof *p);
    if (!p) {
        free(k);
        return HLOD_ERR_NOMEM;
    }
    size_t n = 0;
    for (size_t i = 0; i < nv;) {
        size_t j = i;
        double sum[3] = {0, 0, 0};
        for (; j < nv && k[j].key == k[i].key; j++) {
            map[k[j].v] = (uint32_t)n;
            for (int a = 0; a < 3; a++)
                sum[a] += in->positions[3 * (size_t)k[j].v + a];
        }
        for (int a = 0; a < 3; a++)
            p[3 * n + a] = sum[a] / (double)(j - i);
        n++;
        i = j;
    }
    hlod_result r = pick_representatives(in, map, n, k, p);
    free(k);
    if (r != HLOD_OK) {
        free(p);
        return r;
    }
    *pos = p;
    *n_out = n;
    return HLOD_OK;
}

/* Which triangles survive: not degenerate, the first of their duplicates. */
static hlod_result surviving(const hlod_mesh *in, const uint32_t *map, uint8_t *keep)
{
    size_t nt = in->tri_count, m = 0;
    tkey *tk = malloc((nt + 1) * sizeof *tk);
    if (!tk)
        return HLOD_ERR_NOMEM;
    for (size_t t = 0; t < nt; t++) {
        uint32_t a = map[in->indices[3 * t]], b = map[in->indices[3 * t + 1]],
                 c = map[in->indices[3 * t + 2]];
        keep[t] = 0;
        if (a == b || b == c || a == c)
            continue;
        /* rotate the smallest first: the same cyclic order gives the same key */
        uint32_t v[3] = {a, b, c};
        int r = a < b ? (a < c ? 0 : 2) : (b < c ? 1 : 2);
        tk[m++] = (tkey){{v[r], v[(r + 1) % 3], v[(r + 2) % 3]}, (uint32_t)t};
    }
    qsort(tk, m, sizeof *tk, cmp_tkey);
    for (size_t i = 0; i < m; i++)
        if (i == 0 || memcmp(tk[i].v, tk[i - 1].v, sizeof tk[i].v) != 0)
            keep[tk[i].t] = 1;
    free(tk);
    return HLOD_OK;
}

hlod_result hlod_cluster_vertices(const hlod_mesh *in, double cell, const uint8_t *lock,
                                  hlod_mesh *out)
{
    hlod_mesh_free(out);
    if (!(cell > 0 && isfinite(cell)) || !in->vertex_count)
        return HLOD_ERR_INVALID_ARG;
    uint32_t *map = malloc((in->vertex_count + 1) * sizeof *map);
    uint8_t *keep = malloc(in->tri_count + 1);
    double *pos = NULL;
    size_t n = 0;
    hlod_result r = map && keep ? cluster_map(in, cell, lock, map, &pos, &n) : HLOD_ERR_NOMEM;
    if (r == HLOD_OK)
        r = surviving(in, map, keep);
    size_t nt = 0;
    for (size_t t = 0; r == HLOD_OK && t < in->tri_count; t++)
        nt += keep[t];
    if (r == HLOD_OK)
        r = hlod_mesh_alloc(out, n, nt, in->tri_material ? HLOD_MESH_MATERIALS : 0);
    if (r == HLOD_OK) {
        memcpy(out->positions, pos, n * 3 * sizeof *pos);
        size_t k = 0;
        for (size_t t = 0; t < in->tri_count; t++) {
            if (!keep[t])
                continue;
            for (int c = 0; c < 3; c++)
                out->indices[3 * k + c] = map[in->indices[3 * t + c]];
            if (in->tri_material)
                out->tri_material[k] = in->tri_material[t];
            k++;
        }
        r = hlod_mesh_copy_tables(out, in, keep);
    }
    free(map);
    free(keep);
    free(pos);
    if (r != HLOD_OK)
        hlod_mesh_free(out);
    return r;
}
