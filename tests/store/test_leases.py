"""Leases: renewed while their holder lives, broken at once when it was killed here,
lapsing after their TTL when it stopped elsewhere; only the holder's token touches them."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from neural_shdf.store.backends import DiskBackend, RedisBackend
from neural_shdf.store.cache import ResultCache

# A lease holder in its own process, killed with SIGKILL by the tests (a crashed worker).
_HOLDER = """
import sys, time
from pathlib import Path
from neural_shdf.store.backends import DiskBackend, RedisBackend
from neural_shdf.store.cache import ResultCache
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
