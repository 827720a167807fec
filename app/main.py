"""The HTTP service: app factory, lifespan (the GL worker) and the ``serve`` entry point.

Run it with ``shadowmap serve`` (which calls :func:`run`), or directly::

    uvicorn --factory shadowmap.app.main:create_app --port 8000

Settings come from ``SHADOWMAP_*`` environment variables, see
:class:`shadowmap.app.settings.Settings`.
The GL platform is chosen by ``PYOPENGL_PLATFORM`` (``egl`` or ``osmesa``; probed when unset).
"""

from __future__ import annotations

import logging
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from shadowmap import __version__
from shadowmap.renderer import RenderParams

from .deps import demo_upload
from .encode import RenderJSON
from .errors import install_handlers
from .routes import health, page, render
from .settings import Settings
from .worker import RenderWorker

log = logging.getLogger("shadowmap.app")

DESCRIPTION = """\
Renders glTF scenes with two-pass shadow maps in an offscreen OpenGL context (Mesa llvmpipe).

`POST /render` takes a scene (`.glb`, `.gltf` with embedded buffers, or a `.zip` of a `.gltf`
and its files) and a `params` JSON, and answers with a PNG, a `multipart/mixed` set of PNGs or
JSON, chosen by `Accept`. With no scene it renders a built-in demo scene (`GET /demo.glb`).
Errors are JSON: `{"error": ..., "detail": ...}`.
"""


def _setup_logging() -> None:
    # uvicorn configures only its own loggers; give ours a handler unless the host app did.
    root = logging.getLogger("shadowmap")
    if not root.handlers and not logging.getLogger().handlers:
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter("%(levelname)s:     %(name)s: %(message)s"))
        root.addHandler(handler)
        root.setLevel(logging.INFO)


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Start this process's GL thread before serving; stop it on shutdown."""
    _setup_logging()
    settings: Settings = app.state.settings
    worker = RenderWorker(settings)
    await run_in_threadpool(worker.start)  # blocks until the GL context exists (or fails)
    await run_in_threadpool(demo_upload)  # build the demo scene once, before the first request
    app.state.worker = worker
    try:
        yield
    finally:
        app.state.worker = None
        await run_in_threadpool(worker.close)


class ServerTimingMiddleware:
    """Adds ``Server-Timing: total`` to responses that do not carry their own breakdown."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()

        async def send_with_timing(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                if "server-timing" not in headers:
                    headers.append("Server-Timing",
                                   f"total;dur={(time.perf_counter() - t0) * 1000.0:.2f}")
            await send(message)

        await self.app(scope, receive, send_with_timing)


def _install_openapi(app: FastAPI) -> None:
    """Add the models that the hand-written body and response schemas refer to."""

    def openapi() -> dict:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, description=app.description,
                             routes=app.routes)
        components = schema.setdefault("components", {}).setdefault("schemas", {})
        for model in (RenderParams, RenderJSON):
            s = model.model_json_schema(ref_template="#/components/schemas/{model}")
            components.update(s.pop("$defs", {}))
            components[model.__name__] = s
        app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the FastAPI application.

    Parameters
    ----------
    settings : Settings, optional
        Defaults to reading ``SHADOWMAP_*`` from the environment.
    """
    app = FastAPI(title="shadowmap-service", version=__version__,
                  description=DESCRIPTION, lifespan=lifespan)
    app.state.settings = settings or Settings()
    app.state.worker = None
    install_handlers(app)
    app.add_middleware(ServerTimingMiddleware)
    app.include_router(render.router)
    app.include_router(health.router)
    app.include_router(page.router)
    _install_openapi(app)
    return app


def run(host: str = "127.0.0.1", port: int = 8000, workers: int = 1,
        log_level: str = "info") -> None:
    """Serve with uvicorn; each of ``workers`` processes has its own GL thread and queue.

    Parameters
    ----------
    host : str
    port : int
    workers : int
        Processes (not threads): a GL context serves one render at a time, so this is how a
        machine with several cores renders in parallel.
    log_level : str
    """
    import uvicorn

    uvicorn.run("shadowmap.app.main:create_app", factory=True, host=host, port=port,
                workers=workers if workers > 1 else None, log_level=log_level)


def __getattr__(name: str) -> FastAPI:
    # ``uvicorn shadowmap.app.main:app`` works too; the app is built on first access, not on
    # import, so importing this module reads no settings and starts nothing.
    if name == "app":
        return create_app()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
