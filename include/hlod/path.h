/*
 * path.h - camera paths: keyframed eye and look-at points over time, replayed
 * by hlod-bench at a fixed simulated dt and recorded by hlod-view.
 *
 * Text format (ASCII, one keyframe per line):
 *
 *     # comment                 a '#' starts a comment, whole-line or trailing
 *     t px py pz lx ly lz       time (s), eye, look-at: model coordinates
 *
 * Blank lines are allowed; fields are separated by spaces or tabs; lines end
 * in "\n" or "\r\n".  Numbers are plain decimals ("-12", "0.5", "1e-3"; no
 * hex, no "nan"/"inf").  A file is refused (HLOD_ERR_FORMAT, or HLOD_ERR_NAN
 * for a non-finite number, with "FILE:LINE: reason" through the logger) when
 * a line has other than 7 numbers or junk after them, a number is not
 * finite or out of range (|t| <= 1e9 s, |coordinate| <= 1e12), times do not
 * increase strictly, a keyframe's eye equals its look-at, a line is longer
 * than HLOD_PATH_LINE_MAX bytes or holds a NUL byte, or there is no
 * keyframe at all.  One keyframe is a valid path (the camera stands still,
 * duration 0).
 *
 * Interpolation: each coordinate of the eye and of the look-at is a cubic
 * Hermite spline through the keyframes with Catmull-Rom tangents taken over
 * time, m_i = (p[i+1] - p[i-1]) / (t[i+1] - t[i-1]), one-sided at the two
 * ends.  It passes through every keyframe exactly (at t == t_i the keyframe
 * itself is returned, bit for bit), is C1 in time, reproduces motion at
 * constant velocity exactly (even with uneven keyframe spacing), and is
 * deterministic: the same path and t give the same bits on every run.
 * Like every Catmull-Rom spline it may overshoot a little where the motion
 * changes abruptly; put keyframes closer there.  Outside [t0, tN] the path
 * is clamped to its first or last keyframe.  Between keyframes the eye may
 * come arbitrarily close to the look-at if the two curves cross; callers
 * check hlod_camera_look_at's result.
 *
 * Replay: frame i is shown at t0 + i * dt (computed from i, not
 * accumulated), for i = 0 .. hlod_path_frame_count(p, dt) - 1.
 *
 * Ownership: an hlod_path owns its keys; hlod_path_free releases them.  A
 * zeroed hlod_path is an empty path.  Thread safety: functions taking a
 * const path may be called from any number of threads at once; others need
 * exclusive access.  Nothing here uses global state.
 */
#ifndef HLOD_PATH_H
#define HLOD_PATH_H

#include <stddef.h>
#include <stdint.h>

#include "hlod/hlod.h"

#ifdef __cplusplus
extern "C" {
#endif

#define HLOD_PATH_LINE_MAX 4096     /* bytes per line, newline excluded */
#define HLOD_PATH_T_MAX 1e9         /* |t| limit, seconds */
#define HLOD_PATH_COORD_MAX 1e12    /* |coordinate| limit, model units */

typedef struct hlod_path_key {
    double t;               /* seconds */
    double eye[3];          /* model coordinates */
    double at[3];           /* look-at point, model coordinates; != eye */
} hlod_path_key;

typedef struct hlod_path {
    hlod_path_key *keys;    /* count keyframes, t strictly increasing */
    size_t count;
    size_t capacity;        /* allocated keys (hlod_path_append grows it) */
} hlod_path;

/* Parses len bytes of text (need not be NUL-terminated; may hold any bytes:
 * a fuzzer drives it).  name labels the messages ("NAME:LINE: ...") and may
 * be NULL ("<buffer>").  *out is freed first and left empty on failure.
 * Cost: one pass, O(len), one allocation growing geometrically. */
hlod_result hlod_path_parse(const char *text, size_t len, const char *name,
                            const hlod_logger *lg, hlod_path *out);

/* Reads and parses a file (messages name it).  HLOD_ERR_IO when it cannot
 * be read or is larger than 256 MiB. */
hlod_result hlod_path_load(const char *file, const hlod_logger *lg, hlod_path *out);

/* Checks an in-memory path by the rules of the text format (messages name
 * `name` and the keyframe index).  HLOD_ERR_FORMAT/NAN as for parsing. */
hlod_result hlod_path_validate(const hlod_path *p, const char *name, const hlod_logger *lg);

/* Appends one keyframe (hlod-view --record).  HLOD_ERR_NAN for a
 * non-finite value, HLOD_ERR_INVALID_ARG when t does not follow the last
 * keyframe strictly, a value is out of range or eye == at, HLOD_ERR_NOMEM.
 * p is unchanged on failure.  Amortised O(1). */
hlod_result hlod_path_append(hlod_path *p, double t, const double eye[3], const double at[3]);

void hlod_path_free(hlod_path *p);   /* p may be NULL; leaves it empty */

/* First and last keyframe times, and their difference (0 for one
 * keyframe).  The path must not be empty. */
double hlod_path_start(const hlod_path *p);
double hlod_path_end(const hlod_path *p);
double hlod_path_duration(const hlod_path *p);

/* Frames of a replay at step dt: floor(duration / dt + 1e-6) + 1, so both
 * ends are shown and a last frame within 1e-6 of a step of tN counts (a
 * path of 399/30 s at dt = 1/30 has 400 frames).  0 when p is empty, dt is
 * not finite and > 0, or the count exceeds 2^53. */
uint64_t hlod_path_frame_count(const hlod_path *p, double dt);

/* t0 + frame * dt. */
double hlod_path_frame_time(const hlod_path *p, double dt, uint64_t frame);

/* Eye and look-at at time t (see the interpolation rules above).  The path
 * must not be empty; a NaN t gives the first keyframe.  O(log count). */
void hlod_path_eval(const hlod_path *p, double t, double eye[3], double at[3]);

/* The path as text: "# " + each line of comment (NULL for none), then the
 * legend line "# t px py pz lx ly lz", then one keyframe per line, every
 * number in the shortest decimal form that reads back to the same double
 * (%.15g, %.16g or %.17g), so parsing the text gives the path bit for bit.
 * *text is malloc'ed and NUL-terminated; *len excludes the NUL (len may be
 * NULL).  HLOD_ERR_INVALID_ARG for an empty path, HLOD_ERR_NOMEM. */
hlod_result hlod_path_to_text(const hlod_path *p, const char *comment, char **text, size_t *len);

/* A number as the path writer prints it: the shortest of %.15g, %.16g and
 * %.17g that reads back to the same bits. */
void hlod_path_format_double(char buf[32], double v);

/* Writes hlod_path_to_text's text to file through a temporary file and a
 * rename (the file appears whole or not at all).  The path is validated
 * first (hlod_path_validate).  HLOD_ERR_IO with the reason logged. */
hlod_result hlod_path_write(const hlod_path *p, const char *file, const char *comment,
                            const hlod_logger *lg);

#ifdef __cplusplus
}
#endif
#endif
