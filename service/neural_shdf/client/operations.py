"""What each client call does, written once for the sync and the async client (sans I/O).

An operation is a generator: it yields ``Call`` (send this request, send me the response)
or ``Pause`` (wait this long), and returns the typed result. ``Client`` and ``AsyncClient``
only drive these generators with their own transport and sleep, and add retries with
backoff (``RetryPolicy``) around each call.
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys
import time
from collections.abc import Generator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypedDict

import httpx

from neural_shdf.client.errors import JobFailedError, ServiceTimeoutError, raise_for_error
from neural_shdf.client.results import (
    Job,
    LabelerInfo,
    MeshInfo,
    Segmentation,
    ShdfStatus,
    Upload,
    decode_shdf,
)

#: Statuses worth repeating a request for: the service is busy, restarting, or a computation
#: outlived the request timeout (it goes on in the background and is cached).
RETRY_STATUSES = frozenset({502, 503, 504})
#: How many times a request that answered 202 (a job) is repeated after the job finished.
MAX_JOB_ROUNDS = 3


@dataclass(frozen=True)
class Call:
    """One HTTP request of an operation."""

    method: str
    path: str
    params: Mapping[str, Any] | None = None
    json: Mapping[str, Any] | None = None
    data: Mapping[str, Any] | None = None
    files: Mapping[str, tuple[str, bytes]] | None = None
    headers: Mapping[str, str] = field(default_factory=dict)
    retry: bool = True


@dataclass(frozen=True)
class Pause:
    """Wait before the next step (job polling)."""

    seconds: float


Operation = Generator[Call | Pause, httpx.Response | None, Any]


@dataclass(frozen=True)
class RetryPolicy:
    """Retries of a request that got a 502/503/504 or no answer in time: up to ``retries``
    more attempts, waiting ``backoff_s * 2**attempt`` (at most ``max_backoff_s``) or the
    service's ``Retry-After``."""

    retries: int = 3
    backoff_s: float = 0.5
    max_backoff_s: float = 8.0

    def should_retry(self, attempt: int, outcome: httpx.Response | httpx.TransportError) -> bool:
        if attempt >= self.retries:
            return False
        if isinstance(outcome, httpx.Response):
            return outcome.status_code in RETRY_STATUSES
        return isinstance(outcome, httpx.TimeoutException | httpx.NetworkError)

    def delay(self, attempt: int, outcome: httpx.Response | httpx.TransportError) -> float:
        delay = min(self.backoff_s * 2**attempt, self.max_backoff_s)
        if isinstance(outcome, httpx.Response):
            with contextlib.suppress(KeyError, ValueError):
                delay = max(delay, min(float(outcome.headers["retry-after"]), self.max_backoff_s))
        return delay


@dataclass(frozen=True)
class PollPolicy:
    """Job polling: first after ``interval_s``, growing by half up to ``max_interval_s``;
    give up after ``timeout_s``. ``progress``: show a tqdm bar (None: only on a terminal)."""

    interval_s: float = 0.2
    max_interval_s: float = 2.0
    timeout_s: float = 3600.0
    progress: bool | None = None


# -- requests -----------------------------------------------------------------------


class SegmentArgs(TypedDict, total=False):
    """Segmentation options (keyword arguments of the client's segment calls); omitted or
    None: the service's default. Fields of newer service versions may be passed too."""

    method: str | None  # ShDF method: auto, exact, sampled, neural
    partitioner: str | None  # graphcut, metis
    clusters: int | None  # Gaussian mixture components (0: chosen by BIC)
    smoothing: float | None  # graph-cut smoothness weight
    parts: int | None  # part count for metis
    refine: bool | None
    boundary_smoothing: bool | None
    crease_boundaries: bool | None  # boundaries moved onto concave creases
    symmetry: bool | None  # both sides of a mirror-symmetric shape cut alike
    seed: int | None  # seeds every random step: the ShDF's sampling and the segmentation
    labeler_id: str | None  # named parts by a stored labeller (upload_labeler, train_labeler)


def given(options: Mapping[str, Any]) -> dict[str, Any]:
    """The options that were given (None means: the service's default)."""
    return {key: value for key, value in options.items() if value is not None}


def as_query(options: Mapping[str, Any]) -> dict[str, str]:
    """Options as query parameters (booleans as ``true``/``false``)."""
    return {k: str(v).lower() if isinstance(v, bool) else str(v) for k, v in options.items()}


def mesh_payload(
    source: str | Path | bytes, filename: str | None, file_type: str | None
) -> tuple[tuple[str, bytes], dict[str, str]]:
    """The multipart file part and form fields of an upload: a path (its name tells the
    format) or bytes (give ``file_type`` or a ``filename`` with an extension)."""
    if isinstance(source, bytes | bytearray | memoryview):
        content = bytes(source)
        name = filename or (f"mesh.{file_type}" if file_type else "mesh")
    else:
        path = Path(source)
        content = path.read_bytes()
        name = filename or path.name
    form = {"file_type": file_type} if file_type else {}
    return (name, content), form


# -- operations ---------------------------------------------------------------------


def wait_job(job: Job, poll: PollPolicy) -> Operation:
    """Poll a job until it succeeded (returns it) or failed (raises JobFailedError), with a
    tqdm bar of its progress."""
    # Lazy: the client needs httpx and numpy alone; tqdm only when a job is polled.
    from tqdm import tqdm

    deadline = time.monotonic() + poll.timeout_s
    interval = poll.interval_s
    disable = None if poll.progress is None else not poll.progress
    with tqdm(
        total=100,
        desc=f"ShDF ({job.method})" if job.kind == "shdf" else job.kind,
        unit="%",
        disable=disable,
        file=sys.stderr,
        leave=False,
        bar_format="{desc}: {percentage:3.0f}%|{bar}| {elapsed}<{remaining}",
    ) as bar:
        while job.state not in ("succeeded", "failed"):
            if time.monotonic() > deadline:
                raise ServiceTimeoutError(
                    0,
                    "job_timeout",
                    f"job {job.job_id} is still {job.state} after {poll.timeout_s:g} s "
                    f"({job.progress:.0%} done); poll it later with job({job.job_id!r})",
                )
            yield Pause(interval)
            interval = min(interval * 1.5, poll.max_interval_s)
            response = yield Call("GET", f"/v1/jobs/{job.job_id}")
            job = Job.from_json(raise_for_error(response).json())
            bar.n = round(100 * job.progress)
            bar.refresh()
    if job.state == "failed":
        error = job.error
        code, message = (error.code, error.message) if error else ("job_failed", "job failed")
        raise JobFailedError(200, code, message, error.detail if error else None)
    return job


def until_done(call: Call, poll: PollPolicy) -> Operation:
    """Send ``call``; while it answers 202 (a job computes the ShDF), wait for the job and
    send it again. Returns the final successful response."""
    for _ in range(MAX_JOB_ROUNDS):
        response = raise_for_error((yield call))
        if response.status_code != 202:
            return response
        yield from wait_job(Job.from_json(response.json()), poll)
    raise ServiceTimeoutError(
        0, "job_loop", f"{call.method} {call.path} kept answering 202 after its job finished"
    )


def upload(
    source: str | Path | bytes,
    poll: PollPolicy,
    *,
    filename: str | None = None,
    file_type: str | None = None,
    method: str | None = None,
    seed: int = 0,
) -> Operation:
    """Upload a mesh; its ShDF is computed (waiting for the job of a large mesh)."""
    file_part, form = mesh_payload(source, filename, file_type)
    if method:
        form["method"] = method
    form["seed"] = str(seed)
    started = time.monotonic()
    response = raise_for_error(
        (yield Call("POST", "/v1/meshes", data=form, files={"file": file_part}))
    )
    body = response.json()
    if response.status_code != 202:
        return Upload(MeshInfo.from_json(body["mesh"]), ShdfStatus.from_json(body["shdf"]))
    job = yield from wait_job(Job.from_json(body), poll)
    info = raise_for_error((yield Call("GET", f"/v1/meshes/{job.mesh_id}")))
    status = ShdfStatus(
        method=job.method, seed=job.seed, cached=False, seconds=time.monotonic() - started
    )
    # The service keeps no upload's file name with the shared mesh: this upload's is ours.
    mesh = dataclasses.replace(MeshInfo.from_json(info.json()), filename=file_part[0])
    return Upload(mesh, status)


def segment(
    mesh_id: str,
    options: Mapping[str, Any],
    poll: PollPolicy,
    *,
    edits: Sequence[Mapping[str, Any]] | None = None,
) -> Operation:
    """Segment a stored mesh (from its cached ShDF), edited by ``edits`` if given."""
    body = {"mesh_id": mesh_id, **options, "labels_format": "base64"}
    if edits is not None:
        body["edits"] = [dict(edit) for edit in edits]
    response = yield from until_done(Call("POST", "/v1/segment", json=body), poll)
    return Segmentation.from_json(response.json())


def segment_file(
    source: str | Path | bytes,
    options: Mapping[str, Any],
    poll: PollPolicy,
    *,
    filename: str | None = None,
    file_type: str | None = None,
) -> Operation:
    """Upload and segment in one call; a large mesh's job is waited for, then it is
    segmented by id (no second upload)."""
    file_part, form = mesh_payload(source, filename, file_type)
    form.update(as_query({**options, "labels_format": "base64"}))
    call = Call("POST", "/v1/segment/file", data=form, files={"file": file_part})
    response = raise_for_error((yield call))
    if response.status_code != 202:
        return Segmentation.from_json(response.json())
    job = yield from wait_job(Job.from_json(response.json()), poll)
    result = yield from segment(job.mesh_id, options, poll)
    # The answer by id does not name the upload's file; the 202 did, in a header.
    return dataclasses.replace(result, source_id=response.headers.get("x-source-id"))


def shdf(mesh_id: str, poll: PollPolicy, *, method: str | None = None, seed: int = 0) -> Operation:
    """Per-input-face ShDF as float32 (NaN: faces without triangles)."""
    params: dict[str, Any] = {"format": "f32", "seed": seed}
    if method:
        params["method"] = method
    call = Call("GET", f"/v1/meshes/{mesh_id}/shdf", params=params)
    response = yield from until_done(call, poll)
    faces = response.headers.get("x-faces")
    return decode_shdf(response.content, int(faces) if faces else None)


def glb(mesh_id: str, style: str, options: Mapping[str, Any], poll: PollPolicy) -> Operation:
    """The segmentation as a GLB: ``colored`` (one colour per part) or ``parts`` (one node
    per part)."""
    call = Call("GET", f"/v1/meshes/{mesh_id}/segmentation/{style}.glb", params=as_query(options))
    response = yield from until_done(call, poll)
    return response.content


def usda(mesh_id: str, options: Mapping[str, Any], poll: PollPolicy) -> Operation:
    """The segmentation as a USD text layer (``parts.usda``)."""
    call = Call("GET", f"/v1/meshes/{mesh_id}/segmentation/parts.usda", params=as_query(options))
    response = yield from until_done(call, poll)
    return response.content


def get_json(path: str) -> Operation:
    """A GET whose JSON body is the result."""
    response = raise_for_error((yield Call("GET", path)))
    return response.json()


def list_labelers() -> Operation:
    """Every stored labeller, oldest first, following the pages of ``GET /v1/labelers``."""
    entries: list[LabelerInfo] = []
    offset: int | None = 0
    while offset is not None:
        call = Call("GET", "/v1/labelers", params={"offset": offset})
        body = raise_for_error((yield call)).json()
        entries += [LabelerInfo.from_json(entry) for entry in body["labelers"]]
        offset = body.get("next_offset")
    return entries


def upload_labeler(source: str | Path | bytes) -> Operation:
    """Upload a labeller file (checked by the service, stored under its content id)."""
    if isinstance(source, bytes | bytearray | memoryview):
        part = ("labeler.npz", bytes(source))
    else:
        part = (Path(source).name, Path(source).read_bytes())
    response = raise_for_error((yield Call("POST", "/v1/labelers", files={"file": part})))
    return LabelerInfo.from_json(response.json())


def training_labels(labels: Sequence[Any]) -> bytes:
    """One integer label array per mesh as the training form's file: little-endian int32,
    the meshes' labels one after the other. ValueError for labels that are not integers."""
    import numpy as np

    arrays = [np.asarray(values) for values in labels]
    for values in arrays:
        if values.ndim != 1 or not (
            np.issubdtype(values.dtype, np.integer)
            or (len(values) and np.all(values == np.round(values)))
        ):
            raise ValueError("give one 1-D array of integer labels per mesh, one per input face")
    joined = np.concatenate(arrays) if arrays else np.zeros(0)
    if len(joined) and (joined.min() < -(2**31) or joined.max() >= 2**31):
        raise ValueError("labels must fit in 32-bit integers")
    return joined.astype("<i4").tobytes()


def train_labeler(
    mesh_ids: Sequence[str],
    labels: Sequence[Any],
    poll: PollPolicy,
    *,
    names: Sequence[str] | None = None,
    method: str | None = None,
    seed: int = 0,
    smoothing: float | None = None,
) -> Operation:
    """Train a labeller from stored meshes and one label array per mesh (per input face);
    waits for the training job, returns the stored labeller."""
    if len(mesh_ids) != len(labels):
        raise ValueError(f"{len(mesh_ids)} mesh ids but {len(labels)} label arrays")
    if names is not None and any("," in name or not name.strip() for name in names):
        raise ValueError("label names must be non-empty and hold no comma")
    form = {"mesh_ids": ",".join(mesh_ids), "seed": str(seed)}
    if names is not None:
        form["names"] = ",".join(names)
    if method:
        form["method"] = method
    if smoothing is not None:
        form["smoothing"] = repr(float(smoothing))
    files = {"labels": ("labels.i32", training_labels(labels))}
    call = Call("POST", "/v1/labeler-trainings", data=form, files=files)
    response = raise_for_error((yield call))
    job = yield from wait_job(Job.from_json(response.json()), poll)
    info = raise_for_error((yield Call("GET", job.result_url)))
    return LabelerInfo.from_json(info.json())


def labeler_file(labeler_id: str) -> Operation:
    response = raise_for_error((yield Call("GET", f"/v1/labelers/{labeler_id}/file")))
    return response.content


def delete_labeler(labeler_id: str) -> Operation:
    raise_for_error((yield Call("DELETE", f"/v1/labelers/{labeler_id}")))
    return None


def delete_mesh(mesh_id: str) -> Operation:
    raise_for_error((yield Call("DELETE", f"/v1/meshes/{mesh_id}")))
    return None


def readiness() -> Operation:
    """``/readyz``'s body, whether ready (200) or not (503, not raised)."""
    response = yield Call("GET", "/readyz", retry=False)
    if response.status_code not in (200, 503):
        raise_for_error(response)
    return response.json()
