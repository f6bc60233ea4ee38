"""Small labelled meshes for the labeller's tests: dumbbells whose balls and neck are
the labels, in a few proportions and poses."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment.synthetic import JUNCTION_Z, dumbbell

BALL, NECK = 5, 2


def labelled_dumbbell(
    faces: int = 1500, stretch: float = 1.0, seed: int | None = None
) -> tuple[TriangleMesh, np.ndarray]:
    """A dumbbell (``stretch`` along its axis, then a random rigid pose for ``seed``) and
    its labels per face: ``BALL`` on the balls, ``NECK`` on the neck."""
    mesh, _ = dumbbell(faces)
    vertices = np.asarray(mesh.vertices) * [1.0, 1.0, stretch]
    centre_z = np.asarray(mesh.triangles_center)[:, 2]
    labels = np.where(np.abs(centre_z) > JUNCTION_Z, BALL, NECK).astype(np.int64)
    if seed is not None:
        rotation = Rotation.random(random_state=seed).as_matrix()
        vertices = vertices @ rotation.T + np.random.default_rng(seed).normal(size=3)
    return TriangleMesh(vertices, np.asarray(mesh.faces)), labels
