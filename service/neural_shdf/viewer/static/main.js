// The viewer page: upload, live segmentation controls, parts panel, downloads.
import * as api from './api.js';
import { setUpEditing } from './edit-panel.js';
import { faceParts, leafParts, leafSums, partSums } from './hierarchy.js';
import { MeshView, heatGradient, parseHex } from './scene.js';
import { setUpUnwrap } from './unwrap-panel.js';

const config = JSON.parse(document.getElementById('viewer-config').textContent);
const UNLABELED = parseHex(config.unlabeledColor);
const $ = (id) => document.getElementById(id);
const SPECULATIVE_DELAY_MS = 150;  // a slider held still this long while dragging re-segments
const CLIENT_CACHE_SIZE = 24;
const DEFAULT_PARTS_MAX = Number(document.getElementById('parts').max);
/** The service's colour of part `label` (the same palette as its answers). */
const partColor = (label) => '#' + config.partPalette.slice(6 * label, 6 * label + 6);
/**
 * The smoothing slider's values, one per position: most of the track goes to the useful
 * range (0.01 to 0.2) that a linear 0..1 slider squeezed into its first fifth.
 */
const SMOOTHING_VALUES = [
  0, 0.005, 0.01, 0.015, 0.02, 0.025, 0.03, 0.035, 0.04, 0.045, 0.05, 0.06, 0.07, 0.08, 0.09,
  0.1, 0.12, 0.14, 0.16, 0.18, 0.2, 0.25, 0.3, 0.4, 0.5, 0.7, 1, 1.5, 2,
];
if (!SMOOTHING_VALUES.includes(config.defaultSmoothing)) {
  SMOOTHING_VALUES.push(config.defaultSmoothing);
  SMOOTHING_VALUES.sort((a, b) => a - b);
}
/** The slider position of the smoothing value nearest `value`. */
function smoothingPosition(value) {
  let best = 0;
  SMOOTHING_VALUES.forEach((v, i) => { if (Math.abs(v - value) < Math.abs(SMOOTHING_VALUES[best] - value)) best = i; });
  return best;
}
const smoothingValue = () => SMOOTHING_VALUES[Number($('smoothing').value)];

const state = {
  meshId: null,
  meta: null,
  method: config.defaultMethod,
  geometry: null,
  shdf: null,
  labels: null,       // Int32Array per input face
  body: null,         // the Segmentation on screen (labels decoded separately)
  shownRequest: null, // the request that produced it
  palette: null,      // Uint8Array RGB per label
  seq: 0,             // number of the newest segmentation request
  controller: null,   // AbortController of the request in flight
  inflightKey: null,
  releaseTime: null,  // when the slider behind the request in flight was released
  speculative: null,  // timer of the request sent when a dragged slider is held still
  dragPending: false, // a dragged value waits for the request in flight
  cache: new Map(),   // request key -> Segmentation, most recent last
  tree: null,         // the graph cut's part tree of the answer on screen, for recuts
  labelerId: '',      // the part labeller chosen ('' : segment)
  labelers: [],       // the stored labellers (GET /v1/labelers)
  faceValues: null,   // named parts: the labeller's integer per input face (labels: indices)
  confidence: null,   // named parts: Float32Array per input face
  view: 'parts',
  selected: -1,
  hidden: new Set(),
  isolated: -1,
};

const view = new MeshView($('canvas'));
window.shdfViewer = { state, view, config };  // for tests, benchmarks and the console

// ---- messages and progress ------------------------------------------------------------
function setStatus(status) {
  document.body.dataset.status = status;
}

function showError(error, context) {
  const box = $('message');
  const title = error instanceof api.ServiceError ? error.title : 'Error';
  box.replaceChildren();
  const head = document.createElement('b');
  head.textContent = context ? `${title} — ${context}` : title;
  const text = document.createElement('p');
  text.textContent = error.message;
  const close = document.createElement('button');
  close.textContent = '×';
  close.title = 'Dismiss';
  close.onclick = () => { box.hidden = true; };
  box.append(close, head, text);
  box.hidden = false;
  box.dataset.code = error.code || 'error';
}

function clearError() {
  $('message').hidden = true;
}

function showProgress(label, fraction) {
  $('progress').hidden = false;
  $('progress-label').textContent = fraction === null ? label : `${label} ${Math.round(fraction * 100)}%`;
  const bar = $('progress-bar');
  if (fraction === null) bar.removeAttribute('value'); else bar.value = fraction;
}

function hideProgress() {
  $('progress').hidden = true;
}

// ---- upload ---------------------------------------------------------------------------
function checkFile(file) {
  const extension = file.name.includes('.') ? file.name.split('.').pop().toLowerCase() : '';
  if (!config.formats.includes(extension)) {
    return new api.ServiceError(415, 'unsupported_format',
      `${file.name}: not a mesh format the service reads; use one of ${config.formats.map((f) => '.' + f).join(', ')}`);
  }
  if (file.size > config.maxUploadBytes) {
    const mb = (n) => (n / 1024 ** 2).toFixed(1);
    return new api.ServiceError(413, 'payload_too_large',
      `${file.name} is ${mb(file.size)} MB; the service accepts at most ${mb(config.maxUploadBytes)} MB`);
  }
  return null;
}

async function openFile(file) {
  clearError();
  const problem = checkFile(file);
  if (problem) {
    setStatus(state.meshId ? 'ready' : 'error');
    showError(problem, file.name);
    return;
  }
  state.seq++;  // nothing from the previous mesh may land on this one
  state.controller?.abort();
  try {
    setStatus('uploading');
    showProgress(`Uploading ${file.name}`, 0);
    const method = $('method').value;
    const uploaded = await api.uploadMesh(file, method, (f) => showProgress(`Uploading ${file.name}`, f));
    let meta;
    if (uploaded.status === 202) {
      setStatus('computing');
      const job = await api.waitForJob(uploaded.body, (f, jobState) =>
        showProgress(jobState === 'queued' ? 'Queued' : 'Computing the ShDF', f));
      meta = await api.getMesh(job.mesh_id);
    } else {
      meta = uploaded.body.mesh;
    }
    showProgress('Loading the geometry', null);
    setStatus('loading');
    // The service keeps the name of the first upload of this geometry; show this file's.
    await loadMesh({ ...meta, filename: file.name }, method);
  } catch (error) {
    hideProgress();
    setStatus(state.meshId ? 'ready' : 'error');
    showError(error, file.name);
  }
}

async function loadMesh(meta, method) {
  const [geometry, shdf] = await Promise.all([api.getGeometry(meta.mesh_id), fetchShdf(meta.mesh_id, method)]);
  Object.assign(state, {
    meshId: meta.mesh_id, meta, method, geometry, shdf, labels: null, body: null, shownRequest: null,
    tree: null,
    selected: -1, hidden: new Set(), isolated: -1,
  });
  state.cache.clear();
  view.setGeometry(geometry);
  $('empty-hint').hidden = true;
  $('mesh-info').hidden = false;
  $('mesh-name').textContent = meta.filename || meta.mesh_id.slice(0, 12);
  showMeshStats();
  paint();
  hideProgress();
  await resegment({ reason: 'load' });
}

function fetchShdf(meshId, method) {
  return api.getShdf(meshId, method, (f) => showProgress('Computing the ShDF', f));
}

// ---- segmentation ---------------------------------------------------------------------
function controlValues() {
  const partitioner = $('partitioner').value;
  return {
    partitioner,
    clusters: Number($('clusters').value),
    smoothing: smoothingValue(),
    parts: Number($('parts').value) || null,  // 0: automatic
    refine: $('refine').checked,
    boundary_smoothing: $('boundary-smoothing').checked,
    crease_boundaries: $('crease-boundaries').checked,
    symmetry: $('symmetry').checked,
  };
}

function currentRequest() {
  if (state.labelerId) {  // named parts: the partitioning controls play no part
    return { mesh_id: state.meshId, method: state.method, labeler_id: state.labelerId };
  }
  return { mesh_id: state.meshId, method: state.method, ...controlValues() };
}

const requestKey = (request) => JSON.stringify(request);

/**
 * Re-segment with the current controls. A newer call aborts the request in flight and
 * its answer, if it still comes, is ignored. `releaseTime` marks when the user let go.
 */
async function resegment({ reason, releaseTime = null }) {
  if (!state.meshId) return;
  const request = currentRequest();
  const key = requestKey(request);
  const start = releaseTime ?? performance.now();
  if (canRecut(request)) {
    if (key !== requestKey(state.shownRequest)) await recut(request, reason, start);
    return;
  }
  if (state.inflightKey === key) {  // the same request already runs (sent while dragging)
    state.releaseTime = start;
    return;
  }
  if (reason === 'drag' && state.inflightKey) {
    // While dragging, one request at a time: the newest value goes when this one is back.
    state.dragPending = true;
    return;
  }
  state.dragPending = false;
  const seq = ++state.seq;
  state.controller?.abort();
  state.controller = new AbortController();
  state.inflightKey = key;
  state.releaseTime = start;
  $('seg-status').textContent = 'segmenting…';
  setStatus('segmenting');
  try {
    let body = state.cache.get(key);
    const fromPageCache = Boolean(body);
    const fetchStart = performance.now();
    if (body) {
      state.cache.delete(key);  // re-inserted below as the most recent
    } else {
      body = await api.segment(request, state.controller.signal, (f) => showProgress('Computing the ShDF', f));
      hideProgress();
    }
    if (seq !== state.seq) return;  // superseded while it ran
    const fetchMs = performance.now() - fetchStart;
    state.cache.set(key, body);
    if (state.cache.size > CLIENT_CACHE_SIZE) state.cache.delete(state.cache.keys().next().value);
    const paintStart = performance.now();
    applySegmentation(body, request);
    const paintMs = performance.now() - paintStart;
    const shown = await view.presented();
    if (seq !== state.seq) return;
    const detail = {
      seq, reason, request, key,
      parts: body.part_count,
      totalMs: shown - state.releaseTime,
      fetchMs,
      paintMs,
      serverMs: body.timings.total_ms,
      segmentMs: body.timings.segment_ms,
      cached: fromPageCache,
    };
    state.inflightKey = null;
    state.controller = null;
    if (state.dragPending) {
      state.dragPending = false;
      resegment({ reason: 'drag' });
    }
    const service = fromPageCache ? 'from this page' : `service ${Math.round(detail.serverMs)} ms`;
    $('seg-status').textContent = `${body.part_count} parts · ${Math.round(detail.totalMs)} ms (${service})`;
    setStatus('ready');
    window.dispatchEvent(new CustomEvent('shdf:segmented', { detail }));
  } catch (error) {
    if (seq !== state.seq || error.name === 'AbortError') return;
    state.inflightKey = null;
    state.controller = null;
    state.dragPending = false;
    setStatus('ready');
    $('seg-status').textContent = 'segmentation failed';
    showError(error, 'segmentation');
  }
}

/** Whether `request` is a cut of the part tree on screen: only the part count differs. */
function canRecut(request) {
  if (!state.tree || !state.shownRequest) return false;
  return requestKey({ ...request, parts: null }) === requestKey({ ...state.tree.request, parts: null });
}

/**
 * Show the part tree cut at the request's part count (0: automatic) with no request: the
 * labels, colours and parts table the service would answer for that count.
 */
async function recut(request, reason, start) {
  const seq = ++state.seq;
  state.controller?.abort();  // a request for another part count is moot
  Object.assign(state, { controller: null, inflightKey: null, dragPending: false });
  const paintStart = performance.now();
  const { tree, leafLabels, sums, body: base } = state.tree;
  const count = Math.min(request.parts ?? tree.automatic_parts, tree.leaf_count);
  const parts = leafParts(tree, count);
  const partCount = tree.leaf_count ? count : 0;
  const totals = partSums(sums, parts, partCount);
  const summaries = Array.from({ length: partCount }, (_, label) => ({
    label,
    faces: totals.faces[label],
    area: totals.area[label],
    mean_shdf: totals.mean[label],
    color: partColor(label),
  }));
  const body = {
    ...base, labels: null, labels_base64: null, labels_dtype: null,
    part_count: partCount, parts: summaries, hierarchy: { ...tree, parts: partCount },
  };
  applySegmentation(body, request, faceParts(leafLabels, parts));
  const paintMs = performance.now() - paintStart;
  const shown = await view.presented();
  if (seq !== state.seq) return;
  const detail = {
    seq, reason, request, key: requestKey(request), parts: partCount,
    totalMs: shown - start, fetchMs: 0, paintMs, serverMs: 0, segmentMs: 0,
    cached: true, recut: true,
  };
  $('seg-status').textContent = `${partCount} parts · ${Math.round(detail.totalMs)} ms (cut of the part tree)`;
  setStatus('ready');
  window.dispatchEvent(new CustomEvent('shdf:segmented', { detail }));
}

/** Keep the answer's part tree (with its per-leaf sums) for recuts; the slider spans it. */
function keepTree(body, request) {
  const tree = body.hierarchy;
  if (!tree) {
    state.tree = null;
    $('parts').max = String(DEFAULT_PARTS_MAX);
    return;
  }
  if (state.tree?.body === body) return;
  // The leaves are decoded and summed at the first cut of this tree, not for every answer:
  // a new smoothing value is shown without them (two passes over the faces).
  const { geometry, shdf } = state;
  let leafLabels = null;
  let sums = null;
  state.tree = {
    tree, body, request,
    get leafLabels() { return (leafLabels ??= api.decodeLeafLabels(tree)); },
    get sums() { return (sums ??= leafSums(tree.leaf_count, this.leafLabels, geometry, shdf)); },
  };
  $('parts').max = String(Math.max(1, Math.min(tree.leaf_count, config.maxParts)));
  showValues();
}

/** Show a segmentation; `edited`: a hand edit of the one on screen (editing keeps its base). */
function applySegmentation(body, request, labels = null, edited = false) {
  let faceValues = null;
  let confidence = null;
  if (labels === null) {
    labels = api.decodeLabels(body);
    keepTree(body, request);
    if (body.labeler_id) {
      // Named parts come in the labeller's own integers; the page works on part indices.
      faceValues = labels;
      const index = new Map(body.parts.map((part, i) => [part.label, i]));
      labels = Int32Array.from(faceValues, (value) => index.get(value) ?? -1);
      confidence = api.decodeConfidence(body);
    }
  }
  Object.assign(state, { faceValues, confidence });
  const palette = new Uint8Array(body.parts.length * 3);
  body.parts.forEach((part, i) => palette.set(parseHex(part.color), i * 3));
  Object.assign(state, { labels, body, palette, shownRequest: request });
  showMeshStats();
  if (state.selected >= body.part_count) state.selected = -1;
  state.hidden = new Set([...state.hidden].filter((label) => label < body.part_count));
  if (state.isolated >= body.part_count) state.isolated = -1;
  updateVisibility();
  paint();
  renderPartsPanel();
  for (const id of ['download-seg', 'download-json', 'download-colored', 'download-parts', 'unwrap-open']) $(id).disabled = false;
  if (!edited) editing.segmented(body, request, labels);
}

function paint() {
  if (!view.mesh) return;
  if (state.view === 'shdf' && state.shdf) view.paintShdf(state.shdf);
  else if (state.view === 'parts' && state.labels) view.paintParts(state.labels, state.palette, UNLABELED, state.selected);
  else view.paintPlain();
  $('shdf-legend').hidden = state.view !== 'shdf';  // an overlay: nothing else moves
  view.requestRender();
}

// ---- parts: selection, hide, isolate ----------------------------------------------------
function updateVisibility() {
  if (!state.labels) return;
  const { hidden, isolated } = state;
  const filter = isolated >= 0 ? (label) => label === isolated
    : hidden.size ? (label) => !hidden.has(label) : null;
  view.setVisibility(state.labels, filter);
}

/** Select part `label` (-1: none); `repaint`: false when the caller has just painted. */
function select(label, repaint = true) {
  state.selected = label;
  const box = $('selection');
  if (label < 0 || !state.body) {
    box.hidden = true;
  } else {
    const part = state.body.parts[label];
    $('selection-swatch').style.background = part.color;
    $('selection-title').textContent = partTitle(part, label);
    $('selection-label').textContent = String(part.label);
    $('selection-faces').textContent = part.faces.toLocaleString();
    $('selection-area').textContent = formatNumber(part.area);
    $('selection-shdf').textContent = part.mean_shdf.toFixed(3);
    $('selection-hide').textContent = state.hidden.has(label) ? 'Show' : 'Hide';
    $('selection-isolate').textContent = state.isolated === label ? 'Show all' : 'Isolate';
    box.hidden = false;
  }
  for (const row of $('parts-table').tBodies[0].rows) row.classList.toggle('selected', Number(row.dataset.label) === label);
  editing.selected();
  if (repaint) paint();
}

function toggleHidden(label) {
  if (state.hidden.has(label)) state.hidden.delete(label); else state.hidden.add(label);
  state.isolated = -1;
  updateVisibility();
  renderPartsPanel();
  select(state.selected);
}

function toggleIsolated(label) {
  state.isolated = state.isolated === label ? -1 : label;
  updateVisibility();
  renderPartsPanel();
  select(state.selected);
}

function showAll() {
  state.hidden.clear();
  state.isolated = -1;
  updateVisibility();
  renderPartsPanel();
  select(state.selected);
}

/** "head" for a named part, "Part 3" for a segment. */
const partTitle = (part, index) => part.name ?? `Part ${part.label ?? index}`;

const formatNumber = (x) => (Math.abs(x) >= 1000 || (x !== 0 && Math.abs(x) < 0.01) ? x.toExponential(2) : x.toFixed(3));
const MAX_ROWS = 500;

function renderPartsPanel() {
  const body = state.body;
  $('parts-panel').hidden = !body;
  if (!body) return;
  $('part-count').textContent = `(${body.part_count})`;
  const rows = body.parts.slice(0, MAX_ROWS).map((part) => {
    const row = document.createElement('tr');
    row.dataset.label = part.label;
    const visible = state.isolated >= 0 ? state.isolated === part.label : !state.hidden.has(part.label);
    row.classList.toggle('hidden-part', !visible);
    row.classList.toggle('selected', part.label === state.selected);
    row.innerHTML = `<td><span class="swatch" style="background:${part.color}"></span></td>
      <td class="part-name"></td><td>${part.faces.toLocaleString()}</td><td>${formatNumber(part.area)}</td>
      <td>${part.mean_shdf.toFixed(3)}</td>
      <td><button class="eye" title="Hide or show">${visible ? '◉' : '○'}</button><button class="solo" title="Isolate">◎</button></td>`;
    // A name comes from a labeller file: text, never markup.
    row.querySelector('.part-name').textContent = part.name ?? String(part.label);
    if (part.name) row.querySelector('.part-name').title = `label ${part.label}`;
    row.querySelector('.eye').onclick = (event) => { event.stopPropagation(); toggleHidden(part.label); };
    row.querySelector('.solo').onclick = (event) => { event.stopPropagation(); toggleIsolated(part.label); };
    row.onclick = () => select(part.label === state.selected ? -1 : part.label);
    return row;
  });
  $('parts-table').tBodies[0].replaceChildren(...rows);
}

// ---- downloads --------------------------------------------------------------------------
function saveBlob(blob, name) {
  const link = document.createElement('a');
  link.href = URL.createObjectURL(blob);
  link.download = name;
  link.click();
  setTimeout(() => URL.revokeObjectURL(link.href), 10000);
}

const stem = () => (state.meta.filename || state.meshId.slice(0, 16)).replace(/\.[^.]*$/, '');

async function downloadGlb(style) {
  if (!state.shownRequest) return;
  try {
    saveBlob(await api.getGlb(state.meshId, style, state.shownRequest), `${stem()}-${style}.glb`);
  } catch (error) {
    showError(error, `${style} GLB`);
  }
}

/** Labels per input face as the service gives them (named parts: the labeller's integers). */
const faceLabels = () => state.faceValues ?? state.labels;

$('download-seg').onclick = () => saveBlob(new Blob([faceLabels().join('\n') + '\n'], { type: 'text/plain' }), `${stem()}.seg`);
$('download-json').onclick = () => {
  const body = { ...state.body, labels: Array.from(faceLabels()), labels_base64: null, labels_dtype: null };
  if (state.confidence) Object.assign(body, { confidence: Array.from(state.confidence, (v) => (Number.isNaN(v) ? null : v)), confidence_base64: null });
  saveBlob(new Blob([JSON.stringify(body)], { type: 'application/json' }), `${stem()}-segmentation.json`);
};
$('download-colored').onclick = () => downloadGlb('colored');
$('download-parts').onclick = () => downloadGlb('parts');

// ---- controls ---------------------------------------------------------------------------
function showValues() {
  const clusters = Number($('clusters').value);
  $('clusters-out').textContent = clusters === 0 ? 'auto' : String(clusters);
  $('smoothing-out').textContent = String(smoothingValue());
  const parts = Number($('parts').value);
  $('parts-out').textContent = parts === 0 ? 'auto' : String(parts);
  $('parts').closest('label').title = $('partitioner').value === 'metis'
    ? 'METIS: exactly this many parts' : 'graph cut: a cut of its part tree (at most its leaves)';
}

const CHOICE_NAMES = {
  neural: 'neural', exact: 'exact (ray cast)', graphcut: 'graph cut', metis: 'METIS (exact part count)',
};

function fillSelect(select, values) {
  select.replaceChildren(...values.map((value) => new Option(CHOICE_NAMES[value] || value, value)));
}

function setUpControls() {
  fillSelect($('method'), config.methods);
  fillSelect($('partitioner'), config.partitioners);
  $('clusters').max = String(config.maxClusters);
  $('clusters').value = String(config.defaultClusters);
  $('smoothing').max = String(SMOOTHING_VALUES.length - 1);
  $('smoothing').value = String(smoothingPosition(config.defaultSmoothing));
  $('crease-boundaries').checked = config.defaultCreaseBoundaries;
  $('method').value = config.defaultMethod;
  showValues();
  for (const input of document.querySelectorAll('#controls input[type=range]')) {
    input.addEventListener('input', (event) => {
      showValues();
      clearTimeout(state.speculative);
      if (state.meshId && canRecut(currentRequest())) {  // a cut of the tree: at once
        resegment({ reason: 'drag', releaseTime: event.timeStamp });
        return;
      }
      state.speculative = setTimeout(() => resegment({ reason: 'drag' }), SPECULATIVE_DELAY_MS);
    });
    input.addEventListener('change', (event) => {
      clearTimeout(state.speculative);
      resegment({ reason: 'release', releaseTime: event.timeStamp });
    });
  }
  for (const input of document.querySelectorAll('#controls select, #controls input[type=checkbox]')) {
    input.addEventListener('change', (event) => {
      showValues();
      resegment({ reason: 'release', releaseTime: event.timeStamp });
    });
  }
  $('method').addEventListener('change', async () => {
    if (!state.meshId) return;
    clearError();
    const method = $('method').value;
    try {
      state.seq++;
      state.shdf = await fetchShdf(state.meshId, method);
      state.method = method;
      hideProgress();
      showMeshStats();
      paint();
      await resegment({ reason: 'method' });
    } catch (error) {
      hideProgress();
      $('method').value = state.method;
      showError(error, 'ShDF');
    }
  });
  for (const radio of document.querySelectorAll('input[name=view]')) {
    radio.addEventListener('change', () => { state.view = radio.value; paint(); });
  }
  setUpViewTools();
  $('shdf-legend').querySelector('.ramp').style.background = heatGradient();
  $('selection-hide').onclick = () => toggleHidden(state.selected);
  $('selection-isolate').onclick = () => toggleIsolated(state.selected);
  $('selection-clear').onclick = () => select(-1);
  $('show-all').onclick = showAll;
}

/** Faces, vertices and the ShDF method that ran ("exact (auto)" when auto chose it). */
function showMeshStats() {
  const { meta, method, body } = state;
  if (!meta) return;
  const ran = body?.method;
  const shdf = !ran ? method : ran === method ? ran : `${ran} (${method})`;
  $('mesh-stats').textContent = `${meta.faces.toLocaleString()} faces · ${meta.vertices.toLocaleString()} vertices · ShDF: ${shdf}`;
}

const UP_KEY = 'neural-shdf.up';

/** The stage's tools: up axis (remembered), frame, flat colours; F frames too. */
function setUpViewTools() {
  const up = $('up-axis');
  up.value = localStorage.getItem(UP_KEY) === 'z' ? 'z' : 'y';
  view.setUp(up.value);
  up.addEventListener('change', () => {
    localStorage.setItem(UP_KEY, up.value);
    view.setUp(up.value);
  });
  $('frame').onclick = () => { if (view.mesh) view.frame(); };
  $('flat').addEventListener('change', () => view.setLit(!$('flat').checked));
  window.addEventListener('keydown', (event) => {
    const typing = event.target instanceof HTMLInputElement && event.target.type !== 'range' && event.target.type !== 'checkbox';
    if (event.key.toLowerCase() === 'f' && !event.ctrlKey && !event.metaKey && !event.altKey && !typing && view.mesh) view.frame();
  });
}

function setUpFileInput() {
  $('file-input').addEventListener('change', (event) => {
    const [file] = event.target.files;
    if (file) openFile(file);
    event.target.value = '';
  });
  const overlay = $('drop-overlay');
  let depth = 0;
  window.addEventListener('dragenter', (event) => { event.preventDefault(); depth++; overlay.hidden = false; });
  window.addEventListener('dragleave', () => { if (--depth <= 0) { depth = 0; overlay.hidden = true; } });
  window.addEventListener('dragover', (event) => event.preventDefault());
  window.addEventListener('drop', (event) => {
    event.preventDefault();
    depth = 0;
    overlay.hidden = true;
    const [file] = event.dataTransfer.files;
    if (file) openFile(file);
  });
}

// ---- named parts: the labeller, the hover label -----------------------------------------
function showLabelerNames() {
  const chosen = state.labelers.find((entry) => entry.labeler_id === state.labelerId);
  $('labeler-names').textContent = chosen ? chosen.label_names.join(', ') : '';
  $('labeler-names').hidden = !chosen;
  $('controls').classList.toggle('disabled', Boolean(state.labelerId));
  for (const input of document.querySelectorAll('#controls input, #controls select')) input.disabled = Boolean(state.labelerId);
}

function fillLabelers(labelers) {
  state.labelers = labelers;
  const options = labelers.map((entry) => new Option(
    `${entry.label_names.slice(0, 4).join(', ')}${entry.label_names.length > 4 ? ', …' : ''} (${entry.labeler_id.slice(0, 8)})`,
    entry.labeler_id));
  $('labeler').replaceChildren(new Option('none: segment', ''), ...options);
  $('labeler').value = labelers.some((entry) => entry.labeler_id === state.labelerId) ? state.labelerId : '';
  state.labelerId = $('labeler').value;
  showLabelerNames();
}

async function refreshLabelers() {
  try {
    fillLabelers(await api.listLabelers());
  } catch (error) {
    showError(error, 'labellers');
  }
}

async function chooseLabeler(labelerId) {
  state.labelerId = labelerId;
  $('labeler').value = labelerId;
  showLabelerNames();
  state.selected = -1;
  await resegment({ reason: 'labeler' });
}

function setUpLabelers() {
  $('labeler').addEventListener('change', () => chooseLabeler($('labeler').value));
  $('labeler-input').addEventListener('change', async (event) => {
    const [file] = event.target.files;
    event.target.value = '';
    if (!file) return;
    clearError();
    try {
      const stored = await api.uploadLabeler(file);
      fillLabelers([...state.labelers.filter((e) => e.labeler_id !== stored.labeler_id), stored]);
      await chooseLabeler(stored.labeler_id);
    } catch (error) {
      showError(error, file.name);
    }
  });
  refreshLabelers();
}

/** The text under the pointer: the part's name (and confidence of named parts), or none. */
function hoverText(face) {
  if (face < 0 || !state.labels || !state.body) return null;
  const index = state.labels[face];
  const part = state.body.parts[index];
  if (!part) return null;
  const confidence = state.confidence ? state.confidence[face] : NaN;
  return Number.isNaN(confidence) ? partTitle(part, index) : `${partTitle(part, index)} · ${confidence.toFixed(2)}`;
}

function setUpHover() {
  const canvas = $('canvas');
  const label = $('hover-label');
  let pending = null;
  canvas.addEventListener('pointermove', (event) => {
    if (event.buttons) { label.hidden = true; return; }  // orbiting or painting
    const { clientX, clientY } = event;
    if (pending !== null) cancelAnimationFrame(pending);
    pending = requestAnimationFrame(() => {
      pending = null;
      const text = view.mesh ? hoverText(view.pick(clientX, clientY)) : null;
      label.hidden = text === null;
      if (text === null) return;
      const box = $('stage').getBoundingClientRect();
      label.textContent = text;
      label.style.left = `${clientX - box.left}px`;
      label.style.top = `${clientY - box.top}px`;
    });
  });
  canvas.addEventListener('pointerleave', () => { label.hidden = true; });
}

function setUpPicking() {
  const canvas = $('canvas');
  let down = null;
  canvas.addEventListener('pointerdown', (event) => { down = [event.clientX, event.clientY]; });
  canvas.addEventListener('pointerup', (event) => {
    if (!down || Math.hypot(event.clientX - down[0], event.clientY - down[1]) > 4) return;  // a drag
    if (!state.labels) return;
    const face = view.pick(event.clientX, event.clientY);
    if (editing.pick(face)) return;  // merge or paint mode
    const label = face >= 0 ? state.labels[face] : -1;
    select(label === state.selected ? -1 : label);
  });
}

const editing = setUpEditing({
  state, view, select, showError, partColor,
  show: (body, request, labels, selected) => {
    state.selected = selected;  // painted with the selection at once: one recolouring
    applySegmentation(body, request, labels, true);
    select(state.selected, false);
  },
});
window.shdfViewer.editing = editing;
window.shdfViewer.unwrap = setUpUnwrap({
  state, showError,
  save: (blob, suffix) => saveBlob(blob, `${stem()}${suffix}`),
  editCount: () => editing.document().length,
});
setUpControls();
setUpFileInput();
setUpPicking();
setUpHover();
setUpLabelers();
setStatus('empty');
if ($('message').dataset.code === 'three_missing') {  // three.js came, after a long wait
  clearError();
  $('file-input').disabled = false;
  $('empty-hint').textContent = 'Open or drop a mesh to segment it';
}
window.shdfViewer.openFile = openFile;
window.shdfViewer.select = select;
window.shdfViewer.controlValues = controlValues;
window.shdfViewer.refreshLabelers = refreshLabelers;
window.shdfViewer.chooseLabeler = chooseLabeler;
window.shdfViewer.smoothingPosition = smoothingPosition;
window.shdfViewer.smoothingValues = SMOOTHING_VALUES;
window.shdfViewer.ready = true;
