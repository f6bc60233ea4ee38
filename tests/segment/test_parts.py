"""Canonical labels, connected parts, and merging of tiny parts."""

import numpy as np
import pytest

from neural_shdf.geometry import FaceGraph
from neural_shdf.segment.parts import (
    canonical_labels,
    connected_components,
    connected_parts,
    merge_small_parts,
)


def path_graph(count: int, lengths=None) -> FaceGraph:
    pairs = np.column_stack([np.arange(count - 1), np.arange(1, count)])
    return FaceGraph(
        pairs=pairs,
        edge_vertices=np.zeros_like(pairs),
        edge_length=np.ones(count - 1) if lengths is None else np.asarray(lengths, float),
        dihedral=np.zeros(count - 1),
        concave=np.zeros(count - 1, bool),
        face_count=count,
    )


def test_canonical_labels_number_parts_by_lowest_face():
    np.testing.assert_array_equal(canonical_labels([7, 7, 3, 9, 3, 7]), [0, 0, 1, 2, 1, 0])


def test_connected_parts_split_a_label_that_is_not_connected():
    graph = path_graph(6)
    np.testing.assert_array_equal(
        connected_parts(np.array([1, 1, 2, 2, 1, 1]), graph.pairs, 6), [0, 0, 1, 1, 2, 2]
    )


def test_tiny_part_joins_the_neighbour_with_the_longest_boundary():
    # Faces 0-1 | 2 | 3-4-5 on a path; face 2 touches 1 (length 1) and 3 (length 2).
    graph = path_graph(6, lengths=[1, 1, 2, 1, 1])
    parts = np.array([0, 0, 1, 2, 2, 2])
    areas = np.array([1.0, 1.0, 0.01, 1.0, 1.0, 1.0])
    merged = merge_small_parts(parts, graph, areas, np.zeros((6, 3)), 0.05)
    np.testing.assert_array_equal(merged, [0, 0, 1, 1, 1, 1])


def test_isolated_tiny_shell_joins_the_nearest_part_and_zero_fraction_keeps_all():
    # Faces 0-1-2 connected, faces 3 and 4 isolated tiny shells; 3 is near 0, 4 near 2.
    graph = path_graph(3)
    graph = FaceGraph(
        graph.pairs, graph.edge_vertices, graph.edge_length, graph.dihedral, graph.concave, 5
    )
    parts = np.array([0, 0, 1, 2, 3])
    areas = np.array([1.0, 1.0, 1.0, 0.001, 0.001])
    centroids = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [-0.5, 0, 0], [2.5, 0, 0]], float)
    merged = merge_small_parts(parts, graph, areas, centroids, 0.01)
    np.testing.assert_array_equal(merged, [0, 0, 1, 0, 1])
    np.testing.assert_array_equal(merge_small_parts(parts, graph, areas, centroids, 0.0), parts)


def test_all_tiny_shells_stay_apart():
    graph = FaceGraph(
        np.zeros((0, 2), np.int64),
        np.zeros((0, 2), np.int64),
        np.zeros(0),
        np.zeros(0),
        np.zeros(0, bool),
        4,
    )
    merged = merge_small_parts(np.arange(4), graph, np.ones(4), np.eye(4, 3), 0.3)
    np.testing.assert_array_equal(merged, np.arange(4))


@pytest.mark.parametrize("seed", range(5))
def test_connected_parts_match_scipy_components_numbered_by_lowest_face(seed):
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(seed)
    count = 400
    pairs = rng.integers(0, count, (600, 2))
    labels = rng.integers(0, 3, count)
    keep = labels[pairs[:, 0]] == labels[pairs[:, 1]]
    matrix = sp.coo_matrix((np.ones(keep.sum()), tuple(pairs[keep].T)), shape=(count, count))
    _, components = connected_components(matrix, directed=False)
    np.testing.assert_array_equal(
        connected_parts(labels, pairs, count), canonical_labels(components)
    )


@pytest.mark.parametrize("seed", range(5))
def test_connected_parts_compare_labels_in_the_kernel_as_the_edge_mask_did(seed):
    # The earlier path: a mask of edges with equal labels, then connected_components.
    rng = np.random.default_rng(seed)
    count = 2000
    pairs = np.unique(np.sort(rng.integers(0, count, (5000, 2)), axis=1), axis=0)
    for labels in (rng.integers(-2, 4, count), rng.integers(0, 10**9, count) * 7):
        keep = labels[pairs[:, 0]] == labels[pairs[:, 1]]
        np.testing.assert_array_equal(
            connected_parts(labels, pairs, count), connected_components(pairs, keep, count)
        )


def test_connected_parts_refuse_labels_for_fewer_faces_than_the_graph():
    with pytest.raises(IndexError):
        connected_parts(np.zeros(3, dtype=np.int64), np.array([[0, 5]]), 6)


@pytest.mark.parametrize(
    "labels",
    [
        np.array([7, 7, 3, 9, 3, 7]),
        np.array([-1, 5, -1, 2]),
        np.array([10**12, 4, 10**12]),  # a wide range takes the sorting path
        np.array([2.5, 1.0, 2.5]),
    ],
)
def test_canonical_labels_follow_first_appearance_for_any_labels(labels):
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    expected = np.argsort(np.argsort(first))[inverse]
    np.testing.assert_array_equal(canonical_labels(labels), expected)
