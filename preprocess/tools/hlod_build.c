/*
 * hlod-build: meshes in, one HLOD store out.
 *
 *   hlod-build INPUT... -o OUT.hlod [--method cutplane|metis]
 *              [--blocks objects|grid:SIZE] [--desired-tris N]
 *              [--level-factor F] [--voxel-tris N] [--leaf-tris N]
 *              [--node-tris N] [--c-tex C] [--threads T] [--json] [--quiet]
 *
 * Design:
 * - Blocks: each input object (OBJ o/g, glTF node, a PLY/OFF file) or each
 *   grid cell of SIZE model units (by triangle centroid, x and y: z is up).
 *   A block holds one texture at most, so an object whose triangles use
 *   several textures becomes one block per texture (untextured triangles
 *   form their own block).
 * - Blocks build in parallel on T threads (default: every core), each with
 *   the chosen builder (cutplane.c or metis_partition.c); every node's
 *   payload streams into the store as soon as it is made (store_write.h),
 *   and the block's tree is freed, so memory holds the input plus one tree
 *   per thread.
 * - Untextured nodes carry the material's diffuse colour per vertex, and
 *   every node gets per-vertex normals (area-weighted) when it has none.
 * - The store appears at OUT only when complete (temporary file + rename);
 *   any failure leaves nothing at OUT and an old OUT untouched.
 */
#include "build.h"
#include "cli.h"
#include "hlod/image.h"
#include "hlod/mesh_io.h"
#include "hlod/store_write.h"

#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#define PROG "hlod-build"

typedef struct options {
    const char **inputs;
    int n_inputs;
    const char *out;
    int metis;
    double grid;            /* 0: objects */
    hlod_build_params bp;
    double c_tex;
    size_t threads;
    int json, quiet;
} options;

static void usage(FILE *fp)
{
    fprintf(fp,
            "usage: hlod-build INPUT... -o OUT.hlod [options]\n"
            "\n"
            "Builds a hierarchy of levels of detail (HLOD) from meshes (OBJ+MTL, PLY,\n"
            "OFF, glTF) and writes it as one streaming store for the runtime.\n"
            "\n"
            "  -o, --output OUT       the store to write (required)\n"
            "  --method M             cutplane (Lakhia III-A, default) or metis\n"
            "                         (Okamoto 4.1)\n"
            "  --blocks B             objects (default: each input object is a block)\n"
            "                         or grid:SIZE (square cells of SIZE model units\n"
            "                         in x and y; z is up)\n"
            "  --desired-tris N       C_desiredTri: triangles of hlod_0 (cutplane,\n"
            "                         default 4000)\n"
            "  --level-factor F       C_levelFactor: pieces per cut and triangle ratio\n"
            "                         between levels (cutplane, integer >= 2, default 3)\n"
            "  --voxel-tris N         N_v: triangles per voxel (metis, default 500)\n"
            "  --leaf-tris N          N_l: leaf size (metis, default 4000)\n"
            "  --node-tris N          N_n: inner node size (metis, default 2000)\n"
            "  --c-tex C              c_tex of Lakhia eq. 1 in [0, 1] (default 0.5)\n"
            "  --threads T            build threads (default: every core)\n"
            "  --json                 print one JSON object on stdout: blocks, nodes,\n"
            "                         levels, tris_in, tris_leaf, tris_total, bytes,\n"
            "                         seconds, peak_rss_bytes\n"
            "  --quiet                errors only, no progress bar\n"
            "  -h, --help             show this help\n"
            "\n"
            "Exit status: 0 success, 1 failure (nothing written), 2 bad command line.\n");
}

/* ---- blocks ---------------------------------------------------------------- */

typedef struct block {
    hlod_mesh mesh;         /* own vertices, world coordinates */
    const char *texture;    /* borrowed from the input's material, or NULL */
    float color[4];
    char name[96];
    int solid;              /* hlod_mesh_is_solid: nodes may cull back faces */
} block;

typedef struct blocks {
    block *b;
    size_t n, cap;
} blocks;

static block *blocks_add(blocks *bs)
{
    if (bs->n == bs->cap) {
        size_t nc = bs->cap ? bs->cap * 2 : 64;
        block *n = realloc(bs->b, nc * sizeof *n);
        if (!n)
            return NULL;
        bs->b = n;
        bs->cap = nc;
    }
    memset(&bs->b[bs->n], 0, sizeof bs->b[bs->n]);
    return &bs->b[bs->n++];
}

/* What splitting one input mesh into blocks needs across its blocks, sized
 * once for the whole mesh: a block touches only its own vertices (remap is
 * reset through verts), and each material's texture key is found once
 * (a lookup per triangle; scanning the materials per triangle cost
 * seconds on the 200-block default city, as did a whole-mesh remap per
 * block). */
typedef struct splitter {
    const hlod_mesh *m;
    uint32_t *remap;    /* per input vertex: its index in the block, or UINT32_MAX */
    uint32_t *verts;    /* the block's input vertices, in first-use order */
    long *mat_key;      /* per material: the first material with its texture, or -1 */
} splitter;

static void splitter_free(splitter *sp)
{
    free(sp->remap);
    free(sp->verts);
    free(sp->mat_key);
}

static hlod_result splitter_init(splitter *sp, const hlod_mesh *m)
{
    memset(sp, 0, sizeof *sp);
    sp->m = m;
    sp->remap = malloc((m->vertex_count ? m->vertex_count : 1) * sizeof *sp->remap);
    sp->verts = malloc((m->vertex_count ? m->vertex_count : 1) * sizeof *sp->verts);
    sp->mat_key = malloc((m->material_count ? m->material_count : 1) * sizeof *sp->mat_key);
    if (!sp->remap || !sp->verts || !sp->mat_key) {
        splitter_free(sp);
        return HLOD_ERR_NOMEM;
    }
    for (size_t v = 0; v < m->vertex_count; v++)
        sp->remap[v] = UINT32_MAX;
    for (size_t mat = 0; mat < m->material_count; mat++) {
        const char *path = m->materials[mat].texture_path;
        sp->mat_key[mat] = -1;
        for (size_t k = 0; path && k <= mat; k++)
            if (m->materials[k].texture_path && !strcmp(m->materials[k].texture_path, path)) {
                sp->mat_key[mat] = (long)k;
                break;
            }
    }
    return HLOD_OK;
}

/* The mesh of the triangles tris[0..n) of sp->m, with only the vertices
 * they use. */
static hlod_result extract(splitter *sp, const uint32_t *tris, size_t n, hlod_mesh *out)
{
    const hlod_mesh *m = sp->m;
    uint32_t *remap = sp->remap;
    size_t nv = 0;
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < 3; c++) {
            uint32_t v = m->indices[3 * (size_t)tris[i] + c];
            if (remap[v] == UINT32_MAX) {
                remap[v] = (uint32_t)nv;
                sp->verts[nv++] = v;
            }
        }
    unsigned flags = (m->uvs ? HLOD_MESH_UVS : 0) | (m->normals ? HLOD_MESH_NORMALS : 0);
    hlod_result r = hlod_mesh_alloc(out, nv, n, flags);
    if (r == HLOD_OK) {
        for (size_t o = 0; o < nv; o++) {
            size_t v = sp->verts[o];
            memcpy(out->positions + 3 * o, m->positions + 3 * v, 3 * sizeof(double));
            if (m->uvs)
                memcpy(out->uvs + 2 * o, m->uvs + 2 * v, 2 * sizeof(float));
            if (m->normals)
                memcpy(out->normals + 3 * o, m->normals + 3 * v, 3 * sizeof(float));
        }
        for (size_t i = 0; i < n; i++)
            for (int c = 0; c < 3; c++)
                out->indices[3 * i + c] = remap[m->indices[3 * (size_t)tris[i] + c]];
        if (!m->uvs || !out->uvs) {
            free(out->uvs);
            out->uvs = NULL;
        }
    }
    for (size_t o = 0; o < nv; o++)
        remap[sp->verts[o]] = UINT32_MAX;
    return r;
}

/* The texture key of triangle t: the first material with its texture, or
 * -1 when it has none (or the mesh has no UVs). */
static long tex_key(const splitter *sp, size_t t)
{
    const hlod_mesh *m = sp->m;
    uint32_t mat = m->tri_material ? m->tri_material[t] : 0;
    if (!m->uvs || mat >= m->material_count)
        return -1;
    return sp->mat_key[mat];
}

/* Splits triangle set tris (a group: an object or a cell) by texture and
 * appends one block per texture. */
static hlod_result add_group(splitter *sp, uint32_t *tris, size_t n, const char *name, blocks *bs)
{
    const hlod_mesh *m = sp->m;
    /* stable order: by texture key, then triangle order */
    long *key = malloc((n ? n : 1) * sizeof *key);
    if (!key)
        return HLOD_ERR_NOMEM;
    for (size_t i = 0; i < n; i++)
        key[i] = tex_key(sp, tris[i]);
    size_t done = 0;
    uint32_t *sel = malloc((n ? n : 1) * sizeof *sel);
    uint8_t *used = calloc(n ? n : 1, 1);
    hlod_result r = (sel && used) ? HLOD_OK : HLOD_ERR_NOMEM;
    while (r == HLOD_OK && done < n) {
        size_t first = 0;
        while (used[first])
            first++;
        long k = key[first];
        size_t cnt = 0;
        for (size_t i = first; i < n; i++)
            if (!used[i] && key[i] == k) {
                used[i] = 1;
                sel[cnt++] = tris[i];
            }
        done += cnt;
        block *b = blocks_add(bs);
        if (!b) {
            r = HLOD_ERR_NOMEM;
            break;
        }
        r = extract(sp, sel, cnt, &b->mesh);
        if (r != HLOD_OK) {
            bs->n--;
            break;
        }
        if (k < 0) {
            /* untextured: no UVs, the most used material's colour */
            free(b->mesh.uvs);
            b->mesh.uvs = NULL;
        }
        uint32_t mat = m->tri_material ? m->tri_material[sel[0]] : 0;
        const float grey[4] = {0.8f, 0.8f, 0.8f, 1};
        memcpy(b->color, mat < m->material_count ? m->materials[mat].diffuse : grey, sizeof b->color);
        b->texture = k >= 0 ? m->materials[k].texture_path : NULL;
        snprintf(b->name, sizeof b->name, "%s%s", name, k >= 0 && done < n ? "+tex" : "");
    }
    free(key);
    free(sel);
    free(used);
    return r;
}

static hlod_result make_blocks(const hlod_mesh *m, const char *file, double grid, blocks *bs)
{
    uint32_t *tris = malloc((m->tri_count ? m->tri_count : 1) * sizeof *tris);
    splitter sp;
    if (!tris || splitter_init(&sp, m) != HLOD_OK) {
        free(tris);
        return HLOD_ERR_NOMEM;
    }
    hlod_result r = HLOD_OK;
    if (grid <= 0) {
        size_t no = m->object_count ? m->object_count : 1;
        for (size_t o = 0; o < no && r == HLOD_OK; o++) {
            size_t first = m->object_count ? m->objects[o].first_tri : 0;
            size_t cnt = m->object_count ? m->objects[o].tri_count : m->tri_count;
            if (!cnt)
                continue;
            for (size_t i = 0; i < cnt; i++)
                tris[i] = (uint32_t)(first + i);
            const char *name = m->object_count && m->objects[o].name ? m->objects[o].name : file;
            r = add_group(&sp, tris, cnt, name, bs);
        }
    } else {
        /* cells by centroid; cells sorted by (cy, cx) for a stable order */
        double lo[3], hi[3];
        hlod_mesh_bounds(m, lo, hi);
        size_t nx = (size_t)floor((hi[0] - lo[0]) / grid) + 1, ny = (size_t)floor((hi[1] - lo[1]) / grid) + 1;
        if (nx * ny > 1000000) {
            free(tris);
            splitter_free(&sp);
            return HLOD_ERR_INVALID_ARG;
        }
        uint32_t *cell = malloc((m->tri_count ? m->tri_count : 1) * sizeof *cell);
        size_t *start = calloc(nx * ny + 1, sizeof *start);
        if (!cell || !start) {
            free(cell);
            free(start);
            free(tris);
            splitter_free(&sp);
            return HLOD_ERR_NOMEM;
        }
        for (size_t t = 0; t < m->tri_count; t++) {
            double c[2] = {0, 0};
            for (int k = 0; k < 3; k++)
                for (int a = 0; a < 2; a++)
                    c[a] += m->positions[3 * (size_t)m->indices[3 * t + k] + a] / 3;
            size_t ix = (size_t)floor((c[0] - lo[0]) / grid), iy = (size_t)floor((c[1] - lo[1]) / grid);
            ix = ix >= nx ? nx - 1 : ix;
            iy = iy >= ny ? ny - 1 : iy;
            cell[t] = (uint32_t)(iy * nx + ix);
            start[cell[t] + 1]++;
        }
        for (size_t c = 0; c < nx * ny; c++)
            start[c + 1] += start[c];
        size_t *cur = malloc((nx * ny + 1) * sizeof *cur);
        if (!cur) {
            r = HLOD_ERR_NOMEM;
        } else {
            memcpy(cur, start, (nx * ny + 1) * sizeof *cur);
            for (size_t t = 0; t < m->tri_count; t++)
                tris[cur[cell[t]]++] = (uint32_t)t;
            for (size_t c = 0; c < nx * ny && r == HLOD_OK; c++) {
                size_t cnt = start[c + 1] - start[c];
                if (!cnt)
                    continue;
                char name[96];
                snprintf(name, sizeof name, "cell_%zu_%zu", c % nx, c / nx);
                r = add_group(&sp, tris + start[c], cnt, name, bs);
            }
        }
        free(cur);
        free(cell);
        free(start);
    }
    free(tris);
    splitter_free(&sp);
    return r;
}

/* ---- building ---------------------------------------------------------------- */

typedef struct block_out {
    hlod_store_node *nodes;     /* filled by the store writer, parent local */
    uint32_t *parent;           /* local parent index or HLOD_BNODE_NONE */
    size_t count;
    size_t tris_leaf, tris_total;
    uint32_t depth;             /* deepest level + 1 */
} block_out;

typedef struct job {
    const options *opt;
    blocks *bs;
    block_out *out;
    hlod_store_writer *w;
    const hlod_logger *lg;
    size_t next;            /* next block to build (under turn_mu) */
    atomic_size_t done_blocks;
    atomic_int failed;
    /* Payloads go into the store in block order, whatever thread finishes
     * first, so the same input gives a byte-identical store.  A finished
     * tree waits in its slot; whichever worker finds the next block's tree
     * ready emits it (and any ready ones after it), so no worker idles.
     * Workers stay at most LOOKAHEAD blocks ahead of the emitted ones to
     * bound the memory of waiting trees. */
    pthread_mutex_t turn_mu;
    pthread_cond_t turn_cv;
    size_t turn;            /* next block to emit */
    int emitting;           /* a worker is emitting now */
    hlod_btree *slot;       /* per block: its finished tree */
    uint8_t *ready;
} job;

#define LOOKAHEAD 8

/* Area-weighted vertex normals for a node without any. */
static float *vertex_normals(const hlod_mesh *m)
{
    double *acc = calloc(m->vertex_count * 3 + 1, sizeof *acc);
    float *n = malloc((m->vertex_count * 3 + 1) * sizeof *n);
    if (!acc || !n) {
        free(acc);
        free(n);
        return NULL;
    }
    for (size_t t = 0; t < m->tri_count; t++) {
        const uint32_t *ix = m->indices + 3 * t;
        const double *a = m->positions + 3 * (size_t)ix[0], *b = m->positions + 3 * (size_t)ix[1],
                     *c = m->positions + 3 * (size_t)ix[2];
        double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        double f[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
        for (int k = 0; k < 3; k++)
            for (int j = 0; j < 3; j++)
                acc[3 * (size_t)ix[k] + j] += f[j];
    }
    for (size_t v = 0; v < m->vertex_count; v++) {
        double *a = acc + 3 * v;
        double l = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        for (int j = 0; j < 3; j++)
            n[3 * v + j] = l > 0 ? (float)(a[j] / l) : (j == 2 ? 1.0f : 0.0f);
    }
    free(acc);
    return n;
}

static hlod_result emit_block(job *J, size_t bi, hlod_btree *t)
{
    block *b = &J->bs->b[bi];
    block_out *o = &J->out[bi];
    o->nodes = calloc(t->count, sizeof *o->nodes);
    o->parent = malloc(t->count * sizeof *o->parent);
    if (!o->nodes || !o->parent)
        return HLOD_ERR_NOMEM;
    o->count = t->count;
    uint8_t rgba[4];
    for (int k = 0; k < 4; k++) {
        float c = b->color[k] < 0 ? 0 : b->color[k] > 1 ? 1 : b->color[k];
        rgba[k] = (uint8_t)lrintf(c * 255);
    }
    for (size_t k = 0; k < t->count; k++) {
        const hlod_bnode *n = &t->nodes[k];
        const hlod_mesh *m = &n->mesh;
        double lo[3], hi[3];
        hlod_mesh_bounds(m, lo, hi);
        hlod_store_payload_desc d = {0};
        d.vertex_count = (uint32_t)m->vertex_count;
        d.positions = m->positions;
        for (int a = 0; a < 3; a++)
            d.origin[a] = 0.5 * (lo[a] + hi[a]);
        float *normals = NULL;
        uint8_t *colors = NULL;
        if (m->normals) {
            d.normals = m->normals;
        } else {
            normals = vertex_normals(m);
            if (!normals)
                return HLOD_ERR_NOMEM;
            d.normals = normals;
        }
        d.tri_count = (uint32_t)m->tri_count;
        d.indices = m->indices;
        if (n->tex.width && m->uvs) {
            d.uvs = m->uvs;
            d.tex_tri_count = d.tri_count;
            d.tex_width = (uint32_t)n->tex.width;
            d.tex_height = (uint32_t)n->tex.height;
            d.tex_channels = (uint32_t)n->tex.channels;
            d.pixels = n->tex.pixels;
        } else {
            colors = malloc(m->vertex_count * 4 + 1);
            if (!colors) {
                free(normals);
                return HLOD_ERR_NOMEM;
            }
            for (size_t v = 0; v < m->vertex_count; v++)
                memcpy(colors + 4 * v, rgba, 4);
            d.colors = colors;
        }
        hlod_result r = hlod_store_writer_add(J->w, &d, &o->nodes[k]);
        free(normals);
        free(colors);
        if (r != HLOD_OK)
            return r;
        o->nodes[k].error = n->error;
        o->nodes[k].render_flags = b->solid ? HLOD_RENDER_SOLID : 0;
        o->parent[k] = n->parent;
        o->tris_total += m->tri_count;
        if (n->depth + 1 > o->depth)
            o->depth = n->depth + 1;
        int leaf = 1;
        for (size_t c = k + 1; c < t->count && leaf; c++)
            leaf = t->nodes[c].parent != k;
        if (leaf)
            o->tris_leaf += m->tri_count;
    }
    return HLOD_OK;
}

/* called from a build thread, with turn_mu held: emits every ready block
 * from J->turn on (releasing the lock while it writes). */
static void emit_ready(job *J)
{
    if (J->emitting)
        return;
    J->emitting = 1;
    while (J->turn < J->bs->n && J->ready[J->turn]) {
        size_t bi = J->turn;
        pthread_mutex_unlock(&J->turn_mu);
        hlod_result r = atomic_load(&J->failed) ? HLOD_OK : emit_block(J, bi, &J->slot[bi]);
        if (r != HLOD_OK) {
            hlod_logf(J->lg, HLOD_LOG_ERROR, "block %s: cannot store: %s", J->bs->b[bi].name, hlod_result_str(r));
            atomic_store(&J->failed, 1);
        }
        hlod_btree_free(&J->slot[bi]);
        atomic_fetch_add(&J->done_blocks, 1);
        pthread_mutex_lock(&J->turn_mu);
        J->turn = bi + 1;
        pthread_cond_broadcast(&J->turn_cv);
    }
    J->emitting = 0;
}

/* called from a build thread */
static void *worker(void *arg)
{
    job *J = arg;
    for (;;) {
        pthread_mutex_lock(&J->turn_mu);
        while (J->next < J->bs->n && J->next >= J->turn + LOOKAHEAD && !atomic_load(&J->failed))
            pthread_cond_wait(&J->turn_cv, &J->turn_mu);
        size_t bi = J->next++;
        pthread_mutex_unlock(&J->turn_mu);
        if (bi >= J->bs->n || atomic_load(&J->failed))
            break;
        block *b = &J->bs->b[bi];
        hlod_image tex = {0};
        const hlod_image *texp = NULL;
        hlod_result r = HLOD_OK;
        if (b->texture) {
            r = hlod_image_read(b->texture, &tex, J->lg);
            if (r == HLOD_OK)
                texp = &tex;
            else {
                hlod_logf(J->lg, HLOD_LOG_WARN, "block %s: texture %s unreadable, built untextured", b->name,
                          b->texture);
                free(b->mesh.uvs);
                b->mesh.uvs = NULL;
                r = HLOD_OK;
            }
        }
        b->solid = hlod_mesh_is_solid(&b->mesh);
        hlod_btree t = {0};
        hlod_build_params bp = J->opt->bp;
        bp.logger = J->lg;
        if (r == HLOD_OK)
            r = J->opt->metis ? hlod_build_metis(&b->mesh, texp, &bp, &t)
                              : hlod_build_cutplane(&b->mesh, texp, &bp, &t);
        if (r != HLOD_OK) {
            hlod_logf(J->lg, HLOD_LOG_ERROR, "block %s (%zu triangles): %s", b->name, b->mesh.tri_count,
                      hlod_result_str(r));
            atomic_store(&J->failed, 1);
            hlod_btree_free(&t);
        }
        hlod_image_free(&tex);
        hlod_mesh_free(&b->mesh);
        pthread_mutex_lock(&J->turn_mu);
        J->slot[bi] = t;
        J->ready[bi] = 1;
        emit_ready(J);
        pthread_cond_broadcast(&J->turn_cv);
        pthread_mutex_unlock(&J->turn_mu);
    }
    return NULL;
}

/* ---- command line ------------------------------------------------------------ */

static int parse(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    o->bp.desired_tris = 4000;
    o->bp.level_factor = 3;
    o->bp.voxel_tris = 500;
    o->bp.leaf_tris = 4000;
    o->bp.node_tris = 2000;
    o->bp.seed = 1;
    o->c_tex = 0.5;
    long cpus = sysconf(_SC_NPROCESSORS_ONLN);
    o->threads = cpus > 0 ? (size_t)cpus : 1;
    o->inputs = calloc((size_t)argc, sizeof *o->inputs);
    if (!o->inputs)
        return 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *val = NULL;
        char flag[64];
        const char *eq = strncmp(a, "--", 2) == 0 ? strchr(a, '=') : NULL;
        if (eq && (size_t)(eq - a) < sizeof flag) {
            memcpy(flag, a, (size_t)(eq - a));
            flag[eq - a] = 0;
            val = eq + 1;
            a = flag;
        }
#define NEED_VAL()                                                                   \
    do {                                                                             \
        if (!val) {                                                                  \
            if (i + 1 >= argc) {                                                     \
                hlod_cli_error(PROG, "%s: needs a value", a);                        \
                return 0;                                                            \
            }                                                                        \
            val = argv[++i];                                                         \
        }                                                                            \
    } while (0)
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            exit(0);
        } else if (!strcmp(a, "-o") || !strcmp(a, "--output")) {
            NEED_VAL();
            o->out = val;
        } else if (!strcmp(a, "--method")) {
            NEED_VAL();
            if (!strcmp(val, "cutplane"))
                o->metis = 0;
            else if (!strcmp(val, "metis"))
                o->metis = 1;
            else {
                hlod_cli_error(PROG, "--method: '%s' is not cutplane or metis", val);
                return 0;
            }
        } else if (!strcmp(a, "--blocks")) {
            NEED_VAL();
            if (!strcmp(val, "objects"))
                o->grid = 0;
            else if (!strncmp(val, "grid:", 5)) {
                if (!hlod_cli_parse_double(PROG, "--blocks grid:SIZE", val + 5, 0, 1e12, HLOD_CLI_MIN_OPEN,
                                           &o->grid))
                    return 0;
            } else {
                hlod_cli_error(PROG, "--blocks: '%s' is not objects or grid:SIZE", val);
                return 0;
            }
        } else if (!strcmp(a, "--desired-tris")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 1, 1u << 30, &o->bp.desired_tris))
                return 0;
        } else if (!strcmp(a, "--level-factor")) {
            NEED_VAL();
            size_t f;
            if (!hlod_cli_parse_size(PROG, a, val, 2, 64, &f))
                return 0;
            o->bp.level_factor = (double)f;
        } else if (!strcmp(a, "--voxel-tris")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 1, 1u << 30, &o->bp.voxel_tris))
                return 0;
        } else if (!strcmp(a, "--leaf-tris")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 2, 1u << 30, &o->bp.leaf_tris))
                return 0;
        } else if (!strcmp(a, "--node-tris")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 1, 1u << 30, &o->bp.node_tris))
                return 0;
        } else if (!strcmp(a, "--c-tex")) {
            NEED_VAL();
            if (!hlod_cli_parse_double(PROG, a, val, 0, 1, 0, &o->c_tex))
                return 0;
        } else if (!strcmp(a, "--threads")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 1, 256, &o->threads))
                return 0;
        } else if (!strcmp(a, "--json")) {
            o->json = 1;
        } else if (!strcmp(a, "--quiet")) {
            o->quiet = 1;
        } else if (a[0] == '-' && a[1]) {
            hlod_cli_error(PROG, "unknown option %s (see --help)", a);
            return 0;
        } else {
            o->inputs[o->n_inputs++] = a;
        }
#undef NEED_VAL
    }
    if (!o->n_inputs) {
        hlod_cli_error(PROG, "no input mesh (see --help)");
        return 0;
    }
    if (!o->out) {
        hlod_cli_error(PROG, "no output: -o OUT.hlod is required");
        return 0;
    }
    if (o->metis && o->bp.node_tris >= o->bp.leaf_tris)
        hlod_cli_error(PROG, "warning: --node-tris %zu >= --leaf-tris %zu: inner nodes simplify little",
                       o->bp.node_tris, o->bp.leaf_tris);
    return 1;
}

int main(int argc, char **argv)
{
    options opt;
    if (!parse(argc, argv, &opt)) {
        free(opt.inputs);
        return 2;
    }
    double t0 = hlod_cli_now();
    hlod_cli_progress bar;
    hlod_cli_progress_begin(&bar, "blocks", !opt.quiet);
    hlod_cli_log ls = {PROG, opt.quiet ? HLOD_LOG_ERROR : HLOD_LOG_WARN, &bar};
    hlod_logger lg = hlod_cli_logger(&ls);

    /* The output folder must exist before hours of work. */
    {
        char dir[4096];
        snprintf(dir, sizeof dir, "%s", opt.out);
        char *slash = strrchr(dir, '/');
        if (slash) {
            *slash = 0;
            struct stat st;
            if (dir[0] && (stat(dir, &st) != 0 || !S_ISDIR(st.st_mode))) {
                hlod_cli_error(PROG, "%s: output folder %s does not exist", opt.out, dir);
                free(opt.inputs);
                return 1;
            }
        }
    }

    hlod_mesh *meshes = calloc((size_t)opt.n_inputs, sizeof *meshes);
    blocks bs = {0};
    size_t tris_in = 0;
    int status = 1;
    hlod_store_writer *w = NULL;
    block_out *outs = NULL;
    if (!meshes)
        goto done;
    for (int i = 0; i < opt.n_inputs; i++) {
        hlod_import_desc idesc = {&lg, 0};
        hlod_result r = hlod_mesh_import(opt.inputs[i], &idesc, &meshes[i], NULL);
        if (r != HLOD_OK) {
            hlod_cli_error(PROG, "%s: cannot read: %s", opt.inputs[i], hlod_result_str(r));
            goto done;
        }
        tris_in += meshes[i].tri_count;
        const char *base = strrchr(opt.inputs[i], '/');
        r = make_blocks(&meshes[i], base ? base + 1 : opt.inputs[i], opt.grid, &bs);
        if (r != HLOD_OK) {
            hlod_cli_error(PROG, "%s: cannot split into blocks: %s", opt.inputs[i], hlod_result_str(r));
            goto done;
        }
        /* the blocks own copies; keep only what they borrow (texture paths) */
        free(meshes[i].positions);
        free(meshes[i].normals);
        free(meshes[i].uvs);
        free(meshes[i].indices);
        free(meshes[i].tri_material);
        meshes[i].positions = NULL;
        meshes[i].normals = NULL;
        meshes[i].uvs = NULL;
        meshes[i].indices = NULL;
        meshes[i].tri_material = NULL;
    }
    if (!bs.n) {
        hlod_cli_error(PROG, "no triangles in the input");
        goto done;
    }

    hlod_store_writer_desc wd = {0};
    wd.build.method = opt.metis ? HLOD_STORE_METHOD_METIS : HLOD_STORE_METHOD_CUTPLANE;
    wd.build.desired_tris = opt.metis ? 0 : opt.bp.desired_tris;
    wd.build.level_factor = opt.metis ? 0 : opt.bp.level_factor;
    wd.build.voxel_tris = opt.metis ? opt.bp.voxel_tris : 0;
    wd.build.leaf_tris = opt.metis ? opt.bp.leaf_tris : 0;
    wd.build.node_tris = opt.metis ? opt.bp.node_tris : 0;
    wd.build.c_tex = opt.c_tex;
    wd.logger = &lg;
    hlod_result r = hlod_store_writer_open(opt.out, &wd, &w);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot create: %s", opt.out, hlod_result_str(r));
        goto done;
    }
    outs = calloc(bs.n, sizeof *outs);
    if (!outs)
        goto done;

    job J = {.opt = &opt, .bs = &bs, .out = outs, .w = w, .lg = &lg};
    J.slot = calloc(bs.n, sizeof *J.slot);
    J.ready = calloc(bs.n, 1);
    if (!J.slot || !J.ready) {
        free(J.slot);
        free(J.ready);
        goto done;
    }
    pthread_mutex_init(&J.turn_mu, NULL);
    pthread_cond_init(&J.turn_cv, NULL);
    size_t nth = opt.threads < bs.n ? opt.threads : bs.n;
    pthread_t *th = calloc(nth, sizeof *th);
    if (!th)
        goto done;
    size_t started = 0;
    for (; started < nth; started++)
        if (pthread_create(&th[started], NULL, worker, &J) != 0)
            break;
    if (!started) {
        free(th);
        hlod_cli_error(PROG, "cannot start build threads");
        goto done;
    }
    /* the main thread draws the progress bar */
    while (atomic_load(&J.done_blocks) < bs.n && !atomic_load(&J.failed)) {
        hlod_cli_progress_fn(&bar, (double)atomic_load(&J.done_blocks), (double)bs.n);
        nanosleep(&(struct timespec){0, 100000000}, NULL);
    }
    for (size_t i = 0; i < started; i++)
        pthread_join(th[i], NULL);
    free(th);
    pthread_mutex_destroy(&J.turn_mu);
    pthread_cond_destroy(&J.turn_cv);
    for (size_t b = 0; b < bs.n; b++)
        hlod_btree_free(&J.slot[b]);
    free(J.slot);
    free(J.ready);
    hlod_cli_progress_clear(&bar);
    if (atomic_load(&J.failed))
        goto done;

    /* Global node list: blocks in order, parents as global indices. */
    size_t total = 0, tris_leaf = 0, tris_total = 0;
    uint32_t levels = 0;
    for (size_t b = 0; b < bs.n; b++) {
        total += outs[b].count;
        tris_leaf += outs[b].tris_leaf;
        tris_total += outs[b].tris_total;
        levels = outs[b].depth > levels ? outs[b].depth : levels;
    }
    if (total >= UINT32_MAX)
        goto done;
    hlod_store_node *all = calloc(total, sizeof *all);
    if (!all)
        goto done;
    size_t base = 0;
    for (size_t b = 0; b < bs.n; b++) {
        for (size_t k = 0; k < outs[b].count; k++) {
            hlod_store_node *n = &all[base + k];
            *n = outs[b].nodes[k];
            n->parent = outs[b].parent[k] == HLOD_BNODE_NONE ? HLOD_STORE_NO_PARENT
                                                             : (uint32_t)(base + outs[b].parent[k]);
            n->block = (uint32_t)b;
        }
        base += outs[b].count;
    }
    r = hlod_store_writer_finish(w, all, (uint32_t)total, NULL);
    w = NULL;
    free(all);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot finish the store: %s", opt.out, hlod_result_str(r));
        goto done;
    }
    struct stat st;
    size_t bytes = stat(opt.out, &st) == 0 ? (size_t)st.st_size : 0;
    double secs = hlod_cli_now() - t0;
    if (!opt.quiet)
        fprintf(stderr, "%s: %s: %zu blocks, %zu nodes, %u levels, %zu -> %zu leaf triangles, %.1f MB, %.1f s\n",
                PROG, opt.out, bs.n, total, levels, tris_in, tris_leaf, bytes / 1e6, secs);
    if (opt.json) {
        hlod_json j;
        hlod_json_begin(&j, stdout);
        hlod_json_size(&j, "blocks", bs.n);
        hlod_json_size(&j, "nodes", total);
        hlod_json_size(&j, "levels", levels);
        hlod_json_size(&j, "tris_in", tris_in);
        hlod_json_size(&j, "tris_leaf", tris_leaf);
        hlod_json_size(&j, "tris_total", tris_total);
        hlod_json_size(&j, "bytes", bytes);
        hlod_json_double(&j, "seconds", secs);
        hlod_json_size(&j, "peak_rss_bytes", hlod_cli_peak_rss());
        hlod_json_string(&j, "method", opt.metis ? "metis" : "cutplane");
        hlod_json_size(&j, "threads", opt.threads);
        if (hlod_json_end(&j) != 0)
            goto done;
    }
    status = 0;
done:
    if (w)
        hlod_store_writer_abort(w);
    if (outs)
        for (size_t b = 0; b < bs.n; b++) {
            free(outs[b].nodes);
            free(outs[b].parent);
        }
    free(outs);
    for (size_t b = 0; b < bs.n; b++)
        hlod_mesh_free(&bs.b[b].mesh);
    free(bs.b);
    if (meshes)
        for (int i = 0; i < opt.n_inputs; i++)
            hlod_mesh_free(&meshes[i]);
    free(meshes);
    free(opt.inputs);
    return status;
}
