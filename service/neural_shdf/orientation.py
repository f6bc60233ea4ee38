"""Which way each triangle faces, decided from the geometry rather than the file's winding.

Exporters get winding wrong all the time (an inside-out export, a few flipped
faces, mixed shells), and the ShDF's rays go against the face normal, so a wrong
winding reads air as material. ``orient_faces`` returns, per triangle, whether to
reverse it so that every shell faces out of its solid, plus what the pass found
(``MeshDiagnostics``). The input is never modified.

How, in one compiled pass over the welded edges (coincident vertices merged, so a
triangle soup is connected):

* Duplicate faces (the same three vertices, either winding) and faces that repeat a
  vertex are left out of the edge graph: duplicates take the facing of their first
  copy (a double-sided card becomes one sheet), collapsed faces keep the file's.
* *Patches*: faces connected across manifold edges (two faces on the edge) get one
  consistent winding by breadth-first search (neighbours traverse the shared edge in
  opposite directions). A non-manifold edge (three faces or more) cuts patches
  apart: which pairs of its faces belong together is not known, and a vote over them
  can be forced to contradict itself (a fin on a box), so each side is decided on its
  own geometry instead.
* Each patch faces outward when its signed volume is positive. Open patches are
  closed first, for this measure only, by a fan from each boundary loop (and each
  non-manifold cut) to the loop's centroid: the volume is then the integral of the
  closed surface's winding number, which holes, missing bases and self-intersections
  perturb only in proportion to their size. Where the volume cannot decide (a flat or
  nearly flat open sheet: ``|volume| < AMBIGUOUS_VOLUME * area ** 1.5``) the patch
  keeps the winding most of its area has in the file.

Every shell faces outward on its own, as a solid modeller exports separate solids:
eyes inside a head face out of the eyes. The inner wall of a hollow solid's cavity
is a shell of its own too and is also turned to face out of the region it encloses
(into the cavity), which is not what a solid modeller writes for a cavity; the
geometry alone cannot tell an eye from a cavity.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.geometry import _sorted_edges, face_normals, weld_faces

#: An open patch whose capped signed volume is below this times its area^1.5 is treated
#: as a sheet with no inside (a sphere has 0.094, a tube 1000 radii long about 0.006).
AMBIGUOUS_VOLUME = 1e-3


@dataclass(frozen=True)
class MeshDiagnostics:
    """What the orientation pass found in a mesh and what it did about it.

    Attributes:
        shells: connected pieces (faces linked through shared edges, manifold or not).
        boundary_loops: open boundary loops (holes, missing bases, open sheets' rims).
        non_manifold_edges: edges shared by three faces or more.
        reoriented_faces: triangles whose winding the ShDF and segmentation use reversed.
        degenerate_faces: triangles of zero area (collinear or repeated vertices).
        duplicate_faces: triangles on the same three vertices as an earlier one.
    """

    shells: int
    boundary_loops: int
    non_manifold_edges: int
    reoriented_faces: int
    degenerate_faces: int
    duplicate_faces: int

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def summary(self) -> str:
        """One line for a log or a terminal."""
        return (
            f"mesh: {self.shells} shell{'s' * (self.shells != 1)}, "
            f"{self.boundary_loops} open boundary loop{'s' * (self.boundary_loops != 1)}, "
            f"{self.non_manifold_edges} non-manifold edge{'s' * (self.non_manifold_edges != 1)}, "
            f"{self.reoriented_faces} face{'s' * (self.reoriented_faces != 1)} re-oriented, "
            f"{self.degenerate_faces} degenerate, {self.duplicate_faces} duplicate"
        )


@dataclass(frozen=True)
class Orientation:
    """``flips[i]``: triangle ``i`` is reversed to face out of its solid; and the diagnostics."""

    flips: NDArray[np.bool_]
    diagnostics: MeshDiagnostics


def orient_faces(
    vertices: NDArray,
    faces: NDArray,
    *,
    welded: NDArray | None = None,
    areas: NDArray | None = None,
) -> Orientation:
    """Per-triangle flips that make every shell consistently wound and facing outward.

    ``welded``: ``weld_faces(vertices, faces)`` where the caller has it; ``areas``: the
    triangles' areas (``face_normals``). Deterministic; the arrays are not modified.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    count = len(faces)
    if count == 0:
        return Orientation(np.zeros(0, dtype=bool), MeshDiagnostics(0, 0, 0, 0, 0, 0))
    welded = weld_faces(vertices, faces) if welded is None else np.asarray(welded, np.int64)
    if areas is None:
        _, areas = face_normals(vertices, faces)
    collapsed = (
        (welded[:, 0] == welded[:, 1])
        | (welded[:, 1] == welded[:, 2])
        | (welded[:, 0] == welded[:, 2])
    )
    flips = np.zeros(count, dtype=bool)
    duplicate = np.zeros(count, dtype=bool)
    shells = loops = non_manifold = 0
    kept = np.flatnonzero(~collapsed) if collapsed.any() else None
    kept_faces = welded if kept is None else np.ascontiguousarray(welded[kept])
    if len(kept_faces):
        n_vertices = int(kept_faces.max()) + 1
        edge_table, _ = _sorted_edges(kept_faces, n_vertices)
        origin = vertices.mean(axis=0)
        (first_copy, patch, relative, volume, is_open, shells, loops, non_manifold) = (
            _orient_patches(kept_faces, edge_table, n_vertices, vertices, origin)
        )
        active = patch >= 0
        kept_areas = np.asarray(areas, dtype=np.float64)
        kept_areas = kept_areas if kept is None else kept_areas[kept]
        patch_of = patch[active]
        patch_area = np.bincount(patch_of, weights=kept_areas[active], minlength=len(volume))
        # Area per patch that the search's relative winding reverses against the file.
        flipped_area = np.bincount(
            patch_of, weights=(kept_areas * relative)[active], minlength=len(volume)
        )
        ambiguous = (volume == 0) | (
            is_open & (np.abs(volume) < AMBIGUOUS_VOLUME * patch_area**1.5)
        )
        # Where the volume cannot decide, the winding of most of the patch's area in the file.
        patch_flip = np.where(ambiguous, flipped_area > 0.5 * patch_area, volume < 0)
        kept_flips = np.zeros(len(kept_faces), dtype=bool)
        kept_flips[active] = relative[active].astype(bool) ^ patch_flip[patch_of]
        # Duplicates face as their first copy does.
        copies = np.flatnonzero(~active)
        originals = first_copy[copies]
        same_turn = _same_cyclic_order(kept_faces[copies], kept_faces[originals])
        kept_flips[copies] = kept_flips[originals] ^ ~same_turn
        kept_index = np.arange(count) if kept is None else kept
        flips[kept_index] = kept_flips
        duplicate[kept_index[copies]] = True
    degenerate = collapsed | (np.asarray(areas) <= 0)
    diagnostics = MeshDiagnostics(
        shells=int(shells),
        boundary_loops=int(loops),
        non_manifold_edges=int(non_manifold),
        reoriented_faces=int(flips.sum()),
        degenerate_faces=int(degenerate.sum()),
        duplicate_faces=int(duplicate.sum()),
    )
    return Orientation(flips, diagnostics)


def _same_cyclic_order(faces: NDArray, others: NDArray) -> NDArray[np.bool_]:
    """Whether each triangle lists the same three vertices as its partner in the same turn."""
    same = np.zeros(len(faces), dtype=bool)
    for shift in range(3):
        same |= (np.roll(others, shift, axis=1) == faces).all(axis=1)
    return same


@kernel(inline=True)
def _find(parent, node):  # pragma: no cover - numba
    """Union-find root with path halving."""
    while parent[node] != node:
        parent[node] = parent[parent[node]]
        node = parent[node]
    return node


@kernel(inline=True)
def _runs_forward(faces, face, lo, hi):  # pragma: no cover - numba
    """Whether triangle ``face`` traverses its edge (lo, hi) from lo to hi."""
    for corner in range(3):
        if faces[face, corner] == lo and faces[face, (corner + 1) % 3] == hi:
            return True
    return False


@kernel(inline=True)
def _signed_volume(a, b, c, origin):  # pragma: no cover - numba
    """Six times the signed volume of the tetrahedron (origin, a, b, c); points as rows."""
    ax, ay, az = a[0] - origin[0], a[1] - origin[1], a[2] - origin[2]
    bx, by, bz = b[0] - origin[0], b[1] - origin[1], b[2] - origin[2]
    cx, cy, cz = c[0] - origin[0], c[1] - origin[1], c[2] - origin[2]
    return ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)


@kernel(inline=True)
def _third_vertex(faces, face, lo, hi):  # pragma: no cover - numba
    """The vertex of triangle ``face`` off its edge (lo, hi)."""
    for corner in range(3):
        if faces[face, corner] != lo and faces[face, corner] != hi:
            return faces[face, corner]
    return -1


@kernel
def _orient_patches(faces, edge_table, n_vertices, vertices, origin):  # pragma: no cover
    """Duplicates, patches over manifold edges with a consistent relative winding, per
    patch its capped signed volume and openness; shell, loop and non-manifold counts.

    Returns (first copy (F,) or -1, patch (F,) or -1 for duplicates, relative flip (F,)
    int8, volume (P,), open (P,), shells, boundary loops, non-manifold edges).
    ``edge_table`` from ``_sorted_edges``; faces repeat no vertex.
    """
    face_count = faces.shape[0]
    edge_count = edge_table.shape[0]
    group_start = np.empty(edge_count + 1, dtype=np.int64)
    groups = 0
    for position in range(edge_count):
        if position == 0 or edge_table[position, 0] != edge_table[position - 1, 0]:
            group_start[groups] = position
            groups += 1
    group_start[groups] = edge_count
    # Duplicates: two faces on one edge with the same third vertex (earlier = first copy);
    # within very crowded edges only against the few faces before.
    first_copy = np.full(face_count, -1, dtype=np.int64)
    for group in range(groups):
        i, j = group_start[group], group_start[group + 1]
        if j - i < 2:
            continue
        key = edge_table[i, 0]
        lo, hi = key // n_vertices, key % n_vertices
        for k in range(i + 1, j):
            later = edge_table[k, 1]
            third = _third_vertex(faces, later, lo, hi)
            for m in range(max(i, k - 8), k):
                earlier = edge_table[m, 1]
                if _third_vertex(faces, earlier, lo, hi) == third:
                    original = earlier if first_copy[earlier] < 0 else first_copy[earlier]
                    if first_copy[later] < 0 or original < first_copy[later]:
                        first_copy[later] = original
                    break
    neighbour = np.full((face_count, 3), -1, dtype=np.int64)
    same_direction = np.zeros((face_count, 3), dtype=np.bool_)
    degree = np.zeros(face_count, dtype=np.int64)
    vertex_parent = np.arange(n_vertices)
    on_hole = np.zeros(n_vertices, dtype=np.bool_)  # on an edge of one face
    on_cut = np.zeros(n_vertices, dtype=np.bool_)  # on an edge of one face or of three or more
    members = np.zeros(groups, dtype=np.int64)  # faces on each edge, duplicates left out
    non_manifold = 0
    for group in range(groups):
        i, j = group_start[group], group_start[group + 1]
        f = g = -1
        for k in range(i, j):
            if first_copy[edge_table[k, 1]] < 0:
                members[group] += 1
                if f < 0:
                    f = edge_table[k, 1]
                elif g < 0:
                    g = edge_table[k, 1]
        if members[group] == 0:
            continue
        lo, hi = edge_table[i, 0] // n_vertices, edge_table[i, 0] % n_vertices
        if members[group] == 2:
            same = _runs_forward(faces, f, lo, hi) == _runs_forward(faces, g, lo, hi)
            neighbour[f, degree[f]], same_direction[f, degree[f]] = g, same
            neighbour[g, degree[g]], same_direction[g, degree[g]] = f, same
            degree[f] += 1
            degree[g] += 1
            continue
        # A boundary or a non-manifold cut: part of a loop to cap.
        if members[group] > 2:
            non_manifold += 1
        else:
            on_hole[lo] = True
        on_cut[lo] = True
        on_cut[hi] = True
        a, b = _find(vertex_parent, lo), _find(vertex_parent, hi)
        if a != b:
            vertex_parent[max(a, b)] = min(a, b)
    # Breadth-first search over manifold edges: patches and relative windings.
    patch = np.full(face_count, -1, dtype=np.int64)
    relative = np.zeros(face_count, dtype=np.int8)
    queue = np.empty(face_count, dtype=np.int64)
    patch_count = 0
    for seed in range(face_count):
        if patch[seed] >= 0 or first_copy[seed] >= 0:
            continue
        patch[seed] = patch_count
        head, tail = 0, 1
        queue[0] = seed
        while head < tail:
            face = queue[head]
            head += 1
            for k in range(degree[face]):
                other = neighbour[face, k]
                if patch[other] < 0:
                    patch[other] = patch_count
                    relative[other] = relative[face] ^ np.int8(same_direction[face, k])
                    queue[tail] = other
                    tail += 1
        patch_count += 1
    # Loop centroids: vertices of boundary and non-manifold edges, grouped by component.
    loop_sum = np.zeros((n_vertices, 3))
    loop_size = np.zeros(n_vertices, dtype=np.int64)
    counted = np.zeros(n_vertices, dtype=np.bool_)
    loops = 0
    for vertex in range(n_vertices):
        if on_cut[vertex]:
            root = _find(vertex_parent, vertex)
            loop_size[root] += 1
            loop_sum[root, 0] += vertices[vertex, 0]
            loop_sum[root, 1] += vertices[vertex, 1]
            loop_sum[root, 2] += vertices[vertex, 2]
            if on_hole[vertex] and not counted[root]:
                counted[root] = True
                loops += 1
    # Signed volume per patch, then the caps of its open edges; shells over all edges.
    volume = np.zeros(patch_count)
    is_open = np.zeros(patch_count, dtype=np.bool_)
    for face in range(face_count):
        if patch[face] < 0:
            continue
        a, b, c = faces[face, 0], faces[face, 1], faces[face, 2]
        if relative[face]:
            b, c = c, b
        volume[patch[face]] += _signed_volume(vertices[a], vertices[b], vertices[c], origin)
    patch_parent = np.arange(patch_count)
    centre = np.empty(3)
    for group in range(groups):
        if members[group] == 2 or members[group] == 0:
            continue
        i, j = group_start[group], group_start[group + 1]
        lo, hi = edge_table[i, 0] // n_vertices, edge_table[i, 0] % n_vertices
        root = _find(vertex_parent, lo)
        centre[:] = loop_sum[root] / loop_size[root]
        first = -1
        for k in range(i, j):
            face = edge_table[k, 1]
            if first_copy[face] >= 0:
                continue
            forward = _runs_forward(faces, face, lo, hi) != (relative[face] == 1)
            # The cap runs the edge the other way round: (hi, lo, centre) after lo -> hi.
            if forward:
                cap = _signed_volume(vertices[hi], vertices[lo], centre, origin)
            else:
                cap = _signed_volume(vertices[lo], vertices[hi], centre, origin)
            volume[patch[face]] += cap
            is_open[patch[face]] = True
            if first < 0:
                first = _find(patch_parent, patch[face])
            else:
                other = _find(patch_parent, patch[face])
                if other != first:
                    patch_parent[max(first, other)] = min(first, other)
                    first = min(first, other)
    shells = 0
    for p in range(patch_count):
        if _find(patch_parent, p) == p:
            shells += 1
    return first_copy, patch, relative, volume / 6.0, is_open, shells, loops, non_manifold
