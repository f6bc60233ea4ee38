"""Job records for long ShDF computations, kept in the shared cache so any worker can answer.

The worker running a job holds the lease ``job:<id>`` (renewed while it works) and
rewrites the record at least every third of a lease. A record still ``queued`` or
``running`` whose runner process is gone (seen at once on the same machine, else after
its lease lapsed) is re-run by whoever then takes its lease (``JobStore.orphaned``), up
to ``max_attempts`` runs.
"""

from __future__ import annotations

import os
import socket
import time
import uuid
from typing import Any

from neural_shdf.store.cache import ResultCache
from neural_shdf.store.keys import job_key
from neural_shdf.store.leases import Lease

#: Fields of a job record that the API shows (the rest is bookkeeping between workers).
PUBLIC_FIELDS = (
    "job_id",
    "state",
    "progress",
    "mesh_id",
    "kind",
    "method",
    "seed",
    "attempt",
    "created_at",
    "updated_at",
    "error",
    "result_url",
)
UNFINISHED = ("queued", "running")


class JobAccepted(Exception):  # noqa: N818 - a signal, not a failure
    """Raised by the engine when a computation runs as a job; answered with 202."""

    def __init__(self, job: dict[str, Any]) -> None:
        super().__init__(job["job_id"])
        self.job = job
        #: Headers the 202 answer carries besides ``Location`` (set by the route).
        self.headers: dict[str, str] = {}


def public_job(job: dict[str, Any]) -> dict[str, Any]:
    """The record as the API shows it."""
    defaults = {"attempt": 1, "kind": "shdf"}
    return {name: job.get(name, defaults.get(name)) for name in PUBLIC_FIELDS}


def worker_name() -> str:
    """This process, as named in job records (host:pid)."""
    return f"{socket.gethostname()}:{os.getpid()}"


class JobStore:
    """Create, update and read job records (JSON entries that expire after ``ttl_s``)."""

    def __init__(self, cache: ResultCache, ttl_s: float, max_attempts: int = 3) -> None:
        self.cache = cache
        self.ttl_s = ttl_s
        self.max_attempts = max_attempts

    @property
    def heartbeat_s(self) -> float:
        """Longest a running job's record goes unwritten."""
        return self.cache.lease_s / 3

    def create(
        self,
        mesh_id: str,
        method: str,
        seed: int,
        *,
        kind: str = "shdf",
        result_url: str | None = None,
    ) -> dict[str, Any]:
        """A queued job: ``kind`` ``shdf`` (re-run when its worker dies) or another
        computation (failed, with a message to repeat the request, when its worker dies)."""
        now = time.time()
        job = {
            "job_id": uuid.uuid4().hex,
            "state": "queued",
            "progress": 0.0,
            "mesh_id": mesh_id,
            "method": method,
            "seed": seed,
            "attempt": 1,
            "worker": worker_name(),
            "created_at": now,
            "updated_at": now,
            "error": None,
            "result_url": result_url or f"/v1/meshes/{mesh_id}/shdf?method={method}&seed={seed}",
            "kind": kind,
        }
        self._save(job)
        return job

    def update(self, job: dict[str, Any], **changes: Any) -> dict[str, Any]:
        job.update(changes, updated_at=time.time())
        self._save(job)
        return job

    def get(self, job_id: str) -> dict[str, Any] | None:
        return self.cache.get_json(job_key(job_id))

    def runner_lease(self, job_id: str) -> Lease:
        """The lease its runner holds while the job is queued or running."""
        return self.cache.lease(job_key(job_id))

    def orphaned(self, job: dict[str, Any]) -> Lease | None:
        """For an unfinished job whose runner is gone: its lease, taken (the caller then
        re-runs or fails the job); else None. Gone: a runner process on this machine that
        no longer exists, or a record not written for a whole lease whose lease lapsed."""
        if job.get("state") not in UNFINISHED:
            return None
        lease = self.runner_lease(job["job_id"])
        stale = time.time() - float(job.get("updated_at", 0.0)) >= self.cache.lease_s
        if not stale and not lease.break_if_holder_died():
            return None
        if not lease.try_acquire():
            return None  # its runner (or another adopter) is alive
        current = self.get(job["job_id"])
        if current is None or current.get("state") not in UNFINISHED:
            lease.release()  # finished meanwhile
            return None
        job.clear()
        job.update(current)
        return lease

    def _save(self, job: dict[str, Any]) -> None:
        key = job_key(job["job_id"])
        self.cache.put_json(key, job, group=job["mesh_id"], expire=self.ttl_s, keep_local=True)
