"""``GET /docs`` (Swagger UI) and ``GET /redoc`` (ReDoc), with their assets served by this app.

FastAPI's own pages load Swagger UI and ReDoc from a CDN, so they are blank without internet.
These pages load the same files from ``/static/docs/``, a copy installed with the
``fastapi-offline`` package (Swagger UI 5's ``swagger-ui-bundle.js`` and ``swagger-ui.css``,
ReDoc 2's ``redoc.standalone.js`` and FastAPI's favicon). Only its asset folder is used, not its
``FastAPIOffline`` app factory.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.openapi.docs import (
    get_redoc_html,
    get_swagger_ui_html,
    get_swagger_ui_oauth2_redirect_html,
)
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

STATIC_URL = "/static/docs"
ASSETS = ("swagger-ui-bundle.js", "swagger-ui.css", "redoc.standalone.js", "favicon.png")


def assets_dir() -> Path:
    """The installed folder with the Swagger UI and ReDoc files."""
    folder = Path(str(files("fastapi_offline").joinpath("static")))
    missing = [name for name in ASSETS if not (folder / name).is_file()]
    if missing:
        raise RuntimeError(f"fastapi-offline has no {', '.join(missing)} in {folder}; "
                           "the /docs and /redoc pages need them")
    return folder


def install_docs(app: FastAPI, docs_url: str = "/docs", redoc_url: str = "/redoc") -> None:
    """Mount the assets and add the two pages (and Swagger UI's OAuth2 redirect page).

    ``app`` must be created with ``docs_url=None, redoc_url=None``. None of these routes is in
    the OpenAPI schema.
    """
    app.mount(STATIC_URL, StaticFiles(directory=assets_dir()), name="docs-static")
    oauth2_redirect_url = f"{docs_url}/oauth2-redirect"

    def url(request: Request, path: str) -> str:
        return f"{request.scope.get('root_path', '')}{path}"

    # add_route, as FastAPI adds its own docs pages: plain Starlette routes, GET and HEAD.
    async def swagger_ui(request: Request) -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=url(request, app.openapi_url or "/openapi.json"),
            title=f"{app.title} - Swagger UI",
            oauth2_redirect_url=url(request, oauth2_redirect_url),
            swagger_js_url=url(request, f"{STATIC_URL}/swagger-ui-bundle.js"),
            swagger_css_url=url(request, f"{STATIC_URL}/swagger-ui.css"),
            swagger_favicon_url=url(request, f"{STATIC_URL}/favicon.png"),
            swagger_ui_parameters=app.swagger_ui_parameters,
        )

    async def swagger_ui_oauth2_redirect(request: Request) -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()

    async def redoc(request: Request) -> HTMLResponse:
        return get_redoc_html(
            openapi_url=url(request, app.openapi_url or "/openapi.json"),
            title=f"{app.title} - ReDoc",
            redoc_js_url=url(request, f"{STATIC_URL}/redoc.standalone.js"),
            redoc_favicon_url=url(request, f"{STATIC_URL}/favicon.png"),
            with_google_fonts=False,  # fonts.googleapis.com: ReDoc falls back to system fonts
        )

    app.add_route(docs_url, swagger_ui, include_in_schema=False)
    app.add_route(oauth2_redirect_url, swagger_ui_oauth2_redirect, include_in_schema=False)
    app.add_route(redoc_url, redoc, include_in_schema=False)
