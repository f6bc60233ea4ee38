"""Proximity stitching: open shells that meet along a cut become one surface for the graphs.

A kitbashed or CAD assembly, or an export that splits a surface into pieces, gives open
shells whose boundaries run along each other, a little apart (each piece moved, rounded
or re-tessellated). Left apart, each piece is a solid of its own for the orientation
pass, each boundary loop gets a cap for the ShDF's rays (a lid through the middle of a
limb), and the segmentation's graph has no edge between the pieces.

``stitch_shells`` joins, for the graphs only (never the output), boundary vertices of
different shells that are each other's nearest boundary vertex of another shell and lie
within ``STITCH_TOLERANCE`` times their local boundary edge length (the mean length of
the boundary edges at the two vertices). What is stitched and what is not:

* only vertices on open boundaries (an edge of one triangle), and only between
  different shells (pieces connected through shared vertices): a hole in one piece, a
  closed shell (eyes in a head, a bolt in a plate) and anything farther apart than the
  tolerance stay as they are;
* pairs are mutual nearest neighbours, so each vertex joins at most one other and no
  triangle collapses; a boundary edge whose two ends join the two ends of another
  shell's boundary edge becomes an ordinary edge between the two pieces;
* pieces moved farther apart than about half their boundary's spacing: the first pairs
  give, per two shells that meet, the median offset from one to the other, and the
  points are matched again with each shell moved by it (``_rigid_pairs``), then with each
  point moved by its nearest stitches' offset (``_guided_pairs``: pieces not moved as a
  whole);
* meshes with no open boundary, or a single shell, are returned unchanged (the same array),
  and so are mostly open ones (boundary edges more than ``MAX_BOUNDARY_SHARE`` of the
  triangles, as ``orientation.hole_caps``: separate sheets, not a surface cut in pieces),
  which also bounds the work to a share of the mesh.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.geometry import FaceGraph
from neural_shdf.orientation import (
    MAX_BOUNDARY_SHARE,
    _find,
    _join,
    boundary_edge_rows,
    hole_caps,
)

#: Boundary vertices of different shells closer than this many local boundary edge
#: lengths (their boundary edges' mean length) are stitched.
STITCH_TOLERANCE = 3.0
#: Nearest boundary vertices looked at per boundary vertex for one of another shell.
_NEIGHBOURS = 16
#: Rounds that match again with each shell moved by its stitches' median offset to each
#: shell it is stitched to (``_rigid_pairs``), before the guided rounds.
_RIGID_ROUNDS = 3
#: Stitches between two shells needed to move one onto the other rigidly.
_RIGID_MIN_STITCHES = 3
#: Rounds that match again with each vertex moved by its nearest stitches' offset.
_GUIDED_ROUNDS = 8
#: How far (in local boundary edge lengths) a guided pair may lie from where the offset
#: of the nearest stitches of its shell predicts.
_GUIDED_SLACK = 1.0
#: Passes that undo stitches which fold the surface, each followed by stitching again.
_UNDO_PASSES = 2


def boundary_edges(
    edges: tuple[NDArray[np.int64], NDArray[np.int64]], vertex_count: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(lo, hi) vertex indices of the edges of only one triangle, from ``welded_edges``."""
    boundary = edges[0][boundary_edge_rows(edges[0]), 0]
    return boundary // vertex_count, boundary % vertex_count


def stitch_shells(
    vertices: NDArray[Any],
    welded: NDArray[Any],
    edges: tuple[NDArray[np.int64], NDArray[np.int64]],
    tolerance: float = STITCH_TOLERANCE,
) -> NDArray[np.int64]:
    """``welded`` with the boundary vertices of different shells that meet sharing one index.

    ``welded``: triangles with coincident vertices welded (``geometry.weld_faces``);
    ``edges``: their ``orientation.welded_edges``. Returns ``welded`` itself where nothing
    is stitched. Each stitched pair takes the index of its vertex of lower position (x,
    then y, then z: the same vertex whatever order the file lists them in).
    """
    given = welded
    welded = np.asarray(welded, dtype=np.int64).reshape(-1, 3)
    if len(welded) == 0:
        return given
    vertex_count = int(welded.max()) + 1
    lo, hi = boundary_edges(edges, vertex_count)
    if len(lo) == 0 or len(lo) > MAX_BOUNDARY_SHARE * len(welded):
        return given  # closed, or mostly open (separate sheets): no surface to restore
    shell = _vertex_shells(welded, vertex_count)
    on_boundary, local = np.unique(np.concatenate([lo, hi]), return_inverse=True)
    boundary_shell = shell[on_boundary]
    if np.all(boundary_shell == boundary_shell[0]):
        return given
    points = np.asarray(vertices, dtype=np.float64)[on_boundary]
    ends = local.reshape(2, -1)
    length = np.linalg.norm(points[ends[0]] - points[ends[1]], axis=1)
    incident = np.bincount(ends.reshape(-1), minlength=len(on_boundary))
    scale = np.bincount(ends.reshape(-1), np.tile(length, 2), len(on_boundary)) / incident
    partner = np.full(len(points), -1, dtype=np.int64)
    pairs = _mutual_nearest(points, boundary_shell, scale, tolerance)
    for rounds, match in ((_RIGID_ROUNDS, _rigid_pairs), (_GUIDED_ROUNDS, _guided_pairs)):
        for _ in range(rounds):
            partner[:] = -1
            partner[pairs[:, 0]], partner[pairs[:, 1]] = pairs[:, 1], pairs[:, 0]
            again = match(points, boundary_shell, scale, partner)
            if len(again) <= len(pairs):
                break
            pairs = again
    partner[:] = -1
    partner[pairs[:, 0]], partner[pairs[:, 1]] = pairs[:, 1], pairs[:, 0]
    stitched = welded
    for _ in range(_UNDO_PASSES + 1):
        joined = np.flatnonzero(partner >= 0)
        if len(joined) == 0:
            return given
        representative = np.arange(vertex_count, dtype=np.int64)
        a, b = on_boundary[joined], on_boundary[partner[joined]]
        kept = np.where(_lower_position(points[joined], points[partner[joined]]), a, b)
        representative[a + b - kept] = kept
        stitched = representative[welded]
        # A stitch that puts an edge on three triangles or more folds the surface (the
        # pair did not run along each other): undo the stitches at the fold's ends.
        touched = np.zeros(vertex_count, dtype=bool)
        touched[kept] = True
        near = stitched[touched[stitched].any(axis=1)]  # only their edges can have changed
        folded = _edges_on_many(near, vertex_count)
        undo = np.isin(representative[on_boundary], folded) & (partner >= 0)
        if not undo.any():
            break
        partner[partner[undo]] = -1
        partner[undo] = -1
    return stitched


def _lower_position(first: NDArray[Any], second: NDArray[Any]) -> NDArray[np.bool_]:
    """Per row, whether ``first``'s point comes before ``second``'s (x, then y, then z)."""
    differs = first != second
    axis = np.argmax(differs, axis=1)  # the first coordinate that differs
    rows = np.arange(len(first))
    lower: NDArray[np.bool_] = first[rows, axis] < second[rows, axis]
    return lower


def stitch_counts(coincident: NDArray[Any], stitched: NDArray[Any]) -> tuple[int, int]:
    """(shells joined to another shell, vertices merged into another) by ``stitch_shells``:
    ``coincident`` its input triangles, ``stitched`` its result. (0, 0) where it returned
    its input."""
    if stitched is coincident:
        return 0, 0
    coincident = np.asarray(coincident, dtype=np.int64).reshape(-1, 3)
    stitched = np.asarray(stitched, dtype=np.int64).reshape(-1, 3)
    vertex_count = int(coincident.max()) + 1
    vertices = len(np.unique(coincident)) - len(np.unique(stitched))
    before = _vertex_shells(coincident, vertex_count)[coincident[:, 0]]
    after = _vertex_shells(stitched, vertex_count)[stitched[:, 0]]
    # A shell is stitched when the shell it ends up in holds faces of another shell.
    pairs = np.unique(np.stack([after, before], axis=1), axis=0)
    joined, members = np.unique(pairs[:, 0], return_counts=True)
    shells = int(members[members > 1].sum())
    return shells, int(vertices)


def _rigid_pairs(
    points: NDArray[np.float64],
    shell: NDArray[Any],
    scale: NDArray[np.float64],
    partner: NDArray[np.int64],
) -> NDArray[np.int64]:
    """(P, 2) pairs matched again, each shell's points moved by the median offset of its
    stitches (paired points) to each shell it is stitched to (at least
    ``_RIGID_MIN_STITCHES``), nearest within ``_GUIDED_SLACK`` local boundary edge lengths of
    where that offset puts them, the closest over those shells, kept where mutual. A piece
    moved as a whole (an assembly's parts exported apart, a surface cut and shifted) has one
    offset along its whole cut; the guided rounds' offsets of the nearest few stitches
    follow a run of wrong first stitches (nearest points across a gap of about the boundary's
    spacing are often a neighbour of each other's counterpart) and leave slits."""
    from scipy.spatial import cKDTree

    anchors = np.flatnonzero(partner >= 0)
    if len(anchors) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    links, link_of, counts = np.unique(
        np.stack([shell[anchors], shell[partner[anchors]]], axis=1),
        axis=0,
        return_inverse=True,
        return_counts=True,
    )
    # Stitches grouped by their two shells, points by their shell: no pass over all the
    # points per pair of shells (an assembly may have thousands).
    by_link = np.split(anchors[np.argsort(link_of.reshape(-1), kind="stable")], np.cumsum(counts))
    order = np.argsort(shell, kind="stable")
    shells, starts = np.unique(shell[order], return_index=True)
    members_of = dict(zip(shells.tolist(), np.split(order, starts[1:]), strict=True))
    best = np.full(len(points), -1, dtype=np.int64)
    best_distance = np.full(len(points), np.inf)
    trees: dict[int, Any] = {}
    for (a, b), stitched in zip(links.tolist(), by_link, strict=False):
        if len(stitched) < _RIGID_MIN_STITCHES:
            continue
        offset = np.median(points[partner[stitched]] - points[stitched], axis=0)
        members = members_of[b]
        if b not in trees:
            trees[b] = cKDTree(points[members])
        rows = members_of[a]
        distance, found = trees[b].query(points[rows] + offset)
        found = members[found]
        limit = 0.5 * _GUIDED_SLACK * (scale[rows] + scale[found])
        better = (distance <= limit) & (distance < best_distance[rows])
        best[rows[better]] = found[better]
        best_distance[rows[better]] = distance[better]
    return _mutual_pairs(best)


def _mutual_pairs(best: NDArray[np.int64]) -> NDArray[np.int64]:
    """(P, 2) pairs of points that are each other's ``best`` (-1: none), lower index first."""
    chosen = np.flatnonzero(best >= 0)
    mutual = chosen[(best[best[chosen]] == chosen) & (chosen < best[chosen])]
    return np.stack([mutual, best[mutual]], axis=1)


def _guided_pairs(
    points: NDArray[np.float64],
    shell: NDArray[Any],
    scale: NDArray[np.float64],
    partner: NDArray[np.int64],
) -> NDArray[np.int64]:
    """(P, 2) pairs matched again, each point moved by the mean offset of the stitches
    (paired points) nearest to it in its shell, towards their shell: where two pieces were
    moved apart by about the boundary's spacing or more, nearest points across the gap are
    often a neighbour of each other's counterpart, and mixing such shifts leaves slits."""
    from scipy.spatial import cKDTree

    anchors = np.flatnonzero(partner >= 0)
    if len(anchors) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    count = min(_NEIGHBOURS, len(anchors))
    _, near = cKDTree(points[anchors]).query(points, k=count)
    near = anchors[near.reshape(len(points), -1)]
    # Stitches of the point's own shell that go where its nearest such stitch goes.
    nearest_own = np.argmax(shell[near] == shell[:, None], axis=1)
    target = shell[partner[near[np.arange(len(points)), nearest_own]]]
    same = (shell[near] == shell[:, None]) & (shell[partner[near]] == target[:, None])
    has = same.any(axis=1)
    offset = np.zeros_like(points)
    for column in range(near.shape[1]):  # a column at a time: no (P, k, 3) array
        rows = np.flatnonzero(same[:, column])
        anchor = near[rows, column]
        offset[rows] += points[partner[anchor]] - points[anchor]
    offset /= np.maximum(same.sum(axis=1), 1)[:, None]
    predicted = points + offset
    count = min(_NEIGHBOURS, len(points))
    distance, found = cKDTree(points).query(predicted, k=count)
    distance, found = distance.reshape(len(points), -1), found.reshape(len(points), -1)
    limit = 0.5 * _GUIDED_SLACK * (scale[:, None] + scale[found])
    candidate = has[:, None] & (shell[found] == target[:, None]) & (distance <= limit)
    chosen = np.flatnonzero(candidate.any(axis=1))
    best = np.full(len(points), -1, dtype=np.int64)
    best[chosen] = found[chosen, np.argmax(candidate[chosen], axis=1)]
    return _mutual_pairs(best)


def _edges_on_many(faces: NDArray[np.int64], vertex_count: int) -> NDArray[np.int64]:
    """Vertices of the edges that three triangles or more share."""
    keys = np.sort(
        np.sort(np.stack([faces, faces[:, [1, 2, 0]]], axis=2), axis=2)
        @ np.array([vertex_count, 1], dtype=np.int64),
        axis=None,
    )
    many = keys[2:][keys[2:] == keys[:-2]]
    return np.unique(np.concatenate([many // vertex_count, many % vertex_count]))


def _mutual_nearest(
    points: NDArray[np.float64], shell: NDArray[Any], scale: NDArray[np.float64], tolerance: float
) -> NDArray[np.int64]:
    """(P, 2) pairs of points of different shells, each the other's nearest such point
    within ``tolerance`` times their mean ``scale``."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    reach = tolerance * float(scale.max())
    count = min(_NEIGHBOURS, len(points))
    distance, neighbour = cKDTree(points).query(points, k=count, distance_upper_bound=reach)
    distance, neighbour = distance.reshape(len(points), -1), neighbour.reshape(len(points), -1)
    found = neighbour < len(points)
    other = np.where(found, neighbour, 0)
    limit = 0.5 * tolerance * (scale[:, None] + scale[other])
    candidate = found & (shell[other] != shell[:, None]) & (distance <= limit)
    # The nearest candidate (query results are sorted by distance), kept where mutual.
    has = np.flatnonzero(candidate.any(axis=1))
    best = np.full(len(points), -1, dtype=np.int64)
    best[has] = other[has, np.argmax(candidate[has], axis=1)]
    return _mutual_pairs(best)


@kernel
def _vertex_shells(  # pragma: no cover - numba
    faces: NDArray[np.int64], vertex_count: int
) -> NDArray[np.int64]:
    """Per vertex, the lowest vertex of its shell (vertices connected through triangles)."""
    parent = np.arange(vertex_count)
    for face in range(faces.shape[0]):
        _join(parent, faces[face, 0], faces[face, 1])
        _join(parent, faces[face, 0], faces[face, 2])
    for vertex in range(vertex_count):
        parent[vertex] = _find(parent, vertex)
    return parent


def stitched_edge_geometry(
    graph: FaceGraph,
    vertices: NDArray[Any],
    faces: NDArray[Any],
    normals: NDArray[Any],
    coincident: NDArray[Any],
    welded: NDArray[Any],
) -> FaceGraph:
    """``graph`` (built on ``welded``) with the length and concavity of the edges at stitched
    vertices measured on each triangle's own vertices, as if the pieces were not apart.

    A stitched index stands for two vertices a gap apart, so the length and fold measured
    at its one position are off by the gap (a crease read as concave is cheap to cut).
    Each edge's length is the mean of its two triangles' own edges, and its fold is measured
    from each triangle with the other moved so that its copy of the edge meets it, the two
    measures summed (neither triangle's index decides: the same in any face order).
    ``faces``, ``normals``, ``coincident`` and ``welded``: the triangles ``graph`` was built
    on (same winding) and their normals, with coincident vertices welded, and stitched too.
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    welded = np.asarray(welded, dtype=np.int64).reshape(-1, 3)
    changed = np.asarray(coincident).reshape(-1, 3) != welded
    if not changed.any() or len(graph.pairs) == 0:
        return graph
    vertices = np.asarray(vertices, dtype=np.float64)
    stitched = np.zeros(int(welded.max()) + 1, dtype=bool)
    stitched[welded[changed]] = True
    lo_all, hi_all = graph.edge_vertices[:, 0], graph.edge_vertices[:, 1]
    # Pairs with a stitched vertex on the edge or off it (the fold is measured there too).
    touching: NDArray[np.bool_] = np.any(stitched[welded], axis=1)
    at = np.flatnonzero(touching[graph.pairs[:, 0]] | touching[graph.pairs[:, 1]])
    lo, hi = lo_all[at][:, None], hi_all[at][:, None]
    normals = np.asarray(normals)
    length = np.zeros(len(at))
    fold = np.zeros(len(at))
    # Each triangle's own edge, and the other's third vertex moved onto it: measured from
    # both sides and averaged, so that neither triangle's index decides.
    for a, b in (
        (graph.pairs[at, 0], graph.pairs[at, 1]),
        (graph.pairs[at, 1], graph.pairs[at, 0]),
    ):
        a_lo, a_hi = np.argmax(welded[a] == lo, axis=1), np.argmax(welded[a] == hi, axis=1)
        b_lo, b_hi = np.argmax(welded[b] == lo, axis=1), np.argmax(welded[b] == hi, axis=1)
        own_lo, own_hi = vertices[faces[a, a_lo]], vertices[faces[a, a_hi]]
        shift = 0.5 * (own_lo - vertices[faces[b, b_lo]] + own_hi - vertices[faces[b, b_hi]])
        off_edge = vertices[faces[b, (3 - b_lo - b_hi) % 3]] + shift
        length += 0.5 * np.linalg.norm(own_lo - own_hi, axis=1)
        fold += np.einsum("ij,ij->i", off_edge - own_lo, normals[a])
    edge_length = graph.edge_length.copy()
    concave = graph.concave.copy()
    edge_length[at] = length
    concave[at] = fold > 0
    return replace(graph, edge_length=edge_length, concave=concave)


def bridge_gaps(
    vertices: NDArray[Any],
    coincident: NDArray[Any],
    welded: NDArray[Any],
    edges: tuple[NDArray[np.int64], NDArray[np.int64]],
    caps: NDArray[np.int64],
    tolerance: float = STITCH_TOLERANCE,
) -> NDArray[np.int64]:
    """``caps`` (``orientation.hole_caps`` of ``welded``) with the loops left open between
    stitched shells bridged across instead of fanned to their centroid.

    Where the stitching leaves a slit (pieces moved apart by more than the boundary's
    spacing do not pair everywhere), the slit's loop runs along both pieces, and a fan to
    its centroid would be a lid through the solid. Each boundary edge with a boundary
    vertex of another shell within ``tolerance`` edge lengths gets the triangle from its
    ends to the nearest such vertex (wound as its cap was); every loop with such an edge
    is bridged that way only. ``coincident``: the triangles with coincident vertices
    welded, which say the shells; ``edges``: ``welded``'s ``orientation.welded_edges``.
    """
    from scipy.spatial import cKDTree

    caps = np.asarray(caps, dtype=np.int64).reshape(-1, 3)
    if len(caps) == 0:
        return caps
    vertices = np.asarray(vertices, dtype=np.float64)
    coincident = np.asarray(coincident, dtype=np.int64).reshape(-1, 3)
    welded = np.asarray(welded, dtype=np.int64).reshape(-1, 3)
    shell = _vertex_shells(coincident, len(vertices))
    start, end, loop = caps[:, 0], caps[:, 1], caps[:, 2]
    # The shell of the triangle on each cap's edge (a stitched index stands for two shells).
    vertex_count = int(welded.max()) + 1
    keys = np.minimum(start, end) * vertex_count + np.maximum(start, end)
    table = edges[0]
    owner = table[np.searchsorted(table[:, 0], keys), 1]
    own_shell = shell[coincident[owner, 0]]
    ends = np.unique(np.concatenate([start, end]))
    middle = 0.5 * (vertices[start] + vertices[end])
    length = np.linalg.norm(vertices[start] - vertices[end], axis=1)
    count = min(_NEIGHBOURS, len(ends))
    distance, found = cKDTree(vertices[ends]).query(
        middle, k=count, distance_upper_bound=tolerance * float(length.max())
    )
    distance, found = distance.reshape(len(caps), -1), found.reshape(len(caps), -1)
    inside = found < len(ends)
    nearest = ends[np.where(inside, found, 0)]
    candidate = inside & (shell[nearest] != own_shell[:, None])
    candidate &= distance <= tolerance * length[:, None]
    candidate &= (nearest != start[:, None]) & (nearest != end[:, None])
    bridged = candidate.any(axis=1)
    if not bridged.any():
        return caps
    target = nearest[
        np.arange(len(caps)), _nearest_candidate(distance, nearest, candidate, vertices)
    ]
    slit = np.isin(loop, loop[bridged])
    # The slits' other edges (a piece's own boundary between stitches, farther across than
    # the tolerance): bridged to the nearest vertex of another shell at any distance, so
    # that the slit leaves no hole; a fan triangle where none is among the nearest.
    rest = np.flatnonzero(slit & ~bridged)
    if len(rest):
        distance, found = cKDTree(vertices[ends]).query(middle[rest], k=count)
        far = ends[found.reshape(len(rest), -1)]
        other = (shell[far] != own_shell[rest, None]) & (far != start[rest, None])
        other &= far != end[rest, None]
        reached = other.any(axis=1)
        column = _nearest_candidate(distance.reshape(len(rest), -1), far, other, vertices)
        target[rest[reached]] = far[reached, column[reached]]
        bridged[rest[reached]] = True
    bridges = np.stack([start, end, target], axis=1)[slit & bridged]
    return np.vstack([caps[~(slit & bridged)], bridges])


def _nearest_candidate(
    distance: NDArray[Any], nearest: NDArray[Any], candidate: NDArray[Any], vertices: NDArray[Any]
) -> NDArray[np.int64]:
    """Per row, the column of the nearest ``candidate`` (ties: the vertex of lower position,
    x then y then z, not of lower index: the same vertex whatever order the file lists
    them in); 0 where a row has none."""
    rows, columns = distance.shape
    key = np.where(candidate, distance, np.inf)
    points = vertices[nearest]
    order = np.lexsort(
        (
            points[..., 2].ravel(),
            points[..., 1].ravel(),
            points[..., 0].ravel(),
            key.ravel(),
            np.repeat(np.arange(rows), columns),
        )
    )
    first: NDArray[np.int64] = order.reshape(rows, columns)[:, 0] - np.arange(rows) * columns
    return first


def closing_caps(
    vertices: NDArray[Any],
    coincident: NDArray[Any],
    welded: NDArray[Any],
    edges: tuple[NDArray[np.int64], NDArray[np.int64]],
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """(vertices with a centroid per open loop appended, triangles) that close the open
    loops of the outward-facing ``welded`` triangles (``edges``: their ``welded_edges``;
    ``coincident``: the triangles before stitching): ``orientation.hole_caps``' fans, with
    the slits left between stitched shells bridged (``bridge_gaps``) and the bridges first."""
    vertices_out, caps = hole_caps(vertices, welded, edges)
    if coincident is not welded:  # slits left between stitched shells
        caps = bridge_gaps(vertices, coincident, welded, edges, caps)
        # Bridges (to a vertex of the surface) first: they count as surface for the rays.
        caps = caps[np.argsort(caps[:, 2] >= len(vertices), kind="stable")]
    return vertices_out, caps


def cap_spokes(
    vertices: NDArray[Any],
    surface_vertex_count: int,
    welded: NDArray[Any],
    edges: tuple[NDArray[np.int64], NDArray[np.int64]],
    caps: NDArray[Any],
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Where two fan triangles of a hole's cap meet: (the mesh's triangles on their rim
    edges (S, 2), the length of the spoke they share (S,)).

    Where the two triangles lie in different parts, the boundary between the parts runs
    into the hole; over the cap it would go on along the spokes
    (``segment.hierarchy.merge_tree``). ``vertices``, ``caps``: ``closing_caps``' (the
    mesh's ``surface_vertex_count`` vertices, then a centroid per loop: its fan); ``welded``,
    ``edges``: the triangles the caps close and their ``welded_edges``. Slits bridged
    between shells have no spoke.
    """
    caps = np.asarray(caps, dtype=np.int64).reshape(-1, 3)
    fans = caps[caps[:, 2] >= surface_vertex_count]
    if len(fans) == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    start, end, centre = fans[:, 0], fans[:, 1], fans[:, 2]
    total = len(vertices)
    # The fan triangle that starts where each one ends, over the same loop (a loop is a
    # cycle; where a rim touches itself a vertex starts two: either will do).
    keys = start * total + centre
    order = np.argsort(keys, kind="stable")
    wanted = end * total + centre
    following = order[np.minimum(np.searchsorted(keys[order], wanted), len(order) - 1)]
    found = keys[following] == wanted
    vertex_count = int(np.asarray(welded).max()) + 1
    table = np.asarray(edges[0])
    low, high = np.minimum(start, end), np.maximum(start, end)
    owner = table[np.searchsorted(table[:, 0], low * vertex_count + high), 1]
    pairs = np.stack([owner, owner[following]], axis=1)[found]
    points = np.asarray(vertices, dtype=np.float64)
    spoke = points[end[found]] - points[centre[found]]
    return pairs, np.linalg.norm(spoke, axis=1)


#: Share of the boundary edges between two stitched shells that must agree on their relative
#: winding for the two to be oriented together (a few wrong stitches do not decide it).
SEAM_VOTE_SHARE = 2.0 / 3.0


def orient_stitched_shells(
    vertices: NDArray[Any],
    coincident: NDArray[Any],
    coincident_edges: tuple[NDArray[np.int64], NDArray[np.int64]],
    stitched: NDArray[Any],
    edges: tuple[NDArray[np.int64], NDArray[np.int64]],
    flips: NDArray[Any],
    normals: NDArray[Any],
    areas: NDArray[Any],
) -> NDArray[np.bool_]:
    """``flips`` (``orientation.orient_faces`` of ``coincident``: each shell on its own) with
    shells stitched together turned to one winding and out of the solid they make together.

    A piece cut from a surface cannot always tell its outside from its own capped volume: a
    band of a thin-walled cup (outer wall, rim, inner wall) closed by a fan over each of its
    two loops encloses a negative volume when its inner side reaches deeper than its outer
    one, and the whole piece was turned inside out. Here each open boundary edge of a shell
    (``coincident``, ``coincident_edges``: its ``orientation.welded_edges``) votes with the
    nearest boundary edge of another shell stitched to it (``stitched``, ``edges``: the
    stitched triangles and their edges) within ``STITCH_TOLERANCE`` edge lengths: wound
    alike, the surface goes on across the cut, so their triangles face the same way.
    Shells whose edges agree (``SEAM_VOTE_SHARE``, clearest pairs first) join a group,
    which faces out by the signed volume of the group closed by ``closing_caps`` (where
    that cannot decide, as its largest shell decided alone). Shells in no group keep
    ``flips``.
    Returns ``flips`` itself where nothing is stitched or nothing changes.
    """
    from scipy.spatial import cKDTree

    from neural_shdf.orientation import AMBIGUOUS_VOLUME, reverse_rows

    flips = np.asarray(flips, dtype=bool)
    if stitched is coincident or len(flips) == 0:
        return flips
    vertices = np.asarray(vertices, dtype=np.float64)
    coincident = np.asarray(coincident, dtype=np.int64).reshape(-1, 3)
    stitched = np.asarray(stitched, dtype=np.int64).reshape(-1, 3)
    # Shells numbered 0.. in order of their lowest vertex (no sort: a pass over the roots).
    root = _vertex_shells(coincident, len(vertices))
    is_root = np.zeros(len(vertices), dtype=bool)
    is_root[root[coincident[:, 0]]] = True
    vertex_shell = (np.cumsum(is_root) - 1)[root]
    face_shell = vertex_shell[coincident[:, 0]]
    shell_count = int(face_shell.max()) + 1
    # Shells stitched to each other: a stitched corner takes a vertex of the other shell.
    changed = coincident != stitched
    ours, theirs = vertex_shell[coincident[changed]], vertex_shell[stitched[changed]]
    stitched_pairs = np.unique(np.minimum(ours, theirs) * shell_count + np.maximum(ours, theirs))
    # Each shell's open boundary edges and the normal of their triangle as ``flips`` winds it.
    own_table = np.asarray(coincident_edges[0])
    rows = boundary_edge_rows(own_table)
    if len(rows) == 0:
        return flips
    owner = own_table[rows, 1]
    lo, hi = boundary_edges(coincident_edges, int(coincident.max()) + 1)
    normal = np.where(flips[owner, None], -1.0, 1.0) * np.asarray(normals)[owner]
    length = np.linalg.norm(vertices[hi] - vertices[lo], axis=1)
    middle = 0.5 * (vertices[lo] + vertices[hi])
    shell = face_shell[owner]
    count = min(_NEIGHBOURS, len(rows))
    distance, found = cKDTree(middle).query(
        middle, k=count, distance_upper_bound=STITCH_TOLERANCE * float(length.max())
    )
    distance, found = distance.reshape(len(rows), -1), found.reshape(len(rows), -1)
    inside = found < len(rows)
    other = np.where(inside, found, 0)
    low = np.minimum(shell[other], shell[:, None])
    high = np.maximum(shell[other], shell[:, None])
    candidate = inside & (low != high) & np.isin(low * shell_count + high, stitched_pairs)
    candidate &= distance <= 0.5 * STITCH_TOLERANCE * (length[:, None] + length[other])
    voting = np.flatnonzero(candidate.any(axis=1))
    if len(voting) == 0:
        return flips
    nearest = other[voting, np.argmax(candidate[voting], axis=1)]
    # Across a cut the surface goes on: wound alike, the triangles on either side face
    # the same way (a fold of more than 60 degrees along the cut casts no vote).
    facing = np.einsum("ij,ij->i", normal[voting], normal[nearest])
    clear = np.abs(facing) >= 0.5
    voting, nearest, agree = voting[clear], nearest[clear], facing[clear] > 0
    if len(voting) == 0:
        return flips
    a = np.minimum(shell[voting], shell[nearest])
    b = np.maximum(shell[voting], shell[nearest])
    pair, pair_of = np.unique(a * shell_count + b, return_inverse=True)
    votes = np.bincount(pair_of, minlength=len(pair)).astype(np.float64)
    agreeing = np.bincount(pair_of, agree.astype(np.float64), minlength=len(pair))
    share = np.maximum(agreeing, votes - agreeing) / votes
    decided = np.flatnonzero(share >= SEAM_VOTE_SHARE)
    # Union-find with parity over the shells, the clearest pairs first (ties: pair order).
    order = decided[np.lexsort((decided, -np.abs(2 * agreeing[decided] - votes[decided])))]
    parent = np.arange(shell_count)
    parity = np.zeros(shell_count, dtype=bool)  # against the parent

    def find(node: int) -> tuple[int, bool]:
        turned = False
        while parent[node] != node:
            turned ^= bool(parity[node])
            node = int(parent[node])
        return node, turned

    for index in order.tolist():
        s, t = divmod(int(pair[index]), shell_count)
        (root_s, turn_s), (root_t, turn_t) = find(s), find(t)
        if root_s == root_t:
            continue
        differ = agreeing[index] < votes[index] - agreeing[index]
        low, high = min(root_s, root_t), max(root_s, root_t)
        parent[high] = low
        parity[high] = turn_s ^ turn_t ^ differ
    group = np.arange(shell_count)  # a shell in no decided pair is its own group
    turn = np.zeros(shell_count, dtype=bool)
    for member in np.unique(np.divmod(pair[order], shell_count)).tolist():
        group[member], turn[member] = find(member)
    members = np.bincount(group, minlength=shell_count)
    if members.max() < 2:
        return flips
    # Each group wound as its root shell, then closed and measured.
    together = flips ^ turn[face_shell]
    oriented = reverse_rows(stitched, together)
    closed_vertices, caps = closing_caps(vertices, coincident, oriented, edges)
    table = np.asarray(edges[0])
    keys = table[:, 0]
    vertex_count = int(stitched.max()) + 1
    face_group = group[face_shell]
    centre = vertices.mean(axis=0)
    six = np.zeros(shell_count)
    _add_six_volumes(vertices, oriented, face_group, centre, six)
    if len(caps):
        cap_keys = np.minimum(caps[:, 0], caps[:, 1]) * vertex_count
        cap_keys += np.maximum(caps[:, 0], caps[:, 1])
        owner = table[np.minimum(np.searchsorted(keys, cap_keys), len(keys) - 1), 1]
        _add_six_volumes(closed_vertices, caps, face_group[owner], centre, six)
    volume = six / 6.0
    areas = np.asarray(areas, dtype=np.float64)
    area = np.bincount(face_group, areas, minlength=shell_count)
    shell_area = np.bincount(face_shell, areas, minlength=shell_count)
    # Where the volume cannot decide: as the group's largest shell decided on its own.
    largest = np.full(shell_count, -1, dtype=np.int64)
    for member in np.argsort(shell_area, kind="stable").tolist():
        largest[group[member]] = member
    ambiguous = np.abs(volume) < AMBIGUOUS_VOLUME * area**1.5
    group_turn = np.where(ambiguous, turn[np.maximum(largest, 0)], volume < 0)
    result = together ^ group_turn[face_group]
    single = members[face_group] < 2
    result[single] = flips[single]
    return flips if np.array_equal(result, flips) else result


@kernel
def _add_six_volumes(  # pragma: no cover - numba
    vertices: NDArray[np.float64],
    triangles: NDArray[np.int64],
    group: NDArray[np.int64],
    centre: NDArray[np.float64],
    six: NDArray[np.float64],
) -> None:
    """Adds to ``six[group[t]]`` six times the signed volume of the tetrahedron from
    ``centre`` to each triangle ``t``."""
    for t in range(triangles.shape[0]):
        a, b, c = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        ax, ay, az = (
            vertices[a, 0] - centre[0],
            vertices[a, 1] - centre[1],
            vertices[a, 2] - centre[2],
        )
        bx, by, bz = (
            vertices[b, 0] - centre[0],
            vertices[b, 1] - centre[1],
            vertices[b, 2] - centre[2],
        )
        cx, cy, cz = (
            vertices[c, 0] - centre[0],
            vertices[c, 1] - centre[1],
            vertices[c, 2] - centre[2],
        )
        six[group[t]] += (
            ax * (by * cz - bz * cy) - ay * (bx * cz - bz * cx) + az * (bx * cy - by * cx)
        )
