"""Endpoints end to end in-process (TestClient) on the real pipeline."""

from __future__ import annotations

import base64

import numpy as np
import pytest
import trimesh

from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf
from tests.api.api_helpers import TEST_METHOD, capsule, metric, off_bytes, wait_job


def upload(client, data: bytes, name: str = "mesh.obj", **form):
    return client.post("/v1/meshes", files={"file": (name, data)}, data=form)


def test_health_and_ready(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz")
    assert ready.status_code == 200, ready.text
    assert ready.json()["checks"]["cache"] == {"ok": True, "detail": "disk"}


def test_upload_read_shdf_and_delete(client, capsule_obj):
    response = upload(client, capsule_obj, "capsule.obj")
    assert response.status_code == 200, response.text
    body = response.json()
    mesh = load_mesh(capsule_obj, "obj")
    assert body["mesh"]["mesh_id"] == mesh.content_hash()
    assert body["mesh"]["faces"] == mesh.input_face_count
    assert body["shdf"] == {**body["shdf"], "method": TEST_METHOD, "cached": False}
    mesh_id = body["mesh"]["mesh_id"]

    again = upload(client, capsule_obj, "capsule.obj").json()
    assert again["shdf"]["cached"] is True and again["shdf"]["seconds"] == 0

    info = client.get(f"/v1/meshes/{mesh_id}").json()
    assert info["triangles"] == mesh.face_count and body["mesh"]["format"] == "obj"
    assert info["format"] is None and info["filename"] is None  # per upload, not kept
    assert info["bounds"] == [mesh.vertices.min(0).tolist(), mesh.vertices.max(0).tolist()]

    as_json = client.get(f"/v1/meshes/{mesh_id}/shdf").json()
    expected = mesh.to_input_faces(compute_shdf(mesh, method=TEST_METHOD, seed=0).values)
    np.testing.assert_allclose(as_json["values"], expected, rtol=1e-12)
    binary = client.get(
        f"/v1/meshes/{mesh_id}/shdf", headers={"Accept": "application/octet-stream"}
    )
    assert binary.headers["content-type"] == "application/octet-stream"
    np.testing.assert_array_equal(np.frombuffer(binary.content, "<f4"), expected.astype(np.float32))
    assert client.get(f"/v1/meshes/{mesh_id}/shdf?format=f32").content == binary.content

    assert client.delete(f"/v1/meshes/{mesh_id}").status_code == 204
    gone = client.get(f"/v1/meshes/{mesh_id}")
    assert gone.status_code == 404 and gone.json()["error"]["code"] == "mesh_not_found"
    assert client.post("/v1/segment", json={"mesh_id": mesh_id}).status_code == 404
    assert client.delete(f"/v1/meshes/{mesh_id}").status_code == 404


def test_a_second_uploader_of_the_same_geometry_sees_only_their_own_file_name(client, capsule_obj):
    """Meshes are stored by geometry: the second upload shares the mesh and its ShDF, but
    its answer names its own file and time, and nobody reads back the first one's name."""
    first = upload(client, capsule_obj, "alice-secret-project.obj").json()["mesh"]
    second = upload(client, capsule_obj, "bob.obj").json()
    assert second["mesh"]["mesh_id"] == first["mesh_id"] and second["shdf"]["cached"]
    assert second["mesh"]["filename"] == "bob.obj"
    assert second["mesh"]["uploaded_at"] >= first["uploaded_at"]
    read_back = client.get(f"/v1/meshes/{first['mesh_id']}")
    assert "alice" not in read_back.text and "bob" not in read_back.text
    one_shot = client.post(
        "/v1/segment/file", files={"file": ("carol.obj", capsule_obj)}, data={"clusters": 2}
    )
    assert one_shot.status_code == 200 and "alice" not in one_shot.text


def test_segment_reruns_only_the_partitioning(client, capsule_obj):
    app = client.app
    mesh_id = upload(client, capsule_obj).json()["mesh"]["mesh_id"]
    assert metric(app, "neural_shdf_shdf_computations_total", method=TEST_METHOD) == 1
    first = client.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 2})
    second = client.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 4})
    metis = client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "partitioner": "metis", "parts": 3}
    )
    for response in (first, second, metis):
        assert response.status_code == 200, response.text
        timings = response.json()["timings"]
        assert timings["shdf_cached"] is True and timings["shdf_ms"] == 0
        assert timings["segmentation_cached"] is False
    assert metric(app, "neural_shdf_shdf_computations_total", method=TEST_METHOD) == 1
    assert metric(app, "neural_shdf_segmentations_total") == 3

    body = metis.json()
    assert body["part_count"] == 3 and sorted(set(body["labels"])) == [0, 1, 2]
    mesh = load_mesh(capsule_obj, "obj")
    assert len(body["labels"]) == mesh.input_face_count
    assert sum(p["faces"] for p in body["parts"]) == mesh.input_face_count
    assert sum(p["area"] for p in body["parts"]) == pytest.approx(capsule().area)
    assert all(0 <= p["mean_shdf"] <= 1 for p in body["parts"])
    for part in body["parts"]:
        assert part["faces"] == body["labels"].count(part["label"])

    repeat = client.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 2}).json()
    assert repeat["labels"] == first.json()["labels"]
    assert repeat["timings"]["segmentation_cached"] is True

    # One seed seeds every random step: another seed means the ShDF of that seed (as the
    # CLI's --seed and the library's compute_shdf(seed=...).values with SegmentParams(seed=...)).
    reseeded = client.post("/v1/segment", json={"mesh_id": mesh_id, "seed": 3}).json()
    assert reseeded["timings"]["shdf_cached"] is False
    assert metric(app, "neural_shdf_shdf_computations_total", method=TEST_METHOD) == 2
    assert metric(app, "neural_shdf_segmentations_total") == 4

    compact = client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "clusters": 2, "labels_format": "base64"}
    ).json()
    assert compact["labels"] is None
    assert compact["labels_dtype"] == "int8"
    decoded = np.frombuffer(base64.b64decode(compact["labels_base64"]), "<i1")
    assert decoded.tolist() == first.json()["labels"]


def test_segment_file_one_shot_matches_two_steps(client, capsule_obj):
    one_shot = client.post(
        "/v1/segment/file",
        files={"file": ("c.obj", capsule_obj)},
        data={"partitioner": "metis", "parts": "2"},
    )
    assert one_shot.status_code == 200, one_shot.text
    mesh_id = one_shot.json()["mesh_id"]
    stored = client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "partitioner": "metis", "parts": 2}
    )
    assert stored.json()["labels"] == one_shot.json()["labels"]
    assert stored.json()["timings"]["segmentation_cached"] is True


def test_glb_outputs(client, capsule_obj):
    mesh_id = upload(client, capsule_obj).json()["mesh"]["mesh_id"]
    query = "?partitioner=metis&parts=3"
    labels = client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "partitioner": "metis", "parts": 3}
    ).json()["labels"]
    colored = client.get(f"/v1/meshes/{mesh_id}/segmentation/colored.glb{query}")
    assert colored.status_code == 200 and colored.headers["content-type"] == "model/gltf-binary"
    scene = trimesh.load(trimesh.util.wrap_as_stream(colored.content), file_type="glb")
    colors = np.concatenate([g.visual.vertex_colors for g in scene.geometry.values()])
    assert len(np.unique(colors[:, :3], axis=0)) == 3

    parts = client.get(f"/v1/meshes/{mesh_id}/segmentation/parts.glb{query}")
    scene = trimesh.load(trimesh.util.wrap_as_stream(parts.content), file_type="glb")
    sizes = {name: len(g.faces) for name, g in scene.geometry.items()}
    assert sizes == {f"part_{k:03d}": labels.count(k) for k in range(3)}


def test_usd_uploads_and_parts_come_back_as_usd(client, tmp_path):
    from pxr import Usd, UsdGeom

    from neural_shdf.exchange.gltf_writer import part_name
    from tests.exchange.test_usd import _dumbbell_stage

    source = tmp_path / "dumbbell.usda"
    counts = _dumbbell_stage(source)
    uploaded = client.post(
        "/v1/segment/file",
        files={"file": ("dumbbell.usda", source.read_bytes())},
        data={"method": TEST_METHOD},
    )
    assert uploaded.status_code == 200, uploaded.text
    labels = np.array(uploaded.json()["labels"])
    assert len(labels) == sum(counts)
    mesh_id = uploaded.json()["mesh_id"]
    answer = client.get(f"/v1/meshes/{mesh_id}/segmentation/parts.usda?method={TEST_METHOD}")
    assert answer.status_code == 200 and answer.headers["content-type"] == "model/vnd.usda"
    path = tmp_path / "parts.usda"
    path.write_bytes(answer.content)
    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh.Get(stage, "/World/Mesh")
    subsets = UsdGeom.Subset.GetGeomSubsets(mesh, UsdGeom.Tokens.face, "part")
    found = {s.GetPrim().GetName(): list(s.GetIndicesAttr().Get()) for s in subsets}
    assert found == {part_name(k): np.flatnonzero(labels == k).tolist() for k in set(labels)}
    written, original = load_mesh(path), load_mesh(source)  # same faces, float32 points
    assert np.array_equal(written.faces, original.faces)
    assert np.array_equal(written.face_origin, original.face_origin)
    assert np.allclose(written.vertices, original.vertices, atol=1e-6)


def test_large_mesh_runs_as_a_job(app_factory, capsule_obj):
    from fastapi.testclient import TestClient

    with TestClient(app_factory(sync_face_threshold=100)) as client:
        accepted = upload(client, capsule_obj)
        assert accepted.status_code == 202, accepted.text
        job = accepted.json()
        assert accepted.headers["location"] == f"/v1/jobs/{job['job_id']}"
        assert job["state"] in ("queued", "running")
        done = wait_job(client, job)
        assert done["state"] == "succeeded" and done["progress"] == 1.0
        result = client.get(done["result_url"])
        assert result.status_code == 200
        assert len(result.json()["values"]) == load_mesh(capsule_obj, "obj").input_face_count
        # The result stays: uploading again answers at once from the cache.
        again = upload(client, capsule_obj)
        assert again.status_code == 200 and again.json()["shdf"]["cached"] is True
        segmented = client.post("/v1/segment", json={"mesh_id": done["mesh_id"]})
        assert segmented.status_code == 200
        # A large mesh whose ShDF (another seed) is not cached: segment answers 202 too.
        other = client.post("/v1/segment", json={"mesh_id": done["mesh_id"], "seed": 7})
        if TEST_METHOD == "exact":
            assert other.status_code == 202
            assert wait_job(client, other.json())["state"] == "succeeded"
        unknown = client.get("/v1/jobs/" + "0" * 32).json()
        assert unknown["error"]["code"] == "job_not_found"


def test_metrics_exposition(client, capsule_obj):
    upload(client, capsule_obj)
    text = client.get("/metrics").text
    assert "neural_shdf_shdf_computations_total" in text
    assert 'neural_shdf_http_requests_total{method="POST",route="/v1/meshes",status="200"}' in text


@pytest.mark.parametrize("enabled", [True, False])
def test_start_up_warms_the_compiled_paths_unless_disabled(app_factory, monkeypatch, enabled):
    from fastapi.testclient import TestClient

    from neural_shdf.api import app as app_module

    calls = []
    monkeypatch.setattr(app_module, "warm_up", lambda: calls.append(1) or 0.0)
    with TestClient(app_factory(warm_up=enabled)) as test_client:
        assert test_client.get("/healthz").status_code == 200
    assert calls == ([1] if enabled else [])


def test_a_failing_warm_up_does_not_stop_the_service(app_factory, monkeypatch):
    from fastapi.testclient import TestClient

    from neural_shdf.api import app as app_module

    def broken() -> float:
        raise RuntimeError("simulated warm-up failure")

    monkeypatch.setattr(app_module, "warm_up", broken)
    with TestClient(app_factory()) as test_client:
        assert test_client.get("/healthz").status_code == 200


def test_geometry_is_the_stored_triangles_with_their_input_faces(client):
    from tests.api.api_helpers import obj_bytes, quad_box

    vertices, quads = quad_box((0.0, 0.0, 0.0), 1.0)
    data = obj_bytes(vertices, quads)
    mesh_id = upload(client, data, name="box.obj").json()["mesh"]["mesh_id"]
    response = client.get(f"/v1/meshes/{mesh_id}/geometry")
    assert response.status_code == 200
    assert response.headers["content-type"] == "application/octet-stream"
    blob = response.content
    assert blob[:4] == b"NSHG"
    version, v, t, f = np.frombuffer(blob[4:20], "<u4")
    mesh = load_mesh(data, "obj")
    assert (version, v, t, f) == (1, 8, 12, 6)
    positions = np.frombuffer(blob, "<f4", 3 * v, 20).reshape(-1, 3)
    triangles = np.frombuffer(blob, "<u4", 3 * t, 20 + 12 * v).reshape(-1, 3)
    origin = np.frombuffer(blob, "<u4", t, 20 + 12 * v + 12 * t)
    np.testing.assert_allclose(positions, mesh.vertices, atol=1e-6)
    np.testing.assert_array_equal(triangles, mesh.faces)
    np.testing.assert_array_equal(origin, np.repeat(np.arange(6), 2))
    missing = client.get(f"/v1/meshes/{'0' * 64}/geometry")
    assert missing.status_code == 404 and missing.json()["error"]["code"] == "mesh_not_found"


def test_parts_carry_the_coloured_glb_palette(client, capsule_obj):
    from neural_shdf.palette import part_colors

    mesh_id = upload(client, capsule_obj).json()["mesh"]["mesh_id"]
    body = client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "partitioner": "metis", "parts": 4}
    ).json()
    palette = part_colors(4)[:, :3]
    for part in body["parts"]:
        rgb = [int(part["color"][i : i + 2], 16) for i in (1, 3, 5)]
        assert rgb == palette[part["label"]].tolist()


def cut_hierarchy(tree: dict, leaves: list[int], parts: int) -> list[int]:
    """A client's re-cut of the `hierarchy` member, following the schema's recipe."""
    count, parent = tree["leaf_count"], tree["parent"]
    top = []
    for leaf in range(count):
        node = leaf
        while parent[node] != -1 and parent[node] < 2 * count - parts:
            node = parent[node]
        top.append(node)
    order = sorted(set(top), key=top.index)  # by smallest leaf
    return [-1 if leaf < 0 else order.index(top[leaf]) for leaf in leaves]


def test_graphcut_returns_its_part_tree_for_cuts_without_a_request(client, capsule_obj):
    mesh_id = upload(client, capsule_obj).json()["mesh"]["mesh_id"]
    fine = {"mesh_id": mesh_id, "smoothing": 0.02}
    body = client.post("/v1/segment", json=fine).json()
    tree = body["hierarchy"]
    count = tree["leaf_count"]
    assert count >= 2 and tree["parts"] == body["part_count"]
    assert len(tree["leaf_labels"]) == body["faces"]
    assert len(tree["parent"]) == 2 * count - 1 and tree["parent"][-1] == -1
    assert len(tree["merge_cost"]) == len(tree["merge_height"]) == count - 1
    assert cut_hierarchy(tree, tree["leaf_labels"], tree["parts"]) == body["labels"]
    for parts in range(1, count + 1):
        asked = client.post("/v1/segment", json={**fine, "parts": parts}).json()
        assert asked["part_count"] == parts
        assert asked["hierarchy"]["parent"] == tree["parent"]
        assert cut_hierarchy(tree, tree["leaf_labels"], parts) == asked["labels"]

    compact = client.post("/v1/segment", json={**fine, "labels_format": "base64"}).json()
    packed = compact["hierarchy"]
    assert packed["leaf_labels"] is None
    dtype = {"int8": "<i1", "int16": "<i2", "int32": "<i4"}[packed["leaf_labels_dtype"]]
    decoded = np.frombuffer(base64.b64decode(packed["leaf_labels_base64"]), dtype)
    assert decoded.tolist() == tree["leaf_labels"]

    metis = client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "partitioner": "metis", "parts": 2}
    ).json()
    assert metis["hierarchy"] is None


def test_an_upload_of_a_surface_split_in_pieces_says_what_was_stitched(client):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    upper = vertices[faces].mean(axis=1)[:, 2] > 0
    # The upper half on copies of the vertices moved up a little (a quarter of an edge):
    # two open shells along the cut, as a kitbashed or CAD export gives them.
    split = np.where(upper[:, None], faces + len(vertices), faces)
    body = off_bytes(np.vstack([vertices, vertices + [0.0, 0.0, 0.02]]), split)
    response = upload(client, body, "halves.off")
    assert response.status_code == 200, response.text
    diagnostics = response.json()["mesh"]["diagnostics"]
    assert diagnostics["shells"] == 2 and diagnostics["boundary_loops"] == 2
    assert diagnostics["stitched_shells"] == 2 and diagnostics["stitched_vertices"] > 0


def test_an_inside_out_upload_says_so_and_gets_the_published_shdf(client):
    published = capsule()
    faces = np.asarray(published.faces)
    reference = upload(client, off_bytes(published.vertices, faces), "capsule.off").json()
    response = upload(client, off_bytes(published.vertices, faces[:, ::-1]), "inside_out.off")
    assert response.status_code == 200, response.text
    diagnostics = response.json()["mesh"]["diagnostics"]
    assert diagnostics == {
        "shells": 1,
        "boundary_loops": 0,
        "non_manifold_edges": 0,
        "reoriented_faces": len(faces),
        "degenerate_faces": 0,
        "duplicate_faces": 0,
        "stitched_shells": 0,
        "stitched_vertices": 0,
    }
    mesh_id = response.json()["mesh"]["mesh_id"]
    assert client.get(f"/v1/meshes/{mesh_id}").json()["diagnostics"] == diagnostics
    assert reference["mesh"]["diagnostics"]["reoriented_faces"] == 0
    values = client.get(f"/v1/meshes/{mesh_id}/shdf").json()["values"]
    expected = client.get(f"/v1/meshes/{reference['mesh']['mesh_id']}/shdf").json()["values"]
    np.testing.assert_allclose(values, expected, atol=1e-9)


def test_parts_come_back_in_the_uploads_own_usd_stage(client, tmp_path):
    """parts.usda with the source_id of a USD upload: the file's own prims (transforms,
    UVs, normals) with one GeomSubset per part on each mesh prim."""
    import hashlib

    from pxr import Usd, UsdGeom

    from tests.exchange.test_usd import _dumbbell_stage

    source = tmp_path / "dumbbell.usda"
    counts = _dumbbell_stage(source)
    body = upload(client, source.read_bytes(), "dumbbell.usda", method=TEST_METHOD).json()
    mesh_id, source_id = body["mesh"]["mesh_id"], body["mesh"]["source_id"]
    assert source_id == hashlib.sha256(b"usda\0" + source.read_bytes()).hexdigest()
    assert client.get(f"/v1/meshes/{mesh_id}").json()["source_id"] is None  # per upload
    labels = np.array(
        client.post("/v1/segment", json={"mesh_id": mesh_id, "method": TEST_METHOD}).json()[
            "labels"
        ]
    )
    query = f"?method={TEST_METHOD}&source={source_id}"
    answer = client.get(f"/v1/meshes/{mesh_id}/segmentation/parts.usda{query}")
    assert answer.status_code == 200, answer.text
    path = tmp_path / "parts.usda"
    path.write_bytes(answer.content)
    stage = Usd.Stage.Open(str(path))
    offsets = np.cumsum([0, *counts])
    for prim_path, start, end in zip(
        ("/World/Bar/Shape", "/World/Drum/Shape"), offsets[:-1], offsets[1:], strict=True
    ):
        mesh = UsdGeom.Mesh.Get(stage, prim_path)
        assert UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st").IsDefined()  # the file's own UVs
        subsets = UsdGeom.Subset.GetGeomSubsets(mesh, UsdGeom.Tokens.face, "part")
        found = {s.GetPrim().GetName(): list(s.GetIndicesAttr().Get()) for s in subsets}
        own = labels[start:end]
        assert found == {f"part_{k:03d}": np.flatnonzero(own == k).tolist() for k in np.unique(own)}
    missing = client.get(f"/v1/meshes/{mesh_id}/segmentation/parts.usda?source={'0' * 64}")
    assert missing.status_code == 404 and missing.json()["error"]["code"] == "source_not_found"


def test_parts_glb_keeps_the_uploads_uvs_normals_and_materials(client):
    from neural_shdf.mesh_io import load_source
    from tests.exchange.scene_helpers import parts_order, textured_scene_glb

    data = textured_scene_glb()
    body = upload(client, data, "scene.glb", method=TEST_METHOD).json()
    mesh_id, source_id = body["mesh"]["mesh_id"], body["mesh"]["source_id"]
    query = f"?method={TEST_METHOD}&partitioner=metis&parts=3&source={source_id}"
    answer = client.get(f"/v1/meshes/{mesh_id}/segmentation/parts.glb{query}")
    assert answer.status_code == 200, answer.text
    labels = np.array(
        client.post(
            "/v1/segment",
            json={"mesh_id": mesh_id, "method": TEST_METHOD, "partitioner": "metis", "parts": 3},
        ).json()["labels"]
    )
    source, back = load_source(data, "glb"), load_source(answer.content, "glb")
    order = parts_order(source, labels)
    for name in ("normals", "colors"):
        ours = getattr(back.attributes, name)[back.attributes.corners]
        theirs = getattr(source.attributes, name)[source.attributes.corners][order]
        np.testing.assert_array_equal(ours, theirs)
    assert len(back.attributes.uvs) == 2
    plain = client.get(f"/v1/meshes/{mesh_id}/segmentation/parts.glb?method={TEST_METHOD}")
    assert load_source(plain.content, "glb").attributes.normals is None  # no source: as before


def test_segment_symmetry_is_the_librarys_and_keeps_its_own_basis(client, capsule_obj, tmp_path):
    from neural_shdf.pipeline import segment
    from neural_shdf.segment import SegmentParams

    mesh_id = client.post("/v1/meshes", files={"file": ("capsule.obj", capsule_obj)}).json()[
        "mesh"
    ]["mesh_id"]
    request = {"mesh_id": mesh_id, "method": TEST_METHOD, "smoothing": 0.02}
    plain = client.post("/v1/segment", json=request).json()
    symmetric = client.post("/v1/segment", json={**request, "symmetry": True})
    assert symmetric.status_code == 200, symmetric.text
    path = tmp_path / "capsule.obj"
    path.write_bytes(capsule_obj)
    mesh = load_mesh(path)
    shdf = compute_shdf(mesh, method=TEST_METHOD).values
    expected = segment(mesh, shdf, SegmentParams(smoothing=0.02, symmetry=True))
    assert expected.reflection is not None
    labels, _ = expected.input_face_parts(mesh)
    assert symmetric.json()["labels"] == labels.tolist()
    # Off again: the plain labels (the symmetric basis never stands in for the plain one).
    assert client.post("/v1/segment", json=request).json()["labels"] == plain["labels"]


def test_segment_file_names_the_uploads_kept_file(client, tmp_path):
    """The one-shot route keeps the file like an upload and answers its source_id (body
    and X-Source-Id), so parts.glb keeps a USDZ's materials and texture; a format whose
    file holds nothing to keep (STL) answers none."""
    import hashlib

    from pxr import UsdUtils

    from neural_shdf.mesh_io import load_source
    from tests.exchange.test_usd import WOOD_PNG, _material_stage, _png

    package = tmp_path / "materials.usdz"
    assert UsdUtils.CreateNewUsdzPackage(str(_material_stage(tmp_path)), str(package))
    data = package.read_bytes()
    answer = client.post(
        "/v1/segment/file",
        files={"file": ("materials.usdz", data)},
        data={"method": TEST_METHOD, "partitioner": "metis", "parts": 2},
    )
    assert answer.status_code == 200, answer.text
    body = answer.json()
    source_id = hashlib.sha256(b"usdz\0" + data).hexdigest()
    assert body["source_id"] == answer.headers["x-source-id"] == source_id
    query = f"?method={TEST_METHOD}&partitioner=metis&parts=2&source={source_id}"
    glb = client.get(f"/v1/meshes/{body['mesh_id']}/segmentation/parts.glb{query}")
    assert glb.status_code == 200, glb.text
    back = load_source(glb.content, "glb").attributes.materials
    assert back.image_data == (_png(WOOD_PNG),)
    assert {m["name"] for m in back.materials} >= {"/World/Looks/Wood", "/World/Looks/Paint"}
    stl = client.post(
        "/v1/segment/file",
        files={"file": ("capsule.stl", capsule().export(file_type="stl"))},
        data={"method": TEST_METHOD},
    )
    assert stl.status_code == 200, stl.text
    assert "source_id" not in stl.json() and "x-source-id" not in stl.headers
