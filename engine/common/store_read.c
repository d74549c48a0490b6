/*
 * store_read.c - the store's validating reader (format: hlod/store.h).
 *
 * Nothing read from the file is trusted before it is checked: open reads the
 * header, checks magic, byte order, version, record sizes and checksum, and
 * that the file is exactly as long as the header says (so every truncation
 * is caught here, before any payload read); then it reads the node table
 * (whose size was bounded by the file size first, so a corrupt count cannot
 * make us allocate more than the file), checks its checksum and every rule
 * of hlod_store_validate.  A payload read allocates exactly the validated
 * payload_size, hashes as it reads, and at finish checks the hash and
 * parses with every count compared against the node table, so a payload
 * whose bytes hash right but lie still cannot index past its arrays.
 *
 * The store is immutable after open and payload reads use pread on its file
 * descriptor, so any thread may read any node at any time; each read keeps
 * its own progress in its hlod_store_read.
 *
 * Sources: a path is a local file (pread); an http:// or https:// URL is
 * read with range requests (store_http.c): the header and the node table
 * once at open, validated exactly as a file's (the file size is
 * Content-Range's total), then each payload step one range request, or,
 * for the loader, parallel transfers (hlod_store_fetch_*) that append to
 * the same hlod_store_read as a step does.
 */
#define XXH_INLINE_ALL
#include <xxhash.h>

#include "hlod/store.h"

#include "atomic_file.h"
#include "payload_codec.h"
#include "store_http.h"
#include "store_node.h"

#include <assert.h>
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

/* The structs are the bytes on disk: no compiler padding, fixed offsets. */
_Static_assert(sizeof(hlod_store_build_info) == 56, "build info layout");
_Static_assert(sizeof(hlod_store_header) == 256, "header layout");
_Static_assert(offsetof(hlod_store_header, build) == 136, "header layout");
_Static_assert(offsetof(hlod_store_header, header_hash) == HLOD_STORE_HEADER_HASHED,
               "header layout");
_Static_assert(sizeof(hlod_store_node) == 192, "node layout");
_Static_assert(offsetof(hlod_store_node, avg_normal) == 144, "node layout");
_Static_assert(offsetof(hlod_store_node, payload_offset) == 160, "node layout");
_Static_assert(sizeof(hlod_store_payload_header) == 64, "payload header layout");
_Static_assert(sizeof(float) == 4 && sizeof(double) == 8, "IEEE 754 sizes");

struct hlod_store {
    int fd;                     /* the source: a local file (fd >= 0) ... */
    hlod_http *http;            /* ... or an http(s) URL */
    char *path;
    hlod_logger logger;         /* copy; func may be NULL */
    hlod_store_header header;
    hlod_store_node *nodes;     /* node_count + 1 */
    hlod_store_extra *extras;   /* node_count, or NULL */
    hlod_store_pread_fn pread_fn; /* test hook; NULL: pread */
    void *pread_user;
    struct store_cache *cache;  /* a URL's local payload cache (HLOD_CACHE_DIR), or NULL */
};

static void cache_open(hlod_store *s);
static void cache_close(struct store_cache *c);

/* ---- shared helpers ---- */

uint64_t hlod_store_hash(const void *data, size_t size)
{
    return (uint64_t)XXH3_64bits(data, size);
}

static int finite3d(const double *v)
{
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

static int is_zero(const void *p, size_t n)
{
    const uint8_t *b = p;
    for (size_t i = 0; i < n; i++)
        if (b[i])
            return 0;
    return 1;
}

/* ---- table validation ---- */

typedef struct extent {
    uint64_t begin, end;
    uint32_t node;
} extent;

static int cmp_extent(const void *a, const void *b)
{
    const extent *x = a, *y = b;
    return x->begin < y->begin ? -1 : x->begin > y->begin ? 1 : 0;
}

#define BAD(code, ...)                                  \
    do {                                                \
        hlod_logf(lg, HLOD_LOG_ERROR, __VA_ARGS__);     \
        return (code);                                  \
    } while (0)

/* One node's own fields (everything but the links to other nodes). */
static hlod_result check_node_fields(const hlod_store_header *h, const hlod_store_node *n,
                                     uint32_t i, uint64_t file_size, const char *name,
                                     const hlod_logger *lg)
{
    if ((n->render_flags & ~HLOD_RENDER_ALL_FLAGS) || n->reserved1)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: reserved fields are not zero", name, i);
    if (n->tri_count == 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: no triangles", name, i);
    if (n->tri_count > UINT32_MAX / 3)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: %u triangles is too many", name, i, n->tri_count);
    if ((uint64_t)n->tex_tri_count + n->untex_tri_count != n->tri_count)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: %u textured + %u untextured triangles != %u", name, i,
            n->tex_tri_count, n->untex_tri_count, n->tri_count);
    if (!(n->flags & HLOD_NODE_TEXTURE) && n->tex_tri_count)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: textured triangles but no texture", name, i);
    if (n->vertex_count == 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: no vertices", name, i);
    uint64_t want = hlod_store_payload_size(n->flags, n->vertex_count, 3 * n->tri_count,
                                            n->tex_width, n->tex_height, n->tex_channels);
    if (want == 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: impossible flags %#x or texture %ux%ux%u", name, i,
            n->flags, n->tex_width, n->tex_height, n->tex_channels);
    if (h->payload_codec == HLOD_STORE_CODEC_RAW && n->payload_size != want)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: payload is %llu bytes, its counts need %llu", name,
            i, (unsigned long long)n->payload_size, (unsigned long long)want);
    if (h->payload_codec == HLOD_STORE_CODEC_PACKED &&
        n->payload_size < sizeof(hlod_store_packed_header))
        BAD(HLOD_ERR_FORMAT, "%s: node %u: packed payload of %llu bytes is shorter than its "
            "header", name, i, (unsigned long long)n->payload_size);
    if (n->payload_offset % h->payload_align)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: payload offset %llu is not a multiple of %u", name,
            i, (unsigned long long)n->payload_offset, h->payload_align);
    if (n->payload_offset < h->header_size || n->payload_size > file_size ||
        n->payload_offset > file_size - n->payload_size)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: payload [%llu, +%llu) lies outside the file's "
            "payload area [%u, %llu)", name, i, (unsigned long long)n->payload_offset,
            (unsigned long long)n->payload_size, h->header_size,
            (unsigned long long)file_size);
    uint64_t t0 = h->node_table_offset, t1 = t0 + h->node_table_size;
    if (n->payload_offset < t1 && n->payload_offset + n->payload_size > t0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: payload [%llu, +%llu) overlaps the node table",
            name, i, (unsigned long long)n->payload_offset, (unsigned long long)n->payload_size);

    if (!finite3d(n->bbox_min) || !finite3d(n->bbox_max) || !finite3d(n->origin) ||
        !isfinite(n->cost) || !isfinite(n->static_benefit) || !isfinite(n->error) ||
        !isfinite(n->avg_normal[0]) || !isfinite(n->avg_normal[1]) ||
        !isfinite(n->avg_normal[2]))
        BAD(HLOD_ERR_NAN, "%s: node %u: a non-finite number in box, origin, cost, benefit, "
            "error or normal", name, i);
    for (int k = 0; k < 3; k++)
        if (n->bbox_min[k] > n->bbox_max[k])
            BAD(HLOD_ERR_FORMAT, "%s: node %u: bounding box min > max on axis %d", name, i, k);
    if (n->cost < 0 || n->static_benefit < 0 || n->error < 0)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: negative cost, benefit or error", name, i);
    double cost = hlod_store_cost(n->tex_tri_count, n->untex_tri_count, h->build.c_tex);
    if (fabs(n->cost - cost) > 1e-9 * (cost > 1 ? cost : 1))
        BAD(HLOD_ERR_FORMAT, "%s: node %u: cost %.17g is not eq. 1's %.17g (c_tex %g)", name, i,
            n->cost, cost, h->build.c_tex);
    double len2 = (double)n->avg_normal[0] * n->avg_normal[0] +
                  (double)n->avg_normal[1] * n->avg_normal[1] +
                  (double)n->avg_normal[2] * n->avg_normal[2];
    if (len2 != 0 && fabs(len2 - 1) > 1e-4)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: average normal is neither unit nor zero", name, i);
    return HLOD_OK;
}

hlod_result hlod_store_validate(const hlod_store_header *h, const hlod_store_node *nodes,
                                uint64_t file_size, const char *name, const hlod_logger *lg)
{
    assert(h && nodes);
    if (!name)
        name = "store";
    const uint32_t n = h->node_count, roots = h->root_count;
    if (n == 0 || roots == 0 || roots > n)
        BAD(HLOD_ERR_FORMAT, "%s: %u roots for %u nodes", name, roots, n);
    if (h->payload_align < HLOD_STORE_MIN_ALIGN || h->payload_align > HLOD_STORE_MAX_ALIGN ||
        (h->payload_align & (h->payload_align - 1)))
        BAD(HLOD_ERR_FORMAT, "%s: payload alignment %u is not a power of two in [%u, %u]", name,
            h->payload_align, HLOD_STORE_MIN_ALIGN, HLOD_STORE_MAX_ALIGN);
    if (!(h->build.c_tex >= 0 && h->build.c_tex <= 1))
        BAD(HLOD_ERR_FORMAT, "%s: c_tex %g is not in [0, 1]", name, h->build.c_tex);

    /* Sentinel: first_child = n, nothing else. */
    hlod_store_node sentinel;
    memset(&sentinel, 0, sizeof sentinel);
    sentinel.first_child = n;
    if (memcmp(&nodes[n], &sentinel, sizeof sentinel) != 0)
        BAD(HLOD_ERR_FORMAT, "%s: the sentinel node %u is not {first_child = %u, zeros}", name,
            n, n);
    if (nodes[0].first_child != roots)
        BAD(HLOD_ERR_FORMAT, "%s: node 0: children start at %u, not after the %u roots", name,
            nodes[0].first_child, roots);
    const uint32_t bdepth = h->block_depth, top = h->top_count, blocks = h->block_count;
    if (blocks == 0 || top > n || blocks > top || (bdepth == 0 && (blocks != roots || top != roots)))
        BAD(HLOD_ERR_FORMAT, "%s: %u blocks at depth %u, %u top nodes, %u roots for %u nodes", name,
            blocks, bdepth, top, roots, n);
    const uint32_t first_block = top - blocks;

    uint64_t payload_bytes = 0;
    uint32_t max_depth = 0;
    int textured = 0;
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t i = 0; i < n; i++) {
        const hlod_store_node *nd = &nodes[i];
        hlod_result r = check_node_fields(h, nd, i, file_size, name, lg);
        if (r != HLOD_OK)
            return r;
        uint32_t c0 = nd->first_child, c1 = nodes[i + 1].first_child;
        /* Ranges tile [roots, n) in order: that makes each non-root the
         * child of exactly one earlier node. */
        if (c0 > c1 || c1 > n || c0 <= i)
            BAD(HLOD_ERR_FORMAT, "%s: node %u: children [%u, %u) are not a range after it "
                "inside the %u nodes", name, i, c0, c1, n);
        if (i < roots && (nd->parent != HLOD_STORE_NO_PARENT || nd->depth != 0))
            BAD(HLOD_ERR_FORMAT, "%s: root %u: parent %u, depth %u (want none, 0)", name, i,
                nd->parent, nd->depth);
        /* depth is monotone (breadth-first, checked through the children),
         * so the top nodes are those at depth <= block_depth exactly when
         * the last top node and the first other one say so */
        int is_block = i >= first_block && i < top, is_group = i < first_block;
        if ((i < top) != (nd->depth <= bdepth) || is_block != (nd->depth == bdepth))
            BAD(HLOD_ERR_FORMAT, "%s: node %u at depth %u lies %s the %u top nodes (blocks at "
                "depth %u are nodes [%u, %u))", name, i, nd->depth, i < top ? "inside" : "after",
                top, bdepth, first_block, top);
        uint32_t want_block = is_group ? HLOD_STORE_NO_BLOCK
                              : is_block ? i - first_block
                                         : nodes[nd->parent].block;
        if (nd->block != want_block)
            BAD(HLOD_ERR_FORMAT, "%s: node %u: block %u, want %u (%s)", name, i, nd->block,
                want_block, is_group ? "a group node" : is_block ? "block hlod_0 nodes in order"
                                                                  : "its parent's");
        if (is_group && c0 == c1)
            BAD(HLOD_ERR_FORMAT, "%s: group node %u has no children", name, i);
        for (uint32_t c = c0; c < c1; c++) {
            const hlod_store_node *ch = &nodes[c];
            if (ch->parent != i || ch->depth != nd->depth + 1)
                BAD(HLOD_ERR_FORMAT, "%s: node %u: parent %u, depth %u disagree with its place "
                    "among node %u's children (depth %u)", name, c, ch->parent, ch->depth, i,
                    nd->depth);
            if (isfinite(ch->error) && ch->error > nd->error) /* NaN: caught below */
                BAD(HLOD_ERR_FORMAT, "%s: node %u: error %.17g exceeds its parent %u's %.17g",
                    name, c, ch->error, i, nd->error);
        }
        payload_bytes += nd->payload_size;
        if (nd->depth > max_depth)
            max_depth = nd->depth;
        if (nd->flags & HLOD_NODE_TEXTURE)
            textured = 1;
        for (int k = 0; k < 3; k++) {
            lo[k] = fmin(lo[k], nd->bbox_min[k]);
            hi[k] = fmax(hi[k], nd->bbox_max[k]);
        }
    }

    if (h->depth_count != max_depth + 1)
        BAD(HLOD_ERR_FORMAT, "%s: header says %u depths, the tree has %u", name, h->depth_count,
            max_depth + 1);
    if (h->payload_bytes != payload_bytes)
        BAD(HLOD_ERR_FORMAT, "%s: header says %llu payload bytes, the nodes hold %llu", name,
            (unsigned long long)h->payload_bytes, (unsigned long long)payload_bytes);
    if (((h->flags & HLOD_STORE_TEXTURED) != 0) != textured ||
        (h->flags & ~(HLOD_STORE_TEXTURED | HLOD_STORE_ADDITIVE)) ||
        ((h->flags & HLOD_STORE_ADDITIVE) != 0) != (h->build.method == HLOD_STORE_METHOD_SAMPLETREE ||
                                                 h->build.method == HLOD_STORE_METHOD_CUBES))
        BAD(HLOD_ERR_FORMAT, "%s: header flags %#x disagree with the nodes or the method", name,
            h->flags);
    for (int k = 0; k < 3; k++)
        if (h->bbox_min[k] != lo[k] || h->bbox_max[k] != hi[k])
            BAD(HLOD_ERR_FORMAT, "%s: header bounding box is not the union of the nodes'", name);

    /* Payloads must not overlap each other: sort by offset. */
    extent *ex = malloc((size_t)n * sizeof *ex);
    if (!ex)
        return HLOD_ERR_NOMEM;
    for (uint32_t i = 0; i < n; i++) {
        ex[i].begin = nodes[i].payload_offset;
        ex[i].end = nodes[i].payload_offset + nodes[i].payload_size;
        ex[i].node = i;
    }
    qsort(ex, n, sizeof *ex, cmp_extent);
    hlod_result r = HLOD_OK;
    for (uint32_t i = 1; i < n; i++)
        if (ex[i].begin < ex[i - 1].end) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u: payload overlaps node %u's", name,
                      ex[i].node, ex[i - 1].node);
            r = HLOD_ERR_FORMAT;
            break;
        }
    free(ex);
    return r;
}

/* ---- open ---- */

/* Reads exactly n bytes at off; 0 on success, else errno-style code (0 bytes
 * at the end of the file gives EIO-like -1). */
static int pread_all(int fd, void *buf, size_t n, uint64_t off)
{
    uint8_t *p = buf;
    while (n) {
        ssize_t k = pread(fd, p, n, (off_t)off);
        if (k < 0) {
            if (errno == EINTR)
                continue;
            return errno ? errno : EIO;
        }
        if (k == 0)
            return -1;
        p += k;
        n -= (size_t)k;
        off += (uint64_t)k;
    }
    return 0;
}

hlod_result hlod_store_check_header(const hlod_store_header *h, uint64_t file_size,
                                   const char *name, const hlod_logger *lg)
{
    if (memcmp(h->magic, HLOD_STORE_MAGIC, 8) != 0)
        BAD(HLOD_ERR_FORMAT, "%s: not an hlod store (bad magic)", name);
    if (h->endian != HLOD_STORE_ENDIAN) {
        if (h->endian == 0x04030201u)
            BAD(HLOD_ERR_UNSUPPORTED, "%s: store has the other byte order", name);
        BAD(HLOD_ERR_FORMAT, "%s: bad byte-order marker %#x", name, h->endian);
    }
    if (h->version < HLOD_STORE_VERSION_MIN || h->version > HLOD_STORE_VERSION)
        BAD(HLOD_ERR_VERSION, "%s: store format version %u, this program reads versions %u to "
            "%u; rebuild the store from its input with this hlod-build", name, h->version,
            HLOD_STORE_VERSION_MIN, HLOD_STORE_VERSION);
    if (h->header_size != sizeof(hlod_store_header) || h->node_size != sizeof(hlod_store_node))
        BAD(HLOD_ERR_FORMAT, "%s: header/node record sizes %u/%u, expected %zu/%zu", name,
            h->header_size, h->node_size, sizeof(hlod_store_header), sizeof(hlod_store_node));
    if (hlod_store_hash(h, HLOD_STORE_HEADER_HASHED) != h->header_hash)
        BAD(HLOD_ERR_CHECKSUM, "%s: header checksum mismatch", name);
    if (h->file_size != file_size)
        BAD(HLOD_ERR_FORMAT, "%s: file is %llu bytes, its header says %llu (truncated?)", name,
            (unsigned long long)file_size, (unsigned long long)h->file_size);
    if ((h->version < 4 && (h->extras_size || h->extras_offset)))
        BAD(HLOD_ERR_FORMAT, "%s: reserved header fields are not zero", name);
    if ((h->build.flags & ~HLOD_BUILD_KNOWN_FLAGS) || (h->version < 5 && h->build.flags) ||
        (h->build.flags && h->build.method != HLOD_STORE_METHOD_CUTPLANE))
        BAD(HLOD_ERR_FORMAT, "%s: unknown build flags 0x%x (method %u, version %u)", name,
            h->build.flags, h->build.method, h->version);
    if (h->payload_codec > HLOD_STORE_CODEC_PACKED ||
        (h->version < 3 && h->payload_codec != HLOD_STORE_CODEC_RAW))
        BAD(HLOD_ERR_FORMAT, "%s: unknown payload codec %u", name, h->payload_codec);
    if (h->payload_codec == HLOD_STORE_CODEC_RAW) {
        if (h->quant_step != 0 || h->quant_origin[0] != 0 || h->quant_origin[1] != 0 ||
            h->quant_origin[2] != 0)
            BAD(HLOD_ERR_FORMAT, "%s: a raw store with a position grid", name);
    } else {
        int e2 = 0;
        if (!(h->quant_step > 0) || !isfinite(h->quant_step) ||
            frexp(h->quant_step, &e2) != 0.5 || !finite3d(h->quant_origin))
            BAD(HLOD_ERR_FORMAT, "%s: position grid step %g is not a positive power of two, or "
                "its origin is not finite", name, h->quant_step);
    }
    if (h->node_count == 0 || h->node_count == UINT32_MAX)
        BAD(HLOD_ERR_FORMAT, "%s: %u nodes", name, h->node_count);
    uint64_t table = ((uint64_t)h->node_count + 1) * sizeof(hlod_store_node);
    if (h->node_table_size != table)
        BAD(HLOD_ERR_FORMAT, "%s: node table is %llu bytes, %u nodes need %llu", name,
            (unsigned long long)h->node_table_size, h->node_count, (unsigned long long)table);
    if (h->node_table_offset < h->header_size || table > file_size ||
        h->node_table_offset > file_size - table)
        BAD(HLOD_ERR_FORMAT, "%s: node table [%llu, +%llu) lies outside the file (%llu bytes)",
            name, (unsigned long long)h->node_table_offset, (unsigned long long)table,
            (unsigned long long)file_size);
    if (h->extras_offset || h->extras_size) {
        uint64_t ex = sizeof(hlod_store_extras_header) +
                      (uint64_t)h->node_count * sizeof(hlod_store_extra);
        if (h->extras_size != sizeof(hlod_store_extra))
            BAD(HLOD_ERR_FORMAT, "%s: extras records of %u bytes, expected %zu", name,
                h->extras_size, sizeof(hlod_store_extra));
        if (h->extras_offset < h->node_table_offset + table || ex > file_size ||
            h->extras_offset > file_size - ex)
            BAD(HLOD_ERR_FORMAT, "%s: extras table [%llu, +%llu) lies outside the file after "
                "the node table (%llu bytes)", name, (unsigned long long)h->extras_offset,
                (unsigned long long)ex, (unsigned long long)file_size);
    }
    if (h->build.method > HLOD_STORE_METHOD_LAST)
        BAD(HLOD_ERR_FORMAT, "%s: unknown build method %u", name, h->build.method);
    if (!isfinite(h->build.level_factor) || h->build.level_factor < 0 ||
        !finite3d(h->bbox_min) || !finite3d(h->bbox_max))
        BAD(HLOD_ERR_NAN, "%s: a non-finite number in the header", name);
    return HLOD_OK;
}

/* Reads exactly n bytes at off from the store's source; logs what failed
 * (`what`) naming the store. */
static hlod_result source_read(hlod_store *s, void *buf, size_t n, uint64_t off, const char *what)
{
    if (s->http) {
        hlod_result r = hlod_http_read(s->http, off, buf, n);
        if (r != HLOD_OK)
            hlod_logf(&s->logger, HLOD_LOG_ERROR, "%s: cannot read %s: %s", s->path, what,
                      hlod_result_str(r));
        return r;
    }
    int e = pread_all(s->fd, buf, n, off);
    if (e) {
        hlod_logf(&s->logger, HLOD_LOG_ERROR, "%s: cannot read %s: %s", s->path, what,
                  e > 0 ? strerror(e) : "unexpected end of file");
        return HLOD_ERR_IO;
    }
    return HLOD_OK;
}

/* Opens the source and reads the header into s->header: a URL with one
 * range request, a file with fstat and pread.  *file_size: the source's. */
static hlod_result source_open(hlod_store *s, uint64_t *file_size)
{
    const hlod_logger *lg = &s->logger;
    const char *path = s->path;
    size_t got = 0;
    if (hlod_http_is_url(path)) {
        hlod_result r = hlod_http_open(path, lg, &s->header, sizeof s->header, &got, file_size,
                                       &s->http);
        if (r != HLOD_OK)
            return r;
    } else {
        struct stat st;
        s->fd = open(path, O_RDONLY | O_CLOEXEC);
        if (s->fd < 0 || fstat(s->fd, &st) != 0) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot open: %s", path, strerror(errno));
            return HLOD_ERR_IO;
        }
        if (!S_ISREG(st.st_mode)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: not a regular file", path);
            return HLOD_ERR_IO;
        }
        *file_size = (uint64_t)st.st_size;
    }
    if (*file_size < sizeof(hlod_store_header)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: %llu bytes is shorter than a store header (%zu)",
                  path, (unsigned long long)*file_size, sizeof(hlod_store_header));
        return HLOD_ERR_FORMAT;
    }
    if (s->http)
        return got == sizeof s->header ? HLOD_OK : HLOD_ERR_FORMAT;
    return source_read(s, &s->header, sizeof s->header, 0, "the header");
}

/* One extras record's fields: known flags, a unit axis and a cosine in
 * [-1, 1] when it has a cone, zero where its flags say nothing. */
static int extra_ok(const hlod_store_extra *x)
{
    if (x->flags & ~HLOD_EXTRA_ALL_FLAGS)
        return 0;
    if (!(x->flags & HLOD_EXTRA_CONE))
        return x->cone_axis[0] == 0 && x->cone_axis[1] == 0 && x->cone_axis[2] == 0 &&
               x->cone_cos == 0;
    double len = (double)x->cone_axis[0] * x->cone_axis[0] +
                 (double)x->cone_axis[1] * x->cone_axis[1] +
                 (double)x->cone_axis[2] * x->cone_axis[2];
    return fabs(len - 1) < 1e-4 && x->cone_cos >= -1 && x->cone_cos <= 1;
}

hlod_result hlod_store_check_extras(const hlod_store_header *h, const hlod_store_extras_header *xh,
                                   const hlod_store_extra *x, const char *name,
                                   const hlod_logger *lg)
{
    if (memcmp(xh->magic, HLOD_EXTRAS_MAGIC, 8) != 0 || xh->count != h->node_count ||
        xh->record_size != sizeof(hlod_store_extra) || !is_zero(xh->reserved, sizeof xh->reserved))
        BAD(HLOD_ERR_FORMAT, "%s: the extras table's header is not one for %u nodes", name,
            h->node_count);
    if (hlod_store_hash(x, (size_t)xh->count * sizeof *x) != xh->hash)
        BAD(HLOD_ERR_CHECKSUM, "%s: extras table checksum mismatch", name);
    for (uint32_t i = 0; i < xh->count; i++)
        if (!extra_ok(&x[i]))
            BAD(HLOD_ERR_FORMAT, "%s: node %u: its extras record is not valid (flags %#x)", name,
                i, x[i].flags);
    return HLOD_OK;
}

/* The extras table (check_header bounded it). */
static hlod_result read_extras(hlod_store *s)
{
    hlod_store_extras_header xh;
    hlod_result r = source_read(s, &xh, sizeof xh, s->header.extras_offset, "the extras table");
    if (r != HLOD_OK)
        return r;
    size_t bytes = (size_t)s->header.node_count * sizeof(hlod_store_extra);
    s->extras = malloc(bytes ? bytes : 1);
    if (!s->extras)
        return HLOD_ERR_NOMEM;
    r = source_read(s, s->extras, bytes, s->header.extras_offset + sizeof xh, "the extras table");
    if (r != HLOD_OK)
        return r;
    return hlod_store_check_extras(&s->header, &xh, s->extras, s->path, &s->logger);
}

hlod_result hlod_store_open(const char *path, const hlod_logger *lg_in, hlod_store **out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    *out = NULL;
    if (!path)
        return HLOD_ERR_INVALID_ARG;
    hlod_store *s = calloc(1, sizeof *s);
    if (!s)
        return HLOD_ERR_NOMEM;
    s->fd = -1;
    if (lg_in)
        s->logger = *lg_in;
    const hlod_logger *lg = &s->logger;
    hlod_result r = HLOD_ERR_NOMEM;
    size_t plen = strlen(path);
    s->path = malloc(plen + 1);
    if (!s->path)
        goto fail;
    memcpy(s->path, path, plen + 1);

    uint64_t file_size = 0;
    r = source_open(s, &file_size);
    if (r != HLOD_OK)
        goto fail;
    r = hlod_store_check_header(&s->header, file_size, path, lg);
    if (r != HLOD_OK)
        goto fail;

    /* Bounded by the file size in check_header. */
    size_t table = (size_t)s->header.node_table_size;
    s->nodes = malloc(table);
    if (!s->nodes) {
        r = HLOD_ERR_NOMEM;
        goto fail;
    }
    r = source_read(s, s->nodes, table, s->header.node_table_offset, "the node table");
    if (r != HLOD_OK)
        goto fail;
    if (hlod_store_hash(s->nodes, table) != s->header.node_table_hash) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: node table checksum mismatch", path);
        r = HLOD_ERR_CHECKSUM;
        goto fail;
    }
    r = hlod_store_validate(&s->header, s->nodes, file_size, path, lg);
    if (r != HLOD_OK)
        goto fail;
    if (s->header.extras_offset) {
        r = read_extras(s);
        if (r != HLOD_OK)
            goto fail;
    }
    cache_open(s);
    *out = s;
    return HLOD_OK;
fail:
    hlod_store_close(s);
    return r;
}

void hlod_store_close(hlod_store *s)
{
    if (!s)
        return;
    if (s->fd >= 0)
        close(s->fd);
    hlod_http_close(s->http);
    cache_close(s->cache);
    free(s->nodes);
    free(s->extras);
    free(s->path);
    free(s);
}

const hlod_store_header *hlod_store_get_header(const hlod_store *s) { return &s->header; }
const hlod_store_node *hlod_store_nodes(const hlod_store *s) { return s->nodes; }
const hlod_store_extra *hlod_store_extras(const hlod_store *s) { return s->extras; }
uint32_t hlod_store_node_count(const hlod_store *s) { return s->header.node_count; }
uint32_t hlod_store_root_count(const hlod_store *s) { return s->header.root_count; }
uint32_t hlod_store_block_count(const hlod_store *s) { return s->header.block_count; }
uint32_t hlod_store_top_count(const hlod_store *s) { return s->header.top_count; }
uint32_t hlod_store_first_block(const hlod_store *s)
{
    return s->header.top_count - s->header.block_count;
}
const char *hlod_store_path(const hlod_store *s) { return s->path; }
int hlod_store_is_remote(const hlod_store *s) { return s && s->http != NULL; }

uint64_t hlod_store_memory_bytes(const hlod_store *s)
{
    uint64_t sum = 0;
    for (uint32_t i = 0; i < s->header.node_count; i++)
        sum += hlod_store_node_memory(&s->nodes[i]);
    return sum;
}

/* ---- payload reads ---- */

void hlod_store_payload_free(hlod_store_payload *p)
{
    if (!p)
        return;
    free(p->memory);
    free(p->tex_memory);
    memset(p, 0, sizeof *p);
}

/* called from the loader thread (or any one thread owning rd) */
hlod_result hlod_store_read_begin(const hlod_store *s, uint32_t node, hlod_store_read *rd)
{
    if (!rd)
        return HLOD_ERR_INVALID_ARG;
    memset(rd, 0, sizeof *rd);
    if (!s || node >= s->header.node_count)
        return HLOD_ERR_INVALID_ARG;
    const hlod_store_node *n = &s->nodes[node];
    rd->store = s;
    rd->node = node;
    rd->size = n->payload_size;     /* validated: inside the file */
    rd->buf = malloc((size_t)rd->size);
    XXH3_state_t *st = XXH3_createState();
    if (!rd->buf || !st || XXH3_64bits_reset(st) != XXH_OK) {
        XXH3_freeState(st);
        hlod_store_read_cancel(rd);
        return HLOD_ERR_NOMEM;
    }
    rd->hash_state = st;
    return HLOD_OK;
}

void hlod_store_set_pread(hlod_store *s, hlod_store_pread_fn fn, void *user)
{
    if (!s)
        return;
    s->pread_fn = fn;
    s->pread_user = fn ? user : NULL;
}

/* called from the thread owning rd: reads min(max_bytes, left), looping over
 * short reads (pread may return fewer bytes than asked without an error) and
 * retrying EINTR; the bytes are hashed once they are all in */
hlod_result hlod_store_read_step(hlod_store_read *rd, size_t max_bytes, int *complete)
{
    if (!rd || !rd->store || !rd->buf || max_bytes == 0)
        return HLOD_ERR_INVALID_ARG;
    const hlod_store *s = rd->store;
    const hlod_logger *lg = &s->logger;
    uint64_t left = rd->size - rd->done;
    if (left) {
        size_t want = left < max_bytes ? (size_t)left : max_bytes;
        uint8_t *dst = rd->buf + rd->done;
        uint64_t off = s->nodes[rd->node].payload_offset + rd->done;
        size_t got = 0;
        if (s->http) {
            /* one range request (retried inside); the bytes of a failed
             * step are not kept, the read is cancelled after an error */
            hlod_result r = hlod_http_read(s->http, off, dst, want);
            if (r != HLOD_OK) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: node %u: cannot read payload at offset %llu: %s",
                          s->path, rd->node, (unsigned long long)off, hlod_result_str(r));
                return r;
            }
            got = want;
        }
        while (got < want) {
            ssize_t k;
            errno = 0;
            if (s->pread_fn)
                k = s->pread_fn(s->pread_user, s->fd, dst + got, want - got,
                                (off_t)(off + got));
            else
                k = pread(s->fd, dst + got, want - got, (off_t)(off + got));
            if (k < 0 && errno == EINTR)
                continue;
            if (k <= 0 || (size_t)k > want - got) {
                int err = errno;
                hlod_logf(lg, HLOD_LOG_ERROR,
                          "%s: node %u: cannot read payload at offset %llu: %s", s->path,
                          rd->node, (unsigned long long)(off + got),
                          k < 0 ? strerror(err ? err : EIO)
                          : k == 0 ? "unexpected end of file (file shrank?)"
                                   : "read returned more bytes than asked");
                return HLOD_ERR_IO;
            }
            got += (size_t)k;
        }
        if (XXH3_64bits_update(rd->hash_state, dst, want) != XXH_OK)
            return HLOD_ERR_INVALID_ARG;
        rd->done += want;
    }
    if (complete)
        *complete = rd->done == rd->size;
    return HLOD_OK;
}

void hlod_store_read_cancel(hlod_store_read *rd)
{
    if (!rd)
        return;
    free(rd->buf);
    XXH3_freeState(rd->hash_state);
    memset(rd, 0, sizeof *rd);
}

static int finite_floats(const float *v, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

/* Parses buf (size bytes, hash verified) against node n into *p; apart:
 * the layout holds no texels (the texture was decoded apart from it). */
static hlod_result parse_payload(const hlod_store *s, uint32_t node, uint8_t *buf, uint64_t size,
                                 int apart, hlod_store_payload *p)
{
    const hlod_logger *lg = &s->logger;
    const hlod_store_node *n = &s->nodes[node];
    const char *name = s->path;
    hlod_store_payload_header ph;
    if (size < sizeof ph)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: payload shorter than its header", name, node);
    memcpy(&ph, buf, sizeof ph);
    if (memcmp(ph.magic, HLOD_PAYLOAD_MAGIC, 4) != 0 || !is_zero(ph.reserved, sizeof ph.reserved))
        BAD(HLOD_ERR_FORMAT, "%s: node %u: bad payload header", name, node);
    if (!hlod_store_counts_agree(n, ph.flags, ph.vertex_count, ph.index_count, ph.tex_tri_count,
                                 ph.tex_width, ph.tex_height, ph.tex_channels))
        BAD(HLOD_ERR_FORMAT, "%s: node %u: payload counts disagree with the node table", name,
            node);
    uint64_t texels = apart ? (uint64_t)ph.tex_width * ph.tex_height * ph.tex_channels : 0;
    if (hlod_store_payload_size(ph.flags, ph.vertex_count, ph.index_count, ph.tex_width,
                                ph.tex_height, ph.tex_channels) != size + texels)
        BAD(HLOD_ERR_FORMAT, "%s: node %u: payload size disagrees with its counts", name, node);

    size_t v = ph.vertex_count, off = sizeof ph;
    memset(p, 0, sizeof *p);
    p->node = node;
    p->flags = ph.flags;
    p->vertex_count = ph.vertex_count;
    p->index_count = ph.index_count;
    p->tex_tri_count = ph.tex_tri_count;
    p->tex_width = ph.tex_width;
    p->tex_height = ph.tex_height;
    p->tex_channels = ph.tex_channels;
    /* Sections are 4-byte aligned in a malloc'ed buffer: used in place. */
    p->positions = (const float *)(buf + off);
    off += 12 * v;
    if (ph.flags & HLOD_NODE_NORMALS) {
        p->normals = (const float *)(buf + off);
        off += 12 * v;
    }
    if (ph.flags & HLOD_NODE_UVS) {
        p->uvs = (const float *)(buf + off);
        off += 8 * v;
    }
    if (ph.flags & HLOD_NODE_COLORS) {
        p->colors = buf + off;
        off += 4 * v;
    }
    p->indices = (const uint32_t *)(buf + off);
    off += 4 * (size_t)ph.index_count;
    if ((ph.flags & HLOD_NODE_TEXTURE) && !apart)
        p->pixels = buf + off;

    if (!finite_floats(p->positions, 3 * v) || (p->normals && !finite_floats(p->normals, 3 * v)) ||
        (p->uvs && !finite_floats(p->uvs, 2 * v))) {
        memset(p, 0, sizeof *p);
        BAD(HLOD_ERR_NAN, "%s: node %u: non-finite vertex data", name, node);
    }
    for (size_t i = 0; i < ph.index_count; i++)
        if (p->indices[i] >= ph.vertex_count) {
            uint32_t bad = p->indices[i];
            memset(p, 0, sizeof *p);
            BAD(HLOD_ERR_INDEX_RANGE, "%s: node %u: index %zu is %u, vertex count %u", name,
                node, i, bad, ph.vertex_count);
        }
    p->memory = buf;
    p->bytes = (size_t)size;
    return HLOD_OK;
}

/* called from the thread owning rd */
hlod_result hlod_store_read_finish(hlod_store_read *rd, hlod_store_payload *out)
{
    return hlod_store_read_finish_as(rd, HLOD_TEXOUT_PIXELS, out);
}

/* called from the thread owning rd */
hlod_result hlod_store_read_finish_as(hlod_store_read *rd, int texout, hlod_store_payload *out)
{
    if (!out) {
        hlod_store_read_cancel(rd);
        return HLOD_ERR_INVALID_ARG;
    }
    memset(out, 0, sizeof *out);
    if (!rd || !rd->store || !rd->buf)
        return HLOD_ERR_INVALID_ARG;
    const hlod_store *s = rd->store;
    hlod_result r;
    if (rd->done != rd->size) {
        hlod_logf(&s->logger, HLOD_LOG_ERROR, "%s: node %u: finish before the payload was read",
                  s->path, rd->node);
        r = HLOD_ERR_INVALID_ARG;
    } else if ((uint64_t)XXH3_64bits_digest(rd->hash_state) != s->nodes[rd->node].payload_hash) {
        hlod_logf(&s->logger, HLOD_LOG_ERROR, "%s: node %u: payload checksum mismatch",
                  s->path, rd->node);
        r = HLOD_ERR_CHECKSUM;
    } else if (s->header.payload_codec == HLOD_STORE_CODEC_PACKED) {
        hlod_unpacked u;
        const hlod_store_node *n = &s->nodes[rd->node];
        r = hlod_payload_unpack(rd->buf, (size_t)rd->size, n, rd->node, &s->header, texout, &u,
                                s->path, &s->logger);
        if (r == HLOD_OK) {
            r = parse_payload(s, rd->node, u.raw, u.raw_size, u.tex != NULL, out);
            if (r != HLOD_OK) {
                free(u.raw);
                free(u.tex);
            } else if (u.tex) {
                out->pixels = u.tex;
                out->tex_memory = u.tex;
                out->tex_levels = u.tex_levels;
                out->tex_format = u.tex_format;
                out->tex_channels = u.tex_channels;
            }
        }
    } else {
        r = parse_payload(s, rd->node, rd->buf, rd->size, 0, out);
        if (r == HLOD_OK)
            rd->buf = NULL;     /* moved into *out */
    }
    hlod_store_read_cancel(rd);
    return r;
}

hlod_result hlod_store_read_node(const hlod_store *s, uint32_t node, size_t max_bytes,
                                 hlod_store_payload *out)
{
    return hlod_store_read_node_as(s, node, max_bytes, HLOD_TEXOUT_PIXELS, out);
}

hlod_result hlod_store_read_node_as(const hlod_store *s, uint32_t node, size_t max_bytes,
                                    int texout, hlod_store_payload *out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    memset(out, 0, sizeof *out);
    hlod_store_read rd;
    hlod_result r = hlod_store_read_begin(s, node, &rd);
    int complete = 0, cached = r == HLOD_OK && hlod_store_cache_get(&rd);
    if (!max_bytes)
        max_bytes = 65536;
    if (s && s->http)
        max_bytes = SIZE_MAX; /* one range request: each costs a round trip */
    while (r == HLOD_OK && !complete)
        r = hlod_store_read_step(&rd, max_bytes, &complete);
    if (r != HLOD_OK) {
        hlod_store_read_cancel(&rd);
        return r;
    }
    if (!cached)
        hlod_store_cache_put(&rd);
    return hlod_store_read_finish_as(&rd, texout, out);
}

hlod_result hlod_store_read_nodes(const hlod_store *s, uint32_t first, uint32_t count,
                                  size_t max_bytes, hlod_store_payload *out,
                                  hlod_result *results)
{
    return hlod_store_read_nodes_as(s, first, count, max_bytes, HLOD_TEXOUT_PIXELS, out, results);
}

hlod_result hlod_store_read_nodes_as(const hlod_store *s, uint32_t first, uint32_t count,
                                     size_t max_bytes, int texout, hlod_store_payload *out,
                                     hlod_result *results)
{
    if (!s || !out || !results || (uint64_t)first + count > s->header.node_count)
        return HLOD_ERR_INVALID_ARG;
    memset(out, 0, count * sizeof *out);
    hlod_store_fetch *f = NULL;
    if (!s->http || count < 2 || hlod_store_fetch_create(s, 8, &f) != HLOD_OK) {
        for (uint32_t i = 0; i < count; i++)
            results[i] = hlod_store_read_node_as(s, first + i, max_bytes, texout, &out[i]);
        return HLOD_OK;
    }
    hlod_store_read *rd = calloc(count, sizeof *rd);
    if (!rd) {
        hlod_store_fetch_destroy(f);
        return HLOD_ERR_NOMEM;
    }
    uint32_t next = 0, left = count;
    hlod_store_fetch_end ends[8];
    while (left) {
        while (next < count && hlod_store_fetch_active(f) < 8) {
            uint32_t i = next++;
            results[i] = hlod_store_read_begin(s, first + i, &rd[i]);
            if (results[i] == HLOD_OK && hlod_store_cache_get(&rd[i]))
                results[i] = hlod_store_read_finish_as(&rd[i], texout, &out[i]);
            else if (results[i] == HLOD_OK)
                results[i] = hlod_store_fetch_start(f, &rd[i], UINT64_MAX);
            if (results[i] != HLOD_OK || !rd[i].buf) {
                hlod_store_read_cancel(&rd[i]);
                left--;
            }
        }
        if (!hlod_store_fetch_active(f))
            continue;   /* every read left came from the cache */
        size_t k = hlod_store_fetch_poll(f, 100, -1, ends, 8, NULL);
        for (size_t e = 0; e < k; e++) {
            uint32_t i = (uint32_t)(ends[e].rd - rd);
            results[i] = ends[e].result;
            if (results[i] == HLOD_OK && rd[i].done == rd[i].size) {
                hlod_store_cache_put(&rd[i]);
                results[i] = hlod_store_read_finish_as(&rd[i], texout, &out[i]);
            }
            else if (results[i] == HLOD_OK)
                results[i] = hlod_store_fetch_start(f, &rd[i], UINT64_MAX);
            if (results[i] != HLOD_OK || !rd[i].buf) {
                hlod_store_read_cancel(&rd[i]);
                left--;
            }
        }
    }
    free(rd);
    hlod_store_fetch_destroy(f);
    return HLOD_OK;
}

/* ---- parallel reads of an HTTP store ---- */

struct hlod_store_fetch {
    const hlod_store *store;
    hlod_http_multi *multi;
    hlod_http_end *ends;
    unsigned transfers;
};

/* the transfers' sink: appends to the read as a step does */
static int fetch_sink(void *user, const void *data, size_t n)
{
    hlod_store_read *rd = user;
    if (n > rd->size - rd->done)
        return -1;
    memcpy(rd->buf + rd->done, data, n);
    if (XXH3_64bits_update(rd->hash_state, data, n) != XXH_OK)
        return -1;
    rd->done += n;
    return 0;
}

hlod_result hlod_store_fetch_create(const hlod_store *s, unsigned transfers,
                                    hlod_store_fetch **out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    *out = NULL;
    if (!s || !transfers)
        return HLOD_ERR_INVALID_ARG;
    if (!s->http)
        return HLOD_ERR_UNSUPPORTED;
    hlod_store_fetch *f = calloc(1, sizeof *f);
    if (!f)
        return HLOD_ERR_NOMEM;
    f->store = s;
    f->transfers = transfers;
    f->ends = calloc(transfers, sizeof *f->ends);
    hlod_result r = f->ends ? hlod_http_multi_create(s->http, transfers, &f->multi)
                            : HLOD_ERR_NOMEM;
    if (r != HLOD_OK) {
        hlod_store_fetch_destroy(f);
        return r;
    }
    *out = f;
    return HLOD_OK;
}

void hlod_store_fetch_destroy(hlod_store_fetch *f)
{
    if (!f)
        return;
    hlod_http_multi_destroy(f->multi);
    free(f->ends);
    free(f);
}

hlod_result hlod_store_fetch_start(hlod_store_fetch *f, hlod_store_read *rd, uint64_t max_bytes)
{
    if (!f || !rd || rd->store != f->store || !rd->buf || rd->done >= rd->size || !max_bytes)
        return HLOD_ERR_INVALID_ARG;
    uint64_t left = rd->size - rd->done;
    uint64_t off = f->store->nodes[rd->node].payload_offset + rd->done;
    return hlod_http_multi_start(f->multi, off, left < max_bytes ? left : max_bytes, fetch_sink,
                                 rd);
}

void hlod_store_fetch_stop(hlod_store_fetch *f, hlod_store_read *rd)
{
    if (f)
        hlod_http_multi_stop(f->multi, rd);
}

int hlod_store_fetch_has(const hlod_store_fetch *f, const hlod_store_read *rd)
{
    return f && hlod_http_multi_has(f->multi, (void *)rd);
}

unsigned hlod_store_fetch_active(const hlod_store_fetch *f)
{
    return f ? hlod_http_multi_active(f->multi) : 0;
}

size_t hlod_store_fetch_poll(hlod_store_fetch *f, int timeout_ms, int wake_fd,
                             hlod_store_fetch_end *out, size_t max, uint64_t *bytes)
{
    if (bytes)
        *bytes = 0;
    if (!f || !out || !max)
        return 0;
    if (max > f->transfers)
        max = f->transfers;
    size_t n = hlod_http_multi_poll(f->multi, timeout_ms, wake_fd, f->ends, max, bytes);
    for (size_t i = 0; i < n; i++) {
        out[i].rd = f->ends[i].user;
        out[i].result = f->ends[i].result; /* the HTTP layer logged why */
    }
    return n;
}

void hlod_store_set_http_latency(hlod_store *s, double ms)
{
    if (s)
        hlod_http_set_latency(s->http, ms);
}

/* ---- the local payload cache of a URL (HLOD_CACHE_DIR; store_http.h) ----
 *
 * HLOD_CACHE_DIR/<32 hex digits>/<node>: the digits are XXH3-128 of the
 * URL, the open's ETag and Last-Modified, the header and the node table;
 * each file holds one node's payload as stored (packed or raw), written to
 * <node>.tmp.<pid>.<n> and renamed.  Entries are trusted only after their
 * size and XXH3-64 match the node table.  Any thread: the state is the
 * folder's name and two atomics. */

struct store_cache {
    char *dir;
    hlod_logger lg;
    atomic_int off;             /* a write failed (logged once): no more use */
    atomic_uint seq;            /* temporary names of this process */
};

/* mkdir -p, then the cache folder must be writable: 0, or an errno. */
static int make_dirs(const char *path)
{
    int e = hlod_mkdir_p(path, 0755);
    return e ? e : access(path, W_OK | X_OK) == 0 ? 0 : errno;
}

/* Temporary files left by a process that died mid-write: removed. */
static void cache_sweep(const char *dir)
{
    DIR *d = opendir(dir);
    if (!d)
        return;
    struct dirent *e;
    while ((e = readdir(d))) {
        const char *t = strstr(e->d_name, ".tmp.");
        long pid = t ? strtol(t + 5, NULL, 10) : 0;
        if (pid > 0 && kill((pid_t)pid, 0) != 0 && errno == ESRCH)
            unlinkat(dirfd(d), e->d_name, 0);
    }
    closedir(d);
}

static void cache_open(hlod_store *s)
{
    const char *root = getenv("HLOD_CACHE_DIR");
    if (!s->http || !root || !root[0])
        return;
    const char *etag, *lm;
    hlod_http_validators(s->http, &etag, &lm);
    XXH3_state_t *st = XXH3_createState();
    if (!st)
        return;
    static const char tag[] = "hlod payload cache 1";
    XXH3_128bits_reset(st);
    XXH3_128bits_update(st, tag, sizeof tag);
    XXH3_128bits_update(st, s->path, strlen(s->path) + 1);
    XXH3_128bits_update(st, etag, strlen(etag) + 1);
    XXH3_128bits_update(st, lm, strlen(lm) + 1);
    XXH3_128bits_update(st, &s->header, sizeof s->header);
    XXH3_128bits_update(st, s->nodes, (size_t)s->header.node_table_size);
    XXH128_hash_t key = XXH3_128bits_digest(st);
    XXH3_freeState(st);

    struct store_cache *c = calloc(1, sizeof *c);
    size_t n = strlen(root) + 40;
    char *dir = malloc(n);
    if (!c || !dir) {
        free(c);
        free(dir);
        return;
    }
    snprintf(dir, n, "%s/%016llx%016llx", root, (unsigned long long)key.high64,
             (unsigned long long)key.low64);
    int e = make_dirs(dir);
    if (e) {
        hlod_logf(&s->logger, HLOD_LOG_WARN, "%s: HLOD_CACHE_DIR: cannot use %s: %s; reading "
                  "without a cache", s->path, dir, strerror(e));
        free(c);
        free(dir);
        return;
    }
    cache_sweep(dir);
    c->dir = dir;
    c->lg = s->logger;
    atomic_init(&c->off, 0);
    atomic_init(&c->seq, 0);
    s->cache = c;
}

static void cache_close(struct store_cache *c)
{
    if (!c)
        return;
    free(c->dir);
    free(c);
}

int hlod_store_cache_get(hlod_store_read *rd)
{
    if (!rd || !rd->store || !rd->buf || rd->done != 0 || rd->size == 0)
        return 0;
    const hlod_store *s = rd->store;
    struct store_cache *c = s->cache;
    if (!c || atomic_load(&c->off))
        return 0;
    const hlod_store_node *n = &s->nodes[rd->node];
    char path[4200];
    snprintf(path, sizeof path, "%s/%u", c->dir, rd->node);
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return 0;
    struct stat st;
    int ok = fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && (uint64_t)st.st_size == rd->size &&
             pread_all(fd, rd->buf, (size_t)rd->size, 0) == 0;
    close(fd);
    XXH3_state_t *hs = rd->hash_state;
    if (ok)
        ok = XXH3_64bits_update(hs, rd->buf, (size_t)rd->size) == XXH_OK &&
             (uint64_t)XXH3_64bits_digest(hs) == n->payload_hash;
    if (!ok) {
        XXH3_64bits_reset(hs);
        unlink(path);
        hlod_logf(&c->lg, HLOD_LOG_WARN, "%s: node %u: cache entry %s is damaged (size or "
                  "checksum); removed, read again", s->path, rd->node, path);
        return 0;
    }
    rd->done = rd->size;
    return 1;
}

void hlod_store_cache_put(const hlod_store_read *rd)
{
    if (!rd || !rd->store || !rd->buf || rd->done != rd->size)
        return;
    const hlod_store *s = rd->store;
    struct store_cache *c = s->cache;
    if (!c || atomic_load(&c->off) ||
        (uint64_t)XXH3_64bits_digest(rd->hash_state) != s->nodes[rd->node].payload_hash)
        return;
    char tmp[4200], path[4200];
    snprintf(path, sizeof path, "%s/%u", c->dir, rd->node);
    snprintf(tmp, sizeof tmp, "%s/%u.tmp.%ld.%u", c->dir, rd->node, (long)getpid(),
             atomic_fetch_add(&c->seq, 1));
    int fd = open(tmp, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
    int e = fd < 0 ? errno : 0;
    for (size_t at = 0; !e && at < rd->size;) {
        ssize_t k = write(fd, rd->buf + at, (size_t)rd->size - at);
        if (k < 0 && errno == EINTR)
            continue;
        if (k <= 0)
            e = k < 0 ? errno : EIO;
        else
            at += (size_t)k;
    }
    if (fd >= 0 && close(fd) != 0 && !e)
        e = errno;
    if (!e && rename(tmp, path) != 0)
        e = errno;
    if (!e)
        return;
    if (fd >= 0)
        unlink(tmp);
    if (!atomic_exchange(&c->off, 1))
        hlod_logf(&c->lg, HLOD_LOG_WARN, "%s: HLOD_CACHE_DIR: cannot write %s: %s; going on "
                  "without the cache", s->path, fd >= 0 ? tmp : c->dir, strerror(e));
}
