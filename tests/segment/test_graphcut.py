"""Alpha-expansion: each move is the optimal expansion (brute force), energies only go down."""

import itertools

import numpy as np
import pytest
import trimesh

from neural_shdf.geometry import (
    adjacency_with_edges,
    build_face_graph,
    face_centroids,
    face_normals,
    midpoint_subdivide,
)
from neural_shdf.segment.graphcut import (
    ANGLE_EPS,
    COARSE_NODES,
    LAMBDA_SCALE,
    MAX_CYCLES,
    SMOOTHED_COARSE_NODES,
    SMOOTHED_TOP_CYCLES,
    _band_problem,
    alpha_expansion,
    banded_alpha_expansion,
    coarse_data,
    coarse_graph,
    cut_hierarchy,
    dihedral_weights,
    expansion_move,
    label_reach,
    labelling_energy,
    multilevel_alpha_expansion,
    near_boundary,
    smoothed_preference,
)


def random_problem(seed: int, nodes: int = 9, labels: int = 3):
    rng = np.random.default_rng(seed)
    pairs = np.array(
        [(i, j) for i in range(nodes) for j in range(i + 1, nodes) if rng.random() < 0.4]
    )
    pairs = pairs.reshape(-1, 2)
    weights = rng.uniform(0.1, 2.0, len(pairs))
    data = rng.uniform(0.0, 3.0, (nodes, labels))
    start = rng.integers(0, labels, nodes)
    return data, pairs, weights, start


@pytest.mark.parametrize("seed", range(6))
def test_expansion_move_is_the_best_expansion(seed):
    data, pairs, weights, start = random_problem(seed)
    for alpha in range(data.shape[1]):
        moved = expansion_move(start, alpha, data, pairs, weights)
        best = min(
            labelling_energy(np.where(np.array(switch, bool), alpha, start), data, pairs, weights)
            for switch in itertools.product((0, 1), repeat=len(start))
        )
        assert labelling_energy(moved, data, pairs, weights) == pytest.approx(best)
        assert set(np.flatnonzero(moved != start)) <= set(np.flatnonzero(start != alpha))


@pytest.mark.parametrize("seed", range(4))
def test_alpha_expansion_never_raises_energy_and_beats_each_single_move(seed):
    data, pairs, weights, start = random_problem(seed, nodes=30, labels=4)
    result = alpha_expansion(data, pairs, weights, start)
    energy = labelling_energy(result, data, pairs, weights)
    assert energy <= labelling_energy(start, data, pairs, weights) + 1e-9
    # A local minimum: no expansion move improves it.
    for alpha in range(4):
        moved = expansion_move(result, alpha, data, pairs, weights)
        assert labelling_energy(moved, data, pairs, weights) >= energy - 1e-9


def test_banded_solve_changes_only_the_band():
    data, pairs, weights, start = random_problem(3, nodes=30, labels=3)
    band = np.zeros(30, dtype=bool)
    band[:12] = True
    result = banded_alpha_expansion(data[band], pairs, weights, start, band)
    np.testing.assert_array_equal(result[~band], start[~band])
    assert (
        labelling_energy(result, data, pairs, weights)
        <= labelling_energy(start, data, pairs, weights) + 1e-9
    )


@pytest.mark.parametrize("seed", range(6))
def test_expansion_move_with_allowed_nodes_is_the_best_of_their_expansions(seed):
    data, pairs, weights, start = random_problem(seed)
    allowed = np.random.default_rng(seed).random(len(start)) < 0.6
    for alpha in range(data.shape[1]):
        moved = expansion_move(start, alpha, data, pairs, weights, allowed)
        best = min(
            labelling_energy(np.where(np.array(switch, bool), alpha, start), data, pairs, weights)
            for switch in itertools.product((0, 1), repeat=len(start))
            if not np.any(np.array(switch, bool) & ~allowed)
        )
        assert labelling_energy(moved, data, pairs, weights) == pytest.approx(best)
        assert set(np.flatnonzero(moved != start)) <= set(np.flatnonzero(allowed))


def test_label_reach_counts_hops_through_the_band():
    # A path 0-1-...-9; the band is 2..8, label 3 at node 0 (outside), 1 at node 9 (outside).
    pairs = np.array([(i, i + 1) for i in range(9)])
    labels = np.array([3, 0, 0, 0, 0, 0, 0, 2, 0, 1])
    band = np.zeros(10, dtype=bool)
    band[2:9] = True
    nodes = np.flatnonzero(band)
    local = np.full(10, -1)
    local[nodes] = np.arange(len(nodes))
    inside = pairs[band[pairs[:, 0]] & band[pairs[:, 1]]]
    reach = label_reach(labels, nodes, band, pairs, local[inside], 4, 1)
    # One hop: node 2 has and borders 0 (nodes 1, 3); node 8 borders 1 (node 9) and is
    # beside node 7 (2).
    assert reach[local[2]].tolist() == [True, False, False, False]
    assert reach[local[8]].tolist() == [True, True, True, False]
    assert reach[local[6]].tolist() == [True, False, True, False]
    # Label 3 (node 0, outside, beside node 1 outside) borders no band node.
    assert not reach[:, 3].any()
    far = label_reach(labels, nodes, band, pairs, local[inside], 4, 6)
    assert far[:, :3].all() and far[local[2], 1]


def test_banded_solve_with_label_hops_keeps_far_labels_out():
    # A path of 12 nodes: node 0 labelled 2, nodes 1..10 (the band) 0, node 11 1; every
    # node prefers label 2. Unrestricted, the whole band takes 2; with one hop only node 1
    # (bordering node 0) and node 2 (beside it) can (the others keep 0 or take 1).
    count = 12
    pairs = np.array([(i, i + 1) for i in range(count - 1)])
    weights = np.full(len(pairs), 0.1)
    data = np.tile([1.0, 1.0, 0.5], (count, 1))
    labels = np.zeros(count, dtype=np.int64)
    labels[0], labels[-1] = 2, 1
    band = np.zeros(count, dtype=bool)
    band[1:11] = True
    free = banded_alpha_expansion(data[band], pairs, weights, labels, band)
    assert (free[1:11] == 2).all()
    held = banded_alpha_expansion(data[band], pairs, weights, labels, band, label_hops=1)
    assert (held[1:3] == 2).all() and (held[3:11] != 2).all()
    assert labelling_energy(held, data, pairs, weights) < labelling_energy(
        labels, data, pairs, weights
    )


def bincount_band_problem(band_data, pairs, weights, labels, band):
    """The band's sub-problem as ``banded_alpha_expansion`` built it with numpy before
    ``_band_problem`` (the reference for the float sums)."""
    nodes = np.flatnonzero(band)
    local = np.full(len(labels), -1, dtype=np.int64)
    local[nodes] = np.arange(len(nodes))
    sub_data = np.array(band_data, dtype=np.float64)
    a, b = pairs[:, 0], pairs[:, 1]
    label_count = sub_data.shape[1]
    for inner, outer in ((a, b), (b, a)):
        edge = np.flatnonzero(band[inner] & ~band[outer])
        rows = local[inner[edge]]
        sub_data += np.bincount(rows, weights=weights[edge], minlength=len(nodes))[:, None]
        cell = rows * label_count + labels[outer[edge]]
        sub_data -= np.bincount(cell, weights=weights[edge], minlength=sub_data.size).reshape(
            sub_data.shape
        )
    inside = np.flatnonzero(band[a] & band[b])
    touching = np.flatnonzero(band[a] != band[b])
    alphas = np.union1d(labels[nodes], labels[pairs[touching].reshape(-1)])
    return sub_data, local[pairs[inside]], weights[inside], alphas


@pytest.mark.parametrize("seed", range(4))
def test_band_problem_matches_the_bincount_folding_it_replaced(seed):
    data, pairs, weights, start = random_problem(seed, nodes=60, labels=5)
    rng = np.random.default_rng(seed)
    weights = weights * 10.0 ** rng.uniform(-3, 3, len(weights))  # sums that round
    band = rng.random(60) < 0.5
    nodes = np.flatnonzero(band)
    got = _band_problem(data[band].copy(), nodes, band, start, pairs, weights)
    expected = bincount_band_problem(data[band], pairs, weights, start, band)
    for array, reference in zip(got, expected, strict=True):
        np.testing.assert_array_equal(array, reference)  # bit for bit


def test_near_boundary_grows_by_rings():
    # A path 0-1-2-...-9 with the label changing between 4 and 5.
    pairs = np.column_stack([np.arange(9), np.arange(1, 10)])
    labels = (np.arange(10) >= 5).astype(np.int64)
    np.testing.assert_array_equal(np.flatnonzero(near_boundary(labels, pairs, 10, 1)), [4, 5])
    np.testing.assert_array_equal(
        np.flatnonzero(near_boundary(labels, pairs, 10, 3)), [2, 3, 4, 5, 6, 7]
    )


def test_dihedral_weights_follow_cgal():
    from neural_shdf.geometry import FaceGraph

    angles = np.array([0.0, np.pi / 2, np.pi / 2])
    graph = FaceGraph(
        pairs=np.array([[0, 1], [1, 2], [2, 3]]),
        edge_vertices=np.zeros((3, 2), dtype=np.int64),
        edge_length=np.ones(3),
        dihedral=angles,
        concave=np.array([False, True, False]),
        face_count=4,
    )
    weights = dihedral_weights(graph, 0.26)
    scale = 0.26 * LAMBDA_SCALE
    np.testing.assert_allclose(
        weights, [-np.log(ANGLE_EPS) * scale, -np.log(0.5) * scale, -np.log(0.5 * 0.08) * scale]
    )
    assert weights[1] < weights[2] < weights[0]  # concave folds are the cheapest cuts


def test_multilevel_is_close_to_the_direct_solution_on_a_sphere():
    mesh = trimesh.creation.icosphere(5)  # 20480 faces, several coarse levels
    normals, areas = face_normals(mesh.vertices, mesh.faces)
    graph = build_face_graph(mesh.vertices, mesh.faces, normals)
    centroids = face_centroids(mesh.vertices, mesh.faces)
    # Two clusters by height, noisy: the best cut is near the equator.
    rng = np.random.default_rng(0)
    p_top = np.clip(0.5 + 0.5 * centroids[:, 2] + rng.normal(0, 0.2, len(centroids)), 0.01, 0.99)
    data = -np.log(np.column_stack([1 - p_top, p_top]))
    weights = dihedral_weights(graph, 0.02)
    direct = alpha_expansion(data, graph.pairs, weights)
    multilevel = multilevel_alpha_expansion(
        data, graph.pairs, weights, centroids, areas, coarse_nodes=1000
    )
    e_direct = labelling_energy(direct, data, graph.pairs, weights)
    e_multi = labelling_energy(multilevel, data, graph.pairs, weights)
    assert e_multi <= 1.05 * e_direct
    assert np.mean(multilevel == direct) > 0.95


def test_one_cut_hierarchy_serves_every_smoothing_scale():
    mesh = trimesh.creation.icosphere(5)
    normals, areas = face_normals(mesh.vertices, mesh.faces)
    graph = build_face_graph(mesh.vertices, mesh.faces, normals)
    centroids = face_centroids(mesh.vertices, mesh.faces)
    rng = np.random.default_rng(1)
    p_top = np.clip(0.5 + 0.5 * centroids[:, 2] + rng.normal(0, 0.3, len(centroids)), 0.01, 0.99)
    data = -np.log(np.column_stack([1 - p_top, p_top, np.full_like(p_top, 0.3)]))
    unit = dihedral_weights(graph, 1.0)
    hierarchy = cut_hierarchy(data, graph.pairs, unit, centroids, areas, coarse_nodes=1000)
    assert len(hierarchy.levels) > 2 and hierarchy.nbytes > data.nbytes
    for scale in (0.01, 0.05, 0.3):
        direct = multilevel_alpha_expansion(
            data, graph.pairs, unit * scale, centroids, areas, coarse_nodes=1000
        )
        np.testing.assert_array_equal(hierarchy.solve(scale), direct)
    # No smoothness term: every face takes its cheapest label.
    np.testing.assert_array_equal(hierarchy.solve(0.0), np.argmin(data, axis=1))


def test_coarse_graph_groups_as_the_numpy_steps_did_and_sums_more_weights_alike():
    rng = np.random.default_rng(3)
    for trial in range(10):
        nodes = int(rng.integers(2, 3000))
        count = int(rng.integers(1, nodes))
        pairs = rng.integers(0, nodes, (int(rng.integers(0, 8000)), 2))
        weights = rng.uniform(0.0, 1.0, len(pairs)) * 10.0 ** (trial - 5)
        lengths = rng.uniform(0.0, 1.0, len(pairs))
        coarse_of = rng.integers(0, count, nodes)
        ca, cb = coarse_of[pairs[:, 0]], coarse_of[pairs[:, 1]]
        cross = np.flatnonzero(ca != cb)
        low, high = np.minimum(ca[cross], cb[cross]), np.maximum(ca[cross], cb[cross])
        order = np.argsort(low * count + high, kind="stable")
        low, high = low[order], high[order]
        coarse_pairs, summed, summed_lengths = coarse_graph(
            coarse_of, pairs, weights, count, lengths
        )
        if len(cross) == 0:
            assert coarse_pairs.shape == (0, 2) and len(summed) == len(summed_lengths) == 0
            continue
        starts = np.flatnonzero(np.r_[True, (low[1:] != low[:-1]) | (high[1:] != high[:-1])])
        np.testing.assert_array_equal(coarse_pairs, np.stack([low[starts], high[starts]], 1))
        np.testing.assert_array_equal(summed, np.add.reduceat(weights[cross[order]], starts))
        np.testing.assert_array_equal(
            summed_lengths, np.add.reduceat(lengths[cross[order]], starts)
        )
        np.testing.assert_array_equal(coarse_graph(coarse_of, pairs, weights, count)[1], summed)


def test_coarse_graph_sums_the_weights_between_coarse_nodes():
    import scipy.sparse as sp

    rng = np.random.default_rng(2)
    pairs = rng.integers(0, 300, (2000, 2))
    weights = rng.uniform(0.1, 1.0, len(pairs))
    coarse_of = rng.integers(0, 40, 300)
    coarse_pairs, summed = coarse_graph(coarse_of, pairs, weights, 40)
    ca, cb = coarse_of[pairs[:, 0]], coarse_of[pairs[:, 1]]
    cross = ca != cb
    reference = sp.coo_matrix(
        (weights[cross], (np.minimum(ca, cb)[cross], np.maximum(ca, cb)[cross])), shape=(40, 40)
    ).tocsr()
    np.testing.assert_array_equal(np.lexsort(coarse_pairs.T[::-1]), np.arange(len(summed)))
    np.testing.assert_allclose(reference[coarse_pairs[:, 0], coarse_pairs[:, 1]].A1, summed)
    assert len(summed) == reference.nnz
    data = rng.uniform(0, 1, (300, 3))
    expected = np.stack([np.bincount(coarse_of, data[:, j], 40) for j in range(3)], axis=1)
    np.testing.assert_array_equal(coarse_data(coarse_of, data, 40), expected)


def test_the_cut_hierarchy_groups_the_same_faces_in_any_pose():
    from scipy.spatial.transform import Rotation

    mesh = trimesh.creation.icosphere(4)
    vertices = np.asarray(mesh.vertices) * (2.0, 1.0, 0.5)
    vertices[:, 0] += 0.3 * vertices[:, 0] ** 2  # no symmetry: the mesh's axes are defined
    normals, areas = face_normals(vertices, mesh.faces)
    graph = build_face_graph(vertices, mesh.faces, normals)
    left = (face_centroids(vertices, mesh.faces)[:, 0] < 0.2).astype(np.float64)
    data = np.column_stack([left, 1.0 - left, np.full_like(left, 0.6)])  # per face, any pose
    unit = dihedral_weights(graph, 1.0)
    rotation = Rotation.random(random_state=5).as_matrix()
    levels = [
        cut_hierarchy(
            data, graph.pairs, unit, face_centroids(v, mesh.faces), scale**2 * areas, 500
        ).levels
        for v, scale in ((vertices, 1.0), (3.0 * vertices @ rotation.T + 100.0, 3.0))
    ]
    assert len(levels[0]) > 2
    assert len(levels[0]) == len(levels[1])
    for level, moved in zip(*levels, strict=True):
        if level.coarse_of is not None:
            np.testing.assert_array_equal(moved.coarse_of, level.coarse_of)


@pytest.mark.parametrize("seed", range(4))
def test_smoothed_preference_ends_where_no_single_node_change_helps(seed):
    data, pairs, weights, _ = random_problem(seed, nodes=30, labels=4)
    np.testing.assert_array_equal(
        smoothed_preference(data, pairs, weights, sweeps=0), np.argmin(data, axis=1)
    )
    labels = smoothed_preference(data, pairs, weights, sweeps=100)
    energy = labelling_energy(labels, data, pairs, weights)
    assert energy <= labelling_energy(np.argmin(data, axis=1), data, pairs, weights) + 1e-9
    for node, label in itertools.product(range(30), range(4)):  # brute force: every flip
        flipped = labels.copy()
        flipped[node] = label
        assert labelling_energy(flipped, data, pairs, weights) >= energy - 1e-9


def interleaved_sphere(seed: int, subdivisions: int = 5):
    """A sphere whose faces' cheapest of 4 labels is noise around two halves: coarsening
    by cheapest label stalls far above a few hundred nodes."""
    mesh = trimesh.creation.icosphere(subdivisions)
    vertices = np.asarray(mesh.vertices) * (2.0, 1.0, 0.5)
    vertices[:, 0] += 0.3 * vertices[:, 0] ** 2  # no symmetry: the mesh's axes are defined
    normals, areas = face_normals(vertices, mesh.faces)
    graph = build_face_graph(vertices, mesh.faces, normals)
    centroids = face_centroids(vertices, mesh.faces)
    rng = np.random.default_rng(seed)
    top = centroids[:, 2] > 0
    p = rng.uniform(0.05, 1.0, (len(centroids), 4))
    p[:, 0] += 0.6 * top
    p[:, 1] += 0.6 * ~top
    data = -np.log(p / p.sum(axis=1, keepdims=True))
    return data, graph, centroids, areas


def test_a_stalled_hierarchy_coarsens_further_per_smoothing_and_stays_close_to_direct():
    from scipy.spatial.transform import Rotation

    data, graph, centroids, areas = interleaved_sphere(3)
    rotation = Rotation.random(random_state=4).as_matrix()
    unit = dihedral_weights(graph, 1.0)
    hierarchy = cut_hierarchy(data, graph.pairs, unit, centroids, areas, coarse_nodes=300)
    assert hierarchy.stalled is not None and len(hierarchy.levels[-1].data) > 300
    # The top level's adjacency is built once, with the hierarchy, for every smoothing.
    top = hierarchy.levels[-1]
    kept = hierarchy.stalled.adjacency
    assert kept is not None
    for array, built in zip(kept, adjacency_with_edges(top.pairs, len(top.data)), strict=True):
        np.testing.assert_array_equal(array, built)
    levels_bytes = sum(level.nbytes for level in hierarchy.levels)
    kept_bytes = hierarchy.stalled.positions.nbytes + sum(array.nbytes for array in kept)
    assert hierarchy.nbytes == levels_bytes + kept_bytes  # counted in the working set
    for scale in (0.005, 0.02, 0.1):
        levels = hierarchy._smoothed_levels(scale)
        assert len(levels[-1].data) < len(hierarchy.levels[-1].data) / 2
        labels = hierarchy.solve(scale)
        # Deterministic: the same labels again, and from a hierarchy built afresh.
        np.testing.assert_array_equal(hierarchy.solve(scale), labels)
        fresh = cut_hierarchy(data, graph.pairs, unit, centroids, areas, coarse_nodes=300)
        np.testing.assert_array_equal(fresh.solve(scale), labels)
        # The same in another pose and scale: the grid past the stall turns with the mesh.
        moved = cut_hierarchy(
            data, graph.pairs, unit, 3.0 * centroids @ rotation.T + 100.0, 9.0 * areas, 300
        )
        np.testing.assert_array_equal(moved.solve(scale), labels)
        for level, turned in zip(levels, moved._smoothed_levels(scale), strict=True):
            if level.coarse_of is not None:
                np.testing.assert_array_equal(turned.coarse_of, level.coarse_of)
        weights = unit * scale
        direct = alpha_expansion(data, graph.pairs, weights)
        e_direct = labelling_energy(direct, data, graph.pairs, weights)
        assert labelling_energy(labels, data, graph.pairs, weights) <= 1.02 * e_direct


def test_coarsening_past_a_stall_goes_on_below_coarse_nodes():
    data, graph, centroids, areas = interleaved_sphere(3, subdivisions=6)
    hierarchy = cut_hierarchy(data, graph.pairs, dihedral_weights(graph, 1.0), centroids, areas)
    assert hierarchy.stalled is not None and len(hierarchy.levels[-1].data) > COARSE_NODES
    for scale in (0.005, 0.1):
        levels = hierarchy._smoothed_levels(scale)
        # Past COARSE_NODES (where coarsening used to stop) to SMOOTHED_COARSE_NODES.
        assert len(levels[-2].data) > SMOOTHED_COARSE_NODES >= len(levels[-1].data)
        assert len(levels[-2].data) <= COARSE_NODES


def test_a_top_past_a_stall_runs_two_cycles_and_an_unstalled_top_converges(monkeypatch):
    from neural_shdf.segment import graphcut

    tops = []  # (nodes, max_cycles) of each solve from the cheapest labels: the tops
    expand = graphcut.alpha_expansion

    def recorded(data, pairs, weights, labels=None, max_cycles=MAX_CYCLES, *rest):
        if labels is None:
            tops.append((len(data), max_cycles))
        return expand(data, pairs, weights, labels, max_cycles, *rest)

    monkeypatch.setattr(graphcut, "alpha_expansion", recorded)
    data, graph, centroids, areas = interleaved_sphere(3)
    unit = dihedral_weights(graph, 1.0)
    stalled = cut_hierarchy(data, graph.pairs, unit, centroids, areas, coarse_nodes=300)
    assert stalled.stalled is not None
    stalled.solve(0.02)
    assert tops == [(len(stalled._smoothed_levels(0.02)[-1].data), SMOOTHED_TOP_CYCLES)]
    tops.clear()
    # Labels that do not interleave: coarsening reaches 1,000 nodes, whose solve converges.
    smooth = np.full((len(data), 4), 3.0)
    smooth[np.arange(len(data)), (centroids[:, 2] <= 0).astype(int)] = 0.5
    unstalled = cut_hierarchy(smooth, graph.pairs, unit, centroids, areas, coarse_nodes=1000)
    assert unstalled.stalled is None
    unstalled.solve(0.02)
    assert tops == [(len(unstalled.levels[-1].data), MAX_CYCLES)]
    assert SMOOTHED_TOP_CYCLES < MAX_CYCLES


def cut_energy(vertices, faces, posteriors, labels, params):
    """The graph cut's energy of ``labels`` as ``segment`` weighs it: area-weighted data
    costs plus the dihedral weights at ``params.smoothing_for(faces)``."""
    from neural_shdf.segment.graphcut import data_costs
    from neural_shdf.segment.parts import FaceData

    graph = build_face_graph(vertices, faces)
    data = data_costs(posteriors, FaceData.of(vertices, faces).face_weight)
    weights = dihedral_weights(graph, params.smoothing_for(len(faces)))
    return labelling_energy(labels, data, graph.pairs, weights)


def test_energy_of_a_lifted_labelling_is_resolution_invariant_above_the_reference():
    """Midpoint subdivision keeps the surface; a labelling lifted to the children must cost
    the same per face on every mesh above ``reference_faces`` (data grows with the faces,
    a cut with the edges along it, the smoothing's sqrt(faces) makes up the difference)."""
    from neural_shdf.segment import SegmentParams

    sphere = trimesh.creation.icosphere(2)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    rng = np.random.default_rng(3)
    posteriors = rng.dirichlet(np.ones(3), size=len(faces))
    centres = sphere.triangles_center
    labels = (centres[:, 0] > 0.2).astype(np.int64) + (centres[:, 1] > 0.3)
    params = SegmentParams(smoothing=0.3, reference_faces=len(faces))
    per_face = []
    for passes in range(3):
        v, f, origin = midpoint_subdivide(vertices, faces, passes)
        energy = cut_energy(v, f, posteriors[origin], labels[origin], params)
        per_face.append(energy / len(f))
    # Equal up to the rounding of each cost and weight to ``COST_QUANTUM`` (2^-20).
    np.testing.assert_allclose(per_face, per_face[0], rtol=2e-6)
    # Without the normalisation the cut's share halves with each pass (CGAL's energy).
    raw = SegmentParams(smoothing=0.3, reference_faces=None)
    coarse = cut_energy(vertices, faces, posteriors, labels, raw) / len(faces)
    v, f, origin = midpoint_subdivide(vertices, faces, 1)
    assert cut_energy(v, f, posteriors[origin], labels[origin], raw) / len(f) < 0.9 * coarse


@pytest.mark.parametrize("with_lengths", [True, False])
def test_coarse_nodes_keep_to_the_original_edges_of_a_midpoint_subdivided_mesh(with_lengths):
    """Given edge lengths, creases are judged per unit length at every level, so no coarse
    node crosses a bent edge of the original mesh (three edges in four are flat, and the
    dearest to cut); judged by summed weight, coarse levels group across them."""
    sphere = trimesh.creation.icosphere(2)
    vertices, faces, origin = midpoint_subdivide(
        np.asarray(sphere.vertices), np.asarray(sphere.faces), 2
    )
    graph = build_face_graph(vertices, faces)
    normals, areas = face_normals(vertices, faces)
    data = np.zeros((len(faces), 2))
    data[:, 1] = 1.0  # one preferred label everywhere: only creases stop the grouping
    hierarchy = cut_hierarchy(
        data,
        graph.pairs,
        dihedral_weights(graph, 1.0),
        face_centroids(vertices, faces),
        areas,
        coarse_nodes=50,
        lengths=graph.edge_length if with_lengths else None,
    )
    assert len(hierarchy.levels) >= 3
    node = np.arange(len(faces))
    for level in hierarchy.levels[:-1]:
        node = level.coarse_of[node]
    originals_per_node = np.bincount(
        np.unique(node * len(sphere.faces) + origin) // len(sphere.faces)
    )
    assert (originals_per_node.max() == 1) == with_lengths


def test_rounded_costs_sum_to_the_same_bits_in_any_order():
    from neural_shdf.segment.graphcut import COST_QUANTUM, quantized, summable

    rng = np.random.default_rng(5)
    values = rng.lognormal(0.0, 2.0, 20_000)
    for rounded in (quantized(values), *summable(values, 1e-3 * values)):
        sums = {float(np.add.reduce(rounded[rng.permutation(len(rounded))])) for _ in range(8)}
        forward = 0.0
        for value in rounded.tolist():  # one by one, as a kernel adds them
            forward += value
        assert sums == {forward}
    assert np.all(np.abs(quantized(values) - values) <= COST_QUANTUM / 2)
    assert quantized(np.array([1e-9]))[0] == COST_QUANTUM  # a positive cost stays positive


def test_box_centres_are_the_same_for_any_order_of_the_members():
    from neural_shdf.segment.graphcut import _box_centres

    rng = np.random.default_rng(2)
    positions, group = rng.normal(size=(500, 3)), rng.integers(0, 40, 500)
    centres = _box_centres(group, positions, 40)
    for g in range(40):
        members = positions[group == g]
        np.testing.assert_array_equal(centres[g], (members.min(0) + members.max(0)) / 2)
    order = rng.permutation(500)
    np.testing.assert_array_equal(_box_centres(group[order], positions[order], 40), centres)
