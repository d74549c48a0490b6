/* Pieces every hierarchy builder shares: the tree container, node textures
 * and node errors (see build.h). */
#include "build.h"

#include "hlod/distance.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

void hlod_btree_free(hlod_btree *t)
{
    if (!t)
        return;
    for (size_t i = 0; i < t->count; i++) {
        hlod_mesh_free(&t->nodes[i].mesh);
        hlod_image_free(&t->nodes[i].tex);
    }
    free(t->nodes);
    memset(t, 0, sizeof *t);
}

uint32_t hlod_btree_add(hlod_btree *t)
{
    if (t->count == t->cap) {
        size_t nc = t->cap ? t->cap * 2 : 16;
        hlod_bnode *n = realloc(t->nodes, nc * sizeof *n);
        if (!n)
            return HLOD_BNODE_NONE;
        t->nodes = n;
        t->cap = nc;
    }
    memset(&t->nodes[t->count], 0, sizeof t->nodes[t->count]);
    t->nodes[t->count].parent = HLOD_BNODE_NONE;
    return (uint32_t)t->count++;
}

hlod_result hlod_node_texture(const hlod_image *tex, hlod_mesh *m, double factor, hlod_image *out)
{
    memset(out, 0, sizeof *out);
    if (!tex || !tex->width || !tex->pixels || !m->uvs || !m->vertex_count)
        return HLOD_OK;
    if (!(factor >= 1))
        factor = 1;
    /* UV box of the node; a node whose UVs wrap keeps the whole image. */
    float lo[2] = {m->uvs[0], m->uvs[1]}, hi[2] = {m->uvs[0], m->uvs[1]};
    for (size_t v = 1; v < m->vertex_count; v++)
        for (int k = 0; k < 2; k++) {
            float u = m->uvs[2 * v + k];
            lo[k] = u < lo[k] ? u : lo[k];
            hi[k] = u > hi[k] ? u : hi[k];
        }
    int x0 = 0, y0 = 0, x1 = tex->width, y1 = tex->height;
    if (lo[0] >= 0 && lo[1] >= 0 && hi[0] <= 1 && hi[1] <= 1) {
        /* v = 0 is the image's bottom row (OpenGL convention), rows are
         * stored top first; one texel of margin for bilinear filtering */
        x0 = (int)floor(lo[0] * tex->width) - 1;
        x1 = (int)ceil(hi[0] * tex->width) + 1;
        y0 = (int)floor((1 - hi[1]) * tex->height) - 1;
        y1 = (int)ceil((1 - lo[1]) * tex->height) + 1;
        x0 = x0 < 0 ? 0 : x0;
        y0 = y0 < 0 ? 0 : y0;
        x1 = x1 > tex->width ? tex->width : x1;
        y1 = y1 > tex->height ? tex->height : y1;
        if (x1 <= x0 || y1 <= y0) {
            x0 = y0 = 0;
            x1 = tex->width;
            y1 = tex->height;
        }
    }
    int cw = x1 - x0, ch = y1 - y0, c = tex->channels;
    hlod_image crop = {cw, ch, c, malloc((size_t)cw * ch * c)};
    if (!crop.pixels)
        return HLOD_ERR_NOMEM;
    for (int y = 0; y < ch; y++)
        memcpy(crop.pixels + (size_t)y * cw * c, tex->pixels + ((size_t)(y0 + y) * tex->width + x0) * c,
               (size_t)cw * c);
    /* UVs into the crop */
    if (cw != tex->width || ch != tex->height) {
        for (size_t v = 0; v < m->vertex_count; v++) {
            float *uv = m->uvs + 2 * v;
            uv[0] = (float)((uv[0] * tex->width - x0) / cw);
            uv[1] = (float)((uv[1] * tex->height - (tex->height - y1)) / ch);
        }
    }
    /* Lakhia III-A: texture shrinks with the triangle count (per side, the
     * square root of the simplification factor). */
    double s = 1 / sqrt(factor);
    int w = (int)lround(cw * s), h = (int)lround(ch * s);
    w = w < 4 ? (cw < 4 ? cw : 4) : w;
    h = h < 4 ? (ch < 4 ? ch : 4) : h;
    if (w == cw && h == ch) {
        *out = crop;
        return HLOD_OK;
    }
    hlod_result r = hlod_image_resize(&crop, w, h, out);
    hlod_image_free(&crop);
    return r;
}

hlod_result hlod_node_error(const hlod_mesh *node, const hlod_mesh *original, double *error)
{
    *error = 0;
    if (!node->tri_count || !original->tri_count)
        return HLOD_OK;
    double lower, upper;
    /* 25% and 1e-3 of the size: node errors steer refinement, where a
     * looser bound costs a little detail and a tight one costs build time
     * (coincident flat walls cost the most to resolve) */
    hlod_result r = hlod_mesh_hausdorff_bound(node, original, 0.25, 1e-3 * hlod_mesh_bbox_diag(original), &lower,
                                              &upper);
    if (r == HLOD_OK)
        *error = upper;
    return r;
}
