"""Training data for the neural ShDF: shapes -> exact ShDF targets -> sample graphs.

``python -m model_export.data [--cache DIR]`` (default ``~/.cache/neural-shdf/train``)

* unpacks ``../shared/data/train-shapes/*.tar.xz`` into ``DIR/shapes`` (once);
* gathers shapes: those archives, ``human-seg/train`` and procedural shapes
  (capsules, boxes, cylinders, tori, ellipsoids, unions of primitives); never
  ``psb-dev`` (the evaluation set);
* splits whole shapes into train / validation by a hash of their name;
* per shape: the exact raw ShDF on the (capped) full-resolution mesh, once
  (``DIR/targets``), then several variants (other sampling seeds, subdivided,
  decimated, non-uniformly tessellated, other sample counts), each a sample
  graph whose targets come from the base mesh's nearest face
  (``DIR/graphs-v{GRAPH_FILE_VERSION}/{train,val}/*.npz``). Re-running skips what
  exists (resumable).
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import sys
import tarfile
import time
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from neural_shdf.geometry import face_centroids, face_normals
from neural_shdf.shdf.neural.graph import (
    GraphSpec,
    build_sample_graph,
    sample_targets,
)

REPO_ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO_ROOT / ".." / "shared" / "data"
DEFAULT_CACHE = Path.home() / ".cache" / "neural-shdf" / "train"
#: Base meshes above this many faces are decimated to it before the exact ShDF.
MAX_FACES = 40_000
#: Meshes below this many faces are skipped (too coarse to mean anything).
MIN_FACES = 200
#: Variants above this many faces are not generated.
MAX_VARIANT_FACES = 160_000
#: Share of shapes held out for validation (whole shapes).
VALIDATION_PERCENT = 10
#: Sample counts drawn for training graphs (serving uses GraphSpec's default).
SAMPLE_COUNT_RANGE = (512, 1024)
#: Every n-th human-seg mesh is used (they are 381 similar bodies).
HUMAN_SEG_STRIDE = 3
PROCEDURAL_COUNT = 160


#: Cached graph files stay valid while only node features change (training recomputes
#: them from the density column and the edges); bump when edges or their features change.
GRAPH_FILE_VERSION = 4
#: Rays cast from every sample for the ray-informed network's node features (the exact
#: ShDF's cone, CGAL's 25 rays: the same rays as the ``sampled`` producer).
TRAINING_RAY_COUNT = 25


def graph_folder(cache: Path) -> Path:
    """Cached sample graphs of the current graph file version."""
    return cache / f"graphs-v{GRAPH_FILE_VERSION}"


def is_validation(name: str) -> bool:
    """Whole-shape split: about VALIDATION_PERCENT % of names go to validation."""
    return zlib.crc32(name.encode()) % 100 < VALIDATION_PERCENT


def unpack_archives(cache: Path) -> Path:
    """Unpack the training archives into ``cache/shapes`` (skipped when done)."""
    shapes = cache / "shapes"
    for archive in sorted((SHARED_DATA / "train-shapes").glob("*.tar.xz")):
        marker = shapes / f".{archive.name}.done"
        if marker.exists():
            continue
        shapes.mkdir(parents=True, exist_ok=True)
        with tarfile.open(archive) as tar:
            tar.extractall(shapes, filter="data")
        marker.touch()
    return shapes


def file_sources(cache: Path) -> list[tuple[str, Path]]:
    """(name, path) of every training mesh file."""
    shapes = unpack_archives(cache)
    exts = {".obj", ".off", ".ply", ".stl"}
    out = []
    for path in sorted(shapes.rglob("*")):
        if path.suffix.lower() in exts:
            out.append((str(path.relative_to(shapes)), path))
    human = sorted((SHARED_DATA / "human-seg" / "train").glob("*"))
    for path in human[::HUMAN_SEG_STRIDE]:
        out.append((f"human-seg/{path.name}", path))
    return out


def _primitive(rng: np.random.Generator) -> trimesh.Trimesh:
    kind = rng.integers(6)
    if kind == 0:
        mesh = trimesh.creation.capsule(
            height=rng.uniform(0.2, 3), radius=rng.uniform(0.1, 0.8), count=[32, 32]
        )
    elif kind == 1:
        mesh = trimesh.creation.box(extents=rng.uniform(0.1, 2.0, 3))
        mesh = mesh.subdivide().subdivide()
    elif kind == 2:
        mesh = trimesh.creation.cylinder(
            radius=rng.uniform(0.1, 0.8), height=rng.uniform(0.2, 3), sections=40
        )
    elif kind == 3:
        major = rng.uniform(0.5, 1.5)
        mesh = trimesh.creation.torus(
            major_radius=major,
            minor_radius=rng.uniform(0.05, 0.45) * major,
            major_sections=48,
            minor_sections=24,
        )
    elif kind == 4:
        mesh = trimesh.creation.icosphere(subdivisions=3)
        mesh.apply_scale(rng.uniform(0.15, 1.5, 3))
    else:
        mesh = trimesh.creation.cone(radius=rng.uniform(0.2, 1), height=rng.uniform(0.3, 2))
        mesh = mesh.subdivide()
    rotation = trimesh.transformations.random_rotation_matrix(rng.random(3))
    mesh.apply_transform(rotation)
    return mesh


def procedural_mesh(index: int) -> trimesh.Trimesh:
    """Deterministic procedural shape ``index``: one primitive or a union of 2-6."""
    rng = np.random.default_rng(10_000 + index)
    if index % 3 == 0:
        return _primitive(rng)
    parts = []
    for _ in range(int(rng.integers(2, 7))):
        part = _primitive(rng)
        part.apply_translation(rng.normal(0, 0.7, 3))
        parts.append(part)
    try:
        mesh = trimesh.boolean.union(parts, engine="manifold")
        if len(mesh.faces) >= MIN_FACES:
            return mesh
    except Exception:  # noqa: BLE001 - fall back to separate shells
        pass
    return trimesh.util.concatenate(parts)


def load_vertices_faces(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of a mesh file, via the project's reader (trimesh as a fallback)."""
    try:
        from neural_shdf.mesh_io import load_mesh

        mesh = load_mesh(path)
        return mesh.vertices, mesh.faces
    except ImportError:
        loaded = trimesh.load(path, process=False, force="mesh")
        return np.asarray(loaded.vertices), np.asarray(loaded.faces)


def decimate(vertices: np.ndarray, faces: np.ndarray, target_faces: int):
    """fast_simplification to about ``target_faces`` faces."""
    import fast_simplification

    reduction = 1.0 - target_faces / len(faces)
    if reduction <= 0:
        return vertices, faces
    v, f = fast_simplification.simplify(
        vertices.astype(np.float32), faces.astype(np.int32), target_reduction=reduction
    )
    return np.asarray(v, np.float64), np.asarray(f, np.int64)


def clean(vertices: np.ndarray, faces: np.ndarray):
    """Drop degenerate triangles and unused vertices (keeps everything else)."""
    _, areas = face_normals(vertices, faces)
    faces = faces[areas > 0]
    used, inverse = np.unique(faces, return_inverse=True)
    return vertices[used], inverse.reshape(-1, 3).astype(np.int64)


def subdivide_to(vertices, faces, max_faces: int, face_index=None):
    """Midpoint subdivision (of ``face_index`` only, if given) while under ``max_faces``."""
    v, f = vertices, faces
    for _ in range(3):
        grow = 3 * (len(f) if face_index is None else len(face_index))
        if len(f) + grow > max_faces:
            break
        v, f = trimesh.remesh.subdivide(v, f, face_index=face_index)
        if face_index is not None:
            # New faces replacing the selected ones are appended at the end.
            face_index = np.arange(len(f) - 4 * len(face_index), len(f))
    return np.asarray(v, np.float64), np.asarray(f, np.int64)


def variants(vertices, faces, rng: np.random.Generator):
    """(label, vertices, faces) tessellations of one shape for training."""
    out = [("base", vertices, faces), ("reseed", vertices, faces)]
    if len(faces) * 4 <= MAX_VARIANT_FACES:
        out.append(("subdivided", *subdivide_to(vertices, faces, MAX_VARIANT_FACES)))
    if len(faces) >= 2000:
        with contextlib.suppress(Exception):  # decimation is best effort
            out.append(("decimated", *clean(*decimate(vertices, faces, len(faces) // 4))))
    centroids = face_centroids(vertices, faces)
    direction = rng.normal(size=3)
    side = (centroids - centroids.mean(axis=0)) @ direction > 0
    chosen = np.flatnonzero(side)
    if len(chosen) > 0 and len(faces) + 15 * len(chosen) <= MAX_VARIANT_FACES:
        out.append(("adaptive", *subdivide_to(vertices, faces, MAX_VARIANT_FACES, chosen)))
    return out


def base_mesh(name: str, source) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(source, Path):
        vertices, faces = load_vertices_faces(source)
    else:
        mesh = procedural_mesh(int(source))
        vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    vertices, faces = clean(np.asarray(vertices, np.float64), np.asarray(faces, np.int64))
    if len(faces) > MAX_FACES:
        vertices, faces = clean(*decimate(vertices, faces, MAX_FACES))
    return vertices, faces


def safe_name(name: str) -> str:
    stem = "".join(c if c.isalnum() or c in "-_" else "_" for c in name)[-80:]
    return f"{stem}_{hashlib.sha1(name.encode()).hexdigest()[:8]}"


def ray_arrays(vertices, faces, graph, ray_count: int) -> dict[str, np.ndarray]:
    """The ShDF cone cast from each sample: robust mean diameter in Poisson radii (NaN
    without a valid hit), relative spread and hit fraction (``ray_feature_array``'s inputs)."""
    from neural_shdf.shdf.exact import raw_shdf_at_points

    mean, spread, hits = raw_shdf_at_points(
        vertices,
        faces,
        graph.positions,
        graph.normals,
        graph.face_ids,
        ray_count=ray_count,
        threads=1,
    )
    return {
        "ray_diameter": (mean / graph.radius).astype(np.float32),
        "ray_spread": spread.astype(np.float32),
        "ray_hits": hits.astype(np.float32),
    }


def process_shape(name: str, source, cache: Path, log) -> int:
    """Targets and variant graphs of one shape; returns the number of graphs written."""
    from model_export.shdf_task import graph_arrays, log_diameter_target
    from neural_shdf.shdf.exact import raw_shdf

    split = "val" if is_validation(name) else "train"
    out_dir = graph_folder(cache) / split
    out_dir.mkdir(parents=True, exist_ok=True)
    key = safe_name(name)
    done_marker = out_dir / f"{key}.done"
    if done_marker.exists():
        return 0
    vertices, faces = base_mesh(name, source)
    if len(faces) < MIN_FACES:
        done_marker.write_text("skipped: too few faces")
        return 0
    start = time.time()
    target_file = cache / "targets" / f"{key}.npz"
    if target_file.exists():
        raw = np.load(target_file)["raw"]
    else:
        raw = raw_shdf(vertices, faces, threads=1)
        target_file.parent.mkdir(parents=True, exist_ok=True)  # targets outlive graph versions
        np.savez(target_file, raw=raw, faces=len(faces))
    if np.isfinite(raw).mean() < 0.5:
        done_marker.write_text("skipped: ShDF undefined on most faces")
        return 0
    base_tree = cKDTree(face_centroids(vertices, faces))
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    written = 0
    for index, (label, v, f) in enumerate(variants(vertices, faces, rng)):
        spec = GraphSpec(target_samples=int(rng.integers(*SAMPLE_COUNT_RANGE)))
        normals, areas = face_normals(v, f)
        centroids = face_centroids(v, f)
        graph = build_sample_graph(
            v, f, spec, seed=int(rng.integers(2**31)), normals=normals, areas=areas, workers=1
        )
        face_raw = raw if f is faces else raw[base_tree.query(centroids, workers=1)[1]]
        per_sample = sample_targets(face_raw, areas, centroids, graph)
        target = log_diameter_target(per_sample, graph.radius)
        arrays = graph_arrays(graph)
        arrays["target"] = target.astype(np.float32)
        arrays.update(ray_arrays(v, f, graph, TRAINING_RAY_COUNT))
        np.savez(out_dir / f"{key}__{index}_{label}.npz", **arrays)
        written += 1
    done_marker.write_text(
        json.dumps({"name": name, "faces": int(len(faces)), "seconds": time.time() - start})
    )
    log(f"{split} {name}: {len(faces)} faces, {written} graphs, {time.time() - start:.1f}s")
    return written


def all_sources(cache: Path) -> list[tuple[str, object]]:
    """Every training shape as (name, path or procedural index), in a fixed mixed order."""
    sources: list[tuple[str, object]] = list(file_sources(cache))
    sources += [(f"procedural/{i:04d}", i) for i in range(PROCEDURAL_COUNT)]
    # Interleave kinds so that a partial run already covers all of them.
    return sorted(sources, key=lambda s: hashlib.sha1(s[0].encode()).hexdigest())


def file_logger(path: Path) -> Callable[[str], None]:
    """A ``log(message)`` printing time-stamped lines and appending them to ``path`` (a
    long run's record that survives the terminal; the file stays open for the process)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    log_file = open(path, "a")  # noqa: SIM115 - open for the whole run

    def log(message: str) -> None:
        line = f"{time.strftime('%H:%M:%S')} {message}"
        print(line, file=log_file, flush=True)
        print(line, flush=True)

    return log


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, default=DEFAULT_CACHE)
    parser.add_argument("--limit", type=int, default=0, help="process at most this many shapes")
    parser.add_argument("--part", type=str, default="0/1", help="i/n: this worker's share")
    args = parser.parse_args(argv)
    cache = args.cache.expanduser()
    cache.mkdir(parents=True, exist_ok=True)
    part, parts = (int(x) for x in args.part.split("/"))
    log = file_logger(cache / f"data-{part}.log")
    sources = all_sources(cache)[part::parts]
    if args.limit:
        sources = sources[: args.limit]
    total = 0
    start = time.time()
    for name, source in sources:
        try:
            total += process_shape(name, source, cache, log)
        except Exception as error:  # noqa: BLE001 - one bad mesh must not stop the run
            log(f"FAILED {name}: {type(error).__name__}: {error}")
    log(f"done: {total} graphs in {time.time() - start:.0f}s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
