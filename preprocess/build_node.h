/*
 * build_node.h - what a single build (build_store.c) and a merge of
 * sharded parts (part.c) both make: a node's payload, a group node, the
 * boxes that hold their descendants.  Private to preprocess/.
 */
#ifndef HLOD_BUILD_NODE_H
#define HLOD_BUILD_NODE_H

#include "city_levels.h"
#include "hlod/build_store.h"
#include "hlod/store_write.h"

/* Adds mesh m's payload to the store: its own texture tex for its first
 * tex_tris triangles, per-vertex colours (colors, or rgba for every
 * vertex) for the rest, area-weighted normals where m has none; fills
 * node's payload fields. */
hlod_result hlod_build_add_payload(hlod_store_writer *w, const hlod_mesh *m, const hlod_image *tex,
                                   size_t tex_tris, const uint8_t *colors, const uint8_t rgba[4],
                                   hlod_store_node *node);
/* A group node's payload, error, render flags, no block and no parent. */
hlod_result hlod_build_add_group(hlod_store_writer *w, const hlod_city_item *g,
                                 hlod_store_node *node);
/* Refuses (HLOD_ERR_NAN, logged naming path and the vertex) a mesh with a
 * coordinate beyond HLOD_BUILD_MAX_COORD or not finite. */
hlod_result hlod_build_check_coords(const hlod_mesh *m, const char *path, const hlod_logger *lg);
/* Grows each of the total nodes' boxes to hold its descendants' boxes. */
void hlod_build_contain(hlod_store_node *all, size_t total);
/* A group node's triangle target, and the number of children a group
 * gathers, for descriptor d. */
size_t hlod_build_group_tris(const hlod_build_desc *d);
size_t hlod_build_group_size(const hlod_build_desc *d);

#endif
