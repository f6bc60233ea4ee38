"""Fixtures of the Blender add-on tests: a live service, the add-on's zip, Blender's Python."""

from __future__ import annotations

import functools
import json
import os
import subprocess
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.api.conftest import running_server
from tests.conftest import REPO_ROOT

SESSION_SCRIPT = Path(__file__).with_name("blender_session.py")


@functools.cache
def blender_python() -> tuple[str | None, str]:
    """(interpreter whose ``import bpy`` works, or None; why not)."""
    candidates = [
        os.environ.get("NEURAL_SHDF_BLENDER_PYTHON"),
        REPO_ROOT / ".venv-blender/bin/python",
    ]
    for candidate in filter(None, candidates):
        if not Path(candidate).is_file():
            continue
        probe = subprocess.run(
            [str(candidate), "-c", "import bpy; print(bpy.app.version_string)"],
            capture_output=True,
            text=True,
            timeout=120,
        )
        if probe.returncode == 0:
            return str(candidate), probe.stdout.strip()
    return None, (
        "Blender's bpy module is not installed: bash scripts/test installs bpy==4.5.* into "
        ".venv-blender (or set NEURAL_SHDF_BLENDER_PYTHON to a Python 3.11 that has it)"
    )


@pytest.fixture(scope="module")
def service_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    with running_server(tmp_path_factory.mktemp("addon-cache")) as base:
        yield base


@pytest.fixture(scope="module")
def addon_zip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from scripts.build_blender_addon import build

    return build(tmp_path_factory.mktemp("addon-dist"))


@pytest.fixture(scope="module")
def run_blender(
    tmp_path_factory: pytest.TempPathFactory, addon_zip: Path
) -> Callable[[list[dict]], list[dict]]:
    """Run steps of blender_session.py in Blender's Python with a fresh user folder (the
    add-on installed from the zip there); returns the records."""
    interpreter, why = blender_python()
    if interpreter is None:
        pytest.skip(why)

    def run(steps: list[dict], timeout_s: float = 600) -> list[dict]:
        folder = tmp_path_factory.mktemp("blender")
        spec, out = folder / "spec.json", folder / "out.json"
        spec.write_text(json.dumps({"zip": str(addon_zip), "steps": steps}))
        # Blender's temporary files (its session folder among them) under this test's folder.
        (folder / "tmp").mkdir()
        env = {
            **os.environ,
            "BLENDER_USER_RESOURCES": str(folder / "user"),
            "TMPDIR": str(folder / "tmp"),
        }
        done = subprocess.run(
            [interpreter, str(SESSION_SCRIPT), str(spec), str(out)],
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout_s,
        )
        assert done.returncode == 0 and out.is_file(), done.stdout[-3000:] + done.stderr[-3000:]
        left = [path.name for path in (folder / "tmp").iterdir()]
        assert not left, f"the Blender session left temporary files: {left}"
        return json.loads(out.read_text())

    return run
