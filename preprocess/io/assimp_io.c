/*
 * Import through assimp's C API: glTF 2.0 (.gltf/.glb) and every other
 * format assimp knows that we have no reader of our own for.
 *
 * aiProcess_PreTransformVertices would bake node transforms in 32-bit
 * floats; instead the node tree is walked here with transforms composed in
 * double, and each node that holds meshes becomes one hlod_object named
 * after the node.  Vertex data itself is float in Debian's assimp, so these
 * formats carry float precision; our OBJ/PLY/OFF readers do not.
 *
 * assimp keeps the last error in a process-wide string, so imports are
 * serialised by a mutex to keep that message matched to its file.
 */
#include "io_internal.h"

#include <assimp/cimport.h>
#include <assimp/material.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>
#include <math.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

static pthread_mutex_t assimp_lock = PTHREAD_MUTEX_INITIALIZER;

int io_assimp_knows(const char *ext)
{
    char dotted[20];
    snprintf(dotted, sizeof dotted, ".%s", ext);
    return aiIsExtensionSupported(dotted) == AI_TRUE;
}

typedef struct walker {
    const char *path;
    const hlod_logger *lg;
    const struct aiScene *sc;
    io_vec pos, nrm, uv, idx, mat, objects;
    int any_n, any_uv;
    size_t unnamed;
} walker;

typedef struct dmat {
    double m[4][4];
} dmat;

static dmat mul(const dmat *a, const dmat *b)
{
    dmat r;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++) {
            double s = 0;
            for (int k = 0; k < 4; k++)
                s += a->m[i][k] * b->m[k][j];
            r.m[i][j] = s;
        }
    return r;
}

static dmat from_ai(const struct aiMatrix4x4 *t)
{
    dmat r = {{{t->a1, t->a2, t->a3, t->a4},
               {t->b1, t->b2, t->b3, t->b4},
               {t->c1, t->c2, t->c3, t->c4},
               {t->d1, t->d2, t->d3, t->d4}}};
    return r;
}

static hlod_result add_mesh(walker *w, const struct aiMesh *am, const dmat *M)
{
    size_t base = w->pos.count;
    if (base + am->mNumVertices >= UINT32_MAX)
        return HLOD_ERR_UNSUPPORTED;
    double *P = io_vec_push(&w->pos, sizeof(double[3]), am->mNumVertices);
    float *N = io_vec_push(&w->nrm, sizeof(float[3]), am->mNumVertices);
    float *T = io_vec_push(&w->uv, sizeof(float[2]), am->mNumVertices);
    if (!P || !N || !T)
        return HLOD_ERR_NOMEM;
    const double(*m)[4] = M->m;
    /* Normals go through the cofactor matrix (the inverse transpose up to
     * det), signed so a mirroring node does not turn them inside out. */
    double c[3][3];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            int i1 = (i + 1) % 3, i2 = (i + 2) % 3, j1 = (j + 1) % 3, j2 = (j + 2) % 3;
            c[i][j] = m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1];
        }
    double det = m[0][0] * c[0][0] + m[0][1] * c[0][1] + m[0][2] * c[0][2];
    double sgn = det < 0 ? -1 : 1;
    for (unsigned v = 0; v < am->mNumVertices; v++) {
        const struct aiVector3D *p = &am->mVertices[v];
        for (int i = 0; i < 3; i++)
            P[3 * v + i] = m[i][0] * p->x + m[i][1] * p->y + m[i][2] * p->z + m[i][3];
        if (am->mNormals) {
            const struct aiVector3D *n = &am->mNormals[v];
            double t[3], len = 0;
            for (int i = 0; i < 3; i++) {
                t[i] = sgn * (c[i][0] * n->x + c[i][1] * n->y + c[i][2] * n->z);
                len += t[i] * t[i];
            }
            len = len > 0 ? 1.0 / sqrt(len) : 0;
            for (int i = 0; i < 3; i++)
                N[3 * v + i] = (float)(t[i] * len);
        } else {
            N[3 * v] = N[3 * v + 1] = N[3 * v + 2] = 0;
        }
        if (am->mTextureCoords[0]) {
            T[2 * v] = am->mTextureCoords[0][v].x;
            T[2 * v + 1] = am->mTextureCoords[0][v].y;
        } else {
            T[2 * v] = T[2 * v + 1] = 0;
        }
    }
    w->any_n |= am->mNormals != NULL;
    w->any_uv |= am->mTextureCoords[0] != NULL;
    for (unsigned f = 0; f < am->mNumFaces; f++) {
        const struct aiFace *fc = &am->mFaces[f];
        if (fc->mNumIndices != 3)
            continue; /* points and lines */
        uint32_t *t = io_vec_push(&w->idx, sizeof(uint32_t), 3);
        uint32_t *tm = io_vec_push(&w->mat, sizeof(uint32_t), 1);
        if (!t || !tm)
            return HLOD_ERR_NOMEM;
        for (int k = 0; k < 3; k++) {
            if (fc->mIndices[k] >= am->mNumVertices) {
                hlod_logf(w->lg, HLOD_LOG_ERROR,
                          "%s: mesh %s: face %u: vertex index %u out of range (%u vertices)",
                          w->path, am->mName.data, f, fc->mIndices[k], am->mNumVertices);
                return HLOD_ERR_INDEX_RANGE;
            }
            t[k] = (uint32_t)(base + fc->mIndices[k]);
        }
        if (det < 0) {
            uint32_t s = t[1];
            t[1] = t[2];
            t[2] = s;
        }
        *tm = am->mMaterialIndex;
    }
    return HLOD_OK;
}

static hlod_result walk(walker *w, const struct aiNode *node, const dmat *parent, int depth)
{
    if (depth > 1000) {
        hlod_logf(w->lg, HLOD_LOG_ERROR, "%s: node tree deeper than 1000 levels", w->path);
        return HLOD_ERR_FORMAT;
    }
    dmat local = from_ai(&node->mTransformation);
    dmat M = mul(parent, &local);
    size_t first = w->mat.count;
    for (unsigned i = 0; i < node->mNumMeshes; i++) {
        if (node->mMeshes[i] >= w->sc->mNumMeshes) {
            hlod_logf(w->lg, HLOD_LOG_ERROR, "%s: node %s: mesh %u out of range", w->path,
                      node->mName.data, node->mMeshes[i]);
            return HLOD_ERR_INDEX_RANGE;
        }
        hlod_result res = add_mesh(w, w->sc->mMeshes[node->mMeshes[i]], &M);
        if (res)
            return res;
    }
    if (w->mat.count > first) {
        hlod_object *o = io_vec_push(&w->objects, sizeof(hlod_object), 1);
        if (!o)
            return HLOD_ERR_NOMEM;
        o->first_tri = first;
        o->tri_count = w->mat.count - first;
        if (node->mName.length) {
            o->name = io_strdup(node->mName.data);
        } else {
            char buf[32];
            snprintf(buf, sizeof buf, "node%zu", w->unnamed++);
            o->name = io_strdup(buf);
        }
        if (!o->name)
            return HLOD_ERR_NOMEM;
    }
    for (unsigned i = 0; i < node->mNumChildren; i++) {
        hlod_result res = walk(w, node->mChildren[i], &M, depth + 1);
        if (res)
            return res;
    }
    return HLOD_OK;
}

static int hexval(char c)
{
    return c >= '0' && c <= '9' ? c - '0'
           : c >= 'a' && c <= 'f' ? c - 'a' + 10
           : c >= 'A' && c <= 'F' ? c - 'A' + 10
                                  : -1;
}

/* glTF image URIs are percent-encoded; assimp hands them over raw. */
static void uri_decode(char *s)
{
    char *w = s;
    for (char *r = s; *r; r++) {
        if (r[0] == '%' && hexval(r[1]) >= 0 && hexval(r[2]) >= 0) {
            *w++ = (char)(hexval(r[1]) * 16 + hexval(r[2]));
            r += 2;
        } else {
            *w++ = *r;
        }
    }
    *w = '\0';
}

static hlod_result read_materials(walker *w, hlod_mesh *m, const char *dir,
                                  hlod_import_stats *st)
{
    const struct aiScene *sc = w->sc;
    if (!sc->mNumMaterials)
        return HLOD_OK;
    m->materials = calloc(sc->mNumMaterials, sizeof *m->materials);
    if (!m->materials)
        return HLOD_ERR_NOMEM;
    m->material_count = sc->mNumMaterials;
    for (unsigned i = 0; i < sc->mNumMaterials; i++) {
        const struct aiMaterial *am = sc->mMaterials[i];
        hlod_material *mt = &m->materials[i];
        struct aiString name;
        if (aiGetMaterialString(am, AI_MATKEY_NAME, &name) == aiReturn_SUCCESS && name.length &&
            !(mt->name = io_strdup(name.data)))
            return HLOD_ERR_NOMEM;
        struct aiColor4D c;
        if (aiGetMaterialColor(am, AI_MATKEY_COLOR_DIFFUSE, &c) == aiReturn_SUCCESS ||
            aiGetMaterialColor(am, AI_MATKEY_BASE_COLOR, &c) == aiReturn_SUCCESS) {
            mt->diffuse[0] = c.r;
            mt->diffuse[1] = c.g;
            mt->diffuse[2] = c.b;
            mt->diffuse[3] = c.a;
        } else {
            mt->diffuse[0] = mt->diffuse[1] = mt->diffuse[2] = 0.8f;
            mt->diffuse[3] = 1;
        }
        struct aiString tex;
        if (aiGetMaterialTexture(am, aiTextureType_DIFFUSE, 0, &tex, NULL, NULL, NULL, NULL, NULL,
                                 NULL) != aiReturn_SUCCESS &&
            aiGetMaterialTexture(am, aiTextureType_BASE_COLOR, 0, &tex, NULL, NULL, NULL, NULL,
                                 NULL, NULL) != aiReturn_SUCCESS)
            continue;
        if (!tex.length)
            continue;
        if (tex.data[0] == '*' || strncmp(tex.data, "data:", 5) == 0) {
            /* Embedded images would have to be written out somewhere to be
             * used as files; the material keeps its colour instead, and
             * counts as missing a texture so callers can tell. */
            hlod_logf(w->lg, HLOD_LOG_WARN,
                      "%s: material %u (%s): embedded texture %s is not supported; untextured",
                      w->path, i, mt->name ? mt->name : "unnamed", tex.data);
            st->missing_textures++;
            continue;
        }
        for (char *p = tex.data; *p; p++)
            if (*p == '\\')
                *p = '/';
        char *full = io_join(dir, tex.data);
        if (!full)
            return HLOD_ERR_NOMEM;
        if (!io_file_exists(full) && strchr(tex.data, '%')) {
            uri_decode(tex.data);
            char *dec = io_join(dir, tex.data);
            if (dec && io_file_exists(dec)) {
                free(full);
                full = dec;
            } else {
                free(dec);
            }
        }
        mt->texture_path = full;
    }
    return HLOD_OK;
}

hlod_result io_read_assimp(const char *path, const hlod_logger *lg, hlod_mesh *out,
                           hlod_import_stats *st)
{
    hlod_mesh_free(out);
    unsigned flags = aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                     aiProcess_SortByPType | aiProcess_ValidateDataStructure;
    pthread_mutex_lock(&assimp_lock);
    const struct aiScene *sc = aiImportFile(path, flags);
    if (!sc) {
        const char *why = aiGetErrorString();
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: assimp cannot read it: %s", path,
                  why && *why ? why : "unknown error");
        pthread_mutex_unlock(&assimp_lock);
        return HLOD_ERR_FORMAT;
    }
    pthread_mutex_unlock(&assimp_lock);

    walker w;
    memset(&w, 0, sizeof w);
    w.path = path;
    w.lg = lg;
    w.sc = sc;
    dmat id = {{{1, 0, 0, 0}, {0, 1, 0, 0}, {0, 0, 1, 0}, {0, 0, 0, 1}}};
    hlod_result res = HLOD_OK;
    if (!sc->mRootNode) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: scene has no root node", path);
        res = HLOD_ERR_FORMAT;
    }
    if (res == HLOD_OK)
        res = walk(&w, sc->mRootNode, &id, 0);
    if (res == HLOD_ERR_UNSUPPORTED)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: more vertices than 32-bit indices address", path);
    if (res == HLOD_OK && w.idx.count == 0) {
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: no triangles", path);
        res = HLOD_ERR_EMPTY;
    }
    char *dir = res == HLOD_OK ? io_dirname(path) : NULL;
    if (res == HLOD_OK && !dir)
        res = HLOD_ERR_NOMEM;
    if (res == HLOD_OK) {
        out->vertex_count = w.pos.count;
        out->tri_count = w.mat.count;
        out->positions = io_vec_take(&w.pos, sizeof(double[3]));
        out->indices = io_vec_take(&w.idx, sizeof(uint32_t));
        out->tri_material = io_vec_take(&w.mat, sizeof(uint32_t));
        if (w.any_n)
            out->normals = io_vec_take(&w.nrm, sizeof(float[3]));
        if (w.any_uv)
            out->uvs = io_vec_take(&w.uv, sizeof(float[2]));
        out->object_count = w.objects.count;
        out->objects = io_vec_take(&w.objects, sizeof(hlod_object));
        if (!out->positions || !out->indices || !out->tri_material ||
            (w.any_n && !out->normals) || (w.any_uv && !out->uvs) || !out->objects)
            res = HLOD_ERR_NOMEM;
    }
    if (res == HLOD_OK)
        res = read_materials(&w, out, dir, st);
    if (res == HLOD_OK && !out->material_count) {
        free(out->tri_material);
        out->tri_material = NULL;
    }
    if (res == HLOD_ERR_NOMEM)
        hlod_logf(lg, HLOD_LOG_ERROR, "%s: out of memory", path);
    if (res)
        hlod_mesh_free(out);
    else if (st)
        st->tris_read = out->tri_count;
    hlod_object *objs = w.objects.data;
    for (size_t i = 0; i < w.objects.count; i++)
        free(objs[i].name);
    io_vec_free(&w.objects);
    io_vec_free(&w.pos);
    io_vec_free(&w.nrm);
    io_vec_free(&w.uv);
    io_vec_free(&w.idx);
    io_vec_free(&w.mat);
    free(dir);
    aiReleaseImport(sc);
    return res;
}
