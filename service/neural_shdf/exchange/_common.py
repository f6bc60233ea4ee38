"""Shared steps of every mesh reader: polygon triangulation, validation, error guard."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.constants import AREA_EPS, MAX_COORDINATE
from neural_shdf.errors import (
    InvalidGeometryError,
    MeshError,
    MeshParseError,
    MeshTooLargeError,
)
from neural_shdf.geometry import zero_area_limit
from neural_shdf.mesh import TriangleMesh


@dataclass(frozen=True)
class MeshLimits:
    """Size budgets a reader checks before allocating what they bound (None: no limit).

    Attributes:
        max_faces: triangles after triangulation and glTF instancing (and input faces).
        max_vertices: vertices, counting every glTF instance of a mesh's vertices.
    """

    max_faces: int | None = None
    max_vertices: int | None = None

    def check_faces(
        self, count: int, what: str = "faces", *, context: str = "", at_least: bool = False
    ) -> None:
        """MeshTooLargeError when ``count`` faces (or triangles) exceed ``max_faces``
        (``at_least``: the count is a lower bound, found while reading)."""
        _check(count, self.max_faces, "max_faces", what, context, at_least)

    def check_vertices(self, count: int, *, context: str = "", at_least: bool = False) -> None:
        """MeshTooLargeError when ``count`` vertices exceed ``max_vertices``."""
        _check(count, self.max_vertices, "max_vertices", "vertices", context, at_least)


def _check(
    count: int, maximum: int | None, limit: str, what: str, context: str, at_least: bool
) -> None:
    if maximum is not None and count > maximum:
        raise MeshTooLargeError(
            f"the mesh has {'at least ' if at_least else ''}{count} {what}{context}, more than "
            f"the limit of {maximum} {what} ({limit}); simplify (decimate) it before uploading",
            limit=limit,
            maximum=maximum,
            found=count,
        )


#: No limit at all (the readers' default).
NO_LIMITS = MeshLimits()

#: A reader turns file bytes into a mesh, honouring size limits.
Reader = Callable[[bytes, MeshLimits], TriangleMesh]


@contextmanager
def parse_guard(format_name: str) -> Iterator[None]:
    """Turn any unexpected exception while parsing into a MeshParseError naming the format."""
    try:
        yield
    except MeshError:
        raise
    except MemoryError as exc:
        raise MeshTooLargeError(
            f"the {format_name} file needs more memory than is available to load",
            limit="memory",
        ) from exc
    except Exception as exc:  # noqa: BLE001 - converting is the point of the guard
        detail = str(exc) or type(exc).__name__
        raise MeshParseError(
            f"could not parse the file as {format_name}: {detail}. "
            f"Check that it is a complete, valid {format_name} file."
        ) from exc


UTF8_BOM = b"\xef\xbb\xbf"
_UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")


def strip_bom(data: bytes) -> bytes:
    """The bytes without a leading UTF-8 byte-order mark (editors on Windows add one to
    text files; it is not part of the first record)."""
    return data[len(UTF8_BOM) :] if data.startswith(UTF8_BOM) else data


def decode_text(data: bytes, format_name: str) -> str:
    """Bytes of a text format as str, without a UTF-8 byte-order mark; UTF-16 text and
    binary content are parse errors with a clear message."""
    data = strip_bom(data)
    if data[:2] in _UTF16_BOMS:
        raise MeshParseError(
            f"the {format_name} file is UTF-16 text; save it as UTF-8 or ASCII text"
        )
    if b"\x00" in data[:65536]:
        raise MeshParseError(
            f"the file contains binary data, so it is not a text {format_name} file; "
            "check the file type"
        )
    return data.decode("latin-1")


def fan_triangulate(
    counts: NDArray[np.int64], flat_indices: NDArray[np.int64]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Triangles of polygons given as (counts, concatenated vertex indices).

    Polygon ``p`` with vertices ``v0..v{n-1}`` becomes the fan
    ``(v0, v1, v2), (v0, v2, v3), ..., (v0, v{n-2}, v{n-1})``; polygons with
    fewer than three vertices give no triangle. Returns ``(faces, face_origin)``
    with the triangles of each polygon contiguous and in input order.
    """
    counts = np.asarray(counts, dtype=np.int64)
    flat_indices = np.asarray(flat_indices, dtype=np.int64)
    if len(counts) and (counts == 3).all():  # all triangles already
        return flat_indices.reshape(-1, 3), np.arange(len(counts), dtype=np.int64)
    starts = np.zeros(len(counts), dtype=np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    per_polygon = np.maximum(counts - 2, 0)
    origin = np.repeat(np.arange(len(counts), dtype=np.int64), per_polygon)
    if len(origin) == 0:
        return np.zeros((0, 3), dtype=np.int64), origin
    first_triangle = np.zeros(len(counts), dtype=np.int64)
    np.cumsum(per_polygon[:-1], out=first_triangle[1:])
    k = np.arange(len(origin), dtype=np.int64) - first_triangle[origin] + 1
    base = starts[origin]
    faces = np.stack(
        [flat_indices[base], flat_indices[base + k], flat_indices[base + k + 1]], axis=1
    )
    return faces, origin


def _has_area(vertices: NDArray[Any], faces: NDArray[Any], limit: float) -> bool:
    """Whether any of the triangles has twice its area above ``limit``."""
    tri = vertices[faces]
    doubled_area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return bool((doubled_area > limit).any())


def build_mesh(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    face_origin: NDArray[Any] | None,
    input_face_count: int,
    *,
    format_name: str,
    limits: MeshLimits,
) -> TriangleMesh:
    """Validate parsed geometry and wrap it as a TriangleMesh (nothing merged or reordered).

    Raises InvalidGeometryError for non-finite coordinates, face indices outside
    the vertex list, or a mesh without any face of non-zero area. Degenerate faces
    next to usable ones are kept.
    """
    vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    limits.check_faces(len(faces), "triangles")
    limits.check_vertices(len(vertices))
    if len(faces) == 0:
        raise InvalidGeometryError(
            f"the {format_name} file contains no triangles or polygons (is it a point cloud "
            "or a line drawing?); export the surface as faces"
        )
    # Each check reduces the whole array first (one pass) and looks for the culprit only
    # in a file that fails it: per-row reductions cost 0.1 s at 1M faces.
    if not np.isfinite(vertices).all():
        bad_vertex = ~np.isfinite(vertices).all(axis=1)
        index = int(np.flatnonzero(bad_vertex)[0])
        raise InvalidGeometryError(
            f"{int(bad_vertex.sum())} vertices have NaN or infinite coordinates "
            f"(first: vertex {index}); repair or re-export the mesh"
        )
    largest = float(np.abs(vertices).max()) if len(vertices) else 0.0
    if largest > MAX_COORDINATE:
        index = int(np.abs(vertices).max(axis=1).argmax())
        raise InvalidGeometryError(
            f"coordinates as large as {largest:.3g} (first: vertex {index}) are beyond "
            f"{MAX_COORDINATE:.0e}, where squared lengths overflow the float32 geometry of "
            "the ray tracer and the network; rescale the mesh (e.g. to metres or millimetres)"
        )
    if int(faces.min()) < 0 or int(faces.max()) >= len(vertices):
        bad_face = (faces < 0).any(axis=1) | (faces >= len(vertices)).any(axis=1)
        index = int(np.flatnonzero(bad_face)[0])
        face = index if face_origin is None else int(face_origin[index])
        raise InvalidGeometryError(
            f"{int(bad_face.sum())} faces refer to vertices that do not exist (first: face "
            f"{face} of the file, 0-based vertex indices {faces[index].tolist()}, but there "
            f"are {len(vertices)} vertices); the file is corrupt or truncated"
        )
    limit = zero_area_limit(vertices, faces)  # relative to the mesh's own size
    if not _has_area(vertices, faces[:1024], limit) and not _has_area(vertices, faces, limit):
        used = vertices[np.unique(faces)]
        extent = float((used.max(axis=0) - used.min(axis=0)).max())
        raise InvalidGeometryError(
            f"all {len(faces)} triangles have zero area (twice the area at most {AREA_EPS:g} "
            "of the squared bounding-box diagonal), "
            f"so the mesh has no surface; its triangles span {extent:.3g} units: "
            + (
                "each triangle's corners lie on one line"
                if extent > 0
                else "all their corners are at one point"
            )
        )
    mesh = TriangleMesh(
        vertices=vertices,
        faces=faces,
        # TriangleMesh takes None (one triangle per input face); its field is typed as set.
        face_origin=face_origin,  # type: ignore[arg-type]
        input_face_count=input_face_count,
    )
    mesh.__dict__["zero_area_limit"] = limit  # the normals use the same limit
    return mesh


def polygon_mesh(
    vertices: NDArray[Any],
    counts: NDArray[Any],
    flat_indices: NDArray[Any],
    *,
    format_name: str,
    limits: MeshLimits,
) -> TriangleMesh:
    """Fan-triangulate polygons and validate; each polygon is one input face.

    The triangle count (a polygon of n vertices gives n - 2) is checked against
    ``limits`` before the triangles are made: one 255-gon per PLY row would otherwise
    multiply the face budget by 253.
    """
    counts = np.asarray(counts, dtype=np.int64)
    limits.check_faces(int(np.maximum(counts - 2, 0).sum()), "triangles")
    faces, origin = fan_triangulate(counts, flat_indices)
    return build_mesh(
        vertices,
        faces,
        origin,
        len(counts),
        format_name=format_name,
        limits=limits,
    )
