/*
 * test_tiles.c - 3D Tiles out and back in (preprocess/tiles3d.h,
 * preprocess/io/tiles_read.c; docs/3d-tiles.md).
 *
 * The small city (hlod-gen-city --preset small, hlod-build --desired-tris
 * 450) is built at the origin and at (6e6, 6e6, 300) m, then:
 *   - tileset_mirrors_store: hlod_tiles_export's tileset.json has one tile
 *     per node, each content tiles/N.glb, geometricError = node N's error
 *     exactly, refine REPLACE, and the tile transforms composed down the
 *     tree give node N's origin within 1e-9 of its magnitude;
 *   - leaves_come_back: hlod_mesh_import of the tileset (degenerates kept,
 *     so nothing is reordered) gives each leaf node's triangles, corner
 *     for corner (meshopt's index codec may rotate a triangle), within the
 *     export's position tolerance, max(grid step, 1e-6 x the diagonal);
 *     and the far city's largest deviation equals the origin city's within
 *     1e-6 m: a city at 6e6 m comes back exactly as at the origin;
 *   - never_plain: --meshopt never writes no EXT_meshopt_compression and
 *     comes back the same;
 *   - refuses_and_replaces: an existing folder is refused without force
 *     (its file untouched) and replaced with it; a store with a corrupt
 *     payload fails with HLOD_ERR_CHECKSUM, leaving no folder and no
 *     temporary one;
 *   - bad_tilesets: a missing leaf glb, a truncated glb, a b3dm content, a
 *     tileset without root, and 300 glbs with random bytes flipped each
 *     give an error or a valid mesh, never a crash (the sanitizer build
 *     runs this too).
 */
#define _GNU_SOURCE 1 /* memmem */
#include "check.h"
#include "hlod/mesh_io.h"
#include "hlod/store.h"
#include "tiles3d.h"

#include <cjson/cJSON.h>
#include <dirent.h>
#include <math.h>
#include <stdint.h>
#include <sys/stat.h>
#include <unistd.h>

#define CITIES 2
static const double g_origins[CITIES][3] = {{0, 0, 0}, {6e6, 6e6, 300}};
static char g_bin[1024], g_dir[1024];
static char g_store[CITIES][1200];
static double g_worst[CITIES];

static int exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

static char *slurp(const char *path, size_t *n)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long len = ftell(f);
    rewind(f);
    char *b = malloc((size_t)len + 1);
    if (b && fread(b, 1, (size_t)len, f) != (size_t)len) {
        free(b);
        b = NULL;
    }
    fclose(f);
    if (b) {
        b[len] = 0;
        *n = (size_t)len;
    }
    return b;
}

static hlod_result export_to(const hlod_store *s, const char *dir, int meshopt, int force)
{
    hlod_tiles_export_desc d = {0};
    d.meshopt = meshopt;
    d.jpeg_quality = 90;
    d.threads = 2;
    d.force = force;
    return hlod_tiles_export(s, dir, &d, NULL);
}

/* ---- tileset_mirrors_store ---- */

static int walk(const cJSON *t, const hlod_store_node *nodes, const double parent[3], int *tiles,
                int *bad)
{
    double at[3] = {parent[0], parent[1], parent[2]};
    const cJSON *tr = cJSON_GetObjectItem(t, "transform");
    if (tr)
        for (int k = 0; k < 3; k++)
            at[k] += cJSON_GetArrayItem(tr, 12 + k)->valuedouble;
    const cJSON *uri = cJSON_GetObjectItem(cJSON_GetObjectItem(t, "content"), "uri");
    const cJSON *ref = cJSON_GetObjectItem(t, "refine");
    (*tiles)++;
    if (!cJSON_IsString(ref) || strcmp(ref->valuestring, "REPLACE") != 0)
        (*bad)++;
    if (cJSON_IsString(uri)) {
        unsigned n;
        if (sscanf(uri->valuestring, "tiles/%u.glb", &n) != 1) {
            (*bad)++;
        } else {
            const hlod_store_node *x = &nodes[n];
            if (cJSON_GetObjectItem(t, "geometricError")->valuedouble != x->error) {
                fprintf(stderr, "  node %u: geometricError %.17g, error %.17g\n", n,
                        cJSON_GetObjectItem(t, "geometricError")->valuedouble, x->error);
                (*bad)++;
            }
            for (int k = 0; k < 3; k++)
                if (fabs(at[k] - x->origin[k]) > 1e-9 * (fabs(x->origin[k]) + 1)) {
                    fprintf(stderr, "  node %u: origin %.17g composed as %.17g\n", n, x->origin[k],
                            at[k]);
                    (*bad)++;
                }
        }
    }
    const cJSON *c;
    cJSON_ArrayForEach(c, cJSON_GetObjectItem(t, "children"))
        walk(c, nodes, at, tiles, bad);
    return 1;
}

static void tileset_mirrors_store(void)
{
    for (int c = 0; c < CITIES; c++) {
        hlod_store *s = NULL;
        CHECK(hlod_store_open(g_store[c], NULL, &s) == HLOD_OK);
        if (!s)
            return;
        char dir[1400], ts[1500];
        snprintf(dir, sizeof dir, "%s/tiles-%d", g_dir, c);
        CHECK(export_to(s, dir, HLOD_MESHOPT_AUTO, 1) == HLOD_OK);
        snprintf(ts, sizeof ts, "%s/tileset.json", dir);
        size_t n = 0;
        char *text = slurp(ts, &n);
        cJSON *j = text ? cJSON_Parse(text) : NULL;
        CHECK(j != NULL);
        if (j) {
            CHECK(!strcmp(cJSON_GetObjectItem(cJSON_GetObjectItem(j, "asset"), "version")->valuestring,
                          "1.1"));
            int tiles = 0, bad = 0;
            double zero[3] = {0, 0, 0};
            walk(cJSON_GetObjectItem(j, "root"), hlod_store_nodes(s), zero, &tiles, &bad);
            uint32_t want = hlod_store_node_count(s) + (hlod_store_root_count(s) > 1);
            CHECKF(tiles == (int)want && bad == 0, "city %d: %d tiles (want %u), %d bad", c, tiles,
                   want, bad);
        }
        cJSON_Delete(j);
        free(text);
        hlod_store_close(s);
    }
}

/* ---- leaves_come_back ---- */

/* Largest distance between the store's leaf triangles and the imported
 * mesh's (leaves in the tileset's depth-first order); -1 on a mismatch. */
static double leaf_deviation(const hlod_store *s, const hlod_mesh *m)
{
    const hlod_store_node *nodes = hlod_store_nodes(s);
    uint32_t count = hlod_store_node_count(s);
    /* depth-first leaf order, as the tileset lists them */
    uint32_t *stack = malloc(count * sizeof *stack), sp = 0, obj = 0;
    double worst = 0;
    for (uint32_t r = hlod_store_root_count(s); r-- > 0;)
        stack[sp++] = r;
    while (sp && worst >= 0) {
        uint32_t i = stack[--sp];
        uint32_t c0 = hlod_store_first_child(nodes, i), c1 = hlod_store_child_end(nodes, i);
        if (c1 > c0) {
            for (uint32_t c = c1; c-- > c0;)
                stack[sp++] = c;
            continue;
        }
        hlod_store_payload p;
        if (hlod_store_read_node(s, i, 1u << 20, &p) != HLOD_OK || obj >= m->object_count ||
            m->objects[obj].tri_count != p.index_count / 3) {
            fprintf(stderr, "  leaf %u: object %u missing or of another size\n", i, obj);
            worst = -1;
            hlod_store_payload_free(&p);
            break;
        }
        size_t t0 = m->objects[obj].first_tri;
        for (size_t t = 0; t < p.index_count / 3; t++) {
            double best = INFINITY;
            for (int rot = 0; rot < 3; rot++) {
                double d = 0;
                for (int k = 0; k < 3; k++) {
                    const float *a = p.positions + 3 * p.indices[3 * t + k];
                    const double *b = m->positions + 3 * m->indices[3 * (t0 + t) + (k + rot) % 3];
                    for (int e = 0; e < 3; e++)
                        d = fmax(d, fabs(nodes[i].origin[e] + (double)a[e] - b[e]));
                }
                best = fmin(best, d);
            }
            worst = fmax(worst, best);
        }
        hlod_store_payload_free(&p);
        obj++;
    }
    if (worst >= 0 && obj != m->object_count) {
        fprintf(stderr, "  %u leaves, %zu objects\n", obj, m->object_count);
        worst = -1;
    }
    free(stack);
    return worst;
}

static double tolerance(const hlod_store *s)
{
    const hlod_store_header *h = hlod_store_get_header(s);
    double d2 = 0;
    for (int k = 0; k < 3; k++)
        d2 += (h->bbox_max[k] - h->bbox_min[k]) * (h->bbox_max[k] - h->bbox_min[k]);
    return fmax(h->quant_step, 1e-6 * sqrt(d2));
}

static double import_and_compare(const hlod_store *s, const char *dir, const char *tag)
{
    char ts[1500], scratch[1500];
    snprintf(ts, sizeof ts, "%s/tileset.json", dir);
    snprintf(scratch, sizeof scratch, "%s/scratch-%s", g_dir, tag);
    check_sh("rm -rf '%s' && mkdir -p '%s'", scratch, scratch);
    hlod_import_desc d = {NULL, 1, scratch};
    hlod_mesh m = {0};
    hlod_result r = hlod_mesh_import(ts, &d, &m, NULL);
    CHECKF(r == HLOD_OK, "%s: import %s", tag, hlod_result_str(r));
    double dev = r == HLOD_OK ? leaf_deviation(s, &m) : -1;
    size_t textured = 0;
    for (size_t i = 0; i < m.material_count; i++)
        textured += m.materials[i].texture_path && exists(m.materials[i].texture_path);
    CHECKF(textured > 0 && textured == m.material_count, "%s: %zu of %zu materials textured", tag,
           textured, m.material_count);
    hlod_mesh_free(&m);
    double tol = tolerance(s);
    fprintf(stderr, "  %s: leaves within %.3g (tolerance %.3g)\n", tag, dev, tol);
    CHECKF(dev >= 0 && dev <= tol, "%s: deviation %.3g, tolerance %.3g", tag, dev, tol);
    return dev;
}

static void leaves_come_back(void)
{
    for (int c = 0; c < CITIES; c++) {
        hlod_store *s = NULL;
        CHECK(hlod_store_open(g_store[c], NULL, &s) == HLOD_OK);
        if (!s)
            return;
        char dir[1400], tag[32];
        snprintf(dir, sizeof dir, "%s/tiles-%d", g_dir, c);
        snprintf(tag, sizeof tag, "city %d", c);
        if (!exists(dir))
            CHECK(export_to(s, dir, HLOD_MESHOPT_AUTO, 1) == HLOD_OK);
        g_worst[c] = import_and_compare(s, dir, tag);
        hlod_store_close(s);
    }
    fprintf(stderr, "  deviation at the origin %.9g m, at 6e6 m %.9g m\n", g_worst[0], g_worst[1]);
    CHECK(fabs(g_worst[1] - g_worst[0]) <= 1e-6);
}

static void never_plain(void)
{
    hlod_store *s = NULL;
    CHECK(hlod_store_open(g_store[1], NULL, &s) == HLOD_OK);
    if (!s)
        return;
    char dir[1400], glb[1500];
    snprintf(dir, sizeof dir, "%s/plain", g_dir);
    CHECK(export_to(s, dir, HLOD_MESHOPT_NEVER, 1) == HLOD_OK);
    snprintf(glb, sizeof glb, "%s/tiles/0.glb", dir);
    size_t n = 0;
    char *b = slurp(glb, &n);
    CHECK(b && n > 20 && !memmem(b, n, "EXT_meshopt_compression", 23) &&
          memmem(b, n, "KHR_mesh_quantization", 21));
    free(b);
    import_and_compare(s, dir, "plain");
    hlod_store_close(s);
}

/* ---- refuses_and_replaces ---- */

static int count_prefix(const char *dir, const char *prefix)
{
    DIR *d = opendir(dir);
    int n = 0;
    struct dirent *e;
    while (d && (e = readdir(d)))
        n += !strncmp(e->d_name, prefix, strlen(prefix));
    if (d)
        closedir(d);
    return n;
}

static void refuses_and_replaces(void)
{
    hlod_store *s = NULL;
    CHECK(hlod_store_open(g_store[0], NULL, &s) == HLOD_OK);
    if (!s)
        return;
    char dir[1400], mark[1500], ts[1500];
    snprintf(dir, sizeof dir, "%s/existing", g_dir);
    snprintf(mark, sizeof mark, "%s/mine.txt", dir);
    snprintf(ts, sizeof ts, "%s/tileset.json", dir);
    check_sh("rm -rf '%s' && mkdir -p '%s' && echo mine > '%s'", dir, dir, mark);
    CHECK(export_to(s, dir, HLOD_MESHOPT_AUTO, 0) == HLOD_ERR_IO);
    CHECK(exists(mark) && !exists(ts));
    CHECK(export_to(s, dir, HLOD_MESHOPT_AUTO, 1) == HLOD_OK);
    CHECK(!exists(mark) && exists(ts));
    CHECK(count_prefix(g_dir, "existing.") == 0);
    hlod_store_close(s);

    /* a corrupt payload: nothing written, nothing left */
    char bad[1400], out[1400];
    snprintf(bad, sizeof bad, "%s/corrupt.hlod", g_dir);
    snprintf(out, sizeof out, "%s/corrupt-tiles", g_dir);
    check_sh("cp '%s' '%s'", g_store[0], bad);
    hlod_store *b = NULL;
    CHECK(hlod_store_open(bad, NULL, &b) == HLOD_OK);
    if (!b)
        return;
    const hlod_store_node *nodes = hlod_store_nodes(b);
    uint32_t victim = hlod_store_node_count(b) - 1;
    uint64_t off = nodes[victim].payload_offset + nodes[victim].payload_size / 2;
    hlod_store_close(b);
    FILE *f = fopen(bad, "r+b");
    CHECK(f != NULL);
    if (!f)
        return;
    fseek(f, (long)off, SEEK_SET);
    int ch = fgetc(f);
    fseek(f, (long)off, SEEK_SET);
    fputc(ch ^ 0x5a, f);
    fclose(f);
    CHECK(hlod_store_open(bad, NULL, &b) == HLOD_OK);
    if (!b)
        return;
    CHECK(export_to(b, out, HLOD_MESHOPT_AUTO, 0) == HLOD_ERR_CHECKSUM);
    CHECK(!exists(out));
    CHECK(count_prefix(g_dir, "corrupt-tiles.") == 0);
    hlod_store_close(b);
}

/* ---- bad_tilesets ---- */

static hlod_result import_quiet(const char *path)
{
    char scratch[1500];
    snprintf(scratch, sizeof scratch, "%s/scratch-bad", g_dir);
    if (!exists(scratch))
        check_sh("mkdir -p '%s'", scratch);
    hlod_import_desc d = {NULL, 0, scratch};
    hlod_mesh m = {0};
    hlod_result r = hlod_mesh_import(path, &d, &m, NULL);
    hlod_mesh_free(&m);
    return r;
}

static void bad_tilesets(void)
{
    char src[1400], dir[1400], ts[1500], glb[1500];
    snprintf(src, sizeof src, "%s/tiles-0", g_dir);
    snprintf(dir, sizeof dir, "%s/bad", g_dir);
    snprintf(ts, sizeof ts, "%s/tileset.json", dir);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(g_store[0], NULL, &s) == HLOD_OK);
    if (!s)
        return;
    uint32_t leaf = hlod_store_node_count(s) - 1;   /* breadth-first: the last is a leaf */
    hlod_store_close(s);
    snprintf(glb, sizeof glb, "%s/tiles/%u.glb", dir, leaf);

    check_sh("rm -rf '%s' && cp -r '%s' '%s' && rm '%s'", dir, src, dir, glb);
    CHECK(import_quiet(ts) != HLOD_OK);
    check_sh("rm -rf '%s' && cp -r '%s' '%s' && truncate -s 1000 '%s'", dir, src, dir, glb);
    CHECK(import_quiet(ts) != HLOD_OK);
    check_sh("rm -rf '%s' && cp -r '%s' '%s' && sed -i 's/%u.glb/%u.b3dm/' '%s'", dir, src, dir,
             leaf, leaf, ts);
    CHECK(import_quiet(ts) == HLOD_ERR_FORMAT);
    check_sh("rm -rf '%s' && mkdir -p '%s' && echo '{\"asset\":{\"version\":\"1.1\"}}' > '%s'",
             dir, dir, ts);
    CHECK(import_quiet(ts) == HLOD_ERR_FORMAT);

    /* random byte flips in one leaf glb, the only tile of a tileset: an
     * error or a mesh, no crash */
    check_sh("rm -rf '%s' && mkdir -p '%s/tiles' && printf '%%s' '{\"asset\":{\"version\":\"1.1\"},"
             "\"geometricError\":1,\"root\":{\"boundingVolume\":{\"box\":[0,0,0,1,0,0,0,1,0,0,0,1]},"
             "\"geometricError\":0,\"content\":{\"uri\":\"tiles/%u.glb\"}}}' > '%s'",
             dir, dir, leaf, ts);
    char orig[1500];
    snprintf(orig, sizeof orig, "%s/tiles/%u.glb", src, leaf);
    size_t n = 0;
    char *good = slurp(orig, &n);
    CHECK(good != NULL && n > 100);
    if (!good)
        return;
    check_sh("cp '%s' '%s'", orig, glb);
    CHECK(import_quiet(ts) == HLOD_OK);    /* undamaged, it is read */
    unsigned seed = 12345, ok = 0, failed = 0;
    for (int round = 0; round < 300; round++) {
        char *b = malloc(n);
        memcpy(b, good, n);
        int flips = 1 + round % 8;
        for (int k = 0; k < flips; k++) {
            seed = seed * 1103515245u + 12345u;
            size_t at = (seed >> 8) % n;
            seed = seed * 1103515245u + 12345u;
            b[at] ^= (char)(1u << ((seed >> 16) % 8));
        }
        FILE *f = fopen(glb, "wb");
        fwrite(b, 1, n, f);
        fclose(f);
        free(b);
        if (import_quiet(ts) == HLOD_OK)
            ok++;
        else
            failed++;
    }
    free(good);
    fprintf(stderr, "  300 damaged glbs: %u imported, %u refused, none crashed\n", ok, failed);
    CHECK(ok + failed == 300 && failed > 0);
}

int main(void)
{
    const char *bin = getenv("HLOD_BIN_DIR");
    snprintf(g_bin, sizeof g_bin, "%s", bin && *bin ? bin : "build/bin");
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod-test-tiles-XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    int built = 1;
    for (int c = 0; c < CITIES && built; c++) {
        const double *o = g_origins[c];
        char obj[1200];
        snprintf(obj, sizeof obj, "%s/city-%d.obj", g_dir, c);
        snprintf(g_store[c], sizeof g_store[c], "%s/city-%d.hlod", g_dir, c);
        built = check_sh("'%s/hlod-gen-city' --preset small --origin %.17g %.17g %.17g -o '%s' "
                         "--quiet && '%s/hlod-build' '%s' -o '%s' --desired-tris 450 --quiet",
                         g_bin, o[0], o[1], o[2], obj, g_bin, obj, g_store[c]) == 0;
    }
    CHECK(built);
    if (built) {
        RUN(tileset_mirrors_store);
        RUN(leaves_come_back);
        RUN(never_plain);
        RUN(refuses_and_replaces);
        RUN(bad_tilesets);
    }
    int rc = check_done();
    if (rc == 0)
        check_sh("rm -rf '%s'", g_dir);
    else
        fprintf(stderr, "kept %s\n", g_dir);
    return rc;
}
