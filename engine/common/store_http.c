/*
 * store_http.c - range requests for the store reader through libcurl
 * (store_http.h has the contract).
 *
 * One transfer (struct xfer) is one easy handle with its callbacks: the
 * header callback keeps the response's Content-Range, ETag and
 * Last-Modified; the body callback checks the response before the first
 * byte goes anywhere (206, the range asked, the total and the ETag seen at
 * open; a 200 means the If-Range validator no longer matches, or, before
 * there is one, a server that ignores ranges) and refuses the body
 * otherwise, so no byte of another version or range reaches a payload.
 * classify() turns the outcome into done, retry (from the first byte not
 * yet received) or fail.  Blocking reads run a transfer with
 * curl_easy_perform; parallel ones add it to a multi handle.
 */
#include "store_http.h"

#include <curl/curl.h>
#include <stddef.h>
#include <errno.h>
#include <inttypes.h>
#include <poll.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <time.h>
#include <unistd.h>

#define HTTP_BACKOFF_MS 100.0       /* first retry's wait, doubled each time */
#define HTTP_CONNECT_TIMEOUT_MS 5000L
#define HTTP_LOW_SPEED_BYTES 64L    /* a transfer under this many bytes/s ... */
#define HTTP_LOW_SPEED_S 15L        /* ... for this long is dropped and retried */
#define HTTP_POOL 8                 /* idle handles kept for blocking reads */

struct hlod_http {
    char *url;
    char *cainfo;       /* CA bundle for https (env CURL_CA_BUNDLE or
                           SSL_CERT_FILE), or NULL: libcurl's default */
    hlod_logger lg;
    uint64_t size;              /* the file's size at open */
    char etag[256];             /* strong ETag of the first response, or "" */
    char last_modified[128];
    struct curl_slist *hdrs;    /* If-Range, once there is a validator */
    _Atomic double latency_ms;  /* test hook */
    long low_speed_s;           /* HTTP_LOW_SPEED_S, or the test hook's */
    pthread_mutex_t mu;         /* the pool only, never across I/O */
    CURL *pool[HTTP_POOL];
    int pool_n;
    atomic_int changed;         /* the store changed on the server */
    atomic_int down;            /* the last attempt failed transiently (logged once) */
};

enum { XF_NONE, XF_CHANGED, XF_NORANGE, XF_RANGE, XF_SINK };
enum { X_IDLE, X_WAITING, X_RUNNING };
enum { C_DONE, C_RETRY, C_FAIL };

typedef struct xfer {
    hlod_http *h;
    CURL *easy;
    int probe;                  /* the open's request: no validator yet */
    uint64_t off, len, got;     /* this attempt: range and bytes taken */
    hlod_http_sink sink;
    void *user;
    int checked, why;           /* body checked; why it was refused (XF_*) */
    char cr[128], etag[256], lm[128]; /* this response's headers */
    char err[CURL_ERROR_SIZE];
    /* parallel transfers */
    int state;
    double start_at;            /* ms, when WAITING */
    int attempts;
    uint64_t taken;             /* bytes the sink took, all time */
} xfer;

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

static void sleep_ms(double ms)
{
    if (ms <= 0)
        return;
    struct timespec ts = {(time_t)(ms / 1e3), (long)(((int64_t)(ms * 1e6)) % 1000000000)};
    while (nanosleep(&ts, &ts) != 0 && errno == EINTR)
        ;
}

static double backoff_ms(int attempt)
{
    return attempt <= 0 ? 0 : HTTP_BACKOFF_MS * (double)(1u << (attempt - 1 < 10 ? attempt - 1 : 10));
}

static pthread_once_t curl_once = PTHREAD_ONCE_INIT;
static int curl_ok;

static void curl_init_once(void)
{
    curl_ok = curl_global_init(CURL_GLOBAL_DEFAULT) == CURLE_OK;
}

int hlod_http_is_url(const char *name)
{
    return name && (strncasecmp(name, "http://", 7) == 0 || strncasecmp(name, "https://", 8) == 0);
}

/* ---- one transfer ---- */

/* Copies a header's value (after "Name:") without blanks and CRLF. */
static void header_value(char *dst, size_t cap, const char *v, size_t n)
{
    while (n && (*v == ' ' || *v == '\t')) {
        v++;
        n--;
    }
    while (n && (v[n - 1] == '\r' || v[n - 1] == '\n' || v[n - 1] == ' '))
        n--;
    if (n >= cap)
        n = cap - 1;
    memcpy(dst, v, n);
    dst[n] = 0;
}

static size_t on_header(char *data, size_t size, size_t nmemb, void *u)
{
    xfer *x = u;
    size_t n = size * nmemb;
    if (n >= 5 && memcmp(data, "HTTP/", 5) == 0) {
        x->cr[0] = x->etag[0] = x->lm[0] = 0; /* a new response (redirect, 1xx) */
        return n;
    }
    static const struct {
        const char *name;
        size_t off, cap;
    } keep[] = {
        {"content-range:", offsetof(xfer, cr), sizeof(((xfer *)0)->cr)},
        {"etag:", offsetof(xfer, etag), sizeof(((xfer *)0)->etag)},
        {"last-modified:", offsetof(xfer, lm), sizeof(((xfer *)0)->lm)},
    };
    for (size_t k = 0; k < sizeof keep / sizeof keep[0]; k++) {
        size_t len = strlen(keep[k].name);
        if (n > len && strncasecmp(data, keep[k].name, len) == 0)
            header_value((char *)x + keep[k].off, keep[k].cap, data + len, n - len);
    }
    return n;
}

/* The response of x before its first body byte: 1 when its body may go to
 * the sink, else 0 with x->why set. */
static int check_response(xfer *x)
{
    hlod_http *h = x->h;
    long code = 0;
    curl_easy_getinfo(x->easy, CURLINFO_RESPONSE_CODE, &code);
    if (code == 200) {
        x->why = x->probe ? XF_NORANGE : XF_CHANGED;
        return 0;
    }
    if (code != 206)
        return 0; /* an error page: classify() reads the status */
    unsigned long long a, b, t;
    if (sscanf(x->cr, "bytes %llu-%llu/%llu", &a, &b, &t) != 3 || a != x->off || b < a ||
        b - a + 1 > x->len || (!x->probe && b - a + 1 != x->len)) {
        x->why = XF_RANGE;
        return 0;
    }
    if (!x->probe && (t != h->size || (h->etag[0] && x->etag[0] && strcmp(h->etag, x->etag)))) {
        x->why = XF_CHANGED;
        return 0;
    }
    return 1;
}

static size_t on_body(char *data, size_t size, size_t nmemb, void *u)
{
    xfer *x = u;
    size_t n = size * nmemb;
    if (!x->checked) {
        if (!check_response(x))
            return CURL_WRITEFUNC_ERROR;
        x->checked = 1;
    }
    if (n > x->len - x->got) {
        x->why = XF_RANGE;
        return CURL_WRITEFUNC_ERROR;
    }
    if (x->sink(x->user, data, n) != 0) {
        x->why = XF_SINK;
        return CURL_WRITEFUNC_ERROR;
    }
    x->got += n;
    x->taken += n;
    return n;
}

static CURL *new_easy(xfer *x)
{
    CURL *e = curl_easy_init();
    if (!e)
        return NULL;
    curl_easy_setopt(e, CURLOPT_URL, x->h->url);
    curl_easy_setopt(e, CURLOPT_NOSIGNAL, 1L);
    curl_easy_setopt(e, CURLOPT_FOLLOWLOCATION, 1L);
    curl_easy_setopt(e, CURLOPT_MAXREDIRS, 5L);
    curl_easy_setopt(e, CURLOPT_CONNECTTIMEOUT_MS, HTTP_CONNECT_TIMEOUT_MS);
    curl_easy_setopt(e, CURLOPT_LOW_SPEED_LIMIT, HTTP_LOW_SPEED_BYTES);
    curl_easy_setopt(e, CURLOPT_LOW_SPEED_TIME, x->h->low_speed_s);
    curl_easy_setopt(e, CURLOPT_TCP_KEEPALIVE, 1L);
    curl_easy_setopt(e, CURLOPT_USERAGENT, "hlod");
    if (x->h->cainfo)
        curl_easy_setopt(e, CURLOPT_CAINFO, x->h->cainfo);
    return e;
}

/* Points x's handle at its range (x->off, x->len) for one attempt. */
static void begin(xfer *x)
{
    char range[64];
    snprintf(range, sizeof range, "%llu-%llu", (unsigned long long)x->off,
             (unsigned long long)(x->off + x->len - 1));
    curl_easy_setopt(x->easy, CURLOPT_RANGE, range);
    curl_easy_setopt(x->easy, CURLOPT_HTTPHEADER, x->probe ? NULL : x->h->hdrs);
    curl_easy_setopt(x->easy, CURLOPT_HEADERFUNCTION, on_header);
    curl_easy_setopt(x->easy, CURLOPT_HEADERDATA, x);
    curl_easy_setopt(x->easy, CURLOPT_WRITEFUNCTION, on_body);
    curl_easy_setopt(x->easy, CURLOPT_WRITEDATA, x);
    curl_easy_setopt(x->easy, CURLOPT_ERRORBUFFER, x->err);
    x->got = 0;
    x->checked = 0;
    x->why = XF_NONE;
    x->cr[0] = x->etag[0] = x->lm[0] = x->err[0] = 0;
}

/* The store changed: logged once, every read fails from now on. */
static void changed(hlod_http *h, const xfer *x)
{
    if (atomic_exchange(&h->changed, 1))
        return;
    unsigned long long a, b, t = 0;
    if (sscanf(x->cr, "bytes %llu-%llu/%llu", &a, &b, &t) != 3 &&
        sscanf(x->cr, "bytes */%llu", &t) != 1)
        t = 0;
    hlod_logf(&h->lg, HLOD_LOG_ERROR,
              "%s: the store changed on the server (ETag %s -> %s, Last-Modified %s -> %s%s%s); "
              "no more payloads are read from it (reopen it to read the new one)",
              h->url, h->etag[0] ? h->etag : "none", x->etag[0] ? x->etag : "?",
              h->last_modified[0] ? h->last_modified : "none", x->lm[0] ? x->lm : "?",
              t && t != h->size ? ", size differs" : "", "");
}

/* What the attempt x ended with rc means.  C_FAIL sets *res and logs;
 * C_RETRY writes why to msg. */
static int classify(xfer *x, CURLcode rc, hlod_result *res, char *msg, size_t cap)
{
    hlod_http *h = x->h;
    long code = 0;
    curl_easy_getinfo(x->easy, CURLINFO_RESPONSE_CODE, &code);
    msg[0] = 0;
    if (x->why == XF_CHANGED) {
        changed(h, x);
        *res = HLOD_ERR_VERSION;
        return C_FAIL;
    }
    if (x->why == XF_NORANGE) {
        hlod_logf(&h->lg, HLOD_LOG_ERROR, "%s: the server ignores range requests (it answered "
                  "200 with the whole file to a range request); hlod needs HTTP range requests "
                  "(nginx serves them unless max_ranges is 0)", h->url);
        *res = HLOD_ERR_UNSUPPORTED;
        return C_FAIL;
    }
    if (x->why == XF_RANGE) {
        hlod_logf(&h->lg, HLOD_LOG_ERROR, "%s: asked for bytes %llu-%llu, the server sent "
                  "'Content-Range: %s'", h->url, (unsigned long long)x->off,
                  (unsigned long long)(x->off + x->len - 1), x->cr[0] ? x->cr : "(none)");
        *res = HLOD_ERR_FORMAT;
        return C_FAIL;
    }
    if (x->why == XF_SINK) {
        *res = HLOD_ERR_INVALID_ARG;
        return C_FAIL;
    }
    if (code >= 500 || code == 408 || code == 429) {
        snprintf(msg, cap, "HTTP status %ld", code);
        return C_RETRY;
    }
    if (code == 416 && !x->probe) {
        /* A range inside the file refused: the file shrank or changed
         * (Content-Range 'bytes *' + '/SIZE' with another size, or another
         * ETag), else a glitch of the server or a proxy: retried, not the
         * end of the node. */
        unsigned long long t;
        if ((sscanf(x->cr, "bytes */%llu", &t) == 1 && t != h->size) ||
            (h->etag[0] && x->etag[0] && strcmp(h->etag, x->etag))) {
            x->why = XF_CHANGED;
            changed(h, x);
            *res = HLOD_ERR_VERSION;
            return C_FAIL;
        }
        snprintf(msg, cap, "HTTP status 416 (range not satisfiable)");
        return C_RETRY;
    }
    if (code >= 300 && code != 206) {
        hlod_logf(&h->lg, HLOD_LOG_ERROR, "%s: HTTP status %ld%s", h->url, code,
                  code == 404 ? " (not found)" : code == 416 ? " (range not satisfiable)"
                  : code == 403 ? " (forbidden)" : "");
        *res = code == 416 ? HLOD_ERR_FORMAT : HLOD_ERR_IO;
        return C_FAIL;
    }
    if (rc == CURLE_OK && x->got == x->len)
        return C_DONE;
    if (rc == CURLE_OK && x->probe && x->got > 0)
        return C_DONE; /* a file shorter than the probe: the caller says so */
    switch (rc) {
    case CURLE_OK:
    case CURLE_PARTIAL_FILE:
        snprintf(msg, cap, "truncated body (%llu of %llu bytes)", (unsigned long long)x->got,
                 (unsigned long long)x->len);
        return C_RETRY;
    case CURLE_COULDNT_CONNECT:
    case CURLE_COULDNT_RESOLVE_HOST:
    case CURLE_RECV_ERROR:
    case CURLE_SEND_ERROR:
    case CURLE_OPERATION_TIMEDOUT:
    case CURLE_GOT_NOTHING:
    case CURLE_SSL_CONNECT_ERROR:
    case CURLE_HTTP2:
    case CURLE_HTTP2_STREAM:
        snprintf(msg, cap, "%s%s%s", curl_easy_strerror(rc), x->err[0] ? ": " : "", x->err);
        return C_RETRY;
    default:
        hlod_logf(&h->lg, HLOD_LOG_ERROR, "%s: %s%s%s", h->url, curl_easy_strerror(rc),
                  x->err[0] ? ": " : "", x->err);
        *res = HLOD_ERR_IO;
        return C_FAIL;
    }
}

/* A transient failure: logged when the server was fine before. */
static void went_down(hlod_http *h, const char *msg)
{
    if (!atomic_exchange(&h->down, 1))
        hlod_logf(&h->lg, HLOD_LOG_WARN, "%s: %s; retrying (up to %d tries a range, waiting "
                  "%.0f ms doubling)", h->url, msg, HLOD_HTTP_ATTEMPTS, HTTP_BACKOFF_MS);
}

static void came_back(hlod_http *h)
{
    if (atomic_load_explicit(&h->down, memory_order_relaxed) && atomic_exchange(&h->down, 0))
        hlod_logf(&h->lg, HLOD_LOG_WARN, "%s: the server answers again", h->url);
}

static void gave_up(hlod_http *h, const xfer *x, const char *msg)
{
    hlod_logf(&h->lg, HLOD_LOG_WARN, "%s: bytes %llu-%llu: %s; gave up after %d tries", h->url,
              (unsigned long long)x->off, (unsigned long long)(x->off + x->len - 1), msg,
              HLOD_HTTP_ATTEMPTS);
}

/* ---- blocking reads ---- */

typedef struct flat_sink {
    uint8_t *dst;
} flat_sink;

static int flat_write(void *user, const void *data, size_t n)
{
    flat_sink *f = user;
    memcpy(f->dst, data, n);
    f->dst += n;
    return 0;
}

static CURL *take_handle(hlod_http *h, xfer *x)
{
    CURL *e = NULL;
    pthread_mutex_lock(&h->mu);
    if (h->pool_n)
        e = h->pool[--h->pool_n];
    pthread_mutex_unlock(&h->mu);
    return e ? e : new_easy(x);
}

static void give_handle(hlod_http *h, CURL *e)
{
    pthread_mutex_lock(&h->mu);
    if (h->pool_n < HTTP_POOL) {
        h->pool[h->pool_n++] = e;
        e = NULL;
    }
    pthread_mutex_unlock(&h->mu);
    curl_easy_cleanup(e);
}

/* [off, off + len) into dst, with retries; *got the bytes that came. */
static hlod_result blocking_get(hlod_http *h, int probe, uint64_t off, void *dst, size_t len,
                                size_t *got)
{
    xfer x;
    memset(&x, 0, sizeof x);
    x.h = h;
    x.probe = probe;
    x.easy = take_handle(h, &x);
    if (!x.easy)
        return HLOD_ERR_NOMEM;
    flat_sink fs = {dst};
    x.sink = flat_write;
    x.user = &fs;
    hlod_result res = HLOD_ERR_IO;
    size_t done = 0;
    char msg[CURL_ERROR_SIZE + 64] = "";
    int verdict = C_RETRY;
    for (int attempt = 0; attempt < HLOD_HTTP_ATTEMPTS && verdict == C_RETRY; attempt++) {
        if (atomic_load(&h->changed)) {
            res = HLOD_ERR_VERSION;
            verdict = C_FAIL;
            break;
        }
        sleep_ms(backoff_ms(attempt) + atomic_load(&h->latency_ms));
        x.off = off + done;
        x.len = len - done;
        begin(&x);
        CURLcode rc = curl_easy_perform(x.easy);
        done += (size_t)x.got;
        verdict = classify(&x, rc, &res, msg, sizeof msg);
        if (verdict == C_RETRY && (done == len || (probe && done > 0)))
            verdict = C_DONE;   /* every byte arrived before the error: asking
                                   again for none would read as a change */
        if (verdict == C_RETRY)
            went_down(h, msg);
        if (verdict == C_DONE && (probe || done == len)) {
            came_back(h);
            res = HLOD_OK;
        }
    }
    if (verdict == C_RETRY) {
        x.off = off;
        x.len = len;
        gave_up(h, &x, msg);
        res = HLOD_ERR_IO;
    }
    if (probe && res == HLOD_OK) {
        unsigned long long a, b, t;
        if (sscanf(x.cr, "bytes %llu-%llu/%llu", &a, &b, &t) == 3)
            h->size = t;
        if (strncmp(x.etag, "W/", 2) != 0) /* a weak ETag cannot validate ranges */
            snprintf(h->etag, sizeof h->etag, "%s", x.etag);
        snprintf(h->last_modified, sizeof h->last_modified, "%s", x.lm);
    }
    if (got)
        *got = done;
    give_handle(h, x.easy);
    return res;
}

hlod_result hlod_http_read(hlod_http *h, uint64_t off, void *dst, size_t len)
{
    if (!h || (!dst && len))
        return HLOD_ERR_INVALID_ARG;
    if (len == 0)
        return HLOD_OK;
    return blocking_get(h, 0, off, dst, len, NULL);
}

void hlod_http_validators(const hlod_http *h, const char **etag, const char **last_modified)
{
    *etag = h ? h->etag : "";
    *last_modified = h ? h->last_modified : "";
}

void hlod_http_set_latency(hlod_http *h, double ms)
{
    if (h)
        atomic_store(&h->latency_ms, ms > 0 ? ms : 0);
}

hlod_result hlod_http_open(const char *url, const hlod_logger *lg, void *probe, size_t probe_len,
                           size_t *got, uint64_t *size, hlod_http **out)
{
    *out = NULL;
    pthread_once(&curl_once, curl_init_once);
    if (!curl_ok) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot initialise libcurl", url);
        return HLOD_ERR_IO;
    }
    hlod_http *h = calloc(1, sizeof *h);
    if (!h || !(h->url = strdup(url))) {
        free(h);
        return HLOD_ERR_NOMEM;
    }
    if (lg)
        h->lg = *lg;
    pthread_mutex_init(&h->mu, NULL);
    /* https: certificates are verified against the system's CAs, or the
     * bundle the environment names, as the curl tool reads it */
    const char *ca = getenv("CURL_CA_BUNDLE");
    if (!ca || !*ca)
        ca = getenv("SSL_CERT_FILE");
    if (ca && *ca && !(h->cainfo = strdup(ca))) {
        pthread_mutex_destroy(&h->mu);
        free(h->url);
        free(h);
        return HLOD_ERR_NOMEM;
    }
    const char *lat = getenv("HLOD_HTTP_LATENCY_MS");
    atomic_init(&h->latency_ms, lat ? atof(lat) : 0.0);
    /* test hook: a shorter floor, 1 to 15 s, so a test drops a stalled
     * transfer in seconds (another value keeps 15) */
    const char *slow = getenv("HLOD_HTTP_LOW_SPEED_S");
    long ls = slow ? strtol(slow, NULL, 10) : 0;
    h->low_speed_s = ls >= 1 && ls <= HTTP_LOW_SPEED_S ? ls : HTTP_LOW_SPEED_S;
    atomic_init(&h->changed, 0);
    atomic_init(&h->down, 0);
    hlod_result r = blocking_get(h, 1, 0, probe, probe_len, got);
    if (r == HLOD_OK) {
        char line[300];
        if (h->etag[0] || h->last_modified[0]) {
            snprintf(line, sizeof line, "If-Range: %s", h->etag[0] ? h->etag : h->last_modified);
            h->hdrs = curl_slist_append(NULL, line);
            if (!h->hdrs)
                r = HLOD_ERR_NOMEM;
        } else {
            hlod_logf(lg, HLOD_LOG_WARN, "%s: the server sends neither ETag nor Last-Modified: a "
                      "store replaced on it is noticed only when its size changes", url);
        }
    }
    if (r != HLOD_OK) {
        hlod_http_close(h);
        return r;
    }
    *size = h->size;
    *out = h;
    return HLOD_OK;
}

void hlod_http_close(hlod_http *h)
{
    if (!h)
        return;
    for (int i = 0; i < h->pool_n; i++)
        curl_easy_cleanup(h->pool[i]);
    curl_slist_free_all(h->hdrs);
    pthread_mutex_destroy(&h->mu);
    free(h->url);
    free(h->cainfo);
    free(h);
}

/* ---- parallel transfers ---- */

struct hlod_http_multi {
    hlod_http *h;
    CURLM *m;
    xfer *x;
    unsigned n;
};

hlod_result hlod_http_multi_create(hlod_http *h, unsigned transfers, hlod_http_multi **out)
{
    *out = NULL;
    if (!h || transfers == 0)
        return HLOD_ERR_INVALID_ARG;
    hlod_http_multi *m = calloc(1, sizeof *m);
    if (!m)
        return HLOD_ERR_NOMEM;
    m->h = h;
    m->n = transfers;
    m->x = calloc(transfers, sizeof *m->x);
    m->m = curl_multi_init();
    if (!m->x || !m->m) {
        hlod_http_multi_destroy(m);
        return HLOD_ERR_NOMEM;
    }
    curl_multi_setopt(m->m, CURLMOPT_MAXCONNECTS, (long)transfers);
    for (unsigned i = 0; i < transfers; i++) {
        m->x[i].h = h;
        if (!(m->x[i].easy = new_easy(&m->x[i]))) {
            hlod_http_multi_destroy(m);
            return HLOD_ERR_NOMEM;
        }
    }
    *out = m;
    return HLOD_OK;
}

void hlod_http_multi_destroy(hlod_http_multi *m)
{
    if (!m)
        return;
    for (unsigned i = 0; m->x && i < m->n; i++) {
        if (m->x[i].state == X_RUNNING)
            curl_multi_remove_handle(m->m, m->x[i].easy);
        curl_easy_cleanup(m->x[i].easy);
    }
    if (m->m)
        curl_multi_cleanup(m->m);
    free(m->x);
    free(m);
}

static xfer *find_user(const hlod_http_multi *m, void *user)
{
    for (unsigned i = 0; i < m->n; i++)
        if (m->x[i].state != X_IDLE && m->x[i].user == user)
            return &m->x[i];
    return NULL;
}

hlod_result hlod_http_multi_start(hlod_http_multi *m, uint64_t off, uint64_t len,
                                  hlod_http_sink sink, void *user)
{
    if (!m || !sink || len == 0 || find_user(m, user))
        return HLOD_ERR_INVALID_ARG;
    for (unsigned i = 0; i < m->n; i++) {
        xfer *x = &m->x[i];
        if (x->state != X_IDLE)
            continue;
        x->off = off;
        x->len = len;
        x->sink = sink;
        x->user = user;
        x->attempts = 0;
        x->state = X_WAITING;
        x->start_at = now_ms() + atomic_load(&m->h->latency_ms);
        return HLOD_OK;
    }
    return HLOD_ERR_INVALID_ARG;
}

void hlod_http_multi_stop(hlod_http_multi *m, void *user)
{
    xfer *x = m ? find_user(m, user) : NULL;
    if (!x)
        return;
    if (x->state == X_RUNNING)
        curl_multi_remove_handle(m->m, x->easy);
    x->state = X_IDLE;
    x->user = NULL;
}

int hlod_http_multi_has(const hlod_http_multi *m, void *user)
{
    return m && find_user(m, user) != NULL;
}

unsigned hlod_http_multi_active(const hlod_http_multi *m)
{
    unsigned k = 0;
    for (unsigned i = 0; m && i < m->n; i++)
        k += m->x[i].state != X_IDLE;
    return k;
}

/* Starts the waiting transfers whose time has come; returns the ms until
 * the next one's (or limit). */
static double start_due(hlod_http_multi *m, double limit, unsigned *running)
{
    double t = now_ms(), next = limit;
    *running = 0;
    for (unsigned i = 0; i < m->n; i++) {
        xfer *x = &m->x[i];
        if (x->state == X_WAITING && x->start_at <= t) {
            begin(x);
            if (curl_multi_add_handle(m->m, x->easy) == CURLM_OK)
                x->state = X_RUNNING;
            else
                x->start_at = t + HTTP_BACKOFF_MS;
        }
        if (x->state == X_WAITING && x->start_at - t < next)
            next = x->start_at - t;
        *running += x->state == X_RUNNING;
    }
    return next < 0 ? 0 : next;
}

/* A running transfer ended with rc: done, retried later, or failed. */
static int ended(hlod_http_multi *m, xfer *x, CURLcode rc, hlod_http_end *out)
{
    hlod_http *h = m->h;
    curl_multi_remove_handle(m->m, x->easy);
    char msg[CURL_ERROR_SIZE + 64];
    hlod_result res = HLOD_ERR_IO;
    int v = atomic_load(&h->changed) ? (res = HLOD_ERR_VERSION, C_FAIL)
                                     : classify(x, rc, &res, msg, sizeof msg);
    x->off += x->got;
    x->len -= x->got;
    if (v == C_DONE || (v == C_RETRY && x->len == 0)) {
        came_back(h);
        res = HLOD_OK;
    } else if (v == C_RETRY) {
        went_down(h, msg);
        if (++x->attempts < HLOD_HTTP_ATTEMPTS) {
            x->state = X_WAITING;
            x->start_at = now_ms() + backoff_ms(x->attempts) + atomic_load(&h->latency_ms);
            return 0;
        }
        gave_up(h, x, msg);
    }
    out->user = x->user;
    out->result = res;
    x->state = X_IDLE;
    x->user = NULL;
    return 1;
}

size_t hlod_http_multi_poll(hlod_http_multi *m, int timeout_ms, int wake_fd, hlod_http_end *out,
                            size_t max, uint64_t *bytes)
{
    if (bytes)
        *bytes = 0;
    if (!m || !out || !max)
        return 0;
    uint64_t before = 0;
    for (unsigned i = 0; i < m->n; i++)
        before += m->x[i].taken;
    unsigned running;
    double wait = start_due(m, timeout_ms, &running);
    struct curl_waitfd wfd = {wake_fd, CURL_WAIT_POLLIN, 0};
    if (running) {
        int still = 0;
        curl_multi_perform(m->m, &still);
        /* Wait only while every running transfer is still running: one that
         * ended in this perform is answered now, not after the timeout. */
        if ((unsigned)still >= running) {
            curl_multi_poll(m->m, wake_fd >= 0 ? &wfd : NULL, wake_fd >= 0 ? 1 : 0, (int)wait,
                            NULL);
            curl_multi_perform(m->m, &still);
        }
    } else if (wait > 0) {
        struct pollfd p = {wake_fd, POLLIN, 0};
        if (wake_fd >= 0)
            poll(&p, 1, (int)wait);
        else
            sleep_ms(wait);
    }
    size_t n = 0;
    CURLMsg *msg;
    int left;
    while (n < max && (msg = curl_multi_info_read(m->m, &left))) {
        if (msg->msg != CURLMSG_DONE)
            continue;
        for (unsigned i = 0; i < m->n; i++)
            if (m->x[i].state == X_RUNNING && m->x[i].easy == msg->easy_handle) {
                n += (size_t)ended(m, &m->x[i], msg->data.result, &out[n]);
                break;
            }
    }
    uint64_t after = 0;
    for (unsigned i = 0; i < m->n; i++)
        after += m->x[i].taken;
    if (bytes)
        *bytes = after - before;
    return n;
}
