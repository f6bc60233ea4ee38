// Part editing controls: grow, shrink, merge, paint and split the selected part; undo,
// reset, apply on the server, export. Edits run in the page (editing.js) on the part tree
// it has, with no request; the document names input faces, as the API's `edits` does. A
// split needs the mesh's adjacency and METIS, so a document holding one is applied by the
// service (each edit then costs a request).
import * as api from './api.js';
import { applyEdits, applyLabelEdits, extendEdits } from './editing.js';
import { leafSums } from './hierarchy.js';

/**
 * Wire the edit tools. `page`: { state, view, select(label), show(body, request, labels, selected),
 * showError(error, context), partColor(label) } from main.js. Returns the hooks main.js calls:
 * `segmented(body, request, labels)` for every new segmentation on screen and `pick(face)`
 * for a click on the mesh (true when an edit mode took it).
 */
export function setUpEditing(page) {
  const { state, view } = page;
  const $ = (id) => document.getElementById(id);
  const session = { base: null, edits: [], mode: null, result: null, faceSums: null, sumsOf: null };
  state.selectedFace = -1;

  function partFace(painted) {
    // A face of the selected part: the clicked one if it is still there; for grow and
    // shrink (`painted`: false) one whose tree node is in the part (not painted into it).
    const { labels, selected } = state;
    const moved = (face) => !painted && session.result && session.result.state.painted[face] >= 0;
    const face = state.selectedFace;
    if (face >= 0 && labels[face] === selected && !moved(face)) return face;
    for (let f = 0; f < labels.length; f++) if (labels[f] === selected && !moved(f)) return f;
    return -1;
  }

  function summaries(labels, partCount) {
    if (session.sumsOf !== state.geometry) {  // per input face, once per mesh
      const identity = Int32Array.from({ length: labels.length }, (_, i) => i);
      session.faceSums = leafSums(labels.length, identity, state.geometry, state.shdf);
      session.sumsOf = state.geometry;
    }
    const { faces, area, moment } = session.faceSums;
    const totals = { faces: new Float64Array(partCount), area: new Float64Array(partCount), moment: new Float64Array(partCount) };
    for (let f = 0; f < labels.length; f++) {
      const label = labels[f];
      if (label < 0) continue;
      totals.faces[label] += faces[f];
      totals.area[label] += area[f];
      totals.moment[label] += moment[f];
    }
    return Array.from({ length: partCount }, (_, label) => ({
      label,
      faces: totals.faces[label],
      area: totals.area[label],
      mean_shdf: totals.area[label] > 0 ? totals.moment[label] / totals.area[label] : 0,
      color: page.partColor(label),
    }));
  }

  /** Labels of the base segmentation edited by the document, in the page. */
  function editedLabels(edits) {
    const { base } = session;
    return base.tree
      ? applyEdits(base.tree.tree, base.tree.leafLabels, base.body.part_count, edits)
      : applyLabelEdits(base.labels, edits);
  }

  async function show(labels, source, start, face) {
    const labelled = performance.now();
    let partCount = 0;
    for (let f = 0; f < labels.length; f++) if (labels[f] >= partCount) partCount = labels[f] + 1;
    const body = {
      ...session.base.body, labels: null, labels_base64: null, labels_dtype: null,
      part_count: partCount, parts: summaries(labels, partCount),
    };
    const summarised = performance.now();
    page.show(body, session.base.request, labels, face >= 0 ? labels[face] : -1);
    update();
    const computed = performance.now();  // what follows is the browser drawing the frame
    const shown = await view.presented();
    const detail = {
      source, edits: editDocument(), parts: partCount, ms: shown - start, computeMs: computed - start,
      // Where the time went: the labels (edit or request), the parts table's sums, showing.
      labelsMs: labelled - start, summaryMs: summarised - labelled, showMs: computed - summarised,
    };
    $('edit-status').textContent = `${session.edits.length} edits · ${partCount} parts · ${Math.round(detail.ms)} ms (${source})`;
    window.dispatchEvent(new CustomEvent('shdf:edited', { detail }));
    return detail;
  }

  /** Whether only the service can apply `edits` (a split: METIS on the mesh). */
  const needsService = (edits) => edits.some((operation) => operation.op === 'split');

  /** The document through POST /v1/segment, shown with the service's labels. */
  async function serviceEdit(edits, face, start) {
    try {
      const body = await api.segment({ ...session.base.request, edits }, undefined);
      session.edits = edits;
      session.result = null;
      return show(api.decodeLabels(body), 'service', start, face);
    } catch (error) {
      page.showError(error, 'edits on the service');
      return null;
    }
  }

  /** Add an operation and show the result; `start`: when the user asked (for timings). */
  async function edit(operation, face, start = performance.now()) {
    if (!session.base) return null;
    const edits = [...session.edits, operation];
    if (needsService(edits)) return serviceEdit(edits, face, start);
    let result;
    try {
      // One more operation on the page's edit state (no replay of the whole document).
      result = session.result ? extendEdits(session.result, edits) : editedLabels(edits);
    } catch (error) {
      page.showError(error, 'edit');
      return null;
    }
    session.edits = edits;
    session.result = result;
    return show(result.labels, 'page', start, face);
  }

  async function replay(start = performance.now()) {
    const face = state.selectedFace;
    if (needsService(session.edits)) return serviceEdit(session.edits, face, start);
    session.result = session.edits.length ? editedLabels(session.edits) : null;
    const labels = session.result ? session.result.labels : session.base.labels;
    return show(labels, 'page', start, face);
  }

  const editDocument = () => session.edits.map((operation) => structuredClone(operation));

  function setMode(mode) {
    session.mode = session.mode === mode ? null : mode;
    view.controls.enabled = session.mode !== 'paint';  // a drag paints instead of orbiting
    $('edit-merge').classList.toggle('active', session.mode === 'merge');
    $('edit-paint').classList.toggle('active', session.mode === 'paint');
    $('edit-status').textContent = session.mode === 'merge' ? 'Click the part to merge with'
      : session.mode === 'paint' ? 'Click or drag over faces to paint them into this part' : $('edit-status').textContent;
  }

  function update() {
    const selected = state.selected >= 0 && session.base;
    $('edit-tools').hidden = !session.base;
    const tree = Boolean(session.base?.tree);
    $('edit-grow').disabled = !selected || !tree;
    $('edit-shrink').disabled = !selected || !tree;
    $('edit-merge').disabled = !selected;
    $('edit-paint').disabled = !selected;
    $('edit-split').disabled = !selected;
    for (const id of ['edit-undo', 'edit-reset', 'edit-apply', 'edit-export']) $(id).disabled = session.edits.length === 0;
    if (!selected && session.mode) setMode(session.mode);  // leave the mode
  }

  function treeEdit(op) {
    const face = partFace(false);
    if (face < 0) {
      page.showError(new Error('this part holds only painted faces: it has no node of the part tree'), op);
      return null;
    }
    state.selectedFace = face;
    return edit({ op, face }, face);
  }

  // A paint stroke: faces under the pointer while it is down, one operation at the end.
  const stroke = { faces: null, pending: null };
  const canvas = view.canvas;
  canvas.addEventListener('pointerdown', (event) => {
    if (session.mode !== 'paint') return;
    stroke.faces = new Set();
    collect(event);
  });
  canvas.addEventListener('pointermove', (event) => {
    if (!stroke.faces || stroke.pending) return;
    stroke.pending = requestAnimationFrame(() => { stroke.pending = null; collect(event); });
  });
  window.addEventListener('pointerup', () => {
    if (!stroke.faces) return;
    const faces = [...stroke.faces].sort((a, b) => a - b);
    stroke.faces = null;
    const target = partFace(true);
    if (faces.length && target >= 0) edit({ op: 'paint', faces, to_face: target }, target);
  });
  function collect(event) {
    const face = view.pick(event.clientX, event.clientY);
    if (face >= 0) stroke.faces?.add(face);
  }

  $('edit-grow').onclick = () => treeEdit('grow');
  $('edit-shrink').onclick = () => treeEdit('shrink');
  $('edit-split').onclick = () => split();
  $('edit-merge').onclick = () => setMode('merge');
  $('edit-paint').onclick = () => setMode('paint');
  $('edit-undo').onclick = () => { session.edits = session.edits.slice(0, -1); replay(); };
  $('edit-reset').onclick = () => { session.edits = []; replay(); };
  $('edit-export').onclick = () => {
    const text = JSON.stringify({ request: session.base.request, edits: editDocument() }, null, 1);
    const link = document.createElement('a');
    link.href = URL.createObjectURL(new Blob([text], { type: 'application/json' }));
    link.download = 'part-edits.json';
    link.click();
  };
  $('edit-apply').onclick = () => applyOnServer();

  /** Cut the selected part in two (a METIS bisection, by the service). */
  function split() {
    const face = partFace(true);
    if (face < 0) return null;
    state.selectedFace = face;
    return edit({ op: 'split', face }, face);
  }

  /** The same document through POST /v1/segment: the service's labels on screen. */
  async function applyOnServer() {
    const start = performance.now();
    try {
      const body = await api.segment({ ...session.base.request, edits: editDocument() }, undefined);
      return show(api.decodeLabels(body), 'service', start, state.selectedFace);
    } catch (error) {
      page.showError(error, 'edits on the service');
      return null;
    }
  }

  return {
    /** A new segmentation on screen (not an edit): edits start again from it. */
    segmented(body, request, labels) {
      if (body.labeler_id) {  // named parts are a labeller's answer: not edited by hand
        Object.assign(session, { base: null, edits: [], result: null });
        update();
        return;
      }
      // The leaves are decoded when an edit first needs them (state.tree decodes them once).
      const kept = body.hierarchy ? state.tree : null;
      const tree = kept ? { tree: kept.tree, get leafLabels() { return kept.leafLabels; } } : null;
      Object.assign(session, { base: { body, request, labels, tree }, edits: [], result: null });
      $('edit-status').textContent = '';
      update();
    },
    /** A click on the mesh: merge mode merges with the clicked part; paint mode paints. */
    pick(face) {
      if (session.mode === 'merge' && face >= 0 && state.selected >= 0) {
        const own = partFace(true);
        setMode('merge');
        edit({ op: 'merge', faces: [own, face] }, own);
        return true;
      }
      if (session.mode === 'paint') return true;  // the stroke handles it
      state.selectedFace = face;
      return false;
    },
    selected: update,
    grow: () => treeEdit('grow'),
    reset: () => { session.edits = []; return replay(); },
    shrink: () => treeEdit('shrink'),
    split,
    edit,
    document: editDocument,
    applyOnServer,
    session,
  };
}
