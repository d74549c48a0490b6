/*
 * payload_codec.h - the packed payload layout of store format 3 (store.h,
 * docs/store-format.md): both directions in one place, so the writer and
 * the reader cannot drift apart.
 *
 * pack: the writer hands over a node's vertices already on the store's
 * position grid (integer steps from the node's origin), its normals, UVs,
 * colours, triangles and texture, in the order it wants them stored; pack
 * quantizes normals (octahedral, 2 x 16 bits) and UVs (2 x 16 bits over the
 * node's UV range), runs meshoptimizer's vertex and index codecs and encodes
 * a texture of 1 or 3 channels as block-coded mips (texture_codec.h) or as
 * JPEG (libturbojpeg).
 *
 * unpack: the reader (the loader thread) hands over a payload whose checksum
 * matched; unpack checks the packed header against the node table and every
 * section's size, decodes each section and returns the raw layout, which the
 * reader then validates as it validates a raw payload (finite numbers,
 * indices in range).  Bad bytes give HLOD_ERR_FORMAT, never a crash: the
 * codecs' decoders check their input, and the fuzz harness drives this.
 *
 * Reentrant; no global state (each call makes its own JPEG handle).
 */
#ifndef HLOD_PAYLOAD_CODEC_H
#define HLOD_PAYLOAD_CODEC_H

#include "hlod/store.h"

#include <stddef.h>
#include <stdint.h>

/* One node's data for pack.  grid[3 * i + k] is vertex i's coordinate k in
 * grid steps from the node's origin (the store's quant_step); the rest is as
 * in hlod_store_payload_desc. */
typedef struct hlod_packed_input {
    uint32_t flags;                 /* HLOD_NODE_* */
    uint32_t vertex_count, tri_count, tex_tri_count;
    const int64_t *grid;
    const float *normals;           /* 3 * vertex_count or NULL */
    const float *uvs;               /* 2 * vertex_count or NULL */
    const uint8_t *colors;          /* 4 * vertex_count or NULL */
    const uint32_t *indices;        /* 3 * tri_count */
    uint32_t tex_width, tex_height, tex_channels;
    const uint8_t *pixels;          /* or NULL */
    int jpeg_quality;               /* 1..100; 0: textures stored raw */
    /* 1: a texture of 1 or 3 channels is stored as blocks (HLOD_TEX_BC)
     * when their level 0 reaches texture_min_db against pixels; else as
     * JPEG (or raw without jpeg_quality), its PSNR measured too.  0: JPEG
     * or raw, unmeasured. */
    int texture_blocks;
    double texture_min_db;
} hlod_packed_input;

/* What pack stored for the texture. */
typedef struct hlod_packed_info {
    uint32_t tex_codec;             /* HLOD_TEX_*; 0 without a texture */
    double tex_db;                  /* the stored level 0's PSNR; 0: not measured */
} hlod_packed_info;

/* Encodes in into a new malloc'ed buffer (*out, *out_size bytes: the packed
 * header and its sections).  HLOD_ERR_INVALID_ARG when a vertex lies more
 * than 2^32 - 1 grid steps from another on some axis (logged with name),
 * HLOD_ERR_NOMEM, HLOD_ERR_FORMAT when the JPEG encoder fails. */
hlod_result hlod_payload_pack(const hlod_packed_input *in, uint8_t **out, size_t *out_size,
                              hlod_packed_info *info, const char *name, const hlod_logger *lg);

/* A decoded payload: the raw layout, and a texture kept apart from it. */
typedef struct hlod_unpacked {
    uint8_t *raw;                   /* malloc'ed raw layout */
    uint64_t raw_size;              /* hlod_store_node_memory(n), less the
                                       level-0 texels when tex is set */
    uint8_t *tex;                   /* malloc'ed mip chain, or NULL: the
                                       texels are in raw */
    uint32_t tex_levels, tex_format, tex_channels;  /* of tex (store.h's
                                       hlod_store_payload fields) */
} hlod_unpacked;

/* Decodes a packed payload of node `node` (table record n) of the store
 * with header h into *out.  A block-coded texture becomes what texout
 * (HLOD_TEXOUT_*) asks: level 0 texels inside raw (PIXELS), or a chain
 * apart in tex (CHAIN: texels, BLOCKS: the blocks); any other texture's
 * texels are inside raw.  HLOD_ERR_FORMAT (logged with name and node) for
 * any inconsistency, HLOD_ERR_NOMEM; *out is zeroed on failure. */
hlod_result hlod_payload_unpack(const uint8_t *buf, size_t size, const hlod_store_node *n,
                                uint32_t node, const hlod_store_header *h, int texout,
                                hlod_unpacked *out, const char *name, const hlod_logger *lg);

/* The octahedral normal codec pack and unpack use (exposed for tests). */
void hlod_oct_encode(const float n[3], int16_t out[2]);
void hlod_oct_decode(const int16_t in[2], float n[3]);

#endif
