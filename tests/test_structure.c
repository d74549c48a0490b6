/*
 * test_structure.c - the source tree's shape (docs/testing.md): no include
 * cycle among the project's files, no call cycle between the libraries'
 * files, and no function over 150 lines in engine/ or preprocess/.  Reads
 * the tree under $HLOD_SOURCE_DIR and the object files under
 * $HLOD_BUILD_DIR.
 *
 * A call cycle is found from the object files' symbol tables (nm -P): file
 * A calls file B when A's object leaves a symbol undefined that B's
 * defines.  Files that call each other cannot be read, tested or moved one
 * at a time; a cycle means a function sits in the wrong file.
 */
#include "check.h"

#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>

#define MAX_FILES 1024
#define MAX_LINES 150

static const char *const dirs[] = {"include/hlod", "engine", "engine/common", "engine/tools",
                                   "preprocess", "preprocess/io", "preprocess/tools", "tests",
                                   "tests/bench", "tests/fuzz", NULL};
/* where a quoted include is looked up after the including file's folder */
static const char *const search[] = {"include", "engine", "engine/common", "preprocess",
                                     "preprocess/io", "tests", NULL};

static char *files[MAX_FILES];
static char *text[MAX_FILES];
static int nfiles;
static int edges[MAX_FILES][64], nedges[MAX_FILES];
static char root[1024];

static int source_name(const char *n)
{
    size_t l = strlen(n);
    return (l > 2 && (!strcmp(n + l - 2, ".c") || !strcmp(n + l - 2, ".h"))) ||
           (l > 4 && !strcmp(n + l - 4, ".cpp"));
}

static void collect(void)
{
    for (int d = 0; dirs[d]; d++) {
        char p[2048];
        snprintf(p, sizeof p, "%s/%s", root, dirs[d]);
        DIR *dir = opendir(p);
        CHECKF(dir, "%s: cannot list", p);
        struct dirent *e;
        while (dir && (e = readdir(dir)) && nfiles < MAX_FILES) {
            if (!source_name(e->d_name))
                continue;
            char rel[1024], full[3072];
            snprintf(rel, sizeof rel, "%s/%s", dirs[d], e->d_name);
            snprintf(full, sizeof full, "%s/%s", root, rel);
            files[nfiles] = strdup(rel);
            text[nfiles] = check_slurp(full, NULL);
            CHECKF(text[nfiles], "%s: cannot read", full);
            if (!text[nfiles])
                text[nfiles] = strdup("");
            nfiles++;
        }
        if (dir)
            closedir(dir);
    }
}

static int find(const char *rel)
{
    for (int i = 0; i < nfiles; i++)
        if (!strcmp(files[i], rel))
            return i;
    return -1;
}

/* "a/b/../c" -> "a/c", "./x" -> "x" */
static void normalise(char *p)
{
    char *parts[64], buf[2048];
    int n = 0;
    snprintf(buf, sizeof buf, "%s", p);
    for (char *t = strtok(buf, "/"); t && n < 64; t = strtok(NULL, "/")) {
        if (!strcmp(t, "."))
            continue;
        if (!strcmp(t, "..") && n > 0)
            n--;
        else
            parts[n++] = t;
    }
    p[0] = 0;
    for (int i = 0; i < n; i++) {
        strcat(p, parts[i]);
        if (i + 1 < n)
            strcat(p, "/");
    }
}

static int resolve(int from, const char *inc)
{
    char p[2048], dir[1024];
    snprintf(dir, sizeof dir, "%s", files[from]);
    char *slash = strrchr(dir, '/');
    *slash = 0;
    snprintf(p, sizeof p, "%s/%s", dir, inc);
    normalise(p);
    int k = find(p);
    for (int s = 0; k < 0 && search[s]; s++) {
        snprintf(p, sizeof p, "%s/%s", search[s], inc);
        normalise(p);
        k = find(p);
    }
    return k;
}

static void include_graph(void)
{
    for (int i = 0; i < nfiles; i++)
        for (const char *l = text[i]; (l = strstr(l, "#include \"")); l++) {
            char inc[512];
            const char *q = l + 10, *e = strchr(q, '"');
            if (!e || (size_t)(e - q) >= sizeof inc)
                continue;
            memcpy(inc, q, (size_t)(e - q));
            inc[e - q] = 0;
            int k = resolve(i, inc);
            if (k >= 0 && nedges[i] < 64)
                edges[i][nedges[i]++] = k;
        }
}

/* A directed graph over named vertices, for the cycle search. */
typedef struct graph {
    char **name;
    int n;
    int (*edge)[64];
    int *nedge;
    const char *what; /* "include" or "call", for the message */
} graph;

static int color[MAX_FILES], stack[MAX_FILES], depth;

/* Depth-first search from u; each back edge is a cycle, reported with
 * its path (when report) and counted. */
static int dfs(const graph *g, int u, int report)
{
    int found = 0;
    color[u] = 1;
    stack[depth++] = u;
    for (int j = 0; j < g->nedge[u]; j++) {
        int v = g->edge[u][j];
        if (color[v] == 1) {
            char path[4096] = "";
            for (int s = 0; s < depth; s++)
                if (stack[s] == v || path[0]) {
                    strncat(path, g->name[stack[s]], sizeof path - strlen(path) - 5);
                    strcat(path, " -> ");
                }
            strncat(path, g->name[v], sizeof path - strlen(path) - 1);
            if (report)
                CHECKF(0, "%s cycle: %s", g->what, path);
            found++;
        } else if (!color[v]) {
            found += dfs(g, v, report);
        }
    }
    depth--;
    color[u] = 2;
    return found;
}

/* The number of cycles the search finds in g. */
static int count_cycles(const graph *g, int report)
{
    memset(color, 0, sizeof color);
    depth = 0;
    int found = 0;
    for (int i = 0; i < g->n; i++)
        if (!color[i])
            found += dfs(g, i, report);
    return found;
}

static void no_include_cycle(void)
{
    graph g = {files, nfiles, edges, nedges, "include"};
    int cycles = count_cycles(&g, 1);
    size_t n = 0;
    for (int i = 0; i < nfiles; i++)
        n += (size_t)nedges[i];
    CHECKF(nfiles > 50 && n > 100, "only %d files and %zu includes found", nfiles, n);
    CHECK(cycles == 0);
}

/* ---- call cycles, from nm ---- */

/* The call graph of a set of object files: a vertex per object, named by
 * its source file; symbols defined (global, in any section) and used. */
typedef struct calls {
    char *name[MAX_FILES];
    int n;
    int edge[MAX_FILES][64], nedge[MAX_FILES];
    struct sym {
        char *name;
        int file, defined;
    } *sym;
    size_t nsym, cap;
} calls;

static void calls_free(calls *c)
{
    for (int i = 0; i < c->n; i++)
        free(c->name[i]);
    for (size_t i = 0; i < c->nsym; i++)
        free(c->sym[i].name);
    free(c->sym);
    memset(c, 0, sizeof *c);
}

/* Adds file `name`'s symbols from nm -P output (one "SYMBOL TYPE ..." a
 * line): U is a use, any other type but weak or local a definition. */
static void calls_add(calls *c, const char *name, const char *nm_text)
{
    if (c->n >= MAX_FILES)
        return;
    int f = c->n++;
    c->name[f] = strdup(name);
    c->nedge[f] = 0;
    for (const char *l = nm_text; *l;) {
        const char *e = strchr(l, '\n');
        size_t len = e ? (size_t)(e - l) : strlen(l);
        char sym[512], type = 0;
        if (len < sizeof sym && sscanf(l, "%511s %c", sym, &type) == 2 &&
            (type == 'U' || strchr("TDBRVWGS", type))) {
            if (c->nsym == c->cap) {
                c->cap = c->cap ? 2 * c->cap : 1024;
                c->sym = realloc(c->sym, c->cap * sizeof *c->sym);
            }
            c->sym[c->nsym++] = (struct sym){strdup(sym), f, type != 'U'};
        }
        l += len + (e != NULL);
    }
}

static int sym_cmp(const void *a, const void *b)
{
    const struct sym *x = a, *y = b;
    int d = strcmp(x->name, y->name);
    return d ? d : y->defined - x->defined; /* definitions first */
}

/* Edges: each use to the file that defines the symbol. */
static void calls_link(calls *c)
{
    qsort(c->sym, c->nsym, sizeof *c->sym, sym_cmp);
    for (size_t i = 0; i < c->nsym;) {
        size_t j = i;
        int def = c->sym[i].defined ? c->sym[i].file : -1;
        for (; j < c->nsym && !strcmp(c->sym[j].name, c->sym[i].name); j++) {
            int u = c->sym[j].file;
            if (c->sym[j].defined || def < 0 || u == def)
                continue;
            int k = 0;
            while (k < c->nedge[u] && c->edge[u][k] != def)
                k++;
            if (k == c->nedge[u] && k < 64)
                c->edge[u][c->nedge[u]++] = def;
        }
        i = j;
    }
}

static int calls_cycles(calls *c, int report)
{
    graph g = {c->name, c->n, c->edge, c->nedge, "call"};
    return count_cycles(&g, report);
}

/* Runs nm -P -g on an object file; the output, malloc'ed, or NULL. */
static char *nm_output(const char *obj)
{
    char cmd[8192];
    snprintf(cmd, sizeof cmd, "nm -P -g '%s' 2>/dev/null", obj);
    FILE *p = popen(cmd, "r");
    if (!p)
        return NULL;
    size_t n = 0, cap = 4096;
    char *s = malloc(cap);
    size_t r;
    while (s && (r = fread(s + n, 1, cap - n - 1, p)) > 0) {
        n += r;
        if (cap - n < 2048)
            s = realloc(s, cap *= 2);
    }
    int rc = pclose(p);
    if (s)
        s[n] = 0;
    if (rc != 0) {
        free(s);
        return NULL;
    }
    return s;
}

/* Every .o under dir (recursively), named by its path below lib_dir with
 * ".o" cut: CMake keeps engine/common/store_read.c's object as
 * CMakeFiles/hlod_core.dir/engine/common/store_read.c.o. */
static void add_objects(calls *c, const char *dir, size_t lib_len)
{
    DIR *d = opendir(dir);
    if (!d)
        return;
    struct dirent *e;
    while ((e = readdir(d))) {
        if (e->d_name[0] == '.')
            continue;
        char p[4096];
        snprintf(p, sizeof p, "%s/%s", dir, e->d_name);
        struct stat st;
        if (stat(p, &st) != 0)
            continue;
        size_t l = strlen(p);
        if (S_ISDIR(st.st_mode)) {
            add_objects(c, p, lib_len);
        } else if (l > 2 && !strcmp(p + l - 2, ".o")) {
            char *text = nm_output(p);
            CHECKF(text, "nm %s failed", p);
            p[l - 2] = 0;
            if (text)
                calls_add(c, p + lib_len, text);
            free(text);
        }
    }
    closedir(d);
}

static void no_call_cycle(void)
{
    const char *build = getenv("HLOD_BUILD_DIR");
    if (!build) {
        CHECK_SKIP("HLOD_BUILD_DIR is not set (ctest sets it)");
        return;
    }
    static calls c;
    static const char *const libs[] = {"hlod_core", "hlod_meshio", "hlod_preprocess",
                                       "hlod_engine", "hlod_osmesa", "hlod_egl", NULL};
    for (int i = 0; libs[i]; i++) {
        char dir[2048];
        int n = snprintf(dir, sizeof dir, "%s/CMakeFiles/%s.dir", build, libs[i]);
        add_objects(&c, dir, (size_t)n + 1);
    }
    calls_link(&c);
    size_t used = 0;
    for (int i = 0; i < c.n; i++)
        used += (size_t)c.nedge[i];
    CHECKF(c.n > 40 && used > 100, "only %d objects and %zu calls between them found", c.n, used);
    CHECK(calls_cycles(&c, 1) == 0);
    printf("     %d objects, %zu calls between files\n", c.n, used);
    calls_free(&c);
}

/* The search finds a planted cycle: three files in nm -P's format, a.c
 * calling b.c calling c.c calling a.c, and no cycle once c.c stops. */
static void call_cycle_found(void)
{
    static calls c;
    calls_add(&c, "a.c", "fa T 0000 10\nfb U\nprintf U\n");
    calls_add(&c, "b.c", "fb T 0000 10\nfc U\n");
    calls_add(&c, "c.c", "fc T 0000 10\nfa U\nkeep D 0 4\n");
    calls_link(&c);
    CHECK(c.nedge[0] == 1 && c.nedge[1] == 1 && c.nedge[2] == 1);
    CHECK(calls_cycles(&c, 0) == 1);
    calls_free(&c);
    calls_add(&c, "a.c", "fa T 0000 10\nfb U\n");
    calls_add(&c, "b.c", "fb T 0000 10\nfc U\n");
    calls_add(&c, "c.c", "fc T 0000 10\n");
    calls_link(&c);
    CHECK(calls_cycles(&c, 0) == 0);
    calls_free(&c);
}

/* Blanks comments, strings and character literals, keeping newlines. */
static void strip(char *s)
{
    for (char *p = s; *p; p++) {
        if (p[0] == '/' && p[1] == '*') {
            for (; *p && !(p[0] == '*' && p[1] == '/'); p++)
                if (*p != '\n')
                    *p = ' ';
            if (*p)
                p[0] = p[1] = ' ';
        } else if (p[0] == '/' && p[1] == '/') {
            for (; *p && *p != '\n'; p++)
                *p = ' ';
            if (!*p)
                break;
        } else if (*p == '"' || *p == '\'') {
            char q = *p;
            for (p++; *p && *p != q && *p != '\n'; p++) {
                if (*p == '\\' && p[1])
                    *p++ = ' ';
                *p = ' ';
            }
            if (!*p)
                break;
        }
    }
}

static void functions_are_short(void)
{
    int bodies = 0, longest = 0;
    for (int i = 0; i < nfiles; i++) {
        if (strncmp(files[i], "engine/", 7) && strncmp(files[i], "preprocess/", 11))
            continue;
        if (strstr(files[i], ".h") == files[i] + strlen(files[i]) - 2)
            continue;
        char *s = strdup(text[i]);
        strip(s);
        int depth_ = 0, line = 1, start = 0;
        char prev = 0;
        for (const char *p = s; *p; p++) {
            if (*p == '\n')
                line++;
            if (*p == '{') {
                if (depth_ == 0 && prev == ')')
                    start = line;
                depth_++;
            } else if (*p == '}' && depth_ > 0) {
                if (--depth_ == 0 && start) {
                    int n = line - start + 1;
                    bodies++;
                    longest = n > longest ? n : longest;
                    CHECKF(n <= MAX_LINES, "%s:%d: a function body of %d lines (over %d)",
                           files[i], start, n, MAX_LINES);
                    start = 0;
                }
            }
            if (*p != ' ' && *p != '\n' && *p != '\t')
                prev = *p;
        }
        free(s);
    }
    CHECKF(bodies > 500, "only %d function bodies found", bodies);
    printf("     %d function bodies, the longest %d lines\n", bodies, longest);
}

int main(void)
{
    const char *src = getenv("HLOD_SOURCE_DIR");
    snprintf(root, sizeof root, "%s", src ? src : ".");
    collect();
    include_graph();
    RUN(no_include_cycle);
    RUN(call_cycle_found);
    RUN(no_call_cycle);
    RUN(functions_are_short);
    for (int i = 0; i < nfiles; i++) {
        free(files[i]);
        free(text[i]);
    }
    return check_done();
}
