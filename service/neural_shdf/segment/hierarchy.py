"""A merge tree (dendrogram) over the parts of an over-segmentation.

Adjacent parts merge greedily, cheapest first, where the cost of merging A and B is
what a person would weigh::

    cost = size ** SIZE_EXPONENT * (CONSTANT + difference
           + CONCAVITY_WEIGHT * concavity) * neck ** -NECK_EXPONENT

* ``size``: the smaller part's share of the surface area (slivers go first);
* ``difference``: how far the two parts' ShDF differs (thick and thin differ): the
  difference ``d`` of their area-weighted means of the log-normalised ShDF, times
  ``(min(step, d) / d) ** STEP_EXPONENT`` where ``step`` is the ShDF's step across their
  shared boundary (``boundary_profile``: the two sides' means within ``FOLD_SCALE`` of the
  surface's size, length-weighted over the boundary). A thickness that changes where the
  parts meet is a natural boundary; a cut through a slow gradient (a cup's wall
  thickening to its base, which the over-segmentation may cut anywhere) is not;
* ``concavity``: length-weighted mean over the shared boundary of how far the surface
  folds inward across it (``boundary_profile``: the angle / pi between the two parts' mean
  normals within ``FOLD_SCALE`` of the surface's size; convex and flat folds count 0),
  read at the surface's scale so that a crease weighs the same at any tessellation: a
  crease is a natural boundary;
* ``neck``: shared boundary length over sqrt(smaller part's area): a short cut
  around a protrusion (a finger, a handle) is natural, a long one is not.

Tree layout (scipy's ``linkage`` convention): leaves are nodes ``0..L-1``; merge
``i`` creates node ``L + i`` from ``merges[i]``; the root is ``2L - 2``. Cutting
at N parts undoes the last ``N - 1`` merges: each leaf belongs to its highest
ancestor whose id is below ``2L - N``. Cuts are nested (N + 1 refines N).
Parts of a cut are numbered by their smallest leaf; with leaves numbered by their
lowest face, that is the order of each part's lowest face (``canonical_labels``).

Shells with no shared edge merge after every adjacent pair, smallest first, into
the part of nearest ShDF mean (their cost treats the missing boundary as the
narrowest neck), so the tree always has one root.
"""

from __future__ import annotations

import heapq
import math
from array import array
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.errors import ParameterError
from neural_shdf.geometry import FaceGraph, grid_layout
from neural_shdf.segment.parts import FaceData, canonical_labels, cut_edges

# The weights were tuned on 57 psb-dev models (the 4th model of each category held out),
# first for the Rand index at the humans' most frequent part count, then the size
# exponent with the automatic threshold for the cut discrepancy at the automatic count,
# on leaves with boundaries on creases (the default); the scores are in the benchmark
# outputs (``benchmarks/bench_psb.py``), not here.

#: Exponent of the smaller part's area share: small parts merge first.
SIZE_EXPONENT = 0.5
#: Exponent of the neck ratio (shared boundary length over sqrt(smaller area)).
NECK_EXPONENT = 2.0
#: Cost of merging two parts with the same ShDF across a flat boundary, relative to
#: a difference of 1 in mean log-normalised ShDF.
COST_CONSTANT = 0.005
#: Weight of the boundary's mean concave fold (over pi, ``boundary_profile``). Version 25,
#: on the 57 tuning models (1-RI / CD, automatic count): 2.5 0.140 / 0.231, 3 0.138 /
#: 0.225, 3.5 0.138 / 0.222, 4 0.138 / 0.222 (8 with per-edge angles: 0.141 / 0.221).
CONCAVITY_WEIGHT = 3.5
#: How much the ShDF's step across a boundary, where smaller than the parts' mean
#: difference, stands for it (0: the means alone, 1: the step alone; see the module
#: docstring). Version 26, 57 tuning models, 1-RI / CD at the best threshold of each:
#: 0 0.138 / 0.222 (0.02), 0.5 0.137 / 0.222 (0.014), 0.75 0.139 / 0.223 (0.014), 1 0.139 /
#: 0.221 (0.012); 0.5 and 1 both kept every tuning production variant within +0.01 / +0.02,
#: 0.5 with the better published score (``bench_psb.py``, ``bench_production.py``).
STEP_EXPONENT = 0.5
#: Smallest neck ratio (a shell with no shared boundary counts as this narrow).
NECK_FLOOR = 0.05


@dataclass(frozen=True)
class MergeCost:
    """The weights of the merge cost (see the module docstring)."""

    size_exponent: float = SIZE_EXPONENT
    neck_exponent: float = NECK_EXPONENT
    constant: float = COST_CONSTANT
    concavity_weight: float = CONCAVITY_WEIGHT
    step_exponent: float = STEP_EXPONENT

    def __call__(
        self,
        area_a: float,
        area_b: float,
        mean_a: float,
        mean_b: float,
        boundary: float,
        concave: float,
        total_area: float,
        step: float | None = None,
    ) -> float:
        """Cost of merging parts a and b (``concave``: concave-angle-weighted boundary length;
        ``step``: ShDF-step-weighted boundary length, None where unknown)."""
        smaller = min(area_a, area_b)
        size = smaller / total_area if total_area > 0 else 0.0
        concavity = concave / boundary if boundary > 0 else 1.0
        neck = boundary / math.sqrt(smaller) if smaller > 0 else 0.0
        neck = max(neck, NECK_FLOOR)
        difference = abs(mean_a - mean_b)
        if step is not None and boundary > 0 and difference > 0:
            local = min(step / boundary, difference)
            difference *= (local / difference) ** self.step_exponent
        similarity = self.constant + difference + self.concavity_weight * concavity
        cost: float = size**self.size_exponent * similarity * neck**-self.neck_exponent
        return cost


#: The concavity of a boundary (and its ShDF step) is read between the two parts' surfaces
#: within about this share of sqrt(surface area) of each boundary edge (``boundary_profile``:
#: one to two cells of this side). Version 25, 57 tuning models at weight 3 (1-RI / CD):
#: 0.01 0.141 / 0.239, 0.02 0.138 / 0.225, 0.04 0.142 / 0.254.
FOLD_SCALE = 0.02


class BoundaryProfile(NamedTuple):
    """What changes across each pair of adjacent faces in different leaves, read at the
    surface's scale (``boundary_profile``)."""

    #: How far the surface folds inward, as a share of pi (0: convex or flat).
    folds: NDArray[np.float64]
    #: How far the ShDF differs between the two sides (absolute difference of means).
    steps: NDArray[np.float64]


def boundary_profile(
    face_pairs: NDArray[Any],
    leaves: NDArray[Any],
    surface: FaceData,
    values: NDArray[Any],
    scale: float = FOLD_SCALE,
) -> BoundaryProfile:
    """How concave the surface folds, and how far ``values`` (per-face ShDF) step, across
    each pair of adjacent faces in different leaves, read at the surface's scale rather
    than per edge.

    Around each pair, the faces of each side's leaf within about ``scale`` x sqrt(area)
    (the 27 cells of a grid of that side around the pair's cell) give an area-weighted
    mean normal, centroid and value; the fold is the angle between the two mean normals
    over pi, concave where they turn towards each other (else 0), the step the difference
    of the two mean values (a side whose cells hold none of its leaf's faces, faces larger
    than the cells, reads its own face of the pair). A crease rounded over a few faces
    then folds as much as a sharp one, and as much at any tessellation: per edge, a Loop
    pass halves the angles and a decimation doubles them; a slow gradient of the ShDF
    steps little wherever it is cut. Worked out in a frame of the shape's own
    (``FaceData.pose_centroids``, ``pose_normals``): the same cells and sums in any pose.
    """
    face_pairs = np.asarray(face_pairs, dtype=np.int64).reshape(-1, 2)
    values = np.asarray(values, dtype=np.float64)
    areas = np.asarray(surface.areas, dtype=np.float64)
    total = float(areas.sum())
    if not len(face_pairs) or not total > 0:
        first, second = face_pairs[:, 0], face_pairs[:, 1]
        return BoundaryProfile(np.zeros(len(face_pairs)), np.abs(values[first] - values[second]))
    leaves = np.asarray(leaves, dtype=np.int64)
    coordinates = np.ascontiguousarray(surface.pose_centroids)
    size = scale * math.sqrt(total) / surface.pose_scale
    box = float(np.prod(np.ptp(coordinates, axis=0) / size + 3.0))
    if box > FOLD_GRID_CELLS:  # a surface spread thin over a large space: larger cells
        size *= (box / FOLD_GRID_CELLS) ** (1.0 / 3.0)
    cells, low, spans = grid_layout(coordinates, size, margin=1)
    strides = np.array([spans[1] * spans[2], spans[2], 1], dtype=np.int64)
    first, second = face_pairs[:, 0], face_pairs[:, 1]
    middle = np.floor((coordinates[first] + coordinates[second]) / (2 * size) + 0.5)
    around = (middle.astype(np.int64) - low) @ strides
    groups, group_of_pair = np.unique(
        np.stack([around, leaves[first], leaves[second]], axis=1), axis=0, return_inverse=True
    )
    offsets = np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T @ strides
    leaf_count = int(leaves.max()) + 1
    # The (cell, leaf) slots each side reads (the 27 cells around its group's cell, the
    # side's leaf): only faces in them are summed, a band along the cuts.
    cells_around = groups[:, :1] + offsets[None, :]
    wanted = [cells_around * leaf_count + groups[:, column, None] for column in (1, 2)]
    slot_keys = np.unique(np.concatenate([keys.reshape(-1) for keys in wanted]))
    near = np.zeros(int(np.prod(spans)), dtype=bool)
    near[slot_keys // leaf_count] = True
    band = np.flatnonzero(near[cells])
    band_keys = cells[band] * leaf_count + leaves[band]
    at = np.minimum(np.searchsorted(slot_keys, band_keys), len(slot_keys) - 1)
    inside = slot_keys[at] == band_keys
    band, at = band[inside], at[inside]
    weights = areas[band]
    sums = np.empty((len(slot_keys), 8))  # normal (3), area x centroid (3), area, area x value
    for axis in range(3):
        sums[:, axis] = np.bincount(at, weights * surface.pose_normals[band, axis], len(slot_keys))
        sums[:, 3 + axis] = np.bincount(at, weights * coordinates[band, axis], len(slot_keys))
    sums[:, 6] = np.bincount(at, weights, len(slot_keys))
    sums[:, 7] = np.bincount(at, weights * values[band], len(slot_keys))
    group_of_pair = group_of_pair.reshape(-1)
    side_a, side_b = (
        sums[np.searchsorted(slot_keys, keys)].sum(axis=1)[group_of_pair] for keys in wanted
    )
    # Faces larger than the cells can leave a side's cells empty: its own face stands in.
    for side, faces in ((side_a, first), (side_b, second)):
        empty = np.flatnonzero(side[:, 6] <= 0)
        own = faces[empty]
        side[empty, :3] = areas[own, None] * surface.pose_normals[own]
        side[empty, 3:6] = areas[own, None] * coordinates[own]
        side[empty, 6] = areas[own]
        side[empty, 7] = areas[own] * values[own]
    weight_a = np.maximum(side_a[:, 6:7], np.finfo(np.float64).tiny)
    weight_b = np.maximum(side_b[:, 6:7], np.finfo(np.float64).tiny)
    normal_a, normal_b = side_a[:, :3], side_b[:, :3]
    angle = np.arctan2(
        np.linalg.norm(np.cross(normal_a, normal_b), axis=1),
        np.einsum("ij,ij->i", normal_a, normal_b),
    )
    towards = np.einsum(
        "ij,ij->i", normal_b - normal_a, side_b[:, 3:6] / weight_b - side_a[:, 3:6] / weight_a
    )
    folds = np.where(towards < 0, angle / np.pi, 0.0)
    steps = np.abs(side_b[:, 7] / weight_b[:, 0] - side_a[:, 7] / weight_a[:, 0])
    return BoundaryProfile(folds, steps)


#: ``boundary_profile``: at most this many cells in the grid's box (a surface spread thin
#: over a large space gets larger cells).
FOLD_GRID_CELLS = 2**24


@dataclass(frozen=True)
class PartTree:
    """A dendrogram over leaf parts.

    Attributes:
        leaf_labels: (F,) leaf id of each face, ``0..L-1`` in order of each leaf's lowest face.
        merges: (L-1, 2) the two nodes merged into node ``L + i``, smaller id first.
        costs: (L-1,) the cost of each merge, when it was made (may dip below an earlier one).
    """

    leaf_labels: NDArray[np.int64]
    merges: NDArray[np.int64]
    costs: NDArray[np.float64]

    @property
    def leaf_count(self) -> int:
        return len(self.merges) + 1 if len(self.leaf_labels) else 0

    @property
    def heights(self) -> NDArray[np.float64]:
        """Monotone merge heights: the running maximum of the costs (for display, gaps)."""
        return np.maximum.accumulate(self.costs) if len(self.costs) else self.costs

    @property
    def parent(self) -> NDArray[np.int64]:
        """(2L-1,) parent node of every node; -1 for the root."""
        leaves = self.leaf_count
        parent = np.full(max(2 * leaves - 1, 0), -1, dtype=np.int64)
        if len(self.merges):
            parent[self.merges.reshape(-1)] = np.repeat(
                np.arange(leaves, 2 * leaves - 1, dtype=np.int64), 2
            )
        return parent

    @classmethod
    def from_parent(
        cls, leaf_labels: NDArray[Any], parent: NDArray[Any], costs: NDArray[Any]
    ) -> PartTree:
        """The tree from its ``parent`` array (the API's form; the inverse of ``parent``).

        Raises ValueError when ``parent`` is not a merge tree over ``(len(parent) + 1) / 2``
        leaves (each merge node ``L + i`` with exactly two children, the root last).
        """
        parent = np.asarray(parent, dtype=np.int64).reshape(-1)
        leaves = (len(parent) + 1) // 2
        nodes = np.flatnonzero(parent >= 0)
        merges = nodes[np.lexsort((nodes, parent[nodes]))]
        expected = np.repeat(np.arange(leaves, 2 * leaves - 1, dtype=np.int64), 2)
        if (
            len(parent) != max(2 * leaves - 1, 0)
            or (leaves and parent[-1] != -1)
            or not np.array_equal(parent[merges], expected)
            or np.any(merges >= parent[merges])
        ):
            raise ValueError(f"not a merge tree's parent array over {leaves} leaves")
        return cls(
            np.asarray(leaf_labels, dtype=np.int64),
            merges.reshape(-1, 2),
            np.asarray(costs, dtype=np.float64).reshape(-1),
        )

    def listed_by(self, leaf_labels: NDArray[Any]) -> PartTree:
        """The same tree over the faces listed another way: ``leaf_labels`` gives this
        tree's leaf of each face in the new order; the leaves are numbered again in order
        of their lowest face there (each merge's smaller id first, as always)."""
        leaf_labels = np.asarray(leaf_labels, dtype=np.int64).reshape(-1)
        renumbered = canonical_labels(leaf_labels)
        leaves = self.leaf_count
        node = np.arange(max(2 * leaves - 1, 0), dtype=np.int64)
        node[leaf_labels] = renumbered
        return PartTree(renumbered, np.sort(node[self.merges], axis=1), self.costs)

    def leaf_parts(self, count: int) -> NDArray[np.int64]:
        """(L,) part of each leaf when the tree is cut into ``count`` parts (clamped to 1..L).

        Parts are numbered in order of their smallest leaf.
        """
        leaves = self.leaf_count
        if leaves == 0:
            return np.zeros(0, dtype=np.int64)
        count = min(max(int(count), 1), leaves)
        owner = np.arange(2 * leaves - 1, dtype=np.int64)
        made = leaves - count  # union of the first L - count merges
        owner[self.merges[:made].reshape(-1)] = np.repeat(np.arange(leaves, leaves + made), 2)
        root_of_leaf = _resolve_owners(owner)[:leaves]
        smallest = np.full(2 * leaves - 1, leaves, dtype=np.int64)
        np.minimum.at(smallest, root_of_leaf, np.arange(leaves))
        _, dense = np.unique(smallest[root_of_leaf], return_inverse=True)
        return dense.reshape(-1).astype(np.int64)

    def labels(self, count: int) -> NDArray[np.int64]:
        """(F,) part per face for ``count`` parts (clamped to 1..L); canonical numbering."""
        return self.leaf_parts(count)[self.leaf_labels]

    def relabel(self, leaf_labels: NDArray[Any], count: int) -> NDArray[np.int64]:
        """Parts of any array of leaf ids (e.g. per input face) at ``count``; -1 stays -1."""
        leaf_labels = np.asarray(leaf_labels, dtype=np.int64)
        parts = self.leaf_parts(count)
        return np.where(leaf_labels >= 0, parts[np.maximum(leaf_labels, 0)], -1)


def merge_tree(
    leaf_labels: NDArray[Any],
    graph: FaceGraph,
    surface: FaceData,
    values: NDArray[Any],
    cost: MergeCost | None = None,
    mirror_leaf: NDArray[Any] | None = None,
    spokes: tuple[NDArray[Any], NDArray[Any]] | None = None,
) -> PartTree:
    """The merge tree of the parts ``leaf_labels`` (canonical: 0..L-1 by lowest face).

    ``values``: per-face ShDF on the scale the cost compares (log-normalised, [0, 1]).
    ``mirror_leaf``: the mirror image of each leaf (itself for a leaf across the plane, -1
    for none; ``segment.symmetry.mirror_leaves``): each merge is followed at once by its
    mirror merge, both at the dearer of their two costs, so that the tree's cuts at its
    automatic count are mirror images too (greedy merging alone lets near-equal costs go
    either way).
    ``spokes``: (pairs of faces, lengths) where the fans over holes would join rim faces
    (``stitching.cap_spokes``): between faces of two parts, flat boundary as long as the
    spoke, as if the fan were surface (no fold, no step of the ShDF). A hole on a boundary
    shortened it, which reads as a narrower neck and a dearer merge: holes kept extra parts.
    ``surface``: the faces' areas, and their centroids and normals in the pose frame
    (``boundary_profile``).
    """
    cost = MergeCost() if cost is None else cost
    leaves = np.asarray(leaf_labels, dtype=np.int64)
    face_count = len(leaves)
    if face_count != graph.face_count:
        raise ParameterError(f"{face_count} leaf labels for {graph.face_count} faces")
    if face_count == 0:
        return PartTree(leaves, np.zeros((0, 2), dtype=np.int64), np.zeros(0))
    leaf_count = int(leaves.max()) + 1
    areas = np.asarray(surface.areas, dtype=np.float64)
    if not areas.sum() > 0:
        areas = np.ones(face_count)
    area = np.bincount(leaves, weights=areas, minlength=leaf_count)
    moment = np.bincount(leaves, weights=areas * values, minlength=leaf_count)
    total_area = float(area.sum())

    pairs = np.ascontiguousarray(graph.pairs, dtype=np.int64).reshape(-1, 2)
    cut = cut_edges(leaves, pairs, leaf_count)[0]  # one pass, no per-edge arrays
    a, b = leaves[pairs[cut, 0]], leaves[pairs[cut, 1]]
    lengths = graph.edge_length[cut]
    values = np.asarray(values, dtype=np.float64)
    depth, step = boundary_profile(pairs[cut], leaves, surface, values)
    if spokes is not None and len(spokes[0]):
        spoke_pairs = np.asarray(spokes[0], dtype=np.int64).reshape(-1, 2)
        sa, sb = leaves[spoke_pairs[:, 0]], leaves[spoke_pairs[:, 1]]
        across = sa != sb
        a, b = np.concatenate([a, sa[across]]), np.concatenate([b, sb[across]])
        lengths = np.concatenate([lengths, np.asarray(spokes[1], dtype=np.float64)[across]])
        depth = np.concatenate([depth, np.zeros(int(across.sum()))])
        step = np.concatenate([step, np.zeros(int(across.sum()))])
    low, high = np.minimum(a, b), np.maximum(a, b)
    keys, inverse = np.unique(low * leaf_count + high, return_inverse=True)
    inverse = inverse.reshape(-1)
    boundary = np.bincount(inverse, weights=lengths, minlength=len(keys))
    concave = np.bincount(inverse, weights=lengths * depth, minlength=len(keys))
    stepped = np.bincount(inverse, weights=lengths * step, minlength=len(keys))

    node_count = 2 * leaf_count - 1
    node_area = np.zeros(node_count)
    node_moment = np.zeros(node_count)
    node_area[:leaf_count] = area
    node_moment[:leaf_count] = moment
    # Each neighbour's shared boundary: [length, concave-weighted length, step-weighted].
    neighbours: list[dict[int, list[float]]] = [{} for _ in range(node_count)]
    for key, *shared in zip(
        keys.tolist(), boundary.tolist(), concave.tolist(), stepped.tolist(), strict=True
    ):
        i, j = divmod(key, leaf_count)
        neighbours[i][j] = list(shared)
        neighbours[j][i] = list(shared)

    def mean(node: int) -> float:
        return node_moment[node] / node_area[node] if node_area[node] > 0 else 0.0

    def pair_cost(i: int, j: int, length: float, crease: float, step: float) -> float:
        return cost(node_area[i], node_area[j], mean(i), mean(j), length, crease, total_area, step)

    heap = [
        (pair_cost(i, j, *shared), i, j)
        for i in range(leaf_count)
        for j, shared in neighbours[i].items()
        if i < j
    ]
    heapq.heapify(heap)
    alive = np.zeros(node_count, dtype=bool)
    alive[:leaf_count] = True
    # Flat typed arrays, not lists of tuples: turning ~10^5 tuples into an ndarray is one
    # C call that holds the GIL (and the event loop of the service beside it) too long.
    merges = array("q")  # (low, high) child pair of each merge, flat
    costs = array("d")

    def merge(i: int, j: int, merge_cost: float) -> int:
        node = leaf_count + len(merges) // 2
        merges.extend((min(i, j), max(i, j)))
        costs.append(merge_cost)
        alive[i] = alive[j] = False
        alive[node] = True
        node_area[node] = node_area[i] + node_area[j]
        node_moment[node] = node_moment[i] + node_moment[j]
        joined: dict[int, list[float]] = {}
        for old in (i, j):
            for other, shared in neighbours[old].items():
                if other in (i, j):
                    continue
                entry = joined.setdefault(other, [0.0, 0.0, 0.0])
                for k, amount in enumerate(shared):
                    entry[k] += amount
                del neighbours[other][old]
            neighbours[old] = {}
        neighbours[node] = joined
        for other, shared in joined.items():
            neighbours[other][node] = shared
            heapq.heappush(heap, (pair_cost(other, node, *shared), other, node))
        return node

    # Mirror image of every node (-1: none); a merged node's children point to it.
    mirror = np.full(node_count, -1, dtype=np.int64)
    if mirror_leaf is not None:
        mirror[:leaf_count] = np.asarray(mirror_leaf, dtype=np.int64)
    absorbed = np.full(node_count, -1, dtype=np.int64)

    def current(node: int) -> int:
        while node >= 0 and not alive[node]:
            node = int(absorbed[node])
        return node

    while heap:
        merge_cost, i, j = heapq.heappop(heap)
        if not (alive[i] and alive[j]):
            continue
        node = merge(i, j, merge_cost)
        absorbed[i] = absorbed[j] = node
        if mirror_leaf is None:
            continue
        if mirror[i] < 0 or mirror[j] < 0:
            continue  # no mirror image known: the node has none either
        first, second = current(int(mirror[i])), current(int(mirror[j]))
        if first == second:  # the merge was its own mirror image
            mirror[node] = node if first == node else -1
        elif second in neighbours[first]:  # the mirror merge, at once; both at the dearer cost
            pair = max(merge_cost, pair_cost(first, second, *neighbours[first][second]))
            costs[-1] = pair
            twin = merge(min(first, second), max(first, second), pair)
            absorbed[first] = absorbed[second] = twin
            if node in (first, second):  # both merges together are one symmetric node
                mirror[twin] = twin
            else:
                mirror[node], mirror[twin] = twin, node

    # Separate shells: smallest first into the part of nearest mean ShDF.
    roots = np.flatnonzero(alive)
    pairs = _shell_merge_order(roots, node_area, node_moment, leaf_count + len(merges) // 2)
    shell_area, shell_moment = node_area.tolist(), node_moment.tolist()  # Python floats: fast
    for smallest, target in pairs.tolist():
        merges.extend((min(smallest, target), max(smallest, target)))
        area_s, area_t = shell_area[smallest], shell_area[target]
        mean_s = shell_moment[smallest] / area_s if area_s > 0 else 0.0
        mean_t = shell_moment[target] / area_t if area_t > 0 else 0.0
        costs.append(cost(area_s, area_t, mean_s, mean_t, 0.0, 0.0, total_area))

    return PartTree(
        leaves,
        np.frombuffer(merges, dtype=np.int64).reshape(-1, 2).copy(),
        np.frombuffer(costs, dtype=np.float64).copy(),
    )


@kernel
def _resolve_owners(owner: NDArray[Any]) -> NDArray[Any]:
    """Each node's highest merged ancestor, in place: merge nodes come after their
    children, so one pass from the top resolves every chain."""
    for node in range(len(owner) - 1, -1, -1):
        owner[node] = owner[owner[node]]
    return owner


#: "No group / no part" in the shell merge's linked lists.
_NONE = -1


@kernel(inline=True)
def _node_mean(node_area: NDArray[Any], node_moment: NDArray[Any], node: int) -> float:
    """A node's mean ShDF, as ``merge_tree``'s ``mean`` (0 for a part of no area)."""
    return node_moment[node] / node_area[node] if node_area[node] > 0 else 0.0


@kernel(inline=True)
def _before(area: NDArray[Any], ids: NDArray[Any], i: int, j: int) -> bool:
    """Whether heap entry ``i`` comes before ``j``: less area, then lower id."""
    before: bool = area[i] < area[j] or (area[i] == area[j] and ids[i] < ids[j])
    return before


@kernel(inline=True)
def _heap_push(area: NDArray[Any], ids: NDArray[Any], size: int, value: float, node: int) -> int:
    """Push (value, node) onto the heap of ``size`` entries; return the new size."""
    area[size], ids[size] = value, node
    child = size
    while child > 0:
        parent = (child - 1) // 2
        if not _before(area, ids, child, parent):
            break
        area[child], area[parent] = area[parent], area[child]
        ids[child], ids[parent] = ids[parent], ids[child]
        child = parent
    return size + 1


@kernel(inline=True)
def _heap_pop(area: NDArray[Any], ids: NDArray[Any], size: int) -> int:
    """Remove the first entry of the heap of ``size`` entries; return its node."""
    node: int = ids[0]
    size -= 1
    area[0], ids[0] = area[size], ids[size]
    parent = 0
    while True:
        child = 2 * parent + 1
        if child >= size:
            break
        if child + 1 < size and _before(area, ids, child + 1, child):
            child += 1
        if not _before(area, ids, child, parent):
            break
        area[child], area[parent] = area[parent], area[child]
        ids[child], ids[parent] = ids[parent], ids[child]
        parent = child
    return node


@kernel(inline=True)
def _take_out(
    node: int,
    node_group: NDArray[np.int64],
    member_prev: NDArray[np.int64],
    member_next: NDArray[np.int64],
    head: NDArray[np.int64],
    tail: NDArray[np.int64],
    group_prev: NDArray[np.int64],
    group_next: NDArray[np.int64],
) -> tuple[int, int]:
    """Remove ``node`` from its group; a group left empty leaves the list of groups.

    Returns the (previous, next) groups of the node's group.
    """
    group = node_group[node]
    before, after = member_prev[node], member_next[node]
    if before == _NONE:
        head[group] = after
    else:
        member_next[before] = after
    if after == _NONE:
        tail[group] = before
    else:
        member_prev[after] = before
    left, right = group_prev[group], group_next[group]
    if head[group] == _NONE:
        if left != _NONE:
            group_next[left] = right
        if right != _NONE:
            group_prev[right] = left
    return left, right


@kernel
def _shell_merge_order(
    roots: NDArray[Any], node_area: NDArray[Any], node_moment: NDArray[Any], first_node: int
) -> NDArray[Any]:
    """(len(roots) - 1, 2) the (smallest, target) pairs that merge the parts ``roots``
    (no shared edge left) into one, in order; fills ``node_area`` and ``node_moment`` of
    the new nodes ``first_node, first_node + 1, ...``.

    Each step merges the smallest part (least area, then lowest id) into the part of
    nearest mean (least ``|mean - mean_smallest|``, then lowest id). A heap over (area,
    id) and a list of the distinct means in order, each with its parts in id order, make
    a step about constant time where a rescan of every part made the loop quadratic in
    the number of shells: a merged part's mean lies between its parts' means, which are
    neighbours in that list, so its place is a step or two from theirs.
    """
    count = len(roots)
    nodes = len(node_area)
    pairs = np.empty((max(count - 1, 0), 2), dtype=np.int64)
    if count < 2:
        return pairs
    heap_area = np.empty(count, dtype=np.float64)
    heap_id = np.empty(count, dtype=np.int64)
    merged = np.zeros(nodes, dtype=np.bool_)
    value = np.empty(2 * count, dtype=np.float64)
    group_prev = np.full(2 * count, _NONE, dtype=np.int64)
    group_next = np.full(2 * count, _NONE, dtype=np.int64)
    head = np.full(2 * count, _NONE, dtype=np.int64)
    tail = np.full(2 * count, _NONE, dtype=np.int64)
    node_group = np.full(nodes, _NONE, dtype=np.int64)
    member_prev = np.full(nodes, _NONE, dtype=np.int64)
    member_next = np.full(nodes, _NONE, dtype=np.int64)

    means = np.empty(count, dtype=np.float64)
    for k in range(count):
        means[k] = _node_mean(node_area, node_moment, roots[k])
    groups = 0
    for k in np.argsort(means, kind="mergesort"):  # stable: ids increase within a mean
        node = roots[k]
        if groups == 0 or value[groups - 1] != means[k]:
            value[groups] = means[k]
            if groups:
                group_prev[groups] = groups - 1
                group_next[groups - 1] = groups
            head[groups] = node
            groups += 1
        else:
            member_prev[node] = tail[groups - 1]
            member_next[tail[groups - 1]] = node
        tail[groups - 1] = node
        node_group[node] = groups - 1
    size = 0
    for k in range(count):
        size = _heap_push(heap_area, heap_id, size, node_area[roots[k]], roots[k])

    for step in range(count - 1):
        smallest = _heap_pop(heap_area, heap_id, size)
        size -= 1
        while merged[smallest]:
            smallest = _heap_pop(heap_area, heap_id, size)
            size -= 1
        centre = _node_mean(node_area, node_moment, smallest)
        left, right = _take_out(
            smallest, node_group, member_prev, member_next, head, tail, group_prev, group_next
        )
        if head[node_group[smallest]] != _NONE:  # another part of the same mean: gap 0
            target = head[node_group[smallest]]
        else:  # the gap grows away from the centre: the ties are runs next to it
            best = np.inf
            if left != _NONE:
                best = min(best, abs(value[left] - centre))
            if right != _NONE:
                best = min(best, abs(value[right] - centre))
            target = nodes
            while right != _NONE and abs(value[right] - centre) == best:
                target = min(target, head[right])
                right = group_next[right]
            while left != _NONE and abs(value[left] - centre) == best:
                target = min(target, head[left])
                left = group_prev[left]
        left, right = _take_out(
            target, node_group, member_prev, member_next, head, tail, group_prev, group_next
        )
        pairs[step, 0], pairs[step, 1] = smallest, target
        merged[smallest] = merged[target] = True

        node = first_node + step
        node_area[node] = node_area[smallest] + node_area[target]
        node_moment[node] = node_moment[smallest] + node_moment[target]
        mean = _node_mean(node_area, node_moment, node)
        # Its group: the last group of mean <= its mean, found from where the target was
        # (``first``: the first group, when every group's mean is above it).
        group = node_group[target] if head[node_group[target]] != _NONE else left
        group = right if group == _NONE else group
        first = _NONE
        while group != _NONE and value[group] > mean:
            first = group
            group = group_prev[group]
        if group != _NONE:
            while group_next[group] != _NONE and value[group_next[group]] <= mean:
                group = group_next[group]
        if group != _NONE and value[group] == mean:
            member_prev[node] = tail[group]
            member_next[tail[group]] = node
            tail[group] = node
        else:  # a new group after ``group`` (or before ``first``)
            new = groups
            groups += 1
            value[new] = mean
            head[new] = tail[new] = node
            following = group_next[group] if group != _NONE else first
            if following != _NONE:
                group_prev[following] = new
                group_next[new] = following
            if group != _NONE:
                group_next[group] = new
                group_prev[new] = group
            group = new
        node_group[node] = group
        size = _heap_push(heap_area, heap_id, size, node_area[node], node)
    return pairs


#: Automatic part count: merges costing more than this are not made. Tuned on the same 57
#: models for the cut discrepancy with the Rand index bounded, the same with and without
#: boundaries on creases. Missing a cut the humans make costs more than one cut too many,
#: so it errs towards more parts than the humans cut. Version 26 (with ``STEP_EXPONENT``
#: 0.5, costs lower where parts meet on a gradient), tuning models 1-RI / CD (mean parts):
#: 0.014 0.137 / 0.222 (7.5), 0.017 0.139 / 0.222 (7.2), 0.02 0.140 / 0.225 (7.0); version
#: 25 at 0.02: 0.138 / 0.222 (7.3; the humans' most frequent 7.1). 0.017 keeps the count
#: where it was; 0.014 and 0.017 tied on the tuning production variants.
AUTO_COST_THRESHOLD = 0.017


def automatic_part_count(tree: PartTree, threshold: float = AUTO_COST_THRESHOLD) -> int:
    """The part count where merging stops being cheap: 1 + merges above ``threshold``.

    Heights (running maxima) are compared, so the count is a cut of the tree.
    """
    if tree.leaf_count == 0:
        return 0
    return 1 + int(np.sum(tree.heights > threshold))
