"""What the orientation pass costs against the default ShDF at about 1M faces, side by side.

Meshes: a generated icosphere of 1.3M faces and, where ../shared/data is present, a
dense-dev scan Loop-subdivided past 900k faces; each as given and with every face
reversed (then the oriented copy of the mesh is built too). Per mesh: seconds (wall and
CPU) of ``TriangleMesh.orientation`` plus ``oriented`` (the edge sort it shares with the
face graph is counted apart), of the default ShDF (``compute_shdf``, ``auto``),
and their ratio. Best of ``--repeat`` runs.

    python benchmarks/bench_orientation.py [--scan lucy] [--repeat 2]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import trimesh

from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import compute_shdf, warm_up

DENSE = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "dense-dev"


def timed(function) -> tuple[float, float]:
    """(wall, CPU of the process) seconds of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return time.perf_counter() - wall, time.process_time() - cpu


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scan", default="lucy", help="dense-dev file name part")
    parser.add_argument("--repeat", type=int, default=2)
    args = parser.parse_args()
    sphere = trimesh.creation.icosphere(subdivisions=8)
    meshes = {"icosphere": (np.asarray(sphere.vertices), np.asarray(sphere.faces))}
    scans = sorted(DENSE.glob(f"*{args.scan}*.ply")) if DENSE.is_dir() else []
    if scans:
        scan = trimesh.load(scans[0], process=False)
        vertices, faces = np.asarray(scan.vertices), np.asarray(scan.faces)
        while len(faces) < 900_000:
            vertices, faces = trimesh.remesh.subdivide(vertices, faces)
        meshes[scans[0].stem.split("__")[-1]] = (vertices, faces)
    warm_up(("exact", "sampled"))
    print(
        f"{'mesh':22s} {'faces':>9s} {'edge sort':>10s} {'orient':>15s} "
        f"{'ShDF':>15s} {'ratio':>13s}"
    )
    for name, (vertices, faces) in meshes.items():
        for label, given in (("", faces), (" reversed", faces[:, ::-1])):
            best = None
            for _ in range(args.repeat):
                mesh = TriangleMesh(vertices, given)
                _ = mesh.welded_faces, mesh.normals_and_areas
                edges = timed(lambda m=mesh: m.welded_edges)
                orient = timed(lambda m=mesh: m.oriented)
                _ = mesh.face_graph  # counted apart
                shdf = timed(lambda m=mesh: compute_shdf(m))
                if best is None or orient[0] + shdf[0] < best[1][0] + best[2][0]:
                    best = (edges, orient, shdf)
            edges, orient, shdf = best
            print(
                f"{name + label:22s} {len(faces):9d} {edges[0]:10.3f} "
                f"{orient[0]:6.3f} (cpu {orient[1]:.2f}) {shdf[0]:6.3f} (cpu {shdf[1]:.2f}) "
                f"{orient[0] / shdf[0]:5.3f} ({orient[1] / shdf[1]:.3f})"
            )
    print(
        "ratio: orientation / default ShDF, wall (CPU); the edge sort is shared with the"
        " face graph, which sorted the same edges before"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
