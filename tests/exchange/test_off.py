"""OFF reader: header variants, polygons, truncation, the psb-dev benchmark files."""

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import MeshParseError, MeshTooLargeError, UnsupportedFormatError
from neural_shdf.mesh_io import load_mesh, sniff_format


def test_polygons_comments_and_counts_on_header_line():
    text = (
        "OFF 5 3 0  # counts on the header line\n"
        "# a comment line\n"
        "0 0 0\n1 0 0\n1 1 0\n0 1 0\n\n2 0.5 0\n"
        "4 0 1 2 3\n3 1 4 2\n5 0 1 4 2 3\n"
    )
    mesh = load_mesh(text.encode(), "off")
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 2], [0, 1, 4], [0, 4, 2], [0, 2, 3]]
    assert mesh.face_origin.tolist() == [0, 0, 1, 2, 2, 2]
    assert mesh.input_face_count == 3


def test_coff_with_vertex_and_face_colours():
    text = "COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n0 1 0 0 0 255 255\n3 0 1 2 9 9 9\n"
    mesh = load_mesh(text.encode(), "off")
    np.testing.assert_array_equal(mesh.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert mesh.faces.tolist() == [[0, 1, 2]]


@pytest.mark.parametrize(
    ("text", "error", "words"),
    [
        ("OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n", MeshParseError, "truncated"),
        ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n4 0 1 2\n", MeshParseError, "declares 4"),
        ("OFF\n", MeshParseError, "counts"),
        ("PFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", MeshParseError, "start with 'OFF'"),
        ("4OFF\n3 1 0\n0 0 0 0\n1 0 0 0\n0 1 0 0\n3 0 1 2\n", UnsupportedFormatError, "4OFF"),
        ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 x\n", MeshParseError, "integers"),
    ],
)
def test_bad_off_raises_typed_error(text, error, words):
    with pytest.raises(error, match=words):
        load_mesh(text.encode(), "off")


def test_psb_file_matches_header_and_trimesh(psb_off):
    path = psb_off(1)
    header = path.read_text().split("\n", 2)[1].split()
    mesh = load_mesh(path)
    assert mesh.face_count == int(header[1]) == mesh.input_face_count
    assert len(mesh.vertices) == int(header[0])
    reference = trimesh.load(path, process=False)
    np.testing.assert_array_equal(mesh.faces, reference.faces)
    np.testing.assert_allclose(mesh.vertices, reference.vertices)


def test_max_faces_checked_from_header(psb_off):
    with pytest.raises(MeshTooLargeError):
        load_mesh(psb_off(1), max_faces=100)


def test_psb_segmentations_have_one_label_per_input_face(psb_off, shared_data):
    mesh = load_mesh(psb_off(1))
    for seg in [shared_data / "psb-dev" / "cgal" / "1.seg", shared_data / "psb-dev" / "seg" / "1"]:
        paths = sorted(seg.glob("*.seg")) if seg.is_dir() else [seg]
        for path in paths[:2]:
            assert len(path.read_text().split()) == mesh.input_face_count


def test_byte_order_mark_is_skipped():
    text = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    mesh = load_mesh(b"\xef\xbb\xbf" + text.encode(), "off")
    assert mesh.faces.tolist() == [[0, 1, 2]]
    assert sniff_format(b"\xef\xbb\xbf" + text.encode()) == "off"


def test_face_errors_name_the_line():
    text = "OFF\n# made by hand\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n3 0 x 2\n"
    with pytest.raises(MeshParseError, match="OFF line 8: face 1"):
        load_mesh(text.encode(), "off")
