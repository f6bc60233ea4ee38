"""The batch command: same outputs as the CLI, resumable, one bad asset never stops it."""

from __future__ import annotations

import csv
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import pytest
import trimesh

from neural_shdf.batch import MANIFEST_COLUMNS, collect_assets, run_batch
from neural_shdf.cli import EXIT_BAD_INPUT, main
from neural_shdf.segment import SegmentParams
from tests.api.api_helpers import TEST_METHOD
from tests.conftest import REPO_ROOT
from tests.test_processes import gone_within


def _shape(index: int) -> trimesh.Trimesh:
    """Small varied shapes: capsules and dumbbells of different proportions."""
    if index % 2 == 0:
        return trimesh.creation.capsule(height=1.0 + index * 0.3, radius=0.4, count=(10, 10))
    left = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    right = trimesh.creation.icosphere(subdivisions=2, radius=0.6 + 0.1 * index)
    left.apply_translation([-2.5, 0, 0])
    right.apply_translation([2.5, 0, 0])
    bar = trimesh.creation.cylinder(radius=0.25, height=3.5, sections=16)
    bar.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    return trimesh.util.concatenate([left, bar, right])


def _library(root: Path, count: int, bad: int = 0) -> Path:
    """``count`` good meshes in mixed formats (two folder levels) and ``bad`` corrupt files."""
    formats = ("obj", "off", "ply", "stl")
    for i in range(count):
        folder = root / ("sub" if i % 3 == 0 else "") / ("deep" if i % 6 == 0 else "")
        folder.mkdir(parents=True, exist_ok=True)
        _shape(i).export(folder / f"mesh{i:03d}.{formats[i % len(formats)]}")
    for i in range(bad):
        (root / f"broken{i}.obj").write_text("v 0 0 0\nf 1 2 3\n" if i % 2 else "not a mesh\n")
    return root


def _rows(out: Path) -> list[dict[str, str]]:
    with open(out / "manifest.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def _outputs(out: Path) -> dict[str, bytes]:
    """Every output file's bytes (records and the manifest hold timings: left out)."""
    return {
        p.relative_to(out).as_posix(): p.read_bytes()
        for p in sorted(out.rglob("*"))
        if p.is_file() and not p.name.endswith((".batch.json", "manifest.csv"))
    }


def test_outputs_are_the_cli_outputs_byte_for_byte(tmp_path: Path):
    _library(tmp_path / "in", 2)
    rows = run_batch(
        [tmp_path / "in"],
        tmp_path / "out",
        method=TEST_METHOD,
        params=SegmentParams(clusters=4),
        outputs=["seg", "shdf", "colored", "parts", "usd"],
        workers=0,
    )
    assert [r["status"] for r in rows] == ["ok", "ok"]
    for row in rows:
        mesh, stem = Path(row["path"]), tmp_path / "out" / row["output"]
        cli = tmp_path / "cli"
        cli.mkdir(exist_ok=True)
        args = ["--method", TEST_METHOD, "-q"]
        assert main(["segment", str(mesh), "-o", str(cli / "a.seg"), "--clusters", "4",
                     "--colored", str(cli / "a.glb"), "--parts-glb", str(cli / "p.glb"),
                     "--usd", str(cli / "p.usda"), *args]) == 0  # fmt: skip
        assert main(["shdf", str(mesh), "-o", str(cli / "a.shdf"), *args]) == 0
        assert (cli / "a.seg").read_bytes() == Path(f"{stem}.seg").read_bytes()
        assert (cli / "a.shdf").read_bytes() == Path(f"{stem}.shdf").read_bytes()
        assert (cli / "a.glb").read_bytes() == Path(f"{stem}.colored.glb").read_bytes()
        assert (cli / "p.glb").read_bytes() == Path(f"{stem}.parts.glb").read_bytes()
        assert (cli / "p.usda").read_bytes() == Path(f"{stem}.parts.usda").read_bytes()
        faces = len(Path(f"{stem}.seg").read_text().split())
        assert faces == row["faces"] == len(trimesh.load(mesh, process=False).faces)
        assert row["parts"] == len(set(Path(f"{stem}.seg").read_text().split()))


def test_collects_folders_recursively_manifests_and_keeps_names_apart(tmp_path: Path):
    _library(tmp_path / "lib", 7)
    (tmp_path / "lib" / "notes.txt").write_text("not a mesh")
    (tmp_path / "x.off").write_text("OFF\n")
    (tmp_path / "x.obj").write_text("")
    (tmp_path / "list.txt").write_text("# comment\nlib/mesh001.off\n\nx.obj\n")
    (tmp_path / "rows.csv").write_text("path,faces\nlib/mesh002.ply,3\n")
    assets = collect_assets(
        [tmp_path / "lib", tmp_path / "x.off", tmp_path / "list.txt", tmp_path / "rows.csv"]
    )
    outputs = [a.output for a in assets]
    assert outputs[:7] == [
        "mesh001", "mesh002", "mesh004", "mesh005", "sub/deep/mesh000", "sub/deep/mesh006",
        "sub/mesh003",
    ]  # fmt: skip
    # x.off and x.obj keep their extensions; a second mesh001 gets a number.
    assert outputs[7:] == ["x.off", "lib/mesh001", "x.obj", "lib/mesh002"]
    assert len(set(outputs)) == len(outputs)


def test_a_folder_scan_picks_up_every_format_the_readers_take(tmp_path: Path):
    from neural_shdf.mesh_io import SUPPORTED_FORMATS

    for name in SUPPORTED_FORMATS:
        (tmp_path / f"mesh.{name}").write_text("")
    (tmp_path / "mesh.fbx").write_text("")
    found = sorted(Path(asset.path).suffix[1:] for asset in collect_assets([tmp_path]))
    assert found == sorted(SUPPORTED_FORMATS)  # USD included, FBX (refused) left out


def test_bad_assets_are_reported_and_the_rest_is_done(tmp_path: Path):
    _library(tmp_path / "in", 3, bad=2)
    listing = tmp_path / "list.txt"
    listing.write_text("in/sub/deep/mesh000.obj\nmissing.obj\nin/broken0.obj\n")
    code = main(["batch", str(tmp_path / "in"), str(listing), "-o", str(tmp_path / "out"),
                 "--method", "exact", "--workers", "2", "-q"])  # fmt: skip
    assert code == EXIT_BAD_INPUT
    rows = _rows(tmp_path / "out")
    assert list(rows[0]) == list(MANIFEST_COLUMNS)
    assert len(rows) == 8
    failed = {r["path"]: r for r in rows if r["status"] == "failed"}
    assert {Path(p).name for p in failed} == {"broken0.obj", "broken1.obj", "missing.obj"}
    assert {r["error_type"] for r in failed.values()} == {
        "MeshParseError", "InvalidGeometryError", "FileNotFoundError"
    }  # fmt: skip
    assert all(r["error"] for r in failed.values())
    assert sum(r["status"] == "ok" for r in rows) == 4  # mesh000 twice (folder and list)
    assert {r["method"] for r in rows if r["status"] == "ok"} == {"exact"}
    assert not list((tmp_path / "out").rglob("*.tmp"))
    # Only good meshes have outputs, one label per input face.
    for row in rows:
        seg = tmp_path / "out" / f"{row['output']}.seg"
        assert seg.is_file() == (row["status"] == "ok")
        if seg.is_file():
            assert len(seg.read_text().split()) == int(row["faces"])


def test_rerun_skips_finished_assets_and_redoes_changed_ones(tmp_path: Path):
    _library(tmp_path / "in", 3)
    first = run_batch([tmp_path / "in"], tmp_path / "out", method="exact", workers=0)
    assert [r["status"] for r in first] == ["ok"] * 3
    before = _outputs(tmp_path / "out")
    again = run_batch([tmp_path / "in"], tmp_path / "out", method="exact", workers=0)
    assert [r["status"] for r in again] == ["skipped"] * 3
    assert [r["faces"] for r in again] == [r["faces"] for r in first]
    assert _outputs(tmp_path / "out") == before
    # A changed file, new parameters or a missing output are recomputed.
    _shape(5).export(tmp_path / "in" / "mesh001.off")
    (tmp_path / "out" / "mesh002.seg").unlink()
    rows = run_batch([tmp_path / "in"], tmp_path / "out", method="exact", workers=0)
    assert [r["status"] for r in rows] == ["ok", "ok", "skipped"]
    rows = run_batch(
        [tmp_path / "in"], tmp_path / "out", method="exact", workers=0,
        params=SegmentParams(partitioner="metis", parts=3),
    )  # fmt: skip
    assert [r["status"] for r in rows] == ["ok"] * 3
    assert all(r["parts"] == 3 for r in rows)


def test_killed_batch_leaves_whole_files_and_rerun_redoes_nothing_finished(tmp_path: Path):
    _library(tmp_path / "in", 8)
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": f"{REPO_ROOT / 'service'}:{REPO_ROOT}"}
    command = [sys.executable, "-m", "neural_shdf.cli", "batch", str(tmp_path / "in"),
               "-o", str(out), "--method", TEST_METHOD, "--workers", "2", "-q"]  # fmt: skip
    process = subprocess.Popen(command, env=env, start_new_session=True)
    deadline = time.monotonic() + 120
    while len(list(out.rglob("*.batch.json"))) < 3 and time.monotonic() < deadline:
        assert process.poll() is None, "the batch ended before it could be killed"
        time.sleep(0.05)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    finished = {p.name for p in out.rglob("*.batch.json")}
    assert 3 <= len(finished) < 8
    for record in out.rglob("*.batch.json"):  # a record is only written after its outputs
        seg = record.with_name(record.name.replace(".batch.json", ".seg"))
        row = json.loads(record.read_text())["row"]
        assert len(seg.read_text().split()) == row["faces"]
    assert main([*command[3:]]) == 0
    rows = _rows(out)
    assert sum(r["status"] == "skipped" for r in rows) == len(finished)
    assert sum(r["status"] == "ok" for r in rows) == 8 - len(finished)
    assert not list(out.rglob("*.tmp"))


def test_workers_of_a_killed_batch_end_with_it(tmp_path: Path):
    """Only the batch process killed (the OOM killer picks the largest, not the group):
    its pool's workers end by themselves rather than wait for work for ever."""
    _library(tmp_path / "in", 8)
    env = {**os.environ, "PYTHONPATH": f"{REPO_ROOT / 'service'}:{REPO_ROOT}"}
    out = tmp_path / "out"
    command = [sys.executable, "-m", "neural_shdf.cli", "batch", str(tmp_path / "in"),
               "-o", str(out), "--method", TEST_METHOD, "--workers", "2", "-q"]  # fmt: skip
    process = subprocess.Popen(command, env=env, start_new_session=True)
    try:
        batch = psutil.Process(process.pid)
        deadline = time.monotonic() + 120
        while len(workers := _pool_workers(batch)) < 2:
            assert process.poll() is None, "the batch ended before it could be killed"
            assert time.monotonic() < deadline, "the batch started no workers"
            time.sleep(0.05)
        process.kill()
        process.wait()
        assert [w.pid for w in workers if not gone_within(w, 5.0)] == []
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def _pool_workers(process: psutil.Process) -> list[psutil.Process]:
    """The spawned pool workers among ``process``'s children."""
    try:
        children = process.children()
        return [c for c in children if "spawn_main" in " ".join(c.cmdline())]
    except psutil.NoSuchProcess:
        return []


# -- Dask distributed: a real LocalCluster of 2 worker processes ------------------------


@pytest.fixture(scope="module")
def library(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _library(tmp_path_factory.mktemp("library"), 8, bad=1)


@pytest.fixture(scope="module")
def local_outputs(library: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    out = tmp_path_factory.mktemp("local")
    rows = run_batch([library], out, method=TEST_METHOD, outputs=["seg", "shdf"], workers=2)
    assert [r["status"] for r in rows].count("ok") == 8
    return _outputs(out)


@pytest.fixture(scope="module")
def dask_client() -> Iterator[Any]:
    distributed = pytest.importorskip("distributed")
    cluster = distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=logging.ERROR,
    )
    client = distributed.Client(cluster)
    try:
        yield client
    finally:
        client.close()
        cluster.close()


@pytest.mark.slow
def test_dask_cluster_writes_the_local_outputs_byte_for_byte(
    library: Path, local_outputs: dict[str, bytes], dask_client: Any, tmp_path: Path
):
    rows = run_batch([library], tmp_path, method=TEST_METHOD, outputs=["seg", "shdf"],
                     scheduler=dask_client)  # fmt: skip
    assert [r["status"] for r in rows].count("ok") == 8
    assert [r["error_type"] for r in rows if r["status"] == "failed"] == ["MeshParseError"]
    assert _outputs(tmp_path) == local_outputs
    # Both worker processes took part.
    assert len({r["worker"] for r in rows}) == 2


@pytest.mark.slow
def test_two_batches_on_one_cluster_each_write_their_own_outputs(
    library: Path, local_outputs: dict[str, bytes], dask_client: Any, tmp_path: Path
):
    """The same assets and parameters into two folders at once on one cluster: each batch
    runs its own tasks (Dask shares a result between tasks submitted under one name)."""
    folders = [tmp_path / "first", tmp_path / "second"]
    rows: dict[Path, list] = {}

    def run(folder: Path) -> None:
        rows[folder] = run_batch([library], folder, method=TEST_METHOD, outputs=["seg", "shdf"],
                                 scheduler=dask_client)  # fmt: skip

    threads = [threading.Thread(target=run, args=(folder,)) for folder in folders]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=300)
    for folder in folders:
        assert [r["status"] for r in rows[folder]].count("ok") == 8
        assert _outputs(folder) == local_outputs


@pytest.mark.slow
def test_a_worker_killed_mid_run_has_its_assets_retried_elsewhere(
    library: Path, local_outputs: dict[str, bytes], dask_client: Any, tmp_path: Path
):
    result: dict[str, Any] = {}

    def run() -> None:
        result["rows"] = run_batch([library], tmp_path, method=TEST_METHOD,
                                   outputs=["seg", "shdf"], scheduler=dask_client)  # fmt: skip

    thread = threading.Thread(target=run)
    thread.start()
    deadline = time.monotonic() + 120
    victim = None
    while victim is None and time.monotonic() < deadline:
        busy = {w: tasks for w, tasks in dask_client.processing().items() if tasks}
        if len(list(tmp_path.rglob("*.batch.json"))) >= 2 and busy:
            victim = sorted(busy)[0]
        time.sleep(0.02)
    assert victim is not None, "no worker was busy"
    held = set(dask_client.processing()[victim])
    pids = dask_client.run(os.getpid, workers=[victim])
    os.kill(pids[victim], signal.SIGKILL)
    thread.join(timeout=300)
    assert not thread.is_alive()
    rows = result["rows"]
    assert held, "the killed worker held no asset"
    assert [r["status"] for r in rows].count("ok") == 8
    assert _outputs(tmp_path) == local_outputs


# A batch sharing a disk cache, run where the service (FastAPI, pydantic, neural_shdf.api)
# cannot be imported: the batch reaches the cache through neural_shdf.store alone.
_BATCH_WITHOUT_THE_SERVICE = """
import importlib.abc, json, sys


class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in ("fastapi", "pydantic", "pydantic_settings", "starlette") \\
                or name.startswith("neural_shdf.api"):
            raise ImportError(f"{name} is not installed here")
        return None


sys.meta_path.insert(0, Refuse())
from neural_shdf.batch import run_batch

inputs, out, cache, method = sys.argv[1:]
rows = [run_batch([inputs], f"{out}/{run}", method=method, cache=cache, workers=0)
        for run in ("first", "again")]
print(json.dumps([[row["shdf_cached"] for row in run] for run in rows]))
"""


def test_a_cached_batch_needs_no_part_of_the_service(tmp_path: Path):
    _library(tmp_path / "in", 2)
    run = subprocess.run(
        [sys.executable, "-c", _BATCH_WITHOUT_THE_SERVICE, str(tmp_path / "in"),
         str(tmp_path / "out"), str(tmp_path / "cache"), TEST_METHOD],
        capture_output=True, text=True, timeout=600,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout) == [[False, False], [True, True]]
    assert _outputs(tmp_path / "out" / "again") == _outputs(tmp_path / "out" / "first")


def test_the_docs_example_runs_as_written(tmp_path: Path, monkeypatch):
    """docs/batch.md's example on a folder of three meshes: the manifest rows it returns."""
    from tests.doc_examples import python_blocks

    (block,) = python_blocks("docs/batch.md", "From Python")
    _library(tmp_path / "assets", 3)
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, Any] = {}
    exec(block, namespace)  # noqa: S102
    assert [row["status"] for row in namespace["rows"]] == ["ok"] * 3
    assert len(list((tmp_path / "out").rglob("*.seg"))) == 3
    assert len(list((tmp_path / "out").rglob("*.glb"))) == 3


def test_a_labeler_gives_the_cli_labels_names_and_confidence(tmp_path: Path):
    from tests.labeling.helpers import labelled_dumbbell, obj_of, small_labeler_file

    labeler = tmp_path / "dumbbell.npz"
    labeler.write_bytes(small_labeler_file())
    folder = tmp_path / "in"
    folder.mkdir()
    for name, stretch, seed in (("a", 0.9, 3), ("b", 1.1, 4)):
        (folder / f"{name}.obj").write_bytes(obj_of(labelled_dumbbell(1500, stretch, seed)[0]))
    out = tmp_path / "out"
    rows = run_batch(
        [folder], out, method=TEST_METHOD, outputs=["seg", "parts"], labeler=labeler, workers=1
    )
    assert [r["status"] for r in rows] == ["ok", "ok"], rows
    names = json.loads((out / "label_names.json").read_text())
    assert names["labels"] == [{"value": 2, "name": "neck"}, {"value": 5, "name": "ball"}]
    for row in rows:
        stem = out / row["output"]
        cli = tmp_path / f"cli-{row['output']}"
        assert main(["segment", row["path"], "-o", f"{cli}.seg", "--labeler", str(labeler),
                     "--confidence", f"{cli}.txt", "--method", TEST_METHOD, "-q"]) == 0  # fmt: skip
        assert Path(f"{cli}.seg").read_bytes() == Path(f"{stem}.seg").read_bytes()
        assert Path(f"{cli}.txt").read_bytes() == Path(f"{stem}.confidence").read_bytes()
        glb = Path(f"{stem}.parts.glb").read_bytes()
        assert b'"name":"neck"' in glb and b'"name":"ball"' in glb
        assert row["parts"] == 2
    again = run_batch([folder], out, method=TEST_METHOD, outputs=["seg", "parts"],
                      labeler=labeler, workers=0)  # fmt: skip
    assert [r["status"] for r in again] == ["skipped", "skipped"]
    plain = run_batch([folder], out, method=TEST_METHOD, outputs=["seg"], workers=0)
    assert [r["status"] for r in plain] == ["ok", "ok"]  # another key: a segmentation


def test_a_bad_labeler_or_confidence_without_one_fails_before_any_asset(tmp_path: Path):
    _library(tmp_path / "in", 1)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a labeller")
    code = main(["batch", str(tmp_path / "in"), "-o", str(tmp_path / "out"),
                 "--labeler", str(bad), "-q"])  # fmt: skip
    assert code != 0
    assert not (tmp_path / "out" / "manifest.csv").exists()
    with pytest.raises(ValueError, match="needs a labeller"):
        run_batch([tmp_path / "in"], tmp_path / "out2", outputs=["confidence"], workers=0)
