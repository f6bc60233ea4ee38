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


def _png(color: tuple[int, int, int]) -> bytes:
    import io

    from PIL import Image

    out = io.BytesIO()
    Image.new("RGB", (4, 4), color).save(out, format="PNG")
    return out.getvalue()


MTL = """\
# written by hand: every statement the reader turns into glTF
newmtl wood
Kd 0.8 0.8 0.8
Ns 250
d 1
map_Kd -s 1 1 1 -clamp on tex/wood.png
newmtl glass
Kd 0.1 0.2 0.3
Ns 1000
Tr 0.25
Ke 0.5 0 2
newmtl metal
Kd 0.5 0.5 0.5
Pr 0.2
Pm 1
map_Kd tex/metal.tga
"""

MTL_OBJ = (
    "mtllib mats.mtl\n"
    "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\n"
    "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
    "f 1 2 5\n"  # no material yet: part colours
    "usemtl wood\nf 1/1 2/2 3/3 4/4\n"
    "f 1 5 6\n"  # wood without UVs: the untextured copy
    "usemtl glass\nf 2 3 6\n"
    "usemtl metal\nf 3 4 6\n"
    "usemtl nowhere\nf 4 1 5\n"
)


def _obj_with_library(folder):
    (folder / "tex").mkdir()
    (folder / "tex" / "wood.png").write_bytes(_png((200, 120, 40)))
    (folder / "tex" / "metal.tga").write_bytes(b"\0\0\2" + bytes(15))  # not PNG or JPEG
    (folder / "mats.mtl").write_text(MTL)
    path = folder / "model.obj"
    path.write_text(MTL_OBJ)
    return path


def test_mtl_libraries_beside_an_obj_on_disk_become_gltf_materials(tmp_path):
    """Kd, Ns (as roughness), d/Tr (opacity), Pr/Pm, Ke and map_Kd (a PNG beside the .mtl,
    its options skipped, -clamp kept) as glTF materials in usemtl order; faces without
    UVs get a copy without the texture; a name the library lacks is a white dielectric."""
    from neural_shdf.mesh_io import load_source

    path = _obj_with_library(tmp_path)
    source = load_source(path)
    materials = source.attributes.materials
    assert materials.defined
    by_name = {m["name"]: m for m in materials.materials[:4]}  # usemtl order; then copies
    wood = by_name["wood"]["pbrMetallicRoughness"]
    assert wood["baseColorTexture"] == {"index": 0}
    assert wood["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]  # the texture replaces Kd
    assert wood["roughnessFactor"] == pytest.approx(0.5)  # 1 - sqrt(250 / 1000)
    assert wood["metallicFactor"] == 0.0
    assert materials.image_data == (_png((200, 120, 40)),)
    assert materials.images == ({"mimeType": "image/png"},)
    assert materials.samplers == ({"wrapS": 33071, "wrapT": 33071},)
    glass = by_name["glass"]
    assert glass["pbrMetallicRoughness"]["baseColorFactor"] == pytest.approx([0.1, 0.2, 0.3, 0.75])
    assert glass["pbrMetallicRoughness"]["roughnessFactor"] == 0.0
    assert glass["alphaMode"] == "BLEND" and glass["emissiveFactor"] == [0.5, 0.0, 1.0]
    metal = by_name["metal"]["pbrMetallicRoughness"]
    assert "baseColorTexture" not in metal  # a TGA: glTF holds PNG and JPEG only
    assert (metal["roughnessFactor"], metal["metallicFactor"]) == (0.2, 1.0)
    assert by_name["nowhere"]["pbrMetallicRoughness"]["baseColorFactor"] == [1.0] * 4
    groups = [source.attributes.groups[g] for g in source.attributes.face_group]
    names = [materials.materials[g.material]["name"] if g.material >= 0 else None for g in groups]
    assert names == [None, "wood", "wood", "wood", "glass", "metal", "nowhere"]
    untextured = materials.materials[groups[3].material]
    assert groups[3].uv_sets == 0 and "baseColorTexture" not in untextured["pbrMetallicRoughness"]
    # Bytes alone (an upload): the names only, as before.
    from_bytes = load_source(path.read_bytes(), "obj").attributes.materials
    assert not from_bytes.defined
    assert [m["name"] for m in from_bytes.materials] == ["wood", "glass", "metal", "nowhere"]
    # A library that is not there: names only too.
    (tmp_path / "mats.mtl").unlink()
    assert not load_source(path).attributes.materials.defined


def test_parts_of_an_obj_with_its_library_pass_the_validator_and_read_back(tmp_path):
    from neural_shdf.exchange.gltf_writer import parts_glb
    from neural_shdf.mesh_io import load_source

    from .test_gltf_writer import _khronos_issues

    source = load_source(_obj_with_library(tmp_path))
    labels = (source.mesh.vertices[source.mesh.faces].mean(axis=1)[:, 2] > 0.5).astype(np.int64)
    data = parts_glb(source.mesh, labels, attributes=source.attributes)
    issues = _khronos_issues(tmp_path, {"mtl-parts.glb": data})["mtl-parts.glb"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]
    back = load_source(data, "glb").attributes
    assert back.materials.image_data == (_png((200, 120, 40)),)
    names = sorted({m["name"] for m in back.materials.materials})
    assert names == ["glass", "metal", "nowhere", "wood"]
    colored = [g.colors for g in back.groups if g.material < 0]
    assert colored and all(colored)  # the face without a material shows its part colour
    assert not any(g.colors for g in back.groups if g.material >= 0)


@pytest.mark.parametrize(
    ("statement", "expected"),
    [
        ("map_Kd wood.png", "wood.png"),
        ("map_Kd -o 0.5 0.5 -s 2 wood.png", "wood.png"),
        ("map_Kd -bm 1.0 -clamp off my wood.png", "my wood.png"),
        ("map_Kd -mm 0 1 -imfchan r C:\\textures\\wood.png", "C:\\textures\\wood.png"),
    ],
)
def test_texture_options_are_skipped_to_the_file_name(statement, expected):
    from neural_shdf.exchange.obj import _map_file, parse_mtl

    values = parse_mtl("newmtl a\n" + statement)["a"]["map_kd"]
    assert _map_file(values)[0] == expected
