"""Where the service's work runs, and the one compute-once pattern.

CPU-heavy steps run on a compute thread pool, short blocking steps (cache I/O,
bookkeeping) on an I/O pool, never on the event loop. Deduplication works at two
levels: concurrent requests for one key in a process share one in-flight future
(``single_flight``); workers and replicas serialise on the cache's lock and look
the result up again under it (``compute_once``), so only the first computes.
"""

from __future__ import annotations

import asyncio
import functools
from collections.abc import Awaitable, Callable, Coroutine
from concurrent.futures import ThreadPoolExecutor
from typing import Any, TypeVar

from neural_shdf.api.cache import ResultCache
from neural_shdf.api.errors import ApiError
from neural_shdf.api.settings import Settings

T = TypeVar("T")
G = TypeVar("G")


class TaskRunner:
    """Thread pools, single flight, request timeouts and background tasks of one process."""

    def __init__(self, settings: Settings, cache: ResultCache) -> None:
        self.settings = settings
        self.cache = cache
        self.executor = ThreadPoolExecutor(settings.compute_threads, thread_name_prefix="compute")
        self.io_executor = ThreadPoolExecutor(settings.io_threads, thread_name_prefix="io")
        self._inflight: dict[str, asyncio.Future[Any]] = {}
        self._background: set[asyncio.Task[Any]] = set()

    async def run(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a CPU-heavy ``fn`` on the compute thread pool."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self.executor, functools.partial(fn, *args, **kwargs))

    async def io(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a short blocking step on the I/O thread pool, so it never waits behind
        long computations."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self.io_executor, functools.partial(fn, *args, **kwargs))

    async def single_flight(self, key: str, fn: Callable[[], T]) -> T:
        """Run ``fn`` on the compute pool once per key at a time in this process;
        concurrent callers share it."""
        future = self._inflight.get(key)
        if future is None:
            loop = asyncio.get_running_loop()
            future = loop.run_in_executor(self.executor, fn)
            self._inflight[key] = future

            def _done(done: asyncio.Future[Any], key: str = key) -> None:
                if self._inflight.get(key) is done:
                    del self._inflight[key]
                if not done.cancelled():
                    done.exception()  # mark retrieved; callers get it through await

            future.add_done_callback(_done)
        return await asyncio.shield(future)

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
    ) -> tuple[T, bool]:
        """Under the cache's lock for ``key``: ``lookup`` again (another worker may have
        finished meanwhile), else ``compute`` and ``store``. Returns (result, was cached).
        ``guard``: taken before computing (it raises when the mesh is gone) and handed to
        ``store``, which stores only while it still holds (deletion is final).
        Blocking: call it on the compute pool (``single_flight``)."""
        with self.cache.lock(key, self.settings.lock_timeout_s):
            found = lookup()
            if found is not None:
                return found, True
            held = guard() if guard is not None else None
            result = compute()
            store(result, held)
            return result, False

    def spawn(self, coroutine: Coroutine[Any, Any, Any]) -> asyncio.Task[Any]:
        """Run ``coroutine`` in the background, kept alive until it ends or ``close``."""
        task = asyncio.create_task(coroutine)
        self._background.add(task)
        task.add_done_callback(self._background.discard)
        return task

    async def close(self) -> None:
        for task in list(self._background):
            task.cancel()
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.io_executor.shutdown(wait=False, cancel_futures=True)
