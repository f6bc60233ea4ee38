"""A second, different but valid neural model for tests that must tell models apart."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from neural_shdf.shdf.neural.inference import DEFAULT_MODEL_PATH, file_sha256


def perturbed_model(folder: Path, noise: float = 0.2) -> Path:
    """The committed model with noise added to its weight matrices (its predictions
    change shape, not only scale), saved with a matching model card; its ONNX path."""
    import onnx
    from onnx import numpy_helper

    model = onnx.load(str(DEFAULT_MODEL_PATH))
    rng = np.random.default_rng(0)
    for tensor in model.graph.initializer:
        if len(tensor.dims) == 2 and tensor.data_type == onnx.TensorProto.FLOAT:
            values = numpy_helper.to_array(tensor).astype(np.float32)
            values += rng.normal(0.0, noise * values.std(), values.shape).astype(np.float32)
            tensor.CopyFrom(numpy_helper.from_array(values, tensor.name))
    path = folder / "perturbed.onnx"
    onnx.save(model, str(path))
    card = json.loads(DEFAULT_MODEL_PATH.with_suffix(".json").read_text())
    card["sha256"] = file_sha256(path)
    path.with_suffix(".json").write_text(json.dumps(card))
    return path
