"""The neural ShDF's input graph: Poisson sampling, density, edges, mapping back to faces."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import InvalidGeometryError
from neural_shdf.geometry import face_centroids, face_normals
from neural_shdf.shdf.neural.graph import (
    EDGE_FEATURES,
    GraphSpec,
    build_sample_graph,
    sample_targets,
)
from neural_shdf.shdf.sampling import resample, samples_to_faces

SPEC = GraphSpec(target_samples=400, knn=8, cone_neighbours=3)


def test_samples_are_poisson_disk_and_deterministic() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=4)
    graph = build_sample_graph(sphere.vertices, sphere.faces, SPEC, seed=5)
    again = build_sample_graph(sphere.vertices, sphere.faces, SPEC, seed=5)
    other = build_sample_graph(sphere.vertices, sphere.faces, SPEC, seed=6)
    np.testing.assert_array_equal(graph.positions, again.positions)
    assert not np.array_equal(graph.positions, other.positions[: len(graph.positions)])
    distance = np.linalg.norm(graph.positions[:, None] - graph.positions[None], axis=2)
    np.fill_diagonal(distance, np.inf)
    assert distance.min() >= graph.radius * (1 - 1e-9)
    assert 0.75 * SPEC.target_samples < graph.sample_count < 1.25 * SPEC.target_samples
    # Samples lie on the sphere (radius 1) and carry their face's normal.
    np.testing.assert_allclose(np.linalg.norm(graph.positions, axis=1), 1.0, atol=0.02)
    normals, _ = face_normals(sphere.vertices, sphere.faces)
    np.testing.assert_allclose(graph.normals, normals[graph.face_ids])


def test_density_depends_on_area_not_on_tessellation() -> None:
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    fine = box.subdivide().subdivide().subdivide()
    coarse_graph = build_sample_graph(box.vertices, box.faces, SPEC, seed=0)
    fine_graph = build_sample_graph(fine.vertices, fine.faces, SPEC, seed=0)
    assert abs(coarse_graph.density.mean() - fine_graph.density.mean()) < 0.05
    assert abs(np.median(fine_graph.density) - 1.0) < 0.15  # flat faces: one disk


def test_cone_edges_cross_a_thin_slab() -> None:
    thickness = 0.1
    slab = trimesh.creation.box(extents=(4.0, 4.0, thickness)).subdivide().subdivide()
    graph = build_sample_graph(slab.vertices, slab.faces, SPEC, seed=1)
    cone = graph.edge_features[:, EDGE_FEATURES.index("is_cone_edge")] == 1
    assert cone.any()
    s, r = graph.senders[cone], graph.receivers[cone]
    big_faces = np.abs(graph.normals[r, 2]) > 0.99
    gap = np.abs(graph.positions[s] - graph.positions[r])[big_faces, 2]
    # The other side of the slab, not a neighbour on the same face.
    np.testing.assert_allclose(np.median(gap), thickness, rtol=1e-6)


def test_features_are_rotation_and_scale_invariant() -> None:
    # A bumpy blob: no symmetric ties that rounding could break either way.
    mesh = trimesh.creation.icosphere(subdivisions=3)
    bumps = np.random.default_rng(0).uniform(0.8, 1.2, len(mesh.vertices))
    mesh.vertices = mesh.vertices * bumps[:, None] * np.array([1.0, 0.5, 0.3])
    rotation = trimesh.transformations.random_rotation_matrix(np.array([0.1, 0.7, 0.3]))
    moved = mesh.copy()
    moved.apply_transform(rotation)
    moved.apply_scale(3.0)
    a = build_sample_graph(mesh.vertices, mesh.faces, SPEC, seed=2)
    b = build_sample_graph(moved.vertices, moved.faces, SPEC, seed=2)
    np.testing.assert_array_equal(a.face_ids, b.face_ids)
    np.testing.assert_allclose(a.node_features, b.node_features, atol=1e-5)
    order_a = np.lexsort((a.senders, a.receivers))
    order_b = np.lexsort((b.senders, b.receivers))
    np.testing.assert_allclose(a.edge_features[order_a], b.edge_features[order_b], atol=1e-4)
    assert b.radius == pytest.approx(3.0 * a.radius)


def test_samples_to_faces_keeps_walls_apart() -> None:
    slab = trimesh.creation.box(extents=(4.0, 4.0, 0.6))
    for _ in range(4):
        slab = slab.subdivide()
    graph = build_sample_graph(slab.vertices, slab.faces, SPEC, seed=0)
    normals, _ = face_normals(slab.vertices, slab.faces)
    bottom = graph.normals[:, 2] < -0.99
    values = np.where(bottom, 0.0, 1.0)
    faces = samples_to_faces(values, graph, slab.faces)
    centroids = face_centroids(slab.vertices, slab.faces)
    inner = np.all(np.abs(centroids[:, :2]) < 1.2, axis=1)  # away from the slab's sides
    top_faces = (normals[:, 2] > 0.99) & inner
    bottom_faces = (normals[:, 2] < -0.99) & inner
    np.testing.assert_allclose(faces[top_faces], 1.0)
    np.testing.assert_allclose(faces[bottom_faces], 0.0)
    constant = samples_to_faces(np.full(graph.sample_count, 2.5), graph, slab.faces)
    np.testing.assert_allclose(constant, 2.5, rtol=1e-6)


def test_sample_targets_are_area_weighted_means() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=3)
    graph = build_sample_graph(sphere.vertices, sphere.faces, SPEC, seed=0)
    _, areas = face_normals(sphere.vertices, sphere.faces)
    centroids = face_centroids(sphere.vertices, sphere.faces)
    values = np.random.default_rng(0).random(len(sphere.faces))
    values[::7] = np.nan
    targets = sample_targets(values, areas, centroids, graph)
    distance = np.linalg.norm(centroids[:, None] - graph.positions[None], axis=2)
    nearest = distance.argmin(axis=1)
    sample = int(nearest[1])
    mine = (nearest == sample) & np.isfinite(values)
    expected = np.sum(areas[mine] * values[mine]) / np.sum(areas[mine])
    assert targets[sample] == pytest.approx(expected)


def test_flipped_faces_do_not_flip_sample_normals() -> None:
    sphere = trimesh.creation.icosphere(subdivisions=4)
    faces = sphere.faces.copy()
    flipped = np.random.default_rng(1).random(len(faces)) < 0.2
    faces[flipped] = faces[flipped][:, ::-1]
    damaged = build_sample_graph(sphere.vertices, faces, SPEC, seed=4)
    assert np.any(flipped[damaged.face_ids])
    # Sample normals still point out of the unit sphere (20 % would not, uncorrected).
    outward = np.einsum("ij,ij->i", damaged.normals, damaged.positions)
    assert np.mean(outward > 0) >= 0.98


def test_degenerate_mesh_is_rejected() -> None:
    vertices = np.zeros((3, 3))
    with pytest.raises(InvalidGeometryError):
        build_sample_graph(vertices, np.array([[0, 1, 2]]), SPEC)


def test_resample_carries_values_between_sample_sets_without_crossing_walls() -> None:
    slab = trimesh.creation.box(extents=(4.0, 4.0, 0.6))
    for _ in range(4):
        slab = slab.subdivide()
    source = build_sample_graph(slab.vertices, slab.faces, SPEC, seed=0, map_vertices=False)
    target = build_sample_graph(slab.vertices, slab.faces, SPEC, seed=1)
    assert source.vertex_samples.size == 0
    assert not np.array_equal(source.positions, target.positions)
    # A smooth field: interpolated closely; a field that jumps across the wall: kept apart.
    smooth = resample(source.positions[:, 0], source, target, neighbours=4)
    inner = np.all(np.abs(target.positions[:, :2]) < 1.5, axis=1)  # IDW cannot extrapolate
    np.testing.assert_allclose(smooth[inner], target.positions[inner, 0], atol=0.6 * source.radius)
    sides = resample(np.where(source.normals[:, 2] < -0.99, 0.0, 1.0), source, target, 4)
    np.testing.assert_array_equal(sides[target.normals[:, 2] < -0.99], 0.0)
    np.testing.assert_array_equal(sides[target.normals[:, 2] > 0.99], 1.0)
