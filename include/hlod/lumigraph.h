/*
 * lumigraph.h - the sampling repository of Okamoto's Grid-Lumigraph
 * ("Image-based network rendering of large meshes", section 4.3): images of
 * a model rendered at the points of a regular grid, six axis views of 90
 * degrees per point, each with its depth for the client's visibility test
 * (section 3.2's shadow map).  docs/lumigraph.md describes the bytes.
 *
 * A repository is a folder (or the same folder served over HTTP):
 *
 *     REPO/repo.hlg               the index: grid, box, image sizes, and
 *                                 one state per view (missing, empty, baked)
 *     REPO/views/X/Y_Z_D.hlv      one baked view (a JPEG and its depth)
 *
 * Grid point (x, y, z), x, y, z in [0, G), lies at box_min + (box_max -
 * box_min) * (x, y, z) / (G - 1); view d in [0, 6) looks along +x, -x, +y,
 * -y, +z, -z (hlod_lumi_face).  A view is keyed by (x, y, z, d), its
 * number ((z G + y) G + x) 6 + d.
 *
 * Every function is reentrant; none keeps global state.
 */
#ifndef HLOD_LUMIGRAPH_H
#define HLOD_LUMIGRAPH_H

#include "hlod/hlod.h"

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HLOD_LUMI_VERSION 1u
#define HLOD_LUMI_FACES 6u
#define HLOD_LUMI_GRID_MAX 64u
#define HLOD_LUMI_SIZE_MAX 2048u
#define HLOD_LUMI_INDEX_NAME "repo.hlg"
#define HLOD_LUMI_INDEX_HEAD 112u   /* bytes before the states */
#define HLOD_LUMI_VIEW_HEAD 48u     /* bytes before a view's JPEG */
#define HLOD_LUMI_DEPTH_NONE 65535u /* a depth texel where nothing was drawn */

/* A view's state in the index. */
enum { HLOD_LUMI_MISSING = 0, HLOD_LUMI_EMPTY = 1, HLOD_LUMI_BAKED = 2 };

typedef struct hlod_lumi_index {
    uint32_t grid;              /* G: G^3 points, G in [2, HLOD_LUMI_GRID_MAX] */
    uint32_t size;              /* colour images are size x size */
    uint32_t depth_size;        /* depth images are depth_size x depth_size (divides size) */
    uint32_t quality;           /* JPEG quality the bake used */
    double box_min[3], box_max[3]; /* the grid's box: twice the model's */
    double near_plane, far_plane;  /* the views' clip planes; depth is quantised between them */
    uint64_t store_id;          /* the store's node_table_hash */
    uint32_t views;             /* G^3 * 6 */
    uint8_t *state;             /* views entries, HLOD_LUMI_* */
} hlod_lumi_index;

/* One decoded view: colour top row first (size^2 * 3 bytes), quantised
 * depth top row first (depth_size^2 values; hlod_lumi_depth_quant). */
typedef struct hlod_lumi_view {
    uint32_t id, size, depth_size;
    uint8_t *rgb;
    uint16_t *depth;
} hlod_lumi_view;

/* The axes of face d: the direction it looks along, its up and its right
 * (forward x up), as hlod_camera_look_at builds the view. */
void hlod_lumi_face(uint32_t d, double forward[3], double up[3], double right[3]);

/* The position of grid point (x, y, z). */
void hlod_lumi_point(const hlod_lumi_index *ix, uint32_t x, uint32_t y, uint32_t z, double out[3]);

static inline uint32_t hlod_lumi_view_id(const hlod_lumi_index *ix, uint32_t x, uint32_t y,
                                         uint32_t z, uint32_t d)
{
    return ((z * ix->grid + y) * ix->grid + x) * HLOD_LUMI_FACES + d;
}
void hlod_lumi_view_key(const hlod_lumi_index *ix, uint32_t id, uint32_t *x, uint32_t *y,
                        uint32_t *z, uint32_t *d);

/* The 8 grid points around p (the corners of its cell; p clamped to the
 * box) and their trilinear weights, summing to 1.  Corners repeat where the
 * cell is flat in an axis; a corner whose weight is 0 still appears. */
void hlod_lumi_corners(const hlod_lumi_index *ix, const double p[3], uint32_t point[8],
                       double weight[8]);

/* Axial distance z in [near, far] to a 16-bit code, logarithmic (relative
 * step ln(far / near) / 65534); HLOD_LUMI_DEPTH_NONE is never returned. */
uint16_t hlod_lumi_depth_quant(double z, double near_plane, double far_plane);
double hlod_lumi_depth_value(uint16_t q, double near_plane, double far_plane);

/* Makes an index of the given shape, every view missing.  HLOD_ERR_INVALID_ARG
 * for a shape outside the limits. */
hlod_result hlod_lumi_index_init(hlod_lumi_index *ix, uint32_t grid, uint32_t size,
                                 uint32_t depth_size, uint32_t quality, const double box_min[3],
                                 const double box_max[3], double near_plane, double far_plane,
                                 uint64_t store_id);
void hlod_lumi_index_free(hlod_lumi_index *ix);

/* The index's bytes (written to a temporary file and renamed by callers). */
hlod_result hlod_lumi_index_encode(const hlod_lumi_index *ix, uint8_t **out, size_t *n);
/* Parses and checks an index (magic, version, shape, states, checksum);
 * errors logged naming `name`. */
hlod_result hlod_lumi_index_decode(const uint8_t *buf, size_t n, const char *name,
                                   const hlod_logger *lg, hlod_lumi_index *out);
/* Reads REPO/repo.hlg (REPO a folder or an http(s) URL). */
hlod_result hlod_lumi_index_load(const char *repo, const hlod_logger *lg, hlod_lumi_index *out);
/* Writes REPO/repo.hlg atomically. */
hlod_result hlod_lumi_index_save(const char *repo, const hlod_lumi_index *ix,
                                 const hlod_logger *lg);

/* A view's relative path in the repository, "views/X/Y_Z_D.hlv". */
void hlod_lumi_view_path(const hlod_lumi_index *ix, uint32_t id, char *out, size_t cap);

/* Encodes a view: rgb top row first (ix->size^2 * 3), depth codes top row
 * first (ix->depth_size^2).  *out is malloc'd. */
hlod_result hlod_lumi_view_encode(const hlod_lumi_index *ix, uint32_t id, const uint8_t *rgb,
                                  const uint16_t *depth, uint8_t **out, size_t *n);
/* Parses and checks a view's bytes against the index and the id it was
 * asked for; errors logged naming `name`.  out->rgb and out->depth are
 * malloc'd (hlod_lumi_view_free). */
hlod_result hlod_lumi_view_decode(const hlod_lumi_index *ix, uint32_t id, const uint8_t *buf,
                                  size_t n, const char *name, const hlod_logger *lg,
                                  hlod_lumi_view *out);
void hlod_lumi_view_free(hlod_lumi_view *v);

/* Reads the file at REPO/rel (a folder or an http(s) URL; one GET) into a
 * malloc'd buffer, at most max_bytes.  HLOD_ERR_IO (logged, naming the file
 * or URL) when it cannot, HLOD_ERR_FORMAT when it is longer. */
hlod_result hlod_lumi_fetch(const char *repo, const char *rel, size_t max_bytes,
                            const hlod_logger *lg, uint8_t **out, size_t *n);
/* As hlod_lumi_fetch; an HTTP transfer is abandoned (HLOD_ERR_CANCELLED,
 * not logged) as soon as cancel(user) returns non-zero (asked a few times
 * a second). */
hlod_result hlod_lumi_fetch_cancel(const char *repo, const char *rel, size_t max_bytes,
                                   int (*cancel)(void *), void *user, const hlod_logger *lg,
                                   uint8_t **out, size_t *n);

/* ---- the answer protocol (section 5.1; hlod-lumigraph-serve) ----
 *
 * A request, GET /answer?p=X,Y,Z&d=DX,DY,DZ&have=HEX: the client's eye and
 * view direction (six numbers, as %.17g) and which of its 48 candidates it
 * holds, a hex number whose bit c * 6 + f is candidate (corner c, face f),
 * corners in hlod_lumi_corners' order.  The answer: the candidates it lacks
 * that are baked, in hlod_lumi_candidates' order, each a record of its view
 * number (u32), its length (u32) and its file's bytes, as many as fit in
 * the answer's limit (at least one). */
#define HLOD_LUMI_CANDIDATES 48u

typedef struct hlod_lumi_request {
    double eye[3], dir[3];
    uint64_t have;          /* bit c * 6 + f */
} hlod_lumi_request;

/* Parses a request's query string (after '?'); 0 on anything malformed:
 * a missing or repeated key, a number that is not finite, a direction of
 * length 0, a have of more than 12 hex digits, unknown keys, more than
 * 512 bytes. */
int hlod_lumi_request_parse(const char *query, size_t len, hlod_lumi_request *out);
/* Writes a request's query string; the length (< cap), or 0 when cap is
 * too small. */
size_t hlod_lumi_request_format(const hlod_lumi_request *q, char *out, size_t cap);

/* The candidates for an eye and a direction, in request order (section
 * 5.1, step 3): the corners heaviest first, for each the faces within 120
 * degrees of the direction (dot > -0.5), then the corners' other faces.
 * out[k] is the view number, slot[k] its candidate bit c * 6 + f; returns
 * how many (48, duplicates of a repeated corner left out). */
uint32_t hlod_lumi_candidates(const hlod_lumi_index *ix, const double eye[3], const double dir[3],
                              uint32_t out[HLOD_LUMI_CANDIDATES],
                              uint32_t slot[HLOD_LUMI_CANDIDATES]);

#ifdef __cplusplus
}
#endif
#endif
