/*
 * sampletree.c - Klein's randomized sample tree (sampletree.h,
 * docs/sampletree.md).
 *
 * Triangles are numbered block by block (id = the block's first id + its
 * index there); every list below holds ids, so a node's triangles come out
 * grouped by block in input order, whatever the draws did.
 *
 * The tree lives in memory: per triangle its block, area and colour (17
 * bytes beside the blocks themselves), per node its list.  Payloads are
 * made and written one node at a time, in pre-order.
 */
#include "sampletree.h"

#include "build.h"
#include "build_node.h"
#include "hlod/image.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define MAX_DEPTH 40

typedef struct st_node {
    double c[3], e;          /* the cell: centre and edge */
    uint32_t *tris;          /* ids stored here */
    uint32_t n, cap;
    uint32_t *kids;          /* child node indices */
    uint32_t nkids, kids_cap;
    uint32_t parent;
    uint32_t depth;
    double area;             /* A(P(u)): every triangle of the subtree */
    uint8_t color[4];
} st_node;

typedef struct st_tex {
    const char *path;
    hlod_image img;
    int ok;
} st_tex;

typedef struct st {
    const hlod_st_block *b;
    size_t nb;
    const hlod_st_params *p;
    size_t *first;           /* per block: its first triangle id; first[nb] = total */
    size_t total;
    uint32_t *blk;           /* per id: its block */
    double *area;
    uint8_t (*rgba)[4];      /* per id: its colour */
    st_tex **tex;            /* per block: its texture slot, or NULL */
    st_tex *texes;
    size_t ntex;
    st_node *nodes;
    size_t count, cap;
    uint32_t *remap;         /* per block vertex (all blocks): its index in a payload */
    size_t *vfirst;          /* per block: its first vertex in remap */
} st;

/* ---- randomness (splitmix64: seeded per node, so any node's draws are a
 * function of the seed and that node alone) ---- */

static uint64_t splitmix(uint64_t *s)
{
    uint64_t z = (*s += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    return z ^ (z >> 31);
}

static double uniform01(uint64_t *s)
{
    return (double)(splitmix(s) >> 11) * (1.0 / 9007199254740992.0);
}

size_t hlod_st_sample_size(double area, double face, double c)
{
    double q = ceil(area / face);
    if (!(q >= 1))
        q = 1;
    double m = ceil(q * log(q) + c * q);
    return m < 1 ? 1 : m > 1e15 ? (size_t)1e15 : (size_t)m;
}

void hlod_st_draw(const double *w, size_t n, size_t m, uint64_t *state, double *cum,
                  uint32_t *out)
{
    double s = 0;
    for (size_t j = 0; j < n; j++) {
        s += w[j] > 0 ? w[j] : 0;
        cum[j] = s;
    }
    for (size_t i = 0; i < m; i++) {
        double r = uniform01(state) * s;
        size_t lo = 0, hi = n - 1;
        while (lo < hi) {   /* the first j with cum[j] > r */
            size_t mid = lo + (hi - lo) / 2;
            if (cum[mid] > r)
                hi = mid;
            else
                lo = mid + 1;
        }
        out[i] = (uint32_t)lo;
    }
}

/* ---- triangles ---- */

static const double *tri_vertex(const st *S, uint32_t id, int k)
{
    const hlod_mesh *m = S->b[S->blk[id]].mesh;
    size_t t = id - S->first[S->blk[id]];
    return &m->positions[3 * (size_t)m->indices[3 * t + k]];
}

static double tri_area(const double *a, const double *b, const double *c)
{
    double u[3], v[3];
    for (int k = 0; k < 3; k++) {
        u[k] = b[k] - a[k];
        v[k] = c[k] - a[k];
    }
    double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2],
           z = u[0] * v[1] - u[1] * v[0];
    return 0.5 * sqrt(x * x + y * y + z * z);
}

/* The texture's texel at (u, v), wrapped (v = 0 the bottom row). */
static void texel(const hlod_image *img, double u, double v, uint8_t out[4])
{
    u -= floor(u);
    v -= floor(v);
    int x = (int)(u * img->width), y = (int)((1 - v) * img->height);
    x = x < 0 ? 0 : x >= img->width ? img->width - 1 : x;
    y = y < 0 ? 0 : y >= img->height ? img->height - 1 : y;
    const uint8_t *p = img->pixels + ((size_t)y * img->width + x) * img->channels;
    switch (img->channels) {
    case 1: out[0] = out[1] = out[2] = p[0]; out[3] = 255; break;
    case 2: out[0] = out[1] = out[2] = p[0]; out[3] = p[1]; break;
    case 3: out[0] = p[0]; out[1] = p[1]; out[2] = p[2]; out[3] = 255; break;
    default: memcpy(out, p, 4); break;
    }
}

static hlod_result load_textures(st *S)
{
    S->tex = calloc(S->nb ? S->nb : 1, sizeof *S->tex);
    S->texes = calloc(S->nb ? S->nb : 1, sizeof *S->texes);
    if (!S->tex || !S->texes)
        return HLOD_ERR_NOMEM;
    for (size_t i = 0; i < S->nb; i++) {
        const char *path = S->b[i].texture;
        if (!path || !S->b[i].mesh->uvs)
            continue;
        size_t k = 0;
        while (k < S->ntex && strcmp(S->texes[k].path, path))
            k++;
        if (k == S->ntex) {
            st_tex *t = &S->texes[S->ntex++];
            t->path = path;
            t->ok = hlod_image_read(path, &t->img, S->p->lg) == HLOD_OK && t->img.width > 0;
            if (!t->ok)
                hlod_logf(S->p->lg, HLOD_LOG_WARN, "texture %s unreadable: its triangles are "
                          "built untextured", path);
        }
        if (S->texes[k].ok)
            S->tex[i] = &S->texes[k];
    }
    return HLOD_OK;
}

static hlod_result number_triangles(st *S)
{
    S->first = malloc((S->nb + 1) * sizeof *S->first);
    if (!S->first)
        return HLOD_ERR_NOMEM;
    size_t t = 0, v = 0;
    S->vfirst = malloc((S->nb + 1) * sizeof *S->vfirst);
    if (!S->vfirst)
        return HLOD_ERR_NOMEM;
    for (size_t i = 0; i < S->nb; i++) {
        S->first[i] = t;
        S->vfirst[i] = v;
        t += S->b[i].mesh->tri_count;
        v += S->b[i].mesh->vertex_count;
    }
    S->first[S->nb] = t;
    S->vfirst[S->nb] = v;
    S->total = t;
    if (!t)
        return HLOD_ERR_EMPTY;
    if (t >= UINT32_MAX)
        return HLOD_ERR_INVALID_ARG;
    S->blk = malloc(t * sizeof *S->blk);
    S->area = malloc(t * sizeof *S->area);
    S->rgba = malloc(t * sizeof *S->rgba);
    S->remap = malloc((v ? v : 1) * sizeof *S->remap);
    if (!S->blk || !S->area || !S->rgba || !S->remap)
        return HLOD_ERR_NOMEM;
    for (size_t k = 0; k < v; k++)
        S->remap[k] = UINT32_MAX;
    for (size_t i = 0; i < S->nb; i++) {
        const hlod_mesh *m = S->b[i].mesh;
        for (size_t j = 0; j < m->tri_count; j++) {
            uint32_t id = (uint32_t)(S->first[i] + j);
            S->blk[id] = (uint32_t)i;
            S->area[id] = tri_area(tri_vertex(S, id, 0), tri_vertex(S, id, 1), tri_vertex(S, id, 2));
            if (S->tex[i]) {
                /* the texture under the UV centroid */
                double u = 0, w = 0;
                for (int k = 0; k < 3; k++) {
                    uint32_t vi = m->indices[3 * j + k];
                    u += m->uvs[2 * (size_t)vi] / 3.0;
                    w += m->uvs[2 * (size_t)vi + 1] / 3.0;
                }
                texel(&S->tex[i]->img, u, w, S->rgba[id]);
            } else {
                memcpy(S->rgba[id], S->b[i].rgba, 4);
            }
        }
    }
    return HLOD_OK;
}

/* ---- the octree ---- */

static uint32_t node_add(st *S, const double c[3], double e, uint32_t parent, uint32_t depth)
{
    if (S->count == S->cap) {
        size_t nc = S->cap ? 2 * S->cap : 256;
        st_node *n = realloc(S->nodes, nc * sizeof *n);
        if (!n)
            return UINT32_MAX;
        S->nodes = n;
        S->cap = nc;
    }
    st_node *n = &S->nodes[S->count];
    memset(n, 0, sizeof *n);
    memcpy(n->c, c, sizeof n->c);
    n->e = e;
    n->parent = parent;
    n->depth = depth;
    return (uint32_t)S->count++;
}

static int list_push(uint32_t **v, uint32_t *n, uint32_t *cap, uint32_t x)
{
    if (*n == *cap) {
        uint32_t nc = *cap ? 2 * *cap : 8;
        uint32_t *t = realloc(*v, (size_t)nc * sizeof *t);
        if (!t)
            return 0;
        *v = t;
        *cap = nc;
    }
    (*v)[(*n)++] = x;
    return 1;
}

static int fits(const st *S, uint32_t id, const double c[3], double r2)
{
    for (int k = 0; k < 3; k++) {
        const double *p = tri_vertex(S, id, k);
        double d2 = 0;
        for (int a = 0; a < 3; a++)
            d2 += (p[a] - c[a]) * (p[a] - c[a]);
        if (d2 > r2)
            return 0;
    }
    return 1;
}

/* Node u's triangles ids[0..n): those that fit no child's sphere stay in
 * u; the others go down by their centroid's octant.  A cell whose
 * triangles would all go into one child and none stay is that child's
 * cell instead (no node with a single child and nothing of its own). */
static hlod_result split(st *S, uint32_t u, uint32_t *ids, size_t n, uint8_t *oct)
{
    st_node *N = &S->nodes[u];
    for (;;) {
        N = &S->nodes[u];
        if (n <= S->p->leaf_tris || N->depth >= MAX_DEPTH || !(N->e > 0))
            break;
        double h = N->e / 2, r2 = 0.75 * h * h * (1 + 1e-12); /* (h sqrt(3) / 2)^2 */
        size_t own = 0, cnt[8] = {0};
        for (size_t i = 0; i < n; i++) {
            double g[3] = {0, 0, 0};
            for (int k = 0; k < 3; k++)
                for (int a = 0; a < 3; a++)
                    g[a] += tri_vertex(S, ids[i], k)[a] / 3;
            int o = (g[0] >= N->c[0]) | (g[1] >= N->c[1]) << 1 | (g[2] >= N->c[2]) << 2;
            double cc[3];
            for (int a = 0; a < 3; a++)
                cc[a] = N->c[a] + ((o >> a) & 1 ? h / 2 : -h / 2);
            oct[i] = fits(S, ids[i], cc, r2) ? (uint8_t)o : 8;
            if (oct[i] == 8)
                own++;
            else
                cnt[o]++;
        }
        if (own == n)
            break;
        int used = 0, only = 0;
        for (int o = 0; o < 8; o++)
            if (cnt[o]) {
                used++;
                only = o;
            }
        if (used == 1 && own == 0) {
            /* the same node, one octant smaller */
            for (int a = 0; a < 3; a++)
                N->c[a] += (only >> a) & 1 ? h / 2 : -h / 2;
            N->e = h;
            continue;
        }
        /* partition ids: own first, then octant by octant (stable) */
        uint32_t *tmp = malloc(n * sizeof *tmp);
        if (!tmp)
            return HLOD_ERR_NOMEM;
        size_t start[10] = {0};
        start[0] = 0;
        start[1] = own;
        for (int o = 0; o < 8; o++)
            start[o + 2] = start[o + 1] + cnt[o];
        size_t cur[9];
        for (int o = 0; o < 9; o++)
            cur[o] = o == 0 ? 0 : start[o];
        for (size_t i = 0; i < n; i++) {
            int slot = oct[i] == 8 ? 0 : oct[i] + 1;
            tmp[cur[slot]++] = ids[i];
        }
        memcpy(ids, tmp, n * sizeof *ids);
        free(tmp);
        for (size_t i = 0; i < own; i++)
            if (!list_push(&S->nodes[u].tris, &S->nodes[u].n, &S->nodes[u].cap, ids[i]))
                return HLOD_ERR_NOMEM;
        for (int o = 0; o < 8; o++) {
            if (!cnt[o])
                continue;
            N = &S->nodes[u];
            double cc[3];
            for (int a = 0; a < 3; a++)
                cc[a] = N->c[a] + ((o >> a) & 1 ? h / 2 : -h / 2);
            uint32_t k = node_add(S, cc, h, u, N->depth + 1);
            if (k == UINT32_MAX)
                return HLOD_ERR_NOMEM;
            N = &S->nodes[u];
            if (!list_push(&N->kids, &N->nkids, &N->kids_cap, k))
                return HLOD_ERR_NOMEM;
            hlod_result r = split(S, k, ids + start[o + 1], cnt[o], oct + start[o + 1]);
            if (r != HLOD_OK)
                return r;
        }
        return HLOD_OK;
    }
    /* a leaf: every triangle stays */
    for (size_t i = 0; i < n; i++)
        if (!list_push(&S->nodes[u].tris, &S->nodes[u].n, &S->nodes[u].cap, ids[i]))
            return HLOD_ERR_NOMEM;
    return HLOD_OK;
}

/* ---- the samples (bottom-up) ---- */

typedef struct hist {
    double h[4][256];
} hist;

static void hist_add(hist *H, const uint8_t c[4], double w)
{
    for (int k = 0; k < 4; k++)
        H->h[k][c[k]] += w;
}

static void hist_median(const hist *H, uint8_t out[4])
{
    for (int k = 0; k < 4; k++) {
        double s = 0;
        for (int v = 0; v < 256; v++)
            s += H->h[k][v];
        double acc = 0;
        int v = 0;
        for (; v < 255; v++) {
            acc += H->h[k][v];
            if (acc >= 0.5 * s)
                break;
        }
        out[k] = (uint8_t)v;
    }
}

/* Node u's subtree: its children's samples first, then u's own draws;
 * H receives the subtree's colour histogram. */
static hlod_result sample(st *S, uint32_t u, hist *H)
{
    memset(H, 0, sizeof *H);
    st_node *N = &S->nodes[u];
    for (uint32_t i = 0; i < N->n; i++) {
        N->area += S->area[N->tris[i]];
        hist_add(H, S->rgba[N->tris[i]], S->area[N->tris[i]]);
    }
    if (N->nkids) {
        hist *CH = malloc(sizeof *CH);
        if (!CH)
            return HLOD_ERR_NOMEM;
        for (uint32_t k = 0; k < S->nodes[u].nkids; k++) {
            hlod_result r = sample(S, S->nodes[u].kids[k], CH);
            if (r != HLOD_OK) {
                free(CH);
                return r;
            }
            S->nodes[u].area += S->nodes[S->nodes[u].kids[k]].area;
            for (int c = 0; c < 4; c++)
                for (int v = 0; v < 256; v++)
                    H->h[c][v] += CH->h[c][v];
        }
        free(CH);
    }
    N = &S->nodes[u];
    hist_median(H, N->color);
    if (!N->nkids)
        return HLOD_OK;

    /* the pool: u's own triangles, then each child's, in order */
    size_t pool = N->n;
    for (uint32_t k = 0; k < N->nkids; k++)
        pool += S->nodes[N->kids[k]].n;
    uint32_t *pid = malloc(pool * sizeof *pid);
    uint32_t *pfrom = malloc(pool * sizeof *pfrom);   /* the child's slot, or UINT32_MAX */
    double *w = malloc(pool * sizeof *w), *cum = malloc(pool * sizeof *cum);
    size_t m = hlod_st_sample_size(N->area, N->e * N->e, S->p->c);
    size_t chunk = m < 65536 ? m : 65536;
    uint32_t *draw = malloc(chunk * sizeof *draw);
    uint8_t *chosen = calloc(pool, 1);
    hlod_result r = pid && pfrom && w && cum && draw && chosen ? HLOD_OK : HLOD_ERR_NOMEM;
    if (r == HLOD_OK) {
        size_t j = 0;
        for (uint32_t i = 0; i < N->n; i++, j++) {
            pid[j] = N->tris[i];
            pfrom[j] = UINT32_MAX;
            w[j] = S->area[pid[j]];
        }
        for (uint32_t k = 0; k < N->nkids; k++) {
            const st_node *C = &S->nodes[N->kids[k]];
            for (uint32_t i = 0; i < C->n; i++, j++) {
                pid[j] = C->tris[i];
                pfrom[j] = k;
                w[j] = S->area[pid[j]];
            }
        }
        uint64_t state = S->p->seed ^ (0x632be59bd9b4e019ull * ((uint64_t)u + 1));
        double wsum = 0;
        for (size_t i = 0; i < pool; i++)
            wsum += w[i];
        if (wsum <= 0) /* degenerate triangles only: uniform */
            for (size_t i = 0; i < pool; i++)
                w[i] = 1;
        for (size_t done = 0; done < m; done += chunk) {
            size_t now = m - done < chunk ? m - done : chunk;
            hlod_st_draw(w, pool, now, &state, cum, draw);
            for (size_t i = 0; i < now; i++)
                chosen[draw[i]] = 1;
        }
        /* the distinct triangles drawn from children move up; a child with
         * children of its own keeps one triangle (a node holds >= 1) */
        size_t base = N->n;
        for (uint32_t k = 0; k < N->nkids && r == HLOD_OK; k++) {
            size_t c0 = base, c1 = base + S->nodes[N->kids[k]].n, drawn = 0;
            base = c1;
            for (size_t i = c0; i < c1; i++)
                drawn += chosen[i];
            int spare = S->nodes[N->kids[k]].nkids && drawn == c1 - c0;
            uint32_t keep = 0;
            for (size_t i = c0; i < c1; i++) {
                int up = chosen[i];
                if (up && spare) {
                    up = 0;
                    spare = 0;
                }
                if (up && !list_push(&S->nodes[u].tris, &S->nodes[u].n, &S->nodes[u].cap, pid[i])) {
                    r = HLOD_ERR_NOMEM;
                    break;
                }
                N = &S->nodes[u];
                if (!up)
                    S->nodes[N->kids[k]].tris[keep++] = pid[i];
            }
            S->nodes[N->kids[k]].n = keep;
        }
    }
    free(pid);
    free(pfrom);
    free(w);
    free(cum);
    free(draw);
    free(chosen);
    if (r != HLOD_OK)
        return r;
    /* nothing drawn could move up (each child with children kept its one
     * triangle): the first such child gives its triangle and hands its
     * children to u */
    N = &S->nodes[u];
    if (!N->n && N->nkids) {
        uint32_t k0 = N->kids[0];
        st_node *C = &S->nodes[k0];
        if (!list_push(&N->tris, &N->n, &N->cap, C->tris[--C->n]))
            return HLOD_ERR_NOMEM;
        if (!C->n && C->nkids) {
            N = &S->nodes[u];
            C = &S->nodes[k0];
            N->kids[0] = C->kids[0];
            S->nodes[C->kids[0]].parent = u;
            for (uint32_t k = 1; k < C->nkids; k++) {
                S->nodes[C->kids[k]].parent = u;
                if (!list_push(&N->kids, &N->nkids, &N->kids_cap, C->kids[k]))
                    return HLOD_ERR_NOMEM;
                N = &S->nodes[u];
                C = &S->nodes[k0];
            }
            C->nkids = 0;
        }
    }
    /* leaves the draws emptied go */
    N = &S->nodes[u];
    uint32_t kept = 0;
    for (uint32_t k = 0; k < N->nkids; k++) {
        const st_node *C = &S->nodes[N->kids[k]];
        if (C->n || C->nkids)
            N->kids[kept++] = N->kids[k];
    }
    N->nkids = kept;
    return HLOD_OK;
}

/* ---- payloads ---- */

static int cmp_u32(const void *a, const void *b)
{
    uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
    return (x > y) - (x < y);
}

/* Converts img to 4 channels (a new image). */
static hlod_result to_rgba(const hlod_image *img, hlod_image *out)
{
    memset(out, 0, sizeof *out);
    size_t px = (size_t)img->width * img->height;
    out->pixels = malloc(px * 4 + 1);
    if (!out->pixels)
        return HLOD_ERR_NOMEM;
    out->width = img->width;
    out->height = img->height;
    out->channels = 4;
    for (size_t i = 0; i < px; i++) {
        const uint8_t *p = img->pixels + i * img->channels;
        uint8_t *q = out->pixels + 4 * i;
        switch (img->channels) {
        case 1: q[0] = q[1] = q[2] = p[0]; q[3] = 255; break;
        case 2: q[0] = q[1] = q[2] = p[0]; q[3] = p[1]; break;
        case 3: q[0] = p[0]; q[1] = p[1]; q[2] = p[2]; q[3] = 255; break;
        default: memcpy(q, p, 4); break;
        }
    }
    return HLOD_OK;
}

typedef struct group {
    size_t tri0, tri1;       /* the node's triangles [tri0, tri1) in sorted order */
    size_t v0, v1;           /* its vertices in the payload mesh */
    hlod_image atlas;        /* its texture's crop (hlod_node_texture) */
    int x, y;                /* its place in the packed atlas */
} group;

/* Shelf packing of the groups' atlases into one image (4 channels unless
 * every atlas has the same channel count); UVs remapped. */
static hlod_result pack_atlases(group *g, size_t ng, hlod_mesh *m, hlod_image *out)
{
    memset(out, 0, sizeof *out);
    if (ng == 1) {
        *out = g[0].atlas;
        memset(&g[0].atlas, 0, sizeof g[0].atlas);
        return HLOD_OK;
    }
    double area = 0;
    int maxw = 0, ch = g[0].atlas.channels, same = 1;
    for (size_t i = 0; i < ng; i++) {
        area += (double)g[i].atlas.width * g[i].atlas.height;
        maxw = g[i].atlas.width > maxw ? g[i].atlas.width : maxw;
        same &= g[i].atlas.channels == ch;
    }
    int W = (int)ceil(sqrt(area) * 1.25);
    W = W < maxw ? maxw : W;
    int x = 0, y = 0, row = 0;
    for (size_t i = 0; i < ng; i++) {   /* in order: deterministic, good enough */
        if (x + g[i].atlas.width > W) {
            y += row;
            x = row = 0;
        }
        g[i].x = x;
        g[i].y = y;
        x += g[i].atlas.width;
        row = g[i].atlas.height > row ? g[i].atlas.height : row;
    }
    int H = y + row;
    if (W > (int)HLOD_STORE_MAX_TEXTURE || H > (int)HLOD_STORE_MAX_TEXTURE)
        return HLOD_ERR_INVALID_ARG;
    int oc = same ? ch : 4;
    out->pixels = calloc((size_t)W * H * oc + 1, 1);
    if (!out->pixels)
        return HLOD_ERR_NOMEM;
    out->width = W;
    out->height = H;
    out->channels = oc;
    for (size_t i = 0; i < ng; i++) {
        hlod_image conv = {0};
        const hlod_image *a = &g[i].atlas;
        if (a->channels != oc) {
            hlod_result r = to_rgba(a, &conv);
            if (r != HLOD_OK)
                return r;
            a = &conv;
        }
        for (int row_i = 0; row_i < a->height; row_i++)
            memcpy(out->pixels + ((size_t)(g[i].y + row_i) * W + g[i].x) * oc,
                   a->pixels + (size_t)row_i * a->width * oc, (size_t)a->width * oc);
        for (size_t v = g[i].v0; v < g[i].v1; v++) {
            float *uv = &m->uvs[2 * v];
            double px = g[i].x + uv[0] * a->width, py = g[i].y + (1 - uv[1]) * a->height;
            uv[0] = (float)(px / W);
            uv[1] = (float)(1 - py / H);
        }
        hlod_image_free(&conv);
    }
    return HLOD_OK;
}

/* Node u's payload: its triangles by block, textured blocks first (each
 * block's texels cropped by hlod_node_texture, the crops packed into one
 * atlas), then the untextured ones with their colours. */
static hlod_result emit(st *S, uint32_t u, hlod_store_writer *w, hlod_store_node *out)
{
    st_node *N = &S->nodes[u];
    qsort(N->tris, N->n, sizeof *N->tris, cmp_u32);
    /* textured triangles first: stable by (untextured, id) */
    uint32_t *order = malloc((size_t)N->n * sizeof *order);
    group *g = calloc((size_t)N->n + 1, sizeof *g);
    hlod_mesh m = {0};
    uint8_t *colors = NULL;
    hlod_image tex = {0};
    hlod_result r = order && g ? HLOD_OK : HLOD_ERR_NOMEM;
    size_t ng = 0, ntex = 0, vc = 0;
    if (r == HLOD_OK) {
        size_t j = 0;
        for (int pass = 0; pass < 2; pass++)
            for (uint32_t i = 0; i < N->n; i++)
                if ((S->tex[S->blk[N->tris[i]]] != NULL) == (pass == 0))
                    order[j++] = N->tris[i];
        /* the groups (runs of one block) and their vertices */
        for (uint32_t i = 0; i < N->n; i++) {
            uint32_t id = order[i], b = S->blk[id];
            if (!ng || S->blk[order[g[ng - 1].tri0]] != b) {
                if (ng)
                    g[ng - 1].tri1 = i;
                g[ng].tri0 = i;
                ng++;
            }
            if (S->tex[b])
                ntex++;
            const hlod_mesh *bm = S->b[b].mesh;
            size_t t = id - S->first[b];
            for (int k = 0; k < 3; k++) {
                uint32_t *rv = &S->remap[S->vfirst[b] + bm->indices[3 * t + k]];
                if (*rv == UINT32_MAX)
                    *rv = (uint32_t)vc++;
            }
        }
        g[ng - 1].tri1 = N->n;
        r = hlod_mesh_alloc(&m, vc, N->n, ntex ? HLOD_MESH_UVS : 0);
    }
    if (r == HLOD_OK && !(colors = malloc(vc * 4 + 1)))
        r = HLOD_ERR_NOMEM;
    if (r == HLOD_OK) {
        size_t vdone = 0;
        for (size_t gi = 0; gi < ng; gi++) {
            g[gi].v0 = vdone;
            for (size_t i = g[gi].tri0; i < g[gi].tri1; i++) {
                uint32_t id = order[i], b = S->blk[id];
                const hlod_mesh *bm = S->b[b].mesh;
                size_t t = id - S->first[b];
                for (int k = 0; k < 3; k++) {
                    uint32_t src = bm->indices[3 * t + k], dst = S->remap[S->vfirst[b] + src];
                    m.indices[3 * i + k] = dst;
                    if (dst >= vdone) { /* first use: vertices numbered in order of use */
                        memcpy(&m.positions[3 * (size_t)dst], &bm->positions[3 * (size_t)src],
                               3 * sizeof(double));
                        if (m.uvs) {
                            m.uvs[2 * (size_t)dst] = S->tex[b] ? bm->uvs[2 * (size_t)src] : 0;
                            m.uvs[2 * (size_t)dst + 1] = S->tex[b] ? bm->uvs[2 * (size_t)src + 1] : 0;
                        }
                        memcpy(colors + 4 * (size_t)dst, S->b[b].rgba, 4);
                        vdone = dst + 1;
                    }
                }
            }
            g[gi].v1 = vdone;
        }
        /* reset the remap for the next node */
        for (uint32_t i = 0; i < N->n; i++) {
            uint32_t id = order[i], b = S->blk[id];
            const hlod_mesh *bm = S->b[b].mesh;
            size_t t = id - S->first[b];
            for (int k = 0; k < 3; k++)
                S->remap[S->vfirst[b] + bm->indices[3 * t + k]] = UINT32_MAX;
        }
    }
    /* each textured group's crop, on a view of the payload mesh */
    size_t ntg = 0;
    for (size_t gi = 0; gi < ng && r == HLOD_OK; gi++) {
        uint32_t b = S->blk[order[g[gi].tri0]];
        if (!S->tex[b])
            break;
        ntg++;
        hlod_mesh sub = {0};
        size_t nv = g[gi].v1 - g[gi].v0, nt = g[gi].tri1 - g[gi].tri0;
        r = hlod_mesh_alloc(&sub, nv, nt, HLOD_MESH_UVS);
        if (r != HLOD_OK)
            break;
        memcpy(sub.positions, &m.positions[3 * g[gi].v0], nv * 3 * sizeof(double));
        memcpy(sub.uvs, &m.uvs[2 * g[gi].v0], nv * 2 * sizeof(float));
        for (size_t i = 0; i < 3 * nt; i++)
            sub.indices[i] = m.indices[3 * g[gi].tri0 + i] - (uint32_t)g[gi].v0;
        r = hlod_node_texture(&S->tex[b]->img, &sub, 1.0, &g[gi].atlas);
        if (r == HLOD_OK)
            memcpy(&m.uvs[2 * g[gi].v0], sub.uvs, nv * 2 * sizeof(float));
        hlod_mesh_free(&sub);
    }
    if (r == HLOD_OK && ntg)
        r = pack_atlases(g, ntg, &m, &tex);
    if (r == HLOD_OK) {
        static const uint8_t white[4] = {255, 255, 255, 255};
        r = hlod_build_add_payload(w, &m, ntg ? &tex : NULL, ntex, colors, white, out);
    }
    if (r == HLOD_OK)
        out->error = N->e * sqrt(3.0);  /* the cell's diagonal */
    for (size_t gi = 0; g && gi < ng; gi++)
        hlod_image_free(&g[gi].atlas);
    hlod_image_free(&tex);
    hlod_mesh_free(&m);
    free(colors);
    free(order);
    free(g);
    return r;
}

static void st_free(st *S)
{
    for (size_t i = 0; i < S->count; i++) {
        free(S->nodes[i].tris);
        free(S->nodes[i].kids);
    }
    free(S->nodes);
    for (size_t i = 0; i < S->ntex; i++)
        hlod_image_free(&S->texes[i].img);
    free(S->texes);
    free(S->tex);
    free(S->first);
    free(S->vfirst);
    free(S->blk);
    free(S->area);
    free(S->rgba);
    free(S->remap);
}

hlod_result hlod_build_sampletree(const hlod_st_block *b, size_t nb, const hlod_st_params *p,
                                  hlod_store_writer *w, hlod_st_report *rep)
{
    st S = {0};
    S.b = b;
    S.nb = nb;
    S.p = p;
    if (rep)
        memset(rep, 0, sizeof *rep);
    hlod_result r = (b || !nb) && p && w && p->c > 0 && p->leaf_tris >= 1 ? HLOD_OK
                                                                          : HLOD_ERR_INVALID_ARG;
    if (r == HLOD_OK)
        r = load_textures(&S);
    if (r == HLOD_OK)
        r = number_triangles(&S);
    uint32_t *ids = NULL;
    uint8_t *oct = NULL;
    if (r == HLOD_OK) {
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (size_t i = 0; i < nb; i++) {
            double l[3], h[3];
            if (!b[i].mesh->tri_count || !hlod_mesh_bounds(b[i].mesh, l, h))
                continue;
            for (int a = 0; a < 3; a++) {
                lo[a] = fmin(lo[a], l[a]);
                hi[a] = fmax(hi[a], h[a]);
            }
        }
        double c[3], e = 0;
        for (int a = 0; a < 3; a++) {
            c[a] = 0.5 * (lo[a] + hi[a]);
            e = fmax(e, hi[a] - lo[a]);
        }
        e = e > 0 ? e * (1 + 1e-9) : 1;
        ids = malloc(S.total * sizeof *ids);
        oct = malloc(S.total);
        r = ids && oct && node_add(&S, c, e, UINT32_MAX, 0) == 0 ? HLOD_OK : HLOD_ERR_NOMEM;
    }
    if (r == HLOD_OK) {
        for (size_t i = 0; i < S.total; i++)
            ids[i] = (uint32_t)i;
        r = split(&S, 0, ids, S.total, oct);
    }
    free(ids);
    free(oct);
    hist *H = malloc(sizeof *H);
    if (r == HLOD_OK)
        r = H ? sample(&S, 0, H) : HLOD_ERR_NOMEM;
    free(H);
    /* pre-order over the kept nodes: payloads, then the tree */
    hlod_store_node *out = NULL;
    uint32_t *stack = NULL, *index = NULL, *depth_of = NULL; /* depth_of: each kept node's depth */
    uint8_t (*colors)[4] = NULL;
    size_t kept = 0;
    if (r == HLOD_OK) {
        out = calloc(S.count, sizeof *out);
        stack = malloc(S.count * sizeof *stack);
        index = malloc(S.count * sizeof *index);
        depth_of = malloc(S.count * sizeof *depth_of);
        colors = malloc(S.count * sizeof *colors);
        r = out && stack && index && depth_of && colors ? HLOD_OK : HLOD_ERR_NOMEM;
    }
    if (r == HLOD_OK) {
        size_t sp = 0;
        stack[sp++] = 0;
        while (sp && r == HLOD_OK) {
            uint32_t u = stack[--sp];
            const st_node *N = &S.nodes[u];
            index[u] = (uint32_t)kept;
            depth_of[kept] = N->parent == UINT32_MAX ? 0 : depth_of[index[N->parent]] + 1;
            r = emit(&S, u, w, &out[kept]);
            if (r != HLOD_OK)
                break;
            out[kept].parent = N->parent == UINT32_MAX ? HLOD_STORE_NO_PARENT : index[N->parent];
            out[kept].block = 0;
            memcpy(colors[kept], N->color, 4);
            if (rep) {
                rep->tris += N->n;
                if (N->nkids)
                    rep->tris_inner += N->n;
                else
                    rep->tris_leaf += N->n;
                rep->levels = depth_of[kept] + 1 > rep->levels ? depth_of[kept] + 1 : rep->levels;
            }
            kept++;
            for (uint32_t k = N->nkids; k-- > 0;)
                stack[sp++] = N->kids[k];
        }
    }
    if (r == HLOD_OK) {
        hlod_build_contain(out, kept);
        r = hlod_store_writer_set_colors(w, (const uint8_t (*)[4])colors, (uint32_t)kept);
    }
    if (r == HLOD_OK) {
        r = hlod_store_writer_finish(w, out, (uint32_t)kept, NULL);
        w = NULL;
        if (r == HLOD_OK && rep)
            rep->nodes = kept;
    }
    if (w)
        hlod_store_writer_abort(w);
    free(out);
    free(stack);
    free(index);
    free(depth_of);
    free(colors);
    st_free(&S);
    return r;
}
