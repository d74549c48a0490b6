/*
 * build_node.c - store nodes as a build and a merge both make them
 * (build_node.h).
 */
#include "build_node.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Adds one node's payload: the mesh, its texture on triangles [0,
 * tex_tris) when tex has pixels, per-vertex colours (colors, or rgba for
 * every vertex) when some triangle is untextured, area-weighted normals
 * when the mesh has none. */
hlod_result hlod_build_add_payload(hlod_store_writer *w, const hlod_mesh *m, const hlod_image *tex,
                                  size_t tex_tris, const uint8_t *colors, const uint8_t rgba[4],
                                  hlod_store_node *node)
{
    double lo[3], hi[3];
    hlod_mesh_bounds(m, lo, hi);
    hlod_store_payload_desc d = {0};
    d.vertex_count = (uint32_t)m->vertex_count;
    d.positions = m->positions;
    for (int a = 0; a < 3; a++)
        d.origin[a] = 0.5 * (lo[a] + hi[a]);
    float *normals = NULL;
    uint8_t *own = NULL;
    if (m->normals) {
        d.normals = m->normals;
    } else {
        normals = malloc((m->vertex_count * 3 + 1) * sizeof *normals);
        if (!normals || hlod_mesh_vertex_normals(m, normals) != HLOD_OK) {
            free(normals);
            return HLOD_ERR_NOMEM;
        }
        d.normals = normals;
    }
    d.tri_count = (uint32_t)m->tri_count;
    d.indices = m->indices;
    if (!(tex && tex->width && m->uvs))
        tex_tris = 0;
    if (tex_tris) {
        d.uvs = m->uvs;
        d.tex_tri_count = (uint32_t)tex_tris;
        d.tex_width = (uint32_t)tex->width;
        d.tex_height = (uint32_t)tex->height;
        d.tex_channels = (uint32_t)tex->channels;
        d.pixels = tex->pixels;
    }
    if (tex_tris < m->tri_count) {
        if (!colors) {
            own = malloc(m->vertex_count * 4 + 1);
            if (!own) {
                free(normals);
                return HLOD_ERR_NOMEM;
            }
            for (size_t v = 0; v < m->vertex_count; v++)
                memcpy(own + 4 * v, rgba, 4);
        }
        d.colors = colors ? colors : own;
    }
    hlod_result r = hlod_store_writer_add(w, &d, node);
    free(normals);
    free(own);
    return r;
}

hlod_result hlod_build_add_group(hlod_store_writer *w, const hlod_city_item *g,
                                 hlod_store_node *node)
{
    hlod_result r = hlod_build_add_payload(w, &g->mesh, &g->tex, g->tex_tris, g->colors, g->color,
                                           node);
    if (r != HLOD_OK)
        return r;
    node->error = g->error;
    node->render_flags = g->solid ? HLOD_RENDER_SOLID : 0;
    node->block = HLOD_STORE_NO_BLOCK;
    node->parent = HLOD_STORE_NO_PARENT;
    return HLOD_OK;
}

size_t hlod_build_group_tris(const hlod_build_desc *d)
{
    return d->method == HLOD_BUILD_METIS ? d->node_tris : d->desired_tris;
}

size_t hlod_build_group_size(const hlod_build_desc *d)
{
    return (size_t)llround(d->level_factor * d->level_factor);
}

/* Each node's box grows to hold its descendants' boxes.  A node's
 * content is simplified, and simplification may drop or shrink a part
 * (a tower's top, a building next to a street): a box of its own content
 * alone would let the runtime cull the node, and its whole subtree with
 * it, while its children's content is in view, and 3D Tiles requires a
 * child's content inside its parent's volume.  Parents are global indices
 * in any order, so each box is carried up its whole chain of ancestors
 * (n x depth steps). */
void hlod_build_contain(hlod_store_node *all, size_t total)
{
    for (size_t i = 0; i < total; i++) {
        const hlod_store_node *c = &all[i];
        size_t guard = 0;
        for (uint32_t p = c->parent; p != HLOD_STORE_NO_PARENT && p < total && guard++ < total;
             p = all[p].parent)
            for (int k = 0; k < 3; k++) {
                all[p].bbox_min[k] = fmin(all[p].bbox_min[k], c->bbox_min[k]);
                all[p].bbox_max[k] = fmax(all[p].bbox_max[k], c->bbox_max[k]);
            }
    }
}

/* A coordinate past HLOD_BUILD_MAX_COORD, named with its file. */
hlod_result hlod_build_check_coords(const hlod_mesh *m, const char *path, const hlod_logger *lg)
{
    for (size_t v = 0; v < m->vertex_count; v++)
        for (int k = 0; k < 3; k++)
            if (!(fabs(m->positions[3 * v + k]) <= HLOD_BUILD_MAX_COORD)) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: vertex %zu: coordinate %c = %g is beyond "
                          "+-%g, which a store cannot hold", path, v, "xyz"[k],
                          m->positions[3 * v + k], HLOD_BUILD_MAX_COORD);
                return HLOD_ERR_NAN;
            }
    return HLOD_OK;
}
