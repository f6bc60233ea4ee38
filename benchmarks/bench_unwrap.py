"""Piece-wise UV unwrap by parts against the unwrappers artists use, same meshes, one run.

Methods, each on the same triangles:
- ``parts``: ``neural_shdf.unwrap`` on the default segmentation (exact ShDF), at the default
  ``max_stretch`` and, with ``--curve``, at other values (the trade-off curve);
- ``xatlas``: xatlas on the whole mesh, its own automatic charting and packing (defaults);
- ``blender``: Blender's Smart UV Project (real ``bpy``, default 66 degree angle limit,
  island margin 0.003), in a child process (bpy and our kernels stay apart).

- ``before``: with ``--before REF``, ``neural_shdf/unwrap.py`` as it was at git ``REF``, same
  labels, in the same run (before/after side by side).

Per method: charts (UV islands, counted the same way for all), seam length over total edge
length, L2 stretch (Sander, area-normalised; 1 is isometric), conformal error, flipped area,
atlas utilisation (1024^2 raster), texels claimed by two charts, slivers (charts narrower
than ``SLIVER_WIDTH_EDGES`` mean edges) and their share of the area, border roughness
(border length over smoothed border length) and sharp turns (border vertices turning over
90 degrees), wall and CPU seconds of the unwrap itself (CPU: every thread of this process;
xatlas runs threads, ours one), and their ratios to xatlas's (goal: wall <= 1.5).
The summary prints, per mesh, our ratios against the better anchor: charts (goal <= 0.5),
seams (goal < 1 against both), L2 stretch (goal <= 1.1).

    python benchmarks/bench_unwrap.py [--psb 1,21,61,101,121,181,281,341,381] [--dense skull,lucy]
        [--curve 1.05,1.25,1.5] [--no-blender | --blender-python PY] [--before REF]
        [--labels-cache DIR] [--json out.json]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from neural_shdf.evaluate.uv import uv_islands, uv_quality
from neural_shdf.geometry import weld_faces
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.unwrap import UnwrapParams, unwrap

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
DENSE = {
    "skull": "odedstein__objects__skull__skull.ply",
    "lucy": "vtkdata__Data__lucy.ply",
    "blade": "vtkdata__Data__turbineblade.ply",
    "eagle": "polygonjs__models__resources__threedscans.com__eagle.ply",
    "horse": "polygonjs__models__resources__threedscans.com__horse_head.ply",
    "zenobia": "polygonjs__models__resources__threedscans.com__zenobia_in_chains.ply",
}

BLENDER_SCRIPT = r"""
import sys, time, numpy as np, bpy
bpy.ops.wm.read_factory_settings(use_empty=True)  # no default cube sharing the UV space
vertices = np.load(sys.argv[1]); faces = np.load(sys.argv[2])
mesh = bpy.data.meshes.new("m")
mesh.from_pydata(vertices.tolist(), [], faces.tolist())
mesh.validate(clean_customdata=False)
assert len(mesh.polygons) == len(faces), "Blender dropped faces"
obj = bpy.data.objects.new("m", mesh)
bpy.context.scene.collection.objects.link(obj)
bpy.context.view_layer.objects.active = obj
obj.select_set(True)
bpy.ops.object.mode_set(mode="EDIT")
bpy.ops.mesh.select_all(action="SELECT")
start = time.perf_counter()
bpy.ops.uv.smart_project()  # defaults: angle limit 66 degrees, island margin 0
seconds = time.perf_counter() - start
bpy.ops.object.mode_set(mode="OBJECT")
uv = np.zeros(len(mesh.loops) * 2)
mesh.uv_layers.active.data.foreach_get("uv", uv)
loop_start = np.zeros(len(mesh.polygons), dtype=np.int64)
mesh.polygons.foreach_get("loop_start", loop_start)
corner = uv.reshape(-1, 2)[loop_start[:, None] + np.arange(3)]
np.save(sys.argv[3], corner)
print(seconds)
"""


def _blender(vertices: np.ndarray, faces: np.ndarray, python: str) -> tuple[np.ndarray, float]:
    """Smart UV Project in a child ``python`` with bpy: (corner UVs, seconds of the operator)."""
    with tempfile.TemporaryDirectory() as folder:
        paths = [Path(folder) / name for name in ("v.npy", "f.npy", "uv.npy")]
        np.save(paths[0], vertices)
        np.save(paths[1], faces)
        script = Path(folder) / "smart_uv.py"
        script.write_text(BLENDER_SCRIPT)
        done = subprocess.run(
            [python, str(script), *map(str, paths)],
            capture_output=True, text=True, check=True,
        )  # fmt: skip
        seconds = float(done.stdout.strip().splitlines()[-1])
        return np.load(paths[2]), seconds


def _unwrap_at(ref: str):
    """``unwrap`` from ``neural_shdf/unwrap.py`` as committed at git ``ref``."""
    root = Path(__file__).resolve().parents[1]
    source = subprocess.run(
        ["git", "show", f"{ref}:service/neural_shdf/unwrap.py"],
        cwd=root, capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    path = Path(tempfile.mkdtemp()) / "unwrap_before.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location("neural_shdf._unwrap_before", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module.unwrap


def _labels(name: str, mesh: TriangleMesh, cache: Path | None) -> tuple[np.ndarray, float]:
    """The default segmentation (exact ShDF) and its seconds, read from ``cache`` if there."""
    path = cache / f"{name}-{mesh.face_count}.labels.npy" if cache else None
    if path is not None and path.is_file():
        return np.load(path), float("nan")
    start = time.perf_counter()
    labels = segment(mesh, compute_shdf(mesh, method="exact").values).labels
    seconds = time.perf_counter() - start
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        np.save(path, labels)
    return labels, seconds


def _warm_up(unwrappers: list) -> None:
    """Compile every numba kernel the unwrappers use (cached on disk after a first run)
    on a small mesh, so no timing below includes compiling; xatlas comes compiled."""
    mesh = load_mesh(DATA / "psb-dev" / "off" / "1.off")
    centres = mesh.vertices[mesh.faces].mean(axis=1)[:, 0]
    labels = (centres > np.median(centres)).astype(np.int64)
    for unwrapper in unwrappers:
        unwrapper(mesh, labels, UnwrapParams(max_stretch=1.0))  # every piece is split
    corner_uvs = unwrap(mesh, labels).corner_uvs
    _row(mesh, "warm-up", corner_uvs, 0.0, 0.0)


def _xatlas(vertices: np.ndarray, welded: np.ndarray) -> np.ndarray:
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(vertices.astype(np.float32), welded.astype(np.uint32))
    atlas.generate()
    _, indices, uvs = atlas.get_mesh(0)
    return uvs.astype(np.float64)[indices.astype(np.int64)]


def _timed(function, *args):
    """``function(*args)``, its wall seconds and this process's CPU seconds (every thread:
    on a shared machine CPU time moves far less with the load than wall time does)."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = function(*args)
    return result, time.perf_counter() - wall, time.process_time() - cpu


def _row(
    mesh: TriangleMesh, method: str, corner_uvs: np.ndarray, seconds: float, cpu: float
) -> dict:
    charts = uv_islands(mesh.vertices, mesh.faces, corner_uvs)
    quality = uv_quality(mesh.vertices, mesh.faces, corner_uvs, charts)
    return {"method": method, "seconds": round(seconds, 3), "cpu_seconds": round(cpu, 3),
            **quality.as_dict()}  # fmt: skip


def bench_mesh(
    name: str,
    mesh: TriangleMesh,
    curve: list[float],
    blender: str | None,
    before=None,
    cache: Path | None = None,
) -> list[dict]:
    """Every method on one mesh."""
    _ = mesh.face_graph  # built before the clock starts, as before
    labels, segment_seconds = _labels(name, mesh, cache)
    welded = weld_faces(mesh.vertices, mesh.faces)
    rows = []
    if before is not None:
        atlas, wall, cpu = _timed(before, mesh, labels)
        rows.append(_row(mesh, "before", atlas.corner_uvs, wall, cpu))
    for max_stretch in [UnwrapParams().max_stretch, *curve]:
        atlas, wall, cpu = _timed(unwrap, mesh, labels, UnwrapParams(max_stretch=max_stretch))
        rows.append(_row(mesh, f"parts@{max_stretch:g}", atlas.corner_uvs, wall, cpu))
    uvs, seconds_xatlas, cpu_xatlas = _timed(_xatlas, mesh.vertices, welded)
    rows.append(_row(mesh, "xatlas", uvs, seconds_xatlas, cpu_xatlas))
    if blender:
        uvs, seconds = _blender(mesh.vertices, welded, blender)
        rows.append(_row(mesh, "blender", uvs, seconds, float("nan")))
    for row in rows:
        row.update(mesh=name, faces=mesh.face_count, parts=int(labels.max()) + 1,
                   segment_seconds=round(segment_seconds, 3),
                   x_xatlas=round(row["seconds"] / max(seconds_xatlas, 1e-9), 2),
                   x_xatlas_cpu=round(row["cpu_seconds"] / max(cpu_xatlas, 1e-9), 2))  # fmt: skip
    return rows


def _print_rows(rows: list[dict]) -> None:
    print(f"{'mesh':>8} {'faces':>7} {'parts':>5} {'method':>12} {'charts':>6} {'seams':>6} "
          f"{'L2':>6} {'conf':>6} {'flip':>6} {'util':>5} {'clash':>5} {'sliv':>5} "
          f"{'slivA':>6} {'rough':>6} {'turns':>6} {'sec':>7} {'xXat':>6} {'cpu':>7} "
          f"{'xXcpu':>6}")  # fmt: skip
    for r in rows:
        print(f"{r['mesh']:>8} {r['faces']:>7} {r['parts']:>5} {r['method']:>12} "
              f"{r['charts']:>6} {r['seam_ratio']:>6.4f} {r['l2_stretch']:>6.3f} "
              f"{r['conformal_error']:>6.3f} {r['flipped_fraction']:>6.4f} "
              f"{r['utilization']:>5.2f} {r['overlapping_texels']:>5} {r['slivers']:>5} "
              f"{r['sliver_area']:>6.4f} {r['border_roughness']:>6.3f} "
              f"{r['sharp_turns']:>6.3f} {r['seconds']:>7.2f} {r['x_xatlas']:>6.2f} "
              f"{r['cpu_seconds']:>7.2f} {r['x_xatlas_cpu']:>6.2f}")  # fmt: skip


def _summary(rows: list[dict]) -> None:
    print("\nours (default) against the better anchor: ratio (goal), met")
    meshes = list(dict.fromkeys(r["mesh"] for r in rows))
    default = f"parts@{UnwrapParams().max_stretch:g}"
    met_all = {"charts": 0, "seams": 0, "L2": 0, "time": 0}
    for name in meshes:
        mine = next(r for r in rows if r["mesh"] == name and r["method"] == default)
        anchors = [r for r in rows if r["mesh"] == name and r["method"] in ("xatlas", "blender")]
        charts = mine["charts"] / min(a["charts"] for a in anchors)
        seams = mine["seam_ratio"] / min(a["seam_ratio"] for a in anchors)
        stretch = mine["l2_stretch"] / min(a["l2_stretch"] for a in anchors)
        ok = {"charts": charts <= 0.5, "seams": seams < 1.0, "L2": stretch <= 1.1,
              "time": mine["x_xatlas"] <= 1.5}  # fmt: skip
        for key, value in ok.items():
            met_all[key] += int(value)
        print(f"{name:>8}: charts x{charts:.2f} (<=0.5) {'yes' if ok['charts'] else 'no '}  "
              f"seams x{seams:.2f} (<1) {'yes' if ok['seams'] else 'no '}  "
              f"L2 x{stretch:.3f} (<=1.1) {'yes' if ok['L2'] else 'no '}  "
              f"time x{mine['x_xatlas']:.2f} of xatlas (<=1.5; CPU x{mine['x_xatlas_cpu']:.2f}) "
              f"{'yes' if ok['time'] else 'no'}")  # fmt: skip
    print(f"meshes meeting each goal (of {len(meshes)}): {met_all}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--psb", default="1,21,61,101,121,181,281,341,381")
    parser.add_argument("--dense", default="skull,lucy", help="dense-dev scans ('' for none)")
    parser.add_argument("--curve", default="1.05,1.25,1.5", help="other max_stretch values")
    parser.add_argument("--no-blender", action="store_true")
    parser.add_argument(
        "--blender-python",
        default=os.environ.get("NEURAL_SHDF_BLENDER_PYTHON", sys.executable),
        help="a Python with bpy==4.5.* (bpy wants numpy<2: a venv of its own; "
        "default: $NEURAL_SHDF_BLENDER_PYTHON, as scripts/test sets up)",
    )
    parser.add_argument("--before", help="also run unwrap.py as committed at this git ref")
    parser.add_argument("--labels-cache", type=Path, help="keep the segmentations here")
    parser.add_argument("--json", help="also write every row as JSON")
    args = parser.parse_args()
    curve = [float(v) for v in args.curve.split(",") if v]
    jobs = [(f"psb-{i}", DATA / "psb-dev" / "off" / f"{i}.off") for i in args.psb.split(",") if i]
    jobs += [(n, DATA / "dense-dev" / DENSE[n]) for n in args.dense.split(",") if n]
    before = _unwrap_at(args.before) if args.before else None
    _warm_up([unwrap] + ([before] if before else []))
    rows = []
    for name, path in jobs:
        if not path.is_file():
            print(f"skip {name}: {path} is absent", file=sys.stderr)
            continue
        blender = None if args.no_blender else args.blender_python
        rows.extend(bench_mesh(name, load_mesh(path), curve, blender, before, args.labels_cache))
        _print_rows([r for r in rows if r["mesh"] == name])
        sys.stdout.flush()
    print()
    _print_rows(rows)
    _summary(rows)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
