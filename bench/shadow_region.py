"""What drawing around the shadow region saves: the same renders with and without it.

Per scene of ``bench/floor.py`` (640x480, default settings), interleaved: the frame drawn as the
plan decides (lookups only inside each receiver's shadow rectangle,
:mod:`shadowmap.renderer.plan.shadow_region`) and the same request with every receiver drawn with
lookups (``shadow_region.MIN_SAVED_SHARE`` above 1: the region is planned but never drawn
around), each with its light pass (the light-map cache off), the unshadowed frame beside them;
wall time and the camera pass alone. Then 16 views around four scenes with one scene-fitted map
shared by the views (``shadows.fit: "scene"``), per view, both ways and unshadowed. Plans are
cached as in a repeated request (each arm asks with its own request object); ``plan ms`` is the
cost of one new plan with the region and without it (the region's own Python).

Writes ``bench/results/shadow_region.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/shadow_region.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import math
import sys
import time

from bench import _common as C  # first: selects the GL platform
from bench.floor import VIEW_SCENES, VIEWS, orbit_params  # noqa: E402
from shadowmap.renderer import Renderer, RenderParams  # noqa: E402
from shadowmap.renderer.camera import resolve_camera  # noqa: E402
from shadowmap.renderer.lights import resolve_lights  # noqa: E402
from shadowmap.renderer.plan import make_plan  # noqa: E402
from shadowmap.renderer.plan import shadow_region as SR  # noqa: E402

QUICK_SCENES = ("Duck", "caster_on_ground")
NEVER = 2.0  # a MIN_SAVED_SHARE no estimate reaches: lookups on every receiver


def _arm(p: RenderParams, k: int) -> RenderParams:
    """The same request as another object (its own plan in the plan cache)."""
    return p.model_copy(update={"background": [0.0, 0.0, 0.0, k / 100]})


class _Region:
    """Switches drawing around the region on and off around each call."""

    def __init__(self, on: bool) -> None:
        self.on = on

    def __enter__(self) -> None:
        self.saved = SR.MIN_SAVED_SHARE
        if not self.on:
            SR.MIN_SAVED_SHARE = NEVER

    def __exit__(self, *exc: object) -> None:
        SR.MIN_SAVED_SHARE = self.saved


def call(r: Renderer, scene, p: RenderParams, on: bool):
    with _Region(on):
        return r.render(scene, p)


def plan_ms(bs: C.BenchScene, repeats: int) -> tuple[float, float]:
    """Median ms of one new plan with the region and with none (``optimize`` false skips it,
    and every other rule; the difference is taken from the same request at 320x240, where the
    region is not planned)."""
    p = bs.params()
    camera = resolve_camera(p.camera, bs.scene, p.width, p.height)
    lights = resolve_lights(p.lights, bs.scene)
    lo, hi = bs.scene.bounds
    origin = (lo + hi) / 2
    small = bs.params(320, 240)
    cam_small = resolve_camera(small.camera, bs.scene, 320, 240)
    with_, without = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        make_plan(bs.scene, camera, lights, origin, p)
        with_.append(time.perf_counter() - t)
        t = time.perf_counter()
        make_plan(bs.scene, cam_small, lights, origin, small)
        without.append(time.perf_counter() - t)
    return 1e3 * C.median(with_), 1e3 * C.median(without)


def run(quick: bool, repeats: int) -> None:
    t_start = time.perf_counter()
    r = Renderer(map_cache_bytes=0)  # every shadowed frame draws its light pass
    scenes = C.model_scenes() + [C.stress_scene(n) for n in C.STRESS_SCENES]
    if quick:
        scenes = [s for s in scenes if s.name in QUICK_SCENES]
    bar = C.Progress(len(scenes) + len(VIEW_SCENES), "shadow_region")
    rows, csv_rows = [], []
    for bs in scenes:
        p = bs.params()
        on, off = _arm(p, 1), _arm(p, 2)
        bare = bs.params(lights=C.without_shadows(bs.lights))
        scene = bs.scene
        t = C.time_interleaved({
            "region": lambda on=on, scene=scene: call(r, scene, on, True),
            "everywhere": lambda off=off, scene=scene: call(r, scene, off, False),
            "unshadowed": lambda bare=bare, scene=scene: r.render(scene, bare),
        }, repeats, warmup=2)
        report = t["region"].last.plan["camera_pass"].get("shadow_region") or {}
        with_plan, small_plan = plan_ms(bs, repeats)
        reg, every, un = t["region"].ms(), t["everywhere"].ms(), t["unshadowed"].ms()
        rc, ec, uc = (t[k].ms("camera") for k in ("region", "everywhere", "unshadowed"))
        saved = 1 - (rc - uc) / (ec - uc) if ec > uc else math.nan
        rows.append([bs.name, C.fmt(every, 2), C.fmt(reg, 2), C.fmt(un, 2), C.fmt(ec, 2),
                     C.fmt(rc, 2), C.fmt(uc, 2), f"{100 * saved:.0f} %",
                     f"{report.get('saved_share', 0):.2f}", str(report.get("split", "—")),
                     len(report.get("rects", []))])
        csv_rows.append({"scene": bs.name, "everywhere_ms": round(every, 3),
                         "region_ms": round(reg, 3), "unshadowed_ms": round(un, 3),
                         "everywhere_camera_ms": round(ec, 3), "region_camera_ms": round(rc, 3),
                         "unshadowed_camera_ms": round(uc, 3),
                         "lookup_cost_saved": round(saved, 4),
                         "saved_share": report.get("saved_share"), "split": report.get("split"),
                         "rects": len(report.get("rects", [])),
                         "plan_ms": round(with_plan, 3), "plan_ms_320x240": round(small_plan, 3)})
        bar.step(bs.name)
    view_rows = []
    for name in VIEW_SCENES:
        bs = C.model_scene(name + ".glb") if name[0].isupper() else C.stress_scene(name)
        sets = {"region": [_arm(orbit_params(bs, k, "scene"), 1) for k in range(VIEWS)],
                "everywhere": [_arm(orbit_params(bs, k, "scene"), 2) for k in range(VIEWS)],
                "unshadowed": [orbit_params(bs, k, "view", shadows=False)
                               for k in range(VIEWS)]}
        shared = Renderer()  # the light-map cache on: one pass serves the 16 views

        def views(ps: list[RenderParams], on: bool, shared=shared, bs=bs):
            shared.light_pass.cache.clear()
            last = None
            for q in ps:
                last = call(shared, bs.scene, q, on)
            return last

        t = C.time_interleaved({k: (lambda ps=ps, k=k: views(ps, k != "everywhere"))
                                for k, ps in sets.items()}, repeats, warmup=1)
        ms = {k: t[k].ms() / VIEWS for k in sets}
        view_rows.append([name, C.fmt(ms["everywhere"], 2), C.fmt(ms["region"], 2),
                          C.fmt(ms["unshadowed"], 2),
                          f"{ms['everywhere'] / ms['unshadowed']:.2f}",
                          f"{ms['region'] / ms['unshadowed']:.2f}"])
        csv_rows.append({"scene": f"{name} (16 views, fit scene)",
                         "everywhere_ms": round(ms["everywhere"], 3),
                         "region_ms": round(ms["region"], 3),
                         "unshadowed_ms": round(ms["unshadowed"], 3)})
        bar.step(name)
        shared.close()
    bar.close()
    table = C.markdown_table(
        ["scene", "lookups everywhere ms", "region ms", "unshadowed ms",
         "camera pass, everywhere ms", "camera pass, region ms", "camera pass, unshadowed ms",
         "lookup cost saved", "saved_share", "split", "rectangles"], rows)
    view_table = C.markdown_table(
        ["scene", "everywhere ms/view", "region ms/view", "unshadowed ms/view",
         "everywhere / unshadowed", "region / unshadowed"], view_rows)
    plans = "; ".join(f"{c['scene']} {c['plan_ms']:.2f} ms ({c['plan_ms_320x240']:.2f} at "
                      f"320x240, no region)" for c in csv_rows[:len(scenes)][:4])
    notes = [f"- A new plan with the region, against the same request at 320x240 (where the "
             f"region is not planned): {plans}."]
    md = "\n".join([
        "# The shadow region: lookups only where a shadow can fall", "",
        f"640x480, default settings, medians of {repeats} interleaved calls after two warm-ups; "
        "each shadowed frame draws its light pass. *Lookups everywhere*: every receiver drawn "
        "with the shadow lookups (`MIN_SAVED_SHARE` out of reach); *region*: as the plan "
        "decides. *Lookup cost saved*: the share of the camera pass's extra time over the "
        "unshadowed one that the region removes. `saved_share` and `split` as the plan "
        "reports them.", "", table, "",
        f"## {VIEWS} views, one scene-fitted map", "",
        f"{VIEWS} cameras on a circle (as in `bench/floor.py`), `shadows.fit: \"scene\"`, one "
        "light pass shared by the views (the light-map cache); per view.", "", view_table, "",
        *notes, "", f"Machine: {C.machine_info(r)}. Run time "
        f"{time.perf_counter() - t_start:.0f} s.", ""])
    r.close()
    out = C.results_dir(quick)
    C.finish(out, "shadow_region", md, csv_rows, [table, view_table], notes,
             time.perf_counter() - t_start)


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__, run, "two scenes, 3 repeats (smoke run)", 3, argv)


if __name__ == "__main__":
    main(sys.argv[1:])
