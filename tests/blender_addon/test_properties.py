"""The add-on's panel starts from the library's defaults, so its first run gives the labels
the CLI, the API and the Python client give for a mesh."""

from __future__ import annotations

import ast

from neural_shdf.segment.params import DEFAULT_CLUSTERS, DEFAULT_SMOOTHING, MAX_CLUSTERS
from tests.api.api_helpers import REPO_ROOT


def property_options(name: str) -> dict[str, object]:
    """Keyword arguments of the ``name`` property in the add-on's settings (read, not run:
    the module needs Blender)."""
    tree = ast.parse((REPO_ROOT / "blender_addon" / "properties.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.AnnAssign) and getattr(node.target, "id", None) == name:
            call = node.annotation
            assert isinstance(call, ast.Call)
            return {k.arg: ast.literal_eval(k.value) for k in call.keywords if k.arg}
    raise AssertionError(f"no property {name!r}")


def test_panel_defaults_are_the_library_defaults():
    assert property_options("smoothing")["default"] == DEFAULT_SMOOTHING
    clusters = property_options("clusters")
    assert clusters["default"] == DEFAULT_CLUSTERS and clusters["max"] == MAX_CLUSTERS
    assert property_options("partitioner")["default"] == "graphcut"
