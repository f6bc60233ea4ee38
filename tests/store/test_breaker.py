"""The circuit breaker: open at the first failure, closed again by a probe that succeeds."""

from __future__ import annotations

import threading

from neural_shdf.store.breaker import CircuitBreaker


def test_a_tripped_breaker_stays_open_until_a_probe_and_before_close_succeed():
    reachable, drained, changes = threading.Event(), threading.Event(), []
    closed = threading.Event()

    def probe() -> None:
        if not reachable.is_set():
            raise ConnectionError("still down")

    def before_close() -> None:
        if not drained.is_set():
            drained.set()  # the first attempt fails: the breaker stays open once more
            raise RuntimeError("drain failed")

    breaker = CircuitBreaker("store", probe, retry_s=0.01)
    breaker.before_close = before_close
    breaker.on_change = lambda is_open: (changes.append(is_open), is_open or closed.set())
    assert not breaker.is_open and breaker.describe() == "store reachable"
    breaker.trip(ConnectionError("refused"))
    breaker.trip(ConnectionError("refused again"))  # already open: one probe thread
    assert breaker.is_open and "store unreachable" in breaker.describe()
    reachable.set()
    assert closed.wait(30)
    assert not breaker.is_open and drained.is_set()
    assert changes == [True, False]
    breaker.stop()
