"""Part bookkeeping shared by the partitioners: canonical ids, components, merging tiny parts."""

from __future__ import annotations

import heapq
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from neural_shdf.compiled import kernel
from neural_shdf.geometry import (
    FaceGraph,
    face_centroids,
    face_normals,
    has_own_frame,
    in_frame,
    pose_frame,
    principal_frame,
)


@dataclass(frozen=True)
class FaceData:
    """Per-face geometry the partitioners need: area, centroid and area over mean area; and
    for the part tree's folds, the centroids and unit normals (of the oriented faces) in
    a frame of the shape's own (``of``; rounded by ``geometry.in_frame``: the same bits in
    any pose) with that frame's scale."""

    areas: NDArray[np.float64]
    centroids: NDArray[np.float64]
    face_weight: NDArray[np.float64]
    pose_centroids: NDArray[np.float64]
    pose_normals: NDArray[np.float64]
    pose_scale: float

    @classmethod
    def of(
        cls,
        vertices: NDArray[Any],
        faces: NDArray[Any],
        normals_and_areas: tuple[NDArray[Any], NDArray[Any]] | None = None,
        centroids: NDArray[Any] | None = None,
        pose: tuple[NDArray[Any], NDArray[Any], float] | None = None,
        principal: tuple[NDArray[Any], NDArray[Any]] | None = None,
        pose_normals: NDArray[Any] | None = None,
    ) -> FaceData:
        """The data of ``faces``; ``normals_and_areas`` (``geometry.face_normals``),
        ``centroids``, ``pose`` (``geometry.pose_frame``) and ``principal``
        (``geometry.principal_frame``) where the caller has them (a ``TriangleMesh``
        caches them), and ``pose_normals``, the normals computed from the coordinates in
        ``pose`` (``TriangleMesh.pose_geometry``: a sliver's normal the same in any pose;
        turned from the normals otherwise). Where the shape fixes no pose frame of its own
        (it falls back to the world's axes), its principal axes turn with it instead:
        their senses, which the shape leaves open, do not matter to a grid centred on the
        origin."""
        if normals_and_areas is None:
            normals_and_areas = face_normals(vertices, faces)
        normals, areas = normals_and_areas
        areas = np.asarray(areas, dtype=np.float64)
        mean = float(areas.mean()) if len(areas) else 0.0
        weight = areas / mean if mean > 0 else np.ones(len(areas))
        centroids = face_centroids(vertices, faces) if centroids is None else centroids
        principal = principal_frame(centroids, areas) if principal is None else principal
        pose = pose_frame(centroids, areas, principal) if pose is None else pose
        if not has_own_frame(pose):
            pose = (pose[0], np.asarray(principal[1], dtype=np.float64), pose[2])
            pose_normals = None
        if pose_normals is None:
            pose_normals = in_frame(normals, pose, translate=False)
        return cls(
            areas,
            centroids,
            weight,
            in_frame(centroids, pose),
            np.asarray(pose_normals, dtype=np.float64),
            float(pose[2]),
        )

    def subset(self, faces: NDArray[Any]) -> FaceData:
        """The same data for some faces (weights stay relative to the whole mesh)."""
        return FaceData(
            self.areas[faces],
            self.centroids[faces],
            self.face_weight[faces],
            self.pose_centroids[faces],
            self.pose_normals[faces],
            self.pose_scale,
        )


def canonical_labels(labels: NDArray[Any]) -> NDArray[np.int64]:
    """Labels renumbered 0..P-1 in order of each label's lowest face index."""
    labels = np.asarray(labels).reshape(-1)
    if len(labels) == 0:
        return np.zeros(0, dtype=np.int64)
    low, high = int(labels.min()), int(labels.max())
    if np.issubdtype(labels.dtype, np.integer) and high - low <= 4 * len(labels):
        # Small integer range (the usual case): one pass in face order.
        return _first_seen_order(labels.astype(np.int64) - low, high - low + 1)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return rank[inverse.reshape(-1)]


@kernel
def _first_seen_order(
    labels: NDArray[Any], span: int
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    rank = np.full(span, -1, dtype=np.int64)
    result = np.empty(len(labels), dtype=np.int64)
    seen = 0
    for face in range(len(labels)):
        label = labels[face]
        if rank[label] < 0:
            rank[label] = seen
            seen += 1
        result[face] = rank[label]
    return result


def connected_parts(
    labels: NDArray[Any], pairs: NDArray[Any], face_count: int
) -> NDArray[np.int64]:
    """Connected components of faces with equal labels, as canonical part ids (the labels
    compared edge by edge inside the union-find: no per-edge arrays)."""
    if face_count == 0:
        return np.zeros(0, dtype=np.int64)
    labels = np.ascontiguousarray(labels, dtype=np.int64).reshape(-1)
    pairs = np.ascontiguousarray(pairs, dtype=np.int64).reshape(-1, 2)
    if len(pairs) and int(pairs.max()) >= len(labels):
        raise IndexError(f"{len(labels)} labels for a graph over more faces")
    return _components(pairs, np.zeros(0, dtype=np.bool_), labels, face_count)


def connected_components(
    pairs: NDArray[Any], keep: NDArray[Any], node_count: int
) -> NDArray[np.int64]:
    """Component of each node over the edges ``pairs[keep]``, numbered 0.. in order of each
    component's lowest node (union-find; linear)."""
    if node_count == 0:
        return np.zeros(0, dtype=np.int64)
    return _components(
        np.asarray(pairs, dtype=np.int64).reshape(-1, 2),
        np.asarray(keep, bool),
        np.zeros(0, dtype=np.int64),
        node_count,
    )


@kernel
def _components(
    pairs: NDArray[Any], keep: NDArray[Any], labels: NDArray[Any], node_count: int
) -> NDArray[np.int64]:  # pragma: no cover - compiled
    """Union-find over the edges ``keep`` marks, or, when ``keep`` is empty, the edges
    whose two nodes have equal ``labels``."""
    root = np.arange(node_count)
    by_label = len(keep) == 0

    def find(node: int) -> int:
        while root[node] != node:
            root[node] = root[root[node]]  # path halving
            node = root[node]
        return node

    for edge in range(len(pairs)):
        a, b = pairs[edge, 0], pairs[edge, 1]
        if (labels[a] == labels[b]) if by_label else keep[edge]:
            ra, rb = find(a), find(b)
            if ra < rb:
                root[rb] = ra
            elif rb < ra:
                root[ra] = rb
    component_of_root = np.full(node_count, -1, dtype=np.int64)
    components = np.empty(node_count, dtype=np.int64)
    next_component = 0
    for node in range(node_count):
        top = find(node)
        if component_of_root[top] < 0:
            component_of_root[top] = next_component
            next_component += 1
        components[node] = component_of_root[top]
    return components


def part_sizes(parts: NDArray[Any], areas: NDArray[Any]) -> NDArray[np.float64]:
    """Area of each part; face counts instead when the whole surface has no area."""
    count = int(parts.max()) + 1 if len(parts) else 0
    size: NDArray[Any] = np.bincount(parts, weights=areas, minlength=count)
    if not size.sum() > 0:
        size = np.bincount(parts, minlength=count).astype(np.float64)
    return size


def merge_small_parts(
    parts: NDArray[Any],
    graph: FaceGraph,
    areas: NDArray[Any],
    centroids: NDArray[Any],
    min_fraction: float,
) -> NDArray[np.int64]:
    """Merge parts below ``min_fraction`` of the total area into a neighbour.

    Smallest first, each tiny part joins the part it shares the longest
    boundary with (ties: lower id). A tiny part with no neighbour at all (a
    small shell, an isolated face) joins the part of the nearest face centroid
    among parts that are not tiny; if every part is tiny, such parts stay.
    Returns canonical labels.
    """
    parts = np.asarray(parts, dtype=np.int64)
    if min_fraction <= 0 or len(parts) == 0 or parts.max() == 0:
        return canonical_labels(parts)
    part_count = int(parts.max()) + 1
    size = part_sizes(parts, areas)
    threshold = min_fraction * size.sum()
    if not np.any(size < threshold):
        return canonical_labels(parts)

    neighbours = _part_boundaries(parts, graph, part_count)
    owner = np.arange(part_count)
    # A tiny part without neighbours stays so (no merge gives it one): set it aside now,
    # so that many small shells cost no heap work.
    tiny = np.flatnonzero(size < threshold).tolist()
    isolated = [i for i in tiny if not neighbours[i]]
    heap = [(float(size[i]), i) for i in tiny if neighbours[i]]
    heapq.heapify(heap)
    while heap:
        part_size, part = heapq.heappop(heap)
        if owner[part] != part or part_size != size[part]:
            continue  # merged away, or re-queued with its grown size
        around = neighbours[part]
        if not around:
            isolated.append(part)
            continue
        target = max(around, key=lambda n: (around[n], -n))
        owner[part] = target
        size[target] += size[part]
        for other, length in around.items():
            del neighbours[other][part]
            if other != target:
                neighbours[target][other] = neighbours[target].get(other, 0.0) + length
                neighbours[other][target] = neighbours[other].get(target, 0.0) + length
        neighbours[part] = {}
        if size[target] < threshold:
            heapq.heappush(heap, (float(size[target]), int(target)))

    owner = _resolve(owner)
    merged = owner[parts]
    if isolated:
        merged = _merge_isolated(merged, np.array(isolated), size, threshold, centroids)
    return canonical_labels(merged)


def _part_boundaries(
    parts: NDArray[Any], graph: FaceGraph, part_count: int
) -> list[dict[int, float]]:
    """For each part, {neighbour part: total length of the shared boundary}."""
    cut, pair_keys = cut_edges(
        np.ascontiguousarray(parts, dtype=np.int64),
        np.ascontiguousarray(graph.pairs, dtype=np.int64).reshape(-1, 2),
        part_count,
    )
    keys, inverse = np.unique(pair_keys, return_inverse=True)
    lengths = np.bincount(inverse.reshape(-1), weights=graph.edge_length[cut])
    neighbours: list[dict[int, float]] = [{} for _ in range(part_count)]
    for key, length in zip(keys.tolist(), lengths.tolist(), strict=True):
        i, j = divmod(key, part_count)
        neighbours[i][j] = length
        neighbours[j][i] = length
    return neighbours


@kernel
def cut_edges(
    parts: NDArray[Any], pairs: NDArray[Any], part_count: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # pragma: no cover - compiled
    """The edges between two parts, in order, and each one's pair key ``low * part_count +
    high`` (one pass, no per-edge arrays of the whole graph)."""
    cut = np.empty(len(pairs), dtype=np.int64)
    keys = np.empty(len(pairs), dtype=np.int64)
    count = 0
    for edge in range(len(pairs)):
        a, b = parts[pairs[edge, 0]], parts[pairs[edge, 1]]
        if a != b:
            cut[count] = edge
            keys[count] = min(a, b) * part_count + max(a, b)
            count += 1
    return cut[:count].copy(), keys[:count].copy()


def _resolve(owner: NDArray[Any]) -> NDArray[np.int64]:
    """Follow merge links to each part's final owner."""
    owner = owner.copy()
    while True:
        nxt = owner[owner]
        if np.array_equal(nxt, owner):
            return owner
        owner = nxt


def _merge_isolated(
    merged: NDArray[Any],
    isolated: NDArray[Any],
    size: NDArray[Any],
    threshold: float,
    centroids: NDArray[Any],
) -> NDArray[np.int64]:
    """Give each isolated tiny part the label of the nearest face of a part that is not tiny."""
    kept = np.flatnonzero(size >= threshold)
    kept = kept[np.isin(kept, merged)]
    if len(kept) == 0:
        return merged
    target_faces = np.flatnonzero(np.isin(merged, kept))
    tree = cKDTree(centroids[target_faces])
    query_faces = np.flatnonzero(np.isin(merged, isolated))
    distance, nearest = tree.query(centroids[query_faces])
    source = merged[query_faces]
    # Per isolated part, its face closest to any kept face decides (ties: lowest face).
    order = np.lexsort((query_faces, distance, source))
    source_sorted = source[order]
    first = np.ones(len(order), dtype=bool)
    first[1:] = source_sorted[1:] != source_sorted[:-1]
    choice = order[first]
    relabel = dict(
        zip(source[choice].tolist(), merged[target_faces[nearest[choice]]].tolist(), strict=True)
    )
    result = merged.copy()
    lookup = np.arange(int(merged.max()) + 1)
    for part, target in relabel.items():
        lookup[part] = target
    relabelled: NDArray[np.int64] = lookup[result]
    return relabelled


def induced_subgraph(graph: FaceGraph, faces: NDArray[Any]) -> tuple[FaceGraph, NDArray[np.int64]]:
    """The graph on ``faces`` (sorted ascending) and the indices of its edges in ``graph``."""
    faces = np.asarray(faces, dtype=np.int64)
    inside = np.zeros(graph.face_count, dtype=bool)
    inside[faces] = True
    edges = np.flatnonzero(inside[graph.pairs[:, 0]] & inside[graph.pairs[:, 1]])
    local = np.searchsorted(faces, graph.pairs[edges])
    sub = FaceGraph(
        pairs=local,
        edge_vertices=graph.edge_vertices[edges],
        edge_length=graph.edge_length[edges],
        dihedral=graph.dihedral[edges],
        concave=graph.concave[edges],
        face_count=len(faces),
    )
    return sub, edges
