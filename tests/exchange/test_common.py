"""The readers' shared validation: the zero-area test is relative to the mesh's size."""

import numpy as np
import pytest

from neural_shdf.errors import InvalidGeometryError
from neural_shdf.mesh_io import load_mesh


def obj_text(vertices: np.ndarray, faces: np.ndarray) -> bytes:
    lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    return "\n".join(lines).encode()


TETRAHEDRON = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
TETRAHEDRON_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


@pytest.mark.parametrize("scale", [1e-15, 1e-9, 1.0, 1e9])
def test_a_mesh_of_any_size_loads(scale):
    mesh = load_mesh(obj_text(TETRAHEDRON * scale, TETRAHEDRON_FACES), "obj")
    assert mesh.face_count == 4
    expected = np.array([0.5, 0.5, 0.5, np.sqrt(3) / 2]) * scale**2
    np.testing.assert_allclose(mesh.normals_and_areas[1], expected, rtol=1e-12)
    assert np.all(np.linalg.norm(mesh.normals_and_areas[0], axis=1) > 0.99)


@pytest.mark.parametrize("scale", [1e-9, 1.0, 1e9])
def test_a_mesh_of_only_collinear_triangles_is_refused_at_any_size(scale):
    # Corners at exact multiples of one vector from the origin: collinear at every scale.
    line = np.array([[0, 0, 0], [1, 2, 3], [2, 4, 6], [4, 8, 12]], dtype=np.float64) * scale
    with pytest.raises(InvalidGeometryError, match="zero area.*on one line"):
        load_mesh(obj_text(line, np.array([[0, 1, 2], [0, 1, 3], [0, 0, 3]])), "obj")


def test_a_loaded_mesh_carries_the_degenerate_limit_it_was_checked_with():
    from neural_shdf.geometry import zero_area_limit

    mesh = load_mesh(obj_text(TETRAHEDRON * 3.0, TETRAHEDRON_FACES), "obj")
    assert "zero_area_limit" in mesh.__dict__  # seeded, not measured again
    assert mesh.zero_area_limit == zero_area_limit(mesh.vertices, mesh.faces)
