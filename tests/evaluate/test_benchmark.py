"""Running methods over a PSB-layout folder: averaging, methods, caching, formatting."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from neural_shdf.errors import ParameterError
from neural_shdf.evaluate.benchmark import (
    BenchModel,
    cached_shdf,
    evaluate_folder,
    format_table,
    list_models,
    load_benchmark_mesh,
    make_predictor,
    run_eval,
    table_as_dict,
)
from neural_shdf.evaluate.scores import cut_graph, score_against_humans
from neural_shdf.shdf.stage import ShdfResult


def write_off(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    lines = ["OFF", f"{len(vertices)} {len(faces)} 0"]
    lines += [" ".join(f"{c:.9g}" for c in v) for v in vertices]
    lines += ["3 " + " ".join(str(i) for i in f) for f in faces]
    path.write_text("\n".join(lines) + "\n")


def write_seg(path: Path, labels: np.ndarray) -> None:
    path.write_text("".join(f"{int(x)}\n" for x in labels))


def split_by_height(centroids: np.ndarray, cuts: list[float]) -> np.ndarray:
    return np.searchsorted(np.array(cuts), centroids[:, 2])


@pytest.fixture
def bench(tmp_path: Path) -> Path:
    """Models 1, 2 (category 0) and 21 (category 1): ellipsoids cut across z by humans.

    Humans: each model is cut at z = 0 twice and once at z = 0, 0.5 (most frequent
    part count 2); CGAL cuts every model at z = 0.3.
    """
    sphere = trimesh.creation.icosphere(subdivisions=2)
    vertices = np.asarray(sphere.vertices) * np.array([0.5, 0.5, 1.0])
    faces = np.asarray(sphere.faces)
    centroids = vertices[faces].mean(axis=1)
    for folder in ("off", "seg", "cgal"):
        (tmp_path / folder).mkdir()
    for model_id, scale in ((1, 1.0), (2, 1.5), (21, 0.5)):
        write_off(tmp_path / "off" / f"{model_id}.off", vertices * scale, faces)
        human_dir = tmp_path / "seg" / str(model_id)
        human_dir.mkdir()
        for n, cuts in enumerate(([0.0], [0.0], [0.0, 0.5])):
            write_seg(human_dir / f"{model_id}_{n}.seg", split_by_height(centroids, cuts))
        write_seg(tmp_path / "cgal" / f"{model_id}.seg", split_by_height(centroids, [0.3]))
        sdf = np.clip(np.abs(centroids[:, 2]) / 1.5, 0, 1)
        (tmp_path / "cgal" / f"{model_id}.sdf").write_text("".join(f"{x:.6f}\n" for x in sdf))
    return tmp_path


def test_list_models_and_human_part_count(bench: Path):
    models = list_models(bench)
    assert [m.model_id for m in models] == [1, 2, 21]
    assert [m.category for m in models] == [0, 0, 1]
    assert models[0].human_part_count() == 2
    assert [m.model_id for m in list_models(bench, limit=2)] == [1, 2]


def test_human_part_count_ties_take_the_smaller(tmp_path: Path):
    for n, labels in enumerate(([0, 1, 2], [0, 0, 1])):
        write_seg(tmp_path / f"1_{n}.seg", np.array(labels))
    model = BenchModel(1, tmp_path, (tmp_path / "1_0.seg", tmp_path / "1_1.seg"))
    assert model.human_part_count() == 2


def test_cgal_scores_follow_the_benchmark_averaging(bench: Path):
    table = run_eval(bench, ["cgal"], cache_dir=bench / "cache")
    cgal = table["cgal"]
    # Independent computation: each model against its humans, then the averages.
    per_model = {}
    for model in list_models(bench):
        mesh = load_benchmark_mesh(model.mesh_path)
        graph = cut_graph(mesh.vertices, mesh.faces)
        labels = np.loadtxt(bench / "cgal" / f"{model.model_id}.seg", dtype=int)
        per_model[model.model_id] = score_against_humans(graph, labels, model.human_segmentations())
    got = {r.model_id: r.scores for r in cgal.models}
    for model_id, expected in per_model.items():
        assert got[model_id].as_dict() == pytest.approx(expected.as_dict())
    # Overall = mean over categories ({1, 2} and {21}), not over the three models.
    category_0 = (per_model[1].ri_error + per_model[2].ri_error) / 2
    assert cgal.overall().ri_error == pytest.approx((category_0 + per_model[21].ri_error) / 2)
    assert cgal.mean_parts() == (2.0, 2.0)
    text = format_table(table)
    assert "OVERALL" in text and "Human" in text and "Cup" in text
    assert set(table_as_dict(table)["cgal"]["models"]) == {"1", "2", "21"}


def test_a_bare_predictor_and_two_workers_agree(bench: Path):
    def cut_at_zero(mesh, model):
        return split_by_height(mesh.vertices[mesh.faces].mean(axis=1), [0.0])

    serial = evaluate_folder(bench, cut_at_zero)["method"]
    parallel = evaluate_folder(bench, {"method": make_predictor("cgal")}, jobs=2)["method"]
    assert [r.model_id for r in serial.models] == [r.model_id for r in parallel.models]
    # Two of the three humans cut exactly at z = 0.
    assert serial.overall().ri_error < parallel.overall().ri_error


def test_shdf_methods_run_with_humans_part_count(bench: Path):
    methods = ["cgalsdf-graphcut", "cgalsdf-metis-humanparts", "cgalsdf-graphcut-humanparts",
               "cgalsdf-graphcut-leaves"]  # fmt: skip
    table = run_eval(bench, methods, cache_dir=bench / "cache")
    metis = table["cgalsdf-metis-humanparts"]
    assert [r.parts for r in metis.models] == [r.human_parts for r in metis.models]
    # The tree's cut at the humans' count, unless it has fewer leaves than that.
    leaves = [r.parts for r in table["cgalsdf-graphcut-leaves"].models]
    tree = [r.parts for r in table["cgalsdf-graphcut-humanparts"].models]
    humans = [r.human_parts for r in metis.models]
    assert tree == [min(h, n) for h, n in zip(humans, leaves, strict=True)]
    automatic = [r.parts for r in table["cgalsdf-graphcut"].models]
    assert all(a <= n for a, n in zip(automatic, leaves, strict=True))
    for method_table in table.values():
        for value in method_table.overall().as_dict().values():
            assert np.isnan(value) or value >= 0.0


def test_exact_shdf_is_cached(bench: Path, monkeypatch: pytest.MonkeyPatch):
    model = list_models(bench)[0]
    mesh = load_benchmark_mesh(model.mesh_path)
    calls = []

    def fake_shdf(mesh, method, seed):
        calls.append(method)
        return ShdfResult(np.full(mesh.face_count, 0.5), "exact")

    monkeypatch.setattr("neural_shdf.pipeline.compute_shdf", fake_shdf)
    first = cached_shdf(mesh, "exact", bench / "cache", model)
    second = cached_shdf(mesh, "exact", bench / "cache", model)
    assert calls == ["exact"]
    np.testing.assert_array_equal(first, second)
    assert len(list((bench / "cache" / "exact").glob("*.npy"))) == 1


def test_bad_names_and_folders_are_refused(bench: Path, tmp_path: Path):
    with pytest.raises(ParameterError, match="unknown method"):
        make_predictor("exact-kmeans")
    with pytest.raises(ParameterError, match="-leaves needs the graphcut"):
        make_predictor("exact-metis-leaves")
    with pytest.raises(ParameterError, match="off/ and seg/"):
        list_models(tmp_path / "nowhere")


@pytest.mark.slow
@pytest.mark.needs_data
def test_cgal_on_psb_dev_matches_the_reference_figure(shared_data: Path):
    # The lead's reference: CGAL's default segmentations score 1 - RI = 0.309 on psb-dev.
    table = run_eval(shared_data / "psb-dev", ["cgal"], jobs=2)
    assert table["cgal"].overall().ri_error == pytest.approx(0.309, abs=0.001)
    assert len(table["cgal"].models) == 76
