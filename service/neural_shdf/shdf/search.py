"""Neighbour searches over surface samples, compiled, in time linear in the queries.

* ``nearest_points``: the k nearest of a point set for many query points, on a
  uniform grid walked in growing shells of cells (exact: a shell is only left
  out once the k-th distance lies inside the cells walked);
* ``cone_neighbours``: the sample graph's cone edges, the k nearest samples inside
  each sample's inward cone that face away from it, on a k-d tree whose boxes
  also bound their samples' normals: boxes outside the cone, farther than the
  k-th candidate, or holding only normals that cannot oppose the receiver's are
  never opened.

Both break distance ties by the smaller index, so results do not depend on the
search order, and both split their queries over threads (the kernels release
the GIL; the result does not depend on the thread count).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel

#: The grid's cell side, in units of the ``spacing`` the caller gives (the typical
#: distance between neighbouring points): most queries then end after one shell.
CELL_PER_SPACING = 2.0
#: The grid has at most this many cells per point (a larger cell is used otherwise).
MAX_CELLS_PER_POINT = 8
#: Samples per leaf of the cone search's k-d tree.
LEAF_SIZE = 8
#: Queries per thread block.
QUERIES_PER_BLOCK = 16_384


def _blocks(count: int, workers: int) -> list[tuple[int, int]]:
    """Contiguous (first, last) ranges over ``count`` queries for ``workers`` threads."""
    size = max(1, min(QUERIES_PER_BLOCK, -(-count // max(1, workers))))
    return [(start, min(count, start + size)) for start in range(0, count, size)]


def _run_blocks(function: Callable[[int, int], object], count: int, workers: int) -> None:
    blocks = _blocks(count, workers)
    if workers <= 1 or len(blocks) <= 1:
        for first, last in blocks:
            function(first, last)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(lambda block: function(*block), blocks))


def nearest_points(
    positions: NDArray[Any], queries: NDArray[Any], count: int, spacing: float, workers: int = 2
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """(Q, k) indices of the ``count`` points of ``positions`` nearest to each query
    (k = min(count, number of points)), nearest first, and their distances.

    ``spacing``: the typical distance between neighbouring points (it sizes the grid;
    any positive value gives the same answer, only the time differs).
    """
    positions = np.ascontiguousarray(positions, dtype=np.float64).reshape(-1, 3)
    queries = np.ascontiguousarray(queries, dtype=np.float64).reshape(-1, 3)
    k = max(1, min(count, len(positions)))
    index = np.full((len(queries), k), -1, dtype=np.int64)
    distance = np.full((len(queries), k), np.inf)
    if len(positions) == 0 or len(queries) == 0:
        return index[:, : min(count, len(positions))], distance[:, : min(count, len(positions))]
    origin = positions.min(axis=0)
    extent = positions.max(axis=0) - origin
    cell = float(spacing) * CELL_PER_SPACING if spacing > 0 else 0.0
    if not cell > 0 or not math.isfinite(cell):
        cell = float(extent.max()) or 1.0
    budget = MAX_CELLS_PER_POINT * len(positions) + 64
    while True:
        dims = np.minimum(np.floor(extent / cell), 1 << 20).astype(np.int64) + 1
        if int(np.prod(dims, dtype=np.float64)) <= budget:
            break
        cell *= 1.5
    cells = _cell_of(positions, origin, cell, dims)
    order = np.argsort(cells, kind="stable")
    starts = np.zeros(int(np.prod(dims)) + 1, dtype=np.int64)
    np.cumsum(np.bincount(cells, minlength=len(starts) - 1), out=starts[1:])
    sorted_positions = positions[order]

    def run(first: int, last: int) -> None:
        _grid_nearest(
            queries,
            first,
            last,
            sorted_positions,
            order,
            starts,
            origin,
            cell,
            dims,
            index,
            distance,
        )

    _run_blocks(run, len(queries), workers)
    np.sqrt(distance, out=distance)
    return index, distance


def _cell_of(
    points: NDArray[Any], origin: NDArray[Any], cell: float, dims: NDArray[Any]
) -> NDArray[np.int64]:
    """Linear grid cell of each point (coordinates clamped to the grid)."""
    coordinates = np.floor((points - origin) / cell).astype(np.int64)
    np.clip(coordinates, 0, dims - 1, out=coordinates)
    rows: NDArray[np.int64] = coordinates[:, 0] * dims[1] + coordinates[:, 1]
    cells: NDArray[np.int64] = rows * dims[2] + coordinates[:, 2]
    return cells


@kernel(inline=True)
def _insert(
    best_distance: NDArray[Any],
    best_index: NDArray[Any],
    found: int,
    candidate: int,
    squared: float | np.float32,
) -> int:
    """Insert (squared distance, index) into the sorted top-k lists; new ``found``."""
    k = len(best_distance)
    last = min(found, k - 1)
    if found == k and (
        squared > best_distance[k - 1]
        or (squared == best_distance[k - 1] and candidate > best_index[k - 1])
    ):
        return found
    position = last
    while position > 0 and (
        best_distance[position - 1] > squared
        or (best_distance[position - 1] == squared and best_index[position - 1] > candidate)
    ):
        best_distance[position] = best_distance[position - 1]
        best_index[position] = best_index[position - 1]
        position -= 1
    best_distance[position] = squared
    best_index[position] = candidate
    return min(found + 1, k)


@kernel(inline=True)
def _insert_point(
    queries: NDArray[Any],
    query: int,
    points: NDArray[Any],
    slot: int,
    original: NDArray[Any],
    best_distance: NDArray[Any],
    best_index: NDArray[Any],
    found: int,
) -> int:
    """``_insert`` the sorted point ``slot`` as a neighbour of ``query``."""
    dx = queries[query, 0] - points[slot, 0]
    dy = queries[query, 1] - points[slot, 1]
    dz = queries[query, 2] - points[slot, 2]
    return _insert(best_distance, best_index, found, original[slot], dx * dx + dy * dy + dz * dz)


@kernel
def _grid_nearest(  # noqa: PLR0913
    queries: NDArray[Any],
    first: int,
    last: int,
    points: NDArray[Any],
    original: NDArray[Any],
    starts: NDArray[Any],
    origin: NDArray[Any],
    cell: float,
    dims: NDArray[Any],
    out_index: NDArray[Any],
    out_distance: NDArray[Any],
) -> None:
    """Squared distances and indices of the k nearest points of queries first..last-1."""
    k = out_index.shape[1]
    centre = np.empty(3, dtype=np.int64)
    for query in range(first, last):
        best_distance = out_distance[query]
        best_index = out_index[query]
        found = 0
        for axis in range(3):
            c = np.int64(math.floor((queries[query, axis] - origin[axis]) / cell))
            centre[axis] = min(max(c, 0), dims[axis] - 1)
        shell = 1  # shells 0 and 1 at once: one run of points per column of cells
        low_x, high_x = max(centre[0] - 1, 0), min(centre[0] + 1, dims[0] - 1)
        low_y, high_y = max(centre[1] - 1, 0), min(centre[1] + 1, dims[1] - 1)
        low_z, high_z = max(centre[2] - 1, 0), min(centre[2] + 1, dims[2] - 1)
        for x in range(low_x, high_x + 1):
            for y in range(low_y, high_y + 1):
                column = (x * dims[1] + y) * dims[2]
                for slot in range(starts[column + low_z], starts[column + high_z + 1]):
                    found = _insert_point(
                        queries, query, points, slot, original, best_distance, best_index, found
                    )
        while True:
            if shell > 1:
                low_x, high_x = max(centre[0] - shell, 0), min(centre[0] + shell, dims[0] - 1)
                low_y, high_y = max(centre[1] - shell, 0), min(centre[1] + shell, dims[1] - 1)
                low_z, high_z = max(centre[2] - shell, 0), min(centre[2] + shell, dims[2] - 1)
                for x in range(low_x, high_x + 1):
                    for y in range(low_y, high_y + 1):
                        column = (x * dims[1] + y) * dims[2]
                        if abs(x - centre[0]) == shell or abs(y - centre[1]) == shell:
                            runs = ((low_z, high_z), (1, 0))  # the whole column is new
                        else:  # only the shell's two ends of the column are new
                            runs = (
                                (centre[2] - shell, centre[2] - shell),
                                (centre[2] + shell, centre[2] + shell),
                            )
                        for first_z, last_z in runs:
                            first_z, last_z = max(first_z, low_z), min(last_z, high_z)
                            if first_z > last_z:
                                continue
                            for slot in range(
                                starts[column + first_z], starts[column + last_z + 1]
                            ):
                                found = _insert_point(
                                    queries,
                                    query,
                                    points,
                                    slot,
                                    original,
                                    best_distance,
                                    best_index,
                                    found,
                                )
            # Points not walked yet lie outside the box of shells 0..shell: at least the
            # distance from the query to that box's nearest open side.
            bound = np.inf
            done = True
            for axis in range(3):
                value = queries[query, axis] - origin[axis]
                if centre[axis] - shell > 0:
                    bound = min(bound, value - (centre[axis] - shell) * cell)
                    done = False
                if centre[axis] + shell < dims[axis] - 1:
                    bound = min(bound, (centre[axis] + shell + 1) * cell - value)
                    done = False
            if done or (found == k and best_distance[k - 1] < bound * bound):
                break
            shell += 1


def cone_neighbours(
    positions: NDArray[Any],
    normals: NDArray[Any],
    count: int,
    cone_cos: float,
    radius: float,
    workers: int = 2,
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(senders, receivers) of the cone edges: for each receiver (in order), up to
    ``count`` nearest samples (nearest first, ties by index) that

    * lie in its inward cone (axis minus the normal, half angle ``acos(cone_cos)``)
      whose apex sits ``radius / tan(half angle)`` behind the sample, i.e. depth > 0
      and lateral distance <= depth x tan(half angle) + ``radius``;
    * face away from it (the offset to them along their own normal is positive);
    * have a normal turned by more than the half angle from its own (dot <= ``cone_cos``).

    Distances and tests in float32, as the dense scan this replaces computed them.
    """
    n = len(positions)
    if count <= 0 or n < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    k = min(count, n - 1)
    pos = np.ascontiguousarray(positions, dtype=np.float32)
    nrm = np.ascontiguousarray(normals, dtype=np.float32)
    tan_half = math.sqrt(max(1.0 - cone_cos**2, 0.0)) / max(cone_cos, 1e-6)
    order, node_start, node_end, children, box, normal_box = _kd_tree(
        pos.astype(np.float64), nrm.astype(np.float64)
    )
    senders = np.full((n, k), -1, dtype=np.int64)
    scores = np.full((n, k), np.inf, dtype=np.float32)

    def run(first: int, last: int) -> None:
        _cone_search(
            first,
            last,
            pos,
            nrm,
            order,
            node_start,
            node_end,
            children,
            box,
            normal_box,
            np.float32(tan_half),
            np.float32(radius),
            np.float32(cone_cos),
            math.atan(tan_half),
            senders,
            scores,
        )

    _run_blocks(run, n, workers)
    valid = senders >= 0
    receivers = np.repeat(np.arange(n, dtype=np.int64), k).reshape(n, k)
    return senders[valid], receivers[valid]


def _kd_tree(positions: NDArray[Any], normals: NDArray[Any]) -> tuple[NDArray[Any], ...]:
    """A k-d tree over the points (median splits on the widest axis, ``LEAF_SIZE`` per
    leaf): the point order, each node's range of it, children (-1 for leaves), the box
    of its positions (low xyz, high xyz) and the box of its normals."""
    return _build_kd_tree(positions, normals, LEAF_SIZE)


@kernel
def _build_kd_tree(
    positions: NDArray[Any], normals: NDArray[Any], leaf_size: int
) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any], NDArray[Any]]:
    n = len(positions)
    capacity = 2 * (n // max(1, leaf_size) + 1) * 2 + 1
    order = np.arange(n)
    node_start = np.empty(capacity, dtype=np.int64)
    node_end = np.empty(capacity, dtype=np.int64)
    children = np.full((capacity, 2), -1, dtype=np.int64)
    box = np.empty((capacity, 6))
    normal_box = np.empty((capacity, 6))
    stack = np.empty(capacity, dtype=np.int64)
    node_start[0], node_end[0] = 0, n
    nodes = 1
    stack[0] = 0
    depth = 1
    while depth > 0:
        depth -= 1
        node = stack[depth]
        start, end = node_start[node], node_end[node]
        for axis in range(3):
            box[node, axis] = np.inf
            box[node, 3 + axis] = -np.inf
            normal_box[node, axis] = np.inf
            normal_box[node, 3 + axis] = -np.inf
        for slot in range(start, end):
            point = order[slot]
            for axis in range(3):
                box[node, axis] = min(box[node, axis], positions[point, axis])
                box[node, 3 + axis] = max(box[node, 3 + axis], positions[point, axis])
                normal_box[node, axis] = min(normal_box[node, axis], normals[point, axis])
                normal_box[node, 3 + axis] = max(normal_box[node, 3 + axis], normals[point, axis])
        if end - start <= leaf_size:
            continue
        widest = 0
        for axis in range(1, 3):
            if box[node, 3 + axis] - box[node, axis] > box[node, 3 + widest] - box[node, widest]:
                widest = axis
        members = order[start:end]
        ranked = members[np.argsort(positions[members, widest], kind="mergesort")]
        order[start:end] = ranked
        middle = start + (end - start) // 2
        for side, (first, last) in enumerate(((start, middle), (middle, end))):
            child = nodes
            nodes += 1
            node_start[child], node_end[child] = first, last
            children[node, side] = child
            stack[depth] = child
            depth += 1
    return (
        order,
        node_start[:nodes].copy(),
        node_end[:nodes].copy(),
        children[:nodes].copy(),
        box[:nodes].copy(),
        normal_box[:nodes].copy(),
    )


@kernel(inline=True)
def _cone_accepts(
    pos: NDArray[Any],
    nrm: NDArray[Any],
    receiver: int,
    sender: int,
    tan_half: float | np.float32,
    radius: float | np.float32,
    cone_cos: float | np.float32,
) -> np.float32:
    """Squared distance (float32) if ``sender`` is a cone neighbour of ``receiver``, else -1."""
    ox = pos[sender, 0] - pos[receiver, 0]
    oy = pos[sender, 1] - pos[receiver, 1]
    oz = pos[sender, 2] - pos[receiver, 2]
    squared: np.float32 = ox * ox + oy * oy + oz * oz
    depth = -(ox * nrm[receiver, 0] + oy * nrm[receiver, 1] + oz * nrm[receiver, 2])
    if not depth > 0:
        return np.float32(-1.0)
    lateral = np.sqrt(max(squared - depth * depth, np.float32(0.0)))
    if not lateral <= depth * tan_half + radius:
        return np.float32(-1.0)
    if not ox * nrm[sender, 0] + oy * nrm[sender, 1] + oz * nrm[sender, 2] > 0:
        return np.float32(-1.0)
    turned = (
        nrm[receiver, 0] * nrm[sender, 0]
        + nrm[receiver, 1] * nrm[sender, 1]
        + nrm[receiver, 2] * nrm[sender, 2]
    )
    if not turned <= cone_cos:
        return np.float32(-1.0)
    return squared


@kernel(inline=True)
def _box_gap(box: NDArray[Any], node: int, point: NDArray[Any]) -> float:
    """Squared distance from ``point`` to the box of ``node`` (0 inside)."""
    gap = 0.0
    for axis in range(3):
        below = box[node, axis] - point[axis]
        above = point[axis] - box[node, 3 + axis]
        if below > 0:
            gap += below * below
        elif above > 0:
            gap += above * above
    return gap


@kernel
def _cone_search(  # noqa: PLR0913
    first: int,
    last: int,
    pos: NDArray[Any],
    nrm: NDArray[Any],
    order: NDArray[Any],
    node_start: NDArray[Any],
    node_end: NDArray[Any],
    children: NDArray[Any],
    box: NDArray[Any],
    normal_box: NDArray[Any],
    tan_half: float | np.float32,
    radius: float | np.float32,
    cone_cos: float | np.float32,
    half_angle: float,
    senders: NDArray[Any],
    scores: NDArray[Any],
) -> None:
    """Cone neighbours of receivers first..last-1, depth first, nearer child first."""
    k = senders.shape[1]
    stack = np.empty(2 * len(node_start) + 2, dtype=np.int64)
    slack = 1e-4  # the tests below are in float64; the exact ones in float32
    sin_half, cos_half = math.sin(half_angle), math.cos(half_angle)
    apex_back = float(radius) / max(float(tan_half), 1e-12)
    point = np.empty(3)
    for receiver in range(first, last):
        best = scores[receiver]
        best_index = senders[receiver]
        found = 0
        for axis in range(3):
            point[axis] = pos[receiver, axis]
        px, py, pz = point[0], point[1], point[2]
        ux, uy, uz = -float(nrm[receiver, 0]), -float(nrm[receiver, 1]), -float(nrm[receiver, 2])
        length = math.sqrt(ux * ux + uy * uy + uz * uz)
        top = 1
        stack[0] = 0
        while top > 0:
            top -= 1
            node = stack[top]
            # Nearest point of the box: farther than the k-th candidate -> skip.
            gap = _box_gap(box, node, point)
            if found == k and gap > float(best[k - 1]) * (1.0 + slack) + 1e-30:
                continue
            # No normal of the box can turn far enough from the receiver's -> skip.
            lowest = 0.0
            for axis in range(3):
                value = float(nrm[receiver, axis])
                lowest += min(value * normal_box[node, axis], value * normal_box[node, 3 + axis])
            if lowest > float(cone_cos) + slack:
                continue
            # The box's bounding sphere lies outside the cone (or behind the sample) -> skip.
            cx = 0.5 * (box[node, 0] + box[node, 3])
            cy = 0.5 * (box[node, 1] + box[node, 4])
            cz = 0.5 * (box[node, 2] + box[node, 5])
            sphere = 0.5 * math.sqrt(
                (box[node, 3] - box[node, 0]) ** 2
                + (box[node, 4] - box[node, 1]) ** 2
                + (box[node, 5] - box[node, 2]) ** 2
            )
            margin = sphere + slack * (sphere + apex_back + abs(px) + abs(py) + abs(pz))
            if length > 0:
                vx, vy, vz = cx - px, cy - py, cz - pz
                depth = (vx * ux + vy * uy + vz * uz) / length
                if depth + margin <= 0:
                    continue
                along = depth + apex_back
                lateral = math.sqrt(max(vx * vx + vy * vy + vz * vz - depth * depth, 0.0))
                if lateral * cos_half - along * sin_half > margin:
                    continue
            if children[node, 0] < 0:
                for slot in range(node_start[node], node_end[node]):
                    sender = order[slot]
                    if sender == receiver:
                        continue
                    squared = _cone_accepts(pos, nrm, receiver, sender, tan_half, radius, cone_cos)
                    if squared >= 0:
                        found = _insert(best, best_index, found, sender, squared)
                continue
            # Push the farther child first: the nearer one is opened next.
            a, b = children[node, 0], children[node, 1]
            if _box_gap(box, a, point) <= _box_gap(box, b, point):
                stack[top] = b
                stack[top + 1] = a
            else:
                stack[top] = a
                stack[top + 1] = b
            top += 2
