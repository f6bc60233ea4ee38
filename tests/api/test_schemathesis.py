"""Schemathesis against the committed openapi/openapi.json: no 5xx, responses match the schema."""

from __future__ import annotations

import zlib

import pytest
from hypothesis import HealthCheck, settings

from tests.api.api_helpers import REPO_ROOT, make_settings

schemathesis = pytest.importorskip("schemathesis", reason="schemathesis is not installed")

from schemathesis import GenerationMode  # noqa: E402

from neural_shdf.api.app import create_app  # noqa: E402

#: Seconds a fuzzed request may take: valid ones include an 8192-texel UV atlas, which on a
#: busy 2-core machine takes longer than the ASGI transport's default 10 s.
CALL_TIMEOUT_S = 120


@pytest.fixture
def api_schema(tmp_path):
    schema = schemathesis.openapi.from_path(REPO_ROOT / "openapi" / "openapi.json")
    schema.app = create_app(make_settings(tmp_path / "cache", max_upload_bytes=200_000))
    return schema


schema = schemathesis.pytest.from_fixture("api_schema")


@schema.parametrize()
@settings(
    max_examples=12,
    deadline=None,
    suppress_health_check=list(HealthCheck),
)
def test_api_conforms_to_its_schema(case):
    response = case.call(timeout=CALL_TIMEOUT_S)
    assert response.status_code < 500, response.text
    # A schema-valid request may still carry an unusable mesh (422 saying why): the
    # positive-data check cannot know that, every other built-in check runs.
    case.validate_response(response, excluded_checks=[schemathesis.checks.positive_data_acceptance])


#: Operations that store a mesh, whose file the stateful test replaces with a real one.
UPLOADS = ("upload_mesh", "segment_file")


#: Small real meshes the stateful test uploads in place of schemathesis's random bytes.
def _real_meshes() -> list[tuple[str, bytes]]:
    from tests.api.api_helpers import capsule, obj_bytes, quad_box

    vertices, quads = quad_box((0, 0, 0), 1.0)
    return [
        ("capsule.obj", capsule(8).export(file_type="obj").encode()),
        ("capsule.ply", capsule(6).export(file_type="ply")),
        ("box.obj", obj_bytes(vertices, quads)),
    ]


def test_stateful_fuzzing_follows_the_links_from_real_uploads(tmp_path):
    """Upload real meshes, then follow the schema's links with fuzzed parameters to every
    route that takes the mesh id (segment, ShDF, GLBs, ...) and to the job polls."""
    from collections import Counter

    # Without the labeller and unwrap routes (the stateless test fuzzes them; their own
    # tests cover them): with them the walk spent its steps listing labellers or fetching
    # UVs and reached segment_mesh in 2 of 40 examples.
    schema = schemathesis.openapi.from_path(REPO_ROOT / "openapi" / "openapi.json").exclude(
        path_regex="^/v1/labeler|/segmentation/(uvs|unwrapped|atlas)"
    )
    schema.app = create_app(make_settings(tmp_path / "cache", max_upload_bytes=200_000))
    meshes = _real_meshes()
    statuses: Counter[tuple[str, int]] = Counter()

    # Negative cases are the stateless test's job; here every step is schema-valid, so
    # that uploads succeed and the links lead somewhere.
    schema.config.generation.update(modes=[GenerationMode.POSITIVE])

    class Workflow(schema.as_state_machine()):  # type: ignore[misc]
        def before_call(self, case):
            if case.operation.definition.raw.get("operationId") in UPLOADS:
                body = dict(case.body) if isinstance(case.body, dict) else {}
                fields = repr(sorted((k, repr(v)) for k, v in body.items() if k != "file"))
                name, data = meshes[zlib.crc32(fields.encode()) % len(meshes)]  # replayable
                body["file"] = data
                body["file_type"] = name.rsplit(".", 1)[1]
                case.body = body

        def get_call_kwargs(self, case):
            return {"timeout": CALL_TIMEOUT_S}

        def after_call(self, response, case):
            statuses[(case.operation.definition.raw.get("operationId"), response.status_code)] += 1

        def validate_response(self, response, case, additional_checks=None, **kwargs):
            assert response.status_code < 500, response.text
            excluded = [schemathesis.checks.positive_data_acceptance]
            if case.operation.definition.raw.get("operationId") in UPLOADS:
                # Its generated body was replaced by a real file: whether the generator
                # meant it to be valid says nothing about what was sent.
                excluded.append(schemathesis.checks.negative_data_rejection)
            case.validate_response(
                response, excluded_checks=excluded, transport_kwargs=kwargs or None
            )

    Workflow.run(
        settings=settings(
            # Derandomized, yet which links it follows depends on the schema and on
            # timing (an upload answered by a job offers other links): 10 examples left
            # get_shdf or segment_mesh unreached once `crease_boundaries` joined the schema.
            max_examples=20,
            stateful_step_count=8,
            deadline=None,
            suppress_health_check=list(HealthCheck),
            derandomize=True,
        )
    )
    reached = {operation for (operation, status), _ in statuses.items() if status == 200}
    assert {"upload_mesh", "segment_mesh", "get_shdf"} <= reached, statuses
    assert reached & {"get_colored_glb", "get_parts_glb"}, statuses
