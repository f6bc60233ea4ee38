"""onnxruntime inference of the committed neural ShDF model (no torch needed)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import ModelUnavailableError, ParameterError
from neural_shdf.mesh import TriangleMesh
from neural_shdf.pipeline import compute_shdf
from neural_shdf.shdf.neural.inference import DEFAULT_MODEL_PATH, load_model, neural_raw_shdf


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


def two_shells() -> tuple[TriangleMesh, np.ndarray]:
    """A sphere of radius 1 and, beside it, a capsule of radius 0.1; True on capsule faces."""
    sphere = trimesh.creation.icosphere(subdivisions=4)
    capsule = trimesh.creation.capsule(height=2.0, radius=0.1, count=[32, 32])
    capsule.apply_translation([2.5, 0.0, 0.0])
    both = trimesh.util.concatenate([sphere, capsule])
    thin = np.arange(len(both.faces)) >= len(sphere.faces)
    return TriangleMesh(np.asarray(both.vertices), np.asarray(both.faces)), thin


@pytest.fixture(scope="module")
def committed_model():
    if not DEFAULT_MODEL_PATH.exists():
        pytest.skip("no committed model")
    return load_model()


def test_committed_model_tells_thin_from_thick(committed_model) -> None:
    mesh, thin = two_shells()
    values = compute_shdf(mesh, method="neural", seed=0).values
    assert values.shape == (mesh.face_count,)
    assert np.all((values >= 0) & (values <= 1))
    assert np.median(values[thin]) < 0.5 * np.median(values[~thin])
    raw = neural_raw_shdf(mesh.vertices, mesh.faces, model=committed_model)
    # Diameters in mesh units: sphere about 2 x 0.85 (cone average), capsule about 0.2.
    assert 1.0 < np.median(raw[~thin]) < 2.4
    assert 0.08 < np.median(raw[thin]) < 0.35


def test_more_sample_sets_lower_the_sampling_noise(committed_model) -> None:
    mesh, _ = two_shells()

    def noise(sets: int) -> float:
        a, b = (
            neural_raw_shdf(mesh.vertices, mesh.faces, seed=s, sample_sets=sets) for s in (0, 1)
        )
        return float(np.mean(np.abs(np.log(a / b))))

    one, three = noise(1), noise(3)
    assert three < 0.8 * one
    again = neural_raw_shdf(mesh.vertices, mesh.faces, seed=0, sample_sets=3)
    np.testing.assert_array_equal(again, neural_raw_shdf(mesh.vertices, mesh.faces, sample_sets=3))
    with pytest.raises(ParameterError, match="sample_sets"):
        neural_raw_shdf(mesh.vertices, mesh.faces, sample_sets=0)


def test_committed_model_known_values(committed_model) -> None:
    """Stored outputs of the committed model on a fixed mesh and seed (update on re-export)."""
    mesh, _ = two_shells()
    raw = neural_raw_shdf(mesh.vertices, mesh.faces, seed=0, sample_sets=1, model=committed_model)
    faces = [0, 1000, 4000, 5119, 5120, 6000, 7000]
    np.testing.assert_allclose(raw[faces], EXPECTED_RAW, rtol=1e-4)
    again = compute_shdf(mesh, method="neural", seed=0).values
    np.testing.assert_allclose(again, compute_shdf(mesh, method="neural", seed=0).values)


EXPECTED_RAW = [1.53103, 1.54412, 1.54088, 1.53564, 0.166036, 0.160966, 0.179628]


RAY_MODEL_PATH = DEFAULT_MODEL_PATH.with_name("emd-rays.onnx")


def test_ray_informed_model_reads_the_cone_of_every_sample() -> None:
    if not RAY_MODEL_PATH.exists():
        pytest.skip("no committed ray-informed model")
    from neural_shdf.shdf.neural.graph import RAY_NODE_FEATURES, build_sample_graph

    model = load_model(RAY_MODEL_PATH)
    assert model.spec.ray_count > 0
    assert model.card["node_features"][-len(RAY_NODE_FEATURES) :] == list(RAY_NODE_FEATURES)
    mesh, thin = two_shells()
    graph = build_sample_graph(mesh.vertices, mesh.faces, model.spec)
    assert graph.node_features.shape[1] == len(model.spec.node_features)
    has_hit = graph.node_features[:, -len(RAY_NODE_FEATURES)]
    assert has_hit.mean() > 0.95
    values = compute_shdf(mesh, method="neural", model=RAY_MODEL_PATH).values
    assert np.median(values[thin]) < 0.5 * np.median(values[~thin])
