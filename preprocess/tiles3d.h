/*
 * tiles3d.h - 3D Tiles 1.1 out of an hlod store, and back in
 * (docs/3d-tiles.md).
 *
 * Export (hlod-export-3dtiles): tileset.json is our hierarchy, tile for
 * node, refine REPLACE, geometricError = the node's certified error, a box
 * bounding volume holding the node's content as written and every
 * descendant's (3D Tiles wants a child's content inside its parent's box,
 * and a simplified node may have lost a tower's top); each tile's transform is a translation, its node's
 * origin relative to its parent tile's, printed in full double precision,
 * so a city at projected coordinates keeps its millimetres.  A store with
 * several roots gets a content-less root tile above them.  Each node is one
 * tiles/<node>.glb (glTF 2.0, y up as 3D Tiles requires: glTF (x, y, z) =
 * ours (x, z, -y)):
 *   - positions as 16-bit integers under KHR_mesh_quantization, the glTF
 *     node's translation and uniform scale mapping them back (a uniform
 *     scale keeps normals valid); a node whose 16-bit step would move a
 *     vertex by more than max(the store's position grid, 0.1 x its error,
 *     1e-6 x the store's diagonal) keeps float positions;
 *   - normals as normalized 16-bit, UVs as normalized 16-bit when they lie
 *     in [0, 1] (else float), vertex colours as COLOR_0 (linear, normalized
 *     16-bit: ours are sRGB bytes);
 *   - the textured triangles (stored first) one primitive with the node's
 *     texture (the store's JPEG bytes as they are when it holds JPEG, else
 *     JPEG for 1 or 3 channels and PNG for 2 or 4), the rest a second
 *     primitive with COLOR_0 or the renderer's grey as baseColorFactor;
 *   - EXT_meshopt_compression (meshoptimizer's codecs, no fallback data) on
 *     the vertex and index views when it pays: auto uses it when the coded
 *     views are below 0.9 x the plain ones.
 * All JSON goes through cJSON.  The output folder is written as
 * DIR.tmp-XXXXXX beside DIR and renamed into place when complete.
 *
 * Reentrant; the export runs `threads` workers of its own.
 */
#ifndef HLOD_TILES3D_H
#define HLOD_TILES3D_H

#include "hlod/mesh.h"
#include "hlod/store.h"

#ifdef __cplusplus
extern "C" {
#endif

#define HLOD_MESHOPT_AUTO (-1)
#define HLOD_MESHOPT_NEVER 0
#define HLOD_MESHOPT_ALWAYS 1

typedef struct hlod_tiles_export_desc {
    int meshopt;                /* HLOD_MESHOPT_AUTO, _NEVER or _ALWAYS */
    int jpeg_quality;           /* for textures not already JPEG; 1..100 (0: 90) */
    int force;                  /* replace an existing DIR */
    unsigned threads;           /* workers (0: 2) */
    const hlod_logger *logger;  /* may be NULL */
    hlod_progress_fn progress;  /* may be NULL; called from the calling thread */
    void *progress_user;
} hlod_tiles_export_desc;

typedef struct hlod_tiles_export_stats {
    uint64_t tiles;             /* tiles in tileset.json (content-less root included) */
    uint64_t glbs;              /* .glb files */
    uint64_t bytes;             /* every file written, tileset.json included */
    uint64_t glb_bytes;
    uint64_t tileset_bytes;
    uint64_t texture_bytes;     /* image bytes inside the .glb files */
    uint64_t jpeg_copied;       /* textures whose JPEG bytes came from the store as they were */
    uint64_t meshopt_glbs;      /* .glb files with EXT_meshopt_compression */
    uint64_t float_position_glbs; /* .glb files that kept float positions */
    uint64_t triangles;
} hlod_tiles_export_stats;

/* Writes store s as a tileset in folder dir (absent, or replaced when
 * desc->force).  Errors name the file or node through desc->logger:
 * HLOD_ERR_IO (folder exists without force, write failures),
 * HLOD_ERR_CHECKSUM / HLOD_ERR_FORMAT (a bad payload: nothing is left),
 * HLOD_ERR_NOMEM.  On failure no dir is created and an existing one is
 * left as it was.  stats may be NULL. */
hlod_result hlod_tiles_export(const hlod_store *s, const char *dir,
                              const hlod_tiles_export_desc *desc,
                              hlod_tiles_export_stats *stats);

#ifdef __cplusplus
}
#endif
#endif
