"""Named parts in the service: label stored meshes with a stored labeller (from the
mesh's cached ShDF, cached per mesh, ShDF and labeller) and train labellers as jobs."""

from __future__ import annotations

import functools
import hashlib
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.api.errors import ApiError
from neural_shdf.api.labeler_store import LabelerStore
from neural_shdf.api.mesh_store import MeshStore
from neural_shdf.api.metrics import Metrics
from neural_shdf.api.settings import Settings
from neural_shdf.api.shdf_service import ShdfService
from neural_shdf.api.tasks import TaskRunner, checkpoint
from neural_shdf.labeling.labeler import (
    DEFAULT_SMOOTHING,
    MAX_CLASSES,
    check_compatible,
    label_mesh,
    train_labeler,
)
from neural_shdf.labeling.model import Labeler, labeler_bytes
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment.params import check_seed
from neural_shdf.store.cache import ResultCache
from neural_shdf.store.keys import labeling_key


@dataclass
class StoredLabels:
    """A mesh's labels by a labeller, as the service stores and serves them."""

    labels: NDArray[np.int64]  # per input face: the training labels' integers (-1: none)
    triangle_labels: NDArray[np.int64]  # per triangle: its input face's label
    confidence: NDArray[np.float32]  # per input face (NaN: face without triangles)
    label_seconds: float

    def arrays(self) -> dict[str, NDArray]:
        data = asdict(self)
        data["label_seconds"] = np.array(self.label_seconds)
        return data

    @classmethod
    def from_arrays(cls, arrays: dict[str, NDArray]) -> StoredLabels:
        return cls(
            labels=arrays["labels"].astype(np.int64),
            triangle_labels=arrays["triangle_labels"].astype(np.int64),
            confidence=arrays["confidence"].astype(np.float32),
            label_seconds=float(arrays["label_seconds"]),
        )


def label_stored_mesh(
    mesh: TriangleMesh, labeler: Labeler, shdf: NDArray, graph: Any = None
) -> StoredLabels:
    """``labeling.label_mesh`` from the given (cached) ShDF; every triangle takes its
    input face's label, so a polygon stays in one part of the parts GLB."""
    start = time.perf_counter()
    labels, confidence = label_mesh(mesh, labeler, shdf=shdf, graph=graph)
    return StoredLabels(
        labels=labels,
        triangle_labels=labels[mesh.face_origin],
        confidence=confidence.astype(np.float32),
        label_seconds=time.perf_counter() - start,
    )


def label_summary(
    mesh: TriangleMesh, result: StoredLabels, shdf: NDArray
) -> tuple[list[int], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """(label values present, input faces, area and area-weighted mean ShDF of each)."""
    values, per_triangle = np.unique(result.triangle_labels, return_inverse=True)
    _, area = mesh.normals_and_areas
    part_area = np.bincount(per_triangle, weights=area, minlength=len(values))
    weighted = np.bincount(per_triangle, weights=area * shdf, minlength=len(values))
    mean = np.divide(weighted, part_area, out=np.zeros(len(values)), where=part_area > 0)
    assigned = result.labels[result.labels >= 0]
    faces = np.array([np.count_nonzero(assigned == v) for v in values.tolist()], dtype=np.int64)
    return values.tolist(), faces, part_area.astype(np.float64), mean.astype(np.float64)


@dataclass(frozen=True)
class TrainingRequest:
    """A labeller to train from stored meshes: their ids, one label per input face of each
    (concatenated in mesh order), the label names, and the ShDF and smoothing to use."""

    mesh_ids: tuple[str, ...]
    labels: NDArray[np.int64]
    names: tuple[str, ...] | None
    method: str | None
    seed: int
    smoothing: float | None

    def key(self) -> str:
        """What identifies the training (concurrent identical requests share one run)."""
        digest = hashlib.sha256(self.labels.astype("<i8").tobytes())
        digest.update(repr((self.mesh_ids, self.names, self.method, self.seed)).encode())
        digest.update(repr(self.smoothing).encode())
        return f"labeler-train:{digest.hexdigest()}"


class LabelingService:
    """Labels of stored meshes by stored labellers, and labeller training jobs."""

    def __init__(
        self,
        settings: Settings,
        cache: ResultCache,
        metrics: Metrics,
        tasks: TaskRunner,
        meshes: MeshStore,
        shdf: ShdfService,
        labelers: LabelerStore,
    ) -> None:
        self.settings = settings
        self.cache = cache
        self.metrics = metrics
        self.tasks = tasks
        self.meshes = meshes
        self.shdf = shdf
        self.labelers = labelers

    def key(self, mesh_id: str, method: str, seed: int, labeler_id: str) -> str:
        return labeling_key(mesh_id, self.shdf.version(method, seed), labeler_id)

    def cached(self, key: str) -> StoredLabels | None:
        return self.meshes.recall_result(key, StoredLabels.from_arrays, "labels")

    def _store(
        self, key: str, mesh_id: str, result: StoredLabels, guard: tuple[str, bytes] | None
    ) -> None:
        self.meshes.keep_result(key, mesh_id, result, guard)

    async def get(
        self, mesh_id: str, method: str, seed: int, labeler_id: str
    ) -> tuple[StoredLabels, Labeler, NDArray[np.float64], dict[str, Any]]:
        """Label a stored mesh with a stored labeller, from the mesh's cached ShDF
        (computed once if missing; a large mesh's answers 202 with a job). Returns the
        labels, the labeller, the ShDF per triangle and where the time went."""
        start = time.perf_counter()
        seed = check_seed(seed)
        labeler = await self.tasks.io(self.labelers.load, labeler_id)  # 404 before any work
        mesh = await self.tasks.io(self.meshes.load, mesh_id)
        outcome = await self.shdf.get(mesh_id, mesh, method, seed)
        key = self.key(mesh_id, outcome.method, seed, labeler_id)
        found = await self.tasks.io(self.cached, key)
        labels_cached = found is not None
        if found is not None:
            result = found
        else:
            graph = functools.partial(self.meshes.file_graph, mesh_id, mesh)

            def compute() -> StoredLabels:
                checkpoint()
                return label_stored_mesh(mesh, labeler, outcome.values, graph())

            result, labels_cached = await self.tasks.with_timeout(
                self.tasks.single_flight(
                    key,
                    functools.partial(
                        self.tasks.compute_once,
                        key,
                        functools.partial(self.cached, key),
                        compute,
                        functools.partial(self._store, key, mesh_id),
                        functools.partial(self.meshes.guard, mesh_id),
                    ),
                )
            )
        timings = {
            "shdf_ms": round(outcome.seconds * 1000, 3),
            "segment_ms": 0.0 if labels_cached else round(result.label_seconds * 1000, 3),
            "total_ms": round((time.perf_counter() - start) * 1000, 3),
            "shdf_cached": outcome.cached,
            "segmentation_cached": labels_cached,
        }
        return result, labeler, outcome.values, timings

    async def glb(self, mesh_id: str, method: str, seed: int, labeler_id: str, style: str) -> bytes:
        """The labelled mesh as a GLB: ``colored`` or ``parts`` (nodes named by label)."""
        from neural_shdf.exchange.gltf_writer import colored_glb, parts_glb

        result, labeler, _, _ = await self.get(mesh_id, method, seed, labeler_id)
        mesh = await self.tasks.io(self.meshes.load, mesh_id)
        if style == "colored":
            write = functools.partial(colored_glb, mesh, result.triangle_labels)
        else:
            names = label_name_map(labeler)
            write = functools.partial(parts_glb, mesh, result.triangle_labels, names=names)
        key = f"{self.key(mesh_id, method, seed, labeler_id)}:glb:{style}"
        return await self.tasks.with_timeout(self.tasks.single_flight(key, write))

    async def usda(self, mesh_id: str, method: str, seed: int, labeler_id: str) -> bytes:
        """The labelled mesh as USD, one GeomSubset per label, named by label."""
        from neural_shdf.exchange.usd import mesh_parts_usda

        result, labeler, _, _ = await self.get(mesh_id, method, seed, labeler_id)
        mesh = await self.tasks.io(self.meshes.load, mesh_id)
        write = functools.partial(
            mesh_parts_usda, mesh, result.labels, names=label_name_map(labeler)
        )
        key = f"{self.key(mesh_id, method, seed, labeler_id)}:usda"
        return await self.tasks.with_timeout(self.tasks.single_flight(key, write))

    # -- training ---------------------------------------------------------------------

    async def check_training(self, request: TrainingRequest) -> list[dict[str, Any]]:
        """The meshes' metadata, once the request is within bounds and its labels fit
        them (422/413 before any work); 404 for a mesh that is not stored."""
        if not request.mesh_ids:
            raise ApiError(422, "invalid_parameter", "give at least one mesh id")
        if len(request.mesh_ids) > self.settings.max_train_meshes:
            raise ApiError(
                413,
                "too_many_meshes",
                f"{len(request.mesh_ids)} meshes, at most {self.settings.max_train_meshes} "
                "per training",
                {"max_train_meshes": self.settings.max_train_meshes},
            )
        if len(set(request.mesh_ids)) != len(request.mesh_ids):
            raise ApiError(422, "invalid_parameter", "a mesh id is given twice")
        metas = [await self.tasks.io(self.meshes.meta, m) for m in request.mesh_ids]
        triangles = sum(int(meta["triangles"]) for meta in metas)
        if triangles > self.settings.max_train_triangles:
            raise ApiError(
                413,
                "training_too_large",
                f"the meshes have {triangles} triangles together, at most "
                f"{self.settings.max_train_triangles} per training",
                {"max_train_triangles": self.settings.max_train_triangles},
            )
        faces = [int(meta["faces"]) for meta in metas]
        if len(request.labels) != sum(faces):
            raise ApiError(
                422,
                "invalid_parameter",
                f"{len(request.labels)} labels for meshes of {sum(faces)} faces in all "
                f"({', '.join(map(str, faces))}): give one label per input face of each mesh, "
                "in the file's face order, the meshes in the order of mesh_ids",
            )
        distinct = np.unique(request.labels)
        if len(distinct) < 2 or len(distinct) > MAX_CLASSES:
            raise ApiError(
                422,
                "invalid_parameter",
                f"the labels hold {len(distinct)} distinct values: give 2 to {MAX_CLASSES}",
            )
        if request.names is not None and len(request.names) != len(distinct):
            raise ApiError(
                422,
                "invalid_parameter",
                f"{len(request.names)} label names for {len(distinct)} distinct labels "
                f"({', '.join(str(v) for v in distinct.tolist())}): give one name per label, "
                "in increasing label order",
            )
        return metas

    def _train(self, request: TrainingRequest, faces: list[int], key: str) -> dict[str, Any]:
        """Blocking (a compute thread): the meshes' ShDF (cached, else computed and
        stored), the labeller trained and stored; its description."""
        report = self.shdf.progress_reporter(key)
        meshes, labels, shdf = [], [], []
        bounds = np.cumsum([0, *faces])
        for index, mesh_id in enumerate(request.mesh_ids):
            checkpoint()
            mesh = self.meshes.load(mesh_id)
            method = self.shdf.resolve(request.method, mesh.face_count)
            shdf_key = self.shdf.key(mesh_id, method, request.seed)
            outcome = self.shdf.compute_once(shdf_key, mesh_id, mesh, method, request.seed)
            meshes.append(mesh)
            labels.append(request.labels[bounds[index] : bounds[index + 1]])
            shdf.append(outcome.values)
            report(0.3 * (index + 1) / len(request.mesh_ids))

        def progress(fraction: float) -> None:
            checkpoint()
            report(0.3 + 0.7 * fraction)

        smoothing = DEFAULT_SMOOTHING if request.smoothing is None else request.smoothing
        labeler = train_labeler(
            meshes, labels, request.names, shdf=shdf, progress=progress, smoothing=smoothing
        )
        check_compatible(labeler)
        return self.labelers.store(labeler_bytes(labeler), labeler)

    async def start_training(self, request: TrainingRequest) -> dict[str, Any]:
        """Check the request, then train as a job (``kind`` labeler); the job's record.
        On success its ``result_url`` is the labeller's."""
        metas = await self.check_training(request)
        faces = [int(meta["faces"]) for meta in metas]
        key = request.key()
        compute = functools.partial(self._train, request, faces, key)
        return await self.shdf.start_computation_job(
            key,
            request.mesh_ids[0],
            self.shdf.settings.default_method if request.method is None else request.method,
            request.seed,
            compute,
            kind="labeler",
            result_url="/v1/labelers",
            on_success=lambda meta: {"result_url": f"/v1/labelers/{meta['labeler_id']}"},
        )


def label_name_map(labeler: Labeler) -> dict[int, str]:
    """Label value -> name of a labeller."""
    return dict(zip(labeler.label_values.tolist(), labeler.label_names, strict=True))
