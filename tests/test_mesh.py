"""TriangleMesh: mapping triangle results back to the input file's faces, content hash."""

import numpy as np
import trimesh

from neural_shdf.mesh import TriangleMesh
from tests.mesh_helpers import relisted


def _quad_and_triangle() -> TriangleMesh:
    # Input face 0 is a quad split into two triangles, input face 1 a triangle.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    return TriangleMesh(vertices, faces, face_origin=np.array([0, 0, 1]), input_face_count=2)


def test_values_map_to_input_faces_by_weighted_mean():
    mesh = _quad_and_triangle()
    out = mesh.to_input_faces(np.array([1.0, 3.0, 5.0]), weights=np.array([1.0, 3.0, 1.0]))
    np.testing.assert_allclose(out, [2.5, 5.0])


def test_labels_take_heaviest_share_of_a_polygon():
    mesh = _quad_and_triangle()
    labels = mesh.labels_to_input_faces(np.array([4, 7, 1]), weights=np.array([1, 2, 1]))
    assert labels.tolist() == [7, 1]
    # Ties go to the smaller label, so the result never depends on triangle order.
    assert mesh.labels_to_input_faces(np.array([4, 2, 1])).tolist() == [2, 1]


def test_input_faces_without_triangles_are_marked_missing():
    mesh = TriangleMesh(np.eye(3), [[0, 1, 2]], face_origin=[2], input_face_count=3)
    assert mesh.labels_to_input_faces(np.array([5])).tolist() == [-1, -1, 5]
    assert np.isnan(mesh.to_input_faces(np.array([1.0]))[:2]).all()


def test_identity_mapping_by_default():
    mesh = TriangleMesh(np.eye(3), [[0, 1, 2], [0, 2, 1]])
    assert mesh.input_face_count == 2
    assert mesh.labels_to_input_faces(np.array([3, 9])).tolist() == [3, 9]


def test_content_hash_depends_on_geometry_and_order_only():
    a = _quad_and_triangle()
    b = _quad_and_triangle()
    assert a.content_hash() == b.content_hash()
    moved = TriangleMesh(a.vertices + 1e-9, a.faces, a.face_origin, a.input_face_count)
    assert moved.content_hash() != a.content_hash()
    reordered = TriangleMesh(a.vertices, a.faces[::-1], a.face_origin, a.input_face_count)
    assert reordered.content_hash() != a.content_hash()


def test_normals_and_areas_are_computed_once_and_read_only():
    box = trimesh.creation.box(extents=(1, 2, 3))
    mesh = TriangleMesh(box.vertices, box.faces)
    normals, areas = mesh.normals_and_areas
    assert mesh.normals_and_areas[0] is normals  # cached, not recomputed
    np.testing.assert_allclose(normals, box.face_normals, atol=1e-12)
    np.testing.assert_allclose(areas, box.area_faces, atol=1e-12)
    assert not normals.flags.writeable and not areas.flags.writeable


def test_mapping_weighs_triangles_by_area_by_default():
    # Input face 0: a quad fanned into a big and a small triangle; face 1 a lone triangle.
    vertices = np.array([[0, 0, 0], [4, 0, 0], [4, 1, 0], [3, 1, 0], [5, 0, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])  # areas 2.0 and 0.5
    mesh = TriangleMesh(vertices, faces, face_origin=np.array([0, 0, 1]), input_face_count=2)
    assert mesh.labels_to_input_faces(np.array([7, 2, 1])).tolist() == [7, 1]
    np.testing.assert_allclose(mesh.to_input_faces(np.array([1.0, 6.0, 3.0])), [2.0, 3.0])


def test_polygon_of_degenerate_triangles_counts_them_equally():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], float)  # collinear
    mesh = TriangleMesh(vertices, [[0, 1, 2], [0, 2, 3]], face_origin=[0, 0], input_face_count=1)
    np.testing.assert_allclose(mesh.to_input_faces(np.array([1.0, 3.0])), [2.0])
    assert mesh.labels_to_input_faces(np.array([5, 4])).tolist() == [4]


def test_the_kept_principal_frame_gives_the_crease_graph_and_cut_of_a_fresh_one():
    from neural_shdf.geometry import principal_frame
    from neural_shdf.pipeline import SegmentParams
    from neural_shdf.segment.creases import crease_graph
    from neural_shdf.segment.from_shdf import prepare_segment
    from neural_shdf.segment.graphcut import cut_hierarchy

    sphere = trimesh.creation.icosphere(subdivisions=5)
    vertices = np.asarray(sphere.vertices) * (3.0, 1.0, 0.5)
    mesh = TriangleMesh(vertices, np.asarray(sphere.faces))
    areas = mesh.normals_and_areas[1]
    frame = mesh.principal_frame
    fresh = principal_frame(mesh.centroids, areas)
    np.testing.assert_array_equal(frame[0], fresh[0])
    np.testing.assert_array_equal(frame[1], fresh[1])
    kept = mesh.crease_graph
    alone = crease_graph(mesh.face_graph, areas, mesh.centroids, coarse_above=1_000)
    shared = crease_graph(mesh.face_graph, areas, mesh.centroids, coarse_above=1_000, frame=frame)
    np.testing.assert_array_equal(alone.node_of, shared.node_of)
    np.testing.assert_array_equal(alone.capacity, shared.capacity)
    assert kept.node_of is None  # below COARSE_ABOVE_FACES: the face graph itself
    shdf = (mesh.centroids[:, 0] - vertices[:, 0].min()) / np.ptp(vertices[:, 0])
    basis = prepare_segment(mesh, shdf, SegmentParams(clusters=3))
    assert basis.frame is frame
    graph = mesh.face_graph
    cut = basis.cut(graph)
    fresh_cut = cut_hierarchy(basis.data, graph.pairs, basis.unit_weights, mesh.centroids, areas)
    assert len(cut.levels) == len(fresh_cut.levels) > 1
    for level, other in zip(cut.levels, fresh_cut.levels, strict=True):
        np.testing.assert_array_equal(level.pairs, other.pairs)
        np.testing.assert_array_equal(level.unit_weights, other.unit_weights)
        np.testing.assert_array_equal(level.data, other.data)


def test_a_mesh_keeps_the_spokes_over_its_holes_for_every_segmentation():
    from neural_shdf.pipeline import SegmentParams, prepare_segment, segment
    from neural_shdf.segment.hierarchy import merge_tree
    from neural_shdf.stitching import cap_spokes, closing_caps

    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices = np.asarray(sphere.vertices) * (2.0, 1.0, 1.0)
    faces = np.asarray(sphere.faces)
    mesh = TriangleMesh(vertices, faces[vertices[faces, 2].mean(axis=1) < 0.8])  # a hole
    work = mesh.distinct.mesh
    coincident, _ = work.coincident_welding
    capped, caps = closing_caps(work.vertices, coincident, work.welded_faces, work.welded_edges)
    pairs, lengths = cap_spokes(
        capped, len(work.vertices), work.welded_faces, work.welded_edges, caps
    )
    kept = work.hole_spokes
    assert len(kept[0]) == len(caps) > 0
    np.testing.assert_array_equal(kept[0], pairs)
    np.testing.assert_array_equal(kept[1], lengths)
    shdf = (mesh.centroids[:, 0] - vertices[:, 0].min()) / np.ptp(vertices[:, 0])
    basis = prepare_segment(mesh, shdf, SegmentParams(clusters=3))
    for smoothing in (0.1, 0.3):
        result = segment(mesh, shdf, SegmentParams(clusters=3, smoothing=smoothing), basis=basis)
        # The tree is the one built with the spokes computed afresh, and they are kept.
        tree = merge_tree(
            result.tree.leaf_labels,
            work.face_graph,
            basis.geometry,
            basis.values,
            spokes=(pairs, lengths),
        )
        np.testing.assert_array_equal(result.tree.merges, tree.merges)
        np.testing.assert_array_equal(result.tree.costs, tree.costs)
        assert work.hole_spokes is kept


def test_meshes_oriented_on_many_threads_at_once_get_what_one_thread_gets():
    """The pass works out the face links on a second thread; several requests orienting
    meshes at once (the service's compute pool) neither deadlock nor mix their results."""
    from concurrent.futures import ThreadPoolExecutor

    sphere = trimesh.creation.icosphere(subdivisions=4)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    rng = np.random.default_rng(5)
    windings = [np.where((rng.random(len(faces)) < share)[:, None], faces[:, ::-1], faces)
                for share in (0.0, 0.3, 1.0, 0.5, 0.0, 1.0)]  # fmt: skip

    def graph_of(rows: np.ndarray) -> tuple:
        mesh = TriangleMesh(vertices, rows)
        graph = mesh.face_graph
        return mesh.orientation.flips, graph.pairs, graph.dihedral, graph.concave

    alone = [graph_of(rows) for rows in windings]
    with ThreadPoolExecutor(max_workers=4) as pool:
        together = list(pool.map(graph_of, windings * 3, timeout=120))
    for index, result in enumerate(together):
        for mine, expected in zip(result, alone[index % len(windings)], strict=True):
            np.testing.assert_array_equal(mine, expected)
    # every winding comes out facing outward, with the same graph
    for result in alone[1:]:
        for mine, expected in zip(result[1:], alone[0][1:], strict=True):
            np.testing.assert_array_equal(mine, expected)


def test_the_face_graph_is_the_same_in_any_pose_and_scale():
    """Built in the mesh's own frame: the same links (a crowded edge's faces ordered around
    it there), the same angles and folds to the last bit, lengths in the mesh's units."""
    from scipy.spatial.transform import Rotation

    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices = np.asarray(sphere.vertices) * (1.6, 1.0, 0.7)
    a, b = sphere.faces[0, 0], sphere.faces[0, 1]
    angles = np.radians([10, 50, 95, 140, 200, 250])  # fins on one edge: a crowded edge
    middle = 0.5 * (vertices[a] + vertices[b])
    tips = middle + 0.3 * np.stack([np.cos(angles), np.sin(angles), np.zeros(6)], axis=1)
    fins = [[a, b, len(vertices) + k] for k in range(6)]
    mesh = TriangleMesh(np.vstack([vertices, tips]), np.vstack([sphere.faces, fins]))
    rotation = Rotation.random(random_state=9).as_matrix()
    moved = TriangleMesh(37.0 * mesh.vertices @ rotation.T + (2e3, -5.0, 40.0), mesh.faces)
    here, there = mesh.face_graph, moved.face_graph
    np.testing.assert_array_equal(there.pairs, here.pairs)
    np.testing.assert_array_equal(there.dihedral, here.dihedral)
    np.testing.assert_array_equal(there.concave, here.concave)
    np.testing.assert_allclose(there.edge_length, 37.0 * here.edge_length, rtol=1e-12)


def test_distinct_lists_the_same_surface_the_same_way_whatever_the_file_s_order():
    """``distinct`` numbers vertices by position in the pose frame and sorts the triangles
    by their corners: a file listing the same triangles in another order (vertices, faces
    and each triangle's first corner) gives the same arrays, and the maps lead back."""
    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices = np.asarray(sphere.vertices) * (1.6, 1.0, 0.7)
    vertices[:, 2] += 0.2 * vertices[:, 0] ** 2
    faces = np.vstack([sphere.faces, sphere.faces[:7][:, ::-1]])  # 7 double-sided copies
    mesh = TriangleMesh(vertices, faces)
    other_vertices, other_faces, origin = relisted(
        vertices, faces, np.random.default_rng(8), turn=True
    )
    other = TriangleMesh(other_vertices, other_faces)
    first, second = mesh.distinct, other.distinct
    assert first.reordered and first.has_copies and len(first.kept) == len(sphere.faces)
    np.testing.assert_array_equal(second.mesh.vertices, first.mesh.vertices)
    np.testing.assert_array_equal(second.mesh.faces, first.mesh.faces)
    for distinct, source in ((first, mesh), (second, other)):
        work = distinct.mesh
        # each triangle is its kept triangle, facing out, turned to start at its lowest corner
        kept = source.oriented.vertices[source.oriented.faces[distinct.kept]]
        listed = work.vertices[work.faces]
        turned = np.zeros(len(listed), dtype=bool)
        for k in range(3):
            turned |= (np.roll(kept, -k, axis=1) == listed).all(axis=(1, 2))
        assert turned.all()
        # every triangle (copies too) maps to one listing the same three positions
        np.testing.assert_array_equal(
            np.sort(source.vertices[source.faces], axis=1),
            np.sort(listed[distinct.copy_of], axis=1),
        )
    np.testing.assert_array_equal(second.copy_of, first.copy_of[origin])


def test_a_non_orientable_patch_is_wound_alike_in_any_order_and_pose():
    """A Moebius strip cannot be wound consistently: which edge gives way follows the
    numbering. On ``listing`` (vertices numbered by position in the shape's own frame) the
    same strip listed otherwise, turned and moved gets the same windings."""
    from scipy.spatial.transform import Rotation

    turns, across = 60, 4
    u = np.linspace(0.0, 2.0 * np.pi, turns, endpoint=False)
    v = np.linspace(-0.3, 0.3, across)
    radius = 1.0 + v[None, :] * np.cos(u[:, None] / 2.0)
    points = np.stack(
        [
            radius * np.cos(u[:, None]) * 1.6,  # stretched, and leaning: a frame of its own
            radius * np.sin(u[:, None]),
            v[None, :] * np.sin(u[:, None] / 2.0) + 0.1 * np.cos(u[:, None]) ** 3,
        ],
        axis=-1,
    ).reshape(-1, 3)
    faces = []
    for i in range(turns):
        for j in range(across - 1):
            a, b = i * across + j, i * across + j + 1
            if i + 1 < turns:
                c, d = a + across, b + across
            else:  # the seam joins the strip's start turned over
                c, d = across - 1 - j, across - 2 - j
            faces += [[a, c, b], [b, c, d]]
    faces = np.asarray(faces)
    mesh = TriangleMesh(points, faces)
    assert mesh.listing[1] is not None  # listed by position
    rotation = Rotation.random(random_state=5).as_matrix()
    vertices, listed, origin = relisted(points, faces, np.random.default_rng(6), turn=True)
    moved = TriangleMesh(40.0 * vertices @ rotation.T + (3e2, -7.0, 1.0), listed)
    normals = mesh.oriented.normals_and_areas[0][origin] @ rotation.T
    moved_normals = moved.oriented.normals_and_areas[0]
    np.testing.assert_allclose(moved_normals, normals, atol=1e-9)
    assert 0 < mesh.diagnostics.reoriented_faces < len(faces)
