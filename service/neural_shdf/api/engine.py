"""What the routes call: meshes in, ShDF and segmentations out, each computed once.

Deduplication works at two levels: concurrent requests for the same key in one
process share one in-flight future; several workers/replicas serialise on the
cache's lock and re-check the cache under it, so only the first computes.
CPU-heavy steps run on a dedicated thread pool, never on the event loop.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import functools
import hashlib
import inspect
import json
import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from neural_shdf import __version__
from neural_shdf.api.cache import Lease, ResultCache
from neural_shdf.api.errors import ApiError, error_dict, not_found
from neural_shdf.api.jobs import JobAccepted, JobStore, public_job, worker_name
from neural_shdf.api.metrics import Metrics
from neural_shdf.api.schemas import SegmentOptions
from neural_shdf.api.settings import Settings
from neural_shdf.errors import InvalidGeometryError
from neural_shdf.geometry import FaceGraph
from neural_shdf.mesh import TriangleMesh

logger = logging.getLogger(__name__)
T = TypeVar("T")


def model_path(settings: Settings) -> Path:
    """The neural model file: the setting, else the library's choice (env or packaged)."""
    from neural_shdf.neural.inference import model_path as library_model_path

    return settings.model.expanduser().resolve() if settings.model else library_model_path()


def model_version(path: Path) -> str | None:
    """Short hash of the model card (which holds the weights' checksum and feature version);
    of the weights when there is no card; None when the model is absent."""
    card = path.with_suffix(".json")
    if card.is_file():
        return hashlib.sha256(card.read_bytes()).hexdigest()[:16]
    if path.is_file():
        from neural_shdf.neural.inference import file_sha256

        return file_sha256(path)[:16]
    return None


def _accepts_model_path() -> bool:
    from neural_shdf.pipeline import compute_shdf

    return "model_path" in inspect.signature(compute_shdf).parameters


@dataclass(frozen=True)
class ShdfOutcome:
    """A per-triangle ShDF and how it was obtained."""

    values: NDArray[np.float64]
    cached: bool
    seconds: float


@dataclass
class SegmentResult:
    """A segmentation, stored in the cache as arrays."""

    labels: NDArray[np.int32]  # per input face
    triangle_labels: NDArray[np.int32]  # per triangle
    part_faces: NDArray[np.int64]
    part_area: NDArray[np.float64]
    part_mean_shdf: NDArray[np.float64]
    segment_seconds: float

    @functools.cached_property
    def labels_json(self) -> str:
        """The labels as a JSON array, serialised once per result (the hot path's main cost)."""
        return json.dumps(self.labels.tolist(), separators=(",", ":"))

    @functools.cached_property
    def labels_base64(self) -> tuple[str, str]:
        """(base64 of the labels as the narrowest little-endian integers, their dtype name)."""
        top = int(self.labels.max()) if len(self.labels) else 0
        dtype = "int8" if top < 2**7 else "int16" if top < 2**15 else "int32"
        packed = self.labels.astype(np.dtype(dtype).newbyteorder("<")).tobytes()
        return base64.b64encode(packed).decode(), dtype

    def arrays(self) -> dict[str, NDArray]:
        data = asdict(self)
        data["segment_seconds"] = np.array(self.segment_seconds)
        return data

    @classmethod
    def from_arrays(cls, arrays: dict[str, NDArray]) -> SegmentResult:
        return cls(
            labels=arrays["labels"],
            triangle_labels=arrays["triangle_labels"],
            part_faces=arrays["part_faces"],
            part_area=arrays["part_area"],
            part_mean_shdf=arrays["part_mean_shdf"],
            segment_seconds=float(arrays["segment_seconds"]),
        )


def mesh_arrays(mesh: TriangleMesh) -> dict[str, NDArray]:
    return {
        "vertices": mesh.vertices,
        "faces": mesh.faces,
        "face_origin": mesh.face_origin,
        "input_face_count": np.array(mesh.input_face_count),
    }


def mesh_from_arrays(arrays: dict[str, NDArray]) -> TriangleMesh:
    return TriangleMesh(
        arrays["vertices"],
        arrays["faces"],
        arrays["face_origin"],
        int(arrays["input_face_count"]),
    )


def summarize(
    mesh: TriangleMesh, triangle_labels: NDArray, shdf: NDArray, seconds: float
) -> SegmentResult:
    """Input-face labels and per-part faces, area and area-weighted mean ShDF."""
    labels = mesh.labels_to_input_faces(triangle_labels)
    _, area = mesh.normals_and_areas
    part_count = int(triangle_labels.max()) + 1 if len(triangle_labels) else 0
    tri = np.asarray(triangle_labels, dtype=np.int64)
    part_area = np.bincount(tri, weights=area, minlength=part_count)
    weighted = np.bincount(tri, weights=area * shdf, minlength=part_count)
    mean = np.divide(weighted, part_area, out=np.zeros(part_count), where=part_area > 0)
    assigned = labels[labels >= 0]
    part_faces = np.bincount(assigned, minlength=part_count)
    return SegmentResult(
        labels=labels.astype(np.int32),
        triangle_labels=tri.astype(np.int32),
        part_faces=part_faces.astype(np.int64),
        part_area=part_area,
        part_mean_shdf=mean,
        segment_seconds=seconds,
    )


def shdf_version(method: str, model_version: str | None) -> str:
    """What a cached ShDF depends on besides the mesh: the model and how it is applied."""
    if method == "neural":
        from neural_shdf.neural.inference import DEFAULT_SAMPLE_SETS

        return f"neural-{model_version or 'none'}-sets{DEFAULT_SAMPLE_SETS}"
    return f"exact-{__version__}"


def shdf_key(mesh_id: str, method: str, seed: int, model_version: str | None) -> str:
    """Cache key of a mesh's ShDF (shared by every service replica and batch worker)."""
    return f"{mesh_id}:shdf:{shdf_version(method, model_version)}:{seed}"


def params_digest(options: SegmentOptions) -> str:
    """Stable hash of the segmentation parameters (the cache key's parameter part)."""
    params = asdict(options.segment_params())
    return hashlib.sha256(json.dumps(params, sort_keys=True).encode()).hexdigest()[:20]


class Engine:
    """Meshes, ShDF and segmentations over the shared cache, deduplicated."""

    def __init__(self, settings: Settings, cache: ResultCache, metrics: Metrics) -> None:
        self.settings = settings
        self.cache = cache
        self.metrics = metrics
        self.jobs = JobStore(cache, settings.job_ttl_s, settings.job_max_attempts)
        self.executor = ThreadPoolExecutor(settings.compute_threads, thread_name_prefix="compute")
        self.io_executor = ThreadPoolExecutor(settings.io_threads, thread_name_prefix="io")
        self.model_path = model_path(settings)
        self.model_version = model_version(self.model_path)
        self._inflight: dict[str, asyncio.Future[Any]] = {}
        self._progress: dict[str, float] = {}
        self._background: set[asyncio.Task[Any]] = set()
        self._graph_locks = [threading.Lock() for _ in range(64)]  # striped by mesh id

    # -- plumbing --------------------------------------------------------------
    async def run(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a CPU-heavy ``fn`` on the compute thread pool."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self.executor, functools.partial(fn, *args, **kwargs))

    async def io(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a short blocking step (cache I/O, bookkeeping) on the I/O thread pool, so it
        never waits behind long computations."""
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self.io_executor, functools.partial(fn, *args, **kwargs))

    async def single_flight(self, key: str, fn: Callable[[], T]) -> T:
        """Run ``fn`` once per key at a time in this process; concurrent callers share it."""
        future = self._inflight.get(key)
        if future is None:
            loop = asyncio.get_running_loop()
            future = loop.run_in_executor(self.executor, fn)
            self._inflight[key] = future

            def _done(done: asyncio.Future[Any], key: str = key) -> None:
                if self._inflight.get(key) is done:
                    del self._inflight[key]
                if not done.cancelled():
                    done.exception()  # mark retrieved; callers get it through await

            future.add_done_callback(_done)
        return await asyncio.shield(future)

    async def with_timeout(self, awaitable: Any) -> Any:
        try:
            return await asyncio.wait_for(awaitable, self.settings.request_timeout_s)
        except TimeoutError:
            raise ApiError(
                504,
                "timeout",
                f"the computation did not finish within {self.settings.request_timeout_s:g} s; "
                "it goes on in the background, retry the request later",
            ) from None

    def method_of(self, method: str | None) -> str:
        return method or self.settings.default_method

    def shdf_version(self, method: str) -> str:
        return shdf_version(method, self.model_version)

    def shdf_key(self, mesh_id: str, method: str, seed: int) -> str:
        return shdf_key(mesh_id, method, seed, self.model_version)

    def segment_key(self, mesh_id: str, method: str, options: SegmentOptions) -> str:
        shdf = f"{self.shdf_version(method)}:{options.shdf_seed}"
        return f"{mesh_id}:seg:{__version__}:{shdf}:{params_digest(options)}"

    def _hit(self, kind: str, hit: bool) -> None:
        (self.metrics.cache_hits if hit else self.metrics.cache_misses).labels(kind).inc()

    # -- meshes ----------------------------------------------------------------
    def parse(self, data: bytes, file_type: str | None) -> TriangleMesh:
        from neural_shdf.mesh_io import load_mesh

        mesh = load_mesh(
            data,
            file_type,
            max_faces=self.settings.max_faces,
            max_vertices=self.settings.max_vertices,
        )
        if mesh.face_count == 0:
            raise InvalidGeometryError("the mesh has no triangles")
        return mesh

    def store_mesh(
        self, mesh: TriangleMesh, file_type: str | None, filename: str | None
    ) -> dict[str, Any]:
        """Store the mesh (if new) and return its metadata."""
        mesh_id = mesh.content_hash()
        meta_key = f"{mesh_id}:meta"
        meta = self.cache.get_json(meta_key)
        stored = self.cache.recall(f"{mesh_id}:mesh") is not None
        if meta is None or not (stored or self.cache.get_arrays(f"{mesh_id}:mesh") is not None):
            _, area = mesh.normals_and_areas
            meta = {
                "mesh_id": mesh_id,
                "faces": mesh.input_face_count,
                "triangles": mesh.face_count,
                "vertices": len(mesh.vertices),
                "format": file_type,
                "filename": filename,
                "bounds": [mesh.vertices.min(0).tolist(), mesh.vertices.max(0).tolist()],
                "surface_area": float(area.sum()),
            }
            self.cache.put_arrays(f"{mesh_id}:mesh", mesh_arrays(mesh), group=mesh_id)
            self.cache.put_json(meta_key, meta, group=mesh_id)
        self.cache.remember(f"{mesh_id}:mesh", mesh)
        return meta

    def mesh_meta(self, mesh_id: str) -> dict[str, Any]:
        """Metadata of a mesh that can be used: one whose geometry is gone is gone."""
        meta = self.cache.get_json(f"{mesh_id}:meta")
        if meta is None or self._geometry_lost(mesh_id):
            raise self._mesh_missing(mesh_id)
        return meta

    def _geometry_lost(self, mesh_id: str) -> bool:
        """Whether the mesh's geometry entry is known to be gone (evicted, or dropped as
        corrupt); then its metadata and results are deleted too, so that every route
        answers 404 alike. An unreachable cache cannot tell: not lost."""
        key = f"{mesh_id}:mesh"
        if self.cache.recall(key) is not None or self.cache.backend.exists(key) is not False:
            return False
        logger.warning(
            "mesh %s lost its geometry entry; dropping what was derived from it", mesh_id
        )
        self.cache.delete_group(mesh_id)
        return True

    def still_stored(self, mesh_id: str) -> bool:
        """Whether the shared cache still holds the mesh: a deletion through another
        worker or replica must not be hidden by this process's memory. An unreachable
        cache cannot tell: then memory is trusted (degraded mode)."""
        if self.cache.backend.exists(f"{mesh_id}:meta") is not False:
            return True
        self.cache.forget_group(mesh_id)
        return False

    def load(self, mesh_id: str) -> TriangleMesh:
        """The stored mesh (memory first, then the shared cache)."""
        key = f"{mesh_id}:mesh"
        mesh = self.cache.recall(key)
        if mesh is not None and self.still_stored(mesh_id):
            self._hit("mesh", True)
            return mesh
        arrays = self.cache.get_arrays(key)
        self._hit("mesh", arrays is not None)
        if arrays is None:
            self._geometry_lost(mesh_id)
            raise self._mesh_missing(mesh_id)
        mesh = mesh_from_arrays(arrays)
        self.cache.remember(key, mesh)
        return mesh

    @staticmethod
    def _mesh_missing(mesh_id: str) -> ApiError:
        error = not_found("mesh", mesh_id)
        error.message += (
            " (never uploaded, deleted, evicted from the cache or its stored copy was "
            "damaged: upload it again)"
        )
        return error

    def delete(self, mesh_id: str) -> bool:
        existed = self.cache.get_json(f"{mesh_id}:meta") is not None
        removed = self.cache.delete_group(mesh_id)
        return existed or removed > 0

    def graph(self, mesh_id: str, mesh: TriangleMesh) -> FaceGraph:
        """Face graph of a mesh, built once per process (memory LRU)."""
        from neural_shdf.pipeline import mesh_face_graph

        key = f"{mesh_id}:graph"
        with self._graph_locks[hash(key) % len(self._graph_locks)]:
            graph = self.cache.recall(key)
            if graph is None:
                graph = mesh_face_graph(mesh)
                self.cache.remember(key, graph)
        return graph

    # -- ShDF --------------------------------------------------------------------
    def cached_shdf(self, key: str) -> NDArray[np.float64] | None:
        values = self.cache.recall(key)
        if values is None:
            arrays = self.cache.get_arrays(key)
            if arrays is not None and "shdf" in arrays:
                values = arrays["shdf"]
                self.cache.remember(key, values)
        self._hit("shdf", values is not None)
        return values

    def _compute_shdf(
        self, key: str, mesh_id: str, mesh: TriangleMesh, method: str, seed: int
    ) -> ShdfOutcome:
        """Under the cache lock: re-check the cache, else compute and store (thread)."""
        from neural_shdf.pipeline import compute_shdf

        with self.cache.lock(key, self.settings.lock_timeout_s):
            values = self.cached_shdf(key)
            if values is not None:
                return ShdfOutcome(values, True, 0.0)
            graph = self.graph(mesh_id, mesh)
            self._progress[key] = 0.0

            def progress(fraction: float) -> None:
                self._progress[key] = float(fraction)

            extra = {}
            if method == "neural" and _accepts_model_path():
                extra["model_path"] = self.model_path
            start = time.perf_counter()
            try:
                values = compute_shdf(
                    mesh,
                    method=method,  # type: ignore[arg-type]
                    seed=seed,
                    graph=graph,
                    progress=progress,
                    **extra,
                )
            finally:
                self._progress.pop(key, None)
            seconds = time.perf_counter() - start
            self.metrics.shdf_computations.labels(method).inc()
            self.metrics.shdf_seconds.labels(method).observe(seconds)
            values = np.ascontiguousarray(values, dtype=np.float64)
            self.cache.put_arrays(key, {"shdf": values}, group=mesh_id)
            self.cache.remember(key, values)
            return ShdfOutcome(values, False, seconds)

    def shdf_blocking(
        self, mesh_id: str, mesh: TriangleMesh, method: str, seed: int
    ) -> ShdfOutcome:
        """The cached ShDF, else computed once under the cache lock and stored (blocking:
        for batch workers outside an event loop)."""
        key = self.shdf_key(mesh_id, method, seed)
        values = self.cached_shdf(key)
        if values is not None:
            return ShdfOutcome(values, True, 0.0)
        return self._compute_shdf(key, mesh_id, mesh, method, seed)

    async def shdf(
        self,
        mesh_id: str,
        mesh: TriangleMesh,
        method: str,
        seed: int,
        *,
        allow_job: bool = True,
    ) -> ShdfOutcome:
        """The cached ShDF, else computed once; large meshes raise JobAccepted (202)."""
        key = self.shdf_key(mesh_id, method, seed)
        values = await self.io(self.cached_shdf, key)
        if values is not None:
            return ShdfOutcome(values, True, 0.0)
        if allow_job and mesh.face_count > self.settings.sync_face_threshold:
            raise JobAccepted(await self.start_job(key, mesh_id, mesh, method, seed))
        compute = functools.partial(self._compute_shdf, key, mesh_id, mesh, method, seed)
        return await self.with_timeout(self.single_flight(key, compute))

    async def start_job(
        self, key: str, mesh_id: str, mesh: TriangleMesh, method: str, seed: int
    ) -> dict[str, Any]:
        job = await self.io(self.jobs.create, mesh_id, method, seed)
        lease = self.jobs.runner_lease(job["job_id"])
        await self.io(lease.try_acquire)  # a fresh id: free
        self._launch_job(job, key, mesh_id, mesh, method, seed, lease)
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
        compute = functools.partial(self._compute_shdf, key, mesh_id, mesh, method, seed)
        task = asyncio.create_task(self._run_job(job, key, compute, lease))
        self._background.add(task)
        task.add_done_callback(self._background.discard)

    async def _run_job(
        self, job: dict[str, Any], key: str, compute: Callable[[], ShdfOutcome], lease: Lease
    ) -> None:
        """Run a job, rewriting its record with the progress and at least every heartbeat
        (a record left unwritten for a lease marks a dead runner)."""
        self.metrics.jobs_running.inc()
        try:
            await self.io(self.jobs.update, job, state="running")
            work = asyncio.ensure_future(self.single_flight(key, compute))
            written = time.monotonic()
            while not work.done():
                await asyncio.wait({work}, timeout=0.5)
                progress = self._progress.get(key)
                moved = progress is not None and progress != job["progress"]
                due = time.monotonic() - written >= self.jobs.heartbeat_s
                if not work.done() and (moved or due):
                    changes = {"progress": min(progress, 0.99)} if moved else {}
                    await self.io(self.jobs.update, job, **changes)
                    written = time.monotonic()
            work.result()
            await self.io(self.jobs.update, job, state="succeeded", progress=1.0)
        except Exception as exc:  # noqa: BLE001 - a failed job is recorded, not raised
            if not isinstance(exc, ApiError | ValueError | RuntimeError):
                logger.exception("job %s failed", job["job_id"])
            await self.io(self.jobs.update, job, state="failed", error=error_dict(exc))
        finally:
            self.metrics.jobs_running.dec()
            lease.stop_renewing()
            with contextlib.suppress(RuntimeError):  # executor shut down: it lapses instead
                self.io_executor.submit(lease.release)

    async def job(self, job_id: str) -> dict[str, Any]:
        """A job's record; one whose worker died is re-run here (or failed after
        ``job_max_attempts`` runs), so no job stays ``running`` for ever."""
        job = await self.io(self.jobs.get, job_id)
        if job is None:
            raise not_found("job", job_id)
        lease = await self.io(self.jobs.orphaned, job)
        if lease is not None:
            await self._rerun(job, lease)
        return public_job(job)

    async def _rerun(self, job: dict[str, Any], lease: Lease) -> None:
        """Re-run an orphaned job (holding its lease) on this worker."""
        attempt = int(job.get("attempt", 1)) + 1
        logger.warning(
            "job %s: its worker %s stopped; run %d", job["job_id"], job.get("worker"), attempt
        )
        if attempt > self.jobs.max_attempts:
            error = {
                "code": "worker_lost",
                "message": f"the worker computing this job stopped {attempt - 1} times "
                "(crash, out of memory or restart); the mesh may be too large for this "
                "service: try a smaller mesh or the neural method",
                "detail": None,
            }
            await self.io(self.jobs.update, job, state="failed", error=error)
            await self.io(lease.release)
            return
        self.metrics.jobs_rerun.inc()
        try:
            mesh = await self.io(self.load, job["mesh_id"])
        except ApiError as exc:
            await self.io(self.jobs.update, job, state="failed", error=error_dict(exc))
            await self.io(lease.release)
            return
        method, seed = job["method"], int(job["seed"])
        await self.io(self.jobs.update, job, state="queued", attempt=attempt, worker=worker_name())
        key = self.shdf_key(job["mesh_id"], method, seed)
        self._launch_job(job, key, job["mesh_id"], mesh, method, seed, lease)

    # -- segmentation ----------------------------------------------------------
    def cached_segmentation(self, key: str) -> SegmentResult | None:
        result = self.cache.recall(key)
        if result is None:
            arrays = self.cache.get_arrays(key)
            if arrays is not None:
                try:
                    result = SegmentResult.from_arrays(arrays)
                except (KeyError, ValueError):
                    result = None
                if result is not None:
                    self.cache.remember(key, result)
        self._hit("segmentation", result is not None)
        return result

    def _segment(
        self, key: str, mesh_id: str, mesh: TriangleMesh, shdf: NDArray, options: SegmentOptions
    ) -> SegmentResult:
        from neural_shdf.pipeline import segment_mesh

        with self.cache.lock(key, self.settings.lock_timeout_s):
            result = self.cached_segmentation(key)
            if result is not None:
                return result
            graph = self.graph(mesh_id, mesh)
            start = time.perf_counter()
            triangle_labels = segment_mesh(mesh, shdf, options.segment_params(), graph=graph)
            seconds = time.perf_counter() - start
            self.metrics.segmentations.inc()
            self.metrics.segment_seconds.observe(seconds)
            result = summarize(mesh, np.asarray(triangle_labels), shdf, seconds)
            self.cache.put_arrays(key, result.arrays(), group=mesh_id)
            self.cache.remember(key, result)
            return result

    async def segmentation(
        self, mesh_id: str, options: SegmentOptions, *, need_mesh: bool = False
    ) -> tuple[SegmentResult, dict[str, Any]]:
        """Segment a stored mesh (cached result, else from the cached ShDF)."""
        start = time.perf_counter()
        method = self.method_of(options.method)
        key = self.segment_key(mesh_id, method, options)
        result = self.cache.recall(key)
        if result is not None and not (
            self.still_stored(mesh_id)
            if self.cache.backend.local
            else await self.io(self.still_stored, mesh_id)
        ):
            raise self._mesh_missing(mesh_id)
        if result is None:
            result = await self.io(self.cached_segmentation, key)
        else:
            self._hit("segmentation", True)
        shdf_cached, shdf_seconds, segmentation_cached = True, 0.0, result is not None
        if result is None:
            mesh = await self.io(self.load, mesh_id)
            outcome = await self.shdf(mesh_id, mesh, method, options.shdf_seed)
            shdf_cached, shdf_seconds = outcome.cached, outcome.seconds
            compute = functools.partial(self._segment, key, mesh_id, mesh, outcome.values, options)
            result = await self.with_timeout(self.single_flight(key, compute))
        timings = {
            "shdf_ms": round(shdf_seconds * 1000, 3),
            "segment_ms": 0.0 if segmentation_cached else round(result.segment_seconds * 1000, 3),
            "total_ms": round((time.perf_counter() - start) * 1000, 3),
            "shdf_cached": shdf_cached,
            "segmentation_cached": segmentation_cached,
        }
        return result, timings

    def segmentation_body(
        self,
        mesh_id: str,
        method: str,
        options: SegmentOptions,
        result: SegmentResult,
        timings: dict[str, Any],
    ) -> bytes:
        """The JSON response, serialised directly (no per-label model validation)."""
        compact = options.labels_format == "base64"
        from neural_shdf.export import part_color_hex

        colors = part_color_hex(len(result.part_faces))
        parts = [
            {"label": i, "faces": int(f), "area": float(a), "mean_shdf": float(m), "color": c}
            for i, (f, a, m, c) in enumerate(
                zip(
                    result.part_faces,
                    result.part_area,
                    result.part_mean_shdf,
                    colors,
                    strict=True,
                )
            )
        ]
        body = {
            "mesh_id": mesh_id,
            "method": method,
            "faces": len(result.labels),
            "part_count": len(parts),
            "labels_base64": result.labels_base64[0] if compact else None,
            "labels_dtype": result.labels_base64[1] if compact else None,
            "parts": parts,
            "timings": timings,
        }
        labels = "null" if compact else result.labels_json
        rest = json.dumps(body, separators=(",", ":"))
        return f'{{"labels":{labels},{rest[1:]}'.encode()

    async def export_glb(self, mesh_id: str, options: SegmentOptions, style: str) -> bytes:
        from neural_shdf.export import colored_glb, parts_glb

        result, _ = await self.segmentation(mesh_id, options)
        mesh = await self.io(self.load, mesh_id)
        writer = colored_glb if style == "colored" else parts_glb
        return await self.run(writer, mesh, result.triangle_labels.astype(np.int64))

    # -- lifecycle ---------------------------------------------------------------
    def check_model(self) -> tuple[bool, str]:
        """Whether the neural model loads (cached by the library after the first call)."""
        from neural_shdf.neural.inference import load_model

        try:
            load_model(self.model_path)
        except Exception as exc:  # noqa: BLE001 - reported by /readyz
            return False, str(exc)
        return True, self.model_path.name

    async def close(self) -> None:
        for task in list(self._background):
            task.cancel()
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.io_executor.shutdown(wait=False, cancel_futures=True)
