// The scale bar and the north arrow of a georeferenced view (a layer in a projected CRS:
// x east, y north, metres), HTML/SVG over the canvas, redrawn on every change of the view.
// The bar is a round length (1, 2 or 5 × 10^n m) at most MAX_BAR_PX long at the metres per
// pixel of the orbit's target; the arrow points to grid north (+y) as a compass does: turned
// by the view's heading (the camera's looking direction on the ground).
import * as THREE from 'three';
import { metresPerPixel } from './measure.js';

const MAX_BAR_PX = 120;

// the largest 1, 2 or 5 × 10^n not over `metres` (> 0)
export function roundLength(metres) {
  const decade = 10 ** Math.floor(Math.log10(metres));
  for (const step of [5, 2, 1]) if (step * decade <= metres * (1 + 1e-9)) return step * decade;
  return decade;
}

// a length in m as the bar's label: km, m, cm or mm, whichever keeps it a whole number
export function lengthText(metres) {
  const whole = (v) => String(Number(v.toPrecision(6)));
  if (metres >= 1000) return `${whole(metres / 1000)} km`;
  if (metres >= 1) return `${whole(metres)} m`;
  if (metres >= 0.01) return `${whole(metres * 100)} cm`;
  return `${whole(metres * 1000)} mm`;
}

// the heading of the view (degrees clockwise from grid north of the screen's up, on the
// ground): of the camera's looking direction, or of its up when it looks straight down
export function heading(camera) {
  const forward = camera.getWorldDirection(new THREE.Vector3());
  if (Math.hypot(forward.x, forward.y) < 1e-9) {
    forward.setFromMatrixColumn(camera.matrixWorld, 1);
  }
  return THREE.MathUtils.radToDeg(Math.atan2(forward.x, forward.y));
}

function element(html) {
  const holder = document.createElement('div');
  holder.innerHTML = html.trim();
  return holder.firstChild;
}

// the overlays on the page, updated when `controls` change the view of `camera` on `canvas`;
// window.acqOverlays holds what they show ({metres, px, metresPerPixel, northDeg})
export function overlays(camera, controls, canvas) {
  const bar = element(`<div id="scale-bar"><div class="bar"></div><span class="label"></span></div>`);
  const arrow = element(`
    <svg id="north-arrow" viewBox="-20 -24 40 48" width="40" height="48" aria-label="grid north">
      <polygon points="0,-20 9,10 0,4 -9,10" fill="#e8eaed" stroke="#202124" stroke-width="1.5"/>
      <text x="0" y="22" text-anchor="middle" fill="#e8eaed" font-size="11">N</text>
    </svg>`);
  document.body.append(bar, arrow);
  const line = bar.querySelector('.bar');
  const label = bar.querySelector('.label');

  function update() {
    const forward = camera.getWorldDirection(new THREE.Vector3());
    const depth = controls.target.clone().sub(camera.position).dot(forward);
    const perPixel = metresPerPixel(camera, depth, canvas.getBoundingClientRect().height);
    if (!(perPixel > 0 && Number.isFinite(perPixel))) return; // a canvas of no height
    const metres = roundLength(MAX_BAR_PX * perPixel);
    const px = metres / perPixel;
    line.style.width = `${px}px`;
    label.textContent = lengthText(metres);
    const northDeg = -heading(camera);
    arrow.style.transform = `rotate(${northDeg}deg)`;
    window.acqOverlays = { metres, px, metresPerPixel: perPixel, northDeg };
  }
  controls.addEventListener('change', update);
  window.addEventListener('resize', update);
  update();
}
