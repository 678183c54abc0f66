// Level of detail: a cloud the server subsampled (its layer has `lod`, the URL of its chunks'
// index: acq/view/lod.py) stays drawn by its subset, and its chunks (runs of its rows, or a
// COPC file's octree nodes, each in a box) are loaded at full density as the view closes in
// on them: once the view has been still for SETTLE_MS, the chunks whose box is in the view
// and spans at least MIN_PIXELS on the screen are fetched, the largest on the screen (the
// closest) first, a few at a time, while the points drawn stay within the budget; over it,
// the loaded chunks that matter least (out of view or smallest on the screen; the finest,
// then the farthest, first) are dropped for those that matter more.
import * as THREE from 'three';
import { parsePoints, pointsGeometry } from './points.js';

export const DEFAULT_BUDGET = 6_000_000;  // points: a laptop's browser slows around 5-10 M
const SETTLE_MS = 150;  // the view still this long after a move before chunks are chosen
const IN_FLIGHT = 3;  // chunk requests at a time
const MIN_PIXELS = 150;  // a chunk is worth its points once its box spans this on the screen

// the budget of points drawn by the subsampled layers (subsets and chunks): the page URL's
// `budget` (`?budget=3000000`), DEFAULT_BUDGET without one; Error naming a bad one
export function lodBudget(search) {
  const text = new URLSearchParams(search).get('budget');
  if (text === null) return DEFAULT_BUDGET;
  if (!/^[0-9]+$/.test(text)) {
    throw new Error(`the page's URL: budget=${text} is not a whole number of points`);
  }
  return Number(text);
}

// Starts the level of detail of `layers` ([{layer, object}]: a listed layer with `lod`, its
// subset's Points); `onChunk(object, layerObject)`, when given, is called on each chunk's
// Points once added to its layer's object (sharing its material, so the point-size slider
// holds). window.acqLod gives the figures (chunks and points loaded, requests, bytes, ...),
// the loaded chunks ("k/c") and their point sizes, and `look(position, target)`, to set the
// view from a test.
export async function levelOfDetail({ layers, camera, controls, renderer, render, budget, say, onChunk = null }) {
  const all = [];
  let timer = null;
  let reserved = 0;  // points of the chunks loading
  const stats = {
    chunks: 0, points: 0, requests: 0, bytes: 0, failed: 0, inFlight: 0, updates: 0, idle: false,
    get loaded() { return all.filter((c) => c.state === 'loaded').map((c) => c.key); },
    get pointSizes() { return all.filter((c) => c.state === 'loaded').map((c) => c.points.material.size); },
    look(position, target) {
      camera.position.set(...position);
      controls.target.set(...target);
      controls.update();
      schedule(SETTLE_MS);
    },
  };
  window.acqLod = stats;

  for (const { layer, object } of layers) {
    stats.points += layer.shown;
    const response = await fetch(layer.lod);
    if (!response.ok) {
      say(`${layer.name}: no finer points (${layer.lod}: HTTP ${response.status})`);
      continue;
    }
    const base = layer.lod.slice(0, layer.lod.lastIndexOf('/'));
    (await response.json()).chunks.forEach((chunk, c) => all.push({
      object, c, key: `${base.split('/').pop()}/${c}`, url: `${base}/chunk/${c}.bin`,
      name: layer.name, count: chunk.count, level: chunk.level,
      box: new THREE.Box3(new THREE.Vector3(...chunk.min), new THREE.Vector3(...chunk.max)),
      state: 'none', points: null, priority: 0, distance: 0,
    }));
  }

  // one frame drawn for the chunks that arrive before the next one (each frame of millions
  // of points is costly in a software renderer)
  let drawing = false;
  function redraw() {
    if (drawing) return;
    drawing = true;
    requestAnimationFrame(() => { drawing = false; render(); });
  }

  function schedule(ms) {
    clearTimeout(timer);
    stats.idle = false;
    timer = setTimeout(update, ms);
  }

  const frustum = new THREE.Frustum();
  const matrix = new THREE.Matrix4();
  function update() {
    timer = null;
    stats.updates += 1;
    camera.updateMatrixWorld();
    frustum.setFromProjectionMatrix(matrix.multiplyMatrices(camera.projectionMatrix, camera.matrixWorldInverse));
    // pixels a metre spans at a metre from the camera
    const scale = renderer.domElement.clientHeight / 2 / Math.tan(THREE.MathUtils.degToRad(camera.fov) / 2);
    for (const chunk of all) {
      chunk.distance = chunk.box.distanceToPoint(camera.position);
      const shown = chunk.object.visible && frustum.intersectsBox(chunk.box);
      const size = chunk.box.max.distanceTo(chunk.box.min);
      chunk.priority = shown ? (size * scale) / Math.max(chunk.distance, camera.near) : 0;
    }
    const wanted = all.filter((c) => c.priority >= MIN_PIXELS && c.state === 'none')
      .sort((a, b) => b.priority - a.priority || a.level - b.level);
    for (const chunk of wanted) {
      if (stats.inFlight >= IN_FLIGHT || !makeRoom(chunk)) break;
      load(chunk);
    }
    stats.idle = stats.inFlight === 0 && timer === null;
  }

  // drops loaded chunks that matter less than `chunk` until it fits in the budget; whether it does
  function makeRoom(chunk) {
    const loaded = all.filter((c) => c.state === 'loaded' && c.priority < chunk.priority)
      .sort((a, b) => a.priority - b.priority || b.level - a.level || b.distance - a.distance);
    while (stats.points + reserved + chunk.count > budget) {
      const dropped = loaded.shift();
      if (dropped === undefined) return false;
      dropped.object.remove(dropped.points);
      dropped.points.geometry.dispose();  // not the material: the layer's own
      dropped.points = null;
      dropped.state = 'none';
      stats.chunks -= 1;
      stats.points -= dropped.count;
    }
    return true;
  }

  async function load(chunk) {
    chunk.state = 'loading';
    stats.inFlight += 1;
    stats.requests += 1;
    reserved += chunk.count;
    try {
      const response = await fetch(chunk.url);
      if (!response.ok) throw new Error(`HTTP ${response.status}`);
      const buffer = await response.arrayBuffer();
      stats.bytes += buffer.byteLength;
      const points = parsePoints(buffer);
      if (points.count !== chunk.count) throw new Error(`${points.count} points, its index says ${chunk.count}`);
      chunk.points = new THREE.Points(pointsGeometry(points), chunk.object.material);
      // a child of the layer's object: hidden with it, picked by the distance tool with it
      chunk.points.position.set(...points.origin).sub(chunk.object.position);
      chunk.points.name = `${chunk.object.name} chunk ${chunk.c}`;
      chunk.object.add(chunk.points);
      chunk.state = 'loaded';
      stats.chunks += 1;
      stats.points += chunk.count;
      onChunk?.(chunk.points, chunk.object);
      redraw();
    } catch (error) {
      chunk.state = 'failed';  // not asked again
      stats.failed += 1;
      say(`${chunk.name}: its finer points ${chunk.url} could not be loaded (${error?.message ?? error})`);
    } finally {
      stats.inFlight -= 1;
      reserved -= chunk.count;
      schedule(0);  // the next chunks wanted, if any
    }
  }

  controls.addEventListener('change', () => schedule(SETTLE_MS));
  window.addEventListener('resize', () => schedule(SETTLE_MS));
  update();
}
