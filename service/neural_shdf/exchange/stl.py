"""STL reader (binary and ASCII): a triangle soup, one input face per facet in file order.

Every facet gets its own three vertices (nothing is merged here; the pipeline
welds coincident vertices when it builds the face graph).
"""

from __future__ import annotations

import logging
import re
import struct

import numpy as np

from neural_shdf.errors import MeshParseError
from neural_shdf.exchange._common import (
    NO_LIMITS,
    MeshLimits,
    build_mesh,
    decode_text,
    strip_bom,
)
from neural_shdf.mesh import TriangleMesh

FORMAT_NAME = "STL"
logger = logging.getLogger(__name__)
_HEADER_BYTES = 84
_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
_VERTEX = re.compile(rb"vertex\s+(\S+)\s+(\S+)\s+(\S+)", re.IGNORECASE)
_END_FACET = re.compile(rb"\bendfacet\b", re.IGNORECASE)
_END_SOLID = re.compile(rb"\bendsolid\b", re.IGNORECASE)


def _soup(corners: np.ndarray, limits: MeshLimits) -> TriangleMesh:
    count = len(corners)
    return build_mesh(
        corners.reshape(-1, 3),
        np.arange(3 * count, dtype=np.int64).reshape(-1, 3),
        None,
        count,
        format_name=FORMAT_NAME,
        limits=limits,
    )


def _read_binary(data: bytes, count: int, limits: MeshLimits) -> TriangleMesh:
    limits.check_faces(count)
    limits.check_vertices(3 * count)
    records = np.frombuffer(data, dtype=_RECORD, count=count, offset=_HEADER_BYTES)
    return _soup(records["corners"].astype(np.float64), limits)


def _read_ascii(data: bytes, limits: MeshLimits) -> TriangleMesh:
    decode_text(data, FORMAT_NAME)  # rejects binary content with a clear message
    if not _END_SOLID.search(data[-4096:]):
        raise MeshParseError("the ASCII STL does not end with 'endsolid': the file is truncated")
    facet_count = len(_END_FACET.findall(data))
    limits.check_faces(facet_count)
    limits.check_vertices(3 * facet_count)
    coordinates = _VERTEX.findall(data)
    if len(coordinates) != 3 * facet_count:
        raise MeshParseError(
            f"the ASCII STL has {facet_count} facets but {len(coordinates)} vertices "
            "(each facet needs exactly 3); the file is truncated or malformed"
        )
    try:
        corners = np.array(coordinates, dtype=np.float64).reshape(-1, 3, 3)
    except ValueError as exc:
        raise MeshParseError(f"ASCII STL vertex coordinates are not numbers: {exc}") from None
    return _soup(corners, limits)


def read_stl(data: bytes, limits: MeshLimits = NO_LIMITS) -> TriangleMesh:
    """Parse STL bytes, telling binary from ASCII by the size the binary header implies.

    A binary STL whose header count disagrees with its size is read by its size when the
    bytes after the header are a whole number of 50-byte facets (exporters that write a
    wrong or zero count; logged as a warning), so no facet is left out; fewer bytes than
    the count needs is a truncated file, and any other size is refused.
    """
    declared = struct.unpack_from("<I", data, 80)[0] if len(data) >= _HEADER_BYTES else -1
    binary_size = _HEADER_BYTES + 50 * declared
    text = strip_bom(data)
    is_ascii = text[:1024].lstrip()[:5].lower() == b"solid" and b"\x00" not in text[:65536]
    if declared >= 0 and len(data) == binary_size:
        return _read_binary(data, declared, limits)
    if is_ascii:
        return _read_ascii(text, limits)
    if declared < 0:
        raise MeshParseError(
            f"the file has {len(data)} bytes: too short for a binary STL (84-byte header) "
            "and not an ASCII STL (which starts with 'solid')"
        )
    if len(data) < binary_size:
        raise MeshParseError(
            f"the binary STL is truncated: its header declares {declared} triangles "
            f"({binary_size} bytes) but the file has {len(data)} bytes"
        )
    extra = len(data) - binary_size
    if extra < 50:  # padding shorter than a facet cannot hide one
        return _read_binary(data, declared, limits)
    if extra % 50 == 0:
        actual = (len(data) - _HEADER_BYTES) // 50
        logger.warning(
            "binary STL header declares %d triangles but the file holds %d: reading %d",
            declared,
            actual,
            actual,
        )
        return _read_binary(data, actual, limits)
    raise MeshParseError(
        f"the binary STL header declares {declared} triangles ({binary_size} bytes) but the "
        f"file has {len(data)} bytes, {extra} more, which is not a whole number of 50-byte "
        "facets: the file is corrupt; re-export it"
    )
