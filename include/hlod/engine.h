/*
 * engine.h - the runtime: priority traversal with time slicing and urgency
 * hysteresis (Lakhia III-C), a preemptive loader thread (III-D) and an
 * OpenGL renderer.  docs/runtime.md gives every formula and constant.
 *
 * Usage (render thread, with a GL 3.3 context current when a renderer is
 * given):
 *
 *     hlod_store *st;  hlod_store_open("city.hlod", NULL, &st);
 *     hlod_engine_desc d = {0};          // zero = every default
 *     d.target_ms = 33.3;
 *     d.renderer = r;                    // hlod_renderer_create(), or NULL
 *     hlod_engine *e;  hlod_engine_create(st, &d, &e);
 *     for (;;) {
 *         hlod_camera cam;  hlod_camera_look_at(&cam, eye, at, up, 60, 0.5, 5000, 1280, 720);
 *         hlod_frame_stats fs;  hlod_engine_frame(e, &cam, dt, &fs);
 *     }
 *     hlod_engine_destroy(e);            // stops the loader
 *     hlod_store_close(st);
 *
 * Threads: an engine is used by one thread (the render thread); it owns one
 * loader thread.  Engines share no state, so several may live in one
 * process, over one store or several.  The store must outlive its engines.
 *
 * Numbers: the camera position is double; node origins are double; the
 * renderer draws each node at (origin - camera) computed in double, so a city
 * at x = 5e6 m renders exactly like the same city at the origin.
 */
#ifndef HLOD_ENGINE_H
#define HLOD_ENGINE_H

#include "hlod/camera.h"
#include "hlod/hlod.h"
#include "hlod/store.h"

#include <math.h>

#ifdef __cplusplus
extern "C" {
#endif

/* The renderer (hlod/renderer.h); the engine only holds a pointer. */
typedef struct hlod_renderer hlod_renderer;

/* ---- engine ---- */

typedef struct hlod_engine hlod_engine;

typedef enum hlod_policy {
    HLOD_POLICY_LAKHIA = 0, /* priorities, time slices, urgency hysteresis */
    HLOD_POLICY_NOHYST,     /* eq. 4 recursion rule, no hysteresis */
    HLOD_POLICY_SSE,        /* screen-space error with an adaptive threshold */
    HLOD_POLICY_FULL,       /* leaves only, everything loaded (reference) */
    HLOD_POLICY_COUNTER,    /* nohyst's rule, a switch after switch_frames frames that want it
                               (Maciel and Shirley 1995) */
    HLOD_POLICY_OKAMOTO,    /* depth-first cut at a projected-error threshold (Okamoto, 4.2) */
    HLOD_POLICY_FS93,       /* Funkhouser and Séquin's greedy knapsack (SIGGRAPH 1993) */
    HLOD_POLICY_KLEIN,      /* a sample tree drawn additively, splats of splat_px where a
                               node's box projects to at most that (Klein 4.2, 4.5) */
    HLOD_POLICY_KLEIN_AUTO, /* klein with the splat size adapted each frame to meet
                               target_ms (ours, beyond the paper) */
    HLOD_POLICY_RZB,        /* Wand's randomized z-buffer over the leaves, in core: points
                               of splat_px where faces are small (docs/rzb.md) */
    HLOD_POLICY_CUBES,      /* Chamberlain's colour cubes: a node whose box projects within
                               cube_px is drawn as its blended cube (docs/cubes.md) */
    HLOD_POLICY_LUMIGRAPH,  /* Okamoto's Grid-Lumigraph client: coarse nodes coloured from
                               the views of a sampling repository (lumigraph_repo;
                               docs/lumigraph.md) */
    HLOD_POLICY_COUNT
} hlod_policy;

/* The policies a user picks (full draws references), for help texts. */
#define HLOD_POLICY_CHOICES \
    "lakhia, nohyst, sse, fs93, counter, okamoto, klein, klein-auto, rzb, cubes, lumigraph"

const char *hlod_policy_name(hlod_policy p);           /* "lakhia", ... */
int hlod_policy_parse(const char *name, hlod_policy *out); /* 1 on success */

/* Optional allocator for the engine's own tables (payload buffers come from
 * malloc).  All three or none. */
typedef struct hlod_allocator {
    void *(*alloc)(void *user_data, size_t size);
    void *(*realloc)(void *user_data, void *p, size_t size);
    void (*free)(void *user_data, void *p);
    void *user_data;
} hlod_allocator;

/* Called by the loader before each incremental read of a payload (from the
 * loader thread).  Returning non-OK fails that read as if the disk had
 * (HLOD_ERR_IO is transient and retried with backoff; anything else marks
 * the node bad).  May sleep, to simulate a slow disk.  For tests and fault
 * injection. */
typedef hlod_result (*hlod_read_hook)(void *user_data, uint32_t node, uint64_t offset,
                                      size_t bytes);

/* Replaces measured wall time (for tests without GL): the frame time a
 * synthetic machine would take to draw what the frame drew, given as the
 * frame's stats so far (nodes_drawn, tris_drawn, cost_drawn, pixels_drawn
 * of the nodes actually drawn).  It is the whole frame, uploads included:
 * with a time model the engine reads no clock for its decisions (uploads
 * take nothing off the budget and stop at upload_budget_bytes only). */
struct hlod_frame_stats;
typedef double (*hlod_time_model)(void *user_data, const struct hlod_frame_stats *frame);

/* The engine's numeric settings, one row each (docs/runtime.md; a test keeps that table
 * equal to this one):
 *
 *   X(key, field, kind, default, lo, lo_open, hi, live, help)
 *
 *   key      the setting's name (hlod-bench --set KEY=VALUE)
 *   field    its member of hlod_engine_desc
 *   kind     D (double), U32 or U64 (unsigned counts), B (a switch: the
 *            field is 1 on, -1 off, 0 default; --set takes 0 or 1)
 *   default  what a zero field becomes (hlod_engine_desc_defaults); 0 where
 *            zero itself means something, as the help says
 *   lo, hi   the valid range once defaults are filled in (lo excluded when
 *            lo_open; HLOD_UNBOUNDED: no limit)
 *   live     1: hlod_engine_set applies a change; 0: it needs a new engine
 *   help     one line
 *
 * One row feeds the field, its default, its check, hlod_engine_set,
 * hlod-bench's --set and its help text. */
#define HLOD_UNBOUNDED HUGE_VAL /* no limit: any finite value passes */
#define HLOD_MARGIN_MAX 4.0     /* the deadline margin's cap (hlod_frame_stats.margin;
                                   0.5 is its floor) */
#define HLOD_ENGINE_SETTINGS(X)                                                                  \
    X(target_ms, target_ms, D, 33.3, 0, 1, 1e6, 1,                                               \
      "c_targetTime: the frame time to meet, ms")                                                \
    X(memory_budget_bytes, memory_budget_bytes, U64, 512ull << 20, 0, 0, HLOD_UNBOUNDED, 0,      \
      "maxMemory: bytes of resident nodes plus reads in flight (512 MiB)")                       \
    X(c_vis, c_vis, D, 4.0, 0, 0, HLOD_UNBOUNDED, 1, "vis = 1 + c_vis * frustumVis")             \
    X(c_vis_falloff, c_vis_falloff, D, 1.0, 0, 1, HLOD_UNBOUNDED, 1,                             \
      "frustumVis falls to 0 over this many node radii outside the frustum")                     \
    X(c_fore, c_fore, D, 0.25, 0, 0, 1, 1, "foreshorten = 1 + c_fore * (view . avgNormal)")      \
    X(c_hyst_limit, c_hyst_limit, D, 8.0, 1, 0, 1e6, 1, "hyst is clamped to +-c_hyst_limit")     \
    X(c_hyst_switch, c_hyst_switch, D, 2.0, 1, 0, 1e6, 1,                                        \
      "cumHyst sums trunc(hyst / c_hyst_switch), weighted by slice; switch at most c_hyst_limit") \
    X(c_memory, c_memory, D, 0, 0, 0, HLOD_UNBOUNDED, 1,                                         \
      "bytes per unit of cost; 0: the store's decoded payload bytes / total cost")               \
    X(c_safety_slack, c_safety_slack, D, 0.10, 0, 0, 10, 1,                                      \
      "children's timeNeeded over their share by this much draws the parent")                    \
    X(c_hyst_deadband, c_hyst_deadband, D, 0.10, -HLOD_UNBOUNDED, 0, 1, 1,                       \
      "abs(slice - needed) / needed below this leaves hyst unchanged; negative: none")              \
    X(velocity_lookahead_s, velocity_lookahead_s, D, 0.5, 0, 0, HLOD_UNBOUNDED, 1,               \
      "distances are taken from the eye advanced by this much camera motion, s")                 \
    X(sse_pixels, sse_pixels, D, 2.0, 0, 1, HLOD_UNBOUNDED, 1,                                   \
      "initial screen-space error threshold of the sse policy, pixels")                          \
    X(switch_frames, switch_frames, U32, 8, 1, 0, 1e6, 1,                                        \
      "counter policy: a node switches after this many consecutive frames that want it")        \
    X(fs93_hyst, fs93_hyst, D, 0.9, 0, 1, 1, 1,                                                  \
      "fs93 policy: a choice other than last frame's keeps this fraction of its benefit")       \
    X(fs93_m, fs93_m, D, 0.5, 0, 0, 4, 1,                                                        \
      "fs93 policy: accuracy = 1 - projected error / triangles^fs93_m")                          \
    X(fs93_cost, fs93_cost, B, 0, 0, 0, 1, 1,                                                    \
      "fs93 policy: 1: a node costs max(per-primitive, per-pixel) of the fitted terms; 0: their sum") \
    X(splat_px, splat_px, U32, 1, 1, 0, 64, 1,                                                   \
      "klein policy: a node whose box projects within splat_px x splat_px pixels is one splat; " \
      "rzb policy: the points' size d")                                                         \
    X(rzb_eps, rzb_eps, D, 1.4, 1, 1, 100, 1,                                                    \
      "rzb policy: a box is sampled at its nearest depth when (z_max / z_min)^2 <= rzb_eps")     \
    X(rzb_splat_c, rzb_splat_c, B, 1, 0, 0, 1, 1,                                                \
      "rzb policy: 1: points splatted in C into a depth and colour frame; 0: as GL points")      \
    X(rzb_cache_mb, rzb_cache_mb, U32, 0, 0, 0, 65536, 1,                                        \
      "rzb policy: MiB of sample caches (Wand 7.2), least recently drawn dropped; 0: none")     \
    X(rzb_copies, rzb_copies, U32, 0, 0, 0, 24, 1,                                               \
      "rzb policy: the scene drawn as 2^N x 2^N copies of itself side by side along x and y, held once (Wand 7.3); 0: once") \
    X(rzb_raster, rzb_raster, B, 1, 0, 0, 1, 1,                                                  \
      "rzb policy: 1: faces that may project over d^2 / ln v pixels are rasterised; 0: points only (Wand Fig. 6)") \
    X(cube_px, cube_px, U32, 1, 1, 0, 64, 1,                                                     \
      "cubes policy and far_cubes: a node whose box projects within cube_px x cube_px pixels is drawn as its colour cube") \
    X(far_cubes, far_cubes, B, 0, 0, 0, 1, 0,                                                    \
      "1: a front node within cube_px is drawn as its colour cube, its mesh neither read nor drawn (a store built with far cubes, docs/cubes.md); 0: never") \
    X(cube_copies, cube_copies, U32, 0, 0, 0, 16, 0,                                             \
      "cubes policy: the scene drawn as 2^N x 2^N copies of itself side by side along x and y, held once, a block of copies within cube_px drawn as one cube (Chamberlain Fig. 5); 0: once") \
    X(lumi_mesh_px, lumi_mesh_px, D, 8, 0, 1, HLOD_UNBOUNDED, 1,                                  \
      "lumigraph policy: a node is refined while its projected error exceeds this many pixels (the sparse mesh)") \
    X(lumi_cache_mb, lumi_cache_mb, U32, 50, 1, 0, 65536, 0,                                     \
      "lumigraph policy: MiB of fetched views kept, least recently used dropped")               \
    X(lumi_tol, lumi_tol, D, 0.05, 0, 0, 10, 1,                                                  \
      "lumigraph policy: a fragment farther than (1 + lumi_tol) x a view's depth is hidden from that view") \
    X(lumi_uploads, lumi_uploads, U32, 2, 1, 0, 4, 1,                                            \
      "lumigraph policy: views uploaded to the GPU per frame at most")                          \
    X(splats, splats, B, 1, 0, 0, 1, 1,                                                          \
      "klein policy: 1: small nodes are splats; 0: every node is drawn (the reference walk)")   \
    X(batch, batch, B, 1, 0, 0, 1, 0,                                                            \
      "1: small untextured nodes (batch_tris) are kept on the CPU and drawn together; 0: each in its own draw call") \
    X(batch_tris, batch_tris, U32, 256, 1, 0, 65536, 0,                                          \
      "batch: an untextured node of at most this many triangles is batched")                   \
    X(texture_upload, texture_upload, U32, 0, 0, 0, 2, 0,                                        \
      "block-coded textures: 1 the loader expands them to texels; 2 uploaded as blocks; 0 blocks where the GL samples them natively") \
    X(read_chunk_bytes, read_chunk_bytes, U32, 64u << 10, 1, 0, HLOD_UNBOUNDED, 0,               \
      "the loader reads a payload in steps of this many bytes")                                  \
    X(upload_budget_bytes, upload_budget_bytes, U64, 16ull << 20, 1, 0, HLOD_UNBOUNDED, 1,       \
      "GL uploads per frame, bytes (at least one upload is made)")                               \
    X(upload_budget_ms, upload_budget_ms, D, 0, 0, 0, HLOD_UNBOUNDED, 1,                         \
      "GL upload time per frame; 0: 10% of target_ms; not when deterministic or timed by a model") \
    X(dyn_res, dyn_res, B, 0, 0, 0, 1, 1,                                                        \
      "1: when even the budget's floor misses target_ms, frames render smaller and are scaled up (to 0.5 x width and height); 0: never") \
    X(loader_idle, loader_idle, B, 0, 0, 0, 1, 0,                                                \
      "1: the loader thread runs under SCHED_IDLE (only on a core the render thread leaves); 0: at nice 10") \
    X(max_inflight, max_inflight, U32, 32, 1, 0, HLOD_UNBOUNDED, 1,                              \
      "requests handed to the loader at once")                                                   \
    X(v_time, fixed_v_time, D, 1e-4, 0, 1, HLOD_UNBOUNDED, 1,                                    \
      "deterministic runs: ms per unit of cost, held instead of fitted")                         \
    X(fixed_ms, fixed_frame_ms, D, 0, 0, 0, HLOD_UNBOUNDED, 1,                                   \
      "deterministic runs: the frame's fixed part, ms, below target_ms")                         \
    X(deterministic_load_bytes, deterministic_load_bytes, U64, 4ull << 20, 1, 0, HLOD_UNBOUNDED, 1, \
      "deterministic runs: bytes the synchronous loader reads per frame")                        \
    X(deadline_quantile, deadline_quantile, D, 0.99, 0.5, 1, 0.9999, 1,                           \
      "the fraction of frames to finish within target_ms (the margin follows the measured spread)") \
    X(aim_mean, aim_mean, B, 0, 0, 0, 1, 1,                                                      \
      "1: the paper's control, the mean frame time on target_ms (no margin); 0: the deadline")    \
    X(still_refine_late, still_refine_late, B, 1, 0, 0, 1, 1,                                    \
      "1: a still camera's held front still refines where data it waited for arrives late; 0: no") \
    X(cone_cull, cone_cull, B, 0, 0, 0, 1, 1,                                                    \
      "1: a node whose normal cone faces away from the eye is skipped with its subtree; 0: off") \
    X(occlusion, occlusion, B, 1, 0, 0, 1, 1,                                                    \
      "1: nodes hidden behind this frame's depth are not drawn, charged or refined; 0: off")      \
    X(steady_heap, steady_heap, B, 1, 0, 0, 1, 0,                                                \
      "1: glibc keeps up to 128 MiB freed and maps only blocks over 32 MiB, set once per process; 0: untouched")

#define HLOD_SETTING_KIND_D double
#define HLOD_SETTING_KIND_U32 uint32_t
#define HLOD_SETTING_KIND_U64 uint64_t
/* B: a switch.  Its field holds 1 (on), -1 (off) or 0 (the default), so
 * that zero keeps meaning "default"; hlod_engine_desc_set takes 0 or 1. */
#define HLOD_SETTING_KIND_B int

/* Engine settings.  Zero means "default" for every numeric field (the
 * table above); defaults are filled in one place
 * (hlod_engine_desc_defaults). */
typedef struct hlod_engine_desc {
#define HLOD_SETTING_FIELD(key, field, kind, def, lo, lo_open, hi, live, help) \
    HLOD_SETTING_KIND_##kind field;
    HLOD_ENGINE_SETTINGS(HLOD_SETTING_FIELD)
#undef HLOD_SETTING_FIELD
    hlod_policy policy;          /* default HLOD_POLICY_LAKHIA */

    /* Reproducible runs: v_time and the fixed frame part are held at
     * fixed_v_time and fixed_frame_ms instead of fitted from measurements,
     * and the loader runs synchronously inside frame() reading at most
     * deterministic_load_bytes per frame in priority order. */
    int deterministic;

    /* Nodes that normal cones cull are still asked for (at the priority of
     * a node just outside the frustum), so hlod_engine_replay_coned can
     * draw them: hlod-bench --cone-check. */
    int keep_coned;

    /* Policy lumigraph: the sampling repository (hlod-lumigraph-bake's
     * folder, or its URL); read at create. */
    const char *lumigraph_repo;
    /* ... 1: lumigraph_repo is hlod-lumigraph-serve's URL, asked for answers
     * (the views the eye lacks, one request); 0: each view a file. */
    int lumigraph_answers;

    hlod_renderer *renderer;     /* NULL: select only, draw nothing (tests) */
    hlod_time_model time_model;  /* NULL: wall time (glFinish-bounded) */
    void *time_model_user;
    hlod_read_hook read_hook;    /* NULL: none */
    void *read_hook_user;
    hlod_logger logger;          /* func NULL: silent; may be called from the loader thread */
    hlod_allocator allocator;    /* alloc NULL: malloc/realloc/free */
} hlod_engine_desc;

/* One row of HLOD_ENGINE_SETTINGS, for listing and parsing by name. */
typedef struct hlod_engine_setting {
    const char *key, *help;
    const char *kind;            /* "D", "U32", "U64", "B" */
    double def, lo, hi;
    int lo_open, live;
} hlod_engine_setting;

/* The settings in table order; *count gets their number. */
const hlod_engine_setting *hlod_engine_settings(size_t *count);

/* Sets the setting called key in d.  HLOD_ERR_INVALID_ARG for an unknown
 * key, a non-finite value, or one its kind cannot hold (a negative or
 * fractional count).  The range is checked at create/set. */
hlod_result hlod_engine_desc_set(hlod_engine_desc *d, const char *key, double value);

/* Fills every zero field of d with its default.  Idempotent. */
void hlod_engine_desc_defaults(hlod_engine_desc *d);

#define HLOD_STATS_MAX_DEPTH 32

typedef struct hlod_frame_stats {
    uint64_t frame;              /* 0, 1, ... */
    double measured_ms;          /* whole frame, glFinish-bounded (or time_model) */
    double estimated_ms;         /* fixed_ms + v_time * drawn cost */
    double v_time;               /* ms per cost unit used this frame */
    double fixed_ms;             /* fixed part of the cost model */
    double budget_ms;            /* target - fixed: the bound on the estimate */
    double share_gain;           /* roots' shareTime / budget_ms (>= 1) */
    double traversal_ms;         /* CPU time of selection (no GL) */
    double upload_ms;            /* CPU time of GL uploads and frees */
    double sse_pixels;           /* current SSE threshold (policy sse) */
    double splat_px;             /* the splat size this frame drew with (klein, klein-auto) */
    double res_scale;            /* the scale of width and height this frame was selected
                                    and drawn at, then scaled up to the window (dyn_res;
                                    docs/runtime.md "Dynamic resolution"); 1: full */
    uint32_t nodes_drawn;
    uint32_t nodes_per_depth[HLOD_STATS_MAX_DEPTH]; /* deeper nodes count in the last */
    uint64_t tris_drawn;
    double cost_drawn;           /* sum of eq. 1 over drawn nodes */
    uint32_t toggles_up;         /* drawn node replaced by its children */
    uint32_t toggles_down;       /* children replaced by their parent */
    uint32_t oscillations;       /* toggles reversing one within 10 frames */
    uint32_t nodes_visited;      /* nodes whose priority was computed */
    uint32_t wanted_missing;     /* visible nodes wanted but not resident */
    uint32_t resident_nodes;
    uint64_t resident_bytes;     /* payload bytes of resident nodes */
    double resident_cost;        /* c_memory * sum(cost of resident) */
    uint64_t memory_budget_bytes;
    uint32_t loads;              /* nodes that became resident this frame */
    uint32_t evictions;          /* nodes evicted this frame */
    uint64_t bytes_read;         /* by the loader, this frame */
    uint32_t load_failures;      /* reads that failed this frame */
    uint32_t bad_nodes;          /* nodes marked bad so far */
    uint32_t queued;             /* requests handed to the loader */
    uint32_t render_waits;       /* times the render thread slept in this frame
                                    (voluntary context switches) outside GL, a
                                    deterministic run's synchronous reads and the
                                    logger: it blocked, on the loader or anything
                                    else; must be 0.  A preemption is not a wait, nor
                                    a sleep in a major page fault (render_paged) */
    uint32_t render_paged;       /* sleeps of the render thread in this frame while the
                                    system read a page of the process back in (a major
                                    fault: paging, e.g. a host reclaiming cold pages) */
    /* cost model and deadline (docs/runtime.md, "The cost model and deadline margin") */
    double pixels_drawn;         /* screen pixels of the drawn nodes' projected boxes */
    double margin;               /* deadline margin: the front may take (target - uploads) / margin */
    /* occlusion (docs/runtime.md, "Occlusion") */
    uint32_t occlusion_hidden;   /* front nodes hidden in the last frame: not charged, not refined */
    uint32_t occlusion_tested;   /* front nodes tested against this frame's depth pyramid */
    uint32_t occlusion_culled;   /* front nodes that test hid: not drawn */
    uint32_t cone_culled;        /* nodes skipped with their subtrees because their normal
                                    cone faced away from the eye (docs/runtime.md, "Normal
                                    cones") */
    uint64_t cone_culled_tris;   /* triangles of those nodes themselves: what the
                                    frame would have drawn for them, coarsest */
    uint32_t splats;             /* sample tree nodes drawn as one splat (policy klein;
                                    docs/sampletree.md), rzb's points, colour cubes
                                    drawn (policy cubes, or far_cubes; docs/cubes.md) */
    double occlusion_ms;         /* CPU time of the depth read-back, pyramid and tests */
    /* loader thread CPU time this frame (docs/store-format.md) */
    double loader_finish_ms;     /* checksums, decoding and validation of payloads */
    double loader_busy_ms;       /* all its work: reads, hashing, finishing */
    uint32_t cache_hits;         /* payloads the loader took from the local cache
                                    (HLOD_CACHE_DIR) this frame: not in bytes_read */
    /* policy lumigraph (docs/lumigraph.md) */
    uint64_t lumi_bytes;         /* view bytes fetched from the repository this frame */
    uint64_t lumi_answer_max;    /* the largest answer (one view) among them */
    uint32_t lumi_uploads;       /* views uploaded to the GPU this frame */
    uint32_t lumi_missing;       /* views the frame's blend lacked (not fetched yet) */
    uint32_t gl_draws;           /* draw calls the renderer issued for the frame */
} hlod_frame_stats;

/* Creates an engine over an open store: reads every top node (groups and hlod_0)
 * synchronously (they are always resident), uploads them when a renderer is
 * given, and starts the loader thread (not in deterministic mode).
 * HLOD_ERR_INVALID_ARG for a bad desc (e.g. c_hyst_switch outside [1,
 * c_hyst_limit], a NaN), HLOD_ERR_NOMEM, or the error of an hlod_0 read. */
hlod_result hlod_engine_create(const hlod_store *store, const hlod_engine_desc *desc,
                               hlod_engine **out);

/* Stops and joins the loader, frees GPU resources (context current) and
 * everything else.  e may be NULL. */
void hlod_engine_destroy(hlod_engine *e);

/* One frame: collect finished loads and upload them (within the upload
 * budget), select nodes, draw them, measure, update the cost model, hand
 * the loader its new queue and evict.  Never blocks on the loader.  dt is
 * the simulated time since the previous frame (for the camera velocity).
 * HLOD_ERR_INVALID_ARG for a NULL argument or a non-finite camera or dt (no
 * frame is drawn, stats are zeroed).  stats may be NULL. */
hlod_result hlod_engine_frame(hlod_engine *e, const hlod_camera *cam, double dt,
                              hlod_frame_stats *stats);

/* Changes settings between frames: target_ms, c_* constants, policy,
 * sse_pixels, fixed_v_time.  Fields that need a restart (memory budget,
 * renderer, deterministic) are ignored.  HLOD_ERR_INVALID_ARG as for create. */
hlod_result hlod_engine_set(hlod_engine *e, const hlod_engine_desc *desc);
const hlod_engine_desc *hlod_engine_get_desc(const hlod_engine *e);

/* The box of what the engine draws: the store's, or with copies (rzb_copies
 * under policy rzb, cube_copies under policy cubes) the box of all of
 * them, 2^N store widths along x and y.  A viewer's far plane must reach
 * it. */
void hlod_engine_scene_box(const hlod_engine *e, double lo[3], double hi[3]);

/* Draws the last frame's selection again from cam and returns its time in
 * *ms, measured like a frame's (glFinish-bounded; the time model's when
 * one is set).  Changes nothing: no collecting, uploads, learning or
 * loader requests, and the next frame is as if this call had not been
 * made.  occlusion 1 culls hidden nodes as a frame does (when the setting
 * is on), 0 draws every node of the selection (when the frame culled: in
 * its draw order, the culled nodes last, so that a depth tie between two
 * nodes falls the same way in both).  For the machine's own
 * jitter (hlod-bench replays one frozen selection) and for checking that
 * occlusion culling changes no pixel.  Policy rzb, whose selection is its
 * sampling, samples the last frame's view again with its seed (the same
 * points) before drawing.  HLOD_ERR_INVALID_ARG before the first frame or
 * for a bad camera. */
hlod_result hlod_engine_replay(hlod_engine *e, const hlod_camera *cam, int occlusion, double *ms);

/* Draws the last frame's selection again from cam as hlod_engine_replay
 * with occlusion 1 does, and then every node normal cones culled in it
 * that is resident, as that frame would have drawn them (back faces
 * culled): the pixels must not change.  *drawn gets the culled nodes
 * drawn, *unchecked those not resident (not drawn); either may be NULL.
 * HLOD_ERR_INVALID_ARG as replay. */
hlod_result hlod_engine_replay_coned(hlod_engine *e, const hlod_camera *cam, uint32_t *drawn,
                                     uint32_t *unchecked);

/* Loads every node the policy HLOD_POLICY_FULL would draw from cam (all
 * leaves in or near the frustum), synchronously, ignoring the budget.  For
 * reference renders only. */
hlod_result hlod_engine_load_all_leaves(hlod_engine *e, const hlod_camera *cam);

/* Inspection for tests and tools (render thread). */
typedef enum hlod_node_state {
    HLOD_NODE_ABSENT = 0,
    HLOD_NODE_QUEUED,            /* handed to the loader */
    HLOD_NODE_RESIDENT,
    HLOD_NODE_BAD                /* failed for good: never retried */
} hlod_node_state;

hlod_node_state hlod_engine_node_state(const hlod_engine *e, uint32_t node);
/* 1 when node was drawn in the last frame. */
int hlod_engine_node_drawn(const hlod_engine *e, uint32_t node);
/* The node's hysteresis counter and last time slice / need (ms). */
void hlod_engine_node_debug(const hlod_engine *e, uint32_t node, double *hyst,
                            double *time_slice, double *time_needed, double *priority);

#ifdef __cplusplus
}
#endif
#endif
