/*
 * test_store.c - the HLOD store: writer, validating reader and hlod-info.
 *
 * A small synthetic store (two blocks, textured and untextured nodes, a
 * block far from the origin) is written with the writer API from nodes in
 * scrambled order, read back and compared field by field; then every
 * truncation, bit flips in the header, table and payloads, forged
 * out-of-range offsets and child ranges (with checksums recomputed so the
 * structural checks, not the checksums, must catch them), aborted writers
 * and concurrent readers and writers.  Run under ASan too: no input may
 * crash the reader.
 */
#include "check.h"
#include "grid_quads.h"
#include "rec_log.h"
#include "hlod/store.h"
#include "hlod/store_write.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

/* ---------- helpers ---------- */

static char g_dir[512];

static const char *tmp_path(const char *name, char *buf, size_t n)
{
    snprintf(buf, n, "%s/%s", g_dir, name);
    return buf;
}

static int write_all(const char *path, const void *buf, size_t size)
{
    FILE *fp = fopen(path, "wb");
    if (!fp)
        return 0;
    int ok = fwrite(buf, 1, size, fp) == size;
    return fclose(fp) == 0 && ok;
}

static void flip_bit(const char *path, uint64_t off, int bit)
{
    int fd = open(path, O_RDWR);
    uint8_t b = 0;
    if (fd < 0 || pread(fd, &b, 1, (off_t)off) != 1)
        abort();
    b ^= (uint8_t)(1u << bit);
    if (pwrite(fd, &b, 1, (off_t)off) != 1)
        abort();
    close(fd);
}

/* Number of entries in g_dir besides . and .. */
static int dir_entries(void)
{
    DIR *d = opendir(g_dir);
    int n = 0;
    struct dirent *e;
    while (d && (e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, ".."))
            n++;
    if (d)
        closedir(d);
    return n;
}

static void clear_dir(void)
{
    DIR *d = opendir(g_dir);
    struct dirent *e;
    char p[1024];
    while (d && (e = readdir(d)))
        if (strcmp(e->d_name, ".") && strcmp(e->d_name, ".."))
            unlink(tmp_path(e->d_name, p, sizeof p));
    if (d)
        closedir(d);
}

/* ---------- synthetic node meshes ---------- */

#define S_NORMALS 1u
#define S_UVS 2u
#define S_COLORS 4u
#define S_TEXTURE 8u

typedef struct synth {
    hlod_store_payload_desc d;
    double *pos;
    float *nrm, *uv;
    uint8_t *col, *pix;
    uint32_t *idx;
} synth;

/* An nx x ny grid of quads of side `scale` starting at base, z bumped by
 * `wave` (0: planar), with the attributes opts asks for; a texture of
 * tw x th x tc bytes; `mixed`: only the first half of the triangles
 * textured. */
static void synth_make(synth *s, int nx, int ny, const double base[3], double scale, double wave,
                       unsigned opts, uint32_t tw, uint32_t th, uint32_t tc, int mixed)
{
    memset(s, 0, sizeof *s);
    uint32_t v = (uint32_t)((nx + 1) * (ny + 1)), t = (uint32_t)(2 * nx * ny);
    s->pos = malloc(3 * sizeof(double) * v);
    s->idx = malloc(3 * sizeof(uint32_t) * t);
    if (opts & S_NORMALS)
        s->nrm = malloc(3 * sizeof(float) * v);
    if (opts & (S_UVS | S_TEXTURE))
        s->uv = malloc(2 * sizeof(float) * v);
    if (opts & S_COLORS)
        s->col = malloc(4 * v);
    for (int j = 0; j <= ny; j++)
        for (int i = 0; i <= nx; i++) {
            size_t k = (size_t)j * (nx + 1) + i;
            s->pos[3 * k] = base[0] + scale * i;
            s->pos[3 * k + 1] = base[1] + scale * j;
            s->pos[3 * k + 2] = base[2] + wave * sin(0.7 * i + 1.3 * j);
            if (s->nrm) {
                s->nrm[3 * k] = 0.1f * (float)i;
                s->nrm[3 * k + 1] = -0.2f * (float)j;
                s->nrm[3 * k + 2] = 1.0f;
            }
            if (s->uv) {
                s->uv[2 * k] = (float)i / (float)nx;
                s->uv[2 * k + 1] = (float)j / (float)ny;
            }
            if (s->col)
                for (int c = 0; c < 4; c++)
                    s->col[4 * k + c] = (uint8_t)(17 * k + 31 * c);
        }
    grid_quads(s->idx, (uint32_t)nx, (uint32_t)ny);
    s->d.vertex_count = v;
    s->d.positions = s->pos;
    s->d.origin[0] = base[0] + scale * nx / 2;
    s->d.origin[1] = base[1] + scale * ny / 2;
    s->d.origin[2] = base[2];
    s->d.normals = s->nrm;
    s->d.uvs = s->uv;
    s->d.colors = s->col;
    s->d.tri_count = t;
    s->d.indices = s->idx;
    if (opts & S_TEXTURE) {
        s->pix = malloc((size_t)tw * th * tc);
        for (size_t i = 0; i < (size_t)tw * th * tc; i++)
            s->pix[i] = (uint8_t)(i * 7 + 3);
        s->d.pixels = s->pix;
        s->d.tex_width = tw;
        s->d.tex_height = th;
        s->d.tex_channels = tc;
        s->d.tex_tri_count = mixed ? t / 2 : t;
    }
}

static void synth_free(synth *s)
{
    free(s->pos);
    free(s->nrm);
    free(s->uv);
    free(s->col);
    free(s->pix);
    free(s->idx);
    memset(s, 0, sizeof *s);
}

/* The test store: block 0 textured at a city-scale origin, three levels;
 * block 1 untextured with vertex colours.  Caller order is scrambled. */
enum { R0, A, B, A1, A2, R1, C, D, E, NODES };
static const uint32_t PARENT[NODES] = {HLOD_STORE_NO_PARENT, R0, R0, A, A,
                                       HLOD_STORE_NO_PARENT, R1, R1, R1};
static const double ERROR[NODES] = {2.0, 1.0, 0.5, 0.25, 0, 3.0, 0.5, 0.5, 0};
/* caller position of each logical node */
static const uint32_t CALLER_POS[NODES] = {5, 4, 3, 0, 7, 2, 1, 8, 6};

typedef struct test_store {
    synth mesh[NODES];
    hlod_store_node filled[NODES];  /* as add() filled them (caller order) */
    uint32_t store_index[NODES];    /* caller order -> store order */
    hlod_store_build_info build;
} test_store;

static void make_meshes(test_store *ts)
{
    static const double city[3] = {5e5, 4.1e6, 12.0}, zero[3] = {0, 0, 0};
    synth *m = ts->mesh;
    synth_make(&m[R0], 2, 2, city, 4.0, 0.0, S_NORMALS | S_UVS | S_TEXTURE, 8, 4, 3, 0);
    synth_make(&m[A], 3, 2, city, 2.0, 0.3, S_UVS | S_TEXTURE, 4, 4, 4, 0);
    synth_make(&m[B], 3, 3, city, 1.5, 0.2, S_NORMALS | S_UVS | S_COLORS | S_TEXTURE, 5, 3, 1,
               1);
    synth_make(&m[A1], 4, 4, city, 0.5, 0.1, S_UVS | S_TEXTURE, 2, 2, 2, 0);
    synth_make(&m[A2], 2, 5, city, 0.4, 0.1, S_NORMALS | S_UVS | S_TEXTURE, 3, 7, 3, 1);
    synth_make(&m[R1], 1, 1, zero, 10.0, 0.0, S_COLORS, 0, 0, 0, 0);
    synth_make(&m[C], 3, 1, zero, 3.0, 0.5, S_NORMALS | S_COLORS, 0, 0, 0, 0);
    synth_make(&m[D], 2, 2, zero, 2.5, 0.5, 0, 0, 0, 0, 0);
    synth_make(&m[E], 1, 3, zero, 2.0, 0.5, S_UVS, 0, 0, 0, 0);
    memset(&ts->build, 0, sizeof ts->build);
    ts->build.method = HLOD_STORE_METHOD_CUTPLANE;
    ts->build.desired_tris = 8;
    ts->build.level_factor = 2;
    ts->build.c_tex = 0.6;
}

static void free_meshes(test_store *ts)
{
    for (int i = 0; i < NODES; i++)
        synth_free(&ts->mesh[i]);
}

/* Writes the test store to path; returns the finish result. */
static hlod_result write_test_store(test_store *ts, const char *path, const hlod_logger *lg)
{
    hlod_store_writer_desc desc = {0};
    desc.build = ts->build;
    desc.logger = lg;
    hlod_store_writer *w = NULL;
    hlod_result r = hlod_store_writer_open(path, &desc, &w);
    if (r != HLOD_OK)
        return r;
    hlod_store_node nodes[NODES];
    /* add in an order unlike both the logical and the caller order */
    static const int add_order[NODES] = {C, A2, R0, E, B, R1, A1, D, A};
    for (int j = 0; j < NODES; j++) {
        int i = add_order[j];
        r = hlod_store_writer_add(w, &ts->mesh[i].d, &nodes[CALLER_POS[i]]);
        if (r != HLOD_OK) {
            hlod_store_writer_abort(w);
            return r;
        }
    }
    for (int i = 0; i < NODES; i++) {
        hlod_store_node *n = &nodes[CALLER_POS[i]];
        n->parent = PARENT[i] == HLOD_STORE_NO_PARENT ? PARENT[i] : CALLER_POS[PARENT[i]];
        n->error = ERROR[i];
        n->block = i == R0 ? 0 : i == R1 ? 1 : 0;
        ts->filled[i] = *n;
    }
    uint32_t idx[NODES];
    r = hlod_store_writer_finish(w, nodes, NODES, idx);
    for (int i = 0; i < NODES; i++)
        ts->store_index[i] = idx[CALLER_POS[i]];
    return r;
}

/* A good store at g_dir/NAME, written once per test. */
static hlod_result good_store(test_store *ts, const char *name, char *path, size_t n)
{
    make_meshes(ts);
    return write_test_store(ts, tmp_path(name, path, n), NULL);
}

/* ---------- round trip ---------- */

static void compare_payload(const synth *m, const hlod_store_payload *p)
{
    const hlod_store_payload_desc *d = &m->d;
    CHECK(p->vertex_count == d->vertex_count);
    CHECK(p->index_count == 3 * d->tri_count);
    CHECK(p->tex_tri_count == d->tex_tri_count);
    CHECK(p->tex_width == d->tex_width && p->tex_height == d->tex_height &&
          p->tex_channels == d->tex_channels);
    size_t v = d->vertex_count;
    int same = 1;
    for (size_t i = 0; i < 3 * v; i++)
        same &= p->positions[i] == (float)(d->positions[i] - d->origin[i % 3]);
    CHECK(same);
    CHECK(!d->normals == !p->normals);
    CHECK(!d->uvs == !p->uvs);
    CHECK(!d->colors == !p->colors);
    CHECK(!d->pixels == !p->pixels);
    if (d->normals && p->normals)
        CHECK(memcmp(p->normals, d->normals, 12 * v) == 0);
    if (d->uvs && p->uvs)
        CHECK(memcmp(p->uvs, d->uvs, 8 * v) == 0);
    if (d->colors && p->colors)
        CHECK(memcmp(p->colors, d->colors, 4 * v) == 0);
    CHECK(memcmp(p->indices, d->indices, 12 * (size_t)d->tri_count) == 0);
    if (d->pixels && p->pixels)
        CHECK(memcmp(p->pixels, d->pixels,
                     (size_t)d->tex_width * d->tex_height * d->tex_channels) == 0);
}

static void round_trip(void)
{
    test_store ts;
    char path[1024];
    CHECK(good_store(&ts, "rt.hlod", path, sizeof path) == HLOD_OK);
    rec_log log;
    hlod_logger lg = rec_logger(&log);
    hlod_store *s = NULL;
    hlod_result r = hlod_store_open(path, &lg, &s);
    CHECKF(r == HLOD_OK, "%s: %s", hlod_result_str(r), log.last);
    if (!s)
        goto out;
    const hlod_store_header *h = hlod_store_get_header(s);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    CHECK(memcmp(h->magic, HLOD_STORE_MAGIC, 8) == 0);
    CHECK(h->version == HLOD_STORE_VERSION && h->endian == HLOD_STORE_ENDIAN);
    CHECK(h->header_size == 256 && h->node_size == 192);
    CHECK(h->node_count == NODES && h->root_count == 2 && h->depth_count == 3);
    CHECK(h->flags == HLOD_STORE_TEXTURED);
    CHECK(h->payload_align == HLOD_STORE_DEFAULT_ALIGN);
    CHECK(memcmp(&h->build, &ts.build, sizeof ts.build) == 0);
    CHECK(hlod_store_node_count(s) == NODES && hlod_store_root_count(s) == 2);

    /* roots by block, then breadth-first; children keep caller order
     * (B comes before A in the caller's array) */
    uint32_t *si = ts.store_index;
    CHECK(si[R0] == 0 && si[R1] == 1);
    CHECK(si[B] == 2 && si[A] == 3);
    CHECK(si[C] == 4 && si[E] == 5 && si[D] == 6);  /* caller order: C@1, E@6, D@8 */
    CHECK(si[A1] == 7 && si[A2] == 8);              /* A1@0, A2@7 */
    CHECK(nodes[0].first_child == 2 && nodes[1].first_child == 4);
    CHECK(nodes[2].first_child == 7 && nodes[3].first_child == 7);  /* B leaf */
    CHECK(nodes[4].first_child == 9 && nodes[NODES].first_child == NODES);

    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int i = 0; i < NODES; i++) {
        const hlod_store_node *n = &nodes[si[i]], *f = &ts.filled[i];
        const synth *m = &ts.mesh[i];
        uint32_t depth = (i == R0 || i == R1) ? 0 : (i == A1 || i == A2) ? 2 : 1;
        CHECKF(n->depth == depth, "node %d", i);
        CHECKF(n->parent == (PARENT[i] == HLOD_STORE_NO_PARENT ? PARENT[i] : si[PARENT[i]]),
               "node %d", i);
        CHECKF(n->block == (i == R1 || i == C || i == D || i == E ? 1u : 0u), "node %d", i);
        CHECK(n->error == ERROR[i]);
        CHECK(n->vertex_count == m->d.vertex_count && n->tri_count == m->d.tri_count);
        CHECK(n->tex_tri_count == m->d.tex_tri_count);
        CHECK(n->untex_tri_count == m->d.tri_count - m->d.tex_tri_count);
        CHECK(n->tex_width == m->d.tex_width && n->tex_height == m->d.tex_height &&
              n->tex_channels == m->d.tex_channels);
        CHECK(memcmp(n->origin, m->d.origin, sizeof n->origin) == 0);
        unsigned flags = (m->nrm ? HLOD_NODE_NORMALS : 0) | (m->uv ? HLOD_NODE_UVS : 0) |
                         (m->col ? HLOD_NODE_COLORS : 0) | (m->pix ? HLOD_NODE_TEXTURE : 0);
        CHECK(n->flags == flags);
        /* everything add() computed survives the trip bit for bit */
        CHECK(memcmp(n->bbox_min, f->bbox_min, 48) == 0);
        CHECK(n->cost == f->cost && n->static_benefit == f->static_benefit);
        CHECK(memcmp(n->avg_normal, f->avg_normal, 12) == 0);
        CHECK(n->payload_offset == f->payload_offset && n->payload_size == f->payload_size &&
              n->payload_hash == f->payload_hash);
        CHECK(n->payload_offset % HLOD_STORE_DEFAULT_ALIGN == 0);
        CHECK(n->cost == hlod_store_cost(n->tex_tri_count, n->untex_tri_count, 0.6));
        for (int k = 0; k < 3; k++) {
            lo[k] = fmin(lo[k], n->bbox_min[k]);
            hi[k] = fmax(hi[k], n->bbox_max[k]);
        }

        hlod_store_payload p;
        r = hlod_store_read_node(s, si[i], 100, &p);
        CHECKF(r == HLOD_OK, "node %d: %s %s", i, hlod_result_str(r), log.last);
        if (r == HLOD_OK) {
            CHECK(p.node == si[i] && p.flags == flags && p.bytes == n->payload_size);
            compare_payload(m, &p);
        }
        hlod_store_payload_free(&p);
    }
    CHECK(memcmp(h->bbox_min, lo, sizeof lo) == 0 && memcmp(h->bbox_max, hi, sizeof hi) == 0);

    /* Exact values for R0: a planar 2x2 grid of 4 m quads at z = 12:
     * 8 triangles, area 64, all textured. */
    const hlod_store_node *r0 = &nodes[0];
    CHECK(r0->bbox_min[0] == 5e5 && r0->bbox_max[0] == 5e5 + 8);
    CHECK(r0->bbox_min[1] == 4.1e6 && r0->bbox_max[1] == 4.1e6 + 8);
    CHECK(r0->bbox_min[2] == 12 && r0->bbox_max[2] == 12);
    CHECK(r0->cost == 8 * 0.6);                                 /* eq. 1 */
    CHECK(fabs(r0->static_benefit - sqrt(8.0 * 64.0)) < 1e-12); /* eq. 2 */
    CHECK(r0->avg_normal[0] == 0 && r0->avg_normal[1] == 0 && r0->avg_normal[2] == 1); /* eq. 3 */
    /* B: half textured (eq. 1 with both terms) */
    const hlod_store_node *nb = &nodes[si[B]];
    CHECK(nb->tex_tri_count == 9 && nb->untex_tri_count == 9);
    CHECK(fabs(nb->cost - (9 * 0.6 + 9 * 0.4)) < 1e-12);
    /* R1: one planar 10 m quad at the origin, untextured */
    CHECK(nodes[1].cost == 2 * 0.4 && nodes[1].static_benefit == sqrt(2.0 * 100.0));
out:
    hlod_store_close(s);
    free_meshes(&ts);
    clear_dir();
}

/* Reads resume where they stopped, interleaved with another node's read,
 * and never read a byte twice. */
static void incremental_interleaved(void)
{
    test_store ts;
    char path[1024];
    CHECK(good_store(&ts, "inc.hlod", path, sizeof path) == HLOD_OK);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (!s)
        goto out;
    uint32_t x = ts.store_index[A1], y = ts.store_index[B];
    hlod_store_read rx, ry;
    CHECK(hlod_store_read_begin(s, x, &rx) == HLOD_OK);
    CHECK(rx.size == hlod_store_nodes(s)[x].payload_size && rx.done == 0);
    int complete = 0;
    CHECK(hlod_store_read_step(&rx, 100, &complete) == HLOD_OK && !complete && rx.done == 100);
    CHECK(hlod_store_read_step(&rx, 33, &complete) == HLOD_OK && !complete && rx.done == 133);
    /* suspend x, read y completely */
    CHECK(hlod_store_read_begin(s, y, &ry) == HLOD_OK);
    int steps = 0;
    complete = 0;
    while (!complete && steps < 100000) {
        uint64_t before = ry.done;
        CHECK(hlod_store_read_step(&ry, 64, &complete) == HLOD_OK);
        CHECK(ry.done == before + 64 || (complete && ry.done == ry.size));
        steps++;
    }
    CHECK(steps == (int)((ry.size + 63) / 64));
    hlod_store_payload py, px;
    CHECK(hlod_store_read_finish(&ry, &py) == HLOD_OK);
    compare_payload(&ts.mesh[B], &py);
    /* a finished read is empty; finishing x early is refused and cancels it */
    CHECK(ry.buf == NULL && ry.store == NULL);
    /* resume x */
    complete = 0;
    while (!complete)
        CHECK(hlod_store_read_step(&rx, 1 << 20, &complete) == HLOD_OK);
    CHECK(rx.done == rx.size);
    CHECK(hlod_store_read_step(&rx, 10, &complete) == HLOD_OK && complete); /* no-op */
    CHECK(hlod_store_read_finish(&rx, &px) == HLOD_OK);
    compare_payload(&ts.mesh[A1], &px);
    hlod_store_payload_free(&px);
    hlod_store_payload_free(&py);

    hlod_store_read rz;
    CHECK(hlod_store_read_begin(s, x, &rz) == HLOD_OK);
    CHECK(hlod_store_read_step(&rz, 10, &complete) == HLOD_OK);
    CHECK(hlod_store_read_finish(&rz, &px) == HLOD_ERR_INVALID_ARG && px.memory == NULL);
    CHECK(hlod_store_read_begin(s, NODES, &rz) == HLOD_ERR_INVALID_ARG);
    hlod_store_read_cancel(&rz);
out:
    hlod_store_close(s);
    free_meshes(&ts);
    clear_dir();
}

/* ---------- corruption ---------- */

/* Every truncation is refused at open, naming the problem. */
static void every_truncation(void)
{
    test_store ts;
    char path[1024], cut[1024];
    CHECK(good_store(&ts, "tr.hlod", path, sizeof path) == HLOD_OK);
    size_t size = 0;
    uint8_t *buf = (uint8_t *)check_slurp(path, &size);
    CHECK(buf && size > 4096);
    tmp_path("cut.hlod", cut, sizeof cut);
    CHECK(buf && write_all(cut, buf, size));
    int fails = 0;
    for (size_t len = size; len-- > 0;) {
        if (truncate(cut, (off_t)len) != 0) {
            fails++;
            break;
        }
        rec_log log;
        hlod_logger lg = rec_logger(&log);
        hlod_store *s = NULL;
        hlod_result r = hlod_store_open(cut, &lg, &s);
        if (r != HLOD_ERR_FORMAT || s || log.count != 1 ||
            (!strstr(log.last, "truncated") && !strstr(log.last, "shorter"))) {
            if (fails++ < 5)
                fprintf(stderr, "length %zu: %s, log '%s'\n", len, hlod_result_str(r), log.last);
        }
        hlod_store_close(s);
    }
    CHECK(fails == 0);

    /* A file that shrinks after open fails at payload read, not by a crash. */
    CHECK(write_all(cut, buf, size));
    hlod_store *s = NULL;
    rec_log log;
    hlod_logger lg = rec_logger(&log);
    CHECK(hlod_store_open(cut, &lg, &s) == HLOD_OK);
    if (s) {
        uint32_t i = ts.store_index[A2];
        const hlod_store_node *n = &hlod_store_nodes(s)[i];
        CHECK(truncate(cut, (off_t)(n->payload_offset + n->payload_size / 2)) == 0);
        hlod_store_payload p;
        CHECK(hlod_store_read_node(s, i, 65536, &p) == HLOD_ERR_IO && p.memory == NULL);
        CHECKF(strstr(log.last, "unexpected end of file") != NULL, "log '%s'", log.last);
        CHECK(hlod_store_read_node(s, ts.store_index[C], 65536, &p) == HLOD_OK); /* added first */
        hlod_store_payload_free(&p);
    }
    hlod_store_close(s);
    free(buf);
    free_meshes(&ts);
    clear_dir();
}

/* Every bit of the header and the node table, and a bit in every payload
 * byte, flipped one at a time. */
static void bit_flips(void)
{
    test_store ts;
    char path[1024];
    CHECK(good_store(&ts, "flip.hlod", path, sizeof path) == HLOD_OK);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (!s)
        goto out;
    hlod_store_header h = *hlod_store_get_header(s);
    hlod_store_node nodes[NODES + 1];
    memcpy(nodes, hlod_store_nodes(s), sizeof nodes);
    hlod_store_close(s);
    s = NULL;

    int missed = 0, wrong_code = 0;
    uint64_t regions[2][2] = {{0, 256}, {h.node_table_offset, h.node_table_size}};
    for (int reg = 0; reg < 2; reg++)
        for (uint64_t off = regions[reg][0]; off < regions[reg][0] + regions[reg][1]; off++)
            for (int bit = 0; bit < 8; bit++) {
                flip_bit(path, off, bit);
                hlod_store *t = NULL;
                hlod_result r = hlod_store_open(path, NULL, &t);
                if (r == HLOD_OK && missed++ < 5)
                    fprintf(stderr, "flip at %llu bit %d not detected\n",
                            (unsigned long long)off, bit);
                /* inside the table, only its checksum can see a flip */
                if (reg == 1 && r != HLOD_ERR_CHECKSUM)
                    wrong_code++;
                hlod_store_close(t);
                flip_bit(path, off, bit);
            }
    CHECK(missed == 0);
    CHECK(wrong_code == 0);

    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (!s)
        goto out;
    missed = 0;
    for (uint32_t i = 0; i < NODES; i++)
        for (uint64_t b = 0; b < nodes[i].payload_size; b++) {
            uint64_t off = nodes[i].payload_offset + b;
            flip_bit(path, off, (int)(b % 8));
            hlod_store_payload p;
            hlod_result r = hlod_store_read_node(s, i, 4096, &p);
            hlod_store_payload_free(&p);
            if (r != HLOD_ERR_CHECKSUM && missed++ < 5)
                fprintf(stderr, "node %u byte %llu: %s\n", i, (unsigned long long)b,
                        hlod_result_str(r));
            flip_bit(path, off, (int)(b % 8));
        }
    CHECK(missed == 0);
    /* Padding carries nothing: a flip there changes no data read. */
    flip_bit(path, 1000, 3);
    hlod_store *t = NULL;
    CHECK(hlod_store_open(path, NULL, &t) == HLOD_OK);
    for (uint32_t i = 0; t && i < NODES; i++) {
        hlod_store_payload p;
        CHECK(hlod_store_read_node(t, i, 0, &p) == HLOD_OK);
        hlod_store_payload_free(&p);
    }
    hlod_store_close(t);
out:
    hlod_store_close(s);
    free_meshes(&ts);
    clear_dir();
}

/* Forged stores: the header and table are changed and their checksums
 * recomputed, so the structural checks must catch the change. */
typedef struct forge_ctx {
    hlod_store_header *h;
    hlod_store_node *t;     /* the table inside the file image */
    uint8_t *file;
    size_t size;
} forge_ctx;

static void reseal(forge_ctx *f)
{
    hlod_store_header *h = f->h;
    if (h->node_table_offset <= f->size && h->node_table_size <= f->size - h->node_table_offset)
        h->node_table_hash = hlod_store_hash(f->file + h->node_table_offset, h->node_table_size);
    h->header_hash = hlod_store_hash(h, HLOD_STORE_HEADER_HASHED);
}

/* Re-hashes node i's payload after a change to it. */
static void reseal_payload(forge_ctx *f, uint32_t i)
{
    f->t[i].payload_hash = hlod_store_hash(f->file + f->t[i].payload_offset, f->t[i].payload_size);
}

typedef void (*forge_fn)(forge_ctx *f);

static void f_offset_past_end(forge_ctx *f)
{
    f->t[3].payload_offset = ((f->size + 4095) / 4096 + 1) * 4096;     /* aligned */
}
static void f_offset_in_header(forge_ctx *f) { f->t[3].payload_offset = 0; }
static void f_offset_on_table(forge_ctx *f) { f->t[3].payload_offset = f->h->node_table_offset; }
static void f_offset_huge(forge_ctx *f) { f->t[2].payload_offset = UINT64_MAX - 4095; }
static void f_overlap(forge_ctx *f)
{
    f->t[4].payload_offset = f->t[2].payload_offset;
}
static void f_misaligned(forge_ctx *f) { f->t[5].payload_offset += 64; }
static void f_size(forge_ctx *f) { f->t[5].payload_size += 4; }
static void f_first_child_zero(forge_ctx *f) { f->t[0].first_child = 0; }
static void f_child_past_end(forge_ctx *f) { f->t[4].first_child = NODES + 3; }
static void f_child_decreasing(forge_ctx *f) { f->t[3].first_child = 5; }
static void f_child_self(forge_ctx *f)
{
    /* nodes 0 and 1 become leaves, node 2's children start at itself */
    f->t[1].first_child = 2;
    f->t[2].first_child = 2;
}
static void f_parent(forge_ctx *f) { f->t[7].parent = 2; }
static void f_depth(forge_ctx *f) { f->t[8].depth = 1; }
static void f_block(forge_ctx *f) { f->t[5].block = 0; }
static void f_root_parent(forge_ctx *f) { f->t[1].parent = 0; }
static void f_sentinel(forge_ctx *f) { f->t[NODES].depth = 1; }
static void f_sentinel_child(forge_ctx *f) { f->t[NODES].first_child = NODES - 1; }
static void f_node_count(forge_ctx *f) { f->h->node_count = NODES + 1; }
static void f_node_count_max(forge_ctx *f) { f->h->node_count = UINT32_MAX; }
static void f_table_offset(forge_ctx *f) { f->h->node_table_offset = f->size; }
static void f_table_offset_huge(forge_ctx *f) { f->h->node_table_offset = UINT64_MAX - 100; }
static void f_roots_zero(forge_ctx *f) { f->h->root_count = 0; }
static void f_roots_many(forge_ctx *f) { f->h->root_count = NODES + 1; }
static void f_blocks_zero(forge_ctx *f) { f->h->block_count = 0; }
static void f_top_many(forge_ctx *f) { f->h->top_count = NODES; }
static void f_block_depth(forge_ctx *f) { f->h->block_depth = 1; }
static void f_nan_bbox(forge_ctx *f) { f->t[2].bbox_max[1] = NAN; }
static void f_inf_error(forge_ctx *f) { f->t[8].error = INFINITY; }
static void f_error_order(forge_ctx *f) { f->t[8].error = 10.0; }
static void f_cost(forge_ctx *f) { f->t[3].cost *= 1.5; }
static void f_bbox_inverted(forge_ctx *f) { f->t[3].bbox_min[0] = f->t[3].bbox_max[0] + 1; }
static void f_tri_sum(forge_ctx *f) { f->t[2].untex_tri_count += 1; }
static void f_tex_flag(forge_ctx *f) { f->t[0].flags &= ~HLOD_NODE_UVS; }
static void f_tex_huge(forge_ctx *f) { f->t[0].tex_width = 1u << 30; }
static void f_zero_tris(forge_ctx *f) { f->t[6].tri_count = f->t[6].untex_tri_count = 0; }
static void f_depth_count(forge_ctx *f) { f->h->depth_count = 7; }
static void f_payload_bytes(forge_ctx *f) { f->h->payload_bytes += 1; }
static void f_flags(forge_ctx *f) { f->h->flags = 0; }
static void f_align(forge_ctx *f) { f->h->payload_align = 3000; }
static void f_version(forge_ctx *f) { f->h->version = HLOD_STORE_VERSION + 1; }
static void f_endian(forge_ctx *f) { f->h->endian = 0x04030201u; }
static void f_magic(forge_ctx *f) { f->h->magic[0] = 'X'; }
static void f_node_size(forge_ctx *f) { f->h->node_size = 200; }
static void f_file_size(forge_ctx *f) { f->h->file_size += 4096; }
static void f_c_tex(forge_ctx *f) { f->h->build.c_tex = 1.5; }
static void f_reserved(forge_ctx *f) { f->t[4].reserved1 = 1; }

typedef struct forge_case {
    const char *name;
    forge_fn fn;
    hlod_result want;
    const char *msg;    /* expected in the log line */
} forge_case;

static void forged_tables(void)
{
    static const forge_case cases[] = {
        {"payload past the end", f_offset_past_end, HLOD_ERR_FORMAT, "outside the file"},
        {"payload in the header", f_offset_in_header, HLOD_ERR_FORMAT, "outside the file"},
        {"payload on the table", f_offset_on_table, HLOD_ERR_FORMAT, "overlaps the node table"},
        {"payload offset wraps", f_offset_huge, HLOD_ERR_FORMAT, "outside the file"},
        {"payloads overlap", f_overlap, HLOD_ERR_FORMAT, "overlaps node"},
        {"payload misaligned", f_misaligned, HLOD_ERR_FORMAT, "not a multiple"},
        {"payload size", f_size, HLOD_ERR_FORMAT, "counts need"},
        {"first child 0", f_first_child_zero, HLOD_ERR_FORMAT, "children start"},
        {"child range past end", f_child_past_end, HLOD_ERR_FORMAT, "are not a range"},
        {"child range decreasing", f_child_decreasing, HLOD_ERR_FORMAT, "are not a range"},
        {"child range at itself", f_child_self, HLOD_ERR_FORMAT, "are not a range"},
        {"wrong parent", f_parent, HLOD_ERR_FORMAT, "disagree"},
        {"wrong depth", f_depth, HLOD_ERR_FORMAT, "disagree"},
        {"wrong block", f_block, HLOD_ERR_FORMAT, "its parent's"},
        {"root with a parent", f_root_parent, HLOD_ERR_FORMAT, "root 1"},
        {"sentinel field", f_sentinel, HLOD_ERR_FORMAT, "sentinel"},
        {"sentinel range", f_sentinel_child, HLOD_ERR_FORMAT, "sentinel"},
        {"node count vs table", f_node_count, HLOD_ERR_FORMAT, "node table is"},
        {"node count max", f_node_count_max, HLOD_ERR_FORMAT, "nodes"},
        {"table offset at end", f_table_offset, HLOD_ERR_FORMAT, "outside the file"},
        {"table offset wraps", f_table_offset_huge, HLOD_ERR_FORMAT, "outside the file"},
        {"no roots", f_roots_zero, HLOD_ERR_FORMAT, "roots"},
        {"too many roots", f_roots_many, HLOD_ERR_FORMAT, "roots"},
        {"no blocks", f_blocks_zero, HLOD_ERR_FORMAT, "0 blocks"},
        {"top past the roots", f_top_many, HLOD_ERR_FORMAT, "top nodes"},
        {"blocks below the roots", f_block_depth, HLOD_ERR_FORMAT, "top nodes"},
        {"NaN box", f_nan_bbox, HLOD_ERR_NAN, "non-finite"},
        {"infinite error", f_inf_error, HLOD_ERR_NAN, "non-finite"},
        {"error not monotone", f_error_order, HLOD_ERR_FORMAT, "exceeds its parent"},
        {"cost not eq. 1", f_cost, HLOD_ERR_FORMAT, "eq. 1"},
        {"inverted box", f_bbox_inverted, HLOD_ERR_FORMAT, "min > max"},
        {"triangle sum", f_tri_sum, HLOD_ERR_FORMAT, "untextured"},
        {"texture without UVs", f_tex_flag, HLOD_ERR_FORMAT, "impossible"},
        {"texture too large", f_tex_huge, HLOD_ERR_FORMAT, "impossible"},
        {"no triangles", f_zero_tris, HLOD_ERR_FORMAT, "no triangles"},
        {"depth count", f_depth_count, HLOD_ERR_FORMAT, "depths"},
        {"payload byte total", f_payload_bytes, HLOD_ERR_FORMAT, "payload bytes"},
        {"header flags", f_flags, HLOD_ERR_FORMAT, "flags"},
        {"alignment", f_align, HLOD_ERR_FORMAT, "alignment"},
        {"version", f_version, HLOD_ERR_VERSION, "version"},
        {"byte order", f_endian, HLOD_ERR_UNSUPPORTED, "byte order"},
        {"magic", f_magic, HLOD_ERR_FORMAT, "magic"},
        {"node size", f_node_size, HLOD_ERR_FORMAT, "record sizes"},
        {"file size", f_file_size, HLOD_ERR_FORMAT, "truncated"},
        {"c_tex", f_c_tex, HLOD_ERR_FORMAT, "c_tex"},
        {"reserved", f_reserved, HLOD_ERR_FORMAT, "reserved"},
    };
    test_store ts;
    char path[1024], forged[1024];
    CHECK(good_store(&ts, "forge.hlod", path, sizeof path) == HLOD_OK);
    tmp_path("forged.hlod", forged, sizeof forged);
    size_t size = 0;
    uint8_t *good = (uint8_t *)check_slurp(path, &size);
    uint8_t *img = malloc(size);
    CHECK(good && img);
    if (!good || !img)
        goto out;

    /* sanity: resealing an unchanged image gives a store that opens */
    for (size_t c = 0; c <= sizeof cases / sizeof cases[0]; c++) {
        memcpy(img, good, size);
        forge_ctx f = {(hlod_store_header *)img, NULL, img, size};
        f.t = (hlod_store_node *)(img + f.h->node_table_offset);
        const char *name = c ? cases[c - 1].name : "unchanged";
        if (c)
            cases[c - 1].fn(&f);
        reseal(&f);
        CHECK(write_all(forged, img, size));
        rec_log log;
        hlod_logger lg = rec_logger(&log);
        hlod_store *s = NULL;
        hlod_result r = hlod_store_open(forged, &lg, &s);
        hlod_result want = c ? cases[c - 1].want : HLOD_OK;
        CHECKF(r == want, "%s: got %s, want %s (log '%s')", name, hlod_result_str(r),
               hlod_result_str(want), log.last);
        if (c) {
            CHECKF(s == NULL && strstr(log.last, cases[c - 1].msg) && strstr(log.last, forged),
                   "%s: log '%s' lacks '%s' or the file name", name, log.last, cases[c - 1].msg);
        }
        hlod_store_close(s);
    }

    /* Payloads that hash right but lie: caught when parsed. */
    struct {
        const char *name;
        int what;
        hlod_result want;
        const char *msg;
    } pcases[] = {
        {"index out of range", 0, HLOD_ERR_INDEX_RANGE, "index"},
        {"NaN position", 1, HLOD_ERR_NAN, "non-finite"},
        {"count disagrees", 2, HLOD_ERR_FORMAT, "disagree"},
        {"bad payload magic", 3, HLOD_ERR_FORMAT, "payload header"},
    };
    for (size_t c = 0; c < sizeof pcases / sizeof pcases[0]; c++) {
        memcpy(img, good, size);
        forge_ctx f = {(hlod_store_header *)img, NULL, img, size};
        f.t = (hlod_store_node *)(img + f.h->node_table_offset);
        uint32_t i = ts.store_index[A];
        uint8_t *pl = img + f.t[i].payload_offset;
        hlod_store_payload_header ph;
        memcpy(&ph, pl, sizeof ph);
        size_t idx_off = sizeof ph + 12 * (size_t)ph.vertex_count + 8 * (size_t)ph.vertex_count;
        if (pcases[c].what == 0) {
            uint32_t bad = ph.vertex_count;
            memcpy(pl + idx_off + 4 * 5, &bad, 4);
        } else if (pcases[c].what == 1) {
            float nan = NAN;
            memcpy(pl + sizeof ph + 4, &nan, 4);
        } else if (pcases[c].what == 2) {
            ph.tex_tri_count -= 1;
            memcpy(pl, &ph, sizeof ph);
        } else {
            pl[0] = 'X';
        }
        reseal_payload(&f, i);
        reseal(&f);
        CHECK(write_all(forged, img, size));
        rec_log log;
        hlod_logger lg = rec_logger(&log);
        hlod_store *s = NULL;
        CHECK(hlod_store_open(forged, &lg, &s) == HLOD_OK);
        if (!s)
            continue;
        hlod_store_payload p;
        hlod_result r = hlod_store_read_node(s, i, 65536, &p);
        CHECKF(r == pcases[c].want && p.memory == NULL && strstr(log.last, pcases[c].msg),
               "%s: got %s (log '%s')", pcases[c].name, hlod_result_str(r), log.last);
        hlod_store_payload_free(&p);
        hlod_store_close(s);
    }
out:
    free(good);
    free(img);
    free_meshes(&ts);
    clear_dir();
}

static void not_a_store(void)
{
    char path[1024];
    tmp_path("junk.hlod", path, sizeof path);
    uint8_t junk[4096];
    for (size_t i = 0; i < sizeof junk; i++)
        junk[i] = (uint8_t)(i * 131 + 7);
    CHECK(write_all(path, junk, sizeof junk));
    rec_log log;
    hlod_logger lg = rec_logger(&log);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, &lg, &s) == HLOD_ERR_FORMAT && !s);
    CHECK(strstr(log.last, "magic") != NULL);
    CHECK(hlod_store_open(g_dir, &lg, &s) == HLOD_ERR_IO && !s);
    tmp_path("missing.hlod", path, sizeof path);
    CHECK(hlod_store_open(path, &lg, &s) == HLOD_ERR_IO && !s);
    CHECK(strstr(log.last, "missing.hlod") != NULL);
    clear_dir();
}

/* ---------- writer failures ---------- */

static void abort_leaves_nothing(void)
{
    test_store ts;
    make_meshes(&ts);
    char path[1024];
    tmp_path("aborted.hlod", path, sizeof path);
    hlod_store_writer_desc desc = {0};
    desc.build = ts.build;
    hlod_store_writer *w = NULL;
    CHECK(hlod_store_writer_open(path, &desc, &w) == HLOD_OK);
    hlod_store_node n[2];
    CHECK(hlod_store_writer_add(w, &ts.mesh[R0].d, &n[0]) == HLOD_OK);
    CHECK(hlod_store_writer_add(w, &ts.mesh[A].d, &n[1]) == HLOD_OK);
    CHECK(dir_entries() == 1);  /* the temporary file */
    hlod_store_writer_abort(w);
    CHECK(dir_entries() == 0);

    /* An existing store survives an abort untouched. */
    CHECK(write_all(path, "old", 3));
    CHECK(hlod_store_writer_open(path, &desc, &w) == HLOD_OK);
    CHECK(hlod_store_writer_add(w, &ts.mesh[R0].d, &n[0]) == HLOD_OK);
    hlod_store_writer_abort(w);
    size_t size = 0;
    uint8_t *buf = (uint8_t *)check_slurp(path, &size);
    CHECK(buf && size == 3 && memcmp(buf, "old", 3) == 0);
    CHECK(dir_entries() == 1);
    free(buf);
    clear_dir();

    /* finish refusing a bad tree also leaves nothing */
    struct {
        const char *name;
        int what;
    } bad[] = {{"cycle", 0}, {"unused payload", 1}, {"error not monotone", 2},
               {"duplicate block", 3}, {"payload used twice", 4}, {"changed count", 5}};
    for (size_t c = 0; c < sizeof bad / sizeof bad[0]; c++) {
        rec_log log;
        hlod_logger lg = rec_logger(&log);
        desc.logger = &lg;
        CHECK(hlod_store_writer_open(path, &desc, &w) == HLOD_OK);
        hlod_store_node m[3];
        CHECK(hlod_store_writer_add(w, &ts.mesh[R0].d, &m[0]) == HLOD_OK);
        CHECK(hlod_store_writer_add(w, &ts.mesh[A].d, &m[1]) == HLOD_OK);
        CHECK(hlod_store_writer_add(w, &ts.mesh[B].d, &m[2]) == HLOD_OK);
        m[0].parent = HLOD_STORE_NO_PARENT;
        m[1].parent = 0;
        m[2].parent = 0;
        m[0].error = 1;
        uint32_t count = 3;
        switch (bad[c].what) {
        case 0: m[1].parent = 2; m[2].parent = 1; break;
        case 1: count = 2; break;
        case 2: m[2].error = 2; break;
        case 3: m[1].parent = HLOD_STORE_NO_PARENT; break;  /* two roots, both block 0 */
        case 4: m[2] = m[1]; m[2].parent = 0; break;
        case 5: m[2].vertex_count += 1; break;
        }
        hlod_result r = hlod_store_writer_finish(w, m, count, NULL);
        CHECKF(r != HLOD_OK && log.count > 0, "%s: %s", bad[c].name, hlod_result_str(r));
        CHECKF(dir_entries() == 0, "%s left a file", bad[c].name);
    }
    desc.logger = NULL;

    /* bad payloads are refused by add, naming the problem */
    rec_log log;
    hlod_logger lg = rec_logger(&log);
    desc.logger = &lg;
    CHECK(hlod_store_writer_open(path, &desc, &w) == HLOD_OK);
    hlod_store_payload_desc d = ts.mesh[R0].d;
    uint32_t idx[24];
    memcpy(idx, d.indices, sizeof idx);
    idx[4] = d.vertex_count;
    d.indices = idx;
    CHECK(hlod_store_writer_add(w, &d, &n[0]) == HLOD_ERR_INDEX_RANGE);
    d = ts.mesh[R0].d;
    d.uvs = NULL;
    CHECK(hlod_store_writer_add(w, &d, &n[0]) == HLOD_ERR_INVALID_ARG);
    d = ts.mesh[R0].d;
    d.origin[2] = NAN;
    CHECK(hlod_store_writer_add(w, &d, &n[0]) == HLOD_ERR_NAN);
    d = ts.mesh[D].d;
    d.tex_tri_count = 1;    /* textured triangles without a texture */
    CHECK(hlod_store_writer_add(w, &d, &n[0]) == HLOD_ERR_INVALID_ARG);
    hlod_store_writer_abort(w);
    CHECK(dir_entries() == 0);
    desc.payload_align = 1000;
    CHECK(hlod_store_writer_open(path, &desc, &w) == HLOD_ERR_INVALID_ARG && !w);
    free_meshes(&ts);
    clear_dir();
}

/* ---------- threads ---------- */

typedef struct add_job {
    hlod_store_writer *w;
    const test_store *ts;
    hlod_store_node *nodes;     /* NODES * copies */
    int first, step, copies;
    hlod_result r;
} add_job;

/* runs on a writer thread: adds every step-th payload */
static void *add_thread(void *arg)
{
    add_job *j = arg;
    j->r = HLOD_OK;
    for (int k = j->first; k < NODES * j->copies && j->r == HLOD_OK; k += j->step)
        j->r = hlod_store_writer_add(j->w, &j->ts->mesh[k % NODES].d, &j->nodes[k]);
    return NULL;
}

/* Four threads add payloads concurrently; the store reads back intact. */
static void concurrent_writer(void)
{
    enum { COPIES = 6, THREADS = 4, N = NODES * COPIES };
    test_store ts;
    make_meshes(&ts);
    char path[1024];
    tmp_path("mt.hlod", path, sizeof path);
    hlod_store_writer_desc desc = {0};
    desc.build = ts.build;
    desc.payload_align = 64;
    hlod_store_writer *w = NULL;
    CHECK(hlod_store_writer_open(path, &desc, &w) == HLOD_OK);
    static hlod_store_node nodes[N];
    add_job jobs[THREADS];
    pthread_t th[THREADS];
    for (int t = 0; t < THREADS; t++) {
        jobs[t] = (add_job){w, &ts, nodes, t, THREADS, COPIES, HLOD_OK};
        pthread_create(&th[t], NULL, add_thread, &jobs[t]);
    }
    for (int t = 0; t < THREADS; t++) {
        pthread_join(th[t], NULL);
        CHECK(jobs[t].r == HLOD_OK);
    }
    /* COPIES copies of the tree: copy c's block b is root c*2 + b */
    for (int k = 0; k < N; k++) {
        int i = k % NODES, c = k / NODES;
        nodes[k].parent = PARENT[i] == HLOD_STORE_NO_PARENT ? PARENT[i]
                                                             : (uint32_t)(c * NODES) + PARENT[i];
        nodes[k].block = (uint32_t)(2 * c + (i == R1));
        nodes[k].error = ERROR[i];
    }
    uint32_t idx[N];
    CHECK(hlod_store_writer_finish(w, nodes, N, idx) == HLOD_OK);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (s) {
        CHECK(hlod_store_root_count(s) == 2 * COPIES);
        for (int k = 0; k < N; k++) {
            hlod_store_payload p;
            CHECK(hlod_store_read_node(s, idx[k], 65536, &p) == HLOD_OK);
            if (p.memory)
                compare_payload(&ts.mesh[k % NODES], &p);
            hlod_store_payload_free(&p);
        }
    }
    hlod_store_close(s);
    free_meshes(&ts);
    clear_dir();
}

typedef struct read_job {
    const hlod_store *shared;   /* NULL: open our own */
    const char *path;
    uint64_t sums[NODES];       /* hash of each node's decoded memory */
    int rounds, reverse;
    size_t step;
    int errors;
} read_job;

/* runs on a reader thread */
static void *read_thread(void *arg)
{
    read_job *j = arg;
    hlod_store *own = NULL;
    const hlod_store *s = j->shared;
    if (!s) {
        if (hlod_store_open(j->path, NULL, &own) != HLOD_OK) {
            j->errors++;
            return NULL;
        }
        s = own;
    }
    for (int round = 0; round < j->rounds; round++)
        for (uint32_t k = 0; k < NODES; k++) {
            uint32_t i = j->reverse ? NODES - 1 - k : k;
            hlod_store_payload p;
            if (hlod_store_read_node(s, i, j->step, &p) != HLOD_OK) {
                j->errors++;
                continue;
            }
            uint64_t h = hlod_store_hash(p.memory, p.bytes);
            if (round == 0)
                j->sums[i] = h;
            else if (j->sums[i] != h)
                j->errors++;
            hlod_store_payload_free(&p);
        }
    hlod_store_close(own);
    return NULL;
}

/* Two readers with their own stores and two sharing one, on one file,
 * read identical payloads. */
static void concurrent_readers(void)
{
    test_store ts;
    char path[1024];
    CHECK(good_store(&ts, "readers.hlod", path, sizeof path) == HLOD_OK);
    hlod_store *shared = NULL;
    CHECK(hlod_store_open(path, NULL, &shared) == HLOD_OK);
    if (!shared)
        goto out;
    read_job jobs[4];
    memset(jobs, 0, sizeof jobs);
    for (int t = 0; t < 4; t++) {
        jobs[t].shared = t < 2 ? NULL : shared;
        jobs[t].path = path;
        jobs[t].rounds = 40;
        jobs[t].reverse = t & 1;
        jobs[t].step = t & 1 ? 4096 : 100;
    }
    pthread_t th[4];
    for (int t = 0; t < 4; t++)
        pthread_create(&th[t], NULL, read_thread, &jobs[t]);
    for (int t = 0; t < 4; t++)
        pthread_join(th[t], NULL);
    for (int t = 0; t < 4; t++) {
        CHECK(jobs[t].errors == 0);
        CHECK(memcmp(jobs[t].sums, jobs[0].sums, sizeof jobs[0].sums) == 0);
    }
    for (uint32_t i = 0; i < NODES; i++)
        CHECK(jobs[0].sums[i] == hlod_store_nodes(shared)[i].payload_hash);
out:
    hlod_store_close(shared);
    free_meshes(&ts);
    clear_dir();
}

/* ---------- hlod-info ---------- */

/* Runs bin/hlod-info ARGS; stdout and stderr go to files; returns the exit
 * status or -1.  Skipped (returns -2) when HLOD_BIN_DIR is unset. */
static int run_info(const char *args, char *out, size_t n_out, char *err, size_t n_err)
{
    const char *bin = getenv("HLOD_BIN_DIR");
    if (!bin)
        return -2;
    char cmd[4096], o[1024], e[1024];
    tmp_path("info.out", o, sizeof o);
    tmp_path("info.err", e, sizeof e);
    snprintf(cmd, sizeof cmd, "'%s/hlod-info' %s >'%s' 2>'%s' </dev/null", bin, args, o, e);
    int st = system(cmd);
    size_t size = 0;
    uint8_t *b = (uint8_t *)check_slurp(o, &size);
    snprintf(out, n_out, "%.*s", b ? (int)size : 0, b ? (const char *)b : "");
    free(b);
    b = (uint8_t *)check_slurp(e, &size);
    snprintf(err, n_err, "%.*s", b ? (int)size : 0, b ? (const char *)b : "");
    free(b);
    unlink(o);
    unlink(e);
    return st != -1 && WIFEXITED(st) ? WEXITSTATUS(st) : -1;
}

static void info_tool(void)
{
    test_store ts;
    char path[1024], args[2048];
    static char out[16384], err[16384];
    CHECK(good_store(&ts, "info.hlod", path, sizeof path) == HLOD_OK);
    snprintf(args, sizeof args, "'%s' --verify --json", path);
    int rc = run_info(args, out, sizeof out, err, sizeof err);
    if (rc == -2) {
        CHECK_SKIP("hlod-info checks: HLOD_BIN_DIR not set");
        goto out;
    }
    CHECKF(rc == 0, "rc %d, stderr: %s", rc, err);
    const char *keys[] = {"\"nodes\":9,", "\"blocks\":2,", "\"depths\":3,",
                          "\"nodes_per_depth\":[2,5,2]", "\"tris_per_depth\":[10,50,52]",
                          "\"bytes\":", "\"texture_bytes\":246,", "\"payload_bytes\":",
                          "\"error_min\":0,", "\"error_max\":3,", "\"verified\":true",
                          "\"method\":\"cutplane\"", "\"c_tex\":0.59999999999999998"};
    for (size_t k = 0; k < sizeof keys / sizeof keys[0]; k++)
        CHECKF(strstr(out, keys[k]) != NULL, "'%s' not in %s", keys[k], out);

    snprintf(args, sizeof args, "'%s'", path);
    CHECK(run_info(args, out, sizeof out, err, sizeof err) == 0);
    CHECKF(strstr(out, "blocks 2 at depth 0 (0 group nodes above, 2 roots), nodes 9") != NULL, "%s", out);

    /* a corrupt payload: open still works, --verify names the node */
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    uint32_t i = ts.store_index[A2];
    if (s)
        flip_bit(path, hlod_store_nodes(s)[i].payload_offset + 77, 2);
    hlod_store_close(s);
    CHECK(run_info(args, out, sizeof out, err, sizeof err) == 0);
    snprintf(args, sizeof args, "'%s' --verify", path);
    rc = run_info(args, out, sizeof out, err, sizeof err);
    char want[64];
    snprintf(want, sizeof want, "node %u: payload checksum mismatch", i);
    CHECKF(rc == 1 && strstr(err, want) && strstr(err, "1 of 9"), "rc %d, stderr: %s", rc, err);

    /* a broken table: open fails, exit 1 */
    CHECK(truncate(path, 5000) == 0);
    snprintf(args, sizeof args, "'%s' --json", path);
    rc = run_info(args, out, sizeof out, err, sizeof err);
    CHECKF(rc == 1 && strstr(err, "truncated") && out[0] == 0, "rc %d, stderr: %s", rc, err);
    /* usage errors */
    CHECK(run_info("--frobnicate", out, sizeof out, err, sizeof err) == 2);
    CHECK(run_info("", out, sizeof out, err, sizeof err) == 2);
    CHECK(run_info("--help", out, sizeof out, err, sizeof err) == 0 && strstr(out, "usage"));
out:
    free_meshes(&ts);
    clear_dir();
}

int main(void)
{
    const char *tmp = getenv("TMPDIR");
    snprintf(g_dir, sizeof g_dir, "%s/hlod-test-store.XXXXXX", tmp && *tmp ? tmp : "/tmp");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(round_trip);
    RUN(incremental_interleaved);
    RUN(every_truncation);
    RUN(bit_flips);
    RUN(forged_tables);
    RUN(not_a_store);
    RUN(abort_leaves_nothing);
    RUN(concurrent_writer);
    RUN(concurrent_readers);
    RUN(info_tool);
    clear_dir();
    rmdir(g_dir);
    return check_done();
}
