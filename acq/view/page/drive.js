// A drive's layer (acq/view/drive.py, /data/<k>/drive.json): the vehicle's path as a line,
// a frustum per kept camera pose (a pyramid from the camera along its optical axis, +z,
// its base the image's shape, each camera in its colour), and its coloured cloud once
// the server has one (found beside the log, or coloured in the background: polled, its
// progress in the panel). The path's world points (doubles) stay in group.userData.path
// for the walk mode.
import * as THREE from 'three';

const FRUSTUM_M = 0.6; // a frustum's depth along the optical axis
const FRUSTUM_HALF = 0.35; // its base's half height at that depth (the width by the image's aspect)
const PATH_COLOUR = 0xffffff;
const POLL_MS = 500;

// float32 offsets from `origin` of the points `xyz` ([[x, y, z], ...], doubles)
function offsets(xyz, origin) {
  const out = new Float32Array(3 * xyz.length);
  xyz.forEach((p, i) => {
    out[3 * i] = p[0] - origin[0];
    out[3 * i + 1] = p[1] - origin[1];
    out[3 * i + 2] = p[2] - origin[2];
  });
  return out;
}

// one camera's frustums: their edges as lines and their bases as see-through quads, never picked
function frustums(camera, origin) {
  const aspect = camera.size[0] / camera.size[1];
  const corners = [[-1, -1], [1, -1], [1, 1], [-1, 1]].map(
    ([u, v]) => [u * FRUSTUM_HALF * aspect, v * FRUSTUM_HALF, FRUSTUM_M]);
  const edges = [];
  const faces = [];
  camera.p.forEach((p, n) => {
    const R = camera.R[n];
    const world = corners.map(([x, y, z]) => [0, 1, 2].map(
      (r) => p[r] + R[3 * r] * x + R[3 * r + 1] * y + R[3 * r + 2] * z));
    for (let c = 0; c < 4; c++) edges.push(p, world[c], world[c], world[(c + 1) % 4]);
    faces.push(world[0], world[1], world[2], world[0], world[2], world[3]);
  });
  const colour = new THREE.Color(camera.colour);
  const lines = new THREE.LineSegments(
    new THREE.BufferGeometry().setAttribute('position', new THREE.BufferAttribute(offsets(edges, origin), 3)),
    new THREE.LineBasicMaterial({ color: colour }));
  const bases = new THREE.Mesh(
    new THREE.BufferGeometry().setAttribute('position', new THREE.BufferAttribute(offsets(faces, origin), 3)),
    // see-through, so that they mark the poses without hiding the street behind them
    new THREE.MeshBasicMaterial({
      color: colour, side: THREE.DoubleSide, transparent: true, opacity: 0.25, depthWrite: false,
    }));
  const group = new THREE.Group();
  group.name = `frustums ${camera.camera}`;
  group.add(lines, bases);
  for (const o of [lines, bases]) o.raycast = () => {}; // markers, not data: the tools skip them
  return group;
}

function say(status, text, error = false) {
  status.textContent = text;
  status.className = error ? 'drive-status error' : 'drive-status';
}

// the drive of `layer` (its index k) as a group; `ctx`: render(), loadCloud(url, attributesUrl) -> a cloud
// object (Promise), onCloud(object) once it is in the group; the cloud is added to the
// group when it comes, marked for the frame tool
export async function driveObject(layer, k, ctx) {
  const response = await fetch(layer.url);
  if (!response.ok) throw new Error(`HTTP ${response.status}`);
  const data = await response.json();
  const group = new THREE.Group();
  const origin = data.path[0] ?? data.frustums.find((f) => f.p.length)?.p[0] ?? [0, 0, 0];
  group.position.set(...origin);
  group.userData.path = data.path;
  if (data.path.length >= 2) {
    const line = new THREE.Line(
      new THREE.BufferGeometry().setAttribute('position', new THREE.BufferAttribute(offsets(data.path, origin), 3)),
      new THREE.LineBasicMaterial({ color: PATH_COLOUR }));
    line.name = 'trajectory';
    line.raycast = () => {};
    group.add(line);
  }
  for (const camera of data.frustums) group.add(frustums(camera, origin));

  window.acqDriveCloud ??= {}; // layer k -> its cloud's file once drawn (for tests)
  const status = document.createElement('div');
  status.id = `drive-status-${k}`;
  document.getElementById('drives').append(status);
  const notes = data.notes.map((n) => `${layer.name}: ${n}`);
  say(status, notes.join('\n'));

  const cloudInto = async (cloud) => {
    if (cloud.layer !== undefined) return; // the same file is a layer of its own
    const object = await ctx.loadCloud(cloud.url, cloud.attributes);
    object.position.sub(group.position); // the group's child: its origin relative to the group's
    object.userData.frameLayer = k;
    object.name = cloud.file;
    group.add(object);
    ctx.onCloud?.(object);
    window.acqDriveCloud[k] = cloud.file;
    say(status, [...notes, `${layer.name}: cloud ${cloud.file}`].join('\n'));
    ctx.render();
  };
  const poll = async () => {
    const now = await (await fetch(layer.url)).json();
    const cloud = now.cloud;
    if (cloud.status === 'making') {
      say(status, [...notes, `${layer.name}: colouring its cloud… ${Math.round(100 * cloud.progress)} %`].join('\n'));
      setTimeout(() => poll().catch((e) => say(status, String(e), true)), POLL_MS);
    } else if (cloud.status === 'failed' || cloud.status === 'none') {
      say(status, [...notes, `${layer.name}: ${cloud.message}`].join('\n'), cloud.status === 'failed');
    } else {
      await cloudInto(cloud);
    }
  };
  if (data.cloud.status === 'found' || data.cloud.status === 'ready') await cloudInto(data.cloud);
  else poll().catch((e) => say(status, `${layer.name}: ${e?.message ?? e}`, true));
  return group;
}
