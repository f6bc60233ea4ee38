"""The evaluated mesh of an object as a binary PLY, one face record per polygon in Blender's
polygon order (the service answers one label per face record, in file order)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import bpy


@dataclass
class MeshArrays:
    """Positions and polygons of a mesh, as Blender stores them."""

    positions: np.ndarray  # (V, 3) float32
    loop_start: np.ndarray  # (F,) int32, first corner of each polygon
    loop_total: np.ndarray  # (F,) int32, corners per polygon
    corner_vertex: np.ndarray  # (L,) int32, vertex of each corner

    @property
    def polygon_count(self) -> int:
        return len(self.loop_start)

    def same_topology(self, other: MeshArrays) -> bool:
        """Same polygons over the same vertex indices (positions may differ)."""
        return (
            len(self.positions) == len(other.positions)
            and np.array_equal(self.loop_total, other.loop_total)
            and np.array_equal(self.corner_vertex, other.corner_vertex)
        )


def mesh_arrays(mesh: bpy.types.Mesh, scale: tuple[float, float, float] = (1, 1, 1)) -> MeshArrays:
    """The arrays of a Blender mesh (``foreach_get``: no Python loop), positions scaled."""
    vertices, polygons = len(mesh.vertices), len(mesh.polygons)
    positions = np.empty(vertices * 3, dtype=np.float32)
    mesh.vertices.foreach_get("co", positions)
    loop_start = np.empty(polygons, dtype=np.int32)
    loop_total = np.empty(polygons, dtype=np.int32)
    mesh.polygons.foreach_get("loop_start", loop_start)
    mesh.polygons.foreach_get("loop_total", loop_total)
    corner_vertex = np.empty(len(mesh.loops), dtype=np.int32)
    mesh.loops.foreach_get("vertex_index", corner_vertex)
    positions = positions.reshape(-1, 3) * np.asarray(scale, dtype=np.float32)
    return MeshArrays(positions, loop_start, loop_total, corner_vertex)


def polygon_ply(arrays: MeshArrays) -> bytes:
    """Binary little-endian PLY: float32 vertices, one ``vertex_indices`` list per polygon in
    order (counts as uchar when every polygon has under 256 corners, else uint)."""
    faces = arrays.polygon_count
    if faces == 0:
        raise ValueError("the mesh has no polygons")
    corners = len(arrays.corner_vertex)
    count_type, width = ("uchar", 1) if arrays.loop_total.max(initial=0) < 256 else ("uint", 4)
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment neural-shdf Blender add-on\n"
        f"element vertex {len(arrays.positions)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {faces}\nproperty list {count_type} int vertex_indices\nend_header\n"
    ).encode()
    # Each face record: its corner count, then its vertex indices. Record f starts at byte
    # 4 * loop_start[f] + width * f, so every byte's place is known without a loop.
    body = np.empty(width * faces + 4 * corners, dtype=np.uint8)
    start = np.concatenate([[0], np.cumsum(arrays.loop_total, dtype=np.int64)[:-1]])
    if not np.array_equal(start, arrays.loop_start):
        raise ValueError("the polygons' corners are not stored in polygon order")
    record = 4 * start + width * np.arange(faces, dtype=np.int64)
    counts = arrays.loop_total.astype("<u4").view(np.uint8).reshape(-1, 4)[:, :width]
    body[record[:, None] + np.arange(width)] = counts
    face_of_corner = np.repeat(np.arange(faces, dtype=np.int64), arrays.loop_total)
    corner_at = 4 * np.arange(corners, dtype=np.int64) + width * (face_of_corner + 1)
    index_bytes = arrays.corner_vertex.astype("<i4").view(np.uint8).reshape(-1, 4)
    body[corner_at[:, None] + np.arange(4)] = index_bytes
    vertices = np.ascontiguousarray(arrays.positions, dtype="<f4").tobytes()
    return header + vertices + body.tobytes()


def payload_digest(payload: bytes) -> str:
    """What the add-on remembers of an upload, to send the mesh id instead next time."""
    return hashlib.sha256(payload).hexdigest()
