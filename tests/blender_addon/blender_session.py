"""Drive the installed add-on inside Blender's Python (the `bpy` module), headless.

Run by the tests and the benchmark with Blender's interpreter, never imported by pytest:
``python blender_session.py SPEC.json OUT.json``. SPEC: ``{"zip": ..., "steps": [...]}``;
each step makes a mesh, runs the operator, or inspects an object, and adds a record to OUT.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path

import bpy  # first: importing it makes Blender's bmesh and mathutils importable

# isort: split
import bmesh
import numpy as np
from mathutils import Matrix

ADDON_MODULE = "bl_ext.user_default.neural_shdf"


def install(zip_path: str) -> dict:
    """Install and enable the zip as a user extension, as Install from Disk does."""
    result = bpy.ops.extensions.package_install_files(
        filepath=zip_path, repo="user_default", enable_on_install=True
    )
    panel = bpy.context.scene.neural_shdf.bl_rna.properties
    return {
        "result": sorted(result),
        "enabled": ADDON_MODULE in bpy.context.preferences.addons,
        "operator": hasattr(bpy.ops.neural_shdf, "segment_selected"),
        "defaults": {name: panel[name].default for name in ("assign_materials", "split_parts")},
    }


def dumbbell(
    name: str, cuts: int = 0, subsurf: int = 0, stretch: float = 1.0, materials: int = 0
) -> dict:
    """Two unit boxes (x in [-2, -1] and [1, 2]) joined by a 0.2-thick bar, one connected
    closed mesh: the left box's +x face is inset and extruded into the bar, whose end face
    is widened and extruded into the right box. ``cuts`` subdivides every edge; ``subsurf``
    adds a (simple) Subdivision modifier, which changes the evaluated topology; ``stretch``
    scales x (another geometry, same topology); ``materials`` gives the object that many
    materials of its own ("<name> own i"), polygon i in slot i mod ``materials``."""
    bm = bmesh.new()
    bmesh.ops.create_cube(bm, size=1.0, matrix=Matrix.Translation((-1.5, 0.0, 0.0)))
    cap = max(bm.faces, key=lambda f: f.calc_center_median().x)
    bmesh.ops.inset_region(bm, faces=[cap], thickness=0.4)
    cap = _extrude(bm, cap, 2.0)
    cap = _extrude(bm, cap, 0.0)
    for vert in cap.verts:  # widen the bar's end to the box's full section
        vert.co.y = 0.5 if vert.co.y > 0 else -0.5
        vert.co.z = 0.5 if vert.co.z > 0 else -0.5
    _extrude(bm, cap, 1.0)
    if cuts:
        bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=cuts, use_grid_fill=True)
    if stretch != 1.0:
        bmesh.ops.scale(bm, vec=(stretch, 1.0, 1.0), verts=bm.verts[:])
    bm.normal_update()
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    for index in range(materials):
        mesh.materials.append(bpy.data.materials.new(f"{name} own {index}"))
    if materials:
        slots = np.arange(len(mesh.polygons), dtype=np.int32) % materials
        mesh.polygons.foreach_set("material_index", slots)
    if subsurf:
        modifier = obj.modifiers.new("Subdivision", "SUBSURF")
        modifier.levels = subsurf
        modifier.subdivision_type = "SIMPLE"
    return {"name": name, "polygons": len(mesh.polygons)}


def _extrude(bm: bmesh.types.BMesh, face: bmesh.types.BMFace, distance: float):
    """Extrude ``face`` along +x by ``distance``; returns the new end face."""
    result = bmesh.ops.extrude_face_region(bm, geom=[face])
    new_face = next(g for g in result["geom"] if isinstance(g, bmesh.types.BMFace))
    bmesh.ops.translate(bm, verts=list(new_face.verts), vec=(distance, 0.0, 0.0))
    if face.is_valid:
        bmesh.ops.delete(bm, geom=[face], context="FACES_ONLY")
    return new_face


def flat_triangle(name: str) -> dict:
    """A mesh whose only polygon has zero area (the service rejects it)."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (2, 0, 0)], [], [(0, 1, 2)])
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return {"name": name, "polygons": 1}


def label_regions(name: str, attribute: str, boxes: int, bar: int) -> dict:
    """An integer face attribute on a dumbbell: ``boxes`` on both boxes, ``bar`` on the bar
    (by polygon centre, as the tests' ``regions``), as an artist would paint it."""
    mesh = bpy.data.objects[name].data
    centers = np.empty(len(mesh.polygons) * 3, dtype=np.float64)
    mesh.polygons.foreach_get("center", centers)
    x = centers[0::3] / (np.abs(centers[0::3]).max() / 2.0)  # boxes end at |x| = 2
    labels = np.where(np.abs(x) >= 1 - 1e-6, boxes, bar).astype(np.int32)
    existing = mesh.attributes.get(attribute)
    if existing is not None:
        mesh.attributes.remove(existing)
    mesh.attributes.new(attribute, "INT", "FACE").data.foreach_set("value", labels)
    return {"name": name, "labels": labels.tolist()}


def select(names: list[str]) -> None:
    bpy.context.view_layer.update()
    for obj in bpy.context.scene.objects:
        obj.select_set(obj.name in names)
    bpy.context.view_layer.objects.active = bpy.data.objects[names[0]]


@contextlib.contextmanager
def captured_stdout():
    """What Blender's C code prints (operator reports) while the block runs."""
    sys.stdout.flush()
    saved = os.dup(1)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 1)
        text: list[str] = []
        try:
            yield text
        finally:
            sys.stdout.flush()
            os.dup2(saved, 1)
            os.close(saved)
            sink.seek(0)
            text.append(sink.read().decode("utf-8", "replace"))
        sys.stdout.write(text[0])


def segment(names: list[str], settings: dict) -> dict:
    """Run "Segment Selected" on ``names`` with the panel ``settings``."""
    select(names)
    panel = bpy.context.scene.neural_shdf
    for key, value in settings.items():
        setattr(panel, key, value)
    start = time.perf_counter()
    error = None
    with captured_stdout() as output:
        try:
            result = sorted(bpy.ops.neural_shdf.segment_selected())
        except RuntimeError as report:  # how bpy.ops hands an ERROR report to a script
            result, error = ["CANCELLED"], str(report)
    seconds = time.perf_counter() - start
    return {"result": result, "error": error, "seconds": seconds, "output": output[0]}


def learn(names: list[str], settings: dict) -> dict:
    """Run "Learn from Selected" on ``names`` with the panel ``settings``."""
    select(names)
    panel = bpy.context.scene.neural_shdf
    for key, value in settings.items():
        setattr(panel, key, value)
    error = None
    with captured_stdout() as output:
        try:
            result = sorted(bpy.ops.neural_shdf.learn_from_selected())
        except RuntimeError as report:
            result, error = ["CANCELLED"], str(report)
    return {"result": result, "error": error, "output": output[0],
            "labeler_file": panel.labeler_file}  # fmt: skip


def unwrap(names: list[str], settings: dict, unwrap_settings: dict) -> dict:
    """Run "Unwrap by Parts" on ``names`` with the panels' settings."""
    select(names)
    panel = bpy.context.scene.neural_shdf
    for key, value in settings.items():
        setattr(panel, key, value)
    for key, value in unwrap_settings.items():
        setattr(bpy.context.scene.neural_shdf_unwrap, key, value)
    error = None
    with captured_stdout() as output:
        try:
            result = sorted(bpy.ops.neural_shdf.unwrap_selected())
        except RuntimeError as report:
            result, error = ["CANCELLED"], str(report)
    return {"result": result, "error": error, "output": output[0]}


def edit(name: str, op: str, faces: list[int], active: int, edit_mode: bool = False) -> dict:
    """Select ``faces`` of ``name`` (``active``: the active face, -1 none) and press the
    edit button ``op`` (``reset``: Reset Edits), in Edit Mode when ``edit_mode``."""
    select([name])
    obj = bpy.data.objects[name]
    mesh = obj.data
    chosen = np.zeros(len(mesh.polygons), dtype=bool)
    chosen[faces] = True
    mesh.polygons.foreach_set("select", chosen)
    if active >= 0:
        mesh.polygons.active = active
    if edit_mode:
        bpy.ops.object.mode_set(mode="EDIT")
    error = None
    with captured_stdout() as output:
        try:
            if op == "reset":
                result = sorted(bpy.ops.neural_shdf.reset_edits())
            else:
                result = sorted(bpy.ops.neural_shdf.edit_parts(op=op))
        except RuntimeError as report:
            result, error = ["CANCELLED"], str(report)
    mode = obj.mode
    if edit_mode:
        bpy.ops.object.mode_set(mode="OBJECT")
    return {"result": result, "error": error, "output": output[0], "mode": mode}


def inspect_uv(name: str, uv_map: str) -> dict:
    """The UV map's value per loop and each polygon's loops, and the add-on's note."""
    obj = bpy.data.objects[name]
    mesh = obj.data
    layer = mesh.uv_layers.get(uv_map)
    if layer is None:
        return {"exists": False, "maps": [m.name for m in mesh.uv_layers]}
    values = np.empty(len(mesh.loops) * 2, dtype=np.float32)
    layer.data.foreach_get("uv", values)
    loop_total = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("loop_total", loop_total)
    return {
        "exists": True,
        "active": mesh.uv_layers.active.name,
        "maps": [m.name for m in mesh.uv_layers],
        "uvs": values.reshape(-1, 2).tolist(),
        "loop_total": loop_total.tolist(),
        "note": obj["neural_shdf_unwrap"].to_dict() if "neural_shdf_unwrap" in obj else None,
    }


def phases(names: list[str], settings: dict, payload_path: str | None = None) -> dict:
    """The operator's three steps timed apart: prepare (evaluate + PLY, main thread), the
    worker (network and service), apply (attributes, materials)."""
    operators = importlib.import_module(f"{ADDON_MODULE}.operators")
    select(names)
    panel = bpy.context.scene.neural_shdf
    for key, value in settings.items():
        setattr(panel, key, value)
    t0 = time.perf_counter()
    task = operators.prepare(bpy.context, panel)
    t1 = time.perf_counter()
    task.start()
    task.thread.join()
    t2 = time.perf_counter()
    if task.error:
        raise RuntimeError(task.error)
    if payload_path:
        Path(payload_path).write_bytes(task.requests[0].payload)
    operators.apply(bpy.context, task, panel)
    t3 = time.perf_counter()
    outcome = next(iter(task.outcomes.values()))
    return {
        "prepare_s": t1 - t0,
        "worker_s": t2 - t1,
        "apply_s": t3 - t2,
        "payload_bytes": sum(len(r.payload) for r in task.requests),
        "uploaded": outcome.uploaded,
        "server_ms": outcome.timings,
        "parts": outcome.part_count,
    }


def material_color(material: bpy.types.Material | None) -> dict | None:
    """A material's viewport colour and its Principled BSDF's base colour (linear RGBA)."""
    if material is None:
        return None
    shader = material.node_tree.nodes.get("Principled BSDF") if material.node_tree else None
    base = list(shader.inputs["Base Color"].default_value) if shader else None
    return {"diffuse": list(material.diffuse_color), "base": base}


def inspect(name: str) -> dict:
    """What the add-on left on an object: attribute, materials, custom properties, parts."""
    obj = bpy.data.objects.get(name)
    if obj is None:
        return {"exists": False}
    mesh = obj.data
    record: dict = {"exists": True, "polygons": len(mesh.polygons), "hidden": obj.hide_get()}
    attribute = mesh.attributes.get("neural_shdf_part")
    if attribute is not None:
        labels = np.empty(len(mesh.polygons), dtype=np.int32)
        attribute.data.foreach_get("value", labels)
        record.update(
            attribute_domain=attribute.domain,
            attribute_type=attribute.data_type,
            labels=labels.tolist(),
        )
    material_index = np.empty(len(mesh.polygons), dtype=np.int32)
    mesh.polygons.foreach_get("material_index", material_index)
    record["material_index"] = material_index.tolist()
    record["materials"] = [m.name if m else None for m in mesh.materials]
    record["material_colors"] = [material_color(m) for m in mesh.materials]
    record["has_colors"] = "neural_shdf_color" in mesh.attributes
    if record["has_colors"]:
        colors = mesh.attributes["neural_shdf_color"]
        values = np.empty(len(mesh.polygons) * 4, dtype=np.float32)
        colors.data.foreach_get("color", values)
        record["color_type"] = [colors.domain, colors.data_type]
        record["colors"] = values.reshape(-1, 4).tolist()
    record["props"] = {
        k: obj[k].to_dict() if hasattr(obj[k], "to_dict") else obj[k]
        for k in obj.keys()  # noqa: SIM118
        if k.startswith("neural_shdf")
    }
    named = mesh.attributes.get("neural_shdf_label")
    if named is not None:
        values = np.empty(len(mesh.polygons), dtype=np.int32)
        named.data.foreach_get("value", values)
        record["label_values"] = values.tolist()
        record["label_type"] = [named.domain, named.data_type]
    positions = np.empty(len(mesh.vertices) * 3, dtype=np.float64)
    mesh.vertices.foreach_get("co", positions)
    centers = np.empty(len(mesh.polygons) * 3, dtype=np.float64)
    mesh.polygons.foreach_get("center", centers)
    record["center_x"] = centers[0::3].round(6).tolist()
    record["vertices"] = positions.reshape(-1, 3).round(6).tolist()
    record["polygons_vertices"] = [list(p.vertices) for p in mesh.polygons]
    collection = bpy.data.collections.get(f"{name} parts")
    record["part_objects"] = (
        sorted((o.name, len(o.data.polygons)) for o in collection.objects) if collection else []
    )
    return record


def main() -> None:
    spec = json.loads(Path(sys.argv[1]).read_text())
    records: list[dict] = [{"install": install(spec["zip"])}]
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    makers = {"dumbbell": dumbbell, "flat_triangle": flat_triangle}
    for step in spec["steps"]:
        if "make" in step:
            arguments = {k: v for k, v in step.items() if k != "make"}
            records.append({"make": makers[step["make"]](**arguments)})
        elif "segment" in step:
            records.append({"segment": segment(step["segment"], step.get("settings", {}))})
        elif "phases" in step:
            settings = step.get("settings", {})
            records.append({"phases": phases(step["phases"], settings, step.get("payload"))})
        elif "label_regions" in step:
            arguments = {k: v for k, v in step.items() if k != "label_regions"}
            records.append({"labelled": label_regions(step["label_regions"], **arguments)})
        elif "learn" in step:
            records.append({"learn": learn(step["learn"], step.get("settings", {}))})
        elif "inspect" in step:
            records.append({"inspect": inspect(step["inspect"])})
        elif "unwrap" in step:
            unwrapped = unwrap(
                step["unwrap"], step.get("settings", {}), step.get("unwrap_settings", {})
            )
            records.append({"unwrap": unwrapped})
        elif "edit" in step:
            arguments = {k: v for k, v in step.items() if k != "edit"}
            records.append({"edit": edit(step["edit"], **arguments)})
        elif "inspect_uv" in step:
            records.append({"inspect_uv": inspect_uv(step["inspect_uv"], step["uv_map"])})
    Path(sys.argv[2]).write_text(json.dumps(records))


if __name__ == "__main__":
    status = 0
    try:
        main()
    except BaseException:
        traceback.print_exc()
        status = 1
    sys.stdout.flush()
    sys.stderr.flush()
    # Blender's exit removes its session's temporary folder (blender_XXXXXX); skipped, so here.
    shutil.rmtree(bpy.app.tempdir, ignore_errors=True)
    os._exit(status)  # Blender's own exit may hang or report leaks; the records are written
