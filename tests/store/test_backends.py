"""The byte stores: the disk's LRU cap and persistence, Redis, and Redis faults with the
disk standing in behind the circuit breaker."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from neural_shdf.store.backends import DiskBackend, FallbackBackend, RedisBackend
from neural_shdf.store.cache import ResultCache


def test_disk_cache_is_capped_with_lru_eviction(tmp_path):
    backend = DiskBackend(tmp_path / "c", size_limit=1024**2)
    cache = ResultCache(backend, memory_items=0)
    chunk = np.zeros(40_000, dtype=np.uint8)  # ~40 kB per entry, 100 entries
    cache.put_arrays("k0:x", {"v": chunk}, group="k0")
    for i in range(1, 100):
        cache.get_arrays("k0:x")  # keep the first entry recently used
        cache.put_arrays(f"k{i}:x", {"v": chunk}, group=f"k{i}")
    backend._cache.cull()
    assert backend._cache.volume() <= 1.5 * 1024**2
    assert cache.get_arrays("k0:x") is not None
    assert cache.get_arrays("k1:x") is None


def test_entries_survive_a_restart(tmp_path):
    first = ResultCache(DiskBackend(tmp_path / "c", 10 * 1024**2))
    first.put_json("m:meta", {"a": 1}, group="m")
    first.close()
    second = ResultCache(DiskBackend(tmp_path / "c", 10 * 1024**2))
    assert second.get_json("m:meta") == {"a": 1}
    assert second.delete_group("m") == 1 and second.get_json("m:meta") is None


def test_redis_backend_round_trip_lock_and_groups(redis_url):
    cache = ResultCache(RedisBackend(redis_url, 2.0, ttl_s=100), memory_items=0)
    assert cache.ping()
    cache.put_arrays("m1:shdf", {"shdf": np.linspace(0, 1, 7)}, group="m1")
    cache.put_json("m1:meta", {"faces": 7}, group="m1")
    np.testing.assert_array_equal(cache.get_arrays("m1:shdf")["shdf"], np.linspace(0, 1, 7))
    assert 0 < cache.backend._redis.ttl("neural-shdf:m1:meta") <= 100  # entries expire
    with cache.lock("m1:shdf", wait_s=5) as lease:
        assert lease.held and cache.backend._redis.exists("neural-shdf:lease:lock:m1:shdf")
    assert not cache.backend._redis.exists("neural-shdf:lease:lock:m1:shdf")
    cache.backend.set("m1:bad", b"corrupt", group="m1")
    assert cache.get_json("m1:bad") is None and cache.backend.get("m1:bad") is None
    assert cache.delete_group("m1") == 2
    assert cache.get_json("m1:meta") is None


def _freeze_with_debug_sleep(redis_server, seconds: float) -> threading.Thread:
    """Block redis-server for ``seconds`` with DEBUG SLEEP (another client's command)."""
    import redis

    client = redis.Redis.from_url(redis_server.url, socket_timeout=seconds + 10)
    thread = threading.Thread(target=client.execute_command, args=("DEBUG", "SLEEP", seconds))
    thread.start()
    time.sleep(0.1)
    return thread


@pytest.mark.parametrize("fault", ["sigstop", "debug-sleep", "stopped"])
def test_redis_fault_opens_the_breaker_and_the_disk_stands_in(fault, redis_server, tmp_path):
    """One timeout at most, then no waiting on Redis; writes meanwhile go to disk and move
    to Redis before the breaker closes; entries kept local stay readable throughout."""
    timeout, retry = 0.5, 0.3
    redis = RedisBackend(redis_server.url, timeout, retry_s=retry)
    backend = FallbackBackend(redis, DiskBackend(tmp_path / "disk", 10 * 1024**2))
    cache = ResultCache(backend, memory_items=0)
    cache.put_json("m:before", {"a": 1}, group="m")
    cache.put_json("m:kept", {"k": 1}, group="m", keep_local=True)
    assert redis.get("m:before") is not None and backend.fallback.get("m:before") is None

    sleeper = None
    if fault == "sigstop":
        redis_server.freeze()
    elif fault == "debug-sleep":
        sleeper = _freeze_with_debug_sleep(redis_server, 4)
    else:
        redis_server.stop()
    start = time.monotonic()
    assert cache.get_json("m:before") is None  # only Redis holds it: a miss, not a stall
    assert time.monotonic() - start < timeout + 1.0
    assert backend.degraded
    start = time.monotonic()
    assert cache.get_json("m:kept") == {"k": 1}  # its local copy
    cache.put_json("m:during", {"b": 2}, group="m")
    cache.put_json("m:during-kept", {"c": 3}, group="m", keep_local=True)
    assert cache.get_json("m:during") == {"b": 2}
    lease = cache.lease("lock:m:x")
    assert lease.try_acquire()  # from the disk cache
    lease.release()
    assert time.monotonic() - start < 0.5  # the breaker is open: no timeouts
    ok, detail = cache.health()
    assert not ok and "redis unreachable" in detail and "local disk cache" in detail

    if fault == "sigstop":
        redis_server.thaw()
    elif fault == "debug-sleep":
        sleeper.join()
    else:
        redis_server.start()
    deadline = time.monotonic() + 10
    while backend.degraded and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not backend.degraded and cache.health() == (True, "redis")
    # Drained before the breaker closed: in Redis already, not on disk any more.
    assert redis.get("m:during") is not None
    assert backend.fallback.get("pending:m:during") is None
    assert cache.get_json("m:during") == {"b": 2}
    # Kept local even when written during the outage: readable through the next one.
    assert backend.fallback.get("mirror:m:during-kept") is not None
    if fault != "stopped":  # a restarted Redis without persistence lost what it held
        assert cache.get_json("m:before") == {"a": 1}
    # A local copy is never served while Redis answers (a deletion elsewhere must hold).
    redis.delete("m:kept")
    assert cache.get_json("m:kept") is None
    assert cache.delete_group("m") >= 1 and cache.get_json("m:during") is None
