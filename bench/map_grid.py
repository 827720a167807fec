"""What the steps of ``map_size: "auto"`` cost and buy: powers of two against finer steps.

``auto`` gives a map the smallest power of two of texels per side that makes its texel at most
half a camera pixel on the nearest visible receivers (:meth:`PlanContext.map_size`), so a map
gets between one and two times the side it needs: up to four times the texels, which the light
pass fills and the lookups read (a texel read costs more the larger the map,
``bench/lookup_cost.py``). The same frames with the need rounded up to finer steps instead:

- *pow2*: the plan as made (steps of 2x);
- *halves*: steps of 1.5x and 2x within each power of two (256, 384, 512, 768, 1024, ...);
- *quarters*: four steps per power of two (256, 320, 384, 448, 512, 640, ...).

Per scene (the scenes of ``bench/error_vs_time.py`` and four more stress scenes, 640x480,
default settings, one directional, spot or point light): the map side each arm gives, the shadow
mask's error against the ray-traced reference (misclassified % of its valid pixels, 1 - IoU), and
the frame's median wall time and light-pass time with every frame drawing its light pass (the
light-map cache off), the arms interleaved, each repeat starting one arm later. The finer arms
replace the rounding function for the measurement only (the renderer is not changed); the plan
is made anew for every call.

Writes ``bench/results/map_grid.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/map_grid.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from bench import _common as C  # first: selects the GL platform
from bench.error_vs_time import SCENES, build_scene, light_mean
from shadowmap.renderer import Renderer  # noqa: E402
from shadowmap.renderer.plan import context as plan_context  # noqa: E402
from shadowmap.renderer.reference import trace_reference  # noqa: E402

MORE_SCENES = ("caster_on_ground", "thin_sheets", "degenerate", "room_point")
QUICK_SCENES = ("AlphaBlendModeTest.glb", "far_spot")
POW2 = plan_context._pow2_at_least


def stepped(steps: int) -> Callable[[float, int, int], int]:
    """The rounding of :func:`_pow2_at_least` with ``steps`` equal steps per power of two."""

    def at_least(x: float, lo: int, hi: int) -> int:
        if not np.isfinite(x) or x <= lo:
            return lo
        step = 2 ** math.floor(math.log2(x)) / steps
        return int(min(hi, math.ceil(x / step) * step))

    return at_least


ARMS: dict[str, Callable[[float, int, int], int]] = {
    "pow2": POW2, "halves": stepped(2), "quarters": stepped(4)}


def render(r: Renderer, bs: C.BenchScene, arm: str, **params: Any) -> Any:
    """A render with ``arm``'s rounding, planned anew."""
    plan_context._pow2_at_least = ARMS[arm]  # type: ignore[assignment]
    try:
        r.plans.clear()
        r.scene_fits.clear()
        r.requests.clear()
        return r.render(bs.scene, bs.params(**params))
    finally:
        plan_context._pow2_at_least = POW2  # type: ignore[assignment]


def run(quick: bool, repeats: int) -> None:
    t_start = time.perf_counter()
    names = QUICK_SCENES if quick else (*SCENES, *MORE_SCENES)
    r = Renderer(map_cache_bytes=0)  # every frame draws its light pass
    bar = C.Progress(len(names), "map_grid")
    rows: list[list[str]] = []
    csv_rows: list[dict[str, Any]] = []
    ratios: dict[str, list[float]] = {arm: [] for arm in ARMS}
    errors: dict[str, list[float]] = {arm: [] for arm in ARMS}
    try:
        for name in names:
            bs = build_scene(name)
            camera, lights = bs.resolved()
            ref = trace_reference(bs.scene, camera, lights)
            sizes, err = {}, {}
            for arm in ARMS:
                res = render(r, bs, arm, outputs=["visibility"])
                sizes[arm] = "/".join(str(lp.get("map_size")) for lp in res.plan["lights"]
                                      if lp.get("map_size"))
                err[arm] = light_mean(res.visibility, ref)
                errors[arm].append(err[arm]["misclassified_pct"])
            t = C.time_interleaved({arm: (lambda arm=arm, bs=bs: render(r, bs, arm))
                                    for arm in ARMS}, repeats, warmup=2, rotate=True)
            ms = {arm: t[arm].ms() for arm in ARMS}
            for arm in ARMS:
                ratios[arm].append(ms[arm] / ms["pow2"])
            rows.append([bs.name, *(sizes[a] for a in ARMS),
                         *(f"{err[a]['misclassified_pct']:.4f}" for a in ARMS),
                         *(C.fmt(ms[a], 2) for a in ARMS),
                         *(C.fmt(t[a].ms("light"), 2) for a in ARMS),
                         *(C.fmt(ms[a] / ms["pow2"], 3) for a in ARMS if a != "pow2")])
            csv_rows.append({"scene": bs.name, **{f"{a}_map_size": sizes[a] for a in ARMS},
                             **{f"{a}_misclassified_pct": round(err[a]["misclassified_pct"], 5)
                                for a in ARMS},
                             **{f"{a}_one_minus_iou": round(1 - err[a]["iou"], 6) for a in ARMS},
                             **{f"{a}_ms": round(ms[a], 3) for a in ARMS},
                             **{f"{a}_light_ms": round(t[a].ms("light"), 3) for a in ARMS},
                             "repeats": repeats})
            bar.step(bs.name)
        machine = C.machine_info(r)
    finally:
        bar.close()
        r.close()
    fine = [a for a in ARMS if a != "pow2"]
    table = C.markdown_table(
        ["scene", *(f"{a} map" for a in ARMS), *(f"{a} misclassified %" for a in ARMS),
         *(f"{a} ms" for a in ARMS), *(f"{a} light ms" for a in ARMS),
         *(f"{a} / pow2 time" for a in fine)], rows)
    notes = []
    for arm in ARMS:
        geo = math.exp(float(np.mean(np.log(ratios[arm]))))
        notes.append(f"- {arm}: mean misclassified {np.mean(errors[arm]):.4f} % "
                     f"({np.mean(errors[arm]) / np.mean(errors['pow2']):.2f}x pow2's), "
                     f"geometric mean of the frame time over pow2's {geo:.3f}.")
    md = "\n".join([
        "# The steps of the automatic map size", "",
        f"640x480, default settings; per arm the map side, the shadow mask's error against the "
        f"ray-traced reference, and median wall time of {repeats} frames (each drawing its light "
        "pass), the arms interleaved (see `bench/map_grid.py`). *pow2*: the renderer's own "
        "rounding of the needed side up to a power of two; *halves* and *quarters*: up to 2 and "
        "4 steps per power of two.", "", table, "", *notes, "",
        f"Machine: {machine}. Run time {time.perf_counter() - t_start:.0f} s.", ""])
    C.finish(C.results_dir(quick), "map_grid", md, csv_rows, [table], notes,
             time.perf_counter() - t_start)


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__ or "", run, "two scenes, 3 repeats (smoke run)", 3, argv)


if __name__ == "__main__":
    main(sys.argv[1:])
