"""Boundary refinement: move part boundaries onto nearby concave creases (a banded min cut).

After Katz and Tal (2003, "fuzzy region + min cut"): around the boundary between each
pair of adjacent parts A and B lies a band (the fuzzy region); faces outside every band
keep their part, faces in the band of (A, B) choose A or B, and one max-flow finds the
cheapest boundary inside the band. Cutting an edge costs its length, less where the fold
is concave::

    capacity = length / (1 + CONCAVITY_STRENGTH * (1 - cos angle) / mean(1 - cos angle))

(convex and flat edges count as flat; the mean runs over all edges, so a smooth crease
weighs the same however finely it is tessellated). Moving a face to the other part costs
``CHANGE_COST`` times its area over the band's half-width, so a boundary moves only as
far as a crease (or a much shorter cut) pays for; without it the cut drifts to the
narrowest loop of the band, e.g. towards the tip of a tapering part.

The band is geometric, not a ring count: faces whose geodesic distance (over face
centroids) to the boundary of (A, B) is below ``BAND_WIDTH`` times the boundary's neck
radius (its length over 2 pi, capped by the radius of a disk of the smaller part's
area). Each face belongs to the band of its nearest boundary only, so bands are
disjoint and all of them are solved by one max-flow. A band side that would cover its
whole region (a small part) is cut back to ``SIDE_SHARE`` of its depth, so no part
vanishes. Meshes over ``COARSE_ABOVE_FACES`` faces are solved on about
``COARSE_NODES`` coarse nodes (connected pieces of one grid cell, never across a concave
crease; each takes the part of most of its area, and only nodes the cut moves change
their faces), so the max-flow's size does not grow with the face count. The graph and its edge costs
depend on the mesh only (``crease_graph``; ``SegmentBasis`` keeps them).

Runs on the graph cut's parts before the merge tree is built, so every cut of the tree
(the server's and the clients' re-cuts) has the refined boundaries. Deterministic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import maxflow
import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.geometry import (
    FaceGraph,
    adjacency_lists,
    grid_cells,
    principal_coordinates,
)
from neural_shdf.segment.graphcut import summable
from neural_shdf.segment.parts import canonical_labels, connected_parts, merge_small_parts

# Tuned on the 57 psb-dev tuning models (ids 1-3 of each category), exact ShDF, for the
# sum of CD and 1-RI at the automatic and the humans' part counts: a crease strength of 0
# (length only) scored far worse and a change cost of 0 let cuts drift; the ranges tried
# and the scores are in docs/benchmarks.md ("Measurements behind constants").

#: Band half-width, in neck radii (boundary length / 2 pi) of the pair's boundary.
BAND_WIDTH = 1.0
#: A band side covering all of its region is cut back to this share of its depth.
SIDE_SHARE = 0.5
#: Cost of moving a face to the other part, per area over the band width (a boundary
#: moved across the whole band pays ``CHANGE_COST`` times its length).
CHANGE_COST = 0.5
#: Meshes with more faces are solved on coarse nodes (pieces of grid cells) ...
COARSE_ABOVE_FACES = 60_000
#: ... about this many (a cell is about 1/170 of the extent of a compact shape).
COARSE_NODES = 6_000
#: Edges whose capacity is below this share of their length (concave creases) are never
#: inside a coarse node, so the coarse cut can follow them face by face.
CREASE_RATIO = 0.25
#: How much cheaper a concave edge is to cut, per mean bending of the mesh's edges.
CONCAVITY_STRENGTH = 2.0


def crease_capacities(
    graph: FaceGraph, strength: float = CONCAVITY_STRENGTH
) -> NDArray[np.float64]:
    """Cost of cutting each edge: its length, divided by 1 + strength * relative concavity."""
    return _capacities(
        np.ascontiguousarray(graph.edge_length, dtype=np.float64),
        np.ascontiguousarray(graph.dihedral, dtype=np.float64),
        np.ascontiguousarray(graph.concave, dtype=np.bool_),
        float(strength),
    )


@kernel
def _capacities(
    edge_length: NDArray[Any], dihedral: NDArray[Any], concave: NDArray[Any], strength: float
) -> NDArray[np.float64]:  # pragma: no cover - numba
    """``crease_capacities``: the length-weighted mean bend, then one pass over the edges."""
    bend_sum = 0.0
    length_sum = 0.0
    for e in range(len(edge_length)):
        bend_sum += edge_length[e] * (1.0 - math.cos(dihedral[e]))
        length_sum += edge_length[e]
    mean = bend_sum / length_sum if length_sum > 0 else 0.0
    capacity = edge_length.copy()
    if mean > 0:
        for e in range(len(edge_length)):
            if concave[e]:
                capacity[e] = edge_length[e] / (
                    1.0 + strength * (1.0 - math.cos(dihedral[e])) / mean
                )
    return capacity


@dataclass(frozen=True)
class CreaseGraph:
    """The graph the banded min cut runs on, with its edge costs; it depends on the mesh
    only, so a caller can keep it (``SegmentBasis``) and refine many segmentations.

    Meshes up to ``COARSE_ABOVE_FACES`` faces: the face graph itself (``node_of`` None).
    Larger: coarse nodes, connected pieces of one grid cell never grouped across a concave
    crease; ``node_of`` is each face's node (nodes numbered by their lowest face).
    """

    graph: FaceGraph
    areas: NDArray[np.float64]
    centroids: NDArray[np.float64]
    capacity: NDArray[np.float64]
    indptr: NDArray[np.int64]
    neighbour: NDArray[np.int64]
    node_of: NDArray[np.int64] | None = None

    @property
    def nbytes(self) -> int:
        """Memory held by the arrays this graph owns (not the face graph it may be)."""
        arrays = [self.capacity, self.indptr, self.neighbour]
        if self.node_of is not None:
            arrays += [self.node_of, self.areas, self.centroids, self.graph.pairs]
            arrays += [self.graph.edge_length]
        return sum(a.nbytes for a in arrays)


def crease_graph(
    graph: FaceGraph,
    areas: NDArray[Any],
    centroids: NDArray[Any],
    *,
    strength: float = CONCAVITY_STRENGTH,
    coarse_above: int = COARSE_ABOVE_FACES,
    coarse_nodes: int = COARSE_NODES,
    frame: tuple[NDArray[Any], NDArray[Any]] | None = None,
) -> CreaseGraph:
    """The ``CreaseGraph`` of a mesh: its face graph, or above ``coarse_above`` faces about
    ``coarse_nodes`` coarse nodes; edge costs by ``crease_capacities(graph, strength)``.
    ``frame``: ``principal_frame(centroids, areas)`` where the caller keeps it."""
    areas = np.asarray(areas, dtype=np.float64)
    centroids = np.asarray(centroids, dtype=np.float64)
    capacity = crease_capacities(graph, strength)
    node_of = None
    if graph.face_count > coarse_above:
        graph, areas, centroids, capacity, node_of = _coarse_graph(
            graph, areas, centroids, capacity, coarse_nodes, frame
        )
    indptr, neighbour = adjacency_lists(graph.pairs, graph.face_count)
    return CreaseGraph(graph, areas, centroids, capacity, indptr, neighbour, node_of)


def snap_boundaries_to_creases(
    parts: NDArray[Any],
    graph: FaceGraph,
    areas: NDArray[Any],
    centroids: NDArray[Any],
    min_part_fraction: float,
    *,
    width: float = BAND_WIDTH,
    side_share: float = SIDE_SHARE,
    change_cost: float = CHANGE_COST,
    creases: CreaseGraph | None = None,
) -> NDArray[np.int64]:
    """``parts`` with each boundary moved to the cheapest cut in its band; canonical labels.

    ``width``: band half-width in neck radii of each boundary; ``side_share``: depth share
    kept free where a band side covers its whole region; ``change_cost``: price of moving
    a face (see ``CHANGE_COST``). ``creases``: the mesh's ``crease_graph`` where the caller
    keeps it (else built here with the defaults). On coarse nodes each node takes the part
    of most of its area; faces keep their own part unless the cut moved their node. Parts
    cut in two become two parts; pieces below ``min_part_fraction`` of the area merge into
    a neighbour (``merge_small_parts``).
    """
    parts = canonical_labels(parts)
    face_count = len(parts)
    if face_count == 0 or parts.max() == 0 or len(graph.pairs) == 0:
        return parts
    areas = np.asarray(areas, dtype=np.float64)
    if creases is None:
        creases = crease_graph(graph, areas, centroids)
    if creases.node_of is None:
        node_parts = parts
    else:
        node_parts = _majority_parts(creases.node_of, parts, areas, creases.graph.face_count)
    refined = _snap(node_parts, creases, width, side_share, change_cost)
    if refined is None:
        return parts
    if creases.node_of is not None:
        moved = (refined != node_parts)[creases.node_of]
        refined = np.where(moved, refined[creases.node_of], parts)
    pieces = connected_parts(refined, graph.pairs, face_count)
    return merge_small_parts(pieces, graph, areas, centroids, min_part_fraction)


def _snap(
    parts: NDArray[Any], creases: CreaseGraph, width: float, side_share: float, change_cost: float
) -> NDArray[np.int64] | None:
    """The banded min cut on the crease graph (parts per node); None when nothing moves."""
    graph, areas, capacity = creases.graph, creases.areas, creases.capacity
    node_count = len(parts)
    part_count = int(parts.max()) + 1
    pairs = graph.pairs
    a, b = parts[pairs[:, 0]], parts[pairs[:, 1]]
    cut = np.flatnonzero(a != b)
    if len(cut) == 0:
        return None
    low, high = np.minimum(a[cut], b[cut]), np.maximum(a[cut], b[cut])
    keys, boundary_of_edge = np.unique(low * part_count + high, return_inverse=True)
    boundary_of_edge = boundary_of_edge.reshape(-1)
    boundary_low, boundary_high = keys // part_count, keys % part_count
    boundary_count = len(keys)

    # Band half-width per boundary: its neck radius, capped by the smaller part's radius.
    length = np.bincount(boundary_of_edge, weights=graph.edge_length[cut], minlength=len(keys))
    part_area = np.bincount(parts, weights=areas, minlength=part_count)
    smaller = np.minimum(part_area[boundary_low], part_area[boundary_high])
    limit = width * np.minimum(length / (2 * math.pi), np.sqrt(smaller / math.pi))

    # Seeds: the nodes on each boundary (a node on several: its lowest boundary id).
    seed_boundary = _seed_boundaries(
        np.ascontiguousarray(pairs, dtype=np.int64),
        cut,
        boundary_of_edge,
        node_count,
        boundary_count,
    )
    distance, owner = _dijkstra(
        creases.indptr,
        creases.neighbour,
        creases.centroids,
        parts,
        seed_boundary,
        boundary_low,
        boundary_high,
        limit,
    )

    # Each band side reaches the limit, or a share of its depth where it ends before it
    # (nodes beyond the limit are reached but not spread from: depth > limit says so).
    reached = np.flatnonzero(owner >= 0)
    side = (parts[reached] == boundary_high[owner[reached]]).astype(np.int64)
    slot = owner[reached] * 2 + side
    depth = _deepest(slot, distance[reached], 2 * boundary_count)
    side_limit = np.repeat(limit, 2)
    side_limit = np.where(depth > side_limit, side_limit, side_share * depth)
    in_band = np.zeros(node_count, dtype=bool)
    in_band[reached] = distance[reached] < side_limit[slot]
    if not in_band.any():
        return None
    # Moving a node to the other part costs its area over the band width (times
    # ``change_cost``): a boundary moves only as far as a crease or a shorter cut pays for.
    width_of = np.maximum(limit[np.maximum(owner, 0)], np.finfo(np.float64).tiny)
    change = change_cost * areas / width_of
    refined = _min_cut_in_bands(
        parts, in_band, owner, boundary_low, boundary_high, pairs, capacity, change
    )
    return None if np.array_equal(refined, parts) else refined


def _coarse_graph(
    graph: FaceGraph,
    areas: NDArray[Any],
    centroids: NDArray[Any],
    capacity: NDArray[Any],
    target_nodes: int,
    frame: tuple[NDArray[Any], NDArray[Any]] | None = None,
) -> tuple[FaceGraph, NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]]:
    """Coarse nodes: connected pieces of one grid cell, never grouped across a concave
    crease; cells sized for about ``target_nodes`` nodes, laid along the mesh's own axes
    (``principal_coordinates``, ``grid_cells``: the same nodes in any pose).

    Returns (node graph, node areas, node centroids, edge capacities, node of each face);
    nodes are numbered by their lowest face.
    """
    total = float(areas.sum())
    positions = principal_coordinates(centroids, areas, frame)
    if total > 0:
        cell = math.sqrt(total / target_nodes)
    else:  # no area: a share of the extent (its pass over the positions only here)
        extent = float(np.ptp(positions, axis=0).max()) if len(positions) else 0.0
        cell = (extent or 1.0) / 200.0
    coarse = _coarsen(
        np.ascontiguousarray(graph.pairs, dtype=np.int64),
        np.ascontiguousarray(graph.edge_length, dtype=np.float64),
        np.ascontiguousarray(capacity, dtype=np.float64),
        centroids,
        areas if total > 0 else np.ones(len(areas)),
        grid_cells(positions, cell),
        CREASE_RATIO,
    )
    node_of, node_areas, node_centroids, node_pairs, lengths, node_capacity = coarse
    if not total > 0:
        node_areas = np.zeros(len(node_areas))
    node_graph = FaceGraph(
        pairs=node_pairs,
        edge_vertices=np.zeros((len(node_pairs), 2), dtype=np.int64),
        edge_length=lengths,
        dihedral=np.zeros(len(node_pairs)),
        concave=np.zeros(len(node_pairs), dtype=bool),
        face_count=len(node_areas),
    )
    return node_graph, node_areas, node_centroids, node_capacity, node_of


def _min_cut_in_bands(
    parts: NDArray[Any],
    in_band: NDArray[Any],
    owner: NDArray[Any],
    boundary_low: NDArray[Any],
    boundary_high: NDArray[Any],
    pairs: NDArray[Any],
    capacity: NDArray[Any],
    change: NDArray[Any],
) -> NDArray[np.int64]:
    """One max-flow: each band face picks its boundary's low (0) or high (1) part;
    ``change``: what a face pays for leaving its part. Both rounded to be summed exactly
    (``graphcut.summable``): the same cut whatever order the faces come in."""
    capacity, change = summable(capacity, change)
    nodes = np.flatnonzero(in_band)
    local = np.full(len(parts), -1, dtype=np.int64)
    local[nodes] = np.arange(len(nodes))
    low_part = boundary_low[owner[nodes]]
    high_part = boundary_high[owner[nodes]]
    is_high = parts[nodes] == high_part
    cost_low = np.where(is_high, change[nodes], 0.0)  # paid when the face takes its low part
    cost_high = np.where(is_high, 0.0, change[nodes])
    inside = _band_costs(
        cost_low,
        cost_high,
        in_band,
        owner,
        local,
        parts,
        low_part,
        high_part,
        np.ascontiguousarray(pairs, dtype=np.int64),
        np.asarray(capacity, dtype=np.float64),
    )
    flow = maxflow.Graph[float](len(nodes), len(inside))
    flow.add_nodes(len(nodes))
    if len(inside):
        weight = capacity[inside]
        flow.add_edges(local[pairs[inside, 0]], local[pairs[inside, 1]], weight, weight)
    shift = np.minimum(cost_low, cost_high)
    # Sink side (True) = high part, which pays the source capacity.
    flow.add_grid_tedges(np.arange(len(nodes)), cost_high - shift, cost_low - shift)
    flow.maxflow()
    high = flow.get_grid_segments(np.arange(len(nodes)))
    result = parts.copy()
    result[nodes] = np.where(high, high_part, low_part)
    return result


@kernel
def _band_costs(
    cost_low: NDArray[Any],
    cost_high: NDArray[Any],
    in_band: NDArray[Any],
    owner: NDArray[Any],
    local: NDArray[Any],
    parts: NDArray[Any],
    low_part: NDArray[Any],
    high_part: NDArray[Any],
    pairs: NDArray[Any],
    capacity: NDArray[Any],
) -> NDArray[np.int64]:  # pragma: no cover - numba
    """``_min_cut_in_bands``' unary costs (added in place, edge by edge in order, first the
    edges whose first face is in a band, then those whose second is) and the edges inside
    one band. An edge to a face that keeps its part (outside, or in another band) is cut
    unless the band face takes that part."""
    same_band = np.zeros(len(pairs), dtype=np.bool_)
    inside = 0
    for edge in range(len(pairs)):
        a, b = pairs[edge, 0], pairs[edge, 1]
        if in_band[a] and in_band[b] and owner[a] == owner[b]:
            same_band[edge] = True
            inside += 1
    for side in range(2):
        for edge in range(len(pairs)):
            inner, outer = pairs[edge, side], pairs[edge, 1 - side]
            if in_band[inner] and not same_band[edge]:
                row = local[inner]
                other = parts[outer]
                cost_low[row] += capacity[edge] if other != low_part[row] else 0.0
                cost_high[row] += capacity[edge] if other != high_part[row] else 0.0
    edges = np.empty(inside, dtype=np.int64)
    count = 0
    for edge in range(len(pairs)):
        if same_band[edge]:
            edges[count] = edge
            count += 1
    return edges


@kernel
def _coarsen(
    pairs: NDArray[Any],
    edge_length: NDArray[Any],
    capacity: NDArray[Any],
    centroids: NDArray[Any],
    weight: NDArray[Any],
    cell_of: NDArray[Any],
    crease_ratio: float,
) -> tuple[
    NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]
]:  # pragma: no cover - numba
    """Union-find of faces sharing a grid cell (``cell_of``: a key per face) across
    non-crease edges, then the coarse nodes (numbered by lowest face: weights, weighted
    centroids) and their edges (lengths and capacities summed; duplicates merged
    without sorting)."""
    node_count = len(weight)
    root = np.arange(node_count)
    for e in range(pairs.shape[0]):
        f, g = pairs[e, 0], pairs[e, 1]
        if capacity[e] < crease_ratio * edge_length[e]:
            continue
        if cell_of[f] != cell_of[g]:
            continue
        while root[f] != f:
            root[f] = root[root[f]]
            f = root[f]
        while root[g] != g:
            root[g] = root[root[g]]
            g = root[g]
        if f < g:
            root[g] = f
        elif g < f:
            root[f] = g
    piece = np.empty(node_count, dtype=np.int64)
    count = 0
    for f in range(node_count):
        r = f
        while root[r] != r:
            r = root[r]
        root[f] = r
        if r == f:
            piece[f] = count
            count += 1
        else:
            piece[f] = piece[r]
    node_weight = np.zeros(count)
    node_centroids = np.zeros((count, 3))
    for f in range(node_count):
        c = piece[f]
        node_weight[c] += weight[f]
        for axis in range(3):
            node_centroids[c, axis] += weight[f] * centroids[f, axis]
    for c in range(count):
        if node_weight[c] > 0:
            for axis in range(3):
                node_centroids[c, axis] /= node_weight[c]
    # Coarse edges: bucket the crossing face edges by their lower node, merge repeats.
    start = np.zeros(count + 1, dtype=np.int64)
    for e in range(pairs.shape[0]):
        a, b = piece[pairs[e, 0]], piece[pairs[e, 1]]
        if a != b:
            start[min(a, b) + 1] += 1
    for c in range(count):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    bucket = np.empty(start[count], dtype=np.int64)
    for e in range(pairs.shape[0]):
        a, b = piece[pairs[e, 0]], piece[pairs[e, 1]]
        if a != b:
            low = min(a, b)
            bucket[fill[low]] = e
            fill[low] += 1
    slot_of = np.full(count, -1, dtype=np.int64)
    owner = np.full(count, -1, dtype=np.int64)
    node_pairs = np.empty((start[count], 2), dtype=np.int64)
    lengths = np.zeros(start[count])
    capacities = np.zeros(start[count])
    edges = 0
    for low in range(count):
        for k in range(start[low], start[low + 1]):
            e = bucket[k]
            high = max(piece[pairs[e, 0]], piece[pairs[e, 1]])
            if owner[high] != low:
                owner[high] = low
                slot_of[high] = edges
                node_pairs[edges, 0] = low
                node_pairs[edges, 1] = high
                edges += 1
            lengths[slot_of[high]] += edge_length[e]
            capacities[slot_of[high]] += capacity[e]
    return (
        piece,
        node_weight,
        node_centroids,
        node_pairs[:edges].copy(),
        lengths[:edges].copy(),
        capacities[:edges].copy(),
    )


@kernel
def _seed_boundaries(
    pairs: NDArray[Any],
    cut: NDArray[Any],
    boundary_of_edge: NDArray[Any],
    node_count: int,
    none: int,
) -> NDArray[np.int64]:  # pragma: no cover - numba
    """Each node's lowest boundary id over the cut edges ``cut`` it is on (``none`` where it
    is on none)."""
    seed = np.full(node_count, none, dtype=np.int64)
    for i in range(len(cut)):
        for side in range(2):
            node = pairs[cut[i], side]
            seed[node] = min(seed[node], boundary_of_edge[i])
    return seed


@kernel
def _deepest(
    slot: NDArray[Any], distance: NDArray[Any], slots: int
) -> NDArray[np.float64]:  # pragma: no cover - numba
    """The largest ``distance`` per ``slot`` (0 where a slot has none)."""
    depth = np.zeros(slots)
    for i in range(len(slot)):
        depth[slot[i]] = max(depth[slot[i]], distance[i])
    return depth


@kernel
def _majority_parts(
    node_of: NDArray[Any], parts: NDArray[Any], areas: NDArray[Any], node_count: int
) -> NDArray[np.int64]:  # pragma: no cover - numba
    """Each node's part: a weighted majority vote (Boyer-Moore) of its faces' parts, by
    area, in face order; exact wherever one part holds more than half of a node."""
    choice = np.full(node_count, -1, dtype=np.int64)
    weight = np.zeros(node_count)
    for f in range(len(node_of)):
        node = node_of[f]
        if choice[node] == parts[f]:
            weight[node] += areas[f]
        elif weight[node] > areas[f]:
            weight[node] -= areas[f]
        else:
            weight[node] = areas[f] - weight[node]
            choice[node] = parts[f]
    return choice


@kernel(inline=True)
def _before(
    distance: NDArray[Any], face: NDArray[Any], boundary: NDArray[Any], i: int, j: int
) -> bool:  # pragma: no cover - numba
    """Whether heap entry ``i`` pops before ``j``: (distance, face, boundary) in order."""
    if distance[i] != distance[j]:
        return bool(distance[i] < distance[j])
    if face[i] != face[j]:
        return bool(face[i] < face[j])
    return bool(boundary[i] < boundary[j])


@kernel
def _dijkstra(
    indptr: NDArray[Any],
    neighbour: NDArray[Any],
    centroids: NDArray[Any],
    parts: NDArray[Any],
    seed_boundary: NDArray[Any],
    low: NDArray[Any],
    high: NDArray[Any],
    limit: NDArray[Any],
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:  # pragma: no cover - numba
    """Geodesic distance (over centroids) to the nearest boundary and its id (-1: none).

    Multi-source Dijkstra from the boundary nodes, spreading only through the two parts
    of a boundary; a node farther than its boundary's ``limit`` is reached but not
    spread from (so each band side knows whether it ends before the limit).

    The queue is a binary heap over three flat arrays (no tuples): entries pop in
    (distance, node, boundary) order, and no entry is pushed twice, so the order of pops
    (and the result) is that of any priority queue on those keys.
    """
    face_count = len(parts)
    none = len(limit)
    distance = np.full(face_count, np.inf)
    owner = np.full(face_count, -1, dtype=np.int64)
    done = np.zeros(face_count, dtype=np.bool_)
    # Each node spreads once, pushing at most one entry per neighbour slot.
    capacity = face_count + len(neighbour)
    heap_distance = np.empty(capacity)
    heap_face = np.empty(capacity, dtype=np.int64)
    heap_boundary = np.empty(capacity, dtype=np.int64)
    size = 0
    for face in range(face_count):
        if seed_boundary[face] < none:
            distance[face] = 0.0
            owner[face] = seed_boundary[face]
            heap_distance[size] = 0.0
            heap_face[size] = face
            heap_boundary[size] = seed_boundary[face]
            size += 1
    # Seeds in face order all at distance 0: already a heap.
    while size > 0:
        d, face, boundary = heap_distance[0], heap_face[0], heap_boundary[0]
        size -= 1
        if size > 0:  # the last entry to the root, sifted down
            heap_distance[0] = heap_distance[size]
            heap_face[0] = heap_face[size]
            heap_boundary[0] = heap_boundary[size]
            i = 0
            while True:
                smallest = i
                left, right = 2 * i + 1, 2 * i + 2
                if left < size and _before(heap_distance, heap_face, heap_boundary, left, smallest):
                    smallest = left
                if right < size and _before(
                    heap_distance, heap_face, heap_boundary, right, smallest
                ):
                    smallest = right
                if smallest == i:
                    break
                _swap(heap_distance, heap_face, heap_boundary, i, smallest)
                i = smallest
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
            dx = centroids[face, 0] - centroids[other, 0]
            dy = centroids[face, 1] - centroids[other, 1]
            dz = centroids[face, 2] - centroids[other, 2]
            candidate = d + math.sqrt(dx * dx + dy * dy + dz * dz)
            if candidate < distance[other] or (
                candidate == distance[other] and boundary < owner[other]
            ):
                distance[other] = candidate
                owner[other] = boundary
                i = size  # push, sifted up
                heap_distance[i] = candidate
                heap_face[i] = other
                heap_boundary[i] = boundary
                size += 1
                while i > 0:
                    up = (i - 1) // 2
                    if not _before(heap_distance, heap_face, heap_boundary, i, up):
                        break
                    _swap(heap_distance, heap_face, heap_boundary, i, up)
                    i = up
    return distance, owner


@kernel(inline=True)
def _swap(
    distance: NDArray[Any], face: NDArray[Any], boundary: NDArray[Any], i: int, j: int
) -> None:  # pragma: no cover - numba
    distance[i], distance[j] = distance[j], distance[i]
    face[i], face[j] = face[j], face[i]
    boundary[i], boundary[j] = boundary[j], boundary[i]
