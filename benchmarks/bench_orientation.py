"""What the orientation pass costs against the default ShDF at about 1M faces, side by side.

Meshes: a generated icosphere of 1.3M faces and, where ../shared/data is present, a
dense-dev scan Loop-subdivided past 900k faces; each as given and with every face
reversed (then the oriented copy of the mesh is built too). Per mesh, seconds (wall and
CPU of the process) on a fresh ``TriangleMesh`` of

* ``shared``: what the face graph and the ShDF need whatever the winding, and the pass
  reads: the welding, the sorted edges, the stitching, normals and areas;
* ``pass``: the orientation pass and diagnostics (``orientation``, ``oriented``,
  ``diagnostics``): what the pipeline does only because it does not trust the winding;
* ``graph``: the face graph (``face_graph``), built for the ShDF's post-processing;
* ``ShDF``: the rest of ``compute_shdf(mesh)`` (``auto``: its rays and post-processing);

and two ratios, wall (CPU): ``pass / ShDF`` (the strict one: the ShDF without the graph
and the shared steps, which it needs too) and ``pass / all`` (over shared + graph + ShDF:
everything else ``compute_shdf`` on a fresh mesh costs). The pass is single-threaded and
the ShDF's rays use every core, so on an idle machine the wall ratio is above the CPU
one; on a loaded one the wall clock mostly measures waiting for a core. Best of
``--repeat`` runs (by the pass's CPU time); the load average is printed with them.

    python benchmarks/bench_orientation.py [--scan lucy] [--repeat 2]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import compute_shdf, warm_up

DENSE = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "dense-dev"
STAGES = ("shared", "pass", "graph", "ShDF")


def timed(function: Callable[[], Any]) -> tuple[float, float]:
    """(wall, CPU of the process) seconds of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return time.perf_counter() - wall, time.process_time() - cpu


def stages(vertices: np.ndarray, faces: np.ndarray) -> dict[str, tuple[float, float]]:
    """(wall, CPU) of each stage on a fresh mesh, in the order the pipeline needs them."""
    mesh = TriangleMesh(vertices, faces)
    return {
        "shared": timed(lambda: (mesh.welded_faces, mesh.welded_edges, mesh.normals_and_areas)),
        "pass": timed(lambda: (mesh.orientation, mesh.oriented, mesh.diagnostics)),
        "graph": timed(lambda: mesh.face_graph),
        "ShDF": timed(lambda: compute_shdf(mesh)),
    }


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
    print(f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(
        f"{'mesh':19s} {'faces':>8s} "
        + " ".join(f"{name:>14s}" for name in STAGES)
        + f" {'pass/ShDF':>14s} {'pass/all':>14s}"
    )
    for name, (vertices, faces) in meshes.items():
        for label, given in (("", faces), (" reversed", np.ascontiguousarray(faces[:, ::-1]))):
            runs = [stages(vertices, given) for _ in range(args.repeat)]
            best = min(runs, key=lambda run: run["pass"][1])
            rest = [sum(best[stage][k] for stage in ("shared", "graph", "ShDF")) for k in (0, 1)]
            cells = " ".join(f"{best[s][0]:6.3f} ({best[s][1]:5.3f})" for s in STAGES)
            strict = [best["pass"][k] / best["ShDF"][k] for k in (0, 1)]
            whole = [best["pass"][k] / rest[k] for k in (0, 1)]
            print(
                f"{name + label:19s} {len(faces):8d} {cells} "
                f"{strict[0]:6.3f} ({strict[1]:5.3f}) {whole[0]:6.3f} ({whole[1]:5.3f})"
            )
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(
        "seconds wall (CPU); pass/ShDF: the pass over the ShDF's rays and post-processing;"
        " pass/all: over everything else compute_shdf does on a fresh mesh"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
