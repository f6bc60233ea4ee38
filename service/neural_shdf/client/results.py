"""Typed results of the client: small wire models parsed from the service's JSON, plus
numpy arrays.

The client needs httpx and numpy only (no FastAPI, pydantic or the library's compiled
kernels), so it has its own models of the answers it reads. Each mirrors a response model
of the service (``api.schemas``) field by field; ``tests/client/test_results.py`` fails
when the two drift apart. Fields a newer service adds are ignored (``Segmentation.extra``
keeps them). Per-face data are numpy arrays decoded from the compact binary forms
(base64 labels, float32 ShDF).
"""

from __future__ import annotations

import base64
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from neural_shdf.segment.hierarchy import PartTree

__all__ = [
    "ErrorDetail",
    "Job",
    "LabelerInfo",
    "MeshDiagnostics",
    "MeshInfo",
    "PartHierarchy",
    "PartSummary",
    "Segmentation",
    "ShdfStatus",
    "Timings",
    "Upload",
    "decode_labels",
    "decode_shdf",
]

W = TypeVar("W")

#: The members of a segmentation answer this client reads (``Segmentation.extra``: others).
SEGMENTATION_FIELDS = frozenset(
    {"mesh_id", "method", "faces", "part_count", "parts", "timings"}
    | {"labels", "labels_base64", "labels_dtype", "hierarchy"}
    | {"labeler_id", "label_names", "label_values", "confidence", "confidence_base64"}
    | {"source_id"}
)
#: The members of its ``hierarchy`` this client reads.
HIERARCHY_FIELDS = frozenset(
    {"leaf_count", "parts", "automatic_parts", "parent", "merge_cost", "merge_height"}
    | {"leaf_labels", "leaf_labels_base64", "leaf_labels_dtype"}
)


def parse(model: type[W], body: Mapping[str, Any]) -> W:
    """``model`` from a JSON object: its own fields only (a newer service may send more);
    a ValueError naming what is missing when the answer lacks a required one."""
    if not isinstance(body, Mapping):
        raise ValueError(f"the service sent {type(body).__name__} where {model.__name__} belongs")
    names = {spec.name for spec in fields(model)}  # type: ignore[arg-type]
    try:
        return model(**{name: value for name, value in body.items() if name in names})
    except TypeError as error:
        raise ValueError(f"the service's {model.__name__} is incomplete: {error}") from None


@dataclass(frozen=True)
class ErrorDetail:
    """Why a job failed: a stable ``code``, a ``message`` saying what to do, ``detail``."""

    code: str
    message: str
    detail: Any = None

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> ErrorDetail:
        return parse(cls, body)


@dataclass(frozen=True)
class MeshDiagnostics:
    """What the mesh had and what was done about it before the ShDF and segmentation."""

    shells: int
    boundary_loops: int
    non_manifold_edges: int
    reoriented_faces: int
    degenerate_faces: int
    duplicate_faces: int
    stitched_shells: int = 0
    stitched_vertices: int = 0

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> MeshDiagnostics:
        return parse(cls, body)


@dataclass(frozen=True)
class MeshInfo:
    """A stored mesh: its id (content hash of its geometry), size and diagnostics; the
    ``format``, ``filename`` and ``uploaded_at`` of an upload (None when read back)."""

    mesh_id: str
    faces: int
    triangles: int
    vertices: int
    bounds: list[list[float]]
    surface_area: float
    format: str | None = None
    filename: str | None = None
    uploaded_at: float | None = None
    diagnostics: MeshDiagnostics | None = None
    #: The upload's own file kept with the mesh: ``parts_glb(..., source=...)``.
    source_id: str | None = None

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> MeshInfo:
        diagnostics = body.get("diagnostics")
        if diagnostics is not None:
            body = {**body, "diagnostics": MeshDiagnostics.from_json(diagnostics)}
        return parse(cls, body)


@dataclass(frozen=True)
class ShdfStatus:
    """The ShDF an upload was given: the producer that ran, its seed, whether it came from
    the cache and how long it took."""

    method: str
    seed: int
    cached: bool
    seconds: float

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> ShdfStatus:
        return parse(cls, body)


@dataclass(frozen=True)
class Job:
    """A long computation: its state and progress, and where its result is once done."""

    job_id: str
    state: str  # queued, running, succeeded, failed
    progress: float
    mesh_id: str
    method: str
    seed: int
    created_at: float
    updated_at: float
    result_url: str
    kind: str = "shdf"
    attempt: int = 1
    error: ErrorDetail | None = None

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> Job:
        error = body.get("error")
        if error is not None:
            body = {**body, "error": ErrorDetail.from_json(error)}
        return parse(cls, body)


@dataclass(frozen=True)
class PartSummary:
    """One part of a segmentation: its label, faces, area, mean ShDF and display colour."""

    label: int
    faces: int
    area: float
    mean_shdf: float
    color: str
    name: str | None = None  # the label's name (named parts by a labeller)

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> PartSummary:
        return parse(cls, body)


@dataclass(frozen=True)
class Timings:
    """Where a segmentation's time went, in milliseconds, and what came from the cache."""

    shdf_ms: float
    segment_ms: float
    total_ms: float
    shdf_cached: bool
    segmentation_cached: bool

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> Timings:
        return parse(cls, body)


@dataclass(frozen=True)
class Upload:
    """A stored mesh and where its ShDF stands."""

    mesh: MeshInfo
    shdf: ShdfStatus

    @property
    def mesh_id(self) -> str:
        return self.mesh.mesh_id


@dataclass(frozen=True)
class PartHierarchy:
    """The graph cut's part tree (the response's ``hierarchy``): any part count, no request.

    ``leaf_labels``: leaf per input face (-1: a face without triangles); ``parent``: parent
    of each of the 2L - 1 nodes (-1: the root); ``merge_cost``/``merge_height``: per merge.
    """

    leaf_count: int
    parts: int
    automatic_parts: int
    leaf_labels: NDArray[np.int32]
    parent: NDArray[np.int64]
    merge_cost: NDArray[np.float64]
    merge_height: NDArray[np.float64]

    @classmethod
    def from_json(cls, tree: dict[str, Any]) -> PartHierarchy:
        packed = tree.get("leaf_labels_base64")
        leaves = (
            decode_integers(packed, tree["leaf_labels_dtype"])
            if packed is not None
            else np.asarray(tree["leaf_labels"], dtype=np.int32)
        )
        return cls(
            leaf_count=int(tree["leaf_count"]),
            parts=int(tree["parts"]),
            automatic_parts=int(tree["automatic_parts"]),
            leaf_labels=leaves,
            parent=np.asarray(tree["parent"], dtype=np.int64),
            merge_cost=np.asarray(tree["merge_cost"], dtype=np.float64),
            merge_height=np.asarray(tree["merge_height"], dtype=np.float64),
        )

    @property
    def tree(self) -> PartTree:
        """The library's ``PartTree`` (its ``leaf_labels`` are these, per input face).
        Needs the whole package (its compiled kernels), unlike the rest of the client."""
        from neural_shdf.segment.hierarchy import PartTree  # numba: only for this helper

        return PartTree.from_parent(self.leaf_labels, self.parent, self.merge_cost)

    def labels(self, parts: int | None = None) -> NDArray[np.int32]:
        """Part per input face when the tree is cut into ``parts`` (None: the automatic
        count; clamped to 1..leaf_count): what ``segment(..., parts=parts)`` would answer.
        Needs the whole package, as ``tree`` does."""
        count = self.automatic_parts if parts is None else parts
        return self.tree.relabel(self.leaf_labels, count).astype(np.int32)

    def edited(
        self, edits: Sequence[Mapping[str, Any]], parts: int | None = None
    ) -> NDArray[np.int32]:
        """Part per input face of the cut at ``parts`` (None: the cut this response was
        made at) edited by ``edits``: what ``segment(..., edits=edits)`` would answer.
        Needs the whole package, as ``tree`` does."""
        from neural_shdf.segment.editing import apply_edits  # numba: only for this helper

        count = self.parts if parts is None else parts
        return apply_edits(self.tree, self.leaf_labels, count, edits).astype(np.int32)


@dataclass(frozen=True)
class Segmentation:
    """Part labels per input face (``-1``: a face without triangles) and a summary per part.

    ``hierarchy``: the graph cut's part tree (None for METIS); ``hierarchy.labels(n)``
    gives the labels for any part count without a request. ``extra`` keeps response
    fields this client version does not model, unchanged.

    Named parts (``segment(..., labeler_id=...)``): ``labels`` hold the training labels'
    own integers, ``label_names``/``label_values`` the labeller's names and integers,
    ``confidence`` the probability of each face's label (float32, NaN: no triangles).
    """

    mesh_id: str
    method: str
    labels: NDArray[np.int32]
    parts: list[PartSummary]
    timings: Timings
    extra: dict[str, Any] = field(default_factory=dict)
    hierarchy: PartHierarchy | None = None
    labeler_id: str | None = None
    label_names: list[str] | None = None
    label_values: list[int] | None = None
    confidence: NDArray[np.float32] | None = None
    #: ``segment_file``: the upload's own file kept with the mesh, for
    #: ``parts_glb(..., source=...)`` and ``parts_usda(..., source=...)``.
    source_id: str | None = None

    @property
    def part_count(self) -> int:
        return len(self.parts)

    @property
    def names(self) -> dict[int, str]:
        """Label integer -> name (named parts; empty for a segmentation)."""
        return dict(zip(self.label_values or [], self.label_names or [], strict=True))

    def face_names(self) -> list[str]:
        """The name of each face's label (``unlabeled`` for -1 or an unnamed label)."""
        names = self.names
        return [names.get(label, "unlabeled") for label in self.labels.tolist()]

    @classmethod
    def from_json(cls, body: dict[str, Any]) -> Segmentation:
        labels = decode_labels(body)
        if len(labels) != body["faces"]:
            raise ValueError(f"the service sent {len(labels)} labels for {body['faces']} faces")
        return cls(
            mesh_id=body["mesh_id"],
            method=body["method"],
            labels=labels,
            parts=[PartSummary.from_json(part) for part in body["parts"]],
            timings=Timings.from_json(body["timings"]),
            extra={k: v for k, v in body.items() if k not in SEGMENTATION_FIELDS},
            hierarchy=(
                PartHierarchy.from_json(body["hierarchy"]) if body.get("hierarchy") else None
            ),
            labeler_id=body.get("labeler_id"),
            label_names=body.get("label_names"),
            label_values=body.get("label_values"),
            confidence=decode_confidence(body),
            source_id=body.get("source_id"),
        )


@dataclass(frozen=True)
class LabelerInfo:
    """A stored part labeller: its id, label names and integers, and what it was made of."""

    labeler_id: str
    label_names: list[str]
    label_values: list[int]
    feature_version: int
    smoothing: float
    training_meshes: int
    size_bytes: int
    stored_at: float

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> LabelerInfo:
        return parse(cls, body)


def decode_confidence(body: Mapping[str, Any]) -> NDArray[np.float32] | None:
    """Per-face confidence of named parts (float32; NaN: no triangles), or None."""
    packed = body.get("confidence_base64")
    if packed is not None:
        return np.frombuffer(base64.b64decode(packed), dtype="<f4").astype(np.float32)
    values = body.get("confidence")
    if values is None:
        return None
    return np.array([np.nan if v is None else v for v in values], dtype=np.float32)


def decode_labels(body: dict[str, Any]) -> NDArray[np.int32]:
    """Labels of a segmentation response, from ``labels_base64`` (little-endian integers of
    ``labels_dtype``) or the JSON list."""
    packed = body.get("labels_base64")
    if packed is not None:
        return decode_integers(packed, body["labels_dtype"])
    return np.asarray(body["labels"], dtype=np.int32)


def decode_integers(packed: str, dtype: str) -> NDArray[np.int32]:
    """Base64 little-endian integers of type ``dtype`` (int8/int16/int32) as int32."""
    little = np.dtype(dtype).newbyteorder("<")
    return np.frombuffer(base64.b64decode(packed), dtype=little).astype(np.int32)


def decode_shdf(content: bytes, faces: int | None = None) -> NDArray[np.float32]:
    """Per-input-face ShDF from the service's float32 little-endian form (NaN: no triangles)."""
    if len(content) % 4:
        raise ValueError(f"a float32 ShDF body must be a multiple of 4 bytes, got {len(content)}")
    values = np.frombuffer(content, dtype="<f4").astype(np.float32)
    if faces is not None and len(values) != faces:
        raise ValueError(f"the service sent {len(values)} ShDF values for {faces} faces")
    return values
