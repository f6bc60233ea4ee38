"""The service as a real uvicorn process on loopback (`python -m neural_shdf.api.serve`)."""

from __future__ import annotations

import asyncio
import os
import signal
import time

import httpx
import numpy as np
import pytest

from neural_shdf.mesh_io import load_mesh
from neural_shdf.store.backends import DiskBackend
from neural_shdf.store.cache import ResultCache
from neural_shdf.store.codec import unseal
from neural_shdf.store.keys import job_key
from tests.api.api_helpers import TEST_METHOD, capsule, free_port, wait_job
from tests.api.conftest import running_server


def test_real_server_end_to_end(uvicorn_server, capsule_obj):
    with httpx.Client(base_url=uvicorn_server, timeout=60) as client:
        assert client.get("/readyz").status_code == 200
        uploaded = client.post("/v1/meshes", files={"file": ("c.obj", capsule_obj)})
        assert uploaded.status_code == 200, uploaded.text
        mesh_id = uploaded.json()["mesh"]["mesh_id"]
        assert uploaded.json()["shdf"]["method"] == TEST_METHOD
        shdf = np.frombuffer(
            client.get(f"/v1/meshes/{mesh_id}/shdf", params={"format": "f32"}).content, "<f4"
        )
        assert len(shdf) == load_mesh(capsule_obj, "obj").input_face_count
        segmented = client.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 2})
        assert segmented.status_code == 200 and segmented.json()["timings"]["shdf_cached"]
        too_big = client.post("/v1/meshes", files={"file": ("b.obj", b"v 0 0 0\n" * 300_000)})
        assert too_big.status_code == 413
        assert too_big.json()["error"]["code"] == "payload_too_large"
        assert client.get("/healthz").json() == {"status": "ok"}
        assert "neural_shdf_http_requests_total" in client.get("/metrics").text


def test_real_server_concurrent_duplicates_compute_once(uvicorn_server):
    import trimesh

    data = trimesh.creation.icosphere(subdivisions=3).export(file_type="ply")

    async def burst() -> list[httpx.Response]:
        async with httpx.AsyncClient(base_url=uvicorn_server, timeout=60) as client:
            return await asyncio.gather(
                *[client.post("/v1/meshes", files={"file": ("s.ply", data)}) for _ in range(8)]
            )

    line = f'neural_shdf_shdf_computations_total{{method="{TEST_METHOD}"}}'
    before = computations(uvicorn_server, line)
    responses = asyncio.run(burst())
    assert [r.status_code for r in responses] == [200] * 8
    assert len({r.json()["mesh"]["mesh_id"] for r in responses}) == 1
    assert computations(uvicorn_server, line) == before + 1


def test_two_workers_compute_once_and_report_one_metrics_view(two_worker_server):
    """Two processes behind one port: the disk cache's lock dedups across them, and
    /metrics (multiprocess mode) sums both workers."""
    import trimesh

    data = trimesh.creation.icosphere(subdivisions=3).export(file_type="stl")
    line = f'neural_shdf_shdf_computations_total{{method="{TEST_METHOD}"}}'

    async def burst() -> list[httpx.Response]:
        # Separate connections so that both workers get requests.
        clients = [httpx.AsyncClient(base_url=two_worker_server, timeout=60) for _ in range(8)]
        try:
            return await asyncio.gather(
                *[c.post("/v1/meshes", files={"file": ("s.stl", data)}) for c in clients]
            )
        finally:
            await asyncio.gather(*[c.aclose() for c in clients])

    responses = asyncio.run(burst())
    assert [r.status_code for r in responses] == [200] * 8
    assert computations(two_worker_server, line) == 1
    requests = 'neural_shdf_http_requests_total{method="POST",route="/v1/meshes",status="200"}'
    assert computations(two_worker_server, requests) == 8


def computations(base: str, line: str) -> float:
    for text in httpx.get(f"{base}/metrics").text.splitlines():
        if text.startswith(line):
            return float(text.split()[-1])
    return 0.0


def test_docker_healthcheck_command_passes_against_the_server(uvicorn_server):
    """The Dockerfile's HEALTHCHECK command, run as is against a live server."""
    import json
    import os
    import re
    import subprocess
    import sys

    from tests.api.api_helpers import REPO_ROOT

    dockerfile = (REPO_ROOT / "Dockerfile").read_text()
    assert re.search(r"^FROM python:3\.11-slim", dockerfile, re.M)
    assert re.search(r"^USER (?!root)\S+", dockerfile, re.M)
    assert "RUN pip install -c constraints.txt ." in dockerfile
    assert re.search(r'^CMD \["neural-shdf", "serve"\]', dockerfile, re.M)
    assert "NEURAL_SHDF_HOST=0.0.0.0" in dockerfile
    command = json.loads(re.search(r"HEALTHCHECK .*?CMD (\[[^\n]*\])", dockerfile, re.S).group(1))
    assert command[0] == "python"
    port = uvicorn_server.rsplit(":", 1)[1]
    env = {**os.environ, "NEURAL_SHDF_PORT": port}
    assert subprocess.run([sys.executable, *command[1:]], env=env, timeout=30).returncode == 0
    env["NEURAL_SHDF_PORT"] = "1"  # nothing listens there: the check must fail
    assert (
        subprocess.run(
            [sys.executable, *command[1:]], env=env, timeout=30, capture_output=True
        ).returncode
        != 0
    )
    ignored = (REPO_ROOT / ".dockerignore").read_text().split()
    assert not {"service", "pyproject.toml", "README.md"} & set(ignored)


@pytest.mark.slow
def test_kill_9_mid_job_leaves_no_stuck_lock_job_or_partial_entry(tmp_path):
    """kill -9 while an exact ShDF job holds its compute lock, restart, re-upload: the new
    job does not wait for the 600 s lock timeout, and the old job is re-run, not stuck."""
    cache_dir = tmp_path / "cache"
    # 320k faces: seconds of exact ShDF even on a quiet machine, so the kill lands mid-job
    # (job records are rewritten every 0.5 s: a job shorter than that may finish first).
    data = capsule(400).export(file_type="ply")
    settings = {
        "default_method": "exact",
        "sync_face_threshold": "10",
        "lock_lease_s": "2",
        "warm_up": "false",
        "max_upload_bytes": str(16 * 1024**2),
    }
    port = free_port()
    with (
        running_server(cache_dir, port=port, **settings) as base,
        httpx.Client(base_url=base, timeout=60) as client,
    ):
        old = client.post("/v1/meshes", files={"file": ("c.ply", data)})
        assert old.status_code == 202, old.text
        old_job = old.json()
        deadline = time.monotonic() + 120
        while client.get(f"/v1/jobs/{old_job['job_id']}").json()["progress"] <= 0:
            assert time.monotonic() < deadline, "the job never started computing"
            time.sleep(0.02)
        cache = ResultCache(DiskBackend(cache_dir, 2 * 1024**3))
        worker = cache.get_json(job_key(old_job["job_id"]))["worker"]
        os.kill(int(worker.rsplit(":", 1)[1]), signal.SIGKILL)  # mid-computation, lock held
        cache.close()
    with (
        running_server(cache_dir, port=port, **settings) as base,
        httpx.Client(base_url=base, timeout=60) as client,
    ):
        start = time.monotonic()
        again = client.post("/v1/meshes", files={"file": ("c.ply", data)})
        assert again.status_code == 202, again.text  # nothing partial was cached
        assert wait_job(client, again.json(), timeout_s=120)["state"] == "succeeded"
        assert time.monotonic() - start < 60  # the lock lapsed (lock_timeout_s is 600)
        rerun = wait_job(client, old_job, timeout_s=60)
        assert rerun["state"] == "succeeded" and rerun["attempt"] == 2
    cache = ResultCache(DiskBackend(cache_dir, 2 * 1024**3))
    for key in cache.backend._cache.iterkeys():
        value = cache.backend.get(key)
        if value is not None and not key.startswith("lease:"):
            unseal(value)  # every entry verifies: no partial write survived the crash
    cache.close()


def test_start_up_says_what_it_does_before_serving(tmp_path):
    """The warm-up (up to ~15 s after an install) is announced, not silent."""
    log_file = tmp_path / "serve.log"
    with running_server(tmp_path / "cache", log_file=log_file, log_level="info"):
        pass
    log = log_file.read_text()
    lines = [
        "neural-shdf ",
        "warming up:",
        "warm-up done in",
        "Application startup complete",
    ]
    positions = [log.find(line) for line in lines]
    assert -1 not in positions and positions == sorted(positions), log
