"""The library's front door: mesh -> ShDF -> labels, each step explicit and reusable.

Every array here is per triangle of ``mesh`` (``TriangleMesh.faces``); map to the
input file's faces with ``mesh.to_input_faces`` / ``mesh.labels_to_input_faces``.
Every step works on ``mesh.oriented`` (each shell facing out of its solid, whatever
the file's winding; ``orientation``), whose triangles are ``mesh``'s in the same
order; ``mesh`` itself is never changed. ``mesh.orientation.diagnostics`` says what
the mesh had (shells, holes, non-manifold edges, reversed, degenerate and duplicate
faces); the ShDF and segmentation results carry it too.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from neural_shdf.geometry import FaceGraph, build_face_graph
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment import SegmentParams
from neural_shdf.shdf.stage import ShdfMethod, ShdfParams, ShdfResult, run_shdf, with_seed

if TYPE_CHECKING:
    from neural_shdf.segment.creases import CreaseGraph
    from neural_shdf.segment.pipeline import SegmentBasis, SegmentResult
    from neural_shdf.shdf.neural.inference import NeuralModel

Progress = Callable[[float], None]


def mesh_face_graph(mesh: TriangleMesh) -> FaceGraph:
    """Face adjacency of the mesh with coincident vertices welded (input order kept); its
    dihedral angles and concave flags follow the oriented normals (``mesh.oriented``)."""
    oriented = mesh.oriented
    normals, _ = oriented.normals_and_areas
    return build_face_graph(
        oriented.vertices, oriented.welded_faces, normals, edges=oriented.welded_edges
    )


def compute_shdf(
    mesh: TriangleMesh,
    *,
    method: ShdfMethod = "auto",
    seed: int | None = None,
    graph: FaceGraph | None = None,
    progress: Progress | None = None,
    model: NeuralModel | str | Path | None = None,
    params: ShdfParams | None = None,
) -> NDArray[np.float64]:
    """Post-processed ShDF in [0, 1] per triangle (``shdf.stage``: one raw-diameter
    producer, then one post-processing). ``method``: ``auto`` (default; the producer
    ``resolve_method`` picks for the mesh), ``exact``, ``sampled`` or ``neural``;
    ``model``: the network ``neural`` runs (a loaded model or an ONNX path; default the
    installed one); ``seed``, when given, replaces ``params.seed``. ``compute_shdf_result`` also
    says which producer ran."""
    return compute_shdf_result(
        mesh, method=method, seed=seed, graph=graph, progress=progress, model=model, params=params
    ).values


def compute_shdf_result(
    mesh: TriangleMesh,
    *,
    method: ShdfMethod = "auto",
    seed: int | None = None,
    graph: FaceGraph | None = None,
    progress: Progress | None = None,
    model: NeuralModel | str | Path | None = None,
    params: ShdfParams | None = None,
) -> ShdfResult:
    """``compute_shdf`` with the producer that ran (``ShdfResult.method``). ``seed``:
    0..``MAX_SEED``; by convention the segmentation's ``SegmentParams.seed``."""
    from neural_shdf.segment.params import check_seed

    seed = None if seed is None else check_seed(seed)
    graph = mesh_face_graph(mesh) if graph is None else graph
    return run_shdf(
        mesh,
        graph,
        method=method,
        params=with_seed(params, seed),
        model=model,
        progress=progress,
    )


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
    basis: SegmentBasis | None = None,
) -> SegmentResult:
    """``segment_mesh`` plus the graph cut's part tree, the mixture size and timings.

    ``basis``: ``prepare_segment_mesh``'s result for this mesh, ShDF, clusters and seed;
    keep it to re-segment with other smoothing, parts or refinement values cheaply.
    """
    from neural_shdf.segment.pipeline import segment_with_details

    arguments, areas = _segment_arguments(mesh, shdf, params, graph)
    result = segment_with_details(*arguments, areas=areas, basis=basis)
    result.diagnostics = mesh.orientation.diagnostics
    return result


def prepare_segment_mesh(
    mesh: TriangleMesh,
    shdf: NDArray,
    params: SegmentParams | None = None,
    *,
    graph: FaceGraph | None = None,
    creases: CreaseGraph | None = None,
) -> SegmentBasis:
    """What every segmentation of ``mesh`` with this ShDF, ``params.clusters`` and
    ``params.seed`` shares (mixture, data costs, the graph cut's coarse graphs): pass it
    to ``segment_mesh_with_details`` to try other smoothing or part counts quickly.
    ``creases``: ``mesh_crease_graph(mesh, graph)`` where the caller keeps it per mesh."""
    from neural_shdf.segment.pipeline import prepare_segment

    arguments, areas = _segment_arguments(mesh, shdf, params, graph)
    return prepare_segment(*arguments, areas=areas, creases=creases)


def _segment_arguments(
    mesh: TriangleMesh, shdf: NDArray, params: SegmentParams | None, graph: FaceGraph | None
) -> tuple[tuple[NDArray, NDArray, NDArray, SegmentParams, FaceGraph], NDArray]:
    """(vertices, faces, ShDF, params, graph) for ``segment.pipeline``, and the face areas
    the mesh caches; the default params and the welded face graph where none are given."""
    graph = mesh_face_graph(mesh) if graph is None else graph
    mesh = mesh.oriented
    _, areas = mesh.normals_and_areas
    return (mesh.vertices, mesh.faces, np.asarray(shdf), params or SegmentParams(), graph), areas


def mesh_crease_graph(mesh: TriangleMesh, graph: FaceGraph | None = None) -> CreaseGraph:
    """The graph the crease refinement runs on (``segment.creases.crease_graph``); it
    depends on the mesh only, so a caller may keep it for every ShDF and mixture."""
    from neural_shdf.geometry import face_centroids
    from neural_shdf.segment.creases import crease_graph

    graph = mesh_face_graph(mesh) if graph is None else graph
    _, areas = mesh.normals_and_areas
    return crease_graph(graph, areas, face_centroids(mesh.vertices, mesh.faces))


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


def warm_up(methods: tuple[ShdfMethod, ...] = ("exact", "sampled", "neural")) -> float:
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
    # The multilevel graph cut's coarsening (meshes above COARSE_NODES faces), on any ShDF.
    from neural_shdf.segment.graphcut import cut_hierarchy

    ramp = np.linspace(0.0, 1.0, len(mesh.faces))
    basis = prepare_segment_mesh(mesh, ramp, SegmentParams(), graph=graph)
    centroids, areas = basis.geometry.centroids, basis.geometry.areas
    coarse = cut_hierarchy(basis.data, graph.pairs, basis.unit_weights, centroids, areas, 40)
    coarse.solve(0.06)
    if "exact" in methods:  # the patch filter of wide windows (meshes above ~100k faces)
        from neural_shdf.shdf.postprocess import EXACT_WINDOW_MAX

        wide = ShdfParams(window_size=EXACT_WINDOW_MAX + 1)
        compute_shdf(mesh, method="exact", graph=graph, params=wide)
    return time.perf_counter() - start
