"""One reader per mesh file format, registered by extension (see ``neural_shdf.mesh_io``)."""

from neural_shdf.exchange._common import MeshLimits, Reader, fan_triangulate
from neural_shdf.exchange.fbx import FBX_REFUSAL
from neural_shdf.exchange.gltf import read_glb, read_gltf
from neural_shdf.exchange.obj import read_obj
from neural_shdf.exchange.off import read_off
from neural_shdf.exchange.ply import read_ply
from neural_shdf.exchange.stl import read_stl
from neural_shdf.exchange.usd import read_usd, read_usda, read_usdc, read_usdz

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

#: Formats refused on purpose, with the message that says what to do instead.
REFUSED: dict[str, str] = {"fbx": FBX_REFUSAL}

__all__ = ["READERS", "REFUSED", "MeshLimits", "Reader", "fan_triangulate"]
