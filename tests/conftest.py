"""Shared fixtures: repository paths, the shared data folder, and small test meshes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import trimesh

from neural_shdf.mesh import TriangleMesh

REPO_ROOT = Path(__file__).resolve().parents[1]


def as_triangle_mesh(mesh: trimesh.Trimesh) -> TriangleMesh:
    """A trimesh as a TriangleMesh, vertices and faces in trimesh's order."""
    return TriangleMesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root (the folder holding pyproject.toml)."""
    return REPO_ROOT


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` relative to the repository root; skips the test when absent."""
    path = (REPO_ROOT / ".." / "shared" / "data").resolve()
    if not path.is_dir():
        pytest.skip(f"shared data folder {path} is absent")
    return path


@pytest.fixture(scope="session")
def psb_off(shared_data: Path) -> Callable[[int], Path]:
    """Path of a psb-dev benchmark mesh by id (``psb_off(1)``); skips when it is absent."""

    def path_of(model_id: int) -> Path:
        path = shared_data / "psb-dev" / "off" / f"{model_id}.off"
        if not path.is_file():
            pytest.skip(f"{path} is absent")
        return path

    return path_of


@pytest.fixture
def mesh_from_trimesh() -> Callable[[trimesh.Trimesh], TriangleMesh]:
    """Converter from trimesh.Trimesh to TriangleMesh (order kept)."""
    return as_triangle_mesh


@pytest.fixture
def box_mesh() -> TriangleMesh:
    """Axis-aligned box with extents (1, 1, 1) centred at the origin: 8 vertices, 12 faces."""
    return as_triangle_mesh(trimesh.creation.box(extents=(1.0, 1.0, 1.0)))


@pytest.fixture
def sphere_mesh() -> TriangleMesh:
    """Unit icosphere, 2 subdivisions: 162 vertices, 320 faces, closed and manifold."""
    return as_triangle_mesh(trimesh.creation.icosphere(subdivisions=2, radius=1.0))


@pytest.fixture
def capsule_mesh() -> TriangleMesh:
    """Capsule of radius 0.5 and height 2 along z: thin middle, round caps (one shell)."""
    return as_triangle_mesh(trimesh.creation.capsule(height=2.0, radius=0.5, count=(16, 16)))


@pytest.fixture
def two_box_mesh() -> TriangleMesh:
    """Two disjoint unit boxes, centred at x = -2 and x = +2 (two shells, 24 faces).

    Faces 0..11 belong to the left box, 12..23 to the right one.
    """
    left = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    right = left.copy()
    left.apply_translation((-2.0, 0.0, 0.0))
    right.apply_translation((2.0, 0.0, 0.0))
    vertices = np.concatenate([left.vertices, right.vertices])
    faces = np.concatenate([left.faces, right.faces + len(left.vertices)])
    return TriangleMesh(vertices, faces)


@pytest.fixture
def open_mesh() -> TriangleMesh:
    """An open 4x4 grid of squares in the z = 0 plane (32 triangles, has a boundary)."""
    grid = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0), indexing="ij"), -1).reshape(-1, 2)
    vertices = np.column_stack([grid, np.zeros(len(grid))])
    index = np.arange(25).reshape(5, 5)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return TriangleMesh(vertices, faces)
