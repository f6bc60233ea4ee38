"""Round trip of the Blender add-on at about 10k and 100k polygons, against a live service.

    python benchmarks/bench_blender_addon.py [--blender-python PY] [--cuts 20 67]

Runs the add-on (installed from its zip) in Blender's Python (the real ``bpy`` module,
headless; default ``.venv-blender/bin/python``) on the test dumbbell subdivided to about
10k and 100k quads (twice as many triangles: the 100k mesh's ShDF runs as a job), and
reports, in one run per size:

- "Segment Selected" wall time, first run (upload + ShDF + partition + write-back) and a
  re-run with a new smoothing value (mesh id only, no upload: the service re-cuts from
  the basis it kept for the mesh);
- the operator's steps timed apart on a second copy of the geometry: prepare (evaluate
  modifiers, PLY; main thread), worker (network + service), apply (attribute, colours,
  materials), and the service's own times;
- the same re-run through the Python client (httpx) on the same mesh id, and the ratio.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO / "benchmarks"), str(REPO)]

from bench_service import start_server  # noqa: E402

from neural_shdf.client import Client  # noqa: E402
from scripts.build_blender_addon import build  # noqa: E402

SESSION = REPO / "tests" / "blender_addon" / "blender_session.py"
# First run: the panel's defaults. Re-run: a new smoothing value, by mesh id (the service
# re-cuts from the basis it kept for the mesh).
FIRST = {"partitioner": "graphcut", "clusters": 9, "smoothing": 0.06, "assign_materials": True}
AGAIN = {"smoothing": 0.1}


def run_session(python: str, zip_path: Path, steps: list[dict], folder: Path) -> list[dict]:
    spec, out = folder / "spec.json", folder / "out.json"
    spec.write_text(json.dumps({"zip": str(zip_path), "steps": steps}))
    env = {**os.environ, "BLENDER_USER_RESOURCES": str(folder / "user")}
    done = subprocess.run(
        [python, str(SESSION), str(spec), str(out)], env=env, capture_output=True, text=True
    )
    if done.returncode != 0:
        raise RuntimeError(done.stdout[-2000:] + done.stderr[-2000:])
    return json.loads(out.read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--blender-python", default=str(REPO / ".venv-blender/bin/python"))
    parser.add_argument("--cuts", type=int, nargs="+", default=[20, 67])
    parser.add_argument("--method", default="auto", help="the service's default ShDF method")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="bench-addon-"))
    process, base = start_server(str(folder / "cache"), args.method, 1)
    try:
        zip_path = build(folder / "dist")
        steps: list[dict] = []
        for cuts in args.cuts:
            a, b = f"A{cuts}", f"B{cuts}"
            steps += [
                {"make": "dumbbell", "name": a, "cuts": cuts},
                {"segment": [a], "settings": {"server_url": base, **FIRST}},
                {"segment": [a], "settings": AGAIN},
                {"make": "dumbbell", "name": b, "cuts": cuts, "stretch": 1.1},
                {"phases": [b], "settings": FIRST},
                {"phases": [b], "settings": AGAIN, "payload": str(folder / f"{b}.ply")},
            ]
        records = run_session(args.blender_python, zip_path, steps, folder)[1:]
        rows = []
        for index, cuts in enumerate(args.cuts):
            made, first, again, _, split_first, split_again = records[6 * index : 6 * index + 6]
            polygons = made["make"]["polygons"]
            with Client(base) as client:
                mesh_id = client.segment_file(folder / f"B{cuts}.ply", **FIRST_OPTIONS).mesh_id
                start = time.perf_counter()
                client.segment(mesh_id, smoothing=0.11)  # a value not asked before
                client_again = time.perf_counter() - start
            rows.append(
                {
                    "polygons": polygons,
                    "triangles": 2 * polygons,
                    "payload_mb": split_first["phases"]["payload_bytes"] / 1e6,
                    "first_s": first["segment"]["seconds"],
                    "again_s": again["segment"]["seconds"],
                    "prepare_s": split_first["phases"]["prepare_s"],
                    "worker_first_s": split_first["phases"]["worker_s"],
                    "service_shdf_s": split_first["phases"]["server_ms"]["shdf_ms"] / 1e3,
                    "service_segment_s": split_first["phases"]["server_ms"]["segment_ms"] / 1e3,
                    "apply_s": split_first["phases"]["apply_s"],
                    "worker_again_s": split_again["phases"]["worker_s"],
                    "prepare_again_s": split_again["phases"]["prepare_s"],
                    "apply_again_s": split_again["phases"]["apply_s"],
                    "client_again_s": client_again,
                    "parts": first["segment"]["output"].strip(),
                }
            )
    finally:
        process.terminate()
        process.wait(timeout=30)
    print(
        f"Blender add-on round trip ({args.method} ShDF, {os.cpu_count()} cores, load "
        f"{os.getloadavg()[0]:.1f})"
    )
    print(
        "| polygons (triangles) | PLY MB | first run s | re-run s | prepare s | worker s "
        "(service ShDF + partition) | apply s | re-run worker s | client re-run s | "
        "re-run / client |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['polygons']} ({r['triangles']}) | {r['payload_mb']:.2f} | {r['first_s']:.2f} "
            f"| {r['again_s']:.2f} | {r['prepare_s']:.2f} | {r['worker_first_s']:.2f} "
            f"({r['service_shdf_s']:.2f} + {r['service_segment_s']:.2f}) | {r['apply_s']:.2f} "
            f"| {r['worker_again_s']:.2f} | {r['client_again_s']:.2f} "
            f"| {r['again_s'] / r['client_again_s']:.1f}x |"
        )
    print(json.dumps(rows))


FIRST_OPTIONS = {"partitioner": "graphcut", "clusters": 9, "smoothing": 0.06}

if __name__ == "__main__":
    main()
