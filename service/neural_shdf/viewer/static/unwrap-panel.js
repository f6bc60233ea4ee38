// Unwrap by parts: the "UV atlas" panel over the stage shows the atlas layout PNG of the
// segmentation on screen (charts coloured by part) and downloads the unwrapped GLB, OBJ
// and PNG. The service charts each part on its own and packs one atlas; a large mesh's
// atlas is a job, whose progress the panel shows.
import * as api from './api.js';

const FILES = { png: 'atlas.png', glb: 'unwrapped.glb', obj: 'unwrapped.obj' };

/** Query of the unwrap routes: the segmentation's parameters plus the atlas's. */
function unwrapQuery(request, atlasSize) {
  const query = new URLSearchParams(api.segmentQuery(request));
  query.set('atlas_size', String(atlasSize));
  return query.toString();
}

/** GET an unwrap file; a 202 (the ShDF's or the atlas's job) is waited for, then repeated. */
export async function getUnwrapFile(meshId, kind, request, atlasSize, onJobProgress = () => {}) {
  const url = `/v1/meshes/${meshId}/segmentation/${FILES[kind]}?${unwrapQuery(request, atlasSize)}`;
  for (;;) {
    const response = await api.checked(await fetch(url));
    if (response.status !== 202) return response.blob();
    await api.waitForJob(await response.json(), onJobProgress);
  }
}

/**
 * Wire the panel. `page`: { state, showError(error, context), save(blob, suffix),
 * editCount() } from main.js. Returns { open(), close(), shown: the last atlas shown or null }.
 */
export function setUpUnwrap(page) {
  const { state } = page;
  const $ = (id) => document.getElementById(id);
  const panel = $('atlas-panel');
  const image = $('atlas-image');
  const unwrap = { shown: null, pending: 0, url: null };

  function setStatus(text) { $('atlas-status').textContent = text; }

  async function load() {
    if (!state.meshId || !state.shownRequest) return null;
    const ticket = ++unwrap.pending;  // a newer request wins
    const request = state.shownRequest;
    const atlasSize = Number($('atlas-size').value);
    const start = performance.now();
    setStatus('Unwrapping…');
    for (const id of ['atlas-glb', 'atlas-obj', 'atlas-png']) $(id).disabled = true;
    try {
      const blob = await getUnwrapFile(state.meshId, 'png', request, atlasSize, (progress, jobState) => {
        if (ticket === unwrap.pending) setStatus(`Unwrapping: ${jobState} ${Math.round(100 * progress)}%`);
      });
      if (ticket !== unwrap.pending) return null;
      if (unwrap.url) URL.revokeObjectURL(unwrap.url);
      unwrap.url = URL.createObjectURL(blob);
      await new Promise((resolve, reject) => {
        image.onload = resolve;
        image.onerror = () => reject(new Error('the atlas picture could not be read'));
        image.src = unwrap.url;
      });
      const ms = performance.now() - start;
      unwrap.shown = { request, atlasSize, bytes: blob.size, ms };
      const edited = page.editCount() ? ' (by the segmentation, without the hand edits)' : '';
      setStatus(`${atlasSize}×${atlasSize} atlas, ${state.body ? state.body.part_count : '?'} parts, ${Math.round(ms)} ms${edited}`);
      for (const id of ['atlas-glb', 'atlas-obj', 'atlas-png']) $(id).disabled = false;
      window.dispatchEvent(new CustomEvent('shdf:unwrapped', { detail: unwrap.shown }));
      return unwrap.shown;
    } catch (error) {
      if (ticket === unwrap.pending) {
        setStatus('');
        page.showError(error, 'unwrap');
      }
      return null;
    }
  }

  async function download(kind) {
    const shown = unwrap.shown;
    if (!shown) return;
    try {
      const blob = await getUnwrapFile(state.meshId, kind, shown.request, shown.atlasSize);
      page.save(blob, kind === 'png' ? '-atlas.png' : `-unwrapped.${kind}`);
    } catch (error) {
      page.showError(error, `unwrapped ${kind.toUpperCase()}`);
    }
  }

  function open() {
    panel.hidden = false;
    return load();
  }

  function close() {
    panel.hidden = true;
    unwrap.pending++;  // an answer still coming is dropped
  }

  addEventListener('shdf:segmented', () => {
    if (!panel.hidden && unwrap.shown && unwrap.shown.request !== state.shownRequest) {
      setStatus('The parts changed: "UV atlas…" unwraps them again');
    }
  });
  $('unwrap-open').onclick = () => open();
  $('atlas-close').onclick = () => close();
  $('atlas-size').onchange = () => load();
  $('atlas-glb').onclick = () => download('glb');
  $('atlas-obj').onclick = () => download('obj');
  $('atlas-png').onclick = () => download('png');

  return { open, close, load, get shown() { return unwrap.shown; } };
}
