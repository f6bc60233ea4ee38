"""Small meshes several test modules build the same way."""

from __future__ import annotations

import numpy as np
import trimesh


def balls_and_bar(left_subdivisions: int, right_subdivisions: int) -> trimesh.Trimesh:
    """Two balls of different sizes (radius 1 and 0.6, 2.6 apart along x) joined by a thin
    bar: the parts a segmentation must find."""
    left = trimesh.creation.icosphere(subdivisions=left_subdivisions, radius=1.0)
    right = trimesh.creation.icosphere(subdivisions=right_subdivisions, radius=0.6)
    right.apply_translation([2.6, 0.0, 0.0])
    bar = trimesh.creation.cylinder(radius=0.2, height=1.4, sections=12)
    bar.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    bar.apply_translation([1.3, 0.0, 0.0])
    return trimesh.util.concatenate([left, bar, right])
