"""Named parts: per-face accuracy of the part labeller on the human body segmentation set.

``../shared/data/human-seg`` (381 meshes of 1,500 faces, 8 labels). Validation: every
5th mesh by sorted name (``--every``), never used for training or tuning; the smoothing
is chosen on a split of the training meshes (every 5th of them). Exact ShDF (cached).

Tables:
* tuning: accuracy on the tuning split for a few graph-cut smoothing values;
* validation: per-face accuracy by count and area-weighted, before the graph cut (each
  face's most probable label) and after, with all training meshes; the same on the
  validation meshes subdivided x16 (labels carried to the children), in a random rigid
  pose, and both;
* few-shot: validation accuracy with 1, 3, 10, 30 and all training meshes (mean over
  ``--draws`` random draws for the small sets);
* times: training (features per mesh, fit), labelling a ~100k-face mesh with its ShDF
  given (a validation mesh subdivided x64), and the model file's size.

``--emd FILE``: also the EMD labelling network exported by ``python -m
model_export.train_labeler`` (trained on the same training split), on the same
validation meshes, the same per-sample-to-face mapping and graph cut, side by side;
``--emd-few-shot 10=FILE,30=FILE``: its few-shot rows (networks trained with ``--meshes
N``, draw 0, the trees' first draw).

    python benchmarks/bench_labeler.py [--cache-dir DIR] [--limit N] [--output FILE]
        [--emd FILE] [--emd-few-shot N=FILE,...]
"""

from __future__ import annotations

import argparse
import functools
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from neural_shdf.labeling import load_labeler, save_labeler
from neural_shdf.labeling._library import TriangleMesh, load_mesh
from neural_shdf.labeling.features import FEATURE_VERSION
from neural_shdf.labeling.labeler import (
    AUGMENT_EVERY,
    MeshDescription,
    TrainingRows,
    describe_mesh,
    fit_labeler,
    label_description,
    label_mesh,
    subdivided_copy,
    training_rows,
)

print = functools.partial(print, flush=True)  # noqa: A001
REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT))

from model_export.labeling_data import EmdLabeler, cached_shdf  # noqa: E402

DEFAULT_DIR = REPO_ROOT / ".." / "shared" / "data" / "human-seg"
DEFAULT_CACHE = Path.home() / ".cache" / "neural-shdf" / "labeler"
NAMES = ("head", "hands", "forearms", "upper arms", "torso", "thighs", "lower legs", "feet")
SMOOTHING_GRID = (0.0, 0.001, 0.003, 0.01, 0.03)
#: Training meshes of the model the smoothing is tuned with (keeps the run short).
TUNE_FIT_MESHES = 60
FEW_SHOT = (1, 3, 10, 30)


def cached_rows(
    path: Path, name: str, labels: np.ndarray, cache_dir: Path
) -> tuple[TrainingRows, float]:
    """Training rows of one mesh and the seconds its ShDF and features took (cached)."""
    file = cache_dir / f"rows-v{FEATURE_VERSION}" / f"{name}.npz"
    if file.is_file():
        with np.load(file) as data:
            return TrainingRows(data["features"], data["labels"], data["weights"]), float(
                data["seconds"]
            )
    start = time.perf_counter()
    mesh = load_mesh(path)
    description = describe_mesh(mesh, cached_shdf(mesh, name, cache_dir))
    rows = training_rows(description, labels)
    seconds = time.perf_counter() - start
    file.parent.mkdir(parents=True, exist_ok=True)
    np.savez(
        file, features=rows.features, labels=rows.labels, weights=rows.weights, seconds=seconds
    )
    return rows, seconds


def subdivided(
    mesh: TriangleMesh, labels: np.ndarray, times: int
) -> tuple[TriangleMesh, np.ndarray]:
    """The mesh with every triangle split into 4, ``times`` times; children keep the label."""
    return subdivided_copy(mesh, labels, times)


def cached_subdivided_rows(
    path: Path, name: str, labels: np.ndarray, cache_dir: Path
) -> TrainingRows:
    """Training rows of the mesh subdivided x16 (the labeller's augmentation; cached)."""
    file = cache_dir / f"rows-v{FEATURE_VERSION}" / f"{name}-x16.npz"
    if file.is_file():
        with np.load(file) as data:
            return TrainingRows(data["features"], data["labels"], data["weights"], True)
    fine, fine_labels = subdivided_copy(load_mesh(path), labels)
    rows = training_rows(describe_cached(fine, name + "-x16", cache_dir), fine_labels, True)
    file.parent.mkdir(parents=True, exist_ok=True)
    np.savez(file, features=rows.features, labels=rows.labels, weights=rows.weights)
    return rows


def posed(mesh: TriangleMesh, seed: int) -> TriangleMesh:
    """The mesh under a random rotation and translation."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    rotation = Rotation.random(random_state=seed).as_matrix()
    shift = rng.normal(size=3) * np.ptp(mesh.vertices, axis=0).max()
    return TriangleMesh(mesh.vertices @ rotation.T + shift, mesh.faces)


def accuracy(
    description: MeshDescription, truth: np.ndarray, classes: np.ndarray, values
) -> tuple[float, float]:
    predicted = np.asarray(values)[classes]
    right = predicted == truth
    areas = description.areas
    return float(right.mean()), float((right * areas).sum() / areas.sum())


def evaluate(labeler, described, smoothing=None) -> dict[str, tuple[float, float]]:
    """Mean (by count, area-weighted) accuracy per variant, before and after the cut.
    ``labeler``: the trees (``Labeler``) or an ``EmdLabeler``."""

    def label(description, value):
        if isinstance(labeler, EmdLabeler):
            return labeler.label_description(description, value)
        return label_description(description, labeler, value)

    out = {}
    for variant, items in described.items():
        cut, raw = [], []
        for description, truth in items:
            classes, _ = label(description, smoothing)
            cut.append(accuracy(description, truth, classes, labeler.label_values))
            plain, _ = label(description, 0.0)
            raw.append(accuracy(description, truth, plain, labeler.label_values))
        out[variant] = (tuple(np.mean(cut, axis=0)), tuple(np.mean(raw, axis=0)))
    return out


def load_emd(path: Path, wait: float) -> EmdLabeler:
    """An exported EMD network, waiting up to ``wait`` seconds for its training to write it."""
    deadline = time.monotonic() + wait
    while not path.is_file() and time.monotonic() < deadline:
        time.sleep(10)
    return EmdLabeler(path)


def print_table(result: dict) -> None:
    print(f"{'variant':<16} {'count':>7} {'area':>7}  {'no-cut':>7} {'no-cut area':>11}")
    for variant, (cut, raw) in result.items():
        print(f"{variant:<16} {cut[0]:7.4f} {cut[1]:7.4f}  {raw[0]:7.4f} {raw[1]:11.4f}")


def describe_cached(mesh, name, cache_dir) -> MeshDescription:
    return describe_mesh(mesh, cached_shdf(mesh, name, cache_dir))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=DEFAULT_DIR.resolve())
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE)
    parser.add_argument("--every", type=int, default=5, help="validation: every K-th mesh")
    parser.add_argument("--limit", type=int, help="only the first N meshes (a quick run)")
    parser.add_argument("--draws", type=int, default=3, help="random draws per few-shot size")
    parser.add_argument("--smoothing", type=float, help="skip tuning, use this smoothing")
    parser.add_argument("--output", type=Path, help="also write the trained labeller here")
    parser.add_argument(
        "--no-augment", action="store_true", help="no subdivided copies of training meshes"
    )
    parser.add_argument("--skip", default="", help="comma list of: few-shot,variants,timing")
    parser.add_argument("--emd", type=Path, help="also evaluate this EMD labelling network")
    parser.add_argument(
        "--emd-few-shot", default="", help="N=FILE,...: EMD networks trained on N meshes"
    )
    parser.add_argument(
        "--emd-wait",
        type=float,
        default=0.0,
        help="wait up to this many seconds for an EMD file still being trained",
    )
    args = parser.parse_args()
    skip = set(filter(None, args.skip.split(",")))
    if not (args.data_dir / "train").is_dir():
        print(f"human-seg folder {args.data_dir} is absent", file=sys.stderr)
        return 2
    paths = sorted((args.data_dir / "train").glob("*.obj"))[: args.limit]
    validation = paths[:: args.every]
    training = [p for i, p in enumerate(paths) if i % args.every]
    truth = {
        p.stem: np.loadtxt(args.data_dir / "face_labels" / f"{p.stem}.txt", dtype=np.int64)
        for p in paths
    }
    print(
        f"{len(paths)} meshes: {len(training)} training, "
        f"{len(validation)} validation (every {args.every}th)"
    )

    start = time.perf_counter()
    rows, feature_seconds = {}, []
    for path in training:
        rows[path.stem], seconds = cached_rows(path, path.stem, truth[path.stem], args.cache_dir)
        feature_seconds.append(seconds)
    print(
        f"training rows ready in {time.perf_counter() - start:.0f} s "
        f"(uncached: {np.mean(feature_seconds):.2f} s per mesh for exact ShDF + features)"
    )

    names = [p.stem for p in training]
    path_of = {p.stem: p for p in training}

    def training_set(selected: list[str]) -> list[TrainingRows]:
        """Rows of the selected meshes, and of every AUGMENT_EVERY-th one subdivided x16,
        as ``train_labeler`` learns them."""
        chosen = [rows[n] for n in selected]
        if not args.no_augment:
            chosen += [
                cached_subdivided_rows(path_of[n], n, truth[n], args.cache_dir)
                for n in selected[::AUGMENT_EVERY]
            ]
        return chosen

    if args.smoothing is None:
        tune = names[::5]
        fit = [n for n in names if n not in set(tune)][:: max(1, len(names) // TUNE_FIT_MESHES)]
        labeler = fit_labeler(training_set(fit), NAMES)
        tune_described = {"tune": []}
        for path in training[::5]:
            mesh = load_mesh(path)
            tune_described["tune"].append(
                (describe_cached(mesh, path.stem, args.cache_dir), truth[path.stem])
            )
        print(f"\ntuning: fit on {len(fit)}, tuned on {len(tune)} training meshes")
        print(f"{'smoothing':>9} {'count':>7} {'area':>7}")
        best = (-1.0, 0.0)
        for smoothing in SMOOTHING_GRID:
            (cut, _raw) = evaluate(labeler, tune_described, smoothing)["tune"]
            print(f"{smoothing:9.3f} {cut[0]:7.4f} {cut[1]:7.4f}")
            best = max(best, (cut[0], smoothing))
        args.smoothing = best[1]
        print(f"chosen smoothing {args.smoothing}")
        del tune_described

    described: dict[str, list] = {
        "original": [],
        "subdivided x16": [],
        "rigid pose": [],
        "x16 + pose": [],
    }
    start = time.perf_counter()
    for index, path in enumerate(validation):
        mesh = load_mesh(path)
        labels = truth[path.stem]
        described["original"].append((describe_cached(mesh, path.stem, args.cache_dir), labels))
        if "variants" in skip:
            continue
        fine, fine_labels = subdivided(mesh, labels, 2)
        described["subdivided x16"].append(
            (describe_cached(fine, path.stem + "-x16", args.cache_dir), fine_labels)
        )
        moved = posed(mesh, index)
        described["rigid pose"].append(
            (describe_cached(moved, path.stem + "-pose", args.cache_dir), labels)
        )
        both = posed(fine, index)
        described["x16 + pose"].append(
            (describe_cached(both, path.stem + "-x16-pose", args.cache_dir), fine_labels)
        )
    described = {k: v for k, v in described.items() if v}
    print(f"validation meshes described in {time.perf_counter() - start:.0f} s")

    start = time.perf_counter()
    labeler = fit_labeler(training_set(names), NAMES, smoothing=args.smoothing)
    fit_seconds = time.perf_counter() - start
    with tempfile.TemporaryDirectory() as folder:
        file = save_labeler(labeler, Path(folder) / "human.npz")
        size = file.stat().st_size
        labeler = load_labeler(file)
    if args.output:
        save_labeler(labeler, args.output)
    result = evaluate(labeler, described)
    print(
        f"\nvalidation ({len(validation)} meshes), all {len(names)} training meshes, "
        f"smoothing {args.smoothing}"
    )
    print_table(result)
    emd = load_emd(args.emd, args.emd_wait) if args.emd else None
    if emd is not None:
        training = emd.metadata["training"]
        print(
            f"\nEMD network {args.emd.name} ({training['meshes']} training meshes, "
            f"{training['steps']} steps in {training['train_seconds']:.0f} s), "
            f"smoothing {emd.metadata['smoothing']}, same validation meshes"
        )
        print_table(evaluate(emd, described))

    if "few-shot" not in skip:
        print(f"\nfew-shot (validation, original meshes; mean of {args.draws} draws)")
        print(f"{'meshes':>6} {'count':>7} {'area':>7} {'min':>7} {'fit s':>6}")
        only_original = {"original": described["original"]}
        for count in (*FEW_SHOT, len(names)):
            if count > len(names):
                continue
            if count == len(names):
                print(
                    f"{count:6d} {result['original'][0][0]:7.4f} "
                    f"{result['original'][0][1]:7.4f} {'':>7} {fit_seconds:6.1f}"
                )
                continue
            draws = 1 if count >= 30 else args.draws
            scores, seconds = [], []
            for draw in range(draws):
                chosen = np.random.default_rng(draw).choice(len(names), size=count, replace=False)
                begin = time.perf_counter()
                small = fit_labeler(
                    training_set([names[i] for i in sorted(chosen)]),
                    NAMES,
                    smoothing=args.smoothing,
                    labels=np.arange(1, 9),
                )
                seconds.append(time.perf_counter() - begin)
                scores.append(evaluate(small, only_original)["original"][0])
            scores = np.asarray(scores)
            print(
                f"{count:6d} {scores[:, 0].mean():7.4f} {scores[:, 1].mean():7.4f} "
                f"{scores[:, 0].min():7.4f} {np.mean(seconds):6.1f}"
            )
    emd_files = dict(item.split("=", 1) for item in filter(None, args.emd_few_shot.split(",")))
    if emd is not None and emd_files:
        emd_files[str(len(names))] = str(args.emd)
    if emd_files:
        print("\nfew-shot, EMD network (validation, original meshes; draw 0)")
        print(f"{'meshes':>6} {'count':>7} {'area':>7} {'train s':>8}")
    for count, file in sorted(emd_files.items(), key=lambda item: int(item[0])):
        network = load_emd(Path(file), args.emd_wait)
        (score, _raw) = evaluate(network, {"original": described["original"]})["original"]
        seconds = network.metadata["training"]["train_seconds"]
        print(f"{int(count):6d} {score[0]:7.4f} {score[1]:7.4f} {seconds:8.0f}")

    if "timing" not in skip:
        mesh = load_mesh(validation[0])
        big, _ = subdivided(mesh, truth[validation[0].stem], 3)
        shdf = cached_shdf(big, validation[0].stem + "-x64", args.cache_dir)
        label_mesh(big, labeler, shdf=shdf)  # warm the kernels
        times = []
        for _ in range(3):
            fresh = TriangleMesh(big.vertices, big.faces)  # no cached derived arrays
            begin = time.perf_counter()
            label_mesh(fresh, labeler, shdf=shdf)
            times.append(time.perf_counter() - begin)
        print(
            f"\nlabelling {big.face_count} faces, ShDF given: median {np.median(times):.2f} s of 3 "
            f"(face graph, orientation, features, trees, graph cut)"
        )
        if emd is not None:
            times = []
            for _ in range(3):
                fresh = TriangleMesh(big.vertices, big.faces)
                begin = time.perf_counter()
                emd.label_description(describe_mesh(fresh, shdf))
                times.append(time.perf_counter() - begin)
            print(
                f"EMD network, the same mesh: median {np.median(times):.2f} s of 3 "
                "(the same description, sample graph, onnxruntime, graph cut)"
            )
    print(
        f"\ntraining on {len(names)} meshes: fit {fit_seconds:.0f} s + features "
        f"{np.sum(feature_seconds):.0f} s uncached ({np.mean(feature_seconds):.2f} s per mesh); "
        f"model file {size / 1e6:.1f} MB; {labeler.trees.tree_start.size - 1} trees"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
