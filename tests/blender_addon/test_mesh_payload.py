"""Blender's polygons as a binary PLY: read back by the service's reader in the same order."""

from __future__ import annotations

import numpy as np
import pytest

from blender_addon.mesh_payload import MeshArrays, payload_digest, polygon_ply
from neural_shdf.mesh_io import load_mesh


def arrays_of(positions: list, polygons: list[list[int]]) -> MeshArrays:
    totals = np.array([len(p) for p in polygons], dtype=np.int32)
    starts = (np.cumsum(totals) - totals).astype(np.int32)
    corners = np.array([i for p in polygons for i in p], dtype=np.int32)
    return MeshArrays(np.asarray(positions, dtype=np.float32), starts, totals, corners)


def test_polygons_keep_their_order_and_corners():
    ring = 300  # a polygon with more corners than a uchar count holds
    angles = np.linspace(0, 2 * np.pi, ring, endpoint=False)
    positions = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]]
    positions += [[np.cos(a), np.sin(a), -1.0] for a in angles]
    polygons = [[0, 1, 2, 3], [0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]]
    polygons.insert(2, list(range(5, 5 + ring)))
    for chosen in (polygons, [p for p in polygons if len(p) < 256]):
        arrays = arrays_of(positions, chosen)
        mesh = load_mesh(polygon_ply(arrays), "ply")
        assert mesh.input_face_count == len(chosen)
        np.testing.assert_array_equal(mesh.vertices, np.asarray(positions, dtype=np.float32))
        # Each polygon comes back as its fan (v0, vi, vi+1), contiguous and in order.
        expected = [(p[0], p[i], p[i + 1]) for p in chosen for i in range(1, len(p) - 1)]
        origin = [k for k, p in enumerate(chosen) for _ in range(len(p) - 2)]
        assert mesh.faces.tolist() == [list(t) for t in expected]
        assert mesh.face_origin.tolist() == origin


def test_corners_out_of_polygon_order_and_empty_meshes_are_refused():
    arrays = arrays_of([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 1]])
    arrays.loop_start = arrays.loop_start[::-1].copy()
    with pytest.raises(ValueError, match="polygon order"):
        polygon_ply(arrays)
    with pytest.raises(ValueError, match="no polygons"):
        polygon_ply(arrays_of([[0, 0, 0]], []))


def test_digest_follows_the_geometry():
    square = arrays_of([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2, 3]])
    moved = arrays_of([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.1]], [[0, 1, 2, 3]])
    assert payload_digest(polygon_ply(square)) == payload_digest(polygon_ply(square))
    assert payload_digest(polygon_ply(square)) != payload_digest(polygon_ply(moved))
