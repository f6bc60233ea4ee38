"""Per-face geometry and the face adjacency graph shared by ShDF and segmentation."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from neural_shdf.compiled import kernel
from neural_shdf.constants import AREA_EPS

#: An edge shared by at most ``EDGE_CLIQUE`` faces links every pair of them (T and X
#: junctions); one shared by more links its faces in a chain, in face order, so the
#: graph stays linear in the faces whatever the valence.
EDGE_CLIQUE = 4


def face_normals(
    vertices: NDArray[Any], faces: NDArray[Any], *, area_limit: float | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unit normals (F, 3) and areas (F,) of triangles; degenerate faces get a zero normal.

    ``area_limit``: ``zero_area_limit(vertices, faces)`` where the caller has it.
    ``TriangleMesh.normals_and_areas`` caches this per mesh; call that where a mesh exists.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if area_limit is None:
        area_limit = zero_area_limit(vertices, faces)
    normals = np.empty((len(faces), 3), dtype=np.float64)
    areas = np.empty(len(faces), dtype=np.float64)
    _normals_and_areas(vertices, faces, area_limit, normals, areas)
    return normals, areas


@kernel(inline=True)
def _face_normal(  # pragma: no cover - numba
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    face: int,
    area_eps: float,
    normals: NDArray[np.float64],
) -> float:
    """Face ``face``'s unit normal into ``normals`` (zero when its cross product is at most
    ``area_eps`` long); returns that length, twice the area."""
    a, b, c = faces[face, 0], faces[face, 1], faces[face, 2]
    ux = vertices[b, 0] - vertices[a, 0]
    uy = vertices[b, 1] - vertices[a, 1]
    uz = vertices[b, 2] - vertices[a, 2]
    vx = vertices[c, 0] - vertices[a, 0]
    vy = vertices[c, 1] - vertices[a, 1]
    vz = vertices[c, 2] - vertices[a, 2]
    cx = uy * vz - uz * vy
    cy = uz * vx - ux * vz
    cz = ux * vy - uy * vx
    norm = math.sqrt(cx * cx + cy * cy + cz * cz)
    if norm > area_eps:
        normals[face, 0] = cx / norm
        normals[face, 1] = cy / norm
        normals[face, 2] = cz / norm
    else:
        normals[face, 0] = 0.0
        normals[face, 1] = 0.0
        normals[face, 2] = 0.0
    return norm


def count_zero_rows(normals: NDArray[Any]) -> int:
    """How many rows of ``normals`` (F, 3) are all zero: ``face_normals``' degenerate faces."""
    return int(_count_zero_rows(np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)))


@kernel
def _count_zero_rows(normals: NDArray[np.float64]) -> int:  # pragma: no cover - numba
    count = 0
    for row in range(normals.shape[0]):
        if normals[row, 0] == 0.0 and normals[row, 1] == 0.0 and normals[row, 2] == 0.0:
            count += 1
    return count


def zero_area_limit(vertices: NDArray[Any], faces: NDArray[Any]) -> float:
    """Twice-area at or below which a triangle is degenerate (has no normal):
    ``AREA_EPS`` times the squared diagonal of the triangles' bounding box, so the same
    faces are degenerate at every scale (0 when every corner is one point)."""
    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    return AREA_EPS * _squared_diagonal(vertices, faces)


@kernel
def _squared_diagonal(  # pragma: no cover - numba
    vertices: NDArray[np.float64], faces: NDArray[np.int64]
) -> float:
    """Squared diagonal of the bounding box of the faces' corners (0 for no faces)."""
    if faces.shape[0] == 0:
        return 0.0
    low = vertices[faces[0, 0]].copy()
    high = low.copy()
    for face in range(faces.shape[0]):
        for corner in range(3):
            vertex = faces[face, corner]
            for axis in range(3):
                value = vertices[vertex, axis]
                low[axis] = min(low[axis], value)
                high[axis] = max(high[axis], value)
    squared: float = (high[0] - low[0]) ** 2 + (high[1] - low[1]) ** 2 + (high[2] - low[2]) ** 2
    return squared


@kernel
def _normals_and_areas(  # pragma: no cover - numba
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    area_eps: float,
    normals: NDArray[np.float64],
    areas: NDArray[np.float64],
) -> None:
    """Cross product of two edges per face: its direction the normal, half its length the area."""
    for face in range(faces.shape[0]):
        areas[face] = 0.5 * _face_normal(vertices, faces, face, area_eps, normals)


def face_centroids(vertices: NDArray[Any], faces: NDArray[Any]) -> NDArray[Any]:
    """Centroids (F, 3) of triangles: ``(a + b + c) / 3``, in that order (one pass)."""
    vertices = np.asarray(vertices)
    faces = np.asarray(faces).reshape(-1, 3)
    if vertices.dtype != np.float64 or len(faces) == 0:
        mean: NDArray[Any] = (
            vertices[faces[:, 0]] + vertices[faces[:, 1]] + vertices[faces[:, 2]]
        ) / 3.0
        return mean
    return _face_centroids(
        np.ascontiguousarray(vertices).reshape(-1, 3), np.ascontiguousarray(faces, dtype=np.int64)
    )


def principal_frame(
    points: NDArray[Any], weights: NDArray[Any] | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(weighted mean, principal axes as columns, largest spread first) of (N, 3) points:
    what ``principal_coordinates`` projects on, small enough for a mesh to keep.
    Unit weights where ``weights`` is omitted or sums to zero. From
    ``weighted_moments``: the same bits in whatever order the points come."""
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(points):
        return np.zeros(3), np.eye(3)
    if weights is None or not float(np.sum(weights)) > 0:
        weights = np.ones(len(points))
    mean, second, _ = weighted_moments(
        points, np.ascontiguousarray(weights, dtype=np.float64), False
    )
    _, axes = np.linalg.eigh(second)
    return mean, axes[:, ::-1]


def pose_frame(
    points: NDArray[Any],
    weights: NDArray[Any],
    frame: tuple[NDArray[Any], NDArray[Any]] | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """(origin, rotation, scale) that put the points in a frame of their own, the same in
    any pose and at any scale: ``(points - origin) @ rotation / scale``, from their
    weighted mean, divided by their RMS distance from it, along their principal axes
    (``principal_frame``, or ``frame`` where the caller keeps it) each pointing to the
    side its third moment leans to. A right-handed frame (a rotation: windings keep their
    sense): an axis whose moment does not decide (a mirror-symmetric shape) completes the
    other two. Where the shape fixes no such frame (two spreads within ``POSE_GAP``, or
    fewer than two axes decided), the world's axes: then only the pose's rotation moves
    the frame."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    weights = np.asarray(weights, dtype=np.float64)
    if not len(points):
        return np.zeros(3) if frame is None else np.asarray(frame[0], np.float64), np.eye(3), 1.0
    if not float(np.sum(weights)) > 0:
        weights = np.ones(len(points))
    centre, second_moments, third_moments = weighted_moments(
        np.ascontiguousarray(points), np.ascontiguousarray(weights, dtype=np.float64)
    )
    if frame is None:  # ``principal_frame``'s, from the same moments (one pass, same bits)
        mean, axes = centre, np.linalg.eigh(second_moments)[1][:, ::-1]
    else:
        mean, axes = frame
    mean = np.asarray(mean, dtype=np.float64)
    axes = np.asarray(axes, dtype=np.float64)
    weight = float(np.sum(weights))
    second = np.einsum("ij,ia,ja->a", second_moments, axes, axes) / weight
    third = np.einsum("ijk,ia,ja,ka->a", third_moments, axes, axes, axes) / weight
    total = float(np.sum(second))
    scale = float(np.sqrt(total)) if total > 0 else 1.0
    spreads = np.sort(second)
    if not total > 0 or np.min(np.diff(spreads)) <= POSE_GAP * total:
        return mean, np.eye(3), scale
    lean = np.zeros(3)
    np.divide(third, np.maximum(second, 0.0) ** 1.5, out=lean, where=second > 0)
    decided = np.abs(lean) > POSE_SKEW
    if decided.sum() < 2:
        return mean, np.eye(3), scale
    rotation = np.array(axes, dtype=np.float64, copy=True) * np.where(lean < 0, -1.0, 1.0)
    if not decided.all():  # the undecided axis completes a right-handed frame
        free = int(np.flatnonzero(~decided)[0])
        rotation[:, free] = np.cross(rotation[:, (free + 1) % 3], rotation[:, (free + 2) % 3])
    elif np.linalg.det(rotation) < 0:  # all three decided, a mirror: the weakest gives way
        rotation[:, int(np.argmin(np.abs(lean)))] *= -1.0
    return mean, rotation, scale


def has_own_frame(frame: tuple[NDArray[Any], NDArray[Any], float]) -> bool:
    """Whether a ``pose_frame`` is the shape's own (its axes and their senses decided by
    the shape), not the world's axes that ``pose_frame`` falls back to."""
    return not np.array_equal(frame[1], np.eye(3))


@kernel
def weighted_moments(
    points: NDArray[np.float64], weights: NDArray[np.float64], third_moments: bool = True
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:  # pragma: no cover
    """(weighted centroid (3,), second (3, 3) and, with ``third_moments``, third (3, 3, 3)
    weighted moments of the points about it, summed, not divided by the weights), in
    compiled passes: the orientation pass's sheet skew, ``principal_frame`` and
    ``pose_frame`` read them (numpy's products of an (N, 3) array took 0.14-0.18 s at 1M
    faces).

    Every sum is taken in integers (``_fixed_point``: each term rounded to a power-of-two
    step below its sum's bound), so the same points listed in another order give the
    same bits: a floating-point sum depends on its order, and a frame that moved by a
    rounding would move the coordinates rounded in it (``in_frame``) by a grid step.
    """
    count = points.shape[0]
    bits = _fixed_point_bits(count)
    largest_weight = 0.0
    largest = np.zeros(3)
    for point in range(count):
        largest_weight = max(largest_weight, abs(weights[point]))
        for axis in range(3):
            largest[axis] = max(largest[axis], abs(points[point, axis]))
    weight_step = _fixed_point_step(largest_weight, bits)
    steps = np.empty(3)
    for axis in range(3):
        steps[axis] = _fixed_point_step(largest_weight * largest[axis], bits)
    weight_sum = np.int64(0)
    sums = np.zeros(3, dtype=np.int64)
    for point in range(count):
        w = weights[point]
        weight_sum += _fixed_point(w, weight_step)
        for axis in range(3):
            sums[axis] += _fixed_point(w * points[point, axis], steps[axis])
    weight = float(weight_sum) * weight_step
    centre = np.zeros(3)
    if weight > 0:
        for axis in range(3):
            centre[axis] = float(sums[axis]) * steps[axis] / weight
    for axis in range(3):
        largest[axis] = 0.0
    for point in range(count):
        for axis in range(3):
            largest[axis] = max(largest[axis], abs(points[point, axis] - centre[axis]))
    second_steps = np.empty((3, 3))
    third_steps = np.empty((3, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            second_steps[i, j] = _fixed_point_step(largest_weight * largest[i] * largest[j], bits)
            for k in range(j, 3):
                bound = largest_weight * largest[i] * largest[j] * largest[k]
                third_steps[i, j, k] = _fixed_point_step(bound, bits)
    second_sums = np.zeros((3, 3), dtype=np.int64)
    third_sums = np.zeros((3, 3, 3), dtype=np.int64)
    offset = np.empty(3)
    for point in range(count):
        w = weights[point]
        for axis in range(3):
            offset[axis] = points[point, axis] - centre[axis]
        for i in range(3):
            for j in range(i, 3):
                product = w * offset[i] * offset[j]
                second_sums[i, j] += _fixed_point(product, second_steps[i, j])
                if third_moments:
                    for k in range(j, 3):
                        third_sums[i, j, k] += _fixed_point(
                            product * offset[k], third_steps[i, j, k]
                        )
    second = np.zeros((3, 3))
    third = np.zeros((3, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            second[i, j] = second[j, i] = float(second_sums[i, j]) * second_steps[i, j]
            for k in range(j, 3):
                value = float(third_sums[i, j, k]) * third_steps[i, j, k]
                third[i, j, k] = third[i, k, j] = third[j, i, k] = value
                third[j, k, i] = third[k, i, j] = third[k, j, i] = value
    return centre, second, third


@kernel
def order_free_sum(values: NDArray[np.float64]) -> float:  # pragma: no cover - numba
    """The sum of ``values``, the same bits in whatever order they come (in integers, as
    ``weighted_moments``' sums)."""
    count = len(values)
    bits = _fixed_point_bits(count)
    largest = 0.0
    for value in values:
        largest = max(largest, abs(value))
    step = _fixed_point_step(largest, bits)
    total = np.int64(0)
    for value in values:
        total += _fixed_point(value, step)
    return float(total) * step


@kernel(inline=True)
def _fixed_point_bits(count: int) -> int:  # pragma: no cover - numba
    """Bits per term such that ``count`` terms sum within an int64 (62 bits)."""
    bits = 62
    while bits > 1 and (np.int64(1) << (62 - bits)) <= count:
        bits -= 1
    return bits


@kernel(inline=True)
def _fixed_point_step(bound: float, bits: int) -> float:  # pragma: no cover - numba
    """The power of two that puts terms up to ``bound`` within ``bits`` bits."""
    if not bound > 0 or not bound < math.inf:
        return 1.0
    _, exponent = math.frexp(bound)  # bound < 2**exponent
    return max(math.ldexp(1.0, exponent - bits), 5e-324)


@kernel(inline=True)
def _fixed_point(term: float, step: float) -> np.int64:  # pragma: no cover - numba
    """``term`` in whole ``step``s (nearest; exact scaling by a power of two)."""
    return np.int64(math.floor(term / step + 0.5))


def canonical_triangles(
    vertices: NDArray[Any] | None,
    faces: NDArray[Any],
    head: int | None = None,
    rank: NDArray[Any] | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(triangles, input index of each) in an order set by the corners' positions alone.

    Each triangle starts at its corner of lowest position (x, then y, then z; the
    winding kept), and the triangles are sorted by their corners' positions; the first
    ``head`` triangles (default all) stay before the others. Only triangles at the same
    three positions keep their input order. ``rank``: the vertices' ``position_ranks``
    where the caller has them (then ``vertices`` is not read).
    """
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if not len(faces):
        return faces.copy(), np.zeros(0, dtype=np.int64)
    if rank is None:
        rank = position_ranks(np.asarray(vertices))
    rank = np.ascontiguousarray(rank, dtype=np.int64)
    ranks = int(rank.max()) + 1
    rotated, keys = _turned_to_lowest(faces, rank)
    block = np.zeros(len(faces), dtype=np.int64)
    if head is not None:
        block[head:] = 1
    order = _corner_order(keys, block, ranks)
    return rotated[order], order


@kernel
def _corner_order(
    keys: NDArray[np.int64], block: NDArray[np.int64], ranks: int
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """The stable order of the rows by (block, then the three keys, each below ``ranks``):
    a counting sort by block and first key, then each bucket by the other two (in place
    where few; a stable sort of their combined key otherwise). A quarter of a stable sort
    of one combined key at 1M faces."""
    count = len(keys)
    blocks = 1
    for row in range(count):
        blocks = max(blocks, block[row] + 1)
    start = np.zeros(blocks * ranks + 1, dtype=np.int64)
    for row in range(count):
        start[block[row] * ranks + keys[row, 0] + 1] += 1
    for bucket in range(blocks * ranks):
        start[bucket + 1] += start[bucket]
    fill = start[:-1].copy()
    order = np.empty(count, dtype=np.int64)
    for row in range(count):
        bucket = block[row] * ranks + keys[row, 0]
        order[fill[bucket]] = row
        fill[bucket] += 1
    for bucket in range(blocks * ranks):
        first, end = start[bucket], start[bucket + 1]
        if end - first > 32:
            rows = order[first:end].copy()
            combined = keys[rows, 1] * ranks + keys[rows, 2]
            order[first:end] = rows[np.argsort(combined, kind="mergesort")]
            continue
        for i in range(first + 1, end):
            row = order[i]
            j = i - 1
            while j >= first and (
                keys[order[j], 1] > keys[row, 1]
                or (keys[order[j], 1] == keys[row, 1] and keys[order[j], 2] > keys[row, 2])
            ):
                order[j + 1] = order[j]
                j -= 1
            order[j + 1] = row
    return order


def position_ranks(vertices: NDArray[Any]) -> NDArray[np.int64]:
    """Rank of each vertex's position in (x, y, z) order; equal positions, equal ranks."""
    return position_order(vertices)[0]


def position_order(vertices: NDArray[Any]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(``position_ranks``, the vertices in (x, y, z) order: ranks ascending)."""
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    by_x = np.argsort(vertices[:, 0], kind="stable")
    if not _ties_sorted(vertices, by_x, TIED_RUN):  # long runs of one x (CAD): lexsort
        by_x = np.lexsort((vertices[:, 2], vertices[:, 1], vertices[:, 0]))
    ordered = vertices[by_x]
    new_position = np.ones(len(vertices), dtype=np.int64)
    new_position[1:] = np.any(ordered[1:] != ordered[:-1], axis=1)
    rank = np.empty(len(vertices), dtype=np.int64)
    rank[by_x] = np.cumsum(new_position) - 1
    return rank, by_x.astype(np.int64)


#: ``position_ranks``: runs of equal x up to this long are ordered by (y, z) in place (a
#: float32 scan has many, up to ~100 long); a longer one sorts all vertices by (x, y, z).
TIED_RUN = 4096


@kernel
def _ties_sorted(
    vertices: NDArray[np.float64], order: NDArray[np.int64], longest: int
) -> bool:  # pragma: no cover - compiled
    """Order each run of equal x in ``order`` (sorted by x, stable) by (y, z): sorted by y,
    then by insertion; False, leaving the rest as it was, at a run longer than ``longest``."""
    start = 0
    count = len(order)
    while start < count:
        end = start + 1
        while end < count and vertices[order[end], 0] == vertices[order[start], 0]:
            end += 1
        if end - start > longest:
            return False
        if end - start > 16:
            run = order[start:end].copy()
            by_y = np.argsort(vertices[run, 1])
            for i in range(len(run)):
                order[start + i] = run[by_y[i]]
        for i in range(start + 1, end):
            item = order[i]
            j = i - 1
            while j >= start and (
                vertices[order[j], 1] > vertices[item, 1]
                or (
                    vertices[order[j], 1] == vertices[item, 1]
                    and vertices[order[j], 2] > vertices[item, 2]
                )
            ):
                order[j + 1] = order[j]
                j -= 1
            order[j + 1] = item
        start = end
    return True


@kernel
def _turned_to_lowest(
    faces: NDArray[np.int64], rank: NDArray[np.int64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover - compiled
    """(triangles turned to start at their corner of lowest rank, their corners' ranks)."""
    turned = np.empty_like(faces)
    keys = np.empty_like(faces)
    for face in range(len(faces)):
        low = 0
        for corner in range(1, 3):
            if rank[faces[face, corner]] < rank[faces[face, low]]:
                low = corner
        for corner in range(3):
            vertex = faces[face, (low + corner) % 3]
            turned[face, corner] = vertex
            keys[face, corner] = rank[vertex]
    return turned, keys


#: ``in_frame``: coordinates in a pose frame (unit RMS radius) rounded to multiples of
#: 1 / POSE_GRID, so that another pose's rounding (~1e-14 for a mesh far from the origin,
#: and the noise around an exact 0 that float32 would keep) is gone before Embree's float32
#: and the face graph's angles: 2^-40 left 2% of a scan's coordinates a step apart, 2^-32 a
#: few (whose tangents then tipped rays); 2^-24, float32's own step, moved the geometry by
#: as much as float32 does again and tipped rays near a hole's cap. 2^-30: none of it.
POSE_GRID = 2.0**30


def in_frame(
    points: NDArray[Any], frame: tuple[NDArray[Any], NDArray[Any], float], translate: bool = True
) -> NDArray[np.float64]:
    """``(points - origin) @ rotation / scale`` for a ``pose_frame`` (directions, with
    ``translate=False``: only turned), rounded to multiples of 1 / ``POSE_GRID``."""
    origin, rotation, scale = frame
    points = np.asarray(points, dtype=np.float64)
    with threadpool_limits(limits=1, user_api="blas"):  # the same bits on any core count
        framed: NDArray[np.float64] = ((points - origin) if translate else points) @ rotation
    framed *= POSE_GRID / scale if translate else POSE_GRID
    return np.round(framed, out=framed) / POSE_GRID


#: ``pose_frame``: spreads closer than this share of their sum leave the axes to rounding.
POSE_GAP = 1e-3
#: ``pose_frame``: an axis whose third moment over its spread^1.5 is below this has no side.
POSE_SKEW = 1e-6


def principal_coordinates(
    points: NDArray[Any],
    weights: NDArray[Any] | None = None,
    frame: tuple[NDArray[Any], NDArray[Any]] | None = None,
) -> NDArray[np.float64]:
    """(N, 3) coordinates of the points along their own principal axes (largest spread
    first), from their weighted mean: the same in any pose of the points, up to each
    axis's sign (a shape does not define it), so grids over them are laid with
    ``grid_cells``, which ignores the signs. Axes a shape does not define (equal spreads,
    e.g. about a body of revolution's axis) are whatever the eigensolver returns.
    Unit weights where ``weights`` is omitted or sums to zero. ``frame``: the points'
    ``principal_frame`` where the caller keeps it (then ``weights`` is not read).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(points):
        return points.copy()
    mean, axes = principal_frame(points, weights) if frame is None else frame
    offsets = points - mean
    # One BLAS thread: the same bits as several (each row is one thread's), and on a
    # shared machine the threads' hand-offs cost ten times the product (N x 3 by 3 x 3).
    with threadpool_limits(limits=1, user_api="blas"):
        coordinates: NDArray[np.float64] = offsets @ axes
    return coordinates


def grid_cells(coordinates: NDArray[Any], size: float) -> NDArray[np.int64]:
    """(N,) key of each point's cell in a grid of cubes of side ``size`` centred on the
    origin (cell walls at ``(k + 1/2) size``): points share a key when they share a cell,
    and negating an axis of the coordinates gives the same partition of the points."""
    return grid_layout(coordinates, size)[0]


def grid_layout(
    coordinates: NDArray[Any], size: float, margin: int = 0
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """``grid_cells``' keys, with the box's lowest cell and cells per axis, the box grown
    by ``margin`` cells on each side: a cell's neighbour ``(dx, dy, dz)`` within the
    margin has key ``key + (dx * spans[1] + dy) * spans[2] + dz``."""
    coordinates = np.asarray(coordinates, dtype=np.float64).reshape(-1, 3)
    if not len(coordinates):
        return np.zeros(0, dtype=np.int64), np.zeros(3, np.int64), np.ones(3, np.int64)
    return _grid_cells(np.ascontiguousarray(coordinates), float(size), int(margin))


@kernel
def _grid_cells(  # pragma: no cover - compiled
    coordinates: NDArray[np.float64], size: float, margin: int
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """``floor(c / size + 0.5)`` per axis, shifted to start at 0 (less ``margin``), as one
    key per point: two passes (the bounds, then the keys) instead of numpy's (N, 3)
    temporaries."""
    low = np.empty(3, dtype=np.int64)
    high = np.empty(3, dtype=np.int64)
    for axis in range(3):
        cell = np.int64(np.floor(coordinates[0, axis] / size + 0.5))
        low[axis], high[axis] = cell, cell
    for point in range(coordinates.shape[0]):
        for axis in range(3):
            cell = np.int64(np.floor(coordinates[point, axis] / size + 0.5))
            low[axis] = min(low[axis], cell)
            high[axis] = max(high[axis], cell)
    spans = np.empty(3, dtype=np.int64)
    for axis in range(3):
        low[axis] -= margin
        spans[axis] = high[axis] - low[axis] + 1 + margin
    keys = np.empty(coordinates.shape[0], dtype=np.int64)
    for point in range(coordinates.shape[0]):
        x = np.int64(np.floor(coordinates[point, 0] / size + 0.5)) - low[0]
        y = np.int64(np.floor(coordinates[point, 1] / size + 0.5)) - low[1]
        z = np.int64(np.floor(coordinates[point, 2] / size + 0.5)) - low[2]
        keys[point] = (x * spans[1] + y) * spans[2] + z
    return keys, low, spans


@kernel
def _face_centroids(  # pragma: no cover - compiled
    vertices: NDArray[np.float64], faces: NDArray[np.int64]
) -> NDArray[np.float64]:
    centroids = np.empty((len(faces), 3))
    for face in range(len(faces)):
        a, b, c = faces[face, 0], faces[face, 1], faces[face, 2]
        for axis in range(3):
            total = vertices[a, axis] + vertices[b, axis] + vertices[c, axis]
            centroids[face, axis] = total / 3.0
    return centroids


def equivalent_face_count(areas: NDArray[Any]) -> float:
    """How many faces tessellate the surface, counted at the size most of its area has:
    the total area over the area-weighted median face area (half the surface lies in faces
    at most that large). The face count when all faces have one area (0.56-1.1 of it on the
    psb-dev meshes); a mesh split finely in a small region counts as it did before the
    split, where the face count grows with the split. The face count when no face has
    area. Linear: the areas are binned by octave (1/64 of one), and only the bin holding
    the median is sorted (15 ms at 1M faces, a whole sort 60 ms)."""
    areas = np.asarray(areas, dtype=np.float64).reshape(-1)
    total = float(areas.sum())
    if not total > 0:
        return float(len(areas))
    positive = areas[areas > 0]
    octaves = np.log2(positive)
    low = float(octaves.min())
    bins = np.minimum(((octaves - low) * MEDIAN_BINS_PER_OCTAVE).astype(np.int64), 1 << 20)
    held = np.cumsum(np.bincount(bins, weights=positive))
    middle = int(np.searchsorted(held, 0.5 * held[-1]))
    below = float(held[middle - 1]) if middle > 0 else 0.0
    ordered = np.sort(positive[bins == middle])
    within = np.cumsum(ordered) + below
    median = float(ordered[min(int(np.searchsorted(within, 0.5 * held[-1])), len(ordered) - 1)])
    return total / median


#: ``equivalent_face_count``'s bins per doubling of the face area.
MEDIAN_BINS_PER_OCTAVE = 64


@dataclass(frozen=True)
class FaceGraph:
    """Faces that share an edge, with the edge's length and dihedral angle.

    Attributes:
        pairs: (E, 2) int64 face indices, ``pairs[:, 0] < pairs[:, 1]``, sorted.
        edge_vertices: (E, 2) the shared edge's vertex indices.
        edge_length: (E,) length of the shared edge.
        dihedral: (E,) angle between the two face normals in [0, pi] (0 = flat).
        concave: (E,) True where the fold between the faces is concave (a valley).
        face_count: number of faces (graph nodes).
    """

    pairs: NDArray[np.int64]
    edge_vertices: NDArray[np.int64]
    edge_length: NDArray[np.float64]
    dihedral: NDArray[np.float64]
    concave: NDArray[np.bool_]
    face_count: int

    def csr(self, weights: NDArray[Any] | None = None) -> Any:
        """Symmetric scipy CSR adjacency matrix with the given edge weights (default 1)."""
        w = np.ones(len(self.pairs)) if weights is None else np.asarray(weights, dtype=float)
        rows = np.concatenate([self.pairs[:, 0], self.pairs[:, 1]])
        cols = np.concatenate([self.pairs[:, 1], self.pairs[:, 0]])
        n = self.face_count
        return sp.csr_matrix((np.concatenate([w, w]), (rows, cols)), shape=(n, n))


def build_face_graph(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    normals: NDArray[Any] | None = None,
    *,
    edges: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None,
    adjacency: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None,
) -> FaceGraph:
    """Face adjacency over shared edges.

    Works on open, non-manifold and multi-shell meshes; boundary edges link
    nothing. An edge shared by k faces links every pair of them when
    ``k <= EDGE_CLIQUE`` (T and X junctions), else each face to the next in face
    order (a chain of k - 1 links), so the graph stays linear in the faces even when
    thousands of faces share one edge (a shape repeated in place).
    Edges are found by vertex index, so callers that want welding must weld first.
    Two faces that share several edges are linked once, through the edge shared by
    the fewest faces (ties: the lowest vertex pair). ``edges``: ``_sorted_edges`` of
    ``faces`` where the caller has them (``orientation.welded_edges``); ``adjacency``:
    ``face_adjacency(faces)`` where the caller has it (of these faces in any winding).
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    n_faces = len(faces)
    if normals is None:
        normals, _ = face_normals(vertices, faces)
    if n_faces == 0:
        empty = np.zeros((0, 2), dtype=np.int64)
        return FaceGraph(empty, empty, np.zeros(0), np.zeros(0), np.zeros(0, bool), 0)
    _check_indices(faces, len(vertices))
    normals = np.ascontiguousarray(normals, dtype=np.float64).reshape(n_faces, 3)
    pairs, edge_vertices = face_adjacency(faces, edges) if adjacency is None else adjacency
    edge_length, dihedral, concave = _pair_geometry(vertices, faces, normals, pairs, edge_vertices)
    return FaceGraph(pairs, edge_vertices, edge_length, dihedral, concave, n_faces)


def face_adjacency(
    faces: NDArray[Any],
    edges: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None,
    vertices: NDArray[Any] | Callable[[], NDArray[Any]] | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """``(pairs, edge_vertices)`` of ``build_face_graph``: the faces linked over shared
    edges and the edge each link crosses. The same arrays for any winding of the faces
    (the links depend on which vertices a face has, not their order), so they can be
    worked out before the orientation is known. ``edges`` as in ``build_face_graph``.
    With ``vertices``, the faces of an edge of more than ``EDGE_CLIQUE`` are chained in
    their order around the edge (``_fan_order``: each to its neighbours in angle, the
    widest gap left open), the same in any numbering; without, in face order. ``vertices``
    may be a function that makes them, called only where such an edge exists."""
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        empty = np.zeros((0, 2), dtype=np.int64)
        return empty, empty.copy()
    n_vertices = int(faces.max()) + 1
    _check_indices(faces, n_vertices)  # no negative index reaches the kernels
    edge_table, slot = _sorted_edges(faces, n_vertices) if edges is None else edges
    if vertices is not None and _most_faces_on_an_edge(edge_table) > EDGE_CLIQUE:
        positions = vertices() if callable(vertices) else vertices
        edge_table, slot = _fan_order(
            faces,
            edge_table,
            slot,
            np.ascontiguousarray(positions, dtype=np.float64).reshape(-1, 3),
            n_vertices,
            EDGE_CLIQUE,
        )
    return _adjacent_pairs(faces, edge_table, slot, n_vertices, EDGE_CLIQUE)


@kernel
def _most_faces_on_an_edge(edge_table: NDArray[np.int64]) -> int:  # pragma: no cover
    """The most faces any one edge of the sorted ``edge_table`` has."""
    most, run = 0, 0
    for i in range(edge_table.shape[0]):
        run = run + 1 if i > 0 and edge_table[i, 0] == edge_table[i - 1, 0] else 1
        most = max(most, run)
    return most


@kernel
def _fan_order(
    faces: NDArray[np.int64],
    edge_table: NDArray[np.int64],
    slot: NDArray[np.int64],
    vertices: NDArray[np.float64],
    n_vertices: int,
    clique: int,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover - compiled
    """``(edge_table, slot)`` with the faces of each edge of more than ``clique`` listed in
    their cyclic order around the edge, starting after the widest angle between two of
    them; faces with no direction off the edge (collapsed onto it) after them, in face
    order. The input arrays themselves where there is no such edge."""
    edge_count = edge_table.shape[0]
    table, slots = edge_table, slot
    copied = False
    i = 0
    while i < edge_count:
        j = i + 1
        while j < edge_count and edge_table[j, 0] == edge_table[i, 0]:
            j += 1
        if j - i > clique:
            if not copied:
                table, slots = edge_table.copy(), slot.copy()
                copied = True
            lo, hi = edge_table[i, 0] // n_vertices, edge_table[i, 0] % n_vertices
            # The axis from the end of lower position: the sense of the angles (and the
            # order of faces at one angle along it) the same in any vertex numbering.
            tail, head = lo, hi
            for k in range(3):
                if vertices[lo, k] != vertices[hi, k]:
                    if vertices[lo, k] > vertices[hi, k]:
                        tail, head = hi, lo
                    break
            axis = vertices[head] - vertices[tail]
            length = np.sqrt(np.sum(axis * axis))
            axis /= max(length, 1e-300)
            count = j - i
            angle = np.full(count, np.inf)  # no direction: after the others
            reach = np.zeros(count)  # distance of the face's off-edge vertex from the edge
            off_of = np.full(count, -1)
            reference = np.zeros(3)
            has_reference = False
            for k in range(count):
                face = edge_table[i + k, 1]
                off = -1
                for corner in range(3):
                    if faces[face, corner] != lo and faces[face, corner] != hi:
                        off = faces[face, corner]
                if off < 0:
                    continue
                across = vertices[off] - vertices[tail]
                across -= np.sum(across * axis) * axis
                size = np.sqrt(np.sum(across * across))
                if not size > 1e-9 * length:
                    continue
                if not has_reference:
                    reference = across / size
                    has_reference = True
                side = np.cross(axis, reference)
                angle[k] = np.arctan2(np.sum(across * side), np.sum(across * reference))
                # Faces in one half-plane (a fin on a wall): the nearer first, then by
                # position, not by number; angles to 2^-30 so rounding does not split them.
                angle[k] = np.round(angle[k] * 2.0**30) / 2.0**30
                reach[k] = size
                off_of[k] = off
            order = np.argsort(angle, kind="mergesort")
            if count <= FAN_SORT_FACES:
                _sort_fan(order, angle, reach, off_of, vertices)
            turning = 0
            for k in range(count):
                if np.isfinite(angle[k]):
                    turning += 1
            widest, start = -1.0, 0
            for k in range(turning):
                gap = angle[order[(k + 1) % turning]] - angle[order[k]]
                if k == turning - 1:
                    gap += 2.0 * np.pi
                if gap > widest:
                    widest, start = gap, (k + 1) % turning
            for k in range(count):
                at = order[(start + k) % turning] if k < turning else order[k]
                source = i + at
                table[i + k, 0] = edge_table[source, 0]
                table[i + k, 1] = edge_table[source, 1]
                face = edge_table[source, 1]
                for corner in range(3):
                    if slot[3 * face + corner] == source:
                        slots[3 * face + corner] = i + k
        i = j
    return table, slots


#: ``_fan_order``: edges of up to this many faces order faces at one angle by their
#: distance from the edge and their position too (an insertion sort).
FAN_SORT_FACES = 256


@kernel(inline=True)
def _sort_fan(
    order: NDArray[np.int64],
    angle: NDArray[np.float64],
    reach: NDArray[np.float64],
    off_of: NDArray[np.int64],
    vertices: NDArray[np.float64],
) -> None:  # pragma: no cover - compiled
    """``order`` (sorted by angle) re-sorted in place by (angle, reach, off vertex's x, y,
    z); entries without a direction (infinite angle) keep their order at the end."""
    for i in range(1, len(order)):
        item = order[i]
        j = i - 1
        while j >= 0 and _fan_after(order[j], item, angle, reach, off_of, vertices):
            order[j + 1] = order[j]
            j -= 1
        order[j + 1] = item


@kernel(inline=True)
def _fan_after(
    a: int,
    b: int,
    angle: NDArray[np.float64],
    reach: NDArray[np.float64],
    off_of: NDArray[np.int64],
    vertices: NDArray[np.float64],
) -> bool:  # pragma: no cover - compiled
    """Whether entry ``a`` comes after ``b`` around the edge."""
    if angle[a] != angle[b]:
        return bool(angle[a] > angle[b])
    if not np.isfinite(angle[a]):
        return False
    if reach[a] != reach[b]:
        return bool(reach[a] > reach[b])
    for axis in range(3):
        if vertices[off_of[a], axis] != vertices[off_of[b], axis]:
            return bool(vertices[off_of[a], axis] > vertices[off_of[b], axis])
    return False


def _check_indices(faces: NDArray[np.int64], vertex_count: int) -> None:
    """IndexError unless every vertex index is in ``[0, vertex_count)`` (kernels do not check)."""
    if len(faces) and (int(faces.min()) < 0 or int(faces.max()) >= vertex_count):
        raise IndexError(f"face vertex indices must lie in [0, {vertex_count})")


@kernel
def _sorted_edges(  # pragma: no cover - numba
    faces: NDArray[np.int64], n_vertices: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Face edges sorted by undirected key ``lo * n_vertices + hi``, stable (faces ascend).

    Returns ``edge_table`` (E, 2), the key and face of each edge in sorted order,
    and ``slot`` (3F,), the sorted position of edge ``corner`` of face ``f`` at
    ``3 * f + corner`` (-1: dropped, the face repeats a vertex there). A counting
    sort by ``lo``, then each (small) bucket sorted by ``hi``.
    """
    bucket_start = np.zeros(n_vertices + 1, dtype=np.int64)
    for face in range(faces.shape[0]):
        for corner in range(3):
            start, end = faces[face, corner], faces[face, (corner + 1) % 3]
            if start != end:
                bucket_start[min(start, end) + 1] += 1
    for vertex in range(n_vertices):
        bucket_start[vertex + 1] += bucket_start[vertex]
    fill = bucket_start[:-1].copy()
    edge_count = bucket_start[n_vertices]
    edge_key = np.empty(edge_count, dtype=np.int64)
    edge_id = np.empty(edge_count, dtype=np.int64)
    for face in range(faces.shape[0]):
        for corner in range(3):
            start, end = faces[face, corner], faces[face, (corner + 1) % 3]
            if start != end:
                lo = min(start, end)
                edge_key[fill[lo]] = lo * n_vertices + max(start, end)
                edge_id[fill[lo]] = 3 * face + corner
                fill[lo] += 1
    _sort_buckets(bucket_start, edge_key, edge_id)
    edge_table = np.empty((edge_count, 2), dtype=np.int64)
    slot = np.full(3 * faces.shape[0], -1, dtype=np.int64)
    for position in range(edge_count):
        edge_table[position, 0] = edge_key[position]
        edge_table[position, 1] = edge_id[position] // 3
        slot[edge_id[position]] = position
    return edge_table, slot


@kernel(inline=True)
def _sort_buckets(  # pragma: no cover - numba
    bucket_start: NDArray[np.int64], key: NDArray[np.int64], payload: NDArray[np.int64]
) -> None:
    """Stable in-place sort of ``key`` (and ``payload`` alongside) within each bucket."""
    for bucket in range(bucket_start.shape[0] - 1):
        first, stop = bucket_start[bucket], bucket_start[bucket + 1]
        if stop - first <= 32:  # insertion sort: stable, fast on the usual 1-10 items
            for i in range(first + 1, stop):
                moving_key, moving_payload = key[i], payload[i]
                j = i
                while j > first and key[j - 1] > moving_key:
                    key[j], payload[j] = key[j - 1], payload[j - 1]
                    j -= 1
                key[j], payload[j] = moving_key, moving_payload
        else:
            order = np.argsort(key[first:stop], kind="mergesort") + first
            key[first:stop] = key[order]
            payload[first:stop] = payload[order]


@kernel
def _adjacent_pairs(  # pragma: no cover - numba
    faces: NDArray[np.int64],
    edge_table: NDArray[np.int64],
    slot: NDArray[np.int64],
    n_vertices: int,
    clique: int,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Face pairs ``a < b`` sharing an edge, sorted, each once, with the edge it shares.

    Along an edge (its group in ``edge_table``, faces ascending) a group of
    ``k <= clique`` faces links every pair, a larger one each face to the next:
    linear in the faces whatever the valence. Face by face, the candidates from its
    three edges are sorted by
    ``(b, group size, edge key)``; a pair met on several edges keeps the edge shared
    by the fewest faces, then the lowest. ``edge_table, slot`` come from ``_sorted_edges``.
    """
    edge_count = edge_table.shape[0]
    group_size = np.empty(edge_count, dtype=np.int32)  # faces on the edge at each position
    upper_bound = 0
    i = 0
    while i < edge_count:
        j = i + 1
        while j < edge_count and edge_table[j, 0] == edge_table[i, 0]:
            j += 1
        group_size[i:j] = j - i
        upper_bound += (j - i) * (j - i - 1) // 2 if j - i <= clique else j - i - 1
        i = j
    pairs = np.empty((upper_bound, 2), dtype=np.int64)
    edge_vertices = np.empty((upper_bound, 2), dtype=np.int64)
    neighbours = np.empty(3 * max(clique - 1, 1), dtype=np.int64)
    rank = np.empty((3 * max(clique - 1, 1), 2), dtype=np.int64)  # group size, edge key
    kept = 0
    for face in range(faces.shape[0]):
        found = 0
        for corner in range(3):
            position = slot[3 * face + corner]
            if position < 0:
                continue
            key = edge_table[position, 0]
            size = group_size[position]
            reach = size - 1 if size <= clique else 1  # every later face, or the next
            # A chain links each face to the next and the previous (the link kept by the
            # lower face of the two: the chain need not run in face order, ``_fan_order``).
            first = position + 1 if size <= clique else max(position - 1, 0)
            for k in range(first, min(position + 1 + reach, edge_count)):
                if k == position:
                    continue
                if edge_table[k, 0] != key:
                    if k > position:
                        break
                    continue
                neighbour = edge_table[k, 1]
                if neighbour <= face:
                    continue
                # Insertion by (neighbour, size, key).
                j = found
                while j > 0 and (
                    neighbours[j - 1] > neighbour
                    or (
                        neighbours[j - 1] == neighbour
                        and (rank[j - 1, 0], rank[j - 1, 1]) > (size, key)
                    )
                ):
                    neighbours[j] = neighbours[j - 1]
                    rank[j, 0], rank[j, 1] = rank[j - 1, 0], rank[j - 1, 1]
                    j -= 1
                neighbours[j] = neighbour
                rank[j, 0], rank[j, 1] = size, key
                found += 1
        for j in range(found):
            if j > 0 and neighbours[j] == neighbours[j - 1]:
                continue
            pairs[kept, 0], pairs[kept, 1] = face, neighbours[j]
            edge_vertices[kept, 0] = rank[j, 1] // n_vertices
            edge_vertices[kept, 1] = rank[j, 1] % n_vertices
            kept += 1
    return pairs[:kept].copy(), edge_vertices[:kept].copy()


@kernel
def _pair_geometry(  # pragma: no cover - numba
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    normals: NDArray[np.float64],
    pairs: NDArray[np.int64],
    edge_vertices: NDArray[np.int64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Shared edge length, dihedral angle and concavity of each face pair."""
    count = pairs.shape[0]
    edge_length = np.empty(count, dtype=np.float64)
    dihedral = np.empty(count, dtype=np.float64)
    concave = np.empty(count, dtype=np.bool_)
    for k in range(count):
        a, b = pairs[k, 0], pairs[k, 1]
        lo, hi = edge_vertices[k, 0], edge_vertices[k, 1]
        cos = normals[a, 0] * normals[b, 0] + normals[a, 1] * normals[b, 1]
        cos += normals[a, 2] * normals[b, 2]
        dihedral[k] = math.acos(min(max(cos, -1.0), 1.0))
        dx = vertices[lo, 0] - vertices[hi, 0]
        dy = vertices[lo, 1] - vertices[hi, 1]
        dz = vertices[lo, 2] - vertices[hi, 2]
        edge_length[k] = math.sqrt(dx * dx + dy * dy + dz * dz)
        # Concave when each face's vertex off the shared edge lies above the other's plane:
        # the two heights over the edge's midpoint summed, so that neither the faces'
        # numbers nor the vertices' decide a fold too flat for its sign to hold.
        height = _height_above(vertices, faces, b, lo, hi, normals, a)
        height += _height_above(vertices, faces, a, lo, hi, normals, b)
        concave[k] = height > 0
    return edge_length, dihedral, concave


@kernel(inline=True)
def _height_above(  # pragma: no cover - numba
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    face: int,
    lo: int,
    hi: int,
    normals: NDArray[np.float64],
    other: int,
) -> float:
    """Height of ``face``'s vertex off the edge (lo, hi) above the plane of ``other``
    through the edge's midpoint."""
    off_edge = -1
    for corner in range(3):
        vertex = faces[face, corner]
        if vertex != lo and vertex != hi and vertex > off_edge:
            off_edge = vertex
    if off_edge < 0:
        off_edge = faces[face, 0]
    height = 0.0
    for axis in range(3):
        middle = 0.5 * (vertices[lo, axis] + vertices[hi, axis])
        height += (vertices[off_edge, axis] - middle) * normals[other, axis]
    return height


def midpoint_subdivide(
    vertices: NDArray[Any], faces: NDArray[Any], passes: int
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """(vertices, faces, input face of each face) after ``passes`` midpoint subdivisions
    (each triangle split into 4, the same piecewise-flat surface)."""
    import trimesh.remesh  # only where meshes are subdivided; the CLI's import stays light

    origin = np.arange(len(faces), dtype=np.int64)
    for _ in range(passes):
        vertices, faces, index = trimesh.remesh.subdivide(vertices, faces, return_index=True)  # type: ignore[no-untyped-call]
        parent = np.empty(len(faces), dtype=np.int64)
        for face, children in index.items():
            parent[children] = face
        origin = origin[parent]
    return (
        np.asarray(vertices, dtype=np.float64),
        np.asarray(faces, dtype=np.int64),
        origin,
    )


def split_region(
    vertices: NDArray[Any], faces: NDArray[Any], region: NDArray[Any], splits: int
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """(vertices, faces, input face of each face) with the faces of ``region`` (a boolean
    mask) split 1-to-``splits``**2 (points at k/splits along each edge, shared by the faces
    on both sides) and every face outside with one split edge fanned from its opposite
    corner into ``splits`` triangles, so no T-junction is left (a face outside with two or
    more split edges joins the region): the same piecewise-flat surface, finely tessellated
    in one place, as a sculpted detail on a coarser body. Winding is kept; faces keep their
    input order (each face's pieces in its place). Edges are matched on coincident
    vertices (``weld_faces``)."""
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    if splits < 1:
        raise ValueError(f"splits must be >= 1, got {splits}")
    inside = np.asarray(region, dtype=bool).reshape(-1).copy()
    if len(inside) != len(faces):
        raise ValueError(f"region has {len(inside)} entries for {len(faces)} faces")
    welded_rows = weld_faces(vertices, faces)
    # Edge ids of each face's sides (a, b), (b, c), (c, a), on the welded vertices.
    ends = np.stack([welded_rows, np.roll(welded_rows, -1, axis=1)], axis=2)
    keys = ends.min(axis=2) * (int(welded_rows.max(initial=0)) + 1) + ends.max(axis=2)
    _, side_edge = np.unique(keys.reshape(-1), return_inverse=True)
    side_edge = side_edge.reshape(-1, 3)
    while True:
        is_split = np.zeros(int(side_edge.max(initial=-1)) + 1, dtype=bool)
        is_split[side_edge[inside].reshape(-1)] = True
        grows = ~inside & (is_split[side_edge].sum(axis=1) >= 2)
        if not grows.any():
            break
        inside |= grows
    split_side = is_split[side_edge]
    welded = welded_rows.tolist()
    points: list[NDArray[np.float64]] = list(vertices)
    index_of: dict[tuple[int, ...], int] = {}

    def point(key: tuple[int, ...], position: NDArray[np.float64]) -> int:
        if key not in index_of:
            index_of[key] = len(points)
            points.append(position)
        return index_of[key]

    def along(a: int, b: int, first: int, last: int) -> list[int]:
        """Vertex ids along the edge from input vertex ``first`` (welded ``a``) to ``last``."""
        low_first = a < b
        start, end = (first, last) if low_first else (last, first)
        ids = [start]
        ids += [
            point(
                (-1, min(a, b), max(a, b), k),
                vertices[start] + k / splits * (vertices[end] - vertices[start]),
            )
            for k in range(1, splits)
        ]
        ids.append(end)
        return ids if low_first else ids[::-1]

    out: list[tuple[int, int, int]] = []
    origin: list[int] = []
    for row, ((a, b, c), (i, j, k)) in enumerate(zip(welded, faces.tolist(), strict=True)):
        if inside[row]:
            ab, ac, bc = along(a, b, i, j), along(a, c, i, k), along(b, c, j, k)

            lattice: dict[tuple[int, int], int] = {}
            for s in range(splits + 1):
                for t in range(splits + 1 - s):
                    if t == 0:
                        lattice[s, t] = ab[s]
                    elif s == 0:
                        lattice[s, t] = ac[t]
                    elif s + t == splits:
                        lattice[s, t] = bc[t]
                    else:
                        offset = s * (vertices[j] - vertices[i]) + t * (vertices[k] - vertices[i])
                        lattice[s, t] = point((row, s, t), vertices[i] + offset / splits)
            for s in range(splits):
                for t in range(splits - s):
                    out.append((lattice[s, t], lattice[s + 1, t], lattice[s, t + 1]))
                    if s + t + 2 <= splits:
                        out.append((lattice[s + 1, t], lattice[s + 1, t + 1], lattice[s, t + 1]))
        else:
            corners, ids = (a, b, c), (i, j, k)
            for side in range(3):
                x, y = corners[side], corners[(side + 1) % 3]
                if split_side[row, side]:
                    apex = ids[(side + 2) % 3]
                    run = along(x, y, ids[side], ids[(side + 1) % 3])
                    out += [(apex, run[n], run[n + 1]) for n in range(splits)]
                    break
            else:
                out.append((i, j, k))
        origin += [row] * (len(out) - len(origin))
    return (
        np.asarray(points, dtype=np.float64).reshape(-1, 3),
        np.asarray(out, dtype=np.int64).reshape(-1, 3),
        np.asarray(origin, dtype=np.int64),
    )


def weld_faces(vertices: NDArray[Any], faces: NDArray[Any]) -> NDArray[np.int64]:
    """Face indices rewritten so that vertices at identical positions share one index.

    Faces keep their order and count; only the adjacency they imply changes
    (an STL triangle soup becomes connected). Each index becomes the lowest
    index of a vertex at the same position (-0.0 equals 0.0). Used for graphs,
    never for output. Where no two vertices coincide: a new view of ``faces`` (as int64),
    not a copy.
    """
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if len(vertices) == 0:
        return faces.view()
    _check_indices(faces.reshape(-1, 3), len(vertices))
    bits = (np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3) + 0.0).view(np.uint64)
    representative, merged = _first_of_equal_rows(bits)
    if not merged:
        return faces.view()
    welded: NDArray[np.int64] = representative[faces]
    return welded


@kernel
def _first_of_equal_rows(
    bits: NDArray[np.uint64],
) -> tuple[NDArray[np.int64], bool]:  # pragma: no cover - numba
    """For each row of ``bits`` (V, 3), the lowest index of an equal row (a hash table);
    and whether any row has an equal row before it."""
    count = bits.shape[0]
    capacity = 16
    while capacity < 2 * count:
        capacity *= 2
    mask = np.uint64(capacity - 1)
    table = np.full(capacity, -1, dtype=np.int64)
    representative = np.empty(count, dtype=np.int64)
    merged = False
    for row in range(count):
        key = bits[row, 0] * np.uint64(0x9E3779B97F4A7C15)
        key ^= bits[row, 1] * np.uint64(0xC2B2AE3D27D4EB4F) + (key >> np.uint64(29))
        key ^= bits[row, 2] * np.uint64(0x165667B19E3779F9) + (key >> np.uint64(31))
        key ^= key >> np.uint64(32)
        key *= np.uint64(0xD6E8FEB86659FD93)
        key ^= key >> np.uint64(32)
        slot = key & mask
        while True:
            other = table[slot]
            if other < 0:
                table[slot] = row
                representative[row] = row
                break
            if (
                bits[other, 0] == bits[row, 0]
                and bits[other, 1] == bits[row, 1]
                and bits[other, 2] == bits[row, 2]
            ):
                representative[row] = other
                merged = True
                break
            slot = (slot + np.uint64(1)) & mask
    return representative, merged


def adjacency_lists(
    pairs: NDArray[Any], node_count: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(indptr, neighbours) of an undirected graph given as edge ``pairs``, CSR-style, in
    one counting pass. With sorted unique pairs (``a < b``, as ``FaceGraph.pairs``) each
    node's neighbours come ascending, the arrays of the symmetric CSR matrix."""
    pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
    indptr, neighbours, _ = _adjacency_lists(pairs, node_count, False)
    return indptr, neighbours


def adjacency_with_edges(
    pairs: NDArray[Any], node_count: int
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """``adjacency_lists`` and, beside each neighbour, the row of ``pairs`` linking them
    (to look up an edge's weight)."""
    pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
    return _adjacency_lists(pairs, node_count, True)


@kernel
def _adjacency_lists(  # pragma: no cover - numba
    pairs: NDArray[np.int64], node_count: int, with_edges: bool
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """A node's smaller neighbours arrive as second members (ascending when the pairs are
    sorted), then its larger ones as first members; ``edge_of`` stays empty unless asked."""
    indptr = np.zeros(node_count + 1, dtype=np.int64)
    for row in range(len(pairs)):
        indptr[pairs[row, 0] + 1] += 1
        indptr[pairs[row, 1] + 1] += 1
    for node in range(node_count):
        indptr[node + 1] += indptr[node]
    fill = indptr[:-1].copy()
    neighbours = np.empty(2 * len(pairs), dtype=np.int64)
    edge_of = np.empty(2 * len(pairs) if with_edges else 0, dtype=np.int64)
    for row in range(len(pairs)):  # smaller neighbours
        larger = pairs[row, 1]
        neighbours[fill[larger]] = pairs[row, 0]
        if with_edges:
            edge_of[fill[larger]] = row
        fill[larger] += 1
    for row in range(len(pairs)):  # then the larger ones
        smaller = pairs[row, 0]
        neighbours[fill[smaller]] = pairs[row, 1]
        if with_edges:
            edge_of[fill[smaller]] = row
        fill[smaller] += 1
    return indptr, neighbours, edge_of
