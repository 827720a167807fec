"""Batch throughput: jobs/s on the tests' 200-job manifest, by backend, and what a shared light
pass saves in a 16-view job.

Backends, each started once and then timed on whole batches (``resume=False``, a fresh output
folder per batch), interleaved over ``--repeats`` rounds:

- ``loop``: a plain Python loop in this process: one :class:`~shadowmap.batch.worker.JobRunner`,
  the same files written, the same records appended (no processes, no pool);
- ``local ×1``, ``local ×2``: :class:`~shadowmap.batch.LocalPool` with 1 and 2 worker processes
  (``--pools 1,2,4,8``: other sizes, for a machine with more cores or a GPU);
- ``ray ×1``, ``ray ×2``: :class:`~shadowmap.batch.ray.RayBackend` with 1 and 2 actors on a local
  cluster (``ray.init(num_cpus=3)``: three logical CPUs hold both Ray backends
  at once; one runs at a time). ``--no-ray`` leaves them out (Ray is the ``ray`` extra).

The manifest is ``tests/batch_jobs.py``'s: 96×72 images of the demo scene and four real models,
several output sets, some jobs with 3 views or 2 light lists, 6 bad jobs. Per-job overhead is
the difference of seconds per job against the loop (and Ray against the local pool).

The multi-view part renders Duck on a ground at 640×480 in this process: a 16-view job with
``shadows.fit: "view"`` (a light pass per view) and ``"scene"`` (one light pass reused by the
other 15 views), against a one-view job whose light casts no shadow and against the same 16
views with a light that casts none (the cameras differ in what they cost, so the second ratio
sets each view against itself); times are the worker's wall time per job (renders, PNG encoding,
meta.json), per view.

Writes ``bench/results/batch_throughput.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/batch_throughput.py [--quick] [--repeats N]
[--pools 1,2] [--no-ray]``
"""

from __future__ import annotations

import json
import math
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench import _common as C  # first: selects the GL platform
from shadowmap.batch import LocalPool, render_many  # noqa: E402
from shadowmap.batch.manifest import SceneBytes, SceneHasher, load_manifest  # noqa: E402
from shadowmap.batch.results import ResultsLog, write_job_files  # noqa: E402
from shadowmap.batch.worker import JobRunner, Task  # noqa: E402

sys.path.insert(0, str(C.ROOT / "tests"))
from batch_jobs import manifest_entries, write_manifest  # noqa: E402

VIEWS = 16


class LoopBackend:
    """The plain loop as a backend: jobs rendered one after another in this process."""

    name = "loop"

    def __init__(self) -> None:
        self.runner: JobRunner | None = None

    def start(self) -> None:
        if self.runner is None:
            self.runner = JobRunner()

    def close(self) -> None:
        if self.runner is not None:
            self.runner.close()
            self.runner = None

    def run(self, tasks):  # type: ignore[no-untyped-def]
        assert self.runner is not None
        for task, ref in tasks:
            yield self.runner.run(task, ref.read)


def time_batches(backends: dict[str, object], manifest: Path, work: Path, repeats: int
                 ) -> dict[str, list[float]]:
    """Seconds per whole batch, per backend, interleaved; one untimed batch each first."""
    out: dict[str, list[float]] = {name: [] for name in backends}
    for round_ in range(repeats + 1):
        for name, backend in backends.items():
            target = work / f"{name.replace(' ', '')}-{round_}"
            t = time.perf_counter()
            report = render_many(manifest, target, backend=backend, resume=False)  # type: ignore
            elapsed = time.perf_counter() - t
            assert report.counts["failed"] == 0 and report.counts["ok"] == 194, report.counts
            if round_:
                out[name].append(elapsed)
            shutil.rmtree(target)
    return out


#: The renderer's stages a view's ``meta.json`` times, shown per view in the multi-view table.
STAGES = ("plan", "light", "camera", "readback")


def multiview(repeats: int, width: int, height: int) -> dict[str, list[float]]:
    """Worker seconds per view of: 16 views with a light pass each, 16 sharing one, 1 unshadowed
    view, and the same 16 views unshadowed; under ``"<job>/<stage>"``, seconds per view of each
    of :data:`STAGES` (from the views' ``meta.json``) and of ``files``: the worker's time
    outside the renders (the views' PNG and ``meta.json``)."""
    duck = C.models_dir() / "Duck.glb"
    views = [{"eye": [3.2 * math.cos(a), 2.2, 3.2 * math.sin(a)], "target": [0, 0.6, 0]}
             for a in (2 * math.pi * k / VIEWS for k in range(VIEWS))]

    def task(name: str, params: dict, cameras: list[dict]) -> Task:
        return Task(name, "duck", str(duck), tuple(
            (f"view_{i:03d}", {**params, "camera": c}) for i, c in enumerate(cameras)), name)

    def tasks_of(round_: int) -> dict[str, Task]:
        # A slightly different light for each job of each round, so that no map of another job
        # is reused (from the whole ground in view, a view's fit can equal the scene's): each
        # 16-view job starts with its light pass drawn.
        def base(k: int) -> dict:
            d = [-0.5 + 0.01 * (3 * round_ + k), -1.0, -0.3]
            return {"width": width, "height": height, "ground": True,
                    "lights": [{"type": "directional", "direction": d}]}

        light = base(2)["lights"][0]
        return {
            "16 views, fit view": task("fit-view", {**base(0), "shadows": {"fit": "view"}},
                                       views),
            "16 views, fit scene": task("fit-scene", {**base(1), "shadows": {"fit": "scene"}},
                                        views),
            "1 view, no shadow": task("unshadowed", {**base(2), "lights": [
                {**light, "cast_shadows": False}]}, views[:1]),
            # The same 16 cameras unshadowed (its own light, so that no plan of the 1-view job
            # is reused): each shadowed view set against itself.
            "16 views, no shadow": task("unshadowed-16", {**base(3), "lights": [
                {**base(3)["lights"][0], "cast_shadows": False}]}, views),
        }

    data = duck.read_bytes()
    runner = JobRunner()
    out: dict[str, list[float]] = {k: [] for k in tasks_of(0)}
    cached: dict[str, int] = {}
    try:
        for round_ in range(repeats + 1):
            for name, t in tasks_of(round_).items():
                outcome = runner.run(t, lambda: SceneBytes(data, None, "glb"))
                assert outcome.ok, outcome.error
                cached[name] = outcome.light_passes_cached
                if round_:
                    count = len(t.variations)
                    out[name].append(outcome.seconds / count)
                    metas = [json.loads(outcome.files[f"{v}/meta.json"]) for v, _ in t.variations]
                    for stage in STAGES:
                        out.setdefault(f"{name}/{stage}", []).append(
                            sum(m["timings"].get(stage, 0.0) for m in metas) / count)
                    out.setdefault(f"{name}/files", []).append(
                        (outcome.seconds - outcome.render_seconds) / count)
        out["_info"] = [float(cached["16 views, fit scene"]), float(cached["16 views, fit view"])]
    finally:
        runner.close()
    return out


def run(quick: bool, repeats: int, pools: tuple[int, ...] = (1, 2), with_ray: bool = True
        ) -> None:
    t_start = time.perf_counter()
    out_dir = C.results_dir(quick)
    work = Path(tempfile.mkdtemp(prefix="shadowmap-batch-bench-"))
    entries = manifest_entries(C.models_dir(), work)
    manifest = write_manifest(work / "jobs.jsonl", entries)
    jobs = load_manifest(manifest)
    hasher = SceneHasher()
    t = time.perf_counter()
    for job in jobs:
        hasher.hash_inputs(job)
    hash_s = time.perf_counter() - t
    variations = sum(len(j.variations()) for j in jobs if j.error is None)
    if with_ray:
        import ray

        from shadowmap.batch.ray import RayBackend

        # Three logical CPUs, so that the 1-actor and the 2-actor backends (1 CPU per actor)
        # are held at once; only one of them runs at a time, on the machine's cores.
        ray.init(num_cpus=3, include_dashboard=False, object_store_memory=256 * 2**20,
                 log_to_driver=False)
    starts: dict[str, float] = {}
    backends: dict[str, object] = {}

    def started(name: str, backend: object) -> None:
        t = time.perf_counter()
        backend.start()  # type: ignore[attr-defined]
        starts[name] = time.perf_counter() - t
        backends[name] = backend

    started("loop", LoopBackend())
    for n in pools:
        started(f"local ×{n}", LocalPool(n))
    if with_ray:
        started("ray ×1", RayBackend(actors=1))
        started("ray ×2", RayBackend(actors=2))
    try:
        times = time_batches(backends, manifest, work, repeats)
        footer_renderer = JobRunner()
        try:
            footer = C.machine_info(footer_renderer.renderer)
        finally:
            footer_renderer.close()
    finally:
        for b in backends.values():
            b.close()  # type: ignore[attr-defined]
        if with_ray:
            ray.shutdown()
    # A driver-side cost: writing one job's files and its record, measured on its own.
    sample = next(j for j in jobs if j.error is None and j.views is None)
    log = ResultsLog(work / "drv")
    log.open()
    runner = JobRunner()
    try:
        task = Task(sample.id, sample.scene_digest, "x",
                    tuple((v.name, v.params) for v in sample.variations()), sample.input_hash)
        assert sample.scene is not None
        outcome = runner.run(task, sample.scene.read)
        t = time.perf_counter()
        for i in range(50):
            write_job_files(work / "drv", f"j{i}", outcome.files)
            log.append({"id": f"j{i}", "status": "ok"})
        driver_write = (time.perf_counter() - t) / 50
    finally:
        runner.close()
        log.close()
    mv = multiview(repeats if not quick else 1, 640 if not quick else 320,
                   480 if not quick else 240)
    shutil.rmtree(work, ignore_errors=True)

    n = len(jobs)
    med = {k: statistics.median(v) for k, v in times.items()}
    loop_job = med["loop"] / n
    rows, csv_rows = [], []
    for name, sec in med.items():
        per_job = sec / n
        ref = None
        if name.startswith("ray") and "local " + name.split()[1] in med:
            ref = med["local " + name.split()[1]] / n
        rows.append([name, C.fmt(n / sec, 1), C.fmt(per_job * 1000, 2),
                     C.fmt((per_job - loop_job) * 1000, 2),
                     C.fmt((per_job / ref - 1) * 100, 1) if ref else "—",
                     C.fmt(starts[name], 2), C.fmt(min(times[name]), 2),
                     C.fmt(max(times[name]), 2)])
        csv_rows.append({"backend": name, "jobs": n, "variations": variations,
                         "median_s": round(sec, 4), "jobs_per_s": round(n / sec, 3),
                         "ms_per_job": round(per_job * 1000, 3),
                         "start_s": round(starts[name], 3),
                         "runs": ";".join(f"{x:.3f}" for x in times[name])})
    table = C.markdown_table(
        ["backend", "jobs/s", "ms per job", "ms over the loop", "% over local (same count)",
         "start s", "fastest batch s", "slowest batch s"], rows)
    unshadowed = statistics.median(mv["1 view, no shadow"])
    same_views = statistics.median(mv["16 views, no shadow"])
    mv_rows = []
    for name in ("16 views, fit view", "16 views, fit scene", "1 view, no shadow",
                 "16 views, no shadow"):
        per_view = statistics.median(mv[name])
        stages = {k: statistics.median(mv[f"{name}/{k}"]) for k in (*STAGES, "files")}
        mv_rows.append([name, C.fmt(per_view * 1000, 1), C.fmt(per_view / unshadowed, 2),
                        C.fmt(per_view / same_views, 2),
                        *(C.fmt(v * 1000, 2) for v in stages.values())])
        csv_rows.append({"backend": "multiview", "case": name,
                         "ms_per_view": round(per_view * 1000, 3),
                         **{f"{k}_ms": round(v * 1000, 3) for k, v in stages.items()}})
    mv_table = C.markdown_table(["job", "ms per view", "× one unshadowed view",
                                 "× the same 16 views unshadowed",
                                 *(f"{k} ms" for k in (*STAGES, "files"))], mv_rows)
    size = "640×480" if not quick else "320×240"
    md = (
        "# Batch throughput\n\n"
        f"`bench/batch_throughput.py`: the tests' {n}-job manifest ({n - 6} good jobs, "
        f"{variations} renders at 96×72; 6 bad jobs), whole batches, medians of {repeats} "
        "interleaved runs after one untimed run each; backends started once (start s).\n\n"
        f"{table}\n\n"
        f"Hashing the manifest's inputs (reading each scene once): {hash_s * 1000:.0f} ms. "
        f"Writing one job's files and its record in the driver: {driver_write * 1000:.2f} ms.\n\n"
        f"## One job, {VIEWS} views (Duck on a ground, {size}, colour)\n\n"
        f"{mv_table}\n\n"
        "Per view, medians over the runs: the renderer's stages (`RenderResult.timings`, from "
        "each view's `meta.json`; *plan* includes resolving the camera) and *files*, the "
        "worker's time outside the renders (each view's PNG and `meta.json`).\n\n"
        f"With `fit: \"scene\"` {int(mv['_info'][0])} of the {VIEWS} light passes came from the "
        f"cache ({int(mv['_info'][1])} with `fit: \"view\"`).\n\n"
        f"{footer}\n"
    )
    C.finish(out_dir, "batch_throughput", md, csv_rows, [table, mv_table], [],
             time.perf_counter() - t_start)


def main(argv: list[str] | None = None) -> None:
    import argparse

    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--quick", action="store_true",
                    help="fewer repeats, smaller multi-view frames")
    ap.add_argument("--repeats", type=int, default=None,
                    help=f"timed batches per backend (default {C.DEFAULT_REPEATS}, quick 1)")
    ap.add_argument("--pools", default="1,2",
                    help="local pool sizes to time, comma-separated (default 1,2)")
    ap.add_argument("--no-ray", action="store_true", help="leave out the Ray backends")
    args = ap.parse_args(argv)
    pools = tuple(int(n) for n in args.pools.split(","))
    run(args.quick, args.repeats or (1 if args.quick else C.DEFAULT_REPEATS), pools,
        not args.no_ray)


if __name__ == "__main__":
    main()
