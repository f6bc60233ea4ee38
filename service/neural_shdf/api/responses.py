"""Response bodies: results of the services serialised for the wire."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from fastapi import Response
from numpy.typing import NDArray

from neural_shdf.api.schemas import MeshInfo, ShdfStatus, ShdfValues, UploadResult
from neural_shdf.api.segmentation import StoredSegmentation
from neural_shdf.api.shdf_service import ShdfOutcome
from neural_shdf.arrays import json_array, json_list
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
) -> Response:
    """The `Segmentation` JSON, serialised directly (no per-label model validation).

    ``tree_of``: the result whose ``hierarchy`` to send (an edited result's unedited one).
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
        "labels_base64": result.labels_base64[0] if compact else None,
        "labels_dtype": result.labels_base64[1] if compact else None,
        "timings": timings,
    }
    labels = "null" if compact else result.labels_json
    hierarchy = (result if tree_of is None else tree_of).hierarchy_json(compact)
    rest = json.dumps(body, separators=(",", ":"))
    return Response(
        f'{{"labels":{labels},"hierarchy":{hierarchy},"parts":{json_list(parts)},{rest[1:]}'.encode(),
        media_type="application/json",
    )


def glb_response(glb: bytes, mesh_id: str, style: str) -> Response:
    return Response(
        glb,
        media_type=GLB_MEDIA_TYPE,
        headers={"Content-Disposition": f'attachment; filename="{mesh_id[:16]}-{style}.glb"'},
    )
