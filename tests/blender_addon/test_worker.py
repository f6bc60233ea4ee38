"""The add-on's worker task (no Blender needed): what ends up in its fields, against a real
`neural-shdf serve` process."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
import trimesh

from blender_addon import service
from blender_addon.worker import WorkerTask
from tests.api.api_helpers import capsule, free_port


@dataclass(kw_only=True)
class UploadTask(WorkerTask):
    """Uploads one mesh; ``fail`` raises inside the work instead."""

    payload: bytes
    fail: Exception | None = None
    statuses: list[str] = field(default_factory=list)
    mesh_id: str | None = None

    def work(self, session: service.Session) -> None:
        if self.fail is not None:
            raise self.fail

        def report(fraction: float, status: str) -> None:
            self.progress = fraction
            self.status = status
            self.statuses.append(status)

        self.mesh_id = session.upload_mesh(self.payload, "capsule.ply", report)


def finished(task: WorkerTask) -> WorkerTask:
    assert not task.done  # not started
    task.start()
    task.wait()
    assert task.done
    return task


def test_a_task_runs_on_its_own_thread_and_keeps_its_results(service_url):
    task = finished(UploadTask(server_url=service_url, payload=capsule().export(file_type="ply")))
    assert task.error is None and not task.cancelled
    assert task.mesh_id and task.statuses and task.seconds > 0
    assert task.thread is not None and task.thread.name == "neural-shdf"


def test_keyword_only_fields():
    with pytest.raises(TypeError):
        UploadTask("http://127.0.0.1:1", b"")  # type: ignore[misc]


@pytest.mark.parametrize(
    ("fail", "error", "cancelled"),
    [
        (service.ServiceError("the mesh has no faces"), "the mesh has no faces", False),
        (service.Cancelled("cancelled"), None, True),
        (KeyError("parts"), "unexpected KeyError: 'parts'", False),
    ],
)
def test_errors_become_text_for_the_user_and_a_cancel_a_flag(fail, error, cancelled):
    task = finished(UploadTask(server_url="http://127.0.0.1:1", payload=b"", fail=fail))
    assert (task.error, task.cancelled) == (error, cancelled)


def test_an_unreachable_service_is_an_error_and_a_set_cancel_a_cancel():
    data = trimesh.creation.box().export(file_type="ply")
    nowhere = f"http://127.0.0.1:{free_port()}"
    task = finished(UploadTask(server_url=nowhere, payload=data))
    assert task.error and not task.cancelled
    stopped = UploadTask(server_url=nowhere, payload=data)
    stopped.cancel.set()
    assert finished(stopped).cancelled and stopped.error is None
    bad_url = finished(UploadTask(server_url="localhost:8000", payload=data))
    assert bad_url.error is not None and "must start with http" in bad_url.error
