"""Run segmentation methods over a Princeton-Segmentation-Benchmark folder and tabulate.

Folder layout (as the benchmark ships it): ``off/{id}.off``; human
segmentations ``seg/{id}/{id}_{n}.seg`` (one segment id per face per line, in
the OFF's face order); optionally CGAL's output ``cgal/{id}.seg`` and
``cgal/{id}.sdf``. Category of a model: ``(id - 1) // 20``.

Averaging follows the benchmark: a model's score is the mean over its human
segmentations, a category's the mean over its models, and the overall score
the mean over categories (not over models).

Method names (``run_eval(methods=...)``, the CLI's ``--methods``):

* ``cgal``: CGAL's segmentation read from ``cgal/{id}.seg``;
* ``{source}-{partitioner}`` with source ``exact`` (our exact ShDF, cached per
  mesh), ``neural`` (the neural predictor) or ``cgalsdf`` (CGAL's ShDF read
  from ``cgal/{id}.sdf``; a fast proxy while tuning) and partitioner
  ``graphcut`` or ``metis`` (automatic parameters);
* a ``-humanparts`` suffix: the partitioner is given the number of parts the
  humans used most often for that model, the benchmark's protocol for methods
  that take a part count (graph cut: a cut of its part tree; metis: exactly);
* a ``-leaves`` suffix (graph cut only): every leaf of the part tree, i.e. the
  graph cut's own parts with no merging (the segmentation before the tree).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from collections import Counter
from collections.abc import Callable, Collection, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf import pipeline
from neural_shdf.errors import ParameterError
from neural_shdf.evaluate.scores import (
    METRIC_NAMES,
    CutGraph,
    SegmentationScores,
    cut_distance_field,
    cut_graph,
    score_against_humans,
)
from neural_shdf.exchange.seg import read_labels
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import SegmentParams, segment
from neural_shdf.shdf.stage import resolve_method

#: Category names of the benchmark by ``(id - 1) // 20`` (13, Spring, is not in it).
CATEGORY_NAMES: dict[int, str] = {
    0: "Human", 1: "Cup", 2: "Glasses", 3: "Airplane", 4: "Ant", 5: "Chair",
    6: "Octopus", 7: "Table", 8: "Teddy", 9: "Hand", 10: "Plier", 11: "Fish",
    12: "Bird", 14: "Armadillo", 15: "Bust", 16: "Mech", 17: "Bearing",
    18: "Vase", 19: "Fourleg",
}  # fmt: skip

#: Where computed ShDF values are cached when no cache folder is given.
DEFAULT_CACHE_DIR = Path.home() / ".cache" / "neural-shdf" / "psb"
#: The benchmark's machines here have 2 cores: never more worker processes.
MAX_JOBS = 2

SHDF_SOURCES = ("exact", "sampled", "neural", "auto", "cgalsdf")
_METHOD_PATTERN = re.compile(
    r"^(exact|sampled|neural|auto|cgalsdf)-(graphcut|metis)(-humanparts|-leaves)?$"
)

#: A predictor: (mesh, model) -> one part label per triangle of ``mesh``.
Predictor = Callable[[TriangleMesh, "BenchModel"], NDArray]


@dataclass(frozen=True)
class BenchModel:
    """One benchmark model: its id, category, mesh file and human segmentations."""

    model_id: int
    bench_dir: Path
    human_paths: tuple[Path, ...]

    @property
    def category(self) -> int:
        return (self.model_id - 1) // 20

    @property
    def mesh_path(self) -> Path:
        return self.bench_dir / "off" / f"{self.model_id}.off"

    def human_segmentations(self) -> list[NDArray[np.int64]]:
        return [read_labels(path) for path in self.human_paths]

    def human_part_count(self) -> int:
        """The number of segments the humans used most often (ties: the smaller)."""
        counts = Counter(len(np.unique(seg)) for seg in self.human_segmentations())
        return min(counts, key=lambda parts: (-counts[parts], parts))


@dataclass(frozen=True)
class ModelResult:
    """Scores of one method on one model (mean over its human segmentations)."""

    model_id: int
    scores: SegmentationScores
    parts: int
    human_parts: int


@dataclass(frozen=True)
class MethodTable:
    """One method's results: per model, per category (mean of models), overall (of categories)."""

    method: str
    models: tuple[ModelResult, ...]

    def by_category(self) -> dict[int, SegmentationScores]:
        groups: dict[int, list[SegmentationScores]] = {}
        for result in self.models:
            groups.setdefault((result.model_id - 1) // 20, []).append(result.scores)
        return {cat: SegmentationScores.mean(groups[cat]) for cat in sorted(groups)}

    def overall(self) -> SegmentationScores:
        return SegmentationScores.mean(list(self.by_category().values()))

    def mean_parts(self) -> tuple[float, float]:
        """Mean number of parts of the method and of the humans' most frequent count."""
        return (
            float(np.mean([r.parts for r in self.models])),
            float(np.mean([r.human_parts for r in self.models])),
        )


EvalTable = dict[str, MethodTable]


def list_models(
    bench_dir: Path, limit: int | None = None, ids: Collection[int] | None = None
) -> list[BenchModel]:
    """Models of a PSB-layout folder that have a mesh and human segmentations, by id
    (only ``ids`` when given)."""
    bench_dir = Path(bench_dir)
    if not (bench_dir / "off").is_dir() or not (bench_dir / "seg").is_dir():
        raise ParameterError(f"{bench_dir} is not a benchmark folder: it needs off/ and seg/")
    models = []
    for path in sorted((bench_dir / "off").glob("*.off"), key=lambda p: (len(p.stem), p.stem)):
        if not path.stem.isdigit():
            continue
        if ids is not None and int(path.stem) not in ids:
            continue
        humans = tuple(sorted((bench_dir / "seg" / path.stem).glob("*.seg")))
        if humans:
            models.append(BenchModel(int(path.stem), bench_dir, humans))
    if limit is not None:
        models = models[:limit]
    if not models:
        raise ParameterError(f"no model with human segmentations in {bench_dir}")
    return models


def load_benchmark_mesh(path: Path) -> TriangleMesh:
    """The mesh through the project's loader."""
    return load_mesh(Path(path))


def _metric_mesh(mesh: TriangleMesh, path: Path) -> tuple[CutGraph, int]:
    """The cut graph over the file's own faces (what the human labels index)."""
    if mesh.face_count == mesh.input_face_count and np.array_equal(
        mesh.face_origin, np.arange(mesh.face_count)
    ):
        return cut_graph(mesh.vertices, mesh.faces), mesh.face_count
    import trimesh  # only for files whose faces were rewritten; the CLI's import stays light

    loaded = trimesh.load(path, process=False, force="mesh")
    return cut_graph(np.asarray(loaded.vertices), np.asarray(loaded.faces)), len(loaded.faces)


def _input_labels(mesh: TriangleMesh, labels: NDArray) -> NDArray[np.int64]:
    """Per-triangle labels to per-file-face labels; faces without a triangle form one segment."""
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    if len(labels) != mesh.face_count:
        raise ValueError(f"{len(labels)} labels for {mesh.face_count} triangles")
    return mesh.labels_to_input_faces(labels, missing=-1)


# ---------------------------------------------------------------- predictors


def cached_shdf(
    mesh: TriangleMesh, source: str, cache_dir: Path | None, model: BenchModel, seed: int = 0
) -> NDArray[np.float64]:
    """ShDF per triangle of ``mesh`` from ``source``; exact values are cached as .npy files.

    The cache key is the mesh's content hash and the seed, so a changed mesh
    or loader never reuses stale values.
    """
    if source == "cgalsdf":
        values = np.loadtxt(model.bench_dir / "cgal" / f"{model.model_id}.sdf", ndmin=1)
        return values[mesh.face_origin]
    if source == "auto":
        source = resolve_method(source, mesh.face_count)
    if source != "exact" or cache_dir is None:
        return pipeline.compute_shdf(mesh, method=source, seed=seed).values
    path = Path(cache_dir) / source / f"{model.model_id}-{mesh.content_hash()[:16]}-s{seed}.npy"
    if path.is_file():
        values = np.load(path)
        if len(values) == mesh.face_count:
            return values
    values = pipeline.compute_shdf(mesh, method="exact", seed=seed).values
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(f".{os.getpid()}.tmp.npy")
    np.save(temporary, values)
    temporary.replace(path)
    return values


@dataclass(frozen=True)
class CgalPredictor:
    """CGAL's segmentation from ``cgal/{id}.seg`` (per file face, mapped to triangles)."""

    def __call__(self, mesh: TriangleMesh, model: BenchModel) -> NDArray:
        labels = read_labels(model.bench_dir / "cgal" / f"{model.model_id}.seg")
        return labels[mesh.face_origin]


@dataclass(frozen=True)
class ShdfPredictor:
    """ShDF from ``source``, then ``segment`` with ``params``.

    ``human_parts``: the partitioner gets the humans' most frequent part count of the
    model; ``leaves``: every leaf of the graph cut's part tree.
    """

    source: str
    params: SegmentParams
    human_parts: bool = False
    cache_dir: Path | None = None
    leaves: bool = False

    def __call__(self, mesh: TriangleMesh, model: BenchModel) -> NDArray:
        shdf = cached_shdf(mesh, self.source, self.cache_dir, model, seed=self.params.seed)
        params = self.params
        if self.human_parts:
            params = dataclasses.replace(params, parts=model.human_part_count())
        result = segment(mesh, shdf, params)
        if self.leaves:
            return result.tree.leaf_labels
        return result.labels


def make_predictor(
    method: str,
    *,
    cache_dir: Path | None = DEFAULT_CACHE_DIR,
    params: Mapping[str, Any] | None = None,
) -> Predictor:
    """The predictor a method name stands for (see the module docstring).

    ``params``: SegmentParams fields overriding the automatic defaults (tuning).
    """
    if method == "cgal":
        return CgalPredictor()
    match = _METHOD_PATTERN.match(method)
    if match is None:
        raise ParameterError(
            f"unknown method {method!r}; use 'cgal' or '{{exact,sampled,neural,auto,cgalsdf}}-"
            "{graphcut,metis}', optionally followed by '-humanparts' or (graphcut) '-leaves'"
        )
    source, partitioner, suffix = match.groups()
    if suffix == "-leaves" and partitioner != "graphcut":
        raise ParameterError(f"{method}: -leaves needs the graphcut partitioner")
    segment_params = SegmentParams(partitioner=partitioner, **dict(params or {}))
    return ShdfPredictor(
        source, segment_params, suffix == "-humanparts", cache_dir, suffix == "-leaves"
    )


# ---------------------------------------------------------------- evaluation


def _evaluate_model(
    model: BenchModel, predictors: Mapping[str, Predictor]
) -> dict[str, ModelResult]:
    """All predictors on one model (the mesh, humans and their cut fields loaded once)."""
    mesh = load_benchmark_mesh(model.mesh_path)
    metric_mesh, face_count = _metric_mesh(mesh, model.mesh_path)
    humans = model.human_segmentations()
    for human in humans:
        if len(human) != face_count:
            raise ValueError(
                f"model {model.model_id}: a human segmentation has {len(human)} labels"
                f" for {face_count} faces"
            )
    fields = [cut_distance_field(metric_mesh, human) for human in humans]
    human_parts = model.human_part_count()
    results = {}
    for name, predict in predictors.items():
        labels = _input_labels(mesh, predict(mesh, model))
        scores = score_against_humans(metric_mesh, labels, humans, reference_fields=fields)
        results[name] = ModelResult(model.model_id, scores, len(np.unique(labels)), human_parts)
    return results


def evaluate_folder(
    bench_dir: Path,
    predictors: Mapping[str, Predictor] | Predictor,
    *,
    limit: int | None = None,
    jobs: int = 1,
    progress: Callable[[int, int], None] | None = None,
    ids: Collection[int] | None = None,
) -> EvalTable:
    """Score predictors on every model of a PSB-layout folder.

    ``predictors``: method name -> ``predict(mesh, model)`` returning a label
    per triangle of ``mesh`` (a bare callable is named ``"method"``); they must
    be picklable when ``jobs > 1``. ``jobs`` worker processes (at most 2).
    """
    if callable(predictors):
        predictors = {"method": predictors}
    models = list_models(Path(bench_dir), limit, ids)
    jobs = max(1, min(int(jobs), MAX_JOBS, len(models)))
    per_method: dict[str, list[ModelResult]] = {name: [] for name in predictors}

    def collect(done: int, result: dict[str, ModelResult]) -> None:
        for name, model_result in result.items():
            per_method[name].append(model_result)
        if progress is not None:
            progress(done, len(models))

    if jobs == 1:
        for done, model in enumerate(models, 1):
            collect(done, _evaluate_model(model, predictors))
    else:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            futures = [pool.submit(_evaluate_model, model, predictors) for model in models]
            for done, future in enumerate(futures, 1):
                collect(done, future.result())
    return {name: MethodTable(name, tuple(results)) for name, results in per_method.items()}


def run_eval(
    bench_dir: Path,
    methods: Sequence[str] = ("exact-graphcut",),
    *,
    limit: int | None = None,
    cache_dir: Path | str | None = None,
    jobs: int = 1,
    params: Mapping[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> EvalTable:
    """Evaluate named methods on a benchmark folder (the CLI's ``eval``).

    ``cache_dir``: where exact ShDF values are cached (default
    ``~/.cache/neural-shdf/psb``); ``params``: SegmentParams overrides for every
    ShDF method (tuning); ``jobs``: worker processes, at most 2.
    """
    cache = DEFAULT_CACHE_DIR if cache_dir is None else Path(cache_dir)
    predictors = {
        method: make_predictor(method, cache_dir=cache, params=params) for method in methods
    }
    return evaluate_folder(Path(bench_dir), predictors, limit=limit, jobs=jobs, progress=progress)


# ---------------------------------------------------------------- formatting

_HEADERS = {"cd": "CD", "hd": "HD", "rm": "Rm", "rf": "Rf", "ri_error": "1-RI",
            "gce": "GCE", "lce": "LCE"}  # fmt: skip


def _row(label: str, method: str, scores: SegmentationScores, width: int) -> str:
    cells = []
    for name in METRIC_NAMES:
        value = getattr(scores, name)
        cells.append(f"{'-':>6}" if math.isnan(value) else f"{value:6.3f}")
    return f"{label:<11} {method:<{width}} " + " ".join(cells)


def format_table(table: EvalTable, *, per_category: bool = True) -> str:
    """The table as text: per category (if asked) then overall, one row per method."""
    if not table:
        return "(no methods)"
    width = max(len("method"), *(len(name) for name in table))
    header = f"{'category':<11} {'method':<{width}} " + " ".join(
        f"{_HEADERS[n]:>6}" for n in METRIC_NAMES
    )
    lines = [header, "-" * len(header)]
    if per_category:
        categories = sorted({c for t in table.values() for c in t.by_category()})
        for category in categories:
            for name, method_table in table.items():
                scores = method_table.by_category().get(category)
                if scores is not None:
                    label = CATEGORY_NAMES.get(category, str(category))
                    lines.append(_row(label, name, scores, width))
        lines.append("-" * len(header))
    for name, method_table in table.items():
        lines.append(_row("OVERALL", name, method_table.overall(), width))
    lines.append("")
    first = next(iter(table.values()))
    lines.append(
        f"{len(first.models)} models, {len(first.by_category())} categories;"
        " overall = mean over categories of the mean over models of the mean over humans."
    )
    for name, method_table in table.items():
        parts, human = method_table.mean_parts()
        lines.append(f"mean parts {name}: {parts:.1f} (humans' most frequent: {human:.1f})")
    return "\n".join(lines)


def table_as_dict(table: EvalTable) -> dict[str, Any]:
    """JSON-ready: per method, overall, per category and per model scores."""
    return {
        name: {
            "overall": t.overall().as_dict(),
            "categories": {
                CATEGORY_NAMES.get(c, str(c)): s.as_dict() for c, s in t.by_category().items()
            },
            "models": {
                str(r.model_id): {
                    **r.scores.as_dict(),
                    "parts": r.parts,
                    "human_parts": r.human_parts,
                }
                for r in t.models
            },
        }
        for name, t in table.items()
    }
