"""Write a segmentation back into Blender: an integer face attribute, a colour per part
(face colour attribute and, optionally, one material per part), and optionally one object
per part."""

from __future__ import annotations

import colorsys

import bpy
import numpy as np

#: Integer face attribute holding the part label of each polygon (-1: a degenerate polygon).
PART_ATTRIBUTE = "neural_shdf_part"
#: Face colour attribute with the part colours.
COLOR_ATTRIBUTE = "neural_shdf_color"
MATERIAL_PREFIX = "neural_shdf part"
UNASSIGNED_COLOR = (0.3, 0.3, 0.3, 1.0)


def part_colors(count: int) -> np.ndarray:
    """Distinct colours (golden-ratio hues), one RGBA row per part: part i has the same
    colour on every object and in the service's coloured GLB order."""
    hues = (np.arange(count) * 0.618033988749895) % 1.0
    rows = [(*colorsys.hsv_to_rgb(h, 0.65, 0.95), 1.0) for h in hues]
    return np.array(rows, dtype=np.float32).reshape(count, 4)


def _fresh_attribute(mesh: bpy.types.Mesh, name: str, data_type: str) -> bpy.types.Attribute:
    existing = mesh.attributes.get(name)
    if existing is not None:
        mesh.attributes.remove(existing)
    return mesh.attributes.new(name, data_type, "FACE")


def write_labels(mesh: bpy.types.Mesh, labels: np.ndarray, part_count: int) -> None:
    """The labels as the integer face attribute and the part colours as a colour attribute."""
    if len(labels) != len(mesh.polygons):
        raise ValueError(
            f"{len(labels)} labels for the {len(mesh.polygons)} polygons of {mesh.name!r}"
        )
    labels = np.ascontiguousarray(labels, dtype=np.int32)
    _fresh_attribute(mesh, PART_ATTRIBUTE, "INT").data.foreach_set("value", labels)
    palette = np.vstack([part_colors(part_count), np.array([UNASSIGNED_COLOR], np.float32)])
    colors = palette[np.where(labels >= 0, labels, part_count)]
    _fresh_attribute(mesh, COLOR_ATTRIBUTE, "BYTE_COLOR").data.foreach_set("color", colors.ravel())
    mesh.update()


def part_material(index: int, color: tuple[float, ...]) -> bpy.types.Material:
    """The shared material of part ``index`` (created once, its colour kept up to date)."""
    name = f"{MATERIAL_PREFIX} {index:03d}" if index >= 0 else f"{MATERIAL_PREFIX} none"
    material = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    material.diffuse_color = color
    material.use_nodes = True
    shader = material.node_tree.nodes.get("Principled BSDF")
    if shader is not None:
        shader.inputs["Base Color"].default_value = color
    return material


def assign_materials(mesh: bpy.types.Mesh, labels: np.ndarray, part_count: int) -> None:
    """Replace the mesh's materials by one per part (slot i = part i; degenerate polygons
    get a grey slot at the end)."""
    colors = part_colors(part_count)
    mesh.materials.clear()
    for index in range(part_count):
        mesh.materials.append(part_material(index, tuple(colors[index].tolist())))
    unassigned = labels < 0
    if unassigned.any():
        mesh.materials.append(part_material(-1, UNASSIGNED_COLOR))
    slots = np.where(unassigned, part_count, labels).astype(np.int32)
    mesh.polygons.foreach_set("material_index", slots)
    mesh.update()


def split_parts(obj: bpy.types.Object, part_count: int) -> list[bpy.types.Object]:
    """One object per part in the collection "<object> parts" (its previous content
    replaced), each the polygons of one part with every attribute kept; ``obj`` is hidden.
    ``obj`` must carry the part materials (``assign_materials``)."""
    collection_name = f"{obj.name} parts"
    collection = bpy.data.collections.get(collection_name)
    if collection is None:
        collection = bpy.data.collections.new(collection_name)
        parent = obj.users_collection[0] if obj.users_collection else bpy.context.scene.collection
        parent.children.link(collection)
    for old in list(collection.objects):
        mesh = old.data
        bpy.data.objects.remove(old)
        if mesh is not None and mesh.users == 0:
            bpy.data.meshes.remove(mesh)
    whole = obj.copy()
    whole.data = obj.data.copy()
    whole.name = f"{obj.name} part"
    collection.objects.link(whole)
    view_layer = bpy.context.view_layer
    for other in view_layer.objects.selected:
        other.select_set(False)
    whole.select_set(True)
    view_layer.objects.active = whole
    with bpy.context.temp_override(
        active_object=whole,
        object=whole,
        selected_objects=[whole],
        selected_editable_objects=[whole],
    ):
        bpy.ops.object.mode_set(mode="EDIT")
        bpy.ops.mesh.select_all(action="SELECT")
        bpy.ops.mesh.separate(type="MATERIAL")
        bpy.ops.object.mode_set(mode="OBJECT")
    parts = sorted(collection.objects, key=lambda o: _part_index(o, part_count))
    for part in parts:
        index = _part_index(part, part_count)
        part.name = f"{obj.name} part {index:03d}" if index < part_count else f"{obj.name} rest"
        part.select_set(False)
    obj.hide_set(True)
    view_layer.objects.active = obj
    return parts


def _part_index(part: bpy.types.Object, part_count: int) -> int:
    """The part a separated object holds: the label of its polygons."""
    attribute = part.data.attributes.get(PART_ATTRIBUTE)
    if attribute is None or not len(part.data.polygons):
        return part_count
    label = attribute.data[0].value
    return label if label >= 0 else part_count
