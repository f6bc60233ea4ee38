"""What a file holds beside the geometry: normals, UVs, vertex colours, materials and scene
objects, kept so that results can be written back into the artist's own kind of file.

The readers fill a ``SurfaceAttributes`` next to the ``TriangleMesh`` (``SourceMesh``) when
asked to (``mesh_io.load_source``); the mesh itself, its content hash and everything
cached from it are the same whether or not they are read.

Attributes belong to *attribute vertices*: a mesh vertex with one set of attribute values
(a glTF vertex, an OBJ ``v/vt/vn`` triple, a PLY vertex). Each triangle corner names its
attribute vertex (``corners``), so the writers give every part the corners' own values.
Normals, tangents and UVs are in the space of the corner's scene object (as the file
stores them); positions are those of the mesh (world space).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.mesh import TriangleMesh


@dataclass(frozen=True)
class SceneObject:
    """One object of the file's scene (a glTF node instance, a USD mesh prim).

    Attributes:
        name: the object's name in the file ('' when it has none).
        matrix: (4, 4) world transform of the object (column vectors: world = M @ local).
    """

    name: str
    matrix: NDArray[np.float64]

    @property
    def mirrors(self) -> bool:
        """Whether the transform mirrors (the readers reversed the winding under it)."""
        return bool(np.linalg.det(self.matrix[:3, :3]) < 0)


@dataclass(frozen=True)
class FaceGroup:
    """Triangles that share one object, one material and one set of attributes (a glTF
    primitive of one instance, an OBJ material); a writer's primitive per part."""

    object: int = -1  #: index into ``SurfaceAttributes.objects``; -1: no object
    material: int = -1  #: index into ``Materials.materials``; -1: none
    normals: bool = False
    tangents: bool = False
    uv_sets: int = 0  #: TEXCOORD_0 .. TEXCOORD_{uv_sets - 1}
    colors: bool = False


@dataclass(frozen=True)
class Materials:
    """The file's materials as glTF JSON, with what they need (textures, samplers, images).

    ``defined``: False when only names are known (an OBJ's ``usemtl``: the .mtl file is
    not read), so writers may still show part colours on those faces.
    """

    materials: tuple[dict[str, Any], ...] = ()
    textures: tuple[dict[str, Any], ...] = ()
    samplers: tuple[dict[str, Any], ...] = ()
    #: Image JSON without ``bufferView``/``uri`` when ``image_data`` holds its bytes.
    images: tuple[dict[str, Any], ...] = ()
    #: Encoded bytes of each image (None: the image keeps its external ``uri``).
    image_data: tuple[bytes | None, ...] = ()
    #: glTF extensions the materials and textures use (for ``extensionsUsed``).
    extensions: tuple[str, ...] = ()
    #: Of those, the ones the file required (``extensionsRequired``).
    required: tuple[str, ...] = ()
    defined: bool = True


@dataclass(frozen=True)
class SurfaceAttributes:
    """Per-corner attributes of a mesh (module docstring). ``K`` attribute vertices.

    Attributes:
        corners: (F, 3) attribute vertex of each triangle corner, in the mesh's corner order.
        vertex: (K,) the mesh vertex of each attribute vertex.
        normals: (K, 3) unit normals, or None when no group has them.
        tangents: (K, 4) glTF tangents (xyz, w the handedness), or None.
        uvs: (K, 2) arrays, one per UV set (glTF's TEXCOORD_n; V as glTF has it, down).
        colors: (K, 4) linear RGBA vertex colours, or None.
        face_group: (F,) index into ``groups`` of each triangle.
        groups: the face groups (which attributes each group really has).
        objects: the scene's objects, in reading order ('' named, identity: none).
        materials: the materials groups refer to.
    """

    corners: NDArray[np.int64]
    vertex: NDArray[np.int64]
    face_group: NDArray[np.int64]
    groups: tuple[FaceGroup, ...]
    normals: NDArray[np.float32] | None = None
    tangents: NDArray[np.float32] | None = None
    uvs: tuple[NDArray[np.float32], ...] = ()
    colors: NDArray[np.float32] | None = None
    objects: tuple[SceneObject, ...] = ()
    materials: Materials = field(default_factory=Materials)

    def check(self, mesh: TriangleMesh) -> None:
        """ValueError unless the attributes fit ``mesh`` (a reader's bug, never the user's)."""
        count = len(self.vertex)
        if self.corners.shape != mesh.faces.shape or self.face_group.shape != (mesh.face_count,):
            raise ValueError("attributes do not have one entry per triangle corner of the mesh")
        if len(self.corners) and not (self.corners.min() >= 0 and self.corners.max() < count):
            raise ValueError("a corner names an attribute vertex that does not exist")
        if not np.array_equal(self.vertex[self.corners], mesh.faces):
            raise ValueError("a corner's attribute vertex is not at the corner's mesh vertex")
        for name in ("normals", "tangents", "colors"):
            values = getattr(self, name)
            if values is not None and len(values) != count:
                raise ValueError(f"{name} do not have one row per attribute vertex")
        if any(len(uv) != count for uv in self.uvs):
            raise ValueError("UVs do not have one row per attribute vertex")


@dataclass(frozen=True)
class SourceMesh:
    """A mesh as read from a file, with the file's own attributes (None: none read)."""

    mesh: TriangleMesh
    attributes: SurfaceAttributes | None = None


def vertex_attributes(
    mesh: TriangleMesh,
    *,
    normals: NDArray[Any] | None = None,
    uv: NDArray[Any] | None = None,
    colors: NDArray[Any] | None = None,
) -> SurfaceAttributes | None:
    """Attributes given per mesh vertex (a PLY's): one face group, no object, no
    material; None when there are none. Normals that are not all usable, and UVs or
    colours that are not all finite, are left out."""
    if normals is not None:
        normals, usable = unit_normals(normals)
        normals = normals if usable else None
    if uv is not None and not finite_rows(uv):
        uv = None
    if colors is not None and not finite_rows(colors):
        colors = None
    if normals is None and uv is None and colors is None:
        return None
    group = FaceGroup(normals=normals is not None, uv_sets=int(uv is not None),
                      colors=colors is not None)  # fmt: skip
    attributes = SurfaceAttributes(
        corners=mesh.faces,
        vertex=np.arange(len(mesh.vertices), dtype=np.int64),
        face_group=np.zeros(mesh.face_count, dtype=np.int64),
        groups=(group,),
        normals=normals,
        uvs=() if uv is None else (np.asarray(uv, dtype=np.float32).reshape(-1, 2),),
        colors=None if colors is None else np.asarray(colors, dtype=np.float32).reshape(-1, 4),
    )
    attributes.check(mesh)
    return attributes


def unit_normals(normals: NDArray[Any]) -> tuple[NDArray[np.float32], bool]:
    """``(normals scaled to unit length, whether all of them could be)``: files may store
    normals of any length (OBJ's ``vn``), glTF needs unit ones; a zero or non-finite
    normal has no direction, so the caller drops those normals. Normals already of unit
    length (to float32 precision) are kept exactly as they are."""
    scaled, good = unit_normal_rows(normals)
    return scaled, bool(good.all())


def unit_normal_rows(normals: NDArray[Any]) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """``unit_normals`` row by row: the scaled normals and which rows have a direction."""
    normals = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    length = np.linalg.norm(normals, axis=1)
    good = np.isfinite(length) & (length > 1e-12)
    scale = good & (np.abs(length - 1.0) > 1e-6)
    scaled = np.where(good[:, None], normals, 0.0)
    scaled[scale] = normals[scale] / length[scale, None]
    return scaled.astype(np.float32), good


def finite_rows(values: NDArray[Any]) -> bool:
    """Whether every value is finite (UVs, colours: a NaN would make the output invalid)."""
    return bool(np.isfinite(values).all())


#: Largest side file read beside a mesh file (an OBJ's .mtl, a texture image).
MAX_SIDE_FILE_BYTES = 64 << 20
#: Most texture images carried from one file.
MAX_IMAGES = 256


@dataclass(frozen=True)
class SideFiles:
    """The folder of a mesh file read from disk: its side files (an OBJ's ``.mtl`` and
    textures, a USD layer's textures) are read from there. Bytes (an upload) have none:
    a server never reads its own disk for a client."""

    folder: Path

    def find(self, name: str, max_bytes: int = MAX_SIDE_FILE_BYTES) -> Path | None:
        """The file a mesh file names (relative to the folder, or absolute; Windows
        separators accepted; a name not found there is looked for by its last component
        in the folder, as when textures travel with the file), or None when it is
        missing, not a plain file or larger than ``max_bytes``."""
        name = name.strip().replace("\\", "/")
        if not name:
            return None
        given = Path(name)
        for path in (given if given.is_absolute() else self.folder / given,
                     self.folder / given.name):  # fmt: skip
            try:
                if path.is_file() and path.stat().st_size <= max_bytes:
                    return path
            except OSError:
                continue
        return None

    def read(self, name: str, max_bytes: int = MAX_SIDE_FILE_BYTES) -> bytes | None:
        """The bytes of the file ``find`` finds, or None."""
        path = self.find(name, max_bytes)
        try:
            return None if path is None else path.read_bytes()
        except OSError:
            return None


def image_mime_type(data: bytes) -> str | None:
    """``image/png`` or ``image/jpeg`` (the images core glTF holds); None for others."""
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        return "image/png"
    if data.startswith(b"\xff\xd8\xff"):
        return "image/jpeg"
    return None


#: Material keys that name a texture (removed for faces without UVs).
_TEXTURE_KEYS = ("baseColorTexture", "metallicRoughnessTexture", "normalTexture",
                 "occlusionTexture", "emissiveTexture")  # fmt: skip


class MaterialTable:
    """glTF materials made by a reader from the file's own (an OBJ's ``.mtl``, USD's
    UsdPreviewSurface), with their images embedded, each material and image once."""

    def __init__(self) -> None:
        self.materials: list[dict[str, Any]] = []
        self.textures: list[dict[str, Any]] = []
        self.samplers: list[dict[str, Any]] = []
        self.images: list[dict[str, Any]] = []
        self.image_data: list[bytes | None] = []
        self._material_keys: dict[Any, int] = {}
        self._untextured: dict[int, int] = {}
        self._texture_keys: dict[Any, int] = {}

    def find(self, key: Any) -> int | None:
        """The index of the material added under ``key``, if any."""
        return self._material_keys.get(key)

    def add(self, key: Any, material: dict[str, Any]) -> int:
        """Index of ``material`` (glTF JSON), added once per ``key``."""
        if key not in self._material_keys:
            self._material_keys[key] = len(self.materials)
            self.materials.append(material)
        return self._material_keys[key]

    def texture(self, image: bytes, sampler: dict[str, Any] | None = None) -> int | None:
        """Index of a texture of the encoded ``image`` (PNG or JPEG; None for another kind
        of image, or past ``MAX_IMAGES``), the same image and sampler once."""
        mime = image_mime_type(image)
        if mime is None:
            return None
        key = (image, repr(sorted((sampler or {}).items())))
        if key not in self._texture_keys:
            if len(self.images) >= MAX_IMAGES:
                return None
            texture: dict[str, Any] = {"source": len(self.images)}
            self.images.append({"mimeType": mime})
            self.image_data.append(image)
            if sampler:
                texture["sampler"] = len(self.samplers)
                self.samplers.append(sampler)
            self._texture_keys[key] = len(self.textures)
            self.textures.append(texture)
        return self._texture_keys[key]

    def for_faces(self, index: int, has_uv: bool) -> int:
        """``index``, or for faces without UVs a copy of that material without its
        textures (a textured primitive needs TEXCOORD_0: glTF would be invalid)."""
        material = self.materials[index]
        if has_uv or not any(key in material.get("pbrMetallicRoughness", {}) or key in material
                             for key in _TEXTURE_KEYS):  # fmt: skip
            return index
        if index not in self._untextured:
            plain = copy.deepcopy(material)
            for key in _TEXTURE_KEYS:
                plain.pop(key, None)
                plain.get("pbrMetallicRoughness", {}).pop(key, None)
            self._untextured[index] = len(self.materials)
            self.materials.append(plain)
        return self._untextured[index]

    def result(self) -> Materials:
        return Materials(
            materials=tuple(self.materials),
            textures=tuple(self.textures),
            samplers=tuple(self.samplers),
            images=tuple(self.images),
            image_data=tuple(self.image_data),
        )


__all__ = [
    "MAX_SIDE_FILE_BYTES",
    "FaceGroup",
    "MaterialTable",
    "Materials",
    "SceneObject",
    "SideFiles",
    "SourceMesh",
    "SurfaceAttributes",
    "finite_rows",
    "image_mime_type",
    "unit_normal_rows",
    "unit_normals",
    "vertex_attributes",
]
