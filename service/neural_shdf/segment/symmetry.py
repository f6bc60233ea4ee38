"""A global reflective symmetry of a mesh, and ShDF values made to agree across it.

``detect_reflection`` tries the planes through the area-weighted centroid normal to each
principal axis, refines each from the face pairs it matches (reflected centroid onto the
nearest face centroid, with a mirrored normal), and keeps the plane that pairs the largest
share of the surface, when that share reaches ``MIN_MATCHED_AREA``. The test is geometric
only: the ShDF of a solid is a function of its shape, so a mirror-symmetric surface has a
mirror-symmetric ShDF, up to the estimator's noise (rays, samples, the network), which
is what averaging takes out; a per-face ShDF test would refuse exactly the faces where
that noise is large.
``symmetrize`` averages per-face values with the mirror face's, so the mixture, the graph
cut's data costs and the part tree's merge costs see the same evidence on both sides: a
symmetric shape is cut alike on both sides (the smoothness term is geometric, so it is
symmetric up to the tessellation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from neural_shdf.geometry import principal_frame

#: Share of the surface area a plane must pair with mirror faces to count as a symmetry.
MIN_MATCHED_AREA = 0.9
#: A reflected centroid pairs with a face closer than this fraction of the bounding box's
#: diagonal (or 1.5 times the median face's side, on a coarse mesh).
MATCH_DISTANCE = 0.015
#: ... whose normal is within about 60 degrees of the reflected normal.
MIN_NORMAL_COSINE = 0.5
#: Refinements of each candidate plane from the pairs it matches.
REFINEMENTS = 3
#: Faces the candidate planes are tried on (a regular sample of larger meshes).
SAMPLE_FACES = 4000


@dataclass(frozen=True)
class Reflection:
    """A mirror plane ``{x : normal . x = offset}`` and each face's mirror face.

    Attributes:
        normal: (3,) unit normal of the plane.
        offset: the plane's distance from the origin along ``normal``.
        mirror: (F,) the face nearest each face's reflection (with a mirrored normal),
            -1 where none is near enough.
        matched_area: share of the surface area with a mirror face.
    """

    normal: NDArray[np.float64]
    offset: float
    mirror: NDArray[np.int64]
    matched_area: float


def _reflect(points: NDArray, normal: NDArray, offset: float) -> NDArray[np.float64]:
    return points - 2.0 * (points @ normal - offset)[:, None] * normal


def _pairs(
    tree: cKDTree,
    centroids: NDArray,
    normals: NDArray,
    normal: NDArray,
    offset: float,
    distance: float,
    faces: NDArray[np.int64],
) -> NDArray[np.int64]:
    """The mirror face of each of ``faces`` for this plane (-1: none within the limits)."""
    # Bounded: a point with no face within ``distance`` is answered at once (n: none).
    found_distance, found = tree.query(
        _reflect(centroids[faces], normal, offset), k=1, distance_upper_bound=distance
    )
    found = np.minimum(np.asarray(found, dtype=np.int64), len(centroids) - 1)
    own = normals[faces]
    mirrored = own - 2.0 * (own @ normal)[:, None] * normal
    ok = (found_distance <= distance) & (
        np.sum(mirrored * normals[found], axis=1) >= MIN_NORMAL_COSINE
    )
    return np.where(ok, found, -1)


def _refit(
    centroids: NDArray, areas: NDArray, faces: NDArray, mirror: NDArray, normal: NDArray
) -> tuple[NDArray[np.float64], float] | None:
    """The plane that best bisects the matched pairs of ``faces`` (None: too few)."""
    matched = mirror >= 0
    if matched.sum() < 3:
        return None
    paired, mirror = faces[matched], mirror[matched]
    gap = centroids[paired] - centroids[mirror]
    sign = np.sign(gap @ normal)
    direction = ((gap * sign[:, None]) * areas[paired, None]).sum(axis=0)
    length = float(np.linalg.norm(direction))
    if length == 0.0:
        return None
    fitted = direction / length
    middle = 0.5 * (centroids[paired] + centroids[mirror])
    offset = float(np.average(middle @ fitted, weights=areas[paired]))
    return fitted, offset


def detect_reflection(centroids: NDArray, normals: NDArray, areas: NDArray) -> Reflection | None:
    """The mesh's global reflective symmetry, or None when no plane pairs at least
    ``MIN_MATCHED_AREA`` of the surface. Per-face ``centroids``, unit ``normals`` and
    ``areas``. Deterministic."""
    centroids = np.asarray(centroids, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    areas = np.asarray(areas, dtype=np.float64)
    total = float(areas.sum())
    if len(areas) < 4 or total <= 0:
        return None
    centre, axes = principal_frame(centroids, areas)
    axes = axes[:, ::-1]  # planes across the smallest spread first
    diagonal = float(np.linalg.norm(centroids.max(axis=0) - centroids.min(axis=0)))
    distance = max(MATCH_DISTANCE * diagonal, 1.5 * float(np.sqrt(2.0 * np.median(areas))))
    tree = cKDTree(centroids)
    # The planes are found on a sample of the faces (every n-th: deterministic), the
    # mirror of every face only for the best one.
    sample = np.arange(0, len(areas), max(1, len(areas) // SAMPLE_FACES), dtype=np.int64)
    sample_area = float(areas[sample].sum())
    best: tuple[float, NDArray[np.float64], float] | None = None
    for axis in range(3):
        normal = axes[:, axis] / np.linalg.norm(axes[:, axis])
        offset = float(normal @ centre)
        for round_ in range(REFINEMENTS + 1):
            # Looser pairs first, while the plane is still the principal axes' guess.
            limit = distance * (3.0 if round_ == 0 else 1.0)
            mirror = _pairs(tree, centroids, normals, normal, offset, limit, sample)
            if round_ == REFINEMENTS:
                break
            fitted = _refit(centroids, areas, sample, mirror, normal)
            if fitted is None:
                break
            normal, offset = fitted
        matched = float(areas[sample[mirror >= 0]].sum() / sample_area)
        if best is None or matched > best[0]:
            best = (matched, normal, offset)
    if best is None or best[0] < MIN_MATCHED_AREA:
        return None
    _, normal, offset = best
    everyone = np.arange(len(areas), dtype=np.int64)
    mirror = _pairs(tree, centroids, normals, normal, offset, distance, everyone)
    matched = float(areas[mirror >= 0].sum() / total)
    if matched < MIN_MATCHED_AREA:
        return None
    return Reflection(normal, offset, mirror, matched)


def symmetrize(values: NDArray, mirror: NDArray) -> NDArray[np.float64]:
    """Per-face ``values`` averaged with their mirror face's (unchanged where -1)."""
    values = np.asarray(values, dtype=np.float64)
    mirror = np.asarray(mirror, dtype=np.int64)
    paired = mirror >= 0
    out = values.copy()
    out[paired] = 0.5 * (values[paired] + values[mirror[paired]])
    return out


def mirror_parts(
    parts: NDArray, reflection: Reflection, centroids: NDArray, areas: NDArray
) -> NDArray[np.int64]:
    """Parts cut as exact mirror images on the two sides of the plane: each face on the
    negative side whose mirror face is on the positive side takes the positive side's cut.

    A positive-side part whose mirror image lies mostly (by area) in itself crosses the
    plane: its mirror faces join it. Any other part is given a new label on the negative
    side, its mirror copy (the left wing's copy replaces whatever the right wing was cut
    into). Faces without a mirror keep their part; so do all positive-side faces. Where the
    mirror map pairs faces both ways (a symmetric tessellation) the result is exact:
    faces i, j share a part if and only if their mirror faces do. Returns labels that
    are not canonical and may leave small pieces where no face had a mirror (the caller
    splits them into connected parts and merges tiny ones).
    """
    parts = np.asarray(parts, dtype=np.int64)
    mirror = np.asarray(reflection.mirror, dtype=np.int64)
    normal = np.asarray(reflection.normal, dtype=np.float64)
    offset = float(reflection.offset)
    # The positive side is the one the normal's largest component points to (the fitted
    # normal's sign is arbitrary): the same side whatever the mesh's face order.
    if normal[np.argmax(np.abs(normal))] < 0:
        normal, offset = -normal, -offset
    side = np.asarray(centroids, dtype=np.float64) @ normal - offset
    has = mirror >= 0
    copy = np.flatnonzero(has & (side < 0) & (side[np.where(has, mirror, 0)] >= 0))
    if len(copy) == 0:
        return parts.copy()
    source = parts[mirror[copy]]
    count = int(parts.max()) + 1
    weight = np.asarray(areas, dtype=np.float64)[copy]
    # Per positive-side part: the share of its mirror image's area that it holds itself.
    image = np.bincount(source, weights=weight, minlength=count)
    inside = np.bincount(source, weights=weight * (parts[copy] == source), minlength=count)
    crosses = inside >= 0.5 * image
    out = parts.copy()
    out[copy] = np.where(crosses[source], source, count + source)
    return out


def mirror_leaves(leaves: NDArray, mirror: NDArray, areas: NDArray) -> NDArray[np.int64]:
    """The mirror image of each part of ``leaves`` (canonical labels 0..L-1): the part that
    holds most (by area) of its faces' mirror faces, kept where the two parts are each
    other's image (a part across the plane is its own); -1 elsewhere."""
    leaves = np.asarray(leaves, dtype=np.int64)
    mirror = np.asarray(mirror, dtype=np.int64)
    count = int(leaves.max()) + 1 if len(leaves) else 0
    best = np.full(count, -1, dtype=np.int64)
    has = np.flatnonzero(mirror >= 0)
    if len(has) == 0:
        return best
    keys, inverse = np.unique(leaves[has] * count + leaves[mirror[has]], return_inverse=True)
    weight = np.bincount(inverse.reshape(-1), weights=np.asarray(areas, np.float64)[has])
    source, image = keys // count, keys % count
    order = np.lexsort((-weight, source))  # per source, the heaviest image first
    first = order[np.r_[True, source[order][1:] != source[order][:-1]]]
    best[source[first]] = image[first]
    mutual = (best >= 0) & (best[np.maximum(best, 0)] == np.arange(count))
    return np.where(mutual, best, -1)


def mirror_agreement(labels: NDArray, mirror: NDArray, areas: NDArray) -> float:
    """How alike the two sides are cut: the area-weighted Rand index between the labels and
    the labels of the mirror faces, over the faces that have one. 1: the mirror image of
    the segmentation is the segmentation itself (a left part mirrors a right part, whatever
    their labels); lower: parts cut differently on the two sides. NaN: no face has a mirror.
    """
    labels = np.asarray(labels, dtype=np.int64)
    mirror = np.asarray(mirror, dtype=np.int64)
    paired = np.flatnonzero(mirror >= 0)
    if len(paired) == 0:
        return float("nan")
    own, other = labels[paired], labels[mirror[paired]]
    weight = np.asarray(areas, dtype=np.float64)[paired]
    total = float(weight.sum())
    _, own = np.unique(own, return_inverse=True)
    _, other = np.unique(other, return_inverse=True)
    joint = np.bincount(own * (other.max() + 1) + other, weights=weight)
    rows = np.bincount(own, weights=weight)
    cols = np.bincount(other, weights=weight)
    disagree = (rows**2).sum() + (cols**2).sum() - 2.0 * (joint**2).sum()
    return float(1.0 - disagree / total**2)


__all__ = [
    "MIN_MATCHED_AREA",
    "Reflection",
    "detect_reflection",
    "mirror_agreement",
    "mirror_leaves",
    "mirror_parts",
    "symmetrize",
]
