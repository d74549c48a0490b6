/*
 * city_paths.h - the built-in camera paths of the synthetic city (issue 5),
 * made for exactly the street grid hlod_city_generate lays out for the same
 * block count and origin (the seed, the triangle budget and the textures do
 * not move streets).  hlod-gen-city --paths DIR writes them as DIR/NAME.path
 * in the text format of hlod/path.h; data/paths/default/ and
 * data/paths/small/ hold them for the two presets at origin 0.
 *
 * Paths (z up, metres; the eye is 1.7 m above the ground when walking):
 *   walk        along a street near the centre at about 1.4 m/s, left turn
 *               (6 m radius) at an intersection, looking 10 m ahead; 28.5 s
 *   walk-drive  one straight street through the centre: 200 frames (at
 *               1/30 s) walking at 1.4 m/s, then 200 frames driving at
 *               14 m/s, with a smooth 0.5 s acceleration centred between
 *               frames 199 and 200 (Lakhia Fig. 8); 13.3 s = 400 frames
 *   walk-to-fly 5 s walking north through the central intersection, then
 *               a 15 s rise by a constant factor per frame (straight up
 *               until above the roofs, then back and up) until the whole
 *               city is in view, held for 2 s (Lakhia Fig. 7); 22 s
 *   fly         100 m above the ground at 40 m/s, two passes over the whole
 *               city along x (at y = -D/4 and +D/4) joined by a U-turn,
 *               looking 150 m ahead at the ground
 *   orbit       one turn around the centre in 60 s, at 0.75 R from the
 *               centre and 0.45 R + 40 m high (R the city's half-diagonal),
 *               looking at the centre of the ground
 *   still       20 s at one viewpoint: 30 m above the south edge of the
 *               city, looking at its centre
 *
 * "The whole city in view" assumes a vertical field of view of at least
 * 60 degrees and a landscape viewport: the bounding sphere of the ground
 * and 45 m of buildings fills the vertical field with 5 % margin, about
 * 2.3 km from the far corner for the default city (far plane 5000 is
 * enough).  Keyframes are dense (every 0.5 s; every 0.1 s for walk-drive)
 * samples of smooth curves, coordinates rounded to 0.1 mm, so the
 * Catmull-Rom replay follows the curves to millimetres and the files read
 * the same on every machine.
 *
 * Thread safety: reentrant.  Nothing here calls the engine library; the
 * output is a plain hlod_path (free it with hlod_path_free, or free(keys)).
 */
#ifndef HLOD_CITY_PATHS_H
#define HLOD_CITY_PATHS_H

#include "city.h"
#include "hlod/path.h"

#ifdef __cplusplus
extern "C" {
#endif

#define HLOD_CITY_PATH_COUNT 6

/* "walk", "walk-drive", "walk-to-fly", "fly", "orbit", "still". */
extern const char *const hlod_city_path_names[HLOD_CITY_PATH_COUNT];

/* The keyframes of a named path for the city of desc (only blocks, with
 * 0 meaning 200 as in hlod_city_generate, and origin are read).  *out is
 * freed first (with free()).  HLOD_ERR_INVALID_ARG for an unknown name or a
 * bad desc, HLOD_ERR_NOMEM. */
hlod_result hlod_city_path(const hlod_city_desc *desc, const char *name, hlod_path *out);

/* The path's file contents, as hlod_path_to_text writes them with its
 * header comment (which names the path, the block count and the origin).
 * *text is malloc'ed and NUL-terminated; len may be NULL. */
hlod_result hlod_city_path_text(const hlod_city_desc *desc, const char *name, char **text,
                                size_t *len);

/* Writes every path to DIR/NAME.path (DIR and its parents are created
 * when missing), each through a temporary file and a rename.  HLOD_ERR_IO with the
 * reason logged. */
hlod_result hlod_city_paths_write(const hlod_city_desc *desc, const char *dir,
                                  const hlod_logger *lg);

#ifdef __cplusplus
}
#endif
#endif
