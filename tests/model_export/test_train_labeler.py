"""The EMD labelling network: its inputs, a short training run, its ONNX export."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from model_export import labeling_task, train_labeler  # noqa: E402
from model_export.labeling_data import (  # noqa: E402
    INPUT_NODE_FEATURES,
    EmdLabeler,
    network_inputs,
)
from neural_shdf.labeling.labeler import describe_mesh  # noqa: E402
from neural_shdf.shdf.neural.graph import NODE_FEATURES  # noqa: E402
from tests.labeling.helpers import BALL, NECK, labelled_dumbbell, obj_of  # noqa: E402


def test_inputs_are_the_graph_and_the_labellers_features_of_its_samples() -> None:
    mesh, _ = labelled_dumbbell(1500)
    moved, _ = labelled_dumbbell(1500, seed=4)
    description = describe_mesh(mesh)
    inputs = network_inputs(description)
    again = network_inputs(describe_mesh(moved))
    graph_columns = len(NODE_FEATURES)
    assert inputs["node_features"].shape[1] == len(INPUT_NODE_FEATURES)
    assert len(inputs["senders"]) == len(inputs["edge_features"]) > 0
    np.testing.assert_array_equal(
        inputs["node_features"][:, graph_columns:],
        description.features[description.nodes.samples_node],
    )
    # The sample graph ignores the pose (same samples, same invariant features).
    np.testing.assert_allclose(
        inputs["node_features"][:, :graph_columns],
        again["node_features"][:, :graph_columns],
        atol=1e-3,
    )
    np.testing.assert_allclose(inputs["edge_features"], again["edge_features"], atol=1e-3)
    np.testing.assert_array_equal(inputs["senders"], again["senders"])


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A tiny network trained for 60 steps on four dumbbells (a fifth is held out)."""
    root = tmp_path_factory.mktemp("human-seg")
    (root / "train").mkdir()
    (root / "face_labels").mkdir()
    for index, (stretch, seed) in enumerate(((1.0, 9), (1.0, None), (1.3, 1), (0.8, 2), (1.15, 3))):
        mesh, labels = labelled_dumbbell(1500, stretch, seed)
        (root / "train" / f"m{index}.obj").write_bytes(obj_of(mesh))
        np.savetxt(root / "face_labels" / f"m{index}.txt", labels, fmt="%d")
    cache = tmp_path_factory.mktemp("cache")
    code = train_labeler.main(
        [
            "--data-dir",
            str(root),
            "--cache",
            str(cache),
            "--max-steps",
            "60",
            "--latent",
            "16",
            "--message-steps",
            "2",
            "--no-augment",
        ]
    )
    assert code == 0
    return cache / "emd"


def test_training_runs_and_onnxruntime_matches_pytorch(trained) -> None:
    checkpoint = torch.load(trained / "last.pt", weights_only=False)
    assert checkpoint["state"]["step"] == 60
    model = labeling_task.LabelNetwork(2, latent=16, steps=2)
    model.load_state_dict(checkpoint["model"])
    mesh, _ = labelled_dumbbell(3000, 1.1, seed=7)
    inputs = network_inputs(describe_mesh(mesh))
    assert labeling_task.max_difference(model.eval(), trained / "labeler.onnx", inputs) <= 1e-4


def test_the_exported_network_labels_a_new_dumbbell(trained) -> None:
    network = EmdLabeler(trained / "labeler.onnx")
    assert network.metadata["label_values"] == [NECK, BALL]
    assert network.metadata["training"]["meshes"] == 4
    mesh, truth = labelled_dumbbell(3000, 1.1, seed=7)
    description = describe_mesh(mesh)
    classes, confidence = network.label_description(description)
    assert classes.shape == confidence.shape == (mesh.face_count,)
    assert np.all((confidence > 0) & (confidence <= 1))
    accuracy = np.mean(network.label_values[classes] == truth[mesh.face_origin])
    assert accuracy > 0.8
