"""The FastAPI application: ``create_app(settings)``."""

from __future__ import annotations

import gc
import logging
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI, Request
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse

from neural_shdf import __version__
from neural_shdf.api.clients import ClientMiddleware
from neural_shdf.api.docs import install_docs
from neural_shdf.api.engine import Engine
from neural_shdf.api.errors import BodySizeLimitMiddleware, install_error_handlers
from neural_shdf.api.jobs import JobAccepted, public_job
from neural_shdf.api.links import add_links
from neural_shdf.api.metrics import Metrics, RequestMetricsMiddleware
from neural_shdf.api.routes import health, jobs, labelers, meshes, segment, unwrap
from neural_shdf.api.routes.viewer import install_viewer
from neural_shdf.api.settings import Settings
from neural_shdf.pipeline import warm_up
from neural_shdf.store.cache import CacheConfig, ResultCache, open_cache

DESCRIPTION = """Segment polygonal meshes into parts with the Shape Diameter Function (ShDF).

Upload a mesh once (`POST /v1/meshes`): it is stored under the hash of its geometry and
its ShDF is computed once and cached. Then segment it as often as you like
(`POST /v1/segment`): only the partitioning runs. Every error has the same shape:
`{"error": {"code", "message", "detail"}}`.

Clients that upload the same geometry share its id and everything computed from it; each
upload's file name, format and time are answered to that upload only and never stored.
Deleting a mesh deletes it for all of them, for good: nothing computed from it is stored
after the delete.
"""

logger = logging.getLogger(__name__)


def build_cache(settings: Settings, metrics: Metrics) -> ResultCache:
    """The settings' cache (``store.cache.open_cache``), its faults counted in ``metrics``."""
    return open_cache(
        CacheConfig.of(settings),
        on_error=lambda exc: metrics.cache_errors.inc(),
        on_degraded=lambda is_open: metrics.cache_degraded.set(int(is_open)),
        on_corrupt=lambda key: metrics.cache_corrupt.inc(),
    )


#: Seconds a thread may hold the GIL while another waits for it (Python's default: 0.005).
SWITCH_INTERVAL_S = 0.001


def create_app(settings: Settings | None = None) -> FastAPI:
    """The service with its cache, metrics and compute pool."""
    settings = settings or Settings()
    metrics = Metrics()
    engine = Engine(settings, build_cache(settings, metrics), metrics)

    @asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        logger.info(
            "neural-shdf %s: default ShDF method %s, model %s, cache %s",
            __version__,
            settings.default_method,
            engine.shdf.model_path,
            engine.cache.backend.name,
        )
        if settings.warm_up:
            # The first request then pays no compilation (seconds on a fresh install).
            logger.info(
                "warming up: a small sphere through the face graph, both ShDF methods and "
                "both partitioners (compiles the numba kernels once after an install, about "
                "15 s; later starts load them from their cache)"
            )
            try:
                seconds = await engine.run(warm_up)
                logger.info("warm-up done in %.2f s", seconds)
            except Exception:  # a failing path fails again, visibly, on its first request
                logger.exception("warm-up failed; serving anyway")
        # Everything loaded so far (modules, compiled kernels, the model) lives as long as the
        # process: out of the collector's sight, a full collection no longer walks them all
        # while holding the GIL, which stalled the event loop whenever a request's work
        # allocated enough to trigger one (docs/benchmarks.md, "Event-loop stalls").
        gc.collect()
        gc.freeze()
        # The event loop's thread waits for the GIL at every switch while compute threads
        # run; a shorter interval than Python's 5 ms bounds each of those waits.
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        yield
        await engine.close()
        engine.cache.close()

    app = FastAPI(
        title="neural-shdf",
        version=__version__,
        description=DESCRIPTION,
        lifespan=lifespan,
        docs_url=None,  # served from local assets by install_docs (works offline)
        redoc_url=None,
    )
    app.state.settings = settings
    install_docs(app)
    app.state.engine = engine
    install_error_handlers(app)

    async def job_accepted(_: Request, exc: Exception) -> JSONResponse:
        assert isinstance(exc, JobAccepted)
        return JSONResponse(
            public_job(exc.job),
            status_code=202,
            headers={"Location": f"/v1/jobs/{exc.job['job_id']}", **exc.headers},
        )

    app.add_exception_handler(JobAccepted, job_accepted)
    for module in (health, meshes, segment, unwrap, labelers, jobs):
        app.include_router(module.router)
    install_viewer(app, settings)
    app.openapi = lambda: _openapi_with_error_shape(app)  # type: ignore[method-assign]
    app.add_middleware(
        BodySizeLimitMiddleware,
        limit=settings.max_upload_bytes,
        read_timeout_s=settings.body_read_timeout_s,
        json_limit=settings.max_json_bytes,
    )
    app.add_middleware(ClientMiddleware)  # who asks, and whether they are still there
    app.add_middleware(RequestMetricsMiddleware, metrics=metrics)
    return app


def _openapi_with_error_shape(app: FastAPI) -> dict[str, Any]:
    """FastAPI's schema with its default 422 body replaced by the service's error shape,
    and links from the operations that answer a mesh or job id to those that take one."""
    if app.openapi_schema is None:
        schema = get_openapi(
            title=app.title,
            version=app.version,
            description=app.description,
            routes=app.routes,
        )
        error_ref = {"$ref": "#/components/schemas/ErrorResponse"}
        for path in schema.get("paths", {}).values():
            for operation in path.values():
                response = operation.get("responses", {}).get("422")
                if response is None:
                    continue
                content = response.setdefault("content", {}).setdefault("application/json", {})
                if content.get("schema", {}).get("$ref", "").endswith("HTTPValidationError"):
                    content["schema"] = error_ref
                    response["description"] = "Invalid request (the message says why)."
        components = schema.get("components", {}).get("schemas", {})
        components.pop("HTTPValidationError", None)
        components.pop("ValidationError", None)
        app.openapi_schema = add_links(schema)
    return app.openapi_schema


def create_app_from_env() -> FastAPI:
    """uvicorn factory (``--factory``): settings from the environment."""
    return create_app(Settings())
