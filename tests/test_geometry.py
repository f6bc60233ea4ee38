"""Face normals, areas and the face adjacency graph on clean and messy meshes."""

import numpy as np
import trimesh

from neural_shdf.geometry import build_face_graph, face_normals, weld_faces


def test_normals_and_areas_of_a_box():
    box = trimesh.creation.box(extents=(1, 2, 3))
    normals, areas = face_normals(box.vertices, box.faces)
    np.testing.assert_allclose(normals, box.face_normals, atol=1e-12)
    assert np.isclose(areas.sum(), 2 * (1 * 2 + 2 * 3 + 1 * 3))


def test_closed_mesh_has_three_neighbours_per_face_and_no_concave_edge():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    graph = build_face_graph(sphere.vertices, sphere.faces)
    assert len(graph.pairs) == 3 * len(sphere.faces) // 2
    assert np.all(np.bincount(graph.pairs.ravel()) == 3)
    assert not graph.concave.any()
    # Matches trimesh's independent adjacency.
    expected = np.sort(sphere.face_adjacency, axis=1)
    assert {tuple(p) for p in graph.pairs} == {tuple(p) for p in expected}


def test_box_edges_are_right_angles_or_flat():
    box = trimesh.creation.box()
    graph = build_face_graph(box.vertices, box.faces)
    degrees = np.degrees(graph.dihedral)
    assert np.all(np.isclose(degrees, 0) | np.isclose(degrees, 90))


def test_valley_is_concave_and_ridge_is_convex():
    # Two triangles hinged on the x axis, both wings raised: a valley (concave).
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 1], [0.5, -1, 1]], float)
    valley = np.array([[0, 1, 2], [1, 0, 3]])
    graph = build_face_graph(vertices, valley)
    assert graph.concave.tolist() == [True]
    assert np.isclose(graph.dihedral[0], np.pi / 2)
    ridge = vertices * [1, 1, -1]
    assert build_face_graph(ridge, valley).concave.tolist() == [False]


def test_non_manifold_edge_links_every_pair():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], float)
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    graph = build_face_graph(vertices, faces)
    assert graph.pairs.tolist() == [[0, 1], [0, 2], [1, 2]]


def test_triangle_soup_connects_only_after_welding():
    sphere = trimesh.creation.icosphere(subdivisions=1)
    soup_vertices = sphere.vertices[sphere.faces].reshape(-1, 3)
    soup_faces = np.arange(len(soup_vertices)).reshape(-1, 3)
    assert len(build_face_graph(soup_vertices, soup_faces).pairs) == 0
    welded = weld_faces(soup_vertices, soup_faces)
    assert len(build_face_graph(soup_vertices, welded).pairs) == 3 * len(sphere.faces) // 2


def test_degenerate_and_empty_inputs_do_not_crash():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float)
    graph = build_face_graph(vertices, np.array([[0, 1, 2], [0, 0, 1]]))
    assert graph.face_count == 2
    assert build_face_graph(vertices, np.zeros((0, 3), int)).face_count == 0


def test_weld_faces_keeps_positions_of_the_input_vertices():
    """Welded indices must point at ``vertices`` with the same positions (regression)."""
    mesh = trimesh.creation.icosphere(1)
    soup = mesh.vertices[mesh.faces].reshape(-1, 3)  # every corner its own vertex
    faces = np.arange(len(soup)).reshape(-1, 3)
    welded = weld_faces(soup, faces)
    np.testing.assert_array_equal(soup[welded], soup[faces])
    assert len(np.unique(welded)) == len(mesh.vertices)


def test_weld_matches_an_exact_row_sort_and_folds_negative_zero():
    rng = np.random.default_rng(3)
    distinct = rng.normal(size=(200, 3))
    vertices = distinct[rng.integers(0, 200, size=1000)]
    faces = rng.integers(0, 1000, size=(500, 3))
    _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
    expected = first[inverse.reshape(-1)][faces]
    np.testing.assert_array_equal(weld_faces(vertices, faces), expected)
    signed_zero = np.array([[0.0, 1, 2], [-0.0, 1, 2], [0.0, 1, 2.0000001]])
    assert weld_faces(signed_zero, np.array([[0, 1, 2]])).tolist() == [[0, 0, 2]]
