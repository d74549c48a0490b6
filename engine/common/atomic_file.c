/* Temporary-file-and-rename writes: see atomic_file.h. */
#include "atomic_file.h"

#include <dirent.h>
#include <errno.h>
#include <ftw.h>
#include <fcntl.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

/* Removes the temporary files of path that killed writers left: named
 * "<name>.tmp-" plus six characters, not ours, unlocked, over a minute old. */
static void sweep_stale(const char *path, const char *ours, const hlod_logger *lg)
{
    const char *slash = strrchr(path, '/');
    size_t dlen = slash ? (size_t)(slash - path) : 0;
    const char *name = slash ? slash + 1 : path;
    char dir[4096];
    if (dlen >= sizeof dir)
        return;
    if (slash) {
        memcpy(dir, path, dlen);
        dir[dlen] = 0;
        if (!dlen)
            strcpy(dir, "/");
    } else {
        strcpy(dir, ".");
    }
    DIR *d = opendir(dir);
    if (!d)
        return;
    size_t nlen = strlen(name);
    struct dirent *de;
    while ((de = readdir(d)) != NULL) {
        const char *e = de->d_name;
        if (strncmp(e, name, nlen) != 0 || strncmp(e + nlen, ".tmp-", 5) != 0 ||
            strlen(e + nlen + 5) != 6)
            continue;
        char full[8192];
        if (snprintf(full, sizeof full, "%s/%s", dir, e) >= (int)sizeof full ||
            (ours && strcmp(strrchr(ours, '/') ? strrchr(ours, '/') + 1 : ours, e) == 0))
            continue;
        int fd = open(full, O_RDONLY | O_NOFOLLOW | O_CLOEXEC);
        if (fd < 0)
            continue;
        struct stat sb;
        if (fstat(fd, &sb) == 0 && S_ISREG(sb.st_mode) && time(NULL) - sb.st_mtime > 60 &&
            flock(fd, LOCK_EX | LOCK_NB) == 0) {
            if (unlink(full) == 0)
                hlod_logf(lg, HLOD_LOG_INFO, "%s: removed %s, left by a killed run", path, e);
        }
        close(fd); /* drops our lock, if any */
    }
    closedir(d);
}

hlod_result hlod_atomic_open(hlod_atomic_file *f, const char *path, const hlod_logger *lg)
{
    memset(f, 0, sizeof *f);
    if (!path || !*path)
        return HLOD_ERR_INVALID_ARG;
    size_t n = strlen(path);
    f->final_path = malloc(n + 1);
    f->tmp_path = malloc(n + 16);
    if (!f->final_path || !f->tmp_path) {
        hlod_atomic_abort(f);
        return HLOD_ERR_NOMEM;
    }
    memcpy(f->final_path, path, n + 1);
    snprintf(f->tmp_path, n + 16, "%s.tmp-XXXXXX", path);
    int fd = mkstemp(f->tmp_path);
    if (fd < 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create output: %s", path, strerror(errno));
        free(f->tmp_path);
        f->tmp_path = NULL;
        hlod_atomic_abort(f);
        return HLOD_ERR_IO;
    }
    fchmod(fd, 0644);
    flock(fd, LOCK_EX | LOCK_NB); /* ours alone: nobody else opened it yet */
    sweep_stale(path, f->tmp_path, lg);
    f->fp = fdopen(fd, "wb");
    if (!f->fp) {
        close(fd);
        hlod_atomic_abort(f);
        return HLOD_ERR_IO;
    }
    return HLOD_OK;
}

hlod_result hlod_atomic_commit(hlod_atomic_file *f, const hlod_logger *lg)
{
    if (!f->fp)
        return HLOD_ERR_INVALID_ARG;
    int bad = ferror(f->fp) || fflush(f->fp) != 0 || fsync(fileno(f->fp)) != 0;
    int err = errno;
    if (fclose(f->fp) != 0 && !bad) {
        bad = 1;
        err = errno;
    }
    f->fp = NULL;
    if (!bad && rename(f->tmp_path, f->final_path) != 0) {
        bad = 1;
        err = errno;
    }
    if (bad) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: write failed: %s", f->final_path, strerror(err));
        hlod_atomic_abort(f);
        return HLOD_ERR_IO;
    }
    free(f->tmp_path);
    free(f->final_path);
    f->tmp_path = f->final_path = NULL;
    return HLOD_OK;
}

void hlod_atomic_abort(hlod_atomic_file *f)
{
    if (f->fp)
        fclose(f->fp);
    if (f->tmp_path)
        unlink(f->tmp_path);
    free(f->tmp_path);
    free(f->final_path);
    memset(f, 0, sizeof *f);
}

static int rm_entry(const char *path, const struct stat *sb, int flag, struct FTW *ftw)
{
    (void)sb;
    (void)flag;
    (void)ftw;
    return remove(path);
}

void hlod_rm_tree(const char *dir)
{
    nftw(dir, rm_entry, 16, FTW_DEPTH | FTW_PHYS);
}

int hlod_mkdir_p(const char *path, unsigned mode)
{
    size_t n = strlen(path);
    char *p = malloc(n + 1);
    if (!p)
        return ENOMEM;
    memcpy(p, path, n + 1);
    int e = 0;
    for (char *c = p + 1; n && !e; c++) {
        char keep = *c;
        if (keep != '/' && keep != 0)
            continue;
        *c = 0;
        e = mkdir(p, (mode_t)mode) == 0 || errno == EEXIST ? 0 : errno;
        *c = keep;
        if (!keep)
            break;
    }
    struct stat st;
    if (!e)
        e = stat(p, &st) != 0 ? errno : S_ISDIR(st.st_mode) ? 0 : ENOTDIR;
    free(p);
    return e;
}

int hlod_flush_sync(FILE *fp)
{
    return !ferror(fp) && fflush(fp) == 0 && fsync(fileno(fp)) == 0;
}

int hlod_is_file(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode);
}
