"""Boundary refinement: move part boundaries onto nearby concave creases (a banded min cut).

After Katz and Tal (2003, "fuzzy region + min cut"): around the boundary between each
pair of adjacent parts A and B lies a band (the fuzzy region); faces outside every band
keep their part, faces in the band of (A, B) choose A or B, and one max-flow finds the
cheapest boundary inside the band. Cutting an edge costs its length, less where the fold
is concave::

    capacity = length / (1 + CONCAVITY_STRENGTH * (1 - cos angle) / mean(1 - cos angle))

(convex and flat edges count as flat, and the mean runs over all edges, so the weights
do not depend on how finely a smooth crease is tessellated). There is no data term: in
the band only the cut's cost counts.

The band is geometric, not a ring count: faces whose geodesic distance (over face
centroids) to the boundary of (A, B) is at most ``BAND_WIDTH`` times the boundary's
neck radius (its length over 2 pi, capped by the radius of a disk of the smaller
part's area). Each face belongs to the band of its nearest boundary only, so bands are
disjoint and all pairs are solved by one max-flow. A side of a band that would cover
its whole region keeps its far ``1 - SIDE_SHARE`` fixed, so no part vanishes.

Runs on the graph cut's parts before the merge tree is built, so every cut of the tree
(the server's and the clients' re-cuts) has the refined boundaries. Deterministic.
"""

from __future__ import annotations

import heapq
import math

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.geometry import FaceGraph
from neural_shdf.segment.parts import canonical_labels, connected_parts, merge_small_parts

#: Band half-width, in neck radii (boundary length / 2 pi) of the pair's boundary.
BAND_WIDTH = 1.0
#: A band side covering all of its region is cut back to this share of its depth.
SIDE_SHARE = 0.5
#: How much cheaper a concave edge is to cut, per mean bending of the mesh's edges.
CONCAVITY_STRENGTH = 1.0


def crease_capacities(
    graph: FaceGraph, strength: float = CONCAVITY_STRENGTH
) -> NDArray[np.float64]:
    """Cost of cutting each edge: its length, divided by 1 + strength * relative concavity."""
    bend = 1.0 - np.cos(graph.dihedral)
    mean = float(np.average(bend, weights=graph.edge_length)) if graph.edge_length.sum() else 0.0
    concave = np.where(graph.concave, bend, 0.0)
    relative = concave / mean if mean > 0 else np.zeros_like(concave)
    return graph.edge_length / (1.0 + strength * relative)


def snap_boundaries_to_creases(
    parts: NDArray,
    graph: FaceGraph,
    areas: NDArray,
    centroids: NDArray,
    min_part_fraction: float,
    *,
    width: float = BAND_WIDTH,
    strength: float = CONCAVITY_STRENGTH,
    side_share: float = SIDE_SHARE,
) -> NDArray[np.int64]:
    """``parts`` with each boundary moved to the cheapest cut in its band; canonical labels.

    ``width``: band half-width in neck radii of each boundary; ``strength``: how much
    cheaper concave edges are; ``side_share``: depth share kept free where a band side
    covers its whole region. Parts cut in two become two parts; pieces below
    ``min_part_fraction`` of the area merge into a neighbour (``merge_small_parts``).
    """
    parts = canonical_labels(parts)
    face_count = len(parts)
    part_count = int(parts.max()) + 1 if face_count else 0
    if part_count <= 1 or len(graph.pairs) == 0:
        return parts
    pairs = graph.pairs
    a, b = parts[pairs[:, 0]], parts[pairs[:, 1]]
    cut = np.flatnonzero(a != b)
    low, high = np.minimum(a[cut], b[cut]), np.maximum(a[cut], b[cut])
    keys, boundary_of_edge = np.unique(low * part_count + high, return_inverse=True)
    boundary_of_edge = boundary_of_edge.reshape(-1)
    boundary_low, boundary_high = keys // part_count, keys % part_count
    boundary_count = len(keys)

    # Band half-width per boundary: its neck radius, capped by the smaller part's radius.
    length = np.bincount(boundary_of_edge, weights=graph.edge_length[cut], minlength=len(keys))
    part_area = np.bincount(parts, weights=np.asarray(areas, float), minlength=part_count)
    smaller = np.minimum(part_area[boundary_low], part_area[boundary_high])
    radius = np.minimum(length / (2 * math.pi), np.sqrt(smaller / math.pi))
    limit = width * radius

    # Seeds: the faces on each boundary (a face on several: its lowest boundary id).
    seed_boundary = np.full(face_count, boundary_count, dtype=np.int64)
    ends = pairs[cut].reshape(-1)
    np.minimum.at(seed_boundary, ends, np.repeat(boundary_of_edge, 2))
    indptr, neighbour, edge_of = _adjacency(pairs, face_count)
    step = np.linalg.norm(centroids[pairs[:, 0]] - centroids[pairs[:, 1]], axis=1)
    distance, owner = _nearest_boundary(
        indptr, neighbour, edge_of, step, parts, seed_boundary, boundary_low, boundary_high, limit
    )

    # Each band side: up to the limit, or a share of its depth where it ends before it.
    reached = np.flatnonzero(owner >= 0)
    side = (parts[reached] == boundary_high[owner[reached]]).astype(np.int64)
    slot = owner[reached] * 2 + side
    depth = np.zeros(2 * boundary_count)
    np.maximum.at(depth, slot, distance[reached])
    side_limit = np.repeat(limit, 2)
    ends_early = depth <= side_limit
    side_limit[ends_early] = side_share * depth[ends_early]
    in_band = np.zeros(face_count, dtype=bool)
    in_band[reached] = distance[reached] < side_limit[slot]
    if not in_band.any():
        return parts

    capacity = crease_capacities(graph, strength)
    refined = _min_cut_in_bands(parts, in_band, owner, boundary_low, boundary_high, pairs, capacity)
    if np.array_equal(refined, parts):
        return parts
    pieces = connected_parts(refined, pairs, face_count)
    return merge_small_parts(pieces, graph, areas, centroids, min_part_fraction)


def _min_cut_in_bands(
    parts: NDArray,
    in_band: NDArray,
    owner: NDArray,
    boundary_low: NDArray,
    boundary_high: NDArray,
    pairs: NDArray,
    capacity: NDArray,
) -> NDArray[np.int64]:
    """One max-flow: each band face picks its boundary's low (0) or high (1) part."""
    import maxflow

    nodes = np.flatnonzero(in_band)
    local = np.full(len(parts), -1, dtype=np.int64)
    local[nodes] = np.arange(len(nodes))
    low_part = boundary_low[owner[nodes]]
    high_part = boundary_high[owner[nodes]]
    cost_low = np.zeros(len(nodes))  # paid when the face takes its low part
    cost_high = np.zeros(len(nodes))
    a, b = pairs[:, 0], pairs[:, 1]
    band_a, band_b = in_band[a], in_band[b]
    same_band = band_a & band_b & (owner[a] == owner[b])
    # An edge to a face that keeps its part (outside, or in another band): cut unless
    # the band face takes that part.
    for inner, outer, mask in ((a, b, band_a & ~same_band), (b, a, band_b & ~same_band)):
        edges = np.flatnonzero(mask)
        rows = local[inner[edges]]
        other = parts[outer[edges]]
        weight = capacity[edges]
        np.add.at(cost_low, rows, np.where(other != low_part[rows], weight, 0.0))
        np.add.at(cost_high, rows, np.where(other != high_part[rows], weight, 0.0))
    inside = np.flatnonzero(same_band)
    flow = maxflow.Graph[float](len(nodes), len(inside))
    flow.add_nodes(len(nodes))
    if len(inside):
        weight = capacity[inside]
        flow.add_edges(local[a[inside]], local[b[inside]], weight, weight)
    shift = np.minimum(cost_low, cost_high)
    # Sink side (True) = high part, which pays the source capacity.
    flow.add_grid_tedges(np.arange(len(nodes)), cost_high - shift, cost_low - shift)
    flow.maxflow()
    high = flow.get_grid_segments(np.arange(len(nodes)))
    result = parts.copy()
    result[nodes] = np.where(high, high_part, low_part)
    return result


def _adjacency(pairs: NDArray, face_count: int) -> tuple[NDArray, NDArray, NDArray]:
    """CSR adjacency of the face graph: (indptr, neighbour, edge id), neighbours by edge order."""
    return _csr(np.ascontiguousarray(pairs, dtype=np.int64), face_count)


@kernel
def _csr(pairs, face_count):  # pragma: no cover - numba
    degree = np.zeros(face_count + 1, dtype=np.int64)
    for e in range(pairs.shape[0]):
        degree[pairs[e, 0] + 1] += 1
        degree[pairs[e, 1] + 1] += 1
    indptr = np.cumsum(degree)
    fill = indptr[:-1].copy()
    neighbour = np.empty(2 * pairs.shape[0], dtype=np.int64)
    edge_of = np.empty(2 * pairs.shape[0], dtype=np.int64)
    for e in range(pairs.shape[0]):
        f, g = pairs[e, 0], pairs[e, 1]
        neighbour[fill[f]] = g
        edge_of[fill[f]] = e
        fill[f] += 1
        neighbour[fill[g]] = f
        edge_of[fill[g]] = e
        fill[g] += 1
    return indptr, neighbour, edge_of


def _nearest_boundary(
    indptr: NDArray,
    neighbour: NDArray,
    edge_of: NDArray,
    step: NDArray,
    parts: NDArray,
    seed_boundary: NDArray,
    boundary_low: NDArray,
    boundary_high: NDArray,
    limit: NDArray,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Geodesic distance to the nearest boundary and its id (-1: beyond every band).

    Multi-source Dijkstra from the boundary faces, spreading only through the two parts
    of a boundary; a face farther than its boundary's ``limit`` is reached but not
    spread from (so each band side knows whether it ends before the limit).
    """
    return _dijkstra(
        indptr,
        neighbour,
        edge_of,
        np.ascontiguousarray(step, dtype=np.float64),
        parts,
        seed_boundary,
        boundary_low,
        boundary_high,
        np.ascontiguousarray(limit, dtype=np.float64),
    )


@kernel
def _dijkstra(
    indptr, neighbour, edge_of, step, parts, seed_boundary, low, high, limit
):  # pragma: no cover - numba
    face_count = len(parts)
    none = len(limit)
    distance = np.full(face_count, np.inf)
    owner = np.full(face_count, -1, dtype=np.int64)
    done = np.zeros(face_count, dtype=np.bool_)
    heap = [(0.0, np.int64(0), np.int64(0))]
    heap.pop()
    for face in range(face_count):
        if seed_boundary[face] < none:
            distance[face] = 0.0
            owner[face] = seed_boundary[face]
            heap.append((0.0, np.int64(face), seed_boundary[face]))
    heapq.heapify(heap)
    while heap:
        d, face, boundary = heapq.heappop(heap)
        if done[face]:
            continue
        done[face] = True
        if d > limit[boundary]:
            continue
        for slot in range(indptr[face], indptr[face + 1]):
            other = neighbour[slot]
            if done[other]:
                continue
            part = parts[other]
            if part != low[boundary] and part != high[boundary]:
                continue
            candidate = d + step[edge_of[slot]]
            if candidate < distance[other] or (
                candidate == distance[other] and boundary < owner[other]
            ):
                distance[other] = candidate
                owner[other] = boundary
                heapq.heappush(heap, (candidate, other, boundary))
    return distance, owner
