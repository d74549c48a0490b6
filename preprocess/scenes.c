/*
 * scenes.c - Chamberlain's tree and molecule, made procedurally
 * (scenes.h).
 */
#include "scenes.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

#define TUBE_SIDES 8
#define SPHERE_SLICES 20
#define SPHERE_STACKS 21        /* 2 * 20 * (21 - 1) = 800 triangles */
#define ATOMS_PER_OBJECT 50
#define LEAF_TRIS_PER_OBJECT 20000

typedef struct builder {
    hlod_mesh m;
    size_t vcap, tcap, ocap;
    int failed;
    uint64_t rng;           /* xorshift state: each call its own, no globals */
} builder;

static int grow(builder *b, size_t nv, size_t nt)
{
    hlod_mesh *m = &b->m;
    if (m->vertex_count + nv > b->vcap) {
        size_t cap = b->vcap ? b->vcap : 4096;
        while (cap < m->vertex_count + nv)
            cap *= 2;
        double *p = realloc(m->positions, cap * 3 * sizeof *p);
        if (!p)
            return 0;
        m->positions = p;
        b->vcap = cap;
    }
    if (m->tri_count + nt > b->tcap) {
        size_t cap = b->tcap ? b->tcap : 4096;
        while (cap < m->tri_count + nt)
            cap *= 2;
        uint32_t *ix = realloc(m->indices, cap * 3 * sizeof *ix);
        if (ix)
            m->indices = ix;
        uint32_t *tm = ix ? realloc(m->tri_material, cap * sizeof *tm) : NULL;
        if (!tm)
            return 0;
        m->tri_material = tm;
        b->tcap = cap;
    }
    return 1;
}

static uint32_t vert(builder *b, double x, double y, double z)
{
    double *p = &b->m.positions[3 * b->m.vertex_count];
    p[0] = x;
    p[1] = y;
    p[2] = z;
    return (uint32_t)b->m.vertex_count++;
}

static void tri(builder *b, uint32_t a, uint32_t c, uint32_t d, uint32_t mat)
{
    uint32_t *ix = &b->m.indices[3 * b->m.tri_count];
    ix[0] = a;
    ix[1] = c;
    ix[2] = d;
    b->m.tri_material[b->m.tri_count++] = mat;
}

/* Starts object `name` at the next triangle. */
static void object(builder *b, const char *name)
{
    hlod_mesh *m = &b->m;
    if (m->object_count == b->ocap) {
        size_t cap = b->ocap ? 2 * b->ocap : 16;
        hlod_object *o = realloc(m->objects, cap * sizeof *o);
        if (!o) {
            b->failed = 1;
            return;
        }
        m->objects = o;
        b->ocap = cap;
    }
    if (m->object_count)
        m->objects[m->object_count - 1].tri_count =
            m->tri_count - m->objects[m->object_count - 1].first_tri;
    hlod_object *o = &m->objects[m->object_count++];
    memset(o, 0, sizeof *o);
    o->name = strdup(name);
    o->first_tri = m->tri_count;
    if (!o->name)
        b->failed = 1;
}

static hlod_result finish(builder *b, const float (*colors)[3], size_t nmat, const char *const *names,
                          hlod_mesh *out)
{
    hlod_mesh *m = &b->m;
    if (m->object_count)
        m->objects[m->object_count - 1].tri_count =
            m->tri_count - m->objects[m->object_count - 1].first_tri;
    m->materials = calloc(nmat, sizeof *m->materials);
    if (b->failed || !m->materials) {
        hlod_mesh_free(m);
        return HLOD_ERR_NOMEM;
    }
    m->material_count = nmat;
    for (size_t i = 0; i < nmat; i++) {
        memcpy(m->materials[i].diffuse, colors[i], 3 * sizeof(float));
        m->materials[i].diffuse[3] = 1;
        m->materials[i].name = strdup(names[i]);
    }
    *out = *m;
    return HLOD_OK;
}

static double rnd(builder *b)
{
    b->rng ^= b->rng << 13;
    b->rng ^= b->rng >> 7;
    b->rng ^= b->rng << 17;
    return (double)(b->rng >> 11) / 9007199254740992.0;
}

static void normalize(double v[3])
{
    double l = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
    for (int a = 0; a < 3; a++)
        v[a] = l > 0 ? v[a] / l : (a == 2);
}

/* Two unit vectors perpendicular to d and to each other. */
static void frame(const double d[3], double u[3], double v[3])
{
    double t[3] = {fabs(d[0]) < 0.9 ? 1 : 0, fabs(d[0]) < 0.9 ? 0 : 1, 0};
    u[0] = d[1] * t[2] - d[2] * t[1];
    u[1] = d[2] * t[0] - d[0] * t[2];
    u[2] = d[0] * t[1] - d[1] * t[0];
    normalize(u);
    v[0] = d[1] * u[2] - d[2] * u[1];
    v[1] = d[2] * u[0] - d[0] * u[2];
    v[2] = d[0] * u[1] - d[1] * u[0];
}

/* ---- the tree ---- */

typedef struct twig {
    double p[3], d[3], len;
} twig;

/* A tube from p along d (unit) of length len and radius r. */
static void tube(builder *b, const double p[3], const double d[3], double len, double r)
{
    if (!grow(b, 2 * TUBE_SIDES, 2 * TUBE_SIDES)) {
        b->failed = 1;
        return;
    }
    double u[3], v[3];
    frame(d, u, v);
    uint32_t v0 = (uint32_t)b->m.vertex_count;
    for (int k = 0; k < TUBE_SIDES; k++) {
        double a = 2 * M_PI * k / TUBE_SIDES, c = cos(a) * r, s = sin(a) * r;
        for (int e = 0; e < 2; e++)
            vert(b, p[0] + e * len * d[0] + c * u[0] + s * v[0],
                 p[1] + e * len * d[1] + c * u[1] + s * v[1],
                 p[2] + e * len * d[2] + c * u[2] + s * v[2]);
    }
    for (int k = 0; k < TUBE_SIDES; k++) {
        uint32_t a = v0 + 2 * k, c = v0 + 2 * ((k + 1) % TUBE_SIDES);
        tri(b, a, c, c + 1, 0);
        tri(b, a, c + 1, a + 1, 0);
    }
}

/* Branches to `depth` below (p, d): their tubes, and the twigs' tips. */
static void branch(builder *b, const double p[3], const double d[3], double len, double r,
                   int depth, twig *tips, size_t *ntips)
{
    tube(b, p, d, len, r);
    double q[3] = {p[0] + len * d[0], p[1] + len * d[1], p[2] + len * d[2]};
    if (!depth) {
        twig *t = &tips[(*ntips)++];
        memcpy(t->p, q, sizeof q);
        memcpy(t->d, d, sizeof t->d);
        t->len = len;
        return;
    }
    double u[3], v[3];
    frame(d, u, v);
    double phase = 2 * M_PI * rnd(b);
    for (int k = 0; k < 3; k++) {
        double az = phase + 2 * M_PI * k / 3 + 0.3 * (rnd(b) - 0.5), tilt = 0.45 + 0.35 * rnd(b);
        double nd[3];
        for (int a = 0; a < 3; a++)
            nd[a] = cos(tilt) * d[a] + sin(tilt) * (cos(az) * u[a] + sin(az) * v[a]);
        nd[2] += 0.15; /* towards the light */
        normalize(nd);
        branch(b, q, nd, len * (0.62 + 0.1 * rnd(b)), r * 0.6, depth - 1, tips, ntips);
    }
}

hlod_result hlod_scene_tree(size_t tris, uint64_t seed, hlod_mesh *out)
{
    static const float colors[3][3] = {{0.36f, 0.25f, 0.15f}, {0.22f, 0.45f, 0.16f},
                                       {0.33f, 0.56f, 0.22f}};
    static const char *const names[3] = {"bark", "leaf", "leaf_light"};
    enum { DEPTH = 5, TIPS = 243 };     /* 3^5 twigs */
    memset(out, 0, sizeof *out);
    if (tris < 8000)
        tris = 8000;    /* the bark alone is 5,824 */
    builder b = {0};
    b.rng = seed * 0x9E3779B97F4A7C15ull + 1;
    twig tips[TIPS];
    size_t ntips = 0;
    object(&b, "bark");
    const double foot[3] = {0, 0, 0}, up[3] = {0, 0, 1};
    branch(&b, foot, up, 3.0, 0.25, DEPTH, tips, &ntips);
    size_t leaves = tris > b.m.tri_count ? (tris - b.m.tri_count) / 2 : 1;
    for (size_t i = 0; i < leaves && !b.failed; i++) {
        if (i % (LEAF_TRIS_PER_OBJECT / 2) == 0) {
            char name[32];
            snprintf(name, sizeof name, "leaves_%zu", i / (LEAF_TRIS_PER_OBJECT / 2));
            object(&b, name);
        }
        if (!grow(&b, 4, 2)) {
            b.failed = 1;
            break;
        }
        /* around a twig's tip: a leaf of about 0.12 units, at a random
         * orientation, within the twig's length of its end */
        const twig *t = &tips[i % ntips];
        double c[3], n[3], u[3], v[3];
        for (int a = 0; a < 3; a++) /* one draw after another: a fixed order */
            n[a] = rnd(&b) - 0.5;
        for (int a = 0; a < 3; a++)
            c[a] = t->p[a] + t->len * 0.9 * (rnd(&b) - 0.5) + 0.3 * t->len * t->d[a];
        normalize(n);
        frame(n, u, v);
        double s = 0.05 + 0.04 * rnd(&b);
        uint32_t v0 = (uint32_t)b.m.vertex_count;
        for (int k = 0; k < 4; k++) {
            double x = (k == 1 || k == 2) ? s : -s, y = k >= 2 ? s * 1.6 : -s * 0.4;
            vert(&b, c[0] + x * u[0] + y * v[0], c[1] + x * u[1] + y * v[1],
                 c[2] + x * u[2] + y * v[2]);
        }
        uint32_t mat = rnd(&b) < 0.5 ? 1 : 2;
        tri(&b, v0, v0 + 1, v0 + 2, mat);
        tri(&b, v0, v0 + 2, v0 + 3, mat);
    }
    return finish(&b, colors, 3, names, out);
}

/* ---- the molecule ---- */

hlod_result hlod_scene_molecule(size_t tris, uint64_t seed, hlod_mesh *out)
{
    static const float colors[4][3] = {{0.50f, 0.50f, 0.50f}, {0.85f, 0.15f, 0.10f},
                                       {0.15f, 0.25f, 0.85f}, {0.90f, 0.85f, 0.20f}};
    static const char *const names[4] = {"carbon", "oxygen", "nitrogen", "sulphur"};
    memset(out, 0, sizeof *out);
    size_t atoms = (size_t)llround((double)tris / 800);
    atoms = atoms ? atoms : 1;
    const double R = cbrt((double)atoms / 0.3);
    builder b = {0};
    b.rng = seed * 0x9E3779B97F4A7C15ull + 7;
    const size_t sv = SPHERE_SLICES * (SPHERE_STACKS - 1) + 2;
    for (size_t i = 0; i < atoms && !b.failed; i++) {
        if (i % ATOMS_PER_OBJECT == 0) {
            char name[32];
            snprintf(name, sizeof name, "atoms_%zu", i / ATOMS_PER_OBJECT);
            object(&b, name);
        }
        if (b.m.vertex_count + sv > UINT32_MAX || !grow(&b, sv, 800)) {
            b.failed = 1;
            break;
        }
        double c[3];
        do {
            for (int a = 0; a < 3; a++)
                c[a] = R * (2 * rnd(&b) - 1);
        } while (c[0] * c[0] + c[1] * c[1] + c[2] * c[2] > R * R);
        double x = rnd(&b);
        uint32_t mat = x < 0.6 ? 0 : x < 0.8 ? 1 : x < 0.95 ? 2 : 3;
        uint32_t south = vert(&b, c[0], c[1], c[2] - 1), ring0 = south + 1;
        for (int st = 1; st < SPHERE_STACKS; st++) {
            double th = M_PI * st / SPHERE_STACKS, z = -cos(th), rr = sin(th);
            for (int sl = 0; sl < SPHERE_SLICES; sl++) {
                double ph = 2 * M_PI * sl / SPHERE_SLICES;
                vert(&b, c[0] + rr * cos(ph), c[1] + rr * sin(ph), c[2] + z);
            }
        }
        uint32_t north = vert(&b, c[0], c[1], c[2] + 1);
        for (int sl = 0; sl < SPHERE_SLICES; sl++) {
            uint32_t n1 = (sl + 1) % SPHERE_SLICES;
            tri(&b, south, ring0 + n1, ring0 + sl, mat);
            for (int st = 0; st + 1 < SPHERE_STACKS - 1; st++) {
                uint32_t a = ring0 + st * SPHERE_SLICES + sl, a1 = ring0 + st * SPHERE_SLICES + n1;
                tri(&b, a, a1, a1 + SPHERE_SLICES, mat);
                tri(&b, a, a1 + SPHERE_SLICES, a + SPHERE_SLICES, mat);
            }
            uint32_t top = ring0 + (SPHERE_STACKS - 2) * SPHERE_SLICES;
            tri(&b, top + sl, top + n1, north, mat);
        }
    }
    return finish(&b, colors, 4, names, out);
}
