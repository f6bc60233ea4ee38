"""The sidebar panel (3D Viewport > N > Neural ShDF)."""

from __future__ import annotations

import bpy

from .properties import PARTS_KEY


class SegmentPanel(bpy.types.Panel):
    bl_label = "Segmentation"
    bl_idname = "NEURAL_SHDF_PT_segment"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Neural ShDF"

    def draw(self, context: bpy.types.Context) -> None:
        layout = self.layout
        settings = context.scene.neural_shdf
        layout.prop(settings, "server_url")
        column = layout.column(align=True)
        column.prop(settings, "method")
        column.prop(settings, "partitioner")
        column.prop(settings, "clusters")
        column.prop(settings, "smoothing")
        row = column.row(align=True)
        row.prop(settings, "use_parts", text="")
        parts = row.row(align=True)
        parts.enabled = settings.use_parts
        parts.prop(settings, "parts")
        layout.prop(settings, "labeler_file")
        layout.prop(settings, "assign_materials")
        layout.prop(settings, "split_parts")
        state = context.window_manager.neural_shdf_state
        if state.running:
            layout.progress(factor=state.progress, type="BAR", text=state.status or "working")
        layout.operator("neural_shdf.segment_selected", icon="MOD_EXPLODE")
        obj = context.active_object
        if obj is not None and PARTS_KEY in obj:
            layout.label(text=f"{obj.name}: {obj[PARTS_KEY]} parts", icon="INFO")
        box = layout.box()
        box.label(text="Learn named parts")
        box.prop(settings, "label_attribute")
        box.prop(settings, "label_names")
        box.prop(settings, "learn_output")
        box.operator("neural_shdf.learn_from_selected", icon="FILE_NEW")


CLASSES = (SegmentPanel,)
