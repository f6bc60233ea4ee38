"""Stanford PLY reader (ascii, binary little- and big-endian).

Reads ``x, y, z`` of the ``vertex`` element and the ``vertex_indices`` (or
``vertex_index``) list of the ``face`` element; each face row is one input face,
in file order. Other elements and properties are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import InvalidGeometryError, MeshParseError, UnsupportedFormatError
from neural_shdf.exchange._common import NO_LIMITS, MeshLimits, polygon_mesh, strip_bom
from neural_shdf.exchange.attributes import SourceMesh, SurfaceAttributes, vertex_attributes
from neural_shdf.mesh import TriangleMesh
from neural_shdf.palette import srgb_to_linear

FORMAT_NAME = "PLY"
_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_ENCODINGS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_FACE_LISTS = ("vertex_indices", "vertex_index")


@dataclass
class _Property:
    name: str
    value_type: str
    count_type: str | None = None  # set for list properties

    @property
    def is_list(self) -> bool:
        return self.count_type is not None


@dataclass
class _Element:
    name: str
    count: int
    properties: list[_Property]


#: What the reader keeps of an element: scalar columns, and lists as (counts, flat values).
_Columns = dict[str, NDArray[Any] | tuple[NDArray[Any], NDArray[Any]]]


def _parse_header(data: bytes) -> tuple[str, list[_Element], int]:
    """(encoding prefix or '' for ascii, elements, byte offset of the body)."""
    if not data.startswith(b"ply"):
        raise MeshParseError("a PLY file must start with 'ply'; is it really PLY?")
    end = data.find(b"end_header", 0, 1 << 20)
    if end < 0:
        raise MeshParseError("the PLY header has no 'end_header' line (truncated file?)")
    body = data.find(b"\n", end)
    body = len(data) if body < 0 else body + 1
    lines = data[:end].decode("latin-1").splitlines()
    encoding: str | None = None
    elements: list[_Element] = []
    for line in lines[1:]:
        tokens = line.split()
        if not tokens or tokens[0] in ("comment", "obj_info"):
            continue
        if tokens[0] == "format" and len(tokens) >= 2:
            if tokens[1] not in _ENCODINGS:
                raise UnsupportedFormatError(f"PLY encoding {tokens[1]!r} is not supported")
            encoding = _ENCODINGS[tokens[1]]
        elif tokens[0] == "element" and len(tokens) == 3:
            count = int(tokens[2])
            if count < 0:
                raise MeshParseError(f"PLY element {tokens[1]!r} has a negative count")
            elements.append(_Element(tokens[1], count, []))
        elif tokens[0] == "property" and elements:
            if len(tokens) == 5 and tokens[1] == "list":
                prop = _Property(tokens[4], _TYPES[tokens[3]], _TYPES[tokens[2]])
            elif len(tokens) == 3:
                prop = _Property(tokens[2], _TYPES[tokens[1]])
            else:
                raise MeshParseError(f"malformed PLY property line {line!r}")
            elements[-1].properties.append(prop)
        else:
            raise MeshParseError(f"unexpected PLY header line {line!r}")
    if encoding is None:
        raise MeshParseError("the PLY header has no 'format' line")
    return encoding, elements, body


def _truncated(element: _Element) -> MeshParseError:
    return MeshParseError(
        f"the PLY file is truncated: it ends inside element {element.name!r} "
        f"(declared {element.count} rows)"
    )


def _split_fixed(element: _Element, table: NDArray[Any], widths: list[int]) -> _Columns | None:
    """Columns of a (rows, values) table whose lists all have the assumed widths, else None."""
    columns: _Columns = {}
    col = 0
    for prop, width in zip(element.properties, widths, strict=True):
        if not prop.is_list:
            columns[prop.name] = table[:, col]
            col += 1
            continue
        if len(table) and not (table[:, col] == width).all():
            return None
        values = table[:, col + 1 : col + 1 + width]
        columns[prop.name] = (np.full(len(table), width, dtype=np.int64), values.reshape(-1))
        col += 1 + width
    return columns


def _list_length(element: _Element, value: object) -> int:
    length: int = int(value)  # type: ignore[call-overload]
    if length < 0:
        raise MeshParseError(f"PLY element {element.name!r} has a list of negative length")
    return length


def _empty_columns(element: _Element) -> _Columns:
    empty = np.zeros(0)
    return {
        p.name: (np.zeros(0, dtype=np.int64), empty) if p.is_list else empty
        for p in element.properties
    }


def _read_ascii_element(element: _Element, tokens: list[str], cursor: int) -> tuple[_Columns, int]:
    minimum = element.count * len(element.properties)
    if cursor + minimum > len(tokens):
        raise _truncated(element)
    if element.count == 0:
        return _empty_columns(element), cursor
    # Fast path: every list has the length of the first row's list.
    widths, probe = [], cursor
    for prop in element.properties:
        if probe >= len(tokens):
            raise _truncated(element)
        if prop.is_list:
            widths.append(_list_length(element, tokens[probe]))
            probe += 1 + widths[-1]
        else:
            widths.append(0)
            probe += 1
    row_width = probe - cursor
    end = cursor + row_width * element.count
    if end <= len(tokens):
        table = np.array(tokens[cursor:end], dtype=np.float64).reshape(element.count, row_width)
        columns = _split_fixed(element, table, widths)
        if columns is not None:
            return columns, end
    # General path: row by row.
    scalars: dict[str, list[float]] = {p.name: [] for p in element.properties if not p.is_list}
    lists: dict[str, tuple[list[int], list[str]]] = {
        p.name: ([], []) for p in element.properties if p.is_list
    }
    for _ in range(element.count):
        for prop in element.properties:
            if cursor >= len(tokens):
                raise _truncated(element)
            if prop.is_list:
                n = int(tokens[cursor])
                if n < 0 or cursor + 1 + n > len(tokens):
                    raise _truncated(element)
                lists[prop.name][0].append(n)
                lists[prop.name][1].extend(tokens[cursor + 1 : cursor + 1 + n])
                cursor += 1 + n
            else:
                scalars[prop.name].append(float(tokens[cursor]))
                cursor += 1
    columns = {name: np.array(values, dtype=np.float64) for name, values in scalars.items()}
    for name, (counts, flat) in lists.items():
        columns[name] = (np.array(counts, dtype=np.int64), np.array(flat, dtype=np.float64))
    return columns, cursor


def _read_binary_element(
    element: _Element, data: bytes, offset: int, endian: str
) -> tuple[_Columns, int]:
    fixed = [(p, np.dtype(endian + (p.count_type or p.value_type))) for p in element.properties]
    minimum_row = sum(dtype.itemsize for _, dtype in fixed)
    if offset + minimum_row * element.count > len(data):
        raise _truncated(element)
    if element.count == 0:
        return _empty_columns(element), offset
    # Fast path: every list has the length of the first row's list -> one structured array.
    fields: list[tuple[Any, ...]] = []
    widths, probe = [], offset
    for i, (prop, dtype) in enumerate(fixed):
        fields.append((f"f{i}", dtype))
        if prop.is_list:
            if probe + dtype.itemsize > len(data):
                raise _truncated(element)
            width = _list_length(element, np.frombuffer(data, dtype, 1, probe)[0])
            value_dtype = np.dtype(endian + prop.value_type)
            if width > 0:
                fields.append((f"v{i}", value_dtype, (width,)))
            widths.append(width)
            probe += dtype.itemsize + width * value_dtype.itemsize
        else:
            widths.append(0)
            probe += dtype.itemsize
    row = np.dtype(fields)
    if offset + row.itemsize * element.count <= len(data):
        table = np.frombuffer(data, row, element.count, offset)
        columns: _Columns = {}
        uniform = True
        for i, prop in enumerate(element.properties):
            if not prop.is_list:
                columns[prop.name] = table[f"f{i}"]
            elif (table[f"f{i}"] == widths[i]).all():
                values = table[f"v{i}"] if widths[i] else np.zeros((element.count, 0))
                counts = np.full(element.count, widths[i], dtype=np.int64)
                columns[prop.name] = (counts, values.reshape(-1))
            else:
                uniform = False
                break
        if uniform:
            return columns, offset + row.itemsize * element.count
    # General path: row by row (mixed polygon sizes).
    scalars: dict[str, list[Any]] = {p.name: [] for p in element.properties if not p.is_list}
    lists: dict[str, tuple[list[int], list[NDArray[Any]]]] = {
        p.name: ([], []) for p in element.properties if p.is_list
    }
    for _ in range(element.count):
        for prop, dtype in fixed:
            if offset + dtype.itemsize > len(data):
                raise _truncated(element)
            value = np.frombuffer(data, dtype, 1, offset)[0]
            offset += dtype.itemsize
            if not prop.is_list:
                scalars[prop.name].append(value)
                continue
            value_dtype = np.dtype(endian + prop.value_type)
            n = int(value)
            if n < 0 or offset + n * value_dtype.itemsize > len(data):
                raise _truncated(element)
            lists[prop.name][0].append(n)
            lists[prop.name][1].append(np.frombuffer(data, value_dtype, n, offset))
            offset += n * value_dtype.itemsize
    columns = {name: np.array(values) for name, values in scalars.items()}
    for name, (lengths, chunks) in lists.items():
        flat = np.concatenate(chunks) if chunks else np.zeros(0)
        columns[name] = (np.array(lengths, dtype=np.int64), flat)
    return columns, offset


def read_ply(data: bytes, limits: MeshLimits = NO_LIMITS) -> TriangleMesh:
    """Parse PLY bytes; polygons are fan-triangulated, one input face per face row
    (a row of fewer than 3 vertices is an input face without a triangle)."""
    return read_ply_source(data, limits).mesh


#: Vertex properties read as UVs (first pair found), as written by common tools.
_UV_NAMES = (("u", "v"), ("s", "t"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


def read_ply_source(
    data: bytes, limits: MeshLimits = NO_LIMITS, *, attributes: bool = False
) -> SourceMesh:
    """``read_ply`` with, when ``attributes``, the vertex normals (``nx ny nz``), UVs
    (``u v``, ``s t``, ``texture_u texture_v``; V flipped to glTF's downward V) and
    colours (``red green blue [alpha]``: bytes or 0-1 floats, sRGB, made linear)."""
    data = strip_bom(data)
    endian, elements, body = _parse_header(data)
    names = [e.name for e in elements]
    if "vertex" not in names:
        raise MeshParseError("the PLY file has no 'vertex' element")
    if "face" not in names:
        raise InvalidGeometryError(
            "the PLY file has no 'face' element (a point cloud?); export the surface as faces"
        )
    face_element = elements[names.index("face")]
    limits.check_faces(face_element.count)
    limits.check_vertices(elements[names.index("vertex")].count)
    face_list = next((p.name for p in face_element.properties if p.name in _FACE_LISTS), None)
    if face_list is None:
        raise MeshParseError("the PLY 'face' element has no 'vertex_indices' list property")
    vertex_props = {p.name for p in elements[names.index("vertex")].properties}
    if not {"x", "y", "z"} <= vertex_props:
        raise MeshParseError("the PLY 'vertex' element needs x, y and z properties")

    columns: dict[str, _Columns] = {}
    if endian:
        offset = body
        for element in elements:
            columns[element.name], offset = _read_binary_element(element, data, offset, endian)
    else:
        tokens = data[body:].decode("latin-1").split()
        cursor = 0
        for element in elements:
            columns[element.name], cursor = _read_ascii_element(element, tokens, cursor)

    vertex = columns["vertex"]
    vertices = np.stack([np.asarray(vertex[axis], dtype=np.float64) for axis in "xyz"], axis=1)
    counts, flat = columns["face"][face_list]
    flat = np.asarray(flat)
    if flat.dtype.kind == "f" and not np.array_equal(flat, np.round(flat)):
        raise MeshParseError("PLY face indices must be integers")
    mesh = polygon_mesh(
        vertices,
        counts,
        flat.astype(np.int64),
        format_name=FORMAT_NAME,
        limits=limits,
    )
    if not attributes:
        return SourceMesh(mesh)
    element = elements[names.index("vertex")]
    return SourceMesh(mesh, _vertex_attributes(mesh, vertex, element))


def _vertex_attributes(
    mesh: TriangleMesh, vertex: _Columns, element: _Element
) -> SurfaceAttributes | None:
    def column(name: str) -> NDArray[np.float64]:
        values = vertex[name]
        assert not isinstance(values, tuple)  # noqa: S101 - scalar properties only
        return np.asarray(values, dtype=np.float64)

    scalars = {name for name, values in vertex.items() if not isinstance(values, tuple)}
    normals = (
        np.stack([column(n) for n in ("nx", "ny", "nz")], axis=1)
        if {"nx", "ny", "nz"} <= scalars
        else None
    )
    uv = None
    for u, v in _UV_NAMES:
        if {u, v} <= scalars:
            uv = np.stack([column(u), 1.0 - column(v)], axis=1)
            break
    colors = None
    if {"red", "green", "blue"} <= scalars:
        names = ("red", "green", "blue") + (("alpha",) if "alpha" in scalars else ())
        declared = next(p.value_type for p in element.properties if p.name == "red")
        # Integer colours are bytes (0-255), float colours 0-1, whatever the column's dtype
        # (ascii columns are read as floats).
        scale = 255.0 if np.dtype(declared).kind in "iu" else 1.0
        rgba = np.stack([column(n) / scale for n in names], axis=1)
        if rgba.shape[1] == 3:
            rgba = np.column_stack([rgba, np.ones(len(rgba))])
        rgba[:, :3] = srgb_to_linear(np.clip(rgba[:, :3], 0.0, 1.0))
        colors = rgba
    return vertex_attributes(mesh, normals=normals, uv=uv, colors=colors)
