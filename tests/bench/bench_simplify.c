/*
 * bench_simplify.c - hlod-bench-simplify: our simplifier against
 * meshoptimizer at the requested target, and at equal output counts.
 *
 *   hlod-bench-simplify [--meshes DIR] [--out DIR] [--ratios 0.1,0.01]
 *                       [--samples N] [MESH...]
 *
 * For every mesh and ratio, both simplifiers get the requested target,
 * ratio * triangles (meshopt_simplify with no error limit, hlod_simplify
 * with target_tris), and each reports what it reached: the comparison that
 * counts is at the requested target.  Ours also runs once more (untimed)
 * with target_tris = the count meshoptimizer reached, for a comparison at
 * equal size.  Each simplify call is timed alone
 * (CLOCK_MONOTONIC, single thread); the two simplifiers run in turn, at
 * least 3 times each and until ours has run for 0.5 s (at most 50 times),
 * and each keeps its best time, so a slow moment of a shared machine
 * falls on both alike and a small mesh is not timed by 3 runs of a few
 * milliseconds.  Each output is then
 * measured against the input with hlod_mesh_distance (same seed and sample
 * count for both).  Prints a table and a summary, and writes
 * OUT/simplify.csv and OUT/summary.json, with our time over
 * meshoptimizer's for every pair (a figure that two machines can compare).
 * The targets (at the requested target: max error <= meshoptimizer's on
 * every pair, mean error <= 0.75 x meshoptimizer's on average; each
 * reaching the target within 2%) are reported, not asserted: the exit
 * status is 0 unless a mesh cannot be read or an output not written.
 *
 * meshoptimizer gets positions re-centred on the bounding-box centre as
 * floats, after welding vertices that share a position and a UV
 * (meshopt_generateVertexRemapMulti, not timed), as its documentation asks:
 * it locks every vertex whose copies it cannot pair up as a seam, so an
 * unwelded flat-shaded mesh (Wuson.ply) or glTF would not simplify at all.
 * Our simplifier does the same welding inside its timed call.  When node
 * and the npm package are installed (npm ci), meshoptimizer 1.3 runs too
 * twice (tests/bench/meshopt_js.mjs): positions only with Prune and
 * Permissive, and simplifyWithAttributes with the welded vertices' normals
 * and UVs weighted 1, seams kept as ours keeps them (no flag).  Where
 * that run stops short of the target, ours runs again at its count
 * (hlod_eq_js_attr, untimed) and the comparison is made there.
 */
#include "hlod_clock.h"
#include "atomic_file.h"
#include "cli.h"
#include "hlod/distance.h"
#include "hlod/mesh_io.h"
#include "hlod/simplify.h"

#include <errno.h>
#include <float.h>
#include <math.h>
#include <meshoptimizer.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>

#define PROG "hlod-bench-simplify"
#define RUNS 3            /* at least, for each simplifier */
#define MAX_RUNS 50
#define MIN_SECONDS 0.5   /* of our runs, before the timing stops */
#define SEED 1u
#define MAX_RATIOS 16
#define TARGET_MEAN_RATIO 0.75
#define REACH_SLACK 1.02  /* reached within 2% of the requested count */
/* simplifyWithAttributes' weight for normals and UVs: "around 1.0" for
 * normalised attributes, as its README advises (UVs span about 1). */
#define ATTR_WEIGHT 1.0f

static const char *const default_meshes[] = {"bunny00.off", "fandisk.off", "mech-holes-shark.off",
                                              "spider.obj", "2CylinderEngine.glb", "Wuson.ply"};

typedef struct row {
    const char *mesh;       /* file name, without its folder */
    double ratio;
    const char *simplifier; /* "meshopt", "hlod" (both at the requested
                               target), "hlod_eq" (at meshopt's count) or
                               "meshopt_js" (the npm package's current
                               simplifier, Prune + Permissive, at the
                               requested target; when installed) */
    size_t tris_in, tris_target, tris_out;
    double seconds;         /* best of `runs` */
    int runs;               /* timed runs of each simplifier */
    double diag;
    hlod_distance d;
    int measured;           /* 0: the output was empty, d is meaningless */
    int missed;             /* tris_out over REACH_SLACK x tris_target */
} row;

static void usage(FILE *fp)
{
    fprintf(fp,
            "usage: " PROG " [--meshes DIR] [--out DIR] [--ratios 0.1,0.01] [--samples N] [MESH...]\n"
            "\n"
            "Benchmarks hlod_simplify against meshoptimizer, both asked for the same\n"
            "target (and ours again at meshoptimizer's reached count): triangles\n"
            "reached, time (best of at least %d alternating runs, single thread) and\n"
            "two-sided Hausdorff error.\n"
            "\n"
            "  --meshes DIR   folder of the meshes (default data/meshes); a MESH\n"
            "                 without '/' is looked up there\n"
            "  --out DIR      where simplify.csv and summary.json go\n"
            "                 (default out/bench-simplify)\n"
            "  --ratios LIST  comma-separated output/input triangle ratios in (0, 1]\n"
            "                 (default 0.1,0.01)\n"
            "  --samples N    area samples per mesh for hlod_mesh_distance (default\n"
            "                 200000)\n"
            "  MESH...        default: bunny00.off fandisk.off mech-holes-shark.off\n"
            "                 spider.obj 2CylinderEngine.glb Wuson.ply\n",
            RUNS);
}

static int parse_ratios(const char *text, double *out, int *n)
{
    char buf[512];
    if (strlen(text) >= sizeof buf) {
        hlod_cli_error(PROG, "--ratios: list too long");
        return 0;
    }
    strcpy(buf, text);
    *n = 0;
    for (char *tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
        if (*n == MAX_RATIOS) {
            hlod_cli_error(PROG, "--ratios: at most %d ratios", MAX_RATIOS);
            return 0;
        }
        if (!hlod_cli_parse_double(PROG, "--ratios", tok, 0, 1, HLOD_CLI_MIN_OPEN, &out[*n]))
            return 0;
        (*n)++;
    }
    if (!*n) {
        hlod_cli_error(PROG, "--ratios: needs at least one ratio");
        return 0;
    }
    return 1;
}

/* mkdir -p. */
static int make_dirs(const char *path)
{
    char buf[4096];
    if (snprintf(buf, sizeof buf, "%s", path) >= (int)sizeof buf)
        return 0;
    for (char *p = buf + 1;; p++) {
        if (*p == '/' || *p == 0) {
            char c = *p;
            *p = 0;
            if (mkdir(buf, 0777) != 0 && errno != EEXIST)
                return 0;
            *p = c;
            if (!c)
                break;
        }
    }
    return 1;
}

/* ---- the two simplifiers -------------------------------------------------- */

/* One timed meshopt_simplify call; returns the index count. */
static size_t time_meshopt(const hlod_mesh *m, const uint32_t *indices, const float *pos, size_t vertex_count,
                           size_t target_index_count, uint32_t *dest, double *seconds)
{
    float result_error = 0;
    double t = hlod_now_s();
    size_t n = meshopt_simplify(dest, indices, 3 * m->tri_count, pos, vertex_count, 3 * sizeof(float),
                                target_index_count, FLT_MAX, 0, &result_error);
    *seconds = hlod_now_s() - t;
    return n;
}

/* The npm package's simplifier through node (tests/bench/meshopt_js.mjs),
 * when node and the package are installed (npm ci in the source tree):
 * positions only (n_attr 0: simplify, Prune + Permissive) or with n_attr
 * attributes per vertex and their weights (simplifyWithAttributes, Prune).
 * Returns the index count into dest, or (size_t)-1 when it cannot run. */
static size_t time_meshopt_js(const char *tmp_dir, const uint32_t *indices, size_t n_idx,
                              const float *pos, size_t vertex_count, const float *attr,
                              const float *weights, uint32_t n_attr, size_t target_index_count,
                              uint32_t *dest, double *seconds)
{
    char pkg[4096], in[4200], out[4200], cmd[16384];
    snprintf(pkg, sizeof pkg, "%s/node_modules/meshoptimizer/package.json", HLOD_SOURCE_DIR);
    FILE *probe = fopen(pkg, "rb");
    if (!probe)
        return (size_t)-1;
    fclose(probe);
    snprintf(in, sizeof in, "%s/meshopt_js.in", tmp_dir);
    snprintf(out, sizeof out, "%s/meshopt_js.out", tmp_dir);
    FILE *f = fopen(in, "wb");
    if (!f)
        return (size_t)-1;
    uint32_t head[4] = {(uint32_t)vertex_count, (uint32_t)n_idx, (uint32_t)target_index_count,
                        n_attr};
    int ok = fwrite(head, sizeof head, 1, f) == 1 &&
             fwrite(pos, 3 * sizeof(float), vertex_count, f) == vertex_count &&
             (!n_attr || (fwrite(attr, n_attr * sizeof(float), vertex_count, f) == vertex_count &&
                          fwrite(weights, sizeof(float), n_attr, f) == n_attr)) &&
             fwrite(indices, sizeof(uint32_t), n_idx, f) == n_idx;
    ok &= fclose(f) == 0;
    snprintf(cmd, sizeof cmd, "node '%s/tests/bench/meshopt_js.mjs' '%s' '%s'", HLOD_SOURCE_DIR, in,
             out);
    if (!ok || system(cmd) != 0) {
        remove(in);
        return (size_t)-1;
    }
    size_t n = (size_t)-1;
    f = fopen(out, "rb");
    uint32_t cnt = 0;
    if (f && fread(&cnt, 4, 1, f) == 1 && fread(seconds, 8, 1, f) == 1 && cnt <= n_idx &&
        fread(dest, 4, cnt, f) == cnt)
        n = cnt;
    if (f)
        fclose(f);
    remove(in);
    remove(out);
    return n;
}

/* One timed hlod_simplify call into *out. */
static hlod_result time_ours(const hlod_mesh *m, size_t target_tris, hlod_mesh *out, double *seconds)
{
    hlod_simplify_desc desc = {0};
    desc.target_tris = target_tris;
    double t = hlod_now_s();
    hlod_result res = hlod_simplify(m, &desc, out, NULL);
    *seconds = hlod_now_s() - t;
    return res;
}

/* Both at the requested target, in turn, RUNS to MAX_RUNS times (until
 * ours has run MIN_SECONDS); each keeps its best time.  Both are
 * deterministic, so the last outputs are the outputs. */
static hlod_result time_pair(const hlod_mesh *m, const uint32_t *indices, const float *pos, size_t vertex_count,
                             size_t target_index_count, uint32_t *dest, size_t *n_idx, hlod_mesh *ours,
                             double *s_meshopt, double *s_ours, int *runs)
{
    double t;
    *n_idx = time_meshopt(m, indices, pos, vertex_count, target_index_count, dest, s_meshopt);
    /* target_tris = 0 would mean "no target": ask for at least one */
    size_t target = target_index_count / 3 ? target_index_count / 3 : 1;
    *s_ours = DBL_MAX;
    double spent = 0;
    int r = 0;
    while (r < RUNS || (r < MAX_RUNS && spent < MIN_SECONDS)) {
        hlod_result res = time_ours(m, target, ours, &t);
        if (res != HLOD_OK)
            return res;
        spent += t;
        if (t < *s_ours)
            *s_ours = t;
        r++;
        if (r < RUNS || (r < MAX_RUNS && spent < MIN_SECONDS)) {
            time_meshopt(m, indices, pos, vertex_count, target_index_count, dest, &t);
            if (t < *s_meshopt)
                *s_meshopt = t;
        }
    }
    *runs = r;
    return HLOD_OK;
}

/* ---- output ------------------------------------------------------------- */

static double mtri_per_s(const row *r)
{
    return r->seconds > 0 ? (double)r->tris_in / r->seconds / 1e6 : 0;
}

static double pct(double v, double diag)
{
    return diag > 0 ? 100.0 * v / diag : 0;
}

static void print_header(void)
{
    printf("%-22s %6s %-8s %8s %8s %8s %9s %7s %11s %11s %8s %8s\n", "mesh", "ratio", "simp",
           "tris_in", "target", "tris_out", "seconds", "Mtri/s", "hd_max", "hd_mean", "max%diag",
           "mean%diag");
}

static void print_row(const row *r)
{
    printf("%-22s %6g %-8s %8zu %8zu %8zu %9.5f %7.2f ", r->mesh, r->ratio, r->simplifier,
           r->tris_in, r->tris_target, r->tris_out, r->seconds, mtri_per_s(r));
    if (r->measured)
        printf("%11.4e %11.4e %8.4f %8.4f", r->d.max, r->d.mean, pct(r->d.max, r->diag),
               pct(r->d.mean, r->diag));
    else
        printf("%11s %11s %8s %8s", "-", "-", "-", "-");
    printf("%s\n", r->missed ? "  ! missed the target" : "");
    fflush(stdout);
}

/* %.17g, or an empty field (CSV) / null (JSON) when not measured. */
static void put_num(FILE *fp, int ok, double v, const char *missing)
{
    if (ok && isfinite(v))
        fprintf(fp, "%.17g", v);
    else
        fputs(missing, fp);
}

/* JSON string: mesh names are file names, but escape what JSON needs. */
static void put_str(FILE *fp, const char *s)
{
    fputc('"', fp);
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            fprintf(fp, "\\%c", c);
        else if (c < 0x20)
            fprintf(fp, "\\u%04x", c);
        else
            fputc(c, fp);
    }
    fputc('"', fp);
}

static hlod_result write_csv(const char *path, const row *rows, int n, const hlod_logger *lg)
{
    hlod_atomic_file f;
    hlod_result r = hlod_atomic_open(&f, path, lg);
    if (r != HLOD_OK)
        return r;
    fprintf(f.fp, "mesh,ratio,simplifier,tris_in,tris_target,tris_out,seconds,mtri_per_s,"
                  "hausdorff_max,hausdorff_mean,max_pct_diag,mean_pct_diag,bbox_diag,missed_target,"
                  "runs\n");
    for (int i = 0; i < n; i++) {
        const row *w = &rows[i];
        if (!w->measured && (!strncmp(w->simplifier, "meshopt_js", 10) ||
                             !strcmp(w->simplifier, "hlod_eq_js_attr")))
            continue; /* not installed, failed or not needed: no row */
        /* Mesh names with a comma or quote get CSV quoting. */
        if (strpbrk(w->mesh, ",\"")) {
            fputc('"', f.fp);
            for (const char *s = w->mesh; *s; s++) {
                if (*s == '"')
                    fputc('"', f.fp);
                fputc(*s, f.fp);
            }
            fputc('"', f.fp);
        } else {
            fputs(w->mesh, f.fp);
        }
        fprintf(f.fp, ",%.15g,%s,%zu,%zu,%zu,%.17g,%.17g,", w->ratio, w->simplifier, w->tris_in,
                w->tris_target, w->tris_out, w->seconds, mtri_per_s(w));
        put_num(f.fp, w->measured, w->d.max, "");
        fputc(',', f.fp);
        put_num(f.fp, w->measured, w->d.mean, "");
        fputc(',', f.fp);
        put_num(f.fp, w->measured, pct(w->d.max, w->diag), "");
        fputc(',', f.fp);
        put_num(f.fp, w->measured, pct(w->d.mean, w->diag), "");
        fprintf(f.fp, ",%.17g,%d,%d\n", w->diag, w->missed, w->runs);
    }
    return hlod_atomic_commit(&f, lg);
}

typedef struct summary {
    int all_max_le;          /* our max <= meshopt's on every measured pair */
    double mean_ratio_avg;   /* average over pairs of ours/meshopt mean */
    int mean_ratio_pairs;
    double min_mtri;         /* our slowest throughput */
    double time_ratio_geo;   /* geometric mean over pairs of our time / meshopt's */
    double time_ratio_max;
    int missed_ours, missed_meshopt; /* pairs where each missed the target */
} summary;

/* Rows come in sixes: meshopt, hlod (both at the requested target),
 * hlod_eq (at meshopt's count), meshopt_js and meshopt_js_attr (measured
 * only when installed), hlod_eq_js_attr (ours at meshopt_js_attr's count,
 * measured only where it stopped short of the target). */
#define GROUP 6
#define ROW_JS 3
#define ROW_JS_ATTR 4
#define ROW_EQ_JS_ATTR 5

static double pair_ratio(double ours, double theirs)
{
    if (theirs > 0)
        return ours / theirs;
    return ours > 0 ? INFINITY : 1.0;
}

/* One measured pair into s: ours (o) against the peer (m). */
static void add_pair(summary *s, double *sum, const row *m, const row *o)
{
    if (!m->measured || !o->measured)
        return;
    if (o->d.max > m->d.max)
        s->all_max_le = 0;
    *sum += pair_ratio(o->d.mean, m->d.mean);
    s->mean_ratio_pairs++;
}

/* ours_at = 1: at the requested target; 2: at equal count.  ref_at = 0:
 * against meshopt 0.18; 3: against meshopt_js. */
static summary summarise(const row *rows, int n, int ours_at, int ref_at)
{
    summary s = {1, 0, 0, DBL_MAX, 0, 0, 0, 0};
    double sum = 0, log_sum = 0;
    int timed = 0;
    for (int i = 0; i + GROUP - 1 < n; i += GROUP) {
        const row *m = &rows[i + ref_at], *o = &rows[i + ours_at], *t = &rows[i + 1];
        s.missed_ours += t->missed;
        s.missed_meshopt += m->missed;
        if (mtri_per_s(t) < s.min_mtri)
            s.min_mtri = mtri_per_s(t);
        if (m->seconds > 0 && t->seconds > 0) {
            double tr = t->seconds / m->seconds;
            log_sum += log(tr);
            timed++;
            if (tr > s.time_ratio_max)
                s.time_ratio_max = tr;
        }
        add_pair(&s, &sum, m, o);
    }
    s.mean_ratio_avg = s.mean_ratio_pairs ? sum / s.mean_ratio_pairs : NAN;
    if (s.min_mtri == DBL_MAX)
        s.min_mtri = 0;
    s.time_ratio_geo = timed ? exp(log_sum / timed) : NAN;
    return s;
}

/* Ours against the peer in row ref_at, at the requested target where the
 * peer reached it (within REACH_SLACK), else at the peer's reached count
 * (row eq_at): the project's rule for a peer that stops short. */
static summary summarise_fair(const row *rows, int n, int ref_at, int eq_at)
{
    summary s = {1, 0, 0, DBL_MAX, 0, 0, 0, 0};
    double sum = 0;
    for (int i = 0; i + GROUP - 1 < n; i += GROUP) {
        const row *m = &rows[i + ref_at];
        const row *o = m->missed ? &rows[i + eq_at] : &rows[i + 1];
        s.missed_meshopt += m->missed;
        add_pair(&s, &sum, m, o);
    }
    s.mean_ratio_avg = s.mean_ratio_pairs ? sum / s.mean_ratio_pairs : NAN;
    s.min_mtri = 0;
    return s;
}

static void json_distances(FILE *fp, const row *m, const row *o, const char *suffix)
{
    int ok = m->measured && o->measured;
    fprintf(fp, "\"max_ours%s\": ", suffix);
    put_num(fp, o->measured, o->d.max, "null");
    fprintf(fp, ", \"mean_ours%s\": ", suffix);
    put_num(fp, o->measured, o->d.mean, "null");
    fprintf(fp, ", \"max_ratio%s\": ", suffix);
    put_num(fp, ok, pair_ratio(o->d.max, m->d.max), "null");
    fprintf(fp, ", \"mean_ratio%s\": ", suffix);
    put_num(fp, ok, pair_ratio(o->d.mean, m->d.mean), "null");
}

/* A peer run's tris_out, max, mean and seconds keys, suffixed. */
static void json_peer(FILE *fp, const row *j, const char *suffix)
{
    fprintf(fp, "\"tris_out_meshopt%s\": ", suffix);
    put_num(fp, j->measured, (double)j->tris_out, "null");
    fprintf(fp, ", \"max_meshopt%s\": ", suffix);
    put_num(fp, j->measured, j->d.max, "null");
    fprintf(fp, ", \"mean_meshopt%s\": ", suffix);
    put_num(fp, j->measured, j->d.mean, "null");
    fprintf(fp, ", \"seconds_meshopt%s\": ", suffix);
    put_num(fp, j->measured, j->seconds, "null");
}

static void json_summary(FILE *fp, const summary *s, const char *suffix)
{
    fprintf(fp, "  \"max_le_meshopt_every_pair%s\": %s,\n", suffix, s->all_max_le ? "true" : "false");
    fprintf(fp, "  \"mean_ratio_avg%s\": ", suffix);
    put_num(fp, s->mean_ratio_pairs > 0, s->mean_ratio_avg, "null");
    fprintf(fp, ",\n  \"mean_ratio_met%s\": %s,\n", suffix,
            s->mean_ratio_pairs > 0 && s->mean_ratio_avg <= TARGET_MEAN_RATIO ? "true" : "false");
}

static hlod_result write_json(const char *path, const row *rows, int n, const summary *s,
                              const summary *eq, const summary *js, const summary *ja, size_t samples,
                              const hlod_logger *lg)
{
    hlod_atomic_file f;
    hlod_result r = hlod_atomic_open(&f, path, lg);
    if (r != HLOD_OK)
        return r;
    FILE *fp = f.fp;
    fprintf(fp, "{\n  \"timing\": \"best of %d to %d alternating runs (until ours ran %g s), CLOCK_MONOTONIC "
                "around the simplify call, one thread\",\n",
            RUNS, MAX_RUNS, MIN_SECONDS);
    fprintf(fp, "  \"comparison\": \"both at the requested target; *_eq: ours at meshoptimizer's "
                "reached count\",\n");
    fprintf(fp, "  \"meshoptimizer_version\": %d,\n  \"samples_per_mesh\": %zu,\n  \"seed\": %u,\n",
            MESHOPTIMIZER_VERSION, samples, SEED);
    fprintf(fp, "  \"pairs\": [\n");
    for (int i = 0; i + GROUP - 1 < n; i += GROUP) {
        const row *m = &rows[i], *o = &rows[i + 1], *e = &rows[i + 2];
        fprintf(fp, "    {\"mesh\": ");
        put_str(fp, m->mesh);
        fprintf(fp, ", \"ratio\": %.15g, \"tris_in\": %zu, \"tris_target\": %zu, "
                    "\"tris_out_meshopt\": %zu, \"tris_out_ours\": %zu, \"tris_out_ours_eq\": %zu,\n"
                    "     \"missed_target_meshopt\": %s, \"missed_target_ours\": %s, "
                    "\"bbox_diag\": %.17g,\n",
                m->ratio, m->tris_in, m->tris_target, m->tris_out, o->tris_out, e->tris_out,
                m->missed ? "true" : "false", o->missed ? "true" : "false", m->diag);
        fprintf(fp, "     \"seconds_meshopt\": %.17g, \"seconds_ours\": %.17g, "
                    "\"mtri_per_s_meshopt\": %.17g, \"mtri_per_s_ours\": %.17g, \"runs\": %d,\n",
                m->seconds, o->seconds, mtri_per_s(m), mtri_per_s(o), o->runs);
        fprintf(fp, "     \"time_ratio\": ");
        put_num(fp, m->seconds > 0, o->seconds / m->seconds, "null");
        fprintf(fp, ", \"max_meshopt\": ");
        put_num(fp, m->measured, m->d.max, "null");
        fprintf(fp, ", \"mean_meshopt\": ");
        put_num(fp, m->measured, m->d.mean, "null");
        fprintf(fp, ",\n     ");
        json_distances(fp, m, o, "");
        fprintf(fp, ",\n     ");
        json_distances(fp, m, e, "_eq");
        const row *j = &rows[i + ROW_JS];
        fprintf(fp, ",\n     ");
        json_peer(fp, j, "_js");
        fprintf(fp, ", ");
        json_distances(fp, j, o, "_js");
        const row *a = &rows[i + ROW_JS_ATTR], *ae = &rows[i + ROW_EQ_JS_ATTR];
        fprintf(fp, ",\n     ");
        json_peer(fp, a, "_js_attr");
        fprintf(fp, ", \"missed_target_meshopt_js_attr\": %s", a->missed ? "true" : "false");
        fprintf(fp, ",\n     ");
        json_distances(fp, a, o, "_js_attr");
        fprintf(fp, ", \"tris_out_ours_js_attr_eq\": ");
        put_num(fp, ae->measured, (double)ae->tris_out, "null");
        fprintf(fp, ", ");
        json_distances(fp, a, ae, "_js_attr_eq");
        fprintf(fp, "}%s\n", i + GROUP < n ? "," : "");
    }
    fprintf(fp, "  ],\n");
    json_summary(fp, s, "");
    json_summary(fp, eq, "_eq");
    json_summary(fp, js, "_js");
    json_summary(fp, ja, "_js_attr");
    fprintf(fp, "  \"mean_ratio_target\": %.17g,\n", TARGET_MEAN_RATIO);
    fprintf(fp, "  \"pairs_missed_target_ours\": %d,\n  \"pairs_missed_target_meshopt\": %d,\n",
            s->missed_ours, s->missed_meshopt);
    fprintf(fp, "  \"min_mtri_per_s_ours\": %.17g,\n  \"time_ratio_geomean\": ", s->min_mtri);
    put_num(fp, 1, s->time_ratio_geo, "null");
    fprintf(fp, ",\n  \"time_ratio_max\": ");
    put_num(fp, s->time_ratio_max > 0, s->time_ratio_max, "null");
    fprintf(fp, "\n}\n");
    return hlod_atomic_commit(&f, lg);
}

/* meshoptimizer 1.3's simplifyWithAttributes (through node) at the
 * requested target, into row ra and *out, which shares mo's welded
 * vertices; returns 1 when it ran. */
static int js_attr_run(const char *out_dir, const uint32_t *widx, size_t n_idx, const float *wpos,
                       const float *wattr, const float *weights, uint32_t n_attr, size_t wn,
                       size_t target, uint32_t *dest, const hlod_mesh *mo, row *ra, hlod_mesh *out)
{
    ra->simplifier = "meshopt_js_attr";
    ra->seconds = 0;
    ra->tris_out = 0;
    ra->missed = 0;
    ra->runs = 0;
    ra->measured = 0;
    size_t n = dest && wattr && make_dirs(out_dir)
                   ? time_meshopt_js(out_dir, widx, n_idx, wpos, wn, wattr, weights, n_attr,
                                     3 * target, dest, &ra->seconds)
                   : (size_t)-1;
    if (n == (size_t)-1)
        return 0;
    ra->tris_out = n / 3;
    ra->missed = (double)ra->tris_out > REACH_SLACK * (double)target;
    *out = *mo;
    out->indices = dest;
    out->tri_count = ra->tris_out;
    return 1;
}

/* The table against simplifyWithAttributes. */
static void print_js_attr(const row *rows, int n, const summary *sa)
{
    printf("\nagainst meshoptimizer's current simplifyWithAttributes (npm; normals, and UVs where "
           "the mesh has them, weighted %g; seams kept), at the requested target where it "
           "reached it, else at its count:\n", ATTR_WEIGHT);
    printf("%-22s %6s %8s %8s %8s %8s %8s %s\n", "mesh", "ratio", "target", "js_attr", "ours", "max",
           "mean", "at");
    for (int i = 0; i + GROUP - 1 < n; i += GROUP) {
        const row *a = &rows[i + ROW_JS_ATTR];
        const row *o = a->missed ? &rows[i + ROW_EQ_JS_ATTR] : &rows[i + 1];
        if (!a->measured || !o->measured)
            continue;
        printf("%-22s %6g %8zu %8zu %8zu %8.3f %8.3f %s\n", a->mesh, a->ratio, a->tris_target,
               a->tris_out, o->tris_out, pair_ratio(o->d.max, a->d.max),
               pair_ratio(o->d.mean, a->d.mean), a->missed ? "its count" : "target");
    }
    printf("our max <= its max on every pair: %s; average mean ratio %.3f\n",
           sa->all_max_le ? "yes" : "no", sa->mean_ratio_avg);
}

/* ---- main ----------------------------------------------------------------- */

/* Measures out against in; an empty output is reported, not measured. */
static hlod_result measure(const hlod_mesh *in, const hlod_mesh *out, size_t samples, row *r)
{
    r->measured = 0;
    if (!out->tri_count)
        return HLOD_OK;
    hlod_result res = hlod_mesh_distance(in, out, samples, SEED, &r->d);
    if (res == HLOD_OK)
        r->measured = 1;
    return res;
}

int main(int argc, char **argv)
{
    const char *mesh_dir = "data/meshes", *out_dir = "out/bench-simplify";
    double ratios[MAX_RATIOS] = {0.1, 0.01};
    int n_ratios = 2;
    size_t samples = 200000;
    const char **names = NULL;
    int n_names = 0;

    size_t n_default = sizeof default_meshes / sizeof *default_meshes;
    names = malloc(((size_t)argc > n_default ? (size_t)argc : n_default) * sizeof *names);
    if (!names)
        return 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            free(names);
            return 0;
        }
        int has_value = !strcmp(a, "--meshes") || !strcmp(a, "--out") || !strcmp(a, "--ratios") ||
                        !strcmp(a, "--samples");
        if (has_value && i + 1 >= argc) {
            hlod_cli_error(PROG, "%s: needs a value", a);
            free(names);
            return 2;
        }
        if (!strcmp(a, "--meshes")) {
            mesh_dir = argv[++i];
        } else if (!strcmp(a, "--out")) {
            out_dir = argv[++i];
        } else if (!strcmp(a, "--ratios")) {
            if (!parse_ratios(argv[++i], ratios, &n_ratios)) {
                free(names);
                return 2;
            }
        } else if (!strcmp(a, "--samples")) {
            if (!hlod_cli_parse_size(PROG, "--samples", argv[++i], 1, (size_t)1 << 30, &samples)) {
                free(names);
                return 2;
            }
        } else if (a[0] == '-' && a[1]) {
            hlod_cli_error(PROG, "unknown option %s", a);
            usage(stderr);
            free(names);
            return 2;
        } else {
            names[n_names++] = a;
        }
    }
    if (!n_names) {
        n_names = (int)n_default;
        for (int i = 0; i < n_names; i++)
            names[i] = default_meshes[i];
    }

    hlod_cli_log log_state = {PROG, HLOD_LOG_WARN, NULL};
    hlod_logger lg = hlod_cli_logger(&log_state);
    hlod_import_desc idesc = {0};
    idesc.logger = &lg;

    /* Read every mesh before timing anything, so a bad path fails at once. */
    hlod_mesh *meshes = calloc((size_t)n_names, sizeof *meshes);
    char (*paths)[4096] = calloc((size_t)n_names, sizeof *paths);
    row *rows = calloc((size_t)n_names * (size_t)n_ratios * GROUP, sizeof *rows);
    int status = 0, n_rows = 0;
    if (!meshes || !paths || !rows) {
        hlod_cli_error(PROG, "out of memory");
        status = 1;
        goto done;
    }
    for (int i = 0; i < n_names; i++) {
        if (strchr(names[i], '/'))
            snprintf(paths[i], sizeof paths[i], "%s", names[i]);
        else
            snprintf(paths[i], sizeof paths[i], "%s/%s", mesh_dir, names[i]);
        hlod_result r = hlod_mesh_import(paths[i], &idesc, &meshes[i], NULL);
        if (r != HLOD_OK) {
            hlod_cli_error(PROG, "%s: cannot read mesh: %s", paths[i], hlod_result_str(r));
            status = 1;
            goto done;
        }
    }

    printf("hlod-bench-simplify: meshoptimizer %d.%d vs hlod_simplify at meshoptimizer's triangle "
           "count; seconds = best of %d-%d runs in turn (until ours ran %g s); hausdorff = "
           "hlod_mesh_distance, %zu samples/mesh, seed %u\n\n",
           MESHOPTIMIZER_VERSION / 1000, MESHOPTIMIZER_VERSION % 1000 / 10, RUNS, MAX_RUNS, MIN_SECONDS, samples,
           SEED);
    print_header();

    for (int i = 0; i < n_names; i++) {
        const hlod_mesh *m = &meshes[i];
        double lo[3], hi[3], c[3];
        hlod_mesh_bounds(m, lo, hi);
        for (int k = 0; k < 3; k++)
            c[k] = 0.5 * (lo[k] + hi[k]);
        double diag = hlod_mesh_bbox_diag(m);
        size_t nv = m->vertex_count;
        float *pos = malloc(nv * 3 * sizeof *pos + 1), *uv = calloc(nv * 2 + 1, sizeof *uv);
        float *wpos = malloc(nv * 3 * sizeof *wpos + 1);
        double *wposd = malloc(nv * 3 * sizeof *wposd + 1);
        uint32_t *dest = malloc(m->tri_count * 3 * sizeof *dest + 1);
        uint32_t *remap = malloc(nv * sizeof *remap + 1), *widx = malloc(m->tri_count * 3 * sizeof *widx + 1);
        /* welded attributes for simplifyWithAttributes: the normal, then the UV */
        uint32_t n_attr = m->uvs ? 5 : 3;
        float *wattr = malloc(nv * n_attr * sizeof *wattr + 1), *wtmp = malloc(nv * 3 * sizeof *wtmp + 1);
        if (!pos || !uv || !wpos || !wposd || !dest || !remap || !widx || !wattr || !wtmp) {
            free(wattr);
            free(wtmp);
            free(pos);
            free(uv);
            free(wpos);
            free(wposd);
            free(dest);
            free(remap);
            free(widx);
            hlod_cli_error(PROG, "out of memory");
            status = 1;
            goto done;
        }
        for (size_t v = 0; v < nv; v++)
            for (int k = 0; k < 3; k++)
                pos[3 * v + k] = (float)(m->positions[3 * v + k] - c[k]);
        if (m->uvs)
            memcpy(uv, m->uvs, nv * 2 * sizeof *uv);
        struct meshopt_Stream streams[2] = {{pos, 3 * sizeof(float), 3 * sizeof(float)},
                                            {uv, 2 * sizeof(float), 2 * sizeof(float)}};
        size_t wn = meshopt_generateVertexRemapMulti(remap, m->indices, 3 * m->tri_count, nv, streams, 2);
        meshopt_remapIndexBuffer(widx, m->indices, 3 * m->tri_count, remap);
        meshopt_remapVertexBuffer(wpos, pos, nv, 3 * sizeof(float), remap);
        for (size_t v = 0; v < nv; v++)
            if (remap[v] != ~0u)
                memcpy(wposd + 3 * (size_t)remap[v], m->positions + 3 * v, 3 * sizeof(double));
        const float weights[5] = {ATTR_WEIGHT, ATTR_WEIGHT, ATTR_WEIGHT, ATTR_WEIGHT, ATTR_WEIGHT};
        {
            hlod_mesh wm = {0};
            wm.vertex_count = wn;
            wm.positions = wposd;
            wm.tri_count = m->tri_count;
            wm.indices = widx;
            if (hlod_mesh_vertex_normals(&wm, wtmp) != HLOD_OK)
                memset(wtmp, 0, wn * 3 * sizeof *wtmp);
            for (size_t v = 0; v < wn; v++)
                memcpy(wattr + n_attr * v, wtmp + 3 * v, 3 * sizeof *wtmp);
            if (m->uvs) {
                meshopt_remapVertexBuffer(wtmp, uv, nv, 2 * sizeof(float), remap);
                for (size_t v = 0; v < wn; v++)
                    memcpy(wattr + n_attr * v + 3, wtmp + 2 * v, 2 * sizeof *wtmp);
            }
            free(wtmp);
        }

        for (int j = 0; j < n_ratios; j++) {
            row *rm = &rows[n_rows], *ro = rm + 1, *re = rm + 2, *rj = rm + ROW_JS;
            n_rows += GROUP;
            const char *slash = strrchr(paths[i], '/');
            size_t target = (size_t)(ratios[j] * (double)m->tri_count), n_idx = 0;
            *rm = (row){.mesh = slash ? slash + 1 : paths[i], .ratio = ratios[j], .simplifier = "meshopt",
                        .tris_in = m->tri_count, .tris_target = target, .diag = diag};
            *ro = *rm;
            ro->simplifier = "hlod";
            hlod_mesh ours = {0};
            hlod_result r = time_pair(m, widx, wpos, wn, 3 * target, dest, &n_idx, &ours, &rm->seconds,
                                      &ro->seconds, &ro->runs);
            rm->runs = ro->runs;
            rm->tris_out = n_idx / 3;
            /* Shares the welded vertices: meshopt only rewrites indices. */
            hlod_mesh mo = {0};
            mo.vertex_count = wn;
            mo.positions = wposd;
            mo.tri_count = rm->tris_out;
            mo.indices = dest;

            if (r != HLOD_OK) {
                hlod_cli_error(PROG, "%s: hlod_simplify failed: %s", paths[i], hlod_result_str(r));
                status = 1;
            }
            ro->tris_out = ours.tri_count;
            rm->missed = (double)rm->tris_out > REACH_SLACK * (double)target;
            ro->missed = (double)ro->tris_out > REACH_SLACK * (double)target;
            /* ours again at meshopt's count (untimed) */
            *re = *rm;
            re->simplifier = "hlod_eq";
            re->tris_target = rm->tris_out ? rm->tris_out : 1;
            re->seconds = 0;
            re->runs = 0;
            hlod_mesh eq = {0};
            double t_eq;
            if (r == HLOD_OK && (r = time_ours(m, re->tris_target, &eq, &t_eq)) != HLOD_OK) {
                hlod_cli_error(PROG, "%s: hlod_simplify at meshopt's count failed: %s", paths[i],
                               hlod_result_str(r));
                status = 1;
            }
            re->tris_out = eq.tri_count;
            re->missed = (double)re->tris_out > REACH_SLACK * (double)re->tris_target;

            /* meshoptimizer's current simplifier, when installed */
            *rj = *rm;
            rj->simplifier = "meshopt_js";
            rj->seconds = 0;
            rj->tris_out = 0;
            rj->missed = 0;
            rj->runs = 0;
            uint32_t *destj = malloc(3 * m->tri_count * sizeof *destj);
            size_t nj = destj && make_dirs(out_dir)
                            ? time_meshopt_js(out_dir, widx, 3 * m->tri_count, wpos, wn, NULL, NULL, 0,
                                              3 * target, destj, &rj->seconds)
                            : (size_t)-1;
            hlod_mesh mj = mo;
            mj.indices = destj;
            if (nj != (size_t)-1) {
                rj->tris_out = nj / 3;
                rj->missed = (double)rj->tris_out > REACH_SLACK * (double)target;
                mj.tri_count = rj->tris_out;
            }
            /* ... and with the attributes weighted, seams kept */
            row *ra = rm + ROW_JS_ATTR, *rae = rm + ROW_EQ_JS_ATTR;
            hlod_mesh ma = {0}, eq_a = {0};
            uint32_t *desta = malloc(3 * m->tri_count * sizeof *desta);
            *ra = *rae = *rm;
            rae->simplifier = "hlod_eq_js_attr";
            rae->measured = 0;
            if (js_attr_run(out_dir, widx, 3 * m->tri_count, wpos, wattr, weights, n_attr, wn,
                            target, desta, &mo, ra, &ma) &&
                ra->missed) {
                /* it stopped short: ours at its count too (untimed) */
                rae->tris_target = ra->tris_out ? ra->tris_out : 1;
                double t_a;
                if (r == HLOD_OK && time_ours(m, rae->tris_target, &eq_a, &t_a) == HLOD_OK) {
                    rae->tris_out = eq_a.tri_count;
                    rae->missed = (double)rae->tris_out > REACH_SLACK * (double)rae->tris_target;
                    if (measure(m, &eq_a, samples, rae) != HLOD_OK)
                        rae->measured = 0;
                }
            }
            if (ra->tris_out && measure(m, &ma, samples, ra) != HLOD_OK)
                ra->measured = 0;
            free(desta);
            hlod_mesh_free(&eq_a);

            hlod_result r1 = measure(m, &mo, samples, rm);
            hlod_result r2 = measure(m, &ours, samples, ro);
            if (r2 == HLOD_OK)
                r2 = measure(m, &eq, samples, re);
            if (r1 == HLOD_OK && nj != (size_t)-1)
                r1 = measure(m, &mj, samples, rj);
            else
                rj->measured = 0;
            free(destj);
            hlod_mesh_free(&eq);
            if (r1 != HLOD_OK || r2 != HLOD_OK) {
                hlod_cli_error(PROG, "%s: hlod_mesh_distance failed: %s", paths[i],
                               hlod_result_str(r1 != HLOD_OK ? r1 : r2));
                status = 1;
            }
            hlod_mesh_free(&ours);
            print_row(rm);
            print_row(ro);
            print_row(re);
            if (nj != (size_t)-1)
                print_row(rj);
            if (ra->measured)
                print_row(ra);
            if (rae->measured)
                print_row(rae);
        }
        free(pos);
        free(uv);
        free(wpos);
        free(wposd);
        free(dest);
        free(remap);
        free(widx);
        free(wattr);
    }

    summary s = summarise(rows, n_rows, 1, 0), se = summarise(rows, n_rows, 2, 0),
            sj = summarise(rows, n_rows, 1, ROW_JS),
            sa = summarise_fair(rows, n_rows, ROW_JS_ATTR, ROW_EQ_JS_ATTR);
    printf("\nsummary: ours / meshopt, both at the requested target (eq: ours at meshopt's count)\n");
    printf("%-22s %6s %8s %8s %8s %8s %8s %8s %8s %5s\n", "mesh", "ratio", "target", "meshopt",
           "ours", "max", "mean", "max_eq", "mean_eq", "time");
    for (int i = 0; i + GROUP - 1 < n_rows; i += GROUP) {
        const row *m = &rows[i], *o = &rows[i + 1], *e = &rows[i + 2];
        printf("%-22s %6g %8zu %8zu %8zu ", m->mesh, m->ratio, m->tris_target, m->tris_out,
               o->tris_out);
        if (m->measured && o->measured && e->measured)
            printf("%8.3f %8.3f %8.3f %8.3f", pair_ratio(o->d.max, m->d.max),
                   pair_ratio(o->d.mean, m->d.mean), pair_ratio(e->d.max, m->d.max),
                   pair_ratio(e->d.mean, m->d.mean));
        else
            printf("%8s %8s %8s %8s", "-", "-", "-", "-");
        printf(" %5.2f%s%s\n", pair_ratio(o->seconds, m->seconds), o->missed ? "  ! ours missed" : "",
               m->missed ? "  ! meshopt missed" : "");
    }
    printf("at the requested target: our max <= meshopt's on every pair: %s; average mean ratio "
           "%.3f (target <= %.2f: %s)\n", s.all_max_le ? "yes" : "no", s.mean_ratio_avg,
           TARGET_MEAN_RATIO, s.mean_ratio_pairs && s.mean_ratio_avg <= TARGET_MEAN_RATIO ? "met" : "NOT met");
    printf("at equal count: our max <= meshopt's on every pair: %s; average mean ratio %.3f\n",
           se.all_max_le ? "yes" : "no", se.mean_ratio_avg);
    printf("targets missed (over %.0f%%): ours %d, meshopt %d\n", (REACH_SLACK - 1) * 100,
           s.missed_ours, s.missed_meshopt);
    printf("our min throughput: %.2f Mtri/s; our time / meshopt's: geometric mean %.2f, worst %.2f\n",
           s.min_mtri, s.time_ratio_geo, s.time_ratio_max);
    if (sj.mean_ratio_pairs) {
        printf("\nagainst meshoptimizer's current simplifier (npm, Prune + Permissive), both at the "
               "requested target:\n");
        printf("%-22s %6s %8s %8s %8s %8s %8s\n", "mesh", "ratio", "target", "js", "ours", "max", "mean");
        for (int i = 0; i + GROUP - 1 < n_rows; i += GROUP) {
            const row *j = &rows[i + 3], *o = &rows[i + 1];
            if (!j->measured || !o->measured)
                continue;
            printf("%-22s %6g %8zu %8zu %8zu %8.3f %8.3f%s\n", j->mesh, j->ratio, j->tris_target,
                   j->tris_out, o->tris_out, pair_ratio(o->d.max, j->d.max),
                   pair_ratio(o->d.mean, j->d.mean), j->missed ? "  ! js missed" : "");
        }
        printf("our max <= its max on every pair: %s; average mean ratio %.3f\n",
               sj.all_max_le ? "yes" : "no", sj.mean_ratio_avg);
        print_js_attr(rows, n_rows, &sa);
    } else {
        printf("meshoptimizer's npm package: not installed (npm ci in the source tree), not compared\n");
    }

    char csv[4200], json[4200];
    snprintf(csv, sizeof csv, "%s/simplify.csv", out_dir);
    snprintf(json, sizeof json, "%s/summary.json", out_dir);
    if (!make_dirs(out_dir)) {
        hlod_cli_error(PROG, "%s: cannot create folder: %s", out_dir, strerror(errno));
        status = 1;
        goto done;
    }
    if (write_csv(csv, rows, n_rows, &lg) != HLOD_OK ||
        write_json(json, rows, n_rows, &s, &se, &sj, &sa, samples, &lg) != HLOD_OK) {
        hlod_cli_error(PROG, "cannot write %s or %s", csv, json);
        status = 1;
        goto done;
    }
    printf("\nwrote %s and %s\n", csv, json);

done:
    if (meshes)
        for (int i = 0; i < n_names; i++)
            hlod_mesh_free(&meshes[i]);
    free(meshes);
    free(paths);
    free(rows);
    free(names);
    return status;
}
