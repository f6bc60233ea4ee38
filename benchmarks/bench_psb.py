"""Princeton Segmentation Benchmark metrics on psb-dev: one table, all methods side by side.

Rows per category and overall (mean over categories, as the benchmark averages);
columns CD, HD, Rm, Rf, 1-RI, GCE, LCE (lower is better). Methods by default:
CGAL's own segmentations (``cgal/*.seg``), our exact ShDF with the graph cut,
with METIS (automatic parameters), and METIS given the humans' most frequent
part count per model (the benchmark's protocol for methods that take a count).

References: humans against humans on the whole benchmark score 1-RI 0.103;
CGAL's defaults 0.309 on psb-dev.

    python benchmarks/bench_psb.py [--bench-dir DIR] [--methods ...] [--jobs 2] [--json out.json]
        [--tuned '{"smoothing": 0.1, "clusters": 8}']

``--tuned`` adds rows ``exact-graphcut+tuned`` and ``exact-metis+tuned`` with
those SegmentParams overrides (global values, the same for every mesh).

Exact ShDF values are cached in ~/.cache/neural-shdf/psb (``--cache-dir``), so
re-running with other segmentation parameters only re-segments.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from neural_shdf.evaluate.benchmark import (
    DEFAULT_CACHE_DIR,
    evaluate_folder,
    format_table,
    make_predictor,
    table_as_dict,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_BENCH = REPO_ROOT / ".." / "shared" / "data" / "psb-dev"
DEFAULT_METHODS = ["cgal", "exact-graphcut", "exact-metis", "exact-metis-humanparts"]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bench-dir", type=Path, default=DEFAULT_BENCH.resolve())
    parser.add_argument("--methods", nargs="+", default=DEFAULT_METHODS)
    parser.add_argument("--limit", type=int, help="only the first N models")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (at most 2)")
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE_DIR)
    parser.add_argument("--json", type=Path, help="also write per-model scores as JSON")
    parser.add_argument("--tuned", type=json.loads, help="SegmentParams overrides, as JSON")
    args = parser.parse_args(argv)
    if not args.bench_dir.is_dir():
        print(f"benchmark folder {args.bench_dir} is absent", file=sys.stderr)
        return 2

    start = time.perf_counter()
    predictors = {m: make_predictor(m, cache_dir=args.cache_dir) for m in args.methods}
    if args.tuned:
        for method in ("exact-graphcut", "exact-metis"):
            predictors[f"{method}+tuned"] = make_predictor(
                method, cache_dir=args.cache_dir, params=args.tuned
            )
        print(f"tuned: {json.dumps(args.tuned)}")
    table = evaluate_folder(args.bench_dir, predictors, limit=args.limit, jobs=args.jobs)
    print(format_table(table))
    print(f"evaluated in {time.perf_counter() - start:.0f} s (wall, ShDF cache: {args.cache_dir})")
    if args.json:
        args.json.write_text(json.dumps(table_as_dict(table), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
