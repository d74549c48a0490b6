/*
 * view_flags.c - the flags hlod-bench and hlod-view share (view_flags.h).
 */
#include "view_flags.h"

#include <string.h>
#include <unistd.h>

#include "cli.h"

int view_flags_parse(const char *prog, int argc, char **argv, int *i, const view_flags *f)
{
    static const char *const names[] = {"--width", "--height", "--target-ms", "--memory-mb", "--fov",
                                        "--path",  "--paths-dir", "--frames", "--up"};
    const char *v = NULL;
    size_t k, n;
    for (k = 0; k < sizeof names / sizeof *names; k++)
        if (hlod_cli_match_flag(argc, argv, i, names[k], &v))
            break;
    if (k == sizeof names / sizeof *names)
        return 0;
    const char *flag = names[k];
    if (!v) {
        hlod_cli_usage_error(prog, "%s needs a value", flag);
        return -1;
    }
    switch (k) {
    case 0:
    case 1:
        if (!hlod_cli_parse_size(prog, flag, v, 16, 16384, &n))
            return -1;
        *(k == 0 ? f->width : f->height) = (uint32_t)n;
        return 1;
    case 2:
        return hlod_cli_parse_double(prog, flag, v, 0, 1e6, HLOD_CLI_MIN_OPEN, f->target_ms) ? 1 : -1;
    case 3:
        return hlod_cli_parse_double(prog, flag, v, 0, 1e9, HLOD_CLI_MIN_OPEN, f->memory_mb) ? 1 : -1;
    case 4:
        return hlod_cli_parse_double(prog, flag, v, 1, 170, 0, f->fov) ? 1 : -1;
    case 5:
        *f->path = v;
        return 1;
    case 6:
        *f->paths_dir = v;
        return 1;
    case 7:
        if (!hlod_cli_parse_size(prog, flag, v, 1, 100000000, &n))
            return -1;
        *f->frames = (long)n;
        return 1;
    default:
        if (strcmp(v, "z") && strcmp(v, "y")) {
            hlod_cli_usage_error(prog, "--up must be z or y, not '%s'", v);
            return -1;
        }
        *f->up_y = v[0] == 'y';
        return 1;
    }
}

uint64_t view_default_budget(const hlod_store *s)
{
    uint64_t whole = hlod_store_memory_bytes(s);
    long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
    uint64_t share = pages > 0 && page > 0 ? (uint64_t)pages * (uint64_t)page / 4 : 512ull << 20;
    return whole < share ? whole : share;
}
