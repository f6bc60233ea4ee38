"""Exact ShDF: known diameters of simple solids, robustness, determinism, CGAL agreement."""

import math

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from neural_shdf import constants
from neural_shdf.errors import ParameterError
from neural_shdf.geometry import face_normals
from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.segment import SegmentParams
from neural_shdf.shdf.exact import (
    cone_directions,
    face_tangents,
    plane_basis,
    raw_shdf,
    robust_mean,
)
from neural_shdf.shdf.stage import ShdfParams, raw_diameters
from tests.mesh_helpers import balls_and_bar, relisted


def expected_robust_mean(lengths: np.ndarray) -> float:
    """Mean of the ray lengths within 1.5 median absolute deviations of the median."""
    median = np.median(lengths)
    mad = np.median(np.abs(lengths - median))
    return float(lengths[np.abs(lengths - median) <= 1.5 * mad].mean())


def ray_angles(ray_count: int, cone_angle: float) -> np.ndarray:
    """Angle of each ray to the cone axis, from the spiral radius i/n on the disk."""
    radius = np.arange(ray_count) / ray_count
    return np.arctan(math.tan(cone_angle / 2) * radius)


def test_rays_fill_the_cone_around_the_inward_normal():
    normal = np.array([[0.0, 0.0, -1.0], [0.6, 0.0, 0.8]])
    tangents = np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    directions = cone_directions(normal, tangents, cone_angle=2 * math.pi / 3, ray_count=25)
    assert directions.shape == (2, 25, 3)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=2), 1.0)
    angles = np.arccos(np.clip(np.einsum("frk,fk->fr", directions, normal), -1, 1))
    np.testing.assert_allclose(angles, np.tile(ray_angles(25, 2 * math.pi / 3), (2, 1)), atol=1e-9)
    assert np.all(angles < math.pi / 3)
    # The spiral starts along the tangent (made perpendicular to the axis).
    second = directions[:, 1] - np.einsum("fk,fk->f", directions[:, 1], normal)[:, None] * normal
    first_angle = (3.0 - math.sqrt(5.0)) * math.pi
    np.testing.assert_allclose(
        np.einsum("fk,fk->f", second / np.linalg.norm(second, axis=1, keepdims=True), tangents)
        / np.linalg.norm(tangents, axis=1),
        math.cos(first_angle),
    )


def test_face_tangents_follow_the_triangle_not_its_listing_or_pose():
    rng = np.random.default_rng(0)
    vertices = rng.normal(size=(300, 3))
    faces = np.arange(300).reshape(-1, 3)
    tangents = face_tangents(vertices, faces)
    normals, _ = face_normals(vertices, faces)
    np.testing.assert_allclose(np.linalg.norm(tangents, axis=1), 1.0)
    np.testing.assert_allclose(np.einsum("ij,ij->i", tangents, normals), 0.0, atol=1e-12)
    # Any first vertex, either winding.
    for listing in (faces[:, [1, 2, 0]], faces[:, [2, 0, 1]], faces[:, ::-1]):
        np.testing.assert_allclose(face_tangents(vertices, listing), tangents, atol=1e-12)
    # Turns with the triangle; translation and scale change nothing.
    rotation = Rotation.random(random_state=1).as_matrix()
    moved = 250.0 * vertices @ rotation.T + (1e3, -40.0, 7.0)
    np.testing.assert_allclose(face_tangents(moved, faces), tangents @ rotation.T, atol=1e-9)
    # Leans towards the vertex of the largest angle (opposite the longest edge).
    corners = vertices[faces]
    opposite = np.linalg.norm(np.roll(corners, -1, axis=1) - np.roll(corners, 1, axis=1), axis=2)
    apex = corners[np.arange(len(faces)), opposite.argmax(axis=1)] - corners.mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", tangents, apex) > 0)


def test_an_equilateral_triangle_points_to_its_vertex_of_smallest_index():
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, math.sqrt(3) / 2, 0.0]])
    centroid = vertices.mean(axis=0)
    expected = (vertices[0] - centroid) / np.linalg.norm(vertices[0] - centroid)
    for listing in ([0, 1, 2], [2, 0, 1], [1, 0, 2]):
        np.testing.assert_allclose(face_tangents(vertices, np.array([listing]))[0], expected)
    # A triangle shrunk to a point has no direction (and casts no rays).
    point = np.array([[1.0, 2.0, 3.0]] * 3)
    np.testing.assert_array_equal(face_tangents(point, np.array([[0, 1, 2]])), 0.0)


def lumpy_dumbbell() -> TriangleMesh:
    """Two balls joined by a bar, vertices jittered: no symmetry that ties rays."""
    joined = balls_and_bar(4, 3)
    vertices = np.asarray(joined.vertices, dtype=np.float64)
    vertices += np.random.default_rng(7).normal(scale=0.01, size=vertices.shape)
    return TriangleMesh(vertices, np.asarray(joined.faces, dtype=np.int64))


#: A random rotation, scale and far shift of the mesh.
POSE_SCALE = 250.0
POSE_SHIFT = np.array([1e3, -40.0, 7.0])


def posed(mesh: TriangleMesh) -> TriangleMesh:
    rotation = Rotation.random(random_state=3).as_matrix()
    return TriangleMesh(POSE_SCALE * mesh.vertices @ rotation.T + POSE_SHIFT, mesh.faces)


def test_raw_shdf_does_not_depend_on_the_pose():
    mesh = lumpy_dumbbell()
    moved = posed(mesh)
    # Embree casts in float32: another pose rounds every vertex differently (about 1e-7
    # of the extent), which moves hit distances by about as much. A ray within that
    # rounding of an edge or of its face's outlier threshold could count differently;
    # the jitter leaves no such ties here. 1e-4 leaves margin for other builds of Embree;
    # the world-axis cone differed by a few percent on most faces.
    np.testing.assert_allclose(
        raw_shdf(moved.vertices, moved.faces) / POSE_SCALE,
        raw_shdf(mesh.vertices, mesh.faces),
        rtol=1e-4,
    )


@pytest.mark.parametrize("method", ["exact", "sampled"])
def test_shdf_and_parts_do_not_depend_on_the_pose(method):
    mesh = lumpy_dumbbell()
    moved = posed(mesh)
    shdf = compute_shdf(mesh, method=method).values
    moved_shdf = compute_shdf(moved, method=method).values
    np.testing.assert_allclose(moved_shdf, shdf, atol=1e-5)  # in [0, 1]; as the raw values
    labels = segment(mesh, shdf, SegmentParams()).labels
    assert labels.max() >= 2
    np.testing.assert_array_equal(segment(moved, moved_shdf, SegmentParams()).labels, labels)


@pytest.mark.needs_data
def test_a_benchmark_mesh_gives_the_same_parts_in_another_pose(psb_off):
    # The cup the world-axis cone turned from 1-RI 0.06 into 0.32 when rotated.
    loaded = trimesh.load(psb_off(24), process=False)
    mesh = TriangleMesh(np.asarray(loaded.vertices), np.asarray(loaded.faces))
    moved = posed(mesh)
    shdf = compute_shdf(mesh).values
    moved_shdf = compute_shdf(moved).values
    assert np.corrcoef(shdf, moved_shdf)[0, 1] > 0.99999
    np.testing.assert_array_equal(
        segment(moved, moved_shdf, SegmentParams()).labels,
        segment(mesh, shdf, SegmentParams()).labels,
    )


def test_robust_mean_drops_outliers_and_handles_missing_rays():
    distances = np.array(
        [
            [1.0, 1.1, 0.9, 1.0, 50.0],
            [2.0, np.nan, np.nan, np.nan, np.nan],
            [np.nan] * 5,
            [1.0, 3.0, np.nan, np.nan, np.nan],
        ]
    )
    values = robust_mean(distances, np.ones(5))
    assert values[0] == pytest.approx(1.0)
    assert values[1] == 2.0
    assert np.isnan(values[2])
    assert values[3] == pytest.approx(2.0)


def test_sphere_diameter_matches_the_cone_weighted_chord_mean():
    radius = 2.5
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=radius)
    raw = raw_shdf(sphere.vertices, sphere.faces)
    # A ray at angle a to the inward normal crosses the sphere along a chord 2 r cos(a).
    chords = 2 * radius * np.cos(ray_angles(constants.SHDF_RAY_COUNT, constants.SHDF_CONE_ANGLE))
    expected = expected_robust_mean(chords)
    assert not np.isnan(raw).any()
    # Facets sit slightly inside the sphere; rays right at the outlier threshold
    # may flip in or out on some faces, which moves their mean by a few percent.
    assert np.median(raw) == pytest.approx(expected, rel=0.002)
    np.testing.assert_allclose(raw, expected, rtol=0.04)


def test_slab_thickness_is_recovered():
    thickness = 0.5
    slab = trimesh.creation.box(extents=(20, 20, thickness)).subdivide().subdivide().subdivide()
    raw = raw_shdf(slab.vertices, slab.faces)
    centroids = slab.triangles_center
    # Big faces far from the rim: every ray crosses to the opposite face, t / cos(a).
    inner = (np.abs(centroids[:, 2]) > 0.2) & (np.abs(centroids[:, :2]).max(axis=1) < 8)
    angles = ray_angles(constants.SHDF_RAY_COUNT, constants.SHDF_CONE_ANGLE)
    expected = expected_robust_mean(thickness / np.cos(angles))
    assert inner.sum() > 50
    np.testing.assert_allclose(raw[inner], expected, rtol=1e-6)


def test_thin_cylinder_is_thin_everywhere_on_its_side():
    radius = 0.3
    cylinder = trimesh.creation.cylinder(radius=radius, height=10, sections=48)
    raw = raw_shdf(cylinder.vertices, cylinder.faces)
    side = np.abs(cylinder.face_normals[:, 2]) < 0.1
    assert np.all(raw[side] > 1.8 * radius)
    assert np.all(raw[side] < 3.0 * radius)


def test_two_shells_keep_their_own_diameters():
    small = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    large = trimesh.creation.icosphere(subdivisions=3, radius=3.0)
    large.apply_translation((10, 0, 0))
    both = trimesh.util.concatenate([small, large])
    raw = raw_shdf(both.vertices, both.faces)
    count = len(small.faces)
    assert np.median(raw[count:]) / np.median(raw[:count]) == pytest.approx(3.0, rel=0.01)


def test_inward_facing_hits_are_rejected():
    # Inside-out sphere: every ray meets a face whose normal points back at it.
    sphere = trimesh.creation.icosphere(subdivisions=2)
    raw = raw_shdf(sphere.vertices, sphere.faces[:, ::-1])
    assert np.isnan(raw).all()


def test_open_and_degenerate_faces_do_not_crash():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    keep = sphere.triangles_center[:, 2] < 0.5  # cut a hole at the top
    vertices = np.vstack([sphere.vertices, [[5, 5, 5], [6, 5, 5], [7, 5, 5]]])
    n = len(sphere.vertices)
    degenerate = np.array([[0, 0, 1], [n, n + 1, n + 2]])  # repeated vertex, collinear
    faces = np.vstack([sphere.faces[keep], degenerate])
    mesh = TriangleMesh(vertices, faces)
    raw = raw_shdf(vertices, faces)
    assert np.isnan(raw[-2:]).all()
    assert np.isfinite(raw[:-2]).mean() > 0.9
    values = compute_shdf(mesh, method="exact").values
    assert values.shape == (len(faces),)
    assert np.isfinite(values).all()
    assert values.min() == 0.0 and values.max() == 1.0


def test_flat_sheet_has_no_diameter_and_gives_zeros():
    sheet = trimesh.creation.box(extents=(1, 1, 1))
    faces = sheet.faces[sheet.face_normals[:, 2] > 0.5]
    mesh = TriangleMesh(sheet.vertices, faces)
    assert np.isnan(raw_shdf(mesh.vertices, mesh.faces)).all()
    np.testing.assert_array_equal(compute_shdf(mesh, method="exact").values, 0.0)


def test_empty_mesh():
    mesh = TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64))
    assert compute_shdf(mesh, method="exact").values.shape == (0,)


def test_same_seed_same_values_and_thread_count_does_not_matter():
    mesh = trimesh.creation.annulus(r_min=0.5, r_max=1.0, height=0.4, sections=32)
    first = raw_shdf(mesh.vertices, mesh.faces, rotate_pattern=True, seed=3, threads=1)
    second = raw_shdf(mesh.vertices, mesh.faces, rotate_pattern=True, seed=3, threads=2)
    other = raw_shdf(mesh.vertices, mesh.faces, rotate_pattern=True, seed=4)
    np.testing.assert_array_equal(first, second)
    assert not np.array_equal(first, other, equal_nan=True)
    plain = TriangleMesh(mesh.vertices, mesh.faces)
    np.testing.assert_array_equal(
        compute_shdf(plain, method="exact").values,
        compute_shdf(plain, method="exact").values,
    )


def test_given_normals_are_used_and_progress_reaches_one():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    normals, _ = face_normals(sphere.vertices, sphere.faces)
    seen = []
    raw = raw_shdf(sphere.vertices, sphere.faces, normals=normals, progress=seen.append)
    np.testing.assert_array_equal(raw, raw_shdf(sphere.vertices, sphere.faces))
    assert seen[-1] == 1.0 and all(0 <= s <= 1 for s in seen)


def test_bad_parameters_are_refused():
    sphere = trimesh.creation.icosphere(subdivisions=1)
    with pytest.raises(ParameterError):
        raw_shdf(sphere.vertices, sphere.faces, cone_angle=4.0)
    with pytest.raises(ParameterError):
        raw_shdf(sphere.vertices, sphere.faces, ray_count=0)


@pytest.mark.needs_data
def test_agrees_with_cgal_on_a_benchmark_mesh(psb_off, shared_data):
    loaded = trimesh.load(psb_off(1), process=False)
    mesh = TriangleMesh(np.asarray(loaded.vertices), np.asarray(loaded.faces))
    reference = np.loadtxt(shared_data / "psb-dev" / "cgal" / "1.sdf")
    ours = compute_shdf(mesh, method="exact").values
    assert np.corrcoef(ours, reference)[0, 1] >= 0.99


def test_plane_basis_follows_cgal_and_is_orthonormal():
    normals = np.array([[0.0, 0.6, 0.8], [0.6, 0.0, -0.8], [0.6, 0.8, 0.0], [0.2, 0.4, 0.9]])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    base1, base2 = plane_basis(normals)
    np.testing.assert_allclose(base1[0], [1, 0, 0])
    np.testing.assert_allclose(base1[1], [0, 1, 0])
    np.testing.assert_allclose(base1[2], [0, 0, 1])
    # Smallest component (x) dropped: (0, -nz, ny), normalised.
    np.testing.assert_allclose(base1[3], np.array([0, -0.9, 0.4]) / math.hypot(0.9, 0.4))
    np.testing.assert_allclose(base2, np.cross(normals, base1), atol=1e-15)
    for vectors in (base1, base2):
        np.testing.assert_allclose(np.linalg.norm(vectors, axis=1), 1.0)
        np.testing.assert_allclose(np.einsum("ij,ij->i", vectors, normals), 0.0, atol=1e-15)


def test_exact_shdf_progress_rises_to_one():
    sphere = trimesh.creation.icosphere(subdivisions=3)
    mesh = TriangleMesh(sphere.vertices, sphere.faces)
    seen = []
    compute_shdf(mesh, method="exact", progress=seen.append)
    assert seen == sorted(seen) and seen[-1] == 1.0 and len(seen) >= 2


def test_rays_meeting_the_cap_across_a_cut_limb_near_its_rim_are_not_read_as_thin():
    """A long ellipsoid's end cut off (a limb of a scan with no base): the faces along the
    cut keep about the closed mesh's diameters, and the mesh's smallest value is the closed
    mesh's (rays grazing the cap had read 3% of it there, stretching the normalisation)."""
    sphere = trimesh.creation.icosphere(subdivisions=4)
    vertices, faces = np.asarray(sphere.vertices) * [3.0, 0.6, 0.6], np.asarray(sphere.faces)
    closed = TriangleMesh(vertices, faces)
    along = vertices[faces].mean(axis=1)[:, 0]
    kept = np.flatnonzero(along > -2.0)
    cut = TriangleMesh(vertices, faces[kept])
    assert cut.diagnostics.boundary_loops == 1
    params = ShdfParams()
    whole = raw_diameters(closed, closed.face_graph, "exact", params)[kept]
    capped = raw_diameters(cut, cut.face_graph, "exact", params, close_holes=True)
    rim = along[kept] < -1.8
    assert np.min(capped[rim] / whole[rim]) > 0.9
    # Each mesh casts in its own pose frame: float32 rounding apart, the same value.
    assert capped.min() == pytest.approx(whole.min(), rel=1e-5)


def test_raw_diameters_do_not_follow_the_face_order_where_hits_tie():
    """A box with a double-sided wall inside (coincident faces of opposite winding): rays
    meet both wall triangles at the same distance, and the one reported decides the
    back-face test. Reordered faces and vertices give the same diameters bit for bit."""
    box = trimesh.creation.box((2.0, 1.0, 1.0))
    wall = trimesh.creation.box((0.0, 1.0, 1.0)).subdivide()  # flat: pairs of opposite faces
    wall_vertices, wall_faces = wall.vertices, wall.faces[np.abs(wall.face_normals[:, 0]) > 0.5]
    vertices = np.vstack([box.vertices, wall_vertices])
    faces = np.vstack([box.faces, wall_faces + len(box.vertices)])
    expected = raw_shdf(vertices, faces)
    rng = np.random.default_rng(7)
    for _ in range(3):
        moved, listed, origin = relisted(vertices, faces, rng)
        np.testing.assert_array_equal(raw_shdf(moved, listed), expected[origin])


def test_the_stage_casts_in_the_meshs_own_frame_so_ties_follow_no_pose():
    """A block with a double-sided wall inside, off centre (ties between coincident
    faces, and a shape that fixes its frame): in another pose and scale the ShDF stage
    meets the same float32 coordinates, so the same hits, to the last bits but the scale's."""
    block = trimesh.creation.box((3.0, 1.2, 0.7))
    wall = trimesh.creation.box((0.0, 1.2, 0.7)).subdivide()
    keep = np.abs(wall.face_normals[:, 0]) > 0.5
    lump = trimesh.creation.icosphere(1, radius=0.3)
    vertices = np.vstack(
        [block.vertices, wall.vertices + (0.8, 0, 0), lump.vertices + (-1, 0, 0.5)]
    )
    faces = np.vstack([block.faces, wall.faces[keep] + 8, lump.faces + 8 + len(wall.vertices)])
    mesh = TriangleMesh(vertices, faces)
    moved = posed(mesh)
    params = ShdfParams()
    here = raw_diameters(mesh.oriented, mesh.oriented.face_graph, "exact", params)
    there = raw_diameters(moved.oriented, moved.oriented.face_graph, "exact", params)
    assert np.isfinite(here).sum() > 0.9 * len(here)
    np.testing.assert_allclose(there / POSE_SCALE, here, rtol=1e-12)
