"""USD reader (``.usd``, ``.usda``, ``.usdc``, ``.usdz``) with Pixar's ``usd-core``.

What is read, and the face order (what "input face order" means for USD):

* Every ``UsdGeom.Mesh`` prim of the composed stage, in stage traversal order
  (depth first, children in namespace order), instance proxies included: a mesh
  under an instanceable prim appears once per instance. Meshes whose computed
  purpose is ``guide`` or ``proxy`` are left out: they stand in for, or annotate,
  the render geometry and would overlap it. ``mesh_prims`` gives that list; the
  writer (``neural_shdf.exchange.usd_write``) uses the same one.
* Input faces are each prim's ``faceVertexCounts`` in order, prim after prim.
  Polygons are fan-triangulated (``fan_triangulate``). Faces listed in
  ``holeIndices`` and faces with fewer than 3 vertices are input faces without
  triangles (label -1 in per-face outputs).
* Geometry at the earliest time sample (the first frame of animated meshes; the
  default value otherwise), with the prim's local-to-world transform applied.
  ``orientation = "leftHanded"`` and mirroring transforms reverse each polygon's
  winding (its first vertex kept), so normals point outwards.
* ``UsdGeom.PointInstancer`` prims are refused (their instances cannot carry a
  per-face result back into the file); so are stages that load layers from outside
  the uploaded file or package (a server must not read its own disk for a client),
  layers named by variable expressions, and value clips.

usd-core opens files, not bytes: the data is written to a private temporary
folder first. Size limits: before usd-core opens anything, every array a crate
layer declares (the file, or each layer of a USDZ) must fit a mesh within the
limits (``check_crate_arrays``: compressed arrays could otherwise expand thousands
of times); then every prim's ``faceVertexCounts`` are read and the face and
triangle budgets checked before indices and points are read.

A ``.usda`` has its large numeric arrays parsed by ``_usda_arrays`` (usd-core's text
parser reads about 25 MB/s) and put back into the root layer before the stage is
composed; the file is read by usd-core alone whenever that cannot be done exactly.

``pxr`` (usd-core) is imported inside the functions that use it: it is slow to import and
only USD files need it (docs/benchmarks.md, "Start-up and imports").
"""

from __future__ import annotations

import io
import os
import re
import tempfile
import zipfile
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import (
    InvalidGeometryError,
    MeshParseError,
    MeshTooLargeError,
    ParameterError,
    UnsupportedFormatError,
)
from neural_shdf.exchange._common import NO_LIMITS, MeshLimits, build_mesh, fan_triangulate
from neural_shdf.exchange._usda_arrays import cut_arrays, restore_arrays
from neural_shdf.exchange._usdc import crate_array_sizes
from neural_shdf.exchange.attributes import (
    MAX_SIDE_FILE_BYTES,
    FaceGroup,
    MaterialTable,
    SceneObject,
    SideFiles,
    SourceMesh,
    SurfaceAttributes,
    finite_rows,
    unit_normals,
)
from neural_shdf.exchange.gltf_writer import part_name
from neural_shdf.mesh import TriangleMesh
from neural_shdf.palette import UNLABELED_COLOR, part_colors, srgb_to_linear

FORMAT_NAME = "USD"
#: File extensions of USD (lower case, without the dot).
USD_EXTENSIONS = ("usd", "usda", "usdc", "usdz")
#: Cap on the layers a stage may pull in (sublayers, references, payloads, all within
#: the uploaded file or package).
MAX_LAYERS = 1000
_SKIPPED_PURPOSES = ("guide", "proxy")
#: Most mesh prims read from one stage (each costs a fixed time, whatever its size).
MAX_MESH_PRIMS = 100_000
#: GeomSubset family of the parts that write_usd_parts adds.
PART_FAMILY = "part"


def sniff_usd(data: bytes) -> str | None:
    """``"usda"``, ``"usdc"`` or ``"usdz"`` when the bytes start like that kind of USD."""
    if data.startswith(b"#usda"):
        return "usda"
    if data.startswith(b"PXR-USDC"):
        return "usdc"
    # A USDZ is a zip whose first entry is a USD layer (local header: name at byte 30).
    if data.startswith(b"PK\x03\x04") and len(data) > 30:
        name_length = int.from_bytes(data[26:28], "little")
        first = data[30 : 30 + name_length].lower()
        if first.endswith((b".usd", b".usda", b".usdc")):
            return "usdz"
    return None


@contextmanager
def usd_file(data: bytes, extension: str) -> Iterator[Path]:
    """The bytes as a file in a private temporary folder, removed afterwards."""
    with tempfile.TemporaryDirectory(prefix="neural-shdf-usd-") as folder:
        path = Path(folder) / f"upload.{extension}"
        path.write_bytes(data)
        yield path


def _inside(path: str, folder: Path) -> bool:
    """Whether a layer's real path lies in ``folder`` (package paths: ``pkg.usdz[a.usd]``)."""
    real = path.split("[", 1)[0]
    return bool(real) and os.path.realpath(real).startswith(str(folder.resolve()) + os.sep)


def check_layers_inside(path: Path) -> list[Any]:
    """UnsupportedFormatError unless every layer the file composes (sublayers, references,
    payloads, recursively) is the file itself or inside it (a USDZ's own layers).

    Returns the opened layers, root first: while they are held, opening the stage reuses
    them (usd-core's layer registry) instead of parsing every layer a second time."""
    from pxr import Sdf

    root = Sdf.Layer.FindOrOpen(str(path))
    if root is None:
        raise MeshParseError("usd-core could not open the file as a USD layer")
    seen = {root.identifier}
    opened = [root]
    pending = [root]
    while pending:
        layer = pending.pop()
        for asset in sorted(layer.GetCompositionAssetDependencies()):
            if not asset:  # an internal reference (to a prim of the same layer)
                continue
            if asset.startswith("`"):
                raise UnsupportedFormatError(
                    f"the USD stage names a layer with a variable expression ({asset}); "
                    "flatten the stage into one file (usdcat --flatten)"
                )
            resolved = layer.ComputeAbsolutePath(asset)
            if not _inside(resolved, path.parent):
                raise UnsupportedFormatError(
                    f"the USD stage loads the layer {asset!r} from outside the uploaded file; "
                    "flatten the stage into one file (usdcat --flatten) or package it as "
                    ".usdz (usdzip)"
                )
            if resolved in seen:
                continue
            seen.add(resolved)
            if len(seen) > MAX_LAYERS:
                raise UnsupportedFormatError(f"the USD stage has more than {MAX_LAYERS} layers")
            child = Sdf.Layer.FindOrOpen(resolved)
            if child is None:
                raise MeshParseError(f"the USD layer {asset!r} is missing from the file")
            pending.append(child)
            opened.append(child)
    return opened


class _ArraysNotRestored(Exception):  # noqa: N818 - a signal to read the text whole
    """The cut arrays of a ``.usda`` could not all be put back (``_usda_arrays``)."""


def open_stage(path: Path, prepare: Callable[[Any], bool] | None = None) -> Any:
    """The composed stage of a USD file whose layers were checked with check_layers_inside.

    ``prepare``: called with the root layer before the stage is composed
    (``_usda_arrays.restore_arrays``); False raises ``_ArraysNotRestored``."""
    from pxr import Usd

    layers = check_layers_inside(path)
    if prepare is not None and not prepare(layers[0]):
        raise _ArraysNotRestored
    stage = Usd.Stage.Open(layers[0], Usd.Stage.LoadAll)  # the layers parsed once
    del layers  # the stage holds what it uses
    if stage is None:
        raise MeshParseError("usd-core could not open the file as a USD stage")
    return stage


def mesh_prims(stage: Any) -> list[Any]:
    """The stage's mesh prims in reading order (module docstring); UnsupportedFormatError
    at a point instancer."""
    from pxr import Usd, UsdGeom

    prims = []
    for prim in stage.Traverse(Usd.TraverseInstanceProxies()):
        if prim.HasAuthoredMetadata("clips"):  # value clips load layers of their own
            raise UnsupportedFormatError(
                f"the USD prim {prim.GetPath()} takes its values from clips (other layers); "
                "flatten the stage into one file (usdcat --flatten)"
            )
        if prim.IsA(UsdGeom.PointInstancer):
            raise UnsupportedFormatError(
                f"the USD point instancer {prim.GetPath()} is not supported: make its "
                "instances real meshes (Blender: Realize Instances; Houdini: Unpack) or "
                "export the scene without point instancing"
            )
        if not prim.IsA(UsdGeom.Mesh):
            continue
        if UsdGeom.Imageable(prim).ComputePurpose() in _SKIPPED_PURPOSES:
            continue
        prims.append(prim)
        if len(prims) > MAX_MESH_PRIMS:
            raise MeshTooLargeError(
                f"the USD stage has more than {MAX_MESH_PRIMS} mesh prims; merge them into "
                "fewer meshes before uploading",
                limit="mesh_prims",
                maximum=MAX_MESH_PRIMS,
                found=len(prims),
            )
    return prims


@dataclass(frozen=True)
class _PrimFaces:
    """One mesh prim's polygons, read before its indices and points."""

    prim: Any
    counts: NDArray[np.int64]
    holes: NDArray[np.int64]


def _array(attribute: Any, time: Any, dtype: Any) -> NDArray[Any]:
    value = attribute.Get(time)
    if value is None:
        return np.zeros(0, dtype=dtype)
    # View the Vt array's buffer, then convert: converting directly walks Vec3f elements
    # one by one in Python.
    return np.asarray(value).astype(dtype)


def _reverse_windings(counts: NDArray[np.int64], flat: NDArray[np.int64]) -> NDArray[np.int64]:
    """Each polygon's ring ``v0, v1, ..., vn-1`` as ``v0, vn-1, ..., v1`` (same first vertex,
    so the fan convention holds)."""
    starts = np.repeat(np.cumsum(counts) - counts, counts)
    sizes = np.repeat(counts, counts)
    k = np.arange(len(flat), dtype=np.int64) - starts
    reversed_flat: NDArray[np.int64] = flat[starts + (sizes - k) % sizes]
    return reversed_flat


def _prim_label(prim: Any) -> str:
    return f"USD mesh {prim.GetPath()}"


def read_usd_stage(stage: Any, limits: MeshLimits = NO_LIMITS) -> TriangleMesh:
    """All mesh prims of an open stage as one TriangleMesh (order: module docstring)."""
    return read_usd_stage_source(stage, limits).mesh


def read_usd_stage_source(
    stage: Any,
    limits: MeshLimits = NO_LIMITS,
    *,
    attributes: bool = False,
    package: Path | None = None,
    side_files: SideFiles | None = None,
) -> SourceMesh:
    """``read_usd_stage`` with, when ``attributes``, one scene object per mesh prim (its
    path and world transform), its normals, its ``st`` UVs (V turned to glTF's downward
    V), its ``displayColor`` (on faces without a material) and its bound materials
    (``UsdPreviewMaterials``: per prim and per ``materialBind`` GeomSubset), for
    ``gltf_writer.parts_glb``. Textures are read from inside ``package`` (the folder
    of the uploaded file: a USDZ's own images) or from ``side_files``."""
    from pxr import Usd, UsdGeom

    time = Usd.TimeCode.EarliestTime()
    polygons: list[_PrimFaces] = []
    face_total = triangle_total = 0
    for prim in mesh_prims(stage):
        mesh = UsdGeom.Mesh(prim)
        counts = _array(mesh.GetFaceVertexCountsAttr(), time, np.int64)
        holes = _array(mesh.GetHoleIndicesAttr(), time, np.int64)
        if len(counts) and counts.min() < 0:
            raise MeshParseError(f"{_prim_label(prim)} has a negative faceVertexCount")
        face_total += len(counts)
        triangle_total += int(np.maximum(counts - 2, 0).sum())
        limits.check_faces(face_total, at_least=True)
        limits.check_faces(triangle_total, "triangles", at_least=True)
        polygons.append(_PrimFaces(prim, counts, holes))
    if not polygons:
        raise MeshParseError("the USD stage has no Mesh prim (UsdGeom.Mesh) to read")

    xforms = UsdGeom.XformCache(time)
    kept = _UsdAttributes(UsdPreviewMaterials(time, package, side_files)) if attributes else None
    vertex_parts: list[NDArray[Any]] = []
    face_parts: list[NDArray[Any]] = []
    origin_parts: list[NDArray[Any]] = []
    vertex_offset = face_offset = 0
    for entry in polygons:
        prim, counts = entry.prim, entry.counts
        mesh = UsdGeom.Mesh(prim)
        flat = _array(mesh.GetFaceVertexIndicesAttr(), time, np.int64)
        if len(flat) != int(counts.sum()):
            raise MeshParseError(
                f"{_prim_label(prim)}: faceVertexIndices has {len(flat)} entries but "
                f"faceVertexCounts adds up to {int(counts.sum())}"
            )
        points = _array(mesh.GetPointsAttr(), time, np.float64).reshape(-1, 3)
        limits.check_vertices(vertex_offset + len(points), at_least=True)
        matrix = np.array(xforms.GetLocalToWorldTransform(prim), dtype=np.float64)
        points = points @ matrix[:3, :3] + matrix[3, :3]  # USD transforms row vectors
        left_handed = mesh.GetOrientationAttr().Get(time) == UsdGeom.Tokens.leftHanded
        file_flat = flat
        corner_ids = np.arange(len(flat), dtype=np.int64)  # the file's corner of each entry
        if left_handed != (np.linalg.det(matrix[:3, :3]) < 0):
            flat = _reverse_windings(counts, flat)
            corner_ids = _reverse_windings(counts, corner_ids)
        usable = counts.copy()
        holes = entry.holes[(entry.holes >= 0) & (entry.holes < len(counts))]
        usable[holes] = 0  # a hole stays an input face, without triangles
        if len(holes):
            keep = np.repeat(usable > 0, counts)
            flat, triangulated = flat[keep], usable[usable > 0]
            corner_ids = corner_ids[keep]
            faces, local_origin = fan_triangulate(triangulated, flat)
            triangle_corners, _ = fan_triangulate(triangulated, corner_ids)
            local_origin = np.flatnonzero(usable > 0)[local_origin]
        else:
            faces, local_origin = fan_triangulate(counts, flat)
            triangle_corners, _ = fan_triangulate(counts, corner_ids)
        bad = (faces < 0) | (faces >= len(points))
        if bad.any():
            face = int(local_origin[np.flatnonzero(bad.any(axis=1))[0]])
            raise InvalidGeometryError(
                f"{_prim_label(prim)}: face {face} refers to a point that does not exist "
                f"(the prim has {len(points)} points)"
            )
        if kept is not None:
            kept.add(
                mesh, time, matrix.T, counts, file_flat, triangle_corners, local_origin,
                vertex_offset,
            )  # fmt: skip
        vertex_parts.append(points)
        face_parts.append(faces + vertex_offset)
        origin_parts.append(local_origin + face_offset)
        vertex_offset += len(points)
        face_offset += len(counts)
    read = build_mesh(
        np.concatenate(vertex_parts),
        np.concatenate(face_parts),
        np.concatenate(origin_parts),
        face_offset,
        format_name=FORMAT_NAME,
        limits=limits,
    )
    return SourceMesh(read, None if kept is None else kept.result(read))


class _UsdAttributes:
    """Per mesh prim: a scene object, a face group per bound material, and attribute
    vertices (one per distinct point, ``st`` value, normal and display colour a triangle
    corner uses)."""

    def __init__(self, materials: UsdPreviewMaterials) -> None:
        self.material_reader = materials
        self.objects: list[SceneObject] = []
        self.groups: list[FaceGroup] = []
        self.face_group: list[NDArray[np.int64]] = []
        self.corners: list[NDArray[np.int64]] = []
        self.vertex: list[NDArray[np.int64]] = []
        self.uv: list[NDArray[np.float32] | None] = []
        self.normals: list[NDArray[np.float32] | None] = []
        self.colors: list[NDArray[np.float32] | None] = []
        self.count = 0

    def add(
        self,
        mesh: Any,
        time: Any,
        matrix: NDArray[np.float64],
        counts: NDArray[np.int64],
        flat: NDArray[np.int64],
        triangle_corners: NDArray[np.int64],
        triangle_face: NDArray[np.int64],
        vertex_offset: int,
    ) -> None:
        from pxr import UsdGeom

        primvars = UsdGeom.PrimvarsAPI(mesh)
        face_of_corner = np.repeat(np.arange(len(counts), dtype=np.int64), counts)
        st = _corner_values(primvars.GetPrimvar("st"), time, flat, face_of_corner, 2)
        normal_primvar = primvars.GetPrimvar("normals")
        if normal_primvar and normal_primvar.HasAuthoredValue():
            found = _corner_values(normal_primvar, time, flat, face_of_corner, 3)
        else:
            found = _corner_values(
                mesh.GetNormalsAttr(), time, flat, face_of_corner, 3,
                interpolation=mesh.GetNormalsInterpolation(),
            )  # fmt: skip
        normals: tuple[NDArray[np.float32], NDArray[np.int64]] | None = None
        if found is not None:
            unit, usable = unit_normals(found[0])
            normals = (unit, found[1]) if usable else None
        display = _corner_values(primvars.GetPrimvar("displayColor"), time, flat, face_of_corner, 3)
        corners = triangle_corners.reshape(-1)
        vertex = flat[corners]
        key = vertex
        for table_size, index in (
            (len(st[0]), st[1]) if st is not None else (0, None),
            (len(normals[0]), normals[1]) if normals is not None else (0, None),
            (len(display[0]), display[1]) if display is not None else (0, None),
        ):
            if index is not None:
                _, pairs = np.unique(key * (table_size + 1) + index[corners], return_inverse=True)
                key = pairs.reshape(-1)
        _, first, corner_key = np.unique(key, return_index=True, return_inverse=True)
        self.objects.append(SceneObject(str(mesh.GetPath()), matrix))
        # One group per material of the prim's faces (in order of first use); the
        # display colour shows only where no material is bound, as in USD.
        face_material = self.material_reader.face_materials(mesh.GetPrim(), len(counts))
        triangle_material = face_material[triangle_face]
        used, first_use, group_of = np.unique(
            triangle_material, return_index=True, return_inverse=True
        )
        order = np.argsort(first_use, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(len(order))
        table = self.material_reader.table
        self.face_group.append(len(self.groups) + rank[group_of.reshape(-1)])
        for material in used[order].tolist():
            self.groups.append(
                FaceGroup(
                    object=len(self.objects) - 1,
                    material=-1 if material < 0 else table.for_faces(material, st is not None),
                    normals=normals is not None,
                    uv_sets=int(st is not None),
                    colors=display is not None and material < 0,
                )
            )
        self.corners.append(corner_key.reshape(-1, 3) + self.count)
        self.vertex.append(vertex[first] + vertex_offset)
        chosen = corners[first]
        if st is not None:
            uv = st[0][st[1][chosen]].astype(np.float32)
            uv[:, 1] = 1.0 - uv[:, 1]  # USD's st has V up, glTF's V points down
            self.uv.append(uv)
        else:
            self.uv.append(None)
        self.normals.append(None if normals is None else normals[0][normals[1][chosen]])
        if display is not None:
            rgb = np.clip(display[0][display[1][chosen]], 0.0, 1.0)  # linear, as glTF's
            self.colors.append(np.column_stack([rgb, np.ones(len(rgb))]).astype(np.float32))
        else:
            self.colors.append(None)
        self.count += len(first)

    def result(self, mesh: TriangleMesh) -> SurfaceAttributes:
        def column(blocks: list[NDArray[np.float32] | None], width: int) -> NDArray[np.float32]:
            return np.concatenate(
                [
                    np.zeros((len(v), width), np.float32) if b is None else b
                    for b, v in zip(blocks, self.vertex, strict=True)
                ]
            ).astype(np.float32)

        has_uv = any(g.uv_sets for g in self.groups)
        attributes = SurfaceAttributes(
            corners=np.concatenate(self.corners).astype(np.int64),
            vertex=np.concatenate(self.vertex).astype(np.int64),
            face_group=np.concatenate(self.face_group).astype(np.int64),
            groups=tuple(self.groups),
            normals=column(self.normals, 3) if any(g.normals for g in self.groups) else None,
            uvs=(column(self.uv, 2),) if has_uv else (),
            colors=column(self.colors, 4) if any(g.colors for g in self.groups) else None,
            objects=tuple(self.objects),
            materials=self.material_reader.table.result(),
        )
        attributes.check(mesh)
        return attributes


#: glTF sampler wrap mode of UsdUVTexture's ``wrapS``/``wrapT`` (``black``: clamped,
#: the nearest glTF has).
_WRAP_MODES = {"repeat": 10497, "mirror": 33648, "clamp": 33071, "black": 33071}


class UsdPreviewMaterials:
    """The materials bound to mesh prims, as glTF metallic-roughness materials (one per
    USD material, named by its path): a ``UsdPreviewSurface``'s ``diffuseColor`` (a value,
    or a ``UsdUVTexture``'s ``rgb`` read through the ``st`` primvar: the base colour
    texture, its ``scale`` the factor), ``opacity`` (``opacityThreshold``: a mask),
    ``roughness``, ``metallic`` and ``emissiveColor`` values. Texture images (PNG, JPEG)
    are read from inside ``package`` (the uploaded file's folder: a USDZ's images) or
    from ``side_files``; one that is missing leaves the material untextured. A material
    without a UsdPreviewSurface (MaterialX alone, say) becomes a named grey one."""

    def __init__(self, time: Any, package: Path | None, side_files: SideFiles | None) -> None:
        self.time = time
        self.package = package
        self.side_files = side_files
        self.table = MaterialTable()

    def face_materials(self, prim: Any, face_count: int) -> NDArray[np.int64]:
        """Material index (in ``table``) of each face of a mesh prim; -1 where none."""
        from pxr import UsdGeom, UsdShade

        faces = np.full(face_count, -1, dtype=np.int64)
        binding = UsdShade.MaterialBindingAPI(prim)
        material, _ = binding.ComputeBoundMaterial()
        if material:
            faces[:] = self.index(material)
        for subset in UsdGeom.Subset.GetGeomSubsets(
            UsdGeom.Imageable(prim), UsdGeom.Tokens.face, UsdShade.Tokens.materialBind
        ):
            material, _ = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()
            if not material:
                continue
            chosen = _array(subset.GetIndicesAttr(), self.time, np.int64)
            chosen = chosen[(chosen >= 0) & (chosen < face_count)]
            faces[chosen] = self.index(material)
        return faces

    def index(self, material: Any) -> int:
        key = str(material.GetPath())
        found = self.table.find(key)
        return found if found is not None else self.table.add(key, self._gltf(material))

    def _gltf(self, material: Any) -> dict[str, Any]:
        from pxr import UsdShade

        pbr: dict[str, Any] = {}
        out: dict[str, Any] = {"name": str(material.GetPath()), "pbrMetallicRoughness": pbr}
        shader = material.ComputeSurfaceSource()[0]
        if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
            shader = None
        color = [0.18, 0.18, 0.18]  # UsdPreviewSurface's defaults
        alpha, roughness, metallic = 1.0, 0.5, 0.0
        if shader is not None:
            diffuse = self._input(shader, "diffuseColor")
            if isinstance(diffuse, UsdShade.Output):
                texture = self._texture(diffuse)
                if texture is not None:
                    pbr["baseColorTexture"] = {"index": texture[0]}
                color = texture[1] if texture is not None else [1.0, 1.0, 1.0]
            elif diffuse is not None:
                color = [float(c) for c in diffuse]
            opacity = self._input(shader, "opacity")
            if isinstance(opacity, UsdShade.Output):
                # The diffuse texture's alpha: glTF reads it from the base colour texture.
                same = isinstance(diffuse, UsdShade.Output) and (
                    opacity.GetPrim().GetPath() == diffuse.GetPrim().GetPath()
                    and opacity.GetBaseName() == "a"
                )
                if same and "baseColorTexture" in pbr:
                    out["alphaMode"] = "BLEND"
            elif opacity is not None:
                alpha = float(opacity)
            roughness = _number(self._input(shader, "roughness"), roughness)
            metallic = _number(self._input(shader, "metallic"), metallic)
            emission = self._input(shader, "emissiveColor")
            if emission is not None and not isinstance(emission, UsdShade.Output):
                emissive = [float(np.clip(c, 0.0, 1.0)) for c in emission]
                if any(emissive):
                    out["emissiveFactor"] = emissive
            threshold = _number(self._input(shader, "opacityThreshold"), 0.0)
            if threshold > 0:
                out["alphaMode"] = "MASK"
                out["alphaCutoff"] = float(threshold)
            elif alpha < 1:
                out["alphaMode"] = "BLEND"
        finite = [c if np.isfinite(c) else 1.0 for c in color[:3]]
        pbr["baseColorFactor"] = [float(np.clip(c, 0.0, 1.0)) for c in [*finite, alpha]]
        pbr["roughnessFactor"] = float(np.clip(roughness, 0.0, 1.0))
        pbr["metallicFactor"] = float(np.clip(metallic, 0.0, 1.0))
        return out

    def _input(self, shader: Any, name: str) -> Any:
        """An input's value, the ``UsdShade.Output`` it is connected to, or None."""
        from pxr import UsdShade

        found = shader.GetInput(name)
        if not found:
            return None
        sources = found.GetValueProducingAttributes()
        if not sources:
            return None
        source = sources[0]
        if UsdShade.Output.IsOutput(source):
            return UsdShade.Output(source)
        return source.Get(self.time)

    def _texture(self, output: Any) -> tuple[int, list[float]] | None:
        """(texture index, colour factor) of a ``UsdUVTexture``'s ``rgb`` output read
        through the ``st`` primvar; None when it cannot be carried."""
        from pxr import UsdShade

        texture = UsdShade.Shader(output.GetPrim())
        if texture.GetIdAttr().Get() != "UsdUVTexture" or output.GetBaseName() != "rgb":
            return None
        reader = self._input(texture, "st")
        if not isinstance(reader, UsdShade.Output):
            return None
        primvar_reader = UsdShade.Shader(reader.GetPrim())
        if self._input(primvar_reader, "varname") != "st":  # the only UVs read
            return None
        asset = self._input(texture, "file")
        image = None if asset is None else self._image(asset)
        if image is None:
            return None
        wraps = [_WRAP_MODES.get(str(self._input(texture, w)), 10497) for w in ("wrapS", "wrapT")]
        sampler = None if wraps == [10497, 10497] else {"wrapS": wraps[0], "wrapT": wraps[1]}
        index = self.table.texture(image, sampler)
        if index is None:
            return None
        scale = self._input(texture, "scale")
        factor = [1.0, 1.0, 1.0] if scale is None else [float(c) for c in list(scale)[:3]]
        return index, factor

    def _image(self, asset: Any) -> bytes | None:
        """The bytes of a texture asset: from inside the package, else a side file."""
        from pxr import Ar, Sdf

        if not isinstance(asset, Sdf.AssetPath):
            return None
        resolved = str(asset.resolvedPath)
        if resolved and self.package is not None and _inside(resolved, self.package):
            found = Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved))
            if found is not None and found.GetSize() <= MAX_SIDE_FILE_BYTES:
                return bytes(found.GetBuffer())
        if self.side_files is not None and asset.path:
            return self.side_files.read(str(asset.path))
        return None


def _number(value: Any, default: float) -> float:
    """A shader input's scalar value (``default`` when connected, absent or not finite)."""
    if isinstance(value, int | float) and np.isfinite(value):
        return float(value)
    return default


def _corner_values(
    source: Any,
    time: Any,
    flat: NDArray[np.int64],
    face_of_corner: NDArray[np.int64],
    width: int,
    *,
    interpolation: str | None = None,
) -> tuple[NDArray[np.float64], NDArray[np.int64]] | None:
    """``(table, index of each face corner's value in it)`` of a primvar (or the normals
    attribute, whose ``interpolation`` is given), or None when it is absent or does not
    fit the prim (wrong length, wrong width, values that are not finite)."""
    from pxr import UsdGeom

    if not source or not source.HasAuthoredValue():
        return None
    raw = source.Get(time)
    if raw is None or len(raw) == 0:
        return None
    table = np.asarray(raw, dtype=np.float64)
    if table.ndim != 2 or table.shape[1] != width or not finite_rows(table):
        return None
    indices = None
    if interpolation is None:
        interpolation = source.GetInterpolation()
        if source.IsIndexed():
            indices = np.asarray(source.GetIndices(time), dtype=np.int64)
    base = {
        UsdGeom.Tokens.vertex: flat,
        UsdGeom.Tokens.varying: flat,
        UsdGeom.Tokens.faceVarying: np.arange(len(flat), dtype=np.int64),
        UsdGeom.Tokens.uniform: face_of_corner,
        UsdGeom.Tokens.constant: np.zeros(len(flat), dtype=np.int64),
    }.get(interpolation)
    if base is None:
        return None
    if indices is not None:
        if len(base) and (base.max() >= len(indices)):
            return None
        base = indices[base]
    if len(base) and (base.min() < 0 or base.max() >= len(table)):
        return None
    return table, base


def _usd_message(error: Exception) -> str:
    """usd-core's own words from its error (without the C++ function and source line)."""
    found = re.findall(r" : '(.*?)'\s*$", str(error), flags=re.MULTILINE)
    return "; ".join(found) or str(error).strip()


def read_usd_path(path: str | Path, limits: MeshLimits = NO_LIMITS) -> TriangleMesh:
    """Read a USD file on disk (its layers must lie inside it: see check_layers_inside)."""
    from pxr import Tf

    try:
        return read_usd_stage(open_stage(Path(path)), limits)
    except Tf.ErrorException as error:
        raise MeshParseError(f"usd-core could not read the file: {_usd_message(error)}") from None


def _crate_layers(data: bytes) -> Iterator[tuple[str, bytes]]:
    """(name, bytes) of each crate layer: the file itself, or the ones in a USDZ."""
    if data.startswith(b"PXR-USDC"):
        yield "the file", data
    elif data.startswith(b"PK\x03\x04"):
        with zipfile.ZipFile(io.BytesIO(data)) as package:
            for entry in package.infolist():
                if entry.compress_type != zipfile.ZIP_STORED:
                    raise MeshParseError(
                        f"the USDZ entry {entry.filename!r} is compressed; a USDZ package "
                        "stores its files uncompressed (make it with usdzip)"
                    )
                with package.open(entry) as member:
                    if member.read(8) == b"PXR-USDC":
                        yield repr(entry.filename), package.read(entry)


def check_crate_arrays(data: bytes, limits: MeshLimits) -> None:
    """MeshTooLargeError when a crate layer declares an array longer than a mesh within
    ``limits`` needs: ``max_vertices`` points, or 3 corners per triangle of ``max_faces``
    (per-corner data such as faceVertexIndices, UVs and normals). Read from the file's
    tables before usd-core decompresses anything; no check without both limits."""
    if limits.max_faces is None or limits.max_vertices is None:
        return
    bound = max(3 * limits.max_faces, limits.max_vertices)
    for name, layer in _crate_layers(data):
        largest = max(crate_array_sizes(layer), default=0)
        if largest > bound:
            raise MeshTooLargeError(
                f"{name} declares an array of {largest} values, more than a mesh within the "
                f"limits holds (max_faces {limits.max_faces}: {3 * limits.max_faces} corners; "
                f"max_vertices {limits.max_vertices}); simplify (decimate) it before uploading",
                limit="max_faces",
                maximum=limits.max_faces,
                found=largest // 3,
            )


def _read_usd_bytes(extension: str, data: bytes, limits: MeshLimits = NO_LIMITS) -> TriangleMesh:
    return read_usd_source(extension, data, limits).mesh


def read_usd_source(
    extension: str,
    data: bytes,
    limits: MeshLimits = NO_LIMITS,
    *,
    attributes: bool = False,
    side_files: SideFiles | None = None,
) -> SourceMesh:
    """A USD file's bytes (``extension``: usd, usda, usdc or usdz) read as
    ``read_usd_stage_source`` reads its stage (textures from inside the file, or from
    ``side_files``: the folder of a file read from disk)."""
    if extension == "usd":
        extension = sniff_usd(data) or "usd"
    if extension == "usdz" and not data.startswith(b"PK\x03\x04"):
        raise MeshParseError("a .usdz file is a zip archive, and this file is not one")
    check_crate_arrays(data, limits)
    from pxr import Tf

    read = partial(
        read_usd_stage_source, limits=limits, attributes=attributes, side_files=side_files
    )
    cut = cut_arrays(data, max_elements=_array_bound(limits)) if extension == "usda" else None
    if cut is not None:
        # The large arrays parsed by our kernel, the rest by usd-core; anything that does
        # not come out exactly as usd-core alone reads it is read again by usd-core alone.
        with usd_file(cut.text, extension) as path:
            try:
                return read(open_stage(path, partial(restore_arrays, cut=cut)), package=path.parent)
            except (_ArraysNotRestored, Tf.ErrorException):
                pass
    with usd_file(data, extension) as path:
        try:
            return read(open_stage(path), package=path.parent)
        except Tf.ErrorException as error:
            raise MeshParseError(
                f"usd-core could not read the file: {_usd_message(error)}"
            ) from None


def _array_bound(limits: MeshLimits) -> int | None:
    """Most elements an array of a mesh within ``limits`` has (``check_crate_arrays``)."""
    if limits.max_faces is None or limits.max_vertices is None:
        return None
    return max(3 * limits.max_faces, limits.max_vertices)


#: Readers for the registry, one per extension (the extension tells usd-core the encoding).
read_usd = partial(_read_usd_bytes, "usd")
read_usda = partial(_read_usd_bytes, "usda")
read_usdc = partial(_read_usd_bytes, "usdc")
read_usdz = partial(_read_usd_bytes, "usdz")


def linear_face_colors(face_labels: NDArray[np.int64]) -> NDArray[np.float64]:
    """(F, 3) linear RGB per face: ``palette.part_colors`` by label (sRGB swatches, the API's
    ``color``), ``palette.UNLABELED_COLOR`` for negative labels."""
    top = int(face_labels.max()) + 1 if len(face_labels) else 0
    palette = srgb_to_linear(part_colors(max(top, 0))[:, :3] / 255.0)
    colors = np.tile(srgb_to_linear(UNLABELED_COLOR[:3] / 255.0), (len(face_labels), 1))
    labelled = face_labels >= 0
    colors[labelled] = palette[face_labels[labelled]]
    return colors


def _uninstance(stage: Any, paths: list[Any]) -> None:
    """Make the instances above instance-proxy meshes ordinary prims, so that each copy
    can carry its own subsets (instance proxies cannot be edited)."""
    for path in paths:
        prim = stage.GetPrimAtPath(path)
        while prim.IsInstanceProxy():
            ancestor = prim.GetParent()
            while not ancestor.IsInstance():
                ancestor = ancestor.GetParent()
            stage.GetPrimAtPath(ancestor.GetPath()).SetInstanceable(False)
            prim = stage.GetPrimAtPath(path)


#: Custom data key holding a label's own name on its subset and material (prim names
#: are identifiers: "left arm" becomes ``left_arm``).
LABEL_NAME_KEY = "neural_shdf:label_name"


def usd_identifier(name: str) -> str:
    """``name`` as a USD prim name: letters, digits and ``_``, not starting with a digit."""
    identifier = re.sub(r"[^A-Za-z0-9_]", "_", name) or "_"
    return f"_{identifier}" if identifier[0].isdigit() else identifier


def _subset_names(labels: list[int], names: Mapping[int, str] | None) -> list[str]:
    """Prim name per label: ``part_name``, or the label's name as an identifier (made
    unique by its value when two names become the same identifier)."""

    if names is None:
        return [part_name(label) for label in labels]
    chosen = [usd_identifier(names.get(label, part_name(label))) for label in labels]
    return [
        f"{name}_{label}" if chosen.count(name) > 1 else name
        for name, label in zip(chosen, labels, strict=True)
    ]


def _replace_part_subsets(
    stage: Any, mesh: Any, labels: NDArray[np.int64], names: Mapping[int, str] | None = None
) -> None:
    """One GeomSubset per label of ``labels`` (per face of the prim), family ``part``;
    with ``names``, named by label and each bound to a material of that name."""
    from pxr import UsdGeom, Vt

    for old in UsdGeom.Subset.GetGeomSubsets(mesh, UsdGeom.Tokens.face, PART_FAMILY):
        path = old.GetPrim().GetPath()
        stage.RemovePrim(path)
        if stage.GetPrimAtPath(path):  # defined in a layer below the root: switch it off
            stage.GetPrimAtPath(path).SetActive(False)
    values = np.unique(labels).tolist()
    colors = linear_face_colors(labels) if names is not None else None
    for label, prim_name in zip(values, _subset_names(values, names), strict=True):
        faces = Vt.IntArray.FromNumpy(np.flatnonzero(labels == label).astype(np.int32))
        subset = UsdGeom.Subset.CreateGeomSubset(
            mesh, prim_name, UsdGeom.Tokens.face, faces, PART_FAMILY
        )
        if names is not None and label in names:
            subset.GetPrim().SetCustomDataByKey(LABEL_NAME_KEY, names[label])
            colour = colors[np.flatnonzero(labels == label)[0]]  # type: ignore[index]
            _bind_label_material(stage, subset, prim_name, names[label], colour)
    UsdGeom.Subset.SetFamilyType(mesh, PART_FAMILY, UsdGeom.Tokens.partition)


def _bind_label_material(
    stage: Any, subset: Any, prim_name: str, name: str, colour: NDArray[np.float64]
) -> None:
    """A material ``/World/Looks/<label name>`` (a UsdPreviewSurface of the label's
    colour), made once per stage, bound to ``subset``."""
    from pxr import Gf, Sdf, UsdShade

    path = Sdf.Path(f"/World/Looks/{prim_name}")
    material = UsdShade.Material.Get(stage, path)
    if not material:
        material = UsdShade.Material.Define(stage, path)
        material.GetPrim().SetCustomDataByKey(LABEL_NAME_KEY, name)
        shader = UsdShade.Shader.Define(stage, path.AppendChild("Surface"))
        shader.CreateIdAttr("UsdPreviewSurface")
        rgb = Gf.Vec3f(*(float(c) for c in colour))
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(rgb)
        surface = material.CreateSurfaceOutput()
        surface.ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(material)


def _set_display_colors(mesh: Any, labels: NDArray[np.int64]) -> None:
    from pxr import Sdf, UsdGeom, Vt

    primvar = UsdGeom.PrimvarsAPI(mesh).CreatePrimvar(
        "displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.uniform
    )
    primvar.SetInterpolation(UsdGeom.Tokens.uniform)
    if primvar.IsIndexed():
        primvar.BlockIndices()
    primvar.Set(Vt.Vec3fArray.FromNumpy(linear_face_colors(labels).astype(np.float32)))


def _add_parts(
    stage: Any,
    paths: list[Any],
    counts: list[int],
    labels: NDArray[Any],
    names: Mapping[int, str] | None = None,
) -> None:
    """Subsets and display colours on the mesh prims at ``paths`` (``counts`` faces each,
    ``labels`` one per face of all of them, prim after prim); ``names``: per label."""
    from pxr import UsdGeom

    if sum(counts) != len(labels):
        raise ParameterError(
            f"{len(labels)} labels for a USD stage of {sum(counts)} faces in "
            f"{len(paths)} mesh prims; pass one label per input face"
        )
    offsets = np.cumsum([0, *counts])
    for path, start, end in zip(paths, offsets[:-1], offsets[1:], strict=True):
        mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path))
        _replace_part_subsets(stage, mesh, labels[start:end], names)
        _set_display_colors(mesh, labels[start:end])


def _check_output(output: str | Path, face_labels: NDArray[Any]) -> tuple[Path, NDArray[np.int64]]:
    output = Path(output)
    if output.suffix.lower().lstrip(".") not in USD_EXTENSIONS:
        raise ParameterError(
            f"the USD output must end in .usda, .usdc, .usd or .usdz, got {output.name!r}"
        )
    labels = np.asarray(face_labels)
    if labels.ndim != 1 or labels.dtype.kind not in "iu":
        raise ParameterError("face_labels must be a 1-D integer array (one label per face)")
    return output, labels.astype(np.int64)


def _export(layer: Any, output: Path, scratch: Path) -> None:
    """Write ``layer`` as ``output`` (format from the extension; .usdz: a package of it)."""
    from pxr import UsdUtils

    if output.suffix.lower() != ".usdz":
        if not layer.Export(str(output)):
            raise OSError(f"could not write {output}")
        return
    packed = scratch / "parts.usdc"
    layer.Export(str(packed))
    if not UsdUtils.CreateNewUsdzPackage(str(packed), str(output)):
        raise OSError(f"could not write {output}")


def write_usd_parts(
    source: str | Path | bytes,
    face_labels: NDArray[Any],
    output: str | Path,
    *,
    input_format: str | None = None,
    names: Mapping[int, str] | None = None,
) -> None:
    """Write the USD stage of ``source`` with its parts: on every mesh prim that
    ``read_usd_path`` reads, one ``UsdGeom.Subset`` per part (family ``part``,
    partition of the faces, element type face, named by ``gltf_writer.part_name``;
    faces without a part, such as holes, in ``unlabeled``) and a per-face
    ``primvars:displayColor`` (uniform; the part colours, converted to linear).

    ``source``: the USD file's path, or its bytes (then ``input_format`` says which
    kind: usd, usda, usdc or usdz). ``face_labels``: one label per input face, in the
    reader's order (e.g.
    ``SegmentResult.input_face_parts``). Everything else in the stage is kept. A stage of
    one layer is written as that layer; one composed of several layers (a USDZ with
    sublayers or references) is flattened. Instances holding meshes are made ordinary
    prims, so each copy gets its own subsets. ``output`` ends in .usda, .usdc, .usd or
    .usdz (a package of the one written layer: a USDZ input's textures are not carried).
    ``names``: a name per label value (a labeller's): subsets are named by it (as an
    identifier; the name itself in their custom data ``LABEL_NAME_KEY``), each bound to
    a material ``/World/Looks/<name>`` of the label's colour.
    """
    from pxr import Usd, UsdGeom

    output, labels = _check_output(output, face_labels)
    if isinstance(source, bytes | bytearray | memoryview):
        data, suffix = bytes(source), ""
    else:
        data, suffix = Path(source).read_bytes(), Path(source).suffix
    extension = (input_format or suffix or "usd").lower().lstrip(".")
    if extension == "usd":
        extension = sniff_usd(data) or "usd"
    with usd_file(data, extension) as path:
        stage = open_stage(path)
        paths = [prim.GetPath() for prim in mesh_prims(stage)]
        _uninstance(stage, paths)
        time = Usd.TimeCode.EarliestTime()
        counts = [
            len(UsdGeom.Mesh(stage.GetPrimAtPath(p)).GetFaceVertexCountsAttr().Get(time) or [])
            for p in paths
        ]
        _add_parts(stage, paths, counts, labels, names)
        single = len([layer for layer in stage.GetUsedLayers() if not layer.anonymous]) == 1
        if single and extension != "usdz":
            layer = stage.GetRootLayer()
        else:
            layer = stage.Flatten()
            _unanchor(layer, path.parent)
        _export(layer, output, path.parent)


def _unanchor(layer: Any, folder: Path) -> None:
    """Asset paths of a flattened layer as the input wrote them, not anchored to the
    temporary folder it was read from (which is gone afterwards, differs every time and
    is the server's own): ``<folder>/upload.usdz[tex/a.png]`` becomes ``tex/a.png``,
    ``<folder>/tex/a.png`` becomes ``tex/a.png``. usd-core's note naming the folder goes
    too."""
    from pxr import UsdUtils

    prefix = str(folder) + os.sep
    real_prefix = str(folder.resolve()) + os.sep

    def relative(asset: str) -> str:
        for start in (prefix, real_prefix):
            if asset.startswith(start):
                inner = asset[len(start) :]
                _, bracket, member = inner.partition("[")
                return member[:-1] if bracket and member.endswith("]") else inner
        return asset

    UsdUtils.ModifyAssetPaths(layer, relative)
    layer.documentation = "Flattened from the input stage by neural-shdf"


def usd_parts_usda(data: bytes, input_format: str, face_labels: NDArray[Any]) -> bytes:
    """``write_usd_parts`` of a USD file's bytes, as the bytes of a .usda layer (a stage of
    several layers, such as a USDZ package, flattened)."""
    with tempfile.TemporaryDirectory(prefix="neural-shdf-usd-") as scratch:
        path = Path(scratch) / "parts.usda"
        write_usd_parts(data, face_labels, path, input_format=input_format)
        return path.read_bytes()


def input_polygons(mesh: TriangleMesh) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[Any]]:
    """The input faces as polygons, read back from their triangle fans.

    Returns ``(counts, flat_indices, input_face)``: one polygon per input face that has
    triangles, in input order; a face whose triangles are not one fan (first vertex
    shared, each triangle continuing the last) is given as its triangles instead.
    ``input_face[i]``: the input face of polygon ``i``.
    """
    faces, origin = mesh.faces, mesh.face_origin
    first = np.ones(len(faces), dtype=bool)
    first[1:] = origin[1:] != origin[:-1]
    run_start = np.maximum.accumulate(np.where(first, np.arange(len(faces)), 0))
    continues = np.zeros(len(faces), dtype=bool)
    continues[1:] = (faces[1:, 0] == faces[run_start[1:], 0]) & (faces[1:, 1] == faces[:-1, 2])
    broken = np.zeros(mesh.input_face_count, dtype=bool)
    broken[origin[~first & ~continues]] = True
    start = first | broken[origin]  # a broken face: every triangle is a polygon of its own
    last = np.ones(len(faces), dtype=bool)
    last[:-1] = start[1:]
    corners = np.stack([start, np.ones(len(faces), dtype=bool), last], axis=1)
    polygon = np.cumsum(start) - 1
    counts = np.bincount(polygon) + 2
    return counts.astype(np.int64), faces[corners], origin[start]


def write_mesh_parts_usd(
    mesh: TriangleMesh,
    face_labels: NDArray[Any],
    output: str | Path,
    *,
    names: Mapping[int, str] | None = None,
) -> None:
    """A new USD stage of ``mesh`` with its parts, for inputs that are not USD (or whose
    file is gone, as in the service): one Mesh prim ``/World/Mesh`` whose faces are the
    input faces (``input_polygons``), with the subsets and display colours of
    ``write_usd_parts``. Y up, metres per unit 1 (other formats do not say).
    """
    from pxr import Sdf, Usd, UsdGeom, Vt

    output, labels = _check_output(output, face_labels)
    if len(labels) != mesh.input_face_count:
        raise ParameterError(
            f"{len(labels)} labels for a mesh of {mesh.input_face_count} input faces; "
            "pass one label per input face"
        )
    counts, flat, input_face = input_polygons(mesh)
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, "/World").GetPrim())
    prim = UsdGeom.Mesh.Define(stage, "/World/Mesh")
    prim.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(mesh.vertices.astype(np.float32)))
    prim.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    prim.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(flat.astype(np.int32)))
    prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    lower, upper = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    prim.CreateExtentAttr(Vt.Vec3fArray.FromNumpy(np.stack([lower, upper]).astype(np.float32)))
    _add_parts(stage, [Sdf.Path("/World/Mesh")], [len(counts)], labels[input_face], names)
    with tempfile.TemporaryDirectory(prefix="neural-shdf-usd-") as scratch:
        _export(stage.GetRootLayer(), output, Path(scratch))


def mesh_parts_usda(
    mesh: TriangleMesh, face_labels: NDArray[Any], *, names: Mapping[int, str] | None = None
) -> bytes:
    """``write_mesh_parts_usd`` as the bytes of a .usda file."""
    with tempfile.TemporaryDirectory(prefix="neural-shdf-usd-") as scratch:
        path = Path(scratch) / "parts.usda"
        write_mesh_parts_usd(mesh, face_labels, path, names=names)
        return path.read_bytes()


__all__ = [
    "PART_FAMILY",
    "USD_EXTENSIONS",
    "UsdPreviewMaterials",
    "check_layers_inside",
    "input_polygons",
    "mesh_parts_usda",
    "mesh_prims",
    "open_stage",
    "read_usd",
    "read_usd_path",
    "read_usd_source",
    "read_usd_stage",
    "read_usd_stage_source",
    "read_usda",
    "read_usdc",
    "read_usdz",
    "sniff_usd",
    "usd_file",
    "usd_parts_usda",
    "write_mesh_parts_usd",
    "write_usd_parts",
]
