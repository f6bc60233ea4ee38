"""Segmentations of stored meshes: computed once per (mesh, ShDF, parameters), cached."""

from __future__ import annotations

import base64
import functools
import json
import time
from dataclasses import asdict, dataclass
from dataclasses import field as dataclass_field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.api.errors import ApiError
from neural_shdf.api.mesh_store import MeshStore, mesh_missing
from neural_shdf.api.metrics import Metrics
from neural_shdf.api.shdf_service import ShdfService
from neural_shdf.api.tasks import TaskRunner, checkpoint
from neural_shdf.arrays import json_array
from neural_shdf.exchange.gltf_writer import colored_glb, parts_glb
from neural_shdf.exchange.usd import mesh_parts_usda
from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import SegmentParams, prepare_segment, segment
from neural_shdf.segment.from_shdf import SegmentResult
from neural_shdf.segment.hierarchy import PartTree
from neural_shdf.segment.tree_document import part_tree_document
from neural_shdf.store.cache import ResultCache
from neural_shdf.store.keys import segmentation_basis_key, segmentation_key


@dataclass
class StoredSegmentation:
    """A segmentation as the service stores and serves it (per input face, with per-part
    statistics and the part tree), kept in the cache as arrays; ``summarize`` makes one
    from the library's ``SegmentResult``."""

    labels: NDArray[np.int32]  # per input face
    triangle_labels: NDArray[np.int32]  # per triangle
    part_faces: NDArray[np.int64]
    part_area: NDArray[np.float64]
    part_mean_shdf: NDArray[np.float64]
    segment_seconds: float
    # The graph cut's part tree (empty for metis): leaf per input face, merges, costs.
    leaf_labels: NDArray[np.int32] = dataclass_field(
        default_factory=lambda: np.zeros(0, dtype=np.int32)
    )
    tree_merges: NDArray[np.int64] = dataclass_field(
        default_factory=lambda: np.zeros((0, 2), dtype=np.int64)
    )
    tree_costs: NDArray[np.float64] = dataclass_field(default_factory=lambda: np.zeros(0))

    @property
    def tree(self) -> PartTree | None:
        """The part tree over the input faces' leaves, or None (metis)."""
        if len(self.leaf_labels) == 0:
            return None
        return PartTree(self.leaf_labels.astype(np.int64), self.tree_merges, self.tree_costs)

    @functools.cached_property
    def labels_json(self) -> str:
        """The labels as a JSON array, encoded once per result (the hot path's main cost)."""
        return json_array(self.labels)

    @functools.cached_property
    def labels_base64(self) -> tuple[str, str]:
        """(base64 of the labels as the narrowest little-endian integers, their dtype name)."""
        return pack_integers(self.labels)

    def hierarchy_json(self, compact: bool) -> str:
        """The ``hierarchy`` member as JSON ("null" without a tree), encoded once per form."""
        name = "_hierarchy_base64" if compact else "_hierarchy_list"
        cached = self.__dict__.get(name)
        if cached is None:
            tree = self.tree
            cached = "null"
            if tree is not None:
                document = part_tree_document(
                    tree, self.leaf_labels, len(self.part_faces), as_arrays=True
                )
                packed = pack_integers(self.leaf_labels) if compact else (None, None)
                document["leaf_labels_dtype"] = packed[1]
                # The arrays (one per input face, two per leaf) a chunk at a time, the rest whole;
                # base64 needs no escaping: spliced in, not scanned by json.dumps.
                arrays = {
                    key: "null" if compact and key == "leaf_labels" else json_array(values)
                    for key in ("leaf_labels", "parent", "merge_cost", "merge_height")
                    for values in (document.pop(key),)
                }
                arrays["leaf_labels_base64"] = f'"{packed[0]}"' if compact else "null"
                rest = json.dumps(document, separators=(",", ":"))
                members = "".join(f'"{key}":{text},' for key, text in arrays.items())
                cached = "{" + members + rest[1:]
            self.__dict__[name] = cached
        return cached

    def arrays(self) -> dict[str, NDArray]:
        """The arrays the cache keeps; the per-face labels as the narrowest integers that
        hold them (a quarter of the bytes to frame, hash and write for up to 127 parts)."""
        data = asdict(self)
        data["segment_seconds"] = np.array(self.segment_seconds)
        for name in PER_FACE_LABELS:
            data[name] = narrowest_integers(data[name])
        return data

    @classmethod
    def from_arrays(cls, arrays: dict[str, NDArray]) -> StoredSegmentation:
        wide = {name: arrays[name].astype(np.int32, copy=False) for name in PER_FACE_LABELS}
        return cls(
            labels=wide["labels"],
            triangle_labels=wide["triangle_labels"],
            part_faces=arrays["part_faces"],
            part_area=arrays["part_area"],
            part_mean_shdf=arrays["part_mean_shdf"],
            segment_seconds=float(arrays["segment_seconds"]),
            leaf_labels=wide["leaf_labels"],
            tree_merges=arrays["tree_merges"].reshape(-1, 2),
            tree_costs=arrays["tree_costs"],
        )


#: ``StoredSegmentation``'s arrays of one label per face (int32 in memory).
PER_FACE_LABELS = ("labels", "triangle_labels", "leaf_labels")


def narrowest_integers(values: NDArray) -> NDArray:
    """Integers (at most int32) as the narrowest signed type that holds them."""
    top = max(int(values.max()), -int(values.min()) - 1) if len(values) else 0
    dtype = np.int8 if top < 2**7 else np.int16 if top < 2**15 else np.int32
    return values.astype(dtype, copy=False)


def pack_integers(values: NDArray) -> tuple[str, str]:
    """(base64 of integers as the narrowest little-endian type that holds them, its name)."""
    narrow = narrowest_integers(values)
    packed = narrow.astype(narrow.dtype.newbyteorder("<"), copy=False).tobytes()
    return base64.b64encode(packed).decode(), narrow.dtype.name


def summarize(
    mesh: TriangleMesh, segmentation: SegmentResult, shdf: NDArray, seconds: float
) -> StoredSegmentation:
    """Input-face labels and leaves (the library's mapping), the part tree, and per-part
    faces, area and area-weighted mean ShDF."""
    triangle_labels = segmentation.labels
    labels, leaves = segmentation.input_face_parts(mesh)
    _, area = mesh.normals_and_areas
    part_count = int(triangle_labels.max()) + 1 if len(triangle_labels) else 0
    tri = np.asarray(triangle_labels, dtype=np.int64)
    part_area = np.bincount(tri, weights=area, minlength=part_count)
    weighted = np.bincount(tri, weights=area * shdf, minlength=part_count)
    mean = np.divide(weighted, part_area, out=np.zeros(part_count), where=part_area > 0)
    assigned = labels[labels >= 0]
    part_faces = np.bincount(assigned, minlength=part_count)
    result = StoredSegmentation(
        labels=labels.astype(np.int32),
        triangle_labels=tri.astype(np.int32),
        part_faces=part_faces.astype(np.int64),
        part_area=part_area,
        part_mean_shdf=mean,
        segment_seconds=seconds,
    )
    if leaves is not None and segmentation.tree is not None:
        result.leaf_labels = leaves.astype(np.int32)
        result.tree_merges = segmentation.tree.merges
        result.tree_costs = segmentation.tree.costs
    return result


class SegmentationService:
    """Segmentations of stored meshes from their cached ShDF, deduplicated."""

    def __init__(
        self,
        cache: ResultCache,
        metrics: Metrics,
        tasks: TaskRunner,
        meshes: MeshStore,
        shdf: ShdfService,
    ) -> None:
        self.cache = cache
        self.metrics = metrics
        self.tasks = tasks
        self.meshes = meshes
        self.shdf = shdf

    def key(self, mesh_id: str, method: str, params: SegmentParams) -> str:
        """The cache key: mesh, code version, the ShDF it starts from, the parameters."""
        return segmentation_key(mesh_id, self.shdf.version(method, params.seed), params)

    def cached(self, key: str) -> StoredSegmentation | None:
        """The cached segmentation (memory, then the shared cache), or None."""
        return self.meshes.recall_result(key, StoredSegmentation.from_arrays, "segmentation")

    def _store(
        self, key: str, mesh_id: str, result: StoredSegmentation, guard: tuple[str, bytes] | None
    ) -> None:
        self.meshes.keep_result(key, mesh_id, result, guard)

    def _compute(
        self, mesh_id: str, method: str, mesh: TriangleMesh, shdf: NDArray, params: SegmentParams
    ) -> StoredSegmentation:
        self.meshes.graph(mesh_id, mesh)  # built once per mesh, under the mesh's lock
        start = time.perf_counter()
        # What does not depend on smoothing, parts or refinement is kept per mesh, ShDF,
        # clusters and seed (in memory, within MEMORY_WORKING_SET_BYTES), so a new slider value
        # only re-cuts.
        if params.partitioner == "metis":
            # In the worker process: pymetis partitions holding the GIL, which in a thread
            # stalls the event loop (every other request) for as long.
            segmentation = self.tasks.isolated(segment, mesh.portable(), shdf, params)
        else:
            shdf_version = self.shdf.version(method, params.seed)
            basis_key = segmentation_basis_key(
                mesh_id, shdf_version, params.clusters, params.seed, params.symmetry
            )
            basis = self.cache.working_set(basis_key)
            if basis is None or not basis.matches(params, shdf):
                if params.crease_boundaries:
                    self.meshes.creases(mesh_id, mesh)
                checkpoint()
                basis = prepare_segment(mesh, shdf, params)
            checkpoint()
            # The basis's own ShDF: the one it was checked against just above (no second pass).
            segmentation = segment(mesh, basis.shdf, params, basis=basis)
            self.cache.keep_working_set(basis_key, basis, basis.nbytes)  # sized with its cut
        seconds = time.perf_counter() - start
        self.metrics.segmentations.inc()
        self.metrics.segment_seconds.observe(seconds)
        return summarize(mesh, segmentation, shdf, seconds)

    def _compute_remembered(
        self,
        key: str,
        mesh_id: str,
        method: str,
        mesh: TriangleMesh,
        shdf: NDArray,
        params: SegmentParams,
    ) -> StoredSegmentation:
        """``_compute``, the result remembered in memory at once (its store comes after the
        answer: a request meanwhile finds it here)."""
        result = self._compute(mesh_id, method, mesh, shdf, params)
        self.cache.remember(key, result)
        return result

    async def _recall_fresh(self, mesh_id: str, key: str) -> StoredSegmentation | None:
        """This process's memory of the result, unless the mesh was deleted meanwhile."""
        result = self.cache.recall(key)
        if result is None:
            return None
        stored = (
            self.meshes.still_stored(mesh_id)
            if self.cache.backend.local
            else await self.tasks.io(self.meshes.still_stored, mesh_id)
        )
        if not stored:
            raise mesh_missing(mesh_id)
        self.metrics.count_cache("segmentation", hit=True)
        return result

    async def get(
        self, mesh_id: str, method: str, params: SegmentParams
    ) -> tuple[StoredSegmentation, dict[str, Any]]:
        """Segment a stored mesh (cached result, else from the cached ShDF, whose seed is
        ``params.seed``); returns the result and where the time went."""
        start = time.perf_counter()
        key = self.key(mesh_id, method, params)
        result = await self._recall_fresh(mesh_id, key)
        if result is None:
            result = await self.tasks.io(self.cached, key)
        shdf_cached, shdf_seconds, segmentation_cached = True, 0.0, result is not None
        if result is None:
            mesh = await self.tasks.io(self.meshes.load, mesh_id)
            outcome = await self.shdf.get(mesh_id, mesh, method, params.seed)
            shdf_cached, shdf_seconds = outcome.cached, outcome.seconds
            result, segmentation_cached = await self.tasks.with_timeout(
                self.tasks.single_flight(
                    key,
                    functools.partial(
                        self.tasks.compute_once,
                        key,
                        functools.partial(self.cached, key),
                        functools.partial(
                            self._compute_remembered,
                            key,
                            mesh_id,
                            method,
                            mesh,
                            outcome.values,
                            params,
                        ),
                        functools.partial(self._store, key, mesh_id),
                        functools.partial(self.meshes.guard, mesh_id),
                        # The answer (a slider's new value) does not wait for the write.
                        store_later=True,
                    ),
                )
            )
        timings = {
            "shdf_ms": round(shdf_seconds * 1000, 3),
            "segment_ms": 0.0 if segmentation_cached else round(result.segment_seconds * 1000, 3),
            "total_ms": round((time.perf_counter() - start) * 1000, 3),
            "shdf_cached": shdf_cached,
            "segmentation_cached": segmentation_cached,
        }
        return result, timings

    async def glb(
        self,
        mesh_id: str,
        method: str,
        params: SegmentParams,
        style: str,
        source_id: str | None = None,
    ) -> bytes:
        """The segmentation as a GLB: ``colored`` (vertex colours) or ``parts`` (a node
        each; with ``source_id``, keeping that uploaded file's attributes and objects)."""

        result, _ = await self.get(mesh_id, method, params)
        mesh = await self.tasks.io(self.meshes.load, mesh_id)
        labels = result.triangle_labels.astype(np.int64)
        if style == "colored":
            write = functools.partial(colored_glb, mesh, labels)
        elif source_id is None:
            write = functools.partial(parts_glb, mesh, labels)
        else:
            write = functools.partial(self._source_parts_glb, mesh_id, source_id, mesh, labels)
        # Identical requests share one writer; it runs within the request timeout.
        key = f"{self.key(mesh_id, method, params)}:glb:{style}:{source_id or ''}"
        return await self.tasks.with_timeout(self.tasks.single_flight(key, write))

    def _source_parts_glb(
        self, mesh_id: str, source_id: str, mesh: TriangleMesh, labels: NDArray[np.int64]
    ) -> bytes:
        from neural_shdf.mesh_io import load_source

        data, file_type = self.meshes.source(mesh_id, source_id)
        settings = self.meshes.settings
        source = load_source(
            data, file_type, max_faces=settings.max_faces, max_vertices=settings.max_vertices
        )
        if source.mesh.content_hash() != mesh_id:  # kept under the mesh: never expected
            raise ApiError(
                409,
                "source_mismatch",
                f"the uploaded file {source_id!r} does not hold mesh {mesh_id!r} (this "
                "version reads it differently); upload the file again",
            )
        return parts_glb(mesh, labels, attributes=source.attributes)

    async def usda(
        self, mesh_id: str, method: str, params: SegmentParams, source_id: str | None = None
    ) -> bytes:
        """The segmentation as USD: with the ``source_id`` of a USD upload, that file's own
        stage with one GeomSubset per part; otherwise a new stage of the stored mesh's
        input faces."""
        from neural_shdf.exchange.usd import USD_EXTENSIONS, usd_parts_usda

        result, _ = await self.get(mesh_id, method, params)
        mesh = await self.tasks.io(self.meshes.load, mesh_id)
        labels = result.labels.astype(np.int64)
        write = functools.partial(mesh_parts_usda, mesh, labels)
        if source_id is not None:
            data, file_type = await self.tasks.io(self.meshes.source, mesh_id, source_id)
            if file_type in USD_EXTENSIONS:
                write = functools.partial(usd_parts_usda, data, file_type, labels)
        key = f"{self.key(mesh_id, method, params)}:usda:{source_id or ''}"
        return await self.tasks.with_timeout(self.tasks.single_flight(key, write))
