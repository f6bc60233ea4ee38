"""Neural ShDF benchmark: fidelity, resolution independence, robustness, speed.

``python benchmarks/bench_neural.py [--quick] [--sections fidelity,resolution,robustness,speed]``

Prints numbers measured side by side in one run (no pass/fail timing in tests):

* fidelity: per-mesh Pearson correlation and MAE of the neural ShDF against
  the exact ShDF (both post-processed to [0, 1]) on the held-out validation
  shapes and on ``psb-dev`` (never trained on); targets: median Pearson >= 0.95,
  MAE <= 0.05;
* resolution: one shape at x1, subdivided x16, decimated x0.25 and adaptively
  tessellated; each prediction mapped back to the x1 faces (nearest centroid)
  and compared with the x1 prediction (target MAE <= 0.03);
* robustness: holes, flipped normals, duplicated shells: is the neural ShDF of
  the damaged mesh closer to the clean mesh's exact ShDF than the exact ShDF of
  the damaged mesh is?
* speed: the largest ``dense-dev`` mesh and a ~1M-face subdivided mesh, neural
  vs exact in the same run (file loading excluded), each in a child process
  for its peak RSS; and a profile of the neural path's stages.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / ".." / "shared" / "data"
sys.path.insert(0, str(REPO))

from neural_shdf.geometry import face_centroids  # noqa: E402
from neural_shdf.mesh import TriangleMesh  # noqa: E402
from neural_shdf.pipeline import compute_shdf  # noqa: E402


def exact_shdf(mesh: TriangleMesh) -> np.ndarray:
    return compute_shdf(mesh, method="exact").values


def neural_shdf(mesh: TriangleMesh, *, seed: int = 0) -> np.ndarray:
    return compute_shdf(mesh, method="neural", seed=seed).values


def load(path: Path) -> TriangleMesh:
    from neural_shdf.mesh_io import load_mesh

    return load_mesh(path)


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    if a.std() == 0 or b.std() == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def compare(mesh: TriangleMesh) -> tuple[float, float, float, float]:
    """Pearson and MAE of the neural ShDF vs the exact one: default and with smoothing."""
    from neural_shdf.shdf.neural.inference import neural_raw_shdf
    from neural_shdf.shdf.postprocess import postprocess_shdf

    graph = mesh.face_graph
    exact = exact_shdf(mesh)
    neural = neural_shdf(mesh)
    smoothed = postprocess_shdf(neural_raw_shdf(mesh.vertices, mesh.faces), graph)
    return (
        pearson(neural, exact),
        float(np.abs(neural - exact).mean()),
        pearson(smoothed, exact),
        float(np.abs(smoothed - exact).mean()),
    )


def summary(label: str, rows: list[tuple]) -> None:
    r, m, rs, ms = (np.array([x[k] for x in rows]) for k in (2, 3, 4, 5))
    print(
        f"{label}: {len(rows)} meshes, Pearson median {np.nanmedian(r):.3f} "
        f"mean {np.nanmean(r):.3f} p10 {np.nanpercentile(r, 10):.3f}; "
        f"MAE median {np.median(m):.3f} mean {m.mean():.3f} p90 {np.percentile(m, 90):.3f}; "
        f"with bilateral pass: Pearson median {np.nanmedian(rs):.3f}, "
        f"MAE median {np.median(ms):.3f}"
    )


def fidelity(quick: bool) -> None:
    print("== fidelity (neural vs exact, post-processed [0,1]) ==")
    from model_export.data import DEFAULT_CACHE, all_sources, base_mesh, is_validation

    sources = [s for s in all_sources(DEFAULT_CACHE) if is_validation(s[0])]
    rows = []
    for name, source in sources[: 12 if quick else 40]:
        try:
            v, f = base_mesh(name, source)
            scores = compare(TriangleMesh(v, f))
        except Exception as error:  # noqa: BLE001 - report and continue
            print(f"  skipped {name}: {error}")
            continue
        rows.append((name, len(f), *scores))
        print(f"  val {name}: {len(f)} faces, Pearson {scores[0]:.3f}, MAE {scores[1]:.3f}")
    summary("validation shapes", rows)
    rows = []
    paths = sorted((DATA / "psb-dev" / "off").glob("*.off"), key=lambda p: int(p.stem))
    for path in paths[::4] if quick else paths:
        mesh = load(path)
        scores = compare(mesh)
        rows.append((path.stem, mesh.face_count, *scores))
        print(
            f"  psb {path.stem}: {mesh.face_count} faces, Pearson {scores[0]:.3f}, "
            f"MAE {scores[1]:.3f}"
        )
    summary("psb-dev", rows)


def nearest_face_map(source: TriangleMesh, target: TriangleMesh) -> np.ndarray:
    """For each target face, the nearest source face (by centroid)."""
    tree = cKDTree(face_centroids(source.vertices, source.faces))
    return tree.query(face_centroids(target.vertices, target.faces), workers=2)[1]


def resolution_variants(mesh: TriangleMesh) -> dict[str, TriangleMesh]:
    import fast_simplification

    v, f = mesh.vertices, mesh.faces
    sv, sf = trimesh.remesh.subdivide(*trimesh.remesh.subdivide(v, f))
    dv, df = fast_simplification.simplify(v.astype(np.float32), f.astype(np.int32), 0.75)
    centroids = face_centroids(v, f)
    side = np.flatnonzero(centroids[:, 0] > np.median(centroids[:, 0]))
    av, af = trimesh.remesh.subdivide(v, f, face_index=side)
    chosen = np.arange(len(af) - 4 * len(side), len(af))
    av, af = trimesh.remesh.subdivide(av, af, face_index=chosen)
    return {
        "x16 subdivided": TriangleMesh(sv, sf),
        "x0.25 decimated": TriangleMesh(np.asarray(dv, float), np.asarray(df)),
        "adaptive (half x16)": TriangleMesh(av, af),
    }


def resolution() -> None:
    print("== resolution independence (mapped to x1 faces, MAE vs x1) ==")
    for model_id in (1, 181, 281):
        path = DATA / "psb-dev" / "off" / f"{model_id}.off"
        base = load(path)
        reference = neural_shdf(base)
        exact = exact_shdf(base)
        print(
            f"  psb {model_id} x1: {base.face_count} faces, Pearson vs exact "
            f"{pearson(reference, exact):.3f}"
        )
        for label, variant in resolution_variants(base).items():
            values = neural_shdf(variant)
            mapped = values[nearest_face_map(variant, base)]
            mae = np.abs(mapped - reference).mean()
            print(
                f"    {label}: {variant.face_count} faces, MAE vs x1 {mae:.4f}, "
                f"Pearson {pearson(mapped, reference):.3f}"
            )
        for seed in (1, 2):
            values = neural_shdf(base, seed=seed)
            print(
                f"    x1 other sampling seed {seed}: MAE vs seed 0 "
                f"{np.abs(values - reference).mean():.4f}"
            )


def damaged_versions(mesh: TriangleMesh, rng: np.random.Generator):
    """(label, damaged mesh, index of the clean face behind each damaged face)."""
    v, f = mesh.vertices, mesh.faces
    centroids = face_centroids(v, f)
    n = len(f)
    # Holes: remove the faces nearest to 12 random centres (about 5 % of faces).
    centres = centroids[rng.choice(n, 12, replace=False)]
    _, hole = cKDTree(centroids).query(centres, k=max(1, n // 240))
    keep = np.setdiff1d(np.arange(n), np.unique(hole))
    yield "holes (5%)", TriangleMesh(v, f[keep]), keep
    flipped = f.copy()
    chosen = rng.random(n) < 0.2
    flipped[chosen] = flipped[chosen][:, ::-1]
    yield "flipped normals (20% of faces)", TriangleMesh(v, flipped), np.arange(n)
    duplicated = np.concatenate([f, f + len(v)])
    yield (
        "duplicated shell",
        TriangleMesh(np.concatenate([v, v]), duplicated),
        np.concatenate([np.arange(n), np.arange(n)]),
    )


def robustness() -> None:
    print("== robustness (MAE vs exact ShDF of the clean mesh) ==")
    rng = np.random.default_rng(0)
    for model_id in (1, 21, 101, 161, 381):
        mesh = load(DATA / "psb-dev" / "off" / f"{model_id}.off")
        clean_exact = exact_shdf(mesh)
        clean_neural = neural_shdf(mesh)
        print(f"  psb {model_id}: clean neural MAE {np.abs(clean_neural - clean_exact).mean():.3f}")
        for label, damaged, origin in damaged_versions(mesh, rng):
            exact = exact_shdf(damaged)
            neural = neural_shdf(damaged)
            reference = clean_exact[origin]
            e, nn = np.abs(exact - reference).mean(), np.abs(neural - reference).mean()
            print(
                f"    {label}: exact(damaged) MAE {e:.3f}, neural(damaged) MAE {nn:.3f} "
                f"-> {'neural closer' if nn < e else 'exact closer'}"
            )


CHILD = """
import json, resource, sys, time
import numpy as np
sys.path.insert(0, {repo!r})
from neural_shdf.mesh import TriangleMesh
data = np.load({path!r})
mesh = TriangleMesh(data["vertices"], data["faces"])
start = time.perf_counter()
graph = mesh.face_graph
graph_s = time.perf_counter() - start
if {method!r} == "neural":
    from neural_shdf.shdf.neural.inference import load_model
    from neural_shdf.pipeline import compute_shdf
    run = lambda mesh: compute_shdf(mesh, method="neural").values
    load_model()
else:
    from neural_shdf.pipeline import compute_shdf
    run = lambda mesh: compute_shdf(mesh, method="exact").values
import trimesh  # warm-up: compiled kernels loaded, model session made, before timing
small = trimesh.creation.icosphere(3)
small = TriangleMesh(small.vertices, small.faces)
run(small)
start = time.perf_counter()
values = run(mesh)
seconds = time.perf_counter() - start
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(dict(graph_s=graph_s, seconds=seconds, peak_mb=peak)))
np.save({out!r}, values)
"""


def run_child(mesh_file: Path, method: str, out: Path) -> dict:
    code = CHILD.format(
        repo=str(REPO / "service"), path=str(mesh_file), method=method, out=str(out)
    )
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    return json.loads(result.stdout.strip().splitlines()[-1])


def profile_neural(mesh: TriangleMesh) -> None:
    from neural_shdf.shdf.neural.graph import build_sample_graph
    from neural_shdf.shdf.neural.inference import load_model
    from neural_shdf.shdf.postprocess import postprocess_shdf
    from neural_shdf.shdf.sampling import samples_to_faces

    model = load_model()
    times = {}
    t = time.perf_counter()
    graph_faces = mesh.face_graph
    times["face graph (shared with segmentation)"] = time.perf_counter() - t
    t = time.perf_counter()
    normals, areas = mesh.normals_and_areas
    times["face normals, areas (cached by the face graph)"] = time.perf_counter() - t
    t = time.perf_counter()
    graph = build_sample_graph(mesh.vertices, mesh.faces, model.spec, normals=normals, areas=areas)
    times["sampling + density + edges + vertex kNN"] = time.perf_counter() - t
    t = time.perf_counter()
    log_d = model.predict_log_diameter(graph)
    times["network (onnxruntime)"] = time.perf_counter() - t
    t = time.perf_counter()
    raw = samples_to_faces(np.exp(log_d) * graph.radius, graph, mesh.faces)
    times["samples -> faces"] = time.perf_counter() - t
    t = time.perf_counter()
    postprocess_shdf(raw, graph_faces, smooth=False)
    times["post-processing (fill, normalise)"] = time.perf_counter() - t
    for key, value in times.items():
        print(f"    {key}: {value:.3f}s")


def speed(tmp: Path) -> None:
    print("== speed (same run; file loading excluded; child processes for peak RSS) ==")
    dense = max((DATA / "dense-dev").glob("*.ply"), key=lambda p: load(p).face_count)
    meshes = {f"dense-dev {dense.name}": load(dense)}
    big = load(DATA / "dense-dev" / "vtkdata__Data__lucy.ply")
    v, f = big.vertices, big.faces
    while len(f) < 900_000:
        v, f = trimesh.remesh.subdivide(v, f)
    meshes["lucy subdivided"] = TriangleMesh(v, f)
    tmp.mkdir(parents=True, exist_ok=True)
    for label, mesh in meshes.items():
        mesh_file = tmp / "mesh.npz"
        np.savez(mesh_file, vertices=mesh.vertices, faces=mesh.faces)
        neural = run_child(mesh_file, "neural", tmp / "neural.npy")
        exact = run_child(mesh_file, "exact", tmp / "exact.npy")
        a, b = np.load(tmp / "neural.npy"), np.load(tmp / "exact.npy")
        print(
            f"  {label}: {mesh.face_count} faces; face graph {neural['graph_s']:.2f}s; "
            f"neural {neural['seconds']:.2f}s (peak {neural['peak_mb']:.0f} MB), exact "
            f"{exact['seconds']:.2f}s (peak {exact['peak_mb']:.0f} MB): "
            f"x{exact['seconds'] / neural['seconds']:.1f}; Pearson {pearson(a, b):.3f}, "
            f"MAE {np.abs(a - b).mean():.3f}"
        )
        print("  neural stages:")
        profile_neural(mesh)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--sections", default="fidelity,resolution,robustness,speed")
    parser.add_argument("--tmp", type=Path, default=Path("/tmp/bench-neural"))
    args = parser.parse_args()
    sections = args.sections.split(",")
    start = time.time()
    if "fidelity" in sections:
        fidelity(args.quick)
    if "resolution" in sections:
        resolution()
    if "robustness" in sections:
        robustness()
    if "speed" in sections:
        speed(args.tmp)
    print(f"total {time.time() - start:.0f}s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
