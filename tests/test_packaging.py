"""The locked install: every dependency pinned in constraints.txt, every installer using it."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

from packaging.requirements import Requirement

from tests.conftest import REPO_ROOT


def _pins() -> dict[str, str]:
    pins = {}
    for line in (REPO_ROOT / "constraints.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints.txt line {line!r} is not an exact pin"
            pins[re.sub(r"[-_.]+", "-", name).lower()] = version
    return pins


def _declared() -> list[Requirement]:
    project = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["project"]
    names = list(project["dependencies"])
    for extra in project["optional-dependencies"].values():
        names.extend(extra)
    return [Requirement(name) for name in names]


def test_every_declared_dependency_is_pinned_within_its_range():
    pins = _pins()
    for requirement in _declared():
        key = re.sub(r"[-_.]+", "-", requirement.name).lower()
        assert key in pins, f"{requirement.name} is not pinned in constraints.txt"
        assert requirement.specifier.contains(pins[key], prereleases=True), (
            f"{requirement.name}=={pins[key]} is outside pyproject's {requirement.specifier}"
        )


def test_test_command_ci_and_image_install_the_locked_set():
    assert "-c constraints.txt" in (REPO_ROOT / "scripts" / "test").read_text()
    assert "-c constraints.txt" in (REPO_ROOT / "Dockerfile").read_text()
    assert "NEURAL_SHDF_FRESH_VENV=1" in (REPO_ROOT / ".ci" / "run").read_text()


def test_the_viewer_files_are_package_data_and_node_modules_is_not():
    from fnmatch import fnmatch

    patterns = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"
    ]["neural_shdf"]
    package = REPO_ROOT / "service" / "neural_shdf"
    viewer = [
        path.relative_to(package).as_posix()
        for path in (package / "viewer").rglob("*")
        if path.is_file() and "node_modules" not in path.parts
    ]
    assert "viewer/index.html" in viewer and "viewer/static/main.js" in viewer
    for name in viewer:
        assert any(fnmatch(name, pattern) for pattern in patterns), f"{name} is not package data"
    assert not any(fnmatch("viewer/node_modules/three/build/three.module.js", p) for p in patterns)


def test_test_command_and_pre_commit_run_the_linters_with_local_tools():
    import yaml

    script = (REPO_ROOT / "scripts" / "test").read_text()
    linters = [script.index(f'"$venv/bin/{tool}"') for tool in ("ruff", "mypy")]
    assert '"$venv/bin/ruff" format --check .' in script
    assert max(linters) < script.index("-m pytest"), "the linters run before the tests"
    hooks = yaml.safe_load((REPO_ROOT / ".pre-commit-config.yaml").read_text())["repos"]
    assert [repo["repo"] for repo in hooks] == ["local"], "no hook is downloaded"
    entries = [hook["entry"].split()[0] for repo in hooks for hook in repo["hooks"]]
    assert entries == [".venv/bin/ruff", ".venv/bin/ruff", ".venv/bin/mypy"]


def test_mypy_strict_core_is_not_in_the_baseline():
    mypy = tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["tool"]["mypy"]
    strict = {
        module
        for override in mypy["overrides"]
        if override.get("disallow_untyped_defs")
        for module in override["module"]
    }
    core = {"neural_shdf.geometry", "neural_shdf.orientation", "neural_shdf.errors"}
    core |= {"neural_shdf.exchange.gltf", "neural_shdf.segment.params", "neural_shdf.shdf.stage"}
    # The numba kernel modules: annotated (numba ignores annotations), never baselined.
    core |= {f"neural_shdf.segment.{name}" for name in ("graphcut", "parts", "creases")}
    kernels = ("exact", "embree", "postprocess", "sampling", "search")
    core |= {f"neural_shdf.shdf.{name}" for name in kernels}
    assert core <= strict
    baselined = {
        override["module"] for override in mypy["overrides"] if "disable_error_code" in override
    }
    assert not strict & baselined


def test_the_wheel_installs_neural_shdf_alone(tmp_path: Path) -> None:
    """`model_export/` (training) is a folder of the repository, never a top-level package."""
    source = tmp_path / "source"
    ignore = shutil.ignore_patterns("node_modules", "__pycache__", "*.egg-info", "build")
    for name in ("service", "model_export"):
        shutil.copytree(REPO_ROOT / name, source / name, ignore=ignore)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO_ROOT / name, source / name)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation"]
        + ["--no-index", "--wheel-dir", str(tmp_path / "dist"), str(source)],
        check=True,
    )
    (wheel,) = (tmp_path / "dist").glob("neural_shdf-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top_level = {name.split("/", 1)[0] for name in names}
    assert {name for name in top_level if not name.endswith(".dist-info")} == {"neural_shdf"}
    assert "neural_shdf/models/emd.onnx" in names and "neural_shdf/viewer/index.html" in names
