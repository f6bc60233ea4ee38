"""The orientation pass's patch kernel as it was before the packed union-find (2026-11-26),
kept as the reference the compiled pass must match bit for bit (``test_orientation``)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel


@kernel(inline=True)
def _find(parent: NDArray[np.int64], node: int) -> int:  # pragma: no cover - numba
    """Union-find root with path halving."""
    while parent[node] != node:
        parent[node] = parent[parent[node]]
        node = parent[node]
    return node


@kernel(inline=True)
def _find_parity(  # pragma: no cover - numba
    parent: NDArray[np.int64], parity: NDArray[np.int8], node: int
) -> tuple[int, np.int8]:
    """(root, parity of ``node`` against it); the path is pointed at the root."""
    root, total = node, np.int8(0)
    while parent[root] != root:
        total ^= parity[root]
        root = parent[root]
    remaining = total
    while parent[node] != root and parent[node] != node:
        following, step = parent[node], parity[node]
        parent[node], parity[node] = root, remaining
        remaining ^= step
        node = following
    return root, total


@kernel(inline=True)
def _join(  # pragma: no cover - numba
    parent: NDArray[np.int64], parity: NDArray[np.int8], a: int, b: int, differ: np.int8
) -> int:
    """Put ``a`` and ``b`` in one set with parity(a) ^ parity(b) == ``differ`` (kept as
    found where they already share one: a non-orientable surface); 1 where that
    contradicts the set's parities, else 0."""
    root_a, parity_a = _find_parity(parent, parity, a)
    root_b, parity_b = _find_parity(parent, parity, b)
    if root_a != root_b:
        low, high = min(root_a, root_b), max(root_a, root_b)
        parent[high] = low
        parity[high] = parity_a ^ parity_b ^ differ
        return 0
    return 1 if parity_a ^ parity_b != differ else 0


@kernel(inline=True)
def _union(parent: NDArray[np.int64], a: int, b: int) -> int:  # pragma: no cover - numba
    """Join the sets of ``a`` and ``b`` under the smaller root; that root."""
    a, b = _find(parent, a), _find(parent, b)
    if a != b:
        parent[max(a, b)] = min(a, b)
    return min(a, b)


@kernel(inline=True)
def _third_vertex(  # pragma: no cover - numba
    faces: NDArray[np.int64], face: int, lo: int, hi: int
) -> int:
    """The vertex of triangle ``face`` off its edge (lo, hi)."""
    for corner in range(3):
        if faces[face, corner] != lo and faces[face, corner] != hi:
            vertex: int = faces[face, corner]
            return vertex
    return -1


@kernel(inline=True)
def _signed_volume(  # pragma: no cover - numba
    vertices: NDArray[np.float64], a: int, b: int, c: int, origin: NDArray[np.float64]
) -> float:
    """Six times the signed volume of the tetrahedron (origin, a, b, c); a, b, c vertex
    indices, or -1 for ``origin[3:]`` (a cap's centre)."""
    ax, ay, az = vertices[a, 0] - origin[0], vertices[a, 1] - origin[1], vertices[a, 2] - origin[2]
    bx, by, bz = vertices[b, 0] - origin[0], vertices[b, 1] - origin[1], vertices[b, 2] - origin[2]
    if c < 0:
        cx, cy, cz = origin[3] - origin[0], origin[4] - origin[1], origin[5] - origin[2]
    else:
        cx, cy = vertices[c, 0] - origin[0], vertices[c, 1] - origin[1]
        cz = vertices[c, 2] - origin[2]
    six_volume: float = (
        ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
    )
    return six_volume


@kernel
def reference_orient_patches(  # pragma: no cover
    faces: NDArray[np.int64],
    edge_table: NDArray[np.int64],
    slot: NDArray[np.int64],
    n_vertices: int,
    vertices: NDArray[np.float64],
    centre: NDArray[np.float64],
    areas: NDArray[np.float64],
) -> tuple[
    NDArray[np.int64],
    NDArray[np.int64],
    NDArray[np.int8],
    NDArray[np.float64],
    NDArray[np.bool_],
    NDArray[np.float64],
    NDArray[np.float64],
    int,
    int,
    int,
]:
    """Duplicates, patches over manifold edges with a consistent relative winding, per
    patch its capped signed volume, openness, area and the area its relative winding
    reverses; shell, loop and non-manifold counts.

    Returns (first copy (F,) or -1, patch (F,) or -1 (duplicates and collapsed faces),
    relative flip (F,) int8, volume (P,), open (P,), area (P,), reversed area (P,),
    shells, boundary loops, non-manifold edges). ``edge_table, slot`` from
    ``welded_edges``; ``areas`` (F,) the triangles' areas.
    """
    face_count = faces.shape[0]
    edge_count = edge_table.shape[0]
    # Per edge entry: whether its face runs it lo -> hi (one pass in face order, so the
    # edges need no look-up of their faces). Faces that repeat a vertex take no part
    # (their edges would pair them with themselves).
    skip = np.zeros(face_count, dtype=np.bool_)
    forward = np.zeros(edge_count, dtype=np.bool_)
    # Per face, the sum of its vertices: two faces on an edge have the same third vertex
    # where their sums agree, read without a look-up of either face's row.
    vertex_sum = np.empty(face_count, dtype=np.int64)
    for face in range(face_count):
        a, b, c = faces[face, 0], faces[face, 1], faces[face, 2]
        vertex_sum[face] = a + b + c
        if a == b or b == c or a == c:  # noqa: SIM109 - compiled
            skip[face] = True
            continue
        forward[slot[3 * face]] = a < b
        forward[slot[3 * face + 1]] = b < c
        forward[slot[3 * face + 2]] = c < a
    # Manifold edges link faces; boundary and non-manifold edges join loops to cap.
    first_copy = np.full(face_count, -1, dtype=np.int64)
    # Patches: a union-find over faces whose parity says whether a face is wound against
    # its root (the patch's lowest face); joined across each manifold edge.
    parent = np.arange(face_count)
    parity = np.zeros(face_count, dtype=np.int8)
    vertex_parent = np.arange(n_vertices)
    on_hole = np.zeros(n_vertices, dtype=np.bool_)  # on an edge of one face
    cut_start = np.empty(edge_count, dtype=np.int64)  # edges of one face, or of 3 or more
    cut_end = np.empty(edge_count, dtype=np.int64)
    cuts = 0
    non_manifold = 0
    conflicts = 0  # manifold edges whose join contradicts the set's parities
    i = 0
    while i < edge_count:
        j = i + 1
        while j < edge_count and edge_table[j, 0] == edge_table[i, 0]:
            j += 1
        if j - i >= 2:
            # Duplicates: the same third vertex on one edge. Every copy of a triangle is on
            # each of its edges, so the lowest face of the copies is their original on
            # whichever edge finds them first. Collapsed faces (``skip`` and no original)
            # take no part.
            lo, hi = edge_table[i, 0] // n_vertices, edge_table[i, 0] % n_vertices
            if j - i == 2:
                f, g = edge_table[i, 1], edge_table[i + 1, 1]
                usable = (not skip[f] or first_copy[f] >= 0) and (not skip[g] or first_copy[g] >= 0)
                # Third vertices equal: equal vertex sums (the edge's two are shared).
                if usable and vertex_sum[f] == vertex_sum[g]:
                    first, second = min(f, g), max(f, g)
                    first_copy[second] = first if first_copy[first] < 0 else first_copy[first]
                    skip[second] = True
            else:
                keys = np.empty(j - i, dtype=np.int64)
                count = 0
                for k in range(i, j):
                    face = edge_table[k, 1]
                    if skip[face] and first_copy[face] < 0:
                        continue
                    keys[count] = _third_vertex(faces, face, lo, hi) * face_count + face
                    count += 1
                keys = np.sort(keys[:count])
                start = 0
                for t in range(1, count + 1):
                    if t == count or keys[t] // face_count != keys[start] // face_count:
                        original = keys[start] % face_count
                        for u in range(start + 1, t):
                            copy = keys[u] % face_count
                            first_copy[copy] = original
                            skip[copy] = True
                        start = t
        members, f, g, f_at, g_at = 0, -1, -1, -1, -1
        for k in range(i, j):
            face = edge_table[k, 1]
            if not skip[face]:
                members += 1
                if f < 0:
                    f, f_at = face, k
                elif g < 0:
                    g, g_at = face, k
        if members == 2:
            # Faces wound alike run their shared edge in opposite directions.
            conflicts += _join(parent, parity, f, g, np.int8(forward[f_at] == forward[g_at]))
        elif members > 0:
            lo, hi = edge_table[i, 0] // n_vertices, edge_table[i, 0] % n_vertices
            if members > 2:
                non_manifold += 1
            else:
                on_hole[lo] = True
            cut_start[cuts], cut_end[cuts] = i, j
            cuts += 1
            _union(vertex_parent, lo, hi)
        i = j
    # Patch numbers by lowest face, relative windings and signed volumes in one pass.
    patch = np.full(face_count, -1, dtype=np.int64)
    relative = np.zeros(face_count, dtype=np.int8)
    volume = np.zeros(face_count)
    patch_area = np.zeros(face_count)
    flipped_area = np.zeros(face_count)
    point = np.zeros(6)
    point[:3] = centre
    patch_count = 0
    for face in range(face_count):
        if skip[face]:
            continue
        root, flipped = _find_parity(parent, parity, face)
        if root == face:
            patch[face] = patch_count
            patch_count += 1
        else:
            patch[face] = patch[root]
        relative[face] = flipped
        a, b, c = faces[face, 0], faces[face, 1], faces[face, 2]
        patch_area[patch[face]] += areas[face]
        if flipped:
            b, c = c, b
            flipped_area[patch[face]] += areas[face]
        volume[patch[face]] += _signed_volume(vertices, a, b, c, point)
    volume = volume[:patch_count]
    # Loop centres: the vertices of each component of open edges.
    loop_sum = np.zeros((n_vertices, 3))
    loop_size = np.zeros(n_vertices, dtype=np.int64)
    counted = np.zeros(n_vertices, dtype=np.bool_)
    seen = np.zeros(n_vertices, dtype=np.bool_)
    loops = 0
    for cut in range(cuts):
        key = edge_table[cut_start[cut], 0]
        for vertex in (key // n_vertices, key % n_vertices):
            root = _find(vertex_parent, vertex)
            if not seen[vertex]:
                seen[vertex] = True
                loop_size[root] += 1
                loop_sum[root] += vertices[vertex]
            if on_hole[vertex] and not counted[root]:
                counted[root] = True
                loops += 1
    is_open = np.zeros(patch_count, dtype=np.bool_)
    patch_parent = np.arange(patch_count)
    for cut in range(cuts):
        i, j = cut_start[cut], cut_end[cut]
        lo, hi = edge_table[i, 0] // n_vertices, edge_table[i, 0] % n_vertices
        root = _find(vertex_parent, lo)
        point[3:] = loop_sum[root] / loop_size[root]
        first = -1
        for k in range(i, j):
            face = edge_table[k, 1]
            if skip[face]:
                continue
            runs_forward = forward[k] != (relative[face] == 1)
            # The cap runs the edge the other way round: (hi, lo, centre) after lo -> hi.
            if runs_forward:
                volume[patch[face]] += _signed_volume(vertices, hi, lo, -1, point)
            else:
                volume[patch[face]] += _signed_volume(vertices, lo, hi, -1, point)
            is_open[patch[face]] = True
            # Shells: patches joined through non-manifold edges.
            first = patch[face] if first < 0 else _union(patch_parent, first, patch[face])
    shells = 0
    for p in range(patch_count):
        if _find(patch_parent, p) == p:
            shells += 1
    return (
        first_copy,
        patch,
        relative,
        volume / 6.0,
        is_open,
        patch_area[:patch_count],
        flipped_area[:patch_count],
        shells,
        loops,
        non_manifold,
        conflicts,
    )
