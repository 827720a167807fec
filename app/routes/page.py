"""``GET /``: the web page; ``GET /demo.glb``: the built-in demo scene."""

from __future__ import annotations

from functools import lru_cache
from importlib.resources import files

from fastapi import APIRouter
from fastapi.responses import HTMLResponse, Response
from starlette.concurrency import run_in_threadpool

from shadowmap.renderer.demo import demo_glb

router = APIRouter(tags=["page"])


@lru_cache(maxsize=1)
def _page() -> str:
    return files("shadowmap.app").joinpath("static/index.html").read_text(encoding="utf-8")


@router.get("/", response_class=HTMLResponse, include_in_schema=False)
def index() -> HTMLResponse:
    """The page: pick a scene, set the light and size, render, see colour and depth."""
    # The page is self-contained (inline script and style), so it can forbid everything else.
    csp = ("default-src 'none'; script-src 'unsafe-inline'; style-src 'unsafe-inline'; "
           "img-src data: blob:; connect-src 'self'; form-action 'none'; base-uri 'none'")
    return HTMLResponse(_page(), headers={"Content-Security-Policy": csp})


@router.get(
    "/demo.glb",
    response_class=Response,
    operation_id="demo_scene",
    responses={200: {"content": {"model/gltf-binary": {"schema": {"type": "string",
                                                                   "format": "binary"}}},
                     "description": "the demo scene rendered when a request has no scene"}},
)
async def demo_scene() -> Response:
    """The built-in demo scene as binary glTF."""
    data = await run_in_threadpool(demo_glb)
    return Response(data, media_type="model/gltf-binary",
                    headers={"Content-Disposition": 'attachment; filename="demo.glb"'})
