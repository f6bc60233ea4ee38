"""Part editing: a small document of operations that turns a cut of the part tree into
edited labels.

The document refers to **input faces**, never to tree node ids, so it still applies to a
re-segmentation (new smoothing, new tree) wherever its faces still mean something. The
operations run in order on the parts of the tree cut at ``parts``:

* ``{"op": "grow", "face": F}``: the tree node of the cut that holds F becomes its parent
  node. Every part lying wholly inside the parent joins the grown part (with the faces
  painted into it); a part only partly inside gives up its nodes there. No-op at the root.
* ``{"op": "shrink", "face": F}``: the tree node of the cut that holds F is replaced by its
  two children; the child holding F stays in F's part, the other is a new part. No-op at
  a leaf.
* ``{"op": "merge", "faces": [F1, F2, ...]}``: the parts holding these faces become one.
* ``{"op": "paint", "faces": [...], "to_face": G}``: these faces join the part holding G.
* ``{"op": "split", "face": F}``: the part holding F is cut in two halves of similar face
  count with the shortest boundary (a METIS bisection of its faces' adjacency); the half
  holding F stays in F's part, the other becomes a new part (its faces count as painted
  there). No-op for a one-face part.

Grow and shrink act on the tree: the node that holds F is the one its leaf lies under,
even when F was painted into another part (paint moves a face, not its node). Merge and
paint (and split) act on the parts as they are, paint included. A painted face stays where
it was painted until it is painted again.

Final labels are numbered by each part's smallest input face; faces without a leaf (-1:
no triangles) stay -1. Without a tree (METIS), merge, paint and split apply.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import ParameterError
from neural_shdf.segment.hierarchy import PartTree
from neural_shdf.segment.metis import split_graph

#: Most operations in one document.
MAX_EDIT_OPERATIONS = 1000
#: Most faces named in one document (all operations together).
MAX_EDIT_FACES = 1_000_000
#: The operations a document may hold.
EDIT_OPERATIONS = ("grow", "shrink", "merge", "paint", "split")


class EditError(ParameterError):
    """An edit document that is malformed or does not fit the mesh or its segmentation."""


@dataclass(frozen=True)
class Grow:
    """The tree node holding ``face`` becomes its parent."""

    face: int


@dataclass(frozen=True)
class Shrink:
    """The tree node holding ``face`` is replaced by its two children."""

    face: int


@dataclass(frozen=True)
class Merge:
    """The parts holding ``faces`` become one."""

    faces: tuple[int, ...]


@dataclass(frozen=True)
class Paint:
    """``faces`` join the part holding ``to_face``."""

    faces: tuple[int, ...]
    to_face: int


@dataclass(frozen=True)
class Split:
    """The part holding ``face`` is bisected; the half without ``face`` is a new part."""

    face: int


Edit = Grow | Shrink | Merge | Paint | Split


@dataclass(frozen=True)
class FaceAdjacency:
    """Input faces that share an edge: ``pairs`` (E, 2), each pair once with a < b, and
    the total ``length`` of the edges they share. What ``split`` bisects."""

    pairs: NDArray[np.int64]
    length: NDArray[np.float64]


def input_face_adjacency(
    triangle_pairs: NDArray[Any], edge_length: NDArray[Any], face_origin: NDArray[Any]
) -> FaceAdjacency:
    """The adjacency of input faces from their triangles' face graph (``FaceGraph.pairs``
    and ``edge_length``) and each triangle's input face; edges inside a polygon drop out."""
    pairs = np.asarray(face_origin, dtype=np.int64)[np.asarray(triangle_pairs, dtype=np.int64)]
    pairs = np.sort(pairs.reshape(-1, 2), axis=1)
    between = pairs[:, 0] != pairs[:, 1]
    pairs, length = pairs[between], np.asarray(edge_length, dtype=np.float64)[between]
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    total = np.bincount(inverse.reshape(-1), weights=length, minlength=len(unique)).astype(
        np.float64
    )
    return FaceAdjacency(unique.astype(np.int64).reshape(-1, 2), total)


#: How ``apply_edits`` gets the adjacency a ``split`` needs: built only when one is asked.
AdjacencySource = FaceAdjacency | Callable[[], FaceAdjacency] | None


def _face_index(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise EditError(f"{where}: a face index must be an integer, got {value!r}")
    return int(value)


def _face_list(value: Any, where: str) -> tuple[int, ...]:
    if not isinstance(value, list | tuple) or not value:
        raise EditError(f"{where}: 'faces' must be a non-empty list of face indices")
    return tuple(_face_index(face, where) for face in value)


def parse_edits(document: Iterable[Mapping[str, Any] | Edit]) -> list[Edit]:
    """The typed operations of an edit document (a list of ``{"op": ...}`` objects);
    already typed operations pass through. Raises EditError naming the operation."""
    edits: list[Edit] = []
    faces = 0
    for index, item in enumerate(document):
        if index >= MAX_EDIT_OPERATIONS:
            raise EditError(f"at most {MAX_EDIT_OPERATIONS} edit operations per document")
        where = f"edit {index}"
        if isinstance(item, Grow | Shrink | Merge | Paint | Split):
            edit: Edit = item
        elif not isinstance(item, Mapping):
            raise EditError(f"{where}: expected an object with an 'op', got {item!r}")
        else:
            op = item.get("op")
            expected = {
                "grow": {"op", "face"},
                "shrink": {"op", "face"},
                "merge": {"op", "faces"},
                "paint": {"op", "faces", "to_face"},
                "split": {"op", "face"},
            }.get(op)  # type: ignore[arg-type]
            if expected is None:
                raise EditError(f"{where}: unknown op {op!r}; use one of {EDIT_OPERATIONS}")
            if set(item) != expected:
                raise EditError(f"{where}: '{op}' takes exactly {sorted(expected)}")
            if op == "grow":
                edit = Grow(_face_index(item["face"], where))
            elif op == "shrink":
                edit = Shrink(_face_index(item["face"], where))
            elif op == "split":
                edit = Split(_face_index(item["face"], where))
            elif op == "merge":
                edit = Merge(_face_list(item["faces"], where))
            else:
                edit = Paint(_face_list(item["faces"], where), _face_index(item["to_face"], where))
        faces += len(edit.faces) + 1 if isinstance(edit, Merge | Paint) else 1
        if faces > MAX_EDIT_FACES:
            raise EditError(f"at most {MAX_EDIT_FACES} faces in one edit document")
        edits.append(edit)
    return edits


def edit_document(edits: Sequence[Edit]) -> list[dict[str, Any]]:
    """The JSON form of typed operations (the inverse of ``parse_edits``)."""
    out: list[dict[str, Any]] = []
    for edit in edits:
        if isinstance(edit, Grow):
            out.append({"op": "grow", "face": edit.face})
        elif isinstance(edit, Shrink):
            out.append({"op": "shrink", "face": edit.face})
        elif isinstance(edit, Split):
            out.append({"op": "split", "face": edit.face})
        elif isinstance(edit, Merge):
            out.append({"op": "merge", "faces": list(edit.faces)})
        else:
            out.append({"op": "paint", "faces": list(edit.faces), "to_face": edit.to_face})
    return out


class _EditState:
    """Parts as groups of tree nodes (the cut) plus painted faces.

    The leaves are laid out in depth-first order so that every node's leaves are one
    range ``[low, high)`` of positions; ``top`` holds the cut node over each position, so
    growing or shrinking a node is a slice assignment.
    """

    def __init__(
        self,
        parent: NDArray[Any],
        children: NDArray[Any],
        leaf_of_face: NDArray[Any],
        top: NDArray[Any],
    ):
        leaves = (len(parent) + 1) // 2
        self.parent = parent
        self.children = children  # (L-1, 2): the children of node L + i
        self.leaves = leaves
        self.leaf_of_face = leaf_of_face
        position, self.low, self.high = _depth_first_ranges(children, leaves)
        self.face_position = np.where(leaf_of_face >= 0, position[np.maximum(leaf_of_face, 0)], -1)
        self.top = np.empty(leaves, dtype=np.int64)
        self.top[position] = top  # ``top``: cut node per leaf
        cut = np.unique(top)
        self.node_group = {int(node): group for group, node in enumerate(cut.tolist())}
        self.group_nodes: list[set[int]] = [{int(node)} for node in cut.tolist()]
        self.group_parent = list(range(len(cut)))
        self.painted = np.full(len(leaf_of_face), -1, dtype=np.int64)

    def find(self, group: int) -> int:
        root = group
        while self.group_parent[root] != root:
            root = self.group_parent[root]
        while self.group_parent[group] != root:  # path compression
            self.group_parent[group], group = root, self.group_parent[group]
        return root

    def union(self, into: int, other: int) -> None:
        into, other = self.find(into), self.find(other)
        if into != other:
            self.group_parent[other] = into
            self.group_nodes[into] |= self.group_nodes[other]
            self.group_nodes[other] = set()

    def cut_node(self, face: int) -> int:
        return int(self.top[self.face_position[face]])

    def part(self, face: int) -> int:
        """The part holding ``face`` now (paint included)."""
        painted = int(self.painted[face])
        return self.find(painted if painted >= 0 else self.node_group[self.cut_node(face)])

    def grow(self, face: int) -> None:
        node = self.cut_node(face)
        up = int(self.parent[node])
        if up < 0:
            return
        group = self.find(self.node_group[node])
        low, high = self.low[up], self.high[up]
        emptied = []
        for inside in np.unique(self.top[low:high]).tolist():
            owner = self.find(self.node_group.pop(inside))
            self.group_nodes[owner].discard(inside)
            if owner != group and not self.group_nodes[owner]:
                emptied.append(owner)
        self.top[low:high] = up
        self.node_group[up] = group
        self.group_nodes[group].add(up)
        for owner in emptied:  # wholly inside: joins, with the faces painted into it
            self.union(group, owner)

    def shrink(self, face: int) -> None:
        node = self.cut_node(face)
        if node < self.leaves:
            return
        group = self.find(self.node_group.pop(node))
        self.group_nodes[group].discard(node)
        new_group = len(self.group_parent)
        self.group_parent.append(new_group)
        self.group_nodes.append(set())
        position = self.face_position[face]
        for child in self.children[node - self.leaves].tolist():
            low, high = self.low[child], self.high[child]
            self.top[low:high] = child
            owner = group if low <= position < high else new_group
            self.node_group[child] = owner
            self.group_nodes[owner].add(child)

    def merge(self, faces: Sequence[int]) -> None:
        into = self.part(faces[0])
        for face in faces[1:]:
            self.union(into, self.part(face))

    def paint(self, faces: Sequence[int], to_face: int) -> None:
        self.painted[np.asarray(faces, dtype=np.int64)] = self.part(to_face)

    def split(self, face: int, adjacency: FaceAdjacency, seed: int) -> None:
        members = np.flatnonzero(self.groups() == self.part(face))
        if len(members) < 2:
            return
        pairs = adjacency.pairs
        inside = np.isin(pairs[:, 0], members) & np.isin(pairs[:, 1], members)
        local = np.searchsorted(members, pairs[inside])
        halves = split_graph(len(members), local, adjacency.length[inside], 2, seed)
        moved = members[halves != halves[np.searchsorted(members, face)]]
        if len(moved) == 0:
            return
        new_group = len(self.group_parent)
        self.group_parent.append(new_group)
        self.group_nodes.append(set())
        self.painted[moved] = new_group

    def groups(self) -> NDArray[np.int64]:
        """The part (group root) of every face now, paint included; -1: no part."""
        groups = len(self.group_parent)
        root = np.array([self.find(g) for g in range(groups)], dtype=np.int64)
        node_group = np.full(2 * self.leaves - 1, -1, dtype=np.int64)
        node_group[list(self.node_group)] = list(self.node_group.values())
        valid = self.face_position >= 0
        tree_group = node_group[self.top[np.maximum(self.face_position, 0)]]
        group = np.where(self.painted >= 0, self.painted, tree_group)
        return np.where(valid, root[np.maximum(group, 0)], -1)

    def labels(self) -> NDArray[np.int64]:
        """Part per face, numbered by each part's smallest face; -1 stays -1."""
        return canonical_face_labels(self.groups())


def canonical_face_labels(groups: NDArray[Any]) -> NDArray[np.int64]:
    """Renumber group ids 0, 1, ... in order of each group's smallest face; -1 stays -1."""
    groups = np.asarray(groups, dtype=np.int64)
    valid = groups >= 0
    ids, first = np.unique(groups[valid], return_index=True)
    rank = np.empty(len(ids), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(ids))
    out = np.full(len(groups), -1, dtype=np.int64)
    out[valid] = rank[np.searchsorted(ids, groups[valid])]
    return out


def _depth_first_ranges(
    children: NDArray[Any], leaves: int
) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """(position of each leaf, low, high per node): a depth-first layout of the leaves
    (lower child first) in which node n's leaves are positions ``low[n]..high[n]-1``."""
    nodes = 2 * leaves - 1
    size = np.ones(nodes, dtype=np.int64)
    for i, (a, b) in enumerate(children.tolist()):  # children come before their parent
        size[leaves + i] = size[a] + size[b]
    low = np.zeros(nodes, dtype=np.int64)
    for i in range(leaves - 2, -1, -1):  # parents before children, from the root down
        a, b = children[i]
        low[a] = low[leaves + i]
        low[b] = low[leaves + i] + size[a]
    return low[:leaves].copy(), low, low + size


def _check_faces(edits: Sequence[Edit], leaf_of_face: NDArray[Any], *, tree: bool) -> None:
    count = len(leaf_of_face)
    for index, edit in enumerate(edits):
        if not tree and isinstance(edit, Grow | Shrink):
            op = "grow" if isinstance(edit, Grow) else "shrink"
            raise EditError(
                f"edit {index}: '{op}' needs the part tree, which the METIS partitioner does "
                "not make; use merge and paint, or the graphcut partitioner"
            )
        faces = (edit.face,) if isinstance(edit, Grow | Shrink | Split) else edit.faces
        if isinstance(edit, Paint):
            faces = (*faces, edit.to_face)
        named = np.asarray(faces, dtype=np.int64)
        outside = named[(named < 0) | (named >= count)]
        if len(outside):
            raise EditError(
                f"edit {index}: face {int(outside[0])} is out of range (the mesh has "
                f"{count} input faces, 0..{count - 1})"
            )
        empty = named[leaf_of_face[named] < 0]
        if len(empty):
            raise EditError(
                f"edit {index}: face {int(empty[0])} has no triangles, so it is in no part"
            )


def apply_edits(
    tree: PartTree,
    leaf_of_face: NDArray[Any],
    parts: int,
    edits: Iterable[Mapping[str, Any] | Edit],
    adjacency: AdjacencySource = None,
    seed: int = 0,
) -> NDArray[np.int64]:
    """Labels per input face: ``tree`` cut at ``parts`` (clamped to 1..L), then ``edits``.

    ``leaf_of_face``: the tree's leaf per input face (-1: no triangles). With no edits the
    labels are ``tree.relabel(leaf_of_face, parts)``. ``adjacency`` (or a function that
    builds it, called only when a ``split`` needs it) and ``seed``: the METIS bisection of
    ``split``. Raises EditError for a bad document.
    """
    leaf_of_face = np.asarray(leaf_of_face, dtype=np.int64)
    operations = parse_edits(edits)
    _check_faces(operations, leaf_of_face, tree=True)
    leaves = tree.leaf_count
    if leaves == 0:
        return np.full(len(leaf_of_face), -1, dtype=np.int64)
    parent = tree.parent
    count = min(max(int(parts), 1), leaves)
    limit = 2 * leaves - count
    top = np.arange(2 * leaves - 1, dtype=np.int64)
    for node in range(2 * leaves - 2, -1, -1):  # the cut's node over each node (root down)
        up = parent[node]
        if up >= 0 and up < limit:
            top[node] = top[up]
    state = _EditState(parent, tree.merges, leaf_of_face, top[:leaves])
    return _run(state, operations, adjacency, seed)


def apply_label_edits(
    labels: NDArray[Any],
    edits: Iterable[Mapping[str, Any] | Edit],
    adjacency: AdjacencySource = None,
    seed: int = 0,
) -> NDArray[Any]:
    """Merge, paint and split on labels with no tree (METIS): each part is one leaf; grow
    and shrink raise EditError. -1 stays -1."""
    labels = np.asarray(labels, dtype=np.int64)
    operations = parse_edits(edits)
    _check_faces(operations, labels, tree=False)
    _, dense = np.unique(labels, return_inverse=True)
    dense = dense.reshape(-1) - (1 if len(labels) and labels.min() < 0 else 0)
    leaves = int(dense.max()) + 1 if len(dense) else 0
    if leaves == 0:
        return np.full(len(labels), -1, dtype=np.int64)
    # A chain tree whose merges are never used: only its leaves (the parts) matter.
    chain = np.array(
        [[0, 1]] + [[i + 1, leaves + i - 1] for i in range(1, leaves - 1)], dtype=np.int64
    )[: leaves - 1]
    parent = np.full(2 * leaves - 1, -1, dtype=np.int64)
    if leaves > 1:
        parent[chain.reshape(-1)] = np.repeat(np.arange(leaves, 2 * leaves - 1), 2)
    state = _EditState(parent, chain, dense, np.arange(leaves, dtype=np.int64))
    return _run(state, operations, adjacency, seed)


def _run(
    state: _EditState, operations: Sequence[Edit], adjacency: AdjacencySource, seed: int
) -> NDArray[np.int64]:
    for index, edit in enumerate(operations):
        if isinstance(edit, Split):
            if adjacency is None:
                raise EditError(
                    f"edit {index}: 'split' needs the mesh's face adjacency (the service "
                    "applies it; a part tree alone cannot)"
                )
            if not isinstance(adjacency, FaceAdjacency):
                adjacency = adjacency()
            state.split(edit.face, adjacency, seed)
            continue
        if isinstance(edit, Grow):
            state.grow(edit.face)
        elif isinstance(edit, Shrink):
            state.shrink(edit.face)
        elif isinstance(edit, Merge):
            state.merge(edit.faces)
        else:
            state.paint(edit.faces, edit.to_face)
    return state.labels()


__all__ = [
    "EDIT_OPERATIONS",
    "MAX_EDIT_FACES",
    "MAX_EDIT_OPERATIONS",
    "Edit",
    "EditError",
    "FaceAdjacency",
    "Grow",
    "Merge",
    "Paint",
    "Shrink",
    "Split",
    "apply_edits",
    "apply_label_edits",
    "canonical_face_labels",
    "edit_document",
    "input_face_adjacency",
    "parse_edits",
]
