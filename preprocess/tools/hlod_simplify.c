/*
 * hlod-simplify: simplify one mesh file with the quadric simplifier.
 *
 *   hlod-simplify IN -o OUT (--ratio R | --target-tris N | --target-error E)
 *                 [--lock-border] [--uv-weight W] [--json] [--quiet]
 *
 * Reads IN (hlod_mesh_import), simplifies it (hlod_simplify, with the
 * two-sided Hausdorff error measured afterwards), writes OUT
 * (hlod_mesh_export: temporary file + rename, so a failure leaves no OUT and
 * an existing OUT untouched).  The human summary goes to stderr, the --json
 * record to stdout; the JSON keys are read by scripts, so keep them stable.
 *
 * Exit status: 0 success, 1 a file could not be read, simplified or written,
 * 2 bad command line.
 */
#include <errno.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "cli.h"
#include "hlod/mesh_io.h"
#include "hlod/simplify.h"

static const char *const PROG = "hlod-simplify";

static void usage(FILE *fp)
{
    fprintf(fp,
        "usage: hlod-simplify IN -o OUT (--ratio R | --target-tris N | --target-error E)\n"
        "                     [--lock-border] [--uv-weight W] [--json] [--quiet]\n"
        "\n"
        "Simplifies the triangle mesh IN (OBJ, PLY, OFF, glTF, ...) by quadric edge\n"
        "collapses and writes it to OUT (format from OUT's extension: .obj .ply .off\n"
        ".gltf .glb).  Texture coordinates and materials are kept.\n"
        "\n"
        "  -o, --output OUT     output mesh; written whole or not at all\n"
        "  --ratio R            keep at most R * input triangles, 0 < R <= 1\n"
        "  --target-tris N      keep at most N triangles (N >= 1)\n"
        "  --target-error E     stop before the estimated error exceeds E\n"
        "                       (model units, > 0); combine with --ratio or\n"
        "                       --target-tris to stop at whichever comes first\n"
        "  --lock-border        vertices on open borders never move\n"
        "  --uv-weight W        weight of UV error against geometric error (> 0,\n"
        "                       default 1: a UV shift of 0.01 costs like moving 1%%\n"
        "                       of the mesh size)\n"
        "  --json               print one JSON object on stdout: tris_in, tris_out,\n"
        "                       seconds, error, error_estimate, bbox_diag,\n"
        "                       vertices_in, vertices_out, degenerate_dropped,\n"
        "                       duplicate_dropped and more\n"
        "  --quiet              no summary, no progress bar, errors only\n"
        "  -h, --help           show this help\n"
        "\n"
        "error is a certified upper bound (within 1%%) of the two-sided Hausdorff\n"
        "distance between IN and OUT in model units; seconds is the simplification\n"
        "time without reading, writing or measuring.  Exit status: 0 success,\n"
        "1 failure, 2 bad command line.\n");
}

typedef struct options {
    const char *in, *out;
    int have_ratio, have_tris, have_error;
    double ratio;
    size_t target_tris;
    double target_error;
    int lock_border;
    double uv_weight;       /* 0: the simplifier's default */
    int json, quiet;
} options;

static int match_flag(int argc, char **argv, int *i, const char *flag, const char **value)
{
    return hlod_cli_match_flag(argc, argv, i, flag, value);
}

static int usage_error(const char *fmt, const char *arg)
{
    return hlod_cli_usage_error(PROG, fmt, arg);
}

/* Returns 0 and fills o, -1 when --help was printed, or 2 on a usage error
 * (already reported). */
static int parse_args(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = NULL;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return -1;
        } else if (!strcmp(a, "--lock-border")) {
            o->lock_border = 1;
        } else if (!strcmp(a, "--json")) {
            o->json = 1;
        } else if (!strcmp(a, "--quiet")) {
            o->quiet = 1;
        } else if (match_flag(argc, argv, &i, "-o", &v) ||
                   match_flag(argc, argv, &i, "--output", &v)) {
            if (!v || !*v)
                return usage_error("%s needs an output file name", a);
            o->out = v;
        } else if (match_flag(argc, argv, &i, "--ratio", &v)) {
            if (!v)
                return usage_error("%s needs a value", "--ratio");
            if (!hlod_cli_parse_double(PROG, "--ratio", v, 0.0, 1.0, HLOD_CLI_MIN_OPEN, &o->ratio))
                return 2;
            o->have_ratio = 1;
        } else if (match_flag(argc, argv, &i, "--target-tris", &v)) {
            if (!v)
                return usage_error("%s needs a value", "--target-tris");
            if (!hlod_cli_parse_size(PROG, "--target-tris", v, 1, SIZE_MAX, &o->target_tris))
                return 2;
            o->have_tris = 1;
        } else if (match_flag(argc, argv, &i, "--target-error", &v)) {
            if (!v)
                return usage_error("%s needs a value", "--target-error");
            if (!hlod_cli_parse_double(PROG, "--target-error", v, 0.0, INFINITY,
                                       HLOD_CLI_MIN_OPEN, &o->target_error))
                return 2;
            o->have_error = 1;
        } else if (match_flag(argc, argv, &i, "--uv-weight", &v)) {
            if (!v)
                return usage_error("%s needs a value", "--uv-weight");
            if (!hlod_cli_parse_double(PROG, "--uv-weight", v, 0.0, INFINITY,
                                       HLOD_CLI_MIN_OPEN, &o->uv_weight))
                return 2;
        } else if (a[0] == '-' && a[1] != 0) {
            return usage_error("unknown option '%s'", a);
        } else if (!o->in) {
            o->in = a;
        } else {
            return usage_error("unexpected argument '%s' (only one input file)", a);
        }
    }
    if (!o->in)
        return usage_error("%s", "no input file given");
    if (!o->out)
        return usage_error("%s", "no output file given (-o OUT)");
    if (!o->have_ratio && !o->have_tris && !o->have_error)
        return usage_error("%s", "give a target: --ratio, --target-tris or --target-error");
    if (o->have_ratio && o->have_tris)
        return usage_error("%s", "--ratio and --target-tris cannot be combined");
    return 0;
}

/* Up-front checks so a doomed run fails before minutes of work: IN must be
 * a readable file, OUT's folder must exist and OUT must not be a folder. */
static int check_paths(const options *o)
{
    struct stat st;
    if (stat(o->in, &st) != 0) {
        hlod_cli_error(PROG, "%s: cannot open input: %s", o->in, strerror(errno));
        return 0;
    }
    if (S_ISDIR(st.st_mode)) {
        hlod_cli_error(PROG, "%s: input is a folder, not a mesh file", o->in);
        return 0;
    }
    if (stat(o->out, &st) == 0 && S_ISDIR(st.st_mode)) {
        hlod_cli_error(PROG, "%s: output is a folder; give a file name", o->out);
        return 0;
    }
    size_t n = strlen(o->out);
    char *dir = malloc(n + 2);
    if (!dir)
        return 0;
    memcpy(dir, o->out, n + 1);
    char *slash = strrchr(dir, '/');
    if (!slash)
        strcpy(dir, ".");
    else if (slash == dir)
        dir[1] = 0;
    else
        *slash = 0;
    int ok = stat(dir, &st) == 0 && S_ISDIR(st.st_mode);
    if (!ok)
        hlod_cli_error(PROG, "%s: output folder '%s' does not exist", o->out, dir);
    free(dir);
    return ok;
}

int main(int argc, char **argv)
{
    options o;
    int rc = parse_args(argc, argv, &o);
    if (rc < 0)
        return 0;
    if (rc)
        return rc;
    if (!check_paths(&o))
        return 1;

    hlod_cli_progress bar;
    hlod_cli_progress_begin(&bar, "tri", !o.quiet);
    hlod_cli_log log_state = {PROG, o.quiet ? HLOD_LOG_ERROR : HLOD_LOG_WARN, &bar};
    hlod_logger lg = hlod_cli_logger(&log_state);

    hlod_mesh in = {0}, out = {0};
    hlod_import_stats is = {0};
    hlod_simplify_stats ss = {0};
    int status = 1;

    double t0 = hlod_cli_now();
    hlod_import_desc idesc = {0};
    idesc.logger = &lg;
    hlod_result r = hlod_mesh_import(o.in, &idesc, &in, &is);
    double t_import = hlod_cli_now() - t0;
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot read mesh: %s", o.in, hlod_result_str(r));
        goto done;
    }
    if (in.tri_count == 0) {
        hlod_cli_error(PROG, "%s: no triangles to simplify", o.in);
        goto done;
    }

    hlod_simplify_desc sd = {0};
    if (o.have_ratio) {
        /* floor, so tris_out <= ratio * tris_in; never 0 (0 means no target) */
        double t = floor(o.ratio * (double)in.tri_count);
        sd.target_tris = t < 1 ? 1 : (size_t)t;
    } else if (o.have_tris) {
        sd.target_tris = o.target_tris;
    }
    sd.target_error = o.have_error ? o.target_error : 0.0;
    sd.lock_border = o.lock_border;
    sd.uv_weight = o.uv_weight;
    sd.measure_error = 1;
    sd.progress = hlod_cli_progress_fn;
    sd.progress_user = &bar;
    sd.logger = &lg;

    double t1 = hlod_cli_now();
    r = hlod_simplify(&in, &sd, &out, &ss);
    double t_simplify_wall = hlod_cli_now() - t1;
    hlod_cli_progress_clear(&bar);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: simplification failed: %s", o.in, hlod_result_str(r));
        goto done;
    }

    double t2 = hlod_cli_now();
    r = hlod_mesh_export(o.out, &out, &lg);
    double t_export = hlod_cli_now() - t2;
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot write mesh: %s", o.out, hlod_result_str(r));
        goto done;
    }

    double diag = hlod_mesh_bbox_diag(&in);
    double rel = diag > 0 ? ss.error / diag : NAN;
    if (!o.quiet && sd.target_tris && out.tri_count > sd.target_tris)
        fprintf(stderr, "%s: warning: %s: stopped at %zu triangles for a target of %zu: %s (%zu "
                "locked vertices)\n", PROG, o.in, out.tri_count, sd.target_tris, ss.stop_reason,
                ss.locked_vertices);
    if (!o.quiet) {
        fprintf(stderr,
                "%s: %s -> %s: %zu -> %zu triangles (%.2f%%) in %.3f s, "
                "error %.6g (%.4f%% of diagonal %.6g)\n",
                PROG, o.in, o.out, in.tri_count, out.tri_count,
                100.0 * (double)out.tri_count / (double)in.tri_count, ss.seconds, ss.error,
                100.0 * rel, diag);
    }
    if (o.json) {
        hlod_json j;
        hlod_json_begin(&j, stdout);
        hlod_json_string(&j, "in", o.in);
        hlod_json_string(&j, "out", o.out);
        hlod_json_size(&j, "tris_in", in.tri_count);
        hlod_json_size(&j, "tris_out", out.tri_count);
        hlod_json_size(&j, "target_tris", sd.target_tris);
        hlod_json_double(&j, "target_error", sd.target_error);
        hlod_json_double(&j, "seconds", ss.seconds);
        hlod_json_double(&j, "error", ss.error);
        hlod_json_double(&j, "error_estimate", ss.error_estimate);
        hlod_json_double(&j, "bbox_diag", diag);
        hlod_json_double(&j, "error_rel_diag", rel);
        hlod_json_size(&j, "vertices_in", in.vertex_count);
        hlod_json_size(&j, "vertices_out", out.vertex_count);
        hlod_json_size(&j, "collapses", ss.collapses);
        hlod_json_string(&j, "stop_reason", ss.stop_reason);
        hlod_json_size(&j, "locked_vertices", ss.locked_vertices);
        hlod_json_bool(&j, "clustered", ss.clustered);
        hlod_json_size(&j, "tris_read", is.tris_read);
        hlod_json_size(&j, "degenerate_dropped", is.degenerate_dropped);
        hlod_json_size(&j, "duplicate_dropped", is.duplicate_dropped);
        hlod_json_size(&j, "missing_textures", is.missing_textures);
        hlod_json_double(&j, "seconds_import", t_import);
        hlod_json_double(&j, "seconds_simplify_and_measure", t_simplify_wall);
        hlod_json_double(&j, "seconds_export", t_export);
        hlod_json_size(&j, "peak_rss_bytes", hlod_cli_peak_rss());
        if (hlod_json_end(&j) != 0) {
            hlod_cli_error(PROG, "cannot write the JSON record to standard output");
            goto done;
        }
    }
    status = 0;
done:
    hlod_mesh_free(&in);
    hlod_mesh_free(&out);
    return status;
}
