/*
 * test_build.c - the build pipeline end to end: a generated city in, a
 * store out, read back with the validating reader.  Calls the library
 * (hlod_build_store) and, for the command line, the built tools
 * ($HLOD_BIN_DIR/hlod-gen-city, hlod-build), in a scratch folder.
 */
#include "check.h"
#include "hlod/build_store.h"
#include "hlod/store.h"
#include "rec_log.h"

#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

static char bin[1024], tmp[1024];

static long file_size(const char *path)
{
    struct stat st;
    return stat(path, &st) == 0 ? (long)st.st_size : -1;
}

static int same_file(const char *a, const char *b)
{
    return check_sh("cmp -s '%s' '%s'", a, b) == 0;
}

static void city(const char *name, const char *extra)
{
    CHECKF(check_sh("'%s/hlod-gen-city' --preset tiny --blocks 4 --quiet %s -o '%s/%s.obj'", bin, extra, tmp, name) == 0,
           "hlod-gen-city %s", name);
}

static int build(const char *in, const char *out, const char *extra)
{
    return check_sh("'%s/hlod-build' '%s/%s.obj' -o '%s/%s' --desired-tris 500 --quiet %s", bin, tmp, in, tmp, out,
              extra);
}

/* The library: in.obj of the scratch folder to out, with the tests'
 * settings (desired 500) and method/threads as given. */
static hlod_result lib_build(const char *in, const char *out, hlod_build_method method,
                             size_t threads, hlod_build_report *rep, rec_log *log)
{
    char a[2048], b[2048];
    snprintf(a, sizeof a, "%s/%s.obj", tmp, in);
    snprintf(b, sizeof b, "%s/%s", tmp, out);
    hlod_build_desc d;
    hlod_build_desc_defaults(&d);
    d.desired_tris = 500;
    d.method = method;
    d.threads = threads;
    const char *inputs[] = {a};
    /* rec_log is not thread-safe: only runs that fail before the build
     * threads start (unreadable input, no folder) record the log */
    hlod_logger lg = log ? rec_logger(log) : (hlod_logger){0};
    return hlod_build_store(&d, inputs, 1, b, &lg, rep);
}

/* Children's boxes lying outside their parent's (0: every node's box
 * holds its descendants'), over the store at path. */
static int boxes_outside(const char *path, double *worst)
{
    hlod_store *s = NULL;
    *worst = 0;
    if (hlod_store_open(path, NULL, &s) != HLOD_OK)
        return -1;
    const hlod_store_node *n = hlod_store_nodes(s);
    int bad = 0;
    for (uint32_t i = 0; i < hlod_store_node_count(s); i++) {
        if (n[i].parent == HLOD_STORE_NO_PARENT)
            continue;
        const hlod_store_node *p = &n[n[i].parent];
        double out = 0;
        for (int k = 0; k < 3; k++)
            out = fmax(out, fmax(p->bbox_min[k] - n[i].bbox_min[k], n[i].bbox_max[k] - p->bbox_max[k]));
        bad += out > 0;
        *worst = fmax(*worst, out);
    }
    hlod_store_close(s);
    return bad;
}

static void builds_and_verifies_both_methods(void)
{
    city("c", "");
    CHECK(build("c", "cut.hlod", "--method cutplane") == 0);
    CHECK(build("c", "metis.hlod", "--method metis --leaf-tris 1000 --node-tris 500 --voxel-tris 200") == 0);
    char p[2048];
    snprintf(p, sizeof p, "%s/cut.hlod", tmp);
    CHECK(check_sh("'%s/hlod-info' --verify '%s' > /dev/null", bin, p) == 0);
    snprintf(p, sizeof p, "%s/metis.hlod", tmp);
    CHECK(check_sh("'%s/hlod-info' --verify '%s' > /dev/null", bin, p) == 0);
    /* the tree has more than one level and textures */
    hlod_store *s = NULL;
    snprintf(p, sizeof p, "%s/cut.hlod", tmp);
    CHECK(hlod_store_open(p, NULL, &s) == HLOD_OK);
    if (s) {
        const hlod_store_header *h = hlod_store_get_header(s);
        CHECK(h->depth_count >= 2);
        CHECK(h->flags & HLOD_STORE_TEXTURED);
        /* 4 blocks + ground under one group root */
        CHECKF(h->block_count == 5 && h->root_count == 1 && h->block_depth == 1 && h->top_count == 6,
               "%u blocks at depth %u, %u roots, %u top nodes", h->block_count, h->block_depth,
               h->root_count, h->top_count);
        hlod_store_close(s);
    }
    /* --city-levels off: the paper's layout, every block a root */
    CHECK(build("c", "flat.hlod", "--city-levels off") == 0);
    snprintf(p, sizeof p, "%s/flat.hlod", tmp);
    CHECK(hlod_store_open(p, NULL, &s) == HLOD_OK);
    if (s) {
        const hlod_store_header *h = hlod_store_get_header(s);
        CHECKF(h->block_count == 5 && h->root_count == 5 && h->block_depth == 0 && h->top_count == 5,
               "%u blocks at depth %u, %u roots", h->block_count, h->block_depth, h->root_count);
        hlod_store_close(s);
    }
    CHECK(build("c", "bad.hlod", "--city-levels maybe") == 2);
    /* every box holds its descendants' (simplified nodes lose parts: a
     * box of their own content alone let 187 of the small city's 333
     * children stick out, by up to 1.42 m) */
    const char *const stores[] = {"cut.hlod", "metis.hlod", "flat.hlod"};
    for (int k = 0; k < 3; k++) {
        double worst;
        snprintf(p, sizeof p, "%s/%s", tmp, stores[k]);
        int bad = boxes_outside(p, &worst);
        CHECKF(bad == 0, "%s: %d children's boxes outside their parent's, by up to %.3g", stores[k],
               bad, worst);
    }
}

static void json_keys(void)
{
    char out[2048];
    snprintf(out, sizeof out, "%s/json.txt", tmp);
    CHECK(check_sh("cd '%s' && '%s/hlod-build' c.obj -o j.hlod --desired-tris 500 --quiet --json > json.txt", tmp, bin) ==
          0);
    FILE *fp = fopen(out, "r");
    char line[4096] = {0};
    CHECK(fp && fgets(line, sizeof line, fp));
    if (fp)
        fclose(fp);
    const char *keys[] = {"\"blocks\"", "\"nodes\"", "\"levels\"", "\"tris_in\"", "\"tris_leaf\"",
                          "\"tris_total\"", "\"bytes\"", "\"seconds\"", "\"peak_rss_bytes\"",
                          "\"groups\"", "\"block_depth\""};
    for (size_t i = 0; i < sizeof keys / sizeof *keys; i++)
        CHECKF(strstr(line, keys[i]), "missing %s in %s", keys[i], line);
}

/* The same store on 1 or 2 threads, and from the tool as from the
 * library; the report agrees with the store. */
static void reproducible_byte_for_byte(void)
{
    hlod_build_report r1, r2, m1, m2;
    CHECK(lib_build("c", "r1.hlod", HLOD_BUILD_CUTPLANE, 2, &r1, NULL) == HLOD_OK);
    CHECK(lib_build("c", "r2.hlod", HLOD_BUILD_CUTPLANE, 1, &r2, NULL) == HLOD_OK);
    CHECK(lib_build("c", "m1.hlod", HLOD_BUILD_METIS, 2, &m1, NULL) == HLOD_OK);
    CHECK(lib_build("c", "m2.hlod", HLOD_BUILD_METIS, 1, &m2, NULL) == HLOD_OK);
    CHECK(build("c", "rt.hlod", "--threads 2") == 0);
    CHECK(build("c", "mt.hlod", "--method metis --threads 1") == 0);
    const char *pairs[][2] = {{"r1", "r2"}, {"m1", "m2"}, {"r1", "rt"}, {"m1", "mt"}};
    for (int i = 0; i < 4; i++) {
        char a[2048], b[2048];
        snprintf(a, sizeof a, "%s/%s.hlod", tmp, pairs[i][0]);
        snprintf(b, sizeof b, "%s/%s.hlod", tmp, pairs[i][1]);
        CHECKF(same_file(a, b), "%s.hlod differs from %s.hlod", pairs[i][0], pairs[i][1]);
    }
    char p[2048];
    snprintf(p, sizeof p, "%s/r1.hlod", tmp);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(p, NULL, &s) == HLOD_OK);
    if (s) {
        CHECKF(r1.nodes == hlod_store_node_count(s), "%zu vs %u nodes", r1.nodes,
               hlod_store_node_count(s));
        CHECKF(r1.blocks == hlod_store_block_count(s), "%zu blocks, %u in the store", r1.blocks,
               hlod_store_block_count(s));
        CHECKF(r1.groups == hlod_store_first_block(s) && r1.block_depth == hlod_store_get_header(s)->block_depth,
               "%zu groups, block depth %zu", r1.groups, r1.block_depth);
        CHECKF(r1.levels == hlod_store_get_header(s)->depth_count, "%zu levels", r1.levels);
        hlod_store_close(s);
    }
    /* cutplane leaves hold exactly the source triangles */
    CHECKF(r1.tris_leaf == r1.tris_in && r1.tris_total > r1.tris_in, "%zu leaf, %zu in, %zu total",
           r1.tris_leaf, r1.tris_in, r1.tris_total);
    CHECK(r1.nodes == r2.nodes && m1.nodes == m2.nodes && m1.tris_in == r1.tris_in);
}

/* Triangles of the leaves under node i (itself when a leaf). */
static uint64_t leaf_tris(const hlod_store_node *n, uint32_t i)
{
    uint32_t c0 = hlod_store_first_child(n, i), c1 = hlod_store_child_end(n, i);
    if (c0 == c1)
        return n[i].tri_count;
    uint64_t s = 0;
    for (uint32_t c = c0; c < c1; c++)
        s += leaf_tris(n, c);
    return s;
}

/* A BIM-like city (separate boxes, non-manifold where they touch): every
 * block's hlod_0 holds at most 1.1 x C_desiredTri, and the leaves hold
 * exactly the input's triangles. */
static void parts_city_meets_desired_tris(void)
{
    CHECK(check_sh("'%s/hlod-gen-city' --preset tiny --blocks 3 --tris-per-block 4000 --style parts "
                   "--quiet -o '%s/parts.obj'", bin, tmp) == 0);
    for (int metis = 0; metis < 2; metis++) {
        hlod_build_report rep;
        const char *out = metis ? "parts-m.hlod" : "parts-c.hlod";
        CHECK(lib_build("parts", out, metis ? HLOD_BUILD_METIS : HLOD_BUILD_CUTPLANE, 2, &rep, NULL) ==
              HLOD_OK);
        CHECKF(rep.tris_leaf == rep.tris_in, "%s: %zu leaf triangles of %zu", out, rep.tris_leaf,
               rep.tris_in);
        char p[2048];
        snprintf(p, sizeof p, "%s/%s", tmp, out);
        hlod_store *s = NULL;
        CHECK(hlod_store_open(p, NULL, &s) == HLOD_OK);
        if (!s)
            continue;
        const hlod_store_node *n = hlod_store_nodes(s);
        /* cutplane: C_desiredTri (500 here); metis: N_n (2000), or the
         * block itself when it is one leaf (under N_l) */
        uint32_t cap = metis ? 2200 : 550;
        /* and at least half the target, or all of the block's leaves
         * where they hold fewer (a block is not simplified below its
         * target for nothing) */
        uint32_t floor_tris = metis ? 1000 : 250;
        for (uint32_t r = hlod_store_first_block(s); r < hlod_store_top_count(s); r++) {
            uint64_t leaves = leaf_tris(n, r);
            uint64_t lo = leaves < floor_tris ? leaves : floor_tris;
            CHECKF((n[r].tri_count <= cap ||
                    (metis && hlod_store_first_child(n, r) == hlod_store_child_end(n, r))) &&
                       n[r].tri_count >= lo,
                   "%s: block %u's hlod_0 holds %u triangles (%llu to %u; its leaves %llu)", out,
                   r, n[r].tri_count, (unsigned long long)lo, cap, (unsigned long long)leaves);
        }
        /* the group nodes above them too, and one root */
        CHECK(hlod_store_root_count(s) == 1 && hlod_store_first_block(s) >= 1);
        for (uint32_t g = 0; g < hlod_store_first_block(s); g++) {
            uint64_t leaves = leaf_tris(n, g);
            uint64_t lo = leaves < floor_tris ? leaves : floor_tris;
            CHECKF(n[g].tri_count <= cap && n[g].tri_count >= lo,
                   "%s: group %u holds %u triangles (%llu to %u)", out, g, n[g].tri_count,
                   (unsigned long long)lo, cap);
        }
        hlod_store_close(s);
    }
}

/* The library's errors: named in the log, nothing written, an old store kept. */
static void library_errors_leave_nothing(void)
{
    rec_log log;
    hlod_build_report rep;
    memset(&rep, 1, sizeof rep);
    CHECK(lib_build("missing", "lib-bad.hlod", HLOD_BUILD_CUTPLANE, 1, &rep, &log) == HLOD_ERR_IO);
    CHECKF(strstr(log.last, "missing.obj") && strstr(log.last, "cannot read"), "%s", log.last);
    CHECK(rep.nodes == 0 && rep.blocks == 0);
    char p[2048];
    snprintf(p, sizeof p, "%s/lib-bad.hlod", tmp);
    CHECK(file_size(p) < 0);
    CHECK(lib_build("c", "no/such/dir/x.hlod", HLOD_BUILD_CUTPLANE, 1, NULL, &log) == HLOD_ERR_IO);
    CHECKF(strstr(log.last, "does not exist"), "%s", log.last);
    snprintf(p, sizeof p, "%s/r1.hlod", tmp);
    long before = file_size(p);
    CHECK(lib_build("missing", "r1.hlod", HLOD_BUILD_METIS, 2, NULL, &log) == HLOD_ERR_IO);
    CHECK(before > 0 && file_size(p) == before);
    hlod_build_desc d;
    hlod_build_desc_defaults(&d);
    CHECK(hlod_build_store(&d, NULL, 0, p, NULL, NULL) == HLOD_ERR_INVALID_ARG);
    /* descriptor values out of the flags' ranges are refused, naming them */
    char in[2048], out[2048];
    snprintf(in, sizeof in, "%s/c.obj", tmp);
    snprintf(out, sizeof out, "%s/lib-desc.hlod", tmp);
    const char *inputs[] = {in};
    for (int i = 0; i < 4; i++) {
        hlod_build_desc_defaults(&d);
        const char *what[] = {"c_tex", "grid", "level_factor", "method"};
        if (i == 0)
            d.c_tex = 1.5;
        else if (i == 1)
            d.grid = NAN;
        else if (i == 2)
            d.level_factor = 2.5;
        else
            d.method = (hlod_build_method)7;
        hlod_logger lg = rec_logger(&log);
        CHECKF(hlod_build_store(&d, inputs, 1, out, &lg, NULL) == HLOD_ERR_INVALID_ARG &&
                   strstr(log.last, what[i]),
               "%s: %s", what[i], log.last);
        CHECK(file_size(out) < 0);
    }
}

/* The same city at (5e5, 4.1e6, 0): same tree, node boxes shifted by the
 * offset, the same relative payload positions. */
static void large_coordinates(void)
{
    city("far", "--origin 500000 4100000 0");
    CHECK(lib_build("c", "near.hlod", HLOD_BUILD_CUTPLANE, 0, NULL, NULL) == HLOD_OK);
    CHECK(lib_build("far", "far.hlod", HLOD_BUILD_CUTPLANE, 0, NULL, NULL) == HLOD_OK);
    char a[2048], b[2048];
    snprintf(a, sizeof a, "%s/near.hlod", tmp);
    snprintf(b, sizeof b, "%s/far.hlod", tmp);
    hlod_store *sa = NULL, *sb = NULL;
    CHECK(hlod_store_open(a, NULL, &sa) == HLOD_OK);
    CHECK(hlod_store_open(b, NULL, &sb) == HLOD_OK);
    if (!sa || !sb) {
        hlod_store_close(sa);
        hlod_store_close(sb);
        return;
    }
    uint32_t n = hlod_store_node_count(sa);
    CHECKF(n == hlod_store_node_count(sb), "%u vs %u nodes", n, hlod_store_node_count(sb));
    const hlod_store_node *na = hlod_store_nodes(sa), *nb = hlod_store_nodes(sb);
    const double off[3] = {5e5, 4.1e6, 0};
    size_t bad_box = 0, bad_count = 0, bad_pos = 0;
    double worst = 0;
    for (uint32_t i = 0; i < n && n == hlod_store_node_count(sb); i++) {
        bad_count += na[i].tri_count != nb[i].tri_count || na[i].vertex_count != nb[i].vertex_count ||
                     na[i].first_child != nb[i].first_child;
        for (int k = 0; k < 3; k++)
            bad_box += fabs(na[i].bbox_min[k] + off[k] - nb[i].bbox_min[k]) > 1e-6 ||
                       fabs(na[i].bbox_max[k] + off[k] - nb[i].bbox_max[k]) > 1e-6;
        hlod_store_payload pa, pb;
        hlod_result ra = hlod_store_read_node(sa, i, 65536, &pa);
        CHECKF(ra == HLOD_OK, "node %u of the store at the origin: %s", i, hlod_result_str(ra));
        if (ra == HLOD_OK) {
            hlod_result rb = hlod_store_read_node(sb, i, 65536, &pb);
            CHECKF(rb == HLOD_OK, "node %u of the offset store: %s", i, hlod_result_str(rb));
            if (rb == HLOD_OK) {
                bad_count += pa.vertex_count != pb.vertex_count;
                if (pa.vertex_count == pb.vertex_count)
                    for (size_t v = 0; v < 3 * (size_t)pa.vertex_count; v++) {
                        /* absolute positions agree to a millimetre */
                        double xa = pa.positions[v] + na[i].origin[v % 3] + off[v % 3];
                        double xb = pb.positions[v] + nb[i].origin[v % 3];
                        double d = fabs(xa - xb);
                        worst = d > worst ? d : worst;
                        bad_pos += d > 1e-3;
                    }
                hlod_store_payload_free(&pb);
            }
            hlod_store_payload_free(&pa);
        }
    }
    CHECKF(bad_count == 0, "%zu nodes differ in counts or shape", bad_count);
    CHECKF(bad_box == 0, "%zu box coordinates differ by more than 1e-6 m", bad_box);
    CHECKF(bad_pos == 0, "%zu positions differ by more than 1 mm (worst %g m)", bad_pos, worst);
    hlod_store_close(sa);
    hlod_store_close(sb);
}

static void bad_input_leaves_nothing(void)
{
    char out[2048];
    snprintf(out, sizeof out, "%s/bad.hlod", tmp);
    CHECK(check_sh("'%s/hlod-build' '%s/missing.obj' -o '%s' --quiet 2> /dev/null", bin, tmp, out) == 1);
    CHECK(file_size(out) < 0);
    CHECK(check_sh("'%s/hlod-build' '%s/c.obj' -o '%s' --method bogus 2> /dev/null", bin, tmp, out) == 2);
    CHECK(check_sh("'%s/hlod-build' '%s/c.obj' -o '%s' --level-factor 1 2> /dev/null", bin, tmp, out) == 2);
    CHECK(check_sh("'%s/hlod-build' '%s/c.obj' 2> /dev/null", bin, tmp) == 2);
    CHECK(file_size(out) < 0);
    /* a coordinate no store can hold: refused naming the input and vertex */
    char off[2048], err[2048];
    snprintf(off, sizeof off, "%s/in.off", tmp);
    snprintf(err, sizeof err, "%s/in.err", tmp);
    FILE *fp = fopen(off, "w");
    CHECK(fp != NULL);
    if (fp) {
        fprintf(fp, "OFF\n4 2 0\n0 0 0\n1 0 0\n1e39 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n");
        fclose(fp);
    }
    CHECK(check_sh("'%s/hlod-build' '%s' -o '%s' --quiet 2> '%s'", bin, off, out, err) == 1);
    CHECK(file_size(out) < 0);
    CHECK(check_sh("grep -q \"in.off: vertex 2: coordinate x = 1e+39\" '%s'", err) == 0);
    /* an existing store survives a failed build */
    char good[2048];
    snprintf(good, sizeof good, "%s/cut.hlod", tmp);
    long before = file_size(good);
    CHECK(check_sh("'%s/hlod-build' '%s/missing.obj' -o '%s' --quiet 2> /dev/null", bin, tmp, good) == 1);
    CHECK(file_size(good) == before);
    CHECK(check_sh("'%s/hlod-info' --verify '%s' > /dev/null", bin, good) == 0);
}

/* One object of two untextured materials, a red quad and a green one:
 * each keeps its colour (a block per colour), not the first material's. */
static void untextured_colours_kept(void)
{
    char obj[1200], mtl[1200], out[1200];
    snprintf(obj, sizeof obj, "%s/two.obj", tmp);
    snprintf(mtl, sizeof mtl, "%s/two.mtl", tmp);
    snprintf(out, sizeof out, "%s/two.hlod", tmp);
    FILE *fp = fopen(mtl, "w");
    CHECK(fp != NULL);
    if (!fp)
        return;
    fprintf(fp, "newmtl red\nKd 0.9 0.1 0.1\nnewmtl green\nKd 0.1 0.9 0.1\n");
    fclose(fp);
    fp = fopen(obj, "w");
    CHECK(fp != NULL);
    if (!fp)
        return;
    fprintf(fp, "mtllib two.mtl\no both\n"
                "v 0 0 0\nv 10 0 0\nv 10 10 0\nv 0 10 0\n"
                "v 20 0 0\nv 30 0 0\nv 30 10 0\nv 20 10 0\n"
                "usemtl red\nf 1 2 3\nf 1 3 4\nusemtl green\nf 5 6 7\nf 5 7 8\n");
    fclose(fp);
    CHECK(check_sh("'%s/hlod-build' '%s' -o '%s' --quiet", bin, obj, out) == 0);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(out, NULL, &s) == HLOD_OK);
    int red = 0, green = 0;
    for (uint32_t i = 0; s && i < hlod_store_node_count(s); i++) {
        hlod_store_payload p;
        if (hlod_store_read_node(s, i, 1 << 20, &p) != HLOD_OK)
            continue;
        for (uint32_t v = 0; p.colors && v < p.vertex_count; v++) {
            const uint8_t *c = p.colors + 4 * v;
            red |= c[0] > 200 && c[1] < 60;
            green |= c[1] > 200 && c[0] < 60;
        }
        hlod_store_payload_free(&p);
    }
    CHECKF(red && green, "colours kept: red %d, green %d", red, green);
    hlod_store_close(s);
}

int main(void)
{
    const char *b = getenv("HLOD_BIN_DIR");
    snprintf(bin, sizeof bin, "%s", b ? b : "build/bin");
    snprintf(tmp, sizeof tmp, "/tmp/hlod-test-build-%ld", (long)getpid());
    check_sh("rm -rf '%s' && mkdir -p '%s'", tmp, tmp);
    RUN(builds_and_verifies_both_methods);
    RUN(json_keys);
    RUN(reproducible_byte_for_byte);
    RUN(library_errors_leave_nothing);
    RUN(parts_city_meets_desired_tris);
    RUN(large_coordinates);
    RUN(bad_input_leaves_nothing);
    RUN(untextured_colours_kept);
    check_sh("rm -rf '%s'", tmp);
    return check_done();
}
