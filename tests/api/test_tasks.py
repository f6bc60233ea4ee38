"""The task runner: work no one waits for stops at its next checkpoint, and one client's
requests (abandoned or not) never hold every compute thread."""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

import httpx
import pytest
import trimesh

from neural_shdf.api.clients import Client, current_client
from neural_shdf.api.errors import ApiError
from neural_shdf.api.tasks import STORE_DELAY_S, TaskRunner, checkpoint
from neural_shdf.store.backends import DiskBackend
from neural_shdf.store.cache import ResultCache
from tests.api.api_helpers import make_settings
from tests.api.conftest import running_server


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
