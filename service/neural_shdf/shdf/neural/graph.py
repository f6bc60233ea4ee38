"""The neural ShDF's input graph: Poisson-disk samples of the surface and their edges.

Shared by training (``model_export``) and serving (``neural_shdf.shdf.neural``):
both call :func:`build_sample_graph`, so the network always sees the same features.
Numpy, scipy and numba only (the service never imports torch).

* Samples: Poisson-disk samples of the full-resolution surface
  (``shdf.sampling.sample_surface_points``, shared with the ``sampled`` ShDF): about
  ``target_samples`` of them whatever the tessellation, deterministic for a seed.
* Density ``rho``: full-resolution surface area within ``sampling.DENSITY_RADIUS`` radii
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

from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from neural_shdf.shdf.exact import raw_shdf_at_points
from neural_shdf.shdf.sampling import SurfaceSamples, sample_surface_points
from neural_shdf.shdf.search import cone_neighbours

#: Bump when the meaning or order of features changes (checked against the model card).
FEATURE_SPEC_VERSION = 5
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

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> GraphSpec:
        return cls(**{k: data[k] for k in cls.__dataclass_fields__ if k in data})


@dataclass(frozen=True)
class SampleGraph(SurfaceSamples):
    """Samples of a surface (``SurfaceSamples``: positions, normals, faces, density, the
    Poisson radius, the length unit of features and targets, and each vertex's nearest
    samples) and the directed graph over them.

    Attributes:
        senders, receivers: (E,) int64 edge endpoints (messages go sender -> receiver).
        node_features: (N, len(NODE_FEATURES)) float32.
        edge_features: (E, len(EDGE_FEATURES)) float32.
    """

    senders: NDArray[np.int64]
    receivers: NDArray[np.int64]
    node_features: NDArray[np.float32]
    edge_features: NDArray[np.float32]


def edge_feature_array(
    positions: NDArray[Any],
    normals: NDArray[Any],
    senders: NDArray[Any],
    receivers: NDArray[Any],
    is_cone: NDArray[Any],
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
    density: NDArray[Any], edge_features: NDArray[Any], receivers: NDArray[Any]
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

    def log_or_zero(values: NDArray[Any]) -> NDArray[Any]:
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
    diameter: NDArray[Any], spread: NDArray[Any], hit_fraction: NDArray[Any]
) -> NDArray[np.float32]:
    """``RAY_NODE_FEATURES`` from each sample's ray cone: robust mean ``diameter`` in
    Poisson radii (NaN without a valid hit), relative spread and hit fraction."""
    diameter = np.asarray(diameter, dtype=np.float64)
    has = np.isfinite(diameter) & (diameter > 0)
    log_diameter = np.log(np.where(has, diameter, 1.0))
    return np.stack(
        [has.astype(np.float64), np.where(has, log_diameter, 0.0), spread, hit_fraction], axis=1
    ).astype(np.float32)


def build_sample_graph(
    vertices: NDArray[Any],
    faces: NDArray[Any],
    spec: GraphSpec | None = None,
    *,
    seed: int = 0,
    normals: NDArray[Any] | None = None,
    areas: NDArray[Any] | None = None,
    workers: int = 2,
    map_vertices: bool = True,
    normal_sums: NDArray[Any] | None = None,
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
        spec.target_samples,
        interpolation_neighbours=spec.interpolation_neighbours,
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
    return SampleGraph(
        **{field.name: getattr(samples, field.name) for field in fields(SurfaceSamples)},
        senders=senders,
        receivers=receivers,
        node_features=node_features,
        edge_features=edge_features,
    )


def sample_targets(
    face_values: NDArray[Any], areas: NDArray[Any], centroids: NDArray[Any], graph: SampleGraph
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
