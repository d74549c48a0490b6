/*
 * lumi_bake.h - rendering one Grid-Lumigraph view into a repository
 * (docs/hlod-lumigraph-bake.md): shared by hlod-lumigraph-bake and
 * hlod-lumigraph-serve (which renders missing views on demand).
 */
#ifndef HLOD_TOOLS_LUMI_BAKE_H
#define HLOD_TOOLS_LUMI_BAKE_H

#include "hlod/engine.h"
#include "hlod/lumigraph.h"
#include "hlod/renderer.h"
#include "hlod/store.h"

typedef struct lumi_baker {
    const char *prog, *store_path;
    hlod_logger lg;
    hlod_store *store;
    hlod_osmesa *gl;
    hlod_renderer *renderer;
    hlod_engine *engine;
    hlod_lumi_index ix;     /* the bake's shape; views' states as baked */
    uint8_t *rgb;
    uint32_t *window_depth;
    uint16_t *depth;
} lumi_baker;

/* Opens the store and a headless GL context of the views' size and lays
 * the grid over `box` (lo[3], hi[3]), or NULL: a box twice the store's
 * (the index's states all missing).  0 (said on stderr, naming the file)
 * on failure; lumi_baker_close then. */
int lumi_baker_open(lumi_baker *b, const char *prog, const char *store, hlod_logger lg,
                    uint32_t grid, uint32_t size, uint32_t depth_size, uint32_t quality,
                    const double *box);
/* Renders view id, writes it into repo (views/X/, a temporary file
 * renamed) unless it is empty, and sets its state in b->ix.  0 (said) on
 * failure. */
int lumi_baker_view(lumi_baker *b, uint32_t id, const char *repo);
void lumi_baker_close(lumi_baker *b);
/* 1 when a and b have the same store, grid, sizes, quality, box and clip
 * planes. */
int lumi_same_shape(const hlod_lumi_index *a, const hlod_lumi_index *b);

#endif
