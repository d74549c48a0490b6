/*
 * store_fixture.h - small synthetic HLOD stores for engine tests.
 *
 * fixture_write() writes `roots` square blocks side by side along x, each
 * `size` wide, lying in the plane z = 0 and facing +z (up).  Every node is
 * a regular grid of grid x grid quads over its square; a node's children
 * are its four quadrants, down to `depth` levels below the root, so a
 * child has the same triangle count as its parent over a quarter of the
 * area (4x the detail).  Node error is the grid spacing (monotone up the
 * tree).  `origin` shifts the whole store, to check that a city at 5e6 m
 * behaves exactly as at the origin.  With `height` every other grid vertex
 * is raised that far (a box with volume, that an eye can stand inside).  With `textured` every node carries a
 * small checker texture.  With `cubes` every node carries its colour cube
 * (hlod_store_writer_desc.cubes, far_cubes).
 */
#ifndef HLOD_TESTS_STORE_FIXTURE_H
#define HLOD_TESTS_STORE_FIXTURE_H

#include "hlod/store_write.h"
#include "grid_quads.h"

#include <stdlib.h>
#include <string.h>

typedef struct fixture_opts {
    uint32_t roots;     /* blocks; default 4 */
    uint32_t depth;     /* levels below the roots; default 3 */
    uint32_t grid;      /* quads per side per node; default 4 */
    double size;        /* block width; default 100 */
    double origin[3];
    double height; /* corrugation; default 0 (flat) */
    int textured;
    int cubes;
} fixture_opts;

typedef struct fixture_build {
    hlod_store_writer *w;
    hlod_store_node *nodes;
    uint32_t count, cap;
    const fixture_opts *o;
    hlod_result err;
} fixture_build;

static uint32_t fixture_node(fixture_build *b, double x0, double y0, double side, uint32_t level,
                             uint32_t parent)
{
    const fixture_opts *o = b->o;
    uint32_t g = o->grid, nv = (g + 1) * (g + 1), nt = 2 * g * g;
    double *pos = malloc(3 * sizeof(double) * nv);
    float *nrm = malloc(3 * sizeof(float) * nv), *uv = malloc(2 * sizeof(float) * nv);
    uint32_t *idx = malloc(3 * sizeof(uint32_t) * nt);
    uint8_t *col = malloc(4 * nv);
    uint8_t tex[4 * 4 * 3];
    for (int p = 0; p < 16; p++) {
        uint8_t v = ((p % 4) + (p / 4)) % 2 ? 230 : 40;
        tex[3 * p] = v;
        tex[3 * p + 1] = (uint8_t)(255 - v);
        tex[3 * p + 2] = 128;
    }
    for (uint32_t j = 0; j <= g; j++)
        for (uint32_t i = 0; i <= g; i++) {
            uint32_t v = j * (g + 1) + i;
            pos[3 * v] = o->origin[0] + x0 + side * i / g;
            pos[3 * v + 1] = o->origin[1] + y0 + side * j / g;
            pos[3 * v + 2] = o->origin[2] + o->height * ((i + j) % 2);
            nrm[3 * v] = nrm[3 * v + 1] = 0;
            nrm[3 * v + 2] = 1;
            uv[2 * v] = (float)i / g;
            uv[2 * v + 1] = (float)j / g;
            col[4 * v] = (uint8_t)(60 + 40 * level);
            col[4 * v + 1] = 120;
            col[4 * v + 2] = 200;
            col[4 * v + 3] = 255;
        }
    grid_quads(idx, g, g);
    hlod_store_payload_desc d = {0};
    d.vertex_count = nv;
    d.positions = pos;
    d.origin[0] = o->origin[0] + x0 + side / 2;
    d.origin[1] = o->origin[1] + y0 + side / 2;
    d.origin[2] = o->origin[2];
    d.normals = nrm;
    d.tri_count = nt;
    d.indices = idx;
    if (o->textured) {
        d.uvs = uv;
        d.tex_tri_count = nt;
        d.tex_width = d.tex_height = 4;
        d.tex_channels = 3;
        d.pixels = tex;
    } else {
        d.colors = col;
    }
    if (b->count == b->cap) {
        b->cap = b->cap ? 2 * b->cap : 64;
        b->nodes = realloc(b->nodes, b->cap * sizeof *b->nodes);
    }
    uint32_t me = b->count++;
    hlod_result r = hlod_store_writer_add(b->w, &d, &b->nodes[me]);
    if (r != HLOD_OK)
        b->err = r;
    b->nodes[me].parent = parent;
    b->nodes[me].error = side / g;
    free(pos);
    free(nrm);
    free(uv);
    free(idx);
    free(col);
    if (level < o->depth) {
        double h = side / 2;
        fixture_node(b, x0, y0, h, level + 1, me);
        fixture_node(b, x0 + h, y0, h, level + 1, me);
        fixture_node(b, x0, y0 + h, h, level + 1, me);
        fixture_node(b, x0 + h, y0 + h, h, level + 1, me);
    }
    return me;
}

/* Writes the store; *node_count (may be NULL) gets the node count. */
static hlod_result fixture_write(const char *path, const fixture_opts *opts, uint32_t *node_count)
{
    fixture_opts o = *opts;
    if (!o.roots)
        o.roots = 4;
    if (!o.depth)
        o.depth = 3;
    if (!o.grid)
        o.grid = 4;
    if (!o.size)
        o.size = 100;
    hlod_store_writer_desc wd;
    memset(&wd, 0, sizeof wd);
    wd.build.c_tex = 0.5;
    wd.cubes = o.cubes != 0;
    fixture_build b;
    memset(&b, 0, sizeof b);
    b.o = &o;
    hlod_result r = hlod_store_writer_open(path, &wd, &b.w);
    if (r != HLOD_OK)
        return r;
    /* roots first, each with block = its index, then their subtrees */
    uint32_t *root_ids = malloc(o.roots * sizeof *root_ids);
    for (uint32_t k = 0; k < o.roots; k++) {
        root_ids[k] = fixture_node(&b, k * o.size * 1.1, 0, o.size, 0, HLOD_STORE_NO_PARENT);
        b.nodes[root_ids[k]].block = k;
    }
    free(root_ids);
    if (b.err != HLOD_OK) {
        hlod_store_writer_abort(b.w);
        free(b.nodes);
        return b.err;
    }
    r = hlod_store_writer_finish(b.w, b.nodes, b.count, NULL);
    if (node_count)
        *node_count = b.count;
    free(b.nodes);
    return r;
}

#endif
