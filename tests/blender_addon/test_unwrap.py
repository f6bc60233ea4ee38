""" "Unwrap by Parts" in the real `bpy` module (headless) against a live service: the UV map
holds the service's UVs per loop, in Blender's polygon order, and the part labels."""

from __future__ import annotations

import httpx
import numpy as np
import pytest

pytestmark = pytest.mark.slow

UV_MAP = "neural_shdf parts"
SEGMENT = {"partitioner": "graphcut", "clusters": 9, "smoothing": 0.06}
UNWRAP = {"atlas_size": 256, "padding": 2}


@pytest.fixture(scope="module")
def records(run_blender, service_url) -> list[dict]:
    steps = [
        {"make": "dumbbell", "name": "Box", "cuts": 1},
        {
            "unwrap": ["Box"],
            "settings": {"server_url": service_url},
            "unwrap_settings": {"atlas_size": 256},
        },  # fmt: skip
        {"inspect": "Box"},
        {"inspect_uv": "Box", "uv_map": UV_MAP},
        # Modifiers that change the topology: the UVs go to "<name> segmented".
        {"make": "dumbbell", "name": "Smooth", "cuts": 0, "subsurf": 1},
        {"unwrap": ["Smooth"]},
        {"inspect": "Smooth segmented"},
        {"inspect_uv": "Smooth segmented", "uv_map": UV_MAP},
        # Another map name, and an unreachable service: an error, nothing written.
        {"unwrap": ["Box"], "unwrap_settings": {"uv_map": "second"}},
        {"inspect_uv": "Box", "uv_map": "second"},
        {
            "unwrap": ["Box"],
            "settings": {"server_url": "http://127.0.0.1:9"},
            "unwrap_settings": {"uv_map": "third"},
        },  # fmt: skip
        {"inspect_uv": "Box", "uv_map": "third"},
    ]
    return run_blender(steps)


def service_uvs(service_url: str, mesh_id: str) -> tuple[np.ndarray, np.ndarray, dict]:
    import base64

    response = httpx.get(
        f"{service_url}/v1/meshes/{mesh_id}/segmentation/uvs",
        params={**SEGMENT, **UNWRAP},
        timeout=300,
    )
    assert response.status_code == 200, response.text
    body = response.json()
    counts = np.frombuffer(base64.b64decode(body["corner_counts_base64"]), "<i4")
    uvs = np.frombuffer(base64.b64decode(body["uvs_base64"]), "<f4").reshape(-1, 2)
    return counts, uvs, body


@pytest.mark.parametrize("name", ["Box", "Smooth segmented"])
def test_the_uv_map_holds_the_services_uvs_in_polygon_order(records, service_url, name):
    steps = [r for r in records if "inspect" in r or "inspect_uv" in r]
    index = {"Box": 0, "Smooth segmented": 2}[name]
    inspected, uv = steps[index]["inspect"], steps[index + 1]["inspect_uv"]
    assert uv["exists"] and uv["active"] == UV_MAP
    mesh_id = inspected["props"]["neural_shdf_mesh_id"]
    counts, uvs, body = service_uvs(service_url, mesh_id)
    assert counts.tolist() == uv["loop_total"]  # one UV per loop, polygon after polygon
    np.testing.assert_allclose(np.asarray(uv["uvs"]), uvs, atol=1e-6)
    assert uv["note"]["charts"] == len(body["chart_part"])
    assert uv["note"]["polygons_without_uvs"] == 0
    # The labels are the same segmentation's.
    labels = httpx.post(
        f"{service_url}/v1/segment", json={"mesh_id": mesh_id, **SEGMENT}, timeout=300
    ).json()["labels"]
    assert inspected["labels"] == labels
    assert np.asarray(uv["uvs"]).min() >= 0 and np.asarray(uv["uvs"]).max() <= 1


def test_runs_report_and_errors_leave_the_object_alone(records):
    runs = [record["unwrap"] for record in records if "unwrap" in record]
    assert [run["result"] for run in runs] == [["FINISHED"]] * 3 + [["CANCELLED"]]
    assert "charts" in runs[0]["output"] and UV_MAP in runs[0]["output"]
    assert "cannot reach the neural-shdf service" in runs[3]["error"]
    second, third = [r["inspect_uv"] for r in records if "inspect_uv" in r][2:]
    assert second["exists"] and second["active"] == "second"
    assert UV_MAP in second["maps"]  # the first map stays
    assert not third["exists"] and "third" not in third["maps"]
