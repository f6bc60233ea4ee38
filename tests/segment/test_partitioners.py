"""The graph-cut partitioner: a cut that collapses into one part is solved again."""

import numpy as np
import pytest

from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment.from_shdf import prepare_segment, segment
from neural_shdf.segment.params import SegmentParams
from neural_shdf.segment.partitioners import (
    COLLAPSE_MIN_DEVIATION,
    COLLAPSED_LEAVES,
    Partitioning,
    cut_parts,
    part_count,
    refit_key,
)
from neural_shdf.segment.parts import canonical_labels
from neural_shdf.segment.synthetic import JUNCTION_Z, dumbbell


@pytest.fixture(scope="module")
def spiked_dumbbell():
    """A dumbbell whose ShDF has 60% of its faces, scattered over the whole surface, at
    one value (0.5): the mixture puts several components on that histogram bin and one
    broad component over every other value."""
    mesh, shdf = dumbbell(4000)
    rng = np.random.default_rng(1)
    values = np.clip(shdf + 0.05 * rng.normal(size=len(shdf)), 0.0, 1.0)
    values[rng.random(len(values)) < 0.6] = 0.5
    return TriangleMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)), values


def test_spiked_values_fit_a_degenerate_mixture_whose_cut_collapses(spiked_dumbbell):
    mesh, values = spiked_dumbbell
    basis = prepare_segment(mesh, values, SegmentParams())
    spikes = np.sum(basis.mixture.deviations < 0.002)
    assert spikes >= 4 and basis.mixture.deviations.max() > 0.2
    work = Partitioning(
        graph=mesh.face_graph,
        basis=basis,
        params=SegmentParams(),
        smoothing=SegmentParams().effective_smoothing,
        creases=mesh.crease_graph,
        lap=lambda step: None,
    )
    assert len(np.unique(cut_parts(work))) <= COLLAPSED_LEAVES  # one part without the refit


def test_collapsed_cut_is_solved_again_with_wider_components(spiked_dumbbell):
    mesh, values = spiked_dumbbell
    result = segment(mesh, values, SegmentParams())
    assert result.part_count == 3  # the two balls and the neck, not one part
    z = mesh.centroids[:, 2]
    left, right = result.labels[z < -JUNCTION_Z - 0.2], result.labels[z > JUNCTION_Z + 0.2]
    assert np.bincount(left).max() > 0.9 * len(left)
    assert np.bincount(right).max() > 0.9 * len(right)
    assert np.argmax(np.bincount(left)) != np.argmax(np.bincount(right))
    assert np.array_equal(result.labels, segment(mesh, values, SegmentParams()).labels)


def test_a_cut_into_parts_is_not_solved_again():
    mesh, shdf = dumbbell(4000)
    mesh = TriangleMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    params = SegmentParams()
    work = Partitioning(
        graph=mesh.face_graph,
        basis=prepare_segment(mesh, shdf, params),
        params=params,
        smoothing=params.effective_smoothing,
        creases=mesh.crease_graph,
        lap=lambda step: None,
    )
    parts = cut_parts(work)
    assert len(np.unique(parts)) > COLLAPSED_LEAVES
    assert np.array_equal(segment(mesh, shdf, params).tree.leaf_labels, canonical_labels(parts))


def test_part_count_counts_distinct_labels():
    assert part_count(np.array([3, 3, 7, 5, 7])) == 3
    assert part_count(np.zeros(0, dtype=np.int64)) == 0


def test_a_kept_basis_refits_a_collapse_once_with_the_labels_of_a_fresh_one(spiked_dumbbell):
    mesh, values = spiked_dumbbell
    params = SegmentParams()
    basis = prepare_segment(mesh, values, params)
    kept = segment(mesh, values, params, basis=basis)
    widened = basis.widened(COLLAPSE_MIN_DEVIATION)
    assert basis.widened(COLLAPSE_MIN_DEVIATION) is widened  # refitted and coarsened once
    assert widened._cut is not None  # its coarse graphs were built by the first solve
    assert basis.nbytes > basis.with_mixture(basis.mixture).nbytes
    again = segment(mesh, values, params, basis=basis)
    fresh = segment(mesh, values, params)
    assert np.array_equal(kept.labels, fresh.labels)
    assert np.array_equal(again.labels, fresh.labels)


def partitioning(mesh, basis, params):
    return Partitioning(
        graph=mesh.face_graph,
        basis=basis,
        params=params,
        smoothing=params.smoothing_for(mesh.face_count),
        creases=mesh.crease_graph,
        lap=lambda step: None,
    )


def test_a_collapse_that_smoothing_makes_is_not_solved_again():
    mesh, shdf = dumbbell(4000)
    mesh = TriangleMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    params = SegmentParams(smoothing=2.0)  # high enough to merge the dumbbell into one part
    basis = prepare_segment(mesh, shdf, params)
    result = segment(mesh, shdf, params, basis=basis)
    assert result.tree.leaf_count <= COLLAPSED_LEAVES
    assert basis._widened is None  # the fit did not collapse at the default: no refit
    assert basis.refit_wins == {refit_key(params): False}
    assert np.array_equal(
        result.tree.leaf_labels, canonical_labels(cut_parts(partitioning(mesh, basis, params)))
    )


def test_a_degenerate_fit_is_refitted_at_every_smoothing(spiked_dumbbell):
    mesh, values = spiked_dumbbell
    params = SegmentParams(smoothing=0.15)
    fresh_basis = prepare_segment(mesh, values, params)
    fresh = segment(mesh, values, params, basis=fresh_basis)  # decides at the default first
    assert fresh_basis.refit_wins == {refit_key(params): True}
    assert part_count(cut_parts(partitioning(mesh, fresh_basis, params))) == 1
    assert fresh.part_count == 3  # the widened mixture's cut
    kept = prepare_segment(mesh, values, SegmentParams())
    segment(mesh, values, SegmentParams(), basis=kept)
    assert np.array_equal(segment(mesh, values, params, basis=kept).labels, fresh.labels)
    assert np.array_equal(segment(mesh, values, params).labels, fresh.labels)


def test_the_refit_decision_holds_per_option_set(spiked_dumbbell):
    mesh, values = spiked_dumbbell
    basis = prepare_segment(mesh, values, SegmentParams())
    segment(mesh, values, SegmentParams(smoothing=0.15), basis=basis)
    segment(mesh, values, SegmentParams(smoothing=0.2, parts=2), basis=basis)
    segment(mesh, values, SegmentParams(smoothing=0.2, crease_boundaries=False), basis=basis)
    assert set(basis.refit_wins) == {
        refit_key(SegmentParams()),
        refit_key(SegmentParams(crease_boundaries=False)),
    }
    assert basis.with_mixture(basis.mixture).refit_wins == {}
