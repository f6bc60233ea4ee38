"""Labels follow the input faces: OBJ quads, GLB nodes with transforms, duplicate vertices."""

from __future__ import annotations

import numpy as np
import pytest

from tests.api.api_helpers import (
    capsule,
    glb_two_nodes,
    obj_bytes,
    parts_within_blocks,
    quad_box,
    quad_dumbbell_obj,
)


def segment_file(client, data: bytes, name: str, **options) -> dict:
    """One-shot segmentation with the exact ShDF: deterministic and independent of how
    vertices are shared, so the same surface in any layout must give the same labels
    (the neural ShDF samples the surface and may differ slightly between layouts)."""
    options.setdefault("method", "exact")
    response = client.post("/v1/segment/file", files={"file": (name, data)}, data=options)
    assert response.status_code == 200, response.text
    return response.json()


def test_obj_quads_get_one_label_per_quad(client):
    big_v, big_q = quad_box((0, 0, 0), 2.0)
    small_v, small_q = quad_box((6, 0, 0), 0.5)
    polygons = big_q + [[i + 8 for i in q] for q in small_q]
    quads = obj_bytes(np.concatenate([big_v, small_v]), polygons)
    body = segment_file(client, quads, "boxes.obj")
    assert body["faces"] == 12 and len(body["labels"]) == 12
    assert parts_within_blocks(body["labels"], [6, 6])  # disjoint boxes never share a part

    # The same surface as triangles, each quad fanned (v0 v1 v2), (v0 v2 v3):
    triangles = [t for q in polygons for t in ([q[0], q[1], q[2]], [q[0], q[2], q[3]])]
    fanned = segment_file(client, obj_bytes(np.concatenate([big_v, small_v]), triangles), "t.obj")
    per_triangle = np.array(fanned["labels"]).reshape(12, 2)
    agree = per_triangle[:, 0] == per_triangle[:, 1]
    np.testing.assert_array_equal(np.array(body["labels"])[agree], per_triangle[agree, 0])


def test_glb_nodes_with_transforms_keep_depth_first_order(client):
    shape = capsule(8)
    glb = glb_two_nodes(shape.vertices, shape.faces)
    body = segment_file(client, glb, "scene.glb")
    count = len(shape.faces)
    assert body["faces"] == 2 * count
    # Without the node transforms both instances would coincide and could share parts.
    assert parts_within_blocks(body["labels"], [count, count])
    summary = {p["label"]: p["area"] for p in body["parts"]}
    parent = sum(summary[label] for label in set(body["labels"][:count]))
    child = sum(summary[label] for label in set(body["labels"][count:]))
    # The child is scaled by 0.5 (its parent translates only): a quarter of the area.
    assert child == pytest.approx(parent / 4, rel=1e-5)


def test_duplicate_vertices_segment_like_shared_ones(client):
    shape = capsule(10)
    vertices = shape.vertices.astype(np.float32).astype(float)  # exact in STL's float32
    shared = obj_bytes(vertices, shape.faces.tolist())
    soup = vertices[shape.faces].reshape(-1, 3)  # every face with its own three vertices
    split = obj_bytes(soup, np.arange(len(soup)).reshape(-1, 3).tolist())
    import trimesh

    stl = trimesh.Trimesh(soup, np.arange(len(soup)).reshape(-1, 3), process=False).export(
        file_type="stl"
    )
    options = {"partitioner": "metis", "parts": "3"}
    reference = segment_file(client, shared, "shared.obj", **options)["labels"]
    assert segment_file(client, split, "split.obj", **options)["labels"] == reference
    assert segment_file(client, stl, "soup.stl", **options)["labels"] == reference


def test_every_format_gives_the_same_segmentation(client):
    """OBJ, OFF, PLY, STL, GLB and glTF (embedded buffers) of one surface: same labels."""
    import trimesh

    shape = capsule(8)
    shape = trimesh.Trimesh(shape.vertices.astype(np.float32).astype(float), shape.faces)
    files = {
        "m.obj": obj_bytes(shape.vertices, shape.faces.tolist()),
        "m.off": shape.export(file_type="off"),
        "m.ply": shape.export(file_type="ply"),
        "m.stl": shape.export(file_type="stl"),
        "m.glb": shape.export(file_type="glb"),
        "m.gltf": trimesh.exchange.gltf.export_gltf(shape, embed_buffers=True)["model.gltf"],
    }
    options = {"partitioner": "metis", "parts": "2"}
    results = {
        name: segment_file(
            client, data if isinstance(data, bytes) else data.encode(), name, **options
        )
        for name, data in files.items()
    }
    reference = results["m.obj"]["labels"]
    assert len(reference) == len(shape.faces)
    for name, body in results.items():
        assert body["labels"] == reference, name


@pytest.mark.parametrize(
    "options",
    [{"partitioner": "graphcut"}, {"partitioner": "metis", "parts": 8}],
    ids=["graphcut", "metis"],
)
def test_cli_api_and_library_give_identical_labels_for_quads(client, tmp_path, options):
    """One mapping (area-weighted, in the library) and one seed convention: the same quad
    OBJ gets the same per-polygon labels from the library, the CLI and the API."""
    from neural_shdf.cli import main
    from neural_shdf.mesh_io import load_mesh
    from neural_shdf.pipeline import SegmentParams, compute_shdf, segment

    data, seed = quad_dumbbell_obj(), 3
    mesh = load_mesh(data, "obj")
    params = SegmentParams(seed=seed, **options)
    shdf = compute_shdf(mesh, method="exact", seed=seed).values
    triangle_labels = segment(mesh, shdf, params).labels
    library = mesh.labels_to_input_faces(triangle_labels)
    # The mesh exercises the mapping: counting triangles instead of area would differ.
    by_count = mesh.labels_to_input_faces(triangle_labels, weights=np.ones(mesh.face_count))
    assert np.any(library != by_count)

    path, out = tmp_path / "quads.obj", tmp_path / "labels.seg"
    path.write_bytes(data)
    flags = [f"--{name}={value}" for name, value in options.items()]
    assert main(["segment", str(path), "-o", str(out), "--method", "exact",
                 f"--seed={seed}", *flags, "-q"]) == 0  # fmt: skip
    cli = np.array(out.read_text().split(), dtype=int)

    api = segment_file(client, data, "quads.obj", seed=seed, **options)["labels"]
    form = {"seed": seed, "method": "exact"}
    stored = client.post("/v1/meshes", files={"file": ("q.obj", data)}, data=form)
    mesh_id = stored.json()["mesh"]["mesh_id"]
    again = client.post("/v1/segment", json={"mesh_id": mesh_id, "method": "exact",
                                             "seed": seed, **options})  # fmt: skip
    assert again.status_code == 200, again.text
    np.testing.assert_array_equal(cli, library)
    np.testing.assert_array_equal(api, library)
    np.testing.assert_array_equal(again.json()["labels"], library)
