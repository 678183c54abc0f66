// acq view: every layer the server lists (/api/layers), drawn with three.js in acq's world
// frame (z up, metres): clouds as points in their own colours (or a colour mode's), meshes
// unlit in theirs.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { PLYLoader } from 'three/addons/loaders/PLYLoader.js';
import { georeferenced, showCrs } from './crs.js';
import { driveObject } from './drive.js';
import { frameTool } from './frame.js';
import { walkTool } from './walk.js';
import { orbitHooks } from './orbit.js';
import { overlays } from './overlays.js';
import { applyColourMode, colourModes } from './colour_modes.js';
import { levelOfDetail, lodBudget } from './lod.js';
import { measureTool } from './measure.js';
import { parsePoints, pointsObject } from './points.js';

const message = document.getElementById('message');
const sizeInput = document.getElementById('point-size');
const sizeOutput = document.getElementById('point-size-value');

async function listLayers() {
  const response = await fetch('/api/layers');
  if (!response.ok) throw new Error(`/api/layers: HTTP ${response.status}`);
  return response.json();
}

// WebGL takes no doubles, and PLYLoader keeps a PLY's (acq writes x y z as double: a CRS's
// coordinates keep their millimetres): positions become float32 offsets from the first
// vertex, which the object's position (a double, on the CPU) adds back; the origin
function toFloat32(geometry) {
  const origin = new THREE.Vector3();
  for (const [name, attribute] of Object.entries(geometry.attributes)) {
    if (!(attribute.array instanceof Float64Array)) continue;
    const a = attribute.array;
    const out = new Float32Array(a.length);
    if (name === 'position' && a.length >= 3) {
      origin.set(a[0], a[1], a[2]);
      for (let i = 0; i < a.length; i += 3) {
        out[i] = a[i] - origin.x;
        out[i + 1] = a[i + 1] - origin.y;
        out[i + 2] = a[i + 2] - origin.z;
      }
    } else {
      out.set(a);
    }
    geometry.setAttribute(name, new THREE.BufferAttribute(out, attribute.itemSize, attribute.normalized));
  }
  // the loader's bounds were of the doubles: culled and framed by them, a cloud far from
  // the origin (a CRS's coordinates) was never drawn
  geometry.computeBoundingBox();
  geometry.computeBoundingSphere();
  return origin;
}

// a PLY mesh's triangles, coloured by its vertices where it has colours
function plyMesh(geometry) {
  const origin = toFloat32(geometry);
  const coloured = geometry.hasAttribute('color');
  const material = new THREE.MeshBasicMaterial({
    vertexColors: coloured, color: coloured ? 0xffffff : 0xb0b0b0, side: THREE.DoubleSide,
  });
  const object = new THREE.Mesh(geometry, material);
  object.position.copy(origin);
  return object;
}

// a glTF scene in acq's frame (glTF is +y up: turned back to z up), its facets unlit so that
// they show the colours of their camera frames, not a lighting of them
function gltfObject(gltf) {
  const root = new THREE.Group();
  root.rotation.x = Math.PI / 2;
  root.add(gltf.scene);
  gltf.scene.traverse((node) => {
    if (!node.isMesh) return;
    const old = node.material;
    node.material = new THREE.MeshBasicMaterial({
      map: old.map ?? null, vertexColors: old.vertexColors, side: THREE.DoubleSide,
    });
    old.dispose();
  });
  return root;
}

// the names of the clouds the server is still decoding, said in the page while it waits
const decoding = new Set();
function sayDecoding() {
  if (decoding.size) message.textContent = `decoding ${[...decoding].join(', ')}…`;
  else if (message.textContent.startsWith('decoding')) message.textContent = 'loading…';
}

// a cloud's payload (points.js) once the server has decoded it: it answers 202 until then
async function fetchPoints(layer) {
  for (;;) {
    const response = await fetch(layer.url);
    if (response.status === 202) {
      decoding.add(layer.name);
      sayDecoding();
      const wait = Number(response.headers.get('Retry-After') ?? 1);
      await new Promise((resolve) => { setTimeout(resolve, 1000 * wait); });
      continue;
    }
    decoding.delete(layer.name);
    sayDecoding();
    // the server's reason names the file
    if (response.status === 422) throw new Error(await response.text());
    if (!response.ok) throw new Error(`HTTP ${response.status}`);
    return response.arrayBuffer();
  }
}

async function loadLayer(layer, k, pointSize, render) {
  try {
    if (layer.kind === 'drive') {
      const loadCloud = async (url, attributesUrl) => pointsObject(
        parsePoints(await fetchPoints({ name: layer.name, url })), Number(sizeInput.value), attributesUrl);
      return await driveObject(layer, k, { render, loadCloud, onCloud: applyColourMode });
    }
    if (layer.url.toLowerCase().endsWith('.glb')) {
      return gltfObject(await new GLTFLoader().loadAsync(layer.url));
    }
    if (layer.kind === 'cloud') {
      return pointsObject(parsePoints(await fetchPoints(layer)), pointSize, layer.attributes);
    }
    return plyMesh(await new PLYLoader().loadAsync(layer.url));
  } catch (error) {
    const text = error?.message ?? String(error);
    throw new Error(text.includes(layer.name) ? text : `${layer.name}: ${text}`);
  }
}

function layerToggle(layer, object, render) {
  const label = document.createElement('label');
  const box = document.createElement('input');
  box.type = 'checkbox';
  box.checked = true;
  box.addEventListener('change', () => { object.visible = box.checked; render(); });
  const count = document.createElement('span');
  count.className = 'count';
  const unit = { cloud: 'points', mesh: 'vertices', drive: layer.count === 1 ? 'log file' : 'log files' }[layer.kind];
  const shown = layer.shown < layer.count ? `${layer.shown.toLocaleString('en')} of ` : '';
  count.textContent = ` ${layer.kind}, ${shown}${layer.count.toLocaleString('en')} ${unit}`;
  label.append(box, ` ${layer.name}`, count);
  document.getElementById('layers').append(label);
}

// whether WebGL is drawn on the CPU (SwiftShader, llvmpipe: no GPU), where multisampling
// costs more than half the frames (2 M points: 0.7 fps with it, 1.9 without); a GPU's is
// nearly free, and smooths the meshes' edges
function softwareRenderer() {
  const gl = document.createElement('canvas').getContext('webgl2');
  const info = gl?.getExtension('WEBGL_debug_renderer_info');
  const name = info ? String(gl.getParameter(info.UNMASKED_RENDERER_WEBGL)) : '';
  gl?.getExtension('WEBGL_lose_context')?.loseContext();
  return /swiftshader|llvmpipe|softpipe|software/i.test(name);
}

// the camera looking at the whole of box from above its south-east, the orbit about its centre
function frame(box, camera, controls) {
  const center = box.getCenter(new THREE.Vector3());
  const radius = Math.max(box.getSize(new THREE.Vector3()).length() / 2, 1e-3);
  const distance = (radius / Math.sin(THREE.MathUtils.degToRad(camera.fov) / 2)) * 1.05;
  const direction = new THREE.Vector3(1, -1, 0.8).normalize();
  camera.position.copy(center).addScaledVector(direction, distance);
  camera.near = Math.max(distance - radius, radius) / 1000;
  camera.far = (distance + radius) * 10;
  camera.updateProjectionMatrix();
  controls.target.copy(center);
  controls.update();
}

async function main() {
  const budget = lodBudget(window.location.search);
  const layers = await listLayers();
  message.textContent = `loading ${layers.length} layer${layers.length === 1 ? '' : 's'}…`;
  window.acqAntialias = !softwareRenderer();
  const renderer = new THREE.WebGLRenderer({ antialias: window.acqAntialias });
  renderer.setPixelRatio(window.devicePixelRatio);
  renderer.setSize(window.innerWidth, window.innerHeight);
  document.getElementById('view').append(renderer.domElement);

  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0x202124);
  const camera = new THREE.PerspectiveCamera(50, window.innerWidth / window.innerHeight);
  camera.up.set(0, 0, 1);
  const controls = new OrbitControls(camera, renderer.domElement);
  const render = () => renderer.render(scene, camera);
  controls.addEventListener('change', render);
  window.addEventListener('resize', () => {
    camera.aspect = window.innerWidth / window.innerHeight;
    camera.updateProjectionMatrix();
    renderer.setSize(window.innerWidth, window.innerHeight);
    render();
  });

  const pointSize = Number(sizeInput.value);
  // a drive may have nothing to draw until the server has coloured its cloud: the view is
  // then framed on its origin, and on the cloud when it comes
  let framedOnNothing = false;
  const drawn = () => {
    if (framedOnNothing) {
      framedOnNothing = false;
      frame(new THREE.Box3().setFromObject(scene), camera, controls);
    }
    render();
  };
  const objects = await Promise.all(layers.map((layer, k) => loadLayer(layer, k, pointSize, drawn)));
  objects.forEach((object, k) => {
    object.name = layers[k].name;
    if (layers[k].log !== null && layers[k].log !== undefined) object.userData.frameLayer = k;
    scene.add(object);
    layerToggle(layers[k], object, render);
  });
  sizeInput.addEventListener('input', () => {
    sizeOutput.textContent = `${sizeInput.value} px`;
    for (const object of objects) object.traverse((o) => { if (o.isPoints) o.material.size = Number(sizeInput.value); });
    render();
  });

  const clouds = objects.map((root, k) => ({ name: layers[k].name, root }))
    .filter((_, k) => layers[k].kind === 'cloud' || layers[k].kind === 'drive');
  colourModes(document.getElementById('colour-mode'), document.getElementById('legend'), clouds, render);

  const box = new THREE.Box3().setFromObject(scene);
  if (box.isEmpty()) {
    if (!layers.some((layer) => layer.kind === 'drive')) throw new Error('the layers hold nothing to draw');
    box.setFromCenterAndSize(new THREE.Vector3(), new THREE.Vector3(20, 20, 20));
    framedOnNothing = true;
  }
  frame(box, camera, controls);
  // the drive's tools only where there is one: a trajectory to walk, frames to show
  const drives = layers.some((layer) => layer.kind === 'drive');
  document.getElementById('walk').closest('.control').hidden = !drives;
  document.getElementById('show-frame').closest('.control').hidden =
    !layers.some((layer) => layer.kind === 'drive' || layer.log != null);
  frameTool(camera, renderer.domElement, objects);
  const paths = () => objects.filter((o) => o.visible && o.userData.path).map((o) => o.userData.path);
  walkTool(camera, controls, paths, render);
  measureTool(scene, camera, renderer.domElement, objects, layers, render);
  showCrs(layers, document.getElementById('crs'));
  if (georeferenced(layers)) overlays(camera, controls, renderer.domElement);
  orbitHooks(camera, controls);
  window.acqScene = scene; // each layer's object by its name, for the tests and the console
  render();
  message.textContent = '';
  // the frame rendered above is on the screen at the next animation frame; finer points after it
  requestAnimationFrame(() => {
    window.acqReady = true;
    levelOfDetail({
      layers: layers.map((layer, k) => ({ layer, object: objects[k] })).filter(({ layer }) => layer.lod),
      camera, controls, renderer, render, budget, say: (text) => { message.textContent = text; },
      onChunk: applyColourMode,
    }).catch((error) => window.acqFail(error?.message ?? String(error)));
  });
}

main().catch((error) => window.acqFail(error?.message ?? String(error)));
