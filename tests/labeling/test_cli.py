"""``neural-shdf labeler train`` and ``neural-shdf segment --labeler``: generated meshes,
a few human-seg meshes (skipped when the shared data is absent)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from neural_shdf.cli import main
from neural_shdf.exchange.seg import read_labels, read_values
from neural_shdf.labeling import load_labeler
from tests.labeling.helpers import BALL, NECK, labelled_dumbbell


def write_example(folder: Path, labels_folder: Path, name: str, stretch: float, seed) -> np.ndarray:
    mesh, labels = labelled_dumbbell(1500, stretch, seed)
    trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(folder / f"{name}.obj")
    (labels_folder / f"{name}.txt").write_text("".join(f"{v}\n" for v in labels))
    return labels


@pytest.fixture(scope="module")
def dumbbell_labeler(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("train")
    meshes, labels = root / "meshes", root / "labels"
    meshes.mkdir()
    labels.mkdir()
    for name, stretch, seed in (("a", 1.0, None), ("b", 1.3, 1), ("c", 0.8, 2)):
        write_example(meshes, labels, name, stretch, seed)
    (meshes / "unlabelled.obj").write_text((meshes / "a.obj").read_text())
    output = root / "dumbbell.npz"
    code = main(
        [
            "labeler",
            "train",
            str(meshes),
            str(labels),
            "-o",
            str(output),
            "--names",
            "neck,ball",
            "-q",
        ]
    )
    assert code == 0
    return output


def test_train_writes_a_labeller_with_the_given_names(dumbbell_labeler: Path) -> None:
    labeler = load_labeler(dumbbell_labeler)
    assert labeler.label_names == ("neck", "ball")
    assert labeler.label_values.tolist() == [NECK, BALL]
    assert labeler.metadata["training"]["meshes"] == 3


def test_segment_with_a_labeller_writes_one_training_label_per_face(
    dumbbell_labeler, tmp_path
) -> None:
    truth = write_example(tmp_path, tmp_path, "new", 1.15, 9)
    output, confidence = tmp_path / "new.seg", tmp_path / "new.conf"
    code = main(
        [
            "segment",
            str(tmp_path / "new.obj"),
            "--labeler",
            str(dumbbell_labeler),
            "-o",
            str(output),
            "--confidence",
            str(confidence),
            "-q",
        ]
    )
    assert code == 0
    labels = read_labels(output)
    assert len(labels) == len(truth) and set(np.unique(labels)) <= {NECK, BALL}
    assert np.mean(labels == truth) > 0.9
    assert len(read_values(confidence)) == len(truth)


def test_cli_errors_name_the_problem(dumbbell_labeler, tmp_path, capsys) -> None:
    meshes, labels = tmp_path / "m", tmp_path / "l"
    meshes.mkdir()
    labels.mkdir()
    write_example(meshes, labels, "short", 1.0, None)
    (labels / "short.txt").write_text("2\n5\n")
    assert main(["labeler", "train", str(meshes), str(labels), "-o", str(tmp_path / "x.npz")]) == 2
    assert "has 2 labels but short.obj has" in capsys.readouterr().err
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"PK\x03\x04 not really")
    code = main(
        [
            "segment",
            str(meshes / "short.obj"),
            "--labeler",
            str(broken),
            "-o",
            str(tmp_path / "o.seg"),
        ]
    )
    assert code == 2 and "not a labeller file" in capsys.readouterr().err
    # The labeller is checked before any work on the mesh (here: before it is even read).
    code = main(["segment", str(tmp_path / "absent.obj"), "--labeler", str(broken), "-o", "o.seg"])
    assert code == 2 and "not a labeller file" in capsys.readouterr().err
    code = main(
        [
            "segment",
            str(meshes / "short.obj"),
            "--labeler",
            str(dumbbell_labeler),
            "--tree",
            str(tmp_path / "t.json"),
            "-o",
            str(tmp_path / "o.seg"),
        ]
    )
    assert code == 2 and "--tree cannot be combined with --labeler" in capsys.readouterr().err


def test_human_seg_meshes_through_the_cli(shared_data: Path, tmp_path: Path) -> None:
    source = shared_data / "human-seg"
    if not (source / "train").is_dir():
        pytest.skip("human-seg is absent")
    paths = sorted((source / "train").glob("*.obj"))
    meshes, labels = tmp_path / "meshes", tmp_path / "labels"
    meshes.mkdir()
    labels.mkdir()
    for path in paths[1:80:8]:  # 10 meshes of different families
        (meshes / path.name).symlink_to(path)
        (labels / f"{path.stem}.txt").symlink_to(source / "face_labels" / f"{path.stem}.txt")
    names = "head,hands,forearms,upper arms,torso,thighs,lower legs,feet"
    output = tmp_path / "human.npz"
    assert (
        main(
            [
                "labeler",
                "train",
                str(meshes),
                str(labels),
                "-o",
                str(output),
                "--names",
                names,
                "-q",
            ]
        )
        == 0
    )
    test = paths[200]
    seg = tmp_path / "test.seg"
    assert main(["segment", str(test), "--labeler", str(output), "-o", str(seg), "-q"]) == 0
    truth = np.loadtxt(source / "face_labels" / f"{test.stem}.txt", dtype=np.int64)
    predicted = read_labels(seg)
    assert len(predicted) == len(truth)
    assert np.mean(predicted == truth) > 0.7
