/*
 * hlod.h - results, logging and allocation shared by every hlod library.
 *
 * Every fallible function returns an hlod_result and reports details (file
 * name, element, line) through an optional hlod_logger.  Library code never
 * prints; tools install a logger that writes to stderr, tests install one
 * that records messages so they can assert on them.
 *
 * Thread safety: everything here may be called from any thread.  A logger's
 * callback may be invoked from the engine's loader thread, so it must be
 * thread safe if the engine is used.
 */
#ifndef HLOD_HLOD_H
#define HLOD_HLOD_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

typedef enum hlod_result {
    HLOD_OK = 0,
    HLOD_ERR_INVALID_ARG,   /* a NULL or out-of-range argument */
    HLOD_ERR_NOMEM,         /* an allocation failed */
    HLOD_ERR_IO,            /* a file could not be opened, read or written */
    HLOD_ERR_FORMAT,        /* bytes do not follow the file format */
    HLOD_ERR_UNSUPPORTED,   /* a valid file using a feature we do not read */
    HLOD_ERR_NAN,           /* a NaN or infinite coordinate */
    HLOD_ERR_INDEX_RANGE,   /* an index refers past the end of its array */
    HLOD_ERR_EMPTY,         /* no triangles left to work on */
    HLOD_ERR_CHECKSUM,      /* stored checksum does not match the data */
    HLOD_ERR_VERSION,       /* file written by an incompatible version */
    HLOD_ERR_CANCELLED,     /* a progress callback asked to stop */
    HLOD_RESULT_COUNT
} hlod_result;

/* Short, stable, lower-case description ("invalid argument", ...). */
const char *hlod_result_str(hlod_result r);

typedef enum hlod_log_level {
    HLOD_LOG_ERROR = 0,
    HLOD_LOG_WARN = 1,
    HLOD_LOG_INFO = 2,
    HLOD_LOG_DEBUG = 3
} hlod_log_level;

/* A logger: func may be NULL (messages are dropped).  msg is a complete line
 * without a trailing newline, valid only during the call. */
typedef struct hlod_logger {
    void (*func)(void *user_data, hlod_log_level level, const char *msg);
    void *user_data;
} hlod_logger;

/* printf-style logging through lg (which may be NULL). */
void hlod_logf(const hlod_logger *lg, hlod_log_level level, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 3, 4)))
#endif
    ;

/* Progress callback: done/total in any unit; return non-zero to cancel. */
typedef int (*hlod_progress_fn)(void *user_data, double done, double total);

#ifdef __cplusplus
}
#endif
#endif
