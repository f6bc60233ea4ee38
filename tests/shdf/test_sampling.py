"""Poisson-disk samples of a surface and values carried between samples and faces."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from neural_shdf.geometry import face_normals
from neural_shdf.shdf.neural.graph import GraphSpec, build_sample_graph
from neural_shdf.shdf.sampling import (
    greedy_disk_selection,
    sample_surface_points,
    smooth_samples,
    vertex_normal_sums,
)


def sequential_disk_selection(points: np.ndarray, radius: float) -> list[int]:
    """Reference dart thrower: keep a point if no kept point is closer than radius."""
    kept: list[int] = []
    for i, p in enumerate(points):
        if all(np.linalg.norm(points[j] - p) >= radius for j in kept):
            kept.append(i)
    return kept


def test_greedy_selection_matches_sequential_dart_throwing() -> None:
    points = np.random.default_rng(3).random((400, 3))
    kept = greedy_disk_selection(points, 0.12)
    assert kept.tolist() == sequential_disk_selection(points, 0.12)


def test_greedy_selection_is_linear_when_candidates_pile_up() -> None:
    # 200k candidates within one radius of each other (a surface repeated in place):
    # 2e10 conflict pairs, which the selection must never list.
    points = np.random.default_rng(4).random((200_000, 3)) * 0.01
    assert greedy_disk_selection(points, 1.0).tolist() == [0]
    spread = np.random.default_rng(5).random((3000, 3))
    assert greedy_disk_selection(np.repeat(spread, 20, axis=0), 0.1).tolist() == [
        20 * i for i in sequential_disk_selection(spread, 0.1)
    ]


def test_greedy_selection_on_a_grid_too_fine_for_cell_coordinates() -> None:
    points = np.random.default_rng(6).random((300, 3))
    points[0] = [1e15, 0, 0]  # span / radius beyond the grid's integer range
    kept = greedy_disk_selection(points, 1e-3)
    assert kept.tolist() == sequential_disk_selection(points, 1e-3)


def test_the_network_s_samples_are_the_sampler_s() -> None:
    """One sampler: the neural graph's samples are those of ``sample_surface_points``,
    deterministic for a seed and at least one Poisson radius apart."""
    sphere = trimesh.creation.icosphere(subdivisions=4)
    samples = sample_surface_points(sphere.vertices, sphere.faces, 400, seed=5)
    again = sample_surface_points(sphere.vertices, sphere.faces, 400, seed=5)
    graph = build_sample_graph(sphere.vertices, sphere.faces, GraphSpec(target_samples=400), seed=5)
    np.testing.assert_array_equal(samples.positions, again.positions)
    np.testing.assert_array_equal(samples.positions, graph.positions)
    np.testing.assert_array_equal(samples.vertex_samples, graph.vertex_samples)
    distance = np.linalg.norm(samples.positions[:, None] - samples.positions[None], axis=2)
    np.fill_diagonal(distance, np.inf)
    assert distance.min() >= samples.radius * (1 - 1e-9)


def test_vertex_normal_sums_are_area_weighted_sums_around_each_vertex() -> None:
    mesh = trimesh.creation.icosphere(subdivisions=2)
    normals, areas = face_normals(mesh.vertices, mesh.faces)
    sums = vertex_normal_sums(len(mesh.vertices), mesh.faces, normals, areas)
    for vertex in (0, 17, 100):
        around = np.flatnonzero((mesh.faces == vertex).any(axis=1))
        np.testing.assert_allclose(sums[vertex], (normals[around] * areas[around, None]).sum(0))
    with pytest.raises(IndexError):
        vertex_normal_sums(3, mesh.faces, normals, areas)


def test_sample_smoothing_keeps_steps_and_constants() -> None:
    rng = np.random.default_rng(0)
    positions = rng.random((400, 3)) * [10.0, 1.0, 0.0]
    normals = np.tile([0.0, 0.0, 1.0], (400, 1))
    constant = np.full(400, 2.0)
    np.testing.assert_array_equal(
        smooth_samples(constant, positions, normals, radius=1.0, spatial_sigma=0.5), constant
    )
    step = np.where(positions[:, 0] < 5.0, 1.0, 3.0) + rng.normal(0, 0.05, 400)
    smoothed = smooth_samples(step, positions, normals, radius=1.0, spatial_sigma=0.5)
    far = np.abs(positions[:, 0] - 5.0) > 1.0
    assert np.std(smoothed[far & (positions[:, 0] < 5)]) < np.std(step[far & (positions[:, 0] < 5)])
    assert np.all(np.abs(smoothed[far] - np.round(step[far])) < 0.2)  # no bleeding across
    flipped = normals.copy()
    flipped[::2] *= -1  # the other side of a wall never mixes in
    lone = smooth_samples(step, positions, flipped, radius=1.0, spatial_sigma=0.5)
    assert np.abs(lone - smoothed).max() > 0
