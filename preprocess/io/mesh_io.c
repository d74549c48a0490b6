/*
 * hlod_mesh_import / hlod_mesh_export: format dispatch and the checks every
 * format shares (see mesh_io.h).
 *
 * The format is chosen from the first bytes when they are decisive ("ply",
 * an OFF keyword, the binary glTF magic) and from the extension otherwise,
 * so a mis-named PLY or OFF still reads and an unknown file is an explicit
 * HLOD_ERR_UNSUPPORTED.  After a reader returns, texture files are probed
 * (never decoded), then the mesh is validated and cleaned.
 */
#include "io_internal.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>

enum kind { K_UNKNOWN, K_OBJ, K_PLY, K_OFF, K_ASSIMP, K_TILESET };

static int is_off_keyword(const unsigned char *b, size_t n)
{
    size_t i = 0;
    while (i < n && (b[i] == ' ' || b[i] == '\t' || b[i] == '\r' || b[i] == '\n'))
        i++;
    size_t s = i;
    while (i < n && ((b[i] >= 'A' && b[i] <= 'Z') || b[i] == '4' || b[i] == 'n'))
        i++;
    size_t len = i - s;
    /* [ST][C][N][4][n]OFF, then a blank or the end of the line */
    return len >= 3 && len <= 8 && memcmp(b + i - 3, "OFF", 3) == 0 &&
           (i == n || b[i] == ' ' || b[i] == '\t' || b[i] == '\r' || b[i] == '\n');
}

static enum kind detect(const unsigned char *b, size_t n, const char *ext)
{
    if (n >= 4 && memcmp(b, "ply", 3) == 0 && (b[3] == '\n' || b[3] == '\r'))
        return K_PLY;
    if (n >= 4 && memcmp(b, "glTF", 4) == 0)
        return K_ASSIMP;
    if (is_off_keyword(b, n))
        return K_OFF;
    size_t i = 0;
    while (i < n && (b[i] == ' ' || b[i] == '\t' || b[i] == '\r' || b[i] == '\n'))
        i++;
    if (i < n && b[i] == '{' && strcmp(ext, "json") == 0)
        return K_TILESET; /* 3D Tiles: tileset.json */
    if (i < n && b[i] == '{' && strcmp(ext, "obj") != 0)
        return K_ASSIMP; /* glTF JSON, whatever the file is called */
    if (strcmp(ext, "obj") == 0)
        return K_OBJ;
    if (strcmp(ext, "ply") == 0)
        return K_PLY;
    if (strcmp(ext, "off") == 0)
        return K_OFF;
    if (strcmp(ext, "gltf") == 0 || strcmp(ext, "glb") == 0 || (ext[0] && io_assimp_knows(ext)))
        return K_ASSIMP;
    return K_UNKNOWN;
}

/* The reader path needs (its first bytes, else its extension) in *k;
 * logs and returns HLOD_ERR_IO when it cannot be read (lg may be NULL). */
static hlod_result sniff(const char *path, const hlod_logger *lg, enum kind *k)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot open: %s", path, strerror(errno));
        return HLOD_ERR_IO;
    }
    unsigned char magic[64];
    size_t n = fread(magic, 1, sizeof magic, f);
    int err = ferror(f) ? errno : 0;
    fclose(f);
    if (err) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read: %s", path, strerror(err));
        return HLOD_ERR_IO;
    }
    char ext[16];
    io_ext(path, ext, sizeof ext);
    *k = detect(magic, n, ext);
    return HLOD_OK;
}

int hlod_mesh_is_obj(const char *path)
{
    enum kind k;
    return path && sniff(path, NULL, &k) == HLOD_OK && k == K_OBJ;
}

hlod_result hlod_mesh_import(const char *path, const hlod_import_desc *desc, hlod_mesh *out,
                             hlod_import_stats *stats)
{
    hlod_import_stats local;
    hlod_import_stats *st = stats ? stats : &local;
    memset(st, 0, sizeof *st);
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    hlod_mesh_free(out);
    const hlod_logger *lg = desc ? desc->logger : NULL;
    if (!path || !*path) {
        hlod_logf(lg, HLOD_LOG_ERROR, "import: no file name given");
        return HLOD_ERR_INVALID_ARG;
    }

    enum kind kind;
    hlod_result res = sniff(path, lg, &kind);
    if (res != HLOD_OK)
        return res;
    switch (kind) {
    case K_OBJ: res = io_read_obj(path, lg, out, st); break;
    case K_PLY: res = io_read_ply(path, lg, out, st); break;
    case K_OFF: res = io_read_off(path, lg, out, st); break;
    case K_ASSIMP: res = io_read_assimp(path, lg, out, st); break;
    case K_TILESET:
        res = io_read_tileset(path, desc ? desc->scratch_dir : NULL, lg, out, st);
        break;
    default: {
        char ext[16];
        io_ext(path, ext, sizeof ext);
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: unknown mesh format (extension '%s')", path, ext);
        return HLOD_ERR_UNSUPPORTED;
    }
    }
    if (res) {
        hlod_mesh_free(out);
        return res;
    }
    io_check_textures(path, out, lg, st);
    res = hlod_mesh_validate(out, path, lg);
    if (res == HLOD_OK && !(desc && desc->keep_degenerate)) {
        res = hlod_mesh_clean(out, &st->degenerate_dropped, &st->duplicate_dropped);
        if (res == HLOD_OK && out->tri_count == 0) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: all %zu triangles are degenerate or duplicates",
                      path, st->tris_read);
            res = HLOD_ERR_EMPTY;
        }
    }
    if (res) {
        hlod_mesh_free(out);
        return res;
    }
    hlod_logf(lg, HLOD_LOG_INFO,
              "%s: %zu vertices, %zu triangles (%zu read, %zu degenerate and %zu duplicate "
              "dropped), %zu objects, %zu materials, %zu missing textures",
              path, out->vertex_count, out->tri_count, st->tris_read, st->degenerate_dropped,
              st->duplicate_dropped, out->object_count, out->material_count,
              st->missing_textures);
    return HLOD_OK;
}

hlod_result hlod_mesh_export(const char *path, const hlod_mesh *m, const hlod_logger *lg)
{
    if (!path || !*path || !m)
        return HLOD_ERR_INVALID_ARG;
    hlod_result res = hlod_mesh_validate(m, path, lg);
    if (res)
        return res;
    char ext[16];
    io_ext(path, ext, sizeof ext);
    if (strcmp(ext, "obj") == 0)
        return io_write_obj(path, m, lg);
    if (strcmp(ext, "ply") == 0)
        return io_write_ply(path, m, lg);
    if (strcmp(ext, "off") == 0)
        return io_write_off(path, m, lg);
    if (strcmp(ext, "gltf") == 0 || strcmp(ext, "glb") == 0)
        return io_write_gltf(path, m, strcmp(ext, "glb") == 0, lg);
    hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot write extension '%s' (obj, ply, off, gltf, glb)",
              path, ext);
    return HLOD_ERR_UNSUPPORTED;
}
