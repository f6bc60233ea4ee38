"""Spatially coherent labels: the segmentation's graph cut with the classifier's
probabilities as data costs.

Energy (``segment.graphcut``): ``-log p(label)`` per face weighted by its area, plus the
crease-aware cost of every cut edge (concave creases cheap, flat and convex regions
expensive). Both terms are measured against a reference tessellation of the same
surface (``REFERENCE_FACES`` equal triangles) instead of the mesh's own, so the balance
between them, and the labels, do not change when a mesh is subdivided or remeshed.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from neural_shdf.labeling._library import (
    FaceGraph,
    data_costs,
    dihedral_weights,
    multilevel_alpha_expansion,
)

#: The tessellation the energy's two terms are balanced for (face count of the surface).
REFERENCE_FACES = 1500
#: Edge length of an equilateral triangle over the square root of its area.
EQUILATERAL_EDGE = math.sqrt(4.0 / math.sqrt(3.0))


def coherent_labels(
    probabilities: NDArray,
    graph: FaceGraph,
    areas: NDArray,
    centroids: NDArray,
    smoothing: float,
) -> NDArray[np.int64]:
    """Class per face minimising the graph-cut energy (``smoothing``: CGAL's lambda; 0 =
    each face's most probable class). Deterministic."""
    probabilities = np.asarray(probabilities, dtype=np.float64)
    if smoothing <= 0 or probabilities.shape[1] <= 1 or len(graph.pairs) == 0:
        return np.argmax(probabilities, axis=1).astype(np.int64)
    areas = np.asarray(areas, dtype=np.float64)
    reference_area = float(areas.sum()) / REFERENCE_FACES
    if not reference_area > 0:
        return np.argmax(probabilities, axis=1).astype(np.int64)
    data = data_costs(probabilities, face_weight=areas / reference_area)
    # dihedral_weights measures edges against the mesh's mean edge length: rescale to the
    # reference tessellation's.
    reference_length = EQUILATERAL_EDGE * math.sqrt(reference_area)
    mean_length = float(np.mean(graph.edge_length))
    weights = dihedral_weights(graph, smoothing) * (mean_length / reference_length)
    return multilevel_alpha_expansion(data, graph.pairs, weights, centroids, areas)
