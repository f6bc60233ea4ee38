"""Parts of real, unevenly tessellated meshes against the same surfaces tessellated more evenly.

No labels exist for the training corpus (151 misc + 414 shapedb meshes: CAD parts, web
models, scans), but one thing can be measured on it: whether the parts depend on how the
surface was tessellated. Most of its meshes are uneven (large flat panels beside dense
curved detail: half of them have more than 3x the faces of their surface's resolution,
``geometry.equivalent_face_count``). Per mesh above ``--min-ratio``: the default
segmentation of the file, and of the same surface with its large faces (over 4x the median
area) split 1-to-n² (``geometry.split_region``, n from the sizes, 2-6, no T-junction): a
finer tessellation of its flat panels, as an exporter at a finer tolerance would give.
Each face of the file takes the label most of its pieces have; printed per mesh and in
mean: the area-weighted 1-RI between the two segmentations (0: the same parts).

The archives are unpacked to ``--cache`` (``model_export.data.unpack_archives``) once.
Run it on two checkouts to compare code (``PYTHONPATH=.../service:...``).

    PYTHONPATH=service:. python benchmarks/bench_tessellation.py [--every 4]
        [--min-ratio 3] [--limit N] [--cache DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from bench_production import majority_per_face

from model_export.data import unpack_archives
from neural_shdf.errors import MeshError
from neural_shdf.evaluate.scores import rand_index_error
from neural_shdf.geometry import equivalent_face_count, split_region
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.segment import SegmentParams

DEFAULT_CACHE = Path("/tmp/neural-shdf-corpus")
EXTENSIONS = {".obj", ".off", ".ply", ".stl"}
#: Faces over this many times the median area are split.
LARGE_FACE = 4.0
#: Evened meshes above this many faces are left out (time).
MAX_FACES = 400_000


def evened(mesh: TriangleMesh) -> tuple[TriangleMesh, np.ndarray]:
    """The same surface with its large faces split, and the file's face of each face."""
    areas = mesh.normals_and_areas[1]
    median = float(np.median(areas))
    large = areas > LARGE_FACE * median
    splits = int(np.clip(np.ceil(np.sqrt(np.median(areas[large]) / median)), 2, 6))
    vertices, faces, parent = split_region(mesh.vertices, mesh.faces, large, splits)
    return TriangleMesh(vertices, faces), parent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    parser.add_argument("--every", type=int, default=4, help="every K-th uneven mesh")
    parser.add_argument("--min-ratio", type=float, default=3.0)
    parser.add_argument("--limit", type=int)
    args = parser.parse_args()
    shapes = unpack_archives(args.cache)
    paths = sorted(p for p in shapes.rglob("*") if p.suffix.lower() in EXTENSIONS)
    if not paths:
        print(f"no training meshes under {shapes}", file=sys.stderr)
        return 1
    rows: list[float] = []
    uneven = 0
    start = time.perf_counter()
    print(f"{'mesh':44s} {'faces':>7s} {'ratio':>6s} {'evened':>7s} {'ratio':>6s} parts  1-RI")
    for path in paths:
        try:
            mesh = load_mesh(path)
        except MeshError:
            continue
        areas = mesh.normals_and_areas[1]
        if mesh.face_count < 500 or not areas.sum() > 0:
            continue
        ratio = mesh.face_count / equivalent_face_count(areas)
        if ratio <= args.min_ratio:
            continue
        uneven += 1
        if (uneven - 1) % args.every:
            continue
        finer, parent = evened(mesh)
        if finer.face_count > MAX_FACES:
            continue
        labels = segment(mesh, compute_shdf(mesh), SegmentParams()).labels
        finer_labels = segment(finer, compute_shdf(finer), SegmentParams()).labels
        _, back = majority_per_face(parent, finer_labels)  # every face has pieces
        error = rand_index_error(labels, back, weights=areas)
        rows.append(error)
        finer_ratio = finer.face_count / equivalent_face_count(finer.normals_and_areas[1])
        name = str(path.relative_to(shapes))[-44:]
        print(
            f"{name:44s} {mesh.face_count:7d} {ratio:6.1f} {finer.face_count:7d}"
            f" {finer_ratio:6.1f} {labels.max() + 1:2d}/{finer_labels.max() + 1:<2d} {error:.3f}",
            flush=True,
        )
        if args.limit and len(rows) >= args.limit:
            break
    errors = np.asarray(rows)
    print(
        f"{len(errors)} meshes ({uneven} above ratio {args.min_ratio} seen),"
        f" {time.perf_counter() - start:.0f} s; area-weighted 1-RI between the tessellations:"
        f" mean {errors.mean():.3f}, median {np.median(errors):.3f},"
        f" share above 0.1 {np.mean(errors > 0.1):.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
