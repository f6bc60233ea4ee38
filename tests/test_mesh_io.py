"""load_mesh front door: format detection, typed errors for any bad input, fuzzing."""

import contextlib

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neural_shdf.errors import MeshError, MeshParseError, MeshTooLargeError, UnsupportedFormatError
from neural_shdf.mesh_io import SUPPORTED_FORMATS, detect_format, load_mesh, sniff_format

JPEG_LIKE = b"\xff\xd8\xff\xe0\x00\x10JFIF\x00\x01\x01" + bytes(range(256)) * 4


def _valid_files() -> dict[str, bytes]:
    """A small valid file of every format, all encoding the same icosphere."""
    sphere = trimesh.creation.icosphere(subdivisions=1)
    files = {}
    for name, file_type in [("obj", "obj"), ("off", "off"), ("ply", "ply"), ("stl", "stl"),
                            ("glb", "glb"), ("gltf", "gltf")]:  # fmt: skip
        data = sphere.export(file_type=file_type)
        if isinstance(data, dict):  # trimesh writes .gltf as several files; embed instead
            continue
        files[name] = data.encode() if isinstance(data, str) else data
    files["gltf"] = _embedded_gltf(files["glb"])
    return files


def _embedded_gltf(glb: bytes) -> bytes:
    import base64
    import json
    import struct

    json_length = struct.unpack_from("<I", glb, 12)[0]
    doc = json.loads(glb[20 : 20 + json_length])
    binary = glb[20 + json_length + 8 :]
    doc["buffers"][0]["uri"] = (
        "data:application/octet-stream;base64,"
        + base64.b64encode(binary[: doc["buffers"][0]["byteLength"]]).decode()
    )
    return json.dumps(doc).encode()


VALID = _valid_files()


def test_supported_formats_and_detection():
    assert set(SUPPORTED_FORMATS) == {
        "obj",
        "off",
        "ply",
        "stl",
        "glb",
        "gltf",
        "usd",
        "usda",
        "usdc",
        "usdz",
    }
    assert detect_format("a/b/Model.OBJ") == "obj"
    assert detect_format("scan.ply") == "ply"
    with pytest.raises(UnsupportedFormatError, match="no file extension"):
        detect_format("README")
    with pytest.raises(UnsupportedFormatError, match="supported: obj"):
        detect_format("scene.3ds")


@pytest.mark.parametrize("name", sorted(VALID))
def test_every_format_loads_the_same_triangles(name):
    sphere = trimesh.creation.icosphere(subdivisions=1)
    mesh = load_mesh(VALID[name], name)
    assert mesh.face_count == mesh.input_face_count == len(sphere.faces)
    np.testing.assert_allclose(mesh.vertices[mesh.faces], sphere.vertices[sphere.faces], atol=1e-6)


@pytest.mark.parametrize("name", sorted(VALID))
def test_content_sniffing_when_no_type_is_given(name):
    expected = {"obj": None}.get(name, name)
    assert sniff_format(VALID[name]) == expected


def test_bytes_without_type_that_cannot_be_sniffed():
    with pytest.raises(UnsupportedFormatError, match="file_type"):
        load_mesh(VALID["obj"])


def test_path_and_bytes_give_the_same_mesh(tmp_path):
    path = tmp_path / "sphere.PLY"
    path.write_bytes(VALID["ply"])
    assert load_mesh(path).content_hash() == load_mesh(VALID["ply"], "ply").content_hash()
    assert load_mesh(str(path), ".ply").face_count == 80


def test_missing_file_and_unknown_type(tmp_path):
    with pytest.raises(MeshParseError, match="cannot read"):
        load_mesh(tmp_path / "absent.obj")
    with pytest.raises(UnsupportedFormatError, match="3ds"):
        load_mesh(b"anything", "3ds")


@pytest.mark.parametrize("name", SUPPORTED_FORMATS)
@pytest.mark.parametrize("data", [b"", b"  \n\t "], ids=["empty", "whitespace"])
def test_empty_input_is_a_parse_error(name, data):
    with pytest.raises(MeshParseError, match="empty"):
        load_mesh(data, name)


@pytest.mark.parametrize("name", SUPPORTED_FORMATS)
def test_not_a_mesh_is_a_parse_error(name):
    with pytest.raises(MeshParseError):
        load_mesh(JPEG_LIKE, name)


@pytest.mark.parametrize("name", sorted(VALID))
def test_truncated_files_are_rejected_with_mesh_errors(name):
    data = VALID[name]
    for fraction in (0.1, 0.5, 0.9):
        try:
            mesh = load_mesh(data[: int(len(data) * fraction)], name)
        except MeshError:
            continue
        # Text formats cut at a line may still be a (smaller) valid mesh, never a bigger one.
        assert name in ("obj", "stl") and mesh.face_count < 80


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.binary(max_size=600), name=st.sampled_from(SUPPORTED_FORMATS))
def test_random_bytes_raise_only_mesh_errors(data, name):
    with contextlib.suppress(MeshError):
        load_mesh(data, name)


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    name=st.sampled_from(sorted(VALID)),
    edits=st.lists(st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=6),
    cut=st.floats(0.05, 1.0),
)
def test_corrupted_valid_files_raise_only_mesh_errors(name, edits, cut):
    data = bytearray(VALID[name])
    for position, value in edits:
        data[min(int(position * len(data)), len(data) - 1)] = value
    try:
        mesh = load_mesh(bytes(data[: max(1, int(cut * len(data)))]), name)
    except MeshError:
        return
    assert np.isfinite(mesh.vertices).all()
    assert mesh.faces.min() >= 0 and mesh.faces.max() < len(mesh.vertices)


def _polygon_files() -> dict[str, bytes]:
    """One quad, one triangle and one pentagon, written in each polygon format."""
    vertices = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0.5, 0]]
    polygons = [[0, 1, 2, 3], [1, 4, 2], [0, 1, 4, 2, 3]]
    v_lines = [" ".join(map(str, v)) for v in vertices]
    obj = [f"v {line}" for line in v_lines] + [
        "f " + " ".join(str(i + 1) for i in p) for p in polygons
    ]
    off = ["OFF", f"{len(vertices)} {len(polygons)} 0", *v_lines]
    off += [f"{len(p)} " + " ".join(map(str, p)) for p in polygons]
    ply = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property double x",
           "property double y", "property double z", f"element face {len(polygons)}",
           "property list uchar int vertex_indices", "end_header", *v_lines]  # fmt: skip
    ply += [f"{len(p)} " + " ".join(map(str, p)) for p in polygons]
    return {name: ("\n".join(lines) + "\n").encode() for name, lines in
            [("obj", obj), ("off", off), ("ply", ply)]}  # fmt: skip


def test_polygon_formats_agree_on_triangles_and_origins():
    meshes = {name: load_mesh(data, name) for name, data in _polygon_files().items()}
    hashes = {mesh.content_hash() for mesh in meshes.values()}
    assert len(hashes) == 1
    assert meshes["obj"].face_origin.tolist() == [0, 0, 1, 2, 2, 2]


def test_open_non_manifold_multi_shell_degenerate_mesh_loads_whole():
    text = (
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\n"  # fan of 3 faces on edge 1-2
        "v 5 5 5\nv 6 5 5\nv 5 6 5\n"  # a second shell
        "f 1 2 3\nf 2 1 4\nf 1 2 5\nf 6 7 8\nf 6 6 7\n"  # last face degenerate
    )
    mesh = load_mesh(text.encode(), "obj")
    assert mesh.face_count == mesh.input_face_count == 5
    assert mesh.faces.tolist() == [[0, 1, 2], [1, 0, 3], [0, 1, 4], [5, 6, 7], [5, 5, 6]]


def _big_polygons_ply(polygons: int, sides: int) -> bytes:
    """Binary PLY of ``polygons`` rows of ``sides`` uchar-indexed vertices (tiny per face)."""
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {sides}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {polygons}\nproperty list uchar uchar vertex_indices\nend_header\n"
    ).encode()
    angles = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros(sides)], 1).astype("<f4")
    row = bytes([sides]) + bytes(range(sides))
    return header + ring.tobytes() + row * polygons


@pytest.mark.parametrize("kind", ["vertices", "triangles"])
def test_limits_apply_to_every_format_before_the_arrays_are_made(kind):
    files = _valid_files()
    for name, data in files.items():
        limits = {"max_vertices": 2} if kind == "vertices" else {"max_faces": 1}
        with pytest.raises(MeshTooLargeError) as error:
            load_mesh(data, name, **limits)
        assert error.value.limit == ("max_vertices" if kind == "vertices" else "max_faces")
        assert f"({error.value.limit})" in str(error.value)


def test_polygons_are_budgeted_by_the_triangles_they_fan_into():
    data = _big_polygons_ply(polygons=1000, sides=255)  # 1000 faces, 253,000 triangles
    with pytest.raises(MeshTooLargeError, match="253000 triangles"):
        load_mesh(data, "ply", max_faces=100_000)
    assert load_mesh(data, "ply", max_faces=253_000).face_count == 253_000


def test_coordinates_too_large_for_float32_geometry_are_named():
    from neural_shdf.errors import InvalidGeometryError

    data = b"v 1e300 0 0\nv 0 1e300 0\nv 0 0 1e300\nf 1 2 3\n"
    with pytest.raises(InvalidGeometryError, match=r"as large as 1e\+300 .*rescale"):
        load_mesh(data, "obj")


def test_tiny_triangles_load_and_collapsed_ones_say_why():
    from neural_shdf.errors import InvalidGeometryError

    tiny = b"v 0 0 0\nv 1e-12 0 0\nv 0 1e-12 0\nf 1 2 3\n"
    assert load_mesh(tiny, "obj").face_count == 1  # small is not degenerate: relative limit
    point = b"v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n"
    with pytest.raises(InvalidGeometryError, match="corners are at one point"):
        load_mesh(point, "obj")


def test_text_formats_report_the_whole_file_s_counts_before_parsing():
    obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" + b"f 1 2 3\n" * 5000
    with pytest.raises(MeshTooLargeError, match="has 5000 faces, more than the limit of 10 "):
        load_mesh(obj, "obj", max_faces=10)
    off = b"OFF\n3 5000 0\n0 0 0\n1 0 0\n0 1 0\n" + b"3 0 1 2\n" * 5000
    with pytest.raises(MeshTooLargeError, match="has 5000 faces"):
        load_mesh(off, "off", max_faces=10)
    with pytest.raises(MeshParseError, match="truncated"):
        load_mesh(b"OFF\n3 5000000 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "off", max_faces=10)
