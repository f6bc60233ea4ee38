"""The part-labelling task on the task-agnostic EMD core: classes per sample, ONNX export.

The network (``LabelNetwork``) reads ``labeling_data.network_inputs`` (sample graph +
labeller features), normalises them inside the graph (constants as buffers) and returns
log class probabilities per sample. The exported ONNX file is self-contained: its
metadata (``metadata_props``) holds the label values and names, the graph and feature
specs and versions, the node feature names, the smoothing and the training summary.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from model_export.core_model import EncodeProcessDecode
from model_export.labeling_data import GRAPH_SPEC, INPUT_EDGE_FEATURES, INPUT_NODE_FEATURES
from model_export.shdf_task import INPUT_NAMES, Normaliser, export_graph_network, to_tensors
from neural_shdf.labeling.features import FEATURE_VERSION
from neural_shdf.shdf.neural.graph import FEATURE_SPEC_VERSION, NODE_FEATURES

OUTPUT_NAMES = ("log_probabilities",)
FORMAT = "neural-shdf-emd-labeler"
FORMAT_VERSION = 1
OPSET = 17
DENSITY_COLUMN = NODE_FEATURES.index("density")


class LabelNetwork(nn.Module):
    """Sample graph in, log class probabilities per sample out (Encode-Process-Decode)."""

    def __init__(self, classes: int, *, latent: int = 64, steps: int = 4) -> None:
        super().__init__()
        self.classes = classes
        self.node_norm = Normaliser(len(INPUT_NODE_FEATURES))
        self.edge_norm = Normaliser(len(INPUT_EDGE_FEATURES))
        self.core = EncodeProcessDecode(
            len(INPUT_NODE_FEATURES), len(INPUT_EDGE_FEATURES), classes, latent=latent, steps=steps
        )

    def forward(
        self,
        node_features: torch.Tensor,
        edge_features: torch.Tensor,
        senders: torch.Tensor,
        receivers: torch.Tensor,
    ) -> torch.Tensor:
        logits = self.core(
            self.node_norm(node_features),
            self.edge_norm(edge_features),
            senders,
            receivers,
            node_features[:, DENSITY_COLUMN],
        )
        return torch.log_softmax(logits, dim=1)

    def loss(self, batch: dict[str, torch.Tensor]) -> torch.Tensor:
        """Cross-entropy of the samples' classes (samples are area-uniform: area-weighted)."""
        log_probabilities = self(*(batch[name] for name in INPUT_NAMES))
        return nn.functional.nll_loss(log_probabilities, batch["target"])


def set_feature_stats(model: LabelNetwork, graphs: list[dict[str, np.ndarray]]) -> dict:
    """Mean and std of node and edge features over ``graphs``, set as the normalisers."""
    nodes = np.concatenate([g["node_features"] for g in graphs]).astype(np.float64)
    edges = np.concatenate([g["edge_features"] for g in graphs]).astype(np.float64)
    stats = {
        "node_mean": nodes.mean(0).tolist(),
        "node_std": nodes.std(0).tolist(),
        "edge_mean": edges.mean(0).tolist(),
        "edge_std": edges.std(0).tolist(),
    }
    apply_stats(model, stats)
    return stats


def apply_stats(model: LabelNetwork, stats: dict[str, list[float]]) -> None:
    model.node_norm.set_stats(np.array(stats["node_mean"]), np.array(stats["node_std"]))
    model.edge_norm.set_stats(np.array(stats["edge_mean"]), np.array(stats["edge_std"]))


def batch_graphs(graphs: list[dict[str, np.ndarray]]) -> dict[str, torch.Tensor]:
    """Concatenate graphs into one disconnected graph (indices offset); ``target`` kept."""
    offset = 0
    parts: dict[str, list[np.ndarray]] = {k: [] for k in (*INPUT_NAMES, "target")}
    for graph in graphs:
        parts["node_features"].append(graph["node_features"])
        parts["edge_features"].append(graph["edge_features"])
        parts["senders"].append(graph["senders"].astype(np.int64) + offset)
        parts["receivers"].append(graph["receivers"].astype(np.int64) + offset)
        parts["target"].append(graph["target"].astype(np.int64))
        offset += len(graph["node_features"])
    out = to_tensors({k: np.concatenate(v) for k, v in parts.items() if k != "target"})
    out["target"] = torch.from_numpy(np.concatenate(parts["target"]))
    return out


def example_inputs(nodes: int, edges: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Random inputs of the right shapes and dtypes (tracing and checks)."""
    rng = np.random.default_rng(seed)
    return {
        "node_features": (rng.random((nodes, len(INPUT_NODE_FEATURES))) + 0.5).astype(np.float32),
        "edge_features": rng.normal(size=(edges, len(INPUT_EDGE_FEATURES))).astype(np.float32),
        "senders": rng.integers(0, nodes, edges).astype(np.int64),
        "receivers": rng.integers(0, nodes, edges).astype(np.int64),
    }


def export_onnx(model: LabelNetwork, path: Path, metadata: dict[str, Any]) -> None:
    """Write ``model`` as ONNX (dynamic node and edge counts), ``metadata`` (JSON values)
    in its ``metadata_props``, with the format, versions and input names."""
    import onnx

    export_graph_network(model, to_tensors(example_inputs(64, 400)), path, OUTPUT_NAMES[0], OPSET)
    proto = onnx.load(str(path))
    props = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "feature_version": FEATURE_VERSION,
        "graph_feature_spec_version": FEATURE_SPEC_VERSION,
        "graph_spec": GRAPH_SPEC.to_dict(),
        "node_features": list(INPUT_NODE_FEATURES),
        "edge_features": list(INPUT_EDGE_FEATURES),
        **metadata,
    }
    for key, value in props.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, json.dumps(value)
    onnx.checker.check_model(proto)
    onnx.save(proto, str(path))


def read_metadata(session: Any) -> dict[str, Any]:
    """The JSON metadata of an exported labelling network (an onnxruntime session)."""
    raw = session.get_modelmeta().custom_metadata_map
    metadata = {key: json.loads(value) for key, value in raw.items()}
    if metadata.get("format") != FORMAT:
        raise ValueError(f"not an EMD labelling network (format {metadata.get('format')!r})")
    return metadata


def max_difference(model: LabelNetwork, path: Path, inputs: dict[str, np.ndarray]) -> float:
    """Largest |onnxruntime - PyTorch| difference of the log probabilities on ``inputs``."""
    import onnxruntime

    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (onnx_out,) = session.run(None, {k: inputs[k] for k in INPUT_NAMES})
    with torch.no_grad():
        tensors = to_tensors(inputs)
        torch_out = model(*(tensors[name] for name in INPUT_NAMES)).numpy()
    return float(np.abs(onnx_out - torch_out).max())
