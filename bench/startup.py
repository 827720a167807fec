"""Start-up cost: what a new process pays before its first render, and what it loads.

Each command runs in a fresh interpreter (``PYOPENGL_PLATFORM`` unset, as for a new user), the
commands interleaved, ``--repeats`` times; the table gives the median wall time and whether
PyOpenGL or pyrender were imported (the library selects a GL platform only when a ``Renderer`` is
created). Written to bench/results/startup.md and .csv.

Run: ``PYTHONPATH=. .venv/bin/python bench/startup.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

from bench import _common as C

PROBE = ("import sys; {code}; "
         "print(int('OpenGL' in sys.modules), int('pyrender' in sys.modules))")

COMMANDS: dict[str, str] = {
    "import shadowmap": "import shadowmap",
    "import the request model and the scene loader":
        "import shadowmap.renderer.params, shadowmap.renderer.scene",
    "shadowmap --help": "import shadowmap.cli as c; c.build_parser().format_help()",
    "import the service (shadowmap.app.main)": "import shadowmap.app.main",
    "create and close a Renderer (GL context)":
        "from shadowmap import Renderer; Renderer().close()",
}


def _run(code: str) -> tuple[float, bool, bool]:
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    t = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", PROBE.format(code=code)], env=env,
                         capture_output=True, text=True, check=True, timeout=120).stdout
    seconds = time.perf_counter() - t
    gl, pyr = (bool(int(v)) for v in out.split())
    return seconds, gl, pyr


def run(quick: bool, repeats: int) -> None:
    started = time.perf_counter()
    times: dict[str, list[float]] = {name: [] for name in COMMANDS}
    loaded: dict[str, tuple[bool, bool]] = {}
    bar = C.Progress(repeats * len(COMMANDS), "startup")
    for _ in range(repeats):  # interleaved: a drifting machine affects every command alike
        for name, code in COMMANDS.items():
            seconds, gl, pyr = _run(code)
            times[name].append(seconds)
            loaded[name] = (gl, pyr)
            bar.step(name)
    rows = []
    for name in COMMANDS:
        gl, pyr = loaded[name]
        rows.append({"command": name, "median_s": round(C.median(times[name]), 3),
                     "min_s": round(min(times[name]), 3), "OpenGL": gl, "pyrender": pyr})
    headers = ["command", "median s", "min s", "imports PyOpenGL", "imports pyrender"]
    table = C.markdown_table(headers, [[r["command"], f"{r['median_s']:.3f}", f"{r['min_s']:.3f}",
                                        "yes" if r["OpenGL"] else "no",
                                        "yes" if r["pyrender"] else "no"] for r in rows])
    md = (f"# Start-up cost\n\n{__doc__.splitlines()[0]}\n\n{table}\n\n"
          f"{repeats} fresh interpreters per command, interleaved. {C.code_state()}\n")
    C.finish(C.results_dir(quick), "startup", md, rows, [table], [], time.perf_counter() - started)


if __name__ == "__main__":
    C.bench_main(__doc__, run, "three runs of each command", 3)
