"""``GET /healthz`` and ``GET /version``: answered on the event loop, never through the GL queue."""

from __future__ import annotations

import platform

from fastapi import APIRouter
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field

from shadowmap import DISTRIBUTION, __version__

from ..deps import WorkerDep


class WorkerState(BaseModel):
    alive: bool = Field(description="the GL thread runs and has a context")
    busy_seconds: float | None = Field(description="age of the running render, null when idle")
    queued: int = Field(description="renders waiting (cancelled ones until the thread skips them)")
    queue_size: int
    renders: int = Field(description="renders finished since start-up")
    failures: int = Field(description="renders that raised, bad input included")


class Health(BaseModel):
    status: str = Field(description="ok, or unavailable when the GL thread is down")
    gl: dict[str, str] = Field(description="platform, renderer and version, read at start-up")
    worker: WorkerState


class Version(BaseModel):
    name: str
    version: str
    python: str


router = APIRouter(tags=["service"])


@router.get("/healthz", response_model=Health, responses={503: {"model": Health}})
async def healthz(worker: WorkerDep) -> JSONResponse:
    """Liveness: the GL thread is running. Answers at once even while renders are queued."""
    state = WorkerState(
        alive=worker.alive,
        busy_seconds=worker.busy_seconds,
        queued=worker.queued,
        queue_size=worker.settings.queue_size,
        renders=worker.renders,
        failures=worker.failures,
    )
    body = Health(status="ok" if state.alive else "unavailable", gl=worker.info, worker=state)
    return JSONResponse(body.model_dump(), status_code=200 if state.alive else 503)


@router.get("/version", response_model=Version)
async def version() -> Version:
    """The service's version."""
    return Version(name=DISTRIBUTION, version=__version__,
                   python=platform.python_version())
