// The viewer's page. It draws what the server describes — /api/run (the path, the keyframes, the latency report)
// and /api/map (the map in per-keyframe blocks; the layout is written down in shared/viewer/src/encode.rs) — and
// cannot steer anything: it only reads.
import * as THREE from '/vendor/three/three.module.js';
import { OrbitControls } from '/vendor/three/OrbitControls.js';

const STATE_COLOURS = { ok: 0xffcd3c, uncertain: 0xff8c1a, lost: 0xe0303a, unknown: 0x9a9a9a };
const FRUSTUM_COLOUR = 0x5ac8ff;
const MAP_MAGIC = 'BDISMAP1';
const KEYFRAME_HEADER_BYTES = 4 * (4 + 6 + 16);

// Colours are taken as they are written — the endoscope's bytes, the page's palette — with no conversion.
THREE.ColorManagement.enabled = false;
const canvas = document.getElementById('scene');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
renderer.setClearColor(0x18181c);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 1e7);
const controls = new OrbitControls(camera, canvas);
controls.enableDamping = false;
const viewportHeight = { value: 1 };

// Points shaded from their normals, as map.png is: a light at the eye and one from above, both two-sided (the
// map may be looked at from behind the surface the scope saw). A point stands for a patch spacingPerDepth · z
// wide, z its depth in its own keyframe, so the map reads as a surface at any zoom.
const VERTEX_SHADER = `
uniform float spacingPerDepth;
uniform float viewportHeight;
varying vec3 vColour;
void main() {
  vec4 mv = modelViewMatrix * vec4(position, 1.0);
  vec3 n = normalize(normalMatrix * normal);
  vec3 toEye = normalize(-mv.xyz);
  vec3 key = normalize(vec3(-0.4, 0.7, 0.6));
  float lit = 0.28 + 0.62 * abs(dot(n, toEye)) + 0.3 * abs(dot(n, key));
  vColour = color * min(lit, 1.15);
  gl_Position = projectionMatrix * mv;
  float patchSize = spacingPerDepth * position.z;
  gl_PointSize = clamp(1.5 * patchSize * projectionMatrix[1][1] * 0.5 * viewportHeight / -mv.z, 1.0, 32.0);
}`;
const FRAGMENT_SHADER = `
varying vec3 vColour;
void main() { gl_FragColor = vec4(min(vColour, vec3(1.0)), 1.0); }`;

/** The map's blocks, by keyframe id: a correction later moves one block's matrix. */
const blocks = new Map();

/** One keyframe block at byte `at` of `buffer`: the block and where the next one starts. */
function parseBlock(buffer, at) {
  const view = new DataView(buffer);
  const id = view.getUint32(at, true) + view.getUint32(at + 4, true) * 2 ** 32;
  const n = view.getUint32(at + 8, true);
  const header = new Float32Array(buffer, at + 12, 1 + 6 + 16);
  const [fx, fy, cx, cy, width, height] = header.slice(1, 7);
  const block = {
    id, n, spacingPerDepth: header[0], intrinsics: { fx, fy, cx, cy, width, height },
    worldFromCamera: new THREE.Matrix4().fromArray(header, 7),
  };
  at += KEYFRAME_HEADER_BYTES;
  block.positions = new Float32Array(buffer, at, 3 * n); at += 12 * n;
  block.normals = new Int8Array(buffer, at, 3 * n); at += 3 * n;
  block.colours = new Uint8Array(buffer, at, 3 * n); at += 3 * n;
  return { block, next: (at + 3) & ~3 };
}

function parseMap(buffer) {
  const magic = new TextDecoder().decode(new Uint8Array(buffer, 0, 8));
  if (magic !== MAP_MAGIC) throw new Error(`/api/map: not a bdis-slam map (starts ${JSON.stringify(magic)})`);
  const count = new DataView(buffer).getUint32(8, true);
  const parsed = [];
  let at = 16;
  for (let i = 0; i < count; i++) {
    const { block, next } = parseBlock(buffer, at);
    parsed.push(block);
    at = next;
  }
  if (at !== buffer.byteLength) throw new Error(`/api/map: ${buffer.byteLength - at} bytes after the last keyframe`);
  return parsed;
}

function removeBlock(id) {
  const old = blocks.get(id);
  if (!old) return;
  scene.remove(old.points);
  old.points.geometry.dispose();
  old.points.material.dispose();
  blocks.delete(id);
}

function addBlock(block) {
  removeBlock(block.id);
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(block.positions, 3));
  geometry.setAttribute('normal', new THREE.BufferAttribute(block.normals, 3, true));
  geometry.setAttribute('color', new THREE.BufferAttribute(block.colours, 3, true));
  const material = new THREE.ShaderMaterial({
    uniforms: { spacingPerDepth: { value: block.spacingPerDepth }, viewportHeight },
    vertexColors: true, vertexShader: VERTEX_SHADER, fragmentShader: FRAGMENT_SHADER,
  });
  const points = new THREE.Points(geometry, material);
  points.matrixAutoUpdate = false;
  points.matrix.copy(block.worldFromCamera);
  scene.add(points);
  blocks.set(block.id, { ...block, points });
}

function poseMatrix(pose) {
  const [x, y, z, w] = pose.orientation_xyzw;
  return new THREE.Matrix4().compose(new THREE.Vector3(...pose.position), new THREE.Quaternion(x, y, z, w),
    new THREE.Vector3(1, 1, 1));
}

function addPath(path, keyframes) {
  const added = [];
  if (path.length > 1) {
    const positions = new Float32Array(path.flatMap((p) => p.position));
    const colours = new Float32Array(path.flatMap((p) => new THREE.Color(STATE_COLOURS[p.state] ?? STATE_COLOURS.unknown).toArray()));
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    geometry.setAttribute('color', new THREE.BufferAttribute(colours, 3));
    added.push(new THREE.Line(geometry, new THREE.LineBasicMaterial({ vertexColors: true })));
  }
  if (keyframes.length > 0) {
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(keyframes.flatMap((p) => p.position)), 3));
    added.push(new THREE.Points(geometry, new THREE.PointsMaterial({ color: 0xfff3c0, size: 3, sizeAttenuation: false })));
  }
  added.forEach((o) => scene.add(o));
  return added;
}

function removeObject(object) {
  if (!object) return;
  scene.remove(object);
  object.geometry?.dispose();
  object.material?.dispose();
}

/** The scope at `pose`: its centre and its image's four corners `size` in front of it. */
function addFrustum(pose, intrinsics, size) {
  const { fx, fy, cx, cy, width, height } = intrinsics;
  const corner = (u, v) => new THREE.Vector3((u - cx) / fx, (v - cy) / fy, 1).multiplyScalar(size);
  const c = [corner(0, 0), corner(width, 0), corner(width, height), corner(0, height)];
  const apex = new THREE.Vector3();
  const segments = [];
  for (let i = 0; i < 4; i++) segments.push(apex, c[i], c[i], c[(i + 1) % 4]);
  const geometry = new THREE.BufferGeometry().setFromPoints(segments);
  const frustum = new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ color: FRUSTUM_COLOUR }));
  frustum.matrixAutoUpdate = false;
  frustum.matrix.copy(poseMatrix(pose));
  scene.add(frustum);
  return frustum;
}

/** Frames the map and the path from the scope's side, raised so the relief shows; across a long flight. */
function frame(path) {
  const box = new THREE.Box3();
  for (const b of blocks.values()) {
    b.points.geometry.computeBoundingBox();
    box.union(b.points.geometry.boundingBox.clone().applyMatrix4(b.worldFromCamera));
  }
  for (const p of path) box.expandByPoint(new THREE.Vector3(...p.position));
  if (box.isEmpty()) return 1;
  const centre = box.getCenter(new THREE.Vector3());
  const radius = Math.max(box.getSize(new THREE.Vector3()).length() / 2, 1e-6);
  const forward = new THREE.Vector3();
  const down = new THREE.Vector3();
  // The scope's mean view, from its path (else from the keyframes that made the map).
  const views = path.length ? path.map(poseMatrix) : [...blocks.values()].map((b) => b.worldFromCamera);
  for (const m of views) {
    forward.add(new THREE.Vector3().setFromMatrixColumn(m, 2));
    down.add(new THREE.Vector3().setFromMatrixColumn(m, 1));
  }
  forward.normalize();
  const up = down.negate().addScaledVector(forward, -down.dot(forward)).normalize();
  const travelled = path.length > 1 ? new THREE.Vector3(...path.at(-1).position).sub(new THREE.Vector3(...path[0].position)) : new THREE.Vector3();
  let from;
  if (travelled.length() > 0.5 * radius) {
    // A flight along the map: look across it from above, the way travelled running left to right.
    from = up.clone().multiplyScalar(2.0).addScaledVector(forward, -0.6).normalize();
    const right = travelled.clone().addScaledVector(from, -travelled.dot(from)).normalize();
    camera.up.copy(right.clone().cross(from.clone().negate()));
  } else {
    from = forward.clone().multiplyScalar(-1.6).addScaledVector(up, 1.1).normalize();
    camera.up.copy(up);
  }
  camera.position.copy(centre).addScaledVector(from, 1.9 * radius);
  camera.near = radius / 1000;
  camera.far = radius * 100;
  camera.updateProjectionMatrix();
  controls.target.copy(centre);
  controls.update();
  return radius;
}

function resize() {
  const { clientWidth: w, clientHeight: h } = canvas;
  renderer.setPixelRatio(window.devicePixelRatio || 1);
  renderer.setSize(w, h, false);
  viewportHeight.value = h * renderer.getPixelRatio();
  camera.aspect = w / Math.max(h, 1);
  camera.updateProjectionMatrix();
}

/** The process table: one row of cells per process; the last cell (restarts) is marked when not 0. */
function fillTable(rows, cpuHeading) {
  document.querySelector('#processes thead th:nth-child(5)').textContent = cpuHeading;
  const body = document.querySelector('#processes tbody');
  body.replaceChildren();
  for (const cells of rows) {
    const row = document.createElement('tr');
    for (const [i, text] of cells.entries()) {
      const cell = document.createElement('td');
      cell.textContent = text;
      if (i === cells.length - 1 && text !== '0') cell.className = 'bad';
      row.append(cell);
    }
    body.append(row);
  }
}

function fillEvents(list) {
  const events = document.getElementById('events');
  events.replaceChildren();
  for (const e of list) {
    const item = document.createElement('li');
    item.textContent = e;
    events.append(item);
  }
  if (!list.length) events.textContent = 'none';
}

const fixed = (v, digits) => (v == null ? '–' : v.toFixed(digits));

function showProcesses(latency) {
  const restarts = new Map((latency?.services ?? []).map((s) => [s.name, s.restarts]));
  const ms = (us) => (us == null ? '–' : (us / 1000).toFixed(2));
  fillTable((latency?.processes ?? []).map((p) => [p.name, fixed(p.rate_hz, 1), ms(p.processing_us?.p50),
    ms(p.processing_us?.p99), fixed(p.cpu_time_s, 2), String(restarts.get(p.name) ?? p.restarts ?? 0)]), 'CPU s');
  fillEvents(latency?.events ?? []);
}

function statusLine(keyframes, points, path) {
  const counts = { ok: 0, uncertain: 0, lost: 0 };
  for (const p of path) if (p.state in counts) counts[p.state]++;
  document.getElementById('status').textContent =
    `${keyframes} keyframes, ${points.toLocaleString()} points; ${path.length} poses ` +
    `(Ok ${counts.ok}, Uncertain ${counts.uncertain}, Lost ${counts.lost})`;
}

async function main() {
  const run = await (await fetch('/api/run')).json();
  document.getElementById('run-name').textContent = run.name;
  if (run.live) return watchLive();
  const map = parseMap(await (await fetch('/api/map')).arrayBuffer());
  map.forEach(addBlock);
  addPath(run.path, run.keyframes);
  const radius = frame(run.path);
  const newest = map.at(-1);
  const last = run.path.at(-1) ?? run.keyframes.at(-1);
  if (last) {
    const intrinsics = newest?.intrinsics ?? { fx: 1, fy: 1, cx: 0.5, cy: 0.5, width: 1, height: 1 };
    addFrustum(last, intrinsics, 0.12 * radius);
  }
  statusLine(run.map_keyframes, run.map_points, run.path);
  if (run.has_depth_preview) document.getElementById('depth').src = '/api/depth.png';
  showProcesses(run.latency);
  resize();
  window.addEventListener('resize', resize);
  renderer.setAnimationLoop(() => renderer.render(scene, camera));
  // For whoever waits on the page (a test, a screenshot): the map is drawn.
  requestAnimationFrame(() => requestAnimationFrame(() => { document.body.dataset.ready = String(map.length); }));
}

// ---- A live pipeline: the messages of shared/viewer/src/live.rs over /ws. ----

const live = { path: [], drawn: [], frustum: null, radius: 1, userMoved: false, messages: 0 };
controls.addEventListener('start', () => { live.userMoved = true; });

function tagOf(buffer) {
  return new TextDecoder().decode(new Uint8Array(buffer, 0, 4));
}

function idAt(view, at) {
  return view.getUint32(at, true) + view.getUint32(at + 4, true) * 2 ** 32;
}

/** Points a later view replaced leave the page: keep those whose bit is set. */
function trimBlock(view, buffer) {
  const id = idAt(view, 4);
  const n = view.getUint32(12, true);
  const bits = new Uint8Array(buffer, 16);
  const old = blocks.get(id);
  if (!old || old.n !== n) throw new Error(`trim of keyframe ${id}: the page holds ${old?.n} points, not ${n}`);
  const kept = [];
  for (let i = 0; i < n; i++) if (bits[i >> 3] & (1 << (i & 7))) kept.push(i);
  const pick = (array) => {
    const out = new array.constructor(3 * kept.length);
    kept.forEach((i, k) => out.set(array.subarray(3 * i, 3 * i + 3), 3 * k));
    return out;
  };
  const worldFromCamera = old.points.matrix.clone();
  addBlock({ ...old, n: kept.length, positions: pick(old.positions), normals: pick(old.normals), colours: pick(old.colours), worldFromCamera });
}

function showImage(view, buffer) {
  const w = view.getUint32(4, true);
  const h = view.getUint32(8, true);
  const panel = document.getElementById('depth');
  let canvas = document.getElementById('live-image');
  if (!canvas) {
    canvas = document.createElement('canvas');
    canvas.id = 'live-image';
    canvas.style.width = '100%';
    panel.replaceWith(canvas);
  }
  canvas.width = 2 * w;
  canvas.height = h;
  const image = new ImageData(2 * w, h);
  const rgb = new Uint8Array(buffer, 12);
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < 2 * w; x++) {
      const src = x < w ? 3 * (y * w + x) : 3 * (w * h + y * w + (x - w));
      const dst = 4 * (y * 2 * w + x);
      image.data.set([rgb[src], rgb[src + 1], rgb[src + 2], 255], dst);
    }
  }
  canvas.getContext('2d').putImageData(image, 0, 0);
}

function showLivePath() {
  live.drawn.forEach(removeObject);
  live.drawn = addPath(live.path, []);
  removeObject(live.frustum);
  const last = live.path.at(-1);
  const newest = [...blocks.values()].at(-1);
  if (last && newest) live.frustum = addFrustum(last, newest.intrinsics, 0.12 * live.radius);
}

function onLiveMessage(data) {
  live.messages++;
  if (typeof data === 'string') {
    const message = JSON.parse(data);
    if (message.type === 'poses') {
      live.path.push(...message.poses);
      showLivePath();
    } else if (message.type === 'health') {
      fillTable(message.processes.map((p) => [p.name, fixed(p.rate_hz, 1), fixed(p.processing_p50_ms, 2),
        fixed(p.processing_p99_ms, 2), fixed(p.cpu_percent, 0), String(p.restarts)]), 'CPU %');
      fillEvents(message.events);
    }
  } else {
    const view = new DataView(data);
    const tag = tagOf(data);
    if (tag === 'BLK1') addBlock(parseBlock(data, 4).block);
    else if (tag === 'TRM1') trimBlock(view, data);
    else if (tag === 'DEL1') removeBlock(idAt(view, 4));
    else if (tag === 'COR1') {
      const b = blocks.get(idAt(view, 4));
      if (b) b.points.matrix.fromArray(new Float32Array(data.slice(12, 12 + 64)));
    } else if (tag === 'IMG1') showImage(view, data);
    if (!live.userMoved && (tag === 'BLK1' || tag === 'DEL1')) live.radius = frame(live.path);
  }
  const points = [...blocks.values()].reduce((sum, b) => sum + b.n, 0);
  statusLine(blocks.size, points, live.path);
  document.body.dataset.ready = String(blocks.size);
  document.body.dataset.messages = String(live.messages);
}

function watchLive() {
  document.body.dataset.live = '1';
  resize();
  window.addEventListener('resize', resize);
  renderer.setAnimationLoop(() => renderer.render(scene, camera));
  const socket = new WebSocket(`ws://${location.host}/ws`);
  socket.binaryType = 'arraybuffer';
  socket.onmessage = (event) => {
    try {
      onLiveMessage(event.data);
    } catch (e) {
      document.body.dataset.error = e.message;
      document.getElementById('status').textContent = `error: ${e.message}`;
    }
  };
  // The run ended (or the viewer restarted): the page starts again — over the finished run when that is what
  // is served now, or live again.
  socket.onclose = () => setTimeout(() => location.reload(), 1500);
}

main().catch((e) => {
  document.getElementById('status').textContent = `error: ${e.message}`;
  document.body.dataset.error = e.message;
});
