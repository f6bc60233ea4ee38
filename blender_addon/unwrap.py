""" "Unwrap by Parts": the selected meshes are segmented (as "Segment Selected" does, by mesh
id when the service has them) and unwrapped by the service, part by part into one atlas;
the UVs go into a UV map of the object, one value per loop in Blender's polygon order."""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np
from bpy.props import IntProperty, StringProperty

from . import operators, service, uv_layout
from .worker import WorkerTask

#: The custom property an object keeps about its last unwrap (charts, atlas use).
UNWRAP_KEY = "neural_shdf_unwrap"


class NeuralShdfUnwrapSettings(bpy.types.PropertyGroup):
    """How to chart and pack (the segmentation's settings are the Segmentation panel's)."""

    atlas_size: IntProperty(  # type: ignore[valid-type]
        name="Atlas Size",
        description="Side of the square atlas in texels (the UVs are packed for it)",
        default=1024,
        min=64,
        max=8192,
    )
    padding: IntProperty(  # type: ignore[valid-type]
        name="Padding",
        description="Texels left free around every chart",
        default=2,
        min=0,
        max=64,
    )
    uv_map: StringProperty(  # type: ignore[valid-type]
        name="UV Map",
        description="The UV map the UVs go into (made when missing, made active)",
        default="neural_shdf parts",
    )

    def options(self) -> dict[str, object]:
        return {"atlas_size": self.atlas_size, "padding": self.padding}


@dataclass(kw_only=True)
class UnwrapTask(operators.SegmentTask):
    """Segment, then fetch the UV layout of the same segmentation, per object."""

    unwrap_options: dict[str, object] = field(default_factory=dict)
    layouts: dict[str, uv_layout.UvLayout] = field(default_factory=dict)

    def run_one(
        self,
        session: service.Session,
        request: operators.ObjectRequest,
        report: service.Progress,
    ) -> service.Outcome:
        outcome = super().run_one(session, request, report)
        report(0.5, "unwrapping")
        options = {**self.options, **self.unwrap_options}
        self.layouts[request.object_name] = uv_layout.fetch(
            session, outcome.mesh_id, options, report
        )
        return outcome


def written_object(obj: bpy.types.Object, request: operators.ObjectRequest) -> bpy.types.Object:
    """The object ``operators.apply`` wrote the labels to (itself, or "<name> segmented")."""
    if request.evaluated_mesh is None:
        return obj
    return bpy.data.objects[f"{obj.name} segmented"]


def write_uvs(mesh: bpy.types.Mesh, layout: uv_layout.UvLayout, name: str) -> int:
    """Write the layout into the UV map ``name`` (made when missing, made active); returns
    how many polygons got no UVs (their corner count differs from the service's)."""
    polygons = len(mesh.polygons)
    loop_start = np.empty(polygons, dtype=np.int32)
    loop_total = np.empty(polygons, dtype=np.int32)
    mesh.polygons.foreach_get("loop_start", loop_start)
    mesh.polygons.foreach_get("loop_total", loop_total)
    values, missing = uv_layout.loop_uvs(layout, loop_start, loop_total)
    layer = mesh.uv_layers.get(name) or mesh.uv_layers.new(name=name)
    if layer is None:
        raise service.ServiceError(
            f"{mesh.name!r} has as many UV maps as Blender allows; remove one or name an "
            "existing map in UV Map"
        )
    layer.data.foreach_set("uv", values.reshape(-1))
    mesh.uv_layers.active = layer
    return missing


class UnwrapSelectedOperator(operators.ServiceTaskOperator, bpy.types.Operator):
    """Unwrap the selected meshes part by part into one atlas with the neural-shdf service"""

    bl_idname = "neural_shdf.unwrap_selected"
    bl_label = "Unwrap by Parts"
    bl_options = {"REGISTER", "UNDO"}

    def make_task(self, context: bpy.types.Context) -> operators.SegmentTask:
        base = operators.prepare(context, context.scene.neural_shdf)
        return UnwrapTask(
            server_url=base.server_url,
            options=base.options,
            requests=base.requests,
            unwrap_options=context.scene.neural_shdf_unwrap.options(),
        )

    def write_back(self, context: bpy.types.Context, task: WorkerTask) -> list[str]:
        assert isinstance(task, UnwrapTask)
        operators.apply(context, task, context.scene.neural_shdf)  # labels, as Segment does
        settings = context.scene.neural_shdf_unwrap
        lines = []
        for request in task.requests:
            obj = bpy.data.objects.get(request.object_name)
            layout = task.layouts.get(request.object_name)
            if obj is None or layout is None:
                continue
            target = written_object(obj, request)
            missing = write_uvs(target.data, layout, settings.uv_map)
            target[UNWRAP_KEY] = {
                "charts": layout.chart_count,
                "utilization": layout.utilization,
                "split_polygons": layout.split_faces,
                "polygons_without_uvs": missing,
            }
            note = f", {missing} polygons without UVs" if missing else ""
            lines.append(
                f"{target.name}: {layout.chart_count} charts, {layout.utilization:.0%} of the "
                f"atlas in UV map {settings.uv_map!r}{note}"
            )
        return lines


class UnwrapPanel(bpy.types.Panel):
    bl_label = "Unwrap by Parts"
    bl_idname = "NEURAL_SHDF_PT_unwrap"
    bl_parent_id = "NEURAL_SHDF_PT_segment"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Neural ShDF"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context: bpy.types.Context) -> None:
        layout = self.layout
        settings = context.scene.neural_shdf_unwrap
        column = layout.column(align=True)
        column.prop(settings, "atlas_size")
        column.prop(settings, "padding")
        layout.prop(settings, "uv_map")
        layout.operator("neural_shdf.unwrap_selected", icon="UV")
        obj = context.active_object
        if obj is not None and UNWRAP_KEY in obj:
            info = obj[UNWRAP_KEY]
            layout.label(
                text=f"{info['charts']} charts, {info['utilization']:.0%} used", icon="INFO"
            )


CLASSES = (NeuralShdfUnwrapSettings, UnwrapSelectedOperator, UnwrapPanel)


def register() -> None:
    bpy.types.Scene.neural_shdf_unwrap = bpy.props.PointerProperty(type=NeuralShdfUnwrapSettings)


def unregister() -> None:
    del bpy.types.Scene.neural_shdf_unwrap
