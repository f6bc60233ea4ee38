"""Segmentation of a mesh from any per-face ShDF in [0, 1]: mixture, partition, clean-up.

Steps (Shapira et al. 2008 as implemented by CGAL's ``segmentation_from_sdf_values``):

1. ``prepare_segment``: log-normalise the ShDF and fit a 1-D Gaussian mixture
   (k clusters); data costs ``-log P(cluster | face)`` and the dihedral edge weights
   at smoothing 1 (``SegmentBasis``, reusable for other smoothing or part counts);
2. ``segment``: a partitioner (``segment.partitioners``) cuts the mesh into parts:
   ``graphcut`` (alpha-expansion, the connected runs of one cluster as the leaves of
   a merge tree cut at ``parts`` parts or where the merge cost jumps) or ``metis``
   (a k-way partition into exactly ``parts`` parts); labels renumbered by lowest face.

Every array is per triangle of the mesh (``TriangleMesh.faces``); the steps work on
``mesh.distinct`` (oriented, one copy of each set of coincident triangles) and its cached
structures (face graph, centroids, crease graph); copies take their first copy's part.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import ParameterError
from neural_shdf.geometry import equivalent_face_count
from neural_shdf.mesh import DistinctTriangles, TriangleMesh
from neural_shdf.orientation import MeshDiagnostics
from neural_shdf.segment.basis import SegmentBasis
from neural_shdf.segment.graphcut import data_costs, dihedral_weights
from neural_shdf.segment.hierarchy import PartTree
from neural_shdf.segment.mixture import fit_best_mixture, fit_mixture, value_weights
from neural_shdf.segment.params import AUTO_CLUSTERS, DEFAULT_CLUSTERS, SegmentParams
from neural_shdf.segment.partitioners import PARTITIONERS, Partitioning
from neural_shdf.segment.parts import FaceData, canonical_labels
from neural_shdf.segment.symmetry import Reflection, detect_reflection, symmetrize
from neural_shdf.shdf.postprocess import log_normalize
from neural_shdf.shdf.stage import ShdfResult

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
    #: What the orientation pass found in the mesh.
    diagnostics: MeshDiagnostics | None = None
    #: The mirror plane the segmentation was made symmetric by (``params.symmetry``), or
    #: None (not asked, or no symmetry found).
    reflection: Reflection | None = None

    @property
    def part_count(self) -> int:
        return int(self.labels.max()) + 1 if len(self.labels) else 0

    def input_face_parts(
        self, mesh: TriangleMesh
    ) -> tuple[NDArray[np.int64], NDArray[np.int64] | None]:
        """(part label, leaf of the part tree or None) per face of ``mesh``'s input file,
        in its order (``TriangleMesh.labels_to_input_faces``); -1 for faces without triangles.

        With a tree, the input faces' labels are the tree's cut of their leaves, so a
        client that re-cuts the tree (see ``tree_document.part_tree_document``) gets the same.
        """
        if self.tree is None:
            return mesh.labels_to_input_faces(self.labels), None
        leaves = mesh.labels_to_input_faces(self.tree.leaf_labels)
        return self.tree.relabel(leaves, self.part_count), leaves


def prepare_segment(
    mesh: TriangleMesh, shdf: NDArray[Any] | ShdfResult, params: SegmentParams | None = None
) -> SegmentBasis:
    """The ``SegmentBasis`` of a mesh, its ShDF and ``params.clusters``/``seed``/``symmetry``:
    pass it to ``segment`` to try other smoothing or part counts quickly. Checks the ShDF
    and ``params`` against the mesh (ParameterError). ``shdf``: values per triangle or
    ``compute_shdf``'s result."""
    start = time.perf_counter()
    params = params or SegmentParams()
    shdf = validate(mesh.face_count, shdf_values(shdf), params)
    distinct = mesh.distinct
    if distinct.reordered:
        shdf = shdf[distinct.kept]
    if distinct.has_copies:
        check_part_count(params, distinct.mesh.face_count)
    mesh = distinct.mesh
    geometry = FaceData.of(
        mesh.vertices,
        mesh.faces,
        mesh.normals_and_areas,
        mesh.centroids,
        pose=mesh.pose_frame,
        principal=mesh.principal_frame,
        pose_normals=mesh.pose_geometry[1],
    )
    values = log_normalize(shdf)
    reflection = None
    if params.symmetry:
        normals, areas = mesh.normals_and_areas
        reflection = detect_reflection(mesh.centroids, normals, areas)
        if reflection is not None:  # both sides get the same evidence
            values = symmetrize(values, reflection.mirror)
    equivalent_faces = functools.cache(lambda: equivalent_face_count(geometry.areas))
    weights = value_weights(geometry.areas, equivalent_faces)  # None unless uneven
    if params.clusters == AUTO_CLUSTERS:
        mixture = fit_best_mixture(values, params.seed, weights=weights)
    else:
        clusters = DEFAULT_CLUSTERS if params.clusters is None else params.clusters
        mixture = fit_mixture(values, clusters, params.seed, weights=weights)
    posteriors = mixture.posteriors(values)
    basis = SegmentBasis(
        clusters=params.clusters,
        seed=params.seed,
        geometry=geometry,
        shdf=shdf,
        values=values,
        mixture=mixture,
        posteriors=posteriors,
        data=data_costs(posteriors, geometry.face_weight),
        unit_weights=dihedral_weights(mesh.face_graph, 1.0),
        seconds=time.perf_counter() - start,
        symmetry=params.symmetry,
        reflection=reflection,
        frame=mesh.principal_frame,
        triangles=distinct.kept if distinct.reordered else None,
    )
    if equivalent_faces.cache_info().currsize:  # worked out for the weights: kept
        basis.__dict__["equivalent_faces"] = equivalent_faces()
    return basis


def segment(
    mesh: TriangleMesh,
    shdf: NDArray[Any] | ShdfResult,
    params: SegmentParams | None = None,
    *,
    basis: SegmentBasis | None = None,
) -> SegmentResult:
    """Part label per triangle, 0..P-1 in order of each part's lowest triangle, from a ShDF
    in [0, 1] per triangle (or ``compute_shdf``'s result); deterministic. Also the part
    tree (graph cut), the mixture size, the smoothing and per-step timings.

    ``basis``: ``prepare_segment``'s result for this mesh, ShDF, clusters and seed (kept
    by the caller to re-segment cheaply); the same labels as without it.
    """
    params = params or SegmentParams()
    shdf = shdf_values(shdf)
    timings: dict[str, float] = {}
    clock = time.perf_counter()

    def lap(name: str) -> None:
        nonlocal clock
        now = time.perf_counter()
        timings[name] = timings.get(name, 0.0) + now - clock
        clock = now

    diagnostics = mesh.diagnostics
    distinct = mesh.distinct
    if basis is not None:
        if not basis.matches(params, shdf):
            raise ValueError("the segment basis was prepared for another ShDF, clusters or seed")
        check_part_count(params, distinct.mesh.face_count)
    elif mesh.face_count == 0:
        validate(0, shdf, params)
    else:
        basis = prepare_segment(mesh, shdf, params)
        lap("prepare")
    if basis is None or mesh.face_count == 0:
        empty = np.zeros(0, dtype=np.int64)
        return SegmentResult(empty, 0, params.effective_smoothing, timings, None, diagnostics)
    work = distinct.mesh
    partitioning = Partitioning(
        graph=work.face_graph,
        basis=basis,
        params=params,
        smoothing=params.smoothing_for(work.face_count),
        creases=work.crease_graph if params.crease_boundaries else None,
        lap=lap,
        spokes=work.hole_spokes if diagnostics.boundary_loops > 0 else None,
    )
    labels, tree = PARTITIONERS[params.partitioner].partition(partitioning)
    if distinct.reordered:  # back to the file's triangles (copies in their first copy's part)
        labels = canonical_labels(labels[distinct.copy_of])
        if tree is not None:
            tree = tree.listed_by(tree.leaf_labels[distinct.copy_of])
    return SegmentResult(
        labels,
        basis.mixture.size,
        params.effective_smoothing,
        timings,
        tree,
        diagnostics,
        file_reflection(basis.reflection, distinct),
    )


def file_reflection(
    reflection: Reflection | None, distinct: DistinctTriangles
) -> Reflection | None:
    """``reflection`` (found on ``distinct.mesh``) with each of the file's triangles mapped
    to the file's triangle (a first copy) nearest its reflection."""
    if reflection is None or not distinct.reordered:
        return reflection
    mirror = reflection.mirror[distinct.copy_of]
    mirror = np.where(mirror >= 0, distinct.kept[np.maximum(mirror, 0)], -1)
    return replace(reflection, mirror=mirror)


def check_part_count(params: SegmentParams, face_count: int) -> None:
    """ParameterError when ``params`` asks for more parts than the mesh has faces."""
    if params.parts is not None and params.parts > face_count:
        raise ParameterError(
            f"parts={params.parts} is more than the mesh's {face_count} faces; "
            f"ask for at most {face_count} parts"
        )


def shdf_values(shdf: NDArray[Any] | ShdfResult) -> NDArray[Any]:
    """The values of ``compute_shdf``'s result; anything else as given (checked by
    ``validate``)."""
    return shdf.values if isinstance(shdf, ShdfResult) else shdf


def validate(face_count: int, shdf: NDArray[Any], params: SegmentParams) -> NDArray[np.float64]:
    """Check what depends on the mesh (``SegmentParams`` checks itself when it is built);
    return the ShDF as float64 clipped to [0, 1]. Raises ParameterError."""
    check_part_count(params, face_count)
    values = np.asarray(shdf, dtype=np.float64)
    if values.shape != (face_count,):
        raise ParameterError(
            f"the ShDF has shape {values.shape} but the mesh has {face_count} faces; "
            "give one value per face"
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
