"""Load meshes from files or bytes into a TriangleMesh, keeping the input's face order.

Face order rules (per-face outputs of the project follow them):

* OBJ, OFF, PLY: each face record is one input face, in file order. A polygon
  with n vertices becomes the fan ``(v0, v1, v2), (v0, v2, v3), ...`` of n - 2
  triangles, contiguous and in order; ``TriangleMesh.face_origin`` maps each
  triangle to its polygon and ``labels_to_input_faces`` maps labels back (one
  label per polygon). The fan is exact for convex (and planar star-shaped)
  polygons; a non-convex polygon may get overlapping triangles. Face records
  with fewer than 3 vertices count as input faces but give no triangle. OBJ
  groups and materials never regroup faces.
* STL: each facet is one input face; each facet has its own 3 vertices.
* GLB / glTF: each triangle is one input face; triangles come primitive by
  primitive in a depth-first walk of the default scene's nodes (in listed
  order), node transforms applied, once per instancing node (details in
  ``neural_shdf.exchange.gltf``).
* USD (``.usd``, ``.usda``, ``.usdc``, ``.usdz``): each polygon of each Mesh prim is
  one input face, fan-triangulated as above; prims in stage traversal order,
  instances expanded, world transforms applied (details in ``neural_shdf.exchange.usd``).

Nothing is merged, dropped or reordered: duplicate vertices and degenerate
faces stay. A mesh with no face of non-zero area, non-finite coordinates or
out-of-range indices is rejected with InvalidGeometryError.
"""

from __future__ import annotations

from pathlib import Path

from neural_shdf.errors import MeshParseError, UnsupportedFormatError
from neural_shdf.exchange import READERS, REFUSED, SOURCE_READERS
from neural_shdf.exchange._common import MeshLimits, parse_guard, strip_bom
from neural_shdf.exchange.attributes import SideFiles, SourceMesh
from neural_shdf.exchange.fbx import looks_like_fbx
from neural_shdf.exchange.usd import sniff_usd
from neural_shdf.mesh import TriangleMesh

#: File extensions load_mesh reads (lower case, without the dot).
SUPPORTED_FORMATS: tuple[str, ...] = tuple(READERS)

_FORMAT_NAMES = {"obj": "OBJ", "off": "OFF", "ply": "PLY", "stl": "STL", "glb": "GLB",
                 "gltf": "glTF", "usd": "USD", "usda": "USD", "usdc": "USD",
                 "usdz": "USDZ"}  # fmt: skip


def normalize_format(file_type: str) -> str:
    """The format name of a file type as a user may write it (``" .OBJ"`` -> ``"obj"``);
    UnsupportedFormatError naming the value as given (shortened) for anything else."""
    name = file_type.strip().lower().removeprefix(".")
    if name in REFUSED:
        raise UnsupportedFormatError(REFUSED[name])
    if name not in READERS:
        shown = file_type if len(file_type) <= 40 else file_type[:40] + "..."
        raise UnsupportedFormatError(
            f"unsupported mesh format {shown!r}; supported: {', '.join(SUPPORTED_FORMATS)}"
        )
    return name


def detect_format(filename: str | Path) -> str:
    """Format of a file name from its extension (e.g. ``"obj"``); UnsupportedFormatError if none."""
    suffix = Path(str(filename)).suffix
    if not suffix:
        raise UnsupportedFormatError(
            f"cannot tell the mesh format of {str(filename)!r}: it has no file extension; "
            f"use one of {', '.join('.' + f for f in SUPPORTED_FORMATS)}"
        )
    return normalize_format(suffix)


def sniff_format(data: bytes) -> str | None:
    """Best guess of the format from the first bytes, or None when unsure."""
    usd = sniff_usd(data)
    if usd is not None:
        return usd
    if looks_like_fbx(data):
        return "fbx"  # refused by name, with what to do instead
    head = strip_bom(data[:512]).lstrip()
    if head.startswith(b"glTF"):
        return "glb"
    if head.startswith(b"ply"):
        return "ply"
    first_word = head.split(None, 1)[0].upper() if head.split(None, 1) else b""
    if first_word.endswith(b"OFF"):
        return "off"
    if head[:1] == b"{" and b'"asset"' in data[:4096]:
        return "gltf"
    if head.lower().startswith(b"solid"):
        return "stl"
    if len(data) >= 84 and len(data) == 84 + 50 * int.from_bytes(data[80:84], "little"):
        return "stl"  # binary STL: the size matches the declared triangle count
    return None


def load_mesh(
    source: str | Path | bytes,
    file_type: str | None = None,
    *,
    max_faces: int | None = None,
    max_vertices: int | None = None,
) -> TriangleMesh:
    """Read a mesh from a path (format from the extension unless ``file_type`` is given)
    or from bytes (``file_type`` should be given; a few formats are recognised by content).
    A ``str`` is always a path: pass file contents as bytes.

    Raises a MeshError subclass for anything wrong with the input: UnsupportedFormatError,
    MeshParseError (empty, truncated, not that format), InvalidGeometryError, and
    MeshTooLargeError when the mesh has more than ``max_faces`` faces or triangles or
    more than ``max_vertices`` vertices, counting what glTF instancing expands to (both
    checked from declared counts before the arrays are made; None: no limit).
    """
    name, data = _read(source, file_type)
    with parse_guard(_FORMAT_NAMES[name]):
        return READERS[name](data, MeshLimits(max_faces, max_vertices))


def load_source(
    source: str | Path | bytes,
    file_type: str | None = None,
    *,
    max_faces: int | None = None,
    max_vertices: int | None = None,
) -> SourceMesh:
    """``load_mesh`` with the file's own normals, UVs, vertex colours, materials and scene
    objects (``exchange.attributes``; None for formats that hold none of them), for
    writing results back into the artist's file (``gltf_writer.parts_glb``). The mesh is
    the one ``load_mesh`` reads: same geometry, order and content hash.

    From a path, the files beside it are read too (an OBJ's ``.mtl`` files and textures,
    a USD layer's textures); from bytes, only what the bytes hold (a USDZ's textures)."""
    name, data = _read(source, file_type)
    side_files = None
    if not isinstance(source, bytes | bytearray | memoryview):
        side_files = SideFiles(Path(source).resolve().parent)
    with parse_guard(_FORMAT_NAMES[name]):
        return SOURCE_READERS[name](data, MeshLimits(max_faces, max_vertices), side_files)


def _read(source: str | Path | bytes, file_type: str | None) -> tuple[str, bytes]:
    """(format, bytes) of a path or bytes, with the errors of ``load_mesh``."""
    if isinstance(source, bytes | bytearray | memoryview):
        data = bytes(source)
        if file_type is None:
            file_type = sniff_format(data)
            if file_type is None:
                raise UnsupportedFormatError(
                    "cannot tell the mesh format of these bytes; pass file_type "
                    f"(one of {', '.join(SUPPORTED_FORMATS)})"
                )
        label = "the uploaded data"
    else:
        path = Path(source)
        file_type = detect_format(path) if file_type is None else file_type
        try:
            data = path.read_bytes()
        except OSError as exc:
            shown = str(path) if len(str(path)) <= 200 else str(path)[:200] + "..."
            raise MeshParseError(f"cannot read mesh file {shown!r}: {exc.strerror}") from exc
        label = f"{path.name!r}"
    name = normalize_format(file_type)
    if not data.strip():
        raise MeshParseError(f"{label} is empty; expected a {_FORMAT_NAMES[name]} mesh")
    return name, data


__all__ = [
    "SUPPORTED_FORMATS",
    "MeshLimits",
    "SourceMesh",
    "detect_format",
    "load_mesh",
    "load_source",
    "normalize_format",
    "sniff_format",
]
