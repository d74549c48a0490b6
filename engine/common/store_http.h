/*
 * store_http.h - the HTTP source of the store reader (store_read.c): range
 * requests through libcurl, internal to hlod_core.
 *
 * One hlod_http per opened URL.  It remembers the validators of the first
 * response (a strong ETag, else Last-Modified) and sends them as If-Range
 * with every later request, and checks each 206's Content-Range (the range
 * asked, the total the file had at open) and ETag: a store replaced on the
 * server fails every read from then on with HLOD_ERR_VERSION (logged once,
 * "URL: the store changed on the server ..."); bytes of two versions are
 * never mixed.  A 200 to a range request without If-Range is a server that
 * ignores ranges (HLOD_ERR_UNSUPPORTED).
 *
 * Transient failures (connection refused or reset, a timeout, a truncated
 * body, 5xx, 408, 429, and a 416 to a range inside the file whose
 * Content-Range total and ETag are still those of open: a glitch of the
 * server or a proxy; a 416 naming another size or ETag is the store
 * changed) are retried from the first byte not yet received,
 * HLOD_HTTP_ATTEMPTS times in all, waiting 100 ms, then 200, 400 ... between
 * tries; then the read fails with HLOD_ERR_IO.  Connections are kept (one
 * per idle handle for blocking reads, the multi handle's cache for parallel
 * ones).  Test hook: a latency (env HLOD_HTTP_LATENCY_MS, or
 * hlod_http_set_latency) added before every request, retries included.
 *
 * Local cache (store_read.c, hlod_store_cache_get/put): env HLOD_CACHE_DIR
 * names a folder that keeps the payloads fetched over HTTP between runs.
 * Each store has its own subfolder, named by a hash of the URL, the
 * validators of open (hlod_http_validators: ETag, Last-Modified), the header
 * and the node table, so a different or changed store never reads another's
 * entries; one file per node index, written to a temporary name and renamed
 * (a killed process leaves no entry half written), and every entry is
 * checked against the node table's checksum before use (a short or
 * mismatching one is deleted and fetched again).  A folder that cannot be
 * made or written is logged once and the run goes on without it.  Only the
 * loader thread and the blocking readers (top nodes at start, hlod-info
 * --verify) use it, never a synchronous (--deterministic) pump.
 */
#ifndef HLOD_STORE_HTTP_H
#define HLOD_STORE_HTTP_H

#include "hlod/hlod.h"

#include <stddef.h>
#include <stdint.h>

#define HLOD_HTTP_ATTEMPTS 6

typedef struct hlod_http hlod_http;

/* 1 when name is an http:// or https:// URL. */
int hlod_http_is_url(const char *name);

/* Opens url: one range request for bytes [0, probe_len) into probe, which
 * records the validators and the file's size (Content-Range's total, in
 * *size).  *got: the bytes that came (fewer when the file is shorter).
 * Errors are logged naming the URL. */
hlod_result hlod_http_open(const char *url, const hlod_logger *lg, void *probe, size_t probe_len,
                           size_t *got, uint64_t *size, hlod_http **out);
void hlod_http_close(hlod_http *h);

/* Blocking: exactly len bytes at off into dst, retried as above.  Any
 * thread (idle handles are pooled under a mutex held only to take or give
 * one back, never across I/O). */
hlod_result hlod_http_read(hlod_http *h, uint64_t off, void *dst, size_t len);

/* The validators the open's response carried ("" when none): the ETag kept
 * (strong only) and Last-Modified. */
void hlod_http_validators(const hlod_http *h, const char **etag, const char **last_modified);

/* Test hook: milliseconds waited before every request (>= 0). */
void hlod_http_set_latency(hlod_http *h, double ms);

/* Where the bytes of a parallel transfer go, in order: returns 0, or
 * non-zero to refuse them (the transfer then fails). */
typedef int (*hlod_http_sink)(void *user, const void *data, size_t n);

/* Parallel transfers (curl multi), owned by one thread. */
typedef struct hlod_http_multi hlod_http_multi;

typedef struct hlod_http_end {
    void *user;             /* the transfer's sink user */
    hlod_result result;     /* HLOD_OK: all its bytes went to the sink */
} hlod_http_end;

hlod_result hlod_http_multi_create(hlod_http *h, unsigned transfers, hlod_http_multi **out);
void hlod_http_multi_destroy(hlod_http_multi *m);
/* Starts a transfer of [off, off + len) into sink(user); user identifies it.
 * HLOD_ERR_INVALID_ARG when every transfer is busy or user has one. */
hlod_result hlod_http_multi_start(hlod_http_multi *m, uint64_t off, uint64_t len,
                                  hlod_http_sink sink, void *user);
/* Stops user's transfer (the bytes its sink took stay taken); no-op when none. */
void hlod_http_multi_stop(hlod_http_multi *m, void *user);
int hlod_http_multi_has(const hlod_http_multi *m, void *user);
unsigned hlod_http_multi_active(const hlod_http_multi *m);
/* Runs the transfers for up to timeout_ms, returning early when one ends
 * or wake_fd (>= 0) is readable.  Writes up to max ended transfers to out
 * and returns how many; *bytes (may be NULL) gets the bytes the sinks took
 * meanwhile. */
size_t hlod_http_multi_poll(hlod_http_multi *m, int timeout_ms, int wake_fd, hlod_http_end *out,
                            size_t max, uint64_t *bytes);

#endif
