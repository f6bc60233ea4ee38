"""Event-loop stalls inside a real ``neural-shdf serve``, told apart from a busy machine.

``hostile_corpus.py`` times ``/healthz`` from outside; on a loaded machine the operating
system's scheduling adds its own delays, so a slow ``/healthz`` does not say whether the
service held the GIL. This runs ``serve`` with a watcher thread inside the server process
that wakes every millisecond: for each late wake-up (over ``--over`` ms) it records the delay,
the CPU time the server's *other* threads used during it (a GIL hold shows as other-thread
CPU close to the delay; the machine's load shows as a delay with little other-thread CPU)
and the stack of the thread that ran. Meanwhile a probe process times ``/healthz``.

Cases: 100,000 separate shells (400k faces) uploaded and segmented (100,000 parts in the
answer), and, where ``../shared/data`` exists, the dense-dev zenobia scan subdivided once
(1.85M faces, just under the 2M-face limit), uploaded and segmented.

    python benchmarks/serve_stalls.py [--over 30] [--only SUBSTRING]

Columns: worst ``/healthz`` latency, worst watcher delay, and the worst "GIL" estimate
(``min(delay, other-thread CPU)``) with where the holding thread was.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_service import free_port  # noqa: E402
from hostile_corpus import legit_inputs, separate_shells  # noqa: E402

TICK_S = 0.001
IDLE_FRAMES = ("threading.py", "selectors.py", "queue.py", "thread.py")

PROBE = """
import httpx, sys, time
client = httpx.Client(base_url=sys.argv[1], timeout=60)
while True:
    start = time.perf_counter()
    client.get("/healthz")
    print(f"{start:.4f} {time.perf_counter() - start:.4f}", flush=True)
    time.sleep(0.01)
"""


def watch(log_path: str, over_s: float) -> None:
    """Log late wake-ups of this thread as JSON lines (runs inside the server process)."""
    me = threading.get_ident()
    with open(log_path, "a", buffering=1) as log:
        last, last_cpu, last_mine = time.perf_counter(), time.process_time(), time.thread_time()
        while True:
            time.sleep(TICK_S)
            now, cpu, mine = time.perf_counter(), time.process_time(), time.thread_time()
            delay = now - last - TICK_S
            if delay > over_s:
                other_cpu = (cpu - last_cpu) - (mine - last_mine)
                busy = []
                for ident, frame in sys._current_frames().items():
                    stack = traceback.extract_stack(frame)
                    if ident == me or not stack or Path(stack[-1].filename).name in IDLE_FRAMES:
                        continue
                    busy.append(" <- ".join(
                        f"{Path(e.filename).name}:{e.lineno} {e.name}" for e in stack[::-1][:3]
                    ))  # fmt: skip
                record = {"at": now, "delay": delay, "other_cpu": other_cpu, "where": busy}
                log.write(json.dumps(record) + "\n")
            last, last_cpu, last_mine = (
                time.perf_counter(),
                time.process_time(),
                time.thread_time(),
            )


def serve_with_watcher(port: int, log_path: str, over_s: float) -> None:
    from neural_shdf.api.serve import run

    threading.Thread(target=watch, args=(log_path, over_s), daemon=True).start()
    run(host="127.0.0.1", port=port, workers=1)


def upload_and_segment(client: httpx.Client, name: str, data: bytes) -> str:
    answer = client.post("/v1/meshes", files={"file": (name, data)})
    answer.raise_for_status()
    body = answer.json()
    job = body.get("job_id")
    while job:
        state = client.get(f"/v1/jobs/{job}").json()["state"]
        if state in ("succeeded", "failed"):
            break
        time.sleep(0.2)
    segmented = client.post("/v1/segment", json={"mesh_id": body["mesh_id"]})
    return f"upload {answer.status_code}, segment {segmented.status_code}"


def run_case(name: str, file_name: str, data: bytes, over_s: float) -> None:
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as workdir:
        log_path = os.path.join(workdir, "stalls.jsonl")
        env = {**os.environ, "NEURAL_SHDF_CACHE_DIR": os.path.join(workdir, "cache")}
        server = subprocess.Popen(
            [sys.executable, __file__, "--server", str(port), "--log", log_path,
             "--over", str(over_s * 1e3)],
            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        probe = None
        try:
            with httpx.Client(base_url=base, timeout=600) as client:
                for _ in range(600):
                    try:
                        if client.get("/healthz").status_code == 200:
                            break
                    except httpx.TransportError:
                        pass
                    time.sleep(0.1)
                probe = subprocess.Popen(
                    [sys.executable, "-c", PROBE, base], stdout=subprocess.PIPE, text=True
                )
                time.sleep(1.0)
                start = time.perf_counter()
                status = upload_and_segment(client, file_name, data)
                end = time.perf_counter()
        finally:
            if probe is not None:
                probe.terminate()
            server.terminate()
            server.wait()
        health = [
            float(latency)
            for at, latency in (line.split() for line in probe.communicate()[0].splitlines())
            if start <= float(at) <= end
        ] if probe is not None else []  # fmt: skip
        records = [json.loads(line) for line in Path(log_path).read_text().splitlines()]
        records = [r for r in records if start <= r["at"] <= end]
    worst_delay = max((r["delay"] for r in records), default=0.0)
    held = max(records, key=lambda r: min(r["delay"], r["other_cpu"]), default=None)
    gil = min(held["delay"], held["other_cpu"]) if held else 0.0
    where = (held["where"] or ["?"])[0] if held else "-"
    print(
        f"{name:<28} {status}; /healthz worst {max(health, default=0) * 1e3:5.0f} ms, "
        f"watcher delay worst {worst_delay * 1e3:5.0f} ms, GIL worst {gil * 1e3:4.0f} ms "
        f"at {where}",
        flush=True,
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--over", type=float, default=30.0, help="log delays over this (ms)")
    parser.add_argument("--only", default="")
    parser.add_argument("--server", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--log", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.server:
        serve_with_watcher(args.server, args.log, args.over / 1e3)
        return
    print(f"load average {os.getloadavg()[0]:.1f}", flush=True)
    cases: list[tuple[str, str, bytes]] = [
        ("100,000 shells (400k faces)", "shells.obj", separate_shells(100_000))
    ]
    with tempfile.TemporaryDirectory() as workdir:
        if "scan" in args.only or not args.only:
            largest = legit_inputs(Path(workdir))[-1]
            cases.append(("scan subdivided (1.85M)", largest.name, largest.read_bytes()))
        for name, file_name, data in cases:
            if args.only in name:
                run_case(name, file_name, data, args.over / 1e3)


if __name__ == "__main__":
    main()
