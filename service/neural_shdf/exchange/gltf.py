"""glTF 2.0 readers: binary GLB, and text glTF whose buffers are embedded ``data:`` URIs.

Triangle order (what "input face order" means for glTF): the default scene's
nodes are walked depth-first in their listed order (a node, then its children
in order); for each node with a mesh, the triangles of each primitive follow in
primitive order and index order. A mesh instanced by several nodes appears once
per node. Node transforms (matrix or TRS) are applied to the positions; where a
transform mirrors (negative determinant) the winding is flipped so normals keep
pointing outwards. Triangle strips and fans are expanded to triangles; points
and lines primitives are ignored. Each triangle is one input face. Files without
scenes use every root node in index order, or every mesh if there are no nodes.

Compressed and core encodings read: KHR_draco_mesh_compression primitives (DracoPy;
whether or not the file lists Draco as required; the decoded counts must equal the
primitive's declared, budgeted accessor counts), EXT_/KHR_meshopt_compression
bufferViews (meshopt; a view may decode to no more bytes than the budgeted accessors
read from it need), KHR_mesh_quantization, sparse accessors, and a UTF-8 byte-order
mark before the JSON.
"""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass, replace
from typing import Any, TypeGuard

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import (
    InvalidGeometryError,
    MeshParseError,
    MeshTooLargeError,
    UnsupportedFormatError,
)
from neural_shdf.exchange._common import NO_LIMITS, MeshLimits, build_mesh, strip_bom
from neural_shdf.exchange.attributes import (
    FaceGroup,
    Materials,
    SceneObject,
    SourceMesh,
    SurfaceAttributes,
    finite_rows,
    unit_normal_rows,
)
from neural_shdf.mesh import TriangleMesh

_GLB_MAGIC = b"glTF"
_CHUNK_JSON = 0x4E4F534A
_CHUNK_BIN = 0x004E4942
_COMPONENTS = {5120: "i1", 5121: "u1", 5122: "i2", 5123: "u2", 5125: "u4", 5126: "f4"}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_TRIANGLES, _STRIP, _FAN = 4, 5, 6
_DRACO = "KHR_draco_mesh_compression"
_GPU_INSTANCING = "EXT_mesh_gpu_instancing"
_INSTANCE_ATTRIBUTES = {"TRANSLATION": 3, "ROTATION": 4, "SCALE": 3}
_MESHOPT = ("EXT_meshopt_compression", "KHR_meshopt_compression")
_MESHOPT_MODES = ("ATTRIBUTES", "TRIANGLES", "INDICES")
#: Cap on node visits, so a node graph that instances exponentially cannot blow up
#: (vertices and triangles are budgeted by ``MeshLimits`` before anything is expanded).
MAX_NODE_VISITS = 100_000

#: A JSON object of the file (untrusted: every value is checked where it is read).
JsonObject = dict[str, Any]


def _item(document: JsonObject, key: str, index: Any) -> JsonObject:
    """``document[key][index]`` with a clear error for bad or out-of-range references."""
    items = document.get(key)
    if (
        not isinstance(index, int)
        or isinstance(index, bool)
        or not isinstance(items, list)
        or not 0 <= index < len(items)
        or not isinstance(items[index], dict)
    ):
        raise MeshParseError(f"glTF refers to {key}[{index!r}], which does not exist")
    item: JsonObject = items[index]
    return item


class _Document:
    """A parsed glTF JSON with its buffers, reading accessors with bounds checks."""

    def __init__(self, gltf: Any, glb_bin: bytes | None):
        if not isinstance(gltf, dict):
            raise MeshParseError("the glTF JSON must be an object")
        version = str(gltf.get("asset", {}).get("version", "2.0"))
        if not version.startswith("2"):
            raise UnsupportedFormatError(f"glTF version {version} is not supported (only 2.x)")
        self.gltf = gltf
        self.glb_bin = glb_bin
        self._buffers: dict[int, bytes] = {}
        self._accessors: dict[int, NDArray[Any]] = {}
        self._decoded_views: dict[int, bytes] = {}
        self._draco: dict[int, tuple[NDArray[Any], NDArray[Any]]] = {}
        self._draco_meshes: dict[int, Any] = {}
        #: Bytes each compressed bufferView may decode to: what the accessors read from it
        #: need (set by ``_check_budget`` from the declared, budgeted counts).
        self.view_allowance: dict[int, int] = {}

    def buffer(self, index: int) -> bytes:
        if index in self._buffers:
            return self._buffers[index]
        spec = _item(self.gltf, "buffers", index)
        declared = int(spec.get("byteLength", -1))
        uri = spec.get("uri")
        if uri is None:
            if self.glb_bin is None or index != 0:
                raise MeshParseError(f"glTF buffer {index} has no data (no uri and no GLB chunk)")
            data = self.glb_bin
        elif isinstance(uri, str) and uri.startswith("data:"):
            header, _, payload = uri.partition(",")
            if not header.endswith(";base64"):
                raise UnsupportedFormatError("only base64 data: URIs are supported in glTF")
            if declared > len(payload):  # base64 expands, so the payload is longer than data
                raise MeshParseError(
                    f"glTF buffer {index} declares {declared} bytes but embeds fewer"
                )
            data = base64.b64decode(payload, validate=True)
        else:
            raise UnsupportedFormatError(
                "the glTF refers to an external buffer file; upload a .glb, or a .gltf with "
                "embedded (data: URI) buffers"
            )
        if declared < 0 or declared > len(data):
            raise MeshParseError(
                f"glTF buffer {index} declares {declared} bytes but holds {len(data)} "
                "(truncated or corrupt file)"
            )
        self._buffers[index] = data
        return data

    def _view(self, view_index: Any) -> tuple[bytes, int, int, int]:
        """(bytes, offset, length, byteStride or 0) of a bufferView, decoding a
        meshopt-compressed one first."""
        view = _item(self.gltf, "bufferViews", view_index)
        meshopt = _meshopt_extension(view)
        if meshopt is not None:
            data = self._meshopt_view(view_index, view, meshopt)
            return data, 0, len(data), int(view.get("byteStride", 0))
        buffer = self.buffer(view.get("buffer", -1))
        view_offset = int(view.get("byteOffset", 0))
        view_length = int(view.get("byteLength", -1))
        if view_offset < 0 or view_length < 0 or view_offset + view_length > len(buffer):
            raise MeshParseError(
                f"glTF bufferView {view_index} lies outside its buffer (corrupt file)"
            )
        return buffer, view_offset, view_length, int(view.get("byteStride", 0))

    def _meshopt_view(self, view_index: int, view: JsonObject, meshopt: JsonObject) -> bytes:
        """A bufferView's bytes decoded from its EXT/KHR_meshopt_compression data, after
        checking that they are no more than the accessors read from it need."""
        if view_index in self._decoded_views:
            return self._decoded_views[view_index]
        count, stride = meshopt.get("count"), meshopt.get("byteStride")
        mode, filter_name = meshopt.get("mode"), meshopt.get("filter", "NONE")
        if not (_is_count(count) and _is_count(stride)) or mode not in _MESHOPT_MODES:
            raise MeshParseError(
                f"glTF bufferView {view_index} has invalid meshopt compression settings"
            )
        decoded_size = count * stride
        allowed = self.view_allowance.get(view_index, 0)
        if decoded_size > allowed or decoded_size != int(view.get("byteLength", -1)):
            raise MeshParseError(
                f"glTF bufferView {view_index} would decompress (meshopt) to {decoded_size} "
                f"bytes, but declares {view.get('byteLength')!r} and its accessors read "
                f"{allowed}: the file is corrupt"
            )
        source = self.buffer(meshopt.get("buffer", -1))
        offset, length = int(meshopt.get("byteOffset", 0)), int(meshopt.get("byteLength", -1))
        if offset < 0 or length < 0 or offset + length > len(source):
            raise MeshParseError(
                f"the meshopt data of glTF bufferView {view_index} lies outside its buffer"
            )
        import meshopt as meshopt_codec  # noqa: PLC0415 - only files that need it pay for it

        try:
            rows = meshopt_codec.decode_gltf_buffer(
                source[offset : offset + length], count, stride, mode, filter_name
            )
        except (RuntimeError, ValueError) as exc:
            raise MeshParseError(
                f"the meshopt-compressed glTF bufferView {view_index} cannot be decoded "
                f"({exc}): the file is corrupt"
            ) from None
        data = np.ascontiguousarray(rows).tobytes()
        self._decoded_views[view_index] = data
        return data

    def _array(
        self, view_index: Any, byte_offset: int, count: int, width: int, dtype: np.dtype,
        *, what: str, strided: bool = True,
    ) -> NDArray[Any]:  # fmt: skip
        """``count`` elements of ``width`` values read from a bufferView, bounds checked."""
        buffer, view_offset, view_length, stride = self._view(view_index)
        element_size = dtype.itemsize * width
        stride = (stride if strided else 0) or element_size
        needed = byte_offset + stride * (count - 1) + element_size if count > 0 else 0
        if count < 0 or byte_offset < 0 or stride < element_size or needed > view_length:
            raise MeshParseError(
                f"glTF {what} declares {count} elements, more than its bufferView "
                "holds (corrupt or truncated file)"
            )
        return np.ndarray(
            (count, width),
            dtype=dtype,
            buffer=buffer,
            offset=view_offset + byte_offset,
            strides=(stride, dtype.itemsize),
        )

    def accessor(self, index: int) -> NDArray[Any]:
        """Accessor values as a (count, width) array (float64, or int64 for integer data),
        with sparse substitutions applied."""
        if index in self._accessors:
            return self._accessors[index]
        spec = _item(self.gltf, "accessors", index)
        component = spec.get("componentType")
        width = _WIDTHS.get(spec.get("type", ""))
        count = spec.get("count")
        if component not in _COMPONENTS or width is None or not isinstance(count, int):
            raise MeshParseError(f"glTF accessor {index} has an invalid type or count")
        dtype = np.dtype("<" + _COMPONENTS[component])
        sparse = spec.get("sparse")
        if "bufferView" in spec:
            raw = self._array(
                spec["bufferView"], int(spec.get("byteOffset", 0)), count, width, dtype,
                what=f"accessor {index}",
            )  # fmt: skip
        elif isinstance(sparse, dict) and count >= 0:
            raw = np.zeros((count, width), dtype=dtype)  # the spec's initial values
        else:
            raise MeshParseError(f"glTF accessor {index} has no bufferView (no data)")
        if sparse is not None:
            raw = self._apply_sparse(index, raw, sparse, dtype, width)
        if dtype.kind == "f":
            values = raw.astype(np.float64)
        elif spec.get("normalized", False):
            info = np.iinfo(dtype)
            values = np.maximum(raw.astype(np.float64) / info.max, -1.0)
        else:
            values = raw.astype(np.int64)
        self._accessors[index] = values
        return values

    def _apply_sparse(
        self, index: int, base: NDArray[Any], sparse: Any, dtype: np.dtype, width: int
    ) -> NDArray[Any]:
        """``base`` with a sparse accessor's substitutions (core glTF 2.0)."""
        what = f"the sparse part of accessor {index}"
        if not isinstance(sparse, dict):
            raise MeshParseError(f"{what} is not an object")
        count = sparse.get("count")
        indices, values = sparse.get("indices"), sparse.get("values")
        if not _is_count(count) or count > len(base) or not isinstance(indices, dict):
            raise MeshParseError(
                f"{what} substitutes {count!r} elements of {len(base)} (corrupt file)"
            )
        if not isinstance(values, dict) or indices.get("componentType") not in (5121, 5123, 5125):
            raise MeshParseError(f"{what} has invalid indices or values")
        index_type = np.dtype("<" + _COMPONENTS[indices["componentType"]])
        targets = self._array(
            indices.get("bufferView"), int(indices.get("byteOffset", 0)), count, 1, index_type,
            what=what + " (indices)", strided=False,
        )[:, 0].astype(np.int64)  # fmt: skip
        replacements = self._array(
            values.get("bufferView"), int(values.get("byteOffset", 0)), count, width, dtype,
            what=what + " (values)", strided=False,
        )  # fmt: skip
        if count and (int(targets.max()) >= len(base) or (np.diff(targets) <= 0).any()):
            raise MeshParseError(
                f"{what} has indices that are not increasing or beyond its {len(base)} elements"
            )
        result = np.array(base)
        result[targets] = replacements
        return result

    def _draco_decoded(self, mesh_index: int, view_index: Any) -> Any:
        """The DracoPy mesh of a bufferView, decoded once."""
        if view_index in self._draco_meshes:
            return self._draco_meshes[view_index]
        buffer, offset, length, _ = self._view(view_index)
        import DracoPy  # noqa: PLC0415, N813 - only files that need it pay for it

        try:
            decoded = DracoPy.decode(buffer[offset : offset + length])
        except Exception as exc:  # noqa: BLE001 - the decoder's errors are not typed
            raise MeshParseError(
                f"the Draco-compressed data of glTF mesh {mesh_index} cannot be decoded "
                f"({exc or type(exc).__name__}): the file is corrupt"
            ) from None
        self._draco_meshes[view_index] = decoded
        return decoded

    def draco_attribute(
        self,
        mesh_index: int,
        primitive: dict[str, Any],
        extension: Any,
        name: str,
        spec: dict[str, Any],
    ) -> NDArray[Any] | None:
        """A Draco primitive's attribute ``name`` (float64; normalized integers scaled as
        the accessor ``spec`` says), or None when the Draco data does not hold it."""
        attribute_id = ((extension or {}).get("attributes") or {}).get(name)
        if not _is_count(attribute_id):
            return None
        self.draco(mesh_index, primitive, extension)  # decoded, and checked against the counts
        attribute = self._draco_decoded(mesh_index, extension.get("bufferView"))
        found = attribute.get_attribute_by_unique_id(attribute_id)
        if found is None:
            return None
        raw = np.asarray(found["data"])
        if raw.ndim == 1:
            raw = raw.reshape(len(raw), -1) if len(raw) else raw.reshape(0, 1)
        if raw.dtype.kind in "iu" and spec.get("normalized", False):
            return np.maximum(raw.astype(np.float64) / np.iinfo(raw.dtype).max, -1.0)
        return raw.astype(np.float64)

    def draco(
        self, mesh_index: int, primitive: dict[str, Any], extension: Any
    ) -> tuple[NDArray[Any], NDArray[Any]]:
        """(positions, triangles) of a KHR_draco_mesh_compression primitive, decoded once,
        and checked against the primitive's declared (and budgeted) accessor counts."""
        if not isinstance(extension, dict):
            raise MeshParseError(f"glTF mesh {mesh_index} has invalid Draco settings")
        view_index: Any = extension.get("bufferView")  # checked by ``_view``
        if view_index in self._draco:
            return self._draco[view_index]
        decoded = self._draco_decoded(mesh_index, view_index)
        attribute_id = (extension.get("attributes") or {}).get("POSITION")
        attribute = (
            decoded.get_attribute_by_unique_id(attribute_id) if _is_count(attribute_id) else None
        )
        positions = np.asarray(
            attribute["data"] if attribute is not None else decoded.points, dtype=np.float64
        ).reshape(-1, 3)
        triangles = np.asarray(decoded.faces, dtype=np.int64).reshape(-1, 3)
        declared_vertices = _declared_count(
            _item(self.gltf, "accessors", primitive["attributes"]["POSITION"])
        )
        declared_indices = (
            _declared_count(_item(self.gltf, "accessors", primitive["indices"]))
            if "indices" in primitive
            else 3 * len(triangles)
        )
        if len(positions) != declared_vertices or 3 * len(triangles) != declared_indices:
            raise MeshParseError(
                f"the Draco data of glTF mesh {mesh_index} decodes to {len(positions)} vertices "
                f"and {3 * len(triangles)} indices, but its accessors declare "
                f"{declared_vertices} and {declared_indices}: the file is corrupt"
            )
        self._draco[view_index] = (positions, triangles)
        return positions, triangles


def _is_count(value: Any) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _meshopt_extension(view: JsonObject) -> JsonObject | None:
    extensions = view.get("extensions") or {}
    for name in _MESHOPT:
        if name in extensions:
            if not isinstance(extensions[name], dict):
                raise MeshParseError(f"glTF {name} settings must be an object")
            found: JsonObject = extensions[name]
            return found
    return None


def _draco_extension(primitive: JsonObject) -> Any:
    return (primitive.get("extensions") or {}).get(_DRACO)


def _local_matrix(node: JsonObject) -> NDArray[np.float64]:
    if "matrix" in node:
        matrix = np.asarray(node["matrix"], dtype=np.float64)
        if matrix.shape != (16,):
            raise MeshParseError("a glTF node matrix needs 16 numbers")
        return matrix.reshape(4, 4).T  # stored column-major
    translation = np.asarray(node.get("translation", [0, 0, 0]), dtype=np.float64)
    x, y, z, w = np.asarray(node.get("rotation", [0, 0, 0, 1]), dtype=np.float64)
    scale = np.asarray(node.get("scale", [1, 1, 1]), dtype=np.float64)
    rotation = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    matrix = np.eye(4)
    matrix[:3, :3] = rotation * scale[None, :]
    matrix[:3, 3] = translation
    return matrix


def _triangles(indices: NDArray[Any], mode: int) -> NDArray[Any]:
    """Triangles (T, 3) of a primitive's index list in its drawing mode."""
    n = len(indices)
    if mode == _TRIANGLES:
        if n % 3:
            raise MeshParseError(f"a glTF triangle primitive has {n} indices, not a multiple of 3")
        return indices.reshape(-1, 3)
    if n < 3:
        return np.zeros((0, 3), dtype=np.int64)
    i = np.arange(n - 2)
    if mode == _STRIP:
        odd = i % 2
        return np.stack([indices[i], indices[i + 1 + odd], indices[i + 2 - odd]], axis=1)
    return np.stack([indices[i + 1], indices[i + 2], np.full(len(i), indices[0])], axis=1)


def _triangle_count(document: _Document, primitive: JsonObject, vertex_count: int) -> int:
    mode = primitive.get("mode", _TRIANGLES)
    if "indices" in primitive:
        n = _declared_count(_item(document.gltf, "accessors", primitive["indices"]))
    else:
        n = vertex_count
    return n // 3 if mode == _TRIANGLES else max(n - 2, 0)


def _declared_count(spec: JsonObject) -> int:
    """An accessor's declared element count (0 when invalid: reading it reports that)."""
    count = spec.get("count", 0)
    return count if isinstance(count, int) and not isinstance(count, bool) and count > 0 else 0


def _scene_roots(gltf: JsonObject) -> list[int]:
    scenes = gltf.get("scenes")
    if scenes:
        scene = _item(gltf, "scenes", gltf.get("scene", 0))
        return list(scene.get("nodes", []))
    nodes = gltf.get("nodes", [])
    children = {c for node in nodes if isinstance(node, dict) for c in node.get("children", [])}
    return [i for i in range(len(nodes)) if i not in children]


@dataclass(frozen=True)
class _Instance:
    """A mesh placed by a node: ``matrix`` is the node's world transform; ``gpu`` the
    node's EXT_mesh_gpu_instancing attributes (each of its instances is one placement)."""

    mesh: int
    matrix: NDArray[Any]
    node: int = -1
    gpu: dict[str, Any] | None = None


def _mesh_instances(gltf: dict[str, Any]) -> list[_Instance]:
    """Every mesh placement (a node with a mesh), in the depth-first node order.

    Iterative (a chain of thousands of nodes is fine); a node met again on its own
    path is a cycle; more than ``MAX_NODE_VISITS`` visits (a DAG that instances
    exponentially) is too large.
    """
    if not (gltf.get("nodes") or gltf.get("scenes")):
        return [
            _Instance(mesh_index, np.eye(4)) for mesh_index in range(len(gltf.get("meshes", [])))
        ]
    instances: list[_Instance] = []
    on_path: set[int] = set()
    visits = 0
    # Entries: (node, parent matrix) to enter, or (node, None) to leave.
    stack: list[tuple[Any, NDArray[np.float64] | None]] = [
        (root, np.eye(4)) for root in reversed(_scene_roots(gltf))
    ]
    while stack:
        node_index, parent = stack.pop()
        if parent is None:
            on_path.discard(node_index)
            continue
        node = _item(gltf, "nodes", node_index)
        if node_index in on_path:
            raise MeshParseError(f"the glTF node graph has a cycle through node {node_index}")
        visits += 1
        if visits > MAX_NODE_VISITS:
            raise MeshTooLargeError(
                f"the glTF scene instances more than {MAX_NODE_VISITS} nodes "
                "(max_node_visits); flatten it",
                limit="max_node_visits",
                maximum=MAX_NODE_VISITS,
                found=visits,
            )
        matrix = parent @ _local_matrix(node)
        if "mesh" in node:
            _item(gltf, "meshes", node["mesh"])  # a valid reference, before it is counted
            gpu = (node.get("extensions") or {}).get(_GPU_INSTANCING)
            if gpu is not None and not (
                isinstance(gpu, dict) and isinstance(gpu.get("attributes"), dict)
            ):
                raise MeshParseError(
                    f"glTF node {node_index} has {_GPU_INSTANCING} without attributes"
                )
            instances.append(_Instance(node["mesh"], matrix, node_index, gpu))
        children = node.get("children", [])
        if not isinstance(children, list):
            raise MeshParseError(f"glTF node {node_index} has children that are not a list")
        on_path.add(node_index)
        stack.append((node_index, None))
        stack.extend((child, matrix) for child in reversed(children))
    return instances


def _gpu_instance_count(gltf: dict[str, Any], instance: _Instance) -> int:
    """How many placements an EXT_mesh_gpu_instancing node makes (declared counts; they
    must agree), 1 for an ordinary node."""
    if instance.gpu is None:
        return 1
    counts = {
        _declared_count(_item(gltf, "accessors", accessor))
        for name, accessor in instance.gpu["attributes"].items()
        if name in _INSTANCE_ATTRIBUTES
    }
    if len(counts) != 1:
        raise MeshParseError(
            f"the {_GPU_INSTANCING} attributes of glTF node {instance.node} "
            + ("have different counts" if counts else "have no TRANSLATION, ROTATION or SCALE")
        )
    return counts.pop()


def _expand_gpu_instances(document: _Document, instances: list[_Instance]) -> list[_Instance]:
    """Each EXT_mesh_gpu_instancing placement as an instance of its own, in instance
    order (world = node @ T @ R @ S of the instance), in the node's place."""
    expanded: list[_Instance] = []
    for instance in instances:
        if instance.gpu is None:
            expanded.append(instance)
            continue
        count = _gpu_instance_count(document.gltf, instance)
        attributes = instance.gpu["attributes"]
        trs = {}
        for name, width in _INSTANCE_ATTRIBUTES.items():
            if name in attributes:
                values = document.accessor(attributes[name])
                if values.shape != (count, width):
                    raise MeshParseError(
                        f"{_GPU_INSTANCING} {name} of glTF node {instance.node} must be "
                        f"{'VEC3' if width == 3 else 'VEC4'}"
                    )
                trs[name.lower()] = values
        for k in range(count):
            local = _local_matrix({key: values[k].tolist() for key, values in trs.items()})
            expanded.append(_Instance(instance.mesh, instance.matrix @ local, instance.node))
    return expanded


def _check_budget(
    document: _Document,
    instances: list[_Instance],
    limits: MeshLimits,
    *,
    attributes: bool = False,
) -> None:
    """Vertices and triangles the instances expand to, from the JSON alone, against
    ``limits``: a mesh of 1M vertices placed by 40 nodes (or 40 GPU instances) is 40M
    vertices, rejected before a single accessor is read. ``attributes``: the views of
    the attribute accessors may be decompressed too."""
    gltf = document.gltf
    vertices = triangles = placements = 0
    allowed_meshes: set[int] = set()
    uses: dict[int, int] = {}
    for instance in instances:
        count = _gpu_instance_count(gltf, instance)
        placements += count
        uses[instance.mesh] = uses.get(instance.mesh, 0) + count
        if instance.gpu is not None:
            for accessor in instance.gpu["attributes"].values():
                _allow_views(document, _item(gltf, "accessors", accessor))
    for mesh_index, count in uses.items():
        for primitive in _item(gltf, "meshes", mesh_index).get("primitives", []):
            if primitive.get("mode", _TRIANGLES) not in (_TRIANGLES, _STRIP, _FAN):
                continue
            position = (primitive.get("attributes") or {}).get("POSITION")
            if position is None:
                continue  # reported when the primitive is read
            vertex_count = _declared_count(_item(gltf, "accessors", position))
            vertices += count * vertex_count
            triangles += count * _triangle_count(document, primitive, vertex_count)
            if mesh_index not in allowed_meshes:
                read = [position, primitive.get("indices")]
                if attributes:
                    read += [
                        accessor
                        for name, accessor in (primitive.get("attributes") or {}).items()
                        if name != "POSITION" and _is_kept_attribute(name)
                    ]
                for accessor in read:
                    if accessor is not None:
                        _allow_views(document, _item(gltf, "accessors", accessor))
        allowed_meshes.add(mesh_index)
    plural = "s" if placements != 1 else ""
    context = f" after expanding its {placements} glTF mesh instance{plural}"
    limits.check_faces(triangles, "triangles", context=context)
    limits.check_vertices(vertices, context=context)


def _allow_views(document: _Document, spec: JsonObject) -> None:
    """Let the bufferViews an accessor reads decompress to what it declares it needs."""
    component, width = spec.get("componentType"), _WIDTHS.get(spec.get("type", ""))
    if component not in _COMPONENTS or width is None:
        return  # reported when the accessor is read
    element_size = np.dtype(_COMPONENTS[component]).itemsize * width
    count = _declared_count(spec)
    allowance = document.view_allowance
    if _is_count(spec.get("bufferView")):
        view = _item(document.gltf, "bufferViews", spec["bufferView"])
        stride = max(int(view.get("byteStride", 0) or 0), element_size)
        allowance[spec["bufferView"]] = allowance.get(spec["bufferView"], 0) + count * stride + 16
    sparse = spec.get("sparse")
    if isinstance(sparse, dict) and _is_count(sparse.get("count")):
        for part, size in (("indices", 4), ("values", element_size)):
            view_index = (sparse.get(part) or {}).get("bufferView")
            if _is_count(view_index):
                extra = min(sparse["count"], count) * size + 16
                allowance[view_index] = allowance.get(view_index, 0) + extra


def _read_document(
    document: _Document, format_name: str, limits: MeshLimits, *, attributes: bool = False
) -> SourceMesh:
    gltf = document.gltf
    instances = _mesh_instances(gltf)
    _check_budget(document, instances, limits, attributes=attributes)
    instances = _expand_gpu_instances(document, instances)
    vertex_blocks: list[NDArray[Any]] = []
    face_blocks: list[NDArray[Any]] = []
    kept = _KeptAttributes(document) if attributes else None
    vertex_total = 0
    for instance_number, instance in enumerate(instances):
        mesh_index, matrix = instance.mesh, instance.matrix
        mesh = _item(gltf, "meshes", mesh_index)
        flip = np.linalg.det(matrix[:3, :3]) < 0
        for primitive in mesh.get("primitives", []):
            mode = primitive.get("mode", _TRIANGLES)
            if mode not in (_TRIANGLES, _STRIP, _FAN):
                continue  # points and lines
            if "POSITION" not in primitive.get("attributes", {}):
                raise MeshParseError("a glTF primitive has no POSITION attribute")
            draco = _draco_extension(primitive)
            if draco is not None:  # whether or not the file lists Draco as required
                if mode != _TRIANGLES:
                    raise UnsupportedFormatError(
                        f"glTF mesh {mesh_index} has Draco-compressed triangle strips or "
                        "fans; export triangles"
                    )
                positions, indices = document.draco(mesh_index, primitive, draco)
                indices = indices.reshape(-1)
            else:
                positions = document.accessor(primitive["attributes"]["POSITION"])
            if positions.shape[1] != 3:
                raise MeshParseError("glTF POSITION must be VEC3")
            if draco is not None:
                pass
            elif "indices" in primitive:
                indices = document.accessor(primitive["indices"])
                if indices.shape[1] != 1 or indices.dtype.kind != "i":
                    raise MeshParseError("glTF indices must be unsigned integer scalars")
                indices = indices[:, 0]
            else:
                indices = np.arange(len(positions), dtype=np.int64)
            if len(indices) and int(indices.max()) >= len(positions):
                raise InvalidGeometryError(
                    f"a glTF primitive of mesh {mesh_index} uses vertex {int(indices.max())} but "
                    f"has only {len(positions)} vertices (corrupt file)"
                )
            triangles = _triangles(indices, mode)
            if flip:
                triangles = triangles[:, [0, 2, 1]]
            vertex_blocks.append(positions @ matrix[:3, :3].T + matrix[:3, 3])
            face_blocks.append(triangles + vertex_total)
            vertex_total += len(positions)
            if kept is not None:
                kept.add(instance_number, mesh_index, primitive, len(positions), len(triangles))

    vertices = np.concatenate(vertex_blocks) if vertex_blocks else np.zeros((0, 3))
    faces = np.concatenate(face_blocks) if face_blocks else np.zeros((0, 3), dtype=np.int64)
    read = build_mesh(vertices, faces, None, len(faces), format_name=format_name, limits=limits)
    if kept is None:
        return SourceMesh(read)
    return SourceMesh(read, kept.result(read, instances))


def _is_kept_attribute(name: str) -> bool:
    return name in ("NORMAL", "TANGENT", "COLOR_0") or name.startswith("TEXCOORD_")


class _KeptAttributes:
    """Normals, tangents, UVs, colours and materials of the primitives read, gathered
    primitive by primitive (one face group each) for ``SurfaceAttributes``.

    An attribute whose accessor does not have one value per vertex of its primitive, or
    whose values are not finite, is left out of that group (the geometry is read as it
    would be without attributes)."""

    def __init__(self, document: _Document) -> None:
        self.document = document
        self.groups: list[FaceGroup] = []
        self.group_sizes: list[int] = []
        self.vertex_counts: list[int] = []
        self.blocks: dict[str, list[NDArray[Any] | None]] = {}

    def add(
        self,
        instance: int,
        mesh_index: int,
        primitive: dict[str, Any],
        vertices: int,
        triangles: int,
    ) -> None:
        values = {
            name: self._values(mesh_index, primitive, name, vertices)
            for name in self._names(primitive)
        }
        uv_sets = 0
        while values.get(f"TEXCOORD_{uv_sets}") is not None:
            uv_sets += 1
        material = primitive.get("material", -1)
        if not (_is_count(material) and material < len(self.document.gltf.get("materials", []))):
            material = -1
        self.groups.append(
            FaceGroup(
                object=instance,
                material=material,
                normals=values.get("NORMAL") is not None,  # unless unusable: ``result``
                tangents=values.get("TANGENT") is not None,
                uv_sets=uv_sets,
                colors=values.get("COLOR_0") is not None,
            )
        )
        self.group_sizes.append(triangles)
        for name in values.keys() - self.blocks.keys():  # a name not seen before
            self.blocks[name] = [None] * len(self.vertex_counts)
        for name, column in self.blocks.items():
            column.append(values.get(name))
        self.vertex_counts.append(vertices)

    @staticmethod
    def _names(primitive: dict[str, Any]) -> list[str]:
        return [name for name in primitive.get("attributes", {}) if _is_kept_attribute(name)]

    def _values(
        self, mesh_index: int, primitive: dict[str, Any], name: str, vertices: int
    ) -> NDArray[Any] | None:
        accessor = primitive["attributes"][name]
        spec = _item(self.document.gltf, "accessors", accessor)
        width = {"NORMAL": 3, "TANGENT": 4}.get(name, 2)
        if name == "COLOR_0":
            width = _WIDTHS.get(spec.get("type", ""), 0)
            if width not in (3, 4):
                return None
        if _declared_count(spec) != vertices or _WIDTHS.get(spec.get("type", "")) != width:
            return None
        draco = _draco_extension(primitive)
        if draco is not None:
            values = self.document.draco_attribute(mesh_index, primitive, draco, name, spec)
        else:
            values = self.document.accessor(accessor)
        if values is None or values.shape != (vertices, width) or not finite_rows(values):
            return None
        if name == "COLOR_0" and width == 3:
            values = np.column_stack([values, np.ones(len(values))])
        return values

    def _unit_normals(self, arrays: dict[str, NDArray[Any]]) -> None:
        """Normals scaled to unit length, for all primitives at once; a primitive with a
        normal of no direction loses its normals (and its tangents: glTF wants a NORMAL
        beside every TANGENT)."""
        if "NORMAL" not in arrays:
            self.groups = [replace(g, tangents=False) for g in self.groups]
            return
        arrays["NORMAL"], good = unit_normal_rows(arrays["NORMAL"])
        counts = np.array(self.vertex_counts, dtype=np.int64)
        starts = np.cumsum(counts) - counts
        usable = np.zeros(len(counts), dtype=bool)
        filled = counts > 0
        if filled.any():
            usable[filled] = np.logical_and.reduceat(good, starts[filled])
        self.groups = [
            replace(g, normals=g.normals and ok, tangents=g.tangents and g.normals and ok)
            for g, ok in zip(self.groups, usable.tolist(), strict=True)
        ]

    def result(self, mesh: TriangleMesh, instances: list[_Instance]) -> SurfaceAttributes:
        width = {"NORMAL": 3, "TANGENT": 4, "COLOR_0": 4}
        arrays: dict[str, NDArray[Any]] = {}
        for name, column in self.blocks.items():
            size = width.get(name, 2)
            arrays[name] = (
                np.concatenate(
                    [
                        np.zeros((count, size)) if block is None else block
                        for block, count in zip(column, self.vertex_counts, strict=True)
                    ]
                ).astype(np.float32)
                if column
                else np.zeros((0, size), np.float32)
            )
        self._unit_normals(arrays)
        uv_sets = max((group.uv_sets for group in self.groups), default=0)
        gltf = self.document.gltf
        objects = []
        for instance in instances:
            node = gltf["nodes"][instance.node] if instance.node >= 0 else {}
            name = node.get("name") or _item(gltf, "meshes", instance.mesh).get("name") or ""
            objects.append(SceneObject(str(name), instance.matrix))
        face_group = np.repeat(np.arange(len(self.groups)), self.group_sizes)
        attributes = SurfaceAttributes(
            corners=mesh.faces,
            vertex=np.arange(len(mesh.vertices), dtype=np.int64),
            face_group=face_group.astype(np.int64),
            groups=tuple(self.groups),
            normals=arrays.get("NORMAL") if any(g.normals for g in self.groups) else None,
            tangents=arrays.get("TANGENT") if any(g.tangents for g in self.groups) else None,
            uvs=tuple(arrays[f"TEXCOORD_{k}"] for k in range(uv_sets)),
            colors=arrays.get("COLOR_0") if any(g.colors for g in self.groups) else None,
            objects=tuple(objects),
            materials=_materials(self.document),
        )
        attributes.check(mesh)
        return attributes


def _materials(document: _Document) -> Materials:
    """The document's materials, textures, samplers and images (their bytes read out of
    the buffers or data URIs, so a writer can embed them)."""
    gltf = document.gltf
    images, image_data = [], []
    for index, image in enumerate(gltf.get("images") or []):
        image = dict(image) if isinstance(image, dict) else {}
        data: bytes | None = None
        if _is_count(image.get("bufferView")):
            buffer, offset, length, _ = document._view(image.pop("bufferView"))
            data = bytes(buffer[offset : offset + length])
        elif isinstance(image.get("uri"), str) and image["uri"].startswith("data:"):
            header, _, payload = image.pop("uri").partition(",")
            if not header.endswith(";base64"):
                raise UnsupportedFormatError(f"glTF image {index} has a data: URI without base64")
            data = base64.b64decode(payload, validate=True)
            image.setdefault("mimeType", header[5:].split(";", 1)[0] or "image/png")
        images.append(image)
        image_data.append(data)
    parts = {key: tuple(x for x in gltf.get(key) or [] if isinstance(x, dict))
             for key in ("materials", "textures", "samplers")}  # fmt: skip
    used = sorted(
        _extension_names([parts["materials"], parts["textures"], parts["samplers"], images])
    )
    return Materials(
        materials=parts["materials"],
        textures=parts["textures"],
        samplers=parts["samplers"],
        images=tuple(images),
        image_data=tuple(image_data),
        extensions=tuple(used),
        required=tuple(name for name in used if name in (gltf.get("extensionsRequired") or [])),
    )


def _extension_names(value: Any) -> set[str]:
    """Names of the glTF extensions used anywhere in a JSON value."""
    names: set[str] = set()
    if isinstance(value, dict):
        extensions = value.get("extensions")
        if isinstance(extensions, dict):
            names.update(str(name) for name in extensions)
        for item in value.values():
            names |= _extension_names(item)
    elif isinstance(value, list | tuple):
        for item in value:
            names |= _extension_names(item)
    return names


def _parse_json(text: bytes, format_name: str) -> Any:
    """The glTF JSON, with parse errors a user can act on."""
    try:
        return json.loads(strip_bom(text).decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise MeshParseError(f"the {format_name} JSON is not UTF-8 text: {exc}") from None
    except json.JSONDecodeError as exc:
        raise MeshParseError(f"the {format_name} JSON is malformed: {exc}") from None
    except RecursionError:
        raise MeshParseError(
            f"the {format_name} JSON nests arrays or objects too deeply to read (a valid "
            "glTF nests a few levels); the file is corrupt or not a glTF"
        ) from None


def read_glb(data: bytes, limits: MeshLimits = NO_LIMITS) -> TriangleMesh:
    """Parse binary glTF (GLB) bytes; declared lengths are checked before anything is read."""
    return read_glb_source(data, limits).mesh


def read_gltf(data: bytes, limits: MeshLimits = NO_LIMITS) -> TriangleMesh:
    """Parse text glTF bytes whose buffers are embedded as base64 ``data:`` URIs."""
    return read_gltf_source(data, limits).mesh


def read_glb_source(
    data: bytes, limits: MeshLimits = NO_LIMITS, *, attributes: bool = False
) -> SourceMesh:
    """``read_glb`` with, when ``attributes``, the file's normals, tangents, UVs, colours,
    materials and scene objects (``exchange.attributes``): one face group per primitive
    of each placement, one object per placement (named by its node, else its mesh)."""
    if strip_bom(data).lstrip()[:1] == b"{":  # a text glTF sent as GLB
        return read_gltf_source(data, limits, attributes=attributes)
    if len(data) < 12 or data[:4] != _GLB_MAGIC:
        raise MeshParseError("a GLB file must start with the 'glTF' magic bytes; is it a GLB?")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise UnsupportedFormatError(f"GLB version {version} is not supported (only 2)")
    if length > len(data):
        raise MeshParseError(
            f"the GLB is truncated: its header declares {length} bytes but the file has {len(data)}"
        )
    chunks: list[tuple[int, bytes]] = []
    offset = 12
    while offset + 8 <= length:
        chunk_length, chunk_type = struct.unpack_from("<II", data, offset)
        if offset + 8 + chunk_length > length:
            raise MeshParseError(
                f"a GLB chunk declares {chunk_length} bytes, beyond the end of the file "
                "(truncated or corrupt)"
            )
        chunks.append((chunk_type, data[offset + 8 : offset + 8 + chunk_length]))
        offset += 8 + chunk_length
    if not chunks or chunks[0][0] != _CHUNK_JSON:
        raise MeshParseError("the GLB has no JSON chunk")
    binary = next((payload for kind, payload in chunks[1:] if kind == _CHUNK_BIN), None)
    gltf = _parse_json(chunks[0][1], "GLB")
    return _read_document(_Document(gltf, binary), "GLB", limits, attributes=attributes)


def read_gltf_source(
    data: bytes, limits: MeshLimits = NO_LIMITS, *, attributes: bool = False
) -> SourceMesh:
    """``read_gltf`` with the file's attributes (``read_glb_source``)."""
    if data[:4] == _GLB_MAGIC:
        return read_glb_source(data, limits, attributes=attributes)
    document = _Document(_parse_json(data, "glTF"), None)
    return _read_document(document, "glTF", limits, attributes=attributes)


__all__ = ["read_glb", "read_glb_source", "read_gltf", "read_gltf_source"]
