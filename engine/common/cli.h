/*
 * cli.h - helpers shared by the hlod-<verb> command-line tools.
 *
 * - A progress bar on stderr, drawn only when stderr is a terminal, that
 *   plugs into any hlod_progress_fn:
 *       [#####.....] 45% 1.2 Mtri  ETA 3s
 *   redrawn at most 10 times a second and erased when the work ends, so
 *   logs and pipes never see it.
 * - A logger that erases the bar before it prints, so messages and the bar
 *   never share a line.
 * - Strict flag parsing: the whole argument must be a finite number inside
 *   the allowed range ("12abc", " 12", "nan", "-3" for a count are refused)
 *   and the error names the flag.
 * - A one-line JSON writer for flat objects: keys in the order written,
 *   doubles as %.17g (round-trip exact), NaN and infinities as null.
 * - Monotonic clock and peak resident memory.
 *
 * Not part of the public API (tools only).  Thread safety: a progress bar
 * and a JSON writer belong to the thread that created them; the clock and
 * memory functions may be called from any thread.
 */
#ifndef HLOD_CLI_H
#define HLOD_CLI_H

#include <stdio.h>
#include "hlod/hlod.h"

/* ---- progress bar ---- */

typedef struct hlod_cli_progress {
    int enabled;            /* 0: every call is a no-op */
    const char *unit;       /* shown after the count, e.g. "tri"; may be NULL */
    double start;           /* hlod_cli_now() at begin */
    double last_draw;       /* hlod_cli_now() at the last redraw */
    int drawn;              /* characters on the terminal line now, 0 = clear */
} hlod_cli_progress;

/* Starts a bar.  It is enabled only when `show` is non-zero and stderr is a
 * terminal.  unit names what done/total count (the string must outlive p). */
void hlod_cli_progress_begin(hlod_cli_progress *p, const char *unit, int show);

/* hlod_progress_fn: pass the hlod_cli_progress as user_data.  Redraws when
 * 0.1 s have passed since the last redraw; never cancels (returns 0).
 * Called from the thread that runs the work. */
int hlod_cli_progress_fn(void *user_data, double done, double total);

/* Erases the bar from the terminal (call when the work ends, before any
 * other output).  The bar may be drawn again by later progress calls. */
void hlod_cli_progress_clear(hlod_cli_progress *p);

/* ---- logging ---- */

typedef struct hlod_cli_log {
    const char *prog;           /* message prefix, e.g. "hlod-simplify" */
    hlod_log_level max_level;   /* messages above it are dropped */
    hlod_cli_progress *bar;     /* erased before each message; may be NULL */
} hlod_cli_log;

/* A logger writing "PROG: error: msg" lines to stderr.  `state` must outlive
 * the logger. */
hlod_logger hlod_cli_logger(hlod_cli_log *state);

/* "PROG: error: ..." on stderr (a trailing newline is added). */
void hlod_cli_error(const char *prog, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 2, 3)))
#endif
    ;

/* ---- flags ---- */

/* Matches "--flag VALUE" and "--flag=VALUE" at argv[*i]: returns 1 and sets
 * *value (NULL when the value is missing; *i advances past a separate
 * value) when argv[*i] is the flag, else 0. */
int hlod_cli_match_flag(int argc, char **argv, int *i, const char *flag, const char **value);

/* "PROG: error: <fmt with arg>" and "try 'PROG --help'" on stderr;
 * returns 2, the exit status for a bad command line. */
int hlod_cli_usage_error(const char *prog, const char *fmt, const char *arg);

/* ---- flag values ---- */

/* Range flags for hlod_cli_parse_double. */
#define HLOD_CLI_MIN_OPEN 1u    /* value must be > min (default >= min) */
#define HLOD_CLI_MAX_OPEN 2u    /* value must be < max (default <= max) */

/* Parses text (the value of flag) as a finite double in [min, max] (ends
 * opened by `open`).  On failure prints "PROG: error: FLAG: ..." to stderr
 * and returns 0; on success stores *out and returns 1. */
int hlod_cli_parse_double(const char *prog, const char *flag, const char *text,
                          double min, double max, unsigned open, double *out);

/* Parses text as a decimal integer in [min, max]; a sign, spaces, a fraction
 * or an exponent are refused.  Same reporting as hlod_cli_parse_double. */
int hlod_cli_parse_size(const char *prog, const char *flag, const char *text,
                        size_t min, size_t max, size_t *out);

/* ---- JSON ---- */

typedef struct hlod_json {
    FILE *fp;
    int count;              /* members written so far */
} hlod_json;

/* Writes "{"; members follow in call order; hlod_json_end writes "}\n" and
 * returns 0 when every byte reached fp (ferror/fflush), else -1.  Keys are
 * written as given (callers use plain ASCII identifiers); string values are
 * escaped. */
void hlod_json_begin(hlod_json *j, FILE *fp);
void hlod_json_double(hlod_json *j, const char *key, double v);
void hlod_json_size(hlod_json *j, const char *key, size_t v);
void hlod_json_int(hlod_json *j, const char *key, long long v);
void hlod_json_bool(hlod_json *j, const char *key, int v);
void hlod_json_string(hlod_json *j, const char *key, const char *v); /* NULL -> null */
int hlod_json_end(hlod_json *j);
/* A member `key` of j that is an object: writes `"key": {` and starts
 * inner on j's stream; its members follow on inner, then
 * hlod_json_object_end(inner) writes "}". */
void hlod_json_object(hlod_json *j, const char *key, hlod_json *inner);
void hlod_json_object_end(hlod_json *inner);

/* ---- measurement ---- */

/* Seconds on the monotonic clock (arbitrary origin). */
double hlod_cli_now(void);

/* Peak resident set size of this process so far, in bytes (getrusage
 * ru_maxrss); 0 if unknown. */
size_t hlod_cli_peak_rss(void);

/* CPU seconds this process has used so far, user and system, all its
 * threads (getrusage); 0 if unknown. */
double hlod_cli_cpu_seconds(void);

#endif
