/*
 * Camera paths (hlod/path.h) and the city's built-in paths
 * (preprocess/city_paths.h): parsing with exact FILE:LINE messages, every
 * truncation and a stream of byte mutations of a valid file, interpolation
 * (keyframes hit bit for bit, linear motion reproduced, C1 at keyframes,
 * clamping), frame counts, the writer's bit-exact round trip, and the
 * built-in paths: identical to the files committed under data/paths/,
 * formatted exactly as the engine's writer formats them, and checked
 * against the geometry hlod_city_generate actually makes (eye 1.7 m above
 * the ground, never inside or next to a block, the whole city in view at
 * the end of walk-to-fly).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include "check.h"
#include "rec_log.h"
#include "city.h"
#include "city_paths.h"
#include "hlod/path.h"

/* ---------- helpers ---------- */

static char g_dir[256];

static const char *tmp_path(const char *name, char *buf, size_t n)
{
    snprintf(buf, n, "%s/%s", g_dir, name);
    return buf;
}

static int same_bits(const double *a, const double *b, size_t n)
{
    return memcmp(a, b, n * sizeof *a) == 0;
}

static int same_path(const hlod_path *a, const hlod_path *b)
{
    return a->count == b->count &&
           (a->count == 0 || memcmp(a->keys, b->keys, a->count * sizeof *a->keys) == 0);
}

static hlod_result parse_str(const char *text, hlod_path *p, rec_log *log)
{
    hlod_logger lg = rec_logger(log);
    return hlod_path_parse(text, strlen(text), "bad.path", &lg, p);
}

static double dist3(const double a[3], const double b[3])
{
    return sqrt((a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
                (a[2] - b[2]) * (a[2] - b[2]));
}

/* ---------- parsing ---------- */

static void parse_good(void)
{
    const char *text = "# a camera path\n"
                       "\n"
                       "   # indented comment\n"
                       "0 1 2 3 4 5 6   # trailing comment\n"
                       "0.5\t-1.5e1 +2 3. .25 5E-1 6\r\n"
                       "\t \n"
                       "2 7 8 9 10 11 12";   /* no final newline */
    hlod_path p = {0};
    rec_log log;
    CHECK(parse_str(text, &p, &log) == HLOD_OK);
    CHECK(log.count == 0);
    CHECK(p.count == 3);
    if (p.count == 3) {
        hlod_path_key k0 = {0, {1, 2, 3}, {4, 5, 6}};
        hlod_path_key k1 = {0.5, {-15, 2, 3}, {0.25, 0.5, 6}};
        hlod_path_key k2 = {2, {7, 8, 9}, {10, 11, 12}};
        CHECK(same_bits(&p.keys[0].t, &k0.t, 7));
        CHECK(same_bits(&p.keys[1].t, &k1.t, 7));
        CHECK(same_bits(&p.keys[2].t, &k2.t, 7));
    }
    CHECK(hlod_path_start(&p) == 0 && hlod_path_end(&p) == 2 && hlod_path_duration(&p) == 2);

    /* One keyframe is a path; the buffer need not end in NUL. */
    const char one[] = "5 0 0 0 1 0 0XXXX";
    CHECK(hlod_path_parse(one, 13, "one", NULL, &p) == HLOD_OK);
    CHECK(p.count == 1 && p.keys[0].t == 5 && hlod_path_duration(&p) == 0);
    hlod_path_free(&p);
    CHECK(p.keys == NULL && p.count == 0);
}

typedef struct bad_case {
    const char *text;
    hlod_result result;
    const char *message;
} bad_case;

static void parse_errors(void)
{
    static const bad_case cases[] = {
        {"0 0 0 0 1 1 1\n1 2 3\n", HLOD_ERR_FORMAT,
         "bad.path:2: expected 7 numbers (t px py pz lx ly lz), found 3"},
        {"0 0 0 0 1 1 1 junk\n", HLOD_ERR_FORMAT,
         "bad.path:1: unexpected 'junk' after the 7 numbers of a keyframe"},
        {"0 0 0 0 1 1 1 8 # eight\n", HLOD_ERR_FORMAT,
         "bad.path:1: unexpected '8' after the 7 numbers of a keyframe"},
        {"# x\n0 0 0 0 1 1 abc\n", HLOD_ERR_FORMAT, "bad.path:2: 'abc' is not a number"},
        {"0 0 0 0 1 1 1.5.2\n", HLOD_ERR_FORMAT, "bad.path:1: '1.5.2' is not a number"},
        {"0 0x10 0 0 1 1 1\n", HLOD_ERR_FORMAT, "bad.path:1: '0x10' is not a number"},
        {"0 1e 0 0 1 1 1\n", HLOD_ERR_FORMAT, "bad.path:1: '1e' is not a number"},
        {"0 . 0 0 1 1 1\n", HLOD_ERR_FORMAT, "bad.path:1: '.' is not a number"},
        {"0 1,5 0 0 1 1 1\n", HLOD_ERR_FORMAT, "bad.path:1: '1,5' is not a number"},
        {"0 nan 0 0 1 1 1\n", HLOD_ERR_NAN, "bad.path:1: 'nan' is not a finite number"},
        {"0 0 -inf 0 1 1 1\n", HLOD_ERR_NAN, "bad.path:1: '-inf' is not a finite number"},
        {"1e999 0 0 0 1 1 1\n", HLOD_ERR_NAN, "bad.path:1: '1e999' is not a finite number"},
        {"2e9 0 0 0 1 1 1\n", HLOD_ERR_FORMAT,
         "bad.path:1: time 2e9 is out of range (at most 1e+09 in magnitude)"},
        {"0 0 0 -1e13 1 1 1\n", HLOD_ERR_FORMAT,
         "bad.path:1: coordinate -1e13 is out of range (at most 1e+12 in magnitude)"},
        {"# c\n1 0 0 0 1 1 1\n\n1 0 0 0 2 2 2\n", HLOD_ERR_FORMAT,
         "bad.path:4: time 1 is not after the previous keyframe's time 1 (line 2)"},
        {"0 0 0 0 1 1 1\n2 0 0 0 1 1 1\n1.5 0 0 0 1 1 1\n", HLOD_ERR_FORMAT,
         "bad.path:3: time 1.5 is not after the previous keyframe's time 2 (line 2)"},
        {"0 0 0 0 1 1 1\n1 1 2 3 1 2 3\n", HLOD_ERR_FORMAT,
         "bad.path:2: eye and look-at are the same point"},
        {"", HLOD_ERR_FORMAT, "bad.path: no keyframes (expected lines of 't px py pz lx ly lz')"},
        {"# only a comment\n\n  \n", HLOD_ERR_FORMAT,
         "bad.path: no keyframes (expected lines of 't px py pz lx ly lz')"},
        {"0 0 0 0 1 1 1\n\xff\xfe 1 2\n", HLOD_ERR_FORMAT, "bad.path:2: '?\?' is not a number"},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
        hlod_path p = {0};
        rec_log log;
        hlod_result r = parse_str(cases[i].text, &p, &log);
        CHECKF(r == cases[i].result, "case %zu: result %d", i, (int)r);
        CHECKF(!strcmp(log.last, cases[i].message), "case %zu: message '%s'", i, log.last);
        CHECKF(log.count == 1, "case %zu: %d messages", i, log.count);
        CHECK(p.count == 0 && p.keys == NULL);
    }

    /* A NUL byte, and a line longer than the limit. */
    hlod_path p = {0};
    rec_log log;
    hlod_logger lg = rec_logger(&log);
    const char nul[] = "0 0 0 0 1 1 1\n1 0 0\0 0 2 2 2\n";
    CHECK(hlod_path_parse(nul, sizeof nul - 1, "bad.path", &lg, &p) == HLOD_ERR_FORMAT);
    CHECK(!strcmp(log.last, "bad.path:2: NUL byte in the line"));
    size_t n = HLOD_PATH_LINE_MAX + 100;
    char *lng = malloc(n + 1);
    memset(lng, ' ', n);
    memcpy(lng + n - 13, "0 0 0 0 1 1 1", 13);
    lng[n] = 0;
    lg = rec_logger(&log);
    CHECK(hlod_path_parse(lng, n, "bad.path", &lg, &p) == HLOD_ERR_FORMAT);
    CHECK(!strcmp(log.last, "bad.path:1: line longer than 4096 bytes"));
    free(lng);

    /* A NULL name, a missing file. */
    lg = rec_logger(&log);
    CHECK(hlod_path_parse("x", 1, NULL, &lg, &p) == HLOD_ERR_FORMAT);
    CHECK(!strcmp(log.last, "<buffer>:1: 'x' is not a number"));
    char file[512];
    lg = rec_logger(&log);
    CHECK(hlod_path_load(tmp_path("missing.path", file, sizeof file), &lg, &p) == HLOD_ERR_IO);
    CHECK(strstr(log.last, "missing.path: cannot open") != NULL);
    CHECK(hlod_path_parse(NULL, 0, NULL, NULL, NULL) == HLOD_ERR_INVALID_ARG);
}

/* Text -> path -> text -> path gives the same bits; on failure the path is
 * empty.  Returns the parse result. */
static hlod_result parse_round_trip(const char *text, size_t len)
{
    hlod_path p = {0}, q = {0};
    hlod_result r = hlod_path_parse(text, len, "fuzz", NULL, &p);
    if (r != HLOD_OK) {
        CHECK(p.count == 0 && p.keys == NULL);
        return r;
    }
    CHECK(hlod_path_validate(&p, "fuzz", NULL) == HLOD_OK);
    char *out = NULL;
    size_t n = 0;
    CHECK(hlod_path_to_text(&p, "c", &out, &n) == HLOD_OK);
    CHECK(out && hlod_path_parse(out, n, "again", NULL, &q) == HLOD_OK && same_path(&p, &q));
    double eye[3], at[3];
    hlod_path_eval(&p, 0.5 * (hlod_path_start(&p) + hlod_path_end(&p)), eye, at);
    CHECK(isfinite(eye[0] + eye[1] + eye[2] + at[0] + at[1] + at[2]));
    free(out);
    hlod_path_free(&p);
    hlod_path_free(&q);
    return r;
}

/* Every truncation of a valid file, and deterministic byte mutations: no
 * crash (ASan), no leak, and the invariants above (meshoptimizer's
 * decodeIndexMemorySafe pattern). */
static void parse_truncations_and_mutations(void)
{
    const char *good = "# path\n0 1 2 3 4 5 6 # c\n0.25 1e-300 -0 3 4 5 6\n"
                       "7 1e12 -1e12 5e6 4 5 6\r\n1e9 1 1 1 0 0 0\n";
    size_t n = strlen(good);
    CHECK(parse_round_trip(good, n) == HLOD_OK);
    size_t ok = 0;
    for (size_t k = 0; k <= n; k++) {
        char *buf = malloc(k ? k : 1);   /* exact size: ASan sees any over-read */
        memcpy(buf, good, k);
        ok += parse_round_trip(buf, k) == HLOD_OK;
        free(buf);
    }
    CHECK(ok > 0 && ok < n);
    static const char alphabet[] = "0123456789.eE+-# \t\r\n\0xnai";
    uint64_t s = 12345;
    for (int it = 0; it < 20000; it++) {
        char buf[128];
        memcpy(buf, good, n);
        int edits = 1 + it % 4;
        for (int e = 0; e < edits; e++) {
            s = s * 6364136223846793005ULL + 1442695040888963407ULL;
            size_t pos = (size_t)(s >> 33) % n;
            buf[pos] = alphabet[(s >> 20) % (sizeof alphabet - 1)];
        }
        char *exact = malloc(n);
        memcpy(exact, buf, n);
        parse_round_trip(exact, n);
        free(exact);
    }
}

/* ---------- evaluation ---------- */

static hlod_path make_path(const hlod_path_key *keys, size_t n)
{
    hlod_path p = {0};
    for (size_t i = 0; i < n; i++)
        CHECK(hlod_path_append(&p, keys[i].t, keys[i].eye, keys[i].at) == HLOD_OK);
    return p;
}

static const hlod_path_key CURVY[] = {
    {0.0, {0, 0, 1.7}, {10, 0, 1.7}},
    {0.7, {3, 1, 1.7}, {12, 4, 2}},
    {1.0, {5, 4, 2.5}, {14, 9, 3}},
    {2.5, {6, 12, 9}, {5, 20, 1}},
    {2.6, {6.5, 12.5, 9}, {4, 21, 1}},
    {4.0, {-3, 20, 30}, {0, 0, 0}},
};
#define NCURVY (sizeof CURVY / sizeof CURVY[0])

static void eval_hits_keyframes(void)
{
    hlod_path p = make_path(CURVY, NCURVY);
    for (size_t i = 0; i < NCURVY; i++) {
        double eye[3], at[3];
        hlod_path_eval(&p, CURVY[i].t, eye, at);
        CHECKF(same_bits(eye, CURVY[i].eye, 3) && same_bits(at, CURVY[i].at, 3), "key %zu", i);
    }
    /* -0 keeps its sign too (the keyframe itself is returned). */
    hlod_path q = {0};
    double e0[3] = {-0.0, 1, 2}, a0[3] = {1, 1, 1}, e1[3] = {5, 5, 5};
    CHECK(hlod_path_append(&q, 0, e0, a0) == HLOD_OK && hlod_path_append(&q, 1, e1, a0) == HLOD_OK);
    double eye[3], at[3];
    hlod_path_eval(&q, 0, eye, at);
    CHECK(signbit(eye[0]));
    hlod_path_free(&q);
    hlod_path_free(&p);
}

static void eval_linear_motion_exact(void)
{
    /* Constant velocity with uneven keyframe spacing: the Catmull-Rom
     * tangents are exact, so the spline is the straight line. */
    const double ts[] = {0, 0.1, 1.3, 1.4, 5, 9.25};
    hlod_path p = {0};
    for (size_t i = 0; i < sizeof ts / sizeof ts[0]; i++) {
        double t = ts[i];
        double eye[3] = {5e5 + 3 * t, 4.1e6 - 2 * t, 1.7}, at[3] = {5e5 + 3 * t + 10, 4.1e6, 1.7};
        CHECK(hlod_path_append(&p, t, eye, at) == HLOD_OK);
    }
    double worst = 0;
    for (int k = 0; k <= 1000; k++) {
        double t = 9.25 * k / 1000, eye[3], at[3];
        hlod_path_eval(&p, t, eye, at);
        double want[3] = {5e5 + 3 * t, 4.1e6 - 2 * t, 1.7};
        double d = dist3(eye, want);
        worst = d > worst ? d : worst;
        CHECK(fabs(at[0] - (want[0] + 10)) < 1e-8 && fabs(at[1] - 4.1e6) < 1e-8);
    }
    CHECKF(worst < 1e-8, "worst %g", worst);
    hlod_path_free(&p);
}

static void eval_c1_continuity(void)
{
    hlod_path p = make_path(CURVY, NCURVY);
    const double e = 1e-6;
    for (size_t i = 1; i + 1 < NCURVY; i++) {
        double t = CURVY[i].t, l[3], la[3], m[3], ma[3], r[3], ra[3];
        hlod_path_eval(&p, t - e, l, la);
        hlod_path_eval(&p, t, m, ma);
        hlod_path_eval(&p, t + e, r, ra);
        /* C0: both sides within O(e) of the keyframe. */
        CHECKF(dist3(l, m) < 1e-3 && dist3(r, m) < 1e-3, "key %zu", i);
        /* C1: left and right difference quotients agree to O(e). */
        for (int c = 0; c < 3; c++) {
            double dl = (m[c] - l[c]) / e, dr = (r[c] - m[c]) / e;
            double dla = (ma[c] - la[c]) / e, dra = (ra[c] - ma[c]) / e;
            CHECKF(fabs(dl - dr) < 1e-3 * (1 + fabs(dl)), "key %zu c %d: %g %g", i, c, dl, dr);
            CHECKF(fabs(dla - dra) < 1e-3 * (1 + fabs(dla)), "key %zu c %d", i, c);
        }
    }
    /* A kinked piecewise-linear path would fail the check above; the
     * spline must also be continuous everywhere in between. */
    double prev[3], pa[3];
    hlod_path_eval(&p, 0, prev, pa);
    for (int k = 1; k <= 40000; k++) {
        double t = 4.0 * k / 40000, eye[3], at[3];
        hlod_path_eval(&p, t, eye, at);
        CHECK(dist3(eye, prev) < 0.02 && dist3(at, pa) < 0.02);
        memcpy(prev, eye, sizeof prev);
        memcpy(pa, at, sizeof pa);
    }
    hlod_path_free(&p);
}

static void eval_clamps(void)
{
    hlod_path p = make_path(CURVY, NCURVY);
    double eye[3], at[3];
    hlod_path_eval(&p, -5, eye, at);
    CHECK(same_bits(eye, CURVY[0].eye, 3) && same_bits(at, CURVY[0].at, 3));
    hlod_path_eval(&p, 1e9, eye, at);
    CHECK(same_bits(eye, CURVY[NCURVY - 1].eye, 3) && same_bits(at, CURVY[NCURVY - 1].at, 3));
    hlod_path_eval(&p, NAN, eye, at);
    CHECK(same_bits(eye, CURVY[0].eye, 3));
    hlod_path_eval(&p, INFINITY, eye, at);
    CHECK(same_bits(eye, CURVY[NCURVY - 1].eye, 3));
    hlod_path_free(&p);
    /* One keyframe: the same answer at any time. */
    p = make_path(CURVY + 2, 1);
    hlod_path_eval(&p, 123, eye, at);
    CHECK(same_bits(eye, CURVY[2].eye, 3) && same_bits(at, CURVY[2].at, 3));
    hlod_path_free(&p);
    /* Keyframes a hair apart stay finite (tangents are pre-scaled). */
    hlod_path_key close[] = {{0, {0, 0, 0}, {1, 0, 0}},
                             {1e-300, {1e12, -1e12, 1e12}, {0, 1, 0}},
                             {2e-300, {-1e12, 1e12, 0}, {1, 1, 0}}};
    p = make_path(close, 3);
    for (int k = 0; k <= 10; k++) {
        hlod_path_eval(&p, 2e-300 * k / 10, eye, at);
        CHECK(isfinite(eye[0]) && isfinite(eye[1]) && isfinite(eye[2]) && isfinite(at[0]));
    }
    hlod_path_free(&p);
}

static void frame_count(void)
{
    hlod_path_key k[2] = {{0, {0, 0, 0}, {1, 0, 0}}, {399.0 / 30, {1, 0, 0}, {2, 0, 0}}};
    hlod_path p = make_path(k, 2);
    CHECK(hlod_path_frame_count(&p, 1.0 / 30) == 400);
    CHECK(hlod_path_frame_count(&p, 1.0 / 60) == 799);
    CHECK(hlod_path_frame_count(&p, 100) == 1);
    CHECK(hlod_path_frame_count(&p, 0) == 0 && hlod_path_frame_count(&p, -1) == 0);
    CHECK(hlod_path_frame_count(&p, NAN) == 0 && hlod_path_frame_count(&p, INFINITY) == 0);
    CHECK(hlod_path_frame_count(&p, 1e-300) == 0);
    CHECK(hlod_path_frame_time(&p, 1.0 / 30, 399) == 399 * (1.0 / 30));
    hlod_path_free(&p);
    hlod_path_key j[2] = {{2, {0, 0, 0}, {1, 0, 0}}, {3, {1, 0, 0}, {2, 0, 0}}};
    p = make_path(j, 2);
    CHECK(hlod_path_frame_count(&p, 0.3) == 4);     /* 2, 2.3, 2.6, 2.9 */
    CHECK(hlod_path_frame_time(&p, 0.3, 3) == 2 + 3 * 0.3);
    hlod_path_free(&p);
    p = make_path(j, 1);
    CHECK(hlod_path_frame_count(&p, 1.0 / 30) == 1);
    hlod_path_free(&p);
    hlod_path empty = {0};
    CHECK(hlod_path_frame_count(&empty, 1.0 / 30) == 0);
}

static void append_validates(void)
{
    hlod_path p = {0};
    double e[3] = {0, 0, 0}, a[3] = {1, 0, 0}, nan3[3] = {0, NAN, 0};
    CHECK(hlod_path_append(&p, 0, e, a) == HLOD_OK);
    CHECK(hlod_path_append(&p, 0, e, a) == HLOD_ERR_INVALID_ARG);     /* same time */
    CHECK(hlod_path_append(&p, -1, e, a) == HLOD_ERR_INVALID_ARG);
    CHECK(hlod_path_append(&p, 1, e, e) == HLOD_ERR_INVALID_ARG);     /* eye == at */
    CHECK(hlod_path_append(&p, 1, nan3, a) == HLOD_ERR_NAN);
    CHECK(hlod_path_append(&p, NAN, e, a) == HLOD_ERR_NAN);
    CHECK(hlod_path_append(&p, 2e9, e, a) == HLOD_ERR_INVALID_ARG);
    CHECK(p.count == 1);
    for (int i = 1; i <= 1000; i++) {
        double ei[3] = {i, 0, 0}, ai[3] = {i + 1, 0, 0};
        CHECK(hlod_path_append(&p, i / 30.0, ei, ai) == HLOD_OK);
    }
    CHECK(p.count == 1001 && p.capacity >= 1001);
    /* validate names the keyframe */
    rec_log log;
    hlod_logger lg = rec_logger(&log);
    p.keys[500].t = p.keys[499].t;
    CHECK(hlod_path_validate(&p, "rec", &lg) == HLOD_ERR_FORMAT);
    CHECK(strstr(log.last, "rec: keyframe 500: time ") == log.last);
    hlod_path_free(&p);
}

static void write_round_trip(void)
{
    hlod_path p = {0};
    const double awkward[] = {0.1, 1.0 / 3, 1e-300, 5e6 + 0.123456789, -4.1e6 - 1e-7,
                              3.0000000000000004, 2.675, 1e11, -0.0, 123456789.98765433};
    size_t na = sizeof awkward / sizeof awkward[0];
    for (size_t i = 0; i < 40; i++) {
        double e[3], a[3];
        for (int c = 0; c < 3; c++) {
            e[c] = awkward[(i + (size_t)c) % na] * (c == 2 ? 1 : 1 + (double)i / 7);
            a[c] = awkward[(i * 3 + (size_t)c + 1) % na] + 1;
        }
        CHECK(hlod_path_append(&p, i / 3.0 + 1e-7, e, a) == HLOD_OK);
    }
    char file[512];
    tmp_path("rt.path", file, sizeof file);
    rec_log log;
    hlod_logger lg = rec_logger(&log);
    CHECK(hlod_path_write(&p, file, "recorded by a test\n\nline three", &lg) == HLOD_OK);
    hlod_path q = {0};
    CHECK(hlod_path_load(file, &lg, &q) == HLOD_OK);
    CHECK(same_path(&p, &q));
    size_t n;
    char *text = check_slurp(file, &n);
    CHECK(text && !strncmp(text, "# recorded by a test\n#\n# line three\n# t px py pz lx ly lz\n",
                           strlen("# recorded by a test\n#\n# line three\n# t px py pz lx ly lz\n")));
    /* shortest round-trip numbers: 0.1 is written as "0.1" */
    CHECK(text && strstr(text, " 0.1 ") != NULL);
    free(text);
    /* no temporary file is left behind */
    char tmpname[600];
    snprintf(tmpname, sizeof tmpname, "ls %s | grep -c tmp- > /dev/null", g_dir);
    CHECK(system(tmpname) != 0);

    /* An invalid path is refused before anything is written. */
    char bad[512];
    tmp_path("bad-write.path", bad, sizeof bad);
    q.keys[3].t = q.keys[2].t;
    CHECK(hlod_path_write(&q, bad, NULL, &lg) == HLOD_ERR_FORMAT);
    struct stat st;
    CHECK(stat(bad, &st) != 0);
    /* An unwritable location reports HLOD_ERR_IO. */
    CHECK(hlod_path_write(&p, "/nonexistent-dir/x.path", NULL, &lg) == HLOD_ERR_IO);
    hlod_path empty = {0};
    char *t2 = NULL;
    CHECK(hlod_path_to_text(&empty, NULL, &t2, NULL) == HLOD_ERR_INVALID_ARG && t2 == NULL);
    hlod_path_free(&p);
    hlod_path_free(&q);
}

/* ---------- built-in city paths ---------- */

static const char *const PRESETS[2] = {"default", "small"};

static void preset_desc(const char *preset, hlod_city_desc *d)
{
    memset(d, 0, sizeof *d);
    CHECK(hlod_city_preset(preset, d));
}

static void city_paths_match_committed_files(void)
{
    for (int pi = 0; pi < 2; pi++) {
        hlod_city_desc d;
        preset_desc(PRESETS[pi], &d);
        for (int i = 0; i < HLOD_CITY_PATH_COUNT; i++) {
            const char *name = hlod_city_path_names[i];
            char rel[128], file[512];
            snprintf(rel, sizeof rel, "data/paths/%s/%s.path", PRESETS[pi], name);
            check_src_path(rel, file, sizeof file);
            size_t n = 0, m = 0;
            char *committed = check_slurp(file, &n), *made = NULL;
            CHECKF(committed, "%s is missing", file);
            CHECK(hlod_city_path_text(&d, name, &made, &m) == HLOD_OK);
            CHECKF(committed && made && n == m && !memcmp(committed, made, n),
                   "%s differs from the generator (run hlod-gen-city --preset %s --paths "
                   "data/paths/%s)", rel, PRESETS[pi], PRESETS[pi]);
            /* The engine's loader reads it back as the generator made it
             * (both write through hlod_path_to_text). */
            hlod_path p = {0};
            rec_log log;
            hlod_logger lg = rec_logger(&log);
            CHECKF(hlod_path_load(file, &lg, &p) == HLOD_OK, "%s: %s", rel, log.last);
            hlod_path q = {0};
            CHECK(hlod_city_path(&d, name, &q) == HLOD_OK && same_path(&p, &q));
            free(committed);
            free(made);
            hlod_path_free(&p);
            hlod_path_free(&q);
        }
    }
    hlod_path p = {0};
    hlod_city_desc d = {0};
    CHECK(hlod_city_path(&d, "moonwalk", &p) == HLOD_ERR_INVALID_ARG && p.count == 0);
    d.origin[0] = NAN;
    CHECK(hlod_city_path(&d, "walk", &p) == HLOD_ERR_INVALID_ARG);
}

/* hlod-gen-city --paths writes the same files (when the tool is built). */
static void city_paths_tool(void)
{
    const char *bin = getenv("HLOD_BIN_DIR");
    char tool[512];
    snprintf(tool, sizeof tool, "%s/hlod-gen-city", bin ? bin : ".");
    if (access(tool, X_OK) != 0) {
        CHECK_SKIP("%s not built", tool);
        return;
    }
    for (int pi = 0; pi < 2; pi++) {
        char dir[512], cmd[1200];
        snprintf(dir, sizeof dir, "%s/tool-%s", g_dir, PRESETS[pi]);
        snprintf(cmd, sizeof cmd, "'%s' --preset %s --paths '%s' --quiet", tool, PRESETS[pi], dir);
        CHECK(system(cmd) == 0);
        for (int i = 0; i < HLOD_CITY_PATH_COUNT; i++) {
            char a[700], rel[128], b[512];
            snprintf(a, sizeof a, "%s/%s.path", dir, hlod_city_path_names[i]);
            snprintf(rel, sizeof rel, "data/paths/%s/%s.path", PRESETS[pi],
                     hlod_city_path_names[i]);
            check_src_path(rel, b, sizeof b);
            size_t na = 0, nb = 0;
            char *x = check_slurp(a, &na), *y = check_slurp(b, &nb);
            CHECKF(x && y && na == nb && !memcmp(x, y, na), "%s", a);
            free(x);
            free(y);
        }
    }
    /* --origin moves every point by exactly the origin (model coordinates). */
    char dir[512], cmd[1200], file[700];
    snprintf(dir, sizeof dir, "%s/tool-origin", g_dir);
    snprintf(cmd, sizeof cmd, "'%s' --preset small --origin 500000 4100000 12 --paths '%s' --quiet",
             tool, dir);
    CHECK(system(cmd) == 0);
    snprintf(file, sizeof file, "%s/walk.path", dir);
    hlod_path p = {0}, q = {0};
    hlod_city_desc d;
    preset_desc("small", &d);
    CHECK(hlod_path_load(file, NULL, &p) == HLOD_OK);
    CHECK(hlod_city_path(&d, "walk", &q) == HLOD_OK);
    CHECK(p.count == q.count && p.count > 0);
    const double o[3] = {500000, 4100000, 12};
    for (size_t i = 0; i < p.count && i < q.count; i++)
        for (int c = 0; c < 3; c++) {
            CHECK(fabs(p.keys[i].eye[c] - o[c] - q.keys[i].eye[c]) < 1e-8);
            CHECK(fabs(p.keys[i].at[c] - o[c] - q.keys[i].at[c]) < 1e-8);
        }
    hlod_path_free(&p);
    hlod_path_free(&q);
}

/* The generated city's blocks (boxes) and ground height. */
typedef struct city_geom {
    size_t nblocks;
    double (*lo)[3], (*hi)[3];
    double ground_lo[3], ground_hi[3];
    double all_lo[3], all_hi[3];
} city_geom;

static int make_geom(const char *preset, size_t tris_per_block, const double origin[3],
                     city_geom *g)
{
    hlod_city_desc d;
    preset_desc(preset, &d);
    d.untextured = 1;
    d.tris_per_block = tris_per_block;
    if (origin)
        memcpy(d.origin, origin, sizeof d.origin);
    hlod_mesh m = {0};
    if (hlod_city_generate(&d, &m, NULL) != HLOD_OK)
        return 0;
    memset(g, 0, sizeof *g);
    g->nblocks = m.object_count - 1;
    g->lo = malloc(g->nblocks * sizeof *g->lo);
    g->hi = malloc(g->nblocks * sizeof *g->hi);
    for (int c = 0; c < 3; c++) {
        g->all_lo[c] = INFINITY;
        g->all_hi[c] = -INFINITY;
    }
    for (size_t o = 0; o < m.object_count; o++) {
        double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
        const hlod_object *ob = &m.objects[o];
        for (size_t t = ob->first_tri; t < ob->first_tri + ob->tri_count; t++)
            for (int k = 0; k < 3; k++) {
                const double *v = &m.positions[3 * m.indices[3 * t + k]];
                for (int c = 0; c < 3; c++) {
                    lo[c] = fmin(lo[c], v[c]);
                    hi[c] = fmax(hi[c], v[c]);
                }
            }
        for (int c = 0; c < 3; c++) {
            g->all_lo[c] = fmin(g->all_lo[c], lo[c]);
            g->all_hi[c] = fmax(g->all_hi[c], hi[c]);
        }
        if (!strcmp(ob->name, "ground")) {
            memcpy(g->ground_lo, lo, sizeof lo);
            memcpy(g->ground_hi, hi, sizeof hi);
        } else {
            memcpy(g->lo[o], lo, sizeof lo);
            memcpy(g->hi[o], hi, sizeof hi);
        }
    }
    hlod_mesh_free(&m);
    return 1;
}

static void free_geom(city_geom *g)
{
    free(g->lo);
    free(g->hi);
}

/* Horizontal distance from (x, y) to box b (0 inside). */
static double box_dist2d(const city_geom *g, size_t b, double x, double y)
{
    double dx = fmax(0, fmax(g->lo[b][0] - x, x - g->hi[b][0]));
    double dy = fmax(0, fmax(g->lo[b][1] - y, y - g->hi[b][1]));
    return hypot(dx, dy);
}

/* 1 when the segment p-q crosses box b's footprint (slab clipping). */
static int segment_hits_box2d(const city_geom *g, size_t b, const double p[3], const double q[3])
{
    double t0 = 0, t1 = 1;
    for (int c = 0; c < 2; c++) {
        double d = q[c] - p[c];
        if (d == 0) {
            if (p[c] < g->lo[b][c] || p[c] > g->hi[b][c])
                return 0;
            continue;
        }
        double a = (g->lo[b][c] - p[c]) / d, e = (g->hi[b][c] - p[c]) / d;
        if (a > e) {
            double s = a;
            a = e;
            e = s;
        }
        t0 = fmax(t0, a);
        t1 = fmin(t1, e);
        if (t0 > t1)
            return 0;
    }
    return 1;
}

/* All 8 corners of the city's box inside a 60-degree (vertical),
 * 16:9 frustum from eye towards at. */
static int city_in_view(const city_geom *g, const double eye[3], const double at[3])
{
    double f[3], r[3], u[3], n;
    for (int c = 0; c < 3; c++)
        f[c] = at[c] - eye[c];
    n = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    for (int c = 0; c < 3; c++)
        f[c] /= n;
    r[0] = f[1];                    /* f x (0, 0, 1) */
    r[1] = -f[0];
    r[2] = 0;
    n = hypot(r[0], r[1]);
    r[0] /= n;
    r[1] /= n;
    u[0] = r[1] * f[2] - r[2] * f[1];
    u[1] = r[2] * f[0] - r[0] * f[2];
    u[2] = r[0] * f[1] - r[1] * f[0];
    double tv = tan(30 * M_PI / 180), th = tv * 16 / 9;
    for (int k = 0; k < 8; k++) {
        double c[3] = {k & 1 ? g->all_hi[0] : g->all_lo[0], k & 2 ? g->all_hi[1] : g->all_lo[1],
                       k & 4 ? g->all_hi[2] : g->all_lo[2]};
        double d[3] = {c[0] - eye[0], c[1] - eye[1], c[2] - eye[2]};
        double z = d[0] * f[0] + d[1] * f[1] + d[2] * f[2];
        double x = d[0] * r[0] + d[1] * r[1] + d[2] * r[2];
        double y = d[0] * u[0] + d[1] * u[1] + d[2] * u[2];
        if (z <= 0.5 || fabs(y) > tv * z || fabs(x) > th * z || z > 5000)
            return 0;
    }
    return 1;
}

static void check_paths_against(const char *preset, const city_geom *g, const double origin[3])
{
    hlod_city_desc d;
    preset_desc(preset, &d);
    memcpy(d.origin, origin, sizeof d.origin);
    const double dt = 1.0 / 30;
    double gz_lo = g->ground_lo[2], gz_hi = g->ground_hi[2];
    CHECK(gz_hi - gz_lo < 0.05 && fabs(gz_lo - origin[2]) < 0.05);
    for (int i = 0; i < HLOD_CITY_PATH_COUNT; i++) {
        const char *name = hlod_city_path_names[i];
        hlod_path p = {0};
        CHECK(hlod_city_path(&d, name, &p) == HLOD_OK);
        CHECK(hlod_path_validate(&p, name, NULL) == HLOD_OK);
        int ground = !strncmp(name, "walk", 4);
        uint64_t frames = hlod_path_frame_count(&p, dt);
        double min_clear = INFINITY, min_h = INFINITY, max_h = -INFINITY;
        int inside = 0, blocked = 0, off_ground = 0;
        double first_eye[3], first_at[3];
        int moved = 0;
        for (uint64_t f = 0; f < frames; f++) {
            double eye[3], at[3];
            hlod_path_eval(&p, hlod_path_frame_time(&p, dt, f), eye, at);
            if (f == 0) {
                memcpy(first_eye, eye, sizeof eye);
                memcpy(first_at, at, sizeof at);
            }
            moved |= !same_bits(eye, first_eye, 3) || !same_bits(at, first_at, 3);
            /* On the ground: the walks, and walk-to-fly before it rises. */
            double t = hlod_path_frame_time(&p, dt, f);
            int low = ground && (strcmp(name, "walk-to-fly") || t <= 5);
            if (low) {
                min_h = fmin(min_h, eye[2] - gz_hi);
                max_h = fmax(max_h, eye[2] - gz_lo);
                off_ground |= eye[0] < g->ground_lo[0] || eye[0] > g->ground_hi[0] ||
                              eye[1] < g->ground_lo[1] || eye[1] > g->ground_hi[1];
            }
            for (size_t b = 0; b < g->nblocks; b++) {
                double dd = box_dist2d(g, b, eye[0], eye[1]);
                if (dd == 0 && eye[2] <= g->hi[b][2] + 1)
                    inside = 1;
                if (eye[2] <= g->hi[b][2] + 1)
                    min_clear = fmin(min_clear, dd);
                if (low && segment_hits_box2d(g, b, eye, at))
                    blocked = 1;
            }
        }
        CHECKF(!inside, "%s %s: the eye enters a block", preset, name);
        if (ground) {
            /* Walking: 1.7 m above the ground, on it, in the street. */
            CHECKF(min_h > 1.65 && max_h < 1.75, "%s %s: eye height %g..%g", preset, name,
                   min_h, max_h);
            CHECKF(!off_ground, "%s %s: off the ground", preset, name);
            CHECKF(min_clear > 3.0, "%s %s: %g m from a block", preset, name, min_clear);
            CHECKF(!blocked, "%s %s: looks into a block", preset, name);
        }
        if (!strcmp(name, "fly")) {
            double eye[3], at[3];
            hlod_path_eval(&p, hlod_path_start(&p), eye, at);
            CHECK(eye[2] - g->all_hi[2] > 40);
        }
        if (!strcmp(name, "walk-to-fly")) {
            double eye[3], at[3];
            hlod_path_eval(&p, hlod_path_start(&p), eye, at);
            CHECKF(!city_in_view(g, eye, at), "%s: the city is in view from the street", preset);
            hlod_path_eval(&p, hlod_path_end(&p), eye, at);
            CHECKF(city_in_view(g, eye, at), "%s: the whole city is not in view at the end",
                   preset);
        }
        if (!strcmp(name, "walk-drive")) {
            CHECK(frames == 400);
            double a[3], b[3], x[3], y[3], at[3];
            hlod_path_eval(&p, hlod_path_frame_time(&p, dt, 0), a, at);
            hlod_path_eval(&p, hlod_path_frame_time(&p, dt, 190), b, at);
            hlod_path_eval(&p, hlod_path_frame_time(&p, dt, 210), x, at);
            hlod_path_eval(&p, hlod_path_frame_time(&p, dt, 399), y, at);
            double walk = dist3(a, b) / (190 * dt), drive = dist3(x, y) / (189 * dt);
            CHECKF(fabs(walk - 1.4) < 0.01 && fabs(drive - 14) < 0.1, "%g %g", walk, drive);
        }
        CHECKF(moved == (strcmp(name, "still") != 0), "%s %s: moved %d", preset, name, moved);
        hlod_path_free(&p);
    }
}

static void city_paths_fit_the_geometry(void)
{
    const double zero[3] = {0, 0, 0}, far[3] = {500000, 4100000, 12};
    city_geom g;
    /* The small preset; then the default layout (200 blocks) with a small
     * triangle budget: the layout does not depend on the budget. */
    CHECK(make_geom("small", 0, zero, &g));
    check_paths_against("small", &g, zero);
    free_geom(&g);
    CHECK(make_geom("small", 0, far, &g));
    check_paths_against("small", &g, far);
    free_geom(&g);
    CHECK(make_geom("default", 300, zero, &g));
    CHECK(g.nblocks == 200);
    check_paths_against("default", &g, zero);
    free_geom(&g);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod-test-path-XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(parse_good);
    RUN(parse_errors);
    RUN(parse_truncations_and_mutations);
    RUN(eval_hits_keyframes);
    RUN(eval_linear_motion_exact);
    RUN(eval_c1_continuity);
    RUN(eval_clamps);
    RUN(frame_count);
    RUN(append_validates);
    RUN(write_round_trip);
    RUN(city_paths_match_committed_files);
    RUN(city_paths_tool);
    RUN(city_paths_fit_the_geometry);
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", g_dir);
    return check_done();
}
