"""PLY reader: ascii and binary, uniform and mixed polygons, skipped elements, truncation."""

import struct

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import InvalidGeometryError, MeshParseError, MeshTooLargeError
from neural_shdf.mesh_io import load_mesh

VERTICES = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0.5, 0]], dtype=np.float64)
POLYGONS = [[0, 1, 2, 3], [1, 4, 2], [0, 1, 4, 2, 3]]
FANS = [[0, 1, 2], [0, 2, 3], [1, 4, 2], [0, 1, 4], [0, 4, 2], [0, 2, 3]]


def _header(encoding: str, n_vertices: int, n_faces: int, extras: bool) -> bytes:
    lines = ["ply", f"format {encoding} 1.0", "comment test", f"element vertex {n_vertices}"]
    lines += ["property float x", "property float y", "property float z"]
    if extras:
        lines += ["property uchar red", "property double quality"]
    lines += [f"element face {n_faces}"]
    if extras:
        lines += ["property uchar flags"]
    lines += ["property list uchar int vertex_indices"]
    if extras:
        lines += ["property float weight", "element edge 1", "property int a", "property int b"]
    lines += ["end_header"]
    return ("\n".join(lines) + "\n").encode()


def _binary_ply(polygons, extras=False, endian="<") -> bytes:
    encoding = "binary_little_endian" if endian == "<" else "binary_big_endian"
    out = bytearray(_header(encoding, len(VERTICES), len(polygons), extras))
    for v in VERTICES:
        out += struct.pack(endian + "3f", *v)
        if extras:
            out += struct.pack(endian + "Bd", 7, 0.25)
    for polygon in polygons:
        if extras:
            out += struct.pack(endian + "B", 1)
        out += struct.pack(endian + f"B{len(polygon)}i", len(polygon), *polygon)
        if extras:
            out += struct.pack(endian + "f", 0.5)
    if extras:
        out += struct.pack(endian + "2i", 0, 1)
    return bytes(out)


def _ascii_ply(polygons, extras=False) -> bytes:
    out = _header("ascii", len(VERTICES), len(polygons), extras).decode()
    for v in VERTICES:
        out += " ".join(map(str, v)) + (" 7 0.25" if extras else "") + "\n"
    for polygon in polygons:
        row = [len(polygon), *polygon]
        out += ("1 " if extras else "") + " ".join(map(str, row)) + (" 0.5" if extras else "")
        out += "\n"
    if extras:
        out += "0 1\n"
    return out.encode()


@pytest.mark.parametrize("extras", [False, True])
@pytest.mark.parametrize(
    "make", [_ascii_ply, _binary_ply, lambda p, e: _binary_ply(p, e, ">")], ids=str
)
def test_mixed_polygons_fan_in_input_order(make, extras):
    mesh = load_mesh(make(POLYGONS, extras), "ply")
    assert mesh.faces.tolist() == FANS
    assert mesh.face_origin.tolist() == [0, 0, 1, 2, 2, 2]
    np.testing.assert_array_equal(mesh.vertices, VERTICES.astype(np.float32))


@pytest.mark.parametrize("make", [_ascii_ply, _binary_ply])
def test_uniform_triangles_fast_path(make):
    triangles = [[0, 1, 2], [0, 2, 3], [1, 4, 2]]
    mesh = load_mesh(make(triangles, True), "ply")
    assert mesh.faces.tolist() == triangles
    assert mesh.face_origin.tolist() == [0, 1, 2]


@pytest.mark.parametrize("encoding", ["binary", "ascii"])
def test_trimesh_export_round_trips_in_order(encoding):
    source = trimesh.creation.icosphere(subdivisions=2)
    data = source.export(file_type="ply", encoding=encoding)
    mesh = load_mesh(data, "ply")
    np.testing.assert_array_equal(mesh.faces, source.faces)
    np.testing.assert_allclose(mesh.vertices, source.vertices, atol=1e-6)


def test_truncated_binary_is_a_parse_error():
    data = _binary_ply(POLYGONS)
    for cut in (len(data) - 3, len(data) - 30, 120):
        with pytest.raises(MeshParseError, match="truncated"):
            load_mesh(data[:cut], "ply")


def test_truncated_ascii_is_a_parse_error():
    with pytest.raises(MeshParseError, match="truncated"):
        load_mesh(_ascii_ply(POLYGONS)[:-12], "ply")


def test_huge_declared_count_rejected_before_allocating():
    data = _binary_ply(POLYGONS).replace(b"element face 3", b"element face 3000000000")
    with pytest.raises(MeshParseError, match="truncated"):
        load_mesh(data, "ply")


@pytest.mark.parametrize(
    ("data", "error", "words"),
    [
        (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
         b"property float z\nend_header\n0 0 0\n1 0 0\n0 1 0\n", InvalidGeometryError, "face"),
        (b"ply\nformat ascii 1.0\nelement vertex 3\n", MeshParseError, "end_header"),
        (b"plx\nformat ascii 1.0\nend_header\n", MeshParseError, "start with 'ply'"),
        (b"ply\nelement vertex 0\nend_header\n", MeshParseError, "format"),
    ],
)  # fmt: skip
def test_bad_ply_raises_typed_error(data, error, words):
    with pytest.raises(error, match=words):
        load_mesh(data, "ply")


def test_out_of_range_index_is_invalid_geometry():
    with pytest.raises(InvalidGeometryError, match="do not exist"):
        load_mesh(_binary_ply([[0, 1, 9]]), "ply")


def test_max_faces_checked_from_header():
    with pytest.raises(MeshTooLargeError):
        load_mesh(_binary_ply(POLYGONS), "ply", max_faces=2)


def test_dense_scan_matches_header_count(shared_data):
    path = shared_data / "dense-dev" / "vtkdata__Data__lucy.ply"
    if not path.is_file():
        pytest.skip(f"{path} is absent")
    header = path.read_bytes()[:2000].split(b"end_header")[0].decode("latin-1")
    declared = int(header.split("element face ")[1].split()[0])
    mesh = load_mesh(path)
    assert mesh.face_count == mesh.input_face_count == declared


def test_byte_order_mark_is_skipped():
    text = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    )
    assert load_mesh(b"\xef\xbb\xbf" + text.encode(), "ply").faces.tolist() == [[0, 1, 2]]


def test_vertex_normals_uvs_and_colours_are_kept_when_attributes_are_read():
    from neural_shdf.mesh_io import load_source
    from neural_shdf.palette import srgb_to_linear

    header = (
        "ply\nformat ascii 1.0\nelement vertex 4\n"
        + "".join(f"property float {n}\n" for n in ("x", "y", "z", "nx", "ny", "nz", "s", "t"))
        + "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        + "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    )
    rows = [
        "0 0 0 0 0 2 0 0 255 0 0",  # a normal of length 2: scaled to unit
        "1 0 0 0 0 1 1 0 0 255 0",
        "1 1 0 0 0 1 1 1 0 0 255",
        "0 1 0 0 0 1 0 1 128 128 128",
    ]
    source = load_source((header + "\n".join(rows) + "\n4 0 1 2 3\n").encode(), "ply")
    attributes = source.attributes
    assert source.mesh.face_count == 2 and attributes.groups[0].colors
    np.testing.assert_array_equal(attributes.normals, [[0, 0, 1]] * 4)
    np.testing.assert_array_equal(attributes.uvs[0], [[0, 1], [1, 1], [1, 0], [0, 0]])  # V down
    np.testing.assert_allclose(attributes.colors[3, :3], srgb_to_linear(np.full(3, 128 / 255)))
    assert np.array_equal(attributes.vertex[attributes.corners], source.mesh.faces)
