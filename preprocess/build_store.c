/*
 * build_store.c - the build pipeline behind hlod_build_store
 * (hlod/build_store.h; docs/hlod-build.md).
 *
 * - Blocks: each input object (OBJ o/g, glTF node, a PLY/OFF file) or each
 *   grid cell of SIZE model units (by triangle centroid, x and y: z is up).
 *   A block holds one texture at most, so an object whose triangles use
 *   several textures becomes one block per texture (untextured triangles
 *   form their own block).
 * - Blocks build in parallel on T threads (default: every core), each with
 *   the chosen builder (cutplane.c or metis_partition.c); every node's
 *   payload streams into the store as soon as it is made (store_write.h),
 *   in block order whatever thread finishes first, and the block's tree is
 *   freed, so memory holds the input plus a few trees per thread.
 * - Untextured nodes carry the material's diffuse colour per vertex, and
 *   every node gets per-vertex normals (area-weighted) when it has none.
 * - City levels (city_levels.c): once every block is built, group nodes
 *   over the blocks' hlod_0 nodes, up to one root.
 * - The store appears at the output path only when complete (temporary
 *   file + rename); any failure leaves nothing there and an old store
 *   untouched.
 */
#include "hlod/build_store.h"

#include <errno.h>

#include "atomic_file.h"

#include "build.h"
#include "hlod_clock.h"
#include "city_levels.h"
#include "build_node.h"
#include "part.h"
#include "sampletree.h"
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
    long *col_key;      /* per material: the first material with its diffuse colour */
} splitter;

static void splitter_free(splitter *sp)
{
    free(sp->remap);
    free(sp->verts);
    free(sp->mat_key);
    free(sp->col_key);
}

static hlod_result splitter_init(splitter *sp, const hlod_mesh *m)
{
    memset(sp, 0, sizeof *sp);
    sp->m = m;
    sp->remap = malloc((m->vertex_count ? m->vertex_count : 1) * sizeof *sp->remap);
    sp->verts = malloc((m->vertex_count ? m->vertex_count : 1) * sizeof *sp->verts);
    sp->mat_key = malloc((m->material_count ? m->material_count : 1) * sizeof *sp->mat_key);
    sp->col_key = malloc((m->material_count ? m->material_count : 1) * sizeof *sp->col_key);
    if (!sp->remap || !sp->verts || !sp->mat_key || !sp->col_key) {
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
        sp->col_key[mat] = (long)mat;
        for (size_t k = 0; k < mat; k++)
            if (!memcmp(m->materials[k].diffuse, m->materials[mat].diffuse,
                        sizeof m->materials[k].diffuse)) {
                sp->col_key[mat] = (long)k;
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

/* The key of triangle t's block: the first material with its texture;
 * untextured (no texture, or the mesh has no UVs), -2 - the first
 * material with its diffuse colour, since an untextured block carries one
 * colour; -1 without a material (grey). */
static long tex_key(const splitter *sp, size_t t)
{
    const hlod_mesh *m = sp->m;
    uint32_t mat = m->tri_material ? m->tri_material[t] : 0;
    if (mat >= m->material_count)
        return -1;
    if (m->uvs && sp->mat_key[mat] >= 0)
        return sp->mat_key[mat];
    return -2 - sp->col_key[mat];
}

/* Splits triangle set tris (a group: an object or a cell) by texture, and
 * its untextured triangles by colour, and appends one block per key. */
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
        /* (counted in double first: a tiny cell must not overflow size_t) */
        double fx = floor((hi[0] - lo[0]) / grid) + 1, fy = floor((hi[1] - lo[1]) / grid) + 1;
        if (!(fx * fy <= 1000000)) {
            free(tris);
            splitter_free(&sp);
            return HLOD_ERR_INVALID_ARG;
        }
        size_t nx = (size_t)fx, ny = (size_t)fy;
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
    hlod_city_item top;         /* city levels: its hlod_0 node, kept */
} block_out;

typedef struct job {
    const hlod_build_desc *desc;
    hlod_build_params bp;
    blocks *bs;
    block_out *out;
    hlod_store_writer *w;
    const hlod_logger *lg;
    int keep_top;           /* keep each block's hlod_0 for the city levels */
    size_t next;            /* next block to build (under turn_mu) */
    atomic_size_t done_blocks;
    atomic_int failed;
    hlod_build_timing timing;   /* the builders' parts */
    _Atomic uint64_t texture_read_ns, tree_ns, store_ns; /* the workers' steps */
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
        hlod_result r = hlod_build_add_payload(J->w, m, &n->tex, m->tri_count, NULL, rgba, &o->nodes[k]);
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
    if (J->keep_top) {
        /* the hlod_0 node moves out of the tree, which is freed next */
        hlod_city_item *it = &o->top;
        hlod_bnode *n0 = &t->nodes[0];
        it->mesh = n0->mesh;
        it->tex = n0->tex;
        memset(&n0->mesh, 0, sizeof n0->mesh);
        memset(&n0->tex, 0, sizeof n0->tex);
        it->tex_tris = it->tex.width && it->mesh.uvs ? it->mesh.tri_count : 0;
        memcpy(it->color, rgba, 4);
        it->error = n0->error;
        it->source_tris = n0->source_tris ? n0->source_tris : it->mesh.tri_count;
        it->solid = b->solid;
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
        uint64_t t0 = hlod_thread_ns();
        hlod_result r = atomic_load(&J->failed) ? HLOD_OK : emit_block(J, bi, &J->slot[bi]);
        hlod_timing_add(&J->store_ns, t0);
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
        uint64_t t0 = hlod_thread_ns();
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
        hlod_timing_add(&J->texture_read_ns, t0);
        b->solid = hlod_mesh_is_solid(&b->mesh);
        hlod_btree t = {0};
        hlod_build_params bp = J->bp;
        bp.logger = J->lg;
        bp.timing = &J->timing;
        t0 = hlod_thread_ns();
        if (r == HLOD_OK)
            r = J->desc->method == HLOD_BUILD_METIS ? hlod_build_metis(&b->mesh, texp, &bp, &t)
                                                    : hlod_build_cutplane(&b->mesh, texp, &bp, &t);
        hlod_timing_add(&J->tree_ns, t0);
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

/* ---- the pipeline ----------------------------------------------------------- */

void hlod_build_desc_defaults(hlod_build_desc *d)
{
    memset(d, 0, sizeof *d);
    d->method = HLOD_BUILD_CUTPLANE;
    d->desired_tris = 4000;
    d->level_factor = 3;
    d->voxel_tris = 500;
    d->leaf_tris = 4000;
    d->node_tris = 2000;
    d->c_tex = 0.5;
    d->sample_c = HLOD_BUILD_SAMPLE_C;
    d->seed = 1;
    d->city_levels = 1;
    d->compress = 1;
    d->quant_bits = 24;
    d->jpeg_quality = 90;
    d->texture_blocks = 1;
    d->texture_min_db = 38;
}

/* The descriptor's values, each in the range hlod-build's flags allow. */
static hlod_result check_desc(const hlod_build_desc *d, const hlod_logger *lg)
{
    const char *bad = NULL;
    if (d->method != HLOD_BUILD_CUTPLANE && d->method != HLOD_BUILD_METIS &&
        d->method != HLOD_BUILD_SAMPLETREE && d->method != HLOD_BUILD_CUBES)
        bad = "method is not cutplane, metis, sampletree or cubes";
    else if (!(d->sample_c > 0 && d->sample_c <= 1000))
        bad = "sample_c is not in (0, 1000]";
    else if ((d->method == HLOD_BUILD_SAMPLETREE || d->method == HLOD_BUILD_CUBES) &&
             d->shard_count)
        bad = "a sample tree or colour cubes are built whole (no shards)";
    else if (d->memory_mb > (1u << 24))
        bad = "memory_mb is over 2^24";
    else if (!(isfinite(d->grid) && d->grid >= 0 && d->grid <= 1e12))
        bad = "grid is not a cell size in [0, 1e12]";
    else if (d->desired_tris < 1 || d->voxel_tris < 1 || d->node_tris < 1 || d->leaf_tris < 2)
        bad = "a triangle count is zero (leaf_tris needs 2)";
    else if (!(d->level_factor >= 2 && d->level_factor <= 64) || d->level_factor != floor(d->level_factor))
        bad = "level_factor is not a whole number in [2, 64]";
    else if (!(d->c_tex >= 0 && d->c_tex <= 1))
        bad = "c_tex is not in [0, 1]";
    else if (d->threads > 256)
        bad = "threads is over 256";
    else if (d->compress && (d->quant_bits < 8 || d->quant_bits > 24))
        bad = "quant_bits is not in [8, 24]";
    else if (d->jpeg_quality > 100)
        bad = "jpeg_quality is over 100";
    else if (!(d->texture_min_db >= 0 && d->texture_min_db <= 99))
        bad = "texture_min_db is not in [0, 99]";
    else if (d->shard_count > 65536 || (d->shard_count && (d->shard_index < 1 || d->shard_index > d->shard_count)))
        bad = "shard is not I/N with 1 <= I <= N <= 65536";
    if (!bad)
        return HLOD_OK;
    hlod_logf(lg, HLOD_LOG_ERROR, "build: %s", bad);
    return HLOD_ERR_INVALID_ARG;
}

/* The packed store's position grid (docs/store-format.md): its origin the
 * input's box corner, its step the largest power of two at most the box's
 * diagonal / 2^bits.  Both depend only on the input, so a city moved by a
 * whole number of steps quantizes exactly as before. */
static void position_grid(const double (*blo)[3], const double (*bhi)[3], size_t nb,
                          unsigned bits, hlod_store_writer_desc *wd)
{
    /* the blocks' boxes are of their vertices: their union is the input's */
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (size_t b = 0; b < nb; b++)
        for (int k = 0; k < 3; k++) {
            lo[k] = fmin(lo[k], blo[b][k]);
            hi[k] = fmax(hi[k], bhi[b][k]);
        }
    double diag = 0;
    for (int k = 0; k < 3; k++)
        diag += (hi[k] - lo[k]) * (hi[k] - lo[k]);
    diag = sqrt(diag);
    int e = 0;
    (void)frexp(diag > 0 ? ldexp(diag, -(int)bits) : 1.0, &e);   /* x = f * 2^e, f in [0.5, 1) */
    wd->quant_step = ldexp(1.0, e - 1);
    for (int k = 0; k < 3; k++)
        wd->quant_origin[k] = isfinite(lo[k]) ? lo[k] : 0;
}

/* The output folder must exist before hours of work. */
static hlod_result check_out_dir(const char *out, const hlod_logger *lg)
{
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", out);
    char *slash = strrchr(dir, '/');
    if (!slash)
        return HLOD_OK;
    *slash = 0;
    struct stat st;
    if (dir[0] && (stat(dir, &st) != 0 || !S_ISDIR(st.st_mode))) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: output folder %s does not exist", out, dir);
        return HLOD_ERR_IO;
    }
    return HLOD_OK;
}

/* Reads every input and splits it into blocks; the blocks own copies of
 * the geometry, the meshes keep only what blocks borrow (texture paths). */
/* What read_blocks keeps of the blocks: all of them (a build), only
 * their boxes (a shard's first pass: every block's box, the geometry
 * dropped file by file), or those marked in keep (a shard's second pass:
 * gid[k] receives the k-th kept block's index in the whole input). */
typedef struct read_mode {
    int boxes_only;
    double (*lo)[3], (*hi)[3];  /* boxes_only: every block's box (grown here) */
    size_t count, cap;          /* blocks seen so far */
    const uint8_t *keep;        /* per block of the whole input, or NULL */
    uint32_t *gid;
    size_t *file_blocks;        /* per input file: its blocks and triangles */
    size_t *file_tris;          /* (boxes_only fills them; keep skips the
                                   files without a kept block) */
    size_t *file_objs;          /* per input file: its objects in objs */
    /* OBJ files are streamed one object at a time (hlod_obj_stream), so a
     * shard holds the vertices its objects use, not the file: per object of
     * such files, in input order, what it gave in the first pass */
    struct obj_rec {
        hlod_obj_info info;
        size_t blocks;
    } *objs;
    size_t nobj, objcap;
} read_mode;

/* keep: does input file i hold no kept block?  Then it is skipped. */
static int skip_file(read_mode *mode, size_t i, size_t *tris_in)
{
    if (!mode || !mode->keep)
        return 0;
    for (size_t b = 0; b < mode->file_blocks[i]; b++)
        if (mode->keep[mode->count + b])
            return 0;
    mode->count += mode->file_blocks[i];
    *tris_in += mode->file_tris[i];
    return 1;
}

/* Applies mode to the blocks bs->b[first .. n) just made from one file. */
static hlod_result filter_blocks(blocks *bs, size_t first, read_mode *mode)
{
    if (!mode)
        return HLOD_OK;
    size_t made = bs->n - first;
    if (mode->boxes_only && mode->count + made > mode->cap) {
        size_t cap = mode->cap ? mode->cap : 64;
        while (cap < mode->count + made)
            cap *= 2;
        double (*lo)[3] = realloc(mode->lo, cap * sizeof *lo);
        if (lo)
            mode->lo = lo;
        double (*hi)[3] = realloc(mode->hi, cap * sizeof *hi);
        if (hi)
            mode->hi = hi;
        if (!lo || !hi)
            return HLOD_ERR_NOMEM;
        mode->cap = cap;
    }
    size_t kept = first;
    for (size_t b = first; b < bs->n; b++, mode->count++) {
        block *bl = &bs->b[b];
        if (mode->boxes_only) {
            if (!hlod_mesh_bounds(&bl->mesh, mode->lo[mode->count], mode->hi[mode->count]))
                for (int k = 0; k < 3; k++)
                    mode->lo[mode->count][k] = mode->hi[mode->count][k] = 0;
            hlod_mesh_free(&bl->mesh);
        } else if (mode->keep[mode->count]) {
            mode->gid[kept] = (uint32_t)mode->count;
            bs->b[kept++] = *bl;
        } else {
            hlod_mesh_free(&bl->mesh);
        }
    }
    bs->n = mode->boxes_only ? first : kept;
    return HLOD_OK;
}

/* One OBJ file streamed object by object (a shard's passes). */
typedef struct stream_ctx {
    const char *path, *base;
    blocks *bs;
    read_mode *mode;
    size_t *tris_in;
    size_t obj0;                /* the file's first object in mode->objs */
    const hlod_logger *lg;
} stream_ctx;

static hlod_result stream_changed(const stream_ctx *c)
{
    hlod_logf(c->lg, HLOD_LOG_ERROR, "%s: changed while it was read", c->path);
    return HLOD_ERR_IO;
}

/* The keep pass: does object k of the file hold a kept block?  (Called as
 * the object starts: the blocks before it are counted.) */
static int stream_want(void *user, size_t k)
{
    stream_ctx *c = user;
    read_mode *mode = c->mode;
    size_t g = c->obj0 + k;
    if (mode->boxes_only || g >= mode->nobj)
        return 1;
    for (size_t b = 0; b < mode->objs[g].blocks; b++)
        if (mode->keep[mode->count + b])
            return 1;
    return 0;
}

static hlod_result stream_object(void *user, const hlod_obj_info *info, const hlod_mesh *m)
{
    stream_ctx *c = user;
    read_mode *mode = c->mode;
    size_t g = c->obj0 + info->index;
    if (mode->boxes_only) {
        if (g >= mode->objcap) {
            size_t cap = mode->objcap ? 2 * mode->objcap : 256;
            struct obj_rec *o = realloc(mode->objs, cap * sizeof *o);
            if (!o)
                return HLOD_ERR_NOMEM;
            mode->objs = o;
            mode->objcap = cap;
        }
        mode->objs[g] = (struct obj_rec){*info, 0};
        mode->nobj = g + 1;
    } else if (g >= mode->nobj || memcmp(&info->v, &mode->objs[g].info.v, 3 * sizeof info->v)) {
        return stream_changed(c);
    }
    struct obj_rec *o = &mode->objs[g];
    if (!m) { /* not the shard's */
        mode->count += o->blocks;
        *c->tris_in += o->info.tris;
        return HLOD_OK;
    }
    hlod_result r = hlod_build_check_coords(m, c->path, c->lg);
    if (r != HLOD_OK)
        return r;
    *c->tris_in += m->tri_count;
    size_t first = c->bs->n;
    if ((r = make_blocks(m, c->base, 0, c->bs)) != HLOD_OK) {
        hlod_logf(c->lg, HLOD_LOG_ERROR, "%s: cannot split into blocks: %s", c->path,
                  hlod_result_str(r));
        return r;
    }
    if (mode->boxes_only)
        o->blocks = c->bs->n - first;
    else if (o->blocks != c->bs->n - first || o->info.tris != m->tri_count)
        return stream_changed(c);
    return filter_blocks(c->bs, first, mode);
}

static int range_cmp(const void *a, const void *b)
{
    const hlod_obj_range *x = a, *y = b;
    return x->lo < y->lo ? -1 : x->lo > y->lo;
}

/* The keep pass: the v/vt/vn lines the file's kept objects use, merged
 * (keep[k]: NULL in the first pass, every position read). */
static hlod_result stream_lines(const read_mode *mode, size_t obj0, size_t nobj,
                                hlod_obj_range *keep[3], size_t keep_n[3])
{
    size_t block = mode->count;
    for (int k = 0; k < 3; k++)
        if (!(keep[k] = malloc((nobj ? nobj : 1) * sizeof *keep[k])))
            return HLOD_ERR_NOMEM;
    for (size_t g = obj0; g < obj0 + nobj; g++) {
        const struct obj_rec *o = &mode->objs[g];
        int want = 0;
        for (size_t b = 0; b < o->blocks; b++)
            want |= mode->keep[block + b];
        block += o->blocks;
        const hlod_obj_range *u[3] = {&o->info.v, &o->info.vt, &o->info.vn};
        for (int k = 0; k < 3 && want; k++)
            if (u[k]->lo < u[k]->hi)
                keep[k][keep_n[k]++] = *u[k];
    }
    for (int k = 0; k < 3; k++) {
        qsort(keep[k], keep_n[k], sizeof *keep[k], range_cmp);
        size_t w = 0;
        for (size_t i = 0; i < keep_n[k]; i++) {
            if (w && keep[k][i].lo <= keep[k][w - 1].hi) {
                if (keep[k][i].hi > keep[k][w - 1].hi)
                    keep[k][w - 1].hi = keep[k][i].hi;
            } else {
                keep[k][w++] = keep[k][i];
            }
        }
        keep_n[k] = w;
    }
    return HLOD_OK;
}

/* A shard's OBJ input file i, object by object: the first pass takes every
 * block's box from positions alone, the second the kept blocks, holding
 * only the lines their objects use.  The material table stays in *mesh
 * (blocks borrow its texture paths). */
static hlod_result stream_file(const char *path, size_t i, hlod_mesh *mesh, blocks *bs,
                               size_t *tris_in, read_mode *mode, const hlod_logger *lg)
{
    const char *base = strrchr(path, '/');
    size_t obj0 = 0;
    for (size_t f = 0; f < i; f++)
        obj0 += mode->file_objs[f];
    stream_ctx c = {path, base ? base + 1 : path, bs, mode, tris_in, obj0, lg};
    hlod_obj_stream_desc sd = {.logger = lg, .positions_only = mode->boxes_only,
                               .want = stream_want, .object = stream_object, .user = &c};
    hlod_obj_range *keep[3] = {NULL, NULL, NULL};
    size_t count0 = mode->count, tris0 = *tris_in;
    hlod_result r = HLOD_OK;
    if (!mode->boxes_only && (r = stream_lines(mode, obj0, mode->file_objs[i], keep, sd.keep_n)) == HLOD_OK)
        for (int k = 0; k < 3; k++)
            sd.keep[k] = keep[k];
    if (r == HLOD_OK)
        r = hlod_obj_stream(path, &sd, mesh);
    for (int k = 0; k < 3; k++)
        free(keep[k]);
    if (r != HLOD_OK)
        return r;
    if (mode->boxes_only) {
        mode->file_objs[i] = mode->nobj - obj0;
        if (*tris_in == tris0) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: all triangles are degenerate or duplicates", path);
            return HLOD_ERR_EMPTY;
        }
    } else if (mode->count - count0 != mode->file_blocks[i]) {
        return stream_changed(&c);
    }
    return HLOD_OK;
}

static hlod_result read_blocks(const hlod_build_desc *d, const char *const *inputs, size_t n,
                               hlod_mesh *meshes, blocks *bs, size_t *tris_in,
                               const char *scratch, read_mode *mode, const hlod_logger *lg)
{
    for (size_t i = 0; i < n; i++) {
        if (skip_file(mode, i, tris_in))
            continue;
        size_t tris_before = *tris_in, blocks_before = mode ? mode->count : 0;
        if (mode && d->grid <= 0 && hlod_mesh_is_obj(inputs[i])) {
            hlod_result r = stream_file(inputs[i], i, &meshes[i], bs, tris_in, mode, lg);
            if (r != HLOD_OK)
                return r;
            if (mode->boxes_only) {
                mode->file_blocks[i] = mode->count - blocks_before;
                mode->file_tris[i] = *tris_in - tris_before;
            }
            continue;
        }
        hlod_import_desc idesc = {lg, 0, scratch};
        hlod_result r = hlod_mesh_import(inputs[i], &idesc, &meshes[i], NULL);
        if (r != HLOD_OK) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read: %s", inputs[i], hlod_result_str(r));
            return r;
        }
        *tris_in += meshes[i].tri_count;
        if ((r = hlod_build_check_coords(&meshes[i], inputs[i], lg)) != HLOD_OK)
            return r;
        const char *base = strrchr(inputs[i], '/');
        size_t first = bs->n;
        r = make_blocks(&meshes[i], base ? base + 1 : inputs[i], d->grid, bs);
        if (r != HLOD_OK) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot split into blocks: %s", inputs[i],
                      hlod_result_str(r));
            return r;
        }
        if (mode && mode->keep && bs->n - first != mode->file_blocks[i]) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: changed while it was read (%zu blocks, then %zu)",
                      inputs[i], mode->file_blocks[i], bs->n - first);
            return HLOD_ERR_IO;
        }
        if ((r = filter_blocks(bs, first, mode)) != HLOD_OK)
            return r;
        if (mode && mode->boxes_only) {
            mode->file_blocks[i] = mode->count - blocks_before;
            mode->file_tris[i] = *tris_in - tris_before;
        }
        hlod_mesh *m = &meshes[i];
        free(m->positions);
        free(m->normals);
        free(m->uvs);
        free(m->indices);
        free(m->tri_material);
        m->positions = NULL;
        m->normals = NULL;
        m->uvs = NULL;
        m->indices = NULL;
        m->tri_material = NULL;
    }
    if (mode ? !mode->count : !bs->n) {
        hlod_logf(lg, HLOD_LOG_ERROR, "no triangles in the input");
        return HLOD_ERR_EMPTY;
    }
    return HLOD_OK;
}

static size_t build_threads(const hlod_build_desc *d)
{
    long cpus = sysconf(_SC_NPROCESSORS_ONLN);
    return d->threads ? d->threads : cpus > 0 ? (size_t)cpus : 1;
}

/* City levels are built over more than one block unless turned off. */
static int want_levels(const hlod_build_desc *d, size_t blocks)
{
    return d->city_levels && blocks >= 2 && d->method != HLOD_BUILD_SAMPLETREE &&
           d->method != HLOD_BUILD_CUBES;
}

/* Builds every block on the worker threads and streams their nodes into
 * w; the calling thread reports progress. */
static hlod_result build_blocks(const hlod_build_desc *d, blocks *bs, block_out *outs,
                                hlod_store_writer *w, int keep_top, const hlod_logger *lg,
                                hlod_build_report *rep)
{
    job J = {.desc = d, .bs = bs, .out = outs, .w = w, .lg = lg, .keep_top = keep_top};
    J.bp.desired_tris = d->desired_tris;
    J.bp.level_factor = d->level_factor;
    J.bp.voxel_tris = d->voxel_tris;
    J.bp.leaf_tris = d->leaf_tris;
    J.bp.node_tris = d->node_tris;
    J.bp.seed = d->seed;
    J.bp.cone_split = d->cone_split && d->method == HLOD_BUILD_CUTPLANE;
    J.slot = calloc(bs->n, sizeof *J.slot);
    J.ready = calloc(bs->n, 1);
    size_t threads = build_threads(d);
    size_t nth = threads < bs->n ? threads : bs->n;
    pthread_t *th = calloc(nth, sizeof *th);
    if (!J.slot || !J.ready || !th) {
        free(J.slot);
        free(J.ready);
        free(th);
        return HLOD_ERR_NOMEM;
    }
    pthread_mutex_init(&J.turn_mu, NULL);
    pthread_cond_init(&J.turn_cv, NULL);
    size_t started = 0;
    for (; started < nth; started++)
        if (pthread_create(&th[started], NULL, worker, &J) != 0)
            break;
    if (!started)
        hlod_logf(lg, HLOD_LOG_ERROR, "cannot start build threads");
    while (started && atomic_load(&J.done_blocks) < bs->n && !atomic_load(&J.failed)) {
        if (d->progress)
            d->progress(d->progress_user, atomic_load(&J.done_blocks), bs->n);
        nanosleep(&(struct timespec){0, 100000000}, NULL);
    }
    for (size_t i = 0; i < started; i++)
        pthread_join(th[i], NULL);
    free(th);
    rep->cpu_texture_read_s = atomic_load(&J.texture_read_ns) * 1e-9;
    rep->cpu_tree_s = atomic_load(&J.tree_ns) * 1e-9;
    rep->cpu_simplify_s = atomic_load(&J.timing.simplify_ns) * 1e-9;
    rep->cpu_error_s = atomic_load(&J.timing.error_ns) * 1e-9;
    rep->cpu_node_texture_s = atomic_load(&J.timing.node_texture_ns) * 1e-9;
    rep->cpu_store_s = atomic_load(&J.store_ns) * 1e-9;
    pthread_mutex_destroy(&J.turn_mu);
    pthread_cond_destroy(&J.turn_cv);
    for (size_t b = 0; b < bs->n; b++)
        hlod_btree_free(&J.slot[b]);
    free(J.slot);
    free(J.ready);
    return !started || atomic_load(&J.failed) ? HLOD_ERR_IO : HLOD_OK;
}

/* ---- city levels ------------------------------------------------------------ */

/* The group nodes as city_levels.c emits them; global indices: the blocks'
 * nodes in block order, then the groups in emission order. */
typedef struct top_levels {
    hlod_store_writer *w;
    hlod_store_node *nodes;     /* group nodes, filled by the writer */
    uint32_t *level, *index;    /* each group's place in the plan */
    size_t n, cap;
    size_t base;                /* global index of the first group */
    uint32_t *up;               /* per global index: parent, or NO_PARENT */
    size_t tris;
    uint32_t levels;
} top_levels;

/* called from the thread that runs hlod_city_levels */
static hlod_result emit_group(void *user, uint32_t level, uint32_t index, hlod_city_item *g,
                              const hlod_city_item *const *kids, size_t n)
{
    top_levels *T = user;
    if (T->n == T->cap)
        return HLOD_ERR_INVALID_ARG; /* more groups than the plan has: cannot be */
    hlod_result r = hlod_build_add_group(T->w, g, &T->nodes[T->n]);
    if (r != HLOD_OK)
        return r;
    T->level[T->n] = level;
    T->index[T->n] = index;
    g->node = (uint32_t)(T->base + T->n);
    for (size_t k = 0; k < n; k++)
        T->up[kids[k]->node] = g->node;
    T->tris += g->mesh.tri_count;
    T->n++;
    return HLOD_OK;
}

/* The group levels 1 .. to of plan p over the blocks' hlod_0 nodes
 * (outs[b].top, bs's blocks being the plan's blocks gid[b]); *tops: level
 * `to`'s items when to > 0 (see hlod_city_levels). */
static hlod_result build_levels(const hlod_build_desc *d, const hlod_city_plan *p, uint32_t to,
                                const blocks *bs, const uint32_t *gid, block_out *outs,
                                hlod_store_writer *w, top_levels *T, hlod_city_item **tops,
                                const hlod_logger *lg)
{
    size_t base = 0;
    for (size_t b = 0; b < bs->n; b++)
        base += outs[b].count;
    T->w = w;
    T->base = base;
    T->cap = 0;
    for (uint32_t l = 1; l <= to; l++)
        T->cap += p->count[l];
    T->nodes = calloc(T->cap + 1, sizeof *T->nodes);
    T->level = calloc(T->cap + 1, sizeof *T->level);
    T->index = calloc(T->cap + 1, sizeof *T->index);
    T->up = malloc((base + T->cap + 1) * sizeof *T->up);
    hlod_city_item **items = calloc(p->count[0], sizeof *items);
    if (!T->nodes || !T->level || !T->index || !T->up || !items) {
        free(items);
        return HLOD_ERR_NOMEM;
    }
    for (size_t i = 0; i < base + T->cap; i++)
        T->up[i] = HLOD_STORE_NO_PARENT;
    for (size_t b = 0, at = 0; b < bs->n; at += outs[b].count, b++) {
        outs[b].top.node = (uint32_t)at;
        items[gid ? gid[b] : b] = &outs[b].top;
    }
    hlod_city_levels_desc cd = {0};
    cd.target_tris = hlod_build_group_tris(d);
    cd.threads = build_threads(d);
    cd.logger = lg;
    cd.emit = emit_group;
    cd.user = T;
    hlod_result r = hlod_city_levels(p, 0, items, to, &cd, tops);
    free(items);
    T->levels = to;
    if (r != HLOD_OK)
        hlod_logf(lg, HLOD_LOG_ERROR, "city levels over %zu blocks: %s", bs->n, hlod_result_str(r));
    return r;
}

/* The global node list (blocks in order, then the groups, parents as
 * global indices) and the store's finish.  Consumes w. */
static hlod_result finish_store(hlod_store_writer *w, const blocks *bs, const block_out *outs,
                                const top_levels *T, const char *out_path,
                                hlod_build_report *rep, uint32_t **store_index,
                                const hlod_logger *lg)
{
    size_t total = 0;
    for (size_t b = 0; b < bs->n; b++) {
        total += outs[b].count;
        rep->tris_leaf += outs[b].tris_leaf;
        rep->tris_total += outs[b].tris_total;
        rep->levels = outs[b].depth > rep->levels ? outs[b].depth : rep->levels;
    }
    size_t blocks_nodes = total;
    total += T->n;
    rep->groups = T->n;
    rep->block_depth = T->levels;
    rep->levels += T->levels;
    rep->tris_total += T->tris;
    hlod_store_node *all = total < UINT32_MAX ? calloc(total, sizeof *all) : NULL;
    if (!all) {
        hlod_store_writer_abort(w);
        return total < UINT32_MAX ? HLOD_ERR_NOMEM : HLOD_ERR_INVALID_ARG;
    }
    size_t base = 0;
    for (size_t b = 0; b < bs->n; b++) {
        for (size_t k = 0; k < outs[b].count; k++) {
            hlod_store_node *n = &all[base + k];
            *n = outs[b].nodes[k];
            if (outs[b].parent[k] != HLOD_BNODE_NONE)
                n->parent = (uint32_t)(base + outs[b].parent[k]);
            else
                n->parent = T->up ? T->up[base + k] : HLOD_STORE_NO_PARENT;
            n->block = (uint32_t)b;
        }
        base += outs[b].count;
    }
    for (size_t g = 0; g < T->n; g++) {
        all[blocks_nodes + g] = T->nodes[g];
        all[blocks_nodes + g].parent = T->up[blocks_nodes + g];
    }
    hlod_build_contain(all, total);
    uint32_t *index = store_index ? malloc((total + 1) * sizeof *index) : NULL;
    if (store_index && !index) {
        free(all);
        hlod_store_writer_abort(w);
        return HLOD_ERR_NOMEM;
    }
    hlod_store_texture_stats ts;
    hlod_store_writer_texture_stats(w, &ts);
    rep->textures_bc = ts.bc;
    rep->textures_jpeg = ts.jpeg;
    rep->textures_raw = ts.raw;
    rep->texture_db_min = ts.db_min;
    hlod_result r = hlod_store_writer_finish(w, all, (uint32_t)total, index);
    free(all);
    if (store_index && r == HLOD_OK)
        *store_index = index;
    else
        free(index);
    if (r != HLOD_OK)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot finish the store: %s", out_path,
                  hlod_result_str(r));
    rep->nodes = total;
    return r;
}

/* Each block's box (of its input vertices). */
static hlod_result block_boxes(const blocks *bs, double (**lo)[3], double (**hi)[3])
{
    *lo = malloc(bs->n * sizeof **lo);
    *hi = malloc(bs->n * sizeof **hi);
    if (!*lo || !*hi)
        return HLOD_ERR_NOMEM;
    for (size_t b = 0; b < bs->n; b++)
        if (!hlod_mesh_bounds(&bs->b[b].mesh, (*lo)[b], (*hi)[b]))
            for (int k = 0; k < 3; k++)
                (*lo)[b][k] = (*hi)[b][k] = 0;
    return HLOD_OK;
}

/* Cut-level nodes per shard at least: shards then differ by at most about
 * a quarter of their nodes (with m = N + 1, one would build twice another's
 * share), and the merge builds only the few levels above. */
#define CUT_NODES_PER_SHARD 4

/* The shard's blocks: the cut level is the plan's highest with at least
 * CUT_NODES_PER_SHARD x N nodes (else the blocks), shard I owns its nodes
 * [(I-1) m / N, I m / N) and their subtrees (part.h).  Sets h's shard fields and keep[b] for each block b of the
 * whole input the shard owns. */
static hlod_result shard_keep(const hlod_build_desc *d, const hlod_city_plan *p,
                              hlod_part_header *h, uint8_t **keep_out, const hlod_logger *lg)
{
    uint32_t N = d->shard_count, I = d->shard_index;
    size_t nb = p->count[0];
    if (nb < N) {
        hlod_logf(lg, HLOD_LOG_ERROR, "shard %u/%u: the input has %zu blocks, fewer than %u shards",
                  I, N, nb, N);
        return HLOD_ERR_INVALID_ARG;
    }
    uint32_t L = 0;
    for (uint32_t l = 1; l <= p->levels; l++)
        if (p->count[l] >= (uint64_t)CUT_NODES_PER_SHARD * N)
            L = l;
    uint64_t m = p->count[L];
    h->shard_index = I;
    h->shard_count = N;
    h->cut_level = L;
    h->levels = p->levels;
    h->cut_first = (I - 1) * m / N;
    h->cut_end = I * m / N;
    /* each block's node at the cut level */
    uint32_t *anc = malloc(nb * sizeof *anc), *up = malloc((nb + 1) * sizeof *up);
    uint8_t *keep = malloc(nb);
    if (!anc || !up || !keep) {
        free(anc);
        free(up);
        free(keep);
        return HLOD_ERR_NOMEM;
    }
    for (size_t b = 0; b < nb; b++)
        anc[b] = (uint32_t)b;
    for (uint32_t l = 1; l <= L; l++) {
        for (size_t g = 0; g < p->count[l]; g++)
            for (size_t k = p->first[l][g]; k < p->first[l][g + 1]; k++)
                up[p->kids[l][k]] = (uint32_t)g;
        for (size_t b = 0; b < nb; b++)
            anc[b] = up[anc[b]];
    }
    for (size_t b = 0; b < nb; b++)
        keep[b] = anc[b] >= h->cut_first && anc[b] < h->cut_end;
    free(anc);
    free(up);
    *keep_out = keep;
    return HLOD_OK;
}

/* The plan over nb blocks with boxes lo, hi: the city levels' tree, or
 * none (one level of blocks) without levels. */
static hlod_result make_plan(const hlod_build_desc *d, int levels, const double (*lo)[3],
                             const double (*hi)[3], size_t nb, hlod_city_plan *plan)
{
    if (levels)
        return hlod_city_plan_make(lo, hi, nb, hlod_build_group_size(d), plan);
    plan->count = calloc(1, sizeof *plan->count);
    if (!plan->count)
        return HLOD_ERR_NOMEM;
    plan->count[0] = nb;
    return HLOD_OK;
}

/* What a build knows of its input before building: the blocks it builds
 * (bs; a shard's only), every block's box (lo, hi; nb of them) and the
 * plan.  A shard reads the input twice: first every block's box, file by
 * file, dropping the geometry, then only the files with its blocks,
 * keeping those (gid: their indices in the whole input). */
typedef struct input {
    blocks bs;
    double (*lo)[3], (*hi)[3];
    size_t nb;
    int levels;
    hlod_city_plan plan;
    uint32_t *gid;
} input;

static hlod_result read_input(const hlod_build_desc *d, const char *const *inputs, size_t n,
                              hlod_mesh *meshes, const char *scratch, input *in,
                              hlod_part_header *ph, size_t *tris_in, const hlod_logger *lg)
{
    hlod_result r;
    if (!d->shard_count) {
        r = read_blocks(d, inputs, n, meshes, &in->bs, tris_in, scratch, NULL, lg);
        if (r == HLOD_OK)
            r = block_boxes(&in->bs, &in->lo, &in->hi);
        in->nb = in->bs.n;
        in->levels = want_levels(d, in->nb);
        return r == HLOD_OK ? make_plan(d, in->levels, (const double (*)[3])in->lo,
                                        (const double (*)[3])in->hi, in->nb, &in->plan) : r;
    }
    size_t *file_blocks = calloc(n, sizeof *file_blocks), *file_tris = calloc(n, sizeof *file_tris);
    size_t *file_objs = calloc(n, sizeof *file_objs);
    read_mode boxes = {.boxes_only = 1, .file_blocks = file_blocks, .file_tris = file_tris,
                       .file_objs = file_objs};
    r = file_blocks && file_tris && file_objs ? read_blocks(d, inputs, n, meshes, &in->bs, tris_in,
                                                            scratch, &boxes, lg) : HLOD_ERR_NOMEM;
    in->lo = boxes.lo;
    in->hi = boxes.hi;
    in->nb = boxes.count;
    for (size_t i = 0; i < n; i++)
        hlod_mesh_free(&meshes[i]);
    in->levels = want_levels(d, in->nb);
    if (r == HLOD_OK)
        r = make_plan(d, in->levels, (const double (*)[3])in->lo, (const double (*)[3])in->hi, in->nb,
                  &in->plan);
    uint8_t *keep = NULL;
    if (r == HLOD_OK)
        r = shard_keep(d, &in->plan, ph, &keep, lg);
    if (r == HLOD_OK && !(in->gid = malloc((in->nb + 1) * sizeof *in->gid)))
        r = HLOD_ERR_NOMEM;
    if (r == HLOD_OK) {
        read_mode mine = {.keep = keep, .gid = in->gid, .file_blocks = file_blocks,
                          .file_tris = file_tris, .file_objs = file_objs, .objs = boxes.objs,
                          .nobj = boxes.nobj};
        size_t again = 0;
        r = read_blocks(d, inputs, n, meshes, &in->bs, &again, scratch, &mine, lg);
        if (r == HLOD_OK && (again != *tris_in || mine.count != in->nb)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "the input changed while it was read (%zu triangles, "
                      "then %zu)", *tris_in, again);
            r = HLOD_ERR_IO;
        }
    }
    free(keep);
    free(file_blocks);
    free(file_tris);
    free(file_objs);
    free(boxes.objs);
    return r;
}

/* The part's keys, in the order of the shard's node list (blocks' nodes,
 * then groups), each with its store index. */
static hlod_part_key *part_keys(const blocks *bs, const uint32_t *gid, const block_out *outs,
                                const top_levels *T, const uint32_t *store_index, size_t *count)
{
    size_t total = T->n;
    for (size_t b = 0; b < bs->n; b++)
        total += outs[b].count;
    hlod_part_key *keys = malloc((total + 1) * sizeof *keys);
    if (!keys)
        return NULL;
    size_t j = 0;
    for (size_t b = 0; b < bs->n; b++)
        for (size_t k = 0; k < outs[b].count; k++, j++)
            keys[j] = (hlod_part_key){store_index[j], 0, gid[b], (uint32_t)k, outs[b].nodes[k].error};
    for (size_t g = 0; g < T->n; g++, j++)
        keys[j] = (hlod_part_key){store_index[j], T->level[g], T->index[g], 0, T->nodes[g].error};
    *count = total;
    return keys;
}

/* The store writer's descriptor: the build's parameters and, packed, the
 * position grid of every block (a shard's too: it has all of them here). */
static void writer_desc(const hlod_build_desc *d, const input *in, const hlod_logger *lg,
                        hlod_store_writer_desc *wd)
{
    int metis = d->method == HLOD_BUILD_METIS;
    wd->build.method = metis ? HLOD_STORE_METHOD_METIS : HLOD_STORE_METHOD_CUTPLANE;
    wd->build.desired_tris = metis ? 0 : d->desired_tris;
    wd->build.level_factor = metis ? 0 : d->level_factor;
    wd->build.voxel_tris = metis ? d->voxel_tris : 0;
    wd->build.leaf_tris = metis ? d->leaf_tris : 0;
    wd->build.node_tris = metis ? d->node_tris : 0;
    wd->build.c_tex = d->c_tex;
    wd->build.flags = d->cone_split && d->method == HLOD_BUILD_CUTPLANE ? HLOD_BUILD_CONE_SPLIT : 0;
    wd->cubes = d->far_cubes && d->method != HLOD_BUILD_SAMPLETREE && d->method != HLOD_BUILD_CUBES;
    if (d->method == HLOD_BUILD_SAMPLETREE || d->method == HLOD_BUILD_CUBES) {
        int cubes = d->method == HLOD_BUILD_CUBES;
        memset(&wd->build, 0, sizeof wd->build);
        wd->build.method = cubes ? HLOD_STORE_METHOD_CUBES : HLOD_STORE_METHOD_SAMPLETREE;
        wd->build.level_factor = cubes ? 0 : d->sample_c;
        wd->build.leaf_tris = d->leaf_tris;
        wd->build.c_tex = d->c_tex;
    }
    wd->logger = lg;
    if (d->compress) {
        position_grid((const double (*)[3])in->lo, (const double (*)[3])in->hi, in->nb,
                      d->quant_bits, wd);
        wd->jpeg_quality = d->jpeg_quality;
        wd->texture_blocks = d->texture_blocks != 0;
        wd->texture_min_db = d->texture_min_db;
        wd->payload_align = HLOD_STORE_MIN_ALIGN;    /* packed payloads are small */
    }
}

/* A shard's start: the part header's build fields and the file beside
 * the part its store is written to (store_path; "" when none was made). */
static hlod_result start_shard(const hlod_build_desc *d, const input *in, const char *out_path,
                               hlod_part_header *ph, char *store_path, size_t store_cap,
                               const hlod_logger *lg)
{
    ph->params_hash = hlod_part_params_hash(d, (size_t)ph->tris_in, in->nb,
                                            (const double (*)[3])in->lo,
                                            (const double (*)[3])in->hi);
    ph->plan_hash = hlod_city_plan_hash(&in->plan);
    ph->group_tris = hlod_build_group_tris(d);
    ph->group_size = hlod_build_group_size(d);
    ph->block_count = in->nb;
    snprintf(store_path, store_cap, "%.4096s.store-XXXXXX", out_path);
    int fd = mkstemp(store_path);
    if (fd < 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create a file beside it: %s", out_path,
                  strerror(errno));
        store_path[0] = 0;
        return HLOD_ERR_IO;
    }
    close(fd);
    return HLOD_OK;
}

/* The part file: the shard's store, its keys and its cut-level items
 * (the blocks' hlod_0 nodes at cut level 0, else tops). */
static hlod_result write_part(const hlod_city_plan *plan, const blocks *bs, const uint32_t *gid,
                              block_out *outs, const top_levels *T, const uint32_t *store_index,
                              hlod_city_item *tops, int levels, const double (*lo)[3],
                              const double (*hi)[3], const char *out_path, const char *store_path,
                              hlod_part_header *ph, const hlod_logger *lg)
{
    size_t nkeys = 0;
    hlod_part_key *keys = part_keys(bs, gid, outs, T, store_index, &nkeys);
    hlod_city_item **cut = calloc(plan->count[ph->cut_level] + 1, sizeof *cut);
    hlod_result r = keys && cut ? HLOD_OK : HLOD_ERR_NOMEM;
    if (r == HLOD_OK) {
        for (size_t b = 0; b < bs->n && ph->cut_level == 0; b++)
            cut[gid[b]] = &outs[b].top;
        for (size_t i = 0; tops && i < plan->count[ph->cut_level]; i++)
            cut[i] = &tops[i];
        ph->key_count = (uint32_t)nkeys;
        r = hlod_part_write(out_path, store_path, ph, lo, hi, keys, levels ? cut : NULL, lg);
    }
    free(keys);
    free(cut);
    return r;
}

/* The sample tree (sampletree.c), out of core: a first pass for the box
 * and the counts, the writer over that box, then the build, with a spill
 * file beside the output when the buckets outgrow memory_mb. */
static hlod_result sampletree_store(const hlod_build_desc *d, const char *const *inputs,
                                    size_t n, const char *scratch, const char *out_path,
                                    const hlod_logger *lg, hlod_build_report *rep)
{
    hlod_st_scan *scan = NULL;
    double t0 = hlod_now_s();
    hlod_result r = hlod_st_scan_inputs(inputs, n, scratch, lg, &scan);
    if (r != HLOD_OK)
        return r;
    rep->stage_read_s = hlod_now_s() - t0;
    t0 = hlod_now_s();
    double lo[1][3], hi[1][3];
    hlod_st_scan_box(scan, lo[0], hi[0]);
    input in = {0};
    in.lo = lo;
    in.hi = hi;
    in.nb = 1;
    hlod_store_writer_desc wd = {0};
    writer_desc(d, &in, lg, &wd);
    hlod_store_writer *w = NULL;
    r = hlod_store_writer_open(out_path, &wd, &w);
    if (r != HLOD_OK) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create: %s", out_path, hlod_result_str(r));
        hlod_st_scan_free(scan);
        return r;
    }
    char spill[4096 + 32];
    snprintf(spill, sizeof spill, "%.4096s.spill-%d", out_path, (int)getpid());
    hlod_st_params p = {d->sample_c, d->leaf_tris, d->seed, d->memory_mb << 20, lg,
                        d->method == HLOD_BUILD_CUBES};
    hlod_st_report sr;
    r = hlod_build_sampletree_inputs(scan, inputs, n, scratch, spill, &p, w, &sr);
    rep->tris_in = hlod_st_scan_tris(scan);
    hlod_st_scan_free(scan);
    if (r != HLOD_OK) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %s: %s", out_path,
                  p.cubes ? "colour cubes" : "sample tree", hlod_result_str(r));
        return r;
    }
    rep->stage_blocks_s = hlod_now_s() - t0;
    rep->blocks = 1;
    rep->nodes = sr.nodes;
    rep->levels = sr.levels;
    rep->tris_leaf = sr.tris_leaf;
    rep->tris_total = sr.tris;
    rep->buckets = sr.buckets;
    rep->spill_bytes = sr.spill_bytes;
    rep->textures_bc = sr.tex.bc;
    rep->textures_jpeg = sr.tex.jpeg;
    rep->textures_raw = sr.tex.raw;
    rep->texture_db_min = sr.tex.db_min;
    return HLOD_OK;
}

hlod_result hlod_build_store(const hlod_build_desc *d, const char *const *inputs, size_t n,
                             const char *out_path, const hlod_logger *lg,
                             hlod_build_report *report)
{
    hlod_build_report rep = {0};
    if (report)
        *report = rep;
    if (!d || !inputs || !n || !out_path)
        return HLOD_ERR_INVALID_ARG;
    hlod_result r = check_desc(d, lg);
    if (r == HLOD_OK)
        r = check_out_dir(out_path, lg);
    if (r != HLOD_OK)
        return r;
    hlod_mesh *meshes = calloc(n, sizeof *meshes);
    input in = {0};
    hlod_store_writer *w = NULL;
    block_out *outs = NULL;
    hlod_part_header ph = {0};
    int sharded = d->shard_count > 0;
    char store_path[4096 + 32];
    store_path[0] = 0;
    /* images embedded in a 3D Tiles input's glb files are read from files
     * beside the output while the build runs */
    char scratch[4096 + 32];
    scratch[0] = 0;
    for (size_t i = 0; i < n && r == HLOD_OK && !scratch[0]; i++) {
        const char *dot = strrchr(inputs[i], '.');
        if (dot && !strcmp(dot, ".json")) {
            snprintf(scratch, sizeof scratch, "%.4096s.images-XXXXXX", out_path);
            if (!mkdtemp(scratch)) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create a folder beside it for the "
                          "input's images: %s", out_path, strerror(errno));
                scratch[0] = 0;
                r = HLOD_ERR_IO;
            }
        }
    }
    if (r == HLOD_OK && (d->method == HLOD_BUILD_SAMPLETREE || d->method == HLOD_BUILD_CUBES)) {
        r = sampletree_store(d, inputs, n, scratch[0] ? scratch : NULL, out_path, lg, &rep);
        free(meshes);
        if (scratch[0])
            hlod_rm_tree(scratch);
        if (report && r == HLOD_OK)
            *report = rep;
        return r;
    }
    /* the blocks and the group tree, from the blocks' boxes before any is built */
    double t_stage = hlod_now_s();
    if (r == HLOD_OK)
        r = meshes ? read_input(d, inputs, n, meshes, scratch[0] ? scratch : NULL, &in, &ph,
                                &rep.tris_in, lg) : HLOD_ERR_NOMEM;
    hlod_store_writer_desc wd = {0};
    if (r == HLOD_OK)
        writer_desc(d, &in, lg, &wd);
    if (r == HLOD_OK && sharded) {
        ph.tris_in = rep.tris_in;
        ph.jpeg_quality = wd.jpeg_quality;
        ph.texture_blocks = wd.texture_blocks;
        ph.far_cubes = wd.cubes;
        ph.texture_min_db = wd.texture_min_db;
        r = start_shard(d, &in, out_path, &ph, store_path, sizeof store_path, lg);
    }
    blocks *bs = &in.bs;
    if (r == HLOD_OK) {
        const char *path = sharded ? store_path : out_path;
        r = hlod_store_writer_open(path, &wd, &w);
        if (r != HLOD_OK)
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create: %s", path, hlod_result_str(r));
    }
    rep.blocks = bs->n;
    top_levels T = {0};
    hlod_city_item *tops = NULL;
    uint32_t to = sharded ? ph.cut_level : in.plan.levels;
    uint32_t *store_index = NULL;
    {
        if (r == HLOD_OK && !(outs = calloc(bs->n ? bs->n : 1, sizeof *outs)))
            r = HLOD_ERR_NOMEM;
        rep.stage_read_s = hlod_now_s() - t_stage;
        t_stage = hlod_now_s();
        if (r == HLOD_OK)
            r = build_blocks(d, bs, outs, w, in.levels, lg, &rep);
        rep.stage_blocks_s = hlod_now_s() - t_stage;
        t_stage = hlod_now_s();
        if (r == HLOD_OK && in.levels)
            r = build_levels(d, &in.plan, to, bs, in.gid, outs, w, &T, &tops, lg);
        rep.stage_levels_s = hlod_now_s() - t_stage;
        t_stage = hlod_now_s();
        if (r == HLOD_OK) {
            r = finish_store(w, bs, outs, &T, sharded ? store_path : out_path, &rep,
                             sharded ? &store_index : NULL, lg);
            w = NULL;
        }
        if (r == HLOD_OK && sharded) {
            r = write_part(&in.plan, bs, in.gid, outs, &T, store_index, in.levels ? tops : NULL,
                           in.levels, (const double (*)[3])in.lo, (const double (*)[3])in.hi,
                           out_path, store_path, &ph, lg);
            if (r == HLOD_OK)
                store_path[0] = 0;
        }
        rep.stage_finish_s = hlod_now_s() - t_stage;
    }
    free(store_index);
    if (tops)
        for (size_t i = 0; i < in.plan.count[to]; i++)
            hlod_city_item_free(&tops[i]);
    free(tops);
    free(T.nodes);
    free(T.level);
    free(T.index);
    free(T.up);
    if (w)
        hlod_store_writer_abort(w);
    if (store_path[0])
        unlink(store_path);
    if (outs)
        for (size_t b = 0; b < bs->n; b++) {
            free(outs[b].nodes);
            free(outs[b].parent);
            hlod_city_item_free(&outs[b].top);
        }
    free(outs);
    for (size_t b = 0; b < bs->n; b++)
        hlod_mesh_free(&bs->b[b].mesh);
    free(bs->b);
    if (meshes)
        for (size_t i = 0; i < n; i++)
            hlod_mesh_free(&meshes[i]);
    free(meshes);
    free(in.lo);
    free(in.hi);
    free(in.gid);
    hlod_city_plan_free(&in.plan);
    if (scratch[0])
        hlod_rm_tree(scratch);
    if (report && r == HLOD_OK)
        *report = rep;
    return r;
}
