"""Train the EMD part-labelling network on human-seg's training split (CPU), export ONNX.

``nice -n 10 python -m model_export.train_labeler --minutes 25 [--meshes 10]``

Training meshes: human-seg's training split of ``bench_labeler.py`` (every ``--every``-th
mesh by sorted name is validation and never read here), plus every 3rd training mesh
subdivided x16 (as ``train_labeler(augment=True)``); ``--meshes N`` draws N of them as
the benchmark's few-shot rows do (``numpy.random.default_rng(draw)``). Per mesh: exact
ShDF, labeller description, ``labeling_data.network_inputs`` (cached under
``CACHE/emd-graphs-v*``). Adam, learning rate held for ``--hold`` of the wall-clock
budget then decayed exponentially (``train.learning_rate``); checkpoints every 2 min in
``CACHE/RUN/last.pt`` (a rerun resumes); the final weights are exported to
``CACHE/RUN/labeler.onnx`` and checked against PyTorch with onnxruntime. No
checkpoint is chosen on validation meshes: the last one is exported.
"""

from __future__ import annotations

import argparse
import json
import random
import sys
import time
from pathlib import Path

import numpy as np
import torch

from model_export.data import file_logger
from model_export.labeling_data import (
    cached_shdf,
    human_seg_split,
    network_inputs,
    sample_classes,
)
from model_export.labeling_task import (
    LabelNetwork,
    apply_stats,
    batch_graphs,
    example_inputs,
    export_onnx,
    max_difference,
    set_feature_stats,
)
from model_export.train import learning_rate
from neural_shdf.labeling._library import load_mesh
from neural_shdf.labeling.features import FEATURE_VERSION
from neural_shdf.labeling.labeler import (
    AUGMENT_EVERY,
    DEFAULT_SMOOTHING,
    describe_mesh,
    subdivided_copy,
    triangle_labels,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO_ROOT / ".." / "shared" / "data" / "human-seg"
DEFAULT_CACHE = Path.home() / ".cache" / "neural-shdf" / "labeler"
HUMAN_SEG_NAMES = (
    "head",
    "hands",
    "forearms",
    "upper arms",
    "torso",
    "thighs",
    "lower legs",
    "feet",
)


def training_graph(
    path: Path,
    labels: np.ndarray,
    values: np.ndarray,
    cache: Path,
    subdivided: bool,
    cached_only: bool = False,
) -> dict[str, np.ndarray] | None:
    """Network inputs and per-sample classes of one training mesh (or its x16 copy),
    cached; ``cached_only``: None when not cached yet (another process prepares it)."""
    name = path.stem + ("-x16" if subdivided else "")
    file = cache / f"emd-graphs-v{FEATURE_VERSION}" / f"{name}.npz"
    if file.is_file():
        with np.load(file) as data:
            return {k: data[k] for k in data.files}
    if cached_only:
        return None
    mesh = load_mesh(path)
    per_triangle = triangle_labels(mesh, labels)
    if subdivided:
        mesh, per_triangle = subdivided_copy(mesh, per_triangle)
    description = describe_mesh(mesh, cached_shdf(mesh, name, cache))
    arrays = network_inputs(description)
    arrays["target"] = sample_classes(description, per_triangle, values)
    file.parent.mkdir(parents=True, exist_ok=True)
    np.savez(file.with_suffix(".tmp.npz"), **arrays)
    file.with_suffix(".tmp.npz").replace(file)
    return arrays


def selected_meshes(training: list[Path], count: int, draw: int) -> list[Path]:
    """All training meshes, or ``count`` drawn as ``bench_labeler.py``'s few-shot rows."""
    if count <= 0 or count >= len(training):
        return training
    chosen = np.random.default_rng(draw).choice(len(training), size=count, replace=False)
    return [training[i] for i in sorted(chosen)]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--every", type=int, default=5, help="validation: every K-th mesh")
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    parser.add_argument("--run", default="emd", help="run folder name in the cache")
    parser.add_argument("--meshes", type=int, default=0, help="train on N drawn meshes (0: all)")
    parser.add_argument("--draw", type=int, default=0, help="which random draw of --meshes")
    parser.add_argument("--limit", type=int, default=0, help="only the first N meshes (tests)")
    parser.add_argument("--minutes", type=float, default=25.0, help="wall-clock budget")
    parser.add_argument("--max-steps", type=int, default=0)
    parser.add_argument("--latent", type=int, default=32)
    parser.add_argument("--message-steps", type=int, default=3)
    parser.add_argument("--graphs-per-step", type=int, default=2)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--lr-end", type=float, default=1e-5)
    parser.add_argument("--hold", type=float, default=0.4)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--smoothing", type=float, default=DEFAULT_SMOOTHING)
    parser.add_argument("--no-augment", action="store_true")
    parser.add_argument("--prepare-only", action="store_true", help="only cache the graphs")
    parser.add_argument(
        "--while-preparing",
        action="store_true",
        help="start on the graphs already cached and pick up the others as "
        "--prepare-only processes write them",
    )
    parser.add_argument("--part", default="0/1", help="i/n: this process's share (prepare)")
    parser.add_argument("--out", type=Path, help="ONNX file (default CACHE/RUN/labeler.onnx)")
    args = parser.parse_args(argv)

    torch.set_num_threads(args.threads)
    cache = args.cache.expanduser()
    run = cache / args.run
    log = file_logger(run / "train.log")

    training, _validation = human_seg_split(args.data_dir, args.every)
    if args.limit:
        training = training[: args.limit]
    truth = {
        p.stem: np.loadtxt(args.data_dir / "face_labels" / f"{p.stem}.txt", dtype=np.int64)
        for p in training
    }
    values = np.unique(np.concatenate(list(truth.values())))
    chosen = selected_meshes(training, args.meshes, args.draw)
    jobs = [(p, False) for p in chosen]
    if not args.no_augment:
        jobs += [(p, True) for p in chosen[::AUGMENT_EVERY]]
    start = time.time()
    if args.prepare_only:
        part, parts = (int(x) for x in args.part.split("/"))
        for path, fine in jobs[part::parts]:
            training_graph(path, truth[path.stem], values, cache, fine)
        log(f"prepared {len(jobs[part::parts])} graphs in {time.time() - start:.0f}s")
        return 0
    pending = list(jobs)

    def gather() -> list[dict[str, np.ndarray]]:
        """Graphs of the pending jobs that are ready (all of them unless --while-preparing)."""
        found, waiting = [], []
        for path, fine in pending:
            graph = training_graph(
                path, truth[path.stem], values, cache, fine, cached_only=args.while_preparing
            )
            if graph is None:
                waiting.append((path, fine))
            else:
                found.append(graph)
        pending[:] = waiting
        return found

    graphs = gather()
    prepare_seconds = time.time() - start
    log(
        f"{len(graphs)} training graphs ({len(chosen)} meshes) ready in {prepare_seconds:.0f}s; "
        f"{len(pending)} pending"
    )

    model = LabelNetwork(len(values), latent=args.latent, steps=args.message_steps)
    optimizer = torch.optim.Adam(model.parameters(), lr=args.lr)
    state: dict = {"step": 0, "elapsed": 0.0, "history": []}
    last = run / "last.pt"
    if last.exists():
        checkpoint = torch.load(last, weights_only=False)
        model.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        state, stats = checkpoint["state"], checkpoint["stats"]
        apply_stats(model, stats)
        log(f"resumed at step {state['step']} after {state['elapsed']:.0f}s")
    else:
        torch.manual_seed(args.seed)
        model = LabelNetwork(len(values), latent=args.latent, steps=args.message_steps)
        optimizer = torch.optim.Adam(model.parameters(), lr=args.lr)
        stats = set_feature_stats(model, graphs)
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}

    def save(path: Path) -> None:
        torch.save(
            {
                "model": model.state_dict(),
                "optimizer": optimizer.state_dict(),
                "state": state,
                "stats": stats,
                "config": config,
                "label_values": values.tolist(),
            },
            path.with_suffix(".tmp"),
        )
        path.with_suffix(".tmp").replace(path)

    rng = random.Random(args.seed + state["step"])
    torch.manual_seed(args.seed + state["step"])
    budget = args.minutes * 60.0
    session_start = time.time() - state["elapsed"]
    # CPU seconds the process got (on a shared machine far fewer than the wall-clock ones).
    cpu_start = time.process_time() - state.get("cpu_seconds", 0.0)
    last_save = time.time()
    losses: list[float] = []
    right = total = 0
    model.train()
    while True:
        state["elapsed"] = time.time() - session_start
        state["cpu_seconds"] = time.process_time() - cpu_start
        progress = state["elapsed"] / budget
        if progress >= 1.0 or (args.max_steps and state["step"] >= args.max_steps):
            break
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(progress, args.hold, args.lr, args.lr_end)
        batch = batch_graphs([rng.choice(graphs) for _ in range(args.graphs_per_step)])
        optimizer.zero_grad()
        log_probabilities = model(
            batch["node_features"], batch["edge_features"], batch["senders"], batch["receivers"]
        )
        loss = torch.nn.functional.nll_loss(log_probabilities, batch["target"])
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        losses.append(float(loss.detach()))
        right += int((log_probabilities.argmax(1) == batch["target"]).sum())
        total += len(batch["target"])
        state["step"] += 1
        if pending and state["step"] % 100 == 0:
            graphs += gather()
        if state["step"] % 200 == 0:
            metrics = {
                "step": state["step"],
                "elapsed": round(state["elapsed"], 1),
                "cpu_seconds": round(state["cpu_seconds"], 1),
                "train_loss": round(float(np.mean(losses)), 4),
                "train_sample_accuracy": round(right / max(total, 1), 4),
                "lr": optimizer.param_groups[0]["lr"],
                "graphs": len(graphs),
            }
            state["history"].append(metrics)
            log(json.dumps(metrics))
            losses, right, total = [], 0, 0
        if time.time() - last_save > 120:
            save(last)
            last_save = time.time()
    save(last)
    model.eval()
    out = args.out or run / "labeler.onnx"
    metadata = {
        "label_values": values.tolist(),
        "label_names": list(HUMAN_SEG_NAMES)
        if len(values) == len(HUMAN_SEG_NAMES)
        else [str(v) for v in values],
        "smoothing": args.smoothing,
        "architecture": {
            "kind": "encode-process-decode",
            "latent": args.latent,
            "message_passing_steps": args.message_steps,
            "mlp_hidden_layers": 2,
            "message_weight": "sender density",
        },
        "training": {
            "data": "human-seg train split (bench_labeler.py: every "
            f"{args.every}th mesh by name held out)",
            "meshes": len(chosen),
            "graphs": len(graphs),
            "steps": state["step"],
            "train_seconds": round(state["elapsed"], 1),
            "train_cpu_seconds": round(state["cpu_seconds"], 1),
            "prepare_seconds": round(prepare_seconds, 1),
            "config": config,
        },
    }
    export_onnx(model, out, metadata)
    difference = max(
        max_difference(model, out, example_inputs(n, 10 * n, seed=n)) for n in (50, 1000)
    )
    graph_difference = max_difference(model, out, {k: graphs[0][k] for k in graphs[0]})
    log(
        f"exported {out}: onnxruntime vs PyTorch max |diff| {difference:.2e} (random inputs), "
        f"{graph_difference:.2e} (a training graph); {state['step']} steps in "
        f"{state['elapsed']:.0f}s"
    )
    if max(difference, graph_difference) > 1e-4:
        raise SystemExit("onnxruntime and PyTorch disagree")
    log("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
