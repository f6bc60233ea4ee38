"""ShDF post-processing shared by the exact and the neural ShDF (CGAL's ``sdf_values`` defaults).

Raw per-face diameters -> fill faces without a value from their neighbours ->
one bilateral smoothing pass over the face graph -> linear normalisation to
[0, 1]. A pure function of the raw values and the face graph.
"""

from __future__ import annotations

import functools
import math
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.errors import ParameterError
from neural_shdf.geometry import FaceGraph, adjacency_lists, order_free_sum

#: CGAL's ``CGAL_NORMALIZATION_ALPHA``: strength of the log normalisation.
LOG_NORMALIZATION_ALPHA = 5.0
#: Range sigma of the bilateral filter, in standard deviations of the window's values.
RANGE_SIGMA_FACTOR = 1.5
#: Spatial sigma of the bilateral filter, as a fraction of the window size (in rings).
SPATIAL_SIGMA_FACTOR = 0.5
#: Face pairs handled at once by the bilateral filter (bounds its memory).
PAIRS_PER_CHUNK = 4_000_000
#: Windows up to this many rings are filtered face by face (exactly as CGAL); wider ones
#: (meshes above ~100k faces) on patches of faces (``patch_bilateral``), whose cost does
#: not grow with the window.
EXACT_WINDOW_MAX = 8
#: Patch radius in edge rings, as a fraction of the window (wider windows, wider patches).
PATCH_RADIUS_FACTOR = 0.2
#: Straight distance from a face to the faces k edge rings away, per ring, in units of the
#: mean distance between adjacent centroids: a least-squares fit over psb-dev and dense-dev
#: meshes' windows (breadth-first rings zigzag; docs/benchmarks.md).
RING_PER_SPACING = 0.82
#: Blocks of faces the compiled filter is split into when progress is reported.
PROGRESS_BLOCKS = 100
#: Time of the face-by-face bilateral filter per face and window pair, relative to casting
#: one face's rays (measured on spheres, docs/benchmarks.md); it sets how much of the exact
#: ShDF's progress the post-processing reports.
FILTER_COST_PER_PAIR = 0.0015

Progress = Callable[[float], None]


def bilateral_window(face_count: int) -> int:
    """CGAL's window (in edge rings) for ``face_count`` faces: ``floor(sqrt(F / 2000)) + 1``."""
    return int(math.sqrt(face_count / 2000.0)) + 1


def fill_missing(values: NDArray[Any], graph: FaceGraph) -> NDArray[np.float64]:
    """Faces with NaN take the mean of their valued neighbours, ring by ring outward from the
    measured faces: each ring from the values before it, so the result does not depend on
    the order of the faces (CGAL fills in face order, a face filled earlier counting for
    later ones). Faces no ring reaches (no measured face in their component) get the
    smallest measured value; all NaN (nothing measured) gives all zeros.
    """
    out = np.asarray(values, dtype=np.float64).copy()
    missing = np.isnan(out)
    if not missing.any():
        return out
    if missing.all():
        return np.zeros_like(out)
    indptr, neighbours = adjacency_lists(graph.pairs, graph.face_count)
    return _fill_rings(out, indptr, neighbours, float(np.nanmin(out)))


@kernel
def _fill_rings(
    out: NDArray[np.float64], indptr: NDArray[np.int64], neighbours: NDArray[np.int64], floor: float
) -> NDArray[np.float64]:  # pragma: no cover - numba
    """``fill_missing`` in place on ``out``: rings of missing faces next to valued ones."""
    count = len(out)
    valued = ~np.isnan(out)
    queued = np.zeros(count, dtype=np.bool_)
    ring = np.empty(count, dtype=np.int64)
    size = 0
    for face in range(count):
        if not valued[face]:
            for j in range(indptr[face], indptr[face + 1]):
                if valued[neighbours[j]]:
                    ring[size] = face
                    queued[face] = True
                    size += 1
                    break
    fill = np.empty(count)
    following = np.empty(count, dtype=np.int64)
    while size:
        for k in range(size):
            face = ring[k]
            total, n = 0.0, 0
            for j in range(indptr[face], indptr[face + 1]):
                if valued[neighbours[j]]:
                    total += out[neighbours[j]]
                    n += 1
            fill[k] = total / n
        for k in range(size):
            out[ring[k]] = fill[k]
            valued[ring[k]] = True
        next_size = 0
        for k in range(size):
            for j in range(indptr[ring[k]], indptr[ring[k] + 1]):
                other = neighbours[j]
                if not valued[other] and not queued[other]:
                    queued[other] = True
                    following[next_size] = other
                    next_size += 1
        ring[:next_size] = following[:next_size]
        size = next_size
    for face in range(count):
        if not valued[face]:
            out[face] = floor
    return out


def _window_pairs(
    adjacency: sp.csr_matrix, rows: NDArray[Any], window: int
) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """(row position in ``rows``, face, ring) for every face within ``window`` edge rings.

    Breadth-first, all rows at once: ring k+1 is the neighbours of ring k minus
    rings k and k-1 (in a graph, neighbours of ring k lie in rings k-1..k+1).
    """
    shape = (len(rows), adjacency.shape[0])
    local = np.arange(len(rows))
    current = sp.csr_matrix((np.ones(len(rows)), (local, rows)), shape=shape)
    previous = sp.csr_matrix(shape)
    out_rows, out_faces, out_rings = [local], [rows], [np.zeros(len(rows), dtype=np.int8)]
    for ring in range(1, window + 1):
        reached = current @ adjacency
        reached.data[:] = 1.0
        new = reached - reached.multiply(current + previous)
        new.eliminate_zeros()
        if new.nnz == 0:
            break
        out_rows.append(np.repeat(local, np.diff(new.indptr)))
        out_faces.append(new.indices)
        out_rings.append(np.full(new.nnz, ring, dtype=np.int8))
        previous, current = current, new
    return np.concatenate(out_rows), np.concatenate(out_faces), np.concatenate(out_rings)


def _bilateral_vectorised(
    values: NDArray[Any],
    adjacency: sp.csr_matrix,
    window_size: int,
    spatial_weight: NDArray[Any],
    range_sigma_factor: float,
) -> NDArray[np.float64]:
    """The filter with numpy/scipy only: all (face, window face) pairs, in row chunks."""
    face_count = len(values)
    pairs_per_face = 1 + 3 * window_size * (window_size + 1) // 2
    chunk = max(1024, PAIRS_PER_CHUNK // pairs_per_face)
    out = np.empty(face_count)
    for start in range(0, face_count, chunk):
        rows = np.arange(start, min(start + chunk, face_count))
        local, neighbour, ring = _window_pairs(adjacency, rows, window_size)
        centre = values[rows]
        neighbour_value = np.take(values, neighbour)
        squared = neighbour_value - np.take(centre, local)
        np.square(squared, out=squared)
        count = np.bincount(local, minlength=len(rows))
        variance = np.bincount(local, squared, minlength=len(rows)) / count
        # exp(-0.5 (d / (factor * deviation))^2) = exp(-d^2 * scale) per row.
        varies = variance > 0
        scale = 0.5 / (range_sigma_factor**2 * np.where(varies, variance, 1.0))
        squared *= np.take(scale, local)
        weight = np.exp(np.negative(squared, out=squared), out=squared)
        weight *= np.take(spatial_weight, ring)
        total = np.bincount(local, weight * neighbour_value, minlength=len(rows))
        norm = np.bincount(local, weight, minlength=len(rows))
        out[rows] = np.where(varies, total / norm, centre)
    return out


@kernel(inline=True)
def _grow_rings(
    tail: int,
    max_ring: int,
    indptr: NDArray[Any],
    indices: NDArray[Any],
    seen: NDArray[Any],
    mark: Any,
    queue: NDArray[Any],
    ring: NDArray[Any],
) -> int:
    """Breadth-first walk from the ``tail`` nodes already in ``queue`` (their rings in
    ``ring``, each marked ``seen[node] == mark``) up to ``max_ring`` edge rings: appends
    the nodes reached with their rings, marks them, and returns the new count."""
    head = 0
    while head < tail:
        current, level = queue[head], ring[head]
        head += 1
        if level == max_ring:
            continue
        for edge in range(indptr[current], indptr[current + 1]):
            other = indices[edge]
            if seen[other] != mark:
                seen[other] = mark
                queue[tail] = other
                ring[tail] = level + 1
                tail += 1
    return tail


@kernel(inline=True)
def _walk_rings(
    start: int,
    max_ring: int,
    indptr: NDArray[Any],
    indices: NDArray[Any],
    seen_by: NDArray[Any],
    queue: NDArray[Any],
    ring: NDArray[Any],
) -> int:
    """Breadth-first walk from ``start`` up to ``max_ring`` edge rings: fills ``queue`` with
    the nodes reached (``start`` first) and ``ring`` with their rings; returns their count.
    ``seen_by[node] == start`` marks a node reached by this walk (no clearing between walks)."""
    queue[0] = start
    ring[0] = 0
    seen_by[start] = start
    return _grow_rings(1, max_ring, indptr, indices, seen_by, start, queue, ring)


def _bilateral_faces(
    first: int,
    last: int,
    indptr: NDArray[Any],
    indices: NDArray[Any],
    values: NDArray[Any],
    window_size: int,
    spatial_weight: NDArray[Any],
    range_sigma_factor: float,
    out: NDArray[Any],
) -> None:
    """The filter for faces ``first..last-1``, one breadth-first walk per face (compiled)."""
    face_count = len(values)
    seen_by = np.full(face_count, -1, dtype=np.int64)
    queue = np.empty(face_count, dtype=np.int64)
    ring = np.empty(face_count, dtype=np.int64)
    for face in range(first, last):
        tail = _walk_rings(face, window_size, indptr, indices, seen_by, queue, ring)
        centre = values[face]
        variance = 0.0
        for i in range(tail):
            difference = values[queue[i]] - centre
            variance += difference * difference
        variance /= tail
        if variance == 0.0:
            out[face] = centre
            continue
        scale = 0.5 / (range_sigma_factor * range_sigma_factor * variance)
        total = 0.0
        norm = 0.0
        for i in range(tail):
            value = values[queue[i]]
            difference = value - centre
            weight = spatial_weight[ring[i]] * math.exp(-difference * difference * scale)
            total += weight * value
            norm += weight
        out[face] = total / norm


_bilateral_faces = kernel(_bilateral_faces)


def bilateral_smooth(
    values: NDArray[Any],
    graph: FaceGraph,
    *,
    window_size: int,
    spatial_sigma: float | None = None,
    range_sigma_factor: float = RANGE_SIGMA_FACTOR,
    compiled: bool = True,
    threads: int | None = None,
    progress: Progress | None = None,
) -> NDArray[np.float64]:
    """One pass of CGAL's bilateral filter over faces within ``window_size`` edge rings.

    Weight of a neighbour = Gaussian of its ring distance (sigma
    ``spatial_sigma``, default ``window_size / 2``) times Gaussian of its value
    difference (sigma ``range_sigma_factor`` x the RMS difference over the
    window, the face itself included). Faces whose window has no variation keep
    their value. ``compiled`` uses the numba kernel
    (same result to rounding; the numpy path is several times slower), in
    ``threads`` threads (default one per CPU; the result does not depend on it).
    ``progress`` is called with the fraction of faces done (compiled path).
    """
    values = np.asarray(values, dtype=np.float64)
    if window_size < 0:
        raise ParameterError(f"window_size must be >= 0, got {window_size}")
    face_count = len(values)
    if face_count == 0 or window_size == 0:
        return values.copy()
    spatial = window_size * SPATIAL_SIGMA_FACTOR if spatial_sigma is None else spatial_sigma
    spatial_weight = np.exp(-0.5 * (np.arange(window_size + 1) / spatial) ** 2)
    adjacency = graph.csr()
    adjacency.data[:] = 1.0
    if compiled:
        # Python threads over blocks of faces (the kernel releases the GIL); numba's
        # own parallel layer is avoided because it is not safe under concurrent callers.
        out = np.empty(face_count)
        indptr = adjacency.indptr.astype(np.int64)
        indices = adjacency.indices.astype(np.int64)
        workers = max(1, os.cpu_count() or 1) if threads is None else max(1, threads)
        blocks = min(max(4 * workers, PROGRESS_BLOCKS if progress else 0), face_count)
        bounds = np.linspace(0, face_count, blocks + 1).astype(int)

        def run(block: int) -> None:
            _bilateral_faces(
                bounds[block],
                bounds[block + 1],
                indptr,
                indices,
                values,
                int(window_size),
                spatial_weight,
                float(range_sigma_factor),
                out,
            )

        with ThreadPoolExecutor(max_workers=workers) as pool:
            for done, _ in enumerate(pool.map(run, range(blocks)), start=1):
                if progress is not None:
                    progress(done / blocks)
        return out
    return _bilateral_vectorised(values, adjacency, window_size, spatial_weight, range_sigma_factor)


def sorted_adjacency(graph: FaceGraph) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(indptr, indices) of the face graph, each face's neighbours ascending: the arrays of
    ``graph.csr()``, in one counting pass over the sorted unique pairs."""
    return adjacency_lists(graph.pairs, graph.face_count)


@kernel
def _cover_with_patches(
    indptr: NDArray[Any], indices: NDArray[Any], radius: int
) -> NDArray[np.int64]:
    """Patch id per face: seeds at least ``2 radius`` edge rings apart (greedy, in face
    order: a face becomes a seed unless an earlier seed lies closer), then every face
    joins its nearest seed (multi-source breadth-first walk; ties: the earlier seed)."""
    face_count = len(indptr) - 1
    seen_by = np.full(face_count, -1, dtype=np.int64)
    queue = np.empty(face_count, dtype=np.int64)
    ring = np.empty(face_count, dtype=np.int64)
    seeds = np.empty(face_count, dtype=np.int64)
    seed_count = 0
    covered = np.zeros(face_count, dtype=np.bool_)
    for face in range(face_count):
        if covered[face]:
            continue
        seeds[seed_count] = face
        seed_count += 1
        tail = _walk_rings(face, 2 * radius - 1, indptr, indices, seen_by, queue, ring)
        for i in range(tail):
            covered[queue[i]] = True
    patch_of = np.full(face_count, -1, dtype=np.int64)
    for patch in range(seed_count):
        patch_of[seeds[patch]] = patch
        queue[patch] = seeds[patch]
    head, tail = 0, seed_count
    while head < tail:
        current = queue[head]
        head += 1
        for edge in range(indptr[current], indptr[current + 1]):
            other = indices[edge]
            if patch_of[other] < 0:
                patch_of[other] = patch_of[current]
                queue[tail] = other
                tail += 1
    return patch_of


@kernel
def _patch_windows(
    indptr: NDArray[Any], indices: NDArray[Any], hops: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """For every patch, the patches within ``hops`` steps of the patch graph (itself
    included), as CSR arrays (start, members)."""
    count = len(indptr) - 1
    seen_by = np.full(count, -1, dtype=np.int64)
    queue = np.empty(count, dtype=np.int64)
    ring = np.empty(count, dtype=np.int64)
    starts = np.zeros(count + 1, dtype=np.int64)
    members = np.empty(max(16, count * 8), dtype=np.int64)
    size = 0
    for patch in range(count):
        tail = _walk_rings(patch, hops, indptr, indices, seen_by, queue, ring)
        if size + tail > len(members):
            grown = np.empty(2 * (size + tail), dtype=np.int64)
            grown[:size] = members[:size]
            members = grown
        members[size : size + tail] = queue[:tail]
        size += tail
        starts[patch + 1] = size
    return starts, members[:size]


@kernel
def _patch_bilateral_faces(  # noqa: PLR0913
    first: int,
    last: int,
    values: NDArray[Any],
    patch_of: NDArray[Any],
    starts: NDArray[Any],
    members: NDArray[Any],
    member_weight: NDArray[Any],
    patch_mean: NDArray[Any],
    patch_variance: NDArray[Any],
    window_faces: NDArray[Any],
    window_first: NDArray[Any],
    window_second: NDArray[Any],
    range_sigma_factor: float,
    out: NDArray[Any],
) -> None:
    """``bilateral_smooth`` for faces ``first..last-1`` over the window of their patch:
    each member patch weighs in with ``member_weight`` (its face count x the spatial
    Gaussian) times the range Gaussian averaged over its values (mean and variance)."""
    for face in range(first, last):
        centre = values[face]
        patch = patch_of[face]
        # RMS difference over the window's faces, from the patch window's moments
        # about the patch's own mean (sum of counts, first and second moments).
        offset = centre - patch_mean[patch]
        variance = (window_second[patch] - 2.0 * offset * window_first[patch]) / window_faces[
            patch
        ] + offset * offset
        if variance <= 1e-300:
            out[face] = centre
            continue
        scale = 0.5 / (range_sigma_factor * range_sigma_factor * variance)
        total = 0.0
        norm = 0.0
        for k in range(starts[patch], starts[patch + 1]):
            other = members[k]
            difference = patch_mean[other] - centre
            spread = 1.0 + 2.0 * scale * patch_variance[other]
            weight = (
                member_weight[k]
                * math.exp(-scale * difference * difference / spread)
                / math.sqrt(spread)
            )
            total += weight * (centre + difference / spread)
            norm += weight
        out[face] = total / norm if norm > 0 else centre


def ring_length(graph: FaceGraph, centroids: NDArray[Any]) -> float:
    """Straight-line distance per edge ring of the face graph: ``RING_PER_SPACING`` x the
    mean distance between the centroids of adjacent faces, over all the graph's pairs
    (summed in any order to the same bits: ``geometry.order_free_sum``). Turns a window
    in rings into a distance on the surface."""
    pairs = np.ascontiguousarray(graph.pairs, dtype=np.int64).reshape(-1, 2)
    offset = centroids[pairs[:, 0]] - centroids[pairs[:, 1]]
    return _ring_length(np.sqrt(np.einsum("ij,ij->i", offset, offset)))


def mesh_ring_length(graph: FaceGraph, vertices: NDArray[Any], faces: NDArray[Any]) -> float:
    """``ring_length`` from the mesh, computing the centroids' distances pair by pair."""
    pairs = np.ascontiguousarray(graph.pairs, dtype=np.int64).reshape(-1, 2)
    distances = np.empty(len(pairs))
    _centroid_distances(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
        pairs,
        distances,
    )
    return _ring_length(distances)


@kernel
def _centroid_distances(
    vertices: NDArray[Any], faces: NDArray[Any], pairs: NDArray[Any], out: NDArray[Any]
) -> None:
    """Distance between the centroids of ``pairs[:, 0]`` and ``pairs[:, 1]`` (each centroid
    as ``face_centroids``)."""
    for row in range(len(pairs)):
        a, b = faces[pairs[row, 0]], faces[pairs[row, 1]]
        squared = 0.0
        for axis in range(3):
            first = (vertices[a[0], axis] + vertices[a[1], axis] + vertices[a[2], axis]) / 3.0
            second = (vertices[b[0], axis] + vertices[b[1], axis] + vertices[b[2], axis]) / 3.0
            squared += (first - second) ** 2
        out[row] = math.sqrt(squared)


def _ring_length(distances: NDArray[np.float64]) -> float:
    if len(distances) == 0:
        return 0.0
    return RING_PER_SPACING * order_free_sum(distances) / len(distances)


def patch_bilateral(
    values: NDArray[Any],
    graph: FaceGraph,
    centroids: NDArray[Any],
    *,
    window_size: int,
    spatial_sigma: float | None = None,
    range_sigma_factor: float = RANGE_SIGMA_FACTOR,
    threads: int | None = None,
    progress: Progress | None = None,
) -> NDArray[np.float64]:
    """``bilateral_smooth`` for wide windows, computed over patches of faces
    (``progress`` is told 1.0 when done).

    The faces are covered by patches of about ``PATCH_RADIUS_FACTOR x window`` edge
    rings (``_cover_with_patches``, walking the face graph). A face's window is its patch's: the
    patches within a few steps on the patch graph (so the window follows the surface,
    as the rings do) whose centre lies within ``window_size`` rings of the patch's
    centre, measured as straight distance over ``ring_length``. Each such patch weighs
    in with its face count, the spatial Gaussian of that distance and the range
    Gaussian averaged over its values (their mean and variance: a Gaussian integral);
    the range sigma comes from the window's faces' values exactly (moments). Cost per
    face: the few dozen patches of its window, whatever the window's width.
    """
    values = np.asarray(values, dtype=np.float64)
    face_count = len(values)
    spatial = window_size * SPATIAL_SIGMA_FACTOR if spatial_sigma is None else spatial_sigma
    indptr, indices = sorted_adjacency(graph)
    radius = max(1, int(round(PATCH_RADIUS_FACTOR * window_size)))
    patch_of = _cover_with_patches(indptr, indices, radius)
    patches = int(patch_of.max()) + 1
    count = np.bincount(patch_of, minlength=patches).astype(np.float64)
    mean = np.bincount(patch_of, values, minlength=patches) / count
    variance = np.maximum(np.bincount(patch_of, values**2, minlength=patches) / count - mean**2, 0)
    centre = np.stack(
        [np.bincount(patch_of, centroids[:, axis], minlength=patches) / count for axis in range(3)],
        axis=1,
    )
    a, b = patch_of[graph.pairs[:, 0]], patch_of[graph.pairs[:, 1]]
    crossing = a != b
    patch_graph = sp.csr_matrix(
        (
            np.ones(2 * crossing.sum()),
            (np.r_[a[crossing], b[crossing]], np.r_[b[crossing], a[crossing]]),
        ),
        shape=(patches, patches),
    )
    hops = window_size // (2 * radius) + 2
    starts, members = _patch_windows(
        patch_graph.indptr.astype(np.int64), patch_graph.indices.astype(np.int64), hops
    )
    length = ring_length(graph, centroids)
    if not length > 0:
        return values.copy()
    # A patch's window: the patches within ``hops`` steps whose centre lies within the
    # window (in rings of ``length``), itself always; weights = count x spatial Gaussian.
    owner = np.repeat(np.arange(patches), np.diff(starts))
    rings = np.linalg.norm(centre[members] - centre[owner], axis=1) / length
    keep = (rings <= window_size) | (members == owner)
    owner, members, rings = owner[keep], members[keep], rings[keep]
    starts = np.searchsorted(owner, np.arange(patches + 1)).astype(np.int64)
    member_weight = count[members] * np.exp(-0.5 * (rings / spatial) ** 2)
    about_own = mean[members] - mean[owner]
    window_faces = np.bincount(owner, count[members], minlength=patches)
    window_first = np.bincount(owner, count[members] * about_own, minlength=patches)
    window_second = np.bincount(
        owner, count[members] * (about_own**2 + variance[members]), minlength=patches
    )
    out = np.empty(face_count)
    workers = max(1, os.cpu_count() or 1) if threads is None else max(1, threads)
    bounds = np.linspace(0, face_count, min(4 * workers, face_count) + 1).astype(int)

    def run(block: int) -> None:
        _patch_bilateral_faces(
            bounds[block],
            bounds[block + 1],
            values,
            patch_of,
            starts,
            members.astype(np.int64),
            member_weight,
            mean,
            variance,
            window_faces,
            window_first,
            window_second,
            float(range_sigma_factor),
            out,
        )

    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(run, range(len(bounds) - 1)))
    if progress is not None:
        progress(1.0)
    return out


def linear_normalize(values: NDArray[Any]) -> NDArray[np.float64]:
    """Map to [0, 1] by min and max; constant input gives zeros."""
    values = np.asarray(values, dtype=np.float64)
    if len(values) == 0:
        return values.copy()
    low, high = float(values.min()), float(values.max())
    if not high > low:
        return np.zeros_like(values)
    return np.clip((values - low) / (high - low), 0.0, 1.0)


def faces_away_from(seeds: NDArray[Any], graph: FaceGraph, rings: int) -> NDArray[np.bool_]:
    """(F,) whether each face is more than ``rings`` edge rings from every ``seeds`` face."""
    near = np.asarray(seeds, dtype=bool).copy()
    if not near.any() or rings <= 0:
        return ~near
    indptr, indices = adjacency_lists(graph.pairs, graph.face_count)
    _spread_rings(np.flatnonzero(near), rings, indptr, indices, near)
    return ~near


@kernel
def _spread_rings(  # pragma: no cover - numba
    starts: NDArray[Any],
    max_ring: int,
    indptr: NDArray[Any],
    indices: NDArray[Any],
    near: NDArray[Any],
) -> None:
    """Marks in ``near`` every node within ``max_ring`` edge rings of ``starts`` (already
    marked): one breadth-first walk from all of them, touching only the band it reaches."""
    queue = np.empty(len(near), dtype=np.int64)
    ring = np.zeros(len(near), dtype=np.int64)
    queue[: len(starts)] = starts
    _grow_rings(len(starts), max_ring, indptr, indices, near, True, queue, ring)


def normalize_away_from_rims(
    values: NDArray[Any], graph: FaceGraph, rim: NDArray[Any] | None, rings: int
) -> NDArray[np.float64]:
    """``linear_normalize`` with the min and max taken over the faces more than ``rings``
    edge rings from an open boundary (``rim``: the faces with an open edge), values outside
    clipped; over every face where there is no rim or fewer than half the faces are that
    far (a mostly open sheet).

    Rays near a hole's or a missing base's rim meet the cap or the far side at odd angles,
    and the filter spreads what they read over its window: a few such faces set the min
    or the max and squeezed every other value (a cup with holes read as one part).
    """
    values = np.asarray(values, dtype=np.float64)
    if rim is None or not np.any(rim) or len(values) == 0:
        return linear_normalize(values)
    away = faces_away_from(rim, graph, rings)
    if 2 * int(np.count_nonzero(away)) < len(values):
        return linear_normalize(values)
    low, high = float(values[away].min()), float(values[away].max())
    if not high > low:
        return linear_normalize(values)
    return np.clip((values - low) / (high - low), 0.0, 1.0)


def log_normalize(
    values: NDArray[Any], alpha: float = LOG_NORMALIZATION_ALPHA
) -> NDArray[np.float64]:
    """CGAL's log normalisation of [0, 1] values: ``log(alpha * x + 1) / log(alpha + 1)``."""
    if alpha <= 0:
        raise ParameterError(f"alpha must be > 0, got {alpha}")
    return np.log1p(alpha * np.asarray(values, dtype=np.float64)) / math.log1p(alpha)


def postprocess_shdf(
    raw: NDArray[Any],
    graph: FaceGraph,
    *,
    window_size: int | None = None,
    spatial_sigma: float | None = None,
    range_sigma_factor: float = RANGE_SIGMA_FACTOR,
    smooth: bool = True,
    centroids: NDArray[Any] | None = None,
    rim: NDArray[Any] | None = None,
    progress: Progress | None = None,
) -> NDArray[np.float64]:
    """Raw diameters (NaN = no value) -> ShDF in [0, 1], as CGAL post-processes ``sdf_values``.

    Args:
        raw: (F,) raw values, NaN where unknown.
        graph: face adjacency (the graph the filter walks).
        window_size: smoothing window in edge rings; default ``bilateral_window(F)``.
        spatial_sigma, range_sigma_factor: bilateral filter widths (see ``bilateral_smooth``).
        smooth: False skips the bilateral filter (filling and normalisation only).
        centroids: (F, 3) face centroids; with them, windows wider than
            ``EXACT_WINDOW_MAX`` rings are filtered over patches (``patch_bilateral``).
        rim: (F,) the faces with an open boundary edge, or None: the normalisation's
            min and max come from the faces farther than the window from them
            (``normalize_away_from_rims``).
        progress: called with the fraction done, in [0, 1] (the filter is most of it).
    """
    raw = np.asarray(raw, dtype=np.float64)
    if len(raw) != graph.face_count:
        raise ParameterError(f"{len(raw)} ShDF values for a face graph of {graph.face_count} faces")
    values = fill_missing(raw, graph)
    window = bilateral_window(len(values)) if window_size is None else window_size
    if smooth:
        filter_ = bilateral_smooth
        if centroids is not None and window > EXACT_WINDOW_MAX:
            filter_ = functools.partial(patch_bilateral, centroids=centroids)
        values = filter_(
            values,
            graph,
            window_size=window,
            spatial_sigma=spatial_sigma,
            range_sigma_factor=range_sigma_factor,
            progress=progress,
        )
    result = normalize_away_from_rims(values, graph, rim, window)
    if progress is not None:
        progress(1.0)
    return result
