"""A circuit breaker: stop calling a dependency that fails, probe it in the background."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

logger = logging.getLogger(__name__)


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
