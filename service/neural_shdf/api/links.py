"""OpenAPI links: how the id one operation answers feeds the next.

An upload (or a one-shot segmentation) answers a ``mesh_id``; every operation that
takes a mesh id (in its path or its JSON body) can follow it, and a 202 answers a
``job_id`` to poll. Clients and generators read these links from the schema; the
stateful fuzz test follows them, so it reaches the routes with real meshes.
"""

from __future__ import annotations

from typing import Any

#: Where the mesh id is in the 200 answer of the operations that store a mesh.
MESH_ID_SOURCES = {
    "upload_mesh": "$response.body#/mesh/mesh_id",
    "segment_file": "$response.body#/mesh_id",
}
#: The job id in a 202 answer.
JOB_ID = "$response.body#/job_id"


def _operations(schema: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {
        operation["operationId"]: operation
        for path in schema.get("paths", {}).values()
        for operation in path.values()
        if isinstance(operation, dict) and "operationId" in operation
    }


def _body_fields(schema: dict[str, Any], operation: dict[str, Any]) -> set[str]:
    """Properties of the operation's JSON request body (through one ``$ref``)."""
    body = operation.get("requestBody", {}).get("content", {}).get("application/json", {})
    model = body.get("schema", {})
    reference = model.get("$ref", "")
    if reference.startswith("#/components/schemas/"):
        model = schema["components"]["schemas"][reference.rsplit("/", 1)[1]]
    return set(model.get("properties", {}))


def mesh_id_link(
    schema: dict[str, Any], target_id: str, target: dict[str, Any], expression: str
) -> dict[str, Any] | None:
    """A link passing ``expression`` as the target's mesh id, or None if it takes none."""
    in_path = any(
        parameter.get("name") == "mesh_id" and parameter.get("in") == "path"
        for parameter in target.get("parameters", [])
    )
    link: dict[str, Any] = {"operationId": target_id}
    if in_path:
        link["parameters"] = {"path.mesh_id": expression}
    elif "mesh_id" in _body_fields(schema, target):
        link["requestBody"] = {"mesh_id": expression}
    else:
        return None
    link["description"] = f"The stored mesh's id as `mesh_id` of `{target_id}`."
    return link


def add_links(schema: dict[str, Any]) -> dict[str, Any]:
    """Add the mesh-id and job-id links to ``schema`` (in place); returns it."""
    operations = _operations(schema)
    job_poll = "get_job" in operations
    for source_id, expression in MESH_ID_SOURCES.items():
        source = operations.get(source_id)
        if source is None:
            continue
        links = {}
        for target_id, target in sorted(operations.items()):
            link = mesh_id_link(schema, target_id, target, expression)
            if link is not None:
                links[_link_name(target_id)] = link
        if links:
            source["responses"]["200"]["links"] = links
    if job_poll:
        for operation in operations.values():
            accepted = operation.get("responses", {}).get("202")
            if accepted is not None:
                accepted["links"] = {
                    "GetJob": {
                        "operationId": "get_job",
                        "parameters": {"path.job_id": JOB_ID},
                        "description": "Poll the job until it is `succeeded` or `failed`.",
                    }
                }
    return schema


def _link_name(operation_id: str) -> str:
    """``get_colored_glb`` -> ``GetColoredGlb``."""
    return "".join(part.capitalize() for part in operation_id.split("_"))
