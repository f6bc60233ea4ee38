"""Part editing in the real `bpy` module (headless) against a live service: each button
sends the object's edit document to `/v1/segment` and the labels written are the
service's for that document (Edit Mode or Object Mode)."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest

pytestmark = pytest.mark.slow

MAKE = {"make": "dumbbell", "name": "Parts", "cuts": 2}
SEGMENT = {"partitioner": "graphcut", "clusters": 9, "smoothing": 0.06}


@pytest.fixture(scope="module")
def plain(run_blender, service_url) -> dict:
    """The object's labels before any edit (a first session)."""
    records = run_blender([MAKE, {"segment": ["Parts"], "settings": {"server_url": service_url}},
                           {"inspect": "Parts"}])  # fmt: skip
    return records[-1]["inspect"]


@pytest.fixture(scope="module")
def edited(run_blender, service_url, plain) -> tuple[list[dict], dict]:
    """A second session: the same segmentation, then merge, paint, split (in Edit Mode),
    grow, a refused edit and a reset; the faces chosen from the first session's labels."""
    labels = np.asarray(plain["labels"])
    parts = sorted(set(labels.tolist()))
    assert len(parts) >= 3, parts
    first = {part: int(np.flatnonzero(labels == part)[0]) for part in parts}
    a, b, c = (first[part] for part in parts[:3])
    painted = [int(f) for f in np.flatnonzero(labels == parts[1])[:3]]
    steps = [
        MAKE,
        {"segment": ["Parts"], "settings": {"server_url": service_url}},
        {"edit": "Parts", "op": "merge", "faces": [a, b], "active": a},
        {"inspect": "Parts"},
        {"edit": "Parts", "op": "paint", "faces": [*painted, c], "active": c},
        {"inspect": "Parts"},
        {"edit": "Parts", "op": "split", "faces": [a], "active": a, "edit_mode": True},
        {"inspect": "Parts"},
        {"edit": "Parts", "op": "grow", "faces": [c], "active": c},
        {"inspect": "Parts"},
        {"edit": "Parts", "op": "merge", "faces": [a], "active": a},  # one part: refused
        {"edit": "Parts", "op": "reset", "faces": [], "active": -1},
        {"inspect": "Parts"},
    ]
    return run_blender(steps), {"a": a, "b": b, "c": c, "painted": painted}


def service_labels(service_url: str, mesh_id: str, document: list[dict]) -> list[int]:
    body = {"mesh_id": mesh_id, **SEGMENT, "edits": document}
    response = httpx.post(f"{service_url}/v1/segment", json=body, timeout=300)
    assert response.status_code == 200, response.text
    return response.json()["labels"]


def test_each_edit_writes_the_services_labels_for_the_document(edited, plain, service_url):
    records, faces = edited
    runs = [record["edit"] for record in records if "edit" in record]
    assert [run["result"] for run in runs] == [["FINISHED"]] * 4 + [["CANCELLED"], ["FINISHED"]]
    assert runs[2]["mode"] == "EDIT"  # the split ran from Edit Mode and went back to it
    assert "at least two parts" in runs[4]["error"]
    inspected = [record["inspect"] for record in records if "inspect" in record]
    mesh_id = plain["props"]["neural_shdf_mesh_id"]
    expected_ops = [["merge"], ["merge", "paint"], ["merge", "paint", "split"],
                    ["merge", "paint", "split", "grow"]]  # fmt: skip
    previous = plain["labels"]
    for record, ops in zip(inspected[:4], expected_ops, strict=True):
        document = json.loads(record["props"]["neural_shdf_edits"])
        assert [operation["op"] for operation in document] == ops
        assert record["labels"] == service_labels(service_url, mesh_id, document)
        assert record["labels"] != previous
        assert record["props"]["neural_shdf_part_count"] == max(record["labels"]) + 1
        previous = record["labels"]
    merged = np.asarray(inspected[0]["labels"])
    assert merged[faces["a"]] == merged[faces["b"]]
    painted = np.asarray(inspected[1]["labels"])
    assert (painted[faces["painted"]] == painted[faces["c"]]).all()
    # Reset: the plain segmentation, no document left.
    assert inspected[4]["labels"] == plain["labels"]
    assert "neural_shdf_edits" not in inspected[4]["props"]
