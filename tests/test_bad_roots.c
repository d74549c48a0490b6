/*
 * test_bad_roots.c - top nodes that cannot be read do not stop the city
 * (issue 18, item 4; docs/runtime.md: residency).
 *
 * A top node (a group, or a block's hlod_0) whose payload is corrupt on
 * disk, or whose first read fails with an I/O error, used to make
 * hlod_engine_create fail.  Now the engine starts, the node is marked bad
 * (checksum: for good) or retried after the usual backoff (I/O), and the
 * traversal draws its readable children in its place, recursively; where
 * nothing below is readable nothing is drawn.  Each test runs a threaded
 * engine with no renderer on a synthetic machine and a target so small
 * that no node is refined by choice: every node drawn below a top node is
 * there only because it stands in for one.  Checked: the engine starts,
 * the exact set drawn (the selection's draw list), no bad node drawn or
 * charged (cost_drawn is the drawn nodes' cost), bad_nodes and
 * load_failures, one log line per bad node, no render wait (in frames that
 * kept the CPU: tests/cpu_span.h), no toggles once settled.
 *
 * Fixtures (tests/store_fixture.h): 4 blocks in a row, 2 levels below each
 * hlod_0 (84 nodes); with a group root above them, 85 (node 0 the group,
 * 1-4 the blocks' hlod_0 nodes).
 */
#define _GNU_SOURCE /* RUSAGE_THREAD (cpu_span.h) */
#include "check.h"
#include "inspect.h"
#include "engine_check.h"
#include "store_fixture.h"

#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdatomic.h>
#include <unistd.h>

#define MAXN 128
#define FRAMES 60
#define SETTLED 30 /* frames from this one on: the stand-ins are loaded (each
                      frame waits for the loader to finish its list) */

static char g_dir[256];

/* ---- logger: "unreadable" lines per node (the loader thread logs too) ---- */

typedef struct logrec {
    pthread_mutex_t mu;
    int unreadable[MAXN];
} logrec;

static void log_count(void *user, hlod_log_level level, const char *msg)
{
    logrec *l = user;
    const char *q = strstr(msg, " node ");
    unsigned node;
    (void)level;
    if (!q || sscanf(q, " node %u", &node) != 1 || node >= MAXN || !strstr(msg, "unreadable"))
        return;
    pthread_mutex_lock(&l->mu);
    l->unreadable[node]++;
    pthread_mutex_unlock(&l->mu);
}

/* ---- stores ---- */

/* The fixture (its roots are the blocks), or with group set the same
 * blocks under a group root: one node over the whole row (a square as wide
 * as the row, error above the blocks'), block HLOD_STORE_NO_BLOCK. */
static void write_city(const char *path, int group)
{
    fixture_opts o = {0};
    o.roots = 4;
    o.depth = 2;
    o.grid = 4;
    o.size = 100;
    if (!group) {
        CHECK(fixture_write(path, &o, NULL) == HLOD_OK);
        return;
    }
    hlod_store_writer_desc wd;
    memset(&wd, 0, sizeof wd);
    wd.build.c_tex = 0.5;
    fixture_build b;
    memset(&b, 0, sizeof b);
    CHECK(hlod_store_writer_open(path, &wd, &b.w) == HLOD_OK);
    uint32_t top;
    fixture_opts flat = o;
    flat.depth = 0;
    b.o = &flat; /* no children of its own making */
    top = fixture_node(&b, 0, 0, 4 * 110 - 10, 0, HLOD_STORE_NO_PARENT);
    b.nodes[top].block = HLOD_STORE_NO_BLOCK;
    b.o = &o;
    for (uint32_t k = 0; k < o.roots; k++)
        fixture_node(&b, k * 110.0, 0, o.size, 0, top); /* blocks numbered by the writer */
    CHECK(b.err == HLOD_OK);
    CHECK(hlod_store_writer_finish(b.w, b.nodes, b.count, NULL) == HLOD_OK);
    free(b.nodes);
}

static uint32_t child(const hlod_store_node *n, uint32_t p, uint32_t k)
{
    CHECK(n[p].first_child + k < n[p + 1].first_child);
    return n[p].first_child + k;
}

/* Writes the city to name, flips one byte in the middle of each listed
 * node's payload (the node table and its checksum stay valid: the store
 * opens, the payload checksum fails when the node is read), opens it. */
static hlod_store *corrupt_city(const char *name, int group, const uint32_t *bad, int nbad)
{
    char path[512];
    snprintf(path, sizeof path, "%s/%s", g_dir, name);
    write_city(path, group);
    hlod_store *s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK);
    if (!s)
        return NULL;
    int fd = open(path, O_RDWR);
    CHECK(fd >= 0);
    for (int k = 0; k < nbad && fd >= 0; k++) {
        const hlod_store_node *n = &hlod_store_nodes(s)[bad[k]];
        off_t at = (off_t)(n->payload_offset + n->payload_size / 2);
        uint8_t c = 0;
        CHECK(pread(fd, &c, 1, at) == 1);
        c ^= 0x5a;
        CHECK(pwrite(fd, &c, 1, at) == 1);
    }
    if (fd >= 0)
        close(fd);
    hlod_store_close(s);
    s = NULL;
    CHECK(hlod_store_open(path, NULL, &s) == HLOD_OK); /* header and table are intact */
    CHECK(!s || hlod_store_node_count(s) <= MAXN);
    return s;
}

/* ---- engine runs ---- */

static fixed_machine g_machine = {0.5, 1e-6};

/* Nothing is refined by choice: the budget floor (a tenth of the target)
 * is below any node's timeNeeded. */
static double g_target_ms = 1e-3;   /* tiny: nothing refines unless it stands in */

static hlod_result start(hlod_store *s, logrec *lg, hlod_engine **e)
{
    hlod_engine_desc d = {0};
    d.target_ms = g_target_ms;
    d.time_model = fixed_machine_time;
    d.time_model_user = &g_machine;
    d.logger.func = log_count;
    d.logger.user_data = lg;
    *e = NULL;
    return hlod_engine_create(s, &d, e);
}

static void whole_city(hlod_camera *cam)
{
    double eye[3] = {215, -180, 260}, at[3] = {215, 50, 0}, up[3] = {0, 0, 1};
    CHECK(hlod_camera_look_at(cam, eye, at, up, 60, 0.5, 1e5, 1280, 720) == HLOD_OK);
}

typedef struct tally {
    uint64_t load_failures, toggles_settled, oscillations;
    uint32_t bad_nodes, render_waits;
    int bad_drawn, miscounted; /* frames drawing a bad node; frames whose totals
                                  are not the draw list's */
    int stalled;               /* frames after which the loader was not done in 10 s */
} tally;

/* One frame; the stats are checked against the draw list. */
static void frame(hlod_engine *e, const hlod_camera *cam, int f, tally *t)
{
    hlod_frame_stats st;
    hlod_result r = hlod_engine_frame(e, cam, 1.0 / 30, &st);
    CHECK(r == HLOD_OK);
    t->render_waits += st.render_waits; /* the engine's count of the thread's sleeps */
    t->load_failures += st.load_failures;
    t->bad_nodes = st.bad_nodes;
    t->oscillations += st.oscillations;
    if (f >= SETTLED)
        t->toggles_settled += st.toggles_up + st.toggles_down;
    double cost = 0;
    uint64_t tris = 0;
    int bad = 0;
    size_t ns;
    const uint32_t *sel = hlod_inspect_selected(e, &ns);
    const hlod_store_node *nodes = hlod_store_nodes(hlod_inspect_store(e));
    for (size_t k = 0; k < ns; k++) {
        uint32_t i = sel[k];
        bad |= hlod_engine_node_state(e, i) != HLOD_NODE_RESIDENT;
        cost += nodes[i].cost;
        tris += nodes[i].tri_count;
    }
    t->bad_drawn += bad;
    t->miscounted += st.nodes_drawn != ns || st.tris_drawn != tris ||
                     fabs(st.cost_drawn - cost) > 1e-9 * (1 + cost);
    /* the gate: the next frame starts once the loader has read all it was
     * given (10 s at most), so by frame SETTLED the stand-ins are read on
     * any machine */
    double t0 = now_ms();
    while (!hlod_inspect_loader_idle(e) && now_ms() - t0 < 10000)
        sleep_us(200);
    t->stalled += !hlod_inspect_loader_idle(e);
}

/* The number of nodes the last frame selected. */
static size_t n_selected(const hlod_engine *e)
{
    size_t n;
    (void)hlod_inspect_selected(e, &n);
    return n;
}

/* The draw list is exactly want[0..n) (in any order); when not, says so
 * under what's name (unless what is NULL). */
static int draws_exactly(const hlod_engine *e, const uint32_t *want, int n, const char *what)
{
    size_t ns;
    const uint32_t *sel = hlod_inspect_selected(e, &ns);
    int ok = (int)ns == n;
    for (int k = 0; k < n; k++)
        ok &= hlod_engine_node_drawn(e, want[k]);
    if (!ok && what) {
        fprintf(stderr, "%s: drawn:", what);
        for (size_t k = 0; k < ns; k++)
            fprintf(stderr, " %u", sel[k]);
        fprintf(stderr, "; want:");
        for (int k = 0; k < n; k++)
            fprintf(stderr, " %d", (int)want[k]);
        fputc('\n', stderr);
    }
    return ok;
}

static void check_run(const char *what, const tally *t, uint32_t nbad)
{
    CHECKF(t->bad_nodes == nbad && t->load_failures == nbad,
           "%s: bad_nodes %u, load_failures %llu, want %u (read once each)", what, t->bad_nodes,
           (unsigned long long)t->load_failures, nbad);
    CHECKF(t->bad_drawn == 0, "%s: %d frames drew a node that is not resident", what, t->bad_drawn);
    CHECKF(t->miscounted == 0, "%s: %d frames' drawn totals are not their draw list's", what,
           t->miscounted);
    CHECKF(t->stalled == 0, "%s: the loader was not done within 10 s after %d frames", what,
           t->stalled);
    if (span_judges_waits())
        CHECKF(t->render_waits == 0, "%s: the render thread slept %u times", what,
               t->render_waits);
    CHECKF(t->toggles_settled == 0 && t->oscillations == 0,
           "%s: %llu toggles after frame %d, %llu oscillations", what,
           (unsigned long long)t->toggles_settled, SETTLED, (unsigned long long)t->oscillations);
}

/* Runs FRAMES frames of a still camera over a corrupted city; the last
 * frame must draw exactly want.  Returns the engine's final tally. */
static void run_corrupt(const char *name, int group, const uint32_t *bad, int nbad,
                        const uint32_t *want, int nwant)
{
    logrec *lg = calloc(1, sizeof *lg);
    pthread_mutex_init(&lg->mu, NULL);
    hlod_store *s = corrupt_city(name, group, bad, nbad);
    hlod_engine *e = NULL;
    hlod_result r = s ? start(s, lg, &e) : HLOD_ERR_IO;
    CHECKF(r == HLOD_OK && e, "%s: the engine does not start: %s", name, hlod_result_str(r));
    if (e) {
        hlod_camera cam;
        whole_city(&cam);
        tally t = {0};
        for (int f = 0; f < FRAMES; f++)
            frame(e, &cam, f, &t);
        CHECK(draws_exactly(e, want, nwant, name));
        for (int k = 0; k < nbad; k++) {
            CHECKF(hlod_engine_node_state(e, bad[k]) == HLOD_NODE_BAD, "%s: node %u state %d",
                   name, bad[k], hlod_engine_node_state(e, bad[k]));
            pthread_mutex_lock(&lg->mu);
            CHECKF(lg->unreadable[bad[k]] == 1, "%s: node %u logged %d times", name, bad[k],
                   lg->unreadable[bad[k]]);
            pthread_mutex_unlock(&lg->mu);
        }
        check_run(name, &t, (uint32_t)nbad);
        printf("REPORT bad_roots store=%s bad=%u drawn=%zu frames=%d render_waits=%u\n", name,
               t.bad_nodes, n_selected(e), FRAMES, t.render_waits);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
    pthread_mutex_destroy(&lg->mu);
    free(lg);
}

/* Block 1's hlod_0 (node 1) is corrupt: its four children stand in, the
 * other blocks draw their hlod_0. */
static void bad_hlod0(void)
{
    hlod_store *s = corrupt_city("plain.hlod", 0, NULL, 0);
    if (!s)
        return;
    const hlod_store_node *n = hlod_store_nodes(s);
    uint32_t bad[1] = {1};
    uint32_t want[7] = {0, 2, 3, child(n, 1, 0), child(n, 1, 1), child(n, 1, 2), child(n, 1, 3)};
    hlod_store_close(s);
    run_corrupt("hlod0.hlod", 0, bad, 1, want, 7);
}

/* Recursively: node 1, its first child c and c's first child g (a leaf)
 * are corrupt.  c's three readable children stand in for c, c's siblings
 * for node 1; under g nothing is readable, so nothing is drawn there. */
static void bad_chain(void)
{
    hlod_store *s = corrupt_city("plain2.hlod", 0, NULL, 0);
    if (!s)
        return;
    const hlod_store_node *n = hlod_store_nodes(s);
    uint32_t c = child(n, 1, 0), g = child(n, c, 0);
    uint32_t bad[3] = {1, c, g};
    uint32_t want[9] = {0, 2, 3, child(n, 1, 1), child(n, 1, 2), child(n, 1, 3),
                        child(n, c, 1), child(n, c, 2), child(n, c, 3)};
    hlod_store_close(s);
    run_corrupt("chain.hlod", 0, bad, 3, want, 9);
}

/* The city's group root is corrupt: the four hlod_0 nodes stand in (with
 * a readable root the coarsest frame is the root alone). */
static void bad_group_root(void)
{
    uint32_t bad[1] = {0}, want[4] = {1, 2, 3, 4};
    run_corrupt("group.hlod", 1, bad, 1, want, 4);
}

/* The group root and block 2's hlod_0: blocks 1, 3 and 4 stand in for the
 * root, block 2's children for its hlod_0. */
static void bad_group_and_block(void)
{
    hlod_store *s = corrupt_city("group2-plain.hlod", 1, NULL, 0);
    if (!s)
        return;
    const hlod_store_node *n = hlod_store_nodes(s);
    uint32_t bad[2] = {0, 2};
    uint32_t want[7] = {1, 3, 4, child(n, 2, 0), child(n, 2, 1), child(n, 2, 2), child(n, 2, 3)};
    hlod_store_close(s);
    run_corrupt("group2.hlod", 1, bad, 2, want, 7);
}

/* A readable group root over a corrupt hlod_0 (node 2), with time to spare:
 * the root refines (node 2's children stand in for it, the other blocks
 * are drawn), where before one bad child pinned the whole group at the
 * root forever. */
static void readable_group_bad_block(void)
{
    logrec *lg = calloc(1, sizeof *lg);
    pthread_mutex_init(&lg->mu, NULL);
    uint32_t bad[1] = {2};
    hlod_store *s = corrupt_city("group3.hlod", 1, bad, 1);
    hlod_engine *e = NULL;
    g_target_ms = 1e4;
    hlod_result r = s ? start(s, lg, &e) : HLOD_ERR_IO;
    g_target_ms = 1e-3;
    CHECKF(r == HLOD_OK && e, "the engine does not start: %s", hlod_result_str(r));
    if (e) {
        hlod_camera cam;
        whole_city(&cam);
        tally t = {0};
        for (int f = 0; f < FRAMES; f++)
            frame(e, &cam, f, &t);
        const hlod_store_node *n = hlod_store_nodes(s);
        int under2 = 0;   /* drawn nodes in block 2's subtree */
        size_t ns;
        const uint32_t *sel = hlod_inspect_selected(e, &ns);
        for (size_t k = 0; k < ns; k++)
            under2 += n[sel[k]].block == n[2].block;
        CHECKF(!hlod_engine_node_drawn(e, 0) && !hlod_engine_node_drawn(e, 2) && under2 > 0,
               "root drawn %d, bad node 2 drawn %d, %d nodes of block 2 drawn (of %zu)",
               hlod_engine_node_drawn(e, 0), hlod_engine_node_drawn(e, 2), under2, ns);
        CHECK(hlod_engine_node_state(e, 2) == HLOD_NODE_BAD && t.bad_drawn == 0 &&
              t.miscounted == 0);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
    pthread_mutex_destroy(&lg->mu);
    free(lg);
}

/* ---- a transient failure ---- */

/* A disk whose reads touching [lo, hi) fail with EIO while fails > 0. */
typedef struct flaky {
    uint64_t lo, hi;
    atomic_int fails, eios;
} flaky;

static ssize_t flaky_pread(void *user, int fd, void *buf, size_t n, off_t off)
{
    flaky *d = user;
    if ((uint64_t)off < d->hi && (uint64_t)off + n > d->lo && atomic_load(&d->fails) > 0) {
        atomic_fetch_sub(&d->fails, 1);
        atomic_fetch_add(&d->eios, 1);
        errno = EIO;
        return -1;
    }
    return pread(fd, buf, n, off);
}

/* Node 1's read at start fails with EIO: the engine starts, node 1's
 * children stand in while it is missing, it is read again after the
 * backoff (16 frames) and then drawn itself; it never turns bad. */
static void transient_top(void)
{
    logrec *lg = calloc(1, sizeof *lg);
    pthread_mutex_init(&lg->mu, NULL);
    hlod_store *s = corrupt_city("flaky.hlod", 0, NULL, 0);
    if (!s) {
        free(lg);
        return;
    }
    const hlod_store_node *n = hlod_store_nodes(s);
    flaky d = {n[1].payload_offset, n[1].payload_offset + n[1].payload_size, 1, 0};
    hlod_store_set_pread(s, flaky_pread, &d);
    hlod_engine *e = NULL;
    hlod_result r = start(s, lg, &e);
    CHECKF(r == HLOD_OK && e, "the engine does not start: %s", hlod_result_str(r));
    if (e) {
        hlod_camera cam;
        whole_city(&cam);
        tally t = {0};
        int back = -1, stood_in = 0;
        uint32_t kids[7] = {0, 2, 3, child(n, 1, 0), child(n, 1, 1), child(n, 1, 2),
                            child(n, 1, 3)};
        for (int f = 0; f < 2 * FRAMES; f++) {
            frame(e, &cam, f, &t);
            if (back < 0 && hlod_engine_node_state(e, 1) == HLOD_NODE_RESIDENT)
                back = f;
            stood_in += back < 0 && draws_exactly(e, kids, 7, NULL);
        }
        CHECKF(atomic_load(&d.eios) == 1, "%d reads failed", atomic_load(&d.eios));
        CHECKF(back >= 15, "node 1 resident again at frame %d (the backoff is 16 frames)", back);
        CHECKF(stood_in >= 5, "node 1's children stood in for it in %d frames", stood_in);
        uint32_t all[4] = {0, 1, 2, 3};
        CHECK(draws_exactly(e, all, 4, "transient"));
        CHECKF(t.bad_nodes == 0 && t.load_failures == 1, "bad_nodes %u, load_failures %llu",
               t.bad_nodes, (unsigned long long)t.load_failures);
        CHECKF(t.bad_drawn == 0 && t.miscounted == 0, "%d frames drew a missing node, %d "
               "miscounted", t.bad_drawn, t.miscounted);
        if (span_judges_waits())
            CHECKF(t.render_waits == 0, "the render thread slept %u times", t.render_waits);
        printf("REPORT bad_roots store=flaky.hlod resident_again=%d stood_in=%d render_waits=%u\n",
               back, stood_in, t.render_waits);
        hlod_engine_destroy(e);
    }
    hlod_store_close(s);
    pthread_mutex_destroy(&lg->mu);
    free(lg);
}

int main(void)
{
    snprintf(g_dir, sizeof g_dir, "/tmp/hlod-test-bad-roots-XXXXXX");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        return 1;
    }
    alarm(300); /* a hang fails the test (SIGALRM) */
    RUN(bad_hlod0);
    RUN(bad_chain);
    RUN(bad_group_root);
    RUN(bad_group_and_block);
    RUN(readable_group_bad_block);
    RUN(transient_top);
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf '%s'", g_dir);
    if (system(cmd) != 0)
        fprintf(stderr, "could not remove %s\n", g_dir);
    return check_done();
}
