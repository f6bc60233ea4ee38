"""Whole asset libraries: segment many files on a local process pool or a Dask cluster.

``run_batch(inputs, out_dir, ...)`` (and ``neural-shdf batch``) writes, per asset, the
requested outputs (``.seg`` labels and/or ``.shdf`` values, one line per input face, in
the input file's face order; optionally ``.colored.glb``, ``.parts.glb`` (keeping the
file's normals, UVs, colours, materials and objects) and ``.parts.usda`` (a USD input's
own stage with a GeomSubset per part; a new stage for other inputs)) next to a
small ``.batch.json`` record, then ``manifest.csv`` with one row per asset.

* Resumable: an asset whose record matches its file's content hash and the run's
  parameters, with every requested output present, is skipped (status ``skipped``).
  Every file is written to a temporary name and renamed, the record last, so a killed
  batch leaves no half-written output and never a record without its outputs.
* One bad asset never stops the batch: its row carries the same typed error as the CLI.
* Workers are long-lived processes (a local pool sized to the cores, or Dask workers):
  each loads the model and the compiled kernels once, on its first asset.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import os
import resource
import socket
import sys
import tempfile
import time
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, as_completed
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from tqdm import tqdm

from neural_shdf import __version__
from neural_shdf.constants import DEFAULT_MAX_FACES, DEFAULT_MAX_VERTICES
from neural_shdf.errors import (
    InvalidGeometryError,
    ModelUnavailableError,
    NeuralShdfError,
    ParameterError,
)
from neural_shdf.exchange.gltf_writer import colored_glb, parts_glb
from neural_shdf.exchange.seg import write_labels, write_values
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import SUPPORTED_FORMATS
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.processes import spawn_pool
from neural_shdf.segment import SegmentParams
from neural_shdf.segment.params import check_seed
from neural_shdf.shdf.neural.inference import load_model, model_path, set_session_threads
from neural_shdf.shdf.stage import resolve_method, uses_model
from neural_shdf.store.cache import CacheConfig, ResultCache, open_cache
from neural_shdf.store.codec import shdf_arrays, shdf_from_arrays
from neural_shdf.store.keys import model_version, shdf_key, shdf_version

#: Outputs a batch can write per asset, and their file suffixes.
OUTPUT_SUFFIXES = {
    "seg": ".seg",
    "shdf": ".shdf",
    "colored": ".colored.glb",
    "parts": ".parts.glb",
    "confidence": ".confidence",
    "usd": ".parts.usda",
}
#: Outputs that need a segmentation (everything but the ShDF).
SEGMENT_OUTPUTS = frozenset({"seg", "colored", "parts", "confidence", "usd"})
#: With a labeller: the label names of the run, written once beside the manifest.
LABEL_NAMES_NAME = "label_names.json"
RECORD_SUFFIX = ".batch.json"
MANIFEST_NAME = "manifest.csv"
MANIFEST_COLUMNS = (
    "path",
    "output",
    "status",
    "error_type",
    "error",
    "content_hash",
    "mesh_id",
    "faces",
    "triangles",
    "method",
    "parts",
    "seconds",
    "peak_memory_mb",
    "shdf_cached",
    "worker",
)
#: Extensions a folder scan picks up (the formats ``mesh_io`` reads).
MESH_EXTENSIONS = frozenset("." + name for name in SUPPORTED_FORMATS)
#: Extensions read as manifests: one path per line (``.txt``, ``.lst``) or a CSV with a
#: ``path`` column (``.csv``, e.g. an earlier batch's manifest).
MANIFEST_EXTENSIONS = frozenset({".txt", ".lst", ".csv"})
#: A local worker process that dies this many times while holding an asset fails it.
MAX_ATTEMPTS = 3


@dataclass(frozen=True)
class Asset:
    """One input file and the stem of its outputs, relative to the output folder."""

    path: str
    output: str


@dataclass(frozen=True)
class BatchConfig:
    """What every asset of a batch is computed with."""

    method: str = "auto"
    seed: int = 0
    params: SegmentParams = field(default_factory=SegmentParams)
    outputs: tuple[str, ...] = ("seg",)
    file_type: str | None = None
    max_faces: int | None = DEFAULT_MAX_FACES
    max_vertices: int | None = DEFAULT_MAX_VERTICES
    #: ShDF cache shared with the service: a ``redis://`` URL or a disk-cache folder.
    cache: str | None = None
    #: onnxruntime intra-op threads per worker (not part of the key: results do not
    #: depend on it); None: the library's default.
    session_threads: int | None = None
    #: A part labeller file (``labeling``): named parts instead of a segmentation, in the
    #: training labels' own integers; ``labeler_id``: its content id (part of the key).
    labeler: str | None = None
    labeler_id: str | None = None

    def __post_init__(self) -> None:
        unknown = sorted(set(self.outputs) - set(OUTPUT_SUFFIXES))
        if unknown or not self.outputs:
            raise ParameterError(
                f"unknown or no outputs {unknown or list(self.outputs)}; "
                f"choose from {', '.join(OUTPUT_SUFFIXES)}"
            )
        if "confidence" in self.outputs and self.labeler is None:
            raise ParameterError("the confidence output needs a labeller (--labeler)")

    @property
    def segments(self) -> bool:
        return bool(SEGMENT_OUTPUTS & set(self.outputs))

    def key(self) -> str:
        """Hash of everything the outputs depend on besides the input file."""
        version = model_version(model_path()) if uses_model(self.method) else None
        spec = {
            "version": __version__,
            "shdf": shdf_version(self.method, version, self.seed),
            "seed": self.seed,
            "params": dataclasses.asdict(self.params)
            if self.segments and self.labeler_id is None
            else None,
            "file_type": self.file_type,
        }
        if self.labeler_id is not None:  # absent otherwise: earlier runs' keys unchanged
            spec["labeler"] = self.labeler_id
        return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:20]


# -- inputs ---------------------------------------------------------------------


def _manifest_paths(manifest: Path) -> list[tuple[Path, Path]]:
    """(file, its output name) per listed path; relative paths are from the manifest."""
    text = manifest.read_text()
    if manifest.suffix.lower() == ".csv":
        reader = csv.DictReader(io.StringIO(text))
        if reader.fieldnames is None or "path" not in reader.fieldnames:
            raise ParameterError(f"manifest {manifest} has no 'path' column")
        names = [row["path"] for row in reader]
    else:
        names = [line.split("#", 1)[0].strip() for line in text.splitlines()]
    listed = [Path(name) for name in names if name]
    return [
        (manifest.parent / name, name if not name.is_absolute() and ".." not in name.parts
         else Path(name.name))
        for name in listed
    ]  # fmt: skip


def collect_assets(inputs: Iterable[str | Path]) -> list[Asset]:
    """Assets of files, folders (recursive, mesh extensions only) and manifests, in order.

    Output stems: a folder's files keep their path below the folder, a manifest's their
    path as listed, a file its name; the extension goes, unless two assets would collide.
    """
    found: list[tuple[Path, Path]] = []  # (file, path relative to its root, with extension)
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            files = sorted(
                p for p in path.rglob("*") if p.is_file() and p.suffix.lower() in MESH_EXTENSIONS
            )
            found.extend((p, p.relative_to(path)) for p in files)
        elif path.suffix.lower() in MANIFEST_EXTENSIONS and path.is_file():
            found.extend(_manifest_paths(path))
        else:  # a missing file is reported in its own row, not here
            found.append((path, Path(path.name)))
    stems = [relative.with_suffix("") for _, relative in found]
    counts: dict[Path, int] = {}
    for stem in stems:
        counts[stem] = counts.get(stem, 0) + 1
    assets, taken = [], set()
    for (path, relative), stem in zip(found, stems, strict=True):
        name = stem if counts[stem] == 1 else relative
        candidate, n = name, 1
        while candidate.as_posix() in taken:
            n += 1
            candidate = name.with_name(f"{name.name}~{n}")
        taken.add(candidate.as_posix())
        assets.append(Asset(str(path), candidate.as_posix()))
    return assets


# -- one asset (runs in a worker process) ------------------------------------------


def file_hash(path: str | Path) -> str:
    """SHA-256 of the file's bytes."""
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


def _reset_peak_memory() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")  # Linux: reset the peak RSS
        return True
    except OSError:
        return False


def _peak_memory_mb(reset: bool) -> float:
    if reset:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return round(int(line.split()[1]) / 1024, 1)
    return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)


def _umask() -> int:
    mask = os.umask(0o22)
    os.umask(mask)
    return mask


#: File mode of outputs: what ``open()`` would give (mkstemp's own is 0600).
_FILE_MODE = 0o666 & ~_umask()


def _write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """``write(temporary)`` then rename over ``path``: readers never see a partial file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(handle)
    try:
        os.chmod(temporary, _FILE_MODE)
        write(Path(temporary))
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def _write_bytes_atomic(path: Path, data: bytes) -> None:
    _write_atomic(path, lambda temporary: temporary.write_bytes(data))


_CACHES: dict[str, tuple[ResultCache, CacheConfig]] = {}


def _shared_cache(cache: str) -> tuple[ResultCache, CacheConfig]:
    """The cache shared with the service (``cache``: a Redis URL or a disk-cache folder;
    the other store settings from the service's environment variables), one per worker
    process and cache."""
    opened = _CACHES.get(cache)
    if opened is None:
        where = {"redis_url": cache} if "://" in cache else {"cache_dir": Path(cache)}
        # No in-process memory: a worker sees each mesh once.
        config = CacheConfig.from_environment(
            **where, memory_cache_items=0, memory_working_set_bytes=0
        )
        opened = _CACHES[cache] = (open_cache(config), config)
    return opened


def shared_shdf(
    cache: str, mesh_id: str, mesh: TriangleMesh, method: str, seed: int
) -> tuple[NDArray[np.float64], str, bool]:
    """(ShDF, the producer that ran, whether it was cached): read from the cache shared
    with the service under the service's key (``store.keys.shdf_key``), else computed
    once across workers and replicas and stored there for them."""
    store, config = _shared_cache(cache)
    seed = check_seed(seed)
    method = resolve_method(method, mesh.face_count)
    version = model_version(model_path()) if uses_model(method) else None
    key = shdf_key(mesh_id, method, seed, version)

    def lookup() -> NDArray[np.float64] | None:
        return store.recall_arrays(key, shdf_from_arrays)

    def compute() -> NDArray[np.float64]:
        values = compute_shdf(mesh, method=method, seed=seed).values  # type: ignore[arg-type]
        return np.ascontiguousarray(values, dtype=np.float64)

    def keep(values: NDArray[np.float64], _: None) -> None:
        store.put_arrays(key, shdf_arrays(values), group=mesh_id)

    found = lookup()
    if found is not None:
        return found, method, True
    outcome: tuple[NDArray[np.float64], bool] = store.compute_once(
        key, lookup, compute, keep, wait_s=config.lock_timeout_s
    )
    return outcome[0], method, outcome[1]


_LABELERS: dict[tuple[str, str], Any] = {}


def _worker_labeler(config: BatchConfig) -> Any:
    """The run's labeller, loaded once per worker process (and checked to be the file
    the run was started with: its content id)."""
    from neural_shdf.labeling import labeler_id, load_labeler

    assert config.labeler is not None and config.labeler_id is not None
    key = (config.labeler, config.labeler_id)
    if key not in _LABELERS:
        labeler = load_labeler(config.labeler)
        if labeler_id(labeler) != config.labeler_id:
            raise ParameterError(f"the labeller file {config.labeler} changed during the batch")
        _LABELERS[key] = labeler
    return _LABELERS[key]


def _row(asset: Asset, **values: Any) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(MANIFEST_COLUMNS, "")
    row.update(path=asset.path, output=asset.output)
    row.update(values)
    return row


def output_paths(out_dir: Path, asset: Asset, outputs: Iterable[str]) -> dict[str, Path]:
    return {name: out_dir / (asset.output + OUTPUT_SUFFIXES[name]) for name in outputs}


_PREPARED: list[int | None] = []


def _prepare_worker(config: BatchConfig) -> None:
    """Once per worker process, before its model loads: its session threads."""
    if not _PREPARED:
        if config.session_threads is not None:
            set_session_threads(config.session_threads)
        _PREPARED.append(config.session_threads)


def process_asset(asset: Asset, out_dir: str, config: BatchConfig, key: str) -> dict[str, Any]:
    """Compute and write one asset's outputs and record; its manifest row. Never raises for
    a bad asset: the row says what is wrong (the CLI's typed errors)."""
    _prepare_worker(config)
    start = time.perf_counter()
    reset = _reset_peak_memory()
    try:
        row = _process(asset, Path(out_dir), config, key)
        row["status"] = "ok"
    except (NeuralShdfError, OSError) as error:
        row = _row(asset, status="failed", error_type=type(error).__name__, error=str(error))
    except MemoryError:
        row = _row(asset, status="failed", error_type="MemoryError", error="out of memory")
    except Exception as error:  # noqa: BLE001 - an unexpected failure stays one asset's
        row = _row(
            asset, status="failed", error_type=type(error).__name__, error=f"unexpected: {error}"
        )
    row["seconds"] = round(time.perf_counter() - start, 4)
    row["peak_memory_mb"] = _peak_memory_mb(reset)
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    if row["status"] == "ok":
        record = {"key": key, "content_hash": row["content_hash"], "row": row}
        path = Path(out_dir) / (asset.output + RECORD_SUFFIX)
        _write_bytes_atomic(path, json.dumps(record, indent=1).encode())
    return row


def _process(asset: Asset, out_dir: Path, config: BatchConfig, key: str) -> dict[str, Any]:
    from neural_shdf.exchange.gltf_writer import colored_glb, parts_glb
    from neural_shdf.mesh_io import load_source

    path = Path(asset.path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    content_hash = file_hash(path)
    source = load_source(
        path, config.file_type, max_faces=config.max_faces, max_vertices=config.max_vertices
    )
    mesh = source.mesh
    if mesh.face_count == 0:
        raise InvalidGeometryError(f"{path}: the mesh has no triangles")
    mesh_id = mesh.content_hash()
    cached = False
    if config.cache:
        shdf, method, cached = shared_shdf(config.cache, mesh_id, mesh, config.method, config.seed)
    else:
        result = compute_shdf(mesh, method=config.method, seed=config.seed)  # type: ignore[arg-type]
        shdf, method = result.values, result.method
    paths = output_paths(out_dir, asset, config.outputs)
    if "shdf" in paths:
        values = mesh.to_input_faces(shdf)
        _write_atomic(paths["shdf"], lambda temporary: write_values(temporary, values))
    parts: int | str = ""
    if config.labeler is not None and config.segments:
        parts = _write_named_parts(mesh, shdf, paths, config)
    elif config.segments:
        labels = segment(mesh, shdf, config.params).labels
        parts = int(labels.max()) + 1 if len(labels) else 0
        if "seg" in paths:
            per_face = mesh.labels_to_input_faces(labels)
            _write_atomic(paths["seg"], lambda temporary: write_labels(temporary, per_face))
        if "colored" in paths:
            _write_bytes_atomic(paths["colored"], colored_glb(mesh, labels))
        if "parts" in paths:
            glb = parts_glb(mesh, labels, attributes=source.attributes)
            _write_bytes_atomic(paths["parts"], glb)
        if "usd" in paths:
            _write_bytes_atomic(paths["usd"], _parts_usda(path, config.file_type, mesh, labels))
    return _row(
        asset,
        content_hash=content_hash,
        mesh_id=mesh_id,
        faces=mesh.input_face_count,
        triangles=mesh.face_count,
        method=method,
        parts=parts,
        shdf_cached=cached,
    )


def _write_named_parts(
    mesh: TriangleMesh, shdf: NDArray, paths: dict[str, Path], config: BatchConfig
) -> int:
    """Label one asset with the run's labeller and write its outputs; the labels present."""
    from neural_shdf.labeling import label_mesh

    labeler = _worker_labeler(config)
    per_face, confidence = label_mesh(mesh, labeler, shdf=shdf)
    triangles = per_face[mesh.face_origin]
    names = dict(zip(labeler.label_values.tolist(), labeler.label_names, strict=True))
    if "seg" in paths:
        _write_atomic(paths["seg"], lambda temporary: write_labels(temporary, per_face))
    if "confidence" in paths:
        _write_atomic(paths["confidence"], lambda temporary: write_values(temporary, confidence))
    if "colored" in paths:
        _write_bytes_atomic(paths["colored"], colored_glb(mesh, triangles))
    if "parts" in paths:
        _write_bytes_atomic(paths["parts"], parts_glb(mesh, triangles, names=names))
    return len(np.unique(per_face[per_face >= 0]))


def write_label_names(out_dir: Path, labeler_file: str) -> tuple[str, Path]:
    """Check the labeller (before any asset is read) and write ``label_names.json``
    (its id, and each label's integer and name); (its id, that file)."""
    from neural_shdf.labeling import labeler_id, load_labeler
    from neural_shdf.labeling.labeler import check_compatible

    labeler = load_labeler(labeler_file)
    check_compatible(labeler)
    identifier = labeler_id(labeler)
    document = {
        "labeler_id": identifier,
        "labels": [
            {"value": int(value), "name": name}
            for value, name in zip(labeler.label_values, labeler.label_names, strict=True)
        ],
    }
    path = out_dir / LABEL_NAMES_NAME
    _write_bytes_atomic(path, (json.dumps(document, indent=1) + "\n").encode())
    return identifier, path


def _parts_usda(path: Path, file_type: str | None, mesh: TriangleMesh, labels: NDArray) -> bytes:
    """The parts as a .usda layer: a USD input's own stage with subsets, else a new stage."""
    from neural_shdf.exchange.usd import USD_EXTENSIONS, mesh_parts_usda, usd_parts_usda
    from neural_shdf.mesh_io import detect_format, normalize_format

    kind = normalize_format(file_type) if file_type else detect_format(path)
    per_face = mesh.labels_to_input_faces(labels)
    if kind in USD_EXTENSIONS:
        return usd_parts_usda(path.read_bytes(), kind, per_face)
    return mesh_parts_usda(mesh, per_face)


def finished_row(asset: Asset, out_dir: Path, config: BatchConfig, key: str) -> dict | None:
    """The recorded row when the asset is done for this content and these parameters."""
    record_path = out_dir / (asset.output + RECORD_SUFFIX)
    try:
        record = json.loads(record_path.read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("key") != key:
        return None
    if not all(p.is_file() for p in output_paths(out_dir, asset, config.outputs).values()):
        return None
    try:
        if file_hash(asset.path) != record.get("content_hash"):
            return None
    except OSError:
        return None
    row = _row(asset, **{k: v for k, v in record["row"].items() if k in MANIFEST_COLUMNS})
    row.update(path=asset.path, output=asset.output, status="skipped")
    return row


# -- runners ------------------------------------------------------------------------

Task = tuple[int, Asset]
OnRow = Callable[[int, dict[str, Any]], None]


def _worker_died_row(asset: Asset, why: str) -> dict[str, Any]:
    return _row(asset, status="failed", error_type="WorkerDied", error=why)


def _run_in_process(tasks: list[Task], out_dir: str, config: BatchConfig, key: str,
                    on_row: OnRow) -> None:  # fmt: skip
    for index, asset in tasks:
        on_row(index, process_asset(asset, out_dir, config, key))


def _run_local_pool(tasks: list[Task], out_dir: str, config: BatchConfig, key: str,
                    on_row: OnRow, workers: int) -> None:  # fmt: skip
    """A process pool; a worker that dies (a crash, out of memory) is replaced and the
    assets it may have held are retried, each at most ``MAX_ATTEMPTS`` times."""
    attempts = dict.fromkeys((index for index, _ in tasks), 0)
    pending = list(tasks)
    while pending:
        broken: list[Task] = []
        with spawn_pool(workers) as pool:  # workers end with this process, however it ends
            futures: dict[Future, Task] = {
                pool.submit(process_asset, asset, out_dir, config, key): (index, asset)
                for index, asset in pending
            }
            for future in as_completed(futures):
                index, asset = futures[future]
                try:
                    on_row(index, future.result())
                except BrokenProcessPool:
                    broken.append((index, asset))
        pending = []
        for index, asset in broken:
            attempts[index] += 1
            if attempts[index] >= MAX_ATTEMPTS:
                why = "the worker process died on this asset (crash or out of memory)"
                on_row(index, _worker_died_row(asset, why))
            else:
                pending.append((index, asset))


def _run_dask(tasks: list[Task], out_dir: str, config: BatchConfig, key: str,
              on_row: OnRow, scheduler: Any) -> None:  # fmt: skip
    """The same tasks on Dask distributed; a worker that dies has its tasks rescheduled
    by the scheduler (up to its ``allowed-failures``)."""
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:  # pragma: no cover - depends on the install
        raise ParameterError(
            "--scheduler needs Dask distributed: pip install 'neural-shdf[distributed]'"
        ) from None

    if isinstance(scheduler, Client):
        client = scheduler
    else:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError, ValueError) as error:
            raise ParameterError(f"cannot reach the Dask scheduler {scheduler}: {error}") from error
    # Task names unique to this run: Dask hands a finished result still held under the same
    # name (an earlier batch into another folder) back instead of running the task.
    run_id = uuid.uuid4().hex[:12]
    try:
        futures = {
            client.submit(
                process_asset, asset, out_dir, config, key,
                key=f"neural-shdf-asset-{key}-{run_id}-{index}", pure=False, retries=0,
            ): (index, asset)
            for index, asset in tasks
        }  # fmt: skip
        for future in dask_completed(futures):
            index, asset = futures[future]
            try:
                on_row(index, future.result())
            except Exception as error:  # noqa: BLE001 - e.g. KilledWorker after retries
                on_row(index, _worker_died_row(asset, f"{type(error).__name__}: {error}"))
            future.release()
    finally:
        if client is not scheduler:
            client.close()


# -- progress and manifest -------------------------------------------------------------


class BatchProgress:
    """A tqdm bar on stderr: assets done, failures, faces per second, ETA."""

    def __init__(self, total: int, enabled: bool) -> None:
        self.failed = 0
        self.faces = 0
        self.start = time.perf_counter()
        self.bar = tqdm(
            total=total,
            desc="assets",
            unit="asset",
            disable=not enabled,
            file=sys.stderr,
            dynamic_ncols=True,
            bar_format="{desc}: {n}/{total} |{bar}| {elapsed}<{remaining} {postfix}",
        )

    def update(self, row: dict[str, Any]) -> None:
        if row["status"] == "failed":
            self.failed += 1
        elif row["status"] == "ok" and row["faces"] != "":
            self.faces += int(row["faces"])
        rate = self.faces / max(time.perf_counter() - self.start, 1e-9)
        self.bar.set_postfix_str(f"failed {self.failed}, {rate:,.0f} faces/s", refresh=False)
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()


def write_manifest(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """The manifest as CSV, one row per asset in input order (written atomically)."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=MANIFEST_COLUMNS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    _write_bytes_atomic(path, buffer.getvalue().encode())


def _check_model(config: BatchConfig) -> None:
    """Fail the whole batch up front when the neural model cannot load (every asset would)."""
    if uses_model(config.method):
        try:
            load_model()
        except ModelUnavailableError:
            raise
        except Exception as error:  # noqa: BLE001 - reported as the typed error
            raise ModelUnavailableError(f"the neural model cannot be loaded: {error}") from error


def default_workers() -> int:
    """The cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def run_batch(
    inputs: Iterable[str | Path],
    out_dir: str | Path,
    *,
    method: str = "auto",
    seed: int | None = None,
    params: SegmentParams | None = None,
    outputs: Sequence[str] = ("seg",),
    file_type: str | None = None,
    max_faces: int | None = DEFAULT_MAX_FACES,
    max_vertices: int | None = DEFAULT_MAX_VERTICES,
    cache: str | None = None,
    workers: int | None = None,
    scheduler: Any = None,
    progress: bool = False,
    manifest: bool = True,
    labeler: str | Path | None = None,
) -> list[dict[str, Any]]:
    """Segment (or compute the ShDF of) every input; the manifest rows, in input order.

    Args:
        inputs: mesh files, folders (searched recursively) and manifests (.txt/.lst: one
            path per line; .csv: a ``path`` column), relative paths from the manifest.
        out_dir: where outputs, records and ``manifest.csv`` go.
        seed: seed of the ShDF and the segmentation (default: ``params.seed``).
        outputs: any of ``seg``, ``shdf``, ``colored``, ``parts``.
        cache: ShDF cache shared with the service (``redis://...`` or a folder); the other
            store settings from the service's variables (``store.cache.CacheConfig``).
        workers: local worker processes (default: one per core; 0: in this process).
        scheduler: a Dask scheduler address (``tcp://host:port``) or ``distributed.Client``;
            the workers must see the same paths.
        progress: show a progress bar on stderr.
        labeler: a part labeller file: named parts instead of a segmentation (``seg``: the
            training labels' own integers per input face; ``confidence``: added beside
            ``seg``; ``parts``: nodes named by label) and ``label_names.json`` in
            ``out_dir``. Checked before any asset is read.
    """
    # One seed for the ShDF and the segmentation (the CLI's convention): ``seed``, else
    # ``params.seed``.
    params = params or SegmentParams()
    seed = params.seed if seed is None else seed
    config = BatchConfig(
        method=method,
        seed=seed,
        params=dataclasses.replace(params, seed=seed),
        outputs=tuple(dict.fromkeys(outputs)),
        file_type=file_type,
        max_faces=max_faces,
        max_vertices=max_vertices,
        cache=cache,
    )
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.rglob(".*.tmp"):  # left by a killed run (one batch per folder at a time)
        stale.unlink(missing_ok=True)
    if labeler is not None:
        identifier, _ = write_label_names(out, str(labeler))
        named = config.outputs + (("confidence",) if "seg" in config.outputs else ())
        config = dataclasses.replace(
            config,
            labeler=str(Path(labeler).resolve()),
            labeler_id=identifier,
            outputs=tuple(dict.fromkeys(named)),
        )
    assets = collect_assets(inputs)
    key = config.key()
    rows: list[dict[str, Any] | None] = [None] * len(assets)
    bar = BatchProgress(len(assets), progress)

    def on_row(index: int, row: dict[str, Any]) -> None:
        rows[index] = row
        bar.update(row)

    try:
        todo: list[Task] = []
        for index, asset in enumerate(assets):
            done = finished_row(asset, out, config, key)
            if done is None:
                todo.append((index, asset))
            else:
                on_row(index, done)
        if todo:
            _check_model(config)
        # Largest files first: the pool's last minutes are not one big mesh alone.
        todo.sort(key=lambda task: -_size(task[1].path))
        workers = default_workers() if workers is None else workers
        if scheduler is not None:  # one task per Dask worker thread: one session thread
            config = dataclasses.replace(config, session_threads=1)
            _run_dask(todo, str(out), config, key, on_row, scheduler)
        elif workers <= 0 or len(todo) <= 1:
            _run_in_process(todo, str(out), config, key, on_row)
        else:
            workers = min(workers, len(todo))
            threads = max(1, default_workers() // workers)
            config = dataclasses.replace(config, session_threads=threads)
            _run_local_pool(todo, str(out), config, key, on_row, workers)
    finally:
        bar.close()
        finished = [row for row in rows if row is not None]
        if manifest:
            write_manifest(out / MANIFEST_NAME, finished)
    return finished


def _size(path: str) -> int:
    try:
        return os.path.getsize(path)
    except OSError:
        return 0


def summary(rows: Sequence[dict[str, Any]]) -> dict[str, int]:
    """Assets per status."""
    counts = {"ok": 0, "skipped": 0, "failed": 0}
    for row in rows:
        counts[row["status"]] = counts.get(row["status"], 0) + 1
    return counts


def iter_failures(rows: Iterable[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    return (row for row in rows if row["status"] == "failed")
