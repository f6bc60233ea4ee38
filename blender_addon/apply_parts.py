"""Write a segmentation back into Blender: an integer face attribute, a colour per part
(face colour attribute and, optionally, one material per part), and optionally one object
per part. Part colours are the service's (each part's ``color``), linear as Blender wants."""

from __future__ import annotations

import bpy
import numpy as np

from .colors import UNLABELED_LINEAR

#: Integer face attribute holding the part label of each polygon (-1: a degenerate polygon).
PART_ATTRIBUTE = "neural_shdf_part"
#: Face colour attribute with the part colours (linear floats).
COLOR_ATTRIBUTE = "neural_shdf_color"
#: Integer face attribute keeping each polygon's own material slot while part materials show.
OWN_MATERIAL_ATTRIBUTE = "neural_shdf_own_material"
MATERIAL_PREFIX = "neural_shdf part"
#: Integer face attribute of named parts: each polygon's label in the labeller's own
#: integers (what "Learn from Selected" reads back by default).
LABEL_ATTRIBUTE = "neural_shdf_label"


def _fresh_attribute(mesh: bpy.types.Mesh, name: str, data_type: str) -> bpy.types.Attribute:
    existing = mesh.attributes.get(name)
    if existing is not None:
        mesh.attributes.remove(existing)
    return mesh.attributes.new(name, data_type, "FACE")


def _palette(colors: list[tuple[float, ...]]) -> np.ndarray:
    """(parts + 1, 4) linear RGBA: the parts' colours, then the unlabeled grey."""
    return np.array([*colors, UNLABELED_LINEAR], dtype=np.float32).reshape(-1, 4)


def write_labels(mesh: bpy.types.Mesh, labels: np.ndarray, colors: list[tuple[float, ...]]) -> None:
    """The labels as the integer face attribute and the part colours (linear RGBA per label,
    ``colors.part_colors``) as a FLOAT_COLOR face attribute."""
    if len(labels) != len(mesh.polygons):
        raise ValueError(
            f"{len(labels)} labels for the {len(mesh.polygons)} polygons of {mesh.name!r}"
        )
    labels = np.ascontiguousarray(labels, dtype=np.int32)
    _fresh_attribute(mesh, PART_ATTRIBUTE, "INT").data.foreach_set("value", labels)
    part_count = len(colors)
    per_face = _palette(colors)[np.where(labels >= 0, labels, part_count)]
    attribute = _fresh_attribute(mesh, COLOR_ATTRIBUTE, "FLOAT_COLOR")
    attribute.data.foreach_set("color", per_face.ravel())
    mesh.update()


def write_label_values(mesh: bpy.types.Mesh, values: np.ndarray, name: str) -> None:
    """Named parts' integers (one per polygon) as the integer face attribute ``name``."""
    if len(values) != len(mesh.polygons):
        raise ValueError(
            f"{len(values)} labels for the {len(mesh.polygons)} polygons of {mesh.name!r}"
        )
    values = np.ascontiguousarray(values, dtype=np.int32)
    _fresh_attribute(mesh, name, "INT").data.foreach_set("value", values)
    mesh.update()


def read_label_values(mesh: bpy.types.Mesh, name: str) -> np.ndarray:
    """The integer face attribute ``name`` (one label per polygon); ValueError when the
    mesh has none of that name, domain and type."""
    attribute = mesh.attributes.get(name)
    if attribute is None or attribute.domain != "FACE" or attribute.data_type != "INT":
        raise ValueError(
            f"{mesh.name!r} has no integer face attribute {name!r}: give each polygon its "
            "label there (e.g. from a segmentation with a labeller, or Geometry Nodes)"
        )
    values = np.empty(len(mesh.polygons), dtype=np.int32)
    attribute.data.foreach_get("value", values)
    return values


def part_material(
    index: int, color: tuple[float, ...], name: str | None = None
) -> bpy.types.Material:
    """The shared material of part ``index`` (created once, its colour kept up to date),
    named by the part's label ``name`` where given; ``color``: linear RGBA, as Blender's
    colours are."""
    if name is not None:
        name = f"{MATERIAL_PREFIX} {name}"
    else:
        name = f"{MATERIAL_PREFIX} {index:03d}" if index >= 0 else f"{MATERIAL_PREFIX} none"
    material = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    material.diffuse_color = color
    material.use_nodes = True
    shader = material.node_tree.nodes.get("Principled BSDF")
    if shader is not None:
        shader.inputs["Base Color"].default_value = color
    return material


def _is_part_material(material: bpy.types.Material | None) -> bool:
    return material is not None and material.name.startswith(MATERIAL_PREFIX)


def _drop_part_slots(mesh: bpy.types.Mesh) -> None:
    """Remove the part materials' slots (the last ones); the object's own slots stay."""
    for index in reversed(range(len(mesh.materials))):
        if _is_part_material(mesh.materials[index]):
            mesh.materials.pop(index=index)


def assign_materials(
    mesh: bpy.types.Mesh,
    labels: np.ndarray,
    colors: list[tuple[float, ...]],
    names: list[str] | None = None,
) -> None:
    """Show one material per part: the part materials go in slots after the object's own,
    which are never removed; each polygon's own slot is kept in OWN_MATERIAL_ATTRIBUTE
    (restore_materials puts it back). Degenerate polygons get a grey slot at the end.
    ``names``: a name per part (named parts): the materials are named by it."""
    if mesh.attributes.get(OWN_MATERIAL_ATTRIBUTE) is None:
        own = np.empty(len(mesh.polygons), dtype=np.int32)
        mesh.polygons.foreach_get("material_index", own)
        _fresh_attribute(mesh, OWN_MATERIAL_ATTRIBUTE, "INT").data.foreach_set("value", own)
    _drop_part_slots(mesh)
    first = len(mesh.materials)
    part_count = len(colors)
    for index, color in enumerate(colors):
        mesh.materials.append(part_material(index, color, names[index] if names else None))
    unassigned = labels < 0
    if unassigned.any():
        mesh.materials.append(part_material(-1, UNLABELED_LINEAR))
    slots = first + np.where(unassigned, part_count, labels).astype(np.int32)
    mesh.polygons.foreach_set("material_index", slots)
    mesh.update()


def restore_materials(mesh: bpy.types.Mesh) -> None:
    """Undo assign_materials: the part slots go, each polygon gets its own slot back."""
    saved = mesh.attributes.get(OWN_MATERIAL_ATTRIBUTE)
    if saved is None:
        return
    own = np.empty(len(mesh.polygons), dtype=np.int32)
    saved.data.foreach_get("value", own)
    _drop_part_slots(mesh)
    mesh.polygons.foreach_set("material_index", own)
    mesh.attributes.remove(mesh.attributes[OWN_MATERIAL_ATTRIBUTE])
    mesh.update()


def split_parts(
    obj: bpy.types.Object, part_count: int, names: list[str] | None = None
) -> list[bpy.types.Object]:
    """One object per part in the collection "<object> parts" (its previous content
    replaced), each the polygons of one part with every attribute kept; ``obj`` is hidden.
    ``obj`` must carry the part materials (``assign_materials``). ``names``: a name per
    part: the objects are "<object> <name>"."""
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
        if index >= part_count:
            part.name = f"{obj.name} rest"
        else:
            part.name = f"{obj.name} {names[index]}" if names else f"{obj.name} part {index:03d}"
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
