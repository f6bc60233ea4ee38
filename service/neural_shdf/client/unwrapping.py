"""Unwrap by parts from the client: the request options, the operations and the ``UvLayout``
wire model (UVs per corner of every input face, decoded to numpy arrays).

Every call is a GET of ``/v1/meshes/{id}/segmentation/...`` with the segmentation and
unwrap options; a large mesh answers 202 with a job (the ShDF's, then the atlas's), which
is polled and the request repeated, as for the other downloads.
"""

from __future__ import annotations

import base64
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.client.operations import (
    Call,
    Operation,
    PollPolicy,
    SegmentArgs,
    as_query,
    until_done,
)
from neural_shdf.client.results import parse

__all__ = ["UNWRAP_FILES", "UnwrapArgs", "UvLayout", "download", "uv_layout"]

#: What each download is (``Client.unwrapped``'s ``kind``) and the route that serves it.
UNWRAP_FILES = {"glb": "unwrapped.glb", "obj": "unwrapped.obj", "atlas": "atlas.png"}


class UnwrapArgs(SegmentArgs, total=False):
    """The segmentation to unwrap by (``SegmentArgs``) and how to chart and pack it;
    omitted or None: the service's default."""

    atlas_size: int | None  # side of the square atlas in texels (64-8192)
    padding: int | None  # texels left free around every chart
    max_stretch: float | None  # largest L2 stretch of a part kept as one chart


@dataclass(frozen=True, eq=False)
class UvLayout:
    """UVs of every corner of every input face (the service's ``UvLayout``): faces in the
    input file's order, each face's corners in the file's order, v up. The arrays decode the
    base64 fields once: ``corner_counts``, ``uvs`` (corners, 2), ``chart`` (per face),
    ``face_uvs(face)``."""

    mesh_id: str
    faces: int
    corners: int
    corner_counts_base64: str
    uvs_base64: str
    chart_base64: str
    chart_part: list[int]
    width: int
    height: int
    utilization: float
    split_faces: int

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> UvLayout:
        layout = parse(cls, body)
        if len(layout.corner_counts) != layout.faces or len(layout.uvs) != layout.corners:
            raise ValueError(
                f"the service's UvLayout does not add up: {len(layout.corner_counts)} corner "
                f"counts for {layout.faces} faces, {len(layout.uvs)} UVs for "
                f"{layout.corners} corners"
            )
        return layout

    @cached_property
    def corner_counts(self) -> NDArray[np.int32]:
        """(faces,) corners of each input face (0: a face without triangles)."""
        return _decode(self.corner_counts_base64, "<i4")

    @cached_property
    def uvs(self) -> NDArray[np.float32]:
        """(corners, 2) the UV of each corner, faces one after the other."""
        return _decode(self.uvs_base64, "<f4").reshape(-1, 2)

    @cached_property
    def chart(self) -> NDArray[np.int32]:
        """(faces,) the chart of each input face (-1: none); its part: ``chart_part``."""
        return _decode(self.chart_base64, "<i4")

    @cached_property
    def offsets(self) -> NDArray[np.int64]:
        """(faces + 1,) where each face's corners start in ``uvs``."""
        return np.concatenate([[0], np.cumsum(self.corner_counts, dtype=np.int64)])

    def face_uvs(self, face: int) -> NDArray[np.float32]:
        """(corners of ``face``, 2) its UVs in its own corner order."""
        return self.uvs[self.offsets[face] : self.offsets[face + 1]]


def _decode(text: str, dtype: str) -> NDArray[Any]:
    values = np.frombuffer(base64.b64decode(text), dtype=dtype)
    return values.astype(values.dtype.newbyteorder("="))


def download(mesh_id: str, kind: str, options: Mapping[str, Any], poll: PollPolicy) -> Operation:
    """The unwrapped mesh as GLB (``glb``) or OBJ (``obj``), or the atlas picture (``atlas``,
    PNG), as bytes."""
    if kind not in UNWRAP_FILES:
        raise ValueError(f"kind must be one of {', '.join(UNWRAP_FILES)}, got {kind!r}")
    path = f"/v1/meshes/{mesh_id}/segmentation/{UNWRAP_FILES[kind]}"
    response = yield from until_done(Call("GET", path, params=as_query(options)), poll)
    return response.content


def uv_layout(mesh_id: str, options: Mapping[str, Any], poll: PollPolicy) -> Operation:
    """The UVs per corner of every input face (``UvLayout``)."""
    call = Call("GET", f"/v1/meshes/{mesh_id}/segmentation/uvs", params=as_query(options))
    response = yield from until_done(call, poll)
    return UvLayout.from_json(response.json())
