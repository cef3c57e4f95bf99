// The live map: draws /api/map and follows /api/events (server-sent events).
// Plain JavaScript and SVG, no libraries: the page is embedded in the service binary.
'use strict';

const SVG_NS = 'http://www.w3.org/2000/svg';
const WIDTH = 800, HEIGHT = 600, MARGIN = 40; // px of the SVG viewBox
let lastMap = null;
let selectedId = null;
let selectedComponents = null;
let updates = 0;

function el(name, attrs, parent) {
  const node = document.createElementNS(SVG_NS, name);
  for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, v);
  if (parent) parent.appendChild(node);
  return node;
}

// Why a placed node is not converged (the engine's NodeDoubt, docs/engine.md "Convergence").
const REASONS = {
  'too few links': 'fewer than three links to placed nodes: its ranges cannot fix it',
  'ambiguous': 'another position, or another map of its part, fits its links about as well',
  'foldable': 'its part of the network hangs on one or two nodes: its side is undecided',
  'flexible': 'one unnoticed error in the links it hangs on could move it a metre or more',
  'unsettled': 'its estimate is still moving',
};

// Ids as the service writes them in `id_hex` and in its logs (docs/outputs.md, "Node ids").
function hexId(id) { return '0x' + id.toString(16).toUpperCase().padStart(4, '0'); }
function nodeLabel(n) { return n.id_hex || hexId(n.id); }

// 2x2 covariance -> ellipse radii (sigma) and angle (rad) of the major axis.
function covarianceEllipse(vxx, vxy, vyy) {
  const mean = (vxx + vyy) / 2;
  const diff = (vxx - vyy) / 2;
  const root = Math.sqrt(diff * diff + vxy * vxy);
  const l1 = Math.max(mean + root, 0), l2 = Math.max(mean - root, 0);
  return { r1: Math.sqrt(l1), r2: Math.sqrt(l2), angle: 0.5 * Math.atan2(2 * vxy, vxx - vyy) };
}

// World (m, y up) to SVG (px, y down), fitted to everything that is placed.
function makeView(map) {
  let xs = [], ys = [];
  for (const n of map.nodes) {
    if (!n.placed) continue;
    const s = 2 * Math.sqrt(Math.max(n.var_x_m2, n.var_y_m2, 0));
    xs.push(n.x_m - s, n.x_m + s); ys.push(n.y_m - s, n.y_m + s);
  }
  if (map.robot) { xs.push(map.robot.x_m); ys.push(map.robot.y_m); }
  if (selectedComponents) {
    for (const c of selectedComponents.components) { xs.push(c.x_m); ys.push(c.y_m); }
  }
  if (xs.length === 0) { xs = [-5, 5]; ys = [-5, 5]; }
  let x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  if (x1 - x0 < 1) { x0 -= 0.5; x1 += 0.5; }
  if (y1 - y0 < 1) { y0 -= 0.5; y1 += 0.5; }
  const scale = Math.min((WIDTH - 2 * MARGIN) / (x1 - x0), (HEIGHT - 2 * MARGIN) / (y1 - y0)); // px/m
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  return {
    scale,
    x: (x) => WIDTH / 2 + (x - cx) * scale,
    y: (y) => HEIGHT / 2 - (y - cy) * scale,
  };
}

function drawEllipse(parent, view, x, y, vxx, vxy, vyy, sigmas, cls, opacity) {
  const e = covarianceEllipse(vxx, vxy, vyy);
  const deg = -e.angle * 180 / Math.PI; // y is flipped on screen
  const attrs = {
    class: cls, cx: view.x(x), cy: view.y(y),
    rx: Math.max(sigmas * e.r1 * view.scale, 0.5), ry: Math.max(sigmas * e.r2 * view.scale, 0.5),
    transform: `rotate(${deg} ${view.x(x)} ${view.y(y)})`,
  };
  if (opacity !== undefined) attrs.opacity = opacity;
  return el('ellipse', attrs, parent);
}

function clear(id) { const g = document.getElementById(id); while (g.firstChild) g.removeChild(g.firstChild); return g; }

function drawGrid(view) {
  const g = clear('grid');
  const step = Math.pow(10, Math.floor(Math.log10(200 / view.scale))); // m between lines
  const xw0 = (0 - WIDTH / 2) / view.scale, xw1 = (WIDTH - WIDTH / 2) / view.scale;
  for (let k = -200; k <= 200; ++k) {
    const px = view.x(k * step), py = view.y(k * step);
    if (px >= 0 && px <= WIDTH) el('line', { class: 'grid', x1: px, y1: 0, x2: px, y2: HEIGHT }, g);
    if (py >= 0 && py <= HEIGHT) el('line', { class: 'grid', x1: 0, y1: py, x2: WIDTH, y2: py }, g);
  }
  void xw0; void xw1;
}

function render(map) {
  lastMap = map;
  const view = makeView(map);
  drawGrid(view);
  const byId = new Map(map.nodes.map((n) => [n.id, n]));

  const links = clear('links');
  for (const l of map.links) {
    const a = byId.get(l.a), b = byId.get(l.b);
    if (!a || !b || !a.placed || !b.placed) continue;
    const line = el('line', { class: 'link', 'data-a': l.a, 'data-b': l.b,
      x1: view.x(a.x_m), y1: view.y(a.y_m), x2: view.x(b.x_m), y2: view.y(b.y_m) }, links);
    el('title', {}, line).textContent = `${hexId(l.a)} – ${hexId(l.b)}: ${l.last_range_m.toFixed(3)} m (${l.range_count} ranges)`;
  }

  const ellipses = clear('ellipses');
  const nodes = clear('nodes');
  const unplaced = [];
  for (const n of map.nodes) {
    if (!n.placed) { unplaced.push(n); continue; }
    drawEllipse(ellipses, view, n.x_m, n.y_m, n.var_x_m2, n.cov_xy_m2, n.var_y_m2, 2, 'sigma2').setAttribute('data-id', n.id);
    const cls = ['node'];
    if (n.converged) cls.push('converged');
    if (n.moving) cls.push('moving');
    if (n.foldable) cls.push('foldable');
    if (n.id === selectedId) cls.push('selected');
    const g = el('g', { class: cls.join(' '), 'data-id': n.id, 'data-reason': n.reason || '' }, nodes);
    el('circle', { cx: view.x(n.x_m), cy: view.y(n.y_m), r: 7 }, g);
    el('text', { x: view.x(n.x_m) + 10, y: view.y(n.y_m) - 10 }, g).textContent = nodeLabel(n);
    el('title', {}, g).textContent = `${nodeLabel(n)}: x ${n.x_m.toFixed(3)} m, y ${n.y_m.toFixed(3)} m` +
      (n.z_m !== null && n.z_m !== undefined ? `, z ${n.z_m.toFixed(3)} m` : '') +
      (n.reason ? ` - not converged: ${REASONS[n.reason] || n.reason}` : '');
    g.addEventListener('click', () => selectNode(n.id));
  }
  const list = document.getElementById('unplaced');
  list.textContent = unplaced.length ? 'Not placed yet: ' + unplaced.map(nodeLabel).join(', ') : '';

  const robot = clear('robot');
  if (map.robot) {
    const r = map.robot, x = view.x(r.x_m), y = view.y(r.y_m), h = -r.heading_rad;
    const pts = [[14, 0], [-8, 7], [-8, -7]].map(([u, v]) =>
      `${x + u * Math.cos(h) - v * Math.sin(h)},${y + u * Math.sin(h) + v * Math.cos(h)}`).join(' ');
    const shape = el('polygon', { class: 'robot', points: pts, 'data-id': r.id, 'data-frame': r.frame || '' }, robot);
    el('title', {}, shape).textContent = `robot ${nodeLabel(r)} (${r.frame || 'odometry'} frame): ` +
      `x ${r.x_m.toFixed(3)} m, y ${r.y_m.toFixed(3)} m, heading ${r.heading_rad.toFixed(3)} rad`;
  }

  drawComponents(view);
  renderHealth(map.health);
  document.getElementById('t-s').textContent = map.t_s.toFixed(1);
  if (typeof map.t_unix_s === 'number') {
    document.getElementById('clock').title = new Date(map.t_unix_s * 1000).toISOString();
  }
}

function drawComponents(view) {
  const g = clear('components');
  if (!selectedComponents) return;
  for (const c of selectedComponents.components) {
    drawEllipse(g, view, c.x_m, c.y_m, c.var_x_m2, c.cov_xy_m2, c.var_y_m2, 2, 'component',
      0.25 + 0.75 * Math.min(1, c.weight * selectedComponents.components.length));
  }
}

function renderHealth(h) {
  const badge = document.getElementById('link-state');
  badge.textContent = h.link;
  badge.dataset.state = h.link;
  document.getElementById('health-link').textContent = h.link;
  document.getElementById('health-device').textContent = h.device || '–';
  document.getElementById('health-detail').textContent = h.detail || '–';
  fillTable('counters', h.counters, 'counter');
  const rates = {};
  for (const [k, v] of Object.entries(h.rates)) rates[k] = v.toFixed(1);
  fillTable('rates', rates, 'rate');
}

function fillTable(id, values, kind) {
  const body = document.querySelector(`#${id} tbody`);
  for (const [name, value] of Object.entries(values)) {
    let row = body.querySelector(`tr[data-${kind}="${name}"]`);
    if (!row) {
      row = document.createElement('tr');
      row.dataset[kind] = name;
      const label = document.createElement('td');
      label.textContent = name;
      const cell = document.createElement('td');
      cell.className = 'value';
      row.append(label, cell);
      body.appendChild(row);
    }
    row.lastChild.textContent = String(value);
  }
}

async function selectNode(id) {
  selectedId = id;
  const text = document.getElementById('selection-text');
  text.textContent = `${hexId(id)}: loading components…`;
  try {
    const response = await fetch(`/api/nodes/${id}/components`);
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    selectedComponents = await response.json();
    text.textContent = `${hexId(id)}: ${selectedComponents.components.length} components`;
    const body = document.querySelector('#components-table tbody');
    while (body.firstChild) body.removeChild(body.firstChild);
    for (const c of selectedComponents.components) {
      const row = document.createElement('tr');
      row.className = 'component-row';
      row.innerHTML = `<td>ring of ${hexId(c.center_id)}</td><td class="value">${c.x_m.toFixed(2)}, ${c.y_m.toFixed(2)} m</td><td class="value">w ${c.weight.toFixed(3)}</td>`;
      body.appendChild(row);
    }
  } catch (error) {
    selectedComponents = null;
    text.textContent = `${hexId(id)}: components unavailable (${error.message})`;
  }
  if (lastMap) render(lastMap);
}

async function loadOnce() {
  try {
    const response = await fetch('/api/map');
    if (response.ok) render(await response.json());
  } catch (error) { /* the event stream will bring the map */ }
}

function follow() {
  const stream = document.getElementById('stream');
  const source = new EventSource('/api/events');
  source.addEventListener('open', () => { stream.textContent = 'open'; });
  source.addEventListener('map', (event) => {
    updates += 1;
    document.getElementById('update-count').textContent = String(updates);
    render(JSON.parse(event.data));
  });
  source.addEventListener('error', () => { stream.textContent = 'reconnecting'; });
}

loadOnce();
follow();
