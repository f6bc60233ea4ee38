"""glTF/GLB reader: scene-graph order, node transforms, instancing, and hostile files."""

import base64
import copy
import json
import math
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import (
    InvalidGeometryError,
    MeshParseError,
    MeshTooLargeError,
    UnsupportedFormatError,
)
from neural_shdf.exchange import gltf as gltf_reader
from neural_shdf.mesh_io import load_mesh, sniff_format

TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32)
SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float32)
SQUARE_INDICES = np.array([0, 1, 2, 0, 2, 3], dtype=np.uint32)
TRIANGLE_INDICES = np.array([0, 1, 2], dtype=np.uint16)


class _Builder:
    """Minimal glTF writer for tests: one buffer, one bufferView per accessor."""

    def __init__(self):
        self.blob = bytearray()
        self.doc = {"asset": {"version": "2.0"}, "accessors": [], "bufferViews": [], "meshes": []}

    def accessor(self, array: np.ndarray, kind: str, component: int) -> int:
        while len(self.blob) % 4:
            self.blob += b"\x00"
        self.doc["bufferViews"].append(
            {"buffer": 0, "byteOffset": len(self.blob), "byteLength": array.nbytes}
        )
        self.blob += array.tobytes()
        count = len(array) if array.ndim > 1 or kind == "SCALAR" else 1
        self.doc["accessors"].append(
            {
                "bufferView": len(self.doc["bufferViews"]) - 1,
                "componentType": component,
                "type": kind,
                "count": count,
            }
        )
        return len(self.doc["accessors"]) - 1

    def mesh(self, positions, indices=None, mode=4) -> int:
        primitive = {"attributes": {"POSITION": self.accessor(positions, "VEC3", 5126)}}
        if indices is not None:
            component = {np.dtype(np.uint16): 5123, np.dtype(np.uint32): 5125}[indices.dtype]
            primitive["indices"] = self.accessor(indices, "SCALAR", component)
        if mode != 4:
            primitive["mode"] = mode
        self.doc["meshes"].append({"primitives": [primitive]})
        return len(self.doc["meshes"]) - 1

    def glb(self, doc=None, buffer_length=None) -> bytes:
        doc = copy.deepcopy(self.doc if doc is None else doc)
        length = len(self.blob) if buffer_length is None else buffer_length
        doc["buffers"] = [{"byteLength": length}]
        text = json.dumps(doc).encode()
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

    def gltf(self) -> bytes:
        doc = copy.deepcopy(self.doc)
        payload = base64.b64encode(bytes(self.blob)).decode()
        doc["buffers"] = [
            {"byteLength": len(self.blob), "uri": "data:application/octet-stream;base64," + payload}
        ]
        return json.dumps(doc).encode()


def _scene() -> _Builder:
    """Nodes listed out of index order, a child node, an instanced mesh, a mirror, an orphan."""
    b = _Builder()
    tri = b.mesh(TRIANGLE, TRIANGLE_INDICES)
    square = b.mesh(SQUARE, SQUARE_INDICES)
    lines = b.accessor(np.array([0, 1], np.uint16), "SCALAR", 5123)
    b.doc["meshes"][tri]["primitives"].append(
        {"attributes": {"POSITION": 0}, "indices": lines, "mode": 1}  # lines: ignored
    )
    s = math.sqrt(0.5)
    mirror = [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 5, 1]  # column-major, z += 5
    b.doc["nodes"] = [
        {"name": "A", "mesh": tri, "translation": [10, 0, 0], "children": [1]},
        {"name": "B", "mesh": square, "scale": [2, 2, 2]},
        {"name": "C", "mesh": tri, "rotation": [0, 0, s, s]},
        {"name": "D", "mesh": tri, "matrix": mirror},
        {"name": "orphan", "mesh": square},
    ]
    b.doc["scenes"] = [{"nodes": [2, 0, 3]}]
    b.doc["scene"] = 0
    return b


EXPECTED_TRIANGLES = np.array(
    [
        [[0, 0, 0], [0, 1, 0], [-1, 0, 0]],  # C: rotated 90 degrees about z
        [[10, 0, 0], [11, 0, 0], [10, 1, 0]],  # A: translated
        [[10, 0, 0], [12, 0, 0], [12, 2, 0]],  # B: child of A, scaled by 2
        [[10, 0, 0], [12, 2, 0], [10, 2, 0]],
        [[0, 0, 5], [0, 1, 5], [-1, 0, 5]],  # D: mirrored in x, winding flipped
    ],
    dtype=float,
)


@pytest.mark.parametrize("container", ["glb", "gltf"])
def test_scene_graph_order_transforms_and_instancing(container):
    builder = _scene()
    data = builder.glb() if container == "glb" else builder.gltf()
    mesh = load_mesh(data, container)
    np.testing.assert_allclose(mesh.vertices[mesh.faces], EXPECTED_TRIANGLES, atol=1e-6)
    assert mesh.input_face_count == 5
    assert mesh.face_origin.tolist() == [0, 1, 2, 3, 4]


def test_mirrored_instance_keeps_outward_normal():
    mesh = load_mesh(_scene().glb(), "glb")
    a, b, c = mesh.vertices[mesh.faces[4]]
    assert np.cross(b - a, c - a)[2] > 0  # the source triangle faces +z; so must its mirror


def test_same_triangles_as_trimesh():
    data = _scene().glb()
    mesh = load_mesh(data, "glb")
    scene = trimesh.load(trimesh.util.wrap_as_stream(data), file_type="glb", process=False)
    reference = []
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geometry = scene.geometry[name]
        if isinstance(geometry, trimesh.Trimesh):
            corners = trimesh.transform_points(geometry.vertices, transform)[geometry.faces]
            reference.extend(corners)

    def canonical(triangles):
        rows = [tuple(sorted(map(tuple, np.round(t, 5)))) for t in triangles]
        return sorted(rows)

    assert canonical(mesh.vertices[mesh.faces]) == canonical(reference)


def test_strip_and_fan_modes():
    b = _Builder()
    b.mesh(SQUARE[[0, 1, 3, 2]], np.array([0, 1, 2, 3], np.uint16), mode=5)
    b.mesh(SQUARE, None, mode=6)
    mesh = load_mesh(b.glb(), "glb")
    # glTF strips: odd triangle i is (i, i + 2, i + 1); fans: (i + 1, i + 2, 0).
    assert mesh.faces.tolist() == [[0, 1, 2], [1, 3, 2], [5, 6, 4], [6, 7, 4]]
    normals = np.cross(
        mesh.vertices[mesh.faces[:, 1]] - mesh.vertices[mesh.faces[:, 0]],
        mesh.vertices[mesh.faces[:, 2]] - mesh.vertices[mesh.faces[:, 0]],
    )
    assert (normals[:, 2] > 0).all()  # strips alternate winding so all face the same way


def test_meshes_without_nodes_are_read_in_order():
    b = _Builder()
    b.mesh(SQUARE, SQUARE_INDICES)
    b.mesh(TRIANGLE + 5, TRIANGLE_INDICES)
    mesh = load_mesh(b.glb(), "glb")
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 2, 3], [4, 5, 6]]


def _simple() -> _Builder:
    b = _Builder()
    b.mesh(SQUARE, SQUARE_INDICES)
    return b


def _with(b: _Builder, edit) -> bytes:
    doc = copy.deepcopy(b.doc)
    edit(doc)
    return b.glb(doc)


def test_declared_lengths_beyond_the_file_are_rejected():
    b = _simple()
    data = b.glb()
    too_long = data[:8] + struct.pack("<I", 10**9) + data[12:]
    with pytest.raises(MeshParseError, match="truncated"):
        load_mesh(too_long, "glb")
    json_length = struct.unpack_from("<I", data, 12)[0]
    big_chunk = data[:12] + struct.pack("<I", 2**31) + data[16:]
    with pytest.raises(MeshParseError, match="beyond the end"):
        load_mesh(big_chunk, "glb")
    assert json_length > 0
    with pytest.raises(MeshParseError, match="elements"):
        load_mesh(_with(b, lambda d: d["accessors"][0].update(count=10**12)), "glb")
    with pytest.raises(MeshParseError, match="outside its buffer"):
        load_mesh(_with(b, lambda d: d["bufferViews"][0].update(byteLength=10**12)), "glb")


def test_buffer_length_beyond_its_data_is_rejected():
    b = _simple()
    data = b.glb(buffer_length=99999999)
    with pytest.raises(MeshParseError, match="declares 99999999"):
        load_mesh(data, "glb")


@pytest.mark.parametrize(
    ("edit", "error", "words"),
    [
        (lambda d: d["meshes"][0]["primitives"][0].update(mode=0), InvalidGeometryError,
         "no triangles"),
        (lambda d: d["meshes"][0]["primitives"][0].update(indices=7), MeshParseError,
         "does not exist"),
        (lambda d: d["meshes"][0]["primitives"][0].update(indices=-1), MeshParseError,
         "does not exist"),
        (lambda d: d["accessors"][0].update(sparse={}), MeshParseError, "sparse"),
        (lambda d: d["meshes"][0]["primitives"][0].update(
            extensions={"KHR_draco_mesh_compression": {"bufferView": 0}}), MeshParseError,
         "Draco-compressed data of glTF mesh 0 cannot be decoded"),
        (lambda d: d.update(nodes=[{"mesh": 0, "children": [1]}, {"children": [0]}],
                            scenes=[{"nodes": [0]}]), MeshParseError, "cycle"),
        (lambda d: d["asset"].update(version="1.0"), UnsupportedFormatError, "version"),
        (lambda d: d.update(nodes=[{"mesh": 0, "extensions": {"EXT_mesh_gpu_instancing": {}}}],
                            scenes=[{"nodes": [0]}]), MeshParseError, "without attributes"),
    ],
)  # fmt: skip
def test_bad_documents_raise_typed_errors(edit, error, words):
    with pytest.raises(error, match=words):
        load_mesh(_with(_simple(), edit), "glb")


def test_index_beyond_the_primitive_vertices_is_invalid():
    b = _Builder()
    b.mesh(TRIANGLE, np.array([0, 1, 5], np.uint16))
    b.mesh(SQUARE, SQUARE_INDICES)  # index 5 would silently land here if not checked
    with pytest.raises(InvalidGeometryError, match="uses vertex 5"):
        load_mesh(b.glb(), "glb")


def test_text_gltf_declared_as_glb_still_loads():
    assert load_mesh(_simple().gltf(), "glb").face_count == 2


def test_external_buffer_uri_is_unsupported():
    doc = json.loads(_simple().gltf())
    doc["buffers"][0]["uri"] = "mesh.bin"
    with pytest.raises(UnsupportedFormatError, match="external buffer"):
        load_mesh(json.dumps(doc).encode(), "gltf")


def test_exponential_instancing_is_capped(monkeypatch):
    monkeypatch.setattr(gltf_reader, "MAX_NODE_VISITS", 1000)
    b = _simple()
    layers = 20  # each node instances the next one twice: 2**20 mesh instances
    b.doc["nodes"] = [{"children": [i + 1, i + 1]} for i in range(layers)] + [{"mesh": 0}]
    b.doc["scenes"] = [{"nodes": [0]}]
    with pytest.raises(MeshTooLargeError):
        load_mesh(b.glb(), "glb")


def test_max_faces_before_reading():
    with pytest.raises(MeshTooLargeError, match="limit of 1"):
        load_mesh(_simple().glb(), "glb", max_faces=1)


def test_trimesh_exported_glb_loads_in_order():
    box = trimesh.creation.box()
    mesh = load_mesh(box.export(file_type="glb"), "glb")
    np.testing.assert_allclose(mesh.vertices[mesh.faces], box.vertices[box.faces], atol=1e-6)


def _instanced(vertex_count: int, children: int) -> _Builder:
    """One mesh of ``vertex_count`` vertices (a single indexed triangle) placed by each of
    ``children`` child nodes of one root: few bytes, ``children`` times the vertices."""
    b = _Builder()
    positions = np.random.default_rng(0).random((vertex_count, 3)).astype(np.float32)
    b.mesh(positions, TRIANGLE_INDICES)
    b.doc["nodes"] = [{"children": list(range(1, children + 1))}] + [
        {"mesh": 0, "translation": [i, 0, 0]} for i in range(children)
    ]
    b.doc["scenes"] = [{"nodes": [0]}]
    return b


def test_instanced_vertices_are_budgeted_before_any_accessor_is_read(monkeypatch):
    data = _instanced(50_000, 40).glb()  # 0.6 MB that expands to 2M vertices

    def no_read(*args):
        raise AssertionError("an accessor was read before the budget was checked")

    monkeypatch.setattr(gltf_reader._Document, "accessor", no_read)
    with pytest.raises(MeshTooLargeError, match="max_vertices") as error:
        load_mesh(data, "glb", max_faces=1000, max_vertices=1_000_000)
    assert error.value.limit == "max_vertices"
    assert error.value.found == 2_000_000 and error.value.maximum == 1_000_000
    assert "40 glTF mesh instances" in str(error.value)


def test_instanced_triangles_are_budgeted_before_any_accessor_is_read(monkeypatch):
    b = _instanced(3, 5)
    monkeypatch.setattr(gltf_reader._Document, "accessor", None)  # never called
    with pytest.raises(MeshTooLargeError, match="5 triangles .*limit of 4 triangles"):
        load_mesh(b.glb(), "glb", max_faces=4)


def test_within_budget_every_instance_is_expanded():
    mesh = load_mesh(_instanced(10, 40).glb(), "glb", max_faces=40, max_vertices=400)
    assert mesh.face_count == 40 and len(mesh.vertices) == 400


def test_accessors_aliasing_one_buffer_view_count_once_per_use():
    b = _instanced(1000, 1)
    position = b.doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
    indices = b.doc["meshes"][0]["primitives"][0]["indices"]
    aliases = [dict(b.doc["accessors"][position]) for _ in range(300)]
    first = len(b.doc["accessors"])
    b.doc["accessors"] += aliases  # 300 accessors decoding the same bytes
    b.doc["meshes"][0]["primitives"] = [
        {"attributes": {"POSITION": first + i}, "indices": indices} for i in range(300)
    ]
    with pytest.raises(MeshTooLargeError, match="300000 vertices"):
        load_mesh(b.glb(), "glb", max_vertices=100_000)


def test_a_chain_of_thousands_of_nodes_loads_without_recursion():
    b = _simple()
    depth = 5000
    b.doc["nodes"] = [{"children": [i + 1], "translation": [1, 0, 0]} for i in range(depth)]
    b.doc["nodes"].append({"mesh": 0})
    b.doc["scenes"] = [{"nodes": [0]}]
    mesh = load_mesh(b.glb(), "glb")
    assert mesh.vertices[:, 0].min() == depth  # every ancestor's translation applied


def test_a_cycle_deep_in_a_chain_is_named():
    b = _simple()
    b.doc["nodes"] = [{"children": [i + 1]} for i in range(3000)] + [{"children": [1500]}]
    b.doc["scenes"] = [{"nodes": [0]}]
    with pytest.raises(MeshParseError, match="cycle through node 1500"):
        load_mesh(b.glb(), "glb")


DATA = Path(__file__).parent / "data"


def _glb_json(data: bytes) -> tuple[dict, bytes]:
    length = struct.unpack_from("<I", data, 12)[0]
    return json.loads(data[20 : 20 + length]), data[20 + length + 8 :]


def _glb(document: dict, blob: bytes) -> bytes:
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text
    body += struct.pack("<II", len(blob), 0x004E4942) + blob
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def _reference_scene() -> trimesh.Trimesh:
    return trimesh.load(DATA / "scene.glb", force="mesh", process=False)


def _assert_same_surface(mesh, reference, tolerance):
    assert mesh.face_count == len(reference.faces) == 344
    ours = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    assert ours.area == pytest.approx(reference.area, rel=tolerance)
    assert ours.volume == pytest.approx(reference.volume, rel=tolerance)  # winding kept
    np.testing.assert_allclose(ours.bounds, reference.bounds, atol=tolerance * 10)


@pytest.mark.parametrize(
    "name", ["scene_draco.glb", "scene_gltfpack_meshopt.glb", "scene_gltf_transform_meshopt.glb"]
)
def test_reference_encoder_files_read_to_the_uncompressed_scene(name):
    _assert_same_surface(load_mesh(DATA / name), _reference_scene(), 1e-3)


def test_draco_listed_only_in_extensions_used_is_decoded():
    document, blob = _glb_json((DATA / "scene_draco.glb").read_bytes())
    del document["extensionsRequired"]
    _assert_same_surface(load_mesh(_glb(document, blob), "glb"), _reference_scene(), 1e-3)


def test_draco_counts_other_than_the_accessors_declare_are_refused():
    document, blob = _glb_json((DATA / "scene_draco.glb").read_bytes())
    document["accessors"][0]["count"] = 957  # the sphere's indices
    with pytest.raises(MeshParseError, match="Draco data of glTF mesh 0 decodes to"):
        load_mesh(_glb(document, blob), "glb")


def test_meshopt_view_larger_than_its_accessors_need_is_refused_before_decoding():
    document, blob = _glb_json((DATA / "scene_gltfpack_meshopt.glb").read_bytes())
    view = document["bufferViews"][0]
    view["extensions"]["EXT_meshopt_compression"]["count"] = 10**8
    view["byteLength"] = 8 * 10**8
    with pytest.raises(MeshParseError, match="would decompress"):
        load_mesh(_glb(document, blob), "glb")


def test_corrupt_meshopt_data_is_a_parse_error():
    document, blob = _glb_json((DATA / "scene_gltfpack_meshopt.glb").read_bytes())
    with pytest.raises(MeshParseError, match="meshopt"):
        load_mesh(_glb(document, bytes(len(blob))), "glb")


def _sparse_box(with_base: bool) -> bytes:
    box = trimesh.creation.box()
    builder = _Builder()
    targets = np.array([1, 6], dtype=np.uint16)
    base = box.vertices.astype(np.float32)
    base[targets] = 0
    position = builder.accessor(base, "VEC3", 5126)
    spec = builder.doc["accessors"][position]
    target_view = builder.accessor(targets, "SCALAR", 5123)
    value_view = builder.accessor(box.vertices[targets].astype(np.float32), "VEC3", 5126)
    spec["sparse"] = {
        "count": 2,
        "indices": {"bufferView": builder.doc["accessors"][target_view]["bufferView"],
                    "componentType": 5123},
        "values": {"bufferView": builder.doc["accessors"][value_view]["bufferView"]},
    }  # fmt: skip
    if not with_base:
        del spec["bufferView"]
        spec["sparse"]["count"] = 8
        spec["sparse"]["indices"]["bufferView"] = builder.doc["accessors"][
            builder.accessor(np.arange(8, dtype=np.uint16), "SCALAR", 5123)
        ]["bufferView"]
        spec["sparse"]["values"]["bufferView"] = builder.doc["accessors"][
            builder.accessor(box.vertices.astype(np.float32), "VEC3", 5126)
        ]["bufferView"]
    indices = builder.accessor(box.faces.reshape(-1).astype(np.uint16), "SCALAR", 5123)
    builder.doc["meshes"].append(
        {"primitives": [{"attributes": {"POSITION": position}, "indices": indices}]}
    )
    return builder.glb()


@pytest.mark.parametrize("with_base", [True, False])
def test_sparse_accessors_substitute_their_values(with_base):
    mesh = load_mesh(_sparse_box(with_base), "glb")
    box = trimesh.creation.box()
    np.testing.assert_allclose(mesh.vertices, box.vertices)
    assert mesh.faces.tolist() == box.faces.tolist()


def test_sparse_indices_beyond_the_accessor_are_refused():
    data = _sparse_box(True)
    document, blob = _glb_json(data)
    document["accessors"][0]["sparse"]["count"] = 9
    with pytest.raises(MeshParseError, match="sparse part of accessor 0"):
        load_mesh(_glb(document, blob), "glb")


def test_text_gltf_with_a_byte_order_mark():
    text = b"\xef\xbb\xbf" + _simple().gltf()
    assert load_mesh(text, "gltf").faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    assert sniff_format(text) == "gltf"


def test_gpu_instancing_places_the_mesh_once_per_instance_in_instance_order():
    """EXT_mesh_gpu_instancing: each instance's triangles in instance order, in the node's
    place among the others; world = node @ translation @ rotation @ scale of the instance."""
    b = _Builder()
    b.mesh(SQUARE, SQUARE_INDICES)
    b.mesh(TRIANGLE, TRIANGLE_INDICES)
    translations = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], np.float32)
    quarter_turn = np.array([0, 0, math.sin(math.pi / 4), math.cos(math.pi / 4)], np.float32)
    rotations = np.array([[0, 0, 0, 1], quarter_turn, [0, 0, 0, 1]], np.float32)
    scales = np.array([[1, 1, 1], [1, 1, 1], [2, 2, 2]], np.float32)
    instancing = {"attributes": {
        "TRANSLATION": b.accessor(translations, "VEC3", 5126),
        "ROTATION": b.accessor(rotations, "VEC4", 5126),
        "SCALE": b.accessor(scales, "VEC3", 5126),
    }}  # fmt: skip
    b.doc["nodes"] = [
        {"mesh": 1},
        {"mesh": 0, "translation": [0, 0, 5],
         "extensions": {"EXT_mesh_gpu_instancing": instancing}},
        {"mesh": 1, "translation": [0, 0, -5]},
    ]  # fmt: skip
    b.doc["scenes"] = [{"nodes": [0, 1, 2]}]
    b.doc["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    mesh = load_mesh(b.glb(), "glb")
    assert mesh.face_count == 1 + 3 * 2 + 1
    corners = mesh.vertices[mesh.faces]
    square = SQUARE[SQUARE_INDICES.reshape(-1, 3)].astype(np.float64)
    rotated = square @ np.array([[0, 1, 0], [-1, 0, 0], [0, 0, 1]], np.float64)
    expected = [
        TRIANGLE[None].astype(np.float64),
        square + [0, 0, 5],
        rotated + [10, 0, 5],
        2 * square + [0, 10, 5],
        TRIANGLE[None] + np.array([0, 0, -5.0]),
    ]
    np.testing.assert_allclose(corners, np.concatenate(expected), atol=1e-6)


def test_gpu_instancing_counts_against_the_face_budget():
    b = _Builder()
    b.mesh(TRIANGLE, TRIANGLE_INDICES)
    translations = np.zeros((1000, 3), np.float32)
    attributes = {"TRANSLATION": b.accessor(translations, "VEC3", 5126)}
    b.doc["nodes"] = [
        {"mesh": 0, "extensions": {"EXT_mesh_gpu_instancing": {"attributes": attributes}}}
    ]
    with pytest.raises(MeshTooLargeError, match="1000 glTF mesh instances"):
        load_mesh(b.glb(), "glb", max_faces=999)


def test_draco_primitives_keep_their_normals_and_uvs_when_attributes_are_read():
    """load_source of a Draco primitive: NORMAL and TEXCOORD_0 decoded from the Draco data
    by the ids the extension gives; the mesh is the one load_mesh reads."""
    import DracoPy

    from neural_shdf.mesh_io import load_source

    sphere = trimesh.creation.icosphere(subdivisions=2)
    uv = (sphere.vertices[:, :2] + 1) / 2
    encoded = DracoPy.encode(
        sphere.vertices.astype(np.float32), sphere.faces.astype(np.uint32),
        normals=sphere.vertex_normals.astype(np.float64), tex_coord=uv.astype(np.float64),
        preserve_order=True,
    )  # fmt: skip
    ids = {}
    decoded = DracoPy.decode(encoded)
    for unique_id in range(3):
        kind = decoded.get_attribute_by_unique_id(unique_id)["attribute_type"]
        ids[{0: "POSITION", 1: "NORMAL", 3: "TEXCOORD_0"}[kind]] = unique_id
    b = _Builder()
    b.blob += encoded
    b.doc["bufferViews"].append({"buffer": 0, "byteOffset": 0, "byteLength": len(encoded)})
    vertices, faces = len(sphere.vertices), len(sphere.faces)
    b.doc["accessors"] = [
        {"componentType": 5125, "type": "SCALAR", "count": 3 * faces},
        {"componentType": 5126, "type": "VEC3", "count": vertices},
        {"componentType": 5126, "type": "VEC3", "count": vertices},
        {"componentType": 5126, "type": "VEC2", "count": vertices},
    ]
    draco = {"bufferView": 0, "attributes": ids}
    primitive = {"attributes": {"POSITION": 1, "NORMAL": 2, "TEXCOORD_0": 3}, "indices": 0,
                 "extensions": {"KHR_draco_mesh_compression": draco}}  # fmt: skip
    b.doc["meshes"] = [{"primitives": [primitive]}]
    b.doc["extensionsUsed"] = b.doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    data = b.glb()
    source = load_source(data, "glb")
    assert source.mesh.content_hash() == load_mesh(data, "glb").content_hash()
    attributes = source.attributes
    assert attributes.groups[0].normals and attributes.groups[0].uv_sets == 1
    np.testing.assert_allclose(
        attributes.normals[attributes.corners], sphere.vertex_normals[sphere.faces], atol=1e-6
    )
    np.testing.assert_allclose(attributes.uvs[0][attributes.corners], uv[sphere.faces], atol=1e-6)
