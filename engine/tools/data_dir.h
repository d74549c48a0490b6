/*
 * data_dir.h - where the engine tools (hlod-bench, hlod-view) find their
 * data: the built-in camera paths, DIR/paths/default/ and DIR/paths/small/.
 *
 * An installed tool (PREFIX/bin/hlod-bench) uses PREFIX/share/hlod: the
 * folder HLOD_DATA_REL names relative to the tool's own executable
 * (/proc/self/exe, links resolved), when it holds paths/.  A tool run from
 * the build tree, where there is no such folder, uses the source tree's
 * data/ (HLOD_DATA_DIR, compiled in).  So an installed prefix may be moved
 * and does not need the source tree.
 */
#ifndef HLOD_TOOLS_DATA_DIR_H
#define HLOD_TOOLS_DATA_DIR_H

#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#ifndef HLOD_DATA_DIR
#define HLOD_DATA_DIR "data"
#endif
#ifndef HLOD_DATA_REL
#define HLOD_DATA_REL "../share/hlod"
#endif

/* The data folder, without a trailing slash; the same string every call. */
static inline const char *hlod_tool_data_dir(void)
{
    static char dir[PATH_MAX];
    if (dir[0])
        return dir;
    char exe[PATH_MAX], cand[PATH_MAX + 64];
    ssize_t n = readlink("/proc/self/exe", exe, sizeof exe - 1);
    char *slash = NULL;
    if (n > 0) {
        exe[n] = 0;
        slash = strrchr(exe, '/');
    }
    if (slash) {
        *slash = 0;
        struct stat sb;
        int len = snprintf(cand, sizeof cand, "%s/" HLOD_DATA_REL, exe);
        if (len > 0 && (size_t)len < sizeof cand && realpath(cand, dir) &&
            strlen(dir) + sizeof "/paths" <= sizeof cand) {
            snprintf(cand, sizeof cand, "%s/paths", dir);
            if (stat(cand, &sb) == 0 && S_ISDIR(sb.st_mode))
                return dir;
        }
    }
    snprintf(dir, sizeof dir, "%s", HLOD_DATA_DIR);
    return dir;
}

/* DATA/paths/default: where --path looks up a built-in name by default. */
static inline const char *hlod_tool_default_paths_dir(void)
{
    static char dir[PATH_MAX + 32];
    if (!dir[0])
        snprintf(dir, sizeof dir, "%s/paths/default", hlod_tool_data_dir());
    return dir;
}

#endif
