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

__all__ = [
    "Job",
    "MeshInfo",
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
class Segmentation:
    """Part labels per input face (``-1``: a face without triangles) and a summary per part.

    ``extra`` keeps response fields this client version does not model, unchanged.
    """

    mesh_id: str
    method: str
    labels: NDArray[np.int32]
    parts: list[PartSummary]
    timings: Timings
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def part_count(self) -> int:
        return len(self.parts)

    @classmethod
    def from_json(cls, body: dict[str, Any]) -> Segmentation:
        known = {"mesh_id", "method", "faces", "part_count", "parts", "timings"}
        known |= {"labels", "labels_base64", "labels_dtype"}
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
        )


def decode_labels(body: dict[str, Any]) -> NDArray[np.int32]:
    """Labels of a segmentation response, from ``labels_base64`` (little-endian integers of
    ``labels_dtype``) or the JSON list."""
    packed = body.get("labels_base64")
    if packed is not None:
        dtype = np.dtype(body["labels_dtype"]).newbyteorder("<")
        return np.frombuffer(base64.b64decode(packed), dtype=dtype).astype(np.int32)
    return np.asarray(body["labels"], dtype=np.int32)


def decode_shdf(content: bytes, faces: int | None = None) -> NDArray[np.float32]:
    """Per-input-face ShDF from the service's float32 little-endian form (NaN: no triangles)."""
    if len(content) % 4:
        raise ValueError(f"a float32 ShDF body must be a multiple of 4 bytes, got {len(content)}")
    values = np.frombuffer(content, dtype="<f4").astype(np.float32)
    if faces is not None and len(values) != faces:
        raise ValueError(f"the service sent {len(values)} ShDF values for {faces} faces")
    return values
