"""Human body segmentation set: per-face accuracy after one-to-one (Hungarian) matching.

``../shared/data/human-seg``: 381 meshes of 1,500 faces, 8 labelled body parts (head,
hands, forearms, upper arms, torso, thighs, lower legs, feet). Each segmentation's
parts are matched one-to-one to the labels (maximum total overlap); faces of an
unmatched part count as wrong (``evaluate.scores.matched_accuracy``). Exact ShDF.

Rows: ``before-tree`` (graph cut, lambda 0.12, every part it finds, no crease
refinement: the segmentation before the part tree), ``tree-auto`` (the default:
boundaries moved onto concave creases, then the part tree at its automatic count),
``tree-N8`` (the part tree cut at 8 parts), ``metis-N8`` (METIS, exactly 8 parts);
``-plain``: the same without the crease refinement (``crease_boundaries=False``).
``ceiling``: the labels' own largest connected region per label; 7 of the 8 labels
are left/right pairs (two regions), so 8 connected parts cannot match more than this
share one-to-one.
The paper reports 94.2% on this set with its own (per-label) protocol.

    python benchmarks/bench_human_seg.py [--limit N] [--every K] [--cache-dir DIR]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from neural_shdf.evaluate.scores import matched_accuracy
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.segment import SegmentParams
from neural_shdf.segment.parts import connected_parts

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DIR = REPO_ROOT / ".." / "shared" / "data" / "human-seg"
DEFAULT_CACHE = Path.home() / ".cache" / "neural-shdf" / "human-seg"
ROWS = {
    "before-tree": (SegmentParams(smoothing=0.12, crease_boundaries=False), "leaves"),
    "tree-auto": (SegmentParams(), "labels"),
    "tree-auto-plain": (SegmentParams(crease_boundaries=False), "labels"),
    "tree-N8": (SegmentParams(parts=8), "labels"),
    "tree-N8-plain": (SegmentParams(parts=8, crease_boundaries=False), "labels"),
    "metis-N8": (SegmentParams(partitioner="metis", parts=8), "labels"),
}


def exact_shdf(mesh, name: str, cache_dir: Path) -> np.ndarray:
    path = cache_dir / f"{name}-{mesh.content_hash()[:16]}.npy"
    if path.is_file():
        return np.load(path)
    values = compute_shdf(mesh, method="exact").values
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, values)
    return values


def ceiling(labels: np.ndarray, graph) -> float:
    """Share of faces in the largest connected region of their label."""
    regions = connected_parts(labels, graph.pairs, len(labels))
    best = 0
    for label in np.unique(labels):
        best += np.bincount(regions[labels == label]).max()
    return best / len(labels)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=DEFAULT_DIR.resolve())
    parser.add_argument("--limit", type=int, help="only the first N meshes")
    parser.add_argument("--every", type=int, default=1, help="every K-th mesh")
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE)
    args = parser.parse_args()
    if not (args.data_dir / "train").is_dir():
        print(f"human-seg folder {args.data_dir} is absent", file=sys.stderr)
        return 2
    paths = sorted((args.data_dir / "train").glob("*.obj"))[:: args.every][: args.limit]
    start = time.perf_counter()
    accuracy = {name: [] for name in ROWS} | {"ceiling": []}
    parts = {name: [] for name in ROWS}
    for path in paths:
        mesh = load_mesh(path)
        truth = np.loadtxt(args.data_dir / "face_labels" / f"{path.stem}.txt", dtype=np.int64)
        graph = mesh.face_graph
        shdf = exact_shdf(mesh, path.stem, args.cache_dir)
        for name, (params, which) in ROWS.items():
            result = segment(mesh, shdf, params)
            labels = result.tree.leaf_labels if which == "leaves" else result.labels
            accuracy[name].append(matched_accuracy(labels[: len(truth)], truth))
            parts[name].append(int(labels.max()) + 1)
        accuracy["ceiling"].append(ceiling(truth, graph))
    print(f"{len(paths)} meshes of {args.data_dir.name}; one-to-one matched per-face accuracy")
    print(f"{'row':<18} {'accuracy':>8} {'p10':>6} {'parts':>6}  ratio to before-tree")
    base = float(np.mean(accuracy["before-tree"]))
    for name, values in accuracy.items():
        mean_parts = f"{np.mean(parts[name]):6.1f}" if name in parts else f"{'-':>6}"
        print(
            f"{name:<18} {np.mean(values):8.3f} {np.quantile(values, 0.1):6.3f} {mean_parts}  "
            f"{np.mean(values) / base:.3f}"
        )
    print(f"evaluated in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
