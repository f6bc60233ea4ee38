"""Orientation that does not trust the file: flips, diagnostics, and what the ShDF and the
segmentation see on reversed, mixed, multi-shell, open and non-manifold meshes."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from neural_shdf import orientation
from neural_shdf.geometry import (
    build_face_graph,
    face_centroids,
    face_normals,
    in_frame,
    weld_faces,
    zero_area_limit,
)
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.orientation import (
    boundary_edge_rows,
    hole_caps,
    orient_faces,
    reverse_flipped,
    reverse_rows,
    reversed_slots,
    welded_edges,
)
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.shdf.stage import ShdfParams, raw_diameters
from tests.mesh_helpers import relisted


def _sphere(subdivisions: int = 3, radius: float = 1.0, centre=(0.0, 0.0, 0.0)):
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(sphere.vertices) + centre, np.asarray(sphere.faces)


def _reverse(faces: np.ndarray, which: np.ndarray) -> np.ndarray:
    out = faces.copy()
    out[which] = faces[which][:, ::-1]
    return out


def _dumbbell() -> TriangleMesh:
    left = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    right = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    left.apply_translation([-2.5, 0, 0])
    right.apply_translation([2.5, 0, 0])
    bar = trimesh.creation.cylinder(radius=0.3, height=3.5, sections=24)
    bar.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    mesh = trimesh.util.concatenate([left, bar, right])
    return TriangleMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))


def test_an_outward_closed_mesh_is_left_alone():
    vertices, faces = _sphere()
    result = orient_faces(vertices, faces)
    assert not result.flips.any()
    assert result.diagnostics.as_dict() == {
        "shells": 1,
        "boundary_loops": 0,
        "non_manifold_edges": 0,
        "reoriented_faces": 0,
        "degenerate_faces": 0,
        "duplicate_faces": 0,
        "stitched_shells": 0,
        "stitched_vertices": 0,
    }


def test_an_inside_out_mesh_is_turned_round_and_mixed_winding_made_consistent():
    vertices, faces = _sphere()
    assert orient_faces(vertices, faces[:, ::-1]).flips.all()
    mixed = np.random.default_rng(0).random(len(faces)) < 0.3
    result = orient_faces(vertices, _reverse(faces, mixed))
    np.testing.assert_array_equal(result.flips, mixed)
    assert result.diagnostics.reoriented_faces == mixed.sum()


def test_every_shell_faces_out_of_its_own_solid():
    """Two spheres apart and a small one inside the first (an eye), each given any winding."""
    eye = _sphere(1, radius=0.2, centre=(0.5, 0, 0))
    shells = [_sphere(2), _sphere(2, centre=(3.0, 0, 0)), eye]
    vertices = np.vstack([v for v, _ in shells])
    offsets = np.cumsum([0] + [len(v) for v, _ in shells])[:-1]
    faces = [f + offset for (_, f), offset in zip(shells, offsets, strict=True)]
    given = [faces[0][:, ::-1], faces[1], faces[2][:, ::-1]]
    result = orient_faces(vertices, np.vstack(given))
    sizes = np.cumsum([0] + [len(f) for f in faces])
    assert result.flips[sizes[0] : sizes[1]].all()
    assert not result.flips[sizes[1] : sizes[2]].any()
    assert result.flips[sizes[2] : sizes[3]].all()
    assert result.diagnostics.shells == 3


@pytest.mark.parametrize("cut", [-0.8, 0.0])  # a small hole; half the sphere gone
def test_open_shells_face_outward(cut: float):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    kept = sphere.triangles_center[:, 2] > cut
    faces = np.asarray(sphere.faces)[kept]
    mixed = np.random.default_rng(1).random(len(faces)) < 0.5
    result = orient_faces(np.asarray(sphere.vertices), _reverse(faces, mixed))
    np.testing.assert_array_equal(result.flips, mixed)
    assert result.diagnostics.boundary_loops == 1


def test_a_flat_sheet_keeps_the_winding_most_of_it_has_in_the_file():
    plane = trimesh.creation.box(extents=(1, 1, 1))
    grid = trimesh.remesh.subdivide_to_size(plane.vertices, plane.faces, 0.1)
    vertices, faces = np.asarray(grid[0]), np.asarray(grid[1])
    top = vertices[faces].mean(axis=1)[:, 2] > 0.49
    sheet = faces[top]
    odd = np.random.default_rng(2).random(len(sheet)) < 0.2
    result = orient_faces(vertices, _reverse(sheet, odd))
    np.testing.assert_array_equal(result.flips, odd)


def test_solids_touching_along_an_edge_are_decided_each_on_its_own():
    """Two cubes sharing one edge (four faces on it): the edge is non-manifold."""
    first = trimesh.creation.box(extents=(1, 1, 1))
    second = trimesh.creation.box(extents=(1, 1, 1))
    second.apply_translation([1.0, 1.0, 0.0])
    vertices = np.vstack([first.vertices, second.vertices])
    faces = np.vstack([first.faces, second.faces[:, ::-1] + len(first.vertices)])
    result = orient_faces(vertices, faces)
    assert not result.flips[:12].any()
    assert result.flips[12:].all()
    assert result.diagnostics.non_manifold_edges == 1
    assert result.diagnostics.shells == 1


def test_a_fin_does_not_turn_the_box_it_stands_on():
    """A box with a sheet standing on its top: the sheet's edge is non-manifold."""
    box = trimesh.creation.box(extents=(1, 1, 1))
    top = [i for i, v in enumerate(box.vertices) if v[2] > 0 and v[1] < 0]  # an edge of the top
    a, b = box.vertices[top[0]], box.vertices[top[1]]
    vertices = np.vstack([box.vertices, a + [0, 0, 1], b + [0, 0, 1]])
    fin = np.array([[top[0], top[1], 8], [top[1], 9, 8]])
    faces = np.vstack([np.asarray(box.faces)[:, ::-1], fin])
    result = orient_faces(vertices, faces)
    assert result.flips[:12].all()
    assert result.diagnostics.non_manifold_edges == 1


@pytest.mark.parametrize("wound_out", [True, False])
def test_a_fin_faces_away_from_the_centre_whatever_its_winding_in_the_file(wound_out: bool):
    """A sheet has no inside: it faces away from the mesh's centre, so an inside-out file
    gets the same triangles back (up to version 17 it kept the file's winding, and a
    reversed export of a jet with wing sheets came out in other parts)."""
    box = trimesh.creation.box(extents=(1, 1, 1))
    top = [i for i, v in enumerate(box.vertices) if v[2] > 0 and v[1] < 0]
    a, b = box.vertices[top[0]], box.vertices[top[1]]
    vertices = np.vstack([box.vertices, a + [0, 0, 1], b + [0, 0, 1]])
    fin = np.array([[top[0], top[1], 8], [top[1], 9, 8]])
    faces = np.vstack([np.asarray(box.faces), fin if wound_out else fin[:, ::-1]])
    oriented = []
    for given in (faces, faces[:, ::-1]):
        flips = orient_faces(vertices, given).flips
        oriented.append(_reverse(given, flips))
    np.testing.assert_array_equal(oriented[0], oriented[1])
    normals, _ = face_normals(vertices, oriented[0])
    assert np.all(normals[12:, 1] < -0.99)  # the fin, in the plane y = -0.5, faces -y


def test_a_triangle_soup_is_welded_before_it_is_oriented():
    vertices, faces = _sphere(2)
    soup_vertices = vertices[faces[:, ::-1]].reshape(-1, 3)
    soup_faces = np.arange(len(soup_vertices)).reshape(-1, 3)
    result = orient_faces(soup_vertices, soup_faces)
    assert result.flips.all()
    assert result.diagnostics.shells == 1


def test_duplicate_and_degenerate_faces_are_counted_and_duplicates_follow_their_first_copy():
    vertices, faces = _sphere(2)
    extra = np.vstack([faces[:4][:, ::-1], faces[4:6], [[0, 0, 1], [0, 1, 1]]])
    result = orient_faces(vertices, np.vstack([faces, extra]))
    n = len(faces)
    assert not result.flips[:n].any()
    np.testing.assert_array_equal(result.flips[n : n + 6], [True] * 4 + [False] * 2)
    assert result.diagnostics.duplicate_faces == 6
    assert result.diagnostics.degenerate_faces == 2
    assert result.diagnostics.boundary_loops == 0


def test_an_empty_mesh_has_nothing_to_report():
    result = orient_faces(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    assert len(result.flips) == 0
    assert result.diagnostics.shells == 0


def test_the_oriented_mesh_keeps_the_input_and_is_its_own_orientation():
    vertices, faces = _sphere(2)
    mesh = TriangleMesh(vertices, faces[:, ::-1])
    oriented = mesh.oriented
    np.testing.assert_array_equal(mesh.faces, faces[:, ::-1])  # the input stays as given
    clean = TriangleMesh(vertices, faces)
    # Reversed backwards, each triangle is the clean one again, normals and all.
    np.testing.assert_array_equal(oriented.faces, faces)
    np.testing.assert_array_equal(oriented.normals_and_areas[0], clean.normals_and_areas[0])
    np.testing.assert_array_equal(oriented.face_origin, mesh.face_origin)
    assert oriented.oriented is oriented
    assert not oriented.orientation.flips.any()
    assert clean.oriented is clean


@pytest.mark.parametrize("method", ["exact", "sampled", "neural"])
def test_the_shdf_of_a_reversed_or_mixed_mesh_is_the_published_one(method: str):
    published = _dumbbell()
    reference = compute_shdf(published, method=method)
    assert reference.diagnostics is not None and reference.diagnostics.reoriented_faces == 0
    mixed = np.random.default_rng(3).random(published.face_count) < 0.3
    for which in (np.ones(published.face_count, dtype=bool), mixed):
        variant = TriangleMesh(published.vertices, _reverse(published.faces, which))
        result = compute_shdf(variant, method=method)
        np.testing.assert_allclose(result.values, reference.values, atol=1e-6)
        assert result.diagnostics.reoriented_faces == which.sum()


def test_the_face_graph_sees_the_oriented_creases():
    published = _dumbbell()
    reversed_ = TriangleMesh(published.vertices, published.faces[:, ::-1])
    np.testing.assert_array_equal(reversed_.face_graph.concave, published.face_graph.concave)


def _labels(mesh: TriangleMesh):
    return segment(mesh, compute_shdf(mesh).values)


def test_labels_of_a_reversed_mesh_are_the_published_ones():
    published = _dumbbell()
    reversed_ = TriangleMesh(published.vertices, published.faces[:, ::-1])
    result = _labels(reversed_)
    np.testing.assert_array_equal(result.labels, _labels(published).labels)
    assert result.diagnostics.reoriented_faces == published.face_count


def test_labels_of_a_reversed_benchmark_mesh_are_the_published_ones(psb_off):
    published = load_mesh(psb_off(4))
    reversed_ = TriangleMesh(published.vertices, published.faces[:, ::-1])
    np.testing.assert_array_equal(_labels(reversed_).labels, _labels(published).labels)


def test_the_face_graph_from_the_shared_edges_is_the_one_built_afresh():
    published = _dumbbell()
    mixed = np.random.default_rng(4).random(published.face_count) < 0.3
    variant = TriangleMesh(published.vertices, _reverse(published.faces, mixed))
    oriented = variant.oriented
    shared = variant.face_graph
    # Built in the mesh's pose frame (``TriangleMesh.face_graph``), lengths scaled back.
    framed = in_frame(oriented.vertices, oriented.pose_frame)
    afresh = build_face_graph(
        framed,
        weld_faces(oriented.vertices, oriented.faces),
        face_normals(framed, oriented.faces)[0],
    )
    afresh = replace(afresh, edge_length=afresh.edge_length * oriented.pose_frame[2])
    for name in ("pairs", "edge_vertices", "edge_length", "dihedral", "concave"):
        np.testing.assert_array_equal(getattr(shared, name), getattr(afresh, name))
    # the links were worked out beside the pass, on the file's winding, and shared
    assert oriented.face_adjacency is variant.face_adjacency
    assert shared.pairs is variant.face_adjacency[0]


def test_the_oriented_copy_derives_its_edges_only_when_asked():
    """A closed mesh's ShDF and segmentation never read the oriented copy's edge slots, so
    the copy does not write them; asked for, they are those of its own triangles."""
    published = _dumbbell()
    mixed = np.random.default_rng(5).random(published.face_count) < 0.3
    variant = TriangleMesh(published.vertices, _reverse(published.faces, mixed))
    _labels(variant)
    oriented = variant.oriented
    assert "welded_edges" not in oriented.__dict__
    assert "coincident_welding" not in oriented.__dict__
    table, slot = oriented.welded_edges
    fresh_table, fresh_slot = welded_edges(weld_faces(oriented.vertices, oriented.faces))
    np.testing.assert_array_equal(table, fresh_table)
    np.testing.assert_array_equal(slot, fresh_slot)
    coincident, edges = oriented.coincident_welding
    assert coincident is oriented.welded_faces
    assert edges is oriented.welded_edges


def test_caps_close_each_hole_facing_outward():
    vertices, faces = _sphere(3)
    centres = vertices[faces].mean(axis=1)
    kept = faces[(centres[:, 2] > -0.9) & (np.abs(centres[:, 0]) < 0.9)]  # three holes
    mesh = TriangleMesh(vertices, kept[:, ::-1]).oriented
    capped_vertices, caps = hole_caps(mesh.vertices, mesh.welded_faces, mesh.welded_edges)
    assert len(capped_vertices) == len(vertices) + 3
    closed = orient_faces(capped_vertices, np.vstack([mesh.faces, caps]))
    assert closed.diagnostics.boundary_loops == 0
    assert not closed.flips.any()  # the caps are wound as the surface around them


def test_rays_through_a_hole_stop_where_the_surface_was():
    """A ball of the dumbbell with a hole: the faces across the ball from the hole keep
    the diameters of the closed mesh."""
    published = _dumbbell()
    graph = published.face_graph
    params = ShdfParams()
    closed = raw_diameters(published, graph, "exact", params)
    centres = face_centroids(published.vertices, published.faces)
    hole = np.linalg.norm(centres - [-2.5, 0.0, 1.0], axis=1) < 0.35  # top of the left ball
    kept = np.flatnonzero(~hole)
    holed = TriangleMesh(published.vertices, published.faces[kept])
    assert holed.orientation.diagnostics.boundary_loops == 1
    across = np.linalg.norm(centres[kept] - [-2.5, 0.0, -1.0], axis=1) < 0.4
    capped = raw_diameters(holed, holed.face_graph, "exact", params, close_holes=True)
    np.testing.assert_allclose(capped[across], closed[kept][across], rtol=0.05)
    # Without the caps, rays leave through the hole: those faces read other diameters.
    open_ = raw_diameters(holed, holed.face_graph, "exact", params)
    assert np.nanmax(np.abs(open_[across] / closed[kept][across] - 1)) > 0.05


def test_a_mostly_open_surface_gets_no_caps():
    vertices, faces = _sphere(2)
    apart = vertices[faces].reshape(-1, 3) + np.repeat(np.arange(len(faces)), 3)[:, None] * 1e-3
    soup = TriangleMesh(apart, np.arange(len(apart)).reshape(-1, 3))
    assert soup.orientation.diagnostics.boundary_loops == len(faces)
    capped_vertices, caps = hole_caps(soup.vertices, soup.welded_faces, soup.welded_edges)
    assert len(caps) == 0 and len(capped_vertices) == len(apart)


@pytest.mark.parametrize("copies", [2, 3, 9, 10, 1000])
def test_every_copy_of_a_repeated_triangle_is_found(copies):
    faces = np.tile([[0, 1, 2]], (copies, 1))
    faces[1::2] = faces[1::2, ::-1]  # copies wound either way
    orientation = orient_faces(np.eye(3), faces)
    assert orientation.diagnostics.duplicate_faces == copies - 1
    np.testing.assert_array_equal(orientation.first_copy, [-1] + [0] * (copies - 1))


def test_a_double_sided_shell_is_read_as_its_single_sided_self():
    """Every face of a sphere doubled with the opposite winding (a double-sided export):
    the copies face as their originals and the ShDF is the single-sided sphere's."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    single = TriangleMesh(sphere.vertices, sphere.faces)
    double = TriangleMesh(sphere.vertices, np.vstack([sphere.faces, sphere.faces[:, ::-1]]))
    orientation = double.orientation
    assert orientation.diagnostics.duplicate_faces == len(sphere.faces)
    np.testing.assert_array_equal(orientation.flips, np.r_[np.zeros(320), np.ones(320)] > 0)
    expected = compute_shdf(single, method="exact").values
    values = compute_shdf(double, method="exact").values
    np.testing.assert_allclose(values[:320], expected, atol=1e-9)
    np.testing.assert_allclose(values[320:], expected, atol=1e-9)


def test_reversed_rows_and_slots_are_those_of_the_triangles_listed_backwards():
    vertices, faces = _sphere()
    flips = np.arange(len(faces)) % 4 == 1
    backwards = reverse_rows(faces, flips)
    np.testing.assert_array_equal(backwards, np.where(flips[:, None], faces[:, ::-1], faces))
    table, slot = welded_edges(faces)
    again_table, again_slot = welded_edges(backwards)
    np.testing.assert_array_equal(again_table, table)
    np.testing.assert_array_equal(reversed_slots(slot, flips), again_slot)


def _moebius_strip(segments: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A non-orientable strip: which faces its patch reverses depends on the join order."""
    angle = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    rows = []
    for side in (-0.3, 0.3):
        radius = 1.0 + side * np.cos(angle / 2)
        rows.append(
            np.stack([radius * np.cos(angle), radius * np.sin(angle), side * np.sin(angle / 2)], 1)
        )
    vertices = np.vstack(rows)
    faces = []
    for k in range(segments):
        a, b = k, (k + 1) % segments
        c, d = k + segments, (k + 1) % segments + segments
        if k == segments - 1:  # the half twist: the far side joins the near one
            b, d = d, b
        faces += [[a, b, c], [b, d, c]]
    return vertices, np.asarray(faces)


def _messy_meshes(seed: int):
    """Random meshes with what the pass must handle: reversed and mixed windings, holes,
    non-manifold edges, duplicates in either winding, collapsed faces, a non-orientable
    strip, a triangle soup, shuffled face order."""
    rng = np.random.default_rng(seed)
    sphere_vertices, sphere_faces = _sphere(2)
    strip_vertices, strip_faces = _moebius_strip()
    bases = [
        (sphere_vertices, sphere_faces),
        (strip_vertices, strip_faces),
        (
            np.vstack([sphere_vertices, sphere_vertices + [1.5, 0, 0], strip_vertices]),
            np.vstack([sphere_faces, sphere_faces + 162, strip_faces + 324]),
        ),
        (rng.normal(size=(30, 3)), rng.integers(0, 30, size=(200, 3))),  # soup, many junctions
    ]
    for vertices, faces in bases:
        faces = faces.copy()
        faces = _reverse(faces, rng.random(len(faces)) < rng.choice([0.0, 0.3, 1.0]))
        faces = faces[rng.random(len(faces)) > 0.05]  # holes
        extra = [
            faces[rng.integers(0, len(faces), 8)],  # duplicates
            faces[rng.integers(0, len(faces), 8)][:, ::-1],  # reversed duplicates
            rng.integers(0, len(vertices), size=(8, 3)),  # fins, non-manifold edges
            np.repeat(rng.integers(0, len(vertices), size=(3, 1)), 3, axis=1),  # collapsed
            np.c_[faces[:3, :2], faces[:3, :1]],  # a repeated vertex
        ]
        faces = np.vstack([faces, *extra])
        yield vertices, faces[rng.permutation(len(faces))]


def test_area_moments_are_the_weighted_centroid_and_central_moments():
    from neural_shdf.geometry import face_centroids, weighted_moments

    rng = np.random.default_rng(0)
    vertices, faces, areas = rng.normal(size=(50, 3)), rng.integers(0, 50, (80, 3)), rng.random(80)
    centre, second, third = weighted_moments(face_centroids(vertices, faces), areas)
    centroids = vertices[faces].mean(axis=1)
    np.testing.assert_allclose(centre, areas @ centroids / areas.sum())
    offset = centroids - centre
    np.testing.assert_allclose(second, (offset * areas[:, None]).T @ offset)
    np.testing.assert_allclose(third, np.einsum("f,fi,fj,fk->ijk", areas, offset, offset, offset))


@pytest.mark.parametrize("seed", range(6))
def test_an_inside_out_messy_file_gets_the_same_triangles_back(seed: int):
    """Holes, fins, duplicates, sheets, soups: every face of the file listed backwards gives
    the same oriented triangles (up to version 17 the patches no volume decides kept the
    file's winding, so an inside-out export of a jet with wing sheets came out in other
    parts)."""
    for vertices, faces in _messy_meshes(seed):
        oriented = [
            _reverse(given, orient_faces(vertices, given).flips)
            for given in (faces, faces[:, ::-1])
        ]
        same = (oriented[0] == oriented[1]).all(axis=1)
        collapsed = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2])
        collapsed |= faces[:, 0] == faces[:, 2]
        assert np.all(same | collapsed)


@pytest.mark.parametrize("seed", range(6))
def test_the_patch_kernel_matches_its_reference_bit_for_bit(seed: int):
    """The packed union-find gives the reference kernel's every output, non-orientable
    strips (where the join order decides) included, with 32- and 64-bit links."""
    from neural_shdf.orientation import _orient_patches
    from tests.orientation_reference import reference_orient_patches

    for vertices, faces in _messy_meshes(seed):
        welded = weld_faces(vertices, faces)
        table, slot = welded_edges(welded)
        _, areas = face_normals(vertices, faces)
        expected = reference_orient_patches(
            welded, table, slot, int(welded.max()) + 1, vertices, vertices.mean(0), areas
        )
        for link_type in (np.int32, np.int64):
            link = np.empty(0, dtype=link_type)
            arguments = (welded, table, slot, vertices, vertices.mean(0), areas, link)
            first_copy, winding, *rest = _orient_patches(*arguments)
            assert winding.dtype == link_type
            # 2 * patch + relative winding, -1 off any patch: the reference's two arrays.
            patch = np.where(winding < 0, -1, winding >> 1)
            relative = np.where(winding < 0, 0, winding & 1).astype(np.int8)
            got = (first_copy, patch, relative, *rest)
            for ours, theirs in zip(got, expected, strict=True):
                np.testing.assert_array_equal(ours, theirs)


@pytest.mark.parametrize("threads", ["one", "two"])
@pytest.mark.parametrize("seed", range(3))
def test_the_oriented_copy_in_one_pass_is_the_rows_slots_and_normals_one_by_one(
    seed: int, threads: str, monkeypatch
):
    """``reverse_flipped`` gives what reversing the rows, permuting the slots and computing
    the reversed triangles' normals afresh give, bit for bit (degenerate rows included),
    written by one thread or by two (each half of the rows)."""
    if threads == "two":
        monkeypatch.setattr(orientation, "PARALLEL_COPY_FACES", 2)
    rng = np.random.default_rng(seed)
    for given_vertices, given_faces in _messy_meshes(seed):
        # Also with coincident vertices (a copy of each of the first ten, used by some
        # faces): then the welded rows are not the rows.
        copies = np.vstack([given_vertices, given_vertices[:10]])
        moved = np.where(
            (given_faces < 10) & (rng.random(given_faces.shape) < 0.5),
            given_faces + len(given_vertices),
            given_faces,
        )
        for vertices, faces in ((given_vertices, given_faces), (copies, moved)):
            welded = weld_faces(vertices, faces)
            normals, _ = face_normals(vertices, faces)
            limit = zero_area_limit(vertices, faces)
            for flips in (orient_faces(vertices, faces).flips, rng.random(len(faces)) < 0.5):
                got = reverse_flipped(vertices, faces, welded, flips, normals, limit)
                backwards = reverse_rows(faces, flips)
                np.testing.assert_array_equal(got[0], backwards)
                np.testing.assert_array_equal(got[1], reverse_rows(welded, flips))
                # Where the welding merged nothing the welded rows share the rows' memory.
                assert np.shares_memory(got[0], got[1]) == np.shares_memory(faces, welded)
                np.testing.assert_array_equal(got[2], face_normals(vertices, backwards)[0])


def test_column_means_are_numpys_bit_for_bit():
    """The compiled mean (the capped volumes' reference point) adds the rows in numpy's order."""
    from neural_shdf.orientation import _column_means

    rng = np.random.default_rng(3)
    for count in (1, 2, 7, 100, 4097, 300_000):
        rows = rng.normal(size=(count, 3)) * rng.uniform(0.1, 1e3) + rng.normal(size=3) * 100
        np.testing.assert_array_equal(_column_means(rows), rows.mean(axis=0))


def test_boundary_edge_rows_are_the_keys_without_a_neighbour_alike():
    rng = np.random.default_rng(8)
    for count in (0, 1, 2, 3, 50, 5000):
        keys = np.sort(rng.integers(0, count // 2 + 1, count))
        table = np.stack([keys, rng.integers(0, 100, count)], axis=1)
        alone = [
            row
            for row in range(count)
            if (row == 0 or keys[row - 1] != keys[row])
            and (row + 1 == count or keys[row + 1] != keys[row])
        ]
        rows = boundary_edge_rows(table)
        np.testing.assert_array_equal(rows, np.array(alone, dtype=np.int64))
        assert rows.dtype == np.int64


def test_a_non_orientable_patch_gets_the_same_windings_in_any_listing():
    """On a Moebius strip (and a closed surface with a twisted seam, like some scans) one
    manifold edge must give way; the one that does follows the surface, not the file's
    vertex and face numbering."""
    vertices, faces = _moebius_strip(48)
    expected = orient_faces(vertices, faces).flips
    rng = np.random.default_rng(11)
    for _ in range(6):
        moved, listed, origin = relisted(vertices, faces, rng, turn=True)
        np.testing.assert_array_equal(orient_faces(moved, listed).flips, expected[origin])


def test_shells_with_no_inside_keep_their_windings_in_any_pose():
    """Flat closed shells (zero volume: a pose's rounding would give it a sign) and tiny
    sheets far from the centre have no inside to face out of: they keep the file's
    winding, so a turned and moved copy gets the same flips."""
    from scipy.spatial.transform import Rotation

    body = trimesh.creation.icosphere(subdivisions=2)
    vertices = [np.asarray(body.vertices) * (2.0, 1.0, 0.6)]
    faces = [np.asarray(body.faces)]
    rng = np.random.default_rng(4)
    count = len(vertices[0])
    for k in range(12):  # flat tetrahedra: four points of one tilted plane
        plane = Rotation.random(random_state=k).as_matrix()
        points = np.array([[0, 0, 0], [1, 0.1, 0], [0.2, 1, 0], [0.9, 0.8, 0]]) * 0.05
        vertices.append(points @ plane.T + rng.uniform(-3.0, 3.0, 3))
        tetrahedron = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
        faces.append(tetrahedron[:, ::-1] if k % 2 else tetrahedron)
        faces[-1] = faces[-1] + count
        count += 4
    vertices, faces = np.vstack(vertices), np.vstack(faces)
    mesh = TriangleMesh(vertices, faces)
    rotation = Rotation.random(random_state=21).as_matrix()
    moved = TriangleMesh(7.0 * vertices @ rotation.T + (50.0, -3.0, 9.0), faces)
    np.testing.assert_array_equal(moved.orientation.flips, mesh.orientation.flips)
    flat = np.arange(len(body.faces), len(faces))
    assert not mesh.orientation.flips[flat].any()  # the file's winding kept
