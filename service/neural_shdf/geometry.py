"""Per-face geometry and the face adjacency graph shared by ShDF and segmentation."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from neural_shdf.constants import AREA_EPS


def face_normals(vertices: NDArray, faces: NDArray) -> tuple[NDArray, NDArray]:
    """Unit normals (F, 3) and areas (F,) of triangles; degenerate faces get a zero normal."""
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    normals = np.zeros_like(cross)
    ok = norm > AREA_EPS
    normals[ok] = cross[ok] / norm[ok, None]
    return normals, 0.5 * norm


def face_centroids(vertices: NDArray, faces: NDArray) -> NDArray:
    """Centroids (F, 3) of triangles."""
    return vertices[faces].mean(axis=1)


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

    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    edge_face = np.repeat(np.arange(n_faces), 3)
    # Drop edges of degenerate faces that repeat a vertex.
    keep = edges[:, 0] != edges[:, 1]
    edges, edge_face = edges[keep], edge_face[keep]
    order = np.lexsort((edge_face, edges[:, 1], edges[:, 0]))
    edges, edge_face = edges[order], edge_face[order]
    new_group = np.ones(len(edges), dtype=bool)
    new_group[1:] = np.any(edges[1:] != edges[:-1], axis=1)
    group_start = np.flatnonzero(new_group)
    group_size = np.diff(np.append(group_start, len(edges)))

    pair_list = []
    vert_list = []
    # Manifold edges (size 2) in one vectorised step; larger groups pairwise.
    two = group_start[group_size == 2]
    pair_list.append(np.stack([edge_face[two], edge_face[two + 1]], axis=1))
    vert_list.append(edges[two])
    for size in np.unique(group_size[group_size > 2]):
        starts = group_start[group_size == size]
        ia, ib = np.triu_indices(int(size), k=1)
        pair_list.append(
            np.stack([edge_face[starts[:, None] + ia], edge_face[starts[:, None] + ib]], axis=2)
            .reshape(-1, 2)
        )
        vert_list.append(np.repeat(edges[starts], len(ia), axis=0))
    pairs = np.concatenate(pair_list).astype(np.int64)
    edge_vertices = np.concatenate(vert_list).astype(np.int64)
    # A face listed twice on one edge (repeated vertex pattern) is no adjacency.
    keep = pairs[:, 0] != pairs[:, 1]
    pairs, edge_vertices = np.sort(pairs[keep], axis=1), edge_vertices[keep]
    # Two faces sharing two edges (folded duplicates) keep a single link.
    pairs, first = np.unique(pairs, axis=0, return_index=True)
    edge_vertices = edge_vertices[first]

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
    if len(vertices) == 0:
        return np.asarray(faces, dtype=np.int64)
    _, first, inverse = np.unique(
        np.asarray(vertices), axis=0, return_index=True, return_inverse=True
    )
    return inverse.reshape(-1)[np.asarray(faces, dtype=np.int64)]
