"""Piece-wise UV unwrap by parts against the unwrappers artists use, same meshes, one run.

Methods, each on the same triangles:
- ``parts``: ``neural_shdf.unwrap`` on the default segmentation (exact ShDF), at the default
  ``max_stretch`` and, with ``--curve``, at other values (the trade-off curve);
- ``xatlas``: xatlas on the whole mesh, its own automatic charting and packing (defaults);
- ``blender``: Blender's Smart UV Project (real ``bpy``, default 66 degree angle limit,
  island margin 0.003), in a child process (bpy and our kernels stay apart).

Per method: charts (UV islands, counted the same way for all), seam length over total edge
length, L2 stretch (Sander, area-normalised; 1 is isometric), conformal error, flipped area,
atlas utilisation (1024^2 raster), texels claimed by two charts, seconds of the unwrap itself.
The summary prints, per mesh, our ratios against the better anchor: charts (goal <= 0.5),
seams (goal < 1 against both), L2 stretch (goal <= 1.1).

    python benchmarks/bench_unwrap.py [--psb 1,21,61,101,121,181,281,341,381] [--dense skull,lucy]
        [--curve 1.05,1.25,1.5] [--no-blender | --blender-python PY] [--json out.json]
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

import numpy as np

from neural_shdf.evaluate.uv import uv_islands, uv_quality
from neural_shdf.geometry import weld_faces
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.unwrap import UnwrapParams, unwrap

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
DENSE = {"skull": "odedstein__objects__skull__skull.ply", "lucy": "vtkdata__Data__lucy.ply"}

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


def _xatlas(vertices: np.ndarray, welded: np.ndarray) -> tuple[np.ndarray, float]:
    import xatlas

    start = time.perf_counter()
    atlas = xatlas.Atlas()
    atlas.add_mesh(vertices.astype(np.float32), welded.astype(np.uint32))
    atlas.generate()
    _, indices, uvs = atlas.get_mesh(0)
    return uvs.astype(np.float64)[indices.astype(np.int64)], time.perf_counter() - start


def _row(mesh: TriangleMesh, method: str, corner_uvs: np.ndarray, seconds: float) -> dict:
    charts = uv_islands(mesh.vertices, mesh.faces, corner_uvs)
    quality = uv_quality(mesh.vertices, mesh.faces, corner_uvs, charts)
    return {"method": method, "seconds": round(seconds, 3), **quality.as_dict()}


def bench_mesh(
    name: str, mesh: TriangleMesh, curve: list[float], blender: str | None
) -> list[dict]:
    """Every method on one mesh."""
    _ = mesh.face_graph  # built before the clock starts, as before
    start = time.perf_counter()
    labels = segment(mesh, compute_shdf(mesh, method="exact").values).labels
    segment_seconds = time.perf_counter() - start
    welded = weld_faces(mesh.vertices, mesh.faces)
    rows = []
    for max_stretch in [UnwrapParams().max_stretch, *curve]:
        start = time.perf_counter()
        atlas = unwrap(mesh, labels, UnwrapParams(max_stretch=max_stretch))
        rows.append(_row(mesh, f"parts@{max_stretch:g}", atlas.corner_uvs,
                         time.perf_counter() - start))  # fmt: skip
    uvs, seconds = _xatlas(mesh.vertices, welded)
    rows.append(_row(mesh, "xatlas", uvs, seconds))
    if blender:
        uvs, seconds = _blender(mesh.vertices, welded, blender)
        rows.append(_row(mesh, "blender", uvs, seconds))
    for row in rows:
        row.update(mesh=name, faces=mesh.face_count, parts=int(labels.max()) + 1,
                   segment_seconds=round(segment_seconds, 3))  # fmt: skip
    return rows


def _print_rows(rows: list[dict]) -> None:
    print(f"{'mesh':>8} {'faces':>7} {'parts':>5} {'method':>12} {'charts':>6} {'seams':>6} "
          f"{'L2':>6} {'conf':>6} {'flip':>6} {'util':>5} {'clash':>5} {'sec':>7}")  # fmt: skip
    for r in rows:
        print(f"{r['mesh']:>8} {r['faces']:>7} {r['parts']:>5} {r['method']:>12} "
              f"{r['charts']:>6} {r['seam_ratio']:>6.4f} {r['l2_stretch']:>6.3f} "
              f"{r['conformal_error']:>6.3f} {r['flipped_fraction']:>6.4f} "
              f"{r['utilization']:>5.2f} {r['overlapping_texels']:>5} "
              f"{r['seconds']:>7.2f}")  # fmt: skip


def _summary(rows: list[dict]) -> None:
    print("\nours (default) against the better anchor: ratio (goal), met")
    meshes = list(dict.fromkeys(r["mesh"] for r in rows))
    default = f"parts@{UnwrapParams().max_stretch:g}"
    met_all = {"charts": 0, "seams": 0, "L2": 0}
    for name in meshes:
        mine = next(r for r in rows if r["mesh"] == name and r["method"] == default)
        anchors = [r for r in rows if r["mesh"] == name and r["method"] in ("xatlas", "blender")]
        charts = mine["charts"] / min(a["charts"] for a in anchors)
        seams = mine["seam_ratio"] / min(a["seam_ratio"] for a in anchors)
        stretch = mine["l2_stretch"] / min(a["l2_stretch"] for a in anchors)
        ok = {"charts": charts <= 0.5, "seams": seams < 1.0, "L2": stretch <= 1.1}
        for key, value in ok.items():
            met_all[key] += int(value)
        print(f"{name:>8}: charts x{charts:.2f} (<=0.5) {'yes' if ok['charts'] else 'no '}  "
              f"seams x{seams:.2f} (<1) {'yes' if ok['seams'] else 'no '}  "
              f"L2 x{stretch:.3f} (<=1.1) {'yes' if ok['L2'] else 'no'}")  # fmt: skip
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
    parser.add_argument("--json", help="also write every row as JSON")
    args = parser.parse_args()
    curve = [float(v) for v in args.curve.split(",") if v]
    jobs = [(f"psb-{i}", DATA / "psb-dev" / "off" / f"{i}.off") for i in args.psb.split(",") if i]
    jobs += [(n, DATA / "dense-dev" / DENSE[n]) for n in args.dense.split(",") if n]
    rows = []
    for name, path in jobs:
        if not path.is_file():
            print(f"skip {name}: {path} is absent", file=sys.stderr)
            continue
        blender = None if args.no_blender else args.blender_python
        rows.extend(bench_mesh(name, load_mesh(path), curve, blender))
        _print_rows([r for r in rows if r["mesh"] == name])
        sys.stdout.flush()
    print()
    _print_rows(rows)
    _summary(rows)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
