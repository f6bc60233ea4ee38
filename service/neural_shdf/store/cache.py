"""The result cache: typed, checksummed entries over a backend, with small in-memory LRUs
in front; leases for the compute-once pattern. ``open_cache`` builds one from a
``CacheConfig`` (the service's settings of the same names, or batch's)."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, TypeVar, cast

from numpy.typing import NDArray

from neural_shdf.store.backends import Backend, DiskBackend, FallbackBackend, RedisBackend
from neural_shdf.store.codec import CorruptEntryError, decode_arrays, seal, seal_arrays, unseal
from neural_shdf.store.keys import lock_key
from neural_shdf.store.leases import Lease

logger = logging.getLogger(__name__)
T = TypeVar("T")
G = TypeVar("G")

#: The local disk cache's folder unless configured (``CacheConfig.cache_dir``).
DEFAULT_CACHE_DIR = Path.home() / ".cache" / "neural-shdf" / "service"
#: Prefix of the environment variables that configure the cache (the service's settings).
ENV_PREFIX = "NEURAL_SHDF_"


#: How an environment variable's text becomes a ``CacheConfig`` field, by its type.
_PARSERS: dict[str, Callable[[str], Any]] = {"Path": Path, "int": int, "float": float, "str": str}


@dataclass(frozen=True)
class CacheConfig:
    """Where results are stored and how the store behaves. The service's settings of the
    same names (``api.settings.Settings``, which documents each) take their defaults from
    here; batch workers read them from the same environment variables."""

    cache_dir: Path = DEFAULT_CACHE_DIR
    cache_size_bytes: int = 2 * 1024**3
    redis_url: str | None = None
    redis_timeout_s: float = 2.0
    redis_retry_s: float = 5.0
    redis_ttl_s: float | None = 30 * 24 * 3600
    memory_cache_items: int = 16
    memory_working_set_bytes: int = 1024**3
    lock_lease_s: float = 5.0
    lock_timeout_s: float = 600.0

    @classmethod
    def from_environment(
        cls, environ: Mapping[str, str] | None = None, **overrides: Any
    ) -> CacheConfig:
        """The defaults, overridden by ``NEURAL_SHDF_<NAME>`` variables, then ``overrides``."""
        environ = os.environ if environ is None else environ
        values: dict[str, Any] = {}
        for spec in fields(cls):
            text = environ.get(f"{ENV_PREFIX}{spec.name.upper()}")
            if text is not None:
                values[spec.name] = _PARSERS[str(spec.type).split(" ")[0]](text)
        return replace(cls(**values), **overrides)

    @classmethod
    def of(cls, settings: Any) -> CacheConfig:
        """The cache's part of an object with the same attribute names (the settings)."""
        return cls(**{spec.name: getattr(settings, spec.name) for spec in fields(cls)})


class ResultCache:
    """Typed, checksummed entries over a Backend, with a small in-memory LRU in front."""

    def __init__(
        self,
        backend: Backend,
        memory_items: int = 16,
        lease_s: float = 5.0,
        working_set_bytes: int = 1024**3,
    ) -> None:
        self.backend = backend
        self.lease_s = lease_s
        self._memory: OrderedDict[str, Any] = OrderedDict()
        self._memory_items = memory_items
        # Large per-mesh working sets (e.g. segmentation bases), bounded by their bytes.
        self._working: OrderedDict[str, tuple[Any, int]] = OrderedDict()
        self._working_bytes = working_set_bytes
        self._memory_guard = threading.Lock()
        self.on_corrupt: Callable[[str], None] = lambda key: None

    # -- in-process memory ----------------------------------------------------
    def remember(self, key: str, value: Any) -> None:
        if self._memory_items <= 0:
            return
        with self._memory_guard:
            self._memory[key] = value
            self._memory.move_to_end(key)
            while len(self._memory) > self._memory_items:
                self._memory.popitem(last=False)

    def recall(self, key: str) -> Any | None:
        with self._memory_guard:
            value = self._memory.get(key)
            if value is not None:
                self._memory.move_to_end(key)
            return value

    def keep_working_set(self, key: str, value: Any, nbytes: int) -> None:
        """Keep a large in-process value (never shared), least recently used dropped first
        so that all kept ones stay within ``working_set_bytes``; one larger is not kept."""
        with self._memory_guard:
            self._working.pop(key, None)
            if nbytes > self._working_bytes:
                return
            self._working[key] = (value, nbytes)
            total = sum(size for _, size in self._working.values())
            while total > self._working_bytes:
                _, (_, size) = self._working.popitem(last=False)
                total -= size

    def working_set(self, key: str) -> Any | None:
        """A value ``keep_working_set`` kept, or None."""
        with self._memory_guard:
            kept = self._working.get(key)
            if kept is None:
                return None
            self._working.move_to_end(key)
            return kept[0]

    def forget_group(self, group: str) -> None:
        with self._memory_guard:
            for memory in (self._memory, self._working):
                for key in [k for k in memory if k.startswith(f"{group}:")]:
                    del memory[key]

    # -- shared, checksummed entries -------------------------------------------
    def _payload(self, key: str) -> bytes | None:
        blob = self.backend.get(key)
        if blob is None:
            return None
        try:
            return unseal(blob)
        except CorruptEntryError as exc:
            logger.warning("dropping corrupt cache entry %s: %s", key, exc)
            self.on_corrupt(key)
            self.backend.delete(key)
            return None

    def get_arrays(self, key: str) -> dict[str, NDArray[Any]] | None:
        payload = self._payload(key)
        if payload is None:
            return None
        try:
            return decode_arrays(payload)
        except CorruptEntryError:
            self.on_corrupt(key)
            self.backend.delete(key)
            return None

    def recall_arrays(self, key: str, decode: Callable[[dict[str, NDArray[Any]]], T]) -> T | None:
        """This process's memory of ``key``, else its stored arrays through ``decode`` (then
        remembered); None when absent or when ``decode`` rejects them (KeyError, ValueError)."""
        remembered = self.recall(key)
        if remembered is not None:
            return cast(T, remembered)  # what is remembered under a key is its decoded result
        arrays = self.get_arrays(key)
        if arrays is None:
            return None
        try:
            value = decode(arrays)
        except (KeyError, ValueError):
            return None
        self.remember(key, value)
        return value

    def put_arrays(
        self,
        key: str,
        arrays: dict[str, NDArray[Any]],
        *,
        group: str,
        keep_local: bool = False,
        guard: tuple[str, bytes] | None = None,
    ) -> bool:
        """Store arrays; ``keep_local``: also readable from this host while Redis is down
        (for what cannot be recomputed: uploaded meshes, job records). ``guard``: (key,
        stored bytes) that must still be there, checked atomically with the write (a
        result of a mesh deleted meanwhile is never stored); whether it was stored."""
        blob = seal_arrays(arrays)
        if guard is None:
            self.backend.set(key, blob, group=group, keep_local=keep_local)
            return True
        guard_key, expected = guard
        return self.backend.set_if(key, blob, group=group, guard=guard_key, expected=expected)

    def get_raw(self, key: str) -> bytes | None:
        """The stored bytes of ``key`` as they are (a ``guard`` for ``put_arrays``)."""
        return self.backend.get(key)

    def add_json(self, key: str, value: Any, *, group: str, keep_local: bool = False) -> bool:
        """Store ``value`` unless ``key`` exists (atomic); whether it was stored."""
        blob = seal(json.dumps(value).encode())
        return self.backend.add(key, blob, group=group, keep_local=keep_local)

    def get_json(self, key: str) -> Any | None:
        payload = self._payload(key)
        if payload is None:
            return None
        try:
            return json.loads(payload)
        except ValueError:
            self.on_corrupt(key)
            self.backend.delete(key)
            return None

    def put_json(
        self,
        key: str,
        value: Any,
        *,
        group: str,
        expire: float | None = None,
        keep_local: bool = False,
    ) -> None:
        blob = seal(json.dumps(value).encode())
        self.backend.set(key, blob, group=group, expire=expire, keep_local=keep_local)

    def delete_group(self, group: str) -> int:
        self.forget_group(group)
        return self.backend.delete_group(group)

    def lease(self, key: str) -> Lease:
        """A lease on ``key`` (not yet taken), lapsing ``lease_s`` after its last renewal."""
        return Lease(self.backend, key, self.lease_s)

    @contextlib.contextmanager
    def lock(self, key: str, wait_s: float) -> Iterator[Lease]:
        """Hold the lease on ``lock:<key>``, waiting up to ``wait_s`` for a live holder
        (a dead one's lapses within ``lease_s``); after that, go on without it: duplicate
        work rather than a stall."""
        lease = self.lease(lock_key(key))
        if not lease.acquire(wait_s):
            logger.warning("%s still held by a live worker after %g s: going on", key, wait_s)
        try:
            yield lease
        finally:
            lease.release()

    def compute_once(
        self,
        key: str,
        lookup: Callable[[], T | None],
        compute: Callable[[], T],
        store: Callable[[T, G | None], None],
        *,
        wait_s: float,
        guard: Callable[[], G] | None = None,
        before_compute: Callable[[], None] = lambda: None,
        store_later: Callable[[Callable[[], None]], None] | None = None,
    ) -> tuple[T, bool]:
        """Under the lock for ``key``: ``lookup`` again (another worker or replica may have
        finished meanwhile), else ``compute`` and ``store``. Returns (result, was cached).
        ``guard``: taken before computing (it raises when the mesh is gone) and handed to
        ``store``, which stores only while it still holds (deletion is final).
        ``before_compute``: runs once the lock is held and nothing was found (the service
        checks there whether anyone still waits). ``store_later``: runs a callable
        elsewhere (a thread pool); then the result is returned before it is stored, and
        the lock is held until it is (a worker waiting for it still finds the result), an
        error of the store logged. Blocking."""
        with contextlib.ExitStack() as held_lock:
            held_lock.enter_context(self.lock(key, wait_s))
            found = lookup()
            if found is not None:
                return found, True
            before_compute()
            held = guard() if guard is not None else None
            result = compute()
            if store_later is None:
                store(result, held)
                return result, False
            release = held_lock.pop_all()  # the lock now goes with the store

            def store_then_release() -> None:
                with release:
                    try:
                        store(result, held)
                    except Exception as exc:  # noqa: BLE001 - the result was served
                        logger.warning("%s was not stored: %s", key, exc)

            try:
                store_later(store_then_release)
            except Exception:  # noqa: BLE001 - nowhere to hand it (shutting down): store here
                store_then_release()
            return result, False

    def health(self) -> tuple[bool, str]:
        """(whether the shared store answers, what was checked or why it failed)."""
        return self.backend.health()

    def ping(self) -> bool:
        return self.health()[0]

    def close(self) -> None:
        self.backend.close()


def open_cache(
    config: CacheConfig,
    *,
    on_error: Callable[[Exception], None] | None = None,
    on_degraded: Callable[[bool], None] | None = None,
    on_corrupt: Callable[[str], None] | None = None,
) -> ResultCache:
    """Redis (the local disk cache as its fallback) when ``redis_url`` is set, else the disk.
    ``on_error``: each Redis error; ``on_degraded``: the breaker opened (True) or closed;
    ``on_corrupt``: an entry's key, dropped because it failed its checksum."""
    disk = DiskBackend(config.cache_dir, config.cache_size_bytes)
    backend: DiskBackend | FallbackBackend = disk
    if config.redis_url:
        redis = RedisBackend(
            config.redis_url,
            config.redis_timeout_s,
            ttl_s=config.redis_ttl_s,
            retry_s=config.redis_retry_s,
        )
        if on_error is not None:
            redis.on_error = on_error
        if on_degraded is not None:
            redis.breaker.on_change = on_degraded
        backend = FallbackBackend(redis, disk)
    cache = ResultCache(
        backend,
        config.memory_cache_items,
        lease_s=config.lock_lease_s,
        working_set_bytes=config.memory_working_set_bytes,
    )
    if on_corrupt is not None:
        cache.on_corrupt = on_corrupt
    return cache
