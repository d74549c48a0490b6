/*
 * hlod-export-3dtiles: an HLOD store as a 3D Tiles 1.1 tileset.
 *
 *   hlod-export-3dtiles STORE -o DIR [--meshopt auto|always|never]
 *                       [--jpeg-quality Q] [--threads N] [--force] [--json]
 *
 * STORE is a file or an http(s) URL.  DIR gets tileset.json and tiles/N.glb
 * (one per node), written as DIR.tmp-XXXXXX and renamed into place when
 * complete (preprocess/tiles3d.h; docs/3d-tiles.md).  --json prints one
 * JSON object on stdout; scripts read its keys (tiles, glbs, bytes, ...):
 * keep them stable.
 *
 * Exit status: 0 written, 1 failed (nothing written), 2 bad command line.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "hlod/store.h"
#include "tiles3d.h"

static const char *const PROG = "hlod-export-3dtiles";

static void usage(FILE *fp)
{
    fprintf(fp,
        "usage: hlod-export-3dtiles STORE -o DIR [options]\n"
        "\n"
        "Writes an HLOD store (a file or an http(s) URL) as a 3D Tiles 1.1 tileset:\n"
        "DIR/tileset.json (our hierarchy: geometricError is each node's error,\n"
        "refine REPLACE (ADD for a sample tree), box volumes, tile transforms in double precision) and\n"
        "DIR/tiles/N.glb per node (KHR_mesh_quantization positions, normals, UVs,\n"
        "the node's texture as JPEG or PNG, vertex or material colours).  DIR is\n"
        "written beside itself and renamed into place only when complete.\n"
        "\n"
        "  -o, --out DIR       the output folder (must not exist, but with --force)\n"
        "  --meshopt M         EXT_meshopt_compression on the vertex and index data:\n"
        "                      auto (default: where it saves 10%% or more), always,\n"
        "                      never\n"
        "  --jpeg-quality Q    1..100 for textures not already JPEG in the store\n"
        "                      (default 90)\n"
        "  --threads N         workers (default 2)\n"
        "  --force             replace DIR when it exists\n"
        "  --json              print one JSON object on stdout: tiles, glbs, bytes,\n"
        "                      glb_bytes, tileset_bytes, texture_bytes, jpeg_copied,\n"
        "                      meshopt_glbs, float_position_glbs, triangles, seconds\n"
        "  --quiet             no progress bar\n"
        "  -h, --help          show this help\n"
        "\n"
        "Exit status: 0 written, 1 failed (nothing written), 2 bad command line.\n");
}

int main(int argc, char **argv)
{
    const char *file = NULL, *out = NULL;
    int json = 0, quiet = 0;
    hlod_tiles_export_desc desc = {0};
    desc.meshopt = HLOD_MESHOPT_AUTO;
    desc.jpeg_quality = 90;
    desc.threads = 2;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = NULL;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--json")) {
            json = 1;
        } else if (!strcmp(a, "--quiet")) {
            quiet = 1;
        } else if (!strcmp(a, "--force")) {
            desc.force = 1;
        } else if (!strcmp(a, "-o") || hlod_cli_match_flag(argc, argv, &i, "--out", &v)) {
            if (!strcmp(a, "-o"))
                v = i + 1 < argc ? argv[++i] : NULL;
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a folder", a);
            out = v;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--meshopt", &v)) {
            if (v && !strcmp(v, "auto"))
                desc.meshopt = HLOD_MESHOPT_AUTO;
            else if (v && !strcmp(v, "always"))
                desc.meshopt = HLOD_MESHOPT_ALWAYS;
            else if (v && !strcmp(v, "never"))
                desc.meshopt = HLOD_MESHOPT_NEVER;
            else
                return hlod_cli_usage_error(PROG, "--meshopt takes auto, always or never, not '%s'",
                                            v ? v : "");
        } else if (hlod_cli_match_flag(argc, argv, &i, "--jpeg-quality", &v)) {
            char *end = NULL;
            long q = v ? strtol(v, &end, 10) : 0;
            if (!v || !*v || *end || q < 1 || q > 100)
                return hlod_cli_usage_error(PROG, "--jpeg-quality takes 1..100, not '%s'",
                                            v ? v : "");
            desc.jpeg_quality = (int)q;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--threads", &v)) {
            char *end = NULL;
            long t = v ? strtol(v, &end, 10) : 0;
            if (!v || !*v || *end || t < 1 || t > 64)
                return hlod_cli_usage_error(PROG, "--threads takes 1..64, not '%s'", v ? v : "");
            desc.threads = (unsigned)t;
        } else if (a[0] == '-' && a[1] != 0) {
            return hlod_cli_usage_error(PROG, "unknown option '%s'", a);
        } else if (!file) {
            file = a;
        } else {
            return hlod_cli_usage_error(PROG, "unexpected argument '%s' (one store at a time)", a);
        }
    }
    if (!file)
        return hlod_cli_usage_error(PROG, "no store given%s", "");
    if (!out)
        return hlod_cli_usage_error(PROG, "no output folder given (-o DIR)%s", "");

    hlod_cli_progress bar;
    hlod_cli_progress_begin(&bar, "tiles", !quiet);
    hlod_cli_log log_state = {PROG, HLOD_LOG_WARN, &bar};
    hlod_logger lg = hlod_cli_logger(&log_state);
    desc.logger = &lg;
    desc.progress = hlod_cli_progress_fn;
    desc.progress_user = &bar;

    hlod_store *s = NULL;
    hlod_result r = hlod_store_open(file, &lg, &s);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot open store: %s", file, hlod_result_str(r));
        return 1;
    }
    double t0 = hlod_cli_now();
    hlod_tiles_export_stats st;
    r = hlod_tiles_export(s, out, &desc, &st);
    hlod_cli_progress_clear(&bar);
    hlod_store_close(s);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: export to %s failed (%s); nothing written", file, out,
                       hlod_result_str(r));
        return 1;
    }
    double secs = hlod_cli_now() - t0;
    if (json) {
        hlod_json j;
        hlod_json_begin(&j, stdout);
        hlod_json_string(&j, "store", file);
        hlod_json_string(&j, "out", out);
        hlod_json_int(&j, "tiles", (long long)st.tiles);
        hlod_json_int(&j, "glbs", (long long)st.glbs);
        hlod_json_int(&j, "bytes", (long long)st.bytes);
        hlod_json_int(&j, "glb_bytes", (long long)st.glb_bytes);
        hlod_json_int(&j, "tileset_bytes", (long long)st.tileset_bytes);
        hlod_json_int(&j, "texture_bytes", (long long)st.texture_bytes);
        hlod_json_int(&j, "jpeg_copied", (long long)st.jpeg_copied);
        hlod_json_int(&j, "meshopt_glbs", (long long)st.meshopt_glbs);
        hlod_json_int(&j, "float_position_glbs", (long long)st.float_position_glbs);
        hlod_json_int(&j, "triangles", (long long)st.triangles);
        hlod_json_double(&j, "seconds", secs);
        if (hlod_json_end(&j) != 0) {
            hlod_cli_error(PROG, "cannot write the JSON record to standard output");
            return 1;
        }
    } else {
        printf("%s: %llu tiles, %llu bytes (%llu in textures; %llu JPEGs copied from the store, "
               "%llu tiles with EXT_meshopt_compression) in %.1f s\n",
               out, (unsigned long long)st.tiles, (unsigned long long)st.bytes,
               (unsigned long long)st.texture_bytes, (unsigned long long)st.jpeg_copied,
               (unsigned long long)st.meshopt_glbs, secs);
    }
    return 0;
}
