"""Write an unwrapped mesh as OBJ: one ``f`` line per input face, UVs per corner."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from neural_shdf.mesh import TriangleMesh
from neural_shdf.unwrap import UvAtlas, input_face_corner_uvs


def write_obj_with_uvs(path: str | Path, mesh: TriangleMesh, atlas: UvAtlas) -> int:
    """Write ``obj_text_with_uvs`` to ``path``; returns how many polygons were split."""
    text, split = obj_text_with_uvs(mesh, atlas)
    Path(path).write_text(text)
    return split


def obj_text_with_uvs(mesh: TriangleMesh, atlas: UvAtlas) -> tuple[str, int]:
    """An OBJ with ``v``, ``vt`` and ``f v/vt`` lines, one ``f`` per input face in the
    input order, each polygon with its UVs per corner.

    A polygon a chart boundary runs through (its triangles disagree on a shared corner's
    UV) is written as its triangles, in place. Returns the text and how many polygons
    were split so.
    Input faces that produced no triangle are left out.
    """
    polygons, polygon_uvs, consistent = input_face_corner_uvs(mesh, atlas.corner_uvs)
    lines = ["# neural-shdf unwrap: one f line per input face (split polygons: their triangles)"]
    lines.extend(f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in mesh.vertices)
    uv_rows: list[NDArray[np.float64]] = []  # (u, v) rows
    faces_text = []
    offset = 0
    starts = np.searchsorted(mesh.face_origin, np.arange(mesh.input_face_count))
    for face, ring in enumerate(polygons):
        count = len(ring)
        if count == 0:
            continue
        if consistent[face]:
            base = len(uv_rows)
            uv_rows.extend(polygon_uvs[offset : offset + count])
            faces_text.append(
                "f " + " ".join(f"{v + 1}/{base + k + 1}" for k, v in enumerate(ring))
            )
        else:
            first = int(starts[face])
            for triangle in range(first, first + count - 2):
                base = len(uv_rows)
                uv_rows.extend(atlas.corner_uvs[triangle])
                faces_text.append(
                    "f "
                    + " ".join(
                        f"{v + 1}/{base + k + 1}" for k, v in enumerate(mesh.faces[triangle])
                    )
                )
        offset += count
    lines.extend(f"vt {u:.9g} {v:.9g}" for u, v in uv_rows)
    lines.extend(faces_text)
    return "\n".join(lines) + "\n", int((~consistent).sum())
