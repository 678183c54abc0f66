// A cloud's points as the server packs them (acq/view/points_payload.py), parsed into typed
// arrays over the received buffer (no copy): positions as float32 offsets from an origin
// (doubles), and the attributes the file has; and drawn as a three.js Points object.
import * as THREE from 'three';

const MAGIC = 'ACQPTS2\0';
export const HEADER_BYTES = 80;
// the arrays after the positions, in their order: name, flag bit, typed array, values per point
const COLUMNS = [
  ['time', 2, Float32Array, 1],
  ['scan', 4, Uint32Array, 1],
  ['intensity', 8, Float32Array, 1],
  ['rgb', 1, Uint8Array, 3],
  ['coloured', 16, Uint8Array, 1],
  ['camera', 32, Uint8Array, 1],
];

// {count, rows, start, stop, origin: [x, y z], time0, cameras: [names], positions:
// Float32Array (3 per point), attributes: {time?, scan?, intensity?, rgb?, coloured?,
// camera?}}; an Error saying what is wrong with a buffer that is not such a payload.
// The page's point j is the file's row start + floor(j * (stop - start) / count).
export function parsePoints(buffer) {
  if (!(buffer instanceof ArrayBuffer)) throw new Error('not an ArrayBuffer');
  const bytes = buffer.byteLength;
  const magic = new TextDecoder().decode(new Uint8Array(buffer, 0, Math.min(8, bytes)));
  if (bytes < HEADER_BYTES || magic !== MAGIC) throw new Error('not acq view\'s points');
  const head = new DataView(buffer);
  const u64 = (at) => Number(head.getBigUint64(at, true));
  const count = u64(8);
  const [rows, start, stop] = [u64(16), u64(24), u64(32)];
  const origin = [40, 48, 56].map((at) => head.getFloat64(at, true));
  const time0 = head.getFloat64(64, true);
  const flags = head.getUint32(72, true);
  const namesBytes = head.getUint32(76, true);
  if (!(start < stop && stop <= rows && count <= stop - start && (count > 0))) {
    throw new Error(`rows [${start}, ${stop}) of ${rows} for ${count} points`);
  }
  const columns = COLUMNS.filter(([, flag]) => flags & flag);
  let at = HEADER_BYTES + Math.ceil(namesBytes / 4) * 4;
  const expected = at + 12 * count
    + columns.reduce((sum, [, , Type, width]) => sum + Type.BYTES_PER_ELEMENT * width * count, 0);
  if (bytes !== expected || (flags & ~63) !== 0) {
    throw new Error(`${bytes} bytes for ${count} points of flags ${flags}; expected ${expected}`);
  }
  const names = new TextDecoder().decode(new Uint8Array(buffer, HEADER_BYTES, namesBytes));
  const cameras = namesBytes ? names.split('\n') : [];
  const positions = new Float32Array(buffer, at, 3 * count);
  at += 12 * count;
  const attributes = {};
  for (const [name, , Type, width] of columns) {
    attributes[name] = new Type(buffer, at, width * count);
    at += Type.BYTES_PER_ELEMENT * width * count;
  }
  return { count, rows, start, stop, origin, time0, cameras, positions, attributes };
}

// the parsed points as a geometry about their origin, the points kept in its userData
// (colour_modes.js colours them from there)
export function pointsGeometry(points) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(points.positions, 3));
  geometry.userData.points = points;
  geometry.computeBoundingBox();
  geometry.computeBoundingSphere();
  return geometry;
}

// the parsed points as a three.js Points object at their origin, each a square of pointSize
// pixels; colour_modes.js gives their colours from the attributes kept in its geometry's
// userData.points (applyColourMode for one added to a layer later)
export function pointsObject(points, pointSize) {
  const material = new THREE.PointsMaterial({ size: pointSize, sizeAttenuation: false });
  const object = new THREE.Points(pointsGeometry(points), material);
  object.position.set(...points.origin);
  return object;
}
