"""Neighbour searches: grid k-nearest and the k-d tree cone search against brute force."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from neural_shdf.geometry import face_normals
from neural_shdf.shdf.sampling import sample_surface_points
from neural_shdf.shdf.search import cone_neighbours, nearest_points


def brute_nearest(positions: np.ndarray, queries: np.ndarray, k: int) -> tuple:
    """All distances, sorted by (distance, index)."""
    squared = ((queries[:, None, :] - positions[None, :, :]) ** 2).sum(axis=2)
    order = np.lexsort((np.broadcast_to(np.arange(len(positions)), squared.shape), squared))
    order = order[:, :k]
    return order, np.sqrt(np.take_along_axis(squared, order, axis=1))


def dense_cone_edges(
    positions: np.ndarray, normals: np.ndarray, count: int, cone_cos: float, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """The O(N^2) scan the k-d tree search replaced (float32, as it computed), ties of
    distance broken by index."""
    n = len(positions)
    tan_half = math.sqrt(max(1.0 - cone_cos**2, 0.0)) / max(cone_cos, 1e-6)
    pos, nrm = positions.astype(np.float32), normals.astype(np.float32)
    k = min(count, n - 1)
    senders, receivers = [], []
    for row in range(n):
        offset = pos - pos[row]
        squared = (offset * offset).sum(axis=1, dtype=np.float32)
        depth = -(offset @ nrm[row])
        lateral = np.sqrt(np.maximum(squared - depth**2, np.float32(0)))
        away = (offset * nrm).sum(axis=1) > 0
        opposed = nrm @ nrm[row] <= np.float32(cone_cos)
        ok = (depth > 0) & (lateral <= depth * np.float32(tan_half) + np.float32(radius))
        ok &= away & opposed
        ok[row] = False
        chosen = np.flatnonzero(ok)
        chosen = chosen[np.lexsort((chosen, squared[chosen]))][:k]
        senders.append(chosen)
        receivers.append(np.full(len(chosen), row))
    return np.concatenate(senders).astype(np.int64), np.concatenate(receivers).astype(np.int64)


def surface_samples(mesh: trimesh.Trimesh, count: int, seed: int = 0):  # noqa: ANN201
    normals, areas = face_normals(mesh.vertices, mesh.faces)
    return sample_surface_points(
        mesh.vertices,
        mesh.faces,
        count,
        seed=seed,
        normals=normals,
        areas=areas,
        map_vertices=False,
    )


def test_grid_nearest_matches_brute_force_inside_and_outside_the_points() -> None:
    rng = np.random.default_rng(0)
    positions = rng.normal(size=(500, 3))
    queries = np.concatenate([rng.normal(size=(300, 3)), 6.0 * rng.normal(size=(100, 3))])
    for spacing in (0.01, 0.2, 5.0):  # any spacing: only the time changes
        index, distance = nearest_points(positions, queries, 5, spacing)
        expected_index, expected_distance = brute_nearest(positions, queries, 5)
        np.testing.assert_array_equal(index, expected_index)
        np.testing.assert_allclose(distance, expected_distance, rtol=1e-12)


def test_grid_nearest_breaks_ties_by_index_and_does_not_depend_on_threads() -> None:
    grid = np.stack(np.meshgrid(*[np.arange(6.0)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    queries = grid[::7] + 0.5  # cell centres: 8 grid points at equal distance
    index, _ = nearest_points(grid, queries, 6, 1.0, workers=1)
    expected, _ = brute_nearest(grid, queries, 6)
    np.testing.assert_array_equal(index, expected)
    threaded, _ = nearest_points(grid, np.repeat(queries, 2000, axis=0), 6, 1.0, workers=2)
    np.testing.assert_array_equal(threaded, np.repeat(expected, 2000, axis=0))


def test_grid_nearest_with_fewer_points_than_asked() -> None:
    index, distance = nearest_points(np.eye(3), np.zeros((2, 3)), 5, 1.0)
    assert index.shape == (2, 3)
    np.testing.assert_array_equal(index, [[0, 1, 2], [0, 1, 2]])
    np.testing.assert_allclose(distance, 1.0)


def test_cone_search_gives_the_dense_scans_edges() -> None:
    # A bumpy blob, a thin slab and a torus: thick, thin and facing parts.
    blob = trimesh.creation.icosphere(subdivisions=3)
    blob.vertices *= np.random.default_rng(1).uniform(0.8, 1.2, len(blob.vertices))[:, None]
    slab = trimesh.creation.box(extents=(3.0, 2.0, 0.1)).subdivide().subdivide()
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    for mesh, count in ((blob, 600), (slab, 500), (torus, 800)):
        samples = surface_samples(mesh, count)
        for neighbours, cone_cos in ((4, 0.5), (6, 0.8)):
            expected = dense_cone_edges(
                samples.positions, samples.normals, neighbours, cone_cos, samples.radius
            )
            found = cone_neighbours(
                samples.positions, samples.normals, neighbours, cone_cos, samples.radius
            )
            assert len(expected[0]) > 0
            np.testing.assert_array_equal(found[0], expected[0])
            np.testing.assert_array_equal(found[1], expected[1])


def test_cone_search_on_an_open_flat_sheet_finds_nothing() -> None:
    sheet = trimesh.creation.box(extents=(2.0, 2.0, 1.0)).subdivide().subdivide()
    top = sheet.faces[sheet.face_normals[:, 2] > 0.99]
    samples = surface_samples(trimesh.Trimesh(sheet.vertices, top), 300)
    senders, receivers = cone_neighbours(samples.positions, samples.normals, 4, 0.5, samples.radius)
    assert len(senders) == len(receivers) == 0


def test_grid_nearest_with_far_apart_clusters_and_a_tiny_spacing() -> None:
    rng = np.random.default_rng(5)
    positions = np.concatenate([rng.random((200, 3)), 1e6 + rng.random((200, 3))])
    queries = np.concatenate([rng.random((50, 3)), 1e6 + rng.random((50, 3)), [[5e5] * 3]])
    index, distance = nearest_points(positions, queries, 3, 1e-9)
    expected_index, expected_distance = brute_nearest(positions, queries, 3)
    np.testing.assert_array_equal(index, expected_index)
    np.testing.assert_allclose(distance, expected_distance, rtol=1e-12)
