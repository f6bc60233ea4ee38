"""Where the ShDF's rays go wrong on the ``shells`` variant, and what ray rules could recover.

``bench_production.py``'s ``shells`` variant cuts a psb-dev mesh into 4 pieces, each moved
by a share of the diagonal. Per face, the axis ray of its ray cone (along the inward
normal) is cast into the published mesh and into the variant (both oriented, holes capped
as the ShDF's rays see them) and walked through every surface it crosses. A face is *off*
where the variant's distance is not within a third of the published one (or is missing).
Per model and on average it prints the share of faces off under three rules:

* ``first``: the exact ShDF's rule (the first hit, only when the ray leaves through the
  back of the hit triangle);
* ``through``: a first hit on a triangle's front (the ray enters another solid) goes on,
  counting the solids entered, to where the ray leaves them and its own;
* ``union``: the ray ends where it leaves the union of all the solids (the winding number
  along the whole ray: also right where the face itself lies inside another piece),

and, under ``first``, which share of the off faces had their first hit on a triangle's
front, no hit, or the back of a triangle of another piece (the piece moved: the thickness
there really changed) or of the same piece or a hole's cap.

    python benchmarks/bench_shells_rays.py [--models 1 2 ...] [--shells-move 0.01]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from neural_shdf.evaluate.benchmark import list_models, load_benchmark_mesh
from neural_shdf.geometry import face_normals
from neural_shdf.mesh import TriangleMesh
from neural_shdf.shdf.embree import Scene
from neural_shdf.shdf.stage import ray_targets

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_production import DEFAULT_BENCH, SHELLS_MOVE, is_held_out, patches, shells  # noqa: E402

#: Hits walked along each ray at most.
MAX_HITS = 24
#: A ray goes on this share of the diagonal past each hit.
STEP = 1e-5


def axis_hits(mesh: TriangleMesh) -> tuple[NDArray, NDArray, NDArray]:
    """(triangle, distance, facing) of the successive hits of each face's axis ray, one
    row per hit (-1, NaN, 0 past the last): facing +1 leaving through a triangle's back,
    -1 entering through its front."""
    oriented = mesh.oriented
    vertices, triangles = ray_targets(oriented, oriented.diagnostics.boundary_loops > 0)
    normals, _ = face_normals(vertices, triangles)
    scene = Scene(vertices, triangles)
    faces = len(oriented.faces)
    origins = vertices[oriented.faces].mean(axis=1) - Scene.center_of(vertices)
    directions = -normals[:faces]
    step = STEP * float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    travelled = np.full(faces, 0.1 * step)
    hit = np.full((MAX_HITS, faces), -1)
    distance = np.full((MAX_HITS, faces), np.nan)
    facing = np.zeros((MAX_HITS, faces))
    alive = np.flatnonzero(np.linalg.norm(directions, axis=1) > 0.5)
    for row in range(MAX_HITS):
        if not len(alive):
            break
        found = scene.first_hits(
            origins[alive] + travelled[alive, None] * directions[alive], directions[alive]
        )
        if row == 0:
            found[found == alive] = -1  # a ray back on its own triangle through rounding
        alive, found = alive[found >= 0], found[found >= 0]
        corner = vertices[triangles[found, 0]] - Scene.center_of(vertices)
        along = np.einsum("ij,ij->i", directions[alive], normals[found])
        reach = np.einsum("ij,ij->i", corner - origins[alive], normals[found]) / np.where(
            along == 0, np.nan, along
        )
        hit[row, alive], distance[row, alive], facing[row, alive] = found, reach, np.sign(along)
        travelled[alive] = reach + step
        alive = alive[np.isfinite(reach)]
    return hit, distance, facing


def exit_distances(distance: NDArray, facing: NDArray, start: NDArray) -> NDArray:
    """Distance where the count of solids the ray is in, ``start`` (per ray) just past its
    origin, +1 at each front and -1 at each back, first drops below 1; NaN where it does not."""
    inside = start.astype(np.float64)
    out = np.full(distance.shape[1], np.nan)
    for row in range(len(distance)):
        inside = inside + (facing[row] < 0) - (facing[row] > 0)
        ends = np.isnan(out) & (facing[row] != 0) & (inside < 1)
        out[ends] = distance[row, ends]
        out[np.isnan(out) & (facing[row] == 0) & (inside >= 1)] = -1.0  # never leaves
    out[out < 0] = np.nan
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--bench-dir", type=Path, default=DEFAULT_BENCH)
    parser.add_argument("--models", type=int, nargs="+", help="default: the tuning split")
    parser.add_argument("--shells-move", type=float, default=SHELLS_MOVE)
    args = parser.parse_args()
    models = {m.model_id: m for m in list_models(args.bench_dir)}
    ids = args.models or [i for i in sorted(models) if not is_held_out(i)]
    rules = ("first", "through", "union")
    causes = ("front", "none", "other piece", "own or cap")
    totals: dict[str, list[float]] = {name: [] for name in rules + causes}
    print(f"{'model':>5} " + " ".join(f"{r:>8}" for r in rules) + "  off under first by cause")
    for model_id in ids:
        mesh = load_benchmark_mesh(models[model_id].mesh_path)
        v, f = mesh.vertices, mesh.faces
        piece = patches(v, f, 4, np.random.default_rng(model_id))  # as shells draws them
        variant = shells(v, f, np.random.default_rng(model_id), move=args.shells_move).mesh
        published = axis_hits(mesh)
        hit, distance, facing = axis_hits(variant)
        reference = np.where(published[2][0] > 0, published[1][0], np.nan)
        valid = np.isfinite(reference)
        ones = np.ones(len(f))
        values = {
            "first": np.where(facing[0] > 0, distance[0], np.nan),
            "through": exit_distances(distance, facing, ones),
            "union": exit_distances(distance, facing, (facing > 0).sum(0) - (facing < 0).sum(0)),
        }
        off = {
            name: valid & ~(np.abs(value - reference) <= reference / 3)
            for name, value in values.items()
        }
        first = hit[0]
        surface = (first >= 0) & (first < len(f))
        other = np.zeros(len(f), dtype=bool)
        other[surface] = piece[first[surface]] != piece[np.flatnonzero(surface)]
        cause = {
            "front": facing[0] < 0,
            "none": first < 0,
            "other piece": (facing[0] > 0) & other,
            "own or cap": (facing[0] > 0) & ~other,
        }
        wrong = max(int(off["first"].sum()), 1)
        for name in rules:
            totals[name].append(off[name].sum() / valid.sum())
        for name, where in cause.items():
            totals[name].append((where & off["first"]).sum() / wrong)
        print(
            f"{model_id:5d} "
            + " ".join(f"{totals[r][-1]:8.3f}" for r in rules)
            + "  "
            + " ".join(f"{c} {totals[c][-1]:.2f}" for c in causes),
            flush=True,
        )
    print(
        f"{'mean':>5} "
        + " ".join(f"{np.mean(totals[r]):8.3f}" for r in rules)
        + "  "
        + " ".join(f"{c} {np.mean(totals[c]):.2f}" for c in causes)
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
