/*
 * hlod-view: a GLFW window over a store, flown through freely (or along a
 * camera path) with the engine holding the frame time at its target.
 *
 *   hlod-view STORE [options]
 *
 * Design:
 * - One thread, GLFW's main thread, owns the window, the GL 3.3 core
 *   context, the renderer and the engine (the engine's loader thread is its
 *   own business).  Per iteration: poll events, move the camera by the wall
 *   time since the last frame, one hlod_engine_frame (which draws and waits
 *   for the GPU), a pixel read when a screenshot is due (before the swap:
 *   the back buffer is undefined after it), swap, then sleep out the rest
 *   of target_ms, so a store small enough to draw in full does not spin at
 *   hundreds of frames a second.  The sleep lies outside the engine's
 *   measured frame, so it does not feed its cost model.
 * - All viewer state lives in one `viewer` struct that the GLFW callbacks
 *   reach through glfwSetWindowUserPointer.  The error callback has no user
 *   pointer: it only prints.
 * - Discrete keys (speeds, toggles, screenshots) arrive through the key
 *   callback; movement keys are polled each frame so motion does not
 *   depend on key repeat.
 * - No GL call here (house style: engine/gl_*.c hold them all); screenshots
 *   read pixels through hlod_renderer_read_rgb.
 *
 * Exit status: 0 success, 1 a failure (unreadable store or path, no
 * display, no GL 3.3, a screenshot or recording not written), 2 bad command
 * line.
 */
#include <assert.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#define GLFW_INCLUDE_NONE   /* no GL headers outside engine/gl_*.c */
#include <GLFW/glfw3.h>

#include "atomic_file.h"
#include "cli.h"
#include "data_dir.h"
#include "view_flags.h"
#include "hlod/engine.h"
#include "hlod/renderer.h"
#include "hlod/image.h"
#include "hlod/path.h"
#include "hlod/vec3.h"

static const char *const PROG = "hlod-view";

#define PI 3.14159265358979323846
#define SPEED_WALK 1.5          /* m/s, key 1 */
#define SPEED_DRIVE 15.0        /* key 2 */
#define SPEED_FLY 80.0          /* key 3 (the start speed) */
#define BOOST 4.0               /* speed factor while Shift is held */
#define LOOK_RAD_PER_PIXEL (0.15 * PI / 180)
#define PITCH_LIMIT (89.0 * PI / 180)
#define RECORD_STEP_S 0.1       /* --record: one keyframe per 1/10 s */
#define TITLE_PERIOD_S 0.25
#define STDERR_PERIOD_S 1.0
#define SCREENSHOT_FRAMES 30    /* --screenshot without --frames */
#define TARGET_STEP 1.25        /* +/- multiply or divide target_ms */

/* The sky behind the city; --screenshot's coverage counts other pixels. */
static const float CLEAR_RGB[3] = {0.62f, 0.74f, 0.86f};

static void usage(FILE *fp)
{
    fprintf(fp,
        "usage: hlod-view STORE [options]\n"
        "\n"
        "Opens a window on STORE (OpenGL 3.3) and flies through it while the\n"
        "engine holds the frame time at the target.\n"
        "\n"
        "  --width W         window width (default 1280)\n"
        "  --height H        window height (default 720)\n"
        "  --target-ms T     target frame time in ms (default 33.3)\n"
        "  --policy P        " HLOD_POLICY_CHOICES " (default lakhia)\n"
        "  --lumigraph REPO  policy lumigraph over the sampling repository REPO (a\n"
        "                    folder from hlod-lumigraph-bake, or its URL)\n"
        "  --answers         REPO is hlod-lumigraph-serve's URL: one request brings\n"
        "                    the views the eye lacks\n"
        "  --memory-mb M     memory budget in MiB (default: the whole store decoded,\n"
        "                    at most a quarter of the machine's memory)\n"
        "  --path P          play a camera path instead of free flight: a file,\n"
        "                    or a built-in name (walk, fly, walk-to-fly,\n"
        "                    walk-drive, orbit, still) in --paths-dir; a\n"
        "                    movement key or the mouse takes over, and so does\n"
        "                    the end of the path\n"
        "  --paths-dir D     where built-in names are looked up (default\n"
        "                    %s/paths/default)\n"
        "  --record FILE     record the camera as a path (a keyframe every 0.1 s\n"
        "                    of wall time), written when the viewer exits\n"
        "  --screenshot F    save a PNG after the last frame, print the fraction\n"
        "                    of non-sky pixels as 'coverage=0.43' on stdout, exit\n"
        "  --frames N        exit after N frames (default: on Esc; 30 with\n"
        "                    --screenshot); a path then advances 1/30 s a frame\n"
        "  --start X Y Z     eye position (default: above the south edge of the\n"
        "                    store's bounding box)\n"
        "  --look X Y Z      look-at point (default: the bounding box's centre)\n"
        "  --up z|y          up axis of the model (default z)\n"
        "  --fov DEG         vertical field of view (default 60)\n"
        "  -h, --help        show this help\n"
        "\n"
        "Keys: W/S forward/back, A/D left/right, Q/E down/up, drag with the left\n"
        "button (or M to capture the mouse) to look around, Shift x4 speed;\n"
        "1 walk (1.5 m/s), 2 drive (15 m/s), 3 fly (80 m/s); +/- target time;\n"
        "H hysteresis on/off (lakhia <-> nohyst); C colour by depth; F wireframe;\n"
        "P screenshot (hlod-view-NNNN.png); Esc quit.\n"
        "\n"
        "The window title shows frame time vs target, drawn nodes per depth,\n"
        "resident memory vs budget and loads; stderr gets a line every second.\n"
        "\n"
        "Exit status: 0 success, 1 a failure (store, display, GL, output),\n"
        "2 bad command line.\n",
        hlod_tool_data_dir());
}

/* ---- options ---- */

typedef struct options {
    const char *store, *path, *paths_dir, *record, *screenshot;
    const char *lumigraph;  /* --lumigraph REPO: policy lumigraph from this repository */
    int answers;            /* --answers: REPO is hlod-lumigraph-serve's URL */
    uint32_t width, height;
    double target_ms, memory_mb, fov, near_plane;
    hlod_policy policy;
    int policy_given;   /* --policy was given (else lakhia, klein for a sample tree) */
    long frames;            /* -1: until Esc */
    int up_y, have_start, have_look;
    double start[3], look[3];
} options;

/* "--start X Y Z": three values after the flag. */
static int parse_point(int argc, char **argv, int *i, const char *flag, double out[3])
{
    if (*i + 3 >= argc) {
        hlod_cli_usage_error(PROG, "%s needs three numbers X Y Z", flag);
        return 0;
    }
    for (int k = 0; k < 3; k++)
        if (!hlod_cli_parse_double(PROG, flag, argv[*i + 1 + k], -HLOD_PATH_COORD_MAX,
                                   HLOD_PATH_COORD_MAX, 0, &out[k]))
            return 0;
    *i += 3;
    return 1;
}

/* Returns -1 to continue, else an exit status. */
static int parse_args(int argc, char **argv, options *o)
{
    memset(o, 0, sizeof *o);
    o->width = 1280;
    o->height = 720;
    o->target_ms = 33.3;
    o->fov = 60;
    o->near_plane = 0.25;
    o->frames = -1;
    o->policy = HLOD_POLICY_LAKHIA;
    o->paths_dir = hlod_tool_default_paths_dir();
    const view_flags vf = {&o->width, &o->height, &o->target_ms, &o->memory_mb, &o->fov,
                           &o->path,  &o->paths_dir, &o->frames, &o->up_y};
    for (int i = 1; i < argc; i++) {
        const char *v = NULL;
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            usage(stdout);
            return 0;
        }
        int shared = view_flags_parse(PROG, argc, argv, &i, &vf);
        if (shared < 0)
            return 2;
        if (shared)
            continue;
#define FLAG(name) hlod_cli_match_flag(argc, argv, &i, name, &v)
#define NEED(name)                                                              \
    if (!v)                                                                     \
        return hlod_cli_usage_error(PROG, "%s needs a value", name);
        if (FLAG("--policy")) {
            NEED("--policy");
            o->policy_given = 1;
            if (!hlod_policy_parse(v, &o->policy) || o->policy == HLOD_POLICY_FULL)
                return hlod_cli_usage_error(PROG, "--policy: unknown policy '%s' "
                                            "(" HLOD_POLICY_CHOICES ")", v);
        } else if (FLAG("--lumigraph")) {
            NEED("--lumigraph");
            o->lumigraph = v;
            o->policy = HLOD_POLICY_LUMIGRAPH;
            o->policy_given = 1;
        } else if (!strcmp(a, "--answers")) {
            o->answers = 1;
        } else if (FLAG("--record")) {
            NEED("--record");
            o->record = v;
        } else if (FLAG("--screenshot")) {
            NEED("--screenshot");
            o->screenshot = v;
        } else if (!strcmp(a, "--start")) {
            if (!parse_point(argc, argv, &i, "--start", o->start))
                return 2;
            o->have_start = 1;
        } else if (!strcmp(a, "--look")) {
            if (!parse_point(argc, argv, &i, "--look", o->look))
                return 2;
            o->have_look = 1;
        } else if (a[0] == '-' && a[1]) {
            return hlod_cli_usage_error(PROG, "unknown option '%s'", a);
        } else if (!o->store) {
            o->store = a;
        } else {
            return hlod_cli_usage_error(PROG, "unexpected argument '%s' (one store only)", a);
        }
#undef FLAG
#undef NEED
    }
    if (!o->store)
        return hlod_cli_usage_error(PROG, "no store given%s", "");
    if (o->path && (o->have_start || o->have_look))
        return hlod_cli_usage_error(PROG, "--start/--look and --path exclude each other%s", "");
    if (o->have_start && o->have_look && o->start[0] == o->look[0] &&
        o->start[1] == o->look[1] && o->start[2] == o->look[2])
        return hlod_cli_usage_error(PROG, "--start and --look are the same point%s", "");
    if (o->screenshot && o->frames < 0)
        o->frames = SCREENSHOT_FRAMES;
    return -1;
}

/* ---- viewer state ---- */

/* Frame statistics gathered over a display period (title, stderr line). */
typedef struct period {
    double start;           /* glfwGetTime() when it began */
    uint32_t frames;
    double ms_sum, ms_max;
    uint64_t loads, evictions, toggles_up, toggles_down;
} period;

typedef struct viewer {
    const options *o;
    GLFWwindow *win;
    hlod_store *store;
    hlod_renderer *renderer;
    hlod_engine *engine;
    hlod_logger lg;
    uint32_t depths;        /* depth_count, capped at HLOD_STATS_MAX_DEPTH */

    /* camera: eye plus yaw/pitch in the frame (e1, e2 horizontal, up) */
    double eye[3], yaw, pitch;
    double e1[3], e2[3], up[3];
    double centre[3], diag;
    double speed;
    hlod_camera cam;        /* the last good camera */

    /* mouse look */
    int dragging, captured, have_cursor;
    double cursor_x, cursor_y;

    /* path playback */
    hlod_path path;
    int playing;
    double path_t;

    /* recording */
    hlod_path rec;
    double rec_next;

    /* toggles and requests from the key callback */
    int depth_colors, wireframe, shot_requested;
    unsigned shot_counter;

    hlod_frame_stats last;
    uint64_t total_loads;
    period title, line;
} viewer;

static void forward_dir(const viewer *v, double f[3])
{
    double cp = cos(v->pitch), sp = sin(v->pitch), cy = cos(v->yaw), sy = sin(v->yaw);
    for (int k = 0; k < 3; k++)
        f[k] = cp * (cy * v->e1[k] + sy * v->e2[k]) + sp * v->up[k];
}

/* Horizontal, to the right of the view direction (e1 x e2 = up). */
static void right_dir(const viewer *v, double r[3])
{
    double cy = cos(v->yaw), sy = sin(v->yaw);
    for (int k = 0; k < 3; k++)
        r[k] = sy * v->e1[k] - cy * v->e2[k];
}

/* Points the free-flight camera from eye towards at. */
static void aim(viewer *v, const double eye[3], const double at[3])
{
    double d[3] = {at[0] - eye[0], at[1] - eye[1], at[2] - eye[2]};
    memcpy(v->eye, eye, sizeof v->eye);
    double h1 = hlod_dot3(d, v->e1), h2 = hlod_dot3(d, v->e2), u = hlod_dot3(d, v->up);
    v->yaw = (h1 == 0 && h2 == 0) ? 0 : atan2(h2, h1);
    v->pitch = atan2(u, hypot(h1, h2));
    if (v->pitch > PITCH_LIMIT)
        v->pitch = PITCH_LIMIT;
    if (v->pitch < -PITCH_LIMIT)
        v->pitch = -PITCH_LIMIT;
}

/* Default view: above the south edge of the bounding box (its low end
 * along e2: -y for z up, +z for y up), looking at its centre. */
static void default_view(const viewer *v, const hlod_store_header *h, double eye[3],
                         double at[3])
{
    double ext[3];
    for (int k = 0; k < 3; k++)
        ext[k] = h->bbox_max[k] - h->bbox_min[k];
    double span2 = fabs(hlod_dot3(ext, v->e2)), span_up = fabs(hlod_dot3(ext, v->up));
    double span_h = fmax(fabs(hlod_dot3(ext, v->e1)), span2);
    double height = 0.5 * span_up + fmax(0.4 * span_h, 1.0);
    for (int k = 0; k < 3; k++) {
        at[k] = v->centre[k];
        eye[k] = v->centre[k] - 0.5 * span2 * v->e2[k] + height * v->up[k];
    }
}

/* Builds v->cam from eye and at; keeps the previous camera when they are
 * degenerate (a path whose eye and look-at cross). */
static void make_camera(viewer *v, const double eye[3], const double at[3], uint32_t w,
                        uint32_t h)
{
    double far_plane = 3 * v->diag + 1000;
    for (int k = 0; k < 3; k++)
        far_plane += fabs(eye[k] - v->centre[k]);
    hlod_camera cam;
    if (hlod_camera_look_at(&cam, eye, at, v->up, v->o->fov, v->o->near_plane, far_plane, w,
                            h) != HLOD_OK &&
        /* looking straight along the up axis: any horizontal up will do */
        hlod_camera_look_at(&cam, eye, at, v->e2, v->o->fov, v->o->near_plane, far_plane, w,
                            h) != HLOD_OK)
        return;
    v->cam = cam;
}

/* Free flight from here on, starting where the path left the camera. */
static void take_over(viewer *v)
{
    if (!v->playing)
        return;
    v->playing = 0;
    double f[3];
    hlod_camera_forward(&v->cam, f);
    double at[3] = {v->cam.position[0] + f[0], v->cam.position[1] + f[1],
                    v->cam.position[2] + f[2]};
    aim(v, v->cam.position, at);
    fprintf(stderr, "%s: free flight\n", PROG);
}

/* ---- GLFW callbacks (main thread, from glfwPollEvents) ---- */

static void on_error(int code, const char *desc)
{
    fprintf(stderr, "%s: GLFW error 0x%x: %s\n", PROG, (unsigned)code, desc);
}

static void set_target(viewer *v, double factor)
{
    hlod_engine_desc d = *hlod_engine_get_desc(v->engine);
    d.target_ms = fmin(fmax(d.target_ms * factor, 1.0), 1000.0);
    if (hlod_engine_set(v->engine, &d) == HLOD_OK)
        fprintf(stderr, "%s: target %.1f ms\n", PROG, d.target_ms);
}

static void toggle_policy(viewer *v)
{
    hlod_engine_desc d = *hlod_engine_get_desc(v->engine);
    d.policy = d.policy == HLOD_POLICY_LAKHIA ? HLOD_POLICY_NOHYST : HLOD_POLICY_LAKHIA;
    if (hlod_engine_set(v->engine, &d) == HLOD_OK)
        fprintf(stderr, "%s: policy %s\n", PROG, hlod_policy_name(d.policy));
}

static void on_key(GLFWwindow *win, int key, int scancode, int action, int mods)
{
    viewer *v = glfwGetWindowUserPointer(win);
    (void)scancode;
    (void)mods;
    if (action == GLFW_REPEAT && (key == GLFW_KEY_EQUAL || key == GLFW_KEY_KP_ADD ||
                                  key == GLFW_KEY_MINUS || key == GLFW_KEY_KP_SUBTRACT))
        action = GLFW_PRESS;   /* held +/- keeps stepping */
    if (action != GLFW_PRESS)
        return;
    switch (key) {
    case GLFW_KEY_ESCAPE: glfwSetWindowShouldClose(win, GLFW_TRUE); break;
    case GLFW_KEY_1: v->speed = SPEED_WALK; break;
    case GLFW_KEY_2: v->speed = SPEED_DRIVE; break;
    case GLFW_KEY_3: v->speed = SPEED_FLY; break;
    case GLFW_KEY_EQUAL:
    case GLFW_KEY_KP_ADD: set_target(v, TARGET_STEP); break;
    case GLFW_KEY_MINUS:
    case GLFW_KEY_KP_SUBTRACT: set_target(v, 1 / TARGET_STEP); break;
    case GLFW_KEY_H: toggle_policy(v); break;
    case GLFW_KEY_C:
        v->depth_colors = !v->depth_colors;
        hlod_renderer_set_depth_colors(v->renderer, v->depth_colors);
        break;
    case GLFW_KEY_F:
        v->wireframe = !v->wireframe;
        hlod_renderer_set_wireframe(v->renderer, v->wireframe);
        break;
    case GLFW_KEY_P: v->shot_requested = 1; break;
    case GLFW_KEY_M:
        v->captured = !v->captured;
        v->have_cursor = 0;
        glfwSetInputMode(win, GLFW_CURSOR, v->captured ? GLFW_CURSOR_DISABLED : GLFW_CURSOR_NORMAL);
        break;
    default: break;
    }
}

static void on_mouse_button(GLFWwindow *win, int button, int action, int mods)
{
    viewer *v = glfwGetWindowUserPointer(win);
    (void)mods;
    if (button == GLFW_MOUSE_BUTTON_LEFT) {
        v->dragging = action == GLFW_PRESS;
        v->have_cursor = 0;
    }
}

static void on_cursor(GLFWwindow *win, double x, double y)
{
    viewer *v = glfwGetWindowUserPointer(win);
    if (!v->dragging && !v->captured)
        return;
    if (v->have_cursor && (x != v->cursor_x || y != v->cursor_y)) {
        take_over(v);
        /* screen y grows downwards: moving the mouse up looks up */
        v->yaw -= (x - v->cursor_x) * LOOK_RAD_PER_PIXEL;
        v->pitch -= (y - v->cursor_y) * LOOK_RAD_PER_PIXEL;
        v->pitch = fmin(fmax(v->pitch, -PITCH_LIMIT), PITCH_LIMIT);
        v->yaw = remainder(v->yaw, 2 * PI);
    }
    v->cursor_x = x;
    v->cursor_y = y;
    v->have_cursor = 1;
}

/* ---- per frame ---- */

/* WASD/QE, polled: moves the eye by speed * dt along the view direction,
 * its right and the up axis. */
static void move_free(viewer *v, double dt)
{
    GLFWwindow *w = v->win;
    double f[3], r[3], m[3] = {0, 0, 0};
    forward_dir(v, f);
    right_dir(v, r);
    int fb = (glfwGetKey(w, GLFW_KEY_W) == GLFW_PRESS) - (glfwGetKey(w, GLFW_KEY_S) == GLFW_PRESS);
    int rl = (glfwGetKey(w, GLFW_KEY_D) == GLFW_PRESS) - (glfwGetKey(w, GLFW_KEY_A) == GLFW_PRESS);
    int ud = (glfwGetKey(w, GLFW_KEY_E) == GLFW_PRESS) - (glfwGetKey(w, GLFW_KEY_Q) == GLFW_PRESS);
    if (!fb && !rl && !ud)
        return;
    take_over(v);
    for (int k = 0; k < 3; k++)
        m[k] = fb * f[k] + rl * r[k] + ud * v->up[k];
    double len = sqrt(hlod_dot3(m, m));
    if (len == 0)
        return;
    double boost = (glfwGetKey(w, GLFW_KEY_LEFT_SHIFT) == GLFW_PRESS ||
                    glfwGetKey(w, GLFW_KEY_RIGHT_SHIFT) == GLFW_PRESS) ? BOOST : 1;
    double step = v->speed * boost * dt / len;
    for (int k = 0; k < 3; k++)
        v->eye[k] += m[k] * step;
}

/* Keyframe (t, eye, eye + 1 unit along the view) every RECORD_STEP_S. */
static void record(viewer *v, double t, int force)
{
    if (!v->o->record || (!force && t < v->rec_next))
        return;
    if (v->rec.count && t <= v->rec.keys[v->rec.count - 1].t)
        return;
    double f[3], at[3];
    hlod_camera_forward(&v->cam, f);
    for (int k = 0; k < 3; k++)
        at[k] = v->cam.position[k] + f[k];
    if (hlod_path_append(&v->rec, t, v->cam.position, at) != HLOD_OK)
        return;   /* out of range or no memory: skip this keyframe */
    while (v->rec_next <= t)
        v->rec_next += RECORD_STEP_S;
}

static void period_add(period *p, const hlod_frame_stats *s)
{
    p->frames++;
    p->ms_sum += s->measured_ms;
    p->ms_max = fmax(p->ms_max, s->measured_ms);
    p->loads += s->loads;
    p->evictions += s->evictions;
    p->toggles_up += s->toggles_up;
    p->toggles_down += s->toggles_down;
}

/* "4 12 30": drawn nodes per depth, trailing zero depths left out. */
static void depth_list(const viewer *v, char *buf, size_t size)
{
    uint32_t last = 0;
    for (uint32_t d = 0; d < v->depths; d++)
        if (v->last.nodes_per_depth[d])
            last = d;
    size_t used = 0;
    buf[0] = 0;
    for (uint32_t d = 0; d <= last && used < size; d++) {
        int n = snprintf(buf + used, size - used, "%s%u", d ? " " : "",
                         (unsigned)v->last.nodes_per_depth[d]);
        if (n < 0)
            break;
        used += (size_t)n;
    }
}

static void show_stats(viewer *v, double now)
{
    const hlod_frame_stats *s = &v->last;
    const hlod_engine_desc *d = hlod_engine_get_desc(v->engine);
    char depths[256];
    if (now - v->title.start >= TITLE_PERIOD_S && v->title.frames) {
        depth_list(v, depths, sizeof depths);
        char title[512];
        snprintf(title, sizeof title,
                 "hlod-view | %.1f / %.1f ms | %s | depth %s | %.0f / %.0f MiB | loads %llu "
                 "(%llu queued)%s",
                 v->title.ms_sum / v->title.frames, d->target_ms, hlod_policy_name(d->policy),
                 depths, (double)s->resident_bytes / 1048576.0,
                 (double)s->memory_budget_bytes / 1048576.0,
                 (unsigned long long)v->total_loads, (unsigned long long)s->queued,
                 v->playing ? " | path" : "");
        glfwSetWindowTitle(v->win, title);
        memset(&v->title, 0, sizeof v->title);
        v->title.start = now;
    }
    if (now - v->line.start >= STDERR_PERIOD_S && v->line.frames) {
        const period *p = &v->line;
        depth_list(v, depths, sizeof depths);
        fprintf(stderr,
                "%s: %.1f fps, frame %.1f ms (max %.1f) / %.1f target, %s, %.1f ktri, "
                "depth %s, %.1f / %.0f MiB, %llu loads, %llu evictions, %u queued, "
                "%u missing, toggles +%llu -%llu\n",
                PROG, p->frames / (now - p->start), p->ms_sum / p->frames, p->ms_max,
                d->target_ms, hlod_policy_name(d->policy), (double)s->tris_drawn / 1e3, depths,
                (double)s->resident_bytes / 1048576.0, (double)s->memory_budget_bytes / 1048576.0,
                (unsigned long long)p->loads, (unsigned long long)p->evictions,
                (unsigned)s->queued, (unsigned)s->wanted_missing,
                (unsigned long long)p->toggles_up, (unsigned long long)p->toggles_down);
        memset(&v->line, 0, sizeof v->line);
        v->line.start = now;
    }
}

/* Reads the back buffer and writes it as a PNG; *coverage (may be NULL)
 * gets the fraction of pixels that are not the sky. */
static hlod_result screenshot(viewer *v, const char *file, uint32_t w, uint32_t h,
                              double *coverage)
{
    size_t npix = (size_t)w * h;
    uint8_t *rgb = malloc(npix * 3);
    if (!rgb)
        return HLOD_ERR_NOMEM;
    hlod_result r = hlod_renderer_read_rgb(v->renderer, w, h, rgb);
    if (r == HLOD_OK && coverage) {
        int bg[3];
        for (int c = 0; c < 3; c++)
            bg[c] = (int)lrintf(CLEAR_RGB[c] * 255.0f);
        size_t hit = 0;
        for (size_t i = 0; i < npix; i++)
            for (int c = 0; c < 3; c++)
                if (abs((int)rgb[3 * i + c] - bg[c]) > 2) {
                    hit++;
                    break;
                }
        *coverage = (double)hit / (double)npix;
    }
    if (r == HLOD_OK) {
        hlod_image img = {(int)w, (int)h, 3, rgb};
        r = hlod_image_write(file, &img, &v->lg);
    }
    free(rgb);
    return r;
}

/* P: hlod-view-NNNN.png, the first number not taken in the current folder. */
static void key_screenshot(viewer *v, uint32_t w, uint32_t h)
{
    char name[64];
    for (;;) {
        snprintf(name, sizeof name, "hlod-view-%04u.png", v->shot_counter++);
        if (access(name, F_OK) != 0 || v->shot_counter > 99999)
            break;
    }
    if (screenshot(v, name, w, h, NULL) == HLOD_OK)
        fprintf(stderr, "%s: saved %s\n", PROG, name);
    else
        hlod_cli_error(PROG, "%s: screenshot not saved", name);
}

static void sleep_s(double s)
{
    if (s <= 0)
        return;
    struct timespec ts;
    ts.tv_sec = (time_t)s;
    ts.tv_nsec = (long)((s - (double)ts.tv_sec) * 1e9);
    nanosleep(&ts, NULL);
}

/* The frame loop.  Returns the exit status. */
static int run(viewer *v)
{
    const options *o = v->o;
    const double fixed_dt = 1.0 / 30;   /* path time per frame with --frames */
    double t0 = glfwGetTime(), prev = t0;
    v->title.start = v->line.start = t0;
    if (v->playing)
        v->path_t = hlod_path_start(&v->path);
    int shot_taken = 0;
    for (long frame = 0; !glfwWindowShouldClose(v->win); frame++) {
        double frame_start = glfwGetTime();
        glfwPollEvents();
        double now = glfwGetTime();
        double dt = frame == 0 ? fixed_dt : fmin(fmax(now - prev, 1e-4), 0.25);
        prev = now;
        int fw = 0, fh = 0;
        glfwGetFramebufferSize(v->win, &fw, &fh);
        if (fw <= 0 || fh <= 0) {   /* minimised */
            glfwWaitEventsTimeout(0.1);
            continue;
        }

        double eye[3], at[3];
        if (v->playing) {
            if (o->frames > 0)
                dt = fixed_dt;   /* reproducible screenshots */
            if (frame > 0)
                v->path_t += dt;
            hlod_path_eval(&v->path, v->path_t, eye, at);
            make_camera(v, eye, at, (uint32_t)fw, (uint32_t)fh);
            if (v->path_t >= hlod_path_end(&v->path) && o->frames < 0) {
                fprintf(stderr, "%s: end of the path\n", PROG);
                take_over(v);
            }
        } else {
            move_free(v, dt);
        }
        if (!v->playing) {
            double f[3];
            forward_dir(v, f);
            for (int k = 0; k < 3; k++) {
                eye[k] = v->eye[k];
                at[k] = v->eye[k] + f[k];
            }
            make_camera(v, eye, at, (uint32_t)fw, (uint32_t)fh);
        }

        hlod_result r = hlod_engine_frame(v->engine, &v->cam, dt, &v->last);
        if (r != HLOD_OK) {
            hlod_cli_error(PROG, "%s: frame %ld failed: %s", o->store, frame, hlod_result_str(r));
            return 1;
        }
        v->total_loads += v->last.loads;
        period_add(&v->title, &v->last);
        period_add(&v->line, &v->last);

        int last_frame = o->frames > 0 && frame + 1 >= o->frames;
        if (v->shot_requested) {
            v->shot_requested = 0;
            key_screenshot(v, (uint32_t)fw, (uint32_t)fh);
        }
        if (last_frame && o->screenshot) {
            double coverage = 0;
            if (screenshot(v, o->screenshot, (uint32_t)fw, (uint32_t)fh, &coverage) != HLOD_OK) {
                hlod_cli_error(PROG, "%s: screenshot not saved", o->screenshot);
                return 1;
            }
            printf("coverage=%.4f\n", coverage);
            fflush(stdout);
            shot_taken = 1;
        }
        glfwSwapBuffers(v->win);

        now = glfwGetTime();
        record(v, now - t0, 0);
        show_stats(v, now);
        if (last_frame)
            break;
        /* hold the frame rate at the target (see the design note) */
        sleep_s(hlod_engine_get_desc(v->engine)->target_ms / 1000.0 - (now - frame_start));
    }
    record(v, glfwGetTime() - t0, 1);
    if (o->screenshot && !shot_taken) {
        hlod_cli_error(PROG, "%s: window closed before frame %ld, no screenshot", o->screenshot,
                       o->frames);
        return 1;
    }
    return 0;
}

/* ---- main ---- */

/* 1 when file's folder exists and is writable: checked at start so a
 * flight is not recorded only to fail at exit. */
static int folder_writable(const char *file)
{
    char dir[4096];
    snprintf(dir, sizeof dir, "%s", file);
    char *slash = strrchr(dir, '/');
    if (!slash)
        snprintf(dir, sizeof dir, ".");
    else if (slash == dir)
        slash[1] = 0;
    else
        *slash = 0;
    struct stat sb;
    return stat(dir, &sb) == 0 && S_ISDIR(sb.st_mode) && access(dir, W_OK) == 0;
}

/* glfwGetProcAddress as an hlod_gl_get_proc, converting the function
 * pointer by its bytes rather than by a cast between the two kinds. */
static void *get_proc(const char *name)
{
    GLFWglproc f = glfwGetProcAddress(name);
    void *p;
    static_assert(sizeof p == sizeof f, "function and object pointers differ");
    memcpy(&p, &f, sizeof p);
    return p;
}

static void init_camera(viewer *v, const hlod_store_header *h)
{
    const options *o = v->o;
    /* e1 x e2 = up, so yaw turns counter-clockwise seen from above */
    double zu[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    double yu[3][3] = {{1, 0, 0}, {0, 0, -1}, {0, 1, 0}};
    double (*b)[3] = o->up_y ? yu : zu;
    memcpy(v->e1, b[0], sizeof v->e1);
    memcpy(v->e2, b[1], sizeof v->e2);
    memcpy(v->up, b[2], sizeof v->up);
    double diag2 = 0;
    for (int k = 0; k < 3; k++) {
        v->centre[k] = 0.5 * (h->bbox_min[k] + h->bbox_max[k]);
        diag2 += (h->bbox_max[k] - h->bbox_min[k]) * (h->bbox_max[k] - h->bbox_min[k]);
    }
    v->diag = sqrt(diag2);
    v->speed = SPEED_FLY;

    double eye[3], at[3];
    default_view(v, h, eye, at);
    if (o->have_start)
        memcpy(eye, o->start, sizeof eye);
    if (o->have_look)
        memcpy(at, o->look, sizeof at);
    if (eye[0] == at[0] && eye[1] == at[1] && eye[2] == at[2])
        at[0] += 1;   /* --start at the box centre without --look */
    aim(v, eye, at);
    double f[3];
    forward_dir(v, f);
    double a2[3] = {eye[0] + f[0], eye[1] + f[1], eye[2] + f[2]};
    make_camera(v, eye, a2, o->width, o->height);
}

int main(int argc, char **argv)
{
    options o;
    int rc = parse_args(argc, argv, &o);
    if (rc >= 0)
        return rc;

    hlod_cli_log log_state = {PROG, HLOD_LOG_WARN, NULL};
    viewer v;
    memset(&v, 0, sizeof v);
    v.o = &o;
    v.lg = hlod_cli_logger(&log_state);

    const char *outputs[2] = {o.record, o.screenshot};
    for (int i = 0; i < 2; i++)
        if (outputs[i] && !folder_writable(outputs[i])) {
            hlod_cli_error(PROG, "%s: its folder does not exist or is not writable", outputs[i]);
            return 1;
        }
    if (o.path) {
        char path_file[4096];
        snprintf(path_file, sizeof path_file, "%s", o.path);
        if (!hlod_is_file(path_file) && !strchr(o.path, '/'))
            snprintf(path_file, sizeof path_file, "%s/%s.path", o.paths_dir, o.path);
        if (hlod_path_load(path_file, &v.lg, &v.path) != HLOD_OK)
            return 1;   /* the loader named the file and line */
        v.playing = 1;
    }
    if (hlod_store_open(o.store, &v.lg, &v.store) != HLOD_OK) {
        hlod_cli_error(PROG, "%s: not a readable hlod store", o.store);
        hlod_path_free(&v.path);
        return 1;
    }
    const hlod_store_header *h = hlod_store_get_header(v.store);
    if (!o.policy_given && (h->flags & HLOD_STORE_ADDITIVE))
        o.policy = h->build.method == HLOD_STORE_METHOD_CUBES ? HLOD_POLICY_CUBES
                                                              : HLOD_POLICY_KLEIN;
    v.depths = h->depth_count < HLOD_STATS_MAX_DEPTH ? h->depth_count : HLOD_STATS_MAX_DEPTH;
    init_camera(&v, h);

    rc = 1;
    glfwSetErrorCallback(on_error);
    if (!glfwInit()) {
        hlod_cli_error(PROG, "cannot initialise GLFW: no display? (DISPLAY=%s; "
                       "run under xvfb-run for a virtual one)",
                       getenv("DISPLAY") ? getenv("DISPLAY") : "unset");
        goto close_store;
    }
    glfwWindowHint(GLFW_CONTEXT_VERSION_MAJOR, 3);
    glfwWindowHint(GLFW_CONTEXT_VERSION_MINOR, 3);
    glfwWindowHint(GLFW_OPENGL_PROFILE, GLFW_OPENGL_CORE_PROFILE);
    glfwWindowHint(GLFW_OPENGL_FORWARD_COMPAT, GLFW_TRUE);
    glfwWindowHint(GLFW_DEPTH_BITS, 24);
    glfwWindowHint(GLFW_DOUBLEBUFFER, GLFW_TRUE);
    v.win = glfwCreateWindow((int)o.width, (int)o.height, "hlod-view", NULL, NULL);
    if (!v.win) {
        hlod_cli_error(PROG, "cannot open a %ux%u window with an OpenGL 3.3 core context",
                       (unsigned)o.width, (unsigned)o.height);
        goto terminate;
    }
    glfwMakeContextCurrent(v.win);
    glfwSwapInterval(0);   /* the engine paces frames, not the display */
    glfwSetWindowUserPointer(v.win, &v);
    glfwSetKeyCallback(v.win, on_key);
    glfwSetMouseButtonCallback(v.win, on_mouse_button);
    glfwSetCursorPosCallback(v.win, on_cursor);

    hlod_result r = hlod_renderer_create(get_proc, &v.lg, &v.renderer);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "cannot create the renderer (needs OpenGL 3.3): %s",
                       hlod_result_str(r));
        goto destroy_window;
    }
    hlod_renderer_set_clear_color(v.renderer, CLEAR_RGB[0], CLEAR_RGB[1], CLEAR_RGB[2]);

    hlod_engine_desc d = {0};
    d.target_ms = o.target_ms;
    d.policy = o.policy;
    d.lumigraph_repo = o.lumigraph;
    d.lumigraph_answers = o.answers;
    d.renderer = v.renderer;
    d.logger = v.lg;
    d.memory_budget_bytes = o.memory_mb > 0 ? (uint64_t)(o.memory_mb * 1048576.0)
                                            : view_default_budget(v.store);
    r = hlod_engine_create(v.store, &d, &v.engine);
    if (r != HLOD_OK) {
        hlod_cli_error(PROG, "%s: cannot start the engine: %s", o.store, hlod_result_str(r));
        goto destroy_renderer;
    }
    {
        /* the far plane reaches every copy the engine draws (rzb_copies,
         * cube_copies); the first view stays on the store */
        double lo[3], hi[3], d2 = 0;
        hlod_engine_scene_box(v.engine, lo, hi);
        for (int k = 0; k < 3; k++)
            d2 += (hi[k] - lo[k]) * (hi[k] - lo[k]);
        v.diag = sqrt(d2);
    }
    if (o.frames < 0)
        fprintf(stderr, "%s: WASD/QE move, drag to look (M captures the mouse), 1/2/3 "
                        "walk/drive/fly, +/- target, H hysteresis, C depth colours, "
                        "F wireframe, P screenshot, Esc quit\n", PROG);

    rc = run(&v);
    if (o.record && rc == 0) {
        char comment[4200];
        snprintf(comment, sizeof comment, "recorded by hlod-view from %s", o.store);
        if (v.rec.count == 0 || hlod_path_write(&v.rec, o.record, comment, &v.lg) != HLOD_OK) {
            hlod_cli_error(PROG, "%s: recording not written", o.record);
            rc = 1;
        } else {
            fprintf(stderr, "%s: recorded %zu keyframes to %s\n", PROG, v.rec.count, o.record);
        }
    }

    hlod_engine_destroy(v.engine);
destroy_renderer:
    hlod_renderer_destroy(v.renderer);
destroy_window:
    glfwDestroyWindow(v.win);
terminate:
    glfwTerminate();
close_store:
    hlod_store_close(v.store);
    hlod_path_free(&v.path);
    hlod_path_free(&v.rec);
    return rc;
}
