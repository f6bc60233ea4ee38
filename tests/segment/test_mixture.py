"""1-D Gaussian mixture on binned ShDF values: agrees with scikit-learn, picks sensible k."""

import numpy as np
import pytest
from sklearn.mixture import GaussianMixture

from neural_shdf.geometry import equivalent_face_count, face_normals
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment import mixture
from neural_shdf.segment.from_shdf import prepare_segment
from neural_shdf.segment.mixture import (
    UNEVEN_TESSELLATION,
    choose_cluster_count,
    fit_best_mixture,
    fit_mixture,
    histogram,
    prefers_split,
    value_weights,
)
from neural_shdf.segment.params import SegmentParams
from neural_shdf.segment.synthetic import dumbbell, split_top


def two_populations(n: int = 20000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = np.concatenate(
        [rng.normal(0.25, 0.05, 3 * n // 5), rng.normal(0.65, 0.08, 2 * n // 5)]
    )
    return np.clip(values, 0.0, 1.0)


def test_fit_matches_scikit_learn_on_raw_values():
    values = two_populations()
    ours = fit_mixture(values, 2)
    reference = GaussianMixture(2, random_state=0).fit(values[:, None])
    order = np.argsort(reference.means_[:, 0])
    np.testing.assert_allclose(ours.means, reference.means_[order, 0], atol=5e-3)
    np.testing.assert_allclose(
        ours.deviations, np.sqrt(reference.covariances_.reshape(-1)[order]), atol=5e-3
    )
    np.testing.assert_allclose(ours.weights, reference.weights_[order], atol=1e-2)


def test_posteriors_are_probabilities_and_follow_the_nearest_population():
    values = two_populations()
    mixture = fit_mixture(values, 2)
    posteriors = mixture.posteriors(np.array([0.1, 0.25, 0.65, 0.9]))
    np.testing.assert_allclose(posteriors.sum(axis=1), 1.0)
    assert np.all(posteriors >= 0)
    np.testing.assert_array_equal(posteriors.argmax(axis=1), [0, 0, 1, 1])


def test_bic_prefers_two_components_for_two_populations():
    assert choose_cluster_count(two_populations(), candidates=(1, 2, 3, 4, 5)) == 2


def test_constant_values_give_one_component():
    mixture = fit_best_mixture(np.full(500, 0.4))
    assert mixture.size == 1
    np.testing.assert_allclose(mixture.posteriors(np.full(3, 0.4)), 1.0)
    assert fit_mixture(np.full(500, 0.4), 5).size == 1


@pytest.mark.parametrize(
    "values, expected",
    [
        (two_populations(), True),
        (np.clip(np.random.default_rng(1).normal(0.5, 0.1, 5000), 0, 1), False),
    ],
)
def test_prefers_split_only_for_two_separated_populations(values, expected):
    assert prefers_split(values) is expected


def test_fit_is_deterministic():
    values = two_populations()
    first, second = fit_best_mixture(values), fit_best_mixture(values.copy())
    np.testing.assert_array_equal(first.means, second.means)
    np.testing.assert_array_equal(first.weights, second.weights)


def test_min_deviation_keeps_components_off_a_single_bin():
    values = two_populations()
    values[: len(values) // 2] = 0.5  # half the values on one histogram bin
    narrow = fit_mixture(values, 9)
    wide = fit_mixture(values, 9, min_deviation=0.02)
    assert narrow.deviations.min() < 0.002
    assert wide.deviations.min() >= 0.02 - 1e-12


def split_areas(coarse: int, fine: int, pieces: int) -> np.ndarray:
    """Face areas of ``coarse`` unit faces and ``fine`` unit faces split into ``pieces``."""
    return np.concatenate([np.ones(coarse), np.full(fine * pieces, 1.0 / pieces)])


@pytest.mark.parametrize(
    "areas",
    [
        np.ones(1000),
        np.random.default_rng(0).uniform(0.5, 1.5, 1000),  # uneven, but like a modelled mesh
        split_areas(800, 200, 2),  # face count / equivalent count 1.2
        np.zeros(10),
        np.zeros(0),
    ],
)
def test_faces_count_once_on_an_evenly_tessellated_mesh(areas):
    assert value_weights(areas) is None


def test_faces_count_by_area_where_a_fine_region_outnumbers_the_surface():
    areas = split_areas(800, 200, 100)  # 20,800 faces for the surface of 800 equal ones
    weights = value_weights(areas)
    assert weights is not None
    np.testing.assert_allclose(weights, areas / areas.mean())
    assert weights.sum() == pytest.approx(len(areas))


def test_the_weights_blend_in_without_a_jump():
    """Between ``UNEVEN_TESSELLATION`` and twice it (face count over the equivalent
    count) the weights move from counting faces to their areas, continuously."""
    exponents = []
    for pieces in (3, 4, 5, 6, 8, 10, 12, 16, 24, 40):
        # 40% of the area split: the area-weighted median face is a coarse one
        areas = split_areas(1200, 800, pieces)
        weights = value_weights(areas)
        ratio = len(areas) / 2000
        if ratio <= UNEVEN_TESSELLATION:
            assert weights is None
            exponents.append(0.0)
            continue
        assert weights is not None
        # weights ~ (area / mean) ** blend: the blend from two faces' weights
        blend = np.log(weights[0] / weights[-1]) / np.log(pieces)
        expected = np.clip(np.log2(ratio / UNEVEN_TESSELLATION), 0.0, 1.0)
        assert blend == pytest.approx(expected)
        exponents.append(blend)
    assert exponents == sorted(exponents) and exponents[-1] == pytest.approx(1.0)


def test_integer_weights_fit_as_repeated_values():
    rng = np.random.default_rng(3)
    values = two_populations(4000)
    weights = rng.integers(1, 4, len(values)).astype(float)
    weighted = fit_mixture(values, 3, weights=weights)
    repeated = fit_mixture(np.repeat(values, weights.astype(int)), 3)
    np.testing.assert_allclose(weighted.means, repeated.means, rtol=1e-9)
    np.testing.assert_allclose(weighted.weights, repeated.weights, rtol=1e-9)
    centres, counts = histogram(values, weights=weights)
    assert counts.sum() == pytest.approx(weights.sum())
    assert (
        fit_best_mixture(values, weights=weights).size
        == fit_best_mixture(np.repeat(values, weights.astype(int))).size
    )
    assert prefers_split(values, weights=weights)


def finely_split_dumbbell():
    """A dumbbell (its synthetic ShDF) and the same surface with its top fifth split
    1-to-64, each piece carrying its face's value: (coarse mesh, values, split mesh, parent)."""
    mesh, shdf = dumbbell(3000)
    split_vertices, split_faces, parent = split_top(mesh, 8)
    coarse = TriangleMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    return coarse, shdf, TriangleMesh(split_vertices, split_faces), parent


def test_a_finely_split_detail_gets_the_mixture_of_its_surface():
    """The segmentation's mixture (``prepare_segment``) of a surface whose top fifth is
    split 1-to-64 is the area-weighted fit of the unsplit surface, to rounding: the split
    does not move it. Counting faces, the detail's values (13x the faces of the rest)
    pull the components to the balls' thickness."""
    coarse, shdf, split, parent = finely_split_dumbbell()
    params = SegmentParams(clusters=5)
    ratio_coarse = value_weights(coarse.normals_and_areas[1])
    assert ratio_coarse is None  # the coarse dumbbell counts faces
    basis = prepare_segment(coarse, shdf, params)
    # the basis lists the triangles as ``distinct`` does
    areas = coarse.normals_and_areas[1][coarse.distinct.kept]
    surface = fit_mixture(basis.values, 5, weights=areas / areas.mean())
    found = prepare_segment(split, shdf[parent], params).mixture
    np.testing.assert_allclose(found.means, surface.means, atol=1e-9)
    np.testing.assert_allclose(found.weights, surface.weights, atol=1e-9)
    counted = fit_mixture(basis.values[coarse.distinct.copy_of][parent], 5)
    assert np.abs(counted.means - surface.means).max() > 0.05


def test_the_widened_refit_weighs_as_the_first_fit(monkeypatch):
    coarse, shdf, split, parent = finely_split_dumbbell()
    basis = prepare_segment(split, shdf[parent], SegmentParams(clusters=5))
    seen = []
    original = mixture.histogram

    def spy(values, bins=mixture.HISTOGRAM_BINS, weights=None):
        seen.append(weights)
        return original(values, bins, weights)

    monkeypatch.setattr(mixture, "histogram", spy)
    basis.widened(0.02)
    assert seen and seen[0] is not None
    _, areas = face_normals(split.vertices, split.faces)
    areas = areas[split.distinct.kept]  # the basis lists the triangles as ``distinct`` does
    np.testing.assert_allclose(seen[0], areas / areas.mean())


def test_the_equivalent_count_is_worked_out_once_per_basis(monkeypatch):
    """The weights' equivalent face count is kept by the basis (the part tree's bending
    rule asks for it too): one sort of the areas per segmentation basis."""
    from neural_shdf.segment import basis as basis_module
    from neural_shdf.segment import from_shdf

    coarse, shdf, split, parent = finely_split_dumbbell()
    calls = []

    def counting(areas):
        calls.append(len(areas))
        return equivalent_face_count(areas)

    for module in (from_shdf, basis_module, mixture):
        monkeypatch.setattr(module, "equivalent_face_count", counting)
    basis = prepare_segment(split, shdf[parent], SegmentParams(clusters=5))
    assert basis.equivalent_faces == equivalent_face_count(split.normals_and_areas[1])
    basis.widened(0.02)
    assert calls == [split.face_count]


def test_max_deviation_keeps_every_component_narrower():
    rng = np.random.default_rng(4)
    peaks = [rng.normal(0.5, 0.02, 6000), rng.normal(0.7, 0.02, 3000)]
    values = np.clip(np.concatenate([*peaks, rng.random(1500)]), 0.0, 1.0)
    free = fit_mixture(values, 4)
    assert free.deviations.max() > 0.15  # the uniform spread takes a broad component
    capped = fit_mixture(values, 4, max_deviation=0.08)
    assert capped.deviations.max() <= 0.08 + 1e-12
    assert np.all(np.diff(capped.means) >= 0) and np.isclose(capped.weights.sum(), 1.0)
