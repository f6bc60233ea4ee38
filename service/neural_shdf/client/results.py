"""Typed results of the client: the service's own response models, plus numpy arrays.

Metadata (``MeshInfo``, ``Job``, ``PartSummary``, ``Timings``) are the service's pydantic
models themselves, so the client and the API cannot drift apart; per-face data are numpy
arrays decoded from the compact binary forms (base64 labels, float32 ShDF).
"""

from __future__ import annotations

import base64
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.api.schemas import Job, MeshInfo, PartSummary, ShdfStatus, Timings
from neural_shdf.segment.hierarchy import PartTree

__all__ = [
    "Job",
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
        """The library's ``PartTree`` (its ``leaf_labels`` are these, per input face)."""
        return PartTree.from_parent(self.leaf_labels, self.parent, self.merge_cost)

    def labels(self, parts: int | None = None) -> NDArray[np.int32]:
        """Part per input face when the tree is cut into ``parts`` (None: the automatic
        count; clamped to 1..leaf_count): what ``segment(..., parts=parts)`` would answer."""
        count = self.automatic_parts if parts is None else parts
        return self.tree.relabel(self.leaf_labels, count).astype(np.int32)


@dataclass(frozen=True)
class Segmentation:
    """Part labels per input face (``-1``: a face without triangles) and a summary per part.

    ``hierarchy``: the graph cut's part tree (None for METIS); ``hierarchy.labels(n)``
    gives the labels for any part count without a request. ``extra`` keeps response
    fields this client version does not model, unchanged.
    """

    mesh_id: str
    method: str
    labels: NDArray[np.int32]
    parts: list[PartSummary]
    timings: Timings
    extra: dict[str, Any] = field(default_factory=dict)
    hierarchy: PartHierarchy | None = None

    @property
    def part_count(self) -> int:
        return len(self.parts)

    @classmethod
    def from_json(cls, body: dict[str, Any]) -> Segmentation:
        known = {"mesh_id", "method", "faces", "part_count", "parts", "timings"}
        known |= {"labels", "labels_base64", "labels_dtype", "hierarchy"}
        labels = decode_labels(body)
        if len(labels) != body["faces"]:
            raise ValueError(f"the service sent {len(labels)} labels for {body['faces']} faces")
        return cls(
            mesh_id=body["mesh_id"],
            method=body["method"],
            labels=labels,
            parts=[PartSummary.model_validate(part) for part in body["parts"]],
            timings=Timings.model_validate(body["timings"]),
            extra={k: v for k, v in body.items() if k not in known},
            hierarchy=(
                PartHierarchy.from_json(body["hierarchy"]) if body.get("hierarchy") else None
            ),
        )


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
