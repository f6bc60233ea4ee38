"""Soft clustering of per-face ShDF values with a 1-D Gaussian mixture (CGAL's first step).

A 1-D distribution is summarised exactly enough by a 256-bin histogram of
the (log-normalised, [0, 1]) values, so EM runs on the histogram: its cost no
longer grows with the face count, there is no sampling, and the fit is
deterministic. (scikit-learn's GaussianMixture on raw values gives the same
fit - the tests check that - but its per-iteration overhead alone, times the
7 candidate sizes of the BIC search, exceeded the time budget of large meshes.)
Posteriors for every face are then evaluated in numpy.

Each face counts once, as in CGAL, on a mesh tessellated about evenly; where a mesh has
many more faces than its surface's resolution (a sculpted or densely scanned detail on a
coarse body, dense curved detail beside large flat panels), faces count towards their area
(``value_weights``), so that the finely tessellated region does not decide the mixture for
the whole surface.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.geometry import equivalent_face_count
from neural_shdf.segment.params import CLUSTER_CANDIDATES

#: Histogram bins over [0, 1] the mixture is fitted on.
HISTOGRAM_BINS = 256
#: BIC counts at most this many values (its penalty grows with log n).
BIC_SAMPLES = 3000
#: EM stops when the log-likelihood per value improves by less than this.
EM_TOLERANCE = 1e-4
EM_MAX_ITERATIONS = 200
#: Smallest standard deviation of a component (keeps densities finite).
MIN_DEVIATION = 1e-3
#: A mesh with more than this many faces per face of its surface's resolution (face count
#: over ``geometry.equivalent_face_count``) is unevenly tessellated: its mixture weighs
#: faces towards their areas, fully from twice this ratio (``value_weights``). The
#: ratio is at most 1.8 on psb-dev, 1.22 on the human body set and 2.6 on the dense-dev
#: scans (none of which this changes); a fifth of a psb-dev mesh split to ~100k faces
#: reaches 2.5-55, of a 1,500-face human body 63-74; half the training corpus's web and
#: CAD models (285 of 565: flat panels beside dense detail) are above it, and their parts
#: depend less on the tessellation with the weights (``benchmarks/bench_tessellation.py``).
UNEVEN_TESSELLATION = 3.0


@dataclass(frozen=True)
class Mixture:
    """A fitted 1-D Gaussian mixture, components sorted by mean."""

    means: NDArray[np.float64]
    deviations: NDArray[np.float64]
    weights: NDArray[np.float64]

    @property
    def size(self) -> int:
        return int(len(self.means))

    def log_joint(self, values: NDArray[Any]) -> NDArray[np.float64]:
        """(N, k) log of weight * density of each component at each value."""
        x = np.asarray(values, dtype=np.float64)[:, None]
        z = (x - self.means[None, :]) / self.deviations[None, :]
        joint: NDArray[np.float64] = (
            -0.5 * z * z + (np.log(self.weights) - np.log(self.deviations))[None, :]
        )
        return joint

    def posteriors(self, values: NDArray[Any]) -> NDArray[np.float64]:
        """(N, k) probability of each component given each value; rows sum to 1."""
        return _posteriors(
            np.asarray(values, dtype=np.float64).reshape(-1),
            self.means,
            self.deviations,
            np.log(self.weights) - np.log(self.deviations),
        )


@kernel
def _posteriors(
    values: NDArray[np.float64],
    means: NDArray[np.float64],
    deviations: NDArray[np.float64],
    log_scale: NDArray[np.float64],
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Softmax over components of ``log_joint``, row by row (one pass, no (N, k) temporaries)."""
    count, size = len(values), len(means)
    result = np.empty((count, size))
    for row in range(count):
        top = -np.inf
        for c in range(size):
            z = (values[row] - means[c]) / deviations[c]
            result[row, c] = -0.5 * z * z + log_scale[c]
            top = max(top, result[row, c])
        total = 0.0
        for c in range(size):
            result[row, c] = np.exp(result[row, c] - top)
            total += result[row, c]
        for c in range(size):
            result[row, c] /= total
    return result


def value_weights(
    areas: NDArray[Any], equivalent_faces: Callable[[], float] | None = None
) -> NDArray[np.float64] | None:
    """How much each face's value counts in the mixture's fit: ``None`` (once each) on a
    mesh tessellated about evenly, else ``(area / mean area) ** blend``, scaled to sum to
    the face count, where ``blend`` rises from 0 to 1 as the face count goes from
    ``UNEVEN_TESSELLATION`` to twice that times the surface's resolution
    (``geometry.equivalent_face_count``): no jump at any ratio.

    Counting faces lets a finely split region decide the mixture: a fifth of a 1,500-face
    body split to 100k faces gets nearly every face, its parts then fall under the part
    tree's threshold and the body comes out in 3-5 parts instead of 11-14
    (``benchmarks/bench_production.py --variants refined``). Below the ratio the count
    is kept: there, where artists put more faces is where the detail is, and the part
    tree was tuned on such fits. ``equivalent_faces``: how to get the equivalent count
    where the caller keeps it (asked only where a face is over 3x the mean area).
    """
    areas = np.asarray(areas, dtype=np.float64).reshape(-1)
    mean = float(areas.mean()) if len(areas) else 0.0
    # The ratio is the area-weighted median face area over the mean area, at most the
    # largest over the mean: most meshes are decided by one pass over the areas.
    if not mean > 0 or float(areas.max()) <= UNEVEN_TESSELLATION * mean:
        return None
    equivalent = equivalent_face_count(areas) if equivalent_faces is None else equivalent_faces()
    if not equivalent > 0:
        return None
    ratio = len(areas) / equivalent
    blend = float(np.clip(np.log2(ratio / UNEVEN_TESSELLATION), 0.0, 1.0))
    if blend <= 0.0:
        return None
    weights: NDArray[np.float64] = (areas / mean) ** blend
    weights *= len(areas) / weights.sum()
    return weights


def histogram(
    values: NDArray[Any], bins: int = HISTOGRAM_BINS, weights: NDArray[Any] | None = None
) -> tuple[NDArray[Any], NDArray[Any]]:
    """Bin centres and counts of values in [0, 1] (the sufficient data of a 1-D fit);
    with ``weights`` (one per value), the bins sum them instead of counting."""
    values = np.clip(np.asarray(values, dtype=np.float64), 0.0, 1.0)
    index = np.minimum((values * bins).astype(np.int64), bins - 1)
    per_value = None if weights is None else np.asarray(weights, dtype=np.float64)
    counts = np.bincount(index, weights=per_value, minlength=bins).astype(np.float64)
    used = counts > 0
    return ((np.arange(bins) + 0.5) / bins)[used], counts[used]


def em_fit(
    centres: NDArray[Any],
    counts: NDArray[Any],
    clusters: int,
    sample_size: float,
    min_deviation: float = MIN_DEVIATION,
    max_deviation: float = np.inf,
) -> tuple[Mixture, float]:
    """EM for a 1-D Gaussian mixture on binned data; returns the mixture and its BIC.

    Counts are rescaled to ``sample_size`` points, which sets how strongly BIC
    penalises extra components. Starts from quantile means, equal weights and
    a shared deviation; deterministic. No component is narrower than ``min_deviation``
    nor broader than ``max_deviation``.
    """
    weights_n = counts / counts.sum() * sample_size
    total = weights_n.sum()
    cumulative = np.cumsum(weights_n) / total
    quantiles = (np.arange(clusters) + 0.5) / clusters
    means = centres[np.minimum(np.searchsorted(cumulative, quantiles), len(centres) - 1)]
    overall_mean = float(np.sum(weights_n * centres) / total)
    overall_sd = float(np.sqrt(np.sum(weights_n * (centres - overall_mean) ** 2) / total))
    deviations = np.full(clusters, max(overall_sd / clusters, min_deviation))
    mixing = np.full(clusters, 1.0 / clusters)
    previous = -np.inf
    log_norm = 0.5 * np.log(2 * np.pi)
    for _ in range(EM_MAX_ITERATIONS):
        z = (centres[:, None] - means[None, :]) / deviations[None, :]
        log_joint = -0.5 * z * z + np.log(mixing / deviations)[None, :] - log_norm
        top = log_joint.max(axis=1, keepdims=True)
        joint = np.exp(log_joint - top)
        row = joint.sum(axis=1, keepdims=True)
        log_likelihood = float(np.sum(weights_n * (np.log(row[:, 0]) + top[:, 0])))
        responsibility = joint / row * weights_n[:, None]
        mass = np.maximum(responsibility.sum(axis=0), 1e-12)
        means = (responsibility * centres[:, None]).sum(axis=0) / mass
        variance = (responsibility * (centres[:, None] - means[None, :]) ** 2).sum(axis=0) / mass
        deviations = np.minimum(np.sqrt(np.maximum(variance, min_deviation**2)), max_deviation)
        mixing = np.maximum(mass / total, 1e-12)
        mixing /= mixing.sum()
        if log_likelihood - previous < EM_TOLERANCE * total:
            break
        previous = log_likelihood
    order = np.argsort(means, kind="stable")
    bic = -2.0 * log_likelihood + (3 * clusters - 1) * np.log(total)
    return Mixture(means[order], deviations[order], mixing[order]), float(bic)


def fit_mixture(
    values: NDArray[Any],
    clusters: int,
    seed: int = 0,
    min_deviation: float = MIN_DEVIATION,
    weights: NDArray[Any] | None = None,
    max_deviation: float = np.inf,
) -> Mixture:
    """Fit ``clusters`` Gaussians to values in [0, 1] (fewer if there are fewer distinct bins),
    none narrower than ``min_deviation`` nor broader than ``max_deviation``; ``weights``:
    ``value_weights`` of the faces.

    ``seed`` is accepted for a uniform interface; the fit is deterministic.
    """
    centres, counts = histogram(values, weights=weights)
    clusters = max(1, min(int(clusters), len(centres)))
    return em_fit(centres, counts, clusters, float(counts.sum()), min_deviation, max_deviation)[0]


def fit_best_mixture(
    values: NDArray[Any],
    seed: int = 0,
    candidates: Sequence[int] = CLUSTER_CANDIDATES,
    weights: NDArray[Any] | None = None,
) -> Mixture:
    """The mixture with the lowest BIC among ``candidates`` sizes (1 bin: one component).

    BIC is computed as if there were at most ``BIC_SAMPLES`` values, so that
    on big meshes extra components must explain real structure, not noise.
    The chosen mixture is refitted on all values (``weights`` as ``fit_mixture``).
    """
    centres, counts = histogram(values, weights=weights)
    usable = [k for k in candidates if 1 <= k <= len(centres)]
    if not usable:
        return em_fit(centres, counts, 1, float(counts.sum()))[0]
    sample_size = min(float(counts.sum()), BIC_SAMPLES)
    bics = [em_fit(centres, counts, k, sample_size)[1] for k in usable]
    best = usable[int(np.argmin(bics))]
    return em_fit(centres, counts, best, float(counts.sum()))[0]


def choose_cluster_count(
    values: NDArray[Any], seed: int = 0, candidates: Sequence[int] = CLUSTER_CANDIDATES
) -> int:
    """Mixture size with the lowest BIC (see ``fit_best_mixture``)."""
    return fit_best_mixture(values, seed, candidates).size


def prefers_split(
    values: NDArray[Any],
    seed: int = 0,
    separation: float = 2.0,
    weights: NDArray[Any] | None = None,
) -> bool:
    """Whether ``values`` look like two populations rather than one.

    True when BIC prefers two Gaussians over one, both carry at least 5% of the
    values, and their means are apart by Ashman's D >= ``separation`` (``weights`` as
    ``fit_mixture``).
    """
    centres, counts = histogram(values, weights=weights)
    if len(centres) < 2 or counts.sum() < 10:
        return False
    sample_size = min(float(counts.sum()), BIC_SAMPLES)
    _, bic_one = em_fit(centres, counts, 1, sample_size)
    two, bic_two = em_fit(centres, counts, 2, sample_size)
    if bic_two >= bic_one or two.weights.min() < 0.05:
        return False
    spread = np.sqrt(np.sum(two.deviations**2))
    ashman_d = np.sqrt(2.0) * abs(two.means[1] - two.means[0]) / spread
    return bool(ashman_d >= separation)
