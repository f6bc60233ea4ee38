"""What proximity stitching costs at about 1M faces, against the welding it refines.

Meshes: a dense-dev scan Loop-subdivided past 900k faces (horse_head: 1.0M, open), as
given and as the ``shells`` variant of ``bench_production.py`` (4 patches made open
shells, each moved by ``--move`` of the bounding diagonal). Per mesh: seconds of the
coincident welding and its edge sort (``TriangleMesh.coincident_welding``), of the
stitching on top (``welded_faces`` and ``welded_edges``: boundary search, shells,
KD-tree, the second edge sort) and their ratio; the default ShDF (``compute_shdf``,
``auto``, on a fresh copy: stitching included) and the stitching's share of it; and the
boundary edges before and after. Best of ``--repeat``.

    python benchmarks/bench_stitching.py [--scan horse_head] [--move 0.01] [--repeat 2]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import trimesh

from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf, warm_up
from neural_shdf.stitching import boundary_edges

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_production import patches, split_vertices  # noqa: E402

DENSE = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "dense-dev"


def best_seconds(mesh: TriangleMesh, repeat: int) -> tuple[float, float]:
    """(coincident welding, stitching on top) seconds on fresh copies of ``mesh``."""
    weld, stitch = [], []
    for _ in range(repeat):
        fresh = mesh.bare()
        start = time.perf_counter()
        _ = fresh.coincident_welding
        middle = time.perf_counter()
        _ = fresh.welded_faces, fresh.welded_edges
        stitch.append(time.perf_counter() - middle)
        weld.append(middle - start)
    return min(weld), min(stitch)


def _timed_shdf(mesh: TriangleMesh) -> float:
    fresh = mesh.bare()
    start = time.perf_counter()
    compute_shdf(fresh)
    return time.perf_counter() - start


def open_edges(faces: np.ndarray, edges: tuple) -> int:
    return len(boundary_edges(edges, int(faces.max()) + 1)[0])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scan", default="horse_head", help="dense-dev file name part")
    parser.add_argument("--move", type=float, default=0.01, help="shell move / diagonal")
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    path = next(iter(sorted(DENSE.glob(f"*{args.scan}*.ply"))), None)
    if path is None:
        print(f"no dense-dev scan matching {args.scan!r} in {DENSE}", file=sys.stderr)
        return 1
    warm_up()
    scan = load_mesh(path)
    dense = trimesh.Trimesh(scan.vertices, scan.faces, process=False)
    while len(dense.faces) < 900_000:
        dense = dense.subdivide_loop(iterations=1)
    v, f = np.asarray(dense.vertices), np.asarray(dense.faces, dtype=np.int64)
    rng = np.random.default_rng(0)
    vertices, faces, vertex_patch = split_vertices(v, f, patches(v, f, 4, rng))
    diagonal = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    directions = rng.normal(size=(int(vertex_patch.max()) + 1, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    shells = vertices + args.move * diagonal * directions[vertex_patch]
    print(f"{path.name}: {len(f)} faces")
    print(
        f"{'mesh':8s} {'weld s':>7s} {'stitch s':>9s} {'ratio':>6s} {'ShDF s':>7s}"
        f" {'share':>6s} {'open before':>12s} {'after':>6s}"
    )
    for name, mesh in (("closed", TriangleMesh(v, f)), ("shells", TriangleMesh(shells, faces))):
        weld, stitch = best_seconds(mesh, args.repeat)
        coincident, edges = mesh.coincident_welding
        before = open_edges(coincident, edges)
        after = open_edges(mesh.welded_faces, mesh.welded_edges)
        shdf = min(_timed_shdf(mesh) for _ in range(args.repeat))
        print(
            f"{name:8s} {weld:7.3f} {stitch:9.3f} {stitch / weld:6.2f} {shdf:7.2f}"
            f" {stitch / shdf:6.1%} {before:12d} {after:6d}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
