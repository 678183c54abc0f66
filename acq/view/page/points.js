// A LAS/LAZ/COPC cloud's points as the server packs them (acq/view/las_points.py): a
// 56-byte header (magic, points served, points they stand for, the origin's x y z as
// doubles, flags), then float32 x y z offsets from the origin and uint8 sRGB r g b of each
// point; the whole layer's subset (points.bin) and each of its chunks (chunk/<c>.bin) alike.
import * as THREE from 'three';

const HEADER = 56;

// the payload in ArrayBuffer `buffer`: its origin (m, the file's frame), point count, float32
// offsets from the origin (3 a point), sRGB bytes (3 a point, null without colours) and the
// points' other attributes (none yet); Error when it is not one
export function parsePoints(buffer) {
  const head = new DataView(buffer);
  const magic = new TextDecoder().decode(new Uint8Array(buffer, 0, Math.min(8, buffer.byteLength)));
  if (buffer.byteLength < HEADER || magic !== 'ACQPTS1\0') throw new Error('not acq view\'s points');
  const count = Number(head.getBigUint64(8, true));
  if (buffer.byteLength !== HEADER + 15 * count) throw new Error(`${buffer.byteLength} bytes for ${count} points`);
  const origin = new THREE.Vector3(head.getFloat64(24, true), head.getFloat64(32, true), head.getFloat64(40, true));
  const coloured = (head.getUint32(48, true) & 1) === 1;
  return {
    origin,
    count,
    positions: new Float32Array(buffer, HEADER, 3 * count),
    colours: coloured ? new Uint8Array(buffer, HEADER + 12 * count, 3 * count) : null,
    attributes: {},
  };
}

const SRGB_TO_LINEAR = Float32Array.from(
  { length: 256 }, (_, c) => new THREE.Color().setRGB(c / 255, 0, 0, THREE.SRGBColorSpace).r);

// parsed points (parsePoints) as a geometry about their origin, its colours linear (as
// three.js takes vertex colours) when they have any
export function pointsGeometry(points) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(points.positions, 3));
  if (points.colours !== null) {
    const linear = Float32Array.from(points.colours, (c) => SRGB_TO_LINEAR[c]);
    geometry.setAttribute('color', new THREE.BufferAttribute(linear, 3));
  }
  geometry.computeBoundingBox();
  geometry.computeBoundingSphere();
  return geometry;
}
