// A classic script (it runs when the viewer's modules cannot): if three.js does not load,
// main.js never runs and the page would look normal but do nothing. Say so, and how to fix it.
(function () {
  const WAIT_MS = 10000;
  let failed = false;

  function config() {
    try {
      return JSON.parse(document.getElementById('viewer-config').textContent);
    } catch (_) {
      return {};
    }
  }

  function show(title, text) {
    const box = document.getElementById('message');
    if (!box) return;
    box.replaceChildren();
    const head = document.createElement('b');
    head.textContent = title;
    const body = document.createElement('p');
    body.textContent = text;
    box.append(head, body);
    box.dataset.code = 'three_missing';
    box.hidden = false;
    document.getElementById('empty-hint').textContent = title;
    const input = document.getElementById('file-input');
    if (input) input.disabled = true;
    document.body.dataset.status = 'no-three';
  }

  function check(final) {
    if (window.shdfViewer && window.shdfViewer.ready) return;
    const { threeHelp = '', threeUrl = '' } = config();
    if (final || failed) {
      show('The viewer could not load three.js', threeHelp);
    } else {
      show('Still loading three.js…', `from ${threeUrl}. ${threeHelp}`);
    }
  }

  // The module graph (main.js and three.js) failing to load fires `error` on its script.
  window.addEventListener('error', (event) => {
    const target = event.target;
    if (target instanceof HTMLScriptElement && target.type === 'module') {
      failed = true;
      if (document.readyState !== 'loading') check(true);
    }
  }, true);
  // Module scripts run before `load`: by then the viewer is ready or will never be.
  window.addEventListener('load', () => check(true));
  // A CDN that does not answer holds `load` back: say what the page waits for.
  setTimeout(() => { if (document.readyState !== 'complete') check(false); }, WAIT_MS);
})();
