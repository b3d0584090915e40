// The operator's page: the map preview as it grows, the camera and its path, the daemons' status,
// the coverage, and the scan buttons. The monitor pushes everything over the WebSocket /ws: text
// frames are JSON (status, pose, trajectory, correction, reset), binary frames one map chunk each (layout in
// docs/operator-view.md). window.dfState mirrors what the page shows, for tests.
'use strict';

const state = window.dfState = {
  connected: false, points: 0, chunks: 0, status: null, pose: null, commands: [], errors: [],
  needKey: null, wsUrl: null, path: [], corrections: [], graph: null,
};

// ------------------------------------------------------------------ the 3-D view
const view = document.getElementById('view');
const renderer = new THREE.WebGLRenderer({antialias: true, preserveDrawingBuffer: true});
renderer.setPixelRatio(window.devicePixelRatio);
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x111111);
const camera3d = new THREE.PerspectiveCamera(60, 1, 0.01, 100);
camera3d.position.set(0, 1.5, 3);
const controls = new THREE.OrbitControls(camera3d, renderer.domElement);
// The map is in the depth camera's frame convention (x right, y down, z forward): turned so that
// up is up on screen.
const world = new THREE.Group();
world.rotation.x = Math.PI;
scene.add(world);
scene.add(new THREE.AxesHelper(0.2));

const chunks = new Map();  // "x,y,z" -> {points, box, n, coverage, data}
let target = 0.002;         // target uncertainty of the coverage, m (from the pose message)
let colourMode = 'uncertainty';
let showCoverage = true;
let framed = false;
// The points shown and those of them below the target, over all chunks: kept as chunks come and
// go, so that a chunk costs the same however many are shown; the text is redrawn once a frame.
let coveragePoints = 0, coveredPoints = 0, coverageShown = false;

function resize() {
  const w = view.clientWidth, h = view.clientHeight;
  renderer.setSize(w, h);
  camera3d.aspect = w / Math.max(1, h);
  camera3d.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();

// Green below the target uncertainty, through yellow to red at four times it.
function uncertaintyColour(u, out, i) {
  const t = Math.min(1, Math.max(0, (u / target - 1) / 3));
  out[i] = Math.min(1, 2 * t);
  out[i + 1] = Math.min(1, 2 * (1 - t));
  out[i + 2] = 0.1;
}

function coverageColour(c) {
  return new THREE.Color().setHSL(0.33 * c, 0.9, 0.5);  // red (0) to green (1)
}

function chunkColours(c) {
  const colours = new Float32Array(3 * c.n);
  if (colourMode === 'rgb' && c.rgb) {
    for (let i = 0; i < 3 * c.n; ++i) colours[i] = c.rgb[i] / 255;
  } else {
    for (let i = 0; i < c.n; ++i) uncertaintyColour(c.uncertainty[i], colours, 3 * i);
  }
  return colours;
}

// One binary frame: u32 magic, i32 key[3], f32 centre[3], f32 coverage, u32 n, u32 flags,
// f32 xyz[3n], f32 uncertainty[n], then u8 rgb[3n] when flags & 1.
function onChunk(buffer) {
  const head = new DataView(buffer);
  if (buffer.byteLength < 40 || head.getUint32(0, true) !== 0x4b484344) return;
  const key = [head.getInt32(4, true), head.getInt32(8, true), head.getInt32(12, true)].join(',');
  const centre = [head.getFloat32(16, true), head.getFloat32(20, true), head.getFloat32(24, true)];
  const coverage = head.getFloat32(28, true);
  const n = head.getUint32(32, true), flags = head.getUint32(36, true);
  if (buffer.byteLength < 40 + 16 * n + ((flags & 1) ? 3 * n : 0)) return;
  const c = {
    n, coverage, centre, covered: Math.round(coverage * n),
    xyz: new Float32Array(buffer, 40, 3 * n),
    uncertainty: new Float32Array(buffer, 40 + 12 * n, n),
    rgb: (flags & 1) ? new Uint8Array(buffer, 40 + 16 * n, 3 * n) : null,
  };
  const old = chunks.get(key);
  if (old) {
    state.points -= old.n;
    coveragePoints -= old.n;
    coveredPoints -= old.covered;
    world.remove(old.points);
    world.remove(old.box);
    old.points.geometry.dispose();
  }
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(c.xyz, 3));
  geometry.setAttribute('color', new THREE.BufferAttribute(chunkColours(c), 3));
  c.points = new THREE.Points(geometry, new THREE.PointsMaterial({size: 0.008, vertexColors: true}));
  c.box = old ? old.box : chunkBox(centre);
  c.box.material.color = coverageColour(coverage);
  c.box.visible = showCoverage;
  world.add(c.points);
  world.add(c.box);
  chunks.set(key, c);
  state.points += n;
  state.chunks = chunks.size;
  coveragePoints += n;
  coveredPoints += c.covered;
  state.coverage = coveragePoints ? coveredPoints / coveragePoints : 0;
  coverageShown = false;
  if (!framed) {
    framed = true;
    const p = new THREE.Vector3(...centre).applyMatrix4(world.matrixWorld);
    controls.target.copy(p);
    camera3d.position.set(p.x + 1.5, p.y + 2.0, p.z + 3.5);
  }
}

let chunkSize = 0.5;
function chunkBox(centre) {
  const edges = new THREE.EdgesGeometry(new THREE.BoxBufferGeometry(chunkSize, chunkSize, chunkSize));
  const box = new THREE.LineSegments(edges, new THREE.LineBasicMaterial({transparent: true, opacity: 0.35}));
  box.position.set(...centre);
  return box;
}

function clearMap() {
  for (const c of chunks.values()) {
    world.remove(c.points);
    world.remove(c.box);
    c.points.geometry.dispose();
  }
  chunks.clear();
  state.points = 0;
  state.chunks = 0;
  coveragePoints = coveredPoints = 0;
  state.coverage = 0;
  coverageShown = false;
  trajectory.length = 0;
  framed = false;
  updateTrajectory();
}

// The camera: a small frustum at the last pose; its path as a line.
const frustum = (() => {
  const s = 0.08, d = 0.12;
  const v = [0, 0, 0, -s, -s, d, 0, 0, 0, s, -s, d, 0, 0, 0, s, s, d, 0, 0, 0, -s, s, d,
             -s, -s, d, s, -s, d, s, -s, d, s, s, d, s, s, d, -s, s, d, -s, s, d, -s, -s, d];
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(new Float32Array(v), 3));
  const f = new THREE.LineSegments(g, new THREE.LineBasicMaterial({color: 0x44aaff}));
  f.visible = false;
  world.add(f);
  return f;
})();
const trajectory = [];
const pathLine = new THREE.Line(new THREE.BufferGeometry(), new THREE.LineBasicMaterial({color: 0xffaa00}));
world.add(pathLine);
function updateTrajectory() {
  pathLine.geometry.dispose();
  pathLine.geometry = new THREE.BufferGeometry();
  pathLine.geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(trajectory), 3));
  state.trajectory = trajectory.length / 3;
  state.path = trajectory;
}

// A loop closure moved the keyframes: the monitor has moved the path (and sends all of it again);
// say so for a while.
const kNoteMs = 10000;
let noteTimer = null;
function onCorrection(m) {
  state.corrections.push(m);
  const note = document.getElementById('correction-note');
  note.textContent = `loop closure: correction ${m.version} moved the path ` +
      `(${m.poses_moved} positions, keyframes up to ${(1000 * m.max_translation_m).toFixed(1)} mm)`;
  note.hidden = false;
  clearTimeout(noteTimer);
  noteTimer = setTimeout(() => { note.hidden = true; }, kNoteMs);
}

function onPose(m) {
  state.pose = m;
  if (m.target_uncertainty_m && m.target_uncertainty_m !== target) coverageShown = false;
  target = m.target_uncertainty_m || target;
  chunkSize = m.chunk_size_m || chunkSize;
  frustum.visible = m.has_pose;
  if (m.has_pose) {
    const [w, x, y, z] = m.orientation_wxyz;
    frustum.position.set(...m.position_m);
    frustum.quaternion.set(x, y, z, w);
    // map_delta_t.TRACKING_*: tracked, uncertain, lost.
    frustum.material.color.set([0x44aaff, 0xffaa00, 0xff4444][m.tracking] ?? 0xff4444);
  }
  document.getElementById('map-figures').textContent =
      `${m.map_points} points in the map, ${state.points} shown in ${state.chunks} chunks ` +
      `(one per ${(1000 * m.cell_size_m).toFixed(0)} mm); ${m.chunks_pending} chunks waiting ` +
      `(bandwidth cap); tracking ${m.has_pose ? (['ok', 'uncertain', 'LOST'][m.tracking] ?? '?') : '-'}`;
}

function showCoverageFigures() {
  coverageShown = true;
  document.getElementById('coverage').textContent =
      `coverage: ${(100 * state.coverage).toFixed(1)} % of the points below ${(1000 * target).toFixed(1)} mm ` +
      `(boxes: per chunk, red 0 % to green 100 %)`;
}

document.getElementById('colour-mode').addEventListener('change', (e) => {
  colourMode = e.target.value;
  for (const c of chunks.values())
    c.points.geometry.setAttribute('color', new THREE.BufferAttribute(chunkColours(c), 3));
});
document.getElementById('show-coverage').addEventListener('change', (e) => {
  showCoverage = e.target.checked;
  for (const c of chunks.values()) c.box.visible = showCoverage;
});

// ------------------------------------------------------------------ status
function cell(row, text, cls) {
  const td = row.insertCell();
  td.textContent = text;
  if (cls) td.className = cls;
}
function onStatus(st) {
  state.status = st;
  const body = document.querySelector('#daemons tbody');
  body.innerHTML = '';
  const errors = [];
  for (const d of st.daemons) {
    const row = body.insertRow();
    cell(row, d.name);
    cell(row, d.alive ? 'yes' : 'STALE', d.alive ? 'good' : 'bad');
    cell(row, d.state, d.state === 'error' ? 'bad' : '');
    cell(row, d.input_rate_hz.toFixed(1));
    cell(row, d.output_rate_hz.toFixed(1));
    cell(row, d.frames_dropped);
    cell(row, d.point_count);
    if (d.last_error) errors.push(`${d.name}: ${d.last_error}`);
    if (d.name === 'fusion') {
      showGraph(d.counters);
      showFrames(d);
      document.getElementById('scan').textContent =
          d.scan_id ? `scan ${d.scan_id} (${d.state})` : `no scan (${d.state})`;
      if (d.last_command_message)
        document.getElementById('command').textContent = d.last_command_message;
    }
  }
  document.getElementById('errors').textContent = errors.join('\n');
}

// The fusion daemon's pose graph from its heartbeat counters (docs/protocol.md, heartbeat_t).
function showGraph(c) {
  const shown = document.getElementById('graph');
  if (c.keyframes === undefined) {
    state.graph = null;
    shown.textContent = 'pose graph: -';
    return;
  }
  state.graph = c;
  const plural = (n, one, many) => `${n} ${n === 1 ? one : many}`;
  shown.textContent = `pose graph: ${plural(c.keyframes, 'keyframe', 'keyframes')}, ` +
      `${plural(c.loop_closures, 'loop closure', 'loop closures')}, ` +
      (c.graph_corrections ? `${plural(c.graph_corrections, 'correction', 'corrections')} ` +
                             `(last moved the map ${Number(c.last_correction_mm).toFixed(1)} mm)`
                           : 'no correction yet');
  shown.title = `loop candidates ${c.loop_candidates}, gated ${c.loops_gated}, ` +
      `rejected ${c.loops_rejected}`;
}

// What became of the frames the fusion daemon received: fused into the map, tracked only (fusion
// shed while the daemon was behind its camera), lost by tracking, dropped by its queue.
function showFrames(d) {
  const c = d.counters;
  document.getElementById('frames').textContent =
      `frames: ${d.frames_out} fused, ${c.frames_fusion_shed ?? 0} tracked only (fusion behind), ` +
      `${c.frames_lost_tracking ?? 0} lost, ${d.frames_dropped} dropped`;
}

// ------------------------------------------------------------------ the connection
function connect() {
  // Over https (a TLS proxy in front of the monitor) the browser allows only a secure WebSocket.
  state.wsUrl = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`;
  const ws = new WebSocket(state.wsUrl);
  ws.binaryType = 'arraybuffer';
  const shown = document.getElementById('connection');
  ws.onopen = () => {
    state.connected = true;
    shown.textContent = 'connected';
    shown.className = 'good';
  };
  ws.onclose = () => {
    state.connected = false;
    shown.textContent = 'disconnected: retrying';
    shown.className = 'bad';
    setTimeout(connect, 1000);  // the server starts the new connection from scratch
  };
  ws.onmessage = (e) => {
    if (e.data instanceof ArrayBuffer) return onChunk(e.data);
    const m = JSON.parse(e.data);
    if (m.type === 'status') onStatus(m.status);
    else if (m.type === 'pose') onPose(m);
    else if (m.type === 'reset') clearMap();
    else if (m.type === 'correction') onCorrection(m);
    else if (m.type === 'trajectory') {
      // Appended one by one: a whole path (sent again after a correction) holds up to 300000
      // numbers, more than a call's arguments may be.
      trajectory.length = 3 * m.from;
      for (const v of m.xyz) trajectory.push(v);
      updateTrajectory();
    }
  };
}
connect();

// ------------------------------------------------------------------ the rig key
// With a rig key on the monitor (GET /api/auth says so), commands are signed with it
// (command_auth.js). The operator enters it once per tab: it stays in sessionStorage, is never
// sent, and is forgotten when the monitor says it is not the rig's.
const kKeyItem = 'depthfuse.rigKey';
let auth = {commands_need_key: false, channel: '', offset_us: 0};

// The monitor's settings and clock: offset_us turns this computer's time into the monitor's,
// to within half the request's round trip.
async function loadAuth() {
  const sent = Date.now();
  const a = await (await fetch('/api/auth', {cache: 'no-store'})).json();
  a.offset_us = a.utime - 1000 * (sent + Date.now()) / 2;
  auth = a;
  state.needKey = a.commands_need_key;
  // A rig without a key takes the page's commands from anyone who reaches the page: say so.
  document.getElementById('no-key').hidden = a.commands_need_key;
  showKeyForm();
  return a;
}

function showKeyForm() {
  const have = !!sessionStorage.getItem(kKeyItem);
  document.getElementById('key-form').hidden = !auth.commands_need_key || have;
  document.getElementById('btn-forget-key').hidden = !auth.commands_need_key || !have;
}

document.getElementById('btn-key').addEventListener('click', () => {
  const input = document.getElementById('rig-key');
  const key = dfCommandAuth.parseKey(input.value);
  input.value = '';
  if (!key) {
    document.getElementById('command').textContent =
        'the rig key is 64 hexadecimal digits (the content of /etc/depthfuse/rig.key)';
    return;
  }
  sessionStorage.setItem(kKeyItem, dfCommandAuth.hex(key));
  showKeyForm();
});
document.getElementById('btn-forget-key').addEventListener('click', () => {
  sessionStorage.removeItem(kKeyItem);
  showKeyForm();
});
loadAuth().catch((err) => state.errors.push(`GET /api/auth: ${err}`));

// ------------------------------------------------------------------ the buttons
async function command(action) {
  const params = new URLSearchParams({action});
  const name = document.getElementById('scan-name').value.trim();
  if (action === 'start' && name) params.set('argument', name);
  // Sent as this very string, so that the bytes signed are the bytes the monitor receives.
  const body = params.toString();
  const headers = {'X-Depthfuse': '1', 'Content-Type': 'application/x-www-form-urlencoded'};
  const shown = document.getElementById('command');
  try {
    const a = await loadAuth();
    if (a.commands_need_key) {
      const key = sessionStorage.getItem(kKeyItem);
      if (!key) {
        state.commands.push({action, error: 'no key'});
        shown.textContent = `${action}: enter the rig key first`;
        document.getElementById('rig-key').focus();
        return;
      }
      const utime = Math.round(1000 * Date.now() + a.offset_us);
      headers['X-Depthfuse-Signature'] = dfCommandAuth.sign(dfCommandAuth.parseKey(key), a.channel, body, utime);
    }
    const r = await fetch('/api/command', {method: 'POST', body, headers});
    const reply = await r.json();
    state.commands.push({action, status: r.status, reply});
    if (reply.refused === 'bad_signature') {
      sessionStorage.removeItem(kKeyItem);  // not the rig's key: ask again
      showKeyForm();
    }
    shown.textContent = r.ok ? `${action}: sent, waiting for the fusion daemon` : `${action}: ${reply.error}`;
  } catch (err) {
    state.commands.push({action, error: String(err)});
    shown.textContent = `${action}: ${err}`;
  }
}
for (const b of document.querySelectorAll('button[data-action]'))
  b.addEventListener('click', () => command(b.dataset.action));

function frame() {
  requestAnimationFrame(frame);
  if (!coverageShown) showCoverageFigures();
  controls.update();
  renderer.render(scene, camera3d);
}
frame();
