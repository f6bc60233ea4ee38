"""Crease refinement against resolution: the same parts on finer tessellations, refined.

For psb-dev models, the graph cut's parts (no crease refinement) are refined on the
mesh itself and on its midpoint subdivisions (x4, x16, x64 faces; the same surface),
each finer face taking the part of its nearest original face. Printed: the
area-weighted 1-RI between each subdivision's refined parts and the original's
(mapped to the finer faces; 0 = the refinement does not depend on the tessellation),
beside the 1-RI between the original's parts before and after refinement (what the
refinement changes at all). Meshes over ``COARSE_ABOVE_FACES`` are solved on coarse
nodes (marked ``coarse``).

    python benchmarks/bench_creases.py [--models 1,82,102,181,301] [--levels 3]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from neural_shdf.evaluate.benchmark import (
    DEFAULT_CACHE_DIR,
    cached_shdf,
    list_models,
    load_benchmark_mesh,
)
from neural_shdf.evaluate.scores import rand_index_error
from neural_shdf.geometry import build_face_graph, face_centroids, face_normals, weld_faces
from neural_shdf.pipeline import segment
from neural_shdf.segment import SegmentParams
from neural_shdf.segment.creases import COARSE_ABOVE_FACES, snap_boundaries_to_creases

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_BENCH = REPO_ROOT / ".." / "shared" / "data" / "psb-dev"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bench-dir", type=Path, default=DEFAULT_BENCH.resolve())
    parser.add_argument("--models", default="1,82,102,181,301")
    parser.add_argument("--levels", type=int, default=3, help="subdivisions (x4 each)")
    args = parser.parse_args()
    wanted = {int(m) for m in args.models.split(",")}
    errors = []
    for model in list_models(args.bench_dir):
        if model.model_id not in wanted:
            continue
        mesh = load_benchmark_mesh(model.mesh_path)
        shdf = cached_shdf(mesh, "exact", DEFAULT_CACHE_DIR, model)
        graph = mesh.face_graph
        plain = SegmentParams(crease_boundaries=False)
        leaves = segment(mesh, shdf, plain).tree.leaf_labels
        vertices, faces = mesh.vertices, mesh.faces
        areas, centroids = face_normals(vertices, faces)[1], face_centroids(vertices, faces)
        base = snap_boundaries_to_creases(leaves, graph, areas, centroids, 0.002)
        change = rand_index_error(leaves, base, weights=areas)
        cells = [f"{model.model_id:>4} {len(faces):>7} faces: refinement changes {change:.4f}"]
        original = centroids
        for level in range(1, args.levels + 1):
            vertices, faces = trimesh.remesh.subdivide(vertices, faces)
            normals, areas = face_normals(vertices, faces)
            centroids = face_centroids(vertices, faces)
            fine = build_face_graph(vertices, weld_faces(vertices, faces), normals)
            nearest = cKDTree(original).query(centroids)[1]
            refined = snap_boundaries_to_creases(leaves[nearest], fine, areas, centroids, 0.002)
            error = rand_index_error(refined, base[nearest], weights=areas)
            errors.append(error)
            coarse = " coarse" if len(faces) > COARSE_ABOVE_FACES else ""
            cells.append(f"x{4**level}{coarse} {error:.4f}")
        print("; ".join(cells), flush=True)
    print(
        f"1-RI to the original's refinement: median {np.median(errors):.4f}, "
        f"worst {max(errors):.4f}"
    )


if __name__ == "__main__":
    main()
