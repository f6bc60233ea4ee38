"""HTTP calls to a neural-shdf service with urllib only (Blender's Python has no httpx).

No bpy here: the calls run on a worker thread, and the module is usable (and tested) outside
Blender. Each request is retried with backoff on 502/503/504 and on timeouts; error answers
become ``ServiceError`` carrying the service's own message.
"""

from __future__ import annotations

import base64
import json
import sys
import threading
import time
import urllib.error
import urllib.request
import uuid
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

RETRY_STATUSES = frozenset({502, 503, 504})
#: Array type codes of the service's ``labels_dtype`` (little-endian on the wire).
_TYPECODES = {"int8": "b", "int16": "h", "int32": "i"}

Progress = Callable[[float, str], None]


class ServiceError(Exception):
    """The service answered with an error, or could not be reached; ``str()`` says what to do."""

    def __init__(self, message: str, code: str = "error", status: int = 0) -> None:
        super().__init__(message)
        self.message = message
        self.code = code
        self.status = status


class Cancelled(Exception):  # noqa: N818 - a signal, not a failure
    """The user cancelled the segmentation."""


@dataclass
class Outcome:
    """A segmentation: the service's mesh id, one label per uploaded polygon, part summaries."""

    mesh_id: str
    labels: array
    parts: list[dict[str, Any]]
    uploaded: bool
    timings: dict[str, float] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def part_count(self) -> int:
        return len(self.parts)

    @property
    def named(self) -> bool:
        """Named parts by a labeller: ``labels`` hold its integers, ``parts`` its names."""
        return bool(self.extra.get("labeler_id"))

    def part_indices(self) -> array:
        """Index of each polygon's part in ``parts`` (-1: none): the labels themselves for
        a segmentation, the labeller's integers mapped for named parts."""
        if not self.named:
            return self.labels
        index = {int(part["label"]): i for i, part in enumerate(self.parts)}
        return array("i", (index.get(value, -1) for value in self.labels))


def decode_labels(body: dict[str, Any]) -> array:
    """The labels of a segmentation response (base64 little-endian integers, or a JSON list)."""
    packed = body.get("labels_base64")
    if packed is None:
        return array("i", body["labels"])
    values = array(_TYPECODES[body["labels_dtype"]])
    values.frombytes(base64.b64decode(packed))
    if sys.byteorder == "big":
        values.byteswap()
    return values if values.typecode == "i" else array("i", values)


def multipart(
    fields: dict[str, str], filename: str, content: bytes, file_field: str = "file"
) -> tuple[bytes, str]:
    """A multipart/form-data body with ``fields`` and one file part named ``file_field``."""
    boundary = uuid.uuid4().hex
    parts = []
    for name, value in fields.items():
        parts.append(
            f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"\r\n\r\n{value}\r\n'
        )
    head = "".join(parts) + (
        f'--{boundary}\r\nContent-Disposition: form-data; name="{file_field}"; '
        f'filename="{filename}"\r\n'
        "Content-Type: application/octet-stream\r\n\r\n"
    )
    body = head.encode() + content + f"\r\n--{boundary}--\r\n".encode()
    return body, f"multipart/form-data; boundary={boundary}"


def error_message(status: int, body: bytes, url: str) -> ServiceError:
    """The service's ``{"error": {"code", "message"}}``, else the raw answer, as an error."""
    try:
        error = json.loads(body)["error"]
        return ServiceError(str(error["message"]), str(error["code"]), status)
    except (ValueError, KeyError, TypeError):
        text = body[:200].decode("utf-8", "replace").strip()
        return ServiceError(f"HTTP {status} from {url}: {text}", "http_error", status)


class Session:
    """Requests to one service; ``cancel`` (an Event) stops waits between requests."""

    def __init__(
        self,
        base_url: str,
        *,
        timeout_s: float = 180.0,
        retries: int = 3,
        backoff_s: float = 0.5,
        poll_s: float = 0.25,
        cancel: threading.Event | None = None,
    ) -> None:
        self.base_url = base_url.strip().rstrip("/")
        if not self.base_url.startswith(("http://", "https://")):
            raise ServiceError(
                f"the server URL {base_url!r} must start with http:// or https://", "bad_url"
            )
        self.timeout_s = timeout_s
        self.retries = retries
        self.backoff_s = backoff_s
        self.poll_s = poll_s
        self.cancel = cancel or threading.Event()

    # -- plumbing --------------------------------------------------------------------------
    def pause(self, seconds: float) -> None:
        if self.cancel.wait(seconds):
            raise Cancelled()

    def request(
        self, method: str, path: str, body: bytes | None = None, content_type: str | None = None
    ) -> tuple[int, bytes]:
        """(status, body) of a request; 4xx/5xx raise ServiceError after the retries."""
        url = self.base_url + path
        headers = {"Accept": "application/json"}
        if content_type:
            headers["Content-Type"] = content_type
        for attempt in range(self.retries + 1):
            if self.cancel.is_set():
                raise Cancelled()
            last = attempt == self.retries
            try:
                call = urllib.request.Request(url, data=body, headers=headers, method=method)
                with urllib.request.urlopen(call, timeout=self.timeout_s) as response:
                    return response.status, response.read()
            except urllib.error.HTTPError as exc:
                answer = exc.read()
                if exc.code not in RETRY_STATUSES or last:
                    raise error_message(exc.code, answer, url) from None
            except TimeoutError as exc:
                if last:
                    raise ServiceError(
                        f"the service at {self.base_url} did not answer within "
                        f"{self.timeout_s:g} s ({exc})",
                        "timeout",
                    ) from None
            except urllib.error.URLError as exc:
                if last:
                    raise ServiceError(
                        f"cannot reach the neural-shdf service at {self.base_url} "
                        f"({exc.reason}); start it with 'neural-shdf serve' or fix the server URL",
                        "unreachable",
                    ) from None
            self.pause(min(self.backoff_s * 2**attempt, 8.0))
        raise AssertionError("unreachable")

    def json(
        self, method: str, path: str, payload: dict[str, Any] | None = None
    ) -> tuple[int, Any]:
        body = None if payload is None else json.dumps(payload).encode()
        status, answer = self.request(method, path, body, "application/json" if body else None)
        return status, json.loads(answer)

    # -- calls ------------------------------------------------------------------------------
    def wait_job(self, job: dict[str, Any], progress: Progress) -> dict[str, Any]:
        """Poll a job (a large mesh's ShDF or atlas, a labeller's training) until it
        succeeded; ServiceError if it failed."""
        kind = job.get("kind", "shdf")
        what = {"shdf": "computing the ShDF", "labeler": "training the labeller"}.get(
            kind, "unwrapping"
        )
        while job["state"] not in ("succeeded", "failed"):
            progress(float(job.get("progress", 0.0)), f"{what} ({job['method']})")
            self.pause(self.poll_s)
            _, job = self.json("GET", f"/v1/jobs/{job['job_id']}")
        if job["state"] == "failed":
            error = job.get("error") or {}
            raise ServiceError(error.get("message", "the job failed"), error.get("code", "failed"))
        progress(
            1.0, {"shdf": "ShDF computed", "labeler": "labeller trained"}.get(kind, "unwrapped")
        )
        return job

    def upload_mesh(self, payload: bytes, filename: str, progress: Progress) -> str:
        """Store a mesh on the service (its ShDF computed, a large mesh's job waited for);
        its mesh id."""
        progress(0.0, f"uploading {len(payload) / 1e6:.1f} MB")
        body, content_type = multipart({}, filename, payload)
        status, answer = self.request("POST", "/v1/meshes", body, content_type)
        result = json.loads(answer)
        if status == 202:
            return str(self.wait_job(result, progress)["mesh_id"])
        return str(result["mesh"]["mesh_id"])

    def upload_labeler(self, data: bytes, filename: str) -> dict[str, Any]:
        """Store a labeller file on the service (checked there); its description."""
        body, content_type = multipart({}, filename, data)
        _, answer = self.request("POST", "/v1/labelers", body, content_type)
        return json.loads(answer)

    def train_labeler(
        self,
        mesh_ids: list[str],
        labels: array,
        names: list[str] | None,
        options: dict[str, Any],
        progress: Progress,
    ) -> dict[str, Any]:
        """Train a labeller from stored meshes and one label per polygon of each (``labels``:
        all meshes' labels, one after the other); waits for the job; its description."""
        fields = {"mesh_ids": ",".join(mesh_ids)}
        if names:
            fields["names"] = ",".join(names)
        fields.update({k: str(v) for k, v in options.items() if k in ("method", "seed")})
        values = array("i", labels)
        if sys.byteorder == "big":
            values.byteswap()
        body, content_type = multipart(fields, "labels.i32", values.tobytes(), "labels")
        _, answer = self.request("POST", "/v1/labeler-trainings", body, content_type)
        job = self.wait_job(json.loads(answer), progress)
        _, info = self.json("GET", job["result_url"])
        return info

    def labeler_file(self, labeler_id: str) -> bytes:
        """A stored labeller's file."""
        return self.request("GET", f"/v1/labelers/{labeler_id}/file")[1]

    def segment_by_id(
        self, mesh_id: str, options: dict[str, Any], progress: Progress
    ) -> dict[str, Any]:
        """Segment a stored mesh; a 202 (its ShDF needs a job) is waited for, then repeated."""
        payload = {"mesh_id": mesh_id, **options, "labels_format": "base64"}
        for _ in range(3):
            status, body = self.json("POST", "/v1/segment", payload)
            if status != 202:
                return body
            self.wait_job(body, progress)
        raise ServiceError("the segmentation kept answering 202 after its job finished", "loop")

    def segment(
        self,
        payload: bytes,
        filename: str,
        options: dict[str, Any],
        progress: Progress,
        mesh_id: str | None = None,
    ) -> Outcome:
        """Labels for a mesh file: by ``mesh_id`` when the service still has it (no upload),
        else uploaded and segmented in one call."""
        start = time.perf_counter()
        if mesh_id:
            progress(0.0, "segmenting")
            try:
                body = self.segment_by_id(mesh_id, options, progress)
                return self._outcome(body, uploaded=False, start=start)
            except ServiceError as error:
                if error.status != 404:  # evicted or deleted: upload again
                    raise
        progress(0.0, f"uploading {len(payload) / 1e6:.1f} MB")
        fields = {k: json.dumps(v) if isinstance(v, bool) else str(v) for k, v in options.items()}
        fields["labels_format"] = "base64"
        body_bytes, content_type = multipart(fields, filename, payload)
        status, answer = self.request("POST", "/v1/segment/file", body_bytes, content_type)
        body = json.loads(answer)
        if status == 202:
            job = self.wait_job(body, progress)
            progress(1.0, "segmenting")
            body = self.segment_by_id(job["mesh_id"], options, progress)
        return self._outcome(body, uploaded=True, start=start)

    @staticmethod
    def _outcome(body: dict[str, Any], *, uploaded: bool, start: float) -> Outcome:
        labels = decode_labels(body)
        if len(labels) != body["faces"]:
            raise ServiceError(f"the service sent {len(labels)} labels for {body['faces']} faces")
        known = {"mesh_id", "labels", "labels_base64", "labels_dtype", "parts", "timings"}
        timings = dict(body.get("timings") or {})
        timings["round_trip_ms"] = (time.perf_counter() - start) * 1000
        return Outcome(
            mesh_id=body["mesh_id"],
            labels=labels,
            parts=list(body["parts"]),
            uploaded=uploaded,
            timings=timings,
            extra={k: v for k, v in body.items() if k not in known},
        )
