/*
 * hlod-lumigraph-serve: the Grid-Lumigraph's server (Okamoto et al.,
 * section 5.1): serves a sampling repository over HTTP with libmicrohttpd,
 * and answers a client's position and direction with the views it lacks
 * at the grid points around it (docs/hlod-lumigraph-serve.md).
 *
 *   hlod-lumigraph-serve REPO [--port P] [--bind ADDR] [--store STORE]
 *                        [--answer-kb K] [--quiet]
 */
#include "atomic_file.h"
#include "cli.h"
#include "lumi_bake.h"

#include <arpa/inet.h>
#include <errno.h>
#include <microhttpd.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

static const char *const PROG = "hlod-lumigraph-serve";

static void usage(FILE *fp)
{
    fprintf(fp,
        "usage: hlod-lumigraph-serve REPO [options]\n"
        "\n"
        "Serves the sampling repository REPO (a folder written by\n"
        "hlod-lumigraph-bake) over HTTP until SIGINT or SIGTERM:\n"
        "  GET /repo.hlg, GET /views/X/Y_Z_D.hlv   the repository's files\n"
        "  GET /answer?p=X,Y,Z&d=DX,DY,DZ&have=HEX the views a client at p looking\n"
        "      along d lacks at the grid points around it (docs/lumigraph.md)\n"
        "\n"
        "  --port P         the port (default 8080; 0: any free one)\n"
        "  --bind ADDR      the IPv4 address to listen on (default 127.0.0.1)\n"
        "  --store STORE    the store REPO was baked from: views REPO lacks are\n"
        "                   rendered when an answer needs them, and kept in REPO\n"
        "  --answer-kb K    an answer's limit in KiB, 1..65536 (default 300; at\n"
        "                   least one view is sent whatever its size)\n"
        "  --quiet          no line per request on stderr\n"
        "  -h, --help       show this help\n"
        "\n"
        "Prints 'listening on http://ADDR:PORT/' on stdout once it listens.\n"
        "Exit status: 0 after a signal, 1 failure (stderr names the file and the\n"
        "problem), 2 bad command line.\n");
}

typedef struct server {
    const char *repo, *store;
    hlod_lumi_index ix;
    size_t answer_max;
    int quiet;
    hlod_cli_log log_state;
    hlod_logger lg;
    lumi_baker baker;
    int baker_state; /* 0 not opened, 1 open, -1 failed */
} server;

static volatile sig_atomic_t g_stop;
static void on_signal(int sig)
{
    (void)sig;
    g_stop = 1;
}

static enum MHD_Result reply(struct MHD_Connection *c, unsigned status, void *body, size_t n,
                             enum MHD_ResponseMemoryMode mode, const char *type)
{
    struct MHD_Response *r = MHD_create_response_from_buffer(n, body, mode);
    if (!r) {
        if (mode == MHD_RESPMEM_MUST_FREE)
            free(body);
        return MHD_NO;
    }
    MHD_add_response_header(r, "Content-Type", type);
    enum MHD_Result ok = MHD_queue_response(c, status, r);
    MHD_destroy_response(r);
    return ok;
}

static enum MHD_Result text(struct MHD_Connection *c, unsigned status, const char *msg)
{
    return reply(c, status, (void *)msg, strlen(msg), MHD_RESPMEM_PERSISTENT, "text/plain");
}

/* A view's file, rendered first when REPO lacks it and a store is given;
 * NULL when it cannot be had. */
static uint8_t *view_bytes(server *s, uint32_t id, size_t *n)
{
    if (s->ix.state[id] == HLOD_LUMI_MISSING && s->store && s->baker_state >= 0) {
        if (s->baker_state == 0) {
            s->baker_state = -1;
            const double box[6] = {s->ix.box_min[0], s->ix.box_min[1], s->ix.box_min[2],
                                   s->ix.box_max[0], s->ix.box_max[1], s->ix.box_max[2]};
            if (lumi_baker_open(&s->baker, PROG, s->store, s->lg, s->ix.grid, s->ix.size,
                                s->ix.depth_size, s->ix.quality, box)) {
                if (lumi_same_shape(&s->baker.ix, &s->ix))
                    s->baker_state = 1;
                else
                    hlod_cli_error(PROG, "%s: REPO was not baked from this store with these "
                                   "parameters; views are not rendered on demand", s->store);
            }
        }
        if (s->baker_state == 1 && lumi_baker_view(&s->baker, id, s->repo)) {
            s->ix.state[id] = s->baker.ix.state[id];
            if (hlod_lumi_index_save(s->repo, &s->ix, &s->lg) != HLOD_OK)
                hlod_cli_error(PROG, "%s: the index could not be saved", s->repo);
        }
    }
    if (s->ix.state[id] != HLOD_LUMI_BAKED)
        return NULL;
    char rel[128];
    uint8_t *buf;
    hlod_lumi_view_path(&s->ix, id, rel, sizeof rel);
    return hlod_lumi_fetch(s->repo, rel, 64u << 20, &s->lg, &buf, n) == HLOD_OK ? buf : NULL;
}

static enum MHD_Result count_arg(void *cls, enum MHD_ValueKind kind, const char *key,
                                 const char *value)
{
    (void)kind;
    (void)key;
    (void)value;
    ++*(int *)cls;
    return MHD_YES;
}

/* GET /answer: the lacking views, in candidate order, within the limit. */
static enum MHD_Result answer(server *s, struct MHD_Connection *c)
{
    const char *p = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "p");
    const char *d = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "d");
    const char *h = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "have");
    int args = 0;
    MHD_get_connection_values(c, MHD_GET_ARGUMENT_KIND, count_arg, &args);
    char q[600];
    hlod_lumi_request req;
    if (args != 3 || !p || !d || !h ||
        snprintf(q, sizeof q, "p=%s&d=%s&have=%s", p, d, h) >= (int)sizeof q ||
        !hlod_lumi_request_parse(q, strlen(q), &req))
        return text(c, MHD_HTTP_BAD_REQUEST, "bad request: expected p=X,Y,Z&d=DX,DY,DZ&have=HEX\n");
    uint32_t ids[HLOD_LUMI_CANDIDATES], bits[HLOD_LUMI_CANDIDATES];
    uint32_t n = hlod_lumi_candidates(&s->ix, req.eye, req.dir, ids, bits);
    uint8_t *body = NULL;
    size_t len = 0;
    for (uint32_t k = 0; k < n; k++) {
        if (req.have >> bits[k] & 1 || s->ix.state[ids[k]] == HLOD_LUMI_EMPTY)
            continue;
        size_t vn;
        uint8_t *v = view_bytes(s, ids[k], &vn);
        if (!v)
            continue;
        if (len && len + 8 + vn > s->answer_max) {
            free(v);
            break;
        }
        uint8_t *nb = realloc(body, len + 8 + vn);
        if (!nb) {
            free(v);
            break;
        }
        body = nb;
        uint32_t head[2] = {ids[k], (uint32_t)vn};
        memcpy(body + len, head, 8);
        memcpy(body + len + 8, v, vn);
        len += 8 + vn;
        free(v);
    }
    if (!s->quiet)
        fprintf(stderr, "%s: answer at %.3g %.3g %.3g: %zu bytes\n", PROG, req.eye[0], req.eye[1],
                req.eye[2], len);
    if (!body)
        return reply(c, MHD_HTTP_OK, (void *)"", 0, MHD_RESPMEM_PERSISTENT,
                     "application/octet-stream");
    return reply(c, MHD_HTTP_OK, body, len, MHD_RESPMEM_MUST_FREE, "application/octet-stream");
}

/* GET /views/X/Y_Z_D.hlv of a view the index lists (rendered first when
 * missing and a store is given). */
static enum MHD_Result view_file(server *s, struct MHD_Connection *c, const char *url)
{
    unsigned x, y, z, d;
    char tail;
    if (sscanf(url, "/views/%u/%u_%u_%u.hl%c", &x, &y, &z, &d, &tail) != 5 || tail != 'v' ||
        x >= s->ix.grid || y >= s->ix.grid || z >= s->ix.grid || d >= HLOD_LUMI_FACES)
        return text(c, MHD_HTTP_NOT_FOUND, "not found\n");
    uint32_t id = hlod_lumi_view_id(&s->ix, x, y, z, d);
    char want[128];
    hlod_lumi_view_path(&s->ix, id, want, sizeof want);
    if (strcmp(url + 1, want))
        return text(c, MHD_HTTP_NOT_FOUND, "not found\n");
    size_t n;
    uint8_t *v = view_bytes(s, id, &n);
    if (!v)
        return text(c, MHD_HTTP_NOT_FOUND, "no such view in the repository\n");
    return reply(c, MHD_HTTP_OK, v, n, MHD_RESPMEM_MUST_FREE, "application/octet-stream");
}

static enum MHD_Result handle(void *cls, struct MHD_Connection *c, const char *url,
                              const char *method, const char *version, const char *upload,
                              size_t *upload_size, void **req_cls)
{
    (void)version;
    (void)upload;
    server *s = cls;
    if (strcmp(method, "GET") && strcmp(method, "HEAD")) /* refused before any body */
        return text(c, MHD_HTTP_METHOD_NOT_ALLOWED, "GET only\n");
    if (!*req_cls) { /* headers only: come back for the body */
        *req_cls = (void *)1;
        return MHD_YES;
    }
    if (*upload_size) { /* a GET's body means nothing here: dropped */
        *upload_size = 0;
        return MHD_YES;
    }
    if (!strcmp(url, "/answer"))
        return answer(s, c);
    if (!strcmp(url, "/" HLOD_LUMI_INDEX_NAME)) {
        uint8_t *b;
        size_t n;
        if (hlod_lumi_index_encode(&s->ix, &b, &n) != HLOD_OK)
            return text(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory\n");
        return reply(c, MHD_HTTP_OK, b, n, MHD_RESPMEM_MUST_FREE, "application/octet-stream");
    }
    if (!strncmp(url, "/views/", 7))
        return view_file(s, c, url);
    return text(c, MHD_HTTP_NOT_FOUND, "not found\n");
}

int main(int argc, char **argv)
{
    server s = {0};
    size_t port = 8080, kb = 300;
    const char *bind_addr = "127.0.0.1";
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i], *v = NULL;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--port", &v)) {
            if (!v || !hlod_cli_parse_size(PROG, "--port", v, 0, 65535, &port))
                return 2;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--bind", &v)) {
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs an address", "--bind");
            bind_addr = v;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--store", &v)) {
            if (!v)
                return hlod_cli_usage_error(PROG, "%s needs a store", "--store");
            s.store = v;
        } else if (hlod_cli_match_flag(argc, argv, &i, "--answer-kb", &v)) {
            /* the client takes answers of 64 MiB at most */
            if (!v || !hlod_cli_parse_size(PROG, "--answer-kb", v, 1, 65536, &kb))
                return 2;
        } else if (!strcmp(a, "--quiet")) {
            s.quiet = 1;
        } else if (a[0] == '-' && a[1]) {
            return hlod_cli_usage_error(PROG, "unknown option '%s'", a);
        } else if (!s.repo) {
            s.repo = a;
        } else {
            return hlod_cli_usage_error(PROG, "unexpected argument '%s' (one repository)", a);
        }
    }
    if (!s.repo)
        return hlod_cli_usage_error(PROG, "no repository given (%s)", "REPO");
    s.answer_max = kb << 10;
    s.log_state = (hlod_cli_log){PROG, HLOD_LOG_WARN, NULL};
    s.lg = hlod_cli_logger(&s.log_state);
    if (hlod_lumi_index_load(s.repo, &s.lg, &s.ix) != HLOD_OK)
        return 1;
    struct sockaddr_in sa = {0};
    sa.sin_family = AF_INET;
    sa.sin_port = htons((uint16_t)port);
    if (inet_pton(AF_INET, bind_addr, &sa.sin_addr) != 1) {
        hlod_cli_error(PROG, "--bind: '%s' is not an IPv4 address", bind_addr);
        hlod_lumi_index_free(&s.ix);
        return 2;
    }
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    /* one thread: requests are served in turn, and the on-demand renderer's
     * GL context stays on the thread that made it */
    struct MHD_Daemon *d = MHD_start_daemon(
        MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_ERROR_LOG, (uint16_t)port, NULL, NULL, handle,
        &s, MHD_OPTION_SOCK_ADDR, (struct sockaddr *)&sa, MHD_OPTION_CONNECTION_TIMEOUT,
        (unsigned)30, MHD_OPTION_END);
    if (!d) {
        hlod_cli_error(PROG, "cannot listen on %s:%zu: %s", bind_addr, port, strerror(errno));
        hlod_lumi_index_free(&s.ix);
        return 1;
    }
    const union MHD_DaemonInfo *info = MHD_get_daemon_info(d, MHD_DAEMON_INFO_BIND_PORT);
    printf("listening on http://%s:%u/\n", bind_addr, info ? info->port : (unsigned)port);
    fflush(stdout);
    while (!g_stop) /* a signal cuts the sleep short */
        nanosleep(&(struct timespec){0, 200000000}, NULL);
    MHD_stop_daemon(d);
    if (s.baker_state)
        lumi_baker_close(&s.baker);
    hlod_lumi_index_free(&s.ix);
    return 0;
}
