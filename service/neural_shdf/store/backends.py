"""Byte stores behind the result cache: local disk (diskcache), Redis for several replicas,
and Redis with the disk as its fallback.

Keys are grouped per mesh id so a mesh and everything derived from it can be deleted
together. Locks are leases (``leases.Lease``) that the backends store. Redis sits behind
a circuit breaker with the disk cache as fallback (``FallbackBackend``): an outage
degrades the service, never stalls it.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Protocol, TypeVar, cast

import diskcache
import redis
from redis.backoff import NoBackoff
from redis.retry import Retry

from neural_shdf.store.breaker import CircuitBreaker
from neural_shdf.store.keys import lease_key

logger = logging.getLogger(__name__)
T = TypeVar("T")


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


class DiskBackend:
    """diskcache on local disk: SQLite-indexed, size-capped, LRU, safe across processes."""

    name = "disk"
    local = True  # SQLite in WAL mode: reads do not wait for writers

    def __init__(self, directory: Path, size_limit: int) -> None:
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
        return bool(self._cache.add(lease_key(key), token, expire=ttl_s, retry=True))

    def renew_lease(self, key: str, token: str, ttl_s: float) -> bool:
        lease = lease_key(key)
        with self._cache.transact(retry=True):
            if self._cache.get(lease, default=None) != token:
                return False
            self._cache.set(lease, token, expire=ttl_s)
        return True

    def release_lease(self, key: str, token: str) -> None:
        lease = lease_key(key)
        with self._cache.transact(retry=True):
            if self._cache.get(lease, default=None) == token:
                self._cache.delete(lease)

    def lease_holder(self, key: str) -> str | None:
        holder = self._cache.get(lease_key(key), default=None, retry=True)
        return holder if isinstance(holder, str) else None

    def health(self) -> tuple[bool, str]:
        try:
            self._cache.get("__ping__", retry=True)
        except Exception as exc:  # noqa: BLE001 - reported by /readyz
            return False, f"disk unreadable: {exc}"
        return True, "disk"

    def close(self) -> None:
        self._cache.close()


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
        # bytes: the client is made without decode_responses
        return cast("bytes | None", self._call(self._redis.get, self._key(key)))

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
        lease = self._key(lease_key(key))
        return bool(self._call(self._redis.set, lease, token, nx=True, px=int(ttl_s * 1000)))

    def renew_lease(self, key: str, token: str, ttl_s: float) -> bool:
        lease = self._key(lease_key(key))
        return bool(self._call(self._renew, keys=[lease], args=[token, int(ttl_s * 1000)]))

    def release_lease(self, key: str, token: str) -> None:
        self._call(self._release, keys=[self._key(lease_key(key))], args=[token])

    def lease_holder(self, key: str) -> str | None:
        holder = cast("bytes | None", self._call(self._redis.get, self._key(lease_key(key))))
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
