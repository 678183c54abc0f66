// The frame a point was coloured from (the paper's §4 check by eye): with "show frame" on, a
// click on a cloud's point asks the server (/api/frame?layer=K&point=I, I the point's index
// in the page's cloud) and shows that camera frame with the point ringed at its pixel, the
// camera, the frame's time and the pixel. window.acqFrame holds the server's answer (with
// `ring`, the ring's centre in page pixels) or {error}.
import { pick } from './measure.js';

const DRAG_PX = 4; // a press and release further apart than this is an orbit, not a click

export function frameTool(camera, canvas, objects) {
  const toggle = document.getElementById('show-frame');
  const measure = document.getElementById('measure');
  const panel = document.getElementById('frame-panel');
  const caption = document.getElementById('frame-caption');
  const image = document.getElementById('frame-image');
  const ring = document.getElementById('frame-ring');
  window.acqFrame = null;

  // one tool at a time: the measure tool takes the clicks while it is on
  toggle.addEventListener('change', () => {
    if (toggle.checked && measure.checked) measure.click();
    if (!toggle.checked) panel.hidden = true;
  });
  measure.addEventListener('change', () => {
    if (measure.checked && toggle.checked) toggle.click();
  });

  function show(answer) {
    window.acqFrame = answer;
    panel.hidden = false;
    if (answer.error) {
      caption.textContent = answer.error;
      caption.className = 'error';
      image.hidden = ring.hidden = true;
      return;
    }
    caption.className = '';
    if (answer.camera === null) {
      caption.textContent = answer.message;
      image.hidden = ring.hidden = true;
      return;
    }
    const [u, v] = answer.pixel;
    const when = new Date(answer.utc_s * 1000).toISOString().replace('T', ' ').replace('Z', ' UTC');
    caption.textContent = `${answer.camera}, frame ${answer.frame}: ${when} (${answer.t_s.toFixed(3)} s into the drive)\n`
      + `pixel ${u.toFixed(1)}, ${v.toFixed(1)}${answer.in_image ? '' : ' (outside the image)'}`;
    image.hidden = false;
    image.onload = () => {
      const scale = image.clientWidth / answer.size[0];
      ring.style.left = `${u * scale}px`;
      ring.style.top = `${v * scale}px`;
      ring.hidden = false;
      const box = image.getBoundingClientRect();
      window.acqFrame = { ...answer, ring: [box.left + u * scale, box.top + v * scale] };
    };
    image.onerror = () => show({ error: `${answer.url}: the frame could not be loaded` });
    window.acqFrame = { ...answer, ring: null }; // until the image is drawn
    image.src = answer.url;
  }

  let down = null;
  canvas.addEventListener('pointerdown', (e) => { down = e.button === 0 ? [e.clientX, e.clientY] : null; });
  canvas.addEventListener('pointerup', async (e) => {
    if (!toggle.checked || down === null || e.button !== 0) return;
    if (Math.hypot(e.clientX - down[0], e.clientY - down[1]) > DRAG_PX) return;
    const rect = canvas.getBoundingClientRect();
    const hit = pick(e.clientX - rect.left, e.clientY - rect.top, canvas, camera, objects);
    if (hit === null) return; // the background
    const layer = hit.object.userData.frameLayer;
    if (hit.index === null || layer === undefined) {
      show({ error: 'not a point of a cloud coloured from a drive given here (give its .mcap too)' });
      return;
    }
    const response = await fetch(`/api/frame?layer=${layer}&point=${hit.index}`);
    show(await response.json());
  });
}
