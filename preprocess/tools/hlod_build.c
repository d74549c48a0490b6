/*
 * hlod-build: meshes in, one HLOD store out.
 *
 *   hlod-build INPUT... -o OUT.hlod [--method cutplane|metis]
 *              [--blocks objects|grid:SIZE] [--desired-tris N]
 *              [--level-factor F] [--cone-split on|off] [--far-cubes on|off] [--voxel-tris N] [--leaf-tris N]
 *              [--node-tris N] [--c-tex C] [--city-levels on|off] [--threads T]
 *              [--compress on|off] [--quant-bits B] [--jpeg-quality Q]
 *              [--texture-blocks on|off] [--texture-min-db DB]
 *              [--shard I/N] [--json] [--quiet]
 *
 * The pipeline is the library's (hlod/build_store.h, preprocess/build_store.c);
 * this file parses flags, draws the progress bar and prints the summary.
 */
#include "cli.h"
#include "hlod/build_store.h"

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
    hlod_build_desc bd;
    int json, quiet;
} options;

static void usage(FILE *fp)
{
    fprintf(fp,
            "usage: hlod-build INPUT... -o OUT.hlod [options]\n"
            "\n"
            "Builds a hierarchy of levels of detail (HLOD) from meshes (OBJ+MTL, PLY,\n"
            "OFF, glTF) or a 3D Tiles tileset (tileset.json: its leaf tiles' glb, one\n"
            "block per leaf tile) and writes it as one streaming store for the runtime.\n"
            "\n"
            "  -o, --output OUT       the store to write (required)\n"
            "  --method M             cutplane (Lakhia III-A, default), metis\n"
            "                         (Okamoto 4.1), sampletree (Klein 4-5: a\n"
            "                         randomized sample tree, additive;\n"
            "                         docs/sampletree.md) or cubes (Chamberlain 3-4:\n"
            "                         an octree of colour cubes, additive;\n"
            "                         docs/cubes.md)\n"
            "  --blocks B             objects (default: each input object is a block)\n"
            "                         or grid:SIZE (square cells of SIZE model units\n"
            "                         in x and y; z is up)\n"
            "  --desired-tris N       C_desiredTri: triangles of hlod_0 (cutplane,\n"
            "                         default 4000)\n"
            "  --level-factor F       C_levelFactor: pieces per cut and triangle ratio\n"
            "                         between levels (cutplane, integer >= 2, default 3)\n"
            "  --cone-split S         cutplane: on cuts pieces within three levels of\n"
            "                         the leaves into orientation classes where their\n"
            "                         normals spread over 45 degrees, so normal cones\n"
            "                         cull more (cone_cull); off (default)\n"
            "  --far-cubes S          cutplane, metis: on gives every node the colour\n"
            "                         cube of its own mesh, drawn in its place where\n"
            "                         it projects within cube_px (engine setting\n"
            "                         far_cubes; docs/cubes.md); off (default)\n"
            "  --voxel-tris N         N_v: triangles per voxel (metis, default 500)\n"
            "  --leaf-tris N          N_l: leaf size (metis, default 4000); sampletree\n"
            "                         and cubes: a cell of more triangles splits\n"
            "                         (default 256; cubes 64)\n"
            "  --memory-mb M          sampletree and cubes: MiB the build may hold beside the\n"
            "                         input's vertices (buckets built one at a time,\n"
            "                         a spill file beside OUT; default 0: no limit)\n"
            "  --sample-c C           sampletree: c of the sample size\n"
            "                         q ln q + c q (Klein Theorem 1; default 13.8,\n"
            "                         p > 1 - 1e-6), in (0, 1000]\n"
            "  --node-tris N          N_n: inner node size (metis, default 2000)\n"
            "  --c-tex C              c_tex of Lakhia eq. 1 in [0, 1] (default 0.5)\n"
            "  --city-levels L        on (default): group nodes over the blocks, about\n"
            "                         F^2 neighbours each, up to one root; off: every\n"
            "                         block's hlod_0 is a root (the paper's layout)\n"
            "  --threads T            build threads (default: every core)\n"
            "  --compress C           on (default): packed payloads (positions on a\n"
            "                         grid, meshoptimizer codecs, block-coded or\n"
            "                         JPEG textures); off:\n"
            "                         raw floats and pixels\n"
            "  --quant-bits B         packed: the position grid step is the input's\n"
            "                         diagonal / 2^B rounded down to a power of two\n"
            "                         (8..24, default 24)\n"
            "  --jpeg-quality Q       packed: JPEG quality of textures (1..100, default\n"
            "                         90); 0 keeps textures lossless\n"
            "  --texture-blocks B     packed: on (default): textures of 1 or 3\n"
            "                         channels as BC1/BC4 mip chains with zstd, GPU-\n"
            "                         ready (docs/store-format.md); off: all JPEG\n"
            "  --texture-min-db DB    packed: a texture whose blocks fall under DB dB\n"
            "                         PSNR against it is stored as JPEG (0..99,\n"
            "                         default 38)\n"
            "  --shard I/N            build only shard I of N (1 <= I <= N) and write a\n"
            "                         part file at OUT for hlod-merge\n"
            "                         (docs/sharded-builds.md)\n"
            "  --json                 print one JSON object on stdout: blocks, nodes,\n"
            "                         levels, groups, block_depth, tris_in,\n"
            "                         tris_leaf, tris_total, bytes, seconds,\n"
            "                         peak_rss_bytes (a shard's: its own), buckets\n"
            "                         and spill_bytes (sampletree; else 0),\n"
            "                         textures_bc1, textures_jpeg, textures_raw,\n"
            "                         texture_psnr_min (dB, the worst stored; 0:\n"
            "                         none measured)\n"
            "  --quiet                errors only, no progress bar\n"
            "  -h, --help             show this help\n"
            "\n"
            "Exit status: 0 success, 1 failure (nothing written), 2 bad command line.\n");
}

/* ---- command line ------------------------------------------------------------ */

/* --shard I/N */
static int parse_shard(const char *val, hlod_build_desc *bd)
{
    unsigned si, sn;
    int used = 0;
    if (sscanf(val, "%u/%u%n", &si, &sn, &used) != 2 || val[used] || !sn || sn > 65536 || !si ||
        si > sn || val[0] < '0' || val[0] > '9') {
        hlod_cli_error(PROG, "--shard: '%s' is not I/N with 1 <= I <= N <= 65536", val);
        return 0;
    }
    bd->shard_index = si;
    bd->shard_count = sn;
    return 1;
}

/* --method's value into bd->method. */
static int parse_method(const char *val, hlod_build_desc *bd)
{
    if (!strcmp(val, "cutplane"))
        bd->method = HLOD_BUILD_CUTPLANE;
    else if (!strcmp(val, "metis"))
        bd->method = HLOD_BUILD_METIS;
    else if (!strcmp(val, "sampletree"))
        bd->method = HLOD_BUILD_SAMPLETREE;
    else if (!strcmp(val, "cubes"))
        bd->method = HLOD_BUILD_CUBES;
    else {
        hlod_cli_error(PROG, "--method: '%s' is not cutplane, metis, sampletree or cubes", val);
        return 0;
    }
    return 1;
}

/* val of flag as on (1) or off (0) into *out; 0 when it is neither. */
static int on_off(const char *flag, const char *val, int *out)
{
    if (strcmp(val, "on") != 0 && strcmp(val, "off") != 0) {
        hlod_cli_error(PROG, "%s: '%s' is not on or off", flag, val);
        return 0;
    }
    *out = !strcmp(val, "on");
    return 1;
}

/* What the flags must agree on once all are read; the defaults that
 * depend on the method. */
static int check_options(options *o, int leaf_given)
{
    if (!o->n_inputs) {
        hlod_cli_error(PROG, "no input mesh (see --help)");
        return 0;
    }
    if (!o->out) {
        hlod_cli_error(PROG, "no output: -o OUT.hlod is required");
        return 0;
    }
    if (o->bd.cone_split && o->bd.method != HLOD_BUILD_CUTPLANE) {
        hlod_cli_error(PROG, "--cone-split on: only with --method cutplane");
        return 0;
    }
    if (o->bd.far_cubes &&
        (o->bd.method == HLOD_BUILD_SAMPLETREE || o->bd.method == HLOD_BUILD_CUBES)) {
        hlod_cli_error(PROG, "--far-cubes on: only with --method cutplane or metis (a sample "
                       "tree's small nodes are splats, a cubes store's are cubes already)");
        return 0;
    }
    if (o->bd.method == HLOD_BUILD_SAMPLETREE && !leaf_given)
        o->bd.leaf_tris = HLOD_BUILD_SAMPLE_LEAF;
    if (o->bd.method == HLOD_BUILD_CUBES && !leaf_given)
        o->bd.leaf_tris = HLOD_BUILD_CUBES_LEAF;
    if (o->bd.method == HLOD_BUILD_METIS && o->bd.node_tris >= o->bd.leaf_tris)
        hlod_cli_error(PROG, "warning: --node-tris %zu >= --leaf-tris %zu: inner nodes simplify little",
                       o->bd.node_tris, o->bd.leaf_tris);
    return 1;
}

static int parse(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    hlod_build_desc_defaults(&o->bd);
    long cpus = sysconf(_SC_NPROCESSORS_ONLN);
    o->bd.threads = cpus > 0 ? (size_t)cpus : 1;
    int leaf_given = 0;
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
            if (!parse_method(val, &o->bd))
                return 0;
        } else if (!strcmp(a, "--blocks")) {
            NEED_VAL();
            if (!strcmp(val, "objects"))
                o->bd.grid = 0;
            else if (!strncmp(val, "grid:", 5)) {
                if (!hlod_cli_parse_double(PROG, "--blocks grid:SIZE", val + 5, 0, 1e12, HLOD_CLI_MIN_OPEN,
                                           &o->bd.grid))
                    return 0;
            } else {
                hlod_cli_error(PROG, "--blocks: '%s' is not objects or grid:SIZE", val);
                return 0;
            }
        } else if (!strcmp(a, "--desired-tris")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 1, 1u << 30, &o->bd.desired_tris))
                return 0;
        } else if (!strcmp(a, "--level-factor")) {
            NEED_VAL();
            size_t f;
            if (!hlod_cli_parse_size(PROG, a, val, 2, 64, &f))
                return 0;
            o->bd.level_factor = (double)f;
        } else if (!strcmp(a, "--voxel-tris")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 1, 1u << 30, &o->bd.voxel_tris))
                return 0;
        } else if (!strcmp(a, "--leaf-tris")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 2, 1u << 30, &o->bd.leaf_tris))
                return 0;
            leaf_given = 1;
        } else if (!strcmp(a, "--memory-mb")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 0, 1u << 24, &o->bd.memory_mb))
                return 0;
        } else if (!strcmp(a, "--sample-c")) {
            NEED_VAL();
            if (!hlod_cli_parse_double(PROG, a, val, 0, 1000, HLOD_CLI_MIN_OPEN, &o->bd.sample_c))
                return 0;
        } else if (!strcmp(a, "--node-tris")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 1, 1u << 30, &o->bd.node_tris))
                return 0;
        } else if (!strcmp(a, "--c-tex")) {
            NEED_VAL();
            if (!hlod_cli_parse_double(PROG, a, val, 0, 1, 0, &o->bd.c_tex))
                return 0;
        } else if (!strcmp(a, "--threads")) {
            NEED_VAL();
            if (!hlod_cli_parse_size(PROG, a, val, 1, 256, &o->bd.threads))
                return 0;
        } else if (!strcmp(a, "--city-levels")) {
            NEED_VAL();
            if (!on_off(a, val, &o->bd.city_levels))
                return 0;
        } else if (!strcmp(a, "--compress")) {
            NEED_VAL();
            if (!on_off(a, val, &o->bd.compress))
                return 0;
        } else if (!strcmp(a, "--quant-bits")) {
            NEED_VAL();
            size_t b;
            if (!hlod_cli_parse_size(PROG, a, val, 8, 24, &b))
                return 0;
            o->bd.quant_bits = (unsigned)b;
        } else if (!strcmp(a, "--jpeg-quality")) {
            NEED_VAL();
            size_t q;
            if (!hlod_cli_parse_size(PROG, a, val, 0, 100, &q))
                return 0;
            o->bd.jpeg_quality = (unsigned)q;
        } else if (!strcmp(a, "--far-cubes")) {
            NEED_VAL();
            if (!on_off(a, val, &o->bd.far_cubes))
                return 0;
        } else if (!strcmp(a, "--cone-split")) {
            NEED_VAL();
            if (!on_off(a, val, &o->bd.cone_split))
                return 0;
        } else if (!strcmp(a, "--texture-blocks")) {
            NEED_VAL();
            if (!on_off(a, val, &o->bd.texture_blocks))
                return 0;
        } else if (!strcmp(a, "--texture-min-db")) {
            NEED_VAL();
            if (!hlod_cli_parse_double(PROG, a, val, 0, 99, 0, &o->bd.texture_min_db))
                return 0;
        } else if (!strcmp(a, "--shard")) {
            NEED_VAL();
            if (!parse_shard(val, &o->bd))
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
    return check_options(o, leaf_given);
}

static void progress(void *user, size_t done, size_t total)
{
    hlod_cli_progress_fn(user, (double)done, (double)total);
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
    opt.bd.progress = progress;
    opt.bd.progress_user = &bar;
    hlod_build_report rep;
    hlod_result r = hlod_build_store(&opt.bd, opt.inputs, (size_t)opt.n_inputs, opt.out, &lg, &rep);
    hlod_cli_progress_clear(&bar);
    free(opt.inputs);
    if (r != HLOD_OK)
        return 1;
    struct stat st;
    size_t bytes = stat(opt.out, &st) == 0 ? (size_t)st.st_size : 0;
    double secs = hlod_cli_now() - t0;
    if (!opt.quiet)
        fprintf(stderr, "%s: %s: %zu blocks (depth %zu, %zu groups above), %zu nodes, %zu levels, "
                "%zu -> %zu leaf triangles, %.1f MB, %.1f s\n", PROG, opt.out, rep.blocks,
                rep.block_depth, rep.groups, rep.nodes, rep.levels, rep.tris_in, rep.tris_leaf,
                bytes / 1e6, secs);
    if (opt.json) {
        hlod_json j;
        hlod_json_begin(&j, stdout);
        hlod_json_size(&j, "blocks", rep.blocks);
        hlod_json_size(&j, "nodes", rep.nodes);
        hlod_json_size(&j, "levels", rep.levels);
        hlod_json_size(&j, "groups", rep.groups);
        hlod_json_size(&j, "block_depth", rep.block_depth);
        hlod_json_size(&j, "tris_in", rep.tris_in);
        hlod_json_size(&j, "tris_leaf", rep.tris_leaf);
        hlod_json_size(&j, "tris_total", rep.tris_total);
        hlod_json_size(&j, "bytes", bytes);
        hlod_json_double(&j, "seconds", secs);
        hlod_json_size(&j, "peak_rss_bytes", hlod_cli_peak_rss());
        hlod_json_size(&j, "buckets", rep.buckets);
        hlod_json_size(&j, "spill_bytes", (size_t)rep.spill_bytes);
        hlod_json_size(&j, "textures_bc1", (size_t)rep.textures_bc);
        hlod_json_size(&j, "textures_jpeg", (size_t)rep.textures_jpeg);
        hlod_json_size(&j, "textures_raw", (size_t)rep.textures_raw);
        hlod_json_double(&j, "texture_psnr_min", rep.texture_db_min);
        hlod_json_string(&j, "method", opt.bd.method == HLOD_BUILD_METIS        ? "metis"
                                       : opt.bd.method == HLOD_BUILD_SAMPLETREE ? "sampletree"
                                       : opt.bd.method == HLOD_BUILD_CUBES      ? "cubes"
                                                                                : "cutplane");
        hlod_json_size(&j, "threads", opt.bd.threads);
        hlod_json st;
        hlod_json_object(&j, "stage_seconds", &st);
        hlod_json_double(&st, "read", rep.stage_read_s);
        hlod_json_double(&st, "blocks", rep.stage_blocks_s);
        hlod_json_double(&st, "levels", rep.stage_levels_s);
        hlod_json_double(&st, "finish", rep.stage_finish_s);
        hlod_json_object_end(&st);
        hlod_json_object(&j, "stage_cpu_seconds", &st);
        hlod_json_double(&st, "texture_read", rep.cpu_texture_read_s);
        hlod_json_double(&st, "tree", rep.cpu_tree_s);
        hlod_json_double(&st, "simplify", rep.cpu_simplify_s);
        hlod_json_double(&st, "error", rep.cpu_error_s);
        hlod_json_double(&st, "node_textures", rep.cpu_node_texture_s);
        hlod_json_double(&st, "store", rep.cpu_store_s);
        hlod_json_object_end(&st);
        hlod_json_double(&j, "cpu_seconds", hlod_cli_cpu_seconds());
        if (opt.bd.shard_count) {
            hlod_json_size(&j, "shard_index", opt.bd.shard_index);
            hlod_json_size(&j, "shard_count", opt.bd.shard_count);
        }
        if (hlod_json_end(&j) != 0)
            return 1;
    }
    return 0;
}
