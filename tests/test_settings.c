/*
 * test_settings.c - the engine's settings table (HLOD_ENGINE_SETTINGS in
 * hlod/engine.h): docs/runtime.md's table lists the same settings with the same
 * defaults, ranges, change rule and help; defaults, parsing by name, range
 * checks and hlod_engine_set all follow the table.
 */
#include "check.h"
#include "hlod/engine.h"
#include "store_fixture.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static void range_text(const hlod_engine_setting *s, char *out, size_t n)
{
    char lo[32], hi[32];
    snprintf(lo, sizeof lo, isinf(s->lo) ? "-inf" : "%g", s->lo);
    snprintf(hi, sizeof hi, isinf(s->hi) ? "inf" : "%g", s->hi);
    snprintf(out, n, "%c%s, %s]", s->lo_open ? '(' : '[', lo, hi);
}

/* Splits a table row "| a | b | ... |" into at most max trimmed cells. */
static int cells(char *row, char **cell, int max)
{
    int n = 0;
    char *p = row;
    if (*p == '|')
        p++;
    while (*p && n < max) {
        char *bar = strchr(p, '|');
        if (!bar)
            break;
        *bar = 0;
        while (*p == ' ')
            p++;
        char *e = bar;
        while (e > p && e[-1] == ' ')
            *--e = 0;
        cell[n++] = p;
        p = bar + 1;
    }
    return n;
}

static void docs_table_matches(void)
{
    const char *src = getenv("HLOD_SOURCE_DIR");
    char path[1024];
    snprintf(path, sizeof path, "%s/docs/runtime.md", src ? src : ".");
    char *text = check_slurp(path, NULL);
    CHECKF(text, "%s is missing", path);
    if (!text)
        return;
    char *sec = strstr(text, "\n## Engine settings\n");
    CHECKF(sec, "docs/runtime.md has no section \"## Engine settings\"");
    size_t n;
    const hlod_engine_setting *set = hlod_engine_settings(&n);
    size_t row = 0;
    char *line = sec ? strstr(sec, "\n| `") : NULL;
    /* the rows: consecutive lines starting "| `" after the header */
    while (line && line[1] == '|') {
        line++;
        char *end = strchr(line, '\n');
        if (end)
            *end = 0;
        char *c[6];
        int nc = cells(line, c, 6);
        CHECKF(nc == 5, "docs row %zu: %d cells", row, nc);
        if (nc == 5 && row < n) {
            const hlod_engine_setting *s = &set[row];
            char key[96], range[96];
            snprintf(key, sizeof key, "`%s`", s->key);
            range_text(s, range, sizeof range);
            CHECKF(!strcmp(c[0], key), "docs row %zu is %s, the table's is %s", row, c[0], key);
            CHECKF(strtod(c[1], NULL) == s->def, "%s: docs default %s, table %.17g", s->key, c[1],
                   s->def);
            CHECKF(!strcmp(c[2], range), "%s: docs range %s, table %s", s->key, c[2], range);
            CHECKF(!strcmp(c[3], s->live ? "live" : "restart"), "%s: docs say %s", s->key, c[3]);
            CHECKF(!strcmp(c[4], s->help), "%s: docs help \"%s\", table \"%s\"", s->key, c[4],
                   s->help);
        }
        row++;
        if (!end)
            break;
        *end = '\n';
        line = end;
    }
    CHECKF(row == n, "docs/runtime.md lists %zu settings, the table %zu", row, n);
    free(text);
}

/* Zero takes the default; every key parses; counts refuse fractions. */
static void defaults_and_names(void)
{
    size_t n;
    const hlod_engine_setting *set = hlod_engine_settings(&n);
    CHECK(n >= 19);
    hlod_engine_desc d = {0};
    hlod_engine_desc_defaults(&d);
    CHECK(d.target_ms == 33.3 && d.c_hyst_limit == 8 && d.max_inflight == 32 &&
          d.memory_budget_bytes == 512ull << 20 && d.fixed_v_time == 1e-4 && d.c_memory == 0);
    for (size_t i = 0; i < n; i++) {
        hlod_engine_desc e = {0};
        /* a value other than the default (a switch: the other state) */
        double v = set[i].kind[0] == 'B' ? !set[i].def : set[i].def == 1 ? 2 : 1;
        CHECKF(hlod_engine_desc_set(&e, set[i].key, v) == HLOD_OK, "%s", set[i].key);
        /* a set field is not overwritten by the defaults: set, then
         * defaults, is defaults, then set; and differs from defaults */
        hlod_engine_desc f = e, g = {0}, plain = {0};
        hlod_engine_desc_defaults(&f);
        hlod_engine_desc_defaults(&g);
        hlod_engine_desc_defaults(&plain);
        CHECKF(hlod_engine_desc_set(&g, set[i].key, v) == HLOD_OK &&
                   memcmp(&f, &g, sizeof f) == 0 && memcmp(&f, &plain, sizeof f) != 0,
               "%s = %g: the defaults overwrote it", set[i].key, v);
        int is_count = set[i].kind[0] == 'U' || set[i].kind[0] == 'B';
        CHECKF((hlod_engine_desc_set(&e, set[i].key, 1.5) == HLOD_OK) == !is_count, "%s 1.5",
               set[i].key);
        CHECKF((hlod_engine_desc_set(&e, set[i].key, -2) == HLOD_OK) == !is_count, "%s -2",
               set[i].key);
        CHECK(hlod_engine_desc_set(&e, set[i].key, NAN) == HLOD_ERR_INVALID_ARG);
    }
    CHECK(hlod_engine_desc_set(&d, "v_time", 2e-4) == HLOD_OK && d.fixed_v_time == 2e-4);
    CHECK(hlod_engine_desc_set(&d, "fixed_ms", 1.5) == HLOD_OK && d.fixed_frame_ms == 1.5);
    CHECK(hlod_engine_desc_set(&d, "no_such_setting", 1) == HLOD_ERR_INVALID_ARG);
    CHECK(hlod_engine_desc_set(&d, "fixed_v_time", 1) == HLOD_ERR_INVALID_ARG); /* keys, not fields */
}

/* Each setting's range is enforced by create and set: just outside each
 * finite bound is refused, the bound itself (or, open, just inside it) is
 * taken.  A bound whose outside cannot be asked for (a count below 0, or
 * 0, which means the default) is counted as such. */
static int g_outside, g_inside, g_unreachable;
static void ranges_are_checked(void)
{
    char path[256];
    snprintf(path, sizeof path, "/tmp/hlod-test-settings-%ld.hlod", (long)getpid());
    fixture_opts o = {0};
    o.roots = 2;
    o.depth = 1;
    o.cubes = 1; /* far_cubes = 1 needs them */
    CHECK(fixture_write(path, &o, NULL) == HLOD_OK);
    hlod_store *st = NULL;
    CHECK(hlod_store_open(path, NULL, &st) == HLOD_OK);
    if (!st)
        return;
    hlod_engine_desc base = {0};
    base.deterministic = 1;
    hlod_engine *e = NULL;
    CHECK(hlod_engine_create(st, &base, &e) == HLOD_OK);
    size_t n;
    const hlod_engine_setting *set = hlod_engine_settings(&n);
    for (size_t i = 0; i < n && e; i++) {
        const hlod_engine_setting *s = &set[i];
        if (s->kind[0] == 'B') {
            /* a switch takes 0 and 1 and nothing else */
            hlod_engine_desc d = base;
            CHECKF(hlod_engine_desc_set(&d, s->key, 2) == HLOD_ERR_INVALID_ARG &&
                       hlod_engine_desc_set(&d, s->key, -1) == HLOD_ERR_INVALID_ARG &&
                       hlod_engine_desc_set(&d, s->key, 0.5) == HLOD_ERR_INVALID_ARG,
                   "%s", s->key);
            for (int v = 0; v < 2; v++) {
                CHECK(hlod_engine_desc_set(&d, s->key, v) == HLOD_OK);
                hlod_engine *x = NULL;
                CHECKF(hlod_engine_create(st, &d, &x) == HLOD_OK, "%s = %d", s->key, v);
                hlod_engine_destroy(x);
            }
            continue;
        }
        for (int b = 0; b < 2; b++) {
            double bound = b ? s->hi : s->lo, open = b ? 0 : s->lo_open;
            if (isinf(bound))
                continue; /* no such bound */
            /* just outside: the bound itself when open, else a step past
             * it (a count's step is 1, a double's a relative 1e-9) */
            double step = s->kind[0] == 'U' ? 1 : fmax(1e-9, fabs(bound) * 1e-9);
            double out = open ? bound : b ? bound + step : bound - step;
            if (out == 0 && s->kind[0] == 'D')
                out = -step; /* 0 is the default: a double below it is outside too */
            if ((s->kind[0] == 'U' && out < 0) || out == 0) {
                g_unreachable++; /* a count below 0, or 0 (the default): cannot be asked */
                printf("     %s: %s bound %g cannot be passed\n", s->key, b ? "upper" : "lower",
                       bound);
            } else {
                hlod_engine_desc d = base;
                CHECK(hlod_engine_desc_set(&d, s->key, out) == HLOD_OK);
                hlod_engine *x = NULL;
                CHECKF(hlod_engine_create(st, &d, &x) == HLOD_ERR_INVALID_ARG && !x,
                       "%s = %.17g created", s->key, out);
                hlod_engine_destroy(x);
                if (s->live)
                    CHECKF(hlod_engine_set(e, &d) == HLOD_ERR_INVALID_ARG, "%s = %.17g set",
                           s->key, out);
                g_outside++;
            }
            /* the bound itself (closed) or a step inside it (open; 0 is
             * the default, so a closed 0 is tried as a step above) */
            double in = open || bound == 0 ? (b ? bound - step : bound + step) : bound;
            hlod_engine_desc d = base;
            CHECK(hlod_engine_desc_set(&d, s->key, in) == HLOD_OK);
            if (!strcmp(s->key, "c_hyst_switch"))
                d.c_hyst_limit = in; /* it may not exceed the limit */
            if (!strcmp(s->key, "c_hyst_limit"))
                d.c_hyst_switch = in;
            if (!strcmp(s->key, "fixed_ms"))
                d.target_ms = in + 1; /* it must stay under the target */
            hlod_engine *x = NULL;
            int made = hlod_engine_create(st, &d, &x) == HLOD_OK;
            CHECKF(made, "%s = %.17g refused", s->key, in);
            hlod_engine_destroy(x);
            if (s->live && made)
                CHECKF(hlod_engine_set(e, &d) == HLOD_OK, "%s = %.17g not set", s->key, in);
            g_inside++;
        }
    }
    printf("     %d bounds refused just outside, %d taken at or just inside, %d whose outside "
           "cannot be asked for\n", g_outside, g_inside, g_unreachable);
    CHECK(g_outside + g_unreachable == g_inside && g_outside >= 17);
    /* an unbounded side takes any finite value (old limits were only
     * "finite"), and no value is NaN or infinite */
    for (size_t i = 0; i < n && e; i++) {
        const hlod_engine_setting *s = &set[i];
        if (s->kind[0] != 'D')
            continue;
        double big[2] = {isinf(s->lo) ? -1e308 : NAN, isinf(s->hi) ? 1e308 : NAN};
        for (int b = 0; b < 2; b++) {
            if (isnan(big[b]))
                continue;
            if (!strcmp(s->key, "fixed_ms"))
                continue; /* it must stay under target_ms */
            hlod_engine_desc d = base;
            CHECK(hlod_engine_desc_set(&d, s->key, big[b]) == HLOD_OK);
            hlod_engine *x = NULL;
            CHECKF(hlod_engine_create(st, &d, &x) == HLOD_OK, "%s = %g refused", s->key, big[b]);
            hlod_engine_destroy(x);
        }
        hlod_engine_desc d = base;
        d.c_vis = INFINITY;
        hlod_engine *x = NULL;
        CHECK(hlod_engine_create(st, &d, &x) == HLOD_ERR_INVALID_ARG && !x);
    }
    /* live settings change, restart ones keep the engine's value */
    if (e) {
        hlod_engine_desc d = *hlod_engine_get_desc(e);
        d.c_vis = 7;
        d.read_chunk_bytes = 4096;
        d.memory_budget_bytes = 12345;
        CHECK(hlod_engine_set(e, &d) == HLOD_OK);
        const hlod_engine_desc *now = hlod_engine_get_desc(e);
        CHECK(now->c_vis == 7 && now->read_chunk_bytes == 64u << 10 &&
              now->memory_budget_bytes == 512ull << 20);
        d.c_hyst_switch = 9; /* over c_hyst_limit 8 */
        CHECK(hlod_engine_set(e, &d) == HLOD_ERR_INVALID_ARG);
    }
    hlod_engine_destroy(e);
    hlod_store_close(st);
    unlink(path);
}

int main(void)
{
    RUN(docs_table_matches);
    RUN(defaults_and_names);
    RUN(ranges_are_checked);
    return check_done();
}
