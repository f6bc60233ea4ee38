"""The web viewer's page: its static files, its import map and where three.js comes from.

three.js is never part of the repository. ``npm ci`` in the viewer's folder (the tests and the
Docker image run it) installs the npm package ``three``; the service then serves that copy at
``/viewer/three/``. Without it (a plain ``pip install``) the import map points at the jsDelivr
CDN, pinned to the version locked in the viewer's ``package.json``: the viewer then needs the
internet, and the page says so, with the fix (``three_help``), when three.js does not load.
``viewer_three_url`` overrides both.
"""

from __future__ import annotations

import functools
import html
import json
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any, get_args

from neural_shdf.api.schemas import SegmentOptions, ShdfMethodName
from neural_shdf.api.settings import Settings
from neural_shdf.mesh import TriangleMesh
from neural_shdf.mesh_io import SUPPORTED_FORMATS
from neural_shdf.palette import UNLABELED_COLOR, part_color_hex
from neural_shdf.segment.params import (
    DEFAULT_CLUSTERS,
    DEFAULT_CREASE_BOUNDARIES,
    DEFAULT_SMOOTHING,
    MAX_CLUSTERS,
    MAX_PARTS,
)

VIEWER_DIR = Path(__file__).resolve().parents[1] / "viewer"
STATIC_DIR = VIEWER_DIR / "static"
#: Where the service serves a local copy of three.js.
LOCAL_THREE_PATH = "/viewer/three/"
CDN_TEMPLATE = "https://cdn.jsdelivr.net/npm/three@{version}/"


#: Magic and version of display_geometry's binary layout.
DISPLAY_GEOMETRY_MAGIC = b"NSHG"
DISPLAY_GEOMETRY_VERSION = 1


def display_geometry(mesh: TriangleMesh) -> bytes:
    """The triangles a viewer draws, and the input face each came from, as one binary blob.

    Little-endian: a 20-byte header (``NSHG``, uint32 version, vertex count V, triangle
    count T, input face count F), then float32 positions (V, 3), uint32 triangle corners
    (T, 3) and uint32 input face per triangle (T): per-input-face labels or ShDF values
    colour triangle ``t`` with ``values[face_origin[t]]``.
    """
    header = struct.pack(
        "<4sIIII",
        DISPLAY_GEOMETRY_MAGIC,
        DISPLAY_GEOMETRY_VERSION,
        len(mesh.vertices),
        mesh.face_count,
        mesh.input_face_count,
    )
    return b"".join(
        (
            header,
            mesh.vertices.astype("<f4").tobytes(),
            mesh.faces.astype("<u4").tobytes(),
            mesh.face_origin.astype("<u4").tobytes(),
        )
    )


@functools.cache
def three_version() -> str:
    """The exact version of ``three`` the viewer's package.json asks for."""
    manifest = json.loads((VIEWER_DIR / "package.json").read_text())
    return manifest["dependencies"]["three"]


@dataclass(frozen=True)
class ThreeSource:
    """Where the page loads three.js from, and the local copy the service serves (if any)."""

    base_url: str
    local_dir: Path | None


def three_source(settings: Settings) -> ThreeSource:
    """The configured URL, else the installed local copy, else the CDN."""
    local = settings.viewer_three_dir or VIEWER_DIR / "node_modules" / "three"
    local = local.expanduser().resolve()
    installed = (local / "build" / "three.module.js").is_file()
    if settings.viewer_three_url:
        base = settings.viewer_three_url.rstrip("/") + "/"
        return ThreeSource(base, local if installed else None)
    if installed:
        return ThreeSource(LOCAL_THREE_PATH, local)
    return ThreeSource(CDN_TEMPLATE.format(version=three_version()), None)


def three_help(settings: Settings) -> str:
    """What a person does when the page cannot load three.js from where it points."""
    source = three_source(settings)
    npm = (
        f"run `npm ci` in {VIEWER_DIR} (Node.js; it installs three {three_version()}) and "
        "restart `neural-shdf serve`, or set NEURAL_SHDF_VIEWER_THREE_DIR to a folder holding "
        "the npm package three"
    )
    if settings.viewer_three_url:
        return (
            f"It comes from NEURAL_SHDF_VIEWER_THREE_URL ({source.base_url}), which this "
            "browser could not load: fix or unset that URL (the npm package three's folder, "
            f"with build/ and examples/), or {npm}."
        )
    if source.local_dir is not None:
        return f"The service's copy in {source.local_dir} did not load: reinstall it ({npm})."
    return (
        f"It comes from the CDN ({source.base_url}), which this browser could not reach "
        f"(offline, or blocked). To use the viewer offline, {npm}."
    )


def import_map(base_url: str) -> dict[str, Any]:
    """The page's import map: ``three`` and ``three/addons/`` under one base URL."""
    return {
        "imports": {
            "three": f"{base_url}build/three.module.js",
            "three/addons/": f"{base_url}examples/jsm/",
        }
    }


def _choices(annotation: Any) -> list[str]:
    """The values of a ``Literal`` (possibly inside ``X | None``)."""
    values: list[str] = []
    for arg in get_args(annotation) or (annotation,):
        values.extend(_choices(arg) if get_args(arg) else [arg] if isinstance(arg, str) else [])
    return values


@functools.cache
def part_palette() -> str:
    """The API's part colours for 0..MAX_PARTS-1 as one string of ``rrggbb`` runs: the page
    colours a cut of the part tree it makes itself exactly as the service would."""
    return "".join(color[1:] for color in part_color_hex(MAX_PARTS))


def page_config(settings: Settings) -> dict[str, Any]:
    """What the page needs to know about the service's limits, choices and defaults."""
    return {
        "maxUploadBytes": settings.max_upload_bytes,
        "maxFaces": settings.max_faces,
        "defaultMethod": settings.default_method,
        "methods": _choices(ShdfMethodName),
        "partitioners": _choices(SegmentOptions.model_fields["partitioner"].annotation),
        "formats": list(SUPPORTED_FORMATS),
        "maxClusters": MAX_CLUSTERS,
        "defaultClusters": DEFAULT_CLUSTERS,
        "defaultSmoothing": DEFAULT_SMOOTHING,
        "defaultCreaseBoundaries": DEFAULT_CREASE_BOUNDARIES,
        "unlabeledColor": "#{:02x}{:02x}{:02x}".format(*UNLABELED_COLOR[:3].tolist()),
        "maxParts": MAX_PARTS,
        "partPalette": part_palette(),
        "threeUrl": three_source(settings).base_url,
        "threeHelp": three_help(settings),
    }


def _script_json(value: Any) -> str:
    """JSON safe inside a <script> element."""
    return json.dumps(value).replace("<", "\\u003c").replace(">", "\\u003e")


def render_page(settings: Settings) -> str:
    """index.html with the import map and the page configuration filled in."""
    source = three_source(settings)
    template = (VIEWER_DIR / "index.html").read_text()
    return (
        template.replace("{{IMPORT_MAP}}", _script_json(import_map(source.base_url)))
        .replace("{{CONFIG}}", _script_json(page_config(settings)))
        .replace("{{THREE_BASE}}", html.escape(source.base_url, quote=True))
    )
