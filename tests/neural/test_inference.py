"""onnxruntime inference of the committed neural ShDF model (no torch needed)."""

from __future__ import annotations

import json
import shutil

import pytest
from neural_shdf.errors import ModelUnavailableError
from neural_shdf.neural.inference import DEFAULT_MODEL_PATH, load_model


def test_missing_model_raises_a_clear_error(tmp_path) -> None:
    with pytest.raises(ModelUnavailableError, match="not found"):
        load_model(tmp_path / "absent.onnx")


def test_model_with_other_feature_version_is_refused(tmp_path) -> None:
    if not DEFAULT_MODEL_PATH.exists():
        pytest.skip("no committed model")
    copy = tmp_path / "emd.onnx"
    shutil.copy(DEFAULT_MODEL_PATH, copy)
    card = json.loads(DEFAULT_MODEL_PATH.with_suffix(".json").read_text())
    card["feature_spec_version"] = -1
    copy.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(ModelUnavailableError, match="features version"):
        load_model(copy)


def test_tampered_model_is_refused(tmp_path) -> None:
    if not DEFAULT_MODEL_PATH.exists():
        pytest.skip("no committed model")
    copy = tmp_path / "emd.onnx"
    copy.write_bytes(DEFAULT_MODEL_PATH.read_bytes() + b"\0")
    shutil.copy(DEFAULT_MODEL_PATH.with_suffix(".json"), copy.with_suffix(".json"))
    with pytest.raises(ModelUnavailableError, match="checksum"):
        load_model(copy)
