"""Shared result cache: local disk (diskcache) by default, Redis for several replicas.

Every entry is ``MAGIC + sha256(payload) + payload``; an entry whose checksum does
not match (corrupt, truncated, written by something else) is deleted and reported
as a miss, so it is recomputed and never served. Keys are grouped per mesh id so a
mesh and everything derived from it can be deleted together.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import threading
from collections import OrderedDict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

logger = logging.getLogger(__name__)

MAGIC = b"NSHDF1\n"
_DIGEST_SIZE = 32


class CorruptEntryError(ValueError):
    """A cache entry failed its checksum or could not be decoded."""


def seal(payload: bytes) -> bytes:
    """Frame ``payload`` with its checksum."""
    return MAGIC + hashlib.sha256(payload).digest() + payload


def unseal(blob: bytes) -> bytes:
    """The payload of a sealed blob; CorruptEntryError when it does not verify."""
    head = len(MAGIC) + _DIGEST_SIZE
    if not isinstance(blob, bytes | bytearray | memoryview) or len(blob) < head:
        raise CorruptEntryError("entry too short")
    blob = bytes(blob)
    if blob[: len(MAGIC)] != MAGIC:
        raise CorruptEntryError("bad magic")
    payload = blob[head:]
    if hashlib.sha256(payload).digest() != blob[len(MAGIC) : head]:
        raise CorruptEntryError("checksum mismatch")
    return payload


def encode_arrays(arrays: dict[str, NDArray]) -> bytes:
    """Arrays as an uncompressed .npz (no pickles)."""
    buffer = io.BytesIO()
    np.savez(buffer, **{name: np.asarray(value) for name, value in arrays.items()})
    return buffer.getvalue()


def decode_arrays(payload: bytes) -> dict[str, NDArray]:
    try:
        with np.load(io.BytesIO(payload), allow_pickle=False) as npz:
            return {name: npz[name] for name in npz.files}
    except Exception as exc:  # noqa: BLE001 - any decoding failure means a corrupt entry
        raise CorruptEntryError(f"undecodable arrays: {exc}") from exc


class Backend(Protocol):
    """Byte store shared by every worker/replica of the service."""

    name: str
    #: Whether exists() is cheap enough to call on the event loop (local, never waits).
    local: bool

    def get(self, key: str) -> bytes | None: ...
    def exists(self, key: str) -> bool | None: ...  # None: the store cannot tell now
    def set(self, key: str, value: bytes, *, group: str, expire: float | None = None) -> None: ...
    def delete(self, key: str) -> None: ...
    def delete_group(self, group: str) -> int: ...
    def lock(self, key: str, timeout: float) -> contextlib.AbstractContextManager[None]: ...
    def ping(self) -> bool: ...
    def close(self) -> None: ...


class DiskBackend:
    """diskcache on local disk: SQLite-indexed, size-capped, LRU, safe across processes."""

    name = "disk"
    local = True  # SQLite in WAL mode: reads do not wait for writers

    def __init__(self, directory: Path, size_limit: int) -> None:
        import diskcache

        directory.mkdir(parents=True, exist_ok=True)
        self._cache = diskcache.Cache(
            str(directory),
            size_limit=size_limit,
            eviction_policy="least-recently-used",
            tag_index=True,
            timeout=60,
        )

    def get(self, key: str) -> bytes | None:
        value = self._cache.get(key, default=None, retry=True)
        return value if isinstance(value, bytes) else None

    def exists(self, key: str) -> bool | None:
        return key in self._cache

    def set(self, key: str, value: bytes, *, group: str, expire: float | None = None) -> None:
        # diskcache writes the value file first, then commits the SQLite row in one
        # transaction: a reader never sees a half-written entry.
        self._cache.set(key, value, expire=expire, tag=group, retry=True)

    def delete(self, key: str) -> None:
        self._cache.delete(key, retry=True)

    def delete_group(self, group: str) -> int:
        return int(self._cache.evict(group, retry=True))

    @contextlib.contextmanager
    def lock(self, key: str, timeout: float) -> Iterator[None]:
        import diskcache

        with diskcache.Lock(self._cache, f"lock:{key}", expire=timeout):
            yield

    def ping(self) -> bool:
        try:
            self._cache.get("__ping__", retry=True)
            return True
        except Exception:  # noqa: BLE001
            return False

    def close(self) -> None:
        self._cache.close()


class RedisBackend:
    """Redis shared by several replicas; errors degrade to misses (computing again)."""

    name = "redis"
    local = False

    def __init__(
        self,
        url: str,
        timeout_s: float,
        namespace: str = "neural-shdf",
        ttl_s: float | None = None,
    ) -> None:
        import redis

        self._redis = redis.Redis.from_url(
            url, socket_timeout=timeout_s, socket_connect_timeout=timeout_s
        )
        self._errors = (redis.RedisError, OSError)
        self._ns = namespace
        self._ttl_s = ttl_s
        self._local_locks: dict[str, threading.Lock] = {}
        self._local_guard = threading.Lock()
        self.on_error: Callable[[Exception], None] = lambda exc: None

    def _key(self, key: str) -> str:
        return f"{self._ns}:{key}"

    def _failed(self, exc: Exception) -> None:
        logger.warning("redis unavailable: %s", exc)
        self.on_error(exc)

    def get(self, key: str) -> bytes | None:
        try:
            return self._redis.get(self._key(key))
        except self._errors as exc:
            self._failed(exc)
            return None

    def exists(self, key: str) -> bool | None:
        try:
            return bool(self._redis.exists(self._key(key)))
        except self._errors as exc:
            self._failed(exc)
            return None

    def set(self, key: str, value: bytes, *, group: str, expire: float | None = None) -> None:
        # SET is atomic: readers see the old value or the whole new one.
        expire = expire or self._ttl_s
        seconds = max(1, int(expire)) if expire else None
        try:
            pipe = self._redis.pipeline(transaction=True)
            pipe.set(self._key(key), value, ex=seconds)
            pipe.sadd(self._key(f"group:{group}"), key)
            if self._ttl_s:
                pipe.expire(self._key(f"group:{group}"), max(1, int(self._ttl_s)))
            pipe.execute()
        except self._errors as exc:
            self._failed(exc)

    def delete(self, key: str) -> None:
        try:
            self._redis.delete(self._key(key))
        except self._errors as exc:
            self._failed(exc)

    def delete_group(self, group: str) -> int:
        try:
            members = self._redis.smembers(self._key(f"group:{group}"))
            keys = [self._key(m.decode()) for m in members]
            removed = self._redis.delete(*keys) if keys else 0
            self._redis.delete(self._key(f"group:{group}"))
            return int(removed)
        except self._errors as exc:
            self._failed(exc)
            return 0

    @contextlib.contextmanager
    def lock(self, key: str, timeout: float) -> Iterator[None]:
        lock = self._redis.lock(self._key(f"lock:{key}"), timeout=timeout, blocking_timeout=timeout)
        try:
            acquired = lock.acquire()
        except self._errors as exc:
            self._failed(exc)
            acquired = None
        if acquired is None:  # Redis down: at least serialise this process's threads
            with self._local_guard:
                local = self._local_locks.setdefault(key, threading.Lock())
            with local:
                yield
            return
        try:
            yield
        finally:
            with contextlib.suppress(*self._errors):
                lock.release()

    def ping(self) -> bool:
        try:
            return bool(self._redis.ping())
        except self._errors:
            return False

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._redis.close()


class ResultCache:
    """Typed, checksummed entries over a Backend, with a small in-memory LRU in front."""

    def __init__(self, backend: Backend, memory_items: int = 16) -> None:
        self.backend = backend
        self._memory: OrderedDict[str, Any] = OrderedDict()
        self._memory_items = memory_items
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

    def forget_group(self, group: str) -> None:
        with self._memory_guard:
            for key in [k for k in self._memory if k.startswith(f"{group}:")]:
                del self._memory[key]

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

    def get_arrays(self, key: str) -> dict[str, NDArray] | None:
        payload = self._payload(key)
        if payload is None:
            return None
        try:
            return decode_arrays(payload)
        except CorruptEntryError:
            self.on_corrupt(key)
            self.backend.delete(key)
            return None

    def put_arrays(self, key: str, arrays: dict[str, NDArray], *, group: str) -> None:
        self.backend.set(key, seal(encode_arrays(arrays)), group=group)

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

    def put_json(self, key: str, value: Any, *, group: str, expire: float | None = None) -> None:
        self.backend.set(key, seal(json.dumps(value).encode()), group=group, expire=expire)

    def delete_group(self, group: str) -> int:
        self.forget_group(group)
        return self.backend.delete_group(group)

    def lock(self, key: str, timeout: float) -> contextlib.AbstractContextManager[None]:
        return self.backend.lock(key, timeout)

    def ping(self) -> bool:
        return self.backend.ping()

    def close(self) -> None:
        self.backend.close()
