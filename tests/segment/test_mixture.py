"""1-D Gaussian mixture on binned ShDF values: agrees with scikit-learn, picks sensible k."""

import numpy as np
import pytest
from sklearn.mixture import GaussianMixture

from neural_shdf.segment.mixture import (
    choose_cluster_count,
    fit_best_mixture,
    fit_mixture,
    prefers_split,
)


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
