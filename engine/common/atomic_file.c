/* Temporary-file-and-rename writes: see atomic_file.h. */
#include "atomic_file.h"

#include <errno.h>
#include <fcntl.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

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
