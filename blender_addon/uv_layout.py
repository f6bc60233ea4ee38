"""The service's UVs per corner of every input face (``GET .../segmentation/uvs``) and how
they become a Blender UV map's per-loop values. No bpy here: usable (and tested) outside
Blender."""

from __future__ import annotations

import base64
import urllib.parse
from dataclasses import dataclass
from typing import Any

import numpy as np

from .service import Progress, ServiceError, Session


@dataclass
class UvLayout:
    """UVs per corner, faces in the uploaded polygon order, corners in each polygon's own
    order, v up (Blender's convention)."""

    corner_counts: np.ndarray  # (faces,) int32
    uvs: np.ndarray  # (corners, 2) float32
    chart_count: int
    utilization: float
    split_faces: int

    @classmethod
    def from_json(cls, body: dict[str, Any]) -> UvLayout:
        counts = np.frombuffer(base64.b64decode(body["corner_counts_base64"]), "<i4")
        uvs = np.frombuffer(base64.b64decode(body["uvs_base64"]), "<f4").reshape(-1, 2)
        if len(counts) != body["faces"] or len(uvs) != int(counts.sum()):
            raise ServiceError(
                f"the service sent UVs for {len(counts)} faces and {len(uvs)} corners, "
                f"expected {body['faces']} faces and {int(counts.sum())} corners"
            )
        return cls(
            corner_counts=counts.astype(np.int32),
            uvs=uvs.astype(np.float32),
            chart_count=len(body["chart_part"]),
            utilization=float(body["utilization"]),
            split_faces=int(body["split_faces"]),
        )


def fetch(session: Session, mesh_id: str, options: dict[str, Any], progress: Progress) -> UvLayout:
    """The UV layout of a stored mesh for these segmentation and unwrap options; a 202
    (the ShDF's or the atlas's job) is waited for, then the request repeated."""
    query = urllib.parse.urlencode(
        {k: str(v).lower() if isinstance(v, bool) else str(v) for k, v in options.items()}
    )
    path = f"/v1/meshes/{mesh_id}/segmentation/uvs?{query}"
    for _ in range(3):
        status, body = session.json("GET", path)
        if status != 202:
            return UvLayout.from_json(body)
        session.wait_job(body, progress)
    raise ServiceError("the unwrap kept answering 202 after its job finished", "loop")


def loop_uvs(
    layout: UvLayout, loop_start: np.ndarray, loop_total: np.ndarray
) -> tuple[np.ndarray, int]:
    """(loops, 2) UVs for a mesh whose polygons are the uploaded ones, in order, and how
    many polygons got none (their corner count differs from the service's: left at 0)."""
    if len(layout.corner_counts) != len(loop_total):
        raise ServiceError(
            f"the service unwrapped {len(layout.corner_counts)} faces but the mesh has "
            f"{len(loop_total)} polygons; segment it again"
        )
    values = np.zeros((int(loop_total.sum()), 2), dtype=np.float32)
    same = layout.corner_counts == loop_total
    if same.all():
        values[:] = layout.uvs
        return values, 0
    offsets = np.concatenate([[0], np.cumsum(layout.corner_counts, dtype=np.int64)[:-1]])
    counts = loop_total[same].astype(np.int64)
    within = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
    loops = np.repeat(loop_start[same].astype(np.int64), counts) + within
    corners = np.repeat(offsets[same], counts) + within
    values[loops] = layout.uvs[corners]
    return values, int((~same).sum())
