"""The graph-cut partitioner: a cut that collapses is solved again with a wider mixture,
then, where it still collapses, with no broad component."""

import numpy as np
import pytest

from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf
from neural_shdf.segment import partitioners
from neural_shdf.segment.from_shdf import prepare_segment, segment
from neural_shdf.segment.params import SegmentParams
from neural_shdf.segment.partitioners import (
    COLLAPSE_MAX_DEVIATION,
    COLLAPSE_MIN_DEVIATION,
    COLLAPSED_LEAVES,
    COLLAPSED_SHARE,
    Partitioning,
    collapsed,
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
    listed = mesh.distinct  # what the segmentation works on, in its order
    work = Partitioning(
        graph=listed.mesh.face_graph,
        basis=prepare_segment(mesh, shdf, params),
        params=params,
        smoothing=params.effective_smoothing,
        creases=listed.mesh.crease_graph,
        lap=lambda step: None,
    )
    parts = cut_parts(work)
    assert len(np.unique(parts)) > COLLAPSED_LEAVES
    leaves = segment(mesh, shdf, params).tree.leaf_labels
    assert np.array_equal(leaves, canonical_labels(parts[listed.copy_of]))


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


@pytest.fixture(scope="module")
def two_halves():
    """A dumbbell whose ShDF is one noisy value on each half: two parts at every smoothing,
    from a mixture of more components whose refit finds no more."""
    mesh, _ = dumbbell(4000)
    mesh = TriangleMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    z = mesh.centroids[:, 2]
    noise = np.random.default_rng(2).normal(size=len(z))
    return mesh, np.clip(np.where(z < 0, 0.3, 0.7) + 0.05 * noise, 0.0, 1.0)


def counted_cuts(monkeypatch):
    """Calls of ``cut_parts`` (each one graph cut solved) while the test runs."""
    calls = []

    def counting(work):
        calls.append(work.smoothing)
        return cut_parts(work)

    monkeypatch.setattr(partitioners, "cut_parts", counting)
    return calls


def test_two_parts_that_smoothing_makes_are_cut_once(two_halves, monkeypatch):
    mesh, values = two_halves
    basis = prepare_segment(mesh, values, SegmentParams())
    segment(mesh, values, SegmentParams(), basis=basis)  # collapses at the default: refitted
    assert basis.refit_wins == {refit_key(SegmentParams()): False}  # into no more parts
    calls = counted_cuts(monkeypatch)
    params = SegmentParams(smoothing=1.0)
    result = segment(mesh, values, params, basis=basis)
    assert calls == [params.smoothing_for(mesh.face_count)]  # one cut, not solved again
    assert result.tree.leaf_count == 2
    fresh = prepare_segment(mesh, values, params)
    assert np.array_equal(segment(mesh, values, params, basis=fresh).labels, result.labels)
    assert fresh.refit_wins == basis.refit_wins  # decided at the default on first use


def test_two_parts_are_cut_again_where_the_refit_won_at_the_default(two_halves, monkeypatch):
    mesh, values = two_halves
    basis = prepare_segment(mesh, values, SegmentParams())
    basis.refit_wins[refit_key(SegmentParams())] = True  # as a degenerate fit's basis has it
    calls = counted_cuts(monkeypatch)
    segment(mesh, values, SegmentParams(smoothing=1.0), basis=basis)
    assert len(calls) == 2 and list(basis._widened) == [(COLLAPSE_MIN_DEVIATION, np.inf)]


def test_one_part_is_cut_again_at_any_smoothing(spiked_dumbbell, monkeypatch):
    mesh, values = spiked_dumbbell
    params = SegmentParams(smoothing=0.15)
    basis = prepare_segment(mesh, values, params)
    work = partitioning(mesh, basis, params)
    assert part_count(cut_parts(work)) == 1
    calls = counted_cuts(monkeypatch)
    result = segment(mesh, values, params, basis=basis)
    assert len(calls) == 2 and basis.refit_wins == {}  # the default not consulted
    assert result.part_count == 3  # the widened mixture's cut
    monkeypatch.undo()
    assert np.array_equal(segment(mesh, values, params).labels, result.labels)


def test_the_refit_decision_holds_per_option_set(two_halves):
    mesh, values = two_halves
    basis = prepare_segment(mesh, values, SegmentParams())
    segment(mesh, values, SegmentParams(smoothing=1.0), basis=basis)
    segment(mesh, values, SegmentParams(smoothing=2.0, parts=1), basis=basis)
    segment(mesh, values, SegmentParams(smoothing=2.0, crease_boundaries=False), basis=basis)
    segment(mesh, values, SegmentParams(smoothing=2.0, partitioner="metis"), basis=basis)
    assert set(basis.refit_wins) == {
        refit_key(SegmentParams()),
        refit_key(SegmentParams(crease_boundaries=False)),
    }
    assert basis.with_mixture(basis.mixture).refit_wins == {}


def test_a_cut_is_collapsed_by_its_count_or_by_one_part_holding_the_surface():
    areas = np.ones(100)
    assert collapsed(np.zeros(100, dtype=np.int64), areas)
    assert collapsed(np.repeat([0, 1], 50), areas)  # at most COLLAPSED_LEAVES parts
    crumbs = np.zeros(100, dtype=np.int64)
    crumbs[[3, 40, 77]] = [1, 2, 3]
    assert collapsed(crumbs, areas)  # 97% in one part
    assert not collapsed(np.repeat([0, 1, 2], [40, 30, 30]), areas)
    assert not collapsed(crumbs, np.where(crumbs == 0, 0.1, 10.0))  # crumbs by count only
    assert not collapsed(np.arange(5), np.zeros(5))
    assert COLLAPSED_SHARE == 0.9


@pytest.fixture(scope="module")
def bird_without_base(psb_off):
    """psb 244 (a bird) with its lowest 6% of faces by height removed, as a scan without
    its base (``benchmarks/bench_production.py``'s ``nobase``), and its default ShDF."""
    mesh = load_mesh(psb_off(244))
    height = mesh.vertices[mesh.faces].mean(axis=1)[:, 1]
    kept = np.sort(np.argsort(height, kind="stable")[int(0.06 * mesh.face_count) :])
    open_mesh = TriangleMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)[kept])
    return open_mesh, compute_shdf(open_mesh).values


def test_a_cut_still_collapsed_after_the_refit_is_solved_without_the_broad_component(
    bird_without_base, monkeypatch
):
    mesh, values = bird_without_base
    params = SegmentParams()
    basis = prepare_segment(mesh, values, params)
    work = partitioning(mesh, basis, params)
    assert collapsed(cut_parts(work), basis.geometry.areas)
    widened = basis.widened(COLLAPSE_MIN_DEVIATION)
    assert collapsed(cut_parts(partitioning(mesh, widened, params)), basis.geometry.areas)
    assert widened.mixture.deviations.max() > 2 * COLLAPSE_MAX_DEVIATION  # the broad one
    result = segment(mesh, values, params, basis=basis)
    assert (COLLAPSE_MIN_DEVIATION, COLLAPSE_MAX_DEVIATION) in basis._widened
    assert result.tree.leaf_count > 4 and result.part_count >= 3  # body, wings, head: not one
    areas = basis.geometry.areas
    assert np.bincount(result.labels, weights=areas).max() < 0.8 * areas.sum()
    assert np.array_equal(segment(mesh, values, params).labels, result.labels)  # fresh basis


def test_a_refit_with_no_broad_component_is_not_narrowed(two_halves, monkeypatch):
    mesh, values = two_halves
    basis = prepare_segment(mesh, values, SegmentParams())
    calls = counted_cuts(monkeypatch)
    segment(mesh, values, SegmentParams(), basis=basis)  # collapses into two: refitted once
    assert basis.widened(COLLAPSE_MIN_DEVIATION).mixture.deviations.max() <= COLLAPSE_MAX_DEVIATION
    assert len(calls) == 2 and list(basis._widened) == [(COLLAPSE_MIN_DEVIATION, np.inf)]
