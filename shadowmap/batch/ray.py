"""The Ray backend: actors that each own one Renderer, fed with back-pressure.

- Each actor is a Ray actor process holding one :class:`~.worker.JobRunner` (one GL context). It
  asks Ray for ``cpus_per_actor`` CPUs and, on a cluster with GPUs, one GPU; an actor given a GPU
  renders on the EGL device of that index (``SHADOWMAP_EGL_DEVICE``, read by
  :class:`shadowmap.renderer.gl.context.GLContext`), so actors on one node use different GPUs.
- A scene's bytes are read once by the driver and put in Ray's object store once; every job and
  view of that scene passes the same reference, and an actor fetches it only when it has not
  loaded that scene already. The reference is dropped when the last job of the scene is done.
- At most ``depth`` jobs wait at each actor (the driver submits more as they finish), so a batch
  of any size holds a bounded number of tasks and results in the object store.
- An actor that dies is replaced (Ray's own restart is off, so the driver knows each attempt):
  the job it was running is tried once more, then recorded as ``worker_died``; jobs queued behind
  it are sent again without counting an attempt. A job past ``timeout`` seconds has its actor
  killed, the same way (``timeout``).

``ray`` is imported when the backend starts (the ``ray`` extra).
"""

from __future__ import annotations

import os
import time
from collections import Counter, deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

from shadowmap.hosts import check_address, check_seconds
from shadowmap.renderer import Limits
from shadowmap.renderer.allocator import keep_freed_memory

from .manifest import SceneBytes, SceneRef
from .worker import JobOutcome, Task

__all__ = ["RayBackend"]

#: Seconds the actors may take to be placed and create their GL contexts.
START_TIMEOUT = 120.0


class _RenderActor:
    """The actor's class (made a Ray actor by :meth:`RayBackend.start`)."""

    def __init__(self, platform: str | None, limits: Limits | None, threads: int) -> None:
        import ray

        gpus = ray.get_gpu_ids()
        if gpus:
            # Ray hands out physical GPU indices; EGL enumerates the same devices.
            os.environ["SHADOWMAP_EGL_DEVICE"] = str(int(gpus[0]))
        os.environ.setdefault("LP_NUM_THREADS", str(max(1, threads)))
        keep_freed_memory()  # this process only renders (see shadowmap.renderer.allocator)
        from .worker import JobRunner

        self.runner = JobRunner(platform, limits)
        self.fetched = 0

    def identity(self) -> dict[str, Any]:
        return {**self.runner.identity, "egl_device": os.environ.get("SHADOWMAP_EGL_DEVICE")}

    def run(self, task: Task, scene: list[Any]) -> JobOutcome:
        # ``scene`` holds the ObjectRef inside a list, so Ray does not fetch it before the call:
        # the actor fetches it only on a miss in its own scene cache.
        import ray

        def fetch() -> SceneBytes:
            self.fetched += 1
            value: SceneBytes = ray.get(scene[0])
            return value

        return self.runner.run(task, fetch)


@dataclass
class _Slot:
    handle: Any
    inflight: deque = field(default_factory=deque)  # (ref, task, scene ref, digest)
    head_since: float = 0.0
    timed_out: bool = False


class RayBackend:
    """Ray actors on a local or remote cluster.

    Parameters
    ----------
    address : str, optional
        ``"auto"`` or None: join the Ray cluster this machine runs, else start a local one;
        anything else is given to ``ray.init(address=...)`` (``ray://head:10001``,
        ``head:6379``). When Ray is already initialised in this process it is used as is.
    actors : int, optional
        Default: one per GPU when the cluster has GPUs, else one per ``cpus_per_actor`` CPUs.
    cpus_per_actor : float
    gpus_per_actor : float, optional
        Default 1 when the cluster has GPUs, else 0.
    platform : {"egl", "osmesa"}, optional
    limits : Limits, optional
    timeout : float, optional
        Seconds one job may run before its actor is killed.
    depth : int
        Jobs queued at each actor.
    init_kwargs : dict, optional
        More arguments for ``ray.init`` when this backend starts Ray.
    """

    name = "ray"

    def __init__(self, address: str | None = "auto", *, actors: int | None = None,
                 cpus_per_actor: float = 1.0, gpus_per_actor: float | None = None,
                 platform: str | None = None, limits: Limits | None = None,
                 timeout: float | None = None, depth: int = 2,
                 init_kwargs: dict[str, Any] | None = None) -> None:
        self.address = None if address in (None, "auto") else address
        self.actors = actors
        self.cpus_per_actor = cpus_per_actor
        self.gpus_per_actor = gpus_per_actor
        self.platform = platform
        self.limits = limits
        if timeout is not None:
            check_seconds(timeout, "timeout")
        self.timeout = timeout
        self.depth = max(1, depth)
        self.init_kwargs = init_kwargs or {}
        self._slots: list[_Slot] = []
        self._actor_cls: Any = None
        self.replaced = 0
        self.scene_puts = 0

    def __enter__(self) -> RayBackend:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def start(self) -> None:
        if self._slots:
            return
        import ray

        if not ray.is_initialized():
            check_address(self.address)  # in seconds, where ray.init would retry for minutes
            try:
                ray.init(address=self.address, **self.init_kwargs)
            except (ConnectionError, ValueError) as exc:  # something else answers there
                raise RuntimeError(f"cannot join the Ray cluster at {self.address}: "
                                   f"{exc}") from None
        resources = ray.cluster_resources()
        cpus, gpus = float(resources.get("CPU", 1)), float(resources.get("GPU", 0))
        if self.gpus_per_actor is None:
            self.gpus_per_actor = 1.0 if gpus >= 1 else 0.0
        if self.actors is None:
            self.actors = int(gpus // self.gpus_per_actor) if self.gpus_per_actor else \
                int(cpus // self.cpus_per_actor)
            self.actors = max(1, self.actors)
        self._actor_cls = ray.remote(_RenderActor).options(
            num_cpus=self.cpus_per_actor, num_gpus=self.gpus_per_actor,
            max_restarts=0, max_task_retries=0)
        self._slots = [self._new_slot() for _ in range(self.actors)]
        # Wait until every actor has its GL context, so a broken set-up fails here, whole.
        try:
            ray.get([s.handle.identity.remote() for s in self._slots], timeout=START_TIMEOUT)
        except ray.exceptions.GetTimeoutError:
            self.close()
            raise RuntimeError(
                f"{self.actors} Ray actors ({self.cpus_per_actor:g} CPU, {self.gpus_per_actor:g} "
                f"GPU each) did not start within {START_TIMEOUT:.0f} s: the cluster has "
                f"{cpus:g} CPUs and {gpus:g} GPUs, some perhaps held by other actors") from None

    def _new_slot(self) -> _Slot:
        threads = max(1, int(round(self.cpus_per_actor)))
        return _Slot(self._actor_cls.remote(self.platform, self.limits, threads))

    def close(self) -> None:
        import ray

        for s in self._slots:
            ray.kill(s.handle, no_restart=True)
        self._slots = []

    def identities(self) -> list[dict[str, Any]]:
        import ray

        return list(ray.get([s.handle.identity.remote() for s in self._slots]))

    def run(self, tasks: Iterable[tuple[Task, SceneRef]]) -> Iterator[JobOutcome]:
        """Outcomes of ``tasks`` in the order they finish (see the module's notes)."""
        import ray
        from ray.exceptions import RayActorError

        unavailable: tuple[type[BaseException], ...] = (RayActorError,)
        extra = getattr(ray.exceptions, "ActorUnavailableError", None)
        if extra is not None:
            unavailable += (extra,)
        self.start()
        todo = list(tasks)
        uses = Counter(t.scene_digest for t, _ in todo)
        puts: dict[str, Any] = {}
        queue: deque[tuple[Task, SceneRef]] = deque(todo)
        owner: dict[Any, _Slot] = {}

        def submit(slot: _Slot) -> None:
            while queue and len(slot.inflight) < self.depth:
                task, sref = queue.popleft()
                digest = task.scene_digest
                if digest not in puts:
                    puts[digest] = ray.put(sref.read())  # once per scene while it is in use
                    self.scene_puts += 1
                ref = slot.handle.run.remote(task, [puts[digest]])
                if not slot.inflight:
                    slot.head_since = time.monotonic()
                slot.inflight.append((ref, task, sref, digest))
                owner[ref] = slot

        def finished(digest: str) -> None:
            uses[digest] -= 1
            if uses[digest] <= 0:
                puts.pop(digest, None)  # the last job of this scene: free its bytes

        for slot in self._slots:
            submit(slot)
        while owner:
            wait_for = None
            if self.timeout is not None:
                heads = [s.head_since for s in self._slots if s.inflight]
                wait_for = max(0.0, min(heads) + self.timeout - time.monotonic())
            ready, _ = ray.wait(list(owner), num_returns=1, timeout=wait_for)
            if not ready:
                self._kill_late()
                continue
            # An actor runs its tasks in order: what is ready is its first one, or (when the actor
            # died) every one, and the first is handled first either way.
            slot = owner[ready[0]]
            ref, task, sref, digest = slot.inflight[0]
            try:
                outcome: JobOutcome = ray.get(ref)
            except unavailable:
                yield from self._lost(slot, owner, queue, finished, submit)
                continue
            except ray.exceptions.RayError as exc:
                outcome = JobOutcome(task.job_id, task.input_hash, task.attempt, error={
                    "error": "internal_error", "detail": f"{type(exc).__name__}: {exc}"})
            slot.inflight.popleft()
            del owner[ref]
            slot.head_since = time.monotonic()
            finished(digest)
            submit(slot)
            yield outcome

    def _kill_late(self) -> None:
        import ray

        now = time.monotonic()
        for s in self._slots:
            if s.inflight and not s.timed_out and now - s.head_since > (self.timeout or 0):
                s.timed_out = True
                ray.kill(s.handle, no_restart=True)

    def _lost(self, slot: _Slot, owner: dict, queue: deque, finished: Any,
              submit: Any) -> Iterator[JobOutcome]:
        """The actor of ``slot`` died: replace it, retry its running job once, requeue the rest."""
        reason = "timeout" if slot.timed_out else "worker_died"
        entries = list(slot.inflight)
        for ref, *_ in entries:
            owner.pop(ref, None)
        new = self._new_slot()
        self._slots[self._slots.index(slot)] = new
        self.replaced += 1
        (_, head, head_ref, digest), rest = entries[0], entries[1:]
        # Jobs queued behind the running one never started: first in line again, same attempt.
        for _, task, sref, _ in reversed(rest):
            queue.appendleft((task, sref))
        lost = None
        if head.attempt < 2:
            queue.appendleft((replace(head, attempt=head.attempt + 1), head_ref))
        else:
            finished(digest)
            if reason == "timeout":
                detail = (f"the job ran past the time limit of {self.timeout:g} s twice; "
                          "its actor was killed")
            else:
                detail = "its actor died twice while rendering it"
            lost = JobOutcome(head.job_id, head.input_hash, head.attempt,
                              error={"error": reason, "detail": detail})
        for s in self._slots:
            submit(s)
        if lost is not None:
            yield lost
