/*
 * rec_log.h - a logger for tests that records the last message and counts
 * them (test_path, test_store, test_render).  Not thread-safe: give it to
 * code that logs from the test's own thread.
 */
#ifndef HLOD_TEST_REC_LOG_H
#define HLOD_TEST_REC_LOG_H

#include "hlod/hlod.h"

#include <stdio.h>
#include <string.h>

typedef struct rec_log {
    char last[1024];
    int count;
} rec_log;

static inline void rec_fn(void *user, hlod_log_level level, const char *msg)
{
    rec_log *r = user;
    (void)level;
    snprintf(r->last, sizeof r->last, "%s", msg);
    r->count++;
}

/* Clears *r and returns a logger writing into it. */
static inline hlod_logger rec_logger(rec_log *r)
{
    memset(r, 0, sizeof *r);
    hlod_logger lg = {rec_fn, r};
    return lg;
}

#endif
