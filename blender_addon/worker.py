"""A request to the service run on a worker thread while Blender stays responsive: the state
an operator polls (progress, status, error, cancelled, seconds) and its start and end.

No bpy here: the worker thread must not touch Blender's data, and this module can be
imported (and tested) outside Blender.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import ClassVar

from . import service


@dataclass(kw_only=True)
class WorkerTask:
    """One task's state; a subclass does its requests in ``work`` (on the worker thread),
    reporting through ``progress`` and ``status``. Errors end up in ``error`` as text for
    the user, a cancel in ``cancelled``; ``done`` once the thread has ended."""

    #: The thread's name (a subclass names its own).
    thread_name: ClassVar[str] = "neural-shdf"

    server_url: str
    cancel: threading.Event = field(default_factory=threading.Event)
    error: str | None = None
    cancelled: bool = False
    progress: float = 0.0
    status: str = "starting"
    seconds: float = 0.0
    thread: threading.Thread | None = None

    def start(self) -> None:
        self.thread = threading.Thread(target=self._run, name=self.thread_name, daemon=True)
        self.thread.start()

    @property
    def done(self) -> bool:
        return self.thread is not None and not self.thread.is_alive()

    def wait(self, poll_s: float = 0.05) -> None:
        """Block until the worker has ended (scripts and background mode)."""
        assert self.thread is not None, "start() the task first"
        while self.thread.is_alive():
            self.thread.join(poll_s)

    def work(self, session: service.Session) -> None:
        """The task's requests (worker thread); its results go into the task's fields."""
        raise NotImplementedError

    def _run(self) -> None:
        started = time.perf_counter()
        try:
            self.work(service.Session(self.server_url, cancel=self.cancel))
        except service.Cancelled:
            self.cancelled = True
        except service.ServiceError as error:
            self.error = error.message
        except Exception as error:  # noqa: BLE001 - shown to the user, never a traceback
            self.error = f"unexpected {type(error).__name__}: {error}"
        self.seconds = time.perf_counter() - started
