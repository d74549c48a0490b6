/*
 * test_store_codec.c - store format 3's packed payloads (docs/store-format.md;
 * engine/common/payload_codec.c): what a packed store gives back is
 * the raw store's data within each codec's stated error, the same grid point
 * in every node that shares a vertex, and a forged or damaged packed payload
 * is refused (never read past its buffers); version 2 stores are still read
 * and version 1 stores are refused with a message that says to rebuild.
 */
#include "check.h"
#include "hlod/store_write.h"
#include "payload_codec.h"

#include <math.h>
#include <stdint.h>
#include <unistd.h>

static char g_dir[256];
static char g_log[4096];

static void log_fn(void *user, hlod_log_level level, const char *msg)
{
    (void)user;
    (void)level;
    snprintf(g_log, sizeof g_log, "%s", msg);
}
static const hlod_logger LG = {log_fn, NULL};

/* A wavy textured grid: nx x ny quads over [x0, x0 + s*nx] x [y0, ...]; the
 * first half of the triangles textured.  Coordinates are world ones. */
typedef struct grid_mesh {
    uint32_t v, t;
    double pos[3 * 441];
    float nrm[3 * 441], uv[2 * 441];
    uint8_t col[4 * 441];
    uint32_t idx[3 * 800];
    uint8_t tex[64 * 32 * 3];
} grid_mesh;

static void make_grid(grid_mesh *m, double x0, double y0, double s, double base)
{
    const int n = 20;
    m->v = 0;
    for (int j = 0; j <= n; j++)
        for (int i = 0; i <= n; i++) {
            uint32_t k = m->v++;
            double x = x0 + s * i, y = y0 + s * j;
            m->pos[3 * k] = x;
            m->pos[3 * k + 1] = y;
            /* a function of the position, so neighbours share their edge */
            m->pos[3 * k + 2] = 0.3 * sin(0.7 * (x - base)) * cos(0.4 * (y - base));
            float nx = (float)sin(0.3 * i), ny = (float)cos(0.2 * j), nz = -0.7f + 0.1f * (float)i;
            float len = sqrtf(nx * nx + ny * ny + nz * nz);
            m->nrm[3 * k] = nx / len;
            m->nrm[3 * k + 1] = ny / len;
            m->nrm[3 * k + 2] = nz / len;
            m->uv[2 * k] = -1.5f + 3.0f * (float)i / n;   /* repeats: outside [0, 1] */
            m->uv[2 * k + 1] = (float)j / n;
            for (int c = 0; c < 4; c++)
                m->col[4 * k + c] = (uint8_t)(37 * i + 11 * j + 50 * c);
        }
    m->t = 0;
    for (int j = 0; j < n; j++)
        for (int i = 0; i < n; i++) {
            uint32_t a = (uint32_t)(j * (n + 1) + i), b = a + 1, c = a + (uint32_t)n + 1, d = c + 1;
            uint32_t *t = m->idx + 3 * m->t;
            t[0] = a, t[1] = b, t[2] = d, t[3] = a, t[4] = d, t[5] = c;
            m->t += 2;
        }
    for (int y = 0; y < 32; y++)
        for (int x = 0; x < 64; x++)
            for (int c = 0; c < 3; c++)   /* smooth, so JPEG's error is small */
                m->tex[(y * 64 + x) * 3 + c] = (uint8_t)(128 + 100 * sin(0.1 * x + 0.2 * y + c));
}

static hlod_store_payload_desc desc_of(const grid_mesh *m, int textured, int colored)
{
    hlod_store_payload_desc d;
    memset(&d, 0, sizeof d);
    d.vertex_count = m->v;
    d.positions = m->pos;
    d.origin[0] = m->pos[0] + 3.3;     /* not on any grid */
    d.origin[1] = m->pos[1] + 1.7;
    d.origin[2] = 0.01;
    d.normals = m->nrm;
    d.tri_count = m->t;
    d.indices = m->idx;
    if (textured) {
        d.uvs = m->uv;
        d.tex_tri_count = m->t / 2;
        d.tex_width = 64;
        d.tex_height = 32;
        d.tex_channels = 3;
        d.pixels = m->tex;
    }
    if (colored)
        d.colors = m->col;
    return d;
}

/* Writes one store of two neighbouring grids (sharing the column x = x1)
 * at base; packed when step > 0.  Returns the path in buf. */
static hlod_result write_pair(const char *name, double base, double step, uint32_t quality,
                              grid_mesh *a, grid_mesh *b, char *buf, size_t n)
{
    snprintf(buf, n, "%s/%s", g_dir, name);
    make_grid(a, base, base, 0.5, base);
    make_grid(b, base + 10.0, base, 0.5, base);
    hlod_store_writer_desc wd;
    memset(&wd, 0, sizeof wd);
    wd.build.method = HLOD_STORE_METHOD_OTHER;
    wd.build.c_tex = 0.5;
    wd.payload_align = 64;
    wd.logger = &LG;
    wd.quant_step = step;
    wd.quant_origin[0] = base - 1.25;
    wd.quant_origin[1] = base - 0.75;
    wd.quant_origin[2] = -0.5;
    wd.jpeg_quality = quality;
    hlod_store_writer *w;
    hlod_result r = hlod_store_writer_open(buf, &wd, &w);
    if (r != HLOD_OK)
        return r;
    hlod_store_node nodes[2];
    hlod_store_payload_desc da = desc_of(a, 1, 0), db = desc_of(b, 0, 1);
    if ((r = hlod_store_writer_add(w, &da, &nodes[0])) != HLOD_OK ||
        (r = hlod_store_writer_add(w, &db, &nodes[1])) != HLOD_OK) {
        hlod_store_writer_abort(w);
        return r;
    }
    for (int i = 0; i < 2; i++) {
        nodes[i].parent = HLOD_STORE_NO_PARENT;
        nodes[i].block = (uint32_t)i;
        nodes[i].error = 0;
    }
    return hlod_store_writer_finish(w, nodes, 2, NULL);
}

/* World position of vertex i of payload p in store s. */
static void world(const hlod_store *s, const hlod_store_payload *p, uint32_t i, double out[3])
{
    const hlod_store_node *n = &hlod_store_nodes(s)[p->node];
    for (int k = 0; k < 3; k++)
        out[k] = n->origin[k] + (double)p->positions[3 * i + k];
}

/* The triangle of p nearest (by centroid) to the source triangle t of m:
 * packed payloads reorder triangles and vertices, so data is compared
 * through positions.  Returns the vertex of that triangle nearest to m's
 * vertex v, and its distance. */
static uint32_t match_vertex(const hlod_store *s, const hlod_store_payload *p, const double q[3],
                             double *dist)
{
    uint32_t best = 0;
    double bd = INFINITY;
    for (uint32_t i = 0; i < p->vertex_count; i++) {
        double w[3];
        world(s, p, i, w);
        double d = fabs(w[0] - q[0]) + fabs(w[1] - q[1]) + fabs(w[2] - q[2]);
        if (d < bd)
            bd = d, best = i;
    }
    *dist = bd;
    return best;
}

/* The angle between two directions (atan2 of |a x b| and a . b: exact near
 * 0, where acos of a float dot product is not). */
static double angle(const float *a, const float *b)
{
    double c[3] = {(double)a[1] * b[2] - (double)a[2] * b[1], (double)a[2] * b[0] - (double)a[0] * b[2],
                   (double)a[0] * b[1] - (double)a[1] * b[0]};
    double dot = (double)a[0] * b[0] + (double)a[1] * b[1] + (double)a[2] * b[2];
    return atan2(sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]), dot);
}

static double image_psnr(const uint8_t *a, const uint8_t *b, size_t n)
{
    double se = 0;
    for (size_t i = 0; i < n; i++)
        se += ((double)a[i] - b[i]) * ((double)a[i] - b[i]);
    return se == 0 ? 99 : 10 * log10(255.0 * 255.0 * (double)n / se);
}

/* Every vertex, normal, UV, colour and the texture come back within the
 * codec's error; triangle ranges (textured first) and the grid sharing. */
static void round_trip_within_error(void)
{
    static grid_mesh a, b;
    char path[512];
    const double step = 1.0 / 1024;
    for (int far = 0; far < 2; far++) {
        double base = far ? 5e6 : 0;   /* a city at projected coordinates */
        CHECK(write_pair("packed.hlod", base, step, 90, &a, &b, path, sizeof path) == HLOD_OK);
        hlod_store *s = NULL;
        CHECK(hlod_store_open(path, &LG, &s) == HLOD_OK);
        if (!s)
            return;
        const hlod_store_header *h = hlod_store_get_header(s);
        CHECK(h->version == HLOD_STORE_VERSION && h->payload_codec == HLOD_STORE_CODEC_PACKED &&
              h->quant_step == step);
        hlod_store_payload pa, pb;
        CHECK(hlod_store_read_node(s, 0, 64, &pa) == HLOD_OK);
        CHECK(hlod_store_read_node(s, 1, 64, &pb) == HLOD_OK);
        const hlod_store_node *nd = hlod_store_nodes(s);
        CHECK(pa.bytes == hlod_store_node_memory(&nd[0]) && nd[0].payload_size < pa.bytes);
        CHECK(pa.vertex_count == a.v && pa.index_count == 3 * a.t && pa.tex_tri_count == a.t / 2);
        /* the origin lies on the grid */
        for (int k = 0; k < 3; k++) {
            double g = (nd[0].origin[k] - h->quant_origin[k]) / step;
            CHECK(g == rint(g));
        }
        double worst = 0, worst_n = 0, worst_uv = 0;
        int col_ok = 1;
        for (uint32_t v = 0; v < a.v; v++) {
            double d;
            uint32_t i = match_vertex(s, &pa, a.pos + 3 * v, &d);
            worst = fmax(worst, d);
            worst_n = fmax(worst_n, angle(pa.normals + 3 * i, a.nrm + 3 * v));
            for (int k = 0; k < 2; k++)
                worst_uv = fmax(worst_uv, fabs((double)pa.uvs[2 * i + k] - a.uv[2 * v + k]));
        }
        for (uint32_t v = 0; v < b.v; v++) {
            double d;
            uint32_t i = match_vertex(s, &pb, b.pos + 3 * v, &d);
            worst = fmax(worst, d);
            col_ok &= memcmp(pb.colors + 4 * i, b.col + 4 * v, 4) == 0;
        }
        /* positions: half a step per axis (L1 over 3 axes) plus float
         * rounding of the node-relative offset */
        CHECKF(worst <= 1.5 * step + 1e-5, "worst position error %g (step %g)", worst, step);
        CHECKF(worst_n < 1e-4, "worst normal error %g rad", worst_n);
        CHECKF(worst_uv <= 3.0 / 65535 + 1e-6, "worst UV error %g", worst_uv);
        CHECK(col_ok);
        CHECK(pb.uvs == NULL && pb.pixels == NULL && pa.colors == NULL);
        double psnr = image_psnr(pa.pixels, a.tex, sizeof a.tex);
        CHECKF(psnr >= 40, "texture PSNR %.1f dB", psnr);
        /* the textured range holds exactly the source's textured triangles:
         * every triangle of the first range has its centroid in the first
         * half of the grid (rows j < 10) */
        int ranges_ok = 1;
        for (uint32_t t = 0; t < pa.index_count / 3; t++) {
            double cy = 0;
            for (int c = 0; c < 3; c++) {
                double w[3];
                world(s, &pa, pa.indices[3 * t + c], w);
                cy += w[1] / 3;
            }
            ranges_ok &= (t < pa.tex_tri_count) == (cy - base < 5.0);
        }
        CHECK(ranges_ok);
        /* the shared column x = base + 10: both nodes put it on one grid point */
        int shared = 0, same = 1;
        for (uint32_t i = 0; i < pa.vertex_count; i++) {
            double wa[3];
            world(s, &pa, i, wa);
            if (fabs(wa[0] - (base + 10)) > 0.25)
                continue;
            double d;
            uint32_t j = match_vertex(s, &pb, wa, &d);
            double wb[3];
            world(s, &pb, j, wb);
            for (int k = 0; k < 3; k++)
                same &= rint((wa[k] - h->quant_origin[k]) / step) ==
                        rint((wb[k] - h->quant_origin[k]) / step);
            shared++;
        }
        CHECKF(shared == 21 && same, "%d shared vertices, same grid point %d", shared, same);
        hlod_store_payload_free(&pa);
        hlod_store_payload_free(&pb);
        hlod_store_close(s);
    }
}

/* A city at 5e6 packs to the same payload bytes as at the origin when the
 * grid moves with it by whole steps. */
static void far_city_same_bytes(void)
{
    static grid_mesh a, b;
    char p0[512], p1[512];
    CHECK(write_pair("near.hlod", 0, 1.0 / 256, 90, &a, &b, p0, sizeof p0) == HLOD_OK);
    CHECK(write_pair("far.hlod", 4194304.0, 1.0 / 256, 90, &a, &b, p1, sizeof p1) == HLOD_OK);
    hlod_store *s0 = NULL, *s1 = NULL;
    CHECK(hlod_store_open(p0, &LG, &s0) == HLOD_OK && hlod_store_open(p1, &LG, &s1) == HLOD_OK);
    if (!s0 || !s1)
        return;
    for (uint32_t i = 0; i < 2; i++) {
        const hlod_store_node *n0 = &hlod_store_nodes(s0)[i], *n1 = &hlod_store_nodes(s1)[i];
        CHECK(n0->payload_hash == n1->payload_hash && n0->payload_size == n1->payload_size);
    }
    hlod_store_close(s0);
    hlod_store_close(s1);
}

/* Reads node `node` of the store at path after `mutate` changed its packed
 * payload and the checksums were made right again: the reader must refuse
 * it (not crash), naming the node. */
typedef void (*mutate_fn)(uint8_t *payload, size_t size);

/* 2^31 vertices claimed by a payload of a few KB: the reader must refuse it
 * before allocating their 48 GiB (node table forged to agree). */
static void m_huge(uint8_t *p, size_t n)
{
    (void)n;
    uint32_t v = 1u << 31;
    memcpy(p + 8, &v, 4);
}

static hlod_result read_forged(const char *path, uint32_t node, mutate_fn mutate)
{
    FILE *fp = fopen(path, "rb");
    if (!fp)
        return HLOD_ERR_IO;
    fseek(fp, 0, SEEK_END);
    long size = ftell(fp);
    fseek(fp, 0, SEEK_SET);
    uint8_t *file = malloc((size_t)size);
    if (!file || fread(file, 1, (size_t)size, fp) != (size_t)size)
        abort();
    fclose(fp);
    hlod_store_header *h = (hlod_store_header *)file;
    hlod_store_node *t = (hlod_store_node *)(file + h->node_table_offset);
    mutate(file + t[node].payload_offset, t[node].payload_size);
    if (mutate == m_huge)   /* the table agrees with the forged counts */
        t[node].vertex_count = 1u << 31;
    t[node].payload_hash = hlod_store_hash(file + t[node].payload_offset, t[node].payload_size);
    h->node_table_hash = hlod_store_hash(t, h->node_table_size);
    h->header_hash = hlod_store_hash(h, HLOD_STORE_HEADER_HASHED);
    char forged[600];
    snprintf(forged, sizeof forged, "%s.forged", path);
    fp = fopen(forged, "wb");
    fwrite(file, 1, (size_t)size, fp);
    fclose(fp);
    free(file);
    hlod_store *s = NULL;
    hlod_result r = hlod_store_open(forged, &LG, &s);
    if (r == HLOD_OK) {
        hlod_store_payload p;
        r = hlod_store_read_node(s, node, 4096, &p);
        hlod_store_payload_free(&p);
        hlod_store_close(s);
    }
    unlink(forged);
    return r;
}

static void m_magic(uint8_t *p, size_t n) { (void)n; p[0] ^= 1; }
static void m_count(uint8_t *p, size_t n) { (void)n; p[8] ^= 1; }   /* vertex_count */
static void m_section(uint8_t *p, size_t n)
{
    (void)n;
    hlod_store_packed_header ph;
    memcpy(&ph, p, sizeof ph);
    ph.section_bytes[HLOD_SEC_POSITIONS] += 4;
    ph.section_bytes[HLOD_SEC_INDICES] -= 4;
    memcpy(p, &ph, sizeof ph);
}
static void m_positions(uint8_t *p, size_t n) { (void)n; p[128] = 0xff; p[129] ^= 0x5a; }
static void m_indices(uint8_t *p, size_t n)
{
    hlod_store_packed_header ph;
    memcpy(&ph, p, sizeof ph);
    size_t at = 128;
    for (int k = 0; k < HLOD_SEC_INDICES; k++)
        at += ph.section_bytes[k];
    for (size_t i = at; i < at + ph.section_bytes[HLOD_SEC_INDICES] && i < n; i += 3)
        p[i] ^= 0xa5;
}
static void m_jpeg(uint8_t *p, size_t n)
{
    hlod_store_packed_header ph;
    memcpy(&ph, p, sizeof ph);
    size_t at = n - ph.section_bytes[HLOD_SEC_TEXTURE];
    for (size_t i = at + 2; i < n; i += 7)
        p[i] = (uint8_t)(p[i] * 31 + 7);
}
static void m_uv_nan(uint8_t *p, size_t n)
{
    (void)n;
    float nan = NAN;
    memcpy(p + 56, &nan, 4);
}

static void forged_payloads_refused(void)
{
    static grid_mesh a, b;
    char path[512];
    CHECK(write_pair("forge.hlod", 0, 1.0 / 1024, 90, &a, &b, path, sizeof path) == HLOD_OK);
    struct { mutate_fn fn; uint32_t node; const char *what; } cases[] = {
        {m_magic, 0, "bad packed payload header"},
        {m_count, 1, "disagree with the node table"},
        {m_section, 0, "bad position stream"},
        {m_positions, 0, "bad position stream"},
        {m_indices, 1, "index"},
        {m_jpeg, 0, "JPEG"},
        {m_uv_nan, 0, "non-finite UV range"},
        {m_huge, 1, "cannot come from streams this short"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        g_log[0] = 0;
        hlod_result r = read_forged(path, cases[i].node, cases[i].fn);
        CHECKF(r != HLOD_OK && strstr(g_log, cases[i].what) && strstr(g_log, "node"),
               "case %zu: result %d, log '%s'", i, (int)r, g_log);
    }
}

/* Rewrites the header's version (and its checksum); below version 4, the
 * extras table is cut off the file. */
static void set_version(const char *path, uint32_t version)
{
    FILE *fp = fopen(path, "r+b");
    hlod_store_header h;
    if (!fp || fread(&h, sizeof h, 1, fp) != 1)
        abort();
    h.version = version;
    if (version < 4 && h.extras_offset) {
        h.file_size = h.extras_offset;
        h.extras_offset = 0;
        h.extras_size = 0;
        if (ftruncate(fileno(fp), (off_t)h.file_size) != 0)
            abort();
    }
    h.header_hash = hlod_store_hash(&h, HLOD_STORE_HEADER_HASHED);
    fseek(fp, 0, SEEK_SET);
    fwrite(&h, sizeof h, 1, fp);
    fclose(fp);
}

/* A raw store without its extras table is byte for byte a version 2 store
 * but for the version: read as version 2, exactly, with no extras (no
 * normal cones); version 1 is refused with "rebuild". */
static void versions(void)
{
    static grid_mesh a, b;
    char path[512];
    CHECK(write_pair("raw.hlod", 0, 0, 0, &a, &b, path, sizeof path) == HLOD_OK);
    set_version(path, 2);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, &LG, &s) == HLOD_OK);
    if (s) {
        CHECK(hlod_store_extras(s) == NULL);
        hlod_store_payload p;
        CHECK(hlod_store_read_node(s, 0, 64, &p) == HLOD_OK);
        CHECK(p.vertex_count == a.v && p.uvs && memcmp(p.pixels, a.tex, sizeof a.tex) == 0 &&
              memcmp(p.uvs, a.uv, 8 * a.v) == 0);
        int exact = 1;
        for (uint32_t i = 0; i < 3 * a.v; i++)
            exact &= p.positions[i] == (float)(a.pos[i] - hlod_store_nodes(s)[0].origin[i % 3]);
        CHECK(exact);
        hlod_store_payload_free(&p);
        hlod_store_close(s);
    }
    set_version(path, 1);
    g_log[0] = 0;
    CHECK(hlod_store_open(path, &LG, &s) == HLOD_ERR_VERSION && s == NULL);
    CHECKF(strstr(g_log, "version 1") && strstr(g_log, "rebuild"), "log: %s", g_log);
}

/* Octahedral normals: every direction within 1e-4 rad, the poles exact. */
static void oct(void)
{
    double worst = 0;
    for (int i = 0; i < 2000; i++) {
        double th = acos(1 - 2 * (i + 0.5) / 2000), ph = 2.399963 * i;
        float n[3] = {(float)(sin(th) * cos(ph)), (float)(sin(th) * sin(ph)), (float)cos(th)};
        int16_t e[2];
        float d[3];
        hlod_oct_encode(n, e);
        hlod_oct_decode(e, d);
        worst = fmax(worst, angle(n, d));
    }
    CHECKF(worst < 1e-4, "worst %g rad", worst);
    float down[3] = {0, 0, -1}, d[3];
    int16_t e[2];
    hlod_oct_encode(down, e);
    hlod_oct_decode(e, d);
    CHECK(d[0] == 0 && d[1] == 0 && d[2] == -1);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod_test_codec_XXXXXX");
    if (!mkdtemp(g_dir))
        return 1;
    RUN(oct);
    RUN(round_trip_within_error);
    RUN(far_city_same_bytes);
    RUN(forged_payloads_refused);
    RUN(versions);
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    if (system(cmd) != 0)
        return 1;
    return check_done();
}
