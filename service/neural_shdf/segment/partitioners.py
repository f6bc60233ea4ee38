"""The partitioners: strategies that turn a prepared segmentation into parts.

Both start from the same ``Partitioning`` (the face graph, the ``SegmentBasis`` with
the mixture's data costs and the edge weights at smoothing 1, the parameters and the
smoothing lambda at the mesh's resolution) and return (labels, part tree or None):

* ``GraphCutPartitioner`` (``graphcut``): alpha-expansion over the clusters; the
  connected runs of one cluster, optionally refined, with tiny parts merged and
  boundaries moved onto concave creases, are the leaves of a merge tree
  (``segment.hierarchy``) cut at ``parts`` parts or where the merge cost jumps;
* ``MetisPartitioner`` (``metis``): a METIS k-way partition into exactly ``parts``
  parts (by default as many as the graph cut's automatic count).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from neural_shdf.geometry import FaceGraph
from neural_shdf.segment.basis import SegmentBasis
from neural_shdf.segment.creases import CreaseGraph, snap_boundaries_to_creases
from neural_shdf.segment.graphcut import quantized
from neural_shdf.segment.hierarchy import PartTree, automatic_part_count, merge_tree
from neural_shdf.segment.metis import metis_edge_weights, metis_partition
from neural_shdf.segment.params import SegmentParams
from neural_shdf.segment.parts import canonical_labels, connected_parts, merge_small_parts
from neural_shdf.segment.refine import refine_parts, smooth_boundaries
from neural_shdf.segment.symmetry import mirror_leaves, mirror_parts


@dataclass
class Partitioning:
    """What a partitioner works from; ``lap(step)`` records the time since the last lap."""

    graph: FaceGraph
    basis: SegmentBasis
    params: SegmentParams
    #: The graph cut's smoothness lambda at this mesh's resolution
    #: (``SegmentParams.smoothing_for``): edge weights are ``smoothing * unit_weights``.
    smoothing: float
    #: The mesh's crease graph where ``params.crease_boundaries`` (else None).
    creases: CreaseGraph | None
    lap: Callable[[str], None]
    #: Where the fans over the mesh's holes join rim faces (``stitching.cap_spokes``):
    #: boundary across the holes for the part tree; None for a closed mesh.
    spokes: tuple[NDArray[np.int64], NDArray[np.float64]] | None = None

    @cached_property
    def edge_weights(self) -> NDArray[np.float64]:
        """The graph cut's edge weights: ``smoothing`` times the weights at smoothing 1."""
        return quantized(self.basis.unit_weights * self.smoothing)


#: A graph cut that leaves at most this many parts (leaves) although the mixture has more
#: components has collapsed (see ``graph_cut_parts``).
COLLAPSED_LEAVES = 2
#: The refit after a collapse has collapsed too where it leaves at most ``COLLAPSED_LEAVES``
#: parts or one holding at least this share of the surface (the rest in crumbs).
COLLAPSED_SHARE = 0.9
#: The narrowest mixture component of the refit after a collapse: about five histogram
#: bins (``mixture.HISTOGRAM_BINS``), so that no component sits on a single bin.
COLLAPSE_MIN_DEVIATION = 0.02
#: Where that refit's cut still collapses and a component is broader than this, a second
#: refit has none broader: the broad component (deviation 0.14-0.2 against 0.02-0.06 for
#: the others) is the one that takes every face (see ``graph_cut_parts``).
COLLAPSE_MAX_DEVIATION = 0.08


class Partitioner(Protocol):
    def partition(self, work: Partitioning) -> tuple[NDArray[np.int64], PartTree | None]:
        """Part label per face (0..P-1 by lowest face) and the part tree, if any."""
        ...


def graph_cut_parts(work: Partitioning) -> NDArray[np.int64]:
    """The graph cut's parts (the part tree's leaves): alpha-expansion at ``smoothing``,
    connected runs of one cluster, optional refinement, tiny parts merged, boundaries
    moved onto concave creases (``crease_boundaries``).

    A collapse (at most ``COLLAPSED_LEAVES`` parts from a mixture of more components) is
    solved again with the mixture refitted with no component narrower than
    ``COLLAPSE_MIN_DEVIATION``; where that cut has collapsed too (``collapsed``: also one
    part holding ``COLLAPSED_SHARE`` of the surface) and the refit has a component broader
    than ``COLLAPSE_MAX_DEVIATION``, once more with none broader. The solution with the
    most parts is kept. Such a collapse comes from one broad component (deviation 0.14-0.27
    against 0.001-0.06) that holds every value a little: the data term prefers it nearly
    everywhere and the smoothness gives it every face. Several components on one
    histogram bin (many faces of one ShDF value, e.g. a plate of even thickness) lead to
    it (psb 141 with 10% of its faces removed from below, or its shells moved by 0.5%: one
    part, published three), and so does a ShDF that varies gradually over a smooth shape
    (psb 244, a bird, with its lowest 6% of faces removed: one part, published four;
    docs/messy-meshes.md).

    A high smoothing merges parts by design, so away from the default smoothing a cut into
    two parts is solved again only where the refit won at the default smoothing (decided
    once per basis and options: ``refit_wins_at_default``); one part is solved again at any
    smoothing (a fit degenerate at that smoothing only: psb 141 at 0.3, one part, five
    with the refit). Two parts from a fit that is not degenerate cost one solve.
    """
    parts = cut_parts(work)
    leaves = part_count(parts)
    if leaves > COLLAPSED_LEAVES or work.basis.mixture.size <= COLLAPSED_LEAVES:
        return parts
    default = default_smoothing(work)
    if leaves > 1 and work.smoothing != default and not refit_wins_at_default(work, default):
        return parts
    best = parts
    widened = work.basis.widened(COLLAPSE_MIN_DEVIATION)
    again = cut_parts(replace(work, basis=widened))
    if part_count(again) > leaves:
        best = again
    areas = work.basis.geometry.areas
    if collapsed(again, areas) and widened.mixture.deviations.max() > COLLAPSE_MAX_DEVIATION:
        narrowed = work.basis.widened(COLLAPSE_MIN_DEVIATION, COLLAPSE_MAX_DEVIATION)
        again = cut_parts(replace(work, basis=narrowed))
        if part_count(again) > part_count(best):
            best = again
    if work.smoothing == default:
        work.basis.refit_wins[refit_key(work.params)] = best is not parts
    return best


def collapsed(parts: NDArray[np.int64], areas: NDArray[np.float64]) -> bool:
    """Whether a refit's ``parts`` collapsed too: at most ``COLLAPSED_LEAVES`` of them, or
    one holding ``COLLAPSED_SHARE`` of the surface."""
    if part_count(parts) <= COLLAPSED_LEAVES:
        return True
    total = float(areas.sum())
    if not total > 0:
        return False
    largest = float(np.bincount(parts - parts.min(), weights=areas).max())
    return largest >= COLLAPSED_SHARE * total


def default_smoothing(work: Partitioning) -> float:
    """The smoothing lambda of the default ``SegmentParams.smoothing`` on this graph."""
    return replace(work.params, smoothing=None).smoothing_for(work.graph.face_count)


def refit_key(params: SegmentParams) -> SegmentParams:
    """``params`` less what ``graph_cut_parts`` does not read (the smoothing and what
    comes after the leaves): the options a refit decision at the default smoothing holds for."""
    return replace(
        params, partitioner="graphcut", smoothing=None, parts=None, boundary_smoothing=False
    )


def refit_wins_at_default(work: Partitioning, default: float) -> bool:
    """Whether at the ``default`` smoothing the cut collapses and the refitted mixture's
    cut has more parts (solved once per basis and options, then remembered)."""
    key = refit_key(work.params)
    wins = work.basis.refit_wins.get(key)
    if wins is None:
        graph_cut_parts(replace(work, smoothing=default))  # records a collapse's outcome
        wins = work.basis.refit_wins.setdefault(key, False)
    return wins


def part_count(parts: NDArray[np.int64]) -> int:
    """How many distinct labels ``parts`` has (one pass: ``np.unique`` sorts, 0.1 s at 1M)."""
    if len(parts) == 0:
        return 0
    return int(np.count_nonzero(np.bincount(parts - parts.min())))


def cut_parts(work: Partitioning) -> NDArray[np.int64]:
    """``graph_cut_parts`` without the second solve after a collapse."""
    graph, params, basis, lap = work.graph, work.params, work.basis, work.lap
    geometry = basis.geometry
    clusters = basis.cut(graph).solve(work.smoothing)
    parts = connected_parts(clusters, graph.pairs, graph.face_count)
    lap("graphcut")
    if params.refine:
        parts = refine_parts(parts, basis.shdf, graph, work.edge_weights, geometry, params)
        lap("refine")
    parts = merge_small_parts(
        parts, graph, geometry.areas, geometry.centroids, params.min_part_fraction
    )
    lap("merge_small")
    if work.creases is not None:
        parts = snap_boundaries_to_creases(
            parts,
            graph,
            geometry.areas,
            geometry.centroids,
            params.min_part_fraction,
            creases=work.creases,
        )
        lap("crease_boundaries")
    return parts


class GraphCutPartitioner:
    """``graphcut``: the graph cut's parts as leaves of a merge tree, cut at the asked count."""

    def partition(self, work: Partitioning) -> tuple[NDArray[np.int64], PartTree | None]:
        graph, params, geometry = work.graph, work.params, work.basis.geometry
        parts = graph_cut_parts(work)
        if params.boundary_smoothing:
            smoothed = smooth_boundaries(parts, graph, work.edge_weights, geometry.face_weight)
            parts = merge_small_parts(
                connected_parts(smoothed, graph.pairs, graph.face_count),
                graph,
                geometry.areas,
                geometry.centroids,
                params.min_part_fraction,
            )
            work.lap("boundary_smoothing")
        reflection = work.basis.reflection
        mirror_leaf = None
        if reflection is not None:
            # The symmetry option found a plane: leaves cut as mirror images, and mirror
            # merges made together so that the tree's cuts are mirror images too.
            mirrored = mirror_parts(parts, reflection, geometry.centroids, geometry.areas)
            parts = merge_small_parts(
                connected_parts(mirrored, graph.pairs, graph.face_count),
                graph,
                geometry.areas,
                geometry.centroids,
                params.min_part_fraction,
            )
            mirror_leaf = mirror_leaves(parts, reflection.mirror, geometry.areas)
            work.lap("symmetry")
        leaves = canonical_labels(parts)
        tree = merge_tree(
            leaves,
            graph,
            geometry,
            work.basis.values,
            mirror_leaf=mirror_leaf,
            spokes=work.spokes,
        )
        count = automatic_part_count(tree) if params.parts is None else params.parts
        labels = tree.labels(count)
        work.lap("hierarchy")
        return labels, tree


class MetisPartitioner:
    """``metis``: exactly ``parts`` parts (None: the graph cut's automatic count)."""

    def partition(self, work: Partitioning) -> tuple[NDArray[np.int64], PartTree | None]:
        graph, params, basis = work.graph, work.params, work.basis
        geometry = basis.geometry
        if params.parts is not None:
            count = params.parts
        else:
            leaves = canonical_labels(graph_cut_parts(work))
            tree = merge_tree(
                leaves,
                graph,
                geometry,
                basis.values,
                spokes=work.spokes,
            )
            count = automatic_part_count(tree)
        weights = metis_edge_weights(work.edge_weights, basis.posteriors, graph.pairs)
        parts = metis_partition(
            graph,
            weights,
            count,
            geometry.areas,
            geometry.centroids,
            params.seed,
            params.min_part_fraction,
        )
        work.lap("metis")
        if params.boundary_smoothing:
            smoothed = smooth_boundaries(parts, graph, work.edge_weights, geometry.face_weight)
            # Keep METIS's exact count: drop the smoothing if it emptied a part.
            if len(np.unique(smoothed)) == int(parts.max()) + 1:
                parts = smoothed
            work.lap("boundary_smoothing")
        return canonical_labels(parts), None


#: The partitioner of each ``SegmentParams.partitioner`` value.
PARTITIONERS: dict[str, Partitioner] = {
    "graphcut": GraphCutPartitioner(),
    "metis": MetisPartitioner(),
}
