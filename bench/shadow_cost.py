"""What shadows cost: our shadowed vs unshadowed render, next to pyrender's built-in shadows.

Per scene, at 640x480 with default settings:

- ours: ``renderer.render`` with the scene's lights casting shadows vs the same lights with
  ``cast_shadows: false`` (median wall time of repeated calls after a warm-up), and the shadow IoU
  against the ray-traced reference;
- pyrender: ``OffscreenRenderer.render`` of the same geometry, materials, camera and light
  directions with ``RenderFlags.SHADOWS_DIRECTIONAL`` vs ``RenderFlags.NONE``, and its IoU, its
  shadow mask read off its own images (see :meth:`bench._common.PyrenderBaseline.visibility`).
  Directional lights only (pyrender's point shadows are not implemented; spot scenes are ours only).

Writes ``bench/results/shadow_cost.{md,csv}`` and ``shadow_mask_check.png`` (pyrender's derived
mask next to the reference on one scene, to check the mask by eye); ``--quick`` writes to
``bench/results/quick/``.

Run: ``PYTHONPATH=. .venv/bin/python bench/shadow_cost.py [--quick] [--repeats N]``
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np  # noqa: E402

from bench import _common as C  # before shadowmap: selects the GL platform
from shadowmap.renderer import Renderer, RenderParams  # noqa: E402
from shadowmap.renderer.metrics import compare_all, shadow_metrics  # noqa: E402
from shadowmap.renderer.reference import trace_reference  # noqa: E402

TARGET_RATIO = 1.3
QUICK_SCENES = ("BoxTextured", "caster_on_ground", "caster_1e-3")
MASK_CHECK_SCENE = "CesiumMilkTruck"


def scenes(quick: bool) -> list[C.BenchScene]:
    out = C.model_scenes() + [C.stress_scene(n) for n in C.STRESS_SCENES]
    if quick:
        out = [s for s in out if s.name in QUICK_SCENES]
    return out


def mean_iou(vis: np.ndarray, ref) -> float:
    """Mean over lights of the shadow IoU of ``vis`` (H, W, L) against the reference."""
    ious = [m.iou for m in compare_all(vis, ref)]
    return float(np.mean(ious))


def save_mask_check(path, images: dict, vis: np.ndarray, ref) -> None:
    """A 2x2 picture: pyrender unshadowed | shadowed / derived mask | reference mask.

    Masks: white lit, black shadowed, grey not evaluated (undetermined, or not a valid reference
    pixel).
    """
    from PIL import Image

    def gray(v: np.ndarray) -> np.ndarray:
        g = (np.nan_to_num(v, nan=0.5) * 255).astype(np.uint8)
        return np.dstack([g] * 3)

    ref_v = np.where(ref.valid[..., 0], ref.visibility[..., 0], np.nan)
    top = np.hstack([images["unshadowed"], images["shadowed"]])
    bottom = np.hstack([gray(vis), gray(ref_v)])
    Image.fromarray(np.vstack([top, bottom])).save(path)


def run(quick: bool, repeats: int) -> None:
    out_dir = C.results_dir(quick)
    bench_scenes = scenes(quick)
    t_start = time.perf_counter()
    rows, csv_rows, notes = [], [], []
    mask_scene = "none"
    r = Renderer(map_cache_bytes=0)  # every shadowed frame draws its light pass
    pb = C.PyrenderBaseline(C.WIDTH, C.HEIGHT)
    try:
        bar = C.Progress(len(bench_scenes), "shadow_cost")
        for bs in bench_scenes:
            p_sh = bs.params()
            p_un = bs.params(lights=C.without_shadows(bs.lights))
            ours = C.time_interleaved(
                {"sh": lambda bs=bs, p_sh=p_sh: r.render(bs.scene, p_sh),
                 "un": lambda bs=bs, p_un=p_un: r.render(bs.scene, p_un)},
                repeats,
            )
            camera, lights = bs.resolved()
            ref = trace_reference(bs.scene, camera, lights)
            vis = r.render(bs.scene, bs.params(outputs=["visibility"])).visibility
            our_iou = mean_iou(vis, ref)

            pr_sh = pr_un = pr_iou = math.nan
            undetermined = math.nan
            if bs.directional_only:
                ps = pb.build(bs)
                pyr = C.time_interleaved(
                    {"sh": lambda ps=ps: pb.render(ps, True),
                     "un": lambda ps=ps: pb.render(ps, False)},
                    repeats,
                )
                pr_sh, pr_un = pyr["sh"].ms(), pyr["un"].ms()
                pvis, images = pb.visibility(ps)
                # pyrender shades only its first light's mask here: all scenes have one light.
                m = shadow_metrics(pvis, ref.visibility[..., 0], ref.valid[..., 0])
                pr_iou = m.iou
                valid = ref.valid[..., 0]
                undetermined = 100.0 * float((np.isnan(pvis) & valid).sum()) / max(valid.sum(), 1)
                if bs.name == MASK_CHECK_SCENE or (quick and bs.name == QUICK_SCENES[0]):
                    save_mask_check(out_dir / "shadow_mask_check.png", images, pvis, ref)
                    mask_scene = bs.name
                del ps
            sh, un = ours["sh"].ms(), ours["un"].ms()
            ratio = sh / un
            pr_ratio = pr_sh / pr_un if math.isfinite(pr_sh) else math.nan
            plan = ours["sh"].last.plan["lights"][0]
            rows.append([
                bs.name, C.fmt(sh), C.fmt(un),
                C.fmt(ratio, 2) + ("" if ratio <= TARGET_RATIO else " ✗"),
                C.fmt(our_iou, 3), C.fmt(pr_sh), C.fmt(pr_un), C.fmt(pr_ratio, 2), C.fmt(pr_iou, 3),
            ])
            csv_rows.append({
                "scene": bs.name, "kind": bs.kind, "triangles": bs.scene.triangle_count,
                "light_type": lights[0].type, "map": plan.get("shadow_map"),
                "map_size": plan.get("map_size"),
                "ours_shadowed_ms": round(sh, 3),
                "ours_shadowed_p90_ms": round(ours["sh"].p90_ms(), 3),
                "ours_unshadowed_ms": round(un, 3),
                "ours_unshadowed_p90_ms": round(ours["un"].p90_ms(), 3),
                "ours_light_ms": round(ours["sh"].ms("light"), 3),
                "ours_camera_ms": round(ours["sh"].ms("camera"), 3),
                "ours_unshadowed_camera_ms": round(ours["un"].ms("camera"), 3),
                "ours_ratio": round(ratio, 4), "ours_iou": round(our_iou, 5),
                "pyrender_shadowed_ms": round(pr_sh, 3), "pyrender_unshadowed_ms": round(pr_un, 3),
                "pyrender_ratio": round(pr_ratio, 4), "pyrender_iou": round(pr_iou, 5),
                "pyrender_undetermined_pct": round(undetermined, 4),
                "reference_s": round(ref.seconds, 3), "repeats": repeats,
            })
            bar.step(bs.name)
        bar.close()
        machine = C.machine_info(r)
    finally:
        pb.close()  # before ours: the last EGL context to go terminates the shared display
        r.close()

    ratios = [c["ours_ratio"] for c in csv_rows]
    pr_ratios = [c["pyrender_ratio"] for c in csv_rows if math.isfinite(c["pyrender_ratio"])]
    gmean = float(np.exp(np.mean(np.log(ratios))))
    pr_gmean = float(np.exp(np.mean(np.log(pr_ratios)))) if pr_ratios else math.nan
    headers = ["scene", "ours shadowed ms", "ours unshadowed ms", "ratio", "ours IoU",
               "pyrender shadowed ms", "pyrender unshadowed ms", "ratio", "pyrender IoU"]
    table = C.markdown_table(headers, rows)
    over = [c["scene"] for c in csv_rows if c["ours_ratio"] > TARGET_RATIO]
    und = [c["pyrender_undetermined_pct"] for c in csv_rows
           if math.isfinite(c["pyrender_undetermined_pct"])]
    notes.append(f"Geometric mean of the shadowed/unshadowed ratio: ours {gmean:.2f}x, "
                 f"pyrender {pr_gmean:.2f}x. Target: ours <= {TARGET_RATIO}x; "
                 + (f"over it (✗): {', '.join(over)}." if over else "met on every scene."))
    light = [c["ours_light_ms"] for c in csv_rows]
    extra_camera = [c["ours_camera_ms"] - c["ours_unshadowed_camera_ms"] for c in csv_rows]
    notes.append(f"Where our shadow time goes (median over scenes): light pass "
                 f"{np.median(light):.1f} ms, camera pass {np.median(extra_camera):.1f} ms more "
                 "than unshadowed (the shadow lookups and filtering per pixel).")
    if und:
        notes.append(f"pyrender's mask is undetermined (the light adds < "
                     f"{C.PYRENDER_MIN_LEVELS:g} grey levels) on at most {max(und):.2f} % of the "
                     "reference's valid pixels; those are left out of its IoU.")
    sh = RenderParams().shadows
    default_desc = (f"`RenderParams()`: {sh.encoding}, map size {sh.map_size}, {sh.filter}"
                    + (f" {sh.pcf_kernel}x{sh.pcf_kernel}" if sh.filter == "pcf" else "")
                    + ", default bias")
    elapsed = time.perf_counter() - t_start
    md = "\n".join([
        "# Shadow cost: shadowed vs unshadowed render, ours and pyrender's",
        "",
        f"640x480, default settings ({default_desc}). Median wall time of {repeats} calls "
        "after a warm-up, shadowed and unshadowed calls interleaved. Unshadowed = the same "
        "lights with `cast_shadows: false` (ours) / `RenderFlags.NONE` (pyrender). IoU of the "
        "shadow mask against the ray-traced reference over its valid pixels. pyrender's mask is "
        "read off its shadowed, unshadowed and ambient-only images: a pixel is shadowed when it "
        "lost more than half of the light's contribution (see `shadow_mask_check.png`). "
        "pyrender: directional lights only (— for the spot and point scenes).",
        "",
        table,
        "",
        *[f"- {n}" for n in notes],
        "",
        "![pyrender's derived mask](shadow_mask_check.png)",
        "",
        f"`shadow_mask_check.png` ({mask_scene}): top, pyrender unshadowed and shadowed; "
        "bottom, the mask derived from them and the reference's (white lit, black shadowed, "
        "grey not evaluated).",
        "",
        f"Machine: {machine}. Run time {elapsed:.0f} s"
        + (" (--quick)." if quick else "."),
        "",
    ])
    C.finish(out_dir, "shadow_cost", md, csv_rows, [table], notes, elapsed,
             extra=["shadow_mask_check.png"])


def main(argv: list[str] | None = None) -> None:
    C.bench_main(__doc__, run, "three scenes, 3 repeats (smoke run)", 3, argv)


if __name__ == "__main__":
    sys.exit(main())
