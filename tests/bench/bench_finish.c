/*
 * bench_finish.c - hlod-bench-finish: what the loader thread spends
 * finishing payloads (checksum, decoding, validation, the texel chain),
 * per store and per way a block-coded texture comes out
 * (docs/hlod-bench-finish.md, docs/runtime.md "Texture upload").
 *
 *   hlod-bench-finish STORE... [--rounds N] [--json]
 *
 * For each store and each mode (texels: level 0 only, as the tools read;
 * expanded: the texel chain, as the loader makes it for a GL that takes
 * texels; blocks: the stored blocks, for a GL that samples them), every
 * node is read whole (from the page cache after the first round: the
 * read and its hash are timed apart) and then finished as the loader
 * finishes it: hlod_store_read_finish_as, then hlod_texture_prepare where
 * no chain came out.  Times are the thread's CPU time, the best of
 * --rounds rounds (default 3), so a busy machine slows both alike.
 * Prints a table; --json prints one JSON object instead.  Exit 0, 1 when a
 * store cannot be opened or a payload fails, 2 on a bad command line.
 */
#include "cli.h"
#include "hlod/store.h"
#include "texture.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static const char *const PROG = "hlod-bench-finish";
static const char *const MODE_NAME[3] = {"texels", "expanded", "blocks"};

static double cpu_s(void)
{
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (double)t.tv_sec + (double)t.tv_nsec * 1e-9;
}

typedef struct result {
    double read_s, finish_s, bytes;
    uint32_t nodes;
} result;

/* s as a JSON string's contents. */
static void json_text(const char *s)
{
    for (; *s; s++) {
        if (*s == '"' || *s == '\\')
            printf("\\%c", *s);
        else if ((unsigned char)*s < 0x20)
            printf("\\u%04x", (unsigned char)*s);
        else
            putchar(*s);
    }
}

/* One round over every node of s in mode; 0, or 1 naming a failed node. */
static int round_of(const hlod_store *s, int mode, result *out)
{
    memset(out, 0, sizeof *out);
    uint32_t n = hlod_store_node_count(s);
    for (uint32_t i = 0; i < n; i++) {
        hlod_store_read rd;
        int complete = 0;
        double t0 = cpu_s();
        hlod_result r = hlod_store_read_begin(s, i, &rd);
        while (r == HLOD_OK && !complete)
            r = hlod_store_read_step(&rd, 1u << 20, &complete);
        double t1 = cpu_s();
        if (r != HLOD_OK) {
            hlod_store_read_cancel(&rd);
            hlod_cli_error(PROG, "%s: node %u: cannot read: %s", hlod_store_path(s), i,
                           hlod_result_str(r));
            return 1;
        }
        out->bytes += (double)rd.size;
        hlod_store_payload p;
        r = hlod_store_read_finish_as(&rd, mode, &p);
        if (r == HLOD_OK && mode != HLOD_TEXOUT_PIXELS)
            r = hlod_texture_prepare(&p);
        double t2 = cpu_s();
        hlod_store_payload_free(&p);
        if (r != HLOD_OK) {
            hlod_cli_error(PROG, "%s: node %u: cannot finish: %s", hlod_store_path(s), i,
                           hlod_result_str(r));
            return 1;
        }
        out->read_s += t1 - t0;
        out->finish_s += t2 - t1;
        out->nodes++;
    }
    return 0;
}

static void usage(FILE *fp)
{
    fprintf(fp,
            "usage: hlod-bench-finish STORE... [--rounds N] [--json]\n"
            "\n"
            "The loader thread's finishing work (checksum, decoding, validation, the\n"
            "texel chain) over every node of each store, in each way a block-coded\n"
            "texture comes out: texels (level 0), expanded (the texel chain), blocks.\n"
            "Thread CPU time, the best of N rounds.\n"
            "\n"
            "  --rounds N    rounds per store and mode, best kept (1..100, default 3)\n"
            "  --json        print one JSON object instead of the table: rows of store,\n"
            "                mode, nodes, bytes, read_s, finish_s, finish_ms_per_mb,\n"
            "                finish_share\n"
            "  -h, --help    show this help\n"
            "\n"
            "Exit status: 0 success, 1 a store or payload failed, 2 bad command line.\n");
}

int main(int argc, char **argv)
{
    size_t rounds = 3;
    int json = 0, nstores = 0;
    const char **stores = calloc((size_t)argc, sizeof *stores);
    if (!stores)
        return 1;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            free(stores);
            return 0;
        } else if (!strcmp(a, "--json")) {
            json = 1;
        } else if (!strcmp(a, "--rounds")) {
            if (i + 1 >= argc || !hlod_cli_parse_size(PROG, a, argv[i + 1], 1, 100, &rounds)) {
                if (i + 1 >= argc)
                    hlod_cli_error(PROG, "--rounds needs a value");
                free(stores);
                return 2;
            }
            i++;
        } else if (a[0] == '-') {
            hlod_cli_error(PROG, "unknown option '%s'", a);
            free(stores);
            return 2;
        } else {
            stores[nstores++] = a;
        }
    }
    if (!nstores) {
        hlod_cli_error(PROG, "no store given");
        usage(stderr);
        free(stores);
        return 2;
    }
    int status = 0, rows = 0;
    if (json)
        printf("{\"rounds\": %zu, \"rows\": [", rounds);
    else
        printf("%-40s %-9s %7s %12s %8s %9s %10s %7s\n", "store", "mode", "nodes", "bytes",
               "read_s", "finish_s", "ms_per_MB", "share");
    for (int k = 0; k < nstores && !status; k++) {
        hlod_store *s = NULL;
        if (hlod_store_open(stores[k], NULL, &s) != HLOD_OK) {
            hlod_cli_error(PROG, "%s: cannot open store", stores[k]);
            status = 1;
            break;
        }
        for (int mode = HLOD_TEXOUT_PIXELS; mode <= HLOD_TEXOUT_BLOCKS && !status; mode++) {
            result best = {0}, r;
            for (size_t q = 0; q < rounds && !status; q++) {
                status = round_of(s, mode, &r);
                if (!status && (q == 0 || r.finish_s < best.finish_s))
                    best = r;
            }
            if (status)
                break;
            double per_mb = best.bytes > 0 ? best.finish_s * 1e3 / (best.bytes / 1e6) : 0;
            double share = best.finish_s + best.read_s > 0
                               ? best.finish_s / (best.finish_s + best.read_s) : 0;
            if (json) {
                printf("%s{\"store\": \"", rows++ ? ", " : "");
                json_text(stores[k]);
                printf("\", \"mode\": \"%s\", \"nodes\": %u, \"bytes\": %.0f, \"read_s\": %.6f, "
                       "\"finish_s\": %.6f, \"finish_ms_per_mb\": %.4f, \"finish_share\": %.4f}",
                       MODE_NAME[mode], best.nodes, best.bytes, best.read_s, best.finish_s, per_mb,
                       share);
            }
            else
                printf("%-40s %-9s %7u %12.0f %8.3f %9.3f %10.2f %7.3f\n", stores[k],
                       MODE_NAME[mode], best.nodes, best.bytes, best.read_s, best.finish_s,
                       per_mb, share);
        }
        hlod_store_close(s);
    }
    if (json)
        printf("]}\n");
    free(stores);
    return status;
}
