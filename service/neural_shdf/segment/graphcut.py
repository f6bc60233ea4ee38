"""Alpha-expansion graph cut on the face adjacency graph (CGAL's hard clustering step).

Energy of a labelling ``l``::

    E(l) = sum_f data[f, l_f] + sum_(f,g) edge_weight[f, g] * [l_f != l_g]

minimised by alpha-expansion (Boykov, Veksler, Zabih 2001); each expansion move
is one max-flow (PyMaxflow, Boykov-Kolmogorov) whose graph is built from arrays.

Graphs above ``COARSE_NODES`` nodes are solved through a hierarchy (banded
multilevel graph cut, after Lombaert et al. 2005): faces are grouped into
connected pieces of a 3-D grid (never across creases or across faces that
prefer different clusters), the coarsest graph is solved exactly by
alpha-expansion, and each finer level only re-solves a band around the
boundaries, where a node may take only the labels found near it (``BAND_LABEL_HOPS``):
energies close to the direct solve's in a fraction of its time
(docs/benchmarks.md, "Measurements behind constants"); at 1M faces a direct solve
would need tens of max-flows over the whole mesh.

Where clusters interleave and creases abound (scans), grouping by cheapest cluster stalls
above ``COARSE_NODES`` (the dense-dev skull: 100k faces to 10.6k nodes). Such a
hierarchy keeps the stalled level's grid; each solve coarsens it further by the labels a
few sweeps of iterated conditional modes give at that smoothing, solves the smaller graph,
and runs one full expansion cycle back at the stalled level.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any, cast

import maxflow
import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.geometry import (
    FaceGraph,
    adjacency_lists,
    adjacency_with_edges,
    grid_cells,
    principal_coordinates,
)
from neural_shdf.segment.parts import connected_components

#: CGAL: probabilities below this are clamped before ``-log``.
PROBABILITY_EPS = 5e-6
#: CGAL: normalised dihedral angles below this are clamped before ``-log``.
ANGLE_EPS = 5e-6
#: CGAL: convex folds count as this fraction of their angle (cheap to keep, costly to cut).
CONVEX_FACTOR = 0.08
#: CGAL multiplies the smoothing (its lambda, in [0, 1]) by this in the edge weights.
LAMBDA_SCALE = 100.0
#: Costs and weights are rounded to multiples of this (a power of two) before the graph cut
#: sums them: every sum of them is then exact, whatever order the faces come in, so the same
#: energy has the same minimisers and max-flow returns the same cut for a file with its
#: faces in another order (float sums in face order broke ties apart differently: a CAD
#: part's flat panels, where many cuts cost the same, came out in other parts).
COST_QUANTUM = 2.0**-20
#: Hard limit on alpha-expansion cycles (it usually converges in 2-3).
MAX_CYCLES = 8
#: Multilevel solve: coarsen until at most this many nodes remain, solve there exactly.
COARSE_NODES = 4000
#: Faces per grid cell at the first coarsening level (cells double in size per level).
FACES_PER_CELL = 16
#: Refinement band: nodes within this many hops of a boundary are re-solved per level.
BAND_RINGS = 3
#: Expansion cycles per band solve (the coarse level already placed the labels).
BAND_CYCLES = 1
#: In the multilevel solve's bands a node may take only the labels that the band's nodes
#: within this many hops of it (over the band's edges, itself included) have or border
#: (``label_reach``): a band's expansion moves then cover the nodes near each label's regions
#: instead of the whole band per label (on the noisy dense-dev lucy at 100k faces the bands
#: hold up to 70% of a level's nodes, with all 9 labels). About the band's width
#: (``2 * BAND_RINGS`` nodes across a boundary): a label reaches across it from either side
#: (docs/benchmarks.md, "Measurements behind constants").
BAND_LABEL_HOPS = 2 * BAND_RINGS - 1
#: Edges cheaper than this fraction of the median edge weight (creases) are never coarsened.
#: With edge lengths (``cut_hierarchy(lengths=...)``, fine tessellations) the weight per
#: unit length is compared, at every level: a coarse edge sums many fine ones, and on a
#: midpoint-subdivided mesh grouping across the original edges priced the coarse
#: boundaries by the flat (dearest) edges, so the coarse solve missed parts (psb 102, 142
#: at 500k-1.3M faces: 3 graph-cut parts instead of 19-23, a labelling dearer than the
#: published mesh's lifted one; docs/messy-meshes.md, Resolution).
CREASE_FRACTION = 0.5
#: Coarsening past a stall (``CutHierarchy.solve``): creases are edges lighter than this
#: times the crease weight (on noisy scans most coarse edges pass for creases).
SMOOTHED_CREASE_SCALE = 0.5
#: Sweeps of iterated conditional modes that decide which nodes group past a stall.
PREFERENCE_SWEEPS = 4
#: Coarsening past a stall goes on until at most this many nodes remain (fewer than
#: ``COARSE_NODES``): the full cycle at the stalled level places the labels anyway, and the
#: smaller top's expansion moves cost less (lucy's top 1,600 -> 800 nodes; energies in
#: docs/benchmarks.md, "Measurements behind constants").
SMOOTHED_COARSE_NODES = 1000
#: Expansion cycles at a top coarsened past a stall (elsewhere the top runs to convergence,
#: ``MAX_CYCLES``): the full cycle at the stalled level follows, so the moves past two
#: cycles, mostly a last cycle that all fail and only show the top converged, are left out
#: (lucy: 27-32 moves a value to at most 18; energies in docs/benchmarks.md, "Measurements
#: behind constants").
SMOOTHED_TOP_CYCLES = 2


def data_costs(
    posteriors: NDArray[Any], face_weight: NDArray[Any] | None = None
) -> NDArray[np.float64]:
    """(F, k) cost ``-log(max(p, eps))`` of giving each face each cluster (CGAL's data term).

    ``face_weight`` (e.g. area over mean area) scales each face's row so that
    the energy does not depend on how finely a region is tessellated.
    """
    cost: NDArray[np.float64] = -np.log(np.maximum(posteriors, PROBABILITY_EPS))
    np.maximum(cost, np.finfo(np.float64).eps, out=cost)
    if face_weight is not None:
        cost *= np.asarray(face_weight, dtype=np.float64)[:, None]
    return quantized(cost)


def quantized(values: NDArray[Any], quantum: float = COST_QUANTUM) -> NDArray[np.float64]:
    """``values`` rounded to multiples of ``quantum``, a power of two (positive ones to at
    least one): sums of them below ``2^53 * quantum`` are exact in any order."""
    values = np.asarray(values, dtype=np.float64)
    rounded: NDArray[np.float64] = values * (1.0 / quantum)  # exact: a power of two
    np.rint(rounded, out=rounded)
    np.maximum(rounded, 1.0, out=rounded, where=values > 0)
    rounded *= quantum
    return rounded


def summable(*arrays: NDArray[Any]) -> tuple[NDArray[np.float64], ...]:
    """The ``arrays`` (not negative) rounded so that every sum of their values is exact in
    any order: to multiples of the power of two 2^-50 of their total (about 1e-15 of it)."""
    arrays = tuple(np.asarray(values, dtype=np.float64) for values in arrays)
    total = sum(float(values.sum()) for values in arrays)
    if not (total > 0 and math.isfinite(total)):
        return arrays
    quantum = 2.0 ** (math.ceil(math.log2(total)) - 50)
    return tuple(quantized(values, quantum) for values in arrays)


def dihedral_weights(graph: FaceGraph, smoothing: float) -> NDArray[np.float64]:
    """Cost of cutting each edge: ``-log(max(eps, angle/pi)) * smoothing * LAMBDA_SCALE *
    length/mean`` (``smoothing``: ``SegmentParams.smoothing``, CGAL's lambda).

    As CGAL, convex folds' normalised angle is scaled by ``CONVEX_FACTOR``, so
    concave creases are cheap to cut and flat or convex regions expensive. The
    length factor (edge length over the mean edge length; 1 on a uniform mesh)
    makes the boundary cost a length rather than an edge count.
    """
    if len(graph.pairs) == 0:
        return np.zeros(0)
    angle = graph.dihedral / np.pi
    angle = np.where(graph.concave, angle, angle * CONVEX_FACTOR)
    weight = -np.log(np.maximum(angle, ANGLE_EPS)) * (smoothing * LAMBDA_SCALE)
    return quantized(weight * length_factor(graph.edge_length))


def length_factor(edge_length: NDArray[Any]) -> NDArray[np.float64]:
    """Edge lengths over their mean (ones when every edge has zero length)."""
    mean = float(np.mean(edge_length)) if len(edge_length) else 0.0
    if not mean > 0:
        return np.ones(len(edge_length))
    return np.asarray(edge_length, dtype=np.float64) / mean


def labelling_energy(
    labels: NDArray[Any], data: NDArray[Any], pairs: NDArray[Any], weights: NDArray[Any]
) -> float:
    """E(l): data cost of each face's label plus the weight of every cut edge."""
    return float(
        _labelling_energy(
            np.asarray(labels, dtype=np.int64),
            np.asarray(data, dtype=np.float64),
            np.asarray(pairs, dtype=np.int64).reshape(-1, 2),
            np.asarray(weights, dtype=np.float64),
        )
    )


@kernel
def _labelling_energy(
    labels: NDArray[Any], data: NDArray[Any], pairs: NDArray[Any], weights: NDArray[Any]
) -> float:  # pragma: no cover - compiled
    unary = 0.0
    for node in range(len(labels)):
        unary += data[node, labels[node]]
    cut = 0.0
    for edge in range(len(pairs)):
        if labels[pairs[edge, 0]] != labels[pairs[edge, 1]]:
            cut += weights[edge]
    return unary + cut


@kernel
def _expansion_graph(
    labels: NDArray[Any],
    alpha: int,
    data: NDArray[Any],
    pairs: NDArray[Any],
    weights: NDArray[Any],
    allowed: NDArray[Any],
) -> tuple[
    NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]
]:  # pragma: no cover - compiled
    """The max-flow graph of one expansion move, in one pass: the free nodes (label not
    ``alpha``, ``allowed`` to take it), their terminal capacities and the edges between
    free nodes.

    Node x = 1 (sink side) means "switch to alpha" and pays the source capacity. An edge
    to a node already labelled alpha: keeping our label cuts it. Between two free nodes
    of one label: Potts w * [x_a != x_b]. Of different labels: w * (1 - x_a x_b)
    = w * (1 - x_a) + w * x_a (1 - x_b), i.e. a keep cost on a and an edge b -> a.
    An edge to a node that keeps its other label (not allowed alpha): switching cuts it,
    keeping cuts it where the labels differ.
    Capacities are shifted by min(keep, switch) per node (the cut changes by a constant).
    """
    count = len(labels)
    node_of = np.full(count, -1, dtype=np.int64)
    nodes = np.empty(count, dtype=np.int64)
    free = 0
    for node in range(count):
        if labels[node] != alpha and allowed[node]:
            node_of[node] = free
            nodes[free] = node
            free += 1
    nodes = nodes[:free]
    keep = np.empty(free)
    switch = np.empty(free)
    for i in range(free):
        keep[i] = data[nodes[i], labels[nodes[i]]]
        switch[i] = data[nodes[i], alpha]
    edge_a = np.empty(len(pairs), dtype=np.int64)
    edge_b = np.empty(len(pairs), dtype=np.int64)
    forward = np.empty(len(pairs))
    backward = np.empty(len(pairs))
    edges = 0
    for edge in range(len(pairs)):
        a, b = node_of[pairs[edge, 0]], node_of[pairs[edge, 1]]
        w = weights[edge]
        if a >= 0 and b >= 0:
            edge_a[edges] = a
            edge_b[edges] = b
            backward[edges] = w
            if labels[pairs[edge, 0]] == labels[pairs[edge, 1]]:
                forward[edges] = w
            else:
                forward[edges] = 0.0
                keep[a] += w
            edges += 1
        else:
            for inside, outside in ((a, pairs[edge, 1]), (b, pairs[edge, 0])):
                if inside < 0:
                    continue
                if labels[outside] == alpha:
                    keep[inside] += w
                else:  # fixed to another label
                    switch[inside] += w
                    if labels[outside] != labels[nodes[inside]]:
                        keep[inside] += w
    for i in range(free):
        shift = min(keep[i], switch[i])
        keep[i] -= shift
        switch[i] -= shift
    return nodes, switch, keep, edge_a[:edges], edge_b[:edges], forward[:edges], backward[:edges]


def expansion_move(
    labels: NDArray[Any],
    alpha: int,
    data: NDArray[Any],
    pairs: NDArray[Any],
    weights: NDArray[Any],
    allowed: NDArray[Any] | None = None,
) -> NDArray[np.int64]:
    """The best labelling reachable by letting any face switch to ``alpha`` (one max-flow);
    ``allowed``: which faces may (default: all)."""
    labels = np.asarray(labels, dtype=np.int64)
    moved = _switched(
        labels,
        alpha,
        np.asarray(data, dtype=np.float64),
        np.asarray(pairs, dtype=np.int64).reshape(-1, 2),
        np.asarray(weights, dtype=np.float64),
        np.ones(len(labels), dtype=np.bool_)
        if allowed is None
        else np.ascontiguousarray(allowed, dtype=np.bool_),
    )
    if moved is None:
        return labels
    result = labels.copy()
    result[moved] = alpha
    return result


def _switched(
    labels: NDArray[np.int64],
    alpha: int,
    data: NDArray[np.float64],
    pairs: NDArray[np.int64],
    weights: NDArray[np.float64],
    allowed: NDArray[np.bool_],
) -> NDArray[np.int64] | None:
    """``expansion_move`` on arrays already of its kernels' types: the nodes that switch to
    ``alpha``, or None when none does."""
    nodes, source_cap, sink_cap, edge_a, edge_b, forward, backward = _expansion_graph(
        labels, alpha, data, pairs, weights, allowed
    )
    if len(nodes) == 0:
        return None
    graph = maxflow.Graph[float](len(nodes), len(edge_a))
    graph.add_nodes(len(nodes))
    if len(edge_a):
        graph.add_edges(edge_a, edge_b, forward, backward)
    index = np.arange(len(nodes))
    graph.add_grid_tedges(index, source_cap, sink_cap)
    graph.maxflow()
    switch = graph.get_grid_segments(index)
    moved: NDArray[np.int64] = nodes[switch]
    return moved if len(moved) else None


def alpha_expansion(
    data: NDArray[Any],
    pairs: NDArray[Any],
    weights: NDArray[Any],
    labels: NDArray[Any] | None = None,
    max_cycles: int = MAX_CYCLES,
    alphas: NDArray[Any] | None = None,
    candidates: NDArray[Any] | None = None,
) -> NDArray[np.int64]:
    """Minimise E(l) by alpha-expansion from ``labels`` (default: each face's cheapest label).

    Labels are expanded in order 0..k-1, cyclically, until every label's move
    has failed to lower the energy since the last one that did (or after
    ``max_cycles`` cycles); deterministic. ``alphas`` limits which labels are
    expanded (default: all); ``candidates`` ((F, k) bool) which labels each face may
    take (default: all).
    """
    data = np.asarray(data, dtype=np.float64)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    weights = np.asarray(weights, dtype=np.float64)
    label_count = data.shape[1]
    current = (
        np.argmin(data, axis=1).astype(np.int64)
        if labels is None
        else np.asarray(labels, dtype=np.int64).copy()
    )
    order = np.arange(label_count) if alphas is None else np.asarray(alphas, dtype=np.int64)
    if label_count <= 1 or len(current) == 0 or len(order) == 0:
        return current
    energy = labelling_energy(current, data, pairs, weights)
    tolerance = 1e-9 * max(1.0, abs(energy))
    # Which nodes may take each label, one contiguous row per label (all: one row).
    allowed_rows = (
        np.ones((1, len(current)), dtype=np.bool_)
        if candidates is None
        else np.ascontiguousarray(np.asarray(candidates, dtype=np.bool_).T)
    )
    # Right after a successful move for alpha, alpha's move cannot gain again
    # until another label changes something: k - 1 failures in a row suffice.
    failures_to_stop = len(order)
    failures = 0
    for move in range(max_cycles * len(order)):
        alpha = int(order[move % len(order)])
        allowed = allowed_rows[0 if candidates is None else alpha]
        moved = _switched(current, alpha, data, pairs, weights, allowed)
        # A move that switches no node leaves the labels, and so the energy, as they are.
        candidate_energy = energy
        if moved is not None:
            candidate = current.copy()
            candidate[moved] = alpha
            candidate_energy = float(_labelling_energy(candidate, data, pairs, weights))
        if candidate_energy < energy - tolerance:
            current, energy = candidate, candidate_energy
            failures, failures_to_stop = 0, len(order) - 1
        else:
            failures += 1
            if failures >= failures_to_stop:
                break
    return current


def banded_alpha_expansion(
    band_data: NDArray[Any],
    pairs: NDArray[Any],
    weights: NDArray[Any],
    labels: NDArray[Any],
    band: NDArray[Any],
    max_cycles: int = MAX_CYCLES,
    label_hops: int | None = None,
) -> NDArray[np.int64]:
    """Alpha-expansion where only ``band`` nodes may change; the rest stay fixed.

    ``band_data`` holds the data costs of the band nodes only, in node order.

    Edges from the band to fixed nodes become unary costs (cutting them when
    leaving the fixed neighbour's label), so the result is optimal-by-moves
    for the band given everything outside it. ``label_hops``: a band node may take only
    the labels that band nodes within that many hops of it have or border (``label_reach``;
    default: any label).
    """
    return _solve_band(
        np.array(band_data, dtype=np.float64), pairs, weights, labels, band, max_cycles, label_hops
    )


def _solve_band(
    band_data: NDArray[np.float64],
    pairs: NDArray[Any],
    weights: NDArray[Any],
    labels: NDArray[Any],
    band: NDArray[Any],
    max_cycles: int,
    label_hops: int | None,
) -> NDArray[np.int64]:
    """``banded_alpha_expansion`` on band data costs it may change in place (its own copy)."""
    labels = np.asarray(labels, dtype=np.int64)
    band = np.asarray(band, dtype=bool)
    nodes = np.flatnonzero(band)
    if len(nodes) == 0:
        return labels.copy()
    sub_data, sub_pairs, sub_weights, alphas = _band_problem(
        band_data,
        nodes,
        band,
        labels,
        np.asarray(pairs, dtype=np.int64).reshape(-1, 2),
        np.asarray(weights, dtype=np.float64),
    )
    candidates = (
        None
        if label_hops is None
        else label_reach(
            labels,
            nodes,
            band,
            np.asarray(pairs, dtype=np.int64).reshape(-1, 2),
            sub_pairs,
            sub_data.shape[1],
            label_hops,
        )
    )
    result = labels.copy()
    result[nodes] = alpha_expansion(
        sub_data, sub_pairs, sub_weights, labels[nodes], max_cycles, alphas, candidates
    )
    return result


def label_reach(
    labels: NDArray[Any],
    nodes: NDArray[Any],
    band: NDArray[Any],
    pairs: NDArray[Any],
    band_pairs: NDArray[Any],
    label_count: int,
    hops: int,
) -> NDArray[np.bool_]:
    """(len(nodes), label_count): for each band node (``nodes``, the band's nodes in order),
    the labels that the band nodes within ``hops`` hops of it over ``band_pairs`` (the edges
    inside the band, in local ids; the node itself at 0 hops) have or border (the labels
    of their neighbours outside the band)."""
    if label_count > 64:  # one bit per label below: no restriction past that
        return np.ones((len(nodes), label_count), dtype=np.bool_)
    return _label_reach(
        np.asarray(labels, dtype=np.int64),
        np.asarray(nodes, dtype=np.int64),
        np.asarray(band, dtype=np.bool_),
        pairs,
        np.asarray(band_pairs, dtype=np.int64).reshape(-1, 2),
        label_count,
        hops,
    )


@kernel
def _label_reach(
    labels: NDArray[Any],
    nodes: NDArray[Any],
    band: NDArray[Any],
    pairs: NDArray[Any],
    band_pairs: NDArray[Any],
    label_count: int,
    hops: int,
) -> NDArray[np.bool_]:  # pragma: no cover - compiled
    """``label_reach`` with a bit per label (at most 64 labels: ``MAX_CLUSTERS`` is 32)."""
    count = len(nodes)
    local = np.full(len(labels), -1, dtype=np.int64)
    reach = np.zeros(count, dtype=np.uint64)
    one = np.uint64(1)
    for i in range(count):
        local[nodes[i]] = i
        reach[i] |= one << np.uint64(labels[nodes[i]])
    for edge in range(len(pairs)):
        a, b = pairs[edge, 0], pairs[edge, 1]
        if band[a] and not band[b]:
            reach[local[a]] |= one << np.uint64(labels[b])
        elif band[b] and not band[a]:
            reach[local[b]] |= one << np.uint64(labels[a])
    previous = np.empty_like(reach)
    for _ in range(hops):  # one hop through the band per pass
        previous[:] = reach
        for edge in range(len(band_pairs)):
            a, b = band_pairs[edge, 0], band_pairs[edge, 1]
            reach[a] |= previous[b]
            reach[b] |= previous[a]
    result = np.zeros((count, label_count), dtype=np.bool_)
    for i in range(count):
        for label in range(label_count):
            result[i, label] = (reach[i] >> np.uint64(label)) & one != 0
    return result


@kernel
def _band_problem(
    sub_data: NDArray[Any],
    nodes: NDArray[Any],
    band: NDArray[Any],
    labels: NDArray[Any],
    pairs: NDArray[Any],
    weights: NDArray[Any],
) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]]:  # pragma: no cover
    """``banded_alpha_expansion``'s sub-problem: the band's data costs (updated in place)
    with each edge to a fixed node folded in, the edges inside the band (local ids) with
    their weights, and the labels in or beside the band (sorted).

    The folded sums add as ``np.bincount`` would (per side of the edges, in edge order,
    from zero, then onto the costs), so the floats are those of the numpy folding."""
    count, label_count = sub_data.shape
    local = np.full(len(labels), -1, dtype=np.int64)
    for i in range(count):
        local[nodes[i]] = i
    candidate = np.zeros(label_count, dtype=np.bool_)
    for i in range(count):
        candidate[labels[nodes[i]]] = True
    inside = np.empty(len(pairs), dtype=np.int64)
    leaving = np.empty(len(pairs), dtype=np.int64)  # band node first, then second (negated)
    inside_count = leaving_count = 0
    for edge in range(len(pairs)):
        in_a, in_b = band[pairs[edge, 0]], band[pairs[edge, 1]]
        if in_a and in_b:
            inside[inside_count] = edge
            inside_count += 1
        elif in_a or in_b:
            leaving[leaving_count] = edge if in_a else -1 - edge
            leaving_count += 1
            candidate[labels[pairs[edge, 0]]] = True
            candidate[labels[pairs[edge, 1]]] = True
    sub_pairs = np.empty((inside_count, 2), dtype=np.int64)
    sub_weights = np.empty(inside_count)
    for row in range(inside_count):
        edge = inside[row]
        sub_pairs[row, 0] = local[pairs[edge, 0]]
        sub_pairs[row, 1] = local[pairs[edge, 1]]
        sub_weights[row] = weights[edge]
    cut = np.zeros(count)
    kept = np.zeros((count, label_count))
    for side in range(2):
        for j in range(leaving_count):
            if (leaving[j] >= 0) == (side == 0):
                edge = leaving[j] if side == 0 else -1 - leaving[j]
                row = local[pairs[edge, side]]
                cut[row] += weights[edge]
                kept[row, labels[pairs[edge, 1 - side]]] += weights[edge]
        # Adding or subtracting the zeros of untouched rows and cells changes no float.
        for j in range(leaving_count):
            if (leaving[j] >= 0) == (side == 0):
                edge = leaving[j] if side == 0 else -1 - leaving[j]
                row = local[pairs[edge, side]]
                if cut[row] != 0.0 or kept[row].any():
                    for label in range(label_count):
                        sub_data[row, label] += cut[row]
                    for label in range(label_count):
                        sub_data[row, label] -= kept[row, label]
                    cut[row] = 0.0
                    kept[row] = 0.0
    return sub_data, sub_pairs, sub_weights, np.flatnonzero(candidate)


def near_boundary(
    labels: NDArray[Any],
    pairs: NDArray[Any],
    node_count: int,
    rings: int,
    adjacency: tuple[NDArray[Any], NDArray[Any]] | None = None,
) -> NDArray[Any]:
    """Nodes within ``rings`` hops (1 = the nodes on a cut edge) of a label boundary.

    ``adjacency``: ``adjacency_lists(pairs, node_count)`` where the caller keeps them.
    """
    labels = np.asarray(labels, dtype=np.int64)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if rings > 1 and adjacency is None:
        adjacency = adjacency_lists(pairs, node_count)
    indptr, neighbours = (
        cast(tuple[NDArray[Any], NDArray[Any]], adjacency)
        if rings > 1
        else (np.zeros(1, np.int64), np.zeros(0, np.int64))
    )
    return _near_boundary(labels, pairs, node_count, rings, indptr, neighbours)


@kernel
def _near_boundary(
    labels: NDArray[Any],
    pairs: NDArray[Any],
    node_count: int,
    rings: int,
    indptr: NDArray[Any],
    neighbours: NDArray[Any],
) -> NDArray[np.bool_]:  # pragma: no cover
    band = np.zeros(node_count, dtype=np.bool_)
    front = np.empty(node_count, dtype=np.int64)
    size = 0
    for edge in range(len(pairs)):
        a, b = pairs[edge, 0], pairs[edge, 1]
        if labels[a] != labels[b]:
            for node in (a, b):
                if not band[node]:
                    band[node] = True
                    front[size] = node
                    size += 1
    start = 0
    for _ in range(rings - 1):  # breadth-first, one ring per pass
        end = size
        for i in range(start, end):
            node = front[i]
            for j in range(indptr[node], indptr[node + 1]):
                other = neighbours[j]
                if not band[other]:
                    band[other] = True
                    front[size] = other
                    size += 1
        start = end
    return band


def coarsen(
    pairs: NDArray[Any],
    weights: NDArray[Any],
    node_count: int,
    cells: NDArray[Any],
    crease_weight: float,
    preferred: NDArray[Any],
) -> NDArray[np.int64]:
    """Coarse node of each node: connected pieces of one grid cell (``cells``: a key per
    node, ``grid_cells``).

    Never groups across a crease (an edge lighter than ``crease_weight``) nor
    nodes whose cheapest label (``preferred``) differs.
    """
    a, b = pairs[:, 0], pairs[:, 1]
    keep = (cells[a] == cells[b]) & (weights >= crease_weight) & (preferred[a] == preferred[b])
    return connected_components(pairs, keep, node_count)


def coarse_graph(
    coarse_of: NDArray[Any],
    pairs: NDArray[Any],
    weights: NDArray[Any],
    coarse_count: int,
    *more_weights: NDArray[Any],
) -> tuple[NDArray[Any], ...]:
    """Edges between coarse nodes (pairs sorted by low, then high node) with summed weights;
    each sum adds its fine edges in their order. ``more_weights``: other per-edge values
    summed over the same edges (returned after the weights), grouped once."""
    coarse_pairs, fine_edges, starts = _coarse_edges(
        np.asarray(coarse_of, dtype=np.int64),
        np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2),
        coarse_count,
    )
    if len(fine_edges) == 0:
        return (coarse_pairs, *(np.zeros(0) for _ in range(1 + len(more_weights))))
    # numpy's reduceat keeps the sums' rounding (pairwise within long runs) as it was.
    return (
        coarse_pairs,
        *(
            np.add.reduceat(np.asarray(values, dtype=np.float64)[fine_edges], starts)
            for values in (weights, *more_weights)
        ),
    )


@kernel
def _coarse_edges(
    coarse_of: NDArray[Any], pairs: NDArray[Any], coarse_count: int
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover
    """(coarse pairs, the fine edges between two coarse nodes grouped by coarse pair in
    fine-edge order, where each group starts): one pass over the edges, then a stable
    counting sort by high node, then by low node (``argsort(low * count + high)``)."""
    cross = np.empty(len(pairs), dtype=np.int64)
    count = 0
    for edge in range(len(pairs)):
        if coarse_of[pairs[edge, 0]] != coarse_of[pairs[edge, 1]]:
            cross[count] = edge
            count += 1
    cross = cross[:count]
    low = np.empty(count, dtype=np.int64)
    high = np.empty(count, dtype=np.int64)
    for i in range(count):
        a, b = coarse_of[pairs[cross[i], 0]], coarse_of[pairs[cross[i], 1]]
        low[i], high[i] = min(a, b), max(a, b)
    order = _counting_order(
        low, _counting_order(high, np.arange(count), coarse_count), coarse_count
    )
    starts = np.empty(count, dtype=np.int64)
    groups = 0
    for i in range(count):
        if i == 0 or low[order[i]] != low[order[i - 1]] or high[order[i]] != high[order[i - 1]]:
            starts[groups] = i
            groups += 1
    starts = starts[:groups]
    coarse_pairs = np.empty((groups, 2), dtype=np.int64)
    for group in range(groups):
        coarse_pairs[group, 0] = low[order[starts[group]]]
        coarse_pairs[group, 1] = high[order[starts[group]]]
    fine_edges = np.empty(count, dtype=np.int64)
    for i in range(count):
        fine_edges[i] = cross[order[i]]
    return coarse_pairs, fine_edges, starts


@kernel(inline=True)
def _counting_order(
    keys: NDArray[Any], order: NDArray[Any], count: int
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """``order`` stably re-sorted by ``keys[order]`` (keys in 0..count-1)."""
    start = np.zeros(count + 1, dtype=np.int64)
    for i in range(len(keys)):
        start[keys[i] + 1] += 1
    for key in range(count):
        start[key + 1] += start[key]
    result = np.empty(len(order), dtype=np.int64)
    for i in order:
        result[start[keys[i]]] = i
        start[keys[i]] += 1
    return result


def coarse_data(
    coarse_of: NDArray[Any], data: NDArray[Any], coarse_count: int
) -> NDArray[np.float64]:
    """(coarse_count, k) data costs summed over each coarse node's nodes, in node order."""
    return _coarse_data(np.asarray(coarse_of, dtype=np.int64), data, coarse_count)


@kernel
def _coarse_data(
    coarse_of: NDArray[Any], data: NDArray[Any], coarse_count: int
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    summed = np.zeros((coarse_count, data.shape[1]))
    for node in range(len(coarse_of)):
        for label in range(data.shape[1]):
            summed[coarse_of[node], label] += data[node, label]
    return summed


@dataclass(frozen=True)
class CutLevel:
    """One level of the multilevel graph cut: its graph, data costs and edge weights at
    smoothing 1, and the map of its nodes to the next coarser level."""

    pairs: NDArray[np.int64]
    unit_weights: NDArray[np.float64]
    data: NDArray[np.float64]
    #: Node of the next coarser level per node (None at the coarsest level).
    coarse_of: NDArray[np.int64] | None
    #: ``adjacency_lists`` for the boundary band (None at the coarsest level).
    adjacency: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None
    #: While coarsening: the nodes' grid coordinates and the next level's cell size.
    positions: NDArray[np.float64] | None = None
    cell_size: float = 0.0

    @property
    def nbytes(self) -> int:
        arrays = (self.pairs, self.unit_weights, self.data, self.coarse_of)
        size = sum(a.nbytes for a in arrays if a is not None)
        if self.adjacency is not None:
            size += sum(a.nbytes for a in self.adjacency)
        return size


@dataclass(frozen=True)
class StalledTop:
    """Where coarsening by cheapest label stopped above ``coarse_nodes`` nodes (interleaved
    clusters): what ``CutHierarchy.solve`` needs to coarsen the top level further by each
    smoothing's own label preference."""

    #: Grid coordinates of the top level's nodes (``principal_coordinates`` of their first faces).
    positions: NDArray[np.float64]
    #: The grid cell size of the next level.
    cell_size: float
    crease_weight: float
    coarse_nodes: int
    #: ``adjacency_with_edges`` of the top level, for ``smoothed_preference`` at each smoothing.
    adjacency: tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]] | None = None
    #: Summed edge lengths of the top level's edges where creases are judged per length.
    lengths: NDArray[np.float64] | None = None

    @cached_property
    def sweep_order(self) -> NDArray[np.int64]:
        """The top level's nodes by position, |x| then |y| then |z| (the axes' signs are
        the pose's): the order in which ``smoothed_preference`` visits them, the same
        whatever order the faces came in."""
        order: NDArray[np.int64] = np.lexsort(np.abs(self.positions).T[::-1])
        return order

    @property
    def nbytes(self) -> int:
        arrays = (self.positions, *(self.adjacency or ()))
        if self.lengths is not None:
            arrays = (*arrays, self.lengths)
        return sum(a.nbytes for a in arrays)


@dataclass(frozen=True)
class CutHierarchy:
    """The coarse graphs of a multilevel graph cut, finest first.

    They depend on the data costs, the graph and the edge weights only up to a common
    factor (the smoothing), so one hierarchy serves every smoothing value:
    ``solve(smoothing)`` minimises the energy with edge weights ``smoothing * unit_weights``.
    """

    levels: tuple[CutLevel, ...]
    rings: int = BAND_RINGS
    #: Set when coarsening stalled above ``coarse_nodes``: ``solve`` coarsens further.
    stalled: StalledTop | None = None

    @property
    def nbytes(self) -> int:
        size = sum(level.nbytes for level in self.levels)
        return size + (self.stalled.nbytes if self.stalled is not None else 0)

    def solve(self, smoothing: float) -> NDArray[np.int64]:
        """Labels minimising E with edge weights ``unit_weights * smoothing``; deterministic."""
        finest = self.levels[0]
        if not smoothing > 0 or finest.data.shape[1] <= 1:
            # No smoothness term (or one label): each node's cheapest label is optimal.
            cheapest: NDArray[np.int64] = np.argmin(finest.data, axis=1).astype(np.int64)
            return cheapest
        levels = self.levels
        if self.stalled is not None:
            levels = levels[:-1] + self._smoothed_levels(smoothing)
        top = levels[-1]
        # A top coarsened past a stall is followed by the full cycle at the stalled level.
        cycles = SMOOTHED_TOP_CYCLES if len(levels) > len(self.levels) else MAX_CYCLES
        labels = alpha_expansion(
            top.data, top.pairs, quantized(top.unit_weights * smoothing), None, cycles
        )
        for index in reversed(range(len(levels) - 1)):
            level = levels[index]
            labels = labels[level.coarse_of]
            weights = quantized(level.unit_weights * smoothing)
            if index == len(self.levels) - 1:
                # The stalled level: grouping by smoothed preference leads alpha-expansion
                # to other local minima than a direct solve there; one full cycle of
                # expansion moves from the coarse labels recovers the direct solve's
                # energy (docs/benchmarks.md) in a fraction of its moves.
                labels = alpha_expansion(level.data, level.pairs, weights, labels, max_cycles=1)
                continue
            band = near_boundary(labels, level.pairs, len(level.data), self.rings, level.adjacency)
            # ``level.data[band]`` is a fresh copy: the band solve folds its edges into it.
            labels = _solve_band(
                level.data[band], level.pairs, weights, labels, band, BAND_CYCLES, BAND_LABEL_HOPS
            )
        return labels

    def _smoothed_levels(self, smoothing: float) -> tuple[CutLevel, ...]:
        """The stalled top level coarsened further, grouping nodes by the labels a few
        sweeps of iterated conditional modes give at this smoothing (``smoothed_preference``)
        rather than by their cheapest label, which interleaves where clusters overlap."""
        top, stalled = self.levels[-1], cast(StalledTop, self.stalled)
        preferred = smoothed_preference(
            top.data,
            top.pairs,
            quantized(top.unit_weights * smoothing),
            adjacency=stalled.adjacency,
            order=stalled.sweep_order,
        )
        levels = coarsen_levels(
            top.pairs,
            top.unit_weights,
            top.data,
            stalled.positions,
            stalled.cell_size,
            SMOOTHED_CREASE_SCALE * stalled.crease_weight,
            min(stalled.coarse_nodes, SMOOTHED_COARSE_NODES),
            self.rings,
            preferred,
            stalled.lengths,
            first_band=False,  # the stalled level runs a full cycle
        )[0]
        return (top,) if len(levels) == 1 else tuple(levels)


def cut_hierarchy(
    data: NDArray[Any],
    pairs: NDArray[Any],
    unit_weights: NDArray[Any],
    centroids: NDArray[Any],
    areas: NDArray[Any],
    coarse_nodes: int = COARSE_NODES,
    rings: int = BAND_RINGS,
    lengths: NDArray[Any] | None = None,
    frame: tuple[NDArray[Any], NDArray[Any]] | None = None,
) -> CutHierarchy:
    """Coarsen the graph until at most ``coarse_nodes`` nodes remain (or it stops shrinking).

    Nodes are grouped into connected pieces of a 3-D grid laid along the mesh's own
    axes (``principal_coordinates``, ``grid_cells``: the same groups in any pose; cells
    doubling per level, a coarse node placed at its members' box centre;
    crease edges and nodes preferring different labels never grouped), with data and
    edge weights summed, so a labelling that is constant on groups has the same energy
    at every level. Scaling ``unit_weights`` scales every level's weights alike, so the
    hierarchy does not depend on the smoothing. Where it stops shrinking above
    ``coarse_nodes``, ``stalled`` keeps the top level's grid for ``solve`` to coarsen
    further by each smoothing's own preferences. ``lengths`` (the edges' lengths): creases
    are edges whose weight per unit length is below ``CREASE_FRACTION`` times the median,
    judged so at every level (coarse edges sum lengths as they sum weights); without them,
    edges lighter than ``CREASE_FRACTION`` times the median weight. ``frame``:
    ``principal_frame(centroids, areas)`` where the caller keeps it.
    """
    data = np.asarray(data, dtype=np.float64)
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    weights = np.asarray(unit_weights, dtype=np.float64)
    node_count = len(data)
    if node_count <= coarse_nodes or data.shape[1] <= 1:
        return CutHierarchy((CutLevel(pairs, weights, data, None),), rings)

    positions = principal_coordinates(centroids, areas, frame)  # the grid turns with the mesh
    mean_area = float(np.mean(areas))
    if not mean_area > 0:
        extent = float(np.ptp(positions, axis=0).max()) or 1.0
        mean_area = extent**2 / node_count
    cell_size = np.sqrt(FACES_PER_CELL * mean_area)
    if lengths is not None:
        lengths = np.asarray(lengths, dtype=np.float64)
    per_length = weights if lengths is None else _per_length(weights, lengths)
    crease_weight = CREASE_FRACTION * float(np.median(per_length)) if len(weights) else 0.0

    levels, top_lengths = coarsen_levels(
        pairs,
        weights,
        data,
        positions,
        cell_size,
        crease_weight,
        coarse_nodes,
        rings,
        lengths=lengths,
    )
    top = levels[-1]
    stalled = None
    if len(top.data) > coarse_nodes and top.positions is not None:
        adjacency = adjacency_with_edges(top.pairs, len(top.data))  # kept for every smoothing
        stalled = StalledTop(
            top.positions, top.cell_size, crease_weight, coarse_nodes, adjacency, top_lengths
        )
    levels[-1] = replace(top, positions=None)
    return CutHierarchy(tuple(levels), rings, stalled)


def coarsen_levels(
    pairs: NDArray[Any],
    weights: NDArray[Any],
    data: NDArray[Any],
    positions: NDArray[Any],
    cell_size: float,
    crease_weight: float,
    coarse_nodes: int,
    rings: int,
    preferred: NDArray[Any] | None = None,
    lengths: NDArray[Any] | None = None,
    *,
    first_band: bool = True,
) -> tuple[list[CutLevel], NDArray[np.float64] | None]:
    """The levels from this graph (first) to the coarsest (last): grid-cell pieces grouped
    (``coarsen``) until at most ``coarse_nodes`` nodes remain or a level would keep more
    than 80% of its nodes. ``preferred``: the label each node prefers (default: its cheapest);
    a group prefers its nodes' label. The coarsest level keeps its nodes' ``positions``
    and the next ``cell_size``. ``lengths``: the edges' lengths, where ``crease_weight`` is
    a weight per unit length (summed per coarse edge like the weights; the coarsest
    level's are returned beside the levels). ``first_band``: whether this graph is re-solved
    in a band (False: no adjacency built for it)."""
    levels: list[CutLevel] = []
    level_pairs, level_weights, level_data = pairs, weights, data
    level_lengths = lengths
    while len(level_data) > coarse_nodes:
        count = len(level_data)
        cells = grid_cells(positions, cell_size)
        level_preferred = level_data.argmin(axis=1) if preferred is None else preferred
        judged = (
            level_weights if level_lengths is None else _per_length(level_weights, level_lengths)
        )
        coarse_of = coarsen(level_pairs, judged, count, cells, crease_weight, level_preferred)
        coarse_count = int(coarse_of.max()) + 1
        if coarse_count > 0.8 * count:
            break  # no longer shrinking (many tiny shells, or all creases)
        summed_data = coarse_data(coarse_of, level_data, coarse_count)
        if level_lengths is None:
            coarse_pairs, coarse_weights = coarse_graph(
                coarse_of, level_pairs, level_weights, coarse_count
            )
        else:
            coarse_pairs, coarse_weights, level_lengths = coarse_graph(
                coarse_of, level_pairs, level_weights, coarse_count, level_lengths
            )
        # A node at the centre of its members' box: the same point in any face order and
        # pose (the first member by index was another point when the faces came reordered).
        positions, cell_size = _box_centres(coarse_of, positions, coarse_count), 2.0 * cell_size
        if preferred is not None:  # one label per group: every member prefers it
            first = np.full(coarse_count, -1, dtype=np.int64)
            first[coarse_of] = np.arange(count)
            preferred = preferred[first]
        levels.append(
            CutLevel(
                level_pairs,
                level_weights,
                level_data,
                coarse_of,
                adjacency_lists(level_pairs, count)
                if rings > 1 and (levels or first_band)
                else None,
            )
        )
        level_pairs, level_weights, level_data = coarse_pairs, coarse_weights, summed_data
    levels.append(
        CutLevel(level_pairs, level_weights, level_data, None, None, positions, cell_size)
    )
    return levels, level_lengths


@kernel
def _box_centres(
    group: NDArray[np.int64], positions: NDArray[np.float64], count: int
) -> NDArray[np.float64]:  # pragma: no cover - compiled
    """Per group 0..count-1, the centre of its members' bounding box."""
    low = np.full((count, 3), np.inf)
    high = np.full((count, 3), -np.inf)
    for node in range(len(group)):
        g = group[node]
        for axis in range(3):
            low[g, axis] = min(low[g, axis], positions[node, axis])
            high[g, axis] = max(high[g, axis], positions[node, axis])
    centres: NDArray[np.float64] = 0.5 * (low + high)
    return centres


def _per_length(weights: NDArray[Any], lengths: NDArray[Any]) -> NDArray[np.float64]:
    """Weight per unit length of each edge (an edge of zero length: its weight)."""
    result: NDArray[np.float64] = np.asarray(weights, dtype=np.float64).copy()
    np.divide(weights, lengths, out=result, where=np.asarray(lengths) > 0)
    return result


def smoothed_preference(
    data: NDArray[Any],
    pairs: NDArray[Any],
    weights: NDArray[Any],
    sweeps: int = PREFERENCE_SWEEPS,
    adjacency: tuple[NDArray[Any], NDArray[Any], NDArray[Any]] | None = None,
    order: NDArray[Any] | None = None,
) -> NDArray[np.int64]:
    """Each node's label after ``sweeps`` sweeps of iterated conditional modes (nodes in
    ``order``, default their own; from the cheapest labels): the label minimising its data
    cost plus the weight of its edges to nodes of other labels. Deterministic.
    ``adjacency``: ``adjacency_with_edges(pairs, len(data))`` where the caller keeps it."""
    data = np.asarray(data, dtype=np.float64)
    if adjacency is None:
        pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
        adjacency = adjacency_with_edges(pairs, len(data))
    indptr, neighbours, edge_of = adjacency
    order = np.arange(len(data)) if order is None else np.asarray(order, dtype=np.int64)
    return _iterated_modes(
        data, indptr, neighbours, edge_of, np.asarray(weights, np.float64), sweeps, order
    )


@kernel
def _iterated_modes(
    data: NDArray[Any],
    indptr: NDArray[Any],
    neighbours: NDArray[Any],
    edge_of: NDArray[Any],
    weights: NDArray[Any],
    sweeps: int,
    order: NDArray[Any],
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    count, label_count = data.shape
    labels = np.empty(count, dtype=np.int64)
    for node in range(count):
        labels[node] = np.argmin(data[node])
    cost = np.empty(label_count)
    for _ in range(sweeps):
        changed = 0
        for node in order:
            for label in range(label_count):
                cost[label] = data[node, label]
            for j in range(indptr[node], indptr[node + 1]):
                cost[labels[neighbours[j]]] -= weights[edge_of[j]]
            best = labels[node]
            for label in range(label_count):
                if cost[label] < cost[best]:
                    best = label
            if best != labels[node]:
                labels[node] = best
                changed += 1
        if changed == 0:
            break
    return labels


def multilevel_alpha_expansion(
    data: NDArray[Any],
    pairs: NDArray[Any],
    weights: NDArray[Any],
    centroids: NDArray[Any],
    areas: NDArray[Any],
    coarse_nodes: int = COARSE_NODES,
    rings: int = BAND_RINGS,
) -> NDArray[np.int64]:
    """Alpha-expansion through a hierarchy of coarse graphs (a banded multilevel graph cut).

    The coarsest graph (``cut_hierarchy``) is solved by alpha-expansion; each finer level
    inherits the labels and re-solves only a band of ``rings`` hops around the
    boundaries. Graphs already at most ``coarse_nodes`` large are solved directly.
    Deterministic.
    """
    return cut_hierarchy(data, pairs, weights, centroids, areas, coarse_nodes, rings).solve(1.0)
