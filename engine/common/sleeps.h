/*
 * sleeps.h - when a thread slept (docs/runtime.md, "The loader").
 *
 * A voluntary context switch means the thread blocked: on a lock, on I/O,
 * on a page fault that read a file.  The render thread must never block
 * on the loader, so the engine counts its voluntary switches in each
 * frame (hlod_frame_stats.render_waits) less those inside calls that may
 * sleep by design: GL (a driver waits for its own threads), a synchronous
 * read (deterministic runs) and the user's logger (hlod_logf).  Those
 * calls are bracketed by hlod_excuse_begin/end, which keep a count per
 * thread; an involuntary switch (preemption) is never a sleep.  Any thread.
 */
#ifndef HLOD_SLEEPS_H
#define HLOD_SLEEPS_H

/* Voluntary context switches of the calling thread so far. */
long hlod_sleeps_now(void);

/* Major page faults of the calling thread so far: pages the system read
 * back in (from the executable, a library or a mapped file) that it had
 * evicted.  A sleep in one is the system paging, not a wait on the loader:
 * the engine counts such sleeps apart (render_paged). */
long hlod_sleeps_paged(void);

/* Of those, the ones inside excused calls, on this thread. */
long hlod_sleeps_excused(void);

/* Brackets a call that may sleep by design; nested brackets count once.
 * Returns the token hlod_excuse_end takes. */
long hlod_excuse_begin(void);
void hlod_excuse_end(long token);

#endif
