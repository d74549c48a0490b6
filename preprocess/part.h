/*
 * part.h - part files of a sharded build and what build_store.c shares
 * with the merge (docs/sharded-builds.md).  Private to preprocess/.
 *
 * A part file is shard I of N of one build:
 *
 *   [0, 4096)        the part header (hlod_part_header), its own checksum
 *   [4096, +store)   a complete store of the shard's nodes (store.h): its
 *                    blocks' trees and the group nodes of the city levels
 *                    up to the cut level, whose nodes are its roots
 *   [tops, +size)    the part section, checksummed in the header: every
 *                    block's input box (the merge rebuilds the plan from
 *                    them), a key per store node (which block node or
 *                    group of the single build it is), and the shard's
 *                    cut-level nodes as the merge builds on them: meshes in
 *                    double, textures as pixels (the store's payloads are
 *                    quantized and JPEG-coded, the single build groups
 *                    from the originals)
 *
 * The cut level is the highest level of the plan with at least 4 N nodes
 * (else the blocks' level); shard I owns its nodes [floor((I-1) m / N),
 * floor(I m / N)) of m, each with its whole subtree.  Payloads are copied into the merged store as
 * they are, so the merge writes the single build's bytes.
 */
#ifndef HLOD_PART_H
#define HLOD_PART_H

#include "city_levels.h"
#include "hlod/build_store.h"
#include "hlod/store_write.h"

#define HLOD_PART_MAGIC "HLODPART"
#define HLOD_PART_VERSION 1u
#define HLOD_PART_STORE_OFFSET 4096u

typedef struct hlod_part_header {
    char magic[8];
    uint32_t version;
    uint32_t header_size;       /* sizeof(hlod_part_header) */
    uint32_t shard_index;       /* 1 .. shard_count */
    uint32_t shard_count;
    uint32_t cut_level;         /* the plan level whose nodes are shared out */
    uint32_t levels;            /* the plan's group levels */
    uint64_t cut_first, cut_end;/* this shard's cut-level nodes */
    uint64_t block_count;       /* the whole input's */
    uint64_t tris_in;           /* the whole input's triangles */
    uint64_t params_hash;       /* every parameter and the input's blocks */
    uint64_t plan_hash;         /* hlod_city_plan_hash */
    uint64_t group_tris, group_size;
    uint32_t jpeg_quality;
    uint32_t key_count;         /* = the part store's node count */
    uint64_t store_offset, store_size;
    uint64_t section_offset, section_size, section_hash;
    uint64_t file_size;
    double texture_min_db;      /* the writer's texture settings */
    uint32_t texture_blocks;
    uint32_t far_cubes;         /* the writer's cubes (hlod-build --far-cubes) */
    uint8_t reserved[40];
    uint64_t header_hash;       /* XXH3-64 of the bytes before it */
} hlod_part_header;

/* One store node of a part: block node k of block `id` (level 0), or
 * group `id` of `level`; `store` is its index in the part's store, error
 * its error as built (the store's adds the grid's quantization error, and
 * the merged store adds it once). */
typedef struct hlod_part_key {
    uint32_t store, level, id, k;
    double error;
} hlod_part_key;

/* A checksum of everything a part's bytes depend on besides its shard:
 * the descriptor's build parameters, the input's triangle count and every
 * block's box. */
uint64_t hlod_part_params_hash(const hlod_build_desc *d, size_t tris_in, size_t blocks,
                               const double (*lo)[3], const double (*hi)[3]);

/* Writes the part file at path (temporary file + rename) from the shard's
 * finished store at store_path (removed on success): h's fields other than
 * the offsets, sizes and hashes, every block's box, the keys in the order
 * of the store build (keys[j].store set), and the cut-level items
 * tops[cut_first .. cut_end) (NULL when the plan has no levels). */
hlod_result hlod_part_write(const char *path, const char *store_path, hlod_part_header *h,
                            const double (*lo)[3], const double (*hi)[3],
                            const hlod_part_key *keys, hlod_city_item *const *tops,
                            const hlod_logger *lg);

#endif
