"""What the camera pass's draw order costs: nearest first against the file's order.

A surface drawn before what hides it is shaded and then overwritten; drawn after it, the depth
test drops its fragments before the fragment shader runs. With ``optimize`` the plan draws the
visible instances nearest first (:func:`shadowmap.renderer.plan.culling.near_first`), whatever
order the file lists them in. Per scene, four arms, interleaved (each repeat starting one arm
later):

- the scene as loaded (the bench's ground last, as :meth:`Scene.with_ground` appends it) and its
  instances reversed (the ground first, as in a file whose first node is its floor);
- each drawn nearest first (the plan as made) and in the file's order (the plan's ordering
  replaced by the identity for this measurement, nothing else changed).

Times are the camera pass's fenced time (``timings["camera"]``), 640x480, default settings, the
light pass drawn once and cached (as a repeated request's is); the plan is made anew for every
call so that the two orders never share one. The colour outputs of the arms are compared pixel
by pixel: the order changes which of two surfaces at exactly equal depth shows, nothing else.

Writes ``bench/results/draw_order.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/draw_order.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import math
import time

import numpy as np

from bench import _common as C  # first: selects the GL platform
from shadowmap.renderer import Renderer, RenderParams  # noqa: E402
from shadowmap.renderer.plan import plan as plan_module  # noqa: E402
from shadowmap.renderer.scene import Scene  # noqa: E402

QUICK_SCENES = ("BoxTextured", "TestScene", "caster_on_ground")


def reversed_scene(scene: Scene) -> Scene:
    """``scene`` with its instances listed in the opposite order (the same primitives)."""
    return Scene(scene.primitives, scene.instances[::-1], scene.cameras, scene.lights,
                 key=scene.key + ":reversed" if scene.key else "", focus=scene.focus,
                 warnings=list(scene.warnings))


class FileOrder:
    """While active, the plan keeps the visible instances in the file's order."""

    def __init__(self) -> None:
        self.saved = plan_module.near_first

    def __enter__(self) -> None:
        plan_module.near_first = lambda ctx, instances: instances  # type: ignore[assignment]

    def __exit__(self, *exc: object) -> None:
        plan_module.near_first = self.saved


def render(r: Renderer, scene: Scene, params: RenderParams, file_order: bool):
    r.plans.clear()  # the plan made anew: the two orders must not share one
    if file_order:
        with FileOrder():
            return r.render(scene, params)
    return r.render(scene, params)


def run(quick: bool, repeats: int) -> None:
    out_dir = C.results_dir(quick)
    t_start = time.perf_counter()
    rows, csv_rows, ratios = [], [], []
    r = Renderer()
    try:
        bench_scenes = C.model_scenes() + [C.stress_scene(n) for n in C.STRESS_SCENES]
        if quick:
            bench_scenes = [s for s in bench_scenes if s.name in QUICK_SCENES]
        bar = C.Progress(len(bench_scenes), "draw order")
        for bs in bench_scenes:
            params = bs.params()
            scenes = {"loaded": bs.scene, "reversed": reversed_scene(bs.scene)}
            calls = {f"{s}/{o}": (lambda sc=sc, p=params, fo=(o == "file"): render(r, sc, p, fo))
                     for s, sc in scenes.items() for o in ("near", "file")}
            t = C.time_interleaved(calls, repeats, warmup=2, rotate=True)
            ms = {k: v.ms("camera") for k, v in t.items()}
            colour = {k: v.last.color for k, v in t.items()}
            differ = max(int(np.count_nonzero((colour[k] != colour["loaded/near"]).any(axis=-1)))
                         for k in colour)
            drawn = t["loaded/near"].last.plan["camera_pass"]["drawn"]
            worst_file = max(ms["loaded/file"], ms["reversed/file"])
            worst_near = max(ms["loaded/near"], ms["reversed/near"])
            ratios.append(worst_near / worst_file)
            rows.append([bs.name, drawn, C.fmt(ms["loaded/file"], 2), C.fmt(ms["loaded/near"], 2),
                         C.fmt(ms["reversed/file"], 2), C.fmt(ms["reversed/near"], 2),
                         C.fmt(ms["reversed/file"] / ms["loaded/file"], 3),
                         C.fmt(ms["reversed/near"] / ms["loaded/near"], 3),
                         C.fmt(worst_near / worst_file, 3), differ])
            csv_rows.append({"scene": bs.name, "drawn": drawn,
                             **{f"{k.replace('/', '_')}_ms": round(v, 4) for k, v in ms.items()},
                             "pixels_differing": differ})
            bar.step(bs.name)
        bar.close()
        machine = C.machine_info(r)
    finally:
        r.close()
    headers = ["scene", "instances drawn", "as loaded, file order ms", "as loaded, near first ms",
               "reversed, file order ms", "reversed, near first ms",
               "file order: reversed / as loaded", "near first: reversed / as loaded",
               "slower order: near first / file order", "pixels differing"]
    table = C.markdown_table(headers, rows)
    gm = math.exp(sum(math.log(x) for x in ratios) / len(ratios))
    notes = [
        f"- The slower of the two instance orders of each scene, drawn near first over drawn in "
        f"the file's order: geometric mean {gm:.3f} over {len(ratios)} scenes.",
        "- Pixels differing: the most of any arm against the scene as loaded drawn near first "
        "(colour output, any channel).",
    ]
    md = "\n".join([
        "# Draw order: nearest first against the file's order", "",
        f"{C.WIDTH}x{C.HEIGHT}, default settings, the camera pass's fenced time (median of "
        f"{repeats} interleaved calls after two warm-ups, each repeat starting one arm later), "
        "the light pass cached; *reversed*: the scene's instances listed in the opposite order "
        "(the ground first). See `bench/draw_order.py`.", "",
        table, "", *notes, "",
        machine + f". Run time {time.perf_counter() - t_start:.0f} s.", ""])
    C.finish(out_dir, "draw_order", md, csv_rows, [table], notes,
             time.perf_counter() - t_start)


if __name__ == "__main__":
    C.bench_main(__doc__, run, "three scenes, fewer repeats", 9)
