"""Shared result cache: local disk (diskcache) by default, Redis for several replicas.

Every entry is ``MAGIC + sha256(payload) + payload``; an entry whose checksum does
not match (corrupt, truncated, written by something else) is deleted and reported
as a miss, so it is recomputed and never served. Keys are grouped per mesh id so a
mesh and everything derived from it can be deleted together.

Locks are leases (``Lease``): their holder renews them while it works, so a crashed
holder's lock lapses within seconds. Redis sits behind a circuit breaker with the disk
cache as fallback (``FallbackBackend``): an outage degrades the service, never stalls it.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import logging
import os
import socket
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

logger = logging.getLogger(__name__)
T = TypeVar("T")

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


class BackendUnavailable(Exception):  # noqa: N818 - a state, reported by FallbackBackend
    """The shared store cannot be reached now (error, timeout or open circuit breaker)."""


class Backend(Protocol):
    """Byte store shared by every worker/replica of the service, with leases for locking."""

    name: str
    #: Whether exists() is cheap enough to call on the event loop (local, never waits).
    local: bool

    def get(self, key: str) -> bytes | None: ...
    def exists(self, key: str) -> bool | None: ...  # None: the store cannot tell now
    # keep_local: a shared store also keeps a local copy, readable through its outages
    def set(
        self,
        key: str,
        value: bytes,
        *,
        group: str,
        expire: float | None = None,
        keep_local: bool = False,
    ) -> None: ...
    # add: set only if absent; set_if: only while ``guard`` holds ``expected`` (one of
    # several guard keys, for stores that keep copies under other names); both atomic
    def add(self, key: str, value: bytes, *, group: str, keep_local: bool = False) -> bool: ...
    def set_if(
        self, key: str, value: bytes, *, group: str, guard: str, expected: bytes
    ) -> bool: ...
    def delete(self, key: str) -> None: ...
    def delete_group(self, group: str) -> int: ...  # atomic against set_if
    def acquire_lease(self, key: str, token: str, ttl_s: float) -> bool: ...
    def renew_lease(self, key: str, token: str, ttl_s: float) -> bool: ...
    def release_lease(self, key: str, token: str) -> None: ...  # only if ``token`` holds it
    def lease_holder(self, key: str) -> str | None: ...
    def health(self) -> tuple[bool, str]: ...
    def close(self) -> None: ...


def _lease_key(key: str) -> str:
    return f"lease:{key}"


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

    def get_entry(self, key: str) -> tuple[bytes, str | None, float | None] | None:
        """(value, group, seconds until it expires or None) of a live entry."""
        value, expire_time, group = self._cache.get(
            key, default=None, expire_time=True, tag=True, retry=True
        )
        if not isinstance(value, bytes):
            return None
        return value, group, None if expire_time is None else expire_time - time.time()

    def exists(self, key: str) -> bool | None:
        return key in self._cache

    def keys(self, prefix: str) -> Iterator[str]:
        """Keys starting with ``prefix`` (a scan of the index)."""
        return (key for key in self._cache.iterkeys() if str(key).startswith(prefix))

    def set(
        self,
        key: str,
        value: bytes,
        *,
        group: str,
        expire: float | None = None,
        keep_local: bool = False,
    ) -> None:
        # diskcache writes the value file first, then commits the SQLite row in one
        # transaction: a reader never sees a half-written entry, a crash leaves none.
        self._cache.set(key, value, expire=expire, tag=group, retry=True)

    def add(self, key: str, value: bytes, *, group: str, keep_local: bool = False) -> bool:
        return bool(self._cache.add(key, value, tag=group, retry=True))

    def set_if(
        self,
        key: str,
        value: bytes,
        *,
        group: str,
        guard: str | tuple[str, ...],
        expected: bytes,
    ) -> bool:
        guards = (guard,) if isinstance(guard, str) else guard
        with self._cache.transact(retry=True):
            if not any(self._cache.get(g, default=None) == expected for g in guards):
                return False
            self._cache.set(key, value, tag=group)
        return True

    def delete(self, key: str) -> None:
        self._cache.delete(key, retry=True)

    def delete_group(self, group: str) -> int:
        # One transaction: a set_if either lands before (and is evicted) or sees no guard.
        with self._cache.transact(retry=True):
            return int(self._cache.evict(group))

    def acquire_lease(self, key: str, token: str, ttl_s: float) -> bool:
        # add() is atomic across processes and treats an expired entry as absent.
        return bool(self._cache.add(_lease_key(key), token, expire=ttl_s, retry=True))

    def renew_lease(self, key: str, token: str, ttl_s: float) -> bool:
        lease = _lease_key(key)
        with self._cache.transact(retry=True):
            if self._cache.get(lease, default=None) != token:
                return False
            self._cache.set(lease, token, expire=ttl_s)
        return True

    def release_lease(self, key: str, token: str) -> None:
        lease = _lease_key(key)
        with self._cache.transact(retry=True):
            if self._cache.get(lease, default=None) == token:
                self._cache.delete(lease)

    def lease_holder(self, key: str) -> str | None:
        holder = self._cache.get(_lease_key(key), default=None, retry=True)
        return holder if isinstance(holder, str) else None

    def health(self) -> tuple[bool, str]:
        try:
            self._cache.get("__ping__", retry=True)
        except Exception as exc:  # noqa: BLE001 - reported by /readyz
            return False, f"disk unreadable: {exc}"
        return True, "disk"

    def close(self) -> None:
        self._cache.close()


class CircuitBreaker:
    """Stops calls to a failing dependency at once; a background probe closes it again.

    Closed: calls go through. The first failure opens it: calls fail fast (no waiting on
    timeouts) and a daemon thread runs ``probe`` every ``retry_s`` until one succeeds.
    """

    def __init__(self, name: str, probe: Callable[[], object], retry_s: float) -> None:
        self.name = name
        self.retry_s = retry_s
        self._probe = probe
        self._guard = threading.Lock()
        self._opened_at: float | None = None
        self._last_error = ""
        self._stopped = threading.Event()
        self.on_change: Callable[[bool], None] = lambda is_open: None
        #: Runs after a successful probe, before closing (raising keeps the breaker open).
        self.before_close: Callable[[], None] = lambda: None

    @property
    def is_open(self) -> bool:
        return self._opened_at is not None

    def trip(self, exc: BaseException) -> None:
        """Record a failure: open the breaker (once) and start probing."""
        with self._guard:
            self._last_error = str(exc) or type(exc).__name__
            if self._opened_at is not None:
                return
            self._opened_at = time.monotonic()
        logger.warning(
            "%s unreachable (%s): circuit open, not waiting on it; probing every %g s",
            self.name,
            self._last_error,
            self.retry_s,
        )
        self.on_change(True)
        threading.Thread(
            target=self._probe_until_closed, name=f"{self.name}-probe", daemon=True
        ).start()

    def _probe_until_closed(self) -> None:
        while not self._stopped.wait(self.retry_s):
            try:
                self._probe()
                self.before_close()
            except Exception as exc:  # noqa: BLE001 - still down
                self._last_error = str(exc) or type(exc).__name__
                continue
            with self._guard:
                opened_at, self._opened_at = self._opened_at, None
            seconds = time.monotonic() - opened_at if opened_at is not None else 0.0
            logger.warning("%s reachable again after %.1f s: circuit closed", self.name, seconds)
            self.on_change(False)
            return

    def describe(self) -> str:
        opened_at = self._opened_at
        if opened_at is None:
            return f"{self.name} reachable"
        return (
            f"{self.name} unreachable for {time.monotonic() - opened_at:.0f} s "
            f"({self._last_error}); probed every {self.retry_s:g} s"
        )

    def stop(self) -> None:
        self._stopped.set()


# Compare-and-renew / compare-and-delete: only the holder's token may touch its lease.
_RENEW_LEASE = """
if redis.call('get', KEYS[1]) == ARGV[1] then
    return redis.call('pexpire', KEYS[1], ARGV[2])
end
return 0
"""
_RELEASE_LEASE = """
if redis.call('get', KEYS[1]) == ARGV[1] then
    return redis.call('del', KEYS[1])
end
return 0
"""
# KEYS: key, group set, guard (or the key again for add); ARGV: value, expiry s (0: none),
# group expiry s (0: none), expected guard value ('' for add: set only if the key is absent).
_WRITE_GROUPED = """
if ARGV[4] == '' then
    if redis.call('exists', KEYS[1]) == 1 then return 0 end
elseif redis.call('get', KEYS[3]) ~= ARGV[4] then
    return 0
end
if tonumber(ARGV[2]) > 0 then
    redis.call('set', KEYS[1], ARGV[1], 'EX', ARGV[2])
else
    redis.call('set', KEYS[1], ARGV[1])
end
redis.call('sadd', KEYS[2], ARGV[5])
if tonumber(ARGV[3]) > 0 then redis.call('expire', KEYS[2], ARGV[3]) end
return 1
"""
# KEYS: the group set; ARGV: the namespace prefix of member keys. Atomic: no write lands
# between reading the members and deleting them.
_DELETE_GROUP = """
local removed = 0
for _, member in ipairs(redis.call('smembers', KEYS[1])) do
    removed = removed + redis.call('del', ARGV[1] .. member)
end
redis.call('del', KEYS[1])
return removed
"""


class RedisBackend:
    """Redis shared by several replicas, behind a circuit breaker.

    Every failure raises BackendUnavailable; a connection error or timeout also opens the
    breaker, after which calls fail at once until a probe reaches Redis again. No retries
    inside redis-py: one timeout at most per call, then the breaker decides.
    """

    name = "redis"
    local = False

    def __init__(
        self,
        url: str,
        timeout_s: float,
        namespace: str = "neural-shdf",
        ttl_s: float | None = None,
        retry_s: float = 5.0,
    ) -> None:
        import redis
        from redis.backoff import NoBackoff
        from redis.retry import Retry

        self._redis = redis.Redis.from_url(
            url,
            socket_timeout=timeout_s,
            socket_connect_timeout=timeout_s,
            retry=Retry(NoBackoff(), 0),
        )
        self._down_errors = (redis.ConnectionError, redis.TimeoutError, OSError)
        self._errors = (redis.RedisError, OSError)
        self._ns = namespace
        self._ttl_s = ttl_s
        self._renew = self._redis.register_script(_RENEW_LEASE)
        self._release = self._redis.register_script(_RELEASE_LEASE)
        self._write_grouped = self._redis.register_script(_WRITE_GROUPED)
        self._delete_group = self._redis.register_script(_DELETE_GROUP)
        self.breaker = CircuitBreaker("redis", self._redis.ping, retry_s)
        self.on_error: Callable[[Exception], None] = lambda exc: None

    def _key(self, key: str) -> str:
        return f"{self._ns}:{key}"

    def _call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        if self.breaker.is_open:
            raise BackendUnavailable(self.breaker.describe())
        try:
            return fn(*args, **kwargs)
        except self._errors as exc:
            self.on_error(exc)
            if isinstance(exc, self._down_errors):
                self.breaker.trip(exc)
            else:
                logger.warning("redis error: %s", exc)
            raise BackendUnavailable(str(exc)) from exc

    def get(self, key: str) -> bytes | None:
        return self._call(self._redis.get, self._key(key))

    def exists(self, key: str) -> bool | None:
        return bool(self._call(self._redis.exists, self._key(key)))

    def set(
        self,
        key: str,
        value: bytes,
        *,
        group: str,
        expire: float | None = None,
        keep_local: bool = False,
    ) -> None:
        # SET is atomic: readers see the old value or the whole new one.
        self._call(self.write_now, key, value, group=group, expire=expire)

    def write_now(self, key: str, value: bytes, *, group: str, expire: float | None) -> None:
        """SET past the breaker (raises redis errors): for draining before it closes."""
        expire = expire or self._ttl_s
        seconds = max(1, int(expire)) if expire else None
        pipe = self._redis.pipeline(transaction=True)
        pipe.set(self._key(key), value, ex=seconds)
        pipe.sadd(self._key(f"group:{group}"), key)
        if self._ttl_s:
            pipe.expire(self._key(f"group:{group}"), max(1, int(self._ttl_s)))
        pipe.execute()

    def _write_if(self, key: str, value: bytes, group: str, guard: str, expected: bytes) -> bool:
        seconds = max(1, int(self._ttl_s)) if self._ttl_s else 0
        keys = [self._key(key), self._key(f"group:{group}"), self._key(guard)]
        args = [value, seconds, seconds, expected, key]
        return bool(self._call(self._write_grouped, keys=keys, args=args))

    def add(self, key: str, value: bytes, *, group: str, keep_local: bool = False) -> bool:
        return self._write_if(key, value, group, key, b"")

    def set_if(self, key: str, value: bytes, *, group: str, guard: str, expected: bytes) -> bool:
        return self._write_if(key, value, group, guard, expected)

    def delete(self, key: str) -> None:
        self._call(self._redis.delete, self._key(key))

    def delete_group(self, group: str) -> int:
        keys, args = [self._key(f"group:{group}")], [self._key("")]
        return int(self._call(self._delete_group, keys=keys, args=args))

    def acquire_lease(self, key: str, token: str, ttl_s: float) -> bool:
        lease = self._key(_lease_key(key))
        return bool(self._call(self._redis.set, lease, token, nx=True, px=int(ttl_s * 1000)))

    def renew_lease(self, key: str, token: str, ttl_s: float) -> bool:
        lease = self._key(_lease_key(key))
        return bool(self._call(self._renew, keys=[lease], args=[token, int(ttl_s * 1000)]))

    def release_lease(self, key: str, token: str) -> None:
        self._call(self._release, keys=[self._key(_lease_key(key))], args=[token])

    def lease_holder(self, key: str) -> str | None:
        holder = self._call(self._redis.get, self._key(_lease_key(key)))
        return holder.decode() if holder is not None else None

    def health(self) -> tuple[bool, str]:
        try:
            self._call(self._redis.ping)
        except BackendUnavailable:
            return False, self.breaker.describe()
        return True, "redis"

    def close(self) -> None:
        self.breaker.stop()
        with contextlib.suppress(Exception):
            self._redis.close()


class FallbackBackend:
    """Redis first, the local disk cache whenever Redis is unavailable.

    Through an outage the service keeps working, degraded. Writes go to the disk cache
    that this host's workers share, as ``pending:<key>``; before the breaker closes again
    they are moved to Redis (``drain``), and a Redis miss also looks there meanwhile.
    Entries written with ``keep_local`` (meshes, job records) also keep a copy on disk,
    ``mirror:<key>``, read only while Redis is unavailable: a job or mesh stored before an
    outage stays readable through it. Leases are taken from Redis, else from the disk.
    """

    local = False

    def __init__(self, primary: RedisBackend, fallback: DiskBackend) -> None:
        self.primary = primary
        self.fallback = fallback
        self.name = primary.name
        self._lease_stores: dict[str, Backend] = {}  # lease token -> the store holding it
        self._guard = threading.Lock()
        primary.breaker.before_close = self.drain

    @property
    def degraded(self) -> bool:
        return self.primary.breaker.is_open

    def _local(self, key: str) -> bytes | None:
        """What the disk holds for ``key`` (outage writes first), for an unreachable Redis."""
        value = self.fallback.get(f"pending:{key}")
        return value if value is not None else self.fallback.get(f"mirror:{key}")

    def get(self, key: str) -> bytes | None:
        try:
            value = self.primary.get(key)
            return value if value is not None else self._move(f"pending:{key}", self.primary.set)
        except BackendUnavailable:
            return self._local(key)

    def _move(self, pending: str, write: Callable[..., None]) -> bytes | None:
        """A pending (outage) entry written to Redis with ``write`` and dropped from disk;
        its value, or None if there is none."""
        entry = self.fallback.get_entry(pending)
        if entry is None:
            return None
        value, group, expires_in = entry
        key = pending.removeprefix("pending:")
        if expires_in is None or expires_in > 1:
            write(key, value, group=group or key, expire=expires_in)
        self.fallback.delete(pending)
        return value

    def drain(self) -> None:
        """Move every outage write to Redis, past the (still open) breaker; runs before it
        closes, so nothing newer can be in Redis yet. A Redis error keeps it open."""
        moved = sum(
            self._move(pending, self.primary.write_now) is not None
            for pending in list(self.fallback.keys("pending:"))
        )
        if moved:
            logger.warning("moved %d entries written during the Redis outage to Redis", moved)

    def exists(self, key: str) -> bool | None:
        try:
            if self.primary.exists(key):
                return True
        except BackendUnavailable:
            return True if self._local(key) is not None else None
        return bool(self.fallback.exists(f"pending:{key}"))

    def set(
        self,
        key: str,
        value: bytes,
        *,
        group: str,
        expire: float | None = None,
        keep_local: bool = False,
    ) -> None:
        try:
            self.primary.set(key, value, group=group, expire=expire)
        except BackendUnavailable:
            self.fallback.set(f"pending:{key}", value, group=group, expire=expire)
        if keep_local:  # also after the pending copy has moved to Redis
            self.fallback.set(f"mirror:{key}", value, group=group, expire=expire)

    def add(self, key: str, value: bytes, *, group: str, keep_local: bool = False) -> bool:
        try:
            added = self.primary.add(key, value, group=group)
        except BackendUnavailable:
            added = self._local(key) is None and self.fallback.add(
                f"pending:{key}", value, group=group
            )
        if added and keep_local:
            self.fallback.set(f"mirror:{key}", value, group=group)
        return added

    def set_if(self, key: str, value: bytes, *, group: str, guard: str, expected: bytes) -> bool:
        try:
            return self.primary.set_if(key, value, group=group, guard=guard, expected=expected)
        except BackendUnavailable:
            guards = (f"pending:{guard}", f"mirror:{guard}")
            return self.fallback.set_if(
                f"pending:{key}", value, group=group, guard=guards, expected=expected
            )

    def delete(self, key: str) -> None:
        with contextlib.suppress(BackendUnavailable):
            self.primary.delete(key)
        self.fallback.delete(f"pending:{key}")
        self.fallback.delete(f"mirror:{key}")

    def delete_group(self, group: str) -> int:
        removed = 0
        with contextlib.suppress(BackendUnavailable):
            removed += self.primary.delete_group(group)
        return removed + self.fallback.delete_group(group)

    def acquire_lease(self, key: str, token: str, ttl_s: float) -> bool:
        store: Backend = self.primary
        try:
            acquired = self.primary.acquire_lease(key, token, ttl_s)
        except BackendUnavailable:
            store = self.fallback
            acquired = self.fallback.acquire_lease(key, token, ttl_s)
        if acquired:
            with self._guard:
                self._lease_stores[token] = store
        return acquired

    def renew_lease(self, key: str, token: str, ttl_s: float) -> bool:
        store = self._lease_stores.get(token)
        try:
            return store is not None and store.renew_lease(key, token, ttl_s)
        except BackendUnavailable:
            return False  # the holder then tries to take it again, from the fallback

    def release_lease(self, key: str, token: str) -> None:
        with self._guard:
            store = self._lease_stores.pop(token, None)
        for each in (store,) if store is not None else (self.primary, self.fallback):
            with contextlib.suppress(BackendUnavailable):
                each.release_lease(key, token)

    def lease_holder(self, key: str) -> str | None:
        try:
            holder = self.primary.lease_holder(key)
        except BackendUnavailable:
            holder = None
        return holder or self.fallback.lease_holder(key)

    def health(self) -> tuple[bool, str]:
        ok, detail = self.primary.health()
        if ok:
            return True, detail
        return False, f"{detail}; degraded: serving from the local disk cache"

    def close(self) -> None:
        self.primary.close()
        self.fallback.close()


def _machine() -> str:
    """This host and PID namespace: where process ids in lease tokens are comparable."""
    try:
        namespace = str(os.stat("/proc/self/ns/pid").st_ino)
    except OSError:
        namespace = "?"  # no /proc: holders' liveness is never checked, leases just lapse
    return f"{socket.gethostname()}/{namespace}"


MACHINE = _machine()


def process_is_gone(pid: int) -> bool:
    """Whether no live process has this id here (never started, exited or a zombie)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        return False
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rpartition(")")[2].split()[:1] in (["Z"], ["X"])


class Lease:
    """A lock across threads, processes and replicas that lapses unless its holder renews it.

    While held, a daemon thread renews it every ``ttl_s / 3``; a holder that dies (kill -9,
    out of memory, lost host) stops renewing, so its lease lapses after ``ttl_s`` and the
    next worker goes on. A waiter on the holder's own machine does not wait that long: the
    token names the holder's process, and the lease of a process that is gone is broken at
    once. A holder paused for longer than ``ttl_s`` loses it (``lost``); results are
    deterministic and written atomically, so the cost is only duplicate work.
    """

    def __init__(self, store: Backend, key: str, ttl_s: float) -> None:
        self.store = store
        self.key = key
        self.ttl_s = ttl_s
        self.token = f"{MACHINE}:{os.getpid()}:{uuid.uuid4().hex}"
        self.held = False
        self.lost = False
        self._stop = threading.Event()

    def try_acquire(self) -> bool:
        """Take the lease if it is free or has lapsed; start renewing it."""
        if not self.held and self.store.acquire_lease(self.key, self.token, self.ttl_s):
            self.held, self.lost = True, False
            self._stop = threading.Event()
            threading.Thread(
                target=self._renew_until_released, args=(self._stop,), daemon=True
            ).start()
        return self.held

    def acquire(self, wait_s: float) -> bool:
        """Wait up to ``wait_s`` for the lease; False if a live holder keeps it that long."""
        deadline = time.monotonic() + wait_s
        pause = 0.01
        while not self.try_acquire():
            if self.break_if_holder_died():
                continue
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            time.sleep(min(pause, remaining))
            pause = min(pause * 2, 0.25)
        return True

    def break_if_holder_died(self) -> bool:
        """Free the lease if its holder was a process on this machine that is gone."""
        holder = self.store.lease_holder(self.key)
        if holder is None or holder.count(":") < 2:
            return False
        machine, pid, _ = holder.rsplit(":", 2)
        if machine != MACHINE or machine.endswith("/?") or not pid.isdigit():
            return False
        if not process_is_gone(int(pid)):
            return False
        self.store.release_lease(self.key, holder)  # only if that dead holder still has it
        logger.warning("lease on %s: its holder (process %s) is gone; taking over", self.key, pid)
        return True

    def stop_renewing(self) -> None:
        """Stop the renewals at once (the lease then lapses by itself)."""
        self._stop.set()

    def release(self) -> None:
        if not self.held:
            return
        self.stop_renewing()
        self.held = False
        try:
            self.store.release_lease(self.key, self.token)
        except Exception as exc:  # noqa: BLE001 - it lapses by itself
            logger.warning("could not release the lease on %s: %s", self.key, exc)

    def _renew_until_released(self, stop: threading.Event) -> None:
        while not stop.wait(self.ttl_s / 3):
            why = "taken by another worker after a pause"
            try:
                renewed = self.store.renew_lease(
                    self.key, self.token, self.ttl_s
                ) or self.store.acquire_lease(self.key, self.token, self.ttl_s)
            except Exception as exc:  # noqa: BLE001 - retried at the next beat
                renewed, why = False, f"store unreachable: {exc}"
            if not renewed and not self.lost:
                logger.warning(
                    "lease on %s lost (%s); another worker may compute the same result",
                    self.key,
                    why,
                )
            self.lost = not renewed


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

    def recall_arrays(self, key: str, decode: Callable[[dict[str, NDArray]], T]) -> T | None:
        """This process's memory of ``key``, else its stored arrays through ``decode`` (then
        remembered); None when absent or when ``decode`` rejects them (KeyError, ValueError)."""
        value = self.recall(key)
        if value is not None:
            return value
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
        arrays: dict[str, NDArray],
        *,
        group: str,
        keep_local: bool = False,
        guard: tuple[str, bytes] | None = None,
    ) -> bool:
        """Store arrays; ``keep_local``: also readable from this host while Redis is down
        (for what cannot be recomputed: uploaded meshes, job records). ``guard``: (key,
        stored bytes) that must still be there, checked atomically with the write (a
        result of a mesh deleted meanwhile is never stored); whether it was stored."""
        blob = seal(encode_arrays(arrays))
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
        lease = self.lease(f"lock:{key}")
        if not lease.acquire(wait_s):
            logger.warning("%s still held by a live worker after %g s: going on", key, wait_s)
        try:
            yield lease
        finally:
            lease.release()

    def health(self) -> tuple[bool, str]:
        """(whether the shared store answers, what was checked or why it failed)."""
        return self.backend.health()

    def ping(self) -> bool:
        return self.health()[0]

    def close(self) -> None:
        self.backend.close()
