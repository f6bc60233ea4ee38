"""Intrinsic descriptors of a mesh's surface, per node of a Poisson-disk sample graph.

The labeller classifies nodes, not faces, so its cost and its features do not depend on
the tessellation:

* Nodes: the faces that hold a Poisson-disk sample (about ``FeatureSpec.samples`` of them
  whatever the face count). Every face belongs to the node nearest to it along the
  surface (a geodesic Voronoi cell, grown over the face graph from the node faces), so
  touching but unconnected parts never share a cell.
* Node graph: cells that share a face edge; edge length = the straight distance between
  the two nodes (about one Poisson radius); the boundary's length weighs the
  Laplacian (a finite-volume Laplacian with cell areas as masses).
* Lengths are in units of sqrt(surface area) and areas in units of the surface area, so
  scale, vertex count, pose in space and axis convention do not change the features.

Features per node (``FEATURE_NAMES``): the ShDF (cell mean, geodesic Gaussian means and
spread at a few scales), geodesic statistics (average geodesic distance, quantiles of the
distance distribution, distance to the nearest extremity, area of geodesic balls), the
heat kernel signature at a few times, and normal-variation proxies (normal dispersion,
signed offset of the neighbourhood along the normal: convex or concave).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import dijkstra
from scipy.sparse.linalg import eigsh
from scipy.spatial import cKDTree

from neural_shdf.errors import InvalidGeometryError
from neural_shdf.labeling._library import (
    FaceGraph,
    TriangleMesh,
    face_centroids,
    sample_surface_points,
)

#: Bump when the meaning or order of the features changes (stored in every labeller).
FEATURE_VERSION = 3
#: Geodesic Gaussian scales (units of sqrt(area)) of the smoothed ShDF.
SHDF_SCALES = (0.02, 0.05, 0.1, 0.2)
#: Scales of the normal-variation proxies.
NORMAL_SCALES = (0.02, 0.05, 0.1)
#: Radii of the geodesic balls whose area is measured.
BALL_RADII = (0.05, 0.1, 0.2, 0.4)
#: Heat kernel signature times (surface of unit area).
HKS_TIMES = (0.001, 0.003, 0.01, 0.03, 0.1, 0.3)
#: Eigenpairs of the node Laplacian the heat kernel signature sums.
HKS_EIGENPAIRS = 60
#: Quantiles of each node's geodesic distances to the rest of the surface (area-weighted).
DISTANCE_QUANTILES = (0.1, 0.25, 0.5, 0.75, 0.9, 1.0)
#: An extremity is a node whose average geodesic distance is the largest within this radius.
EXTREMITY_RADIUS = 0.15

FEATURE_NAMES: tuple[str, ...] = (
    ("shdf",)
    + tuple(f"shdf_mean_{s}" for s in SHDF_SCALES)
    + tuple(f"shdf_spread_{s}" for s in SHDF_SCALES[1:])
    + ("agd", "agd_relative", "extremity_distance")
    + tuple(f"distance_q{q}" for q in DISTANCE_QUANTILES)
    + tuple(f"ball_area_{r}" for r in BALL_RADII)
    + tuple(f"log_hks_{t}" for t in HKS_TIMES)
    + tuple(f"normal_dispersion_{s}" for s in NORMAL_SCALES)
    + tuple(f"normal_offset_{s}" for s in NORMAL_SCALES)
)


@dataclass(frozen=True)
class FeatureSpec:
    """How the node graph is sampled (part of a labeller: training and labelling agree)."""

    samples: int = 1024
    seed: int = 0

    def to_dict(self) -> dict[str, int]:
        return {"samples": self.samples, "seed": self.seed}


@dataclass(frozen=True)
class NodeGraph:
    """Nodes of a mesh (faces holding a sample), each face's node, and the node graph.

    Attributes:
        node_faces: (N,) the face each node sits on.
        face_node: (F,) the node whose geodesic cell holds each face.
        cell_area: (N,) area of each node's cell over the surface area (sums to 1).
        pairs: (E, 2) neighbouring nodes; ``lengths`` (E,) their surface distance and
            ``boundary`` (E,) the length of their shared cell boundary, mesh units.
        distances: (N, N) geodesic distances between nodes, units of sqrt(area) (inf
            between unconnected shells).
        positions, normals: (N, 3) node positions (units of sqrt(area), centred) and
            unit normals (area-weighted over the cell).
        samples_node, samples: the Poisson samples (with each mesh vertex's nearest
            samples) and the node of each; they carry node values back to faces.
    """

    node_faces: NDArray[np.int64]
    face_node: NDArray[np.int64]
    cell_area: NDArray[np.float64]
    pairs: NDArray[np.int64]
    lengths: NDArray[np.float64]
    boundary: NDArray[np.float64]
    distances: NDArray[np.float64]
    positions: NDArray[np.float64]
    normals: NDArray[np.float64]
    samples_node: NDArray[np.int64]
    samples: object

    @property
    def node_count(self) -> int:
        return int(len(self.node_faces))


def node_graph(mesh: TriangleMesh, graph: FaceGraph, spec: FeatureSpec) -> NodeGraph:
    """The geodesic Voronoi node graph of ``mesh`` (oriented) over its face graph ``graph``."""
    mesh = mesh.oriented
    normals, areas = mesh.normals_and_areas
    total_area = float(areas.sum())
    if not total_area > 0 or not math.isfinite(total_area):
        raise InvalidGeometryError("the mesh has no surface area: every triangle is degenerate")
    unit = math.sqrt(total_area)
    samples = sample_surface_points(
        mesh.vertices,
        mesh.faces,
        spec.samples,
        seed=spec.seed,
        normals=normals,
        areas=areas,
        workers=1,
    )
    node_faces, samples_node = np.unique(samples.face_ids, return_inverse=True)
    centroids = face_centroids(mesh.vertices, mesh.faces)
    face_count = mesh.face_count

    # Geodesic Voronoi cells: multi-source Dijkstra over face centroids.
    a, b = graph.pairs[:, 0], graph.pairs[:, 1]
    step = np.linalg.norm(centroids[a] - centroids[b], axis=1) + 1e-12 * unit
    adjacency = sp.csr_matrix(
        (np.r_[step, step], (np.r_[a, b], np.r_[b, a])), shape=(face_count, face_count)
    )
    reach, _, source = dijkstra(
        adjacency, indices=node_faces, min_only=True, return_predecessors=True
    )
    node_of_face = np.full(face_count, -1, dtype=np.int64)
    node_of_face[node_faces] = np.arange(len(node_faces))
    face_node = np.where(source >= 0, node_of_face[np.maximum(source, 0)], -1)
    lost = np.flatnonzero(face_node < 0)  # shells without a sample: the nearest node
    if len(lost):
        _, nearest = cKDTree(centroids[node_faces]).query(centroids[lost])
        face_node[lost] = nearest
        reach[lost] = np.linalg.norm(centroids[lost] - centroids[node_faces[nearest]], axis=1)
    node_count = len(node_faces)
    cell_area = np.bincount(face_node, weights=areas, minlength=node_count) / total_area

    # Node graph: cells that share a face edge.
    na, nb = face_node[a], face_node[b]
    cross = np.flatnonzero(na != nb)
    low, high = np.minimum(na[cross], nb[cross]), np.maximum(na[cross], nb[cross])
    key = low * node_count + high
    order = np.argsort(key, kind="stable")
    key = key[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    pairs = np.stack([key[starts] // node_count, key[starts] % node_count], axis=1)
    # Neighbouring nodes are about one Poisson radius apart: the straight segment between
    # them is the surface distance up to a tessellation-independent error, where paths
    # over face centroids zig-zag more on coarse meshes than on fine ones.
    node_points = centroids[node_faces]
    lengths = np.linalg.norm(node_points[pairs[:, 0]] - node_points[pairs[:, 1]], axis=1)
    lengths = np.maximum(lengths, 1e-9 * unit)
    boundary = np.add.reduceat(graph.edge_length[cross][order], starts) if len(starts) else lengths
    # Distances run over neighbours and neighbours' neighbours (straight segments): more
    # directions per node, so shortest paths zig-zag less whatever the cells' shapes.
    ring = sp.csr_matrix(
        (
            np.ones(2 * len(pairs)),
            (np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]]),
        ),
        shape=(node_count, node_count),
    )
    reach_two = sp.triu(ring + ring @ ring, k=1).tocoo()
    chord = np.linalg.norm(node_points[reach_two.row] - node_points[reach_two.col], axis=1)
    node_adjacency = sp.csr_matrix(
        (np.maximum(chord, 1e-9 * unit) / unit, (reach_two.row, reach_two.col)),
        shape=(node_count, node_count),
    )
    distances = dijkstra(node_adjacency, directed=False)

    weighted = normals * areas[:, None]
    node_normals = np.zeros((node_count, 3))
    for axis in range(3):
        node_normals[:, axis] = np.bincount(
            face_node, weights=weighted[:, axis], minlength=node_count
        )
    length = np.linalg.norm(node_normals, axis=1, keepdims=True)
    node_normals = np.divide(
        node_normals, length, out=np.zeros_like(node_normals), where=length > 0
    )
    positions = centroids[node_faces]
    positions = (positions - positions.mean(axis=0)) / unit
    return NodeGraph(
        node_faces=node_faces.astype(np.int64),
        face_node=face_node,
        cell_area=cell_area,
        pairs=pairs.astype(np.int64),
        lengths=lengths,
        boundary=boundary,
        distances=distances,
        positions=positions,
        normals=node_normals,
        samples_node=samples_node.astype(np.int64),
        samples=samples,
    )


def node_features(nodes: NodeGraph, face_shdf: NDArray, face_areas: NDArray) -> NDArray[np.float32]:
    """(N, len(FEATURE_NAMES)) features of each node (see the module doc)."""
    n = nodes.node_count
    area = nodes.cell_area
    finite = np.isfinite(nodes.distances)
    distance = np.where(finite, nodes.distances, 0.0)
    reach_weight = finite * area[None, :]
    reach_area = np.maximum(reach_weight.sum(axis=1), 1e-12)

    shdf_area = np.bincount(
        nodes.face_node, weights=np.asarray(face_shdf) * face_areas, minlength=n
    )
    cell_faces_area = np.bincount(nodes.face_node, weights=face_areas, minlength=n)
    shdf = shdf_area / np.maximum(cell_faces_area, 1e-300)

    columns: list[NDArray] = [shdf]
    kernels = {}
    for scale in sorted(set(SHDF_SCALES) | set(NORMAL_SCALES)):
        weights = np.where(finite, np.exp(-0.5 * (distance / scale) ** 2), 0.0) * area[None, :]
        kernels[scale] = weights / weights.sum(axis=1, keepdims=True)
    for scale in SHDF_SCALES:
        columns.append(kernels[scale] @ shdf)
    for scale in SHDF_SCALES[1:]:
        mean = kernels[scale] @ shdf
        columns.append(np.sqrt(np.maximum(kernels[scale] @ shdf**2 - mean**2, 0.0)))

    agd = (distance * area[None, :]).sum(axis=1) / reach_area
    columns += [agd, agd / max(float(agd.min()), 1e-12)]
    near = finite & (distance < EXTREMITY_RADIUS)
    local_max = np.where(near, agd[None, :], -np.inf).max(axis=1)
    extremity = (agd >= local_max) & (agd > np.median(agd))
    if not extremity.any():
        extremity = agd >= agd.max()
    ext_distance = np.where(finite[:, extremity], distance[:, extremity], np.inf).min(axis=1)
    columns.append(np.where(np.isfinite(ext_distance), ext_distance, 0.0))

    order = np.argsort(np.where(finite, distance, np.inf), axis=1, kind="stable")
    sorted_distance = np.take_along_axis(distance, order, axis=1)
    cumulative = np.cumsum(np.take_along_axis(reach_weight, order, axis=1), axis=1)
    cumulative /= reach_area[:, None]
    for quantile in DISTANCE_QUANTILES:
        index = np.minimum((cumulative < quantile - 1e-9).sum(axis=1), n - 1)
        columns.append(sorted_distance[np.arange(n), index])
    for radius in BALL_RADII:
        columns.append(((distance < radius) * reach_weight).sum(axis=1) / (math.pi * radius**2))

    columns += list(heat_kernel_signature(nodes))

    for scale in NORMAL_SCALES:
        mean_normal = kernels[scale] @ nodes.normals
        columns.append(1.0 - np.linalg.norm(mean_normal, axis=1))
    for scale in NORMAL_SCALES:
        offset = kernels[scale] @ nodes.positions - nodes.positions
        columns.append(np.einsum("ij,ij->i", offset, nodes.normals) / scale)
    features = np.stack(columns, axis=1)
    if features.shape[1] != len(FEATURE_NAMES):
        raise AssertionError("feature columns and FEATURE_NAMES disagree")
    return features.astype(np.float32)


def heat_kernel_signature(nodes: NodeGraph) -> NDArray[np.float64]:
    """(len(HKS_TIMES), N) log of the scaled heat kernel signature (each time's values over
    their area-weighted mean) from the node graph's finite-volume Laplacian."""
    n = nodes.node_count
    flux = nodes.boundary / np.maximum(nodes.lengths, 1e-300)
    i, j = nodes.pairs[:, 0], nodes.pairs[:, 1]
    weights = sp.csr_matrix((np.r_[flux, flux], (np.r_[i, j], np.r_[j, i])), shape=(n, n))
    laplacian = sp.diags(np.asarray(weights.sum(axis=1)).ravel()) - weights
    mass = np.maximum(nodes.cell_area, 1e-12)
    count = min(HKS_EIGENPAIRS, n - 2)
    if count < 2:
        return np.zeros((len(HKS_TIMES), n))
    # Symmetric form M^-1/2 L M^-1/2; its smallest eigenpairs by shift-invert Lanczos
    # from a fixed start vector (deterministic; squares of eigenvectors ignore their sign).
    scale = sp.diags(1.0 / np.sqrt(mass))
    symmetric = (scale @ laplacian @ scale).tocsc()
    values, vectors = eigsh(symmetric, k=count, sigma=-1e-3, which="LM", v0=np.ones(n))
    order = np.argsort(values)
    values = np.maximum(values[order], 0.0)
    vectors = vectors[:, order] / np.sqrt(mass)[:, None]
    out = np.empty((len(HKS_TIMES), n))
    for row, time in enumerate(HKS_TIMES):
        signature = (np.exp(-values * time)[None, :] * vectors**2).sum(axis=1)
        out[row] = np.log(signature / max(float(signature @ mass), 1e-300))
    return out


def node_labels(nodes: NodeGraph, face_labels: NDArray, face_areas: NDArray) -> NDArray[np.int64]:
    """The label covering most of each node's cell (any integers; ties: the smallest)."""
    values, classes = np.unique(np.asarray(face_labels, dtype=np.int64), return_inverse=True)
    votes = np.zeros((nodes.node_count, len(values)))
    np.add.at(votes, (nodes.face_node, classes), face_areas)
    return values[votes.argmax(axis=1)]
