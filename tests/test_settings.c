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
        double v = set[i].lo_open || set[i].lo < 1 ? 1 : set[i].lo;
        CHECKF(hlod_engine_desc_set(&e, set[i].key, v) == HLOD_OK, "%s", set[i].key);
        hlod_engine_desc f = e;
        hlod_engine_desc_defaults(&f);
        /* a set field is not overwritten by the defaults */
        hlod_engine_desc g = {0};
        CHECKF(hlod_engine_desc_set(&g, set[i].key, v) == HLOD_OK && memcmp(&e, &g, sizeof e) == 0,
               "%s", set[i].key);
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

/* Each setting's range is enforced by create and set: just outside its
 * bounds is refused, the bounds themselves are taken. */
static void ranges_are_checked(void)
{
    char path[256];
    snprintf(path, sizeof path, "/tmp/hlod-test-settings-%ld.hlod", (long)getpid());
    fixture_opts o = {0};
    o.roots = 2;
    o.depth = 1;
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
        double bad[2] = {s->lo_open ? s->lo : s->lo - 1, s->hi * 2 + 1};
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
            if (isinf(bad[b]) || (s->kind[0] == 'U' && bad[b] < 0))
                continue; /* no such bound, or not representable */
            if (bad[b] == 0)
                continue; /* zero means the default */
            hlod_engine_desc d = base;
            CHECK(hlod_engine_desc_set(&d, s->key, bad[b]) == HLOD_OK);
            hlod_engine *x = NULL;
            CHECKF(hlod_engine_create(st, &d, &x) == HLOD_ERR_INVALID_ARG && !x, "%s = %g created",
                   s->key, bad[b]);
            hlod_engine_destroy(x);
            if (s->live)
                CHECKF(hlod_engine_set(e, &d) == HLOD_ERR_INVALID_ARG, "%s = %g set", s->key, bad[b]);
        }
    }
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
