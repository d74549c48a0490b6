/*
 * The synthetic city's built-in camera paths (see city_paths.h).
 *
 * Design:
 * - Layout.  The street grid mirrors preprocess/city.c: cells of 80 x 64 m
 *   (a 64 x 48 m block and half of a 16 m street all round), ceil(sqrt(N))
 *   columns, centred on the origin, ground at origin z.  Street lines run
 *   along the cell borders; along the outer border only half a street
 *   exists, so the outer lines are moved 4 m inwards (the middle of that
 *   half-street).  tests/test_path.c checks every path against generated
 *   geometry (block boxes, ground height), so a change of layout in city.c
 *   fails a test rather than walking the camera into a wall.
 * - Ground-level routes are "turtle" curves: straight runs joined by
 *   circular arcs, parameterised by arc length, so a camera moving along
 *   them at constant speed has continuous velocity.  The look-at point is
 *   the route point a fixed distance ahead (the route is extended straight
 *   past its ends).
 * - Each path is sampled at fixed keyframe rates; values are rounded to
 *   0.1 mm in city-local coordinates before the origin is added, so a
 *   last-bit difference in a libm sin() cannot change a file.
 * - The text is formatted here exactly as hlod_path_to_text formats it (the
 *   engine library is not linked into hlod-gen-city); the test compares the
 *   two byte for byte.
 */
#include "city_paths.h"

#include "atomic_file.h"

#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>


/* Street grid: keep in step with preprocess/city.c. */
#define CELL_W 80.0
#define CELL_D 64.0
#define OUTER_INSET 4.0     /* outer street lines: middle of the half-street */

#define CITY_HEIGHT 45.0    /* above the tallest building (12 storeys) */
#define EYE_HEIGHT 1.7
#define WALK_SPEED 1.4
#define DRIVE_SPEED 14.0
#define WALK_LOOK_AHEAD 10.0
#define TURN_RADIUS 6.0
#define FLY_HEIGHT 100.0
#define FLY_SPEED 40.0
#define FLY_LOOK_AHEAD 150.0
#define VIEW_FOV_DEG 60.0   /* vertical field assumed for "whole city in view" */

const char *const hlod_city_path_names[HLOD_CITY_PATH_COUNT] = {
    "walk", "walk-drive", "walk-to-fly", "fly", "orbit", "still",
};

static const char *const DESCRIPTIONS[HLOD_CITY_PATH_COUNT] = {
    "walk: eye 1.7 m above the ground along streets near the centre at about 1.4 m/s,\n"
    "a left turn at an intersection, looking 10 m ahead.",
    "walk-drive: 200 frames (dt 1/30 s) walking at 1.4 m/s, then 200 frames driving at\n"
    "14 m/s along one street (smooth 0.5 s acceleration around frame 200), Lakhia Fig. 8.",
    "walk-to-fly: 5 s walking north at 1.7 m, then rising for 15 s (geometrically) until\n"
    "the whole city is in view (60 degree vertical field), held for 2 s; Lakhia Fig. 7.",
    "fly: 100 m above the ground at 40 m/s, two passes over the whole city joined by a\n"
    "U-turn, looking 150 m ahead at the ground.",
    "orbit: one turn around the centre in 60 s, looking at the centre of the ground.",
    "still: the camera does not move for 20 s (30 m above the south edge, looking at the\n"
    "centre).",
};

/* ---- layout ---- */

typedef struct layout {
    size_t ncols, nrows;
    double w, d;            /* ground extent */
    size_t ic, jc;          /* the central street intersection */
    double origin[3];
} layout;

static void make_layout(const hlod_city_desc *desc, layout *L)
{
    size_t blocks = desc->blocks ? desc->blocks : 200;
    size_t c = (size_t)ceil(sqrt((double)blocks));
    L->ncols = c < 1 ? 1 : c;
    L->nrows = (blocks + L->ncols - 1) / L->ncols;
    L->w = (double)L->ncols * CELL_W;
    L->d = (double)L->nrows * CELL_D;
    L->ic = L->ncols / 2 > 0 ? L->ncols / 2 : 1;
    L->jc = L->nrows / 2;
    memcpy(L->origin, desc->origin, sizeof L->origin);
}

/* Street line i = 0 .. ncols along y (an x position), and j along x. */
static double street_x(const layout *L, size_t i)
{
    if (i == 0)
        return -L->w / 2 + OUTER_INSET;
    if (i >= L->ncols)
        return L->w / 2 - OUTER_INSET;
    return (double)i * CELL_W - L->w / 2;
}

static double street_y(const layout *L, size_t j)
{
    if (j == 0)
        return -L->d / 2 + OUTER_INSET;
    if (j >= L->nrows)
        return L->d / 2 - OUTER_INSET;
    return (double)j * CELL_D - L->d / 2;
}

/* ---- routes: straight runs and arcs by arc length ---- */

#define MAX_PIECES 8

typedef struct piece {
    double x, y, heading;   /* start point, heading (radians) */
    double len;
    double turn;            /* 0: straight; else +1 left, -1 right */
    double radius;
} piece;

typedef struct route {
    piece p[MAX_PIECES];
    int n;
    double x, y, heading, len;  /* the turtle, and the length so far */
} route;

/* Exact unit vectors for the right angles the routes use. */
static void direction(double heading, double *dx, double *dy)
{
    double q = heading / (M_PI / 2);
    if (q == round(q)) {
        static const double c[4] = {1, 0, -1, 0};
        int k = (int)(((long)round(q) % 4 + 4) % 4);
        *dx = c[k];
        *dy = c[(k + 3) % 4];
        return;
    }
    *dx = cos(heading);
    *dy = sin(heading);
}

static void route_start(route *r, double x, double y, double heading)
{
    memset(r, 0, sizeof *r);
    r->x = x;
    r->y = y;
    r->heading = heading;
}

static piece *route_push(route *r, double len)
{
    assert(r->n < MAX_PIECES && len > 0);
    piece *p = &r->p[r->n++];
    p->x = r->x;
    p->y = r->y;
    p->heading = r->heading;
    p->len = len;
    r->len += len;
    return p;
}

/* Point and heading `s` along piece p (0 <= s <= p->len). */
static void piece_at(const piece *p, double s, double *x, double *y, double *heading)
{
    if (p->turn == 0) {
        double dx, dy;
        direction(p->heading, &dx, &dy);
        *x = p->x + s * dx;
        *y = p->y + s * dy;
        *heading = p->heading;
        return;
    }
    double sg = p->turn, rad = p->radius, a = s / rad;
    double nx, ny;     /* left normal at the start */
    direction(p->heading + M_PI / 2, &nx, &ny);
    double cx = p->x + sg * rad * nx, cy = p->y + sg * rad * ny;
    double h = p->heading + sg * a;
    double hx, hy;
    direction(h - M_PI / 2, &hx, &hy);   /* (sin h, -cos h) */
    *x = cx + sg * rad * hx;
    *y = cy + sg * rad * hy;
    *heading = h;
}

static void route_forward(route *r, double len)
{
    piece *p = route_push(r, len);
    double h;
    piece_at(p, len, &r->x, &r->y, &h);
}

/* Turns by `deg` degrees (positive: left) on an arc of `radius`. */
static void route_turn(route *r, double radius, double deg)
{
    double a = fabs(deg) / 180 * M_PI;     /* 90 -> exactly M_PI / 2 */
    piece *p = route_push(r, radius * a);
    p->turn = deg > 0 ? 1 : -1;
    p->radius = radius;
    double h;
    piece_at(p, p->len, &r->x, &r->y, &h);
    r->heading = p->heading + p->turn * a;  /* exact, so later runs stay axis-aligned */
}

/* Point s along the route; straight on past either end. */
static void route_at(const route *r, double s, double xy[2])
{
    double h, x, y, dx, dy;
    if (s <= 0) {
        direction(r->p[0].heading, &dx, &dy);
        xy[0] = r->p[0].x + s * dx;
        xy[1] = r->p[0].y + s * dy;
        return;
    }
    for (int i = 0; i < r->n; i++) {
        if (s <= r->p[i].len) {
            piece_at(&r->p[i], s, &x, &y, &h);
            xy[0] = x;
            xy[1] = y;
            return;
        }
        s -= r->p[i].len;
    }
    direction(r->heading, &dx, &dy);
    xy[0] = r->x + s * dx;
    xy[1] = r->y + s * dy;
}

/* ---- keyframes ---- */

static double smoothstep(double u)
{
    u = u < 0 ? 0 : u > 1 ? 1 : u;
    return u * u * (3 - 2 * u);
}

/* Ends exactly at b, so the held keyframes at the end are identical. */
static double lerp(double a, double b, double w)
{
    return w == 1 ? b : a + w * (b - a);
}

static double round_mm(double v)
{
    return round(v * 1e4) / 1e4;
}

static hlod_result add_key(hlod_path *p, const layout *L, double t, const double eye[3],
                           const double at[3])
{
    if (p->count == p->capacity) {
        size_t cap = p->capacity ? 2 * p->capacity : 64;
        hlod_path_key *k = realloc(p->keys, cap * sizeof *k);
        if (!k)
            return HLOD_ERR_NOMEM;
        p->keys = k;
        p->capacity = cap;
    }
    hlod_path_key *k = &p->keys[p->count++];
    k->t = t;
    for (int i = 0; i < 3; i++) {
        k->eye[i] = round_mm(eye[i]) + L->origin[i];
        k->at[i] = round_mm(at[i]) + L->origin[i];
    }
    return HLOD_OK;
}

/* A ground-level (or constant-height) route at constant speed over
 * `duration`, keys at `rate` per second; the look-at is `ahead` metres
 * further along at height at_z. */
static hlod_result sample_route(hlod_path *p, const layout *L, const route *r, double rate,
                                double duration, double eye_z, double ahead, double at_z)
{
    long nk = lround(duration * rate);
    double v = r->len / duration;
    for (long k = 0; k <= nk; k++) {
        double t = (double)k / rate, s = v * t, eye[3], at[3];
        route_at(r, s, eye);
        route_at(r, s + ahead, at);
        eye[2] = eye_z;
        at[2] = at_z;
        hlod_result res = add_key(p, L, t, eye, at);
        if (res)
            return res;
    }
    return HLOD_OK;
}

static hlod_result make_walk(hlod_path *p, const layout *L)
{
    double x = street_x(L, L->ic), y = street_y(L, L->jc);
    route r;
    route_start(&r, x - 20, y, 0);
    route_forward(&r, 20 - TURN_RADIUS);
    route_turn(&r, TURN_RADIUS, 90);
    route_forward(&r, 22 - TURN_RADIUS);
    double duration = ceil(r.len / WALK_SPEED * 2) / 2;
    return sample_route(p, L, &r, 2, duration, EYE_HEIGHT, WALK_LOOK_AHEAD, EYE_HEIGHT);
}

/* Distance walked by time t: walking speed, then a smoothstep velocity ramp
 * over [tc - ramp, tc + ramp], then driving speed. */
static double walk_drive_s(double t, double tc, double ramp)
{
    double dv = DRIVE_SPEED - WALK_SPEED;
    double s = WALK_SPEED * t;
    if (t <= tc - ramp)
        return s;
    if (t >= tc + ramp)
        return s + dv * (t - tc);
    double u = (t - (tc - ramp)) / (2 * ramp);
    return s + dv * 2 * ramp * (u * u * u - u * u * u * u / 2);   /* integral of smoothstep */
}

static hlod_result make_walk_drive(hlod_path *p, const layout *L)
{
    const double rate = 10, tc = 199.5 / 30, ramp = 0.25, end = 399.0 / 30;
    double len = walk_drive_s(end, tc, ramp);
    double y = street_y(L, L->jc);
    long nk = lround(end * rate);
    for (long k = 0; k <= nk; k++) {
        double t = (double)k / rate;
        double x = -len / 2 + walk_drive_s(t, tc, ramp);
        double eye[3] = {x, y, EYE_HEIGHT}, at[3] = {x + WALK_LOOK_AHEAD, y, EYE_HEIGHT};
        hlod_result res = add_key(p, L, t, eye, at);
        if (res)
            return res;
    }
    return HLOD_OK;
}

/* Where the whole city (ground plus CITY_HEIGHT) fills the vertical field
 * with 5 % margin, seen from the south at 50 degrees elevation. */
static void overview(const layout *L, double eye[3], double at[3])
{
    double radius = 0.5 * sqrt(L->w * L->w + L->d * L->d + CITY_HEIGHT * CITY_HEIGHT);
    double dist = 1.05 * radius / sin(VIEW_FOV_DEG / 2 * M_PI / 180);
    double el = 50 * M_PI / 180;
    at[0] = 0;
    at[1] = 0;
    at[2] = CITY_HEIGHT / 2;
    eye[0] = 0;
    eye[1] = -dist * cos(el);
    eye[2] = CITY_HEIGHT / 2 + dist * sin(el);
}

/* The eye rises geometrically (the same factor every frame, so the
 * level of detail the engine needs sweeps evenly through the hierarchy, as
 * in Lakhia Fig. 7) after a smoothstep in log height, so the rise starts
 * and ends with zero speed.  It walks on above the street until it is
 * higher than any building (CLEAR_HEIGHT), then moves back to the overview
 * point as it climbs; the look-at swings from ahead to the centre with the
 * log height. */
#define CLEAR_HEIGHT 60.0

static hlod_result make_walk_to_fly(hlod_path *p, const layout *L)
{
    const double walk_end = 5, rise = 15, hold = 2, rate = 2;
    double x = street_x(L, L->ic), y0 = street_y(L, L->jc) - (L->jc > 0 ? 7 : 0);
    double eye1[3], at1[3];
    overview(L, eye1, at1);
    double ratio = eye1[2] / EYE_HEIGHT;
    long nk = lround((walk_end + rise + hold) * rate);
    for (long k = 0; k <= nk; k++) {
        double t = (double)k / rate;
        double lift = smoothstep((t - walk_end) / rise);
        double z = lift == 1 ? eye1[2] : EYE_HEIGHT * pow(ratio, lift);
        double back = smoothstep((z - CLEAR_HEIGHT) / (eye1[2] - CLEAR_HEIGHT));
        double wy = y0 + WALK_SPEED * t;   /* walks on until the eye clears the roofs */
        double eye[3] = {lerp(x, eye1[0], back), lerp(wy, eye1[1], back), z};
        double ahead[3] = {x, wy + WALK_LOOK_AHEAD, EYE_HEIGHT}, at[3];
        for (int i = 0; i < 3; i++)
            at[i] = lerp(ahead[i], at1[i], lift);
        hlod_result res = add_key(p, L, t, eye, at);
        if (res)
            return res;
    }
    return HLOD_OK;
}

static hlod_result make_fly(hlod_path *p, const layout *L)
{
    const double margin = 60;
    route r;
    route_start(&r, -L->w / 2 - margin, -L->d / 4, 0);
    route_forward(&r, L->w + margin);
    route_turn(&r, L->d / 4, 180);
    route_forward(&r, L->w + margin);
    double duration = ceil(r.len / FLY_SPEED * 2) / 2;
    return sample_route(p, L, &r, 2, duration, FLY_HEIGHT, FLY_LOOK_AHEAD, 0);
}

static hlod_result make_orbit(hlod_path *p, const layout *L)
{
    const double period = 60, rate = 2;
    double radius = 0.5 * hypot(L->w, L->d);
    double ro = 0.75 * radius, height = 0.45 * radius + 40;
    long nk = lround(period * rate);
    for (long k = 0; k <= nk; k++) {
        double t = (double)k / rate;
        double a = -M_PI / 2 + 2 * M_PI * (double)k / (double)nk;
        double eye[3] = {ro * cos(a), ro * sin(a), height}, at[3] = {0, 0, 0};
        hlod_result res = add_key(p, L, t, eye, at);
        if (res)
            return res;
    }
    return HLOD_OK;
}

static hlod_result make_still(hlod_path *p, const layout *L)
{
    double eye[3] = {street_x(L, L->ic), street_y(L, 0), 30}, at[3] = {0, 0, 0};
    hlod_result res = add_key(p, L, 0, eye, at);
    return res ? res : add_key(p, L, 20, eye, at);
}

static int path_index(const char *name)
{
    for (int i = 0; name && i < HLOD_CITY_PATH_COUNT; i++)
        if (!strcmp(name, hlod_city_path_names[i]))
            return i;
    return -1;
}

static int desc_ok(const hlod_city_desc *d)
{
    if (!d || d->blocks > 1000000)
        return 0;
    for (int i = 0; i < 3; i++)
        if (!isfinite(d->origin[i]) || fabs(d->origin[i]) > 1e9)
            return 0;
    return 1;
}

hlod_result hlod_city_path(const hlod_city_desc *desc, const char *name, hlod_path *out)
{
    if (!out)
        return HLOD_ERR_INVALID_ARG;
    free(out->keys);
    memset(out, 0, sizeof *out);
    int which = path_index(name);
    if (which < 0 || !desc_ok(desc))
        return HLOD_ERR_INVALID_ARG;
    layout L;
    make_layout(desc, &L);
    hlod_result (*const makers[HLOD_CITY_PATH_COUNT])(hlod_path *, const layout *) = {
        make_walk, make_walk_drive, make_walk_to_fly, make_fly, make_orbit, make_still,
    };
    hlod_result r = makers[which](out, &L);
    if (r != HLOD_OK) {
        free(out->keys);
        memset(out, 0, sizeof *out);
    }
    return r;
}

/* ---- text: the shared path writer (hlod_path_to_text) ---- */

/* The comment heading a city path file: what made it, and the path. */
static void city_comment(const hlod_city_desc *desc, const char *name, char *out, size_t n)
{
    char o[3][32];
    for (int i = 0; i < 3; i++)
        hlod_path_format_double(o[i], desc->origin[i]);
    snprintf(out, n,
             "hlod camera path '%s' for the city of: hlod-gen-city --blocks %zu --origin %s %s %s\n"
             "(streets depend on the block count and origin only, not on seed or budget).\n"
             "Made by hlod-gen-city --paths (preprocess/city_paths.c); z up, metres.\n%s",
             name, desc->blocks ? desc->blocks : (size_t)200, o[0], o[1], o[2],
             DESCRIPTIONS[path_index(name)]);
}

hlod_result hlod_city_path_text(const hlod_city_desc *desc, const char *name, char **text,
                                size_t *len)
{
    if (!text)
        return HLOD_ERR_INVALID_ARG;
    *text = NULL;
    if (len)
        *len = 0;
    hlod_path p = {0};
    hlod_result r = hlod_city_path(desc, name, &p);
    if (r != HLOD_OK)
        return r;
    char comment[2048];
    city_comment(desc, name, comment, sizeof comment);
    r = hlod_path_to_text(&p, comment, text, len);
    hlod_path_free(&p);
    return r;
}

hlod_result hlod_city_paths_write(const hlod_city_desc *desc, const char *dir,
                                  const hlod_logger *lg)
{
    if (!dir || !*dir || !desc_ok(desc))
        return HLOD_ERR_INVALID_ARG;
    size_t n = strlen(dir) + 32;
    char *file = malloc(n);
    if (!file)
        return HLOD_ERR_NOMEM;
    int e = hlod_mkdir_p(dir, 0777);
    if (e) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot create folder: %s", dir, strerror(e));
        free(file);
        return HLOD_ERR_IO;
    }
    hlod_result r = HLOD_OK;
    for (int i = 0; i < HLOD_CITY_PATH_COUNT && r == HLOD_OK; i++) {
        const char *name = hlod_city_path_names[i];
        hlod_path p = {0};
        char comment[2048];
        snprintf(file, n, "%s/%s.path", dir, name);
        if ((r = hlod_city_path(desc, name, &p)) != HLOD_OK)
            break;
        city_comment(desc, name, comment, sizeof comment);
        r = hlod_path_write(&p, file, comment, lg);
        hlod_path_free(&p);
    }
    free(file);
    return r;
}
