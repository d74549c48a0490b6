/*
 * test_cones.c - the normal cones of the extras table (store.h,
 * docs/store-format.md "The extras table"; docs/runtime.md "Normal
 * cones"): stores built with hlod-build ($HLOD_BIN_DIR) from a closed
 * model nobody here made (bunny00.off, data/meshes/) and from a generated
 * city, by both methods, packed and raw; every node's cone holds every
 * face of its own payload and of every descendant, as the payloads are
 * stored; a node drawn two-sided, or over one, has no bound; damaged or
 * lying extras are refused; a version-3 store is read with no extras.
 */
#include "check.h"
#include "hlod/store.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static char bin[1024], src[1024], tmp[1024];

/* Whether every face of node i's payload lies within cone (axis, c) up to
 * tol, counting the faces with an area into *faces. */
static int faces_within(const hlod_store *s, uint32_t i, const float axis[3], double c, double tol,
                        uint64_t *faces, double *worst)
{
    hlod_store_payload p;
    if (hlod_store_read_node(s, i, 1u << 20, &p) != HLOD_OK)
        return 0;
    int ok = 1;
    for (uint32_t t = 0; t < p.index_count / 3; t++) {
        const float *a = p.positions + 3 * (size_t)p.indices[3 * t],
                    *b = p.positions + 3 * (size_t)p.indices[3 * t + 1],
                    *d = p.positions + 3 * (size_t)p.indices[3 * t + 2];
        double u[3] = {(double)b[0] - a[0], (double)b[1] - a[1], (double)b[2] - a[2]};
        double v[3] = {(double)d[0] - a[0], (double)d[1] - a[1], (double)d[2] - a[2]};
        double x[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                       u[0] * v[1] - u[1] * v[0]};
        double len = sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
        if (!(len > 0))
            continue;
        double dot = (x[0] * axis[0] + x[1] * axis[1] + x[2] * axis[2]) / len;
        (*faces)++;
        if (dot - c < *worst)
            *worst = dot - c;
        ok &= dot >= c - tol;
    }
    hlod_store_payload_free(&p);
    return ok;
}

/* Checks every cone of the store at path; returns the nodes whose cone
 * could cull (cos > 0). */
static uint32_t check_store(const char *path, const char *what)
{
    hlod_store *s = NULL;
    CHECKF(hlod_store_open(path, NULL, &s) == HLOD_OK, "%s: open", what);
    if (!s)
        return 0;
    const hlod_store_node *n = hlod_store_nodes(s);
    const hlod_store_extra *x = hlod_store_extras(s);
    const uint32_t count = hlod_store_node_count(s);
    CHECKF(x != NULL && hlod_store_get_header(s)->version == HLOD_STORE_VERSION,
           "%s: no extras table", what);
    uint32_t culling = 0, solid = 0, bad = 0;
    uint64_t faces = 0;
    double worst = INFINITY;
    for (uint32_t i = 0; x && i < count; i++) {
        if (!(x[i].flags & HLOD_EXTRA_CONE))
            continue;
        solid += (n[i].render_flags & HLOD_RENDER_SOLID) != 0;
        if (!(x[i].cone_cos > -1))
            continue;
        /* bounded: drawn one-sided, and so is everything under it */
        CHECKF(n[i].render_flags & HLOD_RENDER_SOLID, "%s: node %u is two-sided with a cone %g",
               what, i, x[i].cone_cos);
        culling += x[i].cone_cos > 0;
        /* its subtree: nodes [i, ...) whose chain of parents reaches i */
        for (uint32_t j = i; j < count; j++) {
            uint32_t a = j;
            while (a != HLOD_STORE_NO_PARENT && a > i)
                a = n[a].parent;
            if (a != i)
                continue;
            if (!faces_within(s, j, x[i].cone_axis, x[i].cone_cos, 0, &faces, &worst) &&
                bad++ < 5)
                CHECKF(0, "%s: a face of node %u outside node %u's cone (cos %.7f, worst by %g)",
                       what, j, i, x[i].cone_cos, worst);
        }
    }
    printf("     %s: %u nodes, %u one-sided, %u with a cone under 90 degrees; %llu faces "
           "checked, the tightest %.2g inside\n",
           what, count, solid, culling, (unsigned long long)faces, worst);
    CHECKF(bad == 0, "%s: %u cones miss a face", what, bad);
    hlod_store_close(s);
    return culling;
}

static int build(const char *in, const char *out, const char *flags)
{
    return check_sh("'%s/hlod-build' '%s' -o '%s/%s' --quiet %s", bin, in, tmp, out, flags);
}

/* A closed model by both methods, packed and raw: cones that hold every
 * face beneath them, and some that can cull. */
static void bunny_cones_hold_their_faces(void)
{
    char in[2048], path[2048];
    snprintf(in, sizeof in, "%s/data/meshes/bunny00.off", src);
    if (access(in, R_OK) != 0) {
        CHECK_SKIP("%s missing: run data/fetch-meshes.sh", in);
        return;
    }
    const char *cases[5][2] = {{"bunny-cut.hlod", "--desired-tris 450"},
                               {"bunny-cut-split.hlod", "--desired-tris 450 --cone-split on"},
                               {"bunny-cut-raw.hlod", "--desired-tris 450 --compress off"},
                               {"bunny-metis.hlod", "--method metis --leaf-tris 400 --node-tris 200"},
                               {"bunny-metis-raw.hlod",
                                "--method metis --leaf-tris 400 --node-tris 200 --compress off"}};
    for (int k = 0; k < 5; k++) {
        CHECKF(build(in, cases[k][0], cases[k][1]) == 0, "hlod-build %s %s", in, cases[k][1]);
        snprintf(path, sizeof path, "%s/%s", tmp, cases[k][0]);
        CHECKF(check_store(path, cases[k][0]) >= 50, "%s: fewer than 50 cones under 90 degrees",
               cases[k][0]);
        hlod_store *s = NULL;
        if (hlod_store_open(path, NULL, &s) == HLOD_OK) {
            uint32_t want = k == 1 ? HLOD_BUILD_CONE_SPLIT : 0;
            CHECKF(hlod_store_get_header(s)->build.flags == want, "%s: build flags %u, want %u",
                   cases[k][0], hlod_store_get_header(s)->build.flags, want);
            hlod_store_close(s);
        }
    }
}

/* A generated city (textured, groups over blocks): the same rule. */
static void city_cones_hold_their_faces(void)
{
    char obj[2048], path[2048];
    snprintf(obj, sizeof obj, "%s/city.obj", tmp);
    CHECK(check_sh("'%s/hlod-gen-city' --preset tiny --blocks 4 --quiet -o '%s'", bin, obj) == 0);
    CHECK(build(obj, "city.hlod", "--desired-tris 500") == 0);
    snprintf(path, sizeof path, "%s/city.hlod", tmp);
    check_store(path, "tiny city");
}

/* Rewrites `bytes` at `off` of path. */
static void patch(const char *path, long off, const void *bytes, size_t n)
{
    FILE *fp = fopen(path, "r+b");
    if (!fp || fseek(fp, off, SEEK_SET) != 0 || fwrite(bytes, 1, n, fp) != n)
        abort();
    fclose(fp);
}

/* A flipped byte in a record: a checksum mismatch; a table header for
 * another count: refused naming the table; both name the file. */
static void damaged_extras_refused(void)
{
    char path[2048], copy[2048];
    snprintf(path, sizeof path, "%s/city.hlod", tmp);
    hlod_store *s = NULL;
    if (hlod_store_open(path, NULL, &s) != HLOD_OK) {
        CHECK(0);
        return;
    }
    hlod_store_header h = *hlod_store_get_header(s);
    hlod_store_close(s);
    const long rec = (long)h.extras_offset + (long)sizeof(hlod_store_extras_header) + 12;
    snprintf(copy, sizeof copy, "%s/flipped.hlod", tmp);
    CHECK(check_sh("cp '%s' '%s'", path, copy) == 0);
    uint8_t b = 0x5a;
    patch(copy, rec, &b, 1);
    CHECK(hlod_store_open(copy, NULL, &s) == HLOD_ERR_CHECKSUM && s == NULL);
    snprintf(copy, sizeof copy, "%s/count.hlod", tmp);
    CHECK(check_sh("cp '%s' '%s'", path, copy) == 0);
    uint32_t c = h.node_count + 1;
    patch(copy, (long)h.extras_offset + 8, &c, 4);
    CHECK(hlod_store_open(copy, NULL, &s) == HLOD_ERR_FORMAT && s == NULL);
}

/* The committed version-3 seed: read, with no extras. */
static void version_3_has_no_extras(void)
{
    char path[2048];
    snprintf(path, sizeof path, "%s/tests/fuzz/corpus/store/packed-two-roots.hlod", src);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (s) {
        CHECK(hlod_store_get_header(s)->version == 3 && hlod_store_extras(s) == NULL);
        hlod_store_close(s);
    }
}

int main(void)
{
    const char *b = getenv("HLOD_BIN_DIR"), *sd = getenv("HLOD_SOURCE_DIR"),
               *t = getenv("TMPDIR");
    snprintf(bin, sizeof bin, "%s", b && *b ? b : "build/bin");
    snprintf(src, sizeof src, "%s", sd && *sd ? sd : ".");
    snprintf(tmp, sizeof tmp, "%s/hlod-test-cones.XXXXXX", t && *t ? t : "/tmp");
    if (!mkdtemp(tmp)) {
        perror("mkdtemp");
        return 1;
    }
    RUN(bunny_cones_hold_their_faces);
    RUN(city_cones_hold_their_faces);
    RUN(damaged_extras_refused);
    RUN(version_3_has_no_extras);
    check_sh("rm -rf '%s'", tmp);
    return check_done();
}
