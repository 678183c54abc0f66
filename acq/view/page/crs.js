// The layers' coordinate reference systems as /api/layers gives them (acq/view/crs.py): a
// point's label in its layer's CRS, and the panel's line on the CRS of the whole view.

const fixed = (v) => v.toFixed(3);

// a point [x, y, z] (m) labelled with the CRS `crs` of its layer: easting, northing and
// height for a projected CRS, x y z named by the frame otherwise
export function pointLabel(p, crs) {
  const [x, y, z] = p;
  if (crs?.projected) return `${crs.name} E ${fixed(x)} N ${fixed(y)} h ${fixed(z)}`;
  let frame = 'local frame';
  if (crs?.name) frame = crs.name;
  else if (crs) frame = 'unread CRS';
  return `${frame} x ${fixed(x)} y ${fixed(y)} z ${fixed(z)}`;
}

// whether the view is drawn in a projected CRS (east, north in metres): some layer's is
export function georeferenced(layers) {
  return layers.some((layer) => layer.crs?.projected);
}

// the panel's lines on the layers' CRS: the CRS they share, or that they disagree (each
// layer's named), the layers that declare none beside those that do, and each file whose
// CRS could not be read; {text, warning} each
export function crsLines(layers) {
  const lines = [];
  const named = layers.filter((layer) => layer.crs?.name);
  const names = [...new Set(named.map((layer) => layer.crs.name))];
  if (names.length === 1) {
    lines.push({ text: `CRS ${names[0]}`, warning: false });
  } else if (names.length > 1) {
    const each = named.map((layer) => `${layer.name} ${layer.crs.name}`).join(', ');
    lines.push({ text: `the layers disagree on their CRS: ${each}; each point is given in its own layer's`, warning: true });
  }
  const none = layers.filter((layer) => layer.crs === null);
  if (names.length > 0 && none.length > 0) {
    lines.push({ text: `no CRS in ${none.map((layer) => layer.name).join(', ')}: drawn in its own coordinates`, warning: false });
  }
  for (const layer of layers) {
    if (layer.crs?.note) lines.push({ text: `${layer.name}: ${layer.crs.note}`, warning: true });
  }
  return lines;
}

// the lines of crsLines(layers) in the element `into`
export function showCrs(layers, into) {
  for (const { text, warning } of crsLines(layers)) {
    const line = document.createElement('div');
    line.textContent = text;
    if (warning) line.className = 'warning';
    into.append(line);
  }
}
