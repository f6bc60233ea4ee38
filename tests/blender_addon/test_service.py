"""The add-on's urllib calls against a real `neural-shdf serve` process (no Blender needed)."""

from __future__ import annotations

import base64
import threading

import numpy as np
import pytest
import trimesh

from blender_addon import service
from blender_addon.mesh_payload import polygon_ply
from neural_shdf.client import Client
from tests.api.api_helpers import capsule, free_port
from tests.blender_addon.test_mesh_payload import arrays_of


def no_progress(fraction: float, status: str) -> None:
    pass


def test_upload_then_by_id_match_the_python_client(service_url):
    data = capsule().export(file_type="ply")
    session = service.Session(service_url)
    seen: list[str] = []
    first = session.segment(data, "c.ply", {"clusters": 3}, lambda f, s: seen.append(s))
    again = session.segment(data, "c.ply", {"clusters": 4}, no_progress, mesh_id=first.mesh_id)
    assert first.uploaded and not again.uploaded and again.mesh_id == first.mesh_id
    assert seen and seen[0].startswith("uploading")
    with Client(service_url) as client:
        expected = client.segment(first.mesh_id, clusters=4)
    assert list(again.labels) == expected.labels.tolist()
    assert again.part_count == expected.part_count
    assert again.timings["shdf_cached"]


def test_unknown_mesh_id_falls_back_to_an_upload(service_url):
    data = trimesh.creation.icosphere(subdivisions=2).export(file_type="ply")
    outcome = service.Session(service_url).segment(
        data, "s.ply", {"clusters": 2}, no_progress, mesh_id="0" * 64
    )
    assert outcome.uploaded and outcome.mesh_id != "0" * 64
    assert len(outcome.labels) == 320


def test_large_mesh_job_is_polled_with_progress(service_url):
    data = trimesh.creation.icosphere(subdivisions=6).export(file_type="ply")  # a job (202)
    seen: list[tuple[float, str]] = []
    outcome = service.Session(service_url, poll_s=0.05).segment(
        data, "big.ply", {"clusters": 2}, lambda f, s: seen.append((f, s))
    )
    assert len(outcome.labels) == 81920
    assert any(status.startswith("computing the ShDF") for _, status in seen)
    assert seen[-1][0] == 1.0


def test_service_errors_carry_its_message(service_url):
    session = service.Session(service_url, retries=0)
    flat = arrays_of([[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]])
    with pytest.raises(service.ServiceError, match="zero area") as degenerate:
        session.segment(polygon_ply(flat), "flat.ply", {}, no_progress)
    assert degenerate.value.code == "invalid_geometry"
    with pytest.raises(service.ServiceError, match="clusters") as invalid:
        session.segment(capsule().export(file_type="ply"), "c.ply", {"clusters": 99}, no_progress)
    assert invalid.value.status == 422 and invalid.value.code == "invalid_parameter"


def test_unreachable_service_and_bad_url_and_cancel():
    nowhere = f"http://127.0.0.1:{free_port()}"
    with pytest.raises(service.ServiceError, match="cannot reach") as unreachable:
        service.Session(nowhere, retries=1, backoff_s=0.01).segment(b"x", "x.ply", {}, no_progress)
    assert unreachable.value.code == "unreachable"
    with pytest.raises(service.ServiceError, match="must start with http"):
        service.Session("localhost:8000")
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(service.Cancelled):
        service.Session(nowhere, cancel=cancel).segment(b"x", "x.ply", {}, no_progress)


def test_labels_decode_from_every_width():
    for dtype in ("int8", "int16", "int32"):
        values = np.array([0, 5, -1, 7], dtype=np.dtype(dtype).newbyteorder("<"))
        body = {"labels_base64": base64.b64encode(values.tobytes()).decode(), "labels_dtype": dtype}
        assert list(service.decode_labels(body)) == [0, 5, -1, 7]
    assert list(service.decode_labels({"labels": [1, 2]})) == [1, 2]
