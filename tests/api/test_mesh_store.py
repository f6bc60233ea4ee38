"""Deletion is final: a result computed while its mesh is deleted is never stored, on disk
or in Redis, and the mesh uploaded again starts from nothing."""

from __future__ import annotations

import functools
import time

import pytest
from fastapi.testclient import TestClient

from neural_shdf.api.errors import ApiError
from tests.api.api_helpers import TEST_METHOD, metric, wait_job


def _upload(client: TestClient, data: bytes) -> dict:
    response = client.post("/v1/meshes", files={"file": ("m.obj", data)})
    assert response.status_code in (200, 202), response.text
    return response.json()


@pytest.mark.parametrize("store", ["disk", "redis"])
def test_a_result_finished_after_its_mesh_was_deleted_is_never_stored(
    app_factory, capsule_obj, request, store
):
    """The race, forced: the real ShDF is computed, then the DELETE lands before the
    result is stored. The store is refused (404), nothing is left under the key, and the
    mesh uploaded again computes its ShDF afresh."""
    redis = {"redis_url": request.getfixturevalue("redis_url")} if store == "redis" else {}
    app = app_factory(warm_up=False, **redis)
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = _upload(client, capsule_obj)["mesh"]["mesh_id"]
        seed = 5  # a ShDF the upload did not compute
        key = engine.shdf.key(mesh_id, TEST_METHOD, seed)
        mesh = engine.meshes.load(mesh_id)

        def compute_then_delete():
            outcome = engine.shdf._compute(key, mesh_id, mesh, TEST_METHOD, seed)
            assert client.delete(f"/v1/meshes/{mesh_id}").status_code == 204
            return outcome

        with pytest.raises(ApiError) as refused:
            engine.tasks.compute_once(
                key,
                lambda: None,
                compute_then_delete,
                functools.partial(engine.shdf._store, key, mesh_id),
                functools.partial(engine.meshes.guard, mesh_id),
            )
        assert refused.value.status_code == 404 and "deleted" in refused.value.message
        assert engine.cache.get_arrays(key) is None and engine.cache.recall(key) is None
        again = client.post(
            "/v1/meshes", files={"file": ("m.obj", capsule_obj)}, data={"seed": seed}
        )
        assert again.status_code == 200 and again.json()["shdf"]["cached"] is False


def test_a_result_of_a_mesh_deleted_and_uploaded_again_is_not_stored_for_the_new_one(
    app_factory, capsule_obj
):
    """Deleted and uploaded again while the first upload's computation ran: that result
    belongs to the deleted mesh, so it is refused too (a new upload, a new generation)."""
    app = app_factory(warm_up=False)
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = _upload(client, capsule_obj)["mesh"]["mesh_id"]
        key = engine.shdf.key(mesh_id, TEST_METHOD, 6)
        guard = engine.meshes.guard(mesh_id)  # taken when the computation started
        assert client.delete(f"/v1/meshes/{mesh_id}").status_code == 204
        _upload(client, capsule_obj)
        mesh = engine.meshes.load(mesh_id)
        outcome = engine.shdf._compute(key, mesh_id, mesh, TEST_METHOD, 6)
        with pytest.raises(ApiError):
            engine.shdf._store(key, mesh_id, outcome, guard)
        assert engine.cache.get_arrays(key) is None


def test_deleting_a_mesh_while_its_job_runs_leaves_nothing_behind(app_factory, capsule_obj):
    """The issue's sequence over HTTP: upload (a job), DELETE at once (204), the job ends,
    and the mesh uploaded again finds no ShDF cached."""
    app = app_factory(sync_face_threshold=10, warm_up=False)
    with TestClient(app) as client:
        job = _upload(client, capsule_obj)
        assert client.delete(f"/v1/meshes/{job['mesh_id']}").status_code == 204
        deadline = time.monotonic() + 120
        while metric(app, "neural_shdf_jobs_running") > 0:  # the job ran to its end
            assert time.monotonic() < deadline, "the job did not end"
            time.sleep(0.05)
        again = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)})
        assert again.status_code == 202, again.text  # computed again: nothing was kept
        assert wait_job(client, again.json())["state"] == "succeeded"


def test_an_uploads_file_is_kept_per_upload_and_deleted_with_its_mesh(app_factory, capsule_obj):
    """Two files of one geometry (the second with a comment) get two source ids; each
    names its own bytes; deleting the mesh deletes both."""
    app = app_factory(warm_up=False)
    engine = app.state.engine
    with TestClient(app) as client:
        first = _upload(client, capsule_obj)["mesh"]
        second = _upload(client, b"# exported by hand\n" + capsule_obj)["mesh"]
        assert first["mesh_id"] == second["mesh_id"]
        assert first["source_id"] != second["source_id"]
        mesh_id = first["mesh_id"]
        assert engine.meshes.source(mesh_id, second["source_id"])[0].startswith(b"# exported")
        assert engine.meshes.source(mesh_id, first["source_id"]) == (capsule_obj, "obj")
        assert client.delete(f"/v1/meshes/{mesh_id}").status_code == 204
        for upload in (first, second):
            with pytest.raises(ApiError) as missing:
                engine.meshes.source(mesh_id, upload["source_id"])
            assert missing.value.status_code == 404
