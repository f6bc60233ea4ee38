"""The cache: checksummed framing, disk LRU cap, leases, Redis faults, two replicas."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from fastapi.testclient import TestClient
from hypothesis import given, settings
from hypothesis import strategies as st

from neural_shdf.api.cache import (
    CorruptEntryError,
    DiskBackend,
    FallbackBackend,
    RedisBackend,
    ResultCache,
    decode_arrays,
    encode_arrays,
    seal,
    unseal,
)
from tests.api.api_helpers import TEST_METHOD, metric


@given(st.binary(max_size=512))
@settings(max_examples=50, deadline=None)
def test_seal_round_trip_and_any_change_is_detected(payload):
    blob = seal(payload)
    assert unseal(blob) == payload
    for index in {0, len(blob) // 2, len(blob) - 1}:
        damaged = bytearray(blob)
        damaged[index] ^= 0x01
        with pytest.raises(CorruptEntryError):
            unseal(bytes(damaged))
    with pytest.raises(CorruptEntryError):
        unseal(blob[:-1] if payload else blob[:10])


def test_arrays_round_trip_without_pickles():
    arrays = {"a": np.arange(5.0), "b": np.array(3), "c": np.zeros((2, 3), np.int32)}
    decoded = decode_arrays(encode_arrays(arrays))
    for name, value in arrays.items():
        np.testing.assert_array_equal(decoded[name], value)
        assert decoded[name].dtype == value.dtype
    with pytest.raises(CorruptEntryError):
        decode_arrays(b"PK\x03\x04 not really a zip")


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


def test_working_sets_stay_within_their_bytes_least_recently_used_first(tmp_path):
    cache = ResultCache(DiskBackend(tmp_path / "c", 1024**2), working_set_bytes=100)
    for key in ("m1:a", "m1:b", "m2:a"):
        cache.keep_working_set(key, key.upper(), 40)
    assert cache.working_set("m1:a") is None  # 120 bytes: the oldest went
    assert cache.working_set("m1:b") == "M1:B"  # now the most recently used
    cache.keep_working_set("m3:a", "M3:A", 40)
    assert cache.working_set("m2:a") is None and cache.working_set("m1:b") == "M1:B"
    cache.keep_working_set("m4:a", "too big", 101)
    assert cache.working_set("m4:a") is None
    cache.forget_group("m1")  # a deleted mesh's working sets go with it
    assert cache.working_set("m1:b") is None and cache.working_set("m3:a") == "M3:A"
    none_kept = ResultCache(DiskBackend(tmp_path / "d", 1024**2), working_set_bytes=0)
    none_kept.keep_working_set("m1:a", "value", 1)
    assert none_kept.working_set("m1:a") is None


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


def test_replica_b_segments_what_replica_a_uploaded(app_factory, redis_url, capsule_obj, tmp_path):
    """Two app instances (replicas) share only the Redis URL; B never recomputes the ShDF."""
    replica_a = app_factory(redis_url=redis_url, cache_dir=tmp_path / "a")
    replica_b = app_factory(redis_url=redis_url, cache_dir=tmp_path / "b")
    with TestClient(replica_a) as a, TestClient(replica_b) as b:
        assert b.get("/readyz").json()["checks"]["cache"] == {"ok": True, "detail": "redis"}
        mesh_id = a.post("/v1/meshes", files={"file": ("m.obj", capsule_obj)}).json()["mesh"][
            "mesh_id"
        ]
        assert b.get(f"/v1/meshes/{mesh_id}").status_code == 200
        from_b = b.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 3})
        assert from_b.status_code == 200, from_b.text
        assert from_b.json()["timings"]["shdf_cached"] is True
        name = "neural_shdf_shdf_computations_total"
        assert metric(replica_a, name, method=TEST_METHOD) == 1
        assert metric(replica_b, name, method=TEST_METHOD) == 0
        # B's segmentation is cached for A as well; a deletion through A reaches B.
        from_a = a.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 3}).json()
        assert from_a["labels"] == from_b.json()["labels"]
        assert from_a["timings"]["segmentation_cached"] is True
        assert a.delete(f"/v1/meshes/{mesh_id}").status_code == 204
        # B's memory still holds the mesh and the segmentation: it must not serve them.
        assert b.get(f"/v1/meshes/{mesh_id}").status_code == 404
        gone = b.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 3})
        assert gone.status_code == 404
        other = b.post("/v1/segment", json={"mesh_id": mesh_id, "clusters": 2})
        assert other.status_code == 404


# A lease holder in its own process, killed with SIGKILL by the tests (a crashed worker).
_HOLDER = """
import sys, time
from pathlib import Path
from neural_shdf.api.cache import DiskBackend, RedisBackend, ResultCache
store, ttl = sys.argv[1], float(sys.argv[2])
if store.startswith("redis://"):
    backend = RedisBackend(store, 2.0)
else:
    backend = DiskBackend(Path(store), 10 * 1024**2)
lease = ResultCache(backend, lease_s=ttl).lease("lock:m:shdf")
assert lease.try_acquire()
print("held", flush=True)
time.sleep(600)
"""


def _store(kind: str, tmp_path, redis_url: str | None) -> tuple[str, ResultCache]:
    if kind == "disk":
        return str(tmp_path / "c"), ResultCache(DiskBackend(tmp_path / "c", 10 * 1024**2))
    return redis_url, ResultCache(RedisBackend(redis_url, 2.0))


@pytest.mark.parametrize("kind", ["disk", "redis"])
def test_a_killed_holders_lease_is_broken_at_once(kind, tmp_path, request):
    """The holder renews while alive (others wait through several TTLs); once it is killed
    with SIGKILL, a waiter on the same machine sees its process is gone and takes over."""
    redis_url = request.getfixturevalue("redis_url") if kind == "redis" else None
    where, cache = _store(kind, tmp_path, redis_url)
    ttl = 1.0
    cache.lease_s = 60.0  # the waiter's own lease: irrelevant here
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, where, str(ttl)],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    try:
        assert holder.stdout.readline().strip() == "held"
        waiter = cache.lease("lock:m:shdf")
        assert not waiter.acquire(wait_s=3 * ttl)  # renewed by the live holder
        assert not waiter.break_if_holder_died()
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=10)
        assert not waiter.try_acquire()  # its lease is still there, for up to a TTL
        assert waiter.break_if_holder_died() and waiter.try_acquire()
        waiter.release()
        again = cache.lease("lock:m:shdf")
        assert again.try_acquire()  # released: free at once
        again.release()
    finally:
        holder.kill()
        holder.wait(timeout=10)


@pytest.mark.parametrize("kind", ["disk", "redis"])
def test_a_remote_holders_lease_lapses_after_its_ttl(kind, tmp_path, request):
    """A holder on another machine that stopped renewing (its liveness cannot be checked
    from here): its lease lapses after one TTL, not after the old 600 s lock expiry."""
    redis_url = request.getfixturevalue("redis_url") if kind == "redis" else None
    _, cache = _store(kind, tmp_path, redis_url)
    ttl = 1.0
    assert cache.backend.acquire_lease("lock:m:shdf", "other-host/1:4242:0123abcd", ttl)
    waiter = cache.lease("lock:m:shdf")
    start = time.monotonic()
    assert not waiter.try_acquire() and not waiter.break_if_holder_died()
    assert waiter.acquire(wait_s=30)
    assert ttl - 0.2 <= time.monotonic() - start <= ttl + 1.5
    waiter.release()


def test_lease_tokens_guard_renewal_and_release(tmp_path):
    cache = ResultCache(DiskBackend(tmp_path / "c", 10 * 1024**2), lease_s=0.3)
    first, second = cache.lease("k"), cache.lease("k")
    assert first.try_acquire() and not second.try_acquire()
    cache.backend.release_lease("k", second.token)  # not the holder's token: no effect
    assert not second.try_acquire()
    time.sleep(1.0)  # three TTLs: the renewals keep it
    assert not second.try_acquire() and not first.lost
    first.release()
    assert second.try_acquire()
    second.stop_renewing()  # the holder stops beating: lapses after one TTL
    time.sleep(0.5)
    assert first.try_acquire()
    first.release()


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
