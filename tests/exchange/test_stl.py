"""STL reader: binary and ASCII triangle soups in facet order, truncation."""

import struct

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import InvalidGeometryError, MeshParseError, MeshTooLargeError
from neural_shdf.mesh_io import load_mesh


@pytest.mark.parametrize("file_type", ["stl", "stl_ascii"])
def test_soup_keeps_facet_order_and_own_vertices(file_type):
    box = trimesh.creation.box()
    data = box.export(file_type=file_type)
    mesh = load_mesh(data.encode() if isinstance(data, str) else data, "stl")
    assert mesh.face_count == mesh.input_face_count == 12
    assert mesh.faces.tolist() == np.arange(36).reshape(12, 3).tolist()
    np.testing.assert_allclose(mesh.vertices[mesh.faces], box.vertices[box.faces], atol=1e-6)


def test_binary_with_solid_header_and_trailing_bytes():
    triangle = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0)
    header = b"solid but actually binary".ljust(80, b" ")
    data = header + struct.pack("<I", 1) + triangle
    assert load_mesh(data, "stl").faces.tolist() == [[0, 1, 2]]
    assert load_mesh(data + b"\x00\x00", "stl").face_count == 1  # trailing padding ignored


def test_truncated_binary_is_a_parse_error():
    data = trimesh.creation.box().export(file_type="stl")
    with pytest.raises(MeshParseError, match="truncated"):
        load_mesh(data[:-20], "stl")
    with pytest.raises(MeshParseError, match="too short"):
        load_mesh(data[:50], "stl")


def test_ascii_with_missing_vertex_is_a_parse_error():
    text = trimesh.creation.box().export(file_type="stl_ascii")
    broken = text.replace("vertex", "vurtex", 1)
    with pytest.raises(MeshParseError, match="facets"):
        load_mesh(broken.encode(), "stl")


def test_ascii_cut_at_a_facet_boundary_is_truncated():
    text = trimesh.creation.box().export(file_type="stl_ascii")
    cut = text[: text.rindex("endfacet") + len("endfacet\n")]
    with pytest.raises(MeshParseError, match="endsolid"):
        load_mesh(cut.encode(), "stl")


def test_only_degenerate_facets_is_invalid():
    triangle = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 2, 0, 0, 0)
    data = b" " * 80 + struct.pack("<I", 2) + triangle * 2
    with pytest.raises(InvalidGeometryError, match="zero area"):
        load_mesh(data, "stl")


def test_nan_coordinate_is_invalid():
    triangle = struct.pack("<12fH", 0, 0, 1, 0, 0, float("nan"), 1, 0, 0, 0, 1, 0, 0)
    with pytest.raises(InvalidGeometryError, match="NaN"):
        load_mesh(b" " * 80 + struct.pack("<I", 1) + triangle, "stl")


def test_max_faces():
    with pytest.raises(MeshTooLargeError):
        load_mesh(trimesh.creation.box().export(file_type="stl"), "stl", max_faces=11)


def _binary_with_count(count: int) -> tuple[bytes, int]:
    data = bytearray(trimesh.creation.icosphere(1).export(file_type="stl"))
    facets = struct.unpack_from("<I", data, 80)[0]
    data[80:84] = struct.pack("<I", count)
    return bytes(data), facets


@pytest.mark.parametrize("declared", ["half", "zero"])
def test_header_count_below_the_file_size_reads_every_facet(declared, caplog):
    facets = 80
    data, actual = _binary_with_count(facets // 2 if declared == "half" else 0)
    assert actual == facets
    mesh = load_mesh(data, "stl")
    assert mesh.face_count == mesh.input_face_count == facets
    assert "reading 80" in caplog.text


def test_extra_bytes_that_are_not_whole_facets_are_refused():
    data, _ = _binary_with_count(40)
    with pytest.raises(MeshParseError, match="not a whole number of 50-byte facets"):
        load_mesh(data + bytes(20), "stl")


def test_ascii_with_byte_order_mark_and_odd_whitespace():
    text = trimesh.creation.box().export(file_type="stl_ascii")
    text = text.replace("vertex", "\tVERTEX  ").replace("\n", "\r\n")
    mesh = load_mesh(b"\xef\xbb\xbf" + text.encode(), "stl")
    assert mesh.face_count == 12
