"""Named parts in the web viewer, in real Chromium against a real `neural-shdf serve`: pick a
stored labeller (listed from the API) or upload one, see its label names in the parts table
and under the pointer, the colours and labels of the API's answer.

Skipped with the reason where Chromium, its driver, selenium or the npm copy of three.js
is missing (as tests/api/test_viewer_browser.py).
"""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import numpy as np
import pytest

from tests.api.api_helpers import TEST_METHOD
from tests.api.test_viewer_browser import rgb
from tests.api.test_viewer_editing_browser import FACE_ON_SCREEN
from tests.api.viewer_browser import ViewerPage, browser_marks, neural_shdf_serve
from tests.labeling.helpers import BALL, NECK, labelled_dumbbell, obj_of, small_labeler_file

pytestmark = browser_marks()


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with neural_shdf_serve(
        tmp_path_factory.mktemp("labeler-cache"), default_method=TEST_METHOD
    ) as (base, _):
        yield base


@pytest.fixture
def page(server: str) -> Iterator[ViewerPage]:
    with ViewerPage(server) as viewer:
        yield viewer


def hover_text(page: ViewerPage, part: int) -> tuple[str, int]:
    """Move the real pointer over a face of part ``part`` (an index of the page's parts);
    the label the page shows there, and that face."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    x, y, face = page.js(FACE_ON_SCREEN, part)
    canvas = page.driver.find_element(By.ID, "canvas")
    size = canvas.size
    ActionChains(page.driver).move_to_element_with_offset(
        canvas, int(x - size["width"] / 2), int(y - size["height"] / 2)
    ).perform()
    text = page.wait_for(
        "const l = document.getElementById('hover-label'); return !l.hidden && l.textContent"
    )
    return text, face


def test_a_listed_labeler_names_the_parts_in_the_table_and_under_the_pointer(
    page, server, tmp_path
):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    stored = httpx.post(
        f"{server}/v1/labelers", files={"file": ("l.npz", small_labeler_file())}, timeout=60
    ).json()
    mesh, truth = labelled_dumbbell(1500, 0.9, 3)
    path = tmp_path / "dumbbell.obj"
    path.write_bytes(obj_of(mesh))
    page.open()
    page.wait_for("return document.getElementById('labeler').options.length === 2")
    page.upload(path)
    assert page.message() is None
    assert page.js("return window.shdfViewer.state.body.labeler_id") is None  # a segmentation
    page.js("window.__segmented = []")
    Select(page.driver.find_element(By.ID, "labeler")).select_by_value(stored["labeler_id"])
    page.wait_for(
        "return window.__segmented.length > 0 && document.body.dataset.status === 'ready'"
    )
    assert page.js("return document.getElementById('labeler-names').textContent") == "neck, ball"
    assert page.js("return document.getElementById('clusters').disabled")
    names = page.js(
        "return Array.from(document.querySelectorAll('#parts-table .part-name'), "
        "c => c.textContent)"
    )
    assert names == ["neck", "ball"]
    # The page's labels are the API's for the same request, drawn in the API's colours.
    api = httpx.post(
        f"{server}/v1/segment",
        json={"mesh_id": page.js("return window.shdfViewer.state.meshId"),
              "method": TEST_METHOD, "labeler_id": stored["labeler_id"]},
        timeout=120,
    ).json()  # fmt: skip
    shown = page.segmentation()
    assert page.js("return Array.from(window.shdfViewer.state.faceValues)") == api["labels"]
    assert np.mean(np.array(api["labels"]) == truth) > 0.95
    palette = np.array([rgb(part["color"]) for part in api["parts"]])
    drawn = np.asarray(shown["colors"]).reshape(-1, 3)
    np.testing.assert_array_equal(drawn, palette[np.asarray(shown["labels"])[shown["faceOrigin"]]])
    for index, name in enumerate(["neck", "ball"]):
        text, face = hover_text(page, index)
        assert text.startswith(name), text
        assert text == f"{name} · {api['confidence'][face]:.2f}"
    # Back to a segmentation: numbered parts, the controls back on.
    Select(page.driver.find_element(By.ID, "labeler")).select_by_value("")
    page.wait_for("return window.shdfViewer.state.body.labeler_id === undefined "
                  "|| window.shdfViewer.state.body.labeler_id === null")  # fmt: skip
    assert not page.js("return document.getElementById('clusters').disabled")
    assert {NECK, BALL} == set(stored["label_values"])


def test_a_labeler_uploaded_in_the_page_is_listed_and_chosen(page, server, tmp_path):
    from selenium.webdriver.common.by import By

    page.open()
    file = tmp_path / "parts.npz"
    file.write_bytes(small_labeler_file())
    page.driver.find_element(By.ID, "labeler-input").send_keys(str(file))
    chosen = page.wait_for("return document.getElementById('labeler').value")
    listed = httpx.get(f"{server}/v1/labelers", timeout=30).json()["labelers"]
    assert chosen in [entry["labeler_id"] for entry in listed]
    assert page.js("return document.getElementById('labeler-names').textContent") == "neck, ball"
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a labeller")
    page.driver.find_element(By.ID, "labeler-input").send_keys(str(bad))
    message = page.wait_for("const m = document.getElementById('message'); "
                            "return !m.hidden && m.textContent")  # fmt: skip
    assert "not a labeller file" in message
    assert page.js("return document.getElementById('labeler').value") == chosen
    errors = [
        e for e in page.read_console() if e["level"] == "SEVERE" and "422" not in e["message"]
    ]
    assert errors == []
