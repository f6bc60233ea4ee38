"""The symmetry option on psb-dev: which models have a mirror plane, and how alike the two
sides are cut with and without ``symmetry`` (exact ShDF, default segmentation).

Per model: the share of the surface the plane pairs (``-``: no plane, the option changes
nothing), the mirror agreement without and with the option (``segment.symmetry.
mirror_agreement``: the area-weighted Rand index between the labels and the labels of the
mirror faces; 1 = the two sides cut alike), the part counts and the seconds the segmentation
with the option took (detection included). Quality against the humans:
``bench_psb.py --extra
'sym=exact-graphcut:{"symmetry": true}'``.

    python benchmarks/bench_symmetry.py [--bench-dir DIR] [--models 1 2 3 4 61 62 63 64]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from neural_shdf.evaluate.benchmark import (
    DEFAULT_CACHE_DIR,
    cached_shdf,
    list_models,
    load_benchmark_mesh,
)
from neural_shdf.pipeline import segment
from neural_shdf.segment import SegmentParams
from neural_shdf.segment.symmetry import mirror_agreement

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_BENCH = REPO_ROOT / ".." / "shared" / "data" / "psb-dev"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bench-dir", type=Path, default=DEFAULT_BENCH.resolve())
    parser.add_argument("--models", type=int, nargs="+", help="only these model ids")
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE_DIR)
    args = parser.parse_args(argv)
    if not args.bench_dir.is_dir():
        print(f"benchmark folder {args.bench_dir} is absent", file=sys.stderr)
        return 2
    plain_params = SegmentParams()
    symmetric_params = dataclasses.replace(plain_params, symmetry=True)
    print(f"{'model':>5} {'faces':>7} {'paired':>7} {'agree off':>11} {'on':>6} "
          f"{'parts off':>9} {'on':>4} {'on, s':>8}")  # fmt: skip
    before, after = [], []
    for model in list_models(args.bench_dir, ids=args.models):
        mesh = load_benchmark_mesh(model.mesh_path)
        shdf = cached_shdf(mesh, "exact", args.cache_dir, model)
        plain = segment(mesh, shdf, plain_params)
        start = time.perf_counter()
        symmetric = segment(mesh, shdf, symmetric_params)
        seconds = time.perf_counter() - start
        reflection = symmetric.reflection
        if reflection is None:
            print(f"{model.model_id:>5} {mesh.face_count:>7} {'-':>7}")
            continue
        _, areas = mesh.normals_and_areas
        off = mirror_agreement(plain.labels, reflection.mirror, areas)
        on = mirror_agreement(symmetric.labels, reflection.mirror, areas)
        before.append(off)
        after.append(on)
        print(f"{model.model_id:>5} {mesh.face_count:>7} {reflection.matched_area:>7.3f} "
              f"{off:>11.4f} {on:>6.4f} {plain.part_count:>9} {symmetric.part_count:>4} "
              f"{seconds:>8.2f}")  # fmt: skip
    if before:
        print(f"mean mirror agreement over {len(before)} models with a plane: "
              f"{np.nanmean(before):.4f} off, {np.nanmean(after):.4f} on")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
