/*
 * sampletree.c - Klein's randomized sample tree, in core or out of core
 * (sampletree.h, docs/sampletree.md).
 *
 * Triangles are records (positions in double, UVs, a texture slot, a
 * colour).  A tree holds its records and nodes whose lists index them.
 * Two kinds of tree are built: a bucket's (an octree cell's triangles,
 * split, sampled and written but for its root), and the upper tree (the
 * cells above the buckets: the triangles too big for their bucket, and
 * each bucket's root, sampled and written last).  Everything a node's
 * draws depend on is its cell (level and integer coordinates, which seed
 * its generator) and its children's lists, so the store is a function of
 * the input, the parameters and the bucket plan.
 */
#include "sampletree.h"

#include "build.h"
#include "build_node.h"
#include "cubes.h"
#include "hlod/image.h"
#include "hlod/mesh_io.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define MAX_LEVEL 40
#define NONE UINT32_MAX
#define GRID_LEVEL 6            /* the plan's count grid: 64^3 cells */
#define GRID_N (1u << GRID_LEVEL)
#define TRI_BYTES 320           /* what a triangle of a bucket costs to build, about */
#define CUBE_TRIS 6             /* a colour cube drawn: three faces, two triangles each */

/* ---- records ---- */

/* Reallocates the array *pp (any object pointer, passed by address) to n
 * elements of elem bytes; 0, *pp untouched, when out of memory.  (Object
 * pointers share one representation on every platform hlod builds on.) */
static int grow(void *pp, size_t elem, size_t n)
{
    void *old, *q;
    memcpy(&old, pp, sizeof old);
    if (!(q = realloc(old, n * elem)))
        return 0;
    memcpy(pp, &q, sizeof q);
    return 1;
}

typedef struct st_rec {
    double p[9];
    float uv[6];
    uint32_t tex;               /* texture slot, NONE: untextured */
    uint8_t rgba[4];
} st_rec;

/* A record in the spill file: positions relative to its bucket's centre. */
typedef struct st_disk {
    float p[9];
    float uv[6];
    uint32_t tex;
    uint8_t rgba[4];
} st_disk;

typedef struct st_texes {
    char **path;
    hlod_image *img;
    int *state;                 /* 0 not read, 1 read, -1 unreadable */
    size_t n, cap;
} st_texes;

static void texes_free(st_texes *t)
{
    for (size_t i = 0; i < t->n; i++) {
        free(t->path[i]);
        hlod_image_free(&t->img[i]);
    }
    free(t->path);
    free(t->img);
    free(t->state);
    memset(t, 0, sizeof *t);
}

/* The slot of path (added when new), or NONE when out of memory. */
static uint32_t tex_slot(st_texes *t, const char *path)
{
    for (size_t i = 0; i < t->n; i++)
        if (!strcmp(t->path[i], path))
            return (uint32_t)i;
    if (t->n == t->cap) {
        size_t nc = t->cap ? 2 * t->cap : 16;
        if (!grow(&t->path, sizeof *t->path, nc) || !grow(&t->img, sizeof *t->img, nc) ||
            !grow(&t->state, sizeof *t->state, nc))
            return NONE;
        t->cap = nc;
    }
    if (!(t->path[t->n] = strdup(path)))
        return NONE;
    memset(&t->img[t->n], 0, sizeof t->img[t->n]);
    t->state[t->n] = 0;
    return (uint32_t)t->n++;
}

/* Slot i's image, read at first use; NULL when it cannot be read. */
static const hlod_image *tex_get(st_texes *t, uint32_t i, const hlod_logger *lg)
{
    if (i == NONE || i >= t->n)
        return NULL;
    if (!t->state[i]) {
        int ok = hlod_image_read(t->path[i], &t->img[i], lg) == HLOD_OK && t->img[i].width > 0;
        t->state[i] = ok ? 1 : -1;
        if (!ok)
            hlod_logf(lg, HLOD_LOG_WARN, "texture %s unreadable: its triangles are built "
                      "untextured", t->path[i]);
    }
    return t->state[i] > 0 ? &t->img[i] : NULL;
}

/* The texture's texel at (u, v), wrapped (v = 0 the bottom row), as RGBA. */
static void texel(const hlod_image *img, double u, double v, uint8_t out[4])
{
    hlod_cube_texel(img->pixels, img->width, img->height, img->channels, u, v, out);
}

/* The texture slot of a triangle of m with this texture path (NONE
 * without one, or when m has no UVs): looked up once per material or
 * block, not per triangle. */
static uint32_t mesh_slot(st_texes *tx, const hlod_mesh *m, const char *texture)
{
    return texture && m->uvs ? tex_slot(tx, texture) : NONE;
}

/* Triangle t of mesh m as a record: texture slot `slot` (from mesh_slot)
 * when its image can be read (its colour the texel under the triangle's
 * UV centroid), else the colour `diffuse`. */
static void make_rec(const hlod_mesh *m, size_t t, uint32_t slot, const float diffuse[4],
                     st_texes *tx, const hlod_logger *lg, st_rec *r)
{
    memset(r, 0, sizeof *r);
    for (int k = 0; k < 3; k++)
        memcpy(&r->p[3 * k], &m->positions[3 * (size_t)m->indices[3 * t + k]], 3 * sizeof(double));
    r->tex = NONE;
    const hlod_image *img = slot != NONE ? tex_get(tx, slot, lg) : NULL;
    if (img) {
        double u = 0, v = 0;
        for (int k = 0; k < 3; k++) {
            const float *uv = &m->uvs[2 * (size_t)m->indices[3 * t + k]];
            r->uv[2 * k] = uv[0];
            r->uv[2 * k + 1] = uv[1];
            u += uv[0] / 3.0;
            v += uv[1] / 3.0;
        }
        r->tex = slot;
        texel(img, u, v, r->rgba);
    } else {
        for (int k = 0; k < 4; k++) {
            float c = diffuse[k] < 0 ? 0 : diffuse[k] > 1 ? 1 : diffuse[k];
            r->rgba[k] = (uint8_t)lrintf(c * 255);
        }
    }
}

static double rec_area(const st_rec *r)
{
    double u[3], v[3];
    for (int k = 0; k < 3; k++) {
        u[k] = r->p[3 + k] - r->p[k];
        v[k] = r->p[6 + k] - r->p[k];
    }
    double x = u[1] * v[2] - u[2] * v[1], y = u[2] * v[0] - u[0] * v[2],
           z = u[0] * v[1] - u[1] * v[0];
    return 0.5 * sqrt(x * x + y * y + z * z);
}

static void rec_centroid(const st_rec *r, double g[3])
{
    for (int a = 0; a < 3; a++)
        g[a] = (r->p[a] + r->p[3 + a] + r->p[6 + a]) / 3;
}

/* Do r's vertices lie in the sphere about c of squared radius r2? */
static int rec_fits(const st_rec *r, const double c[3], double r2)
{
    for (int k = 0; k < 3; k++) {
        double d2 = 0;
        for (int a = 0; a < 3; a++)
            d2 += (r->p[3 * k + a] - c[a]) * (r->p[3 * k + a] - c[a]);
        if (d2 > r2)
            return 0;
    }
    return 1;
}

/* The squared radius of the bounding sphere of a cell of edge e, with a
 * hair of slack for rounding. */
static double sphere_r2(double e)
{
    return 0.75 * e * e * (1 + 1e-12);
}

/* ---- randomness (splitmix64, seeded per cell) ---- */

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

/* ---- trees ---- */

typedef struct hist {
    double h[4][256];
} hist;

typedef struct st_cell {
    double c[3], e;             /* centre and edge */
    uint32_t level;             /* octree level: the root cube's is 0 */
    uint64_t ix, iy, iz;        /* integer coordinates at that level */
} st_cell;

typedef struct st_node {
    st_cell cell;
    uint32_t *tris;             /* record indices */
    uint32_t n, cap;
    uint32_t *kids;             /* node indices in the same tree */
    uint32_t nkids, kcap;
    uint32_t *gkids;            /* children written already (their out indices) */
    uint32_t ngk, gkcap;
    uint32_t parent;            /* node index, NONE for the tree's root */
    double area;                /* A(P(u)) */
    uint8_t color[4];
    hist *H;                    /* done: its subtree's colour histogram */
    int done;                   /* sampled already (a bucket's root in the upper tree) */
    double lo[3], hi[3];        /* colour cubes: its subtree's triangles' box */
    hlod_cube cube;             /* ... and that box's six faces */
} st_node;

typedef struct st_tree {
    st_rec *rec;
    double *area;               /* per record */
    size_t nrec, rcap;
    st_node *nodes;
    size_t count, cap;
} st_tree;

static void tree_free(st_tree *t)
{
    for (size_t i = 0; i < t->count; i++) {
        free(t->nodes[i].tris);
        free(t->nodes[i].kids);
        free(t->nodes[i].gkids);
        free(t->nodes[i].H);
    }
    free(t->nodes);
    free(t->rec);
    free(t->area);
    memset(t, 0, sizeof *t);
}

static int push_u32(uint32_t **v, uint32_t *n, uint32_t *cap, uint32_t x)
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

static int tree_reserve_recs(st_tree *t, size_t n)
{
    if (n <= t->rcap)
        return 1;
    size_t nc = t->rcap ? t->rcap : 1024;
    while (nc < n)
        nc *= 2;
    if (!grow(&t->rec, sizeof *t->rec, nc) || !grow(&t->area, sizeof *t->area, nc))
        return 0;
    t->rcap = nc;
    return 1;
}

/* Appends record r; its index, or NONE. */
static uint32_t tree_add_rec(st_tree *t, const st_rec *r)
{
    if (t->nrec >= NONE - 1 || !tree_reserve_recs(t, t->nrec + 1))
        return NONE;
    t->rec[t->nrec] = *r;
    t->area[t->nrec] = rec_area(r);
    return (uint32_t)t->nrec++;
}

static uint32_t node_add(st_tree *t, const st_cell *cell, uint32_t parent)
{
    if (t->count == t->cap) {
        size_t nc = t->cap ? 2 * t->cap : 64;
        st_node *n = realloc(t->nodes, nc * sizeof *n);
        if (!n)
            return NONE;
        t->nodes = n;
        t->cap = nc;
    }
    st_node *n = &t->nodes[t->count];
    memset(n, 0, sizeof *n);
    n->cell = *cell;
    n->parent = parent;
    for (int a = 0; a < 3; a++) {
        n->lo[a] = INFINITY;    /* no geometry yet */
        n->hi[a] = -INFINITY;
    }
    return (uint32_t)t->count++;
}

static st_cell child_cell(const st_cell *p, int o)
{
    st_cell c = *p;
    double h = p->e / 2;
    for (int a = 0; a < 3; a++)
        c.c[a] = p->c[a] + ((o >> a) & 1 ? h / 2 : -h / 2);
    c.e = h;
    c.level = p->level + 1;
    c.ix = 2 * p->ix + (o & 1);
    c.iy = 2 * p->iy + ((o >> 1) & 1);
    c.iz = 2 * p->iz + ((o >> 2) & 1);
    return c;
}

static int octant(const st_cell *cell, const double g[3])
{
    return (g[0] >= cell->c[0]) | (g[1] >= cell->c[1]) << 1 | (g[2] >= cell->c[2]) << 2;
}

static int has_kids(const st_node *n)
{
    return n->nkids + n->ngk > 0;
}

/* Node u's triangles ids[0..n): those that fit no child's sphere stay in
 * u; the others go down by their centroid's octant.  A cell whose
 * triangles would all go into one octant, none staying, is that octant
 * instead. */
static hlod_result split(st_tree *t, uint32_t u, uint32_t *ids, size_t n, uint8_t *oct,
                         size_t leaf_tris, int cubes)
{
    for (;;) {
        st_node *N = &t->nodes[u];
        if (n <= leaf_tris || N->cell.level >= MAX_LEVEL || !(N->cell.e > 0))
            break;
        size_t own = 0, cnt[8] = {0};
        double r2 = sphere_r2(N->cell.e / 2);
        for (size_t i = 0; i < n; i++) {
            double g[3];
            rec_centroid(&t->rec[ids[i]], g);
            int o = octant(&N->cell, g);
            st_cell cc = child_cell(&N->cell, o);
            oct[i] = rec_fits(&t->rec[ids[i]], cc.c, r2) ? (uint8_t)o : 8;
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
        /* colour cubes stop where drawing the triangles costs no more
         * than drawing the children's cubes would (Chamberlain 4) */
        if (cubes && n <= CUBE_TRIS * (size_t)used)
            break;
        if (used == 1 && own == 0) {
            N->cell = child_cell(&N->cell, only);
            continue;
        }
        uint32_t *tmp = malloc(n * sizeof *tmp);
        uint8_t *otmp = malloc(n);
        if (!tmp || !otmp) {
            free(tmp);
            free(otmp);
            return HLOD_ERR_NOMEM;
        }
        size_t start[9];
        start[0] = 0;
        start[1] = own;
        for (int o = 0; o < 7; o++)
            start[o + 2] = start[o + 1] + cnt[o];
        size_t cur[9];
        memcpy(cur, start, sizeof cur);
        for (size_t i = 0; i < n; i++) {
            int slot = oct[i] == 8 ? 0 : oct[i] + 1;
            otmp[cur[slot]] = oct[i];
            tmp[cur[slot]++] = ids[i];
        }
        memcpy(ids, tmp, n * sizeof *ids);
        memcpy(oct, otmp, n);
        free(tmp);
        free(otmp);
        for (size_t i = 0; i < own; i++)
            if (!push_u32(&t->nodes[u].tris, &t->nodes[u].n, &t->nodes[u].cap, ids[i]))
                return HLOD_ERR_NOMEM;
        for (int o = 0; o < 8; o++) {
            if (!cnt[o])
                continue;
            st_cell cc = child_cell(&t->nodes[u].cell, o);
            uint32_t k = node_add(t, &cc, u);
            if (k == NONE || !push_u32(&t->nodes[u].kids, &t->nodes[u].nkids,
                                       &t->nodes[u].kcap, k))
                return HLOD_ERR_NOMEM;
            hlod_result r = split(t, k, ids + start[o + 1], cnt[o], oct + start[o + 1], leaf_tris,
                                  cubes);
            if (r != HLOD_OK)
                return r;
        }
        return HLOD_OK;
    }
    for (size_t i = 0; i < n; i++)
        if (!push_u32(&t->nodes[u].tris, &t->nodes[u].n, &t->nodes[u].cap, ids[i]))
            return HLOD_ERR_NOMEM;
    return HLOD_OK;
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

static uint64_t cell_seed(uint64_t seed, const st_cell *c)
{
    uint64_t s = seed ^ 0x632be59bd9b4e019ull;
    uint64_t k[4] = {c->level, c->ix, c->iy, c->iz};
    for (int i = 0; i < 4; i++) {
        s ^= k[i] + 0x9e3779b97f4a7c15ull;
        s = splitmix(&s);
    }
    return s;
}

typedef struct st_build {
    const hlod_st_params *p;
    st_texes tx;
    hlod_store_writer *w;
    hlod_store_node *out;       /* written nodes; parent NONE until known */
    uint8_t (*colors)[4];
    uint8_t (*cubes)[6][4];     /* colour cubes (p->cubes): per written node */
    size_t nout, ocap;
    hlod_st_report rep;
} st_build;

/* Node u's draws over its pool (its own list, then each child's): the
 * distinct triangles drawn from children move up; a child with children
 * of its own keeps one triangle. */
static hlod_result draw_up(st_tree *t, uint32_t u, double c, uint64_t seed)
{
    st_node *N = &t->nodes[u];
    size_t pool = N->n;
    for (uint32_t k = 0; k < N->nkids; k++)
        pool += t->nodes[N->kids[k]].n;
    uint32_t *pid = malloc((pool + 1) * sizeof *pid);
    double *w = malloc((pool + 1) * sizeof *w), *cum = malloc((pool + 1) * sizeof *cum);
    size_t m = hlod_st_sample_size(N->area, N->cell.e * N->cell.e, c);
    size_t chunk = m < 65536 ? m : 65536;
    uint32_t *draw = malloc(chunk * sizeof *draw);
    uint8_t *chosen = calloc(pool + 1, 1);
    hlod_result r = pid && w && cum && draw && chosen ? HLOD_OK : HLOD_ERR_NOMEM;
    if (r == HLOD_OK && pool) {
        size_t j = 0;
        for (uint32_t i = 0; i < N->n; i++, j++)
            w[j] = t->area[pid[j] = N->tris[i]];
        for (uint32_t k = 0; k < N->nkids; k++) {
            const st_node *C = &t->nodes[N->kids[k]];
            for (uint32_t i = 0; i < C->n; i++, j++)
                w[j] = t->area[pid[j] = C->tris[i]];
        }
        double wsum = 0;
        for (size_t i = 0; i < pool; i++)
            wsum += w[i];
        if (!(wsum > 0)) /* degenerate triangles only: uniform */
            for (size_t i = 0; i < pool; i++)
                w[i] = 1;
        uint64_t state = cell_seed(seed, &N->cell);
        for (size_t done = 0; done < m; done += chunk) {
            size_t now = m - done < chunk ? m - done : chunk;
            hlod_st_draw(w, pool, now, &state, cum, draw);
            for (size_t i = 0; i < now; i++)
                chosen[draw[i]] = 1;
        }
        size_t base = N->n;
        for (uint32_t k = 0; k < t->nodes[u].nkids && r == HLOD_OK; k++) {
            st_node *C = &t->nodes[t->nodes[u].kids[k]];
            size_t c0 = base, c1 = base + C->n, drawn = 0;
            base = c1;
            for (size_t i = c0; i < c1; i++)
                drawn += chosen[i];
            int spare = has_kids(C) && drawn == c1 - c0;
            uint32_t keep = 0;
            for (size_t i = c0; i < c1; i++) {
                int up = chosen[i];
                if (up && spare) {
                    up = 0;
                    spare = 0;
                }
                if (up) {
                    if (!push_u32(&t->nodes[u].tris, &t->nodes[u].n, &t->nodes[u].cap, pid[i])) {
                        r = HLOD_ERR_NOMEM;
                        break;
                    }
                } else {
                    C->tris[keep++] = pid[i];
                }
            }
            C->n = keep;
        }
    }
    free(pid);
    free(w);
    free(cum);
    free(draw);
    free(chosen);
    return r;
}

/* ---- colour cubes ---- */

typedef struct cube_ctx {
    st_build *B;
    const st_tree *t;
    const uint32_t *ids;        /* the node's records, in the order given to the faces */
} cube_ctx;

/* A record's colour at barycentric weights w: its texture's texel there,
 * else its own colour. */
static void rec_color(void *user, size_t i, const double w[3], float rgb[3])
{
    const cube_ctx *c = user;
    const st_rec *r = &c->t->rec[c->ids[i]];
    uint8_t px[4];
    memcpy(px, r->rgba, 4);
    const hlod_image *img = r->tex != NONE ? tex_get(&c->B->tx, r->tex, c->B->p->lg) : NULL;
    if (img)
        texel(img, w[0] * r->uv[0] + w[1] * r->uv[2] + w[2] * r->uv[4],
              w[0] * r->uv[1] + w[1] * r->uv[3] + w[2] * r->uv[5], px);
    for (int k = 0; k < 3; k++)
        rgb[k] = px[k] / 255.0f;
}

/* Node u's box (its triangles' and its children's) and its cube: its own
 * triangles seen through each face, composited with its children's
 * cubes (Chamberlain 4).  Its children's are made already. */
static hlod_result node_cube(st_build *B, st_tree *t, uint32_t u)
{
    st_node *N = &t->nodes[u];
    uint32_t nk = N->nkids;
    double (*P)[9] = malloc(((size_t)N->n + 1) * sizeof *P);
    hlod_cube *kc = malloc(((size_t)nk + 1) * sizeof *kc);
    double (*klo)[3] = malloc(((size_t)nk + 1) * sizeof *klo),
           (*khi)[3] = malloc(((size_t)nk + 1) * sizeof *khi);
    hlod_result r = P && kc && klo && khi ? HLOD_OK : HLOD_ERR_NOMEM;
    if (r == HLOD_OK) {
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        for (uint32_t i = 0; i < N->n; i++) {
            memcpy(P[i], t->rec[N->tris[i]].p, sizeof P[i]);
            for (int k = 0; k < 9; k++) {
                lo[k % 3] = fmin(lo[k % 3], P[i][k]);
                hi[k % 3] = fmax(hi[k % 3], P[i][k]);
            }
        }
        uint32_t m = 0;
        for (uint32_t k = 0; k < nk; k++) {
            const st_node *C = &t->nodes[N->kids[k]];
            if (!(C->lo[0] <= C->hi[0]))
                continue; /* an empty bucket's cell: no geometry, no face */
            kc[m] = C->cube;
            memcpy(klo[m], C->lo, sizeof klo[m]);
            memcpy(khi[m], C->hi, sizeof khi[m]);
            m++;
            for (int a = 0; a < 3; a++) {
                lo[a] = fmin(lo[a], C->lo[a]);
                hi[a] = fmax(hi[a], C->hi[a]);
            }
        }
        memcpy(N->lo, lo, sizeof lo);
        memcpy(N->hi, hi, sizeof hi);
        cube_ctx cc = {B, t, N->tris};
        hlod_cube_in in = {.tris = P, .stride = sizeof *P, .n = N->n, .color = rec_color,
                           .user = &cc, .kids = kc, .kid_lo = (const double (*)[3])klo,
                           .kid_hi = (const double (*)[3])khi, .nkids = m};
        memcpy(in.lo, lo, sizeof lo);
        memcpy(in.hi, hi, sizeof hi);
        hlod_cube_faces(&in, &N->cube);
    }
    free(P);
    free(kc);
    free(klo);
    free(khi);
    return r;
}

/* One triangle out of u's subtree, every node left holding one but u
 * when u has no children (its parent then drops it); NONE when none can
 * go (what is below u is written already). */
static uint32_t take_one(st_tree *t, uint32_t u)
{
    st_node *N = &t->nodes[u];
    if (N->n >= 2 || (N->n == 1 && !has_kids(N)))
        return N->tris[--N->n];
    uint32_t order[8], m = N->nkids < 8 ? N->nkids : 8;
    for (uint32_t k = 0; k < m; k++)
        order[k] = k;
    /* the child holding most first */
    for (uint32_t k = 1; k < m; k++)
        for (uint32_t j = k; j > 0 && t->nodes[N->kids[order[j]]].n >
                                      t->nodes[N->kids[order[j - 1]]].n; j--) {
            uint32_t x = order[j];
            order[j] = order[j - 1];
            order[j - 1] = x;
        }
    for (uint32_t k = 0; k < m; k++) {
        uint32_t c = t->nodes[u].kids[order[k]];
        if (t->nodes[c].done)
            continue;
        uint32_t x = take_one(t, c);
        if (x == NONE)
            continue;
        const st_node *C = &t->nodes[c];
        if (!C->n && !has_kids(C)) { /* emptied: it goes */
            st_node *P = &t->nodes[u];
            for (uint32_t j = order[k]; j + 1 < P->nkids; j++)
                P->kids[j] = P->kids[j + 1];
            P->nkids--;
        }
        return x;
    }
    return NONE;
}

/* Node u's subtree: its children's samples first, then u's own draws (or,
 * for colour cubes, its cube); H receives the subtree's colour histogram. */
static hlod_result sample(st_build *B, st_tree *t, uint32_t u, hist *H)
{
    const double c = B->p->c;
    const uint64_t seed = B->p->seed;
    if (t->nodes[u].done) {
        memcpy(H, t->nodes[u].H, sizeof *H);
        return HLOD_OK;
    }
    memset(H, 0, sizeof *H);
    st_node *N = &t->nodes[u];
    N->area = 0;
    for (uint32_t i = 0; i < N->n; i++) {
        const st_rec *r = &t->rec[N->tris[i]];
        N->area += t->area[N->tris[i]];
        for (int k = 0; k < 4; k++)
            H->h[k][r->rgba[k]] += t->area[N->tris[i]];
    }
    if (N->nkids) {
        hist *CH = malloc(sizeof *CH);
        if (!CH)
            return HLOD_ERR_NOMEM;
        for (uint32_t k = 0; k < t->nodes[u].nkids; k++) {
            hlod_result r = sample(B, t, t->nodes[u].kids[k], CH);
            if (r != HLOD_OK) {
                free(CH);
                return r;
            }
            t->nodes[u].area += t->nodes[t->nodes[u].kids[k]].area;
            for (int ch = 0; ch < 4; ch++)
                for (int v = 0; v < 256; v++)
                    H->h[ch][v] += CH->h[ch][v];
        }
        free(CH);
    }
    N = &t->nodes[u];
    hist_median(H, N->color);
    if (B->p->cubes) {
        /* nothing is drawn up: each triangle stays where it sits; an
         * empty child (an empty bucket's cell) goes */
        uint32_t kept = 0;
        for (uint32_t k = 0; k < N->nkids; k++) {
            const st_node *C = &t->nodes[N->kids[k]];
            if (C->n || has_kids(C))
                N->kids[kept++] = N->kids[k];
        }
        N->nkids = kept;
        /* a store node holds a triangle: one straddling nothing comes up
         * from below (it is drawn a little earlier, never twice) */
        if (!N->n && has_kids(N)) {
            uint32_t x = take_one(t, u);
            if (x == NONE || !push_u32(&t->nodes[u].tris, &t->nodes[u].n, &t->nodes[u].cap, x))
                return x == NONE ? HLOD_ERR_EMPTY : HLOD_ERR_NOMEM;
        }
        return node_cube(B, t, u);
    }
    if (!N->nkids)
        return HLOD_OK;
    hlod_result r = draw_up(t, u, c, seed);
    if (r != HLOD_OK)
        return r;
    /* nothing could move up (each child with children kept its one
     * triangle): the first child gives its triangle, and when that
     * empties it, u adopts its children */
    N = &t->nodes[u];
    if (!N->n && N->nkids) {
        uint32_t k0 = N->kids[0];
        st_node *C = &t->nodes[k0];
        if (C->n) {
            uint32_t x = C->tris[--C->n];
            if (!push_u32(&t->nodes[u].tris, &t->nodes[u].n, &t->nodes[u].cap, x))
                return HLOD_ERR_NOMEM;
        }
        C = &t->nodes[k0];
        if (!C->n && has_kids(C)) {
            N = &t->nodes[u];
            N->kids[0] = NONE;
            for (uint32_t k = 0; k < C->nkids; k++) {
                t->nodes[C->kids[k]].parent = u;
                if (!push_u32(&t->nodes[u].kids, &t->nodes[u].nkids, &t->nodes[u].kcap,
                              C->kids[k]))
                    return HLOD_ERR_NOMEM;
            }
            for (uint32_t k = 0; k < C->ngk; k++)
                if (!push_u32(&t->nodes[u].gkids, &t->nodes[u].ngk, &t->nodes[u].gkcap,
                              C->gkids[k]))
                    return HLOD_ERR_NOMEM;
            C->nkids = C->ngk = 0;
        }
    }
    /* children the draws emptied go */
    N = &t->nodes[u];
    uint32_t kept = 0;
    for (uint32_t k = 0; k < N->nkids; k++) {
        if (N->kids[k] == NONE)
            continue;
        const st_node *C = &t->nodes[N->kids[k]];
        if (C->n || has_kids(C))
            N->kids[kept++] = N->kids[k];
    }
    N->nkids = kept;
    return HLOD_OK;
}

/* ---- payloads ---- */


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
    for (size_t i = 0; i < px; i++)
        hlod_pixel_rgba(img->pixels + i * img->channels, img->channels, out->pixels + 4 * i);
    return HLOD_OK;
}

typedef struct group {
    size_t tri0, tri1;          /* the node's triangles [tri0, tri1) in payload order */
    size_t v0, v1;              /* its vertices in the payload mesh */
    uint32_t tex;
    hlod_image atlas;           /* its texture's crop (hlod_node_texture) */
    int x, y;                   /* its place in the packed atlas */
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
    for (size_t i = 0; i < ng; i++) {
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

/* A vertex of a payload: exact position, UV and colour. */
typedef struct vkey {
    double p[3];
    float uv[2];
    uint8_t rgba[4];
} vkey;

static uint64_t vkey_hash(const vkey *k)
{
    uint64_t h = 0x243f6a8885a308d3ull;
    uint64_t w[4];
    memcpy(w, k->p, 24);
    uint32_t u[3];
    memcpy(u, k->uv, 8);
    memcpy(&u[2], k->rgba, 4);
    w[3] = (uint64_t)u[0] | (uint64_t)u[1] << 32;
    for (int i = 0; i < 4; i++) {
        h ^= w[i];
        h = splitmix(&h);
    }
    h ^= u[2];
    return splitmix(&h);
}

static int cmp_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return (x > y) - (x < y);
}

/* Node u's payload: its triangles by texture slot (textured first; each
 * texture's texels cropped by hlod_node_texture, the crops packed into one
 * atlas), then the untextured ones with their colours; vertices shared
 * where position, UV and colour agree. */
static hlod_result emit_node(st_build *B, st_tree *t, uint32_t u, hlod_store_node *out)
{
    st_node *N = &t->nodes[u];
    uint32_t n = N->n;
    uint32_t *order = malloc(((size_t)n + 1) * sizeof *order);
    group *g = calloc((size_t)n + 1, sizeof *g);
    size_t hcap = 16;
    while (hcap < 6 * (size_t)n)
        hcap *= 2;
    uint32_t *slot = malloc(hcap * sizeof *slot);
    vkey *keys = malloc((3 * (size_t)n + 1) * sizeof *keys);
    hlod_mesh m = {0};
    uint8_t *colors = NULL;
    hlod_image tex = {0};
    hlod_result r = order && g && slot && keys ? HLOD_OK : HLOD_ERR_NOMEM;
    size_t ng = 0, ntex = 0, vc = 0;
    if (r == HLOD_OK) {
        /* by texture slot (untextured, NONE, last), then record */
        uint64_t *key = malloc(((size_t)n + 1) * sizeof *key);
        if (!key) {
            r = HLOD_ERR_NOMEM;
            n = 0;
        }
        for (uint32_t i = 0; i < n; i++)
            key[i] = (uint64_t)t->rec[N->tris[i]].tex << 32 | N->tris[i];
        if (key)
            qsort(key, n, sizeof *key, cmp_u64);
        for (uint32_t i = 0; i < n; i++)
            order[i] = (uint32_t)key[i];
        free(key);
        for (size_t i = 0; i < hcap; i++)
            slot[i] = NONE;
        uint32_t *idx = malloc((3 * (size_t)n + 1) * sizeof *idx);
        if (!idx)
            r = HLOD_ERR_NOMEM;
        for (uint32_t i = 0; i < n && r == HLOD_OK; i++) {
            const st_rec *rc = &t->rec[order[i]];
            if (!ng || g[ng - 1].tex != rc->tex) {
                if (ng)
                    g[ng - 1].tri1 = i;
                g[ng].tri0 = i;
                g[ng].tex = rc->tex;
                g[ng].v0 = vc;
                if (ng)
                    g[ng - 1].v1 = vc;
                ng++;
            }
            if (rc->tex != NONE)
                ntex++;
            for (int k = 0; k < 3; k++) {
                vkey key;
                memset(&key, 0, sizeof key);
                memcpy(key.p, &rc->p[3 * k], sizeof key.p);
                if (rc->tex != NONE) {
                    key.uv[0] = rc->uv[2 * k];
                    key.uv[1] = rc->uv[2 * k + 1];
                    memset(key.rgba, 255, 4);
                } else {
                    memcpy(key.rgba, rc->rgba, 4);
                }
                /* vertices of one group only: a group's range stays contiguous */
                size_t h = vkey_hash(&key) & (hcap - 1);
                uint32_t found = NONE;
                while (slot[h] != NONE) {
                    if (slot[h] >= g[ng - 1].v0 && !memcmp(&keys[slot[h]], &key, sizeof key)) {
                        found = slot[h];
                        break;
                    }
                    h = (h + 1) & (hcap - 1);
                }
                if (found == NONE) {
                    found = (uint32_t)vc;
                    keys[vc++] = key;
                    slot[h] = found;
                }
                idx[3 * (size_t)i + k] = found;
            }
        }
        if (ng) {
            g[ng - 1].tri1 = n;
            g[ng - 1].v1 = vc;
        }
        if (r == HLOD_OK)
            r = hlod_mesh_alloc(&m, vc, n, ntex ? HLOD_MESH_UVS : 0);
        if (r == HLOD_OK && !(colors = malloc(vc * 4 + 1)))
            r = HLOD_ERR_NOMEM;
        if (r == HLOD_OK) {
            memcpy(m.indices, idx, 3 * (size_t)n * sizeof *idx);
            for (size_t v = 0; v < vc; v++) {
                memcpy(&m.positions[3 * v], keys[v].p, sizeof keys[v].p);
                if (m.uvs)
                    memcpy(&m.uvs[2 * v], keys[v].uv, sizeof keys[v].uv);
                memcpy(colors + 4 * v, keys[v].rgba, 4);
            }
        }
        free(idx);
    }
    /* each textured group's crop, on a view of the payload mesh */
    size_t ntg = 0;
    for (size_t gi = 0; gi < ng && r == HLOD_OK; gi++) {
        if (g[gi].tex == NONE)
            break;
        const hlod_image *img = tex_get(&B->tx, g[gi].tex, B->p->lg);
        if (!img) { /* read before, so never: the records said textured */
            r = HLOD_ERR_IO;
            break;
        }
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
        r = hlod_node_texture(img, &sub, 1.0, &g[gi].atlas);
        if (r == HLOD_OK)
            memcpy(&m.uvs[2 * g[gi].v0], sub.uvs, nv * 2 * sizeof(float));
        hlod_mesh_free(&sub);
    }
    if (r == HLOD_OK && ntg)
        r = pack_atlases(g, ntg, &m, &tex);
    if (r == HLOD_OK) {
        static const uint8_t white[4] = {255, 255, 255, 255};
        r = hlod_build_add_payload(B->w, &m, ntg ? &tex : NULL, ntex, colors, white, out);
    }
    if (r == HLOD_OK)
        out->error = N->cell.e * sqrt(3.0);  /* the cell's diagonal */
    for (size_t gi = 0; g && gi < ng; gi++)
        hlod_image_free(&g[gi].atlas);
    hlod_image_free(&tex);
    hlod_mesh_free(&m);
    free(colors);
    free(order);
    free(g);
    free(slot);
    free(keys);
    return r;
}

/* Writes node u of t as the next output node; its index, or NONE. */
static uint32_t write_node(st_build *B, st_tree *t, uint32_t u, hlod_result *res)
{
    if (B->nout == B->ocap) {
        size_t nc = B->ocap ? 2 * B->ocap : 1024;
        if (nc >= NONE || !grow(&B->out, sizeof *B->out, nc) ||
            !grow(&B->colors, sizeof *B->colors, nc) ||
            (B->p->cubes && !grow(&B->cubes, sizeof *B->cubes, nc))) {
            *res = HLOD_ERR_NOMEM;
            return NONE;
        }
        B->ocap = nc;
    }
    const st_node *N = &t->nodes[u];
    hlod_store_node *o = &B->out[B->nout];
    *res = emit_node(B, t, u, o);
    if (*res != HLOD_OK)
        return NONE;
    o->parent = NONE;
    o->block = 0;
    memcpy(B->colors[B->nout], t->nodes[u].color, 4);
    if (B->p->cubes)
        hlod_cube_pack(&t->nodes[u].cube, B->cubes[B->nout]);
    B->rep.tris += N->n;
    if (has_kids(N))
        B->rep.tris_inner += N->n;
    else
        B->rep.tris_leaf += N->n;
    return (uint32_t)B->nout++;
}

/* Writes t's nodes in pre-order from root, the root too unless
 * skip_root (then its children's out indices join its gkids); each
 * node's written children (gkids) get it as parent. */
static hlod_result write_tree(st_build *B, st_tree *t, uint32_t root, int skip_root)
{
    uint32_t *stack = malloc((t->count + 1) * sizeof *stack);
    uint32_t *gidx = malloc((t->count + 1) * sizeof *gidx);
    if (!stack || !gidx) {
        free(stack);
        free(gidx);
        return HLOD_ERR_NOMEM;
    }
    hlod_result r = HLOD_OK;
    size_t sp = 0;
    stack[sp++] = root;
    while (sp && r == HLOD_OK) {
        uint32_t u = stack[--sp];
        st_node *N = &t->nodes[u];
        if (u == root && skip_root) {
            gidx[u] = NONE;
        } else {
            gidx[u] = write_node(B, t, u, &r);
            if (r != HLOD_OK)
                break;
            N = &t->nodes[u];
            if (u != root) {
                uint32_t pg = gidx[N->parent];
                if (pg != NONE)
                    B->out[gidx[u]].parent = pg;
                else if (!push_u32(&t->nodes[N->parent].gkids, &t->nodes[N->parent].ngk,
                                   &t->nodes[N->parent].gkcap, gidx[u]))
                    r = HLOD_ERR_NOMEM;
            }
            for (uint32_t k = 0; k < N->ngk; k++)
                B->out[N->gkids[k]].parent = gidx[u];
        }
        N = &t->nodes[u];
        for (uint32_t k = N->nkids; k-- > 0;)
            stack[sp++] = N->kids[k];
    }
    free(stack);
    free(gidx);
    return r;
}

/* ---- the bucket plan ---- */

typedef struct st_bucket {
    st_cell cell;
    uint32_t upper;             /* its node in the upper tree */
    st_rec *buf;                /* records not spilled yet (in double) */
    size_t nbuf, bufcap;
    uint64_t *chunk_off;        /* spilled runs: offset, records */
    uint32_t *chunk_n;
    size_t nchunk, chunkcap;
    size_t count;               /* records given to it */
} st_bucket;

typedef struct st_plan {
    st_cell root;
    st_tree upper;              /* the cells above and at the buckets */
    st_bucket *b;
    size_t nb;
    uint32_t *grid_bucket;      /* per cell of the count grid: its bucket, or NONE */
    size_t bucket_tris;         /* a bucket's triangles at most (the memory limit's) */
    FILE *spill;
    const char *spill_path;
    uint64_t spill_bytes;
    size_t buffered;            /* records in the buffers */
    size_t buffer_limit;
} st_plan;

static void plan_free(st_plan *P)
{
    for (size_t i = 0; i < P->nb; i++) {
        free(P->b[i].buf);
        free(P->b[i].chunk_off);
        free(P->b[i].chunk_n);
    }
    free(P->b);
    free(P->grid_bucket);
    tree_free(&P->upper);
    if (P->spill)
        fclose(P->spill);   /* unlinked when made */
    memset(P, 0, sizeof *P);
}

struct hlod_st_scan {
    double lo[3], hi[3];
    size_t tris;
    /* per object: its box and triangles (the counts are spread over the
     * grid cells its box meets once the root cube is known) */
    double (*olo)[3], (*ohi)[3];
    size_t *otris;
    size_t nobj, objcap;
};

void hlod_st_scan_free(hlod_st_scan *s)
{
    if (!s)
        return;
    free(s->olo);
    free(s->ohi);
    free(s->otris);
    free(s);
}

void hlod_st_scan_box(const hlod_st_scan *s, double lo[3], double hi[3])
{
    memcpy(lo, s->lo, sizeof s->lo);
    memcpy(hi, s->hi, sizeof s->hi);
}

size_t hlod_st_scan_tris(const hlod_st_scan *s)
{
    return s->tris;
}

static st_cell root_cell(const double lo[3], const double hi[3])
{
    st_cell c;
    memset(&c, 0, sizeof c);
    double e = 0;
    for (int a = 0; a < 3; a++) {
        c.c[a] = 0.5 * (lo[a] + hi[a]);
        e = fmax(e, hi[a] - lo[a]);
    }
    c.e = e > 0 ? e * (1 + 1e-9) : 1;
    return c;
}

/* The count grid's cell index of point g in the root cube. */
static size_t grid_cell(const st_cell *root, const double g[3])
{
    size_t i[3];
    for (int a = 0; a < 3; a++) {
        double f = (g[a] - (root->c[a] - root->e / 2)) / root->e * GRID_N;
        long v = (long)floor(f);
        i[a] = v < 0 ? 0 : v >= (long)GRID_N ? GRID_N - 1 : (size_t)v;
    }
    return (i[2] * GRID_N + i[1]) * GRID_N + i[0];
}

static double grid_sum(const double *grid, uint64_t ix, uint64_t iy, uint64_t iz, uint32_t level)
{
    uint64_t w = (uint64_t)GRID_N >> level;
    double s = 0;
    for (uint64_t z = iz * w; z < (iz + 1) * w; z++)
        for (uint64_t y = iy * w; y < (iy + 1) * w; y++)
            for (uint64_t x = ix * w; x < (ix + 1) * w; x++)
                s += grid[(z * GRID_N + y) * GRID_N + x];
    return s;
}

/* The plan's recursion: cell c (upper node u) is a bucket when its count
 * fits or it is a grid cell; else its octants with triangles are. */
static hlod_result plan_cell(st_plan *P, const double *grid, uint32_t u)
{
    st_cell c = P->upper.nodes[u].cell;
    double count = grid_sum(grid, c.ix, c.iy, c.iz, c.level);
    if (count <= (double)P->bucket_tris || c.level >= GRID_LEVEL) {
        if (P->nb % 64 == 0) {
            st_bucket *b = realloc(P->b, (P->nb + 64) * sizeof *b);
            if (!b)
                return HLOD_ERR_NOMEM;
            P->b = b;
        }
        st_bucket *b = &P->b[P->nb++];
        memset(b, 0, sizeof *b);
        b->cell = c;
        b->upper = u;
        uint64_t w = (uint64_t)GRID_N >> c.level;
        for (uint64_t z = c.iz * w; z < (c.iz + 1) * w; z++)
            for (uint64_t y = c.iy * w; y < (c.iy + 1) * w; y++)
                for (uint64_t x = c.ix * w; x < (c.ix + 1) * w; x++)
                    P->grid_bucket[(z * GRID_N + y) * GRID_N + x] = (uint32_t)(P->nb - 1);
        return HLOD_OK;
    }
    for (int o = 0; o < 8; o++) {
        st_cell cc = child_cell(&c, o);
        if (!(grid_sum(grid, cc.ix, cc.iy, cc.iz, cc.level) > 0))
            continue;
        uint32_t k = node_add(&P->upper, &cc, u);
        if (k == NONE || !push_u32(&P->upper.nodes[u].kids, &P->upper.nodes[u].nkids,
                                   &P->upper.nodes[u].kcap, k))
            return HLOD_ERR_NOMEM;
        hlod_result r = plan_cell(P, grid, k);
        if (r != HLOD_OK)
            return r;
    }
    return HLOD_OK;
}

static hlod_result plan_buckets(st_plan *P, const st_cell *root, const double *grid,
                                size_t bucket_tris)
{
    P->root = *root;
    P->bucket_tris = bucket_tris;
    P->grid_bucket = malloc((size_t)GRID_N * GRID_N * GRID_N * sizeof *P->grid_bucket);
    if (!P->grid_bucket || node_add(&P->upper, root, NONE) != 0)
        return HLOD_ERR_NOMEM;
    for (size_t i = 0; i < (size_t)GRID_N * GRID_N * GRID_N; i++)
        P->grid_bucket[i] = NONE;
    return plan_cell(P, grid, 0);
}

/* Spills every buffer to the spill file. */
static hlod_result spill_all(st_plan *P, const hlod_logger *lg)
{
    if (!P->spill) {
        P->spill = fopen(P->spill_path, "w+b");
        if (!P->spill) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create the spill file: %s", P->spill_path,
                      strerror(errno));
            return HLOD_ERR_IO;
        }
        /* nameless from here on: a killed build leaves nothing behind */
        (void)unlink(P->spill_path);
    }
    for (size_t i = 0; i < P->nb; i++) {
        st_bucket *b = &P->b[i];
        if (!b->nbuf)
            continue;
        if (b->nchunk == b->chunkcap) {
            size_t nc = b->chunkcap ? 2 * b->chunkcap : 8;
            if (!grow(&b->chunk_off, sizeof *b->chunk_off, nc) ||
                !grow(&b->chunk_n, sizeof *b->chunk_n, nc))
                return HLOD_ERR_NOMEM;
            b->chunkcap = nc;
        }
        b->chunk_off[b->nchunk] = P->spill_bytes;
        b->chunk_n[b->nchunk++] = (uint32_t)b->nbuf;
        for (size_t i = 0; i < b->nbuf; i++) {
            const st_rec *r = &b->buf[i];
            st_disk d;
            for (int k = 0; k < 9; k++)
                d.p[k] = (float)(r->p[k] - b->cell.c[k % 3]);
            memcpy(d.uv, r->uv, sizeof d.uv);
            d.tex = r->tex;
            memcpy(d.rgba, r->rgba, 4);
            if (fwrite(&d, sizeof d, 1, P->spill) != 1) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write the spill file: %s",
                          P->spill_path, strerror(errno));
                return HLOD_ERR_IO;
            }
        }
        P->spill_bytes += b->nbuf * sizeof(st_disk);
        free(b->buf);
        b->buf = NULL;
        b->nbuf = b->bufcap = 0;
    }
    P->buffered = 0;
    return HLOD_OK;
}

/* Record r to its place: the bucket its centroid falls in when it fits
 * that bucket's sphere, else the deepest upper cell on the way there
 * whose sphere holds it. */
static hlod_result place(st_plan *P, const st_rec *r, const hlod_logger *lg)
{
    double g[3];
    rec_centroid(r, g);
    uint32_t bi = P->grid_bucket[grid_cell(&P->root, g)];
    if (bi != NONE) {
        st_bucket *b = &P->b[bi];
        if (rec_fits(r, b->cell.c, sphere_r2(b->cell.e))) {
            if (b->nbuf == b->bufcap) {
                size_t nc = b->bufcap ? 2 * b->bufcap : 256;
                st_rec *d = realloc(b->buf, nc * sizeof *d);
                if (!d)
                    return HLOD_ERR_NOMEM;
                b->buf = d;
                b->bufcap = nc;
            }
            b->buf[b->nbuf++] = *r;
            b->count++;
            if (++P->buffered >= P->buffer_limit)
                return spill_all(P, lg);
            return HLOD_OK;
        }
    }
    /* the upper tree: down from the root while a child on the centroid's
     * side holds it */
    st_tree *U = &P->upper;
    uint32_t u = 0;
    for (;;) {
        const st_node *N = &U->nodes[u];
        uint32_t next = NONE;
        for (uint32_t k = 0; k < N->nkids && next == NONE; k++) {
            const st_cell *cc = &U->nodes[N->kids[k]].cell;
            int inside = 1;
            for (int a = 0; a < 3; a++)
                inside &= g[a] >= cc->c[a] - cc->e / 2 && g[a] < cc->c[a] + cc->e / 2;
            if (inside && rec_fits(r, cc->c, sphere_r2(cc->e)))
                next = N->kids[k];
        }
        /* a bucket's own node takes only what fits it (checked above) */
        if (next == NONE || (bi != NONE && next == P->b[bi].upper))
            break;
        u = next;
    }
    uint32_t id = tree_add_rec(U, r);
    if (id == NONE || !push_u32(&U->nodes[u].tris, &U->nodes[u].n, &U->nodes[u].cap, id))
        return HLOD_ERR_NOMEM;
    return HLOD_OK;
}

/* Bucket b's records, relative positions back to world doubles. */
static hlod_result load_bucket(st_plan *P, st_bucket *b, st_tree *t, const hlod_logger *lg)
{
    if (!tree_reserve_recs(t, b->count + 1))
        return HLOD_ERR_NOMEM;
    st_disk *tmp = NULL;
    size_t tmpcap = 0;
    for (size_t c = 0; c < b->nchunk; c++) {
        size_t n = b->chunk_n[c];
        if (n > tmpcap) {
            st_disk *x = realloc(tmp, n * sizeof *x);
            if (!x) {
                free(tmp);
                return HLOD_ERR_NOMEM;
            }
            tmp = x;
            tmpcap = n;
        }
        if (fseeko(P->spill, (off_t)b->chunk_off[c], SEEK_SET) != 0 ||
            fread(tmp, sizeof *tmp, n, P->spill) != n) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read the spill file back: %s",
                      P->spill_path, strerror(errno));
            free(tmp);
            return HLOD_ERR_IO;
        }
        for (size_t i = 0; i < n; i++) {
            st_rec r;
            for (int k = 0; k < 9; k++)
                r.p[k] = b->cell.c[k % 3] + (double)tmp[i].p[k];
            memcpy(r.uv, tmp[i].uv, sizeof r.uv);
            r.tex = tmp[i].tex;
            memcpy(r.rgba, tmp[i].rgba, 4);
            if (tree_add_rec(t, &r) == NONE) {
                free(tmp);
                return HLOD_ERR_NOMEM;
            }
        }
    }
    for (size_t i = 0; i < b->nbuf; i++)
        if (tree_add_rec(t, &b->buf[i]) == NONE) {
            free(tmp);
            return HLOD_ERR_NOMEM;
        }
    free(tmp);
    free(b->buf);
    b->buf = NULL;
    b->nbuf = b->bufcap = 0;
    return HLOD_OK;
}

/* Bucket b: its subtree built, sampled and written but for its root,
 * whose triangles, area, histogram and written children go to its node
 * in the upper tree. */
static hlod_result build_bucket(st_build *B, st_plan *P, st_bucket *b)
{
    st_tree t = {0};
    hlod_result r = load_bucket(P, b, &t, B->p->lg);
    if (r == HLOD_OK && !t.nrec) {
        tree_free(&t);
        return HLOD_OK;
    }
    if (t.nrec > B->rep.bucket_tris_max)
        B->rep.bucket_tris_max = t.nrec;
    B->rep.buckets++;
    uint32_t *ids = r == HLOD_OK ? malloc(t.nrec * sizeof *ids) : NULL;
    uint8_t *oct = r == HLOD_OK ? malloc(t.nrec) : NULL;
    if (r == HLOD_OK && (!ids || !oct || node_add(&t, &b->cell, NONE) != 0))
        r = HLOD_ERR_NOMEM;
    if (r == HLOD_OK) {
        for (size_t i = 0; i < t.nrec; i++)
            ids[i] = (uint32_t)i;
        r = split(&t, 0, ids, t.nrec, oct, B->p->leaf_tris, B->p->cubes);
    }
    free(ids);
    free(oct);
    hist *H = r == HLOD_OK ? malloc(sizeof *H) : NULL;
    if (r == HLOD_OK)
        r = H ? sample(B, &t, 0, H) : HLOD_ERR_NOMEM;
    if (r == HLOD_OK)
        r = write_tree(B, &t, 0, 1);
    if (r == HLOD_OK) {
        /* the root into the upper tree */
        st_tree *U = &P->upper;
        st_node *root = &t.nodes[0];
        for (uint32_t i = 0; i < root->n && r == HLOD_OK; i++) {
            uint32_t id = tree_add_rec(U, &t.rec[root->tris[i]]);
            st_node *un = &U->nodes[b->upper];
            if (id == NONE || !push_u32(&un->tris, &un->n, &un->cap, id))
                r = HLOD_ERR_NOMEM;
        }
        st_node *un = &U->nodes[b->upper];
        un->cell = root->cell;  /* a single-octant cell shrinks */
        un->area = root->area;
        memcpy(un->color, root->color, 4);
        un->cube = root->cube;
        memcpy(un->lo, root->lo, sizeof un->lo);
        memcpy(un->hi, root->hi, sizeof un->hi);
        un->H = H;
        H = NULL;
        un->done = 1;
        for (uint32_t k = 0; k < root->ngk && r == HLOD_OK; k++)
            if (!push_u32(&un->gkids, &un->ngk, &un->gkcap, root->gkids[k]))
                r = HLOD_ERR_NOMEM;
        if (!un->n && !un->ngk)
            un->done = 1; /* empty: its parent drops it */
    }
    free(H);
    tree_free(&t);
    return r;
}

/* The upper tree, once every bucket is in: its own triangles sampled
 * with the buckets' roots below, and written. */
static hlod_result build_upper(st_build *B, st_plan *P)
{
    st_tree *U = &P->upper;
    /* a bucket whose cell held upper triangles as well: they joined its
     * node after its root's (never: place() keeps a bucket's node for
     * what fits the bucket).  An upper node without children or triangles
     * (an empty plan cell) has nothing: its parent drops it. */
    hist *H = malloc(sizeof *H);
    if (!H)
        return HLOD_ERR_NOMEM;
    hlod_result r = sample(B, U, 0, H);
    free(H);
    if (r != HLOD_OK)
        return r;
    if (!U->nodes[0].n) {
        hlod_logf(B->p->lg, HLOD_LOG_ERROR, "sample tree: no triangles");
        return HLOD_ERR_EMPTY;
    }
    return write_tree(B, U, 0, 0);
}

/* ---- finishing ---- */

static size_t depth_of(const hlod_store_node *out, uint32_t *depth, uint32_t k)
{
    if (depth[k] != NONE)
        return depth[k];
    uint32_t d = 0, i = k;
    while (out[i].parent != HLOD_STORE_NO_PARENT && depth[i] == NONE) {
        i = out[i].parent;
        d++;
    }
    d += depth[i] == NONE ? 0 : depth[i];
    depth[k] = d;
    return d;
}

static hlod_result finish(st_build *B, hlod_st_report *rep)
{
    hlod_result r = HLOD_OK;
    uint32_t *depth = malloc((B->nout + 1) * sizeof *depth);
    if (!depth)
        r = HLOD_ERR_NOMEM;
    for (size_t k = 0; r == HLOD_OK && k < B->nout; k++) {
        if (B->out[k].parent == NONE)
            B->out[k].parent = HLOD_STORE_NO_PARENT;
        depth[k] = NONE;
    }
    for (size_t k = 0; r == HLOD_OK && k < B->nout; k++) {
        size_t d = depth_of(B->out, depth, (uint32_t)k) + 1;
        B->rep.levels = d > B->rep.levels ? d : B->rep.levels;
    }
    free(depth);
    if (r == HLOD_OK) {
        hlod_build_contain(B->out, B->nout);
        r = hlod_store_writer_set_colors(B->w, (const uint8_t (*)[4])B->colors, (uint32_t)B->nout);
    }
    if (r == HLOD_OK && B->p->cubes)
        r = hlod_store_writer_set_cubes(B->w, (const uint8_t (*)[6][4])B->cubes, (uint32_t)B->nout);
    if (r == HLOD_OK) {
        hlod_store_writer_texture_stats(B->w, &B->rep.tex);
        r = hlod_store_writer_finish(B->w, B->out, (uint32_t)B->nout, NULL);
        B->w = NULL;
        B->rep.nodes = B->nout;
    }
    if (rep && r == HLOD_OK)
        *rep = B->rep;
    return r;
}

static void build_free(st_build *B)
{
    if (B->w)
        hlod_store_writer_abort(B->w);
    free(B->out);
    free(B->colors);
    free(B->cubes);
    texes_free(&B->tx);
}

/* Every bucket in plan order, then the upper tree; finishes. */
static hlod_result build_all(st_build *B, st_plan *P, hlod_st_report *rep)
{
    hlod_result r = HLOD_OK;
    for (size_t i = 0; i < P->nb && r == HLOD_OK; i++)
        r = build_bucket(B, P, &P->b[i]);
    if (r == HLOD_OK)
        r = build_upper(B, P);
    B->rep.spill_bytes = P->spill_bytes;
    if (r == HLOD_OK)
        r = finish(B, rep);
    return r;
}

/* ---- in memory ---- */

hlod_result hlod_build_sampletree(const hlod_st_block *b, size_t nb, const hlod_st_params *p,
                                  hlod_store_writer *w, hlod_st_report *rep)
{
    if (rep)
        memset(rep, 0, sizeof *rep);
    st_build B = {0};
    B.p = p;
    B.w = w;
    st_plan P = {0};
    hlod_result r = (b || !nb) && p && w && p->c > 0 && p->leaf_tris >= 1 ? HLOD_OK
                                                                          : HLOD_ERR_INVALID_ARG;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    size_t total = 0;
    for (size_t i = 0; r == HLOD_OK && i < nb; i++) {
        const hlod_mesh *m = b[i].mesh;
        for (size_t t = 0; t < m->tri_count; t++)
            for (int k = 0; k < 3; k++)
                for (int a = 0; a < 3; a++) {
                    double v = m->positions[3 * (size_t)m->indices[3 * t + k] + a];
                    lo[a] = fmin(lo[a], v);
                    hi[a] = fmax(hi[a], v);
                }
        total += m->tri_count;
    }
    if (r == HLOD_OK && !total)
        r = HLOD_ERR_EMPTY;
    /* one bucket: the root cube */
    st_cell root = r == HLOD_OK ? root_cell(lo, hi) : (st_cell){{0}, 0, 0, 0, 0, 0};
    double *grid = NULL;
    if (r == HLOD_OK && !(grid = calloc((size_t)GRID_N * GRID_N * GRID_N, sizeof *grid)))
        r = HLOD_ERR_NOMEM;
    if (r == HLOD_OK) {
        grid[0] = (double)total;
        P.buffer_limit = SIZE_MAX;
        r = plan_buckets(&P, &root, grid, SIZE_MAX);
    }
    free(grid);
    for (size_t i = 0; r == HLOD_OK && i < nb; i++) {
        const hlod_mesh *m = b[i].mesh;
        float diffuse[4];
        for (int k = 0; k < 4; k++)
            diffuse[k] = b[i].rgba[k] / 255.0f;
        uint32_t slot = mesh_slot(&B.tx, m, b[i].texture);
        for (size_t t = 0; t < m->tri_count && r == HLOD_OK; t++) {
            st_rec rec;
            make_rec(m, t, slot, diffuse, &B.tx, p->lg, &rec);
            if (rec.tex == NONE)
                memcpy(rec.rgba, b[i].rgba, 4);
            r = place(&P, &rec, p->lg);
        }
    }
    if (r == HLOD_OK)
        r = build_all(&B, &P, rep);
    plan_free(&P);
    build_free(&B);
    return r;
}

/* ---- out of core: the inputs, streamed ---- */

/* Calls fn for every mesh of inputs[0..n): an OBJ object by object
 * (positions only when pos_only), any other format whole. */
typedef hlod_result (*mesh_fn)(void *user, const char *path, const hlod_mesh *m);

typedef struct each_ctx {
    mesh_fn fn;
    void *user;
    const char *path;
} each_ctx;

static hlod_result each_object(void *user, const hlod_obj_info *info, const hlod_mesh *m)
{
    (void)info;
    each_ctx *c = user;
    return m ? c->fn(c->user, c->path, m) : HLOD_OK;
}

static hlod_result each_mesh(const char *const *inputs, size_t n, const char *scratch,
                             int pos_only, const hlod_logger *lg, mesh_fn fn, void *user)
{
    for (size_t i = 0; i < n; i++) {
        hlod_result r;
        hlod_mesh m = {0};
        if (hlod_mesh_is_obj(inputs[i])) {
            each_ctx c = {fn, user, inputs[i]};
            hlod_obj_stream_desc sd = {.logger = lg, .positions_only = pos_only,
                                       .object = each_object, .user = &c};
            r = hlod_obj_stream(inputs[i], &sd, &m);
        } else {
            hlod_import_desc idesc = {lg, 0, scratch};
            r = hlod_mesh_import(inputs[i], &idesc, &m, NULL);
            if (r != HLOD_OK)
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read: %s", inputs[i],
                          hlod_result_str(r));
            else
                r = fn(user, inputs[i], &m);
        }
        hlod_mesh_free(&m);
        if (r != HLOD_OK)
            return r;
    }
    return HLOD_OK;
}

typedef struct scan_ctx {
    hlod_st_scan *s;
    const hlod_logger *lg;
} scan_ctx;

static hlod_result scan_mesh(void *user, const char *path, const hlod_mesh *m)
{
    scan_ctx *c = user;
    hlod_st_scan *s = c->s;
    hlod_result r = hlod_build_check_coords(m, path, c->lg);
    if (r != HLOD_OK)
        return r;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t t = 0; t < m->tri_count; t++)
        for (int k = 0; k < 3; k++) {
            const double *p = &m->positions[3 * (size_t)m->indices[3 * t + k]];
            for (int a = 0; a < 3; a++) {
                lo[a] = fmin(lo[a], p[a]);
                hi[a] = fmax(hi[a], p[a]);
            }
        }
    if (!m->tri_count)
        return HLOD_OK;
    if (s->nobj == s->objcap) {
        size_t nc = s->objcap ? 2 * s->objcap : 256;
        if (!grow(&s->olo, sizeof *s->olo, nc) || !grow(&s->ohi, sizeof *s->ohi, nc) ||
            !grow(&s->otris, sizeof *s->otris, nc))
            return HLOD_ERR_NOMEM;
        s->objcap = nc;
    }
    memcpy(s->olo[s->nobj], lo, sizeof lo);
    memcpy(s->ohi[s->nobj], hi, sizeof hi);
    s->otris[s->nobj++] = m->tri_count;
    for (int a = 0; a < 3; a++) {
        s->lo[a] = fmin(s->lo[a], lo[a]);
        s->hi[a] = fmax(s->hi[a], hi[a]);
    }
    s->tris += m->tri_count;
    return HLOD_OK;
}

hlod_result hlod_st_scan_inputs(const char *const *inputs, size_t n, const char *scratch,
                                const hlod_logger *lg, hlod_st_scan **out)
{
    *out = NULL;
    hlod_st_scan *s = calloc(1, sizeof *s);
    if (!s)
        return HLOD_ERR_NOMEM;
    for (int a = 0; a < 3; a++) {
        s->lo[a] = INFINITY;
        s->hi[a] = -INFINITY;
    }
    scan_ctx c = {s, lg};
    hlod_result r = each_mesh(inputs, n, scratch, 1, lg, scan_mesh, &c);
    if (r == HLOD_OK && !s->tris) {
        hlod_logf(lg, HLOD_LOG_ERROR, "no triangles in the input");
        r = HLOD_ERR_EMPTY;
    }
    if (r != HLOD_OK) {
        hlod_st_scan_free(s);
        return r;
    }
    *out = s;
    return HLOD_OK;
}

/* The approximate count grid: each object's triangles spread evenly over
 * the grid cells its box meets. */
static hlod_result scan_grid(const hlod_st_scan *s, const st_cell *root, double **grid)
{
    double *g = calloc((size_t)GRID_N * GRID_N * GRID_N, sizeof *g);
    if (!g)
        return HLOD_ERR_NOMEM;
    for (size_t o = 0; o < s->nobj; o++) {
        size_t a0 = grid_cell(root, s->olo[o]), a1 = grid_cell(root, s->ohi[o]);
        size_t x0 = a0 % GRID_N, y0 = a0 / GRID_N % GRID_N, z0 = a0 / GRID_N / GRID_N;
        size_t x1 = a1 % GRID_N, y1 = a1 / GRID_N % GRID_N, z1 = a1 / GRID_N / GRID_N;
        double cells = (double)(x1 - x0 + 1) * (y1 - y0 + 1) * (z1 - z0 + 1);
        for (size_t z = z0; z <= z1; z++)
            for (size_t y = y0; y <= y1; y++)
                for (size_t x = x0; x <= x1; x++)
                    g[(z * GRID_N + y) * GRID_N + x] += (double)s->otris[o] / cells;
    }
    *grid = g;
    return HLOD_OK;
}

typedef struct place_ctx {
    st_plan *P;
    st_build *B;
    size_t tris;
} place_ctx;

static hlod_result place_mesh(void *user, const char *path, const hlod_mesh *m)
{
    (void)path;
    place_ctx *c = user;
    static const float grey[4] = {0.8f, 0.8f, 0.8f, 1};
    /* each material's texture slot once (a slot lookup compares paths) */
    uint32_t *slots = malloc((m->material_count + 1) * sizeof *slots);
    if (!slots)
        return HLOD_ERR_NOMEM;
    for (size_t i = 0; i < m->material_count; i++)
        slots[i] = mesh_slot(&c->B->tx, m, m->materials[i].texture_path);
    hlod_result r = HLOD_OK;
    for (size_t t = 0; t < m->tri_count && r == HLOD_OK; t++) {
        uint32_t mat = m->tri_material ? m->tri_material[t] : 0;
        const hlod_material *mt = mat < m->material_count ? &m->materials[mat] : NULL;
        st_rec rec;
        make_rec(m, t, mt ? slots[mat] : NONE, mt ? mt->diffuse : grey, &c->B->tx, c->B->p->lg,
                 &rec);
        r = place(c->P, &rec, c->B->p->lg);
    }
    free(slots);
    c->tris += m->tri_count;
    return r;
}

hlod_result hlod_build_sampletree_inputs(const hlod_st_scan *s, const char *const *inputs,
                                         size_t n, const char *scratch, const char *spill_path,
                                         const hlod_st_params *p, hlod_store_writer *w,
                                         hlod_st_report *rep)
{
    if (rep)
        memset(rep, 0, sizeof *rep);
    st_build B = {0};
    B.p = p;
    B.w = w;
    st_plan P = {0};
    P.spill_path = spill_path;
    double *grid = NULL;
    st_cell root = root_cell(s->lo, s->hi);
    /* the memory: half for the buffers, half for a bucket's build */
    size_t bucket_tris = SIZE_MAX;
    P.buffer_limit = SIZE_MAX;
    if (p->memory_bytes) {
        bucket_tris = p->memory_bytes / 2 / TRI_BYTES;
        P.buffer_limit = p->memory_bytes / 2 / sizeof(st_rec);
        bucket_tris = bucket_tris < 1024 ? 1024 : bucket_tris;
        P.buffer_limit = P.buffer_limit < 1024 ? 1024 : P.buffer_limit;
    }
    hlod_result r = scan_grid(s, &root, &grid);
    if (r == HLOD_OK)
        r = plan_buckets(&P, &root, grid, bucket_tris);
    free(grid);
    place_ctx c = {&P, &B, 0};
    if (r == HLOD_OK)
        r = each_mesh(inputs, n, scratch, 0, p->lg, place_mesh, &c);
    if (r == HLOD_OK && c.tris != s->tris) {
        hlod_logf(p->lg, HLOD_LOG_ERROR, "the input changed while it was read (%zu triangles, "
                  "then %zu)", s->tris, c.tris);
        r = HLOD_ERR_IO;
    }
    if (r == HLOD_OK && P.spill)
        r = spill_all(&P, p->lg); /* one file to read back from */
    if (r == HLOD_OK)
        r = build_all(&B, &P, rep);
    plan_free(&P);
    build_free(&B);
    return r;
}
