"""The embedded backend: a pool of worker processes on this machine, one GL context each.

Each worker is a spawned process holding one :class:`~.worker.JobRunner` and a pipe to the
driver; it gets one job at a time (the next one is sent the moment it answers, before the driver
writes the files), so at most ``workers`` jobs are in flight and nothing queues unread. A worker
that dies (a crash in the GL driver, the OOM killer) is replaced and its job tried once more,
then recorded as ``worker_died``; a job past ``timeout`` seconds has its worker killed, the same
way (``timeout``).

Workers read scene files themselves (this machine's file system) and keep the last few scenes
loaded, so the jobs of one scene are parsed and uploaded once per worker.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.context import SpawnProcess
from typing import Any

from shadowmap.hosts import check_seconds, check_workers
from shadowmap.renderer import Limits
from shadowmap.renderer.allocator import keep_freed_memory

from .manifest import SceneBytes, SceneRef
from .worker import JobOutcome, Task

__all__ = ["LocalPool", "default_workers"]

#: Seconds a new worker may take to create its GL context and report ready.
START_TIMEOUT = 120.0


def default_workers() -> int:
    """Worker processes that use this machine well: one per core.

    llvmpipe (Mesa's CPU rasteriser) spreads one render over threads, but a batch job is mostly
    work it cannot spread (loading, planning, read-back, PNG encoding), so processes scale
    better: on 2 cores, 2 workers render the 200-job manifest about 1.2x faster than one
    (``bench/batch_throughput.py``). Each worker gets ``cores / workers`` llvmpipe threads
    (``LP_NUM_THREADS``), so the processes do not oversubscribe the cores.
    """
    return max(1, os.cpu_count() or 1)


@dataclass(frozen=True)
class PoolConfig:
    platform: str | None
    limits: Limits | None
    threads: int | None  # llvmpipe threads per worker (LP_NUM_THREADS), None: leave as is


def _worker_main(conn: Connection, config: PoolConfig) -> None:
    """A worker process: create the GL context, then render tasks until the pipe closes."""
    if config.threads and "LP_NUM_THREADS" not in os.environ:
        os.environ["LP_NUM_THREADS"] = str(config.threads)
    keep_freed_memory()  # this process only renders (see shadowmap.renderer.allocator)
    from .worker import JobRunner

    try:
        runner = JobRunner(config.platform, config.limits)
    except Exception as exc:  # noqa: BLE001  (reported to the driver, which stops the batch)
        conn.send(("failed", f"{type(exc).__name__}: {exc}"))
        return
    conn.send(("ready", runner.identity))
    try:
        while True:
            try:
                message = conn.recv()
            except EOFError:
                return
            if message is None:
                return
            task, ref = message

            def fetch(ref: SceneRef = ref) -> SceneBytes:
                return ref.read()

            conn.send(("done", runner.run(task, fetch)))
    finally:
        runner.close()


class _Worker:
    def __init__(self, ctx: Any, config: PoolConfig) -> None:
        self.conn, child = ctx.Pipe()
        self.proc: SpawnProcess = ctx.Process(target=_worker_main, args=(child, config),
                                              daemon=True, name="shadowmap-batch-worker")
        self.proc.start()
        child.close()
        self.task: Task | None = None
        self.ref: SceneRef | None = None
        self.started = 0.0
        self.ready = False

    def wait_ready(self) -> None:
        if not self.conn.poll(START_TIMEOUT):
            self.kill()
            raise RuntimeError(f"a batch worker did not start within {START_TIMEOUT:.0f} s")
        try:
            kind, info = self.conn.recv()
        except EOFError:
            raise RuntimeError("a batch worker exited while starting "
                               f"(exit code {self.proc.exitcode})") from None
        if kind != "ready":
            raise RuntimeError(f"a batch worker could not start: {info}")
        self.ready = True

    def send(self, task: Task, ref: SceneRef) -> None:
        self.task, self.ref, self.started = task, ref, time.monotonic()
        try:
            self.conn.send((task, ref))
        except OSError:
            pass  # the worker is gone: its sentinel says so, and the task is retried

    def kill(self) -> None:
        if self.proc.is_alive():
            self.proc.kill()
        self.proc.join(5)
        self.conn.close()

    def stop(self) -> None:
        try:
            self.conn.send(None)
        except OSError:
            pass
        self.proc.join(10)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join(5)
        self.conn.close()


class LocalPool:
    """Worker processes on this machine.

    Parameters
    ----------
    workers : int, optional
        Processes; :func:`default_workers` when omitted.

    Raises
    ------
    ValueError
        ``workers`` under 1 or over 4 per CPU (:func:`shadowmap.hosts.check_workers`).
    platform : {"egl", "osmesa"}, optional
    limits : Limits, optional
    timeout : float, optional
        Seconds one job may take before its worker is killed.
    """

    name = "local"

    def __init__(self, workers: int | None = None, *, platform: str | None = None,
                 limits: Limits | None = None, timeout: float | None = None) -> None:
        self.workers = workers or default_workers()
        check_workers(self.workers)
        cores = os.cpu_count() or 1
        self.config = PoolConfig(platform, limits, max(1, cores // self.workers))
        if timeout is not None:
            check_seconds(timeout, "timeout")
        self.timeout = timeout
        self._ctx = multiprocessing.get_context("spawn")
        self._pool: list[_Worker] = []
        self.replaced = 0

    def __enter__(self) -> LocalPool:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        if self._pool:
            return
        self._pool = [_Worker(self._ctx, self.config) for _ in range(self.workers)]
        try:
            for w in self._pool:
                w.wait_ready()  # they start together; this waits for the slowest
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        for w in self._pool:
            w.stop()
        self._pool = []

    def _replace(self, w: _Worker) -> _Worker:
        w.kill()
        self.replaced += 1
        new = _Worker(self._ctx, self.config)
        new.wait_ready()
        self._pool[self._pool.index(w)] = new
        return new

    def run(self, tasks: Iterable[tuple[Task, SceneRef]]) -> Iterator[JobOutcome]:
        """Outcomes of ``tasks`` in the order they finish; a job whose worker died twice (or
        ran past the time limit twice) comes back with an error."""
        self.start()
        source = iter(tasks)
        retry: deque[tuple[Task, SceneRef]] = deque()
        exhausted = False

        def feed(w: _Worker) -> None:
            nonlocal exhausted
            if retry:
                w.send(*retry.popleft())
                return
            if exhausted:
                return
            try:
                w.send(*next(source))
            except StopIteration:
                exhausted = True

        for w in self._pool:
            feed(w)
        while True:
            busy = [w for w in self._pool if w.task is not None]
            if not busy:
                if retry:
                    for w in self._pool:
                        feed(w)
                    continue
                return
            wait_for = None
            if self.timeout is not None:
                wait_for = max(0.0, min(w.started + self.timeout for w in busy) - time.monotonic())
            ready = wait([w.conn for w in busy] + [w.proc.sentinel for w in busy], wait_for)
            now = time.monotonic()
            for w in busy:
                lost: str | None = None
                if w.conn in ready or w.proc.sentinel in ready:
                    try:
                        if w.conn.poll():
                            kind, outcome = w.conn.recv()
                            task = w.task
                            w.task = None
                            feed(w)  # before the driver writes this job's files
                            assert kind == "done" and task is not None
                            yield outcome
                            continue
                        lost = "worker_died"
                    except (EOFError, OSError):
                        lost = "worker_died"
                elif self.timeout is not None and now - w.started > self.timeout:
                    lost = "timeout"
                if lost is None:
                    continue
                task, ref = w.task, w.ref
                assert task is not None and ref is not None
                exit_code = w.proc.exitcode
                new = self._replace(w)
                if task.attempt < 2:
                    retry.append((_again(task), ref))
                    feed(new)
                    continue
                feed(new)
                yield _lost_outcome(task, lost, self.timeout, exit_code)


def _again(task: Task) -> Task:
    from dataclasses import replace

    return replace(task, attempt=task.attempt + 1)


def _lost_outcome(task: Task, reason: str, timeout: float | None,
                  exit_code: int | None) -> JobOutcome:
    if reason == "timeout":
        detail = f"the job ran past the time limit of {timeout:g} s twice; its worker was killed"
    else:
        detail = ("its worker died twice while rendering it"
                  + (f" (last exit code {exit_code})" if exit_code is not None else ""))
    return JobOutcome(task.job_id, task.input_hash, task.attempt,
                      error={"error": reason, "detail": detail})
