// validate_tileset.mjs - a structural check of a 3D Tiles 1.1 tileset.json
// written by hlod-export-3dtiles.
//
//   node tests/tiles/validate_tileset.mjs TILESET_DIR/tileset.json
//
// NOT a JSON-schema validation: no package on the npm registry ships the
// 3D Tiles 1.1 schema files (CesiumGS's 3d-tiles-validator is not on the
// registry; 3d-tiles-tools 0.5.4 and 3d-tiles-renderer 0.5.3 carry no
// *.schema.json), so this script checks by hand what the schema and the
// specification require of what the exporter writes, and a little more:
//   - asset.version "1.1"; the tileset's geometricError a finite number >= 0;
//     a root tile; no unknown top-level, tile or content property (reported
//     as warnings: the schema allows extensions/extras, not typos);
//   - every tile: boundingVolume.box of 12 finite numbers with a non-zero,
//     non-degenerate frame (a sphere or region is refused: the exporter
//     writes boxes); geometricError a finite number >= 0 and no larger than
//     its parent's (the root's no larger than the tileset's); refine
//     "REPLACE" on the root and, where given, on every other tile;
//     transform, where given, 16 finite numbers, column-major, affine (last
//     row 0 0 0 1); children a non-empty array where given;
//   - every content.uri relative, resolving inside TILESET_DIR, to an
//     existing non-empty file, each used once; a .glb content starts with
//     the glTF magic, and the bounds of its POSITION accessors (through the
//     glTF node matrices, then y-up to z-up: tile frame (x, -z, y) of glTF
//     (x, y, z)) lie inside the tile's box, within 1e-3 of its longest
//     half-axis (the box decides what a viewer culls and refines; how many
//     contents reach past their box at all, and how far, is printed);
//   - the largest geometricError of a leaf is printed (0 is not required).
// Prints "tileset: N tiles, C contents, depth D, geometricError A..B" and
// the first problems; exit 0 when there are none, 1 otherwise, 2 on bad
// usage.
import fs from 'node:fs';
import path from 'node:path';

const file = process.argv[2];
if (!file || !fs.existsSync(file)) {
    console.error('usage: node validate_tileset.mjs TILESET.json');
    process.exit(2);
}
const base = path.dirname(path.resolve(file));
const errors = [], warnings = [];
const err = (p, m) => errors.push(`${p}: ${m}`);
const warn = (p, m) => warnings.push(`${p}: ${m}`);
const finite = (v) => typeof v === 'number' && Number.isFinite(v);

let ts;
try {
    ts = JSON.parse(fs.readFileSync(file, 'utf8'));
} catch (e) {
    console.log('tileset: not JSON: ' + e.message);
    process.exit(1);
}

const TOP = ['asset', 'properties', 'schema', 'schemaUri', 'statistics', 'groups', 'metadata',
    'geometricError', 'root', 'extensionsUsed', 'extensionsRequired', 'extensions', 'extras'];
const TILE = ['boundingVolume', 'viewerRequestVolume', 'geometricError', 'refine', 'transform',
    'content', 'contents', 'metadata', 'implicitTiling', 'children', 'extensions', 'extras'];
const CONTENT = ['boundingVolume', 'uri', 'metadata', 'group', 'extensions', 'extras'];
const unknown = (obj, known, p) => {
    for (const k of Object.keys(obj)) if (!known.includes(k)) warn(p, `unknown property "${k}"`);
};

if (typeof ts !== 'object' || ts === null || Array.isArray(ts)) {
    console.log('tileset: the top level is not an object');
    process.exit(1);
}
unknown(ts, TOP, '/');
if (!ts.asset || ts.asset.version !== '1.1')
    err('/asset/version', `"${ts.asset?.version}", not "1.1"`);
if (!finite(ts.geometricError) || ts.geometricError < 0)
    err('/geometricError', `${ts.geometricError}: not a finite number >= 0`);
for (const k of ['extensionsUsed', 'extensionsRequired'])
    if (k in ts && !Array.isArray(ts[k])) err('/' + k, 'not an array');
if (!ts.root || typeof ts.root !== 'object') err('/root', 'missing');

// ---- glb bounds ----
const mul = (a, b) => { // column-major 4x4
    const r = new Array(16).fill(0);
    for (let c = 0; c < 4; c++) for (let rr = 0; rr < 4; rr++)
        for (let k = 0; k < 4; k++) r[c * 4 + rr] += a[k * 4 + rr] * b[c * 4 + k];
    return r;
};
const I4 = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1];
function nodeMatrix(n) {
    if (n.matrix) return n.matrix;
    const [x, y, z, w] = n.rotation ?? [0, 0, 0, 1], [sx, sy, sz] = n.scale ?? [1, 1, 1];
    const [tx, ty, tz] = n.translation ?? [0, 0, 0];
    return [
        (1 - 2 * (y * y + z * z)) * sx, (2 * (x * y + z * w)) * sx, (2 * (x * z - y * w)) * sx, 0,
        (2 * (x * y - z * w)) * sy, (1 - 2 * (x * x + z * z)) * sy, (2 * (y * z + x * w)) * sy, 0,
        (2 * (x * z + y * w)) * sz, (2 * (y * z - x * w)) * sz, (1 - 2 * (x * x + y * y)) * sz, 0,
        tx, ty, tz, 1];
}
const apply = (m, p) => [0, 1, 2].map(r => m[r] * p[0] + m[4 + r] * p[1] + m[8 + r] * p[2] + m[12 + r]);
// the corners, in the tile's frame (z up), of every primitive's POSITION bounds
function glbCorners(buf, p) {
    if (buf.length < 20 || buf.readUInt32LE(0) !== 0x46546C67) { err(p, 'not a glb (no glTF magic)'); return null; }
    const jlen = buf.readUInt32LE(12);
    let g;
    try { g = JSON.parse(buf.subarray(20, 20 + jlen).toString('utf8')); } catch (e) { err(p, 'glb JSON: ' + e.message); return null; }
    const pts = [];
    const visit = (ni, parent) => {
        const n = g.nodes?.[ni];
        if (!n) return;
        const m = mul(parent, nodeMatrix(n));
        if (n.mesh !== undefined)
            for (const prim of g.meshes?.[n.mesh]?.primitives ?? []) {
                const a = g.accessors?.[prim.attributes?.POSITION];
                if (!a || !a.min || !a.max) { err(p, `mesh ${n.mesh}: POSITION without min/max`); continue; }
                let mn = a.min, mx = a.max;
                if (a.normalized) { // KHR_mesh_quantization: normalized integers
                    const f = { 5120: 127, 5121: 255, 5122: 32767, 5123: 65535 }[a.componentType] ?? 1;
                    const s = a.componentType === 5120 || a.componentType === 5122;
                    mn = mn.map(v => s ? Math.max(v / f, -1) : v / f);
                    mx = mx.map(v => s ? Math.max(v / f, -1) : v / f);
                }
                for (let c = 0; c < 8; c++) {
                    const q = apply(m, [c & 1 ? mx[0] : mn[0], c & 2 ? mx[1] : mn[1], c & 4 ? mx[2] : mn[2]]);
                    pts.push([q[0], -q[2], q[1]]); // y-up -> z-up
                }
            }
        for (const c of n.children ?? []) visit(c, m);
    };
    for (const ni of g.scenes?.[g.scene ?? 0]?.nodes ?? []) visit(ni, I4);
    if (pts.length === 0) err(p, 'glb has no mesh in its scene');
    return pts;
}

// ---- tiles ----
let leafGeMax = 0;
let outside = 0, outsideMax = 0;
let coherence = 0, coherenceMax = 0; // subtrees whose content reaches past the tile's box // contents past their box by any amount
let tiles = 0, contents = 0, maxDepth = 0, geMin = Infinity, geMax = -Infinity;
const uris = new Set();
// past(box, pts): how far the farthest of pts lies outside the box (<= 0: inside)
function past(box, pts) {
    const axes = [box.slice(3, 6), box.slice(6, 9), box.slice(9, 12)];
    const len = axes.map(a => Math.hypot(a[0], a[1], a[2]));
    let worst = -Infinity;
    for (const q of pts) for (let i = 0; i < 3; i++) {
        if (len[i] === 0) continue;
        const a = axes[i];
        worst = Math.max(worst, Math.abs((q[0] - box[0]) * a[0] + (q[1] - box[1]) * a[1] + (q[2] - box[2]) * a[2]) / len[i] - len[i]);
    }
    return worst;
}
// tile(): checks a tile and its subtree; returns the corners of its own
// content's and its descendants' content bounds, in its parent's frame
function tile(t, p, parentGe, depth) {
    const own = [];
    tiles++;
    maxDepth = Math.max(maxDepth, depth);
    if (typeof t !== 'object' || t === null) { err(p, 'not an object'); return; }
    unknown(t, TILE, p);
    const box = t.boundingVolume?.box;
    let axes = null;
    if (!t.boundingVolume) err(p + '/boundingVolume', 'missing');
    else if (!Array.isArray(box) || box.length !== 12 || !box.every(finite))
        err(p + '/boundingVolume/box', `${JSON.stringify(box ?? Object.keys(t.boundingVolume))}: not 12 finite numbers`);
    else {
        axes = [box.slice(3, 6), box.slice(6, 9), box.slice(9, 12)];
        const l2 = axes.map(a => a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        // a flat box (one half-axis 0) is allowed by the spec; two are not useful
        if (l2.filter(v => v === 0).length > 1) err(p + '/boundingVolume/box', 'degenerate (more than one zero half-axis)');
        for (let i = 0; i < 3; i++) for (let j = i + 1; j < 3; j++) {
            const d = axes[i][0] * axes[j][0] + axes[i][1] * axes[j][1] + axes[i][2] * axes[j][2];
            if (Math.abs(d) > 1e-6 * Math.sqrt(l2[i] * l2[j]) + 1e-12) err(p + '/boundingVolume/box', `half-axes ${i} and ${j} not orthogonal`);
        }
    }
    const ge = t.geometricError;
    if (!finite(ge) || ge < 0) err(p + '/geometricError', `${ge}: not a finite number >= 0`);
    else {
        geMin = Math.min(geMin, ge); geMax = Math.max(geMax, ge);
        if (finite(parentGe) && ge > parentGe) err(p + '/geometricError', `${ge} > the parent's ${parentGe}`);
    }
    if (depth === 0 && t.refine !== 'REPLACE') err(p + '/refine', `${JSON.stringify(t.refine)} on the root, not "REPLACE"`);
    else if (t.refine !== undefined && t.refine !== 'REPLACE') err(p + '/refine', `${JSON.stringify(t.refine)}, not "REPLACE"`);
    if (t.transform !== undefined) {
        const m = t.transform;
        if (!Array.isArray(m) || m.length !== 16 || !m.every(finite)) err(p + '/transform', 'not 16 finite numbers');
        else if (m[3] !== 0 || m[7] !== 0 || m[11] !== 0 || m[15] !== 1) err(p + '/transform', `last row ${m[3]} ${m[7]} ${m[11]} ${m[15]}, not 0 0 0 1 (column-major)`);
    }
    if (t.contents !== undefined) err(p + '/contents', 'the exporter writes one content per tile');
    if (t.content !== undefined) {
        contents++;
        const c = t.content;
        unknown(c, CONTENT, p + '/content');
        const uri = c.uri;
        if (typeof uri !== 'string' || uri === '') err(p + '/content/uri', 'missing');
        else if (/^[a-z][a-z0-9+.-]*:/i.test(uri) || uri.startsWith('/')) err(p + '/content/uri', `"${uri}" is not relative`);
        else {
            const f = path.resolve(base, decodeURIComponent(uri));
            if (!f.startsWith(base + path.sep)) err(p + '/content/uri', `"${uri}" leaves the tileset's folder`);
            else if (uris.has(f)) err(p + '/content/uri', `"${uri}" used by two tiles`);
            else if (!fs.existsSync(f) || !fs.statSync(f).isFile()) err(p + '/content/uri', `"${uri}": no such file`);
            else {
                uris.add(f);
                const buf = fs.readFileSync(f);
                if (buf.length === 0) err(p + '/content/uri', `"${uri}" is empty`);
                else if (uri.toLowerCase().endsWith('.glb') && axes) {
                    const pts = glbCorners(buf, `${p}/content (${uri})`);
                    if (pts) own.push(...pts);
                    // the distance past the box's faces, against a slack of
                    // 1e-3 x its longest half-axis (quantization rounding)
                    const len = axes.map(a => Math.hypot(a[0], a[1], a[2]));
                    const slack = 1e-3 * Math.max(...len);
                    let worst = 0;
                    for (const q of pts ?? []) for (let i = 0; i < 3; i++) {
                        if (len[i] === 0) continue;
                        const a = axes[i];
                        const d = Math.abs((q[0] - box[0]) * a[0] + (q[1] - box[1]) * a[1] + (q[2] - box[2]) * a[2]) / len[i];
                        worst = Math.max(worst, d - len[i]);
                    }
                    if (worst > 1e-9) { outside++; outsideMax = Math.max(outsideMax, worst); }
                    if (worst > slack)
                        err(`${p}/content (${uri})`, `the glb's positions reach ${worst.toPrecision(3)} past boundingVolume.box (slack ${slack.toPrecision(3)})`);
                }
            }
        }
    }
    if (t.children !== undefined) {
        if (!Array.isArray(t.children) || t.children.length === 0) err(p + '/children', 'not a non-empty array');
        else t.children.forEach((c, i) => {
            const below = tile(c, `${p}/children/${i}`, finite(ge) ? ge : parentGe, depth + 1) ?? [];
            // spatial coherence: the descendants' content inside this tile's box
            if (axes && below.length) {
                const len = axes.map(a => Math.hypot(a[0], a[1], a[2]));
                const w = past(box, below);
                if (w > 1e-9) { coherence++; coherenceMax = Math.max(coherenceMax, w); }
                if (w > 1e-3 * Math.max(...len))
                    err(`${p}/children/${i}`, `its content reaches ${w.toPrecision(3)} past the parent's boundingVolume.box ` +
                        '(3D Tiles: a child\'s content lies inside its parent\'s bounding volume)');
            }
            own.push(...below);
        });
    } else if (finite(ge)) {
        leafGeMax = Math.max(leafGeMax, ge);
    }
    const m = Array.isArray(t.transform) && t.transform.length === 16 ? t.transform : null;
    return m ? own.map(q => [0, 1, 2].map(r => m[r] * q[0] + m[4 + r] * q[1] + m[8 + r] * q[2] + m[12 + r])) : own;
}
if (ts.root && typeof ts.root === 'object') tile(ts.root, '/root', ts.geometricError, 0);

console.log(`tileset: structural check (no 3D Tiles schema package on npm): ${tiles} tiles, ${contents} contents, ` +
    `depth ${maxDepth}, geometricError ${geMin}..${geMax} (tileset ${ts.geometricError}, leaves <= ${leafGeMax}), ` +
    `${errors.length} errors, ${warnings.length} warnings; ` +
    `${outside} contents reach past their box (at most ${outsideMax.toPrecision(3)}), ` +
    `${coherence} children's contents past the parent's box (at most ${coherenceMax.toPrecision(3)})`);
for (const m of errors.slice(0, 40)) console.log('  error: ' + m);
if (errors.length > 40) console.log(`  ... ${errors.length - 40} more errors`);
for (const m of warnings.slice(0, 5)) console.log('  warning: ' + m);
process.exit(errors.length > 0 ? 1 : 0);
