"""The library's front door, in CGAL's shape: a mesh, then three separable calls.

    mesh = load_mesh("model.obj")                  # TriangleMesh (``neural_shdf.mesh``)
    shdf = compute_shdf(mesh, seed=params.seed)    # ShdfResult: .values per triangle, [0, 1]
    result = segment(mesh, shdf.values, params)    # SegmentResult: .labels, .tree, ...
    basis = prepare_segment(mesh, shdf.values, params)  # reuse: segment(..., basis=basis)

``TriangleMesh`` caches what is derived from it (normals, areas, the orientation, the face
graph, centroids, the crease graph), so the calls share them; ``segment`` takes any
per-face ShDF in [0, 1], and its partitioner (``SegmentParams.partitioner``) is a strategy
of ``segment.partitioners``.

Every array here is per triangle of ``mesh`` (``TriangleMesh.faces``); map to the
input file's faces with ``mesh.to_input_faces`` / ``mesh.labels_to_input_faces`` /
``SegmentResult.input_face_parts``. Every step works on ``mesh.oriented`` (each shell
facing out of its solid, whatever the file's winding; ``orientation``), whose triangles
are ``mesh``'s in the same order; ``mesh`` itself is never changed.
``mesh.diagnostics`` says what the mesh had (shells, holes, non-manifold
edges, reversed, degenerate and duplicate faces, shells stitched); the ShDF and segmentation results
carry it too.
"""

from __future__ import annotations

import time

import numpy as np

from neural_shdf.errors import ModelUnavailableError
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment.basis import SegmentBasis
from neural_shdf.segment.from_shdf import SegmentResult, prepare_segment, segment
from neural_shdf.segment.graphcut import cut_hierarchy
from neural_shdf.segment.params import SegmentParams
from neural_shdf.shdf.postprocess import EXACT_WINDOW_MAX
from neural_shdf.shdf.stage import ShdfMethod, ShdfParams, ShdfResult, compute_shdf

__all__ = [
    "SegmentBasis",
    "SegmentParams",
    "SegmentResult",
    "ShdfParams",
    "ShdfResult",
    "TriangleMesh",
    "compute_shdf",
    "prepare_segment",
    "segment",
    "warm_up",
]


def warm_up(methods: tuple[ShdfMethod, ...] = ("exact", "sampled", "neural")) -> float:
    """Run a small generated sphere through the face graph, each ShDF ``method`` and both
    partitioners, so that the compiled kernels are built (first run after an install) or
    loaded from their cache and the model session exists. Seconds taken; a neural model
    that cannot load is skipped (its error surfaces where it is used).
    """
    import trimesh  # only here: the CLI's import stays light

    start = time.perf_counter()
    sphere = trimesh.creation.icosphere(subdivisions=2)
    mesh = TriangleMesh(sphere.vertices, sphere.faces)
    for method in methods:
        try:
            shdf = compute_shdf(mesh, method=method).values
        except ModelUnavailableError:
            continue
        for params in (SegmentParams(), SegmentParams(partitioner="metis", parts=2)):
            segment(mesh, shdf, params)
    # The multilevel graph cut's coarsening (meshes above COARSE_NODES faces), on any ShDF;
    # asked for 1 node it stalls, so its solve also coarsens past the stall.
    ramp = np.linspace(0.0, 1.0, len(mesh.faces))
    basis = prepare_segment(mesh, ramp, SegmentParams())
    centroids, areas = basis.geometry.centroids, basis.geometry.areas
    graph = mesh.face_graph
    for lengths in (None, graph.edge_length):  # fine tessellations judge creases per length
        coarse = cut_hierarchy(
            basis.data, graph.pairs, basis.unit_weights, centroids, areas, 1, lengths=lengths
        )
        coarse.solve(0.06)
    from neural_shdf.exchange._usda_arrays import warm_up as warm_up_usda

    warm_up_usda()  # the .usda array kernel
    # The oriented copy of an inside-out file (its reversed rows, edge slots and normals).
    _ = TriangleMesh(sphere.vertices, np.asarray(sphere.faces)[:, ::-1]).oriented
    if "exact" in methods:  # the patch filter of wide windows (meshes above ~100k faces)
        wide = ShdfParams(window_size=EXACT_WINDOW_MAX + 1)
        compute_shdf(mesh, method="exact", params=wide)
    return time.perf_counter() - start
