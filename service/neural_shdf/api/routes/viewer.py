"""The web viewer: the page at /viewer/, its scripts, and the local three.js copy."""

from __future__ import annotations

import logging

from fastapi import APIRouter, FastAPI, Request
from fastapi.responses import HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

from neural_shdf.api.settings import Settings
from neural_shdf.api.viewer import LOCAL_THREE_PATH, STATIC_DIR, render_page, three_source

router = APIRouter(include_in_schema=False)
logger = logging.getLogger(__name__)


@router.get("/")
async def root() -> RedirectResponse:
    """The service's home is the viewer."""
    return RedirectResponse("/viewer/")


@router.get("/viewer")
@router.get("/viewer/")
async def viewer_page(request: Request) -> HTMLResponse:
    """The viewer's single page."""
    page = render_page(request.app.state.settings)
    return HTMLResponse(page, headers={"Cache-Control": "no-cache"})


def install_viewer(app: FastAPI, settings: Settings) -> None:
    """Add the page, its static files and (when installed) the local three.js copy."""
    app.include_router(router)
    app.mount("/viewer/static", StaticFiles(directory=STATIC_DIR), name="viewer-static")
    source = three_source(settings)
    if source.local_dir is not None:
        three = StaticFiles(directory=source.local_dir)
        app.mount(LOCAL_THREE_PATH.rstrip("/"), three, name="viewer-three")
    elif not settings.viewer_three_url:
        logger.warning(
            "web viewer: three.js comes from %s (needs the internet); offline: %s",
            source.base_url,
            "run `npm ci` in neural_shdf/viewer or set NEURAL_SHDF_VIEWER_THREE_DIR",
        )
