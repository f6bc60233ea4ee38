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
