"""Part labellers through the API: upload (checked before use), list, read, download,
delete, named parts from `/v1/segment` and the parts GLB/USD, training as a job; and a
labeller stored by one uvicorn process still there after a restart."""

from __future__ import annotations

import base64
import io
import json
import struct
import zipfile

import httpx
import numpy as np
import pytest

from neural_shdf.labeling import label_mesh, labeler_id, load_labeler
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf
from tests.api.api_helpers import TEST_METHOD, wait_job
from tests.api.conftest import running_server
from tests.labeling.helpers import BALL, NECK, labelled_dumbbell, obj_of, small_labeler_file


@pytest.fixture(scope="module")
def labeler_file() -> bytes:
    return small_labeler_file()


@pytest.fixture(scope="module")
def new_mesh() -> tuple[bytes, np.ndarray]:
    """A dumbbell the labeller never saw (other proportions, another pose) and its labels."""
    mesh, labels = labelled_dumbbell(1500, 0.9, 3)
    return obj_of(mesh), labels


def upload_labeler(client, data: bytes, name: str = "parts.npz"):
    return client.post("/v1/labelers", files={"file": (name, data)})


def upload_mesh(client, data: bytes) -> str:
    response = client.post("/v1/meshes", files={"file": ("mesh.obj", data)})
    assert response.status_code == 200, response.text
    return response.json()["mesh"]["mesh_id"]


def glb_document(data: bytes) -> dict:
    length = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20 : 20 + length])


def test_upload_list_read_download_and_delete(client, labeler_file):
    response = upload_labeler(client, labeler_file)
    assert response.status_code == 200, response.text
    info = response.json()
    identifier = labeler_id(load_labeler(labeler_file))
    assert info["labeler_id"] == identifier
    assert (info["label_names"], info["label_values"]) == (["neck", "ball"], [NECK, BALL])
    assert info["size_bytes"] == len(labeler_file) and info["training_meshes"] == 2
    again = upload_labeler(client, labeler_file, "copy.npz").json()
    assert again == info  # content-addressed: one entry, first stored time kept
    page = {"labelers": [info], "total": 1, "next_offset": None}
    assert client.get("/v1/labelers").json() == page
    assert client.get(f"/v1/labelers/{identifier}").json() == info
    download = client.get(f"/v1/labelers/{identifier}/file")
    assert download.status_code == 200 and download.content == labeler_file
    assert client.delete(f"/v1/labelers/{identifier}").status_code == 204
    for path in (f"/v1/labelers/{identifier}", f"/v1/labelers/{identifier}/file"):
        gone = client.get(path)
        assert gone.status_code == 404 and gone.json()["error"]["code"] == "labeler_not_found"
    assert client.get("/v1/labelers").json() == {"labelers": [], "total": 0, "next_offset": None}
    assert client.delete(f"/v1/labelers/{identifier}").status_code == 404


def test_the_list_comes_a_page_at_a_time(client, labeler_file):
    from dataclasses import replace

    from neural_shdf.labeling import labeler_bytes

    base = load_labeler(labeler_file)
    stored = [
        upload_labeler(
            client, labeler_bytes(replace(base, label_names=(f"neck{i}", "ball")))
        ).json()["labeler_id"]
        for i in range(3)
    ]
    first = client.get("/v1/labelers", params={"limit": 2}).json()
    assert [e["labeler_id"] for e in first["labelers"]] == stored[:2]
    assert (first["total"], first["next_offset"]) == (3, 2)
    second = client.get("/v1/labelers", params={"limit": 2, "offset": 2}).json()
    assert [e["labeler_id"] for e in second["labelers"]] == stored[2:]
    assert second["next_offset"] is None
    for query in ({"limit": 0}, {"limit": 1001}, {"offset": -1}):
        assert client.get("/v1/labelers", params=query).status_code == 422
    for identifier in stored:
        assert client.delete(f"/v1/labelers/{identifier}").status_code == 204


def rewritten(data: bytes, change) -> bytes:
    with np.load(io.BytesIO(data)) as archive:
        arrays = {name: archive[name] for name in archive.files}
    change(arrays)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def test_files_that_are_not_sound_labellers_are_refused_before_use(app_factory, labeler_file):
    from fastapi.testclient import TestClient

    def damage(arrays):
        arrays["value"] = arrays["value"] + 1.0

    def pickled(arrays):
        arrays["threshold"] = np.array([object()] * len(arrays["threshold"]), dtype=object)

    def old_features(arrays):
        metadata = json.loads(arrays["metadata"].tobytes())
        metadata["feature_version"] = 1
        arrays["metadata"] = np.frombuffer(json.dumps(metadata).encode(), np.uint8)

    bomb = io.BytesIO()
    with zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("metadata.npy", b"\0" * (300 * 1024**2))  # unpacks past 256 MB
    cases = {
        b"not a zip": "not a labeller file",
        rewritten(labeler_file, damage): "checksum",
        rewritten(labeler_file, pickled): "",
        rewritten(labeler_file, old_features): "train it again",
        bomb.getvalue(): "unpacks to",
    }
    with TestClient(app_factory(max_labeler_bytes=len(labeler_file) + 1024**2)) as client:
        for data, message in cases.items():
            response = upload_labeler(client, data)
            assert response.status_code == 422, response.text
            error = response.json()["error"]
            assert error["code"] == "invalid_labeler" and message in error["message"]
        too_big = upload_labeler(client, labeler_file + b"\0" * (1024**2 + 1))
        assert too_big.status_code == 413
        assert too_big.json()["error"]["detail"]["max_labeler_bytes"] > 0
        assert client.get("/v1/labelers").json()["labelers"] == []


def test_segment_with_a_labeler_gives_named_parts_from_the_cached_shdf(
    client, labeler_file, new_mesh
):
    data, truth = new_mesh
    identifier = upload_labeler(client, labeler_file).json()["labeler_id"]
    mesh_id = upload_mesh(client, data)  # computes and caches the ShDF
    response = client.post("/v1/segment", json={"mesh_id": mesh_id, "labeler_id": identifier})
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["timings"]["shdf_cached"] and not body["timings"]["segmentation_cached"]
    assert body["labeler_id"] == identifier and body["hierarchy"] is None
    assert (body["label_names"], body["label_values"]) == (["neck", "ball"], [NECK, BALL])
    labels = np.array(body["labels"])
    assert len(labels) == len(truth) == body["faces"]
    assert np.mean(labels == truth) > 0.95
    # The library's labels from the same ShDF: the API adds nothing of its own.
    mesh = load_mesh(data, "obj")
    shdf = compute_shdf(mesh, method=TEST_METHOD).values
    expected, confidence = label_mesh(mesh, load_labeler(labeler_file), shdf=shdf)
    np.testing.assert_array_equal(labels, expected)
    np.testing.assert_allclose(body["confidence"], confidence, atol=1e-4)
    parts = {part["name"]: part for part in body["parts"]}
    assert set(parts) == {"neck", "ball"} and body["part_count"] == 2
    assert parts["ball"]["label"] == BALL and parts["ball"]["faces"] == int(np.sum(labels == BALL))
    # Cached, and in the compact form the same labels and confidence.
    compact = client.post(
        "/v1/segment",
        json={"mesh_id": mesh_id, "labeler_id": identifier, "labels_format": "base64"},
    ).json()
    assert compact["timings"]["segmentation_cached"] and compact["labels"] is None
    packed = np.frombuffer(base64.b64decode(compact["labels_base64"]), compact["labels_dtype"])
    np.testing.assert_array_equal(packed, labels)
    scores = np.frombuffer(base64.b64decode(compact["confidence_base64"]), "<f4")
    np.testing.assert_allclose(scores, confidence, atol=1e-6)


def test_parts_glb_and_usd_carry_the_label_names(client, labeler_file, new_mesh):
    identifier = upload_labeler(client, labeler_file).json()["labeler_id"]
    mesh_id = upload_mesh(client, new_mesh[0])
    query = {"labeler_id": identifier}
    glb = client.get(f"/v1/meshes/{mesh_id}/segmentation/parts.glb", params=query)
    assert glb.status_code == 200, glb.text
    assert [node["name"] for node in glb_document(glb.content)["nodes"]] == ["neck", "ball"]
    plain = client.get(f"/v1/meshes/{mesh_id}/segmentation/parts.glb")
    assert all(n["name"].startswith("part_") for n in glb_document(plain.content)["nodes"])
    usda = client.get(f"/v1/meshes/{mesh_id}/segmentation/parts.usda", params=query)
    assert usda.status_code == 200, usda.text
    text = usda.text
    for name in ("neck", "ball"):
        assert f'def GeomSubset "{name}"' in text and f'def Material "{name}"' in text
    colored = client.get(f"/v1/meshes/{mesh_id}/segmentation/colored.glb", params=query)
    assert colored.status_code == 200


def test_labeler_requests_that_cannot_be_served_say_why(client, labeler_file, new_mesh):
    mesh_id = upload_mesh(client, new_mesh[0])
    missing = client.post("/v1/segment", json={"mesh_id": mesh_id, "labeler_id": "a" * 64})
    assert missing.status_code == 404
    assert missing.json()["error"]["code"] == "labeler_not_found"
    bad = client.post("/v1/segment", json={"mesh_id": mesh_id, "labeler_id": "not-an-id"})
    assert bad.status_code == 422
    identifier = upload_labeler(client, labeler_file).json()["labeler_id"]
    edits = [{"op": "merge", "faces": [0, 1]}]
    both = client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "labeler_id": identifier, "edits": edits}
    )
    assert both.status_code == 422 and "edits" in both.json()["error"]["message"]


def labels_file(*arrays: np.ndarray) -> bytes:
    return np.concatenate(arrays).astype("<i4").tobytes()


def test_train_from_stored_meshes_as_a_job_then_label_with_it(client, new_mesh):
    examples = [labelled_dumbbell(1500, stretch, seed) for stretch, seed in ((1.0, None), (1.2, 5))]
    mesh_ids = [upload_mesh(client, obj_of(mesh)) for mesh, _ in examples]
    response = client.post(
        "/v1/labeler-trainings",
        data={"mesh_ids": ",".join(mesh_ids), "names": "neck,ball"},
        files={"labels": ("labels.bin", labels_file(*(labels for _, labels in examples)))},
    )
    assert response.status_code == 202, response.text
    job = response.json()
    assert job["kind"] == "labeler" and response.headers["location"] == f"/v1/jobs/{job['job_id']}"
    done = wait_job(client, job, timeout_s=300)
    assert done["state"] == "succeeded", done
    info = client.get(done["result_url"]).json()
    assert info["label_names"] == ["neck", "ball"] and info["training_meshes"] == 2
    target = upload_mesh(client, new_mesh[0])
    body = client.post(
        "/v1/segment", json={"mesh_id": target, "labeler_id": info["labeler_id"]}
    ).json()
    assert np.mean(np.array(body["labels"]) == new_mesh[1]) > 0.95


def test_training_requests_are_bounded_and_checked_before_any_work(app_factory, new_mesh):
    from fastapi.testclient import TestClient

    mesh, labels = labelled_dumbbell(1500)
    with TestClient(app_factory(max_train_meshes=2, max_train_triangles=5000)) as client:
        mesh_id = upload_mesh(client, obj_of(mesh))

        def train(ids, data, **form):
            return client.post(
                "/v1/labeler-trainings",
                data={"mesh_ids": ",".join(ids), **form},
                files={"labels": ("l.bin", data)},
            )

        cases = [
            (train([mesh_id] * 3, labels_file(labels, labels, labels)), 413, "too_many_meshes"),
            (train([mesh_id, mesh_id], labels_file(labels, labels)), 422, "given twice"),
            (train([mesh_id], labels_file(labels[:-1])), 422, "labels for meshes of"),
            (train([mesh_id], labels_file(labels)[:-1]), 422, "multiple of 4"),
            (train([mesh_id], labels_file(np.zeros_like(labels))), 422, "distinct values"),
            (train([mesh_id], labels_file(labels), names="a,b,c"), 422, "3 label names"),
            (train([mesh_id], labels_file(labels), names="a,"), 422, "empty name"),
            (train(["zz"], labels_file(labels)), 422, "not a mesh id"),
            (train(["0" * 64], labels_file(labels)), 404, "mesh_not_found"),
            (train([mesh_id], labels_file(labels), smoothing="-1"), 422, "smoothing"),
        ]
        for response, status, text in cases:
            assert response.status_code == status, response.text
            assert text in response.text
        big = upload_mesh(client, obj_of(labelled_dumbbell(4000)[0]))
        too_large = train([mesh_id, big], labels_file(labels, labelled_dumbbell(4000)[1]))
        assert too_large.status_code == 413 and "training_too_large" in too_large.text


def test_a_stored_labeler_survives_a_restart_of_the_service(tmp_path, labeler_file):
    cache = tmp_path / "cache"
    with running_server(cache, max_labeler_bytes=1_000_000) as base:
        stored = httpx.post(f"{base}/v1/labelers", files={"file": ("l.npz", labeler_file)})
        assert stored.status_code == 200, stored.text
    with running_server(cache) as base:
        listed = httpx.get(f"{base}/v1/labelers").json()["labelers"]
        assert [entry["labeler_id"] for entry in listed] == [stored.json()["labeler_id"]]
        download = httpx.get(f"{base}/v1/labelers/{listed[0]['labeler_id']}/file")
        assert download.content == labeler_file
