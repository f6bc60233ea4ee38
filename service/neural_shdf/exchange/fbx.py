"""FBX is refused, with a message that says what to do instead.

The readers available (assimp 5.2 through pyassimp or assimp-py) were measured on FBX
files exported by Blender: assimp splits a mesh into one mesh per material and lists
each material's faces in an order of its own, and assimp-py only returns triangles;
neither gives a map back to the file's polygons, so per-face results could not follow
the input's face order. Autodesk's FBX SDK is not redistributable.
"""

from __future__ import annotations

#: Why FBX is refused and what to use instead (the message of UnsupportedFormatError).
FBX_REFUSAL = (
    "FBX files are not read: the FBX readers available reorder faces (one mesh per "
    "material) with no map back to your polygons, so per-face results could not follow "
    "your file. Export the model as USD (.usdc/.usdz) or glTF (.glb), or segment it in "
    "Blender with the Neural ShDF add-on (import the FBX there: parts come back on the "
    "object's own faces)"
)


def looks_like_fbx(data: bytes) -> bool:
    """Whether the bytes start like a binary or an ASCII FBX file."""
    head = data[:64]
    return head.startswith(b"Kaydara FBX Binary") or head.lstrip().startswith(b"; FBX ")


__all__ = ["FBX_REFUSAL", "looks_like_fbx"]
