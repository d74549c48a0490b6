/*
 * fuzz_store.c - libFuzzer harness for the store reader (engine/common/
 * store_read.c): hlod_store_open, then every node payload through
 * read_begin / read_step / read_finish, and read_finish_as for each way a
 * block-coded texture can come out (texels, the texel chain, the blocks).
 *
 * The reader opens files by path, so each input is written to one memfd
 * (no disk) and opened as /proc/self/fd/N.  Every input is tried twice:
 *   1. as is: exercises the header checks up to the checksum;
 *   2. "repaired": file_size set to the input's length and every checksum
 *      the layout lets us find (each payload the table points at inside
 *      the file, the node table, the header) recomputed.  Without this the
 *      fuzzer would almost never get past XXH3 into hlod_store_validate and
 *      the payload parser, which is where counts, offsets and indices from
 *      the file are trusted or not.
 * Must never crash, leak, hang or read out of bounds; any result code is
 * fine.  Opened stores must satisfy what the header promises callers.
 */
#define _GNU_SOURCE     /* memfd_create */
#include "hlod/store.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <unistd.h>

static int g_fd = -1;
static char g_path[64];

static void put_file(const uint8_t *data, size_t size)
{
    if (g_fd < 0) {
        g_fd = memfd_create("fuzz_store", 0);
        if (g_fd < 0) {
            perror("memfd_create");
            abort();
        }
        snprintf(g_path, sizeof g_path, "/proc/self/fd/%d", g_fd);
    }
    if (ftruncate(g_fd, 0) != 0 || (size && pwrite(g_fd, data, size, 0) != (ssize_t)size)) {
        perror("memfd write");
        abort();
    }
}

/* Opens the memfd as a store and reads every payload in steps of `step`. */
static void open_and_read(size_t step)
{
    hlod_store *s = NULL;
    if (hlod_store_open(g_path, NULL, &s) != HLOD_OK) {
        if (s)
            abort();    /* *out must be NULL on failure */
        return;
    }
    const hlod_store_header *h = hlod_store_get_header(s);
    uint32_t n = hlod_store_node_count(s);
    if (n == 0 || n != h->node_count || hlod_store_root_count(s) > n)
        abort();
    const hlod_store_node *nodes = hlod_store_nodes(s);
    for (uint32_t i = 0; i < n; i++) {
        hlod_store_payload p;
        if (hlod_store_read_node(s, i, step, &p) != HLOD_OK)
            continue;
        /* touch what the reader promised: indices in range, sections sized */
        if (p.vertex_count != nodes[i].vertex_count || p.index_count != 3 * nodes[i].tri_count)
            abort();
        uint64_t sum = 0;
        for (uint32_t k = 0; k < p.index_count; k++) {
            if (p.indices[k] >= p.vertex_count)
                abort();
            sum += p.positions[3 * p.indices[k]] != 0;
        }
        if (p.pixels)
            sum += p.pixels[(size_t)p.tex_width * p.tex_height * p.tex_channels - 1];
        if (p.colors)
            sum += p.colors[4 * (size_t)p.vertex_count - 1];
        (void)sum;
        hlod_store_payload_free(&p);
    }
    /* the texture chain and the blocks, as the loader asks for them */
    for (uint32_t i = 0; i < n; i++)
        for (int mode = HLOD_TEXOUT_CHAIN; mode <= HLOD_TEXOUT_BLOCKS; mode++) {
            hlod_store_read rd;
            hlod_store_payload p;
            int complete = 0;
            if (hlod_store_read_begin(s, i, &rd) != HLOD_OK)
                continue;
            while (!complete)
                if (hlod_store_read_step(&rd, step, &complete) != HLOD_OK)
                    break;
            if (!complete) {
                hlod_store_read_cancel(&rd);
                continue;
            }
            if (hlod_store_read_finish_as(&rd, mode, &p) != HLOD_OK)
                continue;
            uint64_t sum = 0;
            if (p.pixels)   /* the texture is there, as promised */
                sum += p.pixels[0];
            (void)sum;
            hlod_store_payload_free(&p);
        }
    /* an out-of-range node is refused */
    hlod_store_read rd;
    if (hlod_store_read_begin(s, n, &rd) != HLOD_ERR_INVALID_ARG)
        abort();
    hlod_store_close(s);
}

/* Rewrites file_size and every checksum it can locate (see the top). */
static void repair(uint8_t *b, size_t size)
{
    hlod_store_header h;
    memcpy(&h, b, sizeof h);
    h.file_size = size;
    uint64_t t0 = h.node_table_offset, tsize = h.node_table_size;
    if (t0 <= size && tsize <= size - t0 && tsize >= sizeof(hlod_store_node) &&
        tsize % sizeof(hlod_store_node) == 0) {
        /* every record but the sentinel, which must stay all zero */
        for (uint64_t off = t0; off + sizeof(hlod_store_node) < t0 + tsize;
             off += sizeof(hlod_store_node)) {
            hlod_store_node nd;
            memcpy(&nd, b + off, sizeof nd);
            if (nd.payload_size && nd.payload_offset <= size &&
                nd.payload_size <= size - nd.payload_offset) {
                nd.payload_hash = hlod_store_hash(b + nd.payload_offset, nd.payload_size);
                memcpy(b + off, &nd, sizeof nd);
            }
        }
        h.node_table_hash = hlod_store_hash(b + t0, tsize);
    }
    h.header_hash = hlod_store_hash(&h, HLOD_STORE_HEADER_HASHED);
    memcpy(b, &h, sizeof h);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* the last byte picks the read step (8 B .. 64 KiB): resumable reads
     * must give the same result for any step */
    size_t step = (size_t)8 << (size ? data[size - 1] % 14 : 0);
    put_file(data, size);
    open_and_read(step);
    if (size < sizeof(hlod_store_header))
        return 0;
    uint8_t *copy = malloc(size);
    if (!copy)
        return 0;
    memcpy(copy, data, size);
    repair(copy, size);
    put_file(copy, size);
    free(copy);
    open_and_read(step);
    return 0;
}
