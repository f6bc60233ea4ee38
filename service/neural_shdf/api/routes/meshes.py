"""Upload, read and delete meshes and their ShDF."""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, File, Form, Header, Path, Query, Response, UploadFile

from neural_shdf.api.engine import Engine
from neural_shdf.api.responses import F32_MEDIA_TYPE, shdf_response, upload_result
from neural_shdf.api.routes.deps import (
    EngineDep,
    SingleFormFields,
    error_responses,
    read_upload,
    upload_format,
)
from neural_shdf.api.schemas import (
    MESH_ID_EXAMPLE,
    MESH_ID_PATTERN,
    SEED_BOUNDS,
    Job,
    MeshInfo,
    ShdfMethodName,
    ShdfValues,
    UploadResult,
)
from neural_shdf.api.viewer import display_geometry
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import normalize_format, sniff_format
from neural_shdf.segment.params import check_seed

router = APIRouter(prefix="/v1", tags=["meshes"])

MeshId = Annotated[
    str,
    Path(
        pattern=MESH_ID_PATTERN,
        description="Mesh id from the upload (64 hex digits).",
        examples=[MESH_ID_EXAMPLE],
    ),
]
SEED_DESCRIPTION = "Seed of the ShDF's sampling (the `seed` of a later segmentation)."


async def ingest(
    engine: Engine, upload: UploadFile, file_type: str | None
) -> tuple[dict, TriangleMesh]:
    """Parse and store an uploaded mesh; returns (metadata, mesh)."""
    data = await read_upload(upload)
    fmt = upload_format(upload, file_type)
    mesh = await engine.run(engine.meshes.parse, data, fmt)
    detected = normalize_format(fmt) if fmt else sniff_format(data)
    meta = await engine.io(engine.meshes.store, mesh, detected, upload.filename, data)
    return meta, mesh


@router.post(
    "/meshes",
    operation_id="upload_mesh",
    summary="Upload a mesh and compute its ShDF",
    response_model=UploadResult,
    dependencies=[SingleFormFields],
    responses={
        202: {"model": Job, "description": "Large mesh: the ShDF is computed by a job."},
        **error_responses(400, 408, 413, 415, 422, 503, 504),
    },
)
async def upload_mesh(
    engine: EngineDep,
    file: Annotated[
        UploadFile,
        File(
            description="OBJ, GLB/glTF (embedded buffers), OFF, PLY, STL or USD (.usd, .usda, "
            ".usdc, .usdz; one file or package)."
        ),
    ],
    file_type: Annotated[
        str | None,
        Form(
            description="Format (obj, glb, gltf, off, ply, stl, usd, usda, usdc, usdz); "
            "default: the file extension.",
            examples=["obj"],
        ),
    ] = None,
    method: Annotated[
        ShdfMethodName | None,
        Form(description="ShDF method; default: the service default.", examples=["neural"]),
    ] = None,
    seed: Annotated[
        int, Form(description=SEED_DESCRIPTION, examples=[0], json_schema_extra=SEED_BOUNDS)
    ] = 0,
) -> UploadResult:
    """Store the mesh under its content hash and compute its ShDF once (cached).

    Meshes above the synchronous threshold answer 202 with a job to poll.
    """
    seed = check_seed(seed)
    meta, mesh = await ingest(engine, file, file_type)
    outcome = await engine.shdf.get(meta["mesh_id"], mesh, engine.method_of(method), seed)
    return upload_result(meta, outcome.method, seed, outcome)


@router.get(
    "/meshes/{mesh_id}",
    operation_id="get_mesh",
    summary="Mesh metadata",
    response_model=MeshInfo,
    responses=error_responses(404),
)
async def get_mesh(engine: EngineDep, mesh_id: MeshId) -> MeshInfo:
    """Size, bounds and origin of a stored mesh."""
    return MeshInfo(**await engine.io(engine.meshes.meta, mesh_id))


@router.delete(
    "/meshes/{mesh_id}",
    operation_id="delete_mesh",
    summary="Delete a mesh",
    status_code=204,
    response_class=Response,
    responses=error_responses(404),
)
async def delete_mesh(engine: EngineDep, mesh_id: MeshId) -> Response:
    """Delete the mesh and everything computed from it (ShDF, segmentations, jobs), for
    every client that uploaded it. Final: a computation still running for it stores
    nothing (its request or job answers 404), and the mesh uploaded again starts afresh."""
    await engine.io(engine.meshes.delete, mesh_id)
    return Response(status_code=204)


@router.get(
    "/meshes/{mesh_id}/shdf",
    operation_id="get_shdf",
    summary="Per-face ShDF",
    response_model=ShdfValues,
    responses={
        200: {
            "content": {F32_MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
            "description": "JSON, or float32 little-endian per input face (NaN: face without "
            "triangles) with `format=f32` or `Accept: application/octet-stream`.",
        },
        202: {"model": Job, "description": "Large mesh: the ShDF is being computed by a job."},
        **error_responses(404, 503, 504),
    },
)
async def get_shdf(
    engine: EngineDep,
    mesh_id: MeshId,
    method: Annotated[ShdfMethodName | None, Query(description="ShDF method.")] = None,
    seed: Annotated[int, Query(description=SEED_DESCRIPTION, json_schema_extra=SEED_BOUNDS)] = 0,
    format: Annotated[  # noqa: A002 - the query parameter's public name
        Literal["json", "f32"] | None,
        Query(description="`json` or `f32` (binary); default: from the Accept header."),
    ] = None,
    accept: Annotated[str | None, Header(include_in_schema=False)] = None,
) -> Response:
    """The ShDF in [0, 1] per input face, computed once and cached."""
    seed = check_seed(seed)
    mesh = await engine.io(engine.meshes.load, mesh_id)
    outcome = await engine.shdf.get(mesh_id, mesh, engine.method_of(method), seed)
    values = await engine.io(mesh.to_input_faces, outcome.values)
    binary = format == "f32" or (format is None and F32_MEDIA_TYPE in (accept or ""))
    version = engine.shdf.model_version
    return await engine.io(
        shdf_response, mesh_id, outcome.method, seed, version, values, binary=binary
    )


@router.get(
    "/meshes/{mesh_id}/geometry",
    operation_id="get_geometry",
    summary="Triangles for display",
    response_class=Response,
    responses={
        200: {
            "content": {F32_MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
            "description": "Little-endian binary: a 20-byte header (`NSHG`, uint32 version 1, "
            "vertex count V, triangle count T, input face count F), float32 positions (V, 3), "
            "uint32 triangle corners (T, 3), uint32 input face of each triangle (T).",
        },
        **error_responses(404),
    },
)
async def get_geometry(engine: EngineDep, mesh_id: MeshId) -> Response:
    """The stored triangles in the service's order, each with the input face it came from,
    so a viewer can colour them by per-input-face labels or ShDF values."""
    mesh = await engine.io(engine.meshes.load, mesh_id)
    body = await engine.io(display_geometry, mesh)
    headers = {"X-Mesh-Id": mesh_id, "X-Faces": str(mesh.input_face_count)}
    return Response(body, media_type=F32_MEDIA_TYPE, headers=headers)
