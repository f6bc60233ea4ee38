"""Bad input never crashes a worker: one JSON error shape, the right status, never a 5xx."""

from __future__ import annotations

import json
import struct

import httpx
import numpy as np
import pytest
import trimesh
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neural_shdf.api.app import create_app
from neural_shdf.mesh_io import SUPPORTED_FORMATS
from tests.api.api_helpers import (
    capsule,
    glb_container,
    instanced_glb,
    make_settings,
    obj_bytes,
    off_bytes,
)

FUZZ = settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def assert_error(response: httpx.Response, status: int, code: str | None = None) -> dict:
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"error"} and set(body["error"]) == {"code", "message", "detail"}
    assert body["error"]["message"]
    if code is not None:
        assert body["error"]["code"] == code
    return body["error"]


@pytest.fixture(scope="module")
def small_client(tmp_path_factory) -> TestClient:
    """Tight limits: 64 kB bodies, 2,000 faces, 50,000 vertices."""
    settings_ = make_settings(
        tmp_path_factory.mktemp("cache"),
        max_upload_bytes=64_000,
        max_faces=2_000,
        max_vertices=50_000,
    )
    with TestClient(create_app(settings_), raise_server_exceptions=False) as client:
        yield client


def post_file(client, data: bytes, name: str) -> httpx.Response:
    return client.post("/v1/meshes", files={"file": (name, data)})


def test_error_shape_for_routing_and_validation(small_client):
    assert_error(small_client.get("/nothing-here"), 404, "not_found")
    assert_error(small_client.delete("/healthz"), 405, "method_not_allowed")
    assert_error(small_client.get("/v1/meshes/" + "0" * 64), 404, "mesh_not_found")
    assert_error(small_client.get("/v1/meshes/not-a-hash"), 422, "validation_error")
    error = assert_error(small_client.post("/v1/segment", json={"clusters": "many"}), 422)
    assert error["code"] == "validation_error"
    assert {tuple(p["loc"]) for p in error["detail"]} >= {("body", "mesh_id"), ("body", "clusters")}
    # Bounds are checked in one place, SegmentParams, before any work (even for unknown ids).
    bad = {"mesh_id": "0" * 64, "clusters": -1}
    error = assert_error(small_client.post("/v1/segment", json=bad), 422, "invalid_parameter")
    assert "clusters must be an integer in 1..32" in error["message"]
    query = "?partitioner=metis&parts=0"
    path = f"/v1/meshes/{'0' * 64}/segmentation/colored.glb{query}"
    assert_error(small_client.get(path), 422, "invalid_parameter")
    malformed = assert_error(
        small_client.post(
            "/v1/segment", content=b"{not json", headers={"content-type": "application/json"}
        ),
        400,
        "malformed_json",
    )
    assert "not valid JSON" in malformed["message"] and "character 1" in malformed["message"]
    assert_error(small_client.post("/v1/meshes"), 422, "validation_error")
    assert_error(
        small_client.post("/v1/segment", json={"mesh_id": "x", "unknown_option": 1}),
        422,
        "validation_error",
    )


def test_upload_size_is_enforced_while_reading(small_client):
    big = b"v 0 0 0\n" * 20_000  # 160 kB
    error = assert_error(post_file(small_client, big, "big.obj"), 413, "payload_too_large")
    assert error["detail"] == {"max_upload_bytes": 64_000}

    def chunks():  # no Content-Length: counted while streaming
        yield b'--b\r\nContent-Disposition: form-data; name="file"; filename="a.obj"\r\n\r\n'
        for _ in range(100):
            yield b"v 0 0 0\n" * 128

    response = small_client.post(
        "/v1/meshes", content=chunks(), headers={"Content-Type": "multipart/form-data; boundary=b"}
    )
    assert_error(response, 413, "payload_too_large")


def test_too_many_faces_is_413(small_client):
    sphere = trimesh.creation.icosphere(subdivisions=4)  # 5,120 faces, ~92 kB as GLB
    sphere = trimesh.Trimesh(sphere.vertices, sphere.faces[:2500])  # over 2,000 faces, < 64 kB
    response = post_file(small_client, sphere.export(file_type="glb"), "s.glb")
    error = assert_error(response, 413, "mesh_too_large")
    assert error["detail"] == {"limit": "max_faces", "maximum": 2_000, "found": 2_500}


def test_instancing_that_expands_past_the_vertex_limit_is_413_naming_it(small_client):
    data = instanced_glb(4000, 40)  # 48 kB, 160,000 vertices once expanded
    error = assert_error(post_file(small_client, data, "bomb.glb"), 413, "mesh_too_large")
    assert error["detail"] == {"limit": "max_vertices", "maximum": 50_000, "found": 160_000}
    assert "max_vertices" in error["message"] and "40 glTF mesh instances" in error["message"]


def test_unsupported_format_is_415(small_client):
    assert_error(post_file(small_client, b"anything", "model.fbx"), 415, "unsupported_format")
    assert_error(post_file(small_client, b"\x01\x02\x03", "noext"), 415, "unsupported_format")
    response = small_client.post(
        "/v1/meshes", files={"file": ("m.obj", b"v 0 0 0")}, data={"file_type": "3ds"}
    )
    assert_error(response, 415, "unsupported_format")


TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)
BAD_FILES = {
    "empty": (b"", "a.obj"),
    "nan coordinates": (b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n", "a.obj"),
    "inf coordinates": (off_bytes(np.full((4, 3), np.inf), np.array([[0, 1, 2]])), "a.off"),
    "index out of range": (obj_bytes(TRIANGLE, [[0, 1, 9]]), "a.obj"),
    "negative index out of range": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -7\n", "a.obj"),
    "only degenerate faces": (obj_bytes(TRIANGLE, [[0, 0, 1], [2, 2, 2]]), "a.obj"),
    "no faces": (b"v 0 0 0\nv 1 0 0\n", "a.obj"),
    "text in binary slot": (b"ply\nformat binary_little_endian 1.0\nend_header\nxx", "a.ply"),
    "truncated binary stl": (capsule().export(file_type="stl")[:500], "a.stl"),
    "truncated glb": (capsule().export(file_type="glb")[:300], "a.glb"),
    "garbage glb": (b"glTF" + struct.pack("<II", 2, 40) + b"\xff" * 28, "a.glb"),
    "off with wrong counts": (b"OFF\n3 5 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "a.off"),
    "binary junk as obj": (bytes(range(256)) * 4, "a.obj"),
}


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_unusable_meshes_are_422_saying_why(small_client, case):
    data, name = BAD_FILES[case]
    response = post_file(small_client, data, name)
    assert response.status_code in (413, 422), (case, response.text)
    assert_error(response, response.status_code)


def _bomb_glb(byte_length: int, count: int) -> bytes:
    """A tiny GLB whose JSON claims a huge buffer and accessor (a zip-bomb-like file)."""
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": byte_length}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": byte_length}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": count}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
    }
    return glb_container(json.dumps(doc).encode(), struct.pack("<9f", *range(9)))


@pytest.mark.parametrize(
    ("byte_length", "count"), [(2**40, 2**36), (36, 2**34), (2**62, 3), (-5, 3), (36, -1)]
)
def test_glb_with_absurd_lengths_is_rejected_cheaply(small_client, byte_length, count):
    response = post_file(small_client, _bomb_glb(byte_length, count), "bomb.glb")
    assert response.status_code in (413, 422), response.text
    assert_error(response, response.status_code)


def test_segment_parameters_the_mesh_cannot_satisfy(small_client):
    obj = capsule(6).export(file_type="obj").encode()
    mesh_id = post_file(small_client, obj, "c.obj").json()["mesh"]["mesh_id"]
    response = small_client.post(
        "/v1/segment", json={"mesh_id": mesh_id, "partitioner": "metis", "parts": 5000}
    )
    assert response.status_code in (200, 422), response.text
    if response.status_code == 422:
        assert_error(response, 422)


def _valid_files() -> list[tuple[bytes, str]]:
    mesh = capsule(6)
    return [(mesh.export(file_type=fmt), f"m.{fmt}") for fmt in ("obj", "off", "ply", "stl", "glb")]


VALID = [
    (data if isinstance(data, bytes) else data.encode(), name) for data, name in _valid_files()
]


@given(
    base=st.sampled_from(VALID),
    cut=st.floats(0, 1),
    flips=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), max_size=8),
    name=st.sampled_from([None, *SUPPORTED_FORMATS, "txt", ""]),
)
@FUZZ
def test_fuzzed_uploads_never_5xx(small_client, base, cut, flips, name):
    data, original = base
    data = bytearray(data[: max(1, int(len(data) * (0.5 + cut / 2)))])
    for where, value in flips:
        data[int(where * (len(data) - 1))] = value
    filename = original if name is None else f"fuzz.{name}" if name else "fuzz"
    response = post_file(small_client, bytes(data), filename)
    assert response.status_code in (200, 202, 413, 415, 422), response.text
    if response.status_code >= 400:
        assert_error(response, response.status_code)


@given(payload=st.binary(max_size=2048), name=st.sampled_from(SUPPORTED_FORMATS))
@FUZZ
def test_random_bytes_never_5xx(small_client, payload, name):
    response = post_file(small_client, payload, f"r.{name}")
    assert response.status_code in (200, 413, 415, 422), response.text


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3)
    ),
    max_leaves=6,
)


@given(
    body=st.dictionaries(
        st.sampled_from(
            [
                "mesh_id",
                "partitioner",
                "clusters",
                "smoothing",
                "parts",
                "refine",
                "seed",
                "method",
                "shdf_seed",
                "boundary_smoothing",
                "crease_boundaries",
                "labels_format",
                "other",
            ]
        ),
        JSON_VALUES,
        max_size=6,
    )
)
@FUZZ
def test_fuzzed_segment_requests_never_5xx(small_client, body):
    response = small_client.post(  # json.dumps writes NaN/Infinity, which are not JSON
        "/v1/segment", content=json.dumps(body), headers={"Content-Type": "application/json"}
    )
    assert response.status_code in (200, 404, 422), response.text
    assert_error(response, response.status_code)


def test_stalled_body_times_out_with_408(app_factory):
    import asyncio

    app = app_factory(body_read_timeout_s=0.2)

    async def slow_body():
        yield b'--b\r\nContent-Disposition: form-data; name="file"; filename="a.obj"\r\n\r\n'
        await asyncio.sleep(1.0)
        yield b"v 0 0 0\r\n--b--\r\n"

    async def send() -> httpx.Response:
        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://t") as client:
            return await client.post(
                "/v1/meshes",
                content=slow_body(),
                headers={"Content-Type": "multipart/form-data; boundary=b"},
            )

    assert_error(asyncio.run(send()), 408, "request_timeout")


def test_non_finite_smoothing_says_finite(small_client):
    body = b'{"mesh_id": "' + b"0" * 64 + b'", "smoothing": NaN}'
    response = small_client.post(
        "/v1/segment", content=body, headers={"content-type": "application/json"}
    )
    error = assert_error(response, 422, "invalid_parameter")
    assert "smoothing must be a finite number" in error["message"]
    query = small_client.get(f"/v1/meshes/{'0' * 64}/segmentation/colored.glb?smoothing=inf")
    assert "finite number" in assert_error(query, 422)["message"]


def test_huge_coordinates_are_named_not_called_degenerate(small_client):
    tetrahedron = b"v 1e308 0 0\nv 0 1e308 0\nv 0 0 1e308\nv 0 0 0\nf 1 2 3\nf 1 2 4\nf 1 3 4\n"
    error = assert_error(post_file(small_client, tetrahedron, "t.obj"), 422, "invalid_geometry")
    assert "1e+308" in error["message"] and "rescale" in error["message"]
    assert "degenerate" not in error["message"]


def test_face_limit_reports_the_file_s_face_count(small_client):
    many = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" + b"f 1 2 3\n" * 5000
    error = assert_error(post_file(small_client, many, "m.obj"), 413, "mesh_too_large")
    assert error["message"].startswith("the mesh has 5000 faces")
    assert error["detail"] == {"limit": "max_faces", "maximum": 2_000, "found": 5000}


def _tetrahedron_obj() -> bytes:
    corners = [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]
    return obj_bytes(np.array(corners, float), [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])


@pytest.mark.parametrize("file_type", ["../../etc/Passwd", "x" * 500])
def test_file_type_is_named_as_given_never_rewritten(small_client, file_type):
    response = small_client.post(
        "/v1/meshes", files={"file": ("m.obj", _tetrahedron_obj())}, data={"file_type": file_type}
    )
    error = assert_error(response, 415, "unsupported_format")
    assert (
        repr(file_type[:40])[:-1] in error["message"] and "/../etc/passwd" not in error["message"]
    )
    assert len(error["message"]) < 200


def test_file_type_is_normalised_when_it_names_a_format(small_client):
    response = small_client.post(
        "/v1/meshes", files={"file": ("m.bin", _tetrahedron_obj())}, data={"file_type": " .OBJ"}
    )
    assert response.status_code == 200, response.text
    assert response.json()["mesh"]["format"] == "obj"


def test_deeply_nested_gltf_json_is_a_parse_error_saying_so(small_client):
    doc = b'{"asset": {"version": "2.0"}, "extras": ' + b"[" * 5000 + b"]" * 5000 + b"}"
    error = assert_error(post_file(small_client, doc, "deep.gltf"), 422, "mesh_parse_error")
    assert "nests" in error["message"] and "recursion" not in error["message"]


@pytest.mark.parametrize("route", ["/v1/meshes", "/v1/segment/file"])
def test_two_files_in_one_upload_are_422_naming_the_field(small_client, route):
    tetrahedron = _tetrahedron_obj()
    files = [("file", ("a.obj", tetrahedron)), ("file", ("b.obj", tetrahedron))]
    error = assert_error(small_client.post(route, files=files), 422, "repeated_form_field")
    assert "'file' 2 times" in error["message"] and error["detail"] == {"repeated": {"file": 2}}


def test_unknown_keys_get_a_bounded_answer(small_client):
    """A body of many unknown keys: 422 listing the first problems and their count (the
    answer stays small); past the JSON limit, 413 before parsing."""
    body = {"mesh_id": "0" * 64, **{f"k{i}": 1 for i in range(2_000)}}
    error = assert_error(small_client.post("/v1/segment", json=body), 422, "validation_error")
    assert len(error["detail"]) == 20 and "2000 problems" in error["message"]
    huge = {"mesh_id": "0" * 64, **{f"k{i:06d}": 1 for i in range(20_000)}}
    error = assert_error(small_client.post("/v1/segment", json=huge), 413, "payload_too_large")
    assert error["detail"] == {"max_json_bytes": 64_000}  # the upload limit is lower here
