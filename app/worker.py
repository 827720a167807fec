"""The render worker process: one GL context, fed by the supervisor over a pipe.

This module is the child's side of :mod:`shadowmap.app.supervisor`. The supervisor starts
:func:`worker_main` in a fresh interpreter (multiprocessing's ``spawn`` context: nothing of the
server's threads or GL state is inherited) and talks to it with picklable messages:

========================================  ==========================================================
from the server                           answer
========================================  ==========================================================
``("render", RenderTask)``                ``("started", job_id)`` at once, then
                                          ``("done", job_id, RenderReply)`` or
                                          ``("error", job_id, ErrorPayload, fatal)``
``("stop",)`` or the pipe closing         the process releases GL and exits
========================================  ==========================================================

and, once at start, ``("ready", WorkerReady)`` or ``("failed", message)``.

The child renders *and* encodes: a render's arrays (a 4096² visibility buffer of 8 lights is
512 MB of float32) never cross the pipe or enter the server process, only the response body
does. Parsed scenes and GPU uploads stay cached by content hash between renders, as long as the
process lives.

A GL call cannot be interrupted; this process can. That is the time limit: the supervisor
kills the whole process when a render runs past ``render_timeout`` and starts a fresh one.
"""

from __future__ import annotations

import logging
import os
import pickle
import signal
import time
from dataclasses import dataclass, field
from importlib import import_module
from multiprocessing.connection import Connection
from typing import Any

from shadowmap.renderer import Renderer, RenderError, RenderParams, ShadowMapError
from shadowmap.renderer.allocator import KEEP_FREED_BYTES, keep_freed_memory
from shadowmap.renderer.limits import Limits

log = logging.getLogger("shadowmap.app.worker")

#: Side of the warm-up renders made before the worker reports ready: small, since they exist to
#: compile the shaders (about a second on llvmpipe) rather than on a client's first request.
WARMUP_SIZE = (64, 48)


@dataclass(frozen=True)
class WorkerConfig:
    """What a worker process needs to build its renderer (sent once, at start).

    Attributes
    ----------
    limits : Limits
    cache_bytes : int
        ``gpu_cache_bytes`` of the settings.
    cache_entries : int
        ``scene_cache_entries`` of the settings.
    map_cache_bytes : int
        ``light_map_cache_bytes`` of the settings.
    warmup_scene : bytes or None
        A ``.glb`` rendered (twice, small) before the worker reports ready, or None for no
        warm-up.
    warmup_params : dict
        RenderParams fields of the warm-up render.
    log_level : int
    keep_freed_bytes : int
        ``keep_freed_bytes`` of the settings
        (:func:`~shadowmap.renderer.allocator.keep_freed_memory`).
    """

    limits: Limits
    cache_bytes: int
    cache_entries: int
    map_cache_bytes: int = 192 * 2**20
    warmup_scene: bytes | None = None
    warmup_params: dict = field(default_factory=dict)
    log_level: int = logging.INFO
    keep_freed_bytes: int = KEEP_FREED_BYTES


@dataclass(frozen=True)
class WorkerReady:
    """The worker's first message: it has a GL context and is waiting for renders.

    Attributes
    ----------
    pid : int
    info : dict of str to str
        GL platform, renderer and version.
    warm_seconds : float or None
        Seconds of the second (shaders already compiled) warm-up render; the supervisor's first
        cost estimate. None without a warm-up.
    """

    pid: int
    info: dict[str, str]
    warm_seconds: float | None


@dataclass
class RenderTask:
    """One render, as sent to the worker.

    Attributes
    ----------
    job_id : int
    data : bytes
        The ``.glb`` or ``.gltf`` file.
    file_type : str
    resources : dict of str to bytes
    params : RenderParams
    media : str
        The response format, one of :data:`shadowmap.app.encode.FORMATS`.
    outputs : list of str
        The outputs the client asked for (a PNG response encodes only the colour image).
    before : dict of str to float
        Seconds of the stages before the worker (read, queue), for ``Server-Timing``.
    elapsed : float
        Seconds since the request began, when the task was sent: process clocks differ, so the
        worker places the request's start on its own clock from this.
    """

    job_id: int
    data: bytes
    file_type: str
    resources: dict[str, bytes]
    params: RenderParams
    media: str
    outputs: list[str]
    before: dict[str, float] = field(default_factory=dict)
    elapsed: float = 0.0


@dataclass
class RenderReply:
    """A finished render, encoded: everything the HTTP response needs.

    Attributes
    ----------
    body : bytes
    media_type : str
        The full ``Content-Type`` (with the boundary of a multipart body).
    headers : dict of str to str
        ``Server-Timing``, ``X-Render-Plan``, ``X-Render-Warnings``, ``Cache-Control``, ...
    seconds : float
        Time the worker spent on the task (parse, render, encode).
    cache_hit : bool
        Whether the parsed scene came from the worker's cache.
    pipe : float
        Set in the server process: seconds the task and this reply spent between the processes
        (pickling, the pipe, the worker's wake-ups), the round trip less ``seconds``.
    answered : float
        Set in the server process: ``time.perf_counter()`` when the reply had crossed the pipe;
        0 where no pipe was crossed.
    """

    body: bytes
    media_type: str
    headers: dict[str, str]
    seconds: float
    cache_hit: bool
    pipe: float = 0.0
    answered: float = 0.0


@dataclass(frozen=True)
class ErrorPayload:
    """An exception raised in the worker, in a form that crosses the pipe.

    Library exceptions do not all survive pickling (``LimitError(limit, message)`` keeps only the
    message in ``args``), so the class, message and attributes travel separately and
    :meth:`rebuild` puts them back together.
    """

    module: str
    qualname: str
    message: str
    attrs: dict[str, Any]
    pickled: bytes | None = None

    @classmethod
    def of(cls, exc: BaseException) -> ErrorPayload:
        kind = type(exc)
        pickled = None
        if not isinstance(exc, ShadowMapError):
            try:  # anything else goes as itself when it can, else as its type name and message
                pickled = pickle.dumps(exc)
                pickle.loads(pickled)
            except Exception:  # noqa: BLE001 - not picklable: rebuilt as a RuntimeError
                pickled = None
        attrs = {}
        for key, value in vars(exc).items():
            try:
                pickle.dumps(value)
            except Exception:  # noqa: BLE001 - an attribute that cannot travel is left out
                continue
            attrs[key] = value
        return cls(kind.__module__, kind.__qualname__, str(exc), attrs, pickled)

    def rebuild(self) -> BaseException:
        """The exception again, in this process."""
        if self.pickled is not None:
            return pickle.loads(self.pickled)
        try:
            kind = getattr(import_module(self.module), self.qualname)
        except (ImportError, AttributeError):
            kind = None
        if isinstance(kind, type) and issubclass(kind, ShadowMapError):
            exc = kind.__new__(kind)
            Exception.__init__(exc, self.message)
            exc.__dict__.update(self.attrs)
            return exc
        return RuntimeError(f"{self.qualname} in the render worker: {self.message}")


# --------------------------------------------------------------------------------------------
# The process
# --------------------------------------------------------------------------------------------


def _setup_logging(level: int) -> None:
    root = logging.getLogger("shadowmap")
    if not root.handlers:
        handler = logging.StreamHandler()
        handler.setFormatter(logging.Formatter(
            f"%(levelname)s:     %(name)s[{os.getpid()}]: %(message)s"))
        root.addHandler(handler)
        root.setLevel(level)


def worker_main(conn: Connection, config: WorkerConfig) -> None:
    """Entry point of the worker process: make the renderer, report ready, serve tasks.

    Parameters
    ----------
    conn : Connection
        This process's end of the pipe to the supervisor.
    config : WorkerConfig
    """
    # Ctrl-C reaches the whole process group; the server decides when its worker stops (and
    # kills it if need be), so the worker does not die half-way through its own answer.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _setup_logging(config.log_level)
    # This process only renders: freed frames stay for the next request's (no page faults).
    keep_freed_memory(config.keep_freed_bytes)

    def new_renderer() -> Renderer:
        return Renderer(limits=config.limits, cache_bytes=config.cache_bytes,
                        cache_entries=config.cache_entries,
                        map_cache_bytes=config.map_cache_bytes)

    try:
        renderer = new_renderer()
    except BaseException as exc:  # noqa: BLE001 - reported to the supervisor, which gives up
        _send(conn, ("failed", f"cannot start the renderer: {type(exc).__name__}: {exc}"))
        return
    try:
        warm = None
        try:
            warm = _warm_up(renderer, config)
        except Exception as exc:  # noqa: BLE001 - a render that fails is not a reason to be down
            # Renders that do not take the failing path may still work: serve without the
            # warm-up (on a fresh context if GL failed) rather than leave the service down.
            log.warning("the warm-up render failed, serving without it: %s: %s",
                        type(exc).__name__, exc)
            if isinstance(exc, RenderError):
                renderer.close()
                renderer = new_renderer()
        if _send(conn, ("ready", WorkerReady(os.getpid(), renderer.info, warm))):
            _serve(renderer, conn)
    except BaseException as exc:  # noqa: BLE001 - e.g. the fresh context failed
        _send(conn, ("failed", f"cannot start the renderer: {type(exc).__name__}: {exc}"))
    finally:
        renderer.close()


def _send(conn: Connection, message: object) -> bool:
    """Send to the supervisor; False when it is gone (then this process just ends)."""
    try:
        conn.send(message)
    except (OSError, EOFError):
        return False
    return True


def _warm_up(renderer: Renderer, config: WorkerConfig) -> float | None:
    """Render the warm-up scene twice; the seconds of the second render (shaders compiled)."""
    if config.warmup_scene is None:
        return None
    w, h = WARMUP_SIZE
    params = RenderParams.model_validate({**config.warmup_params, "width": w, "height": h})
    scene = renderer.load(config.warmup_scene, file_type="glb")
    renderer.render(scene, params)
    t = time.perf_counter()
    renderer.render(scene, params)
    return time.perf_counter() - t


def _serve(renderer: Renderer, conn: Connection) -> None:
    while True:
        try:
            message = conn.recv()
        except (OSError, EOFError):
            return  # the server process is gone
        if not isinstance(message, tuple) or not message or message[0] != "render":
            return  # ("stop",), or anything unexpected: end cleanly
        task: RenderTask = message[1]
        job_id = task.job_id
        del message
        # Received: from now on a death of this process may be this job's doing, so the
        # supervisor no longer retries it elsewhere.
        if not _send(conn, ("started", job_id)):
            return
        try:
            reply = execute(renderer, task)
        except Exception as exc:  # noqa: BLE001 - every error goes back to its request
            if not isinstance(exc, ShadowMapError):
                log.error("render failed unexpectedly", exc_info=exc)
            # After a GL failure the context may be in any state: a fresh process is the only
            # sure reset, so this one ends after answering and the supervisor starts another.
            fatal = isinstance(exc, RenderError)
            if not _send(conn, ("error", job_id, ErrorPayload.of(exc), fatal)) or fatal:
                return
            continue
        finally:
            del task  # the upload's bytes are not kept while idle
        sent = _send(conn, ("done", job_id, reply))
        del reply
        if not sent:
            return


def execute(renderer: Renderer, task: RenderTask) -> RenderReply:
    """Load (or reuse), render and encode one task.

    Parameters
    ----------
    renderer : Renderer
    task : RenderTask

    Raises
    ------
    ShadowMapError
        Whatever the renderer raised.
    """
    from .encode import build_response

    t0 = time.perf_counter()
    started = t0 - task.elapsed  # the request's start, on this process's clock
    hits = renderer.scenes.hits
    scene = renderer.load(task.data, file_type=task.file_type, resources=task.resources)
    cache_hit = renderer.scenes.hits > hits
    before = {**task.before, "parse": time.perf_counter() - t0}
    result = renderer.render(scene, task.params)
    notes = {"parse": "scene cache hit"} if cache_hit else {}
    response = build_response(task.media, result, task.outputs, before, notes, started,
                              task.params.float_format)
    del result, scene
    headers = {k: v for k, v in response.headers.items()
               if k not in ("content-length", "content-type")}
    return RenderReply(bytes(response.body), response.headers["content-type"], headers,
                       time.perf_counter() - t0, cache_hit)
