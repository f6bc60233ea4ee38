"""What the orientation pass adds to the default ShDF at about 1M faces, side by side.

Meshes: a generated icosphere of 1.3M faces and, where ../shared/data is present, a
dense-dev scan Loop-subdivided past 900k faces; each as given and with every face
reversed. Each case is run two ways on a fresh ``TriangleMesh``, in turns:

* ``trusted``: the outward-facing triangles with their orientation given (no triangle
  reversed, the diagnostics filled in): ``compute_shdf`` without the pass, what a
  pipeline that trusted a correct file would do;
* ``full``: the file as given (for ``reversed``, every face backwards), ``compute_shdf``
  from scratch: the pass, the oriented copy where faces are reversed, and everything else.

Both run on the mesh listed by position (``TriangleMesh.listing``, where the pass, the
ShDF and the segmentation work since version 24; the ``listing`` stage, the same work in
both runs). Per case, seconds wall (CPU of the process), medians over ``--repeat`` turns:
the trusted run's stages (``shared``: welding, sorted edges, stitching, normals and areas;
``graph``: the diagnostics and the face graph; ``ShDF``: the rest of ``compute_shdf``,
its rays and post-processing); the full run's ``pass`` (``orientation``, ``oriented``,
``diagnostics``; the face graph's links are worked out beside it, in a second thread);
and ``added``, per turn the full run's pass and face graph less the trusted run's face
graph (the pass moves the links' work out of the graph stage, so the two are counted
together), its median: what not trusting the winding costs. Ratios: ``added / ShDF``
(over the rays and post-processing only, the strict one) and ``added / all`` (over the
whole trusted ``compute_shdf``). The two runs' ShDF stages do the same work and are not
differenced: their turn-to-turn spread (~0.1 s) is larger than the pass. The ShDF's
rays use every core and the pass two threads, so on a loaded machine the wall clock
mostly measures waiting for a core; the load average is printed with them.

    python benchmarks/bench_orientation.py [--scan lucy] [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from neural_shdf.mesh import TriangleMesh
from neural_shdf.orientation import Orientation
from neural_shdf.pipeline import compute_shdf, warm_up

DENSE = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "dense-dev"
STAGES = ("listing", "shared", "graph", "ShDF")


def timed(function: Callable[[], Any]) -> tuple[float, float]:
    """(wall, CPU of the process) seconds of one call."""
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return time.perf_counter() - wall, time.process_time() - cpu


def trusted_run(
    vertices: np.ndarray, faces: np.ndarray, orientation: Orientation
) -> dict[str, tuple[float, float]]:
    """Stages of ``compute_shdf`` on a fresh mesh whose listing's orientation is given."""
    mesh = TriangleMesh(vertices, faces)
    stages = {"listing": timed(lambda: mesh.listing)}
    listed = mesh.listing[0]
    listed.__dict__["orientation"] = orientation
    stages["shared"] = timed(
        lambda: (listed.welded_faces, listed.welded_edges, listed.normals_and_areas)
    )
    stages["graph"] = timed(lambda: (mesh.diagnostics, mesh.distinct.mesh.face_graph))
    stages["ShDF"] = timed(lambda: compute_shdf(mesh))
    return stages


def full_run(vertices: np.ndarray, faces: np.ndarray) -> dict[str, tuple[float, float]]:
    """Stages of ``compute_shdf`` on a fresh mesh of the file as given, the pass among them."""
    mesh = TriangleMesh(vertices, faces)
    stages = {"listing": timed(lambda: mesh.listing)}
    listed = mesh.listing[0]
    stages["shared"] = timed(
        lambda: (listed.welded_faces, listed.welded_edges, listed.normals_and_areas)
    )
    stages["pass"] = timed(lambda: (mesh.orientation, mesh.distinct, mesh.diagnostics))
    stages["graph"] = timed(lambda: mesh.distinct.mesh.face_graph)
    stages["ShDF"] = timed(lambda: compute_shdf(mesh))
    return stages


def outward(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, Orientation]:
    """The outward-facing triangles of ``faces`` and their listing's orientation, nothing
    reversed (the pass runs on ``TriangleMesh.listing``)."""
    straight = np.ascontiguousarray(TriangleMesh(vertices, faces).oriented.faces)
    found = TriangleMesh(vertices, straight).listing[0].orientation
    trusted = replace(
        found,
        flips=np.zeros_like(found.flips),
        diagnostics=replace(found.diagnostics, reoriented_faces=0),
    )
    return straight, trusted


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scan", default="lucy", help="dense-dev file name part")
    parser.add_argument("--repeat", type=int, default=5)
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
    columns = (*STAGES, "pass", "added", "added/ShDF", "added/all")
    print(f"{'mesh':19s} {'faces':>8s} " + " ".join(f"{name:>14s}" for name in columns))
    for name, (vertices, faces) in meshes.items():
        straight, trusted = outward(vertices, faces)
        for label, given in (("", faces), (" reversed", np.ascontiguousarray(faces[:, ::-1]))):
            full_run(vertices, given)  # first touches of the arrays out of the timings
            turns = []
            for turn in range(args.repeat):
                order = (0, 1) if turn % 2 == 0 else (1, 0)
                runs: list[dict[str, tuple[float, float]]] = [{}, {}]
                for which in order:
                    runs[which] = (
                        trusted_run(vertices, straight, trusted)
                        if which == 0
                        else full_run(vertices, given)
                    )
                turns.append(runs)
            cells = {}
            for stage in STAGES:
                cells[stage] = [float(np.median([t[0][stage][k] for t in turns])) for k in (0, 1)]
            cells["pass"] = [float(np.median([t[1]["pass"][k] for t in turns])) for k in (0, 1)]
            added = [
                [t[1]["pass"][k] + t[1]["graph"][k] - t[0]["graph"][k] for t in turns]
                for k in (0, 1)
            ]
            cells["added"] = [float(np.median(a)) for a in added]
            whole = [sum(cells[s][k] for s in STAGES) for k in (0, 1)]
            ratios = [
                [cells["added"][k] / cells["ShDF"][k] for k in (0, 1)],
                [cells["added"][k] / whole[k] for k in (0, 1)],
            ]
            row = " ".join(f"{cells[s][0]:6.3f} ({cells[s][1]:5.3f})" for s in (*STAGES, "pass"))
            row += f" {cells['added'][0]:6.3f} ({cells['added'][1]:5.3f})"
            row += "".join(f" {r[0]:6.3f} ({r[1]:5.3f})" for r in ratios)
            print(f"{name + label:19s} {len(faces):8d} {row}", flush=True)
            spread = [f"{a:+.3f}" for a in added[0]]
            print(f"{'':19s} added wall per turn: {' '.join(spread)}", flush=True)
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(
        "seconds wall (CPU), medians over turns; added: full - trusted compute_shdf (what not"
        " trusting the winding costs); added/ShDF: over the rays and post-processing;"
        " added/all: over the whole trusted compute_shdf"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
