"""Schemathesis against the committed openapi/openapi.json: no 5xx, responses match the schema."""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, settings

from tests.api.api_helpers import REPO_ROOT, make_settings

schemathesis = pytest.importorskip("schemathesis", reason="schemathesis is not installed")

from neural_shdf.api.app import create_app  # noqa: E402


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
    response = case.call()
    assert response.status_code < 500, response.text
    # A schema-valid request may still carry an unusable mesh (422 saying why): the
    # positive-data check cannot know that, every other built-in check runs.
    case.validate_response(response, excluded_checks=[schemathesis.checks.positive_data_acceptance])
