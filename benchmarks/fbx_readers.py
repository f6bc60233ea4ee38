"""Measure FBX readers against Blender's own geometry: why neural-shdf refuses FBX.

Blender (``--blender-python``, a Python with ``bpy``) builds a scene of three objects
(a cube of quads, a rotated and scaled UV sphere of triangles and quads, a cylinder
with 9-gon caps) and a sphere whose faces alternate between two materials, exports
them as FBX and records each face's centre. Each reader that imports here (pyassimp
over the system's libassimp, assimp-py) then reads the files without post-processing;
per mesh the table prints faces, polygon sizes, and whether the faces come back in
Blender's order (each face matched to the Blender face with the nearest centre, up
to the exporter's axis swap and unit scale; mirror-symmetric shapes may match a
twin, so the striped sphere is the decisive row).

    python benchmarks/fbx_readers.py [--blender-python /work/main/.venv-blender/bin/python]
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import tempfile
from pathlib import Path

import numpy as np

BLENDER_SCRIPT = r"""
import bpy, json, sys
out = sys.argv[-1]
facts = {}
def record(ob):
    facts[ob.name] = {"sizes": [p.loop_total for p in ob.data.polygons],
                      "centers": [list(ob.matrix_world @ p.center) for p in ob.data.polygons]}
def export(name):
    bpy.context.view_layer.update()
    for ob in bpy.context.scene.objects:
        record(ob)
    bpy.ops.export_scene.fbx(filepath=f"{out}/{name}.fbx")
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_cube_add(size=2)
bpy.context.active_object.name = "Cube"
bpy.ops.mesh.primitive_uv_sphere_add(segments=12, ring_count=6, location=(4, 0, 0))
sphere = bpy.context.active_object
sphere.name, sphere.rotation_euler, sphere.scale = "Sphere", (0.3, 0.2, 0.1), (1, 2, 1)
bpy.ops.mesh.primitive_cylinder_add(vertices=9, location=(-4, 0, 0))
bpy.context.active_object.name = "Cylinder"
export("scene")
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.mesh.primitive_uv_sphere_add(segments=8, ring_count=4)
striped = bpy.context.active_object
striped.name = "Striped"
for name in ("Red", "Blue"):
    striped.data.materials.append(bpy.data.materials.new(name))
for polygon in striped.data.polygons:
    polygon.material_index = polygon.index % 2
export("materials")
json.dump(facts, open(f"{out}/facts.json", "w"))
"""


def _pyassimp_meshes(path: Path) -> list[tuple[str, list[list[int]], np.ndarray]]:
    import pyassimp
    import pyassimp.core

    pyassimp.core.numpy = None  # its numpy path cannot hold polygons of mixed sizes
    meshes = []
    with pyassimp.load(str(path), processing=0) as scene:

        def walk(node, parent: np.ndarray) -> None:
            matrix = parent @ np.asarray(node.transformation, dtype=float).reshape(4, 4)
            for mesh in node.meshes:
                points = np.asarray(mesh.vertices, dtype=float)
                world = (np.c_[points, np.ones(len(points))] @ matrix.T)[:, :3]
                meshes.append((node.name, [list(face) for face in mesh.faces], world))
            for child in node.children:
                walk(child, matrix)

        walk(scene.rootnode, np.eye(4))
    return meshes


def _assimp_py_meshes(path: Path) -> list[tuple[str, list[list[int]], np.ndarray]]:
    import assimp_py

    scene = assimp_py.import_file(str(path), 0)  # refuses polygons: needs Triangulate
    return [(m.name, [list(f) for f in m.indices], np.asarray(m.vertices)) for m in scene.meshes]


def _order(centers: np.ndarray, expected: np.ndarray) -> tuple[float, list[int]]:
    """Largest centre error and the Blender face of each face, best over axis swaps."""
    scale = np.abs(centers).max() / max(np.abs(expected).max(), 1e-12)
    best = (np.inf, [])
    for axes in itertools.permutations(range(3)):
        for signs in itertools.product((-1, 1), repeat=3):
            moved = centers[:, axes] * signs / scale
            distance = np.linalg.norm(moved[:, None] - expected[None], axis=2)
            error = float(distance.min(axis=1).max())
            if error < best[0]:
                best = (error, distance.argmin(axis=1).tolist())
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--blender-python", default="/work/main/.venv-blender/bin/python")
    args = parser.parse_args()
    readers = {"pyassimp": _pyassimp_meshes, "assimp-py": _assimp_py_meshes}
    with tempfile.TemporaryDirectory(prefix="fbx-readers-") as folder:
        script = Path(folder) / "make.py"
        script.write_text(BLENDER_SCRIPT)
        subprocess.run([args.blender_python, str(script), folder], check=True,
                       capture_output=True, timeout=300)  # fmt: skip
        facts = json.loads((Path(folder) / "facts.json").read_text())
        print(f"{'reader':<10}{'file':<11}{'mesh':<10}{'faces':>7}{'blender':>9}  sizes  in order")
        for reader, read in readers.items():
            for name in ("scene", "materials"):
                try:
                    meshes = read(Path(folder) / f"{name}.fbx")
                except Exception as error:  # noqa: BLE001 - a reader's failure is a result
                    print(f"{reader:<10}{name:<11}fails: {str(error)[:70]}")
                    continue
                for mesh, faces, points in meshes:
                    expected = facts[mesh]
                    centers = np.array([points[face].mean(axis=0) for face in faces])
                    error, match = _order(centers, np.array(expected["centers"]))
                    in_order = error < 1e-4 and match == list(range(len(expected["sizes"])))
                    sizes = sorted({len(face) for face in faces})
                    print(f"{reader:<10}{name:<11}{mesh:<10}{len(faces):>7}"
                          f"{len(expected['sizes']):>9}  {sizes}  {in_order}")  # fmt: skip


if __name__ == "__main__":
    main()
