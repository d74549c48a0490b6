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
 * the texture as JPEG (libturbojpeg) when it has 1 or 3 channels.
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
} hlod_packed_input;

/* Encodes in into a new malloc'ed buffer (*out, *out_size bytes: the packed
 * header and its sections).  HLOD_ERR_INVALID_ARG when a vertex lies more
 * than 2^32 - 1 grid steps from another on some axis (logged with name),
 * HLOD_ERR_NOMEM, HLOD_ERR_FORMAT when the JPEG encoder fails. */
hlod_result hlod_payload_pack(const hlod_packed_input *in, uint8_t **out, size_t *out_size,
                              const char *name, const hlod_logger *lg);

/* Decodes a packed payload of node `node` (table record n) of a store whose
 * grid step is quant_step into a new malloc'ed raw-layout buffer of exactly
 * hlod_store_node_memory(n) bytes (*out).  HLOD_ERR_FORMAT (logged with name
 * and node) for any inconsistency, HLOD_ERR_NOMEM. */
hlod_result hlod_payload_unpack(const uint8_t *buf, size_t size, const hlod_store_node *n,
                                uint32_t node, double quant_step, uint8_t **out,
                                const char *name, const hlod_logger *lg);

/* The octahedral normal codec pack and unpack use (exposed for tests). */
void hlod_oct_encode(const float n[3], int16_t out[2]);
void hlod_oct_decode(const int16_t in[2], float n[3]);

#endif
