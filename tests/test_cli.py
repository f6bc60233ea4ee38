"""The CLI contract: one line per input face, input order, clear errors, non-zero exits."""

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from neural_shdf.cli import EXIT_BAD_INPUT, main


def _dumbbell() -> trimesh.Trimesh:
    left = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    right = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    left.apply_translation([-2.5, 0, 0])
    right.apply_translation([2.5, 0, 0])
    bar = trimesh.creation.cylinder(radius=0.25, height=3.5, sections=24)
    bar.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    return trimesh.util.concatenate([left, bar, right])


def _quad_box_obj(path: Path) -> int:
    """A box of 6 quads followed by 2 triangles of a separate shell; returns face count."""
    lines = [
        "v 0 0 0",
        "v 1 0 0",
        "v 1 1 0",
        "v 0 1 0",
        "v 0 0 1",
        "v 1 0 1",
        "v 1 1 1",
        "v 0 1 1",
        "v 3 0 0",
        "v 4 0 0",
        "v 3 1 0",
        "v 3 0 1",
        "f 1 4 3 2",
        "f 5 6 7 8",
        "f 1 2 6 5",
        "f 2 3 7 6",
        "f 3 4 8 7",
        "f 4 1 5 8",
        "f 9 11 10",
        "f 9 10 12",
    ]
    path.write_text("\n".join(lines) + "\n")
    return 8


@pytest.fixture
def dumbbell_obj(tmp_path: Path) -> Path:
    path = tmp_path / "dumbbell.obj"
    _dumbbell().export(path)
    return path


def _read_lines(path: Path) -> list[str]:
    return path.read_text().split()


def test_segment_writes_one_label_per_input_face(dumbbell_obj: Path, tmp_path: Path):
    out = tmp_path / "labels.seg"
    colored = tmp_path / "colored.glb"
    code = main(
        [
            "segment",
            str(dumbbell_obj),
            "-o",
            str(out),
            "--method",
            "exact",
            "--colored",
            str(colored),
            "-q",
        ]
    )
    assert code == 0
    labels = np.array(_read_lines(out), dtype=int)
    assert len(labels) == len(_dumbbell().faces)
    # With the default parameters the thin bar is a part of its own, apart from the balls.
    x = _dumbbell().triangles_center[:, 0]
    bar, balls = labels[np.abs(x) < 1.2], labels[np.abs(x) > 2.0]
    assert np.mean(bar == np.bincount(bar).argmax()) > 0.95
    assert set(bar).isdisjoint(balls)
    scene = trimesh.load(colored, force="mesh", process=False)
    assert len(scene.faces) == len(labels)


def test_metis_gives_the_requested_number_of_parts(dumbbell_obj: Path, tmp_path: Path):
    out = tmp_path / "labels.seg"
    assert (
        main(
            [
                "segment",
                str(dumbbell_obj),
                "-o",
                str(out),
                "--method",
                "exact",
                "--partitioner",
                "metis",
                "--parts",
                "3",
                "-q",
            ]
        )
        == 0
    )
    assert len(np.unique(np.array(_read_lines(out), dtype=int))) == 3


def test_tree_json_recuts_to_every_part_count(dumbbell_obj: Path, tmp_path: Path):
    import json

    out, tree_path = tmp_path / "labels.seg", tmp_path / "tree.json"
    assert (
        main(
            [
                "segment",
                str(dumbbell_obj),
                "-o",
                str(out),
                "--method",
                "exact",
                "--smoothing",
                "0.03",
                "--parts",
                "2",
                "--tree",
                str(tree_path),
                "-q",
            ]
        )
        == 0
    )
    labels = np.array(_read_lines(out), dtype=int)
    tree = json.loads(tree_path.read_text())
    leaves = np.array(tree["leaf_labels"])
    count = tree["leaf_count"]
    assert len(leaves) == len(labels) and leaves.max() + 1 == count
    assert tree["parts"] == 2 == len(np.unique(labels))
    assert len(tree["parent"]) == 2 * count - 1 and len(tree["merge_cost"]) == count - 1
    assert 1 <= tree["automatic_parts"] <= count

    # The documented recipe, from the JSON alone, reproduces the written labels.
    def cut(parts: int) -> np.ndarray:
        top = []
        for leaf in range(count):
            node = leaf
            while tree["parent"][node] != -1 and tree["parent"][node] < 2 * count - parts:
                node = tree["parent"][node]
            top.append(node)
        smallest = {}
        for leaf, node in enumerate(top):
            smallest.setdefault(node, leaf)
        order = sorted(smallest, key=smallest.get)
        return np.array([order.index(node) for node in top])[leaves]

    np.testing.assert_array_equal(cut(2), labels)
    assert len(np.unique(cut(count))) == count


def test_tree_needs_the_graph_cut(dumbbell_obj: Path, tmp_path: Path, capsys):
    code = main(
        [
            "segment",
            str(dumbbell_obj),
            "-o",
            str(tmp_path / "l.seg"),
            "--partitioner",
            "metis",
            "--parts",
            "2",
            "--tree",
            str(tmp_path / "t.json"),
            "-q",
        ]
    )
    assert code == EXIT_BAD_INPUT
    assert "--tree needs the graphcut partitioner" in capsys.readouterr().err


def test_quads_keep_one_label_and_input_order(tmp_path: Path):
    mesh_path = tmp_path / "quads.obj"
    faces = _quad_box_obj(mesh_path)
    values, labels = tmp_path / "v.txt", tmp_path / "l.seg"
    assert main(["shdf", str(mesh_path), "-o", str(values), "--method", "exact", "-q"]) == 0
    assert main(["segment", str(mesh_path), "-o", str(labels), "--method", "exact", "-q"]) == 0
    shdf = np.array(_read_lines(values), dtype=float)
    assert len(shdf) == faces and len(_read_lines(labels)) == faces
    assert np.all((shdf >= 0) & (shdf <= 1))
    seg = np.array(_read_lines(labels), dtype=int)
    # The box (first six input faces) and the separate two-triangle shell never share a part.
    assert set(seg[:6]).isdisjoint(seg[6:])


def _part_subsets(path: Path, prim_path: str) -> dict[str, list[int]]:
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(path))  # kept alive while its prims are read
    mesh = UsdGeom.Mesh.Get(stage, prim_path)
    subsets = UsdGeom.Subset.GetGeomSubsets(mesh, UsdGeom.Tokens.face, "part")
    return {s.GetPrim().GetName(): list(s.GetIndicesAttr().Get()) for s in subsets}


def _faces_of_each_part(labels: np.ndarray) -> dict[str, list[int]]:
    from neural_shdf.exchange.gltf_writer import part_name

    return {part_name(p): np.flatnonzero(labels == p).tolist() for p in np.unique(labels)}


def _segment_to_usd(source: Path, labels: Path, parts: Path) -> None:
    command = ["segment", str(source), "-o", str(labels), "--method", "exact", "--usd", str(parts)]
    assert main([*command, "-q"]) == 0


def test_segment_writes_a_usd_input_back_as_usd_with_a_subset_per_part(tmp_path: Path):
    from tests.exchange.test_usd import _dumbbell_stage

    source = tmp_path / "dumbbell.usda"
    counts = _dumbbell_stage(source)
    labels, parts = tmp_path / "parts.seg", tmp_path / "parts.usdc"
    _segment_to_usd(source, labels, parts)
    seg = np.array(_read_lines(labels), dtype=int)
    assert len(seg) == sum(counts)
    assert _part_subsets(parts, "/World/Bar/Shape") == _faces_of_each_part(seg[: counts[0]])
    assert _part_subsets(parts, "/World/Drum/Shape") == _faces_of_each_part(seg[counts[0] :])


def test_segment_writes_other_inputs_as_a_new_usd_stage_of_their_faces(tmp_path: Path):
    from neural_shdf.mesh_io import load_mesh

    mesh_path = tmp_path / "quads.obj"
    faces = _quad_box_obj(mesh_path)
    labels, parts = tmp_path / "l.seg", tmp_path / "parts.usda"
    _segment_to_usd(mesh_path, labels, parts)
    seg = np.array(_read_lines(labels), dtype=int)
    assert _part_subsets(parts, "/World/Mesh") == _faces_of_each_part(seg)
    written, original = load_mesh(parts), load_mesh(mesh_path)
    assert written.input_face_count == faces  # 6 quads and 2 triangles, as in the OBJ
    assert np.array_equal(written.faces, original.faces)
    assert np.array_equal(written.face_origin, original.face_origin)


def test_segment_refuses_a_usd_output_it_cannot_write(dumbbell_obj: Path, tmp_path: Path, capsys):
    code = main(
        [
            "segment",
            str(dumbbell_obj),
            "-o",
            str(tmp_path / "l.seg"),
            "--usd",
            str(tmp_path / "parts.glb"),
            "-q",
        ]
    )
    assert code == EXIT_BAD_INPUT
    assert "--usd must end in .usda" in capsys.readouterr().err


def test_same_input_same_labels(dumbbell_obj: Path, tmp_path: Path):
    outputs = []
    for name in ("a.seg", "b.seg"):
        assert (
            main(
                [
                    "segment",
                    str(dumbbell_obj),
                    "-o",
                    str(tmp_path / name),
                    "--method",
                    "exact",
                    "-q",
                ]
            )
            == 0
        )
        outputs.append((tmp_path / name).read_text())
    assert outputs[0] == outputs[1]


@pytest.mark.parametrize(
    ("content", "name", "needle"),
    [
        (b"", "empty.obj", "empty"),
        (b"\x89PNG\r\n\x1a\n" + bytes(100), "image.stl", "stl"),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "bad_index.obj", "do not exist"),
        (b"v 0 0 0\n", "mesh.xyz", "format"),
    ],
)
def test_bad_input_exits_with_a_message(tmp_path: Path, capsys, content, name, needle):
    path = tmp_path / name
    path.write_bytes(content)
    code = main(["segment", str(path), "-o", str(tmp_path / "out.seg"), "--method", "exact", "-q"])
    assert code == EXIT_BAD_INPUT
    assert needle in capsys.readouterr().err.lower()
    assert not (tmp_path / "out.seg").exists()


def test_missing_file_and_bad_parameters(tmp_path: Path, dumbbell_obj: Path, capsys):
    assert main(["shdf", str(tmp_path / "nope.obj"), "-o", "x.txt", "-q"]) == EXIT_BAD_INPUT
    assert "not found" in capsys.readouterr().err
    code = main(
        [
            "segment",
            str(dumbbell_obj),
            "-o",
            str(tmp_path / "o.seg"),
            "--method",
            "exact",
            "--partitioner",
            "metis",
            "--parts",
            "0",
            "-q",
        ]
    )
    assert code == EXIT_BAD_INPUT
    assert "parts" in capsys.readouterr().err


def test_console_script_is_installed(dumbbell_obj: Path, tmp_path: Path):
    out = tmp_path / "labels.seg"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "neural_shdf.cli",
            "segment",
            str(dumbbell_obj),
            "-o",
            str(out),
            "--method",
            "exact",
            "-q",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert len(_read_lines(out)) == len(_dumbbell().faces)


def test_eval_prints_a_table_over_a_benchmark_folder(tmp_path: Path, capsys):
    mesh = _dumbbell()
    (tmp_path / "off").mkdir()
    (tmp_path / "seg" / "1").mkdir(parents=True)
    (tmp_path / "cgal").mkdir()
    mesh.export(tmp_path / "off" / "1.off")
    x = mesh.triangles_center[:, 0]
    human = np.digitize(x, [-1.6, 1.6])
    np.savetxt(tmp_path / "seg" / "1" / "1_0.seg", human, fmt="%d")
    # "CGAL" here is a copy of the human segmentation, so it must score a perfect 0.
    np.savetxt(tmp_path / "cgal" / "1.seg", human, fmt="%d")
    code = main(
        [
            "eval",
            str(tmp_path),
            "--methods",
            "cgal",
            "exact-graphcut",
            "--cache-dir",
            str(tmp_path / "cache"),
            "-q",
        ]
    )
    assert code == 0
    out = capsys.readouterr().out
    assert "cgal" in out and "exact-graphcut" in out
    overall = [line.split() for line in out.splitlines() if line.startswith("OVERALL")]
    scores = {row[1]: [float(value) for value in row[2:] if value != "-"] for row in overall}
    assert len(scores["cgal"]) == 7 and all(value == 0.0 for value in scores["cgal"])
    # The thin bar between the balls is found: far better than one part (1-RI ~ 0.5).
    assert 0.0 <= scores["exact-graphcut"][-3] < 0.3


def test_eval_rejects_a_folder_without_benchmark_layout(tmp_path: Path, capsys):
    assert main(["eval", str(tmp_path), "-q"]) == EXIT_BAD_INPUT
    assert "off/" in capsys.readouterr().err


def test_unwrap_writes_a_glb_and_an_obj_that_keep_the_input_faces(tmp_path: Path):
    from neural_shdf.mesh_io import load_mesh

    source = tmp_path / "quads.obj"
    count = _quad_box_obj(source)
    glb, obj, png, seg = (tmp_path / n for n in ("u.glb", "u.obj", "atlas.png", "u.seg"))
    code = main(
        [
            "unwrap",
            str(source),
            "-o",
            str(glb),
            "--method",
            "exact",
            "--atlas-size",
            "256",
            "--atlas-png",
            str(png),
            "--labels",
            str(seg),
            "-q",
        ]
    )
    assert code == 0
    mesh = load_mesh(source)
    loaded = trimesh.load(glb, force="mesh", process=False)
    # Same triangles in the same order, UVs in [0, 1].
    assert np.allclose(loaded.vertices[loaded.faces], mesh.vertices[mesh.faces], atol=1e-6)
    assert loaded.visual.uv.min() >= 0 and loaded.visual.uv.max() <= 1
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(_read_lines(seg)) == count

    assert main(["unwrap", str(source), "-o", str(obj), "--method", "exact", "-q"]) == 0
    faces = [line.split()[1:] for line in obj.read_text().splitlines() if line.startswith("f ")]
    texcoords = [line for line in obj.read_text().splitlines() if line.startswith("vt ")]
    # One f line per input face (6 quads, 2 triangles), each corner with its own vt.
    assert [len(face) for face in faces] == [4, 4, 4, 4, 4, 4, 3, 3]
    assert len(texcoords) == 4 * 6 + 3 * 2
    assert [int(c.split("/")[0]) for c in faces[0]] == [1, 4, 3, 2]


def test_unwrap_rejects_an_output_it_cannot_write(tmp_path: Path, capsys):
    source = tmp_path / "quads.obj"
    _quad_box_obj(source)
    code = main(["unwrap", str(source), "-o", str(tmp_path / "u.fbx"), "-q"])
    assert code == EXIT_BAD_INPUT
    assert ".glb or .obj" in capsys.readouterr().err


def test_a_mesh_over_the_limits_exits_2_naming_the_limit(tmp_path: Path, capsys):
    from tests.api.api_helpers import instanced_glb

    bomb = tmp_path / "bomb.glb"
    bomb.write_bytes(instanced_glb(4000, 40))  # 160,000 vertices once expanded
    out = str(tmp_path / "o.seg")
    code = main(["segment", str(bomb), "-o", out, "--max-vertices", "100000", "-q"])
    assert code == EXIT_BAD_INPUT
    err = capsys.readouterr().err
    assert "160000 vertices" in err and "limit of 100000 vertices (max_vertices)" in err
    assert main(["segment", str(bomb), "-o", out, "--max-faces", "10", "-q"]) == EXIT_BAD_INPUT
    assert "(max_faces)" in capsys.readouterr().err


class _Stream(io.StringIO):
    """A stderr that records what is written and says whether it is a terminal."""

    def __init__(self, tty: bool) -> None:
        super().__init__()
        self.tty = tty

    def isatty(self) -> bool:
        return self.tty


@pytest.mark.parametrize("tty", [True, False])
def test_progress_bar_waits_its_delay_is_cleared_and_stays_off_logs(monkeypatch, tty):
    import time

    from neural_shdf.cli import progress_bar

    quick, slow = _Stream(tty), _Stream(tty)
    monkeypatch.setattr(sys, "stderr", quick)
    with progress_bar("quick", delay_s=0.5) as update:
        update(0.5)
        update(1.0)
    assert quick.getvalue() == ""  # shorter than the delay: never shown
    monkeypatch.setattr(sys, "stderr", slow)
    with progress_bar("slow", delay_s=0.2) as update:
        for step in range(1, 9):
            time.sleep(0.06)
            update(step / 10)
    frames = slow.getvalue()
    if not tty:
        assert frames == ""  # redirected: no \r frames in the log
        return
    assert "slow:" in frames and "%" in frames
    # Cleared at the end: the last frame is overwritten with blanks and the cursor returns.
    assert frames.endswith("\r") and frames.rstrip("\r").split("\r")[-1].strip() == ""


def test_redirected_stderr_gets_only_the_summary(dumbbell_obj: Path, tmp_path: Path, capsys):
    out = tmp_path / "labels.seg"
    assert main(["segment", str(dumbbell_obj), "-o", str(out), "--method", "exact"]) == 0
    err = capsys.readouterr().err
    # The summary, then what the mesh had.
    assert "\r" not in err and err.count("\n") == 2 and "parts" in err
    assert err.splitlines()[1].startswith("mesh: 3 shells")


@pytest.mark.parametrize("command", ["segment", "shdf"])
def test_the_mesh_diagnostics_line_says_what_was_reoriented(tmp_path: Path, capsys, command):
    inside_out = _dumbbell()
    inside_out.faces = inside_out.faces[:, ::-1]
    path = tmp_path / "inside_out.obj"
    inside_out.export(path)
    out = tmp_path / "values.txt"
    assert main([command, str(path), "-o", str(out), "--method", "exact"]) == 0
    line = capsys.readouterr().err.splitlines()[-1]
    count = len(inside_out.faces)
    assert line == (
        f"mesh: 3 shells, 0 open boundary loops, 0 non-manifold edges, {count} faces "
        "re-oriented, 0 degenerate, 0 duplicate, 0 shells stitched (0 vertices)"
    )


def test_segment_parts_glb_round_trips_the_files_uvs_normals_and_materials(tmp_path: Path):
    """segment scene.glb --parts-glb: every part keeps the file's UVs, normals, colours
    and materials under its object's node; read back, the same faces in the documented
    order with the same values; the Khronos validator finds nothing."""
    from neural_shdf.mesh_io import load_source
    from tests.exchange.scene_helpers import parts_order, textured_scene_glb
    from tests.exchange.test_gltf_writer import _khronos_issues

    scene = tmp_path / "scene.glb"
    scene.write_bytes(textured_scene_glb())
    labels_path, parts = tmp_path / "scene.seg", tmp_path / "parts.glb"
    command = ["segment", str(scene), "-o", str(labels_path), "--method", "exact"]
    assert main([*command, "--parts-glb", str(parts), "-q"]) == 0
    source, back = load_source(scene), load_source(parts)
    labels = np.array(_read_lines(labels_path), dtype=int)[source.mesh.face_origin]
    assert len(np.unique(labels)) >= 2
    order = parts_order(source, labels)
    assert back.mesh.face_count == source.mesh.face_count
    np.testing.assert_allclose(
        back.mesh.vertices[back.mesh.faces],
        source.mesh.vertices[source.mesh.faces][order],
        atol=1e-5,
    )
    for name in ("normals", "tangents", "colors"):
        ours = getattr(back.attributes, name)[back.attributes.corners]
        theirs = getattr(source.attributes, name)[source.attributes.corners][order]
        np.testing.assert_array_equal(ours, theirs)
    for ours, theirs in zip(back.attributes.uvs, source.attributes.uvs, strict=True):
        corners = theirs[source.attributes.corners][order]
        np.testing.assert_array_equal(ours[back.attributes.corners], corners)
    issues = _khronos_issues(tmp_path, {"parts.glb": parts.read_bytes()})["parts.glb"]
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]


def test_segment_symmetry_reports_the_mirror_plane_and_labels_like_the_library(
    dumbbell_obj: Path, tmp_path: Path, capsys
):
    from neural_shdf.mesh_io import load_mesh
    from neural_shdf.pipeline import compute_shdf, segment
    from neural_shdf.segment import SegmentParams

    out = tmp_path / "labels.seg"
    argv = ["segment", str(dumbbell_obj), "-o", str(out), "--method", "exact", "--symmetry"]
    assert main(argv) == 0
    assert "symmetry: mirror plane normal (" in capsys.readouterr().err
    mesh = load_mesh(dumbbell_obj)
    shdf = compute_shdf(mesh, method="exact").values
    result = segment(mesh, shdf, SegmentParams(symmetry=True))
    assert result.reflection is not None
    assert [int(v) for v in _read_lines(out)] == mesh.labels_to_input_faces(result.labels).tolist()


def test_importing_the_cli_leaves_trimesh_unloaded():
    """trimesh's import (~0.3 s, networkx and scipy.spatial with it) is paid only where a
    GLB is written or a file is reloaded for scoring, not by every CLI run."""
    code = "import sys, neural_shdf.cli; print('trimesh' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"
