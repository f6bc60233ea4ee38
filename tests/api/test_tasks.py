"""The task runner: work no one waits for stops at its next checkpoint, one client's
requests (abandoned or not) never hold every compute thread, and its worker process never
outlives it."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterable
from pathlib import Path

import httpx
import psutil
import pytest
import trimesh

from neural_shdf.api.clients import Client, current_client
from neural_shdf.api.errors import ApiError
from neural_shdf.api.tasks import STORE_DELAY_S, TaskRunner, checkpoint
from neural_shdf.client import Client as ServiceClient
from neural_shdf.store.backends import DiskBackend
from neural_shdf.store.cache import ResultCache
from tests.api.api_helpers import make_settings, quad_dumbbell_obj
from tests.api.conftest import running_server

REPOSITORY = Path(__file__).resolve().parents[2]


class FakePeer:
    """The ASGI receive of a client that sent its request and may hang up later."""

    def __init__(self) -> None:
        self.hung_up = asyncio.Event()

    async def receive(self) -> dict:
        await self.hung_up.wait()
        return {"type": "http.disconnect"}


def runner(tmp_path: Path, **settings: object) -> TaskRunner:
    cache = ResultCache(DiskBackend(tmp_path / "cache", 2**30))
    return TaskRunner(make_settings(tmp_path / "cache", **settings), cache)


async def as_client(name: str, peer: FakePeer, work) -> object:
    """Run ``work()`` (a coroutine function) as a request of client ``name``."""
    current_client.set(Client(name, peer.receive))
    return await work()


def until_cancelled(started: threading.Event, stopped: list[str]) -> None:
    """A long computation that reaches a checkpoint every millisecond."""
    started.set()
    try:
        while True:
            checkpoint()
            time.sleep(0.001)
    except Exception as exc:
        stopped.append(type(exc).__name__)
        raise


def test_a_computation_whose_client_left_stops_at_its_next_checkpoint(tmp_path):
    tasks = runner(tmp_path, compute_threads=2)
    cancelled: list[int] = []
    tasks.on_cancelled = lambda: cancelled.append(1)

    async def scenario() -> None:
        peer, started, stopped = FakePeer(), threading.Event(), []

        def compute() -> None:
            until_cancelled(started, stopped)

        flight = lambda: tasks.single_flight("k", compute)  # noqa: E731
        request = asyncio.create_task(as_client("a", peer, flight))
        await asyncio.to_thread(started.wait, 30)
        peer.hung_up.set()
        with pytest.raises(ApiError) as left:
            await request
        assert left.value.status_code == 499
        for _ in range(3000):  # the computation's thread reaches its next checkpoint
            if cancelled:
                break
            await asyncio.sleep(0.01)
        assert stopped == ["ComputationCancelled"] and cancelled == [1]

    asyncio.run(scenario())
    tasks.executor.shutdown(wait=True)


def test_a_computation_another_request_still_waits_for_goes_on(tmp_path):
    tasks = runner(tmp_path, compute_threads=2, compute_share=2)

    async def scenario() -> None:
        leaving, staying, release = FakePeer(), FakePeer(), threading.Event()

        def work() -> str:
            release.wait(30)
            checkpoint()
            return "done"

        def request(peer: FakePeer, name: str) -> asyncio.Task:
            flight = lambda: tasks.single_flight("k", work)  # noqa: E731
            return asyncio.create_task(as_client(name, peer, flight))

        first = request(leaving, "a")
        await asyncio.sleep(0.05)
        second = request(staying, "b")
        await asyncio.sleep(0.05)
        leaving.hung_up.set()
        with pytest.raises(ApiError):
            await first
        release.set()
        assert await second == "done"

    asyncio.run(scenario())
    tasks.executor.shutdown(wait=True)


def test_one_client_cannot_hold_every_compute_thread(tmp_path):
    """Client a sends three blocking computations on a two-thread pool and hangs up; the
    first holds its one thread until it ends, the others never start, and client b's
    computation runs meanwhile on the other thread."""
    tasks = runner(tmp_path, compute_threads=2)
    assert tasks.share == 1

    async def scenario() -> None:
        attacker, other, release = FakePeer(), FakePeer(), threading.Event()
        ran: list[int] = []

        def hog(index: int) -> None:
            ran.append(index)
            release.wait(60)  # no checkpoint: like a writer that cannot stop midway

        abandoned = [
            asyncio.create_task(as_client("a", attacker, lambda i=i: tasks.run(hog, i)))
            for i in range(3)
        ]
        await asyncio.sleep(0.1)
        attacker.hung_up.set()
        ordinary = as_client("b", other, lambda: tasks.run(lambda: "b's answer"))
        assert await asyncio.wait_for(ordinary, 30) == "b's answer"  # while a's still runs
        assert ran == [0]
        release.set()
        for task in abandoned:
            with pytest.raises(ApiError):
                await task

    asyncio.run(scenario())
    tasks.executor.shutdown(wait=True)


def test_an_abandoned_shdf_request_is_cancelled_in_the_service(tmp_path):
    """Through uvicorn: a client asks for the exact ShDF of a 328k-face sphere and hangs
    up; the computation stops (counted) instead of running to its end."""
    # 328k faces: its exact ShDF takes seconds, far longer than the client waits.
    sphere = trimesh.creation.icosphere(subdivisions=7)
    data = sphere.export(file_type="stl")
    settings = {"max_upload_bytes": 40_000_000, "sync_face_threshold": 1_000_000}
    with running_server(tmp_path / "cache", warm_up=False, **settings) as base:
        upload = httpx.post(
            f"{base}/v1/meshes",
            files={"file": ("sphere.stl", data)},
            data={"method": "neural"},
            timeout=300,
        )
        assert upload.status_code == 200, upload.text
        url = f"{base}/v1/meshes/{upload.json()['mesh']['mesh_id']}/shdf"
        with pytest.raises(httpx.TimeoutException):
            httpx.get(url, params={"method": "exact"}, timeout=0.5)

        def metric(name: str) -> float:
            text = httpx.get(f"{base}/metrics", timeout=10).text
            lines = [line for line in text.splitlines() if line.startswith(name)]
            return sum(float(line.split()[-1]) for line in lines)

        deadline = time.monotonic() + 120
        while metric("neural_shdf_computations_cancelled_total") < 1:
            assert time.monotonic() < deadline, "the abandoned computation was not cancelled"
            time.sleep(0.2)
        assert metric('neural_shdf_shdf_computations_total{method="exact"}') == 0


def test_compute_once_can_store_on_the_store_thread_after_answering(tmp_path):
    """``store_later``: the result is returned while its store still waits or runs on the
    store thread (a slider's new value does not wait for the cache write)."""
    tasks = runner(tmp_path)
    writing, finish, stored = threading.Event(), threading.Event(), []

    def store(value: int, _: object) -> None:
        writing.set()
        finish.wait(30)
        stored.append((value, threading.current_thread().name))

    try:
        value, cached = tasks.compute_once("m:x", lambda: None, lambda: 5, store, store_later=True)
        returned = time.monotonic()
        assert (value, cached, stored) == (5, False, [])
        assert writing.wait(30)
        assert time.monotonic() - returned > STORE_DELAY_S / 2  # after the answer went out
        finish.set()
        deadline = time.monotonic() + 30
        while not stored and time.monotonic() < deadline:
            time.sleep(0.01)
        assert stored[0][0] == 5 and stored[0][1].startswith("store")
    finally:
        finish.set()
        asyncio.run(tasks.close())


def test_a_store_still_queued_at_shutdown_runs_there(tmp_path):
    """Closing the runner cancels what waits for the store thread; a queued store then runs
    where it was cancelled, so its result lands and its lock is released."""
    tasks = runner(tmp_path)
    busy, stored = threading.Event(), []
    tasks.store_executor.submit(busy.wait, 30)  # the store thread is taken
    tasks.compute_once(
        "m:x", lambda: None, lambda: 5, lambda value, _: stored.append(value), store_later=True
    )
    assert stored == []
    asyncio.run(tasks.close())
    busy.set()
    assert stored == [5]
    assert tasks.cache.backend.lease_holder("lock:m:x") is None


def _refuse(found: int) -> None:
    from neural_shdf.errors import MeshTooLargeError

    raise MeshTooLargeError("too many charts", limit="max_charts", maximum=10, found=found)


def test_isolated_work_runs_in_another_process_and_keeps_the_errors_details(tmp_path):
    """GIL-holding library calls (xatlas, pymetis) run in a worker process; its answers
    and the project's errors, with their structured detail, come back as raised there."""
    import os

    from neural_shdf.errors import MeshTooLargeError

    tasks = runner(tmp_path)
    try:
        assert tasks.isolated(os.getpid) != os.getpid()
        with pytest.raises(MeshTooLargeError) as raised:
            tasks.isolated(_refuse, 11)
        assert raised.value.detail() == {"limit": "max_charts", "maximum": 10, "found": 11}
    finally:
        asyncio.run(tasks.close())


def _array_summary(arrays: dict) -> dict:
    return {
        name: (a.dtype.str, a.shape, a.flags.writeable, float(a.sum()))
        for name, a in arrays.items()
    }


def test_isolated_arguments_travel_through_shared_memory_intact(tmp_path):
    """Large arrays reach the worker through one shared block (not pickled in band, which
    held the GIL for a third of a second at 1.85M faces), whole, writable, in any layout,
    and no block is left behind."""
    import numpy as np

    shm = Path("/dev/shm")
    before = set(shm.glob("psm_*"))  # SharedMemory's blocks (where /dev/shm exists)
    rng = np.random.default_rng(0)
    arrays = {
        "floats": rng.random((300_000, 3)),
        "ints": rng.integers(0, 1 << 40, 500_000),
        "strided": rng.random((1000, 8))[:, ::2],  # not contiguous: pickled in band
        "empty": np.zeros(0, np.int32),
    }
    tasks = runner(tmp_path)
    try:
        assert tasks.isolated(_array_summary, arrays) == _array_summary(arrays)
    finally:
        asyncio.run(tasks.close())
    assert set(shm.glob("psm_*")) <= before


def test_isolated_arguments_go_in_band_where_shared_memory_lacks_room(tmp_path, monkeypatch):
    """A container's /dev/shm is 64 MB by default, and writing past a full tmpfs is a
    SIGBUS: arguments that would not fit are pickled in band instead."""
    import os
    from types import SimpleNamespace

    import numpy as np

    from neural_shdf.api import tasks as tasks_module

    full = SimpleNamespace(f_bavail=1, f_frsize=4096)
    monkeypatch.setattr(tasks_module.os, "statvfs", lambda path: full)
    arrays = {"floats": np.random.default_rng(1).random((100_000, 3))}
    assert tasks_module._SharedArguments.fitting((arrays,)) is None
    tasks = runner(tmp_path)
    try:
        assert tasks.isolated(_array_summary, arrays) == _array_summary(arrays)
        assert tasks.isolated(os.getpid) != os.getpid()
    finally:
        asyncio.run(tasks.close())


def test_a_dead_worker_process_is_a_503_and_the_next_call_starts_a_new_one(tmp_path):
    import os
    import signal

    tasks = runner(tmp_path)
    try:
        first = tasks.isolated(os.getpid)
        with pytest.raises(ApiError) as raised:
            tasks.isolated(os.kill, first, signal.SIGKILL)
        assert raised.value.status_code == 503 and raised.value.code == "worker_lost"
        assert tasks.isolated(os.getpid) not in (first, os.getpid())
    finally:
        asyncio.run(tasks.close())


def _alive(process: psutil.Process) -> bool:
    try:
        return process.is_running() and process.status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False


def _still_alive(processes: Iterable[psutil.Process], within_s: float = 5.0) -> list[int]:
    """The pids of ``processes`` still alive after up to ``within_s``; those are then
    killed, so that a failing test leaves nothing behind either."""
    processes = list(processes)
    deadline = time.monotonic() + within_s
    while any(_alive(p) for p in processes) and time.monotonic() < deadline:
        time.sleep(0.05)
    alive = [p for p in processes if _alive(p)]
    for process in alive:
        process.kill()
    return [p.pid for p in alive]


def _mark_then_sleep(mark: str, seconds: float) -> None:
    Path(mark).touch()
    time.sleep(seconds)


def test_closing_ends_the_worker_process_even_mid_call(tmp_path):
    """``close`` ends the isolated worker while it computes: asked to exit through its pool,
    it would only read that once its call returned, and only if this process still ran."""
    tasks = runner(tmp_path)
    worker = psutil.Process(tasks.isolated(os.getpid))
    mark, answers = tmp_path / "started", []

    def busy() -> None:
        try:
            tasks.isolated(_mark_then_sleep, str(mark), 60)
        except ApiError as exc:
            answers.append(exc.code)

    call = threading.Thread(target=busy)
    call.start()
    try:
        deadline = time.monotonic() + 30
        while not mark.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert mark.exists()
        asyncio.run(tasks.close())
    finally:
        leftover = _still_alive([worker])
    call.join(10)
    assert leftover == []
    assert answers == ["shutting_down"]
    with pytest.raises(ApiError) as raised:  # no new worker after close
        tasks.isolated(os.getpid)
    assert raised.value.status_code == 503 and raised.value.code == "shutting_down"


def _server_process(base: str) -> psutil.Process:
    """The `neural-shdf serve` process (a child of this one) listening at ``base``."""
    port = base.rsplit(":", 1)[1]
    for child in psutil.Process().children():
        with_port = child.environ().get("NEURAL_SHDF_PORT") == port
        if with_port and "neural_shdf.api.serve" in child.cmdline():
            return child
    raise AssertionError(f"no server process on port {port}")


def test_a_stopped_service_leaves_no_process_behind(tmp_path):
    """A real `neural-shdf serve` stopped with SIGTERM (as a container stop, systemd and the
    test fixtures do) while its worker process packs an atlas leaves no process behind.
    uvicorn re-raises the SIGTERM once its own shutdown is done, which ends the server
    without the clean-up that would tell its pool's worker (and the resource tracker that
    waits on it) to exit."""
    data = quad_dumbbell_obj(rings=12, sectors=8)
    with running_server(tmp_path / "cache", sync_face_threshold=10, warm_up=False) as base:
        server = _server_process(base)
        with ServiceClient(base, progress=False) as client:
            mesh_id = client.upload(data, file_type="obj").mesh_id  # its ShDF job, waited for
        # An 8192-texel atlas: xatlas packs for seconds in the worker process, as a job.
        query = {"clusters": 3, "atlas_size": 8192}
        url = f"{base}/v1/meshes/{mesh_id}/segmentation/uvs"
        assert httpx.get(url, params=query, timeout=60).status_code == 202
        deadline = time.monotonic() + 120
        worker, used = None, 0.0
        while worker is None or sum(worker.cpu_times()[:2]) < used + 1.0:
            assert time.monotonic() < deadline, "the worker process never got busy"
            if worker is None:
                workers = [p for p in server.children() if "spawn_main" in " ".join(p.cmdline())]
                if workers:
                    worker, used = workers[0], sum(workers[0].cpu_times()[:2])
            time.sleep(0.1)
        started = server.children(recursive=True)  # the worker and the resource tracker
    assert not _alive(server)
    assert _still_alive(started) == []


#: Scripts that start a worker process, print its pid, then keep it busy for a minute.
SERVICE_WORKER = """
import os, sys, time
from pathlib import Path
from neural_shdf.api.tasks import TaskRunner
from neural_shdf.store.backends import DiskBackend
from neural_shdf.store.cache import ResultCache
from tests.api.api_helpers import make_settings
cache = Path(sys.argv[1])
tasks = TaskRunner(make_settings(cache), ResultCache(DiskBackend(cache, 2**30)))
print(tasks.isolated(os.getpid), flush=True)
tasks.isolated(time.sleep, 60)
"""
WATCH_ONLY_WORKER = """
import multiprocessing, os, time
from concurrent.futures import ProcessPoolExecutor
from neural_shdf.processes import exit_when_orphaned
spawn = multiprocessing.get_context("spawn")
pool = ProcessPoolExecutor(1, spawn, initializer=exit_when_orphaned, initargs=(os.getpid(),))
print(pool.submit(os.getpid).result(), flush=True)
pool.submit(time.sleep, 60).result()
"""


@pytest.mark.parametrize(
    "script", [SERVICE_WORKER, WATCH_ONLY_WORKER], ids=["service-worker", "portable-watch"]
)
def test_a_worker_process_ends_with_its_killed_parent(tmp_path, script):
    """SIGKILL (the OOM killer, a container stop) runs no clean-up in the parent: the
    worker ends by itself, by the kernel's parent-death signal (Linux) or, anywhere, its
    thread that watches the parent."""
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(REPOSITORY / "service"), str(REPOSITORY)])
    )
    parent = subprocess.Popen(
        [sys.executable, "-c", script, str(tmp_path / "cache")],
        stdout=subprocess.PIPE,
        env=env,
        cwd=REPOSITORY,
    )
    assert parent.stdout is not None
    try:
        worker = psutil.Process(int(parent.stdout.readline()))
        assert worker.ppid() == parent.pid
        parent.kill()
        parent.wait(10)
        assert _still_alive([worker]) == []
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        parent.stdout.close()  # never read to its end: the worker shares it while alive
