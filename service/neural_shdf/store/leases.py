"""Leases: locks across threads, processes and replicas that lapse unless renewed."""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import uuid
from pathlib import Path

from neural_shdf.store.backends import Backend

logger = logging.getLogger(__name__)


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
