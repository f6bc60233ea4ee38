"""Quality of a UV layout: charts, seams, distortion and atlas use, for any unwrapper.

Distortion follows Sander et al. 2001 ("Texture mapping progressive meshes"): the
L2 stretch of the map from UV to surface, with the UVs first scaled so their total
area equals the surface's (1.0 is an isometry, larger is worse), and the conformal
error as the area-weighted mean ratio of the map's singular values (1.0: angles kept).

Chart borders on the surface: ``border_roughness`` is their length over the length of the
same borders smoothed (every border vertex between two border edges moved towards its
neighbours' mean, corners where three charts meet held), 1.0 for straight borders and
about 1.3 for a border that stair-steps across triangles; ``sharp_turns`` is the share of
those border vertices where the border turns by more than 90 degrees. A sliver is a chart
whose mean width (twice its area over its perimeter) is under ``SLIVER_WIDTH_EDGES`` mean
edge lengths of the mesh: a strip a couple of triangles wide.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from neural_shdf.arrays import unique_rows
from neural_shdf.geometry import build_face_graph, face_normals, weld_faces
from neural_shdf.unwrap import (
    SLIVER_WIDTH_EDGES,
    chart_widths,
    rasterize_charts,
    stretch_terms,
)


@dataclass(frozen=True)
class UvQuality:
    """One layout's numbers (see the module docstring)."""

    charts: int
    seam_ratio: float
    l2_stretch: float
    conformal_error: float
    flipped_fraction: float
    utilization: float
    overlapping_texels: int
    slivers: int
    sliver_area: float
    border_roughness: float
    sharp_turns: float

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)


def seam_ratio(vertices: NDArray, faces: NDArray, corner_uvs: NDArray) -> float:
    """Length of the seams over the length of every edge of the (welded) surface.

    A seam is an edge shared by two triangles whose UVs at its two end points differ;
    the surface's own border is not a seam.
    """
    welded = weld_faces(vertices, faces)
    graph = build_face_graph(vertices, welded)
    if len(graph.pairs) == 0:
        return 0.0
    left, right = graph.pairs[:, 0], graph.pairs[:, 1]
    seam = np.zeros(len(left), dtype=bool)
    for end in (0, 1):
        vertex = graph.edge_vertices[:, end][:, None]
        uv_left = corner_uvs[left, np.argmax(welded[left] == vertex, axis=1)]
        uv_right = corner_uvs[right, np.argmax(welded[right] == vertex, axis=1)]
        seam |= np.any(np.abs(uv_left - uv_right) > 1e-7, axis=1)
    edges = np.sort(welded[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique = unique_rows(edges)
    total = float(np.linalg.norm(vertices[unique[:, 0]] - vertices[unique[:, 1]], axis=1).sum())
    return float(graph.edge_length[seam].sum() / total) if total > 0 else 0.0


def uv_islands(vertices: NDArray, faces: NDArray, corner_uvs: NDArray) -> NDArray[np.int64]:
    """Chart per triangle as the UV layout itself says: triangles joined across every edge
    whose two end points have the same UVs on both sides (any unwrapper's charts)."""

    welded = weld_faces(vertices, faces)
    graph = build_face_graph(vertices, welded)
    left, right = graph.pairs[:, 0], graph.pairs[:, 1]
    joined = np.ones(len(left), dtype=bool)
    for end in (0, 1):
        vertex = graph.edge_vertices[:, end][:, None]
        uv_left = corner_uvs[left, np.argmax(welded[left] == vertex, axis=1)]
        uv_right = corner_uvs[right, np.argmax(welded[right] == vertex, axis=1)]
        joined &= np.all(np.abs(uv_left - uv_right) <= 1e-7, axis=1)
    n = len(faces)
    adjacency = sp.csr_matrix(
        (np.ones(int(joined.sum())), (left[joined], right[joined])), shape=(n, n)
    )
    _, island = connected_components(adjacency, directed=False)
    return island.astype(np.int64)


def uv_quality(
    vertices: NDArray,
    faces: NDArray,
    corner_uvs: NDArray,
    chart: NDArray,
    *,
    raster_size: int = 1024,
) -> UvQuality:
    """Charts, seam ratio, L2 stretch, conformal error, flipped share and atlas use.

    ``corner_uvs`` (F, 3, 2) in [0, 1]; ``chart`` (F,) chart per triangle (-1: none).
    Utilisation and overlap are counted on a ``raster_size`` square grid over the UV
    square; ``overlapping_texels`` counts texels covered by two different charts.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    corner_uvs = np.asarray(corner_uvs, dtype=np.float64)
    chart = np.asarray(chart, dtype=np.int64)
    area_3d, area_uv, a, c, b = stretch_terms(vertices, faces, corner_uvs)
    usable = (area_3d > 1e-12 * max(area_3d.max(initial=0.0), 1e-300)) & (chart >= 0)
    total_3d = area_3d[usable].sum()
    total_uv = np.abs(area_uv[usable]).sum()
    # A mirrored chart is not a defect: a triangle is flipped against its chart's majority.
    orientation = np.zeros(int(chart.max(initial=-1)) + 1)
    np.add.at(orientation, chart[usable], area_uv[usable])
    facing = area_uv * np.where(chart >= 0, np.sign(orientation[np.maximum(chart, 0)]), 0.0)
    flipped = usable & (facing <= 0)
    good = usable & (facing > 0) & np.isfinite(a) & np.isfinite(c)
    # Scale UVs to the surface's area: stretch terms a, c scale by total_uv / total_3d.
    scale = total_uv / total_3d if total_3d > 0 else 1.0
    a_n, b_n, c_n = a * scale, b * scale, c * scale
    weights = area_3d[good]
    l2 = (
        np.sqrt(np.sum(weights * (a_n[good] + c_n[good]) / 2.0) / weights.sum())
        if weights.sum() > 0
        else np.nan
    )
    root = np.sqrt(np.maximum((a_n - c_n) ** 2 + 4.0 * b_n**2, 0.0))
    big = np.sqrt(np.maximum((a_n + c_n + root) / 2.0, 0.0))
    small = np.sqrt(np.maximum((a_n + c_n - root) / 2.0, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = big / small
    ratio_ok = good & np.isfinite(ratio)
    conformal = (
        float(np.sum(area_3d[ratio_ok] * ratio[ratio_ok]) / area_3d[ratio_ok].sum())
        if ratio_ok.any()
        else np.nan
    )
    owner, clashes = rasterize_charts(corner_uvs, chart, raster_size)
    borders = chart_borders(vertices, faces, chart)
    return UvQuality(
        charts=int(len(np.unique(chart[chart >= 0]))),
        seam_ratio=seam_ratio(vertices, faces, corner_uvs),
        l2_stretch=float(l2),
        conformal_error=conformal,
        flipped_fraction=float(area_3d[flipped].sum() / total_3d) if total_3d > 0 else 0.0,
        utilization=float((owner >= 0).mean()),
        overlapping_texels=clashes,
        slivers=borders.slivers,
        sliver_area=borders.sliver_area,
        border_roughness=borders.roughness,
        sharp_turns=borders.sharp_turns,
    )


#: Smoothing passes (each moves a border vertex half way to its neighbours' mean).
BORDER_SMOOTHING_PASSES = 20


@dataclass(frozen=True)
class ChartBorders:
    """How charts meet on the surface (see the module docstring)."""

    slivers: int
    sliver_area: float
    roughness: float
    sharp_turns: float


def chart_borders(vertices: NDArray, faces: NDArray, chart: NDArray) -> ChartBorders:
    """Slivers, border roughness and sharp turns of a chart per triangle (-1: none)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    chart = np.asarray(chart, dtype=np.int64)
    welded = weld_faces(vertices, np.asarray(faces, dtype=np.int64))
    charts = int(chart.max(initial=-1)) + 1
    # The unwrapper's own sliver test: mean width (area over border with other charts).
    width, mean_edge, graph = chart_widths(vertices, welded, chart, charts)
    left, right = graph.pairs[:, 0], graph.pairs[:, 1]
    border = chart[left] != chart[right]
    _, area = face_normals(vertices, welded)
    chart_area = np.bincount(chart[chart >= 0], weights=area[chart >= 0], minlength=charts)
    sliver = (chart_area > 0) & (width < SLIVER_WIDTH_EDGES * mean_edge)
    total_area = float(chart_area.sum())
    # Border polylines: vertices of degree 2 in the border-edge graph move, the rest hold.
    ends = graph.edge_vertices[border]
    if len(ends) == 0:
        return ChartBorders(int(sliver.sum()), 0.0, 1.0, 0.0)
    n = len(vertices)
    pair = sp.coo_matrix(
        (np.ones(2 * len(ends)), (np.r_[ends[:, 0], ends[:, 1]], np.r_[ends[:, 1], ends[:, 0]])),
        shape=(n, n),
    ).tocsr()
    pair.data[:] = 1.0  # an edge two charts share twice (non-manifold) still counts once
    degree = np.asarray(pair.sum(axis=1)).reshape(-1)
    moving = degree == 2
    average = sp.diags(1.0 / np.maximum(degree, 1)) @ pair
    points = vertices.copy()
    for _ in range(BORDER_SMOOTHING_PASSES):
        target = average @ points
        points[moving] = 0.5 * points[moving] + 0.5 * target[moving]
    original = float(np.linalg.norm(vertices[ends[:, 0]] - vertices[ends[:, 1]], axis=1).sum())
    smoothed = float(np.linalg.norm(points[ends[:, 0]] - points[ends[:, 1]], axis=1).sum())
    # Turning at each moving vertex: angle between the way in and the way out.
    rows = np.flatnonzero(moving)
    neighbours = pair.indices.reshape(-1)[
        (pair.indptr[rows][:, None] + np.arange(2)).reshape(-1)
    ].reshape(-1, 2)
    way_in = vertices[rows] - vertices[neighbours[:, 0]]
    way_out = vertices[neighbours[:, 1]] - vertices[rows]
    cosine = np.einsum("ij,ij->i", way_in, way_out) / np.maximum(
        np.linalg.norm(way_in, axis=1) * np.linalg.norm(way_out, axis=1), 1e-300
    )
    return ChartBorders(
        slivers=int(sliver.sum()),
        sliver_area=float(chart_area[sliver].sum() / total_area) if total_area > 0 else 0.0,
        roughness=original / smoothed if smoothed > 0 else 1.0,
        sharp_turns=float((cosine < 0).mean()) if len(rows) else 0.0,
    )


__all__ = ["ChartBorders", "UvQuality", "chart_borders", "seam_ratio", "uv_islands", "uv_quality"]
