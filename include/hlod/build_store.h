/*
 * build_store.h - meshes in, one HLOD store out: the pipeline of
 * hlod-build as a library call (docs/hlod-build.md).
 *
 *     hlod_build_desc d;
 *     hlod_build_desc_defaults(&d);
 *     d.method = HLOD_BUILD_METIS;
 *     const char *in[] = {"city.obj"};
 *     hlod_build_report rep;
 *     hlod_result r = hlod_build_store(&d, in, 1, "city.hlod", &logger, &rep);
 *
 * Each input object (or grid cell) becomes a block, split once more by
 * texture; blocks build in parallel and their nodes stream into the store
 * in block order, so the same inputs and settings give a byte-identical
 * store on any number of threads.  The store appears at out_path only when
 * complete; a failure leaves nothing there and an old store untouched.
 */
#ifndef HLOD_BUILD_STORE_H
#define HLOD_BUILD_STORE_H

#include "hlod/hlod.h"

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum hlod_build_method {
    HLOD_BUILD_CUTPLANE = 0,    /* Lakhia III-A */
    HLOD_BUILD_METIS = 1,       /* Okamoto 4.1 */
    HLOD_BUILD_SAMPLETREE = 2,  /* Klein 4-5: a randomized sample tree that
                                   refines additively (docs/sampletree.md) */
    HLOD_BUILD_CUBES = 3        /* Chamberlain 3-4: an octree of colour cubes,
                                   additive, every triangle where it sits
                                   (docs/cubes.md) */
} hlod_build_method;

/* The sample constant c of Klein's Theorem 1: p = exp(-exp(-c)) > 1 - 1e-6. */
#define HLOD_BUILD_SAMPLE_C 13.8
/* The sample tree's leaf size when none is given (hlod-build). */
#define HLOD_BUILD_SAMPLE_LEAF 256
/* The colour cubes' leaf size when none is given (hlod-build; docs/cubes.md). */
#define HLOD_BUILD_CUBES_LEAF 64

/* Input coordinates beyond this magnitude are refused (naming the file and
 * the vertex): past it a double no longer holds a tenth of a millimetre. */
#define HLOD_BUILD_MAX_COORD 1e12

typedef struct hlod_build_desc {
    hlod_build_method method;   /* default cutplane */
    double grid;                /* 0 (default): each input object is a block;
                                   else square cells of this size in x and y */
    size_t desired_tris;        /* C_desiredTri (cutplane); default 4000 */
    double level_factor;        /* C_levelFactor (cutplane), >= 2; default 3 */
    size_t voxel_tris;          /* N_v (metis); default 500 */
    size_t leaf_tris;           /* N_l (metis); default 4000; sampletree: a
                                   cell of more triangles splits */
    double sample_c;            /* sampletree: c of m_u = q ln q + c q, in
                                   (0, 1000]; default HLOD_BUILD_SAMPLE_C */
    size_t memory_mb;           /* sampletree: MiB the build may hold beside the
                                   input's vertices (docs/sampletree.md); 0
                                   (default): no limit, one bucket */
    size_t node_tris;           /* N_n (metis); default 2000 */
    double c_tex;               /* c_tex of Lakhia eq. 1, in [0, 1]; default 0.5 */
    int far_cubes;              /* cutplane, metis: non-zero gives every node
                                   the colour cube of its own mesh (the
                                   runtime's far_cubes, docs/cubes.md); default 0 */
    int cone_split;             /* cutplane: non-zero cuts the pieces within three
                                   levels of the leaves whose normals spread over
                                   45 degrees into orientation classes, so normal
                                   cones cull more (docs/hlod-build.md); default 0 */
    uint64_t seed;              /* every choice's seed; default 1 */
    int city_levels;            /* non-zero (default): group nodes over the
                                   blocks up to one root (docs/store-format.md); 0: every
                                   block is a root */
    size_t threads;             /* 0 (default): every core */
    int compress;               /* non-zero (default): packed payloads
                                   (docs/store-format.md); 0: raw payloads */
    unsigned quant_bits;        /* packed: the position grid's step is the
                                   largest power of two <= the input's
                                   diagonal / 2^quant_bits; 8..24 (a float
                                   holds every step of a node within 2^24),
                                   default 24 */
    unsigned jpeg_quality;      /* packed: JPEG quality of textures, 1..100,
                                   default 90; 0 stores textures raw */
    int texture_blocks;         /* packed: non-zero (default) stores textures
                                   of 1 or 3 channels as block-coded mips
                                   (docs/store-format.md) where they reach
                                   texture_min_db, the rest as JPEG; 0: all JPEG */
    double texture_min_db;      /* [0, 99], default 38 */
    /* A sharded build (docs/sharded-builds.md): shard_count 0 (default)
     * builds the whole store; 1..65536 builds only shard shard_index
     * (1..shard_count) and writes a part file at the output path instead of
     * a store, for hlod_merge_store. */
    uint32_t shard_index, shard_count;
    /* Called from the calling thread about every 100 ms while blocks
     * build; NULL for none. */
    void (*progress)(void *user, size_t blocks_done, size_t blocks);
    void *progress_user;
} hlod_build_desc;

typedef struct hlod_build_report {
    size_t blocks, nodes, levels;
    size_t tris_in;             /* triangles read */
    size_t tris_leaf;           /* triangles in leaves (the source's, split by blocks) */
    size_t tris_total;          /* triangles in all nodes */
    size_t groups;              /* group nodes above the blocks */
    size_t block_depth;         /* depth of the blocks' hlod_0 nodes */
    size_t buckets;             /* sampletree: subtrees built one at a time */
    uint64_t spill_bytes;       /* sampletree: written to the spill file */
    /* packed: textures stored as blocks, as JPEG, raw; the lowest PSNR
     * measured among the first two (0: none measured) */
    uint64_t textures_bc, textures_jpeg, textures_raw;
    double texture_db_min;
    /* wall seconds of each stage (hlod-build --json stage_seconds): reading
     * the input into blocks (sampletree, cubes: the first pass), building
     * and writing the blocks' trees (sampletree, cubes: the whole rest),
     * the city levels above them, the node table and the rename */
    double stage_read_s, stage_blocks_s, stage_levels_s, stage_finish_s;
    /* CPU seconds summed over the block threads (stage_cpu_seconds):
     * texture files read, the block trees (which include the next three),
     * the simplifier, the certified errors, the node atlases, and the
     * payloads encoded and written */
    double cpu_texture_read_s, cpu_tree_s, cpu_simplify_s, cpu_error_s, cpu_node_texture_s,
        cpu_store_s;
} hlod_build_report;

/* Every field set to its default (0 is a valid c_tex, so zero does not
 * mean "default" here). */
void hlod_build_desc_defaults(hlod_build_desc *d);

/* Builds the store.  Errors are logged (naming the file and the problem)
 * and returned: HLOD_ERR_INVALID_ARG for a descriptor value out of range
 * (those of hlod-build's flags), the importer's error for an unreadable
 * input, HLOD_ERR_IO for a missing output folder or a block that failed
 * (its own error is logged), HLOD_ERR_EMPTY for no triangles,
 * HLOD_ERR_NOMEM; report (may be NULL) is filled on success.  lg may be
 * called from the build threads at once: it must be thread-safe. */
hlod_result hlod_build_store(const hlod_build_desc *d, const char *const *inputs, size_t n,
                             const char *out_path, const hlod_logger *lg,
                             hlod_build_report *report);

/* ---- merging a sharded build's parts (docs/sharded-builds.md) ---- */

typedef struct hlod_merge_report {
    size_t parts, shards;
    size_t blocks, nodes;
    size_t cut_level;           /* the plan level shared out among the shards */
    size_t nodes_copied;        /* from the parts, payloads as they are */
    size_t groups_built;        /* the group nodes above the cut level */
} hlod_merge_report;

/* Merges the part files paths[0..n) (every shard of one build, each once,
 * in any order) into the store out_path: the bytes hlod_build_store writes
 * for the same inputs and parameters unsharded.  Every part is checked
 * (its checksums, its store's rules) and the set must be complete:
 * HLOD_ERR_INVALID_ARG names a missing or duplicate shard or parts of
 * different builds; HLOD_ERR_FORMAT, HLOD_ERR_CHECKSUM, HLOD_ERR_VERSION
 * name the damaged part.  The store appears only when complete (temporary
 * file + rename).  threads: for the levels above the shards (0: 1). */
hlod_result hlod_merge_store(const char *const *paths, size_t n, const char *out_path,
                             size_t threads, const hlod_logger *lg, hlod_merge_report *report);

#ifdef __cplusplus
}
#endif
#endif
