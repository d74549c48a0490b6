// meshopt_js.mjs - runs meshoptimizer's current simplifier (the npm package,
// a WASM build) for hlod-bench-simplify, which reports it beside the
// distribution's C library.
//
//   node tests/bench/meshopt_js.mjs IN OUT
//
// IN: uint32 vertex count, uint32 index count, uint32 target index count,
// uint32 attribute count A, then float32 positions (3 per vertex), float32
// attributes (A per vertex), float32 weights (A) and uint32 indices.  OUT:
// uint32 index count, float64 seconds of the best simplify call (of 3),
// uint32 indices.
// A = 0: `simplify` with Prune (parts under the error go whole) and
// Permissive (collapses across attribute seams; positions only here, so it
// only frees the topology rules).  A > 0: `simplifyWithAttributes` with
// the weights given and no flag, so attribute seams are kept the way
// hlod_simplify keeps them (a seam vertex moves only along its seam);
// Prune is left out there because with no error limit it returned an
// empty mesh for Wuson.ply.  Both with no error limit, as the C bench
// runs 0.18.
import { readFileSync, writeFileSync } from 'node:fs';
import { MeshoptSimplifier } from 'meshoptimizer';

const [inPath, outPath] = process.argv.slice(2);
const buf = readFileSync(inPath);
const head = new Uint32Array(buf.buffer, buf.byteOffset, 4);
const [nv, ni, target, na] = head;
let at = buf.byteOffset + 16;
const take = (bytes) => {
    const b = buf.buffer.slice(at, at + bytes);
    at += bytes;
    return b;
};
const pos = new Float32Array(take(nv * 12));
const attr = new Float32Array(take(nv * na * 4));
const weights = Array.from(new Float32Array(take(na * 4)));
const idx = new Uint32Array(take(ni * 4));
if (idx.length !== ni)
    throw new Error(`${inPath}: truncated (${idx.length} of ${ni} indices)`);
await MeshoptSimplifier.ready;
let best = Infinity, out = null;
for (let run = 0; run < 3; run++) {
    const t0 = performance.now();
    const [res] = na
        ? MeshoptSimplifier.simplifyWithAttributes(idx, pos, 3, attr, na, weights, null, target,
                                                   Number.MAX_VALUE, [])
        : MeshoptSimplifier.simplify(idx, pos, 3, target, Number.MAX_VALUE, ['Prune', 'Permissive']);
    const t = (performance.now() - t0) / 1000;
    if (t < best)
        best = t;
    out = res;
}
const o = Buffer.alloc(12 + out.length * 4);
o.writeUInt32LE(out.length, 0);
o.writeDoubleLE(best, 4);
Buffer.from(out.buffer, out.byteOffset, out.length * 4).copy(o, 12);
writeFileSync(outPath, o);
