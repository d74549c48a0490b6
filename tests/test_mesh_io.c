/*
 * Mesh import/export: double precision, round trips, every error path,
 * cleanup of degenerate/duplicate triangles, atomic writes, and the real
 * meshes that data/fetch-meshes.sh puts in data/meshes/; plus the texture
 * image wrapper (image.h) on those meshes' textures.
 */
#include <dirent.h>
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "check.h"
#include "hlod/image.h"
#include "hlod/mesh.h"
#include "hlod/mesh_io.h"
#include "io/io_internal.h"

/* ---- a logger that records what it was told ---- */

#define MAX_MSGS 64
typedef struct recorder {
    int n;
    hlod_log_level level[MAX_MSGS];
    char msg[MAX_MSGS][512];
} recorder;

static void record(void *user, hlod_log_level level, const char *msg)
{
    recorder *r = user;
    if (r->n < MAX_MSGS) {
        r->level[r->n] = level;
        snprintf(r->msg[r->n], sizeof r->msg[0], "%s", msg);
        r->n++;
    }
}

/* Whether some message at `level` contains every non-NULL substring. */
static int logged(const recorder *r, hlod_log_level level, const char *a, const char *b)
{
    for (int i = 0; i < r->n; i++)
        if (r->level[i] == level && (!a || strstr(r->msg[i], a)) && (!b || strstr(r->msg[i], b)))
            return 1;
    return 0;
}

static void dump_log(const recorder *r)
{
    for (int i = 0; i < r->n; i++)
        fprintf(stderr, "  log[%d]: %s\n", r->level[i], r->msg[i]);
}

/* Imports with a fresh recorder. */
static hlod_result import_rec(const char *path, hlod_mesh *m, hlod_import_stats *st, recorder *r,
                              int keep)
{
    memset(r, 0, sizeof *r);
    hlod_logger lg = {record, r};
    hlod_import_desc d = {&lg, keep, NULL};
    return hlod_mesh_import(path, &d, m, st);
}

/* ---- scratch folder ---- */

static char tmpdir[64];

static const char *tpath(const char *name, char *buf)
{
    snprintf(buf, 256, "%s/%s", tmpdir, name);
    return buf;
}

static void write_bytes(const char *path, const void *data, size_t n)
{
    FILE *f = fopen(path, "wb");
    CHECK(f != NULL);
    if (f) {
        CHECK(fwrite(data, 1, n, f) == n);
        fclose(f);
    }
}

static void write_text(const char *path, const char *text)
{
    write_bytes(path, text, strlen(text));
}

static int exists(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0;
}

/* Number of leftover temporary files ("*.tmp-*") in the scratch folder. */
static int tmp_files(void)
{
    int n = 0;
    DIR *d = opendir(tmpdir);
    struct dirent *e;
    while (d && (e = readdir(d)))
        n += strstr(e->d_name, ".tmp-") != NULL;
    if (d)
        closedir(d);
    return n;
}

static void remove_tree(const char *dir)
{
    DIR *d = opendir(dir);
    struct dirent *e;
    char p[512];
    while (d && (e = readdir(d))) {
        if (!strcmp(e->d_name, ".") || !strcmp(e->d_name, ".."))
            continue;
        snprintf(p, sizeof p, "%s/%s", dir, e->d_name);
        struct stat st;
        if (lstat(p, &st) == 0 && S_ISDIR(st.st_mode))
            remove_tree(p);
        else
            unlink(p);
    }
    if (d)
        closedir(d);
    rmdir(dir);
}

/* ---- precision ---- */

/* Decimal strings near a projected-city origin (x ~ 5e5, y ~ 4.1e6), with
 * millimetre and sub-millimetre parts and full 17-digit forms; in float
 * each y moves by up to 0.125 m. */
static const char *const prec_xyz[4][3] = {
    {"500000.123456789", "4100000.13", "30.0001"},
    {"500000.0005", "4100000.3750001", "30.25"},
    {"500001.12345678912", "4100001.9876543211", "29.999"},
    {"500000.87654321", "4100001.1300000001", "30.123456789012345"},
};

static double prec_val(int v, int k)
{
    return strtod(prec_xyz[v][k], NULL); /* glibc strtod rounds correctly */
}

static void check_prec_positions(const hlod_mesh *m, const char *what)
{
    CHECKF(m->vertex_count == 4, "%s: %zu vertices", what, m->vertex_count);
    if (m->vertex_count != 4)
        return;
    for (int v = 0; v < 4; v++)
        for (int k = 0; k < 3; k++)
            CHECKF(m->positions[3 * v + k] == prec_val(v, k), "%s: vertex %d axis %d: %.17g != %s",
                   what, v, k, m->positions[3 * v + k], prec_xyz[v][k]);
}

static void write_prec_obj(const char *path)
{
    char text[1024];
    int n = 0;
    for (int v = 0; v < 4; v++)
        n += snprintf(text + n, sizeof text - (size_t)n, "v %s %s %s\n", prec_xyz[v][0],
                      prec_xyz[v][1], prec_xyz[v][2]);
    snprintf(text + n, sizeof text - (size_t)n, "f 1 2 3\nf 1 3 4\n");
    write_text(path, text);
}

static void obj_keeps_double_precision(void)
{
    char p[256];
    write_prec_obj(tpath("prec.obj", p));
    hlod_mesh m = {0};
    recorder r;
    CHECK(import_rec(p, &m, NULL, &r, 0) == HLOD_OK);
    check_prec_positions(&m, "obj");
    hlod_mesh_free(&m);
}

static void float_path_would_lose_precision(void)
{
    /* The premise: y = 4100000.13 is 0.12 m from the nearest float. */
    CHECK(fabs((double)(float)prec_val(0, 1) - prec_val(0, 1)) > 0.1);
    /* And assimp's own OBJ importer (float) really loses it on this file. */
    char p[256];
    write_prec_obj(tpath("prec_assimp.obj", p));
    hlod_mesh m = {0};
    hlod_import_stats st = {0};
    CHECK(io_read_assimp(p, NULL, &m, &st) == HLOD_OK);
    double worst = 0;
    for (size_t v = 0; v < m.vertex_count; v++) {
        /* assimp may reorder vertices: match each to the nearest original */
        double best = INFINITY;
        for (int o = 0; o < 4; o++) {
            double d = 0;
            for (int k = 0; k < 3; k++)
                d = fmax(d, fabs(m.positions[3 * v + k] - prec_val(o, k)));
            best = fmin(best, d);
        }
        worst = fmax(worst, best);
    }
    CHECKF(m.vertex_count > 0 && worst > 0.1, "assimp error %.3f m", worst);
    hlod_mesh_free(&m);
}

static void put_le(uint8_t *p, const void *v, int n, int big)
{
    const uint8_t *s = v; /* the test machine is little-endian */
    for (int i = 0; i < n; i++)
        p[i] = big ? s[n - 1 - i] : s[i];
}

/* A binary PLY of the precision quad with double (or float) positions. */
static size_t make_binary_ply(uint8_t *buf, int big, int use_float)
{
    int n = sprintf((char *)buf,
                    "ply\nformat %s 1.0\ncomment test\nelement vertex 4\n"
                    "property %s x\nproperty %s y\nproperty %s z\nproperty uchar red\n"
                    "element face 2\nproperty list uchar int vertex_indices\n"
                    "element extra 1\nproperty list ushort float junk\n"
                    "end_header\n",
                    big ? "binary_big_endian" : "binary_little_endian",
                    use_float ? "float" : "double", use_float ? "float" : "double",
                    use_float ? "float" : "double");
    uint8_t *p = buf + n;
    for (int v = 0; v < 4; v++) {
        for (int k = 0; k < 3; k++) {
            if (use_float) {
                float f = (float)prec_val(v, k);
                put_le(p, &f, 4, big);
                p += 4;
            } else {
                double d = prec_val(v, k);
                put_le(p, &d, 8, big);
                p += 8;
            }
        }
        *p++ = 200; /* red */
    }
    int32_t faces[2][3] = {{0, 1, 2}, {0, 2, 3}};
    for (int f = 0; f < 2; f++) {
        *p++ = 3;
        for (int k = 0; k < 3; k++, p += 4)
            put_le(p, &faces[f][k], 4, big);
    }
    uint16_t two = 2;
    float junk[2] = {1.5f, -2.5f};
    put_le(p, &two, 2, big);
    p += 2;
    for (int k = 0; k < 2; k++, p += 4)
        put_le(p, &junk[k], 4, big);
    return (size_t)(p - buf);
}

static void binary_ply_keeps_double_precision(void)
{
    uint8_t buf[1024];
    char p[256];
    for (int big = 0; big <= 1; big++) {
        size_t n = make_binary_ply(buf, big, 0);
        write_bytes(tpath(big ? "prec_be.ply" : "prec_le.ply", p), buf, n);
        hlod_mesh m = {0};
        recorder r;
        CHECK(import_rec(p, &m, NULL, &r, 0) == HLOD_OK);
        check_prec_positions(&m, big ? "binary big-endian ply" : "binary little-endian ply");
        CHECK(m.tri_count == 2);
        hlod_mesh_free(&m);
    }
}

static void float_ply_reads_exact_floats(void)
{
    uint8_t buf[1024];
    char p[256];
    size_t n = make_binary_ply(buf, 1, 1);
    write_bytes(tpath("prec_f.ply", p), buf, n);
    hlod_mesh m = {0};
    recorder r;
    CHECK(import_rec(p, &m, NULL, &r, 0) == HLOD_OK);
    CHECK(m.vertex_count == 4);
    for (int v = 0; v < 4 && m.vertex_count == 4; v++)
        for (int k = 0; k < 3; k++)
            CHECK(m.positions[3 * v + k] == (double)(float)prec_val(v, k));
    hlod_mesh_free(&m);
}

static void ascii_ply_keeps_double_precision(void)
{
    char text[1024], p[256];
    int n = sprintf(text, "ply\r\nformat ascii 1.0\r\nelement vertex 4\r\nproperty double x\r\n"
                          "property double y\r\nproperty double z\r\nelement face 1\r\n"
                          "property list uchar uint vertex_indices\r\nend_header\r\n");
    for (int v = 0; v < 4; v++)
        n += sprintf(text + n, "%s %s %s\r\n", prec_xyz[v][0], prec_xyz[v][1], prec_xyz[v][2]);
    sprintf(text + n, "4 0 1 2 3\r\n");
    write_text(tpath("prec_ascii.ply", p), text);
    hlod_mesh m = {0};
    recorder r;
    CHECK(import_rec(p, &m, NULL, &r, 0) == HLOD_OK);
    check_prec_positions(&m, "ascii ply");
    CHECK(m.tri_count == 2); /* the quad, fan-triangulated */
    hlod_mesh_free(&m);
}

static void off_keeps_double_precision(void)
{
    char text[1024], p[256];
    int n = sprintf(text, "OFF\n# precision test\n4 1 0\n");
    for (int v = 0; v < 4; v++)
        n += sprintf(text + n, "%s %s %s\n", prec_xyz[v][0], prec_xyz[v][1], prec_xyz[v][2]);
    sprintf(text + n, "4 0 1 2 3 255 0 0\n");
    write_text(tpath("prec.off", p), text);
    hlod_mesh m = {0};
    recorder r;
    CHECK(import_rec(p, &m, NULL, &r, 0) == HLOD_OK);
    check_prec_positions(&m, "off");
    CHECK(m.tri_count == 2);
    hlod_mesh_free(&m);
}

static void number_parser_is_exact(void)
{
    /* Fast path, slow path, exponents, signs, tiny and huge values. */
    static const char *const nums[] = {
        "0",    "-0",      "1",          "0.1",          "4100000.13", "1e22",      "1e23",
        "-2.5e-3", "123456789012345678", "9007199254740993", "0.30000000000000004",
        "2.2250738585072014e-308", "4.9e-324", "1.7976931348623157e308", ".5", "5.",
        "+3.25", "1E+05", "0.000000000000000000000000123"};
    for (size_t i = 0; i < sizeof nums / sizeof nums[0]; i++) {
        const char *p = nums[i];
        double d;
        CHECKF(io_parse_double(&p, &d) && *p == '\0', "%s not parsed", nums[i]);
        double want = strtod(nums[i], NULL);
        CHECKF(memcmp(&d, &want, sizeof d) == 0, "%s: %.17g != %.17g", nums[i], d, want);
    }
    const char *bad = "1.5x";
    double d;
    CHECK(!io_parse_double(&bad, &d));
    /* fast_float's refusals reach strtod: hex floats; overflow is inf */
    const char *hex = "0x1.8p1", *huge = "+1e400";
    CHECK(io_parse_double(&hex, &d) && d == 3.0);
    CHECK(io_parse_double(&huge, &d) && isinf(d) && d > 0);
    /* Random decimals, bit for bit against strtod: the 17-digit forms a
     * lossless exporter writes (no fast path, fast_float's Eisel-Lemire),
     * and long digit strings near halfway points (its big-decimal
     * fallback). */
    uint64_t s = 0x9e3779b97f4a7c15u;
    int mismatches = 0;
    for (int i = 0; i < 200000; i++) {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        char text[96];
        if (i % 2) {
            double x;
            uint64_t bits = s & 0x7fefffffffffffffu;   /* finite, either sign */
            memcpy(&x, &bits, sizeof x);
            snprintf(text, sizeof text, i % 4 == 1 ? "%.17g" : "%.25e", x);
        } else {
            /* the exact midpoint between two neighbouring doubles (a
             * long double holds it), whole or cut short just below it */
            double x = (double)(s >> 11) * 0x1p-30;
            long double mid = ((long double)x + (long double)nextafter(x, INFINITY)) / 2;
            int n = snprintf(text, sizeof text, "%.45Lf", mid);
            int cut = 12 + (int)(s % 48);
            if (cut < n)
                text[cut] = '\0';
        }
        const char *p = text;
        double want = strtod(text, NULL);
        if (!io_parse_double(&p, &d) || *p != '\0' || memcmp(&d, &want, sizeof d) != 0) {
            if (mismatches++ < 5)
                CHECKF(0, "%s: %.17g != %.17g", text, d, want);
        }
    }
    CHECKF(mismatches == 0, "%d of 200000 random decimals differ from strtod", mismatches);
}

/* ---- round trips ---- */

/* Two objects, two materials (one textured), uvs and normals, at city
 * coordinates with arbitrary low bits. */
static void make_rich_mesh(hlod_mesh *m, const char *texture)
{
    CHECK(hlod_mesh_alloc(m, 6, 4, HLOD_MESH_NORMALS | HLOD_MESH_UVS | HLOD_MESH_MATERIALS) ==
          HLOD_OK);
    static const double base[6][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0},
                                      {0, 1, 0}, {0, 0, 1}, {1, 0, 1}};
    for (int v = 0; v < 6; v++) {
        m->positions[3 * v] = 512345.0 + base[v][0] * 3.3 + 1e-7 * v;
        m->positions[3 * v + 1] = 4123456.0 + base[v][1] * 2.2 + 1.0 / 3.0;
        m->positions[3 * v + 2] = 31.0 + base[v][2] * 1.1 + 0.0001 * v;
        m->uvs[2 * v] = 0.1f * (float)v;
        m->uvs[2 * v + 1] = 1.0f / (float)(v + 3);
        m->normals[3 * v] = 0.6f;
        m->normals[3 * v + 1] = 0.8f;
        m->normals[3 * v + 2] = 0.0f;
    }
    static const uint32_t idx[12] = {0, 1, 2, 0, 2, 3, 0, 1, 5, 0, 5, 4};
    memcpy(m->indices, idx, sizeof idx);
    m->tri_material[0] = 0;
    m->tri_material[1] = 1;
    m->tri_material[2] = 1;
    m->tri_material[3] = 0;
    m->material_count = 2;
    m->materials = calloc(2, sizeof *m->materials);
    m->materials[0].name = strdup("brick wall");
    m->materials[0].diffuse[0] = 0.5f;
    m->materials[0].diffuse[1] = 0.25f;
    m->materials[0].diffuse[2] = 0.125f;
    m->materials[0].diffuse[3] = 1.0f;
    m->materials[0].texture_path = texture ? strdup(texture) : NULL;
    m->materials[1].name = strdup("roof");
    for (int k = 0; k < 4; k++)
        m->materials[1].diffuse[k] = k == 3 ? 1.0f : 0.75f;
    m->object_count = 2;
    m->objects = calloc(2, sizeof *m->objects);
    m->objects[0].name = strdup("house_1");
    m->objects[0].first_tri = 0;
    m->objects[0].tri_count = 2;
    m->objects[1].name = strdup("house_2");
    m->objects[1].first_tri = 2;
    m->objects[1].tri_count = 2;
}

static int same_file(const char *a, const char *b)
{
    struct stat sa, sb;
    return a && b && stat(a, &sa) == 0 && stat(b, &sb) == 0 && sa.st_ino == sb.st_ino &&
           sa.st_dev == sb.st_dev;
}

static void check_geometry_equal(const hlod_mesh *a, const hlod_mesh *b, int uv_n, const char *w)
{
    CHECKF(a->vertex_count == b->vertex_count && a->tri_count == b->tri_count,
           "%s: %zu/%zu vs %zu/%zu", w, a->vertex_count, a->tri_count, b->vertex_count,
           b->tri_count);
    if (a->vertex_count != b->vertex_count || a->tri_count != b->tri_count)
        return;
    CHECKF(memcmp(a->positions, b->positions, a->vertex_count * 3 * sizeof(double)) == 0,
           "%s: positions differ", w);
    CHECKF(memcmp(a->indices, b->indices, a->tri_count * 3 * sizeof(uint32_t)) == 0,
           "%s: indices differ", w);
    if (uv_n) {
        CHECKF(b->uvs && memcmp(a->uvs, b->uvs, a->vertex_count * 2 * sizeof(float)) == 0,
               "%s: uvs differ", w);
        CHECKF(b->normals &&
                   memcmp(a->normals, b->normals, a->vertex_count * 3 * sizeof(float)) == 0,
               "%s: normals differ", w);
    }
}

static void obj_round_trip(void)
{
    char tex[256], p[256], mtl[256];
    write_text(tpath("wall.png", tex), "not decoded during import");
    hlod_mesh a = {0}, b = {0};
    make_rich_mesh(&a, tex);
    recorder r;
    hlod_logger lg = {record, &r};
    memset(&r, 0, sizeof r);
    CHECK(hlod_mesh_export(tpath("rt.obj", p), &a, &lg) == HLOD_OK);
    CHECK(exists(tpath("rt.mtl", mtl)));
    hlod_import_stats st;
    CHECK(import_rec(p, &b, &st, &r, 0) == HLOD_OK);
    check_geometry_equal(&a, &b, 1, "obj");
    CHECK(b.object_count == 2);
    if (b.object_count == 2) {
        CHECK(strcmp(b.objects[0].name, "house_1") == 0 && b.objects[0].tri_count == 2);
        CHECK(strcmp(b.objects[1].name, "house_2") == 0 && b.objects[1].first_tri == 2);
    }
    CHECK(b.material_count == 2);
    if (b.material_count == 2 && b.tri_material) {
        /* materials come back in first-use order: brick (tri 0), roof (tri 1) */
        CHECK(strcmp(b.materials[0].name, "brick_wall") == 0);
        CHECK(memcmp(b.materials[0].diffuse, a.materials[0].diffuse, sizeof(float[4])) == 0);
        CHECK(same_file(b.materials[0].texture_path, tex));
        CHECK(strcmp(b.materials[1].name, "roof") == 0 && !b.materials[1].texture_path);
        for (size_t t = 0; t < 4; t++)
            CHECK(strcmp(b.materials[b.tri_material[t]].name,
                         t == 0 || t == 3 ? "brick_wall" : "roof") == 0);
    }
    CHECK(st.missing_textures == 0);
    CHECK(tmp_files() == 0);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

static void ply_round_trip(void)
{
    char p[256];
    hlod_mesh a = {0}, b = {0};
    make_rich_mesh(&a, NULL);
    CHECK(hlod_mesh_export(tpath("rt.ply", p), &a, NULL) == HLOD_OK);
    recorder r;
    CHECK(import_rec(p, &b, NULL, &r, 0) == HLOD_OK);
    check_geometry_equal(&a, &b, 1, "ply");
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

static void off_round_trip(void)
{
    char p[256];
    hlod_mesh a = {0}, b = {0};
    make_rich_mesh(&a, NULL);
    CHECK(hlod_mesh_export(tpath("rt.off", p), &a, NULL) == HLOD_OK);
    recorder r;
    CHECK(import_rec(p, &b, NULL, &r, 0) == HLOD_OK);
    check_geometry_equal(&a, &b, 0, "off");
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

/* glTF goes back through assimp (float node transforms), so the check is
 * structure plus float-level positions, on a mesh near the origin. */
static void check_gltf_round_trip(const char *name)
{
    char tex[256], p[256];
    write_text(tpath("wall.png", tex), "not decoded during import");
    hlod_mesh a = {0}, b = {0};
    make_rich_mesh(&a, tex);
    for (size_t v = 0; v < a.vertex_count; v++) {
        a.positions[3 * v] -= 512345.0;
        a.positions[3 * v + 1] -= 4123456.0;
    }
    CHECK(hlod_mesh_export(tpath(name, p), &a, NULL) == HLOD_OK);
    recorder r;
    hlod_import_stats st;
    CHECK(import_rec(p, &b, &st, &r, 0) == HLOD_OK);
    CHECKF(b.tri_count == 4, "%s: %zu triangles", name, b.tri_count);
    CHECK(b.object_count == 2);
    if (b.object_count == 2) {
        CHECK(strcmp(b.objects[0].name, "house_1") == 0);
        CHECK(strcmp(b.objects[1].name, "house_2") == 0);
    }
    /* Primitives group triangles by material, so match triangles by their
     * corners (same cyclic order, i.e. same winding) rather than by index. */
    double err = 0;
    float du = 0;
    int used[4] = {0};
    for (size_t ta = 0; ta < 4 && b.tri_count == 4; ta++) {
        double best = INFINITY;
        size_t bt = 0;
        int brot = 0;
        for (size_t tb = 0; tb < 4; tb++)
            for (int rot = 0; rot < 3 && !used[tb]; rot++) {
                double e = 0;
                for (int k = 0; k < 3; k++)
                    for (int c = 0; c < 3; c++)
                        e = fmax(e, fabs(b.positions[3 * b.indices[3 * tb + (k + rot) % 3] + c] -
                                         a.positions[3 * a.indices[3 * ta + k] + c]));
                if (e < best)
                    best = e, bt = tb, brot = rot;
            }
        used[bt] = 1;
        err = fmax(err, best);
        for (int k = 0; b.uvs && k < 3; k++)
            for (int c = 0; c < 2; c++)
                du = fmaxf(du, fabsf(b.uvs[2 * b.indices[3 * bt + (k + brot) % 3] + c] -
                                     a.uvs[2 * a.indices[3 * ta + k] + c]));
    }
    CHECKF(err < 1e-5, "%s: position error %g", name, err);
    CHECK(b.uvs != NULL && b.normals != NULL);
    CHECKF(du < 1e-6f, "%s: uv error %g", name, du);
    int textured = 0;
    for (size_t i = 0; i < b.material_count; i++)
        textured += same_file(b.materials[i].texture_path, tex);
    CHECK(textured == 1);
    CHECK(st.missing_textures == 0);
    CHECK(tmp_files() == 0);
    hlod_mesh_free(&a);
    hlod_mesh_free(&b);
}

static void gltf_round_trip(void)
{
    check_gltf_round_trip("rt.gltf");
}

static void glb_round_trip(void)
{
    check_gltf_round_trip("rt.glb");
}

static void gltf_keeps_object_centre_in_double(void)
{
    /* The node translation is written with 17 digits, so a reader that
     * keeps doubles gets the object centre exactly. */
    char p[256];
    hlod_mesh a = {0};
    make_rich_mesh(&a, NULL);
    CHECK(hlod_mesh_export(tpath("centre.gltf", p), &a, NULL) == HLOD_OK);
    FILE *f = fopen(p, "rb");
    char json[16384] = {0};
    CHECK(f && fread(json, 1, sizeof json - 1, f) > 0);
    if (f)
        fclose(f);
    double lo = 512345.0, hi = 512345.0 + 3.3 + 5e-7;
    char want[64];
    snprintf(want, sizeof want, "\"translation\":[%.17g,", 0.5 * (lo + hi));
    CHECKF(strstr(json, want) != NULL, "no %s", want);
    hlod_mesh_free(&a);
}

/* ---- errors ---- */

static void expect_error(const char *name, const char *text, hlod_result want,
                         const char *in_msg)
{
    char p[256];
    write_text(tpath(name, p), text);
    hlod_mesh m = {0};
    recorder r;
    hlod_result got = import_rec(p, &m, NULL, &r, 0);
    CHECKF(got == want, "%s: got %s, want %s", name, hlod_result_str(got), hlod_result_str(want));
    CHECKF(logged(&r, HLOD_LOG_ERROR, p, in_msg), "%s: no error naming the file and '%s'", name,
           in_msg ? in_msg : "");
    if (got != want || !logged(&r, HLOD_LOG_ERROR, p, in_msg))
        dump_log(&r);
    CHECK(m.tri_count == 0 && m.positions == NULL);
}

static void missing_file_is_io_error(void)
{
    char p[256];
    hlod_mesh m = {0};
    recorder r;
    CHECK(import_rec(tpath("no-such-file.obj", p), &m, NULL, &r, 0) == HLOD_ERR_IO);
    CHECK(logged(&r, HLOD_LOG_ERROR, p, "No such file"));
    CHECK(import_rec(tmpdir, &m, NULL, &r, 0) == HLOD_ERR_IO);
    CHECK(logged(&r, HLOD_LOG_ERROR, tmpdir, NULL));
}

static void nan_coordinate_is_nan_error(void)
{
    expect_error("nan.obj", "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n", HLOD_ERR_NAN, "vertex 3");
    expect_error("inf.off", "OFF\n3 1 0\n0 0 0\n1 0 inf\n0 1 0\n3 0 1 2\n", HLOD_ERR_NAN,
                 "vertex 1");
    expect_error("overflow.obj", "v 0 0 0\nv 1e999 0 0\nv 0 1 0\nf 1 2 3\n", HLOD_ERR_NAN,
                 "line 2");
    uint8_t buf[1024];
    size_t n = make_binary_ply(buf, 0, 0);
    double nan = NAN;
    /* vertex 2's y: header, then 2 vertices of 25 bytes, then x */
    memcpy(buf + (strstr((char *)buf, "end_header\n") - (char *)buf) + 11 + 2 * 25 + 8, &nan, 8);
    char p[256];
    write_bytes(tpath("nan.ply", p), buf, n);
    hlod_mesh m = {0};
    recorder r;
    CHECK(import_rec(p, &m, NULL, &r, 0) == HLOD_ERR_NAN);
    CHECK(logged(&r, HLOD_LOG_ERROR, p, "vertex 2"));
}

static void index_out_of_range_is_range_error(void)
{
    expect_error("range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n",
                 HLOD_ERR_INDEX_RANGE, "face 2");
    expect_error("negrange.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", HLOD_ERR_INDEX_RANGE,
                 "face 1");
    expect_error("range.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n",
                 HLOD_ERR_INDEX_RANGE, "face 0");
    expect_error("range.ply",
                 "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                 "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                 "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n",
                 HLOD_ERR_INDEX_RANGE, "face 0");
}

static void empty_mesh_is_empty_error(void)
{
    expect_error("empty.obj", "# nothing\nv 0 0 0\nv 1 0 0\n", HLOD_ERR_EMPTY, "no faces");
    expect_error("empty.off", "OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n", HLOD_ERR_EMPTY, "no faces");
    expect_error("points.ply",
                 "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                 "property float z\nend_header\n0 0 0\n",
                 HLOD_ERR_EMPTY, "no faces");
    /* Every triangle degenerate: nothing left after cleaning. */
    expect_error("alldegen.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", HLOD_ERR_EMPTY,
                 "degenerate");
}

static void malformed_header_is_format_error(void)
{
    expect_error("badfmt.ply", "ply\nformat binary_middle_endian 1.0\nend_header\n",
                 HLOD_ERR_FORMAT, "line 2");
    expect_error("noend.ply", "ply\nformat ascii 1.0\nelement vertex 3\n", HLOD_ERR_FORMAT,
                 "end_header");
    expect_error("notply.ply", "PLY\n", HLOD_ERR_FORMAT, "not a PLY");
    expect_error("bad.off", "OF\n3 1 0\n", HLOD_ERR_FORMAT, "OFF header");
    expect_error("badcount.off", "OFF\nthree 1 0\n", HLOD_ERR_FORMAT, "line 2");
    expect_error("liar.off", "OFF\n100000000 1 0\n0 0 0\n", HLOD_ERR_FORMAT, "promises");
    expect_error("liar.ply",
                 "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n"
                 "property double x\nproperty double y\nproperty double z\nelement face 1\n"
                 "property list uchar int vertex_indices\nend_header\n",
                 HLOD_ERR_FORMAT, "promises");
    expect_error("badface.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n", HLOD_ERR_FORMAT,
                 "line 4");
    expect_error("twocorners.obj", "v 0 0 0\nv 1 0 0\nf 1 2\n", HLOD_ERR_FORMAT, "line 3");
    expect_error("unknown.xyz123", "hello\n", HLOD_ERR_UNSUPPORTED, "unknown mesh format");
}

static void every_truncated_binary_ply_fails_cleanly(void)
{
    uint8_t buf[1024];
    size_t n = make_binary_ply(buf, 0, 0);
    char p[256];
    tpath("trunc.ply", p);
    int bad = 0;
    for (size_t len = 0; len < n; len++) {
        write_bytes(p, buf, len);
        hlod_mesh m = {0};
        recorder r;
        hlod_result res = import_rec(p, &m, NULL, &r, 0);
        if (res != HLOD_ERR_FORMAT || !logged(&r, HLOD_LOG_ERROR, p, NULL) || m.positions) {
            if (bad++ < 3) {
                fprintf(stderr, "truncated at %zu of %zu: %s\n", len, n, hlod_result_str(res));
                dump_log(&r);
            }
        }
        hlod_mesh_free(&m);
    }
    CHECKF(bad == 0, "%d truncations misreported", bad);
    /* and the whole file reads */
    write_bytes(p, buf, n);
    hlod_mesh m = {0};
    recorder r;
    CHECK(import_rec(p, &m, NULL, &r, 0) == HLOD_OK);
    hlod_mesh_free(&m);
}

static void every_truncated_ascii_file_fails_or_reads(void)
{
    /* Text truncated at a line end can be a shorter valid file; what must
     * never happen is a crash, an "ok" with the wrong count, or silence. */
    static const char *const files[][2] = {
        {"tr.off", "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n"},
        {"tr.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n"},
    };
    char p[256];
    for (int f = 0; f < 2; f++) {
        size_t n = strlen(files[f][1]);
        for (size_t len = 0; len < n; len++) {
            write_bytes(tpath(files[f][0], p), files[f][1], len);
            hlod_mesh m = {0};
            recorder r;
            hlod_result res = import_rec(p, &m, NULL, &r, 0);
            if (res == HLOD_OK)
                CHECKF(f == 1 && m.tri_count >= 1, "%s at %zu read ok", files[f][0], len);
            else
                CHECKF(logged(&r, HLOD_LOG_ERROR, p, NULL), "%s at %zu: silent %s", files[f][0],
                       len, hlod_result_str(res));
            hlod_mesh_free(&m);
        }
    }
}

static void off_variants_read_normals_colours_and_uvs(void)
{
    char p[256];
    write_text(tpath("v.off", p), "CNOFF # colours and normals\n3 1 0\n"
                                  "0 0 0 0 0 1 255 0 0 255\n1 0 0 0 0 1 0 255 0\n"
                                  "0 1 0 0 0 1 0 0 255 128\n3 0 1 2 0.5 0.5 0.5\n");
    hlod_mesh m = {0};
    recorder r;
    CHECK(import_rec(p, &m, NULL, &r, 0) == HLOD_OK);
    CHECK(m.tri_count == 1 && m.normals && m.normals[2] == 1.0f && !m.uvs);
    hlod_mesh_free(&m);
    write_text(tpath("st.off", p), "STOFF\n3 1\n0 0 0 0.25 0.75\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2\n");
    CHECK(import_rec(p, &m, NULL, &r, 0) == HLOD_OK);
    CHECK(m.uvs && m.uvs[0] == 0.25f && m.uvs[1] == 0.75f);
    hlod_mesh_free(&m);
    expect_error("four.off", "4OFF\n3 1 0\n", HLOD_ERR_UNSUPPORTED, "4OFF");
}

/* A tiny fuzzer: random byte edits of small valid files must give either a
 * mesh or an error that was logged, and never crash (run under ASan). */
static void mutated_files_never_crash(void)
{
    uint8_t ply[1024];
    size_t ply_n = make_binary_ply(ply, 0, 0);
    static const char obj[] = "mtllib none.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nvn 0 0 1\n"
                              "o a\nusemtl m\nf 1/1/1 2/1/1 3/1/1\nf -1 -2 -3\n";
    static const char off[] = "OFF\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n4 0 1 2 3\n";
    static const char aply[] = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                               "property float y\nproperty float z\nelement face 1\n"
                               "property list uchar int vertex_indices\nend_header\n"
                               "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
    const struct {
        const char *name;
        const uint8_t *data;
        size_t n;
    } seeds[] = {{"fz.ply", ply, ply_n},
                 {"fz.obj", (const uint8_t *)obj, sizeof obj - 1},
                 {"fz.off", (const uint8_t *)off, sizeof off - 1},
                 {"fza.ply", (const uint8_t *)aply, sizeof aply - 1}};
    static const uint8_t alphabet[] = "0123456789-+.e/# \n\xff\x00fvn";
    uint32_t rng = 12345;
    int silent = 0;
    char p[256];
    for (size_t s = 0; s < sizeof seeds / sizeof seeds[0]; s++) {
        tpath(seeds[s].name, p);
        for (int it = 0; it < 400; it++) {
            uint8_t buf[1024];
            size_t n = seeds[s].n;
            memcpy(buf, seeds[s].data, n);
            int edits = 1 + it % 4;
            for (int e = 0; e < edits; e++) {
                rng = rng * 1664525u + 1013904223u;
                size_t at = (rng >> 8) % n;
                rng = rng * 1664525u + 1013904223u;
                buf[at] = (rng >> 24) & 1 ? (uint8_t)(rng >> 8)
                                          : alphabet[(rng >> 8) % (sizeof alphabet - 1)];
            }
            write_bytes(p, buf, n);
            hlod_mesh m = {0};
            recorder r;
            hlod_result res = import_rec(p, &m, NULL, &r, it & 1);
            if (res != HLOD_OK && !logged(&r, HLOD_LOG_ERROR, p, NULL))
                silent++;
            if (res == HLOD_OK)
                CHECK(hlod_mesh_validate(&m, p, NULL) == HLOD_OK);
            hlod_mesh_free(&m);
        }
    }
    CHECKF(silent == 0, "%d errors without a message naming the file", silent);
}

/* ---- materials and cleanup ---- */

static void missing_texture_warns_and_untextures(void)
{
    char p[256], mtl[256];
    write_text(tpath("tex.mtl", mtl), "newmtl a\nKd 1 0 0\nmap_Kd -s 1 1 1 missing tex.png\n"
                                      "newmtl b\nKd 0 1 0\n");
    write_text(tpath("tex.obj", p),
               "mtllib tex.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl a\nf 1 2 3\n"
               "usemtl b\nf 2 4 3\n");
    hlod_mesh m = {0};
    recorder r;
    hlod_import_stats st;
    CHECK(import_rec(p, &m, &st, &r, 0) == HLOD_OK);
    CHECK(st.missing_textures == 1);
    CHECK(logged(&r, HLOD_LOG_WARN, p, "missing tex.png"));
    CHECK(m.material_count == 2);
    if (m.material_count == 2) {
        CHECK(m.materials[0].texture_path == NULL);
        CHECK(m.materials[0].diffuse[0] == 1.0f && m.materials[0].diffuse[1] == 0.0f);
    }
    hlod_mesh_free(&m);
}

static void texture_resolves_against_mtl_folder(void)
{
    char sub[256], p[256], tex[256], mtl[256];
    tpath("sub", sub);
    mkdir(sub, 0755);
    write_text(tpath("sub/facade.jpg", tex), "x");
    write_text(tpath("sub/lib.mtl", mtl), "newmtl facade\nmap_Kd .\\facade.jpg\n");
    write_text(tpath("sub_ref.obj", p), "v 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl facade\nf 1 2 3\n"
                                        "mtllib sub/lib.mtl\n");
    hlod_mesh m = {0};
    recorder r;
    hlod_import_stats st;
    CHECK(import_rec(p, &m, &st, &r, 0) == HLOD_OK);
    CHECK(m.material_count == 1 && same_file(m.materials[0].texture_path, tex));
    CHECK(st.missing_textures == 0);
    hlod_mesh_free(&m);
}

static void obj_faces_forms_and_groups(void)
{
    char p[256];
    write_text(tpath("forms.obj", p),
               "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\n"
               "f 1 2 3\n"
               "o second\nf 1/1 2/2 3/3\n"
               "g third\nf 1//1 3//1 4//1\nf -4/-3/-1 -2/-1/-1 -1/-1/-1 \n"
               "f 1/1/1 2/2/1 3/3/1 4/3/1\n");
    hlod_mesh m = {0};
    recorder r;
    hlod_import_stats st;
    CHECK(import_rec(p, &m, &st, &r, 1) == HLOD_OK);
    CHECK(st.tris_read == 6);
    CHECK(m.object_count == 3);
    if (m.object_count == 3) {
        CHECK(strcmp(m.objects[0].name, "forms") == 0 && m.objects[0].tri_count == 1);
        CHECK(strcmp(m.objects[1].name, "second") == 0 && m.objects[1].tri_count == 1);
        CHECK(strcmp(m.objects[2].name, "third") == 0 && m.objects[2].tri_count == 4);
    }
    CHECK(m.uvs != NULL && m.normals != NULL);
    /* distinct (v, vt, vn): (1,-,-) (2,-,-) (3,-,-) | (1,1,-) (2,2,-) (3,3,-) |
     * (1,-,1) (3,-,1) (4,-,1) | (1,1,1) (3,2,1) (4,3,1) | (2,2,1) (3,3,1) (4,3,1)... */
    CHECKF(m.vertex_count == 13, "%zu vertices", m.vertex_count);
    hlod_mesh_free(&m);
}

static void degenerate_and_duplicate_triangles_dropped(void)
{
    char p[256];
    write_text(tpath("dups.obj", p),
               "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 0\nv 0.5 0 0\nv 5 5 5\n"
               "f 1 2 3\n"       /* kept */
               "f 2 3 1\n"       /* rotation: duplicate */
               "f 3 2 1\n"       /* other winding: duplicate */
               "f 4 2 3\n"       /* same positions, other vertex: duplicate */
               "f 1 1 2\n"       /* repeated index: degenerate */
               "f 1 4 3\n"       /* repeated position: degenerate */
               "f 1 5 2\n"       /* collinear, zero area: degenerate */
               "f 1 2 6\n");     /* kept */
    hlod_mesh m = {0};
    recorder r;
    hlod_import_stats st;
    CHECK(import_rec(p, &m, &st, &r, 0) == HLOD_OK);
    CHECK(st.tris_read == 8);
    CHECK(st.duplicate_dropped == 3);
    CHECK(st.degenerate_dropped == 3);
    CHECK(m.tri_count == 2);
    CHECKF(m.vertex_count == 4, "%zu vertices (unused ones are dropped)", m.vertex_count);
    CHECK(logged(&r, HLOD_LOG_INFO, p, "3 degenerate and 3 duplicate"));
    hlod_mesh_free(&m);
    CHECK(import_rec(p, &m, &st, &r, 1) == HLOD_OK);
    CHECK(m.tri_count == 8 && st.degenerate_dropped == 0);
    hlod_mesh_free(&m);
}

static void clean_keeps_objects_and_materials_consistent(void)
{
    hlod_mesh m = {0};
    CHECK(hlod_mesh_alloc(&m, 4, 6, HLOD_MESH_MATERIALS) == HLOD_OK);
    static const double pos[12] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 7, 7, 7};
    memcpy(m.positions, pos, sizeof pos);
    /* object a: t0 = (0,1,2); object b: t1, t2 degenerate (b ends empty);
     * object c: t3 = (2,1,0), the same triangle as a's t0 (another object:
     * kept), t4 = (1,2,0), a duplicate of t3 in c (dropped), t5 = (0,1,3) */
    static const uint32_t idx[18] = {0, 1, 2, 0, 0, 1, 1, 1, 2, 2, 1, 0, 1, 2, 0, 0, 1, 3};
    memcpy(m.indices, idx, sizeof idx);
    for (uint32_t t = 0; t < 6; t++)
        m.tri_material[t] = t % 2;
    m.material_count = 2;
    m.materials = calloc(2, sizeof *m.materials);
    m.object_count = 3;
    m.objects = calloc(3, sizeof *m.objects);
    m.objects[0] = (hlod_object){strdup("a"), 0, 1};
    m.objects[1] = (hlod_object){strdup("b"), 1, 2};
    m.objects[2] = (hlod_object){strdup("c"), 3, 3};
    CHECK(hlod_mesh_validate(&m, "mem", NULL) == HLOD_OK);
    size_t deg, dup;
    CHECK(hlod_mesh_clean(&m, &deg, &dup) == HLOD_OK);
    CHECKF(deg == 2 && dup == 1, "%zu degenerate, %zu duplicates", deg, dup);
    CHECK(m.tri_count == 3);
    CHECK(m.object_count == 2);
    if (m.object_count == 2) {
        CHECK(strcmp(m.objects[0].name, "a") == 0 && m.objects[0].tri_count == 1);
        CHECK(strcmp(m.objects[1].name, "c") == 0 && m.objects[1].first_tri == 1 &&
              m.objects[1].tri_count == 2);
    }
    CHECK(m.tri_material[0] == 0 && m.tri_material[1] == 1 && m.tri_material[2] == 1);
    CHECK(m.vertex_count == 4 && m.indices[8] == 3);
    CHECK(hlod_mesh_validate(&m, "mem", NULL) == HLOD_OK);
    hlod_mesh_free(&m);
}

/* ---- hlod_obj_stream: one object at a time ---- */

typedef struct stream_rec {
    hlod_mesh whole;            /* hlod_mesh_import's mesh of the file */
    size_t seen, wanted_seen, bad;
    size_t want_only;           /* SIZE_MAX: every object */
    hlod_obj_info info[8];
} stream_rec;

static int want_one(void *user, size_t k)
{
    stream_rec *s = user;
    return s->want_only == SIZE_MAX || k == s->want_only;
}

/* Each streamed object equals the whole import's object k: its triangles'
 * corners (positions, uvs, normals) and materials' colours, in order. */
static hlod_result check_object(void *user, const hlod_obj_info *info, const hlod_mesh *m)
{
    stream_rec *s = user;
    if (info->index < 8)
        s->info[info->index] = *info;
    s->seen++;
    if (!m)
        return HLOD_OK;
    s->wanted_seen++;
    const hlod_mesh *w = &s->whole;
    if (info->index >= w->object_count || m->object_count != 1 ||
        m->tri_count != w->objects[info->index].tri_count ||
        strcmp(m->objects[0].name, w->objects[info->index].name) != 0 || !m->uvs != !w->uvs ||
        !m->normals != !w->normals) {
        s->bad++;
        return HLOD_OK;
    }
    size_t t0 = w->objects[info->index].first_tri;
    for (size_t t = 0; t < m->tri_count; t++) {
        for (int c = 0; c < 3; c++) {
            uint32_t a = m->indices[3 * t + c], b = w->indices[3 * (t0 + t) + c];
            if (memcmp(m->positions + 3 * a, w->positions + 3 * b, 3 * sizeof(double)) ||
                (m->uvs && memcmp(m->uvs + 2 * a, w->uvs + 2 * b, 2 * sizeof(float))) ||
                (m->normals && memcmp(m->normals + 3 * a, w->normals + 3 * b, 3 * sizeof(float))))
                s->bad++;
        }
        const hlod_material *ma = &m->materials[m->tri_material[t]];
        const hlod_material *mb = &w->materials[w->tri_material[t0 + t]];
        if (memcmp(ma->diffuse, mb->diffuse, sizeof ma->diffuse) || strcmp(ma->name, mb->name))
            s->bad++;
    }
    return HLOD_OK;
}

static void obj_stream_matches_import(void)
{
    char p[128], mtl[128];
    write_text(tpath("stream.mtl", mtl), "newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n");
    /* faces before any o and usemtl; usemtl before mtllib; an empty
     * object; negative indices; a later object using an earlier one's
     * vertices; a duplicate (dropped) and the first object's triangle
     * again in the last (kept) */
    write_text(tpath("stream.obj", p),
               "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n"
               "f 1 2 3\nf 2 4 3\n"
               "usemtl red\no a\nv 10 0 0\nv 11 0 0\nv 10 1 0.5\n"
               "f -3/1/1 -2/2/1 -1/3/1\nf 5 6 7\n"
               "mtllib stream.mtl\no empty\ng b\nusemtl blue\nv 20 0 0\nv 21 0 0\nv 20 1 0\nv 21 1 1\n"
               "f 8//1 9//1 10//1 11//1\nf 8 10 9\n"
               "o c\nusemtl red\nf 1 2 11\nf 2 4 3\n");
    stream_rec s = {.want_only = SIZE_MAX};
    recorder r = {0};
    CHECK(import_rec(p, &s.whole, NULL, &r, 0) == HLOD_OK);
    CHECKF(s.whole.object_count == 4, "%zu objects", s.whole.object_count);
    hlod_obj_stream_desc d = {.want = want_one, .object = check_object, .user = &s};
    hlod_mesh mats = {0};
    CHECK(hlod_obj_stream(p, &d, &mats) == HLOD_OK);
    CHECKF(s.seen == 4 && s.wanted_seen == 4 && s.bad == 0, "%zu objects, %zu wanted, %zu differ",
           s.seen, s.wanted_seen, s.bad);
    CHECK(mats.material_count == s.whole.material_count && d.lines_kept[0] == 11);
    /* object b alone, holding only the lines it uses */
    CHECK(s.info[2].v.lo == 7 && s.info[2].v.hi == 11 && s.info[2].vn.lo == 0 && s.info[2].vn.hi == 1);
    stream_rec one = {.want_only = 2, .whole = s.whole};
    hlod_obj_stream_desc d1 = {.want = want_one, .object = check_object, .user = &one};
    d1.keep[0] = &s.info[2].v;
    d1.keep[1] = &s.info[2].vt;
    d1.keep[2] = &s.info[2].vn;
    d1.keep_n[0] = d1.keep_n[2] = 1;
    d1.keep_n[1] = 0; /* b uses no vt line: none kept */
    CHECK(hlod_obj_stream(p, &d1, &mats) == HLOD_OK);
    CHECKF(one.seen == 4 && one.wanted_seen == 1 && one.bad == 0 && d1.lines_kept[0] == 4 &&
           d1.lines_kept[1] == 0 && d1.lines_kept[2] == 1,
           "%zu objects, %zu wanted, %zu differ, %zu/%zu/%zu lines kept", one.seen, one.wanted_seen,
           one.bad, d1.lines_kept[0], d1.lines_kept[1], d1.lines_kept[2]);
    /* object c uses lines b's window does not hold: an error, not a guess */
    stream_rec bad = {.want_only = 3, .whole = s.whole};
    hlod_obj_stream_desc d2 = d1;
    d2.user = &bad;
    recorder r2 = {0};
    hlod_logger lg = {record, &r2};
    d2.logger = &lg;
    CHECK(hlod_obj_stream(p, &d2, &mats) == HLOD_ERR_IO);
    CHECK(logged(&r2, HLOD_LOG_ERROR, p, "was not kept"));
    hlod_mesh_free(&mats);
    hlod_mesh_free(&s.whole);
}

static void validate_reports_bad_ranges(void)
{
    hlod_mesh m = {0};
    CHECK(hlod_mesh_alloc(&m, 3, 1, HLOD_MESH_MATERIALS) == HLOD_OK);
    static const double pos[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    memcpy(m.positions, pos, sizeof pos);
    m.indices[0] = 0, m.indices[1] = 1, m.indices[2] = 2;
    m.tri_material[0] = 1;
    m.material_count = 1;
    m.materials = calloc(1, sizeof *m.materials);
    recorder r = {0};
    hlod_logger lg = {record, &r};
    CHECK(hlod_mesh_validate(&m, "x.obj", &lg) == HLOD_ERR_INDEX_RANGE);
    CHECK(logged(&r, HLOD_LOG_ERROR, "x.obj", "material 1"));
    m.tri_material[0] = 0;
    m.object_count = 1;
    m.objects = calloc(1, sizeof *m.objects);
    m.objects[0].tri_count = 2;
    CHECK(hlod_mesh_validate(&m, "x.obj", &lg) == HLOD_ERR_FORMAT);
    m.objects[0].tri_count = 1;
    m.indices[2] = 3;
    CHECK(hlod_mesh_validate(&m, "x.obj", &lg) == HLOD_ERR_INDEX_RANGE);
    m.indices[2] = 2;
    m.positions[4] = NAN;
    CHECK(hlod_mesh_validate(&m, "x.obj", &lg) == HLOD_ERR_NAN);
    CHECK(logged(&r, HLOD_LOG_ERROR, "x.obj", "vertex 1: coordinate is NaN"));
    hlod_mesh_free(&m);
}

/* ---- atomic export ---- */

static void export_to_unwritable_path_leaves_nothing(void)
{
    hlod_mesh m = {0};
    make_rich_mesh(&m, NULL);
    recorder r = {0};
    hlod_logger lg = {record, &r};
    static const char *const paths[] = {"/nonexistent/dir/x.obj", "/nonexistent/dir/x.ply",
                                        "/nonexistent/dir/x.off", "/nonexistent/dir/x.glb"};
    for (int i = 0; i < 4; i++) {
        CHECK(hlod_mesh_export(paths[i], &m, &lg) == HLOD_ERR_IO);
        CHECK(!exists(paths[i]));
        CHECK(logged(&r, HLOD_LOG_ERROR, paths[i], NULL));
    }
    CHECK(!exists("/nonexistent/dir/x.mtl"));
    hlod_mesh_free(&m);
}

static void failed_export_leaves_no_partial_file(void)
{
    char p[256], blocker[256], dir[256];
    hlod_mesh m = {0};
    make_rich_mesh(&m, NULL);
    /* The .mtl name is taken by a folder: the OBJ must not appear either. */
    mkdir(tpath("blocked.mtl", blocker), 0755);
    write_text(tpath("blocked.mtl/keep", dir), "x");
    CHECK(hlod_mesh_export(tpath("blocked.obj", p), &m, NULL) == HLOD_ERR_IO);
    CHECK(!exists(p));
    /* A target that is a non-empty folder: rename fails after writing. */
    mkdir(tpath("taken.ply", blocker), 0755);
    write_text(tpath("taken.ply/keep", dir), "x");
    CHECK(hlod_mesh_export(blocker, &m, NULL) == HLOD_ERR_IO);
    mkdir(tpath("taken.bin", blocker), 0755);
    write_text(tpath("taken.bin/keep", dir), "x");
    CHECK(hlod_mesh_export(tpath("taken.gltf", p), &m, NULL) == HLOD_ERR_IO);
    CHECK(!exists(p));
    CHECK(tmp_files() == 0);
    /* An invalid mesh is refused before any file is created. */
    m.positions[0] = NAN;
    CHECK(hlod_mesh_export(tpath("nan_export.ply", p), &m, NULL) == HLOD_ERR_NAN);
    CHECK(!exists(p));
    /* Overwriting an existing file replaces it whole. */
    m.positions[0] = 1;
    write_text(tpath("over.off", p), "old contents");
    CHECK(hlod_mesh_export(p, &m, NULL) == HLOD_OK);
    hlod_mesh back = {0};
    recorder r;
    CHECK(import_rec(p, &back, NULL, &r, 0) == HLOD_OK && back.tri_count == 4);
    CHECK(tmp_files() == 0);
    hlod_mesh_free(&back);
    hlod_mesh_free(&m);
}

/* ---- real meshes (data/fetch-meshes.sh) ---- */

static void check_real(const char *rel, size_t verts, size_t tris, hlod_mesh *m,
                       hlod_import_stats *st)
{
    char p[512];
    check_src_path(rel, p, sizeof p);
    CHECKF(exists(p), "%s missing: run data/fetch-meshes.sh", p);
    recorder r;
    hlod_result res = import_rec(p, m, st, &r, 1);
    CHECKF(res == HLOD_OK, "%s: %s", rel, hlod_result_str(res));
    if (res != HLOD_OK)
        dump_log(&r);
    if (verts)
        CHECKF(m->vertex_count == verts, "%s: %zu vertices, want %zu", rel, m->vertex_count,
               verts);
    CHECKF(m->tri_count == tris, "%s: %zu triangles, want %zu", rel, m->tri_count, tris);
    CHECK(st->tris_read == tris);
}

static void real_off_meshes(void)
{
    static const struct {
        const char *path;
        size_t v, t;
    } offs[] = {{"data/meshes/bunny00.off", 37706, 75408},
                {"data/meshes/fandisk.off", 6475, 12946},
                {"data/meshes/mech-holes-shark.off", 5246, 10192},
                {"data/meshes/elephant.off", 2775, 5558}};
    for (size_t i = 0; i < 4; i++) {
        hlod_mesh m = {0};
        hlod_import_stats st;
        check_real(offs[i].path, offs[i].v, offs[i].t, &m, &st);
        CHECK(m.object_count == 1 && hlod_mesh_area(&m) > 0);
        hlod_mesh_free(&m);
    }
}

static void real_textured_obj(void)
{
    hlod_mesh m = {0};
    hlod_import_stats st;
    check_real("data/meshes/spider.obj", 0, 1368, &m, &st);
    CHECK(st.missing_textures == 0);
    CHECK(m.uvs != NULL && m.normals != NULL);
    CHECKF(m.material_count == 4, "%zu materials", m.material_count);
    int textured = 0;
    for (size_t i = 0; i < m.material_count; i++)
        textured += m.materials[i].texture_path && exists(m.materials[i].texture_path);
    CHECK(textured == (int)m.material_count);
    CHECKF(m.object_count >= 15, "%zu objects", m.object_count);
    CHECK(hlod_mesh_validate(&m, "spider", NULL) == HLOD_OK);
    hlod_mesh_free(&m);
}

static void real_gltf2_textured(void)
{
    hlod_mesh m = {0};
    hlod_import_stats st;
    check_real("data/meshes/BoxTextured.gltf", 24, 12, &m, &st);
    CHECK(st.missing_textures == 0);
    CHECK(m.uvs != NULL && m.material_count >= 1 && m.object_count == 1);
    int found = 0;
    for (size_t i = 0; i < m.material_count; i++)
        found += m.materials[i].texture_path &&
                 strstr(m.materials[i].texture_path, "CesiumLogoFlat.png") &&
                 exists(m.materials[i].texture_path);
    CHECK(found == 1);
    /* The root node's matrix turns the box's y up into z: bounds stay a
     * unit cube centred on the origin. */
    double lo[3], hi[3];
    hlod_mesh_bounds(&m, lo, hi);
    for (int k = 0; k < 3; k++)
        CHECK(fabs(lo[k] + 0.5) < 1e-6 && fabs(hi[k] - 0.5) < 1e-6);
    hlod_mesh_free(&m);
}

static void real_glb_embedded_texture_falls_back(void)
{
    hlod_mesh m = {0};
    hlod_import_stats st;
    check_real("data/meshes/BoxTextured.glb", 24, 12, &m, &st);
    CHECK(st.missing_textures == 1);
    for (size_t i = 0; i < m.material_count; i++)
        CHECK(m.materials[i].texture_path == NULL);
    hlod_mesh_free(&m);
    check_real("data/meshes/2CylinderEngine.glb", 0, 121496, &m, &st);
    CHECKF(m.object_count > 10, "%zu objects", m.object_count);
    hlod_mesh_free(&m);
}

static void real_ply_meshes(void)
{
    hlod_mesh m = {0};
    hlod_import_stats st;
    check_real("data/meshes/cube_binary.ply", 8, 12, &m, &st);
    hlod_mesh_free(&m);
    check_real("data/meshes/cube_uv.ply", 24, 12, &m, &st);
    CHECK(m.uvs != NULL && m.normals != NULL);
    hlod_mesh_free(&m);
    check_real("data/meshes/Wuson.ply", 11184, 3732, &m, &st);
    CHECK(m.uvs != NULL);
    hlod_mesh_free(&m);
}

/* ---- texture images (image.h) ---- */

static void image_probe_and_read_real_texture(void)
{
    char p[512];
    check_src_path("data/meshes/SpiderTex.jpg", p, sizeof p);
    int w = 0, h = 0, c = 0;
    recorder r = {0};
    hlod_logger lg = {record, &r};
    CHECK(hlod_image_probe(p, &w, &h, &c, &lg) == HLOD_OK);
    CHECK(w > 0 && h > 0 && c == 3);
    hlod_image img = {0};
    CHECK(hlod_image_read(p, &img, &lg) == HLOD_OK);
    CHECK(img.width == w && img.height == h && img.channels == 3 && img.pixels);
    hlod_image_free(&img);
    check_src_path("data/meshes/CesiumLogoFlat.png", p, sizeof p);
    CHECK(hlod_image_read(p, &img, &lg) == HLOD_OK && img.width > 0);
    hlod_image_free(&img);
}

static void image_png_round_trip_is_exact(void)
{
    hlod_image a = {7, 5, 4, malloc(7 * 5 * 4)}, b = {0};
    for (int i = 0; i < 7 * 5 * 4; i++)
        a.pixels[i] = (uint8_t)(i * 37 + 11);
    char p[256];
    CHECK(hlod_image_write(tpath("rt.png", p), &a, NULL) == HLOD_OK);
    CHECK(hlod_image_read(p, &b, NULL) == HLOD_OK);
    CHECK(b.width == 7 && b.height == 5 && b.channels == 4);
    CHECK(b.pixels && memcmp(a.pixels, b.pixels, 7 * 5 * 4) == 0);
    CHECK(tmp_files() == 0);
    hlod_image_free(&a);
    hlod_image_free(&b);
}

static void image_errors_name_the_file(void)
{
    hlod_image img = {0};
    recorder r = {0};
    hlod_logger lg = {record, &r};
    char p[256];
    CHECK(hlod_image_read(tpath("none.png", p), &img, &lg) == HLOD_ERR_IO);
    CHECK(logged(&r, HLOD_LOG_ERROR, p, "No such file"));
    write_text(tpath("garbage.png", p), "this is not a png");
    CHECK(hlod_image_read(p, &img, &lg) == HLOD_ERR_FORMAT);
    CHECK(logged(&r, HLOD_LOG_ERROR, p, NULL));
    CHECK(img.pixels == NULL);
    hlod_image one = {1, 1, 3, malloc(3)};
    memset(one.pixels, 9, 3);
    CHECK(hlod_image_write("/nonexistent/dir/x.png", &one, &lg) == HLOD_ERR_IO);
    CHECK(logged(&r, HLOD_LOG_ERROR, "/nonexistent/dir/x.png", NULL));
    hlod_image_free(&one);
}

static void image_resize_keeps_flat_colour(void)
{
    hlod_image a = {16, 8, 3, malloc(16 * 8 * 3)}, b = {0};
    for (int i = 0; i < 16 * 8; i++) {
        a.pixels[3 * i] = 200;
        a.pixels[3 * i + 1] = 100;
        a.pixels[3 * i + 2] = 50;
    }
    CHECK(hlod_image_resize(&a, 4, 3, &b) == HLOD_OK);
    CHECK(b.width == 4 && b.height == 3 && b.channels == 3);
    for (int i = 0; b.pixels && i < 4 * 3; i++)
        CHECK(abs(b.pixels[3 * i] - 200) <= 1 && abs(b.pixels[3 * i + 1] - 100) <= 1 &&
              abs(b.pixels[3 * i + 2] - 50) <= 1);
    hlod_image_free(&b);
    CHECK(hlod_image_resize(&a, 0, 3, &b) == HLOD_ERR_INVALID_ARG && b.pixels == NULL);
    hlod_image_free(&a);
    hlod_image_free(&b);
}

/* Mean of src over [x0, x1) x [y0, y1) in texel units, partial texels by
 * their overlap: what an area-averaging minification must give. */
static double area_mean(const hlod_image *src, int ch, double x0, double x1, double y0, double y1)
{
    double sum = 0, area = 0;
    for (int y = (int)floor(y0); y < (int)ceil(y1) && y < src->height; y++)
        for (int x = (int)floor(x0); x < (int)ceil(x1) && x < src->width; x++) {
            double wx = fmin(x + 1, x1) - fmax(x, x0), wy = fmin(y + 1, y1) - fmax(y, y0);
            sum += wx * wy * src->pixels[((size_t)y * src->width + x) * src->channels + ch];
            area += wx * wy;
        }
    return sum / area;
}

static void image_shrink_averages_covered_area(void)
{
    /* noise, so any misplaced or mis-weighted texel shows */
    int sizes[][4] = {{64, 48, 32, 24}, {97, 61, 40, 17}, {50, 50, 7, 3}, {9, 5, 9, 2}, {33, 1, 4, 1}};
    uint32_t s = 12345;
    for (size_t k = 0; k < sizeof sizes / sizeof sizes[0]; k++)
        for (int c = 1; c <= 4; c++) {
            int W = sizes[k][0], H = sizes[k][1], w = sizes[k][2], h = sizes[k][3];
            hlod_image a = {W, H, c, malloc((size_t)W * H * c)}, b = {0};
            for (size_t i = 0; i < (size_t)W * H * c; i++) {
                s = s * 1664525u + 1013904223u;
                a.pixels[i] = (uint8_t)(s >> 24);
            }
            CHECK(hlod_image_resize(&a, w, h, &b) == HLOD_OK);
            CHECK(b.width == w && b.height == h && b.channels == c);
            int worst = 0;
            for (int y = 0; b.pixels && y < h; y++)
                for (int x = 0; x < w; x++)
                    for (int ch = 0; ch < c; ch++) {
                        double want = area_mean(&a, ch, x * (double)W / w, (x + 1) * (double)W / w,
                                                y * (double)H / h, (y + 1) * (double)H / h);
                        int d = abs(b.pixels[((size_t)y * w + x) * c + ch] - (int)lround(want));
                        worst = d > worst ? d : worst;
                    }
            CHECKF(worst <= 1, "%dx%d -> %dx%d, %d channels: off by %d", W, H, w, h, c, worst);
            hlod_image_free(&a);
            hlod_image_free(&b);
        }
}

int main(void)
{
    snprintf(tmpdir, sizeof tmpdir, "/tmp/hlod-test-mesh-io-XXXXXX");
    if (!mkdtemp(tmpdir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(obj_keeps_double_precision);
    RUN(float_path_would_lose_precision);
    RUN(binary_ply_keeps_double_precision);
    RUN(float_ply_reads_exact_floats);
    RUN(ascii_ply_keeps_double_precision);
    RUN(off_keeps_double_precision);
    RUN(number_parser_is_exact);
    RUN(obj_round_trip);
    RUN(ply_round_trip);
    RUN(off_round_trip);
    RUN(gltf_round_trip);
    RUN(glb_round_trip);
    RUN(gltf_keeps_object_centre_in_double);
    RUN(missing_file_is_io_error);
    RUN(nan_coordinate_is_nan_error);
    RUN(index_out_of_range_is_range_error);
    RUN(empty_mesh_is_empty_error);
    RUN(malformed_header_is_format_error);
    RUN(every_truncated_binary_ply_fails_cleanly);
    RUN(every_truncated_ascii_file_fails_or_reads);
    RUN(off_variants_read_normals_colours_and_uvs);
    RUN(mutated_files_never_crash);
    RUN(missing_texture_warns_and_untextures);
    RUN(texture_resolves_against_mtl_folder);
    RUN(obj_faces_forms_and_groups);
    RUN(degenerate_and_duplicate_triangles_dropped);
    RUN(clean_keeps_objects_and_materials_consistent);
    RUN(validate_reports_bad_ranges);
    RUN(export_to_unwritable_path_leaves_nothing);
    RUN(failed_export_leaves_no_partial_file);
    RUN(real_off_meshes);
    RUN(real_textured_obj);
    RUN(real_gltf2_textured);
    RUN(real_glb_embedded_texture_falls_back);
    RUN(real_ply_meshes);
    RUN(image_probe_and_read_real_texture);
    RUN(image_png_round_trip_is_exact);
    RUN(obj_stream_matches_import);
    RUN(image_errors_name_the_file);
    RUN(image_resize_keeps_flat_colour);
    RUN(image_shrink_averages_covered_area);
    remove_tree(tmpdir);
    return check_done();
}
