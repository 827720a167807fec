"""The supervisor: renders run in a worker process it can kill, replace and recycle.

A GL call cannot be interrupted, so a time limit that only stops *waiting* for a render leaves
the render running and everyone behind it waiting. Here each service process owns one render
worker *process* (:mod:`shadowmap.app.worker`, one GL context), and the supervisor, in the server
process, feeds it one job at a time:

- **Time limit.** A render still running at its deadline (``render_timeout`` after the request
  was queued) is stopped: the worker is sent SIGTERM, SIGKILL after :data:`KILL_GRACE`, the
  request gets 504, and a fresh worker is started at once. Time the service spends restarting a
  worker is not charged to the jobs waiting for it, so the request after a timeout is served
  within ``render_timeout`` plus the restart time. A waiting job whose deadline passes (503) or
  whose client disconnects leaves the queue at once: it holds no place and never runs.
- **Crashes.** A worker that dies unexpectedly is replaced; its job gets 503 ``worker_restarted``
  with Retry-After, or is retried once on the new worker when it had not reached the old one.
- **Flat memory.** After ``max_renders_per_worker`` renders, or when the worker's resident memory
  (``/proc/<pid>/statm``) is over ``max_worker_memory_bytes``, a replacement is started *beside*
  the busy worker and takes over between jobs, so recycling fails no request and costs none of
  them the start-up time.
- **Admission by expected wait.** A job is queued while the expected wait ahead of it (the
  estimated cost of the queued jobs plus the rest of the running one, from the recent render
  times of requests of the same rough size, see :class:`CostModel`) is under
  ``max_expected_wait`` (and ``render_timeout``), and while fewer than ``queue_size`` wait;
  otherwise 503 ``queue_full`` with Retry-After from that wait.

One thread per supervisor talks to the worker over a pipe (blocking sends and receives of
uploads and encoded responses); the event loop only queues jobs and awaits their futures.
Workers are started with multiprocessing's ``spawn`` context: a fresh interpreter, never a fork
of a process that has threads (this one has the event loop's and the thread pool's).
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import math
import multiprocessing
import os
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Awaitable, Callable, Sequence
from concurrent.futures import Future, InvalidStateError
from dataclasses import dataclass, field
from multiprocessing.connection import wait as wait_for_ready
from multiprocessing.context import SpawnContext, SpawnProcess
from typing import Any

from shadowmap.renderer import RenderError, RenderParams
from shadowmap.renderer.demo import DEMO_PARAMS

from .errors import ServiceError
from .settings import Settings
from .upload import SceneUpload
from .worker import RenderReply, RenderTask, WorkerConfig, WorkerReady, worker_main

log = logging.getLogger("shadowmap.app")

#: Seconds between SIGTERM and SIGKILL when a worker is stopped.
KILL_GRACE = 1.0
#: How often the idle supervisor thread looks at its worker (a death is noticed this late).
IDLE_POLL = 0.5
#: How often it looks at a replacement worker that is starting.
SPARE_POLL = 0.05
#: How often a waiting request looks at its deadline while a worker restarts (the deadline
#: moves on during a restart).
RESTART_POLL = 0.25
#: How often a queued request looks whether its client is still connected.
DISCONNECT_POLL = 0.2
#: Seconds a request waits, after its deadline, for the supervisor to answer for its stopped
#: render (the kill itself takes at most ``KILL_GRACE``).
ANSWER_MARGIN = 5.0
#: Seconds between attempts to start a worker after one failed to start, growing, then repeated.
RESTART_BACKOFF = (1.0, 2.0, 5.0, 10.0, 30.0)
#: First cost estimate of a job (seconds) when the worker made no warm-up render to measure.
DEFAULT_COST = 0.1

try:
    PAGE_SIZE = os.sysconf("SC_PAGE_SIZE")
except (AttributeError, ValueError, OSError):  # not a POSIX system: no memory cap
    PAGE_SIZE = 0

SizeClass = tuple[int, ...]


# --------------------------------------------------------------------------------------------
# Cost estimates
# --------------------------------------------------------------------------------------------


def size_class(params: RenderParams, scene_bytes: int) -> SizeClass:
    """The rough size of a request: requests of one class take about as long to render.

    Buckets (each a factor of about 4 or 16) of the pixel count and the scene file's size, the
    light count (-1: the scene's own lights) and how many are point lights (six map faces each),
    the shadow-map size (0: automatic), the number of outputs and whether the ray-traced
    reference runs.
    """
    lights = params.lights
    map_size = params.shadows.map_size
    return (
        round(math.log(max(params.width * params.height, 1), 4)),
        len(lights) if lights is not None else -1,
        sum(1 for lt in lights if lt.type == "point") if lights else 0,
        round(math.log2(map_size)) if isinstance(map_size, int) else 0,
        len(params.outputs),
        int(params.reference),
        round(math.log(scene_bytes + 1, 16)),
    )


class CostModel:
    """Running mean of the seconds a job takes, per :func:`size_class`.

    A class seen for the first time is estimated at the running mean over all classes (at first
    ``prior``). The most recently used ``max_classes`` classes are kept.

    Parameters
    ----------
    prior : float
        Estimate before anything was measured.
    alpha : float
        Weight of a new measurement in a running mean.
    max_classes : int
    """

    def __init__(self, prior: float, alpha: float = 0.3, max_classes: int = 512) -> None:
        self.alpha = alpha
        self.max_classes = max_classes
        self.overall = prior
        self.observed = 0
        self._means: OrderedDict[SizeClass, float] = OrderedDict()

    def estimate(self, size: SizeClass) -> float:
        """Expected seconds of a job of this class."""
        mean = self._means.get(size)
        return self.overall if mean is None else mean

    def observe(self, size: SizeClass, seconds: float) -> None:
        """Add the measured seconds of a finished job."""
        mean = self._means.get(size)
        self._means[size] = seconds if mean is None else mean + self.alpha * (seconds - mean)
        self._means.move_to_end(size)
        while len(self._means) > self.max_classes:
            self._means.popitem(last=False)
        self.overall = seconds if not self.observed else (
            self.overall + self.alpha * (seconds - self.overall))
        self.observed += 1

    def observe_at_least(self, size: SizeClass, seconds: float) -> None:
        """A job of this class was stopped after ``seconds``: it takes at least that long."""
        self._means[size] = max(seconds, self._means.get(size, 0.0))
        self._means.move_to_end(size)


# --------------------------------------------------------------------------------------------
# One worker process, seen from the server
# --------------------------------------------------------------------------------------------


class WorkerProcess:
    """A started worker process and this side of its pipe.

    Parameters
    ----------
    ctx : SpawnContext
    config : WorkerConfig
    """

    def __init__(self, ctx: SpawnContext, config: WorkerConfig) -> None:
        self.conn, child_end = ctx.Pipe(duplex=True)
        # Daemonic: multiprocessing terminates it if this process exits without stopping it.
        self.process: SpawnProcess = ctx.Process(target=worker_main, args=(child_end, config),
                                                 name="shadowmap-render", daemon=True)
        self.started = time.perf_counter()
        self.process.start()
        # The child has its own copy now; without closing ours its death would not show as
        # end-of-file on the pipe.
        child_end.close()
        self.ready: WorkerReady | None = None
        self.ready_seconds: float | None = None
        #: Tasks this worker has run (finished or failed).
        self.renders = 0

    @property
    def pid(self) -> int | None:
        return self.process.pid

    @property
    def alive(self) -> bool:
        return self.process.is_alive()

    def poll_ready(self, timeout: float) -> bool:
        """Wait up to ``timeout`` for the worker's ready message.

        Raises
        ------
        RenderError
            The worker could not make its renderer, or exited.
        """
        if self.ready is not None:
            return True
        if not wait_for_ready([self.conn, self.process.sentinel], max(timeout, 0.0)):
            return False
        try:
            message = self.conn.recv() if self.conn.poll() else None
        except (EOFError, OSError):
            message = None
        if message is None:
            self.process.join(KILL_GRACE)
            raise RenderError("the render worker exited during start-up "
                              f"(exit code {self.process.exitcode})")
        if message[0] != "ready":
            raise RenderError(str(message[1]))
        self.ready = message[1]
        self.ready_seconds = time.perf_counter() - self.started
        return True

    def wait_ready(self, timeout: float) -> None:
        """Wait for the ready message; kill the worker and raise when it does not come.

        Raises
        ------
        RenderError
        """
        try:
            ok = self.poll_ready(timeout)
        except RenderError:
            self.kill()
            raise
        if not ok:
            self.kill()
            raise RenderError(f"the GL context was not ready after {timeout:g} s")

    def rss_bytes(self) -> int | None:
        """Resident memory of the process, from ``/proc/<pid>/statm``; None when unknown."""
        if not PAGE_SIZE or self.pid is None:
            return None
        try:
            with open(f"/proc/{self.pid}/statm") as f:
                return int(f.read().split()[1]) * PAGE_SIZE
        except (OSError, ValueError, IndexError):
            return None

    def signal_kill(self) -> None:
        """SIGKILL now, from any thread (the supervisor thread notices through the pipe)."""
        if self.process.exitcode is None:
            try:
                self.process.kill()
            except OSError:
                pass

    def kill(self) -> None:
        """SIGTERM, SIGKILL after :data:`KILL_GRACE`, reap, close the pipe."""
        if self.process.exitcode is None:
            self.process.terminate()
            self.process.join(KILL_GRACE)
            if self.process.exitcode is None:
                self.process.kill()
                self.process.join(KILL_GRACE)
        self.conn.close()

    def stop(self, timeout: float) -> None:
        """Ask an idle worker to exit (it releases its GL context); kill it after ``timeout``."""
        try:
            self.conn.send(("stop",))
        except (OSError, ValueError):
            pass
        self.process.join(timeout)
        self.kill()


# --------------------------------------------------------------------------------------------
# Jobs
# --------------------------------------------------------------------------------------------


@dataclass(eq=False)
class Job:
    """One render request on its way through the supervisor.

    Attributes
    ----------
    task : RenderTask
    size : SizeClass
    cost : float
        Estimated seconds, when it was admitted.
    submitted : float
        ``time.perf_counter()`` when it was queued.
    down_at_submit : float
        The supervisor's restart downtime counter then (see :meth:`Supervisor._downtime`).
    request_started : float
        ``time.perf_counter()`` when the request began.
    read_seconds : float
    state : {"queued", "running", "done", "withdrawn"}
    started, deadline : float or None
        When it was handed to the worker, and when it is stopped if still running.
    attempts : int
        Times it was sent to a worker that turned out dead before it started.
    """

    task: RenderTask
    size: SizeClass
    cost: float
    submitted: float
    down_at_submit: float
    request_started: float
    read_seconds: float
    future: Future[RenderReply] = field(default_factory=Future)
    state: str = "queued"
    started: float | None = None
    deadline: float | None = None
    attempts: int = 0


def _retry_after(seconds: float) -> dict[str, str]:
    return {"Retry-After": str(max(1, math.ceil(seconds)))}


class Supervisor:
    """Owns this service process's render worker and its queue.

    Parameters
    ----------
    settings : Settings
    warmup_scene : bytes, optional
        A ``.glb`` each new worker renders (small, twice) before it takes jobs, so that shader
        compilation is not paid by a client and the first cost estimate is a measurement.
    """

    def __init__(self, settings: Settings, warmup_scene: bytes | None = None) -> None:
        self.settings = settings
        self._ctx = multiprocessing.get_context("spawn")
        self._config = WorkerConfig(
            limits=settings.limits(), cache_bytes=settings.gpu_cache_bytes,
            cache_entries=settings.scene_cache_entries,
            map_cache_bytes=settings.light_map_cache_bytes, warmup_scene=warmup_scene,
            warmup_params=dict(DEMO_PARAMS),
            log_level=logging.getLogger("shadowmap").getEffectiveLevel(),
            keep_freed_bytes=settings.keep_freed_bytes)
        self._cond = threading.Condition()
        self._queue: deque[Job] = deque()
        self._running: Job | None = None
        self._child: WorkerProcess | None = None
        self._spare: WorkerProcess | None = None  # a replacement that is starting
        self._starting: WorkerProcess | None = None  # a restart under way (for close())
        self._thread: threading.Thread | None = None
        self._stopping = False
        self._state = "starting"
        self._down_total = 0.0
        self._down_since: float | None = None
        self._retry_at = 0.0
        self._backoff = 0
        self._ids = itertools.count(1)
        self._info: dict[str, str] = {}
        self.costs = CostModel(DEFAULT_COST)
        #: Seconds the last worker took from start to ready.
        self.restart_seconds = 0.0
        self.renders = 0
        self.failures = 0
        self.timeouts = 0
        self.restarts = 0
        self.recycles = 0

    # -- lifetime ----------------------------------------------------------------------------

    def start(self) -> None:
        """Start the first worker, wait until it is ready, then start feeding it.

        Raises
        ------
        RenderError
            The worker could not make its GL context, or not within ``startup_timeout``.
        """
        child = WorkerProcess(self._ctx, self._config)
        child.wait_ready(self.settings.startup_timeout)
        self._install(child)
        self._thread = threading.Thread(target=self._run, name="shadowmap-supervisor",
                                        daemon=True)
        self._thread.start()

    def close(self, timeout: float = 0.0) -> None:
        """Refuse new jobs, answer the queued ones 503, give a running render ``timeout``
        seconds, then kill its worker; an idle worker is stopped cleanly.

        The server has already waited ``shutdown_timeout`` for running requests when the app's
        lifespan calls this, so by default a render still running then is killed at once.
        """
        with self._cond:
            if self._stopping:
                return
            self._stopping = True
            queued = list(self._queue)
            self._queue.clear()
            for job in queued:
                job.state = "withdrawn"
            rendering = self._running is not None or self._starting is not None
            self._cond.notify_all()
        for job in queued:
            self._resolve(job, exc=self._shutting_down())
        thread = self._thread
        if thread is not None:
            thread.join(timeout if rendering else KILL_GRACE + ANSWER_MARGIN)
            if thread.is_alive():  # a render still runs (or a worker is starting): stop it
                for child in (self._child, self._starting, self._spare):
                    if child is not None:
                        child.signal_kill()
                thread.join(KILL_GRACE + ANSWER_MARGIN)
        else:
            for child in (self._child, self._spare):
                if child is not None:
                    child.kill()
        with self._cond:
            self._state = "stopped"

    @staticmethod
    def _shutting_down() -> ServiceError:
        return ServiceError(503, "shutting_down", "the service is shutting down; try again later",
                            headers=_retry_after(1))

    # -- state -------------------------------------------------------------------------------

    @property
    def info(self) -> dict[str, str]:
        """GL platform, renderer and version, as the worker read them."""
        return dict(self._info)

    @property
    def alive(self) -> bool:
        """Whether jobs are accepted: a worker is ready, busy or (re)starting."""
        thread = self._thread
        return (thread is not None and thread.is_alive() and not self._stopping
                and self._state != "down")

    def snapshot(self) -> dict[str, Any]:
        """The state for ``/healthz``."""
        now = time.perf_counter()
        with self._cond:
            child, running = self._child, self._running
            state = self._state
            if state == "ready" and running is not None:
                state = "busy"
            busy = None if running is None or running.started is None else now - running.started
            return {
                "alive": self.alive,
                "state": state,
                "pid": child.pid if child is not None else None,
                "replacing": self._spare is not None,
                "busy_seconds": busy,
                "queued": len(self._queue),
                "queue_size": self.settings.queue_size,
                "expected_wait": round(self._expected_wait(now), 3),
                "renders": self.renders,
                "failures": self.failures,
                "timeouts": self.timeouts,
                "restarts": self.restarts,
                "recycles": self.recycles,
                "worker_renders": child.renders if child is not None else 0,
                "worker_rss_bytes": child.rss_bytes() if child is not None else None,
                "restart_seconds": round(self.restart_seconds, 3),
            }

    def _downtime(self, now: float) -> float:
        """Seconds, summed since start, with no worker to run jobs (restarts)."""
        since = self._down_since
        return self._down_total + (now - since if since is not None else 0.0)

    def _deadline(self, job: Job, now: float) -> float:
        """When a job is stopped: ``render_timeout`` after it was queued, plus the restart time
        spent while it waited."""
        if job.deadline is not None:
            return job.deadline
        return (job.submitted + self.settings.render_timeout
                + self._downtime(now) - job.down_at_submit)

    def _expected_wait(self, now: float) -> float:
        """Seconds a job queued now would wait before it starts (call with the lock held)."""
        wait = sum(job.cost for job in self._queue)
        running = self._running
        if running is not None and running.started is not None:
            left = running.cost - (now - running.started)
            wait += max(0.0, min(left, self._deadline(running, now) - now))
        return wait

    # -- submitting --------------------------------------------------------------------------

    def submit(self, upload: SceneUpload, params: RenderParams, media: str,
               outputs: Sequence[str],
               read_seconds: float = 0.0, request_started: float | None = None) -> Job:
        """Queue a render without waiting for it.

        Raises
        ------
        ServiceError
            503: the queue is full (by count or by expected wait), the renderer is down, or the
            service is shutting down; with Retry-After.
        """
        now = time.perf_counter()
        scene_bytes = len(upload.data) + sum(len(b) for b in upload.resources.values())
        task = RenderTask(next(self._ids), upload.data, upload.file_type, upload.resources,
                          params, media, list(outputs))
        with self._cond:
            if self._stopping:
                raise self._shutting_down()
            if self._state == "down":
                raise ServiceError(503, "unavailable", "the renderer is not running",
                                   headers=_retry_after(self._retry_at - now))
            wait = self._expected_wait(now)
            size = self.settings.queue_size
            if len(self._queue) >= size:
                raise ServiceError(
                    503, "queue_full", f"the render queue is full ({size} waiting, about "
                    f"{wait:.1f} s of work); try again later", limit="queue_size",
                    headers=_retry_after(wait))
            limit = min(self.settings.max_expected_wait, self.settings.render_timeout)
            if wait > limit:
                raise ServiceError(
                    503, "queue_full", f"the renders queued ahead would take about {wait:.1f} s, "
                    f"over the limit of {limit:g} s; try again later", limit="max_expected_wait",
                    headers=_retry_after(wait))
            klass = size_class(params, scene_bytes)
            job = Job(task, klass, self.costs.estimate(klass), now, self._downtime(now),
                      now if request_started is None else request_started, read_seconds)
            self._queue.append(job)
            self._cond.notify_all()
        return job

    async def render(self, upload: SceneUpload, params: RenderParams, media: str,
                     outputs: Sequence[str], read_seconds: float = 0.0,
                     request_started: float | None = None,
                     disconnected: Callable[[], Awaitable[bool]] | None = None) -> RenderReply:
        """Queue a render and await it within ``render_timeout`` (queue wait and run).

        ``disconnected`` (e.g. Starlette's ``Request.is_disconnected``) is asked every
        :data:`DISCONNECT_POLL` seconds while the job waits: a job whose client has left leaves
        the queue then, instead of taking the worker for nobody. (A render already running is
        left to finish: stopping it costs a worker restart.)

        Raises
        ------
        ServiceError
            503 (not admitted, or the time ran out before the render started; ``queue_full``,
            ``render_timeout``, ``worker_restarted``...), 504 (the render was stopped at the
            limit).
        ShadowMapError
            Whatever the renderer raised.
        """
        job = self.submit(upload, params, media, outputs, read_seconds, request_started)
        answer = asyncio.wrap_future(job.future)
        try:
            while not answer.done():
                now = time.perf_counter()
                with self._cond:
                    deadline = self._deadline(job, now)
                    restarting = self._down_since is not None
                left = deadline - now
                if left <= 0:
                    break
                # While a worker restarts the deadline moves on: look again soon.
                step = min(left, RESTART_POLL) if restarting else left
                watching = disconnected is not None and job.state == "queued"
                if watching:
                    step = min(step, DISCONNECT_POLL)
                await asyncio.wait({answer}, timeout=step)
                if (watching and not answer.done() and disconnected is not None
                        and await disconnected() and self._withdraw(job)):
                    raise ServiceError(400, "client_disconnected",
                                       "the client left while its render waited in the queue")
            if not answer.done():
                if self._withdraw(job):
                    raise self._queue_timeout_error()
                # It runs: the supervisor stops it at the deadline and answers for it.
                await asyncio.wait({answer}, timeout=KILL_GRACE + ANSWER_MARGIN)
                if not answer.done():
                    raise self._timeout_error(job)
            return answer.result()
        except asyncio.CancelledError:
            self._withdraw(job)  # the client or the server gave up: free its place at once
            # Nobody will read the answer; retrieving it keeps asyncio from logging it as lost.
            answer.add_done_callback(lambda f: f.cancelled() or f.exception())
            raise

    def _withdraw(self, job: Job) -> bool:
        """Take a job out of the queue if it has not started; True when it was taken out."""
        with self._cond:
            if job.state != "queued":
                return False
            self._queue.remove(job)
            job.state = "withdrawn"
            return True

    def _queue_timeout_error(self) -> ServiceError:
        with self._cond:
            wait = self._expected_wait(time.perf_counter())
        return ServiceError(
            503, "render_timeout", f"the render waited {self.settings.render_timeout:g} s in the "
            "queue without starting; try again later", limit="render_timeout",
            headers=_retry_after(wait))

    def _timeout_error(self, job: Job) -> ServiceError:
        limit = self.settings.render_timeout
        waited = (job.started or job.submitted) - job.submitted
        return ServiceError(
            504, "render_timeout",
            f"the render did not finish within the limit of {limit:g} s (it waited "
            f"{waited:.2f} s in the queue); it was stopped and its worker process replaced",
            limit="render_timeout")

    # -- the supervisor thread ---------------------------------------------------------------

    def _install(self, child: WorkerProcess) -> None:
        """Make a ready worker the current one."""
        ready = child.ready
        assert ready is not None  # poll_ready() returned True
        with self._cond:
            self._child = child
            self._info = dict(ready.info)
            if child.ready_seconds is not None:
                self.restart_seconds = child.ready_seconds
            if ready.warm_seconds is not None and not self.costs.observed:
                self.costs.overall = ready.warm_seconds
            if self._down_since is not None:
                self._down_total += time.perf_counter() - self._down_since
                self._down_since = None
            self._state = "ready"
            self._backoff = 0
        log.info("render worker %s ready in %.2f s: %s", child.pid, child.ready_seconds or 0.0,
                 ready.info)

    def _run(self) -> None:
        try:
            while True:
                job = self._next_job()
                if job is None:
                    break
                try:
                    self._dispatch(job)
                except Exception as exc:  # noqa: BLE001 - a bug here must not end the thread
                    log.exception("supervising a render failed")
                    self._resolve(job, exc=exc)
                    self._lost(self._child, "the supervisor lost track of it")
        finally:
            with self._cond:
                child, spare = self._child, self._spare
                self._child = self._spare = None
            if spare is not None:
                spare.kill()  # it has served nothing, and may still be starting
            if child is not None:
                child.stop(KILL_GRACE)

    def _next_job(self) -> Job | None:
        """The next job to run, once a worker is ready for it; None when stopping."""
        while True:
            self._ensure_worker()
            expired: list[Job] = []
            with self._cond:
                if self._stopping:
                    return None
                job = None
                if self._child is not None:
                    now = time.perf_counter()
                    while self._queue:
                        candidate = self._queue.popleft()
                        if self._deadline(candidate, now) <= now:
                            candidate.state = "withdrawn"  # its waiter answers 503
                            expired.append(candidate)
                            continue
                        job = candidate
                        job.state = "running"
                        job.started = now
                        job.deadline = self._deadline(job, now)
                        self._running = job
                        break
                if job is None and not expired:
                    self._cond.wait(SPARE_POLL if self._spare is not None else IDLE_POLL)
            for old in expired:
                self._resolve(old, exc=self._queue_timeout_error())
            if job is not None:
                return job

    def _ensure_worker(self) -> None:
        """Swap in a replacement that became ready; restart a worker that is gone."""
        spare = self._spare
        if spare is not None:
            try:
                ready = spare.poll_ready(0.0)
            except RenderError as exc:
                log.warning("the replacement render worker did not start: %s", exc)
                spare.kill()
                self._spare, ready = None, False
            if ready:
                with self._cond:
                    old, self._spare = self._child, None
                    self.recycles += 1
                self._install(spare)
                if old is not None:
                    log.info("render worker %s retired after %d renders", old.pid, old.renders)
                    # Idle, so it exits at once; joined off this thread all the same.
                    threading.Thread(target=old.stop, args=(KILL_GRACE,), daemon=True,
                                     name="shadowmap-retire").start()
                return
        child = self._child
        if child is not None:
            if child.alive:
                return
            self._lost(child, f"exited unexpectedly (exit code {child.process.exitcode})")
        if self._stopping or time.perf_counter() < self._retry_at:
            return
        self._restart()

    def _lost(self, child: WorkerProcess | None, reason: str) -> None:
        """The current worker is gone or must go: kill it; a new one starts next."""
        if child is None:
            return
        if self._stopping:
            log.info("render worker %s stopped at shutdown (it %s)", child.pid, reason)
        else:
            log.warning("render worker %s %s; starting a new one", child.pid, reason)
        with self._cond:
            if self._child is child:
                self._child = None
                self.restarts += 1
                self._state = "restarting"
                if self._down_since is None:
                    self._down_since = time.perf_counter()
        child.kill()

    def _restart(self) -> None:
        """Start a worker (the replacement already starting, if any) and wait for it."""
        with self._cond:
            if self._down_since is None:
                self._down_since = time.perf_counter()
            self._state = "restarting"
            child, self._spare = self._spare, None
        if child is None:
            child = WorkerProcess(self._ctx, self._config)
        self._starting = child
        try:
            child.wait_ready(self.settings.startup_timeout)
        except RenderError as exc:
            self._starting = None
            if self._stopping:
                return
            pause = RESTART_BACKOFF[min(self._backoff, len(RESTART_BACKOFF) - 1)]
            log.error("cannot start a render worker (next try in %g s): %s", pause, exc)
            with self._cond:
                self._backoff += 1
                self._state = "down"
                self._retry_at = time.perf_counter() + pause
                failed = list(self._queue)
                self._queue.clear()
                for job in failed:
                    job.state = "withdrawn"
            for job in failed:
                self._resolve(job, exc=ServiceError(
                    503, "unavailable", f"the renderer cannot start: {exc}",
                    headers=_retry_after(pause)))
            return
        self._starting = None
        self._install(child)

    def _dispatch(self, job: Job) -> None:
        """Send a job to the worker, wait for its answer until the deadline, answer it."""
        child = self._child
        assert child is not None and job.started is not None and job.deadline is not None
        job.task.before = {"read": job.read_seconds, "queue": job.started - job.submitted}
        sent = time.perf_counter()
        job.task.elapsed = sent - job.request_started
        try:
            child.conn.send(("render", job.task))
        except (OSError, ValueError):
            # The worker died before the job reached it: the job never started, so it may go
            # again, once (it cannot have been what killed the worker).
            self._lost(child, "was gone when a job was sent to it")
            self._requeue_or_fail(job)
            return
        child.renders += 1
        started = False  # the worker has said it received the job
        while True:
            remaining = job.deadline - time.perf_counter()
            if not wait_for_ready([child.conn, child.process.sentinel], max(remaining, 0.0)):
                self._stop_running(child, job)
                return
            try:
                message = child.conn.recv() if child.conn.poll() else None
            except (EOFError, OSError):
                message = None
            if message is not None and message[1] == job.task.job_id:
                if message[0] != "started":
                    break
                started = True
                continue
            self._lost(child, "died during a render" if message is None
                       else "answered for another job")
            if not started:  # died before it took the job: not the job's doing
                self._requeue_or_fail(job)
            elif self._stopping:
                self._resolve(job, exc=self._shutting_down())
            else:
                self._resolve(job, exc=ServiceError(
                    503, "worker_restarted", "the render worker stopped during this render "
                    f"(exit code {child.process.exitcode}) and is being restarted; try again",
                    headers=_retry_after(self.restart_seconds)))
            return
        now = time.perf_counter()
        seconds = now - job.started
        if message[0] == "done":
            reply: RenderReply = message[2]
            reply.pipe = max(now - sent - reply.seconds, 0.0)
            reply.answered = now
            with self._cond:
                self.renders += 1
                self.costs.observe(job.size, seconds)
            # Before answering, so that whoever sees the answer also sees the replacement.
            self._recycle_if_due(child)
            self._resolve(job, result=reply)
            return
        _, _, payload, fatal = message
        with self._cond:
            self.failures += 1
        if fatal:
            self._lost(child, "failed in GL")
        else:
            self._recycle_if_due(child)
        self._resolve(job, exc=payload.rebuild())

    def _stop_running(self, child: WorkerProcess, job: Job) -> None:
        """The running job passed its deadline: answer 504, kill the worker, start another."""
        assert job.started is not None
        with self._cond:
            self.timeouts += 1
            self.costs.observe_at_least(job.size, time.perf_counter() - job.started)
        self._resolve(job, exc=self._timeout_error(job))
        self._lost(child, f"ran past render_timeout ({self.settings.render_timeout:g} s)")

    def _requeue_or_fail(self, job: Job) -> None:
        with self._cond:
            if self._running is job:
                self._running = None
            if job.attempts == 0 and not self._stopping:
                job.attempts += 1
                job.state = "queued"
                job.started = job.deadline = None
                self._queue.appendleft(job)
                return
        if self._stopping:
            self._resolve(job, exc=self._shutting_down())
            return
        self._resolve(job, exc=ServiceError(
            503, "worker_restarted", "the render worker stopped twice before this render could "
            "start; try again", headers=_retry_after(self.restart_seconds)))

    def _recycle_if_due(self, child: WorkerProcess) -> None:
        """Start a replacement beside a worker that has rendered or grown enough."""
        if child is not self._child or self._spare is not None or self._stopping:
            return
        s = self.settings
        reason = None
        if s.max_renders_per_worker and child.renders >= s.max_renders_per_worker:
            reason = f"{child.renders} renders (max_renders_per_worker)"
        elif s.max_worker_memory_bytes:
            rss = child.rss_bytes()
            if rss is not None and rss > s.max_worker_memory_bytes:
                reason = (f"{rss / 2**20:.0f} MiB resident, over max_worker_memory_bytes "
                          f"({s.max_worker_memory_bytes / 2**20:.0f} MiB)")
        if reason is not None:
            log.info("replacing render worker %s: %s", child.pid, reason)
            self._spare = WorkerProcess(self._ctx, self._config)

    def _resolve(self, job: Job, result: RenderReply | None = None,
                 exc: BaseException | None = None) -> None:
        """Give a job its answer (once; a later answer is dropped)."""
        with self._cond:
            if job.state != "withdrawn":
                job.state = "done"
            if self._running is job:
                self._running = None
        try:
            if result is not None:
                job.future.set_result(result)
            else:
                job.future.set_exception(exc or RenderError("the render ended with no answer"))
        except InvalidStateError:
            pass
