/*
 * atomic_file.h - write a file so that it appears whole or not at all.
 *
 * Opens "PATH.tmp-XXXXXX" in PATH's folder; commit flushes, fsyncs and
 * renames it over PATH; abort removes it.  A killed process leaves at most a
 * stray .tmp- file, never a half-written PATH.
 *
 * Stray files do not pile up: the writer holds an exclusive flock on its
 * temporary file (the kernel drops it when the process dies), and open
 * removes any "PATH.tmp-??????" that nobody holds and that is over a
 * minute old (older than the moment between mkstemp and flock).
 */
#ifndef HLOD_ATOMIC_FILE_H
#define HLOD_ATOMIC_FILE_H

#include <stdio.h>
#include "hlod/hlod.h"

typedef struct hlod_atomic_file {
    FILE *fp;               /* write here */
    char *final_path;
    char *tmp_path;
} hlod_atomic_file;

hlod_result hlod_atomic_open(hlod_atomic_file *f, const char *path, const hlod_logger *lg);
/* Commits (returns the first write/flush/rename error, after aborting). */
hlod_result hlod_atomic_commit(hlod_atomic_file *f, const hlod_logger *lg);
void hlod_atomic_abort(hlod_atomic_file *f);

/* Removes a folder and everything under it (symbolic links are removed,
 * not followed); best effort, for temporary folders. */
void hlod_rm_tree(const char *dir);

/* mkdir -p: creates path and every missing folder above it with mode.
 * 0 when path is then a folder, else an errno (ENOTDIR where a file
 * stands in the way). */
int hlod_mkdir_p(const char *path, unsigned mode);

/* Flushes and fsyncs fp without closing it (so that two files are both
 * on disk before either is renamed): 1 on success. */
int hlod_flush_sync(FILE *fp);

/* 1 when path names a regular file (after symbolic links). */
int hlod_is_file(const char *path);

#endif
