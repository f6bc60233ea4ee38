"""The exact Shape Diameter Function by ray casting (Shapira, Shamir, Cohen-Or 2008).

Follows CGAL's ``sdf_values`` (Surface_mesh_segmentation) step by step:

* per non-degenerate triangle, ``ray_count`` rays leave the centroid inside a
  cone of opening ``cone_angle`` around the inward normal; the cone is sampled
  with Vogel's golden-angle spiral on the unit disk (radius ``i / n``, angle
  ``i * (3 - sqrt 5) * pi``, the first ray along the normal), all rays weighted
  equally; unlike CGAL (whose ``Plane_3::base1`` follows the world axes, so the
  rays and the ShDF change when the mesh is rotated), the spiral is oriented by
  a tangent of the triangle's own shape (``face_tangents``), so the ShDF does not
  depend on the mesh's position, orientation or scale in space;
* each ray keeps its first hit (the triangle itself excluded); the hit counts
  only when the ray leaves through the back of the hit triangle, i.e. the
  ray direction and the hit triangle's outward normal make an acute angle;
* outliers outside ``median +- 1.5 * MAD`` of a face's hit distances are
  dropped and the rest averaged.

Rays are cast through Embree 4 in packets of 16 (``shdf.embree``) from a numba
kernel that also makes the rays and reduces the hits: faces in Morton order,
16 neighbouring faces per packet, ray index by ray index, batches of faces in
several threads. The distance and the back-face test come from the packet (hit
distance, geometric normal), float32 as Embree computes them. Ray origins sit
``ORIGIN_OFFSET`` x the bounding-box diagonal along the ray, so hits closer than
that are not seen: where coplanar faces overlap, CGAL may record near-zero
distances (depending on the rounding of the centroid) that this implementation
does not.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf import constants
from neural_shdf.compiled import kernel
from neural_shdf.errors import ParameterError
from neural_shdf.geometry import face_centroids, face_normals
from neural_shdf.shdf.embree import (
    LANES,
    NORMAL_X,
    NORMAL_Y,
    NORMAL_Z,
    TFAR,
    Scene,
    bounding_box,
    hit_of,
    intersect_packet,
    new_packet,
    set_ray,
)

Progress = Callable[[float], None]

#: Rays whose distance lies further than this many median absolute deviations
#: from the median are outliers (CGAL's ``CGAL_NUMBER_OF_MAD``).
OUTLIER_MAD_FACTOR = 1.5
#: A ray's hit on a hole's cap counts only when it is at least this share of the median
#: of the same origin's hits on the surface (``_drop_short_cap_hits``).
CAP_HIT_SHARE = 0.5
#: Faces whose rays are cast in one Embree call (bounds the memory of a batch).
FACES_PER_BATCH = 32_768
#: Smallest batch when a mesh is split over several threads.
MIN_FACES_PER_BATCH = 2_048
#: Batches per thread at least (small batches balance the threads' load).
BATCHES_PER_THREAD = 8
#: Ray origins move this fraction of the bounding-box diagonal along the ray so
#: that the ray cannot hit its own triangle through float32 rounding.
ORIGIN_OFFSET = 1e-6
#: Offset used again for the few rays that still hit their own triangle.
RETRY_ORIGIN_OFFSET = 1e-4
#: ``face_tangents``: a triangle counts as equilateral when its shape's tangent is
#: shorter than this fraction of its size (there rounding would pick the direction).
EQUILATERAL_TOLERANCE = 1e-7


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


def face_tangents(
    vertices: NDArray[Any], faces: NDArray[Any], which: NDArray[Any] | None = None
) -> NDArray[np.float64]:
    """(F, 3) unit vector in each triangle's plane that orients its ray cone's spiral
    (of the faces ``which`` only, in that order, when given).

    ``t = sum_i (l_i^2 - mean l^2) (v_i - c)``: the vertices' offsets from the centroid
    ``c`` weighted by the squared length of the opposite edge, so it leans towards the
    vertex of the largest angle. It turns with the triangle, ignores translation and
    scale and does not depend on which vertex the face lists first or on its winding;
    it varies continuously with the vertices (no arg-max whose ties rounding would break
    differently in another pose). Only equilateral triangles have no such direction: for
    them (relative asymmetry below ``EQUILATERAL_TOLERANCE``) it is the direction to the
    face's vertex of smallest index; zero for a triangle shrunk to a point.
    """
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    which = np.arange(len(faces)) if which is None else np.asarray(which, dtype=np.int64)
    tangents = np.empty((len(which), 3))
    _face_tangents(
        np.ascontiguousarray(vertices, dtype=np.float64),
        faces,
        which,
        EQUILATERAL_TOLERANCE,
        tangents,
    )
    return tangents


@kernel
def _face_tangents(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    which: NDArray[Any],
    tolerance: float,
    out: NDArray[Any],
) -> None:
    """``face_tangents`` into ``out``, one face at a time."""
    offsets = np.empty((3, 3))
    squared = np.empty(3)
    for k in range(len(which)):
        # Indexed by row: a view of the row per face kept reference counting in the loop.
        row = which[k]
        for i in range(3):
            # Offset of corner i from the centroid, from the two edges leaving it (no
            # cancellation far from the origin); squared length of the opposite edge.
            j, m = (i + 1) % 3, (i + 2) % 3
            length = 0.0
            for axis in range(3):
                here = vertices[faces[row, i], axis]
                offsets[i, axis] = (
                    (here - vertices[faces[row, j], axis]) + (here - vertices[faces[row, m], axis])
                ) / 3.0
                edge = vertices[faces[row, m], axis] - vertices[faces[row, j], axis]
                length += edge * edge
            squared[i] = length
        mean = (squared[0] + squared[1] + squared[2]) / 3.0
        longest = 0.0
        for i in range(3):
            longest = max(longest, offsets[i, 0] ** 2 + offsets[i, 1] ** 2 + offsets[i, 2] ** 2)
        scale = 3.0 * mean * math.sqrt(longest)
        norm = 0.0
        for axis in range(3):
            value = 0.0
            for i in range(3):
                value += (squared[i] - mean) * offsets[i, axis]
            out[k, axis] = value
            norm += value * value
        norm = math.sqrt(norm)
        if not norm > tolerance * scale:  # equilateral: the corner of smallest index
            first = 0
            for i in range(1, 3):
                if faces[row, i] < faces[row, first]:
                    first = i
            norm = 0.0
            for axis in range(3):
                out[k, axis] = offsets[first, axis]
                norm += offsets[first, axis] ** 2
            norm = math.sqrt(norm)
        if norm > 0:
            for axis in range(3):
                out[k, axis] /= norm


def plane_basis(normals: NDArray[Any]) -> tuple[NDArray[Any], NDArray[Any]]:
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


def cone_coefficients(ray_count: int, cone_angle: float) -> NDArray[np.float64]:
    """(ray_count, 3) weights of each ray on (inward normal, base1, base2), unit length.

    Ray ``i`` is ``cos(a/2) n + sin(a/2) (x_i base1 + y_i base2)``, normalised, for
    the disk samples (x_i, y_i).
    """
    points, _ = disk_samples(ray_count)
    half = 0.5 * cone_angle
    coefficients = np.column_stack([np.full(ray_count, math.cos(half)), math.sin(half) * points])
    unit: NDArray[np.float64] = coefficients / np.linalg.norm(coefficients, axis=1, keepdims=True)
    return unit


def cone_frames(
    inward_normals: NDArray[Any], tangents: NDArray[Any], rotation: NDArray[Any] | None = None
) -> NDArray[Any]:
    """(F, 3, 3) rows (inward normal, base1, base2) of each face's ray cone.

    ``base1`` is ``tangents`` (``face_tangents`` of the face the cone leaves from) made
    perpendicular to the axis, ``base2 = normal x base1``; an axis the tangent cannot
    span a plane with (a caller's normal lying in the face) falls back to ``plane_basis``.
    ``rotation`` (F,) optionally turns each face's sample pattern about its axis.
    """
    inward_normals = np.asarray(inward_normals, dtype=np.float64)
    tangents = np.asarray(tangents, dtype=np.float64)
    base1 = tangents - np.einsum("ij,ij->i", tangents, inward_normals)[:, None] * inward_normals
    length = np.linalg.norm(base1, axis=1)
    fallback = ~(length > 1e-6)
    if fallback.any():
        base1[fallback] = plane_basis(inward_normals[fallback])[0]
        length[fallback] = 1.0
    base1 /= length[:, None]
    base2 = np.cross(inward_normals, base1)
    if rotation is not None:
        cos_r, sin_r = np.cos(rotation)[:, None], np.sin(rotation)[:, None]
        base1, base2 = cos_r * base1 + sin_r * base2, cos_r * base2 - sin_r * base1
    return np.stack([inward_normals, base1, base2], axis=1)


def cone_directions(
    inward_normals: NDArray[Any],
    tangents: NDArray[Any],
    *,
    cone_angle: float,
    ray_count: int,
    rotation: NDArray[Any] | None = None,
    dtype: type = np.float64,
) -> NDArray[Any]:
    """Unit ray directions (F, ray_count, 3) inside the cone around each inward normal,
    oriented by ``tangents`` (``cone_coefficients`` on ``cone_frames``)."""
    coefficients: NDArray[Any] = cone_coefficients(ray_count, cone_angle).astype(dtype)
    frames = cone_frames(inward_normals, tangents, rotation)
    directions: NDArray[Any] = np.matmul(coefficients, frames.astype(dtype))
    return directions


def spatial_order(points: NDArray[Any], bits: int = 10) -> NDArray[np.int64]:
    """Indices that sort points along a Morton (Z-order) curve of their bounding box.

    Casting the rays of nearby faces one after another keeps Embree's caches warm.
    Points in one cell go by position (x, y, z), not index: the packets, and so which of
    two triangles at the same distance a ray reports, are the same in any face order.
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
    return np.lexsort((points[:, 2], points[:, 1], points[:, 0], code))


@kernel(inline=True)
def _sorted_median(values: NDArray[Any], count: int) -> float:
    """Sort ``values[:count]`` in place (insertion sort: a face has few rays); their median."""
    for i in range(1, count):
        value = values[i]
        j = i - 1
        while j >= 0 and values[j] > value:
            values[j + 1] = values[j]
            j -= 1
        values[j + 1] = value
    median: float = 0.5 * (values[(count - 1) // 2] + values[count // 2])
    return median


@kernel
def _robust_mean_row(
    distances: NDArray[Any], weights: NDArray[Any], scratch: NDArray[Any]
) -> float:
    """``robust_mean`` of one row; ``scratch`` is work space at least as long as the row."""
    count = 0
    for value in distances:
        if not np.isnan(value):
            scratch[count] = value
            count += 1
    if count == 0:
        return np.nan
    median = _sorted_median(scratch, count)
    for i in range(count):
        scratch[i] = abs(scratch[i] - median)
    limit = OUTLIER_MAD_FACTOR * _sorted_median(scratch, count)
    total = 0.0
    total_weight = 0.0
    for i in range(len(distances)):
        value = distances[i]
        if not np.isnan(value) and abs(value - median) <= limit:
            total += value * weights[i]
            total_weight += weights[i]
    return total / total_weight if total > 0 else median


def robust_mean(distances: NDArray[Any], weights: NDArray[Any]) -> NDArray[np.float64]:
    """Per row of ``distances`` (NaN = no hit): weighted mean of the values within
    ``OUTLIER_MAD_FACTOR`` median absolute deviations of the median; NaN for rows
    without values. Medians of an even count average the two middle values.
    """
    distances = np.asarray(distances, dtype=np.float64)
    weights = np.asarray(weights, dtype=np.float64)
    scratch = np.empty(distances.shape[1])
    return np.array([_robust_mean_row(row, weights, scratch) for row in distances])


def _check_cone(cone_angle: float, ray_count: int) -> None:
    if not 0.0 < cone_angle < math.pi:
        raise ParameterError(f"cone_angle must lie in (0, pi) radians, got {cone_angle}")
    if ray_count < 1:
        raise ParameterError(f"ray_count must be at least 1, got {ray_count}")


def raw_shdf(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    *,
    cone_angle: float = constants.SHDF_CONE_ANGLE,
    ray_count: int = constants.SHDF_RAY_COUNT,
    seed: int = 0,
    rotate_pattern: bool = False,
    normals: NDArray[Any] | None = None,
    threads: int | None = None,
    progress: Progress | None = None,
    scene: Scene | Future[Scene] | None = None,
    surface_triangles: int | None = None,
    centroids: NDArray[Any] | None = None,
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
        scene: the Embree scene the rays are cast into (or its future), when the caller
            built it: ``faces`` first, in order, then any triangles that only stop rays
            (``shdf.stage.ray_targets``); default: one of ``faces``.
        surface_triangles: how many of the scene's first triangles are surface (default
            ``len(faces)``); hits on the others, holes' caps, count only as
            ``_drop_short_cap_hits`` says.
        centroids: (F, 3) the triangles' centroids, where the caller has them (computed
            if omitted).
    """
    _check_cone(cone_angle, ray_count)
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if normals is None and len(faces):
        normals, _ = face_normals(vertices, faces)
    if not len(faces):
        return np.full(0, np.nan)
    result, _, _ = _cast_rays(
        vertices,
        faces,
        face_centroids(vertices, faces) if centroids is None else np.asarray(centroids),
        np.asarray(normals, dtype=np.float64),
        np.arange(len(faces), dtype=np.int64),
        cone_angle=cone_angle,
        ray_count=ray_count,
        seed=seed,
        rotate_pattern=rotate_pattern,
        threads=threads,
        progress=progress,
        statistics=False,
        scene=scene,
        surface_triangles=surface_triangles,
    )
    return result


def raw_shdf_at_points(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    points: NDArray[Any],
    point_normals: NDArray[Any],
    point_faces: NDArray[Any],
    *,
    cone_angle: float = constants.SHDF_CONE_ANGLE,
    ray_count: int = constants.SHDF_RAY_COUNT,
    threads: int | None = None,
    scene: Scene | Future[Scene] | None = None,
    surface_triangles: int | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """The exact ShDF's ray cone cast from surface points instead of face centroids.

    ``points`` (P, 3) lie on the triangles ``point_faces`` (never hit by their own
    rays) with unit outward ``point_normals``. Returns per point the robust mean
    diameter (NaN without a valid hit), the spread of the valid hit distances
    (standard deviation over their mean, 0 without hits) and the fraction of rays
    with a valid hit. Same rays, back-face test and outlier filter as ``raw_shdf``.
    ``scene``: the mesh's Embree scene (or its future) when the caller built it;
    otherwise one of ``low`` build quality is built (a few rays per triangle);
    ``surface_triangles`` as ``raw_shdf``'s.
    """
    _check_cone(cone_angle, ray_count)
    points = np.asarray(points, dtype=np.float64)
    if not len(points):
        empty = np.zeros(0)
        return empty, empty.copy(), empty.copy()
    return _cast_rays(
        np.asarray(vertices, dtype=np.float64),
        np.asarray(faces, dtype=np.int64),
        points,
        np.asarray(point_normals, dtype=np.float64),
        np.asarray(point_faces, dtype=np.int64),
        cone_angle=cone_angle,
        ray_count=ray_count,
        seed=0,
        rotate_pattern=False,
        threads=threads,
        progress=None,
        statistics=True,
        scene=scene,
        quality="low",
        surface_triangles=surface_triangles,
    )


def _cast_rays(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    origins: NDArray[Any],
    normals: NDArray[Any],
    own_faces: NDArray[Any],
    *,
    cone_angle: float,
    ray_count: int,
    seed: int,
    rotate_pattern: bool,
    threads: int | None,
    progress: Progress | None,
    statistics: bool,
    scene: Scene | Future[Scene] | None = None,
    quality: str = "medium",
    surface_triangles: int | None = None,
) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """Cones of rays from ``origins`` around their inward ``normals``, in batches over
    threads: (robust mean, spread, hit fraction) per origin; the last two only with
    ``statistics`` (else empty). Origins with a zero normal get NaN. ``scene``: the
    mesh's scene (or its future), else one of build ``quality`` is built here."""
    count = len(origins)
    result = np.full(count, np.nan)
    spread = np.zeros(count if statistics else 0)
    hit_fraction = np.zeros(count if statistics else 0)
    valid = np.linalg.norm(normals, axis=1) > 0.5
    if not valid.any():
        if progress is not None:
            progress(1.0)
        return result, spread, hit_fraction
    threads = max(1, os.cpu_count() or 1) if threads is None else max(1, threads)
    low, high = bounding_box(vertices)
    diagonal = float(np.linalg.norm(high - low))
    origin_offset = np.float32(ORIGIN_OFFSET * diagonal)
    retry_offset = np.float32(RETRY_ORIGIN_OFFSET * diagonal)
    _, weights = disk_samples(ray_count)
    rotation = (
        np.random.default_rng(seed).uniform(0.0, 2.0 * math.pi, count) if rotate_pattern else None
    )
    with ThreadPoolExecutor(max_workers=threads) as pool:
        # Building the Embree scene releases the GIL: overlap it with the set-up.
        if scene is None:
            building = pool.submit(  # degenerate triangles: never hit
                Scene, vertices, faces, quality, surface_triangles
            )
        elif isinstance(scene, Scene):
            building = pool.submit(lambda: scene)
        else:
            building = scene
        todo = np.flatnonzero(valid)
        todo = todo[spatial_order(origins[todo])]
        size = min(
            FACES_PER_BATCH,
            max(MIN_FACES_PER_BATCH, -(-len(todo) // (BATCHES_PER_THREAD * threads))),
        )
        batches = [todo[i : i + size] for i in range(0, len(todo), size)]
        local_origins = (origins - 0.5 * (low + high)).astype(np.float32)
        coefficients = cone_coefficients(ray_count, cone_angle).astype(np.float32)

        def run_batch(batch: NDArray[Any]) -> None:
            frames = cone_frames(
                np.negative(np.take(normals, batch, axis=0)),
                face_tangents(vertices, faces, np.take(own_faces, batch)),
                None if rotation is None else np.take(rotation, batch),
            ).astype(np.float32)
            scene = building.result()  # the frames above were made while the scene was built
            _shdf_of_faces(
                *scene.kernel_arguments(),
                batch,
                frames,
                coefficients,
                local_origins,
                own_faces,
                scene.scene_index,
                len(faces) if surface_triangles is None else surface_triangles,
                origin_offset,
                retry_offset,
                weights,
                result,
                spread,
                hit_fraction,
            )

        done = 0
        for batch, _ in zip(batches, pool.map(run_batch, batches), strict=True):
            done += len(batch)
            if progress is not None:
                progress(done / len(todo))
    return result, spread, hit_fraction


@kernel(inline=True)
def _exit_distance(
    rays: NDArray[Any], ids: NDArray[Any], lane: int, direction: NDArray[Any], offset: np.float32
) -> float:
    """Distance from the face centroid to the ray's hit, NaN without a hit or when the
    ray does not leave through the back of the hit face (an outward normal facing it)."""
    if hit_of(ids, lane) < 0:
        return np.nan
    along = (
        direction[0] * rays[NORMAL_X, lane]
        + direction[1] * rays[NORMAL_Y, lane]
        + direction[2] * rays[NORMAL_Z, lane]
    )
    if not along > 0:
        return np.nan
    return np.float64(rays[TFAR, lane]) + np.float64(offset)


@kernel
def _shdf_of_faces(
    intersect16: Callable[[int, int, int, int], None],
    scene: int,
    arguments: int,
    batch: NDArray[Any],
    frames: NDArray[Any],
    coefficients: NDArray[Any],
    local_origins: NDArray[Any],
    own_faces: NDArray[Any],
    scene_index: NDArray[Any],
    surface_faces: int,
    origin_offset: np.float32,
    retry_offset: np.float32,
    weights: NDArray[Any],
    result: NDArray[Any],
    spread: NDArray[Any],
    hit_fraction: NDArray[Any],
) -> None:
    """Raw ShDF of the origins ``batch`` into ``result``: rays of 16 origins per packet.

    ``frames[k]`` holds the inward normal and the two plane vectors of origin
    ``batch[k]`` (float32), ``coefficients`` each ray's weights on them; a ray
    hitting ``own_faces[origin]`` (in the scene: ``scene_index`` of it) starts again
    further out; hits on the scene's triangles past the first ``surface_faces`` (holes'
    caps) count as ``_drop_short_cap_hits`` says. Each hit is read from the packet
    itself (distance, geometric normal): no lookup of the hit triangle. ``spread`` and
    ``hit_fraction`` are filled when not empty.
    """
    rays, ids, valid = new_packet()
    ray_count = len(coefficients)
    directions = np.empty((LANES, ray_count, 3), dtype=np.float32)
    own_hit = np.empty((LANES, ray_count), dtype=np.bool_)
    on_cap = np.zeros((LANES, ray_count), dtype=np.bool_)
    distances = np.empty((LANES, ray_count))
    scratch = np.empty(ray_count)
    retry_lane = np.empty(LANES * ray_count, dtype=np.int64)
    retry_ray = np.empty(LANES * ray_count, dtype=np.int64)
    for start in range(0, len(batch), LANES):
        count = min(LANES, len(batch) - start)
        for lane in range(count):
            frame = frames[start + lane]
            for i in range(ray_count):
                for axis in range(3):
                    directions[lane, i, axis] = (
                        coefficients[i, 0] * frame[0, axis]
                        + coefficients[i, 1] * frame[1, axis]
                        + coefficients[i, 2] * frame[2, axis]
                    )
        # Ray i of 16 neighbouring faces: nearly parallel rays, a coherent packet.
        for i in range(ray_count):
            for lane in range(count):
                origin = local_origins[batch[start + lane]]
                set_ray(rays, ids, lane, origin, directions[lane, i], origin_offset)
            intersect_packet(intersect16, scene, arguments, rays, ids, valid, count)
            for lane in range(count):
                own_hit[lane, i] = hit_of(ids, lane) == scene_index[own_faces[batch[start + lane]]]
                distances[lane, i] = _exit_distance(
                    rays, ids, lane, directions[lane, i], origin_offset
                )
                on_cap[lane, i] = hit_of(ids, lane) >= surface_faces
        # Rays that hit their own triangle through rounding start again further out.
        pending = 0
        for lane in range(count):
            for i in range(ray_count):
                if own_hit[lane, i]:
                    retry_lane[pending] = lane
                    retry_ray[pending] = i
                    pending += 1
        for first in range(0, pending, LANES):
            size = min(LANES, pending - first)
            for k in range(size):
                lane = retry_lane[first + k]
                origin = local_origins[batch[start + lane]]
                set_ray(rays, ids, k, origin, directions[lane, retry_ray[first + k]], retry_offset)
            intersect_packet(intersect16, scene, arguments, rays, ids, valid, size)
            for k in range(size):
                lane, i = retry_lane[first + k], retry_ray[first + k]
                own = hit_of(ids, k) == scene_index[own_faces[batch[start + lane]]]
                distances[lane, i] = (
                    np.nan
                    if own
                    else _exit_distance(rays, ids, k, directions[lane, i], retry_offset)
                )
                on_cap[lane, i] = hit_of(ids, k) >= surface_faces
        for lane in range(count):
            item = batch[start + lane]
            _drop_short_cap_hits(distances[lane], on_cap[lane], scratch)
            result[item] = _robust_mean_row(distances[lane], weights, scratch)
            if len(spread):
                _hit_statistics(distances[lane], item, spread, hit_fraction)


@kernel(inline=True)
def _drop_short_cap_hits(
    distances: NDArray[Any], on_cap: NDArray[Any], scratch: NDArray[Any]
) -> None:
    """Set to NaN the hits on a hole's cap shorter than ``CAP_HIT_SHARE`` of the median of
    the same origin's hits on the surface (all cap hits count where it has none).

    A cap stands in for missing surface: across a hole it stops a ray about where the
    surface would have, but next to a cut through a limb (a scan with no base) it stands
    across the limb, and the rays of the faces along its rim meet it at a fraction of the
    limb's width: those few values stretched the ShDF's min-max normalisation.
    """
    count = 0
    for i in range(len(distances)):
        if not on_cap[i] and not np.isnan(distances[i]):
            scratch[count] = distances[i]
            count += 1
    if count == 0:
        return
    limit = CAP_HIT_SHARE * _sorted_median(scratch, count)
    for i in range(len(distances)):
        if on_cap[i] and distances[i] < limit:
            distances[i] = np.nan


@kernel(inline=True)
def _hit_statistics(
    distances: NDArray[Any], item: int, spread: NDArray[Any], hit_fraction: NDArray[Any]
) -> None:
    """Relative standard deviation of the valid hit distances and their share of the rays."""
    hits = 0
    total = 0.0
    squares = 0.0
    for value in distances:
        if not np.isnan(value):
            hits += 1
            total += value
            squares += value * value
    hit_fraction[item] = hits / len(distances)
    if hits > 0 and total > 0:
        mean = total / hits
        spread[item] = math.sqrt(max(squares / hits - mean * mean, 0.0)) / mean
    else:
        spread[item] = 0.0
