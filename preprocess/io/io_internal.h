/*
 * io_internal.h - pieces shared by the mesh readers and writers.
 *
 * io_stream reads a file in large chunks and hands out either lines
 * (NUL-terminated, '\r' stripped, modifiable in place) or runs of raw bytes
 * that stay valid until the next call; neither ever holds the whole file
 * unless a single line is that long.  io_parse_double is exact: it takes
 * Clinger's fast path when the decimal fits a double's mantissa and a power
 * of ten that is itself exact, and otherwise hands the token to fast_float
 * (io_from_chars, parse_double.cpp; strtod for hex floats), both correctly
 * rounded, so 17-digit decimals round-trip bit for bit.
 *
 * Every reader fills an hlod_mesh and returns an hlod_result; it logs its
 * own errors (naming the file and line or element) through the logger.
 */
#ifndef HLOD_IO_INTERNAL_H
#define HLOD_IO_INTERNAL_H

#include <stdint.h>
#include <stdio.h>

#include "hlod/mesh_io.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct io_stream {
    FILE *fp;
    const char *path;       /* for messages; not owned */
    const hlod_logger *lg;
    char *buf;
    size_t cap, pos, end;   /* valid bytes are buf[pos..end) */
    uint64_t file_size;     /* 0 when unknown */
    uint64_t consumed;      /* bytes handed out so far */
    size_t line;            /* number of the last line returned, 1-based */
    int eof, error;
} io_stream;

/* Opens path for reading; logs "path: strerror" and returns HLOD_ERR_IO. */
hlod_result io_open(io_stream *s, const char *path, const hlod_logger *lg);
void io_close(io_stream *s);
/* Next line in *line (len in *len, may be NULL); returns 0 at end of file or
 * on a read error (then s->error is set and has been logged). */
int io_line(io_stream *s, char **line, size_t *len);
/* Pointer to the next n bytes, then consumed; NULL when fewer remain. */
const uint8_t *io_bytes(io_stream *s, size_t n);
/* Bytes not yet consumed (meaningful only when file_size is known). */
uint64_t io_remaining(const io_stream *s);

/* Number parsing.  Both skip leading blanks (space, tab), accept the
 * number and advance *p past it; they return 0 when no number starts at *p
 * or the number is not followed by a blank, '/', or the end of the string. */
int io_parse_double(const char **p, double *out);
/* fast_float on exactly [first, last): 1 and *out when it is all one
 * decimal (or nan/inf), else 0.  No leading '+'. */
int io_from_chars(const char *first, const char *last, double *out);
int io_parse_long(const char **p, long long *out);
/* Skips blanks; returns the first non-blank character (0 at the end). */
static inline char io_skip_blanks(const char **p)
{
    const char *s = *p;
    while (*s == ' ' || *s == '\t')
        s++;
    *p = s;
    return *s;
}

/* A growable array of fixed-size elements. */
typedef struct io_vec {
    void *data;
    size_t count, cap;
} io_vec;

/* Appends n uninitialised elements; returns a pointer to them or NULL. */
void *io_vec_push(io_vec *v, size_t elem_size, size_t n);
/* Ensures room for `total` elements without changing count. */
int io_vec_reserve(io_vec *v, size_t elem_size, size_t total);
/* Hands the array over (shrunk to fit) and empties v. */
void *io_vec_take(io_vec *v, size_t elem_size);
void io_vec_free(io_vec *v);

/* A string -> index map (open addressing) for material names. */
typedef struct io_strmap {
    char **keys;
    uint32_t *vals;
    size_t count, cap;
} io_strmap;

/* Value stored for key, or -1. */
long io_strmap_get(const io_strmap *m, const char *key);
/* Inserts or replaces; returns 0 when out of memory. */
int io_strmap_put(io_strmap *m, const char *key, uint32_t val);
void io_strmap_free(io_strmap *m);

char *io_strdup(const char *s);
char *io_strndup(const char *s, size_t n);
/* "dir/name.ext" -> "name"; malloc'ed. */
char *io_file_stem(const char *path);
/* Folder part of path including the trailing '/', "" when none; malloc'ed. */
char *io_dirname(const char *path);
/* dir + rel unless rel is absolute; malloc'ed. */
char *io_join(const char *dir, const char *rel);
/* Lower-case extension without the dot ("" when none), into buf. */
const char *io_ext(const char *path, char *buf, size_t n);
int io_file_exists(const char *path);

/* Readers (one per file).  Each returns with *out empty on failure. */
hlod_result io_read_obj(const char *path, const hlod_logger *lg, hlod_mesh *out,
                        hlod_import_stats *st);
hlod_result io_read_ply(const char *path, const hlod_logger *lg, hlod_mesh *out,
                        hlod_import_stats *st);
hlod_result io_read_off(const char *path, const hlod_logger *lg, hlod_mesh *out,
                        hlod_import_stats *st);
/* tiles_read.c: a 3D Tiles tileset.json; embedded images go to scratch. */
hlod_result io_read_tileset(const char *path, const char *scratch, const hlod_logger *lg,
                            hlod_mesh *out, hlod_import_stats *st);
hlod_result io_read_assimp(const char *path, const hlod_logger *lg, hlod_mesh *out,
                           hlod_import_stats *st);
int io_assimp_knows(const char *ext);

/* Writers.  m has been validated; each writes through atomic_file.h. */
hlod_result io_write_obj(const char *path, const hlod_mesh *m, const hlod_logger *lg);
hlod_result io_write_ply(const char *path, const hlod_mesh *m, const hlod_logger *lg);
hlod_result io_write_off(const char *path, const hlod_mesh *m, const hlod_logger *lg);
hlod_result io_write_gltf(const char *path, const hlod_mesh *m, int binary,
                          const hlod_logger *lg);

/* Path of `target` relative to folder `dir` when both can be resolved, else
 * target's absolute path; used to reference textures from a written file. */
char *io_relative_path(const char *dir, const char *target);

/* A material whose texture file is missing becomes untextured, with a
 * warning naming the file, the material and the texture. */
void io_check_textures(const char *path, hlod_mesh *m, const hlod_logger *lg,
                       hlod_import_stats *st);

/* Ends a single-object reader (PLY, OFF): on success the mesh becomes one
 * object named after the file's stem and st->tris_read is set; on failure
 * (out of memory logged) the mesh is freed.  Returns the final result. */
hlod_result io_finish_file_mesh(const char *path, const hlod_logger *lg, hlod_result res, hlod_mesh *out,
                                hlod_import_stats *st);

#ifdef __cplusplus
}
#endif

#endif
