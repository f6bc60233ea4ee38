"""The neural ShDF's input graph: Poisson-disk samples of the surface and their edges.

Shared by training (``model_export``) and serving (``neural_shdf.shdf.neural``):
both call :func:`build_sample_graph`, so the network always sees the same features.
Numpy, scipy and numba only (the service never imports torch).

* Samples: Poisson-disk sampling of the full-resolution surface with a fixed
  radius relative to the surface's scale, ``r = sqrt(RADIUS_AREA_FACTOR * area /
  target_samples)`` (about ``target_samples`` samples whatever the tessellation).
  Area-weighted random candidates, then a greedy maximal independent set of the
  candidates' conflict graph (pairs closer than ``r``), in random priority order:
  vectorised, deterministic for a seed.
* Density ``rho``: full-resolution surface area within ``DENSITY_RADIUS`` radii
  of the sample (counted with the area-uniform candidates), over the area of a
  flat disk of that radius: 1 on a plane, about 2 inside thin walls, below 1 at
  borders. It scales the messages a sample sends, so that adaptive and uniform
  tessellations of one shape weigh alike (it depends on area, not on triangles).
* Edges (sender -> receiver): the ``knn`` nearest samples (local surface), plus
  "cone" edges to the ``cone_neighbours`` nearest samples inside the inward
  cone of the receiver's normal (with one radius of lateral slack) that face away
  from it: the other side of the volume, the surface the ShDF's rays hit
  (found on a k-d tree, ``search.cone_neighbours``: linear in the samples).
* Features are rotation, translation and scale invariant: lengths in units of
  the sampling radius, and dot products of normals and edge directions.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from neural_shdf.compiled import kernel
from neural_shdf.errors import InvalidGeometryError
from neural_shdf.geometry import face_normals
from neural_shdf.shdf.neural.search import cone_neighbours, nearest_points

#: Bump when the meaning or order of features changes (checked against the model card).
FEATURE_SPEC_VERSION = 5
#: Poisson radius r: sqrt(RADIUS_AREA_FACTOR * area / target) gives about ``target`` samples
#: (random sequential packing covers ~0.55 of the plane with disks of diameter r).
RADIUS_AREA_FACTOR = 0.57
#: Candidates drawn per target sample before the Poisson elimination.
CANDIDATES_PER_SAMPLE = 12
#: Radius (in Poisson radii) of the neighbourhood whose surface area gives the density.
DENSITY_RADIUS = 1.5
#: Node features: density, and statistics of the sample's cone edges (a ray-free
#: first guess of the diameter the network refines); logs of lengths in radii.
NODE_FEATURES = (
    "density",
    "log_density",
    "has_cone_edge",
    "cone_edge_count",
    "log_min_cone_distance",
    "log_mean_cone_distance",
    "log_mean_cone_depth",
)
#: Node features of the ray-informed network (``GraphSpec.ray_count`` > 0), after
#: ``NODE_FEATURES``: what the ShDF's ray cone cast from the sample sees.
RAY_NODE_FEATURES = (
    "has_ray_hit",
    "log_ray_diameter",
    "ray_spread",
    "ray_hit_fraction",
)
#: Edge features, lengths in units of the sampling radius.
EDGE_FEATURES = (
    "distance",
    "log_distance",
    "receiver_normal_dot_direction",
    "sender_normal_dot_direction",
    "normal_dot_normal",
    "is_cone_edge",
)


@dataclass(frozen=True)
class GraphSpec:
    """How the sample graph is built; stored in the model card, identical at serving."""

    target_samples: int = 1024
    knn: int = 12
    cone_neighbours: int = 6
    #: cos of the half opening of the inward cone (0.5: 60 degrees, the ShDF's cone).
    cone_cos: float = 0.5
    #: Sample-to-face neighbours used when mapping predictions back to faces.
    interpolation_neighbours: int = 4
    #: Rays of the ShDF cone cast from each sample for ``RAY_NODE_FEATURES``; 0 = the
    #: paper's ray-free network.
    ray_count: int = 0

    @property
    def node_features(self) -> tuple[str, ...]:
        """Names of the node feature columns this spec's network reads."""
        return NODE_FEATURES + (RAY_NODE_FEATURES if self.ray_count else ())

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> GraphSpec:
        return cls(**{k: data[k] for k in cls.__dataclass_fields__ if k in data})


@dataclass(frozen=True)
class SampleGraph:
    """Samples of a surface and the directed graph over them.

    Attributes:
        positions: (N, 3) sample positions (mesh units).
        normals: (N, 3) unit normals of the sampled faces.
        face_ids: (N,) face each sample lies on.
        density: (N,) surface area near the sample / area of a flat disk (see module doc).
        senders, receivers: (E,) int64 edge endpoints (messages go sender -> receiver).
        node_features: (N, len(NODE_FEATURES)) float32.
        edge_features: (E, len(EDGE_FEATURES)) float32.
        radius: Poisson radius, the length unit of features and targets.
        vertex_samples: (V, k) nearest samples of each mesh vertex
            (k = interpolation_neighbours), for mapping predictions back.
        vertex_sample_distance: (V, k) their distances.
        vertex_normals: (V, 3) unit area-weighted vertex normals (zero if undefined).
    """

    positions: NDArray[np.float64]
    normals: NDArray[np.float64]
    face_ids: NDArray[np.int64]
    density: NDArray[np.float64]
    senders: NDArray[np.int64]
    receivers: NDArray[np.int64]
    node_features: NDArray[np.float32]
    edge_features: NDArray[np.float32]
    radius: float
    vertex_samples: NDArray[np.int64]
    vertex_sample_distance: NDArray[np.float64]
    vertex_normals: NDArray[np.float64]

    @property
    def sample_count(self) -> int:
        return int(len(self.positions))


def poisson_radius(total_area: float, target_samples: int) -> float:
    """The fixed Poisson-disk radius for a surface of ``total_area``."""
    return math.sqrt(RADIUS_AREA_FACTOR * total_area / max(1, target_samples))


def sample_surface(
    vertices: NDArray, faces: NDArray, areas: NDArray, count: int, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """``count`` area-uniform random points on the triangles and their face ids.

    The faces are looked up and the points made in the order of the random keys
    (face order: cache-friendly on large meshes), then put back in draw order.
    """
    cumulative = np.cumsum(areas)
    keys = rng.random(count) * cumulative[-1]
    u, v = rng.random(count), rng.random(count)
    order = np.argsort(keys, kind="stable")
    face_ids = np.empty(count, dtype=np.int64)
    face_ids[order] = np.searchsorted(cumulative, keys[order], side="right")
    np.minimum(face_ids, len(faces) - 1, out=face_ids)
    points = np.empty((count, 3))
    _points_on_faces(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
        face_ids,
        u,
        v,
        order,
        points,
    )
    return points, face_ids


@kernel
def _points_on_faces(vertices, faces, face_ids, u, v, order, out) -> None:  # noqa: ANN001
    """Point ``i`` at barycentric (u, v) of its face (folded into the triangle when
    u + v > 1), made in the given ``order``."""
    for i in order:
        a, b = u[i], v[i]
        if a + b > 1.0:
            a, b = 1.0 - a, 1.0 - b
        face = faces[face_ids[i]]
        for axis in range(3):
            first = vertices[face[0], axis]
            out[i, axis] = (
                first
                + a * (vertices[face[1], axis] - first)
                + b * (vertices[face[2], axis] - first)
            )


#: Above this many grid cells along an axis, the dart thrower's grid coordinates could
#: lose precision: the conflict-pair computation (same result) is used instead.
_MAX_GRID_CELLS = 2**40


def greedy_disk_selection(points: NDArray, radius: float) -> NDArray[np.int64]:
    """Indices of the points a sequential dart thrower keeps (in index order) for ``radius``.

    Point i is kept iff no kept point j < i lies within ``radius``. The kept points
    sit in a grid of cells of side ``radius / sqrt(3)`` (at most one kept point per
    cell, up to rounding), so each point checks the few kept points of the 5^3 cells
    around it: linear time and memory however densely the candidates pile up (a
    surface repeated in place puts thousands of candidates within one radius).
    """
    points = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    cell_size = radius / math.sqrt(3.0)
    span = float((points.max(axis=0) - points.min(axis=0)).max())
    if not cell_size > 0 or not span / cell_size < _MAX_GRID_CELLS:
        return _conflict_pair_selection(points, radius)
    return _dart_throw(points, radius, cell_size)


def _conflict_pair_selection(points: NDArray, radius: float) -> NDArray[np.int64]:
    """``greedy_disk_selection`` in vectorised rounds over all conflict pairs (memory grows
    with the pairs: only for grids too fine for integer cell coordinates)."""
    n = len(points)
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return np.arange(n, dtype=np.int64)
    low, high = pairs.min(axis=1), pairs.max(axis=1)
    state = np.zeros(n, dtype=np.int8)  # 0 undecided, 1 kept, -1 rejected
    while len(low):
        blocked = np.zeros(n, dtype=bool)
        blocked[high] = True  # has an undecided (or kept) earlier neighbour
        newly_kept = (state == 0) & ~blocked
        state[newly_kept] = 1
        state[high[newly_kept[low]]] = -1
        alive = (state[low] == 0) & (state[high] == 0)
        low, high = low[alive], high[alive]
    state[state == 0] = 1
    return np.flatnonzero(state == 1).astype(np.int64)


@kernel
def _dart_throw(points, radius, cell_size):  # pragma: no cover - numba
    """Sequential dart throwing over a hash grid; kept points chained per cell."""
    n = points.shape[0]
    squared_radius = radius * radius
    origin = np.empty(3)
    for axis in range(3):
        origin[axis] = points[:, axis].min()
    capacity = 16
    while capacity < 2 * n:
        capacity *= 2
    mask = capacity - 1
    table_cell = np.empty((capacity, 3), dtype=np.int64)
    table_head = np.full(capacity, -1, dtype=np.int64)  # -1: empty slot
    chained = np.full(n, -1, dtype=np.int64)  # next kept point in the same cell
    kept = np.empty(n, dtype=np.int64)
    kept_count = 0
    cell = np.empty(3, dtype=np.int64)
    for i in range(n):
        for axis in range(3):
            cell[axis] = np.int64(math.floor((points[i, axis] - origin[axis]) / cell_size))
        conflict = False
        for dx in range(-2, 3):
            for dy in range(-2, 3):
                for dz in range(-2, 3):
                    x, y, z = cell[0] + dx, cell[1] + dy, cell[2] + dz
                    slot = _cell_hash(x, y, z) & mask
                    while table_head[slot] >= 0:
                        if (
                            table_cell[slot, 0] == x
                            and table_cell[slot, 1] == y
                            and table_cell[slot, 2] == z
                        ):
                            j = table_head[slot]
                            while j >= 0:
                                ex = points[i, 0] - points[j, 0]
                                ey = points[i, 1] - points[j, 1]
                                ez = points[i, 2] - points[j, 2]
                                if ex * ex + ey * ey + ez * ez <= squared_radius:
                                    conflict = True
                                    break
                                j = chained[j]
                            break
                        slot = (slot + 1) & mask
                    if conflict:
                        break
                if conflict:
                    break
            if conflict:
                break
        if conflict:
            continue
        kept[kept_count] = i
        kept_count += 1
        slot = _cell_hash(cell[0], cell[1], cell[2]) & mask
        while table_head[slot] >= 0 and not (
            table_cell[slot, 0] == cell[0]
            and table_cell[slot, 1] == cell[1]
            and table_cell[slot, 2] == cell[2]
        ):
            slot = (slot + 1) & mask
        if table_head[slot] >= 0:
            chained[i] = table_head[slot]
        table_cell[slot, 0], table_cell[slot, 1], table_cell[slot, 2] = cell[0], cell[1], cell[2]
        table_head[slot] = i
    return kept[:kept_count].copy()


@kernel(inline=True)
def _cell_hash(x, y, z):  # pragma: no cover - numba
    """A mixed 63-bit hash of integer cell coordinates."""
    key = np.uint64(x) * np.uint64(0x9E3779B97F4A7C15)
    key ^= np.uint64(y) * np.uint64(0xC2B2AE3D27D4EB4F) + (key >> np.uint64(29))
    key ^= np.uint64(z) * np.uint64(0x165667B19E3779F9) + (key >> np.uint64(31))
    key ^= key >> np.uint64(32)
    return np.int64(key >> np.uint64(1))


def edge_feature_array(
    positions: NDArray,
    normals: NDArray,
    senders: NDArray,
    receivers: NDArray,
    is_cone: NDArray,
    radius: float,
) -> NDArray[np.float32]:
    """Invariant edge features (see ``EDGE_FEATURES``)."""
    offset = positions[senders] - positions[receivers]
    distance = np.linalg.norm(offset, axis=1)
    direction = offset / np.maximum(distance, 1e-30)[:, None]
    scaled = distance / radius
    return np.stack(
        [
            scaled,
            np.log(scaled + 1e-3),
            np.einsum("ij,ij->i", normals[receivers], direction),
            np.einsum("ij,ij->i", normals[senders], direction),
            np.einsum("ij,ij->i", normals[receivers], normals[senders]),
            is_cone.astype(np.float64),
        ],
        axis=1,
    ).astype(np.float32)


def node_feature_array(
    density: NDArray, edge_features: NDArray, receivers: NDArray
) -> NDArray[np.float32]:
    """Node features (see ``NODE_FEATURES``) from the density and the edge features."""
    # Rounded to float32 first, as training reads it back from float32 graph files;
    # relative to the median, so that a mesh stored twice (duplicated shells) looks
    # like the mesh stored once, while thin walls still stand out.
    density = np.asarray(density, dtype=np.float32).astype(np.float64)
    if len(density):  # lower median: an element, so that normalising twice changes nothing
        median = float(np.partition(density, (len(density) - 1) // 2)[(len(density) - 1) // 2])
        density = (density / max(median, 1e-6)).astype(np.float32).astype(np.float64)
    n = len(density)
    cone = edge_features[:, EDGE_FEATURES.index("is_cone_edge")] > 0.5
    to = np.asarray(receivers)[cone]
    distance = edge_features[cone, EDGE_FEATURES.index("distance")].astype(np.float64)
    facing = -edge_features[cone, EDGE_FEATURES.index("receiver_normal_dot_direction")]
    depth = distance * facing.astype(np.float64)
    count = np.bincount(to, minlength=n).astype(np.float64)
    safe = np.maximum(count, 1.0)
    min_distance = np.full(n, np.inf)
    np.minimum.at(min_distance, to, distance)
    has = count > 0
    mean_distance = np.bincount(to, distance, minlength=n) / safe
    mean_depth = np.bincount(to, depth, minlength=n) / safe

    def log_or_zero(values: NDArray) -> NDArray:
        return np.where(has, np.log(np.where(has, values, 1.0) + 1e-3), 0.0)

    return np.stack(
        [
            density,
            np.log(density + 1e-3),
            has.astype(np.float64),
            count,
            log_or_zero(min_distance),
            log_or_zero(mean_distance),
            log_or_zero(mean_depth),
        ],
        axis=1,
    ).astype(np.float32)


def ray_feature_array(
    diameter: NDArray, spread: NDArray, hit_fraction: NDArray
) -> NDArray[np.float32]:
    """``RAY_NODE_FEATURES`` from each sample's ray cone: robust mean ``diameter`` in
    Poisson radii (NaN without a valid hit), relative spread and hit fraction."""
    diameter = np.asarray(diameter, dtype=np.float64)
    has = np.isfinite(diameter) & (diameter > 0)
    log_diameter = np.log(np.where(has, diameter, 1.0))
    return np.stack(
        [has.astype(np.float64), np.where(has, log_diameter, 0.0), spread, hit_fraction], axis=1
    ).astype(np.float32)


def vertex_normal_sums(
    vertex_count: int, faces: NDArray, normals: NDArray, areas: NDArray
) -> NDArray[np.float64]:
    """Area-weighted sums of the normals of the faces around each vertex (not unit)."""
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if len(faces) and (faces.min() < 0 or faces.max() >= vertex_count):
        raise IndexError("face vertex index out of range")
    return _vertex_normal_sums(
        vertex_count,
        faces,
        np.ascontiguousarray(normals, dtype=np.float64),
        np.ascontiguousarray(areas, dtype=np.float64),
    )


@kernel
def _vertex_normal_sums(vertex_count, faces, normals, areas):  # noqa: ANN001, ANN202
    out = np.zeros((vertex_count, 3))
    for face in range(len(faces)):
        for axis in range(3):
            weighted = normals[face, axis] * areas[face]
            for corner in range(3):
                out[faces[face, corner], axis] += weighted
    return out


def unit_rows(vectors: NDArray) -> NDArray[np.float64]:
    """Rows scaled to unit length; zero rows stay zero."""
    length = np.linalg.norm(vectors, axis=1, keepdims=True)
    return np.divide(vectors, length, out=np.zeros_like(vectors), where=length > 0)


def sample_surface_points(
    vertices: NDArray,
    faces: NDArray,
    spec: GraphSpec | None = None,
    *,
    seed: int = 0,
    normals: NDArray | None = None,
    areas: NDArray | None = None,
    workers: int = 2,
    map_vertices: bool = True,
    normal_sums: NDArray | None = None,
    density: bool = False,
) -> SampleGraph:
    """Poisson-disk samples of a triangle mesh, without edges (``senders`` etc. empty).

    Each sample's normal takes the side of the faces around it (flipped faces);
    ``map_vertices`` finds each vertex's nearest samples (for ``samples_to_faces``);
    ``density`` computes the density (else zeros).
    """
    spec = spec or GraphSpec()
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if normals is None or areas is None:
        normals, areas = face_normals(vertices, faces)
    if normal_sums is None:
        normal_sums = vertex_normal_sums(len(vertices), faces, normals, areas)
    total_area = float(areas.sum())
    if not total_area > 0 or not np.isfinite(total_area):
        raise InvalidGeometryError("the mesh has no surface area: every triangle is degenerate")
    rng = np.random.default_rng(seed)
    radius = poisson_radius(total_area, spec.target_samples)
    candidates, candidate_faces = sample_surface(
        vertices, faces, areas, CANDIDATES_PER_SAMPLE * spec.target_samples, rng
    )
    kept = greedy_disk_selection(candidates, radius)
    positions, face_ids = candidates[kept], candidate_faces[kept]
    # A sample on a face whose winding disagrees with its surroundings takes the
    # surroundings' side (flipped faces); on clean meshes this changes nothing.
    sample_normals = normals[face_ids]
    around = normal_sums[faces[face_ids]].sum(axis=1) - 3.0 * (
        normals[face_ids] * areas[face_ids, None]
    )  # the faces around the sample's face, without it
    flip = np.einsum("ij,ij->i", sample_normals, around) < 0
    sample_normals[flip] *= -1.0

    sample_density = np.zeros(len(positions))
    if density:
        near_count = cKDTree(candidates).query_ball_point(
            positions, DENSITY_RADIUS * radius, return_length=True, workers=workers
        )
        flat_count = len(candidates) / total_area * math.pi * (DENSITY_RADIUS * radius) ** 2
        sample_density = np.asarray(near_count, dtype=np.float64) / flat_count
    no_edges = np.zeros(0, np.int64)
    samples = SampleGraph(
        positions=positions,
        normals=sample_normals,
        face_ids=face_ids,
        density=sample_density,
        senders=no_edges,
        receivers=no_edges,
        node_features=np.zeros((len(positions), 0), np.float32),
        edge_features=np.zeros((0, len(EDGE_FEATURES)), np.float32),
        radius=radius,
        vertex_samples=np.zeros((0, spec.interpolation_neighbours), np.int64),
        vertex_sample_distance=np.zeros((0, spec.interpolation_neighbours)),
        vertex_normals=np.zeros((0, 3)),
    )
    if map_vertices:
        samples = with_vertex_map(samples, vertices, normal_sums, spec, workers)
    return samples


def with_vertex_map(
    samples: SampleGraph,
    vertices: NDArray,
    normal_sums: NDArray,
    spec: GraphSpec,
    workers: int = 2,
) -> SampleGraph:
    """``samples`` with each mesh vertex's ``spec.interpolation_neighbours`` nearest
    samples and unit normal (``normal_sums``: ``vertex_normal_sums``), which
    ``samples_to_faces`` reads."""
    vertex_samples, vertex_distance = nearest_samples(
        samples.positions, vertices, spec.interpolation_neighbours, samples.radius, workers
    )
    return replace(
        samples,
        vertex_samples=vertex_samples,
        vertex_sample_distance=vertex_distance,
        vertex_normals=unit_rows(normal_sums),
    )


def build_sample_graph(
    vertices: NDArray,
    faces: NDArray,
    spec: GraphSpec | None = None,
    *,
    seed: int = 0,
    normals: NDArray | None = None,
    areas: NDArray | None = None,
    workers: int = 2,
    map_vertices: bool = True,
    normal_sums: NDArray | None = None,
) -> SampleGraph:
    """Samples (``sample_surface_points``), density, edges and features of a triangle
    mesh (full resolution); with ``spec.ray_count``, the ray cone of every sample
    (``RAY_NODE_FEATURES``).

    ``map_vertices=False`` skips each vertex's nearest samples (``vertex_samples``
    and ``vertex_normals`` are then empty): for sample sets whose values reach the faces
    through another set.
    ``normal_sums`` (``vertex_normal_sums``) may be passed when several sets share a mesh.
    """
    spec = spec or GraphSpec()
    samples = sample_surface_points(
        vertices,
        faces,
        spec,
        seed=seed,
        normals=normals,
        areas=areas,
        workers=workers,
        map_vertices=map_vertices,
        normal_sums=normal_sums,
        density=True,
    )
    positions, sample_normals, radius = samples.positions, samples.normals, samples.radius
    n = len(positions)
    # Edges: k nearest samples + the other side of the volume.
    k_near = min(spec.knn, n - 1)
    if k_near > 0:
        _, neighbours = cKDTree(positions).query(positions, k=k_near + 1, workers=workers)
        knn_senders = neighbours[:, 1:].reshape(-1).astype(np.int64)
        knn_receivers = np.repeat(np.arange(n, dtype=np.int64), k_near)
    else:
        knn_senders = knn_receivers = np.zeros(0, np.int64)
    cone_senders, cone_receivers = cone_neighbours(
        positions, sample_normals, spec.cone_neighbours, spec.cone_cos, radius, workers
    )
    senders = np.concatenate([knn_senders, cone_senders])
    receivers = np.concatenate([knn_receivers, cone_receivers])
    is_cone = np.concatenate([np.zeros(len(knn_senders), bool), np.ones(len(cone_senders), bool)])
    edge_features = edge_feature_array(
        positions, sample_normals, senders, receivers, is_cone, radius
    )
    node_features = node_feature_array(samples.density, edge_features, receivers)
    if spec.ray_count:
        from neural_shdf.shdf.exact import raw_shdf_at_points

        diameter, spread, hits = raw_shdf_at_points(
            vertices,
            faces,
            positions,
            sample_normals,
            samples.face_ids,
            ray_count=spec.ray_count,
            threads=workers,
        )
        rays = ray_feature_array(diameter / radius, spread, hits)
        node_features = np.concatenate([node_features, rays], axis=1)
    return replace(
        samples,
        senders=senders,
        receivers=receivers,
        node_features=node_features,
        edge_features=edge_features,
    )


def nearest_samples(
    positions: NDArray, points: NDArray, count: int, radius: float, workers: int = 2
) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """(P, k) indices of the ``count`` samples (``positions``, Poisson ``radius``)
    nearest to each point (k at most the sample count), nearest first, and their
    distances (``search.nearest_points``)."""
    return nearest_points(positions, points, max(1, count), radius, workers)


def interpolate_samples(
    sample_values: NDArray,
    sample_normals: NDArray,
    neighbours: NDArray,
    distances: NDArray,
    point_normals: NDArray,
    radius: float,
) -> NDArray[np.float32]:
    """Values at points from their nearest samples (``nearest_samples``).

    Inverse-distance weights, times the agreement of the sample's normal with the
    point's: the other side of a thin wall or a facing part does not leak in; a
    point with no agreeing sample takes its nearest sample's value. float32.
    """
    out = np.empty(len(neighbours), dtype=np.float32)
    if len(out):
        _interpolate(
            np.ascontiguousarray(sample_values, dtype=np.float32),
            np.ascontiguousarray(sample_normals, dtype=np.float32),
            np.ascontiguousarray(neighbours, dtype=np.int64),
            np.ascontiguousarray(distances, dtype=np.float32),
            np.ascontiguousarray(point_normals, dtype=np.float32),
            np.float32(0.05 * radius),
            out,
        )
    return out


@kernel
def _interpolate(values, sample_normals, neighbours, distances, normals, offset, out) -> None:  # noqa: ANN001
    """``interpolate_samples`` into ``out``, in float32 throughout."""
    zero = np.float32(0.0)
    for point in range(len(out)):
        total = zero
        mixed = zero
        for column in range(neighbours.shape[1]):  # one neighbour rank at a time
            sample = neighbours[point, column]
            agree = (
                sample_normals[sample, 0] * normals[point, 0]
                + sample_normals[sample, 1] * normals[point, 1]
                + sample_normals[sample, 2] * normals[point, 2]
            )
            weight = max(agree, zero) / (distances[point, column] + offset)
            total += weight
            mixed += weight * values[sample]
        out[point] = mixed / total if total > 1e-12 else values[neighbours[point, 0]]


def resample(
    sample_values: NDArray, source: SampleGraph, target: SampleGraph, neighbours: int
) -> NDArray[np.float64]:
    """Values given at the samples of ``source``, interpolated at the samples of
    ``target`` (another sample set of the same surface) from their ``neighbours``
    nearest source samples, as ``interpolate_samples``."""
    index, distances = nearest_samples(
        source.positions, target.positions, neighbours, source.radius
    )
    return interpolate_samples(
        sample_values, source.normals, index, distances, target.normals, source.radius
    ).astype(np.float64)


def samples_to_faces(
    sample_values: NDArray, graph: SampleGraph, faces: NDArray
) -> NDArray[np.float64]:
    """Per-face values from per-sample values: each vertex interpolates its nearest
    samples (``interpolate_samples``), a face takes the mean of its three vertices."""
    per_vertex = interpolate_samples(
        sample_values,
        graph.normals,
        graph.vertex_samples,
        graph.vertex_sample_distance,
        graph.vertex_normals,
        graph.radius,
    )
    out = np.empty(len(faces))
    _face_means(per_vertex, np.ascontiguousarray(faces, dtype=np.int64), out)
    return out


@kernel
def _face_means(per_vertex, faces, out) -> None:  # noqa: ANN001
    """Mean of each face's three vertex values (summed in float32, as the vertex values)."""
    for face in range(len(faces)):
        total = per_vertex[faces[face, 0]] + per_vertex[faces[face, 1]] + per_vertex[faces[face, 2]]
        out[face] = np.float64(total) / 3.0


def sample_targets(
    face_values: NDArray, areas: NDArray, centroids: NDArray, graph: SampleGraph
) -> NDArray[np.float64]:
    """Training target per sample: area-weighted mean of the face values (NaN ignored)
    over the faces whose centroid is nearest to it, else the value of the sample's
    own face; NaN where neither has a value."""
    values = np.asarray(face_values, dtype=np.float64)
    ok = np.isfinite(values)
    nearest = cKDTree(graph.positions).query(centroids, workers=1)[1]
    n = graph.sample_count
    total = np.bincount(nearest[ok], weights=areas[ok] * values[ok], minlength=n)
    weight = np.bincount(nearest[ok], weights=areas[ok], minlength=n)
    own = values[graph.face_ids]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(weight > 0, total / np.where(weight > 0, weight, 1.0), own)
