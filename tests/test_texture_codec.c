/*
 * test_texture_codec.c - block-coded textures (store format 5,
 * docs/store-format.md "Block-coded textures"; engine/common/
 * texture_codec.h, payload_codec.c): the chain's layout, what each way of
 * reading a block-coded texture gives back (level 0 texels, the texel
 * chain, the blocks) and that they agree, the quality guard's choice
 * between blocks, JPEG and raw with the PSNR it records, and forged or
 * damaged texture sections refused.
 */
#include "check.h"
#include "payload_codec.h"
#include "texture_codec.h"

#include <math.h>
#include <stdint.h>
#include <zstd.h>

static char g_log[4096];

static void log_fn(void *user, hlod_log_level level, const char *msg)
{
    (void)user;
    (void)level;
    snprintf(g_log, sizeof g_log, "%s", msg);
}
static const hlod_logger LG = {log_fn, NULL};

/* One textured triangle with a w x h texture of c channels. */
typedef struct tri_node {
    int64_t grid[9];
    float uv[6];
    uint32_t idx[3];
    uint8_t *px;
    hlod_packed_input in;
    hlod_store_node node;
    hlod_store_header h;
} tri_node;

/* kind 0: smooth waves; 1: noise (xorshift); 2: noise blurred a little */
static void make_node(tri_node *t, uint32_t w, uint32_t h, uint32_t c, int kind)
{
    memset(t, 0, sizeof *t);
    const int64_t g[9] = {0, 0, 0, 64, 0, 0, 0, 64, 0};
    memcpy(t->grid, g, sizeof g);
    const float uv[6] = {0, 0, 1, 0, 0, 1};
    memcpy(t->uv, uv, sizeof uv);
    t->idx[1] = 1;
    t->idx[2] = 2;
    t->px = malloc((size_t)w * h * c);
    uint32_t s = 2463534242u;
    for (uint32_t y = 0; y < h; y++)
        for (uint32_t x = 0; x < w; x++)
            for (uint32_t k = 0; k < c; k++) {
                s ^= s << 13;
                s ^= s >> 17;
                s ^= s << 5;
                double v = 128 + 90 * sin(0.11 * x + 0.07 * y + 1.3 * k);
                if (kind == 1)
                    v = s & 255;
                else if (kind == 2)
                    v = v * 0.7 + (double)(s & 63);
                t->px[((size_t)y * w + x) * c + k] = (uint8_t)v;
            }
    t->in = (hlod_packed_input){
        .flags = HLOD_NODE_UVS | HLOD_NODE_TEXTURE, .vertex_count = 3, .tri_count = 1,
        .tex_tri_count = 1, .grid = t->grid, .uvs = t->uv, .indices = t->idx,
        .tex_width = w, .tex_height = h, .tex_channels = c, .pixels = t->px,
        .jpeg_quality = 90, .texture_blocks = 1, .texture_min_db = 0,
    };
    t->node.flags = t->in.flags;
    t->node.vertex_count = 3;
    t->node.tri_count = 1;
    t->node.tex_tri_count = 1;
    t->node.tex_width = w;
    t->node.tex_height = h;
    t->node.tex_channels = c;
    t->h.version = HLOD_STORE_VERSION;
    t->h.quant_step = 1.0 / 64;
}

static const uint8_t *texture_section(const uint8_t *buf, hlod_store_packed_header *ph)
{
    memcpy(ph, buf, sizeof *ph);
    size_t at = sizeof *ph;
    for (int k = 0; k < HLOD_SEC_TEXTURE; k++)
        at += ph->section_bytes[k];
    return buf + at;
}

/* The decoder against libsquish's, byte for byte, on random blocks of
 * both BC1 modes and both BC4 modes, and an edge block cut to 3x2. */
static void decoder_matches_libsquish(void)
{
    uint32_t s = 88172645u;
    int bc1_same = 1, bc4_same = 1, modes[4] = {0};
    for (int n = 0; n < 20000; n++) {
        uint8_t b[8], ref[64], ours[16 * 4], grey[16];
        for (int k = 0; k < 8; k++) {
            s ^= s << 13;
            s ^= s >> 17;
            s ^= s << 5;
            b[k] = (uint8_t)(s >> 8);
        }
        if (n % 7 == 0)
            b[2] = b[0], b[3] = b[1];   /* equal end points: three-colour mode */
        modes[(b[0] | b[1] << 8) > (b[2] | b[3] << 8)]++;
        modes[2 + (b[0] > b[1])]++;
        hlod_bc_decode_block(b, 0, ref);
        hlod_bc_decode_level(b, 4, 4, 3, ours, 4);
        for (int j = 0; j < 16; j++)
            bc1_same &= !memcmp(ref + 4 * j, ours + 4 * j, 3);
        hlod_bc_decode_block(b, 1, ref);
        hlod_bc_decode_level(b, 4, 4, 1, grey, 1);
        for (int j = 0; j < 16; j++)
            bc4_same &= ref[4 * j] == grey[j];
    }
    CHECK(bc1_same && bc4_same);
    CHECK(modes[0] > 1000 && modes[1] > 1000 && modes[2] > 1000 && modes[3] > 1000);
    /* an edge block: only its 3x2 texels are written */
    uint8_t b[8] = {0x1f, 0xf8, 0xe0, 0x07, 0x1b, 0x6c, 0xb1, 0x4e}, ref[64], out[3 * 2 * 3 + 1];
    out[sizeof out - 1] = 0xab;
    hlod_bc_decode_block(b, 0, ref);
    hlod_bc_decode_level(b, 3, 2, 3, out, 3);
    int same = out[sizeof out - 1] == 0xab;
    for (int y = 0; y < 2; y++)
        for (int x = 0; x < 3; x++)
            same &= !memcmp(out + 3 * (3 * y + x), ref + 4 * (4 * y + x), 3);
    CHECK(same);
}

static void chain_layout(void)
{
    CHECK(hlod_tex_level_count(1, 1) == 1);
    CHECK(hlod_tex_level_count(13, 7) == 4);       /* 13x7 6x3 3x1 1x1 */
    CHECK(hlod_tex_level_count(1024, 1) == 11);
    uint32_t lw, lh;
    hlod_tex_level_size(13, 7, 2, &lw, &lh);
    CHECK(lw == 3 && lh == 1);
    hlod_tex_level_size(13, 7, 3, &lw, &lh);
    CHECK(lw == 1 && lh == 1);
    /* blocks: 4x2, 2x1, 1x1, 1x1 */
    CHECK(hlod_bc_chain_bytes(13, 7) == (8 + 2 + 1 + 1) * HLOD_BC_BLOCK_BYTES);
    CHECK(hlod_bc_chain_bytes(0, 7) == 0);
    uint8_t *b = NULL;
    size_t n = 0;
    uint8_t px[3] = {1, 2, 3};
    CHECK(hlod_bc_encode_chain(px, 1, 1, 2, &b, &n) == HLOD_ERR_INVALID_ARG && !b);
    CHECK(hlod_bc_encode_chain(px, 1, 1, 3, &b, &n) == HLOD_OK && n == 8);
    free(b);
}

/* Every way out of one block-coded payload: PIXELS level 0 = CHAIN level 0
 * (RGB of RGBA), every CHAIN level = the BLOCKS level decoded, level l
 * close to the box-filtered source, the recorded PSNR the one of level 0. */
static void ways_out_agree_one(uint32_t w, uint32_t h, uint32_t c)
{
    tri_node t;
    make_node(&t, w, h, c, 0);
    uint8_t *buf = NULL;
    size_t size = 0;
    hlod_packed_info info;
    CHECK(hlod_payload_pack(&t.in, &buf, &size, &info, "t", &LG) == HLOD_OK);
    CHECKF(info.tex_codec == HLOD_TEX_BC, "%ux%ux%u: codec %u", w, h, c, info.tex_codec);
    hlod_unpacked u[3];
    for (int m = 0; m < 3; m++)
        CHECKF(hlod_payload_unpack(buf, size, &t.node, 0, &t.h, m, &u[m], "t", &LG) == HLOD_OK,
               "%ux%ux%u mode %d: %s", w, h, c, m, g_log);
    const size_t texels = (size_t)w * h * c;
    const uint32_t levels = hlod_tex_level_count(w, h), oc = c == 3 ? 4 : 1;
    CHECK(u[0].tex == NULL && u[0].raw_size == hlod_store_node_memory(&t.node));
    CHECK(u[1].raw_size + texels == u[0].raw_size && u[2].raw_size == u[1].raw_size);
    CHECK(u[1].tex_levels == levels && u[1].tex_format == HLOD_TEXFMT_TEXELS &&
          u[1].tex_channels == oc);
    CHECK(u[2].tex_levels == levels && u[2].tex_format == HLOD_TEXFMT_BC &&
          u[2].tex_channels == c);
    const uint8_t *l0 = u[0].raw + u[0].raw_size - texels;
    double db = hlod_tex_psnr(t.px, l0, texels);
    CHECKF(fabs(db - info.tex_db) < 1e-3 && db >= 35, "%ux%ux%u: %.3f dB, recorded %.3f", w, h,
           c, db, info.tex_db);
    int same0 = 1, chain_is_blocks = 1, alpha = 1;
    for (size_t i = 0; i < (size_t)w * h; i++)
        for (uint32_t k = 0; k < oc; k++) {
            uint8_t v = u[1].tex[i * oc + k];
            if (k < c)
                same0 &= v == l0[i * c + k];
            else
                alpha &= v == 255;
        }
    /* the box-filtered source next to each level */
    uint8_t *src = malloc(texels), *next = malloc(texels), *dec = malloc((size_t)w * h * oc);
    memcpy(src, t.px, texels);
    const uint8_t *blocks = u[2].tex, *chain = u[1].tex;
    int same_as_own = 1;
    for (uint32_t l = 0; l < levels; l++) {
        uint32_t lw, lh;
        hlod_tex_level_size(w, h, l, &lw, &lh);
        hlod_bc_decode_level(blocks, lw, lh, c, dec, oc);
        chain_is_blocks &= !memcmp(dec, chain, (size_t)lw * lh * oc);
        /* level l is the blocks of the box-filtered source's level l: coding
         * that level alone gives the same texels */
        uint8_t *own = NULL;
        size_t own_n = 0;
        CHECK(hlod_bc_encode_chain(src, lw, lh, c, &own, &own_n) == HLOD_OK);
        if (own) {
            hlod_bc_decode_level(own, lw, lh, c, dec, oc);
            same_as_own &= !memcmp(dec, chain, (size_t)lw * lh * oc);
        }
        free(own);
        blocks += (size_t)((lw + 3) / 4) * ((lh + 3) / 4) * HLOD_BC_BLOCK_BYTES;
        chain += (size_t)lw * lh * oc;
        hlod_tex_downsample(src, lw, lh, next, c);
        uint8_t *tmp = src;
        src = next;
        next = tmp;
    }
    CHECKF(same0 && alpha && chain_is_blocks, "%ux%ux%u: level 0 %d, alpha %d, chain %d", w, h,
           c, same0, alpha, chain_is_blocks);
    CHECKF(same_as_own, "%ux%ux%u: a level is not the filtered source's blocks", w, h, c);
    CHECK((size_t)(blocks - u[2].tex) == hlod_bc_chain_bytes(w, h));
    free(src);
    free(next);
    free(dec);
    for (int m = 0; m < 3; m++) {
        free(u[m].raw);
        free(u[m].tex);
    }
    free(buf);
    free(t.px);
}

static void ways_out_agree(void)
{
    ways_out_agree_one(64, 32, 3);
    ways_out_agree_one(13, 7, 3);     /* edge blocks padded */
    ways_out_agree_one(1, 1, 3);
    ways_out_agree_one(40, 24, 1);    /* BC4 */
    ways_out_agree_one(5, 3, 1);
}

/* The guard: blocks over the floor; under it JPEG where JPEG is closer,
 * raw without JPEG, the blocks where JPEG is no closer. */
static uint32_t pack_codec(tri_node *t, double min_db, int quality, int blocks, double *db)
{
    t->in.texture_min_db = min_db;
    t->in.jpeg_quality = quality;
    t->in.texture_blocks = blocks;
    uint8_t *buf = NULL;
    size_t size = 0;
    hlod_packed_info info = {99, -1};
    hlod_result r = hlod_payload_pack(&t->in, &buf, &size, &info, "t", &LG);
    CHECK(r == HLOD_OK);
    hlod_store_packed_header ph;
    if (buf)
        texture_section(buf, &ph);
    CHECK(buf && ph.tex_codec == info.tex_codec && ph.tex_db == (float)info.tex_db);
    /* what a reader gets back is as far from the source as recorded */
    hlod_unpacked u;
    if (r == HLOD_OK && hlod_payload_unpack(buf, size, &t->node, 0, &t->h, HLOD_TEXOUT_PIXELS, &u,
                                            "t", &LG) == HLOD_OK) {
        size_t n = (size_t)t->in.tex_width * t->in.tex_height * t->in.tex_channels;
        double got = hlod_tex_psnr(t->px, u.raw + u.raw_size - n, n);
        CHECKF(info.tex_db == 0 ? info.tex_codec != HLOD_TEX_BC : fabs(got - info.tex_db) < 1e-3,
               "codec %u: recorded %.3f dB, read back %.3f", info.tex_codec, info.tex_db, got);
        free(u.raw);
    } else {
        CHECK(0);
    }
    free(buf);
    *db = info.tex_db;
    return info.tex_codec;
}

static void guard_chooses(void)
{
    tri_node t;
    double db_bc, db_jpeg, db;
    make_node(&t, 64, 64, 3, 2);
    CHECK(pack_codec(&t, 0, 90, 1, &db_bc) == HLOD_TEX_BC);
    CHECKF(db_bc > 20 && db_bc < 38, "noisy texture's blocks: %.2f dB", db_bc);
    /* under the floor: JPEG q90 comes closer on noise */
    CHECK(pack_codec(&t, 38, 90, 1, &db_jpeg) == HLOD_TEX_JPEG);
    CHECKF(db_jpeg > db_bc, "JPEG %.2f dB, blocks %.2f", db_jpeg, db_bc);
    /* a JPEG that does worse than the blocks: the blocks stay */
    CHECK(pack_codec(&t, 99, 5, 1, &db) == HLOD_TEX_BC && db == db_bc);
    /* no JPEG: raw, exact, unmeasured */
    CHECK(pack_codec(&t, 38, 0, 1, &db) == HLOD_TEX_RAW && db == 0);
    /* blocks off: JPEG, unmeasured, as before version 5 */
    CHECK(pack_codec(&t, 38, 90, 0, &db) == HLOD_TEX_JPEG && db == 0);
    free(t.px);
    /* 2 or 4 channels never become blocks */
    make_node(&t, 8, 8, 4, 0);
    t.node.tex_channels = 4;
    CHECK(pack_codec(&t, 0, 90, 1, &db) == HLOD_TEX_RAW);
    free(t.px);
}

/* A damaged or forged texture section is HLOD_ERR_FORMAT, never a crash. */
static void damage(const char *what, tri_node *t, const uint8_t *good, size_t size,
                   void (*mutate)(uint8_t *p, size_t n), uint32_t version)
{
    uint8_t *p = malloc(size);
    memcpy(p, good, size);
    mutate(p, size);
    t->h.version = version;
    for (int m = 0; m < 3; m++) {
        hlod_unpacked u;
        g_log[0] = 0;
        hlod_result r = hlod_payload_unpack(p, size, &t->node, 7, &t->h, m, &u, "f.hlod", &LG);
        CHECKF(r == HLOD_ERR_FORMAT && strstr(g_log, "f.hlod: node 7") && !u.raw && !u.tex,
               "%s, mode %d: %s (%s)", what, m, hlod_result_str(r), g_log);
    }
    t->h.version = HLOD_STORE_VERSION;
    free(p);
}

static void m_levels(uint8_t *p, size_t n)
{
    (void)n;
    hlod_store_packed_header ph;
    memcpy(&ph, p, sizeof ph);
    ph.tex_levels++;
    memcpy(p, &ph, sizeof ph);
}
static void m_frame_magic(uint8_t *p, size_t n)
{
    hlod_store_packed_header ph;
    uint8_t *t = (uint8_t *)texture_section(p, &ph);
    (void)n;
    t[0] ^= 0x55;
}
static void m_db_nan(uint8_t *p, size_t n)
{
    (void)n;
    float nan = NAN;
    memcpy(p + 92, &nan, 4);
}
static void m_codec_3(uint8_t *p, size_t n)
{
    (void)n;
    p[44] = 3;
}
static void m_none(uint8_t *p, size_t n)
{
    (void)p;
    (void)n;
}

static void damaged_refused(void)
{
    tri_node t;
    make_node(&t, 32, 16, 3, 0);
    uint8_t *buf = NULL;
    size_t size = 0;
    CHECK(hlod_payload_pack(&t.in, &buf, &size, NULL, "t", &LG) == HLOD_OK);
    damage("levels", &t, buf, size, m_levels, HLOD_STORE_VERSION);
    damage("zstd magic", &t, buf, size, m_frame_magic, HLOD_STORE_VERSION);
    damage("PSNR NaN", &t, buf, size, m_db_nan, HLOD_STORE_VERSION);
    damage("codec 3", &t, buf, size, m_codec_3, HLOD_STORE_VERSION);
    damage("blocks in a version 4 store", &t, buf, size, m_none, 4);

    /* a frame holding one byte less than the chain */
    hlod_store_packed_header ph;
    const uint8_t *sec = texture_section(buf, &ph);
    size_t chain = hlod_bc_chain_bytes(32, 16);
    uint8_t *blocks = malloc(chain);
    CHECK(ZSTD_decompress(blocks, chain, sec, ph.section_bytes[HLOD_SEC_TEXTURE]) == chain);
    uint8_t z[4096];
    size_t zn = ZSTD_compress(z, sizeof z, blocks, chain - 1, 3);
    CHECK(!ZSTD_isError(zn));
    size_t head = (size_t)(sec - buf);
    uint8_t *f = malloc(head + zn);
    memcpy(f, buf, head);
    memcpy(f + head, z, zn);
    ph.section_bytes[HLOD_SEC_TEXTURE] = (uint32_t)zn;
    memcpy(f, &ph, sizeof ph);
    hlod_unpacked u;
    CHECKF(hlod_payload_unpack(f, head + zn, &t.node, 7, &t.h, HLOD_TEXOUT_BLOCKS, &u, "f.hlod",
                               &LG) == HLOD_ERR_FORMAT && strstr(g_log, "chain"), "%s", g_log);
    /* the truncated frame (its last bytes cut, sections sized to match) */
    ph.section_bytes[HLOD_SEC_TEXTURE] = (uint32_t)zn - 3;
    memcpy(f, &ph, sizeof ph);
    CHECKF(hlod_payload_unpack(f, head + zn - 3, &t.node, 7, &t.h, HLOD_TEXOUT_CHAIN, &u,
                               "f.hlod", &LG) == HLOD_ERR_FORMAT, "%s", g_log);
    free(f);
    free(blocks);
    free(buf);
    free(t.px);
}

int main(void)
{
    RUN(chain_layout);
    RUN(decoder_matches_libsquish);
    RUN(ways_out_agree);
    RUN(guard_chooses);
    RUN(damaged_refused);
    return check_done();
}
