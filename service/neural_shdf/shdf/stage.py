"""The ShDF stage, shaped like CGAL's: one raw-diameter producer, then one post-processing.

CGAL computes ``sdf_values(postprocess=false)`` and then
``sdf_values_postprocessing``. Here the producers are

* ``exact``: the ray cone at every face centroid (``exact.raw_shdf``);
* ``sampled``: the same cone cast only from Poisson-disk samples of the surface
  (``exact.raw_shdf_at_points``), smoothed at the sample scale over the surface
  window the exact path's bilateral filter covers, interpolated to the faces
  (``samples_to_faces``);
* ``neural``: the EMD network's diameters at the samples (``neural.inference``),
  smoothed and interpolated the same way;

and ``auto`` picks one per mesh (``resolve_method``). ``postprocess_shdf`` runs
once on the result: with its face-level bilateral filter for ``exact``, without
it for the sample-based producers, whose values are already smoothed at the
sample scale.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from neural_shdf import constants
from neural_shdf.errors import ParameterError
from neural_shdf.geometry import FaceGraph, in_frame
from neural_shdf.mesh import TriangleMesh
from neural_shdf.orientation import MeshDiagnostics, open_boundary_faces
from neural_shdf.segment.params import check_seed
from neural_shdf.shdf.embree import Scene
from neural_shdf.shdf.exact import raw_shdf, raw_shdf_at_points
from neural_shdf.shdf.neural.inference import NeuralModel, load_model, neural_raw_shdf
from neural_shdf.shdf.postprocess import (
    EXACT_WINDOW_MAX,
    FILTER_COST_PER_PAIR,
    SPATIAL_SIGMA_FACTOR,
    bilateral_window,
    mesh_ring_length,
    postprocess_shdf,
)
from neural_shdf.shdf.sampling import (
    DEFAULT_INTERPOLATION_NEIGHBOURS,
    SurfaceSamples,
    fill_samples,
    sample_surface_points,
    samples_to_faces,
    smooth_samples,
    vertex_normal_sums,
    with_vertex_map,
)
from neural_shdf.stitching import closing_caps

ShdfMethod = Literal["auto", "exact", "sampled", "neural"]
RawMethod = Literal["exact", "sampled", "neural"]
METHODS: tuple[str, ...] = ("auto", "exact", "sampled", "neural")
Progress = Callable[[float], None]

#: ``auto`` casts every face's cone up to this many faces (cheaper than sampling there,
#: and exact); above it, the sample-based producer ``AUTO_SAMPLED_METHOD``.
AUTO_EXACT_MAX_FACES = 150_000
#: The sample-based producer ``auto`` uses on large meshes (see the model card: the
#: network does not beat ``sampled`` at equal samples and rays).
AUTO_SAMPLED_METHOD: RawMethod = "sampled"
#: Poisson samples of the sample-based producers (the count follows the surface area,
#: not the triangles).
DEFAULT_SAMPLES = 4096
#: ``sampled`` casts up to this many samples where the surface has thin parts.
DEFAULT_MAX_SAMPLES = 16384
#: Thin parts: ``sampled`` wants the 10th percentile of its diameters to span at least this
#: many Poisson radii (the sample-space smoothing and the mapping to faces reach over a few
#: radii); where the first samples show thinner, it draws (this / p10)^2 as many, up to
#: ``max_samples``. Thin dense-dev meshes fall below it (docs/benchmarks.md).
THIN_PART_RADII = 3.0


@dataclass(frozen=True)
class ShdfParams:
    """Every parameter a ShDF depends on (besides the mesh, the method and the model).

    ``cone_angle``/``ray_count``: the ray cone (CGAL's defaults). ``seed``: the
    Poisson samples of the sample-based producers. ``samples``: their target count;
    ``max_samples``: ``sampled``'s count on surfaces with thin parts (see
    ``THIN_PART_RADII``; equal to ``samples`` for a fixed count).
    ``sample_sets``: the network's averaged sample sets. ``window_size``: the
    bilateral window in edge rings, 0 = CGAL's ``floor(sqrt(F / 2000)) + 1``.
    """

    cone_angle: float = constants.SHDF_CONE_ANGLE
    ray_count: int = constants.SHDF_RAY_COUNT
    seed: int = constants.DEFAULT_SEED
    samples: int = DEFAULT_SAMPLES
    max_samples: int = DEFAULT_MAX_SAMPLES
    sample_sets: int = 2
    window_size: int = 0

    def __post_init__(self) -> None:
        if not 0.0 < self.cone_angle < math.pi:
            raise ParameterError(f"cone_angle must lie in (0, pi) radians, got {self.cone_angle}")
        if self.ray_count < 1:
            raise ParameterError(f"ray_count must be at least 1, got {self.ray_count}")
        if self.samples < 16:
            raise ParameterError(f"samples must be at least 16, got {self.samples}")
        if self.max_samples < self.samples:
            raise ParameterError(
                f"max_samples ({self.max_samples}) must be at least samples ({self.samples})"
            )
        if self.sample_sets < 1:
            raise ParameterError(f"sample_sets must be at least 1, got {self.sample_sets}")
        if self.window_size < 0:
            raise ParameterError(f"window_size must be >= 0, got {self.window_size}")

    def window_for(self, face_count: int) -> int:
        """The bilateral window in edge rings for a mesh of ``face_count`` faces."""
        return self.window_size or bilateral_window(face_count)


def resolve_method(method: str, face_count: int) -> RawMethod:
    """The producer ``method`` means for a mesh of ``face_count`` triangles; deterministic.

    ``auto`` is the fastest producer that meets the fidelity target: every face's
    cone on meshes up to ``AUTO_EXACT_MAX_FACES`` faces (cheaper than sampling
    there), ``AUTO_SAMPLED_METHOD`` above.
    """
    if method == "auto":
        return "exact" if face_count <= AUTO_EXACT_MAX_FACES else AUTO_SAMPLED_METHOD
    if method in ("exact", "sampled", "neural"):
        return method  # type: ignore[return-value]
    raise ParameterError(f"unknown ShDF method {method!r}; use one of {', '.join(METHODS)}")


def uses_model(method: str) -> bool:
    """Whether ``method`` can run the neural network on some mesh."""
    return method == "neural" or (method == "auto" and AUTO_SAMPLED_METHOD == "neural")


def sample_filter_window(
    mesh: TriangleMesh, graph: FaceGraph, params: ShdfParams
) -> tuple[float, float]:
    """(radius, spatial sigma) in mesh units of the surface window the exact path's
    bilateral filter covers on this mesh (``window`` edge rings of ``ring_length``)."""
    window = params.window_for(mesh.face_count)
    spacing = mesh_ring_length(graph, mesh.vertices, mesh.faces)
    return window * spacing, SPATIAL_SIGMA_FACTOR * window * spacing


def thin_part_samples(diameters_in_radii: NDArray[Any], params: ShdfParams) -> int:
    """``sampled``'s sample count for a surface whose first ``params.samples`` samples
    measured these diameters (in Poisson radii, NaN = no hit): more where the 10th
    percentile spans fewer than ``THIN_PART_RADII`` radii (thin parts), at most
    ``params.max_samples``; deterministic."""
    valid = diameters_in_radii[np.isfinite(diameters_in_radii) & (diameters_in_radii > 0)]
    if len(valid) == 0 or params.max_samples <= params.samples:
        return params.samples
    thin = float(np.percentile(valid, 10))
    factor = (THIN_PART_RADII / thin) ** 2
    if factor <= 1.1:  # not worth a second pass
        return params.samples
    return int(min(params.max_samples, round(params.samples * factor)))


def ray_targets(mesh: TriangleMesh, close_holes: bool) -> tuple[NDArray[Any], NDArray[Any]]:
    """(vertices, triangles) the ShDF's rays are cast into: the mesh's triangles in order,
    then with ``close_holes`` a cap over each open boundary loop (``orientation.hole_caps``;
    ``mesh`` already faces outward), so that a ray leaving through a hole stops where the
    missing surface was instead of reading whatever lies beyond as material."""
    if not close_holes:
        return mesh.vertices, mesh.faces
    coincident, _ = mesh.coincident_welding
    vertices, caps = closing_caps(mesh.vertices, coincident, mesh.welded_faces, mesh.welded_edges)
    return vertices, np.vstack([mesh.faces, caps])


def in_pose_frame(mesh: TriangleMesh, points: NDArray[Any]) -> NDArray[np.float64]:
    """Points in ``mesh.pose_frame`` (``geometry.in_frame``): where the rays are cast."""
    return in_frame(points, mesh.pose_frame)


def turned_to_pose_frame(mesh: TriangleMesh, directions: NDArray[Any]) -> NDArray[np.float64]:
    """Directions (normals) turned into ``mesh.pose_frame``, rounded as ``in_pose_frame``."""
    return in_frame(directions, mesh.pose_frame, translate=False)


def framed_targets(mesh: TriangleMesh, vertices: NDArray[Any]) -> NDArray[np.float64]:
    """``ray_targets``' vertices in the pose frame: the mesh's own (``pose_geometry``),
    then any the caps added."""
    framed = mesh.pose_geometry[0]
    if len(vertices) == len(framed):
        return framed
    return np.vstack([framed, in_pose_frame(mesh, vertices[len(framed) :])])


def surface_triangles(mesh: TriangleMesh, triangles: NDArray[Any]) -> int:
    """How many of ``ray_targets``' triangles are surface for the rays: the mesh's and the
    bridges across slits between stitched shells (which end at a vertex of the surface);
    the rest are fans over holes to their loop's centroid, whose hits the exact ShDF
    trusts only as far as ``exact._drop_short_cap_hits`` says."""
    return int(np.count_nonzero(np.asarray(triangles)[:, 2] < len(mesh.vertices)))


def sampled_raw_shdf(
    mesh: TriangleMesh,
    graph: FaceGraph,
    params: ShdfParams,
    workers: int | None = None,
    close_holes: bool = False,
) -> NDArray[np.float64]:
    """Per-face raw diameters from the exact cone cast at ``params.samples`` Poisson
    samples (again at more of them where those show thin parts: ``thin_part_samples``),
    smoothed at the sample scale and interpolated to the faces.

    All of it in ``mesh.pose_frame`` (the diameters scaled back): the samples are drawn
    on the frame's coordinates (``pose_geometry``), each face's from its corners'
    positions there (``sampling.surface_candidates``), so the same surface listed in
    another order, moved, turned or scaled gets the same samples. Vertex normals are
    summed over coincident vertices (a triangle soup's are its surface's). The Embree
    scene is built (``low`` quality: a few rays per triangle) while the samples are
    drawn, and each vertex's nearest samples are found while the rays are cast
    (``workers`` threads, default one per CPU; the result does not depend on it).
    """
    workers = max(1, os.cpu_count() or 1) if workers is None else max(1, workers)
    scale = mesh.pose_frame[2]
    framed_vertices, normals = mesh.pose_geometry
    areas = mesh.normals_and_areas[1] / scale**2
    with ThreadPoolExecutor(max_workers=2) as pool:
        targets = ray_targets(mesh, close_holes)
        surface = surface_triangles(mesh, targets[1])
        framed = framed_targets(mesh, targets[0])
        scene = pool.submit(Scene, framed, targets[1], "low", surface)
        normal_sums = welded_normal_sums(mesh, normals, areas)

        def cast(
            count: int,
        ) -> tuple[SurfaceSamples, Future[SurfaceSamples], NDArray[np.float64]]:
            """Samples (their vertex map under way) and their raw diameters."""
            samples = sample_surface_points(
                framed_vertices,
                mesh.faces,
                count,
                seed=params.seed,
                normals=normals,
                areas=areas,
                map_vertices=False,
                normal_sums=normal_sums,
            )
            mapped = pool.submit(
                with_vertex_map,
                samples,
                framed_vertices,
                normal_sums,
                DEFAULT_INTERPOLATION_NEIGHBOURS,
                workers,
            )
            diameters, _, _ = raw_shdf_at_points(
                framed_vertices,
                mesh.faces,
                samples.positions,
                samples.normals,
                samples.face_ids,
                cone_angle=params.cone_angle,
                ray_count=params.ray_count,
                threads=workers,
                scene=scene,
                surface_triangles=surface,
            )
            return samples, mapped, diameters

        samples, mapped, diameters = cast(params.samples)
        count = thin_part_samples(diameters / samples.radius, params)
        if count > params.samples:
            samples, mapped, diameters = cast(count)
        if np.isnan(diameters).all():
            return np.full(mesh.face_count, np.nan)
        diameters = fill_samples(diameters, samples.positions)
        radius, sigma = sample_filter_window(mesh, graph, params)
        smoothed = smooth_samples(
            diameters,
            samples.positions,
            samples.normals,
            radius=radius / scale,
            spatial_sigma=sigma / scale,
        )
        samples = mapped.result()
    return samples_to_faces(smoothed, samples, mesh.faces) * scale


def welded_normal_sums(
    mesh: TriangleMesh, normals: NDArray[Any], areas: NDArray[Any]
) -> NDArray[np.float64]:
    """``vertex_normal_sums`` over the faces around each vertex's position: vertices at one
    position (a triangle soup's, a seam's) share the sum, as if the file had listed one."""
    coincident = mesh.coincident_faces
    sums = vertex_normal_sums(len(mesh.vertices), coincident, normals, areas)
    if coincident is mesh.faces:
        return sums
    representative = np.arange(len(mesh.vertices))
    representative[mesh.faces.ravel()] = coincident.ravel()
    return sums[representative]


def raw_diameters(
    mesh: TriangleMesh,
    graph: FaceGraph,
    method: RawMethod,
    params: ShdfParams,
    model: object | None = None,
    progress: Progress | None = None,
    close_holes: bool = False,
) -> NDArray[np.float64]:
    """Raw diameter per triangle (mesh units, NaN = unknown) from one producer.

    ``mesh`` faces outward (``TriangleMesh.oriented``); ``close_holes``: its open boundary
    loops are capped for the rays of ``exact`` and ``sampled`` (``ray_targets``). Their
    rays are cast in ``mesh.pose_frame`` (``in_pose_frame``), the diameters scaled back.
    """
    if method == "exact":
        scale = mesh.pose_frame[2]
        targets = ray_targets(mesh, close_holes)
        surface = surface_triangles(mesh, targets[1])
        framed = framed_targets(mesh, targets[0])
        diameters = raw_shdf(
            framed[: len(mesh.vertices)],
            mesh.faces,
            cone_angle=params.cone_angle,
            ray_count=params.ray_count,
            # From the frame's own coordinates: a sliver's normal, which rounding decides,
            # is then the same in any pose.
            normals=mesh.pose_geometry[1],
            progress=progress,
            scene=Scene(framed, targets[1], surface_triangles=surface) if close_holes else None,
            surface_triangles=surface,
            centroids=in_pose_frame(mesh, mesh.centroids),
        )
        return diameters * scale
    if method == "sampled":
        return sampled_raw_shdf(mesh, graph, params, close_holes=close_holes)
    if method == "neural":
        normals, areas = mesh.normals_and_areas
        radius, sigma = sample_filter_window(mesh, graph, params)
        return neural_raw_shdf(
            mesh.vertices,
            mesh.faces,
            seed=params.seed,
            sample_sets=params.sample_sets,
            model=model,  # type: ignore[arg-type]
            normals=normals,
            areas=areas,
            sample_filter=(radius, sigma),
        )
    raise ParameterError(f"unknown ShDF producer {method!r}")


@dataclass(frozen=True)
class ShdfResult:
    """A post-processed ShDF in [0, 1] per triangle, the producer that made it and what
    the orientation pass found in the mesh (its rays went into the solid whatever the
    file's winding)."""

    values: NDArray[np.float64]
    method: RawMethod
    diagnostics: MeshDiagnostics | None = None


def compute_shdf(
    mesh: TriangleMesh,
    *,
    method: str = "auto",
    seed: int | None = None,
    params: ShdfParams | None = None,
    model: object | str | Path | None = None,
    progress: Progress | None = None,
) -> ShdfResult:
    """Post-processed ShDF in [0, 1] per triangle of ``mesh``: raw diameters from the
    producer ``method`` resolves to (``auto``, the default: ``resolve_method`` picks per
    mesh; ``exact``, ``sampled`` or ``neural``), then one post-processing.

    ``seed`` (0..``MAX_SEED``), when given, replaces ``params.seed``; by convention the
    segmentation's ``SegmentParams.seed``. ``model``: a loaded ``NeuralModel`` or the path
    of an ONNX model, used by ``neural`` (default: the installed model); ignored by the
    other producers. Every producer works on ``mesh.oriented`` and its face graph
    (``TriangleMesh.face_graph``): the rays go into the solid whatever the file's winding.
    """
    params = params or ShdfParams()
    if seed is not None:
        params = replace(params, seed=check_seed(seed))
    diagnostics = mesh.diagnostics
    # One copy of each triangle (coincident copies share its value).
    distinct = mesh.distinct
    mesh, graph, copy_of = distinct.mesh, distinct.mesh.face_graph, distinct.copy_of
    resolved = resolve_method(method, mesh.face_count)
    if resolved == "neural":
        model = model if isinstance(model, NeuralModel) else load_model(model)  # type: ignore[arg-type]
    window = params.window_for(mesh.face_count)
    ray_share = 0.5
    if resolved == "exact":  # the rays against the filter's expected time
        pairs = 1 + 3 * min(window, EXACT_WINDOW_MAX) * (min(window, EXACT_WINDOW_MAX) + 1) // 2
        ray_share = 1.0 / (1.0 + FILTER_COST_PER_PAIR * pairs)
    raw = raw_diameters(
        mesh,
        graph,
        resolved,
        params,
        model,
        None if progress is None else (lambda done: progress(ray_share * done)),
        close_holes=diagnostics.boundary_loops > 0,
    )
    values = postprocess_shdf(
        raw,
        graph,
        window_size=window,
        smooth=resolved == "exact",
        # the patch filter of wide windows places patches by centroid (exact only)
        centroids=mesh.centroids if resolved == "exact" else None,
        # the file's own open edges, stitched seams included: rays cross their slits too
        rim=open_boundary_faces(mesh.coincident_welding[1], mesh.face_count)
        if diagnostics.boundary_loops > 0
        else None,
        progress=None
        if progress is None
        else (lambda done: progress(ray_share + (1 - ray_share) * done)),
    )[copy_of]
    return ShdfResult(values, resolved, diagnostics)
