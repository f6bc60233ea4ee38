"""Neural ShDF Segmentation: a Blender 4.2+ extension that splits meshes into parts with a
neural-shdf service (3D Viewport > sidebar > Neural ShDF).

Only ``register``/``unregister`` touch bpy here, so ``service`` and ``mesh_payload`` can be
imported (and tested) outside Blender.
"""

from __future__ import annotations


def _modules():  # noqa: ANN202
    from . import editing, operators, panel, properties, unwrap

    return properties, operators, panel, unwrap, editing


def register() -> None:
    import bpy

    for module in _modules():
        for cls in module.CLASSES:
            bpy.utils.register_class(cls)
    _modules()[0].register()
    _modules()[3].register()


def unregister() -> None:
    import bpy

    properties, unwrap = _modules()[0], _modules()[3]
    unwrap.unregister()
    properties.unregister()
    for module in reversed(_modules()):
        for cls in reversed(module.CLASSES):
            bpy.utils.unregister_class(cls)
