"""The exact Shape Diameter Function by ray casting (Shapira, Shamir, Cohen-Or 2008).

Follows CGAL's ``sdf_values`` (Surface_mesh_segmentation) step by step:

* per non-degenerate triangle, ``ray_count`` rays leave the centroid inside a
  cone of opening ``cone_angle`` around the inward normal; the cone is sampled
  with Vogel's golden-angle spiral on the unit disk (radius ``i / n``, angle
  ``i * (3 - sqrt 5) * pi``, the first ray along the normal), oriented by the
  plane basis CGAL's ``Plane_3::base1/base2`` picks, all rays weighted equally;
* each ray keeps its first hit (the triangle itself excluded); the hit counts
  only when the ray leaves through the back of the hit triangle, i.e. the
  ray direction and the hit triangle's outward normal make an acute angle;
* outliers outside ``median +- 1.5 * MAD`` of a face's hit distances are
  dropped and the rest averaged.

Rays of many faces are cast together through Embree (``embreex``, float32,
in Morton order of the faces, ray index by ray index within a batch, in several
threads that also make the rays and reduce the hits); distances are recomputed in
float64 from the hit triangle's plane. Ray origins sit ``ORIGIN_OFFSET`` x the
bounding-box diagonal along the ray, so hits closer than that are not seen:
where coplanar faces overlap, CGAL may record near-zero distances (depending
on the rounding of the centroid) that this implementation does not.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from neural_shdf import constants
from neural_shdf.errors import ParameterError
from neural_shdf.geometry import FaceGraph, face_centroids, face_normals
from neural_shdf.mesh import TriangleMesh
from neural_shdf.shdf.postprocess import postprocess_shdf

Progress = Callable[[float], None]

#: Rays whose distance lies further than this many median absolute deviations
#: from the median are outliers (CGAL's ``CGAL_NUMBER_OF_MAD``).
OUTLIER_MAD_FACTOR = 1.5
#: Faces whose rays are cast in one Embree call (bounds the memory of a batch).
FACES_PER_BATCH = 32_768
#: Smallest batch when a mesh is split over several threads.
MIN_FACES_PER_BATCH = 2_048
#: Batches per thread at least (small batches balance the threads' load).
BATCHES_PER_THREAD = 8
#: Ray origins move this fraction of the bounding-box diagonal along the ray so
#: that the ray cannot hit its own triangle through float32 rounding.
ORIGIN_OFFSET = 1e-6
#: Share of ``exact_shdf``'s progress reported by the ray casting.
RAY_SHARE = 0.9
#: Offset used again for the few rays that still hit their own triangle.
RETRY_ORIGIN_OFFSET = 1e-4


def disk_samples(ray_count: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """CGAL's default disk sampling: (ray_count, 2) points in the unit disk and their weights.

    Vogel's spiral with radius ``i / n`` (denser towards the centre, so the cone
    axis is favoured by sample density rather than by weight); weights are all 1.
    """
    index = np.arange(ray_count, dtype=np.float64)
    angle = index * (3.0 - math.sqrt(5.0)) * math.pi
    radius = index / ray_count
    points = np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=1)
    return points, np.ones(ray_count)


def plane_basis(normals: NDArray) -> tuple[NDArray, NDArray]:
    """Unit in-plane vectors (base1, base2) of planes with the given unit normals.

    Same choice as CGAL's ``Plane_3::base1`` (CGAL >= 5): (1,0,0) if the normal
    has no x component, else (0,1,0) if no y, else (0,0,1) if no z; otherwise the
    normal's smallest component (by magnitude, x before y before z on ties) is
    dropped and the other two are swapped with one negated. ``base2 = normal x base1``.
    """
    nx, ny, nz = normals[:, 0], normals[:, 1], normals[:, 2]
    ax, ay, az = np.abs(nx), np.abs(ny), np.abs(nz)
    zero = np.zeros_like(nx)
    drop_x = (ax <= ay) & (ax <= az)
    drop_y = ~drop_x & (ay <= ax) & (ay <= az)
    base1 = np.where(
        drop_x[:, None],
        np.stack([zero, -nz, ny], axis=1),
        np.where(
            drop_y[:, None],
            np.stack([-nz, zero, nx], axis=1),
            np.stack([-ny, nx, zero], axis=1),
        ),
    )
    base1[nz == 0] = (0.0, 0.0, 1.0)
    base1[ny == 0] = (0.0, 1.0, 0.0)
    base1[nx == 0] = (1.0, 0.0, 0.0)
    length = np.linalg.norm(base1, axis=1, keepdims=True)
    base1 /= np.where(length > 0, length, 1.0)
    base2 = np.cross(normals, base1)
    length = np.linalg.norm(base2, axis=1, keepdims=True)
    base2 /= np.where(length > 0, length, 1.0)
    return base1, base2


def cone_directions(
    inward_normals: NDArray,
    *,
    cone_angle: float,
    ray_count: int,
    rotation: NDArray | None = None,
    dtype: type = np.float64,
) -> NDArray:
    """Unit ray directions (F, ray_count, 3) inside the cone around each inward normal.

    Ray ``i`` is ``cos(a/2) n + sin(a/2) (x_i base1 + y_i base2)``, normalised, for
    the disk samples (x_i, y_i). ``rotation`` (F,) optionally turns each face's
    sample pattern about its axis.
    """
    points, _ = disk_samples(ray_count)
    half = 0.5 * cone_angle
    # Coefficients on (normal, base1, base2); their norm is the same for every face.
    coefficients = np.column_stack([np.full(ray_count, math.cos(half)), math.sin(half) * points])
    coefficients /= np.linalg.norm(coefficients, axis=1, keepdims=True)
    base1, base2 = plane_basis(inward_normals)
    if rotation is not None:
        cos_r, sin_r = np.cos(rotation)[:, None], np.sin(rotation)[:, None]
        base1, base2 = cos_r * base1 + sin_r * base2, cos_r * base2 - sin_r * base1
    frames = np.stack([inward_normals, base1, base2], axis=1).astype(dtype)
    return np.matmul(coefficients.astype(dtype), frames)


def spatial_order(points: NDArray, bits: int = 10) -> NDArray[np.int64]:
    """Indices that sort points along a Morton (Z-order) curve of their bounding box.

    Casting the rays of nearby faces one after another keeps Embree's caches warm.
    """
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    low = points.min(axis=0)
    extent = float((points.max(axis=0) - low).max()) or 1.0
    cells = ((points - low) / extent * (2**bits - 1)).astype(np.uint64)
    code = np.zeros(len(points), dtype=np.uint64)
    for bit in range(bits):
        for axis in range(3):
            code |= ((cells[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    return np.argsort(code, kind="stable")


def robust_mean(distances: NDArray, weights: NDArray) -> NDArray[np.float64]:
    """Per row of ``distances`` (NaN = no hit): weighted mean of the values within
    ``OUTLIER_MAD_FACTOR`` median absolute deviations of the median; NaN for rows
    without values. Medians of an even count average the two middle values.
    """
    rows = np.arange(len(distances))
    count = np.count_nonzero(~np.isnan(distances), axis=1)
    safe = np.maximum(count, 1)

    def row_median(values: NDArray) -> NDArray:
        ordered = np.sort(values, axis=1)  # NaN sorts last
        low = ordered[rows, (safe - 1) // 2]
        high = ordered[rows, safe // 2]
        return 0.5 * (low + high)

    median = row_median(distances)
    deviation = np.abs(distances - median[:, None])
    mad = row_median(deviation)
    accepted = deviation <= OUTLIER_MAD_FACTOR * mad[:, None]  # False for NaN
    w = np.where(accepted, weights[None, :], 0.0)
    total_weight = w.sum(axis=1)
    total = (np.where(accepted, distances, 0.0) * w).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        value = np.where(total > 0, total / total_weight, median)
    value[count == 0] = np.nan
    return value


class RayCaster:
    """Embree scene of a mesh (float32, centred on its bounding box)."""

    def __init__(self, vertices: NDArray, faces: NDArray) -> None:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh as EmbreeMesh

        self.center = self.center_of(vertices)
        self.scene = rtcore_scene.EmbreeScene()
        EmbreeMesh(
            self.scene,
            (vertices - self.center).astype(np.float32),
            np.ascontiguousarray(faces, dtype=np.int32),
        )

    @staticmethod
    def center_of(vertices: NDArray) -> NDArray:
        """Centre of the bounding box: the origin of the scene's float32 coordinates."""
        return 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))

    @classmethod
    def built(cls, vertices: NDArray, faces: NDArray) -> RayCaster:
        """A caster whose scene is already built, ready to be shared by threads."""
        caster = cls(vertices, faces)
        caster.first_hits(np.zeros((1, 3)), np.ones((1, 3)))  # commits the scene
        return caster

    def first_hits(self, origins: NDArray, directions: NDArray) -> NDArray:
        """Index of the first triangle each ray hits, -1 for none.

        ``origins`` are float32 relative to ``self.center``.
        """
        return self.scene.run(
            np.ascontiguousarray(origins, dtype=np.float32),
            np.ascontiguousarray(directions, dtype=np.float32),
        )


def raw_shdf(
    vertices: NDArray,
    faces: NDArray,
    *,
    cone_angle: float = constants.SHDF_CONE_ANGLE,
    ray_count: int = constants.SHDF_RAY_COUNT,
    seed: int = 0,
    rotate_pattern: bool = False,
    normals: NDArray | None = None,
    threads: int | None = None,
    progress: Progress | None = None,
) -> NDArray[np.float64]:
    """Raw diameter per triangle (mesh units), NaN where no ray gave a valid hit.

    Args:
        vertices: (V, 3) positions. faces: (F, 3) triangle vertex indices.
        cone_angle: full opening angle of the ray cone in radians, in (0, pi).
        ray_count: rays per face.
        seed: seed of the per-face pattern rotation; used only with ``rotate_pattern``.
        rotate_pattern: turn each face's sample pattern by a random angle about its
            axis (decorrelates the sampling of neighbouring faces); off = CGAL's
            deterministic orientation.
        normals: (F, 3) unit outward normals (zero for degenerate faces); computed
            if omitted.
        threads: batches run in this many threads, default one per CPU (the result
            does not depend on it).
        progress: called with the fraction of faces done, in [0, 1].
    """
    if not 0.0 < cone_angle < math.pi:
        raise ParameterError(f"cone_angle must lie in (0, pi) radians, got {cone_angle}")
    if ray_count < 1:
        raise ParameterError(f"ray_count must be at least 1, got {ray_count}")
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    result = np.full(len(faces), np.nan)
    if normals is None and len(faces):
        normals, _ = face_normals(vertices, faces)
    valid = np.zeros(len(faces), dtype=bool)
    if len(faces):
        normals = np.asarray(normals, dtype=np.float64)
        valid = np.linalg.norm(normals, axis=1) > 0.5
    if not valid.any():
        if progress is not None:
            progress(1.0)
        return result

    threads = max(1, os.cpu_count() or 1) if threads is None else max(1, threads)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        # Building the Embree scene releases the GIL: overlap it with the set-up.
        building = pool.submit(RayCaster.built, vertices, faces)  # degenerate faces never hit
        _cast_batches(
            building,
            pool,
            vertices,
            faces,
            normals,
            valid,
            result,
            cone_angle=cone_angle,
            ray_count=ray_count,
            seed=seed,
            rotate_pattern=rotate_pattern,
            threads=threads,
            progress=progress,
        )
    return result


def _cast_batches(
    building: Future[RayCaster],
    pool: ThreadPoolExecutor,
    vertices: NDArray,
    faces: NDArray,
    normals: NDArray,
    valid: NDArray,
    result: NDArray,
    *,
    cone_angle: float,
    ray_count: int,
    seed: int,
    rotate_pattern: bool,
    threads: int,
    progress: Progress | None,
) -> None:
    """Cast the rays of the valid faces in batches on ``pool``, writing ``result``."""
    face_count = len(faces)
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    centroids = face_centroids(vertices, faces)
    plane_offset = np.einsum("ij,ij->i", vertices[faces[:, 0]], normals)
    planes = np.column_stack([normals, plane_offset])  # gathered together per hit
    origin_offset = np.float32(ORIGIN_OFFSET * diagonal)
    retry_offset = np.float32(RETRY_ORIGIN_OFFSET * diagonal)
    _, weights = disk_samples(ray_count)
    rotation = (
        np.random.default_rng(seed).uniform(0.0, 2.0 * math.pi, face_count)
        if rotate_pattern
        else None
    )

    todo = np.flatnonzero(valid)
    todo = todo[spatial_order(centroids[todo])]
    size = min(
        FACES_PER_BATCH, max(MIN_FACES_PER_BATCH, -(-len(todo) // (BATCHES_PER_THREAD * threads)))
    )
    batches = [todo[i : i + size] for i in range(0, len(todo), size)]
    local_centroids = (centroids - RayCaster.center_of(vertices)).astype(np.float32)

    def run_batch(batch: NDArray) -> NDArray:
        directions = cone_directions(
            np.negative(np.take(normals, batch, axis=0)),
            cone_angle=cone_angle,
            ray_count=ray_count,
            rotation=None if rotation is None else np.take(rotation, batch),
            dtype=np.float32,
        )
        # Rays are cast ray index by ray index: ray i of neighbouring faces run
        # almost parallel, which keeps Embree's traversal coherent.
        by_ray = np.ascontiguousarray(directions.transpose(1, 0, 2))
        origins = np.take(local_centroids, batch, axis=0)[None, :, :]
        caster = building.result()  # the rays above were made while the scene was built
        hit = caster.first_hits(
            (origins + origin_offset * by_ray).reshape(-1, 3), by_ray.reshape(-1, 3)
        ).reshape(ray_count, len(batch))
        again_ray, again_face = np.nonzero(hit == batch[None, :])
        if len(again_ray):
            again_directions = by_ray[again_ray, again_face]
            retry = caster.first_hits(
                origins[0, again_face] + retry_offset * again_directions, again_directions
            )
            hit[again_ray, again_face] = np.where(retry == batch[again_face], -1, retry)
        hit = np.ascontiguousarray(hit.T)
        # Distance along the ray to the hit triangle's plane, in float64.
        hit_plane = np.take(planes, np.maximum(hit, 0), axis=0)
        hit_normal = hit_plane[..., :3]
        along = np.einsum("frk,frk->fr", directions.astype(np.float64), hit_normal)
        height = hit_plane[..., 3] - np.einsum(
            "frk,fk->fr", hit_normal, np.take(centroids, batch, axis=0)
        )
        # A hit counts when the ray leaves through the back of the hit face.
        accepted = (hit >= 0) & (along > 0)
        with np.errstate(divide="ignore", invalid="ignore"):
            distance = np.where(accepted, height / along, np.nan)
        return robust_mean(distance, weights)

    done = 0
    for batch, values in zip(batches, pool.map(run_batch, batches), strict=True):
        result[batch] = values
        done += len(batch)
        if progress is not None:
            progress(done / len(todo))


def exact_shdf(
    mesh: TriangleMesh,
    *,
    graph: FaceGraph,
    cone_angle: float = constants.SHDF_CONE_ANGLE,
    ray_count: int = constants.SHDF_RAY_COUNT,
    seed: int = 0,
    rotate_pattern: bool = False,
    window_size: int | None = None,
    threads: int | None = None,
    progress: Progress | None = None,
) -> NDArray[np.float64]:
    """Post-processed exact ShDF in [0, 1] per triangle of ``mesh`` (CGAL's ``sdf_values``).

    ``graph`` is the face adjacency the smoothing walks (``pipeline.mesh_face_graph``);
    the other parameters are those of ``raw_shdf`` and ``postprocess_shdf``.
    Progress: ray casting reports up to 0.9, post-processing the rest.
    """
    normals, _ = face_normals(mesh.vertices, mesh.faces)
    raw = raw_shdf(
        mesh.vertices,
        mesh.faces,
        cone_angle=cone_angle,
        ray_count=ray_count,
        seed=seed,
        rotate_pattern=rotate_pattern,
        normals=normals,
        threads=threads,
        progress=None if progress is None else (lambda done: progress(RAY_SHARE * done)),
    )
    values = postprocess_shdf(raw, graph, window_size=window_size)
    if progress is not None:
        progress(1.0)
    return values
