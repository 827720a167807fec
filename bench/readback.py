"""Reading frames back into arrays used again, against new arrays per frame.

A frame read into a new array can write pages the process has not touched since the allocator
last gave such a block back to the system: each first write is a page fault. The camera pass
reads into :class:`shadowmap.renderer.gl.resources.ReadbackBuffers`, which takes an array again
once nothing refers to it. This benchmark renders the same requests with those buffers (``kept``)
and with each frame read into a new array (``new``: the buffers keep none), each in a process
of its own (the allocator's state is the process's: a service worker's holds what its own
requests left), one call each in turn, and reports per call the median wall time, the readback
and encode stages and the minor page faults (``getrusage``):

- ``render``: :meth:`Renderer.render` alone, the result let go before the next call;
- ``service``: the service's worker path (:func:`shadowmap.app.worker.execute`: the upload
  looked up, the render, its PNG response built), as one HTTP request runs it.

Writes ``bench/results/readback.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/readback.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import multiprocessing as mp
import resource
import time
from multiprocessing.connection import Connection

from bench import _common as C  # before anything that imports PyOpenGL: selects the platform
from shadowmap.app.worker import RenderTask, execute  # noqa: E402
from shadowmap.renderer import RenderParams  # noqa: E402

ARMS = ("new", "kept")
KEEP = {"new": 0, "kept": 2}  # arrays the readback buffers keep per shape


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
    """One arm in a process of its own, as a service worker is: its heap holds only what its
    own calls left. Answers each message with one call's (wall s, faults, stages)."""
    from shadowmap.renderer import Renderer

    data = (C.models_dir() / C.MODEL_NAMES[0]).read_bytes()
    params = RenderParams(width=width, height=height, ground=True)
    with Renderer() as r:
        r.camera_pass.readback.per_shape = KEEP[arm]
        scene = r.load(data)

        def call() -> dict[str, float]:
            if path == "render":
                return dict(r.render(scene, params).timings)
            task = RenderTask(0, data, "glb", {}, params, "image/png", ["color"])
            return _server_timing(execute(r, task).headers["server-timing"])

        conn.send(C.machine_info(r))
        while conn.recv():
            f0, t = _faults(), time.perf_counter()
            stages = call()
            conn.send((time.perf_counter() - t, _faults() - f0, stages))


def _measure(path: str, width: int, height: int,
             repeats: int) -> tuple[dict[str, dict[str, float]], str]:
    """Median wall s, faults and stages of each arm's call, the arms' processes in turn (order
    swapped every repeat), after two warm-up calls each."""
    ctx = mp.get_context("spawn")
    procs, conns, footer = {}, {}, ""
    try:
        for arm in ARMS:
            conns[arm], child = ctx.Pipe()
            procs[arm] = ctx.Process(target=_arm, args=(child, arm, path, width, height))
            procs[arm].start()
            footer = conns[arm].recv()
        samples: dict[str, dict[str, list[float]]] = {a: {} for a in ARMS}
        for k in range(repeats + 2):
            for arm in (ARMS if k % 2 else ARMS[::-1]):
                conns[arm].send(True)
                wall, faults, stages = conns[arm].recv()
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
        for path in ("render", "service"):
            m, footer = _measure(path, w, h, repeats)
            new, kept = m["new"], m["kept"]
            rows.append([f"{name} {w}×{h}", path,
                         C.fmt(1e3 * new["wall"], 2), C.fmt(1e3 * kept["wall"], 2),
                         C.fmt(kept["wall"] / new["wall"], 3),
                         C.fmt(1e3 * new["readback"], 2), C.fmt(1e3 * kept["readback"], 2),
                         C.fmt(1e3 * new.get("encode", float("nan")), 2),
                         C.fmt(1e3 * kept.get("encode", float("nan")), 2),
                         C.fmt(new["faults"], 0), C.fmt(kept["faults"], 0)])
            csv_rows.append({"frame": f"{name} {w}x{h}", "path": path,
                             **{f"{a}_{k}": v for a in ARMS for k, v in m[a].items()}})
    table = C.markdown_table(
        ["frame", "path", "new arrays ms", "kept arrays ms", "kept / new",
         "readback, new ms", "readback, kept ms", "encode, new ms", "encode, kept ms",
         "page faults, new", "page faults, kept"], rows)
    md = (f"# Frames read back into arrays used again (`bench/readback.py`)\n\n{table}\n\n"
          f"Default settings with a ground plane, colour output. *render*: "
          f"`Renderer.render` alone; *service*: the worker's path for one HTTP request (upload "
          f"looked up, render, PNG response built). *new*: each frame read into a new array; "
          f"*kept*: into the camera pass's `ReadbackBuffers`. Each arm in a process of its own "
          f"(as a service worker is: its heap holds what its own calls left), one call each "
          f"in turn, the order swapped every repeat; medians of {repeats} calls per arm after "
          f"two warm-ups; page faults: minor faults per "
          f"call. {footer}\n")
    C.finish(out_dir, "readback", md, csv_rows, [table], [], time.perf_counter() - t_start)


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__ or "", run, "one frame size, 10 calls per arm", 10, argv)


if __name__ == "__main__":
    main()
