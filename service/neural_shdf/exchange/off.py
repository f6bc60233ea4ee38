"""Object File Format (OFF, incl. COFF/NOFF/STOFF headers) reader.

Each face record is one input face, in file order; per-face colours after the
vertex indices are ignored. A face record with fewer than 3 vertices is still an
input face (no triangle; its line stays in per-face outputs). A UTF-8 byte-order mark
is skipped; errors in the body name the file's line.
"""

from __future__ import annotations

import re

import numpy as np

from neural_shdf.errors import MeshParseError, UnsupportedFormatError
from neural_shdf.exchange._common import (
    NO_LIMITS,
    MeshLimits,
    decode_text,
    polygon_mesh,
    strip_bom,
)
from neural_shdf.mesh import TriangleMesh

FORMAT_NAME = "OFF"


def _content_lines(text: str) -> tuple[list[str], list[int]]:
    """Non-empty lines with ``#`` comments removed, and the file line number of each."""
    lines: list[str] = []
    numbers: list[int] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if line:
            lines.append(line)
            numbers.append(number)
    return lines, numbers


def _header(text: str) -> tuple[list[str], list[str], int]:
    """(header tokens, count tokens, content lines the header takes) from the first
    content lines, read lazily so that limits are checked before the body is split."""
    found: list[str] = []
    start = 0
    while len(found) < 2 and start < len(text):
        end = text.find("\n", start)
        end = len(text) if end < 0 else end
        line = text[start:end].split("#", 1)[0].strip()
        if line:
            found.append(line)
        start = end + 1
    if not found:
        raise MeshParseError("the OFF file is empty")
    header = found[0].split()
    keyword = header[0].upper()
    if not re.fullmatch(r"(ST)?C?N?OFF", keyword):
        if keyword.endswith("OFF"):
            raise UnsupportedFormatError(
                f"OFF variant {header[0]!r} is not supported; save as plain 3-D 'OFF'"
            )
        raise MeshParseError(
            f"an OFF file must start with 'OFF', found {found[0][:40]!r}; is it really OFF?"
        )
    if len(header) > 1:
        return header, header[1:], 1
    return header, found[1].split() if len(found) > 1 else [], 2


def read_off(data: bytes, limits: MeshLimits = NO_LIMITS) -> TriangleMesh:
    """Parse OFF bytes; polygons are fan-triangulated, one input face per face record."""
    data = strip_bom(data)
    if data[:64].lstrip().upper().startswith(b"OFF BINARY"):
        raise UnsupportedFormatError("binary OFF is not supported; save the mesh as text OFF")
    text = decode_text(data, FORMAT_NAME)
    _, counts_tokens, body_start = _header(text)
    if len(counts_tokens) < 2:
        raise MeshParseError("the OFF header needs vertex and face counts ('V F E')")
    try:
        vertex_count, face_count = int(counts_tokens[0]), int(counts_tokens[1])
    except ValueError:
        raise MeshParseError(f"OFF counts are not integers: {counts_tokens[:3]}") from None
    if vertex_count < 0 or face_count < 0:
        raise MeshParseError(f"OFF counts are negative: {vertex_count} {face_count}")
    line_count = data.count(b"\n") + data.count(b"\r") + 1  # at least the lines there are
    if vertex_count + face_count > line_count:
        raise MeshParseError(
            f"the OFF file is truncated: its header declares {vertex_count} vertices and "
            f"{face_count} faces but the file has only {line_count} lines"
        )
    limits.check_faces(face_count)
    limits.check_vertices(vertex_count)
    lines, line_numbers = _content_lines(text)
    available = len(lines) - body_start
    if vertex_count + face_count > available:
        raise MeshParseError(
            f"the OFF file is truncated: its header declares {vertex_count} vertices and "
            f"{face_count} faces but only {available} data lines follow"
        )

    vertex_lines = lines[body_start : body_start + vertex_count]
    try:
        vertices = np.array([line.split()[:3] for line in vertex_lines], dtype=np.float64)
    except ValueError:
        vertices = np.zeros((0, 3))
    if vertices.shape != (vertex_count, 3):
        for i, line in enumerate(vertex_lines):
            values = line.split()[:3]
            try:
                [float(value) for value in values]
            except ValueError:
                values = []
            if len(values) < 3:
                raise MeshParseError(
                    f"OFF line {line_numbers[body_start + i]}: vertex {i} needs 3 numbers, "
                    f"got {line[:80]!r}"
                )

    first_face = body_start + vertex_count
    face_lines = lines[first_face : first_face + face_count]
    counts = np.empty(face_count, dtype=np.int64)
    flat: list[str] = []
    for i, line in enumerate(face_lines):
        tokens = line.split()
        n = int(tokens[0]) if tokens[0].isdigit() else -1
        where = f"OFF line {line_numbers[first_face + i]}: face {i}"
        if n < 0 or len(tokens) < n + 1:
            listed = len(tokens) - 1
            raise MeshParseError(
                f"{where} declares {tokens[0][:20]} vertices but lists {listed} values"
            )
        if not all(token.lstrip("-").isdigit() for token in tokens[1 : n + 1]):
            raise MeshParseError(f"{where} has vertex indices that are not integers: {line[:80]!r}")
        counts[i] = n
        flat.extend(tokens[1 : n + 1])
    flat_indices = np.array(flat, dtype=np.int64)
    return polygon_mesh(vertices, counts, flat_indices, format_name=FORMAT_NAME, limits=limits)
