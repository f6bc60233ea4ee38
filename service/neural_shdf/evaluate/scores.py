"""The four segmentation metrics of the Princeton Segmentation Benchmark.

Chen, Golovinskiy, Funkhouser 2009, "A Benchmark for 3D Mesh Segmentation":
cut discrepancy (CD), Hamming distance (HD with its directional parts Rm and
Rf), Rand index (reported as 1 - RI) and the global / local consistency errors
(GCE, LCE). Every metric is a dissimilarity: 0 for identical segmentations,
lower is better.

Conventions (all functions are pure: arrays in, floats out):

* ``labels`` (``computed``) is the segmentation under test, ``reference`` the
  ground truth (a human's). Only CD, 1 - RI and HD are symmetric; Rm/Rf swap
  and GCE/LCE are symmetric by construction.
* ``weights`` is one non-negative mass per face. ``None`` counts faces (every
  face weighs 1), which is what the benchmark's ``segEval`` reports for its
  region metrics; pass face areas for the area-weighted variant the paper
  mentions ("||x|| is the size of set x, or the total area of its faces").
  With unit weights the Rand index is the exact per-face-pair count.
* Labels are arbitrary integers; only the partition they induce matters.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import linear_sum_assignment
from scipy.sparse.csgraph import dijkstra

from neural_shdf.arrays import unique_rows
from neural_shdf.geometry import face_normals, weld_faces

#: Metric names in table order.
METRIC_NAMES: tuple[str, ...] = ("cd", "hd", "rm", "rf", "ri_error", "gce", "lce")


@dataclass(frozen=True)
class SegmentationScores:
    """The benchmark's metrics for one (computed, reference) pair, or an average.

    ``cd`` is NaN when it is undefined (exactly one of the two has no cut).
    """

    cd: float
    hd: float
    rm: float
    rf: float
    ri_error: float
    gce: float
    lce: float

    def as_dict(self) -> dict[str, float]:
        return {f.name: float(getattr(self, f.name)) for f in fields(self)}

    @staticmethod
    def mean(scores: list[SegmentationScores]) -> SegmentationScores:
        """Per-metric mean, ignoring NaN (an undefined CD); NaN when all are NaN."""
        if not scores:
            raise ValueError("cannot average an empty list of scores")
        values = np.array([[getattr(s, n) for n in METRIC_NAMES] for s in scores], float)
        with np.errstate(invalid="ignore"):
            counts = np.sum(~np.isnan(values), axis=0)
            sums = np.nansum(values, axis=0)
            means = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
        return SegmentationScores(*(float(m) for m in means))


def _dense_labels(labels: ArrayLike) -> NDArray[np.int64]:
    """Labels renumbered 0..P-1 (order of first appearance irrelevant)."""
    _, dense = np.unique(np.asarray(labels).reshape(-1), return_inverse=True)
    return dense.astype(np.int64)


def _face_weights(weights: ArrayLike | None, count: int) -> NDArray[np.float64]:
    if weights is None:
        return np.ones(count)
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(w) != count:
        raise ValueError(f"{len(w)} weights for {count} faces")
    if np.any(w < 0) or not np.all(np.isfinite(w)):
        raise ValueError("face weights must be finite and non-negative")
    return w


def overlap_matrix(
    labels: ArrayLike, reference: ArrayLike, weights: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Contingency table: mass of faces in computed segment i and reference segment j."""
    a, b = _dense_labels(labels), _dense_labels(reference)
    if len(a) != len(b):
        raise ValueError(f"segmentations differ in face count: {len(a)} vs {len(b)}")
    w = _face_weights(weights, len(a))
    rows, cols = int(a.max(initial=-1)) + 1, int(b.max(initial=-1)) + 1
    table = np.bincount(a * cols + b, weights=w, minlength=rows * cols)
    return table.reshape(rows, cols)


def hamming_distance(
    labels: ArrayLike, reference: ArrayLike, weights: ArrayLike | None = None
) -> tuple[float, float, float]:
    """(HD, Rm, Rf): Hamming distance and its missing / false-alarm rates.

    D_H(S1 => S2) = sum over reference segments of the mass not covered by the
    computed segment that overlaps it most; Rm = D_H(S1 => S2) / total and
    Rf = D_H(S2 => S1) / total; HD = (Rm + Rf) / 2.
    """
    table = overlap_matrix(labels, reference, weights)
    total = table.sum()
    if total <= 0:
        return 0.0, 0.0, 0.0
    # Clipped: float sums may leave a rounding residue just below 0.
    rm = min(max((total - table.max(axis=0).sum()) / total, 0.0), 1.0)
    rf = min(max((total - table.max(axis=1).sum()) / total, 0.0), 1.0)
    return float((rm + rf) / 2), float(rm), float(rf)


def rand_index_error(
    labels: ArrayLike, reference: ArrayLike, weights: ArrayLike | None = None
) -> float:
    """1 - RI: the share of face pairs that one segmentation joins and the other splits.

    Pairs {i, j} of distinct faces count with mass w_i * w_j. With a_k, b_l the
    segment masses and n_kl the overlaps, the disagreeing mass is
    sum a_k^2 + sum b_l^2 - 2 sum n_kl^2 (the i = j terms cancel) and the total
    pair mass W^2 - sum w_i^2 (both doubled, as ordered pairs).
    """
    table = overlap_matrix(labels, reference, weights)
    w = _face_weights(weights, int(np.asarray(labels).size))
    total_pairs = w.sum() ** 2 - np.sum(w**2)
    if total_pairs <= 0:
        return 0.0
    disagree = (
        np.sum(table.sum(axis=1) ** 2) + np.sum(table.sum(axis=0) ** 2) - 2 * np.sum(table**2)
    )
    return float(min(max(disagree / total_pairs, 0.0), 1.0))


def consistency_errors(
    labels: ArrayLike, reference: ArrayLike, weights: ArrayLike | None = None
) -> tuple[float, float]:
    """(GCE, LCE) of Martin et al., as the benchmark applies them to faces.

    E(S1, S2, f) = |R(S1, f) minus R(S2, f)| / |R(S1, f)|, the share of f's
    segment in S1 that is not in f's segment in S2. GCE = min of the two
    directional averages; LCE = average of the per-face minimum; LCE <= GCE.
    """
    a, b = _dense_labels(labels), _dense_labels(reference)
    table = overlap_matrix(a, b, weights)
    w = _face_weights(weights, len(a))
    total = w.sum()
    if total <= 0:
        return 0.0, 0.0
    size_a, size_b, both = table.sum(axis=1)[a], table.sum(axis=0)[b], table[a, b]
    with np.errstate(invalid="ignore", divide="ignore"):
        e_ab = np.clip(np.where(size_a > 0, (size_a - both) / size_a, 0.0), 0.0, 1.0)
        e_ba = np.clip(np.where(size_b > 0, (size_b - both) / size_b, 0.0), 0.0, 1.0)
    gce = min(np.dot(w, e_ab), np.dot(w, e_ba)) / total
    lce = np.dot(w, np.minimum(e_ab, e_ba)) / total
    return float(gce), float(lce)


def matched_accuracy(
    labels: ArrayLike, reference: ArrayLike, weights: ArrayLike | None = None
) -> float:
    """Share of the mass whose segment is matched to its reference label, one-to-one.

    Segments are matched to reference labels by the Hungarian method (maximum
    total overlap, each segment to at most one label and back); faces of an
    unmatched segment count as wrong. The accuracy that labelled benchmarks
    (e.g. the human body set) report for methods that output unnamed parts.
    """

    table = overlap_matrix(labels, reference, weights)
    total = table.sum()
    if total <= 0:
        return 1.0
    rows, cols = linear_sum_assignment(table, maximize=True)
    return float(min(max(table[rows, cols].sum() / total, 0.0), 1.0))


def average_radius(vertices: ArrayLike, faces: ArrayLike) -> float:
    """Area-weighted mean distance from a surface point (face centroid) to the area centroid."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    _, areas = face_normals(vertices, faces)
    centroids = vertices[faces].mean(axis=1)
    total = areas.sum()
    if total <= 0:
        return 0.0
    center = (areas[:, None] * centroids).sum(axis=0) / total
    return float(np.dot(areas, np.linalg.norm(centroids - center, axis=1)) / total)


@dataclass(frozen=True)
class CutGraph:
    """What cut discrepancy needs of a mesh, computed once and reused for many pairs.

    Attributes:
        edges: (E, 2) welded vertex indices of interior edges (shared by exactly
            two faces), each once.
        edge_faces: (E, 2) the two faces of each edge.
        graph: CSR vertex graph of all mesh edges weighted by length.
        radius: ``average_radius`` of the mesh (CD's normaliser).
        face_count: number of faces.
    """

    edges: NDArray[np.int64]
    edge_faces: NDArray[np.int64]
    graph: sp.csr_matrix
    radius: float
    face_count: int


def cut_graph(vertices: ArrayLike, faces: ArrayLike) -> CutGraph:
    """Prepare a mesh for ``cut_discrepancy`` (coincident vertices are welded)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    welded = weld_faces(vertices, faces)
    # Position of each welded vertex index (weld_faces renumbers vertices).
    positions = np.zeros((int(welded.max(initial=-1)) + 1, 3))
    positions[welded.reshape(-1)] = vertices[faces.reshape(-1)]
    half = np.sort(welded[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    face_of = np.repeat(np.arange(len(welded)), 3)
    keep = half[:, 0] != half[:, 1]
    half, face_of = half[keep], face_of[keep]
    unique, inverse, counts = unique_rows(half, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    # Interior edges: exactly two faces; collect them in edge order.
    order = np.argsort(inverse, kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    two = np.flatnonzero(counts == 2)
    edge_faces = np.stack([face_of[order[starts[two]]], face_of[order[starts[two] + 1]]], axis=1)
    length = np.linalg.norm(positions[unique[:, 0]] - positions[unique[:, 1]], axis=1)
    n = len(positions)
    rows = np.concatenate([unique[:, 0], unique[:, 1]])
    cols = np.concatenate([unique[:, 1], unique[:, 0]])
    graph = sp.coo_matrix((np.concatenate([length, length]), (rows, cols)), shape=(n, n)).tocsr()
    return CutGraph(unique[two], edge_faces, graph, average_radius(vertices, faces), len(welded))


def cut_vertices(mesh: CutGraph, labels: ArrayLike) -> NDArray[np.int64]:
    """Vertices on the cut: endpoints of interior edges whose two faces differ in label."""
    labels = np.asarray(labels).reshape(-1)
    cut = labels[mesh.edge_faces[:, 0]] != labels[mesh.edge_faces[:, 1]]
    return np.unique(mesh.edges[cut])


def cut_distance_field(mesh: CutGraph, labels: ArrayLike) -> NDArray[np.float64] | None:
    """Distance along mesh edges from every vertex to the nearest cut vertex; None if no cut."""
    cut = cut_vertices(mesh, labels)
    if len(cut) == 0:
        return None
    return dijkstra(mesh.graph, directed=False, indices=cut, min_only=True)


def cut_discrepancy(
    mesh: CutGraph,
    labels: ArrayLike,
    reference: ArrayLike,
    *,
    labels_field: NDArray | None = None,
    reference_field: NDArray | None = None,
) -> float:
    """CD: mean surface distance between the two segmentations' cuts, over the average radius.

    Distances run along mesh edges (Dijkstra from every vertex of one cut at
    once) from each cut vertex of one segmentation to the nearest cut vertex of
    the other, both directions pooled into one mean (as segEval's code does;
    the paper writes the sum of the two directional means). 0 when neither
    has a cut; NaN when exactly one has none (undefined). ``*_field`` are
    optional precomputed ``cut_distance_field`` results (to reuse across pairs).
    """
    cut_a, cut_b = cut_vertices(mesh, labels), cut_vertices(mesh, reference)
    if len(cut_a) == 0 and len(cut_b) == 0:
        return 0.0
    if len(cut_a) == 0 or len(cut_b) == 0 or mesh.radius <= 0:
        return float("nan")
    field_a = cut_distance_field(mesh, labels) if labels_field is None else labels_field
    field_b = cut_distance_field(mesh, reference) if reference_field is None else reference_field
    pooled = np.concatenate([field_b[cut_a], field_a[cut_b]])
    # Cut vertices on another shell than the other cut are infinitely far: ignored.
    pooled = pooled[np.isfinite(pooled)]
    if len(pooled) == 0:
        return float("nan")
    return float(pooled.mean() / mesh.radius)


def score_segmentation(
    mesh: CutGraph,
    labels: ArrayLike,
    reference: ArrayLike,
    weights: ArrayLike | None = None,
    *,
    labels_field: NDArray | None = None,
    reference_field: NDArray | None = None,
) -> SegmentationScores:
    """All metrics of ``labels`` against one ``reference`` segmentation of the same faces.

    ``*_field``: optional precomputed ``cut_distance_field`` of either side.
    """
    labels = np.asarray(labels).reshape(-1)
    reference = np.asarray(reference).reshape(-1)
    if len(labels) != mesh.face_count or len(reference) != mesh.face_count:
        raise ValueError(
            f"segmentations have {len(labels)} and {len(reference)} labels"
            f" for a mesh of {mesh.face_count} faces"
        )
    hd, rm, rf = hamming_distance(labels, reference, weights)
    gce, lce = consistency_errors(labels, reference, weights)
    return SegmentationScores(
        cd=cut_discrepancy(
            mesh, labels, reference, labels_field=labels_field, reference_field=reference_field
        ),
        hd=hd,
        rm=rm,
        rf=rf,
        ri_error=rand_index_error(labels, reference, weights),
        gce=gce,
        lce=lce,
    )


def score_against_humans(
    mesh: CutGraph,
    labels: ArrayLike,
    references: list[ArrayLike],
    weights: ArrayLike | None = None,
    *,
    reference_fields: list[NDArray | None] | None = None,
) -> SegmentationScores:
    """Metrics of one segmentation averaged over all human segmentations of its model.

    ``reference_fields``: optional precomputed ``cut_distance_field`` per reference.
    """
    if not references:
        raise ValueError("no reference segmentation to compare with")
    if reference_fields is None:
        reference_fields = [cut_distance_field(mesh, ref) for ref in references]
    labels_field = cut_distance_field(mesh, labels)
    return SegmentationScores.mean(
        [
            score_segmentation(
                mesh, labels, ref, weights, labels_field=labels_field, reference_field=field
            )
            for ref, field in zip(references, reference_fields, strict=True)
        ]
    )
