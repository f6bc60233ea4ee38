"""Hostile meshes and requests through a real ``neural-shdf serve`` on loopback and the CLI.

Generates the corpus of issue 9 (memory bombs in valid files, the same tetrahedron
repeated in place, messages and contracts) plus a set of malformed files, then:

* starts ``neural-shdf serve`` (one worker, default limits, a fresh disk cache) per
  legitimate input, uploads it, segments it (graph cut and METIS) and reads the
  server's peak RSS (``VmHWM``): ``dense-dev`` zenobia (462k faces, where
  ``../shared/data`` exists; else a dumbbell) and the same subdivided once (1.85M
  faces, the largest input the 2M-face limit lets through);
* starts a fresh server and sends every hostile case (uploads, then a segmentation
  of what was accepted; jobs are polled to their end), recording each status, how
  long each answer took and the server's peak RSS;
* runs ``neural-shdf segment`` on every hostile file and on the legitimate inputs
  (exit code, seconds, peak RSS of the process).

Prints one row per case and the figures: 5xx answers (goal 0), hostile peak RSS over
the legitimate one (goal under 2x), slowest answer against the request timeout.

    python benchmarks/hostile_corpus.py [--skip-cli] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

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
class Case:
    """One hostile input: a file to upload (or a raw request) and what a good answer is."""

    name: str
    data: bytes = b""
    filename: str = ""
    expect: str = ""  # the status (or statuses, "200|202") a correct service gives
    form: dict = field(default_factory=dict)
    request: dict | None = None  # a raw request instead of an upload
    cli: bool = True


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


def corpus() -> list[Case]:
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
            cli=False,
        ),
        Case(
            "6 malformed json body",
            expect="400",
            request={"method": "POST", "url": "/v1/segment", "content": b"{not json"},
            cli=False,
        ),
        Case(
            "6 NaN smoothing",
            expect="422",
            request={
                "method": "POST",
                "url": "/v1/segment",
                "content": b'{"mesh_id": "' + mesh_id.encode() + b'", "smoothing": NaN}',
            },
            cli=False,
        ),
        Case(
            "6 deep json body",
            expect="400",
            request={"method": "POST", "url": "/v1/segment", "content": b"[" * 1_000_000},
            cli=False,
        ),
        *malformed_files(),
    ]


# -- running -----------------------------------------------------------------------------------
def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def peak_rss_mb(pid: int) -> float:
    """The process's peak resident set (VmHWM) in MB."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Server:
    """``neural-shdf serve`` in a child process on a free loopback port, fresh cache."""

    def __init__(self, workdir: Path) -> None:
        self.port = free_port()
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
        self.client = httpx.Client(
            base_url=f"http://127.0.0.1:{self.port}", timeout=REQUEST_TIMEOUT_S + 30
        )
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            try:
                if self.client.get("/readyz").status_code == 200:
                    return
            except httpx.TransportError:
                pass
            if self.process.poll() is not None:
                raise RuntimeError("the server exited during start-up")
            time.sleep(0.5)
        raise RuntimeError("the server did not become ready within 180 s")

    def peak_mb(self) -> float:
        return peak_rss_mb(self.process.pid)

    def close(self) -> None:
        self.client.close()
        self.process.terminate()
        self.process.wait(30)
        self.log.close()


@dataclass
class Answer:
    status: int
    seconds: float
    code: str = ""
    message: str = ""
    body: object = None


def timed(server: Server, method: str, url: str, **kwargs) -> Answer:
    start = time.perf_counter()
    try:
        response = server.client.request(method, url, **kwargs)
    except httpx.TimeoutException:
        return Answer(0, time.perf_counter() - start, "client_timeout")
    seconds = time.perf_counter() - start
    code = message = ""
    if response.status_code >= 400 and "json" in response.headers.get("content-type", ""):
        error = response.json().get("error", {})
        code, message = error.get("code", ""), error.get("message", "")
    body = response.json() if "json" in response.headers.get("content-type", "") else None
    return Answer(response.status_code, seconds, code, message, body)


def upload_and_segment(server: Server, case: Case, answers: list[Answer]) -> Answer:
    """Upload; when accepted, poll its job (if any) and segment it. Every answer is kept."""
    first = timed(
        server, "POST", "/v1/meshes", files={"file": (case.filename, case.data)}, data=case.form
    )
    answers.append(first)
    if first.status not in (200, 202):
        return first
    body = first.body
    mesh_id = body["mesh_id"] if first.status == 202 else body["mesh"]["mesh_id"]
    if first.status == 202:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline:
            poll = timed(server, "GET", f"/v1/jobs/{body['job_id']}")
            answers.append(poll)
            if poll.status != 200 or poll.body["state"] in ("succeeded", "failed"):
                break
            time.sleep(1.0)
    for params in ({}, {"partitioner": "metis", "parts": 4}):
        answers.append(timed(server, "POST", "/v1/segment", json={"mesh_id": mesh_id, **params}))
    return first


def run_api(cases: list[Case], workdir: Path) -> tuple[list[tuple[Case, Answer]], list, float]:
    server = Server(workdir)
    rows, answers = [], []
    try:
        for case in cases:
            if case.request is not None:
                request = dict(case.request)
                answer = timed(
                    server,
                    request.pop("method"),
                    request.pop("url"),
                    headers={"content-type": "application/json"},
                    **request,
                )
                answers.append(answer)
            else:
                answer = upload_and_segment(server, case, answers)
            rows.append((case, answer))
            print(
                f"  api {case.name:<48} {answer.status:>3} {answer.seconds:7.2f}s "
                f"{answer.code:<22} peak {server.peak_mb():7.0f} MB",
                flush=True,
            )
        return rows, answers, server.peak_mb()
    finally:
        server.close()


def run_legit_api(path: Path, workdir: Path) -> tuple[float, list[Answer]]:
    server = Server(workdir)
    try:
        answers: list[Answer] = []
        case = Case("legit", path.read_bytes(), path.name, "200|202")
        upload_and_segment(server, case, answers)
        return server.peak_mb(), answers
    finally:
        server.close()


#: Runs a command and prints its peak RSS: measured from this small launcher, since a
#: child's ru_maxrss starts at its parent's RSS when it was forked.
LAUNCHER = """
import os, subprocess, sys
child = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
_, status, usage = os.wait4(child.pid, 0)
print(usage.ru_maxrss)
sys.exit(os.waitstatus_to_exitcode(status))
"""


def run_cli(path: Path, workdir: Path) -> tuple[int, float, float]:
    """(exit code, seconds, peak RSS MB) of ``neural-shdf segment`` on one file."""
    start = time.perf_counter()
    command = [sys.executable, "-m", "neural_shdf.cli", "segment", str(path), "-q", "-o",
               str(workdir / "out.seg")]  # fmt: skip
    result = subprocess.run(
        [sys.executable, "-c", LAUNCHER, *command], capture_output=True, text=True
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
    parser.add_argument("--keep", type=Path, help="write the corpus and logs here")
    args = parser.parse_args()
    workdir = args.keep or Path(tempfile.mkdtemp(prefix="hostile-"))
    workdir.mkdir(parents=True, exist_ok=True)
    cases = corpus()
    print(f"corpus: {len(cases)} cases, {sum(len(c.data) for c in cases) / 1e6:.0f} MB")

    legit = legit_inputs(workdir)
    legit_peaks = []
    for path in legit:
        peak, legit_answers = run_legit_api(path, workdir)
        legit_peaks.append(peak)
        print(
            f"legitimate input {path.name}: server peak {peak:.0f} MB, answers "
            f"{[a.status for a in legit_answers]}, slowest "
            f"{max(a.seconds for a in legit_answers):.2f}s",
            flush=True,
        )
    legit_peak = max(legit_peaks)
    rows, answers, hostile_peak = run_api(cases, workdir)

    cli_rows = []
    legit_cli = (0, 0.0, 0.0)
    if not args.skip_cli:
        for path in legit:
            result = run_cli(path, workdir)
            legit_cli = max(legit_cli, result, key=lambda r: r[2])
            print(f"legitimate input {path.name}, CLI: exit {result[0]}, {result[1]:.1f}s, "
                  f"peak {result[2]:.0f} MB", flush=True)  # fmt: skip
        for case in cases:
            if not case.cli or case.request is not None:
                continue
            path = workdir / "corpus" / case.filename
            path.parent.mkdir(exist_ok=True)
            path.write_bytes(case.data)
            result = run_cli(path, workdir)
            cli_rows.append((case, *result))
            print(f"  cli {case.name:<48} exit {result[0]} {result[1]:6.1f}s "
                  f"peak {result[2]:6.0f} MB", flush=True)  # fmt: skip

    print("\n| case | expected | API status | API s | error code | CLI exit | CLI s | CLI MB |")
    print("|---|---|---|---|---|---|---|---|")
    cli_by_name = {c.name: (code, s, mb) for c, code, s, mb in cli_rows}
    for case, answer in rows:
        code, seconds, mb = cli_by_name.get(case.name, ("-", float("nan"), float("nan")))
        ok = "" if matches(case.expect, answer.status) else " (!)"
        print(
            f"| {case.name} | {case.expect} | {answer.status}{ok} | {answer.seconds:.2f} | "
            f"{answer.code} | {code} | {seconds:.1f} | {mb:.0f} |"
        )
    server_errors = sum(1 for a in answers if a.status >= 500 or a.status == 0)
    unexpected = [c.name for c, a in rows if not matches(c.expect, a.status)]
    slowest = max(a.seconds for a in answers)
    cli_crashes = [c.name for c, code, *_ in cli_rows if code not in (0, 2)]
    cli_peak = max((mb for *_, mb in cli_rows), default=float("nan"))
    print(f"\nanswers: {len(answers)}; 5xx or no answer: {server_errors} (goal 0)")
    print(f"unexpected statuses: {len(unexpected)} {unexpected}")
    print(
        f"server peak RSS: hostile {hostile_peak:.0f} MB, largest legitimate input "
        f"{legit_peak:.0f} MB (each: {', '.join(f'{p:.0f}' for p in legit_peaks)}), ratio "
        f"{hostile_peak / legit_peak:.2f} (goal < 2)"
    )
    print(f"slowest answer: {slowest:.2f} s (request timeout {REQUEST_TIMEOUT_S:.0f} s)")
    if cli_rows:
        print(
            f"CLI: exits other than 0/2: {len(cli_crashes)} {cli_crashes}; peak RSS hostile "
            f"{cli_peak:.0f} MB, legitimate {legit_cli[2]:.0f} MB, ratio "
            f"{cli_peak / legit_cli[2]:.2f} (goal < 2); slowest "
            f"{max(s for _, _, s, _ in cli_rows):.1f} s"
        )
    if args.keep is None:
        shutil.rmtree(workdir, ignore_errors=True)


if __name__ == "__main__":
    main()
