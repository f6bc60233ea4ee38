"""Response bodies: results of the services serialised for the wire."""

from __future__ import annotations

import base64
import json
from typing import Any

import numpy as np
from fastapi import Response
from numpy.typing import NDArray

from neural_shdf.api.labeling import StoredLabels, label_summary
from neural_shdf.api.schemas import MeshInfo, ShdfStatus, ShdfValues, UploadResult
from neural_shdf.api.segmentation import StoredSegmentation, pack_integers
from neural_shdf.api.shdf_service import ShdfOutcome
from neural_shdf.arrays import json_array, json_list
from neural_shdf.labeling.model import Labeler
from neural_shdf.mesh import TriangleMesh
from neural_shdf.palette import part_color_hex

F32_MEDIA_TYPE = "application/octet-stream"
GLB_MEDIA_TYPE = "model/gltf-binary"


def upload_result(
    meta: dict[str, Any], method: str, seed: int, outcome: ShdfOutcome
) -> UploadResult:
    return UploadResult(
        mesh=MeshInfo(**meta),
        shdf=ShdfStatus(
            method=method,  # type: ignore[arg-type]
            seed=seed,
            cached=outcome.cached,
            seconds=round(outcome.seconds, 6),
        ),
    )


def shdf_response(
    mesh_id: str,
    method: str,
    seed: int,
    model_version: str | None,
    values: NDArray[np.float64],
    *,
    binary: bool,
) -> Response:
    """Per-input-face ShDF as JSON (null for faces without triangles) or float32 bytes."""
    headers = {"X-Mesh-Id": mesh_id, "X-Faces": str(len(values))}
    if binary:
        return Response(values.astype("<f4").tobytes(), media_type=F32_MEDIA_TYPE, headers=headers)
    summary = ShdfValues(
        mesh_id=mesh_id,
        method=method,  # type: ignore[arg-type]
        seed=seed,
        model_version=model_version if method == "neural" else None,
        faces=len(values),
        values=[],
    ).model_dump(mode="json", exclude={"values"})
    # The values a chunk at a time (one list of a million floats holds the GIL too long).
    text = json.dumps(summary, separators=(",", ":"))
    array = json_array(np.asarray(values, dtype=np.float64), nan_as_null=True)
    body = f'{{"values":{array},{text[1:]}' if len(text) > 2 else f'{{"values":{array}}}'
    return Response(body.encode(), media_type="application/json", headers=headers)


def segmentation_response(
    mesh_id: str,
    method: str,
    labels_format: str,
    result: StoredSegmentation,
    timings: dict[str, Any],
    tree_of: StoredSegmentation | None = None,
    *,
    source_id: str | None = None,
) -> Response:
    """The `Segmentation` JSON, serialised directly (no per-label model validation).

    ``tree_of``: the result whose ``hierarchy`` to send (an edited result's unedited one).
    ``source_id``: the upload's kept file (``/segment/file``), sent when given.
    """
    compact = labels_format == "base64"
    colors = part_color_hex(len(result.part_faces))
    parts = [
        {"label": i, "faces": int(f), "area": float(a), "mean_shdf": float(m), "color": c}
        for i, (f, a, m, c) in enumerate(
            zip(
                result.part_faces,
                result.part_area,
                result.part_mean_shdf,
                colors,
                strict=True,
            )
        )
    ]
    body = {
        "mesh_id": mesh_id,
        "method": method,
        "faces": len(result.labels),
        "part_count": len(parts),
        "labels_dtype": result.labels_base64[1] if compact else None,
        "timings": timings,
    }
    if source_id is not None:
        body["source_id"] = source_id
    labels = "null" if compact else result.labels_json
    # Base64 needs no JSON escaping: spliced in, not scanned by json.dumps (0.5-1 ms at 100k).
    packed = f'"{result.labels_base64[0]}"' if compact else "null"
    hierarchy = (result if tree_of is None else tree_of).hierarchy_json(compact)
    rest = json.dumps(body, separators=(",", ":"))
    return Response(
        f'{{"labels":{labels},"labels_base64":{packed},"hierarchy":{hierarchy},'
        f'"parts":{json_list(parts)},{rest[1:]}'.encode(),
        media_type="application/json",
    )


def labels_response(
    mesh_id: str,
    method: str,
    labels_format: str,
    labeler_id: str,
    labeler: Labeler,
    mesh: TriangleMesh,
    shdf: NDArray[np.float64],
    result: StoredLabels,
    timings: dict[str, Any],
    *,
    source_id: str | None = None,
) -> Response:
    """The `Segmentation` JSON of named parts: labels in the training labels' integers,
    a part per label present (with its name and colour, the coloured GLB's), the
    labeller's names and the confidence per face (``source_id``: as in
    ``segmentation_response``)."""
    compact = labels_format == "base64"
    values, faces, area, mean = label_summary(mesh, result, shdf)
    names = dict(zip(labeler.label_values.tolist(), labeler.label_names, strict=True))
    top = max([v for v in values if v >= 0], default=-1)
    colors = part_color_hex(top + 1)
    parts = [
        {
            "label": value,
            "faces": int(f),
            "area": float(a),
            "mean_shdf": float(m),
            "color": colors[value] if value >= 0 else "#808080",
            "name": names.get(value, "unlabeled"),
        }
        for value, f, a, m in zip(values, faces, area, mean, strict=True)
    ]
    packed = pack_integers(result.labels) if compact else (None, None)
    confidence = result.confidence.astype("<f4")
    body = {
        "mesh_id": mesh_id,
        "method": method,
        "faces": len(result.labels),
        "part_count": len(parts),
        "labels_base64": packed[0],
        "labels_dtype": packed[1],
        "parts": parts,
        "timings": timings,
        "hierarchy": None,
        "labeler_id": labeler_id,
        "label_names": list(labeler.label_names),
        "label_values": labeler.label_values.tolist(),
        "confidence_base64": base64.b64encode(confidence.tobytes()).decode() if compact else None,
    }
    if source_id is not None:
        body["source_id"] = source_id
    labels = "null" if compact else json_array(result.labels)
    rounded = np.round(confidence.astype(np.float64), 4)  # float32 digits, not float64's
    scores = "null" if compact else json_array(rounded, nan_as_null=True)
    rest = json.dumps(body, separators=(",", ":"))
    return Response(
        f'{{"labels":{labels},"confidence":{scores},{rest[1:]}'.encode(),
        media_type="application/json",
    )


def glb_response(glb: bytes, mesh_id: str, style: str) -> Response:
    return Response(
        glb,
        media_type=GLB_MEDIA_TYPE,
        headers={"Content-Disposition": f'attachment; filename="{mesh_id[:16]}-{style}.glb"'},
    )
