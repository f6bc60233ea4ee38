"""UV atlases of stored meshes, part by part: computed once per (segmentation, unwrap
parameters) from the cached segmentation, cached."""

from __future__ import annotations

import base64
import functools

import numpy as np
from numpy.typing import NDArray

from neural_shdf.api.jobs import JobAccepted
from neural_shdf.api.mesh_store import MeshStore
from neural_shdf.api.metrics import Metrics
from neural_shdf.api.segmentation import SegmentationService
from neural_shdf.api.tasks import TaskRunner
from neural_shdf.exchange.gltf_writer import unwrapped_glb
from neural_shdf.mesh import TriangleMesh
from neural_shdf.segment import SegmentParams
from neural_shdf.store.cache import ResultCache
from neural_shdf.store.keys import atlas_key, atlas_png_key
from neural_shdf.unwrap import UnwrapParams, UvAtlas, atlas_layout_png, polygon_corner_uvs
from neural_shdf.unwrap import unwrap as unwrap_mesh

#: The file each kind of atlas job serves once it succeeded.
RESULT_FILES = {
    "unwrap": "unwrapped.glb",
    "obj": "unwrapped.obj",
    "atlas": "atlas.png",
    "uvs": "uvs",
}


def _atlas_arrays(atlas: UvAtlas) -> dict[str, NDArray]:
    return {
        "corner_uvs": atlas.corner_uvs.astype(np.float32),
        "chart": atlas.chart.astype(np.int32),
        "chart_part": atlas.chart_part.astype(np.int32),
        "size": np.array([atlas.width, atlas.height], dtype=np.int64),
        "utilization": np.array(atlas.utilization),
    }


def _atlas_from_arrays(arrays: dict[str, NDArray]) -> UvAtlas:
    width, height = (int(v) for v in arrays["size"])
    return UvAtlas(
        corner_uvs=arrays["corner_uvs"].astype(np.float64),
        chart=arrays["chart"].astype(np.int64),
        chart_part=arrays["chart_part"].astype(np.int64),
        width=width,
        height=height,
        utilization=float(arrays["utilization"]),
    )


class UnwrapService:
    """UV atlases by part, from the cached segmentation (and so the cached ShDF)."""

    def __init__(
        self,
        cache: ResultCache,
        metrics: Metrics,
        tasks: TaskRunner,
        meshes: MeshStore,
        segmentations: SegmentationService,
    ) -> None:
        self.cache = cache
        self.metrics = metrics
        self.tasks = tasks
        self.meshes = meshes
        self.segmentations = segmentations

    def key(self, mesh_id: str, method: str, params: SegmentParams, unwrap: UnwrapParams) -> str:
        """The segmentation's key plus the unwrap parameters."""
        return atlas_key(self.segmentations.key(mesh_id, method, params), unwrap)

    def cached(self, key: str) -> UvAtlas | None:
        """The cached atlas (memory, then the shared cache), or None."""
        atlas = self.cache.recall_arrays(key, _atlas_from_arrays)
        self.metrics.count_cache("unwrap", hit=atlas is not None)
        return atlas

    def _store(
        self, key: str, mesh_id: str, atlas: UvAtlas, guard: tuple[str, bytes] | None
    ) -> None:
        self.meshes.store_result(key, mesh_id, _atlas_arrays(atlas), guard)
        self.cache.remember(key, atlas)

    async def get(
        self,
        mesh_id: str,
        method: str,
        params: SegmentParams,
        unwrap: UnwrapParams,
        *,
        kind: str = "unwrap",
    ) -> tuple[TriangleMesh, UvAtlas]:
        """The mesh and its atlas (cached, else from the cached segmentation, itself from
        the cached ShDF). A large mesh (over ``sync_face_threshold`` faces) answers 202 with
        a job: first the ShDF's, then the atlas's (``kind`` ``unwrap`` or ``atlas``: the
        route whose result it points to); repeat the request once it succeeded. ``method``
        is a resolved producer (``Engine.resolved_method``)."""
        key = self.key(mesh_id, method, params, unwrap)
        result, _ = await self.segmentations.get(mesh_id, method, params)
        mesh = await self.tasks.io(self.meshes.load, mesh_id)
        atlas = self.cache.recall(key) or await self.tasks.io(self.cached, key)
        if atlas is not None:
            return mesh, atlas
        compute = functools.partial(
            self.tasks.compute_once,
            key,
            functools.partial(self.cached, key),
            # In a worker process: xatlas packs holding the GIL (seconds at 8192 texels).
            functools.partial(
                self.tasks.isolated,
                unwrap_mesh,
                mesh.bare(),
                np.asarray(result.triangle_labels, dtype=np.int64),
                unwrap,
            ),
            functools.partial(self._store, key, mesh_id),
            functools.partial(self.meshes.guard, mesh_id),
        )
        if mesh.face_count > self.segmentations.shdf.settings.sync_face_threshold:
            shdf = self.segmentations.shdf
            job = await shdf.start_computation_job(
                key,
                mesh_id,
                method,
                params.seed,
                compute,
                kind=kind,
                result_url=f"/v1/meshes/{mesh_id}/segmentation/{RESULT_FILES[kind]}",
            )
            raise JobAccepted(job)
        atlas, _ = await self.tasks.with_timeout(self.tasks.single_flight(key, compute))
        return mesh, atlas

    async def glb(
        self, mesh_id: str, method: str, params: SegmentParams, unwrap: UnwrapParams
    ) -> bytes:
        """The mesh with its atlas UVs and the atlas layout as its texture."""
        mesh, atlas = await self.get(mesh_id, method, params, unwrap)
        texture = await self._layout_png(mesh_id, method, params, unwrap, atlas)
        key = self.key(mesh_id, method, params, unwrap)
        write = functools.partial(unwrapped_glb, mesh, atlas, texture_png=texture)
        # Identical requests share one writer; it runs within the request timeout.
        return await self.tasks.with_timeout(self.tasks.single_flight(f"{key}:glb", write))

    async def obj(
        self, mesh_id: str, method: str, params: SegmentParams, unwrap: UnwrapParams
    ) -> bytes:
        """The mesh as OBJ with its atlas UVs (``vt``), one ``f`` per input face."""
        from neural_shdf.exchange.obj_writer import obj_text_with_uvs

        mesh, atlas = await self.get(mesh_id, method, params, unwrap, kind="obj")
        key = self.key(mesh_id, method, params, unwrap)
        write = functools.partial(_obj_bytes, obj_text_with_uvs, mesh, atlas)
        return await self.tasks.with_timeout(self.tasks.single_flight(f"{key}:obj", write))

    async def uvs(
        self, mesh_id: str, method: str, params: SegmentParams, unwrap: UnwrapParams
    ) -> dict[str, object]:
        """The ``UvLayout`` answer: UVs per corner of every input face
        (``polygon_corner_uvs``), the chart of each input face and the atlas's figures."""
        mesh, atlas = await self.get(mesh_id, method, params, unwrap, kind="uvs")
        layout = await self.tasks.io(polygon_corner_uvs, mesh, atlas.corner_uvs)
        first_triangle = np.searchsorted(mesh.face_origin, np.arange(mesh.input_face_count))
        chart = np.full(mesh.input_face_count, -1, dtype="<i4")
        has = layout.corner_counts > 0
        chart[has] = atlas.chart[first_triangle[has]]
        return {
            "mesh_id": mesh_id,
            "faces": mesh.input_face_count,
            "corners": len(layout.uvs),
            "corner_counts_base64": _base64(layout.corner_counts.astype("<i4")),
            "uvs_base64": _base64(layout.uvs.astype("<f4")),
            "chart_base64": _base64(chart),
            "chart_part": [int(part) for part in atlas.chart_part],
            "width": atlas.width,
            "height": atlas.height,
            "utilization": atlas.utilization,
            "split_faces": int((~layout.consistent).sum()),
        }

    async def atlas_png(
        self, mesh_id: str, method: str, params: SegmentParams, unwrap: UnwrapParams
    ) -> bytes:
        """The atlas layout as a PNG: charts coloured by part, outlined."""
        _, atlas = await self.get(mesh_id, method, params, unwrap, kind="atlas")
        return await self._layout_png(mesh_id, method, params, unwrap, atlas)

    async def _layout_png(
        self,
        mesh_id: str,
        method: str,
        params: SegmentParams,
        unwrap: UnwrapParams,
        atlas: UvAtlas,
    ) -> bytes:
        """The atlas picture's PNG, drawn once per atlas and cached as bytes (the GLB's
        texture and ``atlas.png`` share it)."""
        key = atlas_png_key(self.key(mesh_id, method, params, unwrap))
        png = self.cache.recall(key) or await self.tasks.io(self._cached_png, key)
        if png is not None:
            return png
        compute = functools.partial(
            self.tasks.compute_once,
            key,
            functools.partial(self._cached_png, key),
            functools.partial(self._draw_png, atlas, unwrap),
            functools.partial(self._store_png, key, mesh_id),
            functools.partial(self.meshes.guard, mesh_id),
        )
        png, _ = await self.tasks.with_timeout(self.tasks.single_flight(key, compute))
        return png

    def _cached_png(self, key: str) -> bytes | None:
        png = self.cache.recall_arrays(key, _png_from_arrays)
        self.metrics.count_cache("atlas_png", hit=png is not None)
        return png

    def _store_png(
        self, key: str, mesh_id: str, png: bytes, guard: tuple[str, bytes] | None
    ) -> None:
        self.meshes.store_result(key, mesh_id, {"png": np.frombuffer(png, dtype=np.uint8)}, guard)
        self.cache.remember(key, png)

    @staticmethod
    def _draw_png(atlas: UvAtlas, unwrap: UnwrapParams) -> bytes:
        return atlas_layout_png(atlas, size=unwrap.atlas_size)


def _base64(values: NDArray) -> str:
    return base64.b64encode(np.ascontiguousarray(values).tobytes()).decode("ascii")


def _obj_bytes(write, mesh: TriangleMesh, atlas: UvAtlas) -> bytes:  # noqa: ANN001
    text, _ = write(mesh, atlas)
    return text.encode()


def _png_from_arrays(arrays: dict[str, NDArray]) -> bytes:
    return arrays["png"].tobytes()
