"""One JSON error shape everywhere: ``{"error": {"code", "message", "detail"}}``."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from neural_shdf.errors import (
    InvalidGeometryError,
    MeshError,
    MeshParseError,
    MeshTooLargeError,
    ModelUnavailableError,
    ParameterError,
    UnsupportedFormatError,
)
from neural_shdf.labeling.model import LabelerFileError

logger = logging.getLogger(__name__)

#: Validation problems listed in a 422 (the message gives their count): a body with
#: thousands of unknown keys must not get an answer thousands of times its size.
MAX_REPORTED_PROBLEMS = 20


class ApiError(StarletteHTTPException):
    """An error answered with ``status`` and the standard JSON body.

    It derives from HTTPException so FastAPI passes it through unchanged even when
    it is raised while the request body is being parsed.
    """

    def __init__(self, status: int, code: str, message: str, detail: Any = None) -> None:
        super().__init__(status_code=status, detail=message)
        self.code = code
        self.message = message
        self.extra = detail


def error_body(code: str, message: str, detail: Any = None) -> dict[str, Any]:
    return {"error": {"code": code, "message": message, "detail": detail}}


def error_response(status: int, code: str, message: str, detail: Any = None) -> JSONResponse:
    return JSONResponse(jsonable_encoder(error_body(code, message, detail)), status_code=status)


def not_found(what: str, identifier: str) -> ApiError:
    return ApiError(404, f"{what}_not_found", f"no {what} with id {identifier!r}")


def payload_too_large(limit: int, *, json: bool = False) -> ApiError:
    if json:
        return ApiError(
            413,
            "payload_too_large",
            f"the JSON request body exceeds the limit of {limit} bytes; a request names a "
            "mesh id and a few options (upload meshes as multipart/form-data)",
            {"max_json_bytes": limit},
        )
    return ApiError(
        413,
        "payload_too_large",
        f"the request body exceeds the limit of {limit} bytes; "
        "simplify the mesh or use a compact binary format (PLY, GLB, STL)",
        {"max_upload_bytes": limit},
    )


_MESH_ERRORS: list[tuple[type[Exception], int, str]] = [
    (UnsupportedFormatError, 415, "unsupported_format"),
    (MeshTooLargeError, 413, "mesh_too_large"),
    (MeshParseError, 422, "mesh_parse_error"),
    (InvalidGeometryError, 422, "invalid_geometry"),
    (MeshError, 422, "invalid_mesh"),
    (LabelerFileError, 422, "invalid_labeler"),
    (ParameterError, 422, "invalid_parameter"),
    (ModelUnavailableError, 503, "model_unavailable"),
]

_STATUS_CODES = {
    400: "bad_request",
    404: "not_found",
    405: "method_not_allowed",
    406: "not_acceptable",
    413: "payload_too_large",
    415: "unsupported_media_type",
}


def classify(exc: BaseException) -> tuple[int, str, str]:
    """HTTP status, error code and message of a library or API error."""
    if isinstance(exc, ApiError):
        return exc.status_code, exc.code, exc.message
    for kind, status, code in _MESH_ERRORS:
        if isinstance(exc, kind):
            return status, code, str(exc)
    if isinstance(exc, TimeoutError):
        return 504, "timeout", "the computation did not finish within the request timeout"
    return 500, "internal_error", "internal error; the failure was logged"


def error_detail(exc: BaseException) -> Any:
    """Structured detail of an error: an ApiError's extra, the limit a mesh exceeded."""
    if isinstance(exc, ApiError):
        return exc.extra
    if isinstance(exc, MeshTooLargeError):
        return exc.detail()
    return None


def error_dict(exc: BaseException) -> dict[str, Any]:
    """The inner error object for an exception (used in job records too)."""
    _, code, message = classify(exc)
    return {"code": code, "message": message, "detail": error_detail(exc)}


def allowed_methods(app: FastAPI, path: str) -> list[str]:
    """Every method some route serves at ``path``."""
    methods: set[str] = set()
    for route in app.routes:
        regex = getattr(route, "path_regex", None)
        if regex is not None and regex.match(path):
            methods |= set(getattr(route, "methods", None) or ())
    return sorted(methods)


def install_error_handlers(app: FastAPI) -> None:
    """Route every failure, including FastAPI's own, through the standard shape."""

    async def api_error(_: Request, exc: Exception) -> JSONResponse:
        status, code, message = classify(exc)
        if status >= 500:
            logger.exception("request failed", exc_info=exc)
        return error_response(status, code, message, error_detail(exc))

    async def http_error(request: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, StarletteHTTPException)
        status = exc.status_code
        code = _STATUS_CODES.get(status, "http_error")
        response = error_response(status, code, str(exc.detail))
        if exc.headers:
            response.headers.update(exc.headers)
        if status == 405:  # Starlette names only the first matching route's methods
            response.headers["Allow"] = ", ".join(allowed_methods(app, request.url.path))
        return response

    async def validation_error(_: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, RequestValidationError)
        malformed = next((e for e in exc.errors() if e.get("type") == "json_invalid"), None)
        if malformed is not None:  # not JSON at all: a malformed body (400), not a bad value
            reason = (malformed.get("ctx") or {}).get("error") or "it does not parse"
            position = malformed.get("loc", ("body", None))[-1]
            where = f" at character {position}" if isinstance(position, int) else ""
            return error_response(
                400,
                "malformed_json",
                f"the request body is not valid JSON: {reason}{where}; send a JSON object "
                "with content-type application/json",
            )
        errors = exc.errors()
        problems = [
            {"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
            for e in errors[:MAX_REPORTED_PROBLEMS]
        ]
        summary = "; ".join(
            f"{'.'.join(str(p) for p in item['loc'])}: {item['msg']}" for item in problems[:5]
        )
        if len(errors) > len(problems):
            summary += f" ({len(errors)} problems; the first {len(problems)} are in detail)"
        return error_response(422, "validation_error", f"invalid request: {summary}", problems)

    app.add_exception_handler(ApiError, api_error)
    app.add_exception_handler(MeshError, api_error)
    app.add_exception_handler(ParameterError, api_error)
    app.add_exception_handler(ModelUnavailableError, api_error)
    app.add_exception_handler(TimeoutError, api_error)
    app.add_exception_handler(StarletteHTTPException, http_error)
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(Exception, api_error)


class BodySizeLimitMiddleware:
    """Reject bodies over ``limit`` bytes (by Content-Length up front, else while reading)
    and clients that stall for ``read_timeout_s`` between two body chunks (408). JSON
    bodies (requests, never meshes) have their own, small ``json_limit``: parsing and
    validating them runs on the event loop, so their size bounds that time."""

    def __init__(
        self,
        app: ASGIApp,
        limit: int,
        read_timeout_s: float = 60.0,
        json_limit: int | None = None,
    ) -> None:
        self.app = app
        self.limit = limit
        self.read_timeout_s = read_timeout_s
        self.json_limit = limit if json_limit is None else min(json_limit, limit)

    def _limit_of(self, headers: list[tuple[bytes, bytes]]) -> tuple[int, int, bool]:
        """(the limit for this body, its declared length or -1, whether it is JSON)."""
        limit, declared, is_json = self.limit, -1, False
        for name, value in headers:
            if name == b"content-length":
                try:
                    declared = int(value)
                except ValueError:
                    declared = -1
            elif name == b"content-type" and b"json" in value.split(b";")[0].lower():
                limit, is_json = self.json_limit, True
        return limit, declared, is_json

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit, declared, is_json = self._limit_of(scope.get("headers", []))
        if declared > limit:
            err = payload_too_large(limit, json=is_json)
            response = error_response(413, err.code, err.message, err.extra)
            response.headers["Connection"] = "close"
            await response(scope, receive, send)
            return
        received = 0
        body_done = False

        async def limited_receive() -> Message:
            nonlocal received, body_done
            if body_done:  # after the body, receive() waits for a disconnect: no timeout
                return await receive()
            try:
                message = await asyncio.wait_for(receive(), self.read_timeout_s)
            except TimeoutError:
                raise ApiError(
                    408,
                    "request_timeout",
                    f"the request body stalled for more than {self.read_timeout_s:g} s",
                ) from None
            if message["type"] == "http.request":
                body_done = not message.get("more_body", False)
                received += len(message.get("body", b""))
                if received > limit:
                    raise payload_too_large(limit, json=is_json)
            return message

        await self.app(scope, limited_receive, send)
