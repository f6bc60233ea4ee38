"""The interactive docs work offline: Swagger UI and ReDoc load only this service's assets."""

from __future__ import annotations

import re
import shutil
import subprocess

import httpx
import pytest

from neural_shdf.api.docs import ASSETS_URL
from tests.api.conftest import running_server


def test_docs_pages_reference_only_local_assets(client):
    for page in ("/docs", "/redoc"):
        html = client.get(page)
        assert html.status_code == 200
        sources = re.findall(r'(?:src|href)="([^"]+)"', html.text)
        assert sources and all(src.startswith(ASSETS_URL) for src in sources), sources
        assert "cdn" not in html.text.lower() and "fonts.googleapis" not in html.text
        for src in sources:
            asset = client.get(src)
            assert asset.status_code == 200 and len(asset.content) > 1000, src
    assert client.get("/docs/oauth2-redirect").status_code == 200


@pytest.mark.slow
def test_swagger_ui_renders_the_operations_in_chromium_offline(tmp_path):
    """Real Chromium on a machine without internet: the page shows the API's operations."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("chromium is not installed (apt-get install -y chromium)")
    with running_server(tmp_path / "cache", warm_up=False) as base:
        assert httpx.get(f"{base}/openapi.json").status_code == 200
        dom = subprocess.run(
            [chromium, "--headless", "--no-sandbox", "--disable-gpu",
             "--disable-background-networking", "--virtual-time-budget=15000",
             "--dump-dom", f"{base}/docs"],
            capture_output=True, text=True, timeout=120, check=True,
        ).stdout  # fmt: skip
    assert "Upload a mesh and compute its ShDF" in dom  # an operation's summary, rendered
    assert "/v1/segment" in dom
