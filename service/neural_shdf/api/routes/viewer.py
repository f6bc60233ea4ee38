"""The web viewer: the page at /viewer/, its scripts, and the local three.js copy."""

from __future__ import annotations

from fastapi import APIRouter, FastAPI, Request
from fastapi.responses import HTMLResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles

from neural_shdf.api.settings import Settings
from neural_shdf.api.viewer import LOCAL_THREE_PATH, STATIC_DIR, render_page, three_source

router = APIRouter(include_in_schema=False)


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
    local = three_source(settings).local_dir
    if local is not None:
        app.mount(LOCAL_THREE_PATH.rstrip("/"), StaticFiles(directory=local), name="viewer-three")
