"""One reader per mesh file format, registered by extension (see ``neural_shdf.mesh_io``)."""

from collections.abc import Callable
from functools import partial

from neural_shdf.exchange._common import MeshLimits, Reader, fan_triangulate
from neural_shdf.exchange.attributes import SourceMesh
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

#: A reader that also keeps the file's attributes (normals, UVs, colours, materials, objects).
SourceReader = Callable[[bytes, MeshLimits], SourceMesh]


def _geometry_only(reader: Reader, data: bytes, limits: MeshLimits) -> SourceMesh:
    return SourceMesh(reader(data, limits))


#: Reader with attributes for each extension of ``READERS`` (formats whose files hold no
#: attributes that the writers keep give the mesh alone).
SOURCE_READERS: dict[str, SourceReader] = {
    **{name: partial(_geometry_only, reader) for name, reader in READERS.items()},
    "obj": partial(read_obj_source, attributes=True),
    "ply": partial(read_ply_source, attributes=True),
    "glb": partial(read_glb_source, attributes=True),
    "gltf": partial(read_gltf_source, attributes=True),
    **{
        name: partial(read_usd_source, name, attributes=True)
        for name in ("usd", "usda", "usdc", "usdz")
    },
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
