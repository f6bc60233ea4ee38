"""The REST service (FastAPI): ``app.create_app(settings)``; ``serve.run`` is ``neural-shdf serve``.

Endpoints (schema: ``openapi/openapi.json``, regenerated with
``python -m neural_shdf.api.openapi > openapi/openapi.json``; interactive docs at ``/docs``):

* ``POST /v1/meshes`` upload (multipart OBJ, GLB/glTF, OFF, PLY, STL, USD) -> mesh id (content hash)
  and its ShDF computed once; 202 + job above ``sync_face_threshold`` triangles;
* ``GET|DELETE /v1/meshes/{mesh_id}``; ``GET /v1/meshes/{mesh_id}/shdf`` (JSON, or float32
  little-endian with ``format=f32`` / ``Accept: application/octet-stream``);
* ``GET /v1/jobs/{job_id}``: state and progress of a long computation;
* ``POST /v1/segment`` (mesh id + parameters; only the partitioning runs) and
  ``POST /v1/segment/file`` (one shot, multipart); labels per input face, parts, timings;
* ``GET /v1/meshes/{mesh_id}/segmentation/colored.glb``, ``.../parts.glb`` and
  ``.../parts.usda`` (a GeomSubset per part);
* ``/healthz``, ``/readyz``, ``/metrics``.

Settings: ``settings.Settings``, every field from the environment as ``NEURAL_SHDF_<NAME>``.
"""
