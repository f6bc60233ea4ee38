"""The web viewer in real Chromium against a real `neural-shdf serve` process.

Skipped with the reason where Chromium, its driver, selenium or the npm copy of three.js
(`npm ci` in service/neural_shdf/viewer; `bash scripts/test` runs it) is missing.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
import trimesh

from neural_shdf.api.viewer import VIEWER_DIR
from neural_shdf.mesh_io import load_mesh
from neural_shdf.palette import linear_color_bytes, srgb_to_linear
from tests.api.api_helpers import TEST_METHOD, obj_bytes
from tests.api.viewer_browser import ViewerPage, browser_marks, neural_shdf_serve

pytestmark = browser_marks()

#: Meshes above this many triangles go through a job (the page polls it).
SYNC_FACES = 2000
MAX_UPLOAD = 3_000_000


def dumbbell_of_quads(rings: int, segments: int) -> tuple[np.ndarray, list[list[int]]]:
    """Two balls on a thin neck, a surface of revolution made of quads with triangle-fan caps."""
    t = np.linspace(0.0, 1.0, rings)
    z = 4.0 * t - 2.0
    radius = np.where(
        np.abs(z) > 0.7, np.sqrt(np.clip(1.0 - (np.abs(z) - 1.3) ** 2 / 0.49, 0, 1)), 0.2
    )
    radius = np.maximum(radius, 0.2)
    radius[0] = radius[-1] = 0.0
    angles = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    vertices = [[0.0, 0.0, z[0]]]
    for ring in range(1, rings - 1):
        for a in angles:
            vertices.append([radius[ring] * np.cos(a), radius[ring] * np.sin(a), z[ring]])
    vertices.append([0.0, 0.0, z[-1]])
    index = lambda ring, s: 1 + (ring - 1) * segments + s % segments  # noqa: E731
    polygons = [[0, index(1, s + 1), index(1, s)] for s in range(segments)]
    for ring in range(1, rings - 2):
        for s in range(segments):
            polygons.append(
                [index(ring, s), index(ring, s + 1), index(ring + 1, s + 1), index(ring + 1, s)]
            )
    top = len(vertices) - 1
    polygons += [[index(rings - 2, s), index(rings - 2, s + 1), top] for s in range(segments)]
    return np.array(vertices), polygons


@pytest.fixture(scope="module")
def meshes(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("meshes")
    small = folder / "small.obj"
    small.write_bytes(obj_bytes(*dumbbell_of_quads(24, 24)))  # 528 polygons, 576 triangles
    large = folder / "large.obj"
    large.write_bytes(obj_bytes(*dumbbell_of_quads(60, 48)))  # 2,784 polygons, above SYNC_FACES
    broken = folder / "broken.obj"
    broken.write_bytes(b"v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    text = folder / "notes.txt"
    text.write_text("not a mesh\n")
    huge = folder / "huge.obj"
    huge.write_bytes(b"v 0 0 0\n" * (MAX_UPLOAD // 8 + 10))
    return {"small": small, "large": large, "broken": broken, "text": text, "huge": huge}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with neural_shdf_serve(
        tmp_path_factory.mktemp("viewer-cache"),
        default_method=TEST_METHOD,
        sync_face_threshold=SYNC_FACES,
        max_upload_bytes=MAX_UPLOAD,
    ) as (base, _):
        yield base


@pytest.fixture(scope="module")
def browser(server: str, tmp_path_factory: pytest.TempPathFactory) -> Iterator[ViewerPage]:
    downloads = tmp_path_factory.mktemp("downloads")
    with ViewerPage(server) as page:
        page.driver.execute_cdp_cmd(
            "Browser.setDownloadBehavior", {"behavior": "allow", "downloadPath": str(downloads)}
        )
        page.downloads = downloads
        yield page


@pytest.fixture
def page(browser: ViewerPage) -> ViewerPage:
    """The viewer freshly opened, the console emptied."""
    browser.open()
    browser.read_console()
    return browser


def api_labels(server: str, mesh_id: str, controls: dict) -> dict:
    body = {"mesh_id": mesh_id, "method": TEST_METHOD, **controls}
    response = httpx.post(f"{server}/v1/segment", json=body, timeout=120)
    assert response.status_code == 200, response.text
    return response.json()


def rgb(hex_color: str) -> list[int]:
    return [int(hex_color[i : i + 2], 16) for i in (1, 3, 5)]


def assert_colours_match(shown: dict, body: dict) -> None:
    """Each drawn triangle has the API colour of the API label of its input face."""
    assert shown["labels"] == body["labels"]
    labels = np.asarray(body["labels"])[np.asarray(shown["faceOrigin"])]
    palette = np.array([rgb(p["color"]) for p in body["parts"]])
    colors = np.asarray(shown["colors"]).reshape(-1, 3)
    np.testing.assert_array_equal(colors, palette[labels])


def controls_of(shown: dict, **extra) -> dict:
    controls = dict(shown["controls"])
    controls["parts"] = extra.pop("parts", None)
    controls.update(refine=False, boundary_smoothing=False, **extra)
    return controls


def rendered_hues(page: ViewerPage) -> np.ndarray:
    """Share of the coloured pixels in each of 24 hue buckets, read back from WebGL."""
    counts = page.js(
        """
        const view = window.shdfViewer.view;
        view.render();
        const gl = view.renderer.getContext();
        const w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
        const px = new Uint8Array(w * h * 4);
        gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
        const counts = new Array(24).fill(0);
        for (let i = 0; i < px.length; i += 4) {
          const r = px[i] / 255, g = px[i + 1] / 255, b = px[i + 2] / 255;
          const max = Math.max(r, g, b), min = Math.min(r, g, b);
          if (max - min < 0.12) continue;  // greys: background, shading, unlabeled
          let hue = max === r ? (g - b) / (max - min) : max === g ? 2 + (b - r) / (max - min)
            : 4 + (r - g) / (max - min);
          counts[Math.floor(((hue * 60 + 360) % 360) / 15)]++;
        }
        return counts;
        """
    )
    counts = np.asarray(counts, dtype=float)
    return counts / max(counts.sum(), 1.0)


def shdf_computations(server: str) -> float:
    """The service's count of ShDF computations (Prometheus)."""
    prefix = f'neural_shdf_shdf_computations_total{{method="{TEST_METHOD}"}}'
    lines = httpx.get(f"{server}/metrics").text.splitlines()
    return sum(float(line.split()[-1]) for line in lines if line.startswith(prefix))


def severe(page: ViewerPage) -> list[dict]:
    return [entry for entry in page.read_console() if entry["level"] == "SEVERE"]


def test_upload_job_parts_slider_recolours_to_the_api_labels(page, server, meshes, tmp_path):
    page.js(
        "window.__statuses = []; new MutationObserver(() => "
        "__statuses.push(document.body.dataset.status)).observe(document.body, "
        "{attributes: true, attributeFilter: ['data-status']});"
        "window.__progress = []; new MutationObserver(() => __progress.push("
        "document.getElementById('progress-label').textContent)).observe("
        "document.getElementById('progress-label'), {childList: true});"
    )
    page.upload(meshes["large"])
    assert page.status() == "ready", page.message()
    statuses = page.js("return window.__statuses")
    assert statuses[:3] == ["uploading", "computing", "loading"], statuses
    progress = page.js("return window.__progress")
    assert any(p.startswith("Uploading large.obj") for p in progress), progress
    assert any(p.startswith(("Computing the ShDF", "Queued")) for p in progress), progress

    shown = page.segmentation()
    mesh_id = page.js("return window.shdfViewer.state.meshId")
    mesh = load_mesh(meshes["large"].read_bytes(), "obj")
    assert shown["faceOrigin"] == mesh.face_origin.tolist()  # quads: 2 triangles each
    assert_colours_match(shown, api_labels(server, mesh_id, controls_of(shown)))
    hues_before = rendered_hues(page)
    assert (hues_before > 0.01).sum() >= 2  # at least two part colours on screen
    computed = shdf_computations(server)

    detail = page.release_slider("parts", 2)  # a cut of the graph cut's part tree
    assert detail["request"]["parts"] == 2 and detail["parts"] == 2
    tree_cut = page.segmentation()
    assert_colours_match(tree_cut, api_labels(server, mesh_id, controls_of(tree_cut, parts=2)))
    detail = page.release_slider("partitioner", "metis")
    assert detail["request"]["partitioner"] == "metis" and detail["parts"] == 2
    detail = page.release_slider("parts", 3)
    assert detail["reason"] == "release" and detail["parts"] == 3
    moved = page.segmentation()
    body = api_labels(server, mesh_id, controls_of(moved, partitioner="metis", parts=3))
    assert body["part_count"] == 3
    assert_colours_match(moved, body)
    assert moved["colors"] != shown["colors"]
    hues_after = rendered_hues(page)
    assert np.abs(hues_after - hues_before).sum() > 0.1, (hues_before, hues_after)

    detail = page.release_slider("clusters", 4)  # still metis, new mixture
    assert detail["request"]["clusters"] == 4
    assert_colours_match(
        page.segmentation(),
        api_labels(server, mesh_id, controls_of(page.segmentation(), parts=3, clusters=4)),
    )
    # Recoloured in place: the geometry and the ShDF were fetched once, never recomputed.
    fetched = page.js(
        "return performance.getEntriesByType('resource').map(e => new URL(e.name).pathname)"
    )
    assert sum(p.endswith("/geometry") for p in fetched) == 1
    assert sum(p.endswith("/shdf") for p in fetched) == 1
    assert shdf_computations(server) == computed
    assert severe(page) == []
    shot = page.screenshot(tmp_path / "viewer.png")
    assert shot.stat().st_size > 10_000
    print(f"screenshot: {shot}")


def segment_requests(page: ViewerPage) -> int:
    """POST /v1/segment requests the page has made so far."""
    return page.js(
        "return performance.getEntriesByType('resource')"
        ".filter(e => new URL(e.name).pathname === '/v1/segment').length"
    )


def assert_table_matches(page: ViewerPage, body: dict) -> None:
    """The parts table and the page's parts: the API's faces, area and mean ShDF per part."""
    shown = page.segmentation()["parts"]
    assert [p["label"] for p in shown] == [p["label"] for p in body["parts"]]
    assert [p["color"] for p in shown] == [p["color"] for p in body["parts"]]
    assert [p["faces"] for p in shown] == [p["faces"] for p in body["parts"]]
    for key in ("area", "mean_shdf"):
        np.testing.assert_allclose(
            [p[key] for p in shown], [p[key] for p in body["parts"]], rtol=1e-4, atol=1e-6
        )
    rows = page.js(
        "return Array.from(document.querySelectorAll('#parts-table tbody tr'),"
        " r => Array.from(r.cells, c => c.textContent.trim()).slice(1, 3))"
    )
    assert rows == [[str(p["label"]), f"{p['faces']:,}"] for p in body["parts"]]


def test_parts_slider_recuts_the_part_tree_without_a_request(page, server, meshes):
    """Graph cut: moving the parts slider recolours from the answer's part tree, no request;
    labels, colours and the parts table equal the API's answer for that part count."""
    page.upload(meshes["large"])  # quads: two triangles per input face
    assert page.status() == "ready", page.message()
    mesh_id = page.js("return window.shdfViewer.state.meshId")
    tree = page.js("return window.shdfViewer.state.body.hierarchy")
    assert tree is not None and tree["leaf_count"] >= 4, tree
    assert page.js("return Number(document.getElementById('parts').max)") == tree["leaf_count"]
    sent = segment_requests(page)
    counts = sorted({1, 2, 3, tree["leaf_count"] - 1, tree["leaf_count"]})
    for count in [*counts, 0]:  # 0: back to "auto"
        detail = page.release_slider("parts", count)
        assert detail["recut"] and detail["request"]["parts"] == (count or None)
        shown = page.segmentation()
        body = api_labels(server, mesh_id, controls_of(shown, parts=count or None))
        assert detail["parts"] == body["part_count"]
        assert_colours_match(shown, body)
        assert_table_matches(page, body)
    assert detail["parts"] == tree["automatic_parts"]
    assert segment_requests(page) == sent  # the page asked nothing for any of them
    assert page.js("return document.getElementById('parts-out').textContent") == "auto"

    detail = page.release_slider("clusters", 4)  # a new mixture: a new tree from the service
    assert not detail.get("recut") and segment_requests(page) == sent + 1
    detail = page.release_slider("parts", 2)
    assert detail["recut"] and segment_requests(page) == sent + 1
    shown = page.segmentation()
    assert_colours_match(shown, api_labels(server, mesh_id, controls_of(shown, parts=2)))
    assert severe(page) == []


def test_a_newer_slider_value_supersedes_the_request_in_flight(page, server, meshes):
    page.upload(meshes["small"])
    events = page.driver.execute_async_script(
        """
        const done = arguments[0];
        const seen = [];
        addEventListener('shdf:segmented', (e) => seen.push(e.detail));
        const input = document.getElementById('smoothing');
        for (const value of [0.5, 0.05]) {
          input.value = String(window.shdfViewer.smoothingPosition(value));
          input.dispatchEvent(new Event('change'));
        }
        setTimeout(() => done(seen), 3000);
        """
    )
    assert [e["request"]["smoothing"] for e in events] == [0.05]
    shown = page.segmentation()
    mesh_id = page.js("return window.shdfViewer.state.meshId")
    assert_colours_match(shown, api_labels(server, mesh_id, controls_of(shown)))
    assert severe(page) == []


def test_click_a_part_shows_it_and_hides_or_isolates_it(page, server, meshes):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    page.upload(meshes["small"])
    shown = page.segmentation()
    labels = np.asarray(shown["labels"])[np.asarray(shown["faceOrigin"])]
    # The screen position of a triangle of the largest part, facing the camera.
    target = int(np.bincount(labels).argmax())
    x, y = page.js(
        """
        const [label] = arguments;
        const v = window.shdfViewer;
        const position = v.view.mesh.geometry.getAttribute('position');
        const origin = v.view.faceOrigin, labels = v.state.labels;
        const camera = v.view.camera, canvas = v.view.canvas;
        const toCamera = camera.position.clone();
        let best = null;
        for (let t = 0; t < origin.length; t++) {
          if (labels[origin[t]] !== label) continue;
          const p = [0, 1, 2].map(
            (k) => camera.position.clone().fromBufferAttribute(position, 3 * t + k));
          const centre = p[0].clone().add(p[1]).add(p[2]).multiplyScalar(1 / 3);
          const normal = p[1].clone().sub(p[0]).cross(p[2].clone().sub(p[0])).normalize();
          const facing = normal.dot(toCamera.clone().sub(centre).normalize());
          if (!best || facing > best.facing) best = { facing, centre };
        }
        const ndc = best.centre.clone().project(camera);
        const rect = canvas.getBoundingClientRect();
        return [(ndc.x + 1) / 2 * rect.width, (1 - ndc.y) / 2 * rect.height];
        """,
        target,
    )
    canvas = page.driver.find_element(By.ID, "canvas")
    size = canvas.size
    ActionChains(page.driver).move_to_element_with_offset(
        canvas, int(x - size["width"] / 2), int(y - size["height"] / 2)
    ).click().perform()
    selected = page.js("return window.shdfViewer.state.selected")
    assert selected == target
    part = shown["parts"][target]
    assert page.js("return document.getElementById('selection').hidden") is False
    text = page.js("return document.getElementById('selection').textContent")
    assert f"Part {target}" in text and f"{part['faces']:,}" in text
    assert f"{part['mean_shdf']:.3f}" in text
    dimmed = np.asarray(page.segmentation()["colors"]).reshape(-1, 3)
    palette = np.array([rgb(p["color"]) for p in shown["parts"]])
    np.testing.assert_array_equal(dimmed[labels == target], palette[labels[labels == target]])
    assert (dimmed[labels != target].sum(1) < palette[labels[labels != target]].sum(1)).all()

    count = "const i = window.shdfViewer.view.mesh.geometry.index; return i ? i.count : null"
    page.js("document.getElementById('selection-hide').click()")
    assert page.js(count) == 3 * int((labels != target).sum())
    page.js("document.getElementById('selection-isolate').click()")
    assert page.js(count) == 3 * int((labels == target).sum())
    page.js("document.getElementById('show-all').click()")
    assert page.js(count) is None
    assert severe(page) == []


def wait_file(folder: Path, name: str, timeout_s: float = 30) -> Path:
    path = folder / name
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.is_file() and not (folder / f"{name}.crdownload").exists():
            return path
        time.sleep(0.1)
    raise AssertionError(f"{name} was not downloaded: {sorted(p.name for p in folder.iterdir())}")


def test_downloads_hold_the_shown_segmentation(page, meshes):
    page.upload(meshes["small"])
    shown = page.segmentation()
    for button in ("seg", "json", "colored", "parts"):
        page.js(f"document.getElementById('download-{button}').click()")
    folder = page.downloads
    seg = wait_file(folder, "small.seg").read_text().split()
    assert [int(v) for v in seg] == shown["labels"]
    document = json.loads(wait_file(folder, "small-segmentation.json").read_text())
    assert document["labels"] == shown["labels"] and document["parts"] == shown["parts"]
    colored = trimesh.load(wait_file(folder, "small-colored.glb"), file_type="glb", force="mesh")
    # glTF's COLOR_0 is linear: the API's sRGB colours converted.
    expected = {tuple(linear_color_bytes(rgb(p["color"])).tolist()) for p in shown["parts"]}
    assert {tuple(c) for c in colored.visual.vertex_colors[:, :3].tolist()} == expected
    scene = trimesh.load(wait_file(folder, "small-parts.glb"), file_type="glb")
    assert len(scene.geometry) == len(shown["parts"])
    assert severe(page) == []


def test_service_errors_are_shown_as_messages(page, server, meshes):
    page.upload(meshes["text"])
    assert "Unsupported format" in page.message() and ".obj" in page.message()
    page.upload(meshes["huge"])
    assert "Too large" in page.message() and "2.9 MB" in page.message()
    page.upload(meshes["broken"])
    expected = httpx.post(
        f"{server}/v1/meshes", files={"file": ("broken.obj", meshes["broken"].read_bytes())}
    ).json()["error"]["message"]
    assert "Unusable mesh" in page.message() and expected in page.message()
    assert page.status() == "error"


def test_dropped_file_and_shdf_heat_map(page, server, meshes):
    page.js("window.__segmented = []; addEventListener('shdf:segmented', e => __segmented.push(1))")
    page.js(
        """
        const [name, text] = arguments;
        const transfer = new DataTransfer();
        transfer.items.add(new File([text], name));
        dispatchEvent(new DragEvent('dragenter', { dataTransfer: transfer }));
        if (document.getElementById('drop-overlay').hidden) throw new Error('no drop overlay');
        dispatchEvent(new DragEvent('drop', { dataTransfer: transfer }));
        """,
        "dropped.obj",
        meshes["small"].read_text(),
    )
    page.wait_for("return __segmented.length > 0 && document.body.dataset.status === 'ready'")
    assert page.js("return window.shdfViewer.state.meta.filename") == "dropped.obj"
    assert page.js("return document.getElementById('drop-overlay').hidden") is True

    page.js("document.querySelector('input[name=view][value=shdf]').click()")
    assert page.js("return document.getElementById('shdf-legend').hidden") is False
    shown = page.segmentation()
    mesh_id = page.js("return window.shdfViewer.state.meshId")
    shdf = np.frombuffer(
        httpx.get(f"{server}/v1/meshes/{mesh_id}/shdf", params={"format": "f32"}).content, "<f4"
    )
    values = shdf[np.asarray(shown["faceOrigin"])]
    colors = np.asarray(shown["colors"], dtype=float).reshape(-1, 3)
    luminance = colors @ [0.2126, 0.7152, 0.0722]  # viridis brightens monotonically
    assert np.corrcoef(values, luminance)[0, 1] > 0.95
    _, first = np.unique(values, return_index=True)
    same = {float(v): tuple(colors[i]) for v, i in zip(values[first], first, strict=True)}
    assert all(same[float(v)] == tuple(c) for v, c in zip(values, colors, strict=True))

    page.js("document.querySelector('input[name=view][value=plain]').click()")
    plain = np.asarray(page.segmentation()["colors"]).reshape(-1, 3)
    assert len(np.unique(plain, axis=0)) == 1
    assert severe(page) == []


def test_dragging_keeps_one_request_in_flight_and_ends_on_the_released_value(page, server, meshes):
    """Answers are slowed down in the page (a slow service): while dragging, the page never
    aborts one request for the next; the release still wins."""
    page.upload(meshes["small"])
    result = page.driver.execute_async_script(
        """
        const done = arguments[0];
        const original = window.fetch;
        const pause = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
        const signals = [];
        window.fetch = (url, options = {}) => {
          if (!String(url).endsWith('/v1/segment')) return original(url, options);
          signals.push(options.signal);
          return original(url, options).then((response) => pause(600).then(() => response));
        };
        const input = document.getElementById('smoothing');
        const position = window.shdfViewer.smoothingPosition;
        (async () => {
          for (const value of [0.1, 0.12, 0.14, 0.16, 0.18, 0.2]) {
            input.value = String(position(value));  // held still past the page's 150 ms each time
            input.dispatchEvent(new Event('input'));
            await pause(200);
          }
          const last = new Promise((resolve) => addEventListener('shdf:segmented', (e) => {
            if (e.detail.request.smoothing === 0.3) resolve(e.detail);
          }));
          input.value = String(position(0.3));
          input.dispatchEvent(new Event('input'));
          input.dispatchEvent(new Event('change'));
          const detail = await last;
          window.fetch = original;
          done({
            sent: signals.length,
            abortedBeforeRelease: signals.slice(0, -1).filter((s) => s.aborted).length,
            reason: detail.reason,
          });
        })();
        """
    )
    # 1.2 s of dragging, 0.6 s per answer: two drag requests, then the release.
    assert result["sent"] <= 4, result
    assert result["abortedBeforeRelease"] <= 1, result  # only the release aborts one
    assert result["reason"] == "release"
    shown = page.segmentation()
    assert shown["controls"]["smoothing"] == 0.3
    mesh_id = page.js("return window.shdfViewer.state.meshId")
    assert_colours_match(shown, api_labels(server, mesh_id, controls_of(shown)))
    assert severe(page) == []


#: The stage's background (scene.js), as the screen shows it.
BACKGROUND = np.array([0xF3, 0xF4, 0xF6])


def stage_pixels(page: ViewerPage, shot: np.ndarray) -> np.ndarray:
    """(N, 3) pixels of the mesh on the canvas: not the background, not under the tools."""
    scale = shot.shape[1] / page.js("return innerWidth")
    canvas, tools = page.rect("#canvas"), page.rect("#view-tools")
    box = lambda r: tuple(int(round(r[k] * scale)) for k in ("left", "top", "right", "bottom"))  # noqa: E731
    left, top, right, bottom = box(canvas)
    mask = np.zeros(shot.shape[:2], dtype=bool)
    mask[top:bottom, left:right] = True
    t_left, t_top, t_right, t_bottom = box(tools)
    mask[max(t_top - 2, 0) : t_bottom + 2, max(t_left - 2, 0) : t_right + 2] = False
    mask &= np.abs(shot.astype(int) - BACKGROUND).max(axis=-1) > 8
    return shot[mask].astype(int)


def chromaticity(srgb: np.ndarray) -> np.ndarray:
    """Linear RGB over its sum: what white light of any strength leaves unchanged."""
    linear = srgb_to_linear(np.asarray(srgb) / 255.0)
    return linear / linear.sum(axis=-1, keepdims=True)


def test_screen_colours_are_the_api_colours_and_the_swatches(page, server, meshes):
    """A real screenshot: flat, the mesh is drawn in exactly the API's colours and the parts
    table's swatches; shaded, in their hues; the heat map in the legend's colours."""
    page.upload(meshes["small"])
    set_up_axis(page, "z")  # the dumbbell along z stands: every part in sight
    mesh_id = page.js("return window.shdfViewer.state.meshId")
    body = api_labels(server, mesh_id, controls_of(page.segmentation()))
    palette = np.array([rgb(p["color"]) for p in body["parts"]])
    assert len(palette) >= 2

    page.js("document.getElementById('flat').click()")
    flat = stage_pixels(page, page.pixels())
    distance = np.abs(flat[:, None, :] - palette[None]).max(axis=-1)  # (pixels, parts)
    assert (distance.min(axis=1) <= 1).mean() > 0.9  # the rest: anti-aliased edges
    drawn = np.bincount(distance.argmin(axis=1)[distance.min(axis=1) <= 1], minlength=len(palette))
    assert (drawn > 100).all(), drawn  # every part on screen, in its API colour

    shot = page.pixels()
    scale = shot.shape[1] / page.js("return innerWidth")
    for label, colour in enumerate(palette):
        swatch = page.rect(f'#parts-table tr[data-label="{label}"] .swatch')
        x = int((swatch["left"] + swatch["right"]) / 2 * scale)
        y = int((swatch["top"] + swatch["bottom"]) / 2 * scale)
        assert np.abs(shot[y, x].astype(int) - colour).max() <= 1, (label, shot[y, x], colour)

    # Lit: white lights scale linear RGB, so each pixel keeps its part's linear chromaticity
    # (sRGB bytes drawn as if linear shift it by 0.1 and more: orange turns yellow).
    page.js("document.getElementById('flat').click()")
    lit = stage_pixels(page, page.pixels())
    lit = lit[lit.max(axis=1) > 60]  # dark pixels: too few levels for a ratio
    gap = np.abs(chromaticity(lit)[:, None, :] - chromaticity(palette)[None]).max(axis=-1)
    assert (gap.min(axis=1) < 0.03).mean() > 0.85, np.percentile(gap.min(axis=1), [50, 90])

    # The heat map, flat, in the colours of its legend.
    page.js("document.querySelector('input[name=view][value=shdf]').click()")
    page.js("document.getElementById('flat').click()")
    shot = page.pixels()
    ramp = page.rect("#shdf-legend .ramp")
    row = int((ramp["top"] + ramp["bottom"]) / 2 * scale)
    legend = shot[row, int(ramp["left"] * scale) + 2 : int(ramp["right"] * scale) - 2].astype(int)
    heat = stage_pixels(page, shot)
    heat = heat[np.abs(heat - BACKGROUND).max(axis=1) > 20]
    gap = np.abs(heat[:, None, :] - legend[None]).max(axis=-1).min(axis=1)
    assert (gap <= 4).mean() > 0.9, np.percentile(gap, [50, 90])
    page.js("document.getElementById('flat').click()")
    set_up_axis(page, "y")
    assert severe(page) == []


def set_up_axis(page: ViewerPage, axis: str) -> None:
    """Choose the up axis as a user would (the page remembers it)."""
    page.js(
        "const s = document.getElementById('up-axis'); s.value = arguments[0];"
        "s.dispatchEvent(new Event('change'))",
        axis,
    )


def test_a_missing_three_js_says_so_and_names_the_fix(page):
    """three.js unreachable (blocked, as offline): a message naming `npm ci`, no dead page."""
    driver = page.driver
    driver.execute_cdp_cmd("Network.enable", {})
    driver.execute_cdp_cmd("Network.setBlockedURLs", {"urls": ["*/viewer/three/*"]})
    try:
        driver.get(f"{page.base_url}/viewer/")
        page.wait_for("return document.body.dataset.status === 'no-three'", timeout_s=30)
        message = page.message()
        assert "could not load three.js" in message and "npm ci" in message
        assert str(VIEWER_DIR) in message and "NEURAL_SHDF_VIEWER_THREE_DIR" in message
        assert page.js("return document.getElementById('file-input').disabled") is True
        assert "three.js" in page.js("return document.getElementById('empty-hint').textContent")
    finally:
        driver.execute_cdp_cmd("Network.setBlockedURLs", {"urls": []})
        driver.execute_cdp_cmd("Network.disable", {})
    page.open()  # unblocked: the viewer works again
    assert page.message() is None and page.status() == "empty"
    page.read_console()  # the blocked loads' errors


def screen_vector(page: ViewerPage, start: list[float], end: list[float]) -> np.ndarray:
    """Screen pixels (x right, y down) from world point ``start`` to ``end``."""
    return np.asarray(
        page.js(
            """
            const [a, b] = arguments;
            const v = window.shdfViewer.view;
            const rect = v.canvas.getBoundingClientRect();
            const project = (p) => {
              const q = v.camera.position.clone().set(...p).project(v.camera);
              return [(q.x + 1) / 2 * rect.width, (1 - q.y) / 2 * rect.height];
            };
            const [p, q] = [project(a), project(b)];
            return [q[0] - p[0], q[1] - p[1]];
            """,
            start,
            end,
        )
    )


def test_controls_fit_720p_frame_by_up_axis_and_name_the_method(page, server, meshes):
    driver = page.driver
    metrics = {"width": 1280, "height": 720, "deviceScaleFactor": 1, "mobile": False}
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", metrics)
    try:
        page.open()
        page.js("document.getElementById('method').value = 'auto'")
        page.upload(meshes["small"])  # a dumbbell along z
        assert page.status() == "ready", page.message()
        ran = page.js("return window.shdfViewer.state.body.method")
        assert ran in {"exact", "sampled", "neural"}
        stats = page.js("return document.getElementById('mesh-stats').textContent")
        assert stats.endswith(f"ShDF: {ran} (auto)"), stats

        # Every control and download on screen at 1280x720; the ShDF view moves nothing.
        sidebar = page.js(
            "const s = document.getElementById('sidebar');"
            "return [s.scrollHeight - s.clientHeight, s.scrollWidth - s.clientWidth]"
        )
        assert sidebar == [0, 0]
        assert page.rect("#downloads")["bottom"] <= 720
        boxes = ["#sidebar", "#controls", "#downloads", "#canvas", "#parts-panel"]
        before = [page.rect(b) for b in boxes]
        page.js("document.querySelector('input[name=view][value=shdf]').click()")
        assert [page.rect(b) for b in boxes] == before
        page.js("document.querySelector('input[name=view][value=parts]').click()")

        # Smoothing: most of the track for the useful range; the default where it was.
        values = page.js("return window.shdfViewer.smoothingValues")
        assert values == sorted(values) and values[0] == 0 and values[-1] >= 1
        assert sum(0.01 <= v <= 0.2 for v in values) >= len(values) / 2
        assert page.js("return window.shdfViewer.controlValues().smoothing") == 0.06
        detail = page.release_smoothing(0.12)
        assert page.js("return document.getElementById('smoothing-out').textContent") == "0.12"
        assert detail["request"]["smoothing"] == 0.12

        # Up axis: the chosen axis points up on screen; the dumbbell stands with Z up.
        for axis, up in (("y", [0, 1, 0]), ("z", [0, 0, 1])):
            set_up_axis(page, axis)
            dx, dy = screen_vector(page, [0, 0, 0], up)
            assert dy < 0 and abs(dx) < 1e-3 * abs(dy), (axis, dx, dy)
        tall = screen_vector(page, [0, 0, -2], [0, 0, 2])
        wide = screen_vector(page, [-1, 0, 0], [1, 0, 0])
        assert abs(tall[1]) > 1.5 * abs(wide[0])

        # Frame: after orbiting away, the button brings the framed view back.
        framed = page.js("return window.shdfViewer.view.camera.position.toArray()")
        page.js(
            "const v = window.shdfViewer.view; v.camera.position.set(9, 1, 3);v.controls.update()"
        )
        page.js("document.getElementById('frame').click()")
        moved_back = page.js("return window.shdfViewer.view.camera.position.toArray()")
        np.testing.assert_allclose(moved_back, framed, rtol=1e-6)
        page.open()  # the up axis is remembered
        assert page.js("return document.getElementById('up-axis').value") == "z"
    finally:
        page.js("localStorage.clear()")
        driver.execute_cdp_cmd("Emulation.clearDeviceMetricsOverride", {})
    assert severe(page) == []


def test_symmetric_parts_checkbox_sends_symmetry_and_shows_the_apis_labels(page, server, meshes):
    page.upload(meshes["small"])  # a dumbbell: mirror-symmetric
    assert page.status() == "ready", page.message()
    detail = page.release_slider("symmetry", True)
    assert detail["request"]["symmetry"] is True
    shown = page.segmentation()
    mesh_id = page.js("return window.shdfViewer.state.meshId")
    controls = controls_of(shown, symmetry=True)
    controls["crease_boundaries"] = detail["request"]["crease_boundaries"]
    assert_colours_match(shown, api_labels(server, mesh_id, controls))
    assert severe(page) == []


@pytest.mark.parametrize("dtype", ["int8", "int16", "int32"])
def test_base64_labels_decode_the_same_with_and_without_the_native_decoder(page, dtype):
    """The service's packed labels (``pack_integers``) decode to the same Int32Array by
    ``Uint8Array.fromBase64`` and by the plain loop used where a browser lacks it."""
    import base64

    rng = np.random.default_rng(7)
    info = np.iinfo(dtype)
    values = rng.integers(info.min, info.max, 1001, endpoint=True).astype(dtype)
    values[:2] = (info.min, info.max)
    packed = base64.b64encode(values.astype(np.dtype(dtype).newbyteorder("<")).tobytes()).decode()
    page.js(
        """
        window.__decoded = null;
        import('/viewer/static/api.js').then((api) => {
          const native = Array.from(api.decodeIntegers(arguments[0], arguments[1]));
          const own = Uint8Array.fromBase64;
          Uint8Array.fromBase64 = undefined;  // as in a browser without it
          try {
            window.__decoded = [native, Array.from(api.decodeIntegers(arguments[0], arguments[1]))];
          } finally {
            Uint8Array.fromBase64 = own;
          }
        });
        """,
        packed,
        dtype,
    )
    native, looped = page.wait_for("return window.__decoded", timeout_s=30)
    assert native == values.tolist()
    assert looped == values.tolist()
    assert page.js("return typeof Uint8Array.fromBase64") == "function"  # this Chromium has it
