/*
 * test_structure.c - the source tree's shape (README, "Layout"): no include
 * cycle among the project's files, and no function over 150 lines in
 * engine/ or preprocess/.  Reads the tree under $HLOD_SOURCE_DIR.
 */
#include "check.h"

#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

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

static int color[MAX_FILES], stack[MAX_FILES], depth, cycles;

static void dfs(int u)
{
    color[u] = 1;
    stack[depth++] = u;
    for (int j = 0; j < nedges[u]; j++) {
        int v = edges[u][j];
        if (color[v] == 1) {
            char path[4096] = "";
            for (int s = 0; s < depth; s++)
                if (stack[s] == v || path[0]) {
                    strncat(path, files[stack[s]], sizeof path - strlen(path) - 5);
                    strcat(path, " -> ");
                }
            strncat(path, files[v], sizeof path - strlen(path) - 1);
            CHECKF(0, "include cycle: %s", path);
            cycles++;
        } else if (!color[v]) {
            dfs(v);
        }
    }
    depth--;
    color[u] = 2;
}

static void no_include_cycle(void)
{
    for (int i = 0; i < nfiles; i++)
        if (!color[i])
            dfs(i);
    size_t n = 0;
    for (int i = 0; i < nfiles; i++)
        n += (size_t)nedges[i];
    CHECKF(nfiles > 50 && n > 100, "only %d files and %zu includes found", nfiles, n);
    CHECK(cycles == 0);
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
    RUN(functions_are_short);
    for (int i = 0; i < nfiles; i++) {
        free(files[i]);
        free(text[i]);
    }
    return check_done();
}
