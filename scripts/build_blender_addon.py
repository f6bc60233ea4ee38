"""Build the Blender add-on's installable zip (Edit > Preferences > Get Extensions >
Install from Disk): ``python scripts/build_blender_addon.py [--output DIR]``.

The zip holds ``blender_manifest.toml`` and the add-on's modules at its root, as Blender's
own ``blender --command extension build`` lays it out; it is byte-for-byte reproducible.
"""

from __future__ import annotations

import argparse
import tomllib
import zipfile
from pathlib import Path

ADDON_DIR = Path(__file__).resolve().parents[1] / "blender_addon"
#: A fixed timestamp: the same sources give the same zip.
ZIP_TIME = (2024, 1, 1, 0, 0, 0)


def addon_files(source: Path = ADDON_DIR) -> list[Path]:
    """The manifest and every module of the add-on (no caches)."""
    files = [source / "blender_manifest.toml", *sorted(source.glob("*.py"))]
    return [path for path in files if path.is_file()]


def build(output_dir: Path, source: Path = ADDON_DIR) -> Path:
    """Write ``<id>-<version>.zip`` into ``output_dir``; returns its path."""
    manifest = tomllib.loads((source / "blender_manifest.toml").read_text())
    output_dir.mkdir(parents=True, exist_ok=True)
    target = output_dir / f"{manifest['id']}-{manifest['version']}.zip"
    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as archive:
        for path in addon_files(source):
            info = zipfile.ZipInfo(path.name, date_time=ZIP_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            archive.writestr(info, path.read_bytes())
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--output", type=Path, default=Path("dist"), help="folder for the zip")
    print(build(parser.parse_args(argv).output))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
