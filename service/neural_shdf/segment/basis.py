"""What a segmentation computes before the smoothing, part count, refinement and boundary
options enter, kept by a caller to re-segment one mesh cheaply."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.constants import FINE_TESSELLATION_FACES
from neural_shdf.geometry import FaceGraph, equivalent_face_count
from neural_shdf.segment.graphcut import CutHierarchy, cut_hierarchy, data_costs
from neural_shdf.segment.mixture import Mixture, fit_mixture, value_weights
from neural_shdf.segment.params import SegmentParams
from neural_shdf.segment.parts import FaceData
from neural_shdf.segment.symmetry import Reflection


@dataclass
class SegmentBasis:
    """What a segmentation computes before the smoothing, part count, refinement and
    boundary options enter: face data, the mixture and its posteriors, data costs, edge
    weights at smoothing 1 and the graph cut's coarse graphs (built on first use).

    It depends on the mesh, its ShDF, ``clusters``, ``seed`` and ``symmetry`` only (with
    ``symmetry``, ``reflection`` is the plane found, None when none was), so a caller that
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
    symmetry: bool = False
    reflection: Reflection | None = None
    #: ``principal_frame`` of the centroids weighted by the areas (the mesh's, shared
    #: with its crease graph), for the coarse graphs' grid.
    frame: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
    #: The file's triangle each of the basis's triangles is (``TriangleMesh.distinct.kept``:
    #: the segmentation lists them in an order of their positions), None where it is the
    #: file's own order: ``matches`` reads the file's ShDF through it.
    triangles: NDArray[np.int64] | None = None
    _cut: CutHierarchy | None = field(default=None, repr=False)
    #: ``widened``'s bases by the (minimum, maximum) deviation they were fitted with.
    _widened: dict[tuple[float, float], SegmentBasis] = field(default_factory=dict, repr=False)
    #: Per options (``partitioners.refit_key``): whether at the default smoothing the cut
    #: collapsed and a refitted mixture's cut had more parts.
    refit_wins: dict[SegmentParams, bool] = field(default_factory=dict, repr=False)

    @cached_property
    def equivalent_faces(self) -> float:
        """``geometry.equivalent_face_count`` of the faces' areas (a sort: worked out once
        per basis, not per re-segmentation)."""
        return equivalent_face_count(self.geometry.areas)

    def cut(self, graph: FaceGraph) -> CutHierarchy:
        """The graph cut's coarse graphs over ``graph`` (built once)."""
        if self._cut is None:
            self._cut = cut_hierarchy(
                self.data,
                graph.pairs,
                self.unit_weights,
                self.geometry.centroids,
                self.geometry.areas,
                # Fine tessellations judge creases per unit length at every level.
                lengths=graph.edge_length if graph.face_count > FINE_TESSELLATION_FACES else None,
                frame=self.frame,
            )
        return self._cut

    def widened(self, min_deviation: float, max_deviation: float = np.inf) -> SegmentBasis:
        """This basis with its mixture refitted with no component narrower than
        ``min_deviation`` nor broader than ``max_deviation`` (built once per pair, coarse
        graphs included: a caller that keeps the basis pays each refit once, not per
        smoothing value)."""
        key = (min_deviation, max_deviation)
        if key not in self._widened:
            mixture = fit_mixture(
                self.values,
                self.mixture.size,
                self.seed,
                min_deviation=min_deviation,
                weights=value_weights(self.geometry.areas, lambda: self.equivalent_faces),
                max_deviation=max_deviation,
            )
            self._widened[key] = self.with_mixture(mixture)
        return self._widened[key]

    def with_mixture(self, mixture: Mixture) -> SegmentBasis:
        """This basis with another mixture: its posteriors and data costs (coarse graphs
        built anew on use)."""
        posteriors = mixture.posteriors(self.values)
        return replace(
            self,
            mixture=mixture,
            posteriors=posteriors,
            data=data_costs(posteriors, self.geometry.face_weight),
            _cut=None,
            _widened={},
            refit_wins={},
        )

    def matches(self, params: SegmentParams, shdf: NDArray[Any]) -> bool:
        """Whether this basis is the one ``params`` on a mesh with this ShDF needs (one pass
        over the ShDF, none when it is the basis's own: a basis never stands in for
        another field). ``shdf``: per triangle of the file (``TriangleMesh.faces``), or
        the basis's own ``shdf``."""
        if self.clusters != params.clusters or self.seed != params.seed:
            return False
        if self.symmetry != params.symmetry:
            return False
        if shdf is self.shdf:
            return True
        shdf = np.asarray(shdf, dtype=np.float64).reshape(-1)
        if self.triangles is not None:
            if len(self.triangles) and len(shdf) <= int(self.triangles.max()):
                return False
            shdf = shdf[self.triangles]
        return shdf.shape == self.shdf.shape and np.array_equal(np.clip(shdf, 0.0, 1.0), self.shdf)

    def _cut_nbytes(self) -> int:
        """Memory the coarse graphs add (their finest level shares the data, the weights and
        the graph's pairs); 0 before they are built."""
        if self._cut is None:
            return 0
        finest = self._cut.levels[0]
        shared = finest.data.nbytes + finest.unit_weights.nbytes + finest.pairs.nbytes
        return int(self._cut.nbytes - shared)

    @property
    def nbytes(self) -> int:
        """Memory held (arrays only), for callers that bound a cache of bases."""
        arrays = (self.shdf, self.values, self.posteriors, self.data, self.unit_weights)
        geometry = (self.geometry.areas, self.geometry.centroids, self.geometry.face_weight)
        size = sum(a.nbytes for a in arrays + geometry)
        if self.reflection is not None:
            size += self.reflection.mirror.nbytes
        if self.triangles is not None:
            size += self.triangles.nbytes
        size += self._cut_nbytes()
        for widened in self._widened.values():  # shares the face data, ShDF and weights
            size += widened.posteriors.nbytes + widened.data.nbytes + widened._cut_nbytes()
        return size
