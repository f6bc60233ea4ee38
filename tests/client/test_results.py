"""The client's wire models: the service's response models field by field, parsed from
real answers, and usable where FastAPI, pydantic and the compiled library are missing."""

from __future__ import annotations

import dataclasses
import json
import os
import re
import subprocess
import sys
import typing
from pathlib import Path

import httpx
import numpy as np
import pytest
from pydantic import BaseModel

from neural_shdf.api import schemas
from neural_shdf.client import results, unwrapping
from neural_shdf.mesh_io import load_mesh
from neural_shdf.pipeline import compute_shdf, segment
from neural_shdf.segment import SegmentParams
from tests.api.api_helpers import MODEL_FILE, TEST_METHOD, capsule

#: Each wire model of the client and the service's response model it mirrors.
MIRRORS = [
    (results.ErrorDetail, schemas.ErrorDetail),
    (results.MeshDiagnostics, schemas.MeshDiagnosticsInfo),
    (results.MeshInfo, schemas.MeshInfo),
    (results.ShdfStatus, schemas.ShdfStatus),
    (results.Job, schemas.Job),
    (results.PartSummary, schemas.PartSummary),
    (results.Timings, schemas.Timings),
    (results.LabelerInfo, schemas.LabelerInfo),
    (unwrapping.UvLayout, schemas.UvLayout),
    (results.Upload, schemas.UploadResult),
]
#: What the client must never need: the service's and the library's heavy dependencies.
BLOCKED = ("fastapi", "pydantic", "numba", "trimesh", "onnxruntime", "scipy", "sklearn")


def _models_in(annotation: object) -> list[type[BaseModel]]:
    """The pydantic models inside a field's type (``X | None``, ``list[X]``)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [found for arg in typing.get_args(annotation) for found in _models_in(arg)]


def schema_example(model: type[BaseModel]) -> dict[str, object]:
    """A JSON answer of ``model`` built from its documented examples (nested models too),
    validated by the service's own model."""
    body: dict[str, object] = {}
    for name, info in model.model_fields.items():
        if info.examples:
            body[name] = info.examples[0]
        elif nested := _models_in(info.annotation):
            value = schema_example(nested[0])
            body[name] = [value] if typing.get_origin(info.annotation) is list else value
        else:
            assert not info.is_required(), f"{model.__name__}.{name} documents no example"
    return model.model_validate(body).model_dump(mode="json")


@pytest.mark.parametrize(("wire", "schema"), MIRRORS, ids=lambda m: m.__name__)
def test_wire_models_have_the_fields_of_the_services_models(wire, schema):
    """Same names, and the same ones required: a field added, renamed or made optional on
    either side fails here, not in a user's client."""
    fields = {spec.name: spec for spec in dataclasses.fields(wire)}
    assert set(fields) == set(schema.model_fields)
    required = {
        name
        for name, spec in fields.items()
        if spec.default is dataclasses.MISSING and spec.default_factory is dataclasses.MISSING
    }
    assert required == {name for name, info in schema.model_fields.items() if info.is_required()}


def test_segmentation_reads_every_member_of_the_services_answer():
    assert set(schemas.Segmentation.model_fields) == results.SEGMENTATION_FIELDS
    assert set(schemas.PartHierarchy.model_fields) == results.HIERARCHY_FIELDS


@pytest.mark.parametrize(
    ("wire", "schema"), [m for m in MIRRORS if m[0] is not results.Upload], ids=lambda m: m.__name__
)
def test_wire_models_parse_the_services_answers(wire, schema):
    body = schema_example(schema)
    parsed = wire.from_json({**body, "added_by_a_newer_service": 1})
    assert dataclasses.asdict(parsed) == body
    required = next(name for name, info in schema.model_fields.items() if info.is_required())
    with pytest.raises(ValueError, match=wire.__name__):
        wire.from_json({k: v for k, v in body.items() if k != required})


def test_a_real_segmentation_answer_parses_as_the_service_describes_it(service, tmp_path):
    mesh_id = httpx.post(
        f"{service}/v1/meshes",
        files={"file": ("capsule.obj", capsule().export(file_type="obj").encode())},
        timeout=120,
    ).json()["mesh"]["mesh_id"]
    for labels_format in ("json", "base64"):
        body = httpx.post(
            f"{service}/v1/segment",
            json={"mesh_id": mesh_id, "clusters": 3, "labels_format": labels_format},
            timeout=120,
        ).json()
        described = schemas.Segmentation.model_validate(body)
        parsed = results.Segmentation.from_json(body)
        assert (parsed.mesh_id, parsed.method, parsed.part_count) == (
            described.mesh_id,
            described.method,
            described.part_count,
        )
        assert [dataclasses.asdict(part) for part in parsed.parts] == [
            part.model_dump() for part in described.parts
        ]
        assert dataclasses.asdict(parsed.timings) == described.timings.model_dump()
        tree, hierarchy = described.hierarchy, parsed.hierarchy
        assert tree is not None and hierarchy is not None
        assert hierarchy.parent.tolist() == tree.parent
        assert hierarchy.labels().tolist() == parsed.labels.tolist()  # the automatic cut
        assert parsed.extra == {}


# Run by a Python whose import system refuses ``BLOCKED``: the client must work there.
_WITHOUT_HEAVY_DEPENDENCIES = """
import importlib.abc, json, sys

blocked = set(sys.argv[3].split(","))


class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in blocked:
            raise ImportError(f"{name} is not installed here")
        return None


sys.meta_path.insert(0, Refuse())
from neural_shdf.client import Client

with Client(sys.argv[1]) as client:
    uploaded = client.upload(sys.argv[2])
    segmentation = client.segment(uploaded.mesh_id, clusters=3)
    info = client.mesh(uploaded.mesh_id)
    shdf = client.shdf(uploaded.mesh_id)
loaded = sorted(name for name in sys.modules if name.partition(".")[0] in blocked)
print(json.dumps({
    "mesh_id": uploaded.mesh_id,
    "faces": info.faces,
    "shells": info.diagnostics.shells,
    "method": uploaded.shdf.method,
    "labels": segmentation.labels.tolist(),
    "parts": [part.faces for part in segmentation.parts],
    "shdf_values": len(shdf),
    "loaded": loaded,
}))
"""


def test_the_client_works_without_fastapi_pydantic_or_the_compiled_library(service, tmp_path: Path):
    """Upload and segment through a real server from a Python where every one of
    ``BLOCKED`` fails to import; the labels are the library's."""
    path = tmp_path / "capsule.obj"
    path.write_bytes(capsule().export(file_type="obj").encode())
    run = subprocess.run(
        [sys.executable, "-c", _WITHOUT_HEAVY_DEPENDENCIES, service, str(path), ",".join(BLOCKED)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    assert run.returncode == 0, run.stderr
    answer = json.loads(run.stdout)
    assert answer["loaded"] == []
    mesh = load_mesh(path)
    shdf = compute_shdf(mesh, method=TEST_METHOD, model=MODEL_FILE).values
    expected = segment(mesh, shdf, SegmentParams(clusters=3)).labels
    assert answer["labels"] == np.asarray(expected).tolist()
    assert answer["method"] == TEST_METHOD and answer["faces"] == mesh.input_face_count
    assert answer["parts"] == np.bincount(expected).tolist()
    assert answer["shdf_values"] == mesh.input_face_count and answer["shells"] == 1


def test_the_blocker_refuses_what_it_should(tmp_path):
    """The test above proves something only if the blocker works: ``neural_shdf.mesh``
    (scipy, numba) must fail to import under it, on the first blocked module it meets."""
    probe = _WITHOUT_HEAVY_DEPENDENCIES.split("from neural_shdf.client")[0]
    probe += "import neural_shdf\nimport neural_shdf.mesh\n"
    run = subprocess.run(
        [sys.executable, "-c", probe, "", "", ",".join(BLOCKED)],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)},
    )
    assert run.returncode != 0
    assert re.search(r"ImportError: (scipy|numba) is not installed here", run.stderr)


def test_a_named_parts_answer_parses_in_both_forms(service):
    from tests.labeling.helpers import labelled_dumbbell, obj_of, small_labeler_file

    labeler = httpx.post(
        f"{service}/v1/labelers", files={"file": ("l.npz", small_labeler_file())}, timeout=120
    ).json()["labeler_id"]
    mesh_id = httpx.post(
        f"{service}/v1/meshes",
        files={"file": ("d.obj", obj_of(labelled_dumbbell(1500, 0.9, 3)[0]))},
        timeout=120,
    ).json()["mesh"]["mesh_id"]
    parsed = {}
    for labels_format in ("json", "base64"):
        body = httpx.post(
            f"{service}/v1/segment",
            json={"mesh_id": mesh_id, "labeler_id": labeler, "labels_format": labels_format},
            timeout=120,
        ).json()
        described = schemas.Segmentation.model_validate(body)
        parsed[labels_format] = results.Segmentation.from_json(body)
        assert parsed[labels_format].label_names == described.label_names == ["neck", "ball"]
        assert [part.name for part in parsed[labels_format].parts] == ["neck", "ball"]
        assert parsed[labels_format].extra == {}
    json_form, compact = parsed["json"], parsed["base64"]
    np.testing.assert_array_equal(json_form.labels, compact.labels)
    assert json_form.confidence is not None and compact.confidence is not None
    np.testing.assert_allclose(json_form.confidence, compact.confidence, atol=1e-4)
