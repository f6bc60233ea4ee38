"""onnxruntime inference of the neural ShDF: mesh -> samples -> network -> raw ShDF per face.

The ONNX model and its model card (``emd.onnx`` + ``emd.json``) live in
``neural_shdf/models``; ``NEURAL_SHDF_MODEL`` (path of an ``.onnx``) overrides
it. A session is created once per model file and reused (intra-op threads 2).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import ModelUnavailableError, ParameterError
from neural_shdf.geometry import face_normals
from neural_shdf.shdf.neural.graph import (
    FEATURE_SPEC_VERSION,
    GraphSpec,
    SampleGraph,
    build_sample_graph,
)
from neural_shdf.shdf.sampling import (
    resample,
    samples_to_faces,
    smooth_samples,
    vertex_normal_sums,
)

MODEL_DIR = Path(__file__).resolve().parents[2] / "models"
DEFAULT_MODEL_PATH = MODEL_DIR / "emd.onnx"
MODEL_ENV_VAR = "NEURAL_SHDF_MODEL"
INTRA_OP_THREADS = 2
#: Sample sets (sampling seeds) whose predictions are averaged by default. The
#: prediction depends on where the samples fall; averaging sets lowers that noise.
DEFAULT_SAMPLE_SETS = 2
#: Seed offset between the sample sets of one prediction.
SAMPLE_SET_SEED_STRIDE = 7919


@dataclass(frozen=True)
class NeuralModel:
    """A loaded ONNX session, its model card and the graph spec it was trained with."""

    session: Any  # an onnxruntime.InferenceSession
    card: dict[str, Any]
    spec: GraphSpec
    path: Path

    def predict_log_diameter(self, graph: SampleGraph) -> NDArray[np.float64]:
        """Network output per sample: log(diameter / Poisson radius)."""
        feeds = {
            "node_features": np.ascontiguousarray(graph.node_features, dtype=np.float32),
            "edge_features": np.ascontiguousarray(graph.edge_features, dtype=np.float32),
            "senders": np.ascontiguousarray(graph.senders, dtype=np.int64),
            "receivers": np.ascontiguousarray(graph.receivers, dtype=np.int64),
        }
        (out,) = self.session.run(None, feeds)
        return np.asarray(out, dtype=np.float64).reshape(-1)


_MODELS: dict[Path, NeuralModel] = {}
_LOCK = threading.Lock()


def set_session_threads(threads: int) -> None:
    """Intra-op threads of the sessions loaded from now on. Worker pools with one process
    per core use 1: onnxruntime's spinning threads only cost CPU there. Results do not
    depend on it."""
    global INTRA_OP_THREADS
    INTRA_OP_THREADS = max(1, int(threads))


def model_path() -> Path:
    """The model file in use: ``$NEURAL_SHDF_MODEL`` or the packaged ``emd.onnx``."""
    override = os.environ.get(MODEL_ENV_VAR)
    return Path(override).expanduser().resolve() if override else DEFAULT_MODEL_PATH


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def load_model(path: str | Path | None = None) -> NeuralModel:
    """The cached model for ``path`` (default :func:`model_path`), loaded on first use.

    Raises ModelUnavailableError when the file or its card is missing, the
    card's checksum or feature version do not match, or onnxruntime fails.
    """
    path = model_path() if path is None else Path(path).expanduser().resolve()
    with _LOCK:
        if path in _MODELS:
            return _MODELS[path]
        card_path = path.with_suffix(".json")
        if not path.is_file() or not card_path.is_file():
            raise ModelUnavailableError(
                f"neural ShDF model not found: expected {path} and {card_path.name}; "
                "train and export one (python -m model_export.export) or use method='exact'"
            )
        try:
            card = json.loads(card_path.read_text())
        except (OSError, ValueError) as error:
            raise ModelUnavailableError(f"cannot read model card {card_path}: {error}") from error
        if card.get("feature_spec_version") != FEATURE_SPEC_VERSION:
            raise ModelUnavailableError(
                f"model {path.name} expects input features version "
                f"{card.get('feature_spec_version')}, this code builds version "
                f"{FEATURE_SPEC_VERSION}; re-export the model"
            )
        if card.get("sha256") and card["sha256"] != file_sha256(path):
            raise ModelUnavailableError(
                f"model {path.name} does not match the checksum in {card_path.name}"
            )
        try:
            # Inside the try: an onnxruntime that fails to load is a ModelUnavailableError
            # (the other ShDF methods still work), not a failure to import the package.
            import onnxruntime

            options = onnxruntime.SessionOptions()
            options.intra_op_num_threads = INTRA_OP_THREADS
            options.inter_op_num_threads = 1
            session = onnxruntime.InferenceSession(
                str(path), sess_options=options, providers=["CPUExecutionProvider"]
            )
        except Exception as error:  # noqa: BLE001 - any loader failure means no model
            raise ModelUnavailableError(f"cannot load model {path}: {error}") from error
        spec = GraphSpec.from_dict(card.get("graph_spec", {}))
        if card.get("node_features", list(spec.node_features)) != list(spec.node_features):
            raise ModelUnavailableError(
                f"model {path.name}: its card's node features {card['node_features']} are not "
                f"those its graph spec builds {list(spec.node_features)}; re-export the model"
            )
        model = NeuralModel(session, card, spec, path)
        _MODELS[path] = model
        return model


def neural_raw_shdf(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    *,
    seed: int = 0,
    sample_sets: int = DEFAULT_SAMPLE_SETS,
    model: NeuralModel | None = None,
    normals: NDArray[Any] | None = None,
    areas: NDArray[Any] | None = None,
    sample_filter: tuple[float, float] | None = None,
) -> NDArray[np.float64]:
    """Predicted raw diameter per triangle (mesh units), before post-processing.

    The network runs on ``sample_sets`` independent Poisson-disk sample sets
    (seeds derived from ``seed``); the log diameters of the other sets are
    interpolated at the first set's samples and averaged there, smoothed at the
    sample scale when ``sample_filter`` = (radius, spatial sigma) is given
    (``sampling.smooth_samples``), then mapped to the faces once.
    """
    if sample_sets < 1:
        raise ParameterError(f"sample_sets must be at least 1, got {sample_sets}")
    model = load_model() if model is None else model
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if normals is None or areas is None:
        normals, areas = face_normals(vertices, faces)
    normal_sums = vertex_normal_sums(len(vertices), faces, normals, areas)
    anchor = build_sample_graph(
        vertices,
        faces,
        model.spec,
        seed=seed,
        normals=normals,
        areas=areas,
        normal_sums=normal_sums,
    )
    log_diameter = model.predict_log_diameter(anchor)
    for index in range(1, sample_sets):
        other = build_sample_graph(
            vertices,
            faces,
            model.spec,
            seed=seed + SAMPLE_SET_SEED_STRIDE * index,
            normals=normals,
            areas=areas,
            map_vertices=False,
            normal_sums=normal_sums,
        )
        log_diameter += resample(
            model.predict_log_diameter(other), other, anchor, model.spec.interpolation_neighbours
        )
    per_sample = np.exp(log_diameter / sample_sets) * anchor.radius
    if sample_filter is not None:
        radius, sigma = sample_filter
        per_sample = smooth_samples(
            per_sample, anchor.positions, anchor.normals, radius=radius, spatial_sigma=sigma
        )
    return samples_to_faces(per_sample, anchor, faces)
