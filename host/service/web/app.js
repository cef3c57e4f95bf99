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

function finite(value) { return typeof value === 'number' && Number.isFinite(value); }

// A node the map can draw: placed, with a position (null or a non-number is drawn as not placed
// rather than breaking the page).
function hasPosition(n) { return n.placed && finite(n.x_m) && finite(n.y_m); }

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

// The view: world (m, y up) to SVG viewBox (px, y down), px = WIDTH/2 + (x - cx) * scale.
// It follows the map (fitted to everything placed) until the user zooms or pans; "fit" follows
// again. The SVG carries the transform in data attributes (data-scale-px-per-m,
// data-center-x-m, data-center-y-m), so that a test can check what is drawn against it.
const viewState = { follow: true, cx: 0, cy: 0, scale: 50 };
const MIN_SCALE = 0.5, MAX_SCALE = 5000; // px/m

function fitView(map) {
  let xs = [], ys = [];
  for (const n of map.nodes) {
    if (!hasPosition(n)) continue;
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
  viewState.scale = Math.min((WIDTH - 2 * MARGIN) / (x1 - x0), (HEIGHT - 2 * MARGIN) / (y1 - y0));
  viewState.cx = (x0 + x1) / 2;
  viewState.cy = (y0 + y1) / 2;
}

function makeView(map) {
  if (viewState.follow) fitView(map);
  const { cx, cy, scale } = viewState;
  const svg = document.getElementById('map');
  svg.dataset.scalePxPerM = String(scale);
  svg.dataset.centerXM = String(cx);
  svg.dataset.centerYM = String(cy);
  document.getElementById('view-mode').textContent = viewState.follow ? 'following the map' : 'zoomed or panned (fit: follow again)';
  return {
    scale,
    x: (x) => WIDTH / 2 + (x - cx) * scale,
    y: (y) => HEIGHT / 2 - (y - cy) * scale,
    worldX: (px) => cx + (px - WIDTH / 2) / scale,
    worldY: (py) => cy - (py - HEIGHT / 2) / scale,
  };
}

// For tests and the console: the transform now in use.
window.cdroLiveMap = {
  view: () => ({ follow: viewState.follow, center_x_m: viewState.cx, center_y_m: viewState.cy,
                 scale_px_per_m: viewState.scale, width_px: WIDTH, height_px: HEIGHT }),
  map: () => lastMap, // the map drawn now (/api/map's object)
  gridLabel: (valueM, stepM) => `${gridNumber(valueM, stepM)} m`, // a grid line's label
};

// The nicest step of 1, 2 or 5 x 10^k metres that is at least min_px on screen.
function niceStep(scale, minPx) {
  const raw = minPx / scale;
  const decade = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const f of [1, 2, 5, 10]) if (f * decade >= raw) return f * decade;
  return 10 * decade;
}

function metresText(value) {
  const digits = Math.max(0, -Math.floor(Math.log10(Math.abs(value) || 1)));
  return `${value.toFixed(Math.min(digits, 3))} m`;
}

// The decimals that write every multiple of a grid step as it is: 1 m -> 0, 0.5 m -> 1, 0.25 m -> 2.
function stepDigits(stepM) {
  for (let digits = 0; digits < 6; ++digits) {
    const scaled = stepM * Math.pow(10, digits);
    if (Math.abs(scaled - Math.round(scaled)) < 1e-9 * Math.max(1, scaled)) return digits;
  }
  return 6;
}

// A grid line's value (m) with its step's decimals: 4.5 on a 0.5 m grid is "4.5", not "5" (the
// value's own size says nothing about the decimals the grid needs), 4 on it "4.0".
function gridNumber(valueM, stepM) { return valueM.toFixed(stepDigits(stepM)); }

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

// Grid lines at a round number of metres, labelled along the bottom and the left edge.
function drawGrid(view) {
  const g = clear('grid');
  const labels = clear('grid-labels');
  const step = niceStep(view.scale, 60); // m between lines
  const x0 = view.worldX(0), x1 = view.worldX(WIDTH), y0 = view.worldY(HEIGHT), y1 = view.worldY(0);
  for (let k = Math.ceil(x0 / step); k <= Math.floor(x1 / step); ++k) {
    const px = view.x(k * step);
    el('line', { class: k === 0 ? 'grid axis' : 'grid', x1: px, y1: 0, x2: px, y2: HEIGHT }, g);
    el('text', { class: 'grid-label', x: px + 2, y: HEIGHT - 4 }, labels).textContent = `${gridNumber(k * step, step)} m`;
  }
  for (let k = Math.ceil(y0 / step); k <= Math.floor(y1 / step); ++k) {
    const py = view.y(k * step);
    el('line', { class: k === 0 ? 'grid axis' : 'grid', x1: 0, y1: py, x2: WIDTH, y2: py }, g);
    el('text', { class: 'grid-label', x: 2, y: py - 2 }, labels).textContent = `${gridNumber(k * step, step)} m`;
  }
}

// A bar of a round length (1, 2 or 5 x 10^k m) of 60..150 px, bottom right.
function drawScaleBar(view) {
  const g = clear('scale-bar');
  const lengthM = niceStep(view.scale, 60);
  const lengthPx = lengthM * view.scale;
  const x1 = WIDTH - 20, x0 = x1 - lengthPx, y = HEIGHT - 24;
  el('rect', { class: 'scale-backdrop', x: x0 - 6, y: y - 18, width: lengthPx + 12, height: 28 }, g);
  el('line', { id: 'scale-bar-line', class: 'scale', x1: x0, y1: y, x2: x1, y2: y,
    'data-length-m': lengthM, 'data-length-px': lengthPx }, g);
  el('line', { class: 'scale', x1: x0, y1: y - 5, x2: x0, y2: y + 5 }, g);
  el('line', { class: 'scale', x1: x1, y1: y - 5, x2: x1, y2: y + 5 }, g);
  el('text', { id: 'scale-bar-label', class: 'scale-label', x: (x0 + x1) / 2, y: y - 6 }, g).textContent = metresText(lengthM);
}

// ---- floor plan (web.floor_plan) ------------------------------------------------------------
let floorPlan = null; // /api/floor-plan, or null

function drawFloorPlan(view) {
  const g = clear('underlay');
  if (!floorPlan) return;
  const f = floorPlan;
  const wM = f.width_px * f.metres_per_pixel, hM = f.height_px * f.metres_per_pixel;
  const ox = view.x(f.origin_x_m), oy = view.y(f.origin_y_m);
  // The image's bottom-left corner sits at the origin; its top-left is hM above it on the map.
  el('image', { id: 'floor-plan', href: f.url, x: ox, y: oy - hM * view.scale, width: wM * view.scale,
    height: hM * view.scale, preserveAspectRatio: 'none',
    transform: `rotate(${-f.rotation_rad * 180 / Math.PI} ${ox} ${oy})` }, g);
}

async function loadFloorPlan() {
  const state = document.getElementById('floor-plan-state');
  try {
    const response = await fetch('/api/floor-plan');
    if (response.status === 404) { state.textContent = ''; return; }
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    floorPlan = await response.json();
    state.textContent = `floor plan ${floorPlan.width_px} x ${floorPlan.height_px} px, ${floorPlan.metres_per_pixel} m/px`;
    if (lastMap) render(lastMap);
  } catch (error) {
    state.textContent = `floor plan unavailable (${error.message})`;
  }
}

// ---- trails and 2-sigma history, kept by the page from the maps it received ----------------
const ROBOT_TRAIL_POINTS = 2000, NODE_TRAIL_POINTS = 500, SIGMA_SAMPLES = 600;
let robotTrail = [], robotTrailFrame = null;
const nodeTrails = new Map(); // id -> [[x, y], ...] while the node moved
const sigmaHistory = new Map(); // id -> [[t_s, r_m], ...]

function pushBounded(list, item, limit) {
  list.push(item);
  if (list.length > limit) list.splice(0, list.length - limit);
}

function samePoint(a, b) { return a && b && a[0] === b[0] && a[1] === b[1]; }

function twoSigmaRadius(n) { return 2 * covarianceEllipse(n.var_x_m2, n.cov_xy_m2, n.var_y_m2).r1; }

function remember(map) {
  if (map.robot) {
    if (map.robot.frame !== robotTrailFrame) { robotTrail = []; robotTrailFrame = map.robot.frame; }
    const p = [map.robot.x_m, map.robot.y_m];
    if (!samePoint(robotTrail[robotTrail.length - 1], p)) pushBounded(robotTrail, p, ROBOT_TRAIL_POINTS);
  }
  for (const n of map.nodes) {
    if (!hasPosition(n)) continue;
    const p = [n.x_m, n.y_m];
    let trail = nodeTrails.get(n.id);
    if (n.moving || n.status === 'settling') {
      if (!trail) { trail = []; nodeTrails.set(n.id, trail); }
      if (!samePoint(trail[trail.length - 1], p)) pushBounded(trail, p, NODE_TRAIL_POINTS);
    }
    let history = sigmaHistory.get(n.id);
    if (!history) { history = []; sigmaHistory.set(n.id, history); }
    const last = history[history.length - 1];
    if (!last || map.t_s > last[0]) pushBounded(history, [map.t_s, twoSigmaRadius(n)], SIGMA_SAMPLES);
  }
}

function drawTrails(view) {
  const g = clear('trails');
  const points = (list) => list.map(([x, y]) => `${view.x(x)},${view.y(y)}`).join(' ');
  for (const [id, trail] of nodeTrails) {
    if (trail.length >= 2) el('polyline', { class: 'trail node-trail', 'data-id': id, points: points(trail) }, g);
  }
  if (robotTrail.length >= 2) el('polyline', { class: 'trail robot-trail', points: points(robotTrail) }, g);
}

function drawSigmaChart() {
  const svg = document.getElementById('sigma-chart');
  while (svg.firstChild) svg.removeChild(svg.firstChild);
  const W = 360, H = 150, L = 44, B = 20, T = 8, R = 8;
  let t0 = Infinity, t1 = -Infinity, r1 = 0;
  for (const h of sigmaHistory.values()) {
    for (const [t, r] of h) { t0 = Math.min(t0, t); t1 = Math.max(t1, t); r1 = Math.max(r1, r); }
  }
  if (!(t1 > t0) || !(r1 > 0)) {
    el('text', { class: 'chart-label', x: L, y: H / 2 }, svg).textContent = 'waiting for two maps…';
    return;
  }
  const x = (t) => L + (t - t0) / (t1 - t0) * (W - L - R);
  const y = (r) => H - B - r / r1 * (H - B - T);
  el('line', { class: 'chart-axis', x1: L, y1: H - B, x2: W - R, y2: H - B }, svg);
  el('line', { class: 'chart-axis', x1: L, y1: T, x2: L, y2: H - B }, svg);
  el('text', { class: 'chart-label', x: L - 4, y: T + 8, 'text-anchor': 'end' }, svg).textContent = metresText(r1);
  el('text', { class: 'chart-label', x: L - 4, y: H - B, 'text-anchor': 'end' }, svg).textContent = '0 m';
  el('text', { class: 'chart-label', x: L, y: H - 4 }, svg).textContent = `t ${t0.toFixed(0)} s`;
  el('text', { class: 'chart-label', x: W - R, y: H - 4, 'text-anchor': 'end' }, svg).textContent = `${t1.toFixed(0)} s`;
  const ordered = [...sigmaHistory.entries()].sort(([a], [b]) => (a === selectedId) - (b === selectedId));
  for (const [id, samples] of ordered) {
    if (samples.length < 1) continue;
    el('polyline', { class: id === selectedId ? 'sigma-line selected' : 'sigma-line', 'data-id': id,
      points: samples.map(([t, r]) => `${x(t)},${y(r)}`).join(' ') }, svg);
  }
}

// ---- link residuals -----------------------------------------------------------------------
const RESIDUAL_WARN_M = 0.15, RESIDUAL_BAD_M = 0.5;

function residualClass(l) {
  if (typeof l.residual_m !== 'number') return 'residual-unknown';
  const r = Math.abs(l.residual_m);
  return r < RESIDUAL_WARN_M ? 'residual-ok' : r < RESIDUAL_BAD_M ? 'residual-warn' : 'residual-bad';
}

function fixed(value, digits) { return typeof value === 'number' ? value.toFixed(digits) : '–'; }

function renderLinkTable(links) {
  const body = document.querySelector('#links-table tbody');
  while (body.firstChild) body.removeChild(body.firstChild);
  const sorted = [...links].sort((p, q) => Math.abs(q.residual_m ?? -1) - Math.abs(p.residual_m ?? -1));
  for (const l of sorted) {
    const row = document.createElement('tr');
    row.dataset.a = l.a; row.dataset.b = l.b;
    const cells = [`${hexId(l.a)} – ${hexId(l.b)}`, fixed(l.range_median_m, 3), fixed(l.fitted_distance_m, 3),
      (typeof l.residual_m === 'number' && l.residual_m > 0 ? '+' : '') + fixed(l.residual_m, 3)];
    cells.forEach((text, k) => {
      const cell = document.createElement('td');
      cell.textContent = text;
      if (k > 0) cell.className = 'value';
      if (k === 3) cell.classList.add(residualClass(l));
      row.appendChild(cell);
    });
    if (typeof l.inlier_probability === 'number') row.title = `line-of-sight probability ${l.inlier_probability.toFixed(2)}`;
    body.appendChild(row);
  }
}

// ---- side view: the height of the nodes tracked in 3D ---------------------------------------
// x as on the map (the same transform, so a node's dot sits right under its circle), z up from
// the ground with its own scale fitted to the heights and their 2-sigma bars. The SVG carries
// that scale in data-z-scale-px-per-m and the ground's row in data-ground-px, so that a test
// can check what is drawn against it.
const SIDE_HEIGHT = 200, SIDE_TOP = 14, SIDE_BOTTOM = 16; // px of the side view's viewBox
const tracked3d = new Set(); // ids of the nodes seen with a 3D track's keys (var_z_m2)

// A node tracked in 3D (the configuration's moving list) carries var_z_m2 once placed; one seen
// with it stays a 3D node on this page, so a map that lacks the key for it still draws it as one
// (without its bar). Known heights alone (heights CSV) do not make a node 3D.
function isTracked3d(n) {
  if ('var_z_m2' in n) tracked3d.add(n.id);
  return tracked3d.has(n.id);
}

// Half the 2-sigma interval of z (m), or null where the variance is not known.
function twoSigmaZ(n) { return finite(n.var_z_m2) && n.var_z_m2 >= 0 ? 2 * Math.sqrt(n.var_z_m2) : null; }

function heightText(n) {
  const bar = twoSigmaZ(n);
  return bar === null ? `z ${n.z_m.toFixed(2)} m (2-sigma not known)` : `z ${n.z_m.toFixed(2)} ± ${bar.toFixed(2)} m`;
}

function onSideView(n) { return hasPosition(n) && finite(n.z_m); }

function drawSideView(view, map) {
  const panel = document.getElementById('side-panel');
  const tracks = [], others = [];
  for (const n of map.nodes) {
    if (!onSideView(n)) continue;
    (isTracked3d(n) ? tracks : others).push(n);
  }
  const grid = clear('side-grid'), ticks = clear('side-static'), bars = clear('side-bars');
  const dots = clear('side-nodes'), labels = clear('side-labels');
  panel.hidden = tracks.length === 0;
  if (panel.hidden) return;

  // The heights shown: the ground, every dot with its bar, every tick.
  let z0 = 0, z1 = 0;
  for (const n of tracks.concat(others)) {
    const bar = twoSigmaZ(n) || 0;
    z0 = Math.min(z0, n.z_m - bar); z1 = Math.max(z1, n.z_m + bar);
  }
  if (z1 - z0 < 1) z1 = z0 + 1;
  const pad = 0.05 * (z1 - z0);
  z0 -= pad; z1 += pad;
  const zScale = (SIDE_HEIGHT - SIDE_TOP - SIDE_BOTTOM) / (z1 - z0); // px/m
  const zPx = (z) => SIDE_HEIGHT - SIDE_BOTTOM - (z - z0) * zScale;
  const svg = document.getElementById('side');
  svg.dataset.zScalePxPerM = String(zScale);
  svg.dataset.groundPx = String(zPx(0));

  // Vertical lines where the map has its own, so the two views read alike.
  const xStep = niceStep(view.scale, 60); // m
  for (let k = Math.ceil(view.worldX(0) / xStep); k <= Math.floor(view.worldX(WIDTH) / xStep); ++k) {
    const px = view.x(k * xStep);
    el('line', { class: 'grid', x1: px, y1: 0, x2: px, y2: SIDE_HEIGHT }, grid);
  }
  const zStep = niceStep(zScale, 30); // m
  for (let k = Math.ceil(z0 / zStep); k <= Math.floor(z1 / zStep); ++k) {
    const py = zPx(k * zStep);
    el('line', { class: k === 0 ? 'side-z-line side-ground' : 'grid side-z-line', 'data-z-m': k * zStep,
      x1: 0, y1: py, x2: WIDTH, y2: py }, grid);
    el('text', { class: 'grid-label side-z-label', x: 2, y: py - 2, 'data-z-m': k * zStep }, labels).textContent =
      k === 0 ? 'ground, z = 0 m' : `z ${gridNumber(k * zStep, zStep)} m`;
  }

  for (const n of others) {
    const px = view.x(n.x_m), py = zPx(n.z_m);
    const tick = el('line', { class: 'side-static', 'data-id': n.id, x1: px - 6, y1: py, x2: px + 6, y2: py }, ticks);
    el('title', {}, tick).textContent = `${nodeLabel(n)}: z ${n.z_m.toFixed(3)} m`;
  }
  for (const n of tracks) {
    const px = view.x(n.x_m), py = zPx(n.z_m), bar = twoSigmaZ(n);
    if (bar !== null) {
      el('line', { class: 'side-sigma2', 'data-id': n.id, 'data-two-sigma-m': bar,
        x1: px, y1: zPx(n.z_m + bar), x2: px, y2: zPx(n.z_m - bar) }, bars);
    }
    const g = el('g', { class: n.id === selectedId ? 'side-node selected' : 'side-node', 'data-id': n.id }, dots);
    el('circle', { cx: px, cy: py, r: 5 }, g);
    el('text', { x: px + 8, y: py - 6 }, g).textContent = nodeLabel(n);
    el('title', {}, g).textContent = `${nodeLabel(n)}: ${heightText(n)}`;
  }
}

function render(map) {
  lastMap = map;
  const view = makeView(map);
  drawFloorPlan(view);
  drawGrid(view);
  const byId = new Map(map.nodes.map((n) => [n.id, n]));

  const links = clear('links');
  for (const l of map.links) {
    const a = byId.get(l.a), b = byId.get(l.b);
    if (!a || !b || !hasPosition(a) || !hasPosition(b)) continue;
    const line = el('line', { class: `link ${residualClass(l)}`, 'data-a': l.a, 'data-b': l.b,
      'data-residual-m': typeof l.residual_m === 'number' ? l.residual_m : '',
      x1: view.x(a.x_m), y1: view.y(a.y_m), x2: view.x(b.x_m), y2: view.y(b.y_m) }, links);
    el('title', {}, line).textContent = `${hexId(l.a)} – ${hexId(l.b)}: last ${l.last_range_m.toFixed(3)} m (${l.range_count} ranges)` +
      (typeof l.residual_m === 'number' ? `, median ${l.range_median_m.toFixed(3)} m, on the map ${l.fitted_distance_m.toFixed(3)} m, residual ${l.residual_m.toFixed(3)} m` : '');
  }
  drawTrails(view);

  const ellipses = clear('ellipses');
  const nodes = clear('nodes');
  const unplaced = [];
  for (const n of map.nodes) {
    if (!hasPosition(n)) { unplaced.push(n); continue; }
    drawEllipse(ellipses, view, n.x_m, n.y_m, n.var_x_m2, n.cov_xy_m2, n.var_y_m2, 2, 'sigma2').setAttribute('data-id', n.id);
    const cls = ['node'];
    if (n.converged) cls.push('converged');
    if (n.moving) cls.push('moving');
    if (n.foldable) cls.push('foldable');
    if (n.id === selectedId) cls.push('selected');
    const in3d = isTracked3d(n);
    if (in3d) cls.push('tracked-3d');
    const g = el('g', { class: cls.join(' '), 'data-id': n.id, 'data-reason': n.reason || '' }, nodes);
    el('circle', { cx: view.x(n.x_m), cy: view.y(n.y_m), r: 7 }, g);
    el('text', { x: view.x(n.x_m) + 10, y: view.y(n.y_m) - 10 }, g).textContent = nodeLabel(n);
    if (in3d) el('text', { class: 'badge-3d', x: view.x(n.x_m) + 10, y: view.y(n.y_m) + 16 }, g).textContent = '3D';
    let height = '';
    if (finite(n.z_m)) height = in3d ? `, ${heightText(n)}` : `, z ${n.z_m.toFixed(3)} m`;
    else if (in3d) height = ', z not known yet';
    el('title', {}, g).textContent = `${nodeLabel(n)}: x ${n.x_m.toFixed(3)} m, y ${n.y_m.toFixed(3)} m${height}` +
      (n.reason ? ` - not converged: ${REASONS[n.reason] || n.reason}` : '') +
      (typeof n.t_updated_unix_s === 'number' && typeof map.t_unix_s === 'number'
        ? ` (estimate changed ${(map.t_unix_s - n.t_updated_unix_s).toFixed(1)} s ago)` : '');
    g.addEventListener('click', () => { if (!dragMoved) selectNode(n.id); });
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
  drawScaleBar(view);
  drawSideView(view, map);
  drawSigmaChart();
  renderLinkTable(map.links);
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
    if (response.ok) onMap(await response.json());
  } catch (error) { /* the event stream will bring the map */ }
}

function follow() {
  const stream = document.getElementById('stream');
  const source = new EventSource('/api/events');
  source.addEventListener('open', () => { stream.textContent = 'open'; });
  source.addEventListener('map', (event) => {
    updates += 1;
    document.getElementById('update-count').textContent = String(updates);
    onMap(JSON.parse(event.data));
  });
  source.addEventListener('error', () => { stream.textContent = 'reconnecting'; });
}

function onMap(map) {
  remember(map);
  render(map);
}

// ---- zoom and pan ---------------------------------------------------------------------------
let drag = null, dragMoved = false;

// A client (screen) point in viewBox px.
function toViewBox(clientX, clientY) {
  const svg = document.getElementById('map');
  const point = svg.createSVGPoint();
  point.x = clientX; point.y = clientY;
  const mapped = point.matrixTransform(svg.getScreenCTM().inverse());
  return [mapped.x, mapped.y];
}

// Zooms by `factor` keeping the world point under viewBox point (px, py) where it is.
function zoomAt(factor, px, py) {
  if (!lastMap) return;
  const view = makeView(lastMap);
  const wx = view.worldX(px), wy = view.worldY(py);
  viewState.follow = false;
  viewState.scale = Math.min(MAX_SCALE, Math.max(MIN_SCALE, viewState.scale * factor));
  viewState.cx = wx - (px - WIDTH / 2) / viewState.scale;
  viewState.cy = wy + (py - HEIGHT / 2) / viewState.scale;
  render(lastMap);
}

function setUpViewControls() {
  const svg = document.getElementById('map');
  svg.addEventListener('wheel', (event) => {
    event.preventDefault();
    const [px, py] = toViewBox(event.clientX, event.clientY);
    zoomAt(Math.exp(-event.deltaY * 0.0015), px, py);
  }, { passive: false });
  svg.addEventListener('pointerdown', (event) => {
    if (event.button !== 0) return;
    drag = { last: toViewBox(event.clientX, event.clientY), id: event.pointerId };
    dragMoved = false;
  });
  svg.addEventListener('pointermove', (event) => {
    if (!drag || !lastMap) return;
    const p = toViewBox(event.clientX, event.clientY);
    const dx = p[0] - drag.last[0], dy = p[1] - drag.last[1];
    if (!dragMoved && Math.hypot(dx, dy) < 3) return; // a click, not yet a drag
    if (!dragMoved) {
      try { svg.setPointerCapture(drag.id); } catch (error) { /* a synthetic pointer: nothing to capture */ }
    }
    dragMoved = true;
    drag.last = p;
    viewState.follow = false;
    viewState.cx -= dx / viewState.scale;
    viewState.cy += dy / viewState.scale;
    render(lastMap);
  });
  const endDrag = () => { drag = null; setTimeout(() => { dragMoved = false; }, 0); };
  svg.addEventListener('pointerup', endDrag);
  svg.addEventListener('pointercancel', endDrag);
  document.getElementById('zoom-in').addEventListener('click', () => zoomAt(1.5, WIDTH / 2, HEIGHT / 2));
  document.getElementById('zoom-out').addEventListener('click', () => zoomAt(1 / 1.5, WIDTH / 2, HEIGHT / 2));
  document.getElementById('zoom-fit').addEventListener('click', () => {
    viewState.follow = true;
    if (lastMap) render(lastMap);
  });
}

setUpViewControls();
loadFloorPlan();
loadOnce();
follow();
