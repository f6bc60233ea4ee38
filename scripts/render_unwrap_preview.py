"""Render an unwrapped GLB with its atlas texture in Blender (Cycles, CPU, headless).

Run with a Python that has ``bpy==4.5.*`` (bpy wants numpy<2: a venv of its own):

    neural-shdf unwrap ../shared/data/psb-dev/off/61.off -o /tmp/u.glb \
        --atlas-png docs/unwrap_atlas.png
    /path/to/bpy-venv/bin/python scripts/render_unwrap_preview.py /tmp/u.glb docs/unwrap_render.png
"""

from __future__ import annotations

import math
import sys

import bpy
from mathutils import Vector


def render(glb_path: str, png_path: str, size: int = 900) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=glb_path)
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    corners = [o.matrix_world @ Vector(c) for o in meshes for c in o.bound_box]
    low = Vector([min(c[i] for c in corners) for i in range(3)])
    high = Vector([max(c[i] for c in corners) for i in range(3)])
    centre, radius = (low + high) / 2, (high - low).length / 2
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    bpy.context.scene.collection.objects.link(camera)
    direction = Vector((1.0, -1.4, 0.9)).normalized()
    camera.location = centre + direction * radius * 2.6
    camera.rotation_euler = (centre - camera.location).to_track_quat("-Z", "Y").to_euler()
    bpy.context.scene.camera = camera
    for angle, energy in ((0.0, 4.0), (2.5, 2.0)):
        light = bpy.data.objects.new("sun", bpy.data.lights.new("sun", type="SUN"))
        light.data.energy = energy
        light.rotation_euler = (math.radians(50), 0.0, angle)
        bpy.context.scene.collection.objects.link(light)
    world = bpy.data.worlds.new("world")
    world.color = (0.9, 0.9, 0.9)
    bpy.context.scene.world = world
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 24
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.filepath = png_path
    bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    render(sys.argv[1], sys.argv[2])
