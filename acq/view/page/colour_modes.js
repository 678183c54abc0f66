// The clouds' colour modes of acq view: each cloud layer's points coloured by their own
// RGB, intensity, time, scan, source camera or whether they were coloured, chosen in the
// panel's select, with a legend for the mode shown. A mode works on the attributes
// points.js parses (a Points object's geometry.userData.points); a layer without the
// attribute is drawn grey and the legend says so. A cloud's first payload holds its
// positions and colours only: the other attributes are fetched when a mode first needs
// them (the select says "loading attributes…" meanwhile, the legend a layer's failure),
// so that a user who never colours never waits for them. Meshes keep their colours.
import * as THREE from 'three';
import { lacksAttributes, loadAttributes } from './points.js';

// sRGB bytes of the modes' colours
export const GREY = [128, 128, 128]; // a point without the mode's attribute; camera none
export const COLOURED = [46, 204, 64];
export const NOT_COLOURED = [255, 65, 54];
export const NO_RGB = [208, 208, 208]; // a cloud without colours in RGB mode
// one per camera (Tableau 10 without its grey), cycled past nine cameras
export const CAMERA_COLOURS = [
  [78, 121, 167], [242, 142, 43], [225, 87, 89], [118, 183, 178], [89, 161, 79],
  [237, 201, 72], [176, 122, 161], [255, 157, 167], [156, 117, 95],
];
// scans cycle through these seven (Okabe-Ito): neighbouring scans always differ
export const SCAN_COLOURS = [
  [230, 159, 0], [86, 180, 233], [0, 158, 115], [240, 228, 66], [0, 114, 178],
  [213, 94, 0], [204, 121, 167],
];
// viridis (perceptually uniform) at 0, 1/8, ..., 1: the time ramp
const VIRIDIS = [
  [68, 1, 84], [71, 44, 122], [59, 81, 139], [44, 113, 142], [33, 144, 141],
  [39, 173, 129], [92, 200, 99], [170, 220, 50], [253, 231, 37],
];
const GREYS = [[64, 64, 64], [255, 255, 255]]; // the intensity ramp, dark to white

export const MODES = [
  { id: 'rgb', label: 'RGB', needs: null },
  { id: 'intensity', label: 'intensity', needs: 'intensity' },
  { id: 'time', label: 'time', needs: 'time' },
  { id: 'scan', label: 'scan', needs: 'scan' },
  { id: 'camera', label: 'source camera', needs: 'camera' },
  { id: 'coloured', label: 'coloured or not', needs: 'coloured' },
];

const SRGB_TO_LINEAR = Float32Array.from(
  { length: 256 }, (_, c) => new THREE.Color().setRGB(c / 255, 0, 0, THREE.SRGBColorSpace).r);
const css = (rgb) => `rgb(${rgb.join(', ')})`;

const state = { mode: 'rgb', layers: [], legend: null, control: null, render: () => {} };
export const LOADING = 'loading attributes…'; // the select's text while they are fetched

// the Points objects of a layer's root (the root itself, or its children added later)
function pointsOf(root) {
  const found = [];
  root.traverse((o) => { if (o.isPoints && o.geometry.userData.points) found.push(o); });
  return found;
}

// whether a layer's file has an attribute (loaded or not)
const has = (layer, attribute) =>
  pointsOf(layer.root).some((o) => o.geometry.userData.points.has.includes(attribute));

// the attributes of the layers' points that lack `attribute`, fetched (a Promise, resolved
// when every fetch is over); a layer whose fetch failed keeps the reason in layer.failed
function fetchAttributes(layers, attribute) {
  return Promise.all(layers.map(async (layer) => {
    const lacking = pointsOf(layer.root).filter((o) => {
      const p = o.geometry.userData.points;
      return p.has.includes(attribute) && !(attribute in p.attributes);
    });
    if (!lacking.length) return;
    try {
      await Promise.all(lacking.map((o) => loadAttributes(o.geometry.userData.points, o.userData.attributesUrl)));
      layer.failed = undefined;
    } catch (error) {
      layer.failed = `${layer.name}: its attributes could not be loaded (${error?.message ?? error})`;
    }
  }));
}

// whether a mode needs attributes some layer's points have not fetched yet
const lacking = (mode) => {
  const needs = MODES.find((m) => m.id === mode).needs;
  return needs !== null && state.layers.some((layer) => pointsOf(layer.root)
    .some((o) => lacksAttributes(o.geometry.userData.points) && o.geometry.userData.points.has.includes(needs)));
};

const QUANTILE_SAMPLE = 1 << 18; // values a layer's quantiles are taken from at most

// the layer's values of an attribute over all its points (time: UTC s): [min, max], or
// its low and high quantiles
function range(layer, attribute, low = 0, high = 1) {
  const parts = pointsOf(layer.root)
    .map((o) => o.geometry.userData.points)
    .filter((p) => attribute in p.attributes)
    .map((p) => ({ values: p.attributes[attribute], base: attribute === 'time' ? p.time0 : 0 }));
  const n = parts.reduce((sum, p) => sum + p.values.length, 0);
  if (n === 0) return null;
  const all = new Float64Array(n);
  let at = 0;
  for (const { values, base } of parts) {
    for (let i = 0; i < values.length; i += 1) all[at + i] = values[i] + base;
    at += values.length;
  }
  if (low === 0 && high === 1) {
    let [lo, hi] = [Infinity, -Infinity];
    for (let i = 0; i < n; i += 1) {  // comparisons, which a NaN fails: it is no bound
      if (all[i] < lo) lo = all[i];
      if (all[i] > hi) hi = all[i];
    }
    return [lo, hi];
  }
  // the quantiles of an evenly strided sample: a ramp needs no finer rank, and sorting
  // millions of values took seconds
  const step = Math.max(1, Math.ceil(n / QUANTILE_SAMPLE));
  const sample = new Float64Array(Math.ceil(n / step));
  for (let i = 0, j = 0; i < n; i += step, j += 1) sample[j] = all[i];
  sample.sort();
  const m = sample.length;
  const pick = (q) => sample[Math.min(m - 1, Math.max(0, Math.round(q * (m - 1))))];
  return [pick(low), pick(high)];
}

// the sRGB bytes of a ramp's stops at u in [0, 1], interpolated
function ramp(stops, u) {
  const x = u * (stops.length - 1);
  const k = Math.min(Math.floor(x), stops.length - 2);
  const f = x - k;
  return [0, 1, 2].map((c) => Math.round(stops[k][c] + (stops[k + 1][c] - stops[k][c]) * f));
}

// colours (sRGB bytes) as a table of linear floats, three per colour: what three.js takes
function table(colours) {
  const t = new Float32Array(3 * colours.length);
  colours.forEach((rgb, k) => { for (let c = 0; c < 3; c += 1) t[3 * k + c] = SRGB_TO_LINEAR[rgb[c]]; });
  return t;
}
const STEPS = 255; // a ramp's colours: STEPS + 1 of them, from its stops
const rampTable = (stops) => table(Array.from({ length: STEPS + 1 }, (_, k) => ramp(stops, k / STEPS)));
const TABLES = {
  intensity: rampTable(GREYS),
  time: rampTable(VIRIDIS),
  scan: table(SCAN_COLOURS),
  // camera k's colour at k; 255 (none) grey
  camera: table(Array.from({ length: 256 }, (_, k) => (k === 255 ? GREY : CAMERA_COLOURS[k % CAMERA_COLOURS.length]))),
  coloured: table([NOT_COLOURED, COLOURED]),
};

// the layer's statistics the mode needs, computed once per mode switch or new object
function statistics(layer, mode) {
  if (mode === 'intensity') return range(layer, 'intensity', 0.02, 0.98);
  if (mode === 'time') return range(layer, 'time');
  if (mode === 'camera') {  // the names of the cameras its points name (up to the last one)
    const points = pointsOf(layer.root).map((o) => o.geometry.userData.points);
    const named = points.find((p) => p.cameras.length)?.cameras ?? [];
    const used = points.filter((p) => p.attributes.camera)
      .map((p) => p.attributes.camera.reduce((m, c) => (c === 255 ? m : Math.max(m, c)), -1));
    const last = Math.max(named.length - 1, ...used);
    return Array.from({ length: last + 1 }, (_, k) => named[k] ?? `camera ${k}`);
  }
  return null;
}

// the linear colours of each point of one Points object in `mode` into `out` (3 per point)
function colours(points, mode, stats, out) {
  const n = points.count;
  const a = points.attributes;
  const fill = (rgb) => { const [r, g, b] = table([rgb]); for (let i = 0; i < 3 * n; i += 3) { out[i] = r; out[i + 1] = g; out[i + 2] = b; } };
  // each point's entry of a table, from its index in it
  const pick = (t, index) => {
    for (let i = 0; i < n; i += 1) {
      const k = 3 * index(i);
      out[3 * i] = t[k]; out[3 * i + 1] = t[k + 1]; out[3 * i + 2] = t[k + 2];
    }
  };
  // a value's step on a ramp from lo to hi: 0 below (and NaN), STEPS above
  const step = (lo, hi, fallback) => {
    if (!(hi > lo)) return () => fallback;
    const scale = STEPS / (hi - lo);
    return (v) => { const x = (v - lo) * scale + 0.5; return x > 0 ? (x < STEPS ? x | 0 : STEPS) : 0; };
  };
  if (mode === 'rgb') {
    if (!a.rgb) fill(NO_RGB);
    else for (let i = 0; i < 3 * n; i += 1) out[i] = SRGB_TO_LINEAR[a.rgb[i]];
  } else if (!(MODES.find((m) => m.id === mode).needs in a)) {
    fill(GREY);
  } else if (mode === 'intensity') {
    const at = step(stats[0], stats[1], STEPS);
    pick(TABLES.intensity, (i) => at(a.intensity[i]));
  } else if (mode === 'time') {
    const at = step(stats[0] - points.time0, stats[1] - points.time0, 0);
    pick(TABLES.time, (i) => at(a.time[i]));
  } else if (mode === 'scan') {
    pick(TABLES.scan, (i) => a.scan[i] % SCAN_COLOURS.length);
  } else if (mode === 'camera') {
    pick(TABLES.camera, (i) => a.camera[i]);
  } else if (mode === 'coloured') {
    pick(TABLES.coloured, (i) => (a.coloured[i] ? 1 : 0));
  }
}

function recolour(object, mode, stats) {
  const { geometry } = object;
  const n = geometry.userData.points.count;
  let colour = geometry.getAttribute('color');
  if (!colour || colour.array.length !== 3 * n) {
    colour = new THREE.BufferAttribute(new Float32Array(3 * n), 3);
    geometry.setAttribute('color', colour);
  }
  colours(geometry.userData.points, mode, stats, colour.array);
  colour.needsUpdate = true;
  if (!object.material.vertexColors) {
    object.material.vertexColors = true;
    object.material.color.set(0xffffff);
    object.material.needsUpdate = true;
  }
}

function layerOf(object) {
  for (let o = object; o; o = o.parent) {
    const layer = state.layers.find((l) => l.root === o);
    if (layer) return layer;
  }
  return null;
}

// colour one Points object of a layer (one added to a layer's root after the mode was
// chosen, e.g. a finer level of detail) in the mode shown; the layer's ramps are taken
// again over all its points, so its other objects are recoloured with it. The caller
// renders (once for all the objects it adds); attributes the mode needs and the object
// lacks are fetched, drawn grey until then (the returned Promise resolves once they are
// drawn in the mode's colours, or failed, said in the legend).
export async function applyColourMode(object) {
  const layer = layerOf(object);
  if (!layer) return;
  enableModes();
  const mode = state.mode;
  const colour = () => {
    layer.stats = statistics(layer, mode);
    for (const o of pointsOf(layer.root)) recolour(o, mode, layer.stats);
    legend();
  };
  colour();
  const needs = MODES.find((m) => m.id === mode).needs;
  if (needs !== null && lacking(mode)) {  // drawn grey until its attributes come
    await fetchAttributes([layer], needs);
    if (state.mode === mode) { colour(); state.render(); }
  }
}

function swatch(rgb, text) {
  const item = document.createElement('span');
  item.className = 'swatch';
  const box = document.createElement('i');
  box.style.background = css(rgb);
  item.append(box, text);
  return item;
}

function bar(stops, from, to) {
  const row = document.createElement('div');
  row.className = 'ramp';
  const gradient = document.createElement('i');
  gradient.style.background = `linear-gradient(to right, ${stops.map(css).join(', ')})`;
  row.append(from, gradient, to);
  return row;
}

const seconds = (s) => `${s.toFixed(s < 10 ? 2 : 1)} s`;

// the legend of the mode shown: its colours, each layer's range, the layers without it
function legend() {
  const box = state.legend;
  box.replaceChildren();
  const mode = MODES.find((m) => m.id === state.mode);
  const line = (...parts) => { const d = document.createElement('div'); d.append(...parts); box.append(d); };
  for (const layer of state.layers) {
    if (!pointsOf(layer.root).length) continue; // a drive with no cloud (yet, or its own layer)
    const { stats } = layer;
    if (layer.failed && mode.needs && has(layer, mode.needs)) {
      const said = swatch(GREY, layer.failed);
      said.classList.add('error');
      line(said);
    } else if (mode.needs && !has(layer, mode.needs)) {
      line(swatch(GREY, `${layer.name}: no ${mode.label}`));
    } else if (stats === null && (mode.id === 'intensity' || mode.id === 'time')) {
      line(swatch(GREY, `${layer.name}: ${LOADING}`));  // drawn grey until they come
    } else if (mode.id === 'rgb' && !has(layer, 'rgb')) {
      line(swatch(NO_RGB, `${layer.name}: no colours`));
    } else if (mode.id === 'intensity') {
      line(`${layer.name} (2nd to 98th percentile)`);
      box.append(bar(GREYS, `${+stats[0].toPrecision(4)}`, `${+stats[1].toPrecision(4)}`));
    } else if (mode.id === 'time') {
      // a UTC time (not a GPS time of week: a foreign LAS's) as a date
      const start = stats[0] > 1e8 ? ` from ${new Date(stats[0] * 1000).toISOString().replace('T', ' ').slice(0, 19)} UTC` : '';
      line(`${layer.name}${start}`);
      box.append(bar(VIRIDIS, '0 s', seconds(stats[1] - stats[0])));
    } else if (mode.id === 'camera') {
      line(`${layer.name}:`);
      line(...stats.map((name, k) => swatch(CAMERA_COLOURS[k % CAMERA_COLOURS.length], name)),
        swatch(GREY, 'none'));
    }
  }
  if (mode.id === 'scan') {
    line(...SCAN_COLOURS.map((rgb, k) => swatch(rgb, `${k}`)));
    line(`scan index mod ${SCAN_COLOURS.length}`);
  } else if (mode.id === 'coloured') {
    line(swatch(COLOURED, 'coloured'), swatch(NOT_COLOURED, 'not coloured'));
  }
}

// the modes some layer's points have enabled (a drive's cloud may come after the start)
function enableModes() {
  const { control, layers } = state;
  if (!control) return;
  for (const option of control.options) {
    const needs = MODES.find((m) => m.id === option.value).needs;
    option.disabled = needs !== null && !layers.some((layer) => has(layer, needs));
  }
  control.disabled = !layers.some((layer) => pointsOf(layer.root).length);
}

function show(mode) {
  state.mode = mode;
  for (const layer of state.layers) {
    layer.stats = statistics(layer, mode);
    for (const object of pointsOf(layer.root)) recolour(object, mode, layer.stats);
  }
  legend();
}

// the select `control` of the modes over `layers` ([{name, root}]: each cloud layer's
// object), the legend drawn into `legendBox`; a mode no layer has is disabled. The layers
// are coloured by their RGB here, drawn by the caller; `render` draws after each change.
// window.acqColourMode is the mode drawn (for the tests and the benchmark).
export function colourModes(control, legendBox, layers, render) {
  Object.assign(state, { layers, legend: legendBox, control, render });
  control.replaceChildren(...MODES.map((m) => new Option(m.label, m.id)));
  enableModes();
  control.value = 'rgb';
  control.addEventListener('change', async () => {
    const mode = control.value;
    if (lacking(mode)) {
      const option = control.selectedOptions[0];
      option.textContent = LOADING;
      control.disabled = true;
      await fetchAttributes(state.layers, MODES.find((m) => m.id === mode).needs);
      option.textContent = MODES.find((m) => m.id === mode).label;
      enableModes();
    }
    show(mode);
    render();
    window.acqColourMode = mode;
  });
  if (layers.length) show('rgb');
  window.acqColourMode = 'rgb';
}
