"""Bit-for-bit identity of ShDF values and labels across a refactoring.

For every psb-dev mesh (``../shared/data/psb-dev/off/*.off``) and dense-dev scan
(``../shared/data/dense-dev/*.ply``) this computes the default ShDF (``method auto``,
as ``neural-shdf segment`` does) and the labels of a fixed parameter grid on it
(default; part-tree cuts at 2, 5 and 10 parts; smoothing 0.02 and 0.3; refinement;
boundary smoothing; METIS at 6 parts and automatic), plus the ``exact``, ``sampled``
and ``neural`` ShDF on psb-dev. ``--out DIR`` records one ``.npz`` per mesh;
``--compare DIR`` recomputes and prints every array that differs in any bit (exit
status 1 if one does).

    python benchmarks/golden_identity.py --out /work/golden/base
    python benchmarks/golden_identity.py --compare /work/golden/base [--limit 5] [--only NAME]
"""

from __future__ import annotations

import argparse
import gc
import resource
import sys
import time
from pathlib import Path

import numpy as np

from neural_shdf.errors import ModelUnavailableError
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import SegmentParams, compute_shdf, prepare_segment, segment

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
if not DATA.is_dir():
    DATA = Path("/work/shared/data")

#: (name, parameters) of every segmentation recorded, all on the default ShDF.
GRID: tuple[tuple[str, SegmentParams], ...] = (
    ("default", SegmentParams()),
    ("parts2", SegmentParams(parts=2)),
    ("parts5", SegmentParams(parts=5)),
    ("parts10", SegmentParams(parts=10)),
    ("smoothing0.02", SegmentParams(smoothing=0.02)),
    ("smoothing0.3", SegmentParams(smoothing=0.3)),
    ("refine", SegmentParams(refine=True)),
    ("boundary_smoothing", SegmentParams(boundary_smoothing=True)),
    ("no_creases", SegmentParams(crease_boundaries=False)),
    ("reference_faces", SegmentParams(reference_faces=10_000)),
    ("metis6", SegmentParams(partitioner="metis", parts=6)),
    ("metis_auto", SegmentParams(partitioner="metis")),
    (
        "metis6_boundary_smoothing",
        SegmentParams(partitioner="metis", parts=6, boundary_smoothing=True),
    ),
)
#: ShDF methods recorded besides ``auto`` (psb-dev only: the dense scans take minutes each).
METHODS = ("exact", "sampled", "neural")


def meshes() -> list[tuple[str, Path]]:
    psb = sorted((DATA / "psb-dev" / "off").glob("*.off"), key=lambda p: (len(p.stem), p.stem))
    dense = sorted((DATA / "dense-dev").glob("*.ply"))
    return [(f"psb-{p.stem}", p) for p in psb] + [(f"dense-{p.stem}", p) for p in dense]


def record(path: Path, methods: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Every array of one mesh, through the library's front door (``neural_shdf.pipeline``)."""
    mesh = load_mesh(path)
    arrays: dict[str, np.ndarray] = {}
    shdf = compute_shdf(mesh, method="auto").values
    arrays["shdf_auto"] = shdf
    arrays["input_shdf_auto"] = mesh.to_input_faces(shdf)
    for name, params in GRID:
        result = segment(mesh, shdf, params)
        arrays[f"labels_{name}"] = result.labels
        if name == "default":
            face_labels, face_leaves = result.input_face_parts(mesh)
            arrays["input_labels_default"] = face_labels
            if face_leaves is not None:
                arrays["input_leaves_default"] = face_leaves
    # The service's path: a kept basis, re-segmented with other smoothing or parts.
    basis = prepare_segment(mesh, shdf, SegmentParams())
    for name, params in GRID[1:6]:
        arrays[f"labels_basis_{name}"] = segment(mesh, shdf, params, basis=basis).labels
    for method in methods:
        try:
            arrays[f"shdf_{method}"] = compute_shdf(mesh, method=method).values
        except ModelUnavailableError:
            continue
    return arrays


def compare(reference: dict[str, np.ndarray], current: dict[str, np.ndarray]) -> list[str]:
    """What differs between two recordings of one mesh, one line per array."""
    problems = []
    for key in sorted(set(reference) | set(current)):
        if key not in current:
            problems.append(f"{key}: missing now")
        elif key not in reference:
            problems.append(f"{key}: new (not in the reference)")
        else:
            a, b = reference[key], current[key]
            if a.dtype != b.dtype or a.shape != b.shape:
                problems.append(f"{key}: {a.dtype}{a.shape} vs {b.dtype}{b.shape}")
            elif a.tobytes() != b.tobytes():
                differ = int(np.sum(a != b))
                problems.append(f"{key}: {differ} of {a.size} values differ")
    return problems


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--out", type=Path, help="record into this directory")
    group.add_argument("--compare", type=Path, help="compare against this recording")
    parser.add_argument("--limit", type=int, help="only the first N meshes")
    parser.add_argument("--only", action="append", help="only meshes whose name contains this")
    parser.add_argument("--skip-dense", action="store_true", help="psb-dev only")
    args = parser.parse_args()
    selected = meshes()
    if args.only:
        selected = [(n, p) for n, p in selected if any(o in n for o in args.only)]
    if args.skip_dense:
        selected = [(n, p) for n, p in selected if n.startswith("psb-")]
    if args.limit:
        selected = selected[: args.limit]
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
    mismatches = 0
    print(f"{'mesh':<60} {'arrays':>6} {'seconds':>8} {'rss_mb':>7}  result", flush=True)
    for name, path in selected:
        start = time.perf_counter()
        methods = METHODS if name.startswith("psb-") else ()
        arrays = record(path, methods)
        seconds = time.perf_counter() - start
        rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        if args.out:
            np.savez(args.out / f"{name}.npz", **arrays)
            outcome = "recorded"
        else:
            reference_path = args.compare / f"{name}.npz"
            if not reference_path.is_file():
                outcome = "no reference"
                mismatches += 1
            else:
                with np.load(reference_path) as stored:
                    reference = {key: stored[key] for key in stored.files}
                problems = compare(reference, arrays)
                mismatches += bool(problems)
                outcome = "identical" if not problems else "DIFFERS: " + "; ".join(problems)
        print(f"{name:<60} {len(arrays):>6} {seconds:>8.1f} {rss:>7.0f}  {outcome}", flush=True)
        del arrays
        gc.collect()
    if args.compare:
        print(f"{len(selected)} meshes, {mismatches} with mismatches")
    return 1 if mismatches else 0


if __name__ == "__main__":
    sys.exit(main())
