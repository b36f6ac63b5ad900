// The status page's script (index.html), in a file of its own: the Content-Security-Policy of
// every response (default-src 'self') forbids inline script, inline event handlers, eval and
// style attributes (setAttribute('style', …) too); only element.style.x = … is allowed.
'use strict';
// Relative URLs throughout, so the page also works behind a reverse proxy under a path.
const STATE_URL = 'api/v1/state', TRENDS_URL = 'api/v1/trends', WRITE_URL = 'api/v1/write';
const STATE_MS = 1000, TRENDS_MS = 5000, TIMEOUT_MS = 4000;
// A write is answered once the device confirmed it, retries included (gateway.md §3.2), after
// the writes queued before it: far longer than a read may take.
const WRITE_TIMEOUT_MS = 30000;

const DIGITAL = {dim16: 'input', lim16: 'input', dom16: 'output'};
const ANALOG = {acm3p: [3, '%'], acm3c: [3, '%'], dccim: [1, 'A'], dcvim: [1, 'V']};
// Decimals shown: a steady reading, not every raw step. From the channel's range (gateway.md
// §6.1): 1 for 0–100 %, 3 for 0–6 A, 2 for 0–32 V, 1 for -20–150 °C.
const digits = range => {
  const span = range ? range[1] - range[0] : 100;
  return Math.max(0, Math.min(3, 3 - Math.floor(Math.log10(span > 0 ? span : 1))));
};
const SWATCH = {red: '#e5383b', green: '#2fb344', blue: '#2f6fed', cyan: '#19c3d1',
                magenta: '#d33ad3', yellow: '#f2c418', white: '#ffffff'};
const COLOURS = ['off', 'red', 'green', 'blue', 'cyan', 'magenta', 'yellow', 'white'];
const STATUS_CLASS = {1: 's-ok', 2: 's-bad', 3: 's-warn', 4: 's-idle'};
const EVENT_CLASS = {module_online: 's-ok', port_up: 's-ok', module_offline: 's-bad',
                     port_down: 's-bad', comm_loss: 's-bad', client_refused: 's-warn'};

const $ = id => document.getElementById(id);
const SVG = 'http://www.w3.org/2000/svg';
function h(tag, attrs, ...kids) {
  const e = tag.startsWith('svg:') ? document.createElementNS(SVG, tag.slice(4))
                                   : document.createElement(tag);
  for (const k in attrs || {}) e.setAttribute(k, attrs[k]);
  e.append(...kids);
  return e;
}
// Writes only what changed: a poll a second must not churn the DOM (or a reader's selection).
function txt(e, s) { s = String(s); if (e.textContent !== s) e.textContent = s; }
function attr(e, k, v) { if (e.getAttribute(k) !== v) e.setAttribute(k, v); }
function setStatus(e, c) { for (const k of ['s-ok', 's-bad', 's-warn', 's-idle']) e.classList.toggle(k, k === c); }
const pill = (c, text) => h('span', {class: 'pill ' + c}, h('i', {class: 'icon'}), h('span', {}, text));

const num = n => n == null ? '—' : Number(n).toLocaleString('en-US');
const hex = w => '0x' + w.toString(16).toUpperCase().padStart(4, '0');
function dur(s) {  // 0.012 → "12 ms", 75 → "1 min 15 s", 90000 → "1 d 1 h"
  if (s == null) return 'never';
  if (s < 1) return Math.round(s * 1000) + ' ms';
  if (s < 60) return s.toFixed(1) + ' s';
  const d = Math.floor(s / 86400), hr = Math.floor(s / 3600) % 24, m = Math.floor(s / 60) % 60;
  return d ? `${d} d ${hr} h` : hr ? `${hr} h ${m} min` : `${m} min ${Math.floor(s % 60)} s`;
}
const clock = t => t ? t.slice(11, 19) : '';  // RFC 3339 UTC → "03:50:00"
// A module as a write names it, by the ids of gateway.md §6.3: dom16_0, the ID-2's id2.
const moduleId = m => m.type === 'id2' ? 'id2' : `${m.type}_${m.number}`;

// A URL of the daemon's, relative to the page, without the user and password of an address
// typed as http://alice:secret@gateway/: fetch() refuses a URL that carries them, and the
// browser sends the credentials it was given by itself.
function apiUrl(path) {
  const u = new URL(path, document.baseURI);
  u.username = '';
  u.password = '';
  return u;
}

let serverNow = 0;           // the daemon's clock, seconds; trends are drawn against it
let structure = '';          // links and modules the tiles were built for
let tiles = new Map();       // "link|module" → tile view
let series = new Map();      // "link|module|channel" → [[t, v], …]
let span = 600, interval = 5, lastEvent = null, lastOk = 0;
// The user the state names may write (gateway.md §7.1): the tiles are built with the controls
// of the writable points. Everyone else's page has none.
let operator = false;

// ---- Links and module tiles -------------------------------------------------------------
// A titled group of counters: <div><h3/><dl>…</dl></div> (a dl may not hold the heading).
function group(title) {
  const dl = h('dl');
  return {el: h('div', {class: 'stats'}, h('h3', {}, title), dl),
          stat(label) { const dd = h('dd', {}, '—'); dl.append(h('div', {}, h('dt', {}, label), dd)); return dd; }};
}
function buildLink(l) {
  const v = {}, id = 'link-' + l.name.replace(/\W/g, '_');
  v.port = pill('s-idle', '');
  const port = group('Port'), tx = group('Transactions'), wr = group('Writes');
  v.cycle = port.stat('cycle time'); v.reopens = port.stat('reopens');
  for (const k of ['ok', 'no_answer', 'bad_answer', 'error_ack']) v['t_' + k] = tx.stat(k.replace('_', ' '));
  for (const k of ['confirmed', 'error_ack', 'no_answer', 'link_down', 'busy', 'dropped']) v['w_' + k] = wr.stat(k.replace('_', ' '));
  const grid = h('div', {class: 'tiles'});
  v.el = h('section', {class: 'box link', 'data-link': l.name, 'aria-labelledby': id},
    h('h2', {id}, l.name, v.port, h('span', {class: 'meta num'},
      `${l.protocol === 'id2' ? 'ID-2' : 'ioport hub'} · ${l.device} · ${l.baud} baud · unit ${l.unit_id}`)),
    h('div', {class: 'sub'}, port.el, tx.el, wr.el), grid);
  for (const m of l.modules) {
    const t = buildTile(l.name, m);
    tiles.set(l.name + '|' + m.module, t);
    grid.append(t.el);
  }
  return v;
}
function updateLink(v, l) {
  setStatus(v.port, l.port_open ? 's-ok' : 's-bad');
  txt(v.port.lastChild, l.port_open ? 'port open' : 'port not open');
  txt(v.cycle, l.cycle_seconds == null ? '—' : (l.cycle_seconds * 1000).toFixed(1) + ' ms');
  txt(v.reopens, num(l.reopens));
  // Counts of failures stand out once non-zero; the number itself still says it.
  const count = (e, n, bad) => { txt(e, num(n)); e.classList.toggle('warn', !!(bad && n)); };
  for (const k in l.transactions || {}) if (v['t_' + k]) count(v['t_' + k], l.transactions[k], k !== 'ok');
  for (const k in l.writes || {}) if (v['w_' + k]) count(v['w_' + k], l.writes[k], k !== 'confirmed');
  for (const m of l.modules) tiles.get(l.name + '|' + m.module).update(m);
}

function buildTile(link, m) {
  const t = {link, module: m.module};
  t.status = h('span', {class: 'status'});
  t.age = h('span', {class: 'age', title: 'since the last good transaction'});
  t.body = h('div', {class: 'body'});
  t.note = h('p', {class: 'note'});
  if (operator) {
    t.refusal = h('p', {class: 'refusal', role: 'alert', hidden: ''});
    t.write = writer(t, link, moduleId(m));
  }
  // A configured name heads the tile; the module's id stays beside it, as logs and Modbus say it.
  const named = m.name && m.name !== m.module;
  t.el = h('article', {class: 'tile s-idle', 'data-link': link, 'data-module': m.module},
    h('header', {}, h('h3', {}, named ? m.name : m.module),
      h('span', {class: 'muted'}, (named ? m.module + ' · ' : '') +
        (m.type === 'id2' ? 'machine input' : 'slot ' + m.slot))),
    h('p', {class: 'badge'}, h('i', {class: 'icon'}), t.status, t.age), t.body,
    ...(t.refusal ? [t.refusal] : []), t.note);
  const fill = DIGITAL[m.type] ? digital : ANALOG[m.type] ? analog : {rgbdm, mux8m, id2}[m.type];
  const values = fill ? fill(t, m) : () => {};
  t.update = m => {
    setStatus(t.el, STATUS_CLASS[m.status] || 's-idle');
    txt(t.status, m.status_text);
    txt(t.age, m.age_seconds == null ? 'never' : dur(m.age_seconds) + ' ago');
    // Values of a module that stopped answering are its last known ones: say so, and fade them.
    const stale = m.status !== 1 && m.age_seconds != null;
    t.body.classList.toggle('stale', stale);
    txt(t.note, m.age_seconds == null ? 'no value read yet' : stale ? 'last known values' : '');
    values(m);
  };
  return t;
}

function digital(t, m) {
  const kind = DIGITAL[m.type];
  const names = m[kind + 's'] || {};  // named points only: {"5": "pump running"}
  const word = h('code', {class: 'word'}, '—'), lamps = [];
  const ul = h('ul', {class: 'lamps ' + (kind === 'input' ? 'in' : 'out'), 'aria-label': kind + 's 0 to 15'});
  // An operator's outputs are switches: each shows what the device confirmed, as a lamp does,
  // and a press asks for the other state.
  const write = kind === 'output' ? t.write : null;
  for (let i = 0; i < 16; i++) {
    const lamp = write ? h('button', {type: 'button', class: 'lamp', role: 'switch',
                                      'aria-checked': 'false', 'data-point': 'out' + i}, String(i))
                       : h('span', {class: 'lamp', role: 'img'}, String(i));
    if (write)
      lamp.addEventListener('click', () =>
        write(lamp, 'out' + i, lamp.getAttribute('aria-checked') === 'true' ? 'OFF' : 'ON'));
    lamps.push(lamp);
    ul.append(h('li', {}, lamp));
  }
  t.body.append(h('div', {class: 'row'}, h('span', {class: 'k'}, kind + 's'), word), ul);
  if (write) t.body.append(h('p', {class: 'hint'}, 'press an output to switch it'));
  const named = Object.keys(names);
  if (named.length)
    t.body.append(h('ul', {class: 'points muted'},
      ...named.map(k => h('li', {}, h('span', {class: 'num'}, k), ' · ', names[k]))));
  let last;
  return m => {
    const w = m.word;
    txt(word, w == null ? '—' : hex(w));
    if (w === last) return;
    last = w;
    lamps.forEach((e, i) => {
      const on = w != null && (w >> i & 1) === 1;
      e.classList.toggle('on', on);
      const what = names[i] ? `${names[i]} (${kind} ${i})` : `${kind} ${i}`;
      const label = `${what} ${w == null ? 'unknown' : on ? 'on' : 'off'}`;
      if (write) {
        // A switch says its state in aria-checked; one whose state is unknown is not offered.
        e.setAttribute('aria-checked', String(on));
        e.setAttribute('aria-label', what);
        e.disabled = w == null;
        e.title = w == null ? label : `${label}: press to switch ${on ? 'off' : 'on'}`;
      } else {
        e.setAttribute('aria-label', label);
        e.title = label;
      }
    });
  };
}

function analog(t, m) {
  const [count, unit0] = ANALOG[m.type];
  const rows = t.trends = [];  // drawTrends() finds a tile's plots here
  for (let i = 0; i < count; i++) {
    // Names, units and ranges are the configuration's: a reload that changes them rebuilds the tile.
    const c = (m.channels || [])[i] || {};
    const r = {value: h('span', {class: 'value', 'data-channel': String(i)}, '—'),
               unit: h('span', {class: 'unit'}, c.unit ?? unit0), raw: h('div', {class: 'muted num'}),
               line: h('svg:g'), hi: h('span', {class: 'hi'}), lo: h('span', {class: 'lo'}),
               digits: digits(c.range)};
    r.svg = h('svg:svg', {viewBox: '0 0 600 100', preserveAspectRatio: 'none', role: 'img'}, r.line);
    rows.push(r);
    t.body.append(h('div', {class: 'ch'},
      h('div', {}, h('div', {class: 'k'}, c.name || (count > 1 ? 'channel ' + i : 'value')),
        h('div', {}, r.value, r.unit), r.raw),
      h('div', {class: 'trend'}, r.svg, r.hi, r.lo)));
  }
  return m => rows.forEach((r, i) => {
    const c = (m.channels || [])[i] || {};
    txt(r.value, c.value == null ? '—' : c.value.toFixed(r.digits));
    txt(r.raw, c.raw == null ? '' : 'raw ' + c.raw);
  });
}

// The last 10 minutes of a channel as polylines, one per unbroken run of points, so that a
// time the module did not answer shows as a gap rather than as a made-up straight line.
function drawTrends() {
  const now = serverNow || Date.now() / 1000, t0 = now - span;
  for (const t of tiles.values()) (t.trends || []).forEach((r, i) => {
    const pts = (series.get(`${t.link}|${t.module}|${i}`) || []).filter(p => p[0] >= t0 && p[1] != null);
    r.line.replaceChildren();
    const unit = r.unit.textContent;
    if (!pts.length) {
      txt(r.hi, ''); txt(r.lo, '');
      attr(r.svg, 'aria-label', 'no trend data yet');
      return;
    }
    let lo = Math.min(...pts.map(p => p[1])), hi = Math.max(...pts.map(p => p[1]));
    const pad = Math.max((hi - lo) * 0.1, Math.abs(hi) * 0.001, 1e-6);
    const d = r.digits;
    txt(r.hi, hi.toFixed(d)); txt(r.lo, lo.toFixed(d));
    attr(r.svg, 'aria-label', `trend of the last ${span / 60} minutes, ${lo.toFixed(d)} to ${hi.toFixed(d)} ${unit}`);
    lo -= pad; hi += pad;
    let run = [], prev = null;
    const flush = () => { if (run.length) r.line.append(h('svg:polyline', {points: run.join(' ')})); run = []; };
    for (const [ts, v] of pts) {
      if (prev != null && ts - prev > 2.5 * interval) flush();
      run.push(`${((ts - t0) / span * 600).toFixed(1)},${(100 - (v - lo) / (hi - lo) * 100).toFixed(1)}`);
      prev = ts;
    }
    flush();
  });
}

function rgbdm(t) {
  const sw = h('span', {class: 'swatch', role: 'img'}), name = h('span', {class: 'value colour-name'}, '—');
  t.body.append(h('div', {class: 'big'}, sw, name));
  // An operator's: one button a colour, the confirmed one pressed.
  const chips = t.write ? COLOURS.map(c => {
    const b = h('button', {type: 'button', class: 'chip' + (c === 'off' ? ' off' : ''),
                           'aria-pressed': 'false', 'data-point': 'colour', 'data-value': c,
                           'aria-label': c, title: 'set the colour ' + c});
    b.style.background = SWATCH[c] || '';
    b.addEventListener('click', () => t.write(b, 'colour', c));
    return b;
  }) : [];
  if (chips.length)
    t.body.append(h('div', {class: 'chips', role: 'group', 'aria-label': 'colour'}, ...chips));
  return m => {
    const n = m.colour_name;
    txt(name, n == null ? '—' : n);
    sw.classList.toggle('off', n == null || n === 'off');
    sw.style.background = SWATCH[n] || '';
    attr(sw, 'aria-label', 'colour ' + (n == null ? 'unknown' : n));
    for (const b of chips) attr(b, 'aria-pressed', String(b.dataset.value === n));
  };
}

function mux8m(t) {
  const pos = h('span', {class: 'value pos'}, '—'), neg = h('span', {class: 'value neg'}, '—');
  const state = h('span', {class: 'muted'});
  t.body.append(h('div', {class: 'row'}, h('div', {class: 'pair'},
    h('div', {}, h('div', {class: 'k'}, 'pos'), pos), h('div', {}, h('div', {class: 'k'}, 'neg'), neg)), state));
  // An operator's: a row of the eight test points for each side, the confirmed one pressed.
  const picks = {pos: [], neg: []};
  if (t.write)
    for (const side of ['pos', 'neg']) {
      for (let v = 0; v < 8; v++) {
        const b = h('button', {type: 'button', class: 'pick', 'aria-pressed': 'false',
                               'data-point': side, 'data-value': String(v),
                               title: `set ${side} to ${v}`}, String(v));
        b.addEventListener('click', () => t.write(b, side, String(v)));
        picks[side].push(b);
      }
      t.body.append(h('div', {class: 'picks', role: 'group', 'aria-label': side},
        h('span', {class: 'k'}, side), ...picks[side]));
    }
  return m => {
    txt(pos, m.pos == null ? '—' : m.pos);
    txt(neg, m.neg == null ? '—' : m.neg);
    for (const side of ['pos', 'neg'])
      picks[side].forEach((b, v) => attr(b, 'aria-pressed', String(m[side] === v)));
    // Both sides on one test point means the multiplexer connects nothing.
    txt(state, m.pos == null ? '' : m.pos === m.neg ? 'disconnected' : 'connected');
  };
}

function id2(t) {
  const lamp = h('span', {class: 'lamp stop-lamp', role: 'img'});
  const stop = h('span', {class: 'value stop'}, '—'), count = h('span', {class: 'value count'}, '—');
  t.body.append(h('div', {class: 'row'},
    h('div', {}, h('div', {class: 'k'}, 'stop'), h('div', {class: 'big'}, lamp, stop)),
    h('div', {class: 'end'}, h('div', {class: 'k'}, 'count'), count)));
  if (t.write) t.body.append(h('div', {class: 'acts'}, resetButton(t)));
  return m => {
    txt(stop, m.stop == null ? '—' : m.stop ? 'on' : 'off');
    lamp.classList.toggle('on', !!m.stop);
    attr(lamp, 'aria-label', 'stop ' + (m.stop == null ? 'unknown' : m.stop ? 'on' : 'off'));
    txt(count, num(m.count));
  };
}

// The ID-2's counter reset takes two presses within 5 s: the count is the production's tally,
// not to be lost to a stray tap, and a confirm() dialog would stop the page's updates.
function resetButton(t) {
  const idle = 'reset count', asking = 'press again to reset the count';
  const b = h('button', {type: 'button', class: 'act', 'data-point': 'reset'}, idle);
  let armed = 0;
  const disarm = () => {
    clearTimeout(armed);
    armed = 0;
    txt(b, idle);
    b.classList.remove('armed');
  };
  b.addEventListener('click', () => {
    if (!armed) {
      armed = setTimeout(disarm, 5000);
      txt(b, asking);
      b.classList.add('armed');
      return;
    }
    disarm();
    t.write(b, 'reset', 'ON');
  });
  return b;
}

// ---- Writes (gateway.md §7.1) -----------------------------------------------------------
// What went wrong, in words, or null for {"result": "confirmed"} with 200. The daemon says why in
// `error` and `result`; a proxy's answer, or one from an ioportd that takes no writes, may be no
// JSON at all.
async function postWrite(body) {
  const ctl = new AbortController(), timer = setTimeout(() => ctl.abort(), WRITE_TIMEOUT_MS);
  try {
    const r = await fetch(apiUrl(WRITE_URL), {
      method: 'POST', cache: 'no-store', signal: ctl.signal,
      headers: {'Content-Type': 'application/json'}, body: JSON.stringify(body)});
    let a = null;
    try { a = await r.json(); } catch (e) { /* not JSON: said by its status below */ }
    if (r.ok && a && a.result === 'confirmed') return null;
    const why = a && typeof a.error === 'string' && a.error
      ? a.error : `HTTP ${r.status} ${r.statusText}`.trim();
    return a && typeof a.result === 'string' ? `${why} (${a.result})` : why;
  } catch (e) {
    return e.name === 'AbortError' ? `no answer from ioportd within ${WRITE_TIMEOUT_MS / 1000} s`
                                   : 'ioportd cannot be reached';
  } finally {
    clearTimeout(timer);
  }
}

// A tile's writes. A control never shows the value asked for, only what the state says the
// device confirmed: while a write is on its way the control is marked busy, once it is
// confirmed it stays so until a state asked for after that is shown, and a refusal is said in
// words under the tile's values.
function writer(t, link, module) {
  return async (control, point, value) => {
    if (control.getAttribute('aria-busy') === 'true') return;  // one write at a time a control
    control.setAttribute('aria-busy', 'true');
    t.refusal.hidden = true;
    txt(t.refusal, '');
    const refused = await postWrite({link, module, point, value});
    if (refused === null) {
      afterState(() => control.removeAttribute('aria-busy'));
      pollSoon();
      return;
    }
    control.removeAttribute('aria-busy');
    txt(t.refusal, `${point} → ${value} not confirmed: ${refused}`);
    t.refusal.hidden = false;
  };
}

// ---- Modbus server, events, summary -----------------------------------------------------
function renderModbus(mb, now) {
  const listeners = [mb.listen && mb.listen + ' (TCP)', mb.tls_listen && mb.tls_listen + ' (TLS)'];
  txt($('mb-listen'), 'listening on ' + (listeners.filter(Boolean).join(', ') || 'nothing'));
  txt($('mb-conn'), num(mb.connections));
  txt($('mb-max'), num(mb.max_connections));
  txt($('mb-na'), num(mb.refused.not_allowed));
  txt($('mb-tm'), num(mb.refused.too_many));
  txt($('mb-th'), num(mb.refused.tls_handshake));
  txt($('mb-tmh'), num(mb.refused.too_many_handshakes));
  $('mb-cl').hidden = !mb.comm_loss;
  const rows = mb.clients.map(c => h('tr', {},
    h('td', {class: 'num'}, c.address),
    // Modbus/TCP Security (gateway.md §5.6): the role its certificate gave, or none.
    h('td', {}, c.transport === 'tls' ? 'TLS · ' + (c.role || 'no role') : 'plain TCP'),
    h('td', {class: 'n'}, num(c.requests)),
    h('td', {title: c.since}, dur(now - Date.parse(c.since) / 1000), h('div', {class: 'muted'}, 'since ' + clock(c.since)))));
  if (!rows.length) rows.push(h('tr', {}, h('td', {colspan: '4', class: 'muted'}, 'no client connected')));
  $('clients').replaceChildren(...rows);  // a few rows whose counts change every second anyway
}

// Rebuilt only when they change (a reload): they stay the same from one poll to the next.
let shownWarnings = '';
function renderWarnings(warnings) {
  const now = JSON.stringify(warnings);
  if (now === shownWarnings) return;
  shownWarnings = now;
  $('warnings').hidden = !warnings.length;
  $('warn-list').replaceChildren(...warnings.map(w =>
    h('li', {class: 's-warn'}, h('i', {class: 'icon', 'aria-hidden': 'true'}), h('span', {}, 'warning: ' + w))));
}

// The edge node (gateway.md §5.5): absent (null) when MQTT is off.
function renderSparkplug(sp) {
  $('sparkplug').hidden = !sp;
  if (!sp) return;
  txt($('sp-node'), sp.group_id + '/' + sp.edge_node_id + ' on ' + sp.broker);
  txt($('sp-conn'), sp.connected ? 'connected' : 'not connected, retrying');
  txt($('sp-online'), sp.online ? 'out: online' : 'not out yet');
  txt($('sp-bdseq'), num(sp.bdseq));
  txt($('sp-pub'), num(sp.published));
  txt($('sp-drop'), num(sp.dropped));
  txt($('sp-births'), num(sp.births));
  // Store-and-forward (gateway.md §6.2): null without a store.
  const st = sp.store;
  $('sp-store-box').hidden = !st;
  if (!st) return;
  txt($('sp-backlog'), num(st.records) + ' records, ' + num(st.bytes) + ' bytes' +
      (st.forwarding ? ' · forwarding' : ''));
  txt($('sp-oldest'), st.oldest == null ? '—' : dur(Math.max(0, Date.now() - st.oldest) / 1000) + ' ago');
  txt($('sp-fwd'), num(st.forwarded));
  txt($('sp-sdrop'), num(st.dropped));
}

// Plain MQTT and Home Assistant discovery (gateway.md §6.3): absent (null) when off.
function renderMqttJson(mj) {
  $('mqtt-json').hidden = !mj;
  if (!mj) return;
  txt($('mj-where'), mj.topic_prefix + '/# on ' + mj.broker);
  txt($('mj-conn'), mj.connected ? 'connected' : 'not connected, retrying');
  txt($('mj-disc'), mj.discovery_prefix ? 'under ' + mj.discovery_prefix + '/' : 'off');
  txt($('mj-pub'), num(mj.published));
  txt($('mj-drop'), num(mj.dropped));
  txt($('mj-sets'), num(mj.sets) + (mj.sets_refused ? ', ' + num(mj.sets_refused) + ' refused' : ''));
  txt($('mj-clear'), num(mj.discovery_cleared));
}

function renderEvents(events) {
  // Rebuilt only when there is a new event (its time too: a restarted daemon counts from 1 again).
  const newest = events[events.length - 1], key = newest ? newest.seq + newest.time : '';
  if (key === lastEvent) return;
  lastEvent = key;
  const rows = events.slice().reverse().map(e => h('tr', {},
    h('td', {class: 't', title: e.time}, clock(e.time)),
    h('td', {}, h('span', {class: 'kind ' + (EVENT_CLASS[e.kind] || 's-idle')}, h('i', {class: 'icon'}), h('span', {}, e.kind.replace('_', ' ')))),
    h('td', {}, e.text)));
  if (!rows.length) rows.push(h('tr', {}, h('td', {colspan: '3', class: 'muted'}, 'no events yet')));
  $('ev').replaceChildren(...rows);
}

let linkViews = [];
function render(s) {
  serverNow = Date.parse(s.time) / 1000;
  txt($('version'), 'v' + s.version);
  const hl = $('health');
  setStatus(hl, s.health.ok ? 's-ok' : 's-bad');
  txt(hl.lastChild, s.health.ok ? 'healthy' : 'unhealthy: ' + (s.health.reason || 'unknown reason'));
  txt($('updated'), 'updated ' + clock(s.time) + ' UTC');
  // null without authentication (gateway.md §7.1); the user signed in otherwise.
  const user = s.user || null;
  operator = !!(user && user.operator);
  $('user').hidden = !user;
  txt($('user'), user ? `signed in as ${user.name}${operator ? '' : ' (read only)'}` : '');

  // The tiles are built once per configuration (a reload may change it) and for the user's
  // rights (they may change with it), and then only updated.
  const shape = JSON.stringify([operator, s.links.map(l => [l.name, l.protocol, l.device, l.baud,
    l.unit_id, l.modules.map(m => [m.module, m.type, m.number, m.slot, m.name, m.inputs, m.outputs,
      (m.channels || []).map(c => [c.name, c.unit, c.range])])])]);
  if (shape !== structure) {
    structure = shape;
    tiles = new Map();
    linkViews = s.links.map(buildLink);
    $('links').replaceChildren(...linkViews.map(v => v.el));
    drawTrends();
  }
  s.links.forEach((l, i) => updateLink(linkViews[i], l));

  const mods = s.links.flatMap(l => l.modules);
  const up = mods.filter(m => m.status === 1).length, open = s.links.filter(l => l.port_open).length;
  txt($('k-up'), dur(serverNow - Date.parse(s.started) / 1000));
  txt($('k-ports'), `${open} / ${s.links.length}`);
  txt($('k-mods'), `${up} / ${mods.length}`);
  txt($('k-clients'), `${s.modbus.connections} / ${s.modbus.max_connections}`);
  txt($('k-cl'), s.modbus.comm_loss ? 'yes' : 'no');
  for (const [id, bad] of [['k-ports', open < s.links.length], ['k-mods', up < mods.length], ['k-cl-box', s.modbus.comm_loss]])
    $(id).closest('.kpi').classList.toggle('alarm', bad);
  renderWarnings(s.warnings || []);
  renderModbus(s.modbus, serverNow);
  renderSparkplug(s.sparkplug);
  renderMqttJson(s.mqtt_json);
  renderEvents(s.events);
}

// ---- Polling ----------------------------------------------------------------------------
async function getJSON(url) {
  const ctl = new AbortController(), timer = setTimeout(() => ctl.abort(), TIMEOUT_MS);
  try {
    const r = await fetch(apiUrl(url), {cache: 'no-store', signal: ctl.signal});
    if (!r.ok) throw new Error('HTTP ' + r.status);
    return await r.json();
  } finally {
    clearTimeout(timer);
  }
}

function connection(ok, why) {
  document.body.classList.toggle('lost', !ok);
  if (ok) { lastOk = Date.now(); txt($('conn'), ''); return; }
  const since = lastOk ? `; last update ${dur((Date.now() - lastOk) / 1000)} ago` : '';
  txt($('conn'), `Connection to ioportd lost — retrying… (${why}${since})`);
  setStatus($('health'), 's-idle');
  txt($('health').lastChild, 'health unknown');
}

let polls = 0, polling = false, pollAgain = false, pollTimer = 0;
let waiters = [];  // [the number of polls started then, fn]: run once a later poll is shown
const afterState = fn => waiters.push([polls, fn]);
// A confirmed write shows at once rather than at the next second's poll.
function pollSoon() {
  if (polling) { pollAgain = true; return; }
  clearTimeout(pollTimer);
  pollState();
}

// Each poll schedules the next when it is done: a slow daemon never gets requests piling up.
// Nothing here may throw out of the loop, or the page would silently freeze.
async function pollState() {
  polling = true;
  const start = Date.now(), number = ++polls;
  let s = null, why = '';
  try { s = await getJSON(STATE_URL); } catch (e) {
    why = e.name === 'AbortError' ? 'no answer within 4 s' : /^HTTP/.test(e.message) ? e.message : 'no connection';
  }
  connection(s !== null, why);
  if (s) {
    try { render(s); } catch (e) {
      // Data the page does not understand is a bug to see (the browser test fails on console
      // errors); the page keeps polling in case the next answer is fine.
      console.error('ioportd status page: cannot show the state:', e);
    }
    const due = waiters.filter(([after]) => after < number);
    waiters = waiters.filter(([after]) => after >= number);
    for (const [, fn] of due) fn();
  }
  polling = false;
  pollTimer = setTimeout(pollState, pollAgain ? 0 : Math.max(100, STATE_MS - (Date.now() - start)));
  pollAgain = false;
}

async function pollTrends() {
  const start = Date.now();
  let tr = null;
  try { tr = await getJSON(TRENDS_URL); } catch (e) { /* keep the last plots; the state poll reports a lost connection */ }
  if (tr) {
    try {
      span = tr.span_seconds || 600;
      interval = tr.interval_seconds || 5;
      series = new Map(tr.series.map(x => [`${x.link}|${x.module}|${x.channel}`, x.points]));
      drawTrends();
    } catch (e) { console.error('ioportd status page: cannot draw the trends:', e); }
  }
  setTimeout(pollTrends, Math.max(100, TRENDS_MS - (Date.now() - start)));
}

pollState();
pollTrends();
