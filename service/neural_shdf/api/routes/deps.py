"""Dependencies shared by the routes."""

from __future__ import annotations

from collections import Counter
from pathlib import PurePosixPath
from typing import Annotated, Any

from fastapi import Depends, Request, UploadFile

from neural_shdf.api.engine import Engine
from neural_shdf.api.errors import ApiError
from neural_shdf.api.schemas import ErrorResponse


async def get_engine(request: Request) -> Engine:
    """The app's engine (async: FastAPI would run a sync dependency in a thread)."""
    return request.app.state.engine


EngineDep = Annotated[Engine, Depends(get_engine)]


def error_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI entries for the standard error body."""
    text = {
        400: "Malformed request body (not parseable as JSON or multipart).",
        408: "The client stalled while sending the body.",
        404: "Unknown mesh or job.",
        413: "Upload or mesh too large.",
        415: "Unsupported mesh format.",
        422: "Invalid request or unusable mesh (the message says why).",
        503: "The neural model or the cache is unavailable.",
        504: "The computation did not finish within the request timeout.",
    }
    return {s: {"model": ErrorResponse, "description": text.get(s, "Error.")} for s in statuses}


def upload_format(upload: UploadFile, file_type: str | None) -> str | None:
    """The mesh format: explicit, else the file name's extension, else sniffed later (None)."""
    if file_type:
        return file_type  # as given: mesh_io normalises it, or names it in its error
    suffix = PurePosixPath(upload.filename or "").suffix
    return suffix.lower().lstrip(".") or None


async def read_upload(upload: UploadFile) -> bytes:
    """The uploaded bytes (the body size limit was enforced while receiving them)."""
    try:
        return await upload.read()
    finally:
        await upload.close()


async def single_form_fields(request: Request) -> None:
    """422 when a multipart form gives a field twice (two files, say): FastAPI would use
    the last one and drop the others without a word. The form is parsed once (Starlette
    keeps it), so this costs a scan of its field names."""
    form = await request.form()
    counts = {n: c for n, c in Counter(name for name, _ in form.multi_items()).items() if c > 1}
    if counts:
        listed = ", ".join(f"{name!r} {count} times" for name, count in counts.items())
        raise ApiError(
            422,
            "repeated_form_field",
            f"the form gives {listed}; send one mesh file per request (and each option once)",
            {"repeated": counts},
        )


SingleFormFields = Depends(single_form_fields)
