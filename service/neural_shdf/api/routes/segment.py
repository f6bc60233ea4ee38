"""Segmentation: labels JSON, coloured GLB, parts GLB, parts USD."""

from __future__ import annotations

import functools
import time
from typing import Annotated, Any

from fastapi import APIRouter, Form, Query, Response

from neural_shdf.api.editing import edited_result
from neural_shdf.api.engine import Engine
from neural_shdf.api.errors import ApiError
from neural_shdf.api.jobs import JobAccepted
from neural_shdf.api.responses import (
    GLB_MEDIA_TYPE,
    glb_response,
    labels_response,
    segmentation_response,
)
from neural_shdf.api.routes.deps import EngineDep, SingleFormFields, error_responses
from neural_shdf.api.routes.meshes import MeshId, ingest
from neural_shdf.api.schemas import (
    MESH_ID_PATTERN,
    Job,
    LabeledSegmentOptions,
    Segmentation,
    SegmentFileForm,
    SegmentOptions,
    SegmentRequest,
)
from neural_shdf.segment import SegmentParams

router = APIRouter(prefix="/v1", tags=["segmentation"])

#: Header of ``/segment/file``'s answers (200 and 202) naming the upload's kept file.
SOURCE_ID_HEADER = "X-Source-Id"

SEGMENT_ERRORS = {
    202: {
        "model": Job,
        "description": "Large mesh whose ShDF is not cached yet: poll the job, "
        "then repeat the request.",
    },
    **error_responses(400, 404, 408, 413, 415, 422, 503, 504),
}


async def segment_response(
    engine: Engine,
    mesh_id: str,
    options: SegmentOptions,
    params: SegmentParams,
    edits: list[dict[str, Any]] | None = None,
    *,
    source_id: str | None = None,
) -> Response:
    """The segmentation (or the named parts) of a stored mesh as the `Segmentation` JSON;
    ``source_id``: an upload's own file, named in the answer (``/segment/file``)."""
    method = await engine.resolved_method(mesh_id, options.method)
    if isinstance(options, LabeledSegmentOptions) and options.labeler_id is not None:
        if edits:
            raise ApiError(
                422,
                "invalid_parameter",
                "edits cannot be combined with labeler_id: named parts are not edited",
            )
        return await labeled_response(
            engine, mesh_id, method, options, options.labeler_id, source_id=source_id
        )
    result, timings = await engine.segmentations.get(mesh_id, method, params)
    tree_of = None
    if edits:
        start = time.perf_counter()
        mesh = await engine.io(engine.meshes.load, mesh_id)
        shdf = await engine.shdf.get(mesh_id, mesh, method, params.seed)
        tree_of = result
        result = await engine.run(edited_result, result, mesh, shdf.values, edits, params.seed)
        timings = {**timings, "total_ms": timings["total_ms"] + _ms_since(start)}
    # Serialising a million labels takes a while: never on the event loop.
    return await engine.io(
        functools.partial(segmentation_response, source_id=source_id),
        mesh_id, method, options.labels_format, result, timings, tree_of,
    )  # fmt: skip


async def labeled_response(
    engine: Engine,
    mesh_id: str,
    method: str,
    options: SegmentOptions,
    labeler_id: str,
    *,
    source_id: str | None = None,
) -> Response:
    """Named parts of a stored mesh by a stored labeller, from its cached ShDF."""
    result, labeler, shdf, timings = await engine.labelings.get(
        mesh_id, method, options.seed, labeler_id
    )
    mesh = await engine.io(engine.meshes.load, mesh_id)
    return await engine.io(
        functools.partial(labels_response, source_id=source_id),
        mesh_id,
        method,
        options.labels_format,
        labeler_id,
        labeler,
        mesh,
        shdf,
        result,
        timings,
    )


def _ms_since(start: float) -> float:
    return round((time.perf_counter() - start) * 1000, 3)


@router.post(
    "/segment",
    operation_id="segment_mesh",
    summary="Segment a stored mesh",
    response_model=Segmentation,
    responses=SEGMENT_ERRORS,
)
async def segment_mesh(engine: EngineDep, request: SegmentRequest) -> Response:
    """Part label per input face from the cached ShDF; only the partitioning runs.
    With ``edits``, the labels and parts are those of the edited segmentation."""
    params = request.segment_params()
    edits = None if request.edits is None else [e.model_dump() for e in request.edits]
    return await segment_response(engine, request.mesh_id, request, params, edits)


@router.post(
    "/segment/file",
    operation_id="segment_file",
    summary="Upload and segment a mesh in one call",
    response_model=Segmentation,
    dependencies=[SingleFormFields],
    responses=SEGMENT_ERRORS,
)
async def segment_file(
    engine: EngineDep,
    form: Annotated[SegmentFileForm, Form(media_type="multipart/form-data")],
) -> Response:
    """Store the mesh, compute (or reuse) its ShDF and segment it. The upload's own file is
    kept with the mesh like an upload's (OBJ, PLY, glTF/GLB, USD): its `source_id` is in
    the answer, and in the `X-Source-Id` header (also of a 202 answer)."""
    params = form.segment_params()  # bad parameters fail before the upload is parsed
    meta, _ = await ingest(engine, form.file, form.file_type)
    source_id = meta.get("source_id")
    headers = {SOURCE_ID_HEADER: source_id} if source_id else {}
    try:
        response = await segment_response(
            engine, meta["mesh_id"], form, params, source_id=source_id
        )
    except JobAccepted as accepted:
        accepted.headers.update(headers)
        raise
    response.headers.update(headers)
    return response


SourceId = Annotated[
    str | None,
    Query(
        pattern=MESH_ID_PATTERN,
        description="`source_id` of an upload of this mesh (its answer's `mesh.source_id`): "
        "write the parts into that file's own kind of content (normals, UVs, colours, "
        "materials and objects kept; a USD file's own stage).",
    ),
]


def _glb_route(style: str):  # noqa: ANN202 - FastAPI endpoint factory
    if style == "colored":

        async def colored(
            engine: EngineDep, mesh_id: MeshId, options: Annotated[LabeledSegmentOptions, Query()]
        ) -> Response:
            params = options.segment_params()
            method = await engine.resolved_method(mesh_id, options.method)
            if options.labeler_id is not None:
                glb = await engine.labelings.glb(
                    mesh_id, method, options.seed, options.labeler_id, style
                )
            else:
                glb = await engine.segmentations.glb(mesh_id, method, params, style)
            return glb_response(glb, mesh_id, style)

        return colored

    async def parts(
        engine: EngineDep,
        mesh_id: MeshId,
        options: Annotated[LabeledSegmentOptions, Query()],
        source: SourceId = None,
    ) -> Response:
        params = options.segment_params()
        method = await engine.resolved_method(mesh_id, options.method)
        if options.labeler_id is not None:
            glb = await engine.labelings.glb(
                mesh_id, method, options.seed, options.labeler_id, style
            )
            return glb_response(glb, mesh_id, style)
        glb = await engine.segmentations.glb(mesh_id, method, params, style, source)
        return glb_response(glb, mesh_id, style)

    return parts


_GLB_RESPONSES = {
    200: {
        "content": {GLB_MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
        "description": "Binary glTF.",
    },
    **SEGMENT_ERRORS,
}
router.add_api_route(
    "/meshes/{mesh_id}/segmentation/colored.glb",
    _glb_route("colored"),
    methods=["GET"],
    operation_id="get_colored_glb",
    summary="Segmentation as a coloured GLB",
    description="The mesh with one vertex colour per part (parts do not share vertices).",
    response_class=Response,
    responses=_GLB_RESPONSES,
)
router.add_api_route(
    "/meshes/{mesh_id}/segmentation/parts.glb",
    _glb_route("parts"),
    methods=["GET"],
    operation_id="get_parts_glb",
    summary="Segmentation as one mesh per part",
    description="A GLB scene with one node and mesh per part, named `part_000`, `part_001`, "
    "...; with `source`, the parts keep that upload's normals, UV sets, vertex colours and "
    "materials, under one node per object of its scene (name and transform kept); with "
    "`labeler_id`, one per label present, named by "
    "the label's name (`source` is not used then).",
    response_class=Response,
    responses=_GLB_RESPONSES,
)


#: Media type of USD text layers (IANA ``model/vnd.usda``).
USDA_MEDIA_TYPE = "model/vnd.usda"


@router.get(
    "/meshes/{mesh_id}/segmentation/parts.usda",
    operation_id="get_parts_usda",
    summary="Segmentation as a USD stage with one GeomSubset per part",
    description="With the `source` of a USD upload: that file's own stage (prims, "
    "transforms, UVs, normals, materials kept) with, on every mesh prim, one `GeomSubset` "
    "per part (family `part`, named `part_000`, ...) and a per-face "
    "`primvars:displayColor`. Otherwise a USD layer with one Mesh prim `/World/Mesh` whose "
    "faces are the input faces (in input order; faces without triangles are left out), "
    "with the same subsets and colours. With `labeler_id`: a new stage, subsets named by "
    "label, each with a material of the label's name and colour.",
    response_class=Response,
    responses={
        200: {
            "content": {USDA_MEDIA_TYPE: {"schema": {"type": "string"}}},
            "description": "USD text layer (.usda).",
        },
        **SEGMENT_ERRORS,
    },
)
async def get_parts_usda(
    engine: EngineDep,
    mesh_id: MeshId,
    options: Annotated[LabeledSegmentOptions, Query()],
    source: SourceId = None,
) -> Response:
    """The segmentation as USD: the uploaded USD file's own stage, or a new one."""
    params = options.segment_params()
    method = await engine.resolved_method(mesh_id, options.method)
    if options.labeler_id is not None:
        body = await engine.labelings.usda(mesh_id, method, options.seed, options.labeler_id)
    else:
        body = await engine.segmentations.usda(mesh_id, method, params, source)
    disposition = f'attachment; filename="{mesh_id[:16]}-parts.usda"'
    return Response(body, media_type=USDA_MEDIA_TYPE, headers={"Content-Disposition": disposition})
