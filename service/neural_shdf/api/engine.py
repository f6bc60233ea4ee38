"""What the routes call: the service's parts wired together over one cache.

- ``tasks`` (``api/tasks.py``): thread pools, single flight, timeouts, compute-once;
- ``meshes`` (``api/mesh_store.py``): parse, store, load and delete meshes;
- ``shdf`` (``api/shdf_service.py``): the ShDF, cached, and jobs for large meshes;
- ``segmentations`` (``api/segmentation.py``): segmentations from the cached ShDF;
- ``unwraps`` (``api/unwrapping.py``): UV atlases by part from the cached segmentation;
- ``labelers`` (``api/labeler_store.py``): stored part labellers;
- ``labelings`` (``api/labeling.py``): named parts from the cached ShDF, training jobs.

Response bodies are built in ``api/responses.py``; routes stay thin.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from neural_shdf.api.jobs import JobStore
from neural_shdf.api.labeler_store import LabelerStore
from neural_shdf.api.labeling import LabelingService
from neural_shdf.api.mesh_store import MeshStore
from neural_shdf.api.metrics import Metrics
from neural_shdf.api.segmentation import SegmentationService
from neural_shdf.api.settings import Settings
from neural_shdf.api.shdf_service import ShdfService
from neural_shdf.api.tasks import TaskRunner
from neural_shdf.api.unwrapping import UnwrapService
from neural_shdf.store.cache import ResultCache
from neural_shdf.store.keys import mesh_key

T = TypeVar("T")


class Engine:
    """Meshes, ShDF and segmentations over the shared cache (``neural_shdf.store``),
    each computed once."""

    def __init__(self, settings: Settings, cache: ResultCache, metrics: Metrics) -> None:
        self.settings = settings
        self.cache = cache
        self.metrics = metrics
        self.tasks = TaskRunner(settings, cache)
        self.tasks.on_cancelled = metrics.computations_cancelled.inc
        self.jobs = JobStore(cache, settings.job_ttl_s, settings.job_max_attempts)
        self.meshes = MeshStore(settings, cache, metrics)
        self.shdf = ShdfService(settings, cache, metrics, self.tasks, self.meshes, self.jobs)
        self.segmentations = SegmentationService(cache, metrics, self.tasks, self.meshes, self.shdf)
        self.unwraps = UnwrapService(cache, metrics, self.tasks, self.meshes, self.segmentations)
        self.labelers = LabelerStore(settings, cache, metrics)
        self.labelings = LabelingService(
            settings, cache, metrics, self.tasks, self.meshes, self.shdf, self.labelers
        )

    async def run(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a CPU-heavy ``fn`` on the compute thread pool."""
        return await self.tasks.run(fn, *args, **kwargs)

    async def io(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run a short blocking step on the I/O thread pool."""
        return await self.tasks.io(fn, *args, **kwargs)

    def method_of(self, method: str | None) -> str:
        """The ShDF method asked for, else the service's default (may be ``auto``)."""
        return method or self.settings.default_method

    async def resolved_method(self, mesh_id: str, method: str | None) -> str:
        """The ShDF producer a request runs on a stored mesh (``auto`` resolved per mesh)."""
        mesh = self.cache.recall(mesh_key(mesh_id))
        if mesh is not None:
            triangles = mesh.face_count
        else:
            triangles = int((await self.io(self.meshes.meta, mesh_id))["triangles"])
        return self.shdf.resolve(method, triangles)

    async def job(self, job_id: str) -> dict[str, Any]:
        """A job's record (an orphaned job is re-run first: ``ShdfService.job``)."""
        return await self.shdf.job(job_id)

    async def close(self) -> None:
        await self.tasks.close()
