"""Train a part labeller from labelled meshes; label the faces of new meshes.

``train_labeler(meshes, labels, names)`` -> ``Labeler``; ``label_mesh(mesh, labeler)`` ->
(label per input face in the training labels' own integers, confidence per input face).
Features and classes live on the nodes of a Poisson-disk sample graph (``features``);
node probabilities are carried to the faces and made coherent by a graph cut
(``coherence``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from neural_shdf.errors import ParameterError
from neural_shdf.geometry import midpoint_subdivide
from neural_shdf.labeling._library import (
    FaceGraph,
    TriangleMesh,
    compute_shdf,
    face_centroids,
    interpolate_samples,
)
from neural_shdf.labeling.coherence import coherent_labels
from neural_shdf.labeling.features import (
    FEATURE_NAMES,
    FEATURE_VERSION,
    FeatureSpec,
    NodeGraph,
    node_features,
    node_graph,
    node_labels,
)
from neural_shdf.labeling.model import Labeler, TreeEnsemble

#: Graph-cut smoothing (lambda) of the labels; chosen on training meshes.
DEFAULT_SMOOTHING = 0.003
#: Boosting: iterations, learning rate, leaves per tree (chosen on training meshes).
BOOST_ITERATIONS = 150
LEARNING_RATE = 0.1
MAX_LEAF_NODES = 31
#: Every this-many-th training mesh (from the first) is also learned subdivided x16, its
#: labels carried to the children: the trees then see how a finer tessellation of the
#: same surface moves the features, and label fine meshes as well as coarse ones.
AUGMENT_EVERY = 3
#: Meshes above this many triangles are not subdivided for training (already fine).
AUGMENT_MAX_FACES = 20_000
#: A label may have at most this many classes (one tree per class per iteration).
MAX_CLASSES = 64

Progress = Callable[[float], None]


@dataclass(frozen=True)
class MeshDescription:
    """What labelling needs of a mesh: its oriented triangles, face graph, node graph and
    node features (the node graph's distance matrix is dropped once features exist)."""

    mesh: TriangleMesh
    graph: FaceGraph
    nodes: NodeGraph
    features: NDArray[np.float32]

    @property
    def areas(self) -> NDArray[np.float64]:
        return self.mesh.oriented.normals_and_areas[1]


def describe_mesh(
    mesh: TriangleMesh,
    shdf: NDArray | None = None,
    *,
    graph: FaceGraph | None = None,
    spec: FeatureSpec | None = None,
) -> MeshDescription:
    """Node graph and features of ``mesh``; ``shdf``: its ShDF per triangle (computed with
    the default method when None)."""
    graph = mesh.face_graph if graph is None else graph
    if shdf is None:
        shdf = compute_shdf(mesh).values
    shdf = np.asarray(shdf, dtype=np.float64)
    if shdf.shape != (mesh.face_count,):
        raise ParameterError(
            f"the ShDF has {shdf.size} values, the mesh {mesh.face_count} triangles"
        )
    nodes = node_graph(mesh, graph, spec or FeatureSpec())
    features = node_features(nodes, shdf, mesh.oriented.normals_and_areas[1])
    return MeshDescription(mesh, graph, replace(nodes, distances=np.zeros((0, 0))), features)


def triangle_labels(mesh: TriangleMesh, labels: NDArray) -> NDArray[np.int64]:
    """Per-input-face labels as per-triangle labels; ``ParameterError`` on a count mismatch."""
    labels = np.asarray(labels)
    if labels.ndim != 1 or len(labels) != mesh.input_face_count:
        raise ParameterError(
            f"{labels.size} labels for a mesh of {mesh.input_face_count} faces: "
            "give one integer label per face, in the file's face order"
        )
    if not np.issubdtype(labels.dtype, np.integer) and not (
        np.all(np.isfinite(labels)) and np.all(labels == np.round(labels))
    ):
        raise ParameterError("labels must be integers")
    return labels.astype(np.int64)[mesh.face_origin]


@dataclass(frozen=True)
class TrainingRows:
    """One mesh's share of the training set: node features, the label covering most of
    each node's cell, and each node's weight (every mesh weighs the same in total)."""

    features: NDArray[np.float32]
    labels: NDArray[np.int64]
    weights: NDArray[np.float64]
    #: Rows of a training mesh's subdivided copy (``AUGMENT_EVERY``).
    subdivided: bool = False


def training_rows(
    description: MeshDescription, labels: NDArray, subdivided: bool = False
) -> TrainingRows:
    """``TrainingRows`` of a described mesh from its labels per triangle."""
    nodes = description.nodes
    return TrainingRows(
        description.features,
        node_labels(nodes, labels, description.areas),
        nodes.cell_area * nodes.node_count,
        subdivided,
    )


def subdivided_copy(
    mesh: TriangleMesh, labels: NDArray, times: int = 2
) -> tuple[TriangleMesh, NDArray[np.int64]]:
    """``mesh``'s triangles each split into 4, ``times`` times, and the labels per triangle
    carried to the children."""
    vertices, faces, origin = midpoint_subdivide(mesh.vertices, mesh.faces, times)
    return TriangleMesh(vertices, faces), np.asarray(labels, dtype=np.int64)[origin]


def fit_labeler(
    rows: Sequence[TrainingRows],
    names: Sequence[str] | None = None,
    *,
    smoothing: float = DEFAULT_SMOOTHING,
    iterations: int = BOOST_ITERATIONS,
    spec: FeatureSpec | None = None,
    labels: NDArray | None = None,
) -> Labeler:
    """A labeller from training rows of one or more meshes. ``labels``: every label value
    the meshes' faces hold (default: those of the rows); ``names``: one per label."""
    # Lazy: scikit-learn is slow to import and only training needs it (labelling does not).
    from sklearn.ensemble import HistGradientBoostingClassifier

    if len(rows) == 0:
        raise ParameterError("give at least one labelled mesh")
    target = np.concatenate([r.labels for r in rows])
    values = np.unique(target) if labels is None else np.unique(np.asarray(labels, np.int64))
    if len(values) < 2:
        raise ParameterError("the training labels hold one label only: give at least two")
    if len(values) > MAX_CLASSES:
        raise ParameterError(f"{len(values)} distinct labels, at most {MAX_CLASSES} are supported")
    names = tuple(str(v) for v in values) if names is None else tuple(names)
    if len(names) != len(values):
        raise ParameterError(
            f"{len(names)} label names for {len(values)} distinct labels "
            f"({', '.join(str(v) for v in values)}): give one name per label, in label order"
        )
    start = time.perf_counter()
    model = HistGradientBoostingClassifier(
        max_iter=iterations,
        learning_rate=LEARNING_RATE,
        max_leaf_nodes=MAX_LEAF_NODES,
        early_stopping=False,
        random_state=0,
    )
    classes = np.searchsorted(values, target)
    present = np.unique(classes)
    if len(present) < 2:
        raise ParameterError(
            "after sampling, one label covers every region: give meshes where each label "
            "covers a region, not scattered faces"
        )
    # One OpenMP thread: on a shared machine more threads made the fit much slower (they
    # spin while waiting for each other; docs/benchmarks.md), and one thread is deterministic.
    with threadpool_limits(limits=1, user_api="openmp"):
        model.fit(
            np.concatenate([r.features for r in rows]),
            np.searchsorted(present, classes),
            sample_weight=np.concatenate([r.weights for r in rows]),
        )
    trees = TreeEnsemble.from_sklearn(model)
    if len(present) < len(values):
        trees = _expand_classes(trees, present, len(values))
    metadata = {
        "feature_version": FEATURE_VERSION,
        "feature_names": list(FEATURE_NAMES),
        "feature_spec": (spec or FeatureSpec()).to_dict(),
        "smoothing": float(smoothing),
        "classifier": {
            "kind": "HistGradientBoostingClassifier",
            "iterations": iterations,
            "learning_rate": LEARNING_RATE,
            "max_leaf_nodes": MAX_LEAF_NODES,
        },
        "training": {
            "meshes": sum(1 for r in rows if not r.subdivided),
            "nodes": int(len(target)),
            "fit_seconds": round(time.perf_counter() - start, 2),
            "subdivided_copies": sum(1 for r in rows if r.subdivided),
        },
    }
    return Labeler(trees, values, names, metadata)


def _expand_classes(trees: TreeEnsemble, present: NDArray, count: int) -> TreeEnsemble:
    """Trees over the classes present in the nodes, re-indexed to all ``count`` classes
    (a label seen on faces but on no node's majority gets probability ~0). Two present
    classes: the binary score ``s`` becomes the scores (0, s), whose softmax is its sigmoid."""
    baseline = np.full(count, -30.0)
    if len(trees.baseline) == 1:
        baseline[present[0]] = 0.0
        baseline[present[1]] = trees.baseline[0]
        return replace(
            trees, tree_class=np.full_like(trees.tree_class, present[1]), baseline=baseline
        )
    baseline[present] = trees.baseline
    return replace(trees, tree_class=present[trees.tree_class], baseline=baseline)


def train_labeler(
    meshes: Sequence[TriangleMesh],
    labels: Sequence[NDArray],
    names: Sequence[str] | None = None,
    *,
    shdf: Sequence[NDArray | None] | None = None,
    smoothing: float = DEFAULT_SMOOTHING,
    spec: FeatureSpec | None = None,
    augment: bool = True,
    progress: Progress | None = None,
) -> Labeler:
    """Train a labeller from meshes and one integer label per input face of each.

    ``names``: one per distinct label, in increasing label order (default: the labels
    as text). ``shdf``: each mesh's ShDF per triangle where known (else computed).
    ``augment``: also learn every ``AUGMENT_EVERY``-th mesh subdivided x16 (its ShDF
    computed with the default method), so that fine meshes are labelled as well.
    """
    if len(meshes) != len(labels):
        raise ParameterError(f"{len(meshes)} meshes but {len(labels)} label arrays")
    rows, values = [], []
    for index, mesh in enumerate(meshes):
        per_triangle = triangle_labels(mesh, labels[index])
        given = None if shdf is None else shdf[index]
        rows.append(training_rows(describe_mesh(mesh, given, spec=spec), per_triangle))
        values.append(np.unique(per_triangle))
        if augment and index % AUGMENT_EVERY == 0 and mesh.face_count <= AUGMENT_MAX_FACES:
            fine, fine_labels = subdivided_copy(mesh, per_triangle)
            rows.append(training_rows(describe_mesh(fine, spec=spec), fine_labels, True))
        if progress is not None:
            progress(0.8 * (index + 1) / len(meshes))
    labeler = fit_labeler(
        rows, names, smoothing=smoothing, spec=spec, labels=np.unique(np.concatenate(values))
    )
    if progress is not None:
        progress(1.0)
    return labeler


def face_probabilities(description: MeshDescription, node_probabilities: NDArray) -> NDArray:
    """(F, classes) probabilities per triangle from probabilities per node."""
    return sample_face_probabilities(
        description, np.asarray(node_probabilities)[description.nodes.samples_node]
    )


def sample_face_probabilities(
    description: MeshDescription, sample_probabilities: NDArray
) -> NDArray:
    """(F, classes) probabilities per triangle from probabilities per Poisson sample: each
    vertex interpolates its nearest samples (normal-aware, as the neural ShDF), a triangle
    takes its vertices' mean."""
    samples = description.nodes.samples
    faces = description.mesh.oriented.faces
    classes = sample_probabilities.shape[1]
    out = np.empty((len(faces), classes))
    for column in range(classes):
        per_vertex = interpolate_samples(
            sample_probabilities[:, column],
            samples.normals,
            samples.vertex_samples,
            samples.vertex_sample_distance,
            samples.vertex_normals,
            samples.radius,
        )
        out[:, column] = per_vertex[faces].mean(axis=1)
    out /= np.maximum(out.sum(axis=1, keepdims=True), 1e-12)
    return out


def label_description(
    description: MeshDescription, labeler: Labeler, smoothing: float | None = None
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """(class per triangle, its probability) for a described mesh."""
    probabilities = face_probabilities(description, labeler.predict_proba(description.features))
    smoothing = (
        labeler.metadata.get("smoothing", DEFAULT_SMOOTHING) if smoothing is None else smoothing
    )
    return coherent_description_labels(description, probabilities, smoothing)


def coherent_description_labels(
    description: MeshDescription, probabilities: NDArray, smoothing: float
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """(class per triangle, its probability) after the graph cut, from (F, classes)
    probabilities per triangle of a described mesh."""
    mesh = description.mesh.oriented
    classes = coherent_labels(
        probabilities,
        description.graph,
        description.areas,
        face_centroids(mesh.vertices, mesh.faces),
        smoothing,
    )
    return classes, probabilities[np.arange(len(classes)), classes]


def check_compatible(labeler: Labeler) -> FeatureSpec:
    """The labeller's sampling spec; ``ParameterError`` when its features are another version's."""
    if (
        labeler.metadata.get("feature_version") != FEATURE_VERSION
        or tuple(labeler.metadata.get("feature_names", ())) != FEATURE_NAMES
    ):
        raise ParameterError(
            "the labeller was trained with other features "
            f"(version {labeler.metadata.get('feature_version')}, this one computes "
            f"{FEATURE_VERSION}): train it again"
        )
    spec = labeler.metadata.get("feature_spec", {})
    return FeatureSpec(**{k: int(v) for k, v in spec.items() if k in ("samples", "seed")})


def label_mesh(
    mesh: TriangleMesh,
    labeler: Labeler,
    *,
    shdf: NDArray | None = None,
    graph: FaceGraph | None = None,
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """(label per input face, confidence per input face), in the input file's face order.

    Labels are the training labels' own integers; confidence is the classifier's
    probability of the chosen label (area-weighted over a polygon's triangles). Input
    faces that produced no triangle get label -1 and confidence NaN. ``shdf``: the
    mesh's ShDF per triangle where cached (else computed with the default method).
    """
    spec = check_compatible(labeler)
    description = describe_mesh(mesh, shdf, graph=graph, spec=spec)
    classes, confidence = label_description(description, labeler)
    per_face = mesh.labels_to_input_faces(classes)
    labels = np.where(per_face >= 0, labeler.label_values[np.maximum(per_face, 0)], -1)
    return labels.astype(np.int64), mesh.to_input_faces(confidence)
