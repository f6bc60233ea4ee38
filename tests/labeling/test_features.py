"""Node graph and features: independent of pose, scale and tessellation."""

from __future__ import annotations

import numpy as np

from neural_shdf.labeling.features import FEATURE_NAMES, FeatureSpec, node_features, node_graph
from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import compute_shdf
from tests.labeling.helpers import labelled_dumbbell


def face_features(mesh: TriangleMesh) -> np.ndarray:
    """Each face's node features (exact ShDF)."""
    graph = mesh.face_graph
    nodes = node_graph(mesh, graph, FeatureSpec(samples=400))
    shdf = compute_shdf(mesh, method="exact").values
    return node_features(nodes, shdf, mesh.normals_and_areas[1])[nodes.face_node]


def test_every_face_has_a_node_and_the_cells_cover_the_surface() -> None:
    mesh, _ = labelled_dumbbell(1500)
    nodes = node_graph(mesh, mesh.face_graph, FeatureSpec(samples=300))
    assert nodes.face_node.min() >= 0 and nodes.face_node.max() == nodes.node_count - 1
    assert 150 < nodes.node_count <= 300
    np.testing.assert_allclose(nodes.cell_area.sum(), 1.0)
    assert np.isfinite(nodes.distances).all()  # one shell: every node reaches every node
    # A node's own face lies in its own cell.
    assert np.array_equal(nodes.face_node[nodes.node_faces], np.arange(nodes.node_count))


def test_features_do_not_change_with_pose_and_scale() -> None:
    mesh, _ = labelled_dumbbell(1500)
    moved, _ = labelled_dumbbell(1500, seed=3)
    scaled = TriangleMesh(moved.vertices * 7.5, moved.faces)
    original, other = face_features(mesh), face_features(scaled)
    assert original.shape == (mesh.face_count, len(FEATURE_NAMES))
    for column, name in enumerate(FEATURE_NAMES):
        a, b = original[:, column], other[:, column]
        spread = max(float(np.ptp(a)), 1e-6)
        # Samples differ with the pose: compare per face, within a share of the range.
        assert np.median(np.abs(a - b)) < 0.1 * spread, name


def area_quantiles(values: np.ndarray, areas: np.ndarray, q: list[float]) -> np.ndarray:
    order = np.argsort(values)
    cumulative = np.cumsum(areas[order]) / areas.sum()
    return values[order][np.searchsorted(cumulative, q)]


def test_features_do_not_change_with_tessellation() -> None:
    coarse, _ = labelled_dumbbell(1500)
    fine, _ = labelled_dumbbell(6000)
    a, b = face_features(coarse), face_features(fine)
    coarse_area, fine_area = coarse.normals_and_areas[1], fine.normals_and_areas[1]
    for column, name in enumerate(FEATURE_NAMES):
        spread = max(float(np.ptp(a[:, column])), 1e-6)
        low_high = area_quantiles(a[:, column], coarse_area, [0.2, 0.8])
        fine_low_high = area_quantiles(b[:, column], fine_area, [0.2, 0.8])
        assert np.abs(low_high - fine_low_high).max() < 0.15 * spread, name
