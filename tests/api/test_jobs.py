"""Jobs: a dead worker's job is re-run or failed, never `running` for ever; jobs accepted
while Redis is down or frozen stay pollable."""

from __future__ import annotations

import time

from fastapi.testclient import TestClient

from neural_shdf.store.keys import job_key
from tests.api.api_helpers import TEST_METHOD, metric, wait_job


def _orphan(engine, mesh_id: str, seed: int, attempt: int = 1) -> dict:
    """A job record as a worker killed mid-job leaves it: running, not written since."""
    job = engine.jobs.create(mesh_id, TEST_METHOD, seed)
    job.update(state="running", attempt=attempt, worker="gone-host:4242")
    job["updated_at"] = time.time() - 10 * engine.settings.lock_lease_s
    engine.cache.put_json(job_key(job["job_id"]), job, group=mesh_id)
    return job


def _upload(client, data: bytes) -> str:
    response = client.post("/v1/meshes", files={"file": ("m.obj", data)})
    assert response.status_code == 200, response.text
    return response.json()["mesh"]["mesh_id"]


def test_a_dead_workers_job_is_rerun_by_the_next_poll(app_factory, capsule_obj):
    app = app_factory(lock_lease_s=0.5, warm_up=False)
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = _upload(client, capsule_obj)
        computed = metric(app, "neural_shdf_shdf_computations_total", method=TEST_METHOD)
        job = _orphan(engine, mesh_id, seed=7)
        polled = client.get(f"/v1/jobs/{job['job_id']}").json()
        assert polled["attempt"] == 2 and polled["state"] in ("queued", "running")
        assert "worker" not in polled  # bookkeeping stays internal
        done = wait_job(client, polled)
        assert done["state"] == "succeeded" and done["attempt"] == 2
        assert metric(app, "neural_shdf_shdf_computations_total", method=TEST_METHOD) == (
            computed + 1
        )
        assert metric(app, "neural_shdf_jobs_rerun_total") == 1
        shdf = client.get(done["result_url"])
        assert shdf.status_code == 200 and shdf.json()["seed"] == 7


def test_a_job_whose_runner_process_is_gone_is_rerun_at_once(app_factory, capsule_obj):
    """A fresh record, but its runner's lease names a process of this machine that exited."""
    import subprocess
    import sys

    from neural_shdf.store.leases import MACHINE

    app = app_factory(lock_lease_s=600, warm_up=False)
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = _upload(client, capsule_obj)
        job = engine.jobs.create(mesh_id, TEST_METHOD, 11)
        engine.jobs.update(job, state="running")
        exited = subprocess.run(
            [sys.executable, "-c", "import os; print(os.getpid())"],
            capture_output=True,
            text=True,
            check=True,
        )
        token = f"{MACHINE}:{int(exited.stdout)}:dead"
        assert engine.cache.backend.acquire_lease(job_key(job["job_id"]), token, 600)
        polled = client.get(f"/v1/jobs/{job['job_id']}").json()
        assert polled["attempt"] == 2
        assert wait_job(client, polled)["state"] == "succeeded"


def test_a_job_whose_runner_is_alive_is_left_alone(app_factory, capsule_obj):
    """A stale record alone is not enough: the runner's lease must have lapsed."""
    app = app_factory(lock_lease_s=0.5, warm_up=False)
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = _upload(client, capsule_obj)
        job = _orphan(engine, mesh_id, seed=3)
        runner = engine.jobs.runner_lease(job["job_id"])
        assert runner.try_acquire()  # a live runner (slow to write its record)
        try:
            polled = client.get(f"/v1/jobs/{job['job_id']}").json()
            assert polled["state"] == "running" and polled["attempt"] == 1
        finally:
            runner.release()
        assert client.get(f"/v1/jobs/{job['job_id']}").json()["attempt"] == 2


def test_a_job_that_keeps_killing_its_worker_fails(app_factory, capsule_obj):
    app = app_factory(lock_lease_s=0.5, warm_up=False, job_max_attempts=3)
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = _upload(client, capsule_obj)
        job = _orphan(engine, mesh_id, seed=5, attempt=3)
        polled = client.get(f"/v1/jobs/{job['job_id']}").json()
        assert polled["state"] == "failed" and polled["attempt"] == 3
        assert polled["error"]["code"] == "worker_lost"
        assert "stopped 3 times" in polled["error"]["message"]


def test_a_job_of_a_deleted_mesh_fails_instead_of_running(app_factory, capsule_obj):
    app = app_factory(lock_lease_s=0.5, warm_up=False)
    engine = app.state.engine
    with TestClient(app) as client:
        mesh_id = _upload(client, capsule_obj)
        job = _orphan(engine, mesh_id, seed=9)
        engine.cache.delete_group(mesh_id)
        engine.cache.put_json(job_key(job["job_id"]), job, group="elsewhere")
        polled = client.get(f"/v1/jobs/{job['job_id']}").json()
        assert polled["state"] == "failed" and polled["error"]["code"] == "mesh_not_found"


def test_jobs_stay_pollable_while_redis_is_down(app_factory, redis_server, capsule_obj):
    """Redis down: the 202's job lives in the local disk cache, and still answers once
    Redis is back (moved there)."""
    redis_server.stop()
    app = app_factory(
        redis_url=redis_server.url,
        redis_timeout_s=0.5,
        redis_retry_s=0.3,
        sync_face_threshold=10,
        warm_up=False,
    )
    with TestClient(app) as client:
        ready = client.get("/readyz")
        assert ready.status_code == 200 and ready.json()["status"] == "degraded"
        assert "local disk cache" in ready.json()["checks"]["cache"]["detail"]
        accepted = client.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)})
        assert accepted.status_code == 202, accepted.text
        done = wait_job(client, accepted.json())
        assert done["state"] == "succeeded"
        mesh_id = done["mesh_id"]
        redis_server.start()
        deadline = time.monotonic() + 10
        while client.get("/readyz").json()["status"] != "ready":
            assert time.monotonic() < deadline, "the breaker never closed"
            time.sleep(0.05)
        assert client.get(f"/v1/jobs/{done['job_id']}").json()["state"] == "succeeded"
        segment = client.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 2})
        assert segment.status_code == 200 and segment.json()["timings"]["shdf_cached"]
        assert metric(app, "neural_shdf_cache_degraded") == 0


def test_a_frozen_redis_costs_one_timeout_not_one_per_request(
    app_factory, redis_server, capsule_obj
):
    timeout = 0.5
    app = app_factory(
        redis_url=redis_server.url, redis_timeout_s=timeout, redis_retry_s=0.3, warm_up=False
    )
    with TestClient(app) as client:
        mesh_id = _upload(client, capsule_obj)
        redis_server.freeze()
        try:
            latencies = []
            for clusters in (2, 3, 2, 3, 2, 3):
                start = time.monotonic()
                response = client.post(
                    "/v1/segment", json={"mesh_id": mesh_id, "clusters": clusters}
                )
                latencies.append(time.monotonic() - start)
                assert response.status_code == 200, response.text
            assert max(latencies[1:]) < timeout, latencies  # no timeout after the first
            ready = client.get("/readyz").json()
            assert ready["status"] == "degraded" and metric(app, "neural_shdf_cache_degraded") == 1
        finally:
            redis_server.thaw()
        deadline = time.monotonic() + 10
        while client.get("/readyz").json()["status"] != "ready":
            assert time.monotonic() < deadline, "the breaker never closed"
            time.sleep(0.05)


def test_every_kind_of_job_can_be_polled_when_the_method_is_auto(app_factory, capsule_obj):
    """ShDF, unwrap and atlas jobs asked for with `auto`: each poll answers the job (the
    producer resolved, its kind and result named), never a 500."""
    app = app_factory(sync_face_threshold=10, default_method="auto", warm_up=False)
    with TestClient(app) as client:
        form = {"method": "auto"}
        accepted = client.post("/v1/meshes", files={"file": ("c.obj", capsule_obj)}, data=form)
        assert accepted.status_code == 202, accepted.text
        mesh_id = accepted.json()["mesh_id"]
        jobs = {"shdf": accepted.json()}
        for kind, name, size in (("unwrap", "unwrapped.glb", 256), ("atlas", "atlas.png", 512)):
            url = f"/v1/meshes/{mesh_id}/segmentation/{name}"
            assert wait_job(client, jobs["shdf"])["state"] == "succeeded"
            response = client.get(url, params={"method": "auto", "atlas_size": size})
            assert response.status_code == 202, response.text
            jobs[kind] = response.json()
            assert jobs[kind]["result_url"].endswith(f"/segmentation/{name}")
        for kind, job in jobs.items():
            polled = client.get(f"/v1/jobs/{job['job_id']}")
            assert polled.status_code == 200, polled.text
            assert polled.json()["kind"] == kind and polled.json()["method"] != "auto"
            assert wait_job(client, job)["state"] == "succeeded"
