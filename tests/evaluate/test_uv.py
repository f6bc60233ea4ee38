"""UV quality numbers on layouts whose answers are known by hand."""

from __future__ import annotations

import numpy as np

from neural_shdf.evaluate.uv import chart_borders, seam_ratio, uv_quality


def _grid(n: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """A flat n x n grid of unit squares in the plane z = 0, two triangles per square."""
    xs, ys = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="xy")
    vertices = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)]).astype(float)
    faces = []
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i
            faces += [[a, a + 1, a + n + 2], [a, a + n + 2, a + n + 1]]
    return vertices, np.array(faces)


def test_an_isometric_layout_has_no_stretch_no_seam_and_no_flip():
    vertices, faces = _grid()
    uvs = vertices[faces][:, :, :2] / 8.0  # a uniform scale is normalised away
    quality = uv_quality(vertices, faces, uvs, np.zeros(len(faces), dtype=np.int64))
    assert quality.charts == 1
    assert quality.seam_ratio == 0
    assert np.isclose(quality.l2_stretch, 1.0)
    assert np.isclose(quality.conformal_error, 1.0)
    assert quality.flipped_fraction == 0
    assert quality.overlapping_texels == 0
    assert np.isclose(quality.utilization, 0.25, atol=0.01)


def test_anisotropic_scale_gives_sanders_l2_stretch():
    vertices, faces = _grid()
    uvs = vertices[faces][:, :, :2] * np.array([1.0, 0.25]) / 4.0
    quality = uv_quality(vertices, faces, uvs, np.zeros(len(faces), dtype=np.int64))
    # Singular values of UV->surface: 4 and 1 before area normalisation (area ratio 1/4 of
    # the squared scale), so normalised: (2, 0.5); L2 = sqrt((4 + 0.25) / 2).
    assert np.isclose(quality.l2_stretch, np.sqrt((4 + 0.25) / 2))
    assert np.isclose(quality.conformal_error, 4.0)


def test_a_cut_between_two_charts_is_a_seam_and_overlap_is_counted():
    vertices, faces = _grid(2)
    uvs = vertices[faces][:, :, :2] / 4.0
    left = vertices[faces].mean(axis=1)[:, 0] < 1
    moved = uvs.copy()
    moved[left] += np.array([0.5, 0.5])
    chart = left.astype(np.int64)
    ratio = seam_ratio(vertices, faces, moved)
    # Seam: the interior line x = 1 (length 2); every edge: 12 unit edges + 4 diagonals.
    assert np.isclose(ratio, 2.0 / (12 + 4 * np.sqrt(2)))
    # Both charts at the same place: every covered texel is claimed twice.
    stacked = uvs.copy()
    stacked[left] += np.array([0.25, 0.0])
    quality = uv_quality(vertices, faces, stacked, chart, raster_size=64)
    assert quality.overlapping_texels > 0


def _staircase_labels(n: int) -> np.ndarray:
    """Per triangle of ``_grid(n)``: 0 on squares left of the diagonal and on the diagonal
    squares, 1 right of it: a border of unit steps where the diagonal edges would do."""
    square = np.repeat(np.arange(n * n), 2)
    i, j = square % n, square // n
    return (i > j).astype(np.int64)


def test_a_staircase_border_is_rough_and_a_border_along_edges_is_not():
    vertices, faces = _grid(8)
    stairs = chart_borders(vertices, faces, _staircase_labels(8))
    lower = np.zeros(len(faces), dtype=bool)
    lower[0::2] = True  # each square's triangle below its diagonal
    square = np.repeat(np.arange(64), 2)
    straight = (square % 8 > square // 8) | ((square % 8 == square // 8) & lower)
    diagonal = chart_borders(vertices, faces, straight.astype(np.int64))
    assert stairs.roughness > 1.3
    assert np.isclose(diagonal.roughness, 1.0)
    assert diagonal.sharp_turns == 0
    assert stairs.slivers == diagonal.slivers == 0


def test_a_strip_one_square_wide_is_a_sliver():
    vertices, faces = _grid(8)
    chart = np.zeros(len(faces), dtype=np.int64)
    chart[: 2 * 8] = 1  # the bottom row of squares
    borders = chart_borders(vertices, faces, chart)
    assert borders.slivers == 1
    assert np.isclose(borders.sliver_area, 8 / 64)
    quality = uv_quality(vertices, faces, vertices[faces][:, :, :2] / 8.0, chart)
    assert quality.slivers == 1
