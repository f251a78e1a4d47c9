// Tessera operator console. A plain ES module served by tessera-master: no framework, no build
// step and no external URLs, because display walls often run offline. State arrives through
// the event stream; fetches are only for actions and the first load.

import {
  $, on, clamp, isNum, editing, AUTH_TEXT, el, say, showError, reject, setAuthorised, api, post, noteState, act, parseNums, fmt, fmtNum, fmtCount, linToHex, hexToLin,
} from './util.js';

let lastStatus = null;
let pictureFrame = null;
window.tessera = { status: () => lastStatus, lastPictureFrame: () => pictureFrame };

// ---- event stream --------------------------------------------------------------------------
let stream = null;
let retryMs = 1000;
let retryTimer = null;

function setConnected(up) {
  $('conn').textContent = up ? 'connected' : 'disconnected';
  $('conn').className = `badge ${up ? 'up' : 'down'}`;
}

const onEvent = (handler) => (ev) => {
  let data;
  try { data = JSON.parse(ev.data); } catch (e) {
    return showError(null, `bad JSON in a "${ev.type}" event (${e.message})`, 'event stream');
  }
  try { handler(data); } catch (e) { showError(null, e.message, `"${ev.type}" event`); }
};

async function refreshStatus() {
  const r = await api('/api/status', { quiet: true });
  if (r.ok && r.data) onStatus(r.data);
  return r;
}

function connect() {
  clearTimeout(retryTimer);
  if (typeof EventSource === 'undefined') return showError(null, 'this browser has no EventSource: the page will not update', 'event stream');
  try { stream = new EventSource('/api/events'); } catch { setConnected(false); return retryLater(); }
  stream.onopen = async () => {
    setConnected(true);
    retryMs = 1000;
    // Events sent while we were away are lost: catch up on the state and the picture.
    const r = await refreshStatus();
    if (r.ok) requestPicture(r.data?.frame);
  };
  stream.onerror = () => {
    setConnected(false);
    // The browser retries by itself after a dropped connection, but gives up for good on an
    // HTTP error (a 401, a 502 from a proxy): then we retry, backing off.
    if (stream.readyState === EventSource.CLOSED) { stream.close(); retryLater(); }
  };
  stream.addEventListener('status', onEvent(onStatus));
  stream.addEventListener('figures', onEvent(onFigures));
  stream.addEventListener('picture', onEvent((d) => requestPicture(d?.frame)));
  return null;
}

function retryLater() {
  // The stream cannot say why it failed; a plain fetch turns a 401 into the banner.
  retryTimer = setTimeout(() => refreshStatus().then(connect), retryMs);
  retryMs = Math.min(retryMs * 2, 15000);
}

// ---- wall picture --------------------------------------------------------------------------
// Loads off-screen and swaps the element in, so the old picture stays up until the new one is
// decoded, and each picture is fetched exactly once.
async function swapImage(id, url) {
  const old = $(id);
  const im = new Image();
  im.src = url;
  await im.decode();
  Object.assign(im, { id, alt: old.alt, draggable: false, className: old.className, hidden: old.hidden });
  if (old.dataset.test) im.dataset.test = old.dataset.test;
  old.replaceWith(im);
  return im;
}

// One load at a time per image; of the frames announced meanwhile only the newest is fetched.
function singleFlight(load) {
  const s = { busy: false, want: null };
  return async (frame) => {
    s.want = frame;
    if (s.busy) return;
    s.busy = true;
    while (s.want !== null) {
      const f = s.want;
      s.want = null;
      await load(f);
    }
    s.busy = false;
  };
}

const loadPicture = singleFlight(async (frame) => {
  try {
    (await swapImage('picture', `/api/wall.png?frame=${frame}`)).classList.add('loaded');
    pictureFrame = frame;
    $('stage-note').hidden = true;
    if ($('heatmap-toggle').checked) requestHeatmap(frame);
  } catch {
    if (pictureFrame === null) $('stage-note').textContent = `no picture yet (frame ${frame})`;
  }
});
const requestPicture = (frame) => { if (isNum(frame)) loadPicture(frame); };

const requestHeatmap = singleFlight(async (frame) => {
  try { await swapImage('heatmap', `/api/heatmap.png?frame=${frame}`); } catch {
    say($('msg-stage'), 'the heatmap is not available', 'info');
  }
});

on('heatmap-toggle', 'change', (e) => {
  $('heatmap').hidden = !e.target.checked;
  if (e.target.checked) requestHeatmap(pictureFrame ?? 0);
});

let wallKey = '';
function renderWall(s) {
  const w = s.wall;
  if (!(w?.width > 0 && w?.height > 0) || JSON.stringify(w) === wallKey) return;
  wallKey = JSON.stringify(w);
  $('stage').style.setProperty('--aspect', String(w.width / w.height));
  $('outlines').setAttribute('viewBox', `0 0 ${w.width} ${w.height}`);
  const svg = (tag, attrs, text = '') => {
    const e = document.createElementNS('http://www.w3.org/2000/svg', tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    e.textContent = text;
    return e;
  };
  $('outline-rects').replaceChildren(...(w.displays ?? []).flatMap((d) => [
    svg('rect', { x: d.x, y: d.y, width: d.width, height: d.height, 'vector-effect': 'non-scaling-stroke' }),
    svg('text', { x: d.x + w.height * 0.02, y: d.y + w.height * 0.07, 'font-size': w.height * 0.05 }, `display ${d.id}`),
  ]));
  $('probe-marker').setAttribute('r', Math.max(w.width, w.height) / 120);
}

// ---- steering on the picture ---------------------------------------------------------------
// One input request in flight at a time; moves and wheel turns made meanwhile are summed.
const inputQueue = [];
let inputBusy = false;

function queueInput(ev) {
  const last = inputQueue[inputQueue.length - 1];
  if (last && ev.kind !== 'Key' && last.kind === ev.kind && last.button === ev.button) {
    if (ev.kind === 'Drag') { last.dx += ev.dx; last.dy += ev.dy; } else last.lines += ev.lines;
  } else if (inputQueue.length < 16) {
    inputQueue.push(ev);
  }
  pumpInput();
}

async function pumpInput() {
  if (inputBusy || inputQueue.length === 0) return;
  inputBusy = true;
  const ev = inputQueue.shift();
  const body = ev.kind === 'Drag' ? { Drag: { button: ev.button, dx: clamp(ev.dx, -100, 100), dy: clamp(ev.dy, -100, 100) } }
    : ev.kind === 'Scroll' ? { Scroll: { lines: clamp(ev.lines, -5, 5) } } : { Key: { key: ev.key, pressed: true } };
  const r = await post('/api/input', body, $('msg-stage'));
  if (r.ok) noteState(r.data);
  inputBusy = false;
  pumpInput();
}

const stage = $('stage');
let pointer = null;
stage.addEventListener('contextmenu', (e) => e.preventDefault());

stage.addEventListener('pointerdown', (e) => {
  const button = e.button === 0 ? (e.shiftKey ? 'Right' : 'Left') : ['Left', 'Middle', 'Right'][e.button];
  if (pointer || !button) return;
  e.preventDefault();
  stage.focus();
  pointer = { id: e.pointerId, button, x0: e.clientX, y0: e.clientY, x: e.clientX, y: e.clientY, moved: false };
  try { stage.setPointerCapture(e.pointerId); } catch { /* capture is only a nicety */ }
});

stage.addEventListener('pointermove', (e) => {
  if (!pointer || e.pointerId !== pointer.id) return;
  // Within 4 px of the press it may still be a click; past that, the whole move counts.
  if (!pointer.moved && Math.hypot(e.clientX - pointer.x0, e.clientY - pointer.y0) < 4) return;
  pointer.moved = true;
  stage.classList.add('dragging');
  const h = stage.getBoundingClientRect().height || 1;
  const [dx, dy] = [(e.clientX - pointer.x) / h, (e.clientY - pointer.y) / h];
  [pointer.x, pointer.y] = [e.clientX, e.clientY];
  if (dx || dy) queueInput({ kind: 'Drag', button: pointer.button, dx, dy });
});

function endPointer(e, cancelled) {
  if (!pointer || e.pointerId !== pointer.id) return;
  const { moved } = pointer;
  pointer = null;
  stage.classList.remove('dragging');
  if (!cancelled && !moved) probe(e.clientX, e.clientY);
}
stage.addEventListener('pointerup', (e) => endPointer(e, false));
stage.addEventListener('pointercancel', (e) => endPointer(e, true));

stage.addEventListener('wheel', (e) => {
  e.preventDefault();
  const lines = e.deltaMode === 1 ? -e.deltaY : e.deltaMode === 2 ? -e.deltaY * 3 : -e.deltaY / 100;
  if (lines) queueInput({ kind: 'Scroll', lines: clamp(lines, -5, 5) });
}, { passive: false });

const WALL_KEYS = new Set(['H', 'F', 'O', 'W', 'A', 'S', 'D', 'Q', 'E']);
stage.addEventListener('keydown', (e) => {
  // By physical position, as the display nodes send them.
  const key = /^Key([A-Z])$/.exec(e.code)?.[1];
  if (e.ctrlKey || e.metaKey || e.altKey || !WALL_KEYS.has(key)) return;
  e.preventDefault();
  queueInput({ kind: 'Key', key });
});

// ---- probe ---------------------------------------------------------------------------------
async function probe(clientX, clientY) {
  const out = $('probe-result');
  clearTimeout(msgTimers.get(out));
  const w = lastStatus?.wall;
  const rect = stage.getBoundingClientRect();
  if (!(w?.width > 0) || rect.width <= 0 || rect.height <= 0) return say(out, 'no wall geometry yet', 'info');
  const px = clamp((clientX - rect.left) / rect.width, 0, 1) * w.width;
  const py = clamp((clientY - rect.top) / rect.height, 0, 1) * w.height;
  const [x, y] = [Math.min(Math.floor(px), w.width - 1), Math.min(Math.floor(py), w.height - 1)];
  for (const [k, v] of [['cx', px], ['cy', py], ['visibility', 'visible']]) $('probe-marker').setAttribute(k, v);
  $('p-probe').open = true;
  out.className = 'kv';
  out.textContent = `probing wall pixel (${x}, ${y})…`;
  const r = await api(`/api/probe?x=${x}&y=${y}`, { msg: out });
  const d = r.data;
  if (!r.ok) return null;
  if (d === null || typeof d !== 'object') return (out.textContent = `wall pixel (${x}, ${y}): nothing there`);
  const world = Array.isArray(d.world) ? d.world.map((c) => fmtNum(c)).join(', ') : '–';
  const rows = [['value', fmtNum(d.value)], ['position', `(${world})`], ['distance', fmtNum(d.distance)], ['wall pixel', `(${x}, ${y})`]];
  return out.replaceChildren(...rows.map(([k, v]) => el('div', {}, `${k} `, el('b', { textContent: v }))));
}

// ---- status and figures --------------------------------------------------------------------
function onStatus(s) {
  if (!s || typeof s !== 'object') return;
  lastStatus = s;
  // One broken part of a status must not stop the others from updating.
  for (const render of [renderHeader, renderWall, renderQuality, renderViews, renderCuts, renderVolume, renderPlayback, renderParticles]) {
    try { render(s); } catch (e) { showError(null, e.message, `status (${render.name})`); }
  }
  if (pictureFrame === null) requestPicture(s.frame);
}

function renderHeader(s) {
  noteState(s);
  $('converged').textContent = s.converged ? 'converged' : 'rendering';
  $('converged').className = `pill ${s.converged ? 'converged' : 'rendering'}`;
  $('btn-overlay').textContent = s.overlay ? 'Overlay on' : 'Overlay off';
  $('btn-overlay').classList.toggle('active', !!s.overlay);
  $('btn-orbit').classList.toggle('active', !!s.camera?.orbit);
  $('btn-orbit').title = s.camera?.orbit ? 'orbiting the pivot (key F flies)' : 'flying: click to orbit the pivot again';
}

function renderQuality(s) {
  const q = s.quality ?? {};
  $('q-shadows').checked = !!q.shadows;
  if (!editing($('q-ao')) && isNum(q.ao)) $('q-ao').value = q.ao;
  if (!editing($('q-spp')) && isNum(q.spp)) $('q-spp').value = q.spp;
}

const fillTable = (tbody, rows) => tbody.replaceChildren(...rows.map((cells) =>
  el('tr', {}, ...cells.map((c) => el('td', { textContent: c, title: c })))));

function onFigures(f) {
  if (!f || typeof f !== 'object') return;
  $('fig-fps').textContent = f.idle ? 'idle (converged)' : `${fmt(f.fps)} fps`;
  $('fig-ms').textContent = f.idle ? 'nothing to render' : `frame ${fmt(f.frame_ms_last)} ms · mean ${fmt(f.frame_ms_mean)} ms`;
  $('fig-counts').textContent = `${f.frames_presented ?? '–'} frames presented · ${f.changes_applied ?? '–'} changes applied`;
  fillTable($('fig-nodes'), (f.render_nodes ?? []).map((n) => [String(n.id), String(n.host ?? ''), String(n.cores ?? '–'),
    fmtCount(n.tiles), fmtCount(n.rays), fmt(n.peak_mib, 0), fmtCount(n.dsm_misses)]));
  fillTable($('fig-displays'), (f.displays ?? []).map((d) => [String(d.id), String(d.host ?? ''), fmtCount(d.frames_presented)]));
}

// ---- action buttons ------------------------------------------------------------------------
const actionsMsg = $('msg-actions');
on('btn-fit', 'click', (e) => act(e.currentTarget, '/api/camera', { fit: true }, actionsMsg, 'fitted'));
on('btn-home', 'click', (e) => act(e.currentTarget, '/api/camera', { home: true }, actionsMsg, 'home view'));
on('btn-orbit', 'click', (e) => act(e.currentTarget, '/api/camera', { orbit: true }, actionsMsg, 'orbiting'));
on('btn-overlay', 'click', (e) => act(e.currentTarget, '/api/overlay', { on: !lastStatus?.overlay }, actionsMsg));
on('error-close', 'click', () => { $('error-bar').hidden = true; });

async function snapshot(final) {
  const buttons = [$('btn-snapshot'), $('btn-snapshot-final')];
  buttons.forEach((b) => { b.disabled = true; });
  // A final snapshot waits for the wall to converge at full quality, which can take a while.
  say(actionsMsg, final ? 'rendering the final snapshot…' : 'taking a snapshot…', 'info');
  const r = await post('/api/snapshot', { final }, actionsMsg);
  buttons.forEach((b) => { b.disabled = false; });
  if (!r.ok) return;
  const files = Array.isArray(r.data?.files) ? r.data.files : [];
  say(actionsMsg, `snapshot of frame ${r.data?.frame ?? '?'}: ${files.length} file(s)`);
  $('snapshot-files').replaceChildren(...files.map((f) => el('li', { textContent: String(f) })));
}
on('btn-snapshot', 'click', () => snapshot(false));
on('btn-snapshot-final', 'click', () => snapshot(true));

// The status does not say whether a recording runs, so the page keeps what the server answered.
let recording = false;
on('btn-record', 'click', async (e) => {
  const btn = e.currentTarget;
  const path = $('record-path').value.trim();
  const r = await act(btn, '/api/record', !recording && path ? { on: true, path } : { on: !recording }, actionsMsg,
    (d) => (d?.recording ? `recording to ${d.path ?? '?'}` : `recording stopped${d?.path ? ` (${d.path})` : ''}`));
  if (!r.ok) return;
  recording = !!r.data?.recording;
  btn.textContent = recording ? 'Stop recording' : 'Record';
  btn.classList.toggle('active', recording);
});

// A session recorded before (a file name in the wall's --out folder) plays from the next frame.
on('btn-replay', 'click', (e) => {
  const path = $('record-path').value.trim();
  if (!path) return say(actionsMsg, 'name a recorded session file to replay', 'err');
  return act(e.currentTarget, '/api/replay', { path }, actionsMsg, `replaying ${path}`);
});

// ---- quality, views, cut planes, lights ----------------------------------------------------
const qualityMsg = $('msg-quality');
on('q-shadows', 'change', (e) => act(null, '/api/quality', { shadows: e.target.checked }, qualityMsg));
for (const [id, field, min] of [['q-ao', 'ao', 0], ['q-spp', 'spp', 1]]) {
  on(id, 'change', (e) => {
    const v = Number(e.target.value);
    if (!Number.isInteger(v) || v < min) return reject(qualityMsg, 'quality', `${field} must be a whole number ≥ ${min}`);
    return act(null, '/api/quality', { [field]: v }, qualityMsg);
  });
}

const viewsMsg = $('msg-views');
let viewsKey = null;
function renderViewList(views) {
  if (JSON.stringify(views) === viewsKey) return;
  viewsKey = JSON.stringify(views);
  $('views-list').replaceChildren(...views.map((name) => {
    const go = el('button', { type: 'button', textContent: 'Go' });
    go.dataset.test = 'view-go';
    go.addEventListener('click', () => act(go, `/api/views/${encodeURIComponent(name)}/go`, undefined, viewsMsg, `view "${name}"`));
    return el('li', {}, el('span', { textContent: name }), go);
  }));
  if (!views.length) $('views-list').append(el('li', { className: 'empty', textContent: 'no saved views' }));
}
const renderViews = (s) => { if (Array.isArray(s.views)) renderViewList(s.views.map(String)); };

on('view-save', 'click', async (e) => {
  const name = $('view-name').value.trim();
  if (!name) return reject(viewsMsg, 'views', 'give the view a name');
  const r = await act(e.currentTarget, `/api/views/${encodeURIComponent(name)}`, undefined, viewsMsg, `saved "${name}"`);
  const v = r.ok ? await api('/api/views', { msg: viewsMsg }) : r;
  if (v.ok && Array.isArray(v.data)) renderViewList(v.data.map(String));
  return null;
});

const cutsMsg = $('msg-cuts');
const cutInputs = [...document.querySelectorAll('#cut-rows .cut-row')].map((row) => [...row.querySelectorAll('input')]);
let cutsDirty = false;
cutInputs.flat().forEach((inp) => inp.addEventListener('input', () => { cutsDirty = true; }));

function renderCuts(s) {
  if (cutsDirty || !Array.isArray(s.cuts) || cutInputs.flat().some((inp) => editing(inp))) return;
  cutInputs.forEach((inputs, i) => inputs.forEach((inp, j) => { inp.value = isNum(s.cuts[i]?.[j]) ? fmtNum(s.cuts[i][j], 7) : ''; }));
}

on('cuts-apply', 'click', async (e) => {
  const planes = [];
  for (const [i, inputs] of cutInputs.entries()) {
    const raw = inputs.map((inp) => inp.value.trim());
    if (raw.every((t) => t === '')) continue;
    const v = raw.map((t) => (t === '' ? NaN : Number(t)));
    if (!v.every(Number.isFinite)) return reject(cutsMsg, 'cut planes', `plane ${i + 1}: fill in all four numbers`);
    if (v[0] === 0 && v[1] === 0 && v[2] === 0) return reject(cutsMsg, 'cut planes', `plane ${i + 1}: the normal must not be zero`);
    planes.push(v);
  }
  const r = await act(e.currentTarget, '/api/cuts', { planes }, cutsMsg, `${planes.length} plane(s) applied`);
  if (r.ok) cutsDirty = false;
  return r;
});

on('cuts-clear', 'click', async (e) => {
  const r = await act(e.currentTarget, '/api/cuts', { planes: [] }, cutsMsg, 'cut planes cleared');
  if (!r.ok) return;
  cutInputs.flat().forEach((inp) => { inp.value = ''; });
  cutsDirty = false;
});

const lightsMsg = $('msg-lights');
on('lights-scene', 'click', (e) => act(e.currentTarget, '/api/lights', { scene: true }, lightsMsg, "using the scene's lights"));
on('light-apply', 'click', (e) => {
  const towards = parseNums($('light-towards').value);
  const intensity = Number($('light-intensity').value);
  if (towards.length !== 3 || !towards.every(Number.isFinite) || towards.every((c) => c === 0)) {
    return reject(lightsMsg, 'lights', 'the direction needs three numbers, not all zero');
  }
  if (!(intensity >= 0)) return reject(lightsMsg, 'lights', 'the intensity must be a number ≥ 0');
  return act(e.currentTarget, '/api/lights', { lights: [{ directional: { towards, intensity } }] }, lightsMsg, 'directional light set');
});

// ---- volume: transfer-function editor ------------------------------------------------------
const volumeMsg = $('msg-volume');
const canvas = $('tf-canvas');
const MAX_POINTS = 16;
const tf = {
  domain: 'Normalized', points: [], sel: 0, dirty: false, drag: null, range: [0, 1],
  hist: null, histKey: null, histBusy: false, appliedState: -1,
};

function tfRange() {
  const [lo, hi] = Array.isArray(tf.range) && tf.range.every(isNum) ? tf.range : [0, 1];
  return [lo, hi > lo ? hi : lo + 1];
}
// Points hold values in their own domain; the axis is always in data units.
const toData = (v) => { const [lo, hi] = tfRange(); return tf.domain === 'Normalized' ? lo + v * (hi - lo) : v; };
const fromData = (d) => { const [lo, hi] = tfRange(); return tf.domain === 'Normalized' ? (d - lo) / (hi - lo) : d; };
const plotBox = () => ({ w: canvas.clientWidth, h: canvas.clientHeight, L: 12, R: canvas.clientWidth - 12, T: 10, B: canvas.clientHeight - 22 });
const xOfData = (d, b) => { const [lo, hi] = tfRange(); return b.L + ((d - lo) / (hi - lo)) * (b.R - b.L); };
const xOf = (v, b) => xOfData(toData(v), b);
const yOf = (op, b) => b.B - clamp(op, 0, 1) * (b.B - b.T);
const valueAt = (x, b) => { const [lo, hi] = tfRange(); return fromData(lo + clamp((x - b.L) / (b.R - b.L), 0, 1) * (hi - lo)); };
const opacityAt = (y, b) => Math.round(clamp((b.B - y) / (b.B - b.T), 0, 1) * 1000) / 1000;

function colourAt(v) {
  const p = tf.points;
  const i = p.findIndex((q) => v <= q.value);
  if (i <= 0) return [...(p[i === 0 ? 0 : p.length - 1]?.color ?? [1, 1, 1])];
  const t = (v - p[i - 1].value) / (p[i].value - p[i - 1].value || 1);
  return p[i].color.map((c, k) => p[i - 1].color[k] + t * (c - p[i - 1].color[k]));
}

function drawTf() {
  const dpr = window.devicePixelRatio || 1;
  const b = plotBox();
  if (b.w <= 0 || b.h <= 0) return;
  if (canvas.width !== Math.round(b.w * dpr)) canvas.width = Math.round(b.w * dpr);
  if (canvas.height !== Math.round(b.h * dpr)) canvas.height = Math.round(b.h * dpr);
  const ctx = canvas.getContext('2d');
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, b.w, b.h);

  // Histogram on a log scale, so the few voxels of interest are not flattened by the background.
  const { counts, range: hr } = tf.hist ?? {};
  if (Array.isArray(counts) && counts.length && Array.isArray(hr) && hr[1] > hr[0]) {
    const top = Math.log1p(Math.max(1, ...counts.filter(isNum)));
    const bin = (hr[1] - hr[0]) / counts.length;
    ctx.fillStyle = '#4a4f56';
    counts.forEach((c, i) => {
      const x0 = Math.max(b.L, xOfData(hr[0] + i * bin, b));
      const x1 = Math.min(b.R, xOfData(hr[0] + (i + 1) * bin, b));
      const h = (Math.log1p(c) / top) * (b.B - b.T);
      if (c > 0 && x1 > x0) ctx.fillRect(x0, b.B - h, Math.max(1, x1 - x0 - 0.3), h);
    });
  }

  const [lo, hi] = tfRange();
  Object.assign(ctx, { fillStyle: '#9aa1aa', font: '11px system-ui, sans-serif', textBaseline: 'top' });
  ctx.fillRect(b.L, b.B, b.R - b.L, 1);
  for (let k = 0; k <= 4; k++) {
    const x = xOfData(lo + (k / 4) * (hi - lo), b);
    ctx.textAlign = ['left', 'center', 'center', 'center', 'right'][k];
    ctx.fillText(fmtNum(lo + (k / 4) * (hi - lo)), x, b.B + 5);
    ctx.fillRect(x - 0.5, b.B, 1, 3);
  }

  const pts = tf.points;
  if (!pts.length) return;
  const xs = pts.map((p) => xOf(p.value, b));
  const ys = pts.map((p) => yOf(p.opacity, b));
  // The area under the opacity curve in the points' colours, flat beyond the end points
  // because the renderer holds the end values there.
  const grad = ctx.createLinearGradient(b.L, 0, b.R, 0);
  pts.forEach((p, i) => {
    const [r, g, bl] = [1, 3, 5].map((o) => parseInt(linToHex(p.color).slice(o, o + 2), 16));
    grad.addColorStop(clamp((xs[i] - b.L) / (b.R - b.L || 1), 0, 1), `rgba(${r},${g},${bl},0.35)`);
  });
  ctx.beginPath();
  for (const [x, y] of [[b.L, b.B], [b.L, ys[0]], ...xs.map((x, i) => [clamp(x, b.L, b.R), ys[i]]), [b.R, ys[ys.length - 1]], [b.R, b.B]]) ctx.lineTo(x, y);
  ctx.fillStyle = grad;
  ctx.fill();

  ctx.beginPath();
  xs.forEach((x, i) => ctx.lineTo(x, ys[i]));
  Object.assign(ctx, { strokeStyle: '#e2e4e7', lineWidth: 1.5 });
  ctx.stroke();
  pts.forEach((p, i) => {
    const sel = i === tf.sel;
    ctx.beginPath();
    ctx.arc(xs[i], ys[i], sel ? 7 : 6, 0, Math.PI * 2);
    Object.assign(ctx, { fillStyle: linToHex(p.color), lineWidth: sel ? 2.5 : 1.5, strokeStyle: sel ? '#ffcc33' : '#ffffff' });
    ctx.fill();
    ctx.stroke();
  });
}

function syncTfInputs() {
  const p = tf.points[tf.sel];
  $('tf-domain').value = tf.domain;
  $('tf-dirty').hidden = !tf.dirty;
  $('tf-selected').textContent = p ? `point ${tf.sel + 1} of ${tf.points.length} at ${fmtNum(toData(p.value))}` : 'no point';
  for (const id of ['tf-color', 'tf-opacity']) $(id).disabled = !p;
  if (p && !editing($('tf-color'))) $('tf-color').value = linToHex(p.color);
  if (p && !editing($('tf-opacity'))) $('tf-opacity').value = fmtNum(p.opacity);
}

function tfChanged() {
  tf.dirty = true;
  syncTfInputs();
  drawTf();
}

function hitPoint(x, y, b) {
  let [best, bestD] = [-1, 9];
  tf.points.forEach((p, i) => {
    const d = Math.hypot(xOf(p.value, b) - x, yOf(p.opacity, b) - y);
    if (d < bestD) [best, bestD] = [i, d];
  });
  return best;
}

function canvasXY(e) {
  const r = canvas.getBoundingClientRect();
  return [e.clientX - r.left, e.clientY - r.top];
}

canvas.addEventListener('pointerdown', (e) => {
  const [x, y] = canvasXY(e);
  const i = e.button === 0 ? hitPoint(x, y, plotBox()) : -1;
  if (i < 0) return;
  tf.sel = i;
  tf.drag = { id: e.pointerId, x0: x, y0: y, moved: false };
  try { canvas.setPointerCapture(e.pointerId); } catch { /* capture is only a nicety */ }
  syncTfInputs();
  drawTf();
});

canvas.addEventListener('pointermove', (e) => {
  if (!tf.drag || tf.drag.id !== e.pointerId) return;
  const b = plotBox();
  const [x, y] = canvasXY(e);
  // A jitter while clicking to select must not move the point (and apply it).
  if (!tf.drag.moved && Math.hypot(x - tf.drag.x0, y - tf.drag.y0) < 3) return;
  tf.drag.moved = true;
  // Values must stay strictly increasing: a point cannot pass its neighbours.
  const [pts, i] = [tf.points, tf.sel];
  const [lo, hi] = tfRange().map((d) => fromData(d));
  const eps = (hi - lo) * 1e-4;
  const min = i > 0 ? pts[i - 1].value + eps : lo;
  const max = i < pts.length - 1 ? pts[i + 1].value - eps : hi;
  if (min <= max) pts[i].value = clamp(valueAt(x, b), min, max);
  pts[i].opacity = opacityAt(y, b);
  tfChanged();
});

function endTfDrag(e) {
  if (!tf.drag || tf.drag.id !== e.pointerId) return;
  const { moved } = tf.drag;
  tf.drag = null;
  if (moved) applyTf();
}
canvas.addEventListener('pointerup', endTfDrag);
canvas.addEventListener('pointercancel', endTfDrag);

canvas.addEventListener('dblclick', (e) => {
  const b = plotBox();
  const [x, y] = canvasXY(e);
  const i = hitPoint(x, y, b);
  if (i >= 0) {
    if (tf.points.length <= 1) return reject(volumeMsg, 'transfer function', 'the transfer function needs at least one point');
    tf.points.splice(i, 1);
    tf.sel = Math.min(tf.sel, tf.points.length - 1);
  } else {
    if (tf.points.length >= MAX_POINTS) return reject(volumeMsg, 'transfer function', `at most ${MAX_POINTS} points`);
    const value = valueAt(x, b);
    if (tf.points.some((p) => p.value === value)) return null;
    const point = { value, color: colourAt(value), opacity: opacityAt(y, b) };
    tf.points = [...tf.points, point].sort((p, q) => p.value - q.value);
    tf.sel = tf.points.indexOf(point);
  }
  return tfChanged();
});

on('tf-color', 'input', (e) => {
  const p = tf.points[tf.sel];
  if (p) { p.color = hexToLin(e.target.value); tfChanged(); }
});

on('tf-opacity', 'change', (e) => {
  const p = tf.points[tf.sel];
  const v = Number(e.target.value);
  if (!p) return null;
  if (!(v >= 0 && v <= 1)) return reject(volumeMsg, 'transfer function', 'opacity must be between 0 and 1');
  p.opacity = v;
  return tfChanged();
});

// Switching the domain converts the points' values, so the function itself stays the same.
on('tf-domain', 'change', (e) => {
  const data = tf.points.map((p) => toData(p.value));
  tf.domain = e.target.value;
  tf.points.forEach((p, i) => { p.value = fromData(data[i]); });
  tfChanged();
});

async function applyTf() {
  const round = (v) => Number(v.toPrecision(7));
  const points = tf.points.map((p) => ({ value: round(p.value), color: p.color.map(round), opacity: round(p.opacity) }));
  const r = await act($('tf-apply'), '/api/volume', { transfer: { domain: tf.domain, points } }, volumeMsg, 'transfer function applied');
  if (!r.ok) return;
  tf.dirty = false;
  if (isNum(r.data?.state_id)) tf.appliedState = r.data.state_id;
  syncTfInputs();
}
on('tf-apply', 'click', applyTf);

on('tf-preset', 'change', async (e) => {
  const preset = e.target.value;
  if (!preset) return;
  const r = await act(null, '/api/volume', { preset }, volumeMsg, `preset ${preset}`);
  e.target.value = '';
  // The next status carries the preset's points, which local edits would otherwise hide.
  if (r.ok) tf.dirty = false;
});

let isoDirty = false;
on('iso-input', 'input', () => { isoDirty = true; });
on('iso-apply', 'click', async (e) => {
  const iso = parseNums($('iso-input').value);
  if (!iso.every(Number.isFinite)) return reject(volumeMsg, 'iso', 'iso values must be numbers, separated by commas');
  if (iso.length > 4) return reject(volumeMsg, 'iso', 'at most 4 iso values');
  const r = await act(e.currentTarget, '/api/volume', { iso }, volumeMsg, iso.length ? `iso ${iso.join(', ')}` : 'back to the transfer function');
  if (r.ok) isoDirty = false;
  return r;
});

on('vol-step-apply', 'click', (e) => {
  const step = Number($('vol-step').value);
  if (!(step >= 0)) return reject(volumeMsg, 'volume', 'the sample step must be a number ≥ 0');
  return act(e.currentTarget, '/api/volume', { step }, volumeMsg);
});

// The histogram depends on the data's range and time step, not on the transfer function.
async function loadHistogram(key) {
  tf.histBusy = true;
  const r = await api('/api/histogram', { msg: volumeMsg, quiet404: true });
  tf.histBusy = false;
  if (!(r.ok && Array.isArray(r.data?.counts)) && r.status !== 404) return;
  tf.hist = r.ok ? r.data : null;
  tf.histKey = key;
  drawTf();
}

function renderVolume(s) {
  const v = s.volume;
  $('p-volume').hidden = !v;
  if (!v) return;
  if (Array.isArray(v.range)) tf.range = v.range;
  const t = v.transfer;
  // A status from before our last Apply would briefly bring the old points back.
  const stale = isNum(s.state_id) && s.state_id < tf.appliedState;
  if (Array.isArray(t?.points) && !tf.dirty && !tf.drag && !stale) {
    tf.domain = t.domain === 'Data' ? 'Data' : 'Normalized';
    tf.points = t.points.filter((p) => isNum(p?.value)).map((p) => ({
      value: p.value,
      color: Array.isArray(p.color) ? p.color.slice(0, 3).map(Number) : [1, 1, 1],
      opacity: isNum(p.opacity) ? p.opacity : 0,
    }));
    tf.sel = clamp(tf.sel, 0, Math.max(0, tf.points.length - 1));
  }
  if (!isoDirty && !editing($('iso-input')) && Array.isArray(v.iso)) $('iso-input').value = v.iso.map((x) => fmtNum(x, 7)).join(', ');
  if (!editing($('vol-step')) && isNum(v.step)) $('vol-step').value = v.step;
  const key = `${JSON.stringify(v.range)}|${v.time_step}`;
  if (key !== tf.histKey && !tf.histBusy) loadHistogram(key);
  syncTfInputs();
  drawTf();
}

if (typeof ResizeObserver !== 'undefined') new ResizeObserver(() => drawTf()).observe(canvas);

// ---- playback and particles ----------------------------------------------------------------
const playbackMsg = $('msg-playback');
// Focus outlives the drag on a range input, so updates wait only while it is held.
let sliderHeld = false;
on('pb-slider', 'pointerdown', () => { sliderHeld = true; });
window.addEventListener('pointerup', () => { sliderHeld = false; });

function renderPlayback(s) {
  const v = s.volume;
  $('p-playback').hidden = !(isNum(v?.steps) && v.steps > 1);
  if ($('p-playback').hidden) return;
  const k = isNum(v.time_step) ? v.time_step : 0;
  $('pb-current').textContent = `step ${k + 1} of ${v.steps}`;
  $('pb-play').classList.toggle('active', !!v.playing);
  $('pb-pause').classList.toggle('active', !v.playing);
  $('pb-slider').max = String(v.steps - 1);
  if (!sliderHeld) $('pb-slider').value = String(k);
  if (!editing($('pb-speed')) && isNum(v.speed)) $('pb-speed').value = v.speed;
}

on('pb-play', 'click', (e) => act(e.currentTarget, '/api/playback', { playing: true }, playbackMsg, 'playing'));
on('pb-pause', 'click', (e) => act(e.currentTarget, '/api/playback', { playing: false }, playbackMsg, 'paused'));
on('pb-back', 'click', (e) => act(e.currentTarget, '/api/playback', { step: -1 }, playbackMsg, 'stepped back'));
on('pb-forward', 'click', (e) => act(e.currentTarget, '/api/playback', { step: 1 }, playbackMsg, 'stepped forward'));
on('pb-speed', 'change', (e) => {
  const speed = Number(e.target.value);
  if (!(speed >= 0.1 && speed <= 60)) return reject(playbackMsg, 'playback', 'speed must be between 0.1 and 60 steps per second');
  return act(null, '/api/playback', { speed }, playbackMsg, `${speed} steps/s`);
});
on('pb-slider', 'change', (e) => {
  const step = Number(e.target.value);
  act(null, '/api/volume', { time_step: step }, playbackMsg, `step ${step + 1}`);
});

const COLORMAPS = ['viridis', 'magma', 'coolwarm', 'greys'];
function renderParticles(s) {
  const p = s.particles;
  $('p-particles').hidden = !p;
  if (!p) return;
  const map = COLORMAPS.includes(p.colormap) ? p.colormap : 'viridis';
  $('pt-colormap').value = map;
  $('pt-legend').className = `legend ${map}`;
  $('pt-lo').textContent = fmtNum(p.range?.[0]);
  $('pt-hi').textContent = fmtNum(p.range?.[1]);
}

on('pt-colormap', 'change', async (e) => {
  const colormap = e.target.value;
  const r = await act(null, '/api/particles', { colormap }, $('msg-particles'), `colour map ${colormap}`);
  if (r.ok) $('pt-legend').className = `legend ${colormap}`;
});

// ---- start ---------------------------------------------------------------------------------
async function start() {
  setConnected(false);
  const [status, figures] = await Promise.all([api('/api/status'), api('/api/figures', { quiet: true })]);
  if (status.ok && status.data) onStatus(status.data);
  else $('stage-note').textContent = 'the console cannot reach tessera-master';
  if (figures.ok && figures.data) onFigures(figures.data);
  connect();
}

start();
