"""Where the service's work runs, and the one compute-once pattern.

CPU-heavy steps run on a compute thread pool, short blocking steps (cache I/O,
bookkeeping) on an I/O pool, never on the event loop. Deduplication works at two
levels: concurrent requests for one key in a process share one in-flight computation
(``single_flight``); workers and replicas serialise on the cache's lock and look
the result up again under it (``compute_once``), so only the first computes.

Work no one waits for: each computation counts the requests waiting for it. When the
last of them is gone because its client disconnected, the computation is cancelled: it
stops at its next checkpoint (``checkpoint``; the ShDF's progress reports, the steps
between stages, and before it starts at all). A request that timed out (504) keeps its
computation going, and a retry joins it. Background jobs are never cancelled.

Fair shares: every client (by address; background jobs count as one client) runs at most
``compute_share`` computations on the pool at once; its further requests wait, without a
thread, for one of its own to finish (or for their client to leave). One client, however
many requests it abandons, cannot take every compute thread from the others.
"""

from __future__ import annotations

import asyncio
import contextlib
import contextvars
import functools
import os
import pickle
import threading
import time
from collections.abc import Awaitable, Callable, Coroutine
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from multiprocessing import shared_memory
from multiprocessing.process import BaseProcess
from typing import Any, TypeVar

import numpy as np

from neural_shdf.api.clients import BACKGROUND, current_client
from neural_shdf.api.errors import ApiError
from neural_shdf.api.settings import Settings
from neural_shdf.processes import spawn_pool
from neural_shdf.store.cache import ResultCache

T = TypeVar("T")
G = TypeVar("G")

#: A result stored after its answer (``compute_once(store_later=True)``) is written this long
#: after it went back: by then the answer is serialised and sent, which the write (framing,
#: diskcache's Python around SQLite) would otherwise share the GIL and a core with.
STORE_DELAY_S = 0.03

#: How long ``close`` lets a worker take to end after SIGTERM before it sends SIGKILL.
WORKER_STOP_S = 2.0


class ComputationCancelled(Exception):  # noqa: N818 - a signal, raised at checkpoints
    """Raised at a checkpoint of a computation no one waits for any more."""


#: The cancellation flag of the computation running on this compute thread.
_cancellation: contextvars.ContextVar[threading.Event | None] = contextvars.ContextVar(
    "cancellation", default=None
)


def cancellation() -> threading.Event | None:
    """The flag of the computation running on this thread (capture it for callbacks that
    other threads may call), or None outside the task runner."""
    return _cancellation.get()


def checkpoint(flag: threading.Event | None = None) -> None:
    """Stop here (ComputationCancelled) if this computation (or ``flag``) was cancelled."""
    flag = flag if flag is not None else _cancellation.get()
    if flag is not None and flag.is_set():
        raise ComputationCancelled("no request waits for this computation any more")


def client_gone() -> ApiError:
    """What a request whose client disconnected answers (nobody reads it)."""
    return ApiError(499, "client_closed_request", "the client closed the connection")


@dataclass
class Flight:
    """One computation on the compute pool and the requests waiting for it."""

    future: asyncio.Future[Any]
    cancel: threading.Event = field(default_factory=threading.Event)
    waiters: int = 0
    keep: bool = False  # a job or a timed-out request counts on it: never cancelled


class TaskRunner:
    """Thread pools, single flight, fair shares, cancellation, request timeouts and
    background tasks of one process."""

    def __init__(self, settings: Settings, cache: ResultCache) -> None:
        self.settings = settings
        self.cache = cache
        self.executor = ThreadPoolExecutor(settings.compute_threads, thread_name_prefix="compute")
        self.io_executor = ThreadPoolExecutor(settings.io_threads, thread_name_prefix="io")
        # Results stored after their answer (``compute_once(store_later=True)``), one at a time.
        self.store_executor = ThreadPoolExecutor(1, thread_name_prefix="store")
        self._isolated: ProcessPoolExecutor | None = None
        self._isolated_lock = threading.Lock()
        self._closed = False  # no new worker process once closed
        self.share = settings.compute_share or max(1, settings.compute_threads - 1)
        self._inflight: dict[str, Flight] = {}
        self._shares: dict[str, asyncio.Semaphore] = {}
        self._background: set[asyncio.Task[Any]] = set()
        self.on_cancelled: Callable[[], None] = lambda: None  # a computation stopped

    async def run(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a CPU-heavy ``fn`` on the compute pool (within its client's share; cancelled
        when the client leaves)."""
        flight = await self._start(functools.partial(fn, *args, **kwargs))
        return await self._wait(flight)

    async def io(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a short blocking step on the I/O thread pool, so it never waits behind
        long computations."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self.io_executor, functools.partial(fn, *args, **kwargs))

    async def single_flight(self, key: str, fn: Callable[[], T], *, keep: bool = False) -> T:
        """Run ``fn`` on the compute pool once per key at a time in this process;
        concurrent callers share it. ``keep``: never cancel it (a job's)."""
        flight = self._inflight.get(key)
        if flight is None or flight.cancel.is_set():  # a cancelled one is on its way out
            flight = await self._start(fn, key)
        flight.keep |= keep
        return await self._wait(flight)

    async def _start(self, fn: Callable[[], T], key: str | None = None) -> Flight:
        """Wait for a slot of the client's share, then submit ``fn`` (keyed: shared by
        concurrent callers of the key, who join it meanwhile)."""
        client = current_client.get()
        share_key = client.key if client is not None else BACKGROUND
        share = self._shares.setdefault(share_key, asyncio.Semaphore(self.share))
        await self._until_client_gone(share.acquire())
        started = self._inflight.get(key) if key is not None else None
        if started is not None and not started.cancel.is_set():  # started meanwhile: join
            share.release()
            return started
        flag = threading.Event()
        context = contextvars.copy_context()
        context.run(_cancellation.set, flag)

        def call() -> T:
            checkpoint(flag)  # cancelled while it queued
            return context.run(fn)

        loop = asyncio.get_running_loop()
        future = loop.run_in_executor(self.executor, call)
        flight = Flight(future, flag)
        if key is not None:
            self._inflight[key] = flight

        def done(finished: asyncio.Future[Any]) -> None:
            share.release()
            if key is not None and self._inflight.get(key) is flight:
                del self._inflight[key]
            if not finished.cancelled():
                error = finished.exception()  # marks it retrieved; waiters get it through await
                if isinstance(error, ComputationCancelled):
                    self.on_cancelled()

        future.add_done_callback(done)
        return flight

    async def _until_client_gone(self, awaitable: Awaitable[T]) -> T:
        """``awaitable``'s result, or 499 as soon as the request's client disconnects."""
        task = asyncio.ensure_future(awaitable)
        client = current_client.get()
        if client is None:
            return await task
        gone = asyncio.ensure_future(client.gone().wait())
        try:
            await asyncio.wait({task, gone}, return_when=asyncio.FIRST_COMPLETED)
        except asyncio.CancelledError:
            task.cancel()
            raise
        finally:
            gone.cancel()
        if task.done():
            return task.result()
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task  # a cancelled Semaphore.acquire passes on a slot it was handed
        raise client_gone()

    async def _wait(self, flight: Flight) -> Any:
        """The flight's result for one waiter; the last waiter to leave because its client
        disconnected cancels it (unless it is kept)."""
        flight.waiters += 1
        client_left = False
        try:
            return await self._until_client_gone(asyncio.shield(flight.future))
        except ApiError as exc:
            client_left = exc.status_code == 499
            raise
        except asyncio.CancelledError:  # a timeout (504) or shutdown: the work goes on
            flight.keep = True
            raise
        finally:
            flight.waiters -= 1
            if client_left and flight.waiters == 0 and not flight.keep:
                flight.cancel.set()

    async def with_timeout(self, awaitable: Awaitable[T]) -> T:
        """``awaitable`` within the request timeout, else a 504 (the work goes on)."""
        try:
            return await asyncio.wait_for(awaitable, self.settings.request_timeout_s)
        except TimeoutError:
            raise ApiError(
                504,
                "timeout",
                f"the computation did not finish within {self.settings.request_timeout_s:g} s; "
                "it goes on in the background, retry the request later",
            ) from None

    def compute_once(
        self,
        key: str,
        lookup: Callable[[], T | None],
        compute: Callable[[], T],
        store: Callable[[T, G | None], None],
        guard: Callable[[], G] | None = None,
        *,
        store_later: bool = False,
    ) -> tuple[T, bool]:
        """``ResultCache.compute_once`` within the lock timeout, stopping before it computes
        if no request waits any more (it may have waited long for the lock). ``store_later``:
        return the result first and store it on the store thread soon after (the lock held
        until it is stored). Blocking: call it on the compute pool (``single_flight``)."""
        return self.cache.compute_once(
            key,
            lookup,
            compute,
            store,
            wait_s=self.settings.lock_timeout_s,
            guard=guard,
            before_compute=checkpoint,
            store_later=self._store_soon if store_later else None,
        )

    def _store_soon(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` (a store) on the store thread ``STORE_DELAY_S`` from now; if shutting
        down cancels it first, where it was cancelled (it still lands, its lock released)."""
        due = time.monotonic() + STORE_DELAY_S

        def when_due() -> None:
            time.sleep(max(0.0, due - time.monotonic()))
            fn()

        future = self.store_executor.submit(when_due)
        future.add_done_callback(lambda done: fn() if done.cancelled() else None)

    def spawn(self, coroutine: Coroutine[Any, Any, Any]) -> asyncio.Task[Any]:
        """Run ``coroutine`` in the background, kept alive until it ends or ``close``; it
        belongs to no request (its work is not cancelled when that request's client
        leaves, and counts in the background share)."""
        context = contextvars.copy_context()
        context.run(current_client.set, None)
        task = asyncio.create_task(coroutine, context=context)
        self._background.add(task)
        task.add_done_callback(self._background.discard)
        return task

    def isolated(self, function: Callable[..., T], *args: Any) -> T:
        """``function(*args)`` in a worker process (started on first use, then kept), for
        library code that holds the GIL for seconds (xatlas's packing): in a thread it
        would stall the event loop, and with it every other request. Arguments and result
        are pickled; so are the project's exceptions. Blocking: call it on the compute pool
        (on Linux the worker dies with the thread that started it; the pool's threads live
        until ``close``, which ends the worker, and the worker ends with this process however
        it dies)."""
        with self._isolated_lock:
            if self._closed:
                raise _shutting_down()
            if self._isolated is None:
                self._isolated = spawn_pool(1)  # ends with this process, however it ends
            pool = self._isolated
        try:
            shared = _SharedArguments.fitting(args)
            if shared is None:  # no room in /dev/shm (a container's default is 64 MB)
                return _submit(pool, function, *args).result()
            with shared:
                payload, block_name, sizes = shared.handle
                future = _submit(pool, _call_with_shared, function, payload, block_name, sizes)
                return future.result()
        except BrokenProcessPool:
            # The worker died (killed for memory, or ended by ``close``): the next call
            # starts a new one.
            with self._isolated_lock:
                if self._isolated is pool:
                    self._isolated = None
                if self._closed:
                    raise _shutting_down() from None
            raise ApiError(
                503, "worker_lost", "the worker process died during this request; retry it"
            ) from None

    async def close(self) -> None:
        for task in list(self._background):
            task.cancel()
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.io_executor.shutdown(wait=False, cancel_futures=True)
        self.store_executor.shutdown(wait=False, cancel_futures=True)
        with self._isolated_lock:
            self._closed = True
            pool, self._isolated = self._isolated, None
        if pool is not None:
            # Ended here, busy or not: uvicorn re-raises the SIGTERM it stopped on once its
            # shutdown is done, which kills this process without the clean-up that would
            # tell an idle worker to exit (and a busy one would not listen).
            await asyncio.to_thread(_stop_pool, pool)


def _shutting_down() -> ApiError:
    return ApiError(503, "shutting_down", "the service is shutting down; retry the request")


def _submit(pool: ProcessPoolExecutor, function: Callable[..., T], *args: Any) -> Future[T]:
    """``pool.submit``, with a pool that ``close`` shut down meanwhile read as shutting down."""
    try:
        return pool.submit(function, *args)
    except BrokenProcessPool:  # a RuntimeError too: the caller tells a dead worker apart
        raise
    except RuntimeError:  # "cannot schedule new futures after shutdown": ``close`` ran since
        raise _shutting_down() from None


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Shut ``pool`` down and end its worker processes (SIGTERM, then SIGKILL), waiting
    for each; its pending calls fail (``BrokenProcessPool``)."""
    processes = _pool_processes(pool)  # before shutdown, which drops them
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        process.terminate()
    for process in processes:
        process.join(WORKER_STOP_S)
        if process.is_alive():  # stopped (SIGSTOP), or SIGTERM blocked
            process.kill()
            process.join(WORKER_STOP_S)


def _pool_processes(pool: ProcessPoolExecutor) -> list[BaseProcess]:
    """The worker processes ``pool`` started so far. Python has no public handle on them
    before 3.14 (``terminate_workers``, which still does not wait for them); every version
    since 3.2 keeps them in ``_processes`` (pid -> Process), as 3.14's method reads them."""
    return list((pool._processes or {}).values())


class _SharedArguments:
    """Arguments for the worker process with their arrays in shared memory: pickled with
    protocol 5, the arrays' bytes out of band, copied by numpy (which releases the GIL) into
    one shared block. Pickling a million-face mesh in band is one C call on the executor's
    feeder thread that holds the GIL (and stalls the event loop) for a third of a second."""

    def __init__(self, payload: bytes, raws: list[memoryview]) -> None:
        self.payload = payload
        self.sizes = [raw.nbytes for raw in raws]
        self.block = shared_memory.SharedMemory(create=True, size=max(sum(self.sizes), 1))
        shared = np.ndarray((self.block.size,), np.uint8, buffer=self.block.buf)
        offset = 0
        for raw, size in zip(raws, self.sizes, strict=True):
            shared[offset : offset + size] = np.frombuffer(raw, np.uint8)
            offset += size
        del shared  # no view may outlive the block's close

    @classmethod
    def fitting(cls, args: tuple[Any, ...]) -> _SharedArguments | None:
        """The arguments in shared memory, or None where the arrays would take more than
        half the free space of ``/dev/shm`` (writing past a full tmpfs kills the process
        with SIGBUS; pickling in band is slower, never fatal)."""
        buffers: list[pickle.PickleBuffer] = []
        payload = pickle.dumps(args, protocol=5, buffer_callback=buffers.append)
        raws = [buffer.raw() for buffer in buffers]
        needed = sum(raw.nbytes for raw in raws)
        if os.path.isdir("/dev/shm"):
            room = os.statvfs("/dev/shm")
            if needed > 0.5 * room.f_bavail * room.f_frsize:
                return None
        return cls(payload, raws)

    @property
    def handle(self) -> tuple[bytes, str, list[int]]:
        return self.payload, self.block.name, self.sizes

    def __enter__(self) -> _SharedArguments:
        return self

    def __exit__(self, *_: object) -> None:
        self.block.close()
        self.block.unlink()


def _call_with_shared(
    function: Callable[..., T], payload: bytes, block_name: str, sizes: list[int]
) -> T:
    """In the worker: the arguments back from ``_SharedArguments`` (each array copied out
    of the shared block, so the block can close at once), then ``function(*args)``."""
    block = shared_memory.SharedMemory(name=block_name)
    try:
        shared = np.ndarray((block.size,), np.uint8, buffer=block.buf)
        starts = np.cumsum([0, *sizes])
        buffers = [bytearray(shared[a:b]) for a, b in zip(starts[:-1], starts[1:], strict=True)]
        del shared
    finally:
        block.close()
    args = pickle.loads(payload, buffers=buffers)
    return function(*args)
