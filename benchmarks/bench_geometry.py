"""Per-face geometry every path shares: time per stage at about 100k and 1M faces.

Stages of ``TriangleMesh.face_graph``: face normals and areas
(``geometry.face_normals``, cached per mesh as ``TriangleMesh.normals_and_areas``),
vertex welding (``weld_faces``) and the face adjacency graph
(``build_face_graph``: edge matching, dihedral angles, concavity). Meshes: a
dumbbell of about 100k and 1M faces, the same 1M faces as a triangle soup
(every corner its own vertex, as STL files come: the weld's worst case), one
tetrahedron repeated in place to 1M faces (every edge shared by 500k faces: the
face graph must stay linear, ``geometry.EDGE_CLIQUE``), and psb-dev 281 subdivided
twice (808k faces) where ``../shared/data`` exists.
Each stage's best of ``--repeat`` runs after a warm-up (numba kernels load
from their disk cache once per process: ``warmup_s``); ``s_per_Mface`` is the
three stages' total per million faces. ``cpu_s`` is process CPU time (the
kernels are single-threaded, so on a busy machine it is the steadier number).

    python benchmarks/bench_geometry.py [--repeat 3]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import trimesh
from timing import best_time

from neural_shdf.geometry import build_face_graph, face_normals, weld_faces
from neural_shdf.segment.synthetic import dumbbell

PSB_MESH = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "psb-dev" / "off"


def meshes() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, vertices, faces) of the benchmark meshes."""
    out = []
    for size, name in ((100_000, "dumbbell-100k"), (1_000_000, "dumbbell-1M")):
        mesh, _ = dumbbell(size)
        out.append((name, np.asarray(mesh.vertices), np.asarray(mesh.faces)))
    vertices, faces = out[-1][1], out[-1][2]
    soup_faces = np.arange(3 * len(faces)).reshape(-1, 3)
    out.append(("soup-1M", vertices[faces].reshape(-1, 3), soup_faces))
    tetrahedron = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
    out.append(("tet-stack-1M", corners, np.tile(tetrahedron, (250_000, 1))))
    if (PSB_MESH / "281.off").exists():
        base = trimesh.load(PSB_MESH / "281.off", process=False)
        vertices, faces = trimesh.remesh.subdivide(base.vertices, base.faces)
        vertices, faces = trimesh.remesh.subdivide(vertices, faces)
        out.append(("psb281-sub2", np.asarray(vertices), np.asarray(faces)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per stage; the best counts")
    args = parser.parse_args()
    box = trimesh.creation.box()
    start = time.perf_counter()
    build_face_graph(box.vertices, weld_faces(box.vertices, box.faces))
    print(f"warmup_s {time.perf_counter() - start:.3f}")
    print(
        f"{'mesh':>13} {'faces':>9} {'vertices':>9} {'normals_s':>9} {'weld_s':>7} "
        f"{'graph_s':>7} {'total_s':>7} {'cpu_s':>6} {'s_per_Mface':>11} {'pairs':>9}"
    )
    for name, vertices, faces in meshes():
        normals_s, normals_cpu, (normals, _) = best_time(
            lambda v=vertices, f=faces: face_normals(v, f), args.repeat
        )
        weld_s, weld_cpu, welded = best_time(
            lambda v=vertices, f=faces: weld_faces(v, f), args.repeat
        )
        graph_s, graph_cpu, graph = best_time(
            lambda v=vertices, w=welded, n=normals: build_face_graph(v, w, n), args.repeat
        )
        total = normals_s + weld_s + graph_s
        cpu = normals_cpu + weld_cpu + graph_cpu
        print(
            f"{name:>13} {len(faces):>9} {len(vertices):>9} {normals_s:>9.3f} {weld_s:>7.3f} "
            f"{graph_s:>7.3f} {total:>7.3f} {cpu:>6.3f} {total / (len(faces) / 1e6):>11.3f} "
            f"{len(graph.pairs):>9}"
        )


if __name__ == "__main__":
    main()
