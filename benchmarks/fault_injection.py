"""Fault injection and soak of the REST service: real uvicorn workers, a real redis-server.

``python benchmarks/fault_injection.py kill-worker [--rounds 20] [--count 320]``
    Two workers on one disk cache, exact ShDF, every upload a job. Measures the normal
    upload-to-ShDF time T of fresh meshes, then ``rounds`` times: upload a fresh mesh,
    ``kill -9`` the worker running its job at a random moment, re-upload at once. Prints
    per round the re-upload's time and its ratio to T (goal <= 2), the killed job's final
    state (goal: re-run and succeeded, never stuck ``running``) and a scan of every cache
    entry (goal: 0 that fail their checksum, i.e. no partial entry).

``python benchmarks/fault_injection.py redis [--phase-s 30]``
    Two workers on a real redis-server; a bounded mixed load (4 clients: uploads, jobs,
    segmentations, ShDF reads, job polls) runs while Redis is up, stopped (SIGTERM) for
    ``phase-s``, restarted, frozen (SIGSTOP) for ``phase-s``, thawed. Prints per phase:
    requests, 5xx (goal 0), other errors, p50/p99/max latency, /readyz states; then the
    recovery checks (every job finished, meshes uploaded during the outage readable,
    new writes in Redis again).

``python benchmarks/fault_injection.py soak [--minutes 10]``
    Two workers, disk cache, the same mixed load for ``minutes``; every 30 s: throughput,
    p99, errors and the RSS of each server process. Prints the RSS growth from the first
    minutes (after warm-up) to the last.

Every scenario starts its own server on a free loopback port, with its own cache.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import random
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
import psutil
import trimesh

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT / "service"))

from neural_shdf.store.backends import DiskBackend  # noqa: E402
from neural_shdf.store.cache import ResultCache  # noqa: E402
from neural_shdf.store.codec import CorruptEntryError, unseal  # noqa: E402
from neural_shdf.store.keys import job_key  # noqa: E402

FINAL = ("succeeded", "failed")


# -- servers ----------------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@contextmanager
def service(
    cache_dir: Path, log: Path, workers: int = 2, **settings: object
) -> Iterator[tuple[str, subprocess.Popen]]:
    """``neural-shdf serve`` (uvicorn) on a free loopback port: (base URL, process)."""
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("NEURAL_SHDF_")}
    env.pop("PROMETHEUS_MULTIPROC_DIR", None)
    env.update(
        NEURAL_SHDF_HOST="127.0.0.1",
        NEURAL_SHDF_PORT=str(port),
        NEURAL_SHDF_WORKERS=str(workers),
        NEURAL_SHDF_CACHE_DIR=str(cache_dir),
        NEURAL_SHDF_LOG_LEVEL="warning",
        NEURAL_SHDF_MAX_UPLOAD_BYTES=str(64 * 1024**2),
        PYTHONPATH=os.pathsep.join([str(REPO_ROOT / "service"), env.get("PYTHONPATH", "")]),
    )
    env.update({f"NEURAL_SHDF_{k.upper()}": str(v) for k, v in settings.items()})
    with log.open("ab") as out:
        process = subprocess.Popen(
            [sys.executable, "-m", "neural_shdf.api.serve"], env=env, stdout=out, stderr=out
        )
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 300
        while True:
            try:
                ready = httpx.get(f"{base}/readyz", timeout=5)
                if ready.status_code == 200 and len(worker_pids(process)) == workers:
                    break
            except httpx.HTTPError:
                pass
            if process.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the server did not start (see {log})")
            time.sleep(0.3)
        wait_for_workers(process, workers)  # every worker has finished its warm-up
        yield base, process
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def worker_pids(process: subprocess.Popen) -> list[int]:
    """The uvicorn worker processes (spawned children, not multiprocessing's tracker)."""
    pids = []
    try:
        for child in psutil.Process(process.pid).children():
            with suppress(psutil.NoSuchProcess):
                if "spawn_main" in " ".join(child.cmdline()):
                    pids.append(child.pid)
    except psutil.NoSuchProcess:
        return []
    return pids or [process.pid]


def server_rss_mib(process: subprocess.Popen) -> list[float]:
    """RSS of the supervisor and each worker, MiB."""
    try:
        root = psutil.Process(process.pid)
        procs = [root, *root.children(recursive=True)]
    except psutil.NoSuchProcess:
        return []
    sizes = []
    for proc in procs:
        with suppress(psutil.NoSuchProcess):
            sizes.append(proc.memory_info().rss / 2**20)
    return sizes


@contextmanager
def redis_server(directory: Path) -> Iterator[RedisProcess]:
    binary = shutil.which("redis-server")
    if binary is None:
        raise SystemExit("redis-server is not installed (apt-get install -y redis-server)")
    server = RedisProcess(binary, directory, free_port())
    server.start()
    try:
        yield server
    finally:
        server.stop()


@dataclass
class RedisProcess:
    """redis-server that persists on shutdown (SIGTERM saves, a restart loads it)."""

    binary: str
    directory: Path
    port: int
    process: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"redis://127.0.0.1:{self.port}/0"

    def start(self) -> None:
        args = ["--port", str(self.port), "--bind", "127.0.0.1", "--dir", str(self.directory)]
        args += ["--save", "3600 1", "--appendonly", "no"]
        self.process = subprocess.Popen(
            [self.binary, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
        )
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            with socket.socket() as sock:
                if sock.connect_ex(("127.0.0.1", self.port)) == 0:
                    return
            time.sleep(0.05)
        raise RuntimeError("redis-server did not start")

    def stop(self) -> None:
        if self.process is not None:
            self.process.send_signal(signal.SIGCONT)
            self.process.terminate()
            self.process.wait(timeout=30)
            self.process = None

    def signal(self, sig: int) -> None:
        assert self.process is not None
        self.process.send_signal(sig)


# -- meshes -------------------------------------------------------------------------------
def mesh_variant(count: int, index: int) -> bytes:
    """A capsule (2 * count^2 faces) as binary PLY, made unique by ``index`` (its content
    hash differs, so nothing is cached yet)."""
    mesh = trimesh.creation.capsule(height=2.0, radius=0.5, count=(count, count))
    mesh.apply_scale(1.0 + 1e-4 * index)
    return mesh.export(file_type="ply")


def scan_cache(cache_dir: Path) -> tuple[int, int]:
    """(entries checked, entries failing their checksum) over the whole disk cache."""
    cache = ResultCache(DiskBackend(cache_dir, 8 * 1024**3), memory_items=0)
    checked = corrupt = 0
    try:
        for key in list(cache.backend._cache.iterkeys()):
            if key.startswith("lease:"):
                continue
            value = cache.backend.get(key)
            if value is None:
                continue
            checked += 1
            try:
                unseal(value)
            except CorruptEntryError:
                corrupt += 1
    finally:
        cache.close()
    return checked, corrupt


def read_job_record(cache_dir: Path, job_id: str) -> dict | None:
    cache = ResultCache(DiskBackend(cache_dir, 8 * 1024**3), memory_items=0)
    try:
        return cache.get_json(job_key(job_id))
    finally:
        cache.close()


def wait_job(base: str, job: dict, timeout_s: float) -> tuple[dict, float]:
    """Poll until the job is finished (or the time is up): (last record, seconds)."""
    start = time.monotonic()
    with httpx.Client(base_url=base, timeout=30) as client:
        while time.monotonic() - start < timeout_s:
            try:
                response = client.get(f"/v1/jobs/{job['job_id']}")
                if response.status_code == 200:
                    job = response.json()
                    if job["state"] in FINAL:
                        break
            except httpx.HTTPError:
                pass
            time.sleep(0.05)
    return job, time.monotonic() - start


def upload_to_shdf(base: str, data: bytes, timeout_s: float = 600) -> tuple[dict, float]:
    """Upload and wait for the ShDF (job): (final job record, seconds)."""
    start = time.monotonic()
    response = httpx.post(f"{base}/v1/meshes", files={"file": ("m.ply", data)}, timeout=120)
    if response.status_code == 200:
        return {"state": "succeeded", "attempt": 1}, time.monotonic() - start
    if response.status_code != 202:
        raise RuntimeError(f"upload answered {response.status_code}: {response.text[:300]}")
    job, _ = wait_job(base, response.json(), timeout_s)
    return job, time.monotonic() - start


# -- scenario 1: kill -9 a worker mid-job ----------------------------------------------------
def kill_worker(args: argparse.Namespace, workdir: Path) -> int:
    rng = random.Random(args.seed)
    cache_dir = workdir / "cache"
    settings = {"default_method": "exact", "sync_face_threshold": 10, "request_timeout_s": 600}
    faces = 2 * args.count**2
    with service(cache_dir, workdir / "server.log", **settings) as (base, process):
        upload_to_shdf(base, mesh_variant(args.count, 99_999))  # first run: caches warm
        print(f"exact ShDF jobs, {faces} faces, 2 workers, disk cache; per round: a normal")
        print("upload of a fresh mesh (T), then a fresh mesh whose worker is killed mid-job")
        print(
            "\n| round | T s | killed after s | re-upload s | ratio to T | its runs | killed job | "
            "its runs | settled after s | workers lost | entries | corrupt |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|---|")
        failures = 0
        ratios, normals = [], []
        for round_ in range(1, args.rounds + 1):
            job, t_normal = upload_to_shdf(base, mesh_variant(args.count, 10_000 + round_))
            assert job["state"] == "succeeded", job
            normals.append(t_normal)
            data = mesh_variant(args.count, round_)
            accepted = httpx.post(f"{base}/v1/meshes", files={"file": ("m.ply", data)}, timeout=120)
            assert accepted.status_code == 202, accepted.text
            old = accepted.json()
            delay = rng.uniform(0.05, 0.9 * t_normal)
            time.sleep(delay)
            record = read_job_record(cache_dir, old["job_id"])
            victim = int(record["worker"].rsplit(":", 1)[1])
            before = set(worker_pids(process))
            os.kill(victim, signal.SIGKILL)
            job, seconds = upload_to_shdf(base, data)
            lost = len(before - set(worker_pids(process)))  # 1: the killed one
            settled, settle_s = wait_job(base, old, timeout_s=120)
            checked, corrupt = scan_cache(cache_dir)
            ratio = seconds / t_normal
            ratios.append(ratio)
            ok = job["state"] == "succeeded" and ratio <= 2 and settled["state"] in FINAL
            ok = ok and corrupt == 0
            failures += not ok
            print(
                f"| {round_} | {t_normal:.2f} | {delay:.2f} | {seconds:.2f} | {ratio:.2f} | "
                f"{job.get('attempt', 1)} | {settled['state']} | {settled.get('attempt', 1)} | "
                f"{settle_s:.1f} | {lost} | {checked} | {corrupt} |",
                flush=True,
            )
            wait_for_workers(process, 2)  # uvicorn restarts the killed one; let it warm up
        corrupt_metric = metric_total(base, "neural_shdf_cache_corrupt_entries_total")
        print(
            f"\nre-upload / T: max {max(ratios):.2f}, median {statistics.median(ratios):.2f} "
            f"(goal <= 2); T median {statistics.median(normals):.2f} s; rounds failing a goal: "
            f"{failures} of {args.rounds}; corrupt entries dropped by the service: "
            f"{corrupt_metric:g}"
        )
    return 1 if failures else 0


def wait_for_workers(process: subprocess.Popen, count: int, timeout_s: float = 180) -> None:
    """Until ``count`` workers exist and none is busy starting (CPU under 20 % for 1 s)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        pids = worker_pids(process)
        if len(pids) >= count:
            try:
                busy = [psutil.Process(pid).cpu_percent(interval=1.0) for pid in pids]
            except psutil.NoSuchProcess:
                continue
            if max(busy) < 20:
                return
        else:
            time.sleep(0.2)


def metric_total(base: str, name: str) -> float:
    text = httpx.get(f"{base}/metrics", timeout=30).text
    return sum(
        float(line.rsplit(" ", 1)[1])
        for line in text.splitlines()
        if line.startswith(name) and not line.startswith("#")
    )


# -- mixed load -------------------------------------------------------------------------------
@dataclass
class Sample:
    at: float  # seconds since the load started
    op: str
    status: int  # 0: no response (connection error, client timeout)
    seconds: float


@dataclass
class MixedLoad:
    """Clients doing uploads (small: synchronous; large: a job they poll), segmentations,
    ShDF reads, metadata reads and job polls; each client one request at a time."""

    base: str
    clients: int = 4
    small_faces_count: int = 24  # 1152 faces: synchronous
    large_faces_count: int = 60  # 7200 faces: a job (sync threshold 5000)
    variants: int = 100
    seed: int = 0
    samples: list[Sample] = field(default_factory=list)
    meshes: list[str] = field(default_factory=list)
    jobs: list[dict] = field(default_factory=list)
    start: float = 0.0

    async def run(self, seconds: float) -> None:
        cache = {
            (count, variant): mesh_variant(count, variant)
            for count in (self.small_faces_count, self.large_faces_count)
            for variant in range(self.variants)
        }  # made before the clock starts: the load generator never waits on trimesh
        self.start = time.monotonic()
        stop_at = self.start + seconds
        await asyncio.gather(*[self._client(i, stop_at, cache) for i in range(self.clients)])

    async def _request(self, client: httpx.AsyncClient, op: str, method: str, url: str, **kw):
        start = time.monotonic()
        try:
            response = await client.request(method, url, **kw)
            status = response.status_code
        except httpx.HTTPError:
            response, status = None, 0
        self.samples.append(Sample(start - self.start, op, status, time.monotonic() - start))
        return response

    async def _client(self, index: int, stop_at: float, cache: dict) -> None:
        rng = random.Random(self.seed * 1000 + index)
        # A connection per request, as from many clients: the kernel spreads them over the
        # workers (kept-alive connections would pin each client to one worker).
        fresh = httpx.Limits(max_keepalive_connections=0)
        async with httpx.AsyncClient(base_url=self.base, timeout=120, limits=fresh) as client:
            while time.monotonic() < stop_at:
                roll = rng.random()
                if roll < 0.12 or not self.meshes:
                    await self._upload(client, rng, cache, large=False)
                elif roll < 0.17:
                    await self._upload(client, rng, cache, large=True)
                elif roll < 0.62:
                    await self._segment(client, rng, cache)
                elif roll < 0.77:
                    mesh_id = rng.choice(self.meshes)
                    await self._request(
                        client, "shdf", "GET", f"/v1/meshes/{mesh_id}/shdf?format=f32"
                    )
                elif roll < 0.87 and self.jobs:
                    job = rng.choice(self.jobs)
                    await self._request(client, "job", "GET", f"/v1/jobs/{job['job_id']}")
                else:
                    mesh_id = rng.choice(self.meshes)
                    await self._request(client, "mesh", "GET", f"/v1/meshes/{mesh_id}")

    async def _upload(self, client, rng: random.Random, cache: dict, *, large: bool) -> None:
        count = self.large_faces_count if large else self.small_faces_count
        variant = rng.randrange(self.variants)
        data = cache[(count, variant)]
        op = "upload-large" if large else "upload"
        response = await self._request(
            client, op, "POST", "/v1/meshes", files={"file": ("m.ply", data)}
        )
        if response is None:
            return
        if response.status_code == 200:
            self.meshes.append(response.json()["mesh"]["mesh_id"])
        elif response.status_code == 202:
            job = response.json()
            self.jobs.append(job)
            for _ in range(600):  # poll it to the end, as a client would
                await asyncio.sleep(0.2)
                polled = await self._request(client, "job", "GET", f"/v1/jobs/{job['job_id']}")
                state = polled.json()["state"] if polled and polled.status_code == 200 else None
                if state in FINAL:
                    if state == "succeeded":
                        self.meshes.append(job["mesh_id"])
                    return

    async def _segment(self, client, rng: random.Random, cache: dict) -> None:
        mesh_id = rng.choice(self.meshes)
        body = {"mesh_id": mesh_id, "clusters": rng.randint(2, 6), "labels_format": "base64"}
        response = await self._request(client, "segment", "POST", "/v1/segment", json=body)
        if response is not None and response.status_code == 404:
            self.meshes.remove(mesh_id) if mesh_id in self.meshes else None

    def window(self, start: float, end: float) -> dict[str, float]:
        chosen = [s for s in self.samples if start <= s.at < end]
        return summarize(chosen, end - start)


def summarize(samples: list[Sample], seconds: float) -> dict[str, float]:
    ms = sorted(1000 * s.seconds for s in samples)
    return {
        "n": len(samples),
        "rps": len(samples) / seconds if seconds > 0 else 0.0,
        "5xx": sum(500 <= s.status < 600 for s in samples),
        "no_response": sum(s.status == 0 for s in samples),
        "4xx": sum(400 <= s.status < 500 for s in samples),
        "p50": float(np.percentile(ms, 50)) if ms else 0.0,
        "p99": float(np.percentile(ms, 99)) if ms else 0.0,
        "max": ms[-1] if ms else 0.0,
    }


def print_by_operation(samples: list[Sample]) -> None:
    by_op: dict[str, list[Sample]] = {}
    for sample in samples:
        by_op.setdefault(sample.op, []).append(sample)
    print("\n| operation | requests | 5xx | no answer | 4xx | p50 ms | p99 ms |")
    print("|---|---|---|---|---|---|---|")
    for op, chosen in sorted(by_op.items()):
        w = summarize(chosen, 1.0)
        print(
            f"| {op} | {w['n']} | {w['5xx']} | {w['no_response']} | {w['4xx']} | "
            f"{w['p50']:.0f} | {w['p99']:.0f} |"
        )


async def watch_ready(base: str, stop: asyncio.Event, log: list[tuple[float, str]]) -> None:
    """/readyz every 0.5 s (whichever worker answers): (time, status)."""
    async with httpx.AsyncClient(base_url=base, timeout=10) as client:
        start = time.monotonic()
        while not stop.is_set():
            try:
                status = (await client.get("/readyz")).json().get("status", "?")
            except (httpx.HTTPError, ValueError):
                status = "no answer"
            log.append((time.monotonic() - start, status))
            with suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), 0.5)


# -- scenario 2: Redis stopped and frozen under load ------------------------------------------
def redis_faults(args: argparse.Namespace, workdir: Path) -> int:
    phases = [
        ("redis up", args.warm_s, None),
        ("redis stopped (SIGTERM)", args.phase_s, "stop"),
        ("restarted", args.warm_s, "start"),
        ("redis frozen (SIGSTOP)", args.phase_s, "freeze"),
        ("thawed (SIGCONT)", args.warm_s, "thaw"),
    ]
    redis_dir = workdir / "redis"
    redis_dir.mkdir()
    with redis_server(redis_dir) as redis_proc:
        settings = {
            "redis_url": redis_proc.url,
            "default_method": "neural",
            "sync_face_threshold": 5000,
            "request_timeout_s": 120,
        }
        with service(workdir / "cache", workdir / "server.log", **settings) as (base, _):
            load = MixedLoad(base, clients=args.clients, seed=args.seed)
            ready_log: list[tuple[float, str]] = []
            marks: list[tuple[str, float]] = []

            async def drive() -> None:
                stop = asyncio.Event()
                watcher = asyncio.create_task(watch_ready(base, stop, ready_log))
                runner = asyncio.create_task(load.run(sum(p[1] for p in phases)))
                await asyncio.sleep(0.05)
                for name, seconds, action in phases:
                    if action == "stop":
                        redis_proc.stop()
                    elif action == "start":
                        redis_proc.start()
                    elif action == "freeze":
                        redis_proc.signal(signal.SIGSTOP)
                    elif action == "thaw":
                        redis_proc.signal(signal.SIGCONT)
                    marks.append((name, time.monotonic() - load.start))
                    await asyncio.sleep(seconds)
                await runner
                stop.set()
                await watcher

            asyncio.run(drive())
            ends = [m[1] for m in marks[1:]] + [max(s.at for s in load.samples) + 1e-3]
            print(f"mixed load, {args.clients} clients, 2 workers, Redis faults {args.phase_s:g} s")
            print(
                "\n| phase | s | requests | req/s | 5xx | no answer | 4xx | p50 ms | p99 ms "
                "| max ms | /readyz |"
            )
            print("|---|---|---|---|---|---|---|---|---|---|---|")
            total_5xx = 0
            for (name, start), end in zip(marks, ends, strict=True):
                w = load.window(start, end)
                total_5xx += w["5xx"] + w["no_response"]
                states = sorted({s for t, s in ready_log if start <= t < end})
                print(
                    f"| {name} | {end - start:.0f} | {w['n']} | {w['rps']:.1f} | {w['5xx']} | "
                    f"{w['no_response']} | {w['4xx']} | {w['p50']:.0f} | {w['p99']:.0f} | "
                    f"{w['max']:.0f} | {', '.join(states)} |"
                )
            for name, start in marks[2::2]:
                after = [t for t, s in ready_log if t >= start and s == "ready"]
                print(
                    f"{name}: /readyz 'ready' again {after[0] - start:.1f} s after"
                    if after
                    else f"{name}: /readyz never 'ready' again"
                )
            print_by_operation(load.samples)
            # Recovery: every job finished and pollable, every mesh readable, Redis written.
            states: dict[str, int] = {}
            for job in load.jobs:
                final, _ = wait_job(base, job, timeout_s=60)
                states[final["state"]] = states.get(final["state"], 0) + 1
            unreadable = sum(
                httpx.get(f"{base}/v1/meshes/{m}", timeout=30).status_code != 200
                for m in set(load.meshes)
            )
            import redis

            client = redis.Redis.from_url(redis_proc.url)
            fresh = mesh_variant(30, 999_999)
            uploaded = httpx.post(f"{base}/v1/meshes", files={"file": ("m.ply", fresh)}, timeout=60)
            mesh_id = uploaded.json()["mesh"]["mesh_id"]
            in_redis = bool(client.exists(f"neural-shdf:{mesh_id}:meta"))
            print(
                f"\nafter recovery: jobs {states} (of {len(load.jobs)}); meshes not readable: "
                f"{unreadable} of {len(set(load.meshes))}; a new upload is in Redis: {in_redis}; "
                f"5xx or no answer over the whole run: {total_5xx}"
            )
            failed = (
                total_5xx or states.get("running", 0) or states.get("queued", 0) or not in_redis
            )
    return 1 if failed else 0


# -- scenario 3: soak -------------------------------------------------------------------------
def soak(args: argparse.Namespace, workdir: Path) -> int:
    settings = {"default_method": "neural", "sync_face_threshold": 5000, "request_timeout_s": 120}
    seconds = args.minutes * 60
    with service(workdir / "cache", workdir / "server.log", **settings) as (base, process):
        load = MixedLoad(base, clients=args.clients, seed=args.seed)
        rss: list[tuple[float, list[float]]] = []
        loads: list[float] = []

        async def drive() -> None:
            runner = asyncio.create_task(load.run(seconds))
            await asyncio.sleep(0.05)
            while not runner.done():
                rss.append((time.monotonic() - load.start, server_rss_mib(process)))
                loads.append(os.getloadavg()[0])
                await asyncio.wait({runner}, timeout=args.every_s)
            rss.append((time.monotonic() - load.start, server_rss_mib(process)))

        asyncio.run(drive())
        print(f"soak: {args.minutes:g} min, {args.clients} clients, 2 workers, disk cache, neural")
        print(
            "\n| window s | requests | req/s | 5xx | no answer | 4xx | p50 ms | p99 ms "
            "| RSS MiB (supervisor, workers) |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        errors = 0
        for start in np.arange(0, seconds, args.every_s):
            end = min(start + args.every_s, seconds)
            w = load.window(start, end)
            errors += w["5xx"] + w["no_response"]
            sizes = next((r for t, r in rss if t >= end - 1e-6), rss[-1][1])
            print(
                f"| {start:.0f}-{end:.0f} | {w['n']} | {w['rps']:.1f} | {w['5xx']} | "
                f"{w['no_response']} | {w['4xx']} | {w['p50']:.0f} | {w['p99']:.0f} | "
                f"{', '.join(f'{s:.0f}' for s in sizes)} |"
            )
        print_by_operation(load.samples)
        total = summarize(load.samples, seconds)
        early = [sum(r) for t, r in rss if 60 <= t <= 180] or [sum(rss[0][1])]
        late = [sum(r) for t, r in rss if t >= seconds - 120]
        growth = statistics.median(late) / statistics.median(early)
        print(
            f"\nwhole run: {total['n']} requests, {total['rps']:.1f} req/s, "
            f"p99 {total['p99']:.0f} ms, "
            f"5xx {total['5xx']}, no answer {total['no_response']}, 4xx {total['4xx']}; "
            f"total RSS median {statistics.median(early):.0f} MiB (1-3 min) -> "
            f"{statistics.median(late):.0f} MiB (last 2 min): ratio {growth:.3f}; "
            f"machine load average {min(loads):.1f}-{max(loads):.1f} on {os.cpu_count()} cores"
        )
    return 1 if errors else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="scenario", required=True)
    kill = sub.add_parser("kill-worker")
    kill.add_argument("--rounds", type=int, default=20)
    kill.add_argument("--count", type=int, default=320, help="capsule resolution (2 c^2 faces)")
    red = sub.add_parser("redis")
    red.add_argument("--phase-s", type=float, default=30.0)
    red.add_argument("--warm-s", type=float, default=20.0)
    red.add_argument("--clients", type=int, default=4)
    soaked = sub.add_parser("soak")
    soaked.add_argument("--minutes", type=float, default=10.0)
    soaked.add_argument("--every-s", type=float, default=30.0)
    soaked.add_argument("--clients", type=int, default=4)
    for each in (kill, red, soaked):
        each.add_argument("--seed", type=int, default=0)
        each.add_argument("--keep", action="store_true", help="keep the work directory")
    args = parser.parse_args()
    workdir = Path(tempfile.mkdtemp(prefix=f"neural-shdf-{args.scenario}-"))
    print(f"work directory (server log, caches): {workdir}")
    try:
        scenario = {"kill-worker": kill_worker, "redis": redis_faults, "soak": soak}
        return scenario[args.scenario](args, workdir)
    finally:
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(main())
