"""Embree 4 through ctypes, with 16-ray packets cast from numba kernels.

The Embree library is the one the ``embreex`` wheel ships (``embreex.libs``),
or a system ``libembree4``. ``embreex`` itself casts one ray per call
(``rtcIntersect1``); calling ``rtcIntersect16`` from compiled loops that also
make the rays and reduce the hits is what lets the exact ShDF reach ~5 M rays/s
on two cores. Only what the project needs is bound: one triangle mesh per scene
and closest-hit queries.

A packet is a float32 array of shape ``(PACKET_ROWS, 16)`` laid out as Embree's
``RTCRayHit16`` (structure of arrays, 64-byte aligned); ``new_packet`` makes one
and ``intersect_packet`` casts it from inside a numba kernel.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
import threading
from collections.abc import Callable
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from neural_shdf.compiled import kernel
from neural_shdf.geometry import canonical_triangles

#: Rays per packet (``rtcIntersect16``).
LANES = 16
#: Rows of ``RTCRayHit16``: ray (org xyz, tnear, dir xyz, time, tfar, mask, id,
#: flags), hit (Ng xyz, u, v, primID, geomID, instID, instPrimID), spare rows.
PACKET_ROWS = 24
ORG_X, ORG_Y, ORG_Z, TNEAR, DIR_X, DIR_Y, DIR_Z, TIME, TFAR, MASK, RAY_ID, FLAGS = range(12)
NORMAL_X, NORMAL_Y, NORMAL_Z = 12, 13, 14  # unnormalised geometric normal of the hit
PRIM_ID, GEOM_ID = 17, 18
INVALID_ID = 0xFFFFFFFF

_GEOMETRY_TYPE_TRIANGLE = 0
_BUFFER_TYPE_INDEX, _BUFFER_TYPE_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
#: Embree's ``RTCBuildQuality`` by name: ``low`` builds a Morton-code BVH faster than
#: ``medium``'s binned SAH one (docs/benchmarks.md), whose traversal is faster; ``medium``
#: pays off when every face casts its cone, ``low`` when a few thousand points do.
BUILD_QUALITY = {"low": 0, "medium": 1}
_FEATURE_FLAG_ALL = 0xFFFFFFFF
_ERRORS = {
    1: "unknown error",
    2: "invalid argument",
    3: "invalid operation",
    4: "out of memory",
    5: "unsupported CPU",
    6: "cancelled",
}

_Pointer = ctypes.c_size_t
_IntersectPacket = ctypes.CFUNCTYPE(None, _Pointer, _Pointer, _Pointer, _Pointer)


def _library_candidates() -> list[str]:
    """Paths of Embree 4 libraries: the one bundled with embreex first, then the system's."""
    paths: list[str] = []
    try:
        # Optional here: without embreex, the system's Embree 4 serves.
        import embreex

        site = os.path.dirname(os.path.dirname(os.path.abspath(embreex.__file__)))
        for pattern in (
            "embreex.libs/libembree4*.so*",
            "embreex/.dylibs/libembree4*.dylib",
            "embreex.libs/embree4*.dll",
            "embreex/libembree4*",
        ):
            paths += sorted(glob.glob(os.path.join(site, pattern)))
    except ImportError:
        pass
    system = ctypes.util.find_library("embree4")
    if system:
        paths.append(system)
    return paths


class Embree:
    """The loaded library, one device, and the packet function for numba kernels."""

    def __init__(self) -> None:
        candidates = _library_candidates()
        if not candidates:
            raise ImportError(
                "Embree 4 was not found: install the 'embreex' wheel (it ships libembree4) "
                "or the system's libembree4"
            )
        self.path = candidates[0]
        lib = ctypes.CDLL(self.path)
        self.lib = lib
        signatures = {
            "rtcNewDevice": (_Pointer, [ctypes.c_char_p]),
            "rtcGetDeviceError": (ctypes.c_int, [_Pointer]),
            "rtcNewScene": (_Pointer, [_Pointer]),
            "rtcSetSceneBuildQuality": (None, [_Pointer, ctypes.c_int]),
            "rtcNewGeometry": (_Pointer, [_Pointer, ctypes.c_int]),
            "rtcSetGeometryBuildQuality": (None, [_Pointer, ctypes.c_int]),
            "rtcSetSharedGeometryBuffer": (
                None,
                [
                    _Pointer,
                    ctypes.c_int,
                    ctypes.c_uint,
                    ctypes.c_int,
                    _Pointer,
                    _Pointer,
                    _Pointer,
                    _Pointer,
                ],
            ),
            "rtcCommitGeometry": (None, [_Pointer]),
            "rtcAttachGeometry": (ctypes.c_uint, [_Pointer, _Pointer]),
            "rtcReleaseGeometry": (None, [_Pointer]),
            "rtcCommitScene": (None, [_Pointer]),
            "rtcReleaseScene": (None, [_Pointer]),
        }
        for name, (restype, argtypes) in signatures.items():
            function = getattr(lib, name)
            function.restype, function.argtypes = restype, argtypes
        self.device = lib.rtcNewDevice(None)
        if not self.device:
            raise RuntimeError(f"Embree could not create a device ({self.path})")
        address = ctypes.cast(lib.rtcIntersect16, ctypes.c_void_p).value
        #: ``rtcIntersect16(valid, scene, rayhit, arguments)``, callable from numba.
        self.intersect16 = _IntersectPacket(cast(int, address))

    def check(self, what: str) -> None:
        """Raise if the device recorded an error during ``what``."""
        code = self.lib.rtcGetDeviceError(self.device)
        if code:
            raise RuntimeError(f"Embree failed to {what}: {_ERRORS.get(code, code)}")


_embree: Embree | None = None
_embree_lock = threading.Lock()


def embree() -> Embree:
    """The process's Embree device, created on first use."""
    global _embree
    with _embree_lock:
        if _embree is None:
            _embree = Embree()
        return _embree


class Scene:
    """A committed Embree scene of one triangle mesh (float32, centred on its bounding box).

    The triangles are stored in ``canonical_triangles``' order, by position: the same
    surface in any face or vertex order, or winding start, builds the same tree, so a
    ray meeting two triangles at the same distance reports the same one.
    ``triangle_of`` maps the scene's triangle indices (Embree's ``primID``, what
    ``hit_of`` reads) to the input's, ``scene_index`` back; ``first_hits`` returns the
    input's. ``surface_triangles``: the input's first triangles, kept before the rest
    in the scene (``canonical_triangles``' ``head``).
    Degenerate triangles are kept in the buffers; Embree never reports hits on them.
    Rays and hits use coordinates relative to ``center``. ``quality``: a key of
    ``BUILD_QUALITY`` (the hits are the same; build and traversal times differ).
    """

    def __init__(
        self,
        vertices: NDArray[Any],
        faces: NDArray[Any],
        quality: str = "medium",
        surface_triangles: int | None = None,
    ) -> None:
        if quality not in BUILD_QUALITY:
            raise ValueError(f"unknown build quality {quality!r}; use one of {list(BUILD_QUALITY)}")
        api = embree()
        self.api = api
        vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        self.center = self.center_of(vertices)
        # Embree reads these buffers in place (padded by one float for 16-byte loads).
        self._vertices = np.zeros((len(vertices) + 1, 3), dtype=np.float32)
        self._vertices[: len(vertices)] = vertices - self.center
        canonical, self.triangle_of = canonical_triangles(vertices, faces, surface_triangles)
        #: The scene's index of each input triangle (``triangle_of`` inverted).
        self.scene_index = np.empty(len(faces), dtype=np.int64)
        self.scene_index[self.triangle_of] = np.arange(len(faces))
        self._faces = np.ascontiguousarray(canonical, dtype=np.uint32)
        lib = api.lib
        self.handle = lib.rtcNewScene(api.device)
        lib.rtcSetSceneBuildQuality(self.handle, BUILD_QUALITY[quality])
        geometry = lib.rtcNewGeometry(api.device, _GEOMETRY_TYPE_TRIANGLE)
        lib.rtcSetGeometryBuildQuality(geometry, BUILD_QUALITY[quality])
        lib.rtcSetSharedGeometryBuffer(
            geometry,
            _BUFFER_TYPE_VERTEX,
            0,
            _FORMAT_FLOAT3,
            self._vertices.ctypes.data,
            0,
            12,
            len(vertices),
        )
        lib.rtcSetSharedGeometryBuffer(
            geometry,
            _BUFFER_TYPE_INDEX,
            0,
            _FORMAT_UINT3,
            self._faces.ctypes.data,
            0,
            12,
            len(self._faces),
        )
        lib.rtcCommitGeometry(geometry)
        lib.rtcAttachGeometry(self.handle, geometry)
        lib.rtcReleaseGeometry(geometry)
        lib.rtcCommitScene(self.handle)  # ctypes releases the GIL: builds overlap other work
        api.check("build the scene")
        #: ``RTCIntersectArguments`` with default flags and all features.
        self.arguments = np.zeros(16, dtype=np.uint32)
        self.arguments[1] = _FEATURE_FLAG_ALL

    @staticmethod
    def center_of(vertices: NDArray[Any]) -> NDArray[Any]:
        """Centre of the bounding box: the origin of the scene's float32 coordinates."""
        low, high = bounding_box(vertices)
        return 0.5 * (low + high)

    def __del__(self) -> None:
        handle = getattr(self, "handle", None)
        if handle:
            self.api.lib.rtcReleaseScene(handle)
            self.handle = None

    def kernel_arguments(self) -> tuple[Callable[[int, int, int, int], None], int, int]:
        """``(intersect16, scene, arguments)`` as numba kernels take them."""
        return self.api.intersect16, self.handle, self.arguments.ctypes.data

    def first_hits(self, origins: NDArray[Any], directions: NDArray[Any]) -> NDArray[np.int64]:
        """Index of the first triangle each ray hits, -1 for none (origins relative to centre)."""
        origins = np.ascontiguousarray(origins, dtype=np.float32).reshape(-1, 3)
        directions = np.ascontiguousarray(directions, dtype=np.float32).reshape(-1, 3)
        hits = np.empty(len(origins), dtype=np.int64)
        _first_hits(*self.kernel_arguments(), origins, directions, hits)
        return np.where(hits >= 0, self.triangle_of[np.maximum(hits, 0)], -1)


def bounding_box(vertices: NDArray[Any]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(low, high) corners of the points' bounding box (one compiled pass: numpy's
    reductions along the short axis of an (N, 3) array are several times slower)."""
    vertices = np.ascontiguousarray(vertices, dtype=np.float64).reshape(-1, 3)
    if len(vertices) == 0:
        raise ValueError("the bounding box of no points")
    return _bounding_box(vertices)


@kernel
def _bounding_box(vertices: NDArray[Any]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    low = vertices[0].copy()
    high = vertices[0].copy()
    for row in range(1, len(vertices)):
        for axis in range(3):
            value = vertices[row, axis]
            if value < low[axis]:
                low[axis] = value
            elif value > high[axis]:
                high[axis] = value
    return low, high


@kernel
def new_packet() -> tuple[NDArray[Any], NDArray[Any], NDArray[Any]]:
    """(rays as float32 rows, the same memory as uint32, valid mask) for ``intersect_packet``."""
    raw = np.zeros(PACKET_ROWS * LANES + LANES, dtype=np.float32)
    skip = (-raw.ctypes.data % 64) // 4
    rays = raw[skip : skip + PACKET_ROWS * LANES].reshape(PACKET_ROWS, LANES)
    raw_valid = np.zeros(2 * LANES, dtype=np.int32)
    skip = (-raw_valid.ctypes.data % 64) // 4
    return rays, rays.view(np.uint32), raw_valid[skip : skip + LANES]


@kernel(inline=True)
def set_ray(
    rays: NDArray[Any],
    ids: NDArray[Any],
    lane: int,
    origin: NDArray[Any],
    direction: NDArray[Any],
    offset: float | np.float32,
) -> None:
    """Put the ray from ``origin + offset * direction`` along ``direction`` (float32 rows)
    in ``lane`` of a packet and reset its hit."""
    rays[ORG_X, lane] = origin[0] + offset * direction[0]
    rays[ORG_Y, lane] = origin[1] + offset * direction[1]
    rays[ORG_Z, lane] = origin[2] + offset * direction[2]
    rays[TNEAR, lane] = 0.0
    rays[DIR_X, lane] = direction[0]
    rays[DIR_Y, lane] = direction[1]
    rays[DIR_Z, lane] = direction[2]
    rays[TIME, lane] = 0.0
    rays[TFAR, lane] = np.inf
    ids[MASK, lane] = INVALID_ID
    ids[RAY_ID, lane] = 0
    ids[FLAGS, lane] = 0
    ids[GEOM_ID, lane] = INVALID_ID


@kernel(inline=True)
def intersect_packet(
    intersect16: Callable[[int, int, int, int], None],
    scene: int,
    arguments: int,
    rays: NDArray[Any],
    ids: NDArray[Any],
    valid: NDArray[Any],
    count: int,
) -> None:
    """Cast the first ``count`` lanes of a packet; ``hit_of`` then reads each lane's triangle."""
    for lane in range(LANES):
        valid[lane] = -1 if lane < count else 0
    intersect16(valid.ctypes.data, scene, rays.ctypes.data, arguments)


@kernel(inline=True)
def hit_of(ids: NDArray[Any], lane: int) -> int | np.int64:
    """Triangle hit by ``lane`` after ``intersect_packet``, -1 for none."""
    if ids[GEOM_ID, lane] == INVALID_ID:
        return -1
    return np.int64(ids[PRIM_ID, lane])


@kernel
def _first_hits(
    intersect16: Callable[[int, int, int, int], None],
    scene: int,
    arguments: int,
    origins: NDArray[Any],
    directions: NDArray[Any],
    hits: NDArray[Any],
) -> None:
    rays, ids, valid = new_packet()
    no_offset = np.float32(0.0)
    for start in range(0, len(origins), LANES):
        count = min(LANES, len(origins) - start)
        for lane in range(count):
            i = start + lane
            set_ray(rays, ids, lane, origins[i], directions[i], no_offset)
        intersect_packet(intersect16, scene, arguments, rays, ids, valid, count)
        for lane in range(count):
            hits[start + lane] = hit_of(ids, lane)
