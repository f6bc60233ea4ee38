"""Write segmentation results as binary glTF: one colour per part, one node per part, or the
mesh with its atlas UVs."""

from __future__ import annotations

import json
import struct
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.arrays import unique_rows
from neural_shdf.errors import ParameterError
from neural_shdf.exchange.attributes import FaceGroup, Materials, SceneObject, SurfaceAttributes
from neural_shdf.mesh import TriangleMesh
from neural_shdf.palette import UNLABELED_COLOR, linear_color_bytes, part_colors

if TYPE_CHECKING:  # the unwrapper is imported where UVs are written, not by every reader
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
    import trimesh  # its import (~0.3 s) only where a GLB is written, not for every CLI run

    out = trimesh.Trimesh(vertices, faces, vertex_colors=vertex_colors, process=False)
    return out.export(file_type="glb")


def part_name(label: int) -> str:
    """Node and mesh name of a part in parts_glb: ``part_000``, ..., or ``unlabeled``."""
    return f"part_{label:03d}" if label >= 0 else "unlabeled"


def parts_glb(
    mesh: TriangleMesh,
    labels: NDArray,
    *,
    attributes: SurfaceAttributes | None = None,
    names: Mapping[int, str] | None = None,
) -> bytes:
    """GLB scene with one node and mesh per part, named by ``names`` (label -> name;
    part_name for labels it does not name), in label order.

    Each part keeps its triangles in the mesh's order and only the vertices they use
    (in vertex order). ``attributes`` (``mesh_io.load_source``): the parts keep the
    file's normals, tangents, UV sets, vertex colours and materials, one primitive per
    face group (a glTF primitive, an OBJ material); and when the file has scene objects,
    one node per object (its name and world transform, positions in its own space),
    the parts of that object under it, objects in the file's face order.

    COLOR_0 (linear, as glTF defines it): the file's own colours where it has them,
    else the part colour (sRGB palette converted, as in colored_glb) on faces without a
    material of the file's. Written directly from numpy buffers (one buffer view per
    kind of data, shared by every part), so time and memory are linear in the faces and
    the parts, however many parts there are.
    """
    labels = _check_labels(mesh, labels)
    if attributes is None:
        attributes = _plain_attributes(mesh)
    else:
        attributes.check(mesh)
    groups = attributes.groups
    group_object = np.array([g.object for g in groups], dtype=np.int64)
    objects = attributes.objects if (group_object >= 0).any() else ()
    # An object whose transform flattens it (a zero scale) keeps its world positions
    # under an untransformed node: its own space cannot be recovered.
    objects = tuple(
        o if abs(np.linalg.det(o.matrix)) > 1e-300 else SceneObject(o.name, np.eye(4))
        for o in objects
    )
    # One output primitive per (object, label, group), in that order (a group lies in one
    # object); sorted by keys, not one combined integer that many objects could overflow.
    triangle_object = (
        np.maximum(group_object[attributes.face_group], 0)
        if objects
        else np.zeros(len(labels), dtype=np.int64)
    )
    order = np.lexsort((attributes.face_group, labels, triangle_object))
    sorted_label, sorted_group = labels[order], attributes.face_group[order]
    starts = np.ones(len(order), dtype=bool)
    starts[1:] = (sorted_label[1:] != sorted_label[:-1]) | (sorted_group[1:] != sorted_group[:-1])
    face_start = np.flatnonzero(starts)
    face_count = np.diff(np.append(face_start, len(order)))
    primitive_group = sorted_group[face_start]
    primitive_label = sorted_label[face_start]
    primitive_object = triangle_object[order][face_start]
    count = len(face_start)

    # Vertices: one per (primitive, attribute vertex), primitive by primitive.
    corner_primitive = np.repeat(np.arange(count), 3 * face_count)
    key_total = max(len(attributes.vertex), 1)
    corner_keys = corner_primitive * key_total + attributes.corners[order].reshape(-1)
    used, corner_vertex = np.unique(corner_keys, return_inverse=True)
    vertex_primitive = used // key_total
    attribute_vertex = used % key_total
    vertex_start = np.searchsorted(vertex_primitive, np.arange(count))
    vertex_count = np.diff(np.append(vertex_start, len(used)))
    triangles = (corner_vertex.reshape(-1) - vertex_start[corner_primitive]).reshape(-1, 3)
    positions = mesh.vertices[attributes.vertex[attribute_vertex]]
    if objects:
        positions, triangles = _object_space(
            positions, triangles, objects, primitive_object, vertex_start, face_start
        )
    indices = triangles.reshape(-1).astype("<u4")
    positions = positions.astype("<f4")

    own_material = np.array(
        [g.material >= 0 and attributes.materials.defined for g in groups], dtype=bool
    )
    part_colored = ~np.array([g.colors for g in groups], dtype=bool) & ~own_material
    uses_part_color = part_colored[primitive_group]
    label_values = np.unique(primitive_label)
    palette = linear_color_bytes(_label_colors(label_values))
    part_colors = palette[np.searchsorted(label_values, primitive_label)][vertex_primitive]

    builder = _GlbBuilder()
    index_view = builder.view(indices.tobytes(), target=34963)
    position_view = builder.view(positions.tobytes(), stride=12, target=34962)
    views: dict[str, tuple[int, int, str]] = {}  # name -> (view, element bytes, accessor text)

    def add_view(name: str, values: NDArray, template: str) -> None:
        data = np.ascontiguousarray(values)
        element = data.itemsize * (data.shape[1] if data.ndim > 1 else 1)
        views[name] = (
            builder.view(data.tobytes(), stride=element, target=34962),
            element,
            template,
        )

    flag = {
        "NORMAL": [g.normals for g in groups],
        "TANGENT": [g.tangents for g in groups],
        "COLOR_0": [g.colors for g in groups],
    }
    used_groups = set(primitive_group.tolist())
    if attributes.normals is not None and any(flag["NORMAL"][g] for g in used_groups):
        add_view("NORMAL", attributes.normals[attribute_vertex].astype("<f4"), _VEC3_FLOAT)
    if attributes.tangents is not None and any(flag["TANGENT"][g] for g in used_groups):
        add_view("TANGENT", attributes.tangents[attribute_vertex].astype("<f4"), _VEC4_FLOAT)
    for k, uv in enumerate(attributes.uvs):
        if any(groups[g].uv_sets > k for g in used_groups):
            add_view(f"TEXCOORD_{k}", uv[attribute_vertex].astype("<f4"), _VEC2_FLOAT)
    if attributes.colors is not None and any(flag["COLOR_0"][g] for g in used_groups):
        add_view("COLOR_0", attributes.colors[attribute_vertex].astype("<f4"), _VEC4_FLOAT)
    if uses_part_color.any():
        add_view("PART_COLOR", part_colors, _VEC4_BYTE)

    if count:
        low_corner = np.minimum.reduceat(positions, vertex_start).tolist()
        high_corner = np.maximum.reduceat(positions, vertex_start).tolist()
    else:
        low_corner = high_corner = []
    # Per-primitive entries as text from templates: json.dumps of a dict per accessor
    # would take most of the time with many parts.
    # Each group's attributes other than POSITION: (glTF name, view, element bytes, template).
    layouts = []
    for group, part_color in zip(groups, part_colored.tolist(), strict=True):
        wanted = [
            ("NORMAL", group.normals),
            ("TANGENT", group.tangents),
            *((f"TEXCOORD_{k}", True) for k in range(group.uv_sets)),
            ("COLOR_0", group.colors),
            ("PART_COLOR", part_color),
        ]
        layout = [
            ("COLOR_0" if name == "PART_COLOR" else name, *views[name])
            for name, present in wanted
            if present and name in views
        ]
        material = f',"material":{group.material}' if group.material >= 0 else ""
        layouts.append((layout, material))
    accessors: list[str] = []
    primitives: list[str] = []
    rows = zip(
        primitive_group.tolist(), (12 * face_start).tolist(), (3 * face_count).tolist(),
        vertex_start.tolist(), vertex_count.tolist(), low_corner, high_corner, strict=True,
    )  # fmt: skip
    for group_index, index_at, corners, first, vertices, lo, hi in rows:
        layout, material = layouts[group_index]
        base = len(accessors)
        accessors.append(_INDEX_ACCESSOR % (index_view, index_at, corners))
        accessors.append(_POSITION_ACCESSOR % (position_view, 12 * first, vertices, *lo, *hi))
        attribute_text = f'"POSITION":{base + 1}'
        for number, (name, view, element, template) in enumerate(layout, start=base + 2):
            attribute_text += f',"{name}":{number}'
            accessors.append(template % (view, element * first, vertices))
        primitives.append(
            f'{{"attributes":{{{attribute_text}}},"indices":{base},"mode":4{material}}}'
        )

    # Meshes: one per (object, label), its primitives in group order; nodes likewise.
    new_mesh = np.ones(count, dtype=bool)
    new_mesh[1:] = (primitive_label[1:] != primitive_label[:-1]) | (
        primitive_object[1:] != primitive_object[:-1]
    )
    mesh_first = np.flatnonzero(new_mesh).tolist() + [count]
    part_names = [
        _quoted((names or {}).get(label, part_name(label)))
        for label in primitive_label[mesh_first[:-1]].tolist()
    ]
    meshes = [
        f'{{"name":{name},"primitives":[{",".join(primitives[a:b])}]}}'
        for name, a, b in zip(part_names, mesh_first[:-1], mesh_first[1:], strict=True)
    ]
    nodes = [_PART_NODE % (name, m) for m, name in enumerate(part_names)]
    if objects:
        roots = []
        mesh_object = primitive_object[mesh_first[:-1]]  # meshes come object by object
        first_mesh = np.flatnonzero(np.r_[True, mesh_object[1:] != mesh_object[:-1]])
        ends = np.append(first_mesh[1:], len(mesh_object)).tolist()
        for start, end in zip(first_mesh.tolist(), ends, strict=True):
            roots.append(len(nodes))
            children = list(range(start, end))
            nodes.append(_object_node(objects[int(mesh_object[start])], children))
    else:
        roots = list(range(len(nodes)))

    document: dict[str, Any] = {
        "asset": {"version": "2.0", "generator": "neural-shdf"},
        "scene": 0,
        "scenes": [{"nodes": roots} if roots else {}],
    }
    if not count:  # glTF allows no empty arrays
        return glb_bytes(json.dumps(document, separators=(",", ":")), b"")
    material_json = _materials_json(attributes.materials, builder, used_groups, groups)
    document.update(material_json)
    document["bufferViews"] = builder.views
    document["buffers"] = [{"byteLength": builder.length}]
    text = json.dumps(document, separators=(",", ":"))[:-1]  # without its closing brace
    text += (
        f',"nodes":[{",".join(nodes)}],"meshes":[{",".join(meshes)}],'
        f'"accessors":[{",".join(accessors)}]}}'
    )
    return glb_bytes(text, builder.binary())


def _quoted(name: str) -> str:
    """A name as JSON text (part_name's names need no escaping: no json.dumps per part)."""
    return f'"{name}"' if name.isascii() and name.replace("_", "").isalnum() else json.dumps(name)


def _plain_attributes(mesh: TriangleMesh) -> SurfaceAttributes:
    """No attributes: one group, no object, part colours."""
    return SurfaceAttributes(
        corners=mesh.faces,
        vertex=np.arange(len(mesh.vertices), dtype=np.int64),
        face_group=np.zeros(mesh.face_count, dtype=np.int64),
        groups=(FaceGroup(),),
    )


def _object_space(
    positions: NDArray,
    triangles: NDArray,
    objects: tuple[SceneObject, ...],
    primitive_object: NDArray,
    vertex_start: NDArray,
    face_start: NDArray,
) -> tuple[NDArray, NDArray]:
    """Positions in the space of their primitive's object (primitives come object by
    object, so each object's vertices and triangles are one slice), and under a mirroring
    object the file's own winding back (the reader reversed it)."""
    positions = positions.copy()
    triangles = triangles.copy()
    vertex_end = np.append(vertex_start[1:], len(positions))
    face_end = np.append(face_start[1:], len(triangles))
    first = np.flatnonzero(np.r_[True, primitive_object[1:] != primitive_object[:-1]])
    last = np.r_[first[1:], len(primitive_object)] - 1
    for start, stop in zip(first.tolist(), last.tolist(), strict=True):
        matrix = objects[int(primitive_object[start])].matrix
        vertices = slice(vertex_start[start], vertex_end[stop])
        if not np.array_equal(matrix, np.eye(4)):
            inverse = np.linalg.inv(matrix)
            positions[vertices] = positions[vertices] @ inverse[:3, :3].T + inverse[:3, 3]
        if np.linalg.det(matrix[:3, :3]) < 0:
            faces = slice(face_start[start], face_end[stop])
            triangles[faces] = triangles[faces][:, [0, 2, 1]]
    return positions, triangles


def _object_node(scene_object: SceneObject, children: list[int]) -> str:
    node: dict[str, Any] = {"name": scene_object.name, "children": children}
    if not scene_object.name:
        del node["name"]
    if not np.array_equal(scene_object.matrix, np.eye(4)):
        node["matrix"] = scene_object.matrix.T.reshape(-1).tolist()  # column-major
    return json.dumps(node, separators=(",", ":"))


def _materials_json(
    materials: Materials, builder: _GlbBuilder, used_groups: set[int], groups: tuple
) -> dict[str, Any]:
    """The file's materials, textures, samplers and images (embedded in the binary
    chunk), when a written primitive uses a material."""
    if not materials.materials or all(groups[g].material < 0 for g in used_groups):
        return {}
    out: dict[str, Any] = {"materials": [dict(m) for m in materials.materials]}
    images = []
    for image, data in zip(materials.images, materials.image_data, strict=True):
        image = dict(image)
        if data is not None:
            image["bufferView"] = builder.view(data)
            image.setdefault("mimeType", _image_mime_type(data))
        images.append(image)
    for key, values in (("textures", materials.textures), ("samplers", materials.samplers),
                        ("images", images)):  # fmt: skip
        if values:
            out[key] = list(values)
    if materials.extensions:
        out["extensionsUsed"] = list(materials.extensions)
    if materials.required:
        out["extensionsRequired"] = list(materials.required)
    return out


def _image_mime_type(data: bytes) -> str:
    if data.startswith(b"\xff\xd8"):
        return "image/jpeg"
    if data[8:12] == b"WEBP":
        return "image/webp"
    return "image/png"


class _GlbBuilder:
    """The binary chunk of a GLB, one bufferView per block (4-byte aligned)."""

    def __init__(self) -> None:
        self.blocks: list[bytes] = []
        self.views: list[dict[str, int]] = []
        self.length = 0

    def view(self, data: bytes, *, stride: int = 0, target: int = 0) -> int:
        view = {"buffer": 0, "byteOffset": self.length, "byteLength": len(data)}
        if stride:
            view["byteStride"] = stride
        if target:
            view["target"] = target
        self.blocks.append(data)
        self.blocks.append(b"\0" * (-len(data) % 4))
        self.length += len(data) + len(self.blocks[-1])
        self.views.append(view)
        return len(self.views) - 1

    def binary(self) -> bytes:
        return b"".join(self.blocks)


#: parts_glb's JSON per primitive and node; names are part_name's unless given.
_INDEX_ACCESSOR = (
    '{"bufferView":%d,"byteOffset":%d,"componentType":5125,"count":%d,"type":"SCALAR"}'
)
_POSITION_ACCESSOR = (
    '{"bufferView":%d,"byteOffset":%d,"componentType":5126,"count":%d,"type":"VEC3",'
    '"min":[%r,%r,%r],"max":[%r,%r,%r]}'
)
_VEC2_FLOAT = '{"bufferView":%d,"byteOffset":%d,"componentType":5126,"count":%d,"type":"VEC2"}'
_VEC3_FLOAT = '{"bufferView":%d,"byteOffset":%d,"componentType":5126,"count":%d,"type":"VEC3"}'
_VEC4_FLOAT = '{"bufferView":%d,"byteOffset":%d,"componentType":5126,"count":%d,"type":"VEC4"}'
_VEC4_BYTE = (
    '{"bufferView":%d,"byteOffset":%d,"componentType":5121,"normalized":true,"count":%d,'
    '"type":"VEC4"}'
)
_PART_NODE = '{"name":%s,"mesh":%d}'


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
    import trimesh  # as in colored_glb

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
