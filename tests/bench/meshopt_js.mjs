// meshopt_js.mjs - runs meshoptimizer's current simplifier (the npm package,
// a WASM build) for hlod-bench-simplify, which reports it beside the
// distribution's C library.
//
//   node tests/bench/meshopt_js.mjs IN OUT
//
// IN: uint32 vertex count, uint32 index count, uint32 target index count,
// then float32 positions (3 per vertex) and uint32 indices.  OUT: uint32
// index count, float64 seconds of the simplify call, uint32 indices.
// Flags: Prune (parts under the error go whole) and Permissive (collapses
// across attribute seams; positions only here, so it only frees the
// topology rules), with no error limit, as the C bench runs 0.18.
import { readFileSync, writeFileSync } from 'node:fs';
import { MeshoptSimplifier } from 'meshoptimizer';

const [inPath, outPath] = process.argv.slice(2);
const buf = readFileSync(inPath);
const head = new Uint32Array(buf.buffer, buf.byteOffset, 3);
const [nv, ni, target] = head;
const pos = new Float32Array(buf.buffer.slice(buf.byteOffset + 12, buf.byteOffset + 12 + nv * 12));
const idx = new Uint32Array(buf.buffer.slice(buf.byteOffset + 12 + nv * 12, buf.byteOffset + 12 + nv * 12 + ni * 4));
await MeshoptSimplifier.ready;
let best = Infinity, out = null;
for (let run = 0; run < 3; run++) {
    const t0 = performance.now();
    const [res] = MeshoptSimplifier.simplify(idx, pos, 3, target, Number.MAX_VALUE, ['Prune', 'Permissive']);
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
