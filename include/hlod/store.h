/*
 * store.h - the HLOD store: one file holding a whole hierarchy, its format
 * and its validating reader.  The one header both preprocess/ (which writes
 * stores, see store_write.h) and engine/ (which reads them) include.
 *
 * File layout (all integers and floats little-endian, IEEE 754; the structs
 * below are the bytes on disk, without implicit padding):
 *
 *   [0, 256)                hlod_store_header
 *   [256, align)            zero padding
 *   payloads                one per node, each at a multiple of
 *                           header.payload_align (4096 by default), in the
 *                           order the builder produced them, zero padding
 *                           between them
 *   node table              (node_count + 1) hlod_store_node records: the
 *                           nodes in breadth-first order, then a sentinel
 *
 * The node table comes last because the builder knows it only when every
 * payload has been written: payloads stream to the file as they are made, so
 * a store may be larger than RAM, and the header is written at the end.
 *
 * Tree rule (Nexus style): node_count nodes, breadth-first, the root_count
 * roots (depth 0) first.  The children of node i are the nodes
 * [nodes[i].first_child, nodes[i + 1].first_child); node i is a leaf when
 * the range is empty.  nodes[node_count] is the sentinel: first_child =
 * node_count, every other byte zero.  Hence nodes[0].first_child =
 * root_count, first_child never decreases, depth never decreases with the
 * index, and the ranges tile [root_count, node_count) so every non-root node
 * has exactly one parent.  A child has depth parent.depth + 1.
 *
 * Blocks and city levels (docs/store-format.md): every block's hlod_0 node
 * lies at depth block_depth, and those block_count nodes are the nodes
 * [top_count - block_count, top_count), block b being node top_count -
 * block_count + b.  A node below them has its block's index in `block`.
 * With block_depth = 0 the roots are the blocks (the paper's layout).
 * Above them, nodes at depths [0, block_depth) are group nodes (block =
 * HLOD_STORE_NO_BLOCK): each the union of its children simplified, none a
 * leaf.  The top_count nodes at depth <= block_depth are the top of the
 * tree, which the runtime keeps resident.
 *
 * Payload codec (header.payload_codec): HLOD_STORE_CODEC_RAW payloads are
 * the raw layout below, read in place; HLOD_STORE_CODEC_PACKED payloads are
 * the packed layout after it, decoded by the reader (on the loader thread)
 * into the raw layout, so what a reader hands out is the same either way.
 * Version 2 stores (no codec field) are raw.
 *
 * Raw payload layout (offsets from the payload's first byte):
 *   hlod_store_payload_header (64 bytes)
 *   float    positions[3 * vertex_count]   relative to the node's origin
 *   float    normals[3 * vertex_count]     if HLOD_NODE_NORMALS
 *   float    uvs[2 * vertex_count]         if HLOD_NODE_UVS
 *   uint8_t  colors[4 * vertex_count]      if HLOD_NODE_COLORS (RGBA, sRGB)
 *   uint32_t indices[index_count]          triangles, counter-clockwise front;
 *                                          the first tex_tri_count triangles
 *                                          use the texture, the rest do not
 *   uint8_t  pixels[w * h * channels]      if HLOD_NODE_TEXTURE: 8-bit,
 *                                          row-major, top row first (as
 *                                          hlod_image), UVs as in the source
 * Every section starts 4-byte aligned, so a payload read into malloc'ed
 * memory is used in place (zero copy).  payload_size is exactly the sum of
 * these sections; the padding after it belongs to no checksum and carries
 * nothing.  hlod_store_payload_size() gives it from the counts, and it is
 * also what any payload takes in memory once read (hlod_store_node_memory).
 *
 * Packed payload layout (docs/store-format.md):
 *   hlod_store_packed_header (128 bytes), then its sections back to back,
 *   section_bytes[k] bytes each, in this order:
 *   positions  meshopt vertex codec over 12-byte vertices: 3 x uint32 grid
 *              steps k, position = node.origin + (k + pos_shift) * quant_step
 *              (header.quant_step; node.origin lies on the store's grid
 *              header.quant_origin + integer * quant_step, so a point two
 *              nodes share quantizes to the same grid point in both)
 *   normals    meshopt vertex codec over 4-byte vertices: octahedral
 *              2 x int16 (snorm), if HLOD_NODE_NORMALS
 *   uvs        meshopt vertex codec over 4-byte vertices: 2 x uint16,
 *              uv = uv_min + q * uv_scale, if HLOD_NODE_UVS
 *   colors     meshopt vertex codec over the 4-byte RGBA colours, if
 *              HLOD_NODE_COLORS
 *   indices    meshopt index codec (triangle list)
 *   texture    tex_codec HLOD_TEX_JPEG: a baseline JPEG (1 or 3 channels);
 *              HLOD_TEX_BC: one zstd frame holding the mip chain's
 *              BC1 (3 channels) or BC4 (1 channel) blocks, level 0 first;
 *              HLOD_TEX_RAW: the raw pixels; if HLOD_NODE_TEXTURE
 * payload_size = 128 + the sum of section_bytes.
 *
 * Checksums: XXH3-64 (seed 0, libxxhash) over the header's first 248 bytes,
 * over the whole node table (sentinel included) and over each payload.
 * xxHash because Debian ships it (setup.sh installs libxxhash-dev), it hashes
 * at memory speed (so the loader thread spends its time on I/O, not on
 * CRC tables) and its 64 bits make a missed corruption practically
 * impossible.  It is compiled header-only into store_read.c.
 *
 * Reader threads: hlod_store_open() is called once; afterwards the store is
 * immutable, so any number of threads may read payloads from one store at
 * once, each with its own hlod_store_read (reads are pread() on one file
 * descriptor, no shared file position).  Two stores opened on one file are
 * independent.
 */
#ifndef HLOD_STORE_H
#define HLOD_STORE_H

#include "hlod/hlod.h"

#include <sys/types.h> /* ssize_t, off_t: the pread test hook */

#ifdef __cplusplus
extern "C" {
#endif

/* ---- format ---- */

#define HLOD_STORE_MAGIC "HLODSTOR"     /* 8 bytes, no terminator on disk */
#define HLOD_STORE_VERSION 5u       /* 5: block-coded textures (HLOD_TEX_BC); 4: the extras
                                       table; 3: payload codec; 2: city levels
                                       (block_depth, top_count) */
#define HLOD_STORE_VERSION_MIN 2u   /* the oldest version this reader reads */
#define HLOD_STORE_ENDIAN 0x01020304u   /* read back as 0x04030201: wrong byte order */
#define HLOD_STORE_DEFAULT_ALIGN 4096u
#define HLOD_STORE_MIN_ALIGN 64u
#define HLOD_STORE_MAX_ALIGN (1u << 20)
#define HLOD_STORE_NO_PARENT 0xffffffffu
#define HLOD_STORE_NO_BLOCK 0xffffffffu /* node.block of a group node */
#define HLOD_STORE_MAX_TEXTURE 65536u   /* width and height limit */

/* header.payload_codec */
#define HLOD_STORE_CODEC_RAW 0u         /* payloads in the raw layout */
#define HLOD_STORE_CODEC_PACKED 1u      /* payloads in the packed layout */

/* header.flags */
#define HLOD_STORE_TEXTURED 1u          /* some node has a texture */
#define HLOD_STORE_ADDITIVE 2u          /* nodes refine additively: a node's
                                           children add to what it draws, its
                                           ancestors stay drawn (the sample
                                           tree and the colour cubes; set iff
                                           build.method is
                                           HLOD_STORE_METHOD_SAMPLETREE or
                                           HLOD_STORE_METHOD_CUBES) */

/* header.method: how the hierarchy was partitioned */
#define HLOD_STORE_METHOD_OTHER 0u
#define HLOD_STORE_METHOD_CUTPLANE 1u   /* Lakhia III-A */
#define HLOD_STORE_METHOD_METIS 2u      /* Okamoto 4.1 */
#define HLOD_STORE_METHOD_SAMPLETREE 3u /* Klein 4-5: a randomized sample tree
                                           (docs/sampletree.md); additive */
#define HLOD_STORE_METHOD_CUBES 4u      /* Chamberlain 3-4: an octree of colour
                                           cubes (docs/cubes.md); additive */
#define HLOD_STORE_METHOD_LAST 4u

/* The build parameters, recorded so tools can show how a store was made
 * (docs/hlod-build.md).  Zero where the method does not use one. */
typedef struct hlod_store_build_info {
    uint32_t method;        /* HLOD_STORE_METHOD_* */
    uint32_t flags;         /* HLOD_BUILD_* below; 0 before store version 5 */
    uint64_t desired_tris;  /* C_desiredTri: triangles of each hlod_0 node */
    double level_factor;    /* C_levelFactor; sampletree: the sample
                               constant c of m_u = q ln q + c q */
    uint64_t voxel_tris;    /* N_v */
    uint64_t leaf_tris;     /* N_l; sampletree: a leaf cell's polygons at most */
    uint64_t node_tris;     /* N_n */
    double c_tex;           /* c_tex of eq. 1, in [0, 1] */
} hlod_store_build_info;   /* 56 bytes */

#define HLOD_BUILD_CONE_SPLIT 1u /* cutplane: orientation classes near the
                                    leaves (hlod-build --cone-split on) */
#define HLOD_BUILD_KNOWN_FLAGS HLOD_BUILD_CONE_SPLIT

typedef struct hlod_store_header {
    char magic[8];              /*   0 HLOD_STORE_MAGIC */
    uint32_t version;           /*   8 HLOD_STORE_VERSION */
    uint32_t endian;            /*  12 HLOD_STORE_ENDIAN */
    uint32_t header_size;       /*  16 sizeof(hlod_store_header) = 256 */
    uint32_t node_size;         /*  20 sizeof(hlod_store_node) = 192 */
    uint32_t flags;             /*  24 HLOD_STORE_TEXTURED */
    uint32_t node_count;        /*  28 nodes, sentinel excluded, >= 1 */
    uint32_t root_count;        /*  32 depth-0 nodes, >= 1 */
    uint32_t depth_count;       /*  36 deepest depth + 1 */
    uint32_t payload_align;     /*  40 power of two in [64, 1 MiB] */
    uint32_t block_depth;       /*  44 depth of the blocks' hlod_0 nodes */
    uint64_t file_size;         /*  48 bytes in the file */
    uint64_t node_table_offset; /*  56 */
    uint64_t node_table_size;   /*  64 (node_count + 1) * node_size */
    uint64_t node_table_hash;   /*  72 XXH3-64 of the node table */
    uint64_t payload_bytes;     /*  80 sum of payload_size */
    double bbox_min[3];         /*  88 union of the node boxes, model units */
    double bbox_max[3];         /* 112 */
    hlod_store_build_info build; /* 136 */
    uint32_t block_count;       /* 192 blocks, >= 1 */
    uint32_t top_count;         /* 196 nodes at depth <= block_depth */
    uint32_t payload_codec;     /* 200 HLOD_STORE_CODEC_* (0 in version 2) */
    uint32_t extras_size;       /* 204 bytes of an extras record, sizeof(hlod_store_extra);
                                   0: no extras table (always 0 before version 4) */
    double quant_step;          /* 208 packed: the position grid's step (a
                                   power of two), model units; raw: 0 */
    double quant_origin[3];     /* 216 packed: a point of the grid; raw: 0 */
    uint64_t extras_offset;     /* 240 the extras table (hlod_store_extras_header, then
                                   node_count records); 0 when there is none */
    uint64_t header_hash;       /* 248 XXH3-64 of bytes [0, 248) */
} hlod_store_header;

/* header_hash covers the header up to itself. */
#define HLOD_STORE_HEADER_HASHED 248u

/* node.flags: which payload sections exist */
#define HLOD_NODE_NORMALS 1u
#define HLOD_NODE_UVS 2u
#define HLOD_NODE_COLORS 4u
#define HLOD_NODE_TEXTURE 8u    /* requires HLOD_NODE_UVS */
#define HLOD_NODE_ALL_FLAGS 15u

/* node.render_flags: how the node may be drawn */
#define HLOD_RENDER_SOLID 1u    /* its block is a closed, outward-wound
                                   surface: back faces may be culled */
#define HLOD_RENDER_ALL_FLAGS 1u

/* The extras table (version 4, optional; docs/store-format.md): after the
 * node table, a header and then one record a node, in node order.  What a
 * record holds is flagged per node; a reader that finds no table has
 * none of it (normal cones off). */
#define HLOD_EXTRAS_MAGIC "HLODEXTR"

typedef struct hlod_store_extras_header {
    char magic[8];              /*  0 HLOD_EXTRAS_MAGIC */
    uint32_t count;             /*  8 = header.node_count */
    uint32_t record_size;       /* 12 = header.extras_size */
    uint64_t hash;              /* 16 XXH3-64 of the records */
    uint8_t reserved[40];       /* 24 zero */
} hlod_store_extras_header;     /* 64 bytes */

/* hlod_store_extra.flags */
#define HLOD_EXTRA_CONE 1u      /* cone_axis and cone_cos bound the face normals */
#define HLOD_EXTRA_COLOR 2u     /* color holds the node's representative colour */
#define HLOD_EXTRA_CUBE 4u      /* cube holds its six cube-face colours */
#define HLOD_EXTRA_ALL_FLAGS 7u

typedef struct hlod_store_extra {
    float cone_axis[3];         /*  0 unit: with cone_cos, the normal cone of every face
                                   of the node and of its descendants: each face's
                                   unit normal n has dot(n, axis) >= cone_cos */
    float cone_cos;             /* 12 cosine of the half-angle, in [-1, 1] */
    uint8_t color[4];           /* 16 RGBA, sRGB (HLOD_EXTRA_COLOR) */
    uint8_t cube[6][4];         /* 20 RGBA seen along +x, -x, +y, -y, +z, -z (HLOD_EXTRA_CUBE) */
    uint32_t flags;             /* 44 HLOD_EXTRA_* */
} hlod_store_extra;             /* 48 bytes */

typedef struct hlod_store_node {
    uint32_t first_child;       /*   0 see the tree rule above */
    uint32_t parent;            /*   4 HLOD_STORE_NO_PARENT for roots */
    uint32_t depth;             /*   8 0 for roots */
    uint32_t block;             /*  12 its block's index; HLOD_STORE_NO_BLOCK
                                   above the blocks (group nodes) */
    uint32_t flags;             /*  16 HLOD_NODE_* */
    uint32_t vertex_count;      /*  20 */
    uint32_t tri_count;         /*  24 >= 1; = tex_tri_count + untex_tri_count */
    uint32_t tex_tri_count;     /*  28 textured triangles (stored first) */
    uint32_t untex_tri_count;   /*  32 */
    uint32_t tex_width;         /*  36 texture size; all 0 when untextured */
    uint32_t tex_height;        /*  40 */
    uint32_t tex_channels;      /*  44 1..4 */
    double bbox_min[3];         /*  48 world coordinates, model units: the
                                   node's content and every descendant's
                                   (the builder's rule; what the runtime
                                   culls a subtree by) */
    double bbox_max[3];         /*  72 */
    double origin[3];           /*  96 payload positions are relative to it */
    double cost;                /* 120 Lakhia eq. 1 with header.build.c_tex */
    double static_benefit;      /* 128 Lakhia eq. 2: sqrt(numTri * sum(area)) */
    double error;               /* 136 geometric error, model units; a node's
                                   error is >= each child's */
    float avg_normal[3];        /* 144 Lakhia eq. 3 (unit, or 0 when the
                                   area-weighted normals cancel out) */
    uint32_t render_flags;      /* 156 HLOD_RENDER_* */
    uint64_t payload_offset;    /* 160 multiple of payload_align */
    uint64_t payload_size;      /* 168 exact bytes, see the payload layout */
    uint64_t payload_hash;      /* 176 XXH3-64 of the payload */
    uint64_t reserved1;         /* 184 0 */
} hlod_store_node;

#define HLOD_PAYLOAD_MAGIC "HLPL"

typedef struct hlod_store_payload_header {
    char magic[4];              /*  0 HLOD_PAYLOAD_MAGIC */
    uint32_t flags;             /*  4 = node.flags */
    uint32_t vertex_count;      /*  8 = node.vertex_count */
    uint32_t index_count;       /* 12 = 3 * node.tri_count */
    uint32_t tex_tri_count;     /* 16 = node.tex_tri_count */
    uint32_t tex_width;         /* 20 = node.tex_width ... */
    uint32_t tex_height;        /* 24 */
    uint32_t tex_channels;      /* 28 */
    uint32_t reserved[8];       /* 32 zero */
} hlod_store_payload_header;

#define HLOD_PACKED_MAGIC "HLPK"

/* packed.tex_codec */
#define HLOD_TEX_RAW 0u
#define HLOD_TEX_JPEG 1u
#define HLOD_TEX_BC 2u      /* version 5: the mip chain as BC1 blocks (3 channels) or BC4
                               blocks (1 channel), tex_levels levels, one zstd frame
                               (engine/common/texture_codec.h) */

/* Sections of a packed payload, in order. */
enum {
    HLOD_SEC_POSITIONS,
    HLOD_SEC_NORMALS,
    HLOD_SEC_UVS,
    HLOD_SEC_COLORS,
    HLOD_SEC_INDICES,
    HLOD_SEC_TEXTURE,
    HLOD_SEC_COUNT
};

typedef struct hlod_store_packed_header {
    char magic[4];              /*   0 HLOD_PACKED_MAGIC */
    uint32_t flags;             /*   4 = node.flags */
    uint32_t vertex_count;      /*   8 = node.vertex_count */
    uint32_t index_count;       /*  12 = 3 * node.tri_count */
    uint32_t tex_tri_count;     /*  16 = node.tex_tri_count */
    uint32_t tex_width;         /*  20 = node.tex_width ... */
    uint32_t tex_height;        /*  24 */
    uint32_t tex_channels;      /*  28 */
    int32_t pos_shift[3];       /*  32 grid steps added to every vertex's */
    uint32_t tex_codec;         /*  44 HLOD_TEX_*; 0 without a texture */
    float uv_min[2];            /*  48 */
    float uv_scale[2];          /*  56 >= 0, finite */
    uint32_t section_bytes[HLOD_SEC_COUNT]; /* 64; 0 for an absent section */
    uint32_t tex_levels;        /*  88 HLOD_TEX_BC: the full chain's level count; else 0
                                   (version 5; reserved, 0, before) */
    float tex_db;               /*  92 PSNR in dB of the stored texture's level 0 against
                                   its source, measured by the builder; 0: not measured
                                   (raw textures, stores before version 5) */
    uint32_t reserved[8];       /*  96 zero */
} hlod_store_packed_header;

/* Children of node i: [hlod_store_first_child(n, i), hlod_store_child_end(n, i)). */
static inline uint32_t hlod_store_first_child(const hlod_store_node *nodes, uint32_t i)
{
    return nodes[i].first_child;
}
static inline uint32_t hlod_store_child_end(const hlod_store_node *nodes, uint32_t i)
{
    return nodes[i + 1].first_child;
}

/* Bytes of a payload with these counts (header included); 0 when the counts
 * are impossible (texture over HLOD_STORE_MAX_TEXTURE, channels > 4, flags
 * inconsistent). */
uint64_t hlod_store_payload_size(uint32_t flags, uint32_t vertex_count, uint32_t index_count,
                                 uint32_t tex_width, uint32_t tex_height, uint32_t tex_channels);

/* Bytes a node's payload takes in memory once read (decoded, for a packed
 * store): its raw layout's size.  Residency charges this against the
 * memory budget; payload_size is what is read. */
uint64_t hlod_store_node_memory(const hlod_store_node *n);

/* The store's checksum: XXH3-64, seed 0.  Reentrant. */
uint64_t hlod_store_hash(const void *data, size_t size);

/* Lakhia eq. 1: numTexTri * c_tex + numUnTexTri * (1 - c_tex). */
double hlod_store_cost(uint32_t tex_tris, uint32_t untex_tris, double c_tex);

/* Checks a header and node table against every rule of this file (the tree
 * rule, field ranges, finite numbers, eq. 1, error monotone up the tree,
 * payloads aligned, inside the file, off the header and table and not
 * overlapping each other, header totals).  Checksums are not checked here.
 * nodes holds header->node_count + 1 records.  The first problem is logged
 * through lg prefixed with `name`.  Returns HLOD_OK, HLOD_ERR_FORMAT,
 * HLOD_ERR_NAN or HLOD_ERR_NOMEM.  Used by the reader at open and by the
 * writer before it commits a store.  O(n log n), reentrant. */
hlod_result hlod_store_validate(const hlod_store_header *h, const hlod_store_node *nodes,
                                uint64_t file_size, const char *name, const hlod_logger *lg);

/* The extras table of a store whose header passed check_header: its
 * header xh (count and record size as the store's), the records' checksum,
 * and each record's fields.  HLOD_ERR_FORMAT, HLOD_ERR_CHECKSUM. */
hlod_result hlod_store_check_extras(const hlod_store_header *h, const hlod_store_extras_header *xh,
                                   const hlod_store_extra *x, const char *name,
                                   const hlod_logger *lg);

/* Checks a header as the reader does at open, before the node table:
 * magic, byte order, version, record sizes, checksum, file_size equal to
 * file_size, reserved fields, codec and position grid, the node table
 * inside the file, finite numbers.  The first problem is logged through
 * lg prefixed with `name`.  HLOD_OK, HLOD_ERR_FORMAT, HLOD_ERR_VERSION,
 * HLOD_ERR_UNSUPPORTED, HLOD_ERR_CHECKSUM or HLOD_ERR_NAN.  (hlod-merge
 * checks the stores inside part files with it.) */
hlod_result hlod_store_check_header(const hlod_store_header *h, uint64_t file_size,
                                   const char *name, const hlod_logger *lg);

/* ---- reader ---- */

typedef struct hlod_store hlod_store;

/* Opens and validates a store: path is a file, or an http:// or https://
 * URL read with range requests (docs/http.md): the
 * header and the node table are fetched once, validated exactly as a
 * file's, and every later request carries If-Range with the validator
 * (ETag, else Last-Modified) of the first, so a store replaced on the
 * server fails its reads (HLOD_ERR_VERSION, logged once) instead of mixing
 * two versions; a server that ignores ranges is refused at open
 * (HLOD_ERR_UNSUPPORTED), as is any HTTP error status (HLOD_ERR_IO, the
 * URL and status logged).  Transient failures are retried with backoff.
 * Either way it checks the header (magic, endianness, version, sizes,
 * checksum, file size), then the node table (checksum and
 * hlod_store_validate).  Payloads are checked when read.  lg is copied and
 * used for this call and for later payload reads from any thread (so its
 * callback must be thread safe when several threads read); it may be NULL.
 * Results: HLOD_ERR_IO (cannot open/read), HLOD_ERR_FORMAT (not a store,
 * truncated, inconsistent), HLOD_ERR_VERSION, HLOD_ERR_UNSUPPORTED (byte
 * order), HLOD_ERR_CHECKSUM, HLOD_ERR_NAN, HLOD_ERR_NOMEM.  Costs one
 * header read and one node-table read.  *out is NULL on failure. */
hlod_result hlod_store_open(const char *path, const hlod_logger *lg, hlod_store **out);
void hlod_store_close(hlod_store *s);   /* s may be NULL; no reads may be in flight */

/* Read-only views, valid until hlod_store_close.  nodes has node_count + 1
 * records (the sentinel last).  Any thread. */
const hlod_store_header *hlod_store_get_header(const hlod_store *s);
const hlod_store_node *hlod_store_nodes(const hlod_store *s);
/* node_count records of the extras table, or NULL when the store has none
 * (stores before version 4, or built without). */
const hlod_store_extra *hlod_store_extras(const hlod_store *s);
uint32_t hlod_store_node_count(const hlod_store *s);
uint32_t hlod_store_root_count(const hlod_store *s);
uint32_t hlod_store_block_count(const hlod_store *s);
/* Nodes [0, top_count): the groups and the blocks' hlod_0 nodes. */
uint32_t hlod_store_top_count(const hlod_store *s);
/* The first block's hlod_0 node: top_count - block_count. */
uint32_t hlod_store_first_block(const hlod_store *s);
const char *hlod_store_path(const hlod_store *s);
/* 1 when s was opened from an http:// or https:// URL. */
int hlod_store_is_remote(const hlod_store *s);

/* The sum of hlod_store_node_memory over the store's nodes: what the whole
 * store takes in memory (header.payload_bytes is what it takes on disk). */
uint64_t hlod_store_memory_bytes(const hlod_store *s);


/* A node's payload in memory, ready to upload: one allocation (memory, bytes)
 * holding the payload as stored; the pointers point into it.  Owned by
 * whoever received it; free with hlod_store_payload_free() from any thread. */
typedef struct hlod_store_payload {
    uint32_t node;
    uint32_t flags;             /* HLOD_NODE_* */
    uint32_t vertex_count, index_count, tex_tri_count;
    uint32_t tex_width, tex_height, tex_channels;
    const float *positions;     /* 3 * vertex_count, relative to nodes[node].origin */
    const float *normals;       /* 3 * vertex_count or NULL */
    const float *uvs;           /* 2 * vertex_count or NULL */
    const uint8_t *colors;      /* 4 * vertex_count or NULL */
    const uint32_t *indices;    /* index_count, each < vertex_count */
    const uint8_t *pixels;      /* w * h * channels or NULL */
    void *memory;
    size_t bytes;
    /* 0: pixels is the stored texture, one level.  Else pixels holds the
     * mip chain, tex_levels levels one after another, in tex_memory (its
     * own allocation): texels the engine's loader made (engine/texture.h)
     * or took from stored blocks (HLOD_TEXOUT_CHAIN), or the stored blocks
     * themselves (tex_format, HLOD_TEXOUT_BLOCKS). */
    uint32_t tex_levels;
    void *tex_memory;
    /* HLOD_TEXFMT_*: what pixels holds.  Blocks keep the stored channels
     * (tex_channels 3: BC1, 1: BC4); a texel chain from BC1 has 4 (RGBA). */
    uint32_t tex_format;
} hlod_store_payload;

/* hlod_store_payload.tex_format */
#define HLOD_TEXFMT_TEXELS 0u   /* tex_channels bytes a texel */
#define HLOD_TEXFMT_BC 1u       /* 8-byte 4x4 blocks: BC1 (3 channels) or BC4 (1) */

/* What hlod_store_read_finish_as makes of a block-coded (HLOD_TEX_BC)
 * texture; other textures come as level 0 texels in every mode. */
#define HLOD_TEXOUT_PIXELS 0    /* level 0 as texels, the raw layout's pixels
                                   (what hlod_store_read_finish gives) */
#define HLOD_TEXOUT_CHAIN 1     /* the whole chain as texels (RGBA from BC1,
                                   grey from BC4): a GL without the blocks */
#define HLOD_TEXOUT_BLOCKS 2    /* the stored blocks, the whole chain: a GL
                                   that samples them (glCompressedTexImage2D) */

void hlod_store_payload_free(hlod_store_payload *p);   /* p may be zeroed */

/* An incremental payload read, owned by one thread at a time (the loader).
 * Usage:
 *     hlod_store_read rd;
 *     hlod_store_read_begin(s, node, &rd);
 *     while (!rd_complete) hlod_store_read_step(&rd, 65536, &rd_complete);
 *     hlod_store_read_finish(&rd, &payload);
 * Each step reads at most max_bytes (pread, continued over short reads)
 * and hashes them; the bytes read stay read, so a read may be left for
 * another node's read and resumed later without re-reading.  A read that is
 * not finished must be cancelled.  Fields are read-only to the caller. */
typedef struct hlod_store_read {
    const hlod_store *store;
    uint32_t node;
    uint64_t size;              /* payload bytes */
    uint64_t done;              /* bytes read so far */
    uint8_t *buf;               /* size bytes, owned by the read */
    void *hash_state;           /* XXH3 streaming state */
} hlod_store_read;

/* Allocates the payload buffer (payload_size bytes, validated at open to
 * lie inside the file).  HLOD_ERR_INVALID_ARG for a bad node index,
 * HLOD_ERR_NOMEM.  On failure rd is zeroed. */
hlod_result hlod_store_read_begin(const hlod_store *s, uint32_t node, hlod_store_read *rd);

/* Reads up to max_bytes (>= 1) more; *complete becomes non-zero when all
 * bytes are in.  A short pread (fewer bytes than asked, as from a pipe-like
 * file system or a signal) is continued within the step, and EINTR is
 * retried, so a step returns HLOD_OK having read exactly
 * min(max_bytes, bytes left).  HLOD_ERR_IO on a read error or when the file
 * ended early (it shrank after open).  After an error the read must be
 * cancelled. */
hlod_result hlod_store_read_step(hlod_store_read *rd, size_t max_bytes, int *complete);

/* Verifies the checksum (HLOD_ERR_CHECKSUM), then parses: header and counts
 * against the node table, sizes, flags (HLOD_ERR_FORMAT), finite positions,
 * normals and UVs (HLOD_ERR_NAN), indices < vertex_count
 * (HLOD_ERR_INDEX_RANGE).  On success the buffer moves into *out (zero
 * copy); on failure it is freed and *out zeroed.  Either way rd ends zeroed.
 * O(payload size). */
hlod_result hlod_store_read_finish(hlod_store_read *rd, hlod_store_payload *out);

/* hlod_store_read_finish, with a block-coded texture made into what texout
 * (HLOD_TEXOUT_*) asks.  With CHAIN or BLOCKS the payload's memory holds no
 * level-0 texels: the texture lives in tex_memory. */
hlod_result hlod_store_read_finish_as(hlod_store_read *rd, int texout, hlod_store_payload *out);

/* Abandons a read and frees its buffer (rd may be zeroed). */
void hlod_store_read_cancel(hlod_store_read *rd);

/* begin + steps of max_bytes + finish, for tools and tests. */
hlod_result hlod_store_read_node(const hlod_store *s, uint32_t node, size_t max_bytes,
                                 hlod_store_payload *out);

/* hlod_store_read_node and hlod_store_read_nodes, a block-coded texture
 * made what texout asks (hlod_store_read_finish_as). */
hlod_result hlod_store_read_node_as(const hlod_store *s, uint32_t node, size_t max_bytes,
                                    int texout, hlod_store_payload *out);
hlod_result hlod_store_read_nodes_as(const hlod_store *s, uint32_t first, uint32_t count,
                                     size_t max_bytes, int texout, hlod_store_payload *out,
                                     hlod_result *results);

/* Reads nodes [first, first + count) into out[i] with result results[i]
 * (as hlod_store_read_node each); a URL's with 8 parallel transfers.
 * HLOD_ERR_INVALID_ARG for a bad range, HLOD_ERR_NOMEM. */
hlod_result hlod_store_read_nodes(const hlod_store *s, uint32_t first, uint32_t count,
                                  size_t max_bytes, hlod_store_payload *out,
                                  hlod_result *results);

/* The local payload cache of a store opened from a URL (env HLOD_CACHE_DIR,
 * engine/common/store_http.h; no-ops for a file or without it).  get: rd
 * just begun (nothing read) is filled from its entry when that entry's size
 * and checksum match the node table (then rd->done == rd->size, hashed, and
 * 1 is returned); a damaged entry is deleted (0: read it as usual).  put: a
 * complete read whose checksum matches is written as the node's entry
 * (temporary file, then rename).  hlod_store_read_node(s) use both; the
 * loader uses them on its own thread. */
int hlod_store_cache_get(hlod_store_read *rd);
void hlod_store_cache_put(const hlod_store_read *rd);

/* ---- parallel reads of a store opened from a URL ---- */

/* Up to `transfers` range requests in flight at once (curl multi, one
 * persistent connection each), owned by one thread (the loader).  A
 * transfer appends to an hlod_store_read exactly as hlod_store_read_step
 * does (bytes in stay read, hashed in order), so a read may be stopped
 * (a more urgent node preempts it) and started again later from `done`
 * with a new range, or stepped, once no transfer holds it.  While one
 * does, the read must not move, be stepped, finished or cancelled. */
typedef struct hlod_store_fetch hlod_store_fetch;

typedef struct hlod_store_fetch_end {
    hlod_store_read *rd;
    hlod_result result;     /* HLOD_OK: its range is in (rd->done moved on);
                               else after retries: HLOD_ERR_IO (transient),
                               HLOD_ERR_VERSION (the store changed), ... */
} hlod_store_fetch_end;

/* HLOD_ERR_UNSUPPORTED for a store read from a file. */
hlod_result hlod_store_fetch_create(const hlod_store *s, unsigned transfers,
                                    hlod_store_fetch **out);
void hlod_store_fetch_destroy(hlod_store_fetch *f);     /* stops every transfer */
/* Starts a transfer of rd's next min(max_bytes, size - done) bytes;
 * HLOD_ERR_INVALID_ARG when rd is complete or held, or all are busy.  The
 * test latency applies before it is sent. */
hlod_result hlod_store_fetch_start(hlod_store_fetch *f, hlod_store_read *rd, uint64_t max_bytes);
/* Stops rd's transfer, if any: what came stays in rd. */
void hlod_store_fetch_stop(hlod_store_fetch *f, hlod_store_read *rd);
int hlod_store_fetch_has(const hlod_store_fetch *f, const hlod_store_read *rd);
unsigned hlod_store_fetch_active(const hlod_store_fetch *f);
/* Runs the transfers up to timeout_ms, back earlier when one ends or
 * wake_fd (-1: none) turns readable; writes up to max ended transfers to
 * out, returns how many; *bytes (may be NULL): bytes that came meanwhile. */
size_t hlod_store_fetch_poll(hlod_store_fetch *f, int timeout_ms, int wake_fd,
                             hlod_store_fetch_end *out, size_t max, uint64_t *bytes);

/* ---- test hook (fault injection; not for production use) ---- */

/* A latency added before every HTTP request of s (ms; the environment's
 * HLOD_HTTP_LATENCY_MS sets it at open).  No effect on a file. */
void hlod_store_set_http_latency(hlod_store *s, double ms);


/* The function payload reads call instead of pread(2): same contract (bytes
 * read, 0 at end of file, -1 with errno set on error).  Tests use it to
 * inject short reads, EINTR and errors behind the reader; user is passed
 * back.  fn NULL restores pread.  Only payload reads (read_step) go through
 * it, not hlod_store_open.  Set it before any read starts (e.g. before an
 * engine is created on s) and not while reads are in flight: it is a plain
 * field, read without synchronisation by every reading thread.  fn itself
 * must be thread safe when several threads read. */
typedef ssize_t (*hlod_store_pread_fn)(void *user, int fd, void *buf, size_t n, off_t off);
void hlod_store_set_pread(hlod_store *s, hlod_store_pread_fn fn, void *user);

#ifdef __cplusplus
}
#endif
#endif
