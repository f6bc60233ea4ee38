"""Boundary refinement onto concave creases: misplaced boundaries move, parts survive."""

import heapq
import math
from dataclasses import replace

import numpy as np
import pytest

from neural_shdf.geometry import (
    adjacency_lists,
    build_face_graph,
    face_centroids,
    face_normals,
    weld_faces,
)
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment.creases import (
    _band_costs,
    _dijkstra,
    crease_capacities,
    crease_graph,
    snap_boundaries_to_creases,
)
from neural_shdf.segment.from_shdf import prepare_segment, segment
from neural_shdf.segment.params import SegmentParams
from neural_shdf.segment.parts import canonical_labels
from neural_shdf.segment.synthetic import JUNCTION_Z, dumbbell, dumbbell_radius


def case(faces: int, ripple: float = 0.0):
    mesh, shdf = dumbbell(faces, ripple)
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    normals, areas = face_normals(vertices, triangles)
    graph = build_face_graph(vertices, weld_faces(vertices, triangles), normals)
    return vertices, triangles, shdf, graph, areas, face_centroids(vertices, triangles)


@pytest.fixture(scope="module")
def dumbbell_case():
    return case(6000)


def details(vertices, faces, shdf, params):
    """The segmentation of the triangles ``faces`` over ``vertices``."""
    return segment(TriangleMesh(vertices, faces), shdf, params)


def junction_errors(labels, z):
    """Faces on the wrong side of the upper ball's concave junction (1 = the ball)."""
    ball = z > JUNCTION_Z + 0.02
    neck = (z < JUNCTION_Z - 0.02) & (z > 0)
    return int(np.sum(labels[ball] != 1) + np.sum(labels[neck] != 0))


@pytest.mark.parametrize("offset", [0.25, -0.12])
def test_a_misplaced_boundary_moves_onto_the_concave_crease(dumbbell_case, offset):
    _, _, _, graph, areas, centroids = dumbbell_case
    z = centroids[:, 2]
    # Two parts: the upper ball and the rest, cut `offset` off the neck's junction.
    misplaced = (z > JUNCTION_Z + offset).astype(np.int64)
    assert junction_errors(misplaced, z) > 50
    snapped = snap_boundaries_to_creases(misplaced, graph, areas, centroids, 0.002)
    assert snapped.max() == 1
    assert junction_errors(snapped, z) == 0


def test_large_meshes_are_solved_on_coarse_nodes_that_keep_the_crease():
    _, _, _, graph, areas, centroids = case(24000)
    z = centroids[:, 2]
    misplaced = (z > JUNCTION_Z + 0.25).astype(np.int64)
    creases = crease_graph(graph, areas, centroids, coarse_above=10_000, coarse_nodes=2_000)
    assert creases.node_of is not None and creases.graph.face_count < 6_000
    coarse = snap_boundaries_to_creases(misplaced, graph, areas, centroids, 0.002, creases=creases)
    assert junction_errors(coarse, z) == 0
    np.testing.assert_array_equal(coarse, canonical_labels(coarse))
    # A boundary already on the crease stays face for face: unmoved nodes keep their faces.
    on_crease = (z > JUNCTION_Z).astype(np.int64)
    kept = snap_boundaries_to_creases(on_crease, graph, areas, centroids, 0.002, creases=creases)
    np.testing.assert_array_equal(kept, on_crease)


def test_a_boundary_on_the_crease_stays(dumbbell_case):
    _, _, _, graph, areas, centroids = dumbbell_case
    on_crease = (centroids[:, 2] > JUNCTION_Z).astype(np.int64)
    snapped = snap_boundaries_to_creases(on_crease, graph, areas, centroids, 0.002)
    np.testing.assert_array_equal(snapped, on_crease)


def test_concave_edges_are_cheap_and_convex_ones_cost_their_length(dumbbell_case):
    graph = dumbbell_case[3]
    capacity = crease_capacities(graph)
    concave = graph.concave & (graph.dihedral > 0.1)
    assert np.all(capacity[concave] < 0.5 * graph.edge_length[concave])
    np.testing.assert_allclose(capacity[~graph.concave], graph.edge_length[~graph.concave])


def test_a_small_part_inside_the_band_survives(dumbbell_case):
    _, _, _, graph, areas, centroids = dumbbell_case
    # A cap on the upper ball, far narrower than the band width: no part vanishes.
    cap = (centroids[:, 2] > 2.9).astype(np.int64)
    snapped = snap_boundaries_to_creases(cap, graph, areas, centroids, 0.0)
    assert snapped.max() == 1
    assert 0 < np.sum(snapped == 1) <= 2 * np.sum(cap == 1)


def test_refinement_is_deterministic_and_keeps_labels_in_face_order():
    vertices, faces, shdf, graph, areas, _ = case(5000, ripple=0.05)
    params = SegmentParams(crease_boundaries=True, smoothing=0.02)
    first = details(vertices, faces, shdf, params)
    again = details(vertices, faces, shdf, params)
    np.testing.assert_array_equal(first.tree.leaf_labels, again.tree.leaf_labels)
    # The same mesh with its faces in another order: the same parts, per face.
    order = np.random.default_rng(0).permutation(len(faces))
    shuffled_faces = faces[order]
    shuffled = details(vertices, shuffled_faces, shdf[order], params)
    np.testing.assert_array_equal(
        shuffled.tree.leaf_labels, canonical_labels(first.tree.leaf_labels[order])
    )


def test_every_cut_of_the_tree_has_the_refined_boundaries(dumbbell_case):
    vertices, faces, _, graph, areas, centroids = dumbbell_case
    # The ShDF's steps 0.2 off the concave creases: the refinement has boundaries to move.
    shdf = dumbbell_radius(centroids[:, 2] + 0.2)
    shdf = (shdf - shdf.min()) / (shdf.max() - shdf.min())
    params = SegmentParams(crease_boundaries=True, smoothing=0.02)
    whole = details(vertices, faces, shdf, params)
    plain = details(vertices, faces, shdf, replace(params, crease_boundaries=False))
    assert "crease_boundaries" in whole.timings
    assert not np.array_equal(whole.tree.leaf_labels, plain.tree.leaf_labels)
    for parts in range(1, whole.tree.leaf_count + 1):
        asked = details(vertices, faces, shdf, replace(params, parts=parts))
        np.testing.assert_array_equal(asked.tree.leaf_labels, whole.tree.leaf_labels)
        np.testing.assert_array_equal(asked.labels, whole.tree.labels(parts))


def test_the_mesh_s_crease_graph_serves_every_mixture_of_the_mesh(dumbbell_case):
    vertices, faces, shdf, graph, areas, centroids = dumbbell_case
    mesh = TriangleMesh(vertices, faces)
    creases = mesh.crease_graph  # built once per mesh
    for clusters in (3, 5):
        params = SegmentParams(clusters=clusters, smoothing=0.02, crease_boundaries=True)
        basis = prepare_segment(mesh, shdf, params)
        kept = segment(mesh, shdf, params, basis=basis)
        plain = segment(mesh, shdf, replace(params, crease_boundaries=False))
        expected = snap_boundaries_to_creases(
            plain.tree.leaf_labels, graph, areas, centroids, 0.002, creases=creases
        )
        assert mesh.crease_graph is creases
        np.testing.assert_array_equal(kept.tree.leaf_labels, expected)


def test_coarse_crease_nodes_are_the_same_in_any_pose():
    from scipy.spatial.transform import Rotation

    mesh, _ = dumbbell(6000)
    # Wider along x: the mesh's axes are defined (a body of revolution's are not).
    vertices, triangles = np.asarray(mesh.vertices) * (1.4, 1.0, 1.0), np.asarray(mesh.faces)
    normals, areas = face_normals(vertices, triangles)
    graph = build_face_graph(vertices, weld_faces(vertices, triangles), normals)
    centroids = face_centroids(vertices, triangles)
    rotation = Rotation.random(random_state=6).as_matrix()
    moved = face_centroids(2.0 * vertices @ rotation.T - 50.0, triangles)
    kept = crease_graph(graph, areas, centroids, coarse_above=2_000, coarse_nodes=500)
    turned = crease_graph(graph, 4.0 * areas, moved, coarse_above=2_000, coarse_nodes=500)
    assert kept.node_of is not None and kept.graph.face_count < 1_500
    np.testing.assert_array_equal(turned.node_of, kept.node_of)
    expected = 2.0 * kept.centroids @ rotation.T - 50.0
    np.testing.assert_allclose(turned.centroids, expected, atol=1e-9)


def tuple_heap_dijkstra(indptr, neighbour, centroids, parts, seed_boundary, low, high, limit):
    """The band search as it was written with Python's heapq over (distance, node,
    boundary) tuples: the array heap must give the same distances and owners."""
    count, none = len(parts), len(limit)
    distance = np.full(count, np.inf)
    owner = np.full(count, -1, dtype=np.int64)
    done = np.zeros(count, dtype=bool)
    heap = []
    for face in range(count):
        if seed_boundary[face] < none:
            distance[face], owner[face] = 0.0, seed_boundary[face]
            heap.append((0.0, face, int(seed_boundary[face])))
    heapq.heapify(heap)
    while heap:
        d, face, boundary = heapq.heappop(heap)
        if done[face]:
            continue
        done[face] = True
        if d > limit[boundary]:
            continue
        for other in neighbour[indptr[face] : indptr[face + 1]]:
            if done[other] or parts[other] not in (low[boundary], high[boundary]):
                continue
            dx, dy, dz = centroids[face] - centroids[other]
            candidate = d + math.sqrt(dx * dx + dy * dy + dz * dz)
            if candidate < distance[other] or (
                candidate == distance[other] and boundary < owner[other]
            ):
                distance[other], owner[other] = candidate, boundary
                heapq.heappush(heap, (candidate, int(other), boundary))
    return distance, owner


@pytest.mark.parametrize("seed", range(4))
def test_band_search_matches_the_tuple_heap_it_replaced(seed):
    # Grid centroids: many exactly equal distances, so ties between boundaries decide.
    rng = np.random.default_rng(seed)
    count = 600
    centroids = rng.integers(0, 6, (count, 3)).astype(np.float64)
    pairs = np.unique(np.sort(rng.integers(0, count, (2400, 2)), axis=1), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    indptr, neighbour = adjacency_lists(pairs, count)
    parts = rng.integers(0, 4, count)
    boundaries = np.array([[0, 1], [0, 2], [1, 3], [2, 3], [1, 2]])
    seed_boundary = np.where(rng.random(count) < 0.1, rng.integers(0, 5, count), 5)
    limit = rng.uniform(2.0, 12.0, 5)
    arguments = (indptr, neighbour, centroids, parts, seed_boundary)
    arguments += (boundaries[:, 0].copy(), boundaries[:, 1].copy(), limit)
    distance, owner = _dijkstra(*arguments)
    expected_distance, expected_owner = tuple_heap_dijkstra(*arguments)
    np.testing.assert_array_equal(distance, expected_distance)
    np.testing.assert_array_equal(owner, expected_owner)


@pytest.mark.parametrize("seed", range(4))
def test_band_costs_match_the_add_at_folding_they_replaced(seed):
    rng = np.random.default_rng(seed)
    count = 400
    pairs = np.unique(np.sort(rng.integers(0, count, (1600, 2)), axis=1), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    capacity = 10.0 ** rng.uniform(-3, 3, len(pairs))  # sums that round
    parts = rng.integers(0, 4, count)
    owner = rng.integers(0, 3, count)
    in_band = rng.random(count) < 0.6
    nodes = np.flatnonzero(in_band)
    local = np.full(count, -1, dtype=np.int64)
    local[nodes] = np.arange(len(nodes))
    low_part, high_part = rng.integers(0, 2, len(nodes)), rng.integers(2, 4, len(nodes))
    start_low, start_high = rng.random(len(nodes)), rng.random(len(nodes))
    cost_low, cost_high = start_low.copy(), start_high.copy()
    inside = _band_costs(
        cost_low, cost_high, in_band, owner, local, parts, low_part, high_part, pairs, capacity
    )
    # The numpy folding ``_min_cut_in_bands`` used before, bit for bit.
    a, b = pairs[:, 0], pairs[:, 1]
    band_a, band_b = in_band[a], in_band[b]
    same_band = band_a & band_b & (owner[a] == owner[b])
    expected_low, expected_high = start_low.copy(), start_high.copy()
    for inner, outer, mask in ((a, b, band_a & ~same_band), (b, a, band_b & ~same_band)):
        edges = np.flatnonzero(mask)
        rows = local[inner[edges]]
        other = parts[outer[edges]]
        weight = capacity[edges]
        np.add.at(expected_low, rows, np.where(other != low_part[rows], weight, 0.0))
        np.add.at(expected_high, rows, np.where(other != high_part[rows], weight, 0.0))
    np.testing.assert_array_equal(cost_low, expected_low)
    np.testing.assert_array_equal(cost_high, expected_high)
    np.testing.assert_array_equal(inside, np.flatnonzero(same_band))
