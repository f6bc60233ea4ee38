"""Segmentation from a per-face ShDF in [0, 1]: mixture, hard partition, clean-up.

Steps (Shapira et al. 2008 as implemented by CGAL's ``segmentation_from_sdf_values``):

1. log-normalise the ShDF and fit a 1-D Gaussian mixture (k clusters);
2. ``graphcut``: alpha-expansion with data ``-log P(cluster | face)`` and
   dihedral edge weights; connected runs of one cluster become parts.
   ``metis``: METIS k-way partition into exactly ``parts`` parts;
3. optional recursive refinement; tiny parts merged (graph cut only); the graph
   cut's boundaries moved onto nearby concave creases (``creases``, on by default);
   optional boundary smoothing; labels renumbered by lowest face index;
4. graph cut only: the parts are the leaves of a merge tree (``hierarchy``), cut
   at ``parts`` parts or, by default, where the merge cost jumps.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import ParameterError
from neural_shdf.geometry import FaceGraph, face_centroids, face_normals
from neural_shdf.orientation import MeshDiagnostics
from neural_shdf.segment.creases import CreaseGraph, crease_graph, snap_boundaries_to_creases
from neural_shdf.segment.graphcut import (
    CutHierarchy,
    cut_hierarchy,
    data_costs,
    dihedral_weights,
    multilevel_alpha_expansion,
)
from neural_shdf.segment.hierarchy import PartTree, automatic_part_count, merge_tree
from neural_shdf.segment.metis import metis_edge_weights, metis_partition
from neural_shdf.segment.mixture import Mixture, fit_best_mixture, fit_mixture
from neural_shdf.segment.params import (
    AUTO_CLUSTERS,
    DEFAULT_CLUSTERS,
    DEFAULT_SMOOTHING,
    SegmentParams,
)
from neural_shdf.segment.parts import canonical_labels, connected_parts, merge_small_parts
from neural_shdf.shdf.postprocess import log_normalize

#: ShDF values may stray this far outside [0, 1] (rounding) before they are refused.
SHDF_TOLERANCE = 1e-6


@dataclass
class SegmentResult:
    """Labels plus what was chosen and how long each step took (seconds)."""

    labels: NDArray[np.int64]
    clusters: int
    smoothing: float
    timings: dict[str, float] = field(default_factory=dict)
    #: The graph cut's merge tree (None for ``metis``): ``labels`` is one of its cuts.
    tree: PartTree | None = None
    #: What the orientation pass found in the mesh (``pipeline.segment_mesh_with_details``).
    diagnostics: MeshDiagnostics | None = None

    @property
    def part_count(self) -> int:
        return int(self.labels.max()) + 1 if len(self.labels) else 0


@dataclass(frozen=True)
class FaceData:
    """Per-face geometry the partitioners need, computed once."""

    areas: NDArray[np.float64]
    centroids: NDArray[np.float64]
    face_weight: NDArray[np.float64]

    @classmethod
    def of(cls, vertices: NDArray, faces: NDArray, areas: NDArray | None = None) -> FaceData:
        """The data of ``faces``; ``areas`` where the caller has them (e.g. a mesh's cache)."""
        areas = face_normals(vertices, faces)[1] if areas is None else np.asarray(areas, float)
        mean = float(areas.mean()) if len(areas) else 0.0
        weight = areas / mean if mean > 0 else np.ones(len(areas))
        return cls(areas, face_centroids(vertices, faces), weight)

    def subset(self, faces: NDArray) -> FaceData:
        """The same data for some faces (weights stay relative to the whole mesh)."""
        return FaceData(self.areas[faces], self.centroids[faces], self.face_weight[faces])


@dataclass
class SegmentBasis:
    """What a segmentation computes before the smoothing, part count, refinement and
    boundary options enter: face data, the mixture and its posteriors, data costs, edge
    weights at smoothing 1 and the graph cut's coarse graphs (built on first use).

    It depends on the mesh, its ShDF, ``clusters`` and ``seed`` only, so a caller that
    keeps it (the service, per mesh) re-segments with new values of the other parameters
    without refitting the mixture or coarsening the graph again; the labels are the same
    as without it.
    """

    clusters: int | None
    seed: int
    geometry: FaceData
    shdf: NDArray[np.float64]
    values: NDArray[np.float64]
    mixture: Mixture
    posteriors: NDArray[np.float64]
    data: NDArray[np.float64]
    unit_weights: NDArray[np.float64]
    seconds: float = 0.0
    _cut: CutHierarchy | None = field(default=None, repr=False)
    _creases: CreaseGraph | None = field(default=None, repr=False)

    def cut(self, graph: FaceGraph) -> CutHierarchy:
        """The graph cut's coarse graphs over ``graph`` (built once)."""
        if self._cut is None:
            self._cut = cut_hierarchy(
                self.data,
                graph.pairs,
                self.unit_weights,
                self.geometry.centroids,
                self.geometry.areas,
            )
        return self._cut

    def creases(self, graph: FaceGraph) -> CreaseGraph:
        """The crease refinement's graph and edge costs over ``graph`` (built once)."""
        if self._creases is None:
            self._creases = crease_graph(graph, self.geometry.areas, self.geometry.centroids)
        return self._creases

    def matches(self, params: SegmentParams, shdf: NDArray) -> bool:
        """Whether this basis is the one ``params`` on a mesh with this ShDF needs (one pass
        over the ShDF: a basis never stands in for another field)."""
        shdf = np.asarray(shdf, dtype=np.float64).reshape(-1)
        return (
            self.clusters == params.clusters
            and self.seed == params.seed
            and shdf.shape == self.shdf.shape
            and np.array_equal(np.clip(shdf, 0.0, 1.0), self.shdf)
        )

    @property
    def nbytes(self) -> int:
        """Memory held (arrays only), for callers that bound a cache of bases."""
        arrays = (self.shdf, self.values, self.posteriors, self.data, self.unit_weights)
        geometry = (self.geometry.areas, self.geometry.centroids, self.geometry.face_weight)
        size = sum(a.nbytes for a in arrays + geometry)
        if self._creases is not None:
            size += self._creases.nbytes
        if self._cut is not None:
            finest = self._cut.levels[0]  # shares the data, weights and the graph's pairs
            size += self._cut.nbytes - finest.data.nbytes - finest.unit_weights.nbytes
            size -= finest.pairs.nbytes
        return size


def prepare_segment(
    vertices: NDArray,
    faces: NDArray,
    shdf: NDArray,
    params: SegmentParams,
    graph: FaceGraph,
    *,
    areas: NDArray | None = None,
    creases: CreaseGraph | None = None,
) -> SegmentBasis:
    """The ``SegmentBasis`` of a mesh, its ShDF and ``params.clusters``/``params.seed``.

    ``creases``: the mesh's ``crease_graph`` where the caller keeps it per mesh (it does
    not depend on the ShDF or the mixture); else built on first use.
    """
    start = time.perf_counter()
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    shdf = validate(faces, shdf, params, graph)
    geometry = FaceData.of(np.asarray(vertices, dtype=np.float64), faces, areas)
    values = log_normalize(shdf)
    if params.clusters == AUTO_CLUSTERS:
        mixture = fit_best_mixture(values, params.seed)
    else:
        clusters = DEFAULT_CLUSTERS if params.clusters is None else params.clusters
        mixture = fit_mixture(values, clusters, params.seed)
    posteriors = mixture.posteriors(values)
    return SegmentBasis(
        clusters=params.clusters,
        seed=params.seed,
        geometry=geometry,
        shdf=shdf,
        values=values,
        mixture=mixture,
        posteriors=posteriors,
        data=data_costs(posteriors, geometry.face_weight),
        unit_weights=dihedral_weights(graph, 1.0),
        seconds=time.perf_counter() - start,
        _creases=creases,
    )


def segment(
    vertices: NDArray,
    faces: NDArray,
    shdf: NDArray,
    params: SegmentParams,
    graph: FaceGraph,
    *,
    areas: NDArray | None = None,
) -> NDArray[np.int64]:
    """Part label per face, 0..P-1 in order of each part's lowest face; deterministic.

    ``areas``: the faces' areas where the caller has them (else computed).
    """
    return segment_with_details(vertices, faces, shdf, params, graph, areas=areas).labels


def segment_with_details(
    vertices: NDArray,
    faces: NDArray,
    shdf: NDArray,
    params: SegmentParams,
    graph: FaceGraph,
    *,
    areas: NDArray | None = None,
    basis: SegmentBasis | None = None,
) -> SegmentResult:
    """``segment`` plus the chosen mixture size, smoothing and per-step timings.

    ``basis``: a ``prepare_segment`` result for the same mesh, ShDF, clusters and seed
    (kept by the caller to re-segment cheaply); same labels as without it.
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    smoothing = DEFAULT_SMOOTHING if params.smoothing is None else float(params.smoothing)
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[name] = timings.get(name, 0.0) + now - clock
        clock = now

    if basis is not None and not basis.matches(params, shdf):
        raise ValueError("the segment basis was prepared for another ShDF, clusters or seed")
    validate(faces, shdf if basis is None else basis.shdf, params, graph)
    if len(faces) == 0:
        return SegmentResult(np.zeros(0, dtype=np.int64), 0, smoothing, timings)
    if basis is None:
        basis = prepare_segment(vertices, faces, shdf, params, graph, areas=areas)
        lap("prepare")
    geometry, shdf, values, posteriors = basis.geometry, basis.shdf, basis.values, basis.posteriors
    scale = smoothing * (
        1.0 if params.reference_faces is None else np.sqrt(len(faces) / params.reference_faces)
    )
    edge_weights = basis.unit_weights * scale

    need_graphcut = params.partitioner == "graphcut" or params.parts is None
    parts = None
    if need_graphcut:
        clusters = basis.cut(graph).solve(scale)
        parts = connected_parts(clusters, graph.pairs, graph.face_count)
        lap("graphcut")
        if params.refine:
            from neural_shdf.segment.refine import refine_parts

            parts = refine_parts(parts, shdf, graph, edge_weights, geometry, params)
            lap("refine")
        parts = merge_small_parts(
            parts, graph, geometry.areas, geometry.centroids, params.min_part_fraction
        )
        lap("merge_small")
        if params.crease_boundaries:  # the tree's leaves (metis: its automatic count)
            parts = snap_boundaries_to_creases(
                parts,
                graph,
                geometry.areas,
                geometry.centroids,
                params.min_part_fraction,
                creases=basis.creases(graph),
            )
            lap("crease_boundaries")

    if params.partitioner == "metis":
        if params.parts is not None:
            count = params.parts
        else:  # the graph cut's automatic count
            tree = merge_tree(canonical_labels(parts), graph, geometry.areas, values)
            count = automatic_part_count(tree)
        weights = metis_edge_weights(edge_weights, posteriors, graph.pairs)
        parts = metis_partition(
            graph,
            weights,
            count,
            geometry.areas,
            geometry.centroids,
            params.seed,
            params.min_part_fraction,
        )
        lap("metis")

    if params.boundary_smoothing:
        from neural_shdf.segment.refine import smooth_boundaries

        smoothed = smooth_boundaries(parts, graph, edge_weights, geometry.face_weight)
        if params.partitioner == "metis":
            # Keep METIS's exact count: drop the smoothing if it emptied a part.
            if len(np.unique(smoothed)) == int(parts.max()) + 1:
                parts = smoothed
        else:
            parts = merge_small_parts(
                connected_parts(smoothed, graph.pairs, graph.face_count),
                graph,
                geometry.areas,
                geometry.centroids,
                params.min_part_fraction,
            )
        lap("boundary_smoothing")
    if params.partitioner == "metis":
        return SegmentResult(canonical_labels(parts), basis.mixture.size, smoothing, timings)

    # Graph cut: its parts are the leaves of the merge tree; cut it at the asked count.
    tree = merge_tree(canonical_labels(parts), graph, geometry.areas, values)
    count = automatic_part_count(tree) if params.parts is None else params.parts
    labels = tree.labels(count)
    lap("hierarchy")
    return SegmentResult(labels, basis.mixture.size, smoothing, timings, tree)


def cut_into_parts(
    posteriors: NDArray, graph: FaceGraph, edge_weights: NDArray, geometry: FaceData
) -> NDArray[np.int64]:
    """Alpha-expansion over clusters, then connected runs of one cluster as parts."""
    data = data_costs(posteriors, geometry.face_weight)
    clusters = multilevel_alpha_expansion(
        data, graph.pairs, edge_weights, geometry.centroids, geometry.areas
    )
    return connected_parts(clusters, graph.pairs, graph.face_count)


def validate(faces: NDArray, shdf: NDArray, params: SegmentParams, graph: FaceGraph) -> NDArray:
    """Check what depends on the mesh (``SegmentParams`` checks itself when it is built);
    return the ShDF as float64 clipped to [0, 1]. Raises ParameterError."""
    face_count = len(faces)
    if params.parts is not None and params.parts > face_count:
        raise ParameterError(
            f"parts={params.parts} is more than the mesh's {face_count} faces; "
            f"ask for at most {face_count} parts"
        )

    values = np.asarray(shdf, dtype=np.float64)
    if values.shape != (face_count,):
        raise ParameterError(
            f"the ShDF has shape {values.shape} but the mesh has {face_count} faces; "
            "give one value per face"
        )
    if graph.face_count != face_count:
        raise ParameterError(
            f"the face graph has {graph.face_count} faces but the mesh has {face_count}"
        )
    if not np.all(np.isfinite(values)):
        raise ParameterError(
            f"the ShDF has {int(np.sum(~np.isfinite(values)))} non-finite values (NaN or inf)"
        )
    if face_count and (values.min() < -SHDF_TOLERANCE or values.max() > 1 + SHDF_TOLERANCE):
        raise ParameterError(
            f"the ShDF must be normalised to [0, 1], got values in "
            f"[{values.min():.6g}, {values.max():.6g}]"
        )
    return np.clip(values, 0.0, 1.0)
