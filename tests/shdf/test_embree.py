"""Embree 4 through ctypes: packet casts agree with embreex's one-ray casts."""

import numpy as np
import pytest
import trimesh

from neural_shdf.shdf import embree
from neural_shdf.shdf.embree import LANES, Scene
from tests.mesh_helpers import relisted


def random_rays(count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    origins = rng.uniform(-0.3, 0.3, (count, 3))
    directions = rng.normal(size=(count, 3))
    return origins, directions / np.linalg.norm(directions, axis=1, keepdims=True)


def test_packets_hit_the_same_triangles_as_embreex():
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh as EmbreexMesh

    mesh = trimesh.creation.annulus(0.4, 1.0, 0.5, sections=64)
    scene = Scene(mesh.vertices, mesh.faces)
    reference = rtcore_scene.EmbreeScene()
    EmbreexMesh(
        reference,
        (mesh.vertices - scene.center).astype(np.float32),
        mesh.faces.astype(np.int32),
    )
    # A count that is not a multiple of the packet size: the last packet is partial.
    origins, directions = random_rays(40 * LANES + 7)
    origins[::3] += 5.0  # some rays start outside and miss
    local = (origins - scene.center).astype(np.float32)
    hits = scene.first_hits(local, directions)
    expected = reference.run(local, directions.astype(np.float32))
    assert hits.dtype == np.int64
    assert (hits == -1).any() and (hits >= 0).any()
    np.testing.assert_array_equal(hits, expected)


def test_low_build_quality_hits_the_same_triangles():
    mesh = trimesh.creation.icosphere(subdivisions=4)
    mesh.vertices *= np.random.default_rng(2).uniform(0.7, 1.3, len(mesh.vertices))[:, None]
    origins, directions = random_rays(2000, seed=3)
    medium = Scene(mesh.vertices, mesh.faces, "medium")
    low = Scene(mesh.vertices, mesh.faces, "low")
    local = (origins - medium.center).astype(np.float32)
    hits = medium.first_hits(local, directions)
    assert (hits >= 0).all()
    np.testing.assert_array_equal(low.first_hits(local, directions), hits)
    with pytest.raises(ValueError, match="build quality"):
        Scene(mesh.vertices, mesh.faces, "high")


def test_bounding_box_is_numpys():
    points = np.random.default_rng(4).normal(size=(1001, 3))
    low, high = embree.bounding_box(points)
    np.testing.assert_array_equal(low, points.min(axis=0))
    np.testing.assert_array_equal(high, points.max(axis=0))


def test_hits_are_the_closest_triangle_along_the_ray():
    box = trimesh.creation.box((2.0, 2.0, 2.0))
    scene = Scene(box.vertices, box.faces)
    origins = np.zeros((3, 3), dtype=np.float32)
    directions = np.eye(3, dtype=np.float32)
    hits = scene.first_hits(origins, directions)
    outward = box.face_normals[hits]
    np.testing.assert_allclose(outward, np.eye(3), atol=1e-12)


def test_degenerate_triangles_are_never_hit():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 1, 3]])  # the second one is a segment
    scene = Scene(vertices, faces)
    origins = (np.array([[0.2, 0.2, 1.0], [0.5, 0.0, 1.0]]) - scene.center).astype(np.float32)
    hits = scene.first_hits(origins, np.array([[0, 0, -1], [0, 0, -1]], dtype=np.float32))
    assert hits[0] == 0
    assert hits[1] in (-1, 0)  # on the edge of the real triangle at most, never face 1


def test_a_missing_library_says_what_to_install(monkeypatch):
    monkeypatch.setattr(embree, "_library_candidates", lambda: [])
    with pytest.raises(ImportError, match="embreex"):
        embree.Embree()


def test_a_ray_meeting_two_triangles_at_once_reports_the_same_one_in_any_order():
    """Coincident triangles of opposite winding (a double-sided card): the hit, and so the
    back-face test of the ShDF's rays, must not follow the file's face order."""
    card = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 2, 1], [0, 3, 2]])
    origins = np.array([[0.7, 0.2, 1.0], [0.2, 0.7, 1.0], [0.5, 0.5, 1.0]])
    down = np.tile([0.0, 0.0, -1.0], (3, 1)).astype(np.float32)
    normals = []
    for seed in range(6):
        vertices, listed, _ = relisted(card, faces, np.random.default_rng(seed), turn=True)
        scene = Scene(vertices, listed)
        hits = scene.first_hits((origins - scene.center).astype(np.float32), down)
        assert (hits >= 0).all()
        corners = vertices[listed[hits]]
        normals.append(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    for other in normals[1:]:
        np.testing.assert_array_equal(np.sign(other), np.sign(normals[0]))
