"""Wavefront OBJ reader: every ``f`` record is one input face, in file order.

Groups (``g``/``o``) and materials (``usemtl``) never regroup or reorder faces
(trimesh's OBJ loader splits by material, which is why this reader exists). The
geometry uses the position index of ``v/vt/vn`` references; negative indices are
relative to the vertices defined so far. Lines (``l``) and points (``p``) are
ignored. A UTF-8 byte-order mark and ``#`` comments after a record are skipped;
errors name the file's line.

``read_obj_source(..., attributes=True)`` also keeps each corner's ``vt`` and ``vn``
(a reference to one that does not exist counts as none), vertex colours written as
``v x y z r g b`` (taken as sRGB) and each face's ``usemtl`` material
(``exchange.attributes``). The ``mtllib`` files are read only from a file on disk
(``side_files``: the OBJ's folder), as glTF materials (``mtl_material``); bytes alone (an
upload) keep the material names only.
"""

from __future__ import annotations

from array import array
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import InvalidGeometryError, MeshParseError
from neural_shdf.exchange._common import (
    NO_LIMITS,
    MeshLimits,
    decode_text,
    fan_triangulate,
    polygon_mesh,
    strip_bom,
)
from neural_shdf.exchange.attributes import (
    FaceGroup,
    Materials,
    MaterialTable,
    SideFiles,
    SourceMesh,
    SurfaceAttributes,
    finite_rows,
    unit_normals,
)
from neural_shdf.mesh import TriangleMesh
from neural_shdf.palette import srgb_to_linear

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
    return read_obj_source(data, limits).mesh


class _Extras:
    """What ``attributes=True`` keeps beside the geometry, record by record."""

    def __init__(self) -> None:
        self.uv_values: list[str] = []
        self.normal_values: list[str] = []
        self.color_values: list[str] = []
        self.colored_vertices = 0
        self.uv_refs: list[str] = []  # per f corner: its vt reference as written
        self.normal_refs: list[str] = []  # per f corner: its vn reference as written
        self.face_material = array("q")  # per f record: index into names, or -1
        self.face_corners = array("q")  # per f record: its corners
        self.uv_defined = array("q")  # per f record: vt records before it
        self.normal_defined = array("q")  # per f record: vn records before it
        self.names: dict[str, int] = {}
        self.material = -1
        self.libraries: list[str] = []  # mtllib records, as written

    def vertex(self, parts: list[str]) -> None:
        if len(parts) >= 7:
            self.color_values.extend(parts[4:7])
            self.colored_vertices += 1

    def record(self, parts: list[str]) -> bool:
        """Read a ``vt``, ``vn`` or ``usemtl`` record; False for anything else."""
        keyword = parts[0]
        if keyword == "vt" and len(parts) >= 3:
            self.uv_values.extend(parts[1:3])
        elif keyword == "vt":
            self.uv_values.extend([parts[1] if len(parts) > 1 else "0", "0"])
        elif keyword == "vn" and len(parts) >= 4:
            self.normal_values.extend(parts[1:4])
        elif keyword == "vn":
            self.normal_values.extend(["0", "0", "0"])  # no direction: dropped later
        elif keyword == "usemtl":
            name = " ".join(parts[1:])
            self.material = self.names.setdefault(name, len(self.names))
        elif keyword == "mtllib" and len(parts) > 1:
            self.libraries.append(" ".join(parts[1:]))
        else:
            return False
        return True

    def face(self, corners: int) -> None:
        self.face_material.append(self.material)
        self.face_corners.append(corners)
        self.uv_defined.append(len(self.uv_values) // 2)
        self.normal_defined.append(len(self.normal_values) // 3)

    def corner_indices(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """0-based ``vt`` and ``vn`` of every face corner (-1: none, or one that does not
        exist), negative references resolved against what was defined before the face."""
        corners = np.array(self.face_corners, dtype=np.int64)
        return (
            _references(self.uv_refs, np.repeat(np.array(self.uv_defined), corners)),
            _references(self.normal_refs, np.repeat(np.array(self.normal_defined), corners)),
        )


def _references(texts: list[str], defined: NDArray[np.int64]) -> NDArray[np.int64]:
    """1-based (or negative, relative) OBJ references as 0-based indices; -1 where
    missing, not a number or out of range."""
    try:  # int() per text: several times faster than numpy's string-to-int conversion
        numbers = np.array(list(map(int, [t or "0" for t in texts])), dtype=np.int64)
    except ValueError:  # some reference is not a number: one by one
        numbers = np.array([int(t) if t.lstrip("-").isdigit() else 0 for t in texts], np.int64)
    if not len(numbers):
        return numbers
    index = np.where(numbers > 0, numbers - 1, defined + numbers)
    return np.where((numbers != 0) & (index >= 0) & (index < defined), index, -1)


def read_obj_source(
    data: bytes,
    limits: MeshLimits = NO_LIMITS,
    *,
    attributes: bool = False,
    side_files: SideFiles | None = None,
) -> SourceMesh:
    """``read_obj`` with, when ``attributes``, the file's UVs, normals, vertex colours and
    materials (module docstring; ``side_files``: where its .mtl files and textures are)."""
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
    extras = _Extras() if attributes else None
    uv_refs = extras.uv_refs if extras is not None else None
    normal_refs = extras.normal_refs if extras is not None else None
    first_letters = "vfum" if attributes else "vf"
    line_number = 0
    for chunk in _chunks(text):
        lines = chunk.splitlines()
        first_line = line_number + 1
        coordinates: list[str] = []
        flat: list[int] = []
        for line_number, raw in enumerate(lines, start=first_line):
            line = raw.lstrip()
            if not line or line[0] not in first_letters:
                continue
            if "#" in line:  # a comment may follow a record
                line = line.split("#", 1)[0]
            parts = line.split()
            if not parts or parts[0] not in ("v", "f"):
                if parts and extras is not None:
                    extras.record(parts)
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
                if extras is not None:
                    extras.vertex(parts)
                continue
            # parts[0] == "f"
            references = parts[1:]
            for reference in references:
                fields = reference.split("/", 2)
                position = fields[0]
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
                if uv_refs is not None and normal_refs is not None:  # attributes
                    uv_refs.append(fields[1] if len(fields) > 1 else "")
                    normal_refs.append(fields[2] if len(fields) > 2 else "")
            counts.append(len(references))
            face_lines.append(line_number)
            if extras is not None:
                extras.face(len(references))
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
    face_counts = np.array(counts, dtype=np.int64)
    mesh = polygon_mesh(
        vertices,
        face_counts,
        flat_indices,
        format_name=FORMAT_NAME,
        limits=limits,
    )
    if extras is None:
        return SourceMesh(mesh)
    return SourceMesh(
        mesh, _attributes(mesh, face_counts, flat_indices, extras, vertex_count, side_files)
    )


def _numbers(values: list[str], width: int) -> NDArray[np.float64] | None:
    """The values as rows of ``width`` numbers; None when some are not numbers."""
    try:
        return np.array(values, dtype=np.float64).reshape(-1, width)
    except ValueError:
        return None


def _attributes(
    mesh: TriangleMesh,
    counts: NDArray[np.int64],
    flat: NDArray[np.int64],
    extras: _Extras,
    vertex_count: int,
    side_files: SideFiles | None = None,
) -> SurfaceAttributes | None:
    """Attribute vertices (one per distinct ``v/vt/vn``) and face groups (one per
    material and set of attributes) of the file's triangles."""
    uv_table = _numbers(extras.uv_values, 2)
    normal_table = _numbers(extras.normal_values, 3)
    color_table = _numbers(extras.color_values, 3)
    corner_uv, corner_normal = extras.corner_indices()
    if uv_table is None or not finite_rows(uv_table):
        corner_uv[:] = -1
    normal_usable = np.zeros(0, dtype=bool)
    unit_table: NDArray[np.float32] | None = None
    if normal_table is not None:
        unit_table, _ = unit_normals(normal_table)
        normal_usable = np.abs(unit_table).sum(axis=1) > 0
    else:
        corner_normal[:] = -1
    corner_normal[corner_normal >= 0] = np.where(
        normal_usable[corner_normal[corner_normal >= 0]], corner_normal[corner_normal >= 0], -1
    )
    colored = (
        color_table is not None
        and extras.colored_vertices == vertex_count
        and finite_rows(color_table)
    )
    found = (corner_uv >= 0).any() or (corner_normal >= 0).any() or colored or extras.names
    if not found:
        return None
    # Triangle corners -> the file's face corners (the same fan as the geometry).
    triangle_corner, origin = fan_triangulate(counts, np.arange(len(flat), dtype=np.int64))
    # One attribute vertex per distinct (v, vt, vn).
    attribute_pair = (corner_uv + 1) * (len(normal_usable) + 1) + (corner_normal + 1)
    pair_values, pair_id = np.unique(attribute_pair, return_inverse=True)
    key = flat * len(pair_values) + pair_id.reshape(-1)
    _, corner_key = np.unique(key[triangle_corner.reshape(-1)], return_inverse=True)
    first = triangle_corner.reshape(-1)[np.unique(corner_key, return_index=True)[1]]
    vertex = flat[first]
    uv_index, normal_index = corner_uv[first], corner_normal[first]
    # Face groups: material, and whether the face's corners all have UVs, normals.
    face_of_corner = np.repeat(np.arange(len(counts)), counts)
    face_has_uv = np.bincount(face_of_corner[corner_uv < 0], minlength=len(counts)) == 0
    face_has_normal = np.bincount(face_of_corner[corner_normal < 0], minlength=len(counts)) == 0
    material = np.array(extras.face_material, dtype=np.int64)
    face_key = (material + 1) * 4 + np.asarray(face_has_uv, dtype=np.int64) * 2
    face_key = face_key + np.asarray(face_has_normal, dtype=np.int64)
    triangle_key = face_key[origin]
    group_keys, first_seen, group_of = np.unique(
        triangle_key, return_index=True, return_inverse=True
    )
    order = np.argsort(first_seen, kind="stable")  # groups in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    library = _read_libraries(extras, side_files)
    groups = tuple(
        FaceGroup(
            material=(
                int(k // 4) - 1
                if library is None or k < 4
                else library.for_faces(int(k // 4) - 1, bool((k >> 1) & 1))
            ),
            normals=bool(k & 1),
            uv_sets=int((k >> 1) & 1),
            colors=colored,
        )
        for k in group_keys[order].tolist()
    )
    uv = np.zeros((len(vertex), 2), dtype=np.float32)
    if uv_table is not None and (uv_index >= 0).any():
        uv[uv_index >= 0] = uv_table[uv_index[uv_index >= 0]]
        uv[:, 1] = 1.0 - uv[:, 1]  # OBJ's V points up, glTF's down
    normals = np.zeros((len(vertex), 3), dtype=np.float32)
    if unit_table is not None and (normal_index >= 0).any():
        normals[normal_index >= 0] = unit_table[normal_index[normal_index >= 0]]
    colors = None
    if colored and color_table is not None:
        colors = np.column_stack(
            [srgb_to_linear(np.clip(color_table[vertex], 0.0, 1.0)), np.ones(len(vertex))]
        ).astype(np.float32)
    attributes = SurfaceAttributes(
        corners=corner_key.reshape(-1, 3).astype(np.int64),
        vertex=vertex,
        face_group=rank[group_of.reshape(-1)].astype(np.int64),
        groups=groups,
        normals=normals if any(g.normals for g in groups) else None,
        uvs=(uv,) if any(g.uv_sets for g in groups) else (),
        colors=colors,
        materials=(
            Materials(materials=tuple({"name": name} for name in extras.names), defined=False)
            if library is None
            else library.result()
        ),
    )
    attributes.check(mesh)
    return attributes


def _read_libraries(extras: _Extras, side_files: SideFiles | None) -> MaterialTable | None:
    """The faces' materials from the OBJ's ``mtllib`` files (first definition of a name
    wins), in ``usemtl`` order; None when no library could be read (names only then)."""
    if side_files is None or not extras.names:
        return None
    found: dict[str, tuple[dict[str, list[str]], SideFiles]] = {}
    read_any = False
    for record in extras.libraries:
        # One name with spaces, else several names (the record allows a list).
        names = [record] if side_files.find(record) else record.split()
        for name in names:
            path = side_files.find(name)
            if path is None:
                continue
            try:
                text = decode_text(strip_bom(path.read_bytes()), "MTL")
            except (OSError, MeshParseError):
                continue
            read_any = True
            for material, statements in parse_mtl(text).items():
                found.setdefault(material, (statements, SideFiles(path.parent)))
    if not read_any:
        return None
    table = MaterialTable()
    for name in extras.names:  # indices follow the usemtl order
        statements, folder = found.get(name, ({}, side_files))
        table.add(name, mtl_material(name, statements, folder, table))
    return table


def parse_mtl(text: str) -> dict[str, dict[str, list[str]]]:
    """An MTL file's materials: name -> keyword (lower case) -> its values (the last
    statement of a keyword wins)."""
    materials: dict[str, dict[str, list[str]]] = {}
    current: dict[str, list[str]] | None = None
    for raw in _joined_continuations(text).splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        keyword, _, rest = line.partition(" ")
        keyword = keyword.lower()
        if keyword == "newmtl":
            current = materials.setdefault(rest.strip(), {})
        elif current is not None:
            current[keyword] = rest.split()
    return materials


#: Options of MTL texture statements and how many values each takes (``-o``, ``-s``,
#: ``-t``: one to three numbers).
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1,
                "-imfchan": 1, "-mm": 2, "-texres": 1, "-type": 1, "-o": 3, "-s": 3,
                "-t": 3}  # fmt: skip


def _map_file(values: list[str]) -> tuple[str, bool]:
    """``(file name, clamped)`` of a texture statement's values (options skipped)."""
    clamp = False
    index = 0
    while index < len(values) and values[index].lower() in _MAP_OPTIONS:
        option = values[index].lower()
        taken = _MAP_OPTIONS[option]
        if option == "-clamp":
            clamp = index + 1 < len(values) and values[index + 1].lower() == "on"
        index += 1
        for _ in range(taken):  # numbers only for the variable-length options
            if index < len(values) and (taken < 3 or _is_number(values[index])):
                index += 1
    return " ".join(values[index:]), clamp


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _floats(values: list[str] | None, count: int) -> list[float] | None:
    """The first ``count`` values as finite numbers, or None."""
    if values is None or len(values) < count:
        return None
    try:
        numbers = [float(v) for v in values[:count]]
    except ValueError:
        return None
    return numbers if all(np.isfinite(numbers)) else None


def mtl_material(
    name: str, statements: dict[str, list[str]], side_files: SideFiles, table: MaterialTable
) -> dict[str, Any]:
    """A glTF metallic-roughness material of an MTL material (as Blender's OBJ importer
    reads it): ``Kd`` the base colour (linear values, as Blender writes them), ``map_Kd``
    the base colour texture (PNG or JPEG, beside the .mtl; it replaces ``Kd``), ``d``
    (or ``1 - Tr``) the opacity, ``Pr`` the roughness (else ``1 - sqrt(Ns / 1000)``),
    ``Pm`` the metalness (else 0: MTL's model has no metals), ``Ke`` the emission.
    A name the libraries do not define gets a plain white dielectric."""
    pbr: dict[str, Any] = {"metallicFactor": 0.0}
    material: dict[str, Any] = {"name": name, "pbrMetallicRoughness": pbr}
    color = _floats(statements.get("kd"), 3) or [1.0, 1.0, 1.0]
    opacity = _floats(statements.get("d"), 1)
    if opacity is None and (transparency := _floats(statements.get("tr"), 1)) is not None:
        opacity = [1.0 - transparency[0]]
    alpha = float(np.clip(opacity[0], 0.0, 1.0)) if opacity else 1.0
    if "map_kd" in statements:
        file_name, clamp = _map_file(statements["map_kd"])
        image = side_files.read(file_name)
        sampler = {"wrapS": 33071, "wrapT": 33071} if clamp else None
        texture = None if image is None else table.texture(image, sampler)
        if texture is not None:
            pbr["baseColorTexture"] = {"index": texture}
            color = [1.0, 1.0, 1.0]
    pbr["baseColorFactor"] = [*(float(np.clip(c, 0.0, 1.0)) for c in color), alpha]
    if (rough := _floats(statements.get("pr"), 1)) is not None:
        pbr["roughnessFactor"] = float(np.clip(rough[0], 0.0, 1.0))
    elif (shine := _floats(statements.get("ns"), 1)) is not None:
        pbr["roughnessFactor"] = float(1.0 - np.sqrt(np.clip(shine[0], 0.0, 1000.0) / 1000.0))
    if (metal := _floats(statements.get("pm"), 1)) is not None:
        pbr["metallicFactor"] = float(np.clip(metal[0], 0.0, 1.0))
    emission = _floats(statements.get("ke"), 3)
    if emission is not None and any(e > 0 for e in emission):
        material["emissiveFactor"] = [float(np.clip(e, 0.0, 1.0)) for e in emission]
    if alpha < 1.0:
        material["alphaMode"] = "BLEND"
    return material
