// validate_glb.mjs - the Khronos glTF validator (npm gltf-validator, its JS
// API validateBytes) over every .glb under a 3D Tiles export.
//
//   node tests/tiles/validate_glb.mjs TILESET_DIR
//
// Every .glb below TILESET_DIR (recursively) is validated on its own.  The
// validator (2.0.0-dev.3.10) does not know EXT_meshopt_compression: it
// reports it as UNSUPPORTED_EXTENSION (an info) and cannot look into the
// compressed vertex and index data, so a glb that uses it is validated
// twice: as written, and decoded (meshoptimizer's MeshoptDecoder, npm
// meshoptimizer: every compressed bufferView decoded into one plain BIN
// buffer, the extension dropped), where accessor bounds, index ranges,
// normals' lengths and the rest are checked on the real data.  A summary
// line:
//   glb: N files (D decoded), E errors, W warnings, I infos, H hints
// and the first messages of each severity (code, pointer, message, file).
// Exit 0 when no file has an error (warnings, infos and hints are reported,
// not failed), 1 on any error or when no .glb was found, 2 on bad usage or
// a missing package (npm ci).
import fs from 'node:fs';
import path from 'node:path';

let validator;
try {
    validator = await import('gltf-validator');
    validator = validator.default ?? validator;
} catch (e) {
    console.error('validate_glb: the npm package gltf-validator is not installed (run npm ci): ' + e.message);
    process.exit(2);
}

let MeshoptDecoder;
try {
    ({ MeshoptDecoder } = await import('meshoptimizer/decoder'));
    await MeshoptDecoder.ready;
} catch (e) {
    console.error('validate_glb: the npm package meshoptimizer is not installed (run npm ci): ' + e.message);
    process.exit(2);
}

// A glb using EXT_meshopt_compression rewritten without it: one BIN of
// every bufferView's bytes (decoded where compressed), 4-byte aligned.
// Returns null when the glb does not use the extension; throws on a glb
// that cannot be decoded.
function decodeMeshopt(buf) {
    if (buf.readUInt32LE(0) !== 0x46546C67) throw new Error('no glTF magic');
    const jlen = buf.readUInt32LE(12);
    const json = JSON.parse(buf.subarray(20, 20 + jlen).toString('utf8'));
    if (!(json.extensionsUsed ?? []).includes('EXT_meshopt_compression')) return null;
    let bin = null;
    const at = 20 + jlen;
    if (at + 8 <= buf.length && buf.readUInt32LE(at + 4) === 0x004E4942)
        bin = buf.subarray(at + 8, at + 8 + buf.readUInt32LE(at));
    const bufferData = (i) => {
        if (i === 0 && bin && json.buffers[0].uri === undefined) return bin;
        throw new Error(`buffer ${i} has no data in the glb`);
    };
    const parts = [];
    let off = 0;
    for (const [i, bv] of json.bufferViews.entries()) {
        const ext = bv.extensions?.EXT_meshopt_compression;
        let data;
        if (ext) {
            const src = bufferData(ext.buffer).subarray(ext.byteOffset ?? 0, (ext.byteOffset ?? 0) + ext.byteLength);
            data = new Uint8Array(ext.count * ext.byteStride);
            try {
                MeshoptDecoder.decodeGltfBuffer(data, ext.count, ext.byteStride, src, ext.mode, ext.filter ?? 'NONE');
            } catch (e) {
                throw new Error(`bufferView ${i}: meshopt decoding failed: ${e.message ?? e}`);
            }
            if (data.length !== bv.byteLength)
                throw new Error(`bufferView ${i}: decodes to ${data.length} bytes, byteLength ${bv.byteLength}`);
            delete bv.extensions.EXT_meshopt_compression;
            if (Object.keys(bv.extensions).length === 0) delete bv.extensions;
        } else {
            data = bufferData(bv.buffer).subarray(bv.byteOffset ?? 0, (bv.byteOffset ?? 0) + bv.byteLength);
        }
        bv.buffer = 0;
        bv.byteOffset = off;
        const pad = (4 - data.length % 4) % 4;
        parts.push(Buffer.from(data.buffer, data.byteOffset, data.length), Buffer.alloc(pad));
        off += data.length + pad;
    }
    json.buffers = [{ byteLength: off }];
    for (const k of ['extensionsUsed', 'extensionsRequired']) {
        if (!json[k]) continue;
        json[k] = json[k].filter(e => e !== 'EXT_meshopt_compression');
        if (json[k].length === 0) delete json[k];
    }
    let j = Buffer.from(JSON.stringify(json));
    j = Buffer.concat([j, Buffer.alloc((4 - j.length % 4) % 4, 0x20)]);
    const b = Buffer.concat(parts);
    const head = Buffer.alloc(12);
    head.writeUInt32LE(0x46546C67, 0); head.writeUInt32LE(2, 4); head.writeUInt32LE(12 + 8 + j.length + 8 + b.length, 8);
    const chunk = (len, type) => { const c = Buffer.alloc(8); c.writeUInt32LE(len, 0); c.writeUInt32LE(type, 4); return c; };
    return Buffer.concat([head, chunk(j.length, 0x4E4F534A), j, chunk(b.length, 0x004E4942), b]);
}

const dir = process.argv[2];
if (!dir || !fs.existsSync(dir)) {
    console.error('usage: node validate_glb.mjs TILESET_DIR');
    process.exit(2);
}

function glbs(d) {
    const out = [];
    for (const e of fs.readdirSync(d, { withFileTypes: true })) {
        const p = path.join(d, e.name);
        if (e.isDirectory()) out.push(...glbs(p));
        else if (e.isFile() && e.name.toLowerCase().endsWith('.glb')) out.push(p);
    }
    return out.sort();
}

const files = glbs(dir);
const SEV = ['error', 'warning', 'info', 'hint'];
const totals = [0, 0, 0, 0];
const first = [[], [], [], []]; // the first messages of each severity
const byCode = new Map();       // "severity code" -> count over all files
let failedFiles = 0;
let decoded = 0;
async function validate(bytes, rel) {
    let report;
    try {
        report = await validator.validateBytes(new Uint8Array(bytes), {
            uri: rel,
            maxIssues: 0, // all
            // a glb of the export is self-contained: any external resource is an error
            externalResourceFunction: (uri) => Promise.reject(new Error('external resource ' + uri)),
        });
    } catch (e) {
        totals[0]++;
        first[0].push(`${rel}: the validator threw: ${e.message ?? e}`);
        return 1;
    }
    const is = report.issues;
    const n = [is.numErrors, is.numWarnings, is.numInfos, is.numHints];
    for (let s = 0; s < 4; s++) totals[s] += n[s];
    for (const m of is.messages) {
        const key = `${SEV[m.severity]} ${m.code}`;
        byCode.set(key, (byCode.get(key) ?? 0) + 1);
        if (first[m.severity].length < 5)
            first[m.severity].push(`${rel}: ${m.code} ${m.pointer ?? ''} ${m.message}`);
    }
    return n[0];
}
for (const f of files) {
    const rel = path.relative(dir, f);
    const bytes = fs.readFileSync(f);
    let bad = await validate(bytes, rel);
    let plain = null;
    try {
        plain = decodeMeshopt(bytes);
    } catch (e) {
        totals[0]++;
        bad++;
        first[0].push(`${rel}: EXT_meshopt_compression: ${e.message ?? e}`);
    }
    if (plain) {
        decoded++;
        bad += await validate(plain, rel + ' (meshopt decoded)');
    }
    if (bad > 0) failedFiles++;
}

console.log(`glb: ${files.length} files (${decoded} also validated meshopt-decoded), ${totals[0]} errors (${failedFiles} files), ${totals[1]} warnings, ` +
    `${totals[2]} infos, ${totals[3]} hints`);
for (const [k, c] of [...byCode].sort()) console.log(`  ${c} x ${k}`);
for (let s = 0; s < 3; s++)
    for (const m of first[s]) console.log(`  first ${SEV[s]}: ${m}`);
if (files.length === 0) {
    console.log('validate_glb: no .glb under ' + dir);
    process.exit(1);
}
process.exit(totals[0] > 0 ? 1 : 0);
