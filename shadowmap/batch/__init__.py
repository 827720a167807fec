"""Batch rendering: many jobs (scenes × cameras × lights) to files, resumable, on this machine or
on a Ray cluster.

>>> from shadowmap.batch import render_many
>>> report = render_many("manifest.jsonl", "out/")                  # doctest: +SKIP
>>> report.counts                                                   # doctest: +SKIP
{'ok': 198, 'error': 2, 'failed': 0}

The library (:mod:`shadowmap.renderer`) knows nothing of batches; this package is one of its
clients, beside the HTTP service. Modules: ``manifest`` (jobs, ids, input hashes), ``worker``
(one job on one GL context), ``local`` (the process pool), ``ray`` (Ray actors), ``results``
(``results.jsonl``, resume).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from shadowmap.hosts import check_seconds
from shadowmap.renderer import Limits

from .errors import JobError
from .local import LocalPool, default_workers
from .manifest import (
    MAX_JOB_RENDERS,
    MAX_LINE_BYTES,
    Job,
    SceneHasher,
    SceneRef,
    load_manifest,
    parse_job,
)
from .results import ResultsLog, clean_partial, write_job_files
from .worker import JobOutcome, Task

__all__ = ["BatchReport", "Job", "JobError", "LocalPool", "Progress", "default_workers",
           "load_manifest", "render_many"]


class Progress(Protocol):
    """Told how many jobs will run, then of each record as it is written."""

    def start(self, total: int, skipped: int) -> None: ...

    def update(self, record: dict[str, Any]) -> None: ...


class Backend(Protocol):
    name: str

    def start(self) -> None: ...

    def close(self) -> None: ...

    def run(self, tasks: Iterable[tuple[Task, SceneRef]]) -> Iterable[JobOutcome]: ...


@dataclass
class BatchReport:
    """What a call of :func:`render_many` did.

    Attributes
    ----------
    records : list of dict
        The records written by this run, in the order they were written.
    skipped : int
        Jobs already done by an earlier run with the same inputs.
    seconds : float
        Wall time of the run, backend start included.
    backend : str
    """

    records: list[dict[str, Any]] = field(default_factory=list)
    skipped: int = 0
    seconds: float = 0.0
    backend: str = ""

    @property
    def counts(self) -> dict[str, int]:
        out = {"ok": 0, "error": 0, "failed": 0}
        for rec in self.records:
            out[rec["status"]] += 1
        return out


def _jobs(jobs: Iterable[Job | dict[str, Any]] | str | Path, base_dir: Path,
          limits: Limits, max_job_renders: int, max_line_bytes: int) -> list[Job]:
    if isinstance(jobs, (str, Path)):
        return load_manifest(jobs, limits, max_job_renders, max_line_bytes)
    out = []
    for i, job in enumerate(jobs, start=1):
        out.append(job if isinstance(job, Job)
                   else parse_job(job, base_dir, i, limits, max_job_renders))
    from .manifest import _unique_ids

    return _unique_ids(out)


def _record(job: Job, status: str, **fields: Any) -> dict[str, Any]:
    scene = None if job.scene is None else (
        f"builtin:{job.scene.builtin}" if job.scene.builtin else str(job.scene.path))
    return {"id": job.id, "hash": job.input_hash, "status": status, "line": job.line,
            "scene": scene, **fields}


def render_many(jobs: Iterable[Job | dict[str, Any]] | str | Path, out_dir: str | Path, *,
                workers: int | None = None, ray: str | None = None,
                actors: int | None = None, backend: Backend | None = None,
                limits: Limits | None = None, timeout: float | None = None,
                platform: str | None = None, resume: bool = True,
                base_dir: str | Path | None = None,
                progress: Progress | None = None,
                max_job_renders: int = MAX_JOB_RENDERS,
                max_line_bytes: int = MAX_LINE_BYTES) -> BatchReport:
    """Render every job to ``out_dir/<job id>/`` and record each in ``out_dir/results.jsonl``.

    Parameters
    ----------
    jobs : path, or iterable of Job or dict
        A JSON Lines manifest (see :mod:`.manifest`), or its entries as dicts (scene paths
        relative to ``base_dir``), or parsed jobs.
    out_dir : path
    workers : int, optional
        Local worker processes (:func:`default_workers` when omitted); ignored with ``ray``.
    ray : str, optional
        Use Ray: ``"auto"`` (join this machine's cluster, or start one) or a cluster address.
    actors : int, optional
        Ray actors (see :class:`~.ray.RayBackend`).
    backend : optional
        A started-or-not backend to use instead (:class:`LocalPool`, ``RayBackend``); it is
        left open for the caller.
    limits : Limits, optional
        What a job may ask for; over a limit, the job is an ``error`` record.
    max_job_renders : int
        Renders one job may ask for (its views times its light lists); a job asking for more
        is an ``error`` record (``limit_exceeded``), refused before any of them is validated.
    max_line_bytes : int
        Longest manifest line read (bytes); a longer one is an ``error`` record
        (``limit_exceeded``, limit ``max_line_bytes``), passed over without being held.
    timeout : float, optional
        Seconds one job may run before its worker is killed (tried once more, then ``failed``);
        above 0 and at most a week (:data:`shadowmap.hosts.MAX_SECONDS`), else ValueError.
    platform : {"egl", "osmesa"}, optional
    resume : bool
        Skip jobs that ``results.jsonl`` records as done with the same inputs (default).
        False renders every job again.
    base_dir : path, optional
        Folder that relative scene paths of dict entries start from (default: the working
        directory).
    progress : Progress, optional

    Returns
    -------
    BatchReport

    Raises
    ------
    OSError
        The manifest or the output folder cannot be read or written.
    RuntimeError
        The workers cannot start (no GL context).
    """
    t0 = time.perf_counter()
    if timeout is not None:
        check_seconds(timeout, "timeout")  # before any job is read or any worker started
    limits = limits or Limits()
    out = Path(out_dir)
    job_list = _jobs(jobs, Path(base_dir) if base_dir is not None else Path.cwd(), limits,
                     max_job_renders, max_line_bytes)
    hasher = SceneHasher()
    for job in job_list:
        hasher.hash_inputs(job)
    log = ResultsLog(out)
    latest = log.latest() if resume else {}
    todo = [j for j in job_list if not log.is_done(latest.get(j.id), j.input_hash)]
    report = BatchReport(skipped=len(job_list) - len(todo))
    if progress is not None:
        progress.start(len(todo), report.skipped)
    log.open()
    clean_partial(out)
    owned = backend is None
    try:
        by_id = {j.id: j for j in todo}

        def emit(rec: dict[str, Any]) -> None:
            log.append(rec)
            report.records.append(rec)
            if progress is not None:
                progress.update(rec)

        runnable = []
        for job in todo:
            if job.error is not None:
                emit(_record(job, "error", error=job.error.to_dict(), attempts=0))
            else:
                runnable.append(job)
        if runnable:
            if backend is None:
                backend = _make_backend(workers, ray, actors, limits, timeout, platform)
            report.backend = backend.name
            backend.start()
            tasks = [(_task(job), job.scene) for job in runnable]
            assert all(ref is not None for _, ref in tasks)
            for outcome in backend.run((t, r) for t, r in tasks if r is not None):
                job = by_id[outcome.job_id]
                emit(_outcome_record(job, outcome, out))
    finally:
        log.close()
        clean_partial(out)
        if owned and backend is not None:
            backend.close()
    report.seconds = time.perf_counter() - t0
    return report


def _make_backend(workers: int | None, ray: str | None, actors: int | None, limits: Limits,
                  timeout: float | None, platform: str | None) -> Backend:
    if ray is not None:
        from .ray import RayBackend

        return RayBackend(ray, actors=actors, limits=limits, timeout=timeout, platform=platform)
    return LocalPool(workers, limits=limits, timeout=timeout, platform=platform)


def _task(job: Job) -> Task:
    assert job.scene is not None
    label = job.scene.key if job.scene.path is None else str(job.scene.path)
    return Task(job.id, job.scene_digest, label,
                tuple((v.name, v.params) for v in job.variations()), job.input_hash)


def _outcome_record(job: Job, outcome: JobOutcome, out: Path) -> dict[str, Any]:
    common = {"attempts": outcome.attempt, "seconds": round(outcome.seconds, 6),
              "render_seconds": round(outcome.render_seconds, 6), "worker": outcome.worker,
              "variations": len(job.variations())}
    if outcome.error is not None:
        status = "failed" if outcome.error.get("error") in ("worker_died", "timeout") else "error"
        return _record(job, status, error=outcome.error, **common)
    names = write_job_files(out, job.id, outcome.files)
    return _record(job, "ok", outputs=names, light_passes_cached=outcome.light_passes_cached,
                   **common)
