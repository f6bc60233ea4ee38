"""Hostile meshes and requests through a real ``neural-shdf serve`` on loopback and the CLI.

The corpus of issues 9 and 20: memory bombs in valid files, the same tetrahedron repeated
in place, malformed files of every format, and the second round's cases (unwrap and atlas
memory, 100,000 shells, abandoned requests, a 200k-key JSON body, DELETE during a job,
another uploader's file name, two files in one upload, tiny and huge units, polls of every
job kind). For each case it records, through a fresh ``neural-shdf serve`` (one worker,
default limits, a fresh disk cache):

* every status (0 when no answer came within the request timeout + 30 s), how long each
  answer took, and whether the answer is the correct one (a status, or a checked property
  such as "the re-upload after DELETE is not cached");
* the server's peak resident memory during the case, its worker processes included
  (sampled every 20 ms; the server is killed and restarted past ``--kill-mb``, which
  counts as a server death);
* the longest ``/healthz`` latency during the case (an event-loop stall), measured from a
  probe process of its own, so that this process's own work cannot add to it.

Then the legitimate inputs for scale: ``dense-dev`` zenobia (462k faces, where
``../shared/data`` exists; else a dumbbell) and the same subdivided once (1.85M faces, the
largest input the 2M-face limit lets through), uploaded and segmented; and
``neural-shdf segment`` / ``unwrap`` on every file (exit code, seconds, peak RSS).

    python benchmarks/hostile_corpus.py [--skip-cli] [--skip-legit] [--only SUBSTRING] [--keep DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
from bench_service import free_port

REPO = Path(__file__).resolve().parents[1]
LEGIT = (
    REPO
    / ".."
    / "shared"
    / "data"
    / "dense-dev"
    / ("polygonjs__models__resources__threedscans.com__zenobia_in_chains.ply")
)
REQUEST_TIMEOUT_S = 120.0  # the service's default NEURAL_SHDF_REQUEST_TIMEOUT_S
TETRAHEDRON = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
CORNERS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float)


@dataclass
class Answer:
    status: int
    seconds: float
    code: str = ""
    message: str = ""
    body: object = None
    size: int = 0


@dataclass
class Outcome:
    """What a scenario saw: its answers, whether the service behaved, and a short note."""

    answers: list[Answer]
    ok: bool
    note: str = ""


@dataclass
class Case:
    """One hostile input: a file to upload, a raw request, or a scenario of several calls."""

    name: str
    data: bytes = b""
    filename: str = ""
    expect: str = ""  # the status (or statuses, "200|202") a correct service gives
    form: dict = field(default_factory=dict)
    request: dict | None = None  # a raw request instead of an upload
    scenario: Callable[[Server], Outcome] | None = None  # several calls and a check
    cli: str | None = "segment"  # the CLI command run on the file, if any
    fresh: bool = False  # on a server of its own, so no earlier case's work is still running


# -- file builders -------------------------------------------------------------------------
def obj(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(vertices, float).tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in np.asarray(faces).tolist()]
    return ("\n".join(lines) + "\n").encode()


def glb(document: dict, blob: bytes) -> bytes:
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\x00" * (-len(blob) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    return (
        struct.pack("<4sII", b"glTF", 2, total)
        + struct.pack("<II", len(text), 0x4E4F534A)
        + text
        + struct.pack("<II", len(blob), 0x004E4942)
        + blob
    )


def gltf_document(vertex_count: int, blob_length: int, nodes: list, meshes: list) -> dict:
    return {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": blob_length}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 12 * vertex_count},
            {"buffer": 0, "byteOffset": 12 * vertex_count, "byteLength": 12},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": vertex_count},
            {"bufferView": 1, "componentType": 5125, "type": "SCALAR", "count": 3},
        ],
        "meshes": meshes,
        "nodes": nodes,
        "scenes": [{"nodes": [0]}],
    }


def instancing_bomb(vertex_count: int = 1_000_000, children: int = 40) -> bytes:
    """The issue's 12 MB GLB: one 1M-vertex accessor placed by 40 child nodes."""
    positions = np.random.default_rng(0).random((vertex_count, 3)).astype("<f4")
    blob = positions.tobytes() + np.array([0, 1, 2], "<u4").tobytes()
    nodes = [{"children": list(range(1, children + 1))}]
    nodes += [{"mesh": 0, "translation": [i, 0, 0]} for i in range(children)]
    meshes = [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]
    return glb(gltf_document(vertex_count, len(blob), nodes, meshes), blob)


def aliased_accessors(vertex_count: int = 100_000, aliases: int = 2000) -> bytes:
    """2,000 primitives, each with its own accessor over the same 1.2 MB of positions."""
    positions = np.random.default_rng(1).random((vertex_count, 3)).astype("<f4")
    blob = positions.tobytes() + np.array([0, 1, 2], "<u4").tobytes()
    primitives = [{"attributes": {"POSITION": 2 + i}, "indices": 1} for i in range(aliases)]
    document = gltf_document(vertex_count, len(blob), [{"mesh": 0}], [{"primitives": primitives}])
    document["accessors"] += [dict(document["accessors"][0]) for _ in range(aliases)]
    return glb(document, blob)


def exponential_dag(layers: int = 40) -> bytes:
    """Each node instances the next twice: 2**40 instances of one triangle."""
    positions = np.eye(3, dtype="<f4")
    blob = positions.tobytes() + np.array([0, 1, 2], "<u4").tobytes()
    nodes = [{"children": [i + 1, i + 1]} for i in range(layers)] + [{"mesh": 0}]
    meshes = [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]
    return glb(gltf_document(3, len(blob), nodes, meshes), blob)


def node_chain(depth: int = 5000) -> bytes:
    """A 5,000-deep chain of nodes over a tetrahedron (valid: must load)."""
    blob = CORNERS.astype("<f4").tobytes() + TETRAHEDRON.astype("<u4").tobytes()
    document = gltf_document(4, len(blob), [], [])
    document["bufferViews"][1]["byteLength"] = 48
    document["accessors"][1]["count"] = 12
    document["meshes"] = [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]
    document["nodes"] = [{"children": [i + 1], "translation": [0.001, 0, 0]} for i in range(depth)]
    document["nodes"].append({"mesh": 0})
    return glb(document, blob)


def deep_json_gltf(depth: int = 100_000) -> bytes:
    return b'{"asset": {"version": "2.0"}, "extras": ' + b"[" * depth + b"]" * depth + b"}"


def big_polygons_ply(rows: int = 100_000, sides: int = 255) -> bytes:
    """Binary PLY whose rows are 255-gons with uchar indices: 253 triangles per 256 bytes."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {sides}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {rows}\nproperty list uchar uchar vertex_indices\nend_header\n"
    ).encode()
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros(sides)], 1).astype("<f4")
    return header + ring.tobytes() + (bytes([sides]) + bytes(range(sides))) * rows


def tetrahedra_in_place(copies: int) -> bytes:
    return obj(CORNERS, np.tile(TETRAHEDRON, (copies, 1)))


def malformed_files() -> list[Case]:
    """Truncated, corrupt and nonsense files of every format (each must be a 4xx)."""
    sphere = obj(*_icosphere())
    binary_stl = struct.pack("<80sI", b"x", 2_000_000_000) + b"\x00" * 50
    ply_ascii = (
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    gltf_external = json.dumps(
        {"asset": {"version": "2.0"}, "buffers": [{"uri": "file:///etc/passwd", "byteLength": 9}]}
    ).encode()
    bad_glb = struct.pack("<4sII", b"glTF", 2, 10**9) + b"\x00" * 64
    cases = [
        ("empty.obj", b""),
        ("random.obj", os.urandom(4096)),
        ("random.ply", b"ply\n" + os.urandom(4096)),
        ("random.glb", b"glTF" + os.urandom(4096)),
        ("random.stl", os.urandom(4096)),
        ("truncated.obj", sphere[: len(sphere) // 2] + b"f 1 2 999999\n"),
        ("index-zero.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n"),
        ("nan.obj", b"v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
        ("no-faces.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n"),
        ("degenerate.obj", b"v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n"),
        ("lying-header.off", b"OFF\n3 5000000 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
        ("negative.off", b"OFF\n-3 1 0\n"),
        ("stl-count.stl", binary_stl),
        ("ply-truncated.ply", ply_ascii + b"0 0 0\n1 0 0\n"),
        ("ply-negative.ply", b"ply\nformat ascii 1.0\nelement vertex -5\nend_header\n"),
        ("glb-length.glb", bad_glb),
        ("gltf-external.gltf", gltf_external),
        ("binary-as-text.off", b"OFF\n\x00\x01\x02" * 100),
        ("unknown.fbx", b"Kaydara FBX Binary  \x00"),
        ("bad-json.gltf", b'{"asset": {"version": "2.0"'),
    ]
    return [Case(f"malformed/{name}", data, name, "4xx") for name, data in cases]


def _icosphere() -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(sphere.vertices), np.asarray(sphere.faces)


def first_round() -> list[Case]:
    """Issue 9: memory bombs, repeated tetrahedra, malformed files and requests."""
    mesh_id = "0" * 64
    five_million = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" + b"f 1 2 3\n" * 5_000_000
    huge = b"v 1e308 0 0\nv 0 1e308 0\nv 0 0 1e308\nv 0 0 0\nf 1 2 3\nf 1 2 4\nf 1 3 4\n"
    return [
        Case("2 glb-instancing-bomb (12 MB, 1M vertices x 40)", instancing_bomb(), "b.glb", "413"),
        Case("2 glb-aliased-accessors (2000 x 100k)", aliased_accessors(), "a.glb", "413"),
        Case("2 glb-exponential-dag (2^40)", exponential_dag(), "d.glb", "413"),
        Case("2 ply-255-gons (100k rows)", big_polygons_ply(), "p.ply", "413"),
        Case("3 tetrahedron x500 (2k faces)", tetrahedra_in_place(500), "t2k.obj", "200"),
        Case("3 tetrahedron x2500 (10k faces)", tetrahedra_in_place(2500), "t10k.obj", "200"),
        Case("3 tetrahedron x12000 (48k faces)", tetrahedra_in_place(12_000), "t48k.obj", "200"),
        Case("3 tetrahedron x475k (1.9M faces)", tetrahedra_in_place(475_000), "t19m.obj", "202"),
        Case("6 coordinates 1e308", huge, "huge.obj", "422"),
        Case("6 5M-face obj", five_million, "five.obj", "413"),
        Case("6 glb 5000-deep node chain", node_chain(), "chain.glb", "200"),
        Case("6 gltf 100000-deep json", deep_json_gltf(), "deep.gltf", "422"),
        Case(
            "6 file_type is a path",
            tetrahedra_in_place(1),
            "t.obj",
            "415",
            form={"file_type": "../../etc/passwd"},
            cli=None,
        ),
        Case(
            "6 malformed json body",
            expect="400",
            request={"method": "POST", "url": "/v1/segment", "content": b"{not json"},
            cli=None,
        ),
        Case(
            "6 NaN smoothing",
            expect="422",
            request={
                "method": "POST",
                "url": "/v1/segment",
                "content": b'{"mesh_id": "' + mesh_id.encode() + b'", "smoothing": NaN}',
            },
            cli=None,
        ),
        Case(
            "6 deep json body",
            expect="400|413",  # 413 since JSON bodies over MAX_JSON_BYTES are refused unread
            request={"method": "POST", "url": "/v1/segment", "content": b"[" * 1_000_000},
            cli=None,
        ),
        *malformed_files(),
    ]


# -- second round (issue 20) -----------------------------------------------------------------
def repeated_triangle(copies: int = 50_000) -> bytes:
    """One triangle repeated in place: every edge is shared by ``copies`` faces."""
    return obj(np.eye(3), np.tile([[0, 1, 2]], (copies, 1)))


def zero_area_fan(count: int = 20_000) -> bytes:
    """One real triangle and ``count`` zero-area faces on its first edge (one edge, k faces)."""
    along = np.column_stack([np.linspace(0.1, 0.9, count), np.zeros(count), np.zeros(count)])
    vertices = np.vstack([np.eye(3), along])
    faces = np.vstack([[[0, 1, 2]], np.column_stack([np.zeros(count), np.ones(count),
                                                     np.arange(3, 3 + count)])])  # fmt: skip
    return obj(vertices, faces.astype(int))


def separate_shells(count: int, spacing: float = 3.0) -> bytes:
    """``count`` tetrahedra on a grid, none touching: foliage cards, CAD assemblies."""
    side = int(np.ceil(count ** (1 / 3)))
    cells = np.stack(np.unravel_index(np.arange(count), (side, side, side)), 1) * spacing
    vertices = (cells[:, None, :] + CORNERS[None]).reshape(-1, 3)
    faces = (TETRAHEDRON[None] + 4 * np.arange(count)[:, None, None]).reshape(-1, 3)
    return obj(vertices, faces)


def dumbbell_obj(faces: int, scale: float = 1.0) -> bytes:
    from neural_shdf.segment.synthetic import dumbbell

    mesh, _ = dumbbell(faces)
    return obj(np.asarray(mesh.vertices) * scale, np.asarray(mesh.faces))


def upload(server: Server, data: bytes, name: str, **form) -> tuple[Answer, str | None]:
    """Upload; returns the answer and the mesh id (also of a 202)."""
    answer = timed(server, "POST", "/v1/meshes", files={"file": (name, data)}, data=form)
    if answer.status == 200:
        return answer, answer.body["mesh"]["mesh_id"]
    if answer.status == 202:
        return answer, answer.body["mesh_id"]
    return answer, None


def follow(server: Server, first: Answer, answers: list[Answer], limit_s: float = 600) -> Answer:
    """Poll a 202's job to its end (every poll kept); returns the last poll or ``first``."""
    if first.status != 202:
        return first
    deadline, poll = time.monotonic() + limit_s, first
    while time.monotonic() < deadline:
        poll = timed(server, "GET", f"/v1/jobs/{first.body['job_id']}")
        answers.append(poll)
        if poll.status != 200 or poll.body["state"] in ("succeeded", "failed"):
            break
        time.sleep(0.5)
    return poll


def get_after_jobs(server: Server, url: str, answers: list[Answer]) -> Answer:
    """GET ``url``; while it answers 202, poll the job and ask again."""
    for _ in range(4):
        answer = timed(server, "GET", url)
        answers.append(answer)
        if answer.status != 202:
            return answer
        follow(server, answer, answers)
    return answer


def bounded_get(data: bytes, name: str, url: str, expect: str) -> Callable[[Server], Outcome]:
    """Upload ``data``, then GET ``url`` (``{id}`` is the mesh id): a bounded answer."""

    def scenario(server: Server) -> Outcome:
        answers: list[Answer] = []
        first, mesh_id = upload(server, data, name)
        answers.append(first)
        follow(server, first, answers)
        if mesh_id is None:
            return Outcome(answers, matches(expect, first.status), f"upload {first.status}")
        answer = get_after_jobs(server, url.format(id=mesh_id), answers)
        return Outcome(answers, matches(expect, answer.status), f"{answer.status} {answer.code}")

    return scenario


def atlas_twice(size: int) -> Callable[[Server], Outcome]:
    """The atlas of a ~2k-face mesh at ``size`` texels, asked twice (the second is cached)."""

    def scenario(server: Server) -> Outcome:
        answers: list[Answer] = []
        first, mesh_id = upload(server, dumbbell_obj(2000), "d2k.obj")
        answers.append(first)
        url = f"/v1/meshes/{mesh_id}/segmentation/atlas.png?atlas_size={size}"
        one = get_after_jobs(server, url, answers)
        two = get_after_jobs(server, url, answers)
        ok = one.status == two.status and one.status in (200, 422)
        return Outcome(answers, ok, f"{one.status} in {one.seconds:.1f}s, again {two.seconds:.2f}s")

    return scenario


def many_shells(server: Server) -> Outcome:
    answers: list[Answer] = []
    first, mesh_id = upload(server, separate_shells(100_000), "shells.obj")
    answers.append(first)
    follow(server, first, answers)
    start = time.perf_counter()
    segment = timed(server, "POST", "/v1/segment", json={"mesh_id": mesh_id})
    answers.append(segment)
    seconds = time.perf_counter() - start
    return Outcome(answers, segment.status == 200, f"segment {segment.status}, {seconds:.1f}s")


def abandoned_requests(server: Server) -> Outcome:
    """Two 10,000-part GLB requests abandoned after 2 s, then an ordinary 20k-face upload."""
    answers: list[Answer] = []
    first, mesh_id = upload(server, dumbbell_obj(20_000), "d20k.obj")
    answers.append(first)
    url = f"/v1/meshes/{mesh_id}/segmentation/parts.glb?partitioner=metis&parts=10000"
    for _ in range(2):
        try:
            with httpx.Client(base_url=server.client.base_url, timeout=2.0) as impatient:
                answers.append(Answer(impatient.get(url).status_code, 2.0))
        except httpx.TimeoutException:
            pass  # the client has gone: the service should stop that work
    ordinary = timed(server, "POST", "/v1/meshes", files={"file": ("o.obj", dumbbell_obj(19_000))})
    answers.append(ordinary)
    full = timed(server, "GET", url)
    answers.append(full)
    ok = ordinary.status == 200 and ordinary.seconds < 10 and full.status in (200, 422)
    return Outcome(answers, ok, f"ordinary upload {ordinary.seconds:.1f}s; 10k parts "
                   f"{full.status} in {full.seconds:.1f}s")  # fmt: skip


def unknown_keys_body(server: Server) -> Outcome:
    body = {"mesh_id": "0" * 64, **{f"key{i}": i for i in range(200_000)}}
    answer = timed(server, "POST", "/v1/segment", content=json.dumps(body).encode(),
                   headers={"content-type": "application/json"})  # fmt: skip
    ok = 400 <= answer.status < 500 and answer.size < 64_000
    return Outcome([answer], ok, f"{answer.status}, error body {answer.size / 1e3:.0f} kB")


def delete_during_job(server: Server) -> Outcome:
    """Delete a mesh while its ShDF job runs; a re-upload must not find the ShDF cached."""
    answers: list[Answer] = []
    data = dumbbell_obj(60_000)
    first, mesh_id = upload(server, data, "race.obj")
    answers.append(first)
    deadline = time.monotonic() + 60
    while first.status == 202 and time.monotonic() < deadline:  # delete while it runs
        poll = timed(server, "GET", f"/v1/jobs/{first.body['job_id']}")
        answers.append(poll)
        if poll.status != 200 or poll.body["state"] != "queued":
            break
        time.sleep(0.05)
    deleted = timed(server, "DELETE", f"/v1/meshes/{mesh_id}")
    answers.append(deleted)
    follow(server, first, answers)
    again, _ = upload(server, data, "race.obj")
    answers.append(again)
    cached = again.status == 200 and again.body["shdf"]["cached"]
    ok = deleted.status == 204 and not cached
    return Outcome(answers, ok, f"delete {deleted.status}; re-upload {again.status}, "
                   f"cached {cached}")  # fmt: skip


def other_uploaders_name(server: Server) -> Outcome:
    data = dumbbell_obj(1000)
    alice, mesh_id = upload(server, data, "alice-secret-project.obj")
    bob, _ = upload(server, data, "bob.obj")
    info = timed(server, "GET", f"/v1/meshes/{mesh_id}")
    leaked = "alice" in json.dumps(bob.body)
    return Outcome([alice, bob, info], bob.status == 200 and not leaked,
                   f"second uploader sees alice's name: {leaked}")  # fmt: skip


def two_files(server: Server) -> Outcome:
    files = [("file", ("a.obj", dumbbell_obj(500))), ("file", ("b.obj", dumbbell_obj(800)))]
    answer = timed(server, "POST", "/v1/meshes", files=files)
    return Outcome([answer], answer.status == 422, f"{answer.status} {answer.code}")


def units(server: Server) -> Outcome:
    """The same dumbbell at 1e-9, 1 and 1e9: the same labels."""
    answers, labels = [], {}
    for scale in (1e-9, 1.0, 1e9):
        first, mesh_id = upload(server, dumbbell_obj(4000, scale), f"s{scale:g}.obj")
        answers.append(first)
        answer = timed(server, "POST", "/v1/segment", json={"mesh_id": mesh_id})
        answers.append(answer)
        labels[scale] = answer.body["labels"] if answer.status == 200 else None
    counts = {s: (len(set(v)) if v else None) for s, v in labels.items()}
    ok = labels[1e-9] == labels[1.0] == labels[1e9] and labels[1.0] is not None
    return Outcome(answers, ok, f"parts at 1e-9/1/1e9: {list(counts.values())}")


def every_job_polls(server: Server) -> Outcome:
    """ShDF, segmentation, unwrap and atlas jobs with method auto: every poll answers 200."""
    answers: list[Answer] = []
    data = dumbbell_obj(60_000)
    first, mesh_id = upload(server, data, "jobs.obj", method="auto")
    answers.append(first)
    follow(server, first, answers)
    for route in ("unwrapped.glb", "atlas.png"):
        get_after_jobs(server, f"/v1/meshes/{mesh_id}/segmentation/{route}?method=auto", answers)
    polls = [a.status for a in answers]
    return Outcome(answers, all(s < 500 for s in polls), f"statuses {sorted(set(polls))}")


def slow_body(server: Server) -> Outcome:
    """A client that sends its upload a byte every 0.5 s: others are not kept waiting."""
    port = int(str(server.client.base_url).rsplit(":", 1)[1])
    sock = socket.create_connection(("127.0.0.1", port))
    sock.sendall(b"POST /v1/meshes HTTP/1.1\r\nHost: x\r\nContent-Length: 100000\r\n"
                 b"Content-Type: multipart/form-data; boundary=b\r\n\r\n--b\r\n")  # fmt: skip
    answers = []
    for _ in range(6):
        sock.sendall(b"x")
        answers.append(timed(server, "GET", "/healthz"))
        time.sleep(0.5)
    sock.close()
    worst = max(a.seconds for a in answers)
    return Outcome(answers, worst < 0.5, f"healthz worst {worst * 1e3:.0f} ms while trickling")


def huge_parameters(server: Server) -> Outcome:
    """Extreme but schema-valid parameters on a small mesh: bounded answers, no 5xx."""
    answers: list[Answer] = []
    first, mesh_id = upload(server, dumbbell_obj(2000), "p.obj")
    answers.append(first)
    for params in ({"parts": 1_000_000_000}, {"clusters": 1_000_000}, {"smoothing": 1e30},
                   {"partitioner": "metis", "parts": 1_000_000}, {"seed": 2**63 - 1}):  # fmt: skip
        answers.append(timed(server, "POST", "/v1/segment", json={"mesh_id": mesh_id, **params}))
    for query in ("atlas_size=1000000", "padding=100000", "max_stretch=1.0", "atlas_size=-1"):
        answers.append(timed(server, "GET", f"/v1/meshes/{mesh_id}/segmentation/atlas.png?{query}"))
    statuses = [a.status for a in answers]
    return Outcome(answers, all(0 < s < 500 for s in statuses), f"statuses {statuses}")


def second_round() -> list[Case]:
    """Issue 20: what one request could still do to the service, and what it kept. Each
    case runs on a server of its own."""
    unwrap = "/v1/meshes/{id}/segmentation/unwrapped.glb"
    cases = [
        Case("20.1 unwrap: one triangle x50,000", repeated_triangle(), "rep.obj", cli="unwrap",
             scenario=bounded_get(repeated_triangle(), "rep.obj", unwrap, "200|422")),
        Case("20.1 unwrap: 20,000 zero-area faces on one edge", zero_area_fan(), "fan.obj",
             cli="unwrap",
             scenario=bounded_get(zero_area_fan(), "fan.obj", unwrap, "200|413|422")),
        Case("20.2 atlas 8192 on 2k faces, twice", cli=None, scenario=atlas_twice(8192)),
        Case("20.2 atlas 4096 on 2k faces, twice", cli=None, scenario=atlas_twice(4096)),
        Case("20.3 100,000 shells (400k faces)", separate_shells(100_000), "shells.obj",
             scenario=many_shells),
        Case("20.4 two abandoned 10k-part GLBs, then a 20k upload", cli=None,
             scenario=abandoned_requests),
        Case("20.5 JSON body with 200k unknown keys", cli=None, scenario=unknown_keys_body),
        Case("20.6 DELETE while the ShDF job runs", cli=None, scenario=delete_during_job),
        Case("20.7 another uploader's file name", cli=None, scenario=other_uploaders_name),
        Case("20.8 two files in one upload", cli=None, scenario=two_files),
        Case("20.9 units 1e-9 / 1 / 1e9", dumbbell_obj(4000, 1e-9), "tiny.obj",
             scenario=units),
        Case("20.10 unwrap and atlas jobs with method auto", cli=None, scenario=every_job_polls),
        Case("20.x slow upload body", cli=None, scenario=slow_body),
        Case("20.x extreme parameters", cli=None, scenario=huge_parameters),
    ]  # fmt: skip
    for case in cases:
        case.fresh = True
    return cases


def corpus() -> list[Case]:
    return [*first_round(), *second_round()]


# -- running -----------------------------------------------------------------------------------
def rss_mb(pid: int, key: str = "VmRSS:") -> float:
    """A process's resident set (``VmRSS``) or its peak (``VmHWM:``) in MB."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def tree_rss_mb(pid: int) -> float:
    """Resident memory of a process and all its descendants (worker processes) in MB."""
    total, todo = 0.0, [pid]
    while todo:
        current = todo.pop()
        rss = rss_mb(current)
        total += rss if rss == rss else 0.0
        for task in Path(f"/proc/{current}/task").glob("*"):
            with contextlib.suppress(OSError):
                todo += [int(child) for child in (task / "children").read_text().split()]
    return total


#: Polls ``/healthz`` every 50 ms and prints each latency in seconds, one per line.
HEALTH_PROBE = """
import sys, time, httpx
with httpx.Client(base_url=sys.argv[1], timeout=60) as client:
    while True:
        start = time.perf_counter()
        try:
            client.get("/healthz")
        except httpx.TransportError:
            pass
        print(time.perf_counter() - start, flush=True)
        time.sleep(0.05)
"""


class Server:
    """``neural-shdf serve`` in a child process on a free loopback port, fresh cache, with a
    monitor thread that samples its memory and kills it past ``kill_mb`` (a death,
    recorded), and a probe process that times ``/healthz``."""

    def __init__(self, workdir: Path, kill_mb: float) -> None:
        self.port = free_port()
        self.kill_mb = kill_mb
        self.cache = Path(tempfile.mkdtemp(dir=workdir, prefix="cache-"))
        env = {
            **os.environ,
            "NEURAL_SHDF_PORT": str(self.port),
            "NEURAL_SHDF_CACHE_DIR": str(self.cache),
            "NEURAL_SHDF_LOG_LEVEL": "warning",
        }
        self.log = open(workdir / f"server-{self.port}.log", "wb")  # noqa: SIM115
        self.process = subprocess.Popen(
            [sys.executable, "-m", "neural_shdf.cli", "serve"],
            env=env,
            stdout=self.log,
            stderr=subprocess.STDOUT,
        )
        base = f"http://127.0.0.1:{self.port}"
        self.client = httpx.Client(base_url=base, timeout=REQUEST_TIMEOUT_S + 30)
        self.killed = False
        self.window_rss = 0.0
        self.window_health = 0.0
        self._stop = threading.Event()
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            try:
                if self.client.get("/readyz").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if self.process.poll() is not None:
                raise RuntimeError("the server exited during start-up")
            time.sleep(0.5)
        else:
            raise RuntimeError("the server did not become ready within 180 s")
        self.baseline_mb = rss_mb(self.process.pid)
        self._threads = [
            threading.Thread(target=self._watch_memory, daemon=True),
            threading.Thread(target=self._watch_health, args=(base,), daemon=True),
        ]
        for thread in self._threads:
            thread.start()

    def _watch_memory(self) -> None:
        while not self._stop.is_set() and self.process.poll() is None:
            rss = tree_rss_mb(self.process.pid)
            if rss == rss:
                self.window_rss = max(self.window_rss, rss)
            if rss > self.kill_mb:
                self.killed = True
                self.process.send_signal(signal.SIGKILL)
            time.sleep(0.02)

    def _watch_health(self, base: str) -> None:
        """Keep the worst ``/healthz`` latency, measured by a probe process of its own: a
        thread here would also count this process's own GIL holds (parsing a million-label
        answer), which are not the server's."""
        self._probe = subprocess.Popen(
            [sys.executable, "-c", HEALTH_PROBE, base], stdout=subprocess.PIPE, text=True
        )
        assert self._probe.stdout is not None
        for line in self._probe.stdout:
            if self._stop.is_set() or self.process.poll() is not None:
                break
            self.window_health = max(self.window_health, float(line))

    def open_window(self) -> None:
        self.window_rss = tree_rss_mb(self.process.pid)
        self.window_health = 0.0

    @property
    def alive(self) -> bool:
        return self.process.poll() is None

    def close(self) -> None:
        self._stop.set()
        probe = getattr(self, "_probe", None)
        if probe is not None:
            probe.kill()
        self.client.close()
        if self.alive:
            self.process.terminate()
        self.process.wait(30)
        self.log.close()


def timed(server: Server, method: str, url: str, **kwargs) -> Answer:
    start = time.perf_counter()
    try:
        response = server.client.request(method, url, **kwargs)
    except httpx.TimeoutException:
        return Answer(0, time.perf_counter() - start, "client_timeout")
    except httpx.TransportError as error:
        return Answer(0, time.perf_counter() - start, "connection_lost", str(error))
    seconds = time.perf_counter() - start
    code = message = ""
    body = None
    if "json" in response.headers.get("content-type", ""):
        try:
            body = response.json()
        except ValueError:
            body = None
    if response.status_code >= 400 and isinstance(body, dict):
        error = body.get("error", {})
        if isinstance(error, dict):
            code, message = error.get("code", ""), str(error.get("message", ""))
    return Answer(response.status_code, seconds, code, message, body, len(response.content))


def upload_and_segment(server: Server, case: Case) -> Outcome:
    """Upload; when accepted, poll its job (if any) and segment it. Every answer is kept."""
    answers: list[Answer] = []
    first, mesh_id = upload(server, case.data, case.filename, **case.form)
    answers.append(first)
    if mesh_id is not None:
        follow(server, first, answers)
        for params in ({}, {"partitioner": "metis", "parts": 4}):
            request = {"mesh_id": mesh_id, **params}
            answers.append(timed(server, "POST", "/v1/segment", json=request))
    return Outcome(answers, matches(case.expect, first.status), f"{first.status} {first.code}")


def raw_request(server: Server, case: Case) -> Outcome:
    request = dict(case.request or {})
    answer = timed(
        server,
        request.pop("method"),
        request.pop("url"),
        headers={"content-type": "application/json"},
        **request,
    )
    return Outcome([answer], matches(case.expect, answer.status), f"{answer.status} {answer.code}")


@dataclass
class Row:
    case: Case
    outcome: Outcome
    peak_mb: float
    health_s: float
    died: str = ""


def run_api(cases: list[Case], workdir: Path, kill_mb: float) -> list[Row]:
    """Every case through one server; a fresh one after a death."""
    server = Server(workdir, kill_mb)
    rows = []
    try:
        for case in cases:
            if case.fresh and rows and not rows[-1].case.fresh:
                server.close()
                server = Server(workdir, kill_mb)
            server.open_window()
            try:
                if case.scenario is not None:
                    outcome = case.scenario(server)
                elif case.request is not None:
                    outcome = raw_request(server, case)
                else:
                    outcome = upload_and_segment(server, case)
            except Exception as error:  # noqa: BLE001 - a broken scenario is a row, not a stop
                outcome = Outcome([], False, f"scenario error: {error!r}"[:120])
            time.sleep(0.1)
            died = ""
            if not server.alive:
                died = "killed (RSS)" if server.killed else f"exited {server.process.returncode}"
            row = Row(case, outcome, server.window_rss, server.window_health, died)
            rows.append(row)
            statuses = sorted({a.status for a in outcome.answers})
            print(
                f"  api {case.name:<52} {'ok ' if outcome.ok else 'BAD'} {statuses} "
                f"peak {row.peak_mb:6.0f} MB healthz {row.health_s * 1e3:6.0f} ms {died} "
                f"| {outcome.note}",
                flush=True,
            )
            if died or case.fresh:
                server.close()
                server = Server(workdir, kill_mb)
        return rows
    finally:
        server.close()


def run_legit_api(path: Path, workdir: Path, kill_mb: float) -> Row:
    server = Server(workdir, kill_mb)
    try:
        case = Case("legit " + path.name, path.read_bytes(), path.name, "200|202")
        server.open_window()
        outcome = upload_and_segment(server, case)
        return Row(case, outcome, server.window_rss, server.window_health)
    finally:
        server.close()


#: Runs a command and prints its peak RSS: measured from this small launcher, since a
#: child's ru_maxrss starts at its parent's RSS when it was forked. The child is killed
#: past the time limit.
LAUNCHER = """
import os, subprocess, sys, time
deadline = time.monotonic() + float(sys.argv[1])
child = subprocess.Popen(sys.argv[2:], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
while True:
    pid, status, usage = os.wait4(child.pid, os.WNOHANG)
    if pid:
        break
    if time.monotonic() > deadline:
        child.kill()
    time.sleep(0.05)
print(usage.ru_maxrss)
sys.exit(os.waitstatus_to_exitcode(status))
"""


def run_cli(command: str, path: Path, workdir: Path) -> tuple[int, float, float]:
    """(exit code, seconds, peak RSS MB) of ``neural-shdf COMMAND`` on one file."""
    start = time.perf_counter()
    out = workdir / ("out.glb" if command == "unwrap" else "out.seg")
    cli = [sys.executable, "-m", "neural_shdf.cli", command, str(path), "-q", "-o", str(out)]
    result = subprocess.run(
        [sys.executable, "-c", LAUNCHER, str(REQUEST_TIMEOUT_S), *cli],
        capture_output=True,
        text=True,
    )
    peak_kb = float(result.stdout.strip() or "nan")
    return result.returncode, time.perf_counter() - start, peak_kb / 1024


def legit_inputs(workdir: Path) -> list[Path]:
    """The largest legitimate inputs: zenobia (462k faces) and zenobia subdivided once
    (1.85M faces, just under the 2M-face limit), or dumbbells where the data is absent."""
    import trimesh

    from neural_shdf.mesh_io import load_mesh
    from neural_shdf.segment.synthetic import dumbbell

    if LEGIT.exists():
        base = load_mesh(LEGIT)
        vertices, faces, first = base.vertices, base.faces, LEGIT
    else:
        mesh, _ = dumbbell(460_000)
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        first = workdir / "dumbbell-460k.ply"
        trimesh.Trimesh(vertices, faces, process=False).export(first)
    largest = workdir / f"{first.stem}-subdivided.ply"
    vertices, faces = trimesh.remesh.subdivide(vertices, faces)
    trimesh.Trimesh(vertices, faces, process=False).export(largest)
    return [first, largest]


def matches(expect: str, status: int) -> bool:
    return any(str(status) == e or (e == "4xx" and 400 <= status < 500) for e in expect.split("|"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-cli", action="store_true", help="only the service")
    parser.add_argument("--skip-legit", action="store_true", help="no legitimate inputs")
    parser.add_argument("--only", help="only the cases whose name contains this")
    parser.add_argument("--kill-mb", type=float, default=8000, help="a server past this dies")
    parser.add_argument("--keep", type=Path, help="write the corpus and logs here")
    args = parser.parse_args()
    workdir = args.keep or Path(tempfile.mkdtemp(prefix="hostile-"))
    workdir.mkdir(parents=True, exist_ok=True)
    cases = [c for c in corpus() if args.only is None or args.only in c.name]
    print(f"corpus: {len(cases)} cases, {sum(len(c.data) for c in cases) / 1e6:.0f} MB")

    legit_rows = []
    legit = [] if args.skip_legit else legit_inputs(workdir)
    for path in legit:
        row = run_legit_api(path, workdir, args.kill_mb)
        legit_rows.append(row)
        answers = row.outcome.answers
        print(f"legitimate input {path.name}: server peak {row.peak_mb:.0f} MB, answers "
              f"{[a.status for a in answers]}, slowest {max(a.seconds for a in answers):.2f}s, "
              f"healthz {row.health_s * 1e3:.0f} ms", flush=True)  # fmt: skip
    rows = run_api(cases, workdir, args.kill_mb)

    cli_rows: dict[str, tuple[int, float, float]] = {}
    legit_cli = (0, 0.0, float("nan"))
    if not args.skip_cli:
        for path in legit:
            result = run_cli("segment", path, workdir)
            legit_cli = max(legit_cli, result, key=lambda r: r[2] if r[2] == r[2] else 0)
            print(f"legitimate input {path.name}, CLI: exit {result[0]}, {result[1]:.1f}s, "
                  f"peak {result[2]:.0f} MB", flush=True)  # fmt: skip
        for case in cases:
            if case.cli is None or not case.data:
                continue
            path = workdir / "corpus" / case.filename
            path.parent.mkdir(exist_ok=True)
            path.write_bytes(case.data)
            result = run_cli(case.cli, path, workdir)
            cli_rows[case.name] = result
            print(f"  cli {case.cli} {case.name:<48} exit {result[0]} {result[1]:6.1f}s "
                  f"peak {result[2]:6.0f} MB", flush=True)  # fmt: skip

    print("\n| case | expected | verdict | statuses | slowest s | peak MB | healthz ms | "
          "CLI exit | CLI s | CLI MB | note |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for row in rows:
        code, seconds, mb = cli_rows.get(row.case.name, ("-", float("nan"), float("nan")))
        answers = row.outcome.answers
        slowest = max((a.seconds for a in answers), default=float("nan"))
        verdict = ("ok" if row.outcome.ok else "**no**") + (f", {row.died}" if row.died else "")
        statuses = ",".join(str(s) for s in sorted({a.status for a in answers}))
        print(f"| {row.case.name} | {row.case.expect or 'check'} | {verdict} | {statuses} | "
              f"{slowest:.2f} | {row.peak_mb:.0f} | {row.health_s * 1e3:.0f} | {code} | "
              f"{seconds:.1f} | {mb:.0f} | {row.outcome.note.replace('|', '/')} |")  # fmt: skip
    answers = [a for row in rows for a in row.outcome.answers]
    deaths = [r.case.name for r in rows if r.died]
    server_errors = sum(1 for a in answers if a.status >= 500 or a.status == 0)
    wrong = [r.case.name for r in rows if not r.outcome.ok]
    slowest = max((a.seconds for a in answers), default=0.0)
    stalls = [r.case.name for r in rows if r.health_s > 0.1]
    hostile_peak = max((r.peak_mb for r in rows), default=float("nan"))
    print(f"\nanswers: {len(answers)}; server deaths: {len(deaths)} {deaths} (goal 0)")
    print(f"5xx or no answer: {server_errors} (goal 0)")
    print(f"wrong answers: {len(wrong)} {wrong}")
    print(f"/healthz over 100 ms during: {len(stalls)} {stalls}")
    if legit_rows:
        legit_peak = max(r.peak_mb for r in legit_rows)
        print(f"server peak RSS: hostile {hostile_peak:.0f} MB, largest legitimate input "
              f"{legit_peak:.0f} MB, ratio {hostile_peak / legit_peak:.2f} (goal < 2)")  # fmt: skip
    print(f"slowest answer: {slowest:.2f} s (request timeout {REQUEST_TIMEOUT_S:.0f} s)")
    if cli_rows:
        crashes = [name for name, (code, *_) in cli_rows.items() if code not in (0, 2)]
        cli_peak = max(mb for *_, mb in cli_rows.values())
        print(f"CLI: exits other than 0/2: {len(crashes)} {crashes}; peak RSS hostile "
              f"{cli_peak:.0f} MB, legitimate {legit_cli[2]:.0f} MB, ratio "
              f"{cli_peak / legit_cli[2]:.2f} (goal < 2); slowest "
              f"{max(s for _, s, _ in cli_rows.values()):.1f} s")  # fmt: skip
    if args.keep is None:
        shutil.rmtree(workdir, ignore_errors=True)


if __name__ == "__main__":
    main()
