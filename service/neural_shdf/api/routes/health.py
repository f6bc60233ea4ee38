"""Liveness, readiness and metrics."""

from __future__ import annotations

from fastapi import APIRouter, Response
from fastapi.responses import JSONResponse

from neural_shdf.api.metrics import CONTENT_TYPE_LATEST
from neural_shdf.api.routes.deps import EngineDep
from neural_shdf.api.schemas import Health, Readiness
from neural_shdf.shdf.stage import uses_model

router = APIRouter(tags=["operations"])


@router.get("/healthz", operation_id="health", response_model=Health, summary="Liveness")
async def health() -> Health:
    """The process is up and answering."""
    return Health(status="ok")


@router.get(
    "/readyz",
    operation_id="ready",
    response_model=Readiness,
    summary="Readiness",
    responses={503: {"model": Readiness, "description": "Not ready (model or cache)."}},
)
async def ready(engine: EngineDep) -> JSONResponse:
    """Ready when the neural model loads (if it is the default method) and the cache answers;
    `degraded` (still 200: requests are served) while Redis is down and the local disk
    cache stands in."""
    model_ok, model_detail = await engine.io(engine.shdf.check_model)
    if not uses_model(engine.settings.default_method) and not model_ok:
        default = engine.settings.default_method
        model_ok, model_detail = True, f"not needed (default method {default}): {model_detail}"
    cache_ok, cache_detail = await engine.io(engine.cache.health)
    degraded = not cache_ok and getattr(engine.cache.backend, "degraded", False)
    checks = {
        "model": {"ok": model_ok, "detail": model_detail},
        "cache": {"ok": cache_ok, "detail": cache_detail},
    }
    status = "ready" if model_ok and cache_ok else "degraded" if model_ok and degraded else None
    body = Readiness(status=status or "not_ready", checks=checks)  # type: ignore[arg-type]
    return JSONResponse(body.model_dump(), status_code=503 if status is None else 200)


@router.get(
    "/metrics",
    operation_id="metrics",
    summary="Prometheus metrics",
    response_class=Response,
    responses={200: {"content": {CONTENT_TYPE_LATEST: {}}, "description": "Metrics."}},
)
async def metrics(engine: EngineDep) -> Response:
    """Counters and histograms in the Prometheus text format."""
    return Response(engine.metrics.export(), media_type=CONTENT_TYPE_LATEST)
