/*
 * mesh.h - the in-memory triangle mesh every hlod tool works on.
 *
 * Layout: one indexed triangle list.  Vertices carry a double position and,
 * optionally, a float normal and a float texture coordinate; a vertex that
 * sits on a UV seam appears once per side (same position, different UV), as
 * a GPU wants it.  Triangles carry a material index and are sorted by input
 * object, so object k owns triangles [objects[k].first_tri,
 * objects[k].first_tri + objects[k].tri_count).
 *
 * Ownership: an hlod_mesh owns every array it points to; hlod_mesh_free()
 * releases them all (arrays are malloc'ed).  A zero-initialised hlod_mesh is
 * a valid empty mesh.  Functions here may be called from any thread on
 * distinct meshes.
 */
#ifndef HLOD_MESH_H
#define HLOD_MESH_H

#include "hlod/hlod.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hlod_material {
    char *name;           /* may be NULL */
    float diffuse[4];     /* RGBA, linear 0..1; default (0.8, 0.8, 0.8, 1) */
    char *texture_path;   /* diffuse texture, resolved against the mesh file's
                             folder; NULL when untextured */
} hlod_material;

typedef struct hlod_object {
    char *name;           /* OBJ o/g name, glTF node name, or file stem */
    size_t first_tri;
    size_t tri_count;
} hlod_object;

typedef struct hlod_mesh {
    size_t vertex_count;
    double *positions;    /* 3 * vertex_count, model units (e.g. metres) */
    float *normals;       /* 3 * vertex_count, or NULL */
    float *uvs;           /* 2 * vertex_count, or NULL */

    size_t tri_count;
    uint32_t *indices;    /* 3 * tri_count, counter-clockwise = front */
    uint32_t *tri_material; /* tri_count material indices, or NULL = all 0 */

    size_t material_count;
    hlod_material *materials; /* may be NULL when material_count == 0 */

    size_t object_count;
    hlod_object *objects; /* may be NULL: then the mesh is one object */
} hlod_mesh;

void hlod_mesh_free(hlod_mesh *m);

/* Allocates positions/indices (and normals/uvs/tri_material when the flags
 * ask) for the given counts; contents are uninitialised.  Frees m first. */
#define HLOD_MESH_NORMALS 1u
#define HLOD_MESH_UVS 2u
#define HLOD_MESH_MATERIALS 4u
hlod_result hlod_mesh_alloc(hlod_mesh *m, size_t vertex_count, size_t tri_count, unsigned flags);

/* Deep copy of src into dst (dst is freed first). */
hlod_result hlod_mesh_copy(hlod_mesh *dst, const hlod_mesh *src);

/* Copies src's materials and objects into dst (which has none yet), for a
 * mesh made from src's triangles in their order: kept[t] non-zero for each
 * src triangle dst holds (NULL: all of them), so object ranges shrink to
 * what is kept.  HLOD_ERR_NOMEM (dst then holds what was copied, freed
 * with it). */
hlod_result hlod_mesh_copy_tables(hlod_mesh *dst, const hlod_mesh *src, const uint8_t *kept);

/* Axis-aligned bounds of the positions; returns 0 for an empty mesh. */
int hlod_mesh_bounds(const hlod_mesh *m, double lo[3], double hi[3]);
/* Length of the bounding-box diagonal (0 for an empty mesh). */
double hlod_mesh_bbox_diag(const hlod_mesh *m);
/* Sum of triangle areas, in double. */
double hlod_mesh_area(const hlod_mesh *m);

/* Checks finite positions/normals/uvs, indices < vertex_count, material
 * indices < material_count and object ranges that tile the triangle list.
 * Reports the first problem through lg, prefixed with `name` (a file name).
 * Returns HLOD_ERR_NAN, HLOD_ERR_INDEX_RANGE, HLOD_ERR_EMPTY or
 * HLOD_ERR_FORMAT accordingly. */
hlod_result hlod_mesh_validate(const hlod_mesh *m, const char *name, const hlod_logger *lg);

/* Removes degenerate triangles (repeated index, or zero area in double) and
 * duplicate triangles (the same three vertex positions in any rotation or
 * winding, within one object: a triangle two objects share stays in both),
 * keeping the first of each duplicate set, and drops vertices no
 * triangle uses.  Object ranges and materials are kept consistent.  Counts go
 * to *degenerate / *duplicate (either may be NULL). */
hlod_result hlod_mesh_clean(hlod_mesh *m, size_t *degenerate, size_t *duplicate);

/* Area-weighted vertex normals of m's triangles into out
 * (3 * vertex_count floats): each vertex gets the unit sum of its
 * triangles' doubled-area normals, computed in double.  A vertex whose
 * sum is zero (no triangle, only degenerate ones, or faces that cancel)
 * gets (0, 0, 0): no direction, which the renderer lights as facing the
 * eye.  HLOD_ERR_NOMEM. */
hlod_result hlod_mesh_vertex_normals(const hlod_mesh *m, float *out);

#ifdef __cplusplus
}
#endif
#endif
