"""Batch throughput, Dask overhead and resume, measured side by side in one run.

1. ``throughput``: per data set (psb-dev's 76 meshes; the 151 misc training shapes, unpacked
   to a temporary folder outside the repository), a shell loop over ``neural-shdf segment``
   against ``neural-shdf batch --workers 2``, alternating. Assets/s and faces/s for both and
   the speed-up (goal >= 5x).
2. ``dask``: the same batch on the local pool (2 processes) and on a Dask ``LocalCluster``
   of 2 single-threaded worker processes (cluster start-up not counted), alternating;
   overhead per asset = dask time / local time - 1 (goal <= 15%).
3. ``resume``: 1,000 small generated meshes, 5% of them corrupt, in a batch that is killed
   (SIGKILL of the whole process group) part-way and run again: every good asset done,
   every bad one reported, and nothing finished before the kill computed again.

Every step runs in child processes; ``cpu_s`` is their CPU time (user + system), less
inflated than wall time on a shared, oversubscribed machine, so both are printed with
their ratios. The load average is printed before and after each step.

    nice -n 10 python benchmarks/bench_batch.py [--steps throughput dask resume]
        [--sets psb misc] [--sample N] [--repeat 1] [--work DIR]
"""

from __future__ import annotations

import argparse
import csv
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("NEURAL_SHDF_DATA", REPO / ".." / "shared" / "data"))
ENV = {**os.environ, "PYTHONPATH": f"{REPO / 'service'}:{REPO}"}
CLI = [sys.executable, "-m", "neural_shdf.cli"]


def load() -> str:
    one, five, _ = os.getloadavg()
    return f"load average {one:.1f} (1 min), {five:.1f} (5 min) on {os.cpu_count()} cores"


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timed(command: list[str], **kwargs) -> tuple[float, float, int]:
    """(wall seconds, CPU seconds of the process tree, exit code)."""
    cpu, start = children_cpu(), time.perf_counter()
    code = subprocess.run(command, env=ENV, **kwargs).returncode
    return time.perf_counter() - start, children_cpu() - cpu, code


def manifest_rows(out: Path) -> list[dict[str, str]]:
    with open(out / "manifest.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def mesh_files(folder: Path, sample: int | None) -> list[Path]:
    from neural_shdf.batch import collect_assets

    files = [Path(a.path) for a in collect_assets([folder])]
    if sample and sample < len(files):
        files = files[:: max(1, len(files) // sample)][:sample]
    return files


def data_sets(names: list[str], work: Path) -> dict[str, Path]:
    sets = {}
    if "psb" in names:
        sets["psb-dev"] = DATA / "psb-dev" / "off"
    if "misc" in names:
        target = work / "misc"
        if not target.is_dir():
            with tarfile.open(DATA / "train-shapes" / "misc.tar.xz") as archive:
                archive.extractall(target, filter="data")
        sets["misc"] = target
    for name, folder in sets.items():
        if not folder.is_dir():
            raise SystemExit(f"{folder} is absent: {name} needs ../shared/data")
    return sets


def listing(files: list[Path], path: Path) -> Path:
    path.write_text("".join(f"{f}\n" for f in files))
    return path


def throughput(args: argparse.Namespace, work: Path) -> None:
    print("\n## throughput: shell loop over `neural-shdf segment` vs `batch --workers 2`")
    header = (
        f"{'set':>8} {'assets':>6} {'faces':>9} {'how':>6} {'wall_s':>8} {'cpu_s':>8} "
        f"{'assets/s':>8} {'faces/s':>9} {'failed':>6}"
    )
    results = []
    for name, folder in data_sets(args.sets, work).items():
        files = mesh_files(folder, args.sample)
        manifest = listing(files, work / f"{name}.txt")
        print(f"{name}: {len(files)} meshes, {args.method} ShDF; {load()}")
        loop_script = (
            'i=0; while read -r f; do i=$((i+1)); "$@" segment "$f" -o "$OUT/$i.seg" -q '
            f"--method {args.method} "
            '|| echo "failed: $f" >&2; done < "$LIST"'
        )
        walls: dict[str, list[float]] = {"loop": [], "batch": []}
        cpus: dict[str, list[float]] = {"loop": [], "batch": []}
        faces, failed = 0, {"loop": 0, "batch": 0}
        for _ in range(args.repeat):
            out = work / f"{name}-loop"
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir()
            wall, cpu, _ = _loop(loop_script, out, manifest)
            walls["loop"].append(wall)
            cpus["loop"].append(cpu)
            failed["loop"] = len(files) - len(list(out.glob("*.seg")))
            out = work / f"{name}-batch"
            shutil.rmtree(out, ignore_errors=True)
            wall, cpu, _ = timed([*CLI, "batch", str(manifest), "-o", str(out), "--workers", "2",
                                  "--method", args.method, "-q"])  # fmt: skip
            walls["batch"].append(wall)
            cpus["batch"].append(cpu)
            rows = manifest_rows(out)
            failed["batch"] = sum(r["status"] == "failed" for r in rows)
            faces = sum(int(r["faces"]) for r in rows if r["faces"])
        print(header)
        for how in ("loop", "batch"):
            wall, cpu = min(walls[how]), min(cpus[how])
            print(
                f"{name:>8} {len(files):>6} {faces:>9} {how:>6} {wall:>8.1f} {cpu:>8.1f} "
                f"{len(files) / wall:>8.3f} {faces / wall:>9.0f} {failed[how]:>6}"
            )
        speedup = min(walls["loop"]) / min(walls["batch"])
        cpu_speedup = min(cpus["loop"]) / min(cpus["batch"])
        results.append((name, speedup, cpu_speedup))
        print(f"{name}: batch speed-up {speedup:.2f}x wall, {cpu_speedup:.2f}x CPU "
              f"(goal >= 5x wall); {load()}")  # fmt: skip
    for name, speedup, cpu_speedup in results:
        print(f"RESULT throughput {name}: {speedup:.2f}x wall, {cpu_speedup:.2f}x CPU, "
              f"{'met' if speedup >= 5 else 'NOT met'}")  # fmt: skip


def _loop(script: str, out: Path, manifest: Path) -> tuple[float, float, int]:
    env = {**ENV, "OUT": str(out), "LIST": str(manifest)}
    cpu, start = children_cpu(), time.perf_counter()
    code = subprocess.run(["bash", "-c", script, "loop", *CLI], env=env).returncode
    return time.perf_counter() - start, children_cpu() - cpu, code


DASK_RUNNER = r"""
import json, logging, resource, sys, time
from distributed import Client, LocalCluster
from neural_shdf.batch import run_batch

manifest, out, mode, method = sys.argv[1:5]
if mode.startswith("dask"):
    if mode == "dask-noprofile":  # the workers' statistical profiler off (a cluster setting)
        import dask

        dask.config.set({"distributed.worker.profile.enabled": False})
    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=logging.ERROR)
    client = Client(cluster)
    # Workers started and warm like the local pool's (which start inside the timing, but
    # spawn in about a second): the cluster start-up is a once-per-session cost.
    client.run(lambda: __import__("neural_shdf.pipeline"))
    start = time.perf_counter()
    rows = run_batch([manifest], out, scheduler=client, method=method)
    seconds = time.perf_counter() - start
    client.close(); cluster.close()
else:
    start = time.perf_counter()
    rows = run_batch([manifest], out, workers=2, method=method)
    seconds = time.perf_counter() - start
print(json.dumps({"seconds": seconds, "ok": sum(r["status"] == "ok" for r in rows)}))
"""


def dask_overhead(args: argparse.Namespace, work: Path) -> None:
    import json

    print("\n## Dask LocalCluster (2 worker processes) vs local pool (2 processes)")
    for name, folder in data_sets(args.sets, work).items():
        files = mesh_files(folder, args.sample)
        manifest = listing(files, work / f"{name}.txt")
        print(f"{name}: {len(files)} meshes, {args.method} ShDF; {load()}")
        modes = ("local", "dask", "dask-noprofile")
        seconds: dict[str, list[float]] = {mode: [] for mode in modes}
        cpus: dict[str, list[float]] = {mode: [] for mode in modes}
        for _ in range(args.repeat):
            for mode in modes:
                out = work / f"{name}-{mode}"
                shutil.rmtree(out, ignore_errors=True)
                cpu = children_cpu()
                result = subprocess.run(
                    [sys.executable, "-c", DASK_RUNNER, str(manifest), str(out), mode, args.method],
                    env=ENV, capture_output=True, text=True, check=True,
                )  # fmt: skip
                report = json.loads(result.stdout.strip().splitlines()[-1])
                seconds[mode].append(report["seconds"])
                cpus[mode].append(children_cpu() - cpu)
                print(f"  {mode:>5}: {report['seconds']:7.1f} s wall, {cpus[mode][-1]:7.1f} s "
                      f"CPU (incl. start-up), {report['ok']} ok")  # fmt: skip
        local = min(seconds["local"])
        for mode in modes[1:]:
            dask = min(seconds[mode])
            overhead = dask / local - 1
            per_asset = (dask - local) / len(files) * 1000
            print(f"RESULT {mode} {name}: local {local:.1f} s, {mode} {dask:.1f} s, overhead "
                  f"{overhead * 100:+.1f}% ({per_asset:+.0f} ms/asset), goal <= 15%: "
                  f"{'met' if overhead <= 0.15 else 'NOT met'}; {load()}")  # fmt: skip


def generate_library(folder: Path, count: int, corrupt_fraction: float, seed: int = 0) -> set[str]:
    """``count`` small meshes (OBJ/OFF/PLY/STL), ``corrupt_fraction`` of them corrupt;
    returns the corrupt files' names."""
    import numpy as np
    import trimesh

    rng = random.Random(seed)
    folder.mkdir(parents=True, exist_ok=True)
    bad_count = round(count * corrupt_fraction)
    bad = set(rng.sample(range(count), bad_count))
    formats = ("obj", "off", "ply", "stl")
    corrupt_names = set()
    for i in range(count):
        kind = i % 4
        if kind == 0:
            mesh = trimesh.creation.capsule(height=rng.uniform(0.5, 3), radius=0.5, count=(8, 8))
        elif kind == 1:
            mesh = trimesh.creation.icosphere(subdivisions=2, radius=rng.uniform(0.5, 2))
            mesh.vertices *= np.array([1.0, rng.uniform(0.3, 1.0), 1.0])
        elif kind == 2:
            mesh = trimesh.creation.cylinder(radius=rng.uniform(0.2, 1), height=2, sections=24)
        else:
            a = trimesh.creation.icosphere(subdivisions=2)
            b = trimesh.creation.box(extents=(3, 0.4, 0.4))
            mesh = trimesh.util.concatenate([a, b])
        path = folder / f"{i // 100:02d}" / f"asset{i:04d}.{formats[i % 4]}"
        path.parent.mkdir(exist_ok=True)
        if i in bad:
            corrupt_names.add(str(path))
            style = len(corrupt_names) % 5
            if style == 0:
                path.write_bytes(b"")  # empty
            elif style == 1:
                path.write_bytes(os.urandom(512))  # noise
            elif style == 2:
                data = mesh.export(file_type=formats[i % 4])
                data = data if isinstance(data, bytes) else data.encode()
                path.write_bytes(data[: len(data) // 3])  # truncated
            elif style == 3:
                path = path.with_suffix(".obj")
                corrupt_names.discard(str(path.with_suffix(f".{formats[i % 4]}")))
                corrupt_names.add(str(path))
                path.write_text("v 0 0 0\nv 1 0 0\nf 1 2 9\n")  # face on a missing vertex
            else:
                path = path.with_suffix(".obj")
                corrupt_names.discard(str(path.with_suffix(f".{formats[i % 4]}")))
                corrupt_names.add(str(path))
                path.write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")  # NaN vertex
        else:
            mesh.export(path)
    return corrupt_names


def resume(args: argparse.Namespace, work: Path) -> None:
    print(f"\n## resume: {args.count} generated meshes, 5% corrupt, killed then run again")
    library = work / "generated"
    shutil.rmtree(library, ignore_errors=True)
    corrupt = generate_library(library, args.count, 0.05)
    out = work / "generated-out"
    shutil.rmtree(out, ignore_errors=True)
    command = [*CLI, "batch", str(library), "-o", str(out), "--workers", "2", "-q",
               "--method", args.method]  # fmt: skip
    print(f"{load()}")
    start = time.perf_counter()
    process = subprocess.Popen(command, env=ENV, start_new_session=True)
    while len(list(out.rglob("*.batch.json"))) < args.count * 0.4:
        if process.poll() is not None:
            raise SystemExit("the batch finished before it could be killed")
        time.sleep(0.2)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    first_wall = time.perf_counter() - start
    records = {p: p.stat().st_mtime_ns for p in out.rglob("*.batch.json")}
    # Outputs of finished assets (a .seg without its record belongs to an unfinished one).
    outputs = {
        seg: seg.stat().st_mtime_ns
        for seg in (p.with_name(p.name.replace(".batch.json", ".seg")) for p in records)
    }
    temporary = list(out.rglob(".*.tmp"))
    print(f"killed after {first_wall:.1f} s: {len(records)} assets finished, "
          f"{len(temporary)} temporary files of unfinished writes")  # fmt: skip
    wall, cpu, code = timed(command)
    rows = manifest_rows(out)
    by_status: dict[str, int] = {}
    for row in rows:
        by_status[row["status"]] = by_status.get(row["status"], 0) + 1
    failed = {r["path"] for r in rows if r["status"] == "failed"}
    good_done = sum(r["status"] in ("ok", "skipped") for r in rows if r["path"] not in corrupt)
    touched = sum(p.stat().st_mtime_ns != t for p, t in records.items())
    touched += sum(p.stat().st_mtime_ns != t for p, t in outputs.items())
    half_written = [p for p in out.rglob("*.seg") if not p.read_text().endswith("\n")]
    print(f"re-run: {wall:.1f} s wall, {cpu:.1f} s CPU, exit code {code}; rows {by_status}")
    print(
        f"RESULT resume: {len(rows)} rows; good done {good_done}/{args.count - len(corrupt)}; "
        f"corrupt reported {len(failed & corrupt)}/{len(corrupt)}, other failures "
        f"{len(failed - corrupt)}; finished before the kill and recomputed: {touched}; "
        f"skipped {by_status.get('skipped', 0)} == finished {len(records)}; half-written "
        f"outputs {len(half_written)}; leftover temporaries {len(list(out.rglob('.*.tmp')))}"
    )
    errors: dict[str, int] = {}
    for row in rows:
        if row["status"] == "failed":
            errors[row["error_type"]] = errors.get(row["error_type"], 0) + 1
    print(f"errors by type: {errors}; {load()}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", nargs="+", default=["throughput", "dask", "resume"])
    parser.add_argument("--sets", nargs="+", default=["psb", "misc"])
    parser.add_argument("--sample", type=int, help="only N meshes of each set (evenly spread)")
    parser.add_argument("--repeat", type=int, default=1, help="runs per case; the best counts")
    parser.add_argument("--count", type=int, default=1000, help="generated meshes (resume)")
    parser.add_argument("--method", default="neural", help="ShDF method of every step")
    parser.add_argument("--work", type=Path, help="work folder (default: a temporary one)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="neural-shdf-bench-batch-"))
    work.mkdir(parents=True, exist_ok=True)
    print(f"work folder {work}; {load()}")
    # Compile or load the kernels once, outside every timing.
    subprocess.run([*CLI, "batch", str(DATA / "psb-dev" / "off" / "1.off"), "-o",
                    str(work / "warm"), "--workers", "0", "-q"], env=ENV, check=True)  # fmt: skip
    for step in args.steps:
        {"throughput": throughput, "dask": dask_overhead, "resume": resume}[step](args, work)
    if args.work is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
