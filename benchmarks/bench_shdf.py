"""Speed of the exact ShDF: time and rays per second against face count, and the ratio to CGAL.

Meshes: a torus at ~10k and ~100k faces and an icosphere at ~20k (generated),
a few psb-dev meshes (CGAL's own time for them is in ``cgal/timings.csv``),
and with ``--dense`` the 100k-460k-face scans in ``../shared/data/dense-dev``.
Columns: ray casting alone (Embree, same rays, one thread: one ray per call through
embreex's ``rtcIntersect1``, and our 16-ray packets, with their ratio), the whole raw ShDF, the
post-processing, the total; rays/s from wall-clock and from CPU time (the CPU
figure is less disturbed by other jobs on a shared machine, but counts both
threads); the ratio of our total to CGAL's time: measured for psb-dev meshes,
estimated from its mean time per face (psb-dev) for the others.

    python benchmarks/bench_shdf.py [--dense] [--threads 2] [--repeat 3] [--psb 1 21 281]
"""

from __future__ import annotations

import argparse
import csv
import os
import time
from pathlib import Path

import numpy as np
import trimesh

from neural_shdf import constants
from neural_shdf.geometry import face_centroids, face_normals
from neural_shdf.mesh import TriangleMesh
from neural_shdf.shdf.embree import Scene
from neural_shdf.shdf.exact import ORIGIN_OFFSET, cone_directions, face_tangents, raw_shdf
from neural_shdf.shdf.postprocess import postprocess_shdf

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def load(path: Path) -> TriangleMesh:
    try:
        from neural_shdf.mesh_io import load_mesh

        return load_mesh(path)
    except ImportError:
        loaded = trimesh.load(path, process=False, force="mesh")
        return TriangleMesh(np.asarray(loaded.vertices), np.asarray(loaded.faces))


def generated() -> list[tuple[str, TriangleMesh, float | None]]:
    meshes = []
    for name, shape in (
        ("torus-10k", trimesh.creation.torus(1.0, 0.25, major_sections=100, minor_sections=50)),
        ("icosphere-20k", trimesh.creation.icosphere(subdivisions=5)),
        ("torus-100k", trimesh.creation.torus(1.0, 0.25, major_sections=400, minor_sections=125)),
    ):
        meshes.append((name, TriangleMesh(shape.vertices, shape.faces), None))
    return meshes


def cgal_table() -> dict[int, float]:
    path = DATA / "psb-dev" / "cgal" / "timings.csv"
    if not path.is_file():
        return {}
    with open(path) as handle:
        return {int(row["id"]): float(row["sdf_ms"]) for row in csv.DictReader(handle)}


def cgal_ms_per_face() -> float:
    """CGAL's ShDF milliseconds per face over all psb-dev meshes (total time / total faces)."""
    path = DATA / "psb-dev" / "cgal" / "timings.csv"
    if not path.is_file():
        return 0.142  # the figure measured for this machine
    with open(path) as handle:
        rows = list(csv.DictReader(handle))
    return sum(float(r["sdf_ms"]) for r in rows) / sum(int(r["faces"]) for r in rows)


def embree_only(mesh: TriangleMesh) -> tuple[float, float]:
    """Seconds Embree alone takes for the same rays, one thread, rays prepared beforehand:
    (embreex, one ray per call; our packets of 16)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh as EmbreexMesh

    normals, _ = face_normals(mesh.vertices, mesh.faces)
    caster = Scene(mesh.vertices, mesh.faces)
    single = rtcore_scene.EmbreeScene()
    EmbreexMesh(
        single,
        (mesh.vertices - caster.center).astype(np.float32),
        np.ascontiguousarray(mesh.faces, dtype=np.int32),
    )
    directions = cone_directions(
        -normals,
        face_tangents(mesh.vertices, mesh.faces),
        cone_angle=constants.SHDF_CONE_ANGLE,
        ray_count=constants.SHDF_RAY_COUNT,
        dtype=np.float32,
    ).reshape(-1, 3)
    diagonal = float(np.ptp(mesh.vertices, axis=0).max()) * np.sqrt(3)
    origins = (
        np.repeat(
            (face_centroids(mesh.vertices, mesh.faces) - caster.center).astype(np.float32),
            constants.SHDF_RAY_COUNT,
            axis=0,
        )
        + np.float32(ORIGIN_OFFSET * diagonal) * directions
    )
    single.run(origins[:1], directions[:1])  # builds the scene
    start = time.perf_counter()
    single.run(origins, directions)
    single_s = time.perf_counter() - start
    start = time.perf_counter()
    caster.first_hits(origins, directions)
    return single_s, time.perf_counter() - start


def best_of(repeat: int, action):
    """(result, best wall seconds, CPU seconds of that run)."""
    best = (None, float("inf"), 0.0)
    for _ in range(repeat):
        wall, cpu = time.perf_counter(), time.process_time()
        result = action()
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        if wall < best[1]:
            best = (result, wall, cpu)
    return best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dense", action="store_true", help="also the dense-dev scans (slow)")
    parser.add_argument("--threads", type=int, default=None, help="default: one per CPU")
    parser.add_argument("--repeat", type=int, default=3, help="best of N runs per mesh")
    parser.add_argument("--psb", type=int, nargs="*", default=[1, 21, 281], help="psb-dev ids")
    args = parser.parse_args(argv)

    meshes = generated()
    cgal_ms = cgal_table()
    for mesh_id in args.psb:
        path = DATA / "psb-dev" / "off" / f"{mesh_id}.off"
        if path.is_file():
            meshes.append((f"psb-{mesh_id}", load(path), cgal_ms.get(mesh_id)))
    if args.dense:
        for path in sorted((DATA / "dense-dev").glob("*.ply")):
            meshes.append((path.stem.split("__")[-1], load(path), None))

    per_face = cgal_ms_per_face()
    print(
        f"cpus {os.cpu_count()}  load {os.getloadavg()[0]:.1f}  "
        f"threads {args.threads or os.cpu_count()}  "
        f"CGAL {per_face * 1000:.0f} ms per 1000 faces (psb-dev mean)"
    )
    header = (
        f"{'mesh':<22} {'faces':>7} {'Mrays':>6} {'x1_1t':>6} {'x16_1t':>6} {'gain':>5} "
        f"{'raw_s':>7} "
        f"{'post_s':>7} {'total_s':>7} {'Mray/s':>7} {'Mray/cpu_s':>10} "
        f"{'ms/kface':>8} {'cgal_s':>7} {'ratio':>6}"
    )
    print(header)
    total_rays = total_seconds = 0.0
    for name, mesh, cgal_known in meshes:
        rays = mesh.face_count * constants.SHDF_RAY_COUNT
        graph = mesh.face_graph
        runs = [embree_only(mesh) for _ in range(args.repeat)]
        single_s, packet_s = min(r[0] for r in runs), min(r[1] for r in runs)
        raw, raw_s, raw_cpu = best_of(
            args.repeat, lambda m=mesh: raw_shdf(m.vertices, m.faces, threads=args.threads)
        )
        _, post_s, _ = best_of(args.repeat, lambda r=raw, g=graph: postprocess_shdf(r, g))
        total = raw_s + post_s
        cgal_s = (cgal_known / 1000.0) if cgal_known else per_face * mesh.face_count / 1000.0
        total_rays += rays
        total_seconds += raw_s
        print(
            f"{name[:22]:<22} {mesh.face_count:>7} {rays / 1e6:>6.2f} {single_s:>6.3f} "
            f"{packet_s:>6.3f} {single_s / packet_s:>5.2f} "
            f"{raw_s:>7.3f} {post_s:>7.3f} {total:>7.3f} {rays / raw_s / 1e6:>7.2f} "
            f"{rays / raw_cpu / 1e6:>10.2f} {1e6 * total / mesh.face_count:>8.1f} "
            f"{cgal_s:>7.2f} {total / cgal_s:>6.3f}",
            flush=True,
        )
    print(f"\nall meshes: {total_rays / total_seconds / 1e6:.2f} M rays/s (raw ShDF, wall clock)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
