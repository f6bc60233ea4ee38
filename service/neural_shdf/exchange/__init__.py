"""One reader per mesh file format, registered by extension (see ``neural_shdf.mesh_io``)."""

from collections.abc import Callable
from functools import partial

from neural_shdf.exchange._common import MeshLimits, Reader, fan_triangulate
from neural_shdf.exchange.attributes import SideFiles, SourceMesh
from neural_shdf.exchange.fbx import FBX_REFUSAL
from neural_shdf.exchange.gltf import read_glb, read_glb_source, read_gltf, read_gltf_source
from neural_shdf.exchange.obj import read_obj, read_obj_source
from neural_shdf.exchange.off import read_off
from neural_shdf.exchange.ply import read_ply, read_ply_source
from neural_shdf.exchange.stl import read_stl
from neural_shdf.exchange.usd import read_usd, read_usd_source, read_usda, read_usdc, read_usdz

#: Reader for each supported file extension (lower case, without the dot).
READERS: dict[str, Reader] = {
    "obj": read_obj,
    "off": read_off,
    "ply": read_ply,
    "stl": read_stl,
    "glb": read_glb,
    "gltf": read_gltf,
    "usd": read_usd,
    "usda": read_usda,
    "usdc": read_usdc,
    "usdz": read_usdz,
}

#: A reader that also keeps the file's attributes (normals, UVs, colours, materials,
#: objects); the side files are those of a file read from disk (None for bytes).
SourceReader = Callable[[bytes, MeshLimits, SideFiles | None], SourceMesh]


def _geometry_only(
    reader: Reader, data: bytes, limits: MeshLimits, _: SideFiles | None
) -> SourceMesh:
    return SourceMesh(reader(data, limits))


def _no_side_files(
    reader: Callable[..., SourceMesh], data: bytes, limits: MeshLimits, _: SideFiles | None
) -> SourceMesh:
    return reader(data, limits, attributes=True)


def _obj(data: bytes, limits: MeshLimits, side_files: SideFiles | None) -> SourceMesh:
    return read_obj_source(data, limits, attributes=True, side_files=side_files)


def _usd(name: str, data: bytes, limits: MeshLimits, side_files: SideFiles | None) -> SourceMesh:
    return read_usd_source(name, data, limits, attributes=True, side_files=side_files)


#: Reader with attributes for each extension of ``READERS`` (formats whose files hold no
#: attributes that the writers keep give the mesh alone).
SOURCE_READERS: dict[str, SourceReader] = {
    **{name: partial(_geometry_only, reader) for name, reader in READERS.items()},
    "obj": _obj,
    "ply": partial(_no_side_files, read_ply_source),
    "glb": partial(_no_side_files, read_glb_source),
    "gltf": partial(_no_side_files, read_gltf_source),
    **{name: partial(_usd, name) for name in ("usd", "usda", "usdc", "usdz")},
}

#: Formats refused on purpose, with the message that says what to do instead.
REFUSED: dict[str, str] = {"fbx": FBX_REFUSAL}

__all__ = [
    "READERS",
    "REFUSED",
    "SOURCE_READERS",
    "MeshLimits",
    "Reader",
    "SourceMesh",
    "SourceReader",
    "fan_triangulate",
]
