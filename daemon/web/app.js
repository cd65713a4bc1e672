// The live page: one Server-Sent Events stream (/events, one event per journal line, `state`
// events with the source's state) drives the numbers, the plots, the 3D view (/latest.ply) and
// the slices (/slices/*.png). No framework; three.js is Debian's libjs-three served by sonomeshd.
'use strict';

const PLOT_WINDOW_MS = 5 * 60 * 1000;  // the plots show the last five minutes
const AXES = ['axial', 'coronal', 'sagittal'];

// What the page shows, also read by the browser test.
const live = window.sonomesh = {
  events: 0, processed: 0, counts: {}, lastSequence: null, sourceState: null,
  meshSequence: null, meshVertices: 0, meshLoads: 0, slicesSequence: null, slicesLoaded: 0,
  history: [],
};

const $ = (id) => document.getElementById(id);

// ---- numbers -------------------------------------------------------------------------------

function showProcessed(line) {
  $('n-sequence').textContent = line.sequence;
  $('n-genus').textContent = line.genus;
  $('n-volume').textContent = line.volume_ml !== undefined ? line.volume_ml.toFixed(2) + ' mL' : '–';
  const quality = line.quality || '–';
  const q = $('n-quality');
  q.textContent = quality + (line.quality_reasons && line.quality_reasons.length
                               ? ' (' + line.quality_reasons.join(', ') + ')' : '');
  q.className = quality === 'suspect' ? 'suspect' : '';
  $('n-latency').textContent =
      line.latency_ms !== undefined ? Math.round(line.latency_ms) + ' ms' : '–';
}

function showCounts() {
  $('n-counts').textContent = Object.entries(live.counts).map(([k, v]) => k + ' ' + v).join(', ');
}

function showConnection(kind, text) {
  const badge = $('connection');
  badge.className = 'badge ' + kind;
  badge.textContent = text;
}

function showSourceState(state) {
  live.sourceState = state.source ? state.source.state : null;
  $('source').textContent = state.source ? state.source.uri : '';
  const banner = $('banner');
  if (live.sourceState && live.sourceState !== 'connected') {
    const why = state.last_error ? ': ' + state.last_error.message : '';
    banner.textContent = live.sourceState === 'ended'
        ? 'The source ended: no more volumes will arrive.'
        : 'Probe disconnected (' + live.sourceState + ')' + why;
    banner.classList.remove('hidden');
  } else {
    banner.classList.add('hidden');
  }
}

// ---- plots ---------------------------------------------------------------------------------

function drawPlot(canvas, key, label, unit) {
  const ctx = canvas.getContext('2d');
  const w = canvas.width, h = canvas.height, pad = 4;
  ctx.clearRect(0, 0, w, h);
  const now = Date.now();
  const points = live.history.filter((p) => p[key] !== undefined && now - p.t <= PLOT_WINDOW_MS);
  ctx.fillStyle = '#8b96a3';
  ctx.font = '12px system-ui, sans-serif';
  if (points.length === 0) {
    ctx.fillText(label + ': no data yet', 8, 16);
    return;
  }
  let lo = Math.min(...points.map((p) => p[key])), hi = Math.max(...points.map((p) => p[key]));
  if (hi - lo < 1e-9) { lo -= 1; hi += 1; }
  const x = (t) => pad + (w - 2 * pad) * (1 - (now - t) / PLOT_WINDOW_MS);
  const y = (v) => h - pad - (h - 2 * pad - 14) * (v - lo) / (hi - lo);
  ctx.strokeStyle = '#58a6ff';
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  points.forEach((p, i) => (i ? ctx.lineTo(x(p.t), y(p[key])) : ctx.moveTo(x(p.t), y(p[key]))));
  ctx.stroke();
  const last = points[points.length - 1][key];
  ctx.fillText(label + ' ' + last.toFixed(unit === 'ms' ? 0 : 2) + ' ' + unit + '  (' +
               lo.toFixed(1) + '–' + hi.toFixed(1) + ', last 5 min)', 8, 14);
}

function drawPlots() {
  drawPlot($('plot-volume'), 'volume_ml', 'volume', 'mL');
  drawPlot($('plot-latency'), 'latency_ms', 'latency', 'ms');
}

// ---- 3D view -------------------------------------------------------------------------------

const view = { renderer: null, scene: null, camera: null, controls: null, mesh: null,
               framed: false, loading: false, wanted: null };

function initView() {
  const el = $('view3d');
  try {
    if (!window.THREE || !THREE.PLYLoader || !THREE.OrbitControls) throw new Error('no three.js');
    view.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  } catch (e) {
    $('no3d').classList.remove('hidden');
    return;
  }
  view.renderer.setPixelRatio(window.devicePixelRatio || 1);
  el.appendChild(view.renderer.domElement);
  view.scene = new THREE.Scene();
  view.scene.background = new THREE.Color(0x05070a);
  view.camera = new THREE.PerspectiveCamera(40, 1, 0.1, 5000);
  view.scene.add(new THREE.HemisphereLight(0xffffff, 0x303040, 0.9));
  const sun = new THREE.DirectionalLight(0xffffff, 0.6);
  sun.position.set(1, 2, 3);
  view.camera.add(sun);
  view.scene.add(view.camera);
  view.controls = new THREE.OrbitControls(view.camera, view.renderer.domElement);
  view.controls.addEventListener('change', render);
  window.addEventListener('resize', resizeView);
  resizeView();
}

function resizeView() {
  if (!view.renderer) return;
  const el = $('view3d');
  const w = Math.max(320, el.clientWidth), h = Math.max(320, el.clientHeight);
  view.renderer.setSize(w, h);
  view.camera.aspect = w / h;
  view.camera.updateProjectionMatrix();
  render();
}

function render() {
  if (view.renderer) view.renderer.render(view.scene, view.camera);
}

// One load in flight; a newer sequence that arrives meanwhile is loaded right after.
function loadMesh(sequence) {
  if (!view.renderer) return;
  view.wanted = sequence;
  if (view.loading) return;
  view.loading = true;
  new THREE.PLYLoader().load('/latest.ply?seq=' + sequence, (geometry) => {
    geometry.computeVertexNormals();
    const material = new THREE.MeshPhongMaterial({ color: 0xe0b080, specular: 0x222222,
                                                   shininess: 30, side: THREE.DoubleSide });
    if (view.mesh) { view.scene.remove(view.mesh); view.mesh.geometry.dispose(); }
    view.mesh = new THREE.Mesh(geometry, material);
    view.scene.add(view.mesh);
    if (!view.framed) frameMesh(geometry);
    render();
    live.meshSequence = sequence;
    live.meshVertices = geometry.attributes.position.count;
    live.meshLoads += 1;
    finishLoad(sequence);
  }, undefined, () => finishLoad(sequence));
}

function finishLoad(sequence) {
  view.loading = false;
  if (view.wanted !== sequence) loadMesh(view.wanted);
}

// The first mesh sets the camera; later ones keep the user's rotation and zoom.
function frameMesh(geometry) {
  geometry.computeBoundingSphere();
  const s = geometry.boundingSphere;
  view.controls.target.copy(s.center);
  view.camera.position.set(s.center.x + 2.2 * s.radius, s.center.y - 2.2 * s.radius,
                           s.center.z + 1.6 * s.radius);
  view.camera.up.set(0, 0, 1);
  view.controls.update();
  view.framed = true;
}

// ---- slices --------------------------------------------------------------------------------

let sliceInfo = null;

// Each slice is fetched off screen and shown once it decoded, so a failed load (the daemon
// restarting) keeps the last good image instead of a broken one.
function loadSlices(sequence) {
  live.slicesSequence = sequence;
  for (const axis of AXES) {
    const next = new Image();
    next.onload = () => {
      $('slice-' + axis).src = next.src;
      live.slicesLoaded += 1;
    };
    next.src = '/slices/' + axis + '.png?seq=' + sequence;
  }
  fetch('/slices/info', { cache: 'no-store' }).then((r) => r.json())
      .then((info) => { sliceInfo = info; }).catch(() => {});
}

function onSliceClick(axis, event) {
  if (!sliceInfo || !sliceInfo.slices) return;
  const img = event.currentTarget, s = sliceInfo.slices[axis];
  const width = sliceInfo.dims[s.u_axis], height = sliceInfo.dims[s.v_axis];
  let u = event.offsetX / img.clientWidth * width - 0.5;
  let v = event.offsetY / img.clientHeight * height - 0.5;
  if (s.v_up) v = height - 1 - v;
  const ijk = sliceInfo.seed_index.slice();
  ijk[s.u_axis] = u;
  ijk[s.v_axis] = v;
  // POST /seed takes world mm: origin + D (spacing * ijk), D column-major (column = index axis).
  const step = ijk.map((c, a) => sliceInfo.spacing_mm[a] * c);
  const d = sliceInfo.direction || [1, 0, 0, 0, 1, 0, 0, 0, 1];
  const seed = [0, 1, 2].map((r) => sliceInfo.origin_mm[r] +
      d[r] * step[0] + d[3 + r] * step[1] + d[6 + r] * step[2]);
  fetch('/seed', { method: 'POST', body: JSON.stringify({ seed_mm: seed }) })
      .then((r) => r.json())
      .then((j) => {
        $('banner').textContent = j.error ? 'seed refused: ' + j.error
            : 'seed set to ' + seed.map((c) => c.toFixed(1)).join(', ') + ' mm (next volume)';
        $('banner').classList.remove('hidden');
        setTimeout(() => $('banner').classList.add('hidden'), 3000);
      });
}

// ---- events --------------------------------------------------------------------------------

let pendingSequence = null;  // a burst of lines (the replay on connect) loads only the newest

function onJournalLine(line) {
  live.events += 1;
  live.counts[line.status] = (live.counts[line.status] || 0) + 1;
  if (line.status === 'processed') {
    live.processed += 1;
    live.lastSequence = line.sequence;
    live.history.push({ t: Date.parse(line.time) || Date.now(), volume_ml: line.volume_ml,
                        latency_ms: line.latency_ms });
    while (live.history.length > 5000) live.history.shift();
    showProcessed(line);
    if (pendingSequence === null) setTimeout(loadLatest, 30);
    pendingSequence = line.sequence;
  }
}

function loadLatest() {
  const sequence = pendingSequence;
  pendingSequence = null;
  loadMesh(sequence);
  loadSlices(sequence);
  drawPlots();
  showCounts();
}

function connect() {
  const events = new EventSource('/events');
  events.onopen = () => showConnection('ok', 'live');
  events.onmessage = (e) => {
    try { onJournalLine(JSON.parse(e.data)); } catch (err) { console.error(err); }
    showCounts();
  };
  events.addEventListener('state', (e) => showSourceState(JSON.parse(e.data)));
  // EventSource reconnects by itself and sends Last-Event-ID, so nothing is missed.
  events.onerror = () => showConnection('bad', 'daemon unreachable, retrying');
}

for (const axis of AXES) {
  const img = $('slice-' + axis);
  img.addEventListener('click', (e) => onSliceClick(axis, e));
}
initView();
drawPlots();
setInterval(drawPlots, 2000);
connect();
