"""Poisson-disk samples of a surface, and values carried between samples and faces.

Used by the ``sampled`` ShDF (rays cast from the samples) and by the neural one (the
network's input graph, ``neural.graph``, is built over these samples):

* ``sample_surface_points``: area-weighted random candidates, then a greedy maximal
  independent set of the candidates closer than the Poisson radius
  ``r = sqrt(RADIUS_AREA_FACTOR * area / target_samples)`` (about ``target_samples``
  samples whatever the tessellation), in random priority order: deterministic for a
  seed; optionally each sample's density (surface area within ``DENSITY_RADIUS`` radii
  over a flat disk's) and each mesh vertex's nearest samples;
* ``samples_to_faces`` / ``resample``: values at the samples interpolated to the faces
  or to another sample set of the same surface (normal-aware inverse distance);
* ``smooth_samples`` / ``fill_samples``: the exact path's bilateral filter at the sample
  scale, and samples without a value filled from their neighbours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from neural_shdf.compiled import kernel
from neural_shdf.errors import InvalidGeometryError
from neural_shdf.geometry import face_normals
from neural_shdf.shdf.postprocess import RANGE_SIGMA_FACTOR
from neural_shdf.shdf.search import nearest_points

#: Default Poisson sample count of ``sample_surface_points``.
DEFAULT_TARGET_SAMPLES = 1024
#: Default nearest samples per vertex when mapping sample values back to the faces.
DEFAULT_INTERPOLATION_NEIGHBOURS = 4


@dataclass(frozen=True)
class SurfaceSamples:
    """Poisson-disk samples of a surface.

    Attributes:
        positions: (N, 3) sample positions (mesh units).
        normals: (N, 3) unit normals of the sampled faces.
        face_ids: (N,) face each sample lies on.
        density: (N,) surface area near the sample / area of a flat disk (zeros unless
            asked for).
        radius: Poisson radius, the length unit of the samples' spacing.
        vertex_samples: (V, k) nearest samples of each mesh vertex
            (k = interpolation neighbours), for mapping values back to the faces.
        vertex_sample_distance: (V, k) their distances.
        vertex_normals: (V, 3) unit area-weighted vertex normals (zero if undefined).
    """

    positions: NDArray[np.float64]
    normals: NDArray[np.float64]
    face_ids: NDArray[np.int64]
    density: NDArray[np.float64]
    radius: float
    vertex_samples: NDArray[np.int64]
    vertex_sample_distance: NDArray[np.float64]
    vertex_normals: NDArray[np.float64]

    @property
    def sample_count(self) -> int:
        return int(len(self.positions))


#: Poisson radius r: sqrt(RADIUS_AREA_FACTOR * area / target) gives about ``target`` samples
#: (random sequential packing covers ~0.55 of the plane with disks of diameter r).
RADIUS_AREA_FACTOR = 0.57

#: Candidates drawn per target sample before the Poisson elimination.
CANDIDATES_PER_SAMPLE = 12

#: Radius (in Poisson radii) of the neighbourhood whose surface area gives the density.
DENSITY_RADIUS = 1.5


def poisson_radius(total_area: float, target_samples: int) -> float:
    """The fixed Poisson-disk radius for a surface of ``total_area``."""
    return math.sqrt(RADIUS_AREA_FACTOR * total_area / max(1, target_samples))


def sample_surface(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    areas: NDArray[Any],
    count: int,
    rng: np.random.Generator,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """``count`` area-uniform random points on the triangles and their face ids.

    The faces are looked up and the points made in the order of the random keys
    (face order: cache-friendly on large meshes), then put back in draw order.
    """
    cumulative = np.cumsum(areas)
    keys = rng.random(count) * cumulative[-1]
    u, v = rng.random(count), rng.random(count)
    order = np.argsort(keys, kind="stable")
    face_ids = np.empty(count, dtype=np.int64)
    face_ids[order] = np.searchsorted(cumulative, keys[order], side="right")
    np.minimum(face_ids, len(faces) - 1, out=face_ids)
    points = np.empty((count, 3))
    _points_on_faces(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
        face_ids,
        u,
        v,
        order,
        points,
    )
    return points, face_ids


@kernel
def _points_on_faces(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    face_ids: NDArray[Any],
    u: NDArray[Any],
    v: NDArray[Any],
    order: NDArray[Any],
    out: NDArray[Any],
) -> None:
    """Point ``i`` at barycentric (u, v) of its face (folded into the triangle when
    u + v > 1), made in the given ``order``."""
    for i in order:
        a, b = u[i], v[i]
        if a + b > 1.0:
            a, b = 1.0 - a, 1.0 - b
        face = faces[face_ids[i]]
        for axis in range(3):
            first = vertices[face[0], axis]
            out[i, axis] = (
                first
                + a * (vertices[face[1], axis] - first)
                + b * (vertices[face[2], axis] - first)
            )


#: Above this many grid cells along an axis, the dart thrower's grid coordinates could
#: lose precision: the conflict-pair computation (same result) is used instead.
_MAX_GRID_CELLS = 2**40


def greedy_disk_selection(points: NDArray[Any], radius: float) -> NDArray[np.int64]:
    """Indices of the points a sequential dart thrower keeps (in index order) for ``radius``.

    Point i is kept iff no kept point j < i lies within ``radius``. The kept points
    sit in a grid of cells of side ``radius / sqrt(3)`` (at most one kept point per
    cell, up to rounding), so each point checks the few kept points of the 5^3 cells
    around it: linear time and memory however densely the candidates pile up (a
    surface repeated in place puts thousands of candidates within one radius).
    """
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    cell_size = radius / math.sqrt(3.0)
    span = float((points.max(axis=0) - points.min(axis=0)).max())
    if not cell_size > 0 or not span / cell_size < _MAX_GRID_CELLS:
        return _conflict_pair_selection(points, radius)
    return _dart_throw(points, radius, cell_size)


def _conflict_pair_selection(points: NDArray[Any], radius: float) -> NDArray[np.int64]:
    """``greedy_disk_selection`` in vectorised rounds over all conflict pairs (memory grows
    with the pairs: only for grids too fine for integer cell coordinates)."""
    n = len(points)
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return np.arange(n, dtype=np.int64)
    low, high = pairs.min(axis=1), pairs.max(axis=1)
    state = np.zeros(n, dtype=np.int8)  # 0 undecided, 1 kept, -1 rejected
    while len(low):
        blocked = np.zeros(n, dtype=bool)
        blocked[high] = True  # has an undecided (or kept) earlier neighbour
        newly_kept = (state == 0) & ~blocked
        state[newly_kept] = 1
        state[high[newly_kept[low]]] = -1
        alive = (state[low] == 0) & (state[high] == 0)
        low, high = low[alive], high[alive]
    state[state == 0] = 1
    return np.flatnonzero(state == 1).astype(np.int64)


@kernel
def _dart_throw(
    points: NDArray[Any], radius: float, cell_size: float
) -> NDArray[np.int64]:  # pragma: no cover - numba
    """Sequential dart throwing over a hash grid; kept points chained per cell."""
    n = points.shape[0]
    squared_radius = radius * radius
    origin = np.empty(3)
    for axis in range(3):
        origin[axis] = points[:, axis].min()
    capacity = 16
    while capacity < 2 * n:
        capacity *= 2
    mask = capacity - 1
    table_cell = np.empty((capacity, 3), dtype=np.int64)
    table_head = np.full(capacity, -1, dtype=np.int64)  # -1: empty slot
    chained = np.full(n, -1, dtype=np.int64)  # next kept point in the same cell
    kept = np.empty(n, dtype=np.int64)
    kept_count = 0
    cell = np.empty(3, dtype=np.int64)
    for i in range(n):
        for axis in range(3):
            cell[axis] = np.int64(math.floor((points[i, axis] - origin[axis]) / cell_size))
        conflict = False
        for dx in range(-2, 3):
            for dy in range(-2, 3):
                for dz in range(-2, 3):
                    x, y, z = cell[0] + dx, cell[1] + dy, cell[2] + dz
                    slot = _cell_hash(x, y, z) & mask
                    while table_head[slot] >= 0:
                        if (
                            table_cell[slot, 0] == x
                            and table_cell[slot, 1] == y
                            and table_cell[slot, 2] == z
                        ):
                            j = table_head[slot]
                            while j >= 0:
                                ex = points[i, 0] - points[j, 0]
                                ey = points[i, 1] - points[j, 1]
                                ez = points[i, 2] - points[j, 2]
                                if ex * ex + ey * ey + ez * ez <= squared_radius:
                                    conflict = True
                                    break
                                j = chained[j]
                            break
                        slot = (slot + 1) & mask
                    if conflict:
                        break
                if conflict:
                    break
            if conflict:
                break
        if conflict:
            continue
        kept[kept_count] = i
        kept_count += 1
        slot = _cell_hash(cell[0], cell[1], cell[2]) & mask
        while table_head[slot] >= 0 and not (
            table_cell[slot, 0] == cell[0]
            and table_cell[slot, 1] == cell[1]
            and table_cell[slot, 2] == cell[2]
        ):
            slot = (slot + 1) & mask
        if table_head[slot] >= 0:
            chained[i] = table_head[slot]
        table_cell[slot, 0], table_cell[slot, 1], table_cell[slot, 2] = cell[0], cell[1], cell[2]
        table_head[slot] = i
    return kept[:kept_count].copy()


@kernel(inline=True)
def _cell_hash(x: int, y: int, z: int) -> np.int64:  # pragma: no cover - numba
    """A mixed 63-bit hash of integer cell coordinates."""
    key = np.uint64(x) * np.uint64(0x9E3779B97F4A7C15)
    key ^= np.uint64(y) * np.uint64(0xC2B2AE3D27D4EB4F) + (key >> np.uint64(29))
    key ^= np.uint64(z) * np.uint64(0x165667B19E3779F9) + (key >> np.uint64(31))
    key ^= key >> np.uint64(32)
    return np.int64(key >> np.uint64(1))


def vertex_normal_sums(
    vertex_count: int, faces: NDArray[Any], normals: NDArray[Any], areas: NDArray[Any]
) -> NDArray[np.float64]:
    """Area-weighted sums of the normals of the faces around each vertex (not unit)."""
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if len(faces) and (faces.min() < 0 or faces.max() >= vertex_count):
        raise IndexError("face vertex index out of range")
    return _vertex_normal_sums(
        vertex_count,
        faces,
        np.ascontiguousarray(normals, dtype=np.float64),
        np.ascontiguousarray(areas, dtype=np.float64),
    )


@kernel
def _vertex_normal_sums(
    vertex_count: int, faces: NDArray[Any], normals: NDArray[Any], areas: NDArray[Any]
) -> NDArray[np.float64]:
    out = np.zeros((vertex_count, 3))
    for face in range(len(faces)):
        for axis in range(3):
            weighted = normals[face, axis] * areas[face]
            for corner in range(3):
                out[faces[face, corner], axis] += weighted
    return out


def unit_rows(vectors: NDArray[Any]) -> NDArray[np.float64]:
    """Rows scaled to unit length; zero rows stay zero."""
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    unit: NDArray[np.float64] = np.divide(
        vectors, length, out=np.zeros_like(vectors), where=length > 0
    )
    return unit


def sample_surface_points(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    target_samples: int = DEFAULT_TARGET_SAMPLES,
    *,
    interpolation_neighbours: int = DEFAULT_INTERPOLATION_NEIGHBOURS,
    seed: int = 0,
    normals: NDArray[Any] | None = None,
    areas: NDArray[Any] | None = None,
    workers: int = 2,
    map_vertices: bool = True,
    normal_sums: NDArray[Any] | None = None,
    density: bool = False,
) -> SurfaceSamples:
    """About ``target_samples`` Poisson-disk samples of a triangle mesh.

    Each sample's normal takes the side of the faces around it (flipped faces);
    ``map_vertices`` finds each vertex's nearest samples (for ``samples_to_faces``);
    ``density`` computes the density (else zeros).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if normals is None or areas is None:
        normals, areas = face_normals(vertices, faces)
    if normal_sums is None:
        normal_sums = vertex_normal_sums(len(vertices), faces, normals, areas)
    total_area = float(areas.sum())
    if not total_area > 0 or not np.isfinite(total_area):
        raise InvalidGeometryError("the mesh has no surface area: every triangle is degenerate")
    rng = np.random.default_rng(seed)
    radius = poisson_radius(total_area, target_samples)
    candidates, candidate_faces = sample_surface(
        vertices, faces, areas, CANDIDATES_PER_SAMPLE * target_samples, rng
    )
    kept = greedy_disk_selection(candidates, radius)
    positions, face_ids = candidates[kept], candidate_faces[kept]
    # A sample on a face whose winding disagrees with its surroundings takes the
    # surroundings' side (flipped faces); on clean meshes this changes nothing.
    sample_normals = normals[face_ids]
    around = normal_sums[faces[face_ids]].sum(axis=1) - 3.0 * (
        normals[face_ids] * areas[face_ids, None]
    )  # the faces around the sample's face, without it
    flip = np.einsum("ij,ij->i", sample_normals, around) < 0
    sample_normals[flip] *= -1.0

    sample_density = np.zeros(len(positions))
    if density:
        near_count = cKDTree(candidates).query_ball_point(
            positions, DENSITY_RADIUS * radius, return_length=True, workers=workers
        )
        flat_count = len(candidates) / total_area * math.pi * (DENSITY_RADIUS * radius) ** 2
        sample_density = np.asarray(near_count, dtype=np.float64) / flat_count
    samples = SurfaceSamples(
        positions=positions,
        normals=sample_normals,
        face_ids=face_ids,
        density=sample_density,
        radius=radius,
        vertex_samples=np.zeros((0, interpolation_neighbours), np.int64),
        vertex_sample_distance=np.zeros((0, interpolation_neighbours)),
        vertex_normals=np.zeros((0, 3)),
    )
    if map_vertices:
        samples = with_vertex_map(samples, vertices, normal_sums, interpolation_neighbours, workers)
    return samples


def with_vertex_map(
    samples: SurfaceSamples,
    vertices: NDArray[Any],
    normal_sums: NDArray[Any],
    interpolation_neighbours: int = DEFAULT_INTERPOLATION_NEIGHBOURS,
    workers: int = 2,
) -> SurfaceSamples:
    """``samples`` with each mesh vertex's ``interpolation_neighbours`` nearest
    samples and unit normal (``normal_sums``: ``vertex_normal_sums``), which
    ``samples_to_faces`` reads."""
    vertex_samples, vertex_distance = nearest_samples(
        samples.positions, vertices, interpolation_neighbours, samples.radius, workers
    )
    return replace(
        samples,
        vertex_samples=vertex_samples,
        vertex_sample_distance=vertex_distance,
        vertex_normals=unit_rows(normal_sums),
    )


def nearest_samples(
    positions: NDArray[Any], points: NDArray[Any], count: int, radius: float, workers: int = 2
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """(P, k) indices of the ``count`` samples (``positions``, Poisson ``radius``)
    nearest to each point (k at most the sample count), nearest first, and their
    distances (``search.nearest_points``)."""
    return nearest_points(positions, points, max(1, count), radius, workers)


def interpolate_samples(
    sample_values: NDArray[Any],
    sample_normals: NDArray[Any],
    neighbours: NDArray[Any],
    distances: NDArray[Any],
    point_normals: NDArray[Any],
    radius: float,
) -> NDArray[np.float32]:
    """Values at points from their nearest samples (``nearest_samples``).

    Inverse-distance weights, times the agreement of the sample's normal with the
    point's: the other side of a thin wall or a facing part does not leak in; a
    point with no agreeing sample takes its nearest sample's value. float32.
    """
    out = np.empty(len(neighbours), dtype=np.float32)
    if len(out):
        _interpolate(
            np.ascontiguousarray(sample_values, dtype=np.float32),
            np.ascontiguousarray(sample_normals, dtype=np.float32),
            np.ascontiguousarray(neighbours, dtype=np.int64),
            np.ascontiguousarray(distances, dtype=np.float32),
            np.ascontiguousarray(point_normals, dtype=np.float32),
            np.float32(0.05 * radius),
            out,
        )
    return out


@kernel
def _interpolate(
    values: NDArray[Any],
    sample_normals: NDArray[Any],
    neighbours: NDArray[Any],
    distances: NDArray[Any],
    normals: NDArray[Any],
    offset: np.float32,
    out: NDArray[Any],
) -> None:
    """``interpolate_samples`` into ``out``, in float32 throughout."""
    zero = np.float32(0.0)
    for point in range(len(out)):
        total = zero
        mixed = zero
        for column in range(neighbours.shape[1]):  # one neighbour rank at a time
            sample = neighbours[point, column]
            agree = (
                sample_normals[sample, 0] * normals[point, 0]
                + sample_normals[sample, 1] * normals[point, 1]
                + sample_normals[sample, 2] * normals[point, 2]
            )
            weight = max(agree, zero) / (distances[point, column] + offset)
            total += weight
            mixed += weight * values[sample]
        out[point] = mixed / total if total > 1e-12 else values[neighbours[point, 0]]


def resample(
    sample_values: NDArray[Any], source: SurfaceSamples, target: SurfaceSamples, neighbours: int
) -> NDArray[np.float64]:
    """Values given at the samples of ``source``, interpolated at the samples of
    ``target`` (another sample set of the same surface) from their ``neighbours``
    nearest source samples, as ``interpolate_samples``."""
    index, distances = nearest_samples(
        source.positions, target.positions, neighbours, source.radius
    )
    return interpolate_samples(
        sample_values, source.normals, index, distances, target.normals, source.radius
    ).astype(np.float64)


def samples_to_faces(
    sample_values: NDArray[Any], graph: SurfaceSamples, faces: NDArray[Any]
) -> NDArray[np.float64]:
    """Per-face values from per-sample values: each vertex interpolates its nearest
    samples (``interpolate_samples``), a face takes the mean of its three vertices."""
    per_vertex = interpolate_samples(
        sample_values,
        graph.normals,
        graph.vertex_samples,
        graph.vertex_sample_distance,
        graph.vertex_normals,
        graph.radius,
    )
    out = np.empty(len(faces))
    _face_means(per_vertex, np.ascontiguousarray(faces, dtype=np.int64), out)
    return out


@kernel
def _face_means(per_vertex: NDArray[Any], faces: NDArray[Any], out: NDArray[Any]) -> None:
    """Mean of each face's three vertex values (summed in float32, as the vertex values)."""
    for face in range(len(faces)):
        total = per_vertex[faces[face, 0]] + per_vertex[faces[face, 1]] + per_vertex[faces[face, 2]]
        out[face] = np.float64(total) / 3.0


#: Samples without a valid hit take the mean of their valid ones among this many nearest.
FILL_NEIGHBOURS = 8


def smooth_samples(
    values: NDArray[Any],
    positions: NDArray[Any],
    normals: NDArray[Any],
    *,
    radius: float,
    spatial_sigma: float,
    range_sigma_factor: float = RANGE_SIGMA_FACTOR,
) -> NDArray[np.float64]:
    """The exact path's bilateral filter at the sample scale: for each sample, the
    samples within ``radius`` (mesh units) whose normals do not oppose its own (the
    other side of a thin wall is not its surface neighbourhood), weighted by a
    Gaussian of their distance (``spatial_sigma``) times a Gaussian of their value
    difference (``range_sigma_factor`` x the window's RMS difference)."""
    values = np.asarray(values, dtype=np.float64)
    if len(values) < 2 or not radius > 0:
        return values.copy()
    tree = cKDTree(positions)
    pairs = tree.query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return values.copy()
    pairs = pairs[np.einsum("ij,ij->i", normals[pairs[:, 0]], normals[pairs[:, 1]]) > 0]
    rows = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(len(values))])
    cols = np.concatenate([pairs[:, 1], pairs[:, 0], np.arange(len(values))])
    offset = positions[rows] - positions[cols]
    squared_distance = np.einsum("ij,ij->i", offset, offset)
    difference = values[cols] - values[rows]
    count = np.bincount(rows, minlength=len(values))
    variance = np.bincount(rows, difference**2, minlength=len(values)) / count
    varies = variance > 0
    scale = 0.5 / (range_sigma_factor**2 * np.where(varies, variance, 1.0))
    weight = np.exp(-0.5 * squared_distance / spatial_sigma**2 - difference**2 * scale[rows])
    total = np.bincount(rows, weight * values[cols], minlength=len(values))
    norm = np.bincount(rows, weight, minlength=len(values))
    return np.where(varies, total / norm, values)


def fill_samples(values: NDArray[Any], positions: NDArray[Any]) -> NDArray[np.float64]:
    """Samples without a value (NaN) take the mean of their valid nearest samples;
    those with none nearby the smallest value; all NaN stays all NaN."""
    values = np.asarray(values, dtype=np.float64).copy()
    missing = np.isnan(values)
    if not missing.any() or missing.all():
        return values
    valid = np.flatnonzero(~missing)
    k = min(FILL_NEIGHBOURS, len(valid))
    _, nearest = cKDTree(positions[valid]).query(positions[missing], k=k)
    values[missing] = values[valid][np.asarray(nearest).reshape(-1, k)].mean(axis=1)
    return values
