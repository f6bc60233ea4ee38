"""Load test of the REST service on loopback: a real uvicorn process, httpx + asyncio clients.

``python benchmarks/bench_service.py [--quick] [--method neural|exact] [--workers N]``

Prints, measured in one run:

* cached ``POST /v1/segment`` on a ~20k-face mesh with 1, 8 and 32 concurrent
  clients: throughput, p50/p99 latency and errors, for the JSON labels and the
  compact ``base64`` labels (int8 here) (goal: >= 50 req/s, p99 <= 200 ms, 0 errors;
  ratios printed as measured / goal);
  "server ms" is the server's own mean time per request (its metrics histogram,
  from the request's arrival in the app to the response), the rest of the
  latency is queueing, the network stack and the client;
* upload-to-ShDF latency (upload, then polling the job when the mesh is above
  the synchronous threshold) for ~10k, ~100k and ~500k faces.

The clients run on the same machine as the server and share its CPU cores.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
import trimesh

REPO_ROOT = Path(__file__).resolve().parents[1]
MODEL = REPO_ROOT / "service" / "neural_shdf" / "models" / "emd.onnx"
GOAL_RPS = 50.0
GOAL_P99_MS = 200.0


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def capsule_ply(target_faces: int) -> tuple[bytes, int]:
    """A capsule tessellated to about ``target_faces`` faces, as binary PLY."""
    count = max(8, int(round((target_faces / 2) ** 0.5)))
    mesh = trimesh.creation.capsule(height=2.0, radius=0.5, count=(count, count))
    return mesh.export(file_type="ply"), len(mesh.faces)


def start_server(
    cache_dir: str,
    method: str,
    workers: int,
    *,
    source: Path | None = None,
    request_timeout_s: float | None = 600,
) -> tuple[subprocess.Popen, str]:
    """``neural-shdf serve`` on a free loopback port, once it answers ``/healthz``.

    ``source``: the package tree to run (another checkout, for side-by-side runs);
    ``request_timeout_s``: None keeps the service's default."""
    port = free_port()
    env = {
        **os.environ,
        "NEURAL_SHDF_HOST": "127.0.0.1",
        "NEURAL_SHDF_PORT": str(port),
        "NEURAL_SHDF_CACHE_DIR": cache_dir,
        "NEURAL_SHDF_DEFAULT_METHOD": method,
        "NEURAL_SHDF_WORKERS": str(workers),
        "NEURAL_SHDF_LOG_LEVEL": "warning",
    }
    if request_timeout_s is not None:
        env["NEURAL_SHDF_REQUEST_TIMEOUT_S"] = str(request_timeout_s)
    if source is not None:
        env["PYTHONPATH"] = str(source)
    env.pop("NEURAL_SHDF_REDIS_URL", None)
    process = subprocess.Popen([sys.executable, "-m", "neural_shdf.api.serve"], env=env)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{base}/healthz", timeout=1).status_code == 200:
                return process, base
        except httpx.HTTPError:
            time.sleep(0.2)
    process.terminate()
    raise RuntimeError("the server did not start")


async def upload_until_shdf(client: httpx.AsyncClient, data: bytes, name: str) -> tuple[str, float]:
    """Upload; poll the job if one is started. Returns (mesh id, seconds to the ShDF)."""
    start = time.perf_counter()
    response = await client.post("/v1/meshes", files={"file": (name, data)})
    if response.status_code == 202:
        job = response.json()
        while job["state"] not in ("succeeded", "failed"):
            await asyncio.sleep(0.1)
            job = (await client.get(f"/v1/jobs/{job['job_id']}")).json()
        if job["state"] != "succeeded":
            raise RuntimeError(f"job failed: {job['error']}")
        return job["mesh_id"], time.perf_counter() - start
    response.raise_for_status()
    return response.json()["mesh"]["mesh_id"], time.perf_counter() - start


async def load(base: str, body: dict, clients: int, requests: int) -> dict[str, float]:
    """``requests`` POST /v1/segment spread over ``clients`` concurrent clients.

    Each client has its own connection (its own httpx client: a shared httpx pool
    serialises on its lock and would measure the load generator, not the service).
    """
    latencies: list[float] = []
    errors = 0
    remaining = iter(range(requests))
    sessions = [httpx.AsyncClient(base_url=base, timeout=60) for _ in range(clients)]
    try:
        # Open every connection first (one request each), then measure.
        await asyncio.gather(*[s.post("/v1/segment", json=body) for s in sessions])

        async def worker(session: httpx.AsyncClient) -> None:
            nonlocal errors
            for _ in remaining:
                start = time.perf_counter()
                try:
                    response = await session.post("/v1/segment", json=body)
                    ok = response.status_code == 200 and len(response.content) > 0
                except httpx.HTTPError:
                    ok = False
                latencies.append(time.perf_counter() - start)
                errors += not ok

        wall = time.perf_counter()
        await asyncio.gather(*[worker(s) for s in sessions])
        wall = time.perf_counter() - wall
    finally:
        await asyncio.gather(*[s.aclose() for s in sessions])
    ms = sorted(1000 * x for x in latencies)
    return {
        "rps": len(ms) / wall,
        "p50": statistics.median(ms),
        "p99": float(np.percentile(ms, 99)),
        "errors": errors,
        "n": len(ms),
    }


def server_seconds(base: str) -> tuple[float, float]:
    """(sum, count) of the server's own /v1/segment latency histogram."""
    total = count = 0.0
    for line in httpx.get(f"{base}/metrics", timeout=30).text.splitlines():
        if line.startswith('neural_shdf_http_request_seconds_sum{route="/v1/segment"}'):
            total = float(line.split()[-1])
        if line.startswith('neural_shdf_http_request_seconds_count{route="/v1/segment"}'):
            count = float(line.split()[-1])
    return total, count


async def run(args: argparse.Namespace, base: str) -> None:
    async with httpx.AsyncClient(base_url=base, timeout=900) as client:
        data, faces = capsule_ply(20_000)
        mesh_id, seconds = await upload_until_shdf(client, data, "capsule20k.ply")
        print(f"# cached /segment, {faces} faces, method {args.method}, workers {args.workers}")
        print(f"upload + ShDF of the load-test mesh: {seconds:.2f} s")
        body = {"mesh_id": mesh_id, "clusters": 4}
        first = (await client.post("/v1/segment", json=body)).json()
        print(f"first (uncached) segmentation: {first['timings']}")
    json_size = len(httpx.post(f"{base}/v1/segment", json=body, timeout=60).content)
    compact = {**body, "labels_format": "base64"}
    compact_size = len(httpx.post(f"{base}/v1/segment", json=compact, timeout=60).content)
    print(f"response size: json {json_size} B, base64 {compact_size} B")
    print(
        "labels   clients  requests   req/s   p50 ms   p99 ms  errors  rps/goal  p99/goal"
        "  server ms"
    )
    per_client = 40 if args.quick else 150
    for name, request in (("json", body), ("base64", compact)):
        for clients in (1, 8, 32):
            requests = per_client * max(1, min(clients, 4))  # 1x, 4x, 4x
            before = server_seconds(base)
            r = await load(base, request, clients, requests)
            after = server_seconds(base)
            server_ms = 1000 * (after[0] - before[0]) / max(1.0, after[1] - before[1])
            print(
                f"{name:8s} {clients:7d} {r['n']:9d} {r['rps']:7.1f} {r['p50']:8.1f} "
                f"{r['p99']:8.1f} {r['errors']:7d} {r['rps'] / GOAL_RPS:9.2f} "
                f"{r['p99'] / GOAL_P99_MS:9.2f} {server_ms:10.2f}"
            )

    print("\n# upload-to-ShDF latency (binary PLY; job polled above the sync threshold)")
    print("faces      upload MB   seconds")
    sizes = (10_000, 100_000) if args.quick else (10_000, 100_000, 500_000)
    async with httpx.AsyncClient(base_url=base, timeout=900) as client:
        for target in sizes:
            data, faces = capsule_ply(target)
            _, seconds = await upload_until_shdf(client, data, f"capsule{target}.ply")
            print(f"{faces:<10d} {len(data) / 1e6:9.2f} {seconds:9.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer requests, no 500k mesh")
    parser.add_argument(
        "--method", choices=("neural", "exact"), default="neural" if MODEL.is_file() else "exact"
    )
    parser.add_argument("--workers", type=int, default=1, help="uvicorn worker processes")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as cache_dir:
        process, base = start_server(cache_dir, args.method, args.workers)
        try:
            asyncio.run(run(args, base))
        finally:
            process.terminate()
            process.wait(timeout=30)


if __name__ == "__main__":
    main()
