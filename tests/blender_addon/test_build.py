"""The installable zip (scripts/build_blender_addon.py) and the locked bpy environment."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
import zipfile

from scripts.build_blender_addon import ADDON_DIR, build
from tests.conftest import REPO_ROOT


def test_zip_holds_the_manifest_and_every_module_at_its_root(tmp_path):
    target = build(tmp_path)
    with zipfile.ZipFile(target) as archive:
        names = archive.namelist()
        manifest = tomllib.loads(archive.read("blender_manifest.toml").decode())
        init = archive.read("__init__.py").decode()
    modules = sorted(path.name for path in ADDON_DIR.glob("*.py"))
    assert names == ["blender_manifest.toml", *modules]
    assert {"service.py", "operators.py", "panel.py", "mesh_payload.py"} <= set(names)
    assert "def register" in init and "def unregister" in init
    assert manifest["id"] == "neural_shdf" and manifest["type"] == "add-on"
    assert tuple(int(p) for p in manifest["blender_version_min"].split(".")) >= (4, 2, 0)
    assert "network" in manifest["permissions"]
    assert target.name == f"neural_shdf-{manifest['version']}.zip"


def test_build_is_reproducible_and_runs_as_a_command(tmp_path):
    first = build(tmp_path / "a").read_bytes()
    done = subprocess.run(
        [sys.executable, "scripts/build_blender_addon.py", "--output", str(tmp_path / "b")],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
        check=True,
    )
    assert (tmp_path / "b" / "neural_shdf-0.2.0.zip").read_bytes() == first
    assert done.stdout.strip().endswith("neural_shdf-0.2.0.zip")


def test_addon_imports_only_what_blender_ships():
    """Blender's Python has no httpx or requests: the add-on speaks HTTP with urllib."""
    for path in ADDON_DIR.glob("*.py"):
        imports = re.findall(r"^\s*(?:from|import) (\w+)", path.read_text(), re.M)
        assert not {"httpx", "requests", "neural_shdf"} & set(imports), path.name


def test_bpy_environment_is_locked_and_installed_by_the_test_command():
    pins = {}
    for line in (REPO_ROOT / "constraints-blender.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints-blender.txt line {line!r} is not an exact pin"
            pins[name.lower()] = version
    assert re.fullmatch(r"4\.5\.\d+", pins["bpy"])
    assert "-c constraints-blender.txt bpy" in (REPO_ROOT / "scripts" / "test").read_text()
