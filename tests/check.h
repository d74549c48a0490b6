/*
 * check.h - the tests' tiny assertion kit.
 *
 * CHECK(cond) records a failure with file:line and keeps going; RUN(fn)
 * runs one test function; check_done() prints "N passed, N failed, N
 * skipped" and returns the exit code (non-zero if any CHECK failed
 * anywhere).  Each test program is one ctest test.
 *
 * No test passes empty: every CHECK that is evaluated is counted, and a
 * RUN whose function evaluated none fails ("made no check").  A test that
 * cannot run here says so with CHECK_SKIP(reason...) and returns: it is
 * reported as SKIP, not ok; under the test command (HLOD_TEST_STRICT=1,
 * set by tests/run.sh) a skip is a failure, since everything a test needs
 * is installed there.
 */
#ifndef HLOD_CHECK_H
#define HLOD_CHECK_H

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>

static int check_failures_, check_passed_, check_failed_, check_skipped_;
static long check_count_;   /* CHECKs evaluated, pass or fail */
static int check_skip_;     /* the running test called CHECK_SKIP */

#define CHECK(cond)                                                                   \
    do {                                                                              \
        check_count_++;                                                               \
        if (!(cond)) {                                                                \
            fprintf(stderr, "%s:%d: CHECK failed: %s\n", __FILE__, __LINE__, #cond);  \
            check_failures_++;                                                        \
        }                                                                             \
    } while (0)

#define CHECKF(cond, ...)                                                             \
    do {                                                                              \
        check_count_++;                                                               \
        if (!(cond)) {                                                                \
            fprintf(stderr, "%s:%d: CHECK failed: %s: ", __FILE__, __LINE__, #cond);  \
            fprintf(stderr, __VA_ARGS__);                                             \
            fputc('\n', stderr);                                                      \
            check_failures_++;                                                        \
        }                                                                             \
    } while (0)

/* The running test cannot run here (a tool not built, a variable unset):
 * says why; the caller returns.  A failure under the test command. */
#define CHECK_SKIP(...)                                                               \
    do {                                                                              \
        fprintf(stderr, "%s:%d: skip: ", __FILE__, __LINE__);                         \
        fprintf(stderr, __VA_ARGS__);                                                 \
        fputc('\n', stderr);                                                          \
        check_skip_ = 1;                                                              \
    } while (0)

/* Under the test command (tests/run.sh) nothing may be skipped. */
static inline int check_strict(void)
{
    const char *s = getenv("HLOD_TEST_STRICT");
    return s && *s && strcmp(s, "0") != 0;
}

/* The ThreadSanitizer build exists to find races: a test program there
 * runs what spawns threads (RUN) and leaves single-threaded work, which
 * the plain and ASan builds run, out (RUN_UNTHREADED: not run, and not
 * reported as a skip). */
#if defined(__SANITIZE_THREAD__)
#define CHECK_TSAN 1
#elif defined(__has_feature)
#if __has_feature(thread_sanitizer)
#define CHECK_TSAN 1
#endif
#endif
#ifndef CHECK_TSAN
#define CHECK_TSAN 0
#endif
#define RUN_UNTHREADED(fn)                                                            \
    do {                                                                              \
        if (!CHECK_TSAN)                                                              \
            RUN(fn);                                                                  \
    } while (0)

#define RUN(fn)                                                                       \
    do {                                                                              \
        int before_ = check_failures_;                                                \
        long count_ = check_count_;                                                   \
        check_skip_ = 0;                                                              \
        fn();                                                                         \
        if (check_skip_ && check_failures_ == before_ && !check_strict()) {           \
            check_skipped_++;                                                         \
            fprintf(stderr, "SKIP %s\n", #fn);                                        \
        } else if (check_skip_ && check_failures_ == before_) {                       \
            check_failures_++;                                                        \
            check_failed_++;                                                          \
            fprintf(stderr, "FAIL %s: skipped under HLOD_TEST_STRICT\n", #fn);         \
        } else if (check_failures_ == before_ && check_count_ == count_) {            \
            check_failures_++;                                                        \
            check_failed_++;                                                          \
            fprintf(stderr, "FAIL %s: made no check\n", #fn);                          \
        } else if (check_failures_ == before_) {                                      \
            check_passed_++;                                                          \
            fprintf(stderr, "ok   %s (%ld checks)\n", #fn, check_count_ - count_);     \
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
    printf("%d passed, %d failed, %d skipped\n", check_passed_, check_failed_, check_skipped_);
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

/* A whole file, NUL-terminated (text can be searched as a string); *n
 * (may be NULL) gets its size.  NULL when it cannot be read. */
static inline char *check_slurp(const char *path, size_t *n)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long len = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *b = malloc(len > 0 ? (size_t)len + 1 : 1);
    if (b && len > 0 && fread(b, 1, (size_t)len, f) != (size_t)len) {
        free(b);
        b = NULL;
    }
    if (b)
        b[len > 0 ? len : 0] = 0;
    fclose(f);
    if (n)
        *n = len > 0 ? (size_t)len : 0;
    return b;
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
