/*
 * loader_store.h - the synthetic store of the loader's and residency's
 * tests (test_loader.c, test_residency.c): two roots; under the first a
 * 4 MiB textured node (BIG) and two small ones; under the second ten
 * medium nodes of a few KiB.  Include once per test program.
 */
#ifndef HLOD_LOADER_STORE_H
#define HLOD_LOADER_STORE_H

#include "hlod/store.h"
#include "grid_quads.h"
#include "hlod/store_write.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* Logical nodes.  R0: BIG, S1, S2; R1: M0..M9. */
enum { R0, R1, BIG, S1, S2, M0, NODES = M0 + 10 };
#define M(i) (M0 + (i))
#define BIG_TEX 1024    /* RGBA: 4 MiB of pixels */

static uint32_t g_idx[NODES];           /* logical -> store index */
static hlod_store *g_store;
static hlod_store_payload g_ref[NODES]; /* by store index, read with hlod_store_read_node */
static uint64_t g_size[NODES];          /* payload bytes, by store index */

typedef struct mesh {
    hlod_store_payload_desc d;
    double *pos;
    float *uv;
    uint8_t *pix;
    uint32_t *idx;
} mesh;

/* An nx x ny grid of unit quads at x0, a little wavy; with a tex x tex RGBA
 * texture (and UVs) when tex > 0. */
static void mesh_make(mesh *m, int nx, int ny, double x0, uint32_t tex)
{
    memset(m, 0, sizeof *m);
    uint32_t v = (uint32_t)((nx + 1) * (ny + 1)), t = (uint32_t)(2 * nx * ny);
    m->pos = malloc(3 * sizeof(double) * v);
    m->idx = malloc(3 * sizeof(uint32_t) * t);
    if (tex)
        m->uv = malloc(2 * sizeof(float) * v);
    for (int j = 0; j <= ny; j++)
        for (int i = 0; i <= nx; i++) {
            size_t k = (size_t)j * (nx + 1) + i;
            m->pos[3 * k] = x0 + i;
            m->pos[3 * k + 1] = j;
            m->pos[3 * k + 2] = 0.1 * sin(0.7 * i + 1.3 * j + x0);
            if (m->uv) {
                m->uv[2 * k] = (float)i / (float)nx;
                m->uv[2 * k + 1] = (float)j / (float)ny;
            }
        }
    grid_quads(m->idx, (uint32_t)nx, (uint32_t)ny);
    m->d.vertex_count = v;
    m->d.positions = m->pos;
    m->d.origin[0] = x0 + nx / 2.0;
    m->d.origin[1] = ny / 2.0;
    m->d.uvs = m->uv;
    m->d.tri_count = t;
    m->d.indices = m->idx;
    if (tex) {
        size_t bytes = (size_t)tex * tex * 4;
        m->pix = malloc(bytes);
        for (size_t i = 0; i < bytes; i++)
            m->pix[i] = (uint8_t)(i * 7 + (i >> 12));
        m->d.pixels = m->pix;
        m->d.tex_width = m->d.tex_height = tex;
        m->d.tex_channels = 4;
        m->d.tex_tri_count = t;
    }
}

static void mesh_free(mesh *m)
{
    free(m->pos);
    free(m->uv);
    free(m->pix);
    free(m->idx);
    memset(m, 0, sizeof *m);
}

/* Writes the test store to path; fills g_idx. */
static hlod_result write_store(const char *path)
{
    mesh m[NODES];
    mesh_make(&m[R0], 4, 4, 0, 0);
    mesh_make(&m[R1], 4, 4, 100, 0);
    mesh_make(&m[BIG], 1, 1, 0, BIG_TEX);
    mesh_make(&m[S1], 3, 3, 10, 0);
    mesh_make(&m[S2], 3, 4, 20, 0);
    for (int i = 0; i < 10; i++)
        mesh_make(&m[M(i)], 20 + i, 20, 100 + 30 * i, 0);

    hlod_store_writer_desc desc = {0};
    desc.build.method = HLOD_STORE_METHOD_OTHER;
    desc.build.c_tex = 0.5;
    hlod_store_writer *w = NULL;
    hlod_result r = hlod_store_writer_open(path, &desc, &w);
    hlod_store_node nodes[NODES];
    for (int i = 0; i < NODES && r == HLOD_OK; i++)
        r = hlod_store_writer_add(w, &m[i].d, &nodes[i]);
    if (r == HLOD_OK) {
        for (int i = 0; i < NODES; i++) {
            int root = i == R0 || i == R1;
            nodes[i].parent = root ? HLOD_STORE_NO_PARENT : i < M0 ? (uint32_t)R0 : (uint32_t)R1;
            nodes[i].block = i == R1 ? 1 : 0;
            nodes[i].error = root ? 2.0 : 1.0;
        }
        r = hlod_store_writer_finish(w, nodes, NODES, g_idx);
    } else {
        hlod_store_writer_abort(w);
    }
    for (int i = 0; i < NODES; i++)
        mesh_free(&m[i]);
    return r;
}

/* Payload bytes of logical nodes. */
static uint64_t size_of(int logical)
{
    return g_size[g_idx[logical]];
}

/* Writes the store at path, opens it into g_store and reads every
 * payload into g_ref.  1 on success. */
static int loader_store_open(const char *path)
{
    int ok = write_store(path) == HLOD_OK && hlod_store_open(path, NULL, &g_store) == HLOD_OK;
    for (int i = 0; ok && i < NODES; i++) {
        g_size[i] = hlod_store_nodes(g_store)[i].payload_size;
        ok = hlod_store_read_node(g_store, (uint32_t)i, 0, &g_ref[i]) == HLOD_OK;
    }
    return ok;
}

static void loader_store_close(const char *path)
{
    for (int i = 0; i < NODES; i++)
        hlod_store_payload_free(&g_ref[i]);
    hlod_store_close(g_store);
    unlink(path);
}

#endif
