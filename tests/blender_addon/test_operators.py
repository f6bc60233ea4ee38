"""The add-on in the real `bpy` module (headless): installed from its zip, "Segment Selected"
run against a live service on a dumbbell (two boxes joined by a thin bar)."""

from __future__ import annotations

import collections

import httpx
import numpy as np
import pytest

from neural_shdf.client import Client
from tests.api.api_helpers import free_port, obj_bytes

pytestmark = pytest.mark.slow

SUBDIVIDED_POLYGONS = 4 * 88  # the cuts=1 dumbbell (88 quads), simple subdivision level 1


@pytest.fixture(scope="module")
def session(run_blender, service_url) -> dict:
    """One Blender session: segment, re-segment with new parameters, a modifier stack with
    split parts, two failures (degenerate mesh, unreachable service), a part count. The
    panel's settings persist from step to step, as in Blender."""
    nowhere = f"http://127.0.0.1:{free_port()}"
    steps = [
        {"make": "dumbbell", "name": "Dumbbell", "cuts": 3},
        {"segment": ["Dumbbell"], "settings": {"server_url": service_url}},
        {"inspect": "Dumbbell"},
        {
            "segment": ["Dumbbell"],
            "settings": {"partitioner": "metis", "use_parts": True, "parts": 2, "method": "exact"},
        },
        {"inspect": "Dumbbell"},
        {"make": "dumbbell", "name": "Smooth", "cuts": 1, "subsurf": 1},
        {
            "segment": ["Smooth"],
            "settings": {"partitioner": "graphcut", "use_parts": False, "split_parts": True},
        },
        {"inspect": "Smooth segmented"},
        {"inspect": "Smooth"},
        {"make": "flat_triangle", "name": "Flat"},
        {"segment": ["Flat"], "settings": {"split_parts": False}},
        {"segment": ["Dumbbell"], "settings": {"server_url": nowhere}},
        # A part count for the graph cut: a cut of its part tree, by mesh id.
        {
            "segment": ["Dumbbell"],
            "settings": {
                "server_url": service_url,
                "partitioner": "graphcut",
                "method": "default",
                "use_parts": True,
                "parts": 2,
            },
        },
        {"inspect": "Dumbbell"},
    ]
    records = run_blender(steps)
    return {
        # What the service received, before other tests send it anything.
        "uploads": requests_to(service_url, "/v1/segment/file"),
        "by_id": requests_to(service_url, "/v1/segment"),
        "install": records[0]["install"],
        "segments": [r["segment"] for r in records if "segment" in r],
        "inspections": [r["inspect"] for r in records if "inspect" in r],
    }


def regions(record: dict) -> dict[str, collections.Counter]:
    """Labels of the left box (x <= -1), the right box (x >= 1) and the bar, by polygon
    centre (each box's inner face ring lies in its plane x = -1 or 1)."""
    found: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    for x, label in zip(record["center_x"], record["labels"], strict=True):
        found["left" if x <= -1 + 1e-6 else "right" if x >= 1 - 1e-6 else "bar"][label] += 1
    return found


def requests_to(base: str, route: str) -> float:
    prefix = f'neural_shdf_http_requests_total{{method="POST",route="{route}",status="200"}}'
    lines = httpx.get(f"{base}/metrics").text.splitlines()
    return sum(float(line.split()[-1]) for line in lines if line.startswith(prefix))


def test_addon_installs_from_its_zip_and_registers_the_operator(session):
    assert session["install"] == {"result": ["FINISHED"], "enabled": True, "operator": True}


def test_labels_cover_every_polygon_in_blender_order(session, service_url):
    first = session["segments"][0]
    assert first["result"] == ["FINISHED"] and "Dumbbell: 3 parts (uploaded)" in first["output"]
    record = session["inspections"][0]
    assert record["attribute_domain"] == "FACE" and record["attribute_type"] == "INT"
    assert len(record["labels"]) == record["polygons"] == 22 * 4**2
    # The same polygons, in Blender's order, segmented independently through the Python
    # client: label i belongs to polygon i.
    data = obj_bytes(np.array(record["vertices"]), record["polygons_vertices"])
    with Client(service_url) as client:
        expected = client.segment_file(data, file_type="obj", clusters=9)
    assert record["labels"] == expected.labels.tolist()
    # Known parts: each box one part, the bar a third.
    found = regions(record)
    majority = {name: counter.most_common(1)[0][0] for name, counter in found.items()}
    assert len(set(majority.values())) == 3
    for name, counter in found.items():
        assert counter[majority[name]] == sum(counter.values()), (name, counter)
    assert record["props"]["neural_shdf_part_count"] == 3
    assert record["material_index"] == record["labels"]
    assert record["materials"] == [f"neural_shdf part {i:03d}" for i in range(3)]
    assert record["has_colors"]


def test_new_parameters_reuse_the_mesh_id_without_uploading(session, service_url):
    """Another partitioner, part count and even ShDF method: the mesh id, no upload."""
    second = session["segments"][1]
    assert second["result"] == ["FINISHED"] and "Dumbbell: 2 parts (by mesh id)" in second["output"]
    before, after = session["inspections"][0], session["inspections"][1]
    assert after["props"]["neural_shdf_mesh_id"] == before["props"]["neural_shdf_mesh_id"]
    assert len(set(after["labels"])) == after["props"]["neural_shdf_part_count"] == 2
    with Client(service_url) as client:
        expected = client.segment(
            after["props"]["neural_shdf_mesh_id"],
            method="exact",
            partitioner="metis",
            parts=2,
            clusters=9,
        )
    assert after["labels"] == expected.labels.tolist()
    # Uploads: the dumbbell once and the subdivided one once; the re-run went by id.
    assert session["uploads"] == 2 and session["by_id"] == 2


def test_modifiers_are_applied_and_parts_split_into_objects(session):
    assert session["segments"][2]["result"] == ["FINISHED"]
    result, source = session["inspections"][2], session["inspections"][3]
    assert result["polygons"] == SUBDIVIDED_POLYGONS == len(result["labels"])
    assert "labels" not in source and source["polygons"] == 88  # the source keeps its mesh
    assert source["hidden"] and result["hidden"]  # the part objects take their place
    part_count = len(set(result["labels"]))
    assert len(result["part_objects"]) == part_count == 3
    counts = collections.Counter(result["labels"])
    assert sorted(n for _, n in result["part_objects"]) == sorted(counts.values())


def test_errors_are_reported_in_blender_never_as_a_traceback(session):
    degenerate, unreachable = session["segments"][3], session["segments"][4]
    assert degenerate["result"] == ["CANCELLED"]
    assert "neural-shdf: all 1 triangles have zero area" in degenerate["error"]
    assert unreachable["result"] == ["CANCELLED"]
    assert "cannot reach the neural-shdf service" in unreachable["error"]
    assert not any("Traceback" in s["output"] for s in session["segments"])


def test_part_count_for_the_graph_cut_cuts_its_part_tree(session, service_url):
    run, record = session["segments"][5], session["inspections"][4]
    assert run["result"] == ["FINISHED"] and "Dumbbell: 2 parts (by mesh id)" in run["output"]
    with Client(service_url) as client:
        expected = client.segment(record["props"]["neural_shdf_mesh_id"], clusters=9, parts=2)
    assert record["labels"] == expected.labels.tolist()
    found = regions(record)
    assert found["left"].most_common(1)[0][0] != found["right"].most_common(1)[0][0]
