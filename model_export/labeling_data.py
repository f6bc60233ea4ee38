"""Inputs of the EMD part-labelling network: the neural ShDF's sample graph + labeller features.

Numpy only (no torch): the benchmark's evaluation and the training data both call
:func:`network_inputs`, so the network sees the same inputs in both (no train/serve skew).

* Graph: ``build_sample_graph`` (the neural ShDF's sampler, edges and invariant edge and
  node features) with the labeller's own sample count and seed, so its samples are
  exactly the labeller's samples (checked) and the network's per-sample outputs reach
  the faces through ``labeler.sample_face_probabilities``, as the neural ShDF's do.
* Node features: the sample graph's ``NODE_FEATURES`` (density and cone statistics),
  then the labeller's ``FEATURE_NAMES`` (ShDF at 5 scales, geodesic, heat-kernel and
  normal descriptors) of the sample's node. All invariant to pose, scale and tessellation.
* Target: the class (index into the label values) of the face holding the sample.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from neural_shdf.labeling._library import TriangleMesh, compute_shdf
from neural_shdf.labeling.features import FEATURE_NAMES, FeatureSpec
from neural_shdf.labeling.labeler import MeshDescription
from neural_shdf.shdf.neural.graph import (
    EDGE_FEATURES,
    NODE_FEATURES,
    GraphSpec,
    build_sample_graph,
)

#: Edges of the labelling network's graph (fewer than the ShDF network's 12 + 6: the
#: labeller features already carry the global context, and training runs on 2 cores).
GRAPH_SPEC = GraphSpec(knn=8, cone_neighbours=4)
#: Node feature names the network reads, in column order.
INPUT_NODE_FEATURES: tuple[str, ...] = NODE_FEATURES + FEATURE_NAMES
INPUT_EDGE_FEATURES: tuple[str, ...] = EDGE_FEATURES


def network_inputs(
    description: MeshDescription,
    spec: GraphSpec = GRAPH_SPEC,
    feature_spec: FeatureSpec | None = None,
) -> dict[str, NDArray]:
    """The network's inputs for a described mesh (float32 features, int64 indices)."""
    feature_spec = feature_spec or FeatureSpec()
    mesh = description.mesh.oriented
    normals, areas = mesh.normals_and_areas
    graph = build_sample_graph(
        mesh.vertices,
        mesh.faces,
        GraphSpec.from_dict({**spec.to_dict(), "target_samples": feature_spec.samples}),
        seed=feature_spec.seed,
        normals=normals,
        areas=areas,
        workers=1,
        map_vertices=False,
    )
    samples = description.nodes.samples
    if not np.array_equal(graph.face_ids, samples.face_ids):  # type: ignore[attr-defined]
        raise AssertionError("the sample graph's samples are not the labeller's samples")
    per_sample = description.features[description.nodes.samples_node]
    return {
        "node_features": np.concatenate([graph.node_features, per_sample], axis=1).astype(
            np.float32
        ),
        "edge_features": graph.edge_features.astype(np.float32),
        "senders": graph.senders.astype(np.int64),
        "receivers": graph.receivers.astype(np.int64),
    }


def sample_classes(
    description: MeshDescription, triangle_labels: NDArray, label_values: NDArray
) -> NDArray[np.int64]:
    """Class index (into ``label_values``) of the triangle holding each sample."""
    face_ids = description.nodes.samples.face_ids  # type: ignore[attr-defined]
    return np.searchsorted(label_values, np.asarray(triangle_labels)[face_ids]).astype(np.int64)


def cached_shdf(mesh: TriangleMesh, name: str, cache_dir: Path) -> NDArray[np.float64]:
    """The mesh's exact ShDF, cached under ``cache_dir/shdf`` by name and content hash
    (the layout ``benchmarks/bench_labeler.py`` uses, so both share one cache)."""
    path = cache_dir / "shdf" / f"{name}-{mesh.content_hash()[:16]}.npy"
    if path.is_file():
        return np.load(path)
    values = compute_shdf(mesh, method="exact").values
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, values)
    return values


def human_seg_split(data_dir: Path, every: int = 5) -> tuple[list[Path], list[Path]]:
    """(training, validation) meshes of human-seg: validation is every ``every``-th mesh by
    sorted name (``bench_labeler.py``'s split)."""
    paths = sorted((data_dir / "train").glob("*.obj"))
    return [p for i, p in enumerate(paths) if i % every], paths[::every]


class EmdLabeler:
    """An exported labelling network run by onnxruntime (as the service would run it)."""

    def __init__(self, path: str | Path, threads: int = 1) -> None:
        import json

        import onnxruntime

        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.session = onnxruntime.InferenceSession(
            str(path), sess_options=options, providers=["CPUExecutionProvider"]
        )
        raw = self.session.get_modelmeta().custom_metadata_map
        self.metadata = {key: json.loads(value) for key, value in raw.items()}
        if self.metadata.get("node_features") != list(INPUT_NODE_FEATURES):
            raise ValueError(f"{path}: the network reads other node features; train it again")
        self.spec = GraphSpec.from_dict(self.metadata["graph_spec"])
        self.label_values = np.asarray(self.metadata["label_values"], dtype=np.int64)

    def sample_probabilities(self, description: MeshDescription) -> NDArray[np.float64]:
        """(samples, classes) class probabilities per Poisson sample."""
        inputs = network_inputs(description, self.spec)
        (log_probabilities,) = self.session.run(None, inputs)
        return np.exp(np.asarray(log_probabilities, dtype=np.float64))

    def label_description(
        self, description: MeshDescription, smoothing: float | None = None
    ) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """(class per triangle, its probability), the shipped labeller's mapping and cut."""
        from neural_shdf.labeling.labeler import (
            coherent_description_labels,
            sample_face_probabilities,
        )

        probabilities = sample_face_probabilities(
            description, self.sample_probabilities(description)
        )
        smoothing = self.metadata["smoothing"] if smoothing is None else smoothing
        return coherent_description_labels(description, probabilities, smoothing)
