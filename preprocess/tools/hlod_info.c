/*
 * hlod-info: statistics of an HLOD store, and a full integrity check.
 *
 *   hlod-info FILE [--verify] [--json]
 *
 * Opens FILE with the validating reader (header, node table and its
 * checksum, every structural rule), prints the build parameters and per
 * depth the nodes, triangles, bytes and error range.  --verify also reads
 * every payload as the loader does (64 KiB steps), checks its checksum and
 * parses it, naming each corrupt node.  --json prints one JSON object on
 * stdout instead of the table; its keys are read by scripts, keep them
 * stable.
 *
 * Exit status: 0 valid, 1 the store cannot be read or is corrupt, 2 bad
 * command line.
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cli.h"
#include "hlod/store.h"

static const char *const PROG = "hlod-info";

static void usage(FILE *fp)
{
    fprintf(fp,
        "usage: hlod-info FILE [--verify] [--json]\n"
        "\n"
        "Shows an HLOD store's build parameters and tree statistics: nodes,\n"
        "triangles, payload and texture bytes and the geometric error range per\n"
        "depth.  Opening validates the header and the node table.\n"
        "\n"
        "  --verify      read every payload, check its checksum and contents;\n"
        "                exit 1 naming each corrupt node\n"
        "  --json        print one JSON object on stdout: nodes, blocks, depths,\n"
        "                block_depth (depth of the blocks' hlod_0 nodes), groups,\n"
        "                nodes_per_depth, tris_per_depth, bytes, payload_bytes,\n"
        "                texture_bytes, error_min, error_max, textures_bc1,\n"
        "                textures_jpeg, textures_raw, texture_psnr_min (dB, the\n"
        "                lowest the builder measured; 0: none; null: a remote\n"
        "                store without --verify), verified and more\n"
        "  -h, --help    show this help\n"
        "\n"
        "Exit status: 0 valid, 1 unreadable or corrupt, 2 bad command line.\n");
}

typedef struct depth_stats {
    uint64_t nodes, tris, tex_tris, payload_bytes, texture_bytes;
    double error_min, error_max;
} depth_stats;

typedef struct stats {
    depth_stats *depth;         /* header depth_count entries */
    uint64_t tris, leaves, leaf_tris, leaf_payload_bytes, payload_bytes, texture_bytes;
    double error_min, error_max;
    /* textures by codec, from the packed headers (scanned: 0 when not) */
    int scanned;
    uint64_t tex_bc, tex_jpeg, tex_raw;
    double tex_db_min;          /* lowest measured PSNR; 0: none measured */
} stats;

/* Reads the packed header of every textured node: how its texture is
 * stored and the PSNR the builder measured.  0, or 1 on a read error
 * (logged by the reader, naming the node). */
static int scan_textures(const hlod_store *s, stats *st)
{
    const hlod_store_header *h = hlod_store_get_header(s);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    st->scanned = 1;
    if (h->payload_codec != HLOD_STORE_CODEC_PACKED)
        return 0;
    for (uint32_t i = 0; i < h->node_count; i++) {
        if (!(nodes[i].flags & HLOD_NODE_TEXTURE))
            continue;
        hlod_store_read rd;
        int complete = 0;
        hlod_store_packed_header ph;
        if (hlod_store_read_begin(s, i, &rd) != HLOD_OK ||
            hlod_store_read_step(&rd, sizeof ph, &complete) != HLOD_OK) {
            hlod_store_read_cancel(&rd);
            return 1;
        }
        memcpy(&ph, rd.buf, sizeof ph);   /* payloads are at least this long */
        hlod_store_read_cancel(&rd);
        if (ph.tex_codec == HLOD_TEX_BC)
            st->tex_bc++;
        else if (ph.tex_codec == HLOD_TEX_JPEG)
            st->tex_jpeg++;
        else
            st->tex_raw++;
        if (ph.tex_db > 0 && (st->tex_db_min == 0 || ph.tex_db < st->tex_db_min))
            st->tex_db_min = ph.tex_db;
    }
    return 0;
}

static int gather(const hlod_store *s, stats *st)
{
    const hlod_store_header *h = hlod_store_get_header(s);
    const hlod_store_node *nodes = hlod_store_nodes(s);
    memset(st, 0, sizeof *st);
    st->depth = calloc(h->depth_count, sizeof *st->depth);
    if (!st->depth)
        return 0;
    st->error_min = INFINITY;
    st->error_max = -INFINITY;
    for (uint32_t d = 0; d < h->depth_count; d++) {
        st->depth[d].error_min = INFINITY;
        st->depth[d].error_max = -INFINITY;
    }
    for (uint32_t i = 0; i < h->node_count; i++) {
        const hlod_store_node *n = &nodes[i];
        depth_stats *d = &st->depth[n->depth];     /* validated < depth_count */
        uint64_t tex = (uint64_t)n->tex_width * n->tex_height * n->tex_channels;
        d->nodes++;
        d->tris += n->tri_count;
        d->tex_tris += n->tex_tri_count;
        d->payload_bytes += n->payload_size;
        d->texture_bytes += tex;
        d->error_min = fmin(d->error_min, n->error);
        d->error_max = fmax(d->error_max, n->error);
        st->tris += n->tri_count;
        st->payload_bytes += n->payload_size;
        st->texture_bytes += tex;
        st->error_min = fmin(st->error_min, n->error);
        st->error_max = fmax(st->error_max, n->error);
        if (hlod_store_first_child(nodes, i) == hlod_store_child_end(nodes, i)) {
            st->leaves++;
            st->leaf_tris += n->tri_count;
            st->leaf_payload_bytes += n->payload_size;
        }
    }
    return 1;
}

/* Reads every payload; returns the number of bad nodes (each reported by
 * the reader's logger, which names the node and the problem). */
static uint32_t verify(const hlod_store *s, hlod_cli_progress *bar, int *oom)
{
    const hlod_store_header *h = hlod_store_get_header(s);
    uint32_t bad = 0;
    double done = 0;
    /* batches: a store read from a URL reads each with parallel requests */
    enum { BATCH = 32 };
    hlod_store_payload p[BATCH];
    hlod_result res[BATCH];
    for (uint32_t i = 0; i < h->node_count; i += BATCH) {
        uint32_t n = h->node_count - i < BATCH ? h->node_count - i : BATCH;
        if (hlod_store_read_nodes(s, i, n, 65536, p, res) != HLOD_OK) {
            *oom = 1;
            return bad + 1;
        }
        for (uint32_t k = 0; k < n; k++) {
            if (res[k] == HLOD_ERR_NOMEM)
                *oom = 1;
            if (res[k] != HLOD_OK)
                bad++;
            hlod_store_payload_free(&p[k]);
            done += (double)hlod_store_nodes(s)[i + k].payload_size;
        }
        if (*oom)
            return bad;
        hlod_cli_progress_fn(bar, done, (double)h->payload_bytes);
    }
    hlod_cli_progress_clear(bar);
    return bad;
}

static const char *method_name(uint32_t m)
{
    return m == HLOD_STORE_METHOD_CUTPLANE ? "cutplane"
         : m == HLOD_STORE_METHOD_METIS    ? "metis"
         : m == HLOD_STORE_METHOD_SAMPLETREE ? "sampletree"
         : m == HLOD_STORE_METHOD_CUBES    ? "cubes"
                                           : "other";
}

static void json_double(FILE *fp, double v)
{
    if (isfinite(v))
        fprintf(fp, "%.17g", v);
    else
        fputs("null", fp);
}

/* The per-depth arrays make this more than hlod_json's flat objects. */
/* Whether the nodes carry colour cubes (a cubes store's, or a build's
 * --far-cubes): the first node's extras record says it for all. */
static int carries_cubes(const hlod_store *s)
{
    const hlod_store_extra *x = hlod_store_extras(s);
    return x && hlod_store_get_header(s)->node_count && (x[0].flags & HLOD_EXTRA_CUBE);
}

static int print_json(FILE *fp, const char *file, const hlod_store *s, const stats *st,
                      int verified)
{
    const hlod_store_header *h = hlod_store_get_header(s);
    fputs("{\"file\":\"", fp);
    for (const char *c = file; *c; c++) {
        if (*c == '"' || *c == '\\')
            fprintf(fp, "\\%c", *c);
        else if ((unsigned char)*c < 0x20)
            fprintf(fp, "\\u%04x", (unsigned char)*c);
        else
            fputc(*c, fp);
    }
    fprintf(fp, "\",\"version\":%u,\"nodes\":%u,\"blocks\":%u,\"depths\":%u,\"block_depth\":%u"
            ",\"groups\":%u,\"roots\":%u,\"top_nodes\":%u", h->version, h->node_count,
            h->block_count, h->depth_count, h->block_depth, h->top_count - h->block_count,
            h->root_count, h->top_count);
    fputs(",\"nodes_per_depth\":[", fp);
    for (uint32_t d = 0; d < h->depth_count; d++)
        fprintf(fp, "%s%llu", d ? "," : "", (unsigned long long)st->depth[d].nodes);
    fputs("],\"tris_per_depth\":[", fp);
    for (uint32_t d = 0; d < h->depth_count; d++)
        fprintf(fp, "%s%llu", d ? "," : "", (unsigned long long)st->depth[d].tris);
    fputs("],\"error_max_per_depth\":[", fp);
    for (uint32_t d = 0; d < h->depth_count; d++) {
        fputs(d ? "," : "", fp);
        json_double(fp, st->depth[d].error_max);
    }
    fprintf(fp, "],\"tris_total\":%llu,\"leaves\":%llu,\"tris_leaf\":%llu",
            (unsigned long long)st->tris, (unsigned long long)st->leaves,
            (unsigned long long)st->leaf_tris);
    fprintf(fp, ",\"bytes\":%llu,\"payload_bytes\":%llu,\"leaf_payload_bytes\":%llu"
            ",\"texture_bytes\":%llu", (unsigned long long)h->file_size,
            (unsigned long long)st->payload_bytes, (unsigned long long)st->leaf_payload_bytes,
            (unsigned long long)st->texture_bytes);
    fprintf(fp, ",\"codec\":\"%s\",\"memory_bytes\":%llu,\"quant_step\":",
            h->payload_codec == HLOD_STORE_CODEC_PACKED ? "packed" : "raw",
            (unsigned long long)hlod_store_memory_bytes(s));
    json_double(fp, h->quant_step);
    fputs(",\"error_min\":", fp);
    json_double(fp, st->error_min);
    fputs(",\"error_max\":", fp);
    json_double(fp, st->error_max);
    fprintf(fp, ",\"textured\":%s,\"refine\":\"%s\",\"method\":\"%s\",\"desired_tris\":%llu,"
            "\"level_factor\":",
            (h->flags & HLOD_STORE_TEXTURED) ? "true" : "false",
            (h->flags & HLOD_STORE_ADDITIVE) ? "add" : "replace", method_name(h->build.method),
            (unsigned long long)h->build.desired_tris);
    json_double(fp, h->build.level_factor);
    fprintf(fp, ",\"voxel_tris\":%llu,\"leaf_tris\":%llu,\"node_tris\":%llu,\"c_tex\":",
            (unsigned long long)h->build.voxel_tris, (unsigned long long)h->build.leaf_tris,
            (unsigned long long)h->build.node_tris);
    json_double(fp, h->build.c_tex);
    fprintf(fp, ",\"cone_split\":%s,\"cubes\":%s",
            (h->build.flags & HLOD_BUILD_CONE_SPLIT) ? "true" : "false",
            carries_cubes(s) ? "true" : "false");
    fputs(",\"bbox_min\":[", fp);
    for (int k = 0; k < 3; k++) {
        fputs(k ? "," : "", fp);
        json_double(fp, h->bbox_min[k]);
    }
    fputs("],\"bbox_max\":[", fp);
    for (int k = 0; k < 3; k++) {
        fputs(k ? "," : "", fp);
        json_double(fp, h->bbox_max[k]);
    }
    if (st->scanned)
        fprintf(fp, "],\"textures_bc1\":%llu,\"textures_jpeg\":%llu,\"textures_raw\":%llu"
                ",\"texture_psnr_min\":%.4f", (unsigned long long)st->tex_bc,
                (unsigned long long)st->tex_jpeg, (unsigned long long)st->tex_raw, st->tex_db_min);
    else
        fputs("],\"textures_bc1\":null,\"textures_jpeg\":null,\"textures_raw\":null"
              ",\"texture_psnr_min\":null", fp);
    fprintf(fp, ",\"verified\":%s}\n", verified ? "true" : "false");
    return ferror(fp) || fflush(fp) != 0 ? -1 : 0;
}

static void print_table(FILE *fp, const char *file, const hlod_store *s, const stats *st)
{
    const hlod_store_header *h = hlod_store_get_header(s);
    const hlod_store_build_info *b = &h->build;
    fprintf(fp, "%s: hlod store version %u, %llu bytes, %s, %s\n", file, h->version,
            (unsigned long long)h->file_size,
            (h->flags & HLOD_STORE_TEXTURED) ? "textured" : "untextured",
            (h->flags & HLOD_STORE_ADDITIVE) ? "refines additively" : "refines by replacement");
    if (b->method == HLOD_STORE_METHOD_SAMPLETREE)
        fprintf(fp, "build: method sampletree, c %g, leaf cells of at most %llu triangles, "
                "c_tex %g\n", b->level_factor, (unsigned long long)b->leaf_tris, b->c_tex);
    else if (b->method == HLOD_STORE_METHOD_CUBES)
        fprintf(fp, "build: method cubes, leaf cells of at most %llu triangles, c_tex %g\n",
                (unsigned long long)b->leaf_tris, b->c_tex);
    else
        fprintf(fp, "build: method %s, C_desiredTri %llu, C_levelFactor %g, N_v %llu, N_l %llu, "
                "N_n %llu, c_tex %g%s%s\n", method_name(b->method),
                (unsigned long long)b->desired_tris, b->level_factor,
                (unsigned long long)b->voxel_tris, (unsigned long long)b->leaf_tris,
                (unsigned long long)b->node_tris, b->c_tex,
                (b->flags & HLOD_BUILD_CONE_SPLIT) ? ", cone split" : "",
                carries_cubes(s) ? ", far cubes" : "");
    fprintf(fp, "bbox: (%.17g, %.17g, %.17g) - (%.17g, %.17g, %.17g)\n", h->bbox_min[0],
            h->bbox_min[1], h->bbox_min[2], h->bbox_max[0], h->bbox_max[1], h->bbox_max[2]);
    fprintf(fp, "blocks %u at depth %u (%u group nodes above, %u roots), nodes %u, leaves %llu, "
            "depths %u, triangles %llu (leaves %llu)\n", h->block_count, h->block_depth,
            h->top_count - h->block_count, h->root_count, h->node_count,
            (unsigned long long)st->leaves, h->depth_count, (unsigned long long)st->tris,
            (unsigned long long)st->leaf_tris);
    fprintf(fp, "payload %llu bytes (leaves %llu), texture %llu bytes, error %.6g .. %.6g\n",
            (unsigned long long)st->payload_bytes, (unsigned long long)st->leaf_payload_bytes,
            (unsigned long long)st->texture_bytes, st->error_min, st->error_max);
    if (h->payload_codec == HLOD_STORE_CODEC_PACKED)
        fprintf(fp, "payloads packed: %llu bytes decoded (%.3fx on disk), position grid %.17g\n",
                (unsigned long long)hlod_store_memory_bytes(s),
                (double)st->payload_bytes / (double)hlod_store_memory_bytes(s), h->quant_step);
    else
        fprintf(fp, "payloads raw\n");
    if (st->scanned && st->tex_bc + st->tex_jpeg + st->tex_raw) {
        fprintf(fp, "textures: %llu block-coded (BC1/BC4 mips, zstd), %llu JPEG, %llu raw; ",
                (unsigned long long)st->tex_bc, (unsigned long long)st->tex_jpeg,
                (unsigned long long)st->tex_raw);
        if (st->tex_db_min > 0)
            fprintf(fp, "lowest PSNR against the source %.2f dB\n", st->tex_db_min);
        else
            fprintf(fp, "lowest PSNR not measured\n");
    }
    else if (!st->scanned && (h->flags & HLOD_STORE_TEXTURED))
        fprintf(fp, "textures: codecs not scanned (a remote store: --verify reads them)\n");
    fprintf(fp, "%5s %9s %12s %12s %14s %14s %12s %12s\n", "depth", "nodes", "tris",
            "tex_tris", "payload_bytes", "texture_bytes", "error_min", "error_max");
    for (uint32_t d = 0; d < h->depth_count; d++) {
        const depth_stats *ds = &st->depth[d];
        fprintf(fp, "%5u %9llu %12llu %12llu %14llu %14llu %12.6g %12.6g\n", d,
                (unsigned long long)ds->nodes, (unsigned long long)ds->tris,
                (unsigned long long)ds->tex_tris, (unsigned long long)ds->payload_bytes,
                (unsigned long long)ds->texture_bytes, ds->error_min, ds->error_max);
    }
}

int main(int argc, char **argv)
{
    const char *file = NULL;
    int json = 0, check = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(a, "--json")) {
            json = 1;
        } else if (!strcmp(a, "--verify")) {
            check = 1;
        } else if (a[0] == '-' && a[1] != 0) {
            hlod_cli_error(PROG, "unknown option '%s'", a);
            fprintf(stderr, "try '%s --help'\n", PROG);
            return 2;
        } else if (!file) {
            file = a;
        } else {
            hlod_cli_error(PROG, "unexpected argument '%s' (one store at a time)", a);
            fprintf(stderr, "try '%s --help'\n", PROG);
            return 2;
        }
    }
    if (!file) {
        hlod_cli_error(PROG, "no store file given");
        fprintf(stderr, "try '%s --help'\n", PROG);
        return 2;
    }

    hlod_cli_progress bar;
    hlod_cli_progress_begin(&bar, "B", 1);
    hlod_cli_log log_state = {PROG, HLOD_LOG_WARN, &bar};
    hlod_logger lg = hlod_cli_logger(&log_state);

    hlod_store *s = NULL;
    hlod_result r = hlod_store_open(file, &lg, &s);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot open store: %s", file, hlod_result_str(r));
        return 1;
    }
    int status = 1;
    stats st;
    if (!gather(s, &st)) {
        hlod_cli_error(PROG, "out of memory");
        goto done;
    }
    if (check) {
        int oom = 0;
        uint32_t bad = verify(s, &bar, &oom);
        if (oom) {
            hlod_cli_error(PROG, "%s: out of memory while verifying", file);
            goto done;
        }
        if (bad) {
            hlod_cli_error(PROG, "%s: %u of %u payloads are corrupt", file, bad,
                           hlod_store_node_count(s));
            goto done;
        }
    }
    if ((check || !hlod_store_is_remote(s)) && scan_textures(s, &st) != 0) {
        hlod_cli_error(PROG, "%s: cannot read the payload headers", file);
        goto done;
    }
    if (json) {
        if (print_json(stdout, file, s, &st, check) != 0) {
            hlod_cli_error(PROG, "cannot write the JSON record to standard output");
            goto done;
        }
    } else {
        print_table(stdout, file, s, &st);
        if (check)
            printf("verified: all %u payloads read, checksums and contents valid\n",
                   hlod_store_node_count(s));
        if (fflush(stdout) != 0) {
            hlod_cli_error(PROG, "cannot write to standard output");
            goto done;
        }
    }
    status = 0;
done:
    free(st.depth);
    hlod_store_close(s);
    return status;
}
