"""Worker processes that end with the process that started them.

A ``ProcessPoolExecutor`` worker whose parent dies without clean-up (SIGKILL by the OOM
killer, a container stop, a server ended by the signal it stopped on) waits on its call
queue for ever: it holds its own copy of the queue's write end, so it never reads
end-of-file. The service's isolated worker and ``batch``'s local pool are started here,
with an initializer that ends each worker when its parent ends.
"""

from __future__ import annotations

import contextlib
import ctypes
import multiprocessing
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor

#: How often a worker checks that the process that started it still runs (where the
#: kernel cannot tell it, or it missed the moment).
PARENT_POLL_S = 0.5
#: ``<linux/prctl.h>``: the signal the kernel sends a process when its parent ends.
_PR_SET_PDEATHSIG = 1


def spawn_pool(max_workers: int) -> ProcessPoolExecutor:
    """A pool of ``max_workers`` spawned processes (forking a process whose threads hold
    locks can deadlock the child), each ended when this process ends, however it ends."""
    return ProcessPoolExecutor(
        max_workers=max_workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=end_with_parent,
        initargs=(os.getpid(),),  # evaluated here, in the parent; spawn pickles it across
    )


def end_with_parent(parent_pid: int) -> None:
    """A worker's initializer: end the worker when the process ``parent_pid`` ends."""
    if sys.platform.startswith("linux"):
        # The kernel sends SIGKILL at once, even while a call holds the GIL. Strictly it
        # follows the parent's thread that started the worker (the thread that submitted
        # first): one that lives as long as the pool, in the service and in ``batch``.
        with contextlib.suppress(OSError, AttributeError):  # no prctl: the thread below
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    exit_when_orphaned(parent_pid)


def exit_when_orphaned(parent_pid: int) -> None:
    """Exit this process within ``PARENT_POLL_S`` of ``parent_pid`` ending (its parent
    changes), from a daemon thread: portable, and it covers the parent that ended before
    the kernel was told to watch it."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    if os.getppid() != parent_pid:
        os._exit(1)
    threading.Thread(target=watch, name="parent-watch", daemon=True).start()
