"""A synthetic shape with a known segmentation, for tests and benchmarks.

The dumbbell: two balls of radius 1 centred at z = -2 and z = +2, joined by a
neck of radius ``NECK_RADIUS``; one closed surface of revolution. Its ShDF
stand-in is the local radius (what the ShDF measures up to a factor), with an
optional smooth ripple, normalised to [0, 1].
"""

from __future__ import annotations

from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray

from neural_shdf.geometry import split_region

NECK_RADIUS = 0.3
#: |z| where the neck meets a ball (the concave junctions).
JUNCTION_Z = 2.0 - float(np.sqrt(1.0 - NECK_RADIUS**2))


def dumbbell_radius(z: NDArray[Any]) -> NDArray[np.float64]:
    """Radius of the dumbbell at height ``z``."""
    z = np.asarray(z, dtype=np.float64)
    ball = np.sqrt(np.clip(1.0 - (np.abs(z) - 2.0) ** 2, 0.0, None))
    neck = np.where(np.abs(z) < 1.9, NECK_RADIUS, 0.0)
    radius: NDArray[np.float64] = np.maximum(ball, neck)
    return radius


def dumbbell(faces: int = 4000, ripple: float = 0.0) -> tuple[trimesh.Trimesh, NDArray[Any]]:
    """A dumbbell with about ``faces`` triangles and a synthetic ShDF in [0, 1]."""
    side = max(8, int(round(np.sqrt(faces / 2.0))))
    z = np.linspace(-3.0, 3.0, side + 1)
    radius = dumbbell_radius(z)
    radius[0] = radius[-1] = 0.0
    mesh = trimesh.creation.revolve(np.column_stack([radius, z]), sections=side)
    centre = mesh.triangles_center
    shdf = dumbbell_radius(centre[:, 2])
    if ripple:
        shdf = shdf + ripple * np.sin(3 * centre[:, 0]) * np.cos(2 * centre[:, 1])
    shdf = (shdf - shdf.min()) / (shdf.max() - shdf.min())
    return mesh, shdf


def split_top(
    mesh: trimesh.Trimesh, splits: int, share: float = 0.2
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """(vertices, faces, input face of each face) of ``mesh`` with the top ``share`` of its
    area (highest centroids first) split 1-to-``splits``**2 (``geometry.split_region``):
    the same surface with a finely tessellated detail on a coarser body."""
    top_first = np.argsort(-mesh.triangles_center[:, 2])
    detail = np.zeros(len(mesh.faces), dtype=bool)
    detail[top_first[np.cumsum(mesh.area_faces[top_first]) <= share * mesh.area]] = True
    return split_region(np.asarray(mesh.vertices), np.asarray(mesh.faces), detail, splits)
