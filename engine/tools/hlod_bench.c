/*
 * hlod-bench: replays a camera path through the engine, headless (OSMesa,
 * or EGL with --backend egl), and reports frame time against the target,
 * image error against a full-detail reference, flicker, detail per depth,
 * streaming, and the machine's own jitter (one frozen selection replayed).
 *
 *   hlod-bench STORE --path P --target-ms T --out DIR [options]
 *
 * One run writes DIR/frames.csv (one row per frame, every stats field;
 * new columns go at the end), DIR/summary.json (keys scripts rely on: keep
 * them stable), DIR/jitter.csv (the frozen selection of frame N/2 replayed
 * --jitter-frames times: the machine's own spread), DIR/frame_NNNNN.png
 * (and _ref.png) for --save-frames, and PNG plots drawn by gnuplot.  --policy with several names, or --sweep KEY=V1,V2,..,
 * runs the path once per (policy, value) into DIR/<policy>[-KEY=V]/ and
 * adds DIR/sweep.csv plus the run-time-vs-error (Pareto) plot.
 *
 * Reference frames (--reference) come from a second engine over the same
 * store with the full-detail policy, in a second GL context of its own
 * (2W x 2H, box-filtered down to W x H, with --reference-ss 2, the
 * default) with its own renderer, drawn after the measured frame has
 * ended, so they are never charged to its time.  Each engine call is made
 * with its engine's context current.
 *
 * --compare A.png B.png prints the PSNR, SSIM and differing pixels of two
 * images as one JSON line (tests compare the backends' frames with it).
 *
 * Exit status: 0 success, 1 a run failed (unreadable store or path, GL
 * unavailable, output not writable), 2 bad command line.
 */
#include <errno.h>
#include <assert.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#include "atomic_file.h"
#include "cli.h"
#include "hlod_clock.h"
#include "data_dir.h"
#include "view_flags.h"
#include "hlod/engine.h"
#include "hlod/image.h"
#include "hlod/lumigraph.h"
#include "hlod/renderer.h"
#include "hlod/metrics.h"
#include "hlod/path.h"

static const char *const PROG = "hlod-bench";

static void usage(FILE *fp)
{
    fprintf(fp,
        "usage: hlod-bench STORE --path P --target-ms T --out DIR [options]\n"
        "       hlod-bench --compare A.png B.png\n"
        "\n"
        "Replays camera path P through the engine headless (OSMesa or EGL) and\n"
        "writes DIR/frames.csv, DIR/summary.json, DIR/jitter.csv and PNG plots.\n"
        "\n"
        "  --path P          a path file (t ex ey ez lx ly lz per line), or a\n"
        "                    built-in name (walk, fly, walk-to-fly, walk-drive,\n"
        "                    orbit, still) looked up in --paths-dir\n"
        "  --paths-dir D     where built-in names are looked up (default\n"
        "                    %s/paths/default)\n"
        "  --target-ms T     c_targetTime in ms (default 33.3)\n"
        "  --out DIR         output folder (created)\n"
        "  --width W         viewport (default 1280)\n"
        "  --height H        viewport (default 720)\n"
        "  --fov DEG         vertical field of view (default 60)\n"
        "  --near N          near plane in model units (default 0.25)\n"
        "  --up z|y          the path's up axis (default z)\n"
        "  --dt S            simulated time per frame (default 1/30 s)\n"
        "  --frames N        stop after N frames (default: the whole path)\n"
        "  --policy LIST     " HLOD_POLICY_CHOICES " (comma list; default lakhia)\n"
        "  --method LIST     the same as --policy\n"
        "  --repo REPO       policy lumigraph's sampling repository: a folder\n"
        "                    written by hlod-lumigraph-bake, or its http(s) URL\n"
        "  --answers         --repo is hlod-lumigraph-serve's URL: one request per\n"
        "                    frame at most brings the views the eye lacks\n"
        "  --memory-mb M     memory budget in MiB (default: the whole store decoded,\n"
        "                    at most a quarter of the machine's memory)\n"
        "  --reference       render a full-detail reference per frame: PSNR, SSIM\n"
        "  --reference-store R  the reference drawn at full detail from store R\n"
        "                    (e.g. a chessboard's reference board) instead\n"
        "                    of STORE; implies --reference\n"
        "  --reference-every K  only every K-th frame (default 1); each reference\n"
        "                    is drawn once and reused by every policy and sweep run\n"
        "  --reference-ss S  1, or 2 (default): the reference drawn at 2W x 2H in\n"
        "                    a context of its own and box-filtered down to W x H\n"
        "  --save-frames LIST  comma list of frame numbers: DIR/frame_NNNNN.png of\n"
        "                    each (the measured image), and frame_NNNNN_ref.png of\n"
        "                    its reference with --reference; frames past the end\n"
        "                    are not written (said on stderr)\n"
        "  --jitter-frames R  after frame N/2 of each run (N frames), its frozen\n"
        "                    selection is drawn again R times (default 120; 0: off):\n"
        "                    the machine's own spread, machine_p50_ms/p99 and\n"
        "                    DIR/jitter.csv\n"
        "  --occlusion-check after each frame, draw its selection again without\n"
        "                    occlusion culling and compare with the frame's image\n"
        "                    (frames.csv occlusion_check_psnr/_differing, summary\n"
        "                    occlusion_check_*); not charged to the frame\n"
        "  --cone-check      after each frame, draw its selection again with the\n"
        "                    nodes normal cones culled (kept loaded for it) and\n"
        "                    compare (frames.csv cone_check_differing, summary\n"
        "                    cone_check_*); not charged to the frame\n"
        "  --backend B       osmesa (default), or egl: a hardware EGL device, else\n"
        "                    Mesa's surfaceless platform (llvmpipe without a GPU)\n"
        "  --compare A B     print the PSNR, SSIM and differing pixels of images\n"
        "                    A and B (same size) as JSON, then exit\n"
        "  --set KEY=VALUE   an engine setting (repeatable; below)\n"
        "  --sweep KEY=V1,V2 run once per value of KEY (any --set key)\n"
        "  --deterministic   fixed v_time and fixed_ms (calibrated in a short\n"
        "                    warm-up unless given with --set) and a loader that\n"
        "                    reads synchronously at --io-mbps: the selection is\n"
        "                    the same on any machine\n"
        "  --io-mbps R       simulated disk in MB/s for --deterministic (default 100)\n"
        "  --realtime        start frame N no earlier than N x --dt of wall time after\n"
        "                    the first, as a viewer would (loads over a network\n"
        "                    then take as many frames as they would there)\n"
        "  --no-plots        skip gnuplot\n"
        "  --json            also print summary.json on stdout (last run)\n"
        "  -h, --help        show this help\n"
        "\n"
        "summary.json keys: frames, target_ms, frame_ms_mean, frame_ms_p50,\n"
        "frame_ms_p95, frame_ms_p99, frame_ms_max, within_10pct, over_target_frac,\n"
        "toggles_up, toggles_down, toggles_per_frame, oscillations, psnr_mean,\n"
        "psnr_min, ssim_mean, image_flicker, tris_mean, loads, evictions, bytes_read,\n"
        "cache_hits (payloads from HLOD_CACHE_DIR, not in bytes_read),\n"
        "bytes_fetched, answer_bytes_max, lumi_missing_frames, grid_point_psnr_min,\n"
        "grid_point_checks (policy lumigraph: view bytes fetched, the largest\n"
        "answer, frames whose blend lacked a view, the client against the baked\n"
        "views at the path's grid points: the worst PSNR, views checked),\n"
        "loader_finish_ms, loader_busy_ms, loader_finish_share,\n"
        "peak_resident_bytes, memory_budget_bytes, missing_wanted_frames,\n"
        "render_waits, bad_nodes, load_failures, traversal_ms_mean, traversal_ms_max,\n"
        "deadline_met, margin_cap_frames, margin_cap_run_max, machine_p50_ms,\n"
        "machine_p99_ms, machine_p99_over_p50,\n"
        "estimate_err_p50, estimate_err_p95, occlusion_culled_mean, toggles_after_60,\n"
        "occlusion_ms_mean, overhead_ms_mean, overhead_ms_max,\n"
        "occlusion_check_psnr_min, occlusion_check_differing_max,\n"
        "occlusion_check_bad_frames, cone_culled_mean, cone_culled_tris_share,\n"
        "cone_check_differing_max,\n"
        "cone_check_nodes, cone_check_unchecked, splats_mean, res_scale_mean,\n"
        "res_scale_min, res_scaled_frames (dyn_res), policy, path,\n"
        "backend, gl_renderer, texture_upload (blocks or expanded).\n"
        "\n"
        "Exit status: 0 success, 1 a run failed, 2 bad command line.\n"
        "\n"
        "Engine settings (--set KEY=VALUE; default, then meaning):\n",
        hlod_tool_data_dir());
    size_t n;
    const hlod_engine_setting *set = hlod_engine_settings(&n);
    for (size_t i = 0; i < n; i++)
        fprintf(fp, "  %-24s %-10.15g %s\n", set[i].key, set[i].def, set[i].help);
}

/* ---- options ---- */

#define MAX_SETS 32
#define MAX_SWEEP 64
#define MAX_SAVE 256

enum { BACKEND_OSMESA, BACKEND_EGL };

typedef struct setting {
    const char *key;
    double value;
} setting;

typedef struct options {
    const char *store, *path, *paths_dir, *out;
    double target_ms, fov, near_plane, dt, io_mbps, memory_mb;
    uint32_t width, height;
    long frames;
    int up_y, reference, reference_every, reference_ss, deterministic, plots, json;
    const char *reference_store; /* the reference drawn from this store instead */
    const char *repo;            /* policy lumigraph's sampling repository */
    int answers;                 /* ... is hlod-lumigraph-serve's URL: ask it for answers */
    int backend, jitter_frames, occlusion_check, cone_check, realtime;
    uint64_t save[MAX_SAVE];    /* --save-frames */
    int nsave;
    const char *compare[2];     /* --compare A B */
    hlod_policy policies[HLOD_POLICY_COUNT];
    int npolicies;
    int policy_given;           /* --policy was given (else lakhia, klein for a sample tree) */
    setting sets[MAX_SETS];
    int nsets;
    const char *sweep_key;
    double sweep[MAX_SWEEP];
    int nsweep;
} options;

/* A --set or --sweep key: one of the engine's settings, and a value its
 * kind can hold. */
static int known_key(const char *k)
{
    hlod_engine_desc d = {0};
    return hlod_engine_desc_set(&d, k, 0) == HLOD_OK;
}

static int value_ok(const char *k, double v)
{
    hlod_engine_desc d = {0};
    if (hlod_engine_desc_set(&d, k, v) == HLOD_OK)
        return 1;
    char what[160];
    snprintf(what, sizeof what, "%s=%g", k, v);
    hlod_cli_usage_error(PROG, "--set/--sweep %s: not a value the setting can hold (a count is a "
                         "whole number >= 0)", what);
    return 0;
}

/* Was key given with --set (or is it the sweep's key)? */
static int given(const options *o, const setting *extra, const char *key)
{
    for (int i = 0; i < o->nsets; i++)
        if (!strcmp(o->sets[i].key, key))
            return 1;
    return extra && !strcmp(extra->key, key);
}

static int is_copies_key(const char *k)
{
    return !strcmp(k, "rzb_copies") || !strcmp(k, "cube_copies");
}

/* --set or --sweep rzb_copies or cube_copies: the most levels of copies
 * policy rzb or cubes draws in any run (0: none). */
static uint32_t copy_levels(const options *o)
{
    double l = 0;
    for (int i = 0; i < o->nsets; i++)
        if (is_copies_key(o->sets[i].key))
            l = o->sets[i].value > l ? o->sets[i].value : l;
    for (int i = 0; o->sweep_key && is_copies_key(o->sweep_key) && i < o->nsweep; i++)
        l = o->sweep[i] > l ? o->sweep[i] : l;
    return l > 0 && l <= 64 ? (uint32_t)l : 0;
}

static void apply_setting(hlod_engine_desc *d, const char *k, double v)
{
    hlod_result r = hlod_engine_desc_set(d, k, v);
    assert(r == HLOD_OK); /* keys and values were checked when parsed */
    (void)r;
}

/* "KEY=VALUE" */
static int parse_set(const char *text, setting *out)
{
    const char *eq = strchr(text, '=');
    static char keys[MAX_SETS + 1][64];
    static int next;
    if (!eq || eq == text || (size_t)(eq - text) >= sizeof keys[0]) {
        hlod_cli_usage_error(PROG, "--set wants KEY=VALUE, got '%s'", text);
        return 0;
    }
    char *k = keys[next++ % (MAX_SETS + 1)];
    memcpy(k, text, (size_t)(eq - text));
    k[eq - text] = 0;
    if (!known_key(k)) {
        hlod_cli_usage_error(PROG, "--set: unknown key '%s' (see --help)", k);
        return 0;
    }
    out->key = k;
    return hlod_cli_parse_double(PROG, k, eq + 1, -1e12, 1e12, 0, &out->value) &&
           value_ok(k, out->value);
}

static int parse_sweep(const char *text, options *o)
{
    static char key[64];
    const char *eq = strchr(text, '=');
    if (!eq || eq == text || (size_t)(eq - text) >= sizeof key) {
        hlod_cli_usage_error(PROG, "--sweep wants KEY=V1,V2,..., got '%s'", text);
        return 0;
    }
    memcpy(key, text, (size_t)(eq - text));
    key[eq - text] = 0;
    if (!known_key(key)) {
        hlod_cli_usage_error(PROG, "--sweep: unknown key '%s' (see --help)", key);
        return 0;
    }
    o->sweep_key = key;
    const char *p = eq + 1;
    while (*p) {
        const char *c = strchr(p, ',');
        size_t n = c ? (size_t)(c - p) : strlen(p);
        char buf[64];
        if (n == 0 || n >= sizeof buf || o->nsweep >= MAX_SWEEP) {
            hlod_cli_usage_error(PROG, "--sweep: bad value list '%s'", eq + 1);
            return 0;
        }
        memcpy(buf, p, n);
        buf[n] = 0;
        if (!hlod_cli_parse_double(PROG, "--sweep", buf, -1e12, 1e12, 0, &o->sweep[o->nsweep]) ||
            !value_ok(key, o->sweep[o->nsweep]))
            return 0;
        o->nsweep++;
        p += n + (c ? 1 : 0);
        if (c && !*p) {
            hlod_cli_usage_error(PROG, "--sweep: trailing comma in '%s'", eq + 1);
            return 0;
        }
    }
    if (o->nsweep == 0) {
        hlod_cli_usage_error(PROG, "--sweep: no values in '%s'", text);
        return 0;
    }
    return 1;
}

static int parse_save_frames(const char *text, options *o)
{
    const char *p = text;
    if (!*p) {
        hlod_cli_usage_error(PROG, "--save-frames: empty list%s", "");
        return 0;
    }
    while (*p) {
        const char *c = strchr(p, ',');
        size_t n = c ? (size_t)(c - p) : strlen(p), f;
        char buf[32];
        if (n == 0 || n >= sizeof buf) {
            hlod_cli_usage_error(PROG, "--save-frames: bad list '%s' (frame numbers, e.g. 0,100)",
                                 text);
            return 0;
        }
        if (o->nsave >= MAX_SAVE) {
            hlod_cli_usage_error(PROG, "--save-frames: more than %s frames", "256");
            return 0;
        }
        memcpy(buf, p, n);
        buf[n] = 0;
        if (!hlod_cli_parse_size(PROG, "--save-frames", buf, 0, SIZE_MAX, &f))
            return 0;
        o->save[o->nsave++] = f;
        p += n + (c ? 1 : 0);
        if (c && !*p) {
            hlod_cli_usage_error(PROG, "--save-frames: trailing comma in '%s'", text);
            return 0;
        }
    }
    return 1;
}

static int save_frame(const options *o, uint64_t f)
{
    for (int i = 0; i < o->nsave; i++)
        if (o->save[i] == f)
            return 1;
    return 0;
}

static int parse_policies(const char *text, options *o)
{
    char buf[128];
    if (strlen(text) >= sizeof buf) {
        hlod_cli_usage_error(PROG, "--policy: list too long: '%s'", text);
        return 0;
    }
    strcpy(buf, text);
    o->npolicies = 0;
    for (char *save = NULL, *t = strtok_r(buf, ",", &save); t; t = strtok_r(NULL, ",", &save)) {
        hlod_policy p;
        if (!hlod_policy_parse(t, &p) || p == HLOD_POLICY_FULL) {
            hlod_cli_usage_error(PROG, "--policy: unknown policy '%s' (" HLOD_POLICY_CHOICES ")", t);
            return 0;
        }
        for (int i = 0; i < o->npolicies; i++)
            if (o->policies[i] == p) {
                hlod_cli_usage_error(PROG, "--policy: '%s' given twice", t);
                return 0;
            }
        o->policies[o->npolicies++] = p;
    }
    if (!o->npolicies) {
        hlod_cli_usage_error(PROG, "--policy: empty list '%s'", text);
        return 0;
    }
    return 1;
}

/* Returns -1 to continue, else an exit status. */
static int parse_args(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    o->target_ms = 33.3;
    o->width = 1280;
    o->height = 720;
    o->fov = 60;
    o->near_plane = 0.25;
    o->dt = 1.0 / 30;
    o->io_mbps = 100;
    o->frames = -1;
    o->reference_every = 1;
    o->reference_ss = 2;
    o->jitter_frames = 120;
    o->plots = 1;
    o->policies[0] = HLOD_POLICY_LAKHIA;
    o->npolicies = 1;
    o->paths_dir = hlod_tool_default_paths_dir();
    const view_flags vf = {&o->width, &o->height, &o->target_ms, &o->memory_mb, &o->fov,
                           &o->path,  &o->paths_dir, &o->frames, &o->up_y};
    for (int i = 1; i < argc; i++) {
        const char *v = NULL;
        const char *a = argv[i];
        size_t n;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        }
        int shared = view_flags_parse(PROG, argc, argv, &i, &vf);
        if (shared < 0)
            return 2;
        if (shared)
            continue;
#define FLAG(name) hlod_cli_match_flag(argc, argv, &i, name, &v)
#define NEED(name)                                                              \
    if (!v)                                                                     \
        return hlod_cli_usage_error(PROG, "%s needs a value", name);
        if (FLAG("--out")) {
            NEED("--out");
            o->out = v;
        } else if (FLAG("--near")) {
            NEED("--near");
            if (!hlod_cli_parse_double(PROG, "--near", v, 0, 1e6, HLOD_CLI_MIN_OPEN,
                                       &o->near_plane))
                return 2;
        } else if (FLAG("--dt")) {
            NEED("--dt");
            if (!hlod_cli_parse_double(PROG, "--dt", v, 0, 10, HLOD_CLI_MIN_OPEN, &o->dt))
                return 2;
        } else if (FLAG("--repo")) {
            NEED("--repo");
            o->repo = v;
        } else if (!strcmp(a, "--answers")) {
            o->answers = 1;
        } else if (FLAG("--policy") || FLAG("--method")) {
            NEED("--policy");
            o->policy_given = 1;
            if (!parse_policies(v, o))
                return 2;
        } else if (!strcmp(a, "--reference")) {
            o->reference = 1;
        } else if (FLAG("--reference-store")) {
            NEED("--reference-store");
            o->reference_store = v;
            o->reference = 1;
        } else if (FLAG("--reference-every")) {
            NEED("--reference-every");
            if (!hlod_cli_parse_size(PROG, "--reference-every", v, 1, 1000000, &n))
                return 2;
            o->reference_every = (int)n;
        } else if (FLAG("--reference-ss")) {
            NEED("--reference-ss");
            if (!hlod_cli_parse_size(PROG, "--reference-ss", v, 1, 2, &n))
                return 2;
            o->reference_ss = (int)n;
        } else if (FLAG("--save-frames")) {
            NEED("--save-frames");
            if (!parse_save_frames(v, o))
                return 2;
        } else if (FLAG("--jitter-frames")) {
            NEED("--jitter-frames");
            if (!hlod_cli_parse_size(PROG, "--jitter-frames", v, 0, 1000000, &n))
                return 2;
            o->jitter_frames = (int)n;
        } else if (!strcmp(a, "--occlusion-check")) {
            o->occlusion_check = 1;
        } else if (!strcmp(a, "--cone-check")) {
            o->cone_check = 1;
        } else if (FLAG("--backend")) {
            NEED("--backend");
            if (!strcmp(v, "osmesa"))
                o->backend = BACKEND_OSMESA;
            else if (!strcmp(v, "egl"))
                o->backend = BACKEND_EGL;
            else
                return hlod_cli_usage_error(PROG, "--backend: '%s' is not osmesa or egl", v);
        } else if (!strcmp(a, "--compare")) {
            if (i + 2 >= argc)
                return hlod_cli_usage_error(PROG, "--compare needs two images%s", "");
            o->compare[0] = argv[++i];
            o->compare[1] = argv[++i];
        } else if (FLAG("--set")) {
            NEED("--set");
            if (o->nsets >= MAX_SETS)
                return hlod_cli_usage_error(PROG, "too many --set flags (%s)", "32");
            if (!parse_set(v, &o->sets[o->nsets]))
                return 2;
            o->nsets++;
        } else if (FLAG("--sweep")) {
            NEED("--sweep");
            if (o->sweep_key)
                return hlod_cli_usage_error(PROG, "--sweep given twice (%s)", v);
            if (!parse_sweep(v, o))
                return 2;
        } else if (!strcmp(a, "--deterministic")) {
            o->deterministic = 1;
        } else if (FLAG("--io-mbps")) {
            NEED("--io-mbps");
            if (!hlod_cli_parse_double(PROG, "--io-mbps", v, 0, 1e6, HLOD_CLI_MIN_OPEN,
                                       &o->io_mbps))
                return 2;
        } else if (!strcmp(a, "--realtime")) {
            o->realtime = 1;
        } else if (!strcmp(a, "--no-plots")) {
            o->plots = 0;
        } else if (!strcmp(a, "--json")) {
            o->json = 1;
        } else if (a[0] == '-' && a[1]) {
            return hlod_cli_usage_error(PROG, "unknown option '%s'", a);
        } else if (!o->store) {
            o->store = a;
        } else {
            return hlod_cli_usage_error(PROG, "unexpected argument '%s' (one store only)", a);
        }
#undef FLAG
#undef NEED
    }
    if (o->compare[0])
        return o->store ? hlod_cli_usage_error(PROG, "--compare takes no store ('%s')", o->store)
                        : -1;
    if (!o->store)
        return hlod_cli_usage_error(PROG, "no store given%s", "");
    if (!o->path)
        return hlod_cli_usage_error(PROG, "--path is required%s", "");
    if (!o->out)
        return hlod_cli_usage_error(PROG, "--out is required%s", "");
    if (o->reference && copy_levels(o))
        return hlod_cli_usage_error(PROG, "--reference draws the store once: not with "
                                    "rzb_copies or cube_copies (%s)", o->store);
    return -1;
}

/* ---- per-frame records ---- */

typedef struct frame_rec {
    hlod_frame_stats st;
    double t;
    double psnr, ssim;          /* NAN when no reference this frame */
    double luma, ref_luma;      /* change from the previous frame; NAN when unknown */
    double up_ma, down_ma;      /* toggles, 35-frame moving average */
    double occ_psnr;            /* --occlusion-check: against occlusion off; NAN without */
    long long occ_differing;    /* its differing pixels; -1 without */
    long long cone_differing;   /* --cone-check: pixels the culled nodes changed; -1 without */
    uint32_t cone_checked;      /* ... culled nodes drawn in the check */
    uint32_t cone_unchecked;    /* ... culled nodes not resident (not drawn) */
} frame_rec;

typedef struct summary {
    long frames;
    double target_ms;
    double mean, p50, p95, p99, max, within, over;
    uint64_t up, down, osc;
    double toggles_per_frame;
    double psnr_mean, psnr_min, ssim_mean, image_flicker;
    double tris_mean, traversal_mean, traversal_max;
    uint64_t loads, evictions, bytes_read, peak_resident, budget, missing_frames, waits;
    uint64_t cache_hits;                    /* payloads from HLOD_CACHE_DIR (not in bytes_read) */
    uint64_t lumi_bytes, lumi_answer_max;   /* policy lumigraph: view bytes fetched, largest */
    uint64_t lumi_missing_frames;           /* ... frames whose blend lacked a view */
    double loader_finish_ms, loader_busy_ms;    /* loader thread CPU time, whole run */
    uint64_t load_failures;                 /* failed reads (top nodes at start included) */
    uint32_t bad_nodes;                     /* nodes marked bad by the run's end */
    double v_time, fixed_ms;
    double deadline_met;                    /* fraction with measured <= target */
    double machine_p50, machine_p99;        /* the frozen replay; NAN without one */
    double est_err_p50, est_err_p95;        /* |estimated - measured| / measured */
    double occlusion_culled_mean;
    double cone_culled_mean;
    double cone_culled_tris_share;          /* culled nodes' triangles / (drawn + them) */
    double splats_mean;
    double res_scale_mean, res_scale_min;   /* dyn_res: the frames' scales */
    long res_scaled_frames;                 /* frames drawn below full size */
    long long cone_differing_max;           /* --cone-check; -1 without */
    unsigned long long cone_checked, cone_unchecked;
    uint64_t toggles_after_60;              /* up + down over frames 60.. */
    long margin_cap_frames, margin_cap_run; /* frames with the margin at its cap; the
                                               longest run of them */
    double occlusion_ms_mean;
    double overhead_mean, overhead_max;     /* traversal + occlusion ms per frame */
    double occ_psnr_min;                    /* --occlusion-check; NAN without */
    long long occ_differing_max, occ_bad;   /* -1 without */
    uint64_t jitter_frame;                  /* the replayed frame */
    int jitter_count;
    const char *gl_renderer;
    const char *texture_upload;             /* "blocks" or "expanded" */
    double grid_psnr_min;                   /* policy lumigraph: the client against the
                                               baked views at the path's grid points */
    int grid_checks;                        /* ... views checked */
} summary;

/* Frames from this one on count in toggles_after_60 (the still
 * camera settles in 2 s). */
#define SETTLED_FRAME 60

/* Quantiles over the frames' estimate error and the replay times. */
static void summarise_extra(const frame_rec *r, long n, double target, const double *jit,
                            int njit, summary *s)
{
    double *err = malloc((size_t)(n ? n : 1) * sizeof *err);
    size_t nerr = 0;
    long cap_run = 0;
    double coned_tris = 0, all_tris = 0; /* cone_culled_tris_share */
    s->occ_psnr_min = NAN;
    s->occ_differing_max = s->occ_bad = -1;
    s->cone_differing_max = -1;
    for (long i = 0; i < n; i++) {
        const hlod_frame_stats *st = &r[i].st;
        double overhead = st->traversal_ms + st->occlusion_ms;
        s->occlusion_ms_mean += st->occlusion_ms;
        s->overhead_mean += overhead;
        if (overhead > s->overhead_max)
            s->overhead_max = overhead;
        if (r[i].occ_differing >= 0) {
            if (s->occ_differing_max < 0)
                s->occ_differing_max = s->occ_bad = 0;
            if (r[i].occ_differing > s->occ_differing_max)
                s->occ_differing_max = r[i].occ_differing;
            if (isnan(s->occ_psnr_min) || r[i].occ_psnr < s->occ_psnr_min)
                s->occ_psnr_min = r[i].occ_psnr;
            /* the rule: no differing pixel, or >= 60 dB where the
             * rasteriser's order differs */
            s->occ_bad += r[i].occ_differing > 0 && r[i].occ_psnr < 60;
        }
        s->deadline_met += st->measured_ms <= target;
        s->occlusion_culled_mean += st->occlusion_culled;
        s->cone_culled_mean += st->cone_culled;
        coned_tris += (double)st->cone_culled_tris;
        all_tris += (double)st->cone_culled_tris + (double)st->tris_drawn;
        s->splats_mean += st->splats;
        double rs = st->res_scale > 0 ? st->res_scale : 1;
        s->res_scale_mean += rs;
        s->res_scale_min = i == 0 || rs < s->res_scale_min ? rs : s->res_scale_min;
        s->res_scaled_frames += rs < 1;
        if (r[i].cone_differing >= 0) {
            if (r[i].cone_differing > s->cone_differing_max)
                s->cone_differing_max = r[i].cone_differing;
            s->cone_checked += r[i].cone_checked;
            s->cone_unchecked += r[i].cone_unchecked;
        }
        if (i >= SETTLED_FRAME)
            s->toggles_after_60 += (uint64_t)st->toggles_up + st->toggles_down;
        cap_run = st->margin >= HLOD_MARGIN_MAX ? cap_run + 1 : 0;
        s->margin_cap_frames += cap_run > 0;
        s->margin_cap_run = cap_run > s->margin_cap_run ? cap_run : s->margin_cap_run;
        if (err && st->measured_ms > 0)
            err[nerr++] = fabs(st->estimated_ms - st->measured_ms) / st->measured_ms;
    }
    if (n) {
        s->occlusion_ms_mean /= (double)n;
        s->overhead_mean /= (double)n;
        s->deadline_met /= (double)n;
        s->occlusion_culled_mean /= (double)n;
        s->cone_culled_mean /= (double)n;
        s->cone_culled_tris_share = all_tris > 0 ? coned_tris / all_tris : 0;
        s->splats_mean /= (double)n;
        s->res_scale_mean /= (double)n;
    }
    s->est_err_p50 = s->est_err_p95 = NAN;
    if (err && nerr) {
        hlod_stats_sort(err, nerr);
        s->est_err_p50 = hlod_stats_percentile_sorted(err, nerr, 50);
        s->est_err_p95 = hlod_stats_percentile_sorted(err, nerr, 95);
    }
    free(err);
    s->machine_p50 = s->machine_p99 = NAN;
    s->jitter_count = njit;
    double *m = njit ? malloc((size_t)njit * sizeof *m) : NULL;
    if (m) {
        memcpy(m, jit, (size_t)njit * sizeof *m);
        hlod_stats_sort(m, (size_t)njit);
        s->machine_p50 = hlod_stats_percentile_sorted(m, (size_t)njit, 50);
        s->machine_p99 = hlod_stats_percentile_sorted(m, (size_t)njit, 99);
    }
    free(m);
}

static void summarise(const frame_rec *r, long n, double target, summary *s)
{
    memset(s, 0, sizeof *s);
    s->frames = n;
    s->target_ms = target;
    double *ms = malloc((size_t)(n ? n : 1) * sizeof *ms);
    double psnr_sum = 0, ssim_sum = 0, luma = 0, ref_luma = 0;
    long npsnr = 0, nluma = 0;
    s->psnr_min = NAN;
    for (long i = 0; i < n; i++) {
        const hlod_frame_stats *st = &r[i].st;
        ms[i] = st->measured_ms;
        s->within += fabs(st->measured_ms - target) <= 0.1 * target;
        s->over += st->measured_ms > target;
        s->up += st->toggles_up;
        s->down += st->toggles_down;
        s->osc += st->oscillations;
        s->tris_mean += (double)st->tris_drawn;
        s->traversal_mean += st->traversal_ms;
        if (st->traversal_ms > s->traversal_max)
            s->traversal_max = st->traversal_ms;
        s->loads += st->loads;
        s->evictions += st->evictions;
        s->bytes_read += st->bytes_read;
        s->cache_hits += st->cache_hits;
        s->lumi_bytes += st->lumi_bytes;
        if (st->lumi_answer_max > s->lumi_answer_max)
            s->lumi_answer_max = st->lumi_answer_max;
        s->lumi_missing_frames += st->lumi_missing > 0;
        s->loader_finish_ms += st->loader_finish_ms;
        s->loader_busy_ms += st->loader_busy_ms;
        if (st->resident_bytes > s->peak_resident)
            s->peak_resident = st->resident_bytes;
        s->budget = st->memory_budget_bytes;
        s->missing_frames += st->wanted_missing > 0;
        s->waits += st->render_waits;
        s->load_failures += st->load_failures;
        s->bad_nodes = st->bad_nodes; /* a running total */
        if (!isnan(r[i].psnr)) {
            psnr_sum += r[i].psnr;
            ssim_sum += r[i].ssim;
            s->psnr_min = npsnr == 0 || r[i].psnr < s->psnr_min ? r[i].psnr : s->psnr_min;
            npsnr++;
        }
        if (!isnan(r[i].luma) && !isnan(r[i].ref_luma)) {
            luma += r[i].luma;
            ref_luma += r[i].ref_luma;
            nluma++;
        }
        s->v_time = st->v_time;
        s->fixed_ms = st->fixed_ms;
    }
    if (n) {
        s->mean = hlod_stats_mean(ms, (size_t)n);
        hlod_stats_sort(ms, (size_t)n);
        s->p50 = hlod_stats_percentile_sorted(ms, (size_t)n, 50);
        s->p95 = hlod_stats_percentile_sorted(ms, (size_t)n, 95);
        s->p99 = hlod_stats_percentile_sorted(ms, (size_t)n, 99);
        s->max = ms[n - 1];
        s->within /= (double)n;
        s->over /= (double)n;
        s->tris_mean /= (double)n;
        s->traversal_mean /= (double)n;
        s->toggles_per_frame = (double)(s->up + s->down) / (double)n;
    }
    s->psnr_mean = npsnr ? psnr_sum / (double)npsnr : NAN;
    s->ssim_mean = npsnr ? ssim_sum / (double)npsnr : NAN;
    s->image_flicker = nluma ? (luma - ref_luma) / (double)nluma : NAN;
    free(ms);
}

static void moving_averages(frame_rec *r, long n)
{
    double *in = malloc((size_t)(n ? n : 1) * sizeof *in), *ma = malloc((size_t)(n ? n : 1) * sizeof *ma);
    if (!in || !ma) {
        free(in);
        free(ma);
        return;
    }
    for (int dir = 0; dir < 2; dir++) {
        for (long i = 0; i < n; i++)
            in[i] = dir ? r[i].st.toggles_down : r[i].st.toggles_up;
        if (n && hlod_stats_moving_average(in, (size_t)n, 35, ma) == HLOD_OK)
            for (long i = 0; i < n; i++)
                *(dir ? &r[i].down_ma : &r[i].up_ma) = ma[i];
    }
    free(in);
    free(ma);
}

/* ---- outputs ---- */

static hlod_result write_frames_csv(const char *dir, const frame_rec *r, long n, uint32_t depths,
                                    const hlod_logger *lg)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/frames.csv", dir);
    hlod_atomic_file af;
    hlod_result res = hlod_atomic_open(&af, path, lg);
    if (res != HLOD_OK)
        return res;
    FILE *fp = af.fp;
    fprintf(fp, "frame,t,measured_ms,estimated_ms,v_time,fixed_ms,budget_ms,share_gain,"
                "traversal_ms,upload_ms,sse_pixels,nodes_drawn");
    for (uint32_t d = 0; d < depths; d++)
        fprintf(fp, ",depth%u", d);
    fprintf(fp, ",tris_drawn,cost_drawn,toggles_up,toggles_down,oscillations,nodes_visited,"
                "wanted_missing,resident_nodes,resident_bytes,resident_cost,memory_budget_bytes,"
                "loads,evictions,bytes_read,load_failures,bad_nodes,queued,render_waits,psnr,"
                "ssim,luma_change,ref_luma_change,toggles_up_ma35,toggles_down_ma35,"
                "pixels_drawn,margin,occlusion_hidden,occlusion_tested,occlusion_culled,"
                "occlusion_ms,occlusion_check_psnr,occlusion_check_differing,cone_culled,"
                "cone_check_differing,splats,splat_px,res_scale,cone_culled_tris,lumi_bytes,"
                "lumi_missing,gl_draws\n");
    for (long i = 0; i < n; i++) {
        const hlod_frame_stats *s = &r[i].st;
        fprintf(fp, "%llu,%.6f,%.4f,%.4f,%.9g,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%u",
                (unsigned long long)s->frame, r[i].t, s->measured_ms, s->estimated_ms, s->v_time,
                s->fixed_ms, s->budget_ms, s->share_gain, s->traversal_ms, s->upload_ms,
                s->sse_pixels, s->nodes_drawn);
        for (uint32_t d = 0; d < depths; d++)
            fprintf(fp, ",%u", s->nodes_per_depth[d]);
        fprintf(fp, ",%llu,%.3f,%u,%u,%u,%u,%u,%u,%llu,%.0f,%llu,%u,%u,%llu,%u,%u,%u,%u",
                (unsigned long long)s->tris_drawn, s->cost_drawn, s->toggles_up,
                s->toggles_down, s->oscillations, s->nodes_visited, s->wanted_missing,
                s->resident_nodes, (unsigned long long)s->resident_bytes, s->resident_cost,
                (unsigned long long)s->memory_budget_bytes, s->loads, s->evictions,
                (unsigned long long)s->bytes_read, s->load_failures, s->bad_nodes, s->queued,
                s->render_waits);
        if (isnan(r[i].psnr))
            fprintf(fp, ",,");
        else
            fprintf(fp, ",%.4f,%.6f", r[i].psnr, r[i].ssim);
        if (isnan(r[i].luma))
            fprintf(fp, ",");
        else
            fprintf(fp, ",%.5f", r[i].luma);
        if (isnan(r[i].ref_luma))
            fprintf(fp, ",");
        else
            fprintf(fp, ",%.5f", r[i].ref_luma);
        fprintf(fp, ",%.4f,%.4f,%.0f,%.4f,%u,%u,%u,%.4f", r[i].up_ma, r[i].down_ma,
                s->pixels_drawn, s->margin, s->occlusion_hidden, s->occlusion_tested,
                s->occlusion_culled, s->occlusion_ms);
        if (r[i].occ_differing < 0)
            fprintf(fp, ",,");
        else
            fprintf(fp, ",%.4f,%lld", r[i].occ_psnr, r[i].occ_differing);
        fprintf(fp, ",%u", s->cone_culled);
        if (r[i].cone_differing < 0)
            fprintf(fp, ",");
        else
            fprintf(fp, ",%lld", r[i].cone_differing);
        fprintf(fp, ",%u,%.3f,%.4f,%llu,%llu,%u,%u\n", s->splats, s->splat_px,
                s->res_scale > 0 ? s->res_scale : 1.0, (unsigned long long)s->cone_culled_tris,
                (unsigned long long)s->lumi_bytes, s->lumi_missing, s->gl_draws);
    }
    return hlod_atomic_commit(&af, lg);
}

static void json_summary(hlod_json *j, const summary *s, const char *policy, const char *path,
                         const options *o)
{
    hlod_json_int(j, "frames", s->frames);
    hlod_json_double(j, "target_ms", s->target_ms);
    hlod_json_double(j, "frame_ms_mean", s->mean);
    hlod_json_double(j, "frame_ms_p50", s->p50);
    hlod_json_double(j, "frame_ms_p95", s->p95);
    hlod_json_double(j, "frame_ms_p99", s->p99);
    hlod_json_double(j, "frame_ms_max", s->max);
    hlod_json_double(j, "within_10pct", s->within);
    hlod_json_double(j, "over_target_frac", s->over);
    hlod_json_int(j, "toggles_up", (long long)s->up);
    hlod_json_int(j, "toggles_down", (long long)s->down);
    hlod_json_double(j, "toggles_per_frame", s->toggles_per_frame);
    hlod_json_int(j, "oscillations", (long long)s->osc);
    hlod_json_double(j, "psnr_mean", s->psnr_mean);
    hlod_json_double(j, "psnr_min", s->psnr_min);
    hlod_json_double(j, "ssim_mean", s->ssim_mean);
    hlod_json_double(j, "image_flicker", s->image_flicker);
    hlod_json_double(j, "tris_mean", s->tris_mean);
    hlod_json_int(j, "loads", (long long)s->loads);
    hlod_json_int(j, "evictions", (long long)s->evictions);
    hlod_json_int(j, "bytes_read", (long long)s->bytes_read);
    hlod_json_int(j, "cache_hits", (long long)s->cache_hits);
    hlod_json_int(j, "bytes_fetched", (long long)s->lumi_bytes);
    hlod_json_int(j, "answer_bytes_max", (long long)s->lumi_answer_max);
    hlod_json_int(j, "lumi_missing_frames", (long long)s->lumi_missing_frames);
    hlod_json_double(j, "grid_point_psnr_min", s->grid_psnr_min);
    hlod_json_int(j, "grid_point_checks", s->grid_checks);
    hlod_json_double(j, "loader_finish_ms", s->loader_finish_ms);
    hlod_json_double(j, "loader_busy_ms", s->loader_busy_ms);
    hlod_json_double(j, "loader_finish_share",
                     s->loader_busy_ms > 0 ? s->loader_finish_ms / s->loader_busy_ms : 0);
    hlod_json_int(j, "peak_resident_bytes", (long long)s->peak_resident);
    hlod_json_int(j, "memory_budget_bytes", (long long)s->budget);
    hlod_json_int(j, "missing_wanted_frames", (long long)s->missing_frames);
    hlod_json_int(j, "render_waits", (long long)s->waits);
    hlod_json_int(j, "bad_nodes", (long long)s->bad_nodes);
    hlod_json_int(j, "load_failures", (long long)s->load_failures);
    hlod_json_double(j, "traversal_ms_mean", s->traversal_mean);
    hlod_json_double(j, "traversal_ms_max", s->traversal_max);
    hlod_json_double(j, "v_time_final", s->v_time);
    hlod_json_double(j, "fixed_ms_final", s->fixed_ms);
    hlod_json_double(j, "deadline_met", s->deadline_met);
    hlod_json_int(j, "margin_cap_frames", s->margin_cap_frames);
    hlod_json_int(j, "margin_cap_run_max", s->margin_cap_run);
    hlod_json_double(j, "res_scale_mean", s->res_scale_mean);
    hlod_json_double(j, "res_scale_min", s->res_scale_min);
    hlod_json_int(j, "res_scaled_frames", s->res_scaled_frames);
    hlod_json_double(j, "machine_p50_ms", s->machine_p50);
    hlod_json_double(j, "machine_p99_ms", s->machine_p99);
    hlod_json_double(j, "machine_p99_over_p50", s->machine_p99 / s->machine_p50);
    hlod_json_int(j, "machine_frame", s->jitter_count ? (long long)s->jitter_frame : -1);
    hlod_json_int(j, "machine_replays", s->jitter_count);
    hlod_json_double(j, "estimate_err_p50", s->est_err_p50);
    hlod_json_double(j, "estimate_err_p95", s->est_err_p95);
    hlod_json_double(j, "occlusion_culled_mean", s->occlusion_culled_mean);
    hlod_json_int(j, "toggles_after_60", (long long)s->toggles_after_60);
    hlod_json_double(j, "occlusion_ms_mean", s->occlusion_ms_mean);
    hlod_json_double(j, "overhead_ms_mean", s->overhead_mean);
    hlod_json_double(j, "overhead_ms_max", s->overhead_max);
    hlod_json_double(j, "occlusion_check_psnr_min", s->occ_psnr_min);
    if (s->occ_differing_max < 0) {
        hlod_json_string(j, "occlusion_check_differing_max", NULL);
        hlod_json_string(j, "occlusion_check_bad_frames", NULL);
    } else {
        hlod_json_int(j, "occlusion_check_differing_max", s->occ_differing_max);
        hlod_json_int(j, "occlusion_check_bad_frames", s->occ_bad);
    }
    hlod_json_double(j, "cone_culled_mean", s->cone_culled_mean);
    hlod_json_double(j, "cone_culled_tris_share", s->cone_culled_tris_share);
    hlod_json_double(j, "splats_mean", s->splats_mean);
    if (s->cone_differing_max < 0) {
        hlod_json_string(j, "cone_check_differing_max", NULL);
        hlod_json_string(j, "cone_check_nodes", NULL);
        hlod_json_string(j, "cone_check_unchecked", NULL);
    } else {
        hlod_json_int(j, "cone_check_differing_max", s->cone_differing_max);
        hlod_json_int(j, "cone_check_nodes", (long long)s->cone_checked);
        hlod_json_int(j, "cone_check_unchecked", (long long)s->cone_unchecked);
    }
    hlod_json_string(j, "policy", policy);
    hlod_json_string(j, "path", path);
    hlod_json_int(j, "width", o->width);
    hlod_json_int(j, "height", o->height);
    hlod_json_bool(j, "deterministic", o->deterministic);
    hlod_json_bool(j, "reference", o->reference);
    hlod_json_int(j, "reference_ss", o->reference_ss);
    hlod_json_string(j, "backend", o->backend == BACKEND_EGL ? "egl" : "osmesa");
    hlod_json_string(j, "gl_renderer", s->gl_renderer);
    hlod_json_string(j, "texture_upload", s->texture_upload);
}

static hlod_result write_summary(const char *dir, const summary *s, const char *policy,
                                 const char *path, const options *o, const hlod_logger *lg)
{
    char file[4200];
    snprintf(file, sizeof file, "%s/summary.json", dir);
    hlod_atomic_file af;
    hlod_result r = hlod_atomic_open(&af, file, lg);
    if (r != HLOD_OK)
        return r;
    hlod_json j;
    hlod_json_begin(&j, af.fp);
    json_summary(&j, s, policy, path, o);
    hlod_json_end(&j);
    return hlod_atomic_commit(&af, lg);
}

/* Runs gnuplot on script text; 0 on success. */
static int run_gnuplot(const char *dir, const char *name, const char *script)
{
    char gp[4096], cmd[8400];
    snprintf(gp, sizeof gp, "%s/%s.gp", dir, name);
    FILE *fp = fopen(gp, "w");
    if (!fp) {
        hlod_cli_error(PROG, "%s: cannot write: %s", gp, strerror(errno));
        return 1;
    }
    fputs(script, fp);
    if (fclose(fp) != 0) {
        hlod_cli_error(PROG, "%s: cannot write: %s", gp, strerror(errno));
        return 1;
    }
    snprintf(cmd, sizeof cmd, "cd '%s' && gnuplot '%s.gp' 2>'%s.log'", dir, name, name);
    if (system(cmd) != 0) {
        hlod_cli_error(PROG, "%s/%s.gp: gnuplot failed (see %s/%s.log)", dir, name, dir, name);
        return 1;
    }
    return 0;
}

static int plot_run(const char *dir, uint32_t depths, int have_psnr, double target)
{
    /* frames.csv columns: 1 frame, 3 measured, 4 estimated, 12 nodes_drawn,
     * 13.. depth d, then tris, cost, up, down, ... */
    int c_depth0 = 13, c_up = 13 + (int)depths + 2;
    int c_res = c_up + 6, c_budget = c_up + 8;
    int c_psnr = c_up + 16, c_up_ma = c_up + 20, c_down_ma = c_up + 21;
    char s[8192];
    int n = snprintf(s, sizeof s,
        "set datafile separator ','\nset terminal pngcairo size 1100,500\nset key outside\n"
        "set grid\nset xlabel 'frame'\n"
        "set output 'frame_time.png'\nset title 'Frame time vs target (Lakhia Fig. 9)'\n"
        "set ylabel 'ms'\nplot 'frames.csv' every ::1 using 1:3 with lines title 'measured', "
        "'' every ::1 using 1:4 with lines title 'estimated', %g with lines dt 2 title "
        "'target'\n"
        "set output 'nodes_per_depth.png'\nset title 'Nodes drawn per depth (Lakhia Fig. 7)'\n"
        "set ylabel 'nodes'\nplot for [d=0:%u] 'frames.csv' every ::1 using 1:(column(%d+d)) "
        "with lines title sprintf('depth %%d', d)\n"
        "set output 'toggles.png'\nset title 'Toggles, 35-frame moving average (Lakhia Fig. 8)'\n"
        "set ylabel 'toggles per frame'\n"
        "plot 'frames.csv' every ::1 using 1:(column(%d)) with lines title 'up', "
        "'' every ::1 using 1:(-column(%d)) with lines title 'down (negative)', 0 with lines "
        "lc rgb 'black' notitle\n"
        "set output 'memory.png'\nset title 'Resident memory vs budget'\nset ylabel 'MiB'\n"
        "plot 'frames.csv' every ::1 using 1:(column(%d)/1048576.0) with lines title "
        "'resident', '' every ::1 using 1:(column(%d)/1048576.0) with lines dt 2 title "
        "'budget'\n",
        target, depths ? depths - 1 : 0, c_depth0, c_up_ma, c_down_ma, c_res, c_budget);
    if (have_psnr && n > 0 && (size_t)n < sizeof s)
        snprintf(s + n, sizeof s - (size_t)n,
                 "set output 'psnr.png'\nset title 'PSNR against the full-detail reference'\n"
                 "set ylabel 'dB'\nplot 'frames.csv' every ::1 using 1:%d with linespoints "
                 "pt 7 ps 0.3 title 'PSNR'\n",
                 c_psnr);
    return run_gnuplot(dir, "plots", s);
}

/* ---- GL contexts ---- */

/* A headless context of one backend with its own renderer. */
typedef struct gl_target {
    hlod_osmesa *osmesa;
#ifdef HLOD_HAVE_EGL
    hlod_egl *egl;
#endif
    hlod_renderer *renderer;
    uint32_t width, height;
} gl_target;

static hlod_result target_create(int backend, uint32_t w, uint32_t h, const hlod_logger *lg,
                                 gl_target *t)
{
    memset(t, 0, sizeof *t);
    t->width = w;
    t->height = h;
    hlod_result r;
    hlod_gl_get_proc get_proc;
    if (backend == BACKEND_EGL) {
#ifdef HLOD_HAVE_EGL
        r = hlod_egl_create(w, h, lg, &t->egl);
        get_proc = hlod_egl_get_proc();
#else
        hlod_logf(lg, HLOD_LOG_ERROR, "--backend egl: this hlod-bench was built without EGL "
                  "(libegl-dev was missing when cmake ran)");
        return HLOD_ERR_UNSUPPORTED;
#endif
    } else {
        r = hlod_osmesa_create(w, h, lg, &t->osmesa);
        get_proc = hlod_osmesa_get_proc();
    }
    if (r == HLOD_OK)
        r = hlod_renderer_create(get_proc, lg, &t->renderer);
    if (r == HLOD_OK && t->osmesa)
        hlod_osmesa_share_depth(t->osmesa, t->renderer); /* occlusion reads depth in place */
    return r;
}

static hlod_result target_current(gl_target *t)
{
#ifdef HLOD_HAVE_EGL
    if (t->egl)
        return hlod_egl_make_current(t->egl);
#endif
    return hlod_osmesa_make_current(t->osmesa);
}

/* The current image, top row first; t current. */
static hlod_result target_read(gl_target *t, uint8_t *rgb)
{
#ifdef HLOD_HAVE_EGL
    if (t->egl)
        return hlod_egl_read_rgb(t->egl, rgb);
#endif
    return hlod_osmesa_read_rgb(t->osmesa, rgb);
}

static const char *target_name(const gl_target *t)
{
#ifdef HLOD_HAVE_EGL
    if (t->egl)
        return hlod_egl_renderer_name(t->egl);
#endif
    return t->osmesa ? hlod_osmesa_renderer_name(t->osmesa) : "";
}

static void target_destroy(gl_target *t)
{
    int have = t->osmesa != NULL;
#ifdef HLOD_HAVE_EGL
    have |= t->egl != NULL;
#endif
    if (have && target_current(t) == HLOD_OK)
        hlod_renderer_destroy(t->renderer);
#ifdef HLOD_HAVE_EGL
    hlod_egl_destroy(t->egl);
#endif
    hlod_osmesa_destroy(t->osmesa);
    memset(t, 0, sizeof *t);
}

/* dst (w x h RGB) = src (2w x 2h RGB) averaged over 2 x 2 blocks. */
static void downsample_2x2(const uint8_t *src, uint32_t w, uint32_t h, uint8_t *dst)
{
    size_t row = (size_t)w * 2 * 3;
    for (uint32_t y = 0; y < h; y++) {
        const uint8_t *a = src + (size_t)y * 2 * row, *b = a + row;
        uint8_t *d = dst + (size_t)y * w * 3;
        for (uint32_t x = 0; x < w; x++)
            for (int k = 0; k < 3; k++) {
                size_t i = (size_t)x * 6 + (size_t)k;
                d[(size_t)x * 3 + (size_t)k] = (uint8_t)((a[i] + a[i + 3] + b[i] + b[i + 3] + 2) / 4);
            }
    }
}

/* Writes a w x h RGB image as DIR/frame_NNNNN<suffix>.png; 0 on success. */
static int write_frame_png(const char *dir, uint64_t f, const char *suffix, const uint8_t *rgb,
                           uint32_t w, uint32_t h, const hlod_logger *lg)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/frame_%05llu%s.png", dir, (unsigned long long)f, suffix);
    hlod_image img = {(int)w, (int)h, 3, (uint8_t *)rgb}; /* only read */
    if (hlod_image_write(path, &img, lg) != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot write the frame image", path);
        return 1;
    }
    return 0;
}

/* ---- one run ---- */

typedef struct context {
    const options *o;
    hlod_store *store;
    hlod_store *ref_store;      /* --reference-store, or NULL: the measured store */
    hlod_path path;
    const char *path_name;
    gl_target gl;               /* the measured engine's context */
    gl_target ref_gl;           /* the reference's, ss * W x ss * H */
    hlod_logger lg;
    uint8_t *img, *prev_img, *ref, *prev_ref;
    uint8_t *ref_big;           /* the reference's read-back at ss * W x ss * H */
    uint8_t *occ_img;           /* --occlusion-check: the frame drawn without occlusion */
    uint8_t *cone_img;          /* --cone-check: the frame drawn with the cone-culled nodes */
    /* Reference frames depend on the camera alone, not on the policy or a
     * swept constant, so one invocation renders each frame's reference
     * once and keeps it (up to REF_CACHE_BYTES): a policy comparison or a
     * sweep pays for the full-detail renders only once. */
    hlod_engine *ref_engine;
    uint8_t **ref_cache; /* per frame index, NULL until rendered */
    uint64_t ref_cache_frames;
    size_t ref_cache_bytes;
    int ref_flip;
} context;

#define REF_CACHE_BYTES ((size_t)3 << 30)

/* The camera of frame f for a w x h viewport (the measured one, or the
 * supersampled reference's: the same view, more pixels). */
static void path_camera_size(const context *c, uint64_t f, uint32_t width, uint32_t height,
                             hlod_camera *cam, double *t_out)
{
    const options *o = c->o;
    double t = hlod_path_frame_time(&c->path, o->dt, f), eye[3], at[3];
    hlod_path_eval(&c->path, t, eye, at);
    const hlod_store_header *h = hlod_store_get_header(c->store);
    /* the scene's box: with rzb_copies or cube_copies, its copies' along x and y */
    double lo[3], hi[3], diag = 0;
    for (int k = 0; k < 3; k++) {
        lo[k] = h->bbox_min[k];
        hi[k] = h->bbox_max[k];
        if (k < 2)
            hi[k] = lo[k] + ldexp(hi[k] - lo[k], (int)copy_levels(o));
        diag += (hi[k] - lo[k]) * (hi[k] - lo[k]);
    }
    double far_plane = 3 * sqrt(diag) + 1000;
    for (int k = 0; k < 3; k++) {
        double m = fabs(eye[k] - 0.5 * (lo[k] + hi[k]));
        far_plane += m;
    }
    double up[3] = {0, o->up_y ? 1 : 0, o->up_y ? 0 : 1};
    if (hlod_camera_look_at(cam, eye, at, up, o->fov, o->near_plane, far_plane, width,
                            height) != HLOD_OK) {
        /* looking straight along the up axis: tilt the up vector */
        double up2[3] = {0, o->up_y ? 0 : 1, o->up_y ? 1 : 0};
        hlod_camera_look_at(cam, eye, at, up2, o->fov, o->near_plane, far_plane, width, height);
    }
    *t_out = t;
}

static void path_camera(const context *c, uint64_t f, hlod_camera *cam, double *t_out)
{
    path_camera_size(c, f, c->o->width, c->o->height, cam, t_out);
}

/* Frames a run replays: the path's, or --frames when fewer. */
static uint64_t run_frames(const context *c)
{
    uint64_t total = hlod_path_frame_count(&c->path, c->o->dt);
    if (c->o->frames > 0 && (uint64_t)c->o->frames < total)
        total = (uint64_t)c->o->frames;
    return total;
}

/* Calibrates v_time and fixed_ms for --deterministic from a short warm-up
 * in the normal mode. */
static hlod_result calibrate(context *c, const hlod_engine_desc *base, double *v_time,
                             double *fixed_ms)
{
    hlod_engine_desc d = *base;
    d.deterministic = 0;
    hlod_engine *e = NULL;
    hlod_result r = hlod_engine_create(c->store, &d, &e);
    if (r != HLOD_OK)
        return r;
    hlod_frame_stats st;
    uint64_t n = hlod_path_frame_count(&c->path, c->o->dt);
    double sum_front = 0, sum_cost = 0;
    for (int i = 0; i < 60; i++) {
        hlod_camera cam;
        double t;
        path_camera(c, (uint64_t)i * (n > 60 ? n / 60 : 1) % (n ? n : 1), &cam, &t);
        r = hlod_engine_frame(e, &cam, c->o->dt, &st);
        if (r != HLOD_OK)
            break;
        /* The deterministic engine prices by cost alone: the fitted
         * model's other terms (per draw, per pixel) are folded into ms per
         * cost over the warm-up's second half.  One frame alone may have
         * no front (all fixed part, or nothing drawn); then v_time, often
         * at its floor when draws and pixels carry the cost, would give
         * the deterministic run an unbounded budget (seen: 1e-9 on fly). */
        double front = st.estimated_ms - st.upload_ms - st.fixed_ms;
        if (i >= 30 && st.cost_drawn > 0 && front > 0) {
            sum_front += front;
            sum_cost += st.cost_drawn;
        }
    }
    *v_time = sum_cost > 0 ? sum_front / sum_cost : base->fixed_v_time;
    if (!(*v_time > 0))
        *v_time = 1e-4; /* the setting's default */
    *fixed_ms = st.fixed_ms;
    hlod_engine_destroy(e);
    return r;
}

/* The full-detail image of frame f (W x H): from the cache, or drawn by
 * the reference engine (created on first use, kept for the whole
 * invocation so its loaded leaves serve every run) in its own context at
 * ss * W x ss * H and box-filtered down.  The measured engine's context is
 * current again on return.  The result stays valid until the next call at
 * least.  NULL on failure. */
static const uint8_t *reference_image(context *c, uint64_t f)
{
    const options *o = c->o;
    if (f < c->ref_cache_frames && c->ref_cache[f])
        return c->ref_cache[f];
    if (target_current(&c->ref_gl) != HLOD_OK)
        return NULL;
    const uint8_t *result = NULL;
    if (!c->ref_engine) {
        hlod_engine_desc rd = {0};
        rd.policy = HLOD_POLICY_FULL;
        rd.renderer = c->ref_gl.renderer;
        rd.logger = c->lg;
        rd.deterministic = 1; /* no loader thread: load_all_leaves loads */
        rd.memory_budget_bytes = UINT64_MAX / 4;
        hlod_result r = hlod_engine_create(c->ref_store ? c->ref_store : c->store, &rd,
                                           &c->ref_engine);
        if (r != HLOD_OK) {
            hlod_cli_error(PROG, "%s: cannot start the reference engine: %s", o->store,
                           hlod_result_str(r));
            c->ref_engine = NULL;
            goto out;
        }
    }
    hlod_camera cam;
    double t;
    path_camera_size(c, f, c->ref_gl.width, c->ref_gl.height, &cam, &t);
    hlod_frame_stats rs;
    if (hlod_engine_load_all_leaves(c->ref_engine, &cam) != HLOD_OK ||
        hlod_engine_frame(c->ref_engine, &cam, o->dt, &rs) != HLOD_OK)
        goto out;
    size_t npix = (size_t)o->width * o->height * 3;
    uint8_t *dst = NULL;
    if (f < c->ref_cache_frames && c->ref_cache_bytes + npix <= REF_CACHE_BYTES) {
        dst = malloc(npix);
        if (dst) {
            c->ref_cache[f] = dst;
            c->ref_cache_bytes += npix;
        }
    }
    if (!dst) { /* not cached: two scratch images in turn */
        dst = c->ref_flip ? c->prev_ref : c->ref;
        c->ref_flip ^= 1;
    }
    if (target_read(&c->ref_gl, o->reference_ss == 1 ? dst : c->ref_big) != HLOD_OK) {
        if (f < c->ref_cache_frames && c->ref_cache[f] == dst) {
            free(dst);
            c->ref_cache[f] = NULL;
            c->ref_cache_bytes -= npix;
        }
        goto out;
    }
    if (o->reference_ss == 2)
        downsample_2x2(c->ref_big, o->width, o->height, dst);
    result = dst;
out:
    if (target_current(&c->gl) != HLOD_OK)
        return NULL;
    return result;
}

/* DIR/jitter.csv: one row per replay of the frozen selection. */
static hlod_result write_jitter_csv(const char *dir, const double *ms, int n,
                                    const hlod_logger *lg)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/jitter.csv", dir);
    hlod_atomic_file af;
    hlod_result res = hlod_atomic_open(&af, path, lg);
    if (res != HLOD_OK)
        return res;
    fprintf(af.fp, "i,ms\n");
    for (int i = 0; i < n; i++)
        fprintf(af.fp, "%d,%.4f\n", i, ms[i]);
    return hlod_atomic_commit(&af, lg);
}

/* The engine description of one run: the options, --set, the swept value,
 * and for --deterministic the calibrated constants.  0, or 1 when the
 * calibration fails. */
static int run_desc(context *c, hlod_policy policy, const setting *extra, hlod_engine_desc *d)
{
    const options *o = c->o;
    memset(d, 0, sizeof *d);
    d->target_ms = o->target_ms;
    d->policy = policy;
    d->renderer = c->gl.renderer;
    d->logger = c->lg;
    d->lumigraph_repo = o->repo;
    d->lumigraph_answers = o->answers;
    d->memory_budget_bytes = o->memory_mb > 0 ? (uint64_t)(o->memory_mb * 1048576.0)
                                              : view_default_budget(c->store);
    for (int i = 0; i < o->nsets; i++)
        apply_setting(d, o->sets[i].key, o->sets[i].value);
    if (extra)
        apply_setting(d, extra->key, extra->value);
    if (!o->deterministic)
        return 0;
    int have_v = given(o, extra, "v_time"), have_fixed = given(o, extra, "fixed_ms");
    if (!have_v || !have_fixed) {
        double v, fixed;
        if (calibrate(c, d, &v, &fixed) != HLOD_OK) {
            hlod_cli_error(PROG, "%s: calibration run failed", o->store);
            return 1;
        }
        if (!have_v)
            d->fixed_v_time = v;
        if (!have_fixed)
            d->fixed_frame_ms = fixed < d->target_ms ? fixed : 0.5 * d->target_ms;
        fprintf(stderr, "%s: calibrated v_time %.6g ms/cost, fixed %.3g ms (pass them "
                "with --set to repeat this run exactly)\n", PROG, d->fixed_v_time,
                d->fixed_frame_ms);
    }
    d->deterministic = 1;
    if (!given(o, extra, "deterministic_load_bytes")) /* else --set wins over --io-mbps */
        d->deterministic_load_bytes = (uint64_t)(o->io_mbps * 1e6 * o->dt);
    if (!d->deterministic_load_bytes)
        d->deterministic_load_bytes = 1;
    return 0;
}

/* What one run's frames share, and carry from one frame to the next. */
typedef struct run_state {
    context *c;
    hlod_engine *e;
    const char *dir;
    frame_rec *rec;
    uint64_t total;
    double *jit;                /* the machine's jitter: frame total / 2's selection, replayed */
    int njit;
    uint64_t jitter_frame;
    int have_prev;              /* c->prev_img holds the previous frame */
    const uint8_t *prev_ref;    /* the last scored reference */
    hlod_cli_progress bar;
    double wall0;               /* --realtime: frame 0's start, ms */
    double grid_psnr_min;       /* policy lumigraph: grid_point_check's; NAN without */
    int grid_checks;
} run_state;

/* Reads frame f's image back when anything needs it; *image is NULL when
 * not read.  0, or 1 on failure. */
static int frame_image(run_state *s, uint64_t f, frame_rec *fr, int save, const uint8_t **image)
{
    context *c = s->c;
    const options *o = c->o;
    *image = NULL;
    if (o->reference || save || o->occlusion_check || o->cone_check) {
        hlod_result r = target_read(&c->gl, c->img);
        if (r != HLOD_OK) {
            hlod_cli_progress_clear(&s->bar);
            hlod_cli_error(PROG, "frame %llu: cannot read the image back: %s",
                           (unsigned long long)f, hlod_result_str(r));
            return 1;
        }
        *image = c->img;
    }
    if (o->reference) {
        if (s->have_prev)
            hlod_luma_change_rgb8(c->prev_img, c->img, o->width, o->height, &fr->luma);
        /* the flicker needs the previous frame: keep this one */
        uint8_t *t = c->prev_img;
        c->prev_img = c->img;
        c->img = t;
        *image = c->prev_img;
        s->have_prev = 1;
    }
    return 0;
}

/* The pixels of two RGB images of npix pixels that differ. */
static long long differing_pixels(const uint8_t *a, const uint8_t *b, size_t npix)
{
    long long differ = 0;
    for (size_t k = 0; k < npix; k++)
        differ += memcmp(a + 3 * k, b + 3 * k, 3) != 0;
    return differ;
}

/* --occlusion-check: the same selection without occlusion culling must
 * draw the same image.  0, or 1 on failure. */
static int check_occlusion(run_state *s, uint64_t f, const hlod_camera *cam,
                           const uint8_t *image, frame_rec *fr)
{
    context *c = s->c;
    const options *o = c->o;
    double ms;
    hlod_result r = hlod_engine_replay(s->e, cam, 0, &ms);
    if (r == HLOD_OK)
        r = target_read(&c->gl, c->occ_img);
    if (r != HLOD_OK) {
        hlod_cli_progress_clear(&s->bar);
        hlod_cli_error(PROG, "%s: frame %llu: the occlusion check's replay failed: %s",
                       o->store, (unsigned long long)f, hlod_result_str(r));
        return 1;
    }
    fr->occ_differing = differing_pixels(image, c->occ_img, (size_t)o->width * o->height);
    hlod_psnr_rgb8(image, c->occ_img, o->width, o->height, &fr->occ_psnr);
    return 0;
}

/* --cone-check: the frame's selection drawn again with the nodes normal
 * cones culled must draw the same image.  0, or 1 on failure. */
static int check_cones(run_state *s, uint64_t f, const hlod_camera *cam, const uint8_t *image,
                       frame_rec *fr)
{
    context *c = s->c;
    const options *o = c->o;
    hlod_result r = hlod_engine_replay_coned(s->e, cam, &fr->cone_checked, &fr->cone_unchecked);
    if (r == HLOD_OK)
        r = target_read(&c->gl, c->cone_img);
    if (r != HLOD_OK) {
        hlod_cli_progress_clear(&s->bar);
        hlod_cli_error(PROG, "%s: frame %llu: the cone check's replay failed: %s", o->store,
                       (unsigned long long)f, hlod_result_str(r));
        return 1;
    }
    fr->cone_differing = differing_pixels(image, c->cone_img, (size_t)o->width * o->height);
    return 0;
}

/* The frozen selection of frame f drawn njit times: called after the
 * frame, before its reference, so the loaded state is the frame's own.
 * 0, or 1 on failure. */
static int replay_jitter(run_state *s, uint64_t f, const hlod_camera *cam)
{
    hlod_result r = HLOD_OK;
    for (int k = 0; k < s->njit && r == HLOD_OK; k++)
        r = hlod_engine_replay(s->e, cam, 1, &s->jit[k]);
    if (r != HLOD_OK) {
        hlod_cli_progress_clear(&s->bar);
        hlod_cli_error(PROG, "%s: replaying frame %llu failed: %s", s->c->o->store,
                       (unsigned long long)f, hlod_result_str(r));
        return 1;
    }
    return 0;
}

/* --reference: frame f against the full-detail image (every
 * --reference-every frames), and the reference saved with --save-frames.
 * 0, or 1 on failure. */
static int score_reference(run_state *s, uint64_t f, frame_rec *fr, int save)
{
    context *c = s->c;
    const options *o = c->o;
    int scored = f % (uint64_t)o->reference_every == 0;
    if (!o->reference || (!scored && !save))
        return 0;
    const uint8_t *ref = reference_image(c, f);
    if (!ref) {
        hlod_cli_progress_clear(&s->bar);
        hlod_cli_error(PROG, "%s: reference frame %llu failed", o->store, (unsigned long long)f);
        return 1;
    }
    if (save && write_frame_png(s->dir, f, "_ref", ref, o->width, o->height, &c->lg) != 0)
        return 1;
    if (scored) {
        hlod_psnr_rgb8(c->prev_img, ref, o->width, o->height, &fr->psnr);
        hlod_ssim_rgb8(c->prev_img, ref, o->width, o->height, &fr->ssim);
        /* the reference's own flicker only between neighbouring frames */
        if (s->prev_ref && o->reference_every == 1)
            hlod_luma_change_rgb8(s->prev_ref, ref, o->width, o->height, &fr->ref_luma);
        s->prev_ref = ref;
    }
    return 0;
}

/* Frame f of the run: drawn, read back, checked and scored as the options
 * ask.  0, or 1 on failure. */
static int run_frame(run_state *s, uint64_t f)
{
    context *c = s->c;
    const options *o = c->o;
    hlod_camera cam;
    frame_rec *fr = &s->rec[f];
    path_camera(c, f, &cam, &fr->t);
    fr->psnr = fr->ssim = fr->luma = fr->ref_luma = fr->occ_psnr = NAN;
    fr->occ_differing = fr->cone_differing = -1;
    fr->cone_checked = fr->cone_unchecked = 0;
    if (o->realtime) {
        /* a viewer's pace: frame f starts f x dt after frame 0 */
        double now = hlod_now_ms();
        if (f == 0)
            s->wall0 = now;
        double wait = s->wall0 + (double)f * o->dt * 1e3 - now;
        if (wait > 0) {
            struct timespec ts = {(time_t)(wait / 1e3), (long)(fmod(wait, 1e3) * 1e6)};
            nanosleep(&ts, NULL);
        }
    }
    hlod_result r = target_current(&c->gl);
    if (r == HLOD_OK)
        r = hlod_engine_frame(s->e, &cam, o->dt, &fr->st);
    if (r != HLOD_OK) {
        hlod_cli_progress_clear(&s->bar);
        hlod_cli_error(PROG, "%s: frame %llu failed: %s", o->store, (unsigned long long)f,
                       hlod_result_str(r));
        return 1;
    }
    int save = save_frame(o, f);
    const uint8_t *image;
    if (frame_image(s, f, fr, save, &image) != 0)
        return 1;
    if (save && write_frame_png(s->dir, f, "", image, o->width, o->height, &c->lg) != 0)
        return 1;
    if (o->occlusion_check && check_occlusion(s, f, &cam, image, fr) != 0)
        return 1;
    if (o->cone_check && check_cones(s, f, &cam, image, fr) != 0)
        return 1;
    if (s->njit && f == s->jitter_frame && replay_jitter(s, f, &cam) != 0)
        return 1;
    return score_reference(s, f, fr, save);
}

/* The run's summary into out, and its frames.csv, summary.json and
 * jitter.csv.  0, or 1 when a file cannot be written. */
/* ---- policy lumigraph: the client at the grid points ---- */

#define GRID_CHECKS_MAX 24

/* The views to check: each baked face of the grid point nearest each
 * frame's eye, when the eye is within a grid step of it along every axis;
 * at most GRID_CHECKS_MAX of them, spread evenly over the list. */
static uint32_t grid_views(const context *c, const hlod_lumi_index *ix, uint32_t *out)
{
    uint32_t *all = malloc((size_t)ix->views * sizeof *all);
    uint8_t *seen = calloc(ix->views / HLOD_LUMI_FACES, 1);
    uint32_t n = 0;
    for (uint64_t f = 0; all && seen && f < run_frames(c); f++) {
        double eye[3], at[3];
        hlod_path_eval(&c->path, hlod_path_frame_time(&c->path, c->o->dt, f), eye, at);
        uint32_t q[3];
        int near = 1;
        for (int k = 0; k < 3; k++) {
            double step = (ix->box_max[k] - ix->box_min[k]) / (ix->grid - 1);
            double u = step > 0 ? (eye[k] - ix->box_min[k]) / step : 0;
            double r = floor(u + 0.5);
            r = r < 0 ? 0 : r > ix->grid - 1 ? ix->grid - 1 : r;
            near &= fabs(u - r) <= 1;
            q[k] = (uint32_t)r;
        }
        uint32_t p = (q[2] * ix->grid + q[1]) * ix->grid + q[0];
        if (!near || seen[p])
            continue;
        seen[p] = 1;
        for (uint32_t d = 0; d < HLOD_LUMI_FACES; d++)
            if (ix->state[p * HLOD_LUMI_FACES + d] == HLOD_LUMI_BAKED)
                all[n++] = p * HLOD_LUMI_FACES + d;
    }
    uint32_t m = n < GRID_CHECKS_MAX ? n : GRID_CHECKS_MAX;
    for (uint32_t k = 0; k < m; k++)
        out[k] = all[(uint64_t)k * n / m];
    free(all);
    free(seen);
    return m;
}

/* One view: the client's image at its grid point along its axis, once no
 * view or node is missing (10 s at most), against the baked view. */
static double grid_view_psnr(context *c, hlod_engine *e, gl_target *t, const hlod_lumi_index *ix,
                             uint32_t id, uint8_t *img)
{
    uint32_t x, y, z, d;
    double eye[3], fwd[3], up[3], right[3], at[3];
    hlod_lumi_view_key(ix, id, &x, &y, &z, &d);
    hlod_lumi_point(ix, x, y, z, eye);
    hlod_lumi_face(d, fwd, up, right);
    for (int k = 0; k < 3; k++)
        at[k] = eye[k] + fwd[k];
    hlod_camera cam;
    if (hlod_camera_look_at(&cam, eye, at, up, 90, c->o->near_plane, ix->far_plane * 2, ix->size,
                            ix->size) != HLOD_OK)
        return NAN;
    hlod_frame_stats st;
    int quiet = 0;
    for (int k = 0; k < 1000 && quiet < 3; k++) {
        if (hlod_engine_frame(e, &cam, c->o->dt, &st) != HLOD_OK)
            return NAN;
        quiet = !st.lumi_missing && !st.wanted_missing && !st.lumi_uploads ? quiet + 1 : 0;
        if (!quiet)
            nanosleep(&(struct timespec){0, 10000000}, NULL);
    }
    char rel[128];
    uint8_t *buf = NULL;
    size_t n = 0;
    hlod_lumi_view v = {0};
    double db = NAN;
    hlod_lumi_view_path(ix, id, rel, sizeof rel);
    if (target_read(t, img) == HLOD_OK &&
        hlod_lumi_fetch(c->o->repo, rel, 64u << 20, &c->lg, &buf, &n) == HLOD_OK &&
        hlod_lumi_view_decode(ix, id, buf, n, rel, &c->lg, &v) == HLOD_OK &&
        hlod_psnr_rgb8(img, v.rgb, ix->size, ix->size, &db) != HLOD_OK)
        db = NAN;
    hlod_lumi_view_free(&v);
    free(buf);
    return db;
}

/* summary.json grid_point_psnr_min (docs/lumigraph.md): the client against
 * the baked views at the grid points the path passes, drawn by a second
 * engine in a context of the views' size.  *min NAN with no view to check;
 * 1 (said) on failure. */
static int grid_point_check(context *c, const hlod_engine_desc *base, double *min, int *checks)
{
    *min = NAN;
    *checks = 0;
    hlod_lumi_index ix;
    if (hlod_lumi_index_load(c->o->repo, &c->lg, &ix) != HLOD_OK)
        return 1;
    uint32_t ids[GRID_CHECKS_MAX], n = grid_views(c, &ix, ids);
    gl_target t;
    hlod_engine *e = NULL;
    uint8_t *img = malloc((size_t)ix.size * ix.size * 3);
    int bad = !img;
    if (n && !bad && target_create(c->o->backend, ix.size, ix.size, &c->lg, &t) == HLOD_OK) {
        hlod_engine_desc d = *base;
        d.renderer = t.renderer;
        d.deterministic = 0;
        bad = hlod_engine_create(c->store, &d, &e) != HLOD_OK;
        for (uint32_t k = 0; k < n && !bad; k++) {
            double db = grid_view_psnr(c, e, &t, &ix, ids[k], img);
            bad = isnan(db);
            if (!bad && !(db >= *min))
                *min = db;
            *checks += !bad;
        }
        hlod_engine_destroy(e);
        target_destroy(&t);
    } else if (n) {
        bad = 1;
    }
    if (bad)
        hlod_cli_error(PROG, "%s: the grid-point check failed", c->o->repo);
    free(img);
    hlod_lumi_index_free(&ix);
    return target_current(&c->gl) != HLOD_OK || bad;
}

static int write_run(run_state *s, hlod_policy policy, const hlod_engine_desc *d,
                     uint32_t depths, summary *out)
{
    const double target_ms = d->target_ms;
    context *c = s->c;
    long n = (long)s->total;
    summarise(s->rec, n, target_ms, out);
    summarise_extra(s->rec, n, target_ms, s->jit, s->njit, out);
    out->jitter_frame = s->jitter_frame;
    out->grid_psnr_min = s->grid_psnr_min;
    out->grid_checks = s->grid_checks;
    out->gl_renderer = target_name(&c->gl);
    out->texture_upload =
        hlod_renderer_texture_blocks(c->gl.renderer, d->texture_upload) ? "blocks" : "expanded";
    moving_averages(s->rec, n);
    if (write_frames_csv(s->dir, s->rec, n, depths, &c->lg) != HLOD_OK ||
        write_summary(s->dir, out, hlod_policy_name(policy), c->path_name, c->o, &c->lg) !=
            HLOD_OK ||
        (s->njit && write_jitter_csv(s->dir, s->jit, s->njit, &c->lg) != HLOD_OK))
        return 1;
    return 0;
}

static int run(context *c, hlod_policy policy, const char *dir, const setting *extra,
               summary *out)
{
    const options *o = c->o;
    hlod_engine_desc d;
    if (run_desc(c, policy, extra, &d) != 0)
        return 1;
    d.keep_coned = o->cone_check;
    run_state s;
    memset(&s, 0, sizeof s);
    s.c = c;
    s.dir = dir;
    hlod_result r = hlod_engine_create(c->store, &d, &s.e);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot start the engine: %s", o->store, hlod_result_str(r));
        return 1;
    }
    s.total = run_frames(c);
    s.rec = calloc(s.total ? s.total : 1, sizeof *s.rec);
    s.jitter_frame = s.total / 2;
    s.njit = s.total ? o->jitter_frames : 0;
    s.jit = s.njit ? calloc((size_t)s.njit, sizeof *s.jit) : NULL;
    if (!s.rec || (s.njit && !s.jit)) {
        hlod_cli_error(PROG, "out of memory for %llu frames", (unsigned long long)s.total);
        free(s.rec);
        free(s.jit);
        hlod_engine_destroy(s.e);
        return 1;
    }
    hlod_cli_progress_begin(&s.bar, "frames", 1);
    int status = 0;
    for (uint64_t f = 0; f < s.total; f++) {
        status = run_frame(&s, f);
        if (status)
            break;
        hlod_cli_progress_fn(&s.bar, (double)(f + 1), (double)s.total);
    }
    hlod_cli_progress_clear(&s.bar);
    hlod_engine_destroy(s.e); /* c->gl current */
    s.grid_psnr_min = NAN;
    if (!status && policy == HLOD_POLICY_LUMIGRAPH)
        status = grid_point_check(c, &d, &s.grid_psnr_min, &s.grid_checks);
    if (status) {
        free(s.rec);
        free(s.jit);
        return status;
    }

    const hlod_store_header *h = hlod_store_get_header(c->store);
    uint32_t depths = h->depth_count < HLOD_STATS_MAX_DEPTH ? h->depth_count : HLOD_STATS_MAX_DEPTH;
    status = write_run(&s, policy, &d, depths, out);
    free(s.rec);
    free(s.jit);
    if (!status && o->plots)
        status = plot_run(dir, depths, o->reference, d.target_ms);
    fprintf(stderr, "%s: %s: %ld frames, mean %.2f ms (p95 %.2f, p99 %.2f) for %.1f target, "
            "%.0f%% within 10%%, %.0f%% within the target, machine p50 %.2f p99 %.2f ms, "
            "%.3f toggles/frame, psnr %.2f dB -> %s\n", PROG,
            hlod_policy_name(policy), out->frames, out->mean, out->p95, out->p99, d.target_ms,
            100 * out->within, 100 * out->deadline_met, out->machine_p50, out->machine_p99,
            out->toggles_per_frame, out->psnr_mean, dir);
    return status;
}

/* ---- main ---- */

/* mkdir -p; on failure errno says why. */
static int make_dir(const char *dir)
{
    int e = hlod_mkdir_p(dir, 0777);
    errno = e;
    return e ? -1 : 0;
}

/* pareto.png (with a reference: PSNR needs one) and sweep_frame_time.png
 * from DIR/sweep.csv. */
static int plot_sweep(const options *o)
{
    char names[256] = "", pareto[512] = "", s[2048];
    for (int i = 0; i < o->npolicies; i++) {
        size_t n = strlen(names);
        snprintf(names + n, sizeof names - n, "%s%s", i ? " " : "", hlod_policy_name(o->policies[i]));
    }
    if (o->reference)
        snprintf(pareto, sizeof pareto,
                 "set xlabel 'mean frame time (ms)'\n"
                 "set ylabel 'mean PSNR (dB)'\nset output 'pareto.png'\n"
                 "set title 'Run time vs error, one curve per policy'\n"
                 "plot for [p in '%s'] '< grep ^'.p.', sweep.csv' using 6:13 "
                 "with linespoints title p\n",
                 names);
    snprintf(s, sizeof s,
             "set datafile separator ','\nset terminal pngcairo size 900,600\n"
             "set grid\nset key outside\n%s"
             "set output 'sweep_frame_time.png'\nset ylabel 'ms'\n"
             "set xlabel 'run'\nset title 'Mean and p95 frame time per run'\n"
             "plot 'sweep.csv' every ::1 using 0:6 with linespoints title 'mean', "
             "'' every ::1 using 0:7 with linespoints title 'p95', '' every ::1 using "
             "0:5 with lines dt 2 title 'target'\n",
             pareto);
    return run_gnuplot(o->out, "sweep", s);
}

/* An image as RGB (the first three channels; grey repeated); NULL on error. */
static uint8_t *image_rgb(const hlod_image *img)
{
    size_t n = (size_t)img->width * (size_t)img->height;
    uint8_t *rgb = malloc(n * 3 + 1);
    if (!rgb)
        return NULL;
    for (size_t i = 0; i < n; i++)
        for (int k = 0; k < 3; k++)
            rgb[i * 3 + (size_t)k] =
                img->pixels[i * (size_t)img->channels + (size_t)(img->channels >= 3 ? k : 0)];
    return rgb;
}

/* --compare A B: one JSON line with psnr, ssim (null under 11 pixels a
 * side), differing_pixels, far_pixels (a channel off by more than 64 of
 * 255: a hole, not a rasteriser's rounding), width, height.  0, or 1 when
 * an image cannot be read or the sizes differ. */
static int compare_images(const char *a, const char *b, const hlod_logger *lg)
{
    hlod_image ia = {0}, ib = {0};
    int rc = 1;
    uint8_t *ra = NULL, *rb = NULL;
    if (hlod_image_read(a, &ia, lg) != HLOD_OK || hlod_image_read(b, &ib, lg) != HLOD_OK)
        goto out;
    if (ia.width != ib.width || ia.height != ib.height) {
        hlod_cli_error(PROG, "%s is %dx%d but %s is %dx%d: cannot compare", a, ia.width,
                       ia.height, b, ib.width, ib.height);
        goto out;
    }
    ra = image_rgb(&ia);
    rb = image_rgb(&ib);
    if (!ra || !rb) {
        hlod_cli_error(PROG, "out of memory comparing %s and %s", a, b);
        goto out;
    }
    uint32_t w = (uint32_t)ia.width, h = (uint32_t)ia.height;
    double psnr = NAN, ssim = NAN;
    long long differ = 0, far = 0;
    hlod_psnr_rgb8(ra, rb, w, h, &psnr);
    if (w >= HLOD_SSIM_WINDOW && h >= HLOD_SSIM_WINDOW)
        hlod_ssim_rgb8(ra, rb, w, h, &ssim);
    for (size_t i = 0; i < (size_t)w * h; i++) {
        differ += memcmp(ra + 3 * i, rb + 3 * i, 3) != 0;
        int off = 0;
        for (int k = 0; k < 3; k++)
            off |= abs((int)ra[3 * i + k] - (int)rb[3 * i + k]) > 64;
        far += off;
    }
    hlod_json j;
    hlod_json_begin(&j, stdout);
    hlod_json_double(&j, "psnr", psnr);
    hlod_json_double(&j, "ssim", ssim);
    hlod_json_int(&j, "differing_pixels", differ);
    hlod_json_int(&j, "far_pixels", far);
    hlod_json_int(&j, "width", w);
    hlod_json_int(&j, "height", h);
    rc = hlod_json_end(&j) == 0 ? 0 : 1;
out:
    free(ra);
    free(rb);
    hlod_image_free(&ia);
    hlod_image_free(&ib);
    return rc;
}

/* The path (a file, or a built-in name), the store, and the output
 * folder.  0, or 1 with nothing left open. */
static int open_inputs(context *c)
{
    const options *o = c->o;
    char path_file[4096];
    snprintf(path_file, sizeof path_file, "%s", o->path);
    if (!hlod_is_file(path_file) && !strchr(o->path, '/'))
        snprintf(path_file, sizeof path_file, "%s/%s.path", o->paths_dir, o->path);
    c->path_name = o->path;
    if (hlod_path_load(path_file, &c->lg, &c->path) != HLOD_OK)
        return 1; /* the loader named the file and line */

    if (hlod_store_open(o->store, &c->lg, &c->store) != HLOD_OK) {
        hlod_path_free(&c->path);
        return 1;
    }
    if (o->reference_store && hlod_store_open(o->reference_store, &c->lg, &c->ref_store) != HLOD_OK) {
        hlod_store_close(c->store);
        hlod_path_free(&c->path);
        return 1;
    }
    if (make_dir(o->out) != 0) {
        hlod_cli_error(PROG, "%s: cannot create the output folder: %s", o->out, strerror(errno));
        hlod_store_close(c->store);
        hlod_store_close(c->ref_store);
        hlod_path_free(&c->path);
        return 1;
    }
    return 0;
}

/* The GL contexts (the reference's, then the measured one) and the image
 * buffers.  0, or 1; teardown() frees what was made either way. */
static int setup_gl(context *c)
{
    const options *o = c->o;
    const char *backend = o->backend == BACKEND_EGL ? "EGL" : "OSMesa";
    uint32_t ss = (uint32_t)o->reference_ss;
    hlod_result r = HLOD_OK;
    if (o->reference) { /* its own context first: the measured one stays current */
        r = target_create(o->backend, o->width * ss, o->height * ss, &c->lg, &c->ref_gl);
        if (r != HLOD_OK) {
            hlod_cli_error(PROG, "cannot set up the reference's headless OpenGL (%s, GL 3.3, "
                           "%ux%u): %s", backend, o->width * ss, o->height * ss,
                           hlod_result_str(r));
            return 1;
        }
    }
    r = target_create(o->backend, o->width, o->height, &c->lg, &c->gl);
    size_t npix = (size_t)o->width * o->height * 3;
    c->img = malloc(npix);
    c->prev_img = malloc(npix);
    c->ref = malloc(npix);
    c->prev_ref = malloc(npix);
    c->ref_big = o->reference && ss > 1 ? malloc(npix * ss * ss) : NULL;
    c->occ_img = o->occlusion_check ? malloc(npix) : NULL;
    c->cone_img = o->cone_check ? malloc(npix) : NULL;
    if (r != HLOD_OK || !c->img || !c->prev_img || !c->ref || !c->prev_ref ||
        (o->occlusion_check && !c->occ_img) || (o->cone_check && !c->cone_img) ||
        (o->reference && ss > 1 && !c->ref_big)) {
        hlod_cli_error(PROG, "cannot set up headless OpenGL (%s, GL 3.3): %s", backend,
                       hlod_result_str(r != HLOD_OK ? r : HLOD_ERR_NOMEM));
        return 1;
    }
    return 0;
}

/* Warns of --save-frames past the end, and makes the reference cache: one
 * slot per frame, shared by every run. */
static void prepare_frames(context *c)
{
    const options *o = c->o;
    uint64_t nframes = run_frames(c);
    for (int i = 0; i < o->nsave; i++)
        if (o->save[i] >= nframes)
            fprintf(stderr, "%s: --save-frames: frame %llu is past the last frame (%llu): not "
                    "written\n", PROG, (unsigned long long)o->save[i],
                    (unsigned long long)(nframes ? nframes - 1 : 0));
    if (o->reference) {
        c->ref_cache = calloc(nframes ? nframes : 1, sizeof *c->ref_cache);
        c->ref_cache_frames = c->ref_cache ? nframes : 0; /* no cache: draw each time */
    }
}

/* DIR/sweep.csv opened with its header.  0, or 1. */
static int open_sweep(context *c, hlod_atomic_file *af)
{
    char p[4096];
    snprintf(p, sizeof p, "%s/sweep.csv", c->o->out);
    if (hlod_atomic_open(af, p, &c->lg) != HLOD_OK)
        return 1;
    fprintf(af->fp, "policy,key,value,frames,target_ms,frame_ms_mean,frame_ms_p95,"
                    "frame_ms_p99,within_10pct,over_target_frac,toggles_per_frame,"
                    "oscillations,psnr_mean,psnr_min,ssim_mean,tris_mean,loads,evictions,"
                    "peak_resident_bytes,run_dir,deadline_met,machine_p50_ms,"
                    "machine_p99_ms,machine_p99_over_p50,estimate_err_p50,estimate_err_p95,"
                    "occlusion_culled_mean,toggles_after_60,cone_culled_mean\n");
    return 0;
}

static void sweep_row(FILE *fp, const options *o, const char *pname, int vi, const summary *s,
                      const char *dir)
{
    fprintf(fp, "%s,%s,%g,%ld,%g,%.4f,%.4f,%.4f,%.4f,%.4f,%.5f,%llu,%.4f,%.4f,"
            "%.5f,%.1f,%llu,%llu,%llu,%s,%.4f,%.4f,%.4f,%.4f,%.5f,%.5f,%.3f,%llu,%.3f\n",
            pname, o->sweep_key ? o->sweep_key : "", o->sweep_key ? o->sweep[vi] : 0,
            s->frames, s->target_ms, s->mean, s->p95, s->p99, s->within, s->over,
            s->toggles_per_frame, (unsigned long long)s->osc, s->psnr_mean, s->psnr_min,
            s->ssim_mean, s->tris_mean, (unsigned long long)s->loads,
            (unsigned long long)s->evictions, (unsigned long long)s->peak_resident, dir,
            s->deadline_met, s->machine_p50, s->machine_p99, s->machine_p99 / s->machine_p50,
            s->est_err_p50, s->est_err_p95, s->occlusion_culled_mean,
            (unsigned long long)s->toggles_after_60, s->cone_culled_mean);
}

/* Policy pi with sweep value vi, into DIR itself for a single run, else
 * into DIR/<policy>[-KEY=V]/ with a row in sweep.csv (when sweep_fp).
 * 0, or 1. */
static int run_one(context *c, int pi, int vi, int multi, FILE *sweep_fp, summary *last)
{
    const options *o = c->o;
    char dir[4096];
    setting extra = {o->sweep_key, o->sweep_key ? o->sweep[vi] : 0};
    const char *pname = hlod_policy_name(o->policies[pi]);
    if (!multi)
        snprintf(dir, sizeof dir, "%s", o->out);
    else if (o->sweep_key)
        snprintf(dir, sizeof dir, "%s/%s-%s=%g", o->out, pname, o->sweep_key, o->sweep[vi]);
    else
        snprintf(dir, sizeof dir, "%s/%s", o->out, pname);
    if (make_dir(dir) != 0) {
        hlod_cli_error(PROG, "%s: cannot create: %s", dir, strerror(errno));
        return 1;
    }
    int rc = run(c, o->policies[pi], dir, o->sweep_key ? &extra : NULL, last);
    if (rc == 0 && sweep_fp)
        sweep_row(sweep_fp, o, pname, vi, last, dir);
    return rc;
}

/* Every (policy, sweep value) run, then sweep.csv and its plots, and
 * --json's summary of the last run.  0, or 1. */
static int run_all(context *c)
{
    const options *o = c->o;
    int multi = o->npolicies > 1 || o->sweep_key;
    FILE *sweep_fp = NULL;
    hlod_atomic_file sweep_af;
    if (multi) {
        if (open_sweep(c, &sweep_af) != 0)
            return 1;
        sweep_fp = sweep_af.fp;
    }
    int rc = 0;
    summary last;
    int nvalues = o->sweep_key ? o->nsweep : 1;
    for (int pi = 0; pi < o->npolicies && rc == 0; pi++)
        for (int vi = 0; vi < nvalues && rc == 0; vi++)
            rc = run_one(c, pi, vi, multi, sweep_fp, &last);
    if (sweep_fp) {
        if (rc == 0) {
            if (hlod_atomic_commit(&sweep_af, &c->lg) != HLOD_OK)
                rc = 1;
        } else {
            hlod_atomic_abort(&sweep_af);
        }
        if (rc == 0 && o->plots) {
            rc = plot_sweep(o);
        }
    }
    if (rc == 0 && o->json) {
        hlod_json j;
        hlod_json_begin(&j, stdout);
        json_summary(&j, &last, hlod_policy_name(o->policies[o->npolicies - 1]), o->path, o);
        if (hlod_json_end(&j) != 0)
            rc = 1;
    }
    return rc;
}

/* The reference engine is destroyed with its own context current, before
 * the contexts themselves. */
static void teardown(context *c)
{
    if (c->ref_engine && target_current(&c->ref_gl) == HLOD_OK)
        hlod_engine_destroy(c->ref_engine);
    for (uint64_t f = 0; f < c->ref_cache_frames; f++)
        free(c->ref_cache[f]);
    free(c->ref_cache);
    free(c->img);
    free(c->prev_img);
    free(c->ref);
    free(c->prev_ref);
    free(c->ref_big);
    free(c->occ_img);
    free(c->cone_img);
    target_destroy(&c->ref_gl);
    target_destroy(&c->gl);
    hlod_store_close(c->store);
    hlod_store_close(c->ref_store);
    hlod_path_free(&c->path);
}

int main(int argc, char **argv)
{
    options o;
    int rc = parse_args(argc, argv, &o);
    if (rc >= 0)
        return rc;

    hlod_cli_log log_state = {PROG, HLOD_LOG_WARN, NULL};
    if (o.compare[0]) {
        hlod_logger lg = hlod_cli_logger(&log_state);
        return compare_images(o.compare[0], o.compare[1], &lg);
    }
    context c;
    memset(&c, 0, sizeof c);
    c.o = &o;
    c.lg = hlod_cli_logger(&log_state);
    if (open_inputs(&c) != 0)
        return 1;
    /* a sample tree is drawn by klein, colour cubes by cubes, unless
     * --policy says otherwise */
    if (!o.policy_given && (hlod_store_get_header(c.store)->flags & HLOD_STORE_ADDITIVE))
        o.policies[0] = hlod_store_get_header(c.store)->build.method == HLOD_STORE_METHOD_CUBES
                            ? HLOD_POLICY_CUBES
                            : HLOD_POLICY_KLEIN;
    rc = setup_gl(&c);
    if (rc == 0) {
        prepare_frames(&c);
        rc = run_all(&c);
    }
    teardown(&c);
    return rc;
}
