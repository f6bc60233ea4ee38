"""The merge tree: structure, nested cuts, the client's relabelling recipe, what merges first."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from neural_shdf.geometry import (
    build_face_graph,
    face_normals,
    weld_faces,
)
from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.segment import SegmentParams
from neural_shdf.segment.hierarchy import (
    MergeCost,
    PartTree,
    automatic_part_count,
    boundary_profile,
    merge_tree,
)
from neural_shdf.segment.parts import FaceData, canonical_labels, connected_parts, cut_edges
from neural_shdf.segment.synthetic import JUNCTION_Z, dumbbell, split_top
from neural_shdf.shdf.postprocess import log_normalize
from tests.mesh_helpers import ball_with_arm


def graph_and_surface(vertices, faces):
    """The face graph and ``FaceData`` of a mesh (the segmentation's inputs to the tree)."""
    normals, areas = face_normals(vertices, faces)
    graph = build_face_graph(vertices, weld_faces(vertices, faces), normals)
    return graph, FaceData.of(vertices, faces, (normals, areas))


@pytest.fixture(scope="module")
def dumbbell_leaves():
    """A dumbbell over-segmented into 8 leaves: each ball and the neck cut by flat planes."""
    mesh, shdf = dumbbell(6000)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    graph, surface = graph_and_surface(vertices, faces)
    centre = mesh.triangles_center
    z = centre[:, 2]
    region = np.where(z < -JUNCTION_Z, 0, np.where(z > JUNCTION_Z, 2, 1))
    # Flat cuts: each ball split by x = 0 and by its equator, the neck at z = 0.
    pieces = region * 4 + (centre[:, 0] > 0) * 2 + (np.abs(z) > 2.0) * (region != 1)
    pieces = np.where(region == 1, 4 + (z > 0), pieces)
    leaves = connected_parts(pieces, graph.pairs, len(faces))
    return leaves, graph, surface, log_normalize(shdf), region


def relabel_like_a_client(tree: PartTree, count: int) -> np.ndarray:
    """The recipe the API documents: climb while the parent's id is below 2L - count."""
    leaves = tree.leaf_count
    parent = tree.parent
    top = np.empty(leaves, dtype=np.int64)
    for leaf in range(leaves):
        node = leaf
        while parent[node] != -1 and parent[node] < 2 * leaves - count:
            node = parent[node]
        top[leaf] = node
    return canonical_labels(top[tree.leaf_labels])


def test_tree_structure(dumbbell_leaves):
    leaves, graph, surface, values, _ = dumbbell_leaves
    tree = merge_tree(leaves, graph, surface, values)
    count = int(leaves.max()) + 1
    assert count >= 8
    assert tree.leaf_count == count
    assert tree.merges.shape == (count - 1, 2)
    # Every node but the root is merged exactly once, and only after it exists.
    merged = tree.merges.reshape(-1)
    assert sorted(merged.tolist()) == list(range(2 * count - 2))
    for i, (a, b) in enumerate(tree.merges):
        assert a < b < count + i
    parent = tree.parent
    assert parent[-1] == -1 and np.all(parent[:-1] >= count)
    assert np.all(np.diff(tree.heights) >= 0)
    assert np.all(tree.costs >= 0)


def test_cuts_are_nested_and_canonical(dumbbell_leaves):
    leaves, graph, surface, values, _ = dumbbell_leaves
    tree = merge_tree(leaves, graph, surface, values)
    count = tree.leaf_count
    assert np.array_equal(tree.labels(count), leaves)
    assert np.all(tree.labels(1) == 0)
    previous = tree.labels(1)
    for parts in range(2, count + 1):
        labels = tree.labels(parts)
        assert labels.max() + 1 == parts
        assert np.array_equal(labels, canonical_labels(labels))
        # Each part at N lies inside one part at N - 1.
        pairs = np.unique(np.stack([labels, previous], axis=1), axis=0)
        assert len(pairs) == parts
        previous = labels
    # Out-of-range counts clamp to 1..L.
    assert np.array_equal(tree.labels(10 * count), leaves)
    assert np.all(tree.labels(0) == 0)


def test_the_documented_client_recipe_gives_the_same_cuts(dumbbell_leaves):
    leaves, graph, surface, values, _ = dumbbell_leaves
    tree = merge_tree(leaves, graph, surface, values)
    for parts in range(1, tree.leaf_count + 1):
        assert np.array_equal(relabel_like_a_client(tree, parts), tree.labels(parts))


def test_flat_cuts_merge_before_the_creases_between_balls_and_neck(dumbbell_leaves):
    leaves, graph, surface, values, region = dumbbell_leaves
    tree = merge_tree(leaves, graph, surface, values)
    labels = tree.labels(3)
    for part in range(3):
        inside = region[labels == part]
        assert np.all(inside == inside[0])
    assert automatic_part_count(tree) == 3


def test_deterministic_and_independent_of_leaf_numbering(dumbbell_leaves):
    leaves, graph, surface, values, _ = dumbbell_leaves
    first = merge_tree(leaves, graph, surface, values)
    again = merge_tree(leaves.copy(), graph, surface, values)
    assert np.array_equal(first.merges, again.merges)
    assert np.array_equal(first.costs, again.costs)


def loop_subdivided(vertices, faces, passes):
    """Loop subdivision and the input face of each new face (trimesh writes face i's four
    children at rows 4i..4i+3)."""
    fine_vertices, fine_faces = trimesh.remesh.subdivide_loop(vertices, faces, iterations=passes)
    return fine_vertices, fine_faces, np.arange(len(fine_faces)) // 4**passes


def post_on_a_disc(spacing: float, fillet: float = 0.2) -> trimesh.Trimesh:
    """A post (radius 0.3) standing on a disc (radius 1.5, 0.3 thick), the concave corner
    between them rounded with radius ``fillet`` (0: sharp), revolved from a profile
    sampled every ``spacing``: the same surface at any tessellation."""

    def line(start, end):
        start, end = np.asarray(start, float), np.asarray(end, float)
        steps = max(1, int(np.ceil(np.linalg.norm(end - start) / spacing)))
        return start + np.linspace(0.0, 1.0, steps + 1)[:-1, None] * (end - start)

    corner = np.array([(0.3 + fillet, 0.3)])
    if fillet > 0:
        turn = np.linspace(1.5 * np.pi, np.pi, int(np.ceil(fillet * np.pi / 2 / spacing)) + 1)
        corner = 0.3 + fillet + fillet * np.stack([np.cos(turn), np.sin(turn)], axis=1)
    profile = np.concatenate(
        [
            line((0.0, 0.0), (1.5, 0.0)),
            line((1.5, 0.0), (1.5, 0.3)),
            line((1.5, 0.3), corner[0]),
            corner[:-1],
            line((0.3, 0.3 + fillet), (0.3, 2.0)),
            line((0.3, 2.0), (0.0, 2.0)),
            [(0.0, 2.0)],
        ]
    )
    return trimesh.creation.revolve(profile, sections=int(np.ceil(3 * np.pi / spacing)))


def folds_between(mesh: trimesh.Trimesh, leaves: np.ndarray) -> np.ndarray:
    """``boundary_profile``'s folds across every cut between the two leaves of ``mesh``."""
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    graph, surface = graph_and_surface(vertices, faces)
    pairs = graph.pairs[cut_edges(leaves, graph.pairs, 2)[0]]
    assert len(pairs)
    return boundary_profile(pairs, leaves, surface, np.zeros(len(faces))).folds


def post_and_disc(mesh: trimesh.Trimesh, height: float) -> np.ndarray:
    """Leaves: the faces above ``height`` (the post), the rest (the disc)."""
    return (mesh.triangles_center[:, 2] > height).astype(np.int64)


def test_a_rounded_crease_folds_alike_at_any_tessellation():
    """Per edge, a rounded crease folds by its turn over the edges across it: along these
    cuts 0.125, 0.071, 0.038 of pi at 9k, 37k, 148k faces, or 0 where a cut runs along
    the quads' flat diagonals. Read at the surface's scale it folds 0.20-0.25 at any
    tessellation, wherever the cut crosses it."""
    coarse, fine = (post_on_a_disc(spacing) for spacing in (0.1, 0.025))
    assert len(fine.faces) > 10 * len(coarse.faces)
    for height in (0.35, 0.4, 0.45):
        at_coarse = folds_between(coarse, post_and_disc(coarse, height)).mean()
        assert 0.15 < at_coarse < 0.45
        fine_folds = folds_between(fine, post_and_disc(fine, height))
        assert fine_folds.mean() == pytest.approx(at_coarse, rel=0.1)


def test_a_sharp_concave_corner_folds_a_right_angle_and_a_convex_rim_none():
    mesh = post_on_a_disc(0.05, fillet=0.0)
    assert mesh.is_watertight and mesh.volume > 0
    np.testing.assert_allclose(folds_between(mesh, post_and_disc(mesh, 0.3)), 0.5, atol=0.02)
    centre = mesh.triangles_center
    rim = (np.hypot(centre[:, 0], centre[:, 1]) > 1.45).astype(np.int64)  # the disc's edge
    assert np.all(folds_between(mesh, rim) == 0.0)
    inside_out = trimesh.Trimesh(mesh.vertices, mesh.faces[:, ::-1], process=False)
    assert np.all(folds_between(inside_out, post_and_disc(mesh, 0.3)) == 0.0)  # convex now


def test_folds_follow_the_surface_not_its_pose():
    mesh = post_on_a_disc(0.05)
    mesh.vertices[:, 0] *= 0.8  # an elliptic disc: principal axes of its own
    leaves = post_and_disc(mesh, 0.4)
    rotation = trimesh.transformations.random_rotation_matrix(np.random.default_rng(3).random(3))
    moved = mesh.copy()
    moved.apply_transform(rotation)
    moved.apply_scale(1000.0)
    moved.apply_translation([5e3, -2e3, 7e3])
    np.testing.assert_allclose(folds_between(moved, leaves), folds_between(mesh, leaves), atol=1e-9)


def test_a_finely_split_detail_costs_what_the_unsplit_mesh_costs():
    """The top fifth of a dumbbell split 1-to-36 (6x the faces, the same surface and
    creases): its merges cost what the unsplit mesh's do."""
    mesh, shdf = dumbbell(3000)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    split_vertices, split_faces, parent = split_top(mesh, 6)
    assert len(split_faces) > 5 * len(faces)
    z = mesh.triangles_center[:, 2]
    regions = np.where(z < -JUNCTION_Z, 0, np.where(z > JUNCTION_Z, 2, 1))
    values = log_normalize(shdf)
    coarse = merge_tree(regions, *graph_and_surface(vertices, faces), values).costs
    split_graph, split_surface = graph_and_surface(split_vertices, split_faces)
    split = merge_tree(regions[parent], split_graph, split_surface, values[parent]).costs
    np.testing.assert_allclose(split, coarse, rtol=2e-3)


def ramp_and_step(mesh: trimesh.Trimesh, height: float) -> tuple[np.ndarray, np.ndarray]:
    """Two ShDF fields on ``mesh`` with the same means in each leaf of ``post_and_disc``:
    a slow ramp with height, and the step between those means at the cut."""
    leaves = post_and_disc(mesh, height)
    ramp = mesh.triangles_center[:, 2] / 2.0
    area = mesh.area_faces
    means = np.bincount(leaves, area * ramp) / np.bincount(leaves, area)
    return ramp, means[leaves]


def test_a_cut_through_a_slow_gradient_steps_less_than_a_cut_at_a_step():
    """The ShDF's step across a boundary, read at the surface's scale: a ramp cut anywhere
    steps about its slope over a few cells, at any tessellation; a step field steps its
    full height."""
    for height in (0.8, 1.2):
        per_spacing = []
        for spacing in (0.1, 0.025):
            mesh = post_on_a_disc(spacing)
            vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
            graph, surface = graph_and_surface(vertices, faces)
            leaves = post_and_disc(mesh, height)
            pairs = graph.pairs[cut_edges(leaves, graph.pairs, 2)[0]]
            ramp, step = ramp_and_step(mesh, height)
            ramp_steps = boundary_profile(pairs, leaves, surface, ramp).steps
            step_steps = boundary_profile(pairs, leaves, surface, step).steps
            np.testing.assert_allclose(step_steps, np.ptp(step), rtol=1e-9)
            assert ramp_steps.max() < 0.15 * np.ptp(step)
            per_spacing.append(ramp_steps.mean())
        assert per_spacing[1] == pytest.approx(per_spacing[0], rel=0.35)


def test_faces_larger_than_the_cells_read_their_own_step():
    """A box of 12 triangles: no centroid lies in the cells around its edges' midpoints,
    so each side of a pair reads its own face (before, the step read 0 and a coarse
    dumbbell's boxes merged with its bar)."""
    box = trimesh.creation.box()
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces)
    graph, surface = graph_and_surface(vertices, faces)
    leaves = (box.triangles_center[:, 2] > 0.49).astype(np.int64)  # the top
    pairs = graph.pairs[cut_edges(leaves, graph.pairs, 2)[0]]
    profile = boundary_profile(pairs, leaves, surface, leaves * 0.7)
    np.testing.assert_allclose(profile.steps, 0.7)
    np.testing.assert_array_equal(profile.folds, 0.0)  # convex edges


def test_a_slow_gradient_merges_cheaper_than_a_step_of_the_same_means():
    mesh = post_on_a_disc(0.05)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    graph, surface = graph_and_surface(vertices, faces)
    leaves = post_and_disc(mesh, 1.0)
    ramp, step = ramp_and_step(mesh, 1.0)
    at_ramp = merge_tree(leaves, graph, surface, ramp).costs[0]
    at_step = merge_tree(leaves, graph, surface, step).costs[0]
    means_only = merge_tree(leaves, graph, surface, ramp, MergeCost(step_exponent=0.0)).costs[0]
    assert at_step == pytest.approx(means_only, rel=1e-9)  # the step is the means' difference
    assert at_ramp < 0.6 * at_step


def test_cost_prefers_small_similar_parts_across_flat_wide_boundaries():
    cost = MergeCost()
    base = dict(area_a=1.0, area_b=4.0, mean_a=0.5, mean_b=0.5, boundary=2.0, concave=0.0,
                total_area=10.0)  # fmt: skip
    reference = cost(**base)
    assert cost(**{**base, "area_a": 0.1}) < reference  # smaller
    assert cost(**{**base, "mean_a": 0.8}) > reference  # thicker or thinner
    assert cost(**{**base, "concave": 1.0}) > reference  # along a crease
    assert cost(**{**base, "boundary": 0.5}) > reference  # a narrow neck
    # A difference that changes where the parts meet weighs fully, a gradient's less.
    assert cost(**{**base, "mean_a": 0.8, "step": 1.2}) == cost(**{**base, "mean_a": 0.8})
    assert cost(**{**base, "mean_a": 0.8, "step": 0.2}) < cost(**{**base, "mean_a": 0.8})


def test_separate_shells_still_make_one_tree():
    spheres = [trimesh.creation.icosphere(2, radius=r).apply_translation([3 * i, 0, 0])
               for i, r in enumerate((1.0, 0.5, 0.8))]  # fmt: skip
    mesh = trimesh.util.concatenate(spheres)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    graph, surface = graph_and_surface(vertices, faces)
    leaves = connected_parts(np.zeros(len(faces), dtype=np.int64), graph.pairs, len(faces))
    assert leaves.max() == 2
    values = np.repeat([0.9, 0.1, 0.6], len(faces) // 3)
    tree = merge_tree(leaves, graph, surface, values)
    assert tree.leaf_count == 3 and tree.parent[-1] == -1
    # The smallest shell (0.5) joins the one of nearest ShDF (0.8 -> 0.6) first.
    assert tree.merges[0].tolist() == [1, 2]
    assert np.all(tree.costs > 0)


def tetrahedra(count: int, scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``count`` separate tetrahedra on a line, tetrahedron i scaled by ``scales[i]``."""
    corner = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    vertices = corner[None] * scales[:, None, None]
    vertices[:, :, 0] += 3.0 * np.arange(count)[:, None]
    triangles = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return vertices.reshape(-1, 3), (triangles[None] + 4 * np.arange(count)[:, None, None]).reshape(
        -1, 3
    )


def reference_shell_merges(area: np.ndarray, moment: np.ndarray) -> list[list[int]]:
    """The shell rule written plainly (quadratic): smallest part (then lowest id) into the
    part of nearest mean (then lowest id)."""
    area, moment = list(area), list(moment)
    alive = set(range(len(area)))
    merges = []
    while len(alive) > 1:

        def mean(node):
            return moment[node] / area[node] if area[node] > 0 else 0.0

        smallest = min(alive, key=lambda n: (area[n], n))
        target = min(alive - {smallest}, key=lambda n: (abs(mean(n) - mean(smallest)), n))
        merges.append(sorted([smallest, target]))
        alive -= {smallest, target}
        alive.add(len(area))
        area.append(area[smallest] + area[target])
        moment.append(moment[smallest] + moment[target])
    return merges


@pytest.mark.parametrize("case", ["random", "equal", "few values", "rounding ties"])
def test_shells_merge_in_the_order_of_the_plain_rule(case):
    rng = np.random.default_rng(7)
    count = 300
    scales = {"random": 1 + rng.random(count), "equal": np.ones(count)}.get(
        case, rng.choice([1.0, 2.0], count)
    )
    vertices, faces = tetrahedra(count, scales)
    graph, surface = graph_and_surface(vertices, faces)
    if case == "random":
        shell_values = rng.random(count)
    elif case == "equal":
        shell_values = np.full(count, 0.3)
    elif case == "few values":
        shell_values = rng.choice([0.125, 0.25, 0.5, 0.75, 0.875], count)
    else:  # means one ulp apart, whose gaps to a far centre round to the same value
        shell_values = np.where(
            rng.random(count) < 0.3, 0.75, 0.1 + rng.integers(0, 4, count) * np.spacing(0.1)
        )
    values = np.repeat(shell_values, 4)
    leaves = np.repeat(np.arange(count), 4)
    tree = merge_tree(leaves, graph, surface, values)
    area = np.bincount(leaves, weights=surface.areas)
    moment = np.bincount(leaves, weights=surface.areas * values)
    assert tree.merges.tolist() == reference_shell_merges(area, moment)


def test_twenty_thousand_shells_make_one_tree():
    count = 20_000
    vertices, faces = tetrahedra(count, 1 + np.random.default_rng(0).random(count))
    graph, surface = graph_and_surface(vertices, faces)
    leaves = connected_parts(np.zeros(len(faces), dtype=np.int64), graph.pairs, len(faces))
    tree = merge_tree(leaves, graph, surface, np.full(len(faces), 0.5))
    assert tree.leaf_count == count and tree.parent[-1] == -1
    assert len(np.unique(tree.merges)) == 2 * count - 2
    assert np.array_equal(tree.labels(count), leaves)
    assert np.all(tree.labels(1) == 0)


def test_a_single_leaf_and_an_empty_mesh():
    mesh = trimesh.creation.icosphere(1)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    graph, surface = graph_and_surface(vertices, faces)
    tree = merge_tree(
        np.zeros(len(faces), dtype=np.int64), graph, surface, np.full(len(faces), 0.5)
    )
    assert tree.leaf_count == 1 and len(tree.merges) == 0
    assert np.all(tree.labels(5) == 0)
    assert automatic_part_count(tree) == 1
    assert tree.parent.tolist() == [-1]


def test_from_parent_rebuilds_the_tree_and_its_cuts(dumbbell_leaves):
    leaves, graph, surface, values, _ = dumbbell_leaves
    tree = merge_tree(leaves, graph, surface, values)
    rebuilt = PartTree.from_parent(tree.leaf_labels, tree.parent, tree.costs)
    np.testing.assert_array_equal(rebuilt.merges, tree.merges)
    np.testing.assert_array_equal(rebuilt.costs, tree.costs)
    for count in range(1, tree.leaf_count + 1):
        np.testing.assert_array_equal(rebuilt.labels(count), tree.labels(count))
    single = PartTree.from_parent([0, 0], [-1], [])
    assert single.leaf_count == 1 and single.labels(3).tolist() == [0, 0]


@pytest.mark.parametrize(
    "parent",
    [[2, 2, 3, -1], [2, 2, -1, 4, -1], [3, 3, 3, 4, -1], [4, 3, 4, 4, -1], [2, 1, -1]],
)
def test_from_parent_refuses_what_is_not_a_merge_tree(parent):
    with pytest.raises(ValueError, match="not a merge tree"):
        PartTree.from_parent([0], parent, [0.0] * (len(parent) // 2))


def test_mirror_merges_are_made_together_at_one_cost():
    """A bar cut into 5 leaves symmetric about x = 0: with ``mirror_leaf`` each merge is
    followed at once by its mirror merge, at the same cost, so every cut of the tree that
    does not fall between the two is a mirror image; without it, greedy merging made the
    second merge of a pair at another cost."""
    box = trimesh.creation.box([10.0, 1.0, 1.0])
    vertices, faces = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, 0.25)
    vertices, faces = np.asarray(vertices), np.asarray(faces)
    graph, surface = graph_and_surface(vertices, faces)
    x = vertices[faces].mean(axis=1)[:, 0]
    band = np.searchsorted([-2.5, -0.5, 0.5, 2.5], x)  # 0 1 2 3 4 along x
    leaves = canonical_labels(band)
    values = np.array([0.5, 0.52, 0.55, 0.52, 0.5])[band]
    mirror_band = {0: 4, 1: 3, 2: 2, 3: 1, 4: 0}
    mirror_leaf = np.array(
        [leaves[band == mirror_band[int(band[leaves == leaf][0])]][0] for leaf in range(5)]
    )
    plain = merge_tree(leaves, graph, surface, values)
    paired = merge_tree(leaves, graph, surface, values, mirror_leaf=mirror_leaf)
    assert plain.costs[0] != plain.costs[1]
    assert paired.costs[0] == paired.costs[1] and paired.costs[2] == paired.costs[3]
    for count in (1, 3, 5):  # counts between the two merges of no pair
        labels = paired.labels(count)
        for leaf in range(5):  # a leaf's mirror leaf is in its part's mirror part
            own, image = labels[leaves == leaf][0], labels[leaves == mirror_leaf[leaf]][0]
            for other in range(5):
                same = labels[leaves == other][0] == own
                assert same == (labels[leaves == mirror_leaf[other]][0] == image)


def test_a_hole_on_a_boundary_does_not_make_its_merge_dearer():
    """A hole where an arm meets a ball took part of their shared boundary: a narrower neck
    and a merge 1.7 times dearer (holes kept extra parts). The fan over the hole counts as
    boundary (``stitching.cap_spokes``): the merge costs about what it did closed."""
    vertices, faces = ball_with_arm()
    closed = TriangleMesh(vertices, faces)
    centroids = closed.centroids
    kept = np.linalg.norm(centroids - np.array([0.97, 0.0, 0.25]), axis=1) >= 0.2
    holed = TriangleMesh(vertices, faces[kept])
    assert holed.diagnostics.boundary_loops == 1
    costs = []
    for mesh in (closed, holed):
        shdf = compute_shdf(mesh, method="exact", seed=0).values
        result = segment(mesh, shdf, SegmentParams())
        assert result.part_count == 2
        costs.append(result.tree.costs.max())
    assert 0.6 < costs[1] / costs[0] < 1.3  # 0.76; 1.73 before


def test_a_tree_listed_by_another_order_of_its_faces_is_the_same_tree():
    """``listed_by``: the leaves numbered again by their lowest face in the new order, the
    merges and costs the same tree's (every cut the same partition), and back again."""
    tree = PartTree(
        leaf_labels=np.array([0, 0, 1, 2, 2, 3, 1, 3]),
        merges=np.array([[0, 1], [2, 3], [4, 5]]),
        costs=np.array([0.1, 0.2, 0.3]),
    )
    order = np.array([5, 3, 0, 7, 2, 6, 1, 4])
    listed = tree.listed_by(tree.leaf_labels[order])
    assert listed.leaf_labels.tolist() == [0, 1, 2, 0, 3, 3, 2, 1]
    np.testing.assert_array_equal(listed.costs, tree.costs)
    assert (listed.merges[:, 0] < listed.merges[:, 1]).all()
    for count in range(1, 5):
        given, moved = tree.labels(count)[order].tolist(), listed.labels(count).tolist()
        pairs = set(zip(given, moved, strict=True))
        assert len(pairs) == count
        assert listed.labels(count).tolist() == canonical_labels(listed.labels(count)).tolist()
    back = np.argsort(order)
    again = listed.listed_by(listed.leaf_labels[back])
    np.testing.assert_array_equal(again.leaf_labels, tree.leaf_labels)
    np.testing.assert_array_equal(again.merges, tree.merges)
