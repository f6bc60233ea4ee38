"""Part hierarchy speed on a ~1M-face mesh from a cached ShDF: tree build + cut, later cuts.

Mesh: psb-dev 82 (an ant, 16.6k faces) subdivided three times (1.06M faces)
where ``../shared/data`` exists, else the 1M-face dumbbell. ShDF: the exact
ShDF of the base mesh, each subdivided face taking its nearest base face's
value (a realistic per-face field; "cached" means it is given). The face graph
is built first and reported apart (it is cached with the mesh in the service).

Rows (wall and CPU seconds, best of ``--repeat``; ratio = time / target):

* ``segment``: the whole re-segmentation from the cached ShDF with default
  parameters: mixture, graph cut (the tree's leaves), tree build, automatic cut;
  target 1.5 s.
* ``creases``: moving the graph cut's part boundaries onto concave creases
  (``segment.creases``, ``crease_boundaries``, on by default; part of ``segment``), from
  the unrefined leaves, with the mesh's crease graph kept (as ``SegmentBasis`` and the
  service keep it); aim 0.15 s. ``crease graph``: building that graph (once per mesh).
* ``resegment``: the same with a kept ``SegmentBasis`` (what the service keeps per
  mesh) and another smoothing value, as a viewer slider asks; target 1.5 s.
* ``tree+cut``: building the merge tree from the leaves and cutting it
  (automatic count); the part of ``segment`` the hierarchy adds.
* ``later cut``: ``PartTree.labels(N)`` for every N in 1..leaves; the worst and
  the median; target 20 ms.

    python benchmarks/bench_hierarchy.py [--repeat 3] [--subdivisions 3]
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh
from timing import best_time

from neural_shdf.geometry import face_centroids
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment.creases import crease_graph, snap_boundaries_to_creases
from neural_shdf.segment.from_shdf import prepare_segment, segment
from neural_shdf.segment.hierarchy import automatic_part_count, merge_tree
from neural_shdf.segment.params import SegmentParams
from neural_shdf.segment.parts import FaceData
from neural_shdf.segment.synthetic import dumbbell
from neural_shdf.shdf.postprocess import log_normalize

REPO_ROOT = Path(__file__).resolve().parents[1]
BASE_MESH = REPO_ROOT / ".." / "shared" / "data" / "psb-dev" / "off" / "82.off"
TARGET_SEGMENT_S = 1.5
TARGET_CUT_S = 0.020
TARGET_CREASES_S = 0.15


def test_mesh(subdivisions: int) -> tuple[str, np.ndarray, np.ndarray, np.ndarray]:
    """(name, vertices, faces, ShDF per face) of the benchmark mesh."""
    if not BASE_MESH.is_file():
        mesh, shdf = dumbbell(1_000_000, ripple=0.05)
        return "dumbbell", np.asarray(mesh.vertices), np.asarray(mesh.faces), shdf
    from scipy.spatial import cKDTree

    from neural_shdf.mesh_io import load_mesh
    from neural_shdf.pipeline import compute_shdf

    base = load_mesh(BASE_MESH)
    base_shdf = compute_shdf(base, method="exact").values
    vertices, faces = base.vertices, base.faces
    for _ in range(subdivisions):
        vertices, faces = trimesh.remesh.subdivide(vertices, faces)
    nearest = cKDTree(face_centroids(base.vertices, base.faces)).query(
        face_centroids(vertices, faces)
    )[1]
    return f"psb-82 x{4**subdivisions}", vertices, faces, base_shdf[nearest]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per case; the best counts")
    parser.add_argument("--subdivisions", type=int, default=3)
    args = parser.parse_args()

    name, vertices, faces, shdf = test_mesh(args.subdivisions)
    start = time.perf_counter()
    mesh = TriangleMesh(vertices, faces)
    graph = mesh.face_graph
    areas = mesh.normals_and_areas[1]
    print(
        f"mesh {name}: {len(faces)} faces; face graph {time.perf_counter() - start:.2f} s "
        "(not counted: cached with the mesh)"
    )

    params = SegmentParams()
    # A mesh with its face graph but not its crease graph, per run (the crease graph is
    # part of a first segmentation's time).
    wall, cpu, result = best_time(lambda: segment(mesh.portable(), shdf, params), args.repeat)
    steps = " ".join(f"{k}={v:.3f}" for k, v in result.timings.items())
    tree = result.tree
    print(f"{'what':<10} {'wall_s':>8} {'cpu_s':>7} {'target_s':>8} {'ratio':>6} {'cpu_ratio':>9}")
    print(
        f"{'segment':<10} {wall:8.3f} {cpu:7.3f} {TARGET_SEGMENT_S:8.3f} "
        f"{wall / TARGET_SEGMENT_S:6.2f} {cpu / TARGET_SEGMENT_S:9.2f}  "
        f"{result.part_count} parts of {tree.leaf_count} leaves; {steps}"
    )

    plain = segment(mesh, shdf, replace(params, crease_boundaries=False))
    centroids = face_centroids(vertices, faces)
    wall, cpu, creases = best_time(lambda: crease_graph(graph, areas, centroids), args.repeat)
    print(
        f"{'crease graph':<10} {wall:8.3f} {cpu:7.3f} {'-':>8} {'-':>6} {'-':>9}  "
        f"{creases.graph.face_count} nodes (once per mesh; included in segment)"
    )
    wall, cpu, snapped = best_time(
        lambda: snap_boundaries_to_creases(
            plain.tree.leaf_labels,
            graph,
            areas,
            centroids,
            params.min_part_fraction,
            creases=creases,
        ),
        args.repeat,
    )
    moved = float(areas[snapped != plain.tree.leaf_labels].sum() / areas.sum())
    print(
        f"{'creases':<10} {wall:8.3f} {cpu:7.3f} {TARGET_CREASES_S:8.3f} "
        f"{wall / TARGET_CREASES_S:6.2f} {cpu / TARGET_CREASES_S:9.2f}  "
        f"{plain.tree.leaf_count} -> {int(snapped.max()) + 1} leaves, {moved:.1%} of the area "
        f"relabelled (leaf ids may shift)"
    )

    basis = prepare_segment(mesh, shdf, params)
    basis.cut(graph)
    _ = mesh.crease_graph  # kept per mesh, as the service keeps it
    other = SegmentParams(smoothing=0.08)
    wall, cpu, again = best_time(lambda: segment(mesh, shdf, other, basis=basis), args.repeat)
    steps = " ".join(f"{k}={v:.3f}" for k, v in again.timings.items())
    print(
        f"{'resegment':<10} {wall:8.3f} {cpu:7.3f} {TARGET_SEGMENT_S:8.3f} "
        f"{wall / TARGET_SEGMENT_S:6.2f} {cpu / TARGET_SEGMENT_S:9.2f}  "
        f"smoothing 0.08, kept basis; {again.part_count} parts; {steps}"
    )

    values = log_normalize(shdf)
    leaves = tree.leaf_labels  # in the file's face order, as the graph and the surface
    surface = FaceData.of(vertices, faces, mesh.normals_and_areas, mesh.centroids)

    def build_and_cut():
        built = merge_tree(leaves, graph, surface, values)
        return built.labels(automatic_part_count(built))

    wall, cpu, _ = best_time(build_and_cut, args.repeat)
    print(
        f"{'tree+cut':<10} {wall:8.3f} {cpu:7.3f} {'-':>8} {'-':>6} {'-':>9}  (included in segment)"
    )

    cut_times = []
    for count in range(1, tree.leaf_count + 1):
        cut_times.append(best_time(lambda count=count: tree.labels(count), args.repeat)[0])
    worst, median = max(cut_times), float(np.median(cut_times))
    print(
        f"{'later cut':<10} {worst:8.4f} {'-':>7} {TARGET_CUT_S:8.3f} "
        f"{worst / TARGET_CUT_S:6.2f} {'-':>9}  worst of N = 1..{tree.leaf_count}; "
        f"median {median * 1000:.1f} ms"
    )


if __name__ == "__main__":
    main()
