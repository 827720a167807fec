"""The HTTP service: app factory, lifespan (the render worker) and the ``serve`` entry point.

Run it with ``shadowmap serve`` (which calls :func:`run`), or directly::

    uvicorn --factory shadowmap.app.main:create_app --port 8000

Settings come from ``SHADOWMAP_*`` environment variables, see
:class:`shadowmap.app.settings.Settings`. Those of the HTTP server itself (``keep_alive_timeout``,
``limit_concurrency``, ``shutdown_timeout``, ``send_timeout``) are applied by :func:`run`; with
the ``uvicorn`` command give the first three as its own options (``--timeout-keep-alive``,
``--limit-concurrency``, ``--timeout-graceful-shutdown``); it has no deadline on the request head
or on the client's reading of the response.
The GL platform is chosen by ``PYOPENGL_PLATFORM`` (``egl`` or ``osmesa``; probed when unset).
"""

from __future__ import annotations

import asyncio
import copy
import ctypes
import functools
import logging
import multiprocessing
import os
import signal
import socket
import sys
import time
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from shadowmap import __version__
from shadowmap.hosts import check_workers
from shadowmap.renderer import RenderParams

from .deps import default_size, demo_upload, optional_features
from .encode import RenderJSON
from .errors import install_handlers
from .routes import docs, health, page, render
from .routes.render import SERVER_TIMING
from .settings import Settings
from .supervisor import Supervisor

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


#: prctl(2): the signal this process gets when its parent ends.
_PR_SET_PDEATHSIG = 1


def end_with_parent() -> bool:
    """Have a server process that uvicorn started for ``--workers N`` end with uvicorn's main
    process; True where that was set up.

    uvicorn's worker processes answer its health checks from a thread that stops when the pipe
    to the main process closes, and go on serving: with the main process killed (SIGKILL, the
    OOM killer) they kept the port, their render workers and their memory, with nothing left to
    stop them. Asked here (``PR_SET_PDEATHSIG``, Linux), the kernel sends this process SIGTERM
    when its parent ends, which uvicorn takes as a graceful shutdown: the lifespan then stops
    the render worker. A process that no ``multiprocessing`` parent started (one server
    process, a Ray Serve replica, tests) is left alone.
    """
    parent = multiprocessing.parent_process()
    if parent is None or not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
            return False
    except (OSError, AttributeError):  # no prctl in this C library
        return False
    if os.getppid() != parent.pid:  # it ended before the request took effect
        os.kill(os.getpid(), signal.SIGTERM)
    return True


@asynccontextmanager
async def lifespan(app: FastAPI) -> AsyncIterator[None]:
    """Start this process's render worker before serving; stop it on shutdown."""
    _setup_logging()
    end_with_parent()
    settings: Settings = app.state.settings
    # The demo scene: built once, before the first request, and each worker's warm-up render.
    demo = await run_in_threadpool(demo_upload)
    supervisor = Supervisor(settings, warmup_scene=demo.data)
    await run_in_threadpool(supervisor.start)  # blocks until the worker is ready (or fails)
    app.state.worker = supervisor
    try:
        yield
    finally:
        app.state.worker = None
        # The server has already given running requests shutdown_timeout: a render still
        # running now is killed at once.
        await run_in_threadpool(supervisor.close)


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


def _describe_instance(components: dict[str, Any], settings: Settings) -> None:
    """Write this instance's limits and features into the request schema, as maximums and
    enumerations (the library's own schema has only the renderer's structural bounds)."""
    params = components["RenderParams"]["properties"]
    side = min(settings.max_image_side, settings.max_pixels)
    for name, default in zip(("width", "height"), default_size(settings), strict=True):
        params[name]["maximum"] = min(params[name]["maximum"], side)
        params[name]["default"] = default
        params[name]["examples"] = [default]
        params[name]["description"] += (f" (here: {side} pixels at most each, "
                                        f"{settings.max_pixels} pixels in all)")
    lights = next(s for s in params["lights"]["anyOf"] if s.get("type") == "array")
    lights["maxItems"] = min(lights["maxItems"], settings.max_lights)
    map_size = components["ShadowParams"]["properties"]["map_size"]
    sizes = next(s for s in map_size["anyOf"] if s["type"] == "integer")
    sizes["enum"] = [v for v in sizes["enum"] if v <= settings.max_map_size]
    map_size["examples"] = [v for v in map_size["examples"] if v == "auto" or v in sizes["enum"]]
    map_size["description"] += f" (here: at most {settings.max_map_size})"
    # The whole-request examples at sizes this instance takes.
    width, height = default_size(settings)
    top = max(sizes["enum"])
    for example in components["RenderParams"].get("examples", []):
        example.update(width=width, height=height)
        shadows = example.get("shadows", {})
        if isinstance(shadows.get("map_size"), int):
            shadows["map_size"] = min(shadows["map_size"], top)
    for example in components["ShadowParams"].get("examples", []):
        if isinstance(example.get("map_size"), int):
            example["map_size"] = min(example["map_size"], top)
    features = optional_features()
    if not features["reference"]:
        params["reference"]["enum"] = [False]
        params["reference"]["description"] += " (not on this service: embreex is not installed)"
    if not features["exr"]:
        params["float_format"]["enum"] = [v for v in params["float_format"]["enum"]
                                          if v != "exr"]
        params["float_format"]["description"] += (" (exr is not on this service: OpenEXR is "
                                                  "not installed)")


def _instance_examples(operation: dict[str, Any], settings: Settings) -> None:
    """The request examples of ``POST /render`` at sizes this instance accepts."""
    width, height = default_size(settings)
    body = operation["requestBody"]["content"]["application/json"]
    body["example"] = {**body["example"], "width": width, "height": height}
    for parameter in operation["parameters"]:
        if parameter["name"] == "params":
            media = parameter["content"]["application/json"]
            media["example"] = {"width": max(1, width // 2), "height": max(1, height // 2)}


_HTML = {"content": {"text/html": {"schema": {"type": "string"}}}}


def _document_pages(paths: dict[str, Any]) -> None:
    """The HTML pages (the web page, Swagger UI, ReDoc): plain GETs answered with HTML."""
    pages = {"/": "the web page: pick a scene, set the light and size, render",
             "/docs": "the API documentation (Swagger UI; its assets are served by this app)",
             "/redoc": "the API documentation (ReDoc; its assets are served by this app)"}
    for path, summary in pages.items():
        paths.setdefault(path, {})["get"] = {
            "summary": summary,
            "operationId": "page_" + (path.strip("/") or "index"),
            "tags": ["page"],
            "responses": {"200": {"description": "an HTML page", **_HTML,
                                  "headers": dict(SERVER_TIMING)}},
        }


def _install_openapi(app: FastAPI) -> None:
    """Add the models that the hand-written body and response schemas refer to, and this
    instance's limits."""

    def openapi() -> dict:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, description=app.description,
                             routes=app.routes)
        components = schema.setdefault("components", {}).setdefault("schemas", {})
        for model in (RenderParams, RenderJSON):
            # A copy: the instance's limits are written into it, and pydantic's schema may
            # share the models' own example objects.
            s = copy.deepcopy(model.model_json_schema(ref_template="#/components/schemas/{model}"))
            components.update(s.pop("$defs", {}))
            components[model.__name__] = s
        _describe_instance(components, app.state.settings)
        _instance_examples(schema["paths"]["/render"]["post"], app.state.settings)
        _document_pages(schema.setdefault("paths", {}))
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
    # /docs and /redoc are added by install_docs, with assets served here rather than a CDN.
    app = FastAPI(title="shadowmap-service", version=__version__,
                  description=DESCRIPTION, lifespan=lifespan, docs_url=None, redoc_url=None)
    app.state.settings = settings or Settings()
    app.state.worker = None  # the Supervisor, while the lifespan runs
    install_handlers(app)
    app.add_middleware(ServerTimingMiddleware)
    app.include_router(render.router)
    app.include_router(health.router)
    app.include_router(page.router)
    docs.install_docs(app)
    _install_openapi(app)
    return app


def run(host: str = "127.0.0.1", port: int = 8000, workers: int = 1,
        log_level: str = "info", **overrides: Any) -> None:
    """Serve with uvicorn; each of ``workers`` processes has its own render worker and queue.

    Parameters
    ----------
    host : str
    port : int
    workers : int
        Processes (not threads): a GL context serves one render at a time, so this is how a
        machine with several cores renders in parallel.
    log_level : str
    **overrides
        Settings by field name (e.g. ``shutdown_timeout=5``). They are exported as
        ``SHADOWMAP_*`` environment variables, which is how the app in every server process
        reads them.

    Raises
    ------
    TypeError
        An override that is not a setting.
    pydantic.ValidationError
        A setting (from the environment or ``overrides``) out of range.
    ValueError
        ``workers`` or ``port`` out of range (:func:`check_server`).
    OSError
        Nothing can listen on ``host:port`` (in use, or not an address of this machine).
    """
    import uvicorn

    for name, value in overrides.items():
        if name not in Settings.model_fields:
            raise TypeError(f"run() got an unknown setting {name!r}")
        if value is not None:
            os.environ[f"SHADOWMAP_{name.upper()}"] = str(value)
    settings = Settings()  # validated here, so a bad value fails before anything starts
    check_server(host, port, workers)
    uvicorn.run("shadowmap.app.main:create_app", factory=True, host=host, port=port,
                workers=workers if workers > 1 else None, log_level=log_level,
                timeout_keep_alive=settings.keep_alive_timeout,
                limit_concurrency=settings.limit_concurrency,
                # Typed int, used as a float (asyncio.wait_for's timeout).
                timeout_graceful_shutdown=settings.shutdown_timeout,  # type: ignore[arg-type]
                http=_http_protocol())


def check_server(host: str, port: int, workers: int) -> None:
    """What :func:`run` checks before it starts anything: a bad value would otherwise surface
    after every worker process had started its render worker (a port or host), or start as many
    processes as it says (``workers``, see :data:`shadowmap.hosts.MAX_WORKERS_PER_CPU`).

    Raises
    ------
    ValueError
        ``workers`` out of range (:func:`shadowmap.hosts.check_workers`); ``port`` outside
        0-65535.
    OSError
        ``host:port`` cannot be listened on (bound once, then released).
    """
    check_workers(workers)
    if not 0 <= port <= 65535:
        raise ValueError(f"port must be from 0 to 65535, not {port}")
    # As uvicorn binds (uvicorn.Config.bind_socket).
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    try:
        with socket.socket(family) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((host, port))
    except OSError as exc:
        raise OSError(exc.errno, f"cannot listen on {host}:{port}: "
                      f"{exc.strerror or exc}") from None


def _http_protocol() -> type[asyncio.Protocol] | str:
    """uvicorn's httptools protocol with deadlines on the request head and on the client's
    reading of the response, when it is installed."""
    return DeadlineProtocol if DeadlineProtocol is not None else "auto"


@functools.cache
def _send_timeout() -> float:
    """``send_timeout`` of this process's settings: read once, as :func:`run` wrote them to the
    environment (every server process reads its own)."""
    return Settings().send_timeout


try:
    from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol
except ImportError:  # no httptools (or no uvicorn): the server's own protocol, without them
    DeadlineProtocol = None
else:

    class DeadlineProtocol(HttpToolsProtocol):  # type: ignore[no-redef]
        """uvicorn's httptools protocol with two deadlines on the client.

        The request head: a connection that has not sent a whole head ``timeout_keep_alive``
        seconds after it opened or after its last response is closed. uvicorn's own keep-alive
        timer starts only after a first response and stops at the first byte, so a connection
        that never sends anything, or sends its headers a byte at a time, would hold one of the
        ``limit_concurrency`` places for ever.

        The response: the time the server waits on the client to read (its send buffer full:
        between the transport's ``pause_writing`` and ``resume_writing``) is summed from each
        request head on (a head sent while an earlier response still waits does not start the
        sum again); past ``send_timeout`` seconds the connection is dropped. A response is
        handed to the transport whole, and closing a connection waits until the buffer is sent,
        so a client that stops reading a response larger than the kernel's socket buffers would
        otherwise hold its place, and the response's bytes, for ever. Summed, not per pause: a
        client that reads a few kB now and then resumes the transport each time.
        """

        _head_timer: asyncio.TimerHandle | None = None
        _send_timer: asyncio.TimerHandle | None = None
        _paused_at: float | None = None  # loop time of the pause now in force
        _paused_total = 0.0  # seconds paused since the last request head, before _paused_at

        def _arm_head_timer(self) -> None:
            self._cancel_head_timer()
            self._head_timer = self.loop.call_later(self.timeout_keep_alive, self._head_late)

        def _cancel_head_timer(self) -> None:
            if self._head_timer is not None:
                self._head_timer.cancel()
                self._head_timer = None

        def _head_late(self) -> None:
            self._head_timer = None
            if not self.transport.is_closing():
                self.transport.close()

        def _cancel_send_timer(self) -> None:
            if self._send_timer is not None:
                self._send_timer.cancel()
                self._send_timer = None

        def _send_late(self) -> None:
            # abort(), not close(): close() would wait for the buffer to be read.
            self._send_timer = None
            self.transport.abort()

        def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
            super().connection_made(transport)
            self._arm_head_timer()

        def on_headers_complete(self) -> None:
            self._cancel_head_timer()
            # A new request gets the whole allowance, unless an earlier response still waits on
            # the client (a pipelined head): that wait goes on counting.
            if self._paused_at is None:
                self._paused_total = 0.0
            super().on_headers_complete()

        def on_response_complete(self) -> None:
            # A pipelined request (started by super() below) already has its head and must
            # not be timed; otherwise the next request must send its head in time.
            pipelined = bool(self.pipeline)
            super().on_response_complete()
            if not pipelined and not self.transport.is_closing():
                self._arm_head_timer()

        def pause_writing(self) -> None:
            super().pause_writing()
            if self._paused_at is None:
                self._paused_at = self.loop.time()
                left = _send_timeout() - self._paused_total
                self._send_timer = self.loop.call_later(max(left, 0.0), self._send_late)

        def resume_writing(self) -> None:
            super().resume_writing()
            if self._paused_at is not None:
                self._paused_total += self.loop.time() - self._paused_at
                self._paused_at = None
            self._cancel_send_timer()

        def connection_lost(self, exc: Exception | None) -> None:
            self._cancel_head_timer()
            self._cancel_send_timer()
            super().connection_lost(exc)


def __getattr__(name: str) -> FastAPI:
    # ``uvicorn shadowmap.app.main:app`` works too; the app is built on first access, not on
    # import, so importing this module reads no settings and starts nothing.
    if name == "app":
        return create_app()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
