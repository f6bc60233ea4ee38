"""k-way partition of the face graph with METIS (pymetis) into exactly ``parts`` parts.

Edge weights make METIS cut where the graph cut would: along concave creases
(the dihedral weight) and between faces whose cluster posteriors differ.
Each connected component of the face graph is partitioned on its own; the
parts are shared out between components in proportion to their area.
"""

from __future__ import annotations

import heapq
from typing import Any

import numpy as np
import pymetis
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from neural_shdf.errors import ParameterError
from neural_shdf.geometry import FaceGraph
from neural_shdf.segment.parts import canonical_labels

#: Integer edge weights span 1..this.
WEIGHT_RANGE = 1000
#: METIS load imbalance allowed (1 + UFACTOR / 1000 times the mean part weight).
UFACTOR = 3000
#: Faces whose posteriors are disjoint still keep this fraction of the dihedral weight.
SIMILARITY_FLOOR = 0.05


def metis_edge_weights(
    dihedral_weight: NDArray[Any], posteriors: NDArray[Any], pairs: NDArray[Any]
) -> NDArray[np.int64]:
    """Integer weights in 1..WEIGHT_RANGE: dihedral weight times posterior similarity.

    Similarity is the Bhattacharyya coefficient ``sum_c sqrt(p_a[c] p_b[c])``
    (1 for identical cluster posteriors, 0 for disjoint ones).
    """
    if len(pairs) == 0:
        return np.zeros(0, dtype=np.int64)
    root = np.sqrt(posteriors)
    similarity = np.einsum("ij,ij->i", root[pairs[:, 0]], root[pairs[:, 1]])
    weight = dihedral_weight * (SIMILARITY_FLOOR + (1 - SIMILARITY_FLOOR) * similarity)
    top = float(weight.max())
    if not top > 0:
        return np.ones(len(pairs), dtype=np.int64)
    scaled: NDArray[np.float64] = np.clip(np.rint(weight / top * WEIGHT_RANGE), 1, WEIGHT_RANGE)
    return scaled.astype(np.int64)


def share_parts(
    sizes: NDArray[Any], counts: NDArray[Any], parts: int, min_fraction: float = 0.0
) -> NDArray[np.int64]:
    """Parts per component, summing to ``parts``.

    Components of at least ``min_fraction`` of the total size first get one
    part each (largest first, while parts last); the rest are handed out one
    at a time to the component furthest below its share by size. A component
    never gets more parts than faces; one that gets none is joined to the
    nearest component that has parts.
    """
    sizes = np.asarray(sizes, dtype=np.float64)
    counts = np.asarray(counts, dtype=np.int64)
    if not sizes.sum() > 0:
        sizes = counts.astype(np.float64)
    share = sizes / sizes.sum() * parts
    given = np.zeros(len(sizes), dtype=np.int64)
    by_size = np.lexsort((np.arange(len(sizes)), -sizes))
    significant = by_size[sizes[by_size] >= min_fraction * sizes.sum()]
    given[significant[:parts]] = 1
    # One part at a time to the largest deficit (then the largest size, the lowest index)
    # among components with room: a heap, as only the receiving component's deficit moves.
    deficit = (share - given).tolist()
    heap = [
        (-deficit[c], -size, c) for c, size in enumerate(sizes.tolist()) if given[c] < counts[c]
    ]
    heapq.heapify(heap)
    for _ in range(parts - int(given.sum())):
        _, negative_size, c = heapq.heappop(heap)
        given[c] += 1
        if given[c] < counts[c]:
            heapq.heappush(heap, (-float(share[c] - given[c]), negative_size, c))
    return given


def metis_partition(
    graph: FaceGraph,
    edge_weights: NDArray[Any],
    parts: int,
    areas: NDArray[Any],
    centroids: NDArray[Any],
    seed: int = 0,
    min_fraction: float = 0.0,
) -> NDArray[np.int64]:
    """Exactly ``parts`` parts (canonical labels 0..parts-1); deterministic for a seed.

    Shells (connected components) are partitioned separately; see ``share_parts``
    for how the parts are shared out (``min_fraction``: smallest shell, as a
    fraction of the area, sure to get a part of its own).
    """

    face_count = graph.face_count
    if parts < 1:
        raise ParameterError(f"parts must be at least 1, got {parts}")
    if parts > face_count:
        raise ParameterError(
            f"parts={parts} is more than the mesh's {face_count} faces; ask for at most "
            f"{face_count} parts"
        )
    component_count, component = connected_components(graph.csr(), directed=False)
    component = canonical_labels(component)
    counts = np.bincount(component, minlength=component_count)
    sizes = np.bincount(component, weights=areas, minlength=component_count)
    given = share_parts(sizes, counts, parts, min_fraction)

    labels = np.full(face_count, -1, dtype=np.int64)
    next_label = 0
    pair_component = component[graph.pairs[:, 0]]
    edge_order = np.argsort(pair_component, kind="stable")
    edge_bounds = np.searchsorted(pair_component[edge_order], np.arange(component_count + 1))
    face_order = np.argsort(component, kind="stable")
    face_bounds = np.searchsorted(component[face_order], np.arange(component_count + 1))
    for c in np.flatnonzero(given):
        faces = face_order[face_bounds[c] : face_bounds[c + 1]]
        edges = edge_order[edge_bounds[c] : edge_bounds[c + 1]]
        local = _partition_component(
            faces, graph.pairs[edges], edge_weights[edges], int(given[c]), seed
        )
        labels[faces] = local + next_label
        next_label += int(given[c])

    unassigned = np.flatnonzero(labels < 0)
    if len(unassigned):
        # Whole components join one part: the part nearest to their first face.
        assigned = np.flatnonzero(labels >= 0)
        joining, first = np.unique(component[unassigned], return_index=True)
        _, nearest = cKDTree(centroids[assigned]).query(centroids[unassigned[first]])
        joined = np.full(component_count, -1, dtype=np.int64)
        joined[joining] = labels[assigned[nearest]]
        labels[unassigned] = joined[component[unassigned]]
    return canonical_labels(labels)


def split_faces(
    graph: FaceGraph,
    parts: int,
    seed: int = 0,
    edge_length: NDArray[Any] | None = None,
    ufactor: int = UFACTOR,
) -> NDArray[np.int64]:
    """``parts`` pieces of one connected face graph with the shortest total boundary
    (METIS on edge lengths, or on ``edge_length`` given per pair), labels 0..parts-1.
    ``ufactor``: imbalance allowed (a part up to 1 + ufactor / 1000 times the mean)."""
    length = graph.edge_length if edge_length is None else np.asarray(edge_length, float)
    return split_graph(graph.face_count, graph.pairs, length, parts, seed, ufactor)


def split_graph(
    node_count: int,
    pairs: NDArray[Any],
    length: NDArray[Any],
    parts: int,
    seed: int = 0,
    ufactor: int = UFACTOR,
) -> NDArray[np.int64]:
    """``parts`` pieces of a graph given as unique node pairs with a length per pair, with
    the shortest total boundary (METIS), labels 0..parts-1 (all used)."""
    length = np.asarray(length, dtype=np.float64)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    top = float(length.max(initial=0.0))
    weights = (
        np.clip(np.rint(length / top * WEIGHT_RANGE), 1, WEIGHT_RANGE).astype(np.int64)
        if top > 0
        else np.ones(len(length), dtype=np.int64)
    )
    faces = np.arange(node_count, dtype=np.int64)
    return _partition_component(faces, pairs, weights, parts, seed, ufactor)


def _partition_component(
    faces: NDArray[Any],
    pairs: NDArray[Any],
    weights: NDArray[Any],
    parts: int,
    seed: int,
    ufactor: int = UFACTOR,
) -> NDArray[np.int64]:
    """Labels 0..parts-1 (all used) for the faces of one connected component."""
    if parts == 1:
        return np.zeros(len(faces), dtype=np.int64)
    local = np.searchsorted(faces, pairs)  # faces are sorted ascending
    labels = _metis(len(faces), local, weights, parts, seed, ufactor)
    # METIS may leave parts empty (tiny graphs, many parts): fill each missing label, lowest
    # first, with half of the largest part. Each step costs one pass over the faces and
    # edges (a part never empties again: both halves keep faces).
    counts = np.bincount(labels, minlength=parts)
    for missing in np.flatnonzero(counts == 0).tolist():
        largest = int(np.argmax(counts))
        members = np.flatnonzero(labels == largest)
        keep = (labels[local[:, 0]] == largest) & (labels[local[:, 1]] == largest)
        sub_pairs = np.searchsorted(members, local[keep])
        halves = _metis(len(members), sub_pairs, weights[keep], 2, seed, ufactor)
        if halves.min() == halves.max():
            halves = (np.arange(len(members)) >= len(members) // 2).astype(np.int64)
        moved = members[halves == 1]
        labels[moved] = missing
        counts[largest] -= len(moved)
        counts[missing] = len(moved)
    return labels


def _metis(
    node_count: int,
    pairs: NDArray[Any],
    weights: NDArray[Any],
    parts: int,
    seed: int,
    ufactor: int = UFACTOR,
) -> NDArray[np.int64]:
    """pymetis k-way partition of a graph given as edge pairs (CSR built here)."""
    if node_count <= parts:
        return np.arange(node_count, dtype=np.int64) % parts
    rows = np.concatenate([pairs[:, 0], pairs[:, 1]])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0]])
    both = np.concatenate([weights, weights])
    order = np.lexsort((cols, rows))
    xadj = np.zeros(node_count + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=node_count), out=xadj[1:])
    options = pymetis.Options(seed=int(seed) & 0x7FFFFFFF, ufactor=int(ufactor))
    graph: dict[str, Any]
    if hasattr(pymetis, "CSRAdjacency"):  # pymetis >= 2025.2
        graph = {"adjacency": pymetis.CSRAdjacency(xadj, cols[order])}
    else:
        graph = {"xadj": xadj, "adjncy": cols[order]}
    _, membership = pymetis.part_graph(parts, eweights=both[order], options=options, **graph)
    return np.asarray(membership, dtype=np.int64)
