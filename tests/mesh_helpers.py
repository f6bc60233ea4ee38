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


def ball_with_arm(sections: int = 32, rings: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, triangles) of one closed surface of revolution about x: a ball of radius
    1 and an arm of radius 0.25 out to x = 3, the neck at x ~ 0.97 (two parts)."""
    xs = np.unique(
        np.round(np.r_[np.linspace(-0.999, 0.999, rings)[:-1], np.linspace(0.97, 3.0, rings)], 6)
    )
    radius = np.maximum(np.sqrt(np.clip(1.0 - xs**2, 0.0, None)), 0.25 * (xs > 0))
    radius = np.maximum(radius, 1e-3)
    turn = np.linspace(0.0, 2.0 * np.pi, sections, endpoint=False)
    circles = np.stack(
        [
            np.repeat(xs, sections),
            (radius[:, None] * np.cos(turn)[None, :]).reshape(-1),
            (radius[:, None] * np.sin(turn)[None, :]).reshape(-1),
        ],
        axis=1,
    )
    count = len(xs)
    vertices = np.vstack([circles, [[xs[0], 0.0, 0.0], [xs[-1], 0.0, 0.0]]])
    ring = np.arange(count - 1)[:, None] * sections
    step = np.arange(sections)[None, :]
    a, b = ring + step, ring + (step + 1) % sections
    c, d = a + sections, b + sections
    sides = np.concatenate(
        [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([b, d, c], -1).reshape(-1, 3)]
    )
    first, last = count * sections, count * sections + 1
    around = np.arange(sections)
    start_cap = np.stack([np.full(sections, first), (around + 1) % sections, around], axis=1)
    end_ring = (count - 1) * sections
    end_cap = np.stack(
        [np.full(sections, last), end_ring + around, end_ring + (around + 1) % sections], axis=1
    )
    return vertices, np.concatenate([sides, start_cap, end_cap]).astype(np.int64)


def relisted(
    vertices: np.ndarray, faces: np.ndarray, rng: np.random.Generator, turn: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same triangles listed another way: vertices and faces in a random order and,
    with ``turn``, each triangle starting at another corner (winding kept). Returns
    (vertices, faces, input face of each face)."""
    new_vertex = rng.permutation(len(vertices))
    moved = np.empty_like(vertices)
    moved[new_vertex] = vertices
    origin = rng.permutation(len(faces))
    listed = new_vertex[faces[origin]]
    if turn:
        listed = np.roll(listed, 1, axis=1)
        listed[::2] = np.roll(listed[::2], 1, axis=1)
    return moved, listed, origin
