/*
 * hlod-lumigraph-bake: the Grid-Lumigraph's sampling repository (Okamoto et
 * al., section 4.3): a store rendered from the G^3 points of a grid over a
 * box twice the model's size, six 90-degree axis views per point, each a
 * JPEG with its depth (docs/hlod-lumigraph-bake.md, docs/lumigraph.md).
 *
 *   hlod-lumigraph-bake STORE -o REPO [--grid G] [--size N] [--depth-size N]
 *                       [--quality Q] [--shard I/N] [--json] [--quiet]
 *   hlod-lumigraph-bake --merge -o REPO PART...
 *
 * Views are rendered at full detail (the engine's full policy, which is
 * okamoto's depth-first cut at a threshold of zero), so a view is the same
 * bytes whatever was baked before it: an interrupted bake continues where
 * it stopped, and shards merge into the repository one bake would write.
 */
#include "cli.h"
#include "lumi_bake.h"
#include "hlod/engine.h"
#include "hlod/lumigraph.h"
#include "hlod/renderer.h"
#include "hlod/store.h"

#include "atomic_file.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static const char *const PROG = "hlod-lumigraph-bake";

static void usage(FILE *fp)
{
    fprintf(fp,
        "usage: hlod-lumigraph-bake STORE -o REPO [options]\n"
        "       hlod-lumigraph-bake --merge -o REPO PART...\n"
        "\n"
        "Renders STORE from the G^3 points of a grid over a box twice the model's\n"
        "size, six 90-degree views along the axes per point, and writes each view\n"
        "(a JPEG and its depth) into the sampling repository REPO, a folder; views\n"
        "that see nothing are flagged empty in REPO/repo.hlg, not stored.  A bake\n"
        "into a REPO that holds an unfinished bake of the same parameters goes on\n"
        "from where it stopped.\n"
        "\n"
        "  -o, --out REPO     the repository folder (created)\n"
        "  --grid G           grid points per axis, 2..64 (default 16)\n"
        "  --size N           views are N x N pixels, 8..2048 (default 512)\n"
        "  --depth-size N     their depth is N x N, N dividing --size (default\n"
        "                     --size); a coarser depth keeps each block's nearest\n"
        "  --quality Q        JPEG quality 1..100 (default 85)\n"
        "  --box X0,Y0,Z0,X1,Y1,Z1  the grid's box instead of twice the model's\n"
        "                     (e.g. a city's up to the height its paths fly at)\n"
        "  --shard I/N        bake only grid points p with p mod N = I - 1 into\n"
        "                     REPO (1 <= I <= N); --merge joins the N folders\n"
        "  --merge            join the shard folders PART... into REPO (each view\n"
        "                     from the part that baked it; the parts must share\n"
        "                     every parameter and the store)\n"
        "  --json             print a summary on stdout: views, empty, missing,\n"
        "                     bytes, view_bytes_max, seconds, grid, size,\n"
        "                     depth_size, points, shard_index, shard_count\n"
        "  --quiet            no progress bar\n"
        "  -h, --help         show this help\n"
        "\n"
        "Exit status: 0 success, 1 failure (stderr names the file and the\n"
        "problem), 2 bad command line.\n");
}

typedef struct options {
    const char *store, *out;
    const char *parts[256];
    size_t part_count;
    size_t grid, size, depth_size, quality, shard_i, shard_n;
    double box[6];
    int have_box;
    int json, quiet, merge;
} options;

static int parse_args(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    o->grid = 16;
    o->size = 512;
    o->quality = 85;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = NULL;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            exit(0);
        } else if (!strcmp(a, "-o") || hlod_cli_match_flag(argc, argv, &i, "--out", &v)) {
            if (!strcmp(a, "-o"))
                v = i + 1 < argc ? argv[++i] : NULL;
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a folder", "--out");
            o->out = v;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--grid", &v)) {
            if (!v || !hlod_cli_parse_size(PROG, "--grid", v, 2, HLOD_LUMI_GRID_MAX, &o->grid))
                return 2;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--size", &v)) {
            if (!v || !hlod_cli_parse_size(PROG, "--size", v, 8, HLOD_LUMI_SIZE_MAX, &o->size))
                return 2;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--depth-size", &v)) {
            if (!v || !hlod_cli_parse_size(PROG, "--depth-size", v, 1, HLOD_LUMI_SIZE_MAX,
                                           &o->depth_size))
                return 2;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--box", &v)) {
            char tail;
            double *q = o->box;
            if (!v || sscanf(v, "%lf,%lf,%lf,%lf,%lf,%lf%c", &q[0], &q[1], &q[2], &q[3], &q[4],
                             &q[5], &tail) != 6 ||
                !(q[3] > q[0] && q[4] > q[1] && q[5] > q[2]) || !isfinite(q[0] + q[1] + q[2]) ||
                !isfinite(q[3] + q[4] + q[5]))
                return hlod_cli_usage_error(PROG, "--box: '%s' is not X0,Y0,Z0,X1,Y1,Z1 with "
                                            "X0 < X1, Y0 < Y1, Z0 < Z1", v ? v : "");
            o->have_box = 1;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--quality", &v)) {
            if (!v || !hlod_cli_parse_size(PROG, "--quality", v, 1, 100, &o->quality))
                return 2;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--shard", &v)) {
            unsigned si = 0, sn = 0;
            char tail;
            if (!v || sscanf(v, "%u/%u%c", &si, &sn, &tail) != 2 || si < 1 || sn < 1 || si > sn ||
                sn > 65536)
                return hlod_cli_usage_error(PROG, "--shard: '%s' is not I/N with 1 <= I <= N", v ? v : "");
            o->shard_i = si;
            o->shard_n = sn;
        } else if (!strcmp(a, "--merge")) {
            o->merge = 1;
        } else if (!strcmp(a, "--json")) {
            o->json = 1;
        } else if (!strcmp(a, "--quiet")) {
            o->quiet = 1;
        } else if (a[0] == '-' && a[1]) {
            return hlod_cli_usage_error(PROG, "unknown option '%s'", a);
        } else if (o->merge || o->store) {
            if (o->part_count == sizeof o->parts / sizeof *o->parts)
                return hlod_cli_usage_error(PROG, "too many parts (at most 256): '%s'", a);
            o->parts[o->part_count++] = a;
        } else {
            o->store = a;
        }
    }
    if (o->merge && o->store) { /* the first part was taken for a store */
        memmove(o->parts + 1, o->parts, o->part_count * sizeof *o->parts);
        o->parts[0] = o->store;
        o->part_count++;
        o->store = NULL;
    }
    if (!o->out)
        return hlod_cli_usage_error(PROG, "no repository folder given (%s)", "-o REPO");
    if (o->merge ? !o->part_count : !o->store || o->part_count)
        return hlod_cli_usage_error(PROG, "%s", o->merge ? "--merge needs the shard folders"
                                                         : "give one STORE to bake");
    if (!o->depth_size)
        o->depth_size = o->size;
    if (o->size % o->depth_size)
        return hlod_cli_usage_error(PROG, "--depth-size must divide --size (%s)", "e.g. 512 and 256");
    return 0;
}

/* ---- baking ---- */

/* Adopts an unfinished bake in REPO with the same parameters; 0 (said)
 * when REPO holds a bake of others. */
static int resume(lumi_baker *b, const char *repo)
{
    char path[4200];
    snprintf(path, sizeof path, "%s/%s", repo, HLOD_LUMI_INDEX_NAME);
    if (!hlod_is_file(path))
        return 1;
    hlod_lumi_index old;
    if (hlod_lumi_index_load(repo, &b->lg, &old) != HLOD_OK)
        return 0;
    int same = lumi_same_shape(&old, &b->ix);
    if (same)
        memcpy(b->ix.state, old.state, b->ix.views);
    else
        hlod_cli_error(PROG, "%s: holds a bake of another store or other parameters (grid %u, "
                       "size %u, depth size %u, quality %u); remove it or bake into another "
                       "folder", path, old.grid, old.size, old.depth_size, old.quality);
    hlod_lumi_index_free(&old);
    return same;
}

/* Bytes of the baked views in repo (and the largest). */
static void count_bytes(const hlod_lumi_index *ix, const char *repo, size_t *bytes, size_t *max)
{
    *bytes = HLOD_LUMI_INDEX_HEAD + ix->views;
    *max = 0;
    for (uint32_t id = 0; id < ix->views; id++) {
        if (ix->state[id] != HLOD_LUMI_BAKED)
            continue;
        char rel[128], path[4200];
        struct stat sb;
        hlod_lumi_view_path(ix, id, rel, sizeof rel);
        snprintf(path, sizeof path, "%s/%s", repo, rel);
        if (stat(path, &sb) == 0) {
            *bytes += (size_t)sb.st_size;
            if ((size_t)sb.st_size > *max)
                *max = (size_t)sb.st_size;
        }
    }
}

static void print_json(const options *o, const hlod_lumi_index *ix, const char *repo,
                       double seconds)
{
    size_t baked = 0, empty = 0, missing = 0, bytes, max;
    for (uint32_t id = 0; id < ix->views; id++) {
        baked += ix->state[id] == HLOD_LUMI_BAKED;
        empty += ix->state[id] == HLOD_LUMI_EMPTY;
        missing += ix->state[id] == HLOD_LUMI_MISSING;
    }
    count_bytes(ix, repo, &bytes, &max);
    hlod_json j;
    hlod_json_begin(&j, stdout);
    hlod_json_size(&j, "views", baked);
    hlod_json_size(&j, "empty", empty);
    hlod_json_size(&j, "missing", missing);
    hlod_json_size(&j, "bytes", bytes);
    hlod_json_size(&j, "view_bytes_max", max);
    hlod_json_double(&j, "seconds", seconds);
    hlod_json_size(&j, "grid", ix->grid);
    hlod_json_size(&j, "size", ix->size);
    hlod_json_size(&j, "depth_size", ix->depth_size);
    hlod_json_size(&j, "points", (size_t)ix->grid * ix->grid * ix->grid);
    hlod_json_size(&j, "shard_index", o->shard_i);
    hlod_json_size(&j, "shard_count", o->shard_n);
    hlod_json_end(&j);
}

static int bake(const options *o)
{
    double t0 = hlod_cli_now();
    hlod_cli_progress bar;
    hlod_cli_progress_begin(&bar, "views", !o->quiet);
    hlod_cli_log ls = {PROG, HLOD_LOG_WARN, &bar};
    lumi_baker b;
    int ok = lumi_baker_open(&b, PROG, o->store, hlod_cli_logger(&ls), (uint32_t)o->grid,
                             (uint32_t)o->size, (uint32_t)o->depth_size, (uint32_t)o->quality,
                             o->have_box ? o->box : NULL);
    int err = ok ? hlod_mkdir_p(o->out, 0777) : 0;
    if (err) {
        hlod_cli_error(PROG, "%s: cannot make the folder: %s", o->out, strerror(err));
        ok = 0;
    }
    ok = ok && resume(&b, o->out);
    const int adopted = ok; /* REPO's index is ours to write */
    uint32_t points = b.ix.grid * b.ix.grid * b.ix.grid, total = 0, done = 0;
    for (uint32_t p = 0; ok && p < points; p++)
        total += !o->shard_n || p % o->shard_n == o->shard_i - 1;
    total *= HLOD_LUMI_FACES;
    double saved = hlod_cli_now();
    for (uint32_t p = 0; ok && p < points; p++) {
        if (o->shard_n && p % o->shard_n != o->shard_i - 1)
            continue;
        for (uint32_t d = 0; ok && d < HLOD_LUMI_FACES; d++, done++) {
            uint32_t id = p * HLOD_LUMI_FACES + d;
            if (b.ix.state[id] == HLOD_LUMI_MISSING)
                ok = lumi_baker_view(&b, id, o->out);
            hlod_cli_progress_fn(&bar, done + 1, total);
        }
        /* the index now and then: an interrupted bake keeps its views */
        if (ok && hlod_cli_now() - saved > 5) {
            ok = hlod_lumi_index_save(o->out, &b.ix, &b.lg) == HLOD_OK;
            saved = hlod_cli_now();
        }
    }
    /* saved after a failure too: the views written so far are kept */
    if (adopted && hlod_lumi_index_save(o->out, &b.ix, &b.lg) != HLOD_OK)
        ok = 0;
    hlod_cli_progress_clear(&bar);
    if (ok && o->json)
        print_json(o, &b.ix, o->out, hlod_cli_now() - t0);
    lumi_baker_close(&b);
    return ok ? 0 : 1;
}

/* ---- merging ---- */

/* Links (or copies) src to dst under a temporary name, then renames it
 * over dst: dst is never missing, and src and dst the same file (a folder
 * named two ways) is left alone. */
static int place_file(const char *src, const char *dst, const hlod_logger *lg)
{
    struct stat a, b;
    if (stat(src, &a) == 0 && stat(dst, &b) == 0 && a.st_dev == b.st_dev && a.st_ino == b.st_ino)
        return 1;
    char tmp[4300];
    snprintf(tmp, sizeof tmp, "%s.merge-%ld", dst, (long)getpid());
    unlink(tmp);
    if (link(src, tmp) == 0) {
        if (rename(tmp, dst) == 0)
            return 1;
        unlink(tmp);
    }
    FILE *in = fopen(src, "rb");
    if (!in) {
        hlod_cli_error(PROG, "%s: %s", src, strerror(errno));
        return 0;
    }
    hlod_atomic_file af;
    int ok = hlod_atomic_open(&af, dst, lg) == HLOD_OK;
    char buf[65536];
    size_t n;
    while (ok && (n = fread(buf, 1, sizeof buf, in)) > 0)
        ok = fwrite(buf, 1, n, af.fp) == n;
    ok = ok && !ferror(in);
    fclose(in);
    if (!ok) {
        hlod_atomic_abort(&af);
        hlod_cli_error(PROG, "%s: cannot copy to %s", src, dst);
        return 0;
    }
    return hlod_atomic_commit(&af, lg) == HLOD_OK;
}

static int merge(const options *o)
{
    double t0 = hlod_cli_now();
    hlod_cli_log ls = {PROG, HLOD_LOG_WARN, NULL};
    hlod_logger lg = hlod_cli_logger(&ls);
    hlod_lumi_index out = {0}, part = {0};
    int ok = hlod_mkdir_p(o->out, 0777) == 0;
    if (!ok)
        hlod_cli_error(PROG, "%s: cannot make the folder: %s", o->out, strerror(errno));
    for (size_t k = 0; ok && k < o->part_count; k++) {
        const char *dir = o->parts[k];
        ok = hlod_lumi_index_load(dir, &lg, &part) == HLOD_OK;
        if (ok && k == 0) {
            ok = hlod_lumi_index_init(&out, part.grid, part.size, part.depth_size, part.quality,
                                      part.box_min, part.box_max, part.near_plane,
                                      part.far_plane, part.store_id) == HLOD_OK;
            /* an index already in REPO must be of the same bake */
            hlod_lumi_index have;
            char ipath[4200];
            snprintf(ipath, sizeof ipath, "%s/%s", o->out, HLOD_LUMI_INDEX_NAME);
            if (ok && hlod_is_file(ipath)) {
                ok = hlod_lumi_index_load(o->out, &lg, &have) == HLOD_OK;
                if (ok && !lumi_same_shape(&have, &out)) {
                    hlod_cli_error(PROG, "%s: holds a bake of another store or other parameters "
                                   "than %s's; merge into another folder", ipath, dir);
                    ok = 0;
                }
                hlod_lumi_index_free(&have);
            }
        } else if (ok && !lumi_same_shape(&part, &out)) {
            hlod_cli_error(PROG, "%s/%s: a bake of another store or other parameters than %s's",
                           dir, HLOD_LUMI_INDEX_NAME, o->parts[0]);
            ok = 0;
        }
        for (uint32_t id = 0; ok && id < out.views; id++) {
            if (out.state[id] != HLOD_LUMI_MISSING || part.state[id] == HLOD_LUMI_MISSING)
                continue;
            if (part.state[id] == HLOD_LUMI_BAKED) {
                uint32_t x, y, z, d;
                char rel[128], src[4200], dst[4200], sub[4200];
                hlod_lumi_view_key(&out, id, &x, &y, &z, &d);
                hlod_lumi_view_path(&out, id, rel, sizeof rel);
                snprintf(src, sizeof src, "%s/%s", dir, rel);
                snprintf(dst, sizeof dst, "%s/%s", o->out, rel);
                snprintf(sub, sizeof sub, "%s/views/%u", o->out, x);
                if (strcmp(src, dst))
                    ok = hlod_mkdir_p(sub, 0777) == 0 && place_file(src, dst, &lg);
            }
            out.state[id] = part.state[id];
        }
        hlod_lumi_index_free(&part);
    }
    if (ok)
        ok = hlod_lumi_index_save(o->out, &out, &lg) == HLOD_OK;
    if (ok && o->json)
        print_json(o, &out, o->out, hlod_cli_now() - t0);
    hlod_lumi_index_free(&out);
    return ok ? 0 : 1;
}

int main(int argc, char **argv)
{
    options o;
    int r = parse_args(argc, argv, &o);
    if (r)
        return r;
    return o.merge ? merge(&o) : bake(&o);
}
