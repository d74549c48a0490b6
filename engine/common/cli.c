/*
 * Command-line helpers: see cli.h.
 *
 * The progress bar is rewritten in place with a carriage return and padded
 * with spaces over whatever the previous draw left, rather than with
 * terminal escape sequences, so it behaves on any terminal.  It is built in
 * one buffer and written with one fwrite so a concurrent log line cannot
 * land in its middle.
 */
#include "hlod_clock.h"
#include "cli.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#define BAR_CELLS 20
#define REDRAW_SECONDS 0.1

double hlod_cli_now(void)
{
    return hlod_now_s();
}

double hlod_cli_cpu_seconds(void)
{
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) != 0)
        return 0;
    return (double)ru.ru_utime.tv_sec + ru.ru_utime.tv_usec * 1e-6 + (double)ru.ru_stime.tv_sec +
           ru.ru_stime.tv_usec * 1e-6;
}

size_t hlod_cli_peak_rss(void)
{
    struct rusage ru;
    if (getrusage(RUSAGE_SELF, &ru) != 0 || ru.ru_maxrss < 0)
        return 0;
    return (size_t)ru.ru_maxrss * 1024u; /* Linux reports kilobytes */
}

/* ---- progress bar ---- */

void hlod_cli_progress_begin(hlod_cli_progress *p, const char *unit, int show)
{
    memset(p, 0, sizeof *p);
    p->enabled = show && isatty(STDERR_FILENO);
    p->unit = unit ? unit : "";
    p->start = hlod_cli_now();
    p->last_draw = p->start;
}

/* "950 ", "12.3 k", "1.2 M": three significant digits with an SI prefix. */
static void format_count(char *buf, size_t n, double v)
{
    static const char prefix[] = " kMGTP";
    int k = 0;
    while (v >= 999.5 && k < 5) {
        v /= 1000.0;
        k++;
    }
    if (k == 0)
        snprintf(buf, n, "%.0f ", v);
    else
        snprintf(buf, n, v < 9.95 ? "%.1f %c" : "%.0f %c", v, prefix[k]);
}

static void format_duration(char *buf, size_t n, double s)
{
    if (!(s >= 0) || s > 360000.0)
        snprintf(buf, n, "--");
    else if (s < 60)
        snprintf(buf, n, "%.0fs", s);
    else if (s < 3600)
        snprintf(buf, n, "%dm%02ds", (int)(s / 60), (int)fmod(s, 60));
    else
        snprintf(buf, n, "%dh%02dm", (int)(s / 3600), (int)fmod(s / 60, 60));
}

/* called from the working thread */
int hlod_cli_progress_fn(void *user_data, double done, double total)
{
    hlod_cli_progress *p = user_data;
    if (!p || !p->enabled)
        return 0;
    double now = hlod_cli_now();
    if (now - p->last_draw < REDRAW_SECONDS)
        return 0;
    p->last_draw = now;

    if (!isfinite(done) || done < 0)
        done = 0;
    double frac = (isfinite(total) && total > 0) ? done / total : 0;
    if (frac > 1)
        frac = 1;
    int cells = (int)(frac * BAR_CELLS + 0.5);

    char bar[BAR_CELLS + 1];
    for (int i = 0; i < BAR_CELLS; i++)
        bar[i] = i < cells ? '#' : '.';
    bar[BAR_CELLS] = 0;

    char count[32], eta[32];
    format_count(count, sizeof count, done);
    double elapsed = now - p->start;
    /* Extrapolate linearly once there is something to extrapolate from. */
    if (frac >= 0.01 && elapsed > 0.3)
        format_duration(eta, sizeof eta, elapsed * (1 - frac) / frac);
    else
        snprintf(eta, sizeof eta, "--");

    char line[160];
    int len = snprintf(line, sizeof line, "\r[%s] %3d%% %s%s  ETA %s", bar,
                       (int)(frac * 100), count, p->unit, eta);
    if (len < 0)
        return 0;
    if (len >= (int)sizeof line)
        len = (int)sizeof line - 1;
    int shown = len - 1; /* without the '\r' */
    /* Pad over the tail of a longer previous line. */
    while (shown < p->drawn && len < (int)sizeof line - 1) {
        line[len++] = ' ';
        shown++;
    }
    fwrite(line, 1, (size_t)len, stderr);
    fflush(stderr);
    p->drawn = shown;
    return 0;
}

void hlod_cli_progress_clear(hlod_cli_progress *p)
{
    if (!p || !p->enabled || p->drawn == 0)
        return;
    char line[170];
    int n = p->drawn < 160 ? p->drawn : 160;
    line[0] = '\r';
    memset(line + 1, ' ', (size_t)n);
    line[n + 1] = '\r';
    fwrite(line, 1, (size_t)n + 2, stderr);
    fflush(stderr);
    p->drawn = 0;
}

/* ---- logging ---- */

static const char *level_tag(hlod_log_level level)
{
    switch (level) {
    case HLOD_LOG_ERROR: return "error";
    case HLOD_LOG_WARN: return "warning";
    case HLOD_LOG_INFO: return "info";
    default: return "debug";
    }
}

/* called from any thread that runs library code for the tool */
static void cli_log(void *user, hlod_log_level level, const char *msg)
{
    hlod_cli_log *s = user;
    if (level > s->max_level)
        return;
    hlod_cli_progress_clear(s->bar);
    fprintf(stderr, "%s: %s: %s\n", s->prog ? s->prog : "hlod", level_tag(level), msg);
}

hlod_logger hlod_cli_logger(hlod_cli_log *state)
{
    hlod_logger lg = {cli_log, state};
    return lg;
}

void hlod_cli_error(const char *prog, const char *fmt, ...)
{
    char buf[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    fprintf(stderr, "%s: error: %s\n", prog ? prog : "hlod", buf);
}

/* ---- flag values ---- */

static void describe_range(char *buf, size_t n, double min, double max, unsigned open)
{
    const char *lo = (open & HLOD_CLI_MIN_OPEN) ? ">" : ">=";
    const char *hi = (open & HLOD_CLI_MAX_OPEN) ? "<" : "<=";
    if (isinf(max))
        snprintf(buf, n, "must be %s %g", lo, min);
    else if (isinf(min))
        snprintf(buf, n, "must be %s %g", hi, max);
    else
        snprintf(buf, n, "must be %s %g and %s %g", lo, min, hi, max);
}

int hlod_cli_parse_double(const char *prog, const char *flag, const char *text,
                          double min, double max, unsigned open, double *out)
{
    if (!text || !*text) {
        hlod_cli_error(prog, "%s: needs a number", flag);
        return 0;
    }
    /* strtod alone would accept leading spaces, "nan", "inf" and hex. */
    if (strspn(text, "0123456789+-.eE") != strlen(text)) {
        hlod_cli_error(prog, "%s: '%s' is not a number", flag, text);
        return 0;
    }
    char *end = NULL;
    errno = 0;
    double v = strtod(text, &end);
    if (end == text || *end != 0) {
        hlod_cli_error(prog, "%s: '%s' is not a number", flag, text);
        return 0;
    }
    if ((errno == ERANGE && fabs(v) > 1.0) || !isfinite(v)) {
        hlod_cli_error(prog, "%s: '%s' is too large", flag, text);
        return 0;
    }
    int below = (open & HLOD_CLI_MIN_OPEN) ? !(v > min) : !(v >= min);
    int above = (open & HLOD_CLI_MAX_OPEN) ? !(v < max) : !(v <= max);
    if (below || above) {
        char why[128];
        describe_range(why, sizeof why, min, max, open);
        hlod_cli_error(prog, "%s: %s is out of range (%s)", flag, text, why);
        return 0;
    }
    *out = v;
    return 1;
}

int hlod_cli_parse_size(const char *prog, const char *flag, const char *text,
                        size_t min, size_t max, size_t *out)
{
    if (!text || !*text) {
        hlod_cli_error(prog, "%s: needs a whole number", flag);
        return 0;
    }
    /* strtoull would accept "-5" (as a huge value), spaces and "0x". */
    if (strspn(text, "0123456789") != strlen(text)) {
        hlod_cli_error(prog, "%s: '%s' is not a whole number >= 0", flag, text);
        return 0;
    }
    errno = 0;
    unsigned long long v = strtoull(text, NULL, 10);
    if (errno == ERANGE || v > SIZE_MAX) {
        hlod_cli_error(prog, "%s: '%s' is too large", flag, text);
        return 0;
    }
    if ((size_t)v < min || (size_t)v > max) {
        if (max == SIZE_MAX)
            hlod_cli_error(prog, "%s: %s is out of range (must be >= %zu)", flag, text, min);
        else
            hlod_cli_error(prog, "%s: %s is out of range (must be >= %zu and <= %zu)",
                           flag, text, min, max);
        return 0;
    }
    *out = (size_t)v;
    return 1;
}

/* ---- JSON ---- */

static void json_key(hlod_json *j, const char *key)
{
    fprintf(j->fp, "%s\"%s\": ", j->count++ ? ", " : "", key);
}

void hlod_json_begin(hlod_json *j, FILE *fp)
{
    j->fp = fp;
    j->count = 0;
    fputc('{', fp);
}

void hlod_json_object(hlod_json *j, const char *key, hlod_json *inner)
{
    json_key(j, key);
    hlod_json_begin(inner, j->fp);
}

void hlod_json_object_end(hlod_json *inner)
{
    fputc('}', inner->fp);
}

void hlod_json_double(hlod_json *j, const char *key, double v)
{
    json_key(j, key);
    if (isfinite(v))
        fprintf(j->fp, "%.17g", v);
    else
        fputs("null", j->fp);
}

void hlod_json_size(hlod_json *j, const char *key, size_t v)
{
    json_key(j, key);
    fprintf(j->fp, "%zu", v);
}

void hlod_json_int(hlod_json *j, const char *key, long long v)
{
    json_key(j, key);
    fprintf(j->fp, "%lld", v);
}

void hlod_json_bool(hlod_json *j, const char *key, int v)
{
    json_key(j, key);
    fputs(v ? "true" : "false", j->fp);
}

void hlod_json_string(hlod_json *j, const char *key, const char *v)
{
    json_key(j, key);
    if (!v) {
        fputs("null", j->fp);
        return;
    }
    fputc('"', j->fp);
    for (const unsigned char *s = (const unsigned char *)v; *s; s++) {
        if (*s == '"' || *s == '\\')
            fprintf(j->fp, "\\%c", *s);
        else if (*s == '\n')
            fputs("\\n", j->fp);
        else if (*s == '\t')
            fputs("\\t", j->fp);
        else if (*s < 0x20)
            fprintf(j->fp, "\\u%04x", *s);
        else
            fputc(*s, j->fp);
    }
    fputc('"', j->fp);
}

int hlod_json_end(hlod_json *j)
{
    fputs("}\n", j->fp);
    if (fflush(j->fp) != 0 || ferror(j->fp))
        return -1;
    return 0;
}

/* ---- flags ---- */

int hlod_cli_match_flag(int argc, char **argv, int *i, const char *flag, const char **value)
{
    const char *a = argv[*i];
    size_t n = strlen(flag);
    if (strncmp(a, flag, n) != 0)
        return 0;
    if (a[n] == '=') {
        *value = a + n + 1;
        return 1;
    }
    if (a[n] != 0)
        return 0;
    *value = *i + 1 < argc ? argv[++*i] : NULL;
    return 1;
}

int hlod_cli_usage_error(const char *prog, const char *fmt, const char *arg)
{
    char msg[512];
    snprintf(msg, sizeof msg, fmt, arg);
    hlod_cli_error(prog, "%s", msg);
    fprintf(stderr, "try '%s --help'\n", prog);
    return 2;
}
