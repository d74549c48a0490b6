/*
 * seed_store.c - writes the tiny stores that seed fuzz_store's corpus.
 *
 *   fuzz_seed_store DIR      (tests/fuzz/run.sh --seeds runs it)
 *
 * Real stores from hlod-build are megabytes, mostly payload padding at 4096
 * bytes; these use the smallest alignment (64) and a handful of triangles,
 * so each seed is a few hundred bytes to a few KB and every mutation lands
 * on a header, a node record or a payload section.  They cover every
 * payload section: normals, UVs, colours, a texture, and the tree rule with
 * several roots and two levels.  The packed-* seeds are format 3's packed
 * payloads (docs/store-format.md): every codec stream, a JPEG texture.
 * The committed one-node, textured-tree and two-roots seeds are format 2's,
 * and the packed-* ones format 3's (the reader still reads both); --seeds
 * leaves them, and the committed v4-* seeds (format 4's, with the extras
 * table: a node's normal cone; one-sided quads, so the cones bound them;
 * v4-sampletree.hlod a sample tree's, additive, with node colours), and
 * writes v5-blocks-tree.hlod, format 5's with block-coded textures (BC1
 * mips in a zstd frame) on a 6x5 texture, whose blocks pad an edge.
 */
#include "hlod/store_write.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A quad split in two triangles over [x0, x0 + s] x [y0, y0 + s], z = 0. */
static hlod_result add_quad(hlod_store_writer *w, double x0, double y0, double s, int textured,
                            hlod_store_node *node)
{
    double pos[12] = {x0, y0, 0, x0 + s, y0, 0, x0 + s, y0 + s, 0, x0, y0 + s, 0};
    float nrm[12] = {0, 0, 1, 0, 0, 1, 0, 0, 1, 0, 0, 1};
    float uv[8] = {0, 0, 1, 0, 1, 1, 0, 1};
    uint8_t col[16] = {200, 10, 10, 255, 10, 200, 10, 255, 10, 10, 200, 255, 90, 90, 90, 255};
    uint8_t tex[6 * 5 * 3];
    for (int i = 0; i < 6 * 5 * 3; i++)
        tex[i] = (uint8_t)(i * 37 + (int)(x0 * 50));
    uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
    hlod_store_payload_desc d;
    memset(&d, 0, sizeof d);
    d.vertex_count = 4;
    d.positions = pos;
    d.origin[0] = x0;
    d.origin[1] = y0;
    d.normals = nrm;
    d.tri_count = 2;
    d.indices = idx;
    if (textured) {
        d.uvs = uv;
        d.tex_tri_count = 2;
        d.tex_width = textured == 2 ? 6 : 2;
        d.tex_height = textured == 2 ? 5 : 2;
        d.tex_channels = 3;
        d.pixels = tex;
    } else {
        d.colors = col;
    }
    return hlod_store_writer_add(w, &d, node);
}

/* roots blocks side by side, each a quad with `children` child quads;
 * sampletree: a sample tree's header (additive) and node colours; 2:
 * colour cubes' (additive, node colours and cubes). */
static int write_store(const char *dir, const char *name, uint32_t roots, uint32_t children,
                       int textured, int packed, int sampletree)
{
    char path[4096];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    hlod_store_writer_desc wd;
    memset(&wd, 0, sizeof wd);
    wd.build.method = HLOD_STORE_METHOD_CUTPLANE;
    wd.build.desired_tris = 2;
    wd.build.level_factor = 2;
    wd.build.c_tex = 0.5;
    if (sampletree) {
        wd.build.method = sampletree == 2 ? HLOD_STORE_METHOD_CUBES : HLOD_STORE_METHOD_SAMPLETREE;
        wd.build.desired_tris = 0;
        wd.build.level_factor = sampletree == 2 ? 0 : 13.8;
        wd.build.leaf_tris = 2;
    }
    wd.payload_align = 64;
    if (packed) {
        wd.quant_step = 1.0 / 64;
        wd.jpeg_quality = 90;
        wd.texture_blocks = textured == 2;   /* blocks whatever their PSNR */
    }
    hlod_store_writer *w;
    if (hlod_store_writer_open(path, &wd, &w) != HLOD_OK)
        return 1;
    hlod_store_node nodes[16];
    uint32_t n = 0;
    hlod_result r = HLOD_OK;
    for (uint32_t b = 0; b < roots && r == HLOD_OK; b++) {
        uint32_t root = n++;
        r = add_quad(w, 2.0 * b, 0, 1, textured, &nodes[root]);
        nodes[root].parent = HLOD_STORE_NO_PARENT;
        nodes[root].block = b;
        nodes[root].error = 0.5;
        nodes[root].render_flags = HLOD_RENDER_SOLID;
        for (uint32_t c = 0; c < children && r == HLOD_OK; c++) {
            uint32_t k = n++;
            r = add_quad(w, 2.0 * b + 0.5 * c, 0, 0.5, textured && c == 0, &nodes[k]);
            nodes[k].parent = root;
            nodes[k].error = 0.25;
            nodes[k].render_flags = HLOD_RENDER_SOLID;
        }
    }
    if (r != HLOD_OK) {
        hlod_store_writer_abort(w);
        return 1;
    }
    uint8_t colors[16][4];
    for (uint32_t k = 0; k < n; k++) {
        const uint8_t c[4] = {(uint8_t)(40 * k), 120, (uint8_t)(200 - 30 * k), 255};
        memcpy(colors[k], c, 4);
    }
    if (sampletree && hlod_store_writer_set_colors(w, (const uint8_t (*)[4])colors, n) != HLOD_OK) {
        hlod_store_writer_abort(w);
        return 1;
    }
    uint8_t cubes[16][6][4];
    for (uint32_t k = 0; k < n; k++)
        for (int f = 0; f < 6; f++) {
            const uint8_t c[4] = {(uint8_t)(20 * f), (uint8_t)(30 * k), 90, (uint8_t)(255 - 20 * f)};
            memcpy(cubes[k][f], c, 4);
        }
    if (sampletree == 2 &&
        hlod_store_writer_set_cubes(w, (const uint8_t (*)[6][4])cubes, n) != HLOD_OK) {
        hlod_store_writer_abort(w);
        return 1;
    }
    if (hlod_store_writer_finish(w, nodes, n, NULL) != HLOD_OK)
        return 1;
    printf("%s\n", path);
    return 0;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: fuzz_seed_store DIR\n");
        return 2;
    }
    int bad = 0;
    bad |= write_store(argv[1], "v5-blocks-tree.hlod", 1, 2, 2, 1, 0);
    bad |= write_store(argv[1], "v5-cubes.hlod", 1, 2, 0, 1, 2);
    return bad;
}
