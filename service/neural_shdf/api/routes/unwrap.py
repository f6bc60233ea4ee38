"""UV unwrap by parts: the unwrapped GLB or OBJ, the atlas layout PNG and the UVs per
corner of a stored mesh."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response

from neural_shdf.api.responses import GLB_MEDIA_TYPE, glb_response
from neural_shdf.api.routes.deps import EngineDep
from neural_shdf.api.routes.meshes import MeshId
from neural_shdf.api.routes.segment import SEGMENT_ERRORS
from neural_shdf.api.schemas import UnwrapOptions, UvLayout

router = APIRouter(prefix="/v1", tags=["unwrap"])

PNG_MEDIA_TYPE = "image/png"
OBJ_MEDIA_TYPE = "model/obj"


@router.get(
    "/meshes/{mesh_id}/segmentation/unwrapped.glb",
    operation_id="get_unwrapped_glb",
    summary="UVs charted part by part, packed into one atlas (GLB)",
    response_class=Response,
    responses={
        200: {
            "content": {GLB_MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
            "description": "The mesh's triangles in order with `TEXCOORD_0` and the atlas "
            "layout as the base colour texture.",
        },
        **SEGMENT_ERRORS,
    },
)
async def unwrapped_glb(
    engine: EngineDep, mesh_id: MeshId, options: Annotated[UnwrapOptions, Query()]
) -> Response:
    """Each part of the segmentation is its own chart where its stretch allows (the cached
    ShDF and segmentation are reused; the atlas is cached per parameters)."""
    params, unwrap = options.segment_params(), options.unwrap_params()
    method = await engine.resolved_method(mesh_id, options.method)
    glb = await engine.unwraps.glb(mesh_id, method, params, unwrap)
    return glb_response(glb, mesh_id, "unwrapped")


@router.get(
    "/meshes/{mesh_id}/segmentation/atlas.png",
    operation_id="get_atlas_png",
    summary="The UV atlas layout (PNG)",
    response_class=Response,
    responses={
        200: {
            "content": {PNG_MEDIA_TYPE: {"schema": {"type": "string", "format": "binary"}}},
            "description": "Charts coloured by part under a checker, outlined; white is unused.",
        },
        **SEGMENT_ERRORS,
    },
)
async def atlas_png(
    engine: EngineDep, mesh_id: MeshId, options: Annotated[UnwrapOptions, Query()]
) -> Response:
    """The atlas of ``unwrapped.glb`` with the same parameters, for people to look at."""
    params, unwrap = options.segment_params(), options.unwrap_params()
    method = await engine.resolved_method(mesh_id, options.method)
    png = await engine.unwraps.atlas_png(mesh_id, method, params, unwrap)
    return Response(png, media_type=PNG_MEDIA_TYPE)


@router.get(
    "/meshes/{mesh_id}/segmentation/unwrapped.obj",
    operation_id="get_unwrapped_obj",
    summary="UVs charted part by part, packed into one atlas (OBJ)",
    response_class=Response,
    responses={
        200: {
            "content": {OBJ_MEDIA_TYPE: {"schema": {"type": "string"}}},
            "description": "`v`, `vt` and one `f v/vt` line per input face in the file's "
            "order (a polygon a chart boundary runs through: its triangles, in place).",
        },
        **SEGMENT_ERRORS,
    },
)
async def unwrapped_obj(
    engine: EngineDep, mesh_id: MeshId, options: Annotated[UnwrapOptions, Query()]
) -> Response:
    """The atlas of ``unwrapped.glb`` with the same parameters, as OBJ (polygons kept)."""
    params, unwrap = options.segment_params(), options.unwrap_params()
    method = await engine.resolved_method(mesh_id, options.method)
    obj = await engine.unwraps.obj(mesh_id, method, params, unwrap)
    return Response(
        obj,
        media_type=OBJ_MEDIA_TYPE,
        headers={"Content-Disposition": f'attachment; filename="{mesh_id[:12]}-unwrapped.obj"'},
    )


@router.get(
    "/meshes/{mesh_id}/segmentation/uvs",
    operation_id="get_uvs",
    summary="UVs per corner of every input face",
    response_model=UvLayout,
    responses=SEGMENT_ERRORS,
)
async def uvs(
    engine: EngineDep, mesh_id: MeshId, options: Annotated[UnwrapOptions, Query()]
) -> UvLayout:
    """The atlas of ``unwrapped.glb`` with the same parameters, as UVs per corner of each
    input face in the file's order: for a client that keeps its own mesh (a DCC tool)."""
    params, unwrap = options.segment_params(), options.unwrap_params()
    method = await engine.resolved_method(mesh_id, options.method)
    return UvLayout(**await engine.unwraps.uvs(mesh_id, method, params, unwrap))
