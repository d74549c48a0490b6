/*
 * glTF 2.0 writer (.gltf + .bin, or one .glb).
 *
 * Written directly rather than through assimp's exporter: aiExportScene
 * writes to the path it is given (and a .bin named after it), which would
 * defeat the temp-file-and-rename rule, and it would need a hand-built C++
 * scene.  glTF stores float positions, so each object becomes a node whose
 * translation (a JSON number, printed with %.17g) is the object's bounding
 * box centre, and its vertices are stored as float offsets from that centre:
 * a city at x = 5e5, y = 4.1e6 keeps millimetres instead of losing 0.25 m.
 *
 * Texture coordinates are stored with v flipped (glTF's origin is the
 * image's top left, ours and OBJ's the bottom left), matching what assimp
 * undoes on import.
 */
#include "io_internal.h"

#include <errno.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "atomic_file.h"

/* glTF buffers are little-endian and add_view copies host floats/uint32s. */
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "gltf_write.c assumes a little-endian host"
#endif

typedef struct sbuf {
    char *s;
    size_t len, cap;
    int oom;
} sbuf;

static void sb_printf(sbuf *b, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void sb_printf(sbuf *b, const char *fmt, ...)
{
    if (b->oom)
        return;
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int n = vsnprintf(b->s ? b->s + b->len : NULL, b->s ? b->cap - b->len : 0, fmt, ap);
        va_end(ap);
        if (n < 0) {
            b->oom = 1;
            return;
        }
        if (b->s && b->len + (size_t)n < b->cap) {
            b->len += (size_t)n;
            return;
        }
        size_t ncap = b->cap ? b->cap * 2 : 4096;
        while (ncap <= b->len + (size_t)n)
            ncap *= 2;
        char *ns = realloc(b->s, ncap);
        if (!ns) {
            b->oom = 1;
            return;
        }
        b->s = ns;
        b->cap = ncap;
    }
}

static void sb_json_string(sbuf *b, const char *s)
{
    sb_printf(b, "\"");
    for (; s && *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            sb_printf(b, "\\%c", c);
        else if (c < 0x20)
            sb_printf(b, "\\u%04x", c);
        else
            sb_printf(b, "%c", c);
    }
    sb_printf(b, "\"");
}

/* A relative URI: RFC 3986 unreserved characters and '/' stay, the rest is
 * percent-encoded. */
static void sb_uri(sbuf *b, const char *s)
{
    sb_printf(b, "\"");
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if ((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
            strchr("-._~/", c))
            sb_printf(b, "%c", c);
        else
            sb_printf(b, "%%%02X", c);
    }
    sb_printf(b, "\"");
}

typedef struct writer {
    const hlod_mesh *m;
    io_vec bin;           /* uint8_t */
    sbuf views, accessors, meshes, nodes;
    size_t nviews, naccessors, nmeshes;
    int oom;
} writer;

/* Appends bytes as one bufferView (4-byte aligned); returns its index. */
static size_t add_view(writer *w, const void *data, size_t n, int target)
{
    while (w->bin.count % 4) {
        uint8_t *z = io_vec_push(&w->bin, 1, 1);
        if (!z) {
            w->oom = 1;
            return 0;
        }
        *z = 0;
    }
    size_t off = w->bin.count;
    uint8_t *d = io_vec_push(&w->bin, 1, n);
    if (!d) {
        w->oom = 1;
        return 0;
    }
    memcpy(d, data, n);
    sb_printf(&w->views, "%s{\"buffer\":0,\"byteOffset\":%zu,\"byteLength\":%zu,\"target\":%d}",
              w->nviews ? "," : "", off, n, target);
    return w->nviews++;
}

static size_t add_accessor(writer *w, size_t view, int ctype, size_t count, const char *type,
                           const float *lo, const float *hi)
{
    sb_printf(&w->accessors, "%s{\"bufferView\":%zu,\"componentType\":%d,\"count\":%zu,\"type\":\"%s\"",
              w->naccessors ? "," : "", view, ctype, count, type);
    if (lo)
        sb_printf(&w->accessors, ",\"min\":[%.9g,%.9g,%.9g],\"max\":[%.9g,%.9g,%.9g]", lo[0],
                  lo[1], lo[2], hi[0], hi[1], hi[2]);
    sb_printf(&w->accessors, "}");
    return w->naccessors++;
}

/* One node + mesh for triangles [first, first + count): vertices renumbered
 * locally, one primitive per material. */
static void add_object(writer *w, const char *name, size_t k, size_t first, size_t count,
                       uint32_t *remap, uint32_t *order)
{
    const hlod_mesh *m = w->m;
    sb_printf(&w->nodes, "%s{\"name\":", k ? "," : "");
    sb_json_string(&w->nodes, name);
    if (!count) {
        sb_printf(&w->nodes, "}");
        return;
    }
    size_t nv = 0;
    for (size_t i = 3 * first; i < 3 * (first + count); i++)
        if (remap[m->indices[i]] == UINT32_MAX) {
            remap[m->indices[i]] = (uint32_t)nv;
            order[nv++] = m->indices[i];
        }
    double lo[3], hi[3], c[3];
    for (int a = 0; a < 3; a++)
        lo[a] = hi[a] = m->positions[3 * (size_t)order[0] + a];
    for (size_t v = 1; v < nv; v++)
        for (int a = 0; a < 3; a++) {
            double x = m->positions[3 * (size_t)order[v] + a];
            lo[a] = x < lo[a] ? x : lo[a];
            hi[a] = x > hi[a] ? x : hi[a];
        }
    for (int a = 0; a < 3; a++)
        c[a] = 0.5 * (lo[a] + hi[a]);

    size_t comps = 3 + (m->normals ? 3 : 0) + (m->uvs ? 2 : 0);
    float *buf = malloc((nv * comps > count * 3 ? nv * comps : count * 3) * sizeof(float) + 4);
    if (!buf) {
        w->oom = 1;
        return;
    }
    float flo[3], fhi[3];
    for (size_t v = 0; v < nv; v++)
        for (int a = 0; a < 3; a++) {
            float f = (float)(m->positions[3 * (size_t)order[v] + a] - c[a]);
            buf[3 * v + a] = f;
            flo[a] = v == 0 || f < flo[a] ? f : flo[a];
            fhi[a] = v == 0 || f > fhi[a] ? f : fhi[a];
        }
    size_t pos_acc = add_accessor(w, add_view(w, buf, nv * 12, 34962), 5126, nv, "VEC3", flo, fhi);
    size_t nrm_acc = 0, uv_acc = 0;
    if (m->normals) {
        for (size_t v = 0; v < nv; v++)
            memcpy(buf + 3 * v, m->normals + 3 * (size_t)order[v], 12);
        nrm_acc = add_accessor(w, add_view(w, buf, nv * 12, 34962), 5126, nv, "VEC3", NULL, NULL);
    }
    if (m->uvs) {
        for (size_t v = 0; v < nv; v++) {
            buf[2 * v] = m->uvs[2 * (size_t)order[v]];
            buf[2 * v + 1] = 1.0f - m->uvs[2 * (size_t)order[v] + 1];
        }
        uv_acc = add_accessor(w, add_view(w, buf, nv * 8, 34962), 5126, nv, "VEC2", NULL, NULL);
    }

    sb_printf(&w->meshes, "%s{\"name\":", w->nmeshes ? "," : "");
    sb_json_string(&w->meshes, name);
    sb_printf(&w->meshes, ",\"primitives\":[");
    /* One primitive per material, in material order. */
    uint32_t *ib = (uint32_t *)buf;
    size_t nmat = m->tri_material ? m->material_count : 1, nprim = 0;
    for (size_t mat = 0; mat < nmat; mat++) {
        size_t n = 0;
        for (size_t t = first; t < first + count; t++) {
            if (m->tri_material && m->tri_material[t] != mat)
                continue;
            for (int j = 0; j < 3; j++)
                ib[n++] = remap[m->indices[3 * t + j]];
        }
        if (!n)
            continue;
        size_t ia = add_accessor(w, add_view(w, ib, n * 4, 34963), 5125, n, "SCALAR", NULL, NULL);
        sb_printf(&w->meshes, "%s{\"attributes\":{\"POSITION\":%zu", nprim++ ? "," : "", pos_acc);
        if (m->normals)
            sb_printf(&w->meshes, ",\"NORMAL\":%zu", nrm_acc);
        if (m->uvs)
            sb_printf(&w->meshes, ",\"TEXCOORD_0\":%zu", uv_acc);
        sb_printf(&w->meshes, "},\"indices\":%zu,\"mode\":4", ia);
        if (m->material_count)
            sb_printf(&w->meshes, ",\"material\":%zu", m->tri_material ? mat : (size_t)0);
        sb_printf(&w->meshes, "}");
    }
    sb_printf(&w->meshes, "]}");
    sb_printf(&w->nodes, ",\"mesh\":%zu,\"translation\":[%.17g,%.17g,%.17g]}", w->nmeshes++,
              c[0], c[1], c[2]);
    for (size_t v = 0; v < nv; v++)
        remap[order[v]] = UINT32_MAX;
    free(buf);
}

static void add_materials(sbuf *j, const hlod_mesh *m, const char *dir, int *oom)
{
    sbuf images = {0}, textures = {0};
    io_strmap seen = {0};
    size_t nimg = 0;
    sb_printf(j, ",\"materials\":[");
    for (size_t i = 0; i < m->material_count; i++) {
        const hlod_material *mt = &m->materials[i];
        sb_printf(j, "%s{", i ? "," : "");
        if (mt->name) {
            sb_printf(j, "\"name\":");
            sb_json_string(j, mt->name);
            sb_printf(j, ",");
        }
        sb_printf(j, "\"pbrMetallicRoughness\":{\"baseColorFactor\":[%.9g,%.9g,%.9g,%.9g],"
                     "\"metallicFactor\":0,\"roughnessFactor\":1",
                  mt->diffuse[0], mt->diffuse[1], mt->diffuse[2], mt->diffuse[3]);
        if (mt->texture_path) {
            long img = io_strmap_get(&seen, mt->texture_path);
            if (img < 0) {
                char *rel = io_relative_path(dir, mt->texture_path);
                if (!rel || !io_strmap_put(&seen, mt->texture_path, (uint32_t)nimg)) {
                    free(rel);
                    *oom = 1;
                    break;
                }
                sb_printf(&images, "%s{\"uri\":", nimg ? "," : "");
                sb_uri(&images, rel);
                sb_printf(&images, "}");
                sb_printf(&textures, "%s{\"source\":%zu,\"sampler\":0}", nimg ? "," : "", nimg);
                free(rel);
                img = (long)nimg++;
            }
            sb_printf(j, ",\"baseColorTexture\":{\"index\":%ld}", img);
        }
        sb_printf(j, "}}");
    }
    sb_printf(j, "]");
    if (nimg)
        sb_printf(j,
                  ",\"samplers\":[{\"wrapS\":10497,\"wrapT\":10497}],\"images\":[%s],"
                  "\"textures\":[%s]",
                  images.s, textures.s);
    *oom |= images.oom || textures.oom;
    free(images.s);
    free(textures.s);
    io_strmap_free(&seen);
}

hlod_result io_write_gltf(const char *path, const hlod_mesh *m, int binary, const hlod_logger *lg)
{
    writer w;
    memset(&w, 0, sizeof w);
    w.m = m;
    hlod_result res = HLOD_OK;
    uint32_t *remap = malloc(m->vertex_count * sizeof *remap);
    uint32_t *order = malloc(m->vertex_count * sizeof *order);
    char *dir = io_dirname(path);
    char *bin_path = NULL;
    sbuf j = {0};
    hlod_atomic_file f, fb;
    memset(&f, 0, sizeof f);
    memset(&fb, 0, sizeof fb);
    if (!remap || !order || !dir) {
        res = HLOD_ERR_NOMEM;
        goto done;
    }
    for (size_t v = 0; v < m->vertex_count; v++)
        remap[v] = UINT32_MAX;
    size_t nobj = m->object_count ? m->object_count : 1;
    for (size_t o = 0; o < nobj && !w.oom; o++) {
        char name[32];
        const char *nm = m->object_count ? m->objects[o].name : NULL;
        if (!nm) {
            snprintf(name, sizeof name, "object%zu", o);
            nm = name;
        }
        size_t first = m->object_count ? m->objects[o].first_tri : 0;
        size_t count = m->object_count ? m->objects[o].tri_count : m->tri_count;
        add_object(&w, nm, o, first, count, remap, order);
    }

    sb_printf(&j, "{\"asset\":{\"version\":\"2.0\",\"generator\":\"hlod\"},\"scene\":0,"
                  "\"scenes\":[{\"nodes\":[");
    for (size_t o = 0; o < nobj; o++)
        sb_printf(&j, "%s%zu", o ? "," : "", o);
    sb_printf(&j, "]}],\"nodes\":[%s],\"meshes\":[%s]", w.nodes.s, w.meshes.s);
    if (m->material_count)
        add_materials(&j, m, dir, &w.oom);
    sb_printf(&j, ",\"buffers\":[{\"byteLength\":%zu", w.bin.count);
    if (!binary) {
        size_t n = strlen(path);
        const char *dot = strrchr(path, '.');
        size_t stem = dot ? (size_t)(dot - path) : n;
        bin_path = malloc(stem + 5);
        if (!bin_path) {
            res = HLOD_ERR_NOMEM;
            goto done;
        }
        memcpy(bin_path, path, stem);
        memcpy(bin_path + stem, ".bin", 5);
        const char *base = strrchr(bin_path, '/');
        sb_printf(&j, ",\"uri\":");
        sb_uri(&j, base ? base + 1 : bin_path);
    }
    sb_printf(&j, "}],\"bufferViews\":[%s],\"accessors\":[%s]}", w.views.s, w.accessors.s);
    if (w.oom || j.oom || w.views.oom || w.accessors.oom || w.meshes.oom || w.nodes.oom) {
        res = HLOD_ERR_NOMEM;
        goto done;
    }

    if ((res = hlod_atomic_open(&f, path, lg)))
        goto done;
    if (binary) {
        /* GLB: 12-byte header, then a JSON chunk padded with spaces and a
         * BIN chunk padded with zeros, both to 4 bytes. */
        size_t jl = (j.len + 3) & ~(size_t)3, bl = (w.bin.count + 3) & ~(size_t)3;
        if (jl + bl > UINT32_MAX - 28) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: %zu bytes exceed GLB's 4 GiB limit", path,
                      jl + bl + 28);
            res = HLOD_ERR_UNSUPPORTED;
            goto done;
        }
        uint32_t words[7] = {0x46546C67u, 2, (uint32_t)(12 + 8 + jl + 8 + bl), (uint32_t)jl,
                             0x4E4F534Au, (uint32_t)bl, 0x004E4942u};
        uint8_t hdr[20], bhdr[8];
        for (int i = 0; i < 7; i++)
            for (int b = 0; b < 4; b++)
                (i < 5 ? hdr + 4 * i : bhdr + 4 * (i - 5))[b] = (uint8_t)(words[i] >> (8 * b));
        static const char spaces[3] = {' ', ' ', ' '};
        static const uint8_t zeros[3] = {0, 0, 0};
        fwrite(hdr, 1, sizeof hdr, f.fp);
        fwrite(j.s, 1, j.len, f.fp);
        fwrite(spaces, 1, jl - j.len, f.fp);
        fwrite(bhdr, 1, sizeof bhdr, f.fp);
        fwrite(w.bin.data, 1, w.bin.count, f.fp);
        fwrite(zeros, 1, bl - w.bin.count, f.fp);
        res = hlod_atomic_commit(&f, lg);
        goto done;
    }
    if ((res = hlod_atomic_open(&fb, bin_path, lg)))
        goto done;
    fwrite(j.s, 1, j.len, f.fp);
    fwrite(w.bin.data, 1, w.bin.count, fb.fp);
    if (!hlod_flush_sync(f.fp) || !hlod_flush_sync(fb.fp)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: write failed: %s", path, strerror(errno));
        res = HLOD_ERR_IO;
        goto done;
    }
    if ((res = hlod_atomic_commit(&fb, lg)))
        goto done;
    if ((res = hlod_atomic_commit(&f, lg)))
        unlink(bin_path);
done:
    if (res == HLOD_ERR_NOMEM)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory", path);
    hlod_atomic_abort(&f);
    hlod_atomic_abort(&fb);
    free(remap);
    free(order);
    free(dir);
    free(bin_path);
    free(j.s);
    free(w.views.s);
    free(w.accessors.s);
    free(w.meshes.s);
    free(w.nodes.s);
    io_vec_free(&w.bin);
    return res;
}
