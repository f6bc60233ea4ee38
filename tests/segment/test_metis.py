"""METIS partitioner: exactly the requested number of parts, on any graph."""

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import ParameterError
from neural_shdf.geometry import build_face_graph, face_centroids, face_normals
from neural_shdf.segment.metis import metis_partition, share_parts


def sphere_graph(subdivisions: int = 3):
    mesh = trimesh.creation.icosphere(subdivisions)
    normals, areas = face_normals(mesh.vertices, mesh.faces)
    graph = build_face_graph(mesh.vertices, mesh.faces, normals)
    return graph, areas, face_centroids(mesh.vertices, mesh.faces)


@pytest.mark.parametrize("parts", [1, 2, 5, 9])
def test_exactly_the_requested_parts_canonical_and_connected(parts):
    graph, areas, centroids = sphere_graph()
    labels = metis_partition(graph, np.ones(len(graph.pairs), np.int64), parts, areas, centroids)
    assert sorted(np.unique(labels)) == list(range(parts))
    _, first = np.unique(labels, return_index=True)
    assert np.all(np.diff(first) > 0)  # part ids in order of lowest face


def test_deterministic_for_a_seed():
    graph, areas, centroids = sphere_graph()
    weights = np.ones(len(graph.pairs), np.int64)
    first = metis_partition(graph, weights, 6, areas, centroids, seed=3)
    np.testing.assert_array_equal(
        first, metis_partition(graph, weights, 6, areas, centroids, seed=3)
    )


def test_parts_are_shared_between_shells_by_area():
    np.testing.assert_array_equal(share_parts(np.array([3.0, 1.0]), np.array([50, 50]), 4), [3, 1])
    np.testing.assert_array_equal(share_parts(np.array([1.0, 1.0]), np.array([2, 80]), 6), [2, 4])
    # A shell above the minimum size gets a part even when its share rounds to 0.
    np.testing.assert_array_equal(
        share_parts(np.array([10.0, 1.0]), np.array([50, 50]), 3, 0.05), [2, 1]
    )
    # A tiny shell gets none (it joins its nearest neighbour) unless parts remain.
    np.testing.assert_array_equal(
        share_parts(np.array([5.0, 1e-6]), np.array([10, 1]), 3, 0.01), [3, 0]
    )
    np.testing.assert_array_equal(share_parts(np.array([1.0, 1.0]), np.array([1, 1]), 2), [1, 1])


def reference_share_parts(sizes, counts, parts, min_fraction=0.0):
    """share_parts written plainly: one part at a time, rescanning every component."""
    share = sizes / sizes.sum() * parts
    given = np.zeros(len(sizes), dtype=np.int64)
    by_size = np.lexsort((np.arange(len(sizes)), -sizes))
    given[by_size[sizes[by_size] >= min_fraction * sizes.sum()][:parts]] = 1
    while given.sum() < parts:
        deficit = np.where(given < counts, share - given, -np.inf)
        given[np.lexsort((np.arange(len(sizes)), -sizes, -deficit))[0]] += 1
    return given


@pytest.mark.parametrize("min_fraction", [0.0, 0.01])
def test_sharing_parts_follows_the_plain_rule(min_fraction):
    rng = np.random.default_rng(3)
    sizes = rng.choice([1.0, 2.0, 3.5, 0.001], 400)  # many ties
    counts = rng.integers(1, 6, 400)
    for parts in (1, 7, 200, 400, 900, int(counts.sum())):
        np.testing.assert_array_equal(
            share_parts(sizes, counts, parts, min_fraction),
            reference_share_parts(sizes, counts, parts, min_fraction),
        )


def test_ten_thousand_parts_of_twenty_thousand_faces():
    # METIS leaves hundreds of parts empty here; each is filled by splitting the largest.
    mesh = trimesh.creation.icosphere(5)
    faces = np.asarray(mesh.faces)[:20_000]
    normals, areas = face_normals(mesh.vertices, faces)
    graph = build_face_graph(mesh.vertices, faces, normals)
    labels = metis_partition(
        graph, np.ones(len(graph.pairs), np.int64), 10_000, areas,
        face_centroids(mesh.vertices, faces),
    )  # fmt: skip
    assert sorted(np.unique(labels)) == list(range(10_000))


def test_many_tiny_shells_join_their_nearest_part():
    # 2,000 separate triangles beside one sphere: two parts for the sphere, each triangle
    # joins the part nearest to it.
    sphere = trimesh.creation.icosphere(2)
    x = 3.0 + np.arange(2000) * 0.01
    triangles = np.stack([np.column_stack([x, y, np.zeros(2000)])
                          for y in (np.zeros(2000), np.full(2000, 0.005), np.full(2000, -0.005))],
                         axis=1)  # fmt: skip
    triangles[:1000, :, 0] *= -1
    vertices = np.concatenate([sphere.vertices, triangles.reshape(-1, 3)])
    faces = np.concatenate(
        [sphere.faces, len(sphere.vertices) + np.arange(6000).reshape(-1, 3)[:, [0, 2, 1]]]
    )
    normals, areas = face_normals(vertices, faces)
    graph = build_face_graph(vertices, faces, normals)
    centroids = face_centroids(vertices, faces)
    labels = metis_partition(
        graph, np.ones(len(graph.pairs), np.int64), 2, areas, centroids, 0, 0.01
    )
    sphere_faces = len(sphere.faces)
    assert len(np.unique(labels[:sphere_faces])) == 2
    left = labels[:sphere_faces][np.argmin(centroids[:sphere_faces, 0])]
    right = labels[:sphere_faces][np.argmax(centroids[:sphere_faces, 0])]
    assert np.all(labels[sphere_faces : sphere_faces + 1000] == left)
    assert np.all(labels[sphere_faces + 1000 :] == right)


def test_two_shells_three_parts_and_isolated_faces():
    a = trimesh.creation.icosphere(2)
    b = a.copy()
    b.apply_translation([3, 0, 0])
    vertices = np.concatenate([a.vertices, b.vertices, [[9, 9, 9], [9, 9, 10], [9, 10, 9]]])
    n = len(a.vertices)
    faces = np.concatenate([a.faces, b.faces + n, [[2 * n, 2 * n + 1, 2 * n + 2]]])
    normals, areas = face_normals(vertices, faces)
    graph = build_face_graph(vertices, faces, normals)
    centroids = face_centroids(vertices, faces)
    for parts in (1, 2, 3, 7):
        labels = metis_partition(
            graph, np.ones(len(graph.pairs), np.int64), parts, areas, centroids
        )
        assert labels.max() + 1 == parts
    labels = metis_partition(graph, np.ones(len(graph.pairs), np.int64), 2, areas, centroids)
    # The two equal spheres get one part each; the lone face joins the nearer one (b).
    assert len(np.unique(labels[: len(a.faces)])) == 1
    assert labels[-1] == labels[len(a.faces)]


def test_more_parts_than_faces_is_a_parameter_error():
    graph, areas, centroids = sphere_graph(0)
    with pytest.raises(ParameterError, match="more than the mesh's 20 faces"):
        metis_partition(graph, np.ones(len(graph.pairs), np.int64), 21, areas, centroids)
