"""Piece-wise UV unwrapping by parts (the paper's application).

Part borders are first straightened (a min-cut on edge length within a few rings of
faces: borders along mesh edges, no stair steps). Each connected piece of a part is then
flattened on its own (cut to a disk with libigl, a least-squares conformal map, cut
further while it is too stretched and the cuts still help, halved with METIS into two
balanced, connected halves along a straightened border when it still fails), so every
chart lies within one part and seams run where parts meet, plus whatever cuts a part
still needs to flatten. Sliver charts are merged into a neighbour of their part where the
two flatten as one; only pieces that never flatten (non-manifold ones) are charted by
xatlas, inside the piece. xatlas packs all charts into one atlas, and every chart's
corners are mapped through the affine map its packing found (so none depends on xatlas
placing it). UVs are per triangle corner, in ``[0, 1]``, with ``v`` pointing up (OBJ's
and trimesh's convention; the GLB writer flips it for glTF).
"""

from __future__ import annotations

import io
import math
import struct
import zlib
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import igl
import numpy as np
import scipy.sparse as sp
import xatlas
from numpy.typing import NDArray
from PIL import Image
from scipy.sparse.csgraph import connected_components, dijkstra

from neural_shdf.arrays import unique_rows
from neural_shdf.compiled import kernel
from neural_shdf.errors import MeshTooLargeError, ParameterError
from neural_shdf.geometry import FaceGraph, build_face_graph, face_normals, weld_faces
from neural_shdf.mesh import TriangleMesh
from neural_shdf.palette import part_colors
from neural_shdf.segment.graphcut import banded_alpha_expansion, near_boundary
from neural_shdf.segment.metis import split_faces

#: Atlas sides a user may ask for, in texels.
MIN_ATLAS_SIZE, MAX_ATLAS_SIZE = 64, 8192
#: Largest gap between charts, in texels.
MAX_PADDING = 64
#: Packing passes, each with the charts a little smaller, until they fit one atlas.
PACK_ATTEMPTS = 12
#: A piece smaller than twice this is never halved further.
MIN_SPLIT_FACES = 16
#: METIS imbalance when halving a piece (a half up to 1.2 times the mean): the segmenter's
#: looser setting peels a sliver off a big piece instead of halving it.
BISECT_UFACTOR = 200
#: Rings of faces either side of a new halving's border that a min-cut on edge length may
#: move it through: METIS's border zig-zags across triangles, this straightens it.
BORDER_BAND_RINGS = 4
#: A cut that has not halved the stretch over the first this many cuts is given up: the
#: piece is halved instead (each cut costs one more solve at full resolution).
CUTS_BEFORE_PROGRESS = 3
#: A cut that lowers the stretch by less than this fraction of its excess stalls; after
#: this many stalls in a row the piece is halved (on the dense scans a stalled piece
#: stayed within 1% of its stretch for every further cut).
STALL_FRACTION = 0.1
STALLED_CUTS = 2
#: Stretch above ``max_stretch`` that one cut (from the most compressed point, which fixes
#: a cone or a tube's closed end at once) must bring the piece under, else it is halved:
#: on the dense scans no piece further off ever came under ``max_stretch`` by more cuts.
FIRST_CUT_SLACK = 0.4


@dataclass(frozen=True)
class UnwrapParams:
    """How to chart and pack.

    Attributes:
        atlas_size: side of the square atlas in texels; charts are scaled to fill it.
        padding: texels left free around every chart.
        max_stretch: largest L2 stretch (1 = isometric) a part may have as one chart;
            above it the part is cut further, then left to xatlas's charting.
        max_cuts: extra cuts tried per part before it is split in two.
        max_splits: how many times a part that cannot be one chart is halved (METIS,
            shortest boundary, straightened) before xatlas charts what is left.
        straighten: rings of faces either side of a part border within which chart
            borders are straightened (a min-cut on edge length; 0: charts follow the
            part borders face for face, stair steps and all).
    """

    atlas_size: int = 1024
    padding: int = 2
    max_stretch: float = 1.1
    max_cuts: int = 10
    max_splits: int = 6
    straighten: int = BORDER_BAND_RINGS

    def __post_init__(self) -> None:
        if not MIN_ATLAS_SIZE <= self.atlas_size <= MAX_ATLAS_SIZE:
            raise ParameterError(
                f"atlas_size must be in [{MIN_ATLAS_SIZE}, {MAX_ATLAS_SIZE}] texels, "
                f"got {self.atlas_size}"
            )
        if not 0 <= self.padding <= MAX_PADDING:
            raise ParameterError(
                f"padding must be in [0, {MAX_PADDING}] texels, got {self.padding}"
            )
        if not (math.isfinite(self.max_stretch) and self.max_stretch >= 1.0):
            raise ParameterError(f"max_stretch must be a number >= 1, got {self.max_stretch}")
        if not 0 <= self.max_cuts <= 64:
            raise ParameterError(f"max_cuts must be in [0, 64], got {self.max_cuts}")
        if not 0 <= self.max_splits <= 8:
            raise ParameterError(f"max_splits must be in [0, 8], got {self.max_splits}")
        if not 0 <= self.straighten <= 16:
            raise ParameterError(f"straighten must be in [0, 16] rings, got {self.straighten}")


@dataclass(frozen=True)
class UvAtlas:
    """UVs of every triangle corner and the charts they form.

    Attributes:
        corner_uvs: (F, 3, 2) float64 in ``[0, 1]``, per corner of ``mesh.faces``.
        chart: (F,) chart of each triangle; -1 for a degenerate triangle xatlas left out
            (its corners sit at one point of a neighbouring chart, or at 0).
        chart_part: (C,) the part label each chart belongs to.
        width, height: the packed atlas in texels (UVs are normalised by them).
        utilization: fraction of the atlas covered by charts (xatlas's count).
    """

    corner_uvs: NDArray[np.float64]
    chart: NDArray[np.int64]
    chart_part: NDArray[np.int64]
    width: int
    height: int
    utilization: float

    @property
    def chart_count(self) -> int:
        return int(len(self.chart_part))


def part_labels_per_triangle(mesh: TriangleMesh, labels: NDArray) -> NDArray[np.int64]:
    """Per-triangle labels with every input polygon in one part (the polygon's label).

    ``labels`` may be per triangle or per input face; polygons split between parts
    take the label covering most of their area, as everywhere else.
    """
    labels = np.asarray(labels)
    if labels.dtype.kind not in "iu" or labels.ndim != 1:
        raise ParameterError("labels must be a 1-D integer array")
    if len(labels) == mesh.face_count:
        _, areas = mesh.normals_and_areas
        labels = mesh.labels_to_input_faces(labels, weights=areas)
    elif len(labels) != mesh.input_face_count:
        raise ParameterError(
            f"need one label per triangle ({mesh.face_count}) or per input face "
            f"({mesh.input_face_count}), got {len(labels)}"
        )
    return np.asarray(labels, dtype=np.int64)[mesh.face_origin]


def unwrap(mesh: TriangleMesh, labels: NDArray, params: UnwrapParams | None = None) -> UvAtlas:
    """Chart each part on its own, parameterise it, pack every chart into one atlas.

    Part borders are straightened within ``params.straighten`` rings of faces (so a chart's
    part, ``chart_part``, may differ from ``labels`` on a few faces along a border). Each
    connected piece of a part becomes one chart where that is possible within
    ``params.max_stretch``: cut to a disk (libigl), flattened by a least-squares
    conformal map, and cut further from its most compressed point to its border while
    it is too stretched and the cuts still lower the stretch. A piece that still fails is
    halved (up to ``max_splits`` times); one that can be halved no further is kept as one
    chart within ``LAST_PIECE_STRETCH`` times ``max_stretch``, else (non-manifold,
    overlapping itself) charted by xatlas inside the piece. Sliver charts are merged into
    a neighbour of their part where the two flatten as one. xatlas packs all charts (see
    ``_pack``).
    ``labels``: a part per triangle or per input face (see ``part_labels_per_triangle``).
    Deterministic.
    """
    params = params or UnwrapParams()
    labels = part_labels_per_triangle(mesh, labels)
    welded = weld_faces(mesh.vertices, mesh.faces)
    diagonal_pairs = _polygon_diagonals(mesh, welded)
    if params.straighten > 0:
        labels = straighten_borders(
            mesh.vertices, welded, labels, diagonal_pairs, params.straighten
        )
    representative = _coincident_representative(welded, labels)
    first = representative == np.arange(mesh.face_count)
    parts = np.unique(labels)
    pieces = [_connected_pieces(welded, np.flatnonzero((labels == part) & first)) for part in parts]
    later = sum(len(found) for found in pieces)
    _check_chart_budget(later)
    corner_uvs = np.zeros((mesh.face_count, 3, 2), dtype=np.float64)
    chart = np.full(mesh.face_count, -1, dtype=np.int64)
    chart_part: list[int] = []
    leftovers: list[tuple[int, NDArray[np.int64]]] = []

    def flatten(piece: NDArray[np.int64], max_stretch: float) -> NDArray[np.float64] | None:
        used, local = np.unique(welded[piece], return_inverse=True)
        diagonals = _local_diagonals(diagonal_pairs, used)
        return _flatten_piece(
            mesh.vertices[used], local.reshape(-1, 3), max_stretch, params.max_cuts, diagonals
        )

    for part, found in zip(parts, pieces, strict=True):
        pending = deque((piece, 0) for piece in found)
        later -= len(found)
        while pending:
            piece, depth = pending.popleft()
            uvs = flatten(piece, params.max_stretch)
            splits = depth < params.max_splits and len(piece) >= 2 * MIN_SPLIT_FACES
            if uvs is None and not splits:
                # Small and still too stretched: one chart a little more stretched beats
                # the handful of slivers xatlas would make of it.
                uvs = flatten(piece, params.max_stretch * LAST_PIECE_STRETCH)
            if uvs is not None:
                corner_uvs[piece] = uvs
                chart[piece] = len(chart_part)
                chart_part.append(int(part))
            elif splits:
                used, local = np.unique(welded[piece], return_inverse=True)
                diagonals = _local_diagonals(diagonal_pairs, used)
                halves = _bisect(mesh.vertices[used], local.reshape(-1, 3), diagonals)
                for half in (0, 1):
                    for sub in _connected_pieces(welded, piece[halves == half]):
                        pending.append((sub, depth + 1))
                _check_chart_budget(len(chart_part) + len(leftovers) + len(pending) + later)
            else:
                leftovers.append((int(part), piece))
    for part, piece in leftovers:
        for faces, uvs in _xatlas_charts(mesh.vertices, welded, piece, params):
            corner_uvs[faces] = uvs
            chart[faces] = len(chart_part)
            chart_part.append(part)
        _check_chart_budget(len(chart_part))
    chart_part_array = _merge_slivers(
        mesh.vertices,
        welded,
        corner_uvs,
        chart,
        np.asarray(chart_part, dtype=np.int64),
        flatten,
        params.max_stretch,
    )
    atlas = _pack(mesh, corner_uvs, chart, chart_part_array, params)
    _copy_to_coincident(atlas, welded, representative)
    return atlas


#: A chart narrower on average (twice its area over its border with other charts) than this
#: many mean edge lengths is a sliver: a strip a couple of triangles wide.
SLIVER_WIDTH_EDGES = 3.0
#: Stretch (times ``max_stretch``) a piece that can be halved no further may keep.
LAST_PIECE_STRETCH = 1.5


def chart_widths(
    vertices: NDArray, welded: NDArray[np.int64], chart: NDArray[np.int64], charts: int
) -> tuple[NDArray[np.float64], float, FaceGraph]:
    """Per chart, its mean width (twice its area over its border with other charts; inf
    with no such border), the mean edge length, and the face graph."""
    graph = build_face_graph(vertices, welded)
    _, areas = face_normals(vertices, welded)
    charted = chart >= 0
    chart_area = np.bincount(chart[charted], weights=areas[charted], minlength=charts)
    left, right = graph.pairs[:, 0], graph.pairs[:, 1]
    border = (chart[left] != chart[right]) & (chart[left] >= 0) & (chart[right] >= 0)
    length = graph.edge_length[border]
    perimeter = np.bincount(chart[left[border]], weights=length, minlength=charts)
    perimeter += np.bincount(chart[right[border]], weights=length, minlength=charts)
    with np.errstate(divide="ignore"):
        width = np.where(perimeter > 0, 2.0 * chart_area / np.maximum(perimeter, 1e-300), np.inf)
    mean_edge = float(graph.edge_length.mean()) if len(graph.edge_length) else 0.0
    return width, mean_edge, graph


def _merge_slivers(
    vertices: NDArray,
    welded: NDArray[np.int64],
    corner_uvs: NDArray[np.float64],
    chart: NDArray[np.int64],
    chart_part: NDArray[np.int64],
    flatten: Callable[[NDArray[np.int64], float], NDArray[np.float64] | None],
    max_stretch: float,
) -> NDArray[np.int64]:
    """Merge every sliver chart (``SLIVER_WIDTH_EDGES``) into the chart of its part it
    shares the longest border with, where the two flatten as one chart (no flip, no
    overlap, within ``max_stretch``); else keep it. ``corner_uvs`` and ``chart`` change in
    place; returns the part of each chart, charts renumbered in their first order."""
    charts = len(chart_part)
    if charts < 2:
        return chart_part
    width, mean_edge, graph = chart_widths(vertices, welded, chart, charts)
    slivers = np.flatnonzero(width < SLIVER_WIDTH_EDGES * mean_edge)
    if len(slivers) == 0:
        return chart_part
    left, right = chart[graph.pairs[:, 0]], chart[graph.pairs[:, 1]]
    valid = (left >= 0) & (right >= 0)
    left, right, length = left[valid], right[valid], graph.edge_length[valid]
    charted = np.flatnonzero(chart >= 0)
    merged = np.arange(charts)
    for sliver in slivers[np.argsort(width[slivers], kind="stable")].tolist():
        a, b = merged[left], merged[right]
        across = (a != b) & ((a == sliver) | (b == sliver))
        other = np.where(a[across] == sliver, b[across], a[across])
        same_part = chart_part[other] == chart_part[sliver]
        if not same_part.any():
            continue
        shared = np.bincount(other[same_part], weights=length[across][same_part])
        target = int(np.argmax(shared))
        owner = merged[chart[charted]]
        union = charted[(owner == sliver) | (owner == target)]
        uvs = flatten(union, max_stretch)
        if uvs is None:
            continue
        corner_uvs[union] = uvs
        merged[merged == sliver] = target
    # Charts keep the order they were made in (ids ascending), the merged ones left out.
    kept, new_id = np.unique(merged, return_inverse=True)
    chart[charted] = new_id.reshape(-1)[chart[charted]]
    return chart_part[kept]


#: Most charts one atlas is packed with; each costs a few milliseconds to chart and pack,
#: and past this a 8192-texel atlas gives each under ~80 x 80 texels.
MAX_CHARTS = 10_000


def _check_chart_budget(charts: int) -> None:
    """MeshTooLargeError once the charts (or pieces that become at least one chart each)
    pass MAX_CHARTS: checked before the work that would make more."""
    if charts > MAX_CHARTS:
        raise MeshTooLargeError(
            f"unwrapping needs at least {charts} charts (separate pieces of the parts), more "
            f"than the limit of {MAX_CHARTS}: merge the mesh's loose pieces or segment it "
            "into fewer, connected parts",
            limit="max_charts",
            maximum=MAX_CHARTS,
            found=charts,
        )


def _coincident_representative(
    welded: NDArray[np.int64], labels: NDArray[np.int64]
) -> NDArray[np.int64]:
    """Per face, the first face of the same part on the same (welded) vertices, in any
    order: copies of one triangle are charted once and share its UVs."""
    keys = np.column_stack([labels, np.sort(welded, axis=1)])
    _, first, inverse = unique_rows(keys, return_index=True, return_inverse=True)
    return first[inverse.reshape(-1)].astype(np.int64)


def _copy_to_coincident(
    atlas: UvAtlas, welded: NDArray[np.int64], representative: NDArray[np.int64]
) -> None:
    """Give every copy its first face's chart and UVs, corner by matching vertex."""
    copies = np.flatnonzero(representative != np.arange(len(representative)))
    if len(copies) == 0:
        return
    source = representative[copies]
    corner = np.argmax(welded[source][:, None, :] == welded[copies][:, :, None], axis=2)
    atlas.corner_uvs[copies] = atlas.corner_uvs[source[:, None], corner]
    atlas.chart[copies] = atlas.chart[source]


def _polygon_diagonals(mesh: TriangleMesh, welded: NDArray[np.int64]) -> NDArray[np.int64]:
    """(D, 2) welded vertex pairs of the fan diagonals inside input polygons."""
    same_polygon = mesh.face_origin[1:] == mesh.face_origin[:-1]
    # In a fan (v0, vi, vi+1), (v0, vi+1) is shared with the next triangle of the polygon.
    following = np.flatnonzero(same_polygon)
    return np.sort(welded[following][:, [0, 2]], axis=1)


def _local_diagonals(pairs: NDArray[np.int64], used: NDArray[np.int64]) -> NDArray[np.int64]:
    """Sorted keys ``low * len(used) + high`` of the diagonals among a piece's vertices."""
    if len(pairs) == 0:
        return np.zeros(0, dtype=np.int64)
    local = np.searchsorted(used, pairs)
    local = np.minimum(local, len(used) - 1)
    inside = (used[local] == pairs).all(axis=1)
    local = np.sort(local[inside], axis=1)
    return np.unique(local[:, 0] * len(used) + local[:, 1])


def _connected_pieces(welded: NDArray[np.int64], faces: NDArray[np.int64]) -> list[NDArray]:
    """``faces`` split into edge-connected pieces, each in ascending face order.

    Components of the bipartite face-edge graph (3 links per face), not of the face-face
    product: an edge shared by k faces costs k links, not k^2 (a triangle repeated in place).
    """

    if len(faces) == 0:
        return []
    edges = np.sort(welded[faces][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, edge_id = unique_rows(edges, return_inverse=True)
    n_faces, n_edges = len(faces), int(edge_id.max()) + 1
    owner = np.repeat(np.arange(n_faces), 3)
    # Faces are nodes [0, F), edges [F, F + E): face labels come first, in face order.
    links = sp.csr_matrix(
        (np.ones(len(owner), dtype=np.int8), (owner, n_faces + edge_id.reshape(-1))),
        shape=(n_faces + n_edges, n_faces + n_edges),
    )
    _, node_component = connected_components(links, directed=False)
    # Renumber by first face so that pieces come in the order of their lowest face.
    _, first, component = np.unique(
        node_component[:n_faces], return_index=True, return_inverse=True
    )
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    component = rank[component.reshape(-1)]
    order = np.argsort(component, kind="stable")
    return np.split(faces[order], np.cumsum(np.bincount(component))[:-1])


#: Cost of moving a face of average area off its part while straightening, in mean edge
#: lengths: a tooth (one face, two border edges) saves about one edge and moves; a border
#: never slides along a tube or a cap towards a shorter loop (every ring costs more than
#: it saves), and only strips under ~4 faces wide can vanish.
STRAIGHTEN_FACE_COST = 0.25


def straighten_borders(
    vertices: NDArray,
    welded: NDArray[np.int64],
    labels: NDArray[np.int64],
    diagonal_pairs: NDArray[np.int64],
    rings: int,
) -> NDArray[np.int64]:
    """Part labels with their borders straightened: within ``rings`` faces of a border,
    the labelling with the shortest borders plus ``STRAIGHTEN_FACE_COST`` per face moved
    (alpha-expansion, every face outside the band fixed), never across a polygon diagonal.
    What a segmentation's graph cut leaves (borders zig-zagging across triangles along
    noisy creases) becomes borders along mesh edges without stair steps."""
    graph = build_face_graph(vertices, welded)
    if len(graph.pairs) == 0:
        return labels
    values, dense = np.unique(labels, return_inverse=True)
    dense = dense.reshape(-1).astype(np.int64)
    if len(values) < 2:
        return labels
    band = near_boundary(dense, graph.pairs, len(dense), rings)
    if not band.any():
        return labels
    length = _uncut_diagonals(graph, vertices, diagonal_pairs)
    _, areas = face_normals(vertices, welded)
    mean_edge = float(graph.edge_length.mean())
    mean_area = max(float(areas.mean()), 1e-300)
    inside = np.flatnonzero(band)
    move = STRAIGHTEN_FACE_COST * mean_edge * areas[inside] / mean_area
    data = np.repeat(move[:, None], len(values), axis=1)
    data[np.arange(len(inside)), dense[inside]] = 0.0
    straight = banded_alpha_expansion(data, graph.pairs, length, dense, band)
    return values[straight]


def _uncut_diagonals(graph, vertices: NDArray, diagonal_pairs: NDArray[np.int64]) -> NDArray:
    """Edge length per face pair, a thousand times the longest edge on polygon diagonals."""
    if len(diagonal_pairs) == 0:
        return np.asarray(graph.edge_length, dtype=np.float64)
    n = len(vertices)
    keys = np.unique(diagonal_pairs[:, 0] * n + diagonal_pairs[:, 1])
    a, b = graph.edge_vertices[:, 0], graph.edge_vertices[:, 1]
    pair_keys = np.minimum(a, b) * n + np.maximum(a, b)
    found = np.minimum(np.searchsorted(keys, pair_keys), len(keys) - 1)
    return np.where(
        keys[found] == pair_keys, graph.edge_length.max(initial=1.0) * 1e3, graph.edge_length
    )


def _bisect(
    vertices: NDArray, faces: NDArray[np.int64], diagonals: NDArray[np.int64]
) -> NDArray[np.int64]:
    """0/1 per face: two connected halves of similar size with a short, straight boundary
    (METIS, then a min-cut on edge length within ``BORDER_BAND_RINGS`` of its border, then
    stray fragments of a half given to the other), never split across a polygon diagonal."""
    graph = build_face_graph(vertices, faces)
    a, b = graph.edge_vertices[:, 0], graph.edge_vertices[:, 1]
    keys = np.minimum(a, b) * len(vertices) + np.maximum(a, b)
    found = np.minimum(np.searchsorted(diagonals, keys), max(len(diagonals) - 1, 0))
    inside = diagonals[found] == keys if len(diagonals) else np.zeros(len(keys), bool)
    length = np.where(inside, graph.edge_length.max(initial=1.0) * 1e3, graph.edge_length)
    halves = split_faces(graph, 2, seed=0, edge_length=length, ufactor=BISECT_UFACTOR)
    band = near_boundary(halves, graph.pairs, len(faces), BORDER_BAND_RINGS)
    if band.any():
        straight = banded_alpha_expansion(
            np.zeros((int(band.sum()), 2)), graph.pairs, length, halves, band
        )
        if 0 < straight.sum() < len(straight):
            halves = straight
    return _fold_fragments(halves, graph.pairs)


def _fold_fragments(halves: NDArray[np.int64], pairs: NDArray[np.int64]) -> NDArray[np.int64]:
    """Each half kept to its largest connected fragment; the others (METIS leaves a few
    specks, each a sliver chart otherwise) join the other half."""
    n = len(halves)
    joined = halves[pairs[:, 0]] == halves[pairs[:, 1]]
    graph = sp.csr_matrix(
        (np.ones(int(joined.sum()), dtype=np.int8), (pairs[joined, 0], pairs[joined, 1])),
        shape=(n, n),
    )
    _, fragment = connected_components(graph, directed=False)
    sizes = np.bincount(fragment)
    result = halves.copy()
    for half in (0, 1):
        members = halves == half
        if not members.any():
            continue
        largest = np.max(np.where(members, sizes[fragment], -1))
        keep = int(fragment[np.flatnonzero(members & (sizes[fragment] == largest))[0]])
        result[members & (fragment != keep)] = 1 - half
    return result if 0 < result.sum() < n else halves


def _is_edge_manifold(faces: NDArray[np.int64]) -> bool:
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = unique_rows(edges, return_counts=True)
    return bool(counts.max(initial=0) <= 2)


def _triangle_areas(points: NDArray, faces: NDArray) -> NDArray[np.float64]:
    """Unsigned areas in 3D, signed areas in 2D."""
    a, b, c = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    if points.shape[1] == 2:
        u, v = b - a, c - a
        return 0.5 * (u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def _lscm(vertices: NDArray, faces: NDArray) -> NDArray[np.float64] | None:
    """Free-boundary least-squares conformal map of a disk, scaled to the surface's area."""
    boundary = igl.boundary_loop(faces)
    if len(boundary) < 3:
        return None
    points = vertices[boundary]
    far = int(np.argmax(np.linalg.norm(points - points[0], axis=1)))
    pins = np.array([boundary[0], boundary[far]], dtype=np.int64)
    span = float(np.linalg.norm(points[far] - points[0]))
    uv, _ = igl.lscm(vertices, faces, pins, np.array([[0.0, 0.0], [span, 0.0]]))
    if not np.all(np.isfinite(uv)):
        return None
    area_uv = _triangle_areas(uv, faces).sum()
    area_3d = _triangle_areas(vertices, faces).sum()
    if area_uv == 0 or area_3d == 0:
        return None
    if area_uv < 0:
        uv[:, 1] = -uv[:, 1]
        area_uv = -area_uv
    return uv * np.sqrt(area_3d / area_uv)


#: Most boundary loops joined by cuts (each cut is a shortest-path search over the piece);
#: a piece with more holes is split or left to xatlas.
MAX_JOINED_LOOPS = 64
#: Longest chart border tested for self-overlap (the test compares every pair of border
#: edges); a chart with a longer border is split or left to xatlas.
MAX_CHECKED_BORDER = 20_000
#: Edge-length factor that keeps cuts off the diagonals inside input polygons.
DIAGONAL_PENALTY = 1e6


class _CutFailedError(Exception):
    """A cut gave no usable mesh: the piece is left to xatlas."""


class _Piece:
    """A connected piece of a part being cut open: its vertices, its triangles (order kept)
    and, per vertex, the vertex it was copied from when a cut split it."""

    def __init__(self, vertices: NDArray, faces: NDArray, diagonals: NDArray) -> None:
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.origin = np.arange(len(self.vertices), dtype=np.int64)
        self.n_original = len(self.vertices)
        self.diagonals = diagonals  # sorted int64 keys low * n + high of polygon diagonals

    def _is_diagonal(self, a: NDArray, b: NDArray) -> NDArray[np.bool_]:
        low, high = (
            np.minimum(self.origin[a], self.origin[b]),
            np.maximum(self.origin[a], self.origin[b]),
        )
        keys = low * self.n_original + high
        found = np.searchsorted(self.diagonals, keys)
        found = np.minimum(found, max(len(self.diagonals) - 1, 0))
        return (self.diagonals[found] == keys) if len(self.diagonals) else np.zeros(len(a), bool)

    def edge_graph(self):
        """Vertex graph weighted by edge length; polygon diagonals cost DIAGONAL_PENALTY more."""

        edges = unique_rows(np.sort(self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1))
        a, b = edges[:, 0], edges[:, 1]
        length = np.linalg.norm(self.vertices[a] - self.vertices[b], axis=1) + 1e-300
        length[self._is_diagonal(a, b)] *= DIAGONAL_PENALTY
        n = len(self.vertices)
        return sp.csr_matrix((length, (a, b)), shape=(n, n))

    def loops(self) -> list[NDArray[np.int64]]:
        return [np.asarray(loop, dtype=np.int64) for loop in igl.boundary_loop_all(self.faces)]

    def euler_characteristic(self) -> int:
        edges = unique_rows(np.sort(self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1))
        return len(np.unique(self.faces)) - len(edges) + len(self.faces)

    def cut(self, path: list[int] | NDArray) -> None:
        """Cut open along a vertex path (libigl; faces keep their order)."""
        path = np.asarray(path, dtype=np.int64)
        low = np.minimum(path[:-1], path[1:])
        high = np.maximum(path[:-1], path[1:])
        n = len(self.vertices)
        wanted = np.unique(low * n + high)
        flags = np.zeros(self.faces.shape, dtype=bool)
        for k in range(3):
            a, b = self.faces[:, k], self.faces[:, (k + 1) % 3]
            keys = np.minimum(a, b) * n + np.maximum(a, b)
            flags[:, k] = np.isin(keys, wanted)
        vertices, faces, copied_from = igl.cut_mesh(self.vertices, self.faces, flags)
        vertices = np.asarray(vertices)
        faces = np.asarray(faces, dtype=np.int64)
        copied_from = np.asarray(copied_from, dtype=np.int64)
        used = np.unique(faces)
        if len(used) < len(vertices):
            # A cut along a slit can leave an unreferenced copy whose source is itself.
            remap = np.full(len(vertices), -1, dtype=np.int64)
            remap[used] = np.arange(len(used))
            vertices, faces, copied_from = vertices[used], remap[faces], copied_from[used]
        if copied_from.max(initial=0) >= len(self.origin):
            raise _CutFailedError("libigl's cut_mesh copied a vertex that does not exist")
        self.origin = self.origin[copied_from]
        self.vertices = vertices
        self.faces = faces


def _shortest_path(graph, sources: NDArray[np.int64], targets: NDArray[np.int64]) -> list[int]:
    """Shortest edge path from any of ``sources`` to the nearest of ``targets`` ([] if none)."""

    distance, previous, _ = dijkstra(
        graph, directed=False, indices=sources, return_predecessors=True, min_only=True
    )
    if len(targets) == 0:
        return []
    target = int(targets[np.argmin(distance[targets])])
    if not np.isfinite(distance[target]):
        return []
    path = [target]
    while previous[path[-1]] >= 0:
        path.append(int(previous[path[-1]]))
    return path[::-1]


def _open_to_disk(piece: _Piece) -> bool:
    """Cut the piece into a topological disk, off polygon diagonals where possible: join
    boundary loops by shortest paths, open a closed piece between far-apart points, and
    leave handles to libigl's ``cut_to_disk``. False if no disk came out."""
    loops = piece.loops()
    if not loops:
        vertices = piece.vertices
        start = int(np.argmax(np.linalg.norm(vertices - vertices[0], axis=1)))
        end = int(np.argmax(np.linalg.norm(vertices - vertices[start], axis=1)))
        path = _shortest_path(piece.edge_graph(), np.array([start]), np.array([end]))
        if len(path) < 2:
            return False
        piece.cut(path)
        loops = piece.loops()
    if len(loops) > MAX_JOINED_LOOPS:
        return False
    while len(loops) > 1:
        path = _shortest_path(piece.edge_graph(), loops[0], np.concatenate(loops[1:]))
        if len(path) < 2:
            return False
        piece.cut(path)
        remaining = piece.loops()
        if len(remaining) >= len(loops):
            return False
        loops = remaining
    if piece.euler_characteristic() != 1:  # handles: libigl's cuts
        for path in igl.cut_to_disk(piece.faces):
            if len(path) > 1:
                piece.cut(list(path))
    return len(piece.loops()) == 1 and piece.euler_characteristic() == 1


def _flatten_piece(
    vertices: NDArray,
    faces: NDArray,
    max_stretch: float,
    max_cuts: int,
    diagonals: NDArray | None = None,
) -> NDArray[np.float64] | None:
    """(F, 3, 2) UVs of one connected piece as a single chart, or None where it cannot be
    one chart within ``max_stretch`` (L2 stretch) without flips or overlaps.

    ``diagonals``: sorted keys ``low * V + high`` of the edges inside input polygons, which
    cuts avoid so that a polygon's corners keep one UV each.
    """
    if len(faces) < 2 or not _is_edge_manifold(faces):
        return None
    areas = _triangle_areas(vertices, faces)
    if areas.min() <= 1e-12 * areas.max():
        return None
    piece = _Piece(vertices, faces, np.zeros(0, np.int64) if diagonals is None else diagonals)
    try:
        return _flatten_disk(piece, areas, max_stretch, max_cuts)
    except _CutFailedError:
        return None


def _flatten_disk(
    piece: _Piece, areas: NDArray, max_stretch: float, max_cuts: int
) -> NDArray[np.float64] | None:
    """``_flatten_piece`` once the piece passed its checks: cut to a disk, map, cut more."""
    if not _open_to_disk(piece):
        return None
    first_excess = math.inf
    previous, stalls = math.inf, 0
    for cut in range(max_cuts + 1):
        uv = _lscm(piece.vertices, piece.faces)
        if uv is None:
            return None
        area_uv = _triangle_areas(uv, piece.faces)
        stretch = _l2_stretch(piece.vertices, piece.faces, uv)
        if np.all(area_uv > 0) and stretch <= max_stretch:
            return None if _overlaps_itself(uv, piece.faces) else uv[piece.faces]
        if cut == 0:
            first_excess = stretch - max_stretch
        stalls = stalls + 1 if previous - stretch < STALL_FRACTION * (previous - max_stretch) else 0
        previous = stretch
        if (
            cut == max_cuts
            or stalls >= STALLED_CUTS
            or (cut >= 1 and stretch > max_stretch + FIRST_CUT_SLACK)
            or (cut >= CUTS_BEFORE_PROGRESS and stretch - max_stretch > 0.5 * first_excess)
        ):
            return None
        # Cut from the most compressed interior vertex to the border.
        scale = area_uv / np.maximum(areas, 1e-300)
        vertex_scale = np.full(len(piece.vertices), np.inf)
        np.minimum.at(vertex_scale, piece.faces.reshape(-1), np.repeat(scale, 3))
        border = np.concatenate(piece.loops())
        vertex_scale[border] = np.inf
        if not np.isfinite(vertex_scale).any():
            return None
        worst = int(np.argmin(vertex_scale))
        path = _shortest_path(piece.edge_graph(), np.array([worst]), border)
        if len(path) < 2:
            return None
        piece.cut(path)
    return None


def stretch_terms(
    vertices: NDArray, faces: NDArray, corner_uvs: NDArray
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
    """Per triangle: 3D area, signed UV area, and the Gram terms a = |S_s|^2, c = |S_t|^2,
    b = S_s . S_t of the Jacobian of the map from UV to the surface."""
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    area_3d = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    s, t = corner_uvs[:, :, 0], corner_uvs[:, :, 1]
    area_uv = 0.5 * (
        (s[:, 1] - s[:, 0]) * (t[:, 2] - t[:, 0]) - (s[:, 2] - s[:, 0]) * (t[:, 1] - t[:, 0])
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / (2.0 * area_uv)
        ss = (p0 * (t[:, 1] - t[:, 2])[:, None] + p1 * (t[:, 2] - t[:, 0])[:, None]
              + p2 * (t[:, 0] - t[:, 1])[:, None]) * inv[:, None]  # fmt: skip
        st = (p0 * (s[:, 2] - s[:, 1])[:, None] + p1 * (s[:, 0] - s[:, 2])[:, None]
              + p2 * (s[:, 1] - s[:, 0])[:, None]) * inv[:, None]  # fmt: skip
    a = np.einsum("ij,ij->i", ss, ss)
    b = np.einsum("ij,ij->i", ss, st)
    c = np.einsum("ij,ij->i", st, st)
    return area_3d, area_uv, a, c, b


def _l2_stretch(vertices: NDArray, faces: NDArray, uv: NDArray) -> float:
    """Sander's L2 stretch of a chart whose UV area equals its surface area."""
    area_3d, area_uv, gram_a, gram_c, _ = stretch_terms(vertices, faces, uv[faces])
    scale = np.abs(area_uv).sum() / area_3d.sum()
    return float(np.sqrt(np.sum(area_3d * (gram_a + gram_c) * scale / 2) / area_3d.sum()))


def _overlaps_itself(uv: NDArray, faces: NDArray) -> bool:
    """Whether a chart with no flipped triangle still overlaps itself: that happens exactly
    when its border crosses itself, so test every pair of border edges that share no end.
    The two sides of a cut are different border edges: where they cross (the chart wraps
    past a full turn at the cut's end) that is an overlap too."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, counts = unique_rows(edges, return_counts=True)
    border = unique[counts == 1]
    if len(border) > MAX_CHECKED_BORDER:
        return True  # too long a border to test pair by pair: not kept as one chart
    same = border
    start, end = uv[border[:, 0]], uv[border[:, 1]]
    block = max(1, 4_000_000 // max(len(border), 1))
    for first in range(0, len(border), block):
        a, b = start[first : first + block, None], end[first : first + block, None]
        c, d = start[None], end[None]
        crosses = (_orientation(a, b, c) * _orientation(a, b, d) < 0) & (
            _orientation(c, d, a) * _orientation(c, d, b) < 0
        )
        ends = same[first : first + block, None, :, None] == same[None, :, None, :]
        crosses &= ~ends.any(axis=(2, 3))
        if crosses.any():
            return True
    return False


def _orientation(p: NDArray, q: NDArray, r: NDArray) -> NDArray[np.float64]:
    """Sign of the turn p -> q -> r (positive: counter-clockwise)."""
    return np.sign((q[..., 0] - p[..., 0]) * (r[..., 1] - p[..., 1])
                   - (q[..., 1] - p[..., 1]) * (r[..., 0] - p[..., 0]))  # fmt: skip


def _xatlas_charts(
    vertices: NDArray, welded: NDArray, piece: NDArray[np.int64], params: UnwrapParams
) -> list[tuple[NDArray[np.int64], NDArray[np.float64]]]:
    """xatlas's own charts of one piece: (faces, (n, 3, 2) UVs at the surface's scale)."""

    used, local = np.unique(welded[piece], return_inverse=True)
    local = local.reshape(-1, 3)
    atlas = xatlas.Atlas()
    atlas.add_mesh(
        np.ascontiguousarray(vertices[used], dtype=np.float32),
        np.ascontiguousarray(local, dtype=np.uint32),
    )
    atlas.generate()
    _, indices, uvs = atlas.get_mesh(0)
    corner = uvs.astype(np.float64)[indices.astype(np.int64)]
    charts = []
    for index in range(atlas.get_mesh_chart_count(0)):
        faces = np.asarray(atlas.get_mesh_chart(0, index).faces, dtype=np.int64)
        uv = corner[faces].reshape(-1, 2)
        flat = np.arange(len(uv)).reshape(-1, 3)
        area_uv = abs(_triangle_areas(uv, flat).sum())
        area_3d = _triangle_areas(vertices[used], local[faces]).sum()
        scale = np.sqrt(area_3d / area_uv) if area_uv > 0 else 1.0
        charts.append((piece[faces], corner[faces] * scale))
    return charts


#: Median triangle area (UV units squared) the charts are scaled to before xatlas packs
#: them: xatlas drops UV triangles under float32's epsilon in area as degenerate, which a
#: dense scan's thin triangles are at the surface's scale.
PACK_TRIANGLE_AREA = 1.0
#: A corner xatlas placed further than this many texels from its chart's fitted map is one
#: it did not place (a vertex only triangles it dropped use): left out of the refit.
PLACED_TOLERANCE_TEXELS = 0.25


def _pack(
    mesh: TriangleMesh,
    corner_uvs: NDArray,
    chart: NDArray[np.int64],
    chart_part: NDArray[np.int64],
    params: UnwrapParams,
) -> UvAtlas:
    """Pack charts (UVs at the surface's scale) into one atlas with xatlas.

    xatlas moves, turns, mirrors and scales each chart as a whole (scaled a little
    differently along its two axes to fit whole texels), an affine map per chart, so that
    map is fitted from the corners xatlas placed and every corner of the chart is mapped
    through it (``_refit_charts``): no corner depends on xatlas placing it (it leaves a
    vertex that only triangles it deems degenerate use where it falls)."""

    charted = np.flatnonzero(chart >= 0)
    owner = chart[charted]
    laid_out = _side_by_side(corner_uvs[charted], owner, len(chart_part))
    quantum = 2.0**-30 * max(float(np.abs(laid_out).max(initial=1.0)), 1e-30)
    keys = np.column_stack(
        [np.repeat(owner, 3), np.round(laid_out.reshape(-1, 2) / quantum)]
    ).astype(np.int64)
    unique, inverse = unique_rows(keys, return_inverse=True)
    uv_vertices = np.ascontiguousarray(unique[:, 1:] * quantum, dtype=np.float32)
    uv_faces = np.ascontiguousarray(inverse.reshape(-1, 3), dtype=np.uint32)
    atlas = _xatlas_pack(uv_vertices, uv_faces, params)
    _, indices, uvs = atlas.get_mesh(0)
    placed = uvs.astype(np.float64)[indices.astype(np.int64)]
    # The chart xatlas made of each triangle (-1: one it dropped), one per chart of ours.
    packed_chart = np.full(len(charted), -1, dtype=np.int64)
    for index in range(atlas.get_mesh_chart_count(0)):
        packed_chart[np.asarray(atlas.get_mesh_chart(0, index).faces, dtype=np.int64)] = index
    # Fitted in texels, where the tolerance is set, from the float32 positions xatlas got.
    texels = np.array([max(atlas.width, 1), max(atlas.height, 1)], dtype=np.float64)
    source = uv_vertices.astype(np.float64)[inverse.reshape(-1, 3)]
    refitted = _refit_charts(source, placed * texels, owner, packed_chart, PLACED_TOLERANCE_TEXELS)
    packed = np.zeros_like(corner_uvs)
    packed[charted] = refitted / texels
    np.clip(packed, 0.0, 1.0, out=packed)
    return UvAtlas(
        corner_uvs=packed,
        chart=chart,
        chart_part=chart_part,
        width=int(atlas.width),
        height=int(atlas.height),
        utilization=float(atlas.utilization),
    )


def _side_by_side(
    corner_uvs: NDArray[np.float64], owner: NDArray[np.int64], charts: int
) -> NDArray[np.float64]:
    """Charts laid out side by side in one strip (xatlas finds UV charts by shared UV
    positions), scaled so that the median triangle has ``PACK_TRIANGLE_AREA``."""
    laid_out = corner_uvs.copy()
    low = np.full((charts, 2), np.inf)
    high = np.full((charts, 2), -np.inf)
    np.minimum.at(low, owner, laid_out.min(axis=1))
    np.maximum.at(high, owner, laid_out.max(axis=1))
    width = high[:, 0] - low[:, 0]
    gap = 0.1 * float(width.max(initial=1.0)) + 1e-6
    shift = np.concatenate([[0.0], np.cumsum(width + gap)[:-1]]) - low[:, 0]
    laid_out[:, :, 0] += shift[owner][:, None]
    laid_out[:, :, 1] -= low[owner, 1][:, None]
    flat = np.arange(3 * len(laid_out)).reshape(-1, 3)
    areas = np.abs(_triangle_areas(laid_out.reshape(-1, 2), flat))
    median = float(np.median(areas)) if len(areas) else 0.0
    if median > 0:
        laid_out *= math.sqrt(PACK_TRIANGLE_AREA / median)
    return laid_out


def _xatlas_pack(
    uv_vertices: NDArray[np.float32], uv_faces: NDArray[np.uint32], params: UnwrapParams
) -> xatlas.Atlas:
    """xatlas's packing of a UV mesh into one atlas of ``params.atlas_size`` texels,
    charts a little smaller each pass until they fit (``PACK_ATTEMPTS``)."""
    texels_per_unit = 0.0  # first pass: xatlas's estimate for the resolution
    for attempt in range(PACK_ATTEMPTS + 1):
        last = attempt == PACK_ATTEMPTS
        atlas = xatlas.Atlas()
        atlas.add_uv_mesh(uv_vertices, uv_faces)
        pack_options = xatlas.PackOptions()
        # Last resort: no fixed resolution, so xatlas makes a single atlas of its own size.
        pack_options.resolution = 0 if last else params.atlas_size
        pack_options.padding = params.padding
        pack_options.bilinear = True
        pack_options.texels_per_unit = texels_per_unit
        atlas.generate(pack_options=pack_options)
        side = max(atlas.width, atlas.height)
        if last or (atlas.atlas_count == 1 and side <= params.atlas_size):
            break
        # The estimate overshot: scale the charts down until they fit one atlas.
        shrink = min(params.atlas_size / side, 0.97) if atlas.atlas_count == 1 else 0.92
        texels_per_unit = float(atlas.texels_per_unit) * shrink
    return atlas


def _refit_charts(
    source: NDArray[np.float64],
    placed: NDArray[np.float64],
    owner: NDArray[np.int64],
    packed_chart: NDArray[np.int64],
    tolerance: float,
) -> NDArray[np.float64]:
    """(n, 3, 2) corners ``source`` mapped through the affine map that takes each packed
    chart's corners in ``source`` to where xatlas ``placed`` them, fitted by least squares
    on every triangle xatlas kept, then twice more on the corners it left within
    ``tolerance``.

    A triangle xatlas dropped (``packed_chart`` -1) follows the packed chart holding most
    of its chart (``owner``); where there is none, or where a packed chart's fit leaves
    fewer than half its corners within ``tolerance``, xatlas's placement is kept."""
    if len(owner) == 0:
        return placed
    kept = packed_chart >= 0
    groups = int(packed_chart.max(initial=-1)) + 1
    # Each chart of ours: the packed chart holding most of its triangles (-1: none).
    counts = sp.csr_matrix(
        (np.ones(int(kept.sum())), (owner[kept], packed_chart[kept])),
        shape=(int(owner.max()) + 1, max(groups, 1)),
    )
    majority = np.asarray(counts.argmax(axis=1)).reshape(-1)
    majority[np.asarray(counts.sum(axis=1)).reshape(-1) == 0] = -1
    group = np.where(kept, packed_chart, majority[owner])
    fitted = np.repeat(group >= 0, 3)
    corner_group = np.repeat(np.maximum(group, 0), 3)
    q = source.reshape(-1, 2)
    p = placed.reshape(-1, 2)
    weight = np.repeat(kept, 3).astype(np.float64)
    for _ in range(3):
        matrix, shift = _fit_affine_maps(q, p, corner_group, weight, max(groups, 1))
        mapped = np.einsum("nij,nj->ni", matrix[corner_group], q) + shift[corner_group]
        within = np.linalg.norm(mapped - p, axis=1) <= tolerance
        weight = (within & fitted).astype(np.float64)
    corners = np.bincount(corner_group, minlength=max(groups, 1)).astype(np.float64)
    share = np.bincount(corner_group, weights=weight, minlength=max(groups, 1)).astype(np.float64)
    share /= np.maximum(corners, 1.0)
    trusted = fitted & (share[corner_group] >= 0.5)
    return np.where(trusted[:, None], mapped, p).reshape(-1, 3, 2)


def _fit_affine_maps(
    q: NDArray[np.float64],
    p: NDArray[np.float64],
    group: NDArray[np.int64],
    weight: NDArray[np.float64],
    groups: int,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per group, the (2, 2) matrix and shift of the weighted least-squares affine map
    ``p ~ matrix @ q + shift`` (the identity where the group's weighted points are
    collinear or fewer than three)."""

    def total(values: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.bincount(group, weights=weight * values, minlength=groups).astype(np.float64)

    mass = total(np.ones(len(q)))
    safe = np.maximum(mass, 1e-300)
    q_mean = np.column_stack([total(q[:, 0]), total(q[:, 1])]) / safe[:, None]
    p_mean = np.column_stack([total(p[:, 0]), total(p[:, 1])]) / safe[:, None]
    qc = q - q_mean[group]
    pc = p - p_mean[group]
    # Normal equations per group: matrix = (sum p q^T) (sum q q^T)^-1.
    qq = np.empty((groups, 2, 2))
    pq = np.empty((groups, 2, 2))
    for i in range(2):
        for j in range(2):
            qq[:, i, j] = total(qc[:, i] * qc[:, j])
            pq[:, i, j] = total(pc[:, i] * qc[:, j])
    det = qq[:, 0, 0] * qq[:, 1, 1] - qq[:, 0, 1] * qq[:, 1, 0]
    scale = qq[:, 0, 0] * qq[:, 1, 1]
    usable = det > 1e-12 * np.maximum(scale, 1e-300)
    det = np.where(usable, det, 1.0)
    inverse = np.empty_like(qq)
    inverse[:, 0, 0] = qq[:, 1, 1] / det
    inverse[:, 1, 1] = qq[:, 0, 0] / det
    inverse[:, 0, 1] = -qq[:, 0, 1] / det
    inverse[:, 1, 0] = -qq[:, 1, 0] / det
    matrix = pq @ inverse
    matrix[~usable] = np.eye(2)
    shift = p_mean - np.einsum("nij,nj->ni", matrix, q_mean)
    shift[~usable] = 0.0
    return matrix, shift


@dataclass(frozen=True)
class PolygonUvs:
    """UVs per corner of every input polygon, in the input file's face order.

    Attributes:
        corner_counts: (P,) corners of each input face (0: a face without triangles).
        vertices: (C,) the mesh vertex of each corner, polygons concatenated in order,
            each from its first vertex on (the file's own corner order).
        uvs: (C, 2) the UV of each corner.
        consistent: (P,) whether all the polygon's triangles agree on every shared
            corner (False where a chart boundary runs through it: its corner UVs are
            then those of its fan's outer edges, and a writer that can split the polygon
            into its triangles should).
    """

    corner_counts: NDArray[np.int64]
    vertices: NDArray[np.int64]
    uvs: NDArray[np.float64]
    consistent: NDArray[np.bool_]


def polygon_corner_uvs(mesh: TriangleMesh, corner_uvs: NDArray) -> PolygonUvs:
    """Read every input polygon's corners and their UVs back from its fan of triangles
    ``(v0, v1, v2), (v0, v2, v3), ...`` (how every loader triangulates); no Python loop."""
    corner_uvs = np.asarray(corner_uvs, dtype=np.float64).reshape(-1, 3, 2)
    origin = np.asarray(mesh.face_origin, dtype=np.int64)
    triangles = np.bincount(origin, minlength=mesh.input_face_count).astype(np.int64)
    counts = np.where(triangles > 0, triangles + 2, 0)
    first = np.zeros(mesh.input_face_count, dtype=np.int64)
    np.cumsum(triangles[:-1], out=first[1:])
    ring_start = np.zeros(mesh.input_face_count, dtype=np.int64)
    np.cumsum(counts[:-1], out=ring_start[1:])
    total = int(counts.sum())
    vertices = np.zeros(total, dtype=np.int64)
    uvs = np.zeros((total, 2), dtype=np.float64)
    has = np.flatnonzero(triangles > 0)
    # Corner 0: the fan's apex; corners 1..n-2: each triangle's second corner; n-1: the
    # last triangle's third corner.
    vertices[ring_start[has]] = mesh.faces[first[has], 0]
    uvs[ring_start[has]] = corner_uvs[first[has], 0]
    within = np.arange(len(origin), dtype=np.int64) - first[origin]
    middle = ring_start[origin] + 1 + within
    vertices[middle] = mesh.faces[:, 1]
    uvs[middle] = corner_uvs[:, 1]
    last_triangle = first[has] + triangles[has] - 1
    end = ring_start[has] + counts[has] - 1
    vertices[end] = mesh.faces[last_triangle, 2]
    uvs[end] = corner_uvs[last_triangle, 2]
    # A polygon is consistent when every triangle has the apex's UV at its apex and
    # consecutive triangles agree on the diagonal they share.
    apex_off = ~np.all(
        np.isclose(corner_uvs[:, 0], corner_uvs[first[origin], 0], atol=1e-9, rtol=0), axis=1
    )
    bad = np.bincount(origin[apex_off], minlength=mesh.input_face_count)
    if len(origin) > 1:
        same_polygon = origin[1:] == origin[:-1]
        diagonal_off = same_polygon & ~np.all(
            np.isclose(corner_uvs[:-1, 2], corner_uvs[1:, 1], atol=1e-9, rtol=0), axis=1
        )
        bad = bad + np.bincount(origin[1:][diagonal_off], minlength=mesh.input_face_count)
    return PolygonUvs(counts, vertices, uvs, bad == 0)


def input_face_corner_uvs(
    mesh: TriangleMesh, corner_uvs: NDArray
) -> tuple[list[NDArray[np.int64]], NDArray[np.float64], NDArray[np.bool_]]:
    """UVs per corner of every input polygon, for writers that keep polygons.

    Returns ``(polygons, polygon_uvs, consistent)``: the polygon's vertex indices, its corner
    UVs (same lengths, concatenated in polygon order) and, per input face, whether
    all its triangles agree on every shared corner (False where a chart boundary
    runs through the polygon: a writer must then split it into its triangles); see
    ``polygon_corner_uvs``.
    """
    layout = polygon_corner_uvs(mesh, corner_uvs)
    polygons = np.split(layout.vertices, np.cumsum(layout.corner_counts)[:-1])
    return polygons, layout.uvs, layout.consistent


@kernel
def _rasterize_charts(corner_uvs, chart, width, height, owner):  # pragma: no cover - numba
    """Claim every texel whose centre lies in a triangle for that triangle's chart.

    ``owner`` (height, width) starts at -1; returns how many texel claims met a
    texel another chart already owned (0 when no two charts overlap).
    """
    clashes = 0
    for face in range(len(chart)):
        label = chart[face]
        if label < 0:
            continue
        x0 = corner_uvs[face, 0, 0] * width
        y0 = corner_uvs[face, 0, 1] * height
        x1 = corner_uvs[face, 1, 0] * width
        y1 = corner_uvs[face, 1, 1] * height
        x2 = corner_uvs[face, 2, 0] * width
        y2 = corner_uvs[face, 2, 1] * height
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if area == 0.0:
            continue
        sign = 1.0 if area > 0 else -1.0
        xmin = max(int(math.floor(min(x0, x1, x2))), 0)
        xmax = min(int(math.ceil(max(x0, x1, x2))), width - 1)
        ymin = max(int(math.floor(min(y0, y1, y2))), 0)
        ymax = min(int(math.ceil(max(y0, y1, y2))), height - 1)
        for py in range(ymin, ymax + 1):
            cy = py + 0.5
            for px in range(xmin, xmax + 1):
                cx = px + 0.5
                w0 = sign * ((x1 - cx) * (y2 - cy) - (x2 - cx) * (y1 - cy))
                w1 = sign * ((x2 - cx) * (y0 - cy) - (x0 - cx) * (y2 - cy))
                w2 = sign * ((x0 - cx) * (y1 - cy) - (x1 - cx) * (y0 - cy))
                if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                    previous = owner[py, px]
                    if previous < 0:
                        owner[py, px] = label
                    elif previous != label:
                        clashes += 1
    return clashes


def rasterize_charts(
    corner_uvs: NDArray, chart: NDArray, size: int
) -> tuple[NDArray[np.int64], int]:
    """Chart id per texel of a ``size`` x ``size`` grid (-1: empty; row 0 at v = 0), and
    how many texels two charts both cover."""
    owner = np.full((size, size), -1, dtype=np.int64)
    clashes = _rasterize_charts(
        np.ascontiguousarray(corner_uvs, dtype=np.float64),
        np.ascontiguousarray(chart, dtype=np.int64),
        size,
        size,
        owner,
    )
    return owner, int(clashes)


@kernel
def _draw_layout_rows(
    corner_uvs, chart, chart_part, palette, segments, size, checker, row_lo, out
):  # pragma: no cover - numba
    """Rows ``row_lo`` .. ``row_lo + len(out)`` (row 0 at v = 0) of the atlas picture into
    ``out`` (white on entry): each texel takes the first chart (in face order) whose
    triangle covers its centre, coloured ``palette[part, checker square]``, then the
    outline ``segments`` (x0, y0, x1, y1 in texels) are drawn dark."""
    rows = out.shape[0]
    row_hi = row_lo + rows
    owner = np.full((rows, size), -1, dtype=np.int64)
    for face in range(len(chart)):
        label = chart[face]
        if label < 0:
            continue
        x0 = corner_uvs[face, 0, 0] * size
        y0 = corner_uvs[face, 0, 1] * size
        x1 = corner_uvs[face, 1, 0] * size
        y1 = corner_uvs[face, 1, 1] * size
        x2 = corner_uvs[face, 2, 0] * size
        y2 = corner_uvs[face, 2, 1] * size
        ymin = max(int(math.floor(min(y0, y1, y2))), row_lo)
        ymax = min(int(math.ceil(max(y0, y1, y2))), row_hi - 1)
        if ymin > ymax:
            continue
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if area == 0.0:
            continue
        sign = 1.0 if area > 0 else -1.0
        xmin = max(int(math.floor(min(x0, x1, x2))), 0)
        xmax = min(int(math.ceil(max(x0, x1, x2))), size - 1)
        for py in range(ymin, ymax + 1):
            cy = py + 0.5
            for px in range(xmin, xmax + 1):
                if owner[py - row_lo, px] >= 0:
                    continue
                cx = px + 0.5
                w0 = sign * ((x1 - cx) * (y2 - cy) - (x2 - cx) * (y1 - cy))
                w1 = sign * ((x2 - cx) * (y0 - cy) - (x0 - cx) * (y2 - cy))
                w2 = sign * ((x0 - cx) * (y1 - cy) - (x1 - cx) * (y0 - cy))
                if w0 >= 0.0 and w1 >= 0.0 and w2 >= 0.0:
                    owner[py - row_lo, px] = label
    for r in range(rows):
        square_row = (row_lo + r) * checker // size
        for px in range(size):
            label = owner[r, px]
            if label >= 0:
                square = (square_row + px * checker // size) % 2
                for c in range(3):
                    out[r, px, c] = palette[chart_part[label], square, c]
    for i in range(len(segments)):
        x0, y0, x1, y1 = segments[i, 0], segments[i, 1], segments[i, 2], segments[i, 3]
        if max(y0, y1) < row_lo - 1 or min(y0, y1) > row_hi + 1:
            continue
        steps = int(max(abs(x1 - x0), abs(y1 - y0))) + 1
        for s in range(steps + 1):
            t = s / steps
            px = int(x0 + t * (x1 - x0))
            py = int(y0 + t * (y1 - y0))
            if 0 <= px < size and row_lo <= py < row_hi:
                for c in range(3):
                    out[py - row_lo, px, c] = 40


def chart_outline_edges(corner_uvs: NDArray, chart: NDArray) -> NDArray[np.float64]:
    """(E, 2, 2) UV segments on chart outlines: triangle edges no other triangle of the
    same chart shares with the same UV end points."""
    corner_uvs = np.asarray(corner_uvs, dtype=np.float64)
    faces = np.flatnonzero(np.asarray(chart) >= 0)
    starts = corner_uvs[faces][:, [0, 1, 2]].reshape(-1, 2)
    ends = corner_uvs[faces][:, [1, 2, 0]].reshape(-1, 2)
    quantum = 2.0**-24
    a = np.round(starts / quantum).astype(np.int64)
    b = np.round(ends / quantum).astype(np.int64)
    swap = (a[:, 0] > b[:, 0]) | ((a[:, 0] == b[:, 0]) & (a[:, 1] > b[:, 1]))
    low = np.where(swap[:, None], b, a)
    high = np.where(swap[:, None], a, b)
    owner = np.repeat(np.asarray(chart)[faces], 3)
    keys = np.column_stack([owner, low, high])
    _, inverse, counts = unique_rows(keys, return_inverse=True, return_counts=True)
    outline = counts[inverse.reshape(-1)] == 1
    return np.stack([starts[outline], ends[outline]], axis=1)


#: Rows of the atlas picture drawn at a time: memory stays at a strip, not the picture.
LAYOUT_STRIP_ROWS = 256


def _layout_strips(atlas: UvAtlas, size: int | None, checker: int) -> Iterator[NDArray[np.uint8]]:
    """The atlas picture (see ``atlas_layout_image``) as strips of rows, top first."""
    size = (
        min(max(atlas.width, atlas.height, MIN_ATLAS_SIZE), MAX_ATLAS_SIZE)
        if size is None
        else size
    )
    if not MIN_ATLAS_SIZE <= size <= MAX_ATLAS_SIZE:
        raise ParameterError(
            f"the atlas picture's size must be in [{MIN_ATLAS_SIZE}, {MAX_ATLAS_SIZE}] "
            f"texels, got {size}"
        )
    if not 1 <= checker <= size:
        raise ParameterError(f"checker must be in [1, {size}] squares, got {checker}")
    parts = np.asarray(atlas.chart_part, dtype=np.int64)
    if len(parts) and (parts.min() < 0 or parts.max() >= 2 * len(parts) + 64):
        # Sparse or negative labels: colour by rank, so the palette stays as small as the charts.
        parts = np.unique(parts, return_inverse=True)[1].reshape(-1)
    colors = part_colors(int(parts.max()) + 1 if len(parts) else 0)[:, :3].astype(np.float64)
    palette = np.stack([colors * 1.0, colors * 0.72], axis=1).astype(np.uint8)
    outline = chart_outline_edges(atlas.corner_uvs, atlas.chart) * size
    corner_uvs = np.ascontiguousarray(atlas.corner_uvs, dtype=np.float64)
    chart = np.array(atlas.chart, dtype=np.int64)
    # A triangle on the same UVs as an earlier one claims no texel: drawn once, copies of
    # a triangle cost one triangle's texels, not one each.
    _, first = unique_rows(corner_uvs.reshape(-1, 6), return_index=True)
    repeated = np.ones(len(chart), dtype=bool)
    repeated[first] = False
    chart[repeated] = -1
    segments = np.ascontiguousarray(outline.reshape(-1, 4))
    for row_hi in range(size, 0, -LAYOUT_STRIP_ROWS):
        row_lo = max(row_hi - LAYOUT_STRIP_ROWS, 0)
        strip = np.full((row_hi - row_lo, size, 3), 255, dtype=np.uint8)
        _draw_layout_rows(corner_uvs, chart, parts, palette, segments, size, checker, row_lo, strip)
        yield strip[::-1]


def atlas_layout_image(
    atlas: UvAtlas, *, size: int | None = None, checker: int = 16
) -> NDArray[np.uint8]:
    """An RGB picture of the atlas for people: charts filled with their part's colour
    under a checker pattern (``checker`` squares per side; shows stretch when used as a
    texture), chart outlines dark, empty space white. Row 0 is the top (v = 1).
    ``size``: side in texels, in [MIN_ATLAS_SIZE, MAX_ATLAS_SIZE] (default: the atlas's)."""
    return np.ascontiguousarray(np.concatenate(list(_layout_strips(atlas, size, checker))))


#: zlib level of the atlas PNG: the picture is flat colour, so a fast level is enough.
PNG_COMPRESSION = 6


def atlas_layout_png(atlas: UvAtlas, *, size: int | None = None, checker: int = 16) -> bytes:
    """``atlas_layout_image`` as PNG bytes, drawn and compressed a strip at a time so that
    memory is a strip plus the compressed output, whatever the size."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    strips = _layout_strips(atlas, size, checker)
    parts: list[bytes] = []
    compressor = zlib.compressobj(PNG_COMPRESSION)
    previous = None
    width = 0
    for strip in strips:
        width = strip.shape[1]
        if previous is None:
            previous = np.zeros_like(strip[0])
        # PNG filter "up" per row: flat colour between rows compresses to runs of zeros.
        above = np.concatenate([previous[None], strip[:-1]])
        filtered = np.empty((len(strip), 1 + 3 * width), dtype=np.uint8)
        filtered[:, 0] = 2
        filtered[:, 1:] = (strip - above).reshape(len(strip), -1)
        previous = strip[-1].copy()
        parts.append(compressor.compress(filtered.tobytes()))
    parts.append(compressor.flush())
    header = struct.pack(">IIBBBBB", width, width, 8, 2, 0, 0, 0)
    return b"".join(
        [
            b"\x89PNG\r\n\x1a\n",
            chunk(b"IHDR", header),
            chunk(b"IDAT", b"".join(parts)),
            chunk(b"IEND", b""),
        ]  # fmt: skip
    )


def png_bytes(image: NDArray[np.uint8]) -> bytes:
    """Encode an (H, W, 3) uint8 image as PNG."""

    buffer = io.BytesIO()
    Image.fromarray(np.asarray(image, dtype=np.uint8)).save(buffer, format="PNG", optimize=False)
    return buffer.getvalue()


__all__ = [
    "UnwrapParams",
    "UvAtlas",
    "atlas_layout_image",
    "atlas_layout_png",
    "chart_outline_edges",
    "chart_widths",
    "PolygonUvs",
    "input_face_corner_uvs",
    "polygon_corner_uvs",
    "part_labels_per_triangle",
    "png_bytes",
    "rasterize_charts",
    "stretch_terms",
    "unwrap",
]
