/*
 * hlod-gen-city: write the synthetic test city (preprocess/city.h).
 *
 *   hlod-gen-city -o OUT.{obj,gltf,glb} [--preset default|small|tiny]
 *                 [--blocks N] [--tris-per-block M] [--texture-size S]
 *                 [--seed K] [--origin X Y Z] [--untextured] [--style scan|parts] [--paths DIR]
 *                 [--json] [--quiet]
 *   hlod-gen-city --paths DIR [--preset P] [--blocks N] [--origin X Y Z]
 *
 * --paths writes the built-in camera paths for this city's streets
 * (preprocess/city_paths.h) to DIR/NAME.path, after the mesh; without -o
 * it writes only the paths (in milliseconds).
 *
 * Textures go to OUT's stem + "_tex/" (block_0000.png ..., ground.png), each
 * through a temporary file; the mesh is written last, so it is the commit
 * point: a failure never leaves a mesh that names missing or stale
 * textures, and a texture folder this run created is removed again.
 *
 * Exit status: 0 success, 1 generation or writing failed, 2 bad command
 * line.
 */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "../city.h"
#include "../city_paths.h"
#include "cli.h"
#include "hlod/mesh_io.h"

static const char *const PROG = "hlod-gen-city";

static void usage(FILE *fp)
{
    fprintf(fp,
        "usage: hlod-gen-city -o OUT.{obj,gltf,glb} [--preset default|small|tiny]\n"
        "                     [--blocks N] [--tris-per-block M] [--texture-size S]\n"
        "                     [--seed K] [--origin X Y Z] [--untextured] [--style scan|parts]\n"
        "                     [--paths DIR]\n"
        "                     [--json] [--quiet]\n"
        "       hlod-gen-city --paths DIR [--preset P] [--blocks N] [--origin X Y Z]\n"
        "\n"
        "Writes a synthetic city: N blocks of buildings on a street grid, each block\n"
        "one object (block_0000, ...) with dense, scan-like facades (window recesses,\n"
        "string courses, cornices, parapets, a few cm of noise), plus an object\n"
        "'ground' with streets and pavements.  z is up, units are metres.  The same\n"
        "flags give byte-identical files.\n"
        "\n"
        "  -o, --output OUT     .obj (+ .mtl; double positions, the preferred format),\n"
        "                       .gltf (+ .bin) or .glb; textures go to OUT's stem +\n"
        "                       '_tex/'\n"
        "  --preset P           default: 200 blocks x 35000 triangles (7M), 1024^2\n"
        "                       textures: 210M texels like the seed paper's city, yet\n"
        "                       about 0.6 GiB decoded, and 1024 keeps one block's\n"
        "                       facades near 8 texels per metre;\n"
        "                       small: 8 x 5500 (about 50k with the ground), 256^2;\n"
        "                       tiny: 2 x 2500, 64^2 (unit tests).\n"
        "                       Flags given explicitly override the preset.\n"
        "  --blocks N           number of blocks (1..1000000)\n"
        "  --tris-per-block M   triangle budget per block, met within 10%% by the\n"
        "                       facade density (the ground comes on top)\n"
        "  --texture-size S     atlas side per block and of the ground tile, pixels\n"
        "                       (16..16384)\n"
        "  --seed K             random seed (default 1)\n"
        "  --origin X Y Z       added to every position exactly; the city is centred\n"
        "                       on (X, Y) with its ground at Z, e.g. 5e5 4.1e6 0\n"
        "  --untextured         no UVs and no textures; one diffuse colour per block\n"
        "  --style S            scan (default): each building one closed surface of\n"
        "                       dense facades; parts: each building many separate\n"
        "                       boxes (wall piers and spandrels, floor slabs, window\n"
        "                       frames and panes, parapets), as BIM exports are;\n"
        "                       untextured\n"
        "  --paths DIR          also write the built-in camera paths for this city's\n"
        "                       streets to DIR/NAME.path (walk, walk-drive,\n"
        "                       walk-to-fly, fly, orbit, still; model coordinates,\n"
        "                       origin included); without -o only the paths\n"
        "  --json               print one JSON object on stdout: blocks, tris,\n"
        "                       vertices, textures, texture_pixels, bytes_written,\n"
        "                       seconds, origin and more\n"
        "  --quiet              no summary, no progress bar, errors only\n"
        "  -h, --help           show this help\n"
        "\n"
        "Exit status: 0 success, 1 failure, 2 bad command line.\n");
}

typedef struct options {
    const char *out;
    const char *preset;
    const char *paths;
    int have_blocks, have_tris, have_size;
    size_t blocks, tris, size, seed;
    double origin[3];
    int untextured, json, quiet, parts;
} options;

static int match_flag(int argc, char **argv, int *i, const char *flag, const char **value)
{
    return hlod_cli_match_flag(argc, argv, i, flag, value);
}

static int usage_error(const char *fmt, const char *arg)
{
    return hlod_cli_usage_error(PROG, fmt, arg);
}

static int parse_args(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    o->seed = 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = NULL;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return -1;
        } else if (!strcmp(a, "--untextured")) {
            o->untextured = 1;
        } else if (!strcmp(a, "--json")) {
            o->json = 1;
        } else if (!strcmp(a, "--quiet")) {
            o->quiet = 1;
        } else if (!strcmp(a, "--origin")) {
            static const char *const names[3] = {"--origin X", "--origin Y", "--origin Z"};
            if (i + 3 >= argc)
                return usage_error("%s needs three numbers X Y Z", a);
            for (int k = 0; k < 3; k++)
                if (!hlod_cli_parse_double(PROG, names[k], argv[++i], -1e9, 1e9, 0, &o->origin[k]))
                    return 2;
        } else if (match_flag(argc, argv, &i, "-o", &v) ||
                   match_flag(argc, argv, &i, "--output", &v)) {
            if (!v || !*v)
                return usage_error("%s needs an output file name", a);
            o->out = v;
        } else if (match_flag(argc, argv, &i, "--style", &v)) {
            if (v && !strcmp(v, "parts"))
                o->parts = 1;
            else if (!v || strcmp(v, "scan"))
                return usage_error("--style: '%s' is not scan or parts", v ? v : "");
        } else if (match_flag(argc, argv, &i, "--paths", &v)) {
            if (!v || !*v)
                return usage_error("%s needs a folder name", a);
            o->paths = v;
        } else if (match_flag(argc, argv, &i, "--preset", &v)) {
            hlod_city_desc probe = {0};
            if (!v || !hlod_city_preset(v, &probe))
                return usage_error("--preset: '%s' is not one of default, small, tiny",
                                   v ? v : "");
            o->preset = v;
        } else if (match_flag(argc, argv, &i, "--blocks", &v)) {
            if (!hlod_cli_parse_size(PROG, "--blocks", v, 1, 1000000, &o->blocks))
                return 2;
            o->have_blocks = 1;
        } else if (match_flag(argc, argv, &i, "--tris-per-block", &v)) {
            if (!hlod_cli_parse_size(PROG, "--tris-per-block", v, 1, 100000000, &o->tris))
                return 2;
            o->have_tris = 1;
        } else if (match_flag(argc, argv, &i, "--texture-size", &v)) {
            if (!hlod_cli_parse_size(PROG, "--texture-size", v, 16, 16384, &o->size))
                return 2;
            o->have_size = 1;
        } else if (match_flag(argc, argv, &i, "--seed", &v)) {
            if (!hlod_cli_parse_size(PROG, "--seed", v, 0, SIZE_MAX, &o->seed))
                return 2;
        } else if (a[0] == '-' && a[1] != 0) {
            return usage_error("unknown option '%s'", a);
        } else {
            return usage_error("unexpected argument '%s'", a);
        }
    }
    if (!o->out && o->paths)
        return 0;
    if (!o->out)
        return usage_error("%s", "no output file given (-o OUT.obj)");
    const char *slash = strrchr(o->out, '/');
    const char *dot = strrchr(o->out, '.');
    if (!dot || (slash && dot < slash) || dot[1] == 0)
        return usage_error("%s: give an extension: .obj, .gltf or .glb", o->out);
    if (strcmp(dot, ".obj") && strcmp(dot, ".gltf") && strcmp(dot, ".glb"))
        return usage_error("%s: unsupported output format; use .obj, .gltf or .glb (PLY and "
                           "OFF cannot hold one object per block with textures)",
                           o->out);
    return 0;
}

/* OUT's stem + suffix ("out/city.obj" -> "out/city_tex"). */
static char *stem_with(const char *path, const char *suffix)
{
    const char *dot = strrchr(path, '.');
    size_t stem = (size_t)(dot - path), n = strlen(suffix);
    char *p = malloc(stem + n + 1);
    if (p) {
        memcpy(p, path, stem);
        memcpy(p + stem, suffix, n + 1);
    }
    return p;
}

static int output_folder_ok(const char *out)
{
    struct stat st;
    if (stat(out, &st) == 0 && S_ISDIR(st.st_mode)) {
        hlod_cli_error(PROG, "%s: output is a folder; give a file name", out);
        return 0;
    }
    size_t n = strlen(out);
    char *dir = malloc(n + 2);
    if (!dir)
        return 0;
    memcpy(dir, out, n + 1);
    char *slash = strrchr(dir, '/');
    if (!slash)
        strcpy(dir, ".");
    else if (slash == dir)
        dir[1] = 0;
    else
        *slash = 0;
    int ok = stat(dir, &st) == 0 && S_ISDIR(st.st_mode);
    if (!ok)
        hlod_cli_error(PROG, "%s: output folder '%s' does not exist", out, dir);
    free(dir);
    return ok;
}

static uint64_t file_size(const char *path)
{
    struct stat st;
    return path && stat(path, &st) == 0 ? (uint64_t)st.st_size : 0;
}

/* Removes what this run wrote into a texture folder it created. */
static void remove_textures(const char *dir, size_t blocks)
{
    size_t n = strlen(dir) + 32;
    char *p = malloc(n);
    if (!p)
        return;
    for (size_t b = 0; b < blocks; b++) {
        snprintf(p, n, "%s/block_%04zu.png", dir, b);
        unlink(p);
    }
    snprintf(p, n, "%s/ground.png", dir);
    unlink(p);
    free(p);
    rmdir(dir);
}

/* The camera paths for d's streets into o->paths; 1 on success. */
static int write_paths(const options *o, const hlod_city_desc *d)
{
    hlod_cli_log log_state = {PROG, o->quiet ? HLOD_LOG_ERROR : HLOD_LOG_WARN, NULL};
    hlod_logger lg = hlod_cli_logger(&log_state);
    hlod_result r = hlod_city_paths_write(d, o->paths, &lg);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot write the camera paths: %s", o->paths,
                       hlod_result_str(r));
        return 0;
    }
    if (!o->quiet)
        fprintf(stderr, "%s: %s: %d camera paths for %zu blocks\n", PROG, o->paths,
                HLOD_CITY_PATH_COUNT, d->blocks);
    if (o->json && !o->out) {
        hlod_json j;
        hlod_json_begin(&j, stdout);
        hlod_json_string(&j, "paths_dir", o->paths);
        hlod_json_int(&j, "paths", HLOD_CITY_PATH_COUNT);
        hlod_json_size(&j, "blocks", d->blocks);
        if (hlod_json_end(&j) != 0) {
            hlod_cli_error(PROG, "cannot write the JSON record to standard output");
            return 0;
        }
    }
    return 1;
}

int main(int argc, char **argv)
{
    options o;
    int rc = parse_args(argc, argv, &o);
    if (rc < 0)
        return 0;
    if (rc)
        return rc;
    if (o.out && !output_folder_ok(o.out))
        return 1;

    hlod_city_desc d = {0};
    hlod_city_preset(o.preset ? o.preset : "default", &d);
    if (o.have_blocks)
        d.blocks = o.blocks;
    if (o.have_tris)
        d.tris_per_block = o.tris;
    if (o.have_size)
        d.texture_size = (int)o.size;
    d.seed = o.seed;
    memcpy(d.origin, o.origin, sizeof d.origin);
    d.untextured = o.untextured || o.parts;
    d.style = o.parts ? HLOD_CITY_STYLE_PARTS : HLOD_CITY_STYLE_SCAN;
    if (!o.out)
        return write_paths(&o, &d) ? 0 : 1;

    char *tex_dir = stem_with(o.out, "_tex");
    const char *ext = strrchr(o.out, '.');
    char *side = !strcmp(ext, ".obj") ? stem_with(o.out, ".mtl")
               : !strcmp(ext, ".gltf") ? stem_with(o.out, ".bin") : NULL;
    if (!tex_dir || (strcmp(ext, ".glb") && !side)) {
        hlod_cli_error(PROG, "out of memory");
        return 1;
    }
    int created_dir = 0;
    if (!d.untextured) {
        struct stat st;
        if (stat(tex_dir, &st) == 0) {
            if (!S_ISDIR(st.st_mode)) {
                hlod_cli_error(PROG, "%s: texture folder name is taken by a file", tex_dir);
                return 1;
            }
        } else if (errno == ENOENT) {
            created_dir = 1;
        }
    }
    d.texture_dir = tex_dir;

    hlod_cli_progress bar;
    hlod_cli_progress_begin(&bar, "block", !o.quiet);
    hlod_cli_log log_state = {PROG, o.quiet ? HLOD_LOG_ERROR : HLOD_LOG_WARN, &bar};
    hlod_logger lg = hlod_cli_logger(&log_state);
    d.logger = &lg;
    d.progress = hlod_cli_progress_fn;
    d.progress_user = &bar;

    hlod_mesh city = {0};
    hlod_city_stats st = {0};
    int status = 1, committed = 0;
    double t0 = hlod_cli_now();
    hlod_result r = hlod_city_generate(&d, &city, &st);
    double t_gen = hlod_cli_now() - t0;
    hlod_cli_progress_clear(&bar);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot generate the city: %s", o.out, hlod_result_str(r));
        goto done;
    }
    double t1 = hlod_cli_now();
    r = hlod_mesh_export(o.out, &city, &lg);
    double t_export = hlod_cli_now() - t1;
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot write mesh: %s", o.out, hlod_result_str(r));
        goto done;
    }
    committed = 1;
    if (o.paths && !write_paths(&o, &d))
        goto done;
    double seconds = hlod_cli_now() - t0;
    uint64_t bytes = st.texture_bytes + file_size(o.out) + file_size(side);
    if (!o.quiet)
        fprintf(stderr,
                "%s: %s: %zu blocks, %zu triangles (%zu in blocks, %zu ground), %zu vertices, "
                "%zu textures (%.1f Mpixel), %.1f MB in %.1f s\n",
                PROG, o.out, st.blocks, st.tris, st.block_tris, st.ground_tris, st.vertices,
                st.textures, (double)st.texture_pixels / 1e6, (double)bytes / 1e6, seconds);
    if (o.json) {
        hlod_json j;
        hlod_json_begin(&j, stdout);
        hlod_json_string(&j, "out", o.out);
        hlod_json_size(&j, "blocks", st.blocks);
        hlod_json_size(&j, "tris", st.tris);
        hlod_json_size(&j, "block_tris", st.block_tris);
        hlod_json_size(&j, "ground_tris", st.ground_tris);
        hlod_json_size(&j, "min_block_tris", st.min_block_tris);
        hlod_json_size(&j, "max_block_tris", st.max_block_tris);
        hlod_json_size(&j, "tris_per_block", d.tris_per_block);
        hlod_json_size(&j, "vertices", st.vertices);
        hlod_json_size(&j, "textures", st.textures);
        hlod_json_int(&j, "texture_size", d.untextured ? 0 : d.texture_size);
        hlod_json_int(&j, "texture_pixels", (long long)st.texture_pixels);
        hlod_json_int(&j, "bytes_written", (long long)bytes);
        hlod_json_double(&j, "seconds", seconds);
        hlod_json_double(&j, "seconds_generate", t_gen);
        hlod_json_double(&j, "seconds_export", t_export);
        hlod_json_size(&j, "seed", o.seed);
        hlod_json_string(&j, "style", o.parts ? "parts" : "scan");
        hlod_json_size(&j, "peak_rss_bytes", hlod_cli_peak_rss());
        if (o.paths)
            hlod_json_string(&j, "paths_dir", o.paths);
        /* The flat writer has no arrays; this follows its own format. */
        fprintf(j.fp, ", \"origin\": [%.17g, %.17g, %.17g]", d.origin[0], d.origin[1],
                d.origin[2]);
        j.count++;
        if (hlod_json_end(&j) != 0) {
            hlod_cli_error(PROG, "cannot write the JSON record to standard output");
            goto done;
        }
    }
    status = 0;
done:
    if (!committed && created_dir)
        remove_textures(tex_dir, d.blocks);
    hlod_mesh_free(&city);
    free(tex_dir);
    free(side);
    return status;
}
