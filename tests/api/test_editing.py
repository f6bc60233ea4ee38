"""`/v1/segment` with `edits`: the library's edit of the library's segmentation."""

from __future__ import annotations

import numpy as np

from neural_shdf.mesh_io import load_mesh
from neural_shdf.palette import part_color_hex
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.segment import SegmentParams
from neural_shdf.segment.editing import apply_edits, apply_label_edits
from tests.api.api_helpers import TEST_METHOD


def upload_capsule(client, capsule_obj: bytes) -> str:
    response = client.post("/v1/meshes", files={"file": ("capsule.obj", capsule_obj)})
    return response.json()["mesh"]["mesh_id"]


def test_edited_labels_are_the_librarys_edit(client, capsule_obj, tmp_path):
    mesh_id = upload_capsule(client, capsule_obj)
    request = {"mesh_id": mesh_id, "smoothing": 0.02, "parts": 3, "method": TEST_METHOD}
    plain = client.post("/v1/segment", json=request).json()
    faces = plain["faces"]
    document = [
        {"op": "shrink", "face": 0},
        {"op": "grow", "face": faces - 1},
        {"op": "merge", "faces": [0, faces // 2]},
        {"op": "paint", "faces": [1, 2, 3], "to_face": faces - 1},
    ]
    edited = client.post("/v1/segment", json={**request, "edits": document})
    assert edited.status_code == 200, edited.text
    body = edited.json()

    path = tmp_path / "capsule.obj"
    path.write_bytes(capsule_obj)
    mesh = load_mesh(path)
    shdf = compute_shdf(mesh, method=TEST_METHOD).values
    params = SegmentParams(smoothing=0.02, parts=3)
    result = segment(mesh, shdf, params)
    _, leaves = result.input_face_parts(mesh)
    expected = apply_edits(result.tree, leaves, 3, document)
    assert body["labels"] == expected.tolist()
    assert body["labels"] != plain["labels"]

    # The tree is the unedited one, cut where the edits started; parts are the edited ones.
    assert body["hierarchy"] == plain["hierarchy"]
    assert body["part_count"] == int(expected.max()) + 1 == len(body["parts"])
    counts = np.bincount(expected[expected >= 0])
    assert [part["faces"] for part in body["parts"]] == counts.tolist()
    assert [part["color"] for part in body["parts"]] == part_color_hex(len(counts))
    total_area = sum(part["area"] for part in body["parts"])
    assert np.isclose(total_area, mesh.normals_and_areas[1].sum())

    # No edits, an empty document: the plain segmentation.
    assert (
        client.post("/v1/segment", json={**request, "edits": []}).json()["labels"]
        == plain["labels"]
    )


def test_metis_takes_merge_and_paint_only(client, capsule_obj):
    mesh_id = upload_capsule(client, capsule_obj)
    request = {"mesh_id": mesh_id, "partitioner": "metis", "parts": 4}
    plain = client.post("/v1/segment", json=request).json()
    document = [{"op": "merge", "faces": [0, plain["faces"] - 1]}]
    body = client.post("/v1/segment", json={**request, "edits": document}).json()
    expected = apply_label_edits(np.array(plain["labels"]), document)
    assert body["labels"] == expected.tolist()

    grow = client.post("/v1/segment", json={**request, "edits": [{"op": "grow", "face": 0}]})
    assert grow.status_code == 422
    assert "needs the part tree" in grow.json()["error"]["message"]


def test_bad_edits_are_422_that_say_why(client, capsule_obj):
    mesh_id = upload_capsule(client, capsule_obj)
    faces = 288
    out_of_range = client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "edits": [{"op": "grow", "face": faces}]}
    )
    assert out_of_range.status_code == 422
    assert f"face {faces} is out of range" in out_of_range.json()["error"]["message"]
    unknown = client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "edits": [{"op": "cut", "face": 0}]}
    )
    assert unknown.status_code == 422


def test_split_bisects_a_part_as_the_library_does(client, capsule_obj, tmp_path):
    from neural_shdf.segment.editing import input_face_adjacency

    mesh_id = upload_capsule(client, capsule_obj)
    request = {"mesh_id": mesh_id, "smoothing": 0.02, "parts": 2, "method": TEST_METHOD}
    plain = client.post("/v1/segment", json=request).json()
    document = [{"op": "split", "face": 0}, {"op": "merge", "faces": [1, 2]}]
    edited = client.post("/v1/segment", json={**request, "edits": document})
    assert edited.status_code == 200, edited.text
    body = edited.json()

    path = tmp_path / "capsule.obj"
    path.write_bytes(capsule_obj)
    mesh = load_mesh(path)
    shdf = compute_shdf(mesh, method=TEST_METHOD).values
    result = segment(mesh, shdf, SegmentParams(smoothing=0.02, parts=2))
    _, leaves = result.input_face_parts(mesh)
    graph = mesh.face_graph
    adjacency = input_face_adjacency(graph.pairs, graph.edge_length, mesh.face_origin)
    expected = apply_edits(result.tree, leaves, 2, document, adjacency)
    assert body["labels"] == expected.tolist()
    # The part holding face 0 lost faces to a new part, which kept no face of another part.
    before, after = np.asarray(plain["labels"]), np.asarray(body["labels"])
    part = before == before[0]
    assert body["part_count"] >= plain["part_count"]
    assert set(after[~part].tolist()).isdisjoint(set(after[part & (after != after[0])].tolist()))
    # METIS: split applies too.
    metis = {**request, "partitioner": "metis", "edits": [{"op": "split", "face": 0}]}
    answer = client.post("/v1/segment", json=metis)
    assert answer.status_code == 200 and answer.json()["part_count"] == 3
