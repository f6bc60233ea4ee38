"""Piece-wise UV unwrapping: UVs that would be wrong fail these properties."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import ParameterError
from neural_shdf.evaluate.uv import chart_borders, uv_quality
from neural_shdf.mesh import TriangleMesh
from neural_shdf.unwrap import (
    UnwrapParams,
    _bisect,
    _connected_pieces,
    _flatten_piece,
    _merge_slivers,
    atlas_layout_image,
    input_face_corner_uvs,
    part_labels_per_triangle,
    polygon_corner_uvs,
    rasterize_charts,
    unwrap,
)
from tests.conftest import as_triangle_mesh


def _capsule_parts() -> tuple[TriangleMesh, np.ndarray]:
    """A capsule cut into 3 parts by height: two caps and a tube."""
    mesh = as_triangle_mesh(trimesh.creation.capsule(height=2.0, radius=0.5, count=[24, 24]))
    z = mesh.vertices[mesh.faces].mean(axis=1)[:, 2]
    labels = np.where(z < -0.9, 0, np.where(z > 0.9, 2, 1))
    return mesh, labels


def _assert_valid_atlas(mesh: TriangleMesh, labels: np.ndarray, atlas) -> None:
    assert atlas.corner_uvs.shape == (mesh.face_count, 3, 2)
    assert np.all((atlas.corner_uvs >= 0) & (atlas.corner_uvs <= 1))
    charted = atlas.chart >= 0
    assert charted.all(), "every non-degenerate triangle belongs to a chart"
    # Each chart lies within one part; different parts never share a chart.
    assert np.array_equal(atlas.chart_part[atlas.chart], labels)
    # No two charts overlap in the atlas (texel centres claimed by two charts).
    _, clashes = rasterize_charts(atlas.corner_uvs, atlas.chart, 2048)
    assert clashes == 0
    quality = uv_quality(mesh.vertices, mesh.faces, atlas.corner_uvs, atlas.chart)
    assert quality.flipped_fraction == 0
    assert quality.overlapping_texels == 0
    assert 1.0 <= quality.l2_stretch < 1.5


def test_each_part_is_charted_on_its_own_and_packed_without_overlap():
    mesh, labels = _capsule_parts()
    atlas = unwrap(mesh, labels)
    _assert_valid_atlas(mesh, labels, atlas)
    # Caps are disks and the tube opens with one cut: one chart per part.
    assert atlas.chart_count == 3
    assert 0.2 < atlas.utilization <= 1.0


def test_a_closed_part_is_cut_open_and_a_non_manifold_part_falls_back_to_xatlas():
    sphere = as_triangle_mesh(trimesh.creation.icosphere(subdivisions=3))
    atlas = unwrap(sphere, np.zeros(sphere.face_count, dtype=np.int64))
    _assert_valid_atlas(sphere, np.zeros(sphere.face_count, dtype=np.int64), atlas)

    # Three fins on one edge: no disk exists, xatlas charts the piece.
    vertices = np.array([[0, 0, 0], [0, 0, 1], [1, 0, 0.5], [-1, 0, 0.5], [0, 1, 0.5]], float)
    fins = TriangleMesh(vertices, np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]))
    atlas = unwrap(fins, np.zeros(3, dtype=np.int64))
    assert atlas.chart_count >= 1
    assert np.all(atlas.chart_part[atlas.chart] == 0)
    assert rasterize_charts(atlas.corner_uvs, atlas.chart, 1024)[1] == 0


def test_unwrap_is_deterministic_and_honours_the_atlas_size():
    mesh, labels = _capsule_parts()
    first = unwrap(mesh, labels, UnwrapParams(atlas_size=512, padding=4))
    second = unwrap(mesh, labels, UnwrapParams(atlas_size=512, padding=4))
    assert np.array_equal(first.corner_uvs, second.corner_uvs)
    assert np.array_equal(first.chart, second.chart)
    assert max(first.width, first.height) <= 512


def test_polygons_stay_in_one_part_and_keep_their_corner_uvs():
    box = trimesh.creation.box()
    # A quad-faced box: 6 quads fan-triangulated into 12 triangles, with origins.
    polygons = np.array(
        [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    )
    faces = np.concatenate([polygons[:, [0, 1, 2]], polygons[:, [0, 2, 3]]])
    order = np.argsort(np.concatenate([np.arange(6), np.arange(6)]), kind="stable")
    mesh = TriangleMesh(box.vertices, faces[order], np.repeat(np.arange(6), 2), 6)
    # Per-triangle labels disagreeing inside a quad: the quad takes one part.
    triangle_labels = np.array([0, 1, 0, 0, 1, 1, 1, 1, 0, 0, 1, 1])
    per_triangle = part_labels_per_triangle(mesh, triangle_labels)
    assert np.all(per_triangle[0::2] == per_triangle[1::2])
    atlas = unwrap(mesh, np.array([0, 0, 1, 1, 0, 1]))
    polygons_out, corner_uvs, consistent = input_face_corner_uvs(mesh, atlas.corner_uvs)
    assert [p.tolist() for p in polygons_out] == polygons.tolist()
    assert len(corner_uvs) == 24
    assert consistent.all()


def test_polygon_corner_uvs_reads_each_polygon_back_from_its_fan():
    """A pentagon, a face without triangles, a triangle and a quad a chart boundary runs
    through: corners in the file's order, UVs per corner, the split quad flagged."""
    from neural_shdf.exchange._common import fan_triangulate

    polygons = [[0, 1, 2, 3, 4], [5, 6], [4, 3, 5], [6, 7, 8, 9]]
    counts = np.array([len(p) for p in polygons])
    faces, origin = fan_triangulate(counts, np.concatenate(polygons))
    mesh = TriangleMesh(np.random.default_rng(0).random((10, 3)), faces, origin, 4)
    vertex_uv = np.random.default_rng(1).random((10, 2))
    corner_uvs = vertex_uv[faces].copy()
    corner_uvs[-1, 0] += 0.25  # the quad's second triangle moves the apex: two charts
    layout = polygon_corner_uvs(mesh, corner_uvs)
    assert layout.corner_counts.tolist() == [5, 0, 3, 4]
    assert layout.vertices.tolist() == polygons[0] + polygons[2] + polygons[3]
    expected = vertex_uv[layout.vertices]
    np.testing.assert_array_equal(layout.uvs, expected)  # the apex from the first triangle
    assert layout.consistent.tolist() == [True, True, True, False]


def test_layout_image_shows_every_chart():
    mesh, labels = _capsule_parts()
    atlas = unwrap(mesh, labels, UnwrapParams(atlas_size=256))
    image = atlas_layout_image(atlas, size=256)
    assert image.shape == (256, 256, 3) and image.dtype == np.uint8
    assert (image != 255).any(axis=2).mean() > 0.2  # charts drawn, not a blank page


@pytest.mark.parametrize(
    ("field", "value"),
    [("atlas_size", 16), ("padding", -1), ("max_stretch", 0.5), ("max_stretch", float("nan"))],
)
def test_bad_parameters_say_what_is_wrong(field, value):
    with pytest.raises(ParameterError, match=field):
        UnwrapParams(**{field: value})


def test_labels_of_the_wrong_length_are_rejected():
    mesh, _ = _capsule_parts()
    with pytest.raises(ParameterError, match="one label per triangle"):
        unwrap(mesh, np.zeros(5, dtype=np.int64))


def _ring_strip(turn_degrees: float, steps: int = 60) -> tuple[np.ndarray, np.ndarray]:
    """A strip of triangles between two concentric arcs sweeping ``turn_degrees``: no
    triangle is flipped, but past 360 degrees the strip lies over itself."""
    from neural_shdf.unwrap import _triangle_areas

    angles = np.radians(np.linspace(0.0, turn_degrees, steps + 1))
    radius = np.linspace(1.0, 0.95, steps + 1)  # a spiral: no two vertices coincide
    inner = np.column_stack([np.cos(angles), np.sin(angles)]) * radius[:, None]
    outer = inner * 1.3
    uv = np.concatenate([inner, outer])
    faces = []
    for i in range(steps):
        faces += [[i, i + 1, steps + 1 + i], [i + 1, steps + 2 + i, steps + 1 + i]]
    faces = np.array(faces)[:, ::-1]  # counter-clockwise
    assert (_triangle_areas(uv, faces) > 0).all()
    return uv, faces


def test_a_chart_whose_border_crosses_itself_is_an_overlap():
    from neural_shdf.unwrap import _overlaps_itself

    assert not _overlaps_itself(*_ring_strip(300.0))
    assert _overlaps_itself(*_ring_strip(420.0))


def _repeated_triangle(copies: int) -> TriangleMesh:
    """One triangle written ``copies`` times over the same three vertices."""
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return TriangleMesh(vertices, np.tile([[0, 1, 2]], (copies, 1)))


def test_pieces_of_an_edge_shared_by_thousands_of_faces_take_linear_memory():
    import tracemalloc

    from neural_shdf.unwrap import _connected_pieces

    faces = _repeated_triangle(3000).faces
    tracemalloc.start()
    try:
        pieces = _connected_pieces(faces, np.arange(len(faces)))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(pieces) == 1 and np.array_equal(pieces[0], np.arange(len(faces)))
    # A face-by-face product would hold 3000^2 links (over 100 MB).
    assert peak < 10 * 2**20


def test_copies_of_one_triangle_share_its_chart_and_uvs():
    mesh = _repeated_triangle(2000)
    rotated = mesh.faces.copy()
    rotated[1::2] = rotated[1::2][:, [1, 2, 0]]  # same triangle, other first corner
    mesh = TriangleMesh(mesh.vertices, rotated)
    atlas = unwrap(mesh, np.zeros(mesh.face_count, dtype=np.int64))
    assert atlas.chart_count == 1 and np.all(atlas.chart == 0)
    # Each corner's UV follows its vertex, whatever the corner order.
    by_vertex = np.zeros((3, 2))
    by_vertex[mesh.faces[0]] = atlas.corner_uvs[0]
    assert np.array_equal(atlas.corner_uvs, by_vertex[mesh.faces])


def test_more_pieces_than_the_chart_budget_are_refused_before_work():
    from neural_shdf.errors import MeshTooLargeError
    from neural_shdf.unwrap import MAX_CHARTS

    count = MAX_CHARTS + 1
    corners = np.arange(count)[:, None, None] * 2.0 + np.array(
        [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    )
    mesh = TriangleMesh(corners.reshape(-1, 3), np.arange(3 * count).reshape(-1, 3))
    with pytest.raises(MeshTooLargeError, match="charts") as raised:
        unwrap(mesh, np.zeros(count, dtype=np.int64))
    assert raised.value.detail() == {"limit": "max_charts", "maximum": MAX_CHARTS, "found": count}


def test_layout_png_is_the_layout_image_drawn_in_strips_with_bounded_memory():
    import io
    import tracemalloc

    from PIL import Image

    from neural_shdf.unwrap import atlas_layout_png

    mesh, labels = _capsule_parts()
    atlas = unwrap(mesh, labels, UnwrapParams(atlas_size=512))
    for size, checker in ((300, 7), (512, 16)):  # a partial last strip, and whole strips
        png = atlas_layout_png(atlas, size=size, checker=checker)
        decoded = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
        assert np.array_equal(decoded, atlas_layout_image(atlas, size=size, checker=checker))
    tracemalloc.start()
    try:
        atlas_layout_png(atlas, size=4096)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # The whole picture would be 48 MB as uint8 (and several times that in floats).
    assert peak < 24 * 2**20


@pytest.mark.parametrize("size", [16, 8193, 100_000])
def test_layout_sizes_outside_the_documented_range_are_refused(size):
    from neural_shdf.unwrap import atlas_layout_png

    mesh, labels = _capsule_parts()
    atlas = unwrap(mesh, labels, UnwrapParams(atlas_size=256))
    with pytest.raises(ParameterError, match="size"):
        atlas_layout_png(atlas, size=size)


def _grid_mesh(n: int) -> TriangleMesh:
    """A flat n x n grid of unit squares, two triangles per square (lower one first)."""
    xs, ys = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="xy")
    vertices = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)]).astype(float)
    a = (np.arange(n)[None, :] + (n + 1) * np.arange(n)[:, None]).ravel()
    lower = np.column_stack([a, a + 1, a + n + 2])
    upper = np.column_stack([a, a + n + 2, a + n + 1])
    return TriangleMesh(vertices, np.stack([lower, upper], axis=1).reshape(-1, 3))


def test_stair_stepped_part_borders_are_straightened_along_mesh_edges():
    n = 12
    mesh = _grid_mesh(n)
    square = np.repeat(np.arange(n * n), 2)
    i, j = square % n, square // n
    stairs = (i > j).astype(np.int64)  # diagonal squares all in part 0: unit steps
    atlas = unwrap(mesh, stairs)
    parts = atlas.chart_part[atlas.chart]
    # One triangle per step moved, next to the old border (either diagonal line is as
    # short); the border now runs along diagonal edges: no turn, barely rougher than a
    # line (its ends bend where it meets the grid's edge).
    moved = parts != stairs
    assert n - 4 <= moved.sum() <= n + 4
    assert np.all(np.abs(i - j)[moved] <= 1)
    borders = chart_borders(mesh.vertices, mesh.faces, atlas.chart)
    assert borders.roughness < 1.05 and borders.sharp_turns == 0
    assert chart_borders(mesh.vertices, mesh.faces, stairs).roughness > 1.3
    # straighten=0: charts follow the parts face for face.
    exact = unwrap(mesh, stairs, UnwrapParams(straighten=0))
    assert np.array_equal(exact.chart_part[exact.chart], stairs)


def test_a_sliver_chart_is_merged_into_its_neighbour_of_the_same_part():
    mesh = _grid_mesh(8)
    chart = np.zeros(mesh.face_count, dtype=np.int64)
    chart[: 2 * 8] = 1  # the bottom row of squares: a strip one square wide
    corner_uvs = mesh.vertices[mesh.faces][:, :, :2].copy()

    def flatten(piece: np.ndarray, max_stretch: float) -> np.ndarray | None:
        used, local = np.unique(mesh.faces[piece], return_inverse=True)
        return _flatten_piece(mesh.vertices[used], local.reshape(-1, 3), max_stretch, 10)

    parts = _merge_slivers(
        mesh.vertices, mesh.faces, corner_uvs, chart, np.array([0, 0]), flatten, 1.1
    )
    assert parts.tolist() == [0]
    assert np.all(chart == 0)
    quality = uv_quality(mesh.vertices, mesh.faces, corner_uvs, chart)
    assert quality.flipped_fraction == 0 and np.isclose(quality.l2_stretch, 1.0)
    # A strip in a part of its own stays: charts never cross parts.
    chart[:] = 0
    chart[: 2 * 8] = 1
    parts = _merge_slivers(
        mesh.vertices, mesh.faces, corner_uvs, chart, np.array([0, 1]), flatten, 1.1
    )
    assert parts.tolist() == [0, 1]


def test_a_piece_is_halved_into_two_connected_halves_of_similar_size():
    sphere = as_triangle_mesh(trimesh.creation.icosphere(subdivisions=4))
    halves = _bisect(sphere.vertices, sphere.faces, np.zeros(0, dtype=np.int64))
    counts = np.bincount(halves, minlength=2)
    assert counts.max() <= 1.25 * counts.mean()
    for half in (0, 1):
        members = np.flatnonzero(halves == half)
        assert len(_connected_pieces(sphere.faces, members)) == 1


def _signed_uv_areas(corner_uvs: np.ndarray) -> np.ndarray:
    s, t = corner_uvs[:, :, 0], corner_uvs[:, :, 1]
    return (s[:, 1] - s[:, 0]) * (t[:, 2] - t[:, 0]) - (s[:, 2] - s[:, 0]) * (t[:, 1] - t[:, 0])


def _charts_with_two_signs(atlas) -> list[int]:
    """Charts holding triangles of both orientations in UV (a flip inside the chart)."""
    sign = np.sign(_signed_uv_areas(atlas.corner_uvs))
    charted = atlas.chart >= 0
    positive = np.bincount(atlas.chart[charted], weights=sign[charted] > 0)
    negative = np.bincount(atlas.chart[charted], weights=sign[charted] < 0)
    return np.flatnonzero((positive > 0) & (negative > 0)).tolist()


def _grid_with_thin_ear(n: int, spacing: float, height: float) -> TriangleMesh:
    """A flat n x n grid of ``spacing``-sized squares plus one thin triangle ("ear") on the
    middle of its bottom border, ``height`` tall, whose apex no other triangle uses."""
    grid = _grid_mesh(n)
    middle = n // 2
    apex = [[(middle + 0.5), -height / spacing, 0.0]]
    vertices = np.concatenate([grid.vertices, apex]) * spacing
    ear = [[middle, len(vertices) - 1, middle + 1]]
    return TriangleMesh(vertices, np.concatenate([grid.faces, ear]))


def test_a_thin_triangle_of_a_dense_scan_keeps_its_place_in_the_packed_chart():
    """On a dense scan's scale a thin, valid triangle (2% of a square's area here; under
    float32's epsilon in UV area) is one xatlas's packer drops as degenerate, leaving its
    own vertex at the atlas origin: the triangle then crossed the atlas, flipped."""
    mesh = _grid_with_thin_ear(16, spacing=0.003, height=0.02 * 0.003)
    labels = np.zeros(mesh.face_count, dtype=np.int64)
    atlas = unwrap(mesh, labels)
    assert atlas.chart_count == 1
    assert _charts_with_two_signs(atlas) == []
    _assert_valid_atlas(mesh, labels, atlas)
    # The ear keeps its shape: its UV area against the squares' is that in 3D (2%).
    areas = np.abs(_signed_uv_areas(atlas.corner_uvs))
    assert areas[-1] / np.median(areas[:-1]) == pytest.approx(0.02, rel=0.05)
    quality = uv_quality(mesh.vertices, mesh.faces, atlas.corner_uvs, atlas.chart)
    assert quality.l2_stretch == pytest.approx(1.0, abs=1e-3)


def test_every_corner_follows_its_charts_map_where_xatlas_left_it_unplaced():
    """Two charts xatlas turned, mirrored and scaled (a little differently along each axis);
    one triangle it dropped and one vertex it left at the origin are mapped with the rest."""
    from neural_shdf.unwrap import _refit_charts

    rng = np.random.default_rng(3)
    source = rng.random((40, 3, 2)) * 10
    source[20:, :, 0] += 30  # the second chart, beside the first
    owner = np.repeat([0, 1], 20)
    maps = [
        (np.array([[0.0, -2.0], [2.01, 0.0]]), np.array([5.0, 7.0])),  # turned a quarter
        (np.array([[1.5, 0.2], [0.2, -1.5]]), np.array([-40.0, 90.0])),  # mirrored
    ]
    expected = np.empty_like(source)
    for chart, (matrix, shift) in enumerate(maps):
        expected[owner == chart] = source[owner == chart] @ matrix.T + shift
    placed = expected.copy()
    packed_chart = owner[::-1].copy()  # xatlas numbers its charts its own way
    packed_chart[3] = -1  # dropped: placed anywhere
    placed[3] = [[0.1, 0.0], [0.0, 0.0], [0.2, 0.1]]
    placed[25, 1] = [0.0, 0.0]  # a vertex xatlas never placed
    mapped = _refit_charts(source, placed, owner, packed_chart, tolerance=0.25)
    np.testing.assert_allclose(mapped, expected, atol=1e-9)
    # A chart xatlas dropped whole has no map to follow: xatlas's placement stays.
    packed_chart[owner == 1] = -1
    mapped = _refit_charts(source, placed, owner, packed_chart, tolerance=0.25)
    np.testing.assert_allclose(mapped[owner == 0], expected[owner == 0], atol=1e-9)
    np.testing.assert_array_equal(mapped[owner == 1], placed[owner == 1])


@pytest.mark.slow
@pytest.mark.needs_data
def test_no_chart_of_a_dense_scan_has_a_flipped_triangle_after_packing(shared_data):
    """The horse head scan (250k faces, dense-dev), cut into slabs along its longest axis:
    xatlas's packer dropped 58 of its thin triangles as degenerate, 6 of which flipped."""
    from neural_shdf.mesh_io import load_mesh

    path = (
        shared_data / "dense-dev" / "polygonjs__models__resources__threedscans.com__horse_head.ply"
    )
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    mesh = load_mesh(path)
    centres = mesh.vertices[mesh.faces].mean(axis=1)
    axis = int(np.argmax(np.ptp(mesh.vertices, axis=0)))
    labels = np.digitize(centres[:, axis], np.quantile(centres[:, axis], [0.25, 0.5, 0.75]))
    atlas = unwrap(mesh, labels)
    assert _charts_with_two_signs(atlas) == []
    quality = uv_quality(mesh.vertices, mesh.faces, atlas.corner_uvs, atlas.chart)
    assert quality.flipped_fraction == 0
    assert quality.overlapping_texels == 0
    assert quality.l2_stretch < 1.2
