/*
 * mesh_io.h - reading and writing triangle meshes.
 *
 * OBJ(+MTL), PLY (ASCII and binary) and OFF are read by our own streaming
 * readers, which keep positions in double: Debian's assimp stores 32-bit
 * floats, which moves a vertex at y = 4.1e6 m by up to 0.25 m.  glTF 2.0
 * (.gltf/.glb) and anything else assimp knows go through assimp's C API.
 * A 3D Tiles tileset (a .json file) is read by our own glb reader, its leaf
 * tiles one object each, transforms in double (preprocess/io/tiles_read.c).
 * The format is chosen by file content and extension; an unknown one is an
 * HLOD_ERR_UNSUPPORTED result, never a silently empty mesh.
 *
 * Import validates: NaN/Inf coordinates, out-of-range indices, empty meshes
 * and unreadable files are errors naming the file and element; a missing
 * texture is a warning and that material becomes untextured; degenerate and
 * duplicate triangles are dropped and counted.
 *
 * Export writes to "PATH.tmp-XXXXXX" in the same folder and renames it over
 * PATH only when everything was written, so a failure never leaves a
 * partial file.  Thread safety: distinct meshes/paths may be used from any
 * thread.
 */
#ifndef HLOD_MESH_IO_H
#define HLOD_MESH_IO_H

#include "hlod/mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hlod_import_desc {
    const hlod_logger *logger;  /* may be NULL */
    int keep_degenerate;        /* non-zero: skip hlod_mesh_clean() */
    const char *scratch_dir;    /* an existing folder where images embedded in
                                   a 3D Tiles input's glb contents are written
                                   (the materials' texture_path point there;
                                   the caller removes it when done); NULL:
                                   such images are dropped with a warning */
} hlod_import_desc;

typedef struct hlod_import_stats {
    size_t tris_read;           /* triangles after triangulating polygons */
    size_t degenerate_dropped;
    size_t duplicate_dropped;
    size_t missing_textures;    /* materials whose texture file was missing */
} hlod_import_stats;

/* Reads path into *out (freed first).  desc and stats may be NULL.  On
 * failure *out is left empty. */
hlod_result hlod_mesh_import(const char *path, const hlod_import_desc *desc,
                             hlod_mesh *out, hlod_import_stats *stats);

/* Writes m to path; format by extension: .obj (+ .mtl beside it when there
 * are materials), .ply (binary little-endian, double positions), .off,
 * .gltf/.glb (through assimp, float positions). */
hlod_result hlod_mesh_export(const char *path, const hlod_mesh *m, const hlod_logger *lg);

/* ---- An OBJ file one object at a time (the sharded build's reader) ----
 *
 * hlod_mesh_import holds the whole file; a shard wants a few of its
 * objects.  hlod_obj_stream reads an OBJ file once to learn its materials
 * and whether faces carry texture coordinates and normals, then again,
 * handing each object (its faces, in file order; the triangles before the
 * first o/g form one named after the file) to a callback as a mesh of its
 * own.  Each such mesh is what hlod_mesh_import's mesh holds of that
 * object: the same vertex values and triangles in the same order, the
 * same materials, cleaned alike (duplicates are dropped within an object).
 * Memory: the v/vt/vn values the kept objects use (all of them unless
 * ranges say which) and one object's faces.
 */
typedef struct hlod_obj_range {
    uint32_t lo, hi;            /* lines [lo, hi) of one kind (0-based); lo == hi: none */
} hlod_obj_range;

typedef struct hlod_obj_info {
    size_t index;               /* k: the k-th object with faces in the file */
    size_t tris;                /* its triangles after cleaning (0: not wanted) */
    hlod_obj_range v, vt, vn;   /* the v, vt and vn lines its faces use */
} hlod_obj_info;

typedef struct hlod_obj_stream_desc {
    const hlod_logger *logger;  /* may be NULL */
    int positions_only;         /* vt/vn values not kept: each object's uvs and
                                   normals (present as in the file) are zero */
    /* the v, vt and vn lines to keep ([3]: v, vt, vn), sorted and
     * disjoint; NULL: every line (keep[k] non-NULL with keep_n[k] = 0:
     * none).  A wanted object that uses another is an error */
    const hlod_obj_range *keep[3];
    size_t keep_n[3];
    /* want(user, k): is the k-th object wanted?  NULL: every one */
    int (*want)(void *user, size_t k);
    /* every object with faces, in file order; mesh is NULL when not wanted
     * (its faces were checked, not kept) and is freed after the call */
    hlod_result (*object)(void *user, const hlod_obj_info *info, const hlod_mesh *mesh);
    void *user;
    size_t lines_kept[3];       /* out: the v, vt and vn lines held in memory */
} hlod_obj_stream_desc;

/* Is path read as OBJ by hlod_mesh_import (its first bytes, else its
 * extension)? */
int hlod_mesh_is_obj(const char *path);

/* Streams path's objects to d->object.  *materials receives the file's
 * material table (materials and material_count only), which every
 * object's mesh points into: it must outlive anything that borrows a
 * texture path.  An error names the file and line; a callback's error
 * stops the stream and is returned. */
hlod_result hlod_obj_stream(const char *path, hlod_obj_stream_desc *d, hlod_mesh *materials);

#ifdef __cplusplus
}
#endif
#endif
