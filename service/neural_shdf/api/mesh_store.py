"""Stored meshes: parse an upload, store it under its content hash, load it, delete it."""

from __future__ import annotations

import logging
import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.api.cache import ResultCache
from neural_shdf.api.errors import ApiError, not_found
from neural_shdf.api.metrics import Metrics
from neural_shdf.api.settings import Settings
from neural_shdf.errors import InvalidGeometryError
from neural_shdf.geometry import FaceGraph
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment.creases import CreaseGraph

logger = logging.getLogger(__name__)


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


def mesh_missing(mesh_id: str) -> ApiError:
    """The 404 of a mesh that is not stored, saying what to do."""
    error = not_found("mesh", mesh_id)
    error.message += (
        " (never uploaded, deleted, evicted from the cache or its stored copy was "
        "damaged: upload it again)"
    )
    return error


class MeshStore:
    """Meshes and their face graphs over the shared cache (memory first)."""

    def __init__(self, settings: Settings, cache: ResultCache, metrics: Metrics) -> None:
        self.settings = settings
        self.cache = cache
        self.metrics = metrics
        self._graph_locks = [threading.Lock() for _ in range(64)]  # striped by mesh id

    def parse(self, data: bytes, file_type: str | None) -> TriangleMesh:
        """The mesh in an uploaded file (bounded by ``max_faces``)."""
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

    def store(
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
                "diagnostics": mesh.orientation.diagnostics.as_dict(),
            }
            # keep_local: readable through a Redis outage (only the client could restore it)
            self.cache.put_arrays(
                f"{mesh_id}:mesh", mesh_arrays(mesh), group=mesh_id, keep_local=True
            )
            self.cache.put_json(meta_key, meta, group=mesh_id, keep_local=True)
        self.cache.remember(f"{mesh_id}:mesh", mesh)
        return meta

    def meta(self, mesh_id: str) -> dict[str, Any]:
        """Metadata of a mesh that can be used: one whose geometry is gone is gone."""
        meta = self.cache.get_json(f"{mesh_id}:meta")
        if meta is None or self._geometry_lost(mesh_id):
            raise mesh_missing(mesh_id)
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
        """The stored mesh (memory first, then the shared cache); 404 when absent."""
        key = f"{mesh_id}:mesh"
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

    def delete(self, mesh_id: str) -> None:
        """Delete the mesh and everything derived from it; 404 when there was nothing."""
        existed = self.cache.get_json(f"{mesh_id}:meta") is not None
        if not (self.cache.delete_group(mesh_id) > 0 or existed):
            raise mesh_missing(mesh_id)

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

    def creases(self, mesh_id: str, mesh: TriangleMesh) -> CreaseGraph:
        """The crease refinement's graph of a mesh, built once per process (memory LRU); it
        serves every ShDF and mixture of the mesh."""
        from neural_shdf.pipeline import mesh_crease_graph

        key = f"{mesh_id}:creases"
        graph = self.graph(mesh_id, mesh)  # outside the lock: locks are striped, not reentrant
        with self._graph_locks[hash(key) % len(self._graph_locks)]:
            creases = self.cache.recall(key)
            if creases is None:
                creases = mesh_crease_graph(mesh, graph)
                self.cache.remember(key, creases)
        return creases
