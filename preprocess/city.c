/*
 * The synthetic city (see city.h for what it is and why).
 *
 * Design:
 * - Layout.  Blocks sit on a street grid, one per cell of CELL_W x CELL_D
 *   metres, row by row from the south-west; the grid is centred on the
 *   origin.  A block is four rows of detached buildings (south and north
 *   rows span the block, west and east rows fit between them) separated by
 *   gaps of 1.5-4 m, around a courtyard.  Each block draws its layout from
 *   its own splitmix64 stream seeded by (seed, block), so a block does not
 *   change when the block count or the budget does.
 * - Walls.  A building has one vertical profile, a polyline in (n, z) with
 *   n the outward offset from the wall plane: plinth, ground-floor windows,
 *   string course (a ledge), upper-floor window bands, cornice, parapet top
 *   and the parapet's inner face down to the roof.  A wall is the profile
 *   swept along the wall: a grid of rows (profile points, subdivided) by
 *   columns (window edges, subdivided).  Grid cells inside a window are left
 *   out and replaced by a recess (four reveals and a pane set back by the
 *   recess depth), built from the hole's border vertices so that the wall is
 *   conforming (no T-junctions).  Each row's columns are stretched by its
 *   offset n at both ends (squeezed inside the wall), which mitres ledges,
 *   cornice and parapet exactly with the next wall, so a building is closed
 *   but for its bottom.  The roof is a fan over the parapets' inner bottom
 *   vertices, so it shares them exactly.
 * - Noise.  Every position is snapped to 0.1 mm and moved by up to NOISE in
 *   each axis by a hash of the snapped position: coincident vertices of
 *   different charts (wall corners, the roof rim) stay coincident, and the
 *   mesh reads like a scan rather than a box model.
 * - Budget.  count_block() runs the same emitter without storing anything.
 *   Above the base detail (one grid cell per feature) the wall grid is
 *   subdivided so that no edge exceeds `lsub`; below it, windows are spaced
 *   `k` times wider.  A bisection in log space on lsub or k lands within a
 *   fraction of a percent of the budget for realistic budgets.
 * - Texture.  One atlas per block: every wall is a chart unfolded along its
 *   profile (v = arc length, so ledges and reveals get their own texels),
 *   every roof a chart, shelf-packed at the largest common scale that fits,
 *   with a gutter of clamped texels around each chart.  Charts are painted
 *   from the same window rectangles the geometry uses, so texture windows
 *   sit in the recesses.  The ground uses one tile texture per street cell.
 */
#include "city.h"

#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "hlod/image.h"

/* Street grid (metres).  A cell is a block plus half a street all round. */
#define BLOCK_W 64.0
#define BLOCK_D 48.0
#define STREET_HALF 8.0     /* half the street: 5 m of carriageway + pavement */
#define PAVEMENT 3.0
#define CELL_W (BLOCK_W + 2 * STREET_HALF)
#define CELL_D (BLOCK_D + 2 * STREET_HALF)
#define GROUND_STEP 8.0     /* ground grid spacing: flat, so coarse is enough */

#define NOISE_WALL 0.02     /* scan-like noise amplitude per axis, metres */
#define NOISE_GROUND 0.01
#define SNAP 1e4            /* positions are snapped to 1/SNAP m before noise */

#define GUTTER 2            /* texels of clamped chart border in the atlas */
#define MAX_FLOORS 12
#define MAX_PROFILE (2 * MAX_FLOORS + 16)
#define BUDGET_TOLERANCE 0.10

/* ---- random numbers and hashes ---- */

static uint64_t mix64(uint64_t z)
{
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

/* splitmix64: tiny, fast and good enough for layout decisions. */
static uint64_t rng_next(uint64_t *s)
{
    *s += 0x9e3779b97f4a7c15ULL;
    return mix64(*s);
}

static double rng_u01(uint64_t *s)
{
    return (double)(rng_next(s) >> 11) * 0x1p-53;
}

static double rng_range(uint64_t *s, double a, double b)
{
    return a + (b - a) * rng_u01(s);
}

/* Layout lengths are whole centimetres, so corners computed along
 * different walls snap to the same 0.1 mm key. */
static double rng_cm(uint64_t *s, double a, double b)
{
    return round(rng_range(s, a, b) * 100.0) / 100.0;
}

static double hash01(uint64_t h)
{
    return (double)(mix64(h) >> 11) * 0x1p-53;
}

static uint64_t hash2(uint64_t a, uint64_t b)
{
    return mix64(a * 0x9e3779b97f4a7c15ULL ^ mix64(b + 0x632be59bd9b4e019ULL));
}

/* A cheap 32-bit lattice hash (murmur3's finaliser): value noise calls it
 * four times per texel, so mix64 there was a fifth of the run time. */
static double lattice(int64_t x, int64_t y, uint64_t seed)
{
    uint32_t h = (uint32_t)x * 0x9e3779b1u ^ (uint32_t)y * 0x85ebca77u ^ (uint32_t)seed ^
                 (uint32_t)(seed >> 32);
    h ^= h >> 16;
    h *= 0x85ebca6bu;
    h ^= h >> 13;
    h *= 0xc2b2ae35u;
    h ^= h >> 16;
    return (double)h * (2.0 / 4294967295.0) - 1.0;
}

/* Smooth value noise in [-1, 1] on a unit lattice. */
static double vnoise(double x, double y, uint64_t seed)
{
    double fx = floor(x), fy = floor(y);
    int64_t ix = (int64_t)fx, iy = (int64_t)fy;
    double tx = x - fx, ty = y - fy;
    tx = tx * tx * (3 - 2 * tx);
    ty = ty * ty * (3 - 2 * ty);
    double c0 = lattice(ix, iy, seed), c1 = lattice(ix + 1, iy, seed);
    double c2 = lattice(ix, iy + 1, seed), c3 = lattice(ix + 1, iy + 1, seed);
    double a = c0 + (c1 - c0) * tx, b = c2 + (c3 - c2) * tx;
    return a + (b - a) * ty;
}

/* ---- layout ---- */

enum { SIDE_S, SIDE_E, SIDE_N, SIDE_W, SIDE_ROOF };

typedef struct building {
    double x0, y0, x1, y1;      /* footprint, city-local metres */
    int floors;                 /* ground floor included */
    double ground_h, floor_h;   /* storey heights */
    double sill, win_h, win_w;  /* upper-floor windows, relative to the floor */
    double gwin_b, gwin_t;      /* ground-floor windows (absolute z) */
    double bay_w, margin;       /* window spacing, pier at the wall ends */
    double recess;              /* window recess depth */
    double ledge_p, ledge_h;    /* string course: protrusion, height */
    double corn_p, corn_h;      /* cornice */
    double par_t, par_h;        /* parapet thickness, roof depth below its top */
    unsigned windows;           /* bit per side: the wall has windows */
    float wall_rgb[3], trim_rgb[3];
    uint64_t hash;
} building;

typedef struct block {
    building *b;
    size_t nb, cap;
} block;

static const float PALETTE[][3] = {
    {222, 206, 176}, {205, 170, 125}, {190, 190, 185}, {200, 125, 98},  {232, 226, 206},
    {168, 96, 72},   {215, 198, 150}, {178, 188, 198}, {236, 234, 228}, {196, 180, 160},
};

static void city_grid(size_t blocks, size_t *ncols, size_t *nrows)
{
    size_t c = (size_t)ceil(sqrt((double)blocks));
    if (c < 1)
        c = 1;
    *ncols = c;
    *nrows = (blocks + c - 1) / c;
}

/* South-west corner of cell (ci, cj), city-local: the grid is centred on 0. */
static void cell_origin(size_t ncols, size_t nrows, size_t ci, size_t cj, double *x, double *y)
{
    *x = (double)ci * CELL_W - (double)ncols * CELL_W / 2;
    *y = (double)cj * CELL_D - (double)nrows * CELL_D / 2;
}

static int push_building(block *bk, const building *b)
{
    if (bk->nb == bk->cap) {
        size_t nc = bk->cap ? 2 * bk->cap : 16;
        building *nbuf = realloc(bk->b, nc * sizeof *nbuf);
        if (!nbuf)
            return 0;
        bk->b = nbuf;
        bk->cap = nc;
    }
    bk->b[bk->nb++] = *b;
    return 1;
}

/* One building's storeys, windows and trim, drawn from the block stream. */
static void draw_building(uint64_t *s, building *b, double floors_mean)
{
    int nf = (int)lround(floors_mean + rng_range(s, -1.5, 1.5));
    b->floors = nf < 2 ? 2 : nf > MAX_FLOORS ? MAX_FLOORS : nf;
    b->ground_h = rng_cm(s, 3.6, 4.5);
    b->floor_h = rng_cm(s, 2.9, 3.5);
    b->sill = rng_cm(s, 0.8, 1.0);
    b->win_h = rng_cm(s, 1.3, b->floor_h - b->sill - 0.45);
    b->win_w = rng_cm(s, 0.9, 1.5);
    b->bay_w = rng_cm(s, b->win_w + 0.9, b->win_w + 2.2);
    b->margin = rng_cm(s, 0.6, 1.5);
    b->gwin_b = rng_cm(s, 0.4, 0.9);
    b->gwin_t = b->ground_h - rng_cm(s, 0.5, 0.8);
    b->recess = rng_cm(s, 0.12, 0.3);
    b->ledge_p = rng_cm(s, 0.08, 0.2);
    b->ledge_h = rng_cm(s, 0.15, 0.35);
    b->corn_p = rng_cm(s, 0.2, 0.5);
    b->corn_h = rng_cm(s, 0.3, 0.7);
    b->par_t = rng_cm(s, 0.25, 0.4);
    b->par_h = rng_cm(s, 0.6, 1.0);
    const float *p = PALETTE[rng_next(s) % (sizeof PALETTE / sizeof PALETTE[0])];
    for (int i = 0; i < 3; i++) {
        float j = (float)rng_range(s, -10, 10);
        b->wall_rgb[i] = p[i] + j;
        b->trim_rgb[i] = 0.5f * b->wall_rgb[i] + 0.5f * 228.0f;
    }
    b->hash = rng_next(s);
}

/* Splits the row (x0, y0)-(x1, y1), running along x or y, into lots of at
 * least 6 m separated by gaps, one building each.  street_sides: bits 0-3
 * sides with windows on every lot, bits 8-11 extra sides of the first lot,
 * bits 16-19 of the last (their end walls face a street). */
static int split_row(uint64_t *s, block *bk, double floors_mean, int along_x, double x0, double y0,
                     double x1, double y1, unsigned street_sides, unsigned court_side)
{
    double len = along_x ? x1 - x0 : y1 - y0;
    if (len < 6.0)
        return 1;
    double pos = 0;
    while (pos < len) {
        double rest = len - pos;
        double w = rng_cm(s, 10, 24);
        if (rest - w < 10)
            w = rest;
        building b;
        memset(&b, 0, sizeof b);
        if (along_x) {
            b.x0 = x0 + pos;
            b.x1 = x0 + pos + w;
            b.y0 = y0;
            b.y1 = y1;
        } else {
            b.x0 = x0;
            b.x1 = x1;
            b.y0 = y0 + pos;
            b.y1 = y0 + pos + w;
        }
        b.x0 = round(b.x0 * 100) / 100;
        b.x1 = round(b.x1 * 100) / 100;
        b.y0 = round(b.y0 * 100) / 100;
        b.y1 = round(b.y1 * 100) / 100;
        draw_building(s, &b, floors_mean);
        /* Street and courtyard walls have windows; walls facing a gap
         * between lots are blank, unless they stand on the block's edge. */
        b.windows = street_sides | court_side;
        if (pos == 0)
            b.windows |= street_sides >> 8;
        if (w == rest)
            b.windows |= street_sides >> 16;
        b.windows &= 0xF;
        if (!push_building(bk, &b))
            return 0;
        pos += w + rng_cm(s, 1.5, 4);
    }
    return 1;
}

/* Builds block `index`'s buildings; (bx, by) is its south-west corner. */
static int layout_block(uint64_t seed, size_t index, double bx, double by, double floors_mean,
                        block *bk)
{
    uint64_t s = mix64(seed ^ mix64(index + 0x5bd1e995ULL));
    bk->nb = 0;
    double dS = rng_cm(&s, 10, 14), dN = rng_cm(&s, 10, 14);
    double dW = rng_cm(&s, 9, 13), dE = rng_cm(&s, 9, 13);
    double gW0 = rng_cm(&s, 2, 4), gW1 = rng_cm(&s, 2, 4);
    double gE0 = rng_cm(&s, 2, 4), gE1 = rng_cm(&s, 2, 4);
    floors_mean += rng_range(&s, -1, 1);
#define B(side) (1u << (side))
    int ok = split_row(&s, bk, floors_mean, 1, bx, by, bx + BLOCK_W, by + dS,
                       B(SIDE_S) | B(SIDE_W) << 8 | B(SIDE_E) << 16, B(SIDE_N)) &&
             split_row(&s, bk, floors_mean, 1, bx, by + BLOCK_D - dN, bx + BLOCK_W, by + BLOCK_D,
                       B(SIDE_N) | B(SIDE_W) << 8 | B(SIDE_E) << 16, B(SIDE_S)) &&
             split_row(&s, bk, floors_mean, 0, bx, by + dS + gW0, bx + dW, by + BLOCK_D - dN - gW1,
                       B(SIDE_W), B(SIDE_E)) &&
             split_row(&s, bk, floors_mean, 0, bx + BLOCK_W - dE, by + dS + gE0, bx + BLOCK_W,
                       by + BLOCK_D - dN - gE1, B(SIDE_E), B(SIDE_W));
#undef B
    return ok;
}

/* ---- profiles, rows and columns ---- */

typedef struct ppt {
    double n, z, v;     /* outward offset, height, arc length from the bottom */
    int win;            /* the segment to the next point is a window band */
} ppt;

static int add_pt(ppt *p, int np, double n, double z, int win)
{
    assert(np < MAX_PROFILE);
    p[np].n = n;
    p[np].z = z;
    p[np].v = 0;
    p[np].win = win;
    return np + 1;
}

/* The building's wall profile, bottom to top (see the design note). */
static int build_profile(const building *b, ppt *p)
{
    int np = 0;
    double gh = b->ground_h, fh = b->floor_h;
    np = add_pt(p, np, 0, 0, 0);
    np = add_pt(p, np, 0, b->gwin_b, 1);
    np = add_pt(p, np, 0, b->gwin_t, 0);
    np = add_pt(p, np, 0, gh, 0);
    np = add_pt(p, np, b->ledge_p, gh, 0);
    np = add_pt(p, np, b->ledge_p, gh + b->ledge_h, 0);
    np = add_pt(p, np, 0, gh + b->ledge_h, 0);
    for (int f = 1; f < b->floors; f++) {
        double zf = gh + (f - 1) * fh;
        np = add_pt(p, np, 0, zf + b->sill, 1);
        np = add_pt(p, np, 0, zf + b->sill + b->win_h, 0);
    }
    double top = gh + (b->floors - 1) * fh;
    np = add_pt(p, np, 0, top, 0);
    np = add_pt(p, np, b->corn_p, top, 0);
    np = add_pt(p, np, b->corn_p, top + b->corn_h, 0);
    np = add_pt(p, np, 0, top + b->corn_h, 0);
    np = add_pt(p, np, -b->par_t, top + b->corn_h, 0);
    np = add_pt(p, np, -b->par_t, top + b->corn_h - b->par_h, 0);
    for (int i = 1; i < np; i++)
        p[i].v = p[i - 1].v + hypot(p[i].n - p[i - 1].n, p[i].z - p[i - 1].z);
    return np;
}

/* Drops the window-band points of a building without windows: they only
 * split a flat wall into rows.  Arc lengths (texture v) are unchanged, and
 * all four walls drop the same rows, so their corners still coincide. */
static int flatten_profile(ppt *p, int np)
{
    int w = 1;
    for (int i = 1; i + 1 < np; i++) {
        if (p[i].n == 0 && p[w - 1].n == 0 && p[i + 1].n == 0 && p[i].z > p[w - 1].z &&
            p[i + 1].z > p[i].z)
            continue;
        p[w++] = p[i];
    }
    p[w++] = p[np - 1];
    for (int i = 0; i < w; i++)
        p[i].win = 0;
    return w;
}

static double roof_z(const building *b)
{
    return b->ground_h + (b->floors - 1) * b->floor_h + b->corn_h - b->par_h;
}

static int subdivisions(double len, double lsub)
{
    if (!(lsub < INFINITY))
        return 1;
    double n = ceil(len / lsub - 1e-9);
    return n < 1 ? 1 : n > 1e6 ? 1000000 : (int)n;
}

typedef struct grow_row {
    double n, z, v;
    int win_band;   /* band to the next row lies in a window segment */
    int inside;     /* strictly inside a window segment's rows */
} grow_row;

typedef struct grow_col {
    double u;
    int win_band, inside;
} grow_col;

typedef struct span {
    int a, b;       /* first and last row (column) of a window */
} span;

/* Scratch arrays grown on demand and reused across walls and blocks. */
typedef struct scratch {
    grow_row *rows;
    size_t rows_cap;
    grow_col *cols;
    size_t cols_cap;
    span *wrows, *wcols;
    size_t wrows_cap, wcols_cap;
    double *wl, *wr;
    size_t wl_cap, wr_cap;
    uint32_t *grid, *back, *ring0, *ring1;
    size_t grid_cap, back_cap, ring0_cap, ring1_cap;
    double *roof;       /* x, y pairs of the roof rim */
    size_t roof_cap;
    int oom;
} scratch;

static void *reserve(void *p, size_t *cap, size_t need, size_t elem, int *oom)
{
    if (need <= *cap)
        return p;
    size_t nc = *cap ? *cap : 64;
    while (nc < need)
        nc *= 2;
    void *q = realloc(p, nc * elem);
    if (!q) {
        *oom = 1;
        return NULL;
    }
    *cap = nc;
    return q;
}

#define RESERVE(sc, arr, cap, need)                                                     \
    ((sc)->arr = reserve((sc)->arr, &(sc)->cap, (need), sizeof *(sc)->arr, &(sc)->oom), \
     (sc)->arr != NULL)

static void scratch_free(scratch *sc)
{
    free(sc->rows);
    free(sc->cols);
    free(sc->wrows);
    free(sc->wcols);
    free(sc->wl);
    free(sc->wr);
    free(sc->grid);
    free(sc->back);
    free(sc->ring0);
    free(sc->ring1);
    free(sc->roof);
    memset(sc, 0, sizeof *sc);
}

/* ---- the emitter ---- */

typedef struct gen {
    int count_only, with_uv;
    int parts;                  /* HLOD_CITY_STYLE_PARTS: buildings of separate boxes */
    size_t nv, nt;
    double *pos;
    float *uv;
    size_t vcap;
    uint32_t *idx, *mat;
    size_t tcap;
    uint32_t material;
    double origin[3];
    uint64_t noise_seed;
    double noise;
    /* current chart: U = (cu + u * cs) / size, V likewise */
    double cu, cv, cs, size;
    int oom;
    scratch sc;
} gen;

static uint32_t put_vertex(gen *g, double x, double y, double z, double u, double v)
{
    size_t id = g->nv;
    if (g->count_only || g->oom) {
        g->nv++;
        return (uint32_t)id;
    }
    if (id >= UINT32_MAX) {
        g->oom = 1;
        return 0;
    }
    if (id == g->vcap) {
        size_t nc = g->vcap ? 2 * g->vcap : 4096;
        double *np = realloc(g->pos, nc * 3 * sizeof *np);
        if (np)
            g->pos = np;
        float *nu = g->with_uv ? realloc(g->uv, nc * 2 * sizeof *nu) : NULL;
        if (nu)
            g->uv = nu;
        if (!np || (g->with_uv && !nu)) {
            g->oom = 1;
            return 0;
        }
        g->vcap = nc;
    }
    double in[3] = {x, y, z};
    int64_t key[3];
    for (int i = 0; i < 3; i++)
        key[i] = llround(in[i] * SNAP);
    uint64_t h = hash2(hash2((uint64_t)key[0], (uint64_t)key[1]), (uint64_t)key[2] ^ g->noise_seed);
    for (int i = 0; i < 3; i++) {
        double r = (double)((h >> (21 * i)) & 0x1fffff) / (double)0x1fffff * 2.0 - 1.0;
        g->pos[3 * id + i] = g->origin[i] + ((double)key[i] / SNAP + r * g->noise);
    }
    if (g->with_uv) {
        g->uv[2 * id] = (float)((g->cu + u * g->cs) / g->size);
        g->uv[2 * id + 1] = (float)((g->cv + v * g->cs) / g->size);
    }
    g->nv++;
    return (uint32_t)id;
}

static void put_tri(gen *g, uint32_t a, uint32_t b, uint32_t c)
{
    size_t id = g->nt;
    g->nt++;
    if (g->count_only || g->oom)
        return;
    if (id == g->tcap) {
        size_t nc = g->tcap ? 2 * g->tcap : 8192;
        uint32_t *ni = realloc(g->idx, nc * 3 * sizeof *ni);
        if (ni)
            g->idx = ni;
        uint32_t *nm = realloc(g->mat, nc * sizeof *nm);
        if (nm)
            g->mat = nm;
        if (!ni || !nm) {
            g->oom = 1;
            return;
        }
        g->tcap = nc;
    }
    g->idx[3 * id] = a;
    g->idx[3 * id + 1] = b;
    g->idx[3 * id + 2] = c;
    g->mat[id] = g->material;
}

/* Quad a b c d, counter-clockwise seen from the front. */
static void put_quad(gen *g, uint32_t a, uint32_t b, uint32_t c, uint32_t d)
{
    put_tri(g, a, b, c);
    put_tri(g, a, c, d);
}

/* ---- walls ---- */

typedef struct wall {
    double sx, sy;      /* start corner */
    double dx, dy;      /* unit direction along the wall (counter-clockwise) */
    double len;
} wall;

/* Position of (u, n, z) in the wall's frame; the outward normal is
 * (dy, -dx). */
static void wall_point(const wall *w, double u, double n, double *x, double *y)
{
    *x = w->sx + u * w->dx + n * w->dy;
    *y = w->sy + u * w->dy - n * w->dx;
}

/* u along the wall for a grid row at offset n: the row is stretched by n at
 * both ends (squeezed when n < 0), which mitres it exactly with the next
 * wall of the same (convex) footprint: both reach the corner at (len + n,
 * n) in this wall's frame. */
static double mitre(const wall *w, double u, double n)
{
    if (n == 0)
        return u;
    return -n + u * (w->len + 2 * n) / w->len;
}

static int build_rows(gen *g, const ppt *p, int np, double lsub, size_t *nr_out, size_t *nwin)
{
    scratch *sc = &g->sc;
    size_t nr = 0, nw = 0;
    for (int i = 0; i + 1 < np; i++) {
        int ns = subdivisions(hypot(p[i + 1].n - p[i].n, p[i + 1].z - p[i].z), lsub);
        if (!RESERVE(sc, rows, rows_cap, nr + (size_t)ns + 1) ||
            !RESERVE(sc, wrows, wrows_cap, nw + 1))
            return 0;
        if (p[i].win)
            sc->wrows[nw++] = (span){(int)nr, (int)nr + ns};
        for (int j = 0; j < ns; j++) {
            double t = (double)j / ns;
            grow_row *r = &sc->rows[nr++];
            r->n = p[i].n + t * (p[i + 1].n - p[i].n);
            r->z = p[i].z + t * (p[i + 1].z - p[i].z);
            r->v = p[i].v + t * (p[i + 1].v - p[i].v);
            r->win_band = p[i].win;
            r->inside = p[i].win && j > 0;
        }
    }
    grow_row *r = &sc->rows[nr++];
    r->n = p[np - 1].n;
    r->z = p[np - 1].z;
    r->v = p[np - 1].v;
    r->win_band = r->inside = 0;
    *nr_out = nr;
    *nwin = nw;
    return 1;
}

/* Window columns for a wall: fills sc->wl/wr, returns the count. */
static int window_columns(gen *g, const building *b, double len, int has_windows, double k)
{
    scratch *sc = &g->sc;
    if (!has_windows)
        return 0;
    double avail = len - 2 * b->margin, bw = b->bay_w * k;
    if (avail < bw)
        return 0;
    double nbd = floor(avail / bw);
    int nb = nbd > 1e5 ? 100000 : (int)nbd;
    if (!RESERVE(sc, wl, wl_cap, (size_t)nb) || !RESERVE(sc, wr, wr_cap, (size_t)nb))
        return -1;
    double bay = avail / nb, ww = b->win_w;
    for (int j = 0; j < nb; j++) {
        double c = b->margin + (j + 0.5) * bay;
        sc->wl[j] = c - ww / 2;
        sc->wr[j] = c + ww / 2;
    }
    return nb;
}

static int build_cols(gen *g, double len, int nb, double lsub, size_t *nc_out)
{
    scratch *sc = &g->sc;
    size_t nc = 0;
    if (!RESERVE(sc, wcols, wcols_cap, (size_t)nb + 1))
        return 0;
    int breaks = 2 * nb + 2;
    for (int i = 0; i + 1 < breaks; i++) {
        double a = i == 0 ? 0 : (i & 1) ? sc->wl[(i - 1) / 2] : sc->wr[(i - 2) / 2];
        double b = i + 1 == breaks - 1 ? len : ((i + 1) & 1) ? sc->wl[i / 2] : sc->wr[(i - 1) / 2];
        int win = i & 1;
        int ns = subdivisions(b - a, lsub);
        if (!RESERVE(sc, cols, cols_cap, nc + (size_t)ns + 1))
            return 0;
        if (win)
            sc->wcols[i / 2] = (span){(int)nc, (int)nc + ns};
        for (int j = 0; j < ns; j++) {
            grow_col *c = &sc->cols[nc++];
            c->u = a + (b - a) * j / ns;
            c->win_band = win;
            c->inside = win && j > 0;
        }
    }
    grow_col *c = &sc->cols[nc++];
    c->u = len;
    c->win_band = c->inside = 0;
    *nc_out = nc;
    return 1;
}

/* Reveal width in texture space: the pane's texels are inset by this much,
 * so the reveals get their own band of texels. */
static double reveal_band(const building *b, double ww, double wh)
{
    double m = 0.25 * (ww < wh ? ww : wh);
    return b->recess < m ? b->recess : m;
}

/* Emits one wall; appends its roof-rim points (all but the last column of
 * the top row) to sc->roof at *nroof. */
static void emit_wall(gen *g, const building *b, const wall *w, const ppt *prof, int np,
                      int has_windows, double k, double lsub, size_t *nroof)
{
    scratch *sc = &g->sc;
    size_t nr, nwr, nc;
    int nb = window_columns(g, b, w->len, has_windows, k);
    if (nb < 0 || !build_rows(g, prof, np, lsub, &nr, &nwr) || !build_cols(g, w->len, nb, lsub, &nc)) {
        g->oom = 1;
        return;
    }
    if (nb == 0)
        nwr = 0;
    grow_row *rows = sc->rows;
    grow_col *cols = sc->cols;
    if (nb == 0)
        for (size_t r = 0; r < nr; r++)
            rows[r].win_band = rows[r].inside = 0;
    if (!RESERVE(sc, grid, grid_cap, nr * nc)) {
        g->oom = 1;
        return;
    }
    uint32_t *grid = sc->grid;

    /* The front grid, without the vertices strictly inside windows. */
    for (size_t r = 0; r < nr; r++) {
        for (size_t c = 0; c < nc; c++) {
            if (rows[r].inside && cols[c].inside) {
                grid[r * nc + c] = UINT32_MAX;
                continue;
            }
            double u = mitre(w, cols[c].u, rows[r].n), x, y;
            wall_point(w, u, rows[r].n, &x, &y);
            grid[r * nc + c] = put_vertex(g, x, y, rows[r].z, u, rows[r].v);
        }
    }
    for (size_t r = 0; r + 1 < nr; r++)
        for (size_t c = 0; c + 1 < nc; c++) {
            if (rows[r].win_band && cols[c].win_band)
                continue;
            put_quad(g, grid[r * nc + c], grid[r * nc + c + 1], grid[(r + 1) * nc + c + 1],
                     grid[(r + 1) * nc + c]);
        }

    /* Window recesses: the pane, then rings of reveals from the hole's
     * border (counter-clockwise seen from outside) to the pane's border. */
    int nd = subdivisions(b->recess, lsub);
    for (size_t wi = 0; wi < nwr; wi++) {
        span rs = sc->wrows[wi];
        for (int bj = 0; bj < nb; bj++) {
            span cs = sc->wcols[bj];
            size_t pw = (size_t)(cs.b - cs.a + 1), ph = (size_t)(rs.b - rs.a + 1);
            double ul = cols[cs.a].u, ur = cols[cs.b].u, vb = rows[rs.a].v, vt = rows[rs.b].v;
            double fb = reveal_band(b, ur - ul, rows[rs.b].z - rows[rs.a].z);
            double uc = 0.5 * (ul + ur), vc = 0.5 * (vb + vt);
            double su = (ur - ul - 2 * fb) / (ur - ul), sv = (vt - vb - 2 * fb) / (vt - vb);
            size_t loop = 2 * (pw - 1) + 2 * (ph - 1);
            if (!RESERVE(sc, back, back_cap, pw * ph) || !RESERVE(sc, ring0, ring0_cap, loop) ||
                !RESERVE(sc, ring1, ring1_cap, loop)) {
                g->oom = 1;
                return;
            }
            uint32_t *back = sc->back;
            for (size_t i = 0; i < ph; i++)
                for (size_t j = 0; j < pw; j++) {
                    const grow_row *rr = &rows[(size_t)rs.a + i];
                    double u = cols[(size_t)cs.a + j].u, x, y;
                    wall_point(w, u, -b->recess, &x, &y);
                    back[i * pw + j] = put_vertex(g, x, y, rr->z, uc + (u - uc) * su,
                                                  vc + (rr->v - vc) * sv);
                }
            for (size_t i = 0; i + 1 < ph; i++)
                for (size_t j = 0; j + 1 < pw; j++)
                    put_quad(g, back[i * pw + j], back[i * pw + j + 1], back[(i + 1) * pw + j + 1],
                             back[(i + 1) * pw + j]);
            /* Border loop as (row, column) offsets inside the window. */
            for (int d = 1; d <= nd; d++) {
                uint32_t *prev = d == 1 ? NULL : sc->ring0;
                double t = (double)d / nd;
                for (size_t e = 0; e < loop; e++) {
                    size_t i, j;
                    if (e < pw - 1) {
                        i = 0;
                        j = e;
                    } else if (e < pw - 1 + ph - 1) {
                        i = e - (pw - 1);
                        j = pw - 1;
                    } else if (e < 2 * (pw - 1) + ph - 1) {
                        i = ph - 1;
                        j = pw - 1 - (e - (pw - 1) - (ph - 1));
                    } else {
                        i = ph - 1 - (e - 2 * (pw - 1) - (ph - 1));
                        j = 0;
                    }
                    uint32_t id;
                    if (d == nd) {
                        id = back[i * pw + j];
                    } else {
                        const grow_row *rr = &rows[(size_t)rs.a + i];
                        double u = cols[(size_t)cs.a + j].u, x, y;
                        wall_point(w, u, -b->recess * t, &x, &y);
                        double bu = uc + (u - uc) * su, bv = vc + (rr->v - vc) * sv;
                        id = put_vertex(g, x, y, rr->z, u + (bu - u) * t, rr->v + (bv - rr->v) * t);
                    }
                    sc->ring1[e] = id;
                    if (!prev)
                        sc->ring0[e] = grid[((size_t)rs.a + i) * nc + (size_t)cs.a + j];
                }
                for (size_t e = 0; e < loop; e++) {
                    size_t f = (e + 1) % loop;
                    put_quad(g, sc->ring0[e], sc->ring0[f], sc->ring1[f], sc->ring1[e]);
                }
                uint32_t *tmp = sc->ring0;
                size_t tcap = sc->ring0_cap;
                sc->ring0 = sc->ring1;
                sc->ring0_cap = sc->ring1_cap;
                sc->ring1 = tmp;
                sc->ring1_cap = tcap;
            }
        }
    }

    /* The roof rim: the top row, mitred, without the last column (the next
     * wall's first). */
    if (!RESERVE(sc, roof, roof_cap, 2 * (*nroof + nc))) {
        g->oom = 1;
        return;
    }
    for (size_t c = 0; c + 1 < nc; c++) {
        double u = mitre(w, cols[c].u, rows[nr - 1].n);
        wall_point(w, u, rows[nr - 1].n, &sc->roof[2 * *nroof], &sc->roof[2 * *nroof + 1]);
        (*nroof)++;
    }
}

/* ---- blocks ---- */

typedef struct chart {
    double w, h;        /* metres */
    int x, y;           /* content origin in texels, y up from the bottom */
    int pw, ph;         /* content size in texels */
    size_t order;       /* packing order */
} chart;

static void building_walls(const building *b, wall ws[4])
{
    ws[SIDE_S] = (wall){b->x0, b->y0, 1, 0, b->x1 - b->x0};
    ws[SIDE_E] = (wall){b->x1, b->y0, 0, 1, b->y1 - b->y0};
    ws[SIDE_N] = (wall){b->x1, b->y1, -1, 0, b->x1 - b->x0};
    ws[SIDE_W] = (wall){b->x0, b->y1, 0, -1, b->y1 - b->y0};
}

/* Protruding rows reach this far past the wall's ends (mitres), so a wall
 * chart is this much wider on each side than the wall. */
static double chart_margin(const building *b)
{
    return fmax(b->corn_p, b->ledge_p);
}

static void set_chart(gen *g, const chart *charts, size_t i, double scale, double margin)
{
    if (!charts)
        return;
    g->cu = charts[i].x + margin * scale;
    g->cv = charts[i].y;
    g->cs = scale;
}

/* ---- the parts style: buildings as separate boxes, as BIM exports are ---- */

/* One face of a box: a grid of na x nb quads from o along a and b (points
 * in the wall frame: u along the wall, n outward, z up), facing a x b.
 * Each face has its own vertices: the box is closed once positions are
 * welded, as every consumer does. */
static void put_face(gen *g, const wall *w, const double o[3], const double a[3], const double b[3],
                     double lsub)
{
    double la = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    double lb = sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
    int na = subdivisions(la, lsub), nb = subdivisions(lb, lsub);
    uint32_t first = (uint32_t)g->nv;
    for (int j = 0; j <= nb; j++)
        for (int i = 0; i <= na; i++) {
            double fa = (double)i / na, fb = (double)j / nb, q[3], x, y;
            for (int k = 0; k < 3; k++)
                q[k] = o[k] + fa * a[k] + fb * b[k];
            wall_point(w, q[0], q[1], &x, &y);
            put_vertex(g, x, y, q[2], 0, 0);
        }
    for (int j = 0; j < nb; j++)
        for (int i = 0; i < na; i++) {
            uint32_t v = first + (uint32_t)(j * (na + 1) + i);
            put_quad(g, v, v + 1, v + 1 + (uint32_t)(na + 1), v + (uint32_t)(na + 1));
        }
}

/* A box [u0, u1] x [n0, n1] x [z0, z1] in wall w's frame, outward faces. */
static void put_box(gen *g, const wall *w, double u0, double u1, double n0, double n1, double z0,
                    double z1, double lsub)
{
    if (!(u1 > u0 && n1 > n0 && z1 > z0))
        return;
    double du = u1 - u0, dn = n1 - n0, dz = z1 - z0;
    const double U[3] = {du, 0, 0}, mU[3] = {-du, 0, 0}, N[3] = {0, dn, 0}, mN[3] = {0, -dn, 0},
                 Z[3] = {0, 0, dz};
    put_face(g, w, (double[3]){u0, n1, z0}, U, Z, lsub);   /* +n */
    put_face(g, w, (double[3]){u1, n0, z0}, mU, Z, lsub);  /* -n */
    put_face(g, w, (double[3]){u1, n1, z0}, mN, Z, lsub);  /* +u */
    put_face(g, w, (double[3]){u0, n0, z0}, N, Z, lsub);   /* -u */
    put_face(g, w, (double[3]){u0, n0, z1}, N, U, lsub);   /* +z */
    put_face(g, w, (double[3]){u0, n0, z0}, U, N, lsub);   /* -z */
}

#define PART_WALL 0.25      /* wall and slab thickness */
#define PART_FRAME 0.06     /* window frame width and depth */

/* One storey of one wall: a slab, or piers, spandrels, frames and panes
 * around k-spaced windows. */
static void parts_storey(gen *g, const building *b, const wall *w, int has_windows, double k,
                         double z0, double h, double wb, double wt, double lsub)
{
    double span = w->len - 2 * b->margin, bay = b->bay_w * k;
    int nwin = has_windows && span > bay ? (int)floor(span / bay) : 0;
    if (!nwin) {
        put_box(g, w, 0, w->len, -PART_WALL, 0, z0, z0 + h, lsub);
        return;
    }
    double step = span / nwin, half = 0.5 * b->win_w, prev = 0, fr = PART_FRAME;
    for (int i = 0; i < nwin; i++) {
        double c = b->margin + (i + 0.5) * step, l = c - half, r = c + half;
        put_box(g, w, prev, l, -PART_WALL, 0, z0, z0 + h, lsub);    /* pier */
        put_box(g, w, l, r, -PART_WALL, 0, z0, wb, lsub);           /* spandrel below */
        put_box(g, w, l, r, -PART_WALL, 0, wt, z0 + h, lsub);       /* and above */
        double n1 = -b->recess, n0 = n1 - fr;
        put_box(g, w, l, l + fr, n0, n1, wb, wt, lsub);             /* frame */
        put_box(g, w, r - fr, r, n0, n1, wb, wt, lsub);
        put_box(g, w, l + fr, r - fr, n0, n1, wb, wb + fr, lsub);
        put_box(g, w, l + fr, r - fr, n0, n1, wt - fr, wt, lsub);
        put_box(g, w, l + fr, r - fr, n0 + 0.02, n1 - 0.02, wb + fr, wt - fr, lsub); /* pane */
        prev = r;
    }
    put_box(g, w, prev, w->len, -PART_WALL, 0, z0, z0 + h, lsub);
}

static void emit_building_parts(gen *g, const building *b, double k, double lsub)
{
    wall ws[4];
    building_walls(b, ws);
    double top = b->ground_h + (b->floors - 1) * b->floor_h;
    for (int s = 0; s < 4; s++) {
        const wall *w = &ws[s];
        int win = (b->windows >> s) & 1;
        parts_storey(g, b, w, win, k, 0, b->ground_h, b->gwin_b, b->gwin_t, lsub);
        for (int f = 1; f < b->floors; f++) {
            double z0 = b->ground_h + (f - 1) * b->floor_h;
            parts_storey(g, b, w, win, k, z0, b->floor_h, z0 + b->sill, z0 + b->sill + b->win_h, lsub);
        }
        put_box(g, w, 0, w->len, -b->par_t, 0, top, top + b->par_h, lsub); /* parapet */
    }
    /* floor slabs, and the roof: boxes over the footprint (the south wall's
     * frame: u along x, n towards -y) */
    const wall *sw = &ws[SIDE_S];
    double depth = b->y1 - b->y0;
    for (int f = 0; f <= b->floors; f++) {
        double z = f == 0 ? 0 : b->ground_h + (f - 1) * b->floor_h;
        put_box(g, sw, PART_WALL, sw->len - PART_WALL, -depth + PART_WALL, -PART_WALL, z - PART_WALL,
                z, lsub);
    }
}

static void emit_block(gen *g, const block *bk, double k, double lsub, const chart *charts,
                       double scale)
{
    if (g->parts) {
        for (size_t i = 0; i < bk->nb && !g->oom; i++)
            emit_building_parts(g, &bk->b[i], k, lsub);
        return;
    }
    ppt prof[MAX_PROFILE];
    for (size_t i = 0; i < bk->nb && !g->oom; i++) {
        const building *b = &bk->b[i];
        int np = build_profile(b, prof);
        wall ws[4];
        building_walls(b, ws);
        int any = 0;
        for (int s = 0; s < 4; s++)
            any |= window_columns(g, b, ws[s].len, (b->windows >> s) & 1, k) != 0;
        if (!any)
            np = flatten_profile(prof, np);
        size_t nroof = 0;
        for (int s = 0; s < 4; s++) {
            set_chart(g, charts, i * 5 + (size_t)s, scale, chart_margin(b));
            emit_wall(g, b, &ws[s], prof, np, (b->windows >> s) & 1, k, lsub, &nroof);
        }
        if (g->oom)
            return;
        /* Flat roof: a fan from the centre over the parapets' inner rim. */
        set_chart(g, charts, i * 5 + SIDE_ROOF, scale, 0);
        double zr = roof_z(b), ox = b->x0 + b->par_t, oy = b->y0 + b->par_t;
        double cx = 0.5 * (b->x0 + b->x1), cy = 0.5 * (b->y0 + b->y1);
        uint32_t c = put_vertex(g, cx, cy, zr, cx - ox, cy - oy);
        uint32_t first = 0, prev = 0;
        for (size_t j = 0; j < nroof; j++) {
            double x = g->sc.roof[2 * j], y = g->sc.roof[2 * j + 1];
            uint32_t id = put_vertex(g, x, y, zr, x - ox, y - oy);
            if (j == 0)
                first = id;
            else
                put_tri(g, c, prev, id);
            prev = id;
        }
        put_tri(g, c, prev, first);
    }
}

static size_t count_block(gen *cg, const block *bk, double k, double lsub)
{
    cg->nv = cg->nt = 0;
    emit_block(cg, bk, k, lsub, NULL, 0);
    return cg->nt;
}

/* Bisection in log space on a parameter x whose triangle count falls as x
 * grows; f(xa) >= target >= f(xb). */
static void bisect(gen *cg, const block *bk, size_t target, int on_k, double xa, double xb,
                   double *best_x, size_t *best_n)
{
    for (int it = 0; it < 48 && xb / xa > 1 + 1e-9; it++) {
        double xm = sqrt(xa * xb);
        size_t n = on_k ? count_block(cg, bk, xm, INFINITY) : count_block(cg, bk, 1, xm);
        if (fabs((double)n - (double)target) < fabs((double)*best_n - (double)target)) {
            *best_n = n;
            *best_x = xm;
        }
        if (fabs((double)n - (double)target) <= 0.002 * (double)target)
            break;
        if (n >= target)
            xa = xm;
        else
            xb = xm;
    }
}

/* Picks (k, lsub) so that the block has about `target` triangles. */
static size_t choose_detail(gen *cg, const block *bk, size_t target, double *k, double *lsub)
{
    size_t base = count_block(cg, bk, 1, INFINITY);
    *k = 1;
    *lsub = INFINITY;
    size_t best = base;
    if (base == target)
        return base;
    if (base < target) {
        /* Finer: halve lsub until the count passes the target (each halving
         * roughly quadruples it, so no trial runs far past the target). */
        double xb = 64, xa = 4, x = INFINITY;
        size_t n;
        while ((n = count_block(cg, bk, 1, xa)) < target && xa > 1e-3) {
            if (fabs((double)n - (double)target) < fabs((double)best - (double)target)) {
                best = n;
                x = xa;
            }
            xb = xa;
            xa /= 2;
        }
        if (fabs((double)n - (double)target) < fabs((double)best - (double)target)) {
            best = n;
            x = xa;
        }
        bisect(cg, bk, target, 0, xa, xb, &x, &best);
        *lsub = x;
    } else {
        /* Coarser: widen the window spacing. */
        double xa = 1, xb = 2, x = 1;
        size_t n;
        while ((n = count_block(cg, bk, xb, INFINITY)) > target && xb < 1e4) {
            if (fabs((double)n - (double)target) < fabs((double)best - (double)target)) {
                best = n;
                x = xb;
            }
            xa = xb;
            xb *= 2;
        }
        if (fabs((double)n - (double)target) < fabs((double)best - (double)target)) {
            best = n;
            x = xb;
        }
        bisect(cg, bk, target, 1, xa, xb, &x, &best);
        *k = x;
    }
    return best;
}

/* ---- texture atlas ---- */

static int chart_cmp(const void *pa, const void *pb)
{
    const chart *a = *(const chart *const *)pa, *b = *(const chart *const *)pb;
    if (a->h != b->h)
        return a->h > b->h ? -1 : 1;
    return a->order < b->order ? -1 : a->order > b->order;
}

/* Shelf packing at `scale` texels per metre; returns 1 when all fit. */
static int pack(chart **sorted, size_t n, int size, double scale)
{
    int x = 0, y = 0, shelf = 0;
    for (size_t i = 0; i < n; i++) {
        chart *c = sorted[i];
        c->pw = (int)ceil(c->w * scale);
        c->ph = (int)ceil(c->h * scale);
        int cw = c->pw + 2 * GUTTER, chh = c->ph + 2 * GUTTER;
        if (x + cw > size) {
            y += shelf;
            x = 0;
            shelf = 0;
        }
        if (cw > size || y + chh > size)
            return 0;
        c->x = x + GUTTER;
        c->y = y + GUTTER;
        x += cw;
        if (chh > shelf)
            shelf = chh;
    }
    return 1;
}

/* Charts for every wall and roof of the block, packed at the largest scale
 * that fits; returns the scale (texels per metre), 0 when they cannot fit
 * (each chart needs at least 1 + 2 * GUTTER texels a side). */
static double layout_atlas(const block *bk, int size, chart *charts, chart **sorted)
{
    ppt prof[MAX_PROFILE];
    double area = 0;
    for (size_t i = 0; i < bk->nb; i++) {
        const building *b = &bk->b[i];
        int np = build_profile(b, prof);
        double lx = b->x1 - b->x0, ly = b->y1 - b->y0, h = prof[np - 1].v;
        double m2 = 2 * chart_margin(b);
        double w[5] = {lx + m2, ly + m2, lx + m2, ly + m2, lx - 2 * b->par_t};
        for (int s = 0; s < 5; s++) {
            chart *c = &charts[i * 5 + (size_t)s];
            c->w = w[s];
            c->h = s == SIDE_ROOF ? ly - 2 * b->par_t : h;
            c->order = i * 5 + (size_t)s;
            sorted[i * 5 + (size_t)s] = c;
            area += c->w * c->h;
        }
    }
    size_t n = bk->nb * 5;
    qsort(sorted, n, sizeof *sorted, chart_cmp);
    double lo = 0, hi = (double)size / sqrt(area > 0 ? area : 1);
    while (pack(sorted, n, size, hi))
        hi *= 2;
    for (int it = 0; it < 40; it++) {
        double mid = 0.5 * (lo + hi);
        if (pack(sorted, n, size, mid))
            lo = mid;
        else
            hi = mid;
    }
    if (!(lo > 0) || !pack(sorted, n, size, lo))
        return 0;
    return lo;
}

static void put_px(hlod_image *img, int x, int y_up, const double rgb[3])
{
    uint8_t *p = img->pixels + ((size_t)(img->height - 1 - y_up) * (size_t)img->width + (size_t)x) * 3;
    for (int i = 0; i < 3; i++) {
        double v = rgb[i] + 0.5;
        p[i] = (uint8_t)(v < 0 ? 0 : v > 255 ? 255 : v);
    }
}

/* Fine texel-scale variation.  Smooth rather than per-texel random: white
 * noise made each 1024^2 PNG 1.1 MB and 0.9 s of deflate, this keeps the
 * grain but compresses. */
static double grain(uint64_t seed, int x, int y)
{
    return 3.0 * vnoise(x * 0.4, y * 0.4, seed + 17);
}

static void scale3(double out[3], const float in[3], double f, double add)
{
    for (int i = 0; i < 3; i++)
        out[i] = in[i] * f + add;
}

/* Paints one wall chart: the same window rectangles as the geometry. */
static void paint_wall(gen *g, hlod_image *img, const chart *c, double scale, const building *b,
                       const ppt *prof, int np, int has_windows, double k, double len,
                       uint64_t seed)
{
    int nb = window_columns(g, b, len, has_windows, k);
    if (nb < 0)
        return;
    int x0 = c->x - GUTTER, x1 = c->x + c->pw + GUTTER;
    int y0 = c->y - GUTTER, y1 = c->y + c->ph + GUTTER;
    for (int py = y0; py < y1; py++) {
        double v = (py + 0.5 - c->y) / scale;
        v = v < 0 ? 0 : v > c->h ? c->h : v;
        int s = 0;
        while (s + 2 < np && prof[s + 1].v <= v)
            s++;
        const ppt *a = &prof[s], *e = &prof[s + 1];
        double t = e->v > a->v ? (v - a->v) / (e->v - a->v) : 0;
        double z = a->z + t * (e->z - a->z);
        int bj = 0;
        for (int px = x0; px < x1; px++) {
            double u = (px + 0.5 - c->x) / scale;
            u = (u < 0 ? 0 : u > c->w ? c->w : u) - chart_margin(b);
            double lf = 0.07 * vnoise(u * 0.5, v * 0.5, seed) + 0.035 * vnoise(u * 2, v * 2, seed + 1) +
                        0.04 * vnoise(u * 4, v * 0.3, seed + 2);
            double gr = grain(seed, px, py), rgb[3];
            double dn = e->n - a->n, dz = e->z - a->z;
            if (dz < 0) {                               /* parapet inner face */
                scale3(rgb, b->wall_rgb, 0.62 + lf, gr);
            } else if (a->n > 0 || e->n > 0) {          /* string course, cornice */
                double f = dz == 0 ? (dn > 0 ? 0.62 : 1.08) : 1.0;
                scale3(rgb, b->trim_rgb, f + 0.5 * lf, gr);
            } else if (dn < 0) {                        /* parapet top */
                scale3(rgb, b->trim_rgb, 0.85 + 0.5 * lf, gr);
            } else {
                scale3(rgb, b->wall_rgb, 1 + lf, gr);
                if (s == 0 && z < 0.5)                  /* plinth */
                    scale3(rgb, b->wall_rgb, 0.72 + lf, gr);
                while (bj + 1 < nb && g->sc.wr[bj] < u)
                    bj++;
                if (a->win && nb > 0 && u >= g->sc.wl[bj] && u <= g->sc.wr[bj]) {
                    double ul = g->sc.wl[bj], ur = g->sc.wr[bj];
                    double fb = reveal_band(b, ur - ul, e->z - a->z);
                    if (u < ul + fb || u > ur - fb || v < a->v + fb || v > e->v - fb) {
                        scale3(rgb, b->wall_rgb, 0.78 + lf, gr);
                    } else {
                        double wx = (u - ul - fb) / (ur - ul - 2 * fb);
                        double wy = (v - a->v - fb) / (e->v - a->v - 2 * fb);
                        uint64_t h = hash2(b->hash, (uint64_t)s * 1000 + (uint64_t)bj);
                        double kind = hash01(h), tone = hash01(h + 1);
                        double mull = 0.05 / (ur - ul - 2 * fb);
                        if (fabs(wx - 0.5) < mull || (s > 1 && fabs(wy - 0.7) < mull)) {
                            rgb[0] = 226 + gr;
                            rgb[1] = 226 + gr;
                            rgb[2] = 220 + gr;
                        } else if (kind < 0.2 && wy > 0.4) {
                            rgb[0] = 190 * (0.8 + 0.2 * tone) + gr;
                            rgb[1] = 176 * (0.8 + 0.2 * tone) + gr;
                            rgb[2] = 150 * (0.8 + 0.2 * tone) + gr;
                        } else if (kind > 0.96) {
                            rgb[0] = 212 + gr;
                            rgb[1] = 190 + gr;
                            rgb[2] = 122 + gr;
                        } else {
                            double sky = 30 * wy + 25 * tone;
                            rgb[0] = 36 + sky + gr;
                            rgb[1] = 46 + sky + gr;
                            rgb[2] = 62 + 1.2 * sky + gr;
                        }
                    }
                }
            }
            put_px(img, px, py, rgb);
        }
    }
}

static void paint_roof(hlod_image *img, const chart *c, double scale, uint64_t seed)
{
    for (int py = c->y - GUTTER; py < c->y + c->ph + GUTTER; py++)
        for (int px = c->x - GUTTER; px < c->x + c->pw + GUTTER; px++) {
            double u = (px + 0.5 - c->x) / scale, v = (py + 0.5 - c->y) / scale;
            double f = 1 + 0.12 * vnoise(u * 0.3, v * 0.3, seed) + 0.05 * vnoise(u * 2, v * 2, seed + 1);
            double gr = grain(seed, px, py);
            double rgb[3] = {108 * f + gr, 106 * f + gr, 102 * f + gr};
            put_px(img, px, py, rgb);
        }
}

static void paint_block(gen *g, hlod_image *img, const block *bk, const chart *charts,
                        double scale, double k, uint64_t seed)
{
    ppt prof[MAX_PROFILE];
    memset(img->pixels, 0, (size_t)img->width * (size_t)img->height * 3);
    for (size_t i = 0; i < bk->nb; i++) {
        const building *b = &bk->b[i];
        int np = build_profile(b, prof);
        wall ws[4];
        building_walls(b, ws);
        for (int s = 0; s < 4; s++)
            paint_wall(g, img, &charts[i * 5 + (size_t)s], scale, b, prof, np,
                       (b->windows >> s) & 1, k, ws[s].len, hash2(seed, b->hash + (uint64_t)s));
        paint_roof(img, &charts[i * 5 + SIDE_ROOF], scale, hash2(seed, b->hash + 7));
    }
}

/* ---- ground ---- */

static const double GROUND_X[6] = {0, STREET_HALF - PAVEMENT, STREET_HALF, STREET_HALF + BLOCK_W,
                                   STREET_HALF + BLOCK_W + PAVEMENT, CELL_W};
static const double GROUND_Y[6] = {0, STREET_HALF - PAVEMENT, STREET_HALF, STREET_HALF + BLOCK_D,
                                   STREET_HALF + BLOCK_D + PAVEMENT, CELL_D};

static size_t ground_breaks(const double *b, double *out)
{
    size_t n = 0;
    for (int i = 0; i < 5; i++) {
        int ns = subdivisions(b[i + 1] - b[i], GROUND_STEP);
        for (int j = 0; j < ns; j++)
            out[n++] = b[i] + (b[i + 1] - b[i]) * j / ns;
    }
    out[n++] = b[5];
    return n;
}

/* One grid per street cell, UVs 0..1 over the cell (the tile texture). */
static void emit_ground(gen *g, size_t ncols, size_t nrows)
{
    double bx[64], by[64];
    size_t nx = ground_breaks(GROUND_X, bx), ny = ground_breaks(GROUND_Y, by);
    uint32_t ids[64 * 64];
    g->cu = g->cv = 0;
    for (size_t cj = 0; cj < nrows; cj++)
        for (size_t ci = 0; ci < ncols; ci++) {
            double ox, oy;
            cell_origin(ncols, nrows, ci, cj, &ox, &oy);
            for (size_t j = 0; j < ny; j++)
                for (size_t i = 0; i < nx; i++) {
                    double u = bx[i] / CELL_W, v = by[j] / CELL_D;
                    g->cs = 1;
                    ids[j * nx + i] = put_vertex(g, ox + bx[i], oy + by[j], 0, u * g->size, v * g->size);
                }
            for (size_t j = 0; j + 1 < ny; j++)
                for (size_t i = 0; i + 1 < nx; i++)
                    put_quad(g, ids[j * nx + i], ids[j * nx + i + 1], ids[(j + 1) * nx + i + 1],
                             ids[(j + 1) * nx + i]);
        }
}

static void paint_ground(hlod_image *img, uint64_t seed)
{
    int S = img->width;
    for (int py = 0; py < S; py++)
        for (int px = 0; px < S; px++) {
            double x = (px + 0.5) / S * CELL_W, y = (py + 0.5) / S * CELL_D;
            double gr = grain(seed, px, py), rgb[3];
            double n1 = vnoise(x * 0.4, y * 0.4, seed), n2 = vnoise(x * 3, y * 3, seed + 1);
            int in_x = x >= STREET_HALF && x <= STREET_HALF + BLOCK_W;
            int in_y = y >= STREET_HALF && y <= STREET_HALF + BLOCK_D;
            int pav_x = x >= STREET_HALF - PAVEMENT && x <= STREET_HALF + BLOCK_W + PAVEMENT;
            int pav_y = y >= STREET_HALF - PAVEMENT && y <= STREET_HALF + BLOCK_D + PAVEMENT;
            if (in_x && in_y) {                         /* courtyard: grass */
                double f = 1 + 0.15 * n1 + 0.08 * n2;
                rgb[0] = 72 * f + gr;
                rgb[1] = 100 * f + gr;
                rgb[2] = 54 * f + gr;
            } else if (pav_x && pav_y) {                /* pavement slabs, kerb */
                double dx = fmin(fabs(x - (STREET_HALF - PAVEMENT)),
                                 fabs(x - (STREET_HALF + BLOCK_W + PAVEMENT)));
                double dy = fmin(fabs(y - (STREET_HALF - PAVEMENT)),
                                 fabs(y - (STREET_HALF + BLOCK_D + PAVEMENT)));
                double f = 1 + 0.05 * n1 + 0.03 * n2;
                double base = (dx < 0.2 && pav_y) || (dy < 0.2 && pav_x) ? 182 : 150;
                if (fmod(x, 0.6) < 0.04 || fmod(y, 0.6) < 0.04)
                    f *= 0.86;
                rgb[0] = base * f + gr;
                rgb[1] = (base - 3) * f + gr;
                rgb[2] = (base - 10) * f + gr;
            } else {                                    /* asphalt, centre line */
                double f = 1 + 0.1 * n1 + 0.06 * n2;
                int line_x = (x < 0.1 || x > CELL_W - 0.1) && in_y && fmod(y, 6) < 3;
                int line_y = (y < 0.1 || y > CELL_D - 0.1) && in_x && fmod(x, 6) < 3;
                double base = line_x || line_y ? 215 : 58;
                rgb[0] = base * f + gr;
                rgb[1] = base * f + gr;
                rgb[2] = (base + 4) * f + gr;
            }
            put_px(img, px, py, rgb);
        }
}

/* ---- driver ---- */

int hlod_city_preset(const char *name, hlod_city_desc *d)
{
    if (!name || !d)
        return 0;
    if (!strcmp(name, "default")) {
        d->blocks = 200;
        d->tris_per_block = 35000;
        d->texture_size = 1024;
    } else if (!strcmp(name, "small")) {
        d->blocks = 8;
        d->tris_per_block = 5500;
        d->texture_size = 256;
    } else if (!strcmp(name, "tiny")) {
        d->blocks = 2;
        d->tris_per_block = 2500;
        d->texture_size = 64;
    } else {
        return 0;
    }
    return 1;
}

static char *join(const char *dir, const char *name)
{
    size_t a = strlen(dir), b = strlen(name);
    char *p = malloc(a + b + 2);
    if (p) {
        memcpy(p, dir, a);
        p[a] = '/';
        memcpy(p + a + 1, name, b + 1);
    }
    return p;
}

static hlod_result write_texture(const hlod_city_desc *d, const char *name, const hlod_image *img,
                                 char **path_out, hlod_city_stats *st)
{
    char file[64];
    snprintf(file, sizeof file, "%s.png", name);
    char *path = join(d->texture_dir, file);
    if (!path)
        return HLOD_ERR_NOMEM;
    hlod_result r = hlod_image_write(path, img, d->logger);
    if (r != HLOD_OK) {
        free(path);
        return r;
    }
    struct stat sb;
    if (stat(path, &sb) == 0)
        st->texture_bytes += (uint64_t)sb.st_size;
    st->textures++;
    st->texture_pixels += (uint64_t)img->width * (uint64_t)img->height;
    *path_out = path;
    return HLOD_OK;
}

/* sRGB 0..255 to linear 0..1 (materials hold linear colours). */
static float to_linear(double c)
{
    double s = c / 255.0;
    return (float)(s <= 0.04045 ? s / 12.92 : pow((s + 0.055) / 1.055, 2.4));
}

static hlod_result check_desc(const hlod_city_desc *d, const hlod_logger *lg)
{
    if (d->blocks > 1000000 || d->tris_per_block > 100000000 ||
        (double)d->blocks * (double)d->tris_per_block > 1.5e9) {
        hlod_logf(lg, HLOD_LOG_ERROR, "city: %zu blocks of %zu triangles is too large",
                  d->blocks, d->tris_per_block);
        return HLOD_ERR_INVALID_ARG;
    }
    if (d->style != HLOD_CITY_STYLE_SCAN && d->style != HLOD_CITY_STYLE_PARTS) {
        hlod_logf(lg, HLOD_LOG_ERROR, "city: unknown style %d", d->style);
        return HLOD_ERR_INVALID_ARG;
    }
    if (d->style == HLOD_CITY_STYLE_PARTS && !d->untextured) {
        hlod_logf(lg, HLOD_LOG_ERROR, "city: the parts style is untextured (set untextured)");
        return HLOD_ERR_INVALID_ARG;
    }
    if (!d->untextured && (d->texture_size < 16 || d->texture_size > 16384)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "city: texture size %d is out of range (16..16384)",
                  d->texture_size);
        return HLOD_ERR_INVALID_ARG;
    }
    if (!d->untextured && (!d->texture_dir || !*d->texture_dir)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "city: a textured city needs a texture folder");
        return HLOD_ERR_INVALID_ARG;
    }
    for (int i = 0; i < 3; i++)
        if (!isfinite(d->origin[i]) || fabs(d->origin[i]) > 1e9) {
            hlod_logf(lg, HLOD_LOG_ERROR, "city: origin %g is out of range", d->origin[i]);
            return HLOD_ERR_INVALID_ARG;
        }
    return HLOD_OK;
}

/* What generating one city holds while its blocks are made. */
typedef struct city_job {
    hlod_city_desc d;
    const hlod_logger *lg;
    int textured;
    size_t ncols, nrows;
    double radius;              /* of the street grid, for the building heights */
    gen g, cg;                  /* the mesh, and a counting pass for the detail */
    block bk;
    hlod_image img;             /* one block's atlas */
    chart *charts, **sorted;
    size_t charts_cap;
    hlod_material *mats;        /* blocks + 1 (the ground) */
    hlod_object *objs;
    hlod_city_stats st;
} city_job;

/* The atlas of block bi (its charts laid out, painted and written). */
static hlod_result block_texture(city_job *J, size_t bi, const char *name, double k,
                                 double *scale)
{
    const block *bk = &J->bk;
    if (bk->nb * 5 > J->charts_cap) {
        free(J->charts);
        free(J->sorted);
        J->charts_cap = bk->nb * 5;
        J->charts = malloc(J->charts_cap * sizeof *J->charts);
        J->sorted = malloc(J->charts_cap * sizeof *J->sorted);
        if (!J->charts || !J->sorted) {
            J->charts_cap = 0;
            return HLOD_ERR_NOMEM;
        }
    }
    *scale = layout_atlas(&J->bk, J->d.texture_size, J->charts, J->sorted);
    if (!(*scale > 0)) {
        hlod_logf(J->lg, HLOD_LOG_ERROR,
                  "city: a %dx%d texture cannot hold the %zu charts of block %zu",
                  J->d.texture_size, J->d.texture_size, bk->nb * 5, bi);
        return HLOD_ERR_INVALID_ARG;
    }
    paint_block(&J->g, &J->img, &J->bk, J->charts, *scale, k, hash2(J->d.seed, bi));
    return write_texture(&J->d, name, &J->img, &J->mats[bi].texture_path, &J->st);
}

/* Block bi: its layout, its detail for the triangle budget, its texture,
 * its triangles and its material. */
static hlod_result city_block(city_job *J, size_t bi)
{
    const hlod_city_desc *d = &J->d;
    size_t ci = bi % J->ncols, cj = bi / J->ncols;
    double ox, oy;
    cell_origin(J->ncols, J->nrows, ci, cj, &ox, &oy);
    double cx = ox + CELL_W / 2, cy = oy + CELL_D / 2;
    double rr = hypot(cx, cy) / (J->radius > 0 ? J->radius : 1);
    double floors_mean = 3.5 + 4.5 * exp(-3 * rr * rr);
    if (!layout_block(d->seed, bi, ox + STREET_HALF, oy + STREET_HALF, floors_mean, &J->bk))
        return HLOD_ERR_NOMEM;
    double k, lsub;
    size_t n = choose_detail(&J->cg, &J->bk, d->tris_per_block, &k, &lsub);
    if (J->cg.oom || J->cg.sc.oom)
        return HLOD_ERR_NOMEM;
    if (fabs((double)n - (double)d->tris_per_block) > BUDGET_TOLERANCE * (double)d->tris_per_block)
        hlod_logf(J->lg, HLOD_LOG_WARN,
                  "city: block %zu has %zu triangles, more than 10%% off its budget of %zu", bi, n,
                  d->tris_per_block);
    char name[32];
    snprintf(name, sizeof name, "block_%04zu", bi);
    double scale = 0;
    hlod_result res = J->textured ? block_texture(J, bi, name, k, &scale) : HLOD_OK;
    if (res != HLOD_OK)
        return res;
    hlod_object *ob = &J->objs[bi];
    hlod_material *mat = &J->mats[bi];
    ob->first_tri = J->g.nt;
    J->g.material = (uint32_t)bi;
    emit_block(&J->g, &J->bk, k, lsub, J->textured ? J->charts : NULL, scale);
    if (J->g.oom || J->g.sc.oom)
        return HLOD_ERR_NOMEM;
    ob->tri_count = J->g.nt - ob->first_tri;
    if (!(ob->name = strdup(name)) || !(mat->name = strdup(name)))
        return HLOD_ERR_NOMEM;
    float avg[3] = {0, 0, 0};
    for (size_t i = 0; i < J->bk.nb; i++)
        for (int c = 0; c < 3; c++)
            avg[c] += J->bk.b[i].wall_rgb[c] / (float)J->bk.nb;
    for (int c = 0; c < 3; c++)
        mat->diffuse[c] = J->textured ? 1.0f : to_linear(avg[c]);
    mat->diffuse[3] = 1;
    J->st.block_tris += ob->tri_count;
    if (ob->tri_count < J->st.min_block_tris)
        J->st.min_block_tris = ob->tri_count;
    if (ob->tri_count > J->st.max_block_tris)
        J->st.max_block_tris = ob->tri_count;
    return HLOD_OK;
}

/* The ground, last. */
static hlod_result city_ground(city_job *J)
{
    size_t gi = J->d.blocks;
    hlod_result res;
    if (J->textured) {
        paint_ground(&J->img, hash2(J->d.seed, 0x67726f756e64ULL));
        if ((res = write_texture(&J->d, "ground", &J->img, &J->mats[gi].texture_path, &J->st)))
            return res;
    }
    hlod_object *ob = &J->objs[gi];
    ob->first_tri = J->g.nt;
    J->g.material = (uint32_t)gi;
    J->g.noise = NOISE_GROUND;
    emit_ground(&J->g, J->ncols, J->nrows);
    if (J->g.oom)
        return HLOD_ERR_NOMEM;
    ob->tri_count = J->g.nt - ob->first_tri;
    J->st.ground_tris = ob->tri_count;
    if (!(ob->name = strdup("ground")) || !(J->mats[gi].name = strdup("ground")))
        return HLOD_ERR_NOMEM;
    for (int c = 0; c < 3; c++)
        J->mats[gi].diffuse[c] = J->textured ? 1.0f : to_linear(120);
    J->mats[gi].diffuse[3] = 1;
    return HLOD_OK;
}

/* Frees the job's scratch, and on failure what the mesh would have owned. */
static void city_release(city_job *J, int failed)
{
    if (failed) {
        for (size_t i = 0; J->mats && i <= J->d.blocks; i++) {
            free(J->mats[i].name);
            free(J->mats[i].texture_path);
        }
        for (size_t i = 0; J->objs && i <= J->d.blocks; i++)
            free(J->objs[i].name);
        free(J->mats);
        free(J->objs);
        free(J->g.pos);
        free(J->g.uv);
        free(J->g.idx);
        free(J->g.mat);
    }
    scratch_free(&J->g.sc);
    scratch_free(&J->cg.sc);
    free(J->bk.b);
    free(J->charts);
    free(J->sorted);
    hlod_image_free(&J->img);
}

/* The job's settings, grid and tables; then every block and the ground. */
static hlod_result city_run(city_job *J)
{
    const hlod_city_desc *d = &J->d;
    J->st.blocks = d->blocks;
    J->st.min_block_tris = SIZE_MAX;
    J->textured = !d->untextured;
    if (J->textured && mkdir(d->texture_dir, 0777) != 0 && errno != EEXIST) {
        hlod_logf(J->lg, HLOD_LOG_ERROR, "%s: cannot create texture folder: %s", d->texture_dir,
                  strerror(errno));
        return HLOD_ERR_IO;
    }
    city_grid(d->blocks, &J->ncols, &J->nrows);
    J->g.with_uv = J->textured;
    J->g.parts = J->cg.parts = d->style == HLOD_CITY_STYLE_PARTS;
    J->g.noise_seed = mix64(d->seed ^ 0x6e6f697365ULL);
    J->g.size = d->texture_size;
    J->g.noise = NOISE_WALL;
    memcpy(J->g.origin, d->origin, sizeof J->g.origin);
    J->cg.count_only = 1;
    J->mats = calloc(d->blocks + 1, sizeof *J->mats);
    J->objs = calloc(d->blocks + 1, sizeof *J->objs);
    if (!J->mats || !J->objs)
        return HLOD_ERR_NOMEM;
    if (J->textured) {
        J->img.width = J->img.height = d->texture_size;
        J->img.channels = 3;
        J->img.pixels = malloc((size_t)d->texture_size * (size_t)d->texture_size * 3);
        if (!J->img.pixels)
            return HLOD_ERR_NOMEM;
    }
    /* Taller buildings towards the centre: a downtown and a fringe. */
    J->radius = 0.5 * hypot((double)J->ncols * CELL_W, (double)J->nrows * CELL_D);
    for (size_t bi = 0; bi < d->blocks; bi++) {
        hlod_result res = city_block(J, bi);
        if (res != HLOD_OK)
            return res;
        if (d->progress)
            d->progress(d->progress_user, (double)(bi + 1), (double)(d->blocks + 1));
    }
    hlod_result res = city_ground(J);
    if (res == HLOD_OK && d->progress)
        d->progress(d->progress_user, (double)(d->blocks + 1), (double)(d->blocks + 1));
    return res;
}

hlod_result hlod_city_generate(const hlod_city_desc *desc, hlod_mesh *out, hlod_city_stats *stats)
{
    if (!desc || !out)
        return HLOD_ERR_INVALID_ARG;
    hlod_mesh_free(out);
    city_job J;
    memset(&J, 0, sizeof J);
    J.d = *desc;
    if (!J.d.blocks)
        J.d.blocks = 200;
    if (!J.d.tris_per_block)
        J.d.tris_per_block = 35000;
    if (!J.d.texture_size)
        J.d.texture_size = 1024;
    J.lg = J.d.logger;
    hlod_result res = check_desc(&J.d, J.lg);
    if (res)
        return res;
    res = city_run(&J);
    if (res != HLOD_OK) {
        if (res == HLOD_ERR_NOMEM)
            hlod_logf(J.lg, HLOD_LOG_ERROR, "city: out of memory");
        city_release(&J, 1);
        return res;
    }
    out->vertex_count = J.g.nv;
    out->positions = J.g.pos;
    out->uvs = J.g.uv;
    out->tri_count = J.g.nt;
    out->indices = J.g.idx;
    out->tri_material = J.g.mat;
    out->material_count = J.d.blocks + 1;
    out->materials = J.mats;
    out->object_count = J.d.blocks + 1;
    out->objects = J.objs;
    J.st.tris = J.g.nt;
    J.st.vertices = J.g.nv;
    if (J.st.min_block_tris == SIZE_MAX)
        J.st.min_block_tris = 0;
    if (stats)
        *stats = J.st;
    city_release(&J, 0);
    return HLOD_OK;
}
