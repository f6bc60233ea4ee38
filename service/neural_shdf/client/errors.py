"""Exceptions of the Python client, one per kind of failure, carrying the service's message.

Every error response of the service has the body ``{"error": {"code", "message", "detail"}}``;
``error_from_response`` turns it into the matching exception, whose ``str()`` is the
service's own message (it says what is wrong and what to do).
"""

from __future__ import annotations

from typing import Any

import httpx

from neural_shdf.errors import NeuralShdfError


class ServiceError(NeuralShdfError):
    """The service answered with an error (or could not be reached).

    Attributes: ``status`` (HTTP status, 0 when no answer came), ``code`` (the service's
    stable error code, e.g. ``invalid_geometry``), ``message``, ``detail`` (structured extra).
    """

    def __init__(self, status: int, code: str, message: str, detail: Any = None) -> None:
        super().__init__(message)
        self.status = status
        self.code = code
        self.message = message
        self.detail = detail

    def __repr__(self) -> str:
        return f"{type(self).__name__}(status={self.status}, code={self.code!r}, {self.message!r})"


class InvalidRequestError(ServiceError, ValueError):
    """400/422: the request or the mesh cannot be used (bad parameter, bad geometry)."""


class NotFoundError(ServiceError, LookupError):
    """404: unknown mesh or job (never uploaded, deleted or evicted: upload it again)."""


class PayloadTooLargeError(ServiceError):
    """413: the upload or the mesh exceeds the service's limits."""


class UnsupportedMediaError(ServiceError):
    """415: the service does not read this mesh format."""


class ServiceUnavailableError(ServiceError):
    """503, or no answer at all (connection refused): still failing after the retries."""


class ServiceTimeoutError(ServiceError, TimeoutError):
    """408/504 or a client-side timeout, still failing after the retries; or a job that did
    not finish in time."""


class JobFailedError(ServiceError):
    """A job (ShDF of a large mesh) ended in state ``failed``; ``code`` and ``message`` are
    the job's error."""


_BY_STATUS: dict[int, type[ServiceError]] = {
    400: InvalidRequestError,
    404: NotFoundError,
    408: ServiceTimeoutError,
    413: PayloadTooLargeError,
    415: UnsupportedMediaError,
    422: InvalidRequestError,
    503: ServiceUnavailableError,
    504: ServiceTimeoutError,
}


def error_from_response(response: httpx.Response) -> ServiceError:
    """The exception for an error response, with the service's code, message and detail."""
    status = response.status_code
    kind = _BY_STATUS.get(status, ServiceError)
    try:
        error = response.json()["error"]
        return kind(status, str(error["code"]), str(error["message"]), error.get("detail"))
    except (ValueError, KeyError, TypeError):
        # Not the service's error shape (a proxy in between, or not this service at all).
        text = response.text.strip().replace("\n", " ")
        shown = text if len(text) <= 200 else text[:200] + "..."
        return kind(status, "http_error", f"HTTP {status} from {response.url}: {shown}")


def error_from_transport(exc: httpx.TransportError, url: str) -> ServiceError:
    """The exception for a request that got no answer (timeout, refused connection)."""
    if isinstance(exc, httpx.TimeoutException):
        return ServiceTimeoutError(
            0, "client_timeout", f"no answer from {url} in time ({type(exc).__name__})"
        )
    return ServiceUnavailableError(
        0, "unreachable", f"cannot reach the service at {url}: {exc or type(exc).__name__}"
    )


def raise_for_error(response: httpx.Response) -> httpx.Response:
    """The response itself when it succeeded, else its exception raised."""
    if response.status_code >= 400:
        raise error_from_response(response)
    return response
