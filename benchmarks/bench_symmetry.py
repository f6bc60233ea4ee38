"""The symmetry option on psb-dev: which models have a mirror plane, how alike the two sides
are cut, and the scores against the humans with and without ``symmetry`` (exact ShDF,
default segmentation).

Per model with a plane: the share of the surface the plane pairs, the mirror agreement
(``segment.symmetry.mirror_agreement``: the area-weighted Rand index between the labels and
the labels of the mirror faces, over faces paired both ways; 1 = exact mirror images)
without the option (``off``), with the ShDF evidence averaged across the plane only
(``evidence``: the option before its cuts were mirrored) and with the option as it is
(``on``: evidence averaged, the graph cut's leaves made mirror images,
``segment.symmetry.mirror_parts``, and mirror merges of the part tree made together), the
part counts and the seconds ``on`` took.
Then 1-RI and CD against the humans (the benchmark's mean over categories) for all models,
the tuning models (ids 1-3 of each category) and the held-out ones (id 4 of each) apart;
models without a plane score the same in every row.

    python benchmarks/bench_symmetry.py [--bench-dir DIR] [--models 1 2 3 4 61 62 63 64]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from neural_shdf.evaluate.benchmark import (
    DEFAULT_CACHE_DIR,
    BenchModel,
    MethodTable,
    cached_shdf,
    evaluate_folder,
    list_models,
    load_benchmark_mesh,
)
from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import segment
from neural_shdf.segment import SegmentParams, partitioners
from neural_shdf.segment.symmetry import Reflection, mirror_agreement

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_BENCH = REPO_ROOT / ".." / "shared" / "data" / "psb-dev"
ROWS = ("off", "evidence", "on")


def is_held_out(model_id: int) -> bool:
    """The 4th psb-dev model of each category, never used for tuning (as bench_psb.py)."""
    return (model_id - 1) % 20 == 3


@contextlib.contextmanager
def evidence_only() -> Iterator[None]:
    """The option as it was before its cuts were mirrored: leaves left as the cut made them."""
    kept = partitioners.mirror_parts, partitioners.mirror_leaves
    partitioners.mirror_parts = lambda parts, *_: parts  # type: ignore[assignment]
    partitioners.mirror_leaves = lambda *_: None  # type: ignore[assignment]
    try:
        yield
    finally:
        partitioners.mirror_parts, partitioners.mirror_leaves = kept


def two_way(mirror: NDArray) -> NDArray:
    paired = (mirror >= 0) & (mirror[np.maximum(mirror, 0)] == np.arange(len(mirror)))
    return np.where(paired, mirror, -1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bench-dir", type=Path, default=DEFAULT_BENCH.resolve())
    parser.add_argument("--models", type=int, nargs="+", help="only these model ids")
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE_DIR)
    args = parser.parse_args(argv)
    if not args.bench_dir.is_dir():
        print(f"benchmark folder {args.bench_dir} is absent", file=sys.stderr)
        return 2
    plain = SegmentParams()
    symmetric = dataclasses.replace(plain, symmetry=True)
    # (model id, row) -> (labels per triangle, reflection or None, seconds)
    runs: dict[tuple[int, str], tuple[NDArray, Reflection | None, float]] = {}

    def predictor(row: str) -> Callable[[TriangleMesh, BenchModel], NDArray]:
        def predict(mesh: TriangleMesh, model: BenchModel) -> NDArray:
            shdf = cached_shdf(mesh, "exact", args.cache_dir, model)
            start = time.perf_counter()
            with evidence_only() if row == "evidence" else contextlib.nullcontext():
                result = segment(mesh, shdf, plain if row == "off" else symmetric)
            runs[model.model_id, row] = (
                result.labels,
                result.reflection,
                time.perf_counter() - start,
            )
            return result.labels

        return predict

    start = time.perf_counter()
    table = evaluate_folder(args.bench_dir, {row: predictor(row) for row in ROWS}, ids=args.models)
    print(f"{'model':>5} {'paired':>7} {'agree off':>10} {'evidence':>9} {'on':>7} "
          f"{'parts off':>9} {'ev.':>4} {'on':>4} {'on, s':>6}")  # fmt: skip
    agreement: dict[str, list[float]] = {row: [] for row in ROWS}
    for result in table["off"].models:
        model_id = result.model_id
        reflection = runs[model_id, "on"][1]
        if reflection is None:
            continue
        (model,) = list_models(args.bench_dir, ids=[model_id])
        _, areas = load_benchmark_mesh(model.mesh_path).normals_and_areas
        mirror = two_way(reflection.mirror)
        cells = []
        for row in ROWS:
            value = mirror_agreement(runs[model_id, row][0], mirror, areas)
            agreement[row].append(value)
            cells.append(value)
        parts = [int(runs[model_id, row][0].max()) + 1 for row in ROWS]
        seconds = runs[model_id, "on"][2]
        print(f"{model_id:>5} {reflection.matched_area:>7.3f} "
              f"{cells[0]:>10.4f} {cells[1]:>9.4f} {cells[2]:>7.4f} "
              f"{parts[0]:>9} {parts[1]:>4} {parts[2]:>4} {seconds:>6.2f}")  # fmt: skip
    models = len(table["off"].models)
    print(f"a plane on {len(agreement['on'])} of {models} models; mean mirror agreement "
          + ", ".join(f"{row} {np.mean(agreement[row]):.4f}" for row in ROWS))  # fmt: skip
    print(f"\n{'1-RI / CD':<22} " + " ".join(f"{row:>15}" for row in ROWS))
    for title, keep in (
        ("all models", lambda model_id: True),
        ("tuning (ids 1-3)", lambda model_id: not is_held_out(model_id)),
        ("held out (id 4)", is_held_out),
    ):
        cells = []
        for row in ROWS:
            chosen = tuple(r for r in table[row].models if keep(r.model_id))
            if not chosen:
                break
            overall = MethodTable(row, chosen).overall()
            cells.append(f"{overall.ri_error:.3f} / {overall.cd:.3f}")
        if cells:
            count = sum(keep(r.model_id) for r in table["off"].models)
            print(f"{f'{title} ({count})':<22} " + " ".join(f"{c:>15}" for c in cells))
    print(f"evaluated in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
