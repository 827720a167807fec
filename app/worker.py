"""The GL thread: one renderer per process, fed through a bounded queue.

A GL context belongs to the thread that created it, so each service process runs one dedicated
thread that creates the :class:`shadowmap.renderer.Renderer`, which parses scenes (keeping the
last few by content hash) and renders them one at a time. Async routes submit a job and await its
``concurrent.futures.Future``; the event loop never blocks on GL work.

A GL call cannot be interrupted. When a request's time limit passes while its render is running,
the request is answered (504) but the render runs to its end and its result is dropped; a job
whose limit passes while it still waits in the queue is cancelled and never runs.
"""

from __future__ import annotations

import asyncio
import logging
import math
import queue
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass, field

from shadowmap.renderer import Renderer, RenderError, RenderParams, RenderResult

from .errors import ServiceError
from .settings import Settings
from .upload import SceneUpload

log = logging.getLogger("shadowmap.app")

_STOP = object()


@dataclass
class RenderJob:
    """One render request on its way through the queue."""

    upload: SceneUpload
    params: RenderParams
    submitted: float = field(default_factory=time.perf_counter)
    started: float | None = None


@dataclass
class RenderOutcome:
    """A finished render plus the worker's own timings (seconds)."""

    result: RenderResult
    queue: float
    parse: float
    cache_hit: bool


class RenderWorker:
    """Owns the GL thread of this process.

    Parameters
    ----------
    settings : Settings
        Limits, queue size and cache sizes.
    """

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.limits = settings.limits()
        self._queue: queue.Queue = queue.Queue(maxsize=settings.queue_size)
        self._thread = threading.Thread(target=self._run, name="shadowmap-gl", daemon=True)
        self._ready = threading.Event()
        self._stopping = False
        self._startup_error: BaseException | None = None
        self._renderer: Renderer | None = None
        self._info: dict = {}
        self._busy_since: float | None = None
        self._mean_seconds = 1.0  # running mean of render time, for Retry-After
        self.renders = 0
        self.failures = 0

    # -- lifetime ----------------------------------------------------------------------------

    def start(self) -> None:
        """Start the GL thread and wait until its context exists.

        Raises
        ------
        RenderError
            The context could not be created, or not within ``startup_timeout``.
        """
        self._thread.start()
        if not self._ready.wait(self.settings.startup_timeout):
            raise RenderError("the GL context was not ready after "
                              f"{self.settings.startup_timeout} s")
        if self._startup_error is not None:
            raise RenderError(f"cannot start the renderer: {self._startup_error}")

    def close(self, timeout: float = 10.0) -> None:
        """Cancel waiting jobs, let a running one finish (up to ``timeout``), release GL."""
        self._stopping = True
        while True:  # drain, so the stop marker fits into the bounded queue
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                break
            if item is not _STOP:
                item[1].cancel()
        try:
            self._queue.put(_STOP, timeout=timeout)
        except queue.Full:
            pass
        self._thread.join(timeout)

    # -- state -------------------------------------------------------------------------------

    @property
    def info(self) -> dict:
        """GL platform, renderer and version, as read when the context was created."""
        return dict(self._info)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive() and self._renderer is not None and not self._stopping

    @property
    def queued(self) -> int:
        return self._queue.qsize()

    @property
    def busy_seconds(self) -> float | None:
        """How long the current render has been running, None when idle."""
        since = self._busy_since
        return None if since is None else time.perf_counter() - since

    def retry_after(self) -> int:
        """Seconds a client should wait before retrying: roughly the time to drain the queue."""
        estimate = (self.queued + 1) * self._mean_seconds
        return int(min(max(math.ceil(estimate), 1), 300))

    # -- submitting --------------------------------------------------------------------------

    def submit(self, upload: SceneUpload,
               params: RenderParams) -> tuple[RenderJob, Future[RenderOutcome]]:
        """Queue a render without waiting.

        Raises
        ------
        ServiceError
            503 when the queue is full or the renderer is not running.
        """
        if not self.alive:
            raise ServiceError(503, "unavailable", "the renderer is not running",
                               headers={"Retry-After": "10"})
        job = RenderJob(upload, params)
        fut: Future[RenderOutcome] = Future()
        try:
            self._queue.put_nowait((job, fut))
        except queue.Full:
            raise ServiceError(
                503, "queue_full",
                f"the render queue is full ({self.settings.queue_size} waiting); try again later",
                headers={"Retry-After": str(self.retry_after())},
            ) from None
        return job, fut

    async def render(self, upload: SceneUpload, params: RenderParams) -> RenderOutcome:
        """Queue a render and await it within ``settings.render_timeout`` (queue wait + run).

        Raises
        ------
        ServiceError
            503 (queue full, or the time ran out before the render started, with Retry-After)
            or 504 (the render started but did not finish in time).
        ShadowMapError
            Whatever the renderer raised.
        """
        job, fut = self.submit(upload, params)
        limit = self.settings.render_timeout
        try:
            # Cancelling the wrapper on timeout cancels the job too if it has not started.
            return await asyncio.wait_for(asyncio.wrap_future(fut), limit)
        except TimeoutError:
            if fut.cancel():  # true only when it never started (or was cancelled already)
                raise ServiceError(
                    503, "render_timeout",
                    f"the render waited {limit:g} s in the queue without starting; try again later",
                    limit="render_timeout",
                    headers={"Retry-After": str(self.retry_after())},
                ) from None
            if fut.done():  # finished in the same instant: use it
                return fut.result()
            waited = (job.started or time.perf_counter()) - job.submitted
            raise ServiceError(
                504, "render_timeout",
                f"the render did not finish within the limit of {limit:g} s (it waited "
                f"{waited:.2f} s in the queue); GL work cannot be interrupted, so it finishes in "
                "the background and its result is dropped",
                limit="render_timeout",
            ) from None

    # -- the GL thread -----------------------------------------------------------------------

    def _new_renderer(self) -> Renderer:
        return Renderer(limits=self.limits, cache_bytes=self.settings.gpu_cache_bytes,
                        cache_entries=self.settings.scene_cache_entries)

    def _run(self) -> None:
        try:
            self._renderer = self._new_renderer()
            self._info = self._renderer.info
        except BaseException as exc:  # noqa: BLE001 - reported to start()
            self._startup_error = exc
            return
        finally:
            self._ready.set()
        log.info("GL thread ready: %s", self._info)
        try:
            while True:
                item = self._queue.get()
                if item is _STOP:
                    break
                job, fut = item
                if self._stopping or not fut.set_running_or_notify_cancel():
                    fut.cancel()
                    continue
                job.started = self._busy_since = time.perf_counter()
                try:
                    fut.set_result(self._execute(job))
                    self.renders += 1
                except Exception as exc:  # noqa: BLE001 - every error goes to its request
                    self.failures += 1
                    fut.set_exception(exc)
                    if isinstance(exc, RenderError):
                        self._reset_renderer(exc)
                finally:
                    seconds = time.perf_counter() - job.started
                    self._mean_seconds = 0.8 * self._mean_seconds + 0.2 * seconds
                    self._busy_since = None
                    job = fut = item = None  # drop references while idle
        finally:
            renderer, self._renderer = self._renderer, None
            if renderer is not None:
                renderer.close()

    def _reset_renderer(self, exc: Exception) -> None:
        """Replace the GL context after a GL failure, so one bad render cannot poison the next."""
        log.warning("recreating the GL context after: %s", exc)
        old, self._renderer = self._renderer, None
        try:
            if old is not None:
                old.close()
        except Exception:  # noqa: BLE001 - the old context may be beyond repair
            log.exception("closing the failed GL context")
        try:
            self._renderer = self._new_renderer()
        except Exception:  # noqa: BLE001
            log.exception("cannot recreate the GL context; the worker is down")

    def _execute(self, job: RenderJob) -> RenderOutcome:
        if self._renderer is None:
            raise RenderError("the renderer is not running")
        t0 = time.perf_counter()
        cache = self._renderer.scenes
        hits = cache.hits
        scene = self._renderer.load(job.upload.data, file_type=job.upload.file_type,
                                    resources=job.upload.resources)
        parse = time.perf_counter() - t0
        result = self._renderer.render(scene, job.params)
        assert job.started is not None  # _run sets it before executing the job
        return RenderOutcome(result, queue=job.started - job.submitted, parse=parse,
                             cache_hit=cache.hits > hits)
