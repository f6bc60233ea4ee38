"""The benchmark metrics against hand-worked values and brute-force definitions."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neural_shdf.evaluate.scores import (
    SegmentationScores,
    average_radius,
    consistency_errors,
    cut_discrepancy,
    cut_distance_field,
    cut_graph,
    hamming_distance,
    matched_accuracy,
    rand_index_error,
    score_against_humans,
    score_segmentation,
)


def strip_mesh(columns: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit squares [k, k+1] x [0, 1] in the z = 0 plane, two triangles each (faces 2k, 2k+1)."""
    xs = np.arange(columns + 1, dtype=float)
    vertices = np.concatenate(
        [np.column_stack([xs, np.zeros_like(xs), np.zeros_like(xs)]),
         np.column_stack([xs, np.ones_like(xs), np.zeros_like(xs)])]
    )  # fmt: skip
    top = columns + 1
    faces = []
    for k in range(columns):
        faces.append([k, k + 1, top + k + 1])
        faces.append([k, top + k + 1, top + k])
    return vertices, np.array(faces)


def quad_labels(columns: int, cuts: list[int]) -> np.ndarray:
    """Per-face label of a strip cut at the given x positions."""
    quad = np.repeat(np.arange(columns), 2)
    return np.searchsorted(np.array(cuts), quad, side="right")


# -- the 4-face strip, split 2|2 (A) against 1|3 (B), every face weighing 1 ----------
A = np.array([0, 0, 1, 1])
B = np.array([0, 1, 1, 1])


def test_rand_index_of_2_2_against_1_3():
    # 6 face pairs. (0,1): A joins, B splits -> disagree. (0,2), (0,3): both split.
    # (1,2), (1,3): A splits, B joins -> disagree. (2,3): both join. 3 of 6 disagree.
    assert rand_index_error(A, B) == pytest.approx(0.5)
    assert rand_index_error(B, A) == pytest.approx(0.5)


def test_hamming_of_2_2_against_1_3():
    # Overlaps n[A-seg, B-seg]: n00 = 1, n01 = 1, n10 = 0, n11 = 2.
    # Rm: reference (B) segments minus their best A overlap: (1 - 1) + (3 - 2) = 1 -> 1/4.
    # Rf: A segments minus their best B overlap: (2 - 1) + (2 - 2) = 1 -> 1/4.
    hd, rm, rf = hamming_distance(A, B)
    assert (hd, rm, rf) == pytest.approx((0.25, 0.25, 0.25))


def test_consistency_errors_of_2_2_against_1_3():
    # E(A, B, f) = |R_A(f) minus R_B(f)| / |R_A(f)|: f0: {0,1}-{0} = 1/2, f1: {0,1}-{1,2,3}
    # = 1/2, f2, f3: {2,3} inside {1,2,3} = 0 -> sum 1.
    # E(B, A, f): f0: {0} inside {0,1} = 0, f1: {1,2,3}-{0,1} = 2/3, f2: {1,2,3}-{2,3}
    # = 1/3, f3: 1/3 -> sum 4/3.
    # GCE = min(1, 4/3) / 4 = 1/4; LCE = (0 + 1/2 + 0 + 0) / 4 = 1/8.
    assert consistency_errors(A, B) == pytest.approx((0.25, 0.125))


def test_one_part_against_a_segmentation():
    # N = 10 faces, reference parts of 5, 3, 2 faces.
    reference = np.array([0] * 5 + [1] * 3 + [2] * 2)
    one = np.zeros(10, dtype=int)
    # Pairs the reference splits: 45 - (10 + 3 + 1) = 31 of 45.
    assert rand_index_error(one, reference) == pytest.approx(31 / 45)
    # Every reference part sits inside the one part (Rm = 0); the one part loses 5 of 10.
    assert hamming_distance(one, reference) == pytest.approx((0.25, 0.0, 0.5))
    # The reference refines the one part: both consistency errors vanish.
    assert consistency_errors(one, reference) == pytest.approx((0.0, 0.0))


def test_identical_and_relabelled_segmentations_score_zero():
    vertices, faces = strip_mesh(6)
    mesh = cut_graph(vertices, faces)
    labels = quad_labels(6, [2, 4])
    relabelled = np.array([7, 3, 9])[labels]
    scores = score_segmentation(mesh, labels, relabelled)
    assert all(value == 0.0 for value in scores.as_dict().values())


def brute_force_rand_error(a, b, w):
    disagree = total = 0.0
    for i, j in itertools.combinations(range(len(a)), 2):
        total += w[i] * w[j]
        disagree += w[i] * w[j] * ((a[i] == a[j]) != (b[i] == b[j]))
    return disagree / total


def brute_force_consistency(a, b, w):
    e_ab, e_ba = [], []
    for f in range(len(a)):
        in_a, in_b = a == a[f], b == b[f]
        e_ab.append(w[in_a & ~in_b].sum() / w[in_a].sum())
        e_ba.append(w[in_b & ~in_a].sum() / w[in_b].sum())
    e_ab, e_ba = np.array(e_ab), np.array(e_ba)
    return min(w @ e_ab, w @ e_ba) / w.sum(), (w @ np.minimum(e_ab, e_ba)) / w.sum()


def brute_force_hamming(a, b, w):
    def directional(s1, s2):  # sum over segments of s2 of what the best s1 segment misses
        missed = 0.0
        for seg in np.unique(s2):
            inside = s2 == seg
            best = max(w[inside & (s1 == other)].sum() for other in np.unique(s1))
            missed += w[inside].sum() - best
        return missed / w.sum()

    rm, rf = directional(a, b), directional(b, a)
    return (rm + rf) / 2, rm, rf


segmentations = st.integers(2, 12).flatmap(
    lambda n: st.tuples(
        st.lists(st.integers(0, 3), min_size=n, max_size=n),
        st.lists(st.integers(0, 4), min_size=n, max_size=n),
        st.lists(st.floats(0.1, 5.0), min_size=n, max_size=n),
    )
)


@settings(max_examples=40, deadline=None)
@given(segmentations)
def test_region_metrics_match_their_definitions(case):
    a, b, w = (np.array(x) for x in case)
    for weights in (None, w):
        ww = np.ones(len(a)) if weights is None else w
        assert rand_index_error(a, b, weights) == pytest.approx(brute_force_rand_error(a, b, ww))
        assert consistency_errors(a, b, weights) == pytest.approx(brute_force_consistency(a, b, ww))
        assert hamming_distance(a, b, weights) == pytest.approx(brute_force_hamming(a, b, ww))


@settings(max_examples=40, deadline=None)
@given(segmentations)
def test_symmetries_and_bounds(case):
    a, b, w = (np.array(x) for x in case)
    assert rand_index_error(a, b, w) == pytest.approx(rand_index_error(b, a, w))
    hd, rm, rf = hamming_distance(a, b, w)
    hd_swapped, rm_swapped, rf_swapped = hamming_distance(b, a, w)
    assert (hd, rm, rf) == pytest.approx((hd_swapped, rf_swapped, rm_swapped))
    gce, lce = consistency_errors(a, b, w)
    assert (gce, lce) == pytest.approx(consistency_errors(b, a, w))
    assert 0.0 <= lce <= gce + 1e-12 <= 1.0 + 1e-12
    assert 0.0 <= rand_index_error(a, b, w) <= 1.0
    assert 0.0 <= rm <= 1.0 and 0.0 <= rf <= 1.0
    # Scaling every weight changes nothing.
    assert rand_index_error(a, b, 3 * w) == pytest.approx(rand_index_error(a, b, w))


def test_integer_weights_equal_repeated_faces():
    a, b = np.array([0, 0, 1, 2, 2]), np.array([1, 0, 0, 0, 2])
    w = np.array([1, 3, 2, 1, 2])
    a_rep, b_rep = np.repeat(a, w), np.repeat(b, w)
    assert hamming_distance(a, b, w) == pytest.approx(hamming_distance(a_rep, b_rep))
    assert consistency_errors(a, b, w) == pytest.approx(consistency_errors(a_rep, b_rep))


def test_average_radius_of_a_regular_tetrahedron():
    # Vertices on the unit sphere: every face centroid lies 1/3 from the centre.
    vertices = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]]) / math.sqrt(3)
    faces = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    assert average_radius(vertices, faces) == pytest.approx(1 / 3)


def test_cut_discrepancy_of_parallel_cuts():
    vertices, faces = strip_mesh(6)
    mesh = cut_graph(vertices, faces)
    # Cut at x = 2 against cut at x = 3: each cut vertex is one unit edge from the other cut.
    cd = cut_discrepancy(mesh, quad_labels(6, [2]), quad_labels(6, [3]))
    assert cd * mesh.radius == pytest.approx(1.0)


def test_cut_discrepancy_pools_both_directions():
    vertices, faces = strip_mesh(6)
    mesh = cut_graph(vertices, faces)
    # Cuts at x = 1 and 4 (4 vertices) against x = 2 (2 vertices): distances from the
    # first to the second 1, 1, 2, 2; back 1, 1. Pooled mean 8 / 6 (segEval's way).
    cd = cut_discrepancy(mesh, quad_labels(6, [1, 4]), quad_labels(6, [2]))
    assert cd * mesh.radius == pytest.approx(8 / 6)


def test_cut_discrepancy_without_cuts():
    vertices, faces = strip_mesh(4)
    mesh = cut_graph(vertices, faces)
    one = np.zeros(len(faces), dtype=int)
    assert cut_discrepancy(mesh, one, one) == 0.0
    assert math.isnan(cut_discrepancy(mesh, one, quad_labels(4, [2])))
    assert cut_distance_field(mesh, one) is None


def test_cut_graph_welds_split_vertices():
    # The same strip with every face owning its own three vertices (a triangle soup).
    vertices, faces = strip_mesh(6)
    soup_vertices = vertices[faces.reshape(-1)]
    soup_faces = np.arange(len(soup_vertices)).reshape(-1, 3)
    welded, soup = cut_graph(vertices, faces), cut_graph(soup_vertices, soup_faces)
    a, b = quad_labels(6, [1, 4]), quad_labels(6, [2])
    assert cut_discrepancy(soup, a, b) == pytest.approx(cut_discrepancy(welded, a, b))


def test_scores_average_over_humans_and_skip_undefined_cd():
    vertices, faces = strip_mesh(6)
    mesh = cut_graph(vertices, faces)
    labels = quad_labels(6, [3])
    humans = [quad_labels(6, [3]), quad_labels(6, [2]), np.zeros(len(faces), dtype=int)]
    each = [score_segmentation(mesh, labels, h) for h in humans]
    mean = score_against_humans(mesh, labels, humans)
    assert mean.ri_error == pytest.approx(np.mean([s.ri_error for s in each]))
    # CD is undefined against the one-part human and left out of the mean.
    assert math.isnan(each[2].cd)
    assert mean.cd == pytest.approx((each[0].cd + each[1].cd) / 2)
    assert SegmentationScores.mean([mean]) == mean


def test_mismatched_lengths_are_refused():
    vertices, faces = strip_mesh(4)
    mesh = cut_graph(vertices, faces)
    with pytest.raises(ValueError, match="labels"):
        score_segmentation(mesh, np.zeros(3, dtype=int), np.zeros(len(faces), dtype=int))
    with pytest.raises(ValueError, match="weights"):
        rand_index_error(A, B, np.ones(3))


def test_matched_accuracy_matches_segments_one_to_one():
    reference = np.array([0, 0, 0, 1, 1, 2, 2, 2])
    assert matched_accuracy(reference, reference) == 1.0
    assert matched_accuracy(reference + 5, reference) == 1.0  # names do not matter
    # Two segments covering label 0: only one can be matched; the other's face is wrong.
    assert matched_accuracy([0, 0, 3, 1, 1, 2, 2, 2], reference) == pytest.approx(7 / 8)
    # A segment straddling labels 0 and 1 is matched to one of them.
    labels = np.array([0, 0, 1, 1, 1, 2, 2, 2])
    assert matched_accuracy(labels, reference) == pytest.approx(7 / 8)
    # Weights count mass instead of faces.
    weights = np.array([1, 1, 1, 1, 1, 1, 1, 9.0])
    assert matched_accuracy([0, 0, 3, 1, 1, 2, 2, 2], reference, weights) == pytest.approx(15 / 16)


@given(st.lists(st.integers(0, 3), min_size=1, max_size=12), st.data())
@settings(max_examples=60, deadline=None)
def test_matched_accuracy_equals_the_best_permutation(labels, data):
    reference = data.draw(st.lists(st.integers(0, 3), min_size=len(labels), max_size=len(labels)))
    labels, reference = np.array(labels), np.array(reference)
    best = 0
    for perm in itertools.permutations(range(4)):
        best = max(best, int(np.sum(np.array(perm)[labels] == reference)))
    assert matched_accuracy(labels, reference) == pytest.approx(best / len(labels))
