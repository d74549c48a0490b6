/*
 * fuzz_lumi.c - libFuzzer harness for the Grid-Lumigraph repository's
 * parsers (engine/common/lumigraph_repo.c): the index (repo.hlg) and a
 * view (views/X/Y_Z_D.hlv).
 *
 * The first byte picks the parser, by its value mod 3: 0, the index; 1, a
 * view asked for as view 5 of a fixed index (G = 2, 16 x 16 colour, 8 x 8
 * depth, the shape of the committed seeds); 2, a request's query string
 * (hlod-lumigraph-serve's /answer).  Besides "no crash, leak or hang", the
 * oracles:
 *   - an index that parses encodes back to the same bytes;
 *   - a view that parses has its buffers, and a refused one has none;
 *   - a request that parses is formatted and parses back to the same
 *     numbers, bit for bit, and its candidates are 48 distinct views at
 *     most, each a view of the grid.
 * A broken promise aborts, which libFuzzer reports as a crash.
 */
#include "hlod/lumigraph.h"

#include <stdlib.h>
#include <string.h>

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    const uint8_t *b = data + 1;
    size_t n = size - 1;
    if (data[0] % 3 == 2) {
        hlod_lumi_request q, back;
        if (!hlod_lumi_request_parse((const char *)b, n, &q))
            return 0;
        char text[600];
        size_t tn = hlod_lumi_request_format(&q, text, sizeof text);
        if (!tn || !hlod_lumi_request_parse(text, tn, &back) ||
            memcmp(q.eye, back.eye, sizeof q.eye) || memcmp(q.dir, back.dir, sizeof q.dir) ||
            (q.have & ((1ull << 48) - 1)) != back.have)
            abort();
        hlod_lumi_index ix;
        const double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
        if (hlod_lumi_index_init(&ix, 3, 16, 8, 85, lo, hi, 0.01, 10, 1) != HLOD_OK)
            abort();
        uint32_t ids[HLOD_LUMI_CANDIDATES], bits[HLOD_LUMI_CANDIDATES];
        uint32_t nc = hlod_lumi_candidates(&ix, q.eye, q.dir, ids, bits);
        if (nc > HLOD_LUMI_CANDIDATES)
            abort();
        for (uint32_t i = 0; i < nc; i++) {
            if (ids[i] >= ix.views || bits[i] >= HLOD_LUMI_CANDIDATES)
                abort();
            for (uint32_t j = 0; j < i; j++)
                if (ids[i] == ids[j])
                    abort();
        }
        hlod_lumi_index_free(&ix);
        return 0;
    }
    if (data[0] % 3 == 0) {
        hlod_lumi_index ix;
        if (hlod_lumi_index_decode(b, n, "fuzz", NULL, &ix) != HLOD_OK) {
            if (ix.state)
                abort(); /* left empty on failure */
            return 0;
        }
        uint8_t *out;
        size_t on;
        if (hlod_lumi_index_encode(&ix, &out, &on) != HLOD_OK || on != n || memcmp(out, b, n))
            abort();
        free(out);
        hlod_lumi_index_free(&ix);
        return 0;
    }
    hlod_lumi_index ix;
    const double lo[3] = {0, 0, 0}, hi[3] = {1, 1, 1};
    if (hlod_lumi_index_init(&ix, 2, 16, 8, 85, lo, hi, 0.01, 10, 1) != HLOD_OK)
        abort();
    hlod_lumi_view v;
    hlod_result r = hlod_lumi_view_decode(&ix, 5, b, n, "fuzz", NULL, &v);
    if (r == HLOD_OK ? !v.rgb || !v.depth || v.size != 16 : v.rgb || v.depth)
        abort();
    hlod_lumi_view_free(&v);
    hlod_lumi_index_free(&ix);
    return 0;
}
