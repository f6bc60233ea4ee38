"""segment(): dumbbell separation, exact METIS counts, determinism, messy meshes, errors."""

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import ParameterError
from neural_shdf.geometry import build_face_graph, face_normals, weld_faces
from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import compute_shdf
from neural_shdf.segment.basis import SegmentBasis
from neural_shdf.segment.from_shdf import SegmentResult, prepare_segment, segment
from neural_shdf.segment.params import AUTO_CLUSTERS, DEFAULT_REFERENCE_FACES, SegmentParams
from neural_shdf.segment.synthetic import JUNCTION_Z, dumbbell


def details(vertices, faces, shdf, params, *, basis: SegmentBasis | None = None) -> SegmentResult:
    """The segmentation of the triangles ``faces`` over ``vertices``."""
    return segment(TriangleMesh(vertices, faces), shdf, params, basis=basis)


def labels_of(vertices, faces, shdf, params) -> np.ndarray:
    return details(vertices, faces, shdf, params).labels


def basis_of(vertices, faces, shdf, params) -> SegmentBasis:
    return prepare_segment(TriangleMesh(vertices, faces), shdf, params)


def graph_of(vertices, faces):
    normals, _ = face_normals(vertices, faces)
    return build_face_graph(vertices, weld_faces(vertices, faces), normals)


@pytest.fixture(scope="module")
def dumbbell_case():
    mesh, shdf = dumbbell(6000)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    return vertices, faces, shdf, graph_of(vertices, faces), mesh.triangles_center[:, 2]


def assert_canonical(labels):
    assert labels.dtype == np.int64
    _, first = np.unique(labels, return_index=True)
    assert np.array_equal(np.unique(labels), np.arange(len(first)))
    assert np.all(np.diff(first) > 0)


@pytest.mark.parametrize(
    "params",
    [
        SegmentParams(clusters=AUTO_CLUSTERS),
        SegmentParams(clusters=3),
        SegmentParams(clusters=AUTO_CLUSTERS, refine=True, boundary_smoothing=True),
    ],
)
def test_graphcut_separates_the_neck_from_the_balls(dumbbell_case, params):
    vertices, faces, shdf, graph, z = dumbbell_case
    labels = labels_of(vertices, faces, shdf, params)
    assert_canonical(labels)
    neck = np.abs(z) < JUNCTION_Z - 0.1
    left, right = z < -JUNCTION_Z - 0.1, z > JUNCTION_Z + 0.1
    neck_label = np.bincount(labels[neck]).argmax()
    assert np.mean(labels[neck] == neck_label) > 0.95
    for ball in (left, right):
        assert not np.any(labels[ball] == neck_label)
        assert np.mean(labels[ball] == np.bincount(labels[ball]).argmax()) > 0.95
    # The cut sits at the concave junctions, within a few rings.
    cut = labels[graph.pairs[:, 0]] != labels[graph.pairs[:, 1]]
    cut_z = np.abs(z[graph.pairs[cut]].mean(axis=1))
    assert np.all(np.abs(cut_z - JUNCTION_Z) < 0.2)


@pytest.mark.parametrize("parts", [2, 3, 6])
def test_metis_returns_exactly_the_requested_parts(dumbbell_case, parts):
    vertices, faces, shdf, graph, _ = dumbbell_case
    labels = labels_of(vertices, faces, shdf, SegmentParams(partitioner="metis", parts=parts))
    assert_canonical(labels)
    assert labels.max() + 1 == parts


def test_metis_without_parts_uses_the_graph_cut_count(dumbbell_case):
    vertices, faces, shdf, graph, _ = dumbbell_case
    cut = labels_of(vertices, faces, shdf, SegmentParams())
    labels = labels_of(vertices, faces, shdf, SegmentParams(partitioner="metis"))
    assert labels.max() == cut.max()


@pytest.mark.parametrize(
    "params",
    [
        SegmentParams(),
        SegmentParams(partitioner="metis", parts=4, boundary_smoothing=True),
        SegmentParams(refine=True, boundary_smoothing=True, seed=5),
    ],
)
def test_labels_are_deterministic(dumbbell_case, params):
    vertices, faces, shdf, graph, _ = dumbbell_case
    first = labels_of(vertices, faces, shdf, params)
    second = labels_of(vertices.copy(), faces.copy(), shdf.copy(), params)
    np.testing.assert_array_equal(first, second)


def test_reference_faces_make_part_counts_independent_of_tessellation():
    counts = []
    for faces_wanted in (3000, 60000):
        mesh, shdf = dumbbell(faces_wanted)
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        params = SegmentParams(clusters=AUTO_CLUSTERS, smoothing=0.26, reference_faces=3000)
        counts.append(labels_of(vertices, faces, shdf, params).max() + 1)
    assert counts == [3, 3]


def test_the_default_graph_cut_is_normalised_for_resolution():
    params = SegmentParams()
    assert params.reference_faces == DEFAULT_REFERENCE_FACES
    assert params.smoothing_for(4 * DEFAULT_REFERENCE_FACES) == pytest.approx(
        2 * params.effective_smoothing
    )
    assert SegmentParams(reference_faces=None).smoothing_for(10**6) == params.effective_smoothing


def test_graphcut_parts_cut_its_merge_tree(dumbbell_case):
    vertices, faces, shdf, graph, _ = dumbbell_case
    fine = SegmentParams(smoothing=0.02)
    whole = details(vertices, faces, shdf, fine)
    leaves = whole.tree.leaf_count
    assert leaves >= 3
    for parts in range(1, leaves + 1):
        result = details(vertices, faces, shdf, replace(fine, parts=parts))
        assert_canonical(result.labels)
        assert result.part_count == parts
        # The same tree, cut: no new partition per count.
        np.testing.assert_array_equal(result.tree.merges, whole.tree.merges)
        np.testing.assert_array_equal(result.labels, whole.tree.labels(parts))
    # More parts than leaves: all the leaves.
    many = labels_of(vertices, faces, shdf, replace(fine, parts=leaves + 5))
    np.testing.assert_array_equal(many, whole.tree.leaf_labels)


@pytest.mark.parametrize("creases", [True, False])
def test_without_parts_the_tree_is_cut_at_its_automatic_count(dumbbell_case, monkeypatch, creases):
    """``parts=None``: the cut where merge costs pass AUTO_COST_THRESHOLD, with and without
    boundaries on creases."""
    from neural_shdf.segment import hierarchy

    vertices, faces, shdf, graph, _ = dumbbell_case
    params = SegmentParams(smoothing=0.02, crease_boundaries=creases)
    result = details(vertices, faces, shdf, params)
    assert result.part_count == hierarchy.automatic_part_count(result.tree) > 1
    # A threshold above every merge cost leaves one part.
    monkeypatch.setattr(hierarchy.automatic_part_count, "__defaults__", (1e9,))
    assert details(vertices, faces, shdf, params).part_count == 1


def test_metis_has_no_tree(dumbbell_case):
    vertices, faces, shdf, graph, _ = dumbbell_case
    params = SegmentParams(partitioner="metis", parts=3)
    assert details(vertices, faces, shdf, params).tree is None


def test_constant_shdf_gives_one_part(dumbbell_case):
    vertices, faces, _, graph, _ = dumbbell_case
    result = details(vertices, faces, np.full(len(faces), 0.5), SegmentParams())
    assert result.clusters == 1
    np.testing.assert_array_equal(result.labels, 0)


def test_multi_shell_mesh_with_isolated_and_degenerate_faces():
    a = trimesh.creation.icosphere(3)
    b = trimesh.creation.icosphere(3, radius=0.4)
    b.apply_translation([3, 0, 0])
    far = np.array([[10.0, 0, 0], [10, 0.01, 0], [10, 0, 0.01], [20, 0, 0]])
    vertices = np.concatenate([a.vertices, b.vertices, far])
    n, m = len(a.vertices), len(b.vertices)
    extra = np.array(
        [[n + m, n + m + 1, n + m + 2], [n + m, n + m, n + m + 3]]
    )  # lone + degenerate
    faces = np.concatenate([a.faces, b.faces + n, extra])
    shdf = np.concatenate([np.full(len(a.faces), 1.0), np.full(len(b.faces), 0.3), [0.0, 0.0]])
    for params in (
        SegmentParams(),
        SegmentParams(partitioner="metis", parts=3),
        SegmentParams(refine=True, boundary_smoothing=True),
    ):
        labels = labels_of(vertices, faces, shdf, params)
        assert_canonical(labels)
        assert len(labels) == len(faces)
        # The two spheres never share a part.
        assert not set(labels[: len(a.faces)]) & set(labels[len(a.faces) : -2])
    # Graph cut: the tiny lone faces join the nearest big part instead of standing alone.
    labels = labels_of(vertices, faces, shdf, SegmentParams())
    assert labels.max() + 1 == 2


def test_empty_mesh():
    labels = labels_of(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0), SegmentParams())
    assert labels.shape == (0,)


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"partitioner": "kmeans"}, "unknown partitioner"),
        ({"clusters": -1}, "clusters must be an integer"),
        ({"clusters": 2.5}, "clusters must be an integer"),
        ({"smoothing": -1.0}, "smoothing must be a finite number"),
        ({"smoothing": float("nan")}, "smoothing must be a finite number"),
        ({"smoothing": 1e9}, "smoothing must be a finite number in \\[0, 100\\]"),
        ({"parts": 0}, "parts must be an integer in 1..10000"),
        ({"partitioner": "metis", "parts": 0}, "parts must be an integer in 1..10000"),
        ({"partitioner": "metis", "parts": 9999}, "more than the mesh's"),
        ({"partitioner": "metis", "parts": 10**9}, "parts must be an integer in 1..10000"),
        ({"seed": -1}, "seed must be"),
        ({"seed": 2**31}, "seed must be an integer in 0..2147483647"),
        ({"refine": "yes"}, "refine must be true or false"),
        ({"min_part_fraction": 1.5}, "min_part_fraction"),
        ({"refine_depth": 99}, "refine_depth"),
        ({"reference_faces": 0}, "reference_faces"),
    ],
)
def test_invalid_params_raise_parameter_error(dumbbell_case, changes, message):
    vertices, faces, shdf, graph, _ = dumbbell_case
    with pytest.raises(ParameterError, match=message):
        labels_of(vertices, faces, shdf, replace(SegmentParams(), **changes))


@pytest.mark.parametrize(
    "shdf_of, message",
    [
        (lambda n: np.zeros(n + 1), "one value per face"),
        (lambda n: np.full(n, np.nan), "non-finite"),
        (lambda n: np.full(n, 2.0), "normalised to \\[0, 1\\]"),
    ],
)
def test_invalid_shdf_raises_parameter_error(dumbbell_case, shdf_of, message):
    vertices, faces, _, graph, _ = dumbbell_case
    with pytest.raises(ParameterError, match=message):
        labels_of(vertices, faces, shdf_of(len(faces)), SegmentParams())


@pytest.mark.needs_data
@pytest.mark.parametrize("model_id", [1, 61, 361])
def test_part_count_comparable_to_cgal_on_psb(shared_data, psb_off, model_id):
    """With CGAL's own ShDF, the default graph cut finds about as many parts as CGAL."""
    from neural_shdf.segment.parts import connected_parts, merge_small_parts

    mesh = trimesh.load(psb_off(model_id), process=False)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    shdf = np.loadtxt(shared_data / "psb-dev" / "cgal" / f"{model_id}.sdf")
    cgal = np.loadtxt(shared_data / "psb-dev" / "cgal" / f"{model_id}.seg").astype(np.int64)
    graph = graph_of(vertices, faces)
    ours = labels_of(vertices, faces, shdf, SegmentParams())
    _, areas = face_normals(vertices, faces)
    cgal_parts = merge_small_parts(
        connected_parts(cgal, graph.pairs, len(faces)),
        graph,
        areas,
        np.asarray(mesh.triangles_center),
        SegmentParams().min_part_fraction,
    )
    ratio = (ours.max() + 1) / (cgal_parts.max() + 1)
    assert 0.5 <= ratio <= 2.0


@pytest.mark.parametrize("clusters", [None, AUTO_CLUSTERS])
def test_a_kept_basis_gives_the_same_labels_for_every_later_parameter(dumbbell_case, clusters):
    vertices, faces, shdf, graph, _ = dumbbell_case
    basis = basis_of(vertices, faces, shdf, SegmentParams(clusters=clusters))
    for changes in (
        {},
        {"smoothing": 0.3},
        {"smoothing": 0.0},
        {"smoothing": 5.0, "reference_faces": 1000},
        {"parts": 2},
        {"refine": True},
        {"boundary_smoothing": True},
        {"crease_boundaries": False},
        {"partitioner": "metis", "parts": 3},
    ):
        params = SegmentParams(clusters=clusters, **changes)
        kept = details(vertices, faces, shdf, params, basis=basis)
        fresh = details(vertices, faces, shdf, params)
        np.testing.assert_array_equal(kept.labels, fresh.labels, err_msg=str(changes))
        assert "prepare" not in kept.timings and "prepare" in fresh.timings


def test_a_basis_of_other_clusters_or_seed_is_refused(dumbbell_case):
    vertices, faces, shdf, graph, _ = dumbbell_case
    basis = basis_of(vertices, faces, shdf, SegmentParams(clusters=3))
    for params in (SegmentParams(clusters=4), SegmentParams(clusters=3, seed=1)):
        with pytest.raises(ValueError, match="another ShDF, clusters or seed"):
            details(vertices, faces, shdf, params, basis=basis)
    other = np.roll(shdf, 1)
    with pytest.raises(ValueError, match="another ShDF, clusters or seed"):
        details(vertices, faces, other, SegmentParams(clusters=3), basis=basis)
    assert basis.nbytes > shdf.nbytes


def test_the_same_shape_at_any_scale_gets_the_same_parts():
    # Every threshold is relative to the mesh's size: the ShDF is equal up to the rounding
    # of the scaled coordinates (exactly so at powers of two), and so are the parts.
    mesh, _ = dumbbell(3000)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    results = {}
    for scale in (1e-9, 2.0**-30, 1.0, 2.0**30, 1e9):
        scaled = TriangleMesh(vertices * scale, faces)
        shdf = compute_shdf(scaled, method="exact", seed=0).values
        results[scale] = shdf, segment(scaled, shdf, SegmentParams()).labels
    shdf, labels = results[1.0]
    assert labels.max() == 2  # two balls and the neck
    for scale, (scaled_shdf, scaled_labels) in results.items():
        np.testing.assert_array_equal(scaled_labels, labels)
        tolerance = 1e-12 if scale in (2.0**-30, 2.0**30) else 0.1
        np.testing.assert_allclose(scaled_shdf, shdf, atol=tolerance)


@pytest.mark.parametrize("partitioner", ["graphcut", "metis"])
def test_a_double_sided_export_gets_the_parts_of_the_one_sided_mesh(dumbbell_case, partitioner):
    """Every face twice, the copy reversed (a double-sided card export): the copies join
    every neighbour through non-manifold edges, so the segmentation works on one copy of
    each and gives each copy its first copy's part."""
    vertices, faces, shdf, _, _ = dumbbell_case
    params = SegmentParams(partitioner=partitioner, parts=4 if partitioner == "metis" else None)
    one_sided = details(vertices, faces, shdf, params)
    mesh = TriangleMesh(vertices, np.concatenate([faces, faces[:, ::-1]]))
    assert mesh.distinct.has_copies and mesh.distinct.mesh.face_count == len(faces)
    doubled = segment(mesh, np.tile(shdf, 2), params)
    np.testing.assert_array_equal(doubled.labels, np.tile(one_sided.labels, 2))
    if one_sided.tree is not None:
        np.testing.assert_array_equal(
            doubled.tree.leaf_labels, np.tile(one_sided.tree.leaf_labels, 2)
        )
    basis = prepare_segment(mesh, np.tile(shdf, 2), params)
    again = segment(mesh, np.tile(shdf, 2), params, basis=basis)
    np.testing.assert_array_equal(again.labels, doubled.labels)


def test_compute_shdfs_result_segments_as_its_values():
    """``segment(mesh, compute_shdf(mesh))`` works as a user writes it: the same labels as
    with ``.values``, with and without a kept basis."""
    sphere = trimesh.creation.icosphere(3)
    mesh = TriangleMesh(sphere.vertices, sphere.faces)
    result = compute_shdf(mesh)
    params = SegmentParams(parts=2)
    expected = segment(mesh, result.values, params).labels
    np.testing.assert_array_equal(segment(mesh, result, params).labels, expected)
    basis = prepare_segment(mesh, result, params)
    np.testing.assert_array_equal(segment(mesh, result, params, basis=basis).labels, expected)


@pytest.mark.parametrize("partitioner", ["graphcut", "metis"])
def test_a_file_listed_another_way_gets_the_same_parts_and_tree(dumbbell_case, partitioner):
    """The segmentation runs on the triangles in an order of their positions
    (``TriangleMesh.distinct``): the file's faces, vertices and corners in another order
    give the same parts, tree and mirror map, numbered by each file's own lowest face."""
    from tests.mesh_helpers import relisted

    vertices, faces, shdf, _, _ = dumbbell_case
    # one ball stretched and the bar bent: a shape with a frame of its own (the dumbbell's
    # symmetry leaves its frame to the world's axes, and the file's order stands)
    vertices = vertices * np.where(vertices[:, 2:] > 0, 1.2, 1.0) ** np.array([0, 0, 1])
    vertices[:, 0] += 0.05 * vertices[:, 2] ** 2
    assert not TriangleMesh(*dumbbell_case[:2]).distinct.reordered
    params = SegmentParams(
        partitioner=partitioner, parts=4 if partitioner == "metis" else None, symmetry=True
    )
    given = segment(TriangleMesh(vertices, faces), shdf, params)
    other_vertices, other_faces, origin = relisted(
        vertices, faces, np.random.default_rng(11), turn=True
    )
    other = TriangleMesh(other_vertices, other_faces)
    assert other.distinct.reordered and not other.distinct.has_copies
    listed = segment(other, shdf[origin], params)
    basis = prepare_segment(other, shdf[origin], params)
    again = segment(other, shdf[origin], params, basis=basis)
    for result in (listed, again):
        assert_canonical(result.labels)
        pairs = set(zip(given.labels[origin].tolist(), result.labels.tolist(), strict=True))
        assert len(pairs) == given.labels.max() + 1 == result.labels.max() + 1
        if given.tree is not None:
            assert_canonical(result.tree.leaf_labels)
            np.testing.assert_array_equal(result.tree.costs, given.tree.costs)
            for count in range(1, given.tree.leaf_count + 1):
                cut = set(
                    zip(
                        given.tree.labels(count)[origin].tolist(),
                        result.tree.labels(count).tolist(),
                        strict=True,
                    )
                )
                assert len(cut) == min(count, given.tree.leaf_count)
    assert given.reflection is not None and listed.reflection is not None
    # the mirror of each face, as the file numbers its faces
    position = np.empty(len(origin), dtype=np.int64)
    position[origin] = np.arange(len(origin))
    mirror = given.reflection.mirror[origin]
    np.testing.assert_array_equal(
        listed.reflection.mirror, np.where(mirror >= 0, position[np.maximum(mirror, 0)], -1)
    )
