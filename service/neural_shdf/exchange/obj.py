"""Wavefront OBJ reader: every ``f`` record is one input face, in file order.

Groups (``g``/``o``) and materials (``usemtl``) are ignored, so faces are never
regrouped or reordered (trimesh's OBJ loader splits by material, which is why
this reader exists). Only the position index of ``v/vt/vn`` references is used;
negative indices are relative to the vertices defined so far. Texture coordinates,
normals, lines (``l``) and points (``p``) are ignored. A UTF-8 byte-order mark
and ``#`` comments after a record are skipped; errors name the file's line.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import InvalidGeometryError, MeshParseError
from neural_shdf.exchange._common import (
    NO_LIMITS,
    MeshLimits,
    decode_text,
    polygon_mesh,
    strip_bom,
)
from neural_shdf.mesh import TriangleMesh

FORMAT_NAME = "OBJ"


#: Characters of text parsed per step. Each step's C calls (``splitlines``, ``np.array`` over
#: its records) then hold the GIL for milliseconds, not for the whole file: the service
#: parses uploads in a thread beside its event loop.
CHUNK_CHARS = 1 << 19


def _joined_continuations(text: str) -> str:
    """The text with ``\\`` line continuations joined."""
    if "\\\n" in text or "\\\r\n" in text:
        text = text.replace("\\\r\n", " ").replace("\\\n", " ")
    return text


def _chunks(text: str) -> Iterator[str]:
    """The text in pieces of about ``CHUNK_CHARS`` that end after a newline, so that each
    piece's ``splitlines`` gives whole lines and the pieces' lines are the text's lines."""
    start = 0
    while start < len(text):
        newline = text.find("\n", start + CHUNK_CHARS)
        end = len(text) if newline < 0 else newline + 1
        yield text[start:end]
        start = end


def _record_count(data: bytes, keyword: bytes) -> int:
    """Lines that start with ``keyword`` and a blank (indented ones are missed: a lower
    bound, counted at C speed before anything is parsed)."""
    count = data.count(b"\n" + keyword + b" ") + data.count(b"\n" + keyword + b"\t")
    return count + (data[:2] in (keyword + b" ", keyword + b"\t"))


def _first_bad_coordinate(lines: list[str]) -> tuple[int, str]:
    """(index in ``lines``, text) of the first ``v`` record whose coordinates are not
    numbers."""
    for index, raw in enumerate(lines):
        parts = raw.split("#", 1)[0].split()
        if parts and parts[0] == "v":
            try:
                [float(value) for value in parts[1:4]]
            except ValueError:
                return index, raw.strip()
    return 0, ""


def read_obj(data: bytes, limits: MeshLimits = NO_LIMITS) -> TriangleMesh:
    """Parse OBJ bytes; polygons are fan-triangulated, one input face per ``f`` record.

    An ``f`` record with fewer than 3 vertices (a point or an edge) is still an input
    face: it gets no triangle, and per-face outputs keep its line (label -1, ShDF NaN),
    so the faces after it keep their place.
    """
    data = strip_bom(data)
    limits.check_faces(_record_count(data, b"f"))
    limits.check_vertices(_record_count(data, b"v"))
    text = _joined_continuations(decode_text(data, FORMAT_NAME))
    vertex_blocks: list[NDArray[np.float64]] = []
    index_blocks: list[NDArray[np.int64]] = []
    counts = array("q")  # corners of each f record
    face_lines = array("q")  # line of each f record, to name it in errors
    vertex_count = 0
    polygon_count = 0
    vertex_limit = limits.max_vertices if limits.max_vertices is not None else len(data)
    face_limit = limits.max_faces if limits.max_faces is not None else len(data)
    line_number = 0
    for chunk in _chunks(text):
        lines = chunk.splitlines()
        first_line = line_number + 1
        coordinates: list[str] = []
        flat: list[int] = []
        for line_number, raw in enumerate(lines, start=first_line):
            line = raw.lstrip()
            if not line or line[0] not in "vf":
                continue
            if "#" in line:  # a comment may follow a record
                line = line.split("#", 1)[0]
            parts = line.split()
            if not parts or parts[0] not in ("v", "f"):
                continue
            if parts[0] == "v":
                if len(parts) < 4:
                    raise MeshParseError(
                        f"OBJ line {line_number}: a vertex needs 3 coordinates, got {raw.strip()!r}"
                    )
                coordinates.extend(parts[1:4])
                vertex_count += 1
                if vertex_count > vertex_limit:
                    limits.check_vertices(vertex_count, at_least=True)
                continue
            # parts[0] == "f"
            references = parts[1:]
            for reference in references:
                position = reference.split("/", 1)[0]
                try:
                    index = int(position)
                except ValueError:
                    raise MeshParseError(
                        f"OBJ line {line_number}: face vertex {reference!r} is not an integer index"
                    ) from None
                if index == 0:
                    raise InvalidGeometryError(
                        f"OBJ line {line_number}: face index 0 is invalid (OBJ indices start at 1)"
                    )
                flat.append(index - 1 if index > 0 else vertex_count + index)
            counts.append(len(references))
            face_lines.append(line_number)
            if len(references) >= 3:
                polygon_count += 1
                if polygon_count > face_limit:
                    limits.check_faces(polygon_count, at_least=True)
        line_number = first_line + len(lines) - 1
        try:
            vertex_blocks.append(np.array(coordinates, dtype=np.float64))
        except ValueError:
            index, bad = _first_bad_coordinate(lines)
            raise MeshParseError(
                f"OBJ line {first_line + index}: vertex coordinates are not all numbers: "
                f"{bad[:80]!r}"
            ) from None
        index_blocks.append(np.array(flat, dtype=np.int64))
    if not vertex_count and not counts:
        raise MeshParseError("no vertex ('v') or face ('f') records found: this is not an OBJ mesh")
    vertices = np.concatenate(vertex_blocks).reshape(-1, 3)
    flat_indices = np.concatenate(index_blocks)
    outside = (flat_indices < 0) | (flat_indices >= vertex_count)
    if outside.any():
        corner = int(np.flatnonzero(outside)[0])
        face = int(np.searchsorted(np.cumsum(counts), corner, side="right"))
        raise InvalidGeometryError(
            f"OBJ line {face_lines[face]}: {int(outside.sum())} face corners refer to "
            f"vertices that do not exist (first: face {face} of the file; there are "
            f"{vertex_count} vertices); the file is corrupt or truncated"
        )
    return polygon_mesh(
        vertices,
        np.array(counts, dtype=np.int64),
        flat_indices,
        format_name=FORMAT_NAME,
        limits=limits,
    )
