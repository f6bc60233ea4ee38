"""The library's front door: mesh -> ShDF -> labels, each step explicit and reusable.

Every array here is per triangle of ``mesh`` (``TriangleMesh.faces``); map to the
input file's faces with ``mesh.to_input_faces`` / ``mesh.labels_to_input_faces``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import NDArray

from neural_shdf.geometry import FaceGraph, build_face_graph, weld_faces
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment import SegmentParams

if TYPE_CHECKING:
    from neural_shdf.segment.pipeline import SegmentResult

ShdfMethod = Literal["exact", "neural"]
Progress = Callable[[float], None]


def mesh_face_graph(mesh: TriangleMesh) -> FaceGraph:
    """Face adjacency of the mesh with coincident vertices welded (input order kept)."""
    normals, _ = mesh.normals_and_areas
    return build_face_graph(mesh.vertices, weld_faces(mesh.vertices, mesh.faces), normals)


def compute_shdf(
    mesh: TriangleMesh,
    *,
    method: ShdfMethod = "neural",
    seed: int = 0,
    graph: FaceGraph | None = None,
    progress: Progress | None = None,
) -> NDArray[np.float64]:
    """Post-processed ShDF in [0, 1] per triangle (exact rays or the neural predictor).

    ``seed``: 0..``MAX_SEED``; by convention the segmentation's ``SegmentParams.seed``.
    """
    from neural_shdf.segment.params import check_seed

    seed = check_seed(seed)
    graph = mesh_face_graph(mesh) if graph is None else graph
    if method == "exact":
        from neural_shdf.shdf.exact import exact_shdf

        return exact_shdf(mesh, graph=graph, seed=seed, progress=progress)
    if method == "neural":
        from neural_shdf.shdf.neural import neural_shdf

        return neural_shdf(mesh, graph=graph, seed=seed, progress=progress)
    raise ValueError(f"unknown ShDF method {method!r}; use 'exact' or 'neural'")


def segment_mesh(
    mesh: TriangleMesh,
    shdf: NDArray,
    params: SegmentParams | None = None,
    *,
    graph: FaceGraph | None = None,
) -> NDArray[np.int64]:
    """Part label per triangle, 0..P-1, from a ShDF in [0, 1]; deterministic."""
    return segment_mesh_with_details(mesh, shdf, params, graph=graph).labels


def segment_mesh_with_details(
    mesh: TriangleMesh,
    shdf: NDArray,
    params: SegmentParams | None = None,
    *,
    graph: FaceGraph | None = None,
) -> SegmentResult:
    """``segment_mesh`` plus the graph cut's part tree, the mixture size and timings."""
    from neural_shdf.segment.pipeline import segment_with_details

    graph = mesh_face_graph(mesh) if graph is None else graph
    _, areas = mesh.normals_and_areas
    return segment_with_details(
        mesh.vertices, mesh.faces, np.asarray(shdf), params or SegmentParams(), graph, areas=areas
    )


def input_face_labels(mesh: TriangleMesh, labels: NDArray) -> NDArray[np.int64]:
    """One label per face of the input file, in its order (a polygon split into triangles
    takes the label covering most of its area): ``mesh.labels_to_input_faces``."""
    return mesh.labels_to_input_faces(labels)


def input_face_shdf(mesh: TriangleMesh, values: NDArray) -> NDArray[np.float64]:
    """One ShDF value per face of the input file, in its order (area-weighted mean over a
    polygon's triangles): ``mesh.to_input_faces``."""
    return mesh.to_input_faces(values)


def input_face_parts(
    mesh: TriangleMesh, result: SegmentResult
) -> tuple[NDArray[np.int64], NDArray[np.int64] | None]:
    """(part label, leaf of the part tree or None) per input face; -1 for faces without triangles.

    With a tree, the input faces' labels are the tree's cut of their leaves, so a
    client that re-cuts the tree (see ``export.part_tree_document``) gets the same.
    """
    if result.tree is None:
        return input_face_labels(mesh, result.labels), None
    leaves = input_face_labels(mesh, result.tree.leaf_labels)
    return result.tree.relabel(leaves, result.part_count), leaves


def warm_up(methods: tuple[ShdfMethod, ...] = ("exact", "neural")) -> float:
    """Run a small generated sphere through the face graph, each ShDF ``method`` and both
    partitioners, so that the compiled kernels are built (first run after an install) or
    loaded from their cache and the model session exists. Seconds taken; a neural model
    that cannot load is skipped (its error surfaces where it is used).
    """
    import trimesh

    from neural_shdf.errors import ModelUnavailableError

    start = time.perf_counter()
    sphere = trimesh.creation.icosphere(subdivisions=2)
    mesh = TriangleMesh(sphere.vertices, sphere.faces)
    graph = mesh_face_graph(mesh)
    for method in methods:
        try:
            shdf = compute_shdf(mesh, method=method, graph=graph)
        except ModelUnavailableError:
            continue
        for params in (SegmentParams(), SegmentParams(partitioner="metis", parts=2)):
            segment_mesh(mesh, shdf, params, graph=graph)
    return time.perf_counter() - start
