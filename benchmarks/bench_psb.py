"""Princeton Segmentation Benchmark metrics on psb-dev: one table, all methods side by side.

Rows per category and overall (mean over categories, as the benchmark averages);
columns CD, HD, Rm, Rf, 1-RI, GCE, LCE (lower is better), then the mean part count.
Default rows, from our exact ShDF unless named ``neural-`` (CGAL's are its own):

* ``before-tree``: the segmentation before the part tree (graph cut, lambda 0.12,
  every part it finds, no crease refinement: ``exact-graphcut-leaves``);
* ``tree-auto``: the default (``exact-graphcut``): the graph cut's part boundaries moved
  onto concave creases (``segment.creases``), then the part tree over those parts, cut
  where the merge cost passes the automatic threshold;
* ``tree-auto-plain``: the same without the crease refinement (``crease_boundaries``
  off, the default before; its own threshold);
* ``tree-humansN``: the part tree cut at the humans' most frequent part count of each
  model (``exact-graphcut-humanparts``), the benchmark's protocol for methods that
  take a count; ``tree-humansN-plain`` without the crease refinement;
* ``metis-humansN``: METIS given the same count (``exact-metis-humanparts``);
* ``metis-auto``: METIS given the part tree's automatic count (``exact-metis``);
* ``neural-tree-auto``: the neural ShDF (the ONNX network) with the default
  segmentation (``neural-graphcut``);
* ``cgal``: CGAL's own segmentations (``cgal/*.seg``).

The hierarchy's weights and its automatic count were tuned on the first three
models of each category; the fourth (ids 4, 24, 44, ..., 384) was held out and is
reported apart (``--split``), so the gap shows how much of a gain is tuning.

References: humans against humans on the whole benchmark score 1-RI 0.103, CD 0.172.

    python benchmarks/bench_psb.py [--bench-dir DIR] [--jobs 2] [--json out.json]
        [--rows before-tree tree-auto ...] [--extra NAME=METHOD:JSON ...] [--no-split]
        [--models ID ...]

``--extra`` adds a row, e.g. ``smooth=exact-graphcut:{"boundary_smoothing": true}``.
Exact ShDF values are cached in ~/.cache/neural-shdf/psb (``--cache-dir``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from neural_shdf.evaluate.benchmark import (
    DEFAULT_CACHE_DIR,
    EvalTable,
    MethodTable,
    evaluate_folder,
    format_table,
    make_predictor,
    table_as_dict,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_BENCH = REPO_ROOT / ".." / "shared" / "data" / "psb-dev"
#: Row name -> (method, SegmentParams overrides).
ROWS: dict[str, tuple[str, dict]] = {
    "before-tree": ("exact-graphcut-leaves", {"smoothing": 0.12, "crease_boundaries": False}),
    "tree-auto": ("exact-graphcut", {}),
    "tree-auto-plain": ("exact-graphcut", {"crease_boundaries": False}),
    "tree-humansN": ("exact-graphcut-humanparts", {}),
    "tree-humansN-plain": ("exact-graphcut-humanparts", {"crease_boundaries": False}),
    "metis-humansN": ("exact-metis-humanparts", {}),
    "metis-auto": ("exact-metis", {}),
    "neural-tree-auto": ("neural-graphcut", {}),
    "cgal": ("cgal", {}),
}


def is_held_out(model_id: int) -> bool:
    """The 4th psb-dev model of each category, never used for tuning."""
    return (model_id - 1) % 20 == 3


def subset(table: EvalTable, held_out: bool) -> EvalTable:
    return {
        name: MethodTable(name, tuple(r for r in t.models if is_held_out(r.model_id) == held_out))
        for name, t in table.items()
    }


def parse_extra(text: str) -> tuple[str, tuple[str, dict]]:
    name, _, rest = text.partition("=")
    method, _, params = rest.partition(":")
    return name, (method, json.loads(params) if params else {})


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bench-dir", type=Path, default=DEFAULT_BENCH.resolve())
    parser.add_argument("--rows", nargs="+", default=list(ROWS), choices=list(ROWS))
    parser.add_argument(
        "--extra",
        nargs="*",
        default=[],
        type=parse_extra,
        help="more rows: NAME=METHOD[:JSON SegmentParams overrides]",
    )
    parser.add_argument("--limit", type=int, help="only the first N models")
    parser.add_argument(
        "--models", type=int, nargs="+", help="only these model ids (e.g. 1 2 3 4 61 62 63 64)"
    )
    parser.add_argument("--jobs", type=int, default=2, help="worker processes (at most 2)")
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE_DIR)
    parser.add_argument("--json", type=Path, help="also write per-model scores as JSON")
    parser.add_argument("--no-split", action="store_true", help="no tuned/held-out tables")
    args = parser.parse_args(argv)
    if not args.bench_dir.is_dir():
        print(f"benchmark folder {args.bench_dir} is absent", file=sys.stderr)
        return 2

    start = time.perf_counter()
    rows = {name: ROWS[name] for name in args.rows} | dict(args.extra)
    predictors = {
        name: make_predictor(method, cache_dir=args.cache_dir, params=params)
        for name, (method, params) in rows.items()
    }
    for name, (method, params) in rows.items():
        print(f"{name}: {method} {json.dumps(params) if params else ''}")
    table = evaluate_folder(
        args.bench_dir, predictors, limit=args.limit, jobs=args.jobs, ids=args.models
    )
    print("\n== all models")
    print(format_table(table))
    if not args.no_split:
        for title, held_out in (
            ("tuning models (ids 1-3 of each category)", False),
            ("held-out models (id 4 of each category)", True),
        ):
            part = subset(table, held_out)
            if all(t.models for t in part.values()):
                print(f"\n== {title}")
                print(format_table(part, per_category=False))
    print(f"evaluated in {time.perf_counter() - start:.0f} s (wall, ShDF cache: {args.cache_dir})")
    if args.json:
        args.json.write_text(json.dumps(table_as_dict(table), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
