"""What the render plan saves: ``optimize: true`` against ``optimize: false``, per omission rule.

Each scene is built to exercise one rule of :mod:`shadowmap.renderer.plan` (objects outside the
view, non-casters, a light that reaches nothing visible, cube faces without receivers, shader
variants specialised to textured / untextured materials, outputs not requested, shadow lookups
only where a shadow can fall); the real models exercise them all at once. The scene cache (the
same bytes rendered twice) is compared with a renderer whose cache is off. Times are medians of
repeated calls after a warm-up, the two variants interleaved; per-stage medians and what the plan
reports as left out are listed too.

Writes ``bench/results/plan_savings.{md,csv}`` (``--quick``: ``bench/results/quick/``).

Run: ``PYTHONPATH=. .venv/bin/python bench/plan_savings.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

from bench import _common as C  # first: selects the GL platform
from shadowmap.renderer import Renderer, RenderParams  # noqa: E402
from shadowmap.renderer import testing as T  # noqa: E402
from shadowmap.renderer.demo import DEMO_PARAMS, demo_glb  # noqa: E402

CAMERA = {"eye": [4.0, 4.0, 6.0], "target": [0.0, 0.5, 0.0]}
LIGHT = {"type": "directional", "direction": [-0.5, -1.0, -0.3]}
ALL_OUTPUTS = ["color", "visibility", "depth", "light_depth"]
STAGES = ("load", "upload", "plan", "light", "camera", "readback")


@dataclass
class Case:
    """One row: a scene (or bytes), the request, and the rule it exercises."""

    name: str
    rule: str
    scene: object
    params: dict
    cache: bool = False  # compare scene-cache hits with a renderer without a cache


def cases(quick: bool) -> list[Case]:
    spot_away = {"type": "spot", "position": [0, 3, 0], "direction": [0, 1, 0],
                 "outer_cone_deg": 30}
    point_above = {"type": "point", "position": [0.3, 3.0, 0.2]}
    box = C.load_model("BoxTextured.glb")
    out = [
        Case("many_small_objects", "outside view (camera and light passes)",
             T.many_small_objects(200), {"camera": CAMERA, "lights": [LIGHT]}),
        Case("ground_only_receives", "non-casters left out of the light pass",
             T.ground_only_receives(), {"camera": CAMERA, "lights": [LIGHT]}),
        Case("spot_away", "light pass reaching nothing visible",
             T.caster_on_ground(), {"camera": CAMERA, "lights": [LIGHT, spot_away]}),
        Case("point_above", "cube faces without visible receivers",
             T.caster_on_ground(), {"camera": CAMERA, "lights": [point_above]}),
        Case("BoxTextured", "shader variant: textured", box, {}),
        Case("BoxTextured untextured", "shader variant: untextured", C.untextured(box), {}),
        Case("caster_on_ground, color", "outputs: color only",
             T.caster_on_ground(), {"camera": CAMERA, "lights": [LIGHT]}),
        Case("caster_on_ground, all outputs", "outputs: color, visibility, depth, light_depth",
             T.caster_on_ground(), {"camera": CAMERA, "lights": [LIGHT], "outputs": ALL_OUTPUTS}),
        Case("caster_on_ground, depth", "outputs: depth only (no light pass, no shading)",
             T.caster_on_ground(), {"camera": CAMERA, "lights": [LIGHT], "outputs": ["depth"]}),
        Case("CesiumMilkTruck, visibility", "outputs: visibility only (lookups, no shading)",
             C.load_model("CesiumMilkTruck.glb"), {"outputs": ["visibility"]}),
        Case("CesiumMilkTruck, color and visibility", "outputs: color, visibility",
             C.load_model("CesiumMilkTruck.glb"), {"outputs": ["color", "visibility"]}),
        Case("CesiumMilkTruck, depth", "outputs: depth only (no light pass, no shading)",
             C.load_model("CesiumMilkTruck.glb"), {"outputs": ["depth"]}),
        Case("CesiumMilkTruck, light_depth", "outputs: light_depth only (no camera pass)",
             C.load_model("CesiumMilkTruck.glb"), {"outputs": ["light_depth"]}),
        Case("Duck, lookups in shadow rectangles", "shadow lookups only where a shadow can fall",
             C.load_model("Duck.glb"), {"shadows": {"fit": "scene"}}),
        Case("demo.glb bytes twice", "scene cache (hit vs cache off)", demo_glb(),
             {k: v for k, v in DEMO_PARAMS.items() if k != "outputs"}, cache=True),
    ]
    if not quick:
        for name in C.MODEL_NAMES:
            out.append(Case(name.rsplit(".", 1)[0] + " (model)", "all rules",
                            C.load_model(name), {}))
    else:
        out = [c for c in out if c.name in ("many_small_objects", "point_above",
                                             "CesiumMilkTruck, depth", "demo.glb bytes twice")]
    return out


def plan_summary(plan: dict, cache: bool = False) -> str:
    """What a plan report says was left out, in a few words."""
    parts = []
    culled = plan["camera_pass"]["skipped"].get("outside_view", 0)
    if culled:
        parts.append(f"view: {culled} culled")
    for k, lp in enumerate(plan["lights"]):
        if lp.get("shadow_map") is None:
            parts.append(f"L{k}: no pass ({lp.get('skipped_pass')})")
            continue
        bits = [f"{lp['casters']} casters"]
        sided = lp.get("one_sided", sum(c.get("one_sided", 0) for c in lp.get("cascades", [])))
        if sided:
            bits.append(f"{sided} one-sided")
        bits += [f"{v} {reason}" for reason, v in lp.get("skipped", {}).items()]
        if "faces" in lp:
            bits.append(f"faces {lp['faces']}")
        parts.append(f"L{k}: " + ", ".join(bits))
    region = plan["camera_pass"].get("shadow_region")
    if region is not None:
        parts.append(f"lookups in {len(region['rects'])} rectangles "
                     f"({region['share']:.0%} of the frame)")
    draws = plan["camera_pass"].get("draws", "shaded")
    if draws != "shaded":
        parts.append(f"camera pass: {draws}")
    variants = plan.get("shader_variants", {}).get("camera_pass")
    if variants is not None:
        parts.append(f"{len(variants)} camera variants")
    if cache:
        parts.append(f"scene cache {plan.get('scene_cache')}")
    return "; ".join(parts)


def run(quick: bool, repeats: int) -> None:
    out_dir = C.results_dir(quick)
    t_start = time.perf_counter()
    all_cases = cases(quick)
    rows, stage_rows, csv_rows = [], [], []
    bar = C.Progress(len(all_cases), "plan_savings")
    r = Renderer()
    uncached = Renderer(cache_bytes=0, cache_entries=0)
    try:
        for case in all_cases:
            on = RenderParams.model_validate({**case.params, "optimize": True})
            if case.cache:
                # Both render the same bytes; only one renderer may keep the upload.
                calls: dict[str, Callable] = {
                    "on": lambda case=case, on=on: r.render(case.scene, on),
                    "off": lambda case=case, on=on: uncached.render(case.scene, on),
                }
            else:
                off = RenderParams.model_validate({**case.params, "optimize": False})
                calls = {"on": lambda case=case, on=on: r.render(case.scene, on),
                         "off": lambda case=case, off=off: r.render(case.scene, off)}
            t = C.time_interleaved(calls, repeats)
            on_ms, off_ms = t["on"].ms(), t["off"].ms()
            saved = off_ms - on_ms
            summary = plan_summary(t["on"].last.plan, case.cache)
            off_summary = plan_summary(t["off"].last.plan, case.cache)
            rows.append([case.name, case.rule, C.fmt(on_ms), C.fmt(off_ms), C.fmt(saved),
                         C.fmt(100 * saved / off_ms), summary, off_summary])
            stage_rows.append([case.name] + [
                f"{t['on'].ms(s):.2f} / {t['off'].ms(s):.2f}" for s in STAGES
            ])
            rec = {"scene": case.name, "rule": case.rule, "optimized_ms": round(on_ms, 3),
                   "unoptimized_ms": round(off_ms, 3), "saved_ms": round(saved, 3),
                   "saved_pct": round(100 * saved / off_ms, 2),
                   "optimized_p90_ms": round(t["on"].p90_ms(), 3),
                   "unoptimized_p90_ms": round(t["off"].p90_ms(), 3)}
            for s in STAGES:
                rec[f"{s}_optimized_ms"] = round(t["on"].ms(s), 3)
                rec[f"{s}_unoptimized_ms"] = round(t["off"].ms(s), 3)
            rec["plan_optimized"] = summary
            rec["plan_unoptimized"] = off_summary
            rec["repeats"] = repeats
            csv_rows.append(rec)
            bar.step(case.name)
        bar.close()
        machine = C.machine_info(r)
    finally:
        uncached.close()
        r.close()

    headers = ["scene", "rule", "optimized ms", "unoptimized ms", "saved ms", "saved %",
               "plan reports (optimized)", "plan reports (unoptimized)"]
    table = C.markdown_table(headers, rows, "llrrrrll")
    stage_table = C.markdown_table(["scene"] + [f"{s} ms" for s in STAGES], stage_rows)
    by_name = {c["scene"]: c for c in csv_rows}
    notes = []
    color = by_name.get("caster_on_ground, color")
    alls = by_name.get("caster_on_ground, all outputs")
    if color and alls:
        notes.append(f"Asking for all four outputs instead of colour only costs "
                     f"{alls['optimized_ms'] - color['optimized_ms']:.1f} ms "
                     f"({color['optimized_ms']:.1f} -> {alls['optimized_ms']:.1f} ms, optimized).")
    depth = by_name.get("caster_on_ground, depth")
    if color and depth:
        notes.append(f"Depth alone instead of colour only: {depth['optimized_ms']:.1f} against "
                     f"{color['optimized_ms']:.1f} ms (caster_on_ground, optimized; no light "
                     "pass, a camera pass without lighting).")
    truck = by_name.get("CesiumMilkTruck (model)")
    both_out = by_name.get("CesiumMilkTruck, color and visibility")
    vis_only = by_name.get("CesiumMilkTruck, visibility")
    if both_out and vis_only:
        notes.append(f"CesiumMilkTruck, visibility alone instead of colour and visibility: "
                     f"{vis_only['optimized_ms']:.1f} against {both_out['optimized_ms']:.1f} ms "
                     "(optimized; the same visibility, no shading).")
    for label in ("depth", "light_depth"):
        row = by_name.get(f"CesiumMilkTruck, {label}")
        if truck and row:
            notes.append(f"CesiumMilkTruck, {label} alone instead of the default outputs: "
                         f"{row['optimized_ms']:.1f} against {truck['optimized_ms']:.1f} ms "
                         "(optimized).")
    cache = by_name.get("demo.glb bytes twice")
    if cache:
        notes.append(
            f"Scene cache: a hit skips the parse (load {cache['load_optimized_ms']:.2f} vs "
            f"{cache['load_unoptimized_ms']:.2f} ms) and the upload "
            f"({cache['upload_optimized_ms']:.2f} vs {cache['upload_unoptimized_ms']:.2f} ms). "
            "The unoptimized column is a renderer with both caches off "
            "(`cache_bytes=0, cache_entries=0`)."
        )
    same = [c["scene"] for c in csv_rows
            if "no pass" in c["plan_optimized"] and "no pass" in c["plan_unoptimized"]]
    if same:
        notes.append(f"{', '.join(same)}: the light pass is left out with `optimize: false` too, "
                     "so the time saved there comes from the other rules (shader variants).")
    notes.append("Non-casters are left out of the light pass with `optimize: false` as well "
                 "(castShadow = false is part of the request's meaning), so that row compares "
                 "only the other rules.")
    elapsed = time.perf_counter() - t_start
    md = "\n".join([
        "# Render-plan savings: optimize true vs false",
        "",
        f"640x480 unless the scene's request says otherwise, default shadow settings. Median wall "
        f"time of {repeats} calls of `Renderer.render` after a warm-up, the two variants "
        "interleaved. `optimize: false` draws every object in every pass with one all-features "
        "shader variant and renders every cube face; the plan's fit and map size are the same "
        "either way.",
        "",
        table,
        "",
        *[f"- {n}" for n in notes],
        "",
        "## Per stage (median ms, optimized / unoptimized)",
        "",
        stage_table,
        "",
        f"Machine: {machine}. Run time {elapsed:.0f} s" + (" (--quick)." if quick else "."),
        "",
    ])
    C.finish(out_dir, "plan_savings", md, csv_rows, [table, stage_table], notes, elapsed)


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__, run, "three cases, 3 repeats (smoke run)", 3, argv)


if __name__ == "__main__":
    sys.exit(main())
