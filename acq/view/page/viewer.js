// acq view: every layer the server lists (/api/layers), drawn with three.js in acq's world
// frame (z up, metres): clouds as points in their own colours, meshes unlit in theirs.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { PLYLoader } from 'three/addons/loaders/PLYLoader.js';
import { levelOfDetail, lodBudget } from './lod.js';
import { measureTool } from './measure.js';
import { parsePoints, pointsGeometry } from './points.js';

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

// a PLY as points (a cloud) or triangles (a mesh), coloured by its vertices where it has colours
function plyObject(geometry, kind, pointSize) {
  const origin = toFloat32(geometry);
  const coloured = geometry.hasAttribute('color');
  let object;
  if (kind === 'mesh') {
    const material = new THREE.MeshBasicMaterial({
      vertexColors: coloured, color: coloured ? 0xffffff : 0xb0b0b0, side: THREE.DoubleSide,
    });
    object = new THREE.Mesh(geometry, material);
  } else {
    object = pointsObject(geometry, coloured, pointSize);
  }
  object.position.copy(origin);
  return object;
}

// a cloud: each point a square of pointSize pixels in its colour (grey without colours)
function pointsObject(geometry, coloured, pointSize) {
  const material = new THREE.PointsMaterial({
    size: pointSize, sizeAttenuation: false, vertexColors: coloured,
    color: coloured ? 0xffffff : 0xd0d0d0,
  });
  return new THREE.Points(geometry, material);
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

// a LAS/LAZ/COPC cloud as the server packs it (points.js)
async function packedPointsObject(url, pointSize) {
  const response = await fetch(url);
  if (!response.ok) throw new Error(`HTTP ${response.status}`);
  const points = parsePoints(await response.arrayBuffer());
  const object = pointsObject(pointsGeometry(points), points.colours !== null, pointSize);
  object.position.copy(points.origin);
  return object;
}

async function loadLayer(layer, pointSize) {
  try {
    if (layer.url.toLowerCase().endsWith('.glb')) {
      return gltfObject(await new GLTFLoader().loadAsync(layer.url));
    }
    if (layer.url.endsWith('/points.bin')) return await packedPointsObject(layer.url, pointSize);
    return plyObject(await new PLYLoader().loadAsync(layer.url), layer.kind, pointSize);
  } catch (error) {
    throw new Error(`${layer.name}: ${error?.message ?? error}`);
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
  const unit = layer.kind === 'cloud' ? 'points' : 'vertices';
  const shown = layer.shown < layer.count ? `${layer.shown.toLocaleString('en')} of ` : '';
  count.textContent = ` ${layer.kind}, ${shown}${layer.count.toLocaleString('en')} ${unit}`;
  label.append(box, ` ${layer.name}`, count);
  document.getElementById('layers').append(label);
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
  const renderer = new THREE.WebGLRenderer({ antialias: true });
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
  const objects = await Promise.all(layers.map((layer) => loadLayer(layer, pointSize)));
  objects.forEach((object, k) => {
    object.name = layers[k].name;
    scene.add(object);
    layerToggle(layers[k], object, render);
  });
  sizeInput.addEventListener('input', () => {
    sizeOutput.textContent = `${sizeInput.value} px`;
    for (const object of objects) if (object.isPoints) object.material.size = Number(sizeInput.value);
    render();
  });

  const box = new THREE.Box3().setFromObject(scene);
  if (box.isEmpty()) throw new Error('the layers hold nothing to draw');
  frame(box, camera, controls);
  measureTool(scene, camera, renderer.domElement, objects, render);
  render();
  message.textContent = '';
  // the frame rendered above is on the screen at the next animation frame; finer points after it
  requestAnimationFrame(() => {
    window.acqReady = true;
    levelOfDetail({
      layers: layers.map((layer, k) => ({ layer, object: objects[k] })).filter(({ layer }) => layer.lod),
      camera, controls, renderer, render, budget, say: (text) => { message.textContent = text; },
    }).catch((error) => window.acqFail(error?.message ?? String(error)));
  });
}

main().catch((error) => window.acqFail(error?.message ?? String(error)));
