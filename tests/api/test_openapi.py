"""The committed openapi/openapi.json is the app's schema; operations and models are documented."""

from __future__ import annotations

import json

from neural_shdf.api.openapi import openapi_document, render
from tests.api.api_helpers import REPO_ROOT

COMMITTED = REPO_ROOT / "openapi" / "openapi.json"
OPERATIONS = {
    "health", "ready", "metrics", "upload_mesh", "get_mesh", "delete_mesh", "get_shdf",
    "get_job", "segment_mesh", "segment_file", "get_colored_glb", "get_parts_glb", "get_geometry",
    "get_unwrapped_glb", "get_atlas_png", "get_parts_usda", "upload_labeler", "list_labelers",
    "get_labeler", "get_labeler_file", "delete_labeler", "train_labeler", "get_unwrapped_obj",
    "get_uvs",
}  # fmt: skip


def test_committed_schema_matches_the_app():
    assert COMMITTED.is_file(), "run: python -m neural_shdf.api.openapi > openapi/openapi.json"
    assert json.loads(COMMITTED.read_text()) == json.loads(render()), (
        "openapi/openapi.json is stale; regenerate it with "
        "`python -m neural_shdf.api.openapi > openapi/openapi.json`"
    )


def test_operation_ids_are_stable_and_documented():
    document = openapi_document()
    found = {
        operation["operationId"]: operation
        for path in document["paths"].values()
        for operation in path.values()
    }
    assert set(found) == OPERATIONS
    for operation_id, operation in found.items():
        assert operation.get("summary") and operation.get("description"), operation_id


def test_every_model_field_has_a_description_and_example():
    schemas = openapi_document()["components"]["schemas"]
    for name, schema in schemas.items():
        if name.startswith(("Body_", "HTTPValidationError", "ValidationError")):
            continue
        assert schema.get("description"), f"{name} has no description"
        for field, spec in schema.get("properties", {}).items():
            assert spec.get("description"), f"{name}.{field} has no description"
            has_example = "examples" in spec or "example" in spec or "$ref" in spec
            has_example = has_example or any("$ref" in s for s in spec.get("anyOf", []))
            has_example = has_example or "contentMediaType" in spec  # a file upload
            assert has_example or "examples" in schema, f"{name}.{field} has no example"


def test_links_lead_from_a_stored_mesh_to_every_route_that_takes_its_id():
    operations = {
        operation["operationId"]: operation
        for path in openapi_document()["paths"].values()
        for operation in path.values()
    }
    takes_mesh_id = {
        operation_id
        for operation_id, operation in operations.items()
        if any(p["name"] == "mesh_id" for p in operation.get("parameters", []))
    } | {"segment_mesh"}
    for source, pointer in (("upload_mesh", "/mesh/mesh_id"), ("segment_file", "/mesh_id")):
        links = operations[source]["responses"]["200"]["links"]
        assert {link["operationId"] for link in links.values()} == takes_mesh_id
        for link in links.values():
            expression = (
                link.get("parameters", {}).get("path.mesh_id") or link["requestBody"]["mesh_id"]
            )
            assert expression == f"$response.body#{pointer}"
    for operation in operations.values():
        if "202" in operation["responses"]:
            assert operation["responses"]["202"]["links"]["GetJob"]["operationId"] == "get_job"
