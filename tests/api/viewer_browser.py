"""Drive the web viewer in real Chromium (Debian's /usr/bin/chromium and its chromedriver).

Shared by the browser tests and ``benchmarks/bench_viewer.py``; nothing here downloads a browser.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from neural_shdf.api.viewer import VIEWER_DIR
from tests.api.api_helpers import free_port

CHROMIUM = Path(os.environ.get("NEURAL_SHDF_CHROMIUM", "/usr/bin/chromium"))
CHROMEDRIVER = Path(os.environ.get("NEURAL_SHDF_CHROMEDRIVER", "/usr/bin/chromedriver"))
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    # WebGL on the CPU (SwiftShader) without the deprecation warning of the implicit fallback.
    "--enable-unsafe-swiftshader",
    "--window-size=1400,900",
)


def browser_marks() -> list[pytest.MarkDecorator]:
    """``pytestmark`` of a browser test module: slow, and skipped with the reason where
    Chromium, its driver, selenium or the npm copy of three.js is missing."""
    missing = chromium_missing()
    if missing is None and not (VIEWER_DIR / "node_modules" / "three").is_dir():
        missing = "three.js is not installed: run `npm ci` in service/neural_shdf/viewer"
    return [pytest.mark.slow, pytest.mark.skipif(missing is not None, reason=str(missing))]


def chromium_missing() -> str | None:
    """Why the browser tests cannot run here, or None."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[dev]')"
    for binary in (CHROMIUM, CHROMEDRIVER):
        if not binary.is_file():
            return f"{binary} is missing (apt-get install -y chromium chromium-driver)"
    return None


def cpu_seconds(pid: int) -> float:
    """CPU time (user + system) a process has used so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@contextlib.contextmanager
def neural_shdf_serve(cache_dir: Path, **settings: str) -> Iterator[tuple[str, int]]:
    """`neural-shdf serve` (the CLI) on a free loopback port; yields (base URL, its pid)."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("NEURAL_SHDF_")}
    env.update(
        NEURAL_SHDF_CACHE_DIR=str(cache_dir),
        NEURAL_SHDF_LOG_LEVEL="warning",
        **{f"NEURAL_SHDF_{k.upper()}": str(v) for k, v in settings.items()},
    )
    command = [sys.executable, "-m", "neural_shdf.cli", "serve", "--host", "127.0.0.1"]
    process = subprocess.Popen([*command, "--port", str(port)], env=env)
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 180
        while True:
            if process.poll() is not None:
                raise RuntimeError(f"neural-shdf serve exited with {process.returncode}")
            try:
                if httpx.get(f"{base}/readyz", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("neural-shdf serve did not become ready")
            time.sleep(0.2)
        yield base, process.pid
    finally:
        process.terminate()
        process.wait(timeout=30)


class ViewerPage:
    """The viewer page in one headless Chromium."""

    def __init__(self, base_url: str, download_dir: Path | None = None) -> None:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service

        options = webdriver.ChromeOptions()
        options.binary_location = str(CHROMIUM)
        for flag in CHROMIUM_FLAGS:
            options.add_argument(flag)
        options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
        if download_dir is not None:
            options.add_experimental_option(
                "prefs", {"download.default_directory": str(download_dir)}
            )
        self.driver = webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options)
        self.driver.set_script_timeout(300)
        self.base_url = base_url
        self.console: list[dict[str, Any]] = []

    def close(self) -> None:
        self.driver.quit()

    def __enter__(self) -> ViewerPage:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def js(self, script: str, *args: Any) -> Any:
        return self.driver.execute_script(script, *args)

    def open(self) -> None:
        self.driver.get(f"{self.base_url}/viewer/")
        self.wait_for("return !!(window.shdfViewer && window.shdfViewer.ready)", timeout_s=60)

    def wait_for(self, condition: str, timeout_s: float = 120.0) -> Any:
        """Poll a JavaScript expression (``return ...``) until it is truthy."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            value = self.js(condition)
            if value:
                return value
            time.sleep(0.05)
        raise AssertionError(f"timed out waiting for: {condition}; status {self.status()}")

    def status(self) -> str:
        return self.js("return document.body.dataset.status")

    def message(self) -> str | None:
        """The error message shown to the user, if any."""
        return self.js(
            "const m = document.getElementById('message'); return m.hidden ? null : m.textContent"
        )

    def upload(self, path: Path, timeout_s: float = 300.0) -> None:
        """Pick a file in the file input and wait until its parts are shown (or an error)."""
        from selenium.webdriver.common.by import By

        self.js("window.__segmented = []; addEventListener('shdf:segmented', "
                "e => window.__segmented.push(e.detail))")  # fmt: skip
        self.driver.find_element(By.ID, "file-input").send_keys(str(path))
        self.wait_for(
            "return !document.getElementById('message').hidden || "
            "(window.__segmented.length > 0 && document.body.dataset.status === 'ready')",
            timeout_s,
        )

    def release_slider(self, element_id: str, value: float) -> dict[str, Any]:
        """Set a control as a user releasing it would, and wait for the new colours.

        Returns the page's ``shdf:segmented`` detail (``totalMs``: release to presented frame).
        """
        return self.driver.execute_async_script(
            """
            const [id, value, done] = arguments;
            const input = document.getElementById(id);
            addEventListener('shdf:segmented', (e) => done(e.detail), { once: true });
            if (input.type === 'checkbox') input.checked = Boolean(value);
            else input.value = String(value);
            input.dispatchEvent(new Event('input', { bubbles: true }));
            input.dispatchEvent(new Event('change', { bubbles: true }));
            """,
            element_id,
            value,
        )

    def release_smoothing(self, value: float) -> dict[str, Any]:
        """Move the smoothing slider to the position of ``value`` (one of its values)."""
        position = self.js("return window.shdfViewer.smoothingPosition(arguments[0])", value)
        detail = self.release_slider("smoothing", position)
        assert detail["request"]["smoothing"] == value, (value, detail["request"])
        return detail

    def click_canvas(self, x: float, y: float) -> None:
        """A real mouse click at (x, y) CSS pixels from the canvas's top left corner."""
        from selenium.webdriver.common.action_chains import ActionChains
        from selenium.webdriver.common.by import By

        canvas = self.driver.find_element(By.ID, "canvas")
        size = canvas.size
        ActionChains(self.driver).move_to_element_with_offset(
            canvas, int(x - size["width"] / 2), int(y - size["height"] / 2)
        ).click().perform()

    def pixels(self) -> Any:
        """The page as the screen shows it: an (H, W, 3) uint8 array of a real screenshot."""
        import io

        import numpy as np
        from PIL import Image

        png = self.driver.get_screenshot_as_png()
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))

    def rect(self, selector: str) -> dict[str, float]:
        """An element's box in CSS pixels (left, top, right, bottom, width, height)."""
        return self.js(
            "const r = document.querySelector(arguments[0]).getBoundingClientRect();"
            "return {left: r.left, top: r.top, right: r.right, bottom: r.bottom,"
            " width: r.width, height: r.height}",
            selector,
        )

    def segmentation(self) -> dict[str, Any]:
        """What the page shows: labels per input face, triangle colours, the face map."""
        return self.js(
            """
            const v = window.shdfViewer;
            return {
              labels: Array.from(v.state.labels),
              colors: Array.from(v.view.triangleColors()),
              faceOrigin: Array.from(v.view.faceOrigin),
              parts: v.state.body.parts,
              controls: {
                partitioner: document.getElementById('partitioner').value,
                clusters: Number(document.getElementById('clusters').value),
                smoothing: v.controlValues().smoothing,
              },
            };
            """
        )

    def read_console(self) -> list[dict[str, Any]]:
        """Browser console entries since the last call (kept in ``self.console`` too)."""
        entries = self.driver.get_log("browser")
        self.console.extend(entries)
        return entries

    def screenshot(self, path: Path) -> Path:
        self.driver.save_screenshot(str(path))
        return path
