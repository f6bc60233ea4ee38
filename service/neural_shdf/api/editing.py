"""Hand edits of a cached segmentation: ``segment.editing`` applied to its part tree, with
part summaries of the edited labels. Nothing here is cached: an edit is a pass over the
faces, cheaper than fetching a stored result."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.api.segmentation import StoredSegmentation
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment.editing import (
    AdjacencySource,
    FaceAdjacency,
    apply_edits,
    apply_label_edits,
    input_face_adjacency,
)


def edited_labels(
    result: StoredSegmentation,
    edits: Sequence[dict[str, Any]],
    adjacency: AdjacencySource = None,
    seed: int = 0,
) -> NDArray[np.int64]:
    """Labels per input face of ``result`` edited by ``edits`` (EditError: a 422);
    ``adjacency`` and ``seed``: what a ``split`` bisects, and how."""
    tree = result.tree
    if tree is None:  # METIS: no tree, merge, paint and split only
        return apply_label_edits(result.labels, edits, adjacency, seed)
    return apply_edits(tree, result.leaf_labels, len(result.part_faces), edits, adjacency, seed)


def edited_result(
    result: StoredSegmentation,
    mesh: TriangleMesh,
    shdf: NDArray[np.float64],
    edits: Sequence[dict[str, Any]],
    seed: int = 0,
) -> StoredSegmentation:
    """``result`` with edited labels and per-part faces, area and area-weighted mean ShDF
    (over each input face's triangles; ``shdf`` per triangle). ``seed``: the
    segmentation's, for a ``split``'s bisection."""

    def adjacency() -> FaceAdjacency:
        graph = mesh.face_graph
        return input_face_adjacency(graph.pairs, graph.edge_length, mesh.face_origin)

    labels = edited_labels(result, edits, adjacency, seed)
    triangle_labels = labels[mesh.face_origin]
    _, area = mesh.normals_and_areas
    count = int(labels.max()) + 1 if len(labels) else 0
    covered = triangle_labels >= 0
    tri = triangle_labels[covered]
    part_area = np.bincount(tri, weights=area[covered], minlength=count).astype(np.float64)
    moment = np.bincount(tri, weights=(area * shdf)[covered], minlength=count)
    mean = np.divide(moment, part_area, out=np.zeros(count), where=part_area > 0)
    return dataclasses.replace(
        result,
        labels=labels.astype(np.int32),
        triangle_labels=triangle_labels.astype(np.int32),
        part_faces=np.bincount(labels[labels >= 0], minlength=count).astype(np.int64),
        part_area=part_area,
        part_mean_shdf=mean,
    )
