"""``GET /healthz`` and ``GET /version``: answered on the event loop, never through the queue."""

from __future__ import annotations

import platform

from fastapi import APIRouter
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from shadowmap import DISTRIBUTION, __version__

from ..deps import WorkerDep


class WorkerState(BaseModel):
    alive: bool = Field(description="renders are accepted: a worker process is ready, busy or "
                        "being replaced")
    state: str = Field(description="ready, busy, restarting (after a crash or a timeout), down "
                       "(cannot start one; retried) or stopped")
    pid: int | None = Field(description="process id of the render worker, null while none runs")
    replacing: bool = Field(description="a replacement worker is starting beside this one (it "
                            "takes over between renders)")
    busy_seconds: float | None = Field(description="age of the running render, null when idle")
    queued: int = Field(description="renders waiting")
    queue_size: int
    expected_wait: float = Field(description="seconds a render queued now would wait before "
                                 "it starts (estimated; admission compares it with "
                                 "max_expected_wait)")
    renders: int = Field(description="renders finished since start-up")
    failures: int = Field(description="renders that raised, bad input included")
    timeouts: int = Field(description="renders stopped at render_timeout")
    restarts: int = Field(description="worker processes replaced after a crash, a timeout or a "
                          "GL failure")
    recycles: int = Field(description="worker processes replaced after max_renders_per_worker "
                          "renders or above max_worker_memory_bytes")
    worker_renders: int = Field(description="renders of the current worker process")
    worker_rss_bytes: int | None = Field(description="resident memory of the current worker "
                                         "process")
    restart_seconds: float = Field(description="how long the last worker took to start")


class Health(BaseModel):
    status: str = Field(description="ok, or unavailable when no render worker can run")
    gl: dict[str, str] = Field(description="platform, renderer and version, read by the worker")
    worker: WorkerState


class Version(BaseModel):
    name: str
    version: str
    python: str


router = APIRouter(tags=["service"])


@router.get("/healthz", response_model=Health, operation_id="healthz",
            responses={503: {"model": Health, "description": "no render worker can run (status "
                             "unavailable)"}})
async def healthz(worker: WorkerDep) -> JSONResponse:
    """Liveness: renders are accepted. Answers at once even while renders are queued."""
    state = WorkerState(**worker.snapshot())
    body = Health(status="ok" if state.alive else "unavailable", gl=worker.info, worker=state)
    return JSONResponse(body.model_dump(), status_code=200 if state.alive else 503)


@router.get("/version", response_model=Version, operation_id="version")
async def version() -> Version:
    """The service's version."""
    return Version(name=DISTRIBUTION, version=__version__,
                   python=platform.python_version())
