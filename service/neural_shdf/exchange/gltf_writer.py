"""Write segmentation results as binary glTF: one colour per part, one node per part, or the
mesh with its atlas UVs."""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

from neural_shdf.arrays import unique_rows
from neural_shdf.errors import ParameterError
from neural_shdf.mesh import TriangleMesh
from neural_shdf.palette import UNLABELED_COLOR, linear_color_bytes, part_colors
from neural_shdf.unwrap import UvAtlas


def _check_labels(mesh: TriangleMesh, labels: NDArray) -> NDArray[np.int64]:
    labels = np.asarray(labels)
    if labels.shape != (mesh.face_count,) or labels.dtype.kind not in "iu":
        raise ParameterError(
            f"need one integer label per triangle ({mesh.face_count}), got an array of shape "
            f"{labels.shape} and dtype {labels.dtype}; map per-input-face labels with "
            "labels[mesh.face_origin]"
        )
    return labels.astype(np.int64)


def _label_colors(labels: NDArray[np.int64]) -> NDArray[np.uint8]:
    """RGBA per triangle: part_colors by label value, UNLABELED_COLOR for negative labels."""
    palette = part_colors(int(labels.max()) + 1 if len(labels) and labels.max() >= 0 else 0)
    colors = np.tile(UNLABELED_COLOR, (len(labels), 1))
    labelled = labels >= 0
    colors[labelled] = palette[labels[labelled]]
    return colors


def split_by_part(
    mesh: TriangleMesh, labels: NDArray
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Vertices duplicated so that no vertex is shared by two parts.

    Returns ``(vertices, faces, vertex_label)``: triangles in the mesh's order,
    each vertex used by triangles of one label only.
    """
    labels = _check_labels(mesh, labels)
    corners = mesh.faces.reshape(-1)
    if len(corners) == 0:
        return mesh.vertices[:0], mesh.faces.astype(np.int64), labels[:0]
    # One integer per (vertex, label): sorts like the pairs, far faster than unique rows.
    low = int(labels.min())
    span = int(labels.max()) - low + 1
    keys = corners * span + (np.repeat(labels, 3) - low)
    unique, inverse = np.unique(keys, return_inverse=True)
    vertex, label = np.divmod(unique, span)
    return mesh.vertices[vertex], inverse.reshape(-1, 3).astype(np.int64), label + low


def colored_glb(
    mesh: TriangleMesh, labels_per_triangle: NDArray, *, colors: NDArray | None = None
) -> bytes:
    """GLB of the mesh with one colour per part (vertex colours; parts never share a vertex).

    ``colors`` overrides the palette: (n_labels, 3 or 4) sRGB uint8, indexed by label. COLOR_0
    holds them linear, as glTF defines it, so viewers show the sRGB colours of the API.
    """
    labels = _check_labels(mesh, labels_per_triangle)
    vertices, faces, vertex_label = split_by_part(mesh, labels)
    if colors is None:
        vertex_colors = _label_colors(vertex_label)
    else:
        palette = np.asarray(colors, dtype=np.uint8)
        if palette.shape[1] == 3:
            palette = np.concatenate([palette, np.full((len(palette), 1), 255, np.uint8)], 1)
        vertex_colors = palette[vertex_label]
    vertex_colors = linear_color_bytes(vertex_colors)
    out = trimesh.Trimesh(vertices, faces, vertex_colors=vertex_colors, process=False)
    return out.export(file_type="glb")


def part_name(label: int) -> str:
    """Node and mesh name of a part in parts_glb: ``part_000``, ..., or ``unlabeled``."""
    return f"part_{label:03d}" if label >= 0 else "unlabeled"


def parts_glb(
    mesh: TriangleMesh, labels: NDArray, *, names: Mapping[int, str] | None = None
) -> bytes:
    """GLB scene with one node and mesh per part, named by part_name, in label order.
    ``names``: a name per label value (a labeller's label names) used instead, where given.

    Each part keeps its triangles in the mesh's order and only the vertices they use
    (in vertex order), coloured by part. Written directly from numpy buffers (three
    buffer views shared by every part), so time and memory are linear in the faces and
    the parts, however many parts there are.
    """
    labels = _check_labels(mesh, labels)
    order = np.argsort(labels, kind="stable")
    values, face_start, face_count = np.unique(labels[order], return_index=True, return_counts=True)
    part_count = len(values)
    corner_part = np.repeat(np.arange(part_count), 3 * face_count)
    vertex_total = max(len(mesh.vertices), 1)
    keys = corner_part * vertex_total + mesh.faces[order].reshape(-1)
    used, corner_vertex = np.unique(keys, return_inverse=True)
    vertex_part = used // vertex_total
    vertex_start = np.searchsorted(vertex_part, np.arange(part_count))
    vertex_count = np.diff(np.append(vertex_start, len(used)))
    indices = (corner_vertex.reshape(-1) - vertex_start[corner_part]).astype("<u4")
    positions = mesh.vertices[used % vertex_total].astype("<f4")
    # COLOR_0 is linear in glTF: the sRGB palette converted, as in colored_glb.
    colors = linear_color_bytes(_label_colors(values))[vertex_part]
    if part_count:
        low = np.minimum.reduceat(positions, vertex_start).tolist()
        high = np.maximum.reduceat(positions, vertex_start).tolist()
    else:
        low = high = []

    blocks = [indices.tobytes(), positions.tobytes(), np.ascontiguousarray(colors).tobytes()]
    offsets = np.cumsum([0] + [len(block) for block in blocks]).tolist()
    document: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "neural-shdf"},
        "scene": 0,
        "scenes": [{"nodes": list(range(part_count))} if part_count else {}],
    }
    if not part_count:  # glTF allows no empty arrays
        return glb_bytes(json.dumps(document, separators=(",", ":")), b"")
    document["bufferViews"] = [
        {"buffer": 0, "byteOffset": offsets[0], "byteLength": len(blocks[0]), "target": 34963},
        {"buffer": 0, "byteOffset": offsets[1], "byteLength": len(blocks[1]),
         "byteStride": 12, "target": 34962},
        {"buffer": 0, "byteOffset": offsets[2], "byteLength": len(blocks[2]),
         "byteStride": 4, "target": 34962},
    ]  # fmt: skip
    document["buffers"] = [{"byteLength": offsets[-1]}]
    # Per-part entries as text from templates: json.dumps of a dict per accessor would
    # take most of the time with many parts.
    given = names or {}
    # JSON string bodies (the templates hold the quotes): a name may hold any character.
    node_names = [json.dumps(given.get(label, part_name(label)))[1:-1] for label in values.tolist()]
    rows = zip(
        (12 * face_start).tolist(),
        (3 * face_count).tolist(),
        (12 * vertex_start).tolist(),
        vertex_count.tolist(),
        low,
        high,
        (4 * vertex_start).tolist(),
        strict=True,
    )
    accessors = ",".join(
        _PART_ACCESSORS % (index_at, corners, position_at, vertices, *lo, *hi, color_at, vertices)
        for index_at, corners, position_at, vertices, lo, hi, color_at in rows
    )
    meshes = ",".join(
        _PART_MESH % (name, 3 * part + 1, 3 * part + 2, 3 * part)
        for part, name in enumerate(node_names)
    )
    nodes = ",".join(_PART_NODE % (name, part) for part, name in enumerate(node_names))
    text = json.dumps(document, separators=(",", ":"))[:-1]  # without its closing brace
    text += f',"nodes":[{nodes}],"meshes":[{meshes}],"accessors":[{accessors}]}}'
    return glb_bytes(text, b"".join(blocks))


#: parts_glb's JSON per part (three accessors, a mesh, a node); names are part_name's.
_PART_ACCESSORS = (
    '{"bufferView":0,"byteOffset":%d,"componentType":5125,"count":%d,"type":"SCALAR"},'
    '{"bufferView":1,"byteOffset":%d,"componentType":5126,"count":%d,"type":"VEC3",'
    '"min":[%r,%r,%r],"max":[%r,%r,%r]},'
    '{"bufferView":2,"byteOffset":%d,"componentType":5121,"normalized":true,"count":%d,'
    '"type":"VEC4"}'
)
_PART_MESH = (
    '{"name":"%s","primitives":[{"attributes":{"POSITION":%d,"COLOR_0":%d},"indices":%d,"mode":4}]}'
)
_PART_NODE = '{"name":"%s","mesh":%d}'


def glb_bytes(document: str, binary: bytes) -> bytes:
    """A binary glTF: the JSON text ``document`` and one binary chunk (``binary``)."""
    text = document.encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    chunks = [struct.pack("<I4s", len(text), b"JSON"), text]
    if binary:
        chunks += [struct.pack("<I4s", len(binary), b"BIN\0"), binary]
    body = b"".join(chunks)
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def unwrapped_glb(mesh: TriangleMesh, atlas: UvAtlas, *, texture_png: bytes | None = None) -> bytes:
    """GLB of the mesh with its atlas UVs (TEXCOORD_0), triangles in the mesh's order.

    Vertices are split where a seam gives one position two UVs. ``texture_png`` becomes the
    material's base colour texture (e.g. ``unwrap.atlas_layout_png(atlas)``).
    """
    vertices, faces, uvs = uv_split_vertices(mesh, atlas)
    image = _EncodedImage(texture_png) if texture_png else None
    material = trimesh.visual.material.PBRMaterial(
        baseColorTexture=image, metallicFactor=0.0, roughnessFactor=0.9
    )
    visual = trimesh.visual.TextureVisuals(uv=uvs, material=material)
    out = trimesh.Trimesh(vertices, faces, visual=visual, process=False)
    return out.export(file_type="glb")


class _EncodedImage:
    """An encoded PNG that trimesh's glTF writer embeds as it is: it only reads ``format``
    and calls ``save``, so the picture is never decoded into memory and re-encoded."""

    format = "PNG"

    def __init__(self, data: bytes) -> None:
        self.data = data

    def save(self, file: Any, format: str | None = None, **_: Any) -> None:  # noqa: A002
        file.write(self.data)


def uv_split_vertices(
    mesh: TriangleMesh, atlas: UvAtlas
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """``(vertices, faces, uvs)`` with one vertex per distinct (position, UV) corner:
    triangles in the mesh's order, ``uvs[i]`` the UV of ``vertices[i]``."""
    corners = mesh.faces.reshape(-1)
    uv = np.asarray(atlas.corner_uvs, dtype=np.float64).reshape(-1, 2)
    keys = np.column_stack([corners.astype(np.float64), uv])
    unique, inverse = unique_rows(keys, return_inverse=True)
    vertex = unique[:, 0].astype(np.int64)
    return mesh.vertices[vertex], inverse.reshape(-1, 3).astype(np.int64), unique[:, 1:]
