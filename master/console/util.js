// Helpers of the Tessera console: DOM shortcuts, messages, the API's HTTP calls and colour
// conversion, shared by the page's modules.

export const $ = (id) => document.getElementById(id);
export const on = (id, type, fn, opts) => $(id).addEventListener(type, fn, opts);
export const clamp = (v, lo, hi) => Math.min(hi, Math.max(lo, v));
export const isNum = (v) => typeof v === 'number' && Number.isFinite(v);
// Fields the operator is typing in are left alone; the server's value returns once they leave.
export const editing = (e) => document.activeElement === e;
export const AUTH_TEXT = 'Not authorised: open the URL with the token that tessera-master printed';

export function el(tag, props = {}, ...children) {
  const e = Object.assign(document.createElement(tag), props);
  e.append(...children);
  return e;
}

// ---- messages ------------------------------------------------------------------------------
const msgTimers = new Map();

export function say(box, text, kind = 'ok') {
  if (!box) return;
  clearTimeout(msgTimers.get(box));
  box.textContent = text;
  box.className = `msg ${kind}`;
  // Successes fade, so that a stale "applied" never reads as the answer to a later action.
  if (kind !== 'err' && text) msgTimers.set(box, setTimeout(() => { box.textContent = ''; }, 5000));
}

// Errors show next to the control that caused them, and in the one bar a test can look for.
export function showError(box, text, context = '') {
  say(box, text, 'err');
  $('error-text').textContent = context ? `${context}: ${text}` : text;
  $('error-bar').hidden = false;
}

// Validation failures read like the server's errors; null stops the action.
export const reject = (box, context, text) => { showError(box, text, context); return null; };

export function setAuthorised(ok) {
  $('auth-banner').hidden = ok;
  if (!ok) $('auth-banner').textContent = AUTH_TEXT;
}

// A surprise must not kill the page silently: it is shown like any other error.
window.addEventListener('error', (e) => showError(null, e.message || String(e), 'script'));
window.addEventListener('unhandledrejection', (e) => showError(null, String(e.reason?.message ?? e.reason), 'script'));

// ---- HTTP ----------------------------------------------------------------------------------
// Never throws; resolves to {ok, data, status}. Errors are shown in `msg` unless `quiet`.
export async function api(path, { method = 'GET', body, msg = null, quiet = false, quiet404 = false } = {}) {
  const fail = (text, status = 0) => {
    if (!quiet) showError(msg, text, `${method} ${path}`);
    return { ok: false, status };
  };
  let res;
  let text;
  try {
    res = await fetch(path, {
      method, credentials: 'same-origin', cache: 'no-store',
      headers: body === undefined ? {} : { 'Content-Type': 'application/json' },
      body: body === undefined ? undefined : JSON.stringify(body),
    });
    text = await res.text();
  } catch (e) {
    return fail(`server unreachable (${e.message})`);
  }
  if (res.status === 401) { setAuthorised(false); return fail(AUTH_TEXT, 401); }
  let data = null;
  let parseError = null;
  if (text.trim()) try { data = JSON.parse(text); } catch (e) { parseError = e; }
  if (!res.ok) {
    if (res.status === 404 && quiet404) return { ok: false, status: 404 };
    const reason = typeof data?.error === 'string' ? data.error : (text.trim().slice(0, 300) || res.statusText);
    return fail(`${reason} (HTTP ${res.status})`, res.status);
  }
  setAuthorised(true);
  if (parseError) return fail(`bad JSON from the server (${parseError.message})`, res.status);
  return { ok: true, data, status: res.status };
}

export const post = (path, body, msg) => api(path, { method: 'POST', body, msg });

// The header follows the answers to actions at once instead of waiting for the next status.
export function noteState(d) {
  if (isNum(d?.state_id)) $('state-id').textContent = d.state_id;
  if (isNum(d?.frame)) $('frame').textContent = d.frame;
}

// An action: its button is disabled while in flight, so a double click does not send twice.
export async function act(btn, path, body, msg, okText) {
  if (btn) btn.disabled = true;
  const r = await post(path, body, msg);
  if (btn) btn.disabled = false;
  if (!r.ok) return r;
  noteState(r.data);
  say(msg, typeof okText === 'function' ? okText(r.data) : (okText ?? `applied (state ${r.data?.state_id ?? '?'})`));
  return r;
}

export const parseNums = (text) => String(text).split(/[\s,;]+/).filter(Boolean).map(Number);
export const fmt = (v, digits = 1) => (isNum(v) ? v.toFixed(digits) : '–');

// Short for display; fields whose values are sent back ask for more digits.
export function fmtNum(v, digits = 4) {
  if (!isNum(v)) return '–';
  const a = Math.abs(v);
  return a !== 0 && (a >= 1e5 || a < 1e-3) ? v.toExponential(digits - 2) : String(Number(v.toPrecision(digits)));
}

export function fmtCount(v) {
  if (!isNum(v)) return '–';
  const [div, unit, digits] = [[1e9, 'G', 2], [1e6, 'M', 2], [1e4, 'k', 1]].find(([d]) => v >= d) ?? [1, '', 0];
  return `${(v / div).toFixed(digits)} ${unit}`.trim();
}

// ---- colour --------------------------------------------------------------------------------
// The renderer's colours are linear RGB; <input type=color> speaks sRGB hex.
export function linToHex(rgb) {
  const enc = (c) => {
    c = clamp(isNum(c) ? c : 0, 0, 1);
    const s = c <= 0.0031308 ? 12.92 * c : 1.055 * c ** (1 / 2.4) - 0.055;
    return Math.round(s * 255).toString(16).padStart(2, '0');
  };
  return `#${enc(rgb?.[0])}${enc(rgb?.[1])}${enc(rgb?.[2])}`;
}

export function hexToLin(hex) {
  const n = parseInt(/^#?([0-9a-f]{6})$/i.exec(hex)?.[1] ?? 'ffffff', 16);
  return [(n >> 16) & 255, (n >> 8) & 255, n & 255].map((b) => {
    const s = b / 255;
    return Math.round((s <= 0.04045 ? s / 12.92 : ((s + 0.055) / 1.055) ** 2.4) * 1e4) / 1e4;
  });
}

