"""Train the neural ShDF network on the cached sample graphs (CPU), with checkpoints.

``nice -n 10 python -m model_export.train --minutes 55`` (resumes from
``DIR/run/last.pt`` when it exists). Adam, learning rate held at 1e-3 for the
first ``--hold`` share of the budget, then decayed exponentially to 1e-5 at its
end (the paper's schedule, scaled to a wall-clock budget). Logs to
``DIR/run/train.log``; keeps ``last.pt`` and ``best.pt`` (lowest validation loss).
New graphs written by a running ``model_export.data`` are picked up as they land.
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

from model_export.data import DEFAULT_CACHE, file_logger, graph_folder
from model_export.shdf_task import ShdfNetwork, batch_graphs
from neural_shdf.shdf.neural.graph import (
    EDGE_FEATURES,
    NODE_FEATURES,
    node_feature_array,
    ray_feature_array,
)

CONE_COLUMN = EDGE_FEATURES.index("is_cone_edge")
DENSITY_COLUMN = NODE_FEATURES.index("density")


def rank_within_receiver(receivers: np.ndarray) -> np.ndarray:
    """Position of each edge among its receiver's edges (edges grouped by receiver)."""
    start = np.ones(len(receivers), dtype=bool)
    start[1:] = receivers[1:] != receivers[:-1]
    first = np.maximum.accumulate(np.where(start, np.arange(len(receivers)), 0))
    return np.arange(len(receivers)) - first


def subset_edges(
    arrays: dict[str, np.ndarray], knn: int, cone: int, rays: bool = False
) -> dict[str, np.ndarray]:
    """Keep each receiver's ``knn`` nearest and ``cone`` nearest cone edges (both stored
    nearest first) and recompute the node features, as ``build_sample_graph`` with
    those counts would have built them (cached graphs of an older node-feature
    version work too: only their density column is read)."""
    is_cone = arrays["edge_features"][:, CONE_COLUMN] > 0.5
    receivers = arrays["receivers"]
    keep = np.zeros(len(receivers), dtype=bool)
    for mask, limit in ((~is_cone, knn), (is_cone, cone)):
        index = np.flatnonzero(mask)
        keep[index[rank_within_receiver(receivers[index]) < limit]] = True
    out = dict(arrays)
    for key in ("edge_features", "senders", "receivers"):
        out[key] = arrays[key][keep]
    density = arrays["node_features"][:, DENSITY_COLUMN].astype(np.float64)
    out["node_features"] = node_feature_array(density, out["edge_features"], out["receivers"])
    if rays:
        ray_features = ray_feature_array(
            arrays["ray_diameter"], arrays["ray_spread"], arrays["ray_hits"]
        )
        out["node_features"] = np.concatenate([out["node_features"], ray_features], axis=1)
    for key in ("ray_diameter", "ray_spread", "ray_hits"):
        out.pop(key, None)
    return out


class GraphStore:
    """Graph files of one split, loaded lazily and kept in memory."""

    def __init__(self, folder: Path, *, knn: int, cone: int, rays: bool = False) -> None:
        self.folder = folder
        self.knn, self.cone, self.rays = knn, cone, rays
        self.paths: list[Path] = []
        self.loaded: dict[Path, dict[str, np.ndarray]] = {}
        self.rescan()

    def rescan(self) -> int:
        self.paths = sorted(self.folder.glob("*.npz"))
        return len(self.paths)

    def get(self, path: Path) -> dict[str, np.ndarray]:
        if path not in self.loaded:
            with np.load(path) as data:
                arrays = {k: data[k] for k in data.files}
            self.loaded[path] = subset_edges(arrays, self.knn, self.cone, self.rays)
        return self.loaded[path]


def feature_stats(
    store: GraphStore, model: ShdfNetwork, count: int = 300
) -> dict[str, list[float]]:
    """Mean and std of node features, edge features and finite targets (what the
    network predicts: the residual over ``model.base``) over some graphs."""
    paths = store.paths[:: max(1, len(store.paths) // count)]
    graphs = [store.get(p) for p in paths]
    nodes = np.concatenate([g["node_features"] for g in graphs])
    edges = np.concatenate([g["edge_features"] for g in graphs])
    target = np.concatenate([g["target"] for g in graphs])
    target = target - model.base(torch.from_numpy(nodes)).numpy()
    target = target[np.isfinite(target)]
    return {
        "node_mean": nodes.mean(0).tolist(),
        "node_std": nodes.std(0).tolist(),
        "edge_mean": edges.mean(0).tolist(),
        "edge_std": edges.std(0).tolist(),
        "target_mean": [float(target.mean())],
        "target_std": [float(target.std())],
    }


def apply_stats(model: ShdfNetwork, stats: dict[str, list[float]]) -> None:
    model.node_norm.set_stats(np.array(stats["node_mean"]), np.array(stats["node_std"]))
    model.edge_norm.set_stats(np.array(stats["edge_mean"]), np.array(stats["edge_std"]))
    model.target_norm.set_stats(np.array(stats["target_mean"]), np.array(stats["target_std"]))


@torch.no_grad()
def evaluate(model: ShdfNetwork, store: GraphStore, limit: int) -> dict[str, float]:
    """Loss and MAE of the log diameter over up to ``limit`` validation graphs."""
    model.eval()
    paths = store.paths[:: max(1, len(store.paths) // limit)][:limit]
    if not paths:
        return {"val_loss": float("inf"), "val_log_mae": float("nan"), "val_graphs": 0}
    losses, errors = [], []
    for path in paths:
        batch = batch_graphs([store.get(path)])
        losses.append(float(model.loss(batch)))
        pred = model(
            batch["node_features"], batch["edge_features"], batch["senders"], batch["receivers"]
        )
        mask = torch.isfinite(batch["target"])
        errors.append(float((pred[mask] - batch["target"][mask]).abs().mean()))
    model.train()
    return {
        "val_loss": float(np.mean(losses)),
        "val_log_mae": float(np.mean(errors)),
        "val_graphs": len(paths),
    }


def learning_rate(progress: float, hold: float, start: float, end: float) -> float:
    """Held at ``start`` until ``hold``, then exponential decay reaching ``end`` at 1."""
    if progress <= hold:
        return start
    fraction = min(1.0, (progress - hold) / max(1e-9, 1.0 - hold))
    return start * (end / start) ** fraction


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    parser.add_argument("--run", type=str, default="run", help="run folder name in the cache")
    parser.add_argument("--minutes", type=float, default=55.0, help="wall-clock budget")
    parser.add_argument("--max-steps", type=int, default=0)
    parser.add_argument("--latent", type=int, default=128)
    parser.add_argument("--message-steps", type=int, default=6)
    parser.add_argument("--graphs-per-step", type=int, default=1)
    parser.add_argument("--lr", type=float, default=1e-3)
    parser.add_argument("--lr-end", type=float, default=1e-5)
    parser.add_argument("--hold", type=float, default=0.4)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--val-every", type=int, default=500)
    parser.add_argument("--val-graphs", type=int, default=80)
    parser.add_argument("--knn", type=int, default=8, help="nearest-sample edges kept")
    parser.add_argument("--cone", type=int, default=4, help="cone edges kept (0: none)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--rays",
        action="store_true",
        help="the ray-informed network (RAY_NODE_FEATURES, residual over the "
        "cone's diameter); default the paper's ray-free network",
    )
    parser.add_argument(
        "--init",
        type=Path,
        default=None,
        help="warm start: weights and normalisers of this checkpoint, fresh "
        "optimizer and schedule (ignored when the run folder resumes)",
    )
    args = parser.parse_args(argv)

    torch.set_num_threads(args.threads)
    cache = args.cache.expanduser()
    run = cache / args.run
    log = file_logger(run / "train.log")

    train = GraphStore(graph_folder(cache) / "train", knn=args.knn, cone=args.cone, rays=args.rays)
    val = GraphStore(graph_folder(cache) / "val", knn=args.knn, cone=args.cone, rays=args.rays)
    model = ShdfNetwork(latent=args.latent, steps=args.message_steps, rays=args.rays)
    optimizer = torch.optim.Adam(model.parameters(), lr=args.lr)
    state = {"step": 0, "elapsed": 0.0, "best_val_loss": float("inf"), "history": []}
    last = run / "last.pt"
    if last.exists():
        checkpoint = torch.load(last, weights_only=False)
        model.load_state_dict(checkpoint["model"])
        optimizer.load_state_dict(checkpoint["optimizer"])
        state = checkpoint["state"]
        stats = checkpoint["stats"]
        log(f"resumed at step {state['step']} after {state['elapsed']:.0f}s")
    elif args.init is not None:
        checkpoint = torch.load(args.init.expanduser(), weights_only=False)
        model.load_state_dict(checkpoint["model"])
        stats = checkpoint["stats"]
        state["init"] = {
            "checkpoint": str(args.init),
            "steps": checkpoint["state"]["step"],
            "elapsed": checkpoint["state"]["elapsed"],
        }
        log(f"warm start from {args.init} (step {checkpoint['state']['step']})")
    else:
        stats = feature_stats(train, model)
        apply_stats(model, stats)
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}

    def save(path: Path) -> None:
        torch.save(
            {
                "model": model.state_dict(),
                "optimizer": optimizer.state_dict(),
                "state": state,
                "stats": stats,
                "config": config,
            },
            path.with_suffix(".tmp"),
        )
        path.with_suffix(".tmp").replace(path)

    rng = random.Random(args.seed + state["step"])
    torch.manual_seed(args.seed + state["step"])
    budget = args.minutes * 60.0
    log(
        f"training: {len(train.paths)} train graphs, {len(val.paths)} val graphs, "
        f"config {json.dumps(config)}"
    )
    session_start = time.time() - state["elapsed"]
    last_save = time.time()
    running = []
    while True:
        state["elapsed"] = time.time() - session_start
        progress = state["elapsed"] / budget
        if progress >= 1.0 or (args.max_steps and state["step"] >= args.max_steps):
            break
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(progress, args.hold, args.lr, args.lr_end)
        graphs = [train.get(rng.choice(train.paths)) for _ in range(args.graphs_per_step)]
        batch = batch_graphs(graphs)
        optimizer.zero_grad()
        loss = model.loss(batch)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        running.append(float(loss.detach()))
        state["step"] += 1
        if state["step"] % args.val_every == 0:
            metrics = evaluate(model, val, args.val_graphs)
            metrics.update(
                step=state["step"],
                elapsed=round(state["elapsed"], 1),
                train_loss=float(np.mean(running)),
                lr=optimizer.param_groups[0]["lr"],
                train_graphs=train.rescan(),
            )
            val.rescan()
            running = []
            state["history"].append(metrics)
            log(json.dumps(metrics))
            if metrics["val_loss"] < state["best_val_loss"]:
                state["best_val_loss"] = metrics["val_loss"]
                save(run / "best.pt")
        if time.time() - last_save > 120:
            save(last)
            last_save = time.time()
    metrics = evaluate(model, val, args.val_graphs)
    metrics.update(step=state["step"], elapsed=round(state["elapsed"], 1), final=True)
    state["history"].append(metrics)
    log(json.dumps(metrics))
    if metrics["val_loss"] < state["best_val_loss"]:
        state["best_val_loss"] = metrics["val_loss"]
        save(run / "best.pt")
    save(last)
    log("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
