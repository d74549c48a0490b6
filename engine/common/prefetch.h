/*
 * prefetch.h - HLOD_PREFETCH(p): a read hint for memory about to be used
 * (GCC and Clang's __builtin_prefetch; nothing elsewhere).  Only a hint:
 * results never depend on it.
 */
#ifndef HLOD_PREFETCH_H
#define HLOD_PREFETCH_H

#if defined(__GNUC__)
#define HLOD_PREFETCH(p) __builtin_prefetch(p)
#else
#define HLOD_PREFETCH(p) ((void)(p))
#endif

#endif
