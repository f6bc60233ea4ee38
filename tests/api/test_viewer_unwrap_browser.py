"""Unwrap in the web viewer, in real Chromium against a real `neural-shdf serve`: the "UV
atlas" panel shows the API's atlas PNG for the segmentation on screen (the bytes, and the
parts' colours in a screenshot), follows the size picked, waits for a large mesh's atlas
job, and downloads the unwrapped OBJ.

Skipped with the reason where Chromium, its driver, selenium or the npm copy of three.js
is missing (as tests/api/test_viewer_browser.py).
"""

from __future__ import annotations

import base64
import io
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from neural_shdf.mesh_io import load_mesh
from tests.api.api_helpers import TEST_METHOD, obj_bytes
from tests.api.test_viewer_browser import dumbbell_of_quads, rgb, severe, wait_file
from tests.api.viewer_browser import ViewerPage, browser_marks, neural_shdf_serve

pytestmark = browser_marks()

#: Meshes above this many triangles go through jobs (the ShDF's, then the atlas's).
SYNC_FACES = 2000

# The panel's picture as the page holds it (the blob its <img> shows), base64.
SHOWN_PNG = """
const done = arguments[arguments.length - 1];
fetch(document.getElementById('atlas-image').src).then((r) => r.arrayBuffer()).then((buffer) => {
  let text = '';
  for (const byte of new Uint8Array(buffer)) text += String.fromCharCode(byte);
  done(btoa(text));
});
"""


@pytest.fixture(scope="module")
def meshes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("meshes")
    small = folder / "small.obj"
    small.write_bytes(obj_bytes(*dumbbell_of_quads(24, 24)))  # 528 polygons
    large = folder / "large.obj"
    large.write_bytes(obj_bytes(*dumbbell_of_quads(60, 48)))  # 2,784 polygons: jobs
    return {"small": small, "large": large}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with neural_shdf_serve(
        tmp_path_factory.mktemp("unwrap-cache"),
        default_method=TEST_METHOD,
        sync_face_threshold=SYNC_FACES,
    ) as (base, _):
        yield base


@pytest.fixture(scope="module")
def page(server: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ViewerPage]:
    downloads = tmp_path_factory.mktemp("downloads")
    with ViewerPage(server) as viewer:
        viewer.driver.execute_cdp_cmd(
            "Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)}
        )
        viewer.downloads = downloads
        viewer.open()
        viewer.read_console()
        yield viewer


def unwrap(page: ViewerPage, trigger: str) -> dict:
    """Run ``trigger`` (JavaScript) and wait for the panel's next atlas."""
    return page.driver.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        "addEventListener('shdf:unwrapped', (e) => done(e.detail), { once: true });" + trigger
    )


def api_png(server: str, request: dict, atlas_size: int) -> bytes:
    query = {k: v for k, v in request.items() if k != "mesh_id" and v is not None}
    url = f"{server}/v1/meshes/{request['mesh_id']}/segmentation/atlas.png"
    response = httpx.get(url, params={**query, "atlas_size": atlas_size}, timeout=300)
    assert response.status_code == 200, response.text
    return response.content


def test_the_atlas_panel_shows_the_apis_atlas_of_the_parts_on_screen(page, server, meshes):
    from PIL import Image

    page.upload(meshes["small"])
    assert page.status() == "ready", page.message()
    assert page.js("return document.getElementById('atlas-panel').hidden") is True
    shown = unwrap(page, "document.getElementById('unwrap-open').click();")
    assert shown["atlasSize"] == 1024
    request = page.js("return window.shdfViewer.state.shownRequest")
    assert shown["request"] == request
    png = base64.b64decode(page.driver.execute_async_script(SHOWN_PNG))
    assert png == api_png(server, request, 1024)  # the service's picture, unchanged
    assert page.js("return document.getElementById('atlas-image').naturalWidth") == 1024

    # On screen: the panel's pixels hold every part's colour (charts under a checker of
    # the colour and a darker shade), read from a real screenshot.
    box = page.rect("#atlas-image")
    scale = page.js("return window.devicePixelRatio")
    shot = page.pixels()
    crop = shot[
        int(box["top"] * scale) + 2 : int(box["bottom"] * scale) - 2,
        int(box["left"] * scale) + 2 : int(box["right"] * scale) - 2,
    ].reshape(-1, 3)
    parts = page.segmentation()["parts"]
    for part in parts:
        colour = np.asarray(rgb(part["color"]), dtype=float)
        distance = np.abs(crop.astype(float) - colour).max(axis=1)
        assert (distance <= 12).mean() > 0.0005, (part, crop[:5])
    # The picture is the same size as the API's atlas and its parts fill some of it.
    decoded = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    assert decoded.shape == (1024, 1024, 3) and (decoded != 255).any(axis=2).mean() > 0.2

    smaller = unwrap(
        page,
        "const s = document.getElementById('atlas-size'); s.value = '512';"
        "s.dispatchEvent(new Event('change'));",
    )
    assert smaller["atlasSize"] == 512
    assert page.js("return document.getElementById('atlas-image').naturalWidth") == 512

    page.js("document.getElementById('atlas-obj').click()")
    obj = wait_file(page.downloads, "small-unwrapped.obj", timeout_s=120).read_text()
    mesh = load_mesh(meshes["small"])
    faces = [line for line in obj.splitlines() if line.startswith("f ")]
    assert len(faces) >= mesh.input_face_count
    assert all("/" in corner for corner in faces[0].split()[1:])
    page.js("document.getElementById('atlas-close').click()")
    assert page.js("return document.getElementById('atlas-panel').hidden") is True
    assert severe(page) == []


def test_a_large_meshs_atlas_is_a_job_the_panel_waits_for(page, server, meshes):
    page.open()
    page.upload(meshes["large"])
    assert page.status() == "ready", page.message()
    page.js(
        "window.__atlasStatus = []; new MutationObserver(() => window.__atlasStatus.push("
        "document.getElementById('atlas-status').textContent)).observe("
        "document.getElementById('atlas-status'), { childList: true, characterData: true, "
        "subtree: true })"
    )
    shown = unwrap(page, "document.getElementById('unwrap-open').click();")
    statuses = page.js("return window.__atlasStatus")
    assert any(status.startswith("Unwrapping: ") for status in statuses), statuses
    request = page.js("return window.shdfViewer.state.shownRequest")
    png = base64.b64decode(page.driver.execute_async_script(SHOWN_PNG))
    assert png == api_png(server, request, shown["atlasSize"])
    assert severe(page) == []
