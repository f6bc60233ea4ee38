"""Part labellers: upload, list, read, delete, and train one from stored meshes."""

from __future__ import annotations

import math
import re
from typing import Annotated

import numpy as np
from fastapi import APIRouter, File, Form, Path, Query, Response, UploadFile

from neural_shdf.api.errors import ApiError
from neural_shdf.api.jobs import JobAccepted
from neural_shdf.api.labeling import TrainingRequest
from neural_shdf.api.routes.deps import EngineDep, SingleFormFields, error_responses, read_upload
from neural_shdf.api.schemas import (
    LABELER_ID_EXAMPLE,
    LABELER_ID_PATTERN,
    MESH_ID_PATTERN,
    Job,
    LabelerInfo,
    LabelerList,
    LabelerTrainForm,
)
from neural_shdf.segment.params import MAX_SMOOTHING, check_seed

router = APIRouter(prefix="/v1", tags=["labelers"])

LabelerId = Annotated[
    str,
    Path(
        pattern=LABELER_ID_PATTERN,
        description="Labeller id from the upload (64 hex digits).",
        examples=[LABELER_ID_EXAMPLE],
    ),
]
#: Media type of a labeller file (a NumPy .npz archive).
LABELER_MEDIA_TYPE = "application/x-npz"
#: Labellers per page of ``GET /v1/labelers``: by default and at most.
DEFAULT_PAGE = 100
MAX_PAGE = 1000


@router.post(
    "/labelers",
    operation_id="upload_labeler",
    summary="Upload a part labeller",
    response_model=LabelerInfo,
    dependencies=[SingleFormFields],
    responses=error_responses(400, 408, 413, 422),
)
async def upload_labeler(
    engine: EngineDep,
    file: Annotated[
        UploadFile,
        File(description="A labeller file (`neural-shdf labeler train`, `save_labeler`: .npz)."),
    ],
) -> LabelerInfo:
    """Check the file (size, format, version, checksum, trees; never unpickled) and store
    it under its content id, for `labeler_id` in `POST /v1/segment`."""
    data = await read_upload(file)
    labeler = await engine.run(engine.labelers.parse, data)
    return LabelerInfo(**await engine.io(engine.labelers.store, data, labeler))


@router.get(
    "/labelers",
    operation_id="list_labelers",
    summary="Stored part labellers",
    response_model=LabelerList,
)
async def list_labelers(
    engine: EngineDep,
    offset: Annotated[int, Query(ge=0, description="Labellers to skip (oldest first).")] = 0,
    limit: Annotated[
        int, Query(ge=1, le=MAX_PAGE, description="Labellers in this page at most.")
    ] = DEFAULT_PAGE,
) -> LabelerList:
    """Stored labellers with their label names, oldest first, a page at a time:
    `next_offset` is the next page's `offset` (null after the last page)."""
    entries, total = await engine.io(engine.labelers.list, offset, limit)
    return LabelerList(
        labelers=[LabelerInfo(**m) for m in entries],
        total=total,
        next_offset=offset + limit if offset + limit < total else None,
    )


@router.get(
    "/labelers/{labeler_id}",
    operation_id="get_labeler",
    summary="A part labeller's names and metadata",
    response_model=LabelerInfo,
    responses=error_responses(404),
)
async def get_labeler(engine: EngineDep, labeler_id: LabelerId) -> LabelerInfo:
    """Label names and values, features and training summary of a stored labeller."""
    return LabelerInfo(**await engine.io(engine.labelers.meta, labeler_id))


@router.get(
    "/labelers/{labeler_id}/file",
    operation_id="get_labeler_file",
    summary="Download a part labeller's file",
    response_class=Response,
    responses={
        200: {
            "content": {LABELER_MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
            "description": "The labeller file (.npz), as `labeler train` writes it.",
        },
        **error_responses(404),
    },
)
async def get_labeler_file(engine: EngineDep, labeler_id: LabelerId) -> Response:
    """The stored file, for the CLI's `--labeler` or another service."""
    body = await engine.io(engine.labelers.file, labeler_id)
    disposition = f'attachment; filename="labeler-{labeler_id[:16]}.npz"'
    return Response(
        body, media_type=LABELER_MEDIA_TYPE, headers={"Content-Disposition": disposition}
    )


@router.delete(
    "/labelers/{labeler_id}",
    operation_id="delete_labeler",
    summary="Delete a part labeller",
    status_code=204,
    response_class=Response,
    responses=error_responses(404),
)
async def delete_labeler(engine: EngineDep, labeler_id: LabelerId) -> Response:
    """Delete the labeller for every client (requests naming it then answer 404)."""
    await engine.io(engine.labelers.delete, labeler_id)
    return Response(status_code=204)


def training_request(form: LabelerTrainForm, labels: bytes, max_meshes: int) -> TrainingRequest:
    """The form as a training request; 413 for more than ``max_meshes`` ids (counted before
    any is read), 422 for ids, names or labels that cannot be."""
    if form.mesh_ids.count(",") >= max_meshes:
        raise ApiError(
            413,
            "too_many_meshes",
            f"{form.mesh_ids.count(',') + 1} meshes, at most {max_meshes} per training",
            {"max_train_meshes": max_meshes},
        )
    mesh_ids = tuple(i.strip() for i in form.mesh_ids.split(",") if i.strip())
    pattern = MESH_ID_PATTERN.strip("^$")
    bad = [i for i in mesh_ids if not re.fullmatch(pattern, i)]
    if bad:
        raise ApiError(422, "invalid_parameter", f"not a mesh id (64 hex digits): {bad[0][:80]!r}")
    if len(labels) % 4:
        raise ApiError(
            422,
            "invalid_parameter",
            f"the labels file has {len(labels)} bytes, not a multiple of 4: send one "
            "little-endian int32 per input face",
        )
    names = None
    if form.names is not None:
        names = tuple(name.strip() for name in form.names.split(","))
        if not all(names):
            raise ApiError(422, "invalid_parameter", f"names has an empty name: {form.names!r}")
    return TrainingRequest(
        mesh_ids=mesh_ids,
        labels=np.frombuffer(labels, dtype="<i4").astype(np.int64),
        names=names,
        method=form.method,
        seed=check_seed(form.seed),
        smoothing=form.smoothing,
    )


@router.post(
    "/labeler-trainings",
    operation_id="train_labeler",
    summary="Train a part labeller from stored meshes (a job)",
    status_code=202,
    response_model=Job,
    dependencies=[SingleFormFields],
    responses=error_responses(400, 404, 408, 413, 422, 503),
)
async def train_labeler(
    engine: EngineDep,
    form: Annotated[LabelerTrainForm, Form(media_type="multipart/form-data")],
) -> Response:
    """Train a labeller from uploaded meshes and one integer label per input face; the
    job's `result_url` names the stored labeller once it succeeded. Bounded by the
    service's `max_train_meshes` and `max_train_triangles` (413 before any work)."""
    smoothing = form.smoothing
    if smoothing is not None and not (math.isfinite(smoothing) and 0 <= smoothing <= MAX_SMOOTHING):
        raise ApiError(422, "invalid_parameter", f"smoothing must lie in [0, {MAX_SMOOTHING:g}]")
    labels = await read_upload(form.labels)
    request = training_request(form, labels, engine.settings.max_train_meshes)
    raise JobAccepted(await engine.labelings.start_training(request))
