/*
 * tiles_read.c - a 3D Tiles tileset (tileset.json) as an input mesh
 * (mesh_io.h; docs/3d-tiles.md).
 *
 * The leaf tiles' glb contents become the mesh, one object per leaf tile
 * (so hlod-build makes one block of each).  Transforms are composed in
 * double: tile transforms down the tree, glTF's y-up to 3D Tiles' z-up
 * rotation, then the glTF node transforms, so vertices at projected
 * coordinates keep their millimetres.  An external tileset (a content uri
 * ending in .json) is read in place, 8 levels deep at most.
 *
 * Our own glb reader rather than assimp's: Debian's assimp 5.2 reads
 * neither KHR_mesh_quantization nor EXT_meshopt_compression (what
 * hlod-export-3dtiles writes, and most 3D Tiles producers), and it keeps
 * floats.  It reads triangle-list primitives with POSITION, NORMAL,
 * TEXCOORD_0 and indices of any component type the core spec and
 * KHR_mesh_quantization allow (normalized or not), bufferViews coded with
 * EXT_meshopt_compression (meshoptimizer's decoders and filters), and
 * baseColorTexture images embedded in the glb (written into the import's
 * scratch folder, where the build reads them) or referenced by a relative
 * uri.  Everything is bounds-checked: a bad file is an error naming it.
 */
#include "io_internal.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>
#include <meshoptimizer.h>

#define MAX_EXTERNAL_DEPTH 8

typedef struct acc_mesh {
    io_vec pos;         /* double x3 */
    io_vec nrm;         /* float x3 */
    io_vec uv;          /* float x2 */
    io_vec idx;         /* uint32 */
    io_vec tmat;        /* uint32 per triangle */
    io_vec mats;        /* hlod_material */
    io_vec objs;        /* hlod_object */
    int any_normals, any_uvs;
    size_t images;      /* images written to the scratch folder */
} acc_mesh;

typedef struct rd {
    const char *top;            /* the tileset path the user gave, for messages */
    const char *scratch;
    const hlod_logger *lg;
    acc_mesh *m;
    hlod_import_stats *st;
    size_t leaves;
} rd;

static int read_file(const char *path, uint8_t **data, size_t *len, const hlod_logger *lg)
{
    *data = NULL;
    *len = 0;
    FILE *f = fopen(path, "rb");
    if (!f) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot open: %s", path, strerror(errno));
        return 0;
    }
    if (fseek(f, 0, SEEK_END) != 0) {
        fclose(f);
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot seek: %s", path, strerror(errno));
        return 0;
    }
    long n = ftell(f);
    rewind(f);
    if (n < 0 || !(*data = malloc((size_t)n + 1)) || fread(*data, 1, (size_t)n, f) != (size_t)n) {
        fclose(f);
        free(*data);
        *data = NULL;
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: cannot read", path);
        return 0;
    }
    fclose(f);
    (*data)[n] = 0;
    *len = (size_t)n;
    return 1;
}

/* 4x4 column-major, double */
static void mat_mul(const double a[16], const double b[16], double out[16])
{
    double r[16];
    for (int c = 0; c < 4; c++)
        for (int row = 0; row < 4; row++) {
            double s = 0;
            for (int k = 0; k < 4; k++)
                s += a[k * 4 + row] * b[c * 4 + k];
            r[c * 4 + row] = s;
        }
    memcpy(out, r, sizeof r);
}

static const double IDENTITY[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
/* glTF y up -> 3D Tiles z up: (x, y, z) -> (x, -z, y) */
static const double Y_UP_TO_Z_UP[16] = {1, 0, 0, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 0, 0, 1};

static int get_numbers(const cJSON *a, double *out, int n)
{
    if (!cJSON_IsArray(a) || cJSON_GetArraySize(a) != n)
        return 0;
    int i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, a) {
        if (!cJSON_IsNumber(e) || !isfinite(e->valuedouble))
            return 0;
        out[i++] = e->valuedouble;
    }
    return 1;
}

static long get_index(const cJSON *o, const char *key)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!cJSON_IsNumber(v) || v->valuedouble < 0 || v->valuedouble > 1e9 ||
        v->valuedouble != floor(v->valuedouble))
        return -1;
    return (long)v->valuedouble;
}

/* ---- glb ---- */

typedef struct glb {
    const char *path;
    cJSON *json;
    const uint8_t *bin;
    size_t bin_len;
    uint8_t **decoded;      /* per bufferView: meshopt-decoded bytes, or NULL */
    int view_count;
} glb;

#define GLB_FAIL(...) do { hlod_logf(lg, HLOD_LOG_ERROR, __VA_ARGS__); return NULL; } while (0)

/* The bytes of bufferView v (decoded when meshopt-coded), its length and
 * stride. */
static const uint8_t *view_bytes(glb *g, long v, size_t *len, size_t *stride,
                                 const hlod_logger *lg)
{
    const cJSON *views = cJSON_GetObjectItemCaseSensitive(g->json, "bufferViews");
    const cJSON *bv = cJSON_GetArrayItem(views, (int)v);
    if (v < 0 || !bv)
        GLB_FAIL("%s: bufferView %ld does not exist", g->path, v);
    long blen = get_index(bv, "byteLength"), boff = get_index(bv, "byteOffset");
    if (boff < 0)
        boff = 0;
    *stride = get_index(bv, "byteStride") > 0 ? (size_t)get_index(bv, "byteStride") : 0;
    if (blen < 0)
        GLB_FAIL("%s: bufferView %ld has no byteLength", g->path, v);
    *len = (size_t)blen;
    const cJSON *ext = cJSON_GetObjectItemCaseSensitive(
        cJSON_GetObjectItemCaseSensitive(bv, "extensions"), "EXT_meshopt_compression");
    if (ext) {
        if (g->decoded[v])
            return g->decoded[v];
        long eb = get_index(ext, "buffer"), eoff = get_index(ext, "byteOffset"),
             elen = get_index(ext, "byteLength"), es = get_index(ext, "byteStride"),
             cnt = get_index(ext, "count");
        const cJSON *mode = cJSON_GetObjectItemCaseSensitive(ext, "mode");
        const cJSON *filter = cJSON_GetObjectItemCaseSensitive(ext, "filter");
        if (eoff < 0)
            eoff = 0;
        if (eb != 0 || elen < 0 || es <= 0 || cnt < 0 || !cJSON_IsString(mode) ||
            (size_t)eoff + (size_t)elen > g->bin_len || (size_t)cnt * (size_t)es > (size_t)blen)
            GLB_FAIL("%s: bufferView %ld: a bad EXT_meshopt_compression record", g->path, v);
        uint8_t *out = malloc((size_t)blen + 16);
        if (!out)
            GLB_FAIL("%s: out of memory", g->path);
        const uint8_t *src = g->bin + eoff;
        int rc;
        if (!strcmp(mode->valuestring, "ATTRIBUTES"))
            rc = es % 4 == 0 && es <= 256
                ? meshopt_decodeVertexBuffer(out, (size_t)cnt, (size_t)es, src, (size_t)elen) : -1;
        else if (!strcmp(mode->valuestring, "TRIANGLES"))
            rc = (es == 2 || es == 4) && cnt % 3 == 0
                ? meshopt_decodeIndexBuffer(out, (size_t)cnt, (size_t)es, src, (size_t)elen) : -1;
        else if (!strcmp(mode->valuestring, "INDICES"))
            rc = es == 2 || es == 4
                ? meshopt_decodeIndexSequence(out, (size_t)cnt, (size_t)es, src, (size_t)elen) : -1;
        else
            rc = -1;
        if (rc == 0 && cJSON_IsString(filter) && strcmp(filter->valuestring, "NONE") != 0) {
            if (!strcmp(filter->valuestring, "OCTAHEDRAL") && (es == 4 || es == 8))
                meshopt_decodeFilterOct(out, (size_t)cnt, (size_t)es);
            else if (!strcmp(filter->valuestring, "QUATERNION") && es == 8)
                meshopt_decodeFilterQuat(out, (size_t)cnt, (size_t)es);
            else if (!strcmp(filter->valuestring, "EXPONENTIAL") && es % 4 == 0)
                meshopt_decodeFilterExp(out, (size_t)cnt, (size_t)es);
            else
                rc = -1;
        }
        if (rc != 0) {
            free(out);
            GLB_FAIL("%s: bufferView %ld: cannot decode its EXT_meshopt_compression data", g->path, v);
        }
        memset(out + (size_t)cnt * (size_t)es, 0, (size_t)blen - (size_t)cnt * (size_t)es);
        g->decoded[v] = out;
        return out;
    }
    if (get_index(bv, "buffer") != 0 || (size_t)boff + (size_t)blen > g->bin_len)
        GLB_FAIL("%s: bufferView %ld lies outside the glb's binary chunk", g->path, v);
    return g->bin + boff;
}

static size_t comp_size(long ct)
{
    switch (ct) {
    case 5120: case 5121: return 1;
    case 5122: case 5123: return 2;
    case 5125: case 5126: return 4;
    default: return 0;
    }
}

static double comp_value(const uint8_t *p, long ct, int normalized)
{
    switch (ct) {
    case 5120: { int8_t v; memcpy(&v, p, 1); return normalized ? fmax(v / 127.0, -1.0) : v; }
    case 5121: { uint8_t v = *p; return normalized ? v / 255.0 : v; }
    case 5122: { int16_t v; memcpy(&v, p, 2); return normalized ? fmax(v / 32767.0, -1.0) : v; }
    case 5123: { uint16_t v; memcpy(&v, p, 2); return normalized ? v / 65535.0 : v; }
    case 5125: { uint32_t v; memcpy(&v, p, 4); return v; }
    default: { float v; memcpy(&v, p, 4); return v; }
    }
}

/* Accessor a as doubles (count x comps), malloc'ed; NULL on error. */
static double *accessor(glb *g, long a, int comps, size_t *count, const hlod_logger *lg)
{
    const cJSON *acc = cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(g->json, "accessors"),
                                          (int)a);
    if (a < 0 || !acc)
        GLB_FAIL("%s: accessor %ld does not exist", g->path, a);
    if (cJSON_GetObjectItemCaseSensitive(acc, "sparse"))
        GLB_FAIL("%s: accessor %ld is sparse, which is not read", g->path, a);
    long ct = get_index(acc, "componentType"), n = get_index(acc, "count"),
         off = get_index(acc, "byteOffset"), v = get_index(acc, "bufferView");
    size_t cs = comp_size(ct);
    if (!cs || n < 0 || v < 0)
        GLB_FAIL("%s: accessor %ld: bad componentType, count or bufferView", g->path, a);
    if (off < 0)
        off = 0;
    int norm = cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(acc, "normalized"));
    size_t len, stride;
    const uint8_t *b = view_bytes(g, v, &len, &stride, lg);
    if (!b)
        return NULL;
    size_t elem = cs * (size_t)comps;
    if (!stride)
        stride = elem;
    if (n > 0 && (size_t)off + stride * (size_t)(n - 1) + elem > len)
        GLB_FAIL("%s: accessor %ld runs past its bufferView", g->path, a);
    double *out = malloc(((size_t)n * (size_t)comps + 1) * sizeof *out);
    if (!out)
        GLB_FAIL("%s: out of memory", g->path);
    for (size_t i = 0; i < (size_t)n; i++)
        for (int k = 0; k < comps; k++)
            out[i * (size_t)comps + (size_t)k] =
                comp_value(b + off + i * stride + (size_t)k * cs, ct, norm);
    *count = (size_t)n;
    return out;
}

/* A material's texture as a file: an embedded image written to the scratch
 * folder, or a relative uri resolved against the glb's folder.  NULL when
 * it has none (or it cannot be had: a warning). */
static char *texture_file(rd *R, glb *g, const cJSON *mat)
{
    const hlod_logger *lg = R->lg;
    const cJSON *bct = cJSON_GetObjectItemCaseSensitive(
        cJSON_GetObjectItemCaseSensitive(mat, "pbrMetallicRoughness"), "baseColorTexture");
    if (!bct)
        return NULL;
    const cJSON *tex = cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(g->json, "textures"),
                                          (int)get_index(bct, "index"));
    const cJSON *img = cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(g->json, "images"),
                                          (int)get_index(tex, "source"));
    if (!tex || !img || get_index(bct, "index") < 0 || get_index(tex, "source") < 0) {
        hlod_logf(lg, HLOD_LOG_WARN, "%s: a material's texture does not exist; untextured", g->path);
        return NULL;
    }
    const cJSON *uri = cJSON_GetObjectItemCaseSensitive(img, "uri");
    if (cJSON_IsString(uri)) {
        if (!strncmp(uri->valuestring, "data:", 5)) {
            hlod_logf(lg, HLOD_LOG_WARN, "%s: a data: image uri is not read; untextured", g->path);
            return NULL;
        }
        char *dir = io_dirname(g->path);
        char *p = dir ? io_join(dir, uri->valuestring) : NULL;
        free(dir);
        return p;
    }
    long v = get_index(img, "bufferView");
    const cJSON *mime = cJSON_GetObjectItemCaseSensitive(img, "mimeType");
    if (v < 0 || !cJSON_IsString(mime)) {
        hlod_logf(lg, HLOD_LOG_WARN, "%s: an image has neither uri nor bufferView; untextured",
                  g->path);
        return NULL;
    }
    if (!R->scratch) {
        hlod_logf(lg, HLOD_LOG_WARN, "%s: an embedded image needs a scratch folder "
                  "(hlod_import_desc.scratch_dir); untextured", g->path);
        return NULL;
    }
    size_t len, stride;
    const uint8_t *b = view_bytes(g, v, &len, &stride, lg);
    if (!b)
        return NULL;
    const char *ext = !strcmp(mime->valuestring, "image/png") ? "png" : "jpg";
    char name[64];
    snprintf(name, sizeof name, "image-%zu.%s", R->m->images++, ext);
    char *p = io_join(R->scratch, name);
    FILE *f = p ? fopen(p, "wb") : NULL;
    int ok = f && fwrite(b, 1, len, f) == len;
    if (f && fclose(f) != 0)
        ok = 0;
    if (!ok) {
        hlod_logf(lg, HLOD_LOG_WARN, "%s: cannot write %s: %s; untextured", g->path,
                  p ? p : name, strerror(errno));
        free(p);
        return NULL;
    }
    return p;
}

static int add_primitive(rd *R, glb *g, const cJSON *prim, const double world[16], long obj)
{
    const hlod_logger *lg = R->lg;
    acc_mesh *M = R->m;
    const cJSON *mode = cJSON_GetObjectItemCaseSensitive(prim, "mode");
    if (mode && !(cJSON_IsNumber(mode) && mode->valuedouble == 4)) {
        hlod_logf(lg, HLOD_LOG_WARN, "%s: a primitive that is not a triangle list is skipped",
                  g->path);
        return 1;
    }
    const cJSON *attrs = cJSON_GetObjectItemCaseSensitive(prim, "attributes");
    long ap = get_index(attrs, "POSITION"), an = get_index(attrs, "NORMAL"),
         at = get_index(attrs, "TEXCOORD_0"), ai = get_index(prim, "indices");
    if (ap < 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: a primitive without POSITION", g->path);
        return 0;
    }
    size_t nv = 0, nn = 0, nt = 0, ni = 0;
    double *P = accessor(g, ap, 3, &nv, lg), *N = NULL, *T = NULL, *I = NULL;
    int ok = P != NULL;
    if (ok && an >= 0)
        ok = (N = accessor(g, an, 3, &nn, lg)) && nn == nv;
    if (ok && at >= 0)
        ok = (T = accessor(g, at, 2, &nt, lg)) && nt == nv;
    if (ok && ai >= 0)
        ok = (I = accessor(g, ai, 1, &ni, lg)) != NULL;
    if (ok && ai < 0)
        ni = nv;
    if (ok && (ni % 3 != 0 || (N && nn != nv) || (T && nt != nv))) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: a primitive's attribute counts disagree", g->path);
        ok = 0;
    }
    /* the material */
    long mi = get_index(prim, "material");
    const cJSON *mat = mi >= 0 ? cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(g->json,
                                                                                       "materials"),
                                                    (int)mi) : NULL;
    hlod_material hm = {0};
    hm.diffuse[0] = hm.diffuse[1] = hm.diffuse[2] = 0.8f;
    hm.diffuse[3] = 1;
    if (ok && mat) {
        double f[4];
        if (get_numbers(cJSON_GetObjectItemCaseSensitive(
                            cJSON_GetObjectItemCaseSensitive(mat, "pbrMetallicRoughness"),
                            "baseColorFactor"), f, 4))
            for (int k = 0; k < 4; k++)
                hm.diffuse[k] = (float)f[k];
        hm.texture_path = T ? texture_file(R, g, mat) : NULL;
        const cJSON *nm = cJSON_GetObjectItemCaseSensitive(mat, "name");
        if (cJSON_IsString(nm))
            hm.name = io_strdup(nm->valuestring);
    }
    uint32_t base = (uint32_t)M->pos.count;
    if (ok && (size_t)base + nv > UINT32_MAX) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: more than 2^32 vertices in the tileset", R->top);
        ok = 0;
    }
    double *pp = ok ? io_vec_push(&M->pos, 3 * sizeof(double), nv) : NULL;
    float *np = ok ? io_vec_push(&M->nrm, 3 * sizeof(float), nv) : NULL;
    float *tp = ok ? io_vec_push(&M->uv, 2 * sizeof(float), nv) : NULL;
    uint32_t *ip = ok ? io_vec_push(&M->idx, sizeof(uint32_t), ni) : NULL;
    uint32_t *mp = ok ? io_vec_push(&M->tmat, sizeof(uint32_t), ni / 3) : NULL;
    hlod_material *matp = ok ? io_vec_push(&M->mats, sizeof(hlod_material), 1) : NULL;
    if (matp)
        memset(matp, 0, sizeof *matp);
    if (ok && (!pp || !np || !tp || !ip || !mp || !matp)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory", R->top);
        ok = 0;
    }
    if (ok) {
        /* normals by the inverse transpose of world's 3x3 (cofactors) */
        const double *w = world;
        double c[9] = {
            w[5] * w[10] - w[6] * w[9], w[6] * w[8] - w[4] * w[10], w[4] * w[9] - w[5] * w[8],
            w[2] * w[9] - w[1] * w[10], w[0] * w[10] - w[2] * w[8], w[1] * w[8] - w[0] * w[9],
            w[1] * w[6] - w[2] * w[5], w[2] * w[4] - w[0] * w[6], w[0] * w[5] - w[1] * w[4]};
        for (size_t v = 0; v < nv; v++) {
            const double *q = P + 3 * v;
            for (int k = 0; k < 3; k++)
                pp[3 * v + k] = w[k] * q[0] + w[4 + k] * q[1] + w[8 + k] * q[2] + w[12 + k];
            double n[3] = {0, 0, 0};
            if (N) {
                const double *s = N + 3 * v;
                for (int k = 0; k < 3; k++)
                    n[k] = c[3 * k] * s[0] + c[3 * k + 1] * s[1] + c[3 * k + 2] * s[2];
                double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
                for (int k = 0; k < 3; k++)
                    n[k] = len > 0 ? n[k] / len : 0;
            }
            for (int k = 0; k < 3; k++)
                np[3 * v + k] = (float)n[k];
            tp[2 * v] = T ? (float)T[2 * v] : 0;
            tp[2 * v + 1] = T ? (float)(1.0 - T[2 * v + 1]) : 0;  /* glTF v runs down */
        }
        M->any_normals |= N != NULL;
        M->any_uvs |= T != NULL;
        int flip = w[0] * c[0] + w[1] * c[1] + w[2] * c[2] < 0; /* det < 0: mirrored */
        for (size_t t = 0; t < ni; t++) {
            double iv = I ? I[t] : (double)t;
            if (!(iv >= 0 && iv < (double)nv)) {
                hlod_logf(lg, HLOD_LOG_ERROR, "%s: index %.0f past the primitive's %zu vertices",
                          g->path, iv, nv);
                ok = 0;
                break;
            }
            size_t slot = flip ? t - t % 3 + (3 - t % 3) % 3 : t;
            ip[slot] = base + (uint32_t)iv;
        }
        uint32_t matidx = (uint32_t)(M->mats.count - 1);
        for (size_t t = 0; t < ni / 3; t++)
            mp[t] = matidx;
        *matp = hm;
        hm.name = hm.texture_path = NULL;
        R->st->tris_read += ni / 3;
        (void)obj;
    }
    free(hm.name);
    free(hm.texture_path);
    free(P);
    free(N);
    free(T);
    free(I);
    return ok;
}

static int node_matrix(const cJSON *node, double m[16])
{
    memcpy(m, IDENTITY, sizeof IDENTITY);
    const cJSON *mat = cJSON_GetObjectItemCaseSensitive(node, "matrix");
    if (mat)
        return get_numbers(mat, m, 16);
    double t[3] = {0, 0, 0}, r[4] = {0, 0, 0, 1}, s[3] = {1, 1, 1};
    const cJSON *jt = cJSON_GetObjectItemCaseSensitive(node, "translation"),
                *jr = cJSON_GetObjectItemCaseSensitive(node, "rotation"),
                *js = cJSON_GetObjectItemCaseSensitive(node, "scale");
    if ((jt && !get_numbers(jt, t, 3)) || (jr && !get_numbers(jr, r, 4)) ||
        (js && !get_numbers(js, s, 3)))
        return 0;
    double x = r[0], y = r[1], z = r[2], w = r[3];
    double R[9] = {1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w),
                   2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w),
                   2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)};
    for (int c = 0; c < 3; c++)
        for (int k = 0; k < 3; k++)
            m[c * 4 + k] = R[c * 3 + k] * s[c];
    for (int k = 0; k < 3; k++)
        m[12 + k] = t[k];
    return 1;
}

static int add_node(rd *R, glb *g, long ni, const double parent[16], long obj, int depth)
{
    const cJSON *node = cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(g->json, "nodes"),
                                           (int)ni);
    if (ni < 0 || !node || depth > 64) {
        hlod_logf(R->lg, HLOD_LOG_ERROR, "%s: node %ld does not exist (or the node tree loops)",
                  g->path, ni);
        return 0;
    }
    double local[16], world[16];
    if (!node_matrix(node, local)) {
        hlod_logf(R->lg, HLOD_LOG_ERROR, "%s: node %ld has a bad transform", g->path, ni);
        return 0;
    }
    mat_mul(parent, local, world);
    long mi = get_index(node, "mesh");
    if (mi >= 0) {
        const cJSON *mesh = cJSON_GetArrayItem(cJSON_GetObjectItemCaseSensitive(g->json, "meshes"),
                                               (int)mi);
        if (!mesh) {
            hlod_logf(R->lg, HLOD_LOG_ERROR, "%s: mesh %ld does not exist", g->path, mi);
            return 0;
        }
        const cJSON *prim;
        cJSON_ArrayForEach(prim, cJSON_GetObjectItemCaseSensitive(mesh, "primitives"))
            if (!add_primitive(R, g, prim, world, obj))
                return 0;
    }
    const cJSON *ch;
    cJSON_ArrayForEach(ch, cJSON_GetObjectItemCaseSensitive(node, "children"))
        if (!cJSON_IsNumber(ch) || !add_node(R, g, (long)ch->valuedouble, world, obj, depth + 1))
            return 0;
    return 1;
}

static int read_glb(rd *R, const char *path, const double tile[16], long obj)
{
    const hlod_logger *lg = R->lg;
    uint8_t *data;
    size_t len;
    if (!read_file(path, &data, &len, lg))
        return 0;
    int ok = 0;
    glb g = {path, NULL, NULL, 0, NULL, 0};
    uint32_t h[5];
    if (len < 20 || (memcpy(h, data, 20), h[0] != 0x46546C67u) || h[1] != 2 || h[2] > len ||
        h[4] != 0x4E4F534Au || (size_t)h[3] + 20 > h[2]) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: not a glTF 2.0 binary (glb) file", path);
        goto done;
    }
    g.json = cJSON_ParseWithLength((const char *)data + 20, h[3]);
    if (!g.json) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: its JSON chunk does not parse", path);
        goto done;
    }
    size_t at = 20 + (size_t)h[3];
    if (at + 8 <= h[2]) {
        uint32_t c[2];
        memcpy(c, data + at, 8);
        if (c[1] == 0x004E4942u && at + 8 + c[0] <= h[2]) {
            g.bin = data + at + 8;
            g.bin_len = c[0];
        }
    }
    const cJSON *req;
    cJSON_ArrayForEach(req, cJSON_GetObjectItemCaseSensitive(g.json, "extensionsRequired"))
        if (!cJSON_IsString(req) || (strcmp(req->valuestring, "KHR_mesh_quantization") != 0 &&
                                     strcmp(req->valuestring, "EXT_meshopt_compression") != 0)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: requires extension %s, which is not read", path,
                      cJSON_IsString(req) ? req->valuestring : "?");
            goto done;
        }
    g.view_count = cJSON_GetArraySize(cJSON_GetObjectItemCaseSensitive(g.json, "bufferViews"));
    g.decoded = calloc((size_t)g.view_count + 1, sizeof *g.decoded);
    if (!g.decoded)
        goto done;
    double base[16];
    mat_mul(tile, Y_UP_TO_Z_UP, base);
    const cJSON *scenes = cJSON_GetObjectItemCaseSensitive(g.json, "scenes");
    long si = get_index(g.json, "scene");
    const cJSON *scene = cJSON_GetArrayItem(scenes, si >= 0 ? (int)si : 0);
    ok = 1;
    const cJSON *n;
    if (scene) {
        cJSON_ArrayForEach(n, cJSON_GetObjectItemCaseSensitive(scene, "nodes"))
            if (!cJSON_IsNumber(n) || !add_node(R, &g, (long)n->valuedouble, base, obj, 0)) {
                ok = 0;
                break;
            }
    } else {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: no scene", path);
        ok = 0;
    }
done:
    if (g.decoded)
        for (int v = 0; v < g.view_count; v++)
            free(g.decoded[v]);
    free(g.decoded);
    cJSON_Delete(g.json);
    free(data);
    return ok;
}

/* ---- tileset ---- */

static int read_tileset(rd *R, const char *path, const double parent[16], int depth);

static int add_tile(rd *R, const char *dir, const cJSON *tile, const double parent[16], int depth)
{
    const hlod_logger *lg = R->lg;
    if (depth > 256) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: tiles nested deeper than 256", R->top);
        return 0;
    }
    double local[16], world[16];
    const cJSON *tr = cJSON_GetObjectItemCaseSensitive(tile, "transform");
    if (tr && !get_numbers(tr, local, 16)) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: a tile's transform is not 16 finite numbers", R->top);
        return 0;
    }
    if (!tr)
        memcpy(local, IDENTITY, sizeof local);
    mat_mul(parent, local, world);
    const cJSON *children = cJSON_GetObjectItemCaseSensitive(tile, "children");
    const cJSON *content = cJSON_GetObjectItemCaseSensitive(tile, "content");
    const cJSON *uri = cJSON_GetObjectItemCaseSensitive(content, "uri");
    if (!cJSON_IsString(uri))
        uri = cJSON_GetObjectItemCaseSensitive(content, "url");     /* 3D Tiles 0.0 */
    if (cJSON_GetArraySize(children) > 0) {
        const cJSON *c;
        cJSON_ArrayForEach(c, children)
            if (!add_tile(R, dir, c, world, depth + 1))
                return 0;
        return 1;
    }
    if (!cJSON_IsString(uri))
        return 1;   /* a leaf without content holds nothing */
    char ext[16];
    io_ext(uri->valuestring, ext, sizeof ext);
    char *p = io_join(dir, uri->valuestring);
    if (!p)
        return 0;
    int ok;
    if (!strcmp(ext, "json")) {
        ok = read_tileset(R, p, world, depth + 1);
    } else if (!strcmp(ext, "glb")) {
        /* one object per leaf tile */
        size_t first = R->m->tmat.count;
        ok = read_glb(R, p, world, (long)R->leaves);
        size_t n = R->m->tmat.count - first;
        if (ok && n > 0) {
            hlod_object *o = io_vec_push(&R->m->objs, sizeof *o, 1);
            char name[64];
            snprintf(name, sizeof name, "tile %zu", R->leaves);
            if (!o || !(o->name = io_strdup(name))) {
                ok = 0;
            } else {
                o->first_tri = first;
                o->tri_count = n;
            }
        }
        R->leaves++;
    } else {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: tile content %s: only glb (and external tilesets) "
                  "are read, not '%s'", R->top, p, ext);
        ok = 0;
    }
    free(p);
    return ok;
}

static int read_tileset(rd *R, const char *path, const double parent[16], int depth)
{
    const hlod_logger *lg = R->lg;
    if (depth > MAX_EXTERNAL_DEPTH * 256) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: external tilesets nested too deep", R->top);
        return 0;
    }
    uint8_t *data;
    size_t len;
    if (!read_file(path, &data, &len, lg))
        return 0;
    cJSON *j = cJSON_ParseWithLength((const char *)data, len);
    free(data);
    const cJSON *root = cJSON_GetObjectItemCaseSensitive(j, "root");
    if (!j || !cJSON_IsObject(cJSON_GetObjectItemCaseSensitive(j, "asset")) || !root) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: not a 3D Tiles tileset (no asset or root)", path);
        cJSON_Delete(j);
        return 0;
    }
    char *dir = io_dirname(path);
    int ok = dir && add_tile(R, dir, root, parent, depth);
    free(dir);
    cJSON_Delete(j);
    return ok;
}

hlod_result io_read_tileset(const char *path, const char *scratch, const hlod_logger *lg,
                            hlod_mesh *out, hlod_import_stats *st)
{
    acc_mesh M = {0};
    rd R = {path, scratch, lg, &M, st, 0};
    int ok = read_tileset(&R, path, IDENTITY, 0);
    if (ok && M.tmat.count == 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: no triangles in its leaf tiles", path);
        ok = 0;
    }
    hlod_result r = ok ? HLOD_OK : HLOD_ERR_FORMAT;
    if (ok) {
        out->vertex_count = M.pos.count;
        out->tri_count = M.tmat.count;
        out->positions = io_vec_take(&M.pos, 3 * sizeof(double));
        out->normals = M.any_normals ? io_vec_take(&M.nrm, 3 * sizeof(float)) : NULL;
        out->uvs = M.any_uvs ? io_vec_take(&M.uv, 2 * sizeof(float)) : NULL;
        out->indices = io_vec_take(&M.idx, sizeof(uint32_t));
        out->tri_material = io_vec_take(&M.tmat, sizeof(uint32_t));
        out->material_count = M.mats.count;
        out->materials = io_vec_take(&M.mats, sizeof(hlod_material));
        out->object_count = M.objs.count;
        out->objects = io_vec_take(&M.objs, sizeof(hlod_object));
        if (!out->positions || !out->indices || !out->tri_material || !out->materials ||
            (M.any_normals && !out->normals) || (M.any_uvs && !out->uvs)) {
            hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory", path);
            r = HLOD_ERR_NOMEM;
        }
    } else {
        hlod_material *mats = M.mats.data;
        for (size_t i = 0; i < M.mats.count; i++) {
            free(mats[i].name);
            free(mats[i].texture_path);
        }
        hlod_object *objs = M.objs.data;
        for (size_t i = 0; i < M.objs.count; i++)
            free(objs[i].name);
    }
    io_vec_free(&M.pos);
    io_vec_free(&M.nrm);
    io_vec_free(&M.uv);
    io_vec_free(&M.idx);
    io_vec_free(&M.tmat);
    io_vec_free(&M.mats);
    io_vec_free(&M.objs);
    return r;
}
