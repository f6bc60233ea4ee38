"""ONNX export of the EMD network: onnxruntime matches PyTorch; training runs end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from model_export import data, export, train  # noqa: E402
from model_export.core_model import scatter_sum  # noqa: E402
from model_export.shdf_task import INPUT_NAMES, ShdfNetwork, to_tensors  # noqa: E402
from neural_shdf.shdf.neural.graph import NODE_FEATURES  # noqa: E402
from neural_shdf.shdf.neural.inference import load_model, neural_raw_shdf  # noqa: E402


def random_model(seed: int = 0) -> ShdfNetwork:
    torch.manual_seed(seed)
    model = ShdfNetwork(latent=32, steps=3)
    model.node_norm.set_stats(np.full(len(NODE_FEATURES), 0.5), np.full(len(NODE_FEATURES), 2.0))
    model.target_norm.set_stats(np.array([1.5]), np.array([0.7]))
    return model.eval()


def test_scatter_sum_adds_repeated_indices() -> None:
    values = torch.tensor([[1.0], [2.0], [4.0]])
    index = torch.tensor([2, 0, 2])
    out = scatter_sum(values, index, torch.zeros(3, 1))
    assert out[:, 0].tolist() == [2.0, 0.0, 5.0]


def test_onnxruntime_matches_pytorch_with_dynamic_sizes(tmp_path) -> None:
    model = random_model()
    path = tmp_path / "emd.onnx"
    export.export_onnx(model, path)
    for nodes, edges in ((10, 30), (300, 5000)):
        inputs = export.example_inputs(nodes, edges, seed=nodes)
        assert export.max_difference(model, path, inputs) <= 1e-4


def test_network_is_permutation_equivariant() -> None:
    model = random_model(1)
    inputs = to_tensors(export.example_inputs(40, 200, seed=3))
    perm = torch.randperm(40, generator=torch.Generator().manual_seed(0))
    inverse = torch.argsort(perm)
    permuted = dict(inputs)
    permuted["node_features"] = inputs["node_features"][perm]
    permuted["senders"] = inverse[inputs["senders"]]
    permuted["receivers"] = inverse[inputs["receivers"]]
    with torch.no_grad():
        out = model(*(inputs[k] for k in INPUT_NAMES))
        out_permuted = model(*(permuted[k] for k in INPUT_NAMES))
    torch.testing.assert_close(out_permuted, out[perm], atol=1e-5, rtol=1e-5)


def test_data_train_export_end_to_end(tmp_path, monkeypatch) -> None:
    """A procedural shape -> graphs -> a few training steps -> ONNX the service can run."""
    cache = tmp_path / "cache"
    monkeypatch.setattr(data, "is_validation", lambda name: name.endswith("1"))
    for index in (0, 1):
        written = data.process_shape(f"procedural/{index:04d}", index, cache, lambda m: None)
        assert written >= 3
    train.main(
        [
            "--cache",
            str(cache),
            "--max-steps",
            "4",
            "--val-every",
            "2",
            "--latent",
            "16",
            "--message-steps",
            "2",
        ]
    )
    log = (cache / "run" / "train.log").read_text()
    assert '"final": true' in log
    out = tmp_path / "emd.onnx"
    export.main(["--checkpoint", str(cache / "run" / "last.pt"), "--out", str(out)])
    card = json.loads(out.with_suffix(".json").read_text())
    assert card["training"]["steps"] == 4
    model = load_model(out)
    mesh = data.procedural_mesh(0)
    raw = neural_raw_shdf(np.asarray(mesh.vertices), np.asarray(mesh.faces), model=model)
    assert raw.shape == (len(mesh.faces),)
    assert np.all(np.isfinite(raw)) and np.all(raw > 0)


def test_edge_subset_equals_building_with_fewer_edges() -> None:
    """Training keeps fewer edges of the cached graphs; serving builds them directly."""
    import trimesh

    from model_export.shdf_task import graph_arrays
    from neural_shdf.shdf.neural.graph import GraphSpec, build_sample_graph

    mesh = trimesh.creation.capsule(height=2.0, radius=0.3, count=[24, 24])
    full = build_sample_graph(mesh.vertices, mesh.faces, GraphSpec(target_samples=300), seed=3)
    small = build_sample_graph(
        mesh.vertices, mesh.faces, GraphSpec(target_samples=300, knn=5, cone_neighbours=2), seed=3
    )
    subset = train.subset_edges(graph_arrays(full), 5, 2)
    for key, value in graph_arrays(small).items():
        np.testing.assert_array_equal(subset[key], value)
