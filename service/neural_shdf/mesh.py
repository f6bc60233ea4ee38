"""The triangle mesh every algorithm works on, its derived structures (cached per mesh, as
trimesh caches its properties) and its link back to the input file's faces."""

from __future__ import annotations

import hashlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.geometry import (
    FaceGraph,
    build_face_graph,
    canonical_triangles,
    count_zero_rows,
    face_adjacency,
    face_centroids,
    face_normals,
    has_own_frame,
    in_frame,
    pose_frame,
    position_order,
    principal_frame,
    weld_faces,
    zero_area_limit,
)
from neural_shdf.orientation import (
    MeshDiagnostics,
    Orientation,
    orient_faces,
    reverse_flipped,
    reverse_rows,
    reversed_slots,
)
from neural_shdf.orientation import welded_edges as sorted_welded_edges
from neural_shdf.segment.creases import CreaseGraph, crease_graph
from neural_shdf.stitching import (
    cap_spokes,
    closing_caps,
    orient_stitched_shells,
    stitch_counts,
    stitch_shells,
    stitched_edge_geometry,
)


@dataclass(frozen=True)
class Reversal:
    """How ``TriangleMesh.oriented`` derives its edges from its source's on first use: the
    triangles reversed, the source's ``welded_edges``, and its ``coincident_welding`` edges
    where those are not the same (None where the coincident faces are the welded ones)."""

    flips: NDArray[np.bool_]
    welded_edges: tuple[NDArray[np.int64], NDArray[np.int64]]
    coincident_edges: tuple[NDArray[np.int64], NDArray[np.int64]] | None


@dataclass(frozen=True, eq=False)
class TriangleMesh:
    """Triangles in a fixed order, plus the input face each triangle came from.

    Attributes:
        vertices: (V, 3) float64 positions.
        faces: (F, 3) int64 vertex indices of triangles.
        face_origin: (F,) int64, index of the input file's face (polygon) that
            triangle ``i`` came from; non-decreasing, so triangles of one polygon
            are contiguous and in the input order.
        input_face_count: number of faces in the input file. Input faces that
            produced no triangle (dropped as unusable) map to no triangle.

    Treat the arrays as read-only: what is derived from them (normals and areas, the
    welding, the orientation, the face graph, centroids, the crease graph) is computed
    once, on first use, and cached on the mesh, so every step that needs it shares it.
    ``face_graph``, ``centroids`` and ``crease_graph`` are those of ``oriented`` (the
    winding every algorithm works on), cached there and shared by both meshes.
    """

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    face_origin: NDArray[np.int64] = field(default=None)  # type: ignore[arg-type]
    input_face_count: int = -1

    def __post_init__(self) -> None:
        vertices = np.ascontiguousarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.ascontiguousarray(self.faces, dtype=np.int64).reshape(-1, 3)
        origin = (
            np.arange(len(faces), dtype=np.int64)
            if self.face_origin is None
            else np.ascontiguousarray(self.face_origin, dtype=np.int64)
        )
        count = int(origin.max()) + 1 if self.input_face_count < 0 and len(origin) else 0
        object.__setattr__(self, "vertices", vertices)
        object.__setattr__(self, "faces", faces)
        object.__setattr__(self, "face_origin", origin)
        if self.input_face_count < 0:
            object.__setattr__(self, "input_face_count", count)

    @property
    def face_count(self) -> int:
        return int(len(self.faces))

    def bare(self) -> TriangleMesh:
        """The same mesh without its cached derived arrays (cheap to send to a process)."""
        return TriangleMesh(self.vertices, self.faces, self.face_origin, self.input_face_count)

    def portable(self) -> TriangleMesh:
        """The mesh with, of its caches, only what a segmentation needs and cannot recompute
        cheaply (what the orientation pass found, and the triangles the segmentation works
        on, ``distinct``, with their normals, areas and face graph): what is sent to another
        process to segment there, with the same result."""
        distinct = self.distinct
        work = distinct.mesh
        light_work = work.bare()
        light_work.__dict__.update(
            normals_and_areas=work.normals_and_areas,
            face_graph=work.face_graph,
            oriented=light_work,
            listing=(light_work, None),
        )
        light = self.bare()
        light.__dict__.update(
            diagnostics=self.diagnostics,
            distinct=DistinctTriangles(light_work, distinct.kept, distinct.copy_of),
        )
        return light

    @cached_property
    def zero_area_limit(self) -> float:
        """Twice-area at or below which a triangle is degenerate
        (``geometry.zero_area_limit``), computed once per mesh (and seeded by the loaders,
        which check it first): the same for every winding of the triangles."""
        return zero_area_limit(self.vertices, self.faces)

    @cached_property
    def normals_and_areas(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Unit normal (F, 3) and area (F,) of each triangle, computed once per mesh.

        Degenerate triangles get a zero normal (``geometry.face_normals``). The
        arrays are shared by every caller: do not modify them.
        """
        normals, areas = face_normals(self.vertices, self.faces, area_limit=self.zero_area_limit)
        normals.flags.writeable = False
        areas.flags.writeable = False
        return normals, areas

    @cached_property
    def coincident_welding(
        self,
    ) -> tuple[NDArray[np.int64], tuple[NDArray[np.int64], NDArray[np.int64]]]:
        """``faces`` with coincident vertices sharing one index (``geometry.weld_faces``) and
        their sorted edges (``orientation.welded_edges``): what the orientation pass works on.
        ``oriented`` derives its edges from its source's on first use (``_reversed_from``)."""
        reversal = self.__dict__.get("_reversed_from")
        if reversal is not None:
            if reversal.coincident_edges is None:  # the same array as ``welded_faces``
                return self.welded_faces, self.welded_edges
            table, slot = reversal.coincident_edges
            return self.coincident_faces, (table, reversed_slots(slot, reversal.flips))
        coincident = weld_faces(self.vertices, self.faces)
        coincident.flags.writeable = False
        return coincident, sorted_welded_edges(coincident)

    @cached_property
    def coincident_faces(self) -> NDArray[np.int64]:
        """``coincident_welding``'s faces alone (``oriented`` has them without its edges)."""
        return self.coincident_welding[0]

    @cached_property
    def welded_faces(self) -> NDArray[np.int64]:
        """``coincident_welding`` with the open boundaries of separate shells that meet
        stitched together (``stitching.stitch_shells``), computed once per mesh: the
        adjacency of the face and crease graphs and of the hole caps. The same array as
        ``coincident_welding``'s where nothing is stitched."""
        coincident, edges = self.coincident_welding
        # A listing stitches in the frame it was listed in: the same seams in any pose.
        frame = self.__dict__.get("_listing_frame")
        points = self.vertices if frame is None else in_frame(self.vertices, frame)
        welded = stitch_shells(points, coincident, edges)
        if welded is not coincident:
            edges = sorted_welded_edges(welded)
            welded.flags.writeable = False
        self.__dict__.setdefault("welded_edges", edges)
        return welded

    @cached_property
    def welded_edges(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """The edges of ``welded_faces`` sorted by vertex pair (``orientation.welded_edges``),
        computed once per mesh for the face graph and the hole caps; ``oriented``'s from its
        source's, with the reversed triangles' slots permuted, on first use."""
        reversal = self.__dict__.get("_reversed_from")
        if reversal is not None:
            table, slot = reversal.welded_edges
            return table, reversed_slots(slot, reversal.flips)
        welded = self.welded_faces  # seeds the edges it sorted on the way
        seeded = self.__dict__.get("welded_edges")
        return seeded if seeded is not None else sorted_welded_edges(welded)

    def _positions_in_own_frame(self) -> NDArray[np.float64]:
        """The vertices in the pose frame of this listing's triangles (winding aside):
        where ``face_adjacency`` orders the faces of a crowded edge, the same in any pose.
        Made only where such an edge exists; not ``pose_frame``, which reads the oriented
        copy (whose orientation pass shares these links)."""
        areas = self.normals_and_areas[1]
        frame = pose_frame(face_centroids(self.vertices, self.faces), areas)
        return in_frame(self.vertices, frame)

    @cached_property
    def face_adjacency(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """The links of ``face_graph`` (``geometry.face_adjacency`` of ``welded_faces``):
        the same for every winding, so ``oriented`` shares them."""
        pairs, edge_vertices = face_adjacency(
            self.welded_faces, self.welded_edges, self._positions_in_own_frame
        )
        pairs.flags.writeable = False
        edge_vertices.flags.writeable = False
        return pairs, edge_vertices

    @cached_property
    def orientation(self) -> Orientation:
        """Which triangles to reverse so that every shell faces out of its solid (shells
        stitched together out of theirs: ``stitching.orient_stitched_shells``), and what the
        pass found in the mesh (``orientation.orient_faces``); computed once per mesh, on
        ``listing`` where it lists the triangles otherwise (then mapped back: the same
        decisions for the same surface in any order)."""
        listed, order = self.listing
        if order is not None:
            return listed_orientation(listed.orientation, order)
        coincident, edges = self.coincident_welding
        normals, areas = self.normals_and_areas
        # The face graph's links do not depend on the winding: they are worked out beside
        # the pass (both kernels release the GIL), which then adds little to the wall time.
        with ThreadPoolExecutor(max_workers=1) as beside:
            adjacency = beside.submit(lambda: self.face_adjacency)
            alone = orient_faces(
                self.vertices,
                self.faces,
                welded=coincident,
                areas=areas,
                edges=edges,
                degenerate=count_zero_rows(normals),
                # a listing's vertices are numbered by position already
                numbered_by_position="_listing_frame" in self.__dict__,
            )
            adjacency.result()
        # Shells stitched together face out of the solid they make together.
        flips = orient_stitched_shells(
            self.vertices,
            coincident,
            edges,
            self.welded_faces,
            self.welded_edges,
            alone.flips,
            normals,
            areas,
        )
        if flips is alone.flips:
            return alone
        diagnostics = replace(alone.diagnostics, reoriented_faces=int(flips.sum()))
        return replace(alone, flips=flips, diagnostics=diagnostics)

    @cached_property
    def diagnostics(self) -> MeshDiagnostics:
        """What the mesh had and what was done about it: the orientation pass's findings
        (``orientation``) and the shells stitched for the graphs (``welded_faces``), as
        ``listing`` found them (the counts of any listing)."""
        listed, order = self.listing
        if order is not None:
            return listed.diagnostics
        stitched_shells, stitched_vertices = stitch_counts(self.coincident_faces, self.welded_faces)
        return replace(
            self.orientation.diagnostics,
            stitched_shells=stitched_shells,
            stitched_vertices=stitched_vertices,
        )

    @cached_property
    def oriented(self) -> TriangleMesh:
        """The same triangles in the same order, each wound to face out of its solid
        (``orientation``): what the ShDF and the segmentation work on, whatever the file's
        winding. A reversed triangle lists its vertices backwards, (a, b, c) -> (c, b, a),
        so a file reversed that way gives back the original triangles exactly. ``self``
        where no triangle is reversed; its own ``oriented`` is itself."""
        flips = self.orientation.flips
        if not flips.any():
            return self
        given_normals, areas = self.normals_and_areas
        # One pass: the reversed rows of the triangles and of their welding, and their
        # normals computed from the new order (bit for bit those of a file wound that way);
        # the other rows copied. The edges' slots are permuted only if asked for.
        faces, welded, normals = reverse_flipped(
            self.vertices,
            self.faces,
            self.welded_faces,
            flips,
            given_normals,
            self.zero_area_limit,
        )
        coincident = self.coincident_faces
        if coincident is self.welded_faces:
            oriented_coincident, coincident_edges = welded, None
        else:
            oriented_coincident = reverse_rows(coincident, flips)
            oriented_coincident.flags.writeable = False
            coincident_edges = self.coincident_welding[1]
        oriented = TriangleMesh(self.vertices, faces, self.face_origin, self.input_face_count)
        normals.flags.writeable = False
        welded.flags.writeable = False
        # Seed the caches: the areas, the welding, the face links and the degenerate limit
        # do not change with the winding; the edges follow from this mesh's on first use.
        oriented.__dict__.update(
            zero_area_limit=self.zero_area_limit,
            normals_and_areas=(normals, areas),
            coincident_faces=oriented_coincident,
            welded_faces=welded,
            face_adjacency=self.face_adjacency,
            _reversed_from=Reversal(flips, self.welded_edges, coincident_edges),
        )
        oriented.__dict__["oriented"] = oriented
        return oriented

    @cached_property
    def listing(self) -> tuple[TriangleMesh, NDArray[np.int64] | None]:
        """(the mesh listed in an order of its positions, the index here of each of its
        triangles), or (``self``, None) where the shape leaves that order to the pose.

        Where the triangles' pose frame (``geometry.pose_frame`` of their centroids by
        area) is the shape's own (``geometry.has_own_frame``), the vertices are numbered by
        ``geometry.position_order`` in it, each triangle starts at its lowest corner (its
        winding kept) and the triangles are sorted by their corners
        (``geometry.canonical_triangles``): the same surface listed in any order, moved,
        turned or scaled, is then the same mesh, and the orientation pass, the ShDF and the
        segmentation, which run on it (``orientation``, ``distinct``), give the same
        results, mapped back to this mesh's triangles. Where the shape leaves the frame to
        the world's axes (a body of revolution, a mirror-symmetric box) an order by
        position would follow the pose: the file's order stands (a turned copy then gets
        the same results; one listed otherwise may break ties another way)."""
        if not self.face_count:
            return self, None
        areas = self.normals_and_areas[1]
        frame = pose_frame(face_centroids(self.vertices, self.faces), areas)
        if not has_own_frame(frame):
            return self, None
        rank, vertex_order = position_order(in_frame(self.vertices, frame))
        number = np.empty(len(vertex_order), dtype=np.int64)
        number[vertex_order] = np.arange(len(vertex_order))
        faces, order = canonical_triangles(None, number[self.faces], rank=rank[vertex_order])
        listed = TriangleMesh(
            self.vertices[vertex_order], faces, self.face_origin[order], self.input_face_count
        )
        listed.__dict__.update(
            listing=(listed, None),
            zero_area_limit=self.zero_area_limit,
            _listing_frame=frame,
        )
        return listed, order

    @cached_property
    def distinct(self) -> DistinctTriangles:
        """``oriented`` with one copy of each set of coincident triangles (double-sided
        cards, a triangle repeated in place): what the ShDF and the segmentation work on,
        listed as ``listing`` lists them. Copies would stop each other's rays at distance
        zero, weigh k times in the filters, and join every neighbour through a non-manifold
        edge in the segmentation's graph, so copies take the value and the part of their
        first copy. ``oriented`` itself, with identity maps, where the file's order stands
        and no triangle has a copy."""
        listed, order = self.listing
        if order is not None:
            inner = listed.distinct
            copy_of = np.empty(self.face_count, dtype=np.int64)
            copy_of[order] = inner.copy_of
            return DistinctTriangles(inner.mesh, order[inner.kept], copy_of)
        oriented = self.oriented
        first_copy = np.asarray(self.orientation.first_copy, dtype=np.int64)
        if not len(first_copy) or first_copy.max() < 0:
            identity = np.arange(self.face_count)
            return DistinctTriangles(oriented, identity, identity)
        kept = np.flatnonzero(first_copy < 0)
        copy_of = np.searchsorted(
            kept, np.where(first_copy < 0, np.arange(len(first_copy)), first_copy)
        )
        unique = TriangleMesh(
            oriented.vertices,
            oriented.faces[kept],
            oriented.face_origin[kept],
            oriented.input_face_count,
        )
        normals, areas = oriented.normals_and_areas
        # Already facing out: seed the caches rather than orient and measure again.
        unique.__dict__.update(
            oriented=unique,
            normals_and_areas=(normals[kept], areas[kept]),
            listing=(unique, None),
        )
        if "_listing_frame" in self.__dict__:  # stitched in the same frame as its source
            unique.__dict__["_listing_frame"] = self.__dict__["_listing_frame"]
        return DistinctTriangles(unique, kept, copy_of)

    @cached_property
    def pose_geometry(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(vertices, triangle normals) in ``pose_frame`` (``geometry.in_frame``), computed
        once per mesh: what the face graph and the ShDF's rays read, the same in any pose."""
        framed = in_frame(self.vertices, self.pose_frame)
        normals, _ = face_normals(framed, self.faces)
        framed.flags.writeable = False
        normals.flags.writeable = False
        return framed, normals

    @cached_property
    def face_graph(self) -> FaceGraph:
        """Face adjacency with coincident vertices welded (``welded_faces``), its dihedral
        angles and concave flags following the oriented normals: the graph the ShDF's
        filters and the segmentation run on. Computed once, on ``oriented``, from the
        coordinates in ``pose_frame`` (``geometry.in_frame``), lengths back in the mesh's
        units: a sliver's normal, which rounding decides, is the same in any pose."""
        oriented = self.oriented
        if oriented is not self:
            return oriented.face_graph
        scale = self.pose_frame[2]
        framed, normals = self.pose_geometry
        welded = self.welded_faces
        graph = build_face_graph(framed, welded, normals, adjacency=self.face_adjacency)
        coincident = self.coincident_faces
        if coincident is not welded:
            graph = stitched_edge_geometry(graph, framed, self.faces, normals, coincident, welded)
        return replace(graph, edge_length=graph.edge_length * scale)

    @cached_property
    def centroids(self) -> NDArray[np.float64]:
        """Centroid (F, 3) of each triangle of ``oriented`` (``geometry.face_centroids``)."""
        oriented = self.oriented
        if oriented is not self:
            return oriented.centroids
        centroids = face_centroids(self.vertices, self.faces)
        centroids.flags.writeable = False
        return centroids

    @cached_property
    def principal_frame(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``geometry.principal_frame`` of the centroids weighted by the areas: the axes
        the graph cut's and the crease graph's grids are laid along, computed once per
        mesh (a mean and three axes, not the coordinates)."""
        return principal_frame(self.centroids, self.normals_and_areas[1])

    @cached_property
    def pose_frame(self) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
        """``geometry.pose_frame`` of the centroids weighted by the areas: the frame the
        ShDF's rays are cast in, so that a rotated, moved or scaled copy of the mesh meets
        the same float32 coordinates in Embree (and its ties between hits alike)."""
        return pose_frame(self.centroids, self.normals_and_areas[1], self.principal_frame)

    @cached_property
    def crease_graph(self) -> CreaseGraph:
        """The graph the segmentation's crease refinement runs on (``segment.creases``): it
        depends on the mesh only, so every ShDF and mixture of the mesh shares it."""
        oriented = self.oriented
        if oriented is not self:
            return oriented.crease_graph
        return crease_graph(
            self.face_graph, self.normals_and_areas[1], self.centroids, frame=self.principal_frame
        )

    @cached_property
    def hole_spokes(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """``stitching.cap_spokes`` of the caps over this mesh's holes (its triangles as
        they are): where the part tree counts boundary across a hole. It depends on the mesh
        only, so a kept mesh builds it once for every segmentation, not per slider value
        (dense-dev zenobia, 462k faces, 2 holes: 21 ms each)."""
        coincident, _ = self.coincident_welding
        welded, edges = self.welded_faces, self.welded_edges
        vertices, caps = closing_caps(self.vertices, coincident, welded, edges)
        return cap_spokes(vertices, len(self.vertices), welded, edges, caps)

    def content_hash(self) -> str:
        """SHA-256 of the canonical geometry: vertices, triangles and face origins."""
        digest = hashlib.sha256()
        digest.update(b"neural-shdf-mesh-v1")
        for array in (self.vertices, self.faces, self.face_origin):
            digest.update(str(array.shape).encode())
            digest.update(np.ascontiguousarray(array).tobytes())
        digest.update(str(self.input_face_count).encode())
        return digest.hexdigest()

    def input_face_weights(self) -> NDArray[np.float64]:
        """How much each triangle counts in its input face: its area, or 1 for every
        triangle of a face whose triangles are all degenerate (zero area)."""
        _, areas = self.normals_and_areas
        polygon_area = np.bincount(self.face_origin, weights=areas, minlength=self.input_face_count)
        flat = polygon_area[self.face_origin] <= 0
        return np.where(flat, 1.0, areas) if flat.any() else np.asarray(areas, dtype=np.float64)

    def to_input_faces(
        self, values: NDArray[Any], *, weights: NDArray[Any] | None = None
    ) -> NDArray[Any]:
        """Map per-triangle float values to per-input-face values: the mean over the
        face's triangles weighted by area (``weights`` to weigh otherwise).

        The one mapping of values that the CLI, the API and the library use. Input
        faces without triangles get NaN.
        """
        values = np.asarray(values, dtype=np.float64)
        w = self.input_face_weights() if weights is None else np.asarray(weights, np.float64)
        total = np.bincount(self.face_origin, weights=w * values, minlength=self.input_face_count)
        norm = np.bincount(self.face_origin, weights=w, minlength=self.input_face_count)
        out = np.full(self.input_face_count, np.nan)
        ok = norm > 0
        out[ok] = total[ok] / norm[ok]
        return out

    def labels_to_input_faces(
        self, labels: NDArray[Any], *, weights: NDArray[Any] | None = None, missing: int = -1
    ) -> NDArray[np.int64]:
        """Map per-triangle labels to one label per input face.

        A polygon split into several triangles takes the label that covers the
        largest share of its area (``weights`` to weigh otherwise; ties: the
        smallest label). The one mapping of labels that the CLI, the API and the
        library use. Input faces that produced no triangle get ``missing``.
        """
        labels = np.asarray(labels, dtype=np.int64)
        out = np.full(self.input_face_count, missing, dtype=np.int64)
        if len(labels) == 0:
            return out
        if np.array_equal(self.face_origin, np.arange(len(labels))):
            out[: len(labels)] = labels
            return out
        w = self.input_face_weights() if weights is None else np.asarray(weights, np.float64)
        # Sum weight per (origin, label), then keep the heaviest label per origin.
        keys = self.face_origin * (int(labels.max()) + 1) + labels
        unique_keys, inverse = np.unique(keys, return_inverse=True)
        mass = np.bincount(inverse, weights=w)
        origin = unique_keys // (int(labels.max()) + 1)
        label = unique_keys % (int(labels.max()) + 1)
        order = np.lexsort((label, -mass, origin))
        first = np.ones(len(order), dtype=bool)
        first[1:] = origin[order][1:] != origin[order][:-1]
        chosen = order[first]
        out[origin[chosen]] = label[chosen]
        return out


def listed_orientation(listed: Orientation, order: NDArray[np.int64]) -> Orientation:
    """The orientation of a mesh whose ``listing`` (triangle ``i`` there is triangle
    ``order[i]`` here) found ``listed``: the same flips, each copy's first copy the
    lowest-numbered triangle here of its set."""
    flips = np.empty_like(listed.flips)
    flips[order] = listed.flips
    first = np.asarray(listed.first_copy, dtype=np.int64)
    if not len(first) or first.max() < 0:
        return replace(listed, flips=flips)
    root = np.where(first >= 0, first, np.arange(len(first)))
    lowest = np.full(len(first), len(first), dtype=np.int64)
    np.minimum.at(lowest, root, order)
    first_copy = np.empty_like(first)
    first_copy[order] = np.where(lowest[root] == order, -1, lowest[root])
    return replace(listed, flips=flips, first_copy=first_copy)


@dataclass(frozen=True)
class DistinctTriangles:
    """A mesh's triangles without coincident copies (``TriangleMesh.distinct``).

    ``mesh``: the distinct triangles, oriented, in an order of their positions; ``kept``:
    the index of each in the original mesh (its first copy); ``copy_of``: per original
    triangle, the index of its copy in ``mesh`` (so ``values[copy_of]`` gives every copy
    its value).
    """

    mesh: TriangleMesh
    kept: NDArray[np.int64]
    copy_of: NDArray[np.int64]

    @property
    def has_copies(self) -> bool:
        return len(self.kept) < len(self.copy_of)

    @property
    def reordered(self) -> bool:
        """Whether ``mesh`` is not the original's triangles in the original order."""
        return self.has_copies or not np.array_equal(self.kept, np.arange(len(self.kept)))
