"""Reflective symmetry: the plane of a mirror-symmetric shape found in any pose, none on
an asymmetric one, and a segmentation whose two sides are cut alike."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import prepare_segment, segment
from neural_shdf.segment import SegmentParams
from neural_shdf.segment.parts import canonical_labels
from neural_shdf.segment.symmetry import (
    detect_reflection,
    mirror_agreement,
    mirror_leaves,
    mirror_parts,
    symmetrize,
)

#: A rotation and a shift that put the shapes in no axis-aligned pose.
POSE = Rotation.from_euler("xyz", [0.4, -0.7, 1.1]).as_matrix()
SHIFT = np.array([3.0, -1.0, 0.5])


def plane_shape(fin_side: float = 0.0) -> TriangleMesh:
    """A toy airplane: a fuselage along x, wings along y, a fin on top at the back; its
    only mirror plane is y = 0 (before ``POSE``). ``fin_side`` moves the fin off it."""
    boxes = [
        trimesh.creation.box([6.0, 0.8, 0.8]),
        trimesh.creation.box([1.2, 7.0, 0.2]),
        trimesh.creation.box([0.8, 0.2, 1.6], trimesh.transformations.translation_matrix(
            [-2.4, fin_side, 1.0])),
    ]  # fmt: skip
    shape = trimesh.util.concatenate(boxes)
    vertices, faces = trimesh.remesh.subdivide_to_size(shape.vertices, shape.faces, 0.12)
    return TriangleMesh(np.asarray(vertices) @ POSE.T + SHIFT, np.asarray(faces))


def detect(mesh: TriangleMesh):
    normals, areas = mesh.oriented.normals_and_areas
    return detect_reflection(mesh.oriented.centroids, normals, areas)


def test_the_mirror_plane_is_found_in_any_pose():
    mesh = plane_shape()
    reflection = detect(mesh)
    assert reflection is not None and reflection.matched_area > 0.95
    expected = POSE @ np.array([0.0, 1.0, 0.0])
    assert abs(float(reflection.normal @ expected)) > 0.999
    assert abs(reflection.offset - float(reflection.normal @ SHIFT)) < 1e-3
    # Mirrors pair faces across the plane: the mirror's mirror is (nearly always) the face.
    mirror = reflection.mirror
    both = np.flatnonzero((mirror >= 0) & (mirror[np.maximum(mirror, 0)] >= 0))
    assert (mirror[mirror[both]] == both).mean() > 0.9


def test_an_asymmetric_shape_has_none():
    assert detect(plane_shape(fin_side=1.5)) is None  # the fin far off the plane


def test_mirror_agreement_is_one_for_a_mirrored_cut_whatever_the_labels():
    areas = np.ones(4)
    mirror = np.array([1, 0, 3, 2])  # faces 0 <-> 1 and 2 <-> 3
    assert mirror_agreement(np.array([0, 1, 2, 2]), mirror, areas) == 1.0  # left, right, middle
    assert mirror_agreement(np.array([0, 0, 0, 1]), mirror, areas) < 1.0  # 3 apart from 2
    assert np.isnan(mirror_agreement(np.array([0, 1]), np.array([-1, -1]), np.ones(2)))


def test_symmetrize_averages_each_face_with_its_mirror():
    values = np.array([1.0, 3.0, 5.0, 7.0])
    mirror = np.array([1, 0, -1, 2])
    assert symmetrize(values, mirror).tolist() == [2.0, 2.0, 5.0, 6.0]


def two_way_mirror(mirror: np.ndarray) -> np.ndarray:
    """The mirror map where it pairs faces both ways (-1 elsewhere)."""
    paired = (mirror >= 0) & (mirror[np.maximum(mirror, 0)] == np.arange(len(mirror)))
    return np.where(paired, mirror, -1)


def assert_mirror_images(labels: np.ndarray, mirror: np.ndarray) -> None:
    """Every part's faces map under the mirror onto the faces of one part (itself, or its
    mirror part), and no two parts onto the same one."""
    paired = mirror >= 0
    images = {}
    for part in np.unique(labels[paired]):
        faces = np.flatnonzero((labels == part) & paired)
        onto = np.unique(labels[mirror[faces]])
        assert len(onto) == 1, (part, onto)
        images[int(part)] = int(onto[0])
    assert len(set(images.values())) == len(images)


def test_mirror_parts_copies_one_sides_cut_onto_the_other():
    mesh = plane_shape()
    reflection = detect(mesh)
    assert reflection is not None
    centroids = mesh.oriented.centroids
    _, areas = mesh.oriented.normals_and_areas
    local = (centroids - SHIFT) @ POSE
    # Fuselage 0; each wing cut in two, at |y| = 2 on one side and 2.8 on the other; fin 3.
    labels = np.where(np.abs(local[:, 1]) < 0.45, 0, np.where(local[:, 1] > 0, 1, 4))
    labels[local[:, 1] > 2.0] = 2
    labels[local[:, 1] < -2.8] = 5
    labels[local[:, 2] > 0.45] = 3
    mirror = two_way_mirror(reflection.mirror)
    assert mirror_agreement(labels, mirror, areas) < 0.99
    mirrored = mirror_parts(labels, reflection, centroids, areas)
    assert mirror_agreement(mirrored, mirror, areas) == pytest.approx(1.0, abs=1e-12)
    assert_mirror_images(mirrored, mirror)
    # Parts across the plane (fuselage, fin) keep their label; one wing's pieces are copied.
    for part in (0, 3):
        assert np.all(mirrored[labels == part] == part)
    assert len(np.unique(mirrored)) == 6  # fuselage, fin, two pieces of each wing
    again = mirror_parts(mirrored, reflection, centroids, areas)  # already alike: the same
    assert np.array_equal(canonical_labels(again), canonical_labels(mirrored))


def test_mirror_leaves_pairs_parts_that_are_each_others_image():
    mirror = np.array([1, 0, 3, 2, 4, 4, -1])  # faces 0<->1, 2<->3; 4 its own; 5 -> 4
    areas = np.ones(7)
    # Parts 0 | 1 mirror each other, 2 is its own image, 3's image is 2 but not the reverse.
    leaves = np.array([0, 1, 2, 2, 2, 3, 3])
    assert mirror_leaves(leaves, mirror, areas).tolist() == [1, 0, 2, -1]
    assert mirror_leaves(leaves, np.full(7, -1), areas).tolist() == [-1, -1, -1, -1]


def noisy_shdf(mesh: TriangleMesh) -> np.ndarray:
    """Thick fuselage, thin wings and fin, plus noise and a patch on one side only."""
    local = (mesh.oriented.centroids - SHIFT) @ POSE
    base = np.where(np.abs(local[:, 1]) < 0.5, 0.8, 0.25)
    noise = np.random.default_rng(7).normal(0.0, 0.03, mesh.face_count)
    # A thicker patch at one wing's root only: without symmetry, that side's boundary
    # moves out along the wing.
    patch = (local[:, 1] > 0.45) & (local[:, 1] < 1.0) & (np.abs(local[:, 0]) < 0.6)
    return np.clip(base + noise + 0.45 * patch, 0.0, 1.0)


def test_symmetry_cuts_both_sides_alike_and_is_off_by_default():
    mesh = plane_shape()
    shdf = noisy_shdf(mesh)
    params = SegmentParams(clusters=4, smoothing=0.03, crease_boundaries=False)
    plain = segment(mesh, shdf, params)
    symmetric = segment(mesh, shdf, SegmentParams(**{**params.__dict__, "symmetry": True}))
    assert plain.reflection is None and symmetric.reflection is not None
    mirror = symmetric.reflection.mirror
    _, areas = mesh.normals_and_areas
    before = mirror_agreement(plain.labels, mirror, areas)
    after = mirror_agreement(symmetric.labels, mirror, areas)
    assert after > before and after > 0.99, (before, after)
    # Exact where the tessellation pairs faces both ways: parts map onto parts.
    two_way = two_way_mirror(mirror)
    assert mirror_agreement(symmetric.labels, two_way, areas) == pytest.approx(1.0, abs=1e-12)
    assert_mirror_images(symmetric.labels, two_way)
    assert_mirror_images(symmetric.tree.leaf_labels, two_way)
    again = segment(mesh, shdf, SegmentParams(**{**params.__dict__, "symmetry": True}))
    assert np.array_equal(again.labels, symmetric.labels)  # deterministic


def test_no_symmetry_found_changes_nothing_and_the_basis_knows_the_option():
    mesh = plane_shape(fin_side=1.5)
    shdf = noisy_shdf(mesh)
    params = SegmentParams(clusters=4, smoothing=0.03)
    with_option = SegmentParams(**{**params.__dict__, "symmetry": True})
    assert np.array_equal(
        segment(mesh, shdf, params).labels, segment(mesh, shdf, with_option).labels
    )
    basis = prepare_segment(mesh, shdf, params)
    assert basis.matches(params, shdf) and not basis.matches(with_option, shdf)
    with pytest.raises(ValueError, match="basis"):
        segment(mesh, shdf, with_option, basis=basis)
