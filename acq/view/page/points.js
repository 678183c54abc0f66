// A cloud's points as the server packs them (acq/view/points_payload.py), parsed into typed
// arrays over the received buffer (no copy): positions as float32 offsets from an origin
// (doubles), and the attributes the file has; and drawn as a three.js Points object.
import * as THREE from 'three';

const MAGIC = 'ACQPTS2\0';
export const HEADER_BYTES = 80;
// the attributes after the positions, in their order: name, flag bit, typed array, values per point
const COLUMNS = [
  ['time', 2, Float32Array, 1],
  ['scan', 4, Uint32Array, 1],
  ['intensity', 8, Float32Array, 1],
  ['rgb', 1, Uint8Array, 3],
  ['coloured', 16, Uint8Array, 1],
  ['camera', 32, Uint8Array, 1],
];
// the part flags: positions and sRGB only (the first frame's) / the other attributes only
const POINTS_PART = 64;
const ATTRIBUTES_PART = 128;
const DRAWN = ['rgb']; // the attributes a points part holds

// {count, rows, start, stop, origin: [x, y z], time0, cameras: [names], part: 'whole',
// 'points' or 'attributes', has: [the attributes the file has], positions: Float32Array
// (3 per point; null in an attributes part), attributes: {time?, scan?, intensity?, rgb?,
// coloured?, camera?} (those this buffer holds)}; an Error saying what is wrong with a
// buffer that is not such a payload. The page's point j is the file's row
// start + floor(j * (stop - start) / count).
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
  const part = { 0: 'whole', [POINTS_PART]: 'points', [ATTRIBUTES_PART]: 'attributes' }[flags & (POINTS_PART | ATTRIBUTES_PART)];
  const has = COLUMNS.filter(([, flag]) => flags & flag).map(([name]) => name);
  const columns = COLUMNS.filter(([name]) => has.includes(name)
    && (part === 'whole' || (part === 'points') === DRAWN.includes(name)));
  const xyzBytes = part === 'attributes' ? 0 : 12 * count;
  let at = HEADER_BYTES + Math.ceil(namesBytes / 4) * 4;
  const expected = at + xyzBytes
    + columns.reduce((sum, [, , Type, width]) => sum + Type.BYTES_PER_ELEMENT * width * count, 0);
  if (bytes !== expected || (flags & ~255) !== 0 || part === undefined) {
    throw new Error(`${bytes} bytes for ${count} points of flags ${flags}; expected ${expected}`);
  }
  const names = new TextDecoder().decode(new Uint8Array(buffer, HEADER_BYTES, namesBytes));
  const cameras = namesBytes ? names.split('\n') : [];
  const positions = xyzBytes ? new Float32Array(buffer, at, 3 * count) : null;
  at += xyzBytes;
  const attributes = {};
  for (const [name, , Type, width] of columns) {
    attributes[name] = new Type(buffer, at, width * count);
    at += Type.BYTES_PER_ELEMENT * width * count;
  }
  return { count, rows, start, stop, origin, time0, cameras, part, has, positions, attributes };
}

// whether parsed points lack attributes their file has (a points part's: in its
// attributes part, loadAttributes fetches them)
export const lacksAttributes = (points) => points.has.some((name) => !(name in points.attributes));

// the attributes part of `points` (a points part, parsed) fetched from `url` and added to
// their attributes, once (a Promise of them; rejected with the reason, asked again then)
export function loadAttributes(points, url) {
  if (!lacksAttributes(points)) return Promise.resolve(points);
  points.loading ??= (async () => {
    const response = await fetch(url);
    if (!response.ok) throw new Error(`${url}: HTTP ${response.status} ${(await response.text()).split('\n')[0]}`);
    const more = parsePoints(await response.arrayBuffer());
    const same = ['count', 'rows', 'start', 'stop', 'time0'].every((key) => more[key] === points[key]);
    if (more.part !== 'attributes' || !same) throw new Error(`${url}: not the attributes of these points`);
    Object.assign(points.attributes, more.attributes);
    return points;
  })();
  points.loading.catch(() => { points.loading = undefined; });
  return points.loading;
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
// userData.points (applyColourMode for one added to a layer later), those of a points part
// fetched from attributesUrl when a colour mode needs them
export function pointsObject(points, pointSize, attributesUrl = null) {
  const material = new THREE.PointsMaterial({ size: pointSize, sizeAttenuation: false });
  const object = new THREE.Points(pointsGeometry(points), material);
  object.userData.attributesUrl = attributesUrl;
  object.position.set(...points.origin);
  return object;
}
