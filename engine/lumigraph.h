/*
 * lumigraph.h - the Grid-Lumigraph client inside the engine (policy
 * lumigraph; Okamoto et al. 3.1, 3.2, 5.1, 5.2; docs/lumigraph.md).
 *
 * The engine draws the store's coarse nodes (the sparse mesh) and colours
 * them from the views of the grid points around the eye.  This module owns
 * those views: a fetch thread reads them from the repository (a folder or
 * an HTTP server), keeps the fetched bytes in an LRU cache of a fixed size,
 * and decodes what the render thread asks for; the render thread uploads
 * decoded views into GPU slots, at most a few per frame, and never waits
 * (it only try-locks the shared lists; a view not there yet is left out of
 * the frame's blend).
 *
 * Order of requests each frame (section 5.1, step 3): for the 8 grid
 * points around the eye, heaviest first, the faces the view direction
 * looks into, then the other faces of the same points
 * (hlod_lumi_candidates).  From a folder or a static server each view is
 * one file and one request; from hlod-lumigraph-serve one request
 * carries the eye, the direction and what the client holds, and the answer
 * brings the views it lacks.
 */
#ifndef HLOD_ENGINE_LUMIGRAPH_H
#define HLOD_ENGINE_LUMIGRAPH_H

#include "gl_render.h"
#include "hlod/camera.h"
#include "hlod/lumigraph.h"

typedef struct hlod_lumi hlod_lumi;

typedef struct hlod_lumi_stats {
    uint64_t bytes;        /* fetched from the repository this frame */
    uint64_t answer_max;   /* the largest single answer (one view's file) this frame */
    uint32_t uploads;      /* views uploaded to the GPU this frame */
    uint32_t missing;      /* views the frame's blend wanted and lacked */
    uint32_t fetch_failures; /* fetches that failed this frame */
    double upload_ms;      /* CPU time of the uploads */
} hlod_lumi_stats;

/* Opens the repository (its index read now, blocking) and starts the fetch
 * thread.  answers: repo is hlod-lumigraph-serve's URL, asked for answers
 * (lumigraph.h, the answer protocol), which may hold views the index lists
 * as missing (rendered on demand); else each view is fetched as a file.
 * store_id: the store's node_table_hash, which the repository must have
 * been baked from (HLOD_ERR_FORMAT, logged, otherwise).  cache_bytes: the
 * fetched bytes kept (LRU). */
hlod_result hlod_lumi_create(const char *repo, int answers, uint64_t store_id,
                             uint64_t cache_bytes, const hlod_logger *lg,
                             hlod_lumi **out);
/* Stops and joins the fetch thread; frees the GPU slots (context current). */
void hlod_lumi_destroy(hlod_lumi *l, hlod_renderer *r);

/* Render thread, once per frame before drawing: takes the views decoded
 * since the last frame into GPU slots (at most `uploads` of them), asks
 * the fetch thread for what this camera needs, and fills f (all but its
 * tolerance, the caller's: the engine's live lumi_tol).  With r NULL
 * nothing is uploaded.  HLOD_ERR_UNSUPPORTED when the GPU slots cannot be
 * made (logged). */
hlod_result hlod_lumi_frame(hlod_lumi *l, hlod_renderer *r, const hlod_camera *cam,
                            uint32_t uploads, hlod_gpu_lumi_frame *f, hlod_lumi_stats *st);

const hlod_lumi_index *hlod_lumi_get_index(const hlod_lumi *l);

#endif
