"""Page faults of a process that only renders: new arrays per frame, arrays used again, and
freed memory kept by the allocator.

An array of a frame's size can be memory the process has not touched since the allocator last
gave such a block back to the system: then each first write to one of its pages is a page
fault. Whether it is depends on what else the process allocated and freed, so each arm runs in
a process of its own, as a service worker or a batch worker does, one call each in turn:

- ``new``: every frame read back into a new array (the camera pass's ``ReadbackBuffers`` keep
  none), the C allocator as it comes;
- ``kept``: frames read into the ``ReadbackBuffers``' arrays, used again once nothing holds
  them;
- ``kept + allocator``: the same, in a process that called
  :func:`shadowmap.renderer.allocator.keep_freed_memory` (as the service's worker and the
  batch's workers do).

The paths:

- ``render``: :meth:`Renderer.render` alone (colour), the result let go before the next call;
- ``service``: the service's worker path for one HTTP request (:func:`shadowmap.app.worker.execute`:
  the upload looked up, the render, its PNG response built);
- ``batch``: one view of a batch job with colour, visibility and depth (the render and
  :func:`shadowmap.batch.worker.variation_files`: PNG and ``.npy`` files, ``meta.json``).

Reports per call the median wall time, the readback and encode stages, and the minor page faults
(``getrusage``). Writes ``bench/results/page_faults.{md,csv}`` (``--quick``:
``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/page_faults.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import multiprocessing as mp
import resource
import time
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from types import SimpleNamespace

from bench import _common as C  # before anything that imports PyOpenGL: selects the platform
from shadowmap.renderer import RenderParams  # noqa: E402

ARMS = ("new", "kept", "kept + allocator")
PATHS = ("render", "service", "batch")


def _faults() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt


def _server_timing(header: str) -> dict[str, float]:
    out = {}
    for item in header.split(","):
        name, _, rest = item.strip().partition(";")
        for part in rest.split(";"):
            if part.strip().startswith("dur="):
                out[name] = float(part.strip()[4:]) / 1e3
    return out


def _arm(conn: Connection, arm: str, path: str, width: int, height: int) -> None:
    """One arm in a process of its own. Answers each message with one call's (wall s, faults,
    stages)."""
    from shadowmap.app.worker import RenderTask, execute
    from shadowmap.batch.worker import variation_files
    from shadowmap.renderer import Renderer
    from shadowmap.renderer.allocator import keep_freed_memory

    if arm == "kept + allocator":
        keep_freed_memory()
    data = (C.models_dir() / C.MODEL_NAMES[0]).read_bytes()
    outputs = ["color", "visibility", "depth"] if path == "batch" else ["color"]
    params = RenderParams(width=width, height=height, ground=True, outputs=outputs)
    job = SimpleNamespace(job_id="bench", scene_label=C.MODEL_NAMES[0])
    with Renderer() as r:
        r.camera_pass.readback.per_shape = 0 if arm == "new" else 2
        scene = r.load(data)

        def call() -> dict[str, float]:
            if path == "service":
                task = RenderTask(0, data, "glb", {}, params, "image/png", ["color"])
                return _server_timing(execute(r, task).headers["server-timing"])
            result = r.render(scene, params)
            stages = dict(result.timings)
            if path == "batch":
                t = time.perf_counter()
                variation_files(result, job, "", {})  # type: ignore[arg-type]
                stages["encode"] = time.perf_counter() - t
            return stages

        conn.send(C.machine_info(r))
        while conn.recv():
            f0, t = _faults(), time.perf_counter()
            stages = call()
            conn.send((time.perf_counter() - t, _faults() - f0, stages))


def _recv(conn: Connection, proc: BaseProcess, arm: str) -> object:
    """The arm's next answer; an error naming the arm if its process ended instead."""
    if conn not in wait([conn, proc.sentinel]) and not conn.poll():
        raise RuntimeError(f"the {arm!r} process ended (exit status {proc.exitcode})")
    return conn.recv()


def _measure(path: str, width: int, height: int,
             repeats: int) -> tuple[dict[str, dict[str, float]], str]:
    """Median wall s, faults and stages of each arm's call, the arms' processes in turn (each
    repeat starting one arm later), after two warm-up calls each."""
    ctx = mp.get_context("spawn")
    procs, conns, footer = {}, {}, ""
    samples: dict[str, dict[str, list[float]]] = {a: {} for a in ARMS}
    try:
        for arm in ARMS:
            conns[arm], child = ctx.Pipe()
            procs[arm] = ctx.Process(target=_arm, args=(child, arm, path, width, height))
            procs[arm].start()
            footer = str(_recv(conns[arm], procs[arm], arm))
        for k in range(repeats + 2):
            for arm in ARMS[k % len(ARMS):] + ARMS[:k % len(ARMS)]:
                conns[arm].send(True)
                wall, faults, stages = _recv(conns[arm], procs[arm], arm)  # type: ignore[misc]
                if k < 2:
                    continue
                s = samples[arm]
                s.setdefault("wall", []).append(wall)
                s.setdefault("faults", []).append(faults)
                for name in ("readback", "encode"):
                    if name in stages:
                        s.setdefault(name, []).append(stages[name])
    finally:
        for arm, proc in procs.items():
            if proc.is_alive():
                conns[arm].send(False)
            proc.join(30)
    return {a: {k: C.median(v) for k, v in s.items()} for a, s in samples.items()}, footer


def run(quick: bool, repeats: int) -> None:
    t_start = time.perf_counter()
    out_dir = C.results_dir(quick)
    name = C.MODEL_NAMES[0]
    sizes = [(640, 480)] if quick else [(640, 480), (1920, 1080)]
    rows, csv_rows = [], []
    footer = ""
    for w, h in sizes:
        for path in PATHS:
            m, footer = _measure(path, w, h, repeats)
            base = m["new"]["wall"]
            row = [f"{name} {w}×{h}", path]
            for arm in ARMS:
                row += [C.fmt(1e3 * m[arm]["wall"], 2)]
            for arm in ARMS[1:]:
                row += [C.fmt(m[arm]["wall"] / base, 3)]
            for arm in ARMS:
                row += [C.fmt(1e3 * m[arm]["readback"], 2)]
            for arm in ARMS:
                row += [C.fmt(1e3 * m[arm].get("encode", float("nan")), 2)]
            for arm in ARMS:
                row += [C.fmt(m[arm]["faults"], 0)]
            rows.append(row)
            csv_rows.append({"frame": f"{name} {w}x{h}", "path": path,
                             **{f"{a}_{k}": v for a in ARMS for k, v in m[a].items()}})
    headers = (["frame", "path"] + [f"{a} ms" for a in ARMS]
               + [f"{a} / new" for a in ARMS[1:]] + [f"readback, {a} ms" for a in ARMS]
               + [f"files, {a} ms" for a in ARMS] + [f"page faults, {a}" for a in ARMS])
    table = C.markdown_table(headers, rows)
    md = (f"# Page faults of a process that only renders (`bench/page_faults.py`)\n\n{table}\n\n"
          f"Default settings with a ground plane. *render*: `Renderer.render` alone, colour; "
          f"*service*: the worker's path for one HTTP request (upload looked up, render, PNG "
          f"response built); *batch*: one view of a batch job with colour, visibility and depth "
          f"(render, then its PNG and `.npy` files and `meta.json`). *new*: each frame read into "
          f"a new array; *kept*: into the camera pass's `ReadbackBuffers`; *kept + allocator*: "
          f"the same in a process that called `keep_freed_memory()`. Files: the service's "
          f"`encode` stage, the batch's files. Each arm in a process of its own (as a worker "
          f"is: its heap holds what its own calls left), one call each in turn, each repeat "
          f"starting one arm later; medians of {repeats} calls per arm after two warm-ups; page "
          f"faults: minor faults per call. {footer}\n")
    C.finish(out_dir, "page_faults", md, csv_rows, [table], [], time.perf_counter() - t_start)


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__ or "", run, "one frame size, 10 calls per arm", 10, argv)


if __name__ == "__main__":
    main()
