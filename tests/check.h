/*
 * check.h - the tests' tiny assertion kit.
 *
 * CHECK(cond) records a failure with file:line and keeps going; RUN(fn)
 * runs one test function; check_done() prints "N passed, N failed" and
 * returns the exit code (non-zero if any CHECK failed anywhere).  Each test program is one ctest test.
 */
#ifndef HLOD_CHECK_H
#define HLOD_CHECK_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>

static int check_failures_, check_passed_, check_failed_;

#define CHECK(cond)                                                                   \
    do {                                                                              \
        if (!(cond)) {                                                                \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond);  \
            check_failures_++;                                                        \
        }                                                                             \
    } while (0)

#define CHECKF(cond, ...)                                                             \
    do {                                                                              \
        if (!(cond)) {                                                                \
            fprintf(stderr, "%s:%d: CHECK failed: %s: ", __FILE__, __LINE__, #cond);  \
            fprintf(stderr, __VA_ARGS__);                                             \
            fputc('\n', stderr);                                                      \
            check_failures_++;                                                        \
        }                                                                             \
    } while (0)

#define RUN(fn)                                                                       \
    do {                                                                              \
        int before_ = check_failures_;                                                \
        fn();                                                                         \
        if (check_failures_ == before_) {                                             \
            check_passed_++;                                                          \
            fprintf(stderr, "ok   %s\n", #fn);                                        \
        } else {                                                                      \
            check_failed_++;                                                          \
            fprintf(stderr, "FAIL %s\n", #fn);                                        \
        }                                                                             \
    } while (0)

/* Fails when any CHECK failed, inside a RUN or not: a failed set-up check
 * in main (tools missing, a store not built) must not let the program
 * pass with nothing tested. */
static inline int check_done(void)
{
    printf("%d passed, %d failed\n", check_passed_, check_failed_);
    if (check_failures_ && !check_failed_)
        printf("%d checks failed outside the tests\n", check_failures_);
    return check_failures_ ? 1 : 0;
}

/* Path of a file under the source tree ($HLOD_SOURCE_DIR, else "."). */
static inline const char *check_src_path(const char *rel, char *buf, size_t n)
{
    const char *root = getenv("HLOD_SOURCE_DIR");
    snprintf(buf, n, "%s/%s", root ? root : ".", rel);
    return buf;
}

/* Runs a shell command built printf-style; its exit status, or -1 when it
 * did not exit normally. */
static inline int check_sh(const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 1, 2)))
#endif
    ;
static inline int check_sh(const char *fmt, ...)
{
    char cmd[4096];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(cmd, sizeof cmd, fmt, ap);
    va_end(ap);
    int rc = system(cmd);
    return WIFEXITED(rc) ? WEXITSTATUS(rc) : -1;
}

#endif
