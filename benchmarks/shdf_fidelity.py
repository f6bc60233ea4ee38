"""Fidelity of the exact ShDF against CGAL's ``sdf_values`` on the psb-dev meshes.

Prints, per mesh, the Pearson correlation of our post-processed ShDF with
CGAL's (``../shared/data/psb-dev/cgal/{id}.sdf``), our time, CGAL's time and
their ratio; then the median, minimum and per-category spread.

    python benchmarks/shdf_fidelity.py [--ids 1 2 3] [--limit N]
"""

from __future__ import annotations

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import compute_shdf

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "psb-dev"
CATEGORIES = [
    "Human",
    "Cup",
    "Glasses",
    "Airplane",
    "Ant",
    "Chair",
    "Octopus",
    "Table",
    "Teddy",
    "Hand",
    "Plier",
    "Fish",
    "Bird",
    "Armadillo",
    "Bust",
    "Mech",
    "Bearing",
    "Vase",
    "Fourleg",
]


def load_off(path: Path) -> TriangleMesh:
    """The OFF as a TriangleMesh (the project loader when present, else trimesh, unprocessed)."""
    try:
        from neural_shdf.mesh_io import load_mesh

        return load_mesh(path)
    except ImportError:
        import trimesh

        loaded = trimesh.load(path, process=False)
        return TriangleMesh(np.asarray(loaded.vertices), np.asarray(loaded.faces))


def category_of(mesh_id: int) -> str:
    """Benchmark category of a model id (ids 261-280 do not exist in the benchmark)."""
    index = (mesh_id - 1) // 20
    index -= index > 12  # no category spans 261..280
    return CATEGORIES[index]


def cgal_timings() -> dict[int, float]:
    with open(DATA / "cgal" / "timings.csv") as handle:
        return {int(row["id"]): float(row["sdf_ms"]) for row in csv.DictReader(handle)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ids", type=int, nargs="*", help="mesh ids (default: all)")
    parser.add_argument("--limit", type=int, default=0, help="first N meshes only")
    args = parser.parse_args(argv)
    if not DATA.is_dir():
        print(f"no data at {DATA}", file=sys.stderr)
        return 1
    ids = args.ids or sorted(int(p.stem) for p in (DATA / "off").glob("*.off"))
    if args.limit:
        ids = ids[: args.limit]
    timings = cgal_timings()
    print(
        f"{'id':>4} {'category':<10} {'faces':>7} {'pearson':>9} {'max_diff':>8} "
        f"{'>0.01':>6} {'ours_ms':>8} {'cpu_ms':>8} {'cgal_ms':>8} {'ratio':>6}"
    )
    rows = []
    for mesh_id in ids:
        mesh = load_off(DATA / "off" / f"{mesh_id}.off")
        reference = np.loadtxt(DATA / "cgal" / f"{mesh_id}.sdf")
        start, cpu_start = time.perf_counter(), time.process_time()
        ours = mesh.to_input_faces(compute_shdf(mesh, method="exact").values)
        elapsed_ms = 1000.0 * (time.perf_counter() - start)
        cpu_ms = 1000.0 * (time.process_time() - cpu_start)
        pearson = float(np.corrcoef(ours, reference)[0, 1])
        difference = np.abs(ours - reference)
        cgal_ms = timings.get(mesh_id, float("nan"))
        rows.append((mesh_id, pearson))
        print(
            f"{mesh_id:>4} {category_of(mesh_id):<10} {mesh.face_count:>7} {pearson:>9.6f} "
            f"{difference.max():>8.4f} {np.mean(difference > 0.01):>6.4f} {elapsed_ms:>8.1f} "
            f"{cpu_ms:>8.1f} {cgal_ms:>8.1f} {elapsed_ms / cgal_ms:>6.3f}",
            flush=True,
        )
    values = np.array([p for _, p in rows])
    print(
        f"\nmeshes {len(values)}  median pearson {np.median(values):.6f}  "
        f"mean {values.mean():.6f}  min {values.min():.6f} "
        f"(id {rows[int(values.argmin())][0]})"
    )
    print(f"\n{'category':<10} {'n':>2} {'median':>9} {'min':>9} {'max':>9}")
    by_category: dict[str, list[float]] = {}
    for mesh_id, pearson in rows:
        by_category.setdefault(category_of(mesh_id), []).append(pearson)
    for name, found in by_category.items():
        print(
            f"{name:<10} {len(found):>2} {np.median(found):>9.6f} {min(found):>9.6f} "
            f"{max(found):>9.6f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
