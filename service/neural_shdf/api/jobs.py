"""Job records for long ShDF computations, kept in the shared cache so any worker can answer."""

from __future__ import annotations

import time
import uuid
from typing import Any

from neural_shdf.api.cache import ResultCache


class JobAccepted(Exception):  # noqa: N818 - a signal, not a failure
    """Raised by the engine when a computation runs as a job; answered with 202."""

    def __init__(self, job: dict[str, Any]) -> None:
        super().__init__(job["job_id"])
        self.job = job


def job_key(job_id: str) -> str:
    return f"job:{job_id}"


class JobStore:
    """Create, update and read job records (JSON entries that expire after ``ttl_s``)."""

    def __init__(self, cache: ResultCache, ttl_s: float) -> None:
        self.cache = cache
        self.ttl_s = ttl_s

    def create(self, mesh_id: str, method: str, seed: int) -> dict[str, Any]:
        now = time.time()
        job = {
            "job_id": uuid.uuid4().hex,
            "state": "queued",
            "progress": 0.0,
            "mesh_id": mesh_id,
            "method": method,
            "seed": seed,
            "created_at": now,
            "updated_at": now,
            "error": None,
            "result_url": f"/v1/meshes/{mesh_id}/shdf?method={method}&seed={seed}",
        }
        self._save(job)
        return job

    def update(self, job: dict[str, Any], **changes: Any) -> dict[str, Any]:
        job.update(changes, updated_at=time.time())
        self._save(job)
        return job

    def get(self, job_id: str) -> dict[str, Any] | None:
        return self.cache.get_json(job_key(job_id))

    def _save(self, job: dict[str, Any]) -> None:
        self.cache.put_json(job_key(job["job_id"]), job, group=job["mesh_id"], expire=self.ttl_s)
