"""Mesh files for the API tests, written independently of the package's readers."""

from __future__ import annotations

import json
import os
import socket
import struct
import time
from pathlib import Path

import numpy as np
import trimesh

REPO_ROOT = Path(__file__).resolve().parents[2]
#: The committed model, unless NEURAL_SHDF_MODEL points the library (and so the tests) elsewhere.
MODEL_FILE = Path(
    os.environ.get("NEURAL_SHDF_MODEL")
    or REPO_ROOT / "service" / "neural_shdf" / "models" / "emd.onnx"
)
#: The ShDF method the tests use: neural when the model exists, else exact.
TEST_METHOD = "neural" if MODEL_FILE.is_file() else "exact"


def capsule(count: int = 12) -> trimesh.Trimesh:
    return trimesh.creation.capsule(height=2.0, radius=0.5, count=(count, count))


def obj_bytes(vertices: np.ndarray, polygons: list[list[int]]) -> bytes:
    """OBJ text; ``polygons`` are 0-based vertex index lists (any size)."""
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(vertices, dtype=float).tolist()]
    lines += ["f " + " ".join(str(i + 1) for i in poly) for poly in polygons]
    return ("\n".join(lines) + "\n").encode()


def off_bytes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    lines = ["OFF", f"{len(vertices)} {len(faces)} 0"]
    lines += [f"{x!r} {y!r} {z!r}" for x, y, z in np.asarray(vertices, dtype=float).tolist()]
    lines += ["3 " + " ".join(str(int(i)) for i in face) for face in faces]
    return ("\n".join(lines) + "\n").encode()


def quad_box(center: tuple[float, float, float], size: float) -> tuple[np.ndarray, list[list[int]]]:
    """A cube as 6 outward quads."""
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    vertices = (corners - 0.5) * size + np.asarray(center)
    quads = [[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]]
    return vertices, quads


def glb_two_nodes(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    """GLB with one mesh instanced by a root node (translated) and its child (scaled, moved).

    Triangle order: the parent's triangles, then the child's (depth-first).
    """
    positions = np.asarray(vertices, dtype=np.float32)
    indices = np.asarray(faces, dtype=np.uint32).reshape(-1)
    blob = positions.tobytes() + indices.tobytes()
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": positions.nbytes},
            {"buffer": 0, "byteOffset": positions.nbytes, "byteLength": indices.nbytes},
        ],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "type": "VEC3",
                "count": len(positions),
                "min": positions.min(0).tolist(),
                "max": positions.max(0).tolist(),
            },
            {"bufferView": 1, "componentType": 5125, "type": "SCALAR", "count": len(indices)},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [
            {"mesh": 0, "translation": [-4.0, 0.0, 0.0], "children": [1]},
            {"mesh": 0, "translation": [8.0, 0.0, 0.0], "scale": [0.5, 0.5, 0.5]},
        ],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }
    return glb_container(json.dumps(doc).encode(), blob)


def glb_container(json_chunk: bytes, bin_chunk: bytes) -> bytes:
    json_chunk += b" " * (-len(json_chunk) % 4)
    bin_chunk += b"\x00" * (-len(bin_chunk) % 4)
    total = 12 + 8 + len(json_chunk) + 8 + len(bin_chunk)
    return (
        struct.pack("<4sII", b"glTF", 2, total)
        + struct.pack("<II", len(json_chunk), 0x4E4F534A)
        + json_chunk
        + struct.pack("<II", len(bin_chunk), 0x004E4942)
        + bin_chunk
    )


def parts_within_blocks(labels: list[int], block_sizes: list[int]) -> bool:
    """True when every part label occurs inside one contiguous block of faces only."""
    owner: dict[int, int] = {}
    start = 0
    for block, size in enumerate(block_sizes):
        for label in labels[start : start + size]:
            if owner.setdefault(label, block) != block:
                return False
        start += size
    return start == len(labels)


def wait_job(client, job: dict, timeout_s: float = 60.0) -> dict:
    """Poll a job until it is finished."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job['job_id']}").json()
        if job["state"] in ("succeeded", "failed"):
            return job
        time.sleep(0.05)
    raise AssertionError(f"job {job['job_id']} did not finish: {job}")


def metric(app, name: str, **labels: str) -> float:
    """A Prometheus sample of an app instance."""
    return app.state.engine.metrics.value(name, labels)


def free_port() -> int:
    """A free TCP port on loopback."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def make_settings(cache_dir: Path, **overrides):
    """Service settings for tests: a temp cache, the test method, no Redis, no env file."""
    from neural_shdf.api.settings import Settings

    values = {"cache_dir": cache_dir, "default_method": TEST_METHOD, "redis_url": None}
    values.update(overrides)
    return Settings(_env_file=None, **values)


def quad_dumbbell_obj(rings: int = 24, sectors: int = 16, jitter: float = 0.15) -> bytes:
    """Two balls joined by a thin bar around the x axis, as an OBJ of quads (triangle fans
    at the poles). Vertices are moved radially by up to ``jitter`` (fixed seed), so the
    quads are not planar and part boundaries run through some of them: the two triangles
    of such a quad get different labels and differ in area."""
    x = np.linspace(-3.0, 3.0, rings)
    radius = np.where(np.abs(x) < 1.0, 0.25, np.sqrt(np.clip(1 - (np.abs(x) - 2) ** 2, 0, None)))
    radius[[1, -2]] = np.maximum(radius[[1, -2]], 0.3)
    angles = np.linspace(0, 2 * np.pi, sectors, endpoint=False)
    rings_xyz = [
        [[x[i], radius[i] * np.cos(a), radius[i] * np.sin(a)] for a in angles]
        for i in range(1, rings - 1)
    ]
    vertices = np.array([[x[0], 0, 0], *np.concatenate(rings_xyz), [x[-1], 0, 0]])
    vertices *= 1 + jitter * np.random.default_rng(1).uniform(-1, 1, (len(vertices), 1))

    def ring(i: int, j: int) -> int:
        return 1 + (i - 1) * sectors + j % sectors

    last = len(vertices) - 1
    polygons = [[0, ring(1, j + 1), ring(1, j)] for j in range(sectors)]
    polygons += [
        [ring(i, j), ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)]
        for i in range(1, rings - 2)
        for j in range(sectors)
    ]
    polygons += [[last, ring(rings - 2, j), ring(rings - 2, j + 1)] for j in range(sectors)]
    return obj_bytes(vertices, polygons)


def instanced_glb(vertex_count: int, children: int) -> bytes:
    """A GLB whose one mesh (``vertex_count`` vertices, one triangle) is placed by each of
    ``children`` nodes: a small file that expands to ``children * vertex_count`` vertices."""
    positions = np.random.default_rng(0).random((vertex_count, 3)).astype("<f4")
    indices = np.array([0, 1, 2], dtype="<u4")
    blob = positions.tobytes() + indices.tobytes()
    document = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": positions.nbytes},
            {"buffer": 0, "byteOffset": positions.nbytes, "byteLength": indices.nbytes},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": vertex_count},
            {"bufferView": 1, "componentType": 5125, "type": "SCALAR", "count": 3},
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"children": list(range(1, children + 1))}]
        + [{"mesh": 0, "translation": [i, 0, 0]} for i in range(children)],
        "scenes": [{"nodes": [0]}],
    }
    return glb_container(json.dumps(document).encode(), blob)
