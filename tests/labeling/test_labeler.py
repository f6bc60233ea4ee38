"""Training and labelling end to end on generated dumbbells (balls and neck)."""

from __future__ import annotations

import numpy as np
import pytest

from neural_shdf.errors import ParameterError
from neural_shdf.labeling import label_mesh, load_labeler, save_labeler, train_labeler
from neural_shdf.mesh import TriangleMesh
from tests.labeling.helpers import BALL, NECK, labelled_dumbbell


@pytest.fixture(scope="module")
def trained():
    examples = [
        labelled_dumbbell(1500, stretch, seed)
        for stretch, seed in ((1.0, None), (1.3, 1), (0.8, 2))
    ]
    meshes, labels = zip(*examples, strict=True)
    return train_labeler(meshes, labels, ["neck", "ball"])


def accuracy(predicted: np.ndarray, truth: np.ndarray) -> float:
    return float(np.mean(predicted == truth))


def test_a_new_dumbbell_is_labelled_with_the_training_integers(trained) -> None:
    assert trained.label_values.tolist() == [NECK, BALL]
    assert trained.label_names == ("neck", "ball")
    # The first of every AUGMENT_EVERY meshes is also learned subdivided x16.
    assert trained.metadata["training"]["meshes"] == 3
    assert trained.metadata["training"]["subdivided_copies"] == 1
    mesh, truth = labelled_dumbbell(1500, 1.15, seed=7)
    labels, confidence = label_mesh(mesh, trained)
    assert labels.shape == truth.shape and set(np.unique(labels)) <= {NECK, BALL}
    assert accuracy(labels, truth) > 0.9
    assert confidence.shape == truth.shape and np.all((confidence >= 0) & (confidence <= 1))


def test_subdivided_and_moved_meshes_get_the_same_labels(trained) -> None:
    mesh, truth = labelled_dumbbell(1500, 1.15)
    fine, fine_truth = labelled_dumbbell(6000, 1.15, seed=11)
    coarse_labels, _ = label_mesh(mesh, trained)
    fine_labels, _ = label_mesh(TriangleMesh(fine.vertices * 40.0, fine.faces), trained)
    assert abs(accuracy(coarse_labels, truth) - accuracy(fine_labels, fine_truth)) < 0.03


def test_labels_follow_the_input_faces_of_polygons(trained) -> None:
    mesh, truth = labelled_dumbbell(1500, 1.1)
    # Reverse the triangles' order: the labels must follow each input face.
    order = np.arange(mesh.face_count)[::-1]
    reversed_mesh = TriangleMesh(mesh.vertices, mesh.faces[order])
    labels, _ = label_mesh(mesh, trained)
    reversed_labels, _ = label_mesh(reversed_mesh, trained)
    assert accuracy(reversed_labels, truth[order]) > 0.9
    assert accuracy(reversed_labels[::-1], labels) > 0.95


def test_a_saved_labeler_labels_alike(trained, tmp_path) -> None:
    mesh, _ = labelled_dumbbell(1500, 1.2, seed=5)
    loaded = load_labeler(save_labeler(trained, tmp_path / "dumbbell.npz"))
    np.testing.assert_array_equal(label_mesh(mesh, loaded)[0], label_mesh(mesh, trained)[0])


def test_training_input_errors_say_what_is_wrong() -> None:
    mesh, truth = labelled_dumbbell(1500)
    with pytest.raises(ParameterError, match="one integer label per face"):
        train_labeler([mesh], [truth[:-1]])
    with pytest.raises(ParameterError, match="one label only"):
        train_labeler([mesh], [np.full_like(truth, 3)])
    with pytest.raises(ParameterError, match="3 label names for 2 distinct labels"):
        train_labeler([mesh], [truth], ["a", "b", "c"])


def test_the_docs_example_runs_as_written(tmp_path, monkeypatch) -> None:
    """docs/labeling.md's library example, on labelled dumbbells and a new one as new.obj."""
    import trimesh

    from tests.doc_examples import python_blocks

    (block,) = python_blocks("docs/labeling.md", "Use")
    pairs = [labelled_dumbbell(1500, stretch, seed) for stretch, seed in ((1.0, 1), (1.3, 2))]
    new_mesh, new_labels = labelled_dumbbell(1500, 1.1, 3)
    trimesh.Trimesh(new_mesh.vertices, new_mesh.faces, process=False).export(tmp_path / "new.obj")
    monkeypatch.chdir(tmp_path)
    namespace = {
        "meshes": [mesh for mesh, _ in pairs],
        "labels": [labels for _, labels in pairs],
        "names": ["neck", "ball"],
    }
    exec(block, namespace)  # noqa: S102
    assert (tmp_path / "human.npz").is_file()
    assert np.mean(namespace["labels"] == new_labels) > 0.9
    assert namespace["confidence"].shape == new_labels.shape
