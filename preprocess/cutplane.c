/*
 * cutplane.c - Lakhia III-A hierarchy: simplify, cut, recurse.
 *
 * Node 0 (hlod_0) is the whole block simplified by s_0 = numTri /
 * C_desiredTri.  A node at factor s_d >= 1 is cut by C_levelFactor - 1
 * planes perpendicular to its piece's longest bounding-box axis into
 * C_levelFactor pieces; each piece becomes a child at s_{d+1} = s_d /
 * C_levelFactor, simplified from the ORIGINAL triangles of the piece (not
 * from the parent), with every vertex of a seam locked so neighbouring
 * pieces meet without cracks, at equal or different depths.  Pieces at a
 * factor <= 1 are leaves and keep the original triangles.
 *
 * Cutting: a triangle goes whole to the side of the plane its centroid is
 * on, so no triangle is ever split (a leaf holds no more triangles than
 * its source), and the seam between two pieces is made of original edges
 * whose vertices are locked on both sides.
 *
 * Cut positions are triangle-count quantiles along the axis, so pieces
 * carry equal work and a plane of level d + 1 lies strictly inside its
 * parent's slab: it never lines up with a level-d plane, and a level-d
 * seam is locked only in the subtree below it, never above.
 */
#include "build.h"

#include "hlod/simplify.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* A piece: triangles of the original block (after cuts), with locks. */
typedef struct piece {
    hlod_mesh m;        /* positions, optional uvs/normals, no objects */
    uint8_t *lock;      /* per vertex: on a seam (used on both sides of a cut) */
} piece;

static void piece_free(piece *p)
{
    hlod_mesh_free(&p->m);
    free(p->lock);
    memset(p, 0, sizeof *p);
}

/* Growable vertex/triangle arrays for building a piece. */
typedef struct builder {
    const hlod_mesh *src;
    double *pos;
    float *uv, *nrm;
    uint8_t *lock;
    size_t nv, vcap;
    uint32_t *idx;
    size_t nt, tcap;
} builder;

static int b_vertex(builder *b, const double p[3], const float *uv, const float *n, uint8_t lock)
{
    if (b->nv == b->vcap) {
        size_t nc = b->vcap ? b->vcap * 2 : 1024;
        double *np = realloc(b->pos, nc * 3 * sizeof *np);
        if (np)
            b->pos = np;
        uint8_t *nl = realloc(b->lock, nc);
        if (nl)
            b->lock = nl;
        if (!np || !nl)
            return 0;
        if (b->src->uvs) {
            float *nu = realloc(b->uv, nc * 2 * sizeof *nu);
            if (!nu)
                return 0;
            b->uv = nu;
        }
        if (b->src->normals) {
            float *nn = realloc(b->nrm, nc * 3 * sizeof *nn);
            if (!nn)
                return 0;
            b->nrm = nn;
        }
        b->vcap = nc;
    }
    memcpy(b->pos + 3 * b->nv, p, 3 * sizeof *p);
    if (b->uv)
        memcpy(b->uv + 2 * b->nv, uv, 2 * sizeof *uv);
    if (b->nrm)
        memcpy(b->nrm + 3 * b->nv, n, 3 * sizeof *n);
    b->lock[b->nv] = lock;
    return ++b->nv <= UINT32_MAX;
}

static int b_tri(builder *b, uint32_t x, uint32_t y, uint32_t z)
{
    if (b->nt == b->tcap) {
        size_t nc = b->tcap ? b->tcap * 2 : 1024;
        uint32_t *ni = realloc(b->idx, nc * 3 * sizeof *ni);
        if (!ni)
            return 0;
        b->idx = ni;
        b->tcap = nc;
    }
    b->idx[3 * b->nt] = x;
    b->idx[3 * b->nt + 1] = y;
    b->idx[3 * b->nt + 2] = z;
    b->nt++;
    return 1;
}

static void b_free(builder *b)
{
    free(b->pos);
    free(b->uv);
    free(b->nrm);
    free(b->lock);
    free(b->idx);
}

/* Moves a builder's arrays into a piece, dropping unused vertices. */
static hlod_result b_finish(builder *b, piece *out)
{
    memset(out, 0, sizeof *out);
    uint32_t *remap = malloc((b->nv ? b->nv : 1) * sizeof *remap);
    if (!remap)
        return HLOD_ERR_NOMEM;
    for (size_t v = 0; v < b->nv; v++)
        remap[v] = UINT32_MAX;
    size_t nv = 0;
    for (size_t i = 0; i < 3 * b->nt; i++)
        if (remap[b->idx[i]] == UINT32_MAX)
            remap[b->idx[i]] = 0;
    for (size_t v = 0; v < b->nv; v++)
        if (remap[v] == 0)
            remap[v] = (uint32_t)nv++;
    unsigned flags = (b->uv ? HLOD_MESH_UVS : 0) | (b->nrm ? HLOD_MESH_NORMALS : 0);
    hlod_result r = hlod_mesh_alloc(&out->m, nv, b->nt, flags);
    out->lock = malloc(nv ? nv : 1);
    if (r != HLOD_OK || !out->lock) {
        free(remap);
        piece_free(out);
        return HLOD_ERR_NOMEM;
    }
    for (size_t v = 0; v < b->nv; v++) {
        uint32_t o = remap[v];
        if (o == UINT32_MAX)
            continue;
        memcpy(out->m.positions + 3 * (size_t)o, b->pos + 3 * v, 3 * sizeof(double));
        if (b->uv)
            memcpy(out->m.uvs + 2 * (size_t)o, b->uv + 2 * v, 2 * sizeof(float));
        if (b->nrm)
            memcpy(out->m.normals + 3 * (size_t)o, b->nrm + 3 * v, 3 * sizeof(float));
        out->lock[o] = b->lock[v];
    }
    for (size_t i = 0; i < 3 * b->nt; i++)
        out->m.indices[i] = remap[b->idx[i]];
    free(remap);
    return HLOD_OK;
}

/* Splits p into `count` pieces by a label per triangle (label[t] < count).
 * Each triangle goes whole to its label's piece: no triangle is cut, so
 * the pieces hold exactly the original triangles, in p's order, and the
 * seam between two pieces is the original edges shared by triangles of
 * both.  A vertex used by two pieces or more is locked in each (as are
 * the vertices p had locked), so every node that holds a seam keeps all
 * of its vertices: two nodes at any depths on either side of a seam meet
 * on the same bits, with no T-junction and no crack. */
static hlod_result split_labels(const piece *p, const uint8_t *label, int count, piece *out)
{
    const hlod_mesh *m = &p->m;
    size_t nv = m->vertex_count;
    builder *side = calloc((size_t)count, sizeof *side);
    uint32_t *map = malloc(nv * sizeof(uint32_t) + 1);     /* v -> index in the current side */
    uint8_t *first = malloc(nv + 1);                        /* v's first label; 255: unused */
    uint8_t *shared = calloc(nv + 1, 1);                    /* v used by two labels or more */
    hlod_result r = HLOD_ERR_NOMEM;
    int made = 0;
    if (!side || !map || !first || !shared)
        goto done;
    memset(first, 255, nv);
    for (size_t t = 0; t < 3 * m->tri_count; t++) {
        uint32_t v = m->indices[t];
        uint8_t l = label[t / 3];
        if (first[v] == 255)
            first[v] = l;
        else if (first[v] != l)
            shared[v] = 1;
    }
    for (int sd = 0; sd < count; sd++) {
        builder *b = &side[sd];
        b->src = m;
        for (size_t v = 0; v < nv; v++)
            map[v] = UINT32_MAX;
        for (size_t t = 0; t < m->tri_count; t++) {
            if (label[t] != sd)
                continue;
            const uint32_t *ix = m->indices + 3 * t;
            uint32_t o[3];
            for (int k = 0; k < 3; k++) {
                uint32_t v = ix[k];
                if (map[v] == UINT32_MAX) {
                    map[v] = (uint32_t)b->nv;
                    if (!b_vertex(b, m->positions + 3 * (size_t)v,
                                  m->uvs ? m->uvs + 2 * (size_t)v : NULL,
                                  m->normals ? m->normals + 3 * (size_t)v : NULL,
                                  (uint8_t)(p->lock[v] || shared[v])))
                        goto done;
                }
                o[k] = map[v];
            }
            if (!b_tri(b, o[0], o[1], o[2]))
                goto done;
        }
        r = b_finish(b, &out[sd]);
        if (r != HLOD_OK)
            goto done;
        made++;
    }
    r = HLOD_OK;
done:
    if (r != HLOD_OK)
        for (int i = 0; i < made; i++)
            piece_free(&out[i]);
    if (side)
        for (int sd = 0; sd < count; sd++)
            b_free(&side[sd]);
    free(side);
    free(map);
    free(first);
    free(shared);
    return r;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* Labels p's triangles into `count` slabs along its longest axis, cut at
 * triangle-count quantiles of the centroids: a triangle goes to the first
 * slab whose upper cut its centroid is under. */
static hlod_result slab_labels(const piece *p, int count, uint8_t *label)
{
    double lo[3], hi[3];
    hlod_mesh_bounds(&p->m, lo, hi);
    int axis = 0;
    for (int k = 1; k < 3; k++)
        if (hi[k] - lo[k] > hi[axis] - lo[axis])
            axis = k;
    size_t nt = p->m.tri_count;
    double *cen = malloc((nt ? 2 * nt : 1) * sizeof *cen), *cut = malloc((size_t)count * sizeof *cut);
    if (!cen || !cut) {
        free(cen);
        free(cut);
        return HLOD_ERR_NOMEM;
    }
    for (size_t t = 0; t < nt; t++) {
        double s = 0;
        for (int k = 0; k < 3; k++)
            s += p->m.positions[3 * (size_t)p->m.indices[3 * t + k] + axis];
        cen[t] = cen[nt + t] = s / 3;
    }
    qsort(cen + nt, nt, sizeof *cen, cmp_double);
    for (int i = 1; i < count; i++) {
        double c = cen[nt + nt * (size_t)i / (size_t)count];
        if (!(c > lo[axis] && c < hi[axis]))
            c = lo[axis] + (hi[axis] - lo[axis]) * i / count;
        cut[i] = c;
    }
    for (size_t t = 0; t < nt; t++) {
        int l = 1;
        while (l < count && !(cen[t] < cut[l]))
            l++;
        label[t] = (uint8_t)(l - 1);
    }
    free(cen);
    free(cut);
    return HLOD_OK;
}

/* Face t's unit normal through n, its area as the result (0: degenerate). */
static double face_normal(const hlod_mesh *m, size_t t, double n[3])
{
    const double *a = m->positions + 3 * (size_t)m->indices[3 * t],
                 *b = m->positions + 3 * (size_t)m->indices[3 * t + 1],
                 *c = m->positions + 3 * (size_t)m->indices[3 * t + 2];
    double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]},
           v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    n[0] = u[1] * v[2] - u[2] * v[1];
    n[1] = u[2] * v[0] - u[0] * v[2];
    n[2] = u[0] * v[1] - u[1] * v[0];
    double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (!(len > 0) || !isfinite(len)) {
        n[0] = n[1] = n[2] = 0;
        return 0;
    }
    for (int k = 0; k < 3; k++)
        n[k] /= len;
    return len / 2;
}

/* The area-weighted mean of the unit normals nrm of the triangles with
 * label l, normalised; 0 when it vanishes. */
static int mean_axis(const double *nrm, const double *area, const uint8_t *label, int l,
                     size_t nt, double axis[3])
{
    axis[0] = axis[1] = axis[2] = 0;
    for (size_t t = 0; t < nt; t++)
        if (label[t] == l)
            for (int k = 0; k < 3; k++)
                axis[k] += area[t] * nrm[3 * t + k];
    double len = sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
    if (!(len > 0))
        return 0;
    for (int k = 0; k < 3; k++)
        axis[k] /= len;
    return 1;
}

/* Orientation classes for normal cones (--cone-split): when p's faces
 * spread more than CONE_SPLIT_DEG from their mean normal, labels them
 * into `count` classes by k-means on the unit sphere (area-weighted
 * means; seeds the mean normal, then each time the face farthest from
 * every seed; CONE_SPLIT_ROUNDS Lloyd rounds; ties to the lower index,
 * so deterministic) and returns 1.  0 with label untouched when the
 * faces are already that narrow (or all degenerate), -1 on allocation
 * failure.  The classes' normal cones are narrower than p's, so more of
 * them face away from any eye (meshlet cone culling's idea, at the tree's
 * lower levels: docs/hlod-build.md, "Methods"). */
#define CONE_SPLIT_DEG 45.0
#define CONE_SPLIT_ROUNDS 10
static int normal_labels(const piece *p, int count, uint8_t *label)
{
    size_t nt = p->m.tri_count;
    double *nrm = malloc((3 * nt + 1) * sizeof *nrm), *area = malloc((nt + 1) * sizeof *area);
    double (*seed)[3] = malloc((size_t)count * sizeof *seed);
    int res = -1;
    if (!nrm || !area || !seed)
        goto done;
    double sum[3] = {0, 0, 0};
    for (size_t t = 0; t < nt; t++) {
        area[t] = face_normal(&p->m, t, nrm + 3 * t);
        for (int k = 0; k < 3; k++)
            sum[k] += area[t] * nrm[3 * t + k];
    }
    res = 0;
    double slen = sqrt(sum[0] * sum[0] + sum[1] * sum[1] + sum[2] * sum[2]), big = 0;
    if (slen > 0) {
        for (int k = 0; k < 3; k++)
            seed[0][k] = sum[k] / slen;
        double low = 2;
        for (size_t t = 0; t < nt; t++)
            if (area[t] > 0) {
                double d = nrm[3 * t] * seed[0][0] + nrm[3 * t + 1] * seed[0][1] +
                           nrm[3 * t + 2] * seed[0][2];
                low = d < low ? d : low;
            }
        if (!(low < cos(CONE_SPLIT_DEG * M_PI / 180)))
            goto done; /* narrow already */
    } else {
        /* the normals cancel out (a closed piece): as wide as can be; the
         * largest face seeds the classes */
        for (size_t t = 0; t < nt; t++)
            if (area[t] > big) {
                big = area[t];
                memcpy(seed[0], nrm + 3 * t, sizeof seed[0]);
            }
        if (!(big > 0))
            goto done; /* every face degenerate: slabs */
    }
    for (int s = 1; s < count; s++) {
        double worst = 2;
        size_t far = 0;
        for (size_t t = 0; t < nt; t++) {
            if (!(area[t] > 0))
                continue;
            double best = -2;
            for (int j = 0; j < s; j++) {
                double d = nrm[3 * t] * seed[j][0] + nrm[3 * t + 1] * seed[j][1] +
                           nrm[3 * t + 2] * seed[j][2];
                best = d > best ? d : best;
            }
            if (best < worst) {
                worst = best;
                far = t;
            }
        }
        memcpy(seed[s], nrm + 3 * far, sizeof seed[s]);
    }
    for (int round = 0; round < CONE_SPLIT_ROUNDS; round++) {
        for (size_t t = 0; t < nt; t++) {
            int best = 0;
            double bd = -3;
            for (int j = 0; j < count; j++) {
                double d = nrm[3 * t] * seed[j][0] + nrm[3 * t + 1] * seed[j][1] +
                           nrm[3 * t + 2] * seed[j][2];
                if (d > bd) {
                    bd = d;
                    best = j;
                }
            }
            label[t] = (uint8_t)best;
        }
        for (int j = 0; j < count; j++) {
            double a[3];
            if (mean_axis(nrm, area, label, j, nt, a))
                memcpy(seed[j], a, sizeof a);
        }
    }
    res = 1;
done:
    free(nrm);
    free(area);
    free(seed);
    return res;
}

/* Cuts p into `count` pieces: along its longest axis at triangle-count
 * quantiles of the centroids, or, with cone_split, into orientation
 * classes where its faces spread wide (normal_labels). */
static hlod_result cut(const piece *p, int count, int cone_split, piece *out)
{
    uint8_t *label = malloc(p->m.tri_count + 1);
    if (!label)
        return HLOD_ERR_NOMEM;
    int byn = cone_split ? normal_labels(p, count, label) : 0;
    hlod_result r = byn < 0 ? HLOD_ERR_NOMEM : byn ? HLOD_OK : slab_labels(p, count, label);
    if (r == HLOD_OK)
        r = split_labels(p, label, count, out);
    free(label);
    return r;
}

/* Builds the node for piece p at factor s (and its subtree); returns the
 * node's index through *index. */
static hlod_result build_node(hlod_btree *t, piece *p, double s, uint32_t parent, uint32_t depth,
                              const hlod_image *tex, const hlod_build_params *bp, uint32_t *index)
{
    uint32_t id = hlod_btree_add(t);
    if (id == HLOD_BNODE_NONE)
        return HLOD_ERR_NOMEM;
    t->nodes[id].parent = parent;
    t->nodes[id].depth = depth;
    t->nodes[id].source_tris = p->m.tri_count;
    *index = id;
    hlod_result r;
    hlod_mesh node_mesh = {0};
    if (s <= 1 || p->m.tri_count <= 1) {
        /* leaf: the original triangles */
        r = hlod_mesh_copy(&node_mesh, &p->m);
    } else {
        hlod_simplify_desc d = {0};
        d.strict_texture = 1; /* HLOD nodes: no smeared texture (docs/hlod-build.md) */
        d.target_tris = (size_t)llround((double)p->m.tri_count / s);
        d.target_tris = d.target_tris ? d.target_tris : 1;
        d.vertex_lock = p->lock;
        d.logger = bp->logger;
        uint64_t t0 = hlod_thread_ns();
        r = hlod_simplify(&p->m, &d, &node_mesh, NULL);
        hlod_timing_add(bp->timing ? &bp->timing->simplify_ns : NULL, t0);
    }
    if (r != HLOD_OK)
        return r;
    double err = 0;
    uint64_t t1 = hlod_thread_ns();
    if (s > 1)
        r = hlod_node_error(&node_mesh, &p->m, &err);
    hlod_timing_add(bp->timing ? &bp->timing->error_ns : NULL, t1);
    hlod_image img = {0};
    t1 = hlod_thread_ns();
    if (r == HLOD_OK && tex)
        r = hlod_node_texture(tex, &node_mesh, s > 1 ? s : 1, &img);
    hlod_timing_add(bp->timing ? &bp->timing->node_texture_ns : NULL, t1);
    if (r != HLOD_OK) {
        hlod_mesh_free(&node_mesh);
        return r;
    }
    t->nodes[id].mesh = node_mesh;
    t->nodes[id].tex = img;
    t->nodes[id].error = err;
    if (s <= 1)
        return HLOD_OK;

    int count = (int)llround(bp->level_factor);
    piece *kids = calloc((size_t)count, sizeof *kids);
    if (!kids)
        return HLOD_ERR_NOMEM;
    /* orientation classes only within three levels of the leaves: above,
     * nodes are seen from afar and keep to space */
    int cone_split = bp->cone_split && s <= bp->level_factor;
    r = cut(p, count, cone_split, kids);
    if (r != HLOD_OK) {
        free(kids);
        return r;
    }
    double child_s = s / bp->level_factor;
    for (int i = 0; i < count && r == HLOD_OK; i++) {
        if (!kids[i].m.tri_count)
            continue;
        uint32_t cid;
        r = build_node(t, &kids[i], child_s, id, depth + 1, tex, bp, &cid);
        if (r == HLOD_OK && t->nodes[cid].error > t->nodes[id].error)
            t->nodes[id].error = t->nodes[cid].error; /* monotone up the tree */
    }
    for (int i = 0; i < count; i++)
        piece_free(&kids[i]);
    free(kids);
    return r;
}

hlod_result hlod_build_cutplane(const hlod_mesh *block, const hlod_image *tex,
                                const hlod_build_params *p, hlod_btree *out)
{
    memset(out, 0, sizeof *out);
    if (!block || !p || !(p->level_factor >= 2) || !p->desired_tris)
        return HLOD_ERR_INVALID_ARG;
    if (!block->tri_count)
        return HLOD_ERR_EMPTY;
    piece root = {0};
    hlod_result r = hlod_mesh_copy(&root.m, block);
    root.lock = calloc(block->vertex_count + 1, 1);
    if (r != HLOD_OK || !root.lock) {
        piece_free(&root);
        return HLOD_ERR_NOMEM;
    }
    /* the builder works on triangles alone: objects and materials are the
     * caller's business (one texture per block) */
    for (size_t i = 0; i < root.m.object_count; i++)
        free(root.m.objects[i].name);
    free(root.m.objects);
    root.m.objects = NULL;
    root.m.object_count = 0;
    for (size_t i = 0; i < root.m.material_count; i++) {
        free(root.m.materials[i].name);
        free(root.m.materials[i].texture_path);
    }
    free(root.m.materials);
    free(root.m.tri_material);
    root.m.materials = NULL;
    root.m.material_count = 0;
    root.m.tri_material = NULL;
    const hlod_image *t = block->uvs ? tex : NULL;
    double s0 = (double)block->tri_count / (double)p->desired_tris;
    uint32_t id;
    r = build_node(out, &root, s0 > 1 ? s0 : 1, HLOD_BNODE_NONE, 0, t, p, &id);
    piece_free(&root);
    if (r != HLOD_OK)
        hlod_btree_free(out);
    return r;
}
