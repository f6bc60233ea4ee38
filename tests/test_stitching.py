"""Proximity stitching: open shells split from one surface and moved a little are joined for
the graphs; closed shells, holes in one shell and pieces far apart are not."""

from __future__ import annotations

import numpy as np
import trimesh
from scipy.sparse.csgraph import connected_components

from neural_shdf import stitching
from neural_shdf.geometry import face_normals, weld_faces
from neural_shdf.mesh import TriangleMesh
from neural_shdf.orientation import hole_caps, orient_faces, welded_edges
from neural_shdf.stitching import (
    STITCH_TOLERANCE,
    boundary_edges,
    cap_spokes,
    closing_caps,
    orient_stitched_shells,
    stitch_counts,
    stitch_shells,
)


def _sphere(subdivisions: int = 3) -> tuple[np.ndarray, np.ndarray]:
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    return np.asarray(sphere.vertices), np.asarray(sphere.faces)


def _split(vertices: np.ndarray, faces: np.ndarray, piece: np.ndarray, shift: np.ndarray):
    """Each piece of faces an open shell of its own (vertices copied along the cuts), piece
    ``k`` moved by ``shift[k]``."""
    keys = faces.reshape(-1) * (int(piece.max()) + 1) + np.repeat(piece, 3)
    unique, inverse = np.unique(keys, return_inverse=True)
    vertex, vertex_piece = np.divmod(unique, int(piece.max()) + 1)
    return vertices[vertex] + shift[vertex_piece], inverse.reshape(-1, 3)


def _halves(shift: float) -> tuple[np.ndarray, np.ndarray, float]:
    """A sphere cut in two open halves at z = 0, the upper moved by ``shift`` edge lengths
    (sideways and up); also the median edge length."""
    vertices, faces = _sphere()
    upper = (vertices[faces, 2].mean(axis=1) > 0).astype(np.int64)
    edge = float(np.median(np.linalg.norm(vertices[faces[:, 0]] - vertices[faces[:, 1]], axis=1)))
    offset = np.array([[0.0, 0.0, 0.0], [0.6, 0.0, 0.8]]) * shift * edge
    moved, split = _split(vertices, faces, upper, offset)
    return moved, split, edge


def _cup_pieces(shift: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A thin-walled cup (a closed surface: outer wall and bottom, rim, inner wall and
    bottom) cut in two pieces, the band from the outer wall's middle over the rim down to
    near the inner bottom moved by ``shift`` edge lengths: (vertices, faces, band faces).
    Alone, the band capped over its two loops encloses a negative volume (its inner side
    reaches deeper than its outer one), and so does the inner bottom (a bowl)."""
    wall = 0.06
    profile = np.array(
        [[0, 0], [1, 0], [1, 2], [1 - wall, 2], [1 - wall, wall], [0, wall]], dtype=float
    )
    dense = np.concatenate(
        [
            np.linspace(a, b, 12, endpoint=False)
            for a, b in zip(profile[:-1], profile[1:], strict=True)
        ]
        + [profile[-1:]]
    )
    cup = trimesh.creation.revolve(dense, sections=48)
    cup.merge_vertices()
    cup.update_faces(cup.nondegenerate_faces())
    vertices, faces = np.asarray(cup.vertices), np.asarray(cup.faces)
    centre = vertices[faces].mean(axis=1)
    inner = np.hypot(centre[:, 0], centre[:, 1]) < 1 - wall / 2
    band = np.where(inner, centre[:, 2] > 0.3, centre[:, 2] > 1.2) | (centre[:, 2] > 2 - wall / 2)
    edge = float(np.median(np.linalg.norm(vertices[faces[:, 0]] - vertices[faces[:, 1]], axis=1)))
    offset = np.array([[0.0, 0.0, 0.0], [0.6, 0.0, 0.8]]) * shift * edge
    moved, split = _split(vertices, faces, band.astype(np.int64), offset)
    return moved, split, band


def _stitched(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    coincident = weld_faces(vertices, faces)
    return coincident, stitch_shells(vertices, coincident, welded_edges(coincident))


def _face_components(mesh: TriangleMesh) -> int:
    return connected_components(mesh.face_graph.csr(), directed=False)[0]


def test_a_closed_mesh_is_returned_as_given():
    coincident, stitched = _stitched(*_sphere())
    assert stitched is coincident


def test_one_shell_with_a_hole_is_returned_as_given():
    vertices, faces = _sphere()
    coincident, stitched = _stitched(vertices, faces[10:])
    assert stitched is coincident


def test_halves_moved_apart_by_half_an_edge_length_are_zipped_closed():
    vertices, faces, _ = _halves(0.5)
    coincident, stitched = _stitched(vertices, faces)
    assert len(boundary_edges(welded_edges(coincident), int(coincident.max()) + 1)[0]) == 96
    assert len(boundary_edges(welded_edges(stitched), int(stitched.max()) + 1)[0]) == 0
    _, caps = hole_caps(vertices, stitched, welded_edges(stitched))
    assert len(caps) == 0


def test_halves_moved_apart_by_an_edge_length_are_one_surface_for_the_graphs():
    vertices, faces, _ = _halves(1.0)
    coincident, stitched = _stitched(vertices, faces)
    before = boundary_edges(welded_edges(coincident), int(coincident.max()) + 1)[0]
    after = boundary_edges(welded_edges(stitched), int(stitched.max()) + 1)[0]
    # Farther than about half an edge the mutual nearest pairs zip the cut only in part;
    # the half moved onto the other by their median offset zips it closed.
    assert len(before) == 96 and len(after) == 0
    # Stitching joins pairs: no triangle repeats a vertex, no edge is on three triangles.
    assert np.all((stitched[:, 0] != stitched[:, 1]) & (stitched[:, 1] != stitched[:, 2]))
    mesh = TriangleMesh(vertices, faces)
    assert _face_components(mesh) == 1
    # The rays' caps close only what stays open, not a lid through the middle.
    _, caps = hole_caps(vertices, mesh.welded_faces, mesh.welded_edges)
    _, unstitched_caps = hole_caps(vertices, coincident, welded_edges(coincident))
    assert len(caps) == len(after) < len(unstitched_caps)


def _quarters(shift: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A sphere cut in four open pieces by the planes x = 0 and y = 0, each moved by
    ``shift`` edge lengths in a direction of its own (as ``bench_production.py``'s
    ``shells``): (vertices, faces, the original vertex of each vertex)."""
    vertices, faces = _sphere(4)
    centre = vertices[faces].mean(axis=1)
    piece = (2 * (centre[:, 0] > 0) + (centre[:, 1] > 0)).astype(np.int64)
    edge = float(np.median(np.linalg.norm(vertices[faces[:, 0]] - vertices[faces[:, 1]], axis=1)))
    directions = np.random.default_rng(seed).normal(size=(4, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    keys = faces.reshape(-1) * 4 + np.repeat(piece, 3)
    unique, inverse = np.unique(keys, return_inverse=True)
    vertex, vertex_piece = np.divmod(unique, 4)
    moved = vertices[vertex] + shift * edge * directions[vertex_piece]
    return moved, inverse.reshape(-1, 3), vertex


def test_pieces_moved_apart_in_different_directions_are_zipped_along_their_cuts():
    vertices, faces, original = _quarters(1.0)
    coincident, stitched = _stitched(vertices, faces)
    before = boundary_edges(welded_edges(coincident), int(coincident.max()) + 1)[0]
    after = boundary_edges(welded_edges(stitched), int(stitched.max()) + 1)[0]
    # Mutual nearest pairs and the guided rounds alone left 108 of the 384 open.
    assert len(before) == 384 and len(after) < 0.1 * len(before)
    # Each joined vertex is its own counterpart across the cut (the same original vertex):
    # every piece is moved onto its neighbour by the offset their stitches share.
    joined = np.flatnonzero(stitched.reshape(-1) != coincident.reshape(-1))
    assert len(joined) > 0
    source = coincident.reshape(-1)[joined]
    target = stitched.reshape(-1)[joined]
    assert np.mean(original[source] == original[target]) > 0.95


def test_stitched_pieces_weld_to_the_same_points_whatever_order_the_vertices_come_in():
    vertices, faces, _ = _quarters(1.0)
    _, stitched = _stitched(vertices, faces)
    corners = np.sort(vertices[stitched].reshape(len(faces), -1), axis=1)
    for seed in range(3):
        order = np.random.default_rng(seed).permutation(len(vertices))
        new_index = np.argsort(order)
        _, again = _stitched(vertices[order], new_index[faces])
        # Each stitched pair keeps the point of lower position, not the lower index: the
        # rays' caps and the graphs' edges see the same points (up to version 17 the
        # lower index was kept, so a reordered file moved the caps).
        np.testing.assert_array_equal(
            np.sort(vertices[order][again].reshape(len(faces), -1), axis=1), corners
        )


def test_the_orientation_pass_still_sees_each_piece_as_a_shell():
    vertices, faces, _ = _halves(1.0)
    mesh = TriangleMesh(vertices, faces)
    assert mesh.orientation.diagnostics.shells == 2
    assert not mesh.orientation.flips.any()


def test_the_diagnostics_say_how_many_shells_and_vertices_were_stitched():
    vertices, faces, _ = _halves(0.5)
    mesh = TriangleMesh(vertices, faces)
    # Zipped closed: every one of the 48 vertices along the cut merged into its partner.
    assert (mesh.diagnostics.stitched_shells, mesh.diagnostics.stitched_vertices) == (2, 48)
    assert mesh.diagnostics.shells == 2  # the orientation pass's count is of the file's pieces
    assert "2 shells stitched (48 vertices)" in mesh.diagnostics.summary()
    apart = TriangleMesh(*_halves(2.0 * STITCH_TOLERANCE)[:2])
    assert (apart.diagnostics.stitched_shells, apart.diagnostics.stitched_vertices) == (0, 0)


def test_stitch_counts_count_only_the_shells_joined_to_another():
    vertices, faces, _ = _halves(0.5)
    far = _sphere()[1] + len(vertices)  # a third, closed shell far away: never stitched
    vertices = np.vstack([vertices, _sphere()[0] + 10.0])
    coincident, stitched = _stitched(vertices, np.vstack([faces, far]))
    assert stitch_counts(coincident, stitched) == (2, 48)
    assert stitch_counts(coincident, coincident) == (0, 0)


def test_pieces_farther_apart_than_the_tolerance_stay_apart():
    vertices, faces, _ = _halves(2.0 * STITCH_TOLERANCE)
    coincident, stitched = _stitched(vertices, faces)
    assert stitched is coincident
    assert _face_components(TriangleMesh(vertices, faces)) == 2


def test_a_closed_shell_next_to_open_ones_is_never_stitched():
    vertices, faces, edge = _halves(1.0)
    eye_vertices, eye_faces = _sphere(2)
    # A closed ball touching the cut, as close as the halves are to each other.
    eye_vertices = 0.2 * eye_vertices + np.array([1.0 + 0.2 + 0.5 * edge, 0.0, 0.0])
    all_vertices = np.vstack([vertices, eye_vertices])
    all_faces = np.vstack([faces, eye_faces + len(vertices)])
    _, stitched = _stitched(all_vertices, all_faces)
    eye = stitched[len(faces) :]
    assert np.array_equal(eye, eye_faces + len(vertices))
    assert not np.isin(stitched[: len(faces)], eye).any()
    assert _face_components(TriangleMesh(all_vertices, all_faces)) == 2


def test_labels_keep_the_input_face_order_and_parts_cross_the_cut():
    from neural_shdf.pipeline import compute_shdf, segment

    vertices, faces, _ = _halves(1.0)
    mesh = TriangleMesh(vertices, faces)
    labels = segment(mesh, compute_shdf(mesh, method="exact", seed=0).values).labels
    assert labels.shape == (len(faces),)
    # A ball is one part: the cut between the halves is not a part boundary.
    assert len(np.unique(labels)) == 1


def test_stitched_edges_have_the_length_and_fold_of_the_uncut_surface():
    vertices, faces = _sphere()
    whole = TriangleMesh(vertices, faces).face_graph
    moved, split, _ = _halves(0.5)
    graph = TriangleMesh(moved, split).face_graph
    assert np.array_equal(graph.pairs, whole.pairs)
    # A sphere is convex everywhere: a fold read across the gap would say concave.
    assert not graph.concave.any()
    assert np.allclose(graph.edge_length, whole.edge_length)


def _graph_by_face_pair(mesh: TriangleMesh, face_of: np.ndarray) -> dict:
    """The face graph's edges keyed by the pair of ``face_of`` ids: (length, concave)."""
    graph = mesh.face_graph
    pairs = np.sort(face_of[graph.pairs], axis=1)
    return {
        (int(a), int(b)): (round(float(length), 9), bool(concave))
        for (a, b), length, concave in zip(pairs, graph.edge_length, graph.concave, strict=True)
    }


def test_stitched_edges_measure_the_same_whatever_order_the_faces_come_in():
    """Up to version 17 a stitched edge took its length and fold from the triangle of lower
    index: a file listing the faces in another order read other creases there."""
    vertices, faces, _ = _quarters(1.0)
    # Each piece's copy of a cut vertex a little off the other's (another tessellation):
    # the two triangles at a stitched edge measure it differently.
    vertices = vertices + 0.003 * np.random.default_rng(7).normal(size=vertices.shape)
    given = _graph_by_face_pair(TriangleMesh(vertices, faces), np.arange(len(faces)))
    for seed in range(3):
        order = np.random.default_rng(seed).permutation(len(faces))
        assert _graph_by_face_pair(TriangleMesh(vertices, faces[order]), order) == given


def _slit_halves(monkeypatch) -> tuple[np.ndarray, np.ndarray, float]:
    """``_halves(1.5)`` stitched without the rigid rounds: the cut zipped in part, slits
    left between the stitches (what a piece not moved as a whole leaves)."""
    monkeypatch.setattr(stitching, "_RIGID_ROUNDS", 0)
    return _halves(1.5)


def test_rays_meet_bridges_across_the_slits_not_a_lid_through_the_middle(monkeypatch):
    from neural_shdf.shdf.stage import ray_targets

    vertices, faces, _ = _slit_halves(monkeypatch)
    mesh = TriangleMesh(vertices, faces)
    ray_vertices, targets = ray_targets(mesh, close_holes=True)
    caps = targets[len(faces) :]
    assert len(caps) > 0
    # Every cap lies on the cut (|z| small), none reaches into the ball (a fan's centroid).
    heights = np.abs(ray_vertices[caps, 2] - 0.5 * (vertices[:, 2].max() + vertices[:, 2].min()))
    assert heights.max() < 0.2


def test_bridges_come_first_and_count_as_surface_for_the_rays(monkeypatch):
    from neural_shdf.shdf.stage import ray_targets, surface_triangles

    vertices, faces, _ = _slit_halves(monkeypatch)
    mesh = TriangleMesh(vertices, faces)
    _, targets = ray_targets(mesh, close_holes=True)
    is_fan = targets[:, 2] >= len(vertices)  # a fan ends at its loop's centroid
    surface = surface_triangles(mesh, targets)
    assert len(faces) < surface  # bridges across the slit
    assert not is_fan[:surface].any() and is_fan[surface:].all()
    sphere_vertices, sphere_faces = _sphere()
    holed = TriangleMesh(sphere_vertices, sphere_faces[10:])
    _, holed_targets = ray_targets(holed, close_holes=True)
    assert surface_triangles(holed, holed_targets) == len(sphere_faces) - 10  # fans only


def test_a_mostly_open_mesh_of_separate_sheets_is_not_stitched():
    # Each triangle a sheet of its own, a little apart: nothing to restore, and the work
    # stays bounded (boundary edges are every edge here).
    vertices, faces = _sphere()
    corners = vertices[faces]
    apart = corners + 0.02 * corners.mean(axis=1, keepdims=True)
    soup_vertices = apart.reshape(-1, 3)
    soup_faces = np.arange(len(soup_vertices)).reshape(-1, 3)
    coincident, stitched = _stitched(soup_vertices, soup_faces)
    assert stitched is coincident


def test_cap_spokes_join_the_rim_faces_along_each_hole() -> None:
    """A sphere with a hole: one spoke per rim vertex, between the triangles on the rim
    edges before and after it, as long as the vertex is from the loop's centroid."""
    vertices, faces = _sphere()
    kept = faces[vertices[faces, 2].mean(axis=1) < 0.8]  # a round hole at the top
    mesh = TriangleMesh(vertices, kept)
    welded, edges = mesh.welded_faces, mesh.welded_edges
    coincident, _ = mesh.coincident_welding
    capped, caps = closing_caps(mesh.vertices, coincident, welded, edges)
    pairs, lengths = cap_spokes(capped, len(mesh.vertices), welded, edges, caps)
    rim_vertices = np.unique(caps[:, :2])
    assert len(pairs) == len(caps) == len(rim_vertices)
    rim = np.unique(pairs)
    edge_faces = boundary_edges(edges, len(mesh.vertices))
    assert len(edge_faces[0]) == len(caps)
    # every rim triangle touches the hole, and the spokes reach the loop's centroid
    assert np.all(np.isin(kept[rim], rim_vertices).any(axis=1))
    centre = vertices[rim_vertices].mean(axis=0)
    np.testing.assert_allclose(
        np.sort(lengths), np.sort(np.linalg.norm(vertices[rim_vertices] - centre, axis=1))
    )
    # a closed mesh has no caps and no spokes
    whole = TriangleMesh(vertices, faces)
    capped, caps = closing_caps(
        whole.vertices, whole.coincident_welding[0], whole.welded_faces, whole.welded_edges
    )
    assert len(caps) == 0
    assert (
        len(cap_spokes(capped, len(vertices), whole.welded_faces, whole.welded_edges, caps)[0]) == 0
    )


def test_pieces_of_a_thin_walled_cup_face_out_of_the_cup_together():
    for shift in (0.3, 1.0):
        vertices, faces, _ = _cup_pieces(shift)
        mesh = TriangleMesh(vertices, faces)
        coincident, edges = mesh.coincident_welding
        alone = orient_faces(vertices, faces, welded=coincident, edges=edges)
        assert alone.flips.sum() > len(faces) / 2  # each piece on its own: band and bowl turned
        assert mesh.diagnostics.stitched_shells == 3
        assert not mesh.orientation.flips.any()
        assert mesh.diagnostics.reoriented_faces == 0


def test_a_stitched_piece_wound_inside_out_in_the_file_is_turned_back():
    vertices, faces, band = _cup_pieces(1.0)
    for reversed_faces in (band, np.ones(len(faces), dtype=bool)):
        given = faces.copy()
        given[reversed_faces] = faces[reversed_faces][:, ::-1]
        mesh = TriangleMesh(vertices, given)
        np.testing.assert_array_equal(mesh.orientation.flips, reversed_faces)


def test_a_stitched_mesh_oriented_derives_both_weldings_edges_as_built_afresh():
    vertices, faces, band = _cup_pieces(1.0)
    given = faces.copy()
    given[band] = faces[band][:, ::-1]
    oriented = TriangleMesh(vertices, given).oriented
    afresh = TriangleMesh(oriented.vertices, oriented.faces)
    assert oriented.welded_faces is not oriented.coincident_faces  # pieces stitched
    for name in ("coincident_welding", "welded_edges"):
        assert name not in oriented.__dict__
    coincident, (table, slot) = oriented.coincident_welding
    fresh_coincident, (fresh_table, fresh_slot) = afresh.coincident_welding
    np.testing.assert_array_equal(coincident, fresh_coincident)
    np.testing.assert_array_equal(table, fresh_table)
    np.testing.assert_array_equal(slot, fresh_slot)
    for got, fresh in zip(oriented.welded_edges, afresh.welded_edges, strict=True):
        np.testing.assert_array_equal(got, fresh)
    np.testing.assert_array_equal(oriented.welded_faces, afresh.welded_faces)


def test_shells_not_stitched_keep_their_own_orientation():
    vertices, faces = _sphere()
    coincident = weld_faces(vertices, faces)
    edges = welded_edges(coincident)
    flips = np.zeros(len(faces), dtype=bool)
    normals, areas = face_normals(vertices, faces)
    assert (
        orient_stitched_shells(
            vertices, coincident, edges, coincident, edges, flips, normals, areas
        )
        is flips
    )
    # Halves too far apart to be stitched: each faces out of its own half.
    vertices, faces, _ = _halves(2 * STITCH_TOLERANCE)
    mesh = TriangleMesh(vertices, faces)
    assert mesh.diagnostics.stitched_shells == 0
    assert not mesh.orientation.flips.any()


def test_a_flat_sheet_in_stitched_pieces_takes_the_winding_of_its_largest_piece():
    n = 32  # a grid of n x n squares: boundary edges a small share of the triangles
    x, y = np.meshgrid(np.linspace(-1, 1, n + 1), np.linspace(-1, 1, n + 1), indexing="ij")
    vertices = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    corner = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    faces = np.concatenate(
        [
            np.stack([corner, corner + n + 1, corner + n + 2], axis=1),
            np.stack([corner, corner + n + 2, corner + 1], axis=1),
        ]
    )
    small = (vertices[faces, 0].mean(axis=1) > 0.5).astype(np.int64)  # a quarter of it
    edge = float(np.median(np.linalg.norm(vertices[faces[:, 0]] - vertices[faces[:, 1]], axis=1)))
    moved, split = _split(vertices, faces, small, np.array([[0, 0, 0], [0.5 * edge, 0, 0]]))
    given = split.copy()
    given[small == 1] = split[small == 1][:, ::-1]  # the small piece wound the other way
    mesh = TriangleMesh(moved, given)
    assert mesh.diagnostics.stitched_shells == 2
    np.testing.assert_array_equal(mesh.orientation.flips, small == 1)


def test_a_listed_mesh_stitches_the_same_seams_in_any_pose():
    """``TriangleMesh.listing`` stitches in the frame it was listed in: a turned, scaled
    and moved copy of pieces moved apart joins the same vertices (in world coordinates,
    the nearest-point ties and the position order of a pair followed the pose)."""
    from scipy.spatial.transform import Rotation

    vertices, faces, _ = _quarters(1.0, seed=3)
    vertices = vertices * (1.8, 1.0, 0.7) + (0.0, 0.0, 0.2) * vertices[:, :1] ** 2
    mesh = TriangleMesh(vertices, faces)
    rotation = Rotation.random(random_state=8).as_matrix()
    moved = TriangleMesh(30.0 * vertices @ rotation.T + (4e2, -9.0, 2.0), faces)
    listed, order = mesh.listing
    other, other_order = moved.listing
    assert order is not None and np.array_equal(order, other_order)
    assert listed.diagnostics.stitched_shells == 4
    np.testing.assert_array_equal(other.welded_faces, listed.welded_faces)
    np.testing.assert_array_equal(moved.orientation.flips, mesh.orientation.flips)
