"""The add-on in the real `bpy` module (headless): installed from its zip, "Segment Selected"
run against a live service on a dumbbell (two boxes joined by a thin bar)."""

from __future__ import annotations

import collections
import json

import httpx
import numpy as np
import pytest

from neural_shdf.client import Client
from neural_shdf.palette import srgb_to_linear
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
        # An object with materials of its own: parts as colours only (the default), then as
        # materials (twice), then back without.
        {"make": "dumbbell", "name": "Labelled", "cuts": 1, "materials": 2},
        {
            "segment": ["Labelled"],
            "settings": {"use_parts": False, "assign_materials": False, "split_parts": False},
        },
        {"inspect": "Labelled"},
        {"segment": ["Labelled"], "settings": {"assign_materials": True}},
        {"inspect": "Labelled"},
        {
            "segment": ["Labelled"],
            "settings": {"partitioner": "metis", "use_parts": True, "parts": 4},
        },
        {"inspect": "Labelled"},
        {"segment": ["Labelled"], "settings": {"assign_materials": False}},
        {"inspect": "Labelled"},
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
    assert session["install"] == {
        "result": ["FINISHED"],
        "enabled": True,
        "operator": True,
        # Parts show as a colour attribute; materials and objects only when asked for.
        "defaults": {"assign_materials": False, "split_parts": False},
    }


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
    assert record["materials"] == [] and set(record["material_index"]) == {0}  # the default
    assert record["has_colors"] and record["color_type"] == ["FACE", "FLOAT_COLOR"]


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
    # Uploads: each dumbbell once (the subdivided one, the one with its own materials); the
    # re-runs went by id (the dumbbell twice, the one with materials three times).
    assert session["uploads"] == 3 and session["by_id"] == 5


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


def api_colors(service_url: str, mesh_id: str, **options) -> np.ndarray:
    """The API's part colours for a segmentation, in linear light, one RGBA row per label."""
    body = httpx.post(
        f"{service_url}/v1/segment", json={"mesh_id": mesh_id, "clusters": 9, **options}
    ).json()
    colors = [(*srgb_to_linear(np.array(rgb(p["color"])) / 255.0), 1.0) for p in body["parts"]]
    return np.array(colors)


def rgb(hex_color: str) -> list[int]:
    return [int(hex_color[i : i + 2], 16) for i in (1, 3, 5)]


def test_part_colours_are_the_services_in_linear_light(session, service_url):
    """The colour attribute and the part materials hold the API's `color` of each part,
    converted from sRGB to linear (what Blender's colours are)."""
    colours_only, materials = session["inspections"][5], session["inspections"][6]
    mesh_id = colours_only["props"]["neural_shdf_mesh_id"]
    expected = api_colors(service_url, mesh_id)
    labels = np.asarray(colours_only["labels"])
    assert len(expected) == colours_only["props"]["neural_shdf_part_count"] >= 2
    np.testing.assert_allclose(colours_only["colors"], expected[labels], atol=1e-6)
    part_slots = materials["material_colors"][2:]
    assert len(part_slots) == len(expected)
    for slot, colour in zip(part_slots, expected, strict=True):
        np.testing.assert_allclose(slot["base"], colour, atol=1e-6)
        np.testing.assert_allclose(slot["diffuse"], colour, atol=1e-6)


def test_part_materials_never_remove_the_objects_own(session, service_url):
    colours_only, first, again, restored = session["inspections"][5:9]
    own = ["Labelled own 0", "Labelled own 1"]
    polygons = colours_only["polygons"]
    own_slots = [i % 2 for i in range(polygons)]
    # Off (the default): the object's materials and slots as they were.
    assert colours_only["materials"] == own and colours_only["material_index"] == own_slots
    # On: the part materials come after the object's own, each polygon in its part's slot.
    parts = first["props"]["neural_shdf_part_count"]
    assert first["materials"] == own + [f"neural_shdf part {i:03d}" for i in range(parts)]
    assert first["material_index"] == [2 + label for label in first["labels"]]
    # Again with other parameters: the part slots are replaced, never stacked.
    assert again["props"]["neural_shdf_part_count"] == 4
    assert again["materials"] == own + [f"neural_shdf part {i:03d}" for i in range(4)]
    assert again["material_index"] == [2 + label for label in again["labels"]]
    mesh_id = again["props"]["neural_shdf_mesh_id"]
    expected = api_colors(service_url, mesh_id, partitioner="metis", parts=4)
    for slot, colour in zip(again["material_colors"][2:], expected, strict=True):
        np.testing.assert_allclose(slot["base"], colour, atol=1e-6)
    # Off again: each polygon has its own material back; the labels stay.
    assert restored["materials"] == own and restored["material_index"] == own_slots
    assert len(restored["labels"]) == polygons


@pytest.fixture(scope="module")
def named_session(run_blender, service_url, tmp_path_factory) -> dict:
    """Learn a labeller from two dumbbells whose polygons carry a label attribute (boxes
    7, bar 3), then label a third dumbbell with it; two failures (no attribute, missing
    labeller file)."""
    learnt = tmp_path_factory.mktemp("learnt") / "dumbbells.npz"
    steps = [
        {"make": "dumbbell", "name": "TrainA", "cuts": 3},
        {"make": "dumbbell", "name": "TrainB", "cuts": 2, "stretch": 1.3},
        {"label_regions": "TrainA", "attribute": "neural_shdf_label", "boxes": 7, "bar": 3},
        {"label_regions": "TrainB", "attribute": "neural_shdf_label", "boxes": 7, "bar": 3},
        {
            "learn": ["TrainA", "TrainB"],
            "settings": {
                "server_url": service_url,
                "label_names": "bar,box",
                "learn_output": str(learnt),
            },
        },
        {"make": "dumbbell", "name": "Target", "cuts": 2, "stretch": 1.15},
        {"segment": ["Target"], "settings": {"assign_materials": True, "split_parts": True}},
        {"inspect": "Target"},
        {"make": "dumbbell", "name": "Bare", "cuts": 1},
        {"learn": ["Bare"]},
        {"segment": ["TrainA"], "settings": {"labeler_file": str(learnt) + ".missing"}},
    ]
    records = run_blender(steps)
    return {
        "learnt": learnt,
        "learns": [r["learn"] for r in records if "learn" in r],
        "segments": [r["segment"] for r in records if "segment" in r],
        "inspections": [r["inspect"] for r in records if "inspect" in r],
    }


def test_learn_from_selected_trains_a_labeller_from_the_label_attribute(named_session):
    from neural_shdf.labeling import load_labeler

    learnt, failed = named_session["learns"]
    assert learnt["result"] == ["FINISHED"], learnt
    assert learnt["labeler_file"] == str(named_session["learnt"])
    assert "labeller of 2 objects (bar, box)" in learnt["output"]
    labeler = load_labeler(named_session["learnt"])
    assert labeler.label_names == ("bar", "box") and labeler.label_values.tolist() == [3, 7]
    assert failed["result"] == ["CANCELLED"]
    assert "has no integer face attribute 'neural_shdf_label'" in failed["error"]


def test_a_labeller_names_the_attribute_materials_and_objects(named_session, service_url):
    segmented, missing = named_session["segments"]
    assert segmented["result"] == ["FINISHED"], segmented
    assert "Target: bar, box (uploaded)" in segmented["output"]
    record = named_session["inspections"][0]
    assert record["label_type"] == ["FACE", "INT"]
    values = np.asarray(record["label_values"])
    x = np.asarray(record["center_x"])
    truth = np.where(np.abs(x) / (np.abs(x).max() / 2) >= 1 - 1e-6, 7, 3)
    assert np.mean(values == truth) > 0.9
    # The API's named parts of the same polygons with the same labeller, face for face.
    data = obj_bytes(np.array(record["vertices"]), record["polygons_vertices"])
    with Client(service_url) as client:
        stored = client.upload_labeler(named_session["learnt"])
        expected = client.segment_file(data, file_type="obj", labeler_id=stored.labeler_id)
    assert values.tolist() == expected.labels.tolist()
    assert record["props"]["neural_shdf_labeler"] == stored.labeler_id
    assert json.loads(record["props"]["neural_shdf_label_names"]) == {"3": "bar", "7": "box"}
    assert record["materials"] == ["neural_shdf part bar", "neural_shdf part box"]
    assert record["labels"] == [0 if v == 3 else 1 for v in values]  # part index per polygon
    assert [name for name, _ in record["part_objects"]] == ["Target bar", "Target box"]
    assert missing["result"] == ["CANCELLED"] and "does not exist" in missing["error"]
