"""The .usda fast path: large numeric arrays parsed by our kernel and put back into the
layer usd-core parses without them must give the layer usd-core makes of the whole text,
on every stage the tests build and on hostile text; anything else falls back."""

from __future__ import annotations

from decimal import Decimal, getcontext
from pathlib import Path

import numpy as np
import pytest

pxr = pytest.importorskip("pxr")
from pxr import Sdf  # noqa: E402

from neural_shdf.errors import MeshError, MeshTooLargeError  # noqa: E402
from neural_shdf.exchange import usd  # noqa: E402
from neural_shdf.exchange._usda_arrays import cut_arrays, restore_arrays  # noqa: E402
from neural_shdf.mesh_io import load_mesh, load_source  # noqa: E402

from .test_usd import (  # noqa: E402
    _define_mesh,
    _dumbbell_stage,
    _material_stage,
    _new_stage,
    _tube,
)


def _full(text: str):
    layer = Sdf.Layer.CreateAnonymous(".usda")
    assert layer.ImportFromString(text)
    return layer


def _cut_and_restored(text: str):
    """(cut, restored layer or None) with every array cut, however small."""
    cut = cut_arrays(text.encode(), min_bytes=1)
    if cut is None:
        return None, None
    layer = Sdf.Layer.CreateAnonymous(".usda")
    try:
        if not layer.ImportFromString(cut.text.decode()):
            return cut, None
    except pxr.Tf.ErrorException:
        return cut, None
    return cut, layer if restore_arrays(layer, cut) else None


def _assert_same(text: str, *, cut_expected: bool = True) -> None:
    """The fast path's layer is usd-core's layer of the whole text, or it declined."""
    full = _full(text)
    cut, layer = _cut_and_restored(text)
    if cut_expected:
        assert layer is not None, "the fast path declined"
    if layer is not None:
        assert layer.ExportToString() == full.ExportToString()
        for array in cut.arrays:  # bit for bit, not only as printed
            for spec_layer in (layer,):
                found = [p for p in _attribute_paths(spec_layer) if p.name == array.name]
                for path in found:
                    ours = np.asarray(spec_layer.GetAttributeAtPath(path).default)
                    theirs = np.asarray(full.GetAttributeAtPath(path).default)
                    assert ours.dtype == theirs.dtype
                    assert ours.tobytes() == theirs.tobytes()


def _attribute_paths(layer) -> list:
    paths: list = []
    layer.Traverse(
        Sdf.Path.absoluteRootPath, lambda p: paths.append(p) if p.IsPropertyPath() else None
    )
    return paths


def _stage_texts(tmp_path: Path) -> dict[str, str]:
    """Every kind of stage the USD tests build, as .usda text."""
    texts = {}
    path = tmp_path / "dumbbell.usda"
    _dumbbell_stage(path)
    texts["dumbbell"] = path.read_text()
    folder = tmp_path / "materials"
    folder.mkdir()
    texts["materials"] = _material_stage(folder).read_text()
    stage_path = tmp_path / "instances.usda"
    stage = _new_stage(stage_path)
    _define_mesh(stage, "/Proto/Shape", *_tube(12, 1.0, 0.2), uvs_and_normals=True)
    for k in range(3):
        instance = stage.DefinePrim(f"/World/Copy{k}")
        instance.GetReferences().AddInternalReference("/Proto")
        instance.SetInstanceable(True)
    variant = stage.DefinePrim("/World/Variant")
    variants = variant.GetVariantSets().AddVariantSet("shape")
    for name, sections in (("thin", 5), ("round", 30)):
        variants.AddVariant(name)
        variants.SetVariantSelection(name)
        with variants.GetVariantEditContext():
            _define_mesh(stage, "/World/Variant/Shape", *_tube(sections, 1.0, 0.5))
    loaded = stage.DefinePrim("/World/Loaded")
    loaded.GetPayloads().AddInternalPayload("/Proto")
    stage.GetRootLayer().Save()
    texts["instances-variants-payloads"] = stage_path.read_text()
    return texts


def test_every_test_stage_reads_the_same_through_the_fast_path(tmp_path: Path, monkeypatch):
    """Layer for layer, and mesh for mesh through the reader (every array cut)."""
    for name, text in _stage_texts(tmp_path).items():
        _assert_same(text)
        data = text.encode()
        monkeypatch.setattr(usd, "cut_arrays", lambda d, **k: None)
        plain = load_source(data, "usda")
        monkeypatch.setattr(usd, "cut_arrays", lambda d, **k: cut_arrays(d, 1, **k))
        fast = load_source(data, "usda")
        assert fast.mesh.content_hash() == plain.mesh.content_hash(), name
        for field in ("corners", "vertex", "face_group", "normals"):
            a, b = getattr(fast.attributes, field), getattr(plain.attributes, field)
            assert (a is None and b is None) or np.array_equal(a, b), (name, field)


HOSTILE = {
    "blanks and newlines in tuples": "point3f[] points = [ ( 0 ,0,0 )\n,\n(1, 0,\t0), (0,1,0) ]",
    "scientific notation": "point3f[] points = [(1e-30, 6.123234e-17, 1E+5), (1.e5, -0, 007), "
    "(0.12345678901234567890123, 123456789012345678, 2.5e-320)]",
    "doubles": "double3[] xformOpValues = [(0.1, 0.2, 0.30000000000000004), (1e300, -1e-300, 5)]",
    "nan and inf": "point3f[] points = [(nan, 0, 0), (-inf, 1, 1), (inf, 2, 2)]",
    "None": "point3f[] points = None",
    "a trailing comma": "int[] faceVertexIndices = [0, 1, 2,]",
    "a comment inside": "int[] faceVertexCounts = [3, # three\n 3]",
    "floats in an int array": "int[] faceVertexIndices = [0, 1.5, 2e1]",
    "ints out of range": "int[] faceVertexIndices = [0, 3000000000, 2]",
    "a tuple too short": "point3f[] points = [(0, 0), (1, 1, 1)]",
    "a number outside a tuple": "point3f[] points = [(0, 0, 0), 1]",
    "int blanks": "int[] faceVertexCounts = [\n 3 ,3,\n\t3\n]",
    "int edges": "int[] faceVertexIndices = [-0, 007, 2147483647, -2147483648, 0000000000001]",
    "int line break before a comma": "int[] faceVertexCounts = [3\n, 3]",
    "int too many digits": "int[] faceVertexIndices = [12345678901, 1]",
    "a plus sign": "float[] widths = [+1, 2]",
    "a leading dot": "float[] widths = [.5, 2]",
    "time samples": "point3f[] points.timeSamples = {\n 0: [(0, 0, 0), (1, 0, 0)],\n"
    " 1: [(0, 1, 0), (1, 1, 0)] }",
    "half types": "half3[] halves = [(0.1, 0.2, 0.3)]",
    "texture coordinates": "texCoord2f[] primvars:st = [(0, 0), (1, 0.5)] (\n"
    ' interpolation = "vertex"\n)',
    "colours and widths": "color3f[] primvars:displayColor = [(0.1, 0.2, 0.3)]\n"
    " float[] widths = [1, 2]",
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_hostile_literals_read_as_usd_core_reads_them_or_fall_back(name):
    text = f'#usda 1.0\ndef Mesh "M"\n{{\n    {HOSTILE[name]}\n}}\n'
    exact = name in ("blanks and newlines in tuples", "scientific notation", "doubles",
                     "texture coordinates", "colours and widths", "int blanks",
                     "int edges")  # fmt: skip
    try:
        _full(text)
    except pxr.Tf.ErrorException:  # usd-core refuses it: so must the fast path
        cut, layer = _cut_and_restored(text)
        assert layer is None
        return
    _assert_same(text, cut_expected=exact)


def test_text_that_only_looks_like_an_array_is_left_to_usd_core():
    """An array written inside a doc string, a marker's digits already in the text: the
    fast path declines (the marker is not on an attribute) or picks another marker."""
    inside_string = (
        '#usda 1.0\n(\n    doc = """\nint[] fake = [1, 2, 3]\n"""\n)\n'
        'def Mesh "M"\n{\n    int[] faceVertexCounts = [3]\n    float answer = 9000001\n}\n'
    )
    full = _full(inside_string)
    cut, layer = _cut_and_restored(inside_string)
    assert cut is not None and layer is None  # declined: read again by usd-core alone
    no_string = inside_string.replace('"""\nint[] fake = [1, 2, 3]\n"""', '"plain"')
    cut, layer = _cut_and_restored(no_string)
    assert cut.arrays[0].marker != 9000001
    assert layer.ExportToString() == _full(no_string).ExportToString()
    assert full.GetAttributeAtPath("/M.answer").default == 9000001


def test_floats_round_through_a_double_as_usd_core_rounds_them():
    """Decimals just past a float midpoint: correctly rounded to a double they land on
    the midpoint, and usd-core (as our kernel) then rounds that double to even."""
    getcontext().prec = 60
    rng = np.random.default_rng(7)
    literals = []
    for _ in range(400):
        low = np.float32(rng.uniform(0.01, 1000))
        high = np.nextafter(low, np.float32(np.inf))
        middle = (Decimal(float(low)) + Decimal(float(high))) / 2
        literals.append(f"{middle}{rng.integers(1, 10)}" if rng.random() < 0.5 else f"{middle}")
        literals.append(f"{rng.uniform(-1e3, 1e3):.{rng.integers(1, 18)}g}")
        literals.append(f"{rng.uniform(1, 10):.9f}e{rng.integers(-40, 40)}")
    text = f'#usda 1.0\ndef Mesh "M"\n{{\n    float[] widths = [{", ".join(literals)}]\n}}\n'
    _assert_same(text)


def test_the_reader_falls_back_and_bounds_arrays_before_making_them(monkeypatch):
    from neural_shdf.exchange._common import MeshLimits

    points = ", ".join(f"({k}, {k % 7}, {k % 3})" for k in range(300))
    indices = ", ".join(str(k) for k in range(297))
    text = (
        f'#usda 1.0\n(\n    doc = """\nint[] fake = [1, 2, 3]\n"""\n)\n'
        f'def Mesh "M"\n{{\n    int[] faceVertexCounts = [{", ".join(["3"] * 99)}]\n'
        f"    int[] faceVertexIndices = [{indices}]\n    point3f[] points = [{points}]\n}}\n"
    )
    monkeypatch.setattr(usd, "cut_arrays", lambda d, **k: cut_arrays(d, 1, **k))
    mesh = load_mesh(text.encode(), "usda")  # declined, then read by usd-core alone
    assert mesh.face_count == 99
    with pytest.raises(MeshTooLargeError, match="holds about"):
        usd.read_usd_source("usda", text.encode(), MeshLimits(max_faces=10, max_vertices=20))
    broken = text.replace("faceVertexCounts = [", "faceVertexCounts = [4, ")
    with pytest.raises(MeshError):
        load_mesh(broken.encode(), "usda")


def test_layers_from_outside_are_refused_on_both_paths(tmp_path: Path, monkeypatch):
    """Sublayers (with a layer offset), references and payloads to other files: the same
    error whether or not the arrays were cut first (the composition arcs are usd-core's
    parse of the same text either way)."""
    path = tmp_path / "dumbbell.usda"
    _dumbbell_stage(path)
    body = path.read_text()
    variants = [
        body.replace(
            "defaultPrim",
            "subLayers = [@./other.usda@ (offset = 10; scale = 2)]\n    defaultPrim",
            1,
        ),  # fmt: skip
        *(
            body.replace(
                'def Xform "Bar"', f'def Xform "Bar" (\n    {arc} = @./other.usda@</X>\n)', 1
            )
            for arc in ("references", "payload")
        ),
        body.replace("defaultPrim", "subLayers = [@/etc/hostname@]\n    defaultPrim", 1),
    ]
    for text in variants:
        assert text != body
        outcomes = []
        for cutting in (False, True):
            monkeypatch.setattr(
                usd,
                "cut_arrays",
                (lambda d, **k: cut_arrays(d, 1, **k)) if cutting else (lambda d, **k: None),
            )
            with pytest.raises(MeshError) as refused:
                load_mesh(text.encode(), "usda")
            outcomes.append((type(refused.value), str(refused.value)))
        assert outcomes[0] == outcomes[1]
