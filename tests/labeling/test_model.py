"""Trees as arrays, and the labeller file: round trip, refusal of damaged or foreign files."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest
from sklearn.ensemble import HistGradientBoostingClassifier

from neural_shdf.labeling.model import (
    Labeler,
    LabelerFileError,
    TreeEnsemble,
    labeler_bytes,
    labeler_id,
    load_labeler,
    save_labeler,
)


def fitted(classes: int, nan: bool = False) -> tuple[HistGradientBoostingClassifier, np.ndarray]:
    rng = np.random.default_rng(classes)
    x = rng.normal(size=(600, 4))
    y = (np.digitize(x[:, 0] + 0.5 * x[:, 1], np.linspace(-1, 1, classes - 1))).astype(int)
    if nan:
        x[::7, 2] = np.nan
    model = HistGradientBoostingClassifier(max_iter=20, random_state=0).fit(x, y)
    return model, rng.normal(size=(200, 4)) if not nan else np.where(
        rng.random((200, 4)) < 0.1, np.nan, rng.normal(size=(200, 4))
    )


@pytest.mark.parametrize(("classes", "nan"), [(2, False), (4, False), (3, True)])
def test_trees_as_arrays_give_sklearns_probabilities(classes: int, nan: bool) -> None:
    model, x = fitted(classes, nan)
    trees = TreeEnsemble.from_sklearn(model)
    np.testing.assert_allclose(trees.predict_proba(x, classes), model.predict_proba(x), atol=1e-9)


def a_labeler() -> Labeler:
    model, _ = fitted(3)
    trees = TreeEnsemble.from_sklearn(model)
    return Labeler(trees, np.array([4, 7, 9]), ("head", "arm", "leg"), {"feature_names": ["a"] * 4})


def test_a_saved_labeler_loads_the_same(tmp_path) -> None:
    labeler = a_labeler()
    path = save_labeler(labeler, tmp_path / "l.npz")
    loaded = load_labeler(path)
    assert loaded.label_names == ("head", "arm", "leg")
    assert loaded.label_values.tolist() == [4, 7, 9]
    x = np.random.default_rng(1).normal(size=(50, 4))
    np.testing.assert_array_equal(loaded.predict_proba(x), labeler.predict_proba(x))
    assert load_labeler(path.read_bytes()).label_names == loaded.label_names


def rewrite(path, change) -> bytes:
    """The file's arrays after ``change(arrays)``, written back as an npz."""
    with np.load(path) as data:
        arrays = {name: data[name] for name in data.files}
    change(arrays)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def test_damaged_foreign_and_newer_files_are_refused(tmp_path) -> None:
    path = save_labeler(a_labeler(), tmp_path / "l.npz")
    with pytest.raises(LabelerFileError, match="not a labeller"):
        load_labeler(b"not a zip at all")

    def flip_threshold(arrays):
        arrays["threshold"] = arrays["threshold"] + 1.0

    with pytest.raises(LabelerFileError, match="checksum"):
        load_labeler(rewrite(path, flip_threshold))

    def newer(arrays):
        metadata = json.loads(arrays["metadata"].tobytes())
        metadata["format_version"] = 99
        arrays["metadata"] = np.frombuffer(json.dumps(metadata).encode(), np.uint8)

    with pytest.raises(LabelerFileError, match="version 99"):
        load_labeler(rewrite(path, newer))

    def drop(arrays):
        del arrays["left"]

    with pytest.raises(LabelerFileError, match="missing left"):
        load_labeler(rewrite(path, drop))


def test_a_pickle_inside_is_never_loaded(tmp_path) -> None:
    path = save_labeler(a_labeler(), tmp_path / "l.npz")

    def objects(arrays):
        arrays["threshold"] = np.array([object()] * len(arrays["threshold"]), dtype=object)

    with pytest.raises(LabelerFileError):
        load_labeler(rewrite(path, objects))


def test_trees_whose_children_leave_the_tree_are_refused(tmp_path) -> None:
    labeler = a_labeler()
    trees = labeler.trees
    left = trees.left.copy()
    left[np.flatnonzero(trees.feature >= 0)[0]] = 10**6
    broken = Labeler(
        TreeEnsemble(**(trees.arrays() | {"left": left})),
        labeler.label_values,
        labeler.label_names,
        labeler.metadata,
    )
    path = save_labeler(broken, tmp_path / "l.npz")
    with pytest.raises(LabelerFileError, match="inconsistent"):
        load_labeler(path)
    assert zipfile.is_zipfile(path)


def test_a_file_that_would_unpack_beyond_the_limit_is_refused_before_reading(monkeypatch):
    import neural_shdf.labeling.model as model

    data = labeler_bytes(a_labeler())
    monkeypatch.setattr(model, "MAX_FILE_BYTES", len(data) + 10)  # the zip fits, its members not
    with pytest.raises(LabelerFileError, match="unpacks to"):
        load_labeler(data)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("metadata.npy", b"\0" * (len(data) + 100))  # compresses to little
    with pytest.raises(LabelerFileError, match="unpacks to"):
        load_labeler(buffer.getvalue())


def test_the_id_names_what_labels_not_the_file_or_training_time(tmp_path) -> None:
    labeler = a_labeler()
    again = load_labeler(save_labeler(labeler, tmp_path / "l.npz"))
    assert labeler_id(again) == labeler_id(labeler)
    assert len(labeler_id(labeler)) == 64
    timed = Labeler(labeler.trees, labeler.label_values, labeler.label_names,
                    labeler.metadata | {"training": {"fit_seconds": 3.0}})  # fmt: skip
    assert labeler_id(timed) == labeler_id(labeler)
    renamed = Labeler(labeler.trees, labeler.label_values, ("a", "b", "c"), labeler.metadata)
    assert labeler_id(renamed) != labeler_id(labeler)
    assert labeler_bytes(labeler) == (tmp_path / "l.npz").read_bytes()
