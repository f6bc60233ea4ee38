"""The viewer's page: import map from the settings, its configuration, its static files."""

from __future__ import annotations

import json
import re

import numpy as np
from fastapi.testclient import TestClient

from neural_shdf.api.viewer import STATIC_DIR, VIEWER_DIR, display_geometry, three_version
from neural_shdf.mesh_io import load_mesh


def page_scripts(html: str) -> tuple[dict, dict]:
    """(import map, page config) parsed from the served page."""
    imports = re.search(r'<script type="importmap">(.*?)</script>', html, re.S)
    config = re.search(r'<script id="viewer-config" type="application/json">(.*?)</script>', html)
    assert imports and config
    return json.loads(imports.group(1)), json.loads(config.group(1))


def test_root_leads_to_the_viewer(app_factory):
    with TestClient(app_factory()) as client:
        response = client.get("/", follow_redirects=False)
        assert response.status_code == 307 and response.headers["location"] == "/viewer/"
        page = client.get("/viewer/")
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        assert "/viewer/static/main.js" in page.text
        assert client.get("/viewer").status_code == 200


def test_import_map_uses_the_configured_three_url(app_factory):
    base = "https://assets.example.test/three@1/"
    with TestClient(app_factory(viewer_three_url=base.rstrip("/"))) as client:
        imports, _ = page_scripts(client.get("/viewer/").text)
    assert imports == {
        "imports": {
            "three": f"{base}build/three.module.js",
            "three/addons/": f"{base}examples/jsm/",
        }
    }


def test_without_a_local_copy_three_comes_from_the_cdn_at_the_locked_version(app_factory, tmp_path):
    lock = json.loads((VIEWER_DIR / "package-lock.json").read_text())
    locked = lock["packages"]["node_modules/three"]["version"]
    assert three_version() == locked
    with TestClient(app_factory(viewer_three_dir=tmp_path / "nothing-here")) as client:
        imports, _ = page_scripts(client.get("/viewer/").text)
        assert imports["imports"]["three"] == (
            f"https://cdn.jsdelivr.net/npm/three@{locked}/build/three.module.js"
        )
        assert client.get("/viewer/three/build/three.module.js").status_code == 404


def test_a_local_copy_is_served_and_used(app_factory, tmp_path):
    local = tmp_path / "three"
    (local / "build").mkdir(parents=True)
    (local / "build" / "three.module.js").write_text("export const REVISION = 'local';\n")
    with TestClient(app_factory(viewer_three_dir=local)) as client:
        imports, _ = page_scripts(client.get("/viewer/").text)
        assert imports["imports"]["three"] == "/viewer/three/build/three.module.js"
        served = client.get("/viewer/three/build/three.module.js")
        assert served.status_code == 200 and "REVISION = 'local'" in served.text
        assert "javascript" in served.headers["content-type"]


def test_page_config_reflects_the_service_limits(app_factory):
    with TestClient(app_factory(max_upload_bytes=12345, default_method="exact")) as client:
        _, config = page_scripts(client.get("/viewer/").text)
    assert config["maxUploadBytes"] == 12345 and config["defaultMethod"] == "exact"
    assert set(config["formats"]) == {
        "obj",
        "glb",
        "gltf",
        "off",
        "ply",
        "stl",
        "usd",
        "usda",
        "usdc",
        "usdz",
    }
    assert config["defaultClusters"] == 9 and config["maxClusters"] == 32
    assert config["methods"] == ["auto", "exact", "sampled", "neural"]
    assert config["partitioners"] == ["graphcut", "metis"]
    assert config["unlabeledColor"] == "#404040"


def test_config_cannot_break_out_of_its_script_element(app_factory):
    with TestClient(app_factory(viewer_three_url="https://x.test/</script><b>")) as client:
        html = client.get("/viewer/").text
    assert "</script><b>" not in html
    imports, _ = page_scripts(html)
    assert imports["imports"]["three"].startswith("https://x.test/</script><b>/")


def test_every_module_the_scripts_import_is_served(app_factory):
    relative, bare = set(), set()
    with TestClient(app_factory()) as client:
        for module in sorted(p.name for p in STATIC_DIR.glob("*.js")):
            text = client.get(f"/viewer/static/{module}").text
            relative.update(re.findall(r"""from\s+['"]\./([^'"]+)['"]""", text))
            bare.update(re.findall(r"""from\s+['"]([^./'"][^'"]*)['"]""", text))
        for target in relative:
            assert client.get(f"/viewer/static/{target}").status_code == 200, target
    assert {"api.js", "scene.js"} <= relative
    assert "three" in bare and all(b == "three" or b.startswith("three/addons/") for b in bare)


def test_page_names_the_fix_when_three_js_cannot_load(app_factory, tmp_path):
    """The page carries what to do if three.js does not load: offline with the CDN default,
    install the npm copy the service then serves."""
    with TestClient(app_factory(viewer_three_dir=tmp_path / "nothing-here")) as client:
        _, config = page_scripts(client.get("/viewer/").text)
    assert config["threeUrl"].startswith("https://cdn.jsdelivr.net/npm/three@")
    assert "CDN" in config["threeHelp"] and "offline" in config["threeHelp"]
    assert f"`npm ci` in {VIEWER_DIR}" in config["threeHelp"]
    assert "NEURAL_SHDF_VIEWER_THREE_DIR" in config["threeHelp"]
    with TestClient(app_factory(viewer_three_url="https://x.test/three")) as client:
        _, config = page_scripts(client.get("/viewer/").text)
    assert "NEURAL_SHDF_VIEWER_THREE_URL (https://x.test/three/)" in config["threeHelp"]


def test_display_geometry_layout_round_trips_the_triangles_and_face_map():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1]], float)
    obj = "".join(f"v {x} {y} {z}\n" for x, y, z in vertices) + "f 1 2 3 4\nf 1 2\nf 1 2 5\n"
    mesh = load_mesh(obj.encode(), "obj")
    blob = display_geometry(mesh)
    magic, version, v, t, f = np.frombuffer(blob[:4], "S4")[0], *np.frombuffer(blob[4:20], "<u4")
    assert (magic, version, v, t, f) == (b"NSHG", 1, 5, 3, 3)
    positions = np.frombuffer(blob, "<f4", 3 * v, 20).reshape(-1, 3)
    triangles = np.frombuffer(blob, "<u4", 3 * t, 20 + 12 * v).reshape(-1, 3)
    origin = np.frombuffer(blob, "<u4", t, 20 + 12 * v + 12 * t)
    assert len(blob) == 20 + 12 * v + 12 * t + 4 * t
    np.testing.assert_array_equal(positions, vertices.astype(np.float32))
    np.testing.assert_array_equal(triangles, [[0, 1, 2], [0, 2, 3], [0, 1, 4]])
    np.testing.assert_array_equal(origin, [0, 0, 2])  # the 2-vertex face has no triangle
