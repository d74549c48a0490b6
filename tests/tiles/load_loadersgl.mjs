// load_loadersgl.mjs - a second reader of the export, independent of the
// browser: loaders.gl (npm @loaders.gl/core + @loaders.gl/3d-tiles, whose
// glTF parser is @loaders.gl/gltf) loads tileset.json and every tile's
// content over HTTP from our loopback server (serve.mjs: loaders.gl's node
// fetch reads URLs, not files), as a web client would, resolving each
// content URL itself.
//
//   node tests/tiles/load_loadersgl.mjs TILESET_DIR
//
// For every tile with content: the glb loads and parses (KHR_mesh_quantization
// and EXT_meshopt_compression are decoded by loaders.gl), every primitive has
// a POSITION accessor whose data holds count x size values, its indices
// lie below the vertex count, and every image's bytes carry a PNG or JPEG
// header with a non-zero size (@loaders.gl/images getBinaryImageMetadata;
// pixels are not decoded: loaders.gl decodes images in node only with
// @loaders.gl/polyfills, not installed; the browser test decodes them all).
// Prints one line per failure (the first 10), then
//   loaders.gl: N tiles, C contents, T triangles (L in leaves, F leaves), I images, M ms
// and last a JSON line {"tiles","contents","leaves","triangles",
// "leaf_triangles","images","ms"} for the caller.  Exit 0 when every
// content loaded and parsed, 1 otherwise, 2 on bad usage or a missing
// package (npm ci).
import fs from 'node:fs';
import { startServer } from './serve.mjs';

let load, Tiles3DLoader, getBinaryImageMetadata;
try {
    ({ load } = await import('@loaders.gl/core'));
    ({ Tiles3DLoader } = await import('@loaders.gl/3d-tiles'));
    ({ getBinaryImageMetadata } = await import('@loaders.gl/images'));
} catch (e) {
    console.error('load_loadersgl: the npm packages @loaders.gl/core, @loaders.gl/3d-tiles and @loaders.gl/images ' +
        'are not installed (run npm ci): ' + e.message);
    process.exit(2);
}

const dir = process.argv[2];
if (!dir || !fs.existsSync(dir + '/tileset.json')) {
    console.error('usage: node load_loadersgl.mjs TILESET_DIR (holding tileset.json)');
    process.exit(2);
}

const t0 = performance.now();
const server = await startServer({ '/tiles/': dir });
const failures = [];
let tiles = 0, contents = 0, leaves = 0, tris = 0, leafTris = 0, images = 0;
try {
    const ts = await load(`${server.url}/tiles/tileset.json`, Tiles3DLoader, { '3d-tiles': { isTileset: true } });
    const all = [];
    const walk = (t, path) => {
        tiles++;
        const kids = t.children ?? [];
        if (kids.length === 0) leaves++;
        if (t.contentUrl) all.push({ t, path, leaf: kids.length === 0 });
        kids.forEach((c, i) => walk(c, `${path}/children/${i}`));
    };
    walk(ts.root, '/root');
    contents = all.length;

    const one = async ({ t, path, leaf }) => {
        const where = `${path} (${t.contentUrl.slice(server.url.length + '/tiles/'.length)})`;
        let c;
        try {
            c = await load(t.contentUrl, Tiles3DLoader, {
                '3d-tiles': { loadGLTF: true },
                gltf: { loadImages: false, decompressMeshes: true },
            });
        } catch (e) {
            failures.push(`${where}: load/parse failed: ${e.message ?? e}`);
            return;
        }
        const g = c.gltf;
        if (!g || !Array.isArray(g.meshes) || g.meshes.length === 0) {
            failures.push(`${where}: content type ${c.type}, no glTF meshes`);
            return;
        }
        let n = 0;
        for (const [mi, m] of g.meshes.entries()) {
            for (const [pi, p] of (m.primitives ?? []).entries()) {
                const at = `${where} mesh ${mi} primitive ${pi}`;
                const pos = p.attributes?.POSITION;
                if (!pos || !pos.value) { failures.push(`${at}: no POSITION data`); continue; }
                const count = pos.count ?? pos.value.length / 3;
                const size = pos.components ?? pos.size ?? 3;
                if (pos.value.length < count * size) { failures.push(`${at}: POSITION holds ${pos.value.length} values for ${count} x ${size}`); continue; }
                let idx = count;
                if (p.indices) {
                    const iv = p.indices.value;
                    if (!iv) { failures.push(`${at}: indices without data`); continue; }
                    idx = iv.length;
                    let max = 0;
                    for (let i = 0; i < iv.length; i++) if (iv[i] > max) max = iv[i];
                    if (iv.length && max >= count) { failures.push(`${at}: index ${max} >= vertex count ${count}`); continue; }
                }
                const mode = p.mode ?? 4;
                const k = mode === 4 ? Math.floor(idx / 3) : mode === 5 || mode === 6 ? Math.max(idx - 2, 0) : 0;
                if (mode !== 4 && mode !== 5 && mode !== 6) failures.push(`${at}: mode ${mode} draws no triangles`);
                n += k;
            }
        }
        for (const [ii, im] of (g.images ?? []).entries()) {
            images++;
            const bytes = im.bufferView?.data;
            // an ArrayBuffer of its own: getBinaryImageMetadata ignores a view's offset
            const meta = bytes ? getBinaryImageMetadata(bytes.slice().buffer) : null;
            if (!meta || !(meta.width > 0 && meta.height > 0) || !/^image\/(png|jpeg)$/.test(meta.mimeType))
                failures.push(`${where} image ${ii}: ${bytes ? 'not a PNG or JPEG with a size' : 'no bytes (not in the glb)'}`);
        }
        tris += n;
        if (leaf) leafTris += n;
    };
    // a few at a time, like a viewer's download queue
    let next = 0;
    await Promise.all(Array.from({ length: 8 }, async () => {
        while (next < all.length) await one(all[next++]);
    }));
} catch (e) {
    failures.push(`tileset.json: load/parse failed: ${e.message ?? e}`);
}
for (const e of server.errors) failures.push(`HTTP: ${e}`);
await server.close();
const ms = Math.round(performance.now() - t0);

for (const f of failures.slice(0, 10)) console.log('  FAIL ' + f);
if (failures.length > 10) console.log(`  ... ${failures.length - 10} more failures`);
console.log(`loaders.gl: ${tiles} tiles, ${contents} contents, ${tris} triangles (${leafTris} in leaves, ${leaves} leaves), ` +
    `${images} images, ${ms} ms, ${failures.length} failures`);
console.log(JSON.stringify({ tiles, contents, leaves, triangles: tris, leaf_triangles: leafTris, images, ms, failures: failures.length }));
process.exit(failures.length || contents === 0 ? 1 : 0);
