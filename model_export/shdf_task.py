"""The ShDF task around the task-agnostic core: features, normalisers, target and loss.

Target per sample: ``log(raw diameter / Poisson radius)`` (the radius is the
graph's length unit, so the target is scale invariant). The network's output is
de-normalised inside the model, so the exported ONNX graph returns that log
diameter directly and the service needs no constants besides the graph spec.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from model_export.core_model import EncodeProcessDecode
from neural_shdf.shdf.neural.graph import (
    EDGE_FEATURES,
    NODE_FEATURES,
    RAY_NODE_FEATURES,
    SampleGraph,
)

#: ONNX input and output names (the service feeds these).
INPUT_NAMES = ("node_features", "edge_features", "senders", "receivers")
OUTPUT_NAMES = ("log_diameter",)
#: Node feature column holding the density that scales messages.
DENSITY_COLUMN = NODE_FEATURES.index("density")
#: Ray-informed networks: columns of the ray cone's hit flag and log diameter.
HAS_RAY_COLUMN = len(NODE_FEATURES) + RAY_NODE_FEATURES.index("has_ray_hit")
LOG_RAY_COLUMN = len(NODE_FEATURES) + RAY_NODE_FEATURES.index("log_ray_diameter")


def log_diameter_target(raw_per_sample: np.ndarray, radius: float) -> np.ndarray:
    """Training target from raw diameters (NaN/non-positive stay NaN = no target)."""
    raw = np.asarray(raw_per_sample, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(raw > 0, np.log(raw / radius), np.nan)


class Normaliser(nn.Module):
    """Fixed affine normalisation ``(x - mean) / std`` with constants kept as buffers."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("std", torch.ones(size))

    def set_stats(self, mean: np.ndarray, std: np.ndarray) -> None:
        self.mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        self.std.copy_(torch.as_tensor(np.maximum(std, 1e-6), dtype=torch.float32))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x - self.mean) / self.std

    def inverse(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.std + self.mean


class ShdfNetwork(nn.Module):
    """Graph features in, log diameter (in Poisson radii) per sample out.

    ``rays``: the ray-informed network. Its nodes also carry ``RAY_NODE_FEATURES`` and
    it predicts a correction of the ray cone's own log diameter (a residual: where the
    cone has a valid hit the network starts from it; elsewhere from zero).
    """

    def __init__(self, *, latent: int = 128, steps: int = 6, rays: bool = False) -> None:
        super().__init__()
        self.rays = rays
        node_count = len(NODE_FEATURES) + (len(RAY_NODE_FEATURES) if rays else 0)
        self.node_norm = Normaliser(node_count)
        self.edge_norm = Normaliser(len(EDGE_FEATURES))
        self.target_norm = Normaliser(1)
        self.core = EncodeProcessDecode(
            node_count, len(EDGE_FEATURES), 1, latent=latent, steps=steps
        )

    def base(self, node_features: torch.Tensor) -> torch.Tensor:
        """What the network corrects: the cone's log diameter (rays), else zero."""
        if not self.rays:
            return torch.zeros_like(node_features[:, 0])
        return node_features[:, HAS_RAY_COLUMN] * node_features[:, LOG_RAY_COLUMN]

    def normalised_output(
        self,
        node_features: torch.Tensor,
        edge_features: torch.Tensor,
        senders: torch.Tensor,
        receivers: torch.Tensor,
    ) -> torch.Tensor:
        density = node_features[:, DENSITY_COLUMN]
        out = self.core(
            self.node_norm(node_features),
            self.edge_norm(edge_features),
            senders,
            receivers,
            density,
        )
        return out[:, 0]

    def forward(
        self,
        node_features: torch.Tensor,
        edge_features: torch.Tensor,
        senders: torch.Tensor,
        receivers: torch.Tensor,
    ) -> torch.Tensor:
        normalised = self.normalised_output(node_features, edge_features, senders, receivers)
        return self.base(node_features) + self.target_norm.inverse(normalised.unsqueeze(1))[:, 0]

    def loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """Huber loss (squared within one standard deviation, linear beyond: the
        paper's L2, made robust to the noisy diameters of messy meshes) of the
        normalised log diameter over samples with a target."""
        prediction = self.normalised_output(
            batch["node_features"], batch["edge_features"], batch["senders"], batch["receivers"]
        )
        residual = batch["target"] - self.base(batch["node_features"])
        target = self.target_norm(residual.unsqueeze(1))[:, 0]
        mask = torch.isfinite(target)
        return torch.nn.functional.huber_loss(prediction[mask], target[mask], delta=1.0)


def graph_arrays(graph: SampleGraph) -> dict[str, np.ndarray]:
    """The network's inputs of one sample graph, as numpy arrays (compact dtypes)."""
    return {
        "node_features": graph.node_features.astype(np.float32),
        "edge_features": graph.edge_features.astype(np.float32),
        "senders": graph.senders.astype(np.int32),
        "receivers": graph.receivers.astype(np.int32),
    }


def to_tensors(arrays: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    """Numpy graph arrays -> tensors (int64 indices)."""
    out = {}
    for key, value in arrays.items():
        if key in ("senders", "receivers"):
            out[key] = torch.from_numpy(np.asarray(value, dtype=np.int64))
        else:
            out[key] = torch.from_numpy(np.asarray(value, dtype=np.float32))
    return out


def batch_graphs(graphs: list[dict[str, np.ndarray]]) -> dict[str, torch.Tensor]:
    """Concatenate graphs into one disconnected graph (indices offset)."""
    offset = 0
    parts: dict[str, list[np.ndarray]] = {k: [] for k in (*INPUT_NAMES, "target")}
    for g in graphs:
        n = len(g["node_features"])
        parts["node_features"].append(g["node_features"])
        parts["edge_features"].append(g["edge_features"])
        parts["senders"].append(g["senders"].astype(np.int64) + offset)
        parts["receivers"].append(g["receivers"].astype(np.int64) + offset)
        parts["target"].append(g["target"].astype(np.float32))
        offset += n
    return to_tensors({k: np.concatenate(v) for k, v in parts.items()})


def export_graph_network(
    model: nn.Module, inputs: dict[str, torch.Tensor], path: Path, output: str, opset: int
) -> None:
    """Trace ``model`` on ``inputs`` into ONNX at ``path``: the sample graph's four inputs
    (``INPUT_NAMES``) and one per-node ``output``, with dynamic numbers of nodes and edges."""
    model.eval()
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.onnx.export(
        model,
        tuple(inputs[name] for name in INPUT_NAMES),
        str(path),
        dynamo=False,
        opset_version=opset,
        input_names=list(INPUT_NAMES),
        output_names=[output],
        dynamic_axes={
            "node_features": {0: "nodes"},
            "edge_features": {0: "edges"},
            "senders": {0: "edges"},
            "receivers": {0: "edges"},
            output: {0: "nodes"},
        },
    )
