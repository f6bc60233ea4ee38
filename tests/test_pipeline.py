"""The library's front door: warm-up of the compiled paths."""

import pytest

from neural_shdf import geometry, pipeline
from neural_shdf.shdf import exact
from neural_shdf.shdf.neural import inference


def test_warm_up_compiles_every_kernel_it_reaches():
    seconds = pipeline.warm_up()
    assert seconds > 0
    assert exact._shdf_of_faces.signatures
    compiled = [
        getattr(geometry, name)
        for name in dir(geometry)
        if hasattr(getattr(geometry, name), "signatures")
    ]
    called = [k for k in compiled if k.targetoptions.get("inline") != "always"]  # not inlined
    assert called and all(kernel.signatures for kernel in called)


def test_warm_up_skips_a_missing_model(monkeypatch, tmp_path):
    monkeypatch.setenv(inference.MODEL_ENV_VAR, str(tmp_path / "absent.onnx"))
    assert pipeline.warm_up() > 0
    with pytest.raises(Exception, match="not found"):
        inference.load_model()
