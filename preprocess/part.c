/*
 * part.c - part files of a sharded build and their merge (part.h,
 * hlod/build_store.h; docs/sharded-builds.md).
 *
 * The merge (hlod_merge_store) checks that the parts belong together (one
 * build's parameters and plan, every shard once), then writes the single
 * build's store in the single build's order: each block's nodes and the
 * groups up to the cut level copied from the part that holds them, payload
 * bytes as they are, then the groups above the cut level built from the
 * parts' cut-level items, as the single build builds them.
 */
#include "part.h"

#include "build_node.h"

#include "atomic_file.h"

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* ---- a byte buffer ---------------------------------------------------------- */

typedef struct buf {
    uint8_t *p;
    size_t n, cap;
    int failed;
} buf;

static void put(buf *b, const void *src, size_t n)
{
    if (b->failed || !n)
        return;
    if (b->n + n > b->cap) {
        size_t cap = b->cap ? b->cap : 4096;
        while (cap < b->n + n)
            cap *= 2;
        uint8_t *np = realloc(b->p, cap);
        if (!np) {
            b->failed = 1;
            return;
        }
        b->p = np;
        b->cap = cap;
    }
    memcpy(b->p + b->n, src, n);
    b->n += n;
}

static void put_u64(buf *b, uint64_t v) { put(b, &v, sizeof v); }

/* a reader over a section: every take checks the bounds */
typedef struct cursor {
    const uint8_t *p;
    size_t n, at;
    int bad;
} cursor;

static const void *take(cursor *c, size_t n)
{
    if (c->bad || n > c->n - c->at) {
        c->bad = 1;
        return NULL;
    }
    const void *r = c->p + c->at;
    c->at += n;
    return r;
}

static int take_into(cursor *c, void *dst, size_t n)
{
    const void *s = take(c, n);
    if (s && n)
        memcpy(dst, s, n);
    return s != NULL;
}

static uint64_t take_u64(cursor *c)
{
    uint64_t v = 0;
    take_into(c, &v, sizeof v);
    return v;
}

/* ---- items ------------------------------------------------------------------ */

#define ITEM_NORMALS 1u
#define ITEM_UVS 2u
#define ITEM_COLORS 4u

/* What city_levels.c reads of a child: geometry, texture, colours, error,
 * source triangles and solidity. */
static void put_item(buf *b, const hlod_city_item *it)
{
    const hlod_mesh *m = &it->mesh;
    uint32_t flags = (m->normals ? ITEM_NORMALS : 0) | (m->uvs ? ITEM_UVS : 0) |
                     (it->colors ? ITEM_COLORS : 0);
    put_u64(b, m->vertex_count);
    put_u64(b, m->tri_count);
    put_u64(b, it->tex_tris);
    put_u64(b, it->source_tris);
    uint32_t w[6] = {flags, (uint32_t)it->solid, (uint32_t)it->tex.width, (uint32_t)it->tex.height,
                     (uint32_t)it->tex.channels, 0};
    put(b, w, sizeof w);
    put(b, it->color, 4);
    put(b, &it->error, sizeof it->error);
    put(b, m->positions, 3 * m->vertex_count * sizeof *m->positions);
    if (m->normals)
        put(b, m->normals, 3 * m->vertex_count * sizeof *m->normals);
    if (m->uvs)
        put(b, m->uvs, 2 * m->vertex_count * sizeof *m->uvs);
    put(b, m->indices, 3 * m->tri_count * sizeof *m->indices);
    if (it->colors)
        put(b, it->colors, 4 * m->vertex_count);
    if (it->tex.width)
        put(b, it->tex.pixels, (size_t)it->tex.width * it->tex.height * it->tex.channels);
}

static hlod_result take_item(cursor *c, hlod_city_item *it)
{
    memset(it, 0, sizeof *it);
    uint64_t nv = take_u64(c), nt = take_u64(c), tex_tris = take_u64(c), src = take_u64(c);
    uint32_t w[6] = {0};
    take_into(c, w, sizeof w);
    take_into(c, it->color, 4);
    take_into(c, &it->error, sizeof it->error);
    /* every array must fit in what is left */
    size_t left = c->n - c->at;
    if (c->bad || nv == 0 || nt == 0 || nv > left / 24 || nt > left / 12 || tex_tris > nt ||
        w[2] > 65536 || w[3] > 65536 || w[4] > 4 || !w[2] != !w[3] || !w[2] != !w[4] ||
        (uint64_t)w[2] * w[3] * w[4] > left || !isfinite(it->error) || it->error < 0)
        return HLOD_ERR_FORMAT;
    unsigned mf = (w[0] & ITEM_NORMALS ? HLOD_MESH_NORMALS : 0) | (w[0] & ITEM_UVS ? HLOD_MESH_UVS : 0);
    if (hlod_mesh_alloc(&it->mesh, nv, nt, mf) != HLOD_OK)
        return HLOD_ERR_NOMEM;
    hlod_mesh *m = &it->mesh;
    m->vertex_count = nv;
    m->tri_count = nt;
    it->tex_tris = tex_tris;
    it->source_tris = src;
    it->solid = (int)w[1];
    take_into(c, m->positions, 3 * nv * sizeof *m->positions);
    if (m->normals)
        take_into(c, m->normals, 3 * nv * sizeof *m->normals);
    if (m->uvs)
        take_into(c, m->uvs, 2 * nv * sizeof *m->uvs);
    take_into(c, m->indices, 3 * nt * sizeof *m->indices);
    if (w[0] & ITEM_COLORS) {
        it->colors = malloc(4 * nv);
        if (!it->colors || !take_into(c, it->colors, 4 * nv))
            c->bad = 1;
    }
    if (w[2] && !c->bad) {
        size_t px = (size_t)w[2] * w[3] * w[4];
        it->tex.width = (int)w[2];
        it->tex.height = (int)w[3];
        it->tex.channels = (int)w[4];
        it->tex.pixels = malloc(px ? px : 1);
        if (!it->tex.pixels || !take_into(c, it->tex.pixels, px))
            c->bad = 1;
    }
    for (size_t i = 0; !c->bad && i < 3 * nt; i++)
        c->bad = m->indices[i] >= nv;
    for (size_t i = 0; !c->bad && i < 3 * nv; i++)
        c->bad = !isfinite(m->positions[i]) || (m->normals && !isfinite(m->normals[i]));
    for (size_t i = 0; !c->bad && m->uvs && i < 2 * nv; i++)
        c->bad = !isfinite(m->uvs[i]);
    if (c->bad) {
        hlod_city_item_free(it);
        return HLOD_ERR_FORMAT;
    }
    return HLOD_OK;
}

/* ---- parameters ------------------------------------------------------------- */

uint64_t hlod_part_params_hash(const hlod_build_desc *d, size_t tris_in, size_t blocks,
                               const double (*lo)[3], const double (*hi)[3])
{
    buf b = {0};
    uint64_t u[] = {(uint64_t)d->method, d->desired_tris, d->voxel_tris, d->leaf_tris, d->node_tris,
                    d->seed, (uint64_t)!!d->city_levels, (uint64_t)!!d->compress, d->quant_bits,
                    d->jpeg_quality, tris_in, blocks, (uint64_t)!!d->texture_blocks,
                    (uint64_t)!!d->far_cubes};
    double f[] = {d->grid, d->level_factor, d->c_tex, d->texture_min_db};
    put(&b, u, sizeof u);
    put(&b, f, sizeof f);
    put(&b, lo, blocks * sizeof *lo);
    put(&b, hi, blocks * sizeof *hi);
    uint64_t h = b.failed ? 0 : hlod_store_hash(b.p, b.n);
    free(b.p);
    return h;
}

/* ---- writing ---------------------------------------------------------------- */

static int read_all(int fd, void *p, size_t n, uint64_t off)
{
    uint8_t *d = p;
    while (n) {
        ssize_t k = pread(fd, d, n, (off_t)off);
        if (k < 0 && errno == EINTR)
            continue;
        if (k <= 0)
            return k < 0 ? errno : EIO;
        d += k;
        n -= (size_t)k;
        off += (uint64_t)k;
    }
    return 0;
}

hlod_result hlod_part_write(const char *path, const char *store_path, hlod_part_header *h,
                            const double (*lo)[3], const double (*hi)[3],
                            const hlod_part_key *keys, hlod_city_item *const *tops,
                            const hlod_logger *lg)
{
    buf sec = {0};
    put(&sec, lo, h->block_count * sizeof *lo);
    put(&sec, hi, h->block_count * sizeof *hi);
    put(&sec, keys, (size_t)h->key_count * sizeof *keys);
    for (uint64_t i = h->cut_first; tops && i < h->cut_end; i++)
        put_item(&sec, tops[i]);
    if (sec.failed) {
        free(sec.p);
        return HLOD_ERR_NOMEM;
    }
    int in = open(store_path, O_RDONLY | O_CLOEXEC);
    struct stat st;
    if (in < 0 || fstat(in, &st) != 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read the shard's store %s: %s", path, store_path,
                  strerror(errno));
        if (in >= 0)
            close(in);
        free(sec.p);
        return HLOD_ERR_IO;
    }
    memcpy(h->magic, HLOD_PART_MAGIC, 8);
    h->version = HLOD_PART_VERSION;
    h->header_size = sizeof *h;
    h->store_offset = HLOD_PART_STORE_OFFSET;
    h->store_size = (uint64_t)st.st_size;
    h->section_offset = h->store_offset + h->store_size;
    h->section_size = sec.n;
    h->section_hash = hlod_store_hash(sec.p, sec.n);
    h->file_size = h->section_offset + h->section_size;
    h->header_hash = hlod_store_hash(h, offsetof(hlod_part_header, header_hash));

    hlod_atomic_file f;
    hlod_result r = hlod_atomic_open(&f, path, lg);
    if (r == HLOD_OK) {
        uint8_t head[HLOD_PART_STORE_OFFSET] = {0};
        memcpy(head, h, sizeof *h);
        int e = fwrite(head, 1, sizeof head, f.fp) != sizeof head;
        uint8_t *chunk = malloc(1u << 20);
        for (uint64_t at = 0; !e && at < h->store_size;) {
            size_t n = h->store_size - at < (1u << 20) ? (size_t)(h->store_size - at) : (1u << 20);
            e = !chunk || read_all(in, chunk, n, at) || fwrite(chunk, 1, n, f.fp) != n;
            at += n;
        }
        free(chunk);
        if (!e)
            e = fwrite(sec.p, 1, sec.n, f.fp) != sec.n;
        if (e) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write: %s", path, strerror(errno));
            hlod_atomic_abort(&f);
            r = HLOD_ERR_IO;
        } else {
            r = hlod_atomic_commit(&f, lg);
        }
    }
    close(in);
    free(sec.p);
    if (r == HLOD_OK)
        unlink(store_path);
    return r;
}

/* ---- reading ---------------------------------------------------------------- */

typedef struct part {
    const char *path;
    int fd;
    hlod_part_header h;
    hlod_store_header sh;
    hlod_store_node *nodes;     /* the part store's table */
    hlod_store_extra *extras;   /* its extras, or NULL */
    uint8_t *sec;
    double (*lo)[3], (*hi)[3];
    hlod_part_key *keys;
    hlod_city_item *tops;       /* ntops: cut_end - cut_first, or 0 without levels */
    size_t ntops;
    uint32_t *global;           /* per store node: its index in the merged store */
} part;

static void part_close(part *p)
{
    if (p->fd >= 0)
        close(p->fd);
    free(p->nodes);
    free(p->extras);
    free(p->sec);
    for (size_t i = 0; p->tops && i < p->ntops; i++)
        hlod_city_item_free(&p->tops[i]);
    free(p->tops);
    free(p->global);
    p->fd = -1;
}

/* Opens a part: its header, the store inside it (header, table, the rules
 * of hlod_store_validate) and its section, every checksum checked. */
static hlod_result part_open(part *p, const char *path, const hlod_logger *lg)
{
    memset(p, 0, sizeof *p);
    p->path = path;
    p->fd = open(path, O_RDONLY | O_CLOEXEC);
    struct stat st;
    if (p->fd < 0 || fstat(p->fd, &st) != 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot open: %s", path, strerror(errno));
        return HLOD_ERR_IO;
    }
    hlod_part_header *h = &p->h;
    if (read_all(p->fd, h, sizeof *h, 0) || memcmp(h->magic, HLOD_PART_MAGIC, 8)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: not a part file of a sharded build (hlod-build --shard)",
                  path);
        return HLOD_ERR_FORMAT;
    }
    if (h->version != HLOD_PART_VERSION || h->header_size != sizeof *h) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: part version %u, this hlod-merge reads %u", path,
                  h->version, HLOD_PART_VERSION);
        return HLOD_ERR_VERSION;
    }
    if (hlod_store_hash(h, offsetof(hlod_part_header, header_hash)) != h->header_hash) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: part header checksum mismatch (damaged)", path);
        return HLOD_ERR_CHECKSUM;
    }
    if (h->file_size != (uint64_t)st.st_size) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %llu bytes, its header says %llu (truncated or grown)",
                  path, (unsigned long long)st.st_size, (unsigned long long)h->file_size);
        return HLOD_ERR_FORMAT;
    }
    uint8_t pad[HLOD_PART_STORE_OFFSET - sizeof *h];
    int nonzero = read_all(p->fd, pad, sizeof pad, sizeof *h) != 0;
    for (size_t i = 0; i < sizeof pad && !nonzero; i++)
        nonzero = pad[i] != 0;
    if (nonzero) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: part header padding is not zero (damaged)", path);
        return HLOD_ERR_FORMAT;
    }
    if (!h->shard_count || h->shard_count > 65536 || !h->shard_index ||
        h->shard_index > h->shard_count || h->file_size < HLOD_PART_STORE_OFFSET ||
        h->store_offset != HLOD_PART_STORE_OFFSET || h->store_size < sizeof p->sh ||
        h->store_size > h->file_size - HLOD_PART_STORE_OFFSET ||
        h->section_size > h->file_size || h->levels > 64 ||
        h->section_offset != h->store_offset + h->store_size ||
        h->section_offset + h->section_size != h->file_size || h->cut_level > h->levels ||
        h->cut_first > h->cut_end || !h->block_count || h->block_count > UINT32_MAX ||
        h->section_size > SIZE_MAX || !h->key_count) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: part header inconsistent", path);
        return HLOD_ERR_FORMAT;
    }
    /* the store inside */
    hlod_store_header *sh = &p->sh;
    if (read_all(p->fd, sh, sizeof *sh, h->store_offset)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read the shard's store header", path);
        return HLOD_ERR_IO;
    }
    hlod_result r = hlod_store_check_header(sh, h->store_size, path, lg);
    if (r != HLOD_OK)
        return r;
    if (sh->node_count != h->key_count) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: the shard's store is inconsistent with the part header",
                  path);
        return HLOD_ERR_FORMAT;
    }
    p->nodes = malloc((size_t)sh->node_table_size);
    if (!p->nodes)
        return HLOD_ERR_NOMEM;
    if (read_all(p->fd, p->nodes, (size_t)sh->node_table_size, h->store_offset + sh->node_table_offset) ||
        hlod_store_hash(p->nodes, (size_t)sh->node_table_size) != sh->node_table_hash) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: the shard's node table checksum mismatch (damaged)", path);
        return HLOD_ERR_CHECKSUM;
    }
    r = hlod_store_validate(sh, p->nodes, sh->file_size, path, lg);
    if (r != HLOD_OK)
        return r;
    if (sh->extras_offset) {
        hlod_store_extras_header xh;
        size_t bytes = (size_t)sh->node_count * sizeof *p->extras;
        p->extras = malloc(bytes ? bytes : 1);
        if (!p->extras)
            return HLOD_ERR_NOMEM;
        if (read_all(p->fd, &xh, sizeof xh, h->store_offset + sh->extras_offset) ||
            read_all(p->fd, p->extras, bytes, h->store_offset + sh->extras_offset + sizeof xh)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read the shard's extras table", path);
            return HLOD_ERR_IO;
        }
        r = hlod_store_check_extras(sh, &xh, p->extras, path, lg);
        if (r != HLOD_OK)
            return r;
    }
    /* the section */
    p->sec = malloc(h->section_size ? (size_t)h->section_size : 1);
    if (!p->sec)
        return HLOD_ERR_NOMEM;
    if (read_all(p->fd, p->sec, (size_t)h->section_size, h->section_offset) ||
        hlod_store_hash(p->sec, (size_t)h->section_size) != h->section_hash) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: part section checksum mismatch (damaged)", path);
        return HLOD_ERR_CHECKSUM;
    }
    cursor c = {p->sec, (size_t)h->section_size, 0, 0};
    p->lo = (double (*)[3])take(&c, h->block_count * sizeof *p->lo);
    p->hi = (double (*)[3])take(&c, h->block_count * sizeof *p->hi);
    p->keys = (hlod_part_key *)take(&c, (size_t)h->key_count * sizeof *p->keys);
    for (uint64_t b = 0; !c.bad && b < h->block_count; b++)
        for (int k = 0; k < 3; k++)
            if (!(isfinite(p->lo[b][k]) && isfinite(p->hi[b][k]) && p->lo[b][k] <= p->hi[b][k]))
                c.bad = 1;
    /* an item takes 68 bytes before its arrays */
    size_t ntops = h->levels ? (size_t)(h->cut_end - h->cut_first) : 0;
    if (c.bad || ntops > (c.n - c.at) / 68) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: part section inconsistent", path);
        return HLOD_ERR_FORMAT;
    }
    p->tops = calloc(ntops ? ntops : 1, sizeof *p->tops);
    if (!p->tops)
        return HLOD_ERR_NOMEM;
    p->ntops = ntops;
    for (size_t i = 0; i < ntops && !c.bad; i++)
        if (take_item(&c, &p->tops[i]) != HLOD_OK)
            c.bad = 1;
    if (c.bad || c.at != c.n) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: part section inconsistent", path);
        return HLOD_ERR_FORMAT;
    }
    uint8_t *seen = calloc(h->key_count, 1);
    if (!seen)
        return HLOD_ERR_NOMEM;
    for (uint32_t j = 0; j < h->key_count; j++) {
        int twice = p->keys[j].store < h->key_count && seen[p->keys[j].store]++;
        if (twice || p->keys[j].store >= h->key_count || p->keys[j].level > h->cut_level ||
            (p->keys[j].level == h->cut_level && p->keys[j].k == 0 &&
             (p->keys[j].id < h->cut_first || p->keys[j].id >= h->cut_end)) ||
            (p->keys[j].level == 0 && p->keys[j].id >= h->block_count) ||
            !(p->keys[j].error >= 0 && p->keys[j].error <= p->nodes[p->keys[j].store].error)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: part key %u inconsistent", path, j);
            free(seen);
            return HLOD_ERR_FORMAT;
        }
    }
    free(seen);
    p->global = malloc((size_t)h->key_count * sizeof *p->global);
    if (!p->global)
        return HLOD_ERR_NOMEM;
    for (uint32_t j = 0; j < h->key_count; j++)
        p->global[j] = UINT32_MAX;
    return HLOD_OK;
}

/* ---- the merge -------------------------------------------------------------- */

/* Where a node of the merged store comes from. */
typedef struct source {
    uint32_t part;      /* UINT32_MAX: none yet */
    uint32_t key;       /* the part's key index */
} source;

typedef struct merge {
    part *parts;
    size_t nparts;
    hlod_store_writer *w;
    hlod_store_node *all;       /* the merged store's nodes, global order */
    size_t n, cap;
    uint32_t *up;               /* per global node: its parent from the levels above the cut */
    size_t groups;
} merge;

static hlod_result emit_merged(void *user, uint32_t level, uint32_t index, hlod_city_item *g,
                               const hlod_city_item *const *kids, size_t n)
{
    (void)level;
    (void)index;
    merge *M = user;
    if (M->n == M->cap)
        return HLOD_ERR_INVALID_ARG;
    hlod_result r = hlod_build_add_group(M->w, g, &M->all[M->n]);
    if (r != HLOD_OK)
        return r;
    g->node = (uint32_t)M->n;
    for (size_t k = 0; k < n; k++)
        M->up[kids[k]->node] = g->node;
    M->n++;
    M->groups++;
    return HLOD_OK;
}

/* Copies part p's node for key j into the merged store as node M->n. */
static hlod_result copy_node(merge *M, part *p, uint32_t j, uint8_t **scratch, size_t *scap,
                             const hlod_logger *lg)
{
    const hlod_store_node *src = &p->nodes[p->keys[j].store];
    if (src->payload_size > *scap) {
        uint8_t *n = realloc(*scratch, (size_t)src->payload_size);
        if (!n)
            return HLOD_ERR_NOMEM;
        *scratch = n;
        *scap = (size_t)src->payload_size;
    }
    if (read_all(p->fd, *scratch, (size_t)src->payload_size, p->h.store_offset + src->payload_offset)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read a payload: %s", p->path, strerror(errno));
        return HLOD_ERR_IO;
    }
    if (hlod_store_hash(*scratch, (size_t)src->payload_size) != src->payload_hash) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: store node %u: payload checksum mismatch (damaged)",
                  p->path, p->keys[j].store);
        return HLOD_ERR_CHECKSUM;
    }
    if (M->n == M->cap)
        return HLOD_ERR_INVALID_ARG;
    hlod_store_node *node = &M->all[M->n];
    hlod_result r = hlod_store_writer_add_copy(
        M->w, src, *scratch, p->extras ? &p->extras[p->keys[j].store] : NULL, node);
    if (r != HLOD_OK) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: store node %u: %s", p->path, p->keys[j].store,
                  hlod_result_str(r));
        return r;
    }
    node->error = p->keys[j].error;
    node->render_flags = src->render_flags;
    node->block = p->keys[j].level == 0 ? p->keys[j].id : HLOD_STORE_NO_BLOCK;
    node->parent = src->parent; /* the part's store index for now */
    p->global[p->keys[j].store] = (uint32_t)M->n;
    M->n++;
    return HLOD_OK;
}

static int cmp_key_order(const void *a, const void *b)
{
    const hlod_part_key *x = a, *y = b;
    if (x->level != y->level)
        return x->level < y->level ? -1 : 1;
    if (x->id != y->id)
        return x->id < y->id ? -1 : 1;
    return x->k < y->k ? -1 : x->k > y->k;
}

/* Do the parts belong together: one build (parameters, input, plan, N),
 * every shard once? */
static hlod_result check_together(const part *parts, size_t n, const hlod_logger *lg)
{
    const hlod_part_header *h0 = &parts[0].h;
    const hlod_store_header *s0 = &parts[0].sh;
    uint32_t N = h0->shard_count;
    for (size_t i = 1; i < n; i++) {
        const hlod_part_header *h = &parts[i].h;
        const hlod_store_header *sh = &parts[i].sh;
        if (h->shard_count != N) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s is shard %u/%u, %s shard %u/%u: not one build",
                      parts[i].path, h->shard_index, h->shard_count, parts[0].path,
                      h0->shard_index, N);
            return HLOD_ERR_INVALID_ARG;
        }
        if (h->params_hash != h0->params_hash || h->plan_hash != h0->plan_hash ||
            h->block_count != h0->block_count || h->cut_level != h0->cut_level ||
            h->levels != h0->levels || h->tris_in != h0->tris_in ||
            h->group_tris != h0->group_tris || h->group_size != h0->group_size ||
            h->jpeg_quality != h0->jpeg_quality || h->texture_blocks != h0->texture_blocks || h->far_cubes != h0->far_cubes ||
            h->texture_min_db != h0->texture_min_db || memcmp(&sh->build, &s0->build, sizeof s0->build) ||
            sh->quant_step != s0->quant_step ||
            memcmp(sh->quant_origin, s0->quant_origin, sizeof s0->quant_origin) ||
            sh->payload_align != s0->payload_align || sh->payload_codec != s0->payload_codec) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s and %s are parts of different builds (other input "
                      "or parameters)", parts[0].path, parts[i].path);
            return HLOD_ERR_INVALID_ARG;
        }
    }
    const char **by_index = calloc((size_t)N + 1, sizeof *by_index);
    if (!by_index)
        return HLOD_ERR_NOMEM;
    hlod_result r = HLOD_OK;
    for (size_t i = 0; i < n && r == HLOD_OK; i++) {
        uint32_t I = parts[i].h.shard_index;
        if (by_index[I]) {
            hlod_logf(lg, HLOD_LOG_ERROR, "shard %u/%u given twice: %s and %s", I, N, by_index[I],
                      parts[i].path);
            r = HLOD_ERR_INVALID_ARG;
        }
        by_index[I] = parts[i].path;
    }
    for (uint32_t I = 1; I <= N && r == HLOD_OK; I++)
        if (!by_index[I]) {
            hlod_logf(lg, HLOD_LOG_ERROR, "shard %u/%u is missing (%zu of %u parts given)", I, N, n, N);
            r = HLOD_ERR_INVALID_ARG;
        }
    free(by_index);
    return r;
}

/* The plan again, from the blocks' boxes, and each part's share of it as
 * hlod-build gives it. */
static hlod_result merge_plan(const part *parts, size_t n, hlod_city_plan *plan,
                              const hlod_logger *lg)
{
    const hlod_part_header *h0 = &parts[0].h;
    size_t B = (size_t)h0->block_count;
    hlod_result r = HLOD_OK;
    if (h0->levels) {
        r = hlod_city_plan_make((const double (*)[3])parts[0].lo, (const double (*)[3])parts[0].hi,
                                B, (size_t)h0->group_size, plan);
    } else if (!(plan->count = calloc(1, sizeof *plan->count))) {
        r = HLOD_ERR_NOMEM;
    } else {
        plan->count[0] = B;
    }
    if (r == HLOD_OK && (plan->levels != h0->levels || hlod_city_plan_hash(plan) != h0->plan_hash)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: its blocks do not give its plan", parts[0].path);
        return HLOD_ERR_FORMAT;
    }
    uint32_t L = h0->cut_level, N = h0->shard_count;
    for (size_t i = 0; i < n && r == HLOD_OK; i++) {
        uint64_t m = plan->count[L], I = parts[i].h.shard_index;
        if (parts[i].h.cut_first != (I - 1) * m / N || parts[i].h.cut_end != I * m / N) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: its share of level %u is not shard %llu/%u's",
                      parts[i].path, L, (unsigned long long)I, N);
            r = HLOD_ERR_FORMAT;
        }
    }
    return r;
}

/* A part's key with where it comes from. */
typedef struct ref {
    hlod_part_key k;
    uint32_t part, key;
} ref;

/* Every part's keys, sorted into the single build's order, each node of
 * the plan up to the cut level there exactly once. */
static hlod_result sorted_refs(const part *parts, size_t n, const hlod_city_plan *plan,
                               ref **out, size_t *count, const hlod_logger *lg)
{
    uint32_t L = parts[0].h.cut_level;
    size_t total = 0;
    for (size_t i = 0; i < n; i++)
        total += parts[i].h.key_count;
    ref *refs = malloc((total + 1) * sizeof *refs);
    if (!refs)
        return HLOD_ERR_NOMEM;
    *out = refs;
    *count = total;
    size_t at = 0;
    for (size_t i = 0; i < n; i++)
        for (uint32_t j = 0; j < parts[i].h.key_count; j++)
            refs[at++] = (ref){parts[i].keys[j], (uint32_t)i, j};
    qsort(refs, total, sizeof *refs, cmp_key_order);
    for (size_t a = 0; a < total; a++)
        if (refs[a].k.id >= plan->count[refs[a].k.level] || (refs[a].k.level && refs[a].k.k)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: part key %u names no node of the plan",
                      parts[refs[a].part].path, refs[a].key);
            return HLOD_ERR_FORMAT;
        }
    for (size_t a = 1; a < total; a++)
        if (!cmp_key_order(&refs[a - 1].k, &refs[a].k)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s and %s both hold node %u of %s %u",
                      parts[refs[a - 1].part].path, parts[refs[a].part].path, refs[a].k.k,
                      refs[a].k.level ? "group" : "block", refs[a].k.id);
            return HLOD_ERR_FORMAT;
        }
    size_t want = 0, have = 0;
    for (uint32_t l = 0; l <= L; l++)
        want += plan->count[l];
    for (size_t a = 0; a < total; a++)
        have += refs[a].k.level > 0 || refs[a].k.k == 0;
    if (have != want) {
        hlod_logf(lg, HLOD_LOG_ERROR, "the parts hold %zu of the %zu blocks and groups up to "
                  "level %u", have, want, L);
        return HLOD_ERR_FORMAT;
    }
    return HLOD_OK;
}

/* The groups above the cut level, on the parts' cut-level items (their
 * nodes cut_node[c]), streamed into M after the copied nodes. */
static hlod_result build_above(merge *M, const hlod_city_plan *plan, const uint32_t *cut_node,
                               size_t threads, const hlod_logger *lg)
{
    uint32_t L = M->parts[0].h.cut_level;
    hlod_city_item **items = calloc(plan->count[L], sizeof *items);
    if (!items)
        return HLOD_ERR_NOMEM;
    for (size_t i = 0; i < M->nparts; i++) {
        part *p = &M->parts[i];
        for (uint64_t c = p->h.cut_first; c < p->h.cut_end; c++) {
            hlod_city_item *it = &p->tops[c - p->h.cut_first];
            it->node = cut_node[c];
            items[c] = it;
        }
    }
    for (size_t i = 0; i < M->cap; i++)
        M->up[i] = HLOD_STORE_NO_PARENT;
    hlod_city_levels_desc cd = {0};
    cd.target_tris = (size_t)M->parts[0].h.group_tris;
    cd.threads = threads ? threads : 1;
    cd.logger = lg;
    cd.emit = emit_merged;
    cd.user = M;
    hlod_result r = hlod_city_levels(plan, L, items, plan->levels, &cd, NULL);
    free(items);
    for (size_t i = 0; i < M->n && r == HLOD_OK; i++)
        if (M->up[i] != HLOD_STORE_NO_PARENT)
            M->all[i].parent = M->up[i];
    if (r != HLOD_OK)
        hlod_logf(lg, HLOD_LOG_ERROR, "city levels above level %u: %s", L, hlod_result_str(r));
    return r;
}

/* Every node up to the cut, copied from the part that holds it in the
 * single build's order (refs), then the parents inside the parts as the
 * merged store's indices; cut_node[c]: the merged index of cut-level node c. */
static hlod_result copy_parts(merge *M, const ref *refs, size_t total, uint32_t *cut_node,
                              const hlod_logger *lg)
{
    uint32_t L = M->parts[0].h.cut_level;
    uint8_t *scratch = NULL;
    size_t scap = 0;
    hlod_result r = HLOD_OK;
    for (size_t a = 0; a < total && r == HLOD_OK; a++) {
        r = copy_node(M, &M->parts[refs[a].part], refs[a].key, &scratch, &scap, lg);
        if (refs[a].k.level == L && refs[a].k.k == 0)
            cut_node[refs[a].k.id] = (uint32_t)(M->n - 1);
    }
    free(scratch);
    for (size_t a = 0; a < total && r == HLOD_OK; a++) {
        part *p = &M->parts[refs[a].part];
        hlod_store_node *node = &M->all[p->global[p->keys[refs[a].key].store]];
        if (node->parent == HLOD_STORE_NO_PARENT)
            continue;
        /* the part store's parent (validated: < its node count) */
        node->parent = p->global[node->parent];
        if (node->parent == UINT32_MAX) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: a node's parent has no key", p->path);
            r = HLOD_ERR_FORMAT;
        }
    }
    return r;
}

/* The merged store's writer: the parts' payload layout and build fields. */
static void merged_desc(const part *p0, const hlod_logger *lg, hlod_store_writer_desc *wd)
{
    memset(wd, 0, sizeof *wd);
    wd->build = p0->sh.build;
    wd->payload_align = p0->sh.payload_align;
    wd->quant_step = p0->sh.quant_step;
    memcpy(wd->quant_origin, p0->sh.quant_origin, sizeof wd->quant_origin);
    wd->jpeg_quality = p0->h.jpeg_quality;
    wd->texture_blocks = p0->h.texture_blocks;
    wd->texture_min_db = p0->h.texture_min_db;
    wd->cubes = p0->h.far_cubes;
    wd->logger = lg;
}

hlod_result hlod_merge_store(const char *const *paths, size_t n, const char *out_path,
                             size_t threads, const hlod_logger *lg, hlod_merge_report *report)
{
    if (report)
        memset(report, 0, sizeof *report);
    if (!paths || !n || !out_path)
        return HLOD_ERR_INVALID_ARG;
    part *parts = calloc(n, sizeof *parts);
    if (!parts)
        return HLOD_ERR_NOMEM;
    for (size_t i = 0; i < n; i++)
        parts[i].fd = -1;
    hlod_result r = HLOD_OK;
    for (size_t i = 0; i < n && r == HLOD_OK; i++)
        r = part_open(&parts[i], paths[i], lg);
    if (r == HLOD_OK)
        r = check_together(parts, n, lg);
    hlod_city_plan plan = {0};
    if (r == HLOD_OK)
        r = merge_plan(parts, n, &plan, lg);
    ref *refs = NULL;
    size_t total = 0;
    if (r == HLOD_OK)
        r = sorted_refs(parts, n, &plan, &refs, &total, lg);
    uint32_t L = parts[0].h.cut_level;
    merge M = {parts, n, NULL, NULL, 0, total, NULL, 0};
    for (uint32_t l = L + 1; r == HLOD_OK && l <= plan.levels; l++)
        M.cap += plan.count[l];
    uint32_t *cut_node = NULL;
    if (r == HLOD_OK) {
        M.all = calloc(M.cap + 1, sizeof *M.all);
        M.up = malloc((M.cap + 1) * sizeof *M.up);
        cut_node = malloc((plan.count[L] + 1) * sizeof *cut_node);
        if (!M.all || !M.up || !cut_node)
            r = HLOD_ERR_NOMEM;
    }
    if (r == HLOD_OK) {
        hlod_store_writer_desc wd;
        merged_desc(&parts[0], lg, &wd);
        r = hlod_store_writer_open(out_path, &wd, &M.w);
        if (r != HLOD_OK)
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create: %s", out_path, hlod_result_str(r));
    }
    if (r == HLOD_OK)
        r = copy_parts(&M, refs, total, cut_node, lg);
    if (r == HLOD_OK && L < plan.levels)
        r = build_above(&M, &plan, cut_node, threads, lg);
    if (r == HLOD_OK) {
        hlod_build_contain(M.all, M.n);
        r = hlod_store_writer_finish(M.w, M.all, (uint32_t)M.n, NULL);
        M.w = NULL;
        if (r != HLOD_OK)
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot finish the store: %s", out_path,
                      hlod_result_str(r));
    }
    if (M.w)
        hlod_store_writer_abort(M.w);
    if (r == HLOD_OK && report) {
        report->parts = n;
        report->shards = parts[0].h.shard_count;
        report->nodes = M.n;
        report->blocks = (size_t)parts[0].h.block_count;
        report->cut_level = L;
        report->groups_built = M.groups;
        report->nodes_copied = total;
    }
    free(refs);
    free(cut_node);
    free(M.all);
    free(M.up);
    hlod_city_plan_free(&plan);
    for (size_t i = 0; i < n; i++)
        part_close(&parts[i]);
    free(parts);
    return r;
}
