"""Part editing on hand-made trees: each operation, order, numbering, bounds."""

from __future__ import annotations

import numpy as np
import pytest

from neural_shdf.segment.editing import (
    MAX_EDIT_OPERATIONS,
    EditError,
    FaceAdjacency,
    Grow,
    Merge,
    Paint,
    Shrink,
    Split,
    apply_edits,
    apply_label_edits,
    edit_document,
    input_face_adjacency,
    parse_edits,
)
from neural_shdf.segment.hierarchy import PartTree

# Four leaves of two faces each: node 4 = (0, 1), node 5 = (2, 3), root 6 = (4, 5).
TREE = PartTree(
    np.array([0, 0, 1, 1, 2, 2, 3, 3]),
    np.array([[0, 1], [2, 3], [4, 5]]),
    np.array([0.1, 0.2, 0.3]),
)
LEAVES = TREE.leaf_labels

# The same coarse structure over finer leaves (one per face), as a new smoothing might give.
FINE = PartTree(
    np.arange(8),
    np.array([[0, 1], [2, 3], [4, 5], [6, 7], [8, 9], [10, 11], [12, 13]]),
    np.arange(7, dtype=float),
)


# The eight faces in a row, each sharing one unit edge with the next; the edge between
# faces 2 and 3 is short.
CHAIN = FaceAdjacency(
    np.array([[i, i + 1] for i in range(7)]), np.array([1, 1, 0.05, 1, 1, 1, 1], dtype=float)
)


def edit(parts: int, *edits: dict) -> list[int]:
    return apply_edits(TREE, LEAVES, parts, list(edits)).tolist()


def test_no_edits_is_the_cut() -> None:
    for parts in range(1, 5):
        assert edit(parts) == TREE.labels(parts).tolist()


def test_grow_takes_the_parent_node() -> None:
    assert edit(4, {"op": "grow", "face": 0}) == [0, 0, 0, 0, 1, 1, 2, 2]
    assert edit(2, {"op": "grow", "face": 7}) == [0] * 8
    assert edit(1, {"op": "grow", "face": 3}) == [0] * 8  # the root: no-op


def test_shrink_splits_into_children() -> None:
    assert edit(2, {"op": "shrink", "face": 0}) == [0, 0, 1, 1, 2, 2, 2, 2]
    assert edit(1, {"op": "shrink", "face": 5}) == [0, 0, 0, 0, 1, 1, 1, 1]
    assert edit(4, {"op": "shrink", "face": 0}) == TREE.labels(4).tolist()  # a leaf: no-op


def test_merge_and_paint() -> None:
    assert edit(4, {"op": "merge", "faces": [0, 6]}) == [0, 0, 1, 1, 2, 2, 0, 0]
    assert edit(4, {"op": "merge", "faces": [0, 2, 4, 6]}) == [0] * 8
    assert edit(2, {"op": "paint", "faces": [2], "to_face": 4}) == [0, 0, 1, 0, 1, 1, 1, 1]


def test_numbering_follows_the_smallest_face() -> None:
    # Face 0 painted away: the part holding face 1 is now the one with the smallest face.
    assert edit(2, {"op": "paint", "faces": [0], "to_face": 7}) == [0, 1, 1, 1, 0, 0, 0, 0]


def test_order_matters() -> None:
    merge_then_shrink = edit(2, {"op": "merge", "faces": [0, 4]}, {"op": "shrink", "face": 0})
    shrink_then_merge = edit(2, {"op": "shrink", "face": 0}, {"op": "merge", "faces": [0, 4]})
    assert merge_then_shrink == [0, 0, 1, 1, 0, 0, 0, 0]
    assert shrink_then_merge == [0, 0, 1, 1, 0, 0, 0, 0]
    grow_then_shrink = edit(4, {"op": "grow", "face": 0}, {"op": "shrink", "face": 2})
    assert grow_then_shrink == [0, 0, 1, 1, 2, 2, 3, 3]
    paint_then_merge = edit(
        4, {"op": "paint", "faces": [2], "to_face": 4}, {"op": "merge", "faces": [0, 2]}
    )
    merge_then_paint = edit(
        4, {"op": "merge", "faces": [0, 2]}, {"op": "paint", "faces": [2], "to_face": 4}
    )
    assert paint_then_merge == [0, 0, 0, 1, 0, 0, 2, 2]
    assert merge_then_paint == [0, 0, 1, 0, 1, 1, 2, 2]


def test_grow_absorbs_whole_parts_and_splits_partial_ones() -> None:
    # Leaves 1 and 3 merged; growing leaf 0 takes leaf 1 but the merged part keeps leaf 3.
    assert edit(4, {"op": "merge", "faces": [2, 6]}, {"op": "grow", "face": 0}) == [
        0, 0, 0, 0, 1, 1, 2, 2,
    ]  # fmt: skip
    # Face 4 painted into leaf 1's part: leaf 1's part joins the grown part with it.
    assert edit(4, {"op": "paint", "faces": [4], "to_face": 2}, {"op": "grow", "face": 0}) == [
        0, 0, 0, 0, 0, 1, 2, 2,
    ]  # fmt: skip


def test_paint_persists_and_grow_uses_the_faces_node() -> None:
    # Face 0 painted into leaf 2's part stays there when leaf 1 grows over leaf 0.
    assert edit(4, {"op": "paint", "faces": [0], "to_face": 4}, {"op": "grow", "face": 2}) == [
        0, 1, 1, 1, 0, 0, 2, 2,
    ]  # fmt: skip
    # Growing from a painted face grows the tree node it lies in (leaf 0), not its part.
    assert edit(4, {"op": "paint", "faces": [0], "to_face": 6}, {"op": "grow", "face": 0}) == [
        0, 1, 1, 1, 2, 2, 0, 0,
    ]  # fmt: skip


def test_faces_without_triangles_stay_unlabelled() -> None:
    leaves = np.array([0, -1, 1, 1, 2, 2, 3, 3])
    labels = apply_edits(TREE, leaves, 4, [{"op": "merge", "faces": [0, 2]}])
    assert labels.tolist() == [0, -1, 0, 0, 1, 1, 2, 2]
    with pytest.raises(EditError, match="face 1 has no triangles"):
        apply_edits(TREE, leaves, 4, [{"op": "grow", "face": 1}])


def test_survives_a_finer_tree_where_it_applies() -> None:
    document = [
        {"op": "grow", "face": 0},
        {"op": "merge", "faces": [0, 7]},
        {"op": "paint", "faces": [5], "to_face": 1},
    ]
    assert FINE.labels(4).tolist() == TREE.labels(4).tolist()
    coarse = apply_edits(TREE, LEAVES, 4, document)
    fine = apply_edits(FINE, FINE.leaf_labels, 4, document)
    assert coarse.tolist() == fine.tolist() == [0, 0, 0, 0, 1, 0, 0, 0]


def test_random_trees_match_the_cut_and_are_deterministic() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        leaves = int(rng.integers(1, 30))
        alive = list(range(leaves))
        merges = []
        for node in range(leaves, 2 * leaves - 1):
            a, b = sorted(rng.choice(len(alive), 2, replace=False).tolist(), reverse=True)
            pair = sorted((alive.pop(a), alive.pop(b)))
            merges.append(pair)
            alive.append(node)
        faces = np.concatenate([np.arange(leaves), rng.integers(0, leaves, 40)])
        tree = PartTree(
            faces, np.array(merges, dtype=np.int64).reshape(-1, 2), np.zeros(leaves - 1)
        )
        parts = int(rng.integers(1, leaves + 1))
        assert apply_edits(tree, faces, parts, []).tolist() == tree.labels(parts).tolist()
        document = [
            {"op": str(rng.choice(["grow", "shrink"])), "face": int(rng.integers(0, len(faces)))}
            for _ in range(5)
        ]
        once = apply_edits(tree, faces, parts, document)
        assert once.tolist() == apply_edits(tree, faces, parts, document).tolist()
        # Every part is still a union of leaves after grow and shrink alone.
        assert all(len(set(once[faces == leaf].tolist())) == 1 for leaf in range(leaves))


@pytest.mark.parametrize(
    ("document", "message"),
    [
        ([{"op": "cut", "face": 0}], "unknown op 'cut'"),
        ([{"op": "split", "face": 0}], "'split' needs the mesh's face adjacency"),
        ([{"op": "grow"}], "'grow' takes exactly"),
        ([{"op": "grow", "face": 8}], "face 8 is out of range .* 8 input faces"),
        ([{"op": "merge", "faces": [0, -1]}], "face -1 is out of range"),
        ([{"op": "merge", "faces": []}], "non-empty list"),
        ([{"op": "paint", "faces": [0], "to_face": 1.5}], "must be an integer"),
        ([{"op": "grow", "face": True}], "must be an integer"),
        (["grow"], "expected an object"),
        ([{"op": "grow", "face": 0}] * (MAX_EDIT_OPERATIONS + 1), "at most 1000 edit operations"),
    ],
)
def test_bad_documents_say_what_is_wrong(document: list, message: str) -> None:
    with pytest.raises(EditError, match=message):
        edit(2, *document)


def test_typed_operations_round_trip() -> None:
    typed = [Grow(0), Shrink(1), Merge((0, 2)), Paint((3,), 5), Split(4)]
    assert parse_edits(edit_document(typed)) == typed
    assert apply_edits(TREE, LEAVES, 2, edit_document(typed), CHAIN).tolist() == (
        apply_edits(TREE, LEAVES, 2, typed, CHAIN).tolist()
    )


def test_label_edits_without_a_tree() -> None:
    labels = np.array([2, 2, 0, 0, -1, 1])
    merged = apply_label_edits(labels, [{"op": "merge", "faces": [0, 5]}])
    assert merged.tolist() == [0, 0, 1, 1, -1, 0]
    painted = apply_label_edits(labels, [{"op": "paint", "faces": [1], "to_face": 2}])
    assert painted.tolist() == [0, 1, 1, 1, -1, 2]
    with pytest.raises(EditError, match="'grow' needs the part tree.*METIS"):
        apply_label_edits(labels, [{"op": "grow", "face": 0}])


def test_split_bisects_the_part_along_its_shortest_boundary() -> None:
    whole = apply_edits(TREE, LEAVES, 1, [{"op": "split", "face": 0}], CHAIN)
    assert whole.tolist() == [0, 0, 0, 1, 1, 1, 1, 1]  # cut at the short edge
    kept = apply_edits(TREE, LEAVES, 1, [{"op": "split", "face": 7}], CHAIN)
    assert kept.tolist() == whole.tolist()  # numbered by smallest face either way
    # The adjacency is built only when a split asks for it.
    built: list[int] = []

    def lazily() -> FaceAdjacency:
        built.append(1)
        return CHAIN

    assert apply_edits(TREE, LEAVES, 2, [{"op": "grow", "face": 0}], lazily).tolist() == [0] * 8
    assert built == []
    apply_edits(TREE, LEAVES, 1, [{"op": "split", "face": 0}], lazily)
    assert built == [1]


def test_split_acts_on_parts_as_they_are_and_its_halves_stay_painted() -> None:
    document = [{"op": "merge", "faces": [0, 6]}, {"op": "split", "face": 6}]
    # Parts at 4: {0,1}, {2,3}, {4,5}, {6,7}; merged {0,1,6,7}; its faces 0-1 and 6-7 are
    # not adjacent, so the halves are those two pieces.
    assert apply_edits(TREE, LEAVES, 4, document, CHAIN).tolist() == [0, 0, 1, 1, 2, 2, 3, 3]
    # Parts at 2: {0..3} and {4..7}; the split cuts face 3 off {0..3} (the short edge). A
    # later grow of the node holding face 0 (to the root) takes {4..7} in, not face 3.
    grown = apply_edits(
        TREE, LEAVES, 2, [{"op": "split", "face": 0}, {"op": "grow", "face": 0}], CHAIN
    )
    assert grown.tolist() == [0, 0, 0, 1, 0, 0, 0, 0]
    # A one-face part: no-op.
    assert apply_edits(FINE, np.arange(8), 8, [{"op": "split", "face": 3}], CHAIN).tolist() == (
        list(range(8))
    )


def test_split_without_a_tree_and_deterministic() -> None:
    labels = np.array([0, 0, 0, 0, 0, 0, 0, 0])
    once = apply_label_edits(labels, [{"op": "split", "face": 0}], CHAIN, seed=3)
    assert once.tolist() == [0, 0, 0, 1, 1, 1, 1, 1]
    assert once.tolist() == apply_label_edits(labels, [Split(0)], CHAIN, seed=3).tolist()


def test_input_face_adjacency_sums_shared_edges_and_drops_polygon_diagonals() -> None:
    # Triangles 0-1 form input face 0 (a quad), 2 is face 1, 3 is face 2.
    origin = np.array([0, 0, 1, 2])
    pairs = np.array([[0, 1], [1, 2], [0, 2], [2, 3], [3, 1]])
    length = np.array([9.0, 1.0, 2.0, 4.0, 0.5])
    adjacency = input_face_adjacency(pairs, length, origin)
    assert adjacency.pairs.tolist() == [[0, 1], [0, 2], [1, 2]]
    assert adjacency.length.tolist() == [3.0, 0.5, 4.0]
