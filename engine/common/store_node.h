/*
 * store_node.h - a payload header's counts against its node record
 * (store_node.c).  Private to the store's reader and codec.
 */
#ifndef HLOD_STORE_NODE_H
#define HLOD_STORE_NODE_H

#include "hlod/store.h"

/* Whether a payload header's counts (the fields raw and packed headers
 * share) are node n's. */
int hlod_store_counts_agree(const hlod_store_node *n, uint32_t flags, uint32_t vertex_count,
                            uint32_t index_count, uint32_t tex_tri_count, uint32_t tex_width,
                            uint32_t tex_height, uint32_t tex_channels);

#endif
