"""The ShDF of stored meshes: computed once per (mesh, method, model, seed), cached,
and run as a pollable job when the mesh is large."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf import pipeline
from neural_shdf.api.errors import ApiError, error_dict, not_found
from neural_shdf.api.jobs import JobAccepted, JobStore, public_job, worker_name
from neural_shdf.api.mesh_store import MeshStore
from neural_shdf.api.metrics import Metrics
from neural_shdf.api.settings import Settings
from neural_shdf.api.tasks import TaskRunner, cancellation, checkpoint
from neural_shdf.errors import ModelUnavailableError
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment.params import check_seed
from neural_shdf.shdf.neural.inference import load_model
from neural_shdf.shdf.neural.inference import model_path as library_model_path
from neural_shdf.shdf.stage import resolve_method, uses_model
from neural_shdf.store.cache import ResultCache
from neural_shdf.store.codec import shdf_arrays, shdf_from_arrays
from neural_shdf.store.keys import model_version, shdf_key, shdf_version
from neural_shdf.store.leases import Lease

logger = logging.getLogger(__name__)


def model_path(settings: Settings) -> Path:
    """The neural model file: the setting, else the library's choice (env or packaged)."""
    return settings.model.expanduser().resolve() if settings.model else library_model_path()


@dataclass(frozen=True)
class ShdfOutcome:
    """A per-triangle ShDF and how it was obtained."""

    values: NDArray[np.float64]
    cached: bool
    seconds: float
    method: str  # the producer that made it (``auto`` resolved)


class ShdfService:
    """Per-triangle ShDF of stored meshes over the shared cache, deduplicated."""

    def __init__(
        self,
        settings: Settings,
        cache: ResultCache,
        metrics: Metrics,
        tasks: TaskRunner,
        meshes: MeshStore,
        jobs: JobStore,
    ) -> None:
        self.settings = settings
        self.cache = cache
        self.metrics = metrics
        self.tasks = tasks
        self.meshes = meshes
        self.jobs = jobs
        self.model_path = model_path(settings)
        self.model_version = model_version(self.model_path)
        self._progress: dict[str, float] = {}

    def _require_model(self, method: str) -> None:
        """A ModelUnavailableError naming the missing file, for methods that run the network."""
        if uses_model(method) and not self.model_version:
            raise ModelUnavailableError(
                f"the ShDF method {method!r} needs the neural model, but {self.model_path} "
                "does not exist; set NEURAL_SHDF_MODEL to an exported model (model_export) "
                "or ask for method 'exact'"
            )

    def version(self, method: str, seed: int) -> str:
        """What a cached ShDF depends on besides the mesh (``shdf_version``)."""
        self._require_model(method)
        return shdf_version(method, self.model_version, seed)

    def resolve(self, method: str | None, triangles: int) -> str:
        """The producer ``method`` (or the service default) runs on a mesh of
        ``triangles`` triangles (``auto`` resolved)."""
        return resolve_method(method or self.settings.default_method, triangles)

    def key(self, mesh_id: str, method: str, seed: int) -> str:
        """The cache key of a ShDF (``shdf_key``)."""
        self._require_model(method)
        return shdf_key(mesh_id, method, seed, self.model_version)

    def cached(self, key: str) -> NDArray[np.float64] | None:
        """The cached ShDF (memory, then the shared cache), or None."""
        values = self.cache.recall_arrays(key, shdf_from_arrays)
        self.metrics.count_cache("shdf", hit=values is not None)
        return values

    def _store(
        self, key: str, mesh_id: str, outcome: ShdfOutcome, guard: tuple[str, bytes] | None
    ) -> None:
        self.meshes.store_result(key, mesh_id, shdf_arrays(outcome.values), guard)
        self.cache.remember(key, outcome.values)

    def _compute(
        self, key: str, mesh_id: str, mesh: TriangleMesh, method: str, seed: int
    ) -> ShdfOutcome:
        """Compute the ShDF now (a compute thread), reporting progress under ``key``."""
        self.meshes.graph(mesh_id, mesh)  # built once per mesh, under the mesh's lock
        self._progress[key] = 0.0
        cancelled = cancellation()  # progress may be reported from the library's threads

        def progress(fraction: float) -> None:
            checkpoint(cancelled)  # every report is a checkpoint: stop if no one waits
            self._progress[key] = float(fraction)

        start = time.perf_counter()
        try:
            values = pipeline.compute_shdf(
                mesh,
                method=method,  # type: ignore[arg-type]
                seed=seed,
                progress=progress,
                model=self.model_path,
            ).values
        finally:
            self._progress.pop(key, None)
        seconds = time.perf_counter() - start
        self.metrics.shdf_computations.labels(method).inc()
        self.metrics.shdf_seconds.labels(method).observe(seconds)
        return ShdfOutcome(np.ascontiguousarray(values, dtype=np.float64), False, seconds, method)

    def progress_reporter(self, key: str) -> Callable[[float], None]:
        """A callable recording the progress of the job computing under ``key`` (its
        record shows it at the next heartbeat)."""

        def report(fraction: float) -> None:
            self._progress[key] = float(fraction)

        return report

    def compute_once(
        self, key: str, mesh_id: str, mesh: TriangleMesh, method: str, seed: int
    ) -> ShdfOutcome:
        """Blocking (a compute thread): the cached ShDF, else computed and stored
        (``method`` resolved; ``key`` its ``key``)."""
        return self._compute_once(key, mesh_id, mesh, method, seed)

    def _compute_once(
        self,
        key: str,
        mesh_id: str,
        mesh: TriangleMesh,
        method: str,
        seed: int,
    ) -> ShdfOutcome:
        """Blocking: the cached ShDF, else computed and stored under the cache lock, only
        while the mesh is not deleted (``MeshStore.store_result``)."""

        def lookup() -> ShdfOutcome | None:
            values = self.cached(key)
            return None if values is None else ShdfOutcome(values, True, 0.0, method)

        outcome, _ = self.tasks.compute_once(
            key,
            lookup,
            functools.partial(self._compute, key, mesh_id, mesh, method, seed),
            functools.partial(self._store, key, mesh_id),
            functools.partial(self.meshes.guard, mesh_id),
        )
        return outcome

    async def get(
        self,
        mesh_id: str,
        mesh: TriangleMesh,
        method: str,
        seed: int,
        *,
        allow_job: bool = True,
    ) -> ShdfOutcome:
        """The cached ShDF, else computed once; large meshes raise JobAccepted (202).
        ``method`` may be ``auto`` (resolved for this mesh; the outcome says which ran)."""
        seed = check_seed(seed)
        method = self.resolve(method, mesh.face_count)
        key = self.key(mesh_id, method, seed)
        values = await self.tasks.io(self.cached, key)
        if values is not None:
            return ShdfOutcome(values, True, 0.0, method)
        if allow_job and mesh.face_count > self.settings.sync_face_threshold:
            raise JobAccepted(await self.start_job(key, mesh_id, mesh, method, seed))
        compute = functools.partial(self._compute_once, key, mesh_id, mesh, method, seed)
        return await self.tasks.with_timeout(self.tasks.single_flight(key, compute))

    async def start_job(
        self, key: str, mesh_id: str, mesh: TriangleMesh, method: str, seed: int
    ) -> dict[str, Any]:
        """Record a job and compute the ShDF in the background; the job's record."""
        job = await self.tasks.io(self.jobs.create, mesh_id, method, seed)
        lease = self.jobs.runner_lease(job["job_id"])
        await self.tasks.io(lease.try_acquire)  # a fresh id: free
        self._launch_job(job, key, mesh_id, mesh, method, seed, lease)
        return dict(job)

    async def start_computation_job(
        self,
        key: str,
        mesh_id: str,
        method: str,
        seed: int,
        compute: Callable[[], Any],
        *,
        kind: str,
        result_url: str,
        on_success: Callable[[Any], dict[str, Any]] | None = None,
    ) -> dict[str, Any]:
        """Record a job of another ``kind`` (e.g. an unwrap) running ``compute`` in the
        background under the same leases and heartbeats as ShDF jobs; the job's record.
        ``on_success``: further record changes made from the result (a ``result_url``
        known only then)."""
        job = await self.tasks.io(
            self.jobs.create, mesh_id, method, seed, kind=kind, result_url=result_url
        )
        lease = self.jobs.runner_lease(job["job_id"])
        await self.tasks.io(lease.try_acquire)  # a fresh id: free
        self.tasks.spawn(self._run_job(job, key, compute, lease, on_success))
        return dict(job)

    def _launch_job(
        self,
        job: dict[str, Any],
        key: str,
        mesh_id: str,
        mesh: TriangleMesh,
        method: str,
        seed: int,
        lease: Lease,
    ) -> None:
        compute = functools.partial(self._compute_once, key, mesh_id, mesh, method, seed)
        self.tasks.spawn(self._run_job(job, key, compute, lease))

    async def _run_job(
        self,
        job: dict[str, Any],
        key: str,
        compute: Callable[[], Any],
        lease: Lease,
        on_success: Callable[[Any], dict[str, Any]] | None = None,
    ) -> None:
        """Run a job, rewriting its record with the progress and at least every heartbeat
        (a record left unwritten for a lease marks a dead runner)."""
        self.metrics.jobs_running.inc()
        try:
            await self.tasks.io(self.jobs.update, job, state="running")
            work = asyncio.ensure_future(self.tasks.single_flight(key, compute, keep=True))
            written = time.monotonic()
            while not work.done():
                await asyncio.wait({work}, timeout=0.5)
                progress = self._progress.get(key)
                moved = progress is not None and progress != job["progress"]
                due = time.monotonic() - written >= self.jobs.heartbeat_s
                if not work.done() and (moved or due):
                    changes = {"progress": min(progress, 0.99)} if moved else {}
                    await self.tasks.io(self.jobs.update, job, **changes)
                    written = time.monotonic()
            result = work.result()
            changes = {} if on_success is None else on_success(result)
            await self.tasks.io(self.jobs.update, job, state="succeeded", progress=1.0, **changes)
        except Exception as exc:  # noqa: BLE001 - a failed job is recorded, not raised
            if not isinstance(exc, ApiError | ValueError | RuntimeError):
                logger.exception("job %s failed", job["job_id"])
            await self.tasks.io(self.jobs.update, job, state="failed", error=error_dict(exc))
        finally:
            self.metrics.jobs_running.dec()
            lease.stop_renewing()
            with contextlib.suppress(RuntimeError):  # executor shut down: it lapses instead
                self.tasks.io_executor.submit(lease.release)

    async def job(self, job_id: str) -> dict[str, Any]:
        """A job's record; one whose worker died is re-run here (or failed after
        ``job_max_attempts`` runs), so no job stays ``running`` for ever."""
        job = await self.tasks.io(self.jobs.get, job_id)
        if job is None:
            raise not_found("job", job_id)
        lease = await self.tasks.io(self.jobs.orphaned, job)
        if lease is not None:
            await self._rerun(job, lease)
        return public_job(job)

    async def _rerun(self, job: dict[str, Any], lease: Lease) -> None:
        """Re-run an orphaned job (holding its lease) on this worker."""
        attempt = int(job.get("attempt", 1)) + 1
        logger.warning(
            "job %s: its worker %s stopped; run %d", job["job_id"], job.get("worker"), attempt
        )
        if job.get("kind", "shdf") != "shdf":
            error = {
                "code": "worker_lost",
                "message": f"the worker computing this {job['kind']} stopped (crash, out of "
                "memory or restart); repeat the request to start it again",
                "detail": None,
            }
            await self.tasks.io(self.jobs.update, job, state="failed", error=error)
            await self.tasks.io(lease.release)
            return
        if attempt > self.jobs.max_attempts:
            error = {
                "code": "worker_lost",
                "message": f"the worker computing this job stopped {attempt - 1} times "
                "(crash, out of memory or restart); the mesh may be too large for this "
                "service: try a smaller mesh or the neural method",
                "detail": None,
            }
            await self.tasks.io(self.jobs.update, job, state="failed", error=error)
            await self.tasks.io(lease.release)
            return
        self.metrics.jobs_rerun.inc()
        try:
            mesh = await self.tasks.io(self.meshes.load, job["mesh_id"])
        except ApiError as exc:
            await self.tasks.io(self.jobs.update, job, state="failed", error=error_dict(exc))
            await self.tasks.io(lease.release)
            return
        method, seed = job["method"], int(job["seed"])
        await self.tasks.io(
            self.jobs.update, job, state="queued", attempt=attempt, worker=worker_name()
        )
        key = self.key(job["mesh_id"], method, seed)
        self._launch_job(job, key, job["mesh_id"], mesh, method, seed, lease)

    def check_model(self) -> tuple[bool, str]:
        """Whether the neural model loads (cached by the library after the first call)."""
        try:
            load_model(self.model_path)
        except Exception as exc:  # noqa: BLE001 - reported by /readyz
            return False, str(exc)
        return True, self.model_path.name
