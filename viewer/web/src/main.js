// The trainee page: renders the session's event stream (/events, server-sent events) with
// three.js. Bundled by esbuild into ../dist/viewer.js (see ../build.sh); nothing is fetched
// at run time beyond this server.
import {
  WebGLRenderer, Scene, PerspectiveCamera, Color, BufferGeometry, BufferAttribute, Mesh,
  MeshStandardMaterial, DirectionalLight, AmbientLight, ArrowHelper, Vector3, Quaternion,
  CylinderGeometry, SphereGeometry, Group, DoubleSide, AxesHelper,
} from 'three';

const status = document.getElementById('viewer-status');
const $ = (id) => document.getElementById(id);

// ---- 3D scene -------------------------------------------------------------------------
const host = $('scene');
const renderer = new WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio || 1);
host.appendChild(renderer.domElement);
const scene = new Scene();
scene.background = new Color(0x1b2430);
// Scene units: metres, z up (REP-103), as the session publishes.
const camera = new PerspectiveCamera(40, 1, 0.001, 10);
camera.up.set(0, 0, 1);
scene.add(new AmbientLight(0xffffff, 0.55));
const sun = new DirectionalLight(0xffffff, 1.6);
sun.position.set(0.1, -0.2, 0.3);
scene.add(sun);
const axes = new AxesHelper(0.01);
scene.add(axes);

const meshGeometry = new BufferGeometry();
const meniscus = new Mesh(meshGeometry, new MeshStandardMaterial({
  color: 0xeecbbd, roughness: 0.6, metalness: 0.0, side: DoubleSide,
}));
meniscus.visible = false;
scene.add(meniscus);

// Probe: a tip sphere and a shaft along the probe's local +z.
const probe = new Group();
const shaft = new Mesh(new CylinderGeometry(0.0006, 0.0006, 0.03, 12),
  new MeshStandardMaterial({ color: 0xb8c4d0, metalness: 0.6, roughness: 0.3 }));
shaft.rotation.x = Math.PI / 2;
shaft.position.z = 0.015;
probe.add(shaft);
probe.add(new Mesh(new SphereGeometry(0.0012, 16, 12),
  new MeshStandardMaterial({ color: 0xdfe6ee, metalness: 0.6, roughness: 0.3 })));
probe.visible = false;
scene.add(probe);
// Force arrow at the probe tip, 5 mm per newton.
const ARROW_M_PER_N = 0.005;
const arrow = new ArrowHelper(new Vector3(0, 0, 1), new Vector3(), 0.001, 0xffb347, 0.003, 0.002);
arrow.visible = false;
scene.add(arrow);

let framed = false;
function frameCamera() {
  meshGeometry.computeBoundingSphere();
  const s = meshGeometry.boundingSphere;
  if (!s || !isFinite(s.radius) || s.radius <= 0) return;
  const d = s.radius * 2.8;
  camera.position.set(s.center.x + d * 0.35, s.center.y - d * 0.8, s.center.z + d * 0.6);
  camera.lookAt(s.center);
  camera.near = d / 100; camera.far = d * 20; camera.updateProjectionMatrix();
  framed = true;
}

function resize() {
  const w = host.clientWidth || 640, h = host.clientHeight || 480;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

// ---- stream -------------------------------------------------------------------------
const counts = { frames: 0, mesh: 0, state: 0 };
let vertices = 0;
let lastForce = 0;
const latencies = [];
const history = []; // [t_ms, |f|]

function b64(text) {
  const bin = atob(text);
  const bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  return bytes.buffer;
}

function onTopology(msg) {
  const idx = new Uint32Array(b64(msg.indices));
  meshGeometry.setIndex(new BufferAttribute(idx, 1));
  if (!meshGeometry.getAttribute('position') ||
      meshGeometry.getAttribute('position').count !== msg.vertices) {
    meshGeometry.setAttribute('position',
      new BufferAttribute(new Float32Array(msg.vertices * 3), 3));
  }
  framed = false;
}

function onMesh(msg) {
  const pos = new Float32Array(b64(msg.positions));
  const attr = meshGeometry.getAttribute('position');
  if (!attr || attr.count !== msg.vertices || !meshGeometry.getIndex()) return;
  attr.array.set(pos);
  attr.needsUpdate = true;
  meshGeometry.computeVertexNormals();
  meniscus.visible = true;
  vertices = msg.vertices;
  counts.mesh++;
  counts.frames++;
  if (!framed) frameCamera();
}

function onState(msg) {
  counts.state++;
  counts.frames++;
  lastForce = msg.force_n;
  const p = msg.probe_position, q = msg.probe_orientation;
  probe.position.set(p[0], p[1], p[2]);
  probe.quaternion.copy(new Quaternion(q[0], q[1], q[2], q[3]));
  probe.visible = true;
  if (msg.force_n > 1e-3) {
    const f = new Vector3(msg.force[0], msg.force[1], msg.force[2]);
    arrow.position.set(p[0], p[1], p[2]);
    arrow.setDirection(f.clone().normalize());
    arrow.setLength(Math.max(msg.force_n * ARROW_M_PER_N, 0.002), 0.003, 0.002);
    arrow.visible = true;
  } else {
    arrow.visible = false;
  }
  const now = Date.now();
  latencies.push(now - msg.stamp_ms);
  if (latencies.length > 120) latencies.shift();
  history.push([now, msg.force_n]);
  while (history.length && history[0][0] < now - 10000) history.shift();
  const s = msg.status;
  $('force-big').textContent = msg.force_n.toFixed(2) + ' N';
  $('region').textContent = s.region;
  $('probing').textContent = s.probing ? '#' + s.probing : 'no';
  $('contacts').textContent = s.contacts;
  $('physics-hz').textContent = s.physics_hz.toFixed(0) + ' Hz';
  $('haptic-hz').textContent = s.haptic_hz.toFixed(0) + ' Hz';
  $('rendered').textContent = msg.rendered_n.toFixed(2) + ' N';
  $('faults').textContent = s.faults.length ? s.faults.join(', ') : 'none';
}

let training = { state: 'idle' };
function onTraining(msg) {
  training = msg;
  status.dataset.training = msg.state;
  const prompt = $('prompt');
  const buttons = $('grade-buttons');
  buttons.textContent = '';
  if (msg.state === 'probing') {
    prompt.textContent = `Specimen ${msg.case} of ${msg.cases}: probe it, then choose its grade.`;
    for (let g = 0; g < msg.grades; g++) {
      const b = document.createElement('button');
      b.textContent = 'Grade ' + g;
      b.id = 'answer-' + g;
      b.onclick = () => answer(msg.case, g);
      buttons.appendChild(b);
    }
  } else if (msg.state === 'answered') {
    prompt.textContent = `Answer for specimen ${msg.case} stored; loading the next one…`;
  } else if (msg.state === 'finished') {
    prompt.textContent = `Done: ${msg.correct} of ${msg.cases} correct. Your report is in the terminal and the session folder.`;
  } else {
    prompt.textContent = 'No training running.';
  }
}

function answer(caseIndex, grade) {
  for (const b of document.querySelectorAll('#grade-buttons button')) b.disabled = true;
  fetch('/answer', { method: 'POST', body: `case=${caseIndex}&grade=${grade}`,
    headers: { 'Content-Type': 'application/x-www-form-urlencoded' } })
    .catch(() => { for (const b of document.querySelectorAll('#grade-buttons button')) b.disabled = false; });
}

const events = new EventSource('/events');
events.onopen = () => { $('conn').textContent = 'connected to ' + location.host; };
events.onerror = () => { $('conn').textContent = 'reconnecting…'; };
const guard = (fn) => (e) => { try { fn(JSON.parse(e.data)); } catch (err) { console.error(err); } };
events.addEventListener('topology', guard(onTopology));
events.addEventListener('mesh', guard(onMesh));
events.addEventListener('state', guard(onState));
events.addEventListener('training', guard(onTraining));

// ---- force plot ---------------------------------------------------------------------
const plot = $('plot');
const pctx = plot.getContext('2d');
function drawPlot() {
  const w = plot.width = plot.clientWidth || 900, h = plot.height;
  pctx.fillStyle = '#0b0f14'; pctx.fillRect(0, 0, w, h);
  const maxF = Math.max(1, ...history.map((x) => x[1]));
  pctx.strokeStyle = '#2a3440'; pctx.lineWidth = 1;
  for (let k = 1; k < 4; k++) { pctx.beginPath(); pctx.moveTo(0, h * k / 4); pctx.lineTo(w, h * k / 4); pctx.stroke(); }
  pctx.fillStyle = '#8fa3b8'; pctx.font = '11px sans-serif';
  pctx.fillText(maxF.toFixed(1) + ' N', 4, 12);
  if (history.length < 2) return;
  const now = Date.now();
  pctx.strokeStyle = '#ffb347'; pctx.lineWidth = 2; pctx.beginPath();
  history.forEach(([t, f], i) => {
    const x = w * (1 - (now - t) / 10000), y = h - 4 - (h - 16) * f / maxF;
    if (i) pctx.lineTo(x, y); else pctx.moveTo(x, y);
  });
  pctx.stroke();
}

// ---- render loop and the test-visible status ------------------------------------------
let rendered = 0, fps = 0, fpsWindow = performance.now(), fpsFrames = 0;
const probeCanvas = document.createElement('canvas');
probeCanvas.width = 32; probeCanvas.height = 24;
const probeCtx = probeCanvas.getContext('2d', { willReadFrequently: true });

// Pixels of the 3D view that differ from the background: proof that something is drawn.
function paintedPixels() {
  probeCtx.drawImage(renderer.domElement, 0, 0, probeCanvas.width, probeCanvas.height);
  const d = probeCtx.getImageData(0, 0, probeCanvas.width, probeCanvas.height).data;
  let n = 0;
  for (let i = 0; i < d.length; i += 4) {
    if (Math.abs(d[i] - 0x1b) + Math.abs(d[i + 1] - 0x24) + Math.abs(d[i + 2] - 0x30) > 40) n++;
  }
  return n;
}

function median(a) {
  if (!a.length) return NaN;
  const s = [...a].sort((x, y) => x - y);
  return s[Math.floor(s.length / 2)];
}

function loop() {
  renderer.render(scene, camera);
  rendered++; fpsFrames++;
  const t = performance.now();
  if (t - fpsWindow >= 1000) {
    fps = fpsFrames * 1000 / (t - fpsWindow); fpsWindow = t; fpsFrames = 0;
    drawPlot();
    const lat = median(latencies);
    $('fps').textContent = fps.toFixed(0);
    $('latency').textContent = isFinite(lat) ? lat.toFixed(0) + ' ms' : '–';
    status.dataset.fps = fps.toFixed(1);
    status.dataset.latencyMs = isFinite(lat) ? lat.toFixed(1) : '';
    status.dataset.painted = String(paintedPixels());
  }
  status.dataset.frames = String(counts.frames);
  status.dataset.meshFrames = String(counts.mesh);
  status.dataset.stateFrames = String(counts.state);
  status.dataset.vertices = String(vertices);
  status.dataset.forceN = lastForce.toFixed(4);
  status.dataset.rendered = String(rendered);
  status.textContent = `${counts.frames} frames, ${vertices} vertices, |f| ${lastForce.toFixed(2)} N`;
  requestAnimationFrame(loop);
}
requestAnimationFrame(loop);
window.arthrosimViewer = { counts, get training() { return training; } };
