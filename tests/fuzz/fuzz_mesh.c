/*
 * fuzz_mesh.c - libFuzzer harness for mesh import validation: our OBJ(+MTL),
 * PLY (ASCII and binary) and OFF readers behind hlod_mesh_import, then
 * hlod_mesh_validate.
 *
 * Input: byte 0 picks the format (0 OBJ, 1 PLY, 2 OFF, by value % 3) and,
 * with bit 2, keep_degenerate (skip hlod_mesh_clean); the rest is the file,
 * written as f.obj / f.ply / f.off in a private folder on tmpfs (/dev/shm
 * when it exists), because import chooses the reader by content and
 * extension and resolves mtllib and texture names against the file's folder.
 * Inputs that import would hand to assimp (glTF magic, a JSON '{') are
 * skipped: assimp is not ours and is not built with sanitizers.
 *
 * Oracles: a mesh import accepts must pass hlod_mesh_validate, with
 * triangles, vertices and the reported counts consistent; on failure the
 * mesh must be left empty.  An OBJ import accepts (cleaned) must stream
 * (hlod_obj_stream, the sharded build's reader) too, to the same objects
 * and triangles, each object's mesh valid.  Never a crash, leak, hang or huge allocation
 * (libFuzzer's -malloc_limit_mb catches a reader trusting a count).
 */
#include "hlod/mesh_io.h"

#include <fcntl.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static char g_dir[256];

static void remove_dir(void)
{
    static const char *names[] = {"f.obj", "f.ply", "f.off"};
    char path[300];
    for (int i = 0; i < 3; i++) {
        snprintf(path, sizeof path, "%s/%s", g_dir, names[i]);
        unlink(path);
    }
    rmdir(g_dir);
}

int LLVMFuzzerInitialize(int *argc, char ***argv)
{
    (void)argc;
    (void)argv;
    const char *base = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : getenv("TMPDIR");
    snprintf(g_dir, sizeof g_dir, "%s/hlod-fuzz-mesh.XXXXXX", base ? base : "/tmp");
    if (!mkdtemp(g_dir)) {
        perror("mkdtemp");
        abort();
    }
    atexit(remove_dir);
    return 0;
}

/* What mesh_io.c's detect() would give to assimp. */
static int goes_to_assimp(const uint8_t *b, size_t n, int obj)
{
    if (n >= 4 && memcmp(b, "glTF", 4) == 0)
        return 1;
    size_t i = 0;
    while (i < n && (b[i] == ' ' || b[i] == '\t' || b[i] == '\r' || b[i] == '\n'))
        i++;
    return !obj && i < n && b[i] == '{';
}

typedef struct streamed {
    size_t objects, tris, bad;
} streamed;

static hlod_result count_object(void *user, const hlod_obj_info *info, const hlod_mesh *m)
{
    streamed *s = user;
    /* (an object whose triangles all clean away streams with none) */
    if (!m || info->tris != m->tri_count ||
        (m->tri_count && hlod_mesh_validate(m, "object", NULL) != HLOD_OK))
        s->bad++;
    s->objects += m && m->tri_count > 0;
    s->tris += m ? m->tri_count : 0;
    return HLOD_OK;
}

/* The OBJ file import took, streamed: the same objects and triangles. */
static void check_stream(const char *path, const hlod_mesh *m)
{
    streamed s = {0};
    hlod_obj_stream_desc d = {.object = count_object, .user = &s};
    hlod_mesh mats = {0};
    if (hlod_obj_stream(path, &d, &mats) != HLOD_OK || s.bad || s.tris != m->tri_count ||
        s.objects != m->object_count || mats.material_count != m->material_count)
        abort();
    hlod_mesh_free(&mats);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    if (size < 1)
        return 0;
    static const char *ext[] = {"obj", "ply", "off"};
    int kind = data[0] % 3, keep = (data[0] >> 2) & 1;
    data++;
    size--;
    if (goes_to_assimp(data, size, kind == 0))
        return 0;

    char path[300];
    snprintf(path, sizeof path, "%s/f.%s", g_dir, ext[kind]);
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC, 0600);
    if (fd < 0 || (size && write(fd, data, size) != (ssize_t)size) || close(fd) != 0) {
        perror(path);
        abort();
    }

    hlod_import_desc d = {0};
    d.keep_degenerate = keep;
    hlod_import_stats st;
    hlod_mesh m = {0};
    hlod_result r = hlod_mesh_import(path, &d, &m, &st);
    if (r != HLOD_OK) {
        if (m.vertex_count || m.tri_count || m.positions || m.indices || m.materials ||
            m.objects)
            abort();    /* left empty on failure */
    } else {
        if (hlod_mesh_validate(&m, path, NULL) != HLOD_OK || m.tri_count == 0 ||
            m.tri_count > st.tris_read)
            abort();
        /* every vertex a triangle uses is finite (ASan checks the reads) */
        for (size_t i = 0; i < 3 * m.tri_count; i++)
            if (!isfinite(m.positions[3 * (size_t)m.indices[i]]))
                abort();
        /* (an .obj whose first line is an OFF keyword was read as OFF:
         * content decides, and the stream reads OBJ only) */
        if (kind == 0 && !keep && hlod_mesh_is_obj(path))
            check_stream(path, &m);
    }
    hlod_mesh_free(&m);
    unlink(path);   /* the next input must not see this one as an mtllib */
    return 0;
}
