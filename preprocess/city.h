/*
 * city.h - a deterministic synthetic city: textured blocks of buildings with
 * dense, scan-like facades, standing on a textured ground with streets.
 *
 * It stands in for the seed paper's laser-scanned city (Lakhia: 114 blocks,
 * 7M triangles, 720M texture pixels), which cannot be shipped.  The output is
 * one hlod_mesh holding one object per block ("block_0000", ...) and a last
 * object "ground"; block b uses material b, the ground the last material.
 * z is up, units are metres, the city is centred on desc->origin (x, y) and
 * its ground lies at desc->origin z.
 *
 * A block is a ring of detached buildings around a courtyard.  Every wall is
 * a conforming grid swept along a vertical profile (plinth, string course,
 * cornice, parapet), with inset window recesses, mitred parapets and a
 * fan-triangulated flat roof; every vertex then moves by a few centimetres
 * of position-hashed noise, so that coincident vertices stay coincident and
 * simplification has real work to do.  The triangle budget per block is met
 * by choosing the grid density (finer subdivision above the base detail,
 * wider window spacing below it).
 *
 * Textures (unless desc->untextured): one atlas per block, S x S RGB PNG,
 * with one chart per wall (unfolded along its profile, windows where the
 * recesses are) and per roof, and one tiled ground texture; UVs stay inside
 * [0, 1].  They are written to desc->texture_dir (created when missing)
 * through hlod_image_write, one file at a time, as the blocks are made.
 *
 * Same desc, same bytes: randomness comes from a splitmix64 stream seeded by
 * (seed, block), noise from a hash of the quantised position.
 *
 * Cost: geometry takes about 0.1 us and 40 bytes per triangle; each texture
 * takes one S x S x 3 buffer (reused) and, at S = 1024, about 0.4 s, mostly
 * PNG deflate.  Thread safety: reentrant (no global state).
 */
#ifndef HLOD_CITY_H
#define HLOD_CITY_H

#include "hlod/mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

/* How buildings are made.  SCAN: each building one closed surface of
 * dense, scan-like facades.  PARTS: each building many separate closed
 * boxes, as BIM exports are (wall piers and spandrels, floor slabs, window
 * frames and panes, parapets), untextured. */
enum { HLOD_CITY_STYLE_SCAN = 0, HLOD_CITY_STYLE_PARTS = 1 };

typedef struct hlod_city_desc {
    size_t blocks;              /* 0: 200 */
    size_t tris_per_block;      /* approximate budget per block; 0: 35000 */
    int texture_size;           /* atlas side in pixels, >= 16; 0: 1024 */
    uint64_t seed;              /* any value, 0 included */
    double origin[3];           /* added to every position, exactly */
    int untextured;             /* non-zero: no UVs, no textures, colours only */
    int style;                  /* HLOD_CITY_STYLE_SCAN (0) or _PARTS (untextured) */
    const char *texture_dir;    /* required unless untextured */
    hlod_progress_fn progress;  /* blocks done of blocks + 1; may be NULL */
    void *progress_user;
    const hlod_logger *logger;  /* may be NULL */
} hlod_city_desc;

typedef struct hlod_city_stats {
    size_t blocks;
    size_t tris, vertices;      /* whole mesh */
    size_t block_tris;          /* the blocks' triangles (no ground) */
    size_t ground_tris;
    size_t min_block_tris, max_block_tris;
    size_t textures;            /* files written */
    uint64_t texture_pixels;    /* sum of width * height over them */
    uint64_t texture_bytes;     /* their size on disk */
} hlod_city_stats;

/* Fills blocks, tris_per_block and texture_size for a named preset:
 *   "default": 200 blocks x 35000 triangles, 1024^2 atlases (7M triangles,
 *              210M texture pixels: the seed paper's scale);
 *   "small":   8 blocks x 5500, 256^2 (about 50k triangles with the ground);
 *   "tiny":    2 blocks x 2500, 64^2 (a few thousand, for unit tests).
 * Other fields are left alone.  Returns 0 for an unknown name. */
int hlod_city_preset(const char *name, hlod_city_desc *desc);

/* Generates the city into *out (freed first); texture paths are
 * texture_dir + "/block_0000.png" etc. and "/ground.png".  stats may be
 * NULL.  Returns HLOD_ERR_INVALID_ARG for bad values (named through the
 * logger), HLOD_ERR_IO when a texture cannot be written, HLOD_ERR_NOMEM.
 * A block whose budget cannot be met within 10% (too small for even the
 * plainest facades) is reported as a warning.  On failure *out is empty;
 * textures already written stay (the caller owns the folder). */
hlod_result hlod_city_generate(const hlod_city_desc *desc, hlod_mesh *out,
                               hlod_city_stats *stats);

#ifdef __cplusplus
}
#endif
#endif
