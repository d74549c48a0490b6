// render_tiles.mjs - draws an hlod 3D Tiles export in a real browser:
// headless Debian chromium driven by playwright-core, the project's page
// (tests/tiles/page/: 3d-tiles-renderer + three.js from node_modules, hlod's
// lighting) served from loopback by serve.mjs, at the camera of one frame
// of an hlod camera path; writes the W x H image once every tile the view
// needs at full detail is in.
//
//   node tests/tiles/render_tiles.mjs --tileset DIR --path FILE --frame K
//        --out IMAGE.png [--width 480] [--height 270] [--dt 0.0333..]
//        [--fov 60] [--near 0.25] [--timeout-s 90]
//        [--chromium /usr/bin/chromium]
//
// The camera of frame K is the path's keyframe at t0 + K x dt (hlod-bench
// replays frame K at that time and returns a keyframe bit for bit there);
// a K between keyframes is refused, so the two renderers see one camera.
// Prints a line of numbers and a JSON line {"ms","load_ms","frames",
// "models","triangles","visible_tiles","visible_triangles","requests",
// "gpu"}.  Exit 0 with the image written; 1 with a message saying what
// failed (a tile load, an HTTP 404, a page error, the browser, a timeout);
// 2 on bad usage or a missing package (npm ci).
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import { startServer } from './serve.mjs';

const here = path.dirname(fileURLToPath(import.meta.url));
const root = path.resolve(here, '..', '..');

const o = { width: 480, height: 270, dt: 1 / 30, fov: 60, near: 0.25, 'timeout-s': 90, chromium: '/usr/bin/chromium' };
const argv = process.argv.slice(2);
for (let i = 0; i < argv.length; i += 2) {
    const k = argv[i].replace(/^--/, '');
    if (!(k in o) && !['tileset', 'path', 'frame', 'out'].includes(k) || argv[i + 1] === undefined) {
        console.error(`render_tiles: bad argument ${argv[i]}`);
        process.exit(2);
    }
    o[k] = ['tileset', 'path', 'out', 'chromium'].includes(k) ? argv[i + 1] : Number(argv[i + 1]);
}
if (!o.tileset || !o.path || !(o.frame >= 0) || !o.out) {
    console.error('usage: node render_tiles.mjs --tileset DIR --path FILE --frame K --out IMAGE.png [options]');
    process.exit(2);
}

let chromium;
try {
    ({ chromium } = await import('playwright-core'));
} catch (e) {
    console.error('render_tiles: the npm package playwright-core is not installed (run npm ci): ' + e.message);
    process.exit(2);
}
for (const p of ['three/build/three.module.js', '3d-tiles-renderer/build/index.js',
    'three/examples/jsm/libs/meshopt_decoder.module.js']) {
    if (!fs.existsSync(path.join(root, 'node_modules', p))) {
        console.error(`render_tiles: node_modules/${p} is missing (run npm ci: three, 3d-tiles-renderer)`);
        process.exit(2);
    }
}
if (!fs.existsSync(o.chromium)) {
    console.error(`render_tiles: no browser at ${o.chromium} (data/setup.sh installs Debian's chromium)`);
    process.exit(1);
}

// ---- the camera: frame K of the path ----
const keys = [];
if (!fs.existsSync(o.path)) {
    console.error(`render_tiles: no path file ${o.path}`);
    process.exit(1);
}
for (const line of fs.readFileSync(o.path, 'utf8').split('\n')) {
    const s = line.replace(/#.*/, '').trim();
    if (!s) continue;
    const v = s.split(/\s+/).map(Number);
    if (v.length !== 7 || !v.every(Number.isFinite)) {
        console.error(`render_tiles: ${o.path}: a line that is not "t ex ey ez lx ly lz": ${line}`);
        process.exit(1);
    }
    keys.push(v);
}
if (keys.length === 0) {
    console.error(`render_tiles: ${o.path}: no keyframe`);
    process.exit(1);
}
const t = keys[0][0] + o.frame * o.dt;
const key = keys.length === 1 ? keys[0] : keys.find(k => Math.abs(k[0] - t) <= 1e-9 * Math.max(1, Math.abs(t)));
if (!key) {
    console.error(`render_tiles: frame ${o.frame} (t = ${t}) of ${o.path} is not on a keyframe; pick a frame that is`);
    process.exit(1);
}
const eye = key.slice(1, 4), look = key.slice(4, 7);

// ---- serve, launch, draw ----
const t0 = performance.now();
const server = await startServer({
    '/tiles/': o.tileset, '/page/': path.join(here, 'page'), '/node_modules/': path.join(root, 'node_modules'),
});
const userDir = fs.mkdtempSync(path.join(os.tmpdir(), 'hlod-tiles-chromium-'));
let context = null, rc = 1;
const problems = [];
const watchdog = setTimeout(() => {
    console.error(`render_tiles: FAIL: no result after ${o['timeout-s'] + 30} s (the browser hangs)`);
    fs.rmSync(userDir, { recursive: true, force: true });
    process.exit(1); // playwright kills the browser on exit
}, (o['timeout-s'] + 30) * 1000);
try {
    context = await chromium.launchPersistentContext(userDir, {
        executablePath: o.chromium,
        headless: true,
        args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
            '--disable-background-networking', '--disable-component-update', '--disable-sync',
            '--disable-dev-shm-usage', // a container's small /dev/shm
            // WebGL without a GPU: ANGLE on SwiftShader, which Chromium no
            // longer falls back to by itself
            '--use-angle=swiftshader', '--enable-unsafe-swiftshader'],
        viewport: { width: o.width * 2, height: o.height * 2 },
        timeout: 60000,
    });
    const page = context.pages()[0] ?? await context.newPage();
    page.on('pageerror', e => problems.push(`page error: ${e.message}`));
    page.on('console', m => { if (m.type() === 'error') problems.push(`console: ${m.text()}`); });
    page.on('requestfailed', r => problems.push(`request failed: ${r.url()} ${r.failure()?.errorText ?? ''}`));
    await page.goto(`${server.url}/page/index.html`, { timeout: 30000 });
    await page.waitForFunction(() => window.hlodReady === true || undefined, null, { timeout: 30000 })
        .catch(() => { throw new Error('the page did not load its modules (import map, node_modules)'); });
    const r = await page.evaluate(opts => window.hlodRender(opts), {
        tileset: `${server.url}/tiles/tileset.json`, width: o.width, height: o.height,
        eye, look, fov: o.fov, near: o.near, timeoutMs: o['timeout-s'] * 1000,
    });
    const png = Buffer.from(r.png.replace(/^data:image\/png;base64,/, ''), 'base64');
    fs.mkdirSync(path.dirname(path.resolve(o.out)), { recursive: true });
    fs.writeFileSync(o.out, png);
    for (const e of server.errors) problems.push(`HTTP: ${e}`);
    const ms = Math.round(performance.now() - t0);
    console.log(`browser: ${r.gpu || r.webgl}; frame ${o.frame} of ${path.basename(o.path)} ` +
        `(eye ${eye.join(' ')}, look ${look.join(' ')}), ${o.width}x${o.height}: settled in ${r.ms} ms ` +
        `(${r.frames} frames), ${r.models} tiles loaded (${r.triangles} triangles), ${r.visibleTiles} drawn ` +
        `(${r.visibleTris} triangles), ${server.requests} requests, ${ms} ms in all`);
    console.log(JSON.stringify({ ms, load_ms: r.ms, frames: r.frames, models: r.models, triangles: r.triangles,
        visible_tiles: r.visibleTiles, visible_triangles: r.visibleTris, requests: server.requests, gpu: r.gpu }));
    rc = 0;
    if (problems.length) {
        for (const p of problems.slice(0, 10)) console.log('  FAIL ' + p);
        rc = 1;
    }
} catch (e) {
    for (const p of problems.slice(0, 10)) console.log('  ' + p);
    console.log(`render_tiles: FAIL: ${(e.message ?? String(e)).split('\n')[0]}`);
    rc = 1;
} finally {
    clearTimeout(watchdog);
    if (context) await context.close().catch(() => {});
    await server.close();
    fs.rmSync(userDir, { recursive: true, force: true });
}
process.exit(rc);
