"""Per-face geometry and the face adjacency graph shared by ShDF and segmentation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from neural_shdf.constants import AREA_EPS


def face_normals(vertices: NDArray, faces: NDArray) -> tuple[NDArray, NDArray]:
    """Unit normals (F, 3) and areas (F,) of triangles; degenerate faces get a zero normal."""
    origin = vertices[faces[:, 0]]
    u = vertices[faces[:, 1]] - origin
    v = vertices[faces[:, 2]] - origin
    cross = np.empty_like(u)
    cross[:, 0] = u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1]
    cross[:, 1] = u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2]
    cross[:, 2] = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    norm = np.sqrt(np.einsum("ij,ij->i", cross, cross))
    normals = np.zeros_like(cross)
    ok = norm > AREA_EPS
    normals[ok] = cross[ok] / norm[ok, None]
    return normals, 0.5 * norm


def face_centroids(vertices: NDArray, faces: NDArray) -> NDArray:
    """Centroids (F, 3) of triangles."""
    faces = np.asarray(faces)
    return (vertices[faces[:, 0]] + vertices[faces[:, 1]] + vertices[faces[:, 2]]) / 3.0


@dataclass(frozen=True)
class FaceGraph:
    """Faces that share an edge, with the edge's length and dihedral angle.

    Attributes:
        pairs: (E, 2) int64 face indices, ``pairs[:, 0] < pairs[:, 1]``, sorted.
        edge_vertices: (E, 2) the shared edge's vertex indices.
        edge_length: (E,) length of the shared edge.
        dihedral: (E,) angle between the two face normals in [0, pi] (0 = flat).
        concave: (E,) True where the fold between the faces is concave (a valley).
        face_count: number of faces (graph nodes).
    """

    pairs: NDArray[np.int64]
    edge_vertices: NDArray[np.int64]
    edge_length: NDArray[np.float64]
    dihedral: NDArray[np.float64]
    concave: NDArray[np.bool_]
    face_count: int

    def csr(self, weights: NDArray | None = None):
        """Symmetric scipy CSR adjacency matrix with the given edge weights (default 1)."""
        import scipy.sparse as sp

        w = np.ones(len(self.pairs)) if weights is None else np.asarray(weights, dtype=float)
        rows = np.concatenate([self.pairs[:, 0], self.pairs[:, 1]])
        cols = np.concatenate([self.pairs[:, 1], self.pairs[:, 0]])
        n = self.face_count
        return sp.csr_matrix((np.concatenate([w, w]), (rows, cols)), shape=(n, n))


def build_face_graph(
    vertices: NDArray, faces: NDArray, normals: NDArray | None = None
) -> FaceGraph:
    """Face adjacency over shared edges.

    Works on open, non-manifold and multi-shell meshes: an edge shared by k > 2
    faces links every pair of them; boundary edges link nothing. Edges are found
    by vertex index, so callers that want welding must weld first.
    """
    faces = np.asarray(faces, dtype=np.int64)
    n_faces = len(faces)
    if normals is None:
        normals, _ = face_normals(vertices, faces)
    if n_faces == 0:
        empty = np.zeros((0, 2), dtype=np.int64)
        return FaceGraph(empty, empty, np.zeros(0), np.zeros(0), np.zeros(0, bool), 0)

    n_vertices = int(faces.max()) + 1
    start_vertex = faces.reshape(-1)
    end_vertex = faces[:, [1, 2, 0]].reshape(-1)
    lo, hi = np.minimum(start_vertex, end_vertex), np.maximum(start_vertex, end_vertex)
    edge_face = np.repeat(np.arange(n_faces, dtype=np.int64), 3)
    # Drop edges of degenerate faces that repeat a vertex.
    keep = lo != hi
    lo, hi, edge_face = lo[keep], hi[keep], edge_face[keep]
    # One int64 key per undirected edge; a stable sort keeps faces ascending in a group.
    key = lo * n_vertices + hi
    order = np.argsort(key, kind="stable")
    key, edge_face = key[order], edge_face[order]
    new_group = np.ones(len(key), dtype=bool)
    new_group[1:] = key[1:] != key[:-1]
    group_start = np.flatnonzero(new_group)
    group_size = np.diff(np.append(group_start, len(key)))

    pair_list = []
    key_list = []
    # Manifold edges (size 2) in one vectorised step; larger groups pairwise.
    two = group_start[group_size == 2]
    manifold = np.empty((len(two), 2), dtype=np.int64)
    manifold[:, 0], manifold[:, 1] = edge_face[two], edge_face[two + 1]
    pair_list.append(manifold)
    key_list.append(key[two])
    for size in np.unique(group_size[group_size > 2]):
        starts = group_start[group_size == size]
        ia, ib = np.triu_indices(int(size), k=1)
        pair_list.append(
            np.stack([edge_face[starts[:, None] + ia], edge_face[starts[:, None] + ib]], axis=2)
            .reshape(-1, 2)
        )
        key_list.append(np.repeat(key[starts], len(ia)))
    pairs = pair_list[0] if len(pair_list) == 1 else np.concatenate(pair_list)
    edge_key = key_list[0] if len(key_list) == 1 else np.concatenate(key_list)
    # Faces ascend within a group (stable sort), so pairs[:, 0] <= pairs[:, 1] already.
    # A face listed twice on one edge (repeated vertex pattern) is no adjacency.
    keep = pairs[:, 0] != pairs[:, 1]
    if not keep.all():
        pairs, edge_key = pairs[keep], edge_key[keep]
    # Sorted by face pair; two faces sharing two edges (folded duplicates) keep one link.
    pair_key = pairs[:, 0] * n_faces + pairs[:, 1]
    order = np.argsort(pair_key, kind="stable")
    pair_key, pairs, edge_key = pair_key[order], pairs[order], edge_key[order]
    first = np.ones(len(pair_key), dtype=bool)
    first[1:] = pair_key[1:] != pair_key[:-1]
    pairs, edge_key = pairs[first], edge_key[first]
    edge_vertices = np.stack([edge_key // n_vertices, edge_key % n_vertices], axis=1)

    a, b = pairs[:, 0], pairs[:, 1]
    cos = np.clip(np.einsum("ij,ij->i", normals[a], normals[b]), -1.0, 1.0)
    dihedral = np.arccos(cos)
    edge_length = np.linalg.norm(
        vertices[edge_vertices[:, 0]] - vertices[edge_vertices[:, 1]], axis=1
    )
    # Concave when face b's vertex off the shared edge lies above face a's plane.
    fb = faces[b]
    off_edge = np.where(
        (fb != edge_vertices[:, [0]]) & (fb != edge_vertices[:, [1]]), fb, -1
    ).max(axis=1)
    off_edge = np.where(off_edge < 0, fb[:, 0], off_edge)
    height = np.einsum("ij,ij->i", vertices[off_edge] - vertices[edge_vertices[:, 0]], normals[a])
    concave = height > 0
    return FaceGraph(pairs, edge_vertices, edge_length, dihedral, concave, n_faces)


def weld_faces(vertices: NDArray, faces: NDArray) -> NDArray[np.int64]:
    """Face indices rewritten so that vertices at identical positions share one index.

    Faces keep their order and count; only the adjacency they imply changes
    (an STL triangle soup becomes connected). Used for graphs, never for output.
    """
    faces = np.asarray(faces, dtype=np.int64)
    if len(vertices) == 0:
        return faces
    representative = _first_of_equal_rows(np.ascontiguousarray(vertices, dtype=np.float64))
    return representative[faces]


def _first_of_equal_rows(vertices: NDArray[np.float64]) -> NDArray[np.int64]:
    """For each row, the index of the first row with the same coordinates.

    Sorts one 64-bit hash per row instead of whole rows (several times faster than
    ``np.unique(axis=0)``), then checks that rows sharing a hash are equal; on a
    hash collision it falls back to the exact row sort.
    """
    bits = (vertices + 0.0).view(np.uint64)  # + 0.0 folds -0.0 into 0.0
    with np.errstate(over="ignore"):
        key = bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)
        key ^= bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F) + (key >> np.uint64(29))
        key ^= bits[:, 2] * np.uint64(0x165667B19E3779F9) + (key >> np.uint64(31))
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    starts = np.ones(len(order), dtype=bool)
    starts[1:] = sorted_key[1:] != sorted_key[:-1]
    group_first = order[np.flatnonzero(starts)][np.cumsum(starts) - 1]
    if not np.array_equal(vertices[order], vertices[group_first]):
        _, first, inverse = np.unique(vertices, axis=0, return_index=True, return_inverse=True)
        return first[inverse.reshape(-1)]
    representative = np.empty(len(order), dtype=np.int64)
    representative[order] = group_first
    return representative
