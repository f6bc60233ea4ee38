"""Face normals, areas and the face adjacency graph on clean and messy meshes."""

import math

import numpy as np
import pytest
import trimesh
from threadpoolctl import threadpool_limits

from neural_shdf import geometry
from neural_shdf.constants import AREA_EPS
from neural_shdf.geometry import (
    EDGE_CLIQUE,
    build_face_graph,
    count_zero_rows,
    equivalent_face_count,
    face_adjacency,
    face_normals,
    grid_cells,
    midpoint_subdivide,
    order_free_sum,
    pose_frame,
    principal_coordinates,
    principal_frame,
    split_region,
    weighted_moments,
    weld_faces,
    zero_area_limit,
)
from tests.mesh_helpers import relisted


def test_normals_and_areas_of_a_box():
    box = trimesh.creation.box(extents=(1, 2, 3))
    normals, areas = face_normals(box.vertices, box.faces)
    np.testing.assert_allclose(normals, box.face_normals, atol=1e-12)
    assert np.isclose(areas.sum(), 2 * (1 * 2 + 2 * 3 + 1 * 3))


@pytest.mark.parametrize("scale", [1e-12, 1e-9, 1e9, 1e15])
def test_degenerate_faces_are_the_same_at_every_scale(scale):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    vertices = np.concatenate([sphere.vertices, [[0, 0, 0], [0.25, 0.5, 0.75], [0.5, 1, 1.5]]])
    n = len(sphere.vertices)
    degenerate = np.array([[n, n + 1, n + 2], [0, 0, 1], [n + 1, n + 1, n + 1]])
    faces = np.concatenate([sphere.faces, degenerate])
    normals, areas = face_normals(vertices, faces)
    scaled_normals, scaled_areas = face_normals(vertices * scale, faces)
    np.testing.assert_allclose(scaled_normals, normals, atol=1e-12)
    np.testing.assert_allclose(scaled_areas, areas * scale**2, rtol=1e-12)
    has_normal = np.linalg.norm(scaled_normals, axis=1) > 0
    assert has_normal[: len(sphere.faces)].all() and not has_normal[len(sphere.faces) :].any()
    assert zero_area_limit(vertices * scale, faces) == pytest.approx(
        zero_area_limit(vertices, faces) * scale**2, rel=1e-12
    )
    assert zero_area_limit(np.zeros((3, 3)), np.array([[0, 1, 2]])) == 0.0


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


def test_weld_without_coincident_vertices_is_a_view_the_caller_can_freeze():
    """Nothing to weld: the same indices without a copy, and freezing the result (as
    ``TriangleMesh`` does) leaves the caller's array writeable."""
    mesh = trimesh.creation.icosphere(2)
    faces = np.array(mesh.faces, dtype=np.int64)
    welded = weld_faces(mesh.vertices, faces)
    np.testing.assert_array_equal(welded, faces)
    assert np.shares_memory(welded, faces) and welded is not faces
    welded.flags.writeable = False
    assert faces.flags.writeable
    # one coincident pair (a copy of vertex 0 used by face 0): a new array again
    vertices = np.vstack([mesh.vertices, mesh.vertices[:1]])
    faces[0, 0] = len(mesh.vertices)
    assert not np.shares_memory(weld_faces(vertices, faces), faces)
    assert weld_faces(vertices, faces)[0, 0] == 0


# ---- the compiled kernels against a plain, independent computation ----


def _reference_normals(vertices, faces):
    cross = np.cross(
        vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]]
    )
    norm = np.linalg.norm(cross, axis=1)
    normals = np.zeros_like(cross)
    corners = vertices[faces].reshape(-1, 3)
    ok = norm > AREA_EPS * np.sum((corners.max(axis=0) - corners.min(axis=0)) ** 2)
    normals[ok] = cross[ok] / norm[ok, None]
    return normals, norm / 2


def _reference_graph(vertices, faces, normals):
    """Edge groups in a dict: every pair of a group of up to EDGE_CLIQUE faces, else each
    face with the next; a pair met on several edges keeps (fewest faces, lowest edge)."""
    groups: dict[tuple[int, int], list[int]] = {}
    for face, corners in enumerate(faces.tolist()):
        for start, end in zip(corners, corners[1:] + corners[:1], strict=True):
            if start != end:
                groups.setdefault((min(start, end), max(start, end)), []).append(face)
    best: dict[tuple[int, int], tuple[int, int, int]] = {}
    for (lo, hi), members in groups.items():
        for i, a in enumerate(members):
            reach = len(members) if len(members) <= EDGE_CLIQUE else 1
            for b in members[i + 1 : i + 1 + reach]:
                if a != b:
                    pair = (min(a, b), max(a, b))
                    best[pair] = min(best.get(pair, (len(members), lo, hi)), (len(members), lo, hi))
    pairs = sorted(best)
    edges = [best[p][1:] for p in pairs]
    rows = []

    def height(face: int, lo: int, hi: int, other: int) -> float:
        """``face``'s vertex off the edge above ``other``'s plane through the midpoint."""
        off = [v for v in faces[face].tolist() if v not in (lo, hi)]
        off_vertex = max(off) if off else int(faces[face, 0])
        middle = 0.5 * (vertices[lo] + vertices[hi])
        return float((vertices[off_vertex] - middle) @ normals[other])

    for (a, b), (lo, hi) in zip(pairs, edges, strict=True):
        rows.append(
            (
                math.acos(min(1.0, max(-1.0, float(normals[a] @ normals[b])))),
                float(np.linalg.norm(vertices[lo] - vertices[hi])),
                height(b, lo, hi, a) + height(a, lo, hi, b),  # concave: both above
            )
        )
    table = np.array(rows, dtype=float).reshape(-1, 3)
    return (
        np.array(pairs, dtype=np.int64).reshape(-1, 2),
        np.array(edges, dtype=np.int64).reshape(-1, 2),
        table,
    )


def _messy_mesh(seed: int):
    """Random faces over few vertices: non-manifold edges, repeated and collinear corners."""
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(12, 3))
    points[3] = points[4]  # two vertices at one position
    points[5] = 0.5 * (points[6] + points[7])  # collinear triangles (zero area)
    vertices = np.concatenate(
        [points, points[rng.integers(0, 12, 6)], [[-0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]]]
    )
    faces = rng.integers(0, len(vertices), size=(int(rng.integers(1, 300)), 3))
    repeat = rng.random(len(faces)) < 0.1
    faces[repeat, 2] = faces[repeat, 0]
    faces[0] = [5, 6, 7]
    return vertices, faces


@pytest.mark.parametrize("seed", range(12))
def test_kernels_match_a_plain_computation_on_messy_meshes(seed):
    vertices, faces = _messy_mesh(seed)
    normals, areas = face_normals(vertices, faces)
    expected_normals, expected_areas = _reference_normals(vertices, faces)
    np.testing.assert_allclose(normals, expected_normals, atol=1e-12)
    np.testing.assert_allclose(areas, expected_areas, atol=1e-12)
    for graph_faces in (faces, weld_faces(vertices, faces)):
        graph = build_face_graph(vertices, graph_faces, normals)
        pairs, edges, table = _reference_graph(vertices, graph_faces, normals)
        np.testing.assert_array_equal(graph.pairs, pairs)
        np.testing.assert_array_equal(graph.edge_vertices, edges)
        np.testing.assert_allclose(graph.dihedral, table[:, 0], atol=1e-7)
        np.testing.assert_allclose(graph.edge_length, table[:, 1], atol=1e-12)
        clear = np.abs(table[:, 2]) > 1e-9
        np.testing.assert_array_equal(graph.concave[clear], table[clear, 2] > 0)
        assert graph.face_count == len(faces)


@pytest.mark.parametrize("seed", range(12))
def test_the_face_links_are_the_same_for_every_winding(seed):
    """``face_adjacency`` can run before the orientation is known: rows listed backwards
    (any subset, degenerate rows and edges of many faces included) give the same arrays."""
    vertices, faces = _messy_mesh(seed)
    rng = np.random.default_rng(100 + seed)
    # an edge of more than EDGE_CLIQUE faces, so the chained links are covered too
    faces = np.concatenate(
        [
            faces,
            np.column_stack(
                [
                    np.zeros(EDGE_CLIQUE + 3, int),
                    np.ones(EDGE_CLIQUE + 3, int),
                    rng.integers(2, len(vertices), EDGE_CLIQUE + 3),
                ]
            ),
        ]
    )
    pairs, edge_vertices = face_adjacency(faces)
    flipped = rng.random(len(faces)) < 0.5
    rewound = np.where(flipped[:, None], faces[:, ::-1], faces)
    rolled = np.roll(rewound, int(rng.integers(1, 3)), axis=1)  # other first corners too
    for other in (rewound, rolled):
        other_pairs, other_edge_vertices = face_adjacency(other)
        np.testing.assert_array_equal(other_pairs, pairs)
        np.testing.assert_array_equal(other_edge_vertices, edge_vertices)
        normals, _ = face_normals(vertices, other)
        given = build_face_graph(vertices, other, normals, adjacency=(pairs, edge_vertices))
        afresh = build_face_graph(vertices, other, normals)
        for name in ("pairs", "edge_vertices", "edge_length", "dihedral", "concave"):
            np.testing.assert_array_equal(getattr(given, name), getattr(afresh, name))


def test_face_links_refuse_negative_indices():
    with pytest.raises(IndexError):
        face_adjacency(np.array([[0, 1, -1]]))


def test_kernels_handle_a_high_valence_hub_and_an_edge_of_many_faces():
    rng = np.random.default_rng(7)
    ring = 80  # a fan: one vertex with 80 edges (the long-bucket sort path)
    angles = np.linspace(0, 2 * np.pi, ring, endpoint=False)
    rim = np.stack([np.cos(angles), np.sin(angles), rng.normal(0, 0.1, ring)], axis=1)
    fins = rng.normal(size=(40, 3))  # 40 triangles on one edge (1, 2)
    vertices = np.concatenate([[[0.0, 0, 0]], rim, fins])
    fan = np.stack([np.zeros(ring, int), 1 + np.arange(ring), 1 + (np.arange(ring) + 1) % ring], 1)
    fin_faces = np.stack([np.full(40, 2), np.full(40, 1), 1 + ring + np.arange(40)], axis=1)
    faces = rng.permutation(np.concatenate([fan, fin_faces]))
    normals, _ = face_normals(vertices, faces)
    graph = build_face_graph(vertices, faces, normals)
    pairs, edges, table = _reference_graph(vertices, faces, normals)
    np.testing.assert_array_equal(graph.pairs, pairs)
    np.testing.assert_array_equal(graph.edge_vertices, edges)
    np.testing.assert_allclose(graph.dihedral, table[:, 0], atol=1e-7)


def test_two_faces_sharing_two_edges_link_once_through_the_less_shared_edge():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    # Faces 0 and 1 share edges (0, 1) and (1, 2); face 2 also uses (0, 1).
    faces = np.array([[0, 1, 2], [2, 1, 0], [1, 0, 3]])
    graph = build_face_graph(vertices, faces)
    assert graph.pairs.tolist() == [[0, 1], [0, 2], [1, 2]]
    assert graph.edge_vertices.tolist() == [[0, 2], [0, 1], [0, 1]]


@pytest.mark.parametrize("seed", range(4))
def test_weld_matches_a_dictionary_of_positions(seed):
    vertices, faces = _messy_mesh(seed)
    first: dict[tuple[float, ...], int] = {}
    for index, row in enumerate((vertices + 0.0).tolist()):
        first.setdefault(tuple(row), index)
    expected = np.array([first[tuple(row)] for row in (vertices + 0.0).tolist()])
    np.testing.assert_array_equal(weld_faces(vertices, faces), expected[faces])


def test_out_of_range_vertex_indices_raise():
    vertices = np.zeros((3, 3))
    with pytest.raises(IndexError):
        build_face_graph(vertices, np.array([[0, 1, 3]]))
    with pytest.raises(IndexError):
        weld_faces(vertices, np.array([[0, -1, 2]]))


def _tetrahedra_in_place(copies: int) -> tuple[np.ndarray, np.ndarray]:
    """One tetrahedron repeated ``copies`` times on the same 4 vertices: every edge is
    shared by ``2 * copies`` faces (the worst case of a non-manifold edge)."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    return vertices, np.tile(np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]), (copies, 1))


def test_an_edge_of_up_to_four_faces_links_every_pair():
    # Four fins on one edge (an X junction): every pair is linked, as in a complete graph.
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    faces = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [1, 0, 5]])
    assert EDGE_CLIQUE >= 4
    graph = build_face_graph(vertices.astype(float), faces)
    assert graph.pairs.tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]


def test_an_edge_shared_by_thousands_of_faces_keeps_the_graph_linear_and_connected():
    import scipy.sparse.csgraph as csgraph

    vertices, faces = _tetrahedra_in_place(5000)  # 20k faces; all pairs would be 200M
    graph = build_face_graph(vertices, faces)
    assert len(graph.pairs) <= 3 * len(faces)
    assert csgraph.connected_components(graph.csr(), directed=False)[0] == 1
    # The chain, exactly: each face links the next face along each of its edges.
    small_vertices, small_faces = _tetrahedra_in_place(40)
    normals, _ = face_normals(small_vertices, small_faces)
    small = build_face_graph(small_vertices, small_faces, normals)
    pairs, edges, _ = _reference_graph(small_vertices, small_faces, normals)
    np.testing.assert_array_equal(small.pairs, pairs)
    np.testing.assert_array_equal(small.edge_vertices, edges)


def test_principal_coordinates_are_the_same_in_any_pose_up_to_axis_signs():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    points = rng.normal(size=(500, 3)) * (3.0, 1.5, 0.5)
    weights = rng.uniform(0.5, 2.0, 500)
    local = principal_coordinates(points, weights)
    spread = (weights[:, None] * local**2).sum(axis=0)
    assert spread[0] > spread[1] > spread[2]
    np.testing.assert_allclose(weights @ local, 0.0, atol=1e-12)
    rotation = Rotation.random(random_state=2).as_matrix()
    moved = principal_coordinates(40.0 * points @ rotation.T + (1e3, -7.0, 3.0), weights)
    signs = np.sign(np.sum(moved * local, axis=0))
    np.testing.assert_allclose(moved * signs, 40.0 * local, atol=1e-8)
    # No weight: every point counts alike.
    unweighted = principal_coordinates(points, np.zeros(500))
    np.testing.assert_allclose(unweighted.mean(axis=0), 0.0, atol=1e-12)


def test_principal_coordinates_from_a_kept_frame_are_the_same_bits():
    rng = np.random.default_rng(5)
    points = rng.normal(size=(20_000, 3)) * (30.0, 2.0, 0.5) + (1e3, -7.0, 3.0)
    weights = rng.uniform(0.0, 2.0, len(points))
    frame = principal_frame(points, weights)
    fresh = principal_coordinates(points, weights)
    with threadpool_limits(limits=1, user_api="blas"):
        np.testing.assert_array_equal(fresh, (points - frame[0]) @ frame[1])
    np.testing.assert_array_equal(principal_coordinates(points, weights, frame), fresh)
    np.testing.assert_array_equal(principal_coordinates(points, None, frame), fresh)


def test_moments_and_frames_are_the_same_bits_in_any_order_of_the_points():
    """Sums in integers: a shuffled file's frame (and every coordinate rounded in it) is
    the original's, bit for bit; the sums agree with floating point's to rounding."""
    rng = np.random.default_rng(3)
    # skewed along every axis, so that the pose frame has sides
    points = rng.gamma(2.0, size=(50_000, 3)) * (30.0, 2.0, 0.5) + (1e3, -7.0, 3.0)
    weights = rng.uniform(0.0, 2.0, len(points))
    order = rng.permutation(len(points))
    for first, second in zip(
        weighted_moments(points, weights),
        weighted_moments(points[order], weights[order]),
        strict=True,
    ):
        np.testing.assert_array_equal(first, second)
    centre, second_moments, _ = weighted_moments(points, weights)
    offsets = points - centre
    np.testing.assert_allclose(centre, weights @ points / weights.sum(), rtol=1e-13)
    np.testing.assert_allclose(second_moments, (offsets * weights[:, None]).T @ offsets, rtol=1e-11)
    frame = pose_frame(points, weights)
    shuffled = pose_frame(points[order], weights[order])
    for first, second in zip(frame, shuffled, strict=True):
        np.testing.assert_array_equal(first, second)
    assert not np.array_equal(frame[1], np.eye(3))  # a frame of its own, not the world's
    values = rng.normal(size=10_000) * np.exp(rng.normal(size=10_000) * 5)
    assert order_free_sum(values) == order_free_sum(values[::-1])
    assert order_free_sum(values) == pytest.approx(math.fsum(values), rel=1e-12, abs=1e-12)


def test_principal_frame_does_not_depend_on_the_callers_blas_threads():
    # Grid cells are laid over this frame: its bits must not follow the core count.
    rng = np.random.default_rng(7)
    points = rng.normal(size=(400_000, 3)) * (30.0, 2.0, 0.5) + (1e3, -7.0, 3.0)
    weights = rng.uniform(0.0, 2.0, len(points))
    frames = []
    for threads in (1, 2, 4):
        with threadpool_limits(limits=threads, user_api="blas"):
            frames.append(principal_frame(points, weights))
    for mean, axes in frames[1:]:
        np.testing.assert_array_equal(mean, frames[0][0])
        np.testing.assert_array_equal(axes, frames[0][1])


def test_grid_cells_are_the_numpy_formula_bit_for_bit():
    def numpy_cells(coordinates, size):
        cells = np.floor(coordinates / size + 0.5).astype(np.int64)
        cells -= cells.min(axis=0)
        span = cells.max(axis=0) + 1
        return (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]

    rng = np.random.default_rng(6)
    for trial in range(20):
        coordinates = rng.normal(size=(int(rng.integers(1, 5000)), 3)) * 10.0 ** (trial % 5 - 2)
        size = float(10.0 ** rng.uniform(-3, 1))
        if trial % 3 == 0:  # points on the cell walls
            coordinates, size = np.round(coordinates * 4) / 8, 0.25
        np.testing.assert_array_equal(grid_cells(coordinates, size), numpy_cells(coordinates, size))
    assert grid_cells(np.zeros((0, 3)), 1.0).shape == (0,)


def test_grid_cells_partition_the_points_alike_whatever_the_axis_signs():
    rng = np.random.default_rng(5)
    coordinates = rng.uniform(-3.0, 3.0, (2000, 3))

    def groups(keys: np.ndarray) -> np.ndarray:
        """Each point's group, numbered by first appearance."""
        _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        return np.argsort(np.argsort(first))[inverse]

    keys = grid_cells(coordinates, 0.7)
    cells = np.floor(coordinates / 0.7 + 0.5)
    assert len(np.unique(keys)) == len(np.unique(cells, axis=0))
    for signs in ((-1, 1, 1), (1, -1, -1), (-1, -1, -1)):
        np.testing.assert_array_equal(groups(grid_cells(coordinates * signs, 0.7)), groups(keys))
    # Walls half a cell from the origin: the origin's cell is centred on it.
    assert len(set(grid_cells(np.array([[0.3, -0.3, 0.0], [0, 0, 0], [0.6, 0, 0]]), 1.0))) == 2


def test_normals_with_the_limit_given_are_those_found_with_it():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    faces = np.vstack([faces, [[0, 0, 1]]])  # and a degenerate triangle
    normals, areas = face_normals(vertices, faces)
    given = face_normals(vertices, faces, area_limit=zero_area_limit(vertices, faces))
    np.testing.assert_array_equal(given[0], normals)
    np.testing.assert_array_equal(given[1], areas)
    assert count_zero_rows(normals) == 1
    # A limit above every triangle's doubled area leaves no normal.
    assert count_zero_rows(face_normals(vertices, faces, area_limit=1.0)[0]) == len(faces)


def test_midpoint_subdivision_maps_each_child_to_the_face_it_lies_in():
    """Two passes: 16 children per face, each a sixteenth of its face's area, lying in it."""
    mesh = trimesh.creation.box(extents=(1, 2, 3))
    vertices, faces, origin = midpoint_subdivide(mesh.vertices, mesh.faces, 2)
    assert len(faces) == 16 * len(mesh.faces)
    np.testing.assert_array_equal(np.bincount(origin), np.full(len(mesh.faces), 16))
    _, areas = face_normals(vertices, faces)
    _, parent_areas = face_normals(mesh.vertices, mesh.faces)
    np.testing.assert_allclose(areas, parent_areas[origin] / 16)
    centroid = vertices[faces].mean(axis=1)
    a, b, c = (mesh.vertices[mesh.faces[origin]][:, i] for i in range(3))
    normal = np.cross(b - a, c - a)  # inside the parent: same side of its three edges
    for p, q in ((a, b), (b, c), (c, a)):
        assert np.all(np.einsum("ij,ij->i", np.cross(q - p, centroid - p), normal) > 0)
    unchanged = midpoint_subdivide(mesh.vertices, mesh.faces, 0)
    np.testing.assert_array_equal(unchanged[2], np.arange(12))


def test_equivalent_face_count_reads_the_area_not_the_face_count():
    sphere = trimesh.creation.icosphere(3)
    areas = face_normals(sphere.vertices, sphere.faces)[1]
    assert equivalent_face_count(areas) == pytest.approx(len(areas), rel=0.1)
    # A tenth of the surface split 1-to-16: 2.5x the faces, about the same surface.
    split = np.concatenate([np.ones(900), np.full(1600, 1 / 16)])
    assert equivalent_face_count(split) == pytest.approx(1000)
    # Most of the area in small faces: counted at their size.
    assert equivalent_face_count(np.concatenate([np.ones(100), np.full(1600, 1 / 16)])) == 3200
    assert equivalent_face_count(np.zeros(7)) == 7
    assert equivalent_face_count(np.zeros(0)) == 0


@pytest.mark.parametrize("splits", [1, 2, 4])
def test_split_region_keeps_the_surface_closed_and_each_face_in_its_place(splits):
    sphere = trimesh.creation.icosphere(2)
    vertices, faces = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    region = sphere.triangles_center[:, 2] > 0.6
    new_vertices, new_faces, origin = split_region(vertices, faces[:, ::-1], region, splits)
    split = trimesh.Trimesh(new_vertices, new_faces)  # merges the shared edge points
    assert split.is_watertight  # no T-junction: every edge has two faces
    assert split.volume == pytest.approx(-sphere.volume)  # the input's (reversed) winding
    assert np.all(np.diff(origin) >= 0)  # pieces in their face's place
    pieces = np.bincount(origin, minlength=len(faces))
    assert np.all(pieces[region] == splits**2)
    assert set(np.unique(pieces[~region]).tolist()) <= {1, splits, splits**2}
    areas = face_normals(new_vertices, new_faces)[1]
    np.testing.assert_allclose(
        np.bincount(origin, weights=areas), face_normals(vertices, faces)[1], rtol=1e-9
    )


def test_split_region_checks_its_arguments():
    sphere = trimesh.creation.icosphere(1)
    with pytest.raises(ValueError, match="splits"):
        split_region(sphere.vertices, sphere.faces, np.ones(len(sphere.faces), bool), 0)
    with pytest.raises(ValueError, match="region has 3 entries"):
        split_region(sphere.vertices, sphere.faces, np.ones(3, bool), 2)


def test_equivalent_face_count_is_the_area_weighted_median_of_a_whole_sort():
    """The binned search gives what sorting every area gives, ties and zeros included."""
    rng = np.random.default_rng(11)
    for case in range(200):
        areas = rng.lognormal(sigma=rng.uniform(0.0, 3.0), size=int(rng.integers(1, 3000)))
        if case % 3 == 0:
            areas[rng.random(len(areas)) < 0.2] = 0.0
        if case % 5 == 0:
            areas = np.round(areas, 1)
        ordered = np.sort(areas)
        held = np.cumsum(ordered)
        if not held[-1] > 0:
            continue
        median = ordered[min(int(np.searchsorted(held, 0.5 * held[-1])), len(areas) - 1)]
        assert equivalent_face_count(areas) == areas.sum() / median


def _posed(points, frame):
    origin, rotation, scale = frame
    return (points - origin) @ rotation / scale


@pytest.mark.parametrize("mirrored_axis", [None, 0, 1, 2])
def test_the_pose_frame_is_the_same_in_any_pose_and_scale(mirrored_axis):
    """Axes from the spreads, their sides from the third moments (one axis without a side,
    a mirror-symmetric shape, completes the other two), always a rotation."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(6)
    points = rng.gamma(2.0, size=(400, 3)) * (3.0, 1.5, 0.5)
    if mirrored_axis is not None:
        points[:, mirrored_axis] -= points[:, mirrored_axis].mean()
        points = np.vstack([points, points * np.where(np.arange(3) == mirrored_axis, -1, 1)])
    weights = rng.uniform(0.5, 2.0, len(points)) if mirrored_axis is None else None
    weights = np.ones(len(points)) if weights is None else weights
    frame = pose_frame(points, weights)
    assert np.linalg.det(frame[1]) == pytest.approx(1.0)
    assert not np.allclose(frame[1], np.eye(3))
    local = _posed(points, frame)
    assert np.sum(weights @ local**2) / weights.sum() == pytest.approx(1.0)
    for seed in range(4):
        rotation = Rotation.random(random_state=seed).as_matrix()
        moved = 1e3 * points @ rotation.T + (1e4, -7.0, 3.0)
        np.testing.assert_allclose(_posed(moved, pose_frame(moved, weights)), local, atol=1e-9)


def test_the_pose_frame_keeps_the_worlds_axes_where_the_shape_sets_none():
    """Equal spreads (about a body of revolution's axis): the axes would be rounding's."""
    angle = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    ring = np.stack([np.cos(angle), np.sin(angle), np.zeros(60)], axis=1)
    points = np.vstack([ring * radius + (0, 0, height) for radius, height in ((1, 0), (2, 3))])
    origin, rotation, scale = pose_frame(points, np.ones(len(points)))
    np.testing.assert_array_equal(rotation, np.eye(3))
    np.testing.assert_allclose(origin, points.mean(axis=0), atol=1e-12)
    assert scale == pytest.approx(np.sqrt(np.mean(np.sum((points - origin) ** 2, axis=1))))


def test_a_fold_reads_the_same_whichever_face_or_vertex_comes_first():
    """Concavity from both faces' heights over the edge's midpoint: renumbering the faces
    or the vertices of a nearly flat fold (where one face's height alone is rounding)
    does not turn it."""
    rng = np.random.default_rng(12)
    for _ in range(200):
        a, b = rng.normal(size=(2, 3))
        wing = rng.normal(size=3)
        lift = rng.normal(scale=1e-17, size=2)  # flat but for rounding
        normal = np.cross(b - a, wing)
        normal /= np.linalg.norm(normal)
        other = a + b - wing + lift[0] * normal  # the second wing, in the plane
        vertices = np.array([a, b, wing + lift[1] * normal, other])
        faces = np.array([[0, 1, 2], [1, 0, 3]])
        normals, _ = face_normals(vertices, faces)
        reads = set()
        for face_order in ([0, 1], [1, 0]):
            for vertex_order in ([0, 1, 2, 3], [1, 0, 3, 2]):
                new = np.argsort(vertex_order)
                graph = build_face_graph(
                    vertices[vertex_order], new[faces[face_order]], normals[face_order]
                )
                reads.add(bool(graph.concave[0]))
        assert len(reads) == 1


def test_the_faces_of_a_crowded_edge_chain_by_angle_in_any_numbering():
    """Seven fins on one edge (more than EDGE_CLIQUE): each linked to its neighbours around
    the edge, the widest gap left open, whatever numbers the faces and vertices have."""
    angles = np.radians([0, 40, 85, 130, 180, 225, 270])  # widest gap: 270 -> 360
    tips = np.stack([np.zeros(7) + 0.5, np.cos(angles), np.sin(angles)], axis=1)
    vertices = np.vstack([[[0.0, 0, 0], [1.0, 0, 0]], tips])
    faces = np.array([[0, 1, 2 + k] for k in range(7)])
    rng = np.random.default_rng(5)
    expected = {(k, k + 1) for k in range(6)}
    for _ in range(5):
        moved, listed, origin = relisted(vertices, faces, rng)
        pairs, _ = face_adjacency(listed, vertices=moved)
        assert {tuple(sorted(origin[pair])) for pair in pairs.tolist()} == expected
    # Without positions: a chain in face order, as before.
    pairs, _ = face_adjacency(faces[[3, 0, 5, 1, 6, 2, 4]])
    assert len(pairs) == 6
    # Faces collapsed onto the edge have no angle: they join the chain after the fins,
    # and the fins' links stay the same in any numbering.
    crowded = np.vstack([faces, [[0, 1, 1], [0, 0, 1], [1, 0, 9]]])
    crowded_vertices = np.vstack([vertices, [[1.0, 0.0, 0.0]]])  # 9: a copy of vertex 1
    for _ in range(5):
        moved, listed, origin = relisted(crowded_vertices, crowded, rng)
        pairs, _ = face_adjacency(listed, vertices=moved)
        links = {tuple(sorted(origin[pair])) for pair in pairs.tolist()}
        assert {link for link in links if max(link) < 7} == expected


def test_fins_at_one_angle_chain_nearer_first_in_any_numbering():
    """Two fins in one half-plane (a fin on a wall): the nearer one first around the edge,
    whichever end of the edge has the lower number."""
    angles = np.radians([0, 40, 85, 130, 180, 225, 270, 85])
    reach = np.array([1, 1, 1, 1, 1, 1, 1, 2.0])
    tips = np.stack([np.full(8, 0.5), reach * np.cos(angles), reach * np.sin(angles)], axis=1)
    vertices = np.vstack([[[0.0, 0, 0], [1.0, 0, 0]], tips])
    faces = np.array([[0, 1, 2 + k] for k in range(8)])
    expected = {(0, 1), (1, 2), (2, 7), (3, 7), (3, 4), (4, 5), (5, 6)}
    rng = np.random.default_rng(8)
    for _ in range(8):
        moved, listed, origin = relisted(vertices, faces, rng)
        pairs, _ = face_adjacency(listed, vertices=moved)
        assert {tuple(sorted(origin[pair])) for pair in pairs.tolist()} == expected


def test_canonical_triangles_depend_on_the_positions_alone():
    mesh = trimesh.creation.icosphere(subdivisions=2)
    first, first_of = geometry.canonical_triangles(mesh.vertices, mesh.faces, head=200)
    vertices, faces, origin = relisted(
        mesh.vertices, mesh.faces, np.random.default_rng(5), turn=True
    )
    head = np.flatnonzero(origin < 200)  # the same 200 triangles first
    order = np.concatenate([head, np.setdiff1d(np.arange(len(faces)), head)])
    second, second_of = geometry.canonical_triangles(vertices, faces[order], head=200)
    np.testing.assert_array_equal(vertices[second], mesh.vertices[first])
    np.testing.assert_array_equal(origin[order][second_of], first_of)
    assert set(first_of[:200]) == set(range(200))
    # Each triangle is its input triangle, turned to start at its lowest corner.
    for triangle, source in zip(first[:5], first_of[:5], strict=True):
        turns = [np.roll(mesh.faces[source], -k) for k in range(3)]
        assert any((triangle == turn).all() for turn in turns)


@pytest.mark.parametrize("levels", [3, 40, 100_000])
def test_position_ranks_order_by_x_then_y_then_z(levels: int, monkeypatch):
    """Ties in x (CAD grids, float32 scans) are ordered by y and z, by insertion in short
    runs and by a full sort past ``TIED_RUN``; equal positions share a rank."""
    rng = np.random.default_rng(levels)
    points = rng.integers(0, levels, size=(6000, 3)).astype(float)
    by_position = np.lexsort((points[:, 2], points[:, 1], points[:, 0]))
    ordered = points[by_position]
    expected = np.empty(len(points), dtype=np.int64)
    expected[by_position] = np.cumsum(np.r_[True, np.any(ordered[1:] != ordered[:-1], axis=1)])
    for longest in (geometry.TIED_RUN, 8):  # runs of 2000, 150 and 1 for the three levels
        monkeypatch.setattr(geometry, "TIED_RUN", longest)
        np.testing.assert_array_equal(geometry.position_ranks(points), expected - 1)
