// The distance tool of acq view: in measure mode two clicks on drawn points or facets place
// two markers joined by a line, and the panel gives their distance in metres and both points
// in their file's CRS (crs.js), or its local frame. The scene's world coordinates are the files' (each layer's offset is
// its object's position, a double; a glb's node matrix is in the scene graph), so a hit's
// world point is the file's point.
import * as THREE from 'three';
import { pointLabel } from './crs.js';

const PICK_PX = 6; // a click picks a cloud's point within this many pixels of it
const DRAG_PX = 4; // a press and release further apart than this is an orbit, not a click
const MARKER = 0xffd400;

// metres per pixel at distance `depth` m along the view of a perspective camera drawn
// `height` pixels high
export function metresPerPixel(camera, depth, height) {
  return (2 * depth * Math.tan(THREE.MathUtils.degToRad(camera.fov) / 2)) / height;
}

function shown(object) {
  for (let o = object; o; o = o.parent) if (!o.visible) return false;
  return true;
}

// the drawn point or facet under the pixel (x, y) of the canvas (CSS pixels from its
// top-left corner): a facet exactly where the ray meets it, a cloud's own point within
// PICK_PX pixels of the ray at its depth; the nearest to the eye: {point (world), object
// (the Points or Mesh hit), index (a cloud's point index in its geometry, else null)}, or null
export function pick(x, y, canvas, camera, objects) {
  const rect = canvas.getBoundingClientRect();
  const ndc = new THREE.Vector2((x / rect.width) * 2 - 1, 1 - (y / rect.height) * 2);
  const raycaster = new THREE.Raycaster();
  raycaster.setFromCamera(ndc, camera);
  const forward = camera.getWorldDirection(new THREE.Vector3());
  const reach = new THREE.Box3();
  for (const o of objects) if (shown(o)) reach.expandByObject(o);
  if (reach.isEmpty()) return null;
  // the widest threshold any point may need (at the far side of all that is drawn); each
  // hit is then held to PICK_PX pixels at its own depth
  const far = reach.getBoundingSphere(new THREE.Sphere());
  const farthest = camera.position.distanceTo(far.center) + far.radius;
  raycaster.params.Points.threshold = PICK_PX * metresPerPixel(camera, farthest, rect.height);
  let best = null;
  for (const hit of raycaster.intersectObjects(objects.filter(shown), true)) {
    if (!shown(hit.object)) continue;
    let point = hit.point;
    if (hit.object.isPoints) {
      point = new THREE.Vector3().fromBufferAttribute(hit.object.geometry.attributes.position, hit.index);
      point.applyMatrix4(hit.object.matrixWorld);
      const depth = point.clone().sub(camera.position).dot(forward);
      if (hit.distanceToRay > PICK_PX * metresPerPixel(camera, depth, rect.height)) continue;
    } else if (!hit.object.isMesh) {
      continue;
    }
    if (best === null || hit.distance < best.distance) {
      best = { point, distance: hit.distance, object: hit.object, index: hit.object.isPoints ? hit.index : null };
    }
  }
  return best;
}

// the pixel (CSS, from the page's top-left corner) where the world point xyz is drawn
export function project(xyz, canvas, camera) {
  const rect = canvas.getBoundingClientRect();
  const v = new THREE.Vector3(...xyz).project(camera);
  return [rect.left + ((v.x + 1) / 2) * rect.width, rect.top + ((1 - v.y) / 2) * rect.height];
}

// the CRS of the layer (of /api/layers, in the order of `objects`) that drew `object`
function crsOf(object, objects, layers) {
  for (let o = object; o; o = o.parent) {
    const k = objects.indexOf(o);
    if (k >= 0) return layers[k].crs;
  }
  return null;
}

// the measure toggle, its readout and its markers: `scene` gets the markers, `objects` are
// the layers it picks from (`layers` their entries of /api/layers), render() redraws;
// window.acqMeasured holds the measurement ({points: [[x, y, z], ...], labels: each point
// in its layer's CRS, distance: m or null}, null when cleared)
export function measureTool(scene, camera, canvas, objects, layers, render) {
  const toggle = document.getElementById('measure');
  const readout = document.getElementById('measured');
  const markers = new THREE.Group();
  scene.add(markers);
  let points = [];
  let labels = [];
  window.acqMeasured = null;

  function draw() {
    for (const child of [...markers.children]) {
      child.geometry.dispose();
      child.material.dispose();
      markers.remove(child);
    }
    if (points.length > 0) {
      // float32 offsets from the first point on the GPU; that point (a double) is the position
      markers.position.copy(points[0]);
      const offsets = points.map((p) => p.clone().sub(points[0]));
      const geometry = new THREE.BufferGeometry().setFromPoints(offsets);
      const dots = new THREE.Points(geometry, new THREE.PointsMaterial({
        color: MARKER, size: 10, sizeAttenuation: false, depthTest: false,
      }));
      dots.renderOrder = 1; // after the layers, over them (no depth test)
      markers.add(dots);
      if (points.length === 2) {
        const line = new THREE.Line(geometry.clone(), new THREE.LineBasicMaterial({
          color: MARKER, depthTest: false,
        }));
        line.renderOrder = 1;
        markers.add(line);
      }
    }
    const distance = points.length === 2 ? points[0].distanceTo(points[1]) : null;
    window.acqMeasured = points.length === 0 ? null
      : { points: points.map((p) => p.toArray()), labels, distance };
    const lines = [];
    if (distance !== null) lines.push(`distance ${distance.toFixed(3)} m`);
    labels.forEach((label, k) => lines.push(`${'AB'[k]}: ${label}`));
    if (toggle.checked && points.length < 2) lines.push(`click point ${'AB'[points.length]}`);
    readout.textContent = lines.join('\n');
    render();
  }

  function clear() {
    points = [];
    labels = [];
    draw();
  }

  // on the release (its place keeps the pixel's fractions, a click event's does not)
  let down = null;
  canvas.addEventListener('pointerdown', (e) => { down = e.button === 0 ? [e.clientX, e.clientY] : null; });
  canvas.addEventListener('pointerup', (e) => {
    if (!toggle.checked || down === null || e.button !== 0) return;
    if (Math.hypot(e.clientX - down[0], e.clientY - down[1]) > DRAG_PX) return;
    const rect = canvas.getBoundingClientRect();
    const hit = pick(e.clientX - rect.left, e.clientY - rect.top, canvas, camera, objects);
    if (hit === null) return; // the background: nothing to measure
    const label = pointLabel(hit.point.toArray(), crsOf(hit.object, objects, layers));
    points = points.length === 2 ? [hit.point] : [...points, hit.point];
    labels = labels.length === 2 ? [label] : [...labels, label];
    draw();
  });
  toggle.addEventListener('change', clear);
  window.addEventListener('keydown', (e) => {
    if (e.key === 'Escape') clear();
  });
  window.acqProject = (xyz) => project(xyz, canvas, camera);
}
