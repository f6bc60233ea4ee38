"""The whole ``neural-shdf segment`` at about 1M faces, two trees side by side (issue 18).

A dense-dev scan (default horse_head) midpoint-subdivided to about 1M faces (the same
piecewise-flat surface), written once as binary PLY under ``--cache-dir`` (never in the
repository). Each run is a fresh ``python -m neural_shdf.cli segment MESH -o OUT -q``
process with ``PYTHONPATH`` at a tree's ``service`` folder: this checkout, and
``--before`` (e.g. a ``git worktree`` of an earlier commit) where given, alternating
before/after so both see the same load. Per run: wall seconds, CPU seconds of the child
(user + system, every thread) and the 1-minute load average when it started; then each
tree's best and median. The ``.seg`` files of every run must be identical bytes (the
labels bit for bit); the script exits 1 where they are not.

``--stages`` also times each stage inside one process per tree (imports, load, ShDF,
segment, write; wall and CPU), ``--stage-runs`` times each, alternating.

The first run of each tree compiles or loads its numba cache and is not counted.
The machine's cores may be shared: compare CPU seconds where the wall clock is noisy.

    nice -n 10 python benchmarks/bench_cli_million.py --before /tmp/head [--runs 5] [--stages]
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DENSE = REPO / ".." / "shared" / "data" / "dense-dev"
DEFAULT_CACHE = Path("/tmp/neural-shdf-bench-cli-million")
#: Midpoint subdivisions stop at the first count at or above this many faces.
TARGET_FACES = 800_000

#: Run in a child per tree for ``--stages``: seconds (wall, CPU) of each stage, as JSON.
STAGES = r"""
import json, sys, time
from pathlib import Path
marks, clock = {}, [time.perf_counter(), time.process_time()]
def mark(name):
    now = [time.perf_counter(), time.process_time()]
    marks[name] = [now[0] - clock[0], now[1] - clock[1]]
    clock[:] = now
from neural_shdf.exchange.seg import write_labels
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import SegmentParams, compute_shdf, segment
mark("imports")
mesh = load_mesh(Path(sys.argv[1]))
mark("load")
shdf = compute_shdf(mesh)
mark("ShDF")
result = segment(mesh, shdf, SegmentParams())
mark("segment")
write_labels(sys.argv[2], result.input_face_parts(mesh)[0])
mark("write")
print(json.dumps(marks))
"""


def subdivided_mesh(scan: str, cache_dir: Path) -> Path:
    """The scan midpoint-subdivided to at least ``TARGET_FACES`` faces, as binary PLY
    (cached)."""
    import numpy as np
    import trimesh

    from neural_shdf.geometry import midpoint_subdivide

    sources = sorted(DENSE.glob(f"*{scan}*.ply")) if DENSE.is_dir() else []
    if not sources:
        raise SystemExit(f"no dense-dev scan matching {scan!r} under {DENSE}")
    source = sources[0]
    mesh = trimesh.load(source, process=False)
    faces = len(mesh.faces)
    passes = 0
    while faces < TARGET_FACES:
        faces, passes = 4 * faces, passes + 1
    path = cache_dir / f"{source.stem.split('__')[-1]}_x{passes}_{faces}.ply"
    if not path.is_file():
        cache_dir.mkdir(parents=True, exist_ok=True)
        vertices, triangles, _ = midpoint_subdivide(
            np.asarray(mesh.vertices), np.asarray(mesh.faces), passes
        )
        trimesh.Trimesh(vertices, triangles, process=False).export(path)
    return path


def environment(tree: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": str(tree / "service")}


def cli_run(tree: Path, mesh: Path, output: Path) -> tuple[float, float, float]:
    """(wall, CPU, load average at the start) of one ``segment`` process."""
    load = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    command = [sys.executable, "-m", "neural_shdf.cli", "segment", str(mesh), "-o", str(output)]
    subprocess.run([*command, "-q"], env=environment(tree), cwd=tree, check=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, load


def stage_run(tree: Path, mesh: Path, output: Path) -> dict[str, list[float]]:
    done = subprocess.run(
        [sys.executable, "-c", STAGES, str(mesh), str(output)],
        env=environment(tree),
        cwd=tree,
        check=True,
        capture_output=True,
        text=True,
    )
    stages: dict[str, list[float]] = json.loads(done.stdout.strip().splitlines()[-1])
    return stages


def summary(name: str, runs: list[tuple[float, float, float]]) -> str:
    walls, cpus, loads = zip(*runs, strict=True)
    return (
        f"{name:7s} wall best {min(walls):5.2f} median {statistics.median(walls):5.2f} s, "
        f"CPU best {min(cpus):5.2f} median {statistics.median(cpus):5.2f} s "
        f"(load {min(loads):.1f}-{max(loads):.1f}, {len(runs)} runs)"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", type=Path, help="another tree (its service/ is imported)")
    parser.add_argument("--scan", default="horse_head", help="dense-dev file name part")
    parser.add_argument("--runs", type=int, default=5, help="counted runs per tree")
    parser.add_argument("--stages", action="store_true", help="also time each stage")
    parser.add_argument("--stage-runs", type=int, default=3)
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE)
    args = parser.parse_args()
    mesh = subdivided_mesh(args.scan, args.cache_dir)
    trees = {"after": REPO}
    if args.before is not None:
        trees = {"before": args.before.resolve(), "after": REPO}
    outputs = {name: args.cache_dir / f"{name}.seg" for name in trees}
    print(f"mesh: {mesh} ({mesh.stat().st_size / 1e6:.0f} MB)")
    for name, tree in trees.items():  # compiles or loads each tree's numba cache
        cli_run(tree, mesh, outputs[name])
    first = {name: outputs[name].read_bytes() for name in trees}
    runs: dict[str, list[tuple[float, float, float]]] = {name: [] for name in trees}
    identical = True
    for run in range(args.runs):
        for name, tree in trees.items():
            wall, cpu, load = cli_run(tree, mesh, outputs[name])
            runs[name].append((wall, cpu, load))
            identical &= outputs[name].read_bytes() == first[name]
            print(f"run {run + 1} {name:7s} wall {wall:5.2f} s CPU {cpu:5.2f} s load {load:.1f}")
    for name in trees:
        print(summary(name, runs[name]))
    if len(trees) == 2:
        before, after = runs["before"], runs["after"]
        for k, what in ((0, "wall"), (1, "CPU")):
            best = min(r[k] for r in after) / min(r[k] for r in before)
            middle = statistics.median(r[k] for r in after) / statistics.median(
                r[k] for r in before
            )
            print(f"after / before {what}: best {best:.2f}, median {middle:.2f}")
        identical &= filecmp.cmp(outputs["before"], outputs["after"], shallow=False)
    if args.stages:
        stage_times: dict[str, list[dict[str, list[float]]]] = {name: [] for name in trees}
        for _ in range(args.stage_runs):
            for name, tree in trees.items():
                stage_times[name].append(stage_run(tree, mesh, outputs[name]))
                identical &= outputs[name].read_bytes() == first[name]
        print("stages, best of runs: wall (CPU) seconds")
        for name in trees:
            cells = []
            for stage in stage_times[name][0]:
                wall = min(run[stage][0] for run in stage_times[name])
                cpu = min(run[stage][1] for run in stage_times[name])
                cells.append(f"{stage} {wall:.2f} ({cpu:.2f})")
            print(f"{name:7s} " + ", ".join(cells))
    print(f"load average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("labels identical in every run" if identical else "LABELS DIFFER")
    return 0 if identical else 1


if __name__ == "__main__":
    raise SystemExit(main())
