"""``Client`` (blocking) and ``AsyncClient`` (asyncio) over httpx.

Both drive the same operations (``neural_shdf.client.operations``); they differ only in how
a request is sent and how a pause is waited. Each request is retried with backoff on
502/503/504 and on timeouts or refused connections; an error answer raises the matching
``ServiceError`` with the service's message.
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Self, Unpack

import httpx
import numpy as np
from numpy.typing import NDArray

import neural_shdf.client.operations as ops
from neural_shdf.client.errors import error_from_transport
from neural_shdf.client.operations import Call, Operation, Pause, PollPolicy, RetryPolicy
from neural_shdf.client.results import Job, LabelerInfo, MeshInfo, Segmentation, Upload
from neural_shdf.client.unwrapping import UnwrapArgs, UvLayout, download, uv_layout

DEFAULT_URL = "http://127.0.0.1:8000"
MeshSource = str | Path | bytes


def _timeout(seconds: float) -> httpx.Timeout:
    return httpx.Timeout(seconds, connect=min(seconds, 10.0))


class _Settings:
    """What both clients share: base URL, retry and polling policies."""

    def __init__(
        self,
        base_url: str,
        retries: int,
        backoff_s: float,
        progress: bool | None,
        poll_interval_s: float,
        job_timeout_s: float,
    ) -> None:
        self.base_url = base_url.rstrip("/")
        self.retry = RetryPolicy(retries=retries, backoff_s=backoff_s)
        self.poll = PollPolicy(
            interval_s=poll_interval_s, timeout_s=job_timeout_s, progress=progress
        )

    @staticmethod
    def request_args(call: Call) -> dict[str, Any]:
        return {
            "params": call.params,
            "json": call.json,
            "data": call.data,
            "files": call.files,
            "headers": dict(call.headers) or None,
        }


class Client(_Settings):
    """A blocking client of a neural-shdf service.

    ``timeout``: seconds per request (the service's own limit is 120 s); ``retries`` and
    ``backoff_s``: repeats of a request on 502/503/504 or no answer, after
    ``backoff_s * 2**attempt`` s; ``progress``: tqdm bar while a job runs (None: on a
    terminal only); ``job_timeout_s``: longest wait for a job.
    """

    def __init__(
        self,
        base_url: str = DEFAULT_URL,
        *,
        timeout: float = 180.0,
        retries: int = 3,
        backoff_s: float = 0.5,
        progress: bool | None = None,
        poll_interval_s: float = 0.2,
        job_timeout_s: float = 3600.0,
    ) -> None:
        super().__init__(base_url, retries, backoff_s, progress, poll_interval_s, job_timeout_s)
        self.http = httpx.Client(base_url=self.base_url, timeout=_timeout(timeout))

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        self.http.close()

    # -- driving operations ----------------------------------------------------
    def send(self, call: Call) -> httpx.Response:
        """One request, retried per the retry policy."""
        attempt = 0
        while True:
            try:
                outcome: httpx.Response | httpx.TransportError = self.http.request(
                    call.method, call.path, **self.request_args(call)
                )
            except httpx.TransportError as exc:
                outcome = exc
            if not (call.retry and self.retry.should_retry(attempt, outcome)):
                break
            time.sleep(self.retry.delay(attempt, outcome))
            attempt += 1
        if isinstance(outcome, httpx.TransportError):
            raise error_from_transport(outcome, self.base_url) from outcome
        return outcome

    def run(self, operation: Operation) -> Any:
        """Drive an operation to its result."""
        try:
            step = next(operation)
            while True:
                if isinstance(step, Pause):
                    time.sleep(step.seconds)
                    step = operation.send(None)
                else:
                    step = operation.send(self.send(step))
        except StopIteration as done:
            return done.value
        finally:
            operation.close()

    # -- the API -------------------------------------------------------------------
    def health(self) -> bool:
        """True when the service answers ``/healthz``."""
        return self.run(ops.get_json("/healthz")).get("status") == "ok"

    def ready(self) -> dict[str, Any]:
        """``/readyz``: ``{"status": "ready" | "not_ready", "checks": {...}}``."""
        return self.run(ops.readiness())

    def upload(
        self,
        source: MeshSource,
        *,
        filename: str | None = None,
        file_type: str | None = None,
        method: str | None = None,
        seed: int = 0,
    ) -> Upload:
        """Upload a mesh (a path, or bytes with ``file_type``) and have its ShDF computed;
        a large mesh's job is waited for with a progress bar."""
        return self.run(
            ops.upload(
                source, self.poll, filename=filename, file_type=file_type, method=method, seed=seed
            )
        )

    def mesh(self, mesh_id: str) -> MeshInfo:
        """Metadata of a stored mesh."""
        return MeshInfo.from_json(self.run(ops.get_json(f"/v1/meshes/{mesh_id}")))

    def delete(self, mesh_id: str) -> None:
        """Delete a mesh and everything computed from it."""
        self.run(ops.delete_mesh(mesh_id))

    def shdf(
        self, mesh_id: str, *, method: str | None = None, seed: int = 0
    ) -> NDArray[np.float32]:
        """Per-input-face ShDF in [0, 1] (NaN: a face without triangles)."""
        return self.run(ops.shdf(mesh_id, self.poll, method=method, seed=seed))

    def segment(
        self,
        mesh_id: str,
        *,
        edits: Sequence[Mapping[str, Any]] | None = None,
        **options: Unpack[ops.SegmentArgs],
    ) -> Segmentation:
        """Part labels per input face of a stored mesh; only the partition runs.

        ``edits``: a part-edit document (``neural_shdf.client.edits``: grow, shrink,
        merge, paint by input face), applied by the service to the part tree's cut."""
        return self.run(ops.segment(mesh_id, ops.given(options), self.poll, edits=edits))

    def segment_file(
        self,
        source: MeshSource,
        *,
        filename: str | None = None,
        file_type: str | None = None,
        **options: Unpack[ops.SegmentArgs],
    ) -> Segmentation:
        """Upload and segment in one call (``mesh_id`` of the result: for later calls)."""
        operation = ops.segment_file(
            source, ops.given(options), self.poll, filename=filename, file_type=file_type
        )
        return self.run(operation)

    def colored_glb(self, mesh_id: str, **options: Unpack[ops.SegmentArgs]) -> bytes:
        """The segmentation as a GLB with one colour per part."""
        return self.run(ops.glb(mesh_id, "colored", ops.given(options), self.poll))

    def parts_glb(
        self, mesh_id: str, *, source: str | None = None, **options: Unpack[ops.SegmentArgs]
    ) -> bytes:
        """The segmentation as a GLB with one node per part (``part_000``, ...); ``source``
        (an upload's ``mesh.source_id``): keeping that file's UVs, normals, colours,
        materials and objects."""
        query = ops.given({**options, "source": source})
        return self.run(ops.glb(mesh_id, "parts", query, self.poll))

    def parts_usda(
        self, mesh_id: str, *, source: str | None = None, **options: Unpack[ops.SegmentArgs]
    ) -> bytes:
        """The segmentation as a USD text layer with one ``GeomSubset`` per part; ``source``
        (the ``source_id`` of a USD upload or of ``segment_file``): that file's own stage
        with the subsets, else a new stage of the mesh's input faces."""
        query = ops.given({**options, "source": source})
        return self.run(ops.usda(mesh_id, query, self.poll))

    # -- unwrap by parts (neural_shdf.client.unwrapping) -----------------------------
    def unwrapped_glb(self, mesh_id: str, **options: Unpack[UnwrapArgs]) -> bytes:
        """The mesh with UVs charted part by part in one atlas, the atlas as texture (GLB)."""
        return self.run(download(mesh_id, "glb", ops.given(options), self.poll))

    def unwrapped_obj(self, mesh_id: str, **options: Unpack[UnwrapArgs]) -> bytes:
        """The same UVs as OBJ text: ``v``, ``vt``, one ``f v/vt`` per input face."""
        return self.run(download(mesh_id, "obj", ops.given(options), self.poll))

    def atlas_png(self, mesh_id: str, **options: Unpack[UnwrapArgs]) -> bytes:
        """The atlas layout as a PNG: charts coloured by part, outlined."""
        return self.run(download(mesh_id, "atlas", ops.given(options), self.poll))

    def uvs(self, mesh_id: str, **options: Unpack[UnwrapArgs]) -> UvLayout:
        """The same UVs per corner of every input face, in the file's order (numpy)."""
        return self.run(uv_layout(mesh_id, ops.given(options), self.poll))

    def job(self, job_id: str) -> Job:
        """A job's state and progress."""
        return Job.from_json(self.run(ops.get_json(f"/v1/jobs/{job_id}")))

    def wait(self, job: Job | str) -> Job:
        """Poll a job until it succeeded (raises JobFailedError if it failed)."""
        return self.run(ops.wait_job(self.job(job) if isinstance(job, str) else job, self.poll))

    # -- part labellers (named parts) ----------------------------------------------
    def upload_labeler(self, source: str | Path | bytes) -> LabelerInfo:
        """Upload a labeller file (``neural-shdf labeler train``); its id is for
        ``segment(mesh_id, labeler_id=...)``. The same file twice has one id."""
        return self.run(ops.upload_labeler(source))

    def train_labeler(
        self,
        mesh_ids: Sequence[str],
        labels: Sequence[Any],
        *,
        names: Sequence[str] | None = None,
        method: str | None = None,
        seed: int = 0,
        smoothing: float | None = None,
    ) -> LabelerInfo:
        """Train a labeller on the service from stored meshes and one integer label per
        input face of each (``labels[i]`` for ``mesh_ids[i]``); ``names``: one per distinct
        label, in increasing label order. Waits for the training job."""
        operation = ops.train_labeler(
            mesh_ids, labels, self.poll, names=names, method=method, seed=seed, smoothing=smoothing
        )
        return self.run(operation)

    def labelers(self) -> list[LabelerInfo]:
        """The stored labellers, oldest first (every page)."""
        return self.run(ops.list_labelers())

    def labeler(self, labeler_id: str) -> LabelerInfo:
        """A stored labeller's names and metadata."""
        return LabelerInfo.from_json(self.run(ops.get_json(f"/v1/labelers/{labeler_id}")))

    def labeler_file(self, labeler_id: str) -> bytes:
        """A stored labeller's file (for ``segment --labeler`` or ``load_labeler``)."""
        return self.run(ops.labeler_file(labeler_id))

    def delete_labeler(self, labeler_id: str) -> None:
        """Delete a stored labeller."""
        self.run(ops.delete_labeler(labeler_id))


class AsyncClient(_Settings):
    """The asyncio twin of ``Client``: the same methods and arguments, awaited."""

    def __init__(
        self,
        base_url: str = DEFAULT_URL,
        *,
        timeout: float = 180.0,
        retries: int = 3,
        backoff_s: float = 0.5,
        progress: bool | None = None,
        poll_interval_s: float = 0.2,
        job_timeout_s: float = 3600.0,
    ) -> None:
        super().__init__(base_url, retries, backoff_s, progress, poll_interval_s, job_timeout_s)
        self.http = httpx.AsyncClient(base_url=self.base_url, timeout=_timeout(timeout))

    async def __aenter__(self) -> Self:
        return self

    async def __aexit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.aclose()

    async def aclose(self) -> None:
        await self.http.aclose()

    # -- driving operations ----------------------------------------------------
    async def send(self, call: Call) -> httpx.Response:
        """One request, retried per the retry policy."""
        attempt = 0
        while True:
            try:
                outcome: httpx.Response | httpx.TransportError = await self.http.request(
                    call.method, call.path, **self.request_args(call)
                )
            except httpx.TransportError as exc:
                outcome = exc
            if not (call.retry and self.retry.should_retry(attempt, outcome)):
                break
            await asyncio.sleep(self.retry.delay(attempt, outcome))
            attempt += 1
        if isinstance(outcome, httpx.TransportError):
            raise error_from_transport(outcome, self.base_url) from outcome
        return outcome

    async def run(self, operation: Operation) -> Any:
        """Drive an operation to its result."""
        try:
            step = next(operation)
            while True:
                if isinstance(step, Pause):
                    await asyncio.sleep(step.seconds)
                    step = operation.send(None)
                else:
                    step = operation.send(await self.send(step))
        except StopIteration as done:
            return done.value
        finally:
            operation.close()

    # -- the API (see Client for each method) ----------------------------------
    async def health(self) -> bool:
        return (await self.run(ops.get_json("/healthz"))).get("status") == "ok"

    async def ready(self) -> dict[str, Any]:
        return await self.run(ops.readiness())

    async def upload(
        self,
        source: MeshSource,
        *,
        filename: str | None = None,
        file_type: str | None = None,
        method: str | None = None,
        seed: int = 0,
    ) -> Upload:
        return await self.run(
            ops.upload(
                source, self.poll, filename=filename, file_type=file_type, method=method, seed=seed
            )
        )

    async def mesh(self, mesh_id: str) -> MeshInfo:
        return MeshInfo.from_json(await self.run(ops.get_json(f"/v1/meshes/{mesh_id}")))

    async def delete(self, mesh_id: str) -> None:
        await self.run(ops.delete_mesh(mesh_id))

    async def shdf(
        self, mesh_id: str, *, method: str | None = None, seed: int = 0
    ) -> NDArray[np.float32]:
        return await self.run(ops.shdf(mesh_id, self.poll, method=method, seed=seed))

    async def segment(
        self,
        mesh_id: str,
        *,
        edits: Sequence[Mapping[str, Any]] | None = None,
        **options: Unpack[ops.SegmentArgs],
    ) -> Segmentation:
        operation = ops.segment(mesh_id, ops.given(options), self.poll, edits=edits)
        return await self.run(operation)

    async def segment_file(
        self,
        source: MeshSource,
        *,
        filename: str | None = None,
        file_type: str | None = None,
        **options: Unpack[ops.SegmentArgs],
    ) -> Segmentation:
        operation = ops.segment_file(
            source, ops.given(options), self.poll, filename=filename, file_type=file_type
        )
        return await self.run(operation)

    async def colored_glb(self, mesh_id: str, **options: Unpack[ops.SegmentArgs]) -> bytes:
        return await self.run(ops.glb(mesh_id, "colored", ops.given(options), self.poll))

    async def parts_glb(
        self, mesh_id: str, *, source: str | None = None, **options: Unpack[ops.SegmentArgs]
    ) -> bytes:
        query = ops.given({**options, "source": source})
        return await self.run(ops.glb(mesh_id, "parts", query, self.poll))

    async def parts_usda(
        self, mesh_id: str, *, source: str | None = None, **options: Unpack[ops.SegmentArgs]
    ) -> bytes:
        query = ops.given({**options, "source": source})
        return await self.run(ops.usda(mesh_id, query, self.poll))

    async def unwrapped_glb(self, mesh_id: str, **options: Unpack[UnwrapArgs]) -> bytes:
        return await self.run(download(mesh_id, "glb", ops.given(options), self.poll))

    async def unwrapped_obj(self, mesh_id: str, **options: Unpack[UnwrapArgs]) -> bytes:
        return await self.run(download(mesh_id, "obj", ops.given(options), self.poll))

    async def atlas_png(self, mesh_id: str, **options: Unpack[UnwrapArgs]) -> bytes:
        return await self.run(download(mesh_id, "atlas", ops.given(options), self.poll))

    async def uvs(self, mesh_id: str, **options: Unpack[UnwrapArgs]) -> UvLayout:
        return await self.run(uv_layout(mesh_id, ops.given(options), self.poll))

    async def job(self, job_id: str) -> Job:
        return Job.from_json(await self.run(ops.get_json(f"/v1/jobs/{job_id}")))

    async def wait(self, job: Job | str) -> Job:
        current = await self.job(job) if isinstance(job, str) else job
        return await self.run(ops.wait_job(current, self.poll))

    async def upload_labeler(self, source: str | Path | bytes) -> LabelerInfo:
        return await self.run(ops.upload_labeler(source))

    async def train_labeler(
        self,
        mesh_ids: Sequence[str],
        labels: Sequence[Any],
        *,
        names: Sequence[str] | None = None,
        method: str | None = None,
        seed: int = 0,
        smoothing: float | None = None,
    ) -> LabelerInfo:
        operation = ops.train_labeler(
            mesh_ids, labels, self.poll, names=names, method=method, seed=seed, smoothing=smoothing
        )
        return await self.run(operation)

    async def labelers(self) -> list[LabelerInfo]:
        return await self.run(ops.list_labelers())

    async def labeler(self, labeler_id: str) -> LabelerInfo:
        return LabelerInfo.from_json(await self.run(ops.get_json(f"/v1/labelers/{labeler_id}")))

    async def labeler_file(self, labeler_id: str) -> bytes:
        return await self.run(ops.labeler_file(labeler_id))

    async def delete_labeler(self, labeler_id: str) -> None:
        await self.run(ops.delete_labeler(labeler_id))
