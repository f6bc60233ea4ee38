"""USD and Draco reading against an uncompressed GLB of the same mesh, at about 1M faces.

The mesh: an icosphere subdivided 8 times (1.31M triangles, 655k vertices), written as
an uncompressed GLB (trimesh), a Draco GLB (``KHR_draco_mesh_compression``, DracoPy,
16-bit positions), a crate ``.usdc``, a text ``.usda`` and a ``.usdz`` (one Mesh prim,
triangles as faces), and a grid of 1M quads (polygons take the fan path) as USD and as
a GLB of its 2M triangles. Each file is read with ``mesh_io.load_mesh`` from its path,
under the service's default limits (so USD's crate-array check runs); the table prints
the best wall and CPU seconds of ``--repeat`` reads, the difference from the GLB above
it (issue #19's target: Draco and USD at most 1 s beyond the GLB) and, for USD, the
wall seconds of usd-core alone opening the stage (``Usd.Stage.Open``: its own parse).
``usda core only`` reads the same ``.usda`` without the fast path (``_usda_arrays``:
its large arrays parsed by our kernel), side by side with ``usda``.

    python benchmarks/bench_usd.py [--repeat 3] [--subdivisions 8]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import trimesh
from formats_corpus import draco_glb
from timing import best_time

from neural_shdf.constants import DEFAULT_MAX_FACES, DEFAULT_MAX_VERTICES
from neural_shdf.exchange import usd
from neural_shdf.exchange._usda_arrays import cut_arrays
from neural_shdf.mesh_io import load_mesh


def write_usd(path: Path, vertices: np.ndarray, counts: np.ndarray, flat: np.ndarray) -> None:
    """One Mesh prim under /World with these polygons."""
    from pxr import Usd, UsdGeom, UsdUtils, Vt

    target = path.with_suffix(".usdc") if path.suffix == ".usdz" else path
    stage = Usd.Stage.CreateNew(str(target))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, "/World/Mesh")
    mesh.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(vertices.astype(np.float32)))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(flat.astype(np.int32)))
    stage.GetRootLayer().Save()
    if path.suffix == ".usdz":
        UsdUtils.CreateNewUsdzPackage(str(target), str(path))


def _no_cut(data: bytes, **_: object) -> None:
    """No array cut: usd-core parses the whole text."""
    return None


def _open_stage(path: Path) -> None:
    """usd-core alone: open the stage (parse its layers), as our reader does."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
    assert stage is not None
    del stage


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--subdivisions", type=int, default=8)
    args = parser.parse_args()
    sphere = trimesh.creation.icosphere(subdivisions=args.subdivisions)
    vertices = np.asarray(sphere.vertices, dtype=np.float32).astype(np.float64)
    faces = np.asarray(sphere.faces, dtype=np.int64)
    print(f"mesh: {len(faces)} triangles, {len(vertices)} vertices")
    with tempfile.TemporaryDirectory(prefix="bench-usd-") as folder:
        root = Path(folder)
        files = {"glb": root / "mesh.glb"}
        trimesh.Trimesh(vertices, faces, process=False).export(files["glb"])
        files["glb draco"] = root / "mesh-draco.glb"
        sphere_mesh = trimesh.Trimesh(vertices, faces, process=False)
        files["glb draco"].write_bytes(draco_glb(sphere_mesh, np.eye(4), required=True))
        triangles = np.full(len(faces), 3)
        for suffix in ("usdc", "usda", "usdz"):
            files[suffix] = root / f"mesh.{suffix}"
            write_usd(files[suffix], vertices, triangles, faces.reshape(-1))
        # The same .usda read by usd-core alone (without the fast path of _usda_arrays).
        files["usda core only"] = files["usda"]
        # Quads (the fan path): a 1000 x 1000 grid, against the GLB of its triangles.
        side = 1000
        grid = np.stack(np.meshgrid(np.arange(side + 1), np.arange(side + 1)), -1).reshape(-1, 2)
        grid_vertices = np.column_stack([grid, np.zeros(len(grid))]).astype(np.float64)
        corner = (np.arange(side)[:, None] * (side + 1) + np.arange(side)[None, :]).reshape(-1)
        quads = np.stack([corner, corner + 1, corner + side + 2, corner + side + 1], axis=1)
        files["glb grid"] = root / "grid.glb"
        grid_triangles = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
        trimesh.Trimesh(grid_vertices, grid_triangles, process=False).export(files["glb grid"])
        files["usdc quads"] = root / "grid.usdc"
        write_usd(files["usdc quads"], grid_vertices, np.full(len(quads), 4), quads.reshape(-1))
        header = f"{'file':<15}{'MB':>8}{'faces':>10}{'wall_s':>9}{'cpu_s':>8}{'vs_glb_s':>10}"
        print(header + f"{'usd_core_s':>12}")
        glb_wall = 0.0
        for name, path in files.items():
            usd.cut_arrays = _no_cut if name.endswith("core only") else cut_arrays  # type: ignore[assignment]
            wall, cpu, mesh = best_time(
                lambda p=path: load_mesh(
                    p, max_faces=DEFAULT_MAX_FACES, max_vertices=DEFAULT_MAX_VERTICES
                ),
                args.repeat,
            )
            glb_wall = wall if name in ("glb", "glb grid") else glb_wall
            size = path.stat().st_size / 1e6
            usd_core = (
                f"{best_time(lambda p=path: _open_stage(p), args.repeat)[0]:>12.3f}"
                if name.startswith("usd")
                else ""
            )
            print(
                f"{name:<15}{size:>8.1f}{mesh.input_face_count:>10}{wall:>9.3f}{cpu:>8.3f}"
                f"{wall - glb_wall:>+10.3f}{usd_core}"
            )


if __name__ == "__main__":
    main()
