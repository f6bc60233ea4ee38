// Part editing in the page: the same document and the same rules as the service's
// neural_shdf/segment/editing.py (grow, shrink, merge, paint by input face), so the page's
// labels equal the API's for the same document, with no request.

/** Most operations and named faces in one document (the service's bounds). */
export const MAX_EDIT_OPERATIONS = 1000;
export const MAX_EDIT_FACES = 1_000_000;

export class EditError extends Error {}

/** The children of each merge node L + i, smaller id first (`merges` of the tree). */
function childrenOf(parent, leaves) {
  const children = new Int32Array(Math.max(2 * (leaves - 1), 0)).fill(-1);
  for (let node = 0; node < parent.length; node++) {
    const up = parent[node];
    if (up < 0) continue;
    const slot = 2 * (up - leaves);
    if (children[slot] < 0) children[slot] = node; else children[slot + 1] = node;
  }
  return children;
}

/**
 * Parts as groups of tree nodes (the cut) plus painted faces. The leaves are laid out
 * depth first so each node's leaves are positions low[n]..high[n]-1: growing or shrinking
 * a node fills one range of `top` (the cut node over each position).
 */
class EditState {
  constructor(parent, children, leafOfFace, topOfLeaf) {
    const leaves = (parent.length + 1) >> 1;
    const nodes = parent.length;
    Object.assign(this, { parent, children, leaves, leafOfFace });
    const size = new Int32Array(nodes).fill(1);
    for (let i = 0; i < leaves - 1; i++) size[leaves + i] = size[children[2 * i]] + size[children[2 * i + 1]];
    const low = new Int32Array(nodes);
    for (let i = leaves - 2; i >= 0; i--) {
      const a = children[2 * i], b = children[2 * i + 1];
      low[a] = low[leaves + i];
      low[b] = low[leaves + i] + size[a];
    }
    this.low = low;
    this.high = low.map((value, node) => value + size[node]);
    // Plain loops over typed arrays: at 100k faces a callback per face costs milliseconds.
    const facePosition = new Int32Array(leafOfFace.length);
    for (let face = 0; face < leafOfFace.length; face++) {
      const leaf = leafOfFace[face];
      facePosition[face] = leaf >= 0 ? low[leaf] : -1;
    }
    this.facePosition = facePosition;
    this.top = new Int32Array(leaves);
    for (let leaf = 0; leaf < leaves; leaf++) this.top[low[leaf]] = topOfLeaf[leaf];
    this.nodeGroup = new Int32Array(nodes).fill(-1);
    this.groupNodes = [];
    this.groupParent = [];
    const cut = [...new Set(topOfLeaf)].sort((a, b) => a - b);  // groups in node order, as np.unique
    for (const node of cut) {
      this.nodeGroup[node] = this.groupParent.length;
      this.groupNodes.push(new Set([node]));
      this.groupParent.push(this.groupParent.length);
    }
    this.painted = new Int32Array(leafOfFace.length).fill(-1);
  }

  find(group) {
    let root = group;
    while (this.groupParent[root] !== root) root = this.groupParent[root];
    while (this.groupParent[group] !== root) {
      const next = this.groupParent[group];
      this.groupParent[group] = root;
      group = next;
    }
    return root;
  }

  union(into, other) {
    into = this.find(into);
    other = this.find(other);
    if (into === other) return;
    this.groupParent[other] = into;
    for (const node of this.groupNodes[other]) this.groupNodes[into].add(node);
    this.groupNodes[other] = new Set();
  }

  cutNode(face) { return this.top[this.facePosition[face]]; }

  /** The part holding `face` now, paint included. */
  part(face) {
    const painted = this.painted[face];
    return this.find(painted >= 0 ? painted : this.nodeGroup[this.cutNode(face)]);
  }

  grow(face) {
    const node = this.cutNode(face);
    const up = this.parent[node];
    if (up < 0) return;
    const group = this.find(this.nodeGroup[node]);
    const low = this.low[up], high = this.high[up];
    const emptied = [];
    let previous = -1;
    for (let p = low; p < high; p++) {
      const inside = this.top[p];
      if (inside === previous || this.nodeGroup[inside] < 0) continue;  // seen already
      previous = inside;
      const owner = this.find(this.nodeGroup[inside]);
      this.nodeGroup[inside] = -1;
      this.groupNodes[owner].delete(inside);
      if (owner !== group && this.groupNodes[owner].size === 0) emptied.push(owner);
    }
    this.top.fill(up, low, high);
    this.nodeGroup[up] = group;
    this.groupNodes[group].add(up);
    for (const owner of emptied) this.union(group, owner);  // wholly inside: it joins
  }

  shrink(face) {
    const node = this.cutNode(face);
    if (node < this.leaves) return;
    const group = this.find(this.nodeGroup[node]);
    this.nodeGroup[node] = -1;
    this.groupNodes[group].delete(node);
    const fresh = this.groupParent.length;
    this.groupParent.push(fresh);
    this.groupNodes.push(new Set());
    const position = this.facePosition[face];
    const i = 2 * (node - this.leaves);
    for (const child of [this.children[i], this.children[i + 1]]) {
      const low = this.low[child], high = this.high[child];
      this.top.fill(child, low, high);
      const owner = low <= position && position < high ? group : fresh;
      this.nodeGroup[child] = owner;
      this.groupNodes[owner].add(child);
    }
  }

  merge(faces) {
    const into = this.part(faces[0]);
    for (const face of faces.slice(1)) this.union(into, this.part(face));
  }

  paint(faces, toFace) {
    const group = this.part(toFace);
    for (const face of faces) this.painted[face] = group;
  }

  /** Part per face, numbered by each part's smallest face; -1 stays -1. */
  labels() {
    const count = this.leafOfFace.length;
    const groups = this.groupParent.length;
    const root = new Int32Array(groups);
    for (let g = 0; g < groups; g++) root[g] = this.find(g);
    const { facePosition, painted, nodeGroup, top } = this;
    const rank = new Int32Array(groups).fill(-1);
    const labels = new Int32Array(count);
    let next = 0;
    for (let face = 0; face < count; face++) {
      const position = facePosition[face];
      if (position < 0) { labels[face] = -1; continue; }
      const paint = painted[face];
      const group = root[paint >= 0 ? paint : nodeGroup[top[position]]];
      if (rank[group] < 0) rank[group] = next++;
      labels[face] = rank[group];
    }
    return labels;
  }
}

const KEYS = { grow: ['face', 'op'], shrink: ['face', 'op'], merge: ['faces', 'op'], paint: ['faces', 'op', 'to_face'] };

/** Check a document against the mesh (`leafOfFace`: -1 for faces without triangles). */
function checkDocument(edits, leafOfFace, hasTree) {
  if (!Array.isArray(edits)) throw new EditError('the edits must be a list of operations');
  if (edits.length > MAX_EDIT_OPERATIONS) throw new EditError(`at most ${MAX_EDIT_OPERATIONS} edit operations per document`);
  let named = 0;
  edits.forEach((edit, index) => {
    const where = `edit ${index}`;
    const keys = KEYS[edit?.op];
    if (!keys) throw new EditError(`${where}: unknown op ${JSON.stringify(edit?.op)}; use one of grow, shrink, merge, paint`);
    if (Object.keys(edit).sort().join() !== keys.join()) throw new EditError(`${where}: '${edit.op}' takes exactly ${keys.join(', ')}`);
    if (!hasTree && (edit.op === 'grow' || edit.op === 'shrink')) {
      throw new EditError(`${where}: '${edit.op}' needs the part tree, which the METIS partitioner does not make`);
    }
    const faces = edit.op === 'grow' || edit.op === 'shrink' ? [edit.face] : [...edit.faces];
    if (edit.op !== 'grow' && edit.op !== 'shrink' && faces.length === 0) throw new EditError(`${where}: 'faces' must be a non-empty list`);
    if (edit.op === 'paint') faces.push(edit.to_face);
    named += faces.length;
    if (named > MAX_EDIT_FACES) throw new EditError(`at most ${MAX_EDIT_FACES} faces in one edit document`);
    for (const face of faces) {
      if (!Number.isInteger(face)) throw new EditError(`${where}: a face index must be an integer, got ${face}`);
      if (face < 0 || face >= leafOfFace.length) throw new EditError(`${where}: face ${face} is out of range`);
      if (leafOfFace[face] < 0) throw new EditError(`${where}: face ${face} has no triangles, so it is in no part`);
    }
  });
}

function run(state, edits) {
  for (const edit of edits) {
    if (edit.op === 'grow') state.grow(edit.face);
    else if (edit.op === 'shrink') state.shrink(edit.face);
    else if (edit.op === 'merge') state.merge(edit.faces);
    else state.paint(edit.faces, edit.to_face);
  }
  return state;
}

/**
 * `result` ({labels, state} of applyEdits or applyLabelEdits for `edits` less its last
 * operation) edited by that last operation too: the same labels as applying all of `edits`
 * again, for the cost of one operation and one pass over the faces. `result.state` is
 * changed in place (keep none of its earlier answers).
 */
export function extendEdits(result, edits) {
  const { state } = result;
  checkDocument(edits, state.leafOfFace, state.hasTree);
  run(state, edits.slice(-1));
  return { labels: state.labels(), state };
}

/**
 * The edit of the tree `{leaf_count, parent}` cut at `parts` (clamped to 1..L) by `edits`;
 * `leafOfFace`: leaf per input face. Returns `{labels, state}` (`state.part(face)`,
 * `state.painted`: what a later operation on a face will act on).
 */
export function applyEdits(tree, leafOfFace, parts, edits) {
  checkDocument(edits, leafOfFace, true);
  const leaves = tree.leaf_count;
  const parent = Int32Array.from(tree.parent);
  const limit = 2 * leaves - Math.min(Math.max(Math.round(parts), 1), leaves);
  const top = new Int32Array(parent.length);
  for (let node = parent.length - 1; node >= 0; node--) {
    const up = parent[node];
    top[node] = up >= 0 && up < limit ? top[up] : node;
  }
  const state = new EditState(parent, childrenOf(parent, leaves), leafOfFace, top.subarray(0, leaves));
  state.hasTree = true;
  run(state, edits);
  return { labels: state.labels(), state };
}

/** Merge and paint on labels with no tree (METIS); grow and shrink are refused. */
export function applyLabelEdits(labels, edits) {
  checkDocument(edits, labels, false);
  const ids = [...new Set(Array.from(labels).filter((l) => l >= 0))].sort((a, b) => a - b);
  const dense = new Map(ids.map((id, i) => [id, i]));
  const leafOfFace = Int32Array.from(labels, (l) => (l >= 0 ? dense.get(l) : -1));
  const leaves = ids.length;
  const parent = new Int32Array(Math.max(2 * leaves - 1, 0)).fill(-1);
  // A chain (0, 1) -> L, (i + 1, L + i - 1) -> L + i: only its leaves (the parts) matter.
  for (let i = 0; i < leaves - 1; i++) {
    parent[i + 1] = leaves + i;
    parent[i === 0 ? 0 : leaves + i - 1] = leaves + i;
  }
  const state = new EditState(parent, childrenOf(parent, leaves), leafOfFace, Int32Array.from({ length: leaves }, (_, i) => i));
  state.hasTree = false;
  run(state, edits);
  return { labels: state.labels(), state };
}
