// The graph cut's part tree (the API's `hierarchy`): any part count, with no request.

/**
 * Part of each leaf when the tree is cut into `count` parts (clamped to 1..L): the API's
 * recipe — each leaf climbs while its parent's id is below 2L - count — with the parts
 * numbered by their smallest leaf. The one implementation of the rule in the viewer.
 */
export function leafParts(tree, count) {
  const leaves = tree.leaf_count;
  const parent = tree.parent;
  const parts = new Int32Array(leaves);
  if (leaves === 0) return parts;
  const limit = 2 * leaves - Math.min(Math.max(Math.round(count), 1), leaves);
  // A parent's id is above its children's: resolving from the root down is one pass.
  const top = new Int32Array(2 * leaves - 1);
  for (let node = 2 * leaves - 2; node >= 0; node--) {
    const up = parent[node];
    top[node] = up !== -1 && up < limit ? top[up] : node;
  }
  const number = new Int32Array(2 * leaves - 1).fill(-1);
  let next = 0;
  for (let leaf = 0; leaf < leaves; leaf++) {
    const node = top[leaf];
    if (number[node] < 0) number[node] = next++;
    parts[leaf] = number[node];
  }
  return parts;
}

/** Per-face part labels from per-face leaves (-1 stays -1) and leafParts. */
export function faceParts(leafLabels, parts) {
  const labels = new Int32Array(leafLabels.length);
  for (let i = 0; i < leafLabels.length; i++) {
    const leaf = leafLabels[i];
    labels[i] = leaf >= 0 ? parts[leaf] : -1;
  }
  return labels;
}

/**
 * Per-leaf sums the parts table adds up: input faces, triangle area and area x ShDF
 * (the service's part area and area-weighted mean ShDF are over the triangles).
 * `geometry`: the display geometry (triangles and their input face); `shdf` per input face.
 */
export function leafSums(leafCount, leafLabels, geometry, shdf) {
  const faces = new Float64Array(leafCount);
  const area = new Float64Array(leafCount);
  const moment = new Float64Array(leafCount);
  for (let i = 0; i < leafLabels.length; i++) if (leafLabels[i] >= 0) faces[leafLabels[i]]++;
  const { faceOrigin } = geometry;
  const areas = triangleAreas(geometry);
  for (let k = 0; k < faceOrigin.length; k++) {
    const face = faceOrigin[k];
    const leaf = leafLabels[face];
    if (leaf < 0) continue;
    const triangleArea = areas[k];
    area[leaf] += triangleArea;
    const value = shdf ? shdf[face] : NaN;
    if (Number.isFinite(value)) moment[leaf] += triangleArea * value;
  }
  return { faces, area, moment };
}

const AREAS = new WeakMap();  // geometry -> its triangles' areas (every new answer sums them)

/** Area of each display triangle, computed once per geometry. */
function triangleAreas(geometry) {
  let areas = AREAS.get(geometry);
  if (areas) return areas;
  const { positions: p, triangles: t, faceOrigin } = geometry;
  areas = new Float64Array(faceOrigin.length);
  for (let k = 0; k < faceOrigin.length; k++) {
    const a = 3 * t[3 * k], b = 3 * t[3 * k + 1], c = 3 * t[3 * k + 2];
    const ux = p[b] - p[a], uy = p[b + 1] - p[a + 1], uz = p[b + 2] - p[a + 2];
    const vx = p[c] - p[a], vy = p[c + 1] - p[a + 1], vz = p[c + 2] - p[a + 2];
    const cx = uy * vz - uz * vy, cy = uz * vx - ux * vz, cz = ux * vy - uy * vx;
    areas[k] = 0.5 * Math.sqrt(cx * cx + cy * cy + cz * cz);
  }
  AREAS.set(geometry, areas);
  return areas;
}

/** Parts' faces, area and area-weighted mean ShDF: the leaves' sums added up per part. */
export function partSums(sums, parts, partCount) {
  const faces = new Float64Array(partCount);
  const area = new Float64Array(partCount);
  const moment = new Float64Array(partCount);
  for (let leaf = 0; leaf < parts.length; leaf++) {
    faces[parts[leaf]] += sums.faces[leaf];
    area[parts[leaf]] += sums.area[leaf];
    moment[parts[leaf]] += sums.moment[leaf];
  }
  const mean = Array.from(area, (a, i) => (a > 0 ? moment[i] / a : 0));
  return { faces, area, mean };
}
