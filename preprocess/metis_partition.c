/*
 * metis_partition.c - the METIS hierarchy builder, Okamoto 4.1 (build.h).
 *
 * Design:
 * - Step 1, voxels.  The block's bounding box is split octree-fashion until
 *   every voxel holds fewer than N_v triangles ("we control granularity of
 *   the voxel space so that each voxel contains fewer triangles than N_v").
 *   A box is split only along axes at least half as long as its longest
 *   one, so voxels stay roughly cubic on a flat block.  A triangle goes to
 *   the child holding most of its corners (Okamoto step 1); when all three
 *   differ, to the child holding its centroid.  Splitting stops where
 *   double precision cannot halve the box any more, so a pile of
 *   coincident triangles ends as one over-full voxel instead of looping.
 * - Step 2, graph.  One graph vertex per voxel, weighted by its triangle
 *   count.  Voxels whose triangles share a mesh position are adjacent (the
 *   paper's six face neighbours do not apply to octree voxels of different
 *   sizes).  The edge weight is the paper's inner product of the two
 *   area-weighted mean normals, mapped to 1..101 because METIS wants
 *   positive integers: METIS then prefers to cut along creases.
 * - Step 2, bisection.  A part of N_l triangles or more is cut in two with
 *   METIS_PartGraphRecursive(nparts = 2) on its induced subgraph.  METIS is
 *   wrapped so it never sees what it handles badly: one part, one vertex, a
 *   disconnected graph.  A disconnected part is split by its components
 *   (largest first onto the lighter side); only a component holding more
 *   than 2/3 of the weight goes to METIS.  A METIS error or an empty side
 *   falls back to a weighted median cut of the voxel centroids along their
 *   longest axis, so every split makes progress and the recursion ends.
 *   The parts, in creation order, are the nodes in breadth-first order.
 * - Step 3, simplification, bottom-up.  An inner node is the union of its
 *   two children's meshes (at most 2 max(N_n, N_l) triangles, much cheaper
 *   than the original triangles under a high node) simplified to N_n with
 *   every vertex it shares with the rest of the block locked (Okamoto:
 *   "simplification is not conducted on edges along boundaries"), so a node
 *   meets any neighbour at any level along the original boundary; the
 *   boundary between its own children is free.  Leaves are numbered depth
 *   first, so a node's leaves are a range [lo, hi): a position lies on the
 *   node's outer boundary iff a triangle using it sits in a leaf outside
 *   the range, which the position's smallest and largest leaf answer.
 * - Errors are certified (hlod_node_error) against the original triangles
 *   under the node, which are contiguous once triangles are sorted by leaf,
 *   then raised to the children's errors so they are monotone.
 * - Determinism: every order derives from indices and sorted keys with
 *   index tie-breaks; METIS gets a fixed seed.
 *
 * Thread safety: reentrant.  Called from build worker threads, one block
 * per call.  METIS 5.1 is almost reentrant: its random state and error
 * jump buffers are thread-local (GKlib __thread), but every call installs
 * and then restores process-wide SIGABRT/SIGTERM handlers (gk_sigtrap /
 * gk_siguntrap) from per-thread saves, so two overlapping calls can leave
 * GKlib's longjmp handler installed after both return, and a later abort()
 * would jump through a stale buffer.  The one piece of global state here is
 * therefore a mutex that serialises METIS calls; they take well under 1% of
 * a build (the simplifier and the error bound take the rest).
 */
#include "build.h"

#include "hlod/distance.h"
#include "hlod/simplify.h"

#include <assert.h>
#include <math.h>
#include <metis.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

/* Okamoto section 6 builds with N_v = 500, N_l = 4000, N_n = 2000; a zero
 * parameter selects these. */
#define DEFAULT_VOXEL_TRIS 500
#define DEFAULT_LEAF_TRIS 4000
#define DEFAULT_NODE_TRIS 2000

/* Octree depth limit: far beyond what double precision allows anyway. */
#define MAX_OCTREE_DEPTH 64

/* A component holding more than this share of a disconnected part's
 * triangles is itself bisected, so the two sides stay balanced. */
#define DOMINANT_SHARE (2.0 / 3.0)

#define NONE UINT32_MAX

/* Serialises METIS calls (see the thread-safety note above). */
static pthread_mutex_t metis_lock = PTHREAD_MUTEX_INITIALIZER;

typedef struct part {
    uint32_t *vox;        /* its voxels, ascending */
    size_t nvox;
    size_t tris;          /* original triangles in those voxels */
    uint32_t parent, child[2], depth;
    uint32_t leaf_lo, leaf_hi; /* its leaves in depth-first order */
} part;

typedef struct builder {
    const hlod_mesh *m;
    const hlod_logger *lg;
    size_t nv_max, nl, nn;
    idx_t seed;

    /* Positions welded by exact value, numbered in lexicographic order. */
    size_t npos;
    uint32_t *pid;        /* per vertex: its position */
    uint32_t *pos_rep;    /* per position: its smallest vertex */

    /* Voxels (step 1). */
    size_t nvox;
    uint32_t *tri_vox;    /* per triangle: its voxel */
    idx_t *vox_w;         /* per voxel: triangles */
    double *vox_c;        /* 3 per voxel: mean triangle centroid */

    /* Voxel graph (step 2), CSR, symmetric, no self loops. */
    idx_t *xadj, *adj, *wgt;

    /* Parts = nodes, breadth first; part 0 is the whole block. */
    part *parts;
    size_t nparts, cap;

    idx_t *map;           /* nvox scratch, -1 between uses */
    size_t metis_fallbacks, overfull_voxels;
    hlod_build_timing *timing;  /* NULL: not timed */
} builder;

/* ---------- small helpers ---------- */

static int cmp_pos(const double *a, const double *b)
{
    for (int k = 0; k < 3; k++) {
        if (a[k] < b[k])
            return -1;
        if (a[k] > b[k])
            return 1;
    }
    return 0;
}

typedef struct pkey {
    double x[3];
    uint32_t v;
} pkey;

static int cmp_pkey(const void *pa, const void *pb)
{
    const pkey *a = pa, *b = pb;
    int c = cmp_pos(a->x, b->x);
    return c ? c : (a->v > b->v) - (a->v < b->v);
}

static int cmp_u64(const void *pa, const void *pb)
{
    uint64_t a = *(const uint64_t *)pa, b = *(const uint64_t *)pb;
    return (a > b) - (a < b);
}

static int cmp_u32(const void *pa, const void *pb)
{
    uint32_t a = *(const uint32_t *)pa, b = *(const uint32_t *)pb;
    return (a > b) - (a < b);
}

static const double *vpos(const hlod_mesh *m, uint32_t v)
{
    return m->positions + 3 * (size_t)v;
}

/* The position id of x, or NONE when x is no vertex of the block. */
static uint32_t find_pos(const builder *b, const double *x)
{
    size_t lo = 0, hi = b->npos;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        int c = cmp_pos(vpos(b->m, b->pos_rep[mid]), x);
        if (c == 0)
            return (uint32_t)mid;
        if (c < 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    return NONE;
}

/* ---------- positions ---------- */

/* Welds vertices by exact position: adjacency and boundaries are about
 * where the surface is, not about UV seams or split normals. */
static hlod_result weld_positions(builder *b)
{
    const hlod_mesh *m = b->m;
    size_t nv = m->vertex_count;
    pkey *k = malloc((nv ? nv : 1) * sizeof *k);
    b->pid = malloc((nv ? nv : 1) * sizeof *b->pid);
    b->pos_rep = malloc((nv ? nv : 1) * sizeof *b->pos_rep);
    if (!k || !b->pid || !b->pos_rep) {
        free(k);
        return HLOD_ERR_NOMEM;
    }
    for (size_t v = 0; v < nv; v++) {
        memcpy(k[v].x, vpos(m, (uint32_t)v), sizeof k[v].x);
        k[v].v = (uint32_t)v;
    }
    qsort(k, nv, sizeof *k, cmp_pkey);
    b->npos = 0;
    for (size_t i = 0; i < nv; i++) {
        if (i == 0 || cmp_pos(k[i - 1].x, k[i].x) != 0)
            b->pos_rep[b->npos++] = k[i].v;
        b->pid[k[i].v] = (uint32_t)(b->npos - 1);
    }
    free(k);
    return HLOD_OK;
}

/* ---------- step 1: voxels ---------- */

typedef struct vbox {
    double lo[3], hi[3];
    size_t first, count;  /* a range of the triangle order */
    unsigned depth;
} vbox;

static unsigned child_of(const double *x, const double mid[3], unsigned axes)
{
    unsigned c = 0;
    for (int k = 0; k < 3; k++)
        if ((axes >> k & 1u) && x[k] >= mid[k])
            c |= 1u << k;
    return c;
}

static hlod_result voxelise(builder *b)
{
    const hlod_mesh *m = b->m;
    size_t nt = m->tri_count;
    hlod_result res = HLOD_ERR_NOMEM;
    uint32_t *order = malloc(nt * sizeof *order), *tmp = malloc(nt * sizeof *tmp);
    uint8_t *cof = malloc(nt);
    size_t scap = 64, sn = 0;
    vbox *stack = malloc(scap * sizeof *stack);
    b->tri_vox = malloc(nt * sizeof *b->tri_vox);
    if (!order || !tmp || !cof || !stack || !b->tri_vox)
        goto done;
    for (size_t t = 0; t < nt; t++)
        order[t] = (uint32_t)t;

    vbox root = {.first = 0, .count = nt, .depth = 0};
    hlod_mesh_bounds(m, root.lo, root.hi);
    stack[sn++] = root;
    b->nvox = 0;
    while (sn) {
        vbox box = stack[--sn];
        /* Axes worth halving: at least half the longest extent, and
         * representable (the midpoint differs from both ends). */
        double ext[3], mid[3], emax = 0;
        for (int k = 0; k < 3; k++) {
            ext[k] = box.hi[k] - box.lo[k];
            mid[k] = box.lo[k] + 0.5 * ext[k];
            emax = ext[k] > emax ? ext[k] : emax;
        }
        unsigned axes = 0;
        if (box.count >= b->nv_max && box.depth < MAX_OCTREE_DEPTH)
            for (int k = 0; k < 3; k++)
                if (ext[k] >= 0.5 * emax && ext[k] > 0 && mid[k] > box.lo[k] && mid[k] < box.hi[k])
                    axes |= 1u << k;
        if (!axes) {
            if (box.count >= b->nv_max)
                b->overfull_voxels++;
            for (size_t i = 0; i < box.count; i++)
                b->tri_vox[order[box.first + i]] = (uint32_t)b->nvox;
            b->nvox++;
            continue;
        }
        /* Okamoto step 1: the child holding most corners, else the
         * centroid's child. */
        size_t cnt[8] = {0};
        for (size_t i = 0; i < box.count; i++) {
            const uint32_t *ix = m->indices + 3 * (size_t)order[box.first + i];
            unsigned c0 = child_of(vpos(m, ix[0]), mid, axes), c1 = child_of(vpos(m, ix[1]), mid, axes),
                     c2 = child_of(vpos(m, ix[2]), mid, axes), c;
            if (c0 == c1 || c0 == c2)
                c = c0;
            else if (c1 == c2)
                c = c1;
            else {
                double g[3];
                for (int k = 0; k < 3; k++)
                    g[k] = (vpos(m, ix[0])[k] + vpos(m, ix[1])[k] + vpos(m, ix[2])[k]) / 3;
                c = child_of(g, mid, axes);
            }
            cof[i] = (uint8_t)c;
            cnt[c]++;
        }
        /* stable counting sort keeps each child's triangles ascending */
        size_t start[8], s = 0;
        for (int c = 0; c < 8; c++) {
            start[c] = s;
            s += cnt[c];
        }
        size_t fill[8];
        memcpy(fill, start, sizeof fill);
        for (size_t i = 0; i < box.count; i++)
            tmp[fill[cof[i]]++] = order[box.first + i];
        memcpy(order + box.first, tmp, box.count * sizeof *order);
        if (sn + 8 > scap) {
            vbox *ns = realloc(stack, 2 * scap * sizeof *stack);
            if (!ns)
                goto done;
            stack = ns;
            scap *= 2;
        }
        /* pushed last to first, so children are numbered in order */
        for (int c = 7; c >= 0; c--) {
            if (!cnt[c])
                continue;
            vbox ch = {.first = box.first + start[c], .count = cnt[c], .depth = box.depth + 1};
            for (int k = 0; k < 3; k++) {
                ch.lo[k] = box.lo[k];
                ch.hi[k] = box.hi[k];
                if (axes >> k & 1u) {
                    if ((unsigned)c >> k & 1u)
                        ch.lo[k] = mid[k];
                    else
                        ch.hi[k] = mid[k];
                }
            }
            stack[sn++] = ch;
        }
    }

    /* Weights and centroids (for the fallback cut). */
    b->vox_w = calloc(b->nvox, sizeof *b->vox_w);
    b->vox_c = calloc(3 * b->nvox, sizeof *b->vox_c);
    if (!b->vox_w || !b->vox_c)
        goto done;
    for (size_t t = 0; t < nt; t++) {
        uint32_t v = b->tri_vox[t];
        const uint32_t *ix = m->indices + 3 * t;
        b->vox_w[v]++;
        for (int k = 0; k < 3; k++)
            b->vox_c[3 * v + k] += (vpos(m, ix[0])[k] + vpos(m, ix[1])[k] + vpos(m, ix[2])[k]) / 3;
    }
    for (size_t v = 0; v < b->nvox; v++)
        for (int k = 0; k < 3; k++)
            b->vox_c[3 * v + k] /= (double)b->vox_w[v];
    res = HLOD_OK;
done:
    free(order);
    free(tmp);
    free(cof);
    free(stack);
    return res;
}

/* ---------- step 2: the voxel graph ---------- */

static hlod_result build_graph(builder *b)
{
    const hlod_mesh *m = b->m;
    size_t nt = m->tri_count, nc = 3 * nt;
    hlod_result res = HLOD_ERR_NOMEM;
    uint64_t *pv = malloc(nc * sizeof *pv), *e = NULL;
    double *nrm = calloc(3 * b->nvox, sizeof *nrm);
    size_t ne = 0, ecap = 0;
    if (!pv || !nrm)
        goto done;
    /* (position, voxel) incidences, sorted and unique */
    for (size_t i = 0; i < nc; i++)
        pv[i] = (uint64_t)b->pid[m->indices[i]] << 32 | b->tri_vox[i / 3];
    qsort(pv, nc, sizeof *pv, cmp_u64);
    size_t nu = 0;
    for (size_t i = 0; i < nc; i++)
        if (!nu || pv[nu - 1] != pv[i])
            pv[nu++] = pv[i];
    /* every pair of voxels meeting at a position, both directions */
    for (size_t i = 0; i < nu;) {
        size_t j = i;
        while (j < nu && pv[j] >> 32 == pv[i] >> 32)
            j++;
        size_t pairs = (j - i) * (j - i - 1);
        if (ne + pairs > ecap) {
            size_t nc2 = ecap ? 2 * ecap : 1024;
            while (nc2 < ne + pairs)
                nc2 *= 2;
            uint64_t *n2 = realloc(e, nc2 * sizeof *e);
            if (!n2)
                goto done;
            e = n2;
            ecap = nc2;
        }
        for (size_t a = i; a < j; a++)
            for (size_t c = i; c < j; c++)
                if (a != c)
                    e[ne++] = (pv[a] & 0xffffffffu) << 32 | (pv[c] & 0xffffffffu);
        i = j;
    }
    if (ne)
        qsort(e, ne, sizeof *e, cmp_u64);
    size_t nue = 0;
    for (size_t i = 0; i < ne; i++)
        if (!nue || e[nue - 1] != e[i])
            e[nue++] = e[i];

    /* Okamoto eq.: edge weight = inner product of the mean normals (area
     * weighted: the cross products' sum). */
    for (size_t t = 0; t < nt; t++) {
        const uint32_t *ix = m->indices + 3 * t;
        const double *p0 = vpos(m, ix[0]), *p1 = vpos(m, ix[1]), *p2 = vpos(m, ix[2]);
        double u[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
        double w[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
        double *n = nrm + 3 * (size_t)b->tri_vox[t];
        n[0] += u[1] * w[2] - u[2] * w[1];
        n[1] += u[2] * w[0] - u[0] * w[2];
        n[2] += u[0] * w[1] - u[1] * w[0];
    }
    for (size_t v = 0; v < b->nvox; v++) {
        double *n = nrm + 3 * v, l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for (int k = 0; k < 3; k++)
            n[k] = l > 0 ? n[k] / l : 0;
    }
    b->xadj = calloc(b->nvox + 1, sizeof *b->xadj);
    b->adj = malloc((nue ? nue : 1) * sizeof *b->adj);
    b->wgt = malloc((nue ? nue : 1) * sizeof *b->wgt);
    if (!b->xadj || !b->adj || !b->wgt)
        goto done;
    for (size_t i = 0; i < nue; i++) {
        uint32_t a = (uint32_t)(e[i] >> 32), c = (uint32_t)e[i];
        const double *na = nrm + 3 * (size_t)a, *nb = nrm + 3 * (size_t)c;
        double d = na[0] * nb[0] + na[1] * nb[1] + na[2] * nb[2];
        d = d < -1 ? -1 : d > 1 ? 1 : d;
        b->xadj[a + 1]++;
        b->adj[i] = (idx_t)c;
        b->wgt[i] = (idx_t)(1 + lround(50.0 * (1 + d)));
    }
    for (size_t v = 0; v < b->nvox; v++)
        b->xadj[v + 1] += b->xadj[v];
    res = HLOD_OK;
done:
    free(pv);
    free(e);
    free(nrm);
    return res;
}

/* The contract METIS relies on: each row strictly ascending (no
 * duplicates), no self loops, symmetric with equal weights, weights > 0. */
static int graph_ok(const builder *b)
{
    for (size_t v = 0; v < b->nvox; v++)
        for (idx_t i = b->xadj[v]; i < b->xadj[v + 1]; i++) {
            idx_t u = b->adj[i];
            if (u == (idx_t)v || b->wgt[i] <= 0 || (i > b->xadj[v] && b->adj[i - 1] >= u))
                return 0;
            int back = 0;
            for (idx_t j = b->xadj[u]; j < b->xadj[u + 1] && !back; j++)
                back = b->adj[j] == (idx_t)v && b->wgt[j] == b->wgt[i];
            if (!back)
                return 0;
        }
    return 1;
}

/* ---------- step 2: bisection ---------- */

/* The subgraph induced by sub[0..ns) (ascending ids of a graph of
 * xadj/adj/wgt), relabelled 0..ns-1.  map: the big graph's vertex count of
 * -1 entries, restored before returning. */
static int induced(const idx_t *xadj, const idx_t *adj, const idx_t *wgt, const uint32_t *sub, size_t ns,
                   idx_t *map, idx_t **oxadj, idx_t **oadj, idx_t **owgt)
{
    for (size_t j = 0; j < ns; j++)
        map[sub[j]] = (idx_t)j;
    size_t cnt = 0;
    for (size_t j = 0; j < ns; j++)
        for (idx_t i = xadj[sub[j]]; i < xadj[sub[j] + 1]; i++)
            cnt += map[adj[i]] >= 0;
    idx_t *x = malloc((ns + 1) * sizeof *x), *a = malloc((cnt ? cnt : 1) * sizeof *a),
          *w = malloc((cnt ? cnt : 1) * sizeof *w);
    if (x && a && w) {
        size_t k = 0;
        x[0] = 0;
        for (size_t j = 0; j < ns; j++) {
            for (idx_t i = xadj[sub[j]]; i < xadj[sub[j] + 1]; i++)
                if (map[adj[i]] >= 0) {
                    a[k] = map[adj[i]];
                    w[k++] = wgt[i];
                }
            x[j + 1] = (idx_t)k;
        }
    }
    for (size_t j = 0; j < ns; j++)
        map[sub[j]] = -1;
    if (!x || !a || !w) {
        free(x);
        free(a);
        free(w);
        return 0;
    }
    *oxadj = x;
    *oadj = a;
    *owgt = w;
    return 1;
}

/* METIS, wrapped: one part is answered without calling it (METIS 5.1
 * misbehaves on nparts = 1), as is a single vertex.  Returns 1 when every
 * part is non-empty. */
static int metis_split(idx_t n, idx_t *xadj, idx_t *adj, idx_t *vw, idx_t *ew, idx_t nparts, idx_t seed,
                       idx_t *part)
{
    if (nparts <= 1 || n <= 1) {
        for (idx_t i = 0; i < n; i++)
            part[i] = 0;
        return nparts <= 1 && n >= 1;
    }
    if (n < nparts)
        return 0;
    idx_t opt[METIS_NOPTIONS], ncon = 1, cut = 0;
    METIS_SetDefaultOptions(opt);
    opt[METIS_OPTION_SEED] = seed;
    opt[METIS_OPTION_NUMBERING] = 0;
    pthread_mutex_lock(&metis_lock);
    int r = METIS_PartGraphRecursive(&n, &ncon, xadj, adj, vw, NULL, ew, &nparts, NULL, NULL, opt, &cut, part);
    pthread_mutex_unlock(&metis_lock);
    if (r != METIS_OK)
        return 0;
    for (idx_t k = 0; k < nparts; k++) {
        int found = 0;
        for (idx_t i = 0; i < n && !found; i++)
            found = part[i] == k;
        if (!found)
            return 0;
    }
    for (idx_t i = 0; i < n; i++)
        if (part[i] < 0 || part[i] >= nparts)
            return 0;
    return 1;
}

typedef struct ckey {
    double c;
    uint32_t j;
} ckey;

static int cmp_ckey(const void *pa, const void *pb)
{
    const ckey *a = pa, *b = pb;
    if (a->c != b->c)
        return a->c < b->c ? -1 : 1;
    return (a->j > b->j) - (a->j < b->j);
}

/* Fallback cut: weighted median of the voxel centroids along their longest
 * axis; both sides non-empty whenever n >= 2. */
static int median_split(const builder *b, const uint32_t *vox, const uint32_t *idx, size_t n, uint8_t *side)
{
    assert(n >= 2);
    double lo[3], hi[3];
    for (int k = 0; k < 3; k++)
        lo[k] = hi[k] = b->vox_c[3 * (size_t)vox[idx[0]] + k];
    for (size_t i = 1; i < n; i++)
        for (int k = 0; k < 3; k++) {
            double c = b->vox_c[3 * (size_t)vox[idx[i]] + k];
            lo[k] = c < lo[k] ? c : lo[k];
            hi[k] = c > hi[k] ? c : hi[k];
        }
    int ax = 0;
    for (int k = 1; k < 3; k++)
        if (hi[k] - lo[k] > hi[ax] - lo[ax])
            ax = k;
    ckey *key = malloc(n * sizeof *key);
    if (!key)
        return 0;
    double total = 0;
    for (size_t i = 0; i < n; i++) {
        key[i].c = b->vox_c[3 * (size_t)vox[idx[i]] + ax];
        key[i].j = idx[i];
        total += (double)b->vox_w[vox[idx[i]]];
    }
    qsort(key, n, sizeof *key, cmp_ckey);
    size_t cut = 1;
    double acc = (double)b->vox_w[vox[key[0].j]];
    while (cut < n - 1 && 2 * acc < total)
        acc += (double)b->vox_w[vox[key[cut++].j]];
    for (size_t i = 0; i < n; i++)
        side[key[i].j] = i >= cut;
    free(key);
    return 1;
}

/* Bisects the local vertices idx[0..n) (ascending) of a part's graph
 * (lx/la/lw over vox) with METIS, else the median fallback. */
static int bisect_component(builder *b, const uint32_t *vox, const idx_t *lx, const idx_t *la, const idx_t *lw,
                            idx_t *lmap, const uint32_t *idx, size_t n, uint8_t *side)
{
    if (n == 1) {
        side[idx[0]] = 0;
        return 1;
    }
    idx_t *x = NULL, *a = NULL, *w = NULL;
    idx_t *vw = malloc(n * sizeof *vw), *pt = malloc(n * sizeof *pt);
    int ok = 0;
    if (vw && pt && induced(lx, la, lw, idx, n, lmap, &x, &a, &w)) {
        for (size_t i = 0; i < n; i++)
            vw[i] = b->vox_w[vox[idx[i]]];
        if (metis_split((idx_t)n, x, a, vw, w, 2, b->seed, pt)) {
            for (size_t i = 0; i < n; i++)
                side[idx[i]] = (uint8_t)pt[i];
            ok = 1;
        } else {
            b->metis_fallbacks++;
            ok = median_split(b, vox, idx, n, side);
        }
    }
    free(x);
    free(a);
    free(w);
    free(vw);
    free(pt);
    return ok;
}

typedef struct comp {
    double w;
    uint32_t id, first, n;  /* members: members[first .. first + n) */
} comp;

static int cmp_comp(const void *pa, const void *pb)
{
    const comp *a = pa, *b = pb;
    if (a->w != b->w)
        return a->w > b->w ? -1 : 1;
    return (a->id > b->id) - (a->id < b->id);
}

static hlod_result add_part(builder *b, uint32_t *vox, size_t n, uint32_t parent)
{
    if (b->nparts == b->cap) {
        size_t nc = b->cap ? 2 * b->cap : 16;
        part *np = realloc(b->parts, nc * sizeof *np);
        if (!np)
            return HLOD_ERR_NOMEM;
        b->parts = np;
        b->cap = nc;
    }
    part *pt = &b->parts[b->nparts++];
    memset(pt, 0, sizeof *pt);
    pt->vox = vox;
    pt->nvox = n;
    for (size_t i = 0; i < n; i++)
        pt->tris += (size_t)b->vox_w[vox[i]];
    pt->parent = parent;
    pt->depth = parent == NONE ? 0 : b->parts[parent].depth + 1;
    pt->child[0] = pt->child[1] = NONE;
    return HLOD_OK;
}

/* Splits part pi in two new parts (its children).  Okamoto step 2. */
static hlod_result bisect_part(builder *b, uint32_t pi)
{
    const uint32_t *vox = b->parts[pi].vox;
    size_t n = b->parts[pi].nvox;
    assert(n >= 2);
    hlod_result res = HLOD_ERR_NOMEM;
    idx_t *lx = NULL, *la = NULL, *lw = NULL;
    idx_t *lmap = malloc(n * sizeof *lmap);
    uint32_t *members = malloc(n * sizeof *members), *cid = malloc(n * sizeof *cid);
    uint32_t *sides[2] = {NULL, NULL};
    uint8_t *side = calloc(n, 1);
    comp *comps = NULL;
    size_t nsides[2] = {0, 0};
    if (!lmap || !members || !cid || !side || !induced(b->xadj, b->adj, b->wgt, vox, n, b->map, &lx, &la, &lw))
        goto done;
    for (size_t i = 0; i < n; i++) {
        lmap[i] = -1;
        cid[i] = NONE;
    }

    /* Connected components, breadth first from the smallest free vertex;
     * members[] lists them component by component. */
    size_t nc = 0, filled = 0;
    size_t ccap = 8;
    comps = malloc(ccap * sizeof *comps);
    if (!comps)
        goto done;
    for (size_t s = 0; s < n; s++) {
        if (cid[s] != NONE)
            continue;
        if (nc == ccap) {
            comp *c2 = realloc(comps, 2 * ccap * sizeof *comps);
            if (!c2)
                goto done;
            comps = c2;
            ccap *= 2;
        }
        comp *c = &comps[nc];
        c->id = (uint32_t)nc;
        c->first = (uint32_t)filled;
        c->w = 0;
        members[filled++] = (uint32_t)s;
        cid[s] = (uint32_t)nc;
        for (size_t q = c->first; q < filled; q++) {
            uint32_t u = members[q];
            c->w += (double)b->vox_w[vox[u]];
            for (idx_t i = lx[u]; i < lx[u + 1]; i++)
                if (cid[la[i]] == NONE) {
                    cid[la[i]] = (uint32_t)nc;
                    members[filled++] = (uint32_t)la[i];
                }
        }
        c->n = (uint32_t)(filled - c->first);
        qsort(members + c->first, c->n, sizeof *members, cmp_u32);
        nc++;
    }
    qsort(comps, nc, sizeof *comps, cmp_comp);
    double total = 0, sw[2] = {0, 0};
    for (size_t c = 0; c < nc; c++)
        total += comps[c].w;

    /* METIS on one connected graph: the only component, or a dominant one;
     * the other components then go, heaviest first, to the lighter side. */
    size_t c0 = 0;
    if (nc == 1 || comps[0].w > DOMINANT_SHARE * total) {
        const comp *c = &comps[0];
        if (!bisect_component(b, vox, lx, la, lw, lmap, members + c->first, c->n, side))
            goto done;
        for (uint32_t i = 0; i < c->n; i++)
            sw[side[members[c->first + i]]] += (double)b->vox_w[vox[members[c->first + i]]];
        c0 = 1;
    }
    for (size_t k = c0; k < nc; k++) {
        uint8_t s = sw[1] < sw[0];
        for (uint32_t i = 0; i < comps[k].n; i++)
            side[members[comps[k].first + i]] = s;
        sw[s] += comps[k].w;
    }
    for (size_t i = 0; i < n; i++)
        nsides[side[i]]++;
    if (!nsides[0] || !nsides[1]) {
        /* cannot happen with a sane METIS; guarantees progress anyway */
        b->metis_fallbacks++;
        for (size_t i = 0; i < n; i++)
            members[i] = (uint32_t)i;
        if (!median_split(b, vox, members, n, side))
            goto done;
        nsides[0] = nsides[1] = 0;
        for (size_t i = 0; i < n; i++)
            nsides[side[i]]++;
    }
    for (int s = 0; s < 2; s++) {
        sides[s] = malloc(nsides[s] * sizeof *sides[s]);
        if (!sides[s])
            goto done;
    }
    size_t fill[2] = {0, 0};
    for (size_t i = 0; i < n; i++)
        sides[side[i]][fill[side[i]]++] = vox[i];
    for (int s = 0; s < 2; s++) {
        if ((res = add_part(b, sides[s], nsides[s], pi)) != HLOD_OK)
            goto done;
        b->parts[pi].child[s] = (uint32_t)(b->nparts - 1);
        sides[s] = NULL;
    }
    res = HLOD_OK;
done:
    free(lx);
    free(la);
    free(lw);
    free(lmap);
    free(members);
    free(cid);
    free(side);
    free(comps);
    free(sides[0]);
    free(sides[1]);
    return res;
}

static hlod_result partition(builder *b)
{
    uint32_t *all = malloc(b->nvox * sizeof *all);
    if (!all)
        return HLOD_ERR_NOMEM;
    for (size_t v = 0; v < b->nvox; v++)
        all[v] = (uint32_t)v;
    hlod_result r = add_part(b, all, b->nvox, NONE);
    if (r != HLOD_OK) {
        free(all);
        return r;
    }
    /* Breadth first: part i's children are appended after every part
     * already queued, so parents precede children. */
    for (uint32_t i = 0; i < b->nparts; i++) {
        if (b->parts[i].tris < b->nl)
            continue;
        if (b->parts[i].nvox < 2) {
            hlod_logf(b->lg, HLOD_LOG_DEBUG, "metis: a voxel of %zu triangles cannot be split; kept as a leaf",
                      b->parts[i].tris);
            continue;
        }
        if ((r = bisect_part(b, i)) != HLOD_OK)
            return r;
    }
    return HLOD_OK;
}

/* ---------- step 3: meshes ---------- */

/* The triangles tris[0..n) of m with only the vertices they use, in
 * first-use order.  remap: vertex_count NONE entries, restored. */
static hlod_result submesh(const hlod_mesh *m, const uint32_t *tris, size_t n, uint32_t *remap, hlod_mesh *out)
{
    size_t nv = 0;
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < 3; c++) {
            uint32_t v = m->indices[3 * (size_t)tris[i] + c];
            if (remap[v] == NONE)
                remap[v] = (uint32_t)nv++;
        }
    unsigned flags = (m->normals ? HLOD_MESH_NORMALS : 0) | (m->uvs ? HLOD_MESH_UVS : 0);
    hlod_result r = hlod_mesh_alloc(out, nv, n, flags);
    if (r == HLOD_OK) {
        for (size_t i = 0; i < n; i++)
            for (int c = 0; c < 3; c++) {
                uint32_t v = m->indices[3 * (size_t)tris[i] + c], o = remap[v];
                out->indices[3 * i + c] = o;
                memcpy(out->positions + 3 * (size_t)o, m->positions + 3 * (size_t)v, 3 * sizeof(double));
                if (out->normals)
                    memcpy(out->normals + 3 * (size_t)o, m->normals + 3 * (size_t)v, 3 * sizeof(float));
                if (out->uvs)
                    memcpy(out->uvs + 2 * (size_t)o, m->uvs + 2 * (size_t)v, 2 * sizeof(float));
            }
    }
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < 3; c++)
            remap[m->indices[3 * (size_t)tris[i] + c]] = NONE;
    return r;
}

typedef struct ukey {
    double x[3];
    float uv[2];
    uint32_t v;
} ukey;

static int cmp_ukey(const void *pa, const void *pb)
{
    const ukey *a = pa, *b = pb;
    int c = cmp_pos(a->x, b->x);
    if (c)
        return c;
    for (int k = 0; k < 2; k++)
        if (a->uv[k] != b->uv[k])
            return a->uv[k] < b->uv[k] ? -1 : 1;
    return (a->v > b->v) - (a->v < b->v);
}

static int same_wedge(const ukey *a, const ukey *b)
{
    return !cmp_pos(a->x, b->x) && a->uv[0] == b->uv[0] && a->uv[1] == b->uv[1];
}

/* Okamoto step 2: "we connect all meshes of that node into a continuous
 * mesh patch": the children's meshes, welded where position and UV agree
 * (the simplifier's notion of one vertex), first copy's normal kept. */
static hlod_result union_mesh(const hlod_mesh *a, const hlod_mesh *b, hlod_mesh *out)
{
    size_t nv = a->vertex_count + b->vertex_count, nt = a->tri_count + b->tri_count;
    const hlod_mesh *src[2] = {a, b};
    ukey *k = malloc((nv ? nv : 1) * sizeof *k);
    uint32_t *rep = malloc((nv ? nv : 1) * sizeof *rep), *id = malloc((nv ? nv : 1) * sizeof *id);
    hlod_result r = HLOD_ERR_NOMEM;
    if (!k || !rep || !id)
        goto done;
    size_t v = 0;
    for (int s = 0; s < 2; s++)
        for (size_t i = 0; i < src[s]->vertex_count; i++, v++) {
            memcpy(k[v].x, src[s]->positions + 3 * i, sizeof k[v].x);
            k[v].uv[0] = src[s]->uvs ? src[s]->uvs[2 * i] : 0;
            k[v].uv[1] = src[s]->uvs ? src[s]->uvs[2 * i + 1] : 0;
            k[v].v = (uint32_t)v;
        }
    qsort(k, nv, sizeof *k, cmp_ukey);
    for (size_t i = 0; i < nv; i++)
        rep[k[i].v] = i && same_wedge(&k[i - 1], &k[i]) ? rep[k[i - 1].v] : k[i].v;
    /* new numbering: representatives in concatenation order */
    size_t on = 0;
    for (size_t i = 0; i < nv; i++)
        id[i] = rep[i] == i ? (uint32_t)on++ : NONE;
    unsigned flags = (a->normals ? HLOD_MESH_NORMALS : 0) | (a->uvs ? HLOD_MESH_UVS : 0);
    if ((r = hlod_mesh_alloc(out, on, nt, flags)) != HLOD_OK)
        goto done;
    v = 0;
    for (int s = 0; s < 2; s++)
        for (size_t i = 0; i < src[s]->vertex_count; i++, v++) {
            if (rep[v] != v)
                continue;
            uint32_t o = id[v];
            memcpy(out->positions + 3 * (size_t)o, src[s]->positions + 3 * i, 3 * sizeof(double));
            if (out->normals)
                memcpy(out->normals + 3 * (size_t)o, src[s]->normals + 3 * i, 3 * sizeof(float));
            if (out->uvs)
                memcpy(out->uvs + 2 * (size_t)o, src[s]->uvs + 2 * i, 2 * sizeof(float));
        }
    size_t t = 0, base = 0;
    for (int s = 0; s < 2; s++) {
        for (size_t i = 0; i < src[s]->tri_count; i++, t++)
            for (int c = 0; c < 3; c++)
                out->indices[3 * t + c] = id[rep[base + src[s]->indices[3 * i + c]]];
        base += src[s]->vertex_count;
    }
done:
    free(k);
    free(rep);
    free(id);
    return r;
}

/* Leaves numbered depth first; the triangles sorted by leaf (ascending
 * within one), so the original triangles under part i are
 * order[first[leaf_lo] .. first[leaf_hi]); and the smallest and largest
 * leaf using each position. */
typedef struct leaves {
    uint32_t n;
    uint32_t *order, *first;    /* tri_count, n + 1 */
    uint32_t *pmin, *pmax;      /* per position */
} leaves;

static hlod_result number_leaves(builder *b, leaves *L)
{
    const hlod_mesh *m = b->m;
    size_t np = b->nparts, nt = m->tri_count;
    uint32_t *cnt = malloc(np * sizeof *cnt), *vleaf = malloc(b->nvox * sizeof *vleaf);
    hlod_result res = HLOD_ERR_NOMEM;
    if (!cnt || !vleaf)
        goto done;
    for (size_t i = np; i-- > 0;) {
        const part *pt = &b->parts[i];
        cnt[i] = pt->child[0] == NONE ? 1 : cnt[pt->child[0]] + cnt[pt->child[1]];
    }
    L->n = cnt[0];
    b->parts[0].leaf_lo = 0;
    for (size_t i = 0; i < np; i++) {
        part *pt = &b->parts[i];
        pt->leaf_hi = pt->leaf_lo + cnt[i];
        if (pt->child[0] != NONE) {
            b->parts[pt->child[0]].leaf_lo = pt->leaf_lo;
            b->parts[pt->child[1]].leaf_lo = pt->leaf_lo + cnt[pt->child[0]];
        } else {
            for (size_t j = 0; j < pt->nvox; j++)
                vleaf[pt->vox[j]] = pt->leaf_lo;
        }
    }
    L->order = malloc(nt * sizeof *L->order);
    L->first = calloc((size_t)L->n + 1, sizeof *L->first);
    L->pmin = malloc(b->npos * sizeof *L->pmin);
    L->pmax = malloc(b->npos * sizeof *L->pmax);
    if (!L->order || !L->first || !L->pmin || !L->pmax)
        goto done;
    for (size_t t = 0; t < nt; t++)
        L->first[vleaf[b->tri_vox[t]] + 1]++;
    for (uint32_t l = 0; l < L->n; l++)
        L->first[l + 1] += L->first[l];
    memcpy(cnt, L->first, (size_t)L->n * sizeof *cnt); /* n <= np */
    for (size_t t = 0; t < nt; t++)
        L->order[cnt[vleaf[b->tri_vox[t]]]++] = (uint32_t)t;
    for (size_t q = 0; q < b->npos; q++) {
        L->pmin[q] = NONE;
        L->pmax[q] = 0;
    }
    for (size_t c = 0; c < 3 * nt; c++) {
        uint32_t q = b->pid[m->indices[c]], l = vleaf[b->tri_vox[c / 3]];
        L->pmin[q] = l < L->pmin[q] ? l : L->pmin[q];
        L->pmax[q] = l > L->pmax[q] ? l : L->pmax[q];
    }
    res = HLOD_OK;
done:
    free(cnt);
    free(vleaf);
    return res;
}

static void leaves_free(leaves *L)
{
    free(L->order);
    free(L->first);
    free(L->pmin);
    free(L->pmax);
}

/* Part pi's mesh (block UVs) and error; children are done.  remap: the
 * block's vertex_count NONE entries. */
static hlod_result node_mesh(builder *b, const leaves *L, uint32_t pi, hlod_mesh *meshes, double *errors,
                             uint32_t *remap)
{
    const part *pt = &b->parts[pi];
    const uint32_t *tris = L->order + L->first[pt->leaf_lo];
    size_t ntris = L->first[pt->leaf_hi] - L->first[pt->leaf_lo];
    if (pt->child[0] == NONE) {
        errors[pi] = 0; /* the original triangles themselves */
        return submesh(b->m, tris, ntris, remap, &meshes[pi]);
    }
    hlod_mesh u = {0}, orig = {0};
    uint8_t *lock = NULL;
    hlod_result r = union_mesh(&meshes[pt->child[0]], &meshes[pt->child[1]], &u);
    if (r != HLOD_OK)
        goto done;
    if (u.tri_count > b->nn) {
        /* Okamoto step 3 keeps patch boundaries: lock every vertex that is
         * an original position also used outside this node's leaves. */
        lock = calloc(u.vertex_count ? u.vertex_count : 1, 1);
        if (!lock) {
            r = HLOD_ERR_NOMEM;
            goto done;
        }
        for (size_t v = 0; v < u.vertex_count; v++) {
            uint32_t q = find_pos(b, u.positions + 3 * v);
            lock[v] = q != NONE && (L->pmin[q] < pt->leaf_lo || L->pmax[q] >= pt->leaf_hi);
        }
        hlod_simplify_desc d = {0};
        d.strict_texture = 1; /* HLOD nodes: no smeared texture (docs/hlod-build.md) */
        d.target_tris = b->nn;
        d.vertex_lock = lock;
        d.logger = b->lg;
        hlod_simplify_stats st;
        uint64_t t0 = hlod_thread_ns();
        r = hlod_simplify(&u, &d, &meshes[pi], &st);
        hlod_timing_add(b->timing ? &b->timing->simplify_ns : NULL, t0);
        if (r != HLOD_OK)
            goto done;
        if (st.tris_out > b->nn)
            hlod_logf(b->lg, HLOD_LOG_DEBUG, "metis: node %u kept %zu triangles of %zu (target %zu)", pi,
                      st.tris_out, st.tris_in, b->nn);
    } else {
        meshes[pi] = u;
        u = (hlod_mesh){0};
    }
    /* certified against the original triangles under the node, then
     * monotone: a node is never claimed better than what it replaces */
    if ((r = submesh(b->m, tris, ntris, remap, &orig)) != HLOD_OK)
        goto done;
    uint64_t t1 = hlod_thread_ns();
    r = hlod_node_error(&meshes[pi], &orig, &errors[pi]);
    hlod_timing_add(b->timing ? &b->timing->error_ns : NULL, t1);
    if (r != HLOD_OK)
        goto done;
    for (int c = 0; c < 2; c++)
        if (errors[pt->child[c]] > errors[pi])
            errors[pi] = errors[pt->child[c]];
done:
    hlod_mesh_free(&u);
    hlod_mesh_free(&orig);
    free(lock);
    return r;
}

static hlod_result check_block(const hlod_mesh *m)
{
    if (!m->tri_count)
        return HLOD_ERR_EMPTY;
    if (!m->positions || !m->indices)
        return HLOD_ERR_INVALID_ARG;
    /* METIS weights are 32-bit; vertex and position ids too */
    if (m->tri_count > (size_t)INT32_MAX / 3 || m->vertex_count >= (size_t)UINT32_MAX)
        return HLOD_ERR_INVALID_ARG;
    for (size_t i = 0; i < 3 * m->tri_count; i++)
        if (m->indices[i] >= m->vertex_count)
            return HLOD_ERR_INDEX_RANGE;
    for (size_t i = 0; i < 3 * m->vertex_count; i++)
        if (!isfinite(m->positions[i]))
            return HLOD_ERR_NAN;
    return HLOD_OK;
}

static void builder_free(builder *b)
{
    free(b->pid);
    free(b->pos_rep);
    free(b->tri_vox);
    free(b->vox_w);
    free(b->vox_c);
    free(b->xadj);
    free(b->adj);
    free(b->wgt);
    for (size_t i = 0; i < b->nparts; i++)
        free(b->parts[i].vox);
    free(b->parts);
    free(b->map);
}

/* Called from a build worker thread (one block per call). */
hlod_result hlod_build_metis(const hlod_mesh *block, const hlod_image *tex, const hlod_build_params *p,
                             hlod_btree *out)
{
    if (!block || !p || !out)
        return HLOD_ERR_INVALID_ARG;
    memset(out, 0, sizeof *out);
    hlod_result r = check_block(block);
    if (r != HLOD_OK) {
        hlod_logf(p->logger, HLOD_LOG_ERROR, "metis: invalid block (%s)", hlod_result_str(r));
        return r;
    }
    builder b = {0};
    b.m = block;
    b.lg = p->logger;
    b.timing = p->timing;
    b.nl = p->leaf_tris ? p->leaf_tris : DEFAULT_LEAF_TRIS;
    b.nn = p->node_tris ? p->node_tris : DEFAULT_NODE_TRIS;
    b.nv_max = p->voxel_tris ? p->voxel_tris : DEFAULT_VOXEL_TRIS;
    /* a voxel must fit in a leaf, or a leaf could not be reached */
    b.nv_max = b.nv_max > b.nl ? b.nl : b.nv_max;
    b.seed = (idx_t)((p->seed ^ p->seed >> 31 ^ p->seed >> 62) & 0x7fffffff);

    leaves L = {0};
    hlod_mesh *meshes = NULL;
    double *errors = NULL;
    uint32_t *remap = NULL;
    r = HLOD_ERR_NOMEM;
    if ((r = weld_positions(&b)) != HLOD_OK || (r = voxelise(&b)) != HLOD_OK || (r = build_graph(&b)) != HLOD_OK)
        goto done;
    assert(graph_ok(&b));
    r = HLOD_ERR_NOMEM;
    b.map = malloc(b.nvox * sizeof *b.map);
    if (!b.map)
        goto done;
    for (size_t v = 0; v < b.nvox; v++)
        b.map[v] = -1;
    if ((r = partition(&b)) != HLOD_OK || (r = number_leaves(&b, &L)) != HLOD_OK)
        goto done;
    if (b.overfull_voxels)
        hlod_logf(b.lg, HLOD_LOG_WARN, "metis: %zu voxels hold %zu or more triangles (coincident geometry)",
                  b.overfull_voxels, b.nv_max);
    if (b.metis_fallbacks)
        hlod_logf(b.lg, HLOD_LOG_DEBUG, "metis: %zu bisections fell back to a median cut", b.metis_fallbacks);

    r = HLOD_ERR_NOMEM;
    meshes = calloc(b.nparts, sizeof *meshes);
    errors = calloc(b.nparts, sizeof *errors);
    remap = malloc(block->vertex_count * sizeof *remap);
    if (!meshes || !errors || !remap)
        goto done;
    for (size_t v = 0; v < block->vertex_count; v++)
        remap[v] = NONE;
    /* children after parents in part order: bottom-up is backwards */
    for (size_t i = b.nparts; i-- > 0;)
        if ((r = node_mesh(&b, &L, (uint32_t)i, meshes, errors, remap)) != HLOD_OK)
            goto done;

    for (size_t i = 0; i < b.nparts; i++) {
        uint32_t k = hlod_btree_add(out);
        if (k == HLOD_BNODE_NONE) {
            r = HLOD_ERR_NOMEM;
            goto done;
        }
        assert(k == i);
        hlod_bnode *nd = &out->nodes[k];
        const part *pt = &b.parts[i];
        nd->mesh = meshes[i];
        meshes[i] = (hlod_mesh){0};
        nd->parent = pt->parent == NONE ? HLOD_BNODE_NONE : pt->parent;
        nd->depth = pt->depth;
        nd->source_tris = pt->tris;
        nd->error = errors[i];
        /* Lakhia III-A: texture shrinks with the triangle ratio; done last
         * because it rewrites the UVs the parents were built from */
        if (tex && nd->mesh.tri_count) {
            double factor = (double)nd->source_tris / (double)nd->mesh.tri_count;
            uint64_t t0 = hlod_thread_ns();
            r = hlod_node_texture(tex, &nd->mesh, factor, &nd->tex);
            hlod_timing_add(p->timing ? &p->timing->node_texture_ns : NULL, t0);
            if (r != HLOD_OK)
                goto done;
        }
    }
    hlod_logf(b.lg, HLOD_LOG_DEBUG, "metis: %zu triangles, %zu voxels, %zu nodes, %u leaves, root %zu triangles",
              block->tri_count, b.nvox, b.nparts, L.n, out->nodes[0].mesh.tri_count);
    r = HLOD_OK;
done:
    if (meshes)
        for (size_t i = 0; i < b.nparts; i++)
            hlod_mesh_free(&meshes[i]);
    free(meshes);
    free(errors);
    free(remap);
    leaves_free(&L);
    builder_free(&b);
    if (r != HLOD_OK) {
        hlod_btree_free(out);
        hlod_logf(p->logger, HLOD_LOG_ERROR, "metis: build failed (%s)", hlod_result_str(r));
    }
    return r;
}
