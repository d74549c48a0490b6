/*
 * store_node.c - what a node record says of its payload: its size and
 * memory, its cost, whether a payload header agrees with it (hlod/store.h,
 * store_node.h).  The reader (store_read.c) and the payload codec
 * (payload_codec.c) both check payloads against these.
 */
#include "hlod/store.h"

#include "store_node.h"

double hlod_store_cost(uint32_t tex_tris, uint32_t untex_tris, double c_tex)
{
    return (double)tex_tris * c_tex + (double)untex_tris * (1.0 - c_tex);
}

uint64_t hlod_store_payload_size(uint32_t flags, uint32_t vertex_count, uint32_t index_count,
                                 uint32_t tex_width, uint32_t tex_height, uint32_t tex_channels)
{
    if (flags & ~HLOD_NODE_ALL_FLAGS)
        return 0;
    int textured = (flags & HLOD_NODE_TEXTURE) != 0;
    if (textured) {
        if (!(flags & HLOD_NODE_UVS) || tex_width == 0 || tex_height == 0 ||
            tex_width > HLOD_STORE_MAX_TEXTURE || tex_height > HLOD_STORE_MAX_TEXTURE ||
            tex_channels < 1 || tex_channels > 4)
            return 0;
    } else if (tex_width || tex_height || tex_channels) {
        return 0;
    }
    /* counts are below 2^32 and the texture below 2^34 bytes: no overflow */
    uint64_t v = vertex_count;
    uint64_t size = sizeof(hlod_store_payload_header) + 12 * v + 4 * (uint64_t)index_count;
    if (flags & HLOD_NODE_NORMALS)
        size += 12 * v;
    if (flags & HLOD_NODE_UVS)
        size += 8 * v;
    if (flags & HLOD_NODE_COLORS)
        size += 4 * v;
    if (textured)
        size += (uint64_t)tex_width * tex_height * tex_channels;
    return size;
}

int hlod_store_counts_agree(const hlod_store_node *n, uint32_t flags, uint32_t vertex_count,
                            uint32_t index_count, uint32_t tex_tri_count, uint32_t tex_width,
                            uint32_t tex_height, uint32_t tex_channels)
{
    return flags == n->flags && vertex_count == n->vertex_count &&
           index_count == 3 * (uint64_t)n->tri_count && tex_tri_count == n->tex_tri_count &&
           tex_width == n->tex_width && tex_height == n->tex_height &&
           tex_channels == n->tex_channels;
}

uint64_t hlod_store_node_memory(const hlod_store_node *n)
{
    return hlod_store_payload_size(n->flags, n->vertex_count, 3 * n->tri_count, n->tex_width,
                                   n->tex_height, n->tex_channels);
}
