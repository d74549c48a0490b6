/*
 * hlod-gen-scene - scenes that grow by orders of magnitude, for scaling
 * runs (docs/hlod-gen-scene.md).
 *
 *   hlod-gen-scene --kind chessboard --tris N -o OUT.obj [--textured]
 *                  [--tile-tris T] [--size S] [--quiet]
 *
 * The chessboard of Klein et al. (Fig. 11) and Wand et al. (Fig. 6): a
 * flat board of 8 x 8 squares, S x S model units in the plane z = 0 from
 * the origin, made of g x g quads (2 g^2 triangles, g the multiple of 8 nearest sqrt(N / 2), at
 * least 8), written as tiles (one OBJ object a tile, about T triangles
 * each) so that hlod-build streams it object by object.  Untextured: each
 * tile is two objects, its white and its black squares, each with its
 * material's colour (the build's blocks keep one colour each).  Textured
 * (--textured): each tile one object mapped onto OUT_chess.png, the board's
 * 8 x 8 squares at 64 pixels each.  Beside it, OUT-reference.obj: the
 * whole board as 64 x 64 quads mapped onto the same image, the analytic
 * reference of either variant (build it and draw it with full detail:
 * no full-detail render of the big board is needed).
 *
 *   hlod-gen-scene --kind tree|molecule --tris N -o OUT.obj [--quiet]
 *
 * Chamberlain et al.'s two test models (Table 2), made procedurally
 * (scenes.h): a tree of about N triangles, a molecule of N / 800 spheres.
 *
 * Files are written through temporary files and renamed; a failure leaves
 * none of them.
 */
#include "atomic_file.h"
#include "cli.h"
#include "city.h"
#include "scenes.h"
#include "hlod/image.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define PROG "hlod-gen-scene"
#define SQUARE_PX 64    /* texture pixels of one square */

/* the two squares' colours (sRGB bytes; materials as bytes / 255) */
static const uint8_t LIGHT[3] = {230, 222, 200}, DARK[3] = {40, 46, 60};

typedef struct options {
    const char *kind, *out, *preset;
    size_t tris, tile_tris, copies;
    double size;            /* the board's side, model units */
    int textured, quiet, tile_given, size_given;
} options;

static void usage(FILE *fp)
{
    fprintf(fp,
            "usage: hlod-gen-scene --kind chessboard --tris N -o OUT.obj [options]\n"
            "       hlod-gen-scene --kind city --copies K -o OUT.obj [--preset P]\n"
            "       hlod-gen-scene --kind tree|molecule --tris N -o OUT.obj\n"
            "\n"
            "Writes a scene for scaling runs.  chessboard: a flat board of 8 x 8\n"
            "squares (Klein Fig. 11) of about N triangles in tiles, with OUT.mtl,\n"
            "and OUT-reference.obj, the same board as 64 x 64 textured quads.\n"
            "city: K copies of hlod-gen-city's city side by side (its textures\n"
            "once, in OUT_tex/).  tree and molecule: Chamberlain's test models\n"
            "(colour cubes, Table 2), made procedurally: a tree of about N\n"
            "triangles (leaves as quads), a ball of N / 800 spheres of 800\n"
            "triangles; materials in OUT.mtl.\n"
            "\n"
            "  --kind K          chessboard, city, tree or molecule\n"
            "  --copies K        city: copies, 1 to 10000, in rows of ceil(sqrt(K))\n"
            "  --preset P        city: default (default), small or tiny\n"
            "  --tris N          triangles, about (2 g^2, g a multiple of 8);\n"
            "                    128 to 4e9\n"
            "  -o, --output OUT  the OBJ to write (OUT.mtl and OUT_chess.png beside)\n"
            "  --textured        squares from a texture (OUT_chess.png); default:\n"
            "                    two materials' colours\n"
            "  --tile-tris T     triangles of a tile, about (default 20000)\n"
            "  --size S          the board's side in model units (default 256): more\n"
            "                    triangles make smaller ones on the same board\n"
            "  --quiet           no progress bar\n"
            "  -h, --help        show this help\n"
            "\n"
            "Exit status: 0 success, 1 failure (nothing written), 2 bad command line.\n");
}

static int parse(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    o->tile_tris = 20000;
    o->size = 256;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = NULL;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            exit(0);
        } else if (hlod_cli_match_flag(argc, argv, &i, "--kind", &v)) {
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a value", "--kind") * 0;
            if (strcmp(v, "chessboard") && strcmp(v, "city") && strcmp(v, "tree") &&
                strcmp(v, "molecule"))
                return hlod_cli_usage_error(
                           PROG, "--kind: '%s' is not chessboard, city, tree or molecule", v) * 0;
            o->kind = v;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--copies", &v)) {
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a value", "--copies") * 0;
            if (!hlod_cli_parse_size(PROG, "--copies", v, 1, 10000, &o->copies))
                return 0;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--preset", &v)) {
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a value", "--preset") * 0;
            hlod_city_desc probe = {0};
            if (!hlod_city_preset(v, &probe))
                return hlod_cli_usage_error(PROG, "--preset: '%s' is not default, small or tiny",
                                            v) * 0;
            o->preset = v;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--tris", &v)) {
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a value", "--tris") * 0;
            if (!hlod_cli_parse_size(PROG, "--tris", v, 128, 4000000000u, &o->tris))
                return 0;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--tile-tris", &v)) {
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a value", "--tile-tris") * 0;
            if (!hlod_cli_parse_size(PROG, "--tile-tris", v, 2, 1u << 30, &o->tile_tris))
                return 0;
            o->tile_given = 1;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--size", &v)) {
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a value", "--size") * 0;
            if (!hlod_cli_parse_double(PROG, "--size", v, 0, 1e7, HLOD_CLI_MIN_OPEN, &o->size))
                return 0;
            o->size_given = 1;
        } else if (hlod_cli_match_flag(argc, argv, &i, "-o", &v) ||
                   hlod_cli_match_flag(argc, argv, &i, "--output", &v)) {
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a value", "-o") * 0;
            o->out = v;
        } else if (!strcmp(a, "--textured")) {
            o->textured = 1;
        } else if (!strcmp(a, "--quiet")) {
            o->quiet = 1;
        } else {
            return hlod_cli_usage_error(PROG, "unknown argument '%s'", a) * 0;
        }
    }
    if (!o->kind)
        return hlod_cli_usage_error(PROG, "%s is required (see --help)", "--kind") * 0;
    int city = !strcmp(o->kind, "city");
    if (!city && !o->tris)
        return hlod_cli_usage_error(PROG, "%s is required (see --help)", "--tris") * 0;
    if (city && !o->copies)
        return hlod_cli_usage_error(PROG, "%s is required (see --help)", "--copies") * 0;
    if (city ? o->tris != 0 : o->copies != 0)
        return hlod_cli_usage_error(PROG, "%s does not go with this --kind",
                                    city ? "--tris" : "--copies") * 0;
    int model = !strcmp(o->kind, "tree") || !strcmp(o->kind, "molecule");
    if (model && (o->textured || o->tile_given || o->size_given))
        return hlod_cli_usage_error(PROG, "--textured, --tile-tris and --size go with "
                                    "--kind chessboard only, not %s", o->kind) * 0;
    if (!o->out)
        return hlod_cli_usage_error(PROG, "%s is required (see --help)", "-o OUT.obj") * 0;
    size_t n = strlen(o->out);
    if (n < 5 || strcmp(o->out + n - 4, ".obj"))
        return hlod_cli_usage_error(PROG, "-o: '%s' does not end in .obj", o->out) * 0;
    return 1;
}

/* The path beside OUT.obj with `suffix` in place of ".obj"; its name
 * alone (for references inside the files) in *base. */
static char *beside(const char *out, const char *suffix, const char **base)
{
    size_t n = strlen(out) - 4;
    char *p = malloc(n + strlen(suffix) + 1);
    if (!p)
        return NULL;
    memcpy(p, out, n);
    strcpy(p + n, suffix);
    const char *slash = strrchr(p, '/');
    *base = slash ? slash + 1 : p;
    return p;
}

/* The board's 8 x 8 squares at SQUARE_PX pixels each, top row first
 * (v = 0, the board's y = 0, at the bottom). */
static hlod_result write_texture(const char *path, const hlod_logger *lg)
{
    hlod_image img = {8 * SQUARE_PX, 8 * SQUARE_PX, 3, NULL};
    img.pixels = malloc((size_t)img.width * img.height * 3);
    if (!img.pixels)
        return HLOD_ERR_NOMEM;
    for (int y = 0; y < img.height; y++)
        for (int x = 0; x < img.width; x++) {
            int sx = x / SQUARE_PX, sy = (img.height - 1 - y) / SQUARE_PX;
            memcpy(img.pixels + ((size_t)y * img.width + x) * 3, (sx + sy) % 2 ? LIGHT : DARK, 3);
        }
    /* OpenImageIO picks the format by the extension: a temporary name
     * that keeps it, renamed when written */
    char tmp[4096 + 32];
    snprintf(tmp, sizeof tmp, "%.4096s.tmp-%d.png", path, (int)getpid());
    hlod_result r = hlod_image_write(tmp, &img, lg);
    free(img.pixels);
    if (r == HLOD_OK && rename(tmp, path) != 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot rename into place: %s", path, strerror(errno));
        r = HLOD_ERR_IO;
    }
    if (r != HLOD_OK)
        unlink(tmp);
    return r;
}

static void write_mtl(FILE *fp, const char *png)
{
    fprintf(fp, "# hlod-gen-scene chessboard\n");
    fprintf(fp, "newmtl light\nKd %.6f %.6f %.6f\n\n", LIGHT[0] / 255.0, LIGHT[1] / 255.0,
            LIGHT[2] / 255.0);
    fprintf(fp, "newmtl dark\nKd %.6f %.6f %.6f\n\n", DARK[0] / 255.0, DARK[1] / 255.0,
            DARK[2] / 255.0);
    fprintf(fp, "newmtl chess\nKd 1 1 1\nmap_Kd %s\n", png);
}

/* The board: tiles of t x t quads (the last ones narrower), row by row. */
static int write_board(FILE *fp, const options *o, size_t g, const char *mtl, hlod_cli_progress *bar)
{
    size_t t = (size_t)floor(sqrt((double)o->tile_tris / 2));
    t = t < 1 ? 1 : t > g ? g : t;
    size_t tiles = (g + t - 1) / t, sq = g / 8;
    double q = o->size / (double)g;
    fprintf(fp, "# hlod-gen-scene chessboard: %zu x %zu quads, %zu triangles, %zu x %zu tiles\n",
            g, g, 2 * g * g, tiles, tiles);
    fprintf(fp, "mtllib %s\n", mtl);
    unsigned long long base = 0;
    for (size_t ty = 0; ty < tiles; ty++)
        for (size_t tx = 0; tx < tiles; tx++) {
            size_t x0 = tx * t, y0 = ty * t, x1 = x0 + t < g ? x0 + t : g, y1 = y0 + t < g ? y0 + t : g;
            size_t w = x1 - x0 + 1;
            for (size_t y = y0; y <= y1; y++)
                for (size_t x = x0; x <= x1; x++) {
                    fprintf(fp, "v %.17g %.17g 0\n", x == g ? o->size : (double)x * q,
                            y == g ? o->size : (double)y * q);
                    if (o->textured)
                        fprintf(fp, "vt %.9g %.9g\n", (double)x / (double)g, (double)y / (double)g);
                }
            for (int pass = 0; pass < (o->textured ? 1 : 2); pass++) {
                fprintf(fp, "o tile_%zu_%zu%s\nusemtl %s\n", tx, ty,
                        o->textured ? "" : pass ? "_dark" : "_light",
                        o->textured ? "chess" : pass ? "dark" : "light");
                for (size_t y = y0; y < y1; y++)
                    for (size_t x = x0; x < x1; x++) {
                        int light = ((x / sq) + (y / sq)) % 2 != 0;
                        if (!o->textured && light != (pass == 0))
                            continue;
                        unsigned long long a = base + (y - y0) * w + (x - x0) + 1, b = a + 1,
                                           c = a + w, d = c + 1;
                        if (o->textured)
                            fprintf(fp, "f %llu/%llu %llu/%llu %llu/%llu\nf %llu/%llu %llu/%llu %llu/%llu\n",
                                    a, a, b, b, d, d, a, a, d, d, c, c);
                        else
                            fprintf(fp, "f %llu %llu %llu\nf %llu %llu %llu\n", a, b, d, a, d, c);
                    }
            }
            base += (unsigned long long)w * (y1 - y0 + 1);
            if (ferror(fp))
                return 0;
            hlod_cli_progress_fn(bar, (double)(ty * tiles + tx + 1), (double)(tiles * tiles));
        }
    return 1;
}

/* The reference: the board as REF_N x REF_N quads mapped onto the
 * texture: few enough to draw at any board size, fine enough that the
 * renderer's per-vertex light matches the board's. */
#define REF_N 64

static void write_reference(FILE *fp, const options *o, const char *mtl)
{
    double s = o->size;
    fprintf(fp, "# hlod-gen-scene chessboard reference: %d x %d textured quads\n", REF_N, REF_N);
    fprintf(fp, "mtllib %s\no board\nusemtl chess\n", mtl);
    for (int y = 0; y <= REF_N; y++)
        for (int x = 0; x <= REF_N; x++) {
            fprintf(fp, "v %.17g %.17g 0\n", x == REF_N ? s : s * x / REF_N,
                    y == REF_N ? s : s * y / REF_N);
            fprintf(fp, "vt %.9g %.9g\n", (double)x / REF_N, (double)y / REF_N);
        }
    for (int y = 0; y < REF_N; y++)
        for (int x = 0; x < REF_N; x++) {
            int a = y * (REF_N + 1) + x + 1, b = a + 1, c = a + REF_N + 1, d = c + 1;
            fprintf(fp, "f %d/%d %d/%d %d/%d\nf %d/%d %d/%d %d/%d\n", a, a, b, b, d, d, a, a, d,
                    d, c, c);
        }
}

/* ---- the city, copied ---- */

/* The city's materials, texture paths relative to the OBJ's folder. */
static void write_city_mtl(FILE *fp, const hlod_mesh *m, const char *obj_path)
{
    const char *slash = strrchr(obj_path, '/');
    size_t dir = slash ? (size_t)(slash - obj_path) + 1 : 0;
    fprintf(fp, "# hlod-gen-scene materials\n");
    for (size_t i = 0; i < m->material_count; i++) {
        const hlod_material *mt = &m->materials[i];
        fprintf(fp, "newmtl m%zu\nKd %.6f %.6f %.6f\n", i, mt->diffuse[0], mt->diffuse[1],
                mt->diffuse[2]);
        if (mt->texture_path)
            fprintf(fp, "map_Kd %s\n", strncmp(mt->texture_path, obj_path, dir) ? mt->texture_path
                                                                             : mt->texture_path + dir);
        fputc('\n', fp);
    }
}

/* m moved by off, its objects named NAME_cK (copy k of a city), or NAME
 * when suffix is NULL; base: the vertices written before. */
static int write_mesh(FILE *fp, const hlod_mesh *m, const char *suffix, const double off[2],
                      unsigned long long base)
{
    for (size_t v = 0; v < m->vertex_count; v++) {
        const double *p = &m->positions[3 * v];
        fprintf(fp, "v %.17g %.17g %.17g\n", p[0] + off[0], p[1] + off[1], p[2]);
        if (m->uvs)
            fprintf(fp, "vt %.9g %.9g\n", m->uvs[2 * v], m->uvs[2 * v + 1]);
    }
    size_t nobj = m->object_count ? m->object_count : 1;
    for (size_t o = 0; o < nobj; o++) {
        size_t t0 = m->object_count ? m->objects[o].first_tri : 0;
        size_t t1 = t0 + (m->object_count ? m->objects[o].tri_count : m->tri_count);
        const char *name = m->object_count && m->objects[o].name ? m->objects[o].name : "city";
        fprintf(fp, "o %s%s\n", name, suffix ? suffix : "");
        uint32_t cur = UINT32_MAX;
        for (size_t t = t0; t < t1; t++) {
            uint32_t mat = m->tri_material ? m->tri_material[t] : 0;
            if (mat != cur && mat < m->material_count) {
                fprintf(fp, "usemtl m%u\n", mat);
                cur = mat;
            }
            unsigned long long a = base + m->indices[3 * t] + 1, b = base + m->indices[3 * t + 1] + 1,
                               c = base + m->indices[3 * t + 2] + 1;
            if (m->uvs)
                fprintf(fp, "f %llu/%llu %llu/%llu %llu/%llu\n", a, a, b, b, c, c);
            else
                fprintf(fp, "f %llu %llu %llu\n", a, b, c);
        }
    }
    return !ferror(fp);
}

static int gen_city(const options *o, hlod_cli_progress *bar, const hlod_logger *lg)
{
    hlod_city_desc d = {0};
    hlod_city_preset(o->preset ? o->preset : "default", &d);
    d.seed = 1;
    const char *tex_base;
    char *tex_dir = beside(o->out, "_tex", &tex_base), *mtl_base_path = NULL;
    const char *mtl_base;
    mtl_base_path = beside(o->out, ".mtl", &mtl_base);
    if (!tex_dir || !mtl_base_path) {
        free(tex_dir);
        free(mtl_base_path);
        return 0;
    }
    d.texture_dir = tex_dir;
    d.logger = lg;
    hlod_mesh city = {0};
    hlod_city_stats cs;
    hlod_result r = hlod_city_generate(&d, &city, &cs);
    hlod_atomic_file fo = {0}, fm = {0};
    if (r != HLOD_OK)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot generate the city: %s", o->out,
                  hlod_result_str(r));
    if (r == HLOD_OK)
        r = hlod_atomic_open(&fm, mtl_base_path, lg);
    if (r == HLOD_OK)
        r = hlod_atomic_open(&fo, o->out, lg);
    if (r == HLOD_OK) {
        double lo[3], hi[3];
        hlod_mesh_bounds(&city, lo, hi);
        double dx = (hi[0] - lo[0]) * 1.05, dy = (hi[1] - lo[1]) * 1.05;
        size_t cols = (size_t)ceil(sqrt((double)o->copies));
        write_city_mtl(fm.fp, &city, o->out);
        fprintf(fo.fp, "# hlod-gen-scene city: %zu copies of %zu triangles\nmtllib %s\n",
                o->copies, city.tri_count, mtl_base);
        for (size_t k = 0; k < o->copies && r == HLOD_OK; k++) {
            double off[2] = {(double)(k % cols) * dx, (double)(k / cols) * dy};
            char suffix[32];
            snprintf(suffix, sizeof suffix, "_c%zu", k);
            if (!write_mesh(fo.fp, &city, suffix, off, (unsigned long long)k * city.vertex_count)) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write: %s", o->out, strerror(errno));
                r = HLOD_ERR_IO;
            }
            hlod_cli_progress_fn(bar, (double)(k + 1), (double)o->copies);
        }
    }
    int committed = 0;
    if (r == HLOD_OK && (r = hlod_atomic_commit(&fm, lg)) == HLOD_OK)
        committed = 1;
    if (r == HLOD_OK)
        r = hlod_atomic_commit(&fo, lg);
    hlod_atomic_abort(&fm);
    hlod_atomic_abort(&fo);
    if (r != HLOD_OK) {
        if (committed)
            unlink(mtl_base_path);
        hlod_rm_tree(tex_dir);
    } else if (!o->quiet) {
        hlod_cli_progress_clear(bar);
        fprintf(stderr, "%s: %s: %zu copies of a %zu-triangle city, %zu triangles\n", PROG,
                o->out, o->copies, city.tri_count, o->copies * city.tri_count);
    }
    hlod_mesh_free(&city);
    free(tex_dir);
    free(mtl_base_path);
    return r == HLOD_OK;
}

/* A tree or a molecule (scenes.h), with its materials beside it. */
static int gen_model(const options *o, const hlod_logger *lg)
{
    int tree = !strcmp(o->kind, "tree");
    if (!tree && o->tris / 800 > (UINT32_MAX - 1) / 402) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %zu triangles of spheres: more vertices than one "
                  "mesh indexes", o->out, o->tris);
        return 0;
    }
    const char *mtl_base;
    char *mtl = beside(o->out, ".mtl", &mtl_base);
    hlod_mesh m = {0};
    hlod_result r = mtl ? (tree ? hlod_scene_tree(o->tris, 1, &m) : hlod_scene_molecule(o->tris, 1, &m))
                        : HLOD_ERR_NOMEM;
    if (r != HLOD_OK)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot make the %s: %s", o->out, o->kind,
                  hlod_result_str(r));
    hlod_atomic_file fo = {0}, fm = {0};
    if (r == HLOD_OK)
        r = hlod_atomic_open(&fm, mtl, lg);
    if (r == HLOD_OK)
        r = hlod_atomic_open(&fo, o->out, lg);
    if (r == HLOD_OK) {
        write_city_mtl(fm.fp, &m, o->out);
        fprintf(fo.fp, "# hlod-gen-scene %s: %zu triangles\nmtllib %s\n", o->kind, m.tri_count,
                mtl_base);
        if (!write_mesh(fo.fp, &m, NULL, (const double[2]){0, 0}, 0)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write: %s", o->out, strerror(errno));
            r = HLOD_ERR_IO;
        }
    }
    int committed = 0;
    if (r == HLOD_OK && (r = hlod_atomic_commit(&fm, lg)) == HLOD_OK)
        committed = 1;
    if (r == HLOD_OK)
        r = hlod_atomic_commit(&fo, lg);
    hlod_atomic_abort(&fm);
    hlod_atomic_abort(&fo);
    if (r != HLOD_OK && committed)
        unlink(mtl);
    if (r == HLOD_OK && !o->quiet)
        fprintf(stderr, "%s: %s: a %s of %zu triangles\n", PROG, o->out, o->kind, m.tri_count);
    hlod_mesh_free(&m);
    free(mtl);
    return r == HLOD_OK;
}

int main(int argc, char **argv)
{
    options o;
    if (!parse(argc, argv, &o))
        return 2;
    hlod_cli_progress bar;
    hlod_cli_progress_begin(&bar, "tiles", !o.quiet);
    hlod_cli_log ls = {PROG, o.quiet ? HLOD_LOG_ERROR : HLOD_LOG_WARN, &bar};
    hlod_logger lg = hlod_cli_logger(&ls);
    if (!strcmp(o.kind, "tree") || !strcmp(o.kind, "molecule")) {
        int ok = gen_model(&o, &lg);
        hlod_cli_progress_clear(&bar);
        return ok ? 0 : 1;
    }
    if (!strcmp(o.kind, "city")) {
        int ok = gen_city(&o, &bar, &lg);
        hlod_cli_progress_clear(&bar);
        return ok ? 0 : 1;
    }
    size_t g = (size_t)llround(sqrt((double)o.tris / 2) / 8) * 8;
    g = g < 8 ? 8 : g;
    const char *mtl_base, *png_base, *ref_base;
    char *mtl = beside(o.out, ".mtl", &mtl_base), *png = beside(o.out, "_chess.png", &png_base),
         *ref = beside(o.out, "-reference.obj", &ref_base);
    hlod_atomic_file fo = {0}, fm = {0}, fr = {0};
    hlod_result r = mtl && png && ref ? HLOD_OK : HLOD_ERR_NOMEM;
    if (r == HLOD_OK)
        r = write_texture(png, &lg);
    if (r == HLOD_OK)
        r = hlod_atomic_open(&fm, mtl, &lg);
    if (r == HLOD_OK)
        r = hlod_atomic_open(&fr, ref, &lg);
    if (r == HLOD_OK)
        r = hlod_atomic_open(&fo, o.out, &lg);
    if (r == HLOD_OK) {
        write_mtl(fm.fp, png_base);
        write_reference(fr.fp, &o, mtl_base);
        if (!write_board(fo.fp, &o, g, mtl_base, &bar)) {
            hlod_logf(&lg, HLOD_LOG_ERROR, "%s: cannot write: %s", o.out, strerror(errno));
            r = HLOD_ERR_IO;
        }
    }
    hlod_cli_progress_clear(&bar);
    /* the board last: its .mtl and image are in place when it appears;
     * a failure takes back what was committed */
    int committed = 0;
    if (r == HLOD_OK && (r = hlod_atomic_commit(&fm, &lg)) == HLOD_OK)
        committed = 1;
    if (r == HLOD_OK && (r = hlod_atomic_commit(&fr, &lg)) == HLOD_OK)
        committed = 2;
    if (r == HLOD_OK)
        r = hlod_atomic_commit(&fo, &lg);
    hlod_atomic_abort(&fo);
    hlod_atomic_abort(&fm);
    hlod_atomic_abort(&fr);
    if (r != HLOD_OK) {
        if (png)
            unlink(png);
        if (committed >= 1)
            unlink(mtl);
        if (committed >= 2)
            unlink(ref);
        free(mtl);
        free(png);
        free(ref);
        return 1;
    }
    if (!o.quiet)
        fprintf(stderr, "%s: %s: chessboard of %zu triangles (%zu x %zu quads), %s\n", PROG, o.out,
                2 * g * g, g, g, o.textured ? "textured" : "two colours");
    free(mtl);
    free(png);
    free(ref);
    return 0;
}
