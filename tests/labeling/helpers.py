"""Small labelled meshes for the labeller's tests: dumbbells whose balls and neck are
the labels, in a few proportions and poses."""

from __future__ import annotations

import functools

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


@functools.lru_cache(maxsize=1)
def small_labeler_file() -> bytes:
    """A labeller of dumbbells (labels ``NECK`` "neck", ``BALL`` "ball") trained on two
    1,500-face examples without subdivided copies (a few seconds), as file bytes."""
    from neural_shdf.labeling import labeler_bytes, train_labeler

    examples = [labelled_dumbbell(1500, stretch, seed) for stretch, seed in ((1.0, None), (1.3, 1))]
    meshes, labels = zip(*examples, strict=True)
    return labeler_bytes(train_labeler(meshes, labels, ["neck", "ball"], augment=False))


def obj_of(mesh: TriangleMesh) -> bytes:
    """``mesh`` as OBJ text (its faces in order)."""
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in mesh.vertices.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces.tolist()]
    return ("\n".join(lines) + "\n").encode()
