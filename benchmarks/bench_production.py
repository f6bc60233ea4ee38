"""Production-like variants of psb-dev meshes against the published meshes, side by side.

Each variant keeps the published faces' identity (a map back to the file's faces), so
the humans' segmentations still score it. Per variant and model: the default
``segment`` path (``compute_shdf`` with ``auto``, then ``segment``
with default ``SegmentParams``), scored with the benchmark's metrics (1-RI and CD,
averaged over the humans) next to the published mesh's own segmentation scored on
the same faces. Variants:

* ``reversed``: every face's winding reversed (an inside-out export);
* ``mixed30``: 30% of the faces reversed at random (inconsistent winding);
* ``holes``: 4% of the faces removed in 12 holes (scored on the kept faces);
* ``nobase``: the lowest 6% of the faces (by centroid height, y) removed
  (``--nobase-share`` removes another share);
* ``shuffled``: faces and vertices in random order;
* ``transform``: a random rotation, scale x1000 and a shift far from the origin;
* ``rotated``: a random rotation only (about the bounding-box centre);
* ``soup``: every triangle with its own three vertices (an STL), order shuffled;
* ``seams``: vertices split along the borders of 30 patches (a GLB whose UV seams cut the
  surface: same geometry, no shared vertex across a seam);
* ``doublesided``: every face twice, the copy reversed (a double-sided card export);
* ``shells``: 4 patches made separate open shells, each moved by 1% of the diagonal in a
  random direction, so they overlap and gap (a kitbashed or CAD assembly);
  ``--shells-move`` moves them by another share of the diagonal;
* ``subdivided``: Loop-subdivided until it has at least 400k faces (0.4-1.6M: the same
  shape at production resolution); each published face takes the label most of its
  children have (ties: the smallest). Subdivided meshes are cached (``--cache-dir``);
* ``midpoint``: the same number of midpoint subdivisions (the same piecewise-flat
  surface, sharp creases kept), labels mapped back the same way;
* ``decimated``: quadric decimation (``fast_simplification``) to about a quarter of the
  faces (the same shape at a lower resolution);
* ``remeshed``: one Loop subdivision pass, then quadric decimation back to about the
  published face count (another triangulation of the same shape, no vertex kept);
* ``refined``: a region holding a fifth of the area split 1-to-n² (``geometry.split_region``,
  no T-junction) for about 100k faces in all, the rest as published (a sculpted or
  densely scanned detail on a coarser body); each published face takes the label most of
  its pieces have.

``decimated`` and ``remeshed`` faces have no published parent, so labels map the other
way: every published face takes the label of the variant face at the closest point to its
centroid, and all published faces are scored. For these two, ``--verbose`` and ``--json``
also give how far the surfaces lie apart (published vertices to the variant surface and
back, as shares of the bounding diagonal).

Default models: the held-out fourth of each category (ids 4, 24, ..., 384), never used
for tuning. Run it on two checkouts to compare code (``PYTHONPATH=.../service``).

``--bench-dir ../shared/data/human-seg`` runs the same variants on the human body
segmentation set instead (1,500-face meshes from several scanned and animated sources,
one labelling of 8 body parts per mesh, which scores both segmentations; never used to
tune the segmentation): a second collection of meshes, none of them looked at while
tuning. ``--every K`` takes every K-th of its meshes (sorted by name; many are frames of
one animation), ``--models`` their indices in that order.

``--corpus`` measures something else, on meshes with no labels: whether the parts depend
on how a file lists the same surface. On the training corpus (151 misc + 414 shapedb
meshes: scans, web and CAD models, most of them open, non-manifold or in many shells;
unpacked once to ``--corpus-cache`` by ``model_export.data.unpack_archives``), every
``--every``-th mesh of 200-150,000 faces is segmented as given and as each variant whose
faces map one to one onto the file's (``reversed``, ``mixed30``, ``shuffled``, ``soup``,
``seams``, ``rotated``, ``transform``, ``doublesided``); printed per variant, the mean
area-unweighted 1-RI between the two segmentations (0: the same parts) and how many meshes
differ at all or by more than 0.05.

``--shdf-cache DIR`` keeps each mesh's default ShDF (by the mesh's content and a hash of
the package outside ``neural_shdf.segment``): after a change of the segmentation alone, a
rerun skips every ShDF (the 57 tuning models' eight re-tessellated variants: 861 s
computing them, beside a test run, 480 s from the cache, the same scores; 0.8 GB).

    python benchmarks/bench_production.py [--bench-dir DIR] [--models 4 24 ...]
        [--limit N] [--every K] [--variants reversed holes ...] [--shells-move 0.01]
        [--nobase-share 0.06] [--json out.json]
        [--shdf-fidelity] [--shdf-cache DIR]
    PYTHONPATH=service:. python benchmarks/bench_production.py --corpus [--every 4]
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import json
import os
import sys
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

import neural_shdf
from neural_shdf.evaluate.benchmark import list_models, load_benchmark_mesh
from neural_shdf.evaluate.scores import cut_distance_field, cut_graph, score_against_humans
from neural_shdf.geometry import (
    adjacency_lists,
    build_face_graph,
    midpoint_subdivide,
    split_region,
    weld_faces,
)
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.segment import SegmentParams

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_BENCH = REPO_ROOT / ".." / "shared" / "data" / "psb-dev"
DEFAULT_CACHE = Path("/tmp/neural-shdf-bench-production")
#: ``subdivided``: Loop subdivisions until the mesh has at least this many faces.
SUBDIVIDED_FACES = 400_000
#: Where ``subdivided`` keeps its meshes (set from ``--cache-dir``).
CACHE_DIR = DEFAULT_CACHE
#: Where the default ShDF of each mesh is kept between runs (``--shdf-cache``; None: not).
SHDF_CACHE: Path | None = None


@functools.cache
def shdf_fingerprint() -> str:
    """A hash of the package's code and models outside ``neural_shdf.segment``: what the
    default ShDF depends on. A change of the segmentation alone keeps it."""
    package = Path(neural_shdf.__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*")):
        relative = path.relative_to(package)
        if relative.parts[0] == "segment" or path.suffix not in {".py", ".onnx", ".json"}:
            continue
        digest.update(str(relative).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def default_shdf(mesh: TriangleMesh) -> NDArray[np.float64]:
    """The default ShDF of ``mesh``, kept in ``SHDF_CACHE`` by the mesh's content and the
    ShDF code's fingerprint when a cache is set: a segmentation change re-scores every
    variant without computing their ShDF again."""
    if SHDF_CACHE is None:
        return compute_shdf(mesh).values
    path = SHDF_CACHE / shdf_fingerprint() / f"{mesh.content_hash()[:24]}.npy"
    if path.is_file():
        values = np.load(path)
        if len(values) == mesh.face_count:
            return values
    values = compute_shdf(mesh).values
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(f".{os.getpid()}.tmp.npy")
    np.save(temporary, values)
    temporary.replace(path)
    return values


class BenchCase(NamedTuple):
    """One mesh to vary: its id (the seed of its variants), the mesh, its reference
    segmentations (one label per face each)."""

    model_id: int
    mesh: TriangleMesh
    humans: list[NDArray]


def psb_cases(bench_dir: Path, ids: list[int] | None) -> tuple[list[int], Callable]:
    """The psb-dev model ids to run (default: the held-out ones) and a loader per id."""
    models = {m.model_id: m for m in list_models(bench_dir)}
    ids = ids or [model_id for model_id in models if is_held_out(model_id)]
    missing = sorted(set(ids) - set(models))
    if missing:
        raise SystemExit(f"models not in {bench_dir}: {missing}")

    def load(model_id: int) -> BenchCase:
        model = models[model_id]
        humans = [np.asarray(h) for h in model.human_segmentations()]
        return BenchCase(model_id, load_benchmark_mesh(model.mesh_path), humans)

    return ids, load


def human_seg_cases(
    data_dir: Path, ids: list[int] | None, every: int
) -> tuple[list[int], Callable]:
    """Indices of the human-seg meshes to run (sorted by name; every ``every``-th, or
    ``ids``) and a loader per index: the mesh and its one labelling."""
    paths = sorted((data_dir / "train").glob("*.obj"))
    ids = ids or list(range(0, len(paths), every))
    if max(ids, default=0) >= len(paths):
        raise SystemExit(f"{data_dir} has {len(paths)} meshes")

    def load(index: int) -> BenchCase:
        path = paths[index]
        mesh = load_mesh(path)
        labels = np.loadtxt(data_dir / "face_labels" / f"{path.stem}.txt", dtype=np.int64)
        if len(labels) != mesh.face_count:
            raise SystemExit(f"{path.name}: {mesh.face_count} faces, {len(labels)} labels")
        return BenchCase(index, mesh, [labels])

    return ids, load


def is_held_out(model_id: int) -> bool:
    """The 4th psb-dev model of each category, never used for tuning (as bench_psb.py)."""
    return (model_id - 1) % 20 == 3


class Variant:
    """A changed mesh, and for each of its faces the published face it is (``origin``),
    or ``None`` for a re-triangulated surface whose faces are no published face."""

    def __init__(self, vertices: NDArray, faces: NDArray, origin: NDArray | None) -> None:
        self.mesh = TriangleMesh(vertices, faces)
        self.origin = None if origin is None else np.asarray(origin, dtype=np.int64)


def reversed_faces(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    return Variant(v, f[:, ::-1], np.arange(len(f)))


def mixed_winding(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    flip = rng.random(len(f)) < 0.3
    faces = f.copy()
    faces[flip] = f[flip][:, ::-1]
    return Variant(v, faces, np.arange(len(f)))


def kept_variant(v: NDArray, f: NDArray, kept: NDArray) -> Variant:
    """The faces in ``kept`` (sorted), vertices unchanged."""
    kept = np.sort(kept)
    return Variant(v, f[kept], kept)


def holes(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    """12 holes grown breadth-first from random faces, 4% of the faces in all."""
    graph = build_face_graph(v, weld_faces(v, f))
    indptr, neighbours = adjacency_lists(graph.pairs, len(f))
    removed = np.zeros(len(f), dtype=bool)
    per_hole = max(1, int(0.04 * len(f)) // 12)
    for seed in rng.choice(len(f), size=12, replace=False):
        queue, taken = deque([int(seed)]), 0
        while queue and taken < per_hole:
            face = queue.popleft()
            if removed[face]:
                continue
            removed[face] = True
            taken += 1
            queue.extend(int(n) for n in neighbours[indptr[face] : indptr[face + 1]])
    return kept_variant(v, f, np.flatnonzero(~removed))


#: Which share of the faces ``nobase`` removes, lowest first (``--nobase-share``).
NOBASE_SHARE = 0.06


def no_base(
    v: NDArray, f: NDArray, rng: np.random.Generator, share: float = NOBASE_SHARE
) -> Variant:
    height = v[f].mean(axis=1)[:, 1]
    return kept_variant(v, f, np.argsort(height, kind="stable")[int(share * len(f)) :])


def shuffled(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    face_order = rng.permutation(len(f))
    vertex_order = rng.permutation(len(v))
    new_index = np.empty(len(v), dtype=np.int64)
    new_index[vertex_order] = np.arange(len(v))
    return Variant(v[vertex_order], new_index[f[face_order]], face_order)


def random_rotation(rng: np.random.Generator) -> NDArray:
    """A uniformly random proper rotation (3, 3)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    rotation = q * np.sign(np.diag(r))
    if np.linalg.det(rotation) < 0:
        rotation[:, 0] *= -1
    return rotation


def transformed(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    rotation = random_rotation(rng)
    shift = rng.uniform(-1, 1, size=3) * 1e4
    return Variant(1000.0 * v @ rotation.T + shift, f, np.arange(len(f)))


def rotated(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    return Variant((v - centre) @ random_rotation(rng).T + centre, f, np.arange(len(f)))


def soup(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    order = rng.permutation(len(f))
    return Variant(v[f[order]].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3), order)


def patches(v: NDArray, f: NDArray, count: int, rng: np.random.Generator) -> NDArray[np.int64]:
    """A patch per face: ``count`` regions grown breadth-first together from random faces."""
    graph = build_face_graph(v, weld_faces(v, f))
    indptr, neighbours = adjacency_lists(graph.pairs, len(f))
    patch = np.full(len(f), -1, dtype=np.int64)
    queue = deque()
    for index, seed in enumerate(rng.choice(len(f), size=min(count, len(f)), replace=False)):
        patch[seed] = index
        queue.append(int(seed))
    while queue:
        face = queue.popleft()
        for other in neighbours[indptr[face] : indptr[face + 1]].tolist():
            if patch[other] < 0:
                patch[other] = patch[face]
                queue.append(other)
    unreached = patch < 0  # faces of pieces no seed reached: a patch of their own
    patch[unreached] = count
    return patch


def split_vertices(v: NDArray, f: NDArray, patch: NDArray) -> tuple[NDArray, NDArray, NDArray]:
    """One copy of each vertex per patch using it: ``(vertices, faces, vertex_patch)``."""
    keys = f.reshape(-1) * (int(patch.max()) + 1) + np.repeat(patch, 3)
    unique, inverse = np.unique(keys, return_inverse=True)
    vertex, vertex_patch = np.divmod(unique, int(patch.max()) + 1)
    return v[vertex], inverse.reshape(-1, 3), vertex_patch


def seams(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    vertices, faces, _ = split_vertices(v, f, patches(v, f, 30, rng))
    return Variant(vertices, faces, np.arange(len(f)))


def double_sided(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    return Variant(v, np.concatenate([f, f[:, ::-1]]), np.tile(np.arange(len(f)), 2))


#: How far ``shells`` moves each shell, as a share of the bounding diagonal (``--shells-move``).
SHELLS_MOVE = 0.01


def shells(v: NDArray, f: NDArray, rng: np.random.Generator, move: float = SHELLS_MOVE) -> Variant:
    vertices, faces, vertex_patch = split_vertices(v, f, patches(v, f, 4, rng))
    diagonal = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    directions = rng.normal(size=(int(vertex_patch.max()) + 1, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    moved = vertices + move * diagonal * directions[vertex_patch]
    return Variant(moved, faces, np.arange(len(f)))


def subdivision_passes(face_count: int) -> int:
    """Passes of 1-to-4 subdivision until there are at least ``SUBDIVIDED_FACES`` faces."""
    passes = 0
    while face_count * 4**passes < SUBDIVIDED_FACES:
        passes += 1
    return passes


def cached_subdivision(v: NDArray, f: NDArray, kind: str) -> tuple[NDArray, NDArray, NDArray]:
    """(vertices, faces, published face of each face) of ``kind`` ("loop" or "midpoint")
    subdivision to at least ``SUBDIVIDED_FACES`` faces; cached by the input's bytes."""
    import trimesh.remesh

    passes = subdivision_passes(len(f))
    digest = hashlib.sha256(v.tobytes() + f.tobytes()).hexdigest()[:16]
    file = CACHE_DIR / f"{kind}-{digest}-{passes}.npz"
    if file.is_file():
        with np.load(file) as data:
            return data["vertices"], data["faces"], data["origin"]
    if kind == "loop":
        vertices, faces = trimesh.remesh.subdivide_loop(v, f, iterations=passes)
        # trimesh's Loop pass writes face i's four children at rows 4i..4i+3.
        origin = np.arange(len(faces)) // 4**passes
    else:
        vertices, faces, origin = midpoint_subdivide(v, f, passes)
    file.parent.mkdir(parents=True, exist_ok=True)
    np.savez(file, vertices=vertices, faces=faces, origin=origin)
    return vertices, faces, origin


def subdivided(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    """Loop subdivision (smooth: creases are rounded over the new faces)."""
    return Variant(*cached_subdivision(v, f, "loop"))


def midpoint(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    """Midpoint subdivision (the same piecewise-flat surface: creases stay sharp)."""
    return Variant(*cached_subdivision(v, f, "midpoint"))


#: ``refined``: the share of the surface area split finely, and the face count it reaches.
REFINED_AREA_SHARE = 0.2
REFINED_FACES = 100_000


def grown_region(v: NDArray, f: NDArray, share: float, rng: np.random.Generator) -> NDArray:
    """Faces grown breadth-first from a random face until they hold ``share`` of the area."""
    graph = build_face_graph(v, weld_faces(v, f))
    indptr, neighbours = adjacency_lists(graph.pairs, len(f))
    areas = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    inside = np.zeros(len(f), dtype=bool)
    start = int(rng.integers(len(f)))
    inside[start] = True
    queue, held = deque([start]), float(areas[start])
    while queue and held < share * areas.sum():
        face = queue.popleft()
        for other in neighbours[indptr[face] : indptr[face + 1]].tolist():
            if not inside[other]:
                inside[other] = True
                held += float(areas[other])
                queue.append(other)
    return inside


def refined(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    """``REFINED_AREA_SHARE`` of the surface split finely enough for ``REFINED_FACES`` faces
    in all (a sculpted detail on a coarser body, as scans and sculpts often are)."""
    inside = grown_region(v, f, REFINED_AREA_SHARE, rng)
    splits = max(2, int(np.ceil(np.sqrt(1 + max(REFINED_FACES - len(f), 0) / inside.sum()))))
    return Variant(*split_region(v, f, inside, splits))


#: ``decimated``: the share of the faces quadric decimation removes.
DECIMATED_REDUCTION = 0.75


def decimate(v: NDArray, f: NDArray, reduction: float) -> tuple[NDArray, NDArray]:
    """Quadric decimation removing about ``reduction`` of the faces (as bench_neural.py)."""
    import fast_simplification

    vertices, faces = fast_simplification.simplify(
        v.astype(np.float32), f.astype(np.int32), reduction
    )
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def decimated(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    """About a quarter of the faces, by quadric decimation."""
    return Variant(*decimate(v, f, DECIMATED_REDUCTION), None)


def remeshed(v: NDArray, f: NDArray, rng: np.random.Generator) -> Variant:
    """One Loop pass (every vertex moves, the surface smooths a little), then quadric
    decimation back to about the published face count: another triangulation."""
    import trimesh.remesh

    fine_vertices, fine_faces = trimesh.remesh.subdivide_loop(v, f, iterations=1)
    return Variant(*decimate(fine_vertices, fine_faces, 1.0 - len(f) / len(fine_faces)), None)


def closest_faces(vertices: NDArray, faces: NDArray, points: NDArray) -> tuple[NDArray, NDArray]:
    """(the triangle holding the closest surface point to each point, its distance): an
    exact closest-point query (ties: the smaller triangle). Candidates are the triangles
    whose bounding sphere comes within the distance to the nearest centroid's triangle;
    triangles are searched in groups of similar size, so a few slivers stay cheap."""
    from scipy.spatial import cKDTree
    from trimesh.triangles import closest_point

    triangles = vertices[faces]
    centres = triangles.mean(axis=1)
    radius = np.linalg.norm(triangles - centres[:, None], axis=2).max(axis=1)
    _, nearest = cKDTree(centres).query(points)
    bound = np.linalg.norm(closest_point(triangles[nearest], points) - points, axis=1)
    size = np.ceil(np.log2(np.maximum(radius / max(np.median(radius), 1e-300), 1.0)))
    pairs_point, pairs_face = [], []
    for group in np.unique(size):
        members = np.flatnonzero(size == group)
        candidates = cKDTree(centres[members]).query_ball_point(
            points, bound + radius[members].max() + 1e-12
        )
        counts = np.fromiter((len(c) for c in candidates), dtype=np.int64, count=len(points))
        pairs_point.append(np.repeat(np.arange(len(points)), counts))
        pairs_face.append(members[np.concatenate([np.asarray(c, np.int64) for c in candidates])])
    point, face = np.concatenate(pairs_point), np.concatenate(pairs_face)
    near = np.linalg.norm(centres[face] - points[point], axis=1) - radius[face] <= bound[point]
    point, face = point[near], face[near]
    distance = np.linalg.norm(closest_point(triangles[face], points[point]) - points[point], axis=1)
    order = np.lexsort((face, distance, point))  # by point, then distance, then triangle
    first = order[np.r_[True, point[order][1:] != point[order][:-1]]]
    return face[first], distance[first]


def majority_per_face(origin: NDArray, labels: NDArray) -> tuple[NDArray, NDArray]:
    """(published faces, sorted; the label most of each one's variant faces have, ties:
    the smallest)."""
    kept, face = np.unique(origin, return_inverse=True)
    label_values, label = np.unique(labels, return_inverse=True)
    counts = np.zeros((len(kept), len(label_values)), dtype=np.int64)
    np.add.at(counts, (face, label), 1)
    return kept, label_values[counts.argmax(axis=1)]


def closest_face_labels(variant: Variant, labels: NDArray, v: NDArray, f: NDArray) -> NDArray:
    """The label per published face of a variant with no published parent per face: the
    label of the variant face at the closest point to the published face's centroid (a
    closest point on the triangles, not the nearest centroid, which on coarse meshes picks
    the wrong side of part borders)."""
    centroids = v[f].mean(axis=1)
    face, _ = closest_faces(variant.mesh.vertices, variant.mesh.faces, centroids)
    return np.asarray(labels)[face]


def labels_on_published(
    variant: Variant, labels: NDArray, v: NDArray, f: NDArray
) -> tuple[NDArray, NDArray]:
    """(published faces scored, sorted; their labels) of a variant's labels."""
    if variant.origin is None:
        return np.arange(len(f)), closest_face_labels(variant, labels, v, f)
    return majority_per_face(variant.origin, labels)


def surface_distance(v: NDArray, f: NDArray, variant: Variant) -> tuple[float, float]:
    """(mean, max) distance of the published vertices to the variant surface and of the
    variant vertices to the published surface (max of both ways), as shares of the
    published bounding diagonal."""
    diagonal = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0)))
    _, there = closest_faces(variant.mesh.vertices, variant.mesh.faces, v)
    _, back = closest_faces(v, f, variant.mesh.vertices)
    return float(there.mean()) / diagonal, float(max(there.max(), back.max())) / diagonal


VARIANTS: dict[str, Callable[[NDArray, NDArray, np.random.Generator], Variant]] = {
    "reversed": reversed_faces,
    "mixed30": mixed_winding,
    "holes": holes,
    "nobase": no_base,
    "shuffled": shuffled,
    "transform": transformed,
    "rotated": rotated,
    "soup": soup,
    "seams": seams,
    "doublesided": double_sided,
    "shells": shells,
    "subdivided": subdivided,
    "midpoint": midpoint,
    "decimated": decimated,
    "refined": refined,
    "remeshed": remeshed,
}


def default_segmentation(mesh: TriangleMesh) -> tuple[NDArray[np.int64], str]:
    """Labels per input face from the default path, and the mesh diagnostics if reported."""
    shdf = default_shdf(mesh)
    result = segment(mesh, shdf, SegmentParams())
    diagnostics = getattr(result, "diagnostics", None)
    note = diagnostics.summary() if diagnostics is not None else ""
    return mesh.labels_to_input_faces(result.labels), note


def score(
    vertices: NDArray, faces: NDArray, faces_kept: NDArray, labels: NDArray, humans: list
) -> tuple[float, float]:
    """(1-RI, CD) of ``labels`` (per kept face) against the humans on the kept faces."""
    metric_mesh = cut_graph(vertices, faces[faces_kept])
    references = [human[faces_kept] for human in humans]
    fields = [cut_distance_field(metric_mesh, reference) for reference in references]
    scores = score_against_humans(metric_mesh, labels, references, reference_fields=fields)
    return float(scores.ri_error), float(scores.cd)


#: Variants whose faces are the file's own, one to one: the same parts are expected.
SAME_SURFACE = (
    "reversed",
    "mixed30",
    "shuffled",
    "soup",
    "seams",
    "rotated",
    "transform",
    "doublesided",
)
#: Corpus meshes outside this many faces are left out (too small to cut; time).
CORPUS_FACES = (200, 150_000)


def corpus_consistency(cache: Path, every: int, variants: list[str], json_path: Path | None) -> int:
    """``--corpus``: the file's own parts against each same-surface variant's (1-RI)."""
    from model_export.data import unpack_archives
    from neural_shdf.errors import MeshError
    from neural_shdf.evaluate.scores import rand_index_error

    shapes = unpack_archives(cache)
    suffixes = {".obj", ".off", ".ply", ".stl"}
    paths = sorted(p for p in shapes.rglob("*") if p.suffix.lower() in suffixes)[::every]
    names = [name for name in variants if name in SAME_SURFACE] or list(SAME_SURFACE)
    rows: dict[str, list[float]] = {name: [] for name in names}
    per_mesh = []
    start = time.perf_counter()
    for path in paths:
        try:
            loaded = load_mesh(path)
        except MeshError:
            continue
        if not CORPUS_FACES[0] <= loaded.face_count <= CORPUS_FACES[1]:
            continue
        mesh = TriangleMesh(loaded.vertices, loaded.faces)  # variants map triangles
        given, _ = default_segmentation(mesh)
        for name in names:
            variant = VARIANTS[name](mesh.vertices, mesh.faces, np.random.default_rng(0))
            labels, _ = default_segmentation(variant.mesh)
            kept, kept_labels = labels_on_published(variant, labels, mesh.vertices, mesh.faces)
            error = float(rand_index_error(given[kept], kept_labels))
            rows[name].append(error)
            per_mesh.append({"mesh": path.name, "variant": name, "ri": error})
    print(f"{len(paths)} corpus meshes (every {every}), {time.perf_counter() - start:.0f} s")
    print(f"{'variant':12s} {'meshes':>6s} {'mean 1-RI':>10s} {'differ':>7s} {'> 0.05':>7s}")
    for name, errors in rows.items():
        values = np.asarray(errors)
        print(
            f"{name:12s} {len(values):6d} {values.mean():10.4f}"
            f" {int(np.sum(values > 0)):7d} {int(np.sum(values > 0.05)):7d}"
        )
    if json_path:
        json_path.write_text(json.dumps(per_mesh, indent=1))
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bench-dir", type=Path, default=DEFAULT_BENCH)
    parser.add_argument(
        "--models", type=int, nargs="+", help="model ids (default: the held-out 4th of each)"
    )
    parser.add_argument("--limit", type=int, help="only the first N of those models")
    parser.add_argument("--every", type=int, default=1, help="human-seg: every K-th mesh")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument(
        "--cache-dir", type=Path, default=DEFAULT_CACHE, help="subdivided meshes (reused)"
    )
    parser.add_argument(
        "--shells-move",
        type=float,
        default=SHELLS_MOVE,
        help="how far the shells variant moves each shell, as a share of the diagonal",
    )
    parser.add_argument(
        "--nobase-share",
        type=float,
        default=NOBASE_SHARE,
        help="which share of the faces the nobase variant removes, lowest first",
    )
    parser.add_argument("--json", type=Path, help="write the per-model scores here")
    parser.add_argument(
        "--shdf-cache",
        type=Path,
        help="keep each mesh's default ShDF here (by content and ShDF code; reruns after a"
        " segmentation change skip the ShDF)",
    )
    parser.add_argument(
        "--corpus",
        action="store_true",
        help="the training corpus: the file's own parts against same-surface variants",
    )
    parser.add_argument(
        "--corpus-cache", type=Path, default=Path("/tmp/neural-shdf-corpus"), help="unpacked corpus"
    )
    parser.add_argument("--verbose", action="store_true", help="a line per model and variant")
    parser.add_argument(
        "--shdf-fidelity",
        action="store_true",
        help="also the default ShDF against full exact on each variant (Pearson; slow)",
    )
    args = parser.parse_args()
    global SHDF_CACHE
    SHDF_CACHE = args.shdf_cache
    if args.corpus:
        every = args.every if args.every > 1 else 4
        chosen = args.variants if args.variants != list(VARIANTS) else list(SAME_SURFACE)
        return corpus_consistency(args.corpus_cache, every, chosen, args.json)
    VARIANTS["shells"] = functools.partial(shells, move=args.shells_move)
    VARIANTS["nobase"] = functools.partial(no_base, share=args.nobase_share)
    if (args.bench_dir / "off").is_dir():
        ids, load_case = psb_cases(args.bench_dir, args.models)
    elif (args.bench_dir / "face_labels").is_dir():
        ids, load_case = human_seg_cases(args.bench_dir, args.models, args.every)
    else:
        print(f"no psb-dev or human-seg folder at {args.bench_dir}", file=sys.stderr)
        return 1
    args.models = ids[: args.limit]
    global CACHE_DIR
    CACHE_DIR = args.cache_dir
    # variant -> list of (published 1-RI, CD, variant 1-RI, CD)
    rows: dict[str, list[tuple[float, float, float, float]]] = {name: [] for name in args.variants}
    per_model: list[dict] = []
    fidelity: dict[str, list[float]] = {name: [] for name in args.variants}
    distances: dict[str, list[tuple[float, float]]] = {name: [] for name in args.variants}
    start = time.perf_counter()
    for model_id in args.models:
        _, mesh, humans = load_case(model_id)
        v, f = mesh.vertices, mesh.faces
        published, _ = default_segmentation(mesh)
        for name in args.variants:
            rng = np.random.default_rng(model_id)
            variant = VARIANTS[name](v, f, rng)
            clock = time.perf_counter()
            labels, note = default_segmentation(variant.mesh)
            seconds = time.perf_counter() - clock
            kept, kept_labels = labels_on_published(variant, labels, v, f)
            apart = surface_distance(v, f, variant) if variant.origin is None else None
            if apart is not None:
                distances[name].append(apart)
            base = score(v, f, kept, published[kept], humans)
            ours = score(v, f, kept, kept_labels, humans)
            rows[name].append((*base, *ours))
            if args.shdf_fidelity:
                auto = compute_shdf(variant.mesh).values
                exact = compute_shdf(variant.mesh, method="exact").values
                fidelity[name].append(float(np.corrcoef(auto, exact)[0, 1]))
                print(f"{model_id:4d} {name:10s} ShDF Pearson {fidelity[name][-1]:.4f}", flush=True)
            per_model.append(
                {
                    "model": model_id,
                    "variant": name,
                    "published": base,
                    "variant_scores": ours,
                    "diagnostics": note,
                    "faces": variant.mesh.face_count,
                    "parts": [int(published.max()) + 1, int(labels.max()) + 1],
                    "seconds": seconds,
                    "surface_distance": apart,
                }
            )
            if args.verbose:
                print(
                    f"{model_id:4d} {name:10s} published 1-RI {base[0]:.3f} CD {base[1]:.3f}"
                    f"  variant 1-RI {ours[0]:.3f} CD {ours[1]:.3f}"
                    f"  parts {int(published.max()) + 1} -> {int(labels.max()) + 1}"
                    f"  {variant.mesh.face_count} faces {seconds:.1f} s  {note}"
                    + (f"  apart {apart[0]:.5f} / {apart[1]:.4f}" if apart else ""),
                    file=sys.stderr,
                    flush=True,
                )
    print(f"{len(args.models)} models, {time.perf_counter() - start:.0f} s")
    print(
        f"{'variant':10s} {'published 1-RI':>15s} {'variant 1-RI':>13s} {'diff':>7s}"
        f" {'published CD':>13s} {'variant CD':>11s} {'diff':>7s}"
    )
    for name, values in rows.items():
        b_ri, b_cd, v_ri, v_cd = np.nanmean(np.asarray(values), axis=0)
        print(
            f"{name:10s} {b_ri:15.3f} {v_ri:13.3f} {v_ri - b_ri:+7.3f}"
            f" {b_cd:13.3f} {v_cd:11.3f} {v_cd - b_cd:+7.3f}"
        )
    for name, apart in distances.items():
        if apart:
            mean, most = np.asarray(apart).T
            print(
                f"{name:10s} surfaces apart (share of the diagonal): mean {np.mean(mean):.5f}"
                f" (largest per model {mean.max():.5f}), max {np.median(most):.4f} median,"
                f" {most.max():.4f} largest"
            )
    for name, values in fidelity.items():
        if values:
            print(f"{name:10s} default ShDF vs exact, median Pearson {np.median(values):.4f}")
    if args.json:
        args.json.write_text(json.dumps(per_model, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
