/*
 * store_write.h - writing an HLOD store (format: store.h).  Preprocess side.
 *
 * A builder makes nodes in any order, on any number of threads, and knows
 * the final tree only at the end.  So:
 *
 *   hlod_store_writer *w;
 *   hlod_store_writer_open("city.hlod", &desc, &w);
 *   // any thread, any order, as each node's mesh is ready:
 *   hlod_store_writer_add(w, &payload, &my_nodes[k]);   // fills my_nodes[k]
 *   // the owner, after every add has returned:
 *   my_nodes[k].parent = index of k's parent in my_nodes, or HLOD_STORE_NO_PARENT;
 *   my_nodes[k].block = block id (roots only; 0 .. blocks-1, one root each),
 *                       or HLOD_STORE_NO_BLOCK for a group node (city levels);
 *   my_nodes[k].error = geometric error (>= each child's);
 *   hlod_store_writer_finish(w, my_nodes, count, final_index);  // or _abort(w)
 *
 * Each payload is written to the file as soon as it is added (pwrite at an
 * offset reserved under a mutex), so memory holds one payload per adding
 * thread and a small record per node: a store may be larger than RAM.
 * finish puts the nodes in breadth-first order, computes first_child, depth
 * and the non-root blocks, writes the node table after the last payload and
 * the header at the start, validates everything as the reader will
 * (hlod_store_validate), then fsyncs and renames the temporary file
 * "PATH.tmp-XXXXXX" over PATH.  On any failure, or abort, the temporary
 * file is removed: PATH is never partial and an existing PATH is untouched.
 *
 * Thread rules: open, finish and abort belong to one thread (the owner);
 * add may be called from any threads concurrently, each with its own
 * hlod_store_node to fill, until finish or abort is called.
 */
#ifndef HLOD_STORE_WRITE_H
#define HLOD_STORE_WRITE_H

#include "hlod/store.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hlod_store_writer hlod_store_writer;

typedef struct hlod_store_writer_desc {
    hlod_store_build_info build;    /* recorded in the header; build.c_tex
                                       prices every node (eq. 1) */
    uint32_t payload_align;         /* 0: HLOD_STORE_DEFAULT_ALIGN (4096) */
    /* Packed payloads (store.h, docs/store-format.md) when quant_step > 0:
     * positions on the grid quant_origin + integer * quant_step (a power of
     * two, model units), meshoptimizer-coded geometry, JPEG textures at
     * jpeg_quality (1..100; 0 keeps textures raw).  quant_step 0: the raw
     * layout (no quantization, quant_origin and jpeg_quality unused). */
    double quant_step;
    double quant_origin[3];
    uint32_t jpeg_quality;
    /* packed: 1 stores a texture of 1 or 3 channels as block-coded mips
     * (BC1/BC4 and zstd, docs/store-format.md) when their level 0 reaches
     * texture_min_db dB against the texture given, else as JPEG at
     * jpeg_quality (raw at 0); 0: JPEG or raw as jpeg_quality says. */
    uint32_t texture_blocks;
    double texture_min_db;
    /* 1: every node added gets the colour cube of its own mesh in the
     * extras table (HLOD_EXTRA_CUBE; a copy keeps its source's), for the
     * runtime's far_cubes (docs/cubes.md, "Cubes as stand-ins"); 0: none
     * unless hlod_store_writer_set_cubes gives them. */
    uint32_t cubes;
    const hlod_logger *logger;      /* may be NULL; must outlive the writer
                                       and be thread safe if add is called
                                       from several threads */
} hlod_store_writer_desc;

/* One node's geometry.  The arrays are read during the call only. */
typedef struct hlod_store_payload_desc {
    uint32_t vertex_count;          /* >= 1 */
    const double *positions;        /* 3 * vertex_count, world coordinates */
    double origin[3];               /* stored positions are (float)(p - origin);
                                       pick a point near the node (e.g. its
                                       box centre) so floats keep precision */
    const float *normals;           /* 3 * vertex_count or NULL */
    const float *uvs;               /* 2 * vertex_count or NULL (required
                                       with a texture) */
    const uint8_t *colors;          /* 4 * vertex_count RGBA or NULL */
    uint32_t tri_count;             /* >= 1 */
    const uint32_t *indices;        /* 3 * tri_count, each < vertex_count */
    uint32_t tex_tri_count;         /* the first tex_tri_count triangles use
                                       the texture; 0 without one */
    uint32_t tex_width, tex_height, tex_channels;   /* 0 without a texture */
    const uint8_t *pixels;          /* w * h * channels, top row first, or NULL */
} hlod_store_payload_desc;

/* Starts a store at path (a temporary file beside it).  desc may not be
 * NULL.  HLOD_ERR_INVALID_ARG for a bad alignment or c_tex, HLOD_ERR_IO. */
hlod_result hlod_store_writer_open(const char *path, const hlod_store_writer_desc *desc,
                                   hlod_store_writer **out);

/* called from any thread.  Validates p (HLOD_ERR_INVALID_ARG, HLOD_ERR_NAN,
 * HLOD_ERR_INDEX_RANGE), writes it (HLOD_ERR_IO, HLOD_ERR_NOMEM) and fills
 * *node (zeroed first) with everything the payload determines: flags, counts,
 * texture size, origin, bbox (of the double positions; of the quantized ones
 * in a packed store, whose origin is also snapped to the grid), cost (eq. 1),
 * static_benefit (eq. 2), avg_normal (eq. 3, area-weighted, in double) and
 * payload_offset/size/hash.  parent and error are left 0, block 0 and depth
 * 0: the caller sets parent, block (roots) and error before finish.  After
 * a write error the writer is failed: finish will refuse it. */
hlod_result hlod_store_writer_add(hlod_store_writer *w, const hlod_store_payload_desc *p,
                                  hlod_store_node *node);

/* called from any thread, as add: writes the payload of another store's
 * node as it is (bytes: src->payload_size bytes, checked against
 * src->payload_hash: HLOD_ERR_CHECKSUM) and fills *node with src's
 * fields, its payload offset this store's; parent, first_child, depth,
 * block and error are zeroed as add leaves them.  The two stores must
 * share the payload layout: quant_step, quant_origin and jpeg_quality
 * (hlod-merge copies the payloads of part files, docs/sharded-builds.md).
 * src_extra: src's extras record (its normal cone stands for the copied
 * faces'), or NULL: the node's faces are unbounded (no cone culling at or
 * above it). */
hlod_result hlod_store_writer_add_copy(hlod_store_writer *w, const hlod_store_node *src,
                                       const void *bytes, const hlod_store_extra *src_extra,
                                       hlod_store_node *node);

/* How the textures added so far were stored (packed stores; copies
 * included): block-coded, JPEG, raw, and the lowest PSNR measured among
 * the block-coded and JPEG ones (0 when none was measured).  Call when no
 * add is running. */
typedef struct hlod_store_texture_stats {
    uint64_t bc, jpeg, raw;
    double db_min;
} hlod_store_texture_stats;
void hlod_store_writer_texture_stats(const hlod_store_writer *w, hlod_store_texture_stats *out);

/* called from the owner thread after every add returned.  nodes[0..count)
 * in any order, each filled by add and then given its parent (an index into
 * nodes, or HLOD_STORE_NO_PARENT for a root), its error, and for roots its
 * block (roots must have blocks 0..R-1, each once).  Children keep the
 * relative order they have in nodes.  Group nodes (block =
 * HLOD_STORE_NO_BLOCK) sit above the blocks: a root or a group's child,
 * never a leaf; when the roots are groups they keep their order in nodes.
 * The nodes that are not groups but whose parent is one (or none) are the
 * blocks' hlod_0 nodes: they must share one depth (block_depth) and are
 * numbered as blocks in store order.  Every payload added must be used by
 * exactly one node.  first_child, depth and non-root blocks are computed
 * here (values passed are ignored).  When store_index is not NULL,
 * store_index[k] receives nodes[k]'s index in the store.  The writer is
 * freed whatever the result; on failure nothing appears at the path.
 * Results: HLOD_ERR_INVALID_ARG (tree or payload references inconsistent),
 * HLOD_ERR_FORMAT/HLOD_ERR_NAN (a rule of hlod_store_validate broken, e.g.
 * error not monotone), HLOD_ERR_IO, HLOD_ERR_NOMEM. */
hlod_result hlod_store_writer_finish(hlod_store_writer *w, const hlod_store_node *nodes,
                                     uint32_t count, uint32_t *store_index);

/* called from the owner thread before finish: colors[k] is the
 * representative colour (RGBA, sRGB) of the node finish will get as
 * nodes[k]; finish stores it in the extras table (HLOD_EXTRA_COLOR) and
 * refuses a count other than its own.  Copied; count 0 clears it.
 * HLOD_ERR_INVALID_ARG, HLOD_ERR_NOMEM. */
hlod_result hlod_store_writer_set_colors(hlod_store_writer *w, const uint8_t (*colors)[4],
                                         uint32_t count);

/* called from the owner thread before finish: cubes[k] holds the six
 * colour-cube faces (premultiplied RGBA8, +x -x +y -y +z -z) of the node
 * finish will get as nodes[k], made over that node's box; finish stores
 * them in the extras table (HLOD_EXTRA_CUBE) and refuses a count other
 * than its own.  Copied; count 0 clears it.  HLOD_ERR_INVALID_ARG,
 * HLOD_ERR_NOMEM. */
hlod_result hlod_store_writer_set_cubes(hlod_store_writer *w, const uint8_t (*cubes)[6][4],
                                        uint32_t count);

/* called from the owner thread: removes the temporary file, frees w
 * (NULL is fine).  No add may be in flight. */
void hlod_store_writer_abort(hlod_store_writer *w);

#ifdef __cplusplus
}
#endif
#endif
