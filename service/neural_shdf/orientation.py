"""Which way each triangle faces, decided from the geometry rather than the file's winding.

Exporters get winding wrong all the time (an inside-out export, a few flipped
faces, mixed shells), and the ShDF's rays go against the face normal, so a wrong
winding reads air as material. ``orient_faces`` returns, per triangle, whether to
reverse it so that every shell faces out of its solid, plus what the pass found
(``MeshDiagnostics``). The input is never modified.

How, in one compiled pass over the welded edges (coincident vertices merged, so a
triangle soup is connected):

* Duplicate faces (the same three vertices, either winding, found on edges of three
  faces or more) and faces that repeat a vertex are left out of the edge graph:
  duplicates take the facing of their first copy (a double-sided card becomes one
  sheet), collapsed faces keep the file's.
* *Patches*: faces connected across manifold edges (two faces on the edge) get one
  consistent winding from a union-find with parity (neighbours traverse the shared
  edge in opposite directions). A non-manifold edge (three faces or more) cuts patches
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
geometry alone cannot tell an eye from a cavity. Open shells stitched into one surface
are then turned together (``stitching.orient_stitched_shells``, which
``TriangleMesh.orientation`` applies after this pass).

``hole_caps`` closes the open boundary loops of an oriented mesh with the same fans,
for the ShDF's rays only (``shdf.stage.ray_targets``).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from neural_shdf.compiled import kernel
from neural_shdf.geometry import (
    _face_normal,
    _sorted_edges,
    face_centroids,
    face_normals,
    weighted_moments,
    weld_faces,
    zero_area_limit,
)

#: ``hole_caps`` closes nothing where boundary edges outnumber this share of the triangles:
#: such a surface is mostly open (a soup of separate sheets), and caps would not stand for
#: missing surface but add triangles in proportion to the mesh.
MAX_BOUNDARY_SHARE = 0.25
#: An open patch whose capped signed volume is below this times its area^1.5 is treated
#: as a sheet with no inside (a sphere has 0.094, a tube 1000 radii long about 0.006).
AMBIGUOUS_VOLUME = 1e-3
#: Such a sheet faces away from the mesh's centre where its area-weighted normals' flux out
#: of the centre (``_sheet_flux``) is above this times its area times the mesh's extent
#: (a plane through the centre has none); below it, its winding in the file decides.
SHEET_FLUX = 1e-3
#: Failing that, it faces away from the side the mesh's area is skewed to, where the third
#: moment (``_sheet_skew``) is above this times the mesh's area times its extent cubed: far
#: above float rounding (an exactly symmetric mesh has none).
SHEET_SKEW = 1e-9
#: A sheet's capped volume (over its area^1.5) whose sign still decides where neither the
#: flux nor the skew does: far above float rounding, far below ``AMBIGUOUS_VOLUME``.
SHEET_VOLUME = 1e-10
#: ... and above this times its area times the mesh's extent (the rounding of a capped
#: volume: 1e-19 on 1e-6 patches of a unit mesh, where area^1.5 x ``SHEET_VOLUME`` is too).
SHEET_VOLUME_ROUNDING = 1e-9
#: A patch whose faces are wound half each way (by area, within this share) keeps the
#: winding of its first face (the listing's, ``TriangleMesh.listing``).
WINDING_TIE = 1e-9
#: ``reverse_flipped`` writes the oriented copy in two threads from this many triangles
#: (below, a thread's start costs more than it saves).
PARALLEL_COPY_FACES = 100_000


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
        stitched_shells: open shells joined to another along their boundaries for the
            graphs (``stitching.stitch_shells``; 0 from ``orient_faces``, which does not
            stitch: ``TriangleMesh.diagnostics`` fills it).
        stitched_vertices: boundary vertices merged into one of another shell by it.
    """

    shells: int
    boundary_loops: int
    non_manifold_edges: int
    reoriented_faces: int
    degenerate_faces: int
    duplicate_faces: int
    stitched_shells: int = 0
    stitched_vertices: int = 0

    def as_dict(self) -> dict[str, int]:
        return asdict(self)

    def summary(self) -> str:
        """One line for a log or a terminal."""
        return (
            f"mesh: {self.shells} shell{'s' * (self.shells != 1)}, "
            f"{self.boundary_loops} open boundary loop{'s' * (self.boundary_loops != 1)}, "
            f"{self.non_manifold_edges} non-manifold edge{'s' * (self.non_manifold_edges != 1)}, "
            f"{self.reoriented_faces} face{'s' * (self.reoriented_faces != 1)} re-oriented, "
            f"{self.degenerate_faces} degenerate, {self.duplicate_faces} duplicate, "
            f"{self.stitched_shells} shell{'s' * (self.stitched_shells != 1)} stitched "
            f"({self.stitched_vertices} vert{'ices' if self.stitched_vertices != 1 else 'ex'})"
        )


@dataclass(frozen=True)
class Orientation:
    """``flips[i]``: triangle ``i`` is reversed to face out of its solid; the diagnostics;
    ``first_copy[i]``: the earlier triangle on the same three vertices, or -1."""

    flips: NDArray[np.bool_]
    diagnostics: MeshDiagnostics
    first_copy: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


def orient_faces(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    *,
    welded: NDArray[Any] | None = None,
    areas: NDArray[Any] | None = None,
    edges: tuple[NDArray[np.int64], NDArray[np.int64]] | None = None,
    degenerate: int | None = None,
    numbered_by_position: bool = False,
) -> Orientation:
    """Per-triangle flips that make every shell consistently wound and facing outward.

    Where the caller has them: ``welded``, ``weld_faces(vertices, faces)``; ``areas``,
    the triangles' areas (``face_normals``); ``edges``, ``welded_edges(welded)``;
    ``degenerate``, how many triangles ``face_normals`` gave no normal (zero area).
    ``numbered_by_position``: the vertices are numbered by position already
    (``TriangleMesh.listing``, in the shape's own frame), so a non-orientable patch is
    wound in that numbering rather than the world's x, y, z order, which a pose moves.
    Deterministic; the arrays are not modified.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    count = len(faces)
    if count == 0:
        return Orientation(np.zeros(0, dtype=bool), MeshDiagnostics(0, 0, 0, 0, 0, 0))
    welded = weld_faces(vertices, faces) if welded is None else np.asarray(welded, np.int64)
    if areas is None:
        _, areas = face_normals(vertices, faces)
    areas = np.asarray(areas, dtype=np.float64)
    edge_table, slot = welded_edges(welded) if edges is None else edges
    centre = _column_means(vertices)
    # The union-find's integers in 32 bits where the faces allow: half the memory its
    # scattered loads and stores walk.
    link_type: NDArray[np.integer[Any]] = np.empty(
        0, dtype=np.int32 if 2 * count < 2**31 else np.int64
    )
    patches = _orient_patches(welded, edge_table, slot, vertices, centre, areas, link_type)
    if patches[-1] and not numbered_by_position:
        # A non-orientable patch: which manifold edge gives way follows the joins' order,
        # the edges' by vertex number. Numbered by position instead, the same surface
        # listed in any order gives it the same windings.
        renumbered, by_position = _numbered_by_position(vertices, welded)
        patches = _orient_patches(
            renumbered, *welded_edges(renumbered), by_position, centre, areas, link_type
        )
    (
        first_copy,
        winding,
        volume,
        is_open,
        patch_area,
        flipped_area,
        shells,
        loops,
        non_manifold,
        _,
    ) = patches
    # The diameter about the centre, as a pose leaves it (a bounding box's diagonal turns
    # with the axes: sheets near the thresholds below tipped under a rotation).
    extent = 2.0 * _largest_distance(vertices, centre) if len(vertices) else 0.0
    # A closed patch whose volume is rounding's (a flat double layer) has no inside either:
    # its sign would follow the pose.
    flat = np.abs(volume) <= SHEET_VOLUME_ROUNDING * patch_area * extent
    ambiguous = flat | (is_open & (np.abs(volume) < AMBIGUOUS_VOLUME * patch_area**1.5))
    patch_flip = volume < 0
    if ambiguous.any():
        # A sheet (no inside) faces away from the mesh's centre, whatever the file's winding.
        flux = _sheet_flux(vertices, welded, winding, ambiguous)
        decided = np.abs(flux) > SHEET_FLUX * patch_area * extent
        # A sheet through the centre (a wing at mid-height) faces away from the side the
        # mesh's area is skewed to.
        skew = _sheet_skew(vertices, welded, areas, winding, ambiguous & ~decided)
        by_skew = ~decided & (np.abs(skew) > SHEET_SKEW * float(areas.sum()) * extent**3)
        # Then the sign of its (small) capped volume where float rounding cannot have set
        # it (two layers of a card a hair apart); the file's winding only where none does.
        # (the rounding of a capped volume grows with the patch's area and its distance
        # from the centre, not with area^1.5: a tiny patch far out took rounding's sign).
        signed = np.abs(volume) > np.maximum(
            SHEET_VOLUME * patch_area**1.5, SHEET_VOLUME_ROUNDING * patch_area * extent
        )
        # Most of the area wound against the patch's first face; a tie (two equal faces,
        # one each way, whose areas a pose rounds apart) keeps the first face's winding.
        file_winding = np.where(signed, volume < 0, flipped_area > (0.5 + WINDING_TIE) * patch_area)
        sheet_flip = np.where(decided, flux < 0, np.where(by_skew, skew > 0, file_winding))
        patch_flip = np.where(ambiguous, sheet_flip, patch_flip)
    flips = _face_flips(winding, patch_flip)
    # Duplicates face as their first copy does; collapsed faces keep the file's winding.
    copies = np.flatnonzero(first_copy >= 0)
    originals = first_copy[copies]
    same_turn = _same_cyclic_order(welded[copies], welded[originals])
    flips[copies] = flips[originals] ^ ~same_turn
    diagnostics = MeshDiagnostics(
        shells=int(shells),
        boundary_loops=int(loops),
        non_manifold_edges=int(non_manifold),
        reoriented_faces=int(flips.sum()),
        degenerate_faces=(
            int(np.count_nonzero(2.0 * areas <= zero_area_limit(vertices, faces)))
            if degenerate is None
            else int(degenerate)
        ),
        duplicate_faces=len(copies),
    )
    return Orientation(flips, diagnostics, np.asarray(first_copy, dtype=np.int64))


def _numbered_by_position(
    vertices: NDArray[np.float64], faces: NDArray[np.int64]
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """(faces, vertices) with the vertices renumbered in order of position (x, then y,
    then z): the same numbers for the same surface however the file listed it."""
    order = np.lexsort((vertices[:, 2], vertices[:, 1], vertices[:, 0]))
    number = np.empty(len(vertices), dtype=np.int64)
    number[order] = np.arange(len(vertices))
    return number[faces], np.ascontiguousarray(vertices[order])


@kernel
def _largest_distance(
    points: NDArray[np.float64], centre: NDArray[np.float64]
) -> float:  # pragma: no cover - compiled
    """The largest distance of a point from ``centre``."""
    largest = 0.0
    for row in range(points.shape[0]):
        squared = 0.0
        for axis in range(3):
            squared += (points[row, axis] - centre[axis]) ** 2
        largest = max(largest, squared)
    return float(np.sqrt(largest))


@kernel
def _column_means(rows: NDArray[np.float64]) -> NDArray[np.float64]:  # pragma: no cover
    """``rows.mean(axis=0)`` of an (N, 3) array, bit for bit (numpy adds the rows in order
    along that axis), without numpy's strided reduction, ten times slower here."""
    total = np.zeros(3)
    for row in range(rows.shape[0]):
        for axis in range(3):
            total[axis] += rows[row, axis]
    means: NDArray[np.float64] = total / rows.shape[0]
    return means


def welded_edges(welded: NDArray[Any]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The edges of (welded) triangles sorted by vertex pair, as ``geometry.build_face_graph``
    takes them (``edges``): (edge table (E, 2) of key and face, slot (3F,) of each corner's
    edge). One sort shared by the orientation pass and the face graph."""
    welded = np.ascontiguousarray(welded, dtype=np.int64).reshape(-1, 3)
    return _sorted_edges(welded, int(welded.max(initial=-1)) + 1)


def reversed_slots(slot: NDArray[Any], flips: NDArray[Any]) -> NDArray[np.int64]:
    """``slot`` of ``welded_edges`` for the same triangles with those in ``flips`` listed
    backwards, (a, b, c) -> (c, b, a): their edges (c, b), (b, a), (a, c) were corners 1, 0, 2.
    The edge table itself does not depend on the winding."""
    slots = np.ascontiguousarray(slot, dtype=np.int64).reshape(-1, 3)
    return _permute_flipped_rows(slots, np.asarray(flips, dtype=bool), 1, 0, 2).reshape(-1)


def reverse_rows(faces: NDArray[Any], flips: NDArray[Any]) -> NDArray[np.int64]:
    """Triangles (F, 3) with those in ``flips`` listed backwards, (a, b, c) -> (c, b, a)."""
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    return _permute_flipped_rows(faces, np.asarray(flips, dtype=bool), 2, 1, 0)


def reverse_flipped(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    welded: NDArray[Any],
    flips: NDArray[Any],
    normals: NDArray[Any],
    area_limit: float,
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:
    """The arrays of the oriented copy of a mesh, in one pass over its triangles.

    Returns ``reverse_rows(faces, flips)``, ``reverse_rows(welded, flips)`` (a view of the
    first where ``welded`` is ``faces``' memory: ``geometry.weld_faces`` merged nothing)
    and ``normals`` with the reversed rows' normals computed
    again from their new order, bit for bit those of ``geometry.face_normals`` of the
    reversed triangles (``area_limit``: ``zero_area_limit(vertices, faces)``, which the
    winding does not change); the other rows copied. The edges' slots
    (``reversed_slots``) are left to whoever asks: a closed mesh's segmentation never does.
    From ``PARALLEL_COPY_FACES`` triangles two threads write a half each (the copy is
    mostly first touches of fresh memory: 1.6M triangles reversed, 54 -> 29 ms).
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    welded = np.ascontiguousarray(welded, dtype=np.int64).reshape(-1, 3)
    normals = np.ascontiguousarray(normals, dtype=np.float64).reshape(-1, 3)
    flips = np.ascontiguousarray(flips, dtype=bool).reshape(-1)
    same = welded.shape == faces.shape and welded.ctypes.data == faces.ctypes.data
    count = len(faces)
    # The kernel allocates the copies: fresh memory is faulted in page by page there, while
    # numpy asks for huge pages, which can stall on compaction for longer.
    reversed_faces, reversed_welded, renewed = _empty_copy(count, same)
    arrays = (vertices, faces, welded, flips, normals, float(area_limit), same)
    copies = (reversed_faces, reversed_welded, renewed)
    if count >= PARALLEL_COPY_FACES:
        half = count // 2
        with ThreadPoolExecutor(max_workers=1) as beside:
            first = beside.submit(_reverse_flipped, *arrays, *copies, 0, half)
            _reverse_flipped(*arrays, *copies, half, count)
            first.result()
    else:
        _reverse_flipped(*arrays, *copies, 0, count)
    return (
        reversed_faces,
        reversed_faces.view() if same else reversed_welded,
        renewed,
    )


@kernel
def _empty_copy(
    count: int, same: bool
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]:  # pragma: no cover
    """Unwritten arrays of the oriented copy (the welded rows empty where ``same``)."""
    return (
        np.empty((count, 3), dtype=np.int64),
        np.empty((0 if same else count, 3), dtype=np.int64),
        np.empty((count, 3), dtype=np.float64),
    )


@kernel
def _reverse_flipped(  # pragma: no cover - numba
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    welded: NDArray[np.int64],
    flips: NDArray[np.bool_],
    normals: NDArray[np.float64],
    area_limit: float,
    same: bool,
    reversed_faces: NDArray[np.int64],
    reversed_welded: NDArray[np.int64],
    renewed: NDArray[np.float64],
    start: int,
    stop: int,
) -> None:
    """``reverse_flipped``'s rows ``start:stop``: rows (a, b, c) -> (c, b, a), normals from
    the new rows; the welded rows left alone where ``same``: they are the rows."""
    for face in range(start, stop):
        if flips[face]:
            reversed_faces[face, 0] = faces[face, 2]
            reversed_faces[face, 1] = faces[face, 1]
            reversed_faces[face, 2] = faces[face, 0]
            _face_normal(vertices, reversed_faces, face, area_limit, renewed)
        else:
            for corner in range(3):
                reversed_faces[face, corner] = faces[face, corner]
                renewed[face, corner] = normals[face, corner]
    if not same:
        for face in range(start, stop):
            if flips[face]:
                reversed_welded[face, 0] = welded[face, 2]
                reversed_welded[face, 1] = welded[face, 1]
                reversed_welded[face, 2] = welded[face, 0]
            else:
                for corner in range(3):
                    reversed_welded[face, corner] = welded[face, corner]


@kernel
def _permute_flipped_rows(  # pragma: no cover - numba
    rows: NDArray[np.int64], flips: NDArray[np.bool_], first: int, second: int, third: int
) -> NDArray[np.int64]:
    """A copy of ``rows`` (N, 3) with each flipped row's columns in the order given."""
    result = np.empty_like(rows)
    for row in range(rows.shape[0]):
        if flips[row]:
            a, b, c = rows[row, first], rows[row, second], rows[row, third]
        else:
            a, b, c = rows[row, 0], rows[row, 1], rows[row, 2]
        result[row, 0], result[row, 1], result[row, 2] = a, b, c
    return result


def _same_cyclic_order(faces: NDArray[Any], others: NDArray[Any]) -> NDArray[np.bool_]:
    """Whether each triangle lists the same three vertices as its partner in the same turn."""
    same = np.zeros(len(faces), dtype=bool)
    for shift in range(3):
        same |= (np.roll(others, shift, axis=1) == faces).all(axis=1)
    return same


@kernel(inline=True)
def _find(parent: NDArray[np.int64], node: int) -> int:  # pragma: no cover - numba
    """Union-find root with path halving."""
    while parent[node] != node:
        parent[node] = parent[parent[node]]
        node = parent[node]
    return node


@kernel(inline=True)
def _find_linked(link: NDArray[np.integer[Any]], node: int) -> tuple[int, int]:  # pragma: no cover
    """(root, parity of ``node`` against it) in a union-find with parity packed as
    ``link[x] = 2 * parent + parity against the parent`` (one load per step); the path is
    pointed at the root."""
    root, total = node, 0
    while link[root] >> 1 != root:
        total ^= link[root] & 1
        root = link[root] >> 1
    remaining = total
    while True:
        following = link[node] >> 1
        if following == root or following == node:  # noqa: SIM109 - compiled
            break
        step = link[node] & 1
        link[node] = 2 * root + remaining
        remaining ^= step
        node = following
    return root, total


@kernel(inline=True)
def _join_linked(  # pragma: no cover - numba
    link: NDArray[np.integer[Any]], a: int, b: int, differ: int
) -> int:
    """Put ``a`` and ``b`` in one set of ``_find_linked`` with parity(a) ^ parity(b) ==
    ``differ``, under the lower root (kept as found where they already share one: a
    non-orientable surface); 1 where that contradicts the set's parities, else 0."""
    root_a, parity_a = _find_linked(link, a)
    root_b, parity_b = _find_linked(link, b)
    if root_a != root_b:
        low, high = min(root_a, root_b), max(root_a, root_b)
        link[high] = 2 * low + (parity_a ^ parity_b ^ differ)
        return 0
    return 1 if parity_a ^ parity_b != differ else 0


@kernel
def _join(parent: NDArray[np.int64], a: int, b: int) -> None:  # pragma: no cover - numba
    """Join the sets of ``a`` and ``b`` under the smaller root. No result: written as
    ``parent[max(a, b)] = min(a, b); return min(a, b)`` it compiled 4x slower in
    ``stitching._vertex_shells``' loop (and branches returning the root, 7x)."""
    a, b = _find(parent, a), _find(parent, b)
    if a < b:
        parent[b] = a
    elif b < a:
        parent[a] = b


#: The bits of ``_orient_patches``' byte per edge entry: its face runs the edge lo -> hi; its
#: face repeats a vertex; a hash of its face's third vertex (``_third_hash``).
_FORWARD, _COLLAPSED, _HASH = 1, 2, 0xFC


@kernel(inline=True)
def _third_hash(vertex: int) -> int:  # pragma: no cover - numba
    """Six bits of a multiplicative (Fibonacci) hash of ``vertex``, in ``_HASH``'s place:
    two faces on an edge whose third vertices hash apart are no copies of each other."""
    return (((vertex * -7046029254386353131) >> 58) & 63) << 2


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
def _orient_patches(  # pragma: no cover
    faces: NDArray[np.int64],
    edge_table: NDArray[np.int64],
    slot: NDArray[np.int64],
    vertices: NDArray[np.float64],
    centre: NDArray[np.float64],
    areas: NDArray[np.float64],
    link_type: NDArray[np.integer[Any]],
) -> tuple[
    NDArray[np.int64],
    NDArray[np.integer[Any]],
    NDArray[np.float64],
    NDArray[np.bool_],
    NDArray[np.float64],
    NDArray[np.float64],
    int,
    int,
    int,
    int,
]:
    """Duplicates, patches over manifold edges with a consistent relative winding, per
    patch its capped signed volume, openness, area and the area its relative winding
    reverses; shell, loop and non-manifold counts.

    Returns (first copy (F,) or -1, winding (F,): 2 * patch + relative flip, or -1
    (duplicates and collapsed faces), volume (P,), open (P,), area (P,), reversed area
    (P,), shells, boundary loops, non-manifold edges, manifold edges whose winding
    contradicts the patch's: a non-orientable patch, whose windings then follow the order
    of the joins, the edges' order). ``edge_table, slot`` from
    ``welded_edges``; ``areas`` (F,) the triangles' areas; ``link_type``: an empty array of
    the integers of the union-find (which becomes the winding in place).
    """
    face_count = faces.shape[0]
    edge_count = edge_table.shape[0]
    # Per edge entry, one byte written in face order (so the edges need no look-up of their
    # faces): whether its face runs it lo -> hi, whether that face repeats a vertex (such
    # faces take no part: their edges would pair them with themselves), and a hash of the
    # face's third vertex, off the edge.
    skip = np.zeros(face_count, dtype=np.bool_)
    entry = np.zeros(edge_count, dtype=np.uint8)
    # Patches: a union-find over faces whose parity says whether a face is wound against
    # its root (the patch's lowest face); joined across each manifold edge below.
    link = np.empty(face_count, link_type.dtype)
    top = -1  # the highest vertex: the edge keys are lo * (top + 1) + hi
    for face in range(face_count):
        link[face] = 2 * face
        a, b, c = faces[face, 0], faces[face, 1], faces[face, 2]
        top = max(top, a, b, c)
        if a == b or b == c or a == c:  # noqa: SIM109 - compiled
            skip[face] = True
            for corner in range(3):
                if slot[3 * face + corner] >= 0:
                    entry[slot[3 * face + corner]] = _COLLAPSED
            continue
        entry[slot[3 * face]] = (a < b) | _third_hash(c)
        entry[slot[3 * face + 1]] = (b < c) | _third_hash(a)
        entry[slot[3 * face + 2]] = (c < a) | _third_hash(b)
    n_vertices = top + 1
    # Manifold edges link faces; boundary and non-manifold edges join loops to cap.
    first_copy = np.full(face_count, -1, dtype=np.int64)
    cut_start = np.empty(edge_count, dtype=np.int64)  # edges of one face, or of 3 or more
    cut_end = np.empty(edge_count, dtype=np.int64)
    cut_hole = np.empty(edge_count, dtype=np.bool_)  # of one face
    cuts = 0
    non_manifold = 0
    conflicts = 0  # manifold edges whose join contradicts the set's parities
    i = 0
    while i < edge_count:
        j = i + 1
        while j < edge_count and edge_table[j, 0] == edge_table[i, 0]:
            j += 1
        if j - i == 2:
            first_entry, second_entry = entry[i], entry[i + 1]
            if (first_entry | second_entry) & _COLLAPSED == 0 and (
                first_entry ^ second_entry
            ) & _HASH != 0:
                # The usual manifold edge: two faces, neither collapsed, with different
                # third vertices (so neither a copy of the other, nor of any face: every
                # copy of a triangle is on each of its edges), what the general steps below
                # conclude for it without their look-ups of the faces.
                conflicts += _join_linked(
                    link,
                    edge_table[i, 1],
                    edge_table[i + 1, 1],
                    1 - ((first_entry ^ second_entry) & _FORWARD),
                )
                i = j
                continue
        if j - i >= 2:
            # Duplicates: the same third vertex on one edge. Every copy of a triangle is on
            # each of its edges, so the lowest face of the copies is their original on
            # whichever edge finds them first. Collapsed faces (``skip`` and no original)
            # take no part.
            lo, hi = edge_table[i, 0] // n_vertices, edge_table[i, 0] % n_vertices
            if j - i == 2:
                f, g = edge_table[i, 1], edge_table[i + 1, 1]
                usable = (not skip[f] or first_copy[f] >= 0) and (not skip[g] or first_copy[g] >= 0)
                if usable and _third_vertex(faces, f, lo, hi) == _third_vertex(faces, g, lo, hi):
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
            conflicts += _join_linked(link, f, g, 1 - ((entry[f_at] ^ entry[g_at]) & _FORWARD))
        elif members > 0:
            if members > 2:
                non_manifold += 1
            cut_start[cuts], cut_end[cuts], cut_hole[cuts] = i, j, members == 1
            cuts += 1
        i = j
    # Patch numbers by lowest face and relative windings, then (arrays sized by the patch
    # count, usually a handful rather than one per face) the areas and signed volumes.
    # In place, ``link`` becomes ``winding``: 2 * patch + relative winding, or -1. A face's
    # parent comes before it (sets join under the lower root, paths point at ancestors), so
    # the parent's entry is already rewritten: no walk up to the root.
    winding = link
    patch_count = 0
    for face in range(face_count):
        if skip[face]:
            winding[face] = -1  # never a parent: duplicates and collapsed faces join nothing
        elif link[face] >> 1 == face:
            winding[face] = 2 * patch_count
            patch_count += 1
        else:
            winding[face] = winding[link[face] >> 1] ^ (link[face] & 1)
    volume = np.zeros(patch_count)
    patch_area = np.zeros(patch_count)
    flipped_area = np.zeros(patch_count)
    point = np.zeros(6)
    point[:3] = centre
    for face in range(face_count):
        if skip[face]:
            continue
        patch = winding[face] >> 1
        a, b, c = faces[face, 0], faces[face, 1], faces[face, 2]
        patch_area[patch] += areas[face]
        if winding[face] & 1:
            b, c = c, b
            flipped_area[patch] += areas[face]
        volume[patch] += _signed_volume(vertices, a, b, c, point)
    # Loop centres: the vertices of each component of open edges (none on a closed mesh).
    per_vertex = n_vertices if cuts else 0
    vertex_parent = np.arange(per_vertex)
    on_hole = np.zeros(per_vertex, dtype=np.bool_)  # on an edge of one face
    for cut in range(cuts):
        key = edge_table[cut_start[cut], 0]
        on_hole[key // n_vertices] |= cut_hole[cut]
        _join(vertex_parent, key // n_vertices, key % n_vertices)
    loop_sum = np.zeros((per_vertex, 3))
    loop_size = np.zeros(per_vertex, dtype=np.int64)
    counted = np.zeros(per_vertex, dtype=np.bool_)
    seen = np.zeros(per_vertex, dtype=np.bool_)
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
            patch = winding[face] >> 1
            runs_forward = (entry[k] & _FORWARD) != (winding[face] & 1)
            # The cap runs the edge the other way round: (hi, lo, centre) after lo -> hi.
            if runs_forward:
                volume[patch] += _signed_volume(vertices, hi, lo, -1, point)
            else:
                volume[patch] += _signed_volume(vertices, lo, hi, -1, point)
            is_open[patch] = True
            # Shells: patches joined through non-manifold edges.
            if first < 0:
                first = patch
            else:
                _join(patch_parent, first, patch)
    shells = 0
    for p in range(patch_count):
        if _find(patch_parent, p) == p:
            shells += 1
    return (
        first_copy,
        winding,
        volume / 6.0,
        is_open,
        patch_area,
        flipped_area,
        shells,
        loops,
        non_manifold,
        conflicts,
    )


def _sheet_flux(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    winding: NDArray[np.integer[Any]],
    sheets: NDArray[np.bool_],
) -> NDArray[np.float64]:
    """Per patch, for the ``sheets`` (else 0): the sum over its triangles, wound as its
    first face, of twice the area times the normal dotted with the centroid's offset from
    the mean vertex: positive where the patch faces away from the mesh's centre."""
    flux = np.zeros(len(sheets))
    patch, chosen, corners, doubled = _sheet_triangles(vertices, faces, winding, sheets)
    if len(chosen) == 0:
        return flux
    offset = corners.mean(axis=1) - vertices.mean(axis=0)
    np.add.at(flux, patch, np.einsum("ij,ij->i", doubled, offset))
    return flux


def _sheet_triangles(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    winding: NDArray[np.integer[Any]],
    sheets: NDArray[np.bool_],
) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """The triangles of the ``sheets``: (their patch, their index, their corners (T, 3, 3),
    twice their area times their normal wound as their patch's first face (T, 3))."""
    patch = np.asarray(winding, dtype=np.int64) >> 1
    chosen = np.flatnonzero((np.asarray(winding) >= 0) & sheets[np.maximum(patch, 0)])
    corners = vertices[faces[chosen]]
    doubled = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    doubled *= (1.0 - 2.0 * (np.asarray(winding)[chosen] & 1))[:, None]
    return patch[chosen], chosen, corners, doubled


def _sheet_skew(
    vertices: NDArray[np.float64],
    faces: NDArray[np.int64],
    areas: NDArray[np.float64],
    winding: NDArray[np.integer[Any]],
    sheets: NDArray[np.bool_],
) -> NDArray[np.float64]:
    """Per patch, for the fairly flat ``sheets`` (mean normal at least half their area;
    else 0): the third moment of the whole mesh's area about the sheet's plane, along its
    normal wound as its first face (positive: skewed to the side the sheet faces). The
    mesh's area moments up to the third are summed once (``geometry.weighted_moments``); each sheet
    then costs a few 3 x 3 products."""
    skew = np.zeros(len(sheets))
    patch, chosen, corners, doubled = _sheet_triangles(vertices, faces, winding, sheets)
    weight = float(areas.sum())
    if len(chosen) == 0 or not weight > 0:
        return skew
    centre, second, third = weighted_moments(face_centroids(vertices, faces), areas)
    normal_sum = np.zeros((len(sheets), 3))
    np.add.at(normal_sum, patch, doubled)
    area_sum = np.zeros(len(sheets))
    np.add.at(area_sum, patch, areas[chosen])
    moment = np.zeros((len(sheets), 3))
    np.add.at(moment, patch, areas[chosen, None] * (corners.mean(axis=1) - centre))
    for p in np.flatnonzero(area_sum > 0):
        length = float(np.linalg.norm(normal_sum[p]))
        if length < area_sum[p]:  # |sum of doubled areas| below half: not flat enough
            continue
        n = normal_sum[p] / length
        t = float(moment[p] @ n) / area_sum[p]  # the sheet's plane, along n from the centre
        cubed = float(np.einsum("ijk,i,j,k->", third, n, n, n))
        skew[p] = cubed - 3 * t * float(n @ second @ n) - t**3 * weight
    return skew


@kernel
def _face_flips(  # pragma: no cover - numba
    winding: NDArray[np.integer[Any]], patch_flip: NDArray[np.bool_]
) -> NDArray[np.bool_]:
    """Per face (``winding``: 2 * patch + winding against the patch's root, -1 for faces of
    no patch): that winding, reversed where the patch is; False for faces of no patch
    (duplicates, collapsed faces)."""
    flips = np.zeros(len(winding), dtype=np.bool_)
    for face in range(len(winding)):
        if winding[face] >= 0:
            flips[face] = (winding[face] & 1 != 0) != patch_flip[winding[face] >> 1]
    return flips


def boundary_edge_rows(edge_table: NDArray[Any]) -> NDArray[np.int64]:
    """Rows of a ``welded_edges`` table whose vertex pair has no other entry: the open
    boundary's edges (each on one triangle)."""
    return _alone_rows(np.ascontiguousarray(edge_table, dtype=np.int64).reshape(-1, 2))


@kernel
def _alone_rows(edge_table: NDArray[np.int64]) -> NDArray[np.int64]:  # pragma: no cover
    """``boundary_edge_rows`` in two passes over the keys (count, then fill) instead of
    numpy's four boolean temporaries; the result sized to the boundary."""
    count = edge_table.shape[0]
    found = 0
    for row in range(count):
        key = edge_table[row, 0]
        if (row == 0 or edge_table[row - 1, 0] != key) and (
            row + 1 == count or edge_table[row + 1, 0] != key
        ):
            found += 1
    rows = np.empty(found, dtype=np.int64)
    found = 0
    for row in range(count):
        key = edge_table[row, 0]
        if (row == 0 or edge_table[row - 1, 0] != key) and (
            row + 1 == count or edge_table[row + 1, 0] != key
        ):
            rows[found] = row
            found += 1
    return rows


def open_boundary_faces(
    edges: tuple[NDArray[np.int64], NDArray[np.int64]], face_count: int
) -> NDArray[np.bool_]:
    """(F,) whether each triangle has an open boundary edge (``welded_edges``' ``edges``):
    the rims of holes, of a missing base and of slits left between shells."""
    edge_table, _ = edges
    rim = np.zeros(face_count, dtype=bool)
    rim[np.asarray(edge_table)[boundary_edge_rows(edge_table), 1]] = True
    return rim


def hole_caps(
    vertices: NDArray[Any], faces: NDArray[Any], edges: tuple[NDArray[np.int64], NDArray[np.int64]]
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Triangles that close every open boundary loop of ``faces`` for ray casting only.

    ``faces``: (welded) triangles that already face outward; ``edges``: their
    ``welded_edges``. Each boundary edge (on one triangle) gets the triangle from its ends
    to the centroid of its loop, wound as its triangle's neighbour across the edge would
    be: a ray that leaves through a hole then meets the cap there, as it would have met
    the missing surface, instead of whatever lies beyond. Returns the vertices with one
    centroid per loop appended, and the cap triangles (indices into those vertices); none
    where boundary edges outnumber ``MAX_BOUNDARY_SHARE`` of the triangles.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    edge_table, _ = edges
    keys = edge_table[:, 0]
    boundary = boundary_edge_rows(edge_table)
    if len(boundary) == 0 or len(boundary) > MAX_BOUNDARY_SHARE * len(faces):
        return vertices, np.zeros((0, 3), dtype=np.int64)
    n_vertices = int(faces.max()) + 1
    lo, hi = keys[boundary] // n_vertices, keys[boundary] % n_vertices
    owner = faces[edge_table[boundary, 1]]
    runs_forward = np.zeros(len(boundary), dtype=bool)
    for corner in range(3):
        runs_forward |= (owner[:, corner] == lo) & (owner[:, (corner + 1) % 3] == hi)
    start, end = np.where(runs_forward, hi, lo), np.where(runs_forward, lo, hi)
    # Loops: components of the boundary edges over their vertices.
    used, local = np.unique(np.concatenate([start, end]), return_inverse=True)
    graph = coo_matrix(
        (np.ones(len(boundary)), (local[: len(boundary)], local[len(boundary) :])),
        shape=(len(used), len(used)),
    )
    count, loop_of = connected_components(graph, directed=False)
    size = np.bincount(loop_of, minlength=count)
    centres = (
        np.stack(
            [
                np.bincount(loop_of, weights=vertices[used, axis], minlength=count)
                for axis in range(3)
            ],
            axis=1,
        )
        / size[:, None]
    )
    loop = loop_of[local[: len(boundary)]]
    caps = np.stack([start, end, len(vertices) + loop], axis=1)
    return np.vstack([vertices, centres]), caps
