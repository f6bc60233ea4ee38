"""OBJ reader: faces in file order, polygon fans, relative indices, typed errors."""

import numpy as np
import pytest

from neural_shdf.errors import InvalidGeometryError, MeshParseError, MeshTooLargeError
from neural_shdf.mesh_io import load_mesh

SQUARE_AND_MORE = """\
v 0 0 0
v 1 0 0
v 1 1 0
v 0 1 0
v 2 0.5 0
"""


def _load(text: str, **kwargs):
    return load_mesh(text.encode(), "obj", **kwargs)


def test_mixed_quads_triangles_and_pentagon_keep_input_order():
    mesh = _load(SQUARE_AND_MORE + "f 1 2 3 4\nf 2 5 3\nf 1 2 5 3 4\n")
    # Fans from each polygon's first vertex, contiguous, in file order.
    expected = [[0, 1, 2], [0, 2, 3], [1, 4, 2], [0, 1, 4], [0, 4, 2], [0, 2, 3]]
    assert mesh.faces.tolist() == expected
    assert mesh.face_origin.tolist() == [0, 0, 1, 2, 2, 2]
    assert mesh.input_face_count == 3
    # A per-triangle labelling that is constant per polygon maps back exactly.
    labels = np.array([7, 7, 3, 5, 5, 5])
    assert mesh.labels_to_input_faces(labels).tolist() == [7, 3, 5]


def test_groups_and_materials_interleaved_do_not_regroup_faces():
    vertices = "".join(f"v {i} {i * i % 7} {i % 3}\n" for i in range(12))
    text = (
        vertices
        + "g a\nusemtl red\nf 1 2 3\n"
        + "g b\nusemtl blue\nf 4 5 6\n"
        + "g a\nusemtl red\nf 7 8 9\n"
        + "o other\nusemtl blue\ns 1\nf 10 11 12\n"
    )
    mesh = _load(text)
    assert mesh.faces.tolist() == [[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11]]
    assert mesh.face_origin.tolist() == [0, 1, 2, 3]


def test_negative_indices_are_relative_to_vertices_so_far():
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 1\nv 1 0 1\nv 0 1 1\nf -3/1/1 -2//2 -1/3\n"
    mesh = _load(text)
    assert mesh.faces.tolist() == [[0, 1, 2], [3, 4, 5]]


def test_texture_and_normal_references_and_extra_records_are_ignored():
    text = (
        "# comment\nmtllib x.mtl\nv 0 0 0 1.0\nv 1 0 0 1 0.5 0.5 0.5\nv 0 1 0\n"
        "vt 0 0\nvn 0 0 1\nl 1 2\np 3\nf 1/1/1 2/1/1 3/1/1\n"
    )
    mesh = _load(text)
    assert mesh.faces.tolist() == [[0, 1, 2]]
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])


def test_duplicate_vertices_are_kept_not_merged():
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 4 5\n"
    mesh = _load(text)
    assert mesh.vertices.shape == (5, 3)
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 3, 4]]


def test_face_with_two_vertices_counts_as_input_face_without_triangle():
    mesh = _load(SQUARE_AND_MORE + "f 1 2 3\nf 1 2\nf 2 5 3\n")
    assert mesh.face_origin.tolist() == [0, 2]
    assert mesh.input_face_count == 3
    assert mesh.labels_to_input_faces(np.array([4, 6])).tolist() == [4, -1, 6]


def test_degenerate_faces_stay_next_to_usable_ones():
    mesh = _load(SQUARE_AND_MORE + "f 1 1 2\nf 1 2 3\nf 1 2 2\n")
    assert mesh.faces.tolist() == [[0, 0, 1], [0, 1, 2], [0, 1, 1]]


def test_line_continuation_joins_records():
    mesh = _load("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\n 3\n")
    assert mesh.faces.tolist() == [[0, 1, 2]]


@pytest.mark.parametrize(
    ("text", "error", "words"),
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", InvalidGeometryError, "start at 1"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", InvalidGeometryError, "do not exist"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", InvalidGeometryError, "do not exist"),
        ("v 0 0 nan\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", InvalidGeometryError, "NaN"),
        ("v 0 0 inf\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", InvalidGeometryError, "infinite"),
        ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\nf 1 1 2\n", InvalidGeometryError, "zero area"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", InvalidGeometryError, "no triangles"),
        ("v 0 0\nf 1 2 3\n", MeshParseError, "3 coordinates"),
        ("v 0 0 x\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", MeshParseError, "not all numbers"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 b 3\n", MeshParseError, "not an integer"),
        ("hello world\nthis is text\n", MeshParseError, "not an OBJ"),
    ],
)
def test_bad_obj_raises_typed_error(text, error, words):
    with pytest.raises(error, match=words):
        _load(text)


def test_binary_content_is_not_obj():
    with pytest.raises(MeshParseError, match="binary"):
        load_mesh(b"\xff\xd8\xff\xe0\x00\x10JFIF\x00" + bytes(range(256)), "obj")


def test_bad_index_error_names_the_input_face():
    with pytest.raises(InvalidGeometryError, match="face 1 of the file"):
        _load(SQUARE_AND_MORE + "f 1 2 3 4\nf 1 2 3 9\n")


def test_max_faces_counts_triangles():
    text = SQUARE_AND_MORE + "f 1 2 3 4\nf 2 5 3\n"
    assert _load(text, max_faces=3).face_count == 3
    with pytest.raises(MeshTooLargeError, match="limit of 2"):
        _load(text, max_faces=2)


def test_human_seg_labels_match_input_faces(shared_data):
    name = "MIT_animation__meshes_bouncing__meshes__mesh_0000"
    mesh_path = shared_data / "human-seg" / "train" / f"{name}.obj"
    label_path = shared_data / "human-seg" / "face_labels" / f"{name}.txt"
    if not (mesh_path.is_file() and label_path.is_file()):
        pytest.skip("human-seg sample is absent")
    labels = label_path.read_text().split()
    assert load_mesh(mesh_path).input_face_count == len(labels)


def test_byte_order_mark_keeps_the_vertex_on_line_one():
    # With a spare vertex at the end, dropping line 1 would shift every face silently.
    text = "v 5 5 5\nv 1 0 0\nv 0 1 0\nv 9 9 9\nf 1 2 3\n"
    mesh = load_mesh(b"\xef\xbb\xbf" + text.encode(), "obj")
    np.testing.assert_array_equal(mesh.vertices[0], [5, 5, 5])
    assert mesh.faces.tolist() == [[0, 1, 2]]


def test_comments_after_records_are_ignored():
    mesh = _load("v 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nf 1 2 3 # first\nf 1 3 2#second\n")
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 2, 1]]
    np.testing.assert_array_equal(mesh.vertices[0], [0, 0, 0])


def test_records_without_a_polygon_keep_their_line_in_per_face_outputs():
    # A bare f, a point and an edge record are input faces 1..3, without triangles.
    mesh = _load(SQUARE_AND_MORE + "f 1 2 3\nf\nf 1\nf 2 3\nf 2 5 3\n")
    assert mesh.input_face_count == 5
    assert mesh.face_origin.tolist() == [0, 4]
    assert mesh.labels_to_input_faces(np.array([4, 6])).tolist() == [4, -1, -1, -1, 6]


def test_errors_name_the_line():
    with pytest.raises(InvalidGeometryError, match="OBJ line 7: .*face 1 of the file"):
        _load(SQUARE_AND_MORE + "f 1 2 3\nf 1 2 9\n")
    with pytest.raises(MeshParseError, match="OBJ line 2: .*'v 0,5 0 0'"):
        _load("v 0 0 0\nv 0,5 0 0\nv 0 1 0\nf 1 2 3\n")


def test_uvs_normals_and_materials_follow_each_corner_when_attributes_are_read():
    """Each corner's own vt/vn (also negative and missing ones), one attribute vertex per
    distinct v/vt/vn, one face group per material and set of attributes."""
    from neural_shdf.mesh_io import load_source

    text = (
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\nvn 0 0 -1\n"
        "usemtl wood\nf 1/1/1 2/2/1 3/3/1 4/4/1\n"
        "f 1/-4/-1 3/-2/-1 4/-1/-1  # relative indices\n"
        "usemtl metal\nf 1 2 3\nf 2/9 3/3 4/4\n"
    )
    source = load_source(text.encode(), "obj")
    attributes = source.attributes
    assert source.mesh.face_count == 5
    uv = attributes.uvs[0][attributes.corners]
    normals = attributes.normals[attributes.corners]
    np.testing.assert_array_equal(uv[0], [[0, 1], [1, 1], [1, 0]])  # vt 1, 2, 3 with V down
    np.testing.assert_array_equal(normals[2], [[0, 0, -1]] * 3)
    np.testing.assert_array_equal(uv[2], [[0, 1], [1, 0], [0, 0]])
    groups = [attributes.groups[g] for g in attributes.face_group]
    assert [(g.material, g.uv_sets, g.normals) for g in groups] == [
        (0, 1, True), (0, 1, True), (0, 1, True), (1, 0, False), (1, 0, False),
    ]  # fmt: skip
    assert [m["name"] for m in attributes.materials.materials] == ["wood", "metal"]
    assert not attributes.materials.defined  # names only: the .mtl is not read
    assert np.array_equal(attributes.vertex[attributes.corners], source.mesh.faces)
