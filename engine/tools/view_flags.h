/*
 * view_flags.h - the command-line flags hlod-bench and hlod-view share:
 * image size, target frame time, memory budget, camera path and its
 * folder, frame count, up axis and field of view.  Each tool keeps its own
 * options struct and defaults; a view_flags points into it.
 */
#ifndef HLOD_VIEW_FLAGS_H
#define HLOD_VIEW_FLAGS_H

#include <stdint.h>

#include "hlod/store.h"

typedef struct view_flags {
    uint32_t *width, *height;          /* --width, --height: 16 to 16384 */
    double *target_ms;                 /* --target-ms: > 0 */
    double *memory_mb;                 /* --memory-mb: > 0 */
    double *fov;                       /* --fov: 1 to 170 degrees */
    const char **path, **paths_dir;    /* --path, --paths-dir */
    long *frames;                      /* --frames: 1 to 1e8 */
    int *up_y;                         /* --up z|y */
} view_flags;

/* If argv[*i] is one of the shared flags, stores its value through f (*i
 * advances past a separate value) and returns 1; returns 0 when it is not
 * one of them, and -1 after printing the error when its value is missing
 * or wrong (the tool then exits with status 2). */
int view_flags_parse(const char *prog, int argc, char **argv, int *i, const view_flags *f);

/* The memory budget when --memory-mb is not given: the whole store
 * decoded (hlod_store_memory_bytes; a scene that fits is loaded once),
 * capped at a quarter of the machine's physical memory (the store then
 * streams within it). */
uint64_t view_default_budget(const hlod_store *s);

#endif
