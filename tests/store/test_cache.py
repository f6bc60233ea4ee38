"""The result cache: in-memory LRUs, compute-once under a lease, and how it is opened."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from neural_shdf.store.backends import DiskBackend, FallbackBackend
from neural_shdf.store.cache import CacheConfig, ResultCache, open_cache


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


def test_compute_once_computes_a_key_once_across_callers(tmp_path):
    """A second caller waits for the first one's lease, then finds its stored result."""
    cache = ResultCache(DiskBackend(tmp_path / "c", 10 * 1024**2), memory_items=0)
    calls, results = [], []
    computing, finish = threading.Event(), threading.Event()

    def compute() -> dict[str, np.ndarray]:
        calls.append(1)
        computing.set()
        finish.wait(30)
        return {"v": np.arange(3)}

    def call() -> None:
        results.append(
            cache.compute_once(
                "m:x",
                lambda: cache.get_arrays("m:x"),
                compute,
                lambda value, _: cache.put_arrays("m:x", value, group="m"),
                wait_s=60,
            )
        )

    first = threading.Thread(target=call)
    first.start()
    assert computing.wait(30)
    second = threading.Thread(target=call)
    second.start()
    finish.set()
    first.join(30)
    second.join(30)
    assert len(calls) == 1
    assert sorted(cached for _, cached in results) == [False, True]
    for value, _ in results:
        np.testing.assert_array_equal(value["v"], np.arange(3))


def test_compute_once_checks_before_computing(tmp_path):
    """``before_compute`` and ``guard`` run under the lock before the work; either may
    refuse it (no one waits any more, the mesh was deleted)."""
    cache = ResultCache(DiskBackend(tmp_path / "c", 10 * 1024**2))
    computed = []

    def refuse() -> None:
        raise LookupError("no one waits")

    for hooks in ({"before_compute": refuse}, {"guard": refuse}):
        with pytest.raises(LookupError):
            cache.compute_once(
                "m:x", lambda: None, lambda: computed.append(1), lambda *_: None, wait_s=5, **hooks
            )
    assert computed == []
    stored = []
    value, cached = cache.compute_once(
        "m:x", lambda: None, lambda: 7, lambda *args: stored.append(args), wait_s=5,
        guard=lambda: "guard",
    )  # fmt: skip
    assert (value, cached, stored) == (7, False, [(7, "guard")])
    assert cache.backend.lease_holder("lock:m:x") is None  # released


def test_compute_once_can_store_after_returning_holding_the_lock(tmp_path):
    """``store_later``: the result comes back before it is stored; the lock is held until
    it is, so a caller waiting for it finds the stored result (no second computation); a
    failing store is logged, the lock still released."""
    cache = ResultCache(DiskBackend(tmp_path / "c", 10 * 1024**2), memory_items=0)
    pending: list = []
    computed = []

    def compute() -> dict[str, np.ndarray]:
        computed.append(1)
        return {"v": np.arange(3)}

    def store(value, _) -> None:
        cache.put_arrays("m:x", value, group="m")

    value, cached = cache.compute_once(
        "m:x", lambda: cache.get_arrays("m:x"), compute, store, wait_s=30,
        store_later=pending.append,
    )  # fmt: skip
    assert not cached and cache.get_arrays("m:x") is None  # returned, not stored yet
    assert cache.backend.lease_holder("lock:m:x") is not None  # the store holds the lock
    second: list = []
    waiter = threading.Thread(
        target=lambda: second.append(
            cache.compute_once("m:x", lambda: cache.get_arrays("m:x"), compute, store, wait_s=30)
        )
    )
    waiter.start()
    time.sleep(0.2)
    assert not second  # waits for the lock
    pending.pop()()
    waiter.join(30)
    assert computed == [1] and second[0][1] is True
    np.testing.assert_array_equal(second[0][0]["v"], value["v"])
    assert cache.backend.lease_holder("lock:m:x") is None

    def failing(*_) -> None:
        raise OSError("disk full")

    cache.compute_once(
        "m:y", lambda: None, lambda: 1, failing, wait_s=5, store_later=pending.append
    )
    pending.pop()()  # logged, not raised
    assert cache.backend.lease_holder("lock:m:y") is None

    def refused(_) -> None:
        raise RuntimeError("cannot schedule new futures after shutdown")

    stored = []
    cache.compute_once(
        "m:z", lambda: None, lambda: 2, lambda *args: stored.append(args), wait_s=5,
        store_later=refused,
    )  # fmt: skip
    assert stored == [(2, None)] and cache.backend.lease_holder("lock:m:z") is None


def test_config_from_the_environment_then_overrides(tmp_path):
    environ = {
        "NEURAL_SHDF_CACHE_DIR": str(tmp_path / "env"),
        "NEURAL_SHDF_CACHE_SIZE_BYTES": "4000000",
        "NEURAL_SHDF_REDIS_TTL_S": "2.5",
        "NEURAL_SHDF_LOCK_TIMEOUT_S": "30",
        "NEURAL_SHDF_UNRELATED": "x",
    }
    config = CacheConfig.from_environment(environ, memory_cache_items=0)
    assert config.cache_dir == Path(tmp_path / "env")
    assert (config.cache_size_bytes, config.redis_ttl_s, config.lock_timeout_s) == (
        4_000_000,
        2.5,
        30.0,
    )
    assert config.memory_cache_items == 0 and config.redis_url is None
    assert CacheConfig.from_environment({}) == CacheConfig()


def test_open_cache_is_the_disk_alone_or_redis_with_the_disk_behind_it(tmp_path):
    config = CacheConfig(cache_dir=tmp_path / "c", memory_cache_items=0, lock_lease_s=2.0)
    disk = open_cache(config)
    assert isinstance(disk.backend, DiskBackend) and disk.lease_s == 2.0
    disk.put_json("m:meta", {"a": 1}, group="m")
    assert disk.get_json("m:meta") == {"a": 1} and disk.recall("m:meta") is None
    disk.close()
    # Nothing listens there: the client connects lazily, so opening it does not wait.
    shared = open_cache(CacheConfig(cache_dir=tmp_path / "d", redis_url="redis://127.0.0.1:1/0"))
    assert isinstance(shared.backend, FallbackBackend)
    shared.close()
