"""The labeller's classifier: gradient-boosted trees, trained by scikit-learn, stored as arrays.

Training uses ``HistGradientBoostingClassifier`` (deterministic for a fixed
``random_state``); its trees are then copied into plain arrays (``TreeEnsemble``) that a
compiled kernel evaluates. A labeller file therefore holds numbers and JSON only: it is
read with ``numpy.load(allow_pickle=False)`` and never executes code, so loading a file
from an untrusted source cannot run anything (it can only label badly).

File format (``FORMAT``, version ``FORMAT_VERSION``): one ``.npz`` (zip) with the tree
arrays and ``metadata`` (UTF-8 JSON as bytes: format, versions, label values and names,
feature names, sampling spec, smoothing, training summary, and the SHA-256 of the arrays).
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.errors import ParameterError

FORMAT = "neural-shdf-labeler"
FORMAT_VERSION = 1
#: A labeller file larger than this is refused before it is read.
MAX_FILE_BYTES = 256 * 1024 * 1024
#: Tree arrays of a labeller file, in the order their checksum covers them.
TREE_ARRAYS = (
    "feature",
    "threshold",
    "missing_left",
    "left",
    "right",
    "value",
    "tree_start",
    "tree_class",
    "baseline",
)


class LabelerFileError(ParameterError):
    """A labeller file that is not one, is damaged, or was written by another version."""


@dataclass(frozen=True)
class TreeEnsemble:
    """Boosted trees as arrays: node ``i`` of every tree, trees concatenated.

    Internal node: go to ``left[i]`` when ``x[feature[i]] <= threshold[i]`` (NaN: when
    ``missing_left[i]``), else ``right[i]`` (indices within the tree). Leaf: ``feature[i]
    == -1`` and ``value[i]`` is added to the raw score of class ``tree_class[t]``.
    Probabilities: softmax of ``baseline + scores`` (one class: sigmoid, two columns).
    """

    feature: NDArray[np.int64]
    threshold: NDArray[np.float64]
    missing_left: NDArray[np.uint8]
    left: NDArray[np.int64]
    right: NDArray[np.int64]
    value: NDArray[np.float64]
    tree_start: NDArray[np.int64]
    tree_class: NDArray[np.int64]
    baseline: NDArray[np.float64]

    @property
    def score_count(self) -> int:
        return int(len(self.baseline))

    def arrays(self) -> dict[str, NDArray]:
        return {name: getattr(self, name) for name in TREE_ARRAYS}

    def predict_proba(self, features: NDArray, classes: int) -> NDArray[np.float64]:
        """(N, classes) class probabilities of each row of ``features``."""
        scores = np.empty((len(features), self.score_count))
        _tree_scores(
            np.ascontiguousarray(features, dtype=np.float64),
            self.feature,
            self.threshold,
            self.missing_left,
            self.left,
            self.right,
            self.value,
            self.tree_start,
            self.tree_class,
            self.baseline,
            scores,
        )
        if classes == 2 and self.score_count == 1:
            positive = 1.0 / (1.0 + np.exp(-scores[:, 0]))
            return np.stack([1.0 - positive, positive], axis=1)
        scores -= scores.max(axis=1, keepdims=True)
        np.exp(scores, out=scores)
        scores /= scores.sum(axis=1, keepdims=True)
        return scores

    @classmethod
    def from_sklearn(cls, model: object) -> TreeEnsemble:
        """The trees of a fitted ``HistGradientBoostingClassifier`` (numeric features only)."""
        starts, parts, classes = [0], [], []
        for iteration in model._predictors:  # type: ignore[attr-defined]
            for score, predictor in enumerate(iteration):
                nodes = predictor.nodes
                if np.any(nodes["is_categorical"]):
                    raise ParameterError("categorical features are not supported")
                parts.append(nodes)
                classes.append(score)
                starts.append(starts[-1] + len(nodes))
        nodes = np.concatenate(parts)
        leaf = nodes["is_leaf"].astype(bool)
        return cls(
            feature=np.where(leaf, -1, nodes["feature_idx"]).astype(np.int64),
            threshold=nodes["num_threshold"].astype(np.float64),
            missing_left=nodes["missing_go_to_left"].astype(np.uint8),
            left=nodes["left"].astype(np.int64),
            right=nodes["right"].astype(np.int64),
            value=nodes["value"].astype(np.float64),
            tree_start=np.asarray(starts, dtype=np.int64),
            tree_class=np.asarray(classes, dtype=np.int64),
            baseline=np.asarray(model._baseline_prediction, dtype=np.float64).reshape(-1),  # type: ignore[attr-defined]
        )


@kernel
def _tree_scores(
    x, feature, threshold, missing_left, left, right, value, tree_start, tree_class, baseline, out
):  # noqa: ANN001, E501  # pragma: no cover - compiled
    for row in range(x.shape[0]):
        for k in range(len(baseline)):
            out[row, k] = baseline[k]
        for tree in range(len(tree_class)):
            base = tree_start[tree]
            node = base
            while feature[node] >= 0:
                v = x[row, feature[node]]
                go_left = missing_left[node] != 0 if np.isnan(v) else v <= threshold[node]
                node = base + (left[node] if go_left else right[node])
            out[row, tree_class[tree]] += value[node]


@dataclass(frozen=True)
class Labeler:
    """A trained part labeller: trees, what their classes mean, and how features are made.

    ``label_values``: the training labels' own integers, one per class (class i is
    ``label_values[i]``); ``label_names``: a name per class. ``metadata``: the rest of
    the model card (feature names and version, sampling spec, smoothing, training summary).
    """

    trees: TreeEnsemble
    label_values: NDArray[np.int64]
    label_names: tuple[str, ...]
    metadata: dict = field(default_factory=dict)

    @property
    def class_count(self) -> int:
        return int(len(self.label_values))

    def predict_proba(self, features: NDArray) -> NDArray[np.float64]:
        """(N, classes) probabilities of the classes for feature rows."""
        return self.trees.predict_proba(features, self.class_count)


def _checksum(arrays: dict[str, NDArray]) -> str:
    digest = hashlib.sha256(FORMAT.encode())
    for name in TREE_ARRAYS + ("label_values",):
        array = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}:{array.dtype.str}:{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def save_labeler(labeler: Labeler, path: str | Path) -> Path:
    """Write ``labeler`` as one ``.npz`` file (see the module doc); returns the path."""
    path = Path(path)
    path.write_bytes(labeler_bytes(labeler))
    return path


def labeler_bytes(labeler: Labeler) -> bytes:
    """The bytes of ``labeler``'s file (what ``save_labeler`` writes)."""
    arrays = labeler.trees.arrays() | {"label_values": labeler.label_values.astype(np.int64)}
    metadata = dict(labeler.metadata) | {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "label_names": list(labeler.label_names),
        "label_values": [int(v) for v in labeler.label_values],
        "sha256": _checksum(arrays),
    }
    buffer = io.BytesIO()
    np.savez_compressed(
        buffer, metadata=np.frombuffer(json.dumps(metadata).encode(), dtype=np.uint8), **arrays
    )
    return buffer.getvalue()


def load_labeler(source: str | Path | bytes) -> Labeler:
    """Read a labeller file (path or bytes); ``LabelerFileError`` for anything wrong with it.

    Never executes code from the file (no pickle); checks the format, its version and the
    checksum of the trees before use.
    """
    data = source if isinstance(source, bytes) else Path(source).read_bytes()
    if len(data) > MAX_FILE_BYTES:
        raise LabelerFileError(f"labeller file is {len(data)} bytes, more than {MAX_FILE_BYTES}")
    _check_unpacked_size(data)
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as error:
        raise LabelerFileError(f"not a labeller file (.npz): {error}") from error
    missing = [name for name in (*TREE_ARRAYS, "label_values", "metadata") if name not in arrays]
    if missing:
        raise LabelerFileError(f"not a labeller file: missing {', '.join(missing)}")
    try:
        metadata = json.loads(arrays.pop("metadata").tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise LabelerFileError(f"labeller metadata is not JSON: {error}") from error
    if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
        raise LabelerFileError("not a neural-shdf labeller file")
    if metadata.get("format_version") != FORMAT_VERSION:
        raise LabelerFileError(
            f"labeller format version {metadata.get('format_version')} is not supported "
            f"(this version reads {FORMAT_VERSION}); train it again"
        )
    if metadata.get("sha256") != _checksum(arrays):
        raise LabelerFileError("labeller file is damaged: its checksum does not match")
    trees = TreeEnsemble(
        **{name: arrays[name].astype(_DTYPES[name], copy=False) for name in TREE_ARRAYS}
    )
    _check_trees(trees, len(metadata.get("feature_names", ())))
    label_values = arrays["label_values"].astype(np.int64)
    names = metadata.get("label_names", [])
    if len(names) != len(label_values) or not all(isinstance(n, str) for n in names):
        raise LabelerFileError("labeller file: label names do not match its labels")
    return Labeler(trees, label_values, tuple(names), metadata)


def _check_unpacked_size(data: bytes) -> None:
    """Refuse a zip whose members would unpack to more than ``MAX_FILE_BYTES`` (a small
    upload must not become gigabytes in memory), from its directory, before reading them."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            unpacked = sum(member.file_size for member in archive.infolist())
    except (zipfile.BadZipFile, ValueError, EOFError) as error:
        raise LabelerFileError(f"not a labeller file (.npz): {error}") from error
    if unpacked > MAX_FILE_BYTES:
        raise LabelerFileError(
            f"labeller file unpacks to {unpacked} bytes, more than {MAX_FILE_BYTES}"
        )


def labeler_id(labeler: Labeler) -> str:
    """Content id of a labeller (64 hex digits): the hash of what it labels with (trees,
    labels, names, features, smoothing), not of its training statistics or file bytes, so
    the same labeller saved twice has one id."""
    arrays = labeler.trees.arrays() | {"label_values": labeler.label_values.astype(np.int64)}
    # What save_labeler adds (format, names, values, checksum) is taken from the labeller.
    added = ("training", "sha256", "format", "format_version", "label_names", "label_values")
    described = {k: v for k, v in labeler.metadata.items() if k not in added}
    described |= {"label_names": list(labeler.label_names), "trees": _checksum(arrays)}
    text = json.dumps(described, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


_DTYPES = {
    "feature": np.int64,
    "threshold": np.float64,
    "missing_left": np.uint8,
    "left": np.int64,
    "right": np.int64,
    "value": np.float64,
    "tree_start": np.int64,
    "tree_class": np.int64,
    "baseline": np.float64,
}


def _check_trees(trees: TreeEnsemble, feature_count: int) -> None:
    """Refuse trees whose indices would leave their arrays (the kernel does not check)."""
    node_count = len(trees.feature)
    sizes = {
        len(getattr(trees, n)) for n in ("threshold", "missing_left", "left", "right", "value")
    }
    start = trees.tree_start
    ok = (
        sizes == {node_count}
        and len(start) == len(trees.tree_class) + 1
        and len(start) > 1
        and start[0] == 0
        and start[-1] == node_count
        and np.all(np.diff(start) > 0)
        and np.all((trees.tree_class >= 0) & (trees.tree_class < len(trees.baseline)))
        and np.all(trees.feature < feature_count)
    )
    if ok:
        size = np.repeat(np.diff(start), np.diff(start))
        inner = trees.feature >= 0
        local = np.arange(node_count) - np.repeat(start[:-1], np.diff(start))
        # Children lie after their parent within the tree: every walk ends at a leaf.
        ok = bool(
            np.all(trees.left[inner] > local[inner])
            and np.all(trees.right[inner] > local[inner])
            and np.all(trees.left[inner] < size[inner])
            and np.all(trees.right[inner] < size[inner])
        )
    if not ok:
        raise LabelerFileError("labeller file is damaged: its trees are inconsistent")
