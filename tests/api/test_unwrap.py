"""The unwrap routes end to end in-process on the real pipeline: UVs by part, cached."""

from __future__ import annotations

import io

import numpy as np
import trimesh

from neural_shdf.mesh_io import load_mesh
from neural_shdf.unwrap import rasterize_charts
from tests.api.api_helpers import TEST_METHOD, metric


def _upload(client, data: bytes) -> str:
    response = client.post("/v1/meshes", files={"file": ("capsule.obj", data)})
    assert response.status_code == 200, response.text
    return response.json()["mesh"]["mesh_id"]


def test_unwrapped_glb_keeps_the_triangles_and_is_computed_once(client, capsule_obj):
    mesh_id = _upload(client, capsule_obj)
    query = {"method": TEST_METHOD, "clusters": 3, "atlas_size": 256}
    response = client.get(f"/v1/meshes/{mesh_id}/segmentation/unwrapped.glb", params=query)
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "model/gltf-binary"
    loaded = trimesh.load(io.BytesIO(response.content), file_type="glb", force="mesh",
                          process=False)  # fmt: skip
    mesh = load_mesh(capsule_obj, "obj")
    assert np.allclose(loaded.vertices[loaded.faces], mesh.vertices[mesh.faces], atol=1e-6)
    corner_uvs = loaded.visual.uv[loaded.faces]
    assert corner_uvs.min() >= 0 and corner_uvs.max() <= 1

    # Charts never overlap, and each chart's triangles are one part of the segmentation.
    labels = client.post("/v1/segment", json={"mesh_id": mesh_id, **{
        k: v for k, v in query.items() if k != "atlas_size"}}).json()["labels"]  # fmt: skip
    from neural_shdf.evaluate.uv import uv_islands

    islands = uv_islands(mesh.vertices, mesh.faces, corner_uvs)
    assert rasterize_charts(corner_uvs, islands, 1024)[1] == 0
    triangle_labels = np.asarray(labels)[mesh.face_origin]
    for island in np.unique(islands):
        assert len(np.unique(triangle_labels[islands == island])) == 1

    misses = metric(client.app, "neural_shdf_cache_misses_total", kind="unwrap")
    again = client.get(f"/v1/meshes/{mesh_id}/segmentation/unwrapped.glb", params=query)
    assert again.content == response.content
    assert metric(client.app, "neural_shdf_cache_misses_total", kind="unwrap") == misses

    png = client.get(f"/v1/meshes/{mesh_id}/segmentation/atlas.png", params=query)
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    assert png.content[:8] == b"\x89PNG\r\n\x1a\n"


def test_unwrap_parameters_and_ids_get_actionable_errors(client, capsule_obj):
    mesh_id = _upload(client, capsule_obj)
    bad = client.get(f"/v1/meshes/{mesh_id}/segmentation/unwrapped.glb",
                     params={"method": TEST_METHOD, "atlas_size": 10})  # fmt: skip
    assert bad.status_code == 422
    assert "atlas_size" in bad.json()["error"]["message"]
    missing = client.get(f"/v1/meshes/{'0' * 64}/segmentation/atlas.png")
    assert missing.status_code == 404


def test_a_large_mesh_is_unwrapped_in_a_job(app_factory, capsule_obj):
    from fastapi.testclient import TestClient

    from tests.api.api_helpers import wait_job

    with TestClient(app_factory(sync_face_threshold=10)) as client:
        uploaded = client.post("/v1/meshes", files={"file": ("capsule.obj", capsule_obj)})
        assert uploaded.status_code == 202, uploaded.text  # the ShDF's job
        mesh_id = uploaded.json()["mesh_id"]
        assert wait_job(client, uploaded.json())["state"] == "succeeded"
        url = f"/v1/meshes/{mesh_id}/segmentation/unwrapped.glb"
        query = {"method": TEST_METHOD, "atlas_size": 256}
        accepted = client.get(url, params=query)
        assert accepted.status_code == 202, accepted.text  # the atlas's job
        job = accepted.json()
        assert job["result_url"].endswith("/segmentation/unwrapped.glb")
        assert wait_job(client, job)["state"] == "succeeded"
        done = client.get(url, params=query)
        assert done.status_code == 200 and done.headers["content-type"] == "model/gltf-binary"
        png = client.get(f"/v1/meshes/{mesh_id}/segmentation/atlas.png", params=query)
        assert png.status_code == 200  # the same atlas, cached: no second job


def test_the_atlas_png_is_drawn_once_and_shared_with_the_glb_texture(client, capsule_obj):
    mesh_id = _upload(client, capsule_obj)
    query = {"method": TEST_METHOD, "clusters": 3, "atlas_size": 512}
    url = f"/v1/meshes/{mesh_id}/segmentation"
    first = client.get(f"{url}/atlas.png", params=query)
    assert first.status_code == 200, first.text
    drawn = metric(client.app, "neural_shdf_cache_misses_total", kind="atlas_png")
    assert drawn >= 1  # looked up, not found, drawn
    again = client.get(f"{url}/atlas.png", params=query)
    assert again.content == first.content
    glb = client.get(f"{url}/unwrapped.glb", params=query)
    assert glb.status_code == 200 and first.content in glb.content  # the same PNG embedded
    assert metric(client.app, "neural_shdf_cache_misses_total", kind="atlas_png") == drawn


def test_atlas_sizes_outside_the_documented_range_get_422(client, capsule_obj):
    mesh_id = _upload(client, capsule_obj)
    for route in ("atlas.png", "unwrapped.glb"):
        for size in (63, 8193, 65536):
            response = client.get(f"/v1/meshes/{mesh_id}/segmentation/{route}",
                                  params={"method": TEST_METHOD, "atlas_size": size})  # fmt: skip
            assert response.status_code == 422, response.text
            assert "atlas_size" in response.json()["error"]["message"]


def test_the_atlas_is_computed_in_a_worker_process_with_the_library_s_result(client, capsule_obj):
    """xatlas packs holding the GIL, so the service unwraps in a worker process (the event
    loop keeps answering): the same UVs as the library's ``unwrap`` of the same labels."""
    import os

    from neural_shdf.unwrap import UnwrapParams, unwrap

    mesh_id = _upload(client, capsule_obj)
    query = {"method": TEST_METHOD, "clusters": 3, "atlas_size": 256}
    response = client.get(f"/v1/meshes/{mesh_id}/segmentation/unwrapped.glb", params=query)
    assert response.status_code == 200, response.text
    pool = client.app.state.engine.tasks._isolated
    assert pool is not None
    workers = [process.pid for process in pool._processes.values()]
    assert workers and os.getpid() not in workers
    loaded = trimesh.load(io.BytesIO(response.content), file_type="glb", force="mesh",
                          process=False)  # fmt: skip
    segment = {k: v for k, v in query.items() if k != "atlas_size"}
    labels = np.array(
        client.post("/v1/segment", json={"mesh_id": mesh_id, **segment}).json()["labels"]
    )
    mesh = load_mesh(capsule_obj, "obj")
    atlas = unwrap(mesh, labels[mesh.face_origin], UnwrapParams(atlas_size=256))
    np.testing.assert_allclose(loaded.visual.uv[loaded.faces], atlas.corner_uvs, atol=1e-6)


def test_uvs_and_the_obj_give_each_input_polygon_its_corner_uvs(client):
    """A quad-dominant mesh: /uvs answers one UV per corner of each polygon in the file's order (the
    library's atlas read back from each fan), and unwrapped.obj has one `f` per polygon."""
    import base64

    from neural_shdf.unwrap import UnwrapParams, polygon_corner_uvs, unwrap
    from tests.api.api_helpers import quad_dumbbell_obj

    data = quad_dumbbell_obj(rings=12, sectors=8)
    response = client.post("/v1/meshes", files={"file": ("dumbbell.obj", data)})
    assert response.status_code == 200, response.text
    mesh_id = response.json()["mesh"]["mesh_id"]
    query = {"method": TEST_METHOD, "clusters": 3, "atlas_size": 256}
    answer = client.get(f"/v1/meshes/{mesh_id}/segmentation/uvs", params=query)
    assert answer.status_code == 200, answer.text
    body = answer.json()
    counts = np.frombuffer(base64.b64decode(body["corner_counts_base64"]), "<i4")
    uvs = np.frombuffer(base64.b64decode(body["uvs_base64"]), "<f4").reshape(-1, 2)
    chart = np.frombuffer(base64.b64decode(body["chart_base64"]), "<i4")
    mesh = load_mesh(data, "obj")
    assert body["faces"] == mesh.input_face_count == len(counts) == len(chart)
    assert set(counts.tolist()) == {3, 4}  # triangle fans at the poles, quads between
    assert body["corners"] == len(uvs) == counts.sum()

    segment = {k: v for k, v in query.items() if k != "atlas_size"}
    labels = np.array(
        client.post("/v1/segment", json={"mesh_id": mesh_id, **segment}).json()["labels"]
    )
    atlas = unwrap(mesh, labels, UnwrapParams(atlas_size=256))
    expected = polygon_corner_uvs(mesh, atlas.corner_uvs)
    np.testing.assert_allclose(uvs, expected.uvs, atol=1e-6)
    assert body["split_faces"] == int((~expected.consistent).sum())
    # Each face's chart is one of its part's charts.
    assert np.array_equal(np.asarray(body["chart_part"])[chart], labels)

    obj = client.get(f"/v1/meshes/{mesh_id}/segmentation/unwrapped.obj", params=query)
    assert obj.status_code == 200 and obj.headers["content-type"].startswith("model/obj")
    lines = obj.text.splitlines()
    face_lines = [line for line in lines if line.startswith("f ")]
    assert len(face_lines) == mesh.input_face_count + body["split_faces"]
    vt = np.array([line.split()[1:] for line in lines if line.startswith("vt ")], dtype=float)
    first = [int(corner.split("/")[1]) - 1 for corner in face_lines[0].split()[1:]]
    np.testing.assert_allclose(vt[first], uvs[: counts[0]], atol=1e-6)
