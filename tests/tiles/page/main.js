// main.js - the tiles test's page: draws an hlod 3D Tiles export with
// 3d-tiles-renderer and three.js as hlod's own renderer draws the store
// (engine/gl_render.c), so the two images compare:
//   - the camera of one frame of a camera path: eye, look-at, up (0, 0, 1),
//     vertical FOV (60), near (0.25) and far as hlod-bench sets them;
//   - every tile mesh drawn with a ShaderMaterial of hlod's lighting,
//     light = 0.20 + 0.55 |n . to_eye| + 0.25 (0.5 + 0.5 n.z) in the world
//     (z up) frame, n turned towards the eye; per vertex from the normals
//     when the mesh has them, else per fragment from the face (dFdx/dFdy);
//     colour = base * light with base the raw 8-bit texel (no sRGB
//     decoding: texture colorSpace NoColorSpace), times the vertex colour
//     and the baseColorFactor, which glTF stores linear, turned back into
//     the sRGB values hlod keeps; output with no conversion
//     (LinearSRGBColorSpace, no tone mapping); clear colour (0.62, 0.74, 0.86);
//   - errorTarget 0: every tile refines down to its leaves; drawn at 2W x 2H
//     and box-filtered to W x H, as hlod-bench's reference (--reference-ss 2).
// The driver calls window.hlodRender(opts) and gets the PNG (a data URL)
// and the loader's numbers; a tile that fails to load, or not settling
// within opts.timeoutMs, rejects with a message saying which.
import * as THREE from 'three';
import { TilesRenderer } from '3d-tiles-renderer';
import { GLTFExtensionsPlugin } from '3d-tiles-renderer/plugins';
import { MeshoptDecoder } from 'three/examples/jsm/libs/meshopt_decoder.module.js';

// what the vertex shader hands the fragment shader (declared in both)
const varyings = /* glsl */ `
varying vec2 v_uv;
varying vec3 v_color;
#ifdef HLOD_NORMAL
varying float v_light;
#else
varying vec3 v_rel;
#endif
`;

const vertexShader = /* glsl */ `
${varyings}void main() {
    vec4 world = modelMatrix * vec4(position, 1.0);
    vec3 rel = world.xyz - cameraPosition;
#ifdef HLOD_NORMAL
    float d = length(rel);
    vec3 to_eye = d > 0.0 ? -rel / d : vec3(0.0, 0.0, 1.0);
    // the normal into the world frame (the node's quantization scale and
    // the y-up to z-up turn are in modelMatrix)
    vec3 n = inverse(transpose(mat3(modelMatrix))) * normal;
    float len = length(n);
    n = len > 0.0 ? n / len : to_eye;
    if (dot(n, to_eye) < 0.0) n = -n;
    v_light = 0.20 + 0.55 * abs(dot(n, to_eye)) + 0.25 * (0.5 + 0.5 * n.z);
#else
    v_rel = rel;
#endif
#ifdef HLOD_UV
    v_uv = uv;
#else
    v_uv = vec2(0.0);
#endif
#ifdef USE_COLOR
    v_color = color.rgb;
#else
    v_color = vec3(1.0);
#endif
    gl_Position = projectionMatrix * viewMatrix * world;
}`;

const fragmentShader = /* glsl */ `
uniform vec3 u_factor;
#ifdef HLOD_MAP
uniform sampler2D u_map;
#endif
${varyings}vec3 to_srgb(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
void main() {
#ifdef HLOD_NORMAL
    float light = v_light;
#else
    vec3 to_eye = -v_rel;
    float d = length(to_eye);
    to_eye = d > 0.0 ? to_eye / d : vec3(0.0, 0.0, 1.0);
    vec3 n = cross(dFdx(v_rel), dFdy(v_rel));
    if (dot(n, to_eye) < 0.0) n = -n;
    float len = length(n);
    n = len > 0.0 ? n / len : to_eye;
    float light = 0.20 + 0.55 * abs(dot(n, to_eye)) + 0.25 * (0.5 + 0.5 * n.z);
#endif
    vec3 base = u_factor;
#ifdef HLOD_MAP
    base *= texture2D(u_map, v_uv).rgb;
#endif
#ifdef USE_COLOR
    base *= to_srgb(v_color);
#endif
    gl_FragColor = vec4(base * light, 1.0);
}`;

// hlod's material for one mesh, from the glTF material three made
function hlodMaterial(mesh) {
    const src = mesh.material;
    const g = mesh.geometry;
    const defines = {};
    if (g.attributes.normal) defines.HLOD_NORMAL = 1;
    if (g.attributes.uv) defines.HLOD_UV = 1;
    const map = src.map && g.attributes.uv ? src.map : null;
    if (map) {
        defines.HLOD_MAP = 1;
        map.colorSpace = THREE.NoColorSpace; // raw bytes, as hlod samples them
        map.needsUpdate = true;
    }
    const factor = new THREE.Color(1, 1, 1);
    if (src.color) src.color.getRGB(factor, THREE.SRGBColorSpace); // linear -> sRGB values
    const m = new THREE.ShaderMaterial({
        vertexShader, fragmentShader, defines,
        uniforms: { u_factor: { value: new THREE.Vector3(factor.r, factor.g, factor.b) }, u_map: { value: map } },
        vertexColors: !!g.attributes.color,
        side: src.side,
    });
    return m;
}

window.hlodRender = async function hlodRender(opts) {
    const { tileset, width: W, height: H, eye, look, fov = 60, near = 0.25, timeoutMs = 60000, ss = 2 } = opts;
    const errors = [];
    const canvas = document.createElement('canvas');
    document.body.appendChild(canvas);
    const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
    renderer.setPixelRatio(1);
    renderer.setSize(W * ss, H * ss, false);
    renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
    renderer.toneMapping = THREE.NoToneMapping;
    renderer.setClearColor(new THREE.Color().setRGB(0.62, 0.74, 0.86, THREE.LinearSRGBColorSpace), 1);
    const gl = renderer.getContext();
    const info = {
        webgl: gl.getParameter(gl.VERSION),
        gpu: (() => { const e = gl.getExtension('WEBGL_debug_renderer_info'); return e ? gl.getParameter(e.UNMASKED_RENDERER_WEBGL) : ''; })(),
    };

    const scene = new THREE.Scene();
    const tiles = new TilesRenderer(tileset);
    tiles.registerPlugin(new GLTFExtensionsPlugin({ meshoptDecoder: MeshoptDecoder, metadata: false, rtc: false }));
    tiles.errorTarget = 0;   // refine to the leaves
    tiles.loadSiblings = false;
    let meshes = 0, triangles = 0, models = 0;
    tiles.addEventListener('load-model', ({ scene: s }) => {
        models++;
        s.traverse(o => {
            if (!o.isMesh) return;
            meshes++;
            const g = o.geometry;
            triangles += (g.index ? g.index.count : g.attributes.position.count) / 3;
            const old = o.material;
            o.material = hlodMaterial(o);
            old.dispose();
        });
    });
    tiles.addEventListener('load-error', (e) => {
        errors.push(`${e.url ?? e.tile?.content?.uri ?? '?'}: ${e.error?.message ?? e.error}`);
    });
    scene.add(tiles.group);

    // the far plane as hlod-bench: 3 x the diagonal + 1000 + |eye - centre| per axis
    const camera = new THREE.PerspectiveCamera(fov, W / H, near, 1e5);
    camera.up.set(0, 0, 1);
    camera.position.set(...eye);
    camera.lookAt(new THREE.Vector3(...look));
    camera.updateMatrixWorld(true);
    let farSet = false;
    const setFar = () => {
        const box = tiles.root?.boundingVolume?.box;
        if (!box || farSet) return;
        const m = new THREE.Matrix4();
        if (tiles.root.transform) m.fromArray(tiles.root.transform);
        const c = new THREE.Vector3(box[0], box[1], box[2]).applyMatrix4(m);
        let diag2 = 0;
        for (let k = 0; k < 3; k++) { // axis-aligned span of the box
            const span = 2 * (Math.abs(box[3 + k]) + Math.abs(box[6 + k]) + Math.abs(box[9 + k]));
            diag2 += span * span;
        }
        camera.far = 3 * Math.sqrt(diag2) + 1000 + Math.abs(eye[0] - c.x) + Math.abs(eye[1] - c.y) + Math.abs(eye[2] - c.z);
        camera.updateProjectionMatrix();
        farSet = true;
    };
    tiles.setCamera(camera);
    tiles.setResolution(camera, W, H); // the error is judged at the output size

    const t0 = performance.now();
    let quiet = 0, frames = 0, nonLeaves = 0;
    for (;;) {
        setFar();
        camera.updateMatrixWorld(true);
        tiles.update();
        frames++;
        // no drawing while the tiles load (the loader needs only update());
        // the queues run on animation frames
        await new Promise(r => requestAnimationFrame(r));
        if (errors.length) throw new Error(`tile load failed: ${errors.slice(0, 5).join('; ')}`);
        const s = tiles.stats;
        const busy = s.queued + s.downloading + s.parsing;
        nonLeaves = 0;
        for (const t of tiles.visibleTiles) if (t.children && t.children.length) nonLeaves++;
        const settled = tiles.root && busy === 0 && !tiles.isLoading && s.failed === 0 &&
            tiles.visibleTiles.size > 0 && nonLeaves === 0;
        quiet = settled ? quiet + 1 : 0;
        if (quiet >= 3) break;
        if (performance.now() - t0 > timeoutMs)
            throw new Error(`not settled after ${timeoutMs} ms: queued ${s.queued}, downloading ${s.downloading}, ` +
                `parsing ${s.parsing}, failed ${s.failed}, loaded ${s.loaded}, visible ${tiles.visibleTiles.size} ` +
                `(${nonLeaves} not leaves), isLoading ${tiles.isLoading}, root ${!!tiles.root}`);
    }
    renderer.render(scene, camera);

    // read back 2W x 2H, box-filter to W x H, top row first
    const SW = W * ss, SH = H * ss;
    const px = new Uint8Array(SW * SH * 4);
    gl.readPixels(0, 0, SW, SH, gl.RGBA, gl.UNSIGNED_BYTE, px);
    const out = new ImageData(W, H);
    for (let y = 0; y < H; y++) for (let x = 0; x < W; x++) for (let c = 0; c < 3; c++) {
        let sum = 0;
        for (let j = 0; j < ss; j++) for (let i = 0; i < ss; i++)
            sum += px[((SH - 1 - (y * ss + j)) * SW + x * ss + i) * 4 + c];
        out.data[(y * W + x) * 4 + c] = Math.round(sum / (ss * ss));
        out.data[(y * W + x) * 4 + 3] = 255;
    }
    const c2 = document.createElement('canvas');
    c2.width = W; c2.height = H;
    c2.getContext('2d').putImageData(out, 0, 0);
    const visibleTiles = tiles.visibleTiles.size;
    let visibleTris = 0;
    for (const t of tiles.visibleTiles) {
        const sc = t.cached?.scene ?? t.engineData?.scene;
        sc?.traverse(o => { if (o.isMesh) visibleTris += (o.geometry.index ? o.geometry.index.count : o.geometry.attributes.position.count) / 3; });
    }
    const result = {
        png: c2.toDataURL('image/png'),
        ms: Math.round(performance.now() - t0), frames, models, meshes, triangles,
        visibleTiles, visibleTris, loaded: tiles.stats.loaded, far: camera.far, ...info,
    };
    tiles.dispose();
    renderer.dispose();
    return result;
};
window.hlodReady = true;
