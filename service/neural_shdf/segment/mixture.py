"""Soft clustering of per-face ShDF values with a 1-D Gaussian mixture (CGAL's first step).

The mixture is fitted with scikit-learn on a seeded subsample (a 1-D
distribution needs a few thousand samples, not a million) from deterministic
quantile initial means; posteriors for every face are then evaluated in numpy.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from neural_shdf.segment.params import CLUSTER_CANDIDATES

#: Faces the mixture is fitted on (a seeded subsample when there are more).
FIT_SAMPLES = 5000
#: Faces the BIC model selection fits each candidate on.
BIC_SAMPLES = 3000
#: Values closer than this count as one value when counting distinct ShDF levels.
VALUE_RESOLUTION = 1e-6
#: Smallest standard deviation of a component (keeps densities finite).
MIN_DEVIATION = 1e-3


@dataclass(frozen=True)
class Mixture:
    """A fitted 1-D Gaussian mixture, components sorted by mean."""

    means: NDArray[np.float64]
    deviations: NDArray[np.float64]
    weights: NDArray[np.float64]

    @property
    def size(self) -> int:
        return int(len(self.means))

    def log_joint(self, values: NDArray) -> NDArray[np.float64]:
        """(N, k) log of weight * density of each component at each value."""
        x = np.asarray(values, dtype=np.float64)[:, None]
        z = (x - self.means[None, :]) / self.deviations[None, :]
        return -0.5 * z * z + (np.log(self.weights) - np.log(self.deviations))[None, :]

    def posteriors(self, values: NDArray) -> NDArray[np.float64]:
        """(N, k) probability of each component given each value; rows sum to 1."""
        log_joint = self.log_joint(values)
        log_joint -= log_joint.max(axis=1, keepdims=True)
        np.exp(log_joint, out=log_joint)
        log_joint /= log_joint.sum(axis=1, keepdims=True)
        return log_joint


def subsample(values: NDArray, count: int, seed: int) -> NDArray[np.float64]:
    """At most ``count`` of ``values``, drawn with a seeded generator (all when fewer)."""
    values = np.asarray(values, dtype=np.float64)
    if len(values) <= count:
        return values
    rng = np.random.default_rng(seed)
    return values[rng.integers(0, len(values), size=count)]


def distinct_levels(values: NDArray) -> int:
    """How many distinct values (to ``VALUE_RESOLUTION``) there are."""
    return int(len(np.unique(np.round(np.asarray(values) / VALUE_RESOLUTION))))


def _fit_sklearn(sample: NDArray, clusters: int, seed: int):
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.mixture import GaussianMixture

    # Deterministic start: means at the sample's quantiles, equal weights, and
    # deviations from the spread of values around each mean.
    quantiles = (np.arange(clusters) + 0.5) / clusters
    means = np.quantile(sample, quantiles)
    spread = max(float(np.std(sample)), MIN_DEVIATION) / clusters
    model = GaussianMixture(
        n_components=clusters,
        covariance_type="full",
        tol=1e-3,
        max_iter=100,
        reg_covar=MIN_DEVIATION**2,
        init_params="random_from_data",  # cheap; fully overridden by the three inits
        means_init=means[:, None],
        weights_init=np.full(clusters, 1.0 / clusters),
        precisions_init=np.full((clusters, 1, 1), 1.0 / spread**2),
        random_state=seed,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model.fit(sample[:, None])
    return model


def fit_mixture(values: NDArray, clusters: int, seed: int = 0) -> Mixture:
    """Fit ``clusters`` Gaussians to 1-D ``values`` (fewer when there are fewer distinct values)."""
    sample = subsample(values, FIT_SAMPLES, seed)
    clusters = max(1, min(int(clusters), distinct_levels(sample)))
    if clusters == 1:
        return _single(sample)
    return _as_mixture(_fit_sklearn(sample, clusters, seed))


def fit_best_mixture(
    values: NDArray, seed: int = 0, candidates: Sequence[int] = CLUSTER_CANDIDATES
) -> Mixture:
    """The mixture with the lowest BIC among ``candidates`` sizes, on a seeded subsample.

    Candidates above the number of distinct values are skipped; a constant
    input gives one component.
    """
    sample = subsample(values, BIC_SAMPLES, seed)
    levels = distinct_levels(sample)
    usable = [k for k in candidates if 1 <= k <= levels]
    if not usable:
        return _single(sample)
    best, best_bic = None, np.inf
    for k in usable:
        if k == 1:
            mixture, bic = _single(sample), _bic_one(sample)
        else:
            model = _fit_sklearn(sample, k, seed)
            mixture, bic = _as_mixture(model), model.bic(sample[:, None])
        if bic < best_bic - 1e-9:
            best, best_bic = mixture, bic
    return best


def choose_cluster_count(
    values: NDArray, seed: int = 0, candidates: Sequence[int] = CLUSTER_CANDIDATES
) -> int:
    """Mixture size with the lowest BIC on a seeded subsample of ``values``."""
    return fit_best_mixture(values, seed, candidates).size


def _single(sample: NDArray) -> Mixture:
    return Mixture(
        np.array([float(np.mean(sample))]),
        np.array([max(float(np.std(sample)), MIN_DEVIATION)]),
        np.array([1.0]),
    )


def _as_mixture(model) -> Mixture:
    """A fitted scikit-learn model as a Mixture sorted by mean."""
    means = model.means_[:, 0]
    deviations = np.maximum(np.sqrt(model.covariances_.reshape(-1)), MIN_DEVIATION)
    weights = np.maximum(model.weights_, 1e-12)
    order = np.argsort(means, kind="stable")
    return Mixture(means[order], deviations[order], weights[order] / weights[order].sum())


def _bic_one(sample: NDArray) -> float:
    """BIC of a single Gaussian (closed form)."""
    deviation = max(float(np.std(sample)), MIN_DEVIATION)
    log_likelihood = -0.5 * len(sample) * (np.log(2 * np.pi * deviation**2) + 1.0)
    return float(-2.0 * log_likelihood + 2 * np.log(len(sample)))


def prefers_split(values: NDArray, seed: int = 0, separation: float = 2.0) -> bool:
    """Whether ``values`` look like two populations rather than one.

    True when BIC prefers two Gaussians over one, both carry at least 5% of the
    values, and their means are apart by Ashman's D >= ``separation``.
    """
    sample = subsample(values, BIC_SAMPLES, seed)
    if distinct_levels(sample) < 2 or len(sample) < 10:
        return False
    model = _fit_sklearn(sample, 2, seed)
    if model.bic(sample[:, None]) >= _bic_one(sample):
        return False
    if model.weights_.min() < 0.05:
        return False
    means = model.means_[:, 0]
    variances = model.covariances_.reshape(-1)
    ashman_d = np.sqrt(2.0) * abs(means[0] - means[1]) / np.sqrt(variances.sum())
    return bool(ashman_d >= separation)
