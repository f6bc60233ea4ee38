"""Stored meshes: parse an upload, store it under its content hash, load it, delete it."""

from __future__ import annotations

import hashlib
import logging
import threading
import time
import uuid
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from neural_shdf.api.errors import ApiError, not_found
from neural_shdf.api.metrics import Metrics
from neural_shdf.api.settings import Settings
from neural_shdf.errors import InvalidGeometryError
from neural_shdf.geometry import FaceGraph
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.segment.creases import CreaseGraph
from neural_shdf.store.cache import ResultCache
from neural_shdf.store.codec import mesh_arrays, mesh_from_arrays
from neural_shdf.store.keys import mesh_key, meta_key, source_key

logger = logging.getLogger(__name__)


#: Metadata of one upload, answered to that uploader only. A mesh is stored under the hash
#: of its geometry, so several clients may upload the same one: they share the geometry's
#: facts and everything computed from it, never each other's file name or upload time.
UPLOAD_FIELDS = ("format", "filename", "uploaded_at", "source_id")
#: Formats whose uploaded file is kept (``MeshStore.keep_source``): their normals, UVs,
#: colours, materials and objects, or their USD stage, go back into ``parts.glb`` and
#: ``parts.usda``.
SOURCE_FORMATS = frozenset({"obj", "ply", "glb", "gltf", "usd", "usda", "usdc", "usdz"})
#: Bookkeeping in the stored metadata that no client sees.
PRIVATE_FIELDS = ("generation",)


def shared_meta(meta: dict[str, Any]) -> dict[str, Any]:
    """The geometry's metadata without any upload's own fields (entries stored by older
    versions held the first uploader's)."""
    hidden = UPLOAD_FIELDS + PRIVATE_FIELDS
    return {name: value for name, value in meta.items() if name not in hidden}


def mesh_missing(mesh_id: str) -> ApiError:
    """The 404 of a mesh that is not stored, saying what to do."""
    error = not_found("mesh", mesh_id)
    error.message += (
        " (never uploaded, deleted, evicted from the cache or its stored copy was "
        "damaged: upload it again)"
    )
    return error


#: A result decoded from stored arrays.
Result = TypeVar("Result")


class StoredArrays(Protocol):
    """A result kept as named arrays (a segmentation, a labelling)."""

    def arrays(self) -> dict[str, NDArray[Any]]: ...


class MeshStore:
    """Meshes and their face graphs over the shared cache (memory first)."""

    def __init__(self, settings: Settings, cache: ResultCache, metrics: Metrics) -> None:
        self.settings = settings
        self.cache = cache
        self.metrics = metrics
        self._graph_locks = [threading.Lock() for _ in range(64)]  # striped by mesh id

    def parse(self, data: bytes, file_type: str | None) -> TriangleMesh:
        """The mesh in an uploaded file (bounded by ``max_faces``)."""
        mesh = load_mesh(
            data,
            file_type,
            max_faces=self.settings.max_faces,
            max_vertices=self.settings.max_vertices,
        )
        if mesh.face_count == 0:
            raise InvalidGeometryError("the mesh has no triangles")
        return mesh

    def store(
        self,
        mesh: TriangleMesh,
        file_type: str | None,
        filename: str | None,
        data: bytes | None = None,
    ) -> dict[str, Any]:
        """Store the mesh (if new) and return its metadata as this upload's answer: the
        shared facts of the geometry plus this upload's own file name, format and time,
        which are not stored (``UPLOAD_FIELDS``)."""
        mesh_id = mesh.content_hash()
        meta_entry = meta_key(mesh_id)
        meta = self.cache.get_json(meta_entry)
        stored = self.cache.recall(mesh_key(mesh_id)) is not None
        if meta is None or not (stored or self.cache.get_arrays(mesh_key(mesh_id)) is not None):
            _, area = mesh.normals_and_areas
            meta = {
                "mesh_id": mesh_id,
                "faces": mesh.input_face_count,
                "triangles": mesh.face_count,
                "vertices": len(mesh.vertices),
                "bounds": [mesh.vertices.min(0).tolist(), mesh.vertices.max(0).tolist()],
                "surface_area": float(area.sum()),
                # New with every store after a deletion: the meta entry is the guard
                # results are stored under (``TaskRunner.compute_once``), so a result of
                # the deleted mesh never lands in the cache of the one uploaded again.
                "generation": uuid.uuid4().hex,
                "diagnostics": mesh.diagnostics.as_dict(),
            }
            # keep_local: readable through a Redis outage (only the client could restore it)
            self.cache.put_arrays(
                mesh_key(mesh_id), mesh_arrays(mesh), group=mesh_id, keep_local=True
            )
            # Concurrent first uploads: one meta (one generation) wins, the others read it.
            if not self.cache.add_json(meta_entry, meta, group=mesh_id, keep_local=True):
                meta = self.cache.get_json(meta_entry) or meta
        self.cache.remember(mesh_key(mesh_id), mesh)
        upload = {"format": file_type, "filename": filename, "uploaded_at": time.time()}
        if data is not None and file_type in SOURCE_FORMATS:
            upload["source_id"] = self.keep_source(mesh_id, data, file_type)
        return {**shared_meta(meta), **upload}

    def keep_source(self, mesh_id: str, data: bytes, file_type: str) -> str:
        """Store an upload's file with the mesh (deleted with it) under the SHA-256 of its
        format and bytes: its ``source_id``. Only a client that has the file can name it,
        so one uploader's file never reaches another who uploaded the same geometry."""
        source_id = hashlib.sha256(file_type.encode() + b"\0" + data).hexdigest()
        key = source_key(mesh_id, source_id)
        if self.cache.get_raw(key) is None:
            arrays = {
                "data": np.frombuffer(data, dtype=np.uint8),
                "format": np.frombuffer(file_type.encode(), dtype=np.uint8),
            }
            self.cache.put_arrays(key, arrays, group=mesh_id)
        return source_id

    def source(self, mesh_id: str, source_id: str) -> tuple[bytes, str]:
        """(bytes, format) of an upload's file kept with the mesh; 404 when it is not."""
        arrays = self.cache.get_arrays(source_key(mesh_id, source_id))
        if arrays is None or "data" not in arrays or "format" not in arrays:
            raise ApiError(
                404,
                "source_not_found",
                f"no uploaded file {source_id!r} is kept with mesh {mesh_id!r} (never "
                "uploaded with it, deleted or evicted from the cache): upload the file "
                "again and use the source_id of that answer",
            )
        return arrays["data"].tobytes(), arrays["format"].tobytes().decode()

    def meta(self, mesh_id: str) -> dict[str, Any]:
        """Metadata of a mesh that can be used (one whose geometry is gone is gone): what
        every uploader of the geometry shares, never one uploader's file name."""
        meta = self.cache.get_json(meta_key(mesh_id))
        if meta is None or self._geometry_lost(mesh_id):
            raise mesh_missing(mesh_id)
        return shared_meta(meta)

    def _geometry_lost(self, mesh_id: str) -> bool:
        """Whether the mesh's geometry entry is known to be gone (evicted, or dropped as
        corrupt); then its metadata and results are deleted too, so that every route
        answers 404 alike. An unreachable cache cannot tell: not lost."""
        key = mesh_key(mesh_id)
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
        if self.cache.backend.exists(meta_key(mesh_id)) is not False:
            return True
        self.cache.forget_group(mesh_id)
        return False

    def load(self, mesh_id: str) -> TriangleMesh:
        """The stored mesh (memory first, then the shared cache); 404 when absent."""
        key = mesh_key(mesh_id)
        mesh = self.cache.recall(key)
        if mesh is not None and self.still_stored(mesh_id):
            self.metrics.count_cache("mesh", hit=True)
            return mesh
        arrays = self.cache.get_arrays(key)
        self.metrics.count_cache("mesh", hit=arrays is not None)
        if arrays is None:
            self._geometry_lost(mesh_id)
            raise mesh_missing(mesh_id)
        mesh = mesh_from_arrays(arrays)
        self.cache.remember(key, mesh)
        return mesh

    def guard(self, mesh_id: str) -> tuple[str, bytes]:
        """What a result of the mesh is stored under (``ResultCache.put_arrays``): its meta
        entry as it is now; 404 when the mesh is not stored (deleted)."""
        key = meta_key(mesh_id)
        stored = self.cache.get_raw(key)
        if stored is None:
            raise mesh_missing(mesh_id)
        return key, stored

    def store_result(
        self,
        key: str,
        mesh_id: str,
        arrays: dict[str, NDArray],
        guard: tuple[str, bytes] | None,
    ) -> None:
        """Store a result computed from the mesh, only while ``guard`` (``guard``, taken
        before computing) holds; 404 when the mesh was deleted meanwhile. No guard: stored
        as is (batch workers, whose meshes are not uploaded)."""
        if not self.cache.put_arrays(key, arrays, group=mesh_id, guard=guard):
            self.cache.forget_group(mesh_id)
            error = mesh_missing(mesh_id)
            error.message = f"mesh {mesh_id!r} was deleted while this result was computed"
            raise error

    def recall_result(
        self, key: str, decode: Callable[[dict[str, NDArray[Any]]], Result], kind: str
    ) -> Result | None:
        """A result of a stored mesh: this process's memory, else the shared cache through
        ``decode``; None when absent. Counted as a cache hit or miss of ``kind``."""
        result = self.cache.recall_arrays(key, decode)
        self.metrics.count_cache(kind, hit=result is not None)
        return result

    def keep_result(
        self, key: str, mesh_id: str, result: StoredArrays, guard: tuple[str, bytes] | None
    ) -> None:
        """Store a result of the mesh (as ``store_result``) and remember it in memory."""
        self.store_result(key, mesh_id, result.arrays(), guard)
        self.cache.remember(key, result)

    def delete(self, mesh_id: str) -> None:
        """Delete the mesh and everything derived from it; 404 when there was nothing."""
        existed = self.cache.get_json(meta_key(mesh_id)) is not None
        if not (self.cache.delete_group(mesh_id) > 0 or existed):
            raise mesh_missing(mesh_id)

    def graph(self, mesh_id: str, mesh: TriangleMesh) -> FaceGraph:
        """Face graph the ShDF and the segmentation work on (``TriangleMesh.distinct``'s,
        cached on the mesh this store keeps in memory), built once: concurrent requests
        wait for one build."""
        with self._graph_locks[hash(f"{mesh_id}:graph") % len(self._graph_locks)]:
            return mesh.distinct.mesh.face_graph

    def file_graph(self, mesh_id: str, mesh: TriangleMesh) -> FaceGraph:
        """Face graph of the file's triangles in the file's order (``TriangleMesh.face_graph``:
        what labelling reads per triangle), built once as ``graph``."""
        with self._graph_locks[hash(f"{mesh_id}:file-graph") % len(self._graph_locks)]:
            return mesh.face_graph

    def creases(self, mesh_id: str, mesh: TriangleMesh) -> CreaseGraph:
        """The crease refinement's graph of a mesh (``TriangleMesh.crease_graph``), built
        once as ``graph``; it serves every ShDF and mixture of the mesh."""
        self.graph(mesh_id, mesh)  # outside the lock: locks are striped, not reentrant
        with self._graph_locks[hash(f"{mesh_id}:creases") % len(self._graph_locks)]:
            return mesh.distinct.mesh.crease_graph
