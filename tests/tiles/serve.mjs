// serve.mjs - a tiny static HTTP server on loopback for the tiles tests:
// the export, the page and node_modules (no CDN: the machine's network is
// closed).
//
//   import { startServer } from './serve.mjs';
//   const s = await startServer({ '/tiles/': DIR, '/page/': PAGE_DIR, '/node_modules/': NM });
//   ... s.url ('http://127.0.0.1:PORT'), s.requests, s.errors; await s.close();
//
// Or by hand: node tests/tiles/serve.mjs TILESET_DIR [PORT] serves the
// export at /tiles/, the page at /page/ and node_modules at /node_modules/
// (open http://127.0.0.1:PORT/page/index.html?tileset=/tiles/tileset.json).
//
// GET and HEAD only, files only, no path outside a mount (.. and symlinks
// out are refused), Content-Length and a type by extension, no caching.
// Every 4xx/5xx is counted in s.errors (a request the page or loader made
// for a file that is not there).
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

const TYPES = {
    '.html': 'text/html; charset=utf-8', '.js': 'text/javascript; charset=utf-8',
    '.mjs': 'text/javascript; charset=utf-8', '.json': 'application/json',
    '.glb': 'model/gltf-binary', '.gltf': 'model/gltf+json', '.bin': 'application/octet-stream',
    '.png': 'image/png', '.jpg': 'image/jpeg', '.jpeg': 'image/jpeg', '.wasm': 'application/wasm',
    '.map': 'application/json', '.css': 'text/css',
};

export function startServer(mounts, port = 0) {
    const roots = Object.entries(mounts).map(([prefix, dir]) => [prefix, fs.realpathSync(dir)]);
    const state = { requests: 0, errors: [], bytes: 0 };
    const server = http.createServer((req, res) => {
        state.requests++;
        const fail = (code, why) => {
            state.errors.push(`${code} ${req.method} ${req.url}: ${why}`);
            res.writeHead(code, { 'Content-Type': 'text/plain' });
            res.end(why + '\n');
        };
        if (req.method !== 'GET' && req.method !== 'HEAD') return fail(405, 'method not allowed');
        let p;
        try {
            p = decodeURIComponent(new URL(req.url, 'http://x').pathname);
        } catch {
            return fail(400, 'bad URL');
        }
        const mount = roots.find(([prefix]) => p.startsWith(prefix));
        if (!mount) return fail(404, 'no mount');
        const [prefix, dir] = mount;
        let file = path.resolve(dir, '.' + path.posix.normalize('/' + p.slice(prefix.length)));
        try {
            file = fs.realpathSync(file);
        } catch {
            return fail(404, 'no such file');
        }
        if (file !== dir && !file.startsWith(dir + path.sep)) return fail(403, 'outside the mount');
        let st;
        try {
            st = fs.statSync(file);
        } catch {
            return fail(404, 'no such file');
        }
        if (!st.isFile()) return fail(404, 'not a file');
        res.writeHead(200, {
            'Content-Type': TYPES[path.extname(file).toLowerCase()] ?? 'application/octet-stream',
            'Content-Length': st.size,
            'Cache-Control': 'no-store',
        });
        if (req.method === 'HEAD') return res.end();
        state.bytes += st.size;
        fs.createReadStream(file).pipe(res);
    });
    return new Promise((resolve, reject) => {
        server.once('error', reject);
        server.listen(port, '127.0.0.1', () => {
            const url = `http://127.0.0.1:${server.address().port}`;
            resolve(Object.assign(state, {
                url,
                close: () => new Promise(r => { server.closeAllConnections?.(); server.close(() => r()); }),
            }));
        });
    });
}

if (process.argv[1] && fileURLToPath(import.meta.url) === path.resolve(process.argv[1])) {
    const here = path.dirname(fileURLToPath(import.meta.url));
    const dir = process.argv[2];
    if (!dir) {
        console.error('usage: node serve.mjs TILESET_DIR [PORT]');
        process.exit(2);
    }
    const s = await startServer({
        '/tiles/': dir, '/page/': path.join(here, 'page'),
        '/node_modules/': path.join(here, '..', '..', 'node_modules'),
    }, Number(process.argv[3] ?? 0));
    console.log(`${s.url}/page/index.html?tileset=/tiles/tileset.json`);
}
