"""Part editing on a segmented object: grow, shrink, merge, paint and split the parts of
the selected faces (Edit Mode or Object Mode). Each button adds one operation to the
object's edit document and sends the whole document to the service's ``/v1/segment``
(``edits``), which applies it to the cached segmentation: the add-on, the viewer, the
client and the API agree on the labels. A new "Segment Selected" starts a new document."""

from __future__ import annotations

import json
import time

import bpy
import numpy as np
from bpy.props import EnumProperty

from . import apply_parts, colors, part_edits, service
from .properties import EDITS_KEY, MESH_ID_KEY, OPTIONS_KEY, PARTS_KEY, SERVER_KEY

LABELS_ATTRIBUTE = "neural_shdf_part"


def segmented(obj: bpy.types.Object | None) -> str | None:
    """Why ``obj`` cannot be edited (None: it can)."""
    if obj is None or obj.type != "MESH":
        return "Make a segmented mesh object active"
    if MESH_ID_KEY not in obj or OPTIONS_KEY not in obj:
        return "Segment the object first (Segment Selected)"
    if LABELS_ATTRIBUTE not in obj.data.attributes:
        return "The object has no part labels; segment it again"
    return None


def selection(mesh: bpy.types.Mesh) -> tuple[np.ndarray, np.ndarray, int]:
    """(labels, selected, active polygon) of the mesh as stored (Object Mode data)."""
    count = len(mesh.polygons)
    labels = np.empty(count, dtype=np.int32)
    mesh.attributes[LABELS_ATTRIBUTE].data.foreach_get("value", labels)
    selected = np.empty(count, dtype=bool)
    mesh.polygons.foreach_get("select", selected)
    active = mesh.polygons.active
    if not (0 <= active < count and selected[active]):
        active = -1
    return labels, selected, active


def send(obj: bpy.types.Object, document: list[dict]) -> service.Outcome:
    """The service's labels for the object's segmentation edited by ``document``."""
    session = service.Session(obj[SERVER_KEY])
    options = {**json.loads(obj[OPTIONS_KEY]), "edits": document}
    start = time.perf_counter()

    def ignore(fraction: float, status: str) -> None:
        return None

    try:
        body = session.segment_by_id(obj[MESH_ID_KEY], options, ignore)
    except service.ServiceError as error:
        if error.status == 404:
            raise service.ServiceError(
                "the service no longer has this mesh; press Segment Selected again (the "
                "edits start over)",
                error.code,
                404,
            ) from None
        raise
    outcome = session._outcome(body, uploaded=False, start=start)
    if len(outcome.labels) != len(obj.data.polygons):
        raise service.ServiceError(
            f"the service sent {len(outcome.labels)} labels for {len(obj.data.polygons)} "
            "polygons; the mesh changed since it was segmented: segment it again"
        )
    return outcome


class EditPartsOperator(bpy.types.Operator):
    """Edit the parts of the selected faces through the neural-shdf service"""

    bl_idname = "neural_shdf.edit_parts"
    bl_label = "Edit Parts"
    bl_options = {"REGISTER", "UNDO"}

    op: EnumProperty(  # type: ignore[valid-type]
        name="Edit",
        items=[
            ("grow", "Grow", "The active face's part takes its parent in the part tree"),
            ("shrink", "Shrink", "The active face's part splits into its two children"),
            ("merge", "Merge", "The parts of the selected faces become one part"),
            ("paint", "Paint", "The selected faces join the active face's part"),
            ("split", "Split", "The active face's part is cut in two (METIS bisection)"),
        ],
        default="merge",
    )

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        why = segmented(context.active_object)
        if why:
            cls.poll_message_set(why)
        return why is None

    def execute(self, context: bpy.types.Context) -> set[str]:
        obj = context.active_object
        mode = obj.mode
        if mode == "EDIT":  # the selection and attributes live in the edit mesh until then
            bpy.ops.object.mode_set(mode="OBJECT")
        try:
            labels, selected, active = selection(obj.data)
            operation = part_edits.operation(self.op, labels, selected, active)
            document = [*json.loads(obj.get(EDITS_KEY, "[]")), operation]
            outcome = send(obj, document)
            new_labels = np.frombuffer(outcome.labels, dtype=np.int32)
            part_colors = colors.part_colors(outcome.parts)
            apply_parts.write_labels(obj.data, new_labels, part_colors)
            if context.scene.neural_shdf.assign_materials:
                apply_parts.assign_materials(obj.data, new_labels, part_colors)
            obj[EDITS_KEY] = json.dumps(document)
            obj[PARTS_KEY] = outcome.part_count
        except (part_edits.EditRequestError, service.ServiceError) as error:
            self.report({"ERROR"}, f"neural-shdf: {error}")
            return {"CANCELLED"}
        finally:
            if mode == "EDIT":
                bpy.ops.object.mode_set(mode="EDIT")
        self.report(
            {"INFO"},
            f"neural-shdf: {self.op}: {outcome.part_count} parts ({len(document)} edits)",
        )
        return {"FINISHED"}


class ResetEditsOperator(bpy.types.Operator):
    """Drop the hand edits: the object's segmentation as the service made it"""

    bl_idname = "neural_shdf.reset_edits"
    bl_label = "Reset Edits"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        obj = context.active_object
        return segmented(obj) is None and EDITS_KEY in obj

    def execute(self, context: bpy.types.Context) -> set[str]:
        obj = context.active_object
        mode = obj.mode
        if mode == "EDIT":
            bpy.ops.object.mode_set(mode="OBJECT")
        try:
            outcome = send(obj, [])
            labels = np.frombuffer(outcome.labels, dtype=np.int32)
            part_colors = colors.part_colors(outcome.parts)
            apply_parts.write_labels(obj.data, labels, part_colors)
            if context.scene.neural_shdf.assign_materials:
                apply_parts.assign_materials(obj.data, labels, part_colors)
            del obj[EDITS_KEY]
            obj[PARTS_KEY] = outcome.part_count
        except service.ServiceError as error:
            self.report({"ERROR"}, f"neural-shdf: {error}")
            return {"CANCELLED"}
        finally:
            if mode == "EDIT":
                bpy.ops.object.mode_set(mode="EDIT")
        return {"FINISHED"}


class EditPartsPanel(bpy.types.Panel):
    bl_label = "Edit Parts"
    bl_idname = "NEURAL_SHDF_PT_edit_parts"
    bl_parent_id = "NEURAL_SHDF_PT_segment"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Neural ShDF"

    def draw(self, context: bpy.types.Context) -> None:
        layout = self.layout
        obj = context.active_object
        why = segmented(obj)
        if why:
            layout.label(text=why, icon="INFO")
            return
        layout.label(text="Select faces (the active one: the part)")
        grid = layout.grid_flow(columns=3, align=True)
        for op, label in (
            ("grow", "Grow"),
            ("shrink", "Shrink"),
            ("split", "Split"),
            ("merge", "Merge"),
            ("paint", "Paint"),
        ):
            grid.operator(EditPartsOperator.bl_idname, text=label).op = op
        edits = len(json.loads(obj.get(EDITS_KEY, "[]")))
        row = layout.row()
        row.label(text=f"{edits} edits")
        row.operator(ResetEditsOperator.bl_idname, text="Reset")


CLASSES = (EditPartsOperator, ResetEditsOperator, EditPartsPanel)
