"""Export a trained checkpoint to ``service/neural_shdf/models/emd.onnx`` + ``emd.json``.

``python -m model_export.export [--checkpoint DIR/run/best.pt]``. The ONNX graph
(opset 17, dynamic numbers of nodes and edges) holds the feature and target
normalisers; the model card records the graph spec, feature version, training
data and metrics, and the sha256 of the ONNX file. The export is checked
against PyTorch with onnxruntime before the card is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

from model_export.data import DEFAULT_CACHE, TRAINING_RAY_COUNT
from model_export.shdf_task import (
    INPUT_NAMES,
    OUTPUT_NAMES,
    ShdfNetwork,
    export_graph_network,
    to_tensors,
)
from neural_shdf.shdf.neural.graph import (
    EDGE_FEATURES,
    FEATURE_SPEC_VERSION,
    GraphSpec,
)
from neural_shdf.shdf.neural.inference import DEFAULT_MODEL_PATH, file_sha256

OPSET = 17


def example_inputs(
    nodes: int = 64, edges: int = 400, seed: int = 0, node_columns: int = 7
) -> dict[str, np.ndarray]:
    """Random graph inputs of the right shapes and dtypes (for tracing and checks)."""
    rng = np.random.default_rng(seed)
    node_features = rng.random((nodes, node_columns)).astype(np.float32) + 0.5
    return {
        "node_features": node_features,
        "edge_features": rng.normal(size=(edges, len(EDGE_FEATURES))).astype(np.float32),
        "senders": rng.integers(0, nodes, edges).astype(np.int64),
        "receivers": rng.integers(0, nodes, edges).astype(np.int64),
    }


def export_onnx(model: ShdfNetwork, path: Path) -> None:
    """Write ``model`` as ONNX with dynamic node and edge counts."""
    example = to_tensors(example_inputs(node_columns=model.node_norm.mean.numel()))
    export_graph_network(model, example, path, OUTPUT_NAMES[0], OPSET)


def max_difference(model: ShdfNetwork, path: Path, inputs: dict[str, np.ndarray]) -> float:
    """Largest |onnxruntime - PyTorch| output difference on ``inputs``."""
    import onnxruntime

    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (onnx_out,) = session.run(None, {k: inputs[k] for k in INPUT_NAMES})
    with torch.no_grad():
        tensors = to_tensors(inputs)
        torch_out = model(*(tensors[name] for name in INPUT_NAMES)).numpy()
    return float(np.abs(onnx_out - torch_out).max())


def write_card(path: Path, card: dict) -> None:
    card = dict(card)
    card["sha256"] = file_sha256(path)
    path.with_suffix(".json").write_text(json.dumps(card, indent=2, sort_keys=True) + "\n")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_CACHE / "run" / "best.pt")
    parser.add_argument("--out", type=Path, default=DEFAULT_MODEL_PATH)
    parser.add_argument("--extra", type=Path, default=None, help="JSON merged into the card")
    args = parser.parse_args(argv)
    checkpoint = torch.load(args.checkpoint.expanduser(), weights_only=False)
    config = checkpoint["config"]
    rays = bool(config.get("rays", False))
    model = ShdfNetwork(latent=config["latent"], steps=config["message_steps"], rays=rays)
    model.load_state_dict(checkpoint["model"])
    model.eval()
    export_onnx(model, args.out)
    spec = GraphSpec(
        knn=config.get("knn", GraphSpec.knn),
        cone_neighbours=config.get("cone", 0),
        ray_count=TRAINING_RAY_COUNT if rays else 0,
    )
    columns = len(spec.node_features)
    difference = max(
        max_difference(model, args.out, example_inputs(n, 8 * n, seed=n, node_columns=columns))
        for n in (50, 700)
    )
    if difference > 1e-4:
        raise SystemExit(f"onnxruntime and PyTorch differ by {difference}")
    state = checkpoint["state"]
    history = state.get("history", [])
    card = {
        "format": "neural-shdf-emd",
        "feature_spec_version": FEATURE_SPEC_VERSION,
        "graph_spec": spec.to_dict(),
        "node_features": list(spec.node_features),
        "edge_features": list(EDGE_FEATURES),
        "inputs": list(INPUT_NAMES),
        "outputs": list(OUTPUT_NAMES),
        "output_meaning": "log(raw ShDF diameter / Poisson radius) per sample",
        "ray_informed": rays,
        "opset": OPSET,
        "architecture": {
            "kind": "encode-process-decode",
            "latent": config["latent"],
            "message_passing_steps": config["message_steps"],
            "mlp_hidden_layers": 2,
            "message_weight": "sender density",
        },
        "training": {
            "config": config,
            "steps": state["step"],
            "wall_seconds": round(state["elapsed"], 1),
            "best_val_loss": state.get("best_val_loss"),
            "last_metrics": history[-1] if history else None,
            "checkpoint": args.checkpoint.name,
            "warm_start": state.get("init"),
        },
        "onnx_vs_torch_max_abs_diff": difference,
        "normalisers": {k: v for k, v in checkpoint["stats"].items()},
    }
    if args.extra:
        card.update(json.loads(args.extra.read_text()))
    write_card(args.out, card)
    print(f"wrote {args.out} and {args.out.with_suffix('.json').name} (diff {difference:.2e})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
