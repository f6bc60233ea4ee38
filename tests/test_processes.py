"""Worker processes that end with the process that started them (real processes)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import psutil

REPOSITORY = Path(__file__).resolve().parents[1]
#: Starts a ``spawn_pool`` worker, prints its pid, then keeps it busy for a minute.
POOL_USER = """
import os, time
from neural_shdf.processes import spawn_pool
pool = spawn_pool(1)
print(pool.submit(os.getpid).result(), flush=True)
pool.submit(time.sleep, 60).result()
"""


def gone_within(process: psutil.Process, seconds: float) -> bool:
    """Whether ``process`` ends (or is a zombie: this container's init reaps no orphans)
    within ``seconds``; killed if not, so that a failing test leaves nothing behind."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            if not process.is_running() or process.status() == psutil.STATUS_ZOMBIE:
                return True
        except psutil.NoSuchProcess:
            return True
        time.sleep(0.05)
    process.kill()
    return False


def test_a_pool_worker_ends_with_its_killed_parent():
    env = dict(os.environ, PYTHONPATH=str(REPOSITORY / "service"))
    parent = subprocess.Popen([sys.executable, "-c", POOL_USER], stdout=subprocess.PIPE, env=env)
    assert parent.stdout is not None
    try:
        worker = psutil.Process(int(parent.stdout.readline()))
        assert worker.ppid() == parent.pid
        parent.kill()  # SIGKILL: no clean-up in the parent
        parent.wait(10)
        assert gone_within(worker, 5.0)
    finally:
        if parent.poll() is None:
            parent.kill()
            parent.wait()
        parent.stdout.close()
