/*
 * hlod-merge: a sharded build's part files in, the store out.
 *
 *   hlod-merge PART... -o OUT.hlod [--threads T] [--json] [--quiet]
 *
 * The parts are hlod-build --shard I/N outputs of one build, every I once,
 * in any order.  The store written is byte for byte the one hlod-build
 * writes unsharded (docs/sharded-builds.md); the merge is the library's
 * (hlod/build_store.h, preprocess/part.c).
 */
#include "cli.h"
#include "hlod/build_store.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define PROG "hlod-merge"

static void usage(FILE *fp)
{
    fprintf(fp,
            "usage: hlod-merge PART... -o OUT.hlod [options]\n"
            "\n"
            "Merges the part files of a sharded build (hlod-build --shard I/N, every\n"
            "shard of one build once, in any order) into one store: the same bytes\n"
            "hlod-build writes without --shard for the same inputs and options.\n"
            "Parts that are damaged, missing, given twice or from another build are\n"
            "refused, naming them; the store appears only when complete.\n"
            "\n"
            "  -o, --output OUT       the store to write (required)\n"
            "  --threads T            threads for the levels above the shards\n"
            "                         (default: every core)\n"
            "  --json                 print one JSON object on stdout: parts, shards,\n"
            "                         blocks, nodes, cut_level, nodes_copied,\n"
            "                         groups_built, bytes, seconds, peak_rss_bytes\n"
            "  --quiet                errors only\n"
            "  -h, --help             show this help\n"
            "\n"
            "Exit status: 0 success, 1 failure (nothing written), 2 bad command line.\n");
}

int main(int argc, char **argv)
{
    const char **parts = calloc((size_t)argc + 1, sizeof *parts);
    const char *out = NULL;
    size_t n = 0;
    int json = 0, quiet = 0;
    long cpus = sysconf(_SC_NPROCESSORS_ONLN);
    size_t threads = cpus > 0 ? (size_t)cpus : 1;
    if (!parts)
        return 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            free(parts);
            return 0;
        } else if (!strcmp(a, "-o") || !strcmp(a, "--output") || !strcmp(a, "--threads")) {
            if (i + 1 >= argc) {
                hlod_cli_error(PROG, "%s: needs a value", a);
                free(parts);
                return 2;
            }
            const char *val = argv[++i];
            if (a[1] == 'o' || !strcmp(a, "--output")) {
                out = val;
            } else if (!hlod_cli_parse_size(PROG, a, val, 1, 256, &threads)) {
                free(parts);
                return 2;
            }
        } else if (!strcmp(a, "--json")) {
            json = 1;
        } else if (!strcmp(a, "--quiet")) {
            quiet = 1;
        } else if (a[0] == '-' && a[1]) {
            hlod_cli_error(PROG, "unknown option %s (see --help)", a);
            free(parts);
            return 2;
        } else {
            parts[n++] = a;
        }
    }
    if (!n || !out) {
        hlod_cli_error(PROG, !n ? "no part file (see --help)" : "no output: -o OUT.hlod is required");
        free(parts);
        return 2;
    }
    double t0 = hlod_cli_now();
    hlod_cli_log ls = {PROG, quiet ? HLOD_LOG_ERROR : HLOD_LOG_WARN, NULL};
    hlod_logger lg = hlod_cli_logger(&ls);
    hlod_merge_report rep;
    hlod_result r = hlod_merge_store(parts, n, out, threads, &lg, &rep);
    free(parts);
    if (r != HLOD_OK)
        return 1;
    struct stat st;
    size_t bytes = stat(out, &st) == 0 ? (size_t)st.st_size : 0;
    double secs = hlod_cli_now() - t0;
    if (!quiet)
        fprintf(stderr, "%s: %s: %zu parts, %zu blocks, %zu nodes (%zu copied, %zu groups built "
                "above level %zu), %.1f MB, %.1f s\n", PROG, out, rep.parts, rep.blocks, rep.nodes,
                rep.nodes_copied, rep.groups_built, rep.cut_level, bytes / 1e6, secs);
    if (json) {
        hlod_json j;
        hlod_json_begin(&j, stdout);
        hlod_json_size(&j, "parts", rep.parts);
        hlod_json_size(&j, "shards", rep.shards);
        hlod_json_size(&j, "blocks", rep.blocks);
        hlod_json_size(&j, "nodes", rep.nodes);
        hlod_json_size(&j, "cut_level", rep.cut_level);
        hlod_json_size(&j, "nodes_copied", rep.nodes_copied);
        hlod_json_size(&j, "groups_built", rep.groups_built);
        hlod_json_size(&j, "bytes", bytes);
        hlod_json_double(&j, "seconds", secs);
        hlod_json_size(&j, "peak_rss_bytes", hlod_cli_peak_rss());
        if (hlod_json_end(&j) != 0)
            return 1;
    }
    return 0;
}
