"""Requests that used to stall the event loop or the compute pool, through a real
``neural-shdf serve`` on loopback, for the code in one or more source trees side by side.

Cases (issue 20, items 4 and 5):

* ``json-keys``: a 2.3 MB JSON body with 200,000 unknown keys to ``POST /v1/segment``;
  reports the status, the answer's size, its time and the slowest ``/healthz`` answer
  while it ran (polled every 10 ms from another connection);
* ``abandoned``: two heavy requests (``parts.glb`` with METIS and 10,000 / 9,000 parts
  on a 20k-face mesh) sent by one client that hangs up after 1 s, then an ordinary
  20k-face upload (exact ShDF) from another client (another ``X-Forwarded-For``);
  reports how long that upload took (given up after 150 s).

    python benchmarks/bench_hostile_requests.py [SOURCE_DIR ...]

Each SOURCE_DIR holds the ``neural_shdf`` package (default: this checkout's ``service``);
e.g. a ``git archive`` of the code before, extracted, then its ``service`` folder.
"""

from __future__ import annotations

import contextlib
import json
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import trimesh
from bench_service import start_server

REPO = Path(__file__).resolve().parents[1]


class HealthProbe:
    """Polls /healthz every 10 ms on its own connection; keeps the slowest answer."""

    def __init__(self, base: str) -> None:
        self.base = base
        self.slowest = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with httpx.Client(timeout=60) as client:
            while not self._stop.is_set():
                start = time.perf_counter()
                client.get(f"{self.base}/healthz")
                self.slowest = max(self.slowest, time.perf_counter() - start)
                time.sleep(0.01)

    def __enter__(self) -> HealthProbe:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join()


def json_keys_case(base: str) -> str:
    body = {"mesh_id": "0" * 64, **{f"k{i:06d}": 1 for i in range(200_000)}}
    data = json.dumps(body).encode()
    with HealthProbe(base) as probe:
        start = time.perf_counter()
        response = httpx.post(
            f"{base}/v1/segment",
            content=data,
            headers={"content-type": "application/json"},
            timeout=120,
        )
        seconds = time.perf_counter() - start
        time.sleep(0.1)
    return (
        f"json-keys ({len(data) / 1e6:.1f} MB): {response.status_code}, answer "
        f"{len(response.content) / 1e6:.3f} MB in {seconds:.2f} s, slowest /healthz "
        f"{probe.slowest * 1000:.0f} ms"
    )


def mesh_obj(subdivisions: int, shift: float) -> bytes:
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    sphere.vertices[:, 0] *= 1.0 + shift
    return sphere.export(file_type="obj").encode()


def hang_up_after(seconds: float, method: str, url: str, **kwargs: object) -> None:
    with contextlib.suppress(httpx.HTTPError):  # the point: the client gives up
        httpx.request(method, url, timeout=seconds, **kwargs)  # type: ignore[arg-type]


def abandoned_case(base: str) -> str:
    attacker = {"X-Forwarded-For": "10.0.0.1"}
    first = httpx.post(
        f"{base}/v1/meshes",
        files={"file": ("a.obj", mesh_obj(5, 0.1))},  # 20,480 faces
        data={"method": "neural"},
        headers=attacker,
        timeout=300,
    ).json()["mesh"]["mesh_id"]
    heavy = [
        (
            "GET",
            f"{base}/v1/meshes/{first}/segmentation/parts.glb",
            {"params": {"partitioner": "metis", "parts": parts}, "headers": attacker},
        )
        for parts in (10_000, 9_000)
    ]
    threads = [
        threading.Thread(target=hang_up_after, args=(1.0, method, url), kwargs=kwargs)
        for method, url, kwargs in heavy
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    start = time.perf_counter()
    try:
        status = httpx.post(
            f"{base}/v1/meshes",
            files={"file": ("c.obj", mesh_obj(5, 0.3))},  # 20,480 faces
            data={"method": "exact"},
            headers={"X-Forwarded-For": "10.0.0.2"},
            timeout=150,
        ).status_code
    except httpx.TimeoutException:
        status = "no answer"
    seconds = time.perf_counter() - start
    return f"abandoned: the other client's 20k-face upload: {status} after {seconds:.1f} s"


def main() -> None:
    sources = [Path(p).resolve() for p in sys.argv[1:]] or [REPO / "service"]
    for source in sources:
        with tempfile.TemporaryDirectory() as cache:
            process, base = start_server(cache, "exact", 1, source=source, request_timeout_s=None)
            try:
                print(f"== {source}")
                print("  " + json_keys_case(base))
                print("  " + abandoned_case(base))
            finally:
                process.terminate()
                process.wait(timeout=30)


if __name__ == "__main__":
    main()
