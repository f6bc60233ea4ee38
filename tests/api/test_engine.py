"""Compute-once guarantees: concurrent dedup, corrupt entries, failures, degraded cache."""

from __future__ import annotations

import asyncio
import threading

import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient

from neural_shdf.mesh_io import load_mesh
from neural_shdf.shdf.stage import ShdfParams
from neural_shdf.store.codec import MAGIC, seal
from neural_shdf.store.keys import shdf_params_digest
from tests.api.api_helpers import MODEL_FILE, TEST_METHOD, free_port, metric


async def _concurrent_uploads(app, data: bytes, count: int) -> list[httpx.Response]:
    transport = httpx.ASGITransport(app=app)
    async with httpx.AsyncClient(transport=transport, base_url="http://test") as client:
        return await asyncio.gather(
            *[client.post("/v1/meshes", files={"file": ("m.obj", data)}) for _ in range(count)]
        )


def test_concurrent_uploads_compute_once(app_factory, capsule_obj):
    app = app_factory()
    responses = asyncio.run(_concurrent_uploads(app, capsule_obj, 6))
    assert [r.status_code for r in responses] == [200] * 6
    assert len({r.json()["mesh"]["mesh_id"] for r in responses}) == 1
    assert metric(app, "neural_shdf_shdf_computations_total", method=TEST_METHOD) == 1


def test_two_apps_on_one_disk_cache_compute_once(app_factory, capsule_obj, tmp_path):
    """Two app instances (like two uvicorn workers) share the disk cache and its lock."""
    first, second = app_factory(), app_factory()
    results = []

    def post(app):
        with TestClient(app) as client:
            results.append(client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}))

    threads = [threading.Thread(target=post, args=(app,)) for app in (first, second)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert [r.status_code for r in results] == [200, 200]
    total = sum(
        metric(app, "neural_shdf_shdf_computations_total", method=TEST_METHOD)
        for app in (first, second)
    )
    assert total == 1


def test_corrupt_entry_is_recomputed_never_served(app_factory, capsule_obj):
    app = app_factory()
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}).json()["mesh"][
            "mesh_id"
        ]
        good = client.get(f"/v1/meshes/{mesh_id}/shdf?format=f32").content
        key = engine.shdf.key(mesh_id, TEST_METHOD, 0)
        blob = engine.cache.backend.get(key)
        assert blob.startswith(MAGIC)
        flipped = bytearray(blob)
        flipped[-5] ^= 0xFF  # a bit flip in the payload
        for bad in (bytes(flipped), blob[: len(blob) // 2], b"garbage", seal(b"not an npz")):
            engine.cache.backend.set(key, bad, group=mesh_id)
            engine.cache._memory.clear()
            assert client.get(f"/v1/meshes/{mesh_id}/shdf?format=f32").content == good
        assert metric(app, "neural_shdf_cache_corrupt_entries_total") == 4
        assert metric(app, "neural_shdf_shdf_computations_total", method=TEST_METHOD) == 5


def test_a_corrupt_mesh_entry_is_gone_for_every_route(app_factory, capsule_obj):
    app = app_factory()
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}).json()["mesh"][
            "mesh_id"
        ]
        key = f"{mesh_id}:mesh"
        engine.cache.backend.set(key, engine.cache.backend.get(key)[:-7], group=mesh_id)
        engine.cache._memory.clear()
        segment = client.post("/v1/segment", json={"mesh_id": mesh_id, "method": TEST_METHOD})
        assert segment.status_code == 404
        assert "damaged" in segment.json()["error"]["message"]
        assert client.get(f"/v1/meshes/{mesh_id}").status_code == 404
        # Evicted geometry: metadata answers 404 too, without any route reading the mesh.
        again = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)})
        assert again.status_code == 200 and client.get(f"/v1/meshes/{mesh_id}").status_code == 200
        engine.cache.backend.delete(key)
        engine.cache._memory.clear()
        assert client.get(f"/v1/meshes/{mesh_id}").status_code == 404
        assert client.post("/v1/segment", json={"mesh_id": mesh_id}).status_code == 404


def test_failed_computation_leaves_no_entry(app_factory, capsule_obj, monkeypatch):
    import neural_shdf.pipeline

    app = app_factory(warm_up=False)
    engine = app.state.engine

    def broken(*args, **kwargs):
        raise RuntimeError("simulated crash in the middle of the computation")

    monkeypatch.setattr(neural_shdf.pipeline, "compute_shdf", broken)
    with TestClient(app, raise_server_exceptions=False) as client:
        response = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)})
        assert response.status_code == 500
        assert response.json()["error"]["code"] == "internal_error"
        mesh_id = load_mesh(capsule_obj, "obj").content_hash()
        assert engine.cache.backend.get(engine.shdf.key(mesh_id, TEST_METHOD, 0)) is None
        monkeypatch.undo()
        again = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)})
        assert again.status_code == 200 and again.json()["shdf"]["cached"] is False


def test_unreachable_redis_degrades_to_computing(app_factory, capsule_obj):
    app = app_factory(redis_url=f"redis://127.0.0.1:{free_port()}/0", redis_timeout_s=0.2)
    with TestClient(app) as client:
        ready = client.get("/readyz")  # degraded, still serving: the disk cache stands in
        assert ready.status_code == 200 and ready.json()["status"] == "degraded"
        assert ready.json()["checks"]["cache"]["ok"] is False
        first = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)})
        assert first.status_code == 200, first.text
        segment = client.post(
            "/v1/segment", json={"mesh_id": first.json()["mesh"]["mesh_id"], "clusters": 2}
        )
        assert segment.status_code == 200, segment.text
        assert metric(app, "neural_shdf_cache_errors_total") > 0


@pytest.mark.skipif(TEST_METHOD != "neural", reason="the committed model emd.onnx is absent")
def test_neural_is_the_default_and_keyed_by_model_version(client, capsule_obj):
    engine = client.app.state.engine
    assert engine.shdf.model_version is not None
    body = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}).json()
    assert body["shdf"]["method"] == "neural"
    key = engine.shdf.key(body["mesh"]["mesh_id"], "neural", 0)
    assert key.endswith(shdf_params_digest("neural", ShdfParams(seed=0), engine.shdf.model_version))
    other_model = shdf_params_digest("neural", ShdfParams(seed=0), "0" * 16)
    assert not key.endswith(other_model)
    values = client.get(f"/v1/meshes/{body['mesh']['mesh_id']}/shdf").json()
    assert values["model_version"] == engine.shdf.model_version
    assert np.all((np.array(values["values"]) >= 0) & (np.array(values["values"]) <= 1))


def test_missing_model_is_reported_not_crashed(app_factory, capsule_obj, monkeypatch, tmp_path):
    missing = tmp_path / "absent.onnx"
    monkeypatch.setenv("NEURAL_SHDF_MODEL", str(missing))  # the library reads it too
    app = app_factory(default_method="neural", model=missing)
    with TestClient(app) as client:
        ready = client.get("/readyz")
        assert ready.status_code == 503 and ready.json()["checks"]["model"]["ok"] is False
        response = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)})
        assert response.status_code == 503, response.text
        assert response.json()["error"]["code"] == "model_unavailable"
        exact = client.post(
            "/v1/meshes", files={"file": ("m.obj", capsule_obj)}, data={"method": "exact"}
        )
        assert exact.status_code == 200


def test_long_computation_never_blocks_polling_or_cached_reads(
    app_factory, capsule_obj, monkeypatch
):
    import neural_shdf.pipeline
    from tests.api.api_helpers import capsule, wait_job

    real = neural_shdf.pipeline.compute_shdf
    release = threading.Event()

    def slow(mesh, **kwargs):
        kwargs["progress"](0.5)
        assert release.wait(30)
        return real(mesh, **kwargs)

    app = app_factory(compute_threads=1, sync_face_threshold=300)
    with TestClient(app) as client:
        small = client.post("/v1/meshes", files={"file": ("s.obj", capsule_obj)})
        small_id = small.json()["mesh"]["mesh_id"]
        cached = client.post("/v1/segment", json={"mesh_id": small_id}).json()
        monkeypatch.setattr(neural_shdf.pipeline, "compute_shdf", slow)
        big = capsule(16).export(file_type="obj").encode()  # 480 faces: a job
        job = client.post("/v1/meshes", files={"file": ("b.obj", big)}).json()
        try:
            for _ in range(100):  # the job reports its progress while the compute thread is busy
                polled = client.get(f"/v1/jobs/{job['job_id']}").json()
                if polled["progress"] == 0.5:
                    break
                threading.Event().wait(0.05)
            assert polled["state"] == "running" and polled["progress"] == 0.5
            assert client.get("/healthz").status_code == 200
            app.state.engine.cache._memory.clear()  # read the disk cache (I/O pool)
            again = client.post("/v1/segment", json={"mesh_id": small_id}).json()
            assert again["labels"] == cached["labels"]
        finally:
            release.set()
        assert wait_job(client, job)["state"] == "succeeded"


@pytest.mark.parametrize(
    ("labels", "dtype"),
    [([0, -1, 5, 127], "int8"), ([0, 128, -1], "int16"), ([2**15, 0], "int32"), ([], "int8")],
)
def test_compact_labels_use_the_narrowest_integer(labels, dtype):
    import base64

    from neural_shdf.api.segmentation import StoredSegmentation

    result = StoredSegmentation(
        labels=np.array(labels, dtype=np.int32),
        triangle_labels=np.array(labels, dtype=np.int32),
        part_faces=np.zeros(0, np.int64),
        part_area=np.zeros(0),
        part_mean_shdf=np.zeros(0),
        segment_seconds=0.0,
    )
    encoded, name = result.labels_base64
    assert name == dtype
    decoded = np.frombuffer(base64.b64decode(encoded), np.dtype(dtype).newbyteorder("<"))
    assert decoded.tolist() == labels


@pytest.mark.parametrize(
    ("labels", "dtype"), [([0, -1, 5, 127], "int8"), ([0, 128, -1], "int16"), ([2**15, 0], "int32")]
)
def test_cached_segmentations_keep_labels_narrow_and_read_back_as_int32(labels, dtype):
    from neural_shdf.api.segmentation import StoredSegmentation
    from neural_shdf.store.codec import decode_arrays, encode_arrays

    per_face = np.array(labels, dtype=np.int32)
    result = StoredSegmentation(
        labels=per_face,
        triangle_labels=per_face[::-1].copy(),
        part_faces=np.zeros(0, np.int64),
        part_area=np.zeros(0),
        part_mean_shdf=np.zeros(0),
        segment_seconds=0.5,
        leaf_labels=per_face,
    )
    arrays = result.arrays()
    assert {arrays[name].dtype.name for name in ("labels", "triangle_labels", "leaf_labels")} == {
        dtype
    }
    back = StoredSegmentation.from_arrays(decode_arrays(encode_arrays(arrays)))
    for name in ("labels", "triangle_labels", "leaf_labels"):
        assert getattr(back, name).dtype == np.int32
        assert getattr(back, name).tolist() == getattr(result, name).tolist()
    assert back.labels_base64 == result.labels_base64
    assert back.segment_seconds == 0.5


def test_the_model_setting_decides_which_network_computes(app_factory, capsule_obj, tmp_path):
    """Settings.model is the network that computes, not only the readiness and the cache key."""
    from neural_shdf.pipeline import compute_shdf
    from tests.model_helpers import perturbed_model

    if not MODEL_FILE.is_file():
        pytest.skip("no committed model")
    other = perturbed_model(tmp_path)
    mesh = load_mesh(capsule_obj, "obj")
    served = {}
    for name, model in (("default", None), ("other", other)):
        app = app_factory(model=model, default_method="neural", cache_dir=tmp_path / name)
        with TestClient(app) as client:
            upload = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}).json()
            assert upload["shdf"]["method"] == "neural"
            mesh_id = upload["mesh"]["mesh_id"]
            raw = client.get(f"/v1/meshes/{mesh_id}/shdf?format=f32").content
            served[name] = np.frombuffer(raw, dtype="<f4")
    expected = mesh.to_input_faces(compute_shdf(mesh, method="neural", seed=0, model=other).values)
    np.testing.assert_allclose(served["other"], expected, atol=1e-6)
    assert np.abs(served["other"] - served["default"]).max() > 1e-3


def test_auto_reports_the_producer_that_ran(app_factory, capsule_obj):
    with TestClient(app_factory(default_method="auto")) as client:
        upload = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}).json()
        assert upload["shdf"]["method"] == "exact"  # a small mesh: every face's rays
        mesh_id = upload["mesh"]["mesh_id"]
        assert client.get(f"/v1/meshes/{mesh_id}/shdf").json()["method"] == "exact"
        segmented = client.post("/v1/segment", json={"mesh_id": mesh_id}).json()
        assert segmented["method"] == "exact"
        sampled = client.post("/v1/segment", json={"mesh_id": mesh_id, "method": "sampled"})
        assert sampled.json()["method"] == "sampled"


def test_new_smoothing_values_reuse_the_mesh_basis(app_factory, capsule_obj):
    """What does not depend on smoothing is prepared once per mesh, ShDF, clusters and
    seed; later values only re-cut, with the labels the library gives without it."""
    from neural_shdf.pipeline import SegmentParams, compute_shdf, segment

    app = app_factory()
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}).json()
        mesh_id = mesh_id["mesh"]["mesh_id"]
        bodies = [{"mesh_id": mesh_id, "smoothing": s} for s in (0.1, 0.2, 0.3)]
        bodies.append({"mesh_id": mesh_id, "smoothing": 0.2, "clusters": 3})
        answers = [client.post("/v1/segment", json=body).json() for body in bodies]
    prepared = [key for key in engine.cache._working if ":basis:" in key]
    assert len(prepared) == 2, prepared  # default clusters, and clusters=3
    # The crease refinement's graph depends on the mesh only: the stored mesh keeps one.
    assert "crease_graph" in engine.cache.recall(f"{mesh_id}:mesh").distinct.mesh.__dict__
    mesh = load_mesh(capsule_obj, file_type="obj")
    shdf = compute_shdf(mesh, method=TEST_METHOD, model=MODEL_FILE).values
    for body, answer in zip(bodies, answers, strict=True):
        params = SegmentParams(smoothing=body["smoothing"], clusters=body.get("clusters"))
        np.testing.assert_array_equal(answer["labels"], segment(mesh, shdf, params).labels)


def test_every_result_key_carries_the_algorithm_version(client):
    """ShDF, segmentation and atlas keys all change with ALGORITHM_VERSION."""
    from neural_shdf.constants import ALGORITHM_VERSION
    from neural_shdf.segment import SegmentParams
    from neural_shdf.unwrap import UnwrapParams

    engine = client.app.state.engine
    mesh_id, params = "0" * 64, SegmentParams()
    keys = [
        engine.shdf.key(mesh_id, "exact", 0),
        engine.segmentations.key(mesh_id, "exact", params),
        engine.unwraps.key(mesh_id, "exact", params, UnwrapParams()),
    ]
    assert all(f":a{ALGORITHM_VERSION}:" in key for key in keys), keys


def test_replica_b_segments_what_replica_a_uploaded(app_factory, redis_url, capsule_obj, tmp_path):
    """Two app instances (replicas) share only the Redis URL; B never recomputes the ShDF."""
    replica_a = app_factory(redis_url=redis_url, cache_dir=tmp_path / "a")
    replica_b = app_factory(redis_url=redis_url, cache_dir=tmp_path / "b")
    with TestClient(replica_a) as a, TestClient(replica_b) as b:
        assert b.get("/readyz").json()["checks"]["cache"] == {"ok": True, "detail": "redis"}
        mesh_id = a.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}).json()["mesh"][
            "mesh_id"
        ]
        assert b.get(f"/v1/meshes/{mesh_id}").status_code == 200
        from_b = b.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 3})
        assert from_b.status_code == 200, from_b.text
        assert from_b.json()["timings"]["shdf_cached"] is True
        name = "neural_shdf_shdf_computations_total"
        assert metric(replica_a, name, method=TEST_METHOD) == 1
        assert metric(replica_b, name, method=TEST_METHOD) == 0
        # B's segmentation is cached for A as well; a deletion through A reaches B.
        from_a = a.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 3}).json()
        assert from_a["labels"] == from_b.json()["labels"]
        assert from_a["timings"]["segmentation_cached"] is True
        assert a.delete(f"/v1/meshes/{mesh_id}").status_code == 204
        # B's memory still holds the mesh and the segmentation: it must not serve them.
        assert b.get(f"/v1/meshes/{mesh_id}").status_code == 404
        gone = b.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 3})
        assert gone.status_code == 404
        other = b.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 2})
        assert other.status_code == 404
