// Walk mode: the eye on a drive's trajectory, EYE_M above the vehicle's origin (which a
// vehicle frame usually puts on the ground: about a standing person's eyes), looking along the
// direction of travel; the arrow keys or W/S move it along the drive at the speed set, a
// slider puts it anywhere on it; the button again goes back to orbiting where it was.
// window.acqWalk holds {at (m along the path), length, eye [x, y, z], looking (the unit view
// direction)} while walking, else null.
import * as THREE from 'three';

export const EYE_M = 1.7;
const AHEAD_M = 5; // the eye looks at the path this far ahead

// cumulative length (m) at each vertex of the path [[x, y, z], ...]
function lengths(path) {
  const out = [0];
  for (let i = 1; i < path.length; i++) {
    const [a, b] = [path[i - 1], path[i]];
    out.push(out[i - 1] + Math.hypot(b[0] - a[0], b[1] - a[1], b[2] - a[2]));
  }
  return out;
}

// the point (a Vector3, doubles) of the path at `s` m along it (clamped to its ends)
function along(path, cumulative, s) {
  const total = cumulative[cumulative.length - 1];
  const at = Math.min(Math.max(s, 0), total);
  let i = 1;
  while (i < path.length - 1 && cumulative[i] < at) i++;
  const span = cumulative[i] - cumulative[i - 1];
  const f = span > 0 ? (at - cumulative[i - 1]) / span : 0;
  return new THREE.Vector3(...path[i - 1]).lerp(new THREE.Vector3(...path[i]), f);
}

// `paths()`: the drives' paths now drawn (the first with two points is walked)
export function walkTool(camera, controls, paths, render) {
  const button = document.getElementById('walk');
  const controlsBox = document.getElementById('walk-controls');
  const slider = document.getElementById('walk-at');
  const speed = document.getElementById('walk-speed');
  const speedOutput = document.getElementById('walk-speed-value');
  let walk = null; // {path, cumulative, at, saved}
  const held = new Set();
  let last = null;
  window.acqWalk = null;

  function place() {
    const { path, cumulative } = walk;
    const total = cumulative[cumulative.length - 1];
    walk.at = Math.min(Math.max(walk.at, 0), total);
    const up = new THREE.Vector3(0, 0, EYE_M);
    const eye = along(path, cumulative, walk.at).add(up);
    // at the end, look on along the last stretch
    const ahead = walk.at + AHEAD_M <= total
      ? along(path, cumulative, walk.at + AHEAD_M).add(up)
      : eye.clone().add(along(path, cumulative, total).sub(along(path, cumulative, total - AHEAD_M)));
    camera.position.copy(eye);
    camera.lookAt(ahead);
    slider.value = String(walk.at);
    const looking = camera.getWorldDirection(new THREE.Vector3()).toArray();
    window.acqWalk = { at: walk.at, length: total, eye: eye.toArray(), looking };
    render();
  }

  function step(now) {
    if (walk === null || held.size === 0) { last = null; return; }
    const dt = last === null ? 0 : Math.min((now - last) / 1000, 0.1);
    last = now;
    const direction = (held.has('forward') ? 1 : 0) - (held.has('back') ? 1 : 0);
    walk.at += direction * Number(speed.value) * dt;
    place();
    requestAnimationFrame(step);
  }

  function start() {
    const path = paths().find((p) => p.length >= 2);
    if (!path) {
      button.title = 'no drive with a trajectory to walk';
      return;
    }
    const cumulative = lengths(path);
    walk = {
      path, cumulative, at: 0,
      saved: { position: camera.position.clone(), target: controls.target.clone(), near: camera.near },
    };
    controls.enabled = false;
    camera.near = 0.05;
    camera.updateProjectionMatrix();
    slider.max = String(cumulative[cumulative.length - 1]);
    controlsBox.hidden = false;
    button.textContent = 'orbit';
    place();
  }

  function stop() {
    const { saved } = walk;
    walk = null;
    held.clear();
    camera.position.copy(saved.position);
    camera.near = saved.near;
    camera.updateProjectionMatrix();
    controls.target.copy(saved.target);
    controls.enabled = true;
    controls.update();
    controlsBox.hidden = true;
    button.textContent = 'walk';
    window.acqWalk = null;
    render();
  }

  button.addEventListener('click', () => (walk === null ? start() : stop()));
  slider.addEventListener('input', () => { if (walk) { walk.at = Number(slider.value); place(); } });
  speed.addEventListener('input', () => { speedOutput.textContent = `${speed.value} m/s`; });
  const keys = { ArrowUp: 'forward', w: 'forward', W: 'forward', ArrowDown: 'back', s: 'back', S: 'back' };
  window.addEventListener('keydown', (e) => {
    if (walk === null || !(e.key in keys) || e.target instanceof HTMLInputElement && e.target.type !== 'range') return;
    e.preventDefault();
    const wasIdle = held.size === 0;
    held.add(keys[e.key]);
    if (wasIdle) requestAnimationFrame(step);
  });
  window.addEventListener('keyup', (e) => { if (e.key in keys) held.delete(keys[e.key]); });
}
