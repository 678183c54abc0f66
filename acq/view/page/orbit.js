// Hooks that turn the view about the vertical through the orbit's target, for the tests and
// bench/view_fps.py: window.acqTurn(degrees) once, window.acqOrbit(seconds, degrees) by
// `degrees` at every animation frame for `seconds`, resolving to {frames, seconds};
// window.acqTarget() is the orbit's target [x, y, z] (m).
import * as THREE from 'three';

const Z = new THREE.Vector3(0, 0, 1);

export function orbitHooks(camera, controls) {
  function turn(degrees) {
    const offset = camera.position.clone().sub(controls.target);
    offset.applyAxisAngle(Z, THREE.MathUtils.degToRad(degrees));
    camera.position.copy(controls.target).add(offset);
    controls.update(); // its change event redraws
  }
  window.acqTurn = turn;
  window.acqTarget = () => controls.target.toArray();
  window.acqOrbit = (seconds, degrees = 1) => new Promise((resolve) => {
    let frames = 0;
    let start = null;
    function step(now) {
      if (start === null) start = now;
      else frames += 1; // a frame drawn since the last callback
      if (now - start >= seconds * 1000) {
        resolve({ frames, seconds: (now - start) / 1000 });
        return;
      }
      turn(degrees);
      requestAnimationFrame(step);
    }
    requestAnimationFrame(step);
  });
}
