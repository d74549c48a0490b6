/*
 * fuzz_path.c - libFuzzer harness for the camera path parser
 * (engine/common/path.c: hlod_path_parse).
 *
 * Any bytes in.  Besides "no crash, leak or hang", a path the parser
 * accepts must keep the promises of path.h, checked here as oracles:
 *   - it passes hlod_path_validate;
 *   - its text (hlod_path_to_text) parses back to the same keys, bit for bit;
 *   - hlod_path_eval gives finite points at the keyframe times (exactly the
 *     keyframe), between them, outside them, and at a NaN time;
 *   - the frame count at 30 Hz is at least 1.
 * A broken promise aborts, which libFuzzer reports as a crash.
 */
#include "hlod/path.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static void finite_point(const double p[3])
{
    if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]))
        abort();
}

static void check_eval(const hlod_path *p, double t)
{
    double eye[3], at[3];
    hlod_path_eval(p, t, eye, at);
    finite_point(eye);
    finite_point(at);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    hlod_path p = {0};
    if (hlod_path_parse((const char *)data, size, "fuzz", NULL, &p) != HLOD_OK) {
        if (p.count || p.keys)
            abort();    /* left empty on failure */
        return 0;
    }
    if (p.count == 0 || hlod_path_validate(&p, "fuzz", NULL) != HLOD_OK)
        abort();

    char *text = NULL;
    size_t len = 0;
    if (hlod_path_to_text(&p, "fuzz\nround trip", &text, &len) == HLOD_OK) {
        hlod_path q = {0};
        if (hlod_path_parse(text, len, "round-trip", NULL, &q) != HLOD_OK || q.count != p.count ||
            memcmp(q.keys, p.keys, p.count * sizeof *p.keys) != 0)
            abort();
        hlod_path_free(&q);
        free(text);
    }

    for (size_t i = 0; i < p.count; i++) {
        double eye[3], at[3];
        hlod_path_eval(&p, p.keys[i].t, eye, at);
        if (memcmp(eye, p.keys[i].eye, sizeof eye) || memcmp(at, p.keys[i].at, sizeof at))
            abort();
        if (i + 1 < p.count) {
            check_eval(&p, p.keys[i].t + 0.25 * (p.keys[i + 1].t - p.keys[i].t));
            check_eval(&p, 0.5 * (p.keys[i].t + p.keys[i + 1].t));
            check_eval(&p, nextafter(p.keys[i + 1].t, -INFINITY));
        }
        if (i >= 64)
            break;      /* enough: evaluation cost is not what is fuzzed */
    }
    check_eval(&p, hlod_path_start(&p) - 1);
    check_eval(&p, hlod_path_end(&p) + 1);
    check_eval(&p, NAN);
    if (hlod_path_frame_count(&p, 1.0 / 30) < 1)
        abort();
    hlod_path_free(&p);
    return 0;
}
