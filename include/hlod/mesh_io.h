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

#ifdef __cplusplus
}
#endif
#endif
