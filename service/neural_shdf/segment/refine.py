"""Optional post-steps of the seed paper: recursive refinement and boundary smoothing."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.geometry import FaceGraph
from neural_shdf.segment.graphcut import (
    banded_alpha_expansion,
    data_costs,
    multilevel_alpha_expansion,
    near_boundary,
)
from neural_shdf.segment.mixture import fit_best_mixture, prefers_split, value_weights
from neural_shdf.segment.params import SegmentParams
from neural_shdf.segment.parts import (
    FaceData,
    canonical_labels,
    connected_parts,
    induced_subgraph,
    merge_small_parts,
)
from neural_shdf.shdf.postprocess import linear_normalize, log_normalize

#: Parts with fewer faces are never refined.
MIN_REFINE_FACES = 100
#: Mixture sizes tried inside a part.
REFINE_CLUSTER_CANDIDATES = (2, 3, 4)
#: Rings of faces on each side of a boundary that boundary smoothing may relabel.
BOUNDARY_BAND_RINGS = 3
#: Cost (per face of mean area) of moving a face to another part while smoothing.
BOUNDARY_CHANGE_COST = 20.0


def refine_parts(
    parts: NDArray[Any],
    shdf: NDArray[Any],
    graph: FaceGraph,
    edge_weights: NDArray[Any],
    geometry: FaceData,
    params: SegmentParams,
) -> NDArray[np.int64]:
    """Re-segment, recursively, every part whose own ShDF looks like two populations.

    Inside a part the raw ShDF is re-normalised to [0, 1] (more contrast), a
    mixture is fitted (k by BIC over 2..4) and cut with the same dihedral
    weights; the part is replaced by its sub-parts. Depth is limited by
    ``params.refine_depth``; parts under ``MIN_REFINE_FACES`` faces or below
    twice the minimum part size stay whole.
    """
    parts = canonical_labels(parts)
    total_area = float(geometry.areas.sum())
    result = parts.copy()
    next_label = int(parts.max()) + 1
    order = np.argsort(parts, kind="stable")
    bounds = np.searchsorted(parts[order], np.arange(int(parts.max()) + 2))
    for part in range(int(parts.max()) + 1):
        faces = order[bounds[part] : bounds[part + 1]]
        sub = _refine_faces(
            faces, shdf, graph, edge_weights, geometry, params, total_area, params.refine_depth
        )
        if sub is None:
            continue
        # Sub-part 0 keeps the part's label; the others get new labels.
        new = sub > 0
        result[faces[new]] = next_label + sub[new] - 1
        next_label += int(sub.max())
    return canonical_labels(result)


def _refine_faces(
    faces: NDArray[Any],
    shdf: NDArray[Any],
    graph: FaceGraph,
    edge_weights: NDArray[Any],
    geometry: FaceData,
    params: SegmentParams,
    total_area: float,
    depth: int,
) -> NDArray[np.int64] | None:
    """Sub-part labels of ``faces`` (None when the part stays whole)."""
    if depth <= 0 or len(faces) < MIN_REFINE_FACES:
        return None
    area = float(geometry.areas[faces].sum())
    if total_area > 0 and area < 2 * params.min_part_fraction * total_area:
        return None
    local_values = log_normalize(linear_normalize(shdf[faces]))
    weights = value_weights(geometry.areas[faces])
    if not prefers_split(local_values, params.seed, weights=weights):
        return None
    mixture = fit_best_mixture(
        local_values, params.seed, REFINE_CLUSTER_CANDIDATES, weights=weights
    )
    posteriors = mixture.posteriors(local_values)
    sub_graph, edges = induced_subgraph(graph, faces)
    sub = cut_into_parts(posteriors, sub_graph, edge_weights[edges], geometry.subset(faces))
    fraction = params.min_part_fraction * total_area / area if area > 0 else 0.0
    sub = merge_small_parts(
        sub, sub_graph, geometry.areas[faces], geometry.centroids[faces], min(fraction, 0.5)
    )
    if sub.max() == 0:
        return None
    result = sub.copy()
    next_label = int(sub.max()) + 1
    for part in range(int(sub.max()) + 1):
        members = np.flatnonzero(sub == part)
        deeper = _refine_faces(
            faces[members], shdf, graph, edge_weights, geometry, params, total_area, depth - 1
        )
        if deeper is None:
            continue
        new = deeper > 0
        result[members[new]] = next_label + deeper[new] - 1
        next_label += int(deeper.max())
    return canonical_labels(result)


def cut_into_parts(
    posteriors: NDArray[Any], graph: FaceGraph, edge_weights: NDArray[Any], geometry: FaceData
) -> NDArray[np.int64]:
    """Alpha-expansion over clusters, then connected runs of one cluster as parts."""
    data = data_costs(posteriors, geometry.face_weight)
    clusters = multilevel_alpha_expansion(
        data, graph.pairs, edge_weights, geometry.centroids, geometry.areas
    )
    return connected_parts(clusters, graph.pairs, graph.face_count)


def smooth_boundaries(
    parts: NDArray[Any],
    graph: FaceGraph,
    edge_weights: NDArray[Any],
    face_weight: NDArray[Any],
    rings: int = BOUNDARY_BAND_RINGS,
    change_cost: float = BOUNDARY_CHANGE_COST,
) -> NDArray[np.int64]:
    """Move part boundaries onto cheap (concave) edges by alpha-expansion over part labels.

    Only faces within ``rings`` of a boundary may change; each change costs
    ``change_cost`` (times the face's relative area), each cut edge its
    dihedral weight, so boundaries straighten and snap to nearby creases.
    Parts may vanish or split; the caller re-labels.
    """
    parts = np.asarray(parts, dtype=np.int64)
    part_count = int(parts.max()) + 1 if len(parts) else 0
    if part_count <= 1:
        return parts
    band = near_boundary(parts, graph.pairs, graph.face_count, rings)
    faces = np.flatnonzero(band)
    data = np.repeat((change_cost * face_weight[faces])[:, None], part_count, axis=1)
    data[np.arange(len(faces)), parts[faces]] = 0.0
    return banded_alpha_expansion(data, graph.pairs, edge_weights, parts, band)
