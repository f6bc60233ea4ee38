"""A glTF scene with everything an artist's file carries (normals, tangents, two UV sets,
vertex colours, a textured and a plain material, several nodes, one of them mirrored),
written by hand so that every value is known; and the order parts_glb writes faces in."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import trimesh
from PIL import Image

from neural_shdf.exchange.attributes import SourceMesh


def _png(color: tuple[int, int, int]) -> bytes:
    out = io.BytesIO()
    Image.new("RGB", (4, 4), color).save(out, format="PNG")
    return out.getvalue()


class GltfBuilder:
    """One buffer, one bufferView per accessor or image."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.doc: dict = {"asset": {"version": "2.0"}, "accessors": [], "bufferViews": [],
                          "meshes": [], "nodes": []}  # fmt: skip

    def view(self, data: bytes, target: int | None = None) -> int:
        while len(self.blob) % 4:
            self.blob += b"\x00"
        view = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if target:
            view["target"] = target
        self.doc["bufferViews"].append(view)
        self.blob += data
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, array: np.ndarray, kind: str, *, minmax: bool = False) -> int:
        component = {np.dtype("float32"): 5126, np.dtype("uint32"): 5125}[array.dtype]
        target = 34963 if kind == "SCALAR" else 34962
        spec = {"bufferView": self.view(array.tobytes(), target), "componentType": component,
                "type": kind, "count": len(array)}  # fmt: skip
        if minmax:
            spec["min"] = array.min(axis=0).tolist()
            spec["max"] = array.max(axis=0).tolist()
        self.doc["accessors"].append(spec)
        return len(self.doc["accessors"]) - 1

    def glb(self) -> bytes:
        self.doc["buffers"] = [{"byteLength": len(self.blob)}]
        text = json.dumps(self.doc).encode()
        text += b" " * (-len(text) % 4)
        blob = bytes(self.blob) + b"\x00" * (-len(self.blob) % 4)
        total = 12 + 8 + len(text) + 8 + len(blob)
        return (
            struct.pack("<4sII", b"glTF", 2, total)
            + struct.pack("<II", len(text), 0x4E4F534A)
            + text
            + struct.pack("<II", len(blob), 0x004E4942)
            + blob
        )


def textured_scene_glb() -> bytes:
    """Two nodes ("Body", translated and rotated; "Mirror", scaled by -1 in x) placing
    one mesh of two primitives: an icosphere's upper half with normals, tangents,
    TEXCOORD_0/1, COLOR_0 and a textured material, its lower half with normals,
    TEXCOORD_0 and a plain material."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    builder = GltfBuilder()
    upper = sphere.triangles_center[:, 2] >= 0
    primitives = []
    for half, material in ((upper, 0), (~upper, 1)):
        faces = sphere.faces[half]
        used, inverse = np.unique(faces, return_inverse=True)
        positions = sphere.vertices[used].astype(np.float32)
        normals = sphere.vertex_normals[used].astype(np.float32)
        uv = np.column_stack([np.arctan2(positions[:, 1], positions[:, 0]) / (2 * np.pi) + 0.5,
                              0.5 - positions[:, 2] / 2]).astype(np.float32)  # fmt: skip
        attributes = {
            "POSITION": builder.accessor(positions, "VEC3", minmax=True),
            "NORMAL": builder.accessor(normals, "VEC3"),
            "TEXCOORD_0": builder.accessor(uv, "VEC2"),
        }
        if material == 0:
            tangent = np.cross(normals, [0.0, 0.0, 1.0])
            tangent[np.linalg.norm(tangent, axis=1) < 1e-6] = [1.0, 0.0, 0.0]
            tangent /= np.linalg.norm(tangent, axis=1)[:, None]
            tangents = np.column_stack([tangent, np.ones(len(tangent))]).astype(np.float32)
            colors = np.column_stack([uv, np.full(len(uv), 0.25), np.ones(len(uv))])
            attributes["TANGENT"] = builder.accessor(tangents, "VEC4")
            attributes["TEXCOORD_1"] = builder.accessor(uv[:, ::-1].copy(), "VEC2")
            attributes["COLOR_0"] = builder.accessor(colors.astype(np.float32), "VEC4")
        indices = builder.accessor(inverse.reshape(-1).astype(np.uint32), "SCALAR")
        primitives.append({"attributes": attributes, "indices": indices, "material": material})
    builder.doc["meshes"].append({"name": "Ball", "primitives": primitives})
    image = builder.view(_png((200, 40, 40)))
    builder.doc["images"] = [{"bufferView": image, "mimeType": "image/png"}]
    builder.doc["samplers"] = [{"magFilter": 9729, "minFilter": 9987}]
    builder.doc["textures"] = [{"source": 0, "sampler": 0}]
    builder.doc["materials"] = [
        {"name": "Painted", "pbrMetallicRoughness": {
            "baseColorTexture": {"index": 0, "texCoord": 0}},
         "normalTexture": {"index": 0, "texCoord": 1}},
        {"name": "Plain", "pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.5, 0.8, 1.0]}},
    ]  # fmt: skip
    builder.doc["nodes"] = [
        {"name": "Body", "mesh": 0, "translation": [0.5, 0.0, 2.0],
         "rotation": [0.0, 0.0, 0.38268343, 0.92387953]},
        {"name": "Mirror", "mesh": 0, "scale": [-1.0, 1.0, 1.0], "translation": [3.0, 0, 0]},
    ]  # fmt: skip
    builder.doc["scenes"] = [{"nodes": [0, 1]}]
    builder.doc["scene"] = 0
    return builder.glb()


def parts_order(source: SourceMesh, labels: np.ndarray) -> np.ndarray:
    """The triangles of ``source`` in the order parts_glb writes them: object by object,
    part by part (label order), face group by face group, each in the mesh's order."""
    attributes = source.attributes
    assert attributes is not None
    group_object = np.array([g.object for g in attributes.groups])
    objects = np.maximum(group_object[attributes.face_group], 0)
    return np.lexsort((attributes.face_group, labels, objects))
