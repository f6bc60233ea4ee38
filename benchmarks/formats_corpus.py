"""Corpus of real-world mesh file flavours, read by load_mesh and checked against the truth.

Generates every file in memory (OBJ, OFF, PLY, STL, glTF/GLB flavours, Draco, meshopt,
sparse, BOMs, header lies; USD stages and an FBX header), reads each through
``neural_shdf.mesh_io.load_mesh`` (and ``load_source``, which must read the same mesh
beside the file's attributes) and through an independent reader (trimesh; DracoPy
for Draco; none for USD, checked against the generator alone), and prints one row per file:
the expected outcome, ours (triangles, input faces, area and bounds against the
generator's own geometry, or the refusal message), the independent reader's, and a
verdict. ``MISREAD`` (a file read to the wrong geometry or face count) is what must
never happen; ``REFUSED`` marks a good file we refuse.

The meshopt rows use the reference encoders' files in ``tests/exchange/data`` (gltfpack,
gltf-transform). ``--draco-faces N`` also times a Draco GLB of about N faces against the
same mesh uncompressed (0 to skip).

    PYTHONPATH=service python benchmarks/formats_corpus.py [--draco-faces 1000000]
"""

from __future__ import annotations

import argparse
import base64
import io
import json
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from neural_shdf.errors import MeshError
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh, load_source

DATA = Path(__file__).resolve().parents[1] / "tests" / "exchange" / "data"
BOM = b"\xef\xbb\xbf"


@dataclass
class Truth:
    """World-space triangles a file must read to, and its input face count."""

    vertices: np.ndarray
    faces: np.ndarray
    input_faces: int
    origin: np.ndarray | None = None  # input face of each triangle, when not 1:1

    @property
    def area(self) -> float:
        return _area(self.vertices, self.faces)


@dataclass
class Case:
    name: str
    file_type: str
    data: bytes
    truth: Truth | None  # None: the file must be refused
    independent: Callable[[], tuple[np.ndarray, np.ndarray]] | None = None
    tolerance: float = 1e-6  # relative, for quantized encodings
    notes: list[str] = field(default_factory=list)


def _area(vertices: np.ndarray, faces: np.ndarray) -> float:
    tri = vertices[faces]
    return float(
        np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum() / 2
    )


def _bounds(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    used = vertices[np.unique(faces)]
    return np.stack([used.min(axis=0), used.max(axis=0)])


def _sphere(subdivisions: int = 1) -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions)


def _soup_truth(mesh: trimesh.Trimesh) -> Truth:
    return Truth(np.asarray(mesh.vertices, float), np.asarray(mesh.faces), len(mesh.faces))


def _trimesh_reader(data: bytes, file_type: str) -> Callable[[], tuple[np.ndarray, np.ndarray]]:
    def read() -> tuple[np.ndarray, np.ndarray]:
        loaded = trimesh.load(io.BytesIO(data), file_type=file_type, force="mesh", process=False)
        return np.asarray(loaded.vertices, float), np.asarray(loaded.faces)

    return read


# --- text formats ---------------------------------------------------------------------


def _obj_text(mesh: trimesh.Trimesh, *, faces: list[str] | None = None) -> str:
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in mesh.vertices]
    lines += (
        faces if faces is not None else [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    )
    return "\n".join(lines) + "\n"


def _text_cases() -> list[Case]:
    sphere = _sphere()
    truth = _soup_truth(sphere)
    cases: list[Case] = []

    def add(name: str, file_type: str, data: bytes, case_truth: Truth | None, **kw) -> None:
        cases.append(
            Case(name, file_type, data, case_truth, _trimesh_reader(data, file_type), **kw)
        )

    obj = _obj_text(sphere).encode()
    add("obj_bom_vertex_line1", "obj", BOM + obj, truth)
    spare = _obj_text(sphere).replace("\nf ", "\nv 9 9 9\nf ", 1)  # one unused vertex
    add(
        "obj_bom_vertex_line1_spare_vertex",
        "obj",
        BOM + spare.encode(),
        Truth(np.vstack([truth.vertices, [[9, 9, 9]]]), truth.faces, truth.input_faces),
    )
    add("obj_crlf", "obj", obj.replace(b"\n", b"\r\n"), truth)
    commented = _obj_text(
        sphere,
        faces=[f"f {a + 1} {b + 1} {c + 1} # face {i}" for i, (a, b, c) in enumerate(sphere.faces)],
    )
    add("obj_comment_after_f", "obj", commented.encode(), truth)
    # f 1 / f 2 3: input faces without a triangle keep their place.
    records = [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in sphere.faces]
    records.insert(5, "f 1")
    records.insert(9, "f 2 3")
    origin = np.delete(np.arange(len(records)), [5, 9])
    add(
        "obj_point_and_edge_records",
        "obj",
        _obj_text(sphere, faces=records).encode(),
        Truth(truth.vertices, truth.faces, len(records), origin),
    )
    negative = "".join(
        f"v {x:.17g} {y:.17g} {z:.17g}\n" + ("f -3 -2 -1\n" if i % 3 == 2 else "")
        for i, (x, y, z) in enumerate(sphere.vertices[sphere.faces].reshape(-1, 3))
    )
    add(
        "obj_negative_indices",
        "obj",
        negative.encode(),
        _soup_truth(
            trimesh.Trimesh(
                sphere.vertices[sphere.faces].reshape(-1, 3),
                np.arange(3 * len(sphere.faces)).reshape(-1, 3),
                process=False,
            )
        ),
    )
    box = trimesh.creation.box()
    quads = (
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0.5 0\nv 0.5 2 0\n"
        "f 1 2 3 4\nf 2 5 3\nf 1 2 5 3 6 4\n"
    )
    quad_truth = Truth(
        np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0.5, 0], [0.5, 2, 0]], float),
        np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2], [0, 1, 4], [0, 4, 2], [0, 2, 5], [0, 5, 3]]),
        3,
        np.array([0, 0, 1, 2, 2, 2, 2]),
    )
    add("obj_quads_ngons", "obj", quads.encode(), quad_truth)
    coloured = "".join(f"v {x:.17g} {y:.17g} {z:.17g} 0.5 0.25 1\n" for x, y, z in box.vertices)
    coloured += "vt 0 0\nvn 0 0 1\n" + "".join(
        f"f {a + 1}/1/1 {b + 1}/1/1 {c + 1}/1/1\n" for a, b, c in box.faces
    )
    add("obj_vertex_colours_vt_vn", "obj", coloured.encode(), _soup_truth(box))
    add("obj_index_out_of_range", "obj", (_obj_text(box) + "f 1 2 99\n").encode(), None)
    add("obj_comma_decimal", "obj", b"v 0,5 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", None)

    off = "OFF\n" + f"{len(sphere.vertices)} {len(sphere.faces)} 0\n"
    off += "".join(f"{x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in sphere.vertices)
    off += "".join(f"3 {a} {b} {c}\n" for a, b, c in sphere.faces)
    add("off_bom", "off", BOM + off.encode(), truth)
    off_short = (
        off.replace(f"{len(sphere.faces)} 0\n", f"{len(sphere.faces) + 1} 0\n", 1) + "2 0 1\n"
    )
    add(
        "off_edge_record",
        "off",
        off_short.encode(),
        Truth(truth.vertices, truth.faces, len(sphere.faces) + 1),
    )
    add("off_truncated", "off", off.encode()[: len(off) // 2], None)

    # PLY: extra vertex properties, a face property, big endian, mixed polygons.
    vertex = np.zeros(
        len(box.vertices),
        dtype=[
            ("x", ">f4"),
            ("y", ">f4"),
            ("z", ">f4"),
            ("nx", ">f4"),
            ("ny", ">f4"),
            ("nz", ">f4"),
            ("red", "u1"),
            ("green", "u1"),
            ("blue", "u1"),
            ("quality", ">f8"),
        ],
    )
    for axis, column in zip("xyz", box.vertices.T, strict=True):
        vertex[axis] = column
    face = np.zeros(
        len(box.faces),
        dtype=[("flags", ">i4"), ("n", "u1"), ("idx", ">i4", (3,)), ("material", "u1")],
    )
    face["n"], face["idx"] = 3, box.faces
    header = (
        "ply\nformat binary_big_endian 1.0\ncomment made by formats_corpus\n"
        f"element vertex {len(vertex)}\nproperty float x\nproperty float y\nproperty float z\n"
        "property float nx\nproperty float ny\nproperty float nz\nproperty uchar red\n"
        "property uchar green\nproperty uchar blue\nproperty double quality\n"
        f"element face {len(face)}\nproperty int flags\nproperty list uchar int vertex_indices\n"
        "property uchar material\nend_header\n"
    )
    big = header.encode() + vertex.tobytes() + face.tobytes()
    add("ply_big_endian_extra_properties", "ply", big, _soup_truth(box))
    little = (
        header.replace("big", "little").encode()
        + vertex.astype(vertex.dtype.newbyteorder("<")).tobytes()
        + face.astype(face.dtype.newbyteorder("<")).tobytes()
    )
    add("ply_little_endian_extra_properties", "ply", little, _soup_truth(box))
    ply_ascii = (
        "ply\r\nformat ascii 1.0\r\nelement vertex 6\r\nproperty float x\r\nproperty float y\r\n"
        "property float z\r\nelement face 3\r\nproperty list uchar int vertex_indices\r\n"
        "end_header\r\n0 0 0\r\n1 0 0\r\n1 1 0\r\n0 1 0\r\n2 0.5 0\r\n0.5 2 0\r\n"
        "4 0 1 2 3\r\n3 1 4 2\r\n6 0 1 4 2 5 3\r\n"
    )
    add("ply_ascii_crlf_mixed_polygons", "ply", ply_ascii.encode(), quad_truth)

    stl_soup = trimesh.Trimesh(
        sphere.vertices[sphere.faces].reshape(-1, 3),
        np.arange(3 * len(sphere.faces)).reshape(-1, 3),
        process=False,
    )
    stl_truth = _soup_truth(stl_soup)
    binary = sphere.export(file_type="stl")
    half = bytearray(binary)
    half[80:84] = struct.pack("<I", len(sphere.faces) // 2)
    add("stl_binary_header_count_half", "stl", bytes(half), stl_truth)
    zero = bytearray(binary)
    zero[80:84] = struct.pack("<I", 0)
    add("stl_binary_header_count_zero", "stl", bytes(zero), stl_truth)
    add("stl_binary_70_bytes_extra", "stl", bytes(half) + bytes(20), None)
    add(
        "stl_binary_solid_header", "stl", b"solid exported".ljust(80, b" ") + binary[80:], stl_truth
    )
    ascii_stl = sphere.export(file_type="stl_ascii")
    odd = (
        ascii_stl.replace("facet normal", "  FACET\tNORMAL")
        .replace("vertex", "\tVERTEX  ")
        .replace("\n", "\r\n")
    )
    add("stl_ascii_odd_whitespace", "stl", BOM + odd.encode(), stl_truth)
    return cases


# --- glTF -----------------------------------------------------------------------------


class _Gltf:
    """A small glTF writer: one buffer, one bufferView per accessor."""

    def __init__(self) -> None:
        self.blob = bytearray()
        self.doc: dict = {
            "asset": {"version": "2.0"},
            "accessors": [],
            "bufferViews": [],
            "meshes": [],
            "nodes": [],
            "scenes": [{"nodes": []}],
            "scene": 0,
        }

    def view(self, payload: bytes) -> int:
        while len(self.blob) % 4:
            self.blob += b"\x00"
        self.doc["bufferViews"].append(
            {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(payload)}
        )
        self.blob += payload
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, array: np.ndarray, kind: str, component: int, **extra) -> int:
        count = len(array)
        spec = {
            "bufferView": self.view(np.ascontiguousarray(array).tobytes()),
            "componentType": component,
            "type": kind,
            "count": count,
            **extra,
        }
        if kind == "VEC3" and component == 5126:
            spec["min"], spec["max"] = array.min(axis=0).tolist(), array.max(axis=0).tolist()
        self.doc["accessors"].append(spec)
        return len(self.doc["accessors"]) - 1

    def mesh(self, primitives: list[dict]) -> int:
        self.doc["meshes"].append({"primitives": primitives})
        return len(self.doc["meshes"]) - 1

    def node(self, mesh: int | None = None, root: bool = True, **transform) -> int:
        node = dict(transform)
        if mesh is not None:
            node["mesh"] = mesh
        self.doc["nodes"].append(node)
        index = len(self.doc["nodes"]) - 1
        if root:
            self.doc["scenes"][0]["nodes"].append(index)
        return index

    def glb(self) -> bytes:
        self.doc["buffers"] = [{"byteLength": len(self.blob)}]
        text = json.dumps(self.doc).encode()
        text += b" " * (-len(text) % 4)
        blob = bytes(self.blob) + b"\x00" * (-len(self.blob) % 4)
        body = (
            struct.pack("<II", len(text), 0x4E4F534A)
            + text
            + struct.pack("<II", len(blob), 0x004E4942)
            + blob
        )
        return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body

    def gltf(self) -> bytes:
        uri = "data:application/octet-stream;base64," + base64.b64encode(bytes(self.blob)).decode()
        self.doc["buffers"] = [{"byteLength": len(self.blob), "uri": uri}]
        return json.dumps(self.doc).encode()


def _positions(builder: _Gltf, vertices: np.ndarray) -> int:
    return builder.accessor(vertices.astype(np.float32), "VEC3", 5126)


def _indices(builder: _Gltf, flat: np.ndarray, dtype: type) -> int:
    component = {np.uint8: 5121, np.uint16: 5123, np.uint32: 5125}[dtype]
    return builder.accessor(flat.astype(dtype), "SCALAR", component)


def _transform(vertices: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return vertices @ matrix[:3, :3].T + matrix[:3, 3]


def _flip_if_mirrored(faces: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    return faces[:, [0, 2, 1]] if np.linalg.det(matrix[:3, :3]) < 0 else faces


def draco_glb(mesh: trimesh.Trimesh, matrix: np.ndarray, *, required: bool) -> bytes:
    import DracoPy

    encoded = DracoPy.encode(
        mesh.vertices.astype(np.float32),
        mesh.faces.astype(np.uint32),
        quantization_bits=16,
        compression_level=1,
    )
    decoded = DracoPy.decode(encoded)
    builder = _Gltf()
    view = builder.view(encoded)
    builder.doc["accessors"] += [
        {"componentType": 5125, "type": "SCALAR", "count": 3 * len(decoded.faces)},
        {
            "componentType": 5126,
            "type": "VEC3",
            "count": len(decoded.points),
            "min": decoded.points.min(axis=0).tolist(),
            "max": decoded.points.max(axis=0).tolist(),
        },
    ]
    draco = {"bufferView": view, "attributes": {"POSITION": 0}}
    primitive = {
        "attributes": {"POSITION": 1},
        "indices": 0,
        "mode": 4,
        "extensions": {"KHR_draco_mesh_compression": draco},
    }
    builder.node(builder.mesh([primitive]), matrix=matrix.T.reshape(-1).tolist())
    builder.doc["extensionsUsed"] = ["KHR_draco_mesh_compression"]
    if required:
        builder.doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    return builder.glb()


def _draco_independent(
    data: bytes, matrix: np.ndarray
) -> Callable[[], tuple[np.ndarray, np.ndarray]]:
    def read() -> tuple[np.ndarray, np.ndarray]:
        import DracoPy

        length = struct.unpack_from("<I", data, 12)[0]
        doc = json.loads(data[20 : 20 + length])
        view = doc["bufferViews"][0]
        start = 20 + length + 8 + view["byteOffset"]
        decoded = DracoPy.decode(data[start : start + view["byteLength"]])
        faces = np.asarray(decoded.faces, dtype=np.int64)
        return _transform(np.asarray(decoded.points, float), matrix), _flip_if_mirrored(
            faces, matrix
        )

    return read


def _gltf_cases() -> list[Case]:
    sphere = _sphere(2)
    cases: list[Case] = []
    shift = np.eye(4)
    shift[:3, 3] = [2, 0, 1]
    sphere_truth = Truth(
        _transform(sphere.vertices, shift), np.asarray(sphere.faces), len(sphere.faces)
    )

    for required in (True, False):
        data = draco_glb(sphere, shift, required=required)
        name = "glb_draco_required" if required else "glb_draco_only_in_extensionsUsed"
        cases.append(
            Case(name, "glb", data, sphere_truth, _draco_independent(data, shift), tolerance=1e-4)
        )

    reference = DATA / "scene.glb"
    if reference.is_file():
        loaded = trimesh.load(reference, force="mesh", process=False)
        scene_truth = Truth(
            np.asarray(loaded.vertices, float), np.asarray(loaded.faces), len(loaded.faces)
        )
        for name, tolerance in (
            ("scene_draco.glb", 1e-3),
            ("scene_gltfpack_meshopt.glb", 1e-3),
            ("scene_gltf_transform_meshopt.glb", 1e-3),
        ):
            data = (DATA / name).read_bytes()
            independent = _trimesh_reader(data, "glb") if "draco" not in name else None
            cases.append(
                Case(
                    "ref_" + name.removesuffix(".glb"),
                    "glb",
                    data,
                    scene_truth,
                    independent,
                    tolerance=tolerance,
                )
            )
        plain = reference.read_bytes()
        cases.append(
            Case("ref_scene_trimesh", "glb", plain, scene_truth, _trimesh_reader(plain, "glb"))
        )

    def simple(
        name: str,
        builder: _Gltf,
        truth: Truth | None,
        *,
        text: bool = False,
        prefix: bytes = b"",
        tolerance: float = 1e-6,
    ) -> None:
        data = prefix + (builder.gltf() if text else builder.glb())
        file_type = "gltf" if text else "glb"
        cases.append(
            Case(
                name, file_type, data, truth, _trimesh_reader(data, file_type), tolerance=tolerance
            )
        )

    box = trimesh.creation.box()
    box_truth = _soup_truth(box)
    for name, text, prefix in (("gltf_data_uri", True, b""), ("gltf_bom", True, BOM)):
        builder = _Gltf()
        builder.node(
            builder.mesh(
                [
                    {
                        "attributes": {"POSITION": _positions(builder, box.vertices)},
                        "indices": _indices(builder, box.faces.reshape(-1), np.uint32),
                    }
                ]
            )
        )
        simple(name, builder, box_truth, text=text, prefix=prefix)
    for dtype in (np.uint8, np.uint16):
        builder = _Gltf()
        builder.node(
            builder.mesh(
                [
                    {
                        "attributes": {"POSITION": _positions(builder, box.vertices)},
                        "indices": _indices(builder, box.faces.reshape(-1), dtype),
                    }
                ]
            )
        )
        simple(f"glb_{np.dtype(dtype).name}_indices", builder, box_truth)

    # Triangle strip and fan over a grid row / a disc.
    strip_vertices = np.array([[i // 2, i % 2, 0.1 * i] for i in range(8)], float)
    strip_faces = np.array(
        [[i, i + 1, i + 2] if i % 2 == 0 else [i, i + 2, i + 1] for i in range(6)]
    )
    builder = _Gltf()
    builder.node(
        builder.mesh(
            [
                {
                    "attributes": {"POSITION": _positions(builder, strip_vertices)},
                    "indices": _indices(builder, np.arange(8), np.uint16),
                    "mode": 5,
                }
            ]
        )
    )
    simple("glb_triangle_strip", builder, Truth(strip_vertices, strip_faces, 6))
    angles = np.linspace(0, np.pi, 7)
    fan_vertices = np.concatenate(
        [[[0, 0, 0]], np.stack([np.cos(angles), np.sin(angles), 0 * angles], 1)]
    )
    fan_faces = np.array([[i, i + 1, 0] for i in range(1, 7)])
    builder = _Gltf()
    builder.node(
        builder.mesh([{"attributes": {"POSITION": _positions(builder, fan_vertices)}, "mode": 6}])
    )
    simple("glb_triangle_fan_non_indexed", builder, Truth(fan_vertices, fan_faces, 6))

    soup = box.vertices[box.faces].reshape(-1, 3)
    builder = _Gltf()
    builder.node(builder.mesh([{"attributes": {"POSITION": _positions(builder, soup)}}]))
    simple(
        "glb_non_indexed",
        builder,
        _soup_truth(trimesh.Trimesh(soup, np.arange(len(soup)).reshape(-1, 3), process=False)),
    )

    # KHR_mesh_quantization: normalized int16 positions, the node scales them back.
    quantized = np.round(box.vertices / 0.5 * 32767).astype(np.int16)
    builder = _Gltf()
    position = builder.accessor(quantized, "VEC3", 5122, normalized=True)
    builder.node(
        builder.mesh(
            [
                {
                    "attributes": {"POSITION": position},
                    "indices": _indices(builder, box.faces.reshape(-1), np.uint16),
                }
            ]
        ),
        scale=[0.5, 0.5, 0.5],
    )
    builder.doc["extensionsUsed"] = builder.doc["extensionsRequired"] = ["KHR_mesh_quantization"]
    simple("glb_khr_mesh_quantization", builder, box_truth, tolerance=1e-4)

    # Scene: one mesh instanced by three nodes (one mirrored by a matrix), a parent transform.
    builder = _Gltf()
    mesh = builder.mesh(
        [
            {
                "attributes": {"POSITION": _positions(builder, box.vertices)},
                "indices": _indices(builder, box.faces.reshape(-1), np.uint16),
            }
        ]
    )
    mirror = np.diag([-1.0, 1, 1, 1])
    mirror[:3, 3] = [3, 0, 0]
    child_a = builder.node(mesh, root=False, translation=[0, 2, 0])
    child_b = builder.node(mesh, root=False, matrix=mirror.T.reshape(-1).tolist())
    builder.node(mesh, children=[child_a, child_b], translation=[0, 0, 1])
    parent = np.eye(4)
    parent[2, 3] = 1
    worlds = [
        parent,
        parent @ trimesh.transformations.translation_matrix([0, 2, 0]),
        parent @ mirror,
    ]
    vertices = np.concatenate([_transform(box.vertices, m) for m in worlds])
    faces = np.concatenate([_flip_if_mirrored(box.faces, m) + 8 * i for i, m in enumerate(worlds)])
    simple("glb_instancing_negative_determinant", builder, Truth(vertices, faces, len(faces)))

    # Sparse accessor: the base positions are a flattened box, sparse values restore two corners.
    flattened = box.vertices.copy()
    targets = np.array([1, 6], dtype=np.uint16)
    flattened[targets] = 0
    builder = _Gltf()
    position = _positions(builder, flattened)
    builder.doc["accessors"][position]["sparse"] = {
        "count": 2,
        "indices": {"bufferView": builder.view(targets.tobytes()), "componentType": 5123},
        "values": {"bufferView": builder.view(box.vertices[targets].astype(np.float32).tobytes())},
    }
    builder.doc["accessors"][position]["min"] = box.vertices.min(axis=0).tolist()
    builder.doc["accessors"][position]["max"] = box.vertices.max(axis=0).tolist()
    builder.node(
        builder.mesh(
            [
                {
                    "attributes": {"POSITION": position},
                    "indices": _indices(builder, box.faces.reshape(-1), np.uint16),
                }
            ]
        )
    )
    simple("glb_sparse_accessor", builder, box_truth)

    # Sparse without a bufferView (all zeros, then substitutions), 3 triangles of a box.
    builder = _Gltf()
    builder.doc["accessors"].append(
        {
            "componentType": 5126,
            "type": "VEC3",
            "count": 8,
            "sparse": {
                "count": 8,
                "indices": {
                    "bufferView": builder.view(np.arange(8, dtype=np.uint8).tobytes()),
                    "componentType": 5121,
                },
                "values": {"bufferView": builder.view(box.vertices.astype(np.float32).tobytes())},
            },
            "min": box.vertices.min(axis=0).tolist(),
            "max": box.vertices.max(axis=0).tolist(),
        }
    )
    builder.node(
        builder.mesh(
            [
                {
                    "attributes": {"POSITION": 0},
                    "indices": _indices(builder, box.faces.reshape(-1), np.uint16),
                }
            ]
        )
    )
    simple("glb_sparse_without_bufferview", builder, box_truth)

    # EXT_mesh_gpu_instancing: three instances (translation, rotation, scale) under a moved
    # node; instance order, world = node @ T @ R @ S (no independent reader knows it).
    builder = _Gltf()
    mesh = builder.mesh(
        [
            {
                "attributes": {"POSITION": _positions(builder, box.vertices)},
                "indices": _indices(builder, box.faces.reshape(-1), np.uint16),
            }
        ]
    )
    turn = trimesh.transformations.quaternion_about_axis(np.pi / 3, [0, 0, 1])  # w, x, y, z
    instances = [
        trimesh.transformations.translation_matrix([0, 0, 0]),
        trimesh.transformations.translation_matrix([3, 0, 0])
        @ trimesh.transformations.quaternion_matrix(turn),
        trimesh.transformations.translation_matrix([0, 3, 0]) @ np.diag([2.0, 2, 2, 1]),
    ]
    gpu = {
        "TRANSLATION": builder.accessor(
            np.array([[0, 0, 0], [3, 0, 0], [0, 3, 0]], np.float32), "VEC3", 5126
        ),
        "ROTATION": builder.accessor(
            np.array([[0, 0, 0, 1], [*turn[1:], turn[0]], [0, 0, 0, 1]], np.float32), "VEC4", 5126
        ),
        "SCALE": builder.accessor(np.array([[1, 1, 1], [1, 1, 1], [2, 2, 2]], np.float32), "VEC3",
                                  5126),
    }  # fmt: skip
    builder.node(
        mesh,
        translation=[0, 0, 1],
        extensions={"EXT_mesh_gpu_instancing": {"attributes": gpu}},
    )
    builder.doc["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    node = trimesh.transformations.translation_matrix([0, 0, 1])
    vertices = np.concatenate([_transform(box.vertices, node @ m) for m in instances])
    faces = np.concatenate([box.faces + 8 * i for i in range(3)])
    data = builder.glb()
    cases.append(
        Case("glb_ext_mesh_gpu_instancing", "glb", data, Truth(vertices, faces, len(faces)), None,
             tolerance=1e-5)
    )  # fmt: skip

    # An artist's file: normals, UVs, colours, a textured material (embedded PNG) beside
    # the positions; the geometry reads the same, the attributes are kept (load_source).
    builder = _Gltf()
    soup = box.vertices[box.faces].reshape(-1, 3)
    normals = np.repeat(box.face_normals, 3, axis=0)
    uv = np.tile([[0, 0], [1, 0], [0, 1]], (len(box.faces), 1)).astype(np.float32)
    colors = np.tile([1.0, 0.5, 0.25, 1.0], (len(soup), 1)).astype(np.float32)
    png = io.BytesIO()
    from PIL import Image

    Image.new("RGB", (2, 2), (255, 0, 0)).save(png, format="PNG")
    builder.doc["images"] = [{"bufferView": builder.view(png.getvalue()), "mimeType": "image/png"}]
    builder.doc["textures"] = [{"source": 0}]
    builder.doc["materials"] = [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
    builder.node(
        builder.mesh(
            [
                {
                    "attributes": {
                        "POSITION": _positions(builder, soup),
                        "NORMAL": builder.accessor(normals.astype(np.float32), "VEC3", 5126),
                        "TEXCOORD_0": builder.accessor(uv, "VEC2", 5126),
                        "COLOR_0": builder.accessor(colors, "VEC4", 5126),
                    },
                    "material": 0,
                }
            ]
        )
    )
    simple(
        "glb_normals_uvs_colors_texture",
        builder,
        _soup_truth(trimesh.Trimesh(soup, np.arange(len(soup)).reshape(-1, 3), process=False)),
    )

    # Truncated GLB: must be refused.
    builder = _Gltf()
    builder.node(
        builder.mesh(
            [
                {
                    "attributes": {"POSITION": _positions(builder, box.vertices)},
                    "indices": _indices(builder, box.faces.reshape(-1), np.uint16),
                }
            ]
        )
    )
    cases.append(Case("glb_truncated", "glb", builder.glb()[:-40], None, None))
    return cases


# --- USD and FBX ----------------------------------------------------------------------


def _usd_cases() -> list[Case]:
    """USD stages written with usd-core (the truth: each polygon fanned in prim order, in
    world space); point instancers, outside layers, broken files and FBX are refused."""
    import tempfile

    from pxr import Gf, Sdf, Usd, UsdGeom, UsdUtils

    quad_box = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0],
                         [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)  # fmt: skip
    box_counts = [4, 4, 4, 4, 4, 4]
    box_flat = [0, 3, 2, 1, 4, 5, 6, 7, 0, 1, 5, 4, 1, 2, 6, 5, 2, 3, 7, 6, 3, 0, 4, 7]
    angle = 2 * np.pi * np.arange(7) / 7
    heptagon = np.stack([np.cos(angle), np.sin(angle), np.zeros(7)], axis=1)

    def fan(counts: list[int], flat: list[int]) -> np.ndarray:
        triangles, at = [], 0
        for count in counts:
            ring = flat[at : at + count]
            triangles += [[ring[0], ring[k], ring[k + 1]] for k in range(1, count - 1)]
            at += count
        return np.array(triangles).reshape(-1, 3)

    def define(stage, path: str, points, counts, flat):
        mesh = UsdGeom.Mesh.Define(stage, path)
        mesh.CreatePointsAttr([Gf.Vec3f(*p) for p in points])
        mesh.CreateFaceVertexCountsAttr(counts)
        mesh.CreateFaceVertexIndicesAttr(flat)
        return mesh

    cases: list[Case] = []
    with tempfile.TemporaryDirectory(prefix="corpus-usd-") as folder:
        root = Path(folder)

        def save(stage, name: str) -> bytes:
            stage.GetRootLayer().Save()
            return (root / name).read_bytes()

        # Two prims under transforms: a box of quads moved by (5, 0, 0), a heptagon scaled.
        stage = Usd.Stage.CreateNew(str(root / "scene.usda"))
        UsdGeom.Xform.Define(stage, "/World").AddTranslateOp().Set(Gf.Vec3d(5, 0, 0))
        define(stage, "/World/Box", quad_box, box_counts, box_flat)
        UsdGeom.Xform.Define(stage, "/Wide").AddScaleOp().Set(Gf.Vec3f(2, 3, 1))
        define(stage, "/Wide/Heptagon", heptagon, [7], list(range(7)))
        scene = save(stage, "scene.usda")
        vertices = np.concatenate([quad_box + [5, 0, 0], heptagon * [2, 3, 1]])
        faces = np.concatenate([fan(box_counts, box_flat), fan([7], list(range(7))) + 8])
        origin = np.concatenate([np.repeat(np.arange(6), 2), np.full(5, 6)])
        truth = Truth(vertices, faces, 7, origin)
        cases.append(Case("usda_two_prims_transforms", "usda", scene, truth))
        layer = Sdf.Layer.FindOrOpen(str(root / "scene.usda"))
        for name in ("scene.usdc", "scene_crate.usd"):
            layer.Export(str(root / name))
            kind = name.rsplit(".", 1)[1]
            cases.append(Case(f"{kind}_two_prims_crate", kind, (root / name).read_bytes(), truth))
        UsdUtils.CreateNewUsdzPackage(str(root / "scene.usdc"), str(root / "scene.usdz"))
        cases.append(Case("usdz_package", "usdz", (root / "scene.usdz").read_bytes(), truth))

        # Left-handed prim: the winding is reversed (first vertex kept), faces in order.
        stage = Usd.Stage.CreateNew(str(root / "left.usda"))
        define(stage, "/Box", quad_box, box_counts, box_flat).CreateOrientationAttr("leftHanded")
        reversed_flat = []
        for k in range(6):
            ring = box_flat[4 * k : 4 * k + 4]
            reversed_flat += [ring[0], *ring[:0:-1]]
        left = Truth(quad_box, fan(box_counts, reversed_flat), 6, np.repeat(np.arange(6), 2))
        cases.append(Case("usda_left_handed", "usda", save(stage, "left.usda"), left))

        # Two instances of one prototype, and a hole.
        stage = Usd.Stage.CreateNew(str(root / "instances.usda"))
        define(stage, "/Proto/Box", quad_box, box_counts, box_flat)
        stage.GetPrimAtPath("/Proto").SetSpecifier(Sdf.SpecifierClass)
        for i in range(2):
            copy = UsdGeom.Xform.Define(stage, f"/Copy{i}")
            copy.AddTranslateOp().Set(Gf.Vec3d(0, 3 * i, 0))
            copy.GetPrim().GetReferences().AddInternalReference("/Proto")
            copy.GetPrim().SetInstanceable(True)
        instanced = Truth(
            np.concatenate([quad_box, quad_box + [0, 3, 0]]),
            np.concatenate([fan(box_counts, box_flat), fan(box_counts, box_flat) + 8]),
            12,
            np.repeat(np.arange(12), 2),
        )
        cases.append(Case("usda_instances", "usda", save(stage, "instances.usda"), instanced))
        stage = Usd.Stage.CreateNew(str(root / "hole.usda"))
        define(stage, "/Box", quad_box, box_counts, box_flat).CreateHoleIndicesAttr([1])
        kept = np.r_[0:2, 4:12]
        holed_origin = np.repeat(np.arange(6), 2)[kept]
        holed = Truth(quad_box, fan(box_counts, box_flat)[kept], 6, holed_origin)
        cases.append(Case("usda_hole_index", "usda", save(stage, "hole.usda"), holed))

        # Refused: a point instancer, a layer from outside the upload, broken files.
        stage = Usd.Stage.CreateNew(str(root / "points.usda"))
        UsdGeom.PointInstancer.Define(stage, "/Scatter")
        define(stage, "/Scatter/Prototypes/Box", quad_box, box_counts, box_flat)
        cases.append(Case("usda_point_instancer", "usda", save(stage, "points.usda"), None))
        stage = Usd.Stage.CreateNew(str(root / "outside.usda"))
        stage.DefinePrim("/Ref").GetReferences().AddReference(str(root / "scene.usda"))
        cases.append(Case("usda_outside_reference", "usda", save(stage, "outside.usda"), None))
        usdc = (root / "scene.usdc").read_bytes()
        cases.append(Case("usdc_truncated", "usdc", usdc[: len(usdc) // 2], None))
        cases.append(Case("usdz_not_a_zip", "usdz", scene, None))
        stage = Usd.Stage.CreateNew(str(root / "lines.usda"))
        UsdGeom.BasisCurves.Define(stage, "/Curves")
        cases.append(Case("usda_no_mesh", "usda", save(stage, "lines.usda"), None))
    fbx = b"Kaydara FBX Binary  \x00\x1a\x00" + (7400).to_bytes(4, "little") + bytes(64)
    cases.append(Case("fbx_binary_refused", "fbx", fbx, None))
    return cases


# --- running --------------------------------------------------------------------------


def _compare(vertices: np.ndarray, faces: np.ndarray, truth: Truth, tolerance: float) -> str:
    """'' when the triangles match the truth (count, area, bounds), else what differs."""
    if len(faces) != len(truth.faces):
        return f"{len(faces)} triangles, expected {len(truth.faces)}"
    area, expected_area = _area(vertices, faces), truth.area
    if abs(area - expected_area) > tolerance * max(expected_area, 1e-12) + 1e-9:
        return f"area {area:.6g}, expected {expected_area:.6g}"
    bounds, expected = _bounds(vertices, faces), _bounds(truth.vertices, truth.faces)
    extent = float((expected[1] - expected[0]).max())
    if np.abs(bounds - expected).max() > max(tolerance, 1e-6) * extent:
        return f"bounds {np.round(bounds, 4).tolist()}, expected {np.round(expected, 4).tolist()}"
    return ""


def _attributes_problem(case: Case, mesh: TriangleMesh) -> str:
    """What differs when the file is read with its attributes (``load_source``): the mesh
    must be the same (content hash), the attributes must fit it."""
    try:
        source = load_source(case.data, case.file_type)
    except Exception as exc:  # noqa: BLE001 - reported in the row
        return f"load_source fails: {type(exc).__name__}: {exc}"[:80]
    if source.mesh.content_hash() != mesh.content_hash():
        return "load_source reads another mesh"
    if source.attributes is not None:
        try:
            source.attributes.check(mesh)
        except ValueError as exc:
            return f"attributes do not fit: {exc}"
    return ""


def _run(case: Case) -> tuple[str, str, str, str]:
    """(expected, ours, independent, verdict) of one case."""
    expected = (
        "refuse"
        if case.truth is None
        else f"{len(case.truth.faces)} tri / {case.truth.input_faces} faces"
    )
    try:
        mesh = load_mesh(case.data, case.file_type)
    except MeshError as exc:
        ours = f"refused: {type(exc).__name__}: {str(exc)[:90]}"
        verdict = "ok" if case.truth is None else "REFUSED"
    except Exception as exc:  # noqa: BLE001 - reported as a crash row
        ours, verdict = f"CRASH {type(exc).__name__}: {exc}"[:120], "CRASH"
    else:
        area = _area(mesh.vertices, mesh.faces)
        ours = f"{mesh.face_count} tri / {mesh.input_face_count} faces, area {area:.5g}"
        if case.truth is None:
            verdict = "MISREAD (bad file accepted)"
        else:
            problem = _compare(mesh.vertices, mesh.faces, case.truth, case.tolerance)
            if not problem and mesh.input_face_count != case.truth.input_faces:
                problem = f"{mesh.input_face_count} input faces, expected {case.truth.input_faces}"
            if (
                not problem
                and case.truth.origin is not None
                and not np.array_equal(mesh.face_origin, case.truth.origin)
            ):
                problem = "triangles map to the wrong input faces"
            if not problem:
                problem = _attributes_problem(case, mesh)
            verdict = f"MISREAD: {problem}" if problem else "ok"
    independent = "-"
    if case.independent is not None:
        try:
            vertices, faces = case.independent()
        except Exception as exc:  # noqa: BLE001 - the independent reader's failure is a fact to show
            independent = f"fails: {type(exc).__name__}"
        else:
            if case.truth is None:
                independent = f"reads {len(faces)} tri"
            else:
                problem = _compare(vertices, faces, case.truth, case.tolerance)
                independent = "agrees" if not problem else f"differs: {problem}"[:60]
    return expected, ours, independent, verdict


def _time_draco(faces: int) -> None:
    import DracoPy

    subdivisions = max(1, int(round(np.log(faces / 20) / np.log(4))))
    sphere = trimesh.creation.icosphere(subdivisions)
    plain = _Gltf()
    plain.node(
        plain.mesh(
            [
                {
                    "attributes": {"POSITION": _positions(plain, sphere.vertices)},
                    "indices": _indices(plain, sphere.faces.reshape(-1), np.uint32),
                }
            ]
        )
    )
    plain_glb = plain.glb()
    started = time.perf_counter()
    draco_data = draco_glb(sphere, np.eye(4), required=True)
    encode_s = time.perf_counter() - started
    del DracoPy

    def best(data: bytes) -> float:
        times = []
        for _ in range(3):
            started = time.perf_counter()
            load_mesh(data, "glb")
            times.append(time.perf_counter() - started)
        return min(times)

    plain_s, draco_s = best(plain_glb), best(draco_data)
    print(
        f"\nDraco timing: {len(sphere.faces)} faces; uncompressed GLB "
        f"{len(plain_glb) / 1e6:.1f} MB loads in {plain_s:.3f} s, Draco GLB "
        f"{len(draco_data) / 1e6:.1f} MB (encoded in {encode_s:.1f} s) "
        f"in {draco_s:.3f} s: {draco_s - plain_s:+.3f} s beyond (target at most +1 s), "
        f"ratio {draco_s / plain_s:.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--draco-faces", type=int, default=1_000_000)
    parser.add_argument("--only", default="", help="run the cases whose name contains this")
    args = parser.parse_args()
    cases = [c for c in _text_cases() + _gltf_cases() + _usd_cases() if args.only in c.name]
    rows = [(case.name, *_run(case)) for case in cases]
    header = ("file", "expected", "ours", "independent", "verdict")
    widths = [max(len(str(row[i])) for row in [header, *rows]) for i in range(5)]
    print(" | ".join(h.ljust(w) for h, w in zip(header, widths, strict=True)))
    print("-|-".join("-" * w for w in widths))
    for row in rows:
        print(" | ".join(str(v).ljust(w) for v, w in zip(row, widths, strict=True)))
    misread = sum(row[4].startswith("MISREAD") for row in rows)
    refused = sum(row[4] in ("REFUSED", "CRASH") for row in rows)
    print(
        f"\n{len(rows)} files: {len(rows) - misread - refused} as expected, "
        f"{refused} good files refused or crashed, {misread} silent misreads"
    )
    _check_usda_fast_path(cases)
    if args.draco_faces:
        _time_draco(args.draco_faces)


def _check_usda_fast_path(cases: list[Case]) -> None:
    """Every .usda of the corpus with all its numeric arrays cut (``_usda_arrays``, even
    the smallest): the restored layer must print as usd-core's layer of the whole text,
    and the reader must give the same answer (mesh, or the same refusal) either way."""
    from pxr import Sdf

    from neural_shdf.exchange import usd
    from neural_shdf.exchange._usda_arrays import cut_arrays, restore_arrays

    checked = same = declined = nothing = 0
    for case in cases:
        if case.file_type != "usda":
            continue
        checked += 1
        full = Sdf.Layer.CreateAnonymous(".usda")
        full.ImportFromString(case.data.decode())
        cut = cut_arrays(case.data, 1)
        layer = Sdf.Layer.CreateAnonymous(".usda")
        if cut is None:
            nothing += 1
            continue
        if not layer.ImportFromString(cut.text.decode()):
            declined += 1
            continue
        if not restore_arrays(layer, cut):
            declined += 1
            continue
        answers = []
        for cutter in (lambda d, **k: None, lambda d, **k: cut_arrays(d, 1, **k)):
            usd.cut_arrays = cutter  # type: ignore[assignment]
            try:
                answers.append(load_mesh(case.data, "usda").content_hash())
            except Exception as error:  # noqa: BLE001 - the refusal is the answer
                answers.append(f"{type(error).__name__}: {error}")
        usd.cut_arrays = cut_arrays
        same += layer.ExportToString() == full.ExportToString() and answers[0] == answers[1]
    print(
        f"\n.usda fast path: {checked} corpus files, every array cut: {same} read the same "
        f"as usd-core alone (layer and answer), {nothing} without a numeric array, "
        f"{declined} declined (read by usd-core alone), "
        f"{checked - same - declined - nothing} different"
    )


if __name__ == "__main__":
    main()
