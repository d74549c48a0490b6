/*
 * sleeps.c - voluntary context switches and the calls excused from them
 * (sleeps.h).
 */
#define _GNU_SOURCE /* RUSAGE_THREAD */
#include "sleeps.h"

#include <sys/resource.h>

static _Thread_local long excused; /* switches inside excused calls */
static _Thread_local int depth;    /* excused calls open */

long hlod_sleeps_now(void)
{
    struct rusage ru;
    return getrusage(RUSAGE_THREAD, &ru) == 0 ? ru.ru_nvcsw : 0;
}

long hlod_sleeps_paged(void)
{
    struct rusage ru;
    return getrusage(RUSAGE_THREAD, &ru) == 0 ? ru.ru_majflt : 0;
}

long hlod_sleeps_excused(void)
{
    return excused;
}

long hlod_excuse_begin(void)
{
    return depth++ ? 0 : hlod_sleeps_now();
}

void hlod_excuse_end(long token)
{
    if (--depth == 0)
        excused += hlod_sleeps_now() - token;
}
